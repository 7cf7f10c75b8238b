//! candump log files (`candump -L`, `candump -l`, python-can's `.log`): reading a capture line by
//! line with every mistake located, and writing frames in the same format.
//!
//! A line is `(SECONDS.FRACTION) INTERFACE FRAME [R|T]`:
//!
//! - `SECONDS.FRACTION`: the receive time (can-utils writes 6 fraction digits; up to 9 are read,
//!   cut to whole microseconds);
//! - `FRAME`: `ID#DATA` with ID 3 hex digits (standard) or 8 (extended), DATA 0 to 8 bytes in hex
//!   (dots between bytes allowed, as `cansend` accepts them), optionally `_L` after 8 bytes (a
//!   classic DLC of 9..15); `ID#R` or `ID#R<dlc>` is a remote frame; `ID##F DATA` is a CAN FD
//!   frame: F one hex digit of flags (1 = BRS, the data phase at the data bit rate; 2 = ESI and
//!   4 = FDF, which newer kernels set on every FD frame, are read and not kept), DATA 0 to 64
//!   bytes (a length between the CAN FD lengths is padded with zeros to the next one, as a
//!   controller sends it: 12, 16, 20, 24, 32, 48, 64);
//! - `R`/`T`: the direction python-can's writer adds (received or transmitted by the logger);
//!   both were on the bus and both are read.
//!
//! An 8-digit ID with bit 29 set (`CAN_ERR_FLAG`) is an error frame: it carries no CAN frame and is
//! counted, not read. `candump -l` writes the same lines to a file, so both are read alike.

use std::fmt::Write as _;
use std::io::{self, BufRead};
use std::path::Path;

use embedded_can::Frame as _;
use pab_core::Frame;
use pab_core::frame::{FD_DATA_LEN, raw_id};

use crate::diagnostic::{Diagnostic, Diagnostics};

/// The most frames a capture may hold: a replay keeps the frames, its trace and its record in
/// memory, about 300 bytes per frame with `--trace` and `--records` (a million frames: 0.3 GB),
/// so a limit keeps a runaway file from exhausting memory.
pub const MAX_FRAMES: usize = 10_000_000;

/// The longest line read: a candump -L line of a CAN FD frame with a long interface name is
/// under 200 bytes, so a longer one is not a capture (a binary file, `/dev/zero` behind a
/// symbolic link) and reading stops there rather than buffer it.
pub const MAX_LINE: usize = 4096;
/// The most lines that are not frames reported before reading stops: a file that is not a
/// capture at all says so in its first lines.
pub const MAX_ERRORS: usize = 1000;

/// The CAN_ERR_FLAG of SocketCAN's ids: the line is an error frame.
const ERROR_FLAG: u32 = 0x2000_0000;

/// One frame of a capture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Captured {
    /// The receive time, µs since the Unix epoch (or whatever origin the capture uses).
    pub t_us: u64,
    /// The line it is on, 1-based.
    pub line: usize,
    /// The interface's index in [`Capture::interfaces`].
    pub interface: usize,
    /// The frame.
    pub frame: Frame,
}

/// A whole capture.
#[derive(Clone, Debug, Default)]
pub struct Capture {
    /// The frames, in the order of the file. That is not always time order: a recorder on a
    /// Linux host gets frames from several senders stamped by the kernel when they were sent,
    /// not in the order of those stamps ([`Capture::out_of_order`]).
    pub frames: Vec<Captured>,
    /// The interfaces named, in order of appearance, with their frame counts.
    pub interfaces: Vec<(String, usize)>,
    /// Error frames (`CAN_ERR_FLAG` ids): counted, not read.
    pub error_frames: usize,
    /// Frames whose time is earlier than that of a line before them, and the largest such step
    /// back, µs.
    pub out_of_order: (usize, u64),
}

impl Capture {
    /// The capture of `frames` (time in µs, frame), in that order, as if recorded on one
    /// interface `iface`: what a test or a rig in virtual time builds instead of reading a log.
    pub fn from_frames(iface: &str, frames: &[(u64, Frame)]) -> Capture {
        let mut out_of_order = (0usize, 0u64);
        let mut latest = 0u64;
        for (t_us, _) in frames {
            if *t_us < latest {
                out_of_order.0 += 1;
                out_of_order.1 = out_of_order.1.max(latest - t_us);
            }
            latest = latest.max(*t_us);
        }
        Capture {
            frames: frames
                .iter()
                .enumerate()
                .map(|(line, (t_us, frame))| Captured {
                    t_us: *t_us,
                    line: line + 1,
                    interface: 0,
                    frame: *frame,
                })
                .collect(),
            interfaces: vec![(iface.to_string(), frames.len())],
            error_frames: 0,
            out_of_order,
        }
    }
}

/// Reads the capture at `path`. `progress` is called with the bytes read so far, every 64 KiB and
/// at the end.
///
/// Only a regular file of at most [`crate::input::MAX_CAPTURE_BYTES`] is read (a FIFO or a
/// device is refused before it is opened). Every line that is not a frame is reported
/// (`path:line:column: error: cause`), up to [`MAX_ERRORS`] in one run; so is a file with no
/// frame, a line longer than [`MAX_LINE`] and more than [`MAX_FRAMES`] frames. Frames out of
/// time order are read and counted ([`Capture::out_of_order`]).
pub fn read(path: &Path, progress: &mut dyn FnMut(u64)) -> Result<Capture, Diagnostics> {
    crate::input::regular_file(path, "capture", crate::input::MAX_CAPTURE_BYTES)?;
    let file = std::fs::File::open(path)
        .map_err(|error| Diagnostic::file(path, format!("cannot read: {error}")))?;
    parse(path, io::BufReader::new(file), progress)
}

/// Reads a capture from `input`, reporting errors against the name `path`. See [`read`].
pub fn parse(
    path: &Path,
    mut input: impl BufRead,
    progress: &mut dyn FnMut(u64),
) -> Result<Capture, Diagnostics> {
    let mut capture = Capture::default();
    let mut errors = Vec::new();
    let mut bytes = Vec::new();
    let mut read_so_far = 0u64;
    let mut reported = 0u64;
    let mut latest: Option<u64> = None;
    for number in 1usize.. {
        bytes.clear();
        let read = io::Read::take(&mut input, MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut bytes)
            .map_err(|error| Diagnostic::file(path, format!("cannot read: {error}")))?;
        if read == 0 {
            break;
        }
        if bytes.len() > MAX_LINE {
            errors.push(Diagnostic::at(
                path,
                number,
                1,
                format!(
                    "a line longer than {MAX_LINE} bytes: not a candump -L log (reading stopped \
                     here)"
                ),
            ));
            break;
        }
        if errors.len() >= MAX_ERRORS {
            errors.push(Diagnostic::at(
                path,
                number,
                1,
                format!(
                    "reading stopped after {MAX_ERRORS} lines that are not frames: is this a \
                     candump -L log?"
                ),
            ));
            break;
        }
        read_so_far += read as u64;
        if read_so_far - reported >= 1 << 16 {
            reported = read_so_far;
            progress(read_so_far);
        }
        let at = |column: usize, message: String| Diagnostic::at(path, number, column, message);
        let Ok(text) = std::str::from_utf8(&bytes) else {
            errors.push(at(1, "not text (invalid UTF-8)".into()));
            continue;
        };
        let text = text.trim_end_matches(['\n', '\r']);
        match parse_line(text) {
            Ok(Line::Blank) => {}
            Ok(Line::ErrorFrame) => capture.error_frames += 1,
            Ok(Line::Frame {
                t_us,
                interface,
                frame,
            }) => {
                match latest {
                    Some(before) if t_us < before => {
                        let (count, step) = &mut capture.out_of_order;
                        *count += 1;
                        *step = (*step).max(before - t_us);
                    }
                    _ => latest = Some(t_us),
                }
                let index = match capture
                    .interfaces
                    .iter()
                    .position(|(name, _)| name == interface)
                {
                    Some(index) => index,
                    None => {
                        capture.interfaces.push((interface.to_string(), 0));
                        capture.interfaces.len() - 1
                    }
                };
                if let Some((_, count)) = capture.interfaces.get_mut(index) {
                    *count += 1;
                }
                if capture.frames.len() == MAX_FRAMES {
                    errors.push(at(
                        1,
                        format!("more than {MAX_FRAMES} frames: split the capture"),
                    ));
                    break;
                }
                capture.frames.push(Captured {
                    t_us,
                    line: number,
                    interface: index,
                    frame,
                });
            }
            Err((column, message)) => errors.push(at(column, message)),
        }
    }
    progress(read_so_far);
    if errors.is_empty() && capture.frames.is_empty() {
        errors.push(Diagnostic::file(
            path,
            "no CAN frame in this file (a candump -L log has lines like \
             `(1700000000.123456) vcan0 123#DEADBEEF`)",
        ));
    }
    if errors.is_empty() {
        Ok(capture)
    } else {
        Err(Diagnostics(errors))
    }
}

/// What one line holds.
#[derive(Debug, PartialEq, Eq)]
enum Line<'a> {
    Blank,
    ErrorFrame,
    Frame {
        t_us: u64,
        interface: &'a str,
        frame: Frame,
    },
}

/// Parses one line; an error is (1-based column in characters, cause).
fn parse_line(text: &str) -> Result<Line<'_>, (usize, String)> {
    if text.trim().is_empty() {
        return Ok(Line::Blank);
    }
    // Fields with the column where each starts.
    let mut fields = Vec::new();
    let mut start = None;
    for (offset, character) in text.char_indices() {
        match (character.is_whitespace(), start) {
            (true, Some(from)) => {
                fields.push((from, &text[from..offset]));
                start = None;
            }
            (false, None) => start = Some(offset),
            _ => {}
        }
    }
    if let Some(from) = start {
        fields.push((from, &text[from..]));
    }
    let column = |offset: usize| text[..offset].chars().count() + 1;
    let (time, interface, frame) = match fields.as_slice() {
        [time, interface, frame] => (*time, *interface, *frame),
        [time, interface, frame, (_, "R" | "T" | "r" | "t")] => (*time, *interface, *frame),
        [_, _, _, (offset, extra), ..] => {
            return Err((
                column(*offset),
                format!(
                    "unexpected `{extra}` after the frame (a candump -L line is `(TIME) INTERFACE ID#DATA`)"
                ),
            ));
        }
        _ => {
            return Err((
                1,
                "not a candump -L line: expected `(TIME) INTERFACE ID#DATA`, like \
                 `(1700000000.123456) vcan0 123#DEADBEEF`"
                    .into(),
            ));
        }
    };
    let t_us = parse_time(time.1).map_err(|message| (column(time.0), message))?;
    let frame = parse_frame(frame.1).map_err(|(offset, message)| {
        // `offset` is a byte offset inside the frame field (ASCII up to any error).
        (column(frame.0 + offset), message)
    })?;
    Ok(match frame {
        Some(frame) => Line::Frame {
            t_us,
            interface: interface.1,
            frame,
        },
        None => Line::ErrorFrame,
    })
}

/// `(SECONDS.FRACTION)` to µs.
fn parse_time(field: &str) -> Result<u64, String> {
    let bad = || {
        format!("`{field}` is not a time: expected (SECONDS.FRACTION), like (1700000000.123456)")
    };
    let inner = field
        .strip_prefix('(')
        .and_then(|rest| rest.strip_suffix(')'))
        .ok_or_else(bad)?;
    let (seconds, fraction) = inner.split_once('.').ok_or_else(bad)?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !digits(seconds) || !digits(fraction) || fraction.len() > 9 {
        return Err(bad());
    }
    let seconds: u64 = seconds.parse().map_err(|_| bad())?;
    let mut micros = 0u64;
    for position in 0..6 {
        let digit = fraction.as_bytes().get(position).map_or(0, |b| b - b'0');
        micros = micros * 10 + u64::from(digit);
    }
    seconds
        .checked_mul(1_000_000)
        .and_then(|t| t.checked_add(micros))
        .ok_or_else(|| format!("time `{field}` is too large"))
}

/// `ID#DATA` to a frame (`None`: an error frame); an error is (byte offset in the field, cause).
fn parse_frame(field: &str) -> Result<Option<Frame>, (usize, String)> {
    let Some((id_text, data)) = field.split_once('#') else {
        return Err((
            0,
            format!("`{field}` is not a frame: expected ID#DATA, like 123#DEADBEEF"),
        ));
    };
    // `##F`: a CAN FD frame, F its flags.
    let (fd, data, data_at) = match data.strip_prefix('#') {
        None => (None, data, id_text.len() + 1),
        Some(rest) => {
            let flags_at = id_text.len() + 2;
            let Some(flags) = rest.chars().next().and_then(|c| c.to_digit(16)) else {
                return Err((
                    flags_at,
                    "a CAN FD frame needs one hex digit of flags after `##` (0, or 1 = BRS), \
                     like 123##1DEADBEEF"
                        .into(),
                ));
            };
            (
                Some(flags & FD_BRS != 0),
                rest.get(1..).unwrap_or(""),
                flags_at + 1,
            )
        }
    };
    if id_text.is_empty() || !id_text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err((0, format!("`{id_text}` is not a CAN id in hex")));
    }
    let extended = match id_text.len() {
        3 => false,
        8 => true,
        n => {
            return Err((
                0,
                format!(
                    "CAN id `{id_text}` has {n} digits: candump writes 3 for a standard id and 8 \
                     for an extended one"
                ),
            ));
        }
    };
    let raw = u32::from_str_radix(id_text, 16).map_err(|_| (0, "bad CAN id".to_string()))?;
    if extended && raw & ERROR_FLAG != 0 {
        return Ok(None);
    }
    let id = raw_id(raw, extended).ok_or_else(|| {
        (
            0,
            if extended {
                format!("extended id 0x{raw:X} is above 0x1FFFFFFF")
            } else {
                format!("standard id 0x{raw:X} is above 0x7FF")
            },
        )
    })?;
    if let Some(dlc) = data.strip_prefix(['R', 'r']).filter(|_| fd.is_none()) {
        let len = match dlc {
            "" => 0,
            digit if digit.len() == 1 && digit.as_bytes()[0].is_ascii_digit() => {
                usize::from(digit.as_bytes()[0] - b'0')
            }
            _ => {
                return Err((data_at + 1, format!("`{dlc}` after R is not a length 0..8")));
            }
        };
        return Frame::new_remote(id, len)
            .map(Some)
            .ok_or_else(|| (data_at + 1, format!("remote frame length {len} is above 8")));
    }
    // A classic DLC above 8 for an 8-byte frame: `_9` .. `_F`.
    let (bytes_text, dlc_suffix) = match data.rsplit_once('_') {
        Some((bytes, suffix)) => (bytes, Some(suffix)),
        None => (data, None),
    };
    let most = if fd.is_some() { FD_DATA_LEN } else { 8 };
    let mut payload = Vec::with_capacity(most);
    let mut pending: Option<(usize, u8)> = None;
    for (offset, character) in bytes_text.char_indices() {
        let at = data_at + offset;
        if character == '.' && pending.is_none() {
            continue;
        }
        let Some(value) = character.to_digit(16) else {
            return Err((at, format!("`{character}` is not a hex digit of the data")));
        };
        match pending.take() {
            None => pending = Some((at, value as u8)),
            Some((_, high)) => {
                if payload.len() == most {
                    return Err((
                        at - 1,
                        if fd.is_some() {
                            "more than 64 data bytes: not a CAN FD frame".into()
                        } else {
                            "more than 8 data bytes: not a classic CAN frame (a CAN FD frame is \
                             written ID##FLAGS DATA)"
                                .into()
                        },
                    ));
                }
                payload.push(high << 4 | value as u8);
            }
        }
    }
    if let Some((at, _)) = pending {
        return Err((at, "odd number of hex digits in the data".into()));
    }
    if let Some(suffix) = dlc_suffix {
        let valid = fd.is_none()
            && suffix.len() == 1
            && suffix.as_bytes()[0].is_ascii_hexdigit()
            && u8::from_str_radix(suffix, 16).is_ok_and(|dlc| dlc > 8)
            && payload.len() == 8;
        if !valid {
            return Err((
                data_at + bytes_text.len(),
                format!("`_{suffix}` is not a DLC of 9..F after 8 data bytes"),
            ));
        }
    }
    match fd {
        Some(brs) => Frame::fd(id, &payload, brs),
        None => Frame::data(id, &payload),
    }
    .map(Some)
    .ok_or_else(|| (data_at, format!("more than {most} data bytes")))
}

/// The flag of a CAN FD line (`ID##F`) for bit-rate switching (SocketCAN's `CANFD_BRS`).
const FD_BRS: u32 = 0x1;

/// The candump -L line of `frame` at `t_us` µs on `interface`, without its newline:
/// `(0000000012.345678) vcan0 110#0102`, seconds padded to 10 digits as candump writes them; a
/// CAN FD frame `110##10102...` (flags 1 with bit-rate switching, else 0).
pub fn line(t_us: u64, interface: &str, frame: &Frame) -> String {
    let mut out = format!(
        "({:010}.{:06}) {interface} ",
        t_us / 1_000_000,
        t_us % 1_000_000
    );
    let (id, extended) = frame.raw_id();
    if extended {
        let _ = write!(out, "{id:08X}#");
    } else {
        let _ = write!(out, "{id:03X}#");
    }
    if frame.is_fd() {
        let _ = write!(out, "#{}", u8::from(frame.is_brs()));
    }
    if frame.is_remote() {
        out.push('R');
        if frame.dlc() > 0 {
            let _ = write!(out, "{}", frame.dlc());
        }
    } else {
        for byte in frame.payload() {
            let _ = write!(out, "{byte:02X}");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(text: &str) -> Result<Line<'_>, (usize, String)> {
        parse_line(text)
    }

    fn frame_of(text: &str) -> (u64, Frame) {
        match one(text).unwrap() {
            Line::Frame { t_us, frame, .. } => (t_us, frame),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_capture_of_frames_keeps_their_order_and_counts_steps_back() {
        let frame = |t| (t, frame_of("(0.000000) vcan0 123#01").1);
        let capture = Capture::from_frames("vcan0", &[frame(10), frame(30), frame(25), frame(5)]);
        let times: Vec<u64> = capture.frames.iter().map(|c| c.t_us).collect();
        assert_eq!(times, [10, 30, 25, 5]);
        assert_eq!(capture.frames[3].line, 4);
        assert_eq!(capture.out_of_order, (2, 25));
        assert_eq!(capture.interfaces, [("vcan0".to_string(), 4)]);
    }

    #[test]
    fn candump_lines_of_every_kind_are_read() {
        let (t, frame) = frame_of("(1700000000.123456) vcan0 123#DEADBEEF");
        assert_eq!(t, 1_700_000_000_123_456);
        assert_eq!(
            frame,
            Frame::with_raw_id(0x123, false, &[0xDE, 0xAD, 0xBE, 0xEF]).unwrap()
        );
        let (_, frame) = frame_of("(0.5) can1 1ABCDEF0#0102030405060708 R");
        assert_eq!(
            frame,
            Frame::with_raw_id(0x1ABC_DEF0, true, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap()
        );
        let (_, frame) = frame_of("(0000000001.000000) vcan0 00000010#");
        assert_eq!(frame.raw_id(), (0x10, true));
        assert!(frame.payload().is_empty());
        let (_, frame) = frame_of("(1.0) vcan0 7FF#R");
        assert!(frame.is_remote() && frame.dlc() == 0);
        let (_, frame) = frame_of("(1.0) vcan0 010#R4 T");
        assert!(frame.is_remote() && frame.dlc() == 4);
        let (_, frame) = frame_of("(1.0) vcan0 010#11.22.33");
        assert_eq!(frame.payload(), &[0x11, 0x22, 0x33]);
        let (_, frame) = frame_of("(1.0) vcan0 010#1122334455667788_C");
        assert_eq!(frame.payload().len(), 8);
        // CAN FD: flags 1 (BRS), 5 (BRS and FDF, as newer kernels log it), 0; lengths padded.
        let (_, frame) = frame_of("(1.0) vcan0 123##1DEADBEEF");
        assert!(frame.is_fd() && frame.is_brs());
        assert_eq!(frame.payload(), &[0xDE, 0xAD, 0xBE, 0xEF]);
        let (_, frame) = frame_of("(1.0) vcan0 1ABCDEF0##5112233445566778899AA");
        assert!(frame.is_fd() && frame.is_brs() && frame.raw_id() == (0x1ABC_DEF0, true));
        assert_eq!(frame.payload().len(), 12);
        assert_eq!(&frame.payload()[9..], &[0xAA, 0, 0]);
        let (_, frame) = frame_of(&format!("(1.0) vcan0 123##0{} T", "AB".repeat(64)));
        assert!(frame.is_fd() && !frame.is_brs() && frame.payload() == [0xAB; 64]);
        let (_, frame) = frame_of("(1.0) vcan0 123##0");
        assert!(frame.is_fd() && frame.payload().is_empty());
        assert_eq!(
            one("(1.0) vcan0 20000080#0000000000000000"),
            Ok(Line::ErrorFrame)
        );
        assert_eq!(one("   "), Ok(Line::Blank));
        // Nanoseconds are cut to microseconds.
        assert_eq!(frame_of("(2.123456789) vcan0 001#").0, 2_123_456);
    }

    #[test]
    fn malformed_lines_say_where_and_why() {
        let error = |text| one(text).unwrap_err();
        let (column, message) = error("(1.0) vcan0 123##XDEADBEEF");
        assert_eq!(column, 18);
        assert!(message.contains("CAN FD frame needs"), "{message}");
        let (column, message) = error("(1.0) vcan0 123##");
        assert_eq!((column, message.contains("flags")), (18, true), "{message}");
        let long = format!("(1.0) vcan0 123##1{}", "00".repeat(65));
        assert!(error(&long).1.contains("more than 64"));
        assert!(error("(1.0) vcan0 123##0R").1.contains("`R`"));
        assert!(error("(1.0) vcan0 123##11122_9").1.contains("DLC of 9..F"));
        assert_eq!(error("(1.0) vcan0 12#00").0, 13);
        assert!(error("(1.0) vcan0 12#00").1.contains("3 for a standard id"));
        assert!(error("(1.0) vcan0 800#00").1.contains("above 0x7FF"));
        assert!(
            error("(1.0) vcan0 40000000#")
                .1
                .contains("above 0x1FFFFFFF")
        );
        let (column, message) = error("(1.0) vcan0 123#0G");
        assert_eq!((column, message.contains("`G`")), (18, true));
        assert!(error("(1.0) vcan0 123#012").1.contains("odd number"));
        assert!(
            error("(1.0) vcan0 123#001122334455667788")
                .1
                .contains("more than 8")
        );
        assert_eq!(error("1.0 vcan0 123#00").0, 1);
        assert!(error("(1,0) vcan0 123#00").1.contains("not a time"));
        assert!(error("(1.0) vcan0").1.contains("not a candump -L line"));
        let (column, message) = error("(1.0) vcan0 123#00 X");
        assert_eq!((column, message.contains("`X`")), (20, true));
        assert!(error("(1.0) vcan0 123#R9").1.contains("above 8"));
        assert!(error("(1.0) vcan0 123#1122_9").1.contains("DLC of 9..F"));
    }

    #[test]
    fn every_error_of_a_file_is_reported() {
        let text = "(10.0) vcan0 110#01\nbad line\n(9.5) vcan0 110#\n(11.0) vcan0 110##X0\n";
        let errors = parse(Path::new("c.log"), text.as_bytes(), &mut |_| {}).unwrap_err();
        let shown: Vec<String> = errors.0.iter().map(ToString::to_string).collect();
        assert_eq!(shown.len(), 2, "{shown:?}");
        assert!(shown[0].starts_with("c.log:2:1: error: not a candump -L line"));
        assert!(shown[1].starts_with("c.log:4:19: error: a CAN FD frame needs"));
        let empty = parse(Path::new("e.log"), "\n\n".as_bytes(), &mut |_| {}).unwrap_err();
        assert!(empty.to_string().contains("no CAN frame"));
    }

    #[test]
    fn a_file_that_is_not_a_capture_is_refused_with_bounded_work() {
        // /dev/zero: a character device, refused before it is opened.
        let device = read(Path::new("/dev/zero"), &mut |_| {}).unwrap_err();
        assert!(
            device.0[0]
                .message
                .starts_with("a character device is not a regular file"),
            "{device}"
        );
        // Its bytes through a pipe: one line without end, cut at MAX_LINE.
        let endless = std::io::BufReader::new(std::io::Read::take(std::io::repeat(0), 1 << 30));
        let errors = parse(Path::new("zero"), endless, &mut |_| {}).unwrap_err();
        assert_eq!(errors.0.len(), 1, "{errors}");
        assert!(
            errors.0[0]
                .to_string()
                .starts_with("zero:1:1: error: a line longer than 4096 bytes"),
            "{errors}"
        );
        // Text that is no capture: MAX_ERRORS lines reported, then one that says reading stopped.
        let prose = "not a frame\n".repeat(5000);
        let errors = parse(Path::new("p.log"), prose.as_bytes(), &mut |_| {}).unwrap_err();
        assert_eq!(errors.0.len(), MAX_ERRORS + 1);
        assert!(
            errors.0[MAX_ERRORS]
                .to_string()
                .starts_with("p.log:1001:1: error: reading stopped after 1000 lines"),
            "{}",
            errors.0[MAX_ERRORS]
        );
    }

    #[test]
    fn frames_out_of_time_order_are_read_in_file_order_and_counted() {
        let text = "(10.0) a 110#\n(9.5) a 111#\n(10.2) b 112#\n(10.1) a 113#\n(9.9) a 114#\n";
        let capture = parse(Path::new("c.log"), text.as_bytes(), &mut |_| {}).unwrap();
        let ids: Vec<u32> = capture.frames.iter().map(|c| c.frame.raw_id().0).collect();
        assert_eq!(ids, [0x110, 0x111, 0x112, 0x113, 0x114]);
        assert_eq!(capture.out_of_order, (3, 500_000));
        assert_eq!(
            capture.interfaces,
            [("a".to_string(), 4), ("b".to_string(), 1)]
        );
    }

    #[test]
    fn lines_written_are_read_back() {
        let frames = [
            Frame::with_raw_id(0x110, false, &[]).unwrap(),
            Frame::with_raw_id(0x1ABC_DEF0, true, &[0, 0xFF]).unwrap(),
            Frame::new_remote(raw_id(0x42, false).unwrap(), 3).unwrap(),
            Frame::fd(raw_id(0x43, false).unwrap(), &[7; 48], true).unwrap(),
            Frame::fd(raw_id(0x1ABC_DEF0, true).unwrap(), &[1, 2], false).unwrap(),
        ];
        for (index, frame) in frames.into_iter().enumerate() {
            let t = 12_345_678 * index as u64;
            let text = line(t, "vcan0", &frame);
            assert_eq!(frame_of(&text), (t, frame), "{text}");
        }
        assert_eq!(
            line(12_345_678, "vcan0", &frames[0]),
            "(0000000012.345678) vcan0 110#"
        );
        assert_eq!(
            line(1, "vcan0", &frames[4]),
            "(0000000000.000001) vcan0 1ABCDEF0##00102"
        );
    }
}
