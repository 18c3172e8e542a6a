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
//! `--truth-to ADDR` sends the plant's true pose as one JSON datagram every
//! 10 ms: a motion-capture system's stream, for a client that forwards it
//! with `send_extpos`/`send_extpose` and for tests that compare the flight
//! with the truth. Its frame is the Crazyflie's (x forward, y left, z up).

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
    /// The UDP address to listen on.
    pub listen: SocketAddr,
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
    /// The image's log (QEMU).
    pub firmware_log: Vec<String>,
    /// `--storage`: what the store was at boot, and the stored values
    /// taken and refused.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub storage: Option<(String, u16, u16)>,
    /// The plant's final position, Crazyflie frame, m.
    pub final_position_m: [f64; 3],
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
    store: Option<fc_storage::Store<crate::storage::FileFlash>>,
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

/// Runs the server until `duration_s` (or forever).
pub fn run(cfg: &CrtpConfig) -> Result<CrtpSummary> {
    let socket = match cfg.target {
        CrtpTarget::InProcess => {
            let s = UdpSocket::bind(cfg.listen).with_context(|| format!("binding UDP {}", cfg.listen))?;
            s.set_nonblocking(true)?;
            eprintln!("crtp: listening on udp://{}", s.local_addr()?);
            Some(s)
        }
        CrtpTarget::Qemu { .. } => None,
    };
    let truth = match cfg.truth_to {
        Some(to) => {
            let s = UdpSocket::bind("127.0.0.1:0")?;
            Some((s, to))
        }
        None => None,
    };
    let mut stored = None;
    if cfg.storage.is_some() && !matches!(cfg.target, CrtpTarget::InProcess) {
        anyhow::bail!("--storage is for the in-process vehicle: the images in QEMU keep their own (a RAM stand-in)");
    }
    let mut fc = match (&cfg.target, &socket) {
        (
            CrtpTarget::Qemu {
                syslink,
                wait_s,
                crazyflie,
            },
            _,
        ) => {
            let boot = if *crazyflie {
                crate::link::Boot::Shim {
                    shim: crate::link::boot_shim_elf()?,
                    image: crate::link::firmware_crazyflie_elf()?,
                }
            } else {
                crate::link::Boot::Direct(crate::link::firmware_crtp_elf()?)
            };
            let mut qemu = crate::link::Qemu::start_with_syslink(&boot, syslink, *wait_s)?;
            eprintln!("crtp: the image's syslink (USART6) waits on tcp:{syslink} for tools/nrf51_bridge.py");
            let stream = qemu.connect()?;
            stream.set_read_timeout(Some(Duration::from_secs(10)))?;
            let mut link = SimLink {
                client: crate::link::FcClient::over(stream),
                seq: 0,
            };
            link.set_params(&cfg.settings)?;
            eprintln!("crtp: the image is up, the vehicle's parameters written");
            Fc::Image { qemu, link }
        }
        (CrtpTarget::InProcess, Some(socket)) => {
            let (mut settings, mut store) = (cfg.settings, None);
            if let Some(path) = &cfg.storage {
                let (mut st, boot) = crate::storage::open(path, "crtp")?;
                let l = fc_storage::load_settings(&mut st, settings)
                    .map_err(|e| anyhow::anyhow!("--storage {}: {e}", path.display()))?;
                eprintln!(
                    "crtp: storage: {} persistent parameter(s) taken, {} refused",
                    l.taken, l.refused.0
                );
                settings = l.settings;
                stored = Some((boot.to_string(), l.taken, l.refused.0));
                store = Some(st);
            }
            let mut vehicle = Box::new(
                CrtpVehicle::new(settings)
                    .map_err(|e| anyhow::anyhow!("the flight controller's settings are refused: {e}"))?,
            );
            // cflib's "default value": the command line's, not the stored.
            vehicle.set_defaults(cfg.settings);
            Fc::Local {
                vehicle,
                socket,
                out: Udp {
                    socket,
                    to: None,
                    sent: 0,
                    store,
                },
                clock: MonotonicClock::default(),
            }
        }
        (CrtpTarget::InProcess, None) => anyhow::bail!("no UDP socket"),
    };
    let pc = PlantConfig {
        params: cfg.vehicle,
        ..PlantConfig::nominal(AttitudeForm::Quaternion)
    };
    let mut plant = Plant::new(pc, &fc_core::hover_quat_state(&Vector3::zeros(), 0.0));
    plant.set_rotor_speeds(nalgebra::Vector4::zeros());
    plant.contact_ground(0.0);
    let mut sensor_cfg = SensorConfig::new(FixProfile::Mocap, cfg.seed);
    sensor_cfg.faults.imu_dead = cfg.imu_dead;
    let mut sensors = Sensors::new(sensor_cfg, IMU_PERIOD_S)?;
    let u1_max = 4.0 * cfg.vehicle.kf_ns2 * cfg.vehicle.omega_max_radps.powi(2);
    let start = Instant::now();
    let mut step: u64 = 0;
    let mut late: u64 = 0;
    let mut flown_s = 0.0;
    let mut buf = [0u8; 256];
    loop {
        let t = step as f64 * IMU_PERIOD_S;
        if cfg.duration_s.is_some_and(|d| t > d) || cfg.stop.load(Ordering::Relaxed) {
            break;
        }
        // Packets that arrived, answered at once.
        fc.serve(&mut buf)?;
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
        let mut readings = sensors.read(t, &plant);
        if cfg.position_source == PositionSource::External {
            readings.fixes.clear();
        }
        let t_us = (t * 1e6).round() as u64;
        let (u, flying) = fc.step(t_us, &readings, |u1| battery_v(flown_s, f64::from(u1) / u1_max))?;
        if flying {
            flown_s += IMU_PERIOD_S;
        }
        plant.step(&u.cast::<f64>(), IMU_PERIOD_S);
        plant.contact_ground(0.0);
        if let Some((s, to)) = &truth {
            if step.is_multiple_of(TRUTH_EVERY) {
                let x = plant.quat_state();
                let p = cf_of(&plant.position());
                let armed = fc.armed().map_or("null".to_string(), |a| a.to_string());
                // Body FRD → NED as body FLU → (x, y, z up): (w, x, −y, −z).
                let line = format!(
                    "{{\"t\":{t:.3},\"x\":{:.5},\"y\":{:.5},\"z\":{:.5},\"qx\":{:.6},\"qy\":{:.6},\"qz\":{:.6},\"qw\":{:.6},\"armed\":{armed},\"flying\":{flying}}}",
                    p[0], p[1], p[2], x[7], -x[8], -x[9], x[6]
                );
                let _ = s.send_to(line.as_bytes(), to);
            }
        }
        step += 1;
    }
    let final_position_m = cf_of(&plant.position());
    let duration_s = step as f64 * IMU_PERIOD_S;
    let realtime_factor = duration_s / start.elapsed().as_secs_f64().max(1e-9);
    Ok(match fc {
        Fc::Local { vehicle, out, .. } => CrtpSummary {
            duration_s,
            late_steps: late,
            realtime_factor,
            target: "in-process",
            packets: Some(vehicle.counters().into()),
            sent: Some(out.sent),
            imu: Some({
                let c = vehicle.imu_counters();
                [c.missing, c.bad, c.held, c.timeouts]
            }),
            firmware_log: Vec::new(),
            storage: stored,
            final_position_m,
        },
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
                firmware_log: qemu.finish()?,
                storage: None,
                final_position_m,
            }
        }
    })
}
