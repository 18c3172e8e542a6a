//! Framing: `COBS(postcard(msg) ‖ CRC-32C) 0x00`, and a byte-at-a-time
//! decoder with a fixed buffer that never panics and never allocates.

use crc::{Crc, CRC_32_ISCSI};
use serde::{de::DeserializeOwned, Serialize};

const CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// Largest encoded frame (including the delimiter), bytes. The biggest
/// message (a sensor frame) needs ≈ 70.
pub const MAX_FRAME: usize = 128;
/// Largest payload before COBS (message + CRC).
const MAX_RAW: usize = MAX_FRAME - 2 - MAX_FRAME / 254;

/// Why a frame was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Longer than [`MAX_FRAME`]; dropped up to the next delimiter.
    Oversized,
    /// Invalid COBS or empty.
    Cobs,
    /// Shorter than a CRC, or the CRC did not match.
    Crc,
    /// The payload is not a message of the expected type.
    Message,
    /// The output buffer is too small (encoder only).
    BufferTooSmall,
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FrameError::Oversized => "frame longer than 128 bytes (dropped up to the next delimiter)",
            FrameError::Cobs => "invalid COBS encoding or empty frame",
            FrameError::Crc => "frame shorter than its CRC, or CRC-32C mismatch",
            FrameError::Message => "payload is not a message of the expected type",
            FrameError::BufferTooSmall => "output buffer too small for the frame",
        })
    }
}

impl core::error::Error for FrameError {}

/// Encodes `msg` as one frame into `out`; returns the frame length
/// (delimiter included).
pub fn encode<T: Serialize>(msg: &T, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut raw = [0u8; MAX_RAW];
    let n = postcard::to_slice(msg, &mut raw[..MAX_RAW - 4])
        .map_err(|_| FrameError::BufferTooSmall)?
        .len();
    let crc = CRC.checksum(&raw[..n]);
    raw[n..n + 4].copy_from_slice(&crc.to_le_bytes());
    let len = cobs::try_encode(&raw[..n + 4], out).map_err(|_| FrameError::BufferTooSmall)?;
    let slot = out.get_mut(len).ok_or(FrameError::BufferTooSmall)?;
    *slot = 0;
    Ok(len + 1)
}

/// Accumulates bytes into frames. `CAP` bounds the memory (heapless style)
/// and the frame: at most `CAP` bytes with the delimiter; a longer one is
/// dropped up to its delimiter as [`FrameError::Oversized`].
#[derive(Debug, Clone)]
pub struct FrameDecoder<const CAP: usize = MAX_FRAME> {
    buf: heapless::Vec<u8, CAP>,
    overflow: bool,
}

impl<const CAP: usize> Default for FrameDecoder<CAP> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const CAP: usize> FrameDecoder<CAP> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: heapless::Vec::new(),
            overflow: false,
        }
    }

    /// Feeds one byte. At a delimiter, returns the decoded message or why the
    /// frame was dropped; otherwise `None`.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        if byte != 0 {
            // At most CAP bytes per frame with its delimiter: CAP − 1 before it.
            if self.buf.len() + 1 >= CAP || self.buf.push(byte).is_err() {
                self.overflow = true;
            }
            return None;
        }
        if core::mem::take(&mut self.overflow) {
            self.buf.clear();
            return Some(Err(FrameError::Oversized));
        }
        if self.buf.is_empty() {
            // Back-to-back delimiters: a resync, not a frame.
            return None;
        }
        let out = Self::decode_frame(&mut self.buf);
        self.buf.clear();
        Some(out)
    }

    fn decode_frame<T: DeserializeOwned>(buf: &mut [u8]) -> Result<T, FrameError> {
        let n = cobs::decode_in_place(buf).map_err(|_| FrameError::Cobs)?;
        if n < 5 {
            return Err(if n == 0 { FrameError::Cobs } else { FrameError::Crc });
        }
        let (payload, tail) = buf[..n].split_at(n - 4);
        let mut crc_bytes = [0u8; 4];
        crc_bytes.copy_from_slice(tail);
        if CRC.checksum(payload) != u32::from_le_bytes(crc_bytes) {
            return Err(FrameError::Crc);
        }
        match postcard::take_from_bytes::<T>(payload) {
            Ok((msg, [])) => Ok(msg),
            _ => Err(FrameError::Message),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ToFc, WireSetpoint};

    fn decode_all(bytes: &[u8]) -> Vec<Result<ToFc, FrameError>> {
        let mut d = FrameDecoder::<MAX_FRAME>::new();
        bytes.iter().filter_map(|b| d.push(*b)).collect()
    }

    fn sensor(seq: u32) -> ToFc {
        ToFc::Sensor {
            seq,
            t_us: 1234567,
            state: [0.5; 13],
        }
    }

    #[test]
    fn round_trip_and_bounds() {
        let mut out = [0u8; MAX_FRAME];
        for msg in [
            sensor(7),
            ToFc::Hello { version: 1 },
            ToFc::Setpoint(WireSetpoint {
                pos: [3.0, 2.0, -5.0],
                vel: [0.0; 3],
                acc: [0.0; 3],
                jerk: [0.0; 3],
                yaw: 0.26,
                yaw_rate: 0.0,
            }),
        ] {
            let n = encode(&msg, &mut out).unwrap();
            assert!(n <= MAX_FRAME && out[n - 1] == 0 && !out[..n - 1].contains(&0));
            assert_eq!(decode_all(&out[..n]), vec![Ok(msg)]);
        }
    }

    /// The largest messages of protocols v4 and v5, every optional part
    /// present and every varint at its longest, fit one frame.
    #[test]
    fn the_largest_v4_and_v5_messages_fit_a_frame() {
        use crate::{FromFc, WireFix};
        let mut out = [0u8; MAX_FRAME];
        let fix = ToFc::Fix(WireFix {
            age_us: u32::MAX,
            pos: Some([1.5; 3]),
            pos_sigma: [0.002; 3],
            vel: Some([0.5; 3]),
            vel_sigma: 0.05,
            yaw: Some(1.0),
            yaw_sigma: 0.01,
            alt: Some(5.0),
            alt_sigma: 0.1,
        });
        let imu = ToFc::Imu {
            seq: u32::MAX,
            t_us: u64::MAX,
            gyro: [1.0; 3],
            accel: [-9.81; 3],
        };
        for msg in [fix, imu] {
            let n = encode(&msg, &mut out).unwrap();
            assert_eq!(decode_all(&out[..n]), vec![Ok(msg)]);
        }
        let nav = FromFc::Nav {
            seq: u32::MAX,
            mode: 2,
            pos: [1.0; 3],
            vel: [1.0; 3],
            att: [1.0, 0.0, 0.0, 0.0],
            sigma: [0.1; 9],
            imu_rejected: u32::MAX,
            fixes_rejected: u32::MAX,
            failsafe_entries: u32::MAX,
        };
        let bias = FromFc::NavBias {
            seq: u32::MAX,
            gyro_bias: [0.01; 3],
            accel_bias: [-0.1; 3],
            sigma: [0.001; 6],
        };
        for msg in [nav, bias] {
            let n = encode(&msg, &mut out).unwrap();
            assert!(n <= MAX_FRAME);
            let mut d = FrameDecoder::<MAX_FRAME>::new();
            let got: Vec<_> = out[..n].iter().filter_map(|&b| d.push::<FromFc>(b)).collect();
            assert_eq!(got, vec![Ok(msg)]);
        }
    }

    #[test]
    fn corrupt_truncated_oversized_and_garbage_are_dropped() {
        let mut out = [0u8; MAX_FRAME];
        let n = encode(&sensor(1), &mut out).unwrap();
        // Flip one bit anywhere in the body: the CRC (or COBS) catches it.
        for i in 0..n - 1 {
            let mut f = out[..n].to_vec();
            f[i] ^= 0x10;
            if f[i] == 0 {
                continue; // would split the frame; covered by truncation below
            }
            let r = decode_all(&f);
            assert_eq!(r.len(), 1);
            assert!(
                matches!(
                    r[0],
                    Err(FrameError::Crc) | Err(FrameError::Cobs) | Err(FrameError::Message)
                ),
                "{i}: {r:?}"
            );
        }
        // Truncated: the first half then a delimiter.
        let mut t = out[..n / 2].to_vec();
        t.push(0);
        assert!(decode_all(&t)[0].is_err());
        // Oversized: 300 non-zero bytes, then a good frame still decodes.
        let mut big = vec![0x55u8; 300];
        big.push(0);
        big.extend_from_slice(&out[..n]);
        assert_eq!(decode_all(&big), vec![Err(FrameError::Oversized), Ok(sensor(1))]);
        // Empty frames are resyncs, not errors.
        assert!(decode_all(&[0, 0, 0]).is_empty());
    }

    #[test]
    fn a_frame_is_at_most_max_frame_bytes_with_its_delimiter() {
        // 127 bytes and the delimiter: read (and rejected for its content);
        // 128 and the delimiter: oversized.
        for (body, oversized) in [(MAX_FRAME - 1, false), (MAX_FRAME, true)] {
            let mut f = vec![0x55u8; body];
            f.push(0);
            let r = decode_all(&f);
            assert_eq!(r.len(), 1);
            assert_eq!(r[0] == Err(FrameError::Oversized), oversized, "{body}: {r:?}");
        }
    }
}
