//! Tables of contents (TOC v2), as the Crazyflie's log and param ports
//! serve them: `GET_INFO_V2` answers the entry count and a CRC of the whole
//! table (cflib's cache key, so it changes with the table), `GET_ITEM_V2`
//! one entry: its id, its type byte, `group\0name\0`.

use crate::{CrtpError, Packet, Port};
use crc::{Crc, NoTable, CRC_32_ISO_HDLC};

/// Command: one entry (id as u16).
pub const CMD_GET_ITEM_V2: u8 = 2;
/// Command: count and CRC.
pub const CMD_GET_INFO_V2: u8 = 3;

/// The CRC-32 (IEEE) the TOC CRCs use, bit by bit: they are computed once,
/// when the vehicle is made, where a 1 KiB table would cost flash and save
/// no time that matters.
static CRC: Crc<u32, NoTable> = Crc::<u32, NoTable>::new(&CRC_32_ISO_HDLC);

/// One entry's name: its group and name as the client sees them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Name<'a> {
    /// Group (lower case for our own parameters).
    pub group: &'a str,
    /// Name within the group.
    pub name: &'a str,
    /// Write the group in lower case (our own parameters' prefixes).
    pub lower_group: bool,
}

impl Name<'_> {
    /// The bytes `group\0name\0` one at a time (the group lower-cased if asked).
    fn bytes(&self) -> impl Iterator<Item = u8> + '_ {
        let lower = self.lower_group;
        self.group
            .bytes()
            .map(move |b| if lower { b.to_ascii_lowercase() } else { b })
            .chain(core::iter::once(0))
            .chain(self.name.bytes())
            .chain(core::iter::once(0))
    }

    /// `group.name` equals `group` and `name` given separately (the
    /// group compared without case).
    pub fn is(&self, group: &[u8], name: &[u8]) -> bool {
        self.group.as_bytes().eq_ignore_ascii_case(group) && self.name.as_bytes() == name
    }
}

/// The CRC of a table of `count` entries as `item` serves them (each
/// entry's `GET_ITEM_V2` answer, [`item_packet`]): over every entry's type
/// byte and `group\0name\0`, so any change to the table changes it.
pub fn crc_of_items(count: u16, item: impl Fn(u16) -> Packet) -> u32 {
    let mut d = CRC.digest();
    for id in 0..count {
        let p = item(id);
        // After the command and the id.
        d.update(p.payload().get(3..).unwrap_or(&[]));
    }
    d.finalize()
}

/// The `GET_INFO_V2` answer on `port`: count and CRC, then `extra` (the
/// log port adds its block and variable capacities).
pub fn info_packet(port: Port, count: u16, crc: u32, extra: &[u8]) -> Result<Packet, CrtpError> {
    let mut p = Packet::new(port, 0, &[CMD_GET_INFO_V2])?;
    p.extend(&count.to_le_bytes())?;
    p.extend(&crc.to_le_bytes())?;
    p.extend(extra)?;
    Ok(p)
}

/// The `GET_ITEM_V2` answer on `port` for entry `id`: `Err` if the name is
/// too long for one packet (a table test keeps every name within it).
pub fn item_packet(port: Port, id: u16, type_byte: u8, name: &Name<'_>) -> Result<Packet, CrtpError> {
    let mut p = Packet::new(port, 0, &[CMD_GET_ITEM_V2])?;
    p.extend(&id.to_le_bytes())?;
    p.extend(&[type_byte])?;
    for b in name.bytes() {
        p.extend(&[b])?;
    }
    Ok(p)
}

/// The answer to an item request past the table's end: the command alone,
/// as the firmware answers it.
pub fn no_item_packet(port: Port) -> Packet {
    Packet::new(port, 0, &[CMD_GET_ITEM_V2]).unwrap_or(Packet::NULL)
}
