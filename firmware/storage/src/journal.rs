//! [`Journaled`]: page erases that survive a power cut.
//!
//! A NOR sector erase cut short leaves the sector undefined (RM0090: its
//! contents are not guaranteed): random words, some erased, some old.
//! `sequential-storage` erases a page only after copying its live items
//! elsewhere, and reads a half-erased page's state from its first and last
//! words; undefined contents can read as a closed page of garbage, which its
//! repair then takes for a migration cut short and copies back over the
//! good copy (a value lost). [`Journaled`] wraps the flash so that an erase
//! cut short is finished at the next boot, before the store reads anything:
//! each page erase is announced in a journal page of its own (outside the
//! store's range) and marked done after it; at boot ([`Journaled::open`]) an
//! erase announced and not done is done again.
//!
//! The journal page: a mark word ([`JOURNAL_MARK`]), then one word per event
//! (an erase begun, an erase done, each with the page and a check), then
//! erased words. A word a cut left half-programmed fails its check and is
//! skipped. When the page is full it is voided (every word programmed to
//! zero, so that no event survives an erase of it cut short), erased and
//! marked again, between two erases of the store's pages: a journal without
//! its mark at boot therefore had nothing pending, and is made anew.
//!
//! Needs a flash that writes and reads 4-byte words (or smaller units) and
//! takes a second write over a programmed word (it only clears bits: the
//! STM32F4's without ECC, [`crate::RamFlash`]), for the voiding.

use core::ops::Range;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// The journal page's first word once it is made ("fc-storage journal 1").
pub const JOURNAL_MARK: u32 = 0xFC5E_4A01;

const ERASED: u32 = 0xFFFF_FFFF;
const BEGUN: u32 = 0xB;
const DONE: u32 = 0xD;

/// The journal word of event `kind` on page `page` (its index in the
/// flash): kind (4 bits), page (16), a check of both (12).
fn event(kind: u32, page: u32) -> u32 {
    let page = page & 0xFFFF;
    let check = ((page ^ (kind << 16)).wrapping_mul(0x9E37_79B1) >> 20) & 0xFFF;
    kind << 28 | page << 12 | check
}

/// The event a journal word holds, if its check passes.
fn parse(word: u32) -> Option<(u32, u32)> {
    let (kind, page) = (word >> 28, (word >> 12) & 0xFFFF);
    (matches!(kind, BEGUN | DONE) && event(kind, page) == word).then_some((kind, page))
}

/// Why a [`Journaled`] access failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JournaledError<E> {
    /// The flash below failed.
    Flash(E),
    /// The access touches the journal page (not the store's), or the
    /// journal page is not one whole erase page of the flash.
    Journal,
}

impl<E: NorFlashError> NorFlashError for JournaledError<E> {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            JournaledError::Flash(e) => e.kind(),
            JournaledError::Journal => NorFlashErrorKind::OutOfBounds,
        }
    }
}

impl<E: core::fmt::Debug> core::fmt::Display for JournaledError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            JournaledError::Flash(e) => write!(f, "the flash failed: {e:?}"),
            JournaledError::Journal => f.write_str("a flash access outside the store, into its erase journal"),
        }
    }
}

/// A NOR flash whose page erases are journaled in the erase page `journal`
/// (module docs): the store over it keeps every committed value through an
/// erase cut short, whatever the page holds after the cut.
pub struct Journaled<F> {
    flash: F,
    journal: Range<u32>,
    /// The next free word's offset in the journal.
    next: u32,
}

impl<F: NorFlash> Journaled<F> {
    /// `flash` with its erase journal in `journal` (one whole erase page,
    /// outside the store's range): finishes an erase a power cut left
    /// undone, and makes the journal anew if it holds no mark (blank, or an
    /// erase of it cut short). `Ok(true)` if an erase was finished.
    pub fn open(flash: F, journal: Range<u32>) -> Result<(Self, bool), JournaledError<F::Error>> {
        let page = F::ERASE_SIZE as u32;
        // Its events are 4-byte words.
        let words = 4 % F::WRITE_SIZE == 0 && 4 % F::READ_SIZE == 0;
        if !words || journal.end.checked_sub(journal.start) != Some(page) || !journal.start.is_multiple_of(page) {
            return Err(JournaledError::Journal);
        }
        let mut j = Self {
            flash,
            next: journal.start + 4,
            journal,
        };
        let finished = embassy_futures::block_on(j.recover())?;
        Ok((j, finished))
    }

    /// The flash back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    async fn word(&mut self, at: u32) -> Result<u32, JournaledError<F::Error>> {
        let mut b = [0u8; 4];
        self.flash.read(at, &mut b).await.map_err(JournaledError::Flash)?;
        Ok(u32::from_le_bytes(b))
    }

    async fn append(&mut self, w: u32) -> Result<(), JournaledError<F::Error>> {
        self.flash
            .write(self.next, &w.to_le_bytes())
            .await
            .map_err(JournaledError::Flash)?;
        self.next += 4;
        Ok(())
    }

    /// Erases the journal and marks it: voided first, so that an erase of
    /// it cut short leaves no event that could be read again.
    async fn renew(&mut self) -> Result<(), JournaledError<F::Error>> {
        let mut at = self.journal.start;
        while at < self.journal.end {
            // An erased word holds no event; a zero one is void already.
            if !matches!(self.word(at).await?, 0 | ERASED) {
                self.flash.write(at, &[0; 4]).await.map_err(JournaledError::Flash)?;
            }
            at += 4;
        }
        let (s, e) = (self.journal.start, self.journal.end);
        self.flash.erase(s, e).await.map_err(JournaledError::Flash)?;
        self.next = s;
        self.append(JOURNAL_MARK).await
    }

    async fn recover(&mut self) -> Result<bool, JournaledError<F::Error>> {
        if self.word(self.journal.start).await? != JOURNAL_MARK {
            // Blank, or its own erase cut short (then nothing was pending).
            self.renew().await?;
            return Ok(false);
        }
        let mut pending = None;
        let mut at = self.journal.start + 4;
        while at < self.journal.end {
            let w = self.word(at).await?;
            if w == ERASED {
                break;
            }
            match parse(w) {
                Some((BEGUN, p)) => pending = Some(p),
                Some((DONE, p)) if pending == Some(p) => pending = None,
                // A word a cut left half-programmed, or a stray done.
                _ => {}
            }
            at += 4;
        }
        self.next = at;
        match pending {
            Some(p) => {
                self.erase_page(p).await?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// Erases page `p` (its index), announced before and marked done after.
    async fn erase_page(&mut self, p: u32) -> Result<(), JournaledError<F::Error>> {
        if self.next + 8 > self.journal.end {
            self.renew().await?;
        }
        let size = F::ERASE_SIZE as u32;
        self.append(event(BEGUN, p)).await?;
        self.flash
            .erase(p * size, (p + 1) * size)
            .await
            .map_err(JournaledError::Flash)?;
        self.append(event(DONE, p)).await
    }

    fn outside_journal(&self, from: u32, len: usize) -> Result<(), JournaledError<F::Error>> {
        let end = from.saturating_add(len as u32);
        if end <= self.journal.start || from >= self.journal.end {
            Ok(())
        } else {
            Err(JournaledError::Journal)
        }
    }
}

impl<F: NorFlash> ErrorType for Journaled<F> {
    type Error = JournaledError<F::Error>;
}

impl<F: NorFlash> ReadNorFlash for Journaled<F> {
    const READ_SIZE: usize = F::READ_SIZE;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.outside_journal(offset, bytes.len())?;
        self.flash.read(offset, bytes).await.map_err(JournaledError::Flash)
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash> NorFlash for Journaled<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let size = F::ERASE_SIZE as u32;
        if from > to || !from.is_multiple_of(size) || !to.is_multiple_of(size) {
            // Passed on: the flash names what is wrong with it.
            return self.flash.erase(from, to).await.map_err(JournaledError::Flash);
        }
        self.outside_journal(from, (to - from) as usize)?;
        // A page at a time, each announced in the journal.
        for p in from / size..to / size {
            self.erase_page(p).await?;
        }
        Ok(())
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.outside_journal(offset, bytes.len())?;
        self.flash.write(offset, bytes).await.map_err(JournaledError::Flash)
    }
}
