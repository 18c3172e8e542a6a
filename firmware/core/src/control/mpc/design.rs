//! The MPC's design, run when it is built or re-designed (never in a
//! step): the prediction model's exact ZOH, the disturbance observer, the
//! condensed Hessian, the terminal weight and the QP's iteration bound.

use nalgebra::SVector;

use super::{
    block_of, euler_hover_model, lit, quat_hover_model, solve_dare, zoh_into, AttitudeForm, BoxQp, Channel,
    ControlError, Controller, LinearModel, Mpc, MpcConfig, QpSettings, RealField, SMatrix, Setpoint, Vec12, VecX,
    Vector3, Vector4, VehicleParams, CHANNELS, OBSERVED_ROWS, PREDICTION_STATES,
};

/// The f64 matrices of one discretisation, in one place: the continuous
/// model with the disturbance inputs appended, `[B | Bw]` (Bw =
/// acceleration on ẋ ẏ ż, angular acceleration on ṗ q̇ ṙ), and its ZOH.
/// `S` = 12: the hover model; `S` = [`PREDICTION_STATES`]: the hover model
/// whose inputs reach it through the rotors' first-order lag.
pub(super) struct ModelWork<const S: usize> {
    pub(super) a: SMatrix<f64, S, S>,
    pub(super) b_all: SMatrix<f64, S, 10>,
    ad: SMatrix<f64, S, S>,
    bd_all: SMatrix<f64, S, 10>,
}

impl<const S: usize> ModelWork<S> {
    /// The hover model of `form` for `p64` (ZOH parts zero); with
    /// `rotor_tau_s` (and `S` ≥ 16) the inputs drive the lag states
    /// `U̇_d = (U − U_d)/τr` and those drive the vehicle.
    pub(super) fn hover(form: AttitudeForm, p64: &VehicleParams<f64>, rotor_tau_s: Option<f64>) -> Self {
        let lm: LinearModel<f64> = match form {
            AttitudeForm::Euler => euler_hover_model(p64, 0.0),
            AttitudeForm::Quaternion => quat_hover_model(p64, 0.0),
        };
        let mut a = SMatrix::<f64, S, S>::zeros();
        let mut b_all = SMatrix::<f64, S, 10>::zeros();
        a.fixed_view_mut::<12, 12>(0, 0).copy_from(&lm.a);
        match rotor_tau_s {
            Some(tau) if S >= 16 => {
                a.fixed_view_mut::<12, 4>(0, 12).copy_from(&lm.b);
                for c in 0..4 {
                    a[(12 + c, 12 + c)] = -1.0 / tau;
                    b_all[(12 + c, c)] = 1.0 / tau;
                }
            }
            _ => b_all.fixed_view_mut::<12, 4>(0, 0).copy_from(&lm.b),
        }
        for i in 0..3 {
            b_all[(3 + i, 4 + i)] = 1.0;
            b_all[(9 + i, 7 + i)] = 1.0;
        }
        Self {
            a,
            b_all,
            ad: SMatrix::zeros(),
            bd_all: SMatrix::zeros(),
        }
    }

    /// Exact ZOH at `dt` (s) into `ad`, `bd_all`.
    pub(super) fn zoh(&mut self, dt: f64) -> Result<(), ControlError> {
        Ok(zoh_into(&self.a, &self.b_all, dt, &mut self.ad, &mut self.bd_all)?)
    }

    /// The observer's rows ([`OBSERVED_ROWS`]) of the discrete hover model.
    pub(super) fn store_observed<T: RealField + Copy>(
        &self,
        ad: &mut SMatrix<T, 6, 12>,
        bd: &mut SMatrix<T, 6, 4>,
        wd: &mut SMatrix<T, 6, 6>,
    ) {
        for (r, &i) in OBSERVED_ROWS.iter().enumerate() {
            for j in 0..12 {
                ad[(r, j)] = lit(self.ad[(i, j)]);
            }
            for c in 0..4 {
                bd[(r, c)] = lit(self.bd_all[(i, c)]);
            }
            for c in 0..6 {
                wd[(r, c)] = lit(self.bd_all[(i, 4 + c)]);
            }
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

/// The terminal weight of `cfg` for the whole prediction model `(ad, bd)`
/// of `S` states, in one DARE (the tests' check of the channels' own):
/// the DARE's solution of (Q, R) when `cfg.terminal`, else Q; Q weighs the
/// hover model's states, not the lag states.
#[cfg(test)]
pub(super) fn terminal_weight<const S: usize>(
    cfg: &MpcConfig,
    ad: &SMatrix<f64, S, S>,
    bd: &SMatrix<f64, S, 4>,
) -> Result<SMatrix<f64, S, S>, ControlError> {
    let mut q = SMatrix::<f64, S, S>::zeros();
    for i in 0..12 {
        q[(i, i)] = cfg.q[i];
    }
    Ok(if cfg.terminal {
        // A tiny input weight keeps R invertible when the config has zeros.
        let rr = SMatrix::<f64, 4, 4>::from_diagonal(&Vector4::<f64>::from(cfg.r).map(|v| v.max(1e-6)));
        solve_dare(ad, bd, &q, &rr)?.x
    } else {
        q
    })
}

/// The prediction model in f64 as its 16 states, designed whole (for the
/// tests' dense pass): state and input matrices (one ZOH at `pred_dt`)
/// and the terminal weight (one DARE), what [`Mpc::design_prediction`]
/// designs channel by channel.
#[cfg(test)]
pub(super) struct PredictionModel {
    pub(super) ad: super::MatX<f64>,
    pub(super) bd: SMatrix<f64, PREDICTION_STATES, 4>,
    pub(super) p_term: super::MatX<f64>,
}

/// The prediction model of `cfg` for `p64` ([`PredictionModel`]).
#[cfg(test)]
pub(super) fn prediction_model(cfg: &MpcConfig, p64: &VehicleParams<f64>) -> PredictionModel {
    fn of<const S: usize>(cfg: &MpcConfig, p64: &VehicleParams<f64>, tau: Option<f64>) -> PredictionModel {
        let mut w = ModelWork::<S>::hover(cfg.form, p64, tau);
        w.zoh(cfg.pred_dt_s).unwrap();
        let bd: SMatrix<f64, S, 4> = w.bd_all.fixed_columns::<4>(0).into_owned();
        let p = terminal_weight(cfg, &w.ad, &bd).unwrap();
        let mut m = PredictionModel {
            ad: SMatrix::zeros(),
            bd: SMatrix::zeros(),
            p_term: SMatrix::zeros(),
        };
        m.ad.fixed_view_mut::<S, S>(0, 0).copy_from(&w.ad);
        m.bd.fixed_view_mut::<S, 4>(0, 0).copy_from(&bd);
        m.p_term.fixed_view_mut::<S, S>(0, 0).copy_from(&p);
        m
    }
    if cfg.rotor_lag_prediction && p64.rotor_tau_s > 0.0 {
        of::<PREDICTION_STATES>(cfg, p64, Some(p64.rotor_tau_s))
    } else {
        of::<12>(cfg, p64, None)
    }
}

/// Whether the continuous prediction model's state matrix `a` and its
/// input columns (the first four of `b_all`) couple no two of the
/// [`CHANNELS`]: every entry between two channels below 1e-9 of the
/// matrix's largest. Then each channel's ZOH and DARE are the whole
/// model's, restricted to it, and the design runs channel by channel.
pub(super) fn channels_decouple<const S: usize>(a: &SMatrix<f64, S, S>, b_all: &SMatrix<f64, S, 10>) -> bool {
    let (z, y, x, w) = CHANNELS;
    let mut channel = [usize::MAX; S];
    for (c, states) in [&z[..], &y[..], &x[..], &w[..]].iter().enumerate() {
        for &i in states.iter().filter(|&&i| i < S) {
            channel[i] = c;
        }
    }
    let tol = a.amax() * 1e-9;
    let square_ok = (0..S).all(|i| (0..S).all(|j| channel[i] == channel[j] || a[(i, j)].abs() <= tol));
    let b = b_all.fixed_columns::<4>(0);
    let tol = b.amax() * 1e-9;
    let input_ok = (0..S).all(|i| (0..4).all(|c| channel[i] == c || b[(i, c)].abs() <= tol));
    square_ok && input_ok
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
    /// (Q, R), or Q), designed and stored channel by channel: with the
    /// rotors' lag states when [`MpcConfig::rotor_lag_prediction`] (and the
    /// rotors lag), else the hover model alone (the lag states' blocks
    /// zero). The channels do not couple (checked here on the continuous
    /// model), so each channel's ZOH and DARE, of 3 or 5 states and one
    /// input, are the whole 16-state model's: the design's f64 scratch is a
    /// few hundred bytes a channel, not a 16-state Riccati workspace.
    #[inline(never)]
    pub(super) fn design_prediction(&mut self, p64: &VehicleParams<f64>) -> Result<(), ControlError> {
        let lag = (self.cfg.rotor_lag_prediction && p64.rotor_tau_s > 0.0).then_some(p64.rotor_tau_s);
        let w = ModelWork::<PREDICTION_STATES>::hover(self.cfg.form, p64, lag);
        if !channels_decouple(&w.a, &w.b_all) {
            return Err(ControlError::InvalidParameter);
        }
        let (zi, yi, xi, wi) = CHANNELS;
        let (cfg, lagged) = (self.cfg, lag.is_some());
        self.zc.design(&zi, 0, &w, &cfg, lagged, &mut self.wd)?;
        self.yc.design(&yi, 1, &w, &cfg, lagged, &mut self.wd)?;
        self.xc.design(&xi, 2, &w, &cfg, lagged, &mut self.wd)?;
        self.wc.design(&wi, 3, &w, &cfg, lagged, &mut self.wd)
    }

    /// Observer model (ZOH at `exec_dt`), its velocity and rate rows.
    #[inline(never)]
    pub(super) fn design_observer(&mut self, p64: &VehicleParams<f64>) -> Result<(), ControlError> {
        let mut w = ModelWork::<12>::hover(self.cfg.form, p64, None);
        w.zoh(self.cfg.exec_dt_s)?;
        w.store_observed(&mut self.ad_e, &mut self.bd_e, &mut self.wd_e);
        Ok(())
    }

    /// The condensed Hessian, its QP solver and the box of the moves.
    #[inline(never)]
    pub(super) fn design_qp(&mut self) -> Result<(), ControlError> {
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

    /// `Gx`, `Gw`, `Gt`: the state cost's gradient for a unit initial
    /// state, disturbance and disturbance rate, column by column (each the
    /// adjoint of one free response, references zero).
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub(super) fn design_response(&mut self) {
        const X: usize = PREDICTION_STATES;
        for col in 0..X + 6 + 3 {
            // Column `col` of [Gx | Gw | Gt]: its initial state and its
            // input to the prediction at step k (the lag states take no
            // disturbance).
            let x0 = if col < X {
                VecX::ith(col, T::one())
            } else {
                VecX::zeros()
            };
            let disturbance = |c: usize| {
                let mut v = VecX::<T>::zeros();
                v.fixed_rows_mut::<12>(0).copy_from(&self.wd.column(c));
                v
            };
            let input = |k: usize| match col {
                0..X => VecX::zeros(),
                X..22 => disturbance(col - X),
                _ => disturbance(col - 22) * self.trend[k],
            };
            let g = self.response_gradient(x0, &input);
            match col {
                0..X => {
                    let (zi, yi, xi, wi) = CHANNELS;
                    self.zc.take_response(&zi, col, &g, 0);
                    self.yc.take_response(&yi, col, &g, 1);
                    self.xc.take_response(&xi, col, &g, 2);
                    self.wc.take_response(&wi, col, &g, 3);
                }
                X..22 => self.gw.set_column(col - X, &g),
                _ => self.gt.set_column(col - 22, &g),
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
            let column = self.input_column(c);
            let input = |k: usize| if block_of::<M>(k) == b { column } else { VecX::zeros() };
            h.set_column(col, &self.response_gradient(VecX::zeros(), &input));
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

impl<T: RealField + Copy, const K: usize, const M: usize> Channel<T, K, M> {
    /// This channel's blocks of the f64 design (its states `idx`, input `c`).
    /// Designs this channel (its states `idx`, input `c`) from the
    /// continuous prediction model `w`: the ZOH of its block at `pred_dt`
    /// (its input and the disturbance inputs; the disturbance rows into
    /// `wd`) and its terminal weight. Without the lag (`lagged` false) the
    /// lag state (the channel's last) is given a decay of its own, so that
    /// the DARE sees a stable mode nothing drives or weighs, and its blocks
    /// are then stored as zero.
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    fn design(
        &mut self,
        idx: &[usize; K],
        c: usize,
        w: &ModelWork<PREDICTION_STATES>,
        cfg: &MpcConfig,
        lagged: bool,
        wd: &mut SMatrix<T, 12, 6>,
    ) -> Result<(), ControlError> {
        let mut a = SMatrix::<f64, K, K>::zeros();
        let mut b_all = SMatrix::<f64, K, 10>::zeros();
        for (r, &i) in idx.iter().enumerate() {
            for (s, &j) in idx.iter().enumerate() {
                a[(r, s)] = w.a[(i, j)];
            }
            for col in 0..10 {
                b_all[(r, col)] = w.b_all[(i, col)];
            }
        }
        if !lagged {
            a[(K - 1, K - 1)] = -1.0 / cfg.pred_dt_s;
        }
        let (mut ad, mut bd_all) = (SMatrix::<f64, K, K>::zeros(), SMatrix::<f64, K, 10>::zeros());
        zoh_into(&a, &b_all, cfg.pred_dt_s, &mut ad, &mut bd_all)?;
        let bd: SMatrix<f64, K, 1> = bd_all.fixed_columns::<1>(c).into_owned();
        let mut q = SMatrix::<f64, K, K>::zeros();
        for (r, &i) in idx.iter().enumerate() {
            if i < 12 {
                q[(r, r)] = cfg.q[i];
            }
        }
        let p = if cfg.terminal {
            // A tiny input weight keeps R invertible when the config has zeros.
            let rr = SMatrix::<f64, 1, 1>::new(cfg.r[c].max(1e-6));
            solve_dare(&ad, &bd, &q, &rr)?.x
        } else {
            q
        };
        let keep = |r: usize| lagged || r < K - 1;
        for r in 0..K {
            for s in 0..K {
                let on = keep(r) && keep(s);
                self.a[r][s] = if on { lit(ad[(r, s)]) } else { T::zero() };
                self.p[r][s] = if on { lit(p[(r, s)]) } else { T::zero() };
            }
            self.b[r] = if keep(r) { lit(bd[r]) } else { T::zero() };
        }
        for (r, &i) in idx.iter().enumerate().filter(|&(_, &i)| i < 12) {
            for col in 0..6 {
                wd[(i, col)] = lit(bd_all[(r, 4 + col)]);
            }
        }
        Ok(())
    }

    /// The gradient `g` of a unit initial state `col`, when `col` is one of
    /// this channel's states: the moves of its input `c` (the other
    /// channels' moves do not see it).
    fn take_response<const NZ: usize>(&mut self, idx: &[usize; K], col: usize, g: &SVector<T, NZ>, c: usize) {
        if let Some(a) = idx.iter().position(|&i| i == col) {
            for (b, row) in self.gx.iter_mut().enumerate() {
                row[a] = g[4 * b + c];
            }
        }
    }
}
