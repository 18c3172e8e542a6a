//! Power cuts at every byte written, and foreign or corrupt contents,
//! against a NOR flash model of this crate's own (not sequential-storage's).

use super::*;
use embedded_storage_async::nor_flash::{ErrorType, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// Erase page (bytes), pages, and the write unit of the model: the
/// STM32F4's 32-bit programming (PSIZE x32 at 2.7–3.6 V).
const PAGE: usize = 1024;
const PAGES: usize = 4;
const WORD: usize = 4;

/// A NOR flash whose power fails after `countdown` more bytes are
/// programmed or erased: the byte in flight and those after it are not
/// written or erased. After the cut every access fails, until
/// [`CutFlash::power_on`].
/// Writes a figure to `$FC_MEASUREMENTS` (as `e2e-tests`' `measure`,
/// which this crate cannot depend on: it depends on this one).
fn measure(key: &str, value: u32, unit: &str) {
    use std::io::Write;
    if let Some(path) = std::env::var_os("FC_MEASUREMENTS") {
        let line =
            format!("{{\"key\":\"{key}\",\"value\":{value},\"unit\":\"{unit}\",\"source\":\"fc-storage tests\"}}\n");
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .and_then(|mut f| f.write_all(line.as_bytes()))
            .expect("writing a measurement");
    }
}

#[derive(Clone)]
struct CutFlash {
    data: Vec<u8>,
    countdown: Option<u32>,
    off: bool,
    /// An erase cut short leaves the page in flight undefined (RM0090):
    /// each word erased, as it was, or random, from this seed. `None`: the
    /// bytes before the cut erased, the rest as they were.
    undefined: Option<u64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CutError {
    PowerOff,
    Misaligned,
}

impl NorFlashError for CutError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            CutError::Misaligned => NorFlashErrorKind::NotAligned,
            _ => NorFlashErrorKind::Other,
        }
    }
}

impl CutFlash {
    fn blank() -> Self {
        Self {
            data: vec![0xFF; PAGE * PAGES],
            countdown: None,
            off: false,
            undefined: None,
        }
    }
    /// Blank, with one more page (for an erase journal).
    fn blank_with_journal() -> Self {
        let mut f = Self::blank();
        f.data.resize(PAGE * (PAGES + 1), 0xFF);
        f
    }
    fn power_on(&mut self) {
        self.countdown = None;
        self.off = false;
    }
    /// One more byte (or an erase) spends the countdown: false if the power
    /// fails now.
    fn spend(&mut self) -> bool {
        match self.countdown.as_mut() {
            Some(0) => {
                self.off = true;
                false
            }
            Some(n) => {
                *n -= 1;
                true
            }
            None => true,
        }
    }
}

impl ErrorType for CutFlash {
    type Error = CutError;
}

impl ReadNorFlash for CutFlash {
    const READ_SIZE: usize = 1;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), CutError> {
        if self.off {
            return Err(CutError::PowerOff);
        }
        let o = offset as usize;
        bytes.copy_from_slice(&self.data[o..o + bytes.len()]);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.data.len()
    }
}

impl NorFlash for CutFlash {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = PAGE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), CutError> {
        if self.off {
            return Err(CutError::PowerOff);
        }
        let (from, to) = (from as usize, to as usize);
        if !from.is_multiple_of(PAGE) || !to.is_multiple_of(PAGE) {
            return Err(CutError::Misaligned);
        }
        // Erased a byte at a time, as sequential-storage's own model does:
        // a cut leaves the bytes before it erased and the rest as they were.
        // (A sector erase cut short leaves it undefined on the STM32F4; with
        // pseudo-random contents instead, this sweep loses a value: open.)
        for i in from..to {
            if !self.spend() {
                if let Some(seed) = self.undefined {
                    let page = i - i % PAGE;
                    undefine(&mut self.data[page..page + PAGE], seed);
                }
                return Err(CutError::PowerOff);
            }
            self.data[i] = 0xFF;
        }
        Ok(())
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), CutError> {
        if self.off {
            return Err(CutError::PowerOff);
        }
        let o = offset as usize;
        if !o.is_multiple_of(WORD) || !bytes.len().is_multiple_of(WORD) {
            return Err(CutError::Misaligned);
        }
        // Programming only clears bits. The STM32F4 (no ECC) lets a word be
        // programmed again, clearing more bits (RM0090 has no error for it).
        for (w, chunk) in bytes.chunks(WORD).enumerate() {
            let at = o + w * WORD;
            for (i, &b) in chunk.iter().enumerate() {
                if !self.spend() {
                    return Err(CutError::PowerOff);
                }
                self.data[at + i] &= b;
            }
        }
        Ok(())
    }
}

fn store(flash: CutFlash) -> Store<CutFlash> {
    Store::new(flash, 0..(PAGE * PAGES) as u32).unwrap()
}

/// What a sweep did: cut points tried (each a write cut short, then a
/// boot), values written.
#[derive(Debug, Default)]
struct Sweep {
    cuts: u32,
    values: u32,
}

/// For each of `values` successive writes by `write(store, k)`: the power
/// cut at every byte it programs, then a boot, after which `read` must give
/// the value before the write or the one it wrote (`expect(k - 1)` or
/// `expect(k)`), parameter 7 must still read 42 (nothing else lost), and
/// the store must take the write again.
fn sweep<T: PartialEq + core::fmt::Debug>(
    values: u32,
    write: impl Fn(&mut Store<CutFlash>, u32) -> Result<(), StoreError>,
    read: impl Fn(&mut Store<CutFlash>) -> Result<Option<T>, StoreError>,
    expect: impl Fn(u32) -> T,
) -> Sweep {
    let mut s = store(CutFlash::blank());
    s.set_param(7, 42.0).unwrap();
    write(&mut s, 0).unwrap();
    let mut flash = s.into_flash();
    let mut sweep = Sweep::default();
    for k in 1..=values {
        for cut in 0.. {
            let mut f = flash.clone();
            f.countdown = Some(cut);
            let mut s = store(f);
            let done = write(&mut s, k);
            let mut f = s.into_flash();
            if done.is_ok() && !f.off {
                break; // the write finished before the cut point
            }
            sweep.cuts += 1;
            f.power_on();
            let mut s = store(f);
            let got = read(&mut s).unwrap_or_else(|e| panic!("value {k}, cut at byte {cut}: {e}"));
            assert!(
                got == Some(expect(k - 1)) || got == Some(expect(k)),
                "value {k}, cut at byte {cut}: read {got:?}"
            );
            assert_eq!(
                s.param(7),
                Ok(Some(42.0)),
                "value {k}, cut at byte {cut}: another parameter lost"
            );
            write(&mut s, k).unwrap_or_else(|e| panic!("value {k}, cut at byte {cut}, then: {e}"));
            assert_eq!(read(&mut s), Ok(Some(expect(k))));
        }
        let mut s = store(flash);
        write(&mut s, k).unwrap();
        flash = s.into_flash();
        sweep.values += 1;
    }
    sweep
}

#[test]
fn a_parameter_survives_a_power_cut_at_every_byte_of_every_write() {
    // 400 writes of 16-byte items fill the 4 KiB store more than once: the
    // sweep crosses pages, their erases and the moves of live items.
    let v = |k: u32| k as f32 * 0.25 + 1.0;
    let s = sweep(400, |s, k| s.set_param(3, v(k)), |s| s.param(3), v);
    std::println!("parameter power-cut sweep: {s:?}");
    assert!(s.cuts > 400 * 8, "{s:?}");
    measure("storage_param_power_cuts", s.cuts, "cuts");
    measure("storage_param_power_cut_values", s.values, "values");
}

#[test]
fn the_signing_key_survives_a_power_cut_at_every_byte_of_every_write() {
    let v = |k: u32| ([(k % 251) as u8 + 1; 32], 1_000_000 + u64::from(k));
    let s = sweep(120, |s, k| s.set_signing(&v(k).0, v(k).1), |s| s.signing(), v);
    std::println!("signing-key power-cut sweep: {s:?}");
    assert!(s.cuts > 120 * 40, "{s:?}");
    measure("storage_key_power_cuts", s.cuts, "cuts");
    measure("storage_key_power_cut_values", s.values, "values");
}

/// The erase journal's page, after the store's.
const JOURNAL: core::ops::Range<u32> = (PAGE * PAGES) as u32..(PAGE * (PAGES + 1)) as u32;

/// What an erase-cut sweep did: cuts inside a page erase (the page then
/// undefined), cuts elsewhere, and values lost (a read that was neither the
/// value before the write nor the one written, another parameter changed, or
/// a store that would not take the write again).
#[derive(Debug, Default)]
struct EraseCuts {
    in_erase: u32,
    elsewhere: u32,
    lost: u32,
}

/// A flash model whose power can be cut after a count of bytes, an erase
/// cut short leaving its page undefined.
trait Cuttable: Clone {
    /// Cuts the power after `bytes` more bytes programmed or erased; an
    /// erase cut short leaves its page as `seed` makes it.
    fn cut_after(&mut self, bytes: u32, seed: u64);
    /// Whether the power was cut (accesses fail until [`Cuttable::power_on`]).
    fn was_cut(&self) -> bool;
    /// Power back: every access goes through again.
    fn power_on(&mut self);
    /// The whole contents.
    fn contents(&self) -> &[u8];
}

impl Cuttable for CutFlash {
    fn cut_after(&mut self, bytes: u32, seed: u64) {
        self.countdown = Some(bytes);
        self.undefined = Some(seed);
    }
    fn was_cut(&self) -> bool {
        self.off
    }
    fn power_on(&mut self) {
        CutFlash::power_on(self);
    }
    fn contents(&self) -> &[u8] {
        &self.data
    }
}

/// Each word of `page` erased, as it was, or random, from `seed` (what an
/// erase cut short leaves, RM0090).
fn undefine(page: &mut [u8], seed: u64) {
    let mut x = seed | 1;
    for w in page.chunks_mut(WORD) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        match x % 3 {
            0 => w.fill(0xFF),
            1 => {}
            _ => w.copy_from_slice(&(x >> 32).to_le_bytes()[..WORD]),
        }
    }
}

/// For each of `values` writes of parameter 3 (16-byte items, filling the
/// store several times over, so that pages are erased): the power cut at
/// every byte it programs or erases, an erase cut short leaving its page
/// undefined (a seed per cut); then a boot through `boot`, after which
/// parameter 3 must read the value before or the one written, parameter 7
/// its 42, and the store take the write again. `range`: the store's.
fn erase_cut_sweep<C: Cuttable, F: NorFlash>(
    values: u32,
    blank: C,
    range: core::ops::Range<u32>,
    boot: impl Fn(C) -> F,
    back: impl Fn(F) -> C,
) -> EraseCuts {
    let v = |k: u32| k as f32 * 0.5 + 1.0;
    let store = |f: C| Store::new(boot(f), range.clone()).unwrap();
    let mut s = store(blank);
    s.set_param(7, 42.0).unwrap();
    s.set_param(3, v(0)).unwrap();
    let mut flash = back(s.into_flash());
    let mut out = EraseCuts::default();
    for k in 1..=values {
        for cut in 0.. {
            let mut f = flash.clone();
            f.cut_after(cut, 0x9E37_79B9_7F4A_7C15 ^ (u64::from(k) << 32 | u64::from(cut)));
            let mut s = store(f);
            let done = s.set_param(3, v(k));
            let mut f = back(s.into_flash());
            if done.is_ok() && !f.was_cut() {
                break;
            }
            // Inside an erase if more changed than a write can.
            let changed = f
                .contents()
                .iter()
                .zip(flash.contents())
                .filter(|(a, b)| a != b)
                .count();
            if changed > 64 {
                out.in_erase += 1;
            } else {
                out.elsewhere += 1;
            }
            f.power_on();
            let mut s = store(f);
            let ok = matches!(s.param(3), Ok(Some(x)) if x == v(k - 1) || x == v(k))
                && s.param(7) == Ok(Some(42.0))
                && s.set_param(3, v(k)).is_ok()
                && s.param(3) == Ok(Some(v(k)));
            out.lost += u32::from(!ok);
        }
        let mut s = store(flash);
        s.set_param(3, v(k)).unwrap();
        flash = back(s.into_flash());
    }
    out
}

#[test]
fn an_erase_cut_short_loses_nothing_through_the_journal() {
    let range = 0..(PAGE * PAGES) as u32;
    let s = erase_cut_sweep(
        600,
        CutFlash::blank_with_journal(),
        range,
        |f| Journaled::open(f, JOURNAL).unwrap().0,
        |j| j.into_inner(),
    );
    std::println!("erase-cut sweep, journaled: {s:?}");
    assert_eq!(s.lost, 0, "{s:?}");
    assert!(s.in_erase > 1000, "{s:?}");
    measure("storage_erase_cuts", s.in_erase, "cuts");
    measure("storage_erase_cut_lost", s.lost, "values");
}

#[test]
fn without_the_journal_an_erase_cut_short_can_lose_a_value() {
    // The model bites: the same sweep over the flash itself.
    let s = erase_cut_sweep(600, CutFlash::blank(), 0..(PAGE * PAGES) as u32, |f| f, |f| f);
    std::println!("erase-cut sweep, no journal: {s:?}");
    assert!(s.lost > 0, "{s:?}");
}

/// sequential-storage's own mock flash (STM32-like: a word written again
/// only with zeros), an erase cut short leaving its page undefined.
#[derive(Clone)]
struct UndefinedMock {
    mock: sequential_storage::mock_flash::MockFlashBase<5, 4, 256>,
    seed: u64,
    cut: bool,
}

impl Cuttable for UndefinedMock {
    fn cut_after(&mut self, bytes: u32, seed: u64) {
        self.mock.bytes_until_shutoff = Some(bytes);
        self.seed = seed;
    }
    fn was_cut(&self) -> bool {
        self.cut
    }
    fn power_on(&mut self) {
        self.mock.bytes_until_shutoff = None;
        self.cut = false;
    }
    fn contents(&self) -> &[u8] {
        self.mock.as_bytes()
    }
}

impl ErrorType for UndefinedMock {
    type Error = sequential_storage::mock_flash::MockFlashError;
}

impl ReadNorFlash for UndefinedMock {
    const READ_SIZE: usize = 4;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.mock.read(offset, bytes).await
    }
    fn capacity(&self) -> usize {
        self.mock.capacity()
    }
}

impl NorFlash for UndefinedMock {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = 1024;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        use sequential_storage::mock_flash::MockFlashError;
        let r = self.mock.erase(from, to).await;
        if let Err(MockFlashError::EarlyShutoff(at, _)) = r {
            let page = at as usize / 1024 * 1024;
            undefine(&mut self.mock.as_bytes_mut()[page..page + 1024], self.seed);
        }
        self.note(r)
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let r = self.mock.write(offset, bytes).await;
        self.note(r)
    }
}

impl UndefinedMock {
    /// The mock lets accesses through again after its shutoff; a power
    /// cut does not: every access after it fails until power-on.
    fn note(
        &mut self,
        r: Result<(), sequential_storage::mock_flash::MockFlashError>,
    ) -> Result<(), sequential_storage::mock_flash::MockFlashError> {
        if matches!(r, Err(sequential_storage::mock_flash::MockFlashError::EarlyShutoff(..))) {
            self.cut = true;
            self.mock.bytes_until_shutoff = Some(0);
        }
        r
    }
}

#[test]
fn an_erase_cut_short_loses_nothing_on_the_crates_own_mock_flash() {
    use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};
    let blank = UndefinedMock {
        mock: MockFlashBase::new(WriteCountCheck::TwiceWithZero, None, true),
        seed: 0,
        cut: false,
    };
    let s = erase_cut_sweep(
        600,
        blank,
        0..4096,
        |f| Journaled::open(f, 4096..5120).unwrap().0,
        |j| j.into_inner(),
    );
    std::println!("erase-cut sweep on the crate's mock, journaled: {s:?}");
    assert_eq!(s.lost, 0, "{s:?}");
    assert!(s.in_erase > 1000, "{s:?}");
    measure("storage_crate_mock_erase_cuts", s.in_erase, "cuts");
}

#[test]
fn foreign_or_truncated_contents_boot_to_an_error_or_defaults_never_a_panic() {
    let mut noise = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        noise ^= noise << 13;
        noise ^= noise >> 7;
        noise ^= noise << 17;
        noise
    };
    // A valid store (with its mark), to truncate.
    let (mut s, _) = Store::open(CutFlash::blank(), 0..(PAGE * PAGES) as u32).unwrap();
    for k in 0..100u16 {
        s.set_param(k % 9, f32::from(k)).unwrap();
    }
    s.set_signing(&[3; 32], 99).unwrap();
    let valid = s.into_flash();
    let mut boots = [0u32; 3];
    for case in 0..300 {
        let mut f = if case % 2 == 0 {
            CutFlash::blank()
        } else {
            valid.clone()
        };
        match case % 3 {
            // Random bytes everywhere: another program's data, or noise.
            0 => f.data.iter_mut().for_each(|b| *b = next() as u8),
            // A store cut off at a random byte (a shorter file), the rest erased.
            1 => {
                let at = (next() as usize) % f.data.len();
                f.data[at..].fill(0xFF);
            }
            // A few flipped bits.
            _ => {
                for _ in 0..1 + next() % 8 {
                    let at = (next() as usize) % f.data.len();
                    f.data[at] ^= 1 << (next() % 8);
                }
            }
        }
        let (mut s, boot) = Store::open(f, 0..(PAGE * PAGES) as u32).unwrap();
        boots[match boot {
            Boot::Found => 0,
            Boot::Created => 1,
            Boot::Erased(_) => 2,
        }] += 1;
        if case % 3 == 0 {
            assert!(
                matches!(boot, Boot::Erased(_)),
                "case {case}: noise taken for a store ({boot:?})"
            );
        }
        // Whatever it held, the settings answer (a value, none, or an
        // error naming what is wrong) and a write is taken, after an erase
        // if the damage is in the store's own bookkeeping.
        let _ = (s.param(4), s.signing());
        if s.set_param(4, 1.5).is_err() {
            s.clear().unwrap();
            s.set_param(4, 1.5).unwrap();
        }
        assert_eq!(s.param(4), Ok(Some(1.5)), "case {case}");
    }
    std::println!(
        "foreign contents: found {}, created {}, erased {}",
        boots[0],
        boots[1],
        boots[2]
    );
    assert!(boots.iter().all(|&n| n > 0), "{boots:?}");
    measure("storage_foreign_contents_cases", boots.iter().sum(), "cases");
}

#[test]
fn open_keeps_a_store_and_makes_one_on_blank_flash() {
    let (mut s, boot) = Store::open(CutFlash::blank(), 0..(PAGE * PAGES) as u32).unwrap();
    assert_eq!(boot, Boot::Created);
    s.set_param(2, 0.5).unwrap();
    s.set_signing(&[9; 32], 77).unwrap();
    let (mut s, boot) = Store::open(s.into_flash(), 0..(PAGE * PAGES) as u32).unwrap();
    assert_eq!(boot, Boot::Found);
    assert_eq!((s.param(2), s.signing()), (Ok(Some(0.5)), Ok(Some(([9; 32], 77)))));
    assert!(Boot::Erased(StoreError::Corrupted).to_string().contains("defaults"));
}

#[test]
fn a_blank_store_is_empty_and_bad_ranges_are_refused() {
    let mut s = store(CutFlash::blank());
    assert_eq!((s.param(0), s.signing()), (Ok(None), Ok(None)));
    assert_eq!(s.param(SIGNING_KEY), Err(StoreError::Value));
    assert!(Store::new(CutFlash::blank(), 0..PAGE as u32).is_err(), "one page");
    assert!(
        Store::new(CutFlash::blank(), 0..(PAGE as u32 + 4)).is_err(),
        "not whole pages"
    );
    assert!(StoreError::Corrupted.to_string().contains("corrupt"));
}

#[test]
fn a_removed_parameter_reads_none_and_its_neighbours_stay() {
    let mut s = store(CutFlash::blank());
    s.set_param(3, 1.5).unwrap();
    s.set_param(4, -2.0).unwrap();
    s.remove_param(3).unwrap();
    assert_eq!((s.param(3), s.param(4)), (Ok(None), Ok(Some(-2.0))));
    // The marker is not a value anyone can store.
    assert_eq!(s.set_param(5, f32::from_bits(REMOVED)), Err(StoreError::Value));
    s.set_param(3, 0.25).unwrap();
    let mut s = store(s.into_flash());
    assert_eq!(s.param(3), Ok(Some(0.25)));
    // Through the trait the protocols use.
    let p: &mut dyn Persist = &mut s;
    p.remove_param(3).unwrap();
    assert_eq!(p.param(3), Ok(None));
}

#[test]
fn the_ram_stand_in_keeps_nor_rules_and_a_store() {
    let mut f = RamFlash::<2048>::blank();
    let b = |f: &mut RamFlash<2048>, at: u32, n: usize| {
        let mut v = vec![0u8; n];
        embassy_futures::block_on(f.read(at, &mut v)).map(|()| v)
    };
    embassy_futures::block_on(f.write(4, &[0x0F, 0xF0, 0xAA, 0x55])).unwrap();
    // A second write only clears bits.
    embassy_futures::block_on(f.write(4, &[0xFF, 0x0F, 0xFF, 0xFF])).unwrap();
    assert_eq!(b(&mut f, 4, 4).unwrap(), [0x0F, 0x00, 0xAA, 0x55]);
    assert_eq!(
        embassy_futures::block_on(f.write(2, &[0; 4])),
        Err(RamFlashError::NotAligned)
    );
    assert_eq!(
        embassy_futures::block_on(f.write(2046, &[0; 4])),
        Err(RamFlashError::OutOfBounds)
    );
    assert_eq!(
        embassy_futures::block_on(f.erase(0, 1000)),
        Err(RamFlashError::NotAligned)
    );
    assert_eq!(b(&mut f, 2047, 2), Err(RamFlashError::OutOfBounds));
    embassy_futures::block_on(f.erase(0, 1024)).unwrap();
    assert_eq!(b(&mut f, 4, 4).unwrap(), [0xFF; 4]);
    // The store over it, and a reboot from its bytes.
    let (mut s, boot) = Store::open(RamFlash::<2048>::blank(), 0..2048).unwrap();
    assert_eq!(boot, Boot::Created);
    s.set_param(1, 2.5).unwrap();
    let bytes = *s.into_flash().bytes();
    let (mut s, boot) = Store::open(RamFlash::<2048>::holding(&bytes), 0..2048).unwrap();
    assert_eq!((boot, s.param(1)), (Boot::Found, Ok(Some(2.5))));
}

/// The same power-cut sweep on `sequential-storage`'s own mock flash (its
/// `_test` feature: 4 pages of 1 KiB, 32-bit words, each word written once
/// between erases, a power-off point counted in bytes), a model this
/// project did not write: a parameter's successive writes, cut at every
/// byte, read back old or new, another parameter kept.
#[test]
fn a_parameter_survives_every_power_cut_on_the_crates_own_mock_flash() {
    use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};
    type Mock = MockFlashBase<4, 4, 256>;
    let range = Mock::FULL_FLASH_RANGE;
    let v = |k: u32| k as f32 * 0.5 - 3.0;
    let (mut s, boot) = Store::open(Mock::new(WriteCountCheck::OnceOnly, None, true), range.clone()).unwrap();
    assert_eq!(boot, Boot::Created);
    s.set_param(7, 42.0).unwrap();
    s.set_param(3, v(0)).unwrap();
    let mut flash = s.into_flash();
    let (mut cuts, values) = (0u32, 300u32);
    for k in 1..=values {
        for cut in 0.. {
            let mut f = flash.clone();
            f.bytes_until_shutoff = Some(cut);
            let mut s = Store::new(f, range.clone()).unwrap();
            let done = s.set_param(3, v(k));
            let mut f = s.into_flash();
            if done.is_ok() && f.bytes_until_shutoff.is_some() {
                break; // the write finished before the cut point
            }
            cuts += 1;
            // Power back on: the mock lets every access through again.
            f.bytes_until_shutoff = None;
            let mut s = Store::new(f, range.clone()).unwrap();
            let got = s
                .param(3)
                .unwrap_or_else(|e| panic!("value {k}, cut at byte {cut}: {e}"));
            assert!(
                got == Some(v(k - 1)) || got == Some(v(k)),
                "value {k}, cut at byte {cut}: read {got:?}"
            );
            assert_eq!(s.param(7), Ok(Some(42.0)), "value {k}, cut at byte {cut}");
            s.set_param(3, v(k))
                .unwrap_or_else(|e| panic!("value {k}, cut at byte {cut}, then: {e}"));
            assert_eq!(s.param(3), Ok(Some(v(k))));
        }
        let mut s = Store::new(flash, range.clone()).unwrap();
        s.set_param(3, v(k)).unwrap();
        flash = s.into_flash();
    }
    std::println!("crate mock power-cut sweep: {cuts} cuts over {values} values");
    assert!(cuts > values * 8, "{cuts}");
    measure("storage_crate_mock_power_cuts", cuts, "cuts");
    measure("storage_crate_mock_power_cut_values", values, "values");
}
