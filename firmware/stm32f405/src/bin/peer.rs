//! Our MPC against a peer on the same chip: `tinympc-rs` (ADMM, a Rust port
//! of TinyMPC, `no_std`) and the core's fast MPC solve the same hover
//! regulation problem on the emulated STM32F405 (QEMU `netduinoplus2`,
//! `-icount shift=0`), each in closed loop on the same linear model.
//!
//! The problem (as `sil-host/benches/mpc.rs` flies it on the host): the
//! Euler hover model of the OS4, exact ZOH at 50 ms, the benchmark's Q and
//! the fast preset's R (no input-rate cost: TinyMPC has none), the OS4's
//! input box around hover, horizon 20 prediction steps, 60 closed-loop steps
//! from a (1.5, −1, 0.8) m offset, no disturbance. A second pair of rows
//! flies it with the flight preset's light rate weights
//! ([`fc_core::control::regulation::Weights`]). Ours: 3 moves (12 QP variables),
//! every solve exact (the four input channels' 3-variable blocks, every
//! active set tried: [`fc_core::qp::Blocks`]).
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

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::hprintln;
    use fc_core::control::regulation::{self, Weights, HORIZON, STEPS};
    use fc_core::control::MpcConfig;
    use fc_core::control::{Controller, MpcFast};
    use fc_core::{hover_input, VehicleParams};
    use fc_stm32f405::SYSCLK_HZ;
    use hal_shim::stm32f405::SysTickClock;
    use hal_shim::CycleClock;
    use nalgebra::{SMatrix, SVector, Vector4};
    use tinympc_rs::policy::ArrayPolicy;
    use tinympc_rs::project::{time::Fixed, Box as UBox, ProjectMultiExt};
    use tinympc_rs::Solver;

    /// SysTick counts per executed instruction under `-icount shift=0`.
    const TICKS_PER_INSTRUCTION: f32 = 0.168;
    /// TinyMPC's horizon: 20 states, 19 inputs.
    const HX: usize = HORIZON;
    const HU: usize = HORIZON - 1;
    type Cache = ArrayPolicy<f32, 12, 4, 5>;
    type Tiny = Solver<f32, Cache, 12, 4, HX, HU>;

    /// Instructions (mean, worst) per step, mean iterations per step and the
    /// closed-loop cost of one episode.
    struct Run {
        mean: f32,
        worst: f32,
        cost: f64,
        iterations: f32,
    }

    /// `f()` and the instructions it executed.
    fn measure<R>(clock: &SysTickClock, f: impl FnOnce() -> R) -> (R, f32) {
        let t0 = clock.now();
        let r = f();
        (r, clock.now().wrapping_sub(t0) as f32 / TICKS_PER_INSTRUCTION)
    }

    /// One episode of the shared regulation problem: `solve(x)` gives the
    /// input, the solver's iterations and the instructions its solve took
    /// (timed with [`measure`] around the solver call alone).
    fn timed(
        cfg: &MpcConfig,
        a: &SMatrix<f32, 12, 12>,
        b: &SMatrix<f32, 12, 4>,
        mut solve: impl FnMut(&regulation::State) -> Option<(regulation::Input, usize, f32)>,
    ) -> Option<Run> {
        let (mut total, mut worst, mut its) = (0.0f32, 0.0f32, 0usize);
        let cost = regulation::episode(cfg, a, b, |x| {
            let (u, n, ins) = solve(x)?;
            total += ins;
            worst = worst.max(ins);
            its += n;
            Some(u)
        })?;
        Some(Run {
            mean: total / STEPS as f32,
            worst,
            cost,
            iterations: its as f32 / STEPS as f32,
        })
    }

    fn ours(w: Weights, a: &SMatrix<f32, 12, 12>, b: &SMatrix<f32, 12, 4>, clock: &SysTickClock) -> Option<Run> {
        let p = VehicleParams::<f32>::os4();
        let uh = hover_input(&p);
        let target = regulation::target();
        let cfg = regulation::config_with(w);
        let mut mpc = MpcFast::<f32>::new(p, cfg).ok()?;
        timed(&cfg, a, b, |x| {
            let est = regulation::estimate(x);
            let (out, ins) = measure(clock, || mpc.update(&est, &target));
            let out = out.ok()?;
            Some((out.u - uh, usize::from(out.status.iterations), ins))
        })
    }

    /// The peer's solver and workspace, in static RAM (≈ 30 KiB).
    static mut TINY: Option<Tiny> = None;

    fn tiny(
        w: Weights,
        a: &SMatrix<f32, 12, 12>,
        b: &SMatrix<f32, 12, 4>,
        clock: &SysTickClock,
        tol: f32,
    ) -> Option<Run> {
        let cfg = regulation::config_with(w);
        let (lo, hi) = regulation::input_box();
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
        let mut xc = [xbox.dyn_constraint()];
        let mut uc = [ubox.dyn_constraint()];
        timed(&cfg, a, b, |x| {
            let (sol, ins) = measure(clock, || {
                tiny.solve(*x, Some(&xref), None, Some(&mut xc), Some(&mut uc))
            });
            Some((sol.u_now(), sol.iterations, ins))
        })
    }

    #[entry]
    fn main() -> ! {
        let clock = SysTickClock::start(SYSCLK_HZ);
        let ok = match regulation::model() {
            Ok((a, b)) => {
                hprintln!("peer: hover regulation, {} closed-loop steps, instructions per MPC step under QEMU -icount shift=0", STEPS);
                hprintln!("| solver | variables | iterations per step | mean instructions | worst instructions | closed-loop cost |");
                hprintln!("|---|---|---|---|---|---|");
                let bench = Weights::Benchmark;
                let flight = Weights::Flight;
                let rows = [
                    ("ours (exact QP: 108 active sets)", 12, ours(bench, &a, &b, &clock)),
                    ("tinympc-rs 0.2 (ADMM, tol 1e-4)", 76, tiny(bench, &a, &b, &clock, 1e-4)),
                    ("tinympc-rs 0.2 (ADMM, tol 1e-5)", 76, tiny(bench, &a, &b, &clock, 1e-5)),
                    ("tinympc-rs 0.2 (ADMM, tol 1e-6)", 76, tiny(bench, &a, &b, &clock, 1e-6)),
                    ("flight rate weights: ours", 12, ours(flight, &a, &b, &clock)),
                    (
                        "flight rate weights: tinympc-rs 0.2 (tol 1e-4)",
                        76,
                        tiny(flight, &a, &b, &clock, 1e-4),
                    ),
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
                        (t.cost / o.cost) as f32
                    );
                }
                all
            }
            Err(_) => {
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
