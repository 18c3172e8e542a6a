//! Our MPC against a peer on the same chip: `tinympc-rs` (ADMM, a Rust port
//! of TinyMPC, `no_std`) and the core's fast MPC solve the same hover
//! regulation problem on the emulated STM32F405 (QEMU `netduinoplus2`,
//! `-icount shift=0`), each in closed loop on the same linear model.
//!
//! The problem (as `sil-host/benches/mpc.rs` flies it on the host): the
//! Euler hover model of the OS4, exact ZOH at 50 ms, the fast preset's Q and
//! R (no input-rate cost: TinyMPC has none), the OS4's input box around
//! hover, horizon 20 prediction steps, 60 closed-loop steps from a
//! (1.5, −1, 0.8) m offset, no disturbance. Ours: 3 moves (12 QP variables),
//! every solve certified to 1e-5 of the objective (no iteration cap).
//! tinympc-rs: 19 free inputs (76 variables), primal and dual tolerance
//! 1e-4, at most 500 ADMM iterations, its cached ρ schedule.
//!
//! For each it prints instructions per MPC step (mean and worst, SysTick
//! counts / 0.168: one instruction is one tick of virtual time under
//! icount) and the closed-loop cost `Σ xᵀQx + uᵀRu`, so that speed is
//! compared at equal tracking.
//!
//! Run: `cargo run --release -p fc-stm32f405 --bin peer --target thumbv7em-none-eabihf`
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::hprintln;
    use fc_core::control::{AttitudeForm, Controller, MpcConfig, MpcFast, ReferenceMode, Setpoint, StateEstimate};
    use fc_core::{euler_hover_model, euler_to_quat, hover_input, zoh, VehicleParams};
    use fc_stm32f405::SYSCLK_HZ;
    use hal_shim::stm32f405::SysTickClock;
    use hal_shim::CycleClock;
    use nalgebra::{SMatrix, SVector, Vector3, Vector4};
    use tinympc_rs::policy::ArrayPolicy;
    use tinympc_rs::project::{time::Fixed, Box as UBox, ProjectMultiExt};
    use tinympc_rs::Solver;

    /// SysTick counts per executed instruction under `-icount shift=0`.
    const TICKS_PER_INSTRUCTION: f32 = 0.168;
    const STEPS: usize = 60;
    /// TinyMPC's horizon: 20 states, 19 inputs.
    const HX: usize = 20;
    const HU: usize = 19;
    type X = SVector<f32, 12>;
    type Cache = ArrayPolicy<f32, 12, 4, 5>;
    type Tiny = Solver<f32, Cache, 12, 4, HX, HU>;

    /// The prediction model: ZOH of the Euler hover model at 50 ms.
    fn model() -> Option<(SMatrix<f32, 12, 12>, SMatrix<f32, 12, 4>)> {
        let p = VehicleParams::<f64>::os4();
        let lm = euler_hover_model(&p, 0.0);
        let (a, b) = zoh(&lm.a, &lm.b, 0.05).ok()?;
        Some((a.cast(), b.cast()))
    }

    fn x0() -> X {
        let mut x = X::zeros();
        x[0] = 1.5;
        x[1] = -1.0;
        x[2] = 0.8;
        x
    }

    /// The fast preset as a pure regulator: one closed-loop step per
    /// prediction step, no disturbance estimate, no input-rate cost,
    /// every solve certified.
    fn regulation_config() -> MpcConfig {
        let mut c = MpcConfig::fast(AttitudeForm::Euler);
        c.exec_dt_s = c.pred_dt_s;
        c.observer_tau_s = None;
        c.disturbance_trend_s = None;
        c.reference = ReferenceMode::Thesis;
        c.s = [1e-6; 4];
        c.qp_max_iterations = u32::MAX;
        c
    }

    fn stage_cost(c: &MpcConfig, x: &X, u: &Vector4<f32>) -> f32 {
        (0..12).map(|i| c.q[i] as f32 * x[i] * x[i]).sum::<f32>()
            + (0..4).map(|i| c.r[i] as f32 * u[i] * u[i]).sum::<f32>()
    }

    /// Instructions (mean, worst) per step and the closed-loop cost.
    struct Run {
        mean: f32,
        worst: f32,
        cost: f32,
        iterations: f32,
    }

    fn ours(a: &SMatrix<f32, 12, 12>, b: &SMatrix<f32, 12, 4>, clock: &SysTickClock) -> Option<Run> {
        let cfg = regulation_config();
        let p = VehicleParams::<f32>::os4();
        let uh = hover_input(&p);
        let mut mpc = MpcFast::<f32>::new(p, cfg).ok()?;
        let sp = Setpoint::hold(Vector3::zeros(), 0.0f32);
        let (mut x, mut cost, mut total, mut worst, mut its) = (x0(), 0.0, 0.0, 0.0f32, 0u32);
        for _ in 0..STEPS {
            let est = StateEstimate {
                pos_ned_m: Vector3::new(x[0], x[1], x[2]),
                vel_ned_mps: Vector3::new(x[3], x[4], x[5]),
                att: euler_to_quat(x[6], x[7], x[8]),
                rates_frd_radps: Vector3::new(x[9], x[10], x[11]),
            };
            let t0 = clock.now();
            let out = mpc.update(&est, &sp).ok()?;
            let n = clock.now().wrapping_sub(t0) as f32 / TICKS_PER_INSTRUCTION;
            its += u32::from(out.status.iterations);
            total += n;
            worst = worst.max(n);
            let du = out.u - uh;
            cost += stage_cost(&cfg, &x, &du);
            x = a * x + b * du;
        }
        Some(Run {
            mean: total / STEPS as f32,
            worst,
            cost,
            iterations: its as f32 / STEPS as f32,
        })
    }

    /// The peer's solver and workspace, in static RAM (≈ 30 KiB).
    static mut TINY: Option<Tiny> = None;

    fn tiny(a: &SMatrix<f32, 12, 12>, b: &SMatrix<f32, 12, 4>, clock: &SysTickClock, tol: f32) -> Option<Run> {
        let cfg = regulation_config();
        let p = VehicleParams::<f32>::os4();
        let bx = p.input_box();
        let uh = hover_input(&p);
        let (lo, hi) = (bx.lo - uh, bx.hi - uh);
        let q = SMatrix::<f32, 12, 12>::from_diagonal(&SVector::from(cfg.q.map(|v| v as f32)));
        let r = SMatrix::<f32, 4, 4>::from_diagonal(&Vector4::from(cfg.r.map(|v| v as f32)));
        let cache = Cache::new(5.0, 10.0, 1.8, HX, a, b, &q, &r, &SMatrix::zeros()).ok()?;
        // SAFETY: single-threaded harness; no interrupt touches TINY.
        let solver = unsafe { &mut *core::ptr::addr_of_mut!(TINY) };
        let tiny = solver.insert(Solver::new(*a, *b, cache));
        tiny.config.max_iter = 500;
        tiny.config.prim_tol = tol;
        tiny.config.dual_tol = tol;
        tiny.config.do_check = 1;
        let xref = SMatrix::<f32, 12, HX>::zeros();
        let xbox = Fixed::new(UBox {
            lower: SVector::from_element(-1e6),
            upper: SVector::from_element(1e6),
        });
        let ubox = Fixed::new(UBox { lower: lo, upper: hi });
        let (mut x, mut cost, mut total, mut worst, mut its) = (x0(), 0.0, 0.0, 0.0f32, 0usize);
        let mut xc = [xbox.dyn_constraint()];
        let mut uc = [ubox.dyn_constraint()];
        for _ in 0..STEPS {
            let t0 = clock.now();
            let sol = tiny.solve(x, Some(&xref), None, Some(&mut xc), Some(&mut uc));
            let u = sol.u_now().zip_zip_map(&lo, &hi, |v, l, h| v.max(l).min(h));
            let n = clock.now().wrapping_sub(t0) as f32 / TICKS_PER_INSTRUCTION;
            its += sol.iterations;
            total += n;
            worst = worst.max(n);
            cost += stage_cost(&cfg, &x, &u);
            x = a * x + b * u;
        }
        Some(Run {
            mean: total / STEPS as f32,
            worst,
            cost,
            iterations: its as f32 / STEPS as f32,
        })
    }

    #[entry]
    fn main() -> ! {
        let clock = SysTickClock::start(SYSCLK_HZ);
        let ok = match model() {
            Some((a, b)) => {
                hprintln!("peer: hover regulation, {} closed-loop steps, instructions per MPC step under QEMU -icount shift=0", STEPS);
                hprintln!("| solver | variables | iterations per step | mean instructions | worst instructions | closed-loop cost |");
                hprintln!("|---|---|---|---|---|---|");
                let rows = [
                    ("ours (FGM, certified 1e-5)", 12, ours(&a, &b, &clock)),
                    ("tinympc-rs 0.2 (ADMM, tol 1e-4)", 76, tiny(&a, &b, &clock, 1e-4)),
                    ("tinympc-rs 0.2 (ADMM, tol 1e-5)", 76, tiny(&a, &b, &clock, 1e-5)),
                    ("tinympc-rs 0.2 (ADMM, tol 1e-6)", 76, tiny(&a, &b, &clock, 1e-6)),
                ];
                let mut all = true;
                for (name, vars, run) in rows.iter() {
                    match run {
                        Some(r) => hprintln!(
                            "| {} | {} | {:.1} | {:.0} | {:.0} | {:.1} |",
                            name,
                            vars,
                            r.iterations,
                            r.mean,
                            r.worst,
                            r.cost
                        ),
                        None => {
                            hprintln!("| {} | {} | failed | | | |", name, vars);
                            all = false;
                        }
                    }
                }
                if let [(_, _, Some(o)), (_, _, Some(t)), ..] = &rows {
                    hprintln!(
                        "peer: tinympc-rs / ours: mean {:.2}x, worst {:.2}x instructions; cost ratio {:.4}",
                        t.mean / o.mean,
                        t.worst / o.worst,
                        t.cost / o.cost
                    );
                }
                all
            }
            None => {
                hprintln!("peer: the model's discretisation failed");
                false
            }
        };
        fc_stm32f405::harness_exit(ok)
    }

    fc_stm32f405::harness_runtime!("peer");
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("peer runs on the MCU: cargo run --release -p fc-stm32f405 --bin peer --target thumbv7em-none-eabihf");
}
