#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod hil;
pub mod mission;
pub mod modes;
pub mod signing;
/// The parameter table (it lives with the flight loop, which both protocols drive).
pub use fc_loop::params;
pub mod vehicle;

pub use mavlink::dialects::common::{self, MavMessage};
pub use mavlink::MavHeader;
use mavlink::{MAVLinkV2MessageRaw, Message};
use signing::{SignError, Signing, FLAG_SIGNED, SIGNATURE_LEN};

/// MAVLink 2's start byte.
const STX_V2: u8 = 0xFD;
/// Start byte, length, flags (2), sequence, system, component, id (3).
const HEADER_LEN: usize = 10;
/// The CRC after the payload.
const CRC_LEN: usize = 2;
/// Largest MAVLink 2 frame: header, 255 bytes of payload, CRC, 13 bytes of signature.
pub const MAX_FRAME: usize = HEADER_LEN + 255 + CRC_LEN + 13;

/// Who a message is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Peer {
    /// The simulator (HIL_ACTUATOR_CONTROLS).
    Simulator,
    /// The ground station (telemetry, acknowledgements, parameters).
    GroundStation,
}

/// Where [`MavVehicle`](vehicle::MavVehicle)'s messages go (one link for both peers on the
/// image; a TCP and a UDP socket on the host).
pub trait MavSink {
    /// What sending can fail with.
    type Error;
    /// Sends `msg` to `to`.
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<(), Self::Error>;
    /// The ground station link's signing state, if this link signs (a
    /// `SETUP_SIGNING` changes it; `None`: the request is ignored).
    fn signing(&mut self) -> Option<&mut signing::Signing> {
        None
    }
    /// Where settings persist across a reboot, if anywhere: a parameter a
    /// ground station sets is stored there at once (as PX4 saves its
    /// parameters), and a signing key when `SETUP_SIGNING` sets it.
    /// `None`: they live until power-off.
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        None
    }
}

/// Why a frame was not delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MavError {
    /// The checksum (with the message's CRC extra byte) did not match.
    BadCrc,
    /// A message id the common dialect does not have.
    UnknownMessage(u32),
    /// A frame this reader does not accept: with 32-bit system ids or an
    /// unknown incompatibility flag (its flags, given).
    Unsupported(u8),
    /// Dropped by the signing check (unsigned, badly signed or replayed
    /// while a key is set).
    Signing(SignError),
    /// The payload did not decode as its message.
    Malformed(u32),
    /// A message addressed to another system (its target, given).
    OtherSystem(u8),
    /// A message of the dialect that this crate does not read or write
    /// (not in [`SUBSET`]; its id, given).
    Unused(u32),
    /// The output buffer is smaller than the frame.
    BufferTooSmall,
    /// Not sent: booted on a stored signing key, the vehicle signs nothing
    /// until it has accepted a frame signed with it ([`Signing::may_sign`]);
    /// only its `HEARTBEAT` goes out meanwhile, unsigned.
    Unclocked,
}

impl core::fmt::Display for MavError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MavError::BadCrc => write!(f, "MAVLink frame with a bad checksum"),
            MavError::UnknownMessage(id) => write!(f, "MAVLink message id {id} is not in the common dialect"),
            MavError::Unsupported(flags) => {
                write!(
                    f,
                    "MAVLink frame with incompatibility flags {flags:#04x} (32-bit ids or unknown) is not supported"
                )
            }
            MavError::Signing(e) => write!(f, "{e}"),
            MavError::Malformed(id) => write!(f, "MAVLink message {id} did not decode"),
            MavError::OtherSystem(t) => write!(f, "MAVLink message addressed to system {t}, not this one"),
            MavError::Unused(id) => write!(f, "MAVLink message {id} is not one this flight controller uses"),
            MavError::BufferTooSmall => write!(f, "the buffer is smaller than the MAVLink frame"),
            MavError::Unclocked => write!(
                f,
                "not sent: signing waits for a frame signed with the stored key (its timestamp may be behind)"
            ),
        }
    }
}

/// What the reader delivered and refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MavCounters {
    /// Messages delivered.
    pub ok: u32,
    /// Frames with a bad checksum.
    pub bad_crc: u32,
    /// Frames of message ids the dialect does not have.
    pub unknown: u32,
    /// Frames with 32-bit system ids or unknown incompatibility flags.
    pub unsupported: u32,
    /// Frames the signing check dropped (its own counters tell why).
    pub signing: u32,
    /// Payloads that did not decode.
    pub malformed: u32,
    /// Messages for other systems.
    pub other_system: u32,
    /// Well-formed messages of the dialect this crate does not use.
    pub unused: u32,
    /// Bytes outside any frame (noise before a start byte).
    pub skipped_bytes: u32,
}

impl MavCounters {
    /// Frames refused, of every kind (bad CRC, unknown, unsupported,
    /// signing, malformed, other systems); unused messages and noise are
    /// not refusals.
    pub fn refused(&self) -> u32 {
        self.bad_crc + self.unknown + self.unsupported + self.signing + self.malformed + self.other_system
    }
}

/// MAVLink 2 frames from a byte stream, one byte at a time, in a fixed
/// buffer: a frame is read to its length and then checked, decoded and
/// delivered or refused (counted); a refused frame is dropped whole and the
/// next start byte begins the next (as the reference C parser resumes).
#[derive(Clone)]
pub struct MavReader {
    raw: MAVLinkV2MessageRaw,
    len: usize,
    need: usize,
    system_id: u8,
    counters: MavCounters,
}

impl core::fmt::Debug for MavReader {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("MavReader")
            .field("len", &self.len)
            .field("system_id", &self.system_id)
            .field("counters", &self.counters)
            .finish()
    }
}

impl MavReader {
    /// A reader for system `system_id`: messages addressed to another
    /// system (target system not 0 and not this) are refused.
    pub const fn new(system_id: u8) -> Self {
        Self {
            raw: MAVLinkV2MessageRaw::new(),
            len: 0,
            need: 0,
            system_id,
            counters: MavCounters {
                ok: 0,
                bad_crc: 0,
                unknown: 0,
                unsupported: 0,
                signing: 0,
                malformed: 0,
                other_system: 0,
                unused: 0,
                skipped_bytes: 0,
            },
        }
    }

    /// The bytes of the frame the last `Some` completed (signature included),
    /// to forward it whole; valid until the next byte is pushed.
    pub fn frame(&self) -> &[u8] {
        self.raw.raw_bytes()
    }

    /// What was delivered and refused so far.
    pub fn counters(&self) -> MavCounters {
        self.counters
    }

    /// Feeds one byte: `Some` when it completes a frame, with the message
    /// or the reason it was refused (also counted). Signed frames are read
    /// and delivered unchecked: this is a reader without a key (see
    /// [`MavReader::push_signed`]).
    pub fn push(&mut self, byte: u8) -> Option<Result<(MavHeader, MavMessage), MavError>> {
        self.push_checked(byte, None)
    }

    /// [`MavReader::push`] with the signing check of `signing`: with a key
    /// set, a frame unsigned (but for [`signing::UNSIGNED_ALLOWED`]),
    /// signed with another key or replayed is refused
    /// ([`MavError::Signing`]); [`Signing::last_authenticated`] tells
    /// whether the frame delivered was signed with the key.
    pub fn push_signed(
        &mut self,
        byte: u8,
        signing: &mut Signing,
    ) -> Option<Result<(MavHeader, MavMessage), MavError>> {
        self.push_checked(byte, Some(signing))
    }

    fn push_checked(
        &mut self,
        byte: u8,
        signing: Option<&mut Signing>,
    ) -> Option<Result<(MavHeader, MavMessage), MavError>> {
        if self.len == 0 && byte != STX_V2 {
            self.counters.skipped_bytes = self.counters.skipped_bytes.wrapping_add(1);
            return None;
        }
        self.raw.as_mut_slice()[self.len] = byte;
        self.len += 1;
        if self.len == 3 {
            let flags = self.raw.as_slice()[2];
            if flags & !FLAG_SIGNED != 0 {
                self.len = 0;
                return Some(Err(self.count(MavError::Unsupported(flags))));
            }
            let signature = if flags & FLAG_SIGNED != 0 { SIGNATURE_LEN } else { 0 };
            self.need = HEADER_LEN + usize::from(self.raw.as_slice()[1]) + CRC_LEN + signature;
        }
        if self.len < 3 || self.len < self.need {
            return None;
        }
        self.len = 0;
        Some(self.decode(signing).map_err(|e| self.count(e)))
    }

    fn count(&mut self, e: MavError) -> MavError {
        let c = &mut self.counters;
        let n = match e {
            MavError::BadCrc => &mut c.bad_crc,
            MavError::UnknownMessage(_) => &mut c.unknown,
            MavError::Unsupported(_) => &mut c.unsupported,
            MavError::Signing(_) => &mut c.signing,
            MavError::Malformed(_) => &mut c.malformed,
            MavError::OtherSystem(_) => &mut c.other_system,
            MavError::Unused(_) => &mut c.unused,
            MavError::BufferTooSmall | MavError::Unclocked => return e,
        };
        *n = n.wrapping_add(1);
        e
    }

    /// The complete frame in `raw`, checked and decoded.
    fn decode(&mut self, signing: Option<&mut Signing>) -> Result<(MavHeader, MavMessage), MavError> {
        let raw = &self.raw;
        let id = raw.message_id();
        let extra = <MavMessage as Message>::extra_crc(id);
        // Every id of the dialect has its CRC extra byte; unknown ids get 0
        // (as does COMPONENT_INFORMATION, 395, which no one here uses).
        if extra == 0 && id != 395 {
            return Err(MavError::UnknownMessage(id));
        }
        if !raw.has_valid_crc_with_extra_crc(extra) {
            return Err(MavError::BadCrc);
        }
        if let Some(s) = signing {
            s.check(raw.raw_bytes(), id).map_err(MavError::Signing)?;
        }
        let msg = match parse_subset(id, raw.payload()) {
            Some(Ok(m)) => m,
            Some(Err(())) => return Err(MavError::Malformed(id)),
            None => return Err(MavError::Unused(id)),
        };
        if let Some(t) = msg.target_system_id() {
            if t != 0 && t != self.system_id {
                return Err(MavError::OtherSystem(t));
            }
        }
        self.counters.ok = self.counters.ok.wrapping_add(1);
        let header = MavHeader {
            system_id: raw.system_id(),
            component_id: raw.component_id(),
            sequence: raw.sequence(),
        };
        Ok((header, msg))
    }
}

/// The messages this crate reads and writes, each with its payload type.
/// Only these are parsed and serialised: the `mavlink` crate's whole-dialect
/// `parse` and `ser` would link the code of all ≈ 230 messages (≈ 300 KiB
/// of flash on the F405) for the dozen a flight controller uses. A frame of
/// another dialect message is well-formed but unused ([`MavError::Unused`]).
macro_rules! subset {
    ($($name:ident: $data:ident),+ $(,)?) => {
        /// The ids of the messages this crate reads and writes (see `encode` and `MavReader`).
        // Deprecated messages are in it because ground stations still send them.
        #[allow(deprecated)]
        pub const SUBSET: &[u32] = &[$(<common::$data as mavlink::MessageData>::ID),+];

        #[allow(deprecated)]
        fn parse_subset(id: u32, payload: &[u8]) -> Option<Result<MavMessage, ()>> {
            use mavlink::MessageData;
            match id {
                $(common::$data::ID => Some(
                    common::$data::deser(mavlink::MavlinkVersion::V2, payload)
                        .map(MavMessage::$name)
                        .map_err(|_| ()),
                ),)+
                _ => None,
            }
        }

        #[allow(deprecated)]
        fn serialize_subset(raw: &mut MAVLinkV2MessageRaw, header: MavHeader, msg: &MavMessage) -> Result<(), MavError> {
            match msg {
                $(MavMessage::$name(d) => raw.serialize_message_data(header, d),)+
                other => return Err(MavError::Unused(other.message_id())),
            }
            Ok(())
        }
    };
}

subset! {
    HEARTBEAT: HEARTBEAT_DATA,
    SYS_STATUS: SYS_STATUS_DATA,
    PARAM_REQUEST_READ: PARAM_REQUEST_READ_DATA,
    PARAM_REQUEST_LIST: PARAM_REQUEST_LIST_DATA,
    PARAM_VALUE: PARAM_VALUE_DATA,
    PARAM_SET: PARAM_SET_DATA,
    ATTITUDE: ATTITUDE_DATA,
    LOCAL_POSITION_NED: LOCAL_POSITION_NED_DATA,
    SET_POSITION_TARGET_LOCAL_NED: SET_POSITION_TARGET_LOCAL_NED_DATA,
    COMMAND_LONG: COMMAND_LONG_DATA,
    COMMAND_ACK: COMMAND_ACK_DATA,
    STATUSTEXT: STATUSTEXT_DATA,
    HIL_SENSOR: HIL_SENSOR_DATA,
    HIL_STATE_QUATERNION: HIL_STATE_QUATERNION_DATA,
    HIL_ACTUATOR_CONTROLS: HIL_ACTUATOR_CONTROLS_DATA,
    COMMAND_INT: COMMAND_INT_DATA,
    AUTOPILOT_VERSION: AUTOPILOT_VERSION_DATA,
    GLOBAL_POSITION_INT: GLOBAL_POSITION_INT_DATA,
    ATTITUDE_QUATERNION: ATTITUDE_QUATERNION_DATA,
    HOME_POSITION: HOME_POSITION_DATA,
    EXTENDED_SYS_STATE: EXTENDED_SYS_STATE_DATA,
    BATTERY_STATUS: BATTERY_STATUS_DATA,
    MISSION_COUNT: MISSION_COUNT_DATA,
    MISSION_REQUEST_INT: MISSION_REQUEST_INT_DATA,
    MISSION_REQUEST: MISSION_REQUEST_DATA,
    MISSION_ITEM_INT: MISSION_ITEM_INT_DATA,
    MISSION_ACK: MISSION_ACK_DATA,
    MISSION_CURRENT: MISSION_CURRENT_DATA,
    MISSION_ITEM_REACHED: MISSION_ITEM_REACHED_DATA,
    MISSION_REQUEST_LIST: MISSION_REQUEST_LIST_DATA,
    MISSION_CLEAR_ALL: MISSION_CLEAR_ALL_DATA,
    MISSION_SET_CURRENT: MISSION_SET_CURRENT_DATA,
    MANUAL_CONTROL: MANUAL_CONTROL_DATA,
    ESTIMATOR_STATUS: ESTIMATOR_STATUS_DATA,
    SETUP_SIGNING: SETUP_SIGNING_DATA,
    SET_MODE: SET_MODE_DATA,
}

/// Writes `msg` as one MAVLink 2 frame (unsigned) into `out`; returns its
/// length. `Err` if `out` is too small, the message is not one of
/// [`SUBSET`], or the header's system id does not fit a byte (32-bit ids
/// are not supported).
pub fn encode(header: MavHeader, msg: &MavMessage, out: &mut [u8]) -> Result<usize, MavError> {
    if header.system_id > u32::from(u8::MAX) {
        return Err(MavError::Unsupported(0x02));
    }
    let mut raw = MAVLinkV2MessageRaw::new();
    serialize_subset(&mut raw, header, msg)?;
    let bytes = raw.raw_bytes();
    out.get_mut(..bytes.len())
        .ok_or(MavError::BufferTooSmall)?
        .copy_from_slice(bytes);
    Ok(bytes.len())
}

/// [`encode`], then signed by `signing` when it has a key
/// ([`Signing::sign`]); `out` needs [`MAX_FRAME`] bytes for any message.
/// While `signing` may not sign yet, a `HEARTBEAT` goes unsigned and
/// anything else is [`MavError::Unclocked`].
pub fn encode_signed(
    header: MavHeader,
    msg: &MavMessage,
    out: &mut [u8],
    signing: &mut Signing,
) -> Result<usize, MavError> {
    // Until it may sign, only its HEARTBEAT goes, unsigned (it carries no
    // timestamp), so that a ground station listening on UDP learns where
    // the vehicle is; nothing else is encoded.
    let held = !signing.may_sign();
    if held && !matches!(msg, MavMessage::HEARTBEAT(_)) {
        return Err(MavError::Unclocked);
    }
    let n = encode(header, msg, out)?;
    if held {
        return Ok(n);
    }
    let extra = <MavMessage as Message>::extra_crc(msg.message_id());
    signing.sign(out, n, extra).ok_or(MavError::BufferTooSmall)
}

/// The message id of `msg` (for logs and counters).
pub fn message_id(msg: &MavMessage) -> u32 {
    msg.message_id()
}

#[cfg(test)]
mod tests;
