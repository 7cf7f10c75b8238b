//! Files on the host, through semihosting (QEMU with `-semihosting-config
//! enable=on,target=native`: the calls act on QEMU's own files, relative to its working
//! directory), and the command line QEMU was given for the program (`-semihosting-config
//! ...,arg=NAME,arg=...` or `-append`).
//!
//! Each call is a trap into the emulator: read and write in large pieces.

use cortex_m_semihosting::nr;

/// The longest path accepted (bytes, without the terminating NUL the call needs).
const MAX_PATH: usize = 255;

/// Why a host call failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HostError {
    /// The path is longer than [`MAX_PATH`] or holds a NUL.
    Path,
    /// The host refused to open the file.
    Open,
    /// A read failed.
    Read,
    /// The file ended before the bytes expected.
    EndOfFile,
    /// A write failed.
    Write,
    /// The command line could not be read, or is not text.
    CommandLine,
}

impl core::fmt::Display for HostError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            HostError::Path => "path too long (255 bytes at most) or holding a NUL",
            HostError::Open => "the host cannot open it",
            HostError::Read => "reading failed",
            HostError::EndOfFile => "it ends early",
            HostError::Write => "writing failed",
            HostError::CommandLine => "the host gave no readable command line",
        })
    }
}

/// How to open a file.
#[derive(Clone, Copy, Debug)]
pub enum Mode {
    /// Read, binary (`"rb"`).
    Read,
    /// Write, truncating or creating (`"wb"`).
    Write,
}

/// An open file on the host; closed when dropped.
pub struct HostFile {
    handle: usize,
}

impl HostFile {
    /// Opens `path` on the host.
    pub fn open(path: &str, mode: Mode) -> Result<HostFile, HostError> {
        let mut name = [0u8; MAX_PATH + 1];
        let bytes = path.as_bytes();
        if bytes.contains(&0) {
            return Err(HostError::Path);
        }
        name.get_mut(..bytes.len())
            .ok_or(HostError::Path)?
            .copy_from_slice(bytes);
        let mode = match mode {
            Mode::Read => nr::open::R_BINARY,
            Mode::Write => nr::open::W_TRUNC_BINARY,
        };
        // SAFETY: SYS_OPEN reads `len` bytes at the pointer and the NUL after them, all inside
        // `name`, which lives across the call; it writes no memory of ours.
        let handle = unsafe {
            cortex_m_semihosting::syscall(nr::OPEN, &[name.as_ptr() as usize, mode, bytes.len()])
        };
        if handle as isize == -1 {
            return Err(HostError::Open);
        }
        Ok(HostFile { handle })
    }

    /// Reads up to `buffer.len()` bytes; returns how many (0 at the end of the file).
    pub fn read(&mut self, buffer: &mut [u8]) -> Result<usize, HostError> {
        if buffer.is_empty() {
            return Ok(0);
        }
        // SAFETY: SYS_READ writes at most `len` bytes at the pointer, inside `buffer`, which we
        // borrow mutably across the call.
        let not_read = unsafe {
            cortex_m_semihosting::syscall(
                nr::READ,
                &[self.handle, buffer.as_mut_ptr() as usize, buffer.len()],
            )
        };
        // The call answers with the number of bytes it did *not* read.
        buffer.len().checked_sub(not_read).ok_or(HostError::Read)
    }

    /// Fills `buffer` from the file; fails at the end of the file.
    pub fn read_exact(&mut self, mut buffer: &mut [u8]) -> Result<(), HostError> {
        while !buffer.is_empty() {
            let read = self.read(buffer)?;
            if read == 0 {
                return Err(HostError::EndOfFile);
            }
            buffer = buffer.get_mut(read..).ok_or(HostError::Read)?;
        }
        Ok(())
    }

    /// Writes all of `bytes`.
    pub fn write_all(&mut self, mut bytes: &[u8]) -> Result<(), HostError> {
        while !bytes.is_empty() {
            // SAFETY: SYS_WRITE reads `len` bytes at the pointer, inside `bytes`.
            let not_written = unsafe {
                cortex_m_semihosting::syscall(
                    nr::WRITE,
                    &[self.handle, bytes.as_ptr() as usize, bytes.len()],
                )
            };
            let written = bytes
                .len()
                .checked_sub(not_written)
                .filter(|&written| written > 0)
                .ok_or(HostError::Write)?;
            bytes = bytes.get(written..).ok_or(HostError::Write)?;
        }
        Ok(())
    }
}

impl Drop for HostFile {
    fn drop(&mut self) {
        // SAFETY: SYS_CLOSE takes the handle only. Its error is ignored: nothing is lost by it
        // that the writes did not already report.
        unsafe {
            cortex_m_semihosting::syscall(nr::CLOSE, &[self.handle]);
        }
    }
}

/// The program's command line, read into `buffer` (its program name first, then the arguments,
/// separated by spaces).
pub fn command_line(buffer: &mut [u8]) -> Result<&str, HostError> {
    // SYS_GET_CMDLINE takes a block {pointer, length} and writes the length of the command line
    // back into it.
    let mut block = [buffer.as_mut_ptr() as usize, buffer.len()];
    // SAFETY: the call writes at most `buffer.len()` bytes into `buffer` and one word into
    // `block`, both borrowed mutably across it; the asm is not marked as leaving memory alone,
    // so the compiler reads `block` again after it.
    let status =
        unsafe { cortex_m_semihosting::syscall1(nr::GET_CMDLINE, block.as_mut_ptr() as usize) };
    if status != 0 {
        return Err(HostError::CommandLine);
    }
    let [_, len] = block;
    let bytes = buffer.get(..len).ok_or(HostError::CommandLine)?;
    core::str::from_utf8(bytes).map_err(|_| HostError::CommandLine)
}

/// A [`core::fmt::Write`] that fills a buffer and writes it to a host file when full, so the
/// record goes out in pieces of `N` bytes.
pub struct Buffered<'a, const N: usize> {
    file: &'a mut HostFile,
    buffer: [u8; N],
    len: usize,
    error: Option<HostError>,
}

impl<'a, const N: usize> Buffered<'a, N> {
    /// An empty buffer in front of `file`.
    pub fn new(file: &'a mut HostFile) -> Self {
        Buffered {
            file,
            buffer: [0; N],
            len: 0,
            error: None,
        }
    }

    /// Writes what is buffered; the first error of any write so far.
    pub fn flush(&mut self) -> Result<(), HostError> {
        if let Some(error) = self.error {
            return Err(error);
        }
        let pending = self.buffer.get(..self.len).unwrap_or(&[]);
        let written = self.file.write_all(pending);
        self.len = 0;
        if let Err(error) = written {
            self.error = Some(error);
        }
        written
    }
}

impl<const N: usize> core::fmt::Write for Buffered<'_, N> {
    fn write_str(&mut self, text: &str) -> core::fmt::Result {
        let mut bytes = text.as_bytes();
        while !bytes.is_empty() {
            if self.len == N {
                self.flush().map_err(|_| core::fmt::Error)?;
            }
            let room = N.saturating_sub(self.len).min(bytes.len());
            let (now, later) = bytes.split_at(room);
            self.buffer
                .get_mut(self.len..self.len + room)
                .ok_or(core::fmt::Error)?
                .copy_from_slice(now);
            self.len += room;
            bytes = later;
        }
        Ok(())
    }
}
