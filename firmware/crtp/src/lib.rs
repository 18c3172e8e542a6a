#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod frames;
pub mod log;
pub mod persist;
/// The high-level commander's planner (it lives with the flight loop, which both protocols drive).
pub use fc_loop::planner;
pub mod syslink;
pub mod toc;
pub mod value;
pub mod vehicle;

/// Largest CRTP payload, bytes (`CRTP_MAX_DATA_SIZE`).
pub const MAX_PAYLOAD: usize = 30;
/// Largest CRTP packet on a byte link: header and payload.
pub const MAX_PACKET: usize = MAX_PAYLOAD + 1;
/// The protocol version this firmware reports (platform port, version
/// channel): 12 is the Crazyflie firmware's, from which cflib uses the
/// supervisor port, the V2 TOCs (≥ 4) and `GO_TO_2` (≥ 8).
pub const PROTOCOL_VERSION: i32 = 12;

/// Where [`CrtpVehicle`](vehicle::CrtpVehicle)'s packets go (a UDP socket on the host, syslink
/// on a board).
pub trait CrtpSink {
    /// What sending can fail with.
    type Error;
    /// Sends `p`.
    fn send(&mut self, p: &Packet) -> Result<(), Self::Error>;
    /// Where persistent parameters are kept, if anywhere (cflib's
    /// `param.persistent_store`, answered by [`PersistRequest::answer`](persist::PersistRequest::answer));
    /// `None`: nothing persists, and a request to store is answered with
    /// an error.
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        None
    }
}

/// The CRTP ports, as `cflib.crtp.crtpstack.CRTPPort` numbers them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Port {
    /// Text from the firmware.
    Console = 0x0,
    /// Parameters.
    Param = 0x2,
    /// Legacy roll, pitch, yaw-rate and thrust set-points.
    Commander = 0x3,
    /// Memories.
    Mem = 0x4,
    /// Log blocks.
    Log = 0x5,
    /// External position and pose, emergency stop.
    Localization = 0x6,
    /// Generic set-points.
    Generic = 0x7,
    /// The high-level commander.
    HighLevel = 0x8,
    /// Arming and the supervisor's state.
    Supervisor = 0x9,
    /// Protocol version, platform commands.
    Platform = 0xD,
    /// Link service: echo, source, sink; null packets.
    Link = 0xF,
}

impl Port {
    /// The port numbered `n` (the header's high nibble), if it is one.
    pub fn from_number(n: u8) -> Option<Self> {
        Some(match n {
            0x0 => Port::Console,
            0x2 => Port::Param,
            0x3 => Port::Commander,
            0x4 => Port::Mem,
            0x5 => Port::Log,
            0x6 => Port::Localization,
            0x7 => Port::Generic,
            0x8 => Port::HighLevel,
            0x9 => Port::Supervisor,
            0xD => Port::Platform,
            0xF => Port::Link,
            _ => return None,
        })
    }
}

/// Why a packet was not acted on. Every refusal is counted
/// ([`CrtpCounters`]); those a client waits for are also answered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrtpError {
    /// No header byte.
    Empty,
    /// More than [`MAX_PAYLOAD`] bytes of payload (the length given).
    TooLong(usize),
    /// A port this firmware does not serve (its number).
    NoSuchPort(u8),
    /// A channel or command of a port that this firmware does not
    /// implement.
    Unsupported {
        /// The port.
        port: u8,
        /// The channel.
        channel: u8,
        /// The command byte (0 where the payload is empty).
        command: u8,
    },
    /// A payload shorter than its command needs.
    Short {
        /// The port.
        port: u8,
        /// The channel.
        channel: u8,
        /// Bytes given.
        len: usize,
    },
    /// A set-point, pose or trajectory with NaN or ∞, or out of range.
    BadValue {
        /// The port.
        port: u8,
    },
    /// A command refused in the vehicle's state (not armed, estimator not
    /// ready); the console says which.
    Refused {
        /// The port.
        port: u8,
    },
}

impl core::fmt::Display for CrtpError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            CrtpError::Empty => write!(f, "CRTP packet without a header byte"),
            CrtpError::TooLong(n) => write!(f, "CRTP payload of {n} bytes: at most {MAX_PAYLOAD}"),
            CrtpError::NoSuchPort(p) => write!(f, "CRTP port {p} is not served"),
            CrtpError::Unsupported { port, channel, command } => {
                write!(
                    f,
                    "CRTP port {port} channel {channel}: command {command} is not supported"
                )
            }
            CrtpError::Short { port, channel, len } => {
                write!(
                    f,
                    "CRTP port {port} channel {channel}: {len} bytes are too few for the command"
                )
            }
            CrtpError::BadValue { port } => write!(f, "CRTP port {port}: a value is not finite or out of range"),
            CrtpError::Refused { port } => write!(f, "CRTP port {port}: refused in this state"),
        }
    }
}

/// One CRTP packet: the header byte and up to 30 bytes of payload.
///
/// Aligned to a word (its 32 bytes are a multiple of one, so it is no
/// larger): a copy, of which the link's handling of a packet under its
/// lock of the vehicle makes several, is eight word moves, not 32 byte
/// moves.
#[derive(Clone, Copy, PartialEq, Eq)]
#[repr(align(4))]
pub struct Packet {
    header: u8,
    len: u8,
    data: [u8; MAX_PAYLOAD],
}

impl core::fmt::Debug for Packet {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "Packet({}:{} {:02x?})", self.port(), self.channel(), self.payload())
    }
}

impl Packet {
    /// The null packet (`0xFF`, no payload): what a link sends when it has
    /// nothing, and what cflib's UDP scan probes with.
    pub const NULL: Packet = Packet {
        header: 0xFF,
        len: 0,
        data: [0; MAX_PAYLOAD],
    };

    /// A packet to `port`, `channel` (0–3) with `payload`; `Err` if the
    /// payload is longer than [`MAX_PAYLOAD`].
    pub fn new(port: Port, channel: u8, payload: &[u8]) -> Result<Self, CrtpError> {
        let mut p = Packet {
            header: ((port as u8) << 4) | (channel & 0x3),
            len: 0,
            data: [0; MAX_PAYLOAD],
        };
        p.extend(payload)?;
        Ok(p)
    }

    /// The packet in `raw` (header byte, then payload), as one UDP datagram
    /// of cflib's `udp://` driver carries it.
    pub fn from_bytes(raw: &[u8]) -> Result<Self, CrtpError> {
        let (&header, payload) = raw.split_first().ok_or(CrtpError::Empty)?;
        if payload.len() > MAX_PAYLOAD {
            return Err(CrtpError::TooLong(payload.len()));
        }
        let mut p = Packet {
            header,
            len: payload.len() as u8,
            data: [0; MAX_PAYLOAD],
        };
        p.data[..payload.len()].copy_from_slice(payload);
        Ok(p)
    }

    /// Writes the header and payload into `out`; returns the length.
    pub fn write_to(&self, out: &mut [u8; MAX_PACKET]) -> usize {
        out[0] = self.header;
        out[1..=self.payload().len()].copy_from_slice(self.payload());
        1 + self.payload().len()
    }

    /// The header byte.
    pub fn header(&self) -> u8 {
        self.header
    }

    /// The port number (the header's high nibble).
    pub fn port(&self) -> u8 {
        self.header >> 4
    }

    /// The channel (the header's two low bits; bits 2–3 are ignored, as
    /// the firmware ignores them).
    pub fn channel(&self) -> u8 {
        self.header & 0x3
    }

    /// A null packet (port 15, channel 3: what the radio sends when idle).
    pub fn is_null(&self) -> bool {
        self.header & 0xF3 == 0xF3
    }

    /// The payload.
    pub fn payload(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// Appends `bytes`; `Err` (nothing appended) if they do not fit.
    pub fn extend(&mut self, bytes: &[u8]) -> Result<(), CrtpError> {
        let at = usize::from(self.len);
        let end = at + bytes.len();
        if end > MAX_PAYLOAD {
            return Err(CrtpError::TooLong(end));
        }
        self.data[at..end].copy_from_slice(bytes);
        self.len = end as u8;
        Ok(())
    }

    /// Room left for payload, bytes.
    pub fn room(&self) -> usize {
        MAX_PAYLOAD - usize::from(self.len)
    }
}

/// What the vehicle did with the packets it got.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CrtpCounters {
    /// Packets handled (answered or acted on).
    pub handled: u32,
    /// Null packets (answered with a null packet).
    pub null: u32,
    /// Packets of ports this firmware does not serve.
    pub no_such_port: u32,
    /// Unsupported channels or commands.
    pub unsupported: u32,
    /// Payloads too short for their command.
    pub short: u32,
    /// Set-points, poses or trajectories with bad values.
    pub bad_value: u32,
    /// Commands refused in the vehicle's state.
    pub refused: u32,
    /// Datagrams that were not CRTP packets (empty, too long); counted by
    /// the transport with [`CrtpCounters::count`].
    pub malformed: u32,
}

impl CrtpCounters {
    /// Counts `e` in its kind.
    pub fn count(&mut self, e: CrtpError) {
        let n = match e {
            CrtpError::Empty | CrtpError::TooLong(_) => &mut self.malformed,
            CrtpError::NoSuchPort(_) => &mut self.no_such_port,
            CrtpError::Unsupported { .. } => &mut self.unsupported,
            CrtpError::Short { .. } => &mut self.short,
            CrtpError::BadValue { .. } => &mut self.bad_value,
            CrtpError::Refused { .. } => &mut self.refused,
        };
        *n = n.wrapping_add(1);
    }

    /// Every packet seen: handled, null or refused.
    pub fn total(&self) -> u32 {
        self.handled
            .wrapping_add(self.null)
            .wrapping_add(self.no_such_port)
            .wrapping_add(self.unsupported)
            .wrapping_add(self.short)
            .wrapping_add(self.bad_value)
            .wrapping_add(self.refused)
            .wrapping_add(self.malformed)
    }
}

/// Reads a little-endian `f32` at `at` of `p`, if it is there.
pub(crate) fn f32_at(p: &[u8], at: usize) -> Option<f32> {
    let b = p.get(at..at + 4)?;
    Some(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Reads a little-endian `u32` at `at` of `p`, if it is there.
pub(crate) fn u32_at(p: &[u8], at: usize) -> Option<u32> {
    let b = p.get(at..at + 4)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Reads a little-endian `u16` at `at` of `p`, if it is there.
pub(crate) fn u16_at(p: &[u8], at: usize) -> Option<u16> {
    let b = p.get(at..at + 2)?;
    Some(u16::from_le_bytes([b[0], b[1]]))
}

#[cfg(test)]
mod tests;
