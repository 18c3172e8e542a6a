//! Hover trim: the equilibrium about which the linear models are built.

use super::{euler_state_to_quat, EulerState, Input, QuatState, VehicleParams};
use nalgebra::{RealField, Vector3, Vector4};

/// Hover input `Uss = [m·g, 0, 0, 0]`.
pub fn hover_input<T: RealField + Copy>(p: &VehicleParams<T>) -> Input<T> {
    Vector4::new(p.hover_thrust_n(), T::zero(), T::zero(), T::zero())
}

/// Euler state hovering at `pos_ned` (m) with heading `yaw` (rad), at rest.
pub fn hover_euler_state<T: RealField + Copy>(pos_ned: &Vector3<T>, yaw: T) -> EulerState<T> {
    let mut x = EulerState::zeros();
    x.fixed_rows_mut::<3>(0).copy_from(pos_ned);
    x[8] = yaw;
    x
}

/// Quaternion state hovering at `pos_ned` (m) with heading `yaw` (rad), at rest.
pub fn hover_quat_state<T: RealField + Copy>(pos_ned: &Vector3<T>, yaw: T) -> QuatState<T> {
    euler_state_to_quat(&hover_euler_state(pos_ned, yaw))
}
