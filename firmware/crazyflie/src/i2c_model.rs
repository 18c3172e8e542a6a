//! A model of the STM32F4's I2C peripheral in master mode (RM0090
//! §27.3.3) and of the parts on the bus (register files with an
//! auto-incrementing pointer, as the BMI088 and BMP388 have), for the host
//! tests of [`crate::i2c`] and of what runs on it. The model clocks bytes
//! in as early as the peripheral may (a byte is received as soon as the
//! previous one was ACKed and there is room), so any sequence that leaves
//! the last byte ACKed, clocks a byte more than is read, or writes DR at
//! the wrong time fails the test (a panic naming the mistake).

use crate::i2c::{cr1, cr2, sr1, sr2, Burst, Progress, Regs};
use core::cell::RefCell;

/// A part on the bus.
#[derive(Clone)]
pub(crate) struct Part {
    pub(crate) addr: u8,
    pub(crate) regs: [u8; 256],
    pub(crate) ptr: u8,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Ev {
    Start,
    Stop,
    Addr(u8),
    Wrote(u8),
    Got { byte: u8, acked: bool },
}

#[derive(Default)]
pub(crate) struct State {
    pub(crate) cr1: u32,
    pub(crate) cr2: u32,
    pub(crate) ccr: u32,
    pub(crate) trise: u32,
    sb: bool,
    addr: bool,
    af: bool,
    txe: bool,
    btf_tx: bool,
    sr1_read: bool,
    master: bool,
    reading: bool,
    part: Option<usize>,
    pointer_set: bool,
    dr: Option<u8>,
    shift: Option<u8>,
    last_acked: bool,
    slave_done: bool,
    pub(crate) parts: Vec<Part>,
    pub(crate) log: Vec<Ev>,
    /// START never completes (SDA held low by a stuck part).
    pub(crate) stuck: bool,
    /// BUSY stays set.
    pub(crate) busy_stuck: bool,
    /// Bytes read out of DR in this transfer.
    pub(crate) read_out: usize,
    /// Register reads for which a STOP, once sent, still shows (CR1.STOP
    /// and SR2.BUSY set), as on the chip for about an SCL period.
    pub(crate) stop_lag: u32,
    lag_left: u32,
}

pub(crate) struct Bus(pub(crate) RefCell<State>);

impl Bus {
    pub(crate) fn new(parts: Vec<Part>) -> Self {
        Bus(RefCell::new(State {
            parts,
            ..State::default()
        }))
    }

    pub(crate) fn log(&self) -> Vec<Ev> {
        self.0.borrow().log.clone()
    }

    /// The bytes the parts sent, whether each was ACKed.
    pub(crate) fn received(&self) -> Vec<(u8, bool)> {
        self.log()
            .iter()
            .filter_map(|e| match *e {
                Ev::Got { byte, acked } => Some((byte, acked)),
                _ => None,
            })
            .collect()
    }

    pub(crate) fn event_pending(&self) -> bool {
        let s = self.0.borrow();
        let ev = s.cr2 & cr2::ITEVTEN != 0;
        let buf = s.cr2 & cr2::ITBUFEN != 0;
        let btf = s.btf_tx || (s.dr.is_some() && s.shift.is_some());
        ev && (s.sb || s.addr || btf || (buf && (s.dr.is_some() || (s.txe && !s.reading))))
    }

    pub(crate) fn error_pending(&self) -> bool {
        let s = self.0.borrow();
        s.cr2 & cr2::ITERREN != 0 && s.af
    }
}

impl State {
    /// The part clocks bytes in while the last was ACKed and there is room.
    fn clock_in(&mut self) {
        while self.reading && !self.slave_done && (self.dr.is_none() || self.shift.is_none()) {
            let p = &mut self.parts[self.part.unwrap()];
            let byte = p.regs[usize::from(p.ptr)];
            p.ptr = p.ptr.wrapping_add(1);
            let acked = self.cr1 & cr1::ACK != 0;
            self.log.push(Ev::Got { byte, acked });
            if self.dr.is_none() {
                self.dr = Some(byte);
            } else {
                self.shift = Some(byte);
            }
            self.last_acked = acked;
            if !acked {
                self.slave_done = true;
            }
        }
        self.try_stop();
    }

    /// A STOP asked for is sent once the byte under way is done: in a
    /// read, once the part has had its NACK.
    fn try_stop(&mut self) {
        if self.cr1 & cr1::STOP == 0 {
            return;
        }
        if self.reading {
            assert!(
                self.slave_done,
                "STOP asked while the last byte received was ACKed: the part sends one more"
            );
        }
        self.cr1 &= !cr1::STOP;
        self.lag_left = self.stop_lag;
        self.log.push(Ev::Stop);
        self.master = false;
        self.reading = false;
        self.part = None;
        self.txe = false;
        self.btf_tx = false;
    }
}

impl Regs for Bus {
    fn sr1(&self) -> u32 {
        let mut s = self.0.borrow_mut();
        s.sr1_read = true;
        let btf = s.btf_tx || (s.dr.is_some() && s.shift.is_some());
        [
            (s.sb, sr1::SB),
            (s.addr, sr1::ADDR),
            (btf, sr1::BTF),
            (s.dr.is_some(), sr1::RXNE),
            (s.txe, sr1::TXE),
            (s.af, sr1::AF),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .fold(0, |acc, (_, bit)| acc | bit)
    }
    fn sr2(&self) -> u32 {
        let mut s = self.0.borrow_mut();
        if s.sr1_read && s.addr {
            s.addr = false;
            if s.reading {
                s.clock_in();
            } else {
                s.txe = true;
            }
        }
        s.sr1_read = false;
        let lag = s.lag_left > 0;
        s.lag_left = s.lag_left.saturating_sub(1);
        u32::from(s.master || s.busy_stuck || lag) * sr2::BUSY
    }
    fn cr1(&self) -> u32 {
        let mut s = self.0.borrow_mut();
        let lag = s.lag_left > 0;
        s.lag_left = s.lag_left.saturating_sub(1);
        s.cr1 | (u32::from(lag) * cr1::STOP)
    }
    fn set_cr1(&self, v: u32) {
        let mut s = self.0.borrow_mut();
        assert!(
            s.lag_left == 0 || v & cr1::SWRST != 0,
            "CR1 written while the last STOP is still set (RM0090 §27.6.1)"
        );
        if v & cr1::SWRST != 0 {
            let parts = core::mem::take(&mut s.parts);
            let (stuck, busy_stuck, log) = (s.stuck, s.busy_stuck, core::mem::take(&mut s.log));
            *s = State {
                parts,
                stuck,
                busy_stuck,
                log,
                cr1: v,
                ..State::default()
            };
            return;
        }
        s.cr1 = v;
        if v & cr1::START != 0 && !s.stuck {
            assert!(!s.reading || s.slave_done, "a repeated START in the middle of a read");
            s.cr1 &= !cr1::START;
            s.sb = true;
            s.master = true;
            s.txe = false;
            s.btf_tx = false;
            s.log.push(Ev::Start);
        }
        s.try_stop();
    }
    fn cr2(&self) -> u32 {
        self.0.borrow().cr2
    }
    fn set_cr2(&self, v: u32) {
        self.0.borrow_mut().cr2 = v;
    }
    fn clear_errors(&self, mask: u32) {
        if mask & sr1::AF != 0 {
            self.0.borrow_mut().af = false;
        }
    }
    fn dr(&self) -> u8 {
        let mut s = self.0.borrow_mut();
        let b = s.dr.take().expect("DR read with nothing received");
        s.read_out += 1;
        s.dr = s.shift.take();
        s.clock_in();
        b
    }
    fn set_dr(&self, b: u8) {
        let mut s = self.0.borrow_mut();
        if s.sb {
            s.sb = false;
            s.log.push(Ev::Addr(b));
            let addr = b >> 1;
            match s.parts.iter().position(|p| p.addr == addr) {
                Some(i) => {
                    s.part = Some(i);
                    s.addr = true;
                    s.reading = b & 1 == 1;
                    s.slave_done = false;
                    s.read_out = 0;
                    s.pointer_set = s.reading;
                }
                None => s.af = true,
            }
            return;
        }
        assert!(
            s.master && !s.reading && !s.addr && s.part.is_some(),
            "DR written outside a write"
        );
        s.log.push(Ev::Wrote(b));
        let i = s.part.unwrap();
        if s.pointer_set {
            let p = &mut s.parts[i];
            p.regs[usize::from(p.ptr)] = b;
            p.ptr = p.ptr.wrapping_add(1);
        } else {
            s.parts[i].ptr = b;
            s.pointer_set = true;
        }
        s.txe = true;
        s.btf_tx = true;
    }
    fn set_timing(&self, ccr: u32, trise: u32) {
        let mut s = self.0.borrow_mut();
        s.ccr = ccr;
        s.trise = trise;
    }
}

/// A part at `addr` whose register `r` holds `r + 1` (`0x00` holds `id`).
pub(crate) fn part(addr: u8, id: u8) -> Part {
    let mut regs = [0u8; 256];
    for (i, r) in regs.iter_mut().enumerate() {
        *r = (i as u8).wrapping_add(1);
    }
    regs[0] = id;
    Part { addr, regs, ptr: 0 }
}

/// Runs `b` on its interrupts until it ends (at most 200 of them).
pub(crate) fn run(bus: &Bus, b: &mut Burst) -> (Progress, usize) {
    for k in 1..=200 {
        let p = if bus.error_pending() {
            b.on_error(&bus)
        } else if bus.event_pending() {
            b.on_event(&bus)
        } else {
            panic!("no interrupt pending with the burst under way (interrupt {k})")
        };
        if p != Progress::Pending {
            return (p, k);
        }
    }
    panic!("the burst never ended")
}
