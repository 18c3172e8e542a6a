#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

use core::ops::Range;
use embedded_storage_async::nor_flash::NorFlash;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

mod journal;
mod ram;
pub use journal::{Journaled, JournaledError, JOURNAL_MARK};
pub use ram::{RamFlash, RamFlashError};

/// Largest record: a key (2 bytes) and the signing record (40), with the
/// crate's item header and word alignment (up to 32-byte words).
const BUFFER: usize = 128;

/// Where the signing key lives among the keys (parameters use their index,
/// below it).
const SIGNING_KEY: u16 = 0x8000;

/// The key of the store's own mark: [`MARK`], written when a store is made.
const MARK_KEY: u16 = 0xFFFF;

/// A parameter's value that says "none stored" (a NaN: no parameter takes
/// one).
const REMOVED: u32 = 0x7FC0_0DE1;

/// "fc-storage, layout 1": a range without it holds something else.
const MARK: u32 = 0xFC57_0001;

/// What [`Store::open`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Boot {
    /// A store of this layout: its settings are read.
    Found,
    /// The range was blank: a new, empty store.
    Created,
    /// The range held something else (no mark: another program's data or
    /// noise) or could not be read (the error, given): it was erased and an
    /// empty store made; every setting is at its default.
    Erased(StoreError),
}

impl core::fmt::Display for Boot {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Boot::Found => write!(f, "settings found in flash"),
            Boot::Created => write!(f, "blank flash: a new settings store, defaults"),
            Boot::Erased(e) => write!(f, "{e}: settings erased, defaults"),
        }
    }
}

/// Why the store could not do what was asked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreError {
    /// The flash range is not whole erase pages, or fewer than two.
    BadRange,
    /// The flash driver failed (a read, a write or an erase).
    Flash,
    /// Full: nothing more can be stored until items are removed.
    Full,
    /// The contents are not a store (foreign or corrupt data); erasing the
    /// range starts a new one.
    Corrupted,
    /// A stored value does not decode as its kind (a store of another
    /// version).
    Value,
    /// Refused while the vehicle is armed: writing the flash stalls every
    /// flash read, the control loop's included.
    Armed,
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            StoreError::BadRange => "the storage range is not at least two whole flash pages",
            StoreError::Flash => "the flash failed to read, write or erase",
            StoreError::Full => "the storage is full",
            StoreError::Corrupted => "the storage holds corrupt or foreign data",
            StoreError::Value => "a stored value does not decode as its kind",
            StoreError::Armed => "not while armed: writing the flash stalls the control loop",
        })
    }
}

impl<E> From<sequential_storage::Error<E>> for StoreError {
    fn from(e: sequential_storage::Error<E>) -> Self {
        use sequential_storage::Error as E;
        match e {
            E::Storage { .. } => StoreError::Flash,
            E::FullStorage | E::ItemTooBig => StoreError::Full,
            E::Corrupted { .. } | E::LogicBug { .. } => StoreError::Corrupted,
            _ => StoreError::Value,
        }
    }
}

/// What a flight controller keeps across a reboot, whatever keeps it: the
/// protocols ask this (a link's owner hands it over), so that they need not
/// know the flash. [`Store`] is the one over NOR flash.
pub trait Persist {
    /// The value stored for parameter `index` (its place in the parameter
    /// table), if any.
    fn param(&mut self, index: u16) -> Result<Option<f32>, StoreError>;
    /// Stores `value` for parameter `index`, replacing the last.
    fn set_param(&mut self, index: u16, value: f32) -> Result<(), StoreError>;
    /// Forgets the value stored for parameter `index` (its default rules
    /// at the next boot).
    fn remove_param(&mut self, index: u16) -> Result<(), StoreError>;
    /// The MAVLink signing key and its timestamp (10 µs since 2015), if stored.
    fn signing(&mut self) -> Result<Option<([u8; 32], u64)>, StoreError>;
    /// Stores the signing key and its timestamp.
    fn set_signing(&mut self, key: &[u8; 32], timestamp: u64) -> Result<(), StoreError>;
}

/// The persistent settings, in `range` of the flash `F`.
pub struct Store<F: NorFlash> {
    map: MapStorage<u16, F, Cache<Uncached, Uncached, Uncached, u16>>,
    buf: [u8; BUFFER],
}

impl<F: NorFlash> Store<F> {
    /// The store in `range` of `flash` (whole erase pages, at least two).
    /// Nothing is read until asked: a blank range is an empty store.
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, StoreError> {
        let config = MapConfig::try_new(range).map_err(|_| StoreError::BadRange)?;
        Ok(Self {
            map: MapStorage::new(flash, config, Cache::new_uncached()),
            buf: [0; BUFFER],
        })
    }

    /// Opens the store in `range` of `flash`: a store of this layout is
    /// kept; a blank range gets a new one; anything else (foreign data,
    /// noise, a store that cannot be read) is erased for a new one, and
    /// [`Boot`] says which. Err only if the flash itself fails.
    pub fn open(flash: F, range: Range<u32>) -> Result<(Self, Boot), StoreError> {
        let mut s = Self::new(flash, range.clone())?;
        let mark: Result<Option<u32>, StoreError> =
            embassy_futures::block_on(s.map.fetch_item(&mut s.buf, &MARK_KEY)).map_err(StoreError::from);
        let boot = match mark {
            Ok(Some(MARK)) => return Ok((s, Boot::Found)),
            Ok(_) => {
                let mut flash = s.into_flash();
                let blank = is_blank(&mut flash, range.clone())?;
                s = Self::new(flash, range)?;
                if blank {
                    Boot::Created
                } else {
                    Boot::Erased(StoreError::Corrupted)
                }
            }
            Err(StoreError::Flash) => return Err(StoreError::Flash),
            Err(e) => Boot::Erased(e),
        };
        if boot != Boot::Created {
            s.clear()?;
        }
        embassy_futures::block_on(s.map.store_item(&mut s.buf, &MARK_KEY, &MARK))?;
        Ok((s, boot))
    }

    /// The value stored for parameter `index`, if any.
    pub fn param(&mut self, index: u16) -> Result<Option<f32>, StoreError> {
        if index >= SIGNING_KEY {
            return Err(StoreError::Value);
        }
        let v = embassy_futures::block_on(self.map.fetch_item::<f32>(&mut self.buf, &index))?;
        Ok(v.filter(|v| v.to_bits() != REMOVED))
    }

    /// Stores `value` for parameter `index` (it replaces the last), then
    /// reads it back: [`StoreError::Corrupted`] if the store gives another
    /// value (damage in its bookkeeping; [`Store::clear`] starts afresh).
    pub fn set_param(&mut self, index: u16, value: f32) -> Result<(), StoreError> {
        if index >= SIGNING_KEY || value.to_bits() == REMOVED {
            return Err(StoreError::Value);
        }
        embassy_futures::block_on(self.map.store_item(&mut self.buf, &index, &value))?;
        match self.param(index)? {
            Some(v) if v.to_bits() == value.to_bits() => Ok(()),
            _ => Err(StoreError::Corrupted),
        }
    }

    /// Forgets parameter `index`'s stored value (nothing if none).
    pub fn remove_param(&mut self, index: u16) -> Result<(), StoreError> {
        if index >= SIGNING_KEY {
            return Err(StoreError::Value);
        }
        // Stored as "none" rather than removed: removal needs a flash that
        // takes a second write over a word, which not every NOR does.
        embassy_futures::block_on(self.map.store_item(&mut self.buf, &index, &f32::from_bits(REMOVED)))?;
        match self.param(index)? {
            None => Ok(()),
            Some(_) => Err(StoreError::Corrupted),
        }
    }

    /// The MAVLink signing key and its timestamp, if stored.
    pub fn signing(&mut self) -> Result<Option<([u8; 32], u64)>, StoreError> {
        let r: Option<[u8; 40]> = embassy_futures::block_on(self.map.fetch_item(&mut self.buf, &SIGNING_KEY))?;
        Ok(r.map(|b| {
            let mut key = [0u8; 32];
            key.copy_from_slice(&b[..32]);
            let mut ts = [0u8; 8];
            ts.copy_from_slice(&b[32..]);
            (key, u64::from_le_bytes(ts))
        }))
    }

    /// Stores the signing `key` and `timestamp` (an all-zero key with
    /// timestamp 0 is no key, as PX4's blank key file), then reads them
    /// back, as [`Store::set_param`] does.
    pub fn set_signing(&mut self, key: &[u8; 32], timestamp: u64) -> Result<(), StoreError> {
        let mut b = [0u8; 40];
        b[..32].copy_from_slice(key);
        b[32..].copy_from_slice(&timestamp.to_le_bytes());
        embassy_futures::block_on(self.map.store_item(&mut self.buf, &SIGNING_KEY, &b))?;
        match self.signing()? {
            Some((k, t)) if k == *key && t == timestamp => Ok(()),
            _ => Err(StoreError::Corrupted),
        }
    }

    /// Erases the whole range: every setting back to its default (the
    /// store's mark included: [`Store::open`] makes a new one).
    pub fn clear(&mut self) -> Result<(), StoreError> {
        Ok(embassy_futures::block_on(self.map.erase_all())?)
    }

    /// The flash back, the store closed.
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }
}

impl<F: NorFlash> Persist for Store<F> {
    fn param(&mut self, index: u16) -> Result<Option<f32>, StoreError> {
        Store::param(self, index)
    }
    fn set_param(&mut self, index: u16, value: f32) -> Result<(), StoreError> {
        Store::set_param(self, index, value)
    }
    fn remove_param(&mut self, index: u16) -> Result<(), StoreError> {
        Store::remove_param(self, index)
    }
    fn signing(&mut self) -> Result<Option<([u8; 32], u64)>, StoreError> {
        Store::signing(self)
    }
    fn set_signing(&mut self, key: &[u8; 32], timestamp: u64) -> Result<(), StoreError> {
        Store::set_signing(self, key, timestamp)
    }
}

/// Whether every byte of `range` reads erased (0xFF).
fn is_blank<F: NorFlash>(flash: &mut F, range: Range<u32>) -> Result<bool, StoreError> {
    let mut chunk = [0u8; 64];
    let mut at = range.start;
    while at < range.end {
        let n = chunk.len().min((range.end - at) as usize);
        // READ_SIZE divides 64 for every flash of interest (1 to 32 bytes).
        embassy_futures::block_on(flash.read(at, &mut chunk[..n])).map_err(|_| StoreError::Flash)?;
        if chunk[..n].iter().any(|&b| b != 0xFF) {
            return Ok(false);
        }
        at += n as u32;
    }
    Ok(true)
}

#[cfg(test)]
mod tests;
