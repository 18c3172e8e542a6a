//! Our own protocol ([`fc_proto`]) over the flight loop: frames in
//! ([`Loop::on_frame`]) decoded into the loop's steps, set-points,
//! selections and parameters; answers out as frames ([`Framed`]); the
//! conversions between wire and core types.

use crate::{
    encode, params, ByteLink, ControllerSpec, CycleClock, Fix, FrameDecoder, FrameError, FromFc, ImuSample, Job, Loop,
    NavMode, Outbox, QuatState, Setpoint, StateEstimate, Step, TimeBase, ToFc, Vector3, WireFix, WireSetpoint,
    MAX_FRAME, PROTOCOL_VERSION,
};

/// Our own protocol's frames on a byte link.
pub struct Framed<'a, L>(pub &'a mut L);

impl<L: ByteLink> Outbox for Framed<'_, L> {
    type Error = L::Error;
    fn send(&mut self, msg: &FromFc) -> Result<(), L::Error> {
        let mut out = [0u8; MAX_FRAME];
        match encode(msg, &mut out) {
            Ok(n) => self.0.write_all(&out[..n]),
            // Our own messages always fit MAX_FRAME (tested); nothing to send otherwise.
            Err(_) => Ok(()),
        }
    }
}

/// A controllers' setpoint as sent on the wire.
pub fn setpoint_to_wire(sp: &Setpoint<f32>) -> WireSetpoint {
    WireSetpoint {
        pos: sp.pos_ned_m.into(),
        vel: sp.vel_ned_mps.into(),
        acc: sp.acc_ned_mps2.into(),
        jerk: sp.jerk_ned_mps3.into(),
        yaw: sp.yaw_rad,
        yaw_rate: sp.yaw_rate_radps,
    }
}

/// A wire setpoint as the controllers' type; `None` if any value is not finite.
pub fn setpoint_from_wire(w: &WireSetpoint) -> Option<Setpoint<f32>> {
    let sp = Setpoint {
        pos_ned_m: Vector3::from(w.pos),
        vel_ned_mps: Vector3::from(w.vel),
        acc_ned_mps2: Vector3::from(w.acc),
        jerk_ned_mps3: Vector3::from(w.jerk),
        yaw_rad: w.yaw,
        yaw_rate_radps: w.yaw_rate,
    };
    sp.is_valid().then_some(sp)
}

/// Our protocol's answer to a parameter request (`ParamRead`, `ParamSet`)
/// under `settings`: parameter `index`'s id and value in force, and why a
/// write was refused (`refusal`; 0 when it was not, `Unknown`'s code for an
/// index past the table). For a board whose simulator writes its
/// parameters as [`FlightLoop`](crate::FlightLoop) answers them (`firmware-crtp`).
pub fn param_answer(settings: &params::Settings, index: u16, refusal: Option<params::Refusal>) -> FromFc {
    let p = params::PARAMS.get(usize::from(index));
    let mut id = [0u8; 16];
    if let Some(p) = p {
        // Ids are at most 16 characters (MAVLink's `param_id`); cut, not panic.
        let n = p.id.len().min(id.len());
        id[..n].copy_from_slice(&p.id.as_bytes()[..n]);
    }
    FromFc::Param {
        index,
        count: params::PARAMS.len() as u16,
        id,
        value: p.map_or(f32::NAN, |p| (p.get)(settings)),
        refusal: match (p, refusal) {
            (None, _) => params::Refusal::Unknown.code(),
            (_, Some(r)) => r.code(),
            (_, None) => 0,
        },
    }
}

/// A wire fix as the estimator's type.
pub fn fix_from_wire(w: &WireFix) -> Fix {
    Fix {
        age_s: w.age_us as f32 * 1e-6,
        pos_ned_m: w.pos.map(Vector3::from),
        pos_sigma_m: Vector3::from(w.pos_sigma),
        vel_ned_mps: w.vel.map(Vector3::from),
        vel_sigma_mps: w.vel_sigma,
        yaw_rad: w.yaw,
        yaw_sigma_rad: w.yaw_sigma,
        alt_m: w.alt,
        alt_sigma_m: w.alt_sigma,
    }
}

/// An estimator's fix on the wire (ages rounded to the µs).
pub fn fix_to_wire(f: &Fix) -> WireFix {
    WireFix {
        age_us: (f.age_s.max(0.0) * 1e6 + 0.5) as u32,
        pos: f.pos_ned_m.map(Into::into),
        pos_sigma: f.pos_sigma_m.into(),
        vel: f.vel_ned_mps.map(Into::into),
        vel_sigma: f.vel_sigma_mps,
        yaw: f.yaw_rad,
        yaw_sigma: f.yaw_sigma_rad,
        alt: f.alt_m,
        alt_sigma: f.alt_sigma_m,
    }
}

impl Loop {
    /// The frame decoder of the loop's link: bytes in, frames out for
    /// [`Loop::on_frame`].
    pub fn decoder(&mut self) -> &mut FrameDecoder<MAX_FRAME> {
        &mut self.decoder
    }

    /// One decoded frame (or why it did not decode) as if it had arrived at
    /// `now_us`: counted, its immediate answers (handshake, heartbeat,
    /// parameter reads) to `out`, and what the controller must do returned.
    pub fn on_frame<O: Outbox, C: CycleClock>(
        &mut self,
        frame: Result<ToFc, FrameError>,
        out: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<Option<Job>, O::Error> {
        match frame {
            Ok(m) => self.on_message(m, out, clock, now_us),
            Err(e) => {
                match e {
                    FrameError::Oversized => self.counters.oversized = self.counters.oversized.wrapping_add(1),
                    FrameError::Cobs => self.counters.bad_cobs = self.counters.bad_cobs.wrapping_add(1),
                    FrameError::Crc => self.counters.bad_crc = self.counters.bad_crc.wrapping_add(1),
                    FrameError::Message | FrameError::BufferTooSmall => {
                        self.counters.bad_message = self.counters.bad_message.wrapping_add(1)
                    }
                }
                Ok(None)
            }
        }
    }

    /// One decoded message (see [`Loop::on_frame`]).
    pub fn on_message<O: Outbox, C: CycleClock>(
        &mut self,
        msg: ToFc,
        out: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<Option<Job>, O::Error> {
        self.counters.ok = self.counters.ok.wrapping_add(1);
        match msg {
            ToFc::Hello { version } => {
                let accepted = version == PROTOCOL_VERSION;
                if accepted {
                    self.open_session();
                }
                out.send(&FromFc::HelloAck {
                    version: PROTOCOL_VERSION,
                    accepted,
                })?;
            }
            _ if !self.session => self.counters.unexpected = self.counters.unexpected.wrapping_add(1),
            ToFc::Heartbeat { seq } => out.send(&FromFc::Heartbeat { seq })?,
            ToFc::Select {
                controller,
                feedforward,
            } => {
                // An id no controller has is a message this end cannot read
                // (as an unknown enum index was in protocol v2's decoder).
                match ControllerSpec::from_wire(controller, feedforward) {
                    Ok(spec) => return Ok(Some(Job::Select(spec))),
                    Err(_) => self.counters.bad_message = self.counters.bad_message.wrapping_add(1),
                }
            }
            ToFc::Setpoint(w) => match setpoint_from_wire(&w) {
                Some(sp) => self.sp = sp,
                None => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
            },
            ToFc::Preview { k, sp } => {
                // Held for the controller's next step ([`Loop::apply_previews`]).
                // Slot 0 is the feed's (a preview moved on): from 1.
                match setpoint_from_wire(&sp) {
                    Some(sp) if k >= 1 && self.previews.hold(usize::from(k), sp) => {}
                    _ if self.takes_preview => {
                        self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1)
                    }
                    _ => {}
                }
            }
            ToFc::Sensor { seq, t_us, state } => {
                return Ok(Some(Job::Step(self.on_sensor(seq, t_us, &state, clock, now_us))))
            }
            ToFc::ParamRead { index } => out.send(&param_answer(&self.settings, index, None))?,
            ToFc::ParamSet { index, value } => {
                // Our protocol's motors turn from the session's first
                // step: re-designs only before it (`Loop::write_param`).
                return Ok(Some(Job::Param {
                    index,
                    value,
                    motors_turn: self.last_seq.is_some(),
                }));
            }
            ToFc::Fix(w) => {
                // Queued in the navigator for the next `Imu` step; a full
                // queue drops and counts it (`Nav.fixes_rejected`).
                self.nav.push_fix(&fix_from_wire(&w));
            }
            ToFc::Imu { seq, t_us, gyro, accel } => {
                let imu = ImuSample {
                    gyro_frd_radps: Vector3::from(gyro),
                    accel_frd_mps2: Vector3::from(accel),
                };
                return Ok(Some(Job::Step(self.on_imu(seq, t_us, &imu, clock, now_us))));
            }
        }
        Ok(None)
    }

    /// The sequence and time checks of a control step (`Sensor` or `Imu`):
    /// `Some(now)` on the loop's clock if it is to be flown; `None` (counted)
    /// if its `seq` or, in lockstep, its time does not increase or jumps.
    pub(crate) fn accept_step(&mut self, seq: u32, t_us: u64, now_us: u64) -> Option<u64> {
        let lockstep = self.cfg.time_base == TimeBase::Lockstep;
        let absurd_time = lockstep
            && self
                .last_t_us
                .is_some_and(|last| t_us <= last || t_us - last > self.cfg.max_time_step_us);
        if self.last_seq.is_some_and(|last| seq <= last) || absurd_time {
            self.counters.out_of_order = self.counters.out_of_order.wrapping_add(1);
            return None;
        }
        self.last_seq = Some(seq);
        Some(if lockstep {
            self.last_t_us = Some(t_us);
            // The simulated time since the last valid step: past the
            // timeout it was a failsafe episode, even if this frame ends it.
            self.timeout_at(t_us);
            t_us
        } else {
            now_us
        })
    }

    /// A full-state step (`Sensor`): checked, then the controller's step.
    pub(crate) fn on_sensor<C: CycleClock>(
        &mut self,
        seq: u32,
        t_us: u64,
        state: &[f32; 13],
        clock: &C,
        now_us: u64,
    ) -> Step {
        let mut step = Step {
            seq,
            t0: None,
            nav: false,
            control: None,
        };
        // Not flown, but answered (the held output, the counter in the
        // telemetry), so that a lockstep client waiting on this `seq` does
        // not block.
        let Some(now) = self.accept_step(seq, t_us, now_us) else {
            return step;
        };
        self.nav_failsafe = false;
        let est = StateEstimate::from_quat_state(&QuatState::from_column_slice(state));
        if !est.is_valid() || !self.plausible(&est, now) {
            self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
            return step;
        }
        self.last_pos = Some((est.pos_ned_m, now));
        let resume = self.take_resume(now);
        step.t0 = Some(clock.now());
        step.control = Some(self.control_job(now, est, self.sp, resume, false));
        step
    }

    /// The `Nav` and `NavBias` messages of step `seq` (one covariance
    /// diagonal for both).
    pub(crate) fn nav_messages(&self, seq: u32) -> (FromFc, FromFc) {
        let (mode, est) = match (self.nav.mode(), self.nav.estimate()) {
            (NavMode::Navigating, Some(e)) => (1, Some(e)),
            (NavMode::Failsafe, Some(e)) => (2, Some(e)),
            _ => (0, None),
        };
        let s = self.nav.estimator().sigmas();
        let c = self.nav.counters();
        let nav = FromFc::Nav {
            seq,
            mode,
            pos: est.map_or([0.0; 3], |e| e.pos_ned_m.into()),
            vel: est.map_or([0.0; 3], |e| e.vel_ned_mps.into()),
            att: est.map_or([0.0; 4], |e| e.att.into()),
            sigma: [s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8]],
            imu_rejected: c.imu_rejected.wrapping_add(c.imu_clipped),
            fixes_rejected: c
                .pos_rejected
                .wrapping_add(c.vel_rejected)
                .wrapping_add(c.yaw_rejected)
                .wrapping_add(c.alt_rejected)
                .wrapping_add(c.fix_invalid)
                .wrapping_add(self.nav.fixes_dropped()),
            failsafe_entries: self.nav.failsafe_entries(),
        };
        let (bg, ba) = self.nav.estimator().biases();
        let bias = FromFc::NavBias {
            seq,
            gyro_bias: bg.into(),
            accel_bias: ba.into(),
            sigma: [s[9], s[10], s[11], s[12], s[13], s[14]],
        };
        (nav, bias)
    }
}
