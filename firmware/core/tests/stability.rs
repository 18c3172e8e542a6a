//! Closed-loop stability about hover for every controller: the controller is
//! linearised by central differences in Euler coordinates, the loop is closed
//! with the exact ZOH hover model at the control rate, and every eigenvalue of
//! `Ad + Bd·∂u/∂x` must lie inside the unit circle.

use fc_core::control::{
    AnyController, Controller, LqrEuler, LqrQuat, PdEuler, PdEulerGains, PdQuat, PdQuatGains, ReferenceMode, Setpoint,
    StateEstimate,
};
use fc_core::{euler_hover_model, euler_state_to_quat, hover_euler_state, zoh, EulerState, VehicleParams};
use nalgebra::{SMatrix, Vector3};

const TS: f64 = 0.002;

fn controllers(mode: ReferenceMode) -> Vec<(&'static str, AnyController<f64>)> {
    let p = VehicleParams::<f64>::os4();
    vec![
        (
            "pd euler tuned",
            AnyController::PdEuler(PdEuler::new(p, PdEulerGains::tuned(), mode)),
        ),
        (
            "pd quat tuned",
            AnyController::PdQuat(PdQuat::new(p, PdQuatGains::tuned(), mode)),
        ),
        (
            "pd quat thesis",
            AnyController::PdQuat(PdQuat::new(p, PdQuatGains::thesis(), mode)),
        ),
        (
            "lqr euler",
            AnyController::LqrEuler(LqrEuler::thesis(p, TS, mode).unwrap()),
        ),
        (
            "lqr quat",
            AnyController::LqrQuat(LqrQuat::thesis(p, TS, mode).unwrap()),
        ),
    ]
}

/// ∂u/∂x of the controller at hover (Euler coordinates), holding `x0`.
fn linearise(c: &mut AnyController<f64>, x0: &EulerState<f64>) -> SMatrix<f64, 4, 12> {
    let sp = Setpoint::hold(Vector3::new(x0[0], x0[1], x0[2]), x0[8]);
    let u = |c: &mut AnyController<f64>, x: &EulerState<f64>| {
        c.update(&StateEstimate::from_quat_state(&euler_state_to_quat(x)), &sp)
            .unwrap()
            .u
    };
    let h = 1e-6;
    let mut k = SMatrix::<f64, 4, 12>::zeros();
    for j in 0..12 {
        let (mut xp, mut xm) = (*x0, *x0);
        xp[j] += h;
        xm[j] -= h;
        k.set_column(j, &((u(c, &xp) - u(c, &xm)) / (2.0 * h)));
    }
    k
}

#[test]
fn every_controller_is_stable_about_hover() {
    let p = VehicleParams::<f64>::os4();
    for mode in [ReferenceMode::Feedforward, ReferenceMode::Thesis] {
        for yaw_deg in [0.0f64, 15.0, 100.0, 180.0, -135.0] {
            let yaw = yaw_deg.to_radians();
            let x0 = hover_euler_state(&Vector3::new(1.0, -2.0, -3.0), yaw);
            let lm = euler_hover_model(&p, yaw);
            let (ad, bd) = zoh(&lm.a, &lm.b, TS).unwrap();
            for (name, mut c) in controllers(mode) {
                let ku = linearise(&mut c, &x0);
                // Hover must be an equilibrium of the controller too: u(x0) = mg.
                let sp = Setpoint::hold(Vector3::new(1.0, -2.0, -3.0), yaw);
                let u0 = c
                    .update(&StateEstimate::from_quat_state(&euler_state_to_quat(&x0)), &sp)
                    .unwrap()
                    .u;
                assert!((u0[0] - p.hover_thrust_n()).abs() < 1e-9 && u0.fixed_rows::<3>(1).amax() < 1e-9);
                let acl = ad + bd * ku;
                let eig = acl.complex_eigenvalues();
                let rho = eig.iter().map(|l| l.norm()).fold(0.0, f64::max);
                assert!(rho < 1.0 - 1e-7, "{name} {mode:?} yaw {yaw_deg}: spectral radius {rho}");
                // And the loop is really closed: every mode moves (no eigenvalue at 1).
                assert!(eig.iter().all(|l| (l - nalgebra::Complex::new(1.0, 0.0)).norm() > 1e-7));
            }
        }
    }
}

/// Spectral radius of the 500 Hz closed loop of `c` about hover at `yaw_deg`.
fn spectral_radius(c: &mut AnyController<f64>, yaw_deg: f64) -> f64 {
    let p = VehicleParams::<f64>::os4();
    let yaw = yaw_deg.to_radians();
    let x0 = hover_euler_state(&Vector3::new(0.0, 0.0, -1.0), yaw);
    let lm = euler_hover_model(&p, yaw);
    let (ad, bd) = zoh(&lm.a, &lm.b, TS).unwrap();
    let acl = ad + bd * linearise(c, &x0);
    acl.complex_eigenvalues().iter().map(|l| l.norm()).fold(0.0, f64::max)
}

#[test]
fn printed_roll_pitch_gains_leave_the_euler_pd_marginal() {
    // Table 4.2's roll/pitch gains (a copy of Table 4.1's x/y gains) put the
    // slowest closed-loop mode at or past the unit circle: time constant > 4 s
    // at 0° (ρ > 0.9995 at 500 Hz) and unstable at 15°. The tuned gains fix it.
    let p = VehicleParams::<f64>::os4();
    let mut thesis = AnyController::PdEuler(PdEuler::new(p, PdEulerGains::thesis(), ReferenceMode::Thesis));
    let mut tuned = AnyController::PdEuler(PdEuler::new(p, PdEulerGains::tuned(), ReferenceMode::Thesis));
    let r0 = spectral_radius(&mut thesis, 0.0);
    let r15 = spectral_radius(&mut thesis, 15.0);
    assert!(r0 > 0.9995 && r0 < 1.0, "{r0}");
    assert!(r15 > 1.0, "{r15}");
    for yaw in [0.0, 15.0, 45.0] {
        assert!(spectral_radius(&mut tuned, yaw) < 0.9985, "tuned at {yaw}");
    }
}
