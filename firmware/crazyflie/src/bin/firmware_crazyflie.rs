//! The Crazyflie 2.1 image (`thumbv7em-none-eabihf`), linked at 0x08004000
//! behind Bitcraze's bootloader; its reset handler points VTOR at its own
//! vector table (cortex-m-rt's `set-vtor`).
//!
//! It is a Crazyflie's STM32 as cflib and cfclient know it: CRTP over
//! syslink to the nRF51 radio on USART6 (the RTIC application of
//! `fc_stm32f405::crtp_app`, which `firmware-crtp` runs too:
//! radio bytes at priority 4, the sample and estimator at 3, the
//! controller at 2, the link at 1), the vehicle's parameters and samples from
//! the simulator on USART1, and the Crazyflie's motors on TIM2/TIM4: every
//! step's inputs go through the vehicle's mixer (`MOT_FRAME` 4, the
//! Crazyflie's M1–M4, hubs 46 mm out; the vehicle's parameters as written)
//! and the Crazyflie 2.1's thrust curve at the battery voltage the nRF51
//! reports, to the four compare registers; disarmed, they are 0. A fault
//! zeroes them first. The LEDs show booting, aligning, ready, armed and
//! failsafe (`fc_crazyflie::leds`; QEMU models no GPIO). The IWDG starts
//! once the IMU task and the controller have both run and is fed only
//! while both keep running (`fc_stm32f405::watchdog`; QEMU models no IWDG).
//! Its IMU: in QEMU (the default `qemu` feature; QEMU models no I2C or
//! GPIO) the simulator's `Imu` frame on USART1; on the board build (`cargo
//! cf-build`) the BMI088 on I2C3, started at boot, each sample read on
//! I2C3's interrupts from the gyroscope's data-ready on EXTI14 (`sensors`
//! below; never run here), and after every 20th sample the BMP388 (50 Hz),
//! fused as a height fix. In QEMU the `boot-shim` binary stands in for the
//! bootloader.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
fc_stm32f405::board_runtime!();

#[cfg(target_os = "none")]
fc_stm32f405::crtp_app!();

#[cfg(target_os = "none")]
pub use target::{imu_bus, vehicle, BoardOutputs, ImuBus, WATCHDOG};

#[cfg(target_os = "none")]
mod target {
    use fc_crazyflie::leds::{self, pattern, Indication, LedPin, Leds, Lit};
    use fc_crazyflie::motors::{self, MotorOutput, CF21_LEGACY_PROPELLERS};
    use fc_crtp::vehicle::{CrtpShared, CrtpVehicle};
    use fc_loop::nav::NavMode;
    use fc_loop::params::{Airframe, Settings};
    use fc_loop::power::Power;

    /// Hub distance from the centre, m (Bitcraze's `ARM_LENGTH`).
    const HUB_M: f32 = 0.046;

    /// The fault handlers' first act: the motors off, then the LEDs to "fault".
    fn on_fault() -> (&'static str, [u32; 4]) {
        let stopped = motors::off_now_on_chip();
        // SAFETY: a fault handler is the only code left running.
        let _ = unsafe { leds::start_on_chip() }.show(pattern(Indication::Fault, 0));
        stopped
    }

    /// The Crazyflie's outputs of every step: the four brushed motors on
    /// TIM2/TIM4 through the vehicle's mixer and the thrust curve at the
    /// battery's voltage (off while disarmed), and the LEDs.
    pub struct BoardOutputs {
        tim2: &'static stm32f4::stm32f405::tim2::RegisterBlock,
        tim4: &'static stm32f4::stm32f405::tim3::RegisterBlock,
        leds: Leds<LedPin>,
        last_lit: Lit,
        saturated: bool,
        saturations: u32,
        /// The last step's motor outputs (for [`Outputs::report`]).
        out: MotorOutput,
        armed_steps: u32,
        steps: u32,
    }

    // SAFETY: the timers' registers are reached only through this value,
    // which the controller's task alone owns (RTIC moves it there from
    // `init`); the fault handler's own writes happen when no task runs.
    unsafe impl Send for BoardOutputs {}

    impl BoardOutputs {
        /// The motor timers (compare 0), the fault hook, the LEDs showing "booting".
        pub(crate) fn start() -> Self {
            // SAFETY: the only code that touches the motor peripherals.
            let (tim2, tim4) = unsafe { motors::start_on_chip() };
            fc_stm32f405::board::on_fault_stop_motors(on_fault);
            // SAFETY: the only code that touches the LED pins.
            let mut leds = unsafe { leds::start_on_chip() };
            let last_lit = pattern(Indication::Booting, 0);
            let _ = leds.show(last_lit);
            // SAFETY: a read of SCB.VTOR, which nothing writes after reset.
            let vtor = unsafe { (*cortex_m::peripheral::SCB::PTR).vtor.read() };
            defmt::info!("Crazyflie 2.1 image: vector table at {=u32:#010x}", vtor);
            Self {
                tim2,
                tim4,
                leds,
                last_lit,
                saturated: false,
                saturations: 0,
                out: MotorOutput::OFF,
                armed_steps: 0,
                steps: 0,
            }
        }
    }

    impl fc_stm32f405::crtp_image::Outputs for BoardOutputs {
        fn drive(&mut self, v: &CrtpShared, power: &Power) {
            // The loop's mixer follows every parameter write (`MOT_FRAME`
            // changes it without a design).
            let out = match (v.armed(), v.mixer()) {
                (true, Some(_)) => motors::output(&CF21_LEGACY_PROPELLERS, power.thrusts_n.into(), v.battery_v()),
                _ => MotorOutput::OFF,
            };
            motors::set(self.tim2, self.tim4, &out);
            self.out = out;
        }

        fn report(&mut self, armed: bool, nav: NavMode, battery_v: f32) {
            let out = self.out;
            // The LEDs, on the steps' clock (1 kHz: `steps` is ms).
            self.steps = self.steps.wrapping_add(1);
            let shown = match (armed, nav) {
                (true, NavMode::Failsafe) => Indication::Failsafe,
                (true, _) => Indication::Armed,
                (false, NavMode::Aligning) => Indication::Aligning,
                (false, _) => Indication::Ready,
            };
            // Five pin writes only when what they show changes.
            let lit = pattern(shown, self.steps);
            if lit != self.last_lit {
                self.last_lit = lit;
                let _ = self.leds.show(lit);
            }
            // Once a second of armed flight (at 1 kHz), what the motors get.
            self.armed_steps = if armed { self.armed_steps.wrapping_add(1) } else { 0 };
            if self.armed_steps % 1000 == 500 {
                defmt::info!("motors: compare {} at {=f32} V", out.compare, battery_v);
            }
            if out.saturated != self.saturated {
                self.saturated = out.saturated;
                if self.saturated {
                    self.saturations = self.saturations.wrapping_add(1);
                    defmt::warn!(
                        "motors saturated: a rotor needs more than the Crazyflie's thrust curve gives ({=u32} so far)",
                        self.saturations
                    );
                } else {
                    defmt::info!("motors within the thrust curve again");
                }
            }
        }
    }

    /// The image's watchdog: the chip's IWDG under its feeding rule
    /// (`fc_stm32f405::crtp_image::Iwdg`, shared with `firmware-crtp`).
    pub static WATCHDOG: fc_stm32f405::crtp_image::Iwdg = fc_stm32f405::crtp_image::Iwdg::new();

    /// In QEMU (which models no I2C and no GPIO) the IMU is the
    /// simulator's, on USART1, and taken as up.
    #[cfg(feature = "qemu")]
    pub type ImuBus = fc_stm32f405::crtp_image::SimulatorOnly;

    /// The simulator's sensors (QEMU).
    #[cfg(feature = "qemu")]
    pub fn imu_bus() -> (ImuBus, Result<(), fc_loop::supervisor::SensorDown>) {
        fc_stm32f405::crtp_image::SimulatorOnly::started()
    }

    #[cfg(not(feature = "qemu"))]
    pub use crate::sensors::{imu_bus, ImuBus};

    /// The vehicle, in static RAM (see `firmware-crtp`), with the
    /// Crazyflie's motor order (`MOT_FRAME` 4) and hub distance; the
    /// simulator (or a client) writes the vehicle's parameters.
    #[inline(never)]
    pub fn vehicle() -> Option<&'static mut CrtpVehicle> {
        let settings = Settings {
            airframe: Airframe::XCrazyflie,
            hub_m: HUB_M,
            ..Settings::os4()
        };
        cortex_m::singleton!(: CrtpVehicle = CrtpVehicle::unstarted(settings))
    }
}

/// The Crazyflie's own sensors on the board build (QEMU models no I2C and
/// no GPIO: there the simulator's samples stand in, on USART1): the BMI088
/// and BMP388 started on I2C3 with the blocking master (every wait
/// bounded), then the gyroscope's data-ready on EXTI14 starting each
/// sample's reads on I2C3's interrupts, the barometer's after every 20th.
#[cfg(all(target_os = "none", not(feature = "qemu")))]
mod sensors {
    use fc_core::estimate::ImuSample;
    use fc_crazyflie::bmi088::Bmi088;
    use fc_crazyflie::bmp388::Bmp388;
    use fc_crazyflie::i2c::I2cMaster;
    use fc_crazyflie::reads::{Finished, Reads};
    use fc_crazyflie::sensor_bus;
    use fc_crazyflie::supervisor::sensors_up;
    use fc_crazyflie::SensorError;
    use fc_loop::baro::pressure_altitude_m;
    use fc_loop::supervisor::SensorDown;
    use nalgebra::Vector3;
    use stm32f4::stm32f405::{exti, i2c1};

    /// A busy-wait delay for the sensors' start-up (interrupts are off in
    /// `init`; SysTick is the clock's).
    struct Spin;

    impl embedded_hal::delay::DelayNs for Spin {
        fn delay_ns(&mut self, ns: u32) {
            // 168 cycles per µs; at least one µs.
            cortex_m::asm::delay((ns / 1000 + 1).saturating_mul(168));
        }
    }

    /// The BMI088 and BMP388 on I2C3, read on the bus's interrupts
    /// ([`Reads`]: the IMU at every data-ready, the barometer after every
    /// 20th sample).
    pub struct ImuBus {
        i2c: &'static i2c1::RegisterBlock,
        exti: &'static exti::RegisterBlock,
        reads: Reads,
        /// The data-ready time of the sample on the bus.
        entry: u64,
        /// Samples done, for `data_ready` (an abandoned one and the next).
        ready: heapless::Deque<(u64, Option<ImuSample>), 2>,
        /// The newest barometer reading: its sample's data-ready time and
        /// pressure altitude, m above sea level.
        baro: Option<(u64, f32)>,
        errors: [u32; 2],
    }

    // SAFETY: I2C3 and EXTI14 are reached only through this value, which
    // the priority-3 tasks alone share (an RTIC resource).
    unsafe impl Send for ImuBus {}

    impl ImuBus {
        /// The first and every 1000th failure of a part (the vehicle counts
        /// the IMU's; a barometer reading missed is one fix fewer).
        fn failed(&mut self, part: usize, e: &SensorError) {
            if self.errors[part].is_multiple_of(1000) {
                defmt::warn!(
                    "{=str} read: {} ({=u32} so far)",
                    ["IMU", "barometer"][part],
                    defmt::Display2Format(e),
                    self.errors[part] + 1
                );
            }
            self.errors[part] = self.errors[part].wrapping_add(1);
        }

        /// What an interrupt finished, the IMU sample's as of data-ready
        /// `at`; `true` if `data_ready` has something to take.
        fn finished(&mut self, at: u64, f: Finished) -> bool {
            let mut ready = false;
            if let Some(r) = f.imu {
                let s = match r {
                    Ok(s) => Some(ImuSample {
                        gyro_frd_radps: Vector3::from(s.gyro_frd_radps),
                        accel_frd_mps2: Vector3::from(s.accel_frd_mps2),
                    }),
                    Err(e) => {
                        self.failed(0, &e);
                        None
                    }
                };
                if self.ready.is_full() {
                    self.ready.pop_front();
                }
                let _ = self.ready.push_back((at, s));
                ready = true;
            }
            match f.baro {
                Some(Ok(b)) => match pressure_altitude_m(b.pressure_pa) {
                    Some(alt) => {
                        self.baro = Some((self.entry, alt));
                        ready = true;
                    }
                    None => self.failed(
                        1,
                        &SensorError::Implausible {
                            device: "BMP388",
                            quantity: "pressure (Pa)",
                        },
                    ),
                },
                Some(Err(e)) => self.failed(1, &e),
                None => {}
            }
            ready
        }
    }

    impl fc_stm32f405::crtp_image::ImuBus for ImuBus {
        fn data_ready(&mut self, entry: u64) -> bool {
            sensor_bus::clear_data_ready(self.exti);
            let last = core::mem::replace(&mut self.entry, entry);
            let f = self.reads.data_ready(&self.i2c);
            // An IMU sample reported here is the last one, abandoned on the
            // bus (this one started), or this one, refused by the bus.
            let at = if self.reads.busy() { last } else { entry };
            self.finished(at, f)
        }

        fn bus_interrupt(&mut self, error: bool) -> bool {
            let f = self.reads.on_interrupt(&self.i2c, error);
            self.finished(self.entry, f)
        }

        fn take(&mut self) -> Option<(u64, Option<ImuSample>)> {
            self.ready.pop_front()
        }

        fn take_baro(&mut self) -> Option<(u64, f32)> {
            self.baro.take()
        }
    }

    /// Starts both parts (their failures logged in full and reported to the
    /// vehicle's supervisor, which refuses arming naming the part), then
    /// the data-ready line.
    pub fn imu_bus() -> (ImuBus, Result<(), SensorDown>) {
        // SAFETY: start-up, once; nothing else touches I2C3, EXTI14 or
        // these pins, and nothing runs concurrently in `init`.
        let (i2c, exti) = unsafe { sensor_bus::start_on_chip() };
        let mut imu = Bmi088::new(I2cMaster::new(i2c));
        let imu_up = imu.init(&mut Spin);
        let mut baro = Bmp388::new(imu.release());
        let baro_up = baro.init(&mut Spin);
        let calibration = baro.calibration().filter(|_| baro_up.is_ok());
        for (part, r) in [("BMI088", imu_up), ("BMP388", baro_up)] {
            match r {
                Ok(()) => defmt::info!("{=str} started on I2C3", part),
                Err(e) => defmt::error!("{=str} did not start: {}", part, defmt::Display2Format(&e)),
            }
        }
        let bus = ImuBus {
            i2c,
            exti,
            reads: Reads::new(calibration),
            entry: 0,
            ready: heapless::Deque::new(),
            baro: None,
            errors: [0; 2],
        };
        (bus, sensors_up(imu_up, baro_up))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!(
        "firmware-crazyflie: this binary is the Crazyflie 2.1 image; build it with --target thumbv7em-none-eabihf"
    );
}
