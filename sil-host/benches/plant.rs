//! Plant speed: one 1 ms step (one RK4 sub-step at 1 kHz) of each plant form.
//! Simulated seconds per wall second = 1 ms / (time per step).

use criterion::{criterion_group, criterion_main, Criterion};
use fc_core::hover_quat_state;
use nalgebra::{Vector3, Vector4};
use sil_host::{AttitudeForm, DisturbanceSet, Plant, PlantConfig};
use std::hint::black_box;

fn bench_plant(c: &mut Criterion) {
    let u = Vector4::new(6.4765, 0.001, 0.0, 0.01);
    let x0 = hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.0);
    let mut g = c.benchmark_group("plant_1khz_step");
    for (name, model, lag, dist) in [
        ("quaternion", AttitudeForm::Quaternion, false, DisturbanceSet::NONE),
        ("euler", AttitudeForm::Euler, false, DisturbanceSet::NONE),
        (
            "quaternion_lag_wind",
            AttitudeForm::Quaternion,
            true,
            DisturbanceSet {
                wind: true,
                mismatch: false,
            },
        ),
    ] {
        let mut cfg = PlantConfig::nominal(model).with_disturbance(dist);
        cfg.rotor_lag = lag;
        let mut plant = Plant::new(cfg, &x0);
        g.bench_function(name, |b| {
            b.iter(|| {
                plant.step(black_box(&u), black_box(1e-3));
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_plant);

fn bench_parts(c: &mut Criterion) {
    let x0 = hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.0);
    let v = fc_core::Vehicle::new(&fc_core::VehicleParams::OS4);
    let u = Vector4::new(6.4765, 0.001, 0.0, 0.01);
    let d = fc_core::Disturbance::none();
    c.bench_function("quat_derivative", |b| {
        b.iter(|| v.quat_derivative(black_box(&x0), black_box(&u), 0.1, &d))
    });
    let mut plant = Plant::new(PlantConfig::nominal(AttitudeForm::Quaternion), &x0);
    c.bench_function("plant_10ms_10substeps", |b| b.iter(|| plant.step(black_box(&u), 1e-2)));
    let mut p1 = Plant::new(PlantConfig::nominal(AttitudeForm::Quaternion), &x0);
    let mut p2 = Plant::new(PlantConfig::nominal(AttitudeForm::Quaternion), &x0);
    c.bench_function("two_plants_1ms", |b| {
        b.iter(|| {
            p1.step(black_box(&u), 1e-3);
            p2.step(black_box(&u), 1e-3);
        })
    });
    let p = fc_core::VehicleParams::OS4;
    c.bench_function("rotor_speeds", |b| b.iter(|| fc_core::rotor_speeds(&p, black_box(&u))));
}
criterion_group!(parts, bench_parts);
criterion_main!(benches, parts);
