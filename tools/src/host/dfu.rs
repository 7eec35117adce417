//! A DFU partition in a file, for the firmware update over the PLC link
//! ([`protocol::plc::update`]): what the board's flash does for `Action::Update`, on a PC.
//!
//! The file is the partition, `size` bytes long. An erase fills the pages it covers with 0xFF
//! (2 KiB pages, the L475's); a write puts its bytes at their offset; FINISH reads the image back,
//! checks its CRC-32 and marks it for the bootloader by writing `PATH.marked` (`size crc32`, in
//! hex), which an erase removes. There is no bootloader on a PC: the mark is where a board's
//! would look.

use std::fs::{File, OpenOptions};
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use protocol::plc::update::{crc32, Target, UpdateJob};

/// The erase unit.
pub const PAGE: u64 = 2048;

/// The partition and the board id an image must name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DfuOptions {
    /// The file.
    pub path: PathBuf,
    /// Its size in bytes: the largest image.
    pub size: u32,
    /// The board id (BEGIN must name it).
    pub board: u16,
}

/// The partition, open.
pub struct DfuFile {
    file: File,
    path: PathBuf,
    size: u32,
    board: u16,
}

impl DfuFile {
    /// Opens (or creates) the file, `size` bytes long.
    pub fn open(options: &DfuOptions) -> io::Result<DfuFile> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&options.path)?;
        file.set_len(u64::from(options.size))?;
        Ok(DfuFile {
            file,
            path: options.path.clone(),
            size: options.size,
            board: options.board,
        })
    }

    /// What the node is told about it.
    pub fn target(&self) -> Target {
        Target {
            board: self.board,
            partition: self.size,
        }
    }

    /// Where the mark goes.
    pub fn mark_path(&self) -> PathBuf {
        marked(&self.path)
    }

    /// Carries out `job`; an error is reported to the node as a flash failure.
    pub fn carry_out(&mut self, job: &UpdateJob<'_>) -> io::Result<()> {
        match *job {
            UpdateJob::Erase { len } => {
                let end = u64::from(len)
                    .div_ceil(PAGE)
                    .saturating_mul(PAGE)
                    .min(u64::from(self.size));
                self.file.seek(SeekFrom::Start(0))?;
                let page = [0xFFu8; PAGE as usize];
                let mut left = end;
                while left > 0 {
                    let n = left.min(PAGE);
                    self.file.write_all(&page[..n as usize])?;
                    left -= n;
                }
                match std::fs::remove_file(self.mark_path()) {
                    Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
                    _ => {}
                }
            }
            UpdateJob::Write { offset, bytes } => {
                let end = u64::from(offset) + bytes.len() as u64;
                if end > u64::from(self.size) {
                    return Err(io::Error::other("a write past the partition"));
                }
                self.file.seek(SeekFrom::Start(u64::from(offset)))?;
                self.file.write_all(bytes)?;
            }
            UpdateJob::Finish { len, crc32: crc } => {
                let mut image = vec![0u8; len as usize];
                self.file.seek(SeekFrom::Start(0))?;
                self.file.read_exact(&mut image)?;
                if crc32(&image) != crc {
                    return Err(io::Error::other("the image read back has another CRC-32"));
                }
                self.file.sync_all()?;
                std::fs::write(self.mark_path(), format!("{len:x} {crc:08x}\n"))?;
            }
        }
        Ok(())
    }
}

/// The mark of the partition in `path`.
pub fn marked(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".marked");
    PathBuf::from(name)
}
