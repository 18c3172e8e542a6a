//! The MPC's design, run when it is built or re-designed (never in a
//! step): the prediction model's exact ZOH, the disturbance observer, the
//! condensed Hessian, the terminal weight and the QP's iteration bound.

use super::{
    block_of, euler_hover_model, lit, quat_hover_model, solve_dare, zoh_into, AttitudeForm, BoxQp, ControlError,
    Controller, LinearModel, Mat12, Mpc, MpcConfig, QpSettings, RealField, SMatrix, Setpoint, Vec12, Vector3, Vector4,
    VehicleParams, CHANNELS,
};

/// The f64 matrices of one discretisation, in one place: the continuous
/// hover model with the disturbance inputs appended, `[B | Bw]` (Bw =
/// acceleration on ẋ ẏ ż, angular acceleration on ṗ q̇ ṙ), and its ZOH.
pub(super) struct ModelWork {
    a: SMatrix<f64, 12, 12>,
    b_all: SMatrix<f64, 12, 10>,
    ad: SMatrix<f64, 12, 12>,
    bd_all: SMatrix<f64, 12, 10>,
}

impl ModelWork {
    /// The hover model of `form` for `p64` (ZOH parts zero).
    pub(super) fn hover(form: AttitudeForm, p64: &VehicleParams<f64>) -> Self {
        let lm: LinearModel<f64> = match form {
            AttitudeForm::Euler => euler_hover_model(p64, 0.0),
            AttitudeForm::Quaternion => quat_hover_model(p64, 0.0),
        };
        let mut b_all = SMatrix::<f64, 12, 10>::zeros();
        b_all.fixed_columns_mut::<4>(0).copy_from(&lm.b);
        for i in 0..3 {
            b_all[(3 + i, 4 + i)] = 1.0;
            b_all[(9 + i, 7 + i)] = 1.0;
        }
        Self {
            a: lm.a,
            b_all,
            ad: SMatrix::zeros(),
            bd_all: SMatrix::zeros(),
        }
    }

    /// Exact ZOH at `dt` (s) into `ad`, `bd_all`.
    pub(super) fn zoh(&mut self, dt: f64) -> Result<(), ControlError> {
        Ok(zoh_into(&self.a, &self.b_all, dt, &mut self.ad, &mut self.bd_all)?)
    }

    /// The discrete model in the controller's float type: state matrix,
    /// input matrix, disturbance matrix.
    pub(super) fn store<T: RealField + Copy>(
        &self,
        ad: &mut Mat12<T>,
        bd: &mut SMatrix<T, 12, 4>,
        wd: &mut SMatrix<T, 12, 6>,
    ) {
        cast_into(ad, &self.ad);
        cast_into(bd, &self.bd_all.fixed_columns::<4>(0));
        cast_into(wd, &self.bd_all.fixed_columns::<6>(4));
    }
}

/// `dst = src` converted from the f64 design to the controller's float type.
pub(super) fn cast_into<T, const R: usize, const C: usize, S>(
    dst: &mut SMatrix<T, R, C>,
    src: &nalgebra::Matrix<f64, nalgebra::Const<R>, nalgebra::Const<C>, S>,
) where
    T: RealField + Copy,
    S: nalgebra::storage::Storage<f64, nalgebra::Const<R>, nalgebra::Const<C>>,
{
    for i in 0..R {
        for j in 0..C {
            dst[(i, j)] = lit(src[(i, j)]);
        }
    }
}

/// The QP settings `cfg` asks for (polish always on).
pub(super) fn qp_settings<T: RealField + Copy>(cfg: &MpcConfig) -> QpSettings<T> {
    QpSettings {
        early_exit: cfg.qp_early_exit,
        accuracy: lit(cfg.qp_accuracy),
        max_iterations: cfg.qp_max_iterations,
        polish: true,
        enumerate: cfg.qp_enumerate,
    }
}

/// The terminal weight of `cfg` for the prediction model `(ad, bd)`: the
/// DARE's solution of (Q, R) when `cfg.terminal`, else Q.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub(super) fn terminal_weight<T: RealField + Copy>(
    cfg: &MpcConfig,
    ad: &SMatrix<f64, 12, 12>,
    bd: &SMatrix<f64, 12, 4>,
) -> Result<Mat12<T>, ControlError> {
    let q = SMatrix::<f64, 12, 12>::from_diagonal(&Vec12::<f64>::from(cfg.q));
    Ok(if cfg.terminal {
        // A tiny input weight keeps R invertible when the config has zeros.
        let rr = SMatrix::<f64, 4, 4>::from_diagonal(&Vector4::<f64>::from(cfg.r).map(|v| v.max(1e-6)));
        solve_dare(ad, bd, &q, &rr)?.x.map(lit)
    } else {
        q.map(lit)
    })
}

impl<T: RealField + Copy, const N: usize, const M: usize, const NZ: usize> Mpc<T, N, M, NZ> {
    /// Designs this MPC in place for the vehicle `params` and `cfg`, as
    /// [`Mpc::new`] would, and clears its run-time state. The design's f64
    /// scratch lives in the frames of the steps below, one at a time, so
    /// that designing on a microcontroller needs a few KiB of stack, not a
    /// second controller's worth. On error the controller is not usable
    /// (design it again, or another one).
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub fn redesign(&mut self, params: VehicleParams<T>, cfg: MpcConfig) -> Result<(), ControlError> {
        let p64: VehicleParams<f64> = params.cast();
        let ok_dt = |v: f64| v.is_finite() && v > 0.0;
        if !p64.is_valid() || !ok_dt(cfg.pred_dt_s) || !ok_dt(cfg.exec_dt_s) {
            return Err(ControlError::InvalidParameter);
        }
        if cfg.observer_tau_s.is_some_and(|t| !ok_dt(t)) || !ok_dt(cfg.observer_moment_tau_s) {
            return Err(ControlError::InvalidParameter);
        }
        if cfg
            .q
            .iter()
            .chain(cfg.r.iter())
            .chain(cfg.s.iter())
            .any(|v| !v.is_finite() || *v < 0.0)
        {
            return Err(ControlError::InvalidParameter);
        }
        self.cfg = cfg;
        self.bx = params.input_box();
        self.u_hover = crate::model::hover_input(&params);
        self.params = params;
        self.settings = qp_settings(&cfg);
        self.last_dt = lit(cfg.exec_dt_s);
        self.trend = [T::zero(); N];
        self.preview = [Setpoint::hold(Vector3::zeros(), T::zero()); N];
        Controller::reset(self);
        self.q = Vec12::<f64>::from(cfg.q).map(lit);
        self.r = Vector4::<f64>::from(cfg.r).map(lit);
        self.s = Vector4::<f64>::from(cfg.s).map(lit);
        self.design_prediction(&p64)?;
        self.design_observer(&p64)?;
        if let Some(tt) = cfg.disturbance_trend_s {
            let max = cfg.disturbance_trend_max_mps2;
            let filter_ok = cfg.disturbance_rate_filter_s.is_finite() && cfg.disturbance_rate_filter_s > cfg.exec_dt_s;
            if !ok_dt(tt) || !filter_ok || !max.is_finite() || max < 0.0 {
                return Err(ControlError::InvalidParameter);
            }
            for (k, t) in self.trend.iter_mut().enumerate() {
                let tau = (k as f64 + 0.5) * cfg.pred_dt_s;
                *t = lit(tt * (1.0 - libm::exp(-tau / tt)));
            }
        }
        self.design_qp()
    }

    /// Prediction model (ZOH at `pred_dt`) and the terminal weight (DARE of
    /// (Q, R), or Q).
    #[inline(never)]
    pub(super) fn design_prediction(&mut self, p64: &VehicleParams<f64>) -> Result<(), ControlError> {
        let mut w = ModelWork::hover(self.cfg.form, p64);
        w.zoh(self.cfg.pred_dt_s)?;
        w.store(&mut self.ad, &mut self.bd, &mut self.wd);
        let bd: SMatrix<f64, 12, 4> = w.bd_all.fixed_columns::<4>(0).into_owned();
        self.p_term = terminal_weight(&self.cfg, &w.ad, &bd)?;
        Ok(())
    }

    /// Observer model (ZOH at `exec_dt`).
    #[inline(never)]
    pub(super) fn design_observer(&mut self, p64: &VehicleParams<f64>) -> Result<(), ControlError> {
        let mut w = ModelWork::hover(self.cfg.form, p64);
        w.zoh(self.cfg.exec_dt_s)?;
        w.store(&mut self.ad_e, &mut self.bd_e, &mut self.wd_e);
        Ok(())
    }

    /// The condensed Hessian, its QP solver and the box of the moves.
    #[inline(never)]
    pub(super) fn design_qp(&mut self) -> Result<(), ControlError> {
        self.decoupled = self.channels_decouple();
        let h = self.build_hessian();
        self.qp = BoxQp::new(&h).map_err(|_| ControlError::InvalidParameter)?;
        self.design_response();
        for b in 0..M {
            for c in 0..4 {
                self.lb[4 * b + c] = self.bx.lo[c] - self.u_hover[c];
                self.ub[4 * b + c] = self.bx.hi[c] - self.u_hover[c];
            }
        }
        // An exact (enumerated) solve is one pass: its "bound" is 1.
        self.iteration_bound = if self.qp_active_sets().is_some() {
            1
        } else {
            self.qp.iteration_bound(&self.lb, &self.ub, self.settings.accuracy)
        };
        Ok(())
    }

    /// Whether the prediction model `Ad`, its input matrix `Bd` and the
    /// terminal weight couple no two of the [`CHANNELS`]: every entry
    /// between two channels below 1e-9 of the matrix's largest (the DARE's
    /// rounding leaves ≈ 1e-16 where exact arithmetic has 0).
    pub(super) fn channels_decouple(&self) -> bool {
        let (z, y, x, w) = CHANNELS;
        let mut channel = [0usize; 12];
        for (c, states) in [&z[..], &y[..], &x[..], &w[..]].iter().enumerate() {
            for &i in states.iter() {
                channel[i] = c;
            }
        }
        let square_ok = |m: &Mat12<T>| {
            let tol = m.amax() * lit::<T>(1e-9);
            (0..12).all(|i| (0..12).all(|j| channel[i] == channel[j] || m[(i, j)].abs() <= tol))
        };
        let tol = self.bd.amax() * lit::<T>(1e-9);
        let input_ok = (0..12).all(|i| (0..4).all(|c| channel[i] == c || self.bd[(i, c)].abs() <= tol));
        square_ok(&self.ad) && square_ok(&self.p_term) && input_ok
    }

    /// `Gx`, `Gw`, `Gt`: the state cost's gradient for a unit initial
    /// state, disturbance and disturbance rate, column by column (each the
    /// adjoint of one free response, references zero).
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub(super) fn design_response(&mut self) {
        for col in 0..12 + 6 + 3 {
            // Column `col` of [Gx | Gw | Gt]: its initial state and its
            // input to the prediction at step k.
            let x0 = if col < 12 {
                Vec12::ith(col, T::one())
            } else {
                Vec12::zeros()
            };
            let input = |k: usize| match col {
                0..12 => Vec12::zeros(),
                12..18 => self.wd.column(col - 12).into_owned(),
                _ => self.wd.column(col - 18) * self.trend[k],
            };
            let g = self.response_gradient(x0, &input);
            match col {
                0..12 => self.gx.set_column(col, &g),
                12..18 => self.gw.set_column(col - 12, &g),
                _ => self.gt.set_column(col - 18, &g),
            }
        }
    }

    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub(super) fn build_hessian(&self) -> SMatrix<T, NZ, NZ> {
        let mut h = SMatrix::<T, NZ, NZ>::zeros();
        for col in 0..NZ {
            // A unit move of channel c in move b: the input Bd·e_c at that
            // move's prediction steps.
            let (b, c) = (col / 4, col % 4);
            let input = |k: usize| {
                if block_of::<M>(k) == b {
                    self.bd.column(c).into_owned()
                } else {
                    Vec12::zeros()
                }
            };
            h.set_column(col, &self.response_gradient(Vec12::zeros(), &input));
        }
        // Input magnitude: each prediction step's input belongs to one move.
        for k in 0..N {
            let b = block_of::<M>(k);
            for c in 0..4 {
                h[(4 * b + c, 4 * b + c)] += self.r[c];
            }
        }
        // Input rate: the first move against the previous input, then move to move.
        for b in 0..M {
            for c in 0..4 {
                h[(4 * b + c, 4 * b + c)] += self.s[c];
                if b > 0 {
                    h[(4 * (b - 1) + c, 4 * (b - 1) + c)] += self.s[c];
                    h[(4 * b + c, 4 * (b - 1) + c)] -= self.s[c];
                    h[(4 * (b - 1) + c, 4 * b + c)] -= self.s[c];
                }
            }
        }
        (h + h.transpose()) * lit::<T>(0.5)
    }
}
