//! The Crazyflie 2.1's brushed motors: four MOSFET-driven coreless motors
//! on TIM2 and TIM4, 8-bit PWM at 84 MHz / 256 = 328.125 kHz, as the
//! official firmware drives them (`motors_def.c`, `motors.c`):
//!
//! | motor | pin | timer channel | AF | where (FRD) | spin from above |
//! |---|---|---|---|---|---|
//! | M1 | PA1 | TIM2_CH2 | 1 | front right | anticlockwise |
//! | M2 | PB11 | TIM2_CH4 | 1 | rear right | clockwise |
//! | M3 | PA15 | TIM2_CH1 | 1 | rear left | anticlockwise |
//! | M4 | PB9 | TIM4_CH4 | 2 | front left | clockwise |
//!
//! (`fc_core::model::airframe::RotorLayout::x_crazyflie` is this order.) A thrust
//! per rotor (N) becomes a duty through the Crazyflie 2.1's thrust curve
//! with its standard ("legacy") propellers: thrust = c0 + c1·v + c2·v² +
//! c3·v³ with v the motor's mean voltage, battery voltage × duty
//! (`platform_defaults_cf2.h`, Bitcraze's 2025 thrust identification).
//! So a given thrust needs more duty as the battery drains.

use stm32f4::stm32f405::{gpioa, gpiob, rcc, tim2, tim3};

/// Timer clock of TIM2 and TIM4 (APB1 42 MHz × 2), Hz.
pub const TIMER_CLK_HZ: u32 = 84_000_000;
/// Auto-reload: 8-bit PWM (compare 0–255 of a 256-count period).
pub const ARR: u32 = 255;
/// Prescaler: none.
pub const PSC: u32 = 0;
/// The PWM frequency, Hz: 84 MHz / 256.
pub const PWM_HZ: u32 = TIMER_CLK_HZ / ((PSC + 1) * (ARR + 1));

/// A motor's thrust as a function of its mean voltage, per rotor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrustCurve {
    /// c0..c3 of thrust (N) = c0 + c1·v + c2·v² + c3·v³, v in volts.
    pub coeffs: [f32; 4],
    /// Below this thrust the motor is off (the cubic's inverse is unique above it), N.
    pub thrust_min_n: f32,
    /// The most thrust commanded, N (consistent across battery levels).
    pub thrust_max_n: f32,
}

/// The Crazyflie 2.1 with its standard propellers (`CONFIG_CRAZYFLIE_LEGACY_PROPELLERS`).
pub const CF21_LEGACY_PROPELLERS: ThrustCurve = ThrustCurve {
    coeffs: [-0.014_830_745, 0.047_244_652, -0.018_473_644, 0.005_960_924],
    thrust_min_n: 0.012_817_578,
    thrust_max_n: 0.12,
};

/// Below this battery voltage no duty is computed (all motors off): a
/// damaged pack or a bad reading must not rush the motors (the official
/// firmware's rule).
pub const BATTERY_MIN_V: f32 = 2.0;

/// Newton steps of the inverse (each bracketed: a step that would leave the
/// bracket bisects instead). From the bracket's middle four reach 1 nN of
/// thrust over the whole curve in f64; in f32 the tests hold them to 1 µN
/// (≈ 40 µV, far below one PWM step of ≈ 16 mV at 4.2 V) and to the
/// official firmware's closed-form inverse.
const NEWTON_STEPS: u32 = 4;
/// The inverse's bracket, V: from 0 to above a full 1S pack's 4.2 V.
const V_CEIL: f32 = 4.5;

impl ThrustCurve {
    /// Thrust of one rotor at a mean motor voltage, N.
    pub fn thrust_n(&self, v: f32) -> f32 {
        let [c0, c1, c2, c3] = self.coeffs;
        c0 + v * (c1 + v * (c2 + v * c3))
    }

    /// dThrust/dv at mean motor voltage `v`, N/V (positive everywhere).
    pub fn slope(&self, v: f32) -> f32 {
        let [_, c1, c2, c3] = self.coeffs;
        c1 + v * (2.0 * c2 + v * 3.0 * c3)
    }

    /// The motor voltage that gives `thrust_n` (clamped to the curve's
    /// range; 0 below its minimum or when not finite), V. The curve rises
    /// everywhere (its derivative's discriminant is negative), so a fixed
    /// number of bracketed Newton steps finds it.
    pub fn voltage_for(&self, thrust_n: f32) -> f32 {
        if !thrust_n.is_finite() || thrust_n < self.thrust_min_n {
            return 0.0;
        }
        let target = thrust_n.min(self.thrust_max_n);
        let (mut lo, mut hi) = (0.0f32, V_CEIL);
        let mut v = 0.5 * V_CEIL;
        for _ in 0..NEWTON_STEPS {
            let err = self.thrust_n(v) - target;
            if err < 0.0 {
                lo = v;
            } else {
                hi = v;
            }
            let next = v - err / self.slope(v);
            v = if (lo..=hi).contains(&next) {
                next
            } else {
                0.5 * (lo + hi)
            };
        }
        v
    }
}

/// The four compare values and whether any rotor asked for more than the
/// battery or the curve allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MotorOutput {
    /// Compare value (0–255) of M1..M4.
    pub compare: [u8; 4],
    /// A rotor was clamped (above the curve's maximum, or duty above 100 %).
    pub saturated: bool,
}

impl MotorOutput {
    /// All motors off.
    pub const OFF: MotorOutput = MotorOutput {
        compare: [0; 4],
        saturated: false,
    };
}

/// Thrusts of M1..M4 (N) → compare values at battery voltage `v_bat`.
/// A battery below [`BATTERY_MIN_V`] (or not finite) gives all motors off.
pub fn output(curve: &ThrustCurve, thrusts_n: [f32; 4], v_bat: f32) -> MotorOutput {
    if !v_bat.is_finite() || v_bat < BATTERY_MIN_V {
        return MotorOutput::OFF;
    }
    let mut saturated = false;
    let compare = thrusts_n.map(|f| {
        if f.is_finite() && f > curve.thrust_max_n {
            saturated = true;
        }
        let duty = curve.voltage_for(f) / v_bat;
        if duty >= 1.0 {
            saturated |= duty > 1.0;
            255
        } else {
            // Output high while CNT < CCR: duty = CCR / 256.
            libm::roundf(duty * (ARR + 1) as f32).min(ARR as f32) as u8
        }
    });
    MotorOutput { compare, saturated }
}

/// Clocks on, pins to their timer, TIM2 and TIM4 in PWM mode 1 at
/// [`PWM_HZ`] with every compare 0 (motors off), counters started. PA15
/// (JTDI after reset) loses its reset pull-up so that only the timer drives
/// M3's gate.
pub fn apply_to(
    rcc: &rcc::RegisterBlock,
    gpioa: &gpioa::RegisterBlock,
    gpiob: &gpiob::RegisterBlock,
    tim2: &tim2::RegisterBlock,
    tim4: &tim3::RegisterBlock,
) {
    rcc.ahb1enr().modify(|_, w| w.gpioaen().enabled().gpioben().enabled());
    rcc.apb1enr().modify(|_, w| w.tim2en().enabled().tim4en().enabled());
    // Compares to 0 before the pins switch over: no pulse at start.
    for n in 0..4 {
        tim2.ccr(n).write(|w| unsafe { w.ccr().bits(0) });
        tim4.ccr(n).write(|w| unsafe { w.ccr().bits(0) });
    }
    // SAFETY (the bit writes below): PSC and ARR take any 16/32-bit value.
    tim2.psc().write(|w| unsafe { w.psc().bits(PSC as u16) });
    tim2.arr().write(|w| unsafe { w.arr().bits(ARR) });
    tim4.psc().write(|w| unsafe { w.psc().bits(PSC as u16) });
    tim4.arr().write(|w| unsafe { w.arr().bits(ARR as u16) });
    tim2.ccmr1_output().write(|w| {
        w.oc1m()
            .pwm_mode1()
            .oc1pe()
            .enabled()
            .oc2m()
            .pwm_mode1()
            .oc2pe()
            .enabled()
    });
    tim2.ccmr2_output().write(|w| w.oc4m().pwm_mode1().oc4pe().enabled());
    tim4.ccmr2_output().write(|w| w.oc4m().pwm_mode1().oc4pe().enabled());
    tim2.ccer()
        .write(|w| w.cc1e().set_bit().cc2e().set_bit().cc4e().set_bit());
    tim4.ccer().write(|w| w.cc4e().set_bit());
    tim2.egr().write(|w| w.ug().update());
    tim4.egr().write(|w| w.ug().update());
    tim2.cr1().write(|w| w.cen().enabled());
    tim4.cr1().write(|w| w.cen().enabled());
    gpioa.pupdr().modify(|_, w| w.pupdr(15).floating());
    gpioa.afrl().modify(|_, w| w.afr(1).af1());
    gpioa.afrh().modify(|_, w| w.afr(15 - 8).af1());
    gpiob.afrh().modify(|_, w| w.afr(11 - 8).af1().afr(9 - 8).af2());
    gpioa
        .moder()
        .modify(|_, w| w.moder(1).alternate().moder(15).alternate());
    gpiob
        .moder()
        .modify(|_, w| w.moder(11).alternate().moder(9).alternate());
}

/// Writes M1..M4's compare values (TIM2 CH2, CH4, CH1; TIM4 CH4); they
/// take effect at the next period (preload on).
pub fn set(tim2: &tim2::RegisterBlock, tim4: &tim3::RegisterBlock, out: &MotorOutput) {
    let [m1, m2, m3, m4] = out.compare.map(u32::from);
    // SAFETY: a compare register takes any value; ≤ 255 here.
    tim2.ccr2().write(|w| unsafe { w.ccr().bits(m1) });
    tim2.ccr4().write(|w| unsafe { w.ccr().bits(m2) });
    tim2.ccr1().write(|w| unsafe { w.ccr().bits(m3) });
    tim4.ccr4().write(|w| unsafe { w.ccr().bits(m4 as u16) });
}

/// Every motor off at once (a fault handler's first act): the four
/// compares set to 0 and loaded now by an update event rather than at the
/// end of the period; returns them read back, M1..M4.
pub fn off_now(tim2: &tim2::RegisterBlock, tim4: &tim3::RegisterBlock) -> [u32; 4] {
    set(tim2, tim4, &MotorOutput::OFF);
    tim2.egr().write(|w| w.ug().update());
    tim4.egr().write(|w| w.ug().update());
    compares(tim2, tim4)
}

/// The four compare values read back, M1..M4 (the order of [`set`]).
pub fn compares(tim2: &tim2::RegisterBlock, tim4: &tim3::RegisterBlock) -> [u32; 4] {
    [
        tim2.ccr2().read().ccr().bits(),
        tim2.ccr4().read().ccr().bits(),
        tim2.ccr1().read().ccr().bits(),
        u32::from(tim4.ccr4().read().ccr().bits()),
    ]
}

/// On the chip: [`apply_to`] on the real RCC, GPIOA, GPIOB, TIM2 and TIM4
/// (motors off, counters running); returns the two timers for [`set`].
///
/// # Safety
/// The caller is the only code that touches those peripherals (the image's
/// start-up, once).
#[cfg(target_os = "none")]
pub unsafe fn start_on_chip() -> (&'static tim2::RegisterBlock, &'static tim3::RegisterBlock) {
    use stm32f4::stm32f405 as pac;
    // SAFETY: the blocks' fixed addresses; exclusive by the caller's contract.
    let (rcc, gpioa, gpiob, tim2, tim4) = unsafe {
        (
            &*pac::RCC::ptr(),
            &*pac::GPIOA::ptr(),
            &*pac::GPIOB::ptr(),
            &*pac::TIM2::ptr(),
            &*pac::TIM4::ptr(),
        )
    };
    apply_to(rcc, gpioa, gpiob, tim2, tim4);
    (tim2, tim4)
}

/// On the chip, from a fault handler (which owns the chip from then on):
/// [`off_now`] on TIM2/TIM4, named for the fault's log line.
#[cfg(target_os = "none")]
pub fn off_now_on_chip() -> (&'static str, [u32; 4]) {
    use stm32f4::stm32f405 as pac;
    // SAFETY: the blocks' fixed addresses; a fault handler is the only code left running.
    let (tim2, tim4) = unsafe { (&*pac::TIM2::ptr(), &*pac::TIM4::ptr()) };
    ("TIM2/TIM4", off_now(tim2, tim4))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fc_core::model::airframe::{RotorLayout, Spin};

    #[test]
    fn the_curve_rises_everywhere_and_its_inverse_returns_the_thrust() {
        let c = CF21_LEGACY_PROPELLERS;
        // Rising: dT/dv = c1 + 2 c2 v + 3 c3 v² has no real root.
        let [_, c1, c2, c3] = c.coeffs.map(f64::from);
        assert!((2.0 * c2).powi(2) - 4.0 * 3.0 * c3 * c1 < 0.0);
        for i in 0..=10_000 {
            let f = c.thrust_min_n + (c.thrust_max_n - c.thrust_min_n) * i as f32 / 10_000.0;
            let v = c.voltage_for(f);
            assert!((c.thrust_n(v) - f).abs() < 1e-6, "{f} N");
            // The slope the inverse steps along is the curve's.
            let h = 1e-3;
            let numeric = (f64::from(c.thrust_n(v + h)) - f64::from(c.thrust_n(v - h))) / (2.0 * f64::from(h));
            assert!((f64::from(c.slope(v)) - numeric).abs() < 1e-4, "{v} V");
        }
    }

    /// The official firmware's closed-form inverse (Cardano, in
    /// `motorsCompensateBatteryVoltage`), evaluated independently here.
    fn firmware_voltage(c: &ThrustCurve, thrust: f64) -> f64 {
        let [c0, c1, c2, c3] = c.coeffs.map(f64::from);
        let p = -c2 / (3.0 * c3);
        let q = p * p * p + (c2 * c1 - 3.0 * c3 * (c0 - thrust)) / (6.0 * c3 * c3);
        let r = c1 / (3.0 * c3);
        let qrp = (q * q + (r - p * p).powi(3)).sqrt();
        (q + qrp).cbrt() + (q - qrp).cbrt() + p
    }

    #[test]
    fn duty_agrees_with_the_official_firmwares_inverse() {
        let c = CF21_LEGACY_PROPELLERS;
        for v_bat in [3.0f32, 3.7, 4.2] {
            for f in [0.02f32, 0.0662, 0.09, 0.12] {
                let ours = c.voltage_for(f) / v_bat;
                let theirs = firmware_voltage(&c, f64::from(f)) / f64::from(v_bat);
                assert!((f64::from(ours) - theirs).abs() < 1e-5, "{f} N at {v_bat} V");
            }
        }
        // Hover of a 27 g Crazyflie 2.1: 66 mN per rotor, 2.26 V at the motor:
        // 54 % duty at 4.2 V, 61 % at 3.7 V (more as the pack drains).
        let hover = 0.027 * 9.806_65 / 4.0;
        let o_full = output(&c, [hover; 4], 4.2);
        let o_low = output(&c, [hover; 4], 3.7);
        assert!(o_full.compare[0] < o_low.compare[0]);
        assert_eq!((o_full.compare[0], o_low.compare[0]), (138, 156));
        // The curve's maximum, 120 mN (2.98 V): the book's table.
        assert_eq!(
            (
                output(&c, [0.12; 4], 4.2).compare[0],
                output(&c, [0.12; 4], 3.7).compare[0]
            ),
            (182, 206)
        );
        assert!(!o_full.saturated);
    }

    #[test]
    fn limits_bad_input_and_a_flat_battery_stop_or_clamp() {
        let c = CF21_LEGACY_PROPELLERS;
        // Below the minimum, negative, NaN: off. Above the maximum: clamped and flagged.
        let o = output(&c, [0.005, -1.0, f32::NAN, 0.5], 4.2);
        assert_eq!(&o.compare[..3], &[0, 0, 0]);
        assert!(o.saturated);
        assert_eq!(o.compare[3], output(&c, [0.12; 4], 4.2).compare[3]);
        // 0.12 N needs 2.98 V at the motor: more than a 2.8 V pack can give.
        let o = output(&c, [0.12; 4], 2.8);
        assert_eq!(o.compare, [255; 4]);
        assert!(o.saturated);
        // A battery reading of 1.5 V or NaN: everything off.
        assert_eq!(output(&c, [0.1; 4], 1.5), MotorOutput::OFF);
        assert_eq!(output(&c, [0.1; 4], f32::NAN), MotorOutput::OFF);
    }

    #[test]
    fn the_motor_order_is_the_layouts_the_core_mixes_for() {
        let l = RotorLayout::x_crazyflie(0.046f32);
        let quadrant = |i: usize| (l.rotors[i].pos_frd_m[0] > 0.0, l.rotors[i].pos_frd_m[1] > 0.0);
        // M1 front right, M2 rear right, M3 rear left, M4 front left.
        assert_eq!(
            [quadrant(0), quadrant(1), quadrant(2), quadrant(3)],
            [(true, true), (false, true), (false, false), (true, false)]
        );
        assert_eq!(
            l.rotors.map(|r| r.spin),
            [
                Spin::Anticlockwise,
                Spin::Clockwise,
                Spin::Anticlockwise,
                Spin::Clockwise
            ]
        );
        assert_eq!(PWM_HZ, 328_125);
    }

    /// RCC, GPIOA, GPIOB, TIM2 and TIM4 in host memory at their reset
    /// values (RM0090 §7.3.24, §8.4.11, §18.4.21).
    struct FakeChip {
        rcc: [u32; 64],
        gpioa: [u32; 16],
        gpiob: [u32; 16],
        tim2: [u32; 32],
        tim4: [u32; 32],
    }

    impl FakeChip {
        fn new() -> Self {
            let mut gpioa = [0u32; 16];
            gpioa[0] = 0xA800_0000; // MODER: PA13–15 debug (AF)
            gpioa[3] = 0x6400_0000; // PUPDR: PA15 up, PA14 down, PA13 up
            let mut gpiob = [0u32; 16];
            gpiob[0] = 0x0000_0280; // MODER: PB3, PB4 debug (AF)
            gpiob[3] = 0x0000_0100; // PUPDR: PB4 up
            Self {
                rcc: [0; 64],
                gpioa,
                gpiob,
                tim2: [0; 32],
                tim4: [0; 32],
            }
        }

        fn with<R>(
            &mut self,
            f: impl FnOnce(
                &rcc::RegisterBlock,
                &gpioa::RegisterBlock,
                &gpiob::RegisterBlock,
                &tim2::RegisterBlock,
                &tim3::RegisterBlock,
            ) -> R,
        ) -> R {
            assert!(core::mem::size_of::<tim2::RegisterBlock>() <= 4 * 32);
            assert!(core::mem::size_of::<gpioa::RegisterBlock>() <= 4 * 16);
            assert!(core::mem::size_of::<rcc::RegisterBlock>() <= 4 * 64);
            // SAFETY: each array is at least its register block's size, u32
            // aligned and borrowed mutably for the call; the PAC's registers
            // are volatile cells, so host memory serves as the chip's.
            unsafe {
                f(
                    &*self.rcc.as_mut_ptr().cast(),
                    &*self.gpioa.as_mut_ptr().cast(),
                    &*self.gpiob.as_mut_ptr().cast(),
                    &*self.tim2.as_mut_ptr().cast(),
                    &*self.tim4.as_mut_ptr().cast(),
                )
            }
        }
    }

    // Word indices (RM0090 register maps).
    const AHB1ENR: usize = 0x30 / 4;
    const APB1ENR: usize = 0x40 / 4;
    const MODER: usize = 0;
    const PUPDR: usize = 3;
    const AFRL: usize = 8;
    const AFRH: usize = 9;
    const CR1: usize = 0;
    const EGR: usize = 5;
    const CCMR1: usize = 6;
    const CCMR2: usize = 7;
    const CCER: usize = 8;
    const PSC_: usize = 10;
    const ARR_: usize = 11;
    const CCR1: usize = 13;

    #[test]
    fn timers_and_pins_get_rm0090s_values() {
        let mut chip = FakeChip::new();
        chip.with(apply_to);
        // RCC: GPIOA, GPIOB (AHB1ENR bits 0, 1); TIM2, TIM4 (APB1ENR bits 0, 2).
        assert_eq!((chip.rcc[AHB1ENR], chip.rcc[APB1ENR]), (0b11, 0b101));
        // PA1 and PA15 alternate (0b10), PA13/14 still debug; AF1 on PA1 (AFRL
        // bits 7–4) and PA15 (AFRH bits 31–28); PA15's pull-up gone.
        assert_eq!(chip.gpioa[MODER], 0xA800_0000 | 0b10 << 2);
        assert_eq!((chip.gpioa[AFRL], chip.gpioa[AFRH]), (1 << 4, 1 << 28));
        assert_eq!(chip.gpioa[PUPDR], 0x2400_0000);
        // PB9 (AF2, TIM4) and PB11 (AF1, TIM2) alternate; PB3/PB4 untouched.
        assert_eq!(chip.gpiob[MODER], 0x0000_0280 | 0b10 << 18 | 0b10 << 22);
        assert_eq!(chip.gpiob[AFRH], 2 << 4 | 1 << 12);
        assert_eq!(chip.gpiob[PUPDR], 0x0000_0100);
        // TIM2: PWM mode 1 (OCxM = 0b110) with preload (OCxPE) on CH1, CH2
        // (CCMR1) and CH4 (CCMR2); outputs CC1E, CC2E, CC4E; PSC 0, ARR 255;
        // UG to load them; counter on; compares 0.
        assert_eq!(chip.tim2[CCMR1], 0b110 << 4 | 1 << 3 | 0b110 << 12 | 1 << 11);
        assert_eq!(chip.tim2[CCMR2], 0b110 << 12 | 1 << 11);
        assert_eq!(chip.tim2[CCER], 1 | 1 << 4 | 1 << 12);
        assert_eq!(
            (chip.tim2[PSC_], chip.tim2[ARR_], chip.tim2[EGR], chip.tim2[CR1]),
            (0, 255, 1, 1)
        );
        // TIM4: CH4 only.
        assert_eq!(
            (chip.tim4[CCMR1], chip.tim4[CCMR2], chip.tim4[CCER]),
            (0, 0b110 << 12 | 1 << 11, 1 << 12)
        );
        assert_eq!((chip.tim4[PSC_], chip.tim4[ARR_], chip.tim4[CR1]), (0, 255, 1));
        assert_eq!(&chip.tim2[CCR1..CCR1 + 4], &[0; 4]);
        // M1..M4 land on TIM2 CCR2, CCR4, CCR1 and TIM4 CCR4.
        let out = MotorOutput {
            compare: [11, 22, 33, 44],
            saturated: false,
        };
        chip.with(|_, _, _, t2, t4| set(t2, t4, &out));
        assert_eq!(&chip.tim2[CCR1..CCR1 + 4], &[33, 11, 0, 22]);
        assert_eq!(chip.tim4[CCR1 + 3], 44);
        // A fault: all four to 0 now (update events), read back in motor order.
        chip.tim2[EGR] = 0;
        chip.tim4[EGR] = 0;
        assert_eq!(chip.with(|_, _, _, t2, t4| off_now(t2, t4)), [0; 4]);
        assert_eq!(&chip.tim2[CCR1..CCR1 + 4], &[0; 4]);
        assert_eq!((chip.tim4[CCR1 + 3], chip.tim2[EGR], chip.tim4[EGR]), (0, 1, 1));
    }
}
