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
}

/// What a session did.
#[derive(Debug, Clone, Serialize)]
pub struct CrtpSummary {
    /// Simulated time flown, s.
    pub duration_s: f64,
    /// IMU steps that ran late by more than 5 ms of wall time (a slow host).
    pub late_steps: u64,
    /// Packets: handled, null, refused by kind.
    pub packets: Counters,
    /// Packets sent.
    pub sent: u64,
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

/// Runs the server until `duration_s` (or forever).
pub fn run(cfg: &CrtpConfig) -> Result<CrtpSummary> {
    let socket = UdpSocket::bind(cfg.listen).with_context(|| format!("binding UDP {}", cfg.listen))?;
    socket.set_nonblocking(true)?;
    eprintln!("crtp: listening on udp://{}", socket.local_addr()?);
    let truth = match cfg.truth_to {
        Some(to) => {
            let s = UdpSocket::bind("127.0.0.1:0")?;
            Some((s, to))
        }
        None => None,
    };
    let mut vehicle = CrtpVehicle::new(cfg.settings)
        .map_err(|e| anyhow::anyhow!("the flight controller's settings are refused: {e}"))?;
    let pc = PlantConfig {
        params: cfg.vehicle,
        ..PlantConfig::nominal(AttitudeForm::Quaternion)
    };
    let mut plant = Plant::new(pc, &fc_core::hover_quat_state(&Vector3::zeros(), 0.0));
    plant.set_rotor_speeds(nalgebra::Vector4::zeros());
    plant.contact_ground(0.0);
    let mut sensors = Sensors::new(SensorConfig::new(FixProfile::Mocap, cfg.seed), IMU_PERIOD_S)?;
    let clock = MonotonicClock::default();
    let mut out = Udp {
        socket: &socket,
        to: None,
        sent: 0,
    };
    let u1_max = 4.0 * cfg.vehicle.kf_ns2 * cfg.vehicle.omega_max_radps.powi(2);
    let start = Instant::now();
    let mut step: u64 = 0;
    let mut late: u64 = 0;
    let mut flown_s = 0.0;
    let mut buf = [0u8; 256];
    loop {
        let t = step as f64 * IMU_PERIOD_S;
        if cfg.duration_s.is_some_and(|d| t > d) {
            break;
        }
        // Packets that arrived, answered at once.
        loop {
            match socket.recv_from(&mut buf) {
                Ok((n, from)) => {
                    out.to = Some(from);
                    match Packet::from_bytes(&buf[..n]) {
                        Ok(p) => vehicle.handle(&p, &mut out)?,
                        Err(e) => vehicle.count_malformed(e),
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                // A previous client's port closed (ICMP): not this client's error.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => continue,
                Err(e) => return Err(e).context("receiving CRTP"),
            }
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
        let mut readings = sensors.read(t, &plant);
        if cfg.position_source == PositionSource::External {
            readings.fixes.clear();
        }
        let t_us = (t * 1e6).round() as u64;
        let u = vehicle.imu_step(t_us, &readings.imu, &readings.fixes, &clock);
        if vehicle.flying() {
            flown_s += IMU_PERIOD_S;
        }
        vehicle.set_battery(battery_v(flown_s, f64::from(u[0]) / u1_max), 0);
        plant.step(&u.cast::<f64>(), IMU_PERIOD_S);
        plant.contact_ground(0.0);
        vehicle.poll(&mut out)?;
        if let Some((s, to)) = &truth {
            if step.is_multiple_of(TRUTH_EVERY) {
                let x = plant.quat_state();
                let p = cf_of(&plant.position());
                // Body FRD → NED as body FLU → (x, y, z up): (w, x, −y, −z).
                let line = format!(
                    "{{\"t\":{t:.3},\"x\":{:.5},\"y\":{:.5},\"z\":{:.5},\"qx\":{:.6},\"qy\":{:.6},\"qz\":{:.6},\"qw\":{:.6},\"armed\":{},\"flying\":{}}}",
                    p[0], p[1], p[2], x[7], -x[8], -x[9], x[6], vehicle.armed(), vehicle.flying()
                );
                let _ = s.send_to(line.as_bytes(), to);
            }
        }
        step += 1;
    }
    Ok(CrtpSummary {
        duration_s: step as f64 * IMU_PERIOD_S,
        late_steps: late,
        packets: vehicle.counters().into(),
        sent: out.sent,
        final_position_m: cf_of(&plant.position()),
    })
}
