//! `--storage FILE`: the flight controller's persistent settings in a file
//! standing for its flash ([`fc_storage`]'s store, the same code as on the
//! vehicle, over [`FileFlash`]).

use anyhow::{Context, Result};
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use fc_storage::{Boot, Journaled, RamFlash, RamFlashError, Store};
use std::path::{Path, PathBuf};

/// The file's size: 32 KiB of NOR flash (1 KiB pages, 32-bit words), the
/// last page the store's erase journal.
pub const FILE_BYTES: usize = 32 * 1024;

/// A NOR flash kept in a file: [`RamFlash`]'s rules, every write and erase
/// written through to the file (a whole new file, renamed over the old, so
/// a host that dies mid-write leaves the last whole one).
pub struct FileFlash {
    ram: Box<RamFlash<FILE_BYTES>>,
    path: PathBuf,
}

/// A [`FileFlash`] access that failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileFlashError {
    /// Refused by the NOR rules.
    Flash(RamFlashError),
    /// The file could not be written.
    File,
}

impl embedded_storage_async::nor_flash::NorFlashError for FileFlashError {
    fn kind(&self) -> embedded_storage_async::nor_flash::NorFlashErrorKind {
        match self {
            FileFlashError::Flash(e) => e.kind(),
            FileFlashError::File => embedded_storage_async::nor_flash::NorFlashErrorKind::Other,
        }
    }
}

impl FileFlash {
    /// The flash in `path`: its bytes if the file exists (a file of another
    /// size is taken as it is, cut or padded with erased bytes; the store
    /// then finds it foreign), erased flash if not.
    pub fn open(path: &Path) -> Result<Self> {
        let ram = match std::fs::read(path) {
            Ok(bytes) => RamFlash::holding(&bytes),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => RamFlash::blank(),
            Err(e) => return Err(e).with_context(|| format!("reading --storage {}", path.display())),
        };
        Ok(Self {
            ram: Box::new(ram),
            path: path.to_path_buf(),
        })
    }

    fn sync(&self) -> Result<(), FileFlashError> {
        let tmp = self.path.with_extension("tmp");
        std::fs::write(&tmp, self.ram.bytes())
            .and_then(|()| std::fs::rename(&tmp, &self.path))
            .map_err(|_| FileFlashError::File)
    }
}

impl ErrorType for FileFlash {
    type Error = FileFlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = 1;
    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FileFlashError> {
        self.ram.read(offset, bytes).await.map_err(FileFlashError::Flash)
    }
    fn capacity(&self) -> usize {
        FILE_BYTES
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = <RamFlash<FILE_BYTES> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <RamFlash<FILE_BYTES> as NorFlash>::ERASE_SIZE;
    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FileFlashError> {
        self.ram.erase(from, to).await.map_err(FileFlashError::Flash)?;
        self.sync()
    }
    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FileFlashError> {
        self.ram.write(offset, bytes).await.map_err(FileFlashError::Flash)?;
        self.sync()
    }
}

/// The settings store over a file: its last page is the store's erase
/// journal ([`fc_storage::Journaled`]), the rest the store.
pub type FileStore = Store<Journaled<FileFlash>>;

/// The erase journal's page: the file's last.
const JOURNAL: std::ops::Range<u32> = (FILE_BYTES - RamFlash::<FILE_BYTES>::PAGE) as u32..FILE_BYTES as u32;

/// The settings store in `path` (made if missing), and what opening it
/// found, said on stderr as `storage: FILE: …` (`who`: the command).
pub fn open(path: &Path, who: &str) -> Result<(FileStore, Boot)> {
    let flash = FileFlash::open(path)?;
    let fail = |e: &dyn std::fmt::Display| anyhow::anyhow!("--storage {}: {e}", path.display());
    let (flash, finished) = Journaled::open(flash, JOURNAL).map_err(|e| fail(&e))?;
    let (store, boot) = Store::open(flash, 0..JOURNAL.start).map_err(|e| fail(&e))?;
    let finished = if finished {
        "an erase a power cut left undone finished; "
    } else {
        ""
    };
    eprintln!("{who}: storage {}: {finished}{boot}", path.display());
    Ok((store, boot))
}
