//! Controller behaviour on bad and extreme input: errors for NaN, outputs
//! always inside the input box, the quaternion error the shortest way round.

use fc_core::control::{
    AnyController, ControlError, Controller, LqrEuler, LqrQuat, PdEuler, PdEulerGains, PdQuat, PdQuatGains,
    ReferenceMode, Setpoint, StateEstimate,
};
use fc_core::{euler_to_quat, VehicleParams};
use nalgebra::{Vector3, Vector4};

fn all() -> Vec<AnyController<f32>> {
    let p = VehicleParams::<f32>::os4();
    let m = ReferenceMode::Feedforward;
    vec![
        AnyController::PdEuler(PdEuler::new(p, PdEulerGains::tuned(), m)),
        AnyController::PdQuat(PdQuat::new(p, PdQuatGains::tuned(), m)),
        AnyController::PdQuat(PdQuat::new(p, PdQuatGains::thesis(), m)),
        AnyController::LqrEuler(LqrEuler::thesis(p, 0.002, m).unwrap()),
        AnyController::LqrQuat(LqrQuat::thesis(p, 0.002, m).unwrap()),
    ]
}

fn est(pos: [f32; 3], vel: [f32; 3], rpy: [f32; 3], w: [f32; 3]) -> StateEstimate<f32> {
    StateEstimate {
        pos_ned_m: Vector3::from(pos),
        vel_ned_mps: Vector3::from(vel),
        att: euler_to_quat(rpy[0], rpy[1], rpy[2]),
        rates_frd_radps: Vector3::from(w),
    }
}

#[test]
fn nan_and_non_unit_inputs_are_rejected() {
    let good = est([0.0, 0.0, -1.0], [0.0; 3], [0.0; 3], [0.0; 3]);
    let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
    for mut c in all() {
        let mut bad = good;
        bad.vel_ned_mps[1] = f32::NAN;
        assert_eq!(c.update(&bad, &sp), Err(ControlError::InvalidEstimate));
        let mut bad = good;
        bad.att = Vector4::new(0.5, 0.0, 0.0, 0.0);
        assert_eq!(c.update(&bad, &sp), Err(ControlError::InvalidEstimate));
        let mut bad_sp = sp;
        bad_sp.acc_ned_mps2[2] = f32::INFINITY;
        assert_eq!(c.update(&good, &bad_sp), Err(ControlError::InvalidSetpoint));
        // And it still works afterwards.
        assert!(c.update(&good, &sp).is_ok());
    }
}

#[test]
fn outputs_stay_in_the_box_for_extreme_states() {
    let bx = VehicleParams::<f32>::os4().input_box();
    let mut s = 1u32;
    let mut rnd = |scale: f32| {
        s = s.wrapping_mul(1664525).wrapping_add(1013904223);
        ((s >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 2.0 * scale
    };
    for mut c in all() {
        for _ in 0..500 {
            let e = est(
                [rnd(1e3), rnd(1e3), rnd(1e3)],
                [rnd(50.0), rnd(50.0), rnd(50.0)],
                [rnd(3.1), rnd(1.5), rnd(3.1)],
                [rnd(30.0), rnd(30.0), rnd(30.0)],
            );
            let mut sp = Setpoint::hold(Vector3::new(rnd(1e3), rnd(1e3), rnd(1e3)), rnd(10.0));
            sp.acc_ned_mps2 = Vector3::new(rnd(100.0), rnd(100.0), rnd(100.0));
            sp.jerk_ned_mps3 = Vector3::new(rnd(100.0), rnd(100.0), rnd(100.0));
            let out = c.update(&e, &sp).unwrap();
            assert!(
                bx.violation(&out.u) == 0.0 && out.u.iter().all(|v| v.is_finite()),
                "{}",
                out.u
            );
            assert!(!out.status.saturated || out.status.excursion > 0.0);
        }
    }
}

#[test]
fn quaternion_pd_turns_the_short_way() {
    // Target heading +170°, current −170°: the short way is through ±180°, a
    // yaw error of −20°, i.e. a negative yaw torque (the long way would be
    // +340° and a positive one), whatever the sign of the estimate's quaternion.
    let p = VehicleParams::<f32>::os4();
    let mut c = PdQuat::new(p, PdQuatGains::tuned(), ReferenceMode::Thesis);
    let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 170f32.to_radians());
    let mut e = est([0.0, 0.0, -1.0], [0.0; 3], [0.0, 0.0, -170f32.to_radians()], [0.0; 3]);
    let u_pos = c.update(&e, &sp).unwrap().u[3];
    e.att = -e.att;
    let u_neg = c.update(&e, &sp).unwrap().u[3];
    assert!(u_pos < 0.0, "{u_pos}");
    assert_eq!(u_pos, u_neg);
    // A small positive heading error (target 0.1 rad ahead) gives a positive torque.
    let sp2 = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.1);
    let e2 = est([0.0, 0.0, -1.0], [0.0; 3], [0.0; 3], [0.0; 3]);
    assert!(c.update(&e2, &sp2).unwrap().u[3] > 0.0);
}

#[test]
fn fast_mpc_storage_fits_16_kib() {
    // Everything the controller keeps between steps (models, weights, the
    // Hessian and its scaling, the designed responses, the preview buffer,
    // warm start, estimates): issue 14's budget for the MPC's RAM.
    let size = core::mem::size_of::<fc_core::control::MpcFast<f32>>();
    assert!(size <= 16 * 1024, "MpcFast<f32> is {size} bytes");
    eprintln!("size_of::<MpcFast<f32>>() = {size} bytes");
}
