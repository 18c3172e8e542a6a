//! Analytic Jacobians of the dynamics about hover with heading ψT (docs/book/src/model.md §7).
//!
//! The Euler form uses the full 12-state; the quaternion form uses the reduced
//! 12-state `[x y z ẋ ẏ ż q1 q2 q3 p q r]`, with `q0 = +sqrt(1 − q1² − q2² − q3²)`
//! eliminated (q0 is uncontrollable, thesis §3.6).

use super::{lit, QuatState, VehicleParams};
use crate::math as trig;
use nalgebra::{RealField, SMatrix, SVector};

/// Continuous-time linear model `δẋ = A δx + B δU` (12 states, 4 inputs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearModel<T: RealField + Copy> {
    /// State matrix A (12×12).
    pub a: SMatrix<T, 12, 12>,
    /// Input matrix B (12×4).
    pub b: SMatrix<T, 12, 4>,
}

/// Reduced quaternion state `[x y z ẋ ẏ ż q1 q2 q3 p q r]`.
pub type ReducedQuatState<T> = SVector<T, 12>;

/// Fills the blocks the Euler and quaternion forms share: position kinematics,
/// drag, thrust on z̈, rate damping and the torque inputs.
fn common_blocks<T: RealField + Copy>(p: &VehicleParams<T>) -> LinearModel<T> {
    let mut a = SMatrix::<T, 12, 12>::zeros();
    let mut b = SMatrix::<T, 12, 4>::zeros();
    let m = p.mass_kg;
    let [ix, iy, iz] = p.inertia_kgm2;
    for i in 0..3 {
        a[(i, i + 3)] = T::one();
        a[(i + 3, i + 3)] = -p.kt_nspm[i] / m;
        a[(i + 9, i + 9)] = -p.kr_nms[i] / p.inertia_kgm2[i];
    }
    b[(5, 0)] = -T::one() / m;
    b[(9, 1)] = p.arm_m / ix;
    b[(10, 2)] = p.arm_m / iy;
    b[(11, 3)] = T::one() / iz;
    LinearModel { a, b }
}

/// Euler-form Jacobians about hover with heading `yaw` (rad), `U = [mg 0 0 0]`.
pub fn euler_hover_model<T: RealField + Copy>(p: &VehicleParams<T>, yaw: T) -> LinearModel<T> {
    let mut lm = common_blocks(p);
    let g = p.gravity_mps2;
    let (s, c) = trig::sin_cos(yaw);
    let a = &mut lm.a;
    a[(3, 6)] = -g * s;
    a[(3, 7)] = -g * c;
    a[(4, 6)] = g * c;
    a[(4, 7)] = -g * s;
    a[(6, 9)] = T::one();
    a[(7, 10)] = T::one();
    a[(8, 11)] = T::one();
    lm
}

/// Reduced quaternion-form Jacobians about hover with heading `yaw` (rad),
/// i.e. about `q = (cos ψT/2, 0, 0, sin ψT/2)`, `U = [mg 0 0 0]`.
pub fn quat_hover_model<T: RealField + Copy>(p: &VehicleParams<T>, yaw: T) -> LinearModel<T> {
    let mut lm = common_blocks(p);
    let g = p.gravity_mps2;
    let two = lit::<T>(2.0);
    let half = lit::<T>(0.5);
    let (s, c) = trig::sin_cos(yaw * half);
    let a = &mut lm.a;
    // Thrust direction terms 2(q0q2 + q1q3), 2(q2q3 − q0q1) with q0(q1,q2,q3).
    a[(3, 6)] = -two * g * s;
    a[(3, 7)] = -two * g * c;
    a[(4, 6)] = two * g * c;
    a[(4, 7)] = -two * g * s;
    // Kinematics q̇1..q̇3 about (c, 0, 0, s).
    a[(6, 9)] = half * c;
    a[(6, 10)] = -half * s;
    a[(7, 9)] = half * s;
    a[(7, 10)] = half * c;
    a[(8, 11)] = half * c;
    lm
}

/// Drops `q0` from a quaternion state, flipping the sign of the whole
/// quaternion first so that `q0 ≥ 0` (same rotation, shortest way round).
pub fn reduce_quat_state<T: RealField + Copy>(x: &QuatState<T>) -> ReducedQuatState<T> {
    let sign = if x[6] < T::zero() { -T::one() } else { T::one() };
    let mut r = ReducedQuatState::zeros();
    r.fixed_rows_mut::<6>(0).copy_from(&x.fixed_rows::<6>(0));
    for i in 0..3 {
        r[6 + i] = sign * x[7 + i];
    }
    r.fixed_rows_mut::<3>(9).copy_from(&x.fixed_rows::<3>(10));
    r
}

/// Rebuilds the full quaternion state from the reduced one with
/// `q0 = sqrt(1 − |q_vec|²)`; a vector part longer than 1 is scaled back to
/// unit length (q0 = 0), so the result is always a unit quaternion.
pub fn expand_quat_state<T: RealField + Copy>(r: &ReducedQuatState<T>) -> QuatState<T> {
    let mut x = QuatState::zeros();
    x.fixed_rows_mut::<6>(0).copy_from(&r.fixed_rows::<6>(0));
    let v = r.fixed_rows::<3>(6).into_owned();
    let n2 = v.norm_squared();
    if n2 <= T::one() {
        x[6] = (T::one() - n2).sqrt();
        x.fixed_rows_mut::<3>(7).copy_from(&v);
    } else {
        x.fixed_rows_mut::<3>(7).copy_from(&(v / n2.sqrt()));
    }
    x.fixed_rows_mut::<3>(10).copy_from(&r.fixed_rows::<3>(9));
    x
}
