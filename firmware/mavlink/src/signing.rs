//! MAVLink 2 message signing, as PX4 does it (its "MAVLink Message
//! Signing" page; the protocol is mavlink.io's "Message Signing").
//!
//! A signed frame carries 13 bytes after its CRC: a link id, a 48-bit
//! timestamp (10 µs since 2015-01-01 00:00 UTC) and the first 6 bytes of
//! SHA-256(key ‖ frame up to its CRC ‖ link id ‖ timestamp). [`Signing`]
//! holds the 32-byte key, this side's timestamp and a fixed table of the
//! streams (system, component, link) heard with their last timestamps.
//!
//! The policy (PX4's):
//! - no key: nothing is signed and every frame is accepted, signed or not;
//! - with a key: every frame sent is signed; a frame heard must be signed
//!   with the key, with a timestamp newer than its stream's last (a stream
//!   heard first may be at most a minute behind this side's clock), or it
//!   is dropped and counted — except [`UNSIGNED_ALLOWED`];
//! - `SETUP_SIGNING` provisions the key when there is none; changing or
//!   clearing it (all-zero key and timestamp) needs a frame signed with the
//!   current key; every change is refused while armed ([`Signing::setup`]).
//!
//! No allocation; the stream table is a `heapless::Vec` of `STREAMS`.
//!
//! **Never back, across a power cut.** A side's timestamps must never go
//! back. A vehicle with no calendar clock keeps its timestamp in flash, but
//! not while armed (a write stalls the control loop), so after a power cut
//! in flight the timestamp it stored is behind the ones it signed in the
//! air. A side made from a stored key ([`Signing::stored`]) therefore
//! signs nothing until it has accepted a frame signed with the key
//! ([`Signing::may_sign`]; only its `HEARTBEAT` goes out meanwhile,
//! unsigned, so that a ground station on UDP learns where it is): its
//! clock is then at least that frame's
//! timestamp, which a ground station that heard it before the cut has
//! taken above every one it signed (mavlink.io: each side keeps the newest
//! timestamp it has heard), and a ground station started afresh stamps with
//! the time of day, later than the cut.

use sha2::{Digest, Sha256};

/// A signing key: 32 bytes shared by the vehicle and its ground stations.
pub type Key = [u8; 32];

/// The signature block's length: link id, timestamp (6), signature (6).
pub const SIGNATURE_LEN: usize = 13;

/// The incompatibility flag of a signed frame.
pub const FLAG_SIGNED: u8 = 0x01;

/// How far behind this side's clock a stream heard for the first time may
/// be: one minute, in the timestamp's units of 10 µs (mavlink.io).
pub const NEW_STREAM_WINDOW: u64 = 6_000_000;

/// The 48-bit timestamp's largest value.
const TIMESTAMP_MAX: u64 = (1 << 48) - 1;

/// The message ids PX4 accepts unsigned when a key is set (RADIO_STATUS,
/// ADSB_VEHICLE, COLLISION: from radios and traffic receivers that cannot
/// sign).
pub const UNSIGNED_ALLOWED: [u32; 3] = [109, 246, 247];

/// The simulator's messages, which the `firmware-mavlink` image hears on the
/// ground station's link (one USART for both peers) and accepts unsigned:
/// `HIL_SENSOR`, `HIL_STATE_QUATERNION`. PX4 hears its simulator apart from
/// its MAVLink module; a vehicle flying its own sensors has no such link.
pub const SIMULATOR_UNSIGNED: [u32; 2] = [107, 115];

/// Streams a vehicle tracks at once (mavlink.io's C library keeps 16).
pub const STREAMS: usize = 16;

/// Why a frame was dropped by the signing check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SignError {
    /// Unsigned while a key is set (its message id, given).
    Unsigned(u32),
    /// The signature does not match the key.
    BadSignature,
    /// The timestamp is not newer than its stream's last, or (a new
    /// stream) more than a minute behind this side's clock.
    Replayed,
    /// A new stream while the table is full.
    TooManyStreams,
}

impl core::fmt::Display for SignError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SignError::Unsigned(id) => write!(f, "MAVLink message {id} is unsigned while signing is on"),
            SignError::BadSignature => write!(f, "MAVLink frame signed with another key"),
            SignError::Replayed => write!(
                f,
                "MAVLink frame replayed (its timestamp is not newer than its stream's)"
            ),
            SignError::TooManyStreams => write!(f, "MAVLink signing: no room for another stream ({STREAMS} kept)"),
        }
    }
}

/// Why a `SETUP_SIGNING` was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SetupRefusal {
    /// The vehicle is armed: the key does not change in flight.
    Armed,
    /// A key is set and the request was not signed with it.
    NotSignedWithCurrentKey,
}

impl core::fmt::Display for SetupRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SetupRefusal::Armed => write!(f, "signing: key change refused while armed"),
            SetupRefusal::NotSignedWithCurrentKey => {
                write!(f, "signing: key change refused, not signed with the current key")
            }
        }
    }
}

/// What an accepted `SETUP_SIGNING` did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SetupOutcome {
    /// A key is now set (provisioned or changed): signing is on.
    KeySet,
    /// The key was cleared: signing is off.
    Cleared,
}

impl core::fmt::Display for SetupOutcome {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SetupOutcome::KeySet => write!(f, "signing: key set, unsigned commands are now ignored"),
            SetupOutcome::Cleared => write!(f, "signing: key cleared, signing off"),
        }
    }
}

/// What the signing check accepted and dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SigningCounters {
    /// Signed frames accepted.
    pub accepted: u32,
    /// Unsigned frames accepted while a key is set ([`UNSIGNED_ALLOWED`]).
    pub unsigned_allowed: u32,
    /// Unsigned frames dropped.
    pub unsigned: u32,
    /// Frames with a signature that does not match the key.
    pub bad_signature: u32,
    /// Replayed frames (a timestamp not newer than the stream's).
    pub replayed: u32,
    /// New streams refused for want of room.
    pub too_many_streams: u32,
    /// `SETUP_SIGNING` requests refused.
    pub setups_refused: u32,
}

impl SigningCounters {
    /// Frames dropped, of every kind.
    pub fn dropped(&self) -> u32 {
        self.unsigned + self.bad_signature + self.replayed + self.too_many_streams
    }
}

#[derive(Debug, Clone, Copy)]
struct Stream {
    system: u8,
    component: u8,
    link: u8,
    timestamp: u64,
}

/// One side's signing state: its key (if any), its timestamp, the streams
/// it heard. `Clone` so that the host can keep it beside a link.
#[derive(Clone)]
pub struct Signing {
    key: Option<Key>,
    timestamp: u64,
    link_id: u8,
    streams: heapless::Vec<Stream, STREAMS>,
    counters: SigningCounters,
    last_authenticated: bool,
    also_unsigned: &'static [u32],
    /// Microseconds not yet a whole timestamp unit (10 µs).
    rem_us: u64,
    /// Its clock is one it can sign with: not made from a stored key, or a
    /// frame signed with the key accepted since ([`Signing::may_sign`]).
    clocked: bool,
}

impl core::fmt::Debug for Signing {
    // Never prints the key.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Signing")
            .field("on", &self.key.is_some())
            .field("timestamp", &self.timestamp)
            .field("clocked", &self.clocked)
            .field("streams", &self.streams.len())
            .field("counters", &self.counters)
            .finish()
    }
}

impl Default for Signing {
    fn default() -> Self {
        Self::new()
    }
}

impl Signing {
    /// No key: signing off, everything accepted.
    pub const fn new() -> Self {
        Self {
            key: None,
            timestamp: 0,
            link_id: 0,
            streams: heapless::Vec::new(),
            counters: SigningCounters {
                accepted: 0,
                unsigned_allowed: 0,
                unsigned: 0,
                bad_signature: 0,
                replayed: 0,
                too_many_streams: 0,
                setups_refused: 0,
            },
            last_authenticated: false,
            also_unsigned: &[],
            rem_us: 0,
            clocked: true,
        }
    }

    /// With `key` and this side's `timestamp` (10 µs since 2015): signing
    /// on. An all-zero key with a zero timestamp is no key (PX4's rule for a
    /// blank key file).
    pub fn with_key(key: Key, timestamp: u64) -> Self {
        let mut s = Self::new();
        if key != [0; 32] || timestamp != 0 {
            s.key = Some(key);
            s.timestamp = timestamp.min(TIMESTAMP_MAX);
        }
        s
    }

    /// [`Signing::with_key`] for a key and timestamp read from storage at
    /// boot: the timestamp may be behind what was signed before a power
    /// cut, so nothing is signed until a frame signed with the key is
    /// accepted ([`Signing::may_sign`]).
    pub fn stored(key: Key, timestamp: u64) -> Self {
        let mut s = Self::with_key(key, timestamp);
        s.clocked = s.key.is_none();
        s
    }

    /// Whether frames may be sent: no key, or a clock to sign with (after a
    /// boot on a stored key, once a frame signed with it has been accepted,
    /// or a `SETUP_SIGNING` has given one). Until then [`crate::encode_signed`]
    /// holds every frame ([`crate::MavError::Unclocked`]) but the
    /// `HEARTBEAT`, which goes unsigned.
    pub fn may_sign(&self) -> bool {
        self.key.is_none() || self.clocked
    }

    /// Whether a key is set (frames sent are signed, frames heard must be).
    pub fn is_on(&self) -> bool {
        self.key.is_some()
    }

    /// The key, to be stored (`None`: signing off).
    pub fn key(&self) -> Option<&Key> {
        self.key.as_ref()
    }

    /// This side's timestamp (10 µs since 2015-01-01), to be stored.
    pub fn timestamp(&self) -> u64 {
        self.timestamp
    }

    /// What was accepted and dropped so far.
    pub fn counters(&self) -> SigningCounters {
        self.counters
    }

    /// Whether the last frame checked was signed with the key (what a
    /// `SETUP_SIGNING` that changes the key must be).
    pub fn last_authenticated(&self) -> bool {
        self.last_authenticated
    }

    /// Accepts these message ids unsigned too (beside [`UNSIGNED_ALLOWED`]):
    /// [`SIMULATOR_UNSIGNED`] where the simulator shares the link.
    pub fn also_accept_unsigned(&mut self, ids: &'static [u32]) {
        self.also_unsigned = ids;
    }

    /// The link id this side signs with (0 unless set).
    pub fn set_link_id(&mut self, link_id: u8) {
        self.link_id = link_id;
    }

    /// Moves this side's clock on by `us` microseconds (its timestamps
    /// follow time, never go back; a vehicle without a calendar clock keeps
    /// the stored one and adds the time it has been up).
    pub fn advance_us(&mut self, us: u64) {
        let us = self.rem_us.saturating_add(us);
        self.rem_us = us % 10;
        self.timestamp = self.timestamp.saturating_add(us / 10).min(TIMESTAMP_MAX);
    }

    /// Checks a complete frame `frame` (header to the end of its signature
    /// block, if signed) of message `id`, whose CRC is already checked.
    /// `Ok(true)`: signed with the key; `Ok(false)`: accepted unsigned (no
    /// key, or an id of [`UNSIGNED_ALLOWED`]). Counted either way.
    pub fn check(&mut self, frame: &[u8], id: u32) -> Result<bool, SignError> {
        let r = self.verify(frame, id);
        self.last_authenticated = r == Ok(true);
        let c = &mut self.counters;
        let n = match r {
            Ok(true) => &mut c.accepted,
            Ok(false) if self.key.is_some() => &mut c.unsigned_allowed,
            Ok(false) => return r,
            Err(SignError::Unsigned(_)) => &mut c.unsigned,
            Err(SignError::BadSignature) => &mut c.bad_signature,
            Err(SignError::Replayed) => &mut c.replayed,
            Err(SignError::TooManyStreams) => &mut c.too_many_streams,
        };
        *n = n.wrapping_add(1);
        r
    }

    fn verify(&mut self, frame: &[u8], id: u32) -> Result<bool, SignError> {
        let signed = frame.get(2).is_some_and(|f| f & FLAG_SIGNED != 0) && frame.len() > SIGNATURE_LEN + 12;
        let Some(key) = self.key else {
            return Ok(false);
        };
        if !signed {
            return if UNSIGNED_ALLOWED.contains(&id) || self.also_unsigned.contains(&id) {
                Ok(false)
            } else {
                Err(SignError::Unsigned(id))
            };
        }
        let (body, block) = frame.split_at(frame.len() - SIGNATURE_LEN);
        let link = block[0];
        let mut ts = [0u8; 8];
        ts[..6].copy_from_slice(&block[1..7]);
        let timestamp = u64::from_le_bytes(ts);
        if signature(&key, body, link, timestamp) != block[7..13] {
            return Err(SignError::BadSignature);
        }
        let (system, component) = (frame[5], frame[6]);
        match self
            .streams
            .iter_mut()
            .find(|s| s.system == system && s.component == component && s.link == link)
        {
            Some(s) if timestamp <= s.timestamp => return Err(SignError::Replayed),
            Some(s) => s.timestamp = timestamp,
            None => {
                if timestamp.saturating_add(NEW_STREAM_WINDOW) < self.timestamp {
                    return Err(SignError::Replayed);
                }
                let s = Stream {
                    system,
                    component,
                    link,
                    timestamp,
                };
                self.streams.push(s).map_err(|_| SignError::TooManyStreams)?;
            }
        }
        self.timestamp = self.timestamp.max(timestamp);
        self.clocked = true;
        Ok(true)
    }

    /// Signs the unsigned frame `out[..len]` in place when a key is set:
    /// sets its signed flag, recomputes its CRC (with the message's CRC
    /// extra byte `crc_extra`) and appends the signature block. Returns the
    /// frame's new length (`len` unchanged when signing is off), or `None`
    /// if `out` has no room for the block.
    pub fn sign(&mut self, out: &mut [u8], len: usize, crc_extra: u8) -> Option<usize> {
        let Some(key) = self.key else {
            return Some(len);
        };
        if len < 12 || out.len() < len + SIGNATURE_LEN {
            return None;
        }
        out[2] |= FLAG_SIGNED;
        let crc = mavlink::calculate_crc(&out[1..len - 2], crc_extra);
        out[len - 2..len].copy_from_slice(&crc.to_le_bytes());
        self.timestamp = (self.timestamp + 1).min(TIMESTAMP_MAX);
        let ts = self.timestamp;
        let sig = signature(&key, &out[..len], self.link_id, ts);
        out[len] = self.link_id;
        out[len + 1..len + 7].copy_from_slice(&ts.to_le_bytes()[..6]);
        out[len + 7..len + 13].copy_from_slice(&sig);
        Some(len + SIGNATURE_LEN)
    }

    /// A `SETUP_SIGNING` (key, initial timestamp), heard `authenticated`
    /// (signed with the current key) while the vehicle is `armed` or not.
    /// Provisions the key when none is set; changing or clearing one (an
    /// all-zero key and timestamp) needs `authenticated`; refused while
    /// armed. The timestamp never goes back: it becomes the larger of this
    /// side's and the request's. Refusals are counted.
    pub fn setup(
        &mut self,
        key: &Key,
        initial_timestamp: u64,
        authenticated: bool,
        armed: bool,
    ) -> Result<SetupOutcome, SetupRefusal> {
        let r = if armed {
            Err(SetupRefusal::Armed)
        } else if self.key.is_some() && !authenticated {
            Err(SetupRefusal::NotSignedWithCurrentKey)
        } else if *key == [0; 32] && initial_timestamp == 0 {
            // The streams heard are kept through every key change: a frame
            // signed before, replayed after the same key is set again, is
            // still older than its stream's last.
            self.key = None;
            Ok(SetupOutcome::Cleared)
        } else {
            self.key = Some(*key);
            self.timestamp = self.timestamp.max(initial_timestamp.min(TIMESTAMP_MAX));
            self.clocked = true;
            Ok(SetupOutcome::KeySet)
        };
        if r.is_err() {
            self.counters.setups_refused = self.counters.setups_refused.wrapping_add(1);
        }
        r
    }
}

/// The 48-bit signature: the first 6 bytes of SHA-256(key ‖ `body` (the
/// frame from its start byte to its CRC) ‖ link id ‖ 6 timestamp bytes).
pub fn signature(key: &Key, body: &[u8], link_id: u8, timestamp: u64) -> [u8; 6] {
    let mut h = Sha256::new();
    h.update(key);
    h.update(body);
    h.update([link_id]);
    h.update(&timestamp.to_le_bytes()[..6]);
    let d = h.finalize();
    let mut s = [0u8; 6];
    s.copy_from_slice(&d[..6]);
    s
}
