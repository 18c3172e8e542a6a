//! The IMU step's shared half: the estimator, the commander's set-point,
//! the supervisor (failsafes, tumble, the end of a landing;
//! [`fc_loop::supervisor::Supervisor`]).

use super::{
    CrtpShared, CycleClock, Event, Fix, ImuSample, ImuStep, Power, Reference, Setpoint, IMU_TIMEOUT_US,
    SETPOINT_WATCHDOG,
};

impl CrtpShared {
    /// One IMU sample taken at `t_us` (`None`: the board's driver had
    /// none) with the fixes of the host's own position source (`heading`:
    /// they carry one), the IMU task's half: the sample checked (a bad or
    /// missing one replaced by the last good one,
    /// [`fc_loop::supervisor::ImuGuard`]), the set-point of this instant, one
    /// estimator step, the supervisor's checks; returns the controller's
    /// step ([`fly_step`](super::fly_step) flies it).
    pub fn imu_begin<C: CycleClock>(
        &mut self,
        t_us: u64,
        imu: Option<&ImuSample>,
        fixes: &[Fix],
        clock: &C,
    ) -> ImuStep {
        if t_us < self.now_us {
            // A host that started again: a new time line.
            self.lp.open_session();
            self.client.restart();
        }
        let (sample, _) = self.client.take_sample(t_us, imu);
        // The interval a velocity set-point moves over (at most 0.1 s).
        let dt_s = (t_us.saturating_sub(self.now_us) as f32 * 1e-6).min(0.1);
        self.now_us = t_us;
        for f in fixes {
            self.heading_seen |= f.yaw_rad.is_some();
            self.lp.push_fix(f);
        }
        let sp = self.setpoint_now(t_us, dt_s);
        if let Some(sp) = sp {
            self.lp.set_setpoint(&sp);
        }
        self.seq = self.seq.wrapping_add(1);
        // Nothing to step on before the first good sample.
        let job = sample
            .and_then(|imu| self.lp.imu_job(self.seq, t_us, &imu, clock, t_us))
            // The estimator's state goes out in log blocks, not with every
            // step's answer (our protocol's `Nav`): not built.
            .map(|step| fc_loop::Step { nav: false, ..step });
        if let Some(step) = job.as_ref() {
            // The controller previews what the commander will fly.
            self.lp
                .preview_from(step, self.client.commander(), self.client.trajectory_memory());
        }
        // The controller changes nothing the supervisor reads.
        self.supervise(t_us);
        ImuStep {
            job,
            setpoint: sp.is_some(),
        }
    }

    /// The end of an IMU step whose controller answered `u` (`None`: no
    /// answer): the supervisor's gate (armed and flying a set-point) and
    /// the mixer ([`fc_loop::Loop::power`]); returns what the motors get.
    pub fn imu_end(&mut self, step: &ImuStep, u: Option<[f32; 4]>) -> Power {
        let fly = self.flying() && step.setpoint;
        let power = self.lp.power(fly, u);
        self.u = power.u;
        self.motors = power.motors.commands;
        power
    }

    /// The set-point to fly at `t_us`, `dt_s` after the last step (the
    /// commander advanced: hand-over, watchdog, velocity), `None` while idle.
    pub(in crate::vehicle) fn setpoint_now(&mut self, t_us: u64, dt_s: f32) -> Option<Setpoint<f32>> {
        let (sp, event) = self.client.setpoint_now(t_us, dt_s, &SETPOINT_WATCHDOG);
        if event == Some(Event::StreamStopped) {
            self.say(format_args!("set-points stopped: motors off"));
        }
        sp
    }

    /// The supervisor's step ([`fc_loop::supervisor::Supervisor::step`]):
    /// the IMU's silence, tumble detection and the end of a landing, each
    /// said on the console.
    pub(in crate::vehicle) fn supervise(&mut self, t_us: u64) {
        let est = self.lp.navigator().estimate();
        let done = self.client.supervise(t_us, est.as_ref());
        if done.descent_began {
            let ms = IMU_TIMEOUT_US / 1000;
            self.say(format_args!("IMU silent for more than {ms} ms: failsafe descent"));
        }
        if done.tumbled {
            self.say(format_args!("tumbled: motors off"));
        }
        if done.landed {
            self.say(format_args!("landed: motors off"));
        }
    }

    /// What is flown now, as a reference (the estimate at rest when idle).
    pub(in crate::vehicle) fn reference(&self) -> Reference {
        self.client.flown(self.now_us).unwrap_or_else(|| {
            let est = self.lp.navigator().estimate();
            self.client.reference(self.now_us, est.as_ref())
        })
    }
}
