//! One line ↔ one command or frame.

use embedded_can::Frame as _;
use pab_core::Frame;
use pab_core::frame::{CLASSIC_DATA_LEN, raw_id};

use crate::{BEL, CR, MAX_LINE};

/// A command from the host, one line without its CR.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// `t`, `T`, `r`, `R`: a frame the host puts on the bus.
    Frame(Frame),
    /// `O`: open the channel.
    Open,
    /// `L`: open the channel listen-only.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `S0`..`S8`: one of the standard bit rates.
    Bitrate(Bitrate),
    /// `sXXYY`: SJA1000 bit timing registers.
    BitTiming {
        /// BTR0.
        btr0: u8,
        /// BTR1.
        btr1: u8,
    },
    /// `V`: hardware and software version.
    Version,
    /// `v`: firmware version (an extension some adapters answer).
    FirmwareVersion,
    /// `N`: serial number.
    SerialNumber,
    /// `F`: status flags.
    Status,
    /// `Z0` / `Z1`: timestamps off / on.
    Timestamps(bool),
    /// A Lawicel command this crate knows but does not implement (acceptance code and mask `M`
    /// `m`, auto-poll `X`, `W`, `Q`, `U`, `P`, `A`, `E`, `l`): the letter.
    Unsupported(u8),
}

/// The bit rates of `S0`..`S8`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bitrate {
    /// `S0`: 10 kbit/s.
    K10,
    /// `S1`: 20 kbit/s.
    K20,
    /// `S2`: 50 kbit/s.
    K50,
    /// `S3`: 100 kbit/s.
    K100,
    /// `S4`: 125 kbit/s.
    K125,
    /// `S5`: 250 kbit/s.
    K250,
    /// `S6`: 500 kbit/s.
    K500,
    /// `S7`: 800 kbit/s.
    K800,
    /// `S8`: 1 Mbit/s.
    M1,
}

impl Bitrate {
    /// The bit rate of `S<digit>`; `None` for anything but `0`..`8`.
    pub fn from_digit(digit: u8) -> Option<Bitrate> {
        Some(match digit {
            b'0' => Bitrate::K10,
            b'1' => Bitrate::K20,
            b'2' => Bitrate::K50,
            b'3' => Bitrate::K100,
            b'4' => Bitrate::K125,
            b'5' => Bitrate::K250,
            b'6' => Bitrate::K500,
            b'7' => Bitrate::K800,
            b'8' => Bitrate::M1,
            _ => return None,
        })
    }

    /// Bits per second.
    pub fn bits_per_second(self) -> u32 {
        match self {
            Bitrate::K10 => 10_000,
            Bitrate::K20 => 20_000,
            Bitrate::K50 => 50_000,
            Bitrate::K100 => 100_000,
            Bitrate::K125 => 125_000,
            Bitrate::K250 => 250_000,
            Bitrate::K500 => 500_000,
            Bitrate::K800 => 800_000,
            Bitrate::M1 => 1_000_000,
        }
    }
}

/// Why a line is not a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ParseError {
    /// The first character is no Lawicel command (the character).
    UnknownCommand(u8),
    /// The line is too short or too long for its command (a frame's data shorter or longer than
    /// its DLC says, say).
    Length,
    /// A character that must be a hexadecimal digit is not.
    Hex,
    /// A DLC that is not `0`..`8`.
    Dlc,
    /// An identifier above 0x7FF (`t`, `r`) or 0x1FFFFFFF (`T`, `R`).
    Identifier,
    /// An argument out of range (`S9`, `Z2`, ...).
    Argument,
}

impl core::fmt::Display for ParseError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParseError::UnknownCommand(byte) => write!(f, "unknown SLCAN command 0x{byte:02X}"),
            ParseError::Length => f.write_str("the line's length does not fit its command"),
            ParseError::Hex => f.write_str("a character is not a hexadecimal digit"),
            ParseError::Dlc => f.write_str("the data length is above 8"),
            ParseError::Identifier => f.write_str("the identifier does not fit its format"),
            ParseError::Argument => f.write_str("the command's argument is out of range"),
        }
    }
}

impl core::error::Error for ParseError {}

/// Parses one line, without its CR.
///
/// Costs one pass over the line; fails with a [`ParseError`] saying what is wrong, never panics.
pub fn parse(line: &[u8]) -> Result<Command, ParseError> {
    let Some((&first, rest)) = line.split_first() else {
        return Err(ParseError::Length);
    };
    let bare = |command| {
        if rest.is_empty() {
            Ok(command)
        } else {
            Err(ParseError::Length)
        }
    };
    match first {
        b't' => parse_frame(rest, 3, false, false),
        b'T' => parse_frame(rest, 8, true, false),
        b'r' => parse_frame(rest, 3, false, true),
        b'R' => parse_frame(rest, 8, true, true),
        b'O' => bare(Command::Open),
        b'L' => bare(Command::ListenOnly),
        b'C' => bare(Command::Close),
        b'V' => bare(Command::Version),
        b'v' => bare(Command::FirmwareVersion),
        b'N' => bare(Command::SerialNumber),
        b'F' => bare(Command::Status),
        b'S' => match rest {
            [digit] => Bitrate::from_digit(*digit)
                .map(Command::Bitrate)
                .ok_or(ParseError::Argument),
            _ => Err(ParseError::Length),
        },
        b's' => match rest {
            [a, b, c, d] => Ok(Command::BitTiming {
                btr0: hex_byte(*a, *b)?,
                btr1: hex_byte(*c, *d)?,
            }),
            _ => Err(ParseError::Length),
        },
        b'Z' => match rest {
            [b'0'] => Ok(Command::Timestamps(false)),
            [b'1'] => Ok(Command::Timestamps(true)),
            [_] => Err(ParseError::Argument),
            _ => Err(ParseError::Length),
        },
        b'M' | b'm' | b'X' | b'W' | b'Q' | b'U' | b'P' | b'A' | b'E' | b'l' => {
            Ok(Command::Unsupported(first))
        }
        other => Err(ParseError::UnknownCommand(other)),
    }
}

/// `rest` of a `t`/`T`/`r`/`R` line: `id_digits` identifier digits, the DLC, and (data frames)
/// two digits per data byte, nothing more.
fn parse_frame(
    rest: &[u8],
    id_digits: usize,
    extended: bool,
    remote: bool,
) -> Result<Command, ParseError> {
    let (id, rest) = rest.split_at_checked(id_digits).ok_or(ParseError::Length)?;
    let (&dlc, data) = rest.split_first().ok_or(ParseError::Length)?;
    let mut raw: u32 = 0;
    for &digit in id {
        raw = (raw << 4) | u32::from(hex_digit(digit)?);
    }
    let dlc = match dlc {
        b'0'..=b'8' => usize::from(dlc - b'0'),
        _ => return Err(ParseError::Dlc),
    };
    let id = raw_id(raw, extended).ok_or(ParseError::Identifier)?;
    if remote {
        if !data.is_empty() {
            return Err(ParseError::Length);
        }
        return Frame::new_remote(id, dlc)
            .map(Command::Frame)
            .ok_or(ParseError::Dlc);
    }
    if data.len() != 2 * dlc {
        return Err(ParseError::Length);
    }
    let mut bytes = [0u8; CLASSIC_DATA_LEN];
    for (byte, pair) in bytes.iter_mut().zip(data.chunks_exact(2)) {
        if let [high, low] = pair {
            *byte = hex_byte(*high, *low)?;
        }
    }
    // dlc ≤ 8 was checked above, so the frame always exists.
    let dlc = u8::try_from(dlc).map_err(|_| ParseError::Dlc)?;
    Ok(Command::Frame(Frame::from_buffer(id, bytes, dlc)))
}

fn hex_digit(c: u8) -> Result<u8, ParseError> {
    match c {
        b'0'..=b'9' => Ok(c - b'0'),
        b'A'..=b'F' => Ok(c - b'A' + 10),
        b'a'..=b'f' => Ok(c - b'a' + 10),
        _ => Err(ParseError::Hex),
    }
}

fn hex_byte(high: u8, low: u8) -> Result<u8, ParseError> {
    Ok((hex_digit(high)? << 4) | hex_digit(low)?)
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

/// One line to send, CR (or BEL) included: at most [`MAX_LINE`] bytes, on the stack.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Line {
    bytes: [u8; MAX_LINE],
    len: u8,
}

impl Line {
    /// The adapter's "done": CR alone.
    pub const fn ok() -> Line {
        let mut bytes = [0; MAX_LINE];
        bytes[0] = CR;
        Line { bytes, len: 1 }
    }

    /// The adapter's "refused": BEL alone.
    pub const fn refused() -> Line {
        let mut bytes = [0; MAX_LINE];
        bytes[0] = BEL;
        Line { bytes, len: 1 }
    }

    /// No bytes at all.
    pub const fn empty() -> Line {
        Line {
            bytes: [0; MAX_LINE],
            len: 0,
        }
    }

    /// `text` followed by CR; `text` is cut at `MAX_LINE - 1` bytes.
    pub fn text(text: &[u8]) -> Line {
        let mut line = Line::empty();
        for &byte in text.iter().take(MAX_LINE - 1) {
            line.push(byte);
        }
        line.push(CR);
        line
    }

    /// The bytes to send.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// Appends a byte; a full line ignores it (no caller writes more than [`MAX_LINE`]). Out of
    /// line: seven callers inlined it (128 bytes of the emulated board's flash).
    #[inline(never)]
    fn push(&mut self, byte: u8) {
        if let Some(slot) = self.bytes.get_mut(usize::from(self.len)) {
            *slot = byte;
            self.len = self.len.saturating_add(1);
        }
    }

    /// Appends `value`'s low `digits` nibbles in hexadecimal, the highest first. Out of line:
    /// three callers inlined it (100 bytes of the emulated board's flash).
    #[inline(never)]
    fn push_hex(&mut self, value: u32, digits: u32) {
        for shift in (0..digits).rev() {
            let nibble = (value >> (4 * shift)) & 0xF;
            self.push(HEX.get(nibble as usize).copied().unwrap_or(b'0'));
        }
    }
}

impl core::fmt::Debug for Line {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Line(\"")?;
        for &byte in self.as_bytes() {
            write!(f, "{}", core::ascii::escape_default(byte))?;
        }
        f.write_str("\")")
    }
}

/// The line an adapter sends for `frame`: `tIIIL..`, `TIIIIIIIIL..`, `rIIIL` or `RIIIIIIIIL`,
/// upper-case hex, CR-terminated; every classic frame fits in [`MAX_LINE`] bytes. `None` for a
/// CAN FD frame (pab-core's feature `fd`): SLCAN has no FD lines, and the kernel's `slcan`
/// driver none either, so a board behind it is a classic node (built without `fd`, where this
/// never happens).
pub fn format_frame(frame: &Frame) -> Option<Line> {
    if frame.is_fd() {
        return None;
    }
    let (raw, extended) = frame.raw_id();
    let mut line = Line::empty();
    line.push(match (extended, frame.is_remote()) {
        (false, false) => b't',
        (true, false) => b'T',
        (false, true) => b'r',
        (true, true) => b'R',
    });
    line.push_hex(raw, if extended { 8 } else { 3 });
    // A remote frame's DLC is its length field; a data frame's, its payload's length (≤ 8).
    let dlc = frame.dlc().min(CLASSIC_DATA_LEN) as u32;
    line.push_hex(dlc, 1);
    for &byte in frame.payload() {
        line.push_hex(u32::from(byte), 2);
    }
    line.push(CR);
    Some(line)
}
