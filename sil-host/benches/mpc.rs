//! One MPC step: both presets of the core's MPC, and — on the same hover
//! regulation problem (same ZOH model at 50 ms, Q, R, input box, horizon) —
//! ours against `tinympc-rs` (ADMM, a Rust port of TinyMPC). Each solver flies
//! the same closed loop on the linear model; the bench reports time per step
//! and prints the closed-loop cost of each so speed is compared at equal
//! tracking.

use criterion::{criterion_group, criterion_main, Criterion};
use fc_core::control::{
    AttitudeForm, Controller, MpcConfig, MpcFast, MpcThesis, ReferenceMode, Setpoint, StateEstimate,
};
use fc_core::{euler_hover_model, euler_to_quat, hover_input, zoh, VehicleParams};
use nalgebra::{SMatrix, SVector, Vector3, Vector4};
use std::hint::black_box;
use tinympc_rs::policy::ArrayPolicy;
use tinympc_rs::project::{time::Fixed, Box as UBox, ProjectMultiExt};
use tinympc_rs::Solver;

const STEPS: usize = 60;
type X = SVector<f32, 12>;

fn model() -> (SMatrix<f32, 12, 12>, SMatrix<f32, 12, 4>) {
    let p = VehicleParams::<f64>::os4();
    let lm = euler_hover_model(&p, 0.0);
    let (a, b) = zoh(&lm.a, &lm.b, 0.05).unwrap();
    (a.cast(), b.cast())
}

fn x0() -> X {
    let mut x = X::zeros();
    x[0] = 1.5;
    x[1] = -1.0;
    x[2] = 0.8;
    x
}

fn regulation_config() -> MpcConfig {
    let mut c = MpcConfig::fast(AttitudeForm::Euler);
    c.exec_dt_s = c.pred_dt_s; // one closed-loop step = one prediction step
    c.observer_tau_s = None; // a regulation problem: no disturbance, no trend
    c.disturbance_trend_s = None;
    c.reference = ReferenceMode::Thesis;
    c.s = [1e-6; 4]; // TinyMPC has no input-rate cost
    c.qp_max_iterations = u32::MAX; // every solve certified, as on the chip (bin `peer`)
    c
}

fn stage_cost(c: &MpcConfig, x: &X, u: &Vector4<f32>) -> f64 {
    (0..12).map(|i| c.q[i] * (x[i] as f64).powi(2)).sum::<f64>()
        + (0..4).map(|i| c.r[i] * (u[i] as f64).powi(2)).sum::<f64>()
}

/// Our MPC in closed loop on the linear model; returns the closed-loop cost.
fn ours_episode(mpc: &mut MpcFast<f32>, a: &SMatrix<f32, 12, 12>, b: &SMatrix<f32, 12, 4>, cfg: &MpcConfig) -> f64 {
    let uh = hover_input(&VehicleParams::<f32>::os4());
    mpc.reset();
    let mut x = x0();
    let sp = Setpoint::hold(Vector3::zeros(), 0.0f32);
    let mut cost = 0.0;
    for _ in 0..STEPS {
        let est = StateEstimate {
            pos_ned_m: Vector3::new(x[0], x[1], x[2]),
            vel_ned_mps: Vector3::new(x[3], x[4], x[5]),
            att: euler_to_quat(x[6], x[7], x[8]),
            rates_frd_radps: Vector3::new(x[9], x[10], x[11]),
        };
        let du = mpc.update(black_box(&est), &sp).unwrap().u - uh;
        cost += stage_cost(cfg, &x, &du);
        x = a * x + b * du;
    }
    cost
}

fn bench(c: &mut Criterion) {
    let (a, b) = model();
    let cfg = regulation_config();
    let p = VehicleParams::<f32>::os4();
    let bx = p.input_box();
    let uh = hover_input(&p);
    let (lo, hi) = (bx.lo - uh, bx.hi - uh);

    // Ours, regulation problem.
    let mut ours = MpcFast::<f32>::new(p, cfg).unwrap();
    let ours_cost = ours_episode(&mut ours, &a, &b, &cfg);

    // TinyMPC on the same problem: horizon 20 states, 19 inputs.
    const HX: usize = 20;
    const HU: usize = 19;
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
        let mut x = x0();
        let mut cost = 0.0;
        let mut iters = 0;
        let mut xc = [xbox.dyn_constraint()];
        let mut uc = [ubox.dyn_constraint()];
        for _ in 0..STEPS {
            let sol = tiny.solve(black_box(x), Some(&xref), None, Some(&mut xc), Some(&mut uc));
            iters += sol.iterations;
            let u = sol.u_now().zip_zip_map(&lo, &hi, |v, l, h| v.max(l).min(h));
            cost += stage_cost(&cfg, &x, &u);
            x = a * x + b * u;
        }
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
        bch.iter(|| ours_episode(&mut ours, &a, &b, &cfg))
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
