//! One MPC step: both presets of the core's MPC, and — on the same hover
//! regulation problem (same ZOH model at 50 ms, Q, R, input box, horizon) —
//! ours against `tinympc-rs` (ADMM, a Rust port of TinyMPC). Each solver flies
//! the same closed loop on the linear model; the bench reports time per step
//! and prints the closed-loop cost of each so speed is compared at equal
//! tracking.

use criterion::{criterion_group, criterion_main, Criterion};
use fc_core::control::regulation::{self, HORIZON, STEPS};
use fc_core::control::{AttitudeForm, Controller, MpcConfig, MpcFast, MpcThesis, Setpoint, StateEstimate};
use fc_core::{euler_to_quat, VehicleParams};
use nalgebra::{SMatrix, SVector, Vector3, Vector4};
use std::hint::black_box;
use tinympc_rs::policy::ArrayPolicy;
use tinympc_rs::project::{time::Fixed, Box as UBox, ProjectMultiExt};
use tinympc_rs::Solver;

/// Our MPC over one episode of the shared regulation problem; its cost.
fn ours_episode(mpc: &mut MpcFast<f32>, a: &SMatrix<f32, 12, 12>, b: &SMatrix<f32, 12, 4>) -> f64 {
    mpc.reset();
    regulation::episode(&regulation::config(), a, b, |x| {
        regulation::ours(mpc, black_box(x)).map(|(u, _)| u)
    })
    .unwrap()
}

fn bench(c: &mut Criterion) {
    let (a, b) = regulation::model().unwrap();
    let cfg = regulation::config();
    let p = VehicleParams::<f32>::os4();
    let (lo, hi) = regulation::input_box();

    // Ours, regulation problem.
    let mut ours = MpcFast::<f32>::new(p, cfg).unwrap();
    let ours_cost = ours_episode(&mut ours, &a, &b);

    // TinyMPC on the same problem: horizon 20 states, 19 inputs.
    const HX: usize = HORIZON;
    const HU: usize = HORIZON - 1;
    let q = SMatrix::<f32, 12, 12>::from_diagonal(&SVector::from(cfg.q.map(|v| v as f32)));
    let r = SMatrix::<f32, 4, 4>::from_diagonal(&Vector4::from(cfg.r.map(|v| v as f32)));
    type Cache = ArrayPolicy<f32, 12, 4, 5>;
    let cache = Cache::new(5.0, 10.0, 1.8, HX, &a, &b, &q, &r, &SMatrix::zeros()).unwrap();
    let mut tiny = Solver::<f32, Cache, 12, 4, HX, HU>::new(a, b, cache);
    tiny.config.max_iter = 500;
    tiny.config.prim_tol = 1e-4;
    tiny.config.dual_tol = 1e-4;
    tiny.config.do_check = 1;
    let xref = SMatrix::<f32, 12, HX>::zeros();
    let xbox = Fixed::new(UBox {
        lower: SVector::from_element(-1e6),
        upper: SVector::from_element(1e6),
    });
    let ubox = Fixed::new(UBox { lower: lo, upper: hi });
    let tiny_episode = |tiny: &mut Solver<f32, Cache, 12, 4, HX, HU>| -> (f64, usize) {
        let mut iters = 0;
        let mut xc = [xbox.dyn_constraint()];
        let mut uc = [ubox.dyn_constraint()];
        let cost = regulation::episode(&cfg, &a, &b, |x| {
            let sol = tiny.solve(black_box(*x), Some(&xref), None, Some(&mut xc), Some(&mut uc));
            iters += sol.iterations;
            Some(sol.u_now())
        })
        .unwrap();
        (cost, iters)
    };
    let (tiny_cost, tiny_iters) = tiny_episode(&mut tiny);
    eprintln!(
        "closed-loop cost over {STEPS} steps (lower is better): ours {ours_cost:.2}, tinympc-rs {tiny_cost:.2} \
         (ratio {:.4}); tinympc-rs ADMM iterations per step {:.1}",
        tiny_cost / ours_cost,
        tiny_iters as f64 / STEPS as f64
    );

    let mut g = c.benchmark_group("mpc_step");
    g.bench_function("ours_fast_regulation_60_steps", |bch| {
        bch.iter(|| ours_episode(&mut ours, &a, &b))
    });
    g.bench_function("tinympc_rs_regulation_60_steps", |bch| {
        bch.iter(|| tiny_episode(&mut tiny))
    });

    // The flight presets at a mid-circle state with preview (what the SIL runs).
    let est = StateEstimate {
        pos_ned_m: Vector3::new(1.2, 0.3, -1.1f32),
        vel_ned_mps: Vector3::new(0.4, 0.5, -0.05),
        att: euler_to_quat(0.05, -0.03, 0.2),
        rates_frd_radps: Vector3::new(0.1, -0.05, 0.02),
    };
    let mut sp = Setpoint::hold(Vector3::new(1.25, 0.35, -1.0f32), 0.26);
    sp.vel_ned_mps = Vector3::new(0.45, 0.5, 0.0);
    sp.acc_ned_mps2 = Vector3::new(-0.1, 0.15, 0.0);
    for form in AttitudeForm::ALL {
        let mut fast = MpcFast::<f32>::new(p, MpcConfig::fast(form)).unwrap();
        let mut thesis = MpcThesis::<f32>::new(p, MpcConfig::thesis(form)).unwrap();
        let name = if form == AttitudeForm::Euler {
            "euler"
        } else {
            "quaternion"
        };
        g.bench_function(format!("fast_{name}_step"), |bch| {
            bch.iter(|| fast.update(black_box(&est), &sp).unwrap())
        });
        g.bench_function(format!("thesis_{name}_step"), |bch| {
            bch.iter(|| thesis.update(black_box(&est), &sp).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
