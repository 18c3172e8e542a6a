//! The I2C master against a model of the STM32F4's I2C peripheral in master
//! mode (RM0090 §27.3.3) and of the parts on the bus (register files with
//! an auto-incrementing pointer, as the BMI088 and BMP388 have). The model
//! clocks bytes in as early as the peripheral may (a byte is received as
//! soon as the previous one was ACKed and there is room), so any sequence
//! that leaves the last byte ACKed, clocks a byte more than is read, or
//! writes DR at the wrong time is caught.

use super::*;
use core::cell::RefCell;
use embedded_hal::i2c::I2c as _;

/// A part on the bus.
#[derive(Clone)]
struct Part {
    addr: u8,
    regs: [u8; 256],
    ptr: u8,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ev {
    Start,
    Stop,
    Addr(u8),
    Wrote(u8),
    Got { byte: u8, acked: bool },
}

#[derive(Default)]
struct State {
    cr1: u32,
    cr2: u32,
    ccr: u32,
    trise: u32,
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
    parts: Vec<Part>,
    log: Vec<Ev>,
    /// START never completes (SDA held low by a stuck part).
    stuck: bool,
    /// BUSY stays set.
    busy_stuck: bool,
    /// Bytes read out of DR in this transfer.
    read_out: usize,
}

struct Bus(RefCell<State>);

impl Bus {
    fn new(parts: Vec<Part>) -> Self {
        Bus(RefCell::new(State {
            parts,
            ..State::default()
        }))
    }

    fn log(&self) -> Vec<Ev> {
        self.0.borrow().log.clone()
    }

    /// The bytes the parts sent, whether each was ACKed.
    fn received(&self) -> Vec<(u8, bool)> {
        self.log()
            .iter()
            .filter_map(|e| match *e {
                Ev::Got { byte, acked } => Some((byte, acked)),
                _ => None,
            })
            .collect()
    }

    fn event_pending(&self) -> bool {
        let s = self.0.borrow();
        let ev = s.cr2 & cr2::ITEVTEN != 0;
        let buf = s.cr2 & cr2::ITBUFEN != 0;
        let btf = s.btf_tx || (s.dr.is_some() && s.shift.is_some());
        ev && (s.sb || s.addr || btf || (buf && (s.dr.is_some() || (s.txe && !s.reading))))
    }

    fn error_pending(&self) -> bool {
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
        u32::from(s.master || s.busy_stuck) * sr2::BUSY
    }
    fn cr1(&self) -> u32 {
        self.0.borrow().cr1
    }
    fn set_cr1(&self, v: u32) {
        let mut s = self.0.borrow_mut();
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

impl Regs for &Bus {
    fn sr1(&self) -> u32 {
        (*self).sr1()
    }
    fn sr2(&self) -> u32 {
        (*self).sr2()
    }
    fn cr1(&self) -> u32 {
        (*self).cr1()
    }
    fn set_cr1(&self, v: u32) {
        (*self).set_cr1(v)
    }
    fn cr2(&self) -> u32 {
        (*self).cr2()
    }
    fn set_cr2(&self, v: u32) {
        (*self).set_cr2(v)
    }
    fn clear_errors(&self, mask: u32) {
        (*self).clear_errors(mask)
    }
    fn dr(&self) -> u8 {
        (*self).dr()
    }
    fn set_dr(&self, b: u8) {
        (*self).set_dr(b)
    }
    fn set_timing(&self, ccr: u32, trise: u32) {
        (*self).set_timing(ccr, trise)
    }
}

/// A part at `addr` whose register `r` holds `r + 1` (`0x00` holds `id`).
fn part(addr: u8, id: u8) -> Part {
    let mut regs = [0u8; 256];
    for (i, r) in regs.iter_mut().enumerate() {
        *r = (i as u8).wrapping_add(1);
    }
    regs[0] = id;
    Part { addr, regs, ptr: 0 }
}

#[test]
fn fast_mode_timing_is_rm0090s_for_400_khz_from_42_mhz() {
    // FREQ 42; CCR = 42 MHz / (3 × 400 kHz) = 35 with F/S; TRISE = 300 ns × 42 MHz + 1 = 13.
    assert_eq!(timing(42_000_000, 400_000), (42, 0x8000 | 35, 13));
    let bus = Bus::new(vec![]);
    let _m = I2cMaster::new(&bus);
    let s = bus.0.borrow();
    assert_eq!((s.cr2, s.ccr, s.trise, s.cr1), (42, 0x8023, 13, cr1::PE));
}

#[test]
fn reads_of_every_length_nack_the_last_byte_and_clock_no_more() {
    for n in [1usize, 3, 4, 6, 7, 21] {
        let bus = Bus::new(vec![part(0x18, 0x1E)]);
        let mut m = I2cMaster::new(&bus);
        let mut buf = vec![0u8; n];
        m.write_read(0x18, &[0x10], &mut buf).unwrap();
        let want: Vec<u8> = (0x11..0x11 + n as u8).collect();
        assert_eq!(buf, want, "{n} bytes");
        let got = bus.received();
        assert_eq!(got.len(), n, "{n} bytes clocked, no more");
        assert!(got[..n - 1].iter().all(|(_, a)| *a) && !got[n - 1].1, "{n}: {got:?}");
        let log = bus.log();
        assert_eq!(
            &log[..4],
            &[Ev::Start, Ev::Addr(0x30), Ev::Wrote(0x10), Ev::Start],
            "register, repeated START"
        );
        assert_eq!(log[4], Ev::Addr(0x31));
        assert_eq!(*log.last().unwrap(), Ev::Stop);
        assert_eq!(bus.0.borrow().read_out, n);
    }
}

#[test]
fn a_read_of_two_bytes_is_refused_and_writes_end_with_a_stop() {
    let bus = Bus::new(vec![part(0x69, 0x0F)]);
    let mut m = I2cMaster::new(&bus);
    assert_eq!(m.write_read(0x69, &[0], &mut [0; 2]), Err(I2cError::Unsupported));
    m.write(0x69, &[0x0F, 0x00]).unwrap();
    assert_eq!(bus.0.borrow().parts[0].regs[0x0F], 0);
    assert_eq!(
        bus.log()[bus.log().len() - 5..],
        [Ev::Start, Ev::Addr(0xD2), Ev::Wrote(0x0F), Ev::Wrote(0x00), Ev::Stop]
    );
}

#[test]
fn an_absent_part_a_stuck_bus_and_a_busy_line_are_errors_not_hangs() {
    let bus = Bus::new(vec![part(0x18, 0x1E)]);
    let mut m = I2cMaster::new(&bus);
    assert_eq!(
        m.write_read(0x77, &[0], &mut [0; 1]),
        Err(I2cError::Nack(NoAcknowledgeSource::Address))
    );
    assert_eq!(*bus.log().last().unwrap(), Ev::Stop, "the bus released");
    // The part is still reachable after.
    let mut id = [0u8];
    m.write_read(0x18, &[0], &mut id).unwrap();
    assert_eq!(id, [0x1E]);
    bus.0.borrow_mut().stuck = true;
    assert_eq!(m.write_read(0x18, &[0], &mut id), Err(I2cError::Timeout("the START")));
    let busy = Bus::new(vec![part(0x18, 0x1E)]);
    busy.0.borrow_mut().busy_stuck = true;
    let mut m = I2cMaster::new(&busy);
    assert_eq!(
        m.write_read(0x18, &[0], &mut id),
        Err(I2cError::Timeout("the bus to be free"))
    );
}

/// Runs `b` on its interrupts until it ends (at most 200 of them).
fn run(bus: &Bus, b: &mut Burst) -> (Progress, usize) {
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

#[test]
fn a_burst_reads_on_its_interrupts_as_the_blocking_master_does() {
    for n in 3..=BURST_MAX {
        let bus = Bus::new(vec![part(0x69, 0x0F)]);
        let _m = I2cMaster::new(&bus);
        let mut b = Burst::new();
        b.start(&&bus, 0x69, 0x02, n).unwrap();
        let (p, irqs) = run(&bus, &mut b);
        assert_eq!(p, Progress::Done);
        assert_eq!(b.data(), &(3..3 + n as u8).collect::<Vec<_>>()[..]);
        let got = bus.received();
        assert_eq!(got.len(), n);
        assert!(!got[n - 1].1 && got[..n - 1].iter().all(|(_, a)| *a));
        // SB, ADDR, TXE, BTF, SB, ADDR, then a byte per interrupt but the
        // two taken together at BTF.
        assert_eq!(irqs, 6 + n - 1, "{n} bytes");
        assert_eq!(bus.0.borrow().cr2 & (cr2::ITEVTEN | cr2::ITBUFEN | cr2::ITERREN), 0);
        assert!(!b.busy());
    }
}

#[test]
fn a_burst_to_an_absent_part_fails_on_the_error_interrupt_and_the_next_works() {
    let bus = Bus::new(vec![part(0x69, 0x0F)]);
    let _m = I2cMaster::new(&bus);
    let mut b = Burst::new();
    assert_eq!(b.start(&&bus, 0x69, 0, 2), Err(I2cError::Unsupported));
    b.start(&&bus, 0x18, 0x12, 6).unwrap();
    assert_eq!(b.start(&&bus, 0x18, 0x12, 6), Err(I2cError::Bus), "one at a time");
    let (p, _) = run(&bus, &mut b);
    assert_eq!(p, Progress::Failed(I2cError::Nack(NoAcknowledgeSource::Address)));
    assert_eq!(*bus.log().last().unwrap(), Ev::Stop);
    b.start(&&bus, 0x69, 0x02, 6).unwrap();
    assert_eq!(run(&bus, &mut b).0, Progress::Done);
}

/// The BMI088 driver, unchanged, starts and reads on the blocking master
/// over the modelled bus: chip ids, the power-up sequence, read-backs.
#[test]
fn the_bmi088_driver_starts_and_reads_through_the_master() {
    use crate::bmi088::Bmi088;
    use embedded_hal_mock::eh1::delay::NoopDelay;
    let mut gyro = part(0x69, 0x0F);
    let mut acc = part(0x18, 0x1E);
    acc.regs[0x02] = 0; // ACC_ERR_REG: no error
                        // A sample: gyro x = 100 LSB, accel z = 1365 LSB (1 g at ±24 g).
    gyro.regs[0x02..0x08].copy_from_slice(&[100, 0, 0, 0, 0, 0]);
    acc.regs[0x12..0x18].copy_from_slice(&[0, 0, 0, 0, 0x55, 0x05]);
    let bus = Bus::new(vec![gyro, acc]);
    let mut imu = Bmi088::new(I2cMaster::new(&bus));
    imu.init(&mut NoopDelay::new()).unwrap();
    let s = imu.read().unwrap();
    assert!((s.gyro_frd_radps[0] - 100.0 * crate::bmi088::GYRO_RADPS_PER_LSB).abs() < 1e-6);
    assert!((s.accel_frd_mps2[2] + 9.8).abs() < 0.05, "{s:?}");
}
