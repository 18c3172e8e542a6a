//! PX4's HIL inputs: `HIL_SENSOR` (one estimator step), the barometer and
//! magnetometer in it, `HIL_STATE_QUATERNION` fixes (and on the host, the
//! simulator's true state).

use super::{
    hil, AnyController, CycleClock, Fix, Home, MavMessage, MavShared, MavSink, Peer, StateFixSigmas, Vector3,
    BARO_PERIOD_US, HIL_SENSOR_DATA, HIL_STATE_QUATERNION_DATA, MAG_SIGMA_RAD, STREAMS,
};
use core::borrow::BorrowMut;
use fc_loop::{Actuation, LoopOf, Mutex, Step};

/// A position fix farther than this from the estimate (and outside its
/// gate) is implausible ([`fc_loop::health::plausible`]), m.
pub const POSITION_IMPLAUSIBLE_M: f32 = 0.5;

/// A magnetic heading farther than this from the estimate (and outside
/// its gate) is implausible, rad (20°).
pub const MAG_IMPLAUSIBLE_RAD: f32 = 0.35;

/// A `HIL_SENSOR`'s step between its halves: what the estimator's half
/// ([`MavShared::sensor_begin`]) hands the controller's.
#[derive(Debug, Clone, Copy)]
pub struct SensorStep {
    /// The sample's time (`time_usec`), µs.
    pub(in crate::vehicle) t_us: u64,
    /// The loop's step (`None`: nothing to step on yet).
    pub(in crate::vehicle) job: Option<Step>,
}

/// Flies `step` on the controller `ctrl` (an image's controller task), the
/// vehicle `v` locked only to take the step's inputs and record its result
/// ([`fc_loop::stabilize`]); returns the controller's result for
/// [`MavShared::sensor_end`] (`None`: not due).
pub fn fly_sensor_step<M: Mutex, C: CycleClock>(
    v: &mut M,
    ctrl: &mut AnyController<f32>,
    step: &SensorStep,
    clock: &C,
) -> Option<Actuation>
where
    M::T: BorrowMut<MavShared>,
{
    step.job
        .map(|j| fc_loop::stabilize(&mut LoopOf::<_, MavShared>::new(v), ctrl, &j, clock))
}

impl MavShared {
    /// Flies `truth` (the simulator's true state, NED about home: the
    /// origin of `HIL_STATE_QUATERNION`'s first fix) in place of the
    /// estimate, from the estimator's alignment on: the controller alone,
    /// for measuring it against a peer given perfect state. Host builds
    /// only (`truth-state`); the images fly their estimate.
    #[cfg(feature = "truth-state")]
    pub fn fly_truth(&mut self, truth: fc_core::control::StateEstimate<f32>) {
        self.lp.navigator_mut().set_truth(Some(truth));
    }

    /// The estimator's half of a `HIL_SENSOR` (`m`): the sample checked (a
    /// refused one is counted and steps nothing), a simulator that started
    /// again opens a new time line, the barometer and magnetometer fused,
    /// the commander's part (the ground-station failsafe, the mode's
    /// set-point for this step: `MavShared::command`), one estimator
    /// step ([`Loop::imu_job`](fc_loop::Loop::imu_job)).
    /// Returns the controller's step ([`fly_sensor_step`] flies it, then
    /// [`MavShared::sensor_end`] answers it); `None`: refused.
    pub fn sensor_begin<C: CycleClock>(&mut self, m: &HIL_SENSOR_DATA, clock: &C, now_us: u64) -> Option<SensorStep> {
        let Ok(s) = hil::imu_from_hil_sensor(m) else {
            self.counters.sensors_refused = self.counters.sensors_refused.wrapping_add(1);
            return None;
        };
        if self.last_sensor_us.is_none_or(|t| s.time_us < t) {
            // The first sample, or a simulator that started again: a new time line.
            self.lp.open_session();
            self.home = None;
            self.last_fix_us = None;
            self.mag_ref_rad = None;
            self.mag_due.reset();
            self.faults.new_time_line();
            for (k, st) in self.streams.iter_mut().enumerate() {
                *st = (STREAMS[k].interval_us, s.time_us);
            }
        }
        let dt_s = self
            .last_sensor_us
            .map_or(0.0, |t| s.time_us.saturating_sub(t) as f32 * 1e-6);
        self.last_sensor_us = Some(s.time_us);
        // The sample to step on: this one, or the last good one (the IMU's
        // faults, `faults::Faults::imu`); none yet, nothing to step.
        // In the air, the specific force the last commanded thrust gives
        // (FRD, m/s²): what stands in for an accelerometer without a reading.
        let (modes, lp) = (&self.modes, &self.lp);
        let thrust = || {
            modes
                .in_air(lp)
                .then(|| Vector3::new(0.0, 0.0, -lp.output()[0] / lp.vehicle().mass_kg))
        };
        let Some(imu) = self.faults.imu(s.time_us, &s.imu, thrust) else {
            self.counters.sensors_refused = self.counters.sensors_refused.wrapping_add(1);
            return None;
        };
        if let Some(alt) = s.baro_alt_m.and_then(|a| self.faults.baro(s.time_us, a)) {
            self.on_baro(s.time_us, alt);
        }
        if let Some(mag) = s.mag_frd_gauss.and_then(|m| self.faults.mag(s.time_us, &m)) {
            self.on_mag(s.time_us, &mag);
        }
        self.command(s.time_us, dt_s);
        self.seq = self.seq.wrapping_add(1);
        let job = self.lp.imu_job(self.seq, s.time_us, &imu, clock, now_us);
        let (airborne, armed) = (self.modes.in_air(&self.lp), self.modes.armed());
        self.faults.after_step(s.time_us, airborne, armed);
        if let Some(step) = job.as_ref() {
            // The controller previews what the modes' commander will fly;
            // with the preview off, what an idle commander previews:
            // nothing, so that the controller extrapolates.
            if self.exact_preview {
                self.lp
                    .preview_from(step, self.modes.commander(), &self.modes.trajectories());
            } else {
                const IDLE: fc_loop::commander::Commander = fc_loop::commander::Commander::new();
                self.lp.preview_from(step, &IDLE, &fc_loop::trajectory::NoTrajectories);
            }
        }
        Some(SensorStep { t_us: s.time_us, job })
    }

    /// The end of a sample's step whose controller gave `flown` (`None`:
    /// not due): the supervisor's gate (every armed step flies: the modes'
    /// failsafes are set-points, Hold and Land) and the mixer
    /// ([`Loop::power`](fc_loop::Loop::power)), the simulator answered
    /// (`HIL_ACTUATOR_CONTROLS`), then what the commander's part did told
    /// the ground station, the mission transfer's retries and the
    /// telemetry due.
    pub fn sensor_end<S: MavSink, C: CycleClock>(
        &mut self,
        step: &SensorStep,
        flown: Option<Actuation>,
        clock: &C,
        out: &mut S,
    ) -> Result<(), S::Error> {
        let power = self.lp.power(self.motors_turn(), flown.map(|a| a.u));
        self.cycles = (flown.map_or(0, |a| a.cycles), clock.hz());
        self.counters.steps = self.counters.steps.wrapping_add(1);
        self.motors = power.motors.commands;
        if power.on && power.motors.clamped {
            self.counters.clamped_steps = self.counters.clamped_steps.wrapping_add(1);
        }
        let t_us = step.t_us;
        out.send(
            Peer::Simulator,
            &MavMessage::HIL_ACTUATOR_CONTROLS(hil::actuator_controls(t_us, &self.motors, self.modes.armed())),
        )?;
        self.tell_health(out)?;
        self.tell_events(out)?;
        self.mission.tick(t_us, out)?;
        self.telemetry(t_us, out)
    }

    /// A barometric altitude (`HIL_SENSOR`, flagged): fused as the height
    /// above home at most every [`BARO_PERIOD_US`], once the estimator has
    /// a position. Its first reading is referenced to the estimated height
    /// then (a barometer's altitude is above sea level, and drifts with the
    /// weather: what is fused is its change).
    pub(in crate::vehicle) fn on_baro(&mut self, t_us: u64, alt_m: f32) {
        if self.lp.push_baro(t_us, alt_m) {
            self.counters.baro_fixes = self.counters.baro_fixes.wrapping_add(1);
        }
    }

    /// A magnetometer reading (`HIL_SENSOR`, all three axes flagged): its
    /// tilt-compensated heading ([`hil::mag_heading_rad`], levelled with the
    /// estimated roll and pitch) fused at most every [`BARO_PERIOD_US`].
    /// The first reading is referenced to the estimated heading then, which
    /// removes the declination (no world magnetic model on board).
    pub(in crate::vehicle) fn on_mag(&mut self, t_us: u64, mag_frd: &Vector3<f32>) {
        let Some(est) = self.lp.navigator().estimate() else {
            return;
        };
        let e = est.euler();
        let Some(psi_mag) = hil::mag_heading_rad(mag_frd, e[0], e[1]) else {
            return;
        };
        if !self.mag_due.due(t_us, BARO_PERIOD_US) {
            return;
        }
        let reference = *self.mag_ref_rad.get_or_insert(psi_mag - e[2]);
        let psi = fc_core::control::wrap_pi(psi_mag - reference);
        self.judge_mag(fc_core::control::wrap_pi(psi - e[2]));
        let fix = Fix {
            yaw_rad: Some(psi),
            yaw_sigma_rad: MAG_SIGMA_RAD,
            ..Fix::EMPTY
        };
        self.lp.push_fix(&fix);
        self.counters.mag_fixes = self.counters.mag_fixes.wrapping_add(1);
    }

    /// A `HIL_STATE_QUATERNION`: the position fix as an injected fault
    /// leaves it, taken while its source is healthy
    /// (`faults::Faults::position_usable`, with `sensor-faults`) at most every
    /// `HIL_FIX_MS`; the first one is home.
    pub(in crate::vehicle) fn on_state(&mut self, m: &HIL_STATE_QUATERNION_DATA) {
        let faulty = self.faults.position(m);
        let m = match &faulty {
            None => m,
            Some(Some(f)) => f,
            Some(None) => return,
        };
        if !hil::on_earth(m) {
            self.counters.states_refused = self.counters.states_refused.wrapping_add(1);
            return;
        }
        let home = *self.home.get_or_insert(Home::of(m));
        self.reported_ned_m = Some(home.ned_m(m.lat, m.lon, m.alt));
        let period_us = u64::from(self.lp.settings().fix_period_ms) * 1000;
        if self.last_fix_us.is_some_and(|t| m.time_usec < t + period_us) {
            return;
        }
        if !self.faults.position_usable(m) {
            return;
        }
        if !self.judge_position() {
            return;
        }
        match hil::fix_from_hil_state(m, &home, &StateFixSigmas::MOCAP_LIKE) {
            Ok(mut f) => {
                // A mocap gives position and heading, not velocity.
                f.vel_ned_mps = None;
                self.lp.push_fix(&f);
                self.last_fix_us = Some(m.time_usec);
            }
            Err(_) => self.counters.states_refused = self.counters.states_refused.wrapping_add(1),
        }
    }
}
