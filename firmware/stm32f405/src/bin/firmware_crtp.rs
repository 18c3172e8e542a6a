//! The STM32F405 image speaking CRTP as a Crazyflie 2.1's STM32 does
//! (`thumbv7em-none-eabihf`), linked at 0x0800_0000 for QEMU: the RTIC
//! application of `fc_stm32f405::crtp_app` (syslink to the nRF51 radio on USART6,
//! the vehicle `fc_crtp::vehicle::CrtpVehicle` behind it, split between the
//! sample's, the controller's and the link's tasks; the simulator on
//! USART1). Its simulator stands in for the Crazyflie board's BMI088 and
//! flies the step's inputs; the image drives its own four motors on TIM3
//! as the `firmware` image does (PWM at 400 Hz, each rotor's duty its
//! commanded speed over Ωmax, through the vehicle's mixer: `MOT_FRAME`),
//! off while disarmed. QEMU models TIM3: the image logs its compare values
//! (`tools/crtp_cflib.py --qemu` checks them). `firmware-crazyflie` runs the same application on
//! the Crazyflie's own layout and motors.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
fc_stm32f405::board_runtime!();

#[cfg(target_os = "none")]
fc_stm32f405::crtp_app!();

/// This board's outputs: four motors on TIM3 (PWM at 400 Hz; PA6, PA7,
/// PB0, PB1 on most F405 boards), and the steps they have been running.
#[cfg(target_os = "none")]
pub struct BoardOutputs {
    pwm: hal_shim::stm32f405::PwmActuators,
    running_steps: u32,
}

#[cfg(target_os = "none")]
impl BoardOutputs {
    /// TIM3 started, its outputs at 0; its duties are computed by `drive`
    /// (the vehicle and its layout can change), so the driver takes them as
    /// they are.
    fn start() -> Self {
        let pwm = hal_shim::stm32f405::PwmActuators::start(fc_stm32f405::APB1_TIMER_CLK_HZ, 400, |d| *d);
        Self { pwm, running_steps: 0 }
    }
}

#[cfg(target_os = "none")]
impl fc_stm32f405::crtp_image::Outputs for BoardOutputs {
    fn drive(&mut self, v: &fc_crtp::vehicle::CrtpShared, power: &fc_loop::power::Power) {
        use hal_shim::ActuatorOutput;
        match (v.armed(), v.mixer()) {
            (true, Some(_)) => {
                // Each rotor's thrust (the layout's mixer) as its speed,
                // √(T / kf), over Ωmax: the duty.
                let p = v.flight_loop().vehicle();
                let duty = power
                    .thrusts_n
                    .map(|t| libm::sqrtf(t.max(0.0) / p.kf_ns2) / p.omega_max_radps);
                self.pwm.apply(duty.into());
            }
            _ => self.pwm.disarm(),
        }
    }

    fn report(&mut self, _: bool, _: fc_loop::nav::NavMode, _: f32) {
        // What TIM3 holds: logged when the motors start or stop, and once a
        // second (at 1 kHz) while they run.
        let (reload, compare) = self.pwm.registers();
        let running = compare.iter().any(|&c| c > 0);
        let was_running = self.running_steps > 0;
        self.running_steps = if running { self.running_steps.wrapping_add(1) } else { 0 };
        if running != was_running || self.running_steps % 1000 == 500 {
            defmt::info!("motors: TIM3 compare {} of reload {=u32}", compare, reload);
        }
    }
}

/// The tasks' watchdog: the chip's IWDG, started once the IMU task and the
/// controller have both run, fed only while both keep running, as on the
/// Crazyflie image (QEMU models no IWDG: the image's log says it started).
#[cfg(target_os = "none")]
static WATCHDOG: fc_stm32f405::crtp_image::Iwdg = fc_stm32f405::crtp_image::Iwdg::new();

/// The board's own IMU: none; the simulator's samples come on USART1.
#[cfg(target_os = "none")]
type ImuBus = fc_stm32f405::crtp_image::SimulatorOnly;

/// No sensors to start: the simulator's are taken as up.
#[cfg(target_os = "none")]
fn imu_bus() -> (ImuBus, Result<(), fc_loop::supervisor::SensorDown>) {
    fc_stm32f405::crtp_image::SimulatorOnly::started()
}

/// The vehicle, in static RAM (its flight loop and controller are
/// ≈ 8 KiB), built once and unstarted: the controller is designed in
/// place by `start`, after this frame is gone. It boots with the OS4's
/// parameters; the simulator (or a client) writes the vehicle's.
#[cfg(target_os = "none")]
#[inline(never)]
fn vehicle() -> Option<&'static mut fc_crtp::vehicle::CrtpVehicle> {
    use fc_crtp::vehicle::CrtpVehicle;
    cortex_m::singleton!(: CrtpVehicle = CrtpVehicle::unstarted(fc_loop::params::Settings::os4()))
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("firmware-crtp: this binary is the STM32F405 image; build it with --target thumbv7em-none-eabihf");
}
