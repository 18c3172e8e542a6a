//! The driver against a model of the STM32F4's flash interface written
//! from RM0090 (§3.5 unlocking, §3.6 erase and program sequences, §3.9
//! registers), not from the driver: what the model refuses, the chip
//! refuses.

use super::*;
use fc_storage::{Boot, Store};

const BASE: u32 = 0x0800_0000;
const SIZE: usize = 1 << 20;
/// Everything below the storage: the images' flash (and the Crazyflie's
/// bootloader, in sector 0).
const IMAGE: Range<u32> = BASE..STORAGE.start;

/// The flash interface as RM0090 describes it, with the flash behind it.
struct Model {
    mem: Vec<u8>,
    sr: u32,
    cr: u32,
    /// Keys written since the last unlock or reset.
    keys: Vec<u32>,
    /// A wrong key sequence: CR locked until reset (§3.5.1).
    locked_until_reset: bool,
    /// Reads of SR that still show BSY; `None`: busy for ever (a stuck controller).
    busy: Option<u32>,
    /// How many SR reads an operation keeps BSY set.
    op_polls: u32,
    /// Write-protected sectors (option bytes' nWRP).
    protected: Vec<u8>,
    /// What a real chip would not have taken quietly.
    violations: Vec<String>,
    /// Sectors erased, in order.
    erased: Vec<u8>,
}

impl Model {
    fn new() -> Self {
        Self {
            mem: vec![0xFF; SIZE],
            sr: 0,
            cr: cr::LOCK,
            keys: Vec::new(),
            locked_until_reset: false,
            busy: Some(0),
            op_polls: 3,
            protected: Vec::new(),
            violations: Vec::new(),
            erased: Vec::new(),
        }
    }
    fn bsy(&self) -> bool {
        self.busy != Some(0)
    }
    fn start_op(&mut self) {
        if self.busy.is_some() {
            self.busy = Some(self.op_polls);
        }
    }
    fn flag(&mut self, f: u32) {
        self.sr |= f;
    }
    fn at(&self, addr: u32) -> Option<usize> {
        let i = addr.checked_sub(BASE)? as usize;
        (i < SIZE).then_some(i)
    }
}

impl FlashRegs for Model {
    fn sr(&mut self) -> u32 {
        let bsy = self.bsy();
        if let Some(n) = self.busy.as_mut() {
            *n = n.saturating_sub(1);
        }
        self.sr | if bsy { sr::BSY } else { 0 }
    }
    fn write_sr(&mut self, v: u32) {
        // rc_w1: a 1 clears the flag; BSY is read-only.
        self.sr &= !(v & (sr::ERRORS | sr::EOP));
    }
    fn cr(&mut self) -> u32 {
        self.cr
    }
    fn write_cr(&mut self, v: u32) {
        if self.bsy() {
            self.violations.push(format!("CR written ({v:#x}) while busy"));
            return;
        }
        if self.cr & cr::LOCK != 0 {
            // Locked: not writable (§3.5.1); setting LOCK again is harmless.
            if v != cr::LOCK {
                self.violations.push(format!("CR written ({v:#x}) while locked"));
            }
            return;
        }
        self.cr = v;
        if v & cr::STRT != 0 {
            self.cr &= !cr::STRT;
            if v & cr::SER == 0 || v & cr::PG != 0 {
                self.flag(sr::PGSERR);
                return;
            }
            if v & cr::PSIZE_MASK != cr::PSIZE_X32 {
                self.violations.push("erase without PSIZE x32 (2.7-3.6 V)".into());
            }
            let n = ((v >> cr::SNB_SHIFT) & 0xF) as u8;
            let Some(&(start, size)) = SECTORS.get(usize::from(n)) else {
                self.flag(sr::OPERR);
                return;
            };
            if self.protected.contains(&n) {
                self.flag(sr::WRPERR);
                return;
            }
            let i = (start - BASE) as usize;
            self.mem[i..i + size as usize].fill(0xFF);
            self.erased.push(n);
            self.start_op();
            self.flag(sr::EOP);
        }
    }
    fn write_keyr(&mut self, v: u32) {
        if self.locked_until_reset {
            return;
        }
        self.keys.push(v);
        let k = self.keys.len();
        if self.keys[k - 1] != KEYS[k - 1] {
            // A wrong key: bus error, CR locked until the next reset.
            self.locked_until_reset = true;
            return;
        }
        if k == 2 {
            self.cr &= !cr::LOCK;
            self.keys.clear();
        }
    }
    fn write_word(&mut self, addr: u32, word: u32) {
        if self.bsy() {
            self.violations.push(format!("flash written at {addr:#x} while busy"));
            return;
        }
        if self.cr & cr::LOCK != 0 || self.cr & cr::PG == 0 || self.cr & cr::SER != 0 {
            self.flag(sr::PGSERR);
            return;
        }
        if self.cr & cr::PSIZE_MASK != cr::PSIZE_X32 {
            self.flag(sr::PGPERR);
            return;
        }
        if !addr.is_multiple_of(4) {
            self.flag(sr::PGAERR);
            return;
        }
        let Some(i) = self.at(addr) else {
            self.violations.push(format!("write outside the flash at {addr:#x}"));
            return;
        };
        let (n, _) = sector_of(addr).unwrap();
        if self.protected.contains(&n) {
            self.flag(sr::WRPERR);
            return;
        }
        // Programming clears bits only (no ECC on the F4: a second write ANDs).
        for (k, b) in word.to_le_bytes().iter().enumerate() {
            self.mem[i + k] &= b;
        }
        self.start_op();
        self.flag(sr::EOP);
    }
    fn read(&mut self, addr: u32, buf: &mut [u8]) {
        if self.bsy() {
            self.violations
                .push(format!("flash read at {addr:#x} while busy (the bus stalls)"));
        }
        let i = self.at(addr).expect("a read inside the flash");
        buf.copy_from_slice(&self.mem[i..i + buf.len()]);
    }
}

type Flash = F4Flash<Model, { 128 << 10 }>;

/// The store's own sectors, 10-11 (without the journal's, 9).
const STORE_SECTORS: Range<u32> = STORAGE.start + STORAGE_STORE.start..STORAGE.start + STORAGE_STORE.end;

fn storage(m: Model) -> Flash {
    F4Flash::new(m, STORE_SECTORS, IMAGE).unwrap()
}

#[test]
fn the_sector_map_is_rm0090s() {
    let mut at = BASE;
    for &(start, size) in &SECTORS {
        assert_eq!(start, at);
        at += size;
    }
    assert_eq!(at - BASE, 1 << 20, "1 MiB");
    assert_eq!(sector_of(0x0800_3FFF).map(|s| s.0), Some(0));
    assert_eq!(sector_of(0x0800_4000).map(|s| s.0), Some(1));
    assert_eq!(sector_of(0x080C_0000).map(|s| s.0), Some(10));
    assert_eq!(sector_of(0x0810_0000), None);
    assert_eq!(CRAZYFLIE_BOOTLOADER, SECTORS[0].0..SECTORS[1].0);
}

#[test]
fn only_whole_equal_sectors_clear_of_the_image_are_taken() {
    let new16 = |r: Range<u32>, keep: Range<u32>| F4Flash::<Model, { 16 << 10 }>::new(Model::new(), r, keep).err();
    let new128 = |r: Range<u32>, keep: Range<u32>| F4Flash::<Model, { 128 << 10 }>::new(Model::new(), r, keep).err();
    assert_eq!(new128(STORAGE, IMAGE), None);
    // The Crazyflie image (from sector 1) with its bootloader below it.
    assert_eq!(new128(STORAGE, CRAZYFLIE_BOOTLOADER.start..STORAGE.start), None);
    // Sectors 1-2 are whole 16 KiB sectors, but the bootloader's image lives there.
    assert_eq!(
        new16(0x0800_4000..0x0800_C000, 0x0800_0000..0x0801_0000),
        Some(FlashError::BadRange)
    );
    assert_eq!(new16(0x0800_4000..0x0800_C000, 0x0801_0000..0x080C_0000), None);
    // Sector 0: the bootloader.
    assert_eq!(
        new16(0x0800_0000..0x0800_8000, CRAZYFLIE_BOOTLOADER),
        Some(FlashError::BadRange)
    );
    // Mixed sizes, part of a sector, empty, past the end.
    assert_eq!(new16(0x0800_C000..0x0802_0000, 0..0), Some(FlashError::BadRange));
    assert_eq!(new128(0x080C_0000..0x080D_0000, 0..0), Some(FlashError::BadRange));
    assert_eq!(new128(0x080C_0000..0x080C_0000, 0..0), Some(FlashError::BadRange));
    assert_eq!(new128(0x080E_0000..0x0812_0000, 0..0), Some(FlashError::BadRange));
}

#[test]
fn the_settings_store_runs_on_it_and_survives_a_reset() {
    // The boards' layout: the store in sectors 10-11, its erase journal in 9.
    let (mut s, boot) = open_store(Model::new()).unwrap();
    assert_eq!(boot, Boot::Created);
    for k in 0..300u16 {
        s.set_param(k % 40, f32::from(k)).unwrap();
    }
    s.set_signing(&[3; 32], 1234).unwrap();
    let m = s.into_flash().into_inner().into_regs();
    assert!(m.violations.is_empty(), "{:?}", m.violations);
    assert_eq!(m.cr & cr::LOCK, cr::LOCK, "locked again after every operation");
    // Blank at first: only the journal was erased (to be marked).
    assert_eq!(m.erased, [9], "{:?}", m.erased);
    // A reset: the flash keeps its bytes; the controller starts locked.
    let mut m2 = Model::new();
    m2.mem = m.mem;
    let (mut s, boot) = open_store(m2).unwrap();
    assert_eq!(boot, Boot::Found);
    assert_eq!((s.param(19), s.param(39)), (Ok(Some(299.0)), Ok(Some(279.0))));
    assert_eq!(s.signing(), Ok(Some(([3; 32], 1234))));
}

#[test]
fn sectors_erase_and_words_program_by_rm0090s_sequence() {
    let mut f = storage(Model::new());
    let b = |f: &mut Flash, at: u32| {
        let mut v = [0u8; 4];
        embassy_futures::block_on(f.read(at, &mut v)).map(|()| v)
    };
    embassy_futures::block_on(f.write(8, &[1, 2, 3, 4, 5, 6, 7, 8])).unwrap();
    assert_eq!(b(&mut f, 8), Ok([1, 2, 3, 4]));
    assert_eq!(b(&mut f, 12), Ok([5, 6, 7, 8]));
    // A word not erased cannot take a 1 back: read back, refused.
    assert_eq!(
        embassy_futures::block_on(f.write(8, &[0xFF; 4])),
        Err(FlashError::Verify)
    );
    assert_eq!(
        embassy_futures::block_on(f.write(2, &[0; 4])),
        Err(FlashError::NotAligned)
    );
    assert_eq!(embassy_futures::block_on(f.erase(0, 4096)), Err(FlashError::NotAligned));
    assert_eq!(
        embassy_futures::block_on(f.write(256 << 10, &[0; 4])),
        Err(FlashError::OutOfBounds)
    );
    embassy_futures::block_on(f.erase(0, 128 << 10)).unwrap();
    assert_eq!(b(&mut f, 8), Ok([0xFF; 4]));
    let m = f.into_regs();
    assert_eq!(m.erased, [10]);
    assert!(m.violations.is_empty(), "{:?}", m.violations);
}

#[test]
fn a_controller_that_fails_is_an_error_never_a_hang() {
    // Stuck busy: the poll bound ends the wait.
    let mut m = Model::new();
    m.busy = None;
    let mut f = storage(m);
    assert_eq!(embassy_futures::block_on(f.write(0, &[0; 4])), Err(FlashError::Timeout));
    // Write-protected sectors: WRPERR, named.
    let mut m = Model::new();
    m.protected = vec![10, 11];
    let mut f = storage(m);
    assert_eq!(
        embassy_futures::block_on(f.write(0, &[0; 4])),
        Err(FlashError::Controller(sr::WRPERR))
    );
    assert_eq!(
        embassy_futures::block_on(f.erase(0, 128 << 10)),
        Err(FlashError::Controller(sr::WRPERR))
    );
    // An earlier error flag does not fail the next operation.
    f.regs.protected.clear();
    f.regs.sr |= sr::PGSERR;
    assert_eq!(embassy_futures::block_on(f.write(0, &[0; 4])), Ok(()));
    // Locked until reset (a wrong key earlier): Locked, and the store says
    // the flash failed.
    let mut m = Model::new();
    m.locked_until_reset = true;
    assert_eq!(
        embassy_futures::block_on(storage(m).write(0, &[0; 4])),
        Err(FlashError::Locked)
    );
    let mut m = Model::new();
    m.locked_until_reset = true;
    assert!(Store::open(storage(m), 0..(256 << 10)).is_err());
    assert!(FlashError::Controller(sr::WRPERR).to_string().contains("SR 0x10"));
}

static ARMED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
static WIDENED: std::sync::Mutex<Vec<bool>> = std::sync::Mutex::new(Vec::new());

#[test]
fn the_board_store_writes_only_disarmed_with_the_watchdog_widened() {
    use core::sync::atomic::Ordering;
    use fc_storage::{Persist, StoreError};
    let (store, _) = Store::open(storage(Model::new()), 0..(256 << 10)).unwrap();
    let mut g = Grounded {
        store,
        armed: &ARMED,
        widen: |on| WIDENED.lock().unwrap().push(on),
    };
    g.set_param(2, 1.5).unwrap();
    assert_eq!(
        *WIDENED.lock().unwrap(),
        [true, false],
        "widened around the write, then set back"
    );
    ARMED.store(true, Ordering::Relaxed);
    assert_eq!(g.set_param(2, 9.0), Err(StoreError::Armed));
    assert_eq!(g.set_signing(&[1; 32], 5), Err(StoreError::Armed));
    assert_eq!(g.remove_param(2), Err(StoreError::Armed));
    // Reads go on while armed; nothing was written.
    assert_eq!((g.param(2), g.signing()), (Ok(Some(1.5)), Ok(None)));
    assert_eq!(WIDENED.lock().unwrap().len(), 2);
    ARMED.store(false, Ordering::Relaxed);
    g.remove_param(2).unwrap();
    assert_eq!(g.param(2), Ok(None));
    assert!(StoreError::Armed.to_string().contains("armed"));
}
