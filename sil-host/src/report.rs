//! JSON and text output of flights and designs.

use crate::flight::{FlightConfig, FlightResult};
use crate::metrics::AxisMetrics;
use fc_core::control::lqr_euler::euler_weights;
use fc_core::control::lqr_quat::quat_weights;
use fc_core::control::lqr_table::design_continuous;
use fc_core::AttitudeForm;
use fc_core::{euler_hover_model, quat_hover_model, VehicleParams};
use nalgebra::{Dim, Matrix, RawStorage};
use serde_json::{json, Value};

/// A matrix as row-major nested arrays.
pub fn rows<R: Dim, C: Dim, S: RawStorage<f64, R, C>>(m: &Matrix<f64, R, C, S>) -> Value {
    Value::Array(
        (0..m.nrows())
            .map(|i| Value::Array((0..m.ncols()).map(|j| json!(m[(i, j)])).collect()))
            .collect(),
    )
}

fn axis(a: &AxisMetrics, unit: &str) -> Value {
    json!({
        "rmse_m": a.rmse_m,
        "rmse_pct": a.rmse_pct,
        "settling_s": a.settling_s,
        "overshoot_pct": a.overshoot_pct,
        "unit": unit,
    })
}

/// The `fly` JSON: configuration, per-axis metrics (yaw values in rad),
/// effort, constraint record, final error and controller time per step.
pub fn flight_json(cfg: &FlightConfig, res: &FlightResult) -> Value {
    let m = &res.metrics;
    let mut v = json!({
        "controller": cfg.spec.family.name(),
        "model": cfg.spec.form.name(),
        "scenario": cfg.scenario.kind.name(),
        "disturbance": cfg.disturbance.to_string(),
        "sensor_noise": cfg.noise,
        "reference": cfg.spec.reference.name(),
        "preset": cfg.spec.row().preset_name,
        "control_hz": res.control_hz,
        "integration_hz": cfg.integration_hz,
        "duration_s": cfg.scenario.duration_s,
        "axes": {
            "x": axis(&m.x, "m"),
            "y": axis(&m.y, "m"),
            "z": axis(&m.z, "m"),
            "yaw": axis(&m.yaw, "rad"),
        },
        "u_norm": m.u_norm,
        "max_box_violation": m.max_box_violation,
        "final_error_m": m.final_error_m,
        "tracking_from_s": cfg.scenario.tracking_from_s(),
        "tracking_rmse_m": m.tracking_rmse_m,
        "tracking_worst_m": m.tracking_worst_m,
        "saturated_steps": res.saturated_steps,
        "steps": res.steps,
        "diverged": res.diverged,
        "step_time_ns": { "mean": res.step_time_ns.mean, "max": res.step_time_ns.max },
    });
    if let Some(c) = res.link_counters {
        v["failsafe_steps"] = json!(res.failsafe_steps);
        v["link_counters"] = json!({
            "ok": c.ok, "bad_cobs": c.bad_cobs, "bad_crc": c.bad_crc, "oversized": c.oversized,
            "bad_message": c.bad_message, "out_of_order": c.out_of_order,
            "invalid_values": c.invalid_values, "unexpected": c.unexpected,
            "failsafe_entries": c.failsafe_entries,
        });
    }
    if let Some((mean, max)) = res.instructions_per_step {
        v["instructions_per_step"] = json!({
            "mean": mean,
            "max": max,
            "note": "QEMU netduinoplus2 with -icount shift=0: SysTick counts 0.168 per executed instruction; \
                     step_time_ns then holds SysTick counts, not ns",
        });
    }
    if let Some((mean, max)) = res.estimator_instructions_per_step {
        v["estimator_instructions_per_step"] = json!({
            "mean": mean,
            "max": max,
            "note": "the IMU steps between the controller's runs (the estimator alone), same units",
        });
    } else if let Some(e) = res.estimator_step_time {
        v["estimator_step_time_ns"] = json!({ "mean": e.mean, "max": e.max });
    }
    v["estimator"] = match (&cfg.sensors, &res.estimation) {
        (Some(sc), Some(e)) => {
            let c = &e.counters;
            json!({
                "kind": "ekf",
                "sensors": sc.profile.name(),
                "seed": sc.seed,
                "faults": sc.faults,
                "rms_attitude_deg": e.rms_att_deg,
                "rms_position_m": e.rms_pos_m,
                "rms_velocity_mps": e.rms_vel_mps,
                "max_position_m": e.max_pos_m,
                "nees_mean": e.nees_mean,
                "nees_dof": fc_core::estimate::ERR,
                "nees_blocks_mean": { "position": e.nees_blocks_mean[0], "velocity": e.nees_blocks_mean[1],
                    "attitude": e.nees_blocks_mean[2], "gyro_bias": e.nees_blocks_mean[3],
                    "accel_bias": e.nees_blocks_mean[4], "dof": 3 },
                "aligning_steps": e.aligning_steps,
                "failsafe_steps": e.failsafe_steps,
                "failsafe_entries": e.failsafe_entries,
                "counters": {
                    "imu_rejected": c.imu_rejected, "imu_clipped": c.imu_clipped,
                    "pos_rejected": c.pos_rejected, "vel_rejected": c.vel_rejected,
                    "yaw_rejected": c.yaw_rejected, "alt_rejected": c.alt_rejected,
                    "fix_invalid": c.fix_invalid, "pos_resets": c.pos_resets,
                    "covariance_resets": c.covariance_resets, "fused": c.fused,
                },
            })
        }
        _ => json!({ "kind": "truth" }),
    };
    if cfg.spec.family == fc_core::control::Family::Mpc {
        v["qp_iterations"] = json!({ "mean": res.qp_iterations.0, "max": res.qp_iterations.1 });
        v["qp_iteration_bound"] = json!(res.qp_iteration_bound);
    }
    v
}

/// One line per flight for the terminal.
pub fn flight_summary(cfg: &FlightConfig, res: &FlightResult) -> String {
    let m = &res.metrics;
    let st = |a: &AxisMetrics| match (a.settling_s, a.overshoot_pct) {
        (Some(s), Some(o)) => format!("{s:.2} s/{o:.2} %"),
        _ => "-".into(),
    };
    format!(
        "{} {} {} [{}]: RMSE x {:.3} y {:.3} z {:.3} m, yaw {:.2}°; settle/overshoot x {} y {} z {} yaw {}; \
         final error {:.3} m;{} u_norm {:.4}; saturated {}/{} steps; controller {:.0} ns/step (max {:.0}); \
         QP iterations mean {:.1} max {} (bound {}){}",
        cfg.spec.family.name(),
        cfg.spec.form.name(),
        cfg.scenario.kind.name(),
        cfg.disturbance,
        m.x.rmse_m,
        m.y.rmse_m,
        m.z.rmse_m,
        m.yaw.rmse_m.to_degrees(),
        st(&m.x),
        st(&m.y),
        st(&m.z),
        st(&m.yaw),
        m.final_error_m,
        match (m.tracking_rmse_m, cfg.scenario.tracking_from_s()) {
            (Some(r), Some(from)) if from > 0.0 => format!(" tracking RMSE {r:.3} m from {from} s;"),
            _ => String::new(),
        },
        m.u_norm,
        res.saturated_steps,
        res.steps,
        res.step_time_ns.mean,
        res.step_time_ns.max,
        res.qp_iterations.0,
        res.qp_iterations.1,
        res.qp_iteration_bound,
        if res.diverged { " DIVERGED" } else { "" }
    )
}

/// `design lqr`: the hover model at heading `yaw` (rad), the thesis weights and
/// the continuous-time gain (`U = Uss − K δX`), all row-major.
pub fn lqr_design_json(model: AttitudeForm, yaw: f64) -> anyhow::Result<Value> {
    let p = VehicleParams::OS4;
    if model == AttitudeForm::Quaternion && (yaw / 2.0).cos().abs() < 1e-3 {
        anyhow::bail!(
            "the reduced quaternion form is singular at a heading of ±180° (q0 = cos(ψT/2) = 0, so roll and pitch \
             rates no longer reach q1, q2): no stabilising LQR exists there. Use another heading or --model euler; \
             the flight controller avoids this by working in the current heading's frame."
        );
    }
    let (lm, (q, r), states) = match model {
        AttitudeForm::Euler => (
            euler_hover_model(&p, yaw),
            euler_weights(),
            ["x", "y", "z", "vx", "vy", "vz", "phi", "theta", "psi", "p", "q", "r"],
        ),
        AttitudeForm::Quaternion => (
            quat_hover_model(&p, yaw),
            quat_weights(),
            ["x", "y", "z", "vx", "vy", "vz", "q1", "q2", "q3", "p", "q", "r"],
        ),
    };
    let sol = design_continuous(&lm, &q, &r).map_err(|e| anyhow::anyhow!("Riccati solve failed: {e:?}"))?;
    Ok(json!({
        "model": model.name(),
        "yaw_deg": yaw.to_degrees(),
        "states": states,
        "inputs": ["U1", "U2", "U3", "U4"],
        "A": rows(&lm.a),
        "B": rows(&lm.b),
        "Q": rows(&q),
        "R": rows(&r),
        "K": rows(&sol.k),
        "riccati_iterations": sol.iterations,
    }))
}

/// `design lqr --flown`: the LQR the flight controller flies, for the
/// vehicle `p` at heading `yaw` (rad): the project's weights
/// ([`fc_core::control::lqr_euler::tuned_weights`],
/// [`fc_core::control::lqr_quat::tuned_weights`]) with the inputs weighted
/// for `p` and the project's tuning, designed in discrete time (zero-order
/// hold at `ts` s, the DARE with `Q·ts`, `R·ts`) as
/// [`fc_core::control::ControllerSpec::build`] designs it. Prints the
/// continuous model `A`, `B`, the weights `Q`, `R` (per second), `ts` and
/// the discrete gain `K` (`U = Uss − K δX`), all row-major. The quaternion
/// LQR flies in its heading's frame, so its gain is the one at ψ = 0.
pub fn lqr_flown_design_json(model: AttitudeForm, yaw: f64, p: &VehicleParams<f64>, ts: f64) -> anyhow::Result<Value> {
    use fc_core::control::{lqr_euler, lqr_quat, lqr_table, Tuning};
    let ((mut q, r), lm, yaw) = match model {
        AttitudeForm::Euler => (lqr_euler::tuned_weights(), euler_hover_model(p, yaw), yaw),
        AttitudeForm::Quaternion => (lqr_quat::tuned_weights(), quat_hover_model(p, 0.0), 0.0),
    };
    let mut r = lqr_table::inputs_weighted_for(&r, p);
    Tuning::project().lqr.apply_lqr(&mut q, &mut r);
    let sol = lqr_table::design_discrete(&lm, &q, &r, ts).map_err(|e| anyhow::anyhow!("design failed: {e:?}"))?;
    Ok(json!({
        "model": model.name(),
        "yaw_deg": yaw.to_degrees(),
        "ts_s": ts,
        "A": rows(&lm.a),
        "B": rows(&lm.b),
        "Q": rows(&q),
        "R": rows(&r),
        "K": rows(&sol.k),
    }))
}

/// The QP of the MPC's last step, exactly as its solver saw it (f32 values
/// widened to f64): `min ½zᵀHz + gᵀz, lb ≤ z ≤ ub`, z = the moves of
/// `U − U_hover`, 4 per move. `None` for other controllers or before a step.
pub fn mpc_step_json(ctrl: &fc_core::control::AnyController<f32>, t: f64) -> Option<Value> {
    use fc_core::control::AnyController;
    fn dump<const N: usize, const M: usize, const NZ: usize>(
        m: &fc_core::control::Mpc<f32, N, M, NZ>,
        t: f64,
    ) -> Option<Value> {
        let qp = m.last_qp()?;
        let v = |x: &nalgebra::SVector<f32, NZ>| Value::Array(x.iter().map(|v| json!(*v as f64)).collect());
        let h = m.hessian().map(|x| x as f64);
        let (force, moment) = m.disturbance_estimate();
        let cfg = m.config();
        // The accuracy in input units: f(z) − f* ≥ ½‖z − z*‖²_H, so
        // |zᵢ − z*ᵢ| ≤ √(2ε·(H⁻¹)ᵢᵢ) (Cauchy–Schwarz in the H-norm).
        let eps = cfg.qp_accuracy;
        let hinv = h.try_inverse()?;
        let input_acc: Vec<Value> = (0..NZ).map(|i| json!((2.0 * eps * hinv[(i, i)]).sqrt())).collect();
        // The same solve again on this host, timed: the median of 201 (ns).
        let mut ns: Vec<u128> = (0..201)
            .map(|_| {
                let t0 = std::time::Instant::now();
                std::hint::black_box(m.resolve_last_qp());
                t0.elapsed().as_nanos()
            })
            .collect();
        ns.sort_unstable();
        Some(json!({
            "t": t,
            "horizon": N,
            "moves": M,
            "pred_dt_s": m.config().pred_dt_s,
            "exec_dt_s": m.config().exec_dt_s,
            "variables": "U - U_hover for each move, [U1 N, U2 N, U3 N, U4 N*m] per move",
            "H": rows(&h),
            "g": v(&qp.g),
            "lb": v(&qp.lb),
            "ub": v(&qp.ub),
            "solution": v(&qp.solution.z),
            "iterations": qp.solution.iterations,
            "iteration_bound": m.iteration_bound(),
            "solve_bound": qp.solution.solve_bound,
            "iterations_allowed": m.iteration_bound().min(cfg.qp_max_iterations),
            "method": match m.qp_active_sets() {
                Some(_) => "exact: every active set of the Hessian's independent blocks",
                None => "fast gradient method to its certified iteration bound",
            },
            "active_sets": m.qp_active_sets(),
            "certified_accuracy": {
                "objective": eps,
                "input_units": input_acc,
                "holds_for_every_solve": m.qp_active_sets().is_some() || cfg.qp_max_iterations >= m.iteration_bound(),
            },
            "host_solve_ns_median": ns[ns.len() / 2] as f64,
            "gap": qp.solution.gap as f64,
            "residual": qp.solution.residual as f64,
            "objective": qp.solution.objective as f64,
            "status": format!("{:?}", qp.solution.status),
            "disturbance_estimate": {
                "accel_ned_mps2": [force[0] as f64, force[1] as f64, force[2] as f64],
                "ang_accel_frd_radps2": [moment[0] as f64, moment[1] as f64, moment[2] as f64],
            },
        }))
    }
    match ctrl {
        AnyController::MpcThesis(m) => dump(m, t),
        AnyController::MpcFast(m) => dump(m, t),
        _ => None,
    }
}
