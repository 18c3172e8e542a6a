//! Port mem (4), as the Crazyflie's `crtp_mem.c` and cflib speak it: one
//! memory, the high-level commander's trajectory memory
//! ([`fc_loop::trajectory::TrajectoryMemory`], cflib's `TYPE_TRAJ`), listed
//! on channel 0, read on channel 1 and written on channel 2 in chunks of at
//! most [`CHUNK_BYTES`]. Each read and write is answered with its memory's
//! id, its address and a status (0: done); a refused one is said on the
//! console by name and nothing is written.

use crate::vehicle::*;
use fc_loop::trajectory::{TrajectoryError, MEMORY_BYTES};

/// The trajectory memory's id: the only memory listed.
const TRAJECTORY_MEMORY_ID: u8 = 0;
/// cflib's memory type of a trajectory memory (`MemoryElement.TYPE_TRAJ`).
const TYPE_TRAJ: u8 = 0x12;
/// Most data bytes one read or write carries (cflib's `MAX_DATA_LENGTH`:
/// the 30-byte payload less the id, address and status).
pub(in crate::vehicle) const CHUNK_BYTES: usize = 24;

/// Channel 0's commands (`crtp_mem.c`'s `CMD_INFO_*`).
mod info {
    pub const VERSION: u8 = 0;
    pub const COUNT: u8 = 1;
    pub const DETAILS: u8 = 2;
}

/// The statuses of an answered read or write, as `errno` values
/// (the Crazyflie's `EIO` for a memory that could not do it).
mod status {
    pub const DONE: u8 = 0;
    /// No memory with that id (`ENOENT`).
    pub const NO_SUCH_MEMORY: u8 = 2;
    /// Past the end, or a chunk too long (`EIO`).
    pub const OUT_OF_RANGE: u8 = 5;
    /// A trajectory flies from the memory (`EBUSY`).
    pub const BUSY: u8 = 16;
}

fn status_of(e: TrajectoryError) -> u8 {
    match e {
        TrajectoryError::Flying => status::BUSY,
        _ => status::OUT_OF_RANGE,
    }
}

impl CrtpShared {
    pub(in crate::vehicle) fn on_mem<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = p.payload();
        let Some(&first) = d.first() else {
            return Ok(Err(short(p)));
        };
        match p.channel() {
            0 => match first {
                info::VERSION => out.send(&reply(Port::Mem, 0, &[info::VERSION, 1]))?,
                info::COUNT => out.send(&reply(Port::Mem, 0, &[info::COUNT, 1]))?,
                info::DETAILS => {
                    let Some(&id) = d.get(1) else {
                        return Ok(Err(short(p)));
                    };
                    if id != TRAJECTORY_MEMORY_ID {
                        // The Crazyflie's answer for an id it lacks: no details.
                        out.send(&reply(Port::Mem, 0, &[info::DETAILS, id]))?;
                        return Ok(Err(CrtpError::BadValue { port: p.port() }));
                    }
                    let mut b = [0u8; 15];
                    b[..3].copy_from_slice(&[info::DETAILS, id, TYPE_TRAJ]);
                    b[3..7].copy_from_slice(&(MEMORY_BYTES as u32).to_le_bytes());
                    out.send(&reply(Port::Mem, 0, &b))?;
                }
                _ => return Ok(Err(unsupported(p))),
            },
            // Read: id, address (u32), length (u8); answered with the data.
            1 => {
                let (Some(addr), Some(&len)) = (u32_at(d, 1), d.get(5)) else {
                    return Ok(Err(short(p)));
                };
                let len = usize::from(len);
                let mut b = [0u8; 6 + CHUNK_BYTES];
                b[..5].copy_from_slice(&d[..5]);
                let got = if first != TRAJECTORY_MEMORY_ID {
                    Err(status::NO_SUCH_MEMORY)
                } else if len > CHUNK_BYTES {
                    Err(status::OUT_OF_RANGE)
                } else {
                    self.client.trajectory_memory().read(addr, len).map_err(status_of)
                };
                let refused = match got {
                    Ok(data) => {
                        b[6..6 + len].copy_from_slice(data);
                        out.send(&reply(Port::Mem, 1, &b[..6 + len]))?;
                        return Ok(Ok(()));
                    }
                    Err(s) => s,
                };
                b[5] = refused;
                out.send(&reply(Port::Mem, 1, &b[..6]))?;
                return Ok(Err(CrtpError::BadValue { port: p.port() }));
            }
            // Write: id, address (u32), data; answered with a status.
            2 => {
                let Some(addr) = u32_at(d, 1) else {
                    return Ok(Err(short(p)));
                };
                let data = &d[5..];
                let done = if first != TRAJECTORY_MEMORY_ID {
                    Err(status::NO_SUCH_MEMORY)
                } else {
                    self.client.write_trajectory_memory(addr, data).map_err(|e| {
                        self.say(format_args!("trajectory memory write at {addr}: {e}"));
                        status_of(e)
                    })
                };
                let mut b = [0u8; 6];
                b[..5].copy_from_slice(&d[..5]);
                b[5] = done.err().unwrap_or(status::DONE);
                out.send(&reply(Port::Mem, 2, &b))?;
                if done.is_err() {
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
            }
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }
}
