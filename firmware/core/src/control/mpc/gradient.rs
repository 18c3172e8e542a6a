//! The MPC's step-time work besides the QP: the observer update, the
//! reference over the horizon in the heading frame, and the QP's gradient
//! by adjoint recursion.

use super::{
    lit, quat_to_euler, wrap_pi, AttitudeForm, AttitudeRef, Channel, HeadingFrame, Mpc, RealField, ReferenceMode,
    SVector, Setpoint, StateEstimate, Vec12, VecX, Vector3, Vector4, CHANNELS, LAGGED_CHANNELS, OBSERVED_ROWS,
};

impl<T: RealField + Copy, const N: usize, const M: usize, const NZ: usize> Mpc<T, N, M, NZ> {
    /// Adjoint gradient of the state cost for the errors `e[k] = x[k] − r[k]`
    /// of steps 1..=N: per-move sums of `Bdᵀλ_{k+1}`, channel by channel
    /// (the model couples no two).
    pub(super) fn state_gradient(&self, e: &[VecX<T>; N]) -> SVector<T, NZ> {
        let mut g = SVector::<T, NZ>::zeros();
        let (z, y, x, w) = CHANNELS;
        self.channel_gradient(&self.zc, z, 0, e, &mut g);
        self.channel_gradient(&self.yc, y, 1, e, &mut g);
        self.channel_gradient(&self.xc, x, 2, e, &mut g);
        self.channel_gradient(&self.wc, w, 3, e, &mut g);
        g
    }

    /// [`Mpc::state_gradient`] of one channel: the adjoint recursion on the
    /// states `idx` of input `ch` alone (the others are not coupled to it).
    /// The indices are constants once inlined, so each product is a few
    /// loads and multiply-adds with no index arithmetic; the lag states
    /// (index 12 and up) have no stage weight.
    #[inline(always)]
    pub(super) fn channel_gradient<const K: usize>(
        &self,
        c: &Channel<T, K, M>,
        idx: [usize; K],
        ch: usize,
        e: &[VecX<T>; N],
        g: &mut SVector<T, NZ>,
    ) {
        // Terminal step: P·e restricted to the channel.
        let mut lambda = [T::zero(); K];
        for (a, l) in lambda.iter_mut().enumerate() {
            let mut s = T::zero();
            for (b, &j) in idx.iter().enumerate() {
                s += c.p[a][b] * e[N - 1][j];
            }
            *l = s;
        }
        let mut k = N - 1;
        loop {
            let mut gk = T::zero();
            for (b, l) in lambda.iter().enumerate() {
                gk += c.b[b] * *l;
            }
            g[4 * self.move_of[k] as usize + ch] += gk;
            if k == 0 {
                return;
            }
            k -= 1;
            // `λ_k = Q e_k + Aᵀ λ_{k+1}`. The lag state (the channel's last)
            // is driven by no state of the vehicle (`a[K−1][j] = 0` for
            // j < K−1, exactly: the ZOH of a block-triangular model), so
            // the vehicle's states skip its λ.
            let mut next = [T::zero(); K];
            for (a, &i) in idx.iter().enumerate() {
                let mut s = if i < 12 { self.q[i] * e[k][i] } else { T::zero() };
                let from = if a == K - 1 { K } else { K - 1 };
                for (b, l) in lambda.iter().enumerate().take(from) {
                    s += c.a[b][a] * *l;
                }
                next[a] = s;
            }
            lambda = next;
        }
    }

    /// `Gx·x₀`: the gradient of the free response from the initial state
    /// `x0`, each channel's moves from its own states.
    pub(super) fn initial_response(&self, x0: &VecX<T>) -> SVector<T, NZ> {
        // One copy for every channel's size (48 products a step).
        #[inline(never)]
        fn channel<T: RealField + Copy, const NZ: usize>(
            gx: &[T],
            idx: &[usize],
            ch: usize,
            x0: &VecX<T>,
            g: &mut SVector<T, NZ>,
        ) {
            for (m, row) in gx.chunks_exact(idx.len()).enumerate() {
                let mut s = T::zero();
                for (j, &i) in idx.iter().enumerate() {
                    s += row[j] * x0[i];
                }
                g[4 * m + ch] = s;
            }
        }
        let mut g = SVector::<T, NZ>::zeros();
        let (z, y, x, w) = CHANNELS;
        channel(self.zc.gx.as_flattened(), &z, 0, x0, &mut g);
        channel(self.yc.gx.as_flattened(), &y, 1, x0, &mut g);
        channel(self.xc.gx.as_flattened(), &x, 2, x0, &mut g);
        channel(self.wc.gx.as_flattened(), &w, 3, x0, &mut g);
        g
    }

    /// The prediction model's state after one step from `x`, with no input.
    pub(super) fn predict(&self, x: &VecX<T>) -> VecX<T> {
        // Design-time only: one copy for every channel's size.
        #[inline(never)]
        fn channel<T: RealField + Copy>(a: &[T], idx: &[usize], x: &VecX<T>, y: &mut VecX<T>) {
            let k = idx.len();
            for (r, &i) in idx.iter().enumerate() {
                let mut s = T::zero();
                for (c, &j) in idx.iter().enumerate() {
                    s += a[r * k + c] * x[j];
                }
                y[i] = s;
            }
        }
        let mut y = VecX::<T>::zeros();
        let (z, yi, xi, w) = CHANNELS;
        channel(self.zc.a.as_flattened(), &z, x, &mut y);
        channel(self.yc.a.as_flattened(), &yi, x, &mut y);
        channel(self.xc.a.as_flattened(), &xi, x, &mut y);
        channel(self.wc.a.as_flattened(), &w, x, &mut y);
        y
    }

    /// The input matrix's column of input `c` (0 thrust … 3 yaw torque), as
    /// a prediction state.
    pub(super) fn input_column(&self, c: usize) -> VecX<T> {
        fn put<T: RealField + Copy, const K: usize, const M: usize>(
            ch: &Channel<T, K, M>,
            idx: &[usize; K],
        ) -> VecX<T> {
            let mut v = VecX::<T>::zeros();
            for (a, &i) in idx.iter().enumerate() {
                v[i] = ch.b[a];
            }
            v
        }
        let (z, y, x, w) = CHANNELS;
        match c {
            0 => put(&self.zc, &z),
            1 => put(&self.yc, &y),
            2 => put(&self.xc, &x),
            _ => put(&self.wc, &w),
        }
    }

    /// The state cost's gradient (references zero) of the free response
    /// from `x0` under the per-step input `input(k)` added to the
    /// prediction: the design's one simulation, for the Hessian's columns
    /// and the responses `Gx`, `Gw`, `Gt`.
    pub(super) fn response_gradient(&self, x0: VecX<T>, input: &dyn Fn(usize) -> VecX<T>) -> SVector<T, NZ> {
        let mut x = [VecX::<T>::zeros(); N];
        let mut xk = x0;
        for (k, xs) in x.iter_mut().enumerate() {
            xk = self.predict(&xk) + input(k);
            *xs = xk;
        }
        self.state_gradient(&x)
    }

    /// State in the frame of heading `yaw`, in the form's coordinates.
    pub(super) fn heading_state(&self, est: &StateEstimate<T>, yaw: T) -> Vec12<T> {
        let frame = HeadingFrame::new(yaw);
        let mut x = Vec12::<T>::zeros();
        x.fixed_rows_mut::<3>(0).copy_from(&frame.to_frame(&est.pos_ned_m));
        x.fixed_rows_mut::<3>(3).copy_from(&frame.to_frame(&est.vel_ned_mps));
        let att = self.attitude_coords(&est.att, &frame);
        x.fixed_rows_mut::<3>(6).copy_from(&att);
        x.fixed_rows_mut::<3>(9).copy_from(&est.rates_frd_radps);
        x
    }

    /// Attitude `q` relative to a heading frame in the form's coordinates.
    pub(super) fn attitude_coords(&self, q: &Vector4<T>, frame: &HeadingFrame<T>) -> Vector3<T> {
        let qr = frame.attitude(q);
        match self.cfg.form {
            AttitudeForm::Quaternion => Vector3::new(qr[1], qr[2], qr[3]),
            AttitudeForm::Euler => {
                let e = quat_to_euler(&qr);
                Vector3::new(e[0], e[1], wrap_pi(e[2]))
            }
        }
    }

    /// Reference at prediction step `k` (1-based) as a heading-frame state and
    /// the input reference `U_ref − U_hover`.
    pub(super) fn reference_state(
        &self,
        sp: &Setpoint<T>,
        dist_acc_ned: &Vector3<T>,
        yaw: T,
        frame: &HeadingFrame<T>,
    ) -> (Vec12<T>, Vector4<T>) {
        // Target calculation of offset-free MPC: in feed-forward mode the
        // attitude and thrust are those that produce the reference acceleration
        // *given the estimated disturbance* (thrust must supply a_ref − d̂), and
        // the torque references cancel the estimated moment. Without this the
        // attitude weights pull against the tilt that holds off the wind.
        let mut spd = *sp;
        let mut torque_ref = Vector3::<T>::zeros();
        if self.cfg.reference == ReferenceMode::Feedforward {
            spd.acc_ned_mps2 -= *dist_acc_ned;
            let p = &self.params;
            torque_ref = Vector3::new(
                -p.inertia_kgm2[0] * self.dist[3] / p.arm_m,
                -p.inertia_kgm2[1] * self.dist[4] / p.arm_m,
                -p.inertia_kgm2[2] * self.dist[5],
            );
        }
        let (ar, [s_roll, c_roll, s_pitch, c_pitch]) =
            AttitudeRef::for_mode_trig(&self.params, &spd, self.cfg.reference);
        let lim = lit::<T>(self.cfg.max_heading_error_rad);
        // The heading error the reference asks for, capped.
        let dpsi = crate::math::limit(wrap_pi(ar.yaw_rad - yaw), lim);
        let mut r = Vec12::<T>::zeros();
        r.fixed_rows_mut::<3>(0).copy_from(&frame.to_frame(&sp.pos_ned_m));
        r.fixed_rows_mut::<3>(3).copy_from(&frame.to_frame(&sp.vel_ned_mps));
        // The reference attitude relative to the heading frame: for ZYX
        // angles `q_h⁻¹ ⊗ q(φ, θ, ψ_h + Δψ) = q(φ, θ, Δψ)`, so its Euler
        // coordinates are (φ, θ, Δψ) and its quaternion that of (φ, θ, Δψ),
        // without a round trip through the frame.
        let att = match self.cfg.form {
            AttitudeForm::Euler => Vector3::new(ar.roll_rad, ar.pitch_rad, dpsi),
            AttitudeForm::Quaternion => {
                // The roll's and pitch's half-angles from their sines and
                // cosines (|φ|, |θ| ≤ 45°): no sine or cosine taken again.
                let q = crate::model::quat_of_half_angles(
                    crate::math::half_angle(s_roll, c_roll),
                    crate::math::half_angle(s_pitch, c_pitch),
                    crate::math::sin_cos(dpsi * lit::<T>(0.5)),
                );
                let q = if q[0] < T::zero() { -q } else { q };
                Vector3::new(q[1], q[2], q[3])
            }
        };
        r.fixed_rows_mut::<3>(6).copy_from(&att);
        r.fixed_rows_mut::<3>(9).copy_from(&ar.rates_frd_radps);
        let du = Vector4::new(
            ar.thrust_n - self.u_hover[0],
            torque_ref[0],
            torque_ref[1],
            torque_ref[2],
        );
        (r, du)
    }

    /// The shift of the reference positions that brings the first within
    /// [`MpcConfig::max_position_error_m`] of the vehicle, from its
    /// position error `e1` (reference − vehicle, heading frame); `None`
    /// when it is within.
    pub(super) fn reference_shift(&self, e1: &Vector3<T>) -> Option<Vector3<T>> {
        let lim = lit::<T>(self.cfg.max_position_error_m);
        let d = e1.norm();
        (d > lim).then(|| e1 * ((d - lim) / d))
    }

    /// Setpoint `k` prediction steps ahead: the preview if complete, else the
    /// current setpoint extrapolated along its velocity, acceleration and jerk.
    pub(super) fn horizon_setpoint(&self, sp: &Setpoint<T>, k: usize) -> Setpoint<T> {
        let (base, t) = if self.preview_valid && self.preview_fresh {
            let i = self.preview_head + k - 1;
            (&self.preview[if i >= N { i - N } else { i }], self.preview_age)
        } else {
            (sp, lit::<T>(self.cfg.pred_dt_s) * lit::<T>(k as f64))
        };
        // One call for both; a preview aged 0 (given whole this step) as
        // given, without 20 extrapolations by nothing (≈ 1.1 k instructions
        // a step on the image).
        if t == T::zero() {
            *base
        } else {
            base.extrapolate(t)
        }
    }

    /// The disturbance estimate with its force part in `frame`.
    pub(super) fn dist_in(&self, frame: &HeadingFrame<T>) -> SVector<T, 6> {
        let mut d = self.dist;
        d.fixed_rows_mut::<3>(0)
            .copy_from(&frame.to_frame(&self.dist.fixed_rows::<3>(0).into_owned()));
        d
    }

    /// Whether the prediction has the rotors' lag states
    /// ([`MpcConfig::rotor_lag_prediction`], and the vehicle's rotors lag).
    pub(super) fn predicts_lag(&self) -> bool {
        self.cfg.rotor_lag_prediction && self.params.rotor_tau_s > T::zero()
    }

    /// Whether the controller follows what the rotors deliver by the lag
    /// model: for its observer, its prediction, or both.
    pub(super) fn follows_lag(&self) -> bool {
        (self.cfg.observer_rotor_lag || self.cfg.rotor_lag_prediction) && self.params.rotor_tau_s > T::zero()
    }

    /// The rotors' lag over a step of `dt` s: `(dt, e^(−dt/τr),
    /// (1 − e^(−dt/τr))·τr/dt)`. The identity `(0, 1, 1)` when the
    /// controller does not model the lag.
    pub(super) fn lag_factors_over(&self, dt: T) -> (T, T, T) {
        if !self.follows_lag() {
            return (T::zero(), T::one(), T::one());
        }
        let r = dt / self.params.rotor_tau_s;
        let decay = (-r).exp();
        (dt, decay, (T::one() - decay) / r)
    }

    /// Observer update from the previous step's prediction (and, with a
    /// trend, the low-passed rate of the horizontal estimate).
    ///
    /// The observer model is the ZOH at the execution period `T`; a step of
    /// measured length `dt` ([`Controller::elapsed`]) scales the predicted
    /// change by `dt/T` (exact to first order in `dt`; the second-order
    /// error `dt·(dt − T)·A·ẋ/2` is ≈ 1e-5 m/s on a 2 ms step), and so the
    /// innovations are read against the right interval, not as a
    /// disturbance.
    pub(super) fn observe(&mut self, est: &StateEstimate<T>) {
        let t_nominal = lit::<T>(self.cfg.exec_dt_s);
        let dt = self.next_dt.take().unwrap_or(t_nominal);
        // What the rotors delivered over the step: the lag's mean over it,
        // `u + (u₀ − u)·(τr/dt)·(1 − e^(−dt/τr))` from `u₀` at its start
        // towards the input sent `u` (exact for a first-order lag); and
        // what they deliver at its end, where the next prediction starts.
        // The observer compares with it on thrust and yaw torque, and on
        // every axis when the prediction has the lag; the rest keep the
        // input sent.
        let du_applied = if self.follows_lag() {
            if self.lag_factors.0 != dt {
                self.lag_factors = self.lag_factors_over(dt);
            }
            let (_, decay, mean) = self.lag_factors;
            let u0 = self.du_delivered;
            self.du_delivered = self.du_prev + (u0 - self.du_prev) * decay;
            let mut applied = self.du_prev;
            let all = [0, 1, 2, 3];
            let lagged: &[usize] = if self.predicts_lag() { &all } else { &LAGGED_CHANNELS };
            for &c in lagged {
                applied[c] += (u0[c] - self.du_prev[c]) * mean;
            }
            applied
        } else {
            self.du_prev
        };
        let Some(tau) = self.cfg.observer_tau_s else { return };
        let Some((x_prev, yaw_prev)) = self.last else { return };
        self.last_dt = dt;
        let scale = dt / t_nominal;
        let frame = HeadingFrame::new(yaw_prev);
        // Disturbance in the previous heading frame.
        let mut dh = self.dist_in(&frame);
        let meas = self.heading_state(est, yaw_prev);
        // Only the velocity and rate rows of the prediction are read.
        let mut nu = Vec12::<T>::zeros();
        for (r, &i) in OBSERVED_ROWS.iter().enumerate() {
            let mut p = T::zero();
            for j in 0..12 {
                p += self.ad_e[(r, j)] * x_prev[j];
            }
            for c in 0..4 {
                p += self.bd_e[(r, c)] * du_applied[c];
            }
            for c in 0..6 {
                p += self.wd_e[(r, c)] * dh[c];
            }
            nu[i] = meas[i] - (x_prev[i] + (p - x_prev[i]) * scale);
        }
        // Attribute velocity and rate innovations to the disturbance, low-passed.
        let gain = (dt / lit::<T>(tau)).min(T::one());
        let gain_m = (dt / lit::<T>(self.cfg.observer_moment_tau_s)).min(T::one());
        for i in 0..3 {
            // OBSERVED_ROWS: ẋ ẏ ż are rows 0–2, p q r rows 3–5.
            let bf = self.wd_e[(i, i)] * scale;
            let bm = self.wd_e[(3 + i, 3 + i)] * scale;
            if bf > T::zero() {
                dh[i] += gain * nu[3 + i] / bf;
            }
            if bm > T::zero() {
                dh[3 + i] += gain_m * nu[9 + i] / bm;
            }
        }
        // Back to NED and clamp to a physical range (±1 g, ±100 rad/s²).
        let f_ned = frame.to_ned(&dh.fixed_rows::<3>(0).into_owned());
        dh.fixed_rows_mut::<3>(0).copy_from(&f_ned);
        let g = self.params.gravity_mps2;
        for i in 0..3 {
            dh[i] = dh[i].max(-g).min(g);
            dh[3 + i] = dh[3 + i].max(lit(-100.0)).min(lit(100.0));
        }
        if !dh.iter().all(|v| v.is_finite()) {
            return;
        }
        if self.cfg.disturbance_trend_s.is_some() {
            // The trend's rate filter (see `disturbance_rate`): two cascaded
            // low-passes of the horizontal estimate. Differencing the estimate
            // directly would pass its noise at a gain of 1/dt.
            let a = (dt / lit::<T>(self.cfg.disturbance_rate_filter_s)).min(T::one());
            for i in 0..2 {
                let l1 = self.dist_lp[0][i] + a * (dh[i] - self.dist_lp[0][i]);
                self.dist_lp[0][i] = l1;
                self.dist_lp[1][i] += a * (l1 - self.dist_lp[1][i]);
            }
        }
        self.dist = dh;
    }
}
