//! The STM32F405's internal flash as a NOR flash for the settings store
//! (`fc-storage`): sector erase and 32-bit programming through the flash
//! interface's registers (RM0090 §3.5–3.9), within a range of whole,
//! equal sectors that holds neither the image nor the Crazyflie's
//! bootloader.
//!
//! The driver talks to the controller through [`FlashRegs`]; on the chip
//! that is the PAC's `FLASH` block, on the host a model of RM0090's rules
//! (the tests below). QEMU's netduinoplus2 models no flash controller, so
//! the images there keep their settings in a RAM stand-in instead
//! (`fc_storage::RamFlash`); only silicon can show this driver erasing and
//! programming, and the timings below are the datasheet's.
//!
//! Erasing stalls every flash read, code fetches included, for up to 2 s
//! (a 128 KiB sector, DS8626 table 43): the caller erases only on the
//! ground with the watchdog widened, never in flight.

use core::ops::Range;
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// `FLASH_KEYR`'s unlock sequence (RM0090 §3.5.1).
pub const KEYS: [u32; 2] = [0x4567_0123, 0xCDEF_89AB];

/// `FLASH_SR` bits.
pub mod sr {
    /// End of operation.
    pub const EOP: u32 = 1 << 0;
    /// Operation error.
    pub const OPERR: u32 = 1 << 1;
    /// Write protection error.
    pub const WRPERR: u32 = 1 << 4;
    /// Programming alignment error.
    pub const PGAERR: u32 = 1 << 5;
    /// Programming parallelism error (access size ≠ PSIZE).
    pub const PGPERR: u32 = 1 << 6;
    /// Programming sequence error (a write with CR not set for it).
    pub const PGSERR: u32 = 1 << 7;
    /// Busy.
    pub const BSY: u32 = 1 << 16;
    /// Every error flag (written 1 to clear).
    pub const ERRORS: u32 = OPERR | WRPERR | PGAERR | PGPERR | PGSERR;
}

/// `FLASH_CR` bits.
pub mod cr {
    /// Programming.
    pub const PG: u32 = 1 << 0;
    /// Sector erase.
    pub const SER: u32 = 1 << 1;
    /// Sector number, bits 3–6.
    pub const SNB_SHIFT: u32 = 3;
    /// Program size x32 (PSIZE = 0b10, bits 8–9): 2.7–3.6 V.
    pub const PSIZE_X32: u32 = 0b10 << 8;
    /// The PSIZE field.
    pub const PSIZE_MASK: u32 = 0b11 << 8;
    /// Start (the erase).
    pub const STRT: u32 = 1 << 16;
    /// Locked (set again to lock; cleared by the key sequence).
    pub const LOCK: u32 = 1 << 31;
}

/// The STM32F405's sectors (RM0090 table 5, 1 MiB, one bank): start
/// address and size.
pub const SECTORS: [(u32, u32); 12] = [
    (0x0800_0000, 16 << 10),
    (0x0800_4000, 16 << 10),
    (0x0800_8000, 16 << 10),
    (0x0800_C000, 16 << 10),
    (0x0801_0000, 64 << 10),
    (0x0802_0000, 128 << 10),
    (0x0804_0000, 128 << 10),
    (0x0806_0000, 128 << 10),
    (0x0808_0000, 128 << 10),
    (0x080A_0000, 128 << 10),
    (0x080C_0000, 128 << 10),
    (0x080E_0000, 128 << 10),
];

/// Where both boards keep their settings: sectors 9 to 11, the top
/// 384 KiB (the images are linked below it; the Crazyflie's bootloader is
/// sector 0 and its image starts at sector 1): sector 9 the store's erase
/// journal ([`STORAGE_JOURNAL`]), sectors 10 and 11 the store
/// ([`STORAGE_STORE`]).
pub const STORAGE: Range<u32> = 0x080A_0000..0x0810_0000;

/// The store's erase journal (`fc_storage::Journaled`), as offsets in
/// [`STORAGE`]: sector 9.
pub const STORAGE_JOURNAL: Range<u32> = 0..(128 << 10);

/// The store, as offsets in [`STORAGE`]: sectors 10 and 11.
pub const STORAGE_STORE: Range<u32> = (128 << 10)..(384 << 10);

/// The Crazyflie 2.1's bootloader: sector 0, never erased.
pub const CRAZYFLIE_BOOTLOADER: Range<u32> = 0x0800_0000..0x0800_4000;

/// The stand-in the images built for QEMU keep their settings in (QEMU
/// models no flash controller). Bytes of RAM: two 1 KiB pages, room for
/// every parameter.
pub const STAND_IN_BYTES: usize = 2048;

/// The settings store over the stand-in ([`STAND_IN_BYTES`] of RAM, lost
/// at power-off).
pub type StandInStore = fc_storage::Store<fc_storage::RamFlash<STAND_IN_BYTES>>;

/// The boot log's words for the stand-in.
pub const STAND_IN_NOTE: &str = "a 2 KiB RAM stand-in (QEMU models no flash controller): settings last until power-off";

/// The boot log's words for the board's flash.
pub const BOARD_NOTE: &str = "flash sectors 10-11, their erase journal in sector 9 (written only while disarmed)";

/// A settings store written only on the ground: a write while `armed`
/// reads true is refused ([`fc_storage::StoreError::Armed`]), since
/// programming and erasing stall every flash read, the control loop's
/// code included (an erase for up to 2 s); around each write `widen(true)`
/// and `widen(false)` widen the watchdog's timeout and set it back. Reads
/// pass through.
pub struct Grounded<S> {
    /// The store.
    pub store: S,
    /// Whether the vehicle is armed (the image's link task keeps it).
    pub armed: &'static core::sync::atomic::AtomicBool,
    /// Widens the watchdog (true) or sets it back (false).
    pub widen: fn(bool),
}

impl<S: fc_storage::Persist> Grounded<S> {
    fn write<T>(
        &mut self,
        f: impl FnOnce(&mut S) -> Result<T, fc_storage::StoreError>,
    ) -> Result<T, fc_storage::StoreError> {
        if self.armed.load(core::sync::atomic::Ordering::Relaxed) {
            return Err(fc_storage::StoreError::Armed);
        }
        (self.widen)(true);
        let r = f(&mut self.store);
        (self.widen)(false);
        r
    }
}

impl<S: fc_storage::Persist> fc_storage::Persist for Grounded<S> {
    fn param(&mut self, index: u16) -> Result<Option<f32>, fc_storage::StoreError> {
        self.store.param(index)
    }
    fn set_param(&mut self, index: u16, value: f32) -> Result<(), fc_storage::StoreError> {
        self.write(|s| s.set_param(index, value))
    }
    fn remove_param(&mut self, index: u16) -> Result<(), fc_storage::StoreError> {
        self.write(|s| s.remove_param(index))
    }
    fn signing(&mut self) -> Result<Option<([u8; 32], u64)>, fc_storage::StoreError> {
        self.store.signing()
    }
    fn set_signing(&mut self, key: &[u8; 32], timestamp: u64) -> Result<(), fc_storage::StoreError> {
        self.write(|s| s.set_signing(key, timestamp))
    }
}

/// The board's flash below the settings' sectors: where the images are
/// linked (`memory.x`), the Crazyflie's bootloader included.
pub const IMAGES: Range<u32> = 0x0800_0000..STORAGE.start;

/// The board's settings flash ([`STORAGE`], 128 KiB sectors) through the
/// flash interface `R`, its erases journaled in [`STORAGE_JOURNAL`].
pub type BoardFlash<R> = fc_storage::Journaled<F4Flash<R, { 128 << 10 }>>;

/// The settings store in the board's flash, sectors 10–11, its erase
/// journal in sector 9.
#[cfg(target_os = "none")]
pub type BoardStore = fc_storage::Store<BoardFlash<Registers>>;

/// Opens the settings store over the flash interface `regs`
/// ([`STORAGE_STORE`] of [`STORAGE`]), an erase a power cut left undone
/// first finished from the journal ([`STORAGE_JOURNAL`]).
pub fn open_store<R: FlashRegs>(
    regs: R,
) -> Result<(fc_storage::Store<BoardFlash<R>>, fc_storage::Boot), fc_storage::StoreError> {
    let flash = F4Flash::new(regs, STORAGE, IMAGES).map_err(|_| fc_storage::StoreError::BadRange)?;
    let (flash, _) = fc_storage::Journaled::open(flash, STORAGE_JOURNAL).map_err(|e| match e {
        fc_storage::JournaledError::Journal => fc_storage::StoreError::BadRange,
        fc_storage::JournaledError::Flash(_) => fc_storage::StoreError::Flash,
    })?;
    fc_storage::Store::open(flash, STORAGE_STORE)
}

/// What an image keeps its settings in: built for QEMU (the `qemu`
/// feature) the RAM stand-in, for a board the flash; either written only
/// while disarmed ([`Grounded`]).
#[cfg(all(target_os = "none", feature = "qemu"))]
pub type Kept = Grounded<StandInStore>;
/// What an image keeps its settings in: built for QEMU (the `qemu`
/// feature) the RAM stand-in, for a board the flash; either written only
/// while disarmed ([`Grounded`]).
#[cfg(all(target_os = "none", not(feature = "qemu")))]
pub type Kept = Grounded<BoardStore>;

/// Opens the image's settings store ([`Kept`]) at boot and says on the
/// log what backs it and what it found; `None` (logged) if it cannot be
/// opened. `armed` and `widen` as [`Grounded`]'s.
///
/// Inlined into the image, so that the store's code is built once there
/// (a copy built here as well cost ≈ 10 KiB of flash).
#[cfg(target_os = "none")]
#[inline]
pub fn open_settings(armed: &'static core::sync::atomic::AtomicBool, widen: fn(bool)) -> Option<Kept> {
    #[cfg(feature = "qemu")]
    let (opened, note) = (
        fc_storage::Store::open(fc_storage::RamFlash::blank(), 0..STAND_IN_BYTES as u32),
        STAND_IN_NOTE,
    );
    #[cfg(not(feature = "qemu"))]
    let (opened, note) = (open_board_store(), BOARD_NOTE);
    match opened {
        Ok((store, boot)) => {
            defmt::info!("storage: {=str}; {}", note, defmt::Display2Format(&boot));
            Some(Grounded { store, armed, widen })
        }
        Err(e) => {
            defmt::warn!("storage: none, settings are not kept ({})", defmt::Display2Format(&e));
            None
        }
    }
}

/// Opens the settings store in the board's flash ([`STORAGE`]), saying
/// what it found. At boot: an erase here (foreign contents) runs before
/// the watchdog starts.
#[cfg(target_os = "none")]
#[inline]
pub fn open_board_store() -> Result<(BoardStore, fc_storage::Boot), fc_storage::StoreError> {
    open_store(Registers)
}

/// Polls of `FLASH_SR` before a sector erase is given up: at ≥ 4 cycles a
/// poll, ≥ 2.4 s at 168 MHz, above the 2 s a 128 KiB sector takes at most
/// (DS8626 table 43, x32).
pub const ERASE_POLLS: u32 = 100_000_000;
/// Polls before a word's programming is given up (100 µs at most).
pub const PROGRAM_POLLS: u32 = 100_000;

/// The flash interface's registers and the flash memory, as the driver
/// uses them.
pub trait FlashRegs {
    /// Reads `FLASH_SR`.
    fn sr(&mut self) -> u32;
    /// Writes `FLASH_SR` (1 clears a flag).
    fn write_sr(&mut self, v: u32);
    /// Reads `FLASH_CR`.
    fn cr(&mut self) -> u32;
    /// Writes `FLASH_CR`.
    fn write_cr(&mut self, v: u32);
    /// Writes `FLASH_KEYR`.
    fn write_keyr(&mut self, v: u32);
    /// A 32-bit write to the flash at `addr` (what programs a word).
    fn write_word(&mut self, addr: u32, word: u32);
    /// Reads the flash from `addr` into `buf`.
    fn read(&mut self, addr: u32, buf: &mut [u8]);
}

/// Why the flash did not do what was asked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlashError {
    /// The range is not whole sectors of one size, or it overlaps what must
    /// not be erased (the image, the bootloader).
    BadRange,
    /// An access outside the range.
    OutOfBounds,
    /// Not on a word (write) or sector (erase) boundary.
    NotAligned,
    /// `FLASH_CR` stayed locked after the key sequence (a wrong key locks
    /// it until reset).
    Locked,
    /// The controller stayed busy past the poll bound.
    Timeout,
    /// The controller reported an error: `FLASH_SR`'s error flags.
    Controller(u32),
    /// A word read back other than written (a bit that was already 0 where
    /// the data has a 1: the word was not erased).
    Verify,
}

impl core::fmt::Display for FlashError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FlashError::BadRange => write!(f, "the storage range is not whole equal sectors clear of the image"),
            FlashError::OutOfBounds => write!(f, "flash access outside the storage range"),
            FlashError::NotAligned => write!(f, "flash access not aligned to a word or sector"),
            FlashError::Locked => write!(f, "the flash controller stayed locked"),
            FlashError::Timeout => write!(f, "the flash controller stayed busy"),
            FlashError::Controller(sr) => write!(f, "the flash controller reported errors (SR {sr:#x})"),
            FlashError::Verify => write!(f, "a programmed word read back wrong"),
        }
    }
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::OutOfBounds | FlashError::BadRange => NorFlashErrorKind::OutOfBounds,
            FlashError::NotAligned => NorFlashErrorKind::NotAligned,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The sector holding `addr`: its number and range.
pub fn sector_of(addr: u32) -> Option<(u8, Range<u32>)> {
    SECTORS
        .iter()
        .enumerate()
        .find(|(_, &(start, size))| (start..start + size).contains(&addr))
        .map(|(i, &(start, size))| (i as u8, start..start + size))
}

/// `range` of the flash, whole sectors of `SECTOR` bytes each, as a NOR
/// flash (offsets from its start).
pub struct F4Flash<R: FlashRegs, const SECTOR: usize> {
    regs: R,
    range: Range<u32>,
}

impl<R: FlashRegs, const SECTOR: usize> F4Flash<R, SECTOR> {
    /// The flash in `range` (absolute addresses): whole sectors, every one
    /// `SECTOR` bytes, none overlapping `keep` (the image's flash, and on
    /// the Crazyflie its bootloader: [`CRAZYFLIE_BOOTLOADER`] lies below its
    /// image, so `keep` starting at 0x0800_0000 covers both).
    pub fn new(regs: R, range: Range<u32>, keep: Range<u32>) -> Result<Self, FlashError> {
        let mut at = range.start;
        while at < range.end {
            match sector_of(at) {
                Some((_, s)) if s.start == at && (s.end - s.start) as usize == SECTOR => at = s.end,
                _ => return Err(FlashError::BadRange),
            }
        }
        let overlaps = range.start < keep.end && keep.start < range.end;
        if range.is_empty() || at != range.end || overlaps {
            return Err(FlashError::BadRange);
        }
        Ok(Self { regs, range })
    }

    /// The registers back.
    pub fn into_regs(self) -> R {
        self.regs
    }

    fn span(&self, offset: u32, len: usize) -> Result<u32, FlashError> {
        let size = self.range.end - self.range.start;
        match offset.checked_add(len as u32) {
            Some(end) if end <= size => Ok(self.range.start + offset),
            _ => Err(FlashError::OutOfBounds),
        }
    }

    /// Waits (at most `polls` reads) for BSY to clear; then the error
    /// flags, cleared, as an error.
    fn wait(&mut self, polls: u32) -> Result<(), FlashError> {
        let mut n = 0;
        while self.regs.sr() & sr::BSY != 0 {
            n += 1;
            if n >= polls {
                return Err(FlashError::Timeout);
            }
        }
        let s = self.regs.sr();
        self.regs.write_sr(s & (sr::ERRORS | sr::EOP));
        match s & sr::ERRORS {
            0 => Ok(()),
            e => Err(FlashError::Controller(e)),
        }
    }

    /// Unlocks `FLASH_CR` (after any operation under way), errors of an
    /// earlier operation cleared.
    fn unlock(&mut self) -> Result<(), FlashError> {
        self.wait(ERASE_POLLS).or_else(|e| match e {
            FlashError::Controller(_) => Ok(()),
            e => Err(e),
        })?;
        if self.regs.cr() & cr::LOCK != 0 {
            self.regs.write_keyr(KEYS[0]);
            self.regs.write_keyr(KEYS[1]);
        }
        if self.regs.cr() & cr::LOCK != 0 {
            return Err(FlashError::Locked);
        }
        Ok(())
    }

    /// Locks `FLASH_CR` again, whatever `r` was, and returns `r`.
    fn lock<T>(&mut self, r: Result<T, FlashError>) -> Result<T, FlashError> {
        self.regs.write_cr(cr::LOCK);
        r
    }

    fn erase_sector(&mut self, n: u8) -> Result<(), FlashError> {
        let c = cr::PSIZE_X32 | cr::SER | (u32::from(n) << cr::SNB_SHIFT);
        self.regs.write_cr(c);
        self.regs.write_cr(c | cr::STRT);
        self.wait(ERASE_POLLS)
    }

    fn program(&mut self, addr: u32, bytes: &[u8]) -> Result<(), FlashError> {
        self.regs.write_cr(cr::PSIZE_X32 | cr::PG);
        for (k, w) in bytes.chunks_exact(4).enumerate() {
            let a = addr + 4 * k as u32;
            let word = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
            self.regs.write_word(a, word);
            self.wait(PROGRAM_POLLS)?;
            let mut back = [0u8; 4];
            self.regs.read(a, &mut back);
            if u32::from_le_bytes(back) != word {
                return Err(FlashError::Verify);
            }
        }
        Ok(())
    }
}

impl<R: FlashRegs, const SECTOR: usize> ErrorType for F4Flash<R, SECTOR> {
    type Error = FlashError;
}

impl<R: FlashRegs, const SECTOR: usize> ReadNorFlash for F4Flash<R, SECTOR> {
    const READ_SIZE: usize = 1;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let a = self.span(offset, bytes.len())?;
        self.regs.read(a, bytes);
        Ok(())
    }
    fn capacity(&self) -> usize {
        (self.range.end - self.range.start) as usize
    }
}

impl<R: FlashRegs, const SECTOR: usize> NorFlash for F4Flash<R, SECTOR> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SECTOR;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if from > to {
            return Err(FlashError::OutOfBounds);
        }
        let start = self.span(from, (to - from) as usize)?;
        if !(from as usize).is_multiple_of(SECTOR) || !(to as usize).is_multiple_of(SECTOR) {
            return Err(FlashError::NotAligned);
        }
        self.unlock()?;
        let mut r = Ok(());
        let mut a = start;
        while a < start + (to - from) && r.is_ok() {
            r = match sector_of(a) {
                Some((n, _)) => self.erase_sector(n),
                None => Err(FlashError::OutOfBounds),
            };
            a += SECTOR as u32;
        }
        self.lock(r)
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let a = self.span(offset, bytes.len())?;
        if !offset.is_multiple_of(4) || !bytes.len().is_multiple_of(4) {
            return Err(FlashError::NotAligned);
        }
        self.unlock()?;
        let r = self.program(a, bytes);
        self.lock(r)
    }
}

/// The chip's flash interface (`FLASH` of the PAC) and its memory. One
/// owner: the settings store (the clock bring-up wrote `FLASH_ACR` before).
#[cfg(target_os = "none")]
pub struct Registers;

#[cfg(target_os = "none")]
impl Registers {
    fn block(&self) -> &'static stm32f4::stm32f405::flash::RegisterBlock {
        // SAFETY: a fixed MMIO address; `Registers` is its only user after
        // the clock bring-up.
        unsafe { &*stm32f4::stm32f405::FLASH::ptr() }
    }
}

#[cfg(target_os = "none")]
impl FlashRegs for Registers {
    fn sr(&mut self) -> u32 {
        self.block().sr().read().bits()
    }
    fn write_sr(&mut self, v: u32) {
        // SAFETY: every SR bit written is a write-1-to-clear flag.
        self.block().sr().write(|w| unsafe { w.bits(v) });
    }
    fn cr(&mut self) -> u32 {
        self.block().cr().read().bits()
    }
    fn write_cr(&mut self, v: u32) {
        // SAFETY: the values are RM0090's encodings (module `cr`).
        self.block().cr().write(|w| unsafe { w.bits(v) });
    }
    fn write_keyr(&mut self, v: u32) {
        // SAFETY: KEYR takes any value; a wrong key locks CR until reset.
        self.block().keyr().write(|w| unsafe { w.bits(v) });
    }
    fn write_word(&mut self, addr: u32, word: u32) {
        // SAFETY: `addr` is inside the storage range (F4Flash::span), word
        // aligned, and PG is set: the write programs that word.
        unsafe { core::ptr::write_volatile(addr as *mut u32, word) }
    }
    fn read(&mut self, addr: u32, buf: &mut [u8]) {
        for (i, b) in buf.iter_mut().enumerate() {
            // SAFETY: inside the storage range, which is mapped flash.
            *b = unsafe { core::ptr::read_volatile((addr as usize + i) as *const u8) };
        }
    }
}

#[cfg(test)]
mod tests;
