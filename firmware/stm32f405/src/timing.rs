//! What the image's tasks measure of every step: the time from data-ready
//! (the sample's interrupt) to the estimate, and to the controller's
//! answer (or the outputs driven), against the deadline of one 1 kHz
//! period: the IMU task's deadline and the 1 kHz controller's; the jobs and
//! answers a full queue dropped. In SysTick ticks (168 MHz); under QEMU's
//! `-icount shift=0` a tick is 1/0.168 instructions.

/// The deadline of a step, SysTick ticks: one 1 kHz period, 168 000
/// cycles. On silicon that is 168 000 ticks. Under QEMU (the `qemu`
/// feature), whose SysTick counts executed instructions, it is the
/// instructions the chip executes in that time at an assumed CPI of 1.5
/// with a 1.5 margin: 168 000 / 2.25 = 74 667 instructions = 12 544 ticks.
pub const DEADLINE_TICKS: u64 = if cfg!(feature = "qemu") { 12_544 } else { 168_000 };

/// SysTick ticks as instructions under QEMU's `-icount shift=0` (one
/// instruction per nanosecond, 0.168 ticks each).
pub const fn instructions(ticks: u64) -> u64 {
    ticks * 1000 / 168
}

/// Steps between two timing lines of the log (one second at 1 kHz).
pub const LOG_EVERY: u32 = 1000;

/// The figures so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StepTiming {
    /// Steps the controller's task answered.
    pub steps: u32,
    /// Worst data-ready → estimate done, ticks.
    pub worst_estimate_ticks: u64,
    /// Worst data-ready → the step's answer (controller flown), ticks.
    pub worst_answer_ticks: u64,
    /// Steps answered after their deadline, or dropped.
    pub missed: u32,
    /// Samples whose estimate was done after their deadline (the IMU
    /// task's own deadline: the next sample).
    pub imu_missed: u32,
    /// Jobs the controller's queue had no room for.
    pub jobs_dropped: u32,
    /// Answers the link's queue had no room for.
    pub answers_dropped: u32,
    /// Frames the transmitter gave up on.
    pub tx_timeouts: u32,
    /// Steps answered with the motors off while the controller was lent to
    /// a re-design (disarmed; counted in `steps` too).
    pub passed: u32,
}

/// The tasks' shared record.
#[derive(Debug)]
pub struct Timing {
    deadline_ticks: u64,
    now: StepTiming,
    /// The most the radio's interrupts took of one step, ticks (the CRTP
    /// images: apart from the step's figures, [`Timing::radio_in_step`]).
    worst_radio_ticks: u64,
    /// `worst_radio_ticks` when it was last logged.
    logged_radio_ticks: u64,
}

impl Timing {
    /// Nothing measured; a step is late after `deadline_ticks`.
    pub const fn new(deadline_ticks: u64) -> Self {
        Self {
            deadline_ticks,
            now: StepTiming {
                steps: 0,
                worst_estimate_ticks: 0,
                worst_answer_ticks: 0,
                missed: 0,
                imu_missed: 0,
                jobs_dropped: 0,
                answers_dropped: 0,
                tx_timeouts: 0,
                passed: 0,
            },
            worst_radio_ticks: 0,
            logged_radio_ticks: 0,
        }
    }

    /// A sample that arrived at `entry` was estimated at `done`.
    pub fn estimated(&mut self, entry: u64, done: u64) {
        let t = &mut self.now;
        let took = done.saturating_sub(entry);
        t.worst_estimate_ticks = t.worst_estimate_ticks.max(took);
        if took > self.deadline_ticks {
            t.imu_missed = t.imu_missed.wrapping_add(1);
        }
    }

    /// A step whose sample arrived at `entry` was answered at `done`.
    pub fn flown(&mut self, entry: u64, done: u64) {
        let t = &mut self.now;
        let took = done.saturating_sub(entry);
        t.steps = t.steps.wrapping_add(1);
        t.worst_answer_ticks = t.worst_answer_ticks.max(took);
        if took > self.deadline_ticks {
            t.missed = t.missed.wrapping_add(1);
        }
    }

    /// A step whose sample arrived at `entry` was answered at `done` with
    /// the motors off, its controller lent to a re-design.
    pub fn passed(&mut self, entry: u64, done: u64) {
        self.flown(entry, done);
        self.now.passed = self.now.passed.wrapping_add(1);
    }

    /// The radio's interrupts took `ticks` of a step (a CRTP image's radio;
    /// under QEMU, which delivers its bytes unpaced, kept apart from the
    /// step's figures, `crtp_app::RADIO_APART_FROM_STEPS`).
    pub fn radio_in_step(&mut self, ticks: u64) {
        self.worst_radio_ticks = self.worst_radio_ticks.max(ticks);
    }

    /// The most the radio's interrupts took of one step, instructions, if
    /// it grew since this last said so (for the log).
    pub fn radio_grown(&mut self) -> Option<u64> {
        (self.worst_radio_ticks > self.logged_radio_ticks).then(|| {
            self.logged_radio_ticks = self.worst_radio_ticks;
            instructions(self.worst_radio_ticks)
        })
    }

    /// A job found the controller's queue full: its step is missed.
    pub fn job_dropped(&mut self) {
        self.now.jobs_dropped = self.now.jobs_dropped.wrapping_add(1);
        self.now.missed = self.now.missed.wrapping_add(1);
    }

    /// `n` answers found the link's queue full.
    pub fn answers_dropped(&mut self, n: u32) {
        self.now.answers_dropped = self.now.answers_dropped.wrapping_add(n);
    }

    /// A frame's transmission timed out.
    pub fn tx_timeout(&mut self) {
        self.now.tx_timeouts = self.now.tx_timeouts.wrapping_add(1);
    }

    /// The figures so far.
    pub fn snapshot(&self) -> StepTiming {
        self.now
    }
}

impl StepTiming {
    /// A timing line is due: [`LOG_EVERY`] more steps since `logged`, or a
    /// step missed or anything dropped since.
    pub fn due(&self, logged: &StepTiming) -> bool {
        self.steps / LOG_EVERY != logged.steps / LOG_EVERY
            || self.missed != logged.missed
            || self.imu_missed != logged.imu_missed
            || self.answers_dropped != logged.answers_dropped
            || self.tx_timeouts != logged.tx_timeouts
    }

    /// Logs the figures if a line is due ([`StepTiming::due`]); `logged`
    /// becomes them.
    #[cfg(target_os = "none")]
    pub fn log_if_due(&self, logged: &mut StepTiming) {
        if !self.due(logged) {
            return;
        }
        defmt::info!(
            "timing: {=u32} steps, worst data-ready->estimate {=u64} instructions, worst data-ready->answer {=u64} instructions, deadline {=u64}: {=u32} missed ({=u32} jobs, {=u32} answers dropped, {=u32} tx timeouts); {=u32} IMU deadlines missed; {=u32} steps passed during a design",
            self.steps,
            instructions(self.worst_estimate_ticks),
            instructions(self.worst_answer_ticks),
            instructions(if cfg!(feature = "qemu") { DEADLINE_TICKS } else { 0 }),
            self.missed,
            self.jobs_dropped,
            self.answers_dropped,
            self.tx_timeouts,
            self.imu_missed,
            self.passed
        );
        *logged = *self;
    }
}

/// The longest the link's task has held the vehicle, the resource whose
/// ceiling is the sample task's priority (`crtp_app`): a sample that
/// becomes ready meanwhile waits for the hold to end, and its data-ready is
/// stamped only when its task runs, so [`StepTiming`]'s figures do not
/// include that wait. Timed inside each lock the link's task takes for a
/// packet or the log blocks (not the few of a re-design, which runs only
/// disarmed), less the interrupts above the ceiling that fell inside it
/// (the radio's bytes, which time themselves, each run's entry and exit
/// measured at boot: QEMU delivers them unpaced): the holds' own work,
/// SysTick ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Holds {
    worst_ticks: u64,
    logged_ticks: u64,
}

impl Holds {
    /// One hold of `ticks`.
    pub fn held(&mut self, ticks: u64) {
        self.worst_ticks = self.worst_ticks.max(ticks);
    }

    /// The longest hold so far, SysTick ticks.
    pub fn worst_ticks(&self) -> u64 {
        self.worst_ticks
    }

    /// Logs the longest hold if it grew since it was last logged.
    #[cfg(target_os = "none")]
    pub fn log_if_grown(&mut self) {
        if self.worst_ticks > self.logged_ticks {
            defmt::info!(
                "link: held the vehicle up to {=u64} instructions, the radio's interrupts apart",
                instructions(self.worst_ticks)
            );
            self.logged_ticks = self.worst_ticks;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_radios_most_in_a_step_is_said_once_each_time_it_grows() {
        let mut t = Timing::new(DEADLINE_TICKS);
        assert_eq!(t.radio_grown(), None);
        t.radio_in_step(168);
        t.radio_in_step(84);
        assert_eq!(t.radio_grown(), Some(1_000));
        assert_eq!(t.radio_grown(), None);
        t.radio_in_step(336);
        assert_eq!(t.radio_grown(), Some(2_000));
    }

    #[test]
    fn holds_keep_the_longest() {
        let mut h = Holds::default();
        assert_eq!(h.worst_ticks(), 0);
        for t in [30, 7_000, 12, 6_999] {
            h.held(t);
        }
        assert_eq!(h.worst_ticks(), 7_000);
    }

    #[test]
    fn the_qemu_deadline_is_a_1khz_period_at_cpi_1_5_with_a_1_5_margin() {
        // 168 MHz / 1 kHz = 168 000 cycles; / (1.5 × 1.5) = 74 667 instructions.
        let instr = 168_000.0 / (1.5 * 1.5);
        assert!(
            (instructions(12_544) as f64 - instr).abs() < 1.0,
            "{}",
            instructions(12_544)
        );
    }

    #[test]
    fn a_late_step_and_a_dropped_job_are_missed_and_worsts_are_kept() {
        let mut t = Timing::new(100);
        t.estimated(0, 30);
        t.estimated(1000, 1020);
        t.flown(0, 100);
        assert_eq!(t.snapshot().missed, 0, "on the deadline is in time");
        t.flown(1000, 1101);
        t.job_dropped();
        let s = t.snapshot();
        assert_eq!((s.steps, s.missed, s.jobs_dropped), (2, 2, 1));
        assert_eq!((s.worst_estimate_ticks, s.worst_answer_ticks), (30, 101));
        assert_eq!(s.imu_missed, 0, "every estimate in time");
        assert!(s.due(&StepTiming::default()));
        assert!(!s.due(&s));
        t.estimated(2000, 2101);
        assert_eq!(t.snapshot().imu_missed, 1, "an estimate past the deadline");
        assert!(t.snapshot().due(&s));
        t.passed(3000, 3050);
        let p = t.snapshot();
        assert_eq!(
            (p.steps, p.passed, p.missed),
            (3, 1, 2),
            "a passed step is a step, in time"
        );
    }
}
