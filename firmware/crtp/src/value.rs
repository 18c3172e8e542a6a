//! A parameter's value on the param port: its type byte (cflib's
//! `ParamTocElement.types`) and its bytes, as the param port's reads and
//! writes and the persistent store's answers ([`crate::persist`]) carry it.

use crate::{f32_at, Packet};

/// Param type bytes (cflib's `ParamTocElement.types`).
pub mod param_types {
    /// `uint8_t`.
    pub const U8: u8 = 0x08;
    /// `uint16_t`.
    pub const U16: u8 = 0x09;
    /// `float`.
    pub const FLOAT: u8 = 0x06;
    /// Flag: read-only (`PARAM_RONLY`); cflib refuses to write it.
    pub const RONLY: u8 = 0x40;
    /// Flag: extended type information (`PARAM_EXTENDED`); cflib asks for
    /// it, and ours says "persistent".
    pub const EXTENDED: u8 = 0x10;
    /// The type's bits (size, integer or float, signedness) under the flags.
    pub const TYPE: u8 = 0x0F;
}

/// Whether param types `a` and `b` are the same type, their flags apart.
pub(crate) fn same_type(a: u8, b: u8) -> bool {
    a & param_types::TYPE == b & param_types::TYPE
}

/// Appends `v` to `r` as parameter type `t` (its flags ignored): a byte
/// for `uint8_t`, two little-endian bytes for `uint16_t`, four for `float`.
pub(crate) fn put_typed(r: &mut Packet, t: u8, v: f32) {
    let _ = match t & param_types::TYPE {
        param_types::U8 => r.extend(&[v as u8]),
        param_types::U16 => r.extend(&(v as u16).to_le_bytes()),
        _ => r.extend(&v.to_le_bytes()),
    };
}

/// `[f32]` from the start of `b` as parameter type `t`.
pub(crate) fn read_value(t: u8, b: &[u8]) -> Option<f32> {
    match t & param_types::TYPE {
        param_types::U8 => b.first().map(|&v| f32::from(v)),
        param_types::U16 => b.get(..2).map(|v| f32::from(u16::from_le_bytes([v[0], v[1]]))),
        param_types::FLOAT => f32_at(b, 0),
        _ => None,
    }
}
