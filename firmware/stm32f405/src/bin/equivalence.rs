//! The same controller, the same closed loop, on the host and on the MCU:
//! the `fast` MPC (quaternion) flies 40 steps (0.2 s) of the set-point step
//! against the core's own model (Euler-integrated in `f32`), and prints, per
//! step, `k iterations U1 U2 U3 U4`. Run it on the host (`cargo run -p
//! fc-stm32f405 --bin equivalence`) and in QEMU (`--target
//! thumbv7em-none-eabihf`); `tests/tests/qemu.rs` compares the two. Only the
//! `f32` math library differs (glibc vs `libm` for atan/asin), so the outputs
//! agree to a few ulps.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
use fc_core::control::{AttitudeForm, Controller, MpcConfig, MpcFast, Setpoint, StateEstimate};
use fc_core::VehicleParams;
use nalgebra::Vector3;
#[cfg(target_os = "none")]
use stm32f4 as _;

/// Flies the loop, reporting each step's QP iterations and inputs.
fn run(mut out: impl FnMut(u32, u32, [f32; 4])) {
    use fc_core::{hover_quat_state, Disturbance, Vehicle};
    let p = VehicleParams::<f32>::os4();
    let v = Vehicle::new(&p);
    let mut c = MpcFast::new(p, MpcConfig::fast(AttitudeForm::Quaternion)).unwrap();
    let sp = Setpoint::hold(Vector3::new(3.0, 2.0, -5.0), 0.26f32);
    let mut x = hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.0f32);
    let d = Disturbance::none();
    for k in 0..40u32 {
        let est = StateEstimate::from_quat_state(&x);
        let o = c.update(&est, &sp).unwrap();
        let w = p.hover_rotor_speed_radps();
        for _ in 0..5 {
            x += v.quat_derivative(&x, &o.u, 0.0 * w, &d) * 0.001;
        }
        let n = x.fixed_rows::<4>(6).norm();
        let q = x.fixed_rows::<4>(6) / n;
        x.fixed_rows_mut::<4>(6).copy_from(&q);
        out(k, o.status.iterations as u32, [o.u[0], o.u[1], o.u[2], o.u[3]]);
    }
}

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    #[entry]
    fn main() -> ! {
        super::run(|k, it, u| hprintln!("{} {} {:e} {:e} {:e} {:e}", k, it, u[0], u[1], u[2], u[3]));
        debug::exit(debug::EXIT_SUCCESS);
        loop {
            cortex_m::asm::wfi();
        }
    }
    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        debug::exit(debug::EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    run(|k, it, u| println!("{} {} {:e} {:e} {:e} {:e}", k, it, u[0], u[1], u[2], u[3]));
}
