//! Syslink: the Crazyflie 2.x's serial link between its STM32 and its nRF51
//! radio chip (USART6 at 1 Mbaud on the board), as `bitcraze/crazyflie-firmware`
//! frames it (`src/hal/interface/syslink.h`, `src/drivers/src/uart_syslink.c`):
//!
//! ```text
//! 0xBC 0xCF type length data[length] ckA ckB
//! ```
//!
//! `length` ≤ 64 ([`MTU`]); `ckA`/`ckB` are an 8-bit Fletcher sum over type,
//! length and data (`ckA += b; ckB += ckA`). A radio packet (`RADIO_RAW`)
//! carries one CRTP packet, header byte first. The nRF51 sends one uplink
//! packet per radio packet received (nulls included: the PC's radio polls
//! with them), and the STM32 answers each with at most one downlink packet
//! from its queue ([`Syslink`], as `radiolinkSyslinkDispatch` does). The
//! STM32 says `RADIO_READY` at boot; the nRF51 echoes it and reports the
//! battery (`PM_BATTERY_STATE`: flags, V, A).

use crate::vehicle::CrtpShared;
use crate::CrtpSink;
use crate::{f32_at, CrtpError, Packet, MAX_PACKET};
use core::borrow::BorrowMut;
use fc_loop::Mutex;
use hal_shim::ByteLink;

/// Largest syslink payload, bytes (`SYSLINK_MTU`).
pub const MTU: usize = 64;
/// Largest syslink frame: start bytes, type, length, [`MTU`] bytes, checksum.
pub const FRAME_MAX: usize = MTU + 6;
/// The two start bytes.
pub const START: [u8; 2] = [0xBC, 0xCF];

/// The most packets the vehicle keeps waiting for the link: a
/// re-designing write's answer, its console lines and its log blocks
/// sampled. Bounds the link's one-packet locks ([`Syslink::poll`]).
const WAITING_MAX: usize = 1 + crate::vehicle::CONSOLE_QUEUE + crate::vehicle::LOG_QUEUE;

/// Sends what the vehicle has waiting (with `logs`, its log blocks too)
/// to `down`, one packet per lock of `vehicle`
/// ([`CrtpShared::send_next`]), until none waits or `down` is full.
fn send_waiting<M: Mutex, const Q: usize>(down: &mut Downlink<Q>, vehicle: &mut M, logs: bool)
where
    M::T: BorrowMut<CrtpShared>,
{
    for _ in 0..WAITING_MAX {
        if !matches!(vehicle.lock(|v| v.borrow_mut().send_next(down, logs)), Ok(true)) {
            break;
        }
    }
}

/// Syslink packet types this firmware acts on (`syslink.h`).
pub mod types {
    /// A CRTP packet to or from the radio.
    pub const RADIO_RAW: u8 = 0x00;
    /// Radio channel (STM32 → nRF51).
    pub const RADIO_CHANNEL: u8 = 0x01;
    /// Radio data rate (STM32 → nRF51).
    pub const RADIO_DATARATE: u8 = 0x02;
    /// Radio address (STM32 → nRF51).
    pub const RADIO_ADDRESS: u8 = 0x05;
    /// A broadcast CRTP packet from the radio (no answer).
    pub const RADIO_RAW_BROADCAST: u8 = 0x06;
    /// The STM32 is up (at boot); the nRF51 echoes it once its radio is on.
    pub const RADIO_READY: u8 = 0x0B;
    /// Battery state from the nRF51: flags `u8`, voltage `f32` V, charge current `f32` A.
    pub const PM_BATTERY_STATE: u8 = 0x13;
}

/// Why a syslink frame was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SyslinkError {
    /// A length byte over [`MTU`] (the length given); the frame is skipped.
    TooLong(u8),
    /// The checksum did not match (type of the frame).
    Checksum(u8),
    /// A `RADIO_RAW` frame that is not a CRTP packet.
    Crtp(CrtpError),
    /// A type this firmware does not act on.
    Unhandled(u8),
    /// A `PM_BATTERY_STATE` too short or with a voltage that is not finite.
    BadBattery,
}

impl core::fmt::Display for SyslinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            SyslinkError::TooLong(n) => write!(f, "syslink frame of {n} bytes: at most {MTU}"),
            SyslinkError::Checksum(t) => write!(f, "syslink frame of type {t:#04x}: checksum mismatch"),
            SyslinkError::Crtp(e) => write!(f, "syslink radio frame: {e}"),
            SyslinkError::Unhandled(t) => write!(f, "syslink type {t:#04x} is not handled"),
            SyslinkError::BadBattery => write!(f, "syslink battery state too short or not finite"),
        }
    }
}

/// One syslink packet: type and up to [`MTU`] bytes.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub struct SyslinkPacket {
    ty: u8,
    len: u8,
    data: [u8; MTU],
}

impl SyslinkPacket {
    /// A packet of type `ty` carrying `data`; `Err` if longer than [`MTU`].
    pub fn new(ty: u8, data: &[u8]) -> Result<Self, SyslinkError> {
        if data.len() > MTU {
            return Err(SyslinkError::TooLong(data.len().min(255) as u8));
        }
        let mut p = Self {
            ty,
            len: data.len() as u8,
            data: [0; MTU],
        };
        p.data[..data.len()].copy_from_slice(data);
        Ok(p)
    }

    /// The `RADIO_RAW` packet carrying CRTP packet `p`.
    pub fn radio(p: &Packet) -> Self {
        let mut raw = [0u8; MAX_PACKET];
        let n = p.write_to(&mut raw);
        let mut s = Self {
            ty: types::RADIO_RAW,
            len: n as u8,
            data: [0; MTU],
        };
        s.data[..n].copy_from_slice(&raw[..n]);
        s
    }

    /// The type.
    pub fn ty(&self) -> u8 {
        self.ty
    }

    /// The payload.
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// The frame: start bytes, type, length, payload, checksum; returns its length.
    pub fn encode(&self, out: &mut [u8; FRAME_MAX]) -> usize {
        let n = usize::from(self.len);
        out[..2].copy_from_slice(&START);
        out[2] = self.ty;
        out[3] = self.len;
        out[4..4 + n].copy_from_slice(self.data());
        let [a, b] = checksum(&out[2..4 + n]);
        out[4 + n] = a;
        out[5 + n] = b;
        n + 6
    }
}

/// The 8-bit Fletcher sum of `bytes` (type, length and payload of a frame).
pub fn checksum(bytes: &[u8]) -> [u8; 2] {
    bytes.iter().fold([0u8, 0u8], |[a, b], &x| {
        let a = a.wrapping_add(x);
        [a, b.wrapping_add(a)]
    })
}

/// Where the decoder is in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Start1,
    Start2,
    Type,
    Length,
    Data,
    CkA,
    CkB,
}

/// Byte-at-a-time syslink frame decoder, the firmware's receive state
/// machine: bytes outside a frame are skipped until the start bytes, a
/// bad length or checksum drops the frame and resynchronises.
#[derive(Debug, Clone)]
pub struct Decoder {
    state: State,
    packet: SyslinkPacket,
    at: usize,
    ck: [u8; 2],
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// A decoder waiting for a frame's first start byte.
    pub const fn new() -> Self {
        Self {
            state: State::Start1,
            packet: SyslinkPacket {
                ty: 0,
                len: 0,
                data: [0; MTU],
            },
            at: 0,
            ck: [0; 2],
        }
    }

    /// Feeds one byte; a whole frame gives `Some(Ok)`, a dropped one `Some(Err)`.
    pub fn push(&mut self, b: u8) -> Option<Result<SyslinkPacket, SyslinkError>> {
        match self.state {
            State::Start1 => {
                if b == START[0] {
                    self.state = State::Start2;
                }
            }
            State::Start2 => {
                self.state = match b {
                    _ if b == START[1] => State::Type,
                    _ if b == START[0] => State::Start2,
                    _ => State::Start1,
                };
            }
            State::Type => {
                self.packet.ty = b;
                self.ck = [b, b];
                self.state = State::Length;
            }
            State::Length => {
                self.state = State::Start1;
                if usize::from(b) > MTU {
                    return Some(Err(SyslinkError::TooLong(b)));
                }
                self.packet.len = b;
                self.ck = add(self.ck, b);
                self.at = 0;
                self.state = if b == 0 { State::CkA } else { State::Data };
            }
            State::Data => {
                self.packet.data[self.at] = b;
                self.at += 1;
                self.ck = add(self.ck, b);
                if self.at == usize::from(self.packet.len) {
                    self.state = State::CkA;
                }
            }
            State::CkA => {
                self.state = if b == self.ck[0] { State::CkB } else { State::Start1 };
                if self.state == State::Start1 {
                    return Some(Err(SyslinkError::Checksum(self.packet.ty)));
                }
            }
            State::CkB => {
                self.state = State::Start1;
                return Some(if b == self.ck[1] {
                    Ok(self.packet)
                } else {
                    Err(SyslinkError::Checksum(self.packet.ty))
                });
            }
        }
        None
    }
}

/// One step of the Fletcher sum.
fn add([a, b]: [u8; 2], x: u8) -> [u8; 2] {
    let a = a.wrapping_add(x);
    [a, b.wrapping_add(a)]
}

/// The nRF51's battery report (`PmSyslinkInfo`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BatteryState {
    /// Bit 0 charging, bit 1 USB plugged in, bit 2 can charge.
    pub flags: u8,
    /// Battery voltage, V.
    pub vbat_v: f32,
    /// Charge current, A.
    pub charge_current_a: f32,
}

impl BatteryState {
    /// Parses a `PM_BATTERY_STATE` payload (9 bytes, or more with a temperature).
    pub fn parse(data: &[u8]) -> Result<Self, SyslinkError> {
        let flags = *data.first().ok_or(SyslinkError::BadBattery)?;
        let vbat_v = f32_at(data, 1).ok_or(SyslinkError::BadBattery)?;
        let charge_current_a = f32_at(data, 5).ok_or(SyslinkError::BadBattery)?;
        if !vbat_v.is_finite() || !(0.0..=10.0).contains(&vbat_v) {
            return Err(SyslinkError::BadBattery);
        }
        Ok(Self {
            flags,
            vbat_v,
            charge_current_a,
        })
    }

    /// The payload: flags, voltage, current (little-endian).
    pub fn to_bytes(&self) -> [u8; 9] {
        let mut b = [0u8; 9];
        b[0] = self.flags;
        b[1..5].copy_from_slice(&self.vbat_v.to_le_bytes());
        b[5..9].copy_from_slice(&self.charge_current_a.to_le_bytes());
        b
    }

    /// `pm.state` as the Crazyflie reports it: 1 charging, 2 charged (USB
    /// in, not charging), 0 on battery.
    pub fn pm_state(&self) -> i8 {
        match (self.flags & 1 != 0, self.flags & 2 != 0) {
            (true, _) => 1,
            (false, true) => 2,
            _ => 0,
        }
    }
}

/// What the syslink side saw. Every frame taken is one of `radio`,
/// `ready`, `battery`, `bad_battery` or `unhandled`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SyslinkCounters {
    /// Frames taken.
    pub frames: u32,
    /// Frames dropped: bad length or checksum.
    pub bad_frames: u32,
    /// Radio packets (unicast and broadcast) passed to the vehicle.
    pub radio: u32,
    /// `RADIO_READY` echoes from the nRF51.
    pub ready: u32,
    /// Battery reports taken.
    pub battery: u32,
    /// Battery reports refused (short, not finite, out of range).
    pub bad_battery: u32,
    /// Frames of types not acted on.
    pub unhandled: u32,
    /// Downlink packets sent.
    pub downlink_sent: u32,
    /// Downlink packets dropped because the queue was full.
    pub downlink_dropped: u32,
}

impl SyslinkCounters {
    /// Every frame seen: taken or dropped.
    pub fn total(&self) -> u32 {
        self.frames.wrapping_add(self.bad_frames)
    }
}

/// The STM32's downlink queue: packets wait here for an uplink packet to
/// answer ([`CrtpSink`]; a full queue drops and counts).
#[derive(Default)]
pub struct Downlink<const Q: usize> {
    queue: heapless::Deque<Packet, Q>,
    dropped: u32,
    /// Where persistent parameters are kept ([`Syslink::keep_in`]).
    storage: Option<&'static mut (dyn fc_storage::Persist + Send)>,
}

impl<const Q: usize> core::fmt::Debug for Downlink<Q> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Downlink")
            .field("queued", &self.queue.len())
            .field("dropped", &self.dropped)
            .field("storage", &self.storage.is_some())
            .finish()
    }
}

/// The downlink queue was full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueFull;

impl core::fmt::Display for QueueFull {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "the CRTP downlink queue is full")
    }
}

impl<const Q: usize> CrtpSink for Downlink<Q> {
    type Error = QueueFull;
    fn send(&mut self, p: &Packet) -> Result<(), QueueFull> {
        self.queue.push_back(*p).map_err(|_| {
            self.dropped = self.dropped.wrapping_add(1);
            QueueFull
        })
    }
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        match &mut self.storage {
            Some(s) => Some(&mut **s),
            None => None,
        }
    }
}

/// The STM32's side of syslink in front of a CRTP vehicle: frames in,
/// radio packets to the vehicle, one downlink packet per uplink packet,
/// battery reports to the vehicle. `Q` is the downlink queue's capacity.
///
/// The vehicle is reached through a [`Mutex`] and locked one packet at a
/// time, never while the radio's USART is written: in-process it is the
/// [`crate::vehicle::CrtpVehicle`] itself, on an image a short lock of the
/// [`CrtpShared`] the IMU task shares.
#[derive(Debug)]
pub struct Syslink<const Q: usize> {
    decoder: Decoder,
    down: Downlink<Q>,
    counters: SyslinkCounters,
}

impl<const Q: usize> Default for Syslink<Q> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const Q: usize> Syslink<Q> {
    /// Nothing received, nothing queued.
    pub fn new() -> Self {
        Self {
            decoder: Decoder::new(),
            down: Downlink {
                queue: heapless::Deque::new(),
                dropped: 0,
                storage: None,
            },
            counters: SyslinkCounters::default(),
        }
    }

    /// Keeps persistent parameters in `storage` (cflib's
    /// `param.persistent_store`): the requests are answered here, after the
    /// vehicle's lock is let go.
    pub fn keep_in(&mut self, storage: &'static mut (dyn fc_storage::Persist + Send)) {
        self.down.storage = Some(storage);
    }

    /// What was seen so far.
    pub fn counters(&self) -> SyslinkCounters {
        SyslinkCounters {
            downlink_dropped: self.down.dropped,
            ..self.counters
        }
    }

    /// Says `RADIO_READY` (at boot: the radio may start).
    pub fn boot<L: ByteLink>(&mut self, link: &mut L) -> Result<(), L::Error> {
        let ready = SyslinkPacket {
            ty: types::RADIO_READY,
            ..EMPTY
        };
        send(link, &ready)
    }

    /// What the vehicle has waiting (a re-designing write's answer,
    /// console lines, the log blocks sampled) goes to the downlink queue.
    pub fn poll<M: Mutex>(&mut self, vehicle: &mut M)
    where
        M::T: BorrowMut<CrtpShared>,
    {
        // One packet per lock (each hold short), at most what the vehicle
        // queues; a full queue drops the block's sample (counted), as a
        // radio would.
        send_waiting(&mut self.down, vehicle, true);
    }

    /// Feeds the bytes `rx` from the nRF51; answers on `link`.
    pub fn receive<M: Mutex, L: ByteLink>(&mut self, rx: &[u8], vehicle: &mut M, link: &mut L) -> Result<(), L::Error>
    where
        M::T: BorrowMut<CrtpShared>,
    {
        for &b in rx {
            match self.decoder.push(b) {
                None => {}
                Some(Err(_)) => self.counters.bad_frames = self.counters.bad_frames.wrapping_add(1),
                Some(Ok(p)) => {
                    self.counters.frames = self.counters.frames.wrapping_add(1);
                    self.dispatch(&p, vehicle, link)?;
                }
            }
        }
        Ok(())
    }

    /// Acts on one frame.
    fn dispatch<M: Mutex, L: ByteLink>(
        &mut self,
        p: &SyslinkPacket,
        vehicle: &mut M,
        link: &mut L,
    ) -> Result<(), L::Error>
    where
        M::T: BorrowMut<CrtpShared>,
    {
        match p.ty() {
            types::RADIO_RAW | types::RADIO_RAW_BROADCAST => {
                self.counters.radio = self.counters.radio.wrapping_add(1);
                match Packet::from_bytes(p.data()) {
                    // A full queue drops the answer (counted); the client repeats its request.
                    // The radio acknowledges a null packet itself: the
                    // vehicle counts it, its null answer is not queued.
                    Ok(c) if c.is_null() => {
                        let _ = vehicle.lock(|v| v.borrow_mut().handle(&c, &mut Discard));
                    }
                    Ok(c) => {
                        let down = &mut self.down;
                        let _ = vehicle.lock(|v| v.borrow_mut().handle(&c, down));
                        // A persistent parameter's request, answered with
                        // the storage outside the lock.
                        if let Some(r) = vehicle.lock(|v| v.borrow_mut().take_persist()) {
                            let _ = r.answer(down);
                        }
                        // What the packet's controller work answered, if it
                        // is done already (in-process it is).
                        send_waiting(down, vehicle, false);
                    }
                    Err(e) => vehicle.lock(|v| v.borrow_mut().count_malformed(e)),
                }
                if p.ty() == types::RADIO_RAW {
                    // One downlink packet per uplink packet.
                    if let Some(d) = self.down.queue.pop_front() {
                        self.counters.downlink_sent = self.counters.downlink_sent.wrapping_add(1);
                        return send(link, &SyslinkPacket::radio(&d));
                    }
                }
            }
            types::RADIO_READY => self.counters.ready = self.counters.ready.wrapping_add(1),
            types::PM_BATTERY_STATE => match BatteryState::parse(p.data()) {
                Ok(b) => {
                    self.counters.battery = self.counters.battery.wrapping_add(1);
                    vehicle.lock(|v| v.borrow_mut().set_battery(b.vbat_v, b.pm_state()));
                }
                Err(_) => self.counters.bad_battery = self.counters.bad_battery.wrapping_add(1),
            },
            _ => self.counters.unhandled = self.counters.unhandled.wrapping_add(1),
        }
        Ok(())
    }
}

/// Drops what it is sent.
struct Discard;

impl CrtpSink for Discard {
    type Error = core::convert::Infallible;
    fn send(&mut self, _: &Packet) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// An empty packet (`RADIO_RAW`).
const EMPTY: SyslinkPacket = SyslinkPacket {
    ty: types::RADIO_RAW,
    len: 0,
    data: [0; MTU],
};

/// Writes `p` as one frame.
fn send<L: ByteLink>(link: &mut L, p: &SyslinkPacket) -> Result<(), L::Error> {
    let mut out = [0u8; FRAME_MAX];
    let n = p.encode(&mut out);
    link.write_all(&out[..n])
}

#[cfg(test)]
mod tests;
