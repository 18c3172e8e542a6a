//! QP solver against exact enumeration of active sets (independent truth for
//! small sizes): random, ill-conditioned and degenerate problems.

use super::*;
use nalgebra::{SMatrix, SVector};
use proptest::prelude::*;

/// Exact solution by enumerating every assignment of each variable to
/// {lower, upper, free}, solving the free part and keeping the KKT point.
fn enumerate<const N: usize>(
    h: &SMatrix<f64, N, N>,
    g: &SVector<f64, N>,
    lb: &SVector<f64, N>,
    ub: &SVector<f64, N>,
) -> SVector<f64, N> {
    let mut best: Option<(f64, SVector<f64, N>)> = None;
    let total = 3usize.pow(N as u32);
    for code in 0..total {
        let mut c = code;
        let mut state = [0u8; N];
        for s in state.iter_mut() {
            *s = (c % 3) as u8;
            c /= 3;
        }
        let mut z = SVector::<f64, N>::zeros();
        let free: Vec<usize> = (0..N).filter(|&i| state[i] == 2).collect();
        for i in 0..N {
            z[i] = match state[i] {
                0 => lb[i],
                1 => ub[i],
                _ => 0.0,
            };
        }
        if !free.is_empty() {
            let k = free.len();
            let mut m = nalgebra::DMatrix::<f64>::zeros(k, k);
            let mut r = nalgebra::DVector::<f64>::zeros(k);
            for (a, &i) in free.iter().enumerate() {
                r[a] = -g[i];
                for j in 0..N {
                    if state[j] != 2 {
                        r[a] -= h[(i, j)] * z[j];
                    }
                }
                for (b, &j) in free.iter().enumerate() {
                    m[(a, b)] = h[(i, j)];
                }
            }
            let Some(sol) = m.lu().solve(&r) else { continue };
            for (a, &i) in free.iter().enumerate() {
                z[i] = sol[a];
            }
        }
        let feasible = (0..N).all(|i| z[i] >= lb[i] - 1e-9 && z[i] <= ub[i] + 1e-9);
        if !feasible {
            continue;
        }
        let obj = 0.5 * (h * z).dot(&z) + g.dot(&z);
        if best.as_ref().is_none_or(|(b, _)| obj < *b) {
            best = Some((obj, z));
        }
    }
    best.expect("a box QP always has a solution").1
}

/// A random SPD matrix with condition number about `cond`.
fn spd<const N: usize>(seed: u64, cond: f64) -> SMatrix<f64, N, N> {
    let mut s = seed | 1;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let a = nalgebra::DMatrix::<f64>::from_fn(N, N, |_, _| rnd());
    let qd = a.qr().q();
    let q = SMatrix::<f64, N, N>::from_fn(|i, j| qd[(i, j)]);
    let d = SVector::<f64, N>::from_fn(|i, _| cond.powf(i as f64 / (N.max(2) - 1) as f64));
    let scale = SVector::<f64, N>::from_fn(|_, _| 10f64.powf(2.0 * rnd()));
    // Badly scaled too: D Q Λ Qᵀ D.
    let m = q * SMatrix::from_diagonal(&d) * q.transpose();
    SMatrix::from_fn(|i, j| scale[i] * m[(i, j)] * scale[j])
}

fn check<const N: usize>(h: SMatrix<f64, N, N>, g: SVector<f64, N>, lb: SVector<f64, N>, ub: SVector<f64, N>) {
    let qp = BoxQp::new(&h).unwrap();
    let exact = enumerate(&h, &g, &lb, &ub);
    let f_star = qp.objective(&exact, &g);
    let scale = f_star.abs().max(1.0);
    let settings = QpSettings {
        early_exit: true,
        accuracy: 1e-9 * scale,
        max_iterations: u32::MAX,
        polish: true,
    };
    let bound = qp.iteration_bound(&lb, &ub, settings.accuracy);
    for warm in [SVector::zeros(), ub, (lb + ub) * 0.5] {
        let sol = qp.solve(&g, &lb, &ub, &warm, &settings);
        for i in 0..N {
            assert!(
                sol.z[i] >= lb[i] && sol.z[i] <= ub[i],
                "outside the box: {} not in [{}, {}]",
                sol.z[i],
                lb[i],
                ub[i]
            );
        }
        let rel = (sol.objective - f_star).abs() / f_star.abs().max(1e-12 * (1.0 + (h * exact).norm()));
        assert!(
            rel <= 1e-5,
            "objective {} vs exact {} (rel {rel:e}), status {:?}",
            sol.objective,
            f_star,
            sol.status
        );
        // The a-priori bound is never exceeded, nor the solve's own; the
        // certificate is sound (never below the true gap), and whatever the
        // status says was proved holds.
        assert_eq!(sol.iteration_bound, bound);
        assert!(sol.solve_bound <= bound);
        assert!(
            sol.iterations <= sol.solve_bound,
            "{} iterations > own bound {}",
            sol.iterations,
            sol.solve_bound
        );
        let true_gap = sol.objective - f_star;
        let slack = 1e-9 * scale;
        assert!(
            sol.gap + slack >= true_gap,
            "certificate {} below the true gap {true_gap}",
            sol.gap
        );
        assert!(
            matches!(
                sol.status,
                QpStatus::Converged | QpStatus::Polished | QpStatus::BoundReached
            ),
            "{:?}",
            sol.status
        );
        assert!(
            true_gap <= settings.accuracy + slack,
            "{:?}: gap {true_gap}",
            sol.status
        );
    }
}

fn boxes<const N: usize>(seed: u64, degenerate: bool) -> (SVector<f64, N>, SVector<f64, N>) {
    let mut s = seed.wrapping_mul(2654435761) | 1;
    let mut rnd = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut lb = SVector::<f64, N>::zeros();
    let mut ub = SVector::<f64, N>::zeros();
    for i in 0..N {
        let a = (rnd() - 0.5) * 4.0;
        let w = rnd() * 3.0;
        lb[i] = a;
        ub[i] = if degenerate && i % 2 == 0 { a } else { a + w };
    }
    (lb, ub)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn random_qps_match_enumeration(seed in any::<u64>(), gs in proptest::collection::vec(-10.0f64..10.0, 5)) {
        let h = spd::<5>(seed, 10.0);
        let (lb, ub) = boxes::<5>(seed, false);
        check(h, SVector::from_column_slice(&gs), lb, ub);
    }

    #[test]
    fn ill_conditioned_qps_match_enumeration(seed in any::<u64>(), gs in proptest::collection::vec(-100.0f64..100.0, 6)) {
        let h = spd::<6>(seed, 1e6);
        let (lb, ub) = boxes::<6>(seed ^ 0xabc, false);
        check(h, SVector::from_column_slice(&gs), lb, ub);
    }

    #[test]
    fn degenerate_boxes_match_enumeration(seed in any::<u64>(), gs in proptest::collection::vec(-10.0f64..10.0, 4)) {
        // Half the variables have lb == ub; the others a normal interval.
        let h = spd::<4>(seed, 100.0);
        let (lb, ub) = boxes::<4>(seed, true);
        check(h, SVector::from_column_slice(&gs), lb, ub);
    }
}

#[test]
fn unconstrained_minimum_inside_the_box_is_found_exactly() {
    let h = spd::<6>(42, 50.0);
    let z_star = SVector::<f64, 6>::from_fn(|i, _| 0.1 * i as f64 - 0.2);
    let g = -(h * z_star);
    let lb = SVector::repeat(-10.0);
    let ub = SVector::repeat(10.0);
    let qp = BoxQp::new(&h).unwrap();
    let sol = qp.solve(&g, &lb, &ub, &SVector::zeros(), &QpSettings::default());
    assert!((sol.z - z_star).amax() < 1e-9, "{:?}", sol);
}

#[test]
fn bad_data_returns_a_point_in_the_box() {
    let h = spd::<3>(7, 10.0);
    let qp = BoxQp::new(&h).unwrap();
    let lb = SVector::<f64, 3>::new(-1.0, 0.0, 2.0);
    let ub = SVector::<f64, 3>::new(1.0, 1.0, 3.0);
    let g = SVector::<f64, 3>::new(f64::NAN, 0.0, 0.0);
    let sol = qp.solve(
        &g,
        &lb,
        &ub,
        &nalgebra::Vector3::new(5.0, -5.0, f64::INFINITY),
        &QpSettings::default(),
    );
    assert_eq!(sol.status, QpStatus::InvalidData);
    assert_eq!(sol.z, nalgebra::Vector3::new(1.0, 0.0, 2.0));
    assert!(BoxQp::new(&SMatrix::<f64, 2, 2>::new(1.0, 2.0, 2.0, 1.0)).is_err());
    assert!(BoxQp::new(&SMatrix::<f64, 2, 2>::new(1.0, f64::NAN, 0.0, 1.0)).is_err());
}

#[test]
fn early_stop_is_still_feasible() {
    let h = spd::<6>(9, 1e4);
    let qp = BoxQp::new(&h).unwrap();
    let (lb, ub) = boxes::<6>(9, false);
    let g = SVector::<f64, 6>::from_fn(|i, _| (i as f64 - 2.5) * 30.0);
    let sol = qp.solve(
        &g,
        &lb,
        &ub,
        &SVector::zeros(),
        &QpSettings {
            early_exit: true,
            accuracy: 1e-12,
            max_iterations: 3,
            polish: false,
        },
    );
    assert_eq!(sol.status, QpStatus::IterationLimit);
    assert_eq!(sol.iterations, 3);
    assert!((0..6).all(|i| sol.z[i] >= lb[i] && sol.z[i] <= ub[i]));
    assert!(sol.residual > 0.0 && sol.gap > 1e-12);
}

#[test]
fn fixed_time_runs_exactly_to_the_bound() {
    // Fixed-time mode: an easy problem (solution interior, proved in a few
    // iterations) still runs all min(max_iterations, a-priori bound).
    let h = spd::<4>(3, 50.0);
    let qp = BoxQp::new(&h).unwrap();
    let lb = SVector::<f64, 4>::repeat(-10.0);
    let ub = SVector::<f64, 4>::repeat(10.0);
    let g = SVector::<f64, 4>::new(0.1, -0.2, 0.05, 0.0);
    let mut s = QpSettings {
        early_exit: true,
        accuracy: 1e-9,
        max_iterations: u32::MAX,
        polish: false,
    };
    let early = qp.solve(&g, &lb, &ub, &SVector::zeros(), &s);
    assert_eq!(early.status, QpStatus::Converged);
    assert!(early.gap <= 1e-9);
    s.early_exit = false;
    let fixed = qp.solve(&g, &lb, &ub, &SVector::zeros(), &s);
    assert!(early.iterations < fixed.iterations);
    assert_eq!(fixed.iterations, fixed.iteration_bound);
    s.max_iterations = 7;
    assert_eq!(qp.solve(&g, &lb, &ub, &SVector::zeros(), &s).iterations, 7);
    // Running on never makes the answer worse than the converged one.
    assert!(fixed.objective <= early.objective + 1e-12);
}

/// The certificate is an upper bound on `f(z) − f*` at *any* point of the
/// box, not only at solutions: random points against the exact optimum.
#[test]
fn the_certificate_bounds_the_gap_everywhere() {
    for seed in 0..200u64 {
        let h = spd::<5>(seed, if seed % 2 == 0 { 10.0 } else { 1e4 });
        let (lb, ub) = boxes::<5>(seed ^ 0x55, false);
        let g = SVector::<f64, 5>::from_fn(|i, _| ((seed as f64 + 1.0) * (i as f64 + 0.7)).sin() * 20.0);
        let qp = BoxQp::new(&h).unwrap();
        let f_star = qp.objective(&enumerate(&h, &g, &lb, &ub), &g);
        for k in 0..20u64 {
            let z = SVector::<f64, 5>::from_fn(|i, _| {
                let a = (((seed * 31 + k) * 7 + i as u64) as f64 * 0.618).fract();
                lb[i] + a * (ub[i] - lb[i])
            });
            let grad = h * z + g;
            let c = qp.certificate(&z, &grad, &lb, &ub);
            let true_gap = qp.objective(&z, &g) - f_star;
            assert!(
                c + 1e-9 * (1.0 + f_star.abs()) >= true_gap,
                "seed {seed}: certificate {c} < gap {true_gap}"
            );
        }
    }
}

/// Adversarial: the worst case the bound is made for — a start in the far
/// corner of the box, an optimum in the opposite one, an ill-conditioned
/// Hessian; without early exit the solve still proves its accuracy at the
/// a-priori bound, and with it it never needs more than its own bound.
#[test]
fn far_corner_starts_are_proved_within_the_bound() {
    for seed in 0..50u64 {
        let h = spd::<6>(seed, 1e3);
        let lb = SVector::<f64, 6>::repeat(-1.0);
        let ub = SVector::<f64, 6>::repeat(1.0);
        // Optimum pushed hard into the lower corner; start at the upper one.
        let g = h * SVector::<f64, 6>::repeat(50.0);
        let qp = BoxQp::new(&h).unwrap();
        let f_star = qp.objective(&enumerate(&h, &g, &lb, &ub), &g);
        for early_exit in [true, false] {
            let s = QpSettings {
                early_exit,
                accuracy: 1e-8,
                max_iterations: u32::MAX,
                polish: false,
            };
            let sol = qp.solve(&g, &lb, &ub, &ub, &s);
            assert!(sol.objective - f_star <= 1e-8 * (1.0 + 1e-6), "{sol:?}");
            assert!(
                sol.iterations
                    <= if early_exit {
                        sol.solve_bound
                    } else {
                        sol.iteration_bound
                    }
            );
        }
    }
}
