//! The STM32F405 image speaking CRTP as a Crazyflie 2.1's STM32 does
//! (`thumbv7em-none-eabihf`), linked at 0x0800_0000 for QEMU: the RTIC
//! application of `src/crtp_app.rs` (syslink to the nRF51 radio on USART6,
//! the vehicle `fc_crtp::vehicle::CrtpVehicle` behind it, split between the
//! sample's, the controller's and the link's tasks; the simulator on
//! USART1). Its simulator stands in for the Crazyflie board's BMI088 and
//! flies the inputs (this board drives no motors of its own);
//! `firmware-crazyflie` runs the same application on the Crazyflie's own
//! layout and motors.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
#[path = "../board.rs"]
mod board;

#[cfg(target_os = "none")]
#[path = "../crtp_app.rs"]
mod crtp_app;

/// This board's outputs: none (the simulator flies the step's inputs).
#[cfg(target_os = "none")]
pub struct BoardOutputs;

#[cfg(target_os = "none")]
impl BoardOutputs {
    /// Nothing to start.
    fn start() -> Self {
        Self
    }
}

#[cfg(target_os = "none")]
impl fc_stm32f405::crtp_image::Outputs for BoardOutputs {
    fn drive(&mut self, _: &fc_crtp::vehicle::CrtpCore, _: &nalgebra::Vector4<f32>) {}
}

/// This lockstep test image arms no watchdog (the Crazyflie image does:
/// `fc_crazyflie::watchdog`); the tasks' reports go nowhere.
#[cfg(target_os = "none")]
pub struct NoWatchdog;

#[cfg(target_os = "none")]
impl fc_stm32f405::crtp_image::Watchdog for NoWatchdog {
    fn imu_step(&self) {}
    fn controller_step(&self) {}
    fn designing(&self, _: bool) {}
    fn service(&self) {}
}

/// The tasks' watchdog: none on this image.
#[cfg(target_os = "none")]
static WATCHDOG: NoWatchdog = NoWatchdog;

/// The board's own IMU: none; the simulator's samples come on USART1.
#[cfg(target_os = "none")]
type ImuBus = fc_stm32f405::crtp_image::SimulatorOnly;

/// No sensors to start: the simulator's are taken as up.
#[cfg(target_os = "none")]
fn imu_bus() -> (ImuBus, Result<(), fc_crtp::supervisor::SensorDown>) {
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
