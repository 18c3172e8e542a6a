//! The closed loop that `tests/tests/qemu.rs` flies on the host and on the
//! MCU: the `fast` MPC (quaternion) flies 40 steps (0.2 s) of the set-point
//! step against the core's own model (Euler-integrated in `f32`). The
//! `equivalence` program runs it in QEMU; the test runs the same function
//! in-process and compares the two. Only the `f32` math library differs
//! (glibc vs `libm` for atan/asin), so the outputs agree to a few ulps.

use fc_core::control::{AttitudeForm, Controller, MpcConfig, MpcFast, Setpoint, StateEstimate};
use fc_core::VehicleParams;
use nalgebra::Vector3;

/// Steps the loop flies (0.2 s at the MPC's 5 ms).
pub const STEPS: u32 = 40;

/// Flies the loop, reporting each step `k`'s QP iterations and the inputs
/// U1..U4 (N, N·m) to `out`. Never panics: a controller that cannot be built
/// or refuses a step ends the loop early, which the comparison then sees as
/// missing steps.
pub fn run(mut out: impl FnMut(u32, u32, [f32; 4])) {
    use fc_core::{hover_quat_state, Disturbance, Vehicle};
    let p = VehicleParams::<f32>::os4();
    let v = Vehicle::new(&p);
    let Ok(mut c) = MpcFast::new(p, MpcConfig::fast(AttitudeForm::Quaternion)) else {
        return;
    };
    let sp = Setpoint::hold(Vector3::new(3.0, 2.0, -5.0), 0.26f32);
    let mut x = hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.0f32);
    let d = Disturbance::none();
    for k in 0..STEPS {
        let est = StateEstimate::from_quat_state(&x);
        let Ok(o) = c.update(&est, &sp) else {
            return;
        };
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
