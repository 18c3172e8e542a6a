//! The I2C master against [`crate::i2c_model`].

use super::*;
use crate::i2c_model::{part, run, Bus, Ev};
use embedded_hal::i2c::I2c as _;

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

/// On the chip a STOP takes about an SCL period to go out after the last
/// byte's interrupt, and CR1 must not be written meanwhile: a burst started
/// right after another (the accelerometer's after the gyroscope's) waits
/// for it, bounded, and a bus that stays busy refuses the burst.
#[test]
fn a_burst_right_after_another_waits_for_its_stop_and_the_wait_is_bounded() {
    let bus = Bus::new(vec![part(0x69, 0x0F), part(0x18, 0x1E)]);
    let _m = I2cMaster::new(&bus);
    bus.0.borrow_mut().stop_lag = 40;
    let mut b = Burst::new();
    b.start(&&bus, 0x69, 0x02, 6).unwrap();
    assert_eq!(run(&bus, &mut b).0, Progress::Done);
    b.start(&&bus, 0x18, 0x12, 6).unwrap();
    assert_eq!(run(&bus, &mut b).0, Progress::Done);
    assert_eq!(b.data(), &[0x13, 0x14, 0x15, 0x16, 0x17, 0x18]);
    // A STOP that never clears: refused after BUS_FREE_POLLS, not a hang.
    bus.0.borrow_mut().stop_lag = u32::MAX;
    b.start(&&bus, 0x69, 0x02, 6).unwrap();
    run(&bus, &mut b);
    assert_eq!(b.start(&&bus, 0x18, 0x12, 6), Err(I2cError::Bus));
    assert!(!b.busy());
}
