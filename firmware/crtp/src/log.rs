//! Log blocks, as the Crazyflie firmware keeps them: a client creates a
//! block of TOC variables (each with the type it wants them sent as),
//! appends to it, starts it at a period and gets one packet per period on
//! channel 2 (`block id`, a 24-bit millisecond timestamp, the values), then
//! stops and deletes it. Capacities are the firmware's: 16 blocks, 128
//! variables in all, 26 bytes of values per block. Every refusal is one of
//! the error codes cflib knows (`errno` numbers, as newlib's).

use crate::{CrtpError, Packet, Port};

/// Blocks at once (`LOG_MAX_BLOCKS`).
pub const MAX_BLOCKS: usize = 16;
/// Variables in all blocks together (`LOG_MAX_OPS`).
pub const MAX_OPS: usize = 128;
/// Bytes of values in one block's packet (30 less id and timestamp).
pub const MAX_BLOCK_BYTES: usize = 26;

/// `ENOENT`: no such block, or no such variable.
pub const ENOENT: u8 = 2;
/// `E2BIG`: the block's values would not fit one packet.
pub const E2BIG: u8 = 7;
/// `EIO`: the storage is missing or failed (a persistent parameter's
/// store, state or clear).
pub const EIO: u8 = 5;
/// `ENOEXEC`: an unknown command (or a type cflib cannot fetch).
pub const ENOEXEC: u8 = 8;
/// `ENOMEM`: no free block, or no free variable.
pub const ENOMEM: u8 = 12;
/// `EEXIST`: a block of that id exists.
pub const EEXIST: u8 = 17;

/// Log type numbers (cflib's `LogTocElement.types`).
pub mod types {
    /// `uint8_t`.
    pub const U8: u8 = 1;
    /// `uint16_t`.
    pub const U16: u8 = 2;
    /// `uint32_t`.
    pub const U32: u8 = 3;
    /// `int8_t`.
    pub const I8: u8 = 4;
    /// `int16_t`.
    pub const I16: u8 = 5;
    /// `int32_t`.
    pub const I32: u8 = 6;
    /// `float`.
    pub const FLOAT: u8 = 7;
    /// IEEE half precision.
    pub const FP16: u8 = 8;
}

/// Bytes a value of log type `t` takes, `None` for a type that is not one.
pub fn size_of(t: u8) -> Option<usize> {
    Some(match t {
        types::U8 | types::I8 => 1,
        types::U16 | types::I16 | types::FP16 => 2,
        types::U32 | types::I32 | types::FLOAT => 4,
        _ => return None,
    })
}

/// Writes `v` as log type `t` (integers rounded toward zero and saturated,
/// NaN as 0) into `out`; returns the bytes written, `None` if `t` is no
/// type or `out` too short.
pub fn encode(v: f32, t: u8, out: &mut [u8]) -> Option<usize> {
    let n = size_of(t)?;
    let out = out.get_mut(..n)?;
    match t {
        types::U8 => out.copy_from_slice(&(v as u8).to_le_bytes()),
        types::U16 => out.copy_from_slice(&(v as u16).to_le_bytes()),
        types::U32 => out.copy_from_slice(&(v as u32).to_le_bytes()),
        types::I8 => out.copy_from_slice(&(v as i8).to_le_bytes()),
        types::I16 => out.copy_from_slice(&(v as i16).to_le_bytes()),
        types::I32 => out.copy_from_slice(&(v as i32).to_le_bytes()),
        types::FLOAT => out.copy_from_slice(&v.to_le_bytes()),
        _ => out.copy_from_slice(&half::f16::from_f32(v).to_le_bytes()),
    }
    Some(n)
}

/// One variable of a block: its TOC id and the type it is sent as.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Op {
    /// TOC id.
    pub var: u16,
    /// Log type it is sent as.
    pub fetch: u8,
}

/// One block.
#[derive(Debug, Clone)]
pub struct Block {
    /// The client's id for it.
    pub id: u8,
    /// Its variables, in order.
    pub ops: heapless::Vec<Op, MAX_BLOCK_BYTES>,
    /// Its period while started, ms (`None`: stopped).
    pub period_ms: Option<u16>,
    /// When it is next sent, µs.
    pub due_us: u64,
}

impl Block {
    /// Bytes of its values.
    fn bytes(&self) -> usize {
        self.ops.iter().filter_map(|o| size_of(o.fetch)).sum()
    }
}

/// The blocks of one session.
#[derive(Debug, Clone, Default)]
pub struct LogBlocks {
    blocks: heapless::Vec<Block, MAX_BLOCKS>,
}

impl LogBlocks {
    /// No blocks.
    pub const fn new() -> Self {
        Self {
            blocks: heapless::Vec::new(),
        }
    }

    /// The blocks.
    pub fn blocks(&self) -> &[Block] {
        &self.blocks
    }

    fn ops_in_use(&self) -> usize {
        self.blocks.iter().map(|b| b.ops.len()).sum()
    }

    fn find(&mut self, id: u8) -> Option<&mut Block> {
        self.blocks.iter_mut().find(|b| b.id == id)
    }

    /// Creates block `id` with the variables in `settings` (three bytes
    /// each: the type byte, whose low nibble is the type to send, and the
    /// TOC id); `vars` is the TOC's size. Returns 0 or the error code.
    pub fn create(&mut self, id: u8, settings: &[u8], vars: u16) -> u8 {
        if self.blocks.iter().any(|b| b.id == id) {
            return EEXIST;
        }
        let block = Block {
            id,
            ops: heapless::Vec::new(),
            period_ms: None,
            due_us: 0,
        };
        if self.blocks.push(block).is_err() {
            return ENOMEM;
        }
        self.append(id, settings, vars)
    }

    /// Appends the variables in `settings` to block `id` (as
    /// [`LogBlocks::create`]). The ones before a refusal stay appended,
    /// as in the firmware. Returns 0 or the error code.
    pub fn append(&mut self, id: u8, settings: &[u8], vars: u16) -> u8 {
        let in_use = self.ops_in_use();
        let Some(block) = self.find(id) else {
            return ENOENT;
        };
        for (in_use, s) in (in_use..).zip(settings.chunks(3)) {
            let [t, lo, hi] = *s else {
                return ENOEXEC;
            };
            let var = u16::from_le_bytes([lo, hi]);
            let fetch = t & 0x0F;
            let Some(n) = size_of(fetch) else {
                return ENOEXEC;
            };
            if block.bytes() + n > MAX_BLOCK_BYTES {
                return E2BIG;
            }
            // A raw memory address (id 0xFFFF) or an id past the table.
            if var >= vars {
                return ENOENT;
            }
            if in_use >= MAX_OPS || block.ops.push(Op { var, fetch }).is_err() {
                return ENOMEM;
            }
        }
        0
    }

    /// Deletes block `id`. Returns 0 or [`ENOENT`].
    pub fn delete(&mut self, id: u8) -> u8 {
        match self.blocks.iter().position(|b| b.id == id) {
            Some(i) => {
                self.blocks.swap_remove(i);
                0
            }
            None => ENOENT,
        }
    }

    /// Starts block `id` every `period_ms` from `now_us` (0: once, now).
    /// Returns 0 or [`ENOENT`].
    pub fn start(&mut self, id: u8, period_ms: u16, now_us: u64) -> u8 {
        match self.find(id) {
            Some(b) => {
                b.period_ms = Some(period_ms);
                b.due_us = now_us;
                0
            }
            None => ENOENT,
        }
    }

    /// Stops block `id`. Returns 0 or [`ENOENT`].
    pub fn stop(&mut self, id: u8) -> u8 {
        match self.find(id) {
            Some(b) => {
                b.period_ms = None;
                0
            }
            None => ENOENT,
        }
    }

    /// Deletes every block.
    pub fn reset(&mut self) {
        self.blocks.clear();
    }

    /// A started block is due at `now_us` (so the values need reading).
    pub fn any_due(&self, now_us: u64) -> bool {
        self.blocks.iter().any(|b| b.period_ms.is_some() && b.due_us <= now_us)
    }

    /// The data packet of the first block due at `now_us` (its next time
    /// set; a block started with period 0 stops after it), with the values
    /// `value(var)` gives; `None` when none is due. Call until `None`.
    pub fn next_due(&mut self, now_us: u64, value: impl Fn(u16) -> f32) -> Option<Packet> {
        let b = self
            .blocks
            .iter_mut()
            .find(|b| b.period_ms.is_some() && b.due_us <= now_us)?;
        let period_us = u64::from(b.period_ms.unwrap_or(0)) * 1000;
        if period_us == 0 {
            b.period_ms = None;
        } else {
            // On its grid; a block that fell behind (a slow host) skips ahead.
            b.due_us += period_us;
            if b.due_us <= now_us {
                b.due_us = now_us + period_us;
            }
        }
        let ms = ((now_us / 1000) as u32).to_le_bytes();
        let mut p = Packet::new(Port::Log, 2, &[b.id, ms[0], ms[1], ms[2]]).ok()?;
        let mut buf = [0u8; 4];
        for op in &b.ops {
            let n = encode(value(op.var), op.fetch, &mut buf)?;
            p.extend(&buf[..n]).ok()?;
        }
        Some(p)
    }
}

/// The answer to a log control command: `[command, block id, error code]`.
pub fn control_reply(command: u8, id: u8, code: u8) -> Result<Packet, CrtpError> {
    Packet::new(Port::Log, 1, &[command, id, code])
}
