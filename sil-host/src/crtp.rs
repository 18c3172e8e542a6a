//! `sil-host crtp`: the flight controller behind CRTP over UDP, flying the
//! SIL's plant in real time, for cflib's `udp://` driver and cfclient.
//!
//! One datagram is one CRTP packet (header, then up to 30 bytes), cflib
//! 0.1.34's UDP wire format; answers go to the address the last datagram
//! came from. The plant (the vehicle file's parameters, quaternion form, on
//! a flat ground at NED z = 0, starting at rest there) and its sensors (a
//! BMI088 at 1 kHz; a motion-capture position and heading at 100 Hz unless
//! `--position-source external`) step every millisecond of wall time; the
//! vehicle is [`fc_crtp::vehicle::CrtpVehicle`], the same code a board runs.
//!
//! `--deck NAME` reports a deck attached in its `deck.bc*` flag: a stand-in
//! for the scripts that wait for a positioning deck; no deck is simulated,
//! and the position is still the motion capture's.
//!
//! `--count N` flies N such vehicles in one world (a swarm, for cflib's
//! `Swarm`): vehicle `i` answers on the listen port + `i`, starts where
//! `--at` puts it, has sensors of its own (seed + `i`), and two whose rotor
//! discs meet (centres within twice the hub distance plus a propeller's
//! radius) both lose their rotors and fall. The vehicles do not otherwise
//! touch: no downwash or wake of one reaches another.
//!
//! `--truth-to ADDR` sends the plant's true pose as one JSON datagram every
//! 10 ms (one per vehicle, each with its `id`): a motion-capture system's
//! stream, for a client that forwards it with `send_extpos`/`send_extpose`
//! and for tests that compare the flight with the truth. Its frame is the
//! Crazyflie's (x forward, y left, z up).

use crate::plant::{Plant, PlantConfig};
use crate::sensors::{FixProfile, SensorConfig, Sensors, IMU_PERIOD_S};
use anyhow::{Context, Result};
use fc_core::{AttitudeForm, VehicleParams};
use fc_crtp::vehicle::{CrtpSink, CrtpVehicle};
use fc_crtp::{CrtpCounters, Packet, MAX_PACKET};
use fc_loop::params::Settings;
use hal_shim::host::MonotonicClock;
use nalgebra::Vector3;
use serde::Serialize;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// cflib's first UDP port (its scan probes 19850–19859).
pub const DEFAULT_PORT: u16 = 19850;
/// Truth datagrams, every this many IMU steps (10 ms).
const TRUTH_EVERY: u64 = 10;
/// The most vehicles one world flies (cflib's radio URIs and UDP scan name
/// ten; a swarm's wall time grows with each flight stack stepped).
pub const MAX_VEHICLES: usize = 16;
/// A Crazyflie 2.x propeller's radius, m (its 45 mm propellers): with the
/// hub distance, how far a rotor disc reaches from the centre.
pub const PROP_RADIUS_M: f64 = 0.0225;

/// The default start layout of `n` vehicles: rows of four, 1 m apart, the
/// first at the origin (Crazyflie frame, x forward, y left, m).
pub fn grid_starts(n: usize) -> Vec<[f64; 2]> {
    (0..n).map(|i| [(i / 4) as f64, (i % 4) as f64]).collect()
}

/// Where the estimator's position comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PositionSource {
    /// The SIL's motion capture: position and heading at 100 Hz.
    Mocap,
    /// Only what the client sends (`send_extpos`, `send_extpose`).
    External,
}

/// How `sil-host crtp` runs.
#[derive(Debug, Clone)]
pub struct CrtpConfig {
    /// The UDP address to listen on: vehicle `i` of a swarm on its port + `i`.
    pub listen: SocketAddr,
    /// Where each vehicle starts on the ground, Crazyflie frame (x forward,
    /// y left), m: one per vehicle (a swarm when more than one, in process
    /// only; at most [`MAX_VEHICLES`]).
    pub starts_m: Vec<[f64; 2]>,
    /// The decks each vehicle reports attached in its `deck.bc*` flags
    /// (bit `i`: [`fc_crtp::vehicle::DECK_NAMES`]`[i]`; in process only):
    /// flags only, no deck simulated.
    pub decks: u8,
    /// The flight controller's settings (vehicle, airframe, controller).
    pub settings: Settings,
    /// The plant's vehicle (the same file's, in f64).
    pub vehicle: VehicleParams<f64>,
    /// The estimator's position source.
    pub position_source: PositionSource,
    /// Where to send the true pose (JSON, every 10 ms).
    pub truth_to: Option<SocketAddr>,
    /// Stop after this long, s (`None`: until killed).
    pub duration_s: Option<f64>,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// Every IMU sample in `(start, length)`, s of the plant's time, is NaN.
    pub imu_dead: Option<(f64, f64)>,
    /// No motion-capture fix in `(start, length)`, s of the plant's time.
    pub fix_outage: Option<(f64, f64)>,
    /// The first motion-capture fix at or after this time (s) is 5 m off.
    pub fix_outlier_at_s: Option<f64>,
    /// Where the vehicle runs.
    pub target: CrtpTarget,
    /// Set from elsewhere (a signal handler) to end the flight at the next
    /// step, with the summary written and QEMU stopped.
    pub stop: Arc<AtomicBool>,
    /// Keep persistent parameters (cflib's `param.persistent_store`) in
    /// this file, standing for the flash (in process): read at boot.
    pub storage: Option<std::path::PathBuf>,
}

/// Where `sil-host crtp`'s vehicle runs.
#[derive(Debug, Clone)]
pub enum CrtpTarget {
    /// In this process, served over UDP at [`CrtpConfig::listen`].
    InProcess,
    /// The `firmware-crtp` image in QEMU (or, with `crazyflie`, the
    /// Crazyflie 2.1 image booted through its boot shim): its USART6
    /// (syslink) a TCP server at `syslink` for `tools/nrf51_bridge.py`,
    /// which serves cflib; the plant's sensors on its USART1.
    Qemu {
        /// USART6's address.
        syslink: String,
        /// How long to wait for the bridge, s.
        wait_s: f64,
        /// Fly `firmware-crazyflie` (linked at 0x0800_4000, booted by
        /// `boot-shim`) instead of `firmware-crtp`.
        crazyflie: bool,
    },
}

/// What a session did.
#[derive(Debug, Clone, Serialize)]
pub struct CrtpSummary {
    /// Simulated time flown, s.
    pub duration_s: f64,
    /// IMU steps that ran late by more than 5 ms of wall time (a slow host).
    pub late_steps: u64,
    /// Simulated seconds per wall-clock second: 1 when the vehicle keeps up
    /// with real time; below 1 when it cannot (QEMU's emulated instructions).
    pub realtime_factor: f64,
    /// Where the vehicle ran: `in-process` or `qemu`.
    pub target: &'static str,
    /// Packets: handled, null, refused by kind (in-process).
    pub packets: Option<Counters>,
    /// Packets sent (in-process).
    pub sent: Option<u64>,
    /// IMU samples not good (in-process): missing, bad, steps flown on a
    /// held sample, silences past 10 ms (the image logs its own).
    pub imu: Option<[u32; 4]>,
    /// Position fixes (in-process): fused, refused by the estimator's gate,
    /// resets to them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fixes: Option<[u32; 3]>,
    /// The image's log (QEMU).
    pub firmware_log: Vec<String>,
    /// `--storage`: what the store was at boot, and the stored values
    /// taken and refused.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub storage: Option<(String, u16, u16)>,
    /// The plant's final position, Crazyflie frame, m (vehicle 0's in a
    /// swarm).
    pub final_position_m: [f64; 3],
    /// A swarm's vehicles, each its own flight stack and port (empty with
    /// one vehicle).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub vehicles: Vec<VehicleSummary>,
    /// A swarm's least distance between two vehicles' centres over the
    /// flight, m (`None` with one vehicle).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_separation_m: Option<f64>,
    /// Two vehicles' rotor discs touching: each pair once (empty with one
    /// vehicle, or none met).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub collisions: Vec<Collision>,
}

/// One vehicle of a swarm, in [`CrtpSummary::vehicles`].
#[derive(Debug, Clone, Serialize)]
pub struct VehicleSummary {
    /// Its index: its port is the first + `id`, its truth datagrams carry it.
    pub id: usize,
    /// The UDP address it answers on.
    pub listen: SocketAddr,
    /// Packets: handled, null, refused by kind.
    pub packets: Counters,
    /// Packets sent.
    pub sent: u64,
    /// IMU samples not good, as [`CrtpSummary::imu`].
    pub imu: [u32; 4],
    /// Its final position, Crazyflie frame, m.
    pub final_position_m: [f64; 3],
    /// It met another vehicle and fell (motors off).
    pub crashed: bool,
}

/// Two vehicles whose rotor discs met: both lose their rotors and fall.
#[derive(Debug, Clone, Serialize)]
pub struct Collision {
    /// The two vehicles.
    pub ids: [usize; 2],
    /// When, s of the plant's time.
    pub t_s: f64,
    /// Their centres' distance then, m.
    pub distance_m: f64,
}

/// [`CrtpCounters`] for the JSON summary.
#[derive(Debug, Clone, Serialize)]
pub struct Counters {
    /// Handled.
    pub handled: u32,
    /// Null packets.
    pub null: u32,
    /// Refused: no such port, unsupported, short, bad value, refused in
    /// state, not a packet.
    pub refused: [u32; 6],
}

impl From<CrtpCounters> for Counters {
    fn from(c: CrtpCounters) -> Self {
        Self {
            handled: c.handled,
            null: c.null,
            refused: [
                c.no_such_port,
                c.unsupported,
                c.short,
                c.bad_value,
                c.refused,
                c.malformed,
            ],
        }
    }
}

/// Sends to the client of the last datagram.
struct Udp<'a> {
    socket: &'a UdpSocket,
    to: Option<SocketAddr>,
    sent: u64,
    store: Option<crate::storage::FileStore>,
}

impl CrtpSink for Udp<'_> {
    type Error = std::io::Error;
    fn send(&mut self, p: &Packet) -> std::io::Result<()> {
        let Some(to) = self.to else {
            return Ok(());
        };
        let mut buf = [0u8; MAX_PACKET];
        let n = p.write_to(&mut buf);
        match self.socket.send_to(&buf[..n], to) {
            Ok(_) => {
                self.sent += 1;
                Ok(())
            }
            // A client that went away: its answers are dropped, as a radio's.
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::ConnectionRefused | std::io::ErrorKind::WouldBlock
                ) =>
            {
                Ok(())
            }
            Err(e) => Err(e),
        }
    }
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        match &mut self.store {
            Some(s) => Some(s),
            None => None,
        }
    }
}

/// The Crazyflie world frame's position (x forward, y left, z up) of NED `p`.
fn cf_of(p: &Vector3<f64>) -> [f64; 3] {
    [p[0], -p[1], -p[2]]
}

/// A 1S LiPo under load: 4.2 V full, falling 0.3 V over 7 minutes of
/// flight and sagging up to 0.3 V with the thrust (fraction of full).
fn battery_v(flown_s: f64, thrust_fraction: f64) -> f32 {
    (4.2 - 0.3 * (flown_s / 420.0).min(1.0) - 0.3 * thrust_fraction.clamp(0.0, 1.0)) as f32
}

/// The plant's side of the image's USART1 (our framed protocol): the
/// vehicle's parameters, then one `Imu` (and its fixes) per step, each
/// answered with `Actuator`.
struct SimLink {
    client: crate::link::FcClient,
    seq: u32,
}

impl SimLink {
    /// Writes the parameters of `s` that differ from the image's boot
    /// values (the OS4's) and checks each answer.
    fn set_params(&mut self, s: &Settings) -> Result<()> {
        use fc_loop::params::differences;
        for (i, p, value) in differences(s, &Settings::os4()) {
            let got = self.client.set_param(i, value)?;
            if got != value {
                anyhow::bail!("the image took {} = {value} as {got}", p.id);
            }
        }
        Ok(())
    }

    /// One IMU step: the fixes, the sample, the inputs of its answer.
    fn step(
        &mut self,
        t_us: u64,
        imu: &fc_core::estimate::ImuSample,
        fixes: &[fc_core::estimate::Fix],
    ) -> Result<nalgebra::Vector4<f32>> {
        self.seq += 1;
        let u = self.client.imu_actuator(
            self.seq,
            t_us,
            imu.gyro_frd_radps.into(),
            imu.accel_frd_mps2.into(),
            fixes.iter().map(fc_loop::fix_to_wire),
        )?;
        Ok(nalgebra::Vector4::from(u))
    }
}

/// The vehicle behind the plant.
#[allow(clippy::large_enum_variant, reason = "one per run, on run()'s stack")]
enum Fc<'a> {
    /// In this process, answering cflib over UDP.
    Local {
        vehicle: Box<CrtpVehicle>,
        socket: &'a UdpSocket,
        out: Udp<'a>,
        clock: MonotonicClock,
    },
    /// The `firmware-crtp` image in QEMU.
    Image { qemu: crate::link::Qemu, link: SimLink },
}

impl Fc<'_> {
    /// Serves what cflib sent (in-process only: the image's come through the bridge).
    fn serve(&mut self, buf: &mut [u8]) -> Result<()> {
        let Fc::Local {
            vehicle, socket, out, ..
        } = self
        else {
            return Ok(());
        };
        loop {
            match socket.recv_from(buf) {
                Ok((n, from)) => {
                    out.to = Some(from);
                    match Packet::from_bytes(&buf[..n]) {
                        Ok(p) => vehicle.handle(&p, out)?,
                        Err(e) => vehicle.count_malformed(e),
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(()),
                // A previous client's port closed (ICMP): not this client's error.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => continue,
                Err(e) => return Err(e).context("receiving CRTP"),
            }
        }
    }

    /// One IMU step; returns the inputs and whether the motors turn.
    fn step(
        &mut self,
        t_us: u64,
        r: &crate::sensors::Readings,
        battery: impl Fn(f32) -> f32,
    ) -> Result<(nalgebra::Vector4<f32>, bool)> {
        match self {
            Fc::Local {
                vehicle, out, clock, ..
            } => {
                let u = vehicle.imu_step(t_us, &r.imu, &r.fixes, clock);
                vehicle.set_battery(battery(u[0]), 0);
                vehicle.poll(out)?;
                Ok((u, vehicle.flying()))
            }
            // The image's battery comes from the nRF51 (the bridge).
            Fc::Image { link, .. } => {
                let u = link.step(t_us, &r.imu, &r.fixes)?;
                Ok((u, u != nalgebra::Vector4::zeros()))
            }
        }
    }

    fn armed(&self) -> Option<bool> {
        match self {
            Fc::Local { vehicle, .. } => Some(vehicle.armed()),
            Fc::Image { .. } => None,
        }
    }
}

/// One vehicle of the world: its flight stack, its plant and sensors.
struct Craft<'a> {
    fc: Fc<'a>,
    plant: Plant,
    sensors: Sensors,
    /// Seconds flown with the motors on (the battery's discharge).
    flown_s: f64,
    /// Met another vehicle: its rotors stop and it falls.
    crashed: bool,
}

/// The in-process vehicle on `socket`: with `--storage`, booted from it.
fn local<'a>(cfg: &CrtpConfig, socket: &'a UdpSocket, stored: &mut Option<(String, u16, u16)>) -> Result<Fc<'a>> {
    let (mut settings, mut store) = (cfg.settings, None);
    if let Some(path) = &cfg.storage {
        let (mut st, boot) = crate::storage::open(path, "crtp")?;
        let l = fc_loop::params::load(settings, |i| st.param(i))
            .map_err(|e| anyhow::anyhow!("--storage {}: {e}", path.display()))?;
        eprintln!(
            "crtp: storage: {} persistent parameter(s) taken, {} refused",
            l.taken, l.refused.0
        );
        settings = l.settings;
        *stored = Some((boot.to_string(), l.taken, l.refused.0));
        store = Some(st);
    }
    let mut vehicle = Box::new(
        CrtpVehicle::new(settings).map_err(|e| anyhow::anyhow!("the flight controller's settings are refused: {e}"))?,
    );
    // cflib's "default value": the command line's, not the stored.
    vehicle.set_defaults(cfg.settings);
    vehicle.report_decks(cfg.decks);
    if let Some(st) = store.as_mut() {
        let (taken, refused) = vehicle.load_stored(st).map_err(|e| anyhow::anyhow!("--storage: {e}"))?;
        if taken + refused > 0 {
            eprintln!("crtp: storage: {taken} other persistent parameter(s) taken (ring.effect), {refused} refused");
        }
    }
    Ok(Fc::Local {
        vehicle,
        socket,
        out: Udp {
            socket,
            to: None,
            sent: 0,
            store,
        },
        clock: MonotonicClock::default(),
    })
}

/// The image in QEMU, up and with the vehicle's parameters written.
fn image(cfg: &CrtpConfig, syslink: &str, wait_s: f64, crazyflie: bool) -> Result<Fc<'static>> {
    let boot = if crazyflie {
        crate::link::Boot::Shim {
            shim: crate::link::boot_shim_elf()?,
            image: crate::link::firmware_crazyflie_elf()?,
        }
    } else {
        crate::link::Boot::Direct(crate::link::firmware_crtp_elf()?)
    };
    let mut qemu = crate::link::Qemu::start_with_syslink(&boot, syslink, wait_s)?;
    eprintln!("crtp: the image's syslink (USART6) waits on tcp:{syslink} for tools/nrf51_bridge.py");
    let stream = qemu.connect()?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut link = SimLink {
        client: crate::link::FcClient::over(stream),
        seq: 0,
    };
    link.set_params(&cfg.settings)?;
    eprintln!("crtp: the image is up, the vehicle's parameters written");
    Ok(Fc::Image { qemu, link })
}

/// Checks a configuration before anything is bound or booted.
fn check(cfg: &CrtpConfig) -> Result<()> {
    let n = cfg.starts_m.len();
    if !(1..=MAX_VEHICLES).contains(&n) {
        anyhow::bail!("{n} vehicles: one world flies 1 to {MAX_VEHICLES}");
    }
    if n > 1 && !matches!(cfg.target, CrtpTarget::InProcess) {
        anyhow::bail!("a swarm ({n} vehicles) flies in process only: each image in QEMU is one vehicle");
    }
    if n > 1 && cfg.storage.is_some() {
        anyhow::bail!("--storage keeps one vehicle's flash: a swarm ({n} vehicles) has none");
    }
    if cfg.decks != 0 && !matches!(cfg.target, CrtpTarget::InProcess) {
        anyhow::bail!("--deck is for the in-process vehicle: the images in QEMU report no deck");
    }
    if cfg.storage.is_some() && !matches!(cfg.target, CrtpTarget::InProcess) {
        anyhow::bail!("--storage is for the in-process vehicle: the images in QEMU keep their own (a RAM stand-in)");
    }
    for (i, s) in cfg.starts_m.iter().enumerate() {
        if !s.iter().all(|v| v.is_finite() && v.abs() <= 100.0) {
            anyhow::bail!("vehicle {i}'s start {s:?} is out of range: each of x, y in [-100, 100] m");
        }
    }
    let reach = 2.0 * (cfg.settings.hub_m as f64 + PROP_RADIUS_M);
    for i in 0..n {
        for j in i + 1..n {
            let (a, b) = (cfg.starts_m[i], cfg.starts_m[j]);
            let d = (a[0] - b[0]).hypot(a[1] - b[1]);
            if d < reach {
                anyhow::bail!("vehicles {i} and {j} start {d:.3} m apart: their rotors reach {reach:.3} m");
            }
        }
    }
    Ok(())
}

/// Runs the server until `duration_s` (or forever).
pub fn run(cfg: &CrtpConfig) -> Result<CrtpSummary> {
    check(cfg)?;
    let n = cfg.starts_m.len();
    // One socket per vehicle, bound before any vehicle borrows one.
    let mut sockets = Vec::new();
    if matches!(cfg.target, CrtpTarget::InProcess) {
        for i in 0..n {
            let mut at = cfg.listen;
            if at.port() != 0 {
                let port = usize::from(at.port()) + i;
                at.set_port(
                    u16::try_from(port).map_err(|_| anyhow::anyhow!("vehicle {i}'s port {port} is past 65535"))?,
                );
            }
            let s = UdpSocket::bind(at).with_context(|| format!("binding UDP {at}"))?;
            s.set_nonblocking(true)?;
            eprintln!("crtp: vehicle {i} listening on udp://{}", s.local_addr()?);
            sockets.push(s);
        }
    }
    let truth = match cfg.truth_to {
        Some(to) => {
            let s = UdpSocket::bind("127.0.0.1:0")?;
            Some((s, to))
        }
        None => None,
    };
    let mut stored = None;
    let pc = PlantConfig {
        params: cfg.vehicle,
        ..PlantConfig::nominal(AttitudeForm::Quaternion)
    };
    let mut crafts = Vec::with_capacity(n);
    for (i, start) in cfg.starts_m.iter().enumerate() {
        let fc = match &cfg.target {
            CrtpTarget::Qemu {
                syslink,
                wait_s,
                crazyflie,
            } => image(cfg, syslink, *wait_s, *crazyflie)?,
            CrtpTarget::InProcess => local(cfg, &sockets[i], &mut stored)?,
        };
        // Crazyflie (x, y) → NED (x, −y), on the ground.
        let mut plant = Plant::new(
            pc,
            &fc_core::hover_quat_state(&Vector3::new(start[0], -start[1], 0.0), 0.0),
        );
        plant.set_rotor_speeds(nalgebra::Vector4::zeros());
        plant.contact_ground(0.0);
        let mut sensor_cfg = SensorConfig::new(FixProfile::Mocap, cfg.seed.wrapping_add(i as u64));
        sensor_cfg.faults.imu_dead = cfg.imu_dead;
        sensor_cfg.faults.outage = cfg.fix_outage;
        sensor_cfg.faults.outlier_at_s = cfg.fix_outlier_at_s;
        let sensors = Sensors::new(sensor_cfg, IMU_PERIOD_S)?;
        crafts.push(Craft {
            fc,
            plant,
            sensors,
            flown_s: 0.0,
            crashed: false,
        });
    }
    let u1_max = 4.0 * cfg.vehicle.kf_ns2 * cfg.vehicle.omega_max_radps.powi(2);
    let reach = 2.0 * (cfg.settings.hub_m as f64 + PROP_RADIUS_M);
    let mut min_separation = f64::INFINITY;
    let mut collisions: Vec<Collision> = Vec::new();
    let mut positions = Vec::with_capacity(n);
    let start = Instant::now();
    let mut step: u64 = 0;
    let mut late: u64 = 0;
    let mut buf = [0u8; 256];
    loop {
        let t = step as f64 * IMU_PERIOD_S;
        if cfg.duration_s.is_some_and(|d| t > d) || cfg.stop.load(Ordering::Relaxed) {
            break;
        }
        // Packets that arrived, answered at once.
        for c in &mut crafts {
            c.fc.serve(&mut buf)?;
        }
        // The simulated millisecond, in step with the wall clock.
        let due = start + Duration::from_secs_f64(t);
        let now = Instant::now();
        if due > now {
            std::thread::sleep((due - now).min(Duration::from_micros(500)));
            continue;
        }
        if now - due > Duration::from_millis(5) {
            late += 1;
        }
        let t_us = (t * 1e6).round() as u64;
        for (id, c) in crafts.iter_mut().enumerate() {
            let mut readings = c.sensors.read(t, &c.plant);
            if cfg.position_source == PositionSource::External {
                readings.fixes.clear();
            }
            let flown_s = c.flown_s;
            let (mut u, flying) =
                c.fc.step(t_us, &readings, |u1| battery_v(flown_s, f64::from(u1) / u1_max))?;
            if flying {
                c.flown_s += IMU_PERIOD_S;
            }
            if c.crashed {
                // Its rotors met another's: they stop, whatever is commanded.
                u = nalgebra::Vector4::zeros();
                c.plant.set_rotor_speeds(nalgebra::Vector4::zeros());
            }
            c.plant.step(&u.cast::<f64>(), IMU_PERIOD_S);
            c.plant.contact_ground(0.0);
            if let Some((s, to)) = &truth {
                if step.is_multiple_of(TRUTH_EVERY) {
                    let _ = s.send_to(truth_line(t, id, &c.plant, c.fc.armed(), flying).as_bytes(), to);
                }
            }
        }
        // Every pair of rotor discs, each millisecond.
        if n > 1 {
            positions.clear();
            positions.extend(crafts.iter().map(|c| c.plant.position()));
            let least = separations(&positions, reach, |i, j, d| {
                if !collisions.iter().any(|k| k.ids == [i, j]) {
                    eprintln!("crtp: vehicles {i} and {j} collide at t {t:.3} s, {d:.3} m apart: both fall");
                    collisions.push(Collision {
                        ids: [i, j],
                        t_s: t,
                        distance_m: d,
                    });
                }
            });
            min_separation = min_separation.min(least);
            for k in &collisions {
                crafts[k.ids[0]].crashed = true;
                crafts[k.ids[1]].crashed = true;
            }
        }
        step += 1;
    }
    let duration_s = step as f64 * IMU_PERIOD_S;
    let realtime_factor = duration_s / start.elapsed().as_secs_f64().max(1e-9);
    let swarm = n > 1;
    let mut vehicles = Vec::new();
    let mut first = None;
    for (id, c) in crafts.into_iter().enumerate() {
        let final_position_m = cf_of(&c.plant.position());
        let summary = match c.fc {
            Fc::Local {
                vehicle, out, socket, ..
            } => {
                let imu = {
                    let k = vehicle.imu_counters();
                    [k.missing, k.bad, k.held, k.timeouts]
                };
                if swarm {
                    vehicles.push(VehicleSummary {
                        id,
                        listen: socket.local_addr()?,
                        packets: vehicle.counters().into(),
                        sent: out.sent,
                        imu,
                        final_position_m,
                        crashed: c.crashed,
                    });
                }
                CrtpSummary {
                    duration_s,
                    late_steps: late,
                    realtime_factor,
                    target: "in-process",
                    packets: Some(vehicle.counters().into()),
                    sent: Some(out.sent),
                    imu: Some(imu),
                    fixes: Some({
                        let k = vehicle.flight_loop().navigator().counters();
                        [k.pos_fused, k.pos_rejected, k.pos_resets]
                    }),
                    firmware_log: Vec::new(),
                    storage: stored.clone(),
                    final_position_m,
                    vehicles: Vec::new(),
                    min_separation_m: None,
                    collisions: Vec::new(),
                }
            }
            Fc::Image { qemu, link } => {
                drop(link);
                CrtpSummary {
                    duration_s,
                    late_steps: late,
                    realtime_factor,
                    target: "qemu",
                    packets: None,
                    sent: None,
                    imu: None,
                    fixes: None,
                    firmware_log: qemu.finish()?,
                    storage: None,
                    final_position_m,
                    vehicles: Vec::new(),
                    min_separation_m: None,
                    collisions: Vec::new(),
                }
            }
        };
        first.get_or_insert(summary);
    }
    let mut summary = first.context("no vehicle")?;
    if swarm {
        summary.vehicles = vehicles;
        summary.min_separation_m = Some(min_separation);
        summary.collisions = collisions;
    }
    Ok(summary)
}

/// The least distance between two of `positions` (NED, m; infinite with
/// fewer than two), calling `touched(i, j, distance)` for each pair `i < j`
/// closer than `reach`: two vehicles whose rotor discs meet.
fn separations(positions: &[Vector3<f64>], reach: f64, mut touched: impl FnMut(usize, usize, f64)) -> f64 {
    let mut least = f64::INFINITY;
    for (i, a) in positions.iter().enumerate() {
        for (j, b) in positions.iter().enumerate().skip(i + 1) {
            let d = (a - b).norm();
            least = least.min(d);
            if d < reach {
                touched(i, j, d);
            }
        }
    }
    least
}

/// One truth datagram: vehicle `id`'s true pose at `t`, Crazyflie frame.
fn truth_line(t: f64, id: usize, plant: &Plant, armed: Option<bool>, flying: bool) -> String {
    let x = plant.quat_state();
    let p = cf_of(&plant.position());
    let armed = armed.map_or("null".to_string(), |a| a.to_string());
    // Body FRD → NED as body FLU → (x, y, z up): (w, x, −y, −z).
    format!(
        "{{\"t\":{t:.3},\"id\":{id},\"x\":{:.5},\"y\":{:.5},\"z\":{:.5},\"qx\":{:.6},\"qy\":{:.6},\"qz\":{:.6},\"qw\":{:.6},\"armed\":{armed},\"flying\":{flying}}}",
        p[0], p[1], p[2], x[7], -x[8], -x[9], x[6]
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_layout_is_rows_of_four_a_metre_apart() {
        assert_eq!(grid_starts(1), vec![[0.0, 0.0]]);
        let g = grid_starts(6);
        assert_eq!(g[3], [0.0, 3.0]);
        assert_eq!(g[4], [1.0, 0.0]);
        assert_eq!(g[5], [1.0, 1.0]);
    }

    #[test]
    fn separations_are_the_least_pairwise_distance_and_the_pairs_in_reach() {
        // A 3-4-5 triangle and a point 0.1 m from its first corner.
        let p = [
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(3.0, 0.0, -1.0),
            Vector3::new(0.0, 4.0, -1.0),
            Vector3::new(0.0, 0.0, -1.1),
        ];
        let mut met = Vec::new();
        let least = separations(&p, 0.131, |i, j, d| met.push((i, j, d)));
        assert!((least - 0.1).abs() < 1e-12);
        assert_eq!(met.len(), 1);
        assert_eq!((met[0].0, met[0].1), (0, 3));
        let mut none = 0;
        assert!((separations(&p[..3], 0.131, |_, _, _| none += 1) - 3.0).abs() < 1e-12);
        assert_eq!(none, 0);
        assert_eq!(separations(&p[..1], 1.0, |_, _, _| unreachable!()), f64::INFINITY);
    }

    fn config(starts_m: Vec<[f64; 2]>) -> CrtpConfig {
        let mut settings = Settings::os4();
        settings.hub_m = 0.043;
        CrtpConfig {
            listen: "127.0.0.1:0".parse().unwrap(),
            starts_m,
            decks: 0,
            settings,
            vehicle: VehicleParams::os4(),
            position_source: PositionSource::Mocap,
            truth_to: None,
            duration_s: Some(0.01),
            seed: 1,
            imu_dead: None,
            fix_outage: None,
            fix_outlier_at_s: None,
            target: CrtpTarget::InProcess,
            stop: Arc::new(AtomicBool::new(false)),
            storage: None,
        }
    }

    #[test]
    fn a_swarm_is_refused_by_name_where_it_cannot_fly() {
        let err = |c: CrtpConfig| check(&c).unwrap_err().to_string();
        assert!(err(config(vec![])).contains("1 to 16"));
        assert!(err(config(grid_starts(17))).contains("1 to 16"));
        assert!(err(config(vec![[0.0, 0.0], [0.1, 0.0]])).contains("rotors reach 0.131 m"));
        assert!(err(config(vec![[0.0, 0.0], [f64::NAN, 0.0]])).contains("vehicle 1's start"));
        let mut c = config(grid_starts(2));
        c.storage = Some("x".into());
        assert!(err(c).contains("--storage"));
        let mut c = config(grid_starts(2));
        c.target = CrtpTarget::Qemu {
            syslink: String::new(),
            wait_s: 1.0,
            crazyflie: false,
        };
        assert!(err(c.clone()).contains("in process only"));
        c.starts_m = grid_starts(1);
        c.decks = 1 << 1;
        assert!(err(c).contains("--deck"));
        assert!(check(&config(grid_starts(16))).is_ok());
    }

    #[test]
    fn each_vehicle_of_a_swarm_has_its_own_port_and_starts_where_it_was_put() {
        let s = run(&config(vec![[0.0, 0.0], [2.0, -1.0], [-1.0, 3.0]])).unwrap();
        assert_eq!(s.vehicles.len(), 3);
        let ports: std::collections::BTreeSet<_> = s.vehicles.iter().map(|v| v.listen.port()).collect();
        assert_eq!(ports.len(), 3, "three sockets");
        assert_eq!(s.vehicles[1].final_position_m[..2], [2.0, -1.0]);
        assert_eq!(s.vehicles[2].final_position_m[..2], [-1.0, 3.0]);
        assert!((s.min_separation_m.unwrap() - 5f64.sqrt()).abs() < 1e-9);
        assert!(s.collisions.is_empty());
    }
}
