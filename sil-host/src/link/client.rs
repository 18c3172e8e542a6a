//! The host end of the wire protocol: a client that flies the controller
//! behind frames — in-process over a loopback byte link (`framed`) or over a
//! TCP stream (`tcp:HOST:PORT`, e.g. `sil-host serve`, or QEMU's USART) —
//! and [`Remote`], the flight [`Endpoint`] built on it.

use crate::endpoint::{Endpoint, NavReport, StepReport};
use crate::sensors::Readings;
use anyhow::{bail, Context, Result};
use fc_core::control::StateEstimate;
use fc_core::control::{ControllerSpec, Setpoint};
use fc_core::QuatState;
use fc_loop::nav::NavMode;
use fc_loop::{setpoint_to_wire, FcConfig, FlightLoop};
use fc_proto::{encode, FrameDecoder, FromFc, ToFc, WireSetpoint, MAX_FRAME, PROTOCOL_VERSION};
use hal_shim::host::{LoopbackLink, MonotonicClock};
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// What one remote control step returned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemoteStep {
    /// Inputs `[U1 N, U2 N, U3 N, U4 N·m]`.
    pub u: [f32; 4],
    /// Cycles (or instructions, or ns on the host) spent in the controller.
    pub cycles: u32,
    /// QP iterations.
    pub qp_iterations: u16,
    /// Failsafe active.
    pub failsafe: bool,
    /// The flight controller's frame and error counters after this step.
    pub counters: fc_proto::Counters,
    /// The on-board estimate (`Imu` steps only).
    pub nav: Option<NavMessage>,
}

/// The `Nav` answer of an `Imu` step, as received.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavMessage {
    /// 0 aligning, 1 navigating, 2 failsafe.
    pub mode: u8,
    /// Position (NED, m), velocity (NED, m/s), attitude (scalar first).
    pub pos: [f32; 3],
    /// See `pos`.
    pub vel: [f32; 3],
    /// See `pos`.
    pub att: [f32; 4],
    /// 1σ of position, velocity, attitude.
    pub sigma: [f32; 9],
    /// Refused IMU samples, refused fix parts, failsafe episodes.
    pub counts: [u32; 3],
    /// Gyro (rad/s) and accelerometer (m/s²) bias estimates, FRD (`NavBias`).
    pub biases: [[f32; 3]; 2],
    /// Their 1σ (`NavBias`): gyro, then accelerometer.
    pub bias_sigma: [f32; 6],
}

/// What one control step sends as its measurement.
#[derive(Debug, Clone, Copy)]
pub enum StepInput<'a> {
    /// The state (`Sensor`).
    State(&'a [f32; 13]),
    /// An IMU sample and the fixes that arrived (`Fix` frames, then `Imu`).
    Imu {
        /// Body rates, rad/s.
        gyro: [f32; 3],
        /// Specific force, m/s².
        accel: [f32; 3],
        /// Fixes, sent before the sample.
        fixes: &'a [fc_proto::WireFix],
    },
}

fn frame(m: &ToFc) -> Result<Vec<u8>> {
    let mut b = [0u8; MAX_FRAME];
    let n = encode(m, &mut b).map_err(|e| anyhow::anyhow!("encoding {m:?}: {e}"))?;
    Ok(b[..n].to_vec())
}

/// Where the frames go.
enum Transport {
    /// The core in this process behind a loopback byte link.
    Local {
        fc: Box<FlightLoop>,
        link: LoopbackLink,
        clock: MonotonicClock,
        t0: Instant,
    },
    /// A TCP peer.
    Tcp(TcpStream),
}

/// A client of the flight controller's protocol.
pub struct FcClient {
    transport: Transport,
    decoder: FrameDecoder<MAX_FRAME>,
    pending: Vec<FromFc>,
    /// The setpoint the flight controller holds (it keeps the last one sent).
    last_setpoint: Option<WireSetpoint>,
    /// Parameter reads sent with every step ([`FcClient::flood_param_reads`]).
    flood: u16,
    /// The next parameter the flood reads.
    flood_next: u16,
}

impl FcClient {
    /// The core in-process, reached through frames only.
    pub fn local() -> Result<Self> {
        let fc = FlightLoop::new(FcConfig::default()).map_err(|e| anyhow::anyhow!("flight controller: {e}"))?;
        Ok(Self::with(Transport::Local {
            fc: Box::new(fc),
            link: LoopbackLink::default(),
            clock: MonotonicClock::default(),
            t0: Instant::now(),
        }))
    }

    /// A TCP peer at `addr` (e.g. `127.0.0.1:7000`).
    pub fn tcp(addr: &str) -> Result<Self> {
        let s = TcpStream::connect(addr).with_context(|| format!("connecting to {addr}"))?;
        s.set_nodelay(true)?;
        s.set_read_timeout(Some(Duration::from_secs(5)))?;
        Ok(Self::with(Transport::Tcp(s)))
    }

    /// A client on an open TCP stream (QEMU's USART socket).
    pub(crate) fn over(stream: TcpStream) -> Self {
        Self::with(Transport::Tcp(stream))
    }

    fn with(transport: Transport) -> Self {
        Self {
            transport,
            decoder: FrameDecoder::new(),
            pending: Vec::new(),
            last_setpoint: None,
            flood: 0,
            flood_next: 0,
        }
    }

    fn send(&mut self, m: &ToFc) -> Result<()> {
        let bytes = frame(m)?;
        match &mut self.transport {
            Transport::Local { fc, link, clock, t0 } => {
                link.rx.extend(bytes);
                let now = t0.elapsed().as_micros() as u64;
                while !link.rx.is_empty() {
                    // The loopback link cannot fail (its error type is Infallible).
                    let Ok(()) = fc.service(link, clock, now);
                }
                Ok(())
            }
            Transport::Tcp(s) => Ok(s.write_all(&bytes)?),
        }
    }

    /// Waits for the next message the flight controller sends.
    fn receive(&mut self) -> Result<FromFc> {
        loop {
            if !self.pending.is_empty() {
                return Ok(self.pending.remove(0));
            }
            let bytes: Vec<u8> = match &mut self.transport {
                Transport::Local { link, .. } => {
                    if link.tx.is_empty() {
                        bail!("the flight controller sent nothing");
                    }
                    std::mem::take(&mut link.tx)
                }
                Transport::Tcp(s) => {
                    let mut buf = [0u8; 512];
                    // A signal (SIGINT/SIGTERM, whose handler asks the flight
                    // to stop at its next step) interrupts a blocking read:
                    // read again rather than end the flight with an error.
                    let n = loop {
                        match s.read(&mut buf) {
                            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                            r => break r.context("reading from the flight controller")?,
                        }
                    };
                    if n == 0 {
                        bail!("the flight controller closed the connection");
                    }
                    buf[..n].to_vec()
                }
            };
            for b in bytes {
                if let Some(Ok(m)) = self.decoder.push::<FromFc>(b) {
                    self.pending.push(m);
                }
            }
        }
    }

    /// Sends `n` parameter reads (`ParamRead`, cycling through the table)
    /// with every step from now on, right after the step's sample: a ground
    /// station flooding the flight controller while it flies. Each step
    /// waits for their answers (in order, for the indices read) as for its
    /// own, and checks them: the ground station's next reads and the next
    /// sample follow them. Under QEMU, whose USART has no baud rate, a host
    /// that did not wait would send the next step's bytes as fast as the
    /// image takes them, and the image's lowest-priority task, which sends
    /// these answers, could go without the processor for many steps (on a
    /// 115 200-baud line it has most of each step). 0 stops it.
    pub fn flood_param_reads(&mut self, n: u16) {
        self.flood = n;
    }

    /// Sends a parameter write (`ParamSet`) without waiting for its answer,
    /// as a ground station's write that crosses the next samples: the
    /// answer comes before a later step's, which passes over it.
    pub fn send_param_set(&mut self, index: usize, value: f32) -> Result<()> {
        let index = u16::try_from(index).map_err(|_| anyhow::anyhow!("parameter index {index} is past u16"))?;
        self.send(&ToFc::ParamSet { index, value })
    }

    /// Writes parameter `index` = `value` (`ParamSet`) and returns the
    /// flight controller's answer: the value in force, or an error naming
    /// the parameter and why it was refused.
    pub fn set_param(&mut self, index: usize, value: f32) -> Result<f32> {
        use fc_loop::params::PARAMS;
        let name = PARAMS.get(index).map_or("?", |p| p.id);
        self.send(&ToFc::ParamSet {
            index: index as u16,
            value,
        })?;
        // (Late acknowledgements of repeated Hellos may come first.)
        for _ in 0..64 {
            if let FromFc::Param {
                index: i,
                value: v,
                refusal,
                ..
            } = self.receive()?
            {
                if usize::from(i) != index {
                    continue;
                }
                if refusal != 0 {
                    bail!("the flight controller refused {name} = {value} (refusal code {refusal}; it keeps {v})");
                }
                return Ok(v);
            }
        }
        bail!("no answer to ParamSet {name}")
    }

    /// One IMU step of an image that answers `Imu` with `Actuator` alone (no
    /// session, telemetry or `Nav`: `firmware-crtp`, whose clients speak
    /// CRTP on another port): the fixes, the sample of step `seq`, then the
    /// inputs of its answer.
    pub fn imu_actuator(
        &mut self,
        seq: u32,
        t_us: u64,
        gyro: [f32; 3],
        accel: [f32; 3],
        fixes: impl IntoIterator<Item = fc_proto::WireFix>,
    ) -> Result<[f32; 4]> {
        for f in fixes {
            self.send(&ToFc::Fix(f))?;
        }
        self.send(&ToFc::Imu { seq, t_us, gyro, accel })?;
        loop {
            let got = self
                .receive()
                .with_context(|| format!("waiting for the answer to step {seq} (t {t_us} µs)"))?;
            if let FromFc::Actuator { seq: s, u, .. } = got {
                if s == seq {
                    return Ok(u);
                }
            }
        }
    }

    /// Writes the vehicle's parameters that differ from what the flight
    /// controller has (as read back), so that its controllers are
    /// designed for `vehicle` (`--vehicle` over a link).
    pub fn set_vehicle(&mut self, vehicle: &fc_core::VehicleParams<f64>) -> Result<()> {
        use fc_loop::params::{differences, Settings};
        let os4 = fc_core::VehicleParams::<f64>::OS4;
        if vehicle.gravity_mps2 != os4.gravity_mps2 || vehicle.rotor_gain != os4.rotor_gain {
            bail!(
                "gravity_mps2 and rotor_gain are not parameters of the flight controller: \
                 a vehicle file that sets them flies in-process only"
            );
        }
        let mut wanted = Settings::os4();
        wanted.vehicle = vehicle.cast();
        for (i, p, value) in differences(&wanted, &Settings::os4()) {
            let got = self.set_param(i, value)?;
            if got != value {
                bail!("{} reads back as {got}, not {value}", p.id);
            }
        }
        Ok(())
    }

    /// Handshake and controller selection (`spec` must have a wire id).
    pub fn open(&mut self, spec: ControllerSpec) -> Result<()> {
        self.open_for(spec, &fc_core::VehicleParams::OS4)
    }

    /// Handshake, the vehicle's parameters, and controller selection
    /// (`spec` must have a wire id).
    pub fn open_for(&mut self, spec: ControllerSpec, vehicle: &fc_core::VehicleParams<f64>) -> Result<()> {
        let (controller, feedforward) = spec.to_wire().map_err(|e| anyhow::anyhow!("{e}"))?;
        // Hello is repeated until answered: a flight controller that is still
        // booting drops what arrives before its UART is up.
        let patient = match &self.transport {
            Transport::Tcp(s) => {
                let t = s.read_timeout()?;
                s.set_read_timeout(Some(Duration::from_millis(200)))?;
                t
            }
            Transport::Local { .. } => None,
        };
        let mut answer = None;
        for _ in 0..50 {
            self.send(&ToFc::Hello {
                version: PROTOCOL_VERSION,
            })?;
            match self.receive() {
                Ok(m) => {
                    answer = Some(m);
                    break;
                }
                // Only a read timeout means "ask again".
                Err(e)
                    if e.chain().any(|c| {
                        c.downcast_ref::<std::io::Error>()
                            .is_some_and(|io| matches!(io.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut))
                    }) => {}
                Err(e) => return Err(e),
            }
        }
        if let Transport::Tcp(s) = &self.transport {
            s.set_read_timeout(patient)?;
        }
        match answer {
            Some(FromFc::HelloAck { accepted: true, .. }) => {}
            Some(other) => bail!("handshake refused: {other:?}"),
            None => bail!("no handshake answer after 50 tries"),
        }
        // Acknowledgements of repeated Hellos may still be queued: drop them.
        self.pending.retain(|m| !matches!(m, FromFc::HelloAck { .. }));
        self.last_setpoint = None;
        self.set_vehicle(vehicle)?;
        self.send(&ToFc::Select {
            controller,
            feedforward,
        })?;
        // Building a controller (an MPC's condensed QP and its iteration
        // bound) takes the flight controller a while; bytes sent meanwhile
        // would pile up in its receive queue. A heartbeat is answered only
        // after the selection is processed, so waiting for it paces the host.
        self.send(&ToFc::Heartbeat { seq: u32::MAX })?;
        // (Late acknowledgements of repeated Hellos may come first.)
        for _ in 0..64 {
            if let FromFc::Heartbeat { seq: u32::MAX } = self.receive()? {
                return Ok(());
            }
        }
        bail!("the flight controller did not confirm the controller selection")
    }

    /// One lockstep control step: setpoint (and preview), the state for step
    /// `seq`, and the flight controller's answer for that step.
    pub fn step(
        &mut self,
        seq: u32,
        t_us: u64,
        state: &[f32; 13],
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
    ) -> Result<RemoteStep> {
        self.step_with(seq, t_us, StepInput::State(state), Some(sp), preview)
    }

    /// One lockstep step with either measurement: the setpoint (`None`: the
    /// controller does not run at this step, the held one stays) and
    /// preview, then the state or the fixes and IMU sample of step `seq`,
    /// and the flight controller's answer (with its `Nav` for an IMU step).
    pub fn step_with(
        &mut self,
        seq: u32,
        t_us: u64,
        input: StepInput<'_>,
        sp: Option<&Setpoint<f32>>,
        preview: &[Setpoint<f32>],
    ) -> Result<RemoteStep> {
        // The flight controller holds its setpoint: send it only when it
        // changes (a fixed target then costs one frame a step, not two).
        if let Some(w) = sp.map(setpoint_to_wire).filter(|w| self.last_setpoint != Some(*w)) {
            self.send(&ToFc::Setpoint(w))?;
            self.last_setpoint = Some(w);
        }
        for (k, p) in preview.iter().enumerate() {
            self.send(&ToFc::Preview {
                k: (k + 1) as u8,
                sp: setpoint_to_wire(p),
            })?;
        }
        let want_nav = match input {
            StepInput::State(state) => {
                self.send(&ToFc::Sensor {
                    seq,
                    t_us,
                    state: *state,
                })?;
                false
            }
            StepInput::Imu { gyro, accel, fixes } => {
                for f in fixes {
                    self.send(&ToFc::Fix(*f))?;
                }
                self.send(&ToFc::Imu { seq, t_us, gyro, accel })?;
                true
            }
        };
        let count = fc_loop::params::PARAMS.len() as u16;
        // The flood's reads, answered in order: the step ends when they are
        // (the ground station waits for their answers before its next reads).
        let mut reads = std::collections::VecDeque::new();
        for _ in 0..self.flood {
            self.send(&ToFc::ParamRead { index: self.flood_next })?;
            reads.push_back(self.flood_next);
            self.flood_next = (self.flood_next + 1) % count;
        }
        let mut out: Option<RemoteStep> = None;
        let mut telemetry = false;
        let mut answered = false;
        // The step's four answers, the flood's, and some slack.
        for _ in 0..8 + usize::from(self.flood) {
            let got = self.receive().with_context(|| {
                let have = match &out {
                    None => "nothing",
                    Some(r) if r.nav.is_some() => "actuator, telemetry and nav frames",
                    Some(_) if telemetry => "actuator and telemetry frames",
                    Some(_) => "the actuator frame",
                };
                format!("waiting for the answer to step {seq} (t {t_us} µs; {have} so far)")
            })?;
            match got {
                FromFc::Actuator { seq: s, u, failsafe } if s == seq => {
                    out = Some(RemoteStep {
                        u,
                        cycles: 0,
                        qp_iterations: 0,
                        failsafe,
                        counters: Default::default(),
                        nav: None,
                    });
                }
                FromFc::Nav {
                    seq: s,
                    mode,
                    pos,
                    vel,
                    att,
                    sigma,
                    imu_rejected,
                    fixes_rejected,
                    failsafe_entries,
                } if s == seq && want_nav => {
                    let r = out
                        .as_mut()
                        .filter(|_| telemetry)
                        .ok_or_else(|| anyhow::anyhow!("nav before the actuator and telemetry frames"))?;
                    r.nav = Some(NavMessage {
                        mode,
                        pos,
                        vel,
                        att,
                        sigma,
                        counts: [imu_rejected, fixes_rejected, failsafe_entries],
                        biases: [[f32::NAN; 3]; 2],
                        bias_sigma: [f32::NAN; 6],
                    });
                }
                FromFc::NavBias {
                    seq: s,
                    gyro_bias,
                    accel_bias,
                    sigma,
                } if s == seq && want_nav => {
                    let n = out
                        .as_mut()
                        .and_then(|r| r.nav.as_mut())
                        .ok_or_else(|| anyhow::anyhow!("nav biases before the nav frame"))?;
                    n.biases = [gyro_bias, accel_bias];
                    n.bias_sigma = sigma;
                    answered = true;
                }
                FromFc::Telemetry {
                    seq: s,
                    cycles,
                    qp_iterations,
                    counters,
                    ..
                } if s == seq => {
                    let r = out
                        .as_mut()
                        .ok_or_else(|| anyhow::anyhow!("telemetry before the actuator frame"))?;
                    r.cycles = cycles;
                    r.qp_iterations = qp_iterations;
                    r.counters = counters;
                    telemetry = true;
                    answered |= !want_nav;
                }
                // (Another `Param`, a write's answer sent without waiting,
                // is passed over.)
                FromFc::Param { index, .. } if reads.front() == Some(&index) => {
                    reads.pop_front();
                }
                _ => {}
            }
            if answered && reads.is_empty() {
                return out.ok_or_else(|| anyhow::anyhow!("no actuator frame"));
            }
        }
        if answered {
            bail!(
                "step {seq}: no answer to {} parameter read(s) of the flood",
                reads.len()
            )
        }
        bail!("no answer for step {seq}")
    }
}

/// A flight [`Endpoint`] behind the wire protocol: the flight loop's state
/// goes out as a `Sensor` frame, the `Actuator` and `Telemetry` answers come
/// back. The controller's period and preview come from its spec: nothing is
/// designed on this side.
pub struct Remote {
    client: FcClient,
    spec: ControllerSpec,
    /// The spec's preview spacing, s (0 without a preview).
    preview_dt_s: f64,
    seq: u32,
}

impl Remote {
    /// Opens the session on `client`, sets the vehicle's parameters and
    /// selects `spec` (designed on board for `vehicle`).
    pub fn open(mut client: FcClient, spec: ControllerSpec, vehicle: &fc_core::VehicleParams<f64>) -> Result<Self> {
        client.open_for(spec, vehicle)?;
        let preview_dt_s = spec.preview().map_or(0.0, |(_, dt)| dt);
        Ok(Self {
            client,
            spec,
            preview_dt_s,
            seq: 0,
        })
    }
}

impl Remote {
    /// The preview points to send: none when the setpoint's own
    /// extrapolation reproduces them (the controller extrapolates to the
    /// same values, and a fixed target then costs 2 frames a step, not 22).
    fn preview_to_send<'a>(&self, sp: &Setpoint<f32>, preview: &'a [Setpoint<f32>]) -> &'a [Setpoint<f32>] {
        let redundant = preview.iter().enumerate().all(|(k, p)| {
            let e = sp.extrapolate(((k + 1) as f64 * self.preview_dt_s) as f32);
            setpoints_equal(&e, p)
        });
        if redundant {
            &[]
        } else {
            preview
        }
    }
}

impl Endpoint for Remote {
    fn period_s(&self) -> Option<f64> {
        self.spec.own_period_s()
    }
    fn preview(&self) -> Option<(usize, f64)> {
        self.spec.preview()
    }
    fn step(
        &mut self,
        t: f64,
        state: &QuatState<f64>,
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
    ) -> Result<StepReport> {
        self.seq += 1;
        let x: [f32; 13] = std::array::from_fn(|i| state[i] as f32);
        let sent = self.preview_to_send(sp, preview);
        let step = self.client.step(self.seq, (t * 1e6).round() as u64, &x, sp, sent)?;
        Ok(report_of(&step))
    }

    fn step_sensed(
        &mut self,
        t: f64,
        readings: &Readings,
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
        control: bool,
    ) -> Result<StepReport> {
        // The flight controller runs its controller on its own schedule, on
        // the same grid: between its runs the setpoint is not read, and is
        // not sent (over QEMU's USART every byte costs wall time).
        self.seq += 1;
        let sent = self.preview_to_send(sp, preview);
        let fixes: Vec<_> = readings.fixes.iter().map(fc_loop::fix_to_wire).collect();
        let input = StepInput::Imu {
            gyro: readings.imu.gyro_frd_radps.into(),
            accel: readings.imu.accel_frd_mps2.into(),
            fixes: &fixes,
        };
        let step = self
            .client
            .step_with(self.seq, (t * 1e6).round() as u64, input, control.then_some(sp), sent)?;
        let nav = step
            .nav
            .ok_or_else(|| anyhow::anyhow!("the flight controller sent no estimate for step {}", self.seq))?;
        let mut r = report_of(&step);
        // While aligning the flight controller holds hover thrust: the
        // in-process endpoint gives no output then, and the flight holds the
        // same hover command.
        if nav.mode == 0 {
            r.u = None;
        }
        r.nav = Some(nav_report(&nav));
        Ok(r)
    }
}

fn report_of(step: &RemoteStep) -> StepReport {
    StepReport {
        u: Some(step.u),
        // The flight controller reports its own time per step (ns on the host).
        cost: f64::from(step.cycles),
        iterations: step.qp_iterations,
        saturated: false,
        failsafe: step.failsafe,
        counters: Some(step.counters),
        nav: None,
    }
}

/// A received `Nav` and `NavBias` as the flight's estimator report: the
/// estimate, the biases and the covariance's diagonal (as σ); no
/// off-diagonal terms, so no NEES.
fn nav_report(n: &NavMessage) -> NavReport {
    use nalgebra::{Vector3, Vector4};
    let mode = match n.mode {
        0 => NavMode::Aligning,
        1 => NavMode::Navigating,
        _ => NavMode::Failsafe,
    };
    let estimate = (n.mode != 0).then(|| StateEstimate {
        pos_ned_m: Vector3::from(n.pos),
        vel_ned_mps: Vector3::from(n.vel),
        att: Vector4::from(n.att),
        rates_frd_radps: Vector3::zeros(),
    });
    let mut sigmas = [f32::NAN; fc_core::estimate::ERR];
    sigmas[..9].copy_from_slice(&n.sigma);
    sigmas[9..].copy_from_slice(&n.bias_sigma);
    NavReport {
        mode,
        estimate,
        biases: (Vector3::from(n.biases[0]), Vector3::from(n.biases[1])),
        covariance: None,
        sigmas,
        // The wire carries one count of refused IMU samples (rejected and
        // clipped) and one of refused fix parts (every kind, and invalid
        // fixes): they are reported as `imu_rejected` and `pos_rejected`.
        counters: fc_core::estimate::EskfCounters {
            imu_rejected: n.counts[0],
            pos_rejected: n.counts[1],
            ..Default::default()
        },
        failsafe_entries: n.counts[2],
    }
}

/// Equal to f32 rounding (relative 1e-6, absolute 1e-6).
fn setpoints_equal(a: &Setpoint<f32>, b: &Setpoint<f32>) -> bool {
    let close = |x: f32, y: f32| (x - y).abs() <= 1e-6 * (1.0 + x.abs().max(y.abs()));
    let vclose =
        |x: &nalgebra::Vector3<f32>, y: &nalgebra::Vector3<f32>| x.iter().zip(y.iter()).all(|(p, q)| close(*p, *q));
    vclose(&a.pos_ned_m, &b.pos_ned_m)
        && vclose(&a.vel_ned_mps, &b.vel_ned_mps)
        && vclose(&a.acc_ned_mps2, &b.acc_ned_mps2)
        && vclose(&a.jerk_ned_mps3, &b.jerk_ned_mps3)
        && close(a.yaw_rad, b.yaw_rad)
        && close(a.yaw_rate_radps, b.yaw_rate_radps)
}
