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

/// The continuous hover model with the disturbance inputs appended,
/// `[B | Bw]`, and nothing else.
pub(super) struct HoverModel {
    pub(super) a: SMatrix<f64, 12, 12>,
    pub(super) b_all: SMatrix<f64, 12, 10>,
}

impl HoverModel {
    /// The hover model of `form` for `p64`.
    pub(super) fn of(form: AttitudeForm, p64: &VehicleParams<f64>) -> Self {
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
        Self { a: lm.a, b_all }
    }
}

impl<const S: usize> ModelWork<S> {
    /// The hover model of `form` for `p64` (ZOH parts zero); with
    /// `rotor_tau_s` (and `S` ≥ 16) the inputs drive the lag states
    /// `U̇_d = (U − U_d)/τr` and those drive the vehicle. (The tests' whole
    /// 16-state model; the images design from [`HoverModel`].)
    #[cfg(test)]
    pub(super) fn hover(form: AttitudeForm, p64: &VehicleParams<f64>, rotor_tau_s: Option<f64>) -> Self {
        let h = HoverModel::of(form, p64);
        let mut w = Self::blank();
        w.a.fixed_view_mut::<12, 12>(0, 0).copy_from(&h.a);
        w.b_all.fixed_view_mut::<12, 10>(0, 0).copy_from(&h.b_all);
        if let Some(tau) = rotor_tau_s.filter(|_| S >= 16) {
            // The inputs through the lag states.
            w.a.fixed_view_mut::<12, 4>(0, 12)
                .copy_from(&h.b_all.fixed_columns::<4>(0));
            w.b_all.fixed_view_mut::<12, 4>(0, 0).fill(0.0);
            for c in 0..4 {
                w.a[(12 + c, 12 + c)] = -1.0 / tau;
                w.b_all[(12 + c, c)] = 1.0 / tau;
            }
        }
        w
    }

    /// Every matrix zero.
    pub(super) fn blank() -> Self {
        Self {
            a: SMatrix::zeros(),
            b_all: SMatrix::zeros(),
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

/// A group design's matrices: state, input (with the disturbance
/// columns after the four inputs), terminal weight, and the
/// group's index of each prediction state (`usize::MAX`: not in it).
type GroupDesign<'a> = (
    &'a SMatrix<f64, 12, 12>,
    &'a SMatrix<f64, 12, 10>,
    &'a SMatrix<f64, 12, 12>,
    &'a [usize; PREDICTION_STATES],
);

/// A channel's blocks (its states `idx`, input `c`; `a` and `p` row-major
/// `K × K`, `b` of `K`) from a group's design; a state not designed (a lag
/// state of the hover model alone) is stored as zero. Not generic in the
/// channel's size: one copy in the image.
#[inline(never)]
fn store_channel<T: RealField + Copy>(
    (a, b, p): (&mut [T], &mut [T], &mut [T]),
    idx: &[usize],
    (ad, bd, pt, local): GroupDesign<'_>,
    c: usize,
) {
    let k = idx.len();
    let at = |m: &SMatrix<f64, 12, 12>, i: usize, j: usize| match (local[i], local[j]) {
        (usize::MAX, _) | (_, usize::MAX) => 0.0,
        (li, lj) => m[(li, lj)],
    };
    for (r, &i) in idx.iter().enumerate() {
        for (s, &j) in idx.iter().enumerate() {
            a[r * k + s] = lit(at(ad, i, j));
            p[r * k + s] = lit(at(pt, i, j));
        }
        b[r] = lit(if local[i] == usize::MAX { 0.0 } else { bd[(local[i], c)] });
    }
}

/// Where a group's design is stored: each channel's blocks
/// ([`Channel::blocks`], thrust, roll, pitch, yaw) and the disturbance
/// input's rows (`Wd`, 12 × 6, column-major).
struct GroupOut<'a, T> {
    blocks: [(&'a mut [T], &'a mut [T], &'a mut [T]); 4],
    wd: &'a mut [T],
}

/// Designs the channels `chans` in one model of 12 states: their states
/// and, with the rotors' time constant `tau`, their lag states; the rest
/// of the 12 are states of their own that nothing drives or weighs,
/// decaying at `1/pred_dt`, so the DARE sees them stable. The hover model
/// alone (`tau` `None`, every channel) keeps its own state order. Its ZOH
/// at `pred_dt` and terminal weight (the DARE of (Q, R), or Q) give each
/// channel's blocks and the disturbance rows, stored in `out`. Generic in
/// the scalar only: one copy in an image that carries two MPCs of
/// different sizes.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
fn design_group_into<T: RealField + Copy>(
    cfg: &MpcConfig,
    hover: &HoverModel,
    chans: &[usize],
    tau: Option<f64>,
    out: GroupOut<'_, T>,
) -> Result<(), ControlError> {
    // The group's states: (prediction state, its index in the group);
    // `local` the reverse (usize::MAX: not in the group).
    let mut states = [(0usize, 0usize); 12];
    let mut local = [usize::MAX; PREDICTION_STATES];
    let mut n = 0;
    for &c in chans {
        for &i in channel_states(c) {
            if i >= 12 && tau.is_none() {
                continue;
            }
            let li = if tau.is_some() { n } else { i };
            *states.get_mut(n).ok_or(ControlError::InvalidParameter)? = (i, li);
            local[i] = li;
            n += 1;
        }
    }
    let states = &states[..n];
    let dt = cfg.pred_dt_s;
    let mut w = ModelWork::<12>::blank();
    for l in n..12 {
        w.a[(l, l)] = -1.0 / dt;
    }
    for &(i, li) in states {
        if i >= 12 {
            // A lag state: `U̇_d = (U − U_d)/τ` of its own input.
            let (c, tau) = (i - 12, tau.unwrap_or(dt));
            w.a[(li, li)] = -1.0 / tau;
            w.b_all[(li, c)] = 1.0 / tau;
            continue;
        }
        for &(j, lj) in states {
            // The vehicle's state matrix; its input matrix, into the lag
            // states when they are there, else from the inputs.
            w.a[(li, lj)] = if j < 12 {
                hover.a[(i, j)]
            } else {
                hover.b_all[(i, j - 12)]
            };
        }
        for col in 0..10 {
            if col >= 4 || tau.is_none() {
                w.b_all[(li, col)] = hover.b_all[(i, col)];
            }
        }
    }
    w.zoh(dt)?;
    let mut q = SMatrix::<f64, 12, 12>::zeros();
    for &(i, li) in states.iter().filter(|&&(i, _)| i < 12) {
        q[(li, li)] = cfg.q[i];
    }
    let bd: SMatrix<f64, 12, 4> = w.bd_all.fixed_columns::<4>(0).into_owned();
    let p = if cfg.terminal {
        // A tiny input weight keeps R invertible when the config has
        // zeros (and for the inputs of the channels not in the group,
        // which move nothing here).
        let rr = SMatrix::<f64, 4, 4>::from_diagonal(&Vector4::<f64>::from(cfg.r).map(|v| v.max(1e-6)));
        solve_dare(&w.ad, &bd, &q, &rr)?.x
    } else {
        q
    };
    let m = (&w.ad, &w.bd_all, &p, &local);
    let GroupOut { blocks, wd } = out;
    for (c, b) in blocks.into_iter().enumerate() {
        if chans.contains(&c) {
            store_channel(b, channel_states(c), m, c);
        }
    }
    for &(i, li) in states.iter().filter(|&&(i, _)| i < 12) {
        for col in 0..6 {
            if let Some(v) = wd.get_mut(col * 12 + i) {
                *v = lit(w.bd_all[(li, 4 + col)]);
            }
        }
    }
    Ok(())
}

/// The prediction states of channel `c` (0 thrust, 1 roll, 2 pitch, 3 yaw).
fn channel_states(c: usize) -> &'static [usize] {
    const C: ([usize; 3], [usize; 5], [usize; 5], [usize; 3]) = CHANNELS;
    match c {
        0 => &C.0,
        1 => &C.1,
        2 => &C.2,
        _ => &C.3,
    }
}

/// Whether the continuous prediction model's state matrix `a` and its
/// input columns (the first four of `b_all`) couple no two of the
/// [`CHANNELS`]: every entry between two channels exactly zero, as the
/// hover model builds them. Then each channel's ZOH and DARE are the whole
/// model's, restricted to it, and the design runs channel by channel.
#[inline(never)]
pub(super) fn channels_decouple<const S: usize>(a: &SMatrix<f64, S, S>, b_all: &SMatrix<f64, S, 10>) -> bool {
    let mut channel = [u8::MAX; S];
    for c in 0..4 {
        for &i in channel_states(c).iter().filter(|&&i| i < S) {
            channel[i] = c as u8;
        }
    }
    for (j, &cj) in channel.iter().enumerate() {
        for (i, &ci) in channel.iter().enumerate() {
            if ci != cj && a[(i, j)] != 0.0 {
                return false;
            }
        }
        if j < 4
            && channel
                .iter()
                .enumerate()
                .any(|(i, &ci)| ci != j as u8 && b_all[(i, j)] != 0.0)
        {
            return false;
        }
    }
    true
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
        // A position cap is a distance (infinite: none).
        if cfg.max_position_error_m.is_nan() || cfg.max_position_error_m <= 0.0 {
            return Err(ControlError::InvalidParameter);
        }
        // Every move but the last spans `move_steps` steps, and the last
        // at least one.
        if cfg.move_steps == 0 || (M - 1).saturating_mul(cfg.move_steps) >= N {
            return Err(ControlError::InvalidParameter);
        }
        self.cfg = cfg;
        for (k, m) in self.move_of.iter_mut().enumerate() {
            // < M, which fits a byte (checked where `move_of` is built).
            *m = block_of::<M>(k, cfg.move_steps) as u8;
        }
        self.bx = params.input_box();
        self.u_hover = crate::model::hover_input(&params);
        self.params = params;
        self.settings = qp_settings(&cfg);
        self.last_dt = lit(cfg.exec_dt_s);
        self.trend = [T::zero(); N];
        self.preview = [Setpoint::hold(Vector3::zeros(), T::zero()); N];
        self.preview_head = 0;
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
    /// (Q, R), or Q), stored channel by channel: with the rotors' lag
    /// states when [`MpcConfig::rotor_lag_prediction`] (and the rotors lag),
    /// else the hover model alone (the lag states' blocks zero). The
    /// channels do not couple (checked here on the continuous hover model;
    /// the lag adds to each channel only its own input's state), so the
    /// 16-state model is designed as two models of 12 states, thrust with
    /// yaw and roll with pitch, with the 12-state ZOH and DARE the observer
    /// and the LQR use too: no larger Riccati workspace on the stack, and
    /// no other size of them in the image.
    #[inline(never)]
    pub(super) fn design_prediction(&mut self, p64: &VehicleParams<f64>) -> Result<(), ControlError> {
        // The continuous hover model alone (no ZOH parts: they would sit on
        // the stack beneath the groups' designs).
        let hover = HoverModel::of(self.cfg.form, p64);
        if !channels_decouple(&hover.a, &hover.b_all) {
            return Err(ControlError::InvalidParameter);
        }
        if self.cfg.rotor_lag_prediction && p64.rotor_tau_s > 0.0 {
            self.design_group(&hover, &[0, 3], Some(p64.rotor_tau_s))?;
            self.design_group(&hover, &[1, 2], Some(p64.rotor_tau_s))
        } else {
            self.design_group(&hover, &[0, 1, 2, 3], None)
        }
    }

    /// Designs the channels `chans` ([`design_group_into`]) into this
    /// MPC's channel blocks and disturbance rows.
    fn design_group(&mut self, hover: &HoverModel, chans: &[usize], tau: Option<f64>) -> Result<(), ControlError> {
        let out = GroupOut {
            blocks: [self.zc.blocks(), self.yc.blocks(), self.xc.blocks(), self.wc.blocks()],
            wd: self.wd.as_mut_slice(),
        };
        design_group_into(&self.cfg, hover, chans, tau, out)
    }

    /// Observer model (ZOH at `exec_dt`), its velocity and rate rows.
    #[inline(never)]
    pub(super) fn design_observer(&mut self, p64: &VehicleParams<f64>) -> Result<(), ControlError> {
        let h = HoverModel::of(self.cfg.form, p64);
        let mut w = ModelWork::<12>::blank();
        w.a = h.a;
        w.b_all = h.b_all;
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
            let input = |k: usize| {
                if self.move_of[k] as usize == b {
                    column
                } else {
                    VecX::zeros()
                }
            };
            h.set_column(col, &self.response_gradient(VecX::zeros(), &input));
        }
        // Input magnitude: each prediction step's input belongs to one move.
        for k in 0..N {
            let b = self.move_of[k] as usize;
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
    /// The channel's blocks as flat slices, for [`store_channel`].
    fn blocks(&mut self) -> (&mut [T], &mut [T], &mut [T]) {
        (self.a.as_flattened_mut(), &mut self.b, self.p.as_flattened_mut())
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
