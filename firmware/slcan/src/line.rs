//! Cutting a byte stream into lines.

use crate::codec::{Command, ParseError, parse};
use crate::{CR, MAX_LINE};

/// Characters a line may hold before its CR.
const MAX_CONTENT: usize = MAX_LINE - 1;

// Not `#[non_exhaustive]`: the emulated board reports each variant as its own bus error code
// (slcan_bus.rs), so that a new way to refuse a line gets a code of its own.
/// Why a line was not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LineError {
    /// More than `MAX_LINE - 1` characters before the CR: the whole line is dropped.
    TooLong,
    /// The line is not a command.
    Malformed(ParseError),
}

impl core::fmt::Display for LineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LineError::TooLong => f.write_str("the line is longer than any SLCAN command"),
            LineError::Malformed(error) => write!(f, "malformed SLCAN line: {error}"),
        }
    }
}

impl core::error::Error for LineError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            LineError::Malformed(error) => Some(error),
            LineError::TooLong => None,
        }
    }
}

/// Collects bytes until a line ends (CR or LF) and parses it.
///
/// Holds at most one line (26 bytes). A line longer than that is dropped whole, up to its CR,
/// and reported once; the next line starts clean. Empty lines (a CR after a CR, CR LF) are
/// ignored: hosts send them to flush an adapter's input.
#[derive(Clone, Debug)]
pub struct LineReader {
    buf: [u8; MAX_CONTENT],
    len: u8,
    too_long: bool,
}

impl Default for LineReader {
    fn default() -> Self {
        Self::new()
    }
}

impl LineReader {
    /// An empty reader.
    pub const fn new() -> Self {
        LineReader {
            buf: [0; MAX_CONTENT],
            len: 0,
            too_long: false,
        }
    }

    /// Takes one byte; at the end of a non-empty line, the line's command or why it is none.
    pub fn push(&mut self, byte: u8) -> Option<Result<Command, LineError>> {
        if byte == CR || byte == b'\n' {
            let len = usize::from(self.len);
            let too_long = self.too_long;
            self.len = 0;
            self.too_long = false;
            if too_long {
                return Some(Err(LineError::TooLong));
            }
            if len == 0 {
                return None;
            }
            let content = self.buf.get(..len).unwrap_or(&[]);
            return Some(parse(content).map_err(LineError::Malformed));
        }
        match self.buf.get_mut(usize::from(self.len)) {
            Some(slot) => {
                *slot = byte;
                self.len = self.len.saturating_add(1);
            }
            None => self.too_long = true,
        }
        None
    }

    /// Whether part of a line is waiting for its end.
    pub fn pending(&self) -> bool {
        self.len > 0 || self.too_long
    }
}
