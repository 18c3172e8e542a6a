//! The vehicles the HIL session flies: the flight controller in this
//! process ([`InProcess`]) or the `firmware-mavlink` image in QEMU
//! ([`InQemu`]); the simulator's true state from `ODOMETRY`.

use super::{
    bail, common, encode, route, status_text, Duration, Instant, MavHeader, MavMessage, MavReader, MavSink, MavVehicle,
    Peer, Result, Settings, Signing, SocketAddr, StateEstimate, TcpStream, UdpSocket, Vector3, Vehicle, COMPONENT_ID,
    MAX_FRAME, MISSION_GCS_ID, SYSTEM_ID,
};
use anyhow::Context;
use std::io::Read;
use std::io::Write;

/// [`MavVehicle`] in this process.
pub(super) struct InProcess {
    pub(super) v: MavVehicle,
    pub(super) clock: hal_shim::host::MonotonicClock,
    pub(super) wall: Instant,
    pub(super) store: Option<crate::storage::FileStore>,
}

pub(super) struct Collect<'a>(
    &'a mut Vec<MavMessage>,
    Option<&'a mut Signing>,
    Option<&'a mut dyn fc_storage::Persist>,
);

impl MavSink for Collect<'_> {
    type Error = std::convert::Infallible;
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<(), Self::Error> {
        // The heartbeat goes to both peers; one copy is enough here (routed by type).
        if !(to == Peer::GroundStation && matches!(msg, MavMessage::HEARTBEAT(_))) {
            self.0.push(msg.clone());
        }
        Ok(())
    }
    fn signing(&mut self) -> Option<&mut Signing> {
        self.1.as_deref_mut()
    }
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        match &mut self.2 {
            Some(s) => Some(&mut **s),
            None => None,
        }
    }
}

impl InProcess {
    /// The vehicle handles `msg`; its link signs with `signing`, if given.
    pub(super) fn handle(
        &mut self,
        msg: &MavMessage,
        out: &mut Vec<MavMessage>,
        signing: Option<&mut Signing>,
    ) -> Result<()> {
        let now_us = self.wall.elapsed().as_micros() as u64;
        let store = self.store.as_mut().map(|s| s as &mut dyn fc_storage::Persist);
        let Ok(()) = self
            .v
            .handle(msg, &mut Collect(out, signing, store), &self.clock, now_us);
        Ok(())
    }
}

impl Vehicle for InProcess {
    fn deliver(&mut self, msg: &MavMessage, out: &mut Vec<MavMessage>) -> Result<()> {
        self.handle(msg, out, None)
    }
    fn deliver_from_gcs(
        &mut self,
        msg: &MavMessage,
        _frame: &[u8],
        out: &mut Vec<MavMessage>,
        signing: &mut Signing,
    ) -> Result<()> {
        self.handle(msg, out, Some(signing))
    }
    fn refused(&self) -> u32 {
        0
    }
    fn fly_trajectory(&mut self, flown: &super::trajectory::Flown, start_us: u64) -> Result<()> {
        self.v
            .fly_trajectory(
                flown.memory,
                super::trajectory::TRAJECTORY_ID,
                super::trajectory::START,
                start_us,
            )
            .map_err(|e| anyhow::anyhow!("the vehicle refused the trajectory: {e}"))
    }
    fn keep_signing(&mut self, signing: &Signing) -> Result<(), fc_storage::StoreError> {
        match (&mut self.store, signing.key()) {
            (Some(st), Some(key)) => st.set_signing(key, signing.timestamp()),
            _ => Ok(()),
        }
    }
    fn fly_truth(&mut self, truth: StateEstimate<f32>) -> Result<()> {
        self.v.fly_truth(truth);
        Ok(())
    }
    fn finish(self: Box<Self>) -> Result<Vec<String>> {
        Ok(Vec::new())
    }
}

/// The simulator's true state from its `ODOMETRY` (id 331; `frame`: the
/// whole MAVLink 2 frame): position in `MAV_FRAME_LOCAL_NED` about home,
/// m; attitude body FRD → NED; velocity and rates in `MAV_FRAME_BODY_FRD`,
/// m/s and rad/s (the velocity turned to NED here). `Err` names a frame
/// of reference it does not take, or a value that is not finite.
pub fn truth_from_odometry(frame: &[u8]) -> Result<StateEstimate<f32>> {
    use mavlink::MessageData;
    let len = usize::from(*frame.get(1).context("an ODOMETRY frame shorter than its header")?);
    let payload = frame
        .get(10..10 + len)
        .context("an ODOMETRY frame shorter than its length")?;
    let m = common::ODOMETRY_DATA::deser(mavlink::MavlinkVersion::V2, payload)
        .map_err(|e| anyhow::anyhow!("ODOMETRY unreadable: {e:?}"))?;
    if m.frame_id != common::MavFrame::MAV_FRAME_LOCAL_NED || m.child_frame_id != common::MavFrame::MAV_FRAME_BODY_FRD {
        bail!(
            "ODOMETRY in {:?} / {:?}: the true state is taken in MAV_FRAME_LOCAL_NED / MAV_FRAME_BODY_FRD",
            m.frame_id,
            m.child_frame_id
        );
    }
    let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(m.q[0], m.q[1], m.q[2], m.q[3]));
    let all = [m.x, m.y, m.z, m.vx, m.vy, m.vz, m.rollspeed, m.pitchspeed, m.yawspeed];
    if !all.iter().chain(m.q.iter()).all(|v| v.is_finite()) {
        bail!("ODOMETRY with a value that is not finite");
    }
    let vel_ned = q * Vector3::new(m.vx, m.vy, m.vz);
    Ok(StateEstimate {
        pos_ned_m: Vector3::new(m.x, m.y, m.z),
        vel_ned_mps: vel_ned,
        att: nalgebra::Vector4::new(q.w, q.i, q.j, q.k),
        rates_frd_radps: Vector3::new(m.rollspeed, m.pitchspeed, m.yawspeed),
    })
}

/// The `firmware-mavlink` image in QEMU.
pub(super) struct InQemu {
    pub(super) qemu: crate::link::Qemu,
    pub(super) usart: TcpStream,
    pub(super) reader: MavReader,
    pub(super) seq: u8,
    pub(super) buf: Vec<u8>,
    /// The ground station's socket and address: the image's frames for it
    /// go there as the image wrote them.
    pub(super) gcs: Option<(UdpSocket, SocketAddr)>,
}

impl InQemu {
    pub(super) fn start(elf: &std::path::Path) -> Result<Self> {
        let mut qemu = crate::link::Qemu::start(elf)?;
        let usart = qemu.connect()?;
        Ok(Self {
            qemu,
            usart,
            reader: MavReader::new(MISSION_GCS_ID),
            seq: 0,
            buf: vec![0u8; 4096],
            gcs: None,
        })
    }

    /// Reads what the image sends: up to its motor commands if `lockstep`
    /// (a sample was sent), else what has arrived, without waiting.
    pub(super) fn answer(&mut self, lockstep: bool, out: &mut Vec<MavMessage>) -> Result<()> {
        self.usart.set_nonblocking(!lockstep)?;
        let mut waiting = true;
        while waiting {
            let n = match self.usart.read(&mut self.buf) {
                Ok(0) => bail!("the image closed its USART1"),
                Ok(n) => n,
                Err(e) if !lockstep && e.kind() == std::io::ErrorKind::WouldBlock => break,
                Err(e) => return Err(e).context("reading the image's USART1"),
            };
            waiting = lockstep;
            for &b in &self.buf[..n] {
                if let Some(Ok((_, m))) = self.reader.push(b) {
                    waiting &= !matches!(m, MavMessage::HIL_ACTUATOR_CONTROLS(_));
                    if let (Some((sock, addr)), (_, true)) = (&self.gcs, route(&m)) {
                        // A ground station that has gone away is not an error of the flight.
                        let _ = sock.send_to(self.reader.frame(), addr);
                    }
                    out.push(m);
                }
            }
        }
        Ok(())
    }
}

impl Vehicle for InQemu {
    fn deliver(&mut self, msg: &MavMessage, out: &mut Vec<MavMessage>) -> Result<()> {
        let header = MavHeader {
            system_id: u32::from(MISSION_GCS_ID),
            component_id: 190,
            sequence: self.seq,
        };
        self.seq = self.seq.wrapping_add(1);
        let mut frame = [0u8; MAX_FRAME];
        let n = encode(header, msg, &mut frame).map_err(|e| anyhow::anyhow!("{e}"))?;
        self.usart
            .write_all(&frame[..n])
            .context("writing to the image's USART1")?;
        // In lockstep a sample is answered by its motor commands: read up
        // to them (whatever else the image sent comes first). After any
        // other message, take what has arrived without waiting.
        self.answer(matches!(msg, MavMessage::HIL_SENSOR(_)), out)
    }
    fn deliver_from_gcs(
        &mut self,
        _msg: &MavMessage,
        frame: &[u8],
        out: &mut Vec<MavMessage>,
        _signing: &mut Signing,
    ) -> Result<()> {
        // Forwarded whole: the image checks its signature.
        self.usart.write_all(frame).context("writing to the image's USART1")?;
        self.answer(false, out)
    }
    fn relays_gcs(&self) -> bool {
        self.gcs.is_some()
    }
    fn refused(&self) -> u32 {
        self.reader.counters().refused()
    }
    fn finish(self: Box<Self>) -> Result<Vec<String>> {
        drop(self.usart);
        self.qemu.finish()
    }
}

/// Writes the parameters of `s` that differ from the vehicle's boot values
/// and checks each echo; refusals are errors with the vehicle's reason.
pub(super) fn write_parameters(v: &mut dyn Vehicle, s: &Settings) -> Result<()> {
    for (_, p, value) in fc_mavlink::params::differences(s, &Settings::os4()) {
        let set = MavMessage::PARAM_SET(common::PARAM_SET_DATA {
            param_value: value,
            target_system: SYSTEM_ID,
            target_component: COMPONENT_ID,
            param_id: p.id.into(),
            param_type: common::MavParamType::MAV_PARAM_TYPE_REAL32,
        });
        let mut out = Vec::new();
        v.deliver(&set, &mut out)?;
        // The echo may still be on its way over a link: ask again until it is here.
        let echo = |out: &[MavMessage]| {
            out.iter().find_map(|m| match m {
                MavMessage::PARAM_VALUE(e) if e.param_id.to_str().is_ok_and(|id| id.trim_end_matches('\0') == p.id) => {
                    Some(e.param_value)
                }
                _ => None,
            })
        };
        let t0 = Instant::now();
        while echo(&out).is_none() && t0.elapsed() < Duration::from_secs(10) {
            let read = MavMessage::PARAM_REQUEST_READ(common::PARAM_REQUEST_READ_DATA {
                param_index: -1,
                target_system: SYSTEM_ID,
                target_component: COMPONENT_ID,
                param_id: p.id.into(),
            });
            std::thread::sleep(Duration::from_millis(20));
            v.deliver(&read, &mut out)?;
        }
        let texts: Vec<String> = out.iter().filter_map(status_text).collect();
        match echo(&out) {
            Some(e) if e == value => {}
            Some(e) => bail!(
                "the vehicle refused {} = {value} (kept {e}): {}",
                p.id,
                texts.join("; ")
            ),
            None => bail!("no answer to PARAM_SET {}", p.id),
        }
    }
    Ok(())
}
