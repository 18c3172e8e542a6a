//! One controller step of each f32 controller on the host (what the SIL
//! reports as `step_time_ns`), at a mid-circle state with feed-forward.

use criterion::{criterion_group, criterion_main, Criterion};
use fc_core::control::{Controller, Setpoint, StateEstimate};
use fc_core::control::{ControllerSpec, Family};
use fc_core::euler_to_quat;
use nalgebra::Vector3;
use sil_host::AttitudeForm;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let est = StateEstimate {
        pos_ned_m: Vector3::new(1.2, 0.3, -1.1f32),
        vel_ned_mps: Vector3::new(0.4, 0.5, -0.05),
        att: euler_to_quat(0.05, -0.03, 0.2),
        rates_frd_radps: Vector3::new(0.1, -0.05, 0.02),
    };
    let sp = Setpoint {
        pos_ned_m: Vector3::new(1.25, 0.35, -1.0f32),
        vel_ned_mps: Vector3::new(0.45, 0.5, 0.0),
        acc_ned_mps2: Vector3::new(-0.1, 0.15, 0.0),
        jerk_ned_mps3: Vector3::new(-0.05, -0.03, 0.0),
        yaw_rad: 0.26,
        yaw_rate_radps: 0.0,
    };
    let mut g = c.benchmark_group("controller_step_f32");
    for (fam, model, name) in [
        (Family::Pd, AttitudeForm::Euler, "pd_euler"),
        (Family::Pd, AttitudeForm::Quaternion, "pd_quaternion"),
        (Family::Lqr, AttitudeForm::Euler, "lqr_euler"),
        (Family::Lqr, AttitudeForm::Quaternion, "lqr_quaternion"),
    ] {
        let mut ctrl = ControllerSpec::new(fam, model)
            .build(fc_core::VehicleParams::<f32>::os4(), 0.002)
            .unwrap();
        g.bench_function(name, |b| {
            b.iter(|| ctrl.update(black_box(&est), black_box(&sp)).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
