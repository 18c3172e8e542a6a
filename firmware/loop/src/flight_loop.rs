//! [`FlightLoop`]: the flight loop and its controller in one piece, for
//! the host and for images that run them in one task.

use crate::{
    apply_param, fallback_controller, install, params, run_job, start_front_end, AnyController, ByteLink, ControlError,
    ControllerSpec, CycleClock, Exclusive, FcConfig, Framed, Job, Loop, Outbox, ToFc,
};

/// The flight controller's state between steps.
///
/// One lockstep step over a host link (the SIL's `--target framed` does the
/// same; the image does it over USART1):
///
/// ```
/// use fc_loop::{FcConfig, FlightLoop};
/// use fc_proto::{encode, FrameDecoder, FromFc, ToFc, MAX_FRAME, PROTOCOL_VERSION};
/// use hal_shim::host::{LoopbackLink, MonotonicClock};
///
/// let mut fc = FlightLoop::new(FcConfig::default())?; // quaternion LQR, motors off
/// let (mut link, clock) = (LoopbackLink::default(), MonotonicClock::default());
/// let send = |link: &mut LoopbackLink, m: &ToFc| {
///     let mut frame = [0u8; MAX_FRAME];
///     let n = encode(m, &mut frame).expect("our messages fit a frame");
///     link.rx.extend(&frame[..n]);
/// };
/// send(&mut link, &ToFc::Hello { version: PROTOCOL_VERSION });
/// // The vehicle hovers at its boot setpoint, 1 m up: state
/// // [x y z (m, NED), ẋ ẏ ż (m/s), q0 q1 q2 q3, p q r (rad/s, FRD)].
/// let mut state = [0.0f32; 13];
/// (state[2], state[6]) = (-1.0, 1.0);
/// send(&mut link, &ToFc::Sensor { seq: 1, t_us: 2_000, state });
/// fc.service(&mut link, &clock, 2_000)?;
///
/// let mut rx = FrameDecoder::<MAX_FRAME>::new();
/// let replies: Vec<FromFc> = link.tx.iter().filter_map(|&b| rx.push(b)).collect::<Result<_, _>>()?;
/// assert!(matches!(replies[0], FromFc::HelloAck { accepted: true, .. }));
/// // Step 1's inputs: hover thrust (0.65 kg × 9.81 m/s²), no torque, not the failsafe.
/// let FromFc::Actuator { seq: 1, u, failsafe: false } = replies[1] else { panic!("{replies:?}") };
/// assert!((u[0] - 0.65 * 9.81).abs() < 1e-3 && u[1..].iter().all(|v| v.abs() < 1e-4));
/// assert!(matches!(replies[2], FromFc::Telemetry { .. }));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct FlightLoop {
    /// Everything but the controller.
    lp: Loop,
    /// The running controller.
    ctrl: AnyController<f32>,
}

impl core::ops::Deref for FlightLoop {
    type Target = Loop;
    fn deref(&self) -> &Loop {
        &self.lp
    }
}

impl core::ops::DerefMut for FlightLoop {
    fn deref_mut(&mut self) -> &mut Loop {
        &mut self.lp
    }
}

impl FlightLoop {
    /// A flight controller running the quaternion LQR until told otherwise,
    /// motors off until the first valid sensor frame:
    /// [`FlightLoop::unstarted`] then [`FlightLoop::start`].
    pub fn new(cfg: FcConfig) -> Result<Self, ControlError> {
        let mut me = Self::unstarted(cfg);
        me.start()?;
        Ok(me)
    }

    /// The flight loop with nothing designed yet: it flies the tuned Euler
    /// PD (which needs no design) until [`FlightLoop::start`] designs the
    /// boot controller in place. The firmware constructs it this way, in
    /// its static home, so that the boot design does not run beneath a
    /// stack copy of the whole loop (the controller is ≈ 7 KiB).
    pub fn unstarted(cfg: FcConfig) -> Self {
        Self::unstarted_with(cfg, params::Settings::os4())
    }

    /// The flight loop with `settings` (the parameters: vehicle,
    /// controller, failsafe), nothing designed yet: [`FlightLoop::start`]
    /// checks the settings and designs their controller for their vehicle,
    /// in place.
    pub fn unstarted_with(cfg: FcConfig, settings: params::Settings) -> Self {
        Self {
            ctrl: fallback_controller(settings.vehicle),
            lp: Loop::unstarted_with(cfg, settings),
        }
    }

    /// The loop and its controller apart: for an image that runs them in
    /// two tasks ([`run_job`]).
    pub fn split(&mut self) -> (&mut Loop, &mut AnyController<f32>) {
        (&mut self.lp, &mut self.ctrl)
    }

    /// Designs the settings' controller (by default the boot controller,
    /// [`BOOT_CONTROLLER`](crate::BOOT_CONTROLLER)) in place for their vehicle. On error (settings
    /// [`params::Settings::check`] refuses, or a failed design) the loop
    /// keeps flying the fallback PD.
    pub fn start(&mut self) -> Result<(), ControlError> {
        self.lp.settings.check().map_err(|_| ControlError::InvalidParameter)?;
        // Unstarted, the previous controller is the fallback PD.
        self.install(self.lp.settings.controller)
    }

    /// For a protocol front end (MAVLink, CRTP): checks the settings,
    /// designs their controller in place ([`FlightLoop::start`]), opens the
    /// session (set-points may come before samples) and sets the mixer the
    /// settings give for the front end's motors ([`Loop::mixer`]).
    pub fn start_front_end(&mut self) -> Result<(), params::Refusal> {
        start_front_end(&mut self.lp, &mut self.ctrl)
    }

    /// Sets parameter `index` ([`params::PARAMS`]) to `value`: the whole
    /// settings checked; a change of the vehicle, the controller or its
    /// gains and weights re-designs it, refused while `motors_turn` (the
    /// front end's supervisor gate, [`Loop::write_param`]). A refusal leaves
    /// everything as it was.
    pub fn apply_param(&mut self, index: usize, value: f32, motors_turn: bool) -> Result<(), params::Refusal> {
        apply_param(&mut self.lp, &mut self.ctrl, index, value, motors_turn)
    }

    /// Reads what the link has (bounded), handles every complete frame,
    /// writes replies, then applies the failsafe timer at time `now_us`.
    pub fn service<L: ByteLink, C: CycleClock>(
        &mut self,
        link: &mut L,
        clock: &C,
        now_us: u64,
    ) -> Result<(), L::Error> {
        let mut buf = [0u8; 64];
        for _ in 0..self.lp.cfg.max_reads_per_service {
            let n = link.read(&mut buf)?;
            if n == 0 {
                break;
            }
            for &b in &buf[..n.min(buf.len())] {
                if let Some(frame) = self.lp.decoder.push::<ToFc>(b) {
                    let job = self.lp.on_frame(frame, &mut Framed(link), clock, now_us)?;
                    if let Some(job) = job {
                        self.run(job, &mut Framed(link), clock)?;
                    }
                }
            }
        }
        self.lp.check_timeout(now_us);
        Ok(())
    }

    /// Runs a job of the loop on this controller.
    fn run<O: Outbox, C: CycleClock>(&mut self, job: Job, out: &mut O, clock: &C) -> Result<(), O::Error> {
        run_job(&mut Exclusive(&mut self.lp), &mut self.ctrl, job, out, clock)
    }

    /// [`install`] on this loop's controller.
    fn install(&mut self, spec: ControllerSpec) -> Result<(), ControlError> {
        install(&mut Exclusive(&mut self.lp), &mut self.ctrl, spec)
    }
}
