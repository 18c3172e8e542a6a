//! [`RamFlash`]: a NOR flash in RAM, the stand-in where there is no flash
//! to keep settings in (QEMU models no flash controller) and the base of
//! the host's file-backed flash.

use embedded_storage_async::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};

/// `N` bytes of NOR flash in RAM with the STM32F4's rules, scaled down:
/// pages of [`RamFlash::PAGE`] bytes erase to `0xFF`, writes are whole
/// 32-bit words and only clear bits (programming an already written word
/// again ANDs it, as the STM32F4 does without ECC). A stand-in: its
/// contents are lost when the power goes.
#[derive(Clone)]
pub struct RamFlash<const N: usize> {
    data: [u8; N],
}

/// Why a [`RamFlash`] access was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RamFlashError {
    /// Past the end.
    OutOfBounds,
    /// Not on a word (write) or page (erase) boundary.
    NotAligned,
}

impl core::fmt::Display for RamFlashError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RamFlashError::OutOfBounds => "flash access past the end",
            RamFlashError::NotAligned => "flash access not aligned to a word or page",
        })
    }
}

impl NorFlashError for RamFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            RamFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            RamFlashError::NotAligned => NorFlashErrorKind::NotAligned,
        }
    }
}

impl<const N: usize> Default for RamFlash<N> {
    fn default() -> Self {
        Self::blank()
    }
}

impl<const N: usize> RamFlash<N> {
    /// Erase page, bytes.
    pub const PAGE: usize = 1024;
    /// Write unit, bytes.
    pub const WORD: usize = 4;

    /// Erased flash (every byte `0xFF`). `N` must be whole pages.
    pub const fn blank() -> Self {
        assert!(
            N.is_multiple_of(Self::PAGE) && N >= 2 * Self::PAGE,
            "whole pages, at least two"
        );
        Self { data: [0xFF; N] }
    }

    /// Flash holding `bytes` (the rest erased; a longer `bytes` is cut).
    pub fn holding(bytes: &[u8]) -> Self {
        let mut f = Self::blank();
        let n = bytes.len().min(N);
        f.data[..n].copy_from_slice(&bytes[..n]);
        f
    }

    /// The whole contents.
    pub fn bytes(&self) -> &[u8; N] {
        &self.data
    }

    fn span(offset: u32, len: usize) -> Result<core::ops::Range<usize>, RamFlashError> {
        let start = offset as usize;
        match start.checked_add(len) {
            Some(end) if end <= N => Ok(start..end),
            _ => Err(RamFlashError::OutOfBounds),
        }
    }
}

impl<const N: usize> ErrorType for RamFlash<N> {
    type Error = RamFlashError;
}

impl<const N: usize> ReadNorFlash for RamFlash<N> {
    const READ_SIZE: usize = 1;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RamFlashError> {
        let r = Self::span(offset, bytes.len())?;
        bytes.copy_from_slice(&self.data[r]);
        Ok(())
    }
    fn capacity(&self) -> usize {
        N
    }
}

impl<const N: usize> NorFlash for RamFlash<N> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = 1024;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), RamFlashError> {
        if from > to {
            return Err(RamFlashError::OutOfBounds);
        }
        let r = Self::span(from, (to - from) as usize)?;
        if !r.start.is_multiple_of(Self::PAGE) || !r.end.is_multiple_of(Self::PAGE) {
            return Err(RamFlashError::NotAligned);
        }
        self.data[r].fill(0xFF);
        Ok(())
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), RamFlashError> {
        let r = Self::span(offset, bytes.len())?;
        if !r.start.is_multiple_of(Self::WORD) || !bytes.len().is_multiple_of(Self::WORD) {
            return Err(RamFlashError::NotAligned);
        }
        self.data[r].iter_mut().zip(bytes).for_each(|(d, &b)| *d &= b);
        Ok(())
    }
}
