//! The core's CARE/DARE solutions against a different algorithm: Newton–
//! Kleinman iteration with each Lyapunov equation solved exactly through its
//! Kronecker form (dense LU, host only).

use fc_core::control::lqr_euler::euler_weights;
use fc_core::control::lqr_quat::quat_weights;
use fc_core::control::lqr_table::{design_continuous, design_discrete};
use fc_core::{euler_hover_model, quat_hover_model, zoh, LinearModel, VehicleParams};
use nalgebra::{DMatrix, DVector, SMatrix};

type M12 = SMatrix<f64, 12, 12>;

/// Solves Aᵀ X + X A = −C for X (12×12) via (I⊗Aᵀ + Aᵀ⊗I) vec X = −vec C.
fn lyapunov(a: &M12, c: &M12) -> M12 {
    let n = 12;
    let at = a.transpose();
    let mut big = DMatrix::<f64>::zeros(n * n, n * n);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                // (I ⊗ Aᵀ): block (j, j) = Aᵀ ; (Aᵀ ⊗ I): block (j, k) = Aᵀ[j,k] I  (column-major vec)
                big[(j * n + i, j * n + k)] += at[(i, k)];
                big[(j * n + i, k * n + i)] += at[(j, k)];
            }
        }
    }
    let rhs = DVector::from_iterator(n * n, c.iter().map(|v| -v));
    let x = big
        .lu()
        .solve(&rhs)
        .expect("Lyapunov operator is regular for a stable A");
    M12::from_iterator(x.iter().copied())
}

fn newton_kleinman(lm: &LinearModel<f64>, q: &M12, r: &SMatrix<f64, 4, 4>, k0: SMatrix<f64, 4, 12>) -> M12 {
    let rinv = r.try_inverse().unwrap();
    let mut k = k0;
    let mut x = M12::zeros();
    for _ in 0..50 {
        let acl = lm.a - lm.b * k;
        let c = q + k.transpose() * r * k;
        let xn = lyapunov(&acl, &c);
        let done = (xn - x).amax() < 1e-12 * xn.amax();
        x = (xn + xn.transpose()) / 2.0;
        k = rinv * lm.b.transpose() * x;
        if done {
            break;
        }
    }
    x
}

#[test]
fn care_matches_newton_kleinman() {
    let p = VehicleParams::<f64>::os4();
    for yaw in [0.0f64, 0.26, 1.9, -2.8] {
        for (name, lm, (q, r)) in [
            ("euler", euler_hover_model(&p, yaw), euler_weights()),
            ("quat", quat_hover_model(&p, yaw), quat_weights()),
        ] {
            let sda = design_continuous(&lm, &q, &r).unwrap();
            // Start Newton–Kleinman from a detuned (but stabilising) gain: it
            // converges to the unique stabilising solution on its own.
            let nk = newton_kleinman(&lm, &q, &r, sda.k * 1.3);
            let rel = (sda.x - nk).amax() / nk.amax();
            assert!(rel < 1e-9, "{name} yaw {yaw}: relative difference {rel:e}");
            // Closed loop is Hurwitz.
            let eig = (lm.a - lm.b * sda.k).complex_eigenvalues();
            assert!(eig.iter().all(|l| l.re < 0.0), "{name}: {eig}");
        }
    }
}

#[test]
fn discrete_gain_tends_to_continuous_gain() {
    // With the sampled cost Q·Ts, R·Ts the DARE gain approaches the CARE gain as Ts → 0.
    let p = VehicleParams::<f64>::os4();
    let lm = euler_hover_model(&p, 0.4);
    let (q, r) = euler_weights();
    let kc = design_continuous(&lm, &q, &r).unwrap().k;
    let d = |ts| (design_discrete(&lm, &q, &r, ts).unwrap().k - kc).amax() / kc.amax();
    // First order in Ts: ten times smaller step, ten times closer. (At the
    // 500 Hz control rate the gap is ≈ 55 %: the thesis weights put the fastest
    // continuous closed-loop pole at ≈ 894 rad/s, which sampling changes.)
    let (e4, e5, e6) = (d(1e-4), d(1e-5), d(1e-6));
    assert!(e6 < 1e-3, "{e6}");
    for (big, small) in [(e4, e5), (e5, e6)] {
        assert!((0.08..0.12).contains(&(small / big)), "{e4} {e5} {e6}");
    }
    // The DARE solution satisfies its own equation (checked independently here).
    let (ad, bd) = zoh(&lm.a, &lm.b, 0.002).unwrap();
    let s = design_discrete(&lm, &q, &r, 0.002).unwrap();
    let (qd, rd) = (q * 0.002, r * 0.002);
    let res = ad.transpose() * s.x * ad
        - ad.transpose()
            * s.x
            * bd
            * (rd + bd.transpose() * s.x * bd).try_inverse().unwrap()
            * bd.transpose()
            * s.x
            * ad
        + qd
        - s.x;
    assert!(res.amax() < 1e-9 * s.x.amax(), "{}", res.amax());
}
