//! The ISO-TP frame codec: protocol control information (PCI) in, bytes out, and back.
//!
//! Pure functions over one frame's data field, shared by [`Receiver`](super::Receiver) and
//! [`Sender`](super::Sender), and usable on their own to decode captures.
//!
//! Layout on classic CAN (ISO 15765-2:2016, normal addressing: the PCI is byte 0):
//!
//! ```text
//! Single Frame       0x0L  d1 .. dL                  L = 1..=7
//! First Frame        0x1L  LL  d1 .. d6              12-bit length 8..=4095
//! First Frame (esc)  0x10  00  L3 L2 L1 L0  d1 d2    32-bit big-endian length > 4095
//! Consecutive Frame  0x2N  d1 .. d7                  N = 1, 2, .., 15, 0, 1, ..
//! Flow Control       0x3S  BS  STmin                 S: 0 CTS, 1 WAIT, 2 OVFLW
//! ```
//!
//! Decisions, each from the standard unless said otherwise:
//!
//! - Frames longer than 8 bytes are refused: this module is for classic CAN only (CAN FD's escaped
//!   Single Frame `0x00 LL` would be an SF of length 0 here, and is refused as such).
//! - A received frame may be shorter than 8 bytes (the sender did not pad) as long as it holds every
//!   byte its PCI announces. A First Frame announces a full frame (6 or 2 data bytes after its PCI),
//!   so it must be 8 bytes long.
//! - A First Frame whose 12-bit length is 7 or less is malformed (the message fits a Single Frame),
//!   and so is an escaped First Frame whose 32-bit length is 4095 or less (the standard requires the
//!   shortest encoding). Both are refused, so that every message has exactly one encoding.
//! - Flow status values 3..=15 are reserved: decoding them is an error, which a sender waiting for
//!   a Flow Control treats as fatal (N_INVALID_FS).
//! - Reserved STmin values are kept as received in [`StMin`]; their duration is 127 ms, the longest
//!   valid one, as the standard tells senders to assume.

/// Bytes in a classic CAN frame; every frame this module encodes has exactly this length.
pub const FRAME_LEN: usize = 8;
/// The longest payload of a Single Frame.
pub const MAX_SINGLE_LEN: usize = 7;
/// Payload bytes in a First Frame with a 12-bit length.
pub const FIRST_DATA_LEN: usize = 6;
/// Payload bytes in an escaped First Frame (32-bit length).
pub const FIRST_ESCAPED_DATA_LEN: usize = 2;
/// The most payload bytes in a Consecutive Frame.
pub const CONSECUTIVE_DATA_LEN: usize = 7;
/// The largest length a 12-bit First Frame can announce; longer messages use the escape.
pub const MAX_SHORT_FIRST_LEN: u32 = 4095;
/// The padding byte used unless configured otherwise (what python `can-isotp` and Linux use).
pub const DEFAULT_PADDING: u8 = 0xCC;

/// What a Flow Control frame tells the sender.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlowStatus {
    /// FS = 0: send the next block of Consecutive Frames.
    ContinueToSend,
    /// FS = 1: wait for another Flow Control (restarts the sender's N_Bs timer).
    Wait,
    /// FS = 2: the receiver cannot take a message this long; the sender gives up.
    Overflow,
}

impl FlowStatus {
    /// The 4-bit FS value.
    pub const fn nibble(self) -> u8 {
        match self {
            FlowStatus::ContinueToSend => 0,
            FlowStatus::Wait => 1,
            FlowStatus::Overflow => 2,
        }
    }

    /// The status for a 4-bit FS value, or `None` for the reserved values 3..=15.
    pub const fn from_nibble(nibble: u8) -> Option<FlowStatus> {
        match nibble {
            0 => Some(FlowStatus::ContinueToSend),
            1 => Some(FlowStatus::Wait),
            2 => Some(FlowStatus::Overflow),
            _ => None,
        }
    }
}

/// The separation time a receiver asks for between Consecutive Frames (the STmin byte).
///
/// Encoding: 0x00..=0x7F are 0..=127 ms; 0xF1..=0xF9 are 100..=900 µs; everything else is
/// reserved. The raw byte is kept, so that a decoded capture shows what was on the bus; the
/// [duration](StMin::as_micros) of a reserved value is 127 ms, as ISO 15765-2 tells the sender to
/// assume.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StMin(u8);

impl StMin {
    /// No separation: Consecutive Frames back to back.
    pub const ZERO: StMin = StMin(0);
    /// The longest valid separation, 127 ms.
    pub const MAX: StMin = StMin(0x7F);

    /// `millis` milliseconds, or `None` above 127.
    pub const fn from_millis(millis: u8) -> Option<StMin> {
        if millis <= 0x7F {
            Some(StMin(millis))
        } else {
            None
        }
    }

    /// `hundreds` × 100 µs, for `hundreds` in 1..=9 (bytes 0xF1..=0xF9), or `None` otherwise.
    pub const fn from_hundred_micros(hundreds: u8) -> Option<StMin> {
        if hundreds >= 1 && hundreds <= 9 {
            Some(StMin(0xF0 | hundreds))
        } else {
            None
        }
    }

    /// The shortest encodable separation that is at least `micros` (127 ms when longer).
    ///
    /// Rounds up: 1..=900 µs to the next 100 µs, longer to the next millisecond.
    pub const fn at_least_micros(micros: u32) -> StMin {
        if micros == 0 {
            StMin::ZERO
        } else if micros <= 900 {
            // 1..=900 µs → 1..=9 hundreds; fits in the low nibble.
            StMin(0xF0 | (micros.div_ceil(100) as u8))
        } else if micros <= 127_000 {
            // 901..=127 000 µs → 1..=127 ms.
            StMin(micros.div_ceil(1000) as u8)
        } else {
            StMin::MAX
        }
    }

    /// The STmin byte as received (reserved values included), to decode captures.
    pub const fn from_byte(byte: u8) -> StMin {
        StMin(byte)
    }

    /// The byte sent on the bus.
    pub const fn byte(self) -> u8 {
        self.0
    }

    /// Whether the byte is one of the reserved values (0x80..=0xF0, 0xFA..=0xFF).
    pub const fn is_reserved(self) -> bool {
        !matches!(self.0, 0x00..=0x7F | 0xF1..=0xF9)
    }

    /// The separation in microseconds: 0..=127 000; reserved values count as 127 000.
    pub const fn as_micros(self) -> u32 {
        match self.0 {
            0x00..=0x7F => self.0 as u32 * 1000,
            0xF1..=0xF9 => (self.0 & 0x0F) as u32 * 100,
            _ => 127_000,
        }
    }
}

/// The protocol control information of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Pci {
    /// A whole message of `len` (1..=7) bytes (on CAN FD up to 62: [`fd`](super::fd)).
    Single {
        /// Payload bytes, 1..=7 (on CAN FD up to 62).
        len: u8,
    },
    /// The start of a segmented message of `len` bytes (8..=4095 with the 12-bit length,
    /// 4096..=u32::MAX with the escape).
    First {
        /// The whole message's length.
        len: u32,
    },
    /// The next segment of a message.
    Consecutive {
        /// The sequence number, 0..=15.
        sn: u8,
    },
    /// The receiver's answer to a First Frame or to a full block.
    FlowControl {
        /// Go on, wait, or give up.
        status: FlowStatus,
        /// Consecutive Frames before the next Flow Control; 0: none until the end.
        block_size: u8,
        /// Minimum time between Consecutive Frames.
        st_min: StMin,
    },
}

// Not `#[non_exhaustive]`: the PCI types and their checks are ISO 15765-2's, not ours to extend.
/// Why a frame could not be decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// No data byte at all.
    Empty,
    /// More than 8 data bytes: not a classic CAN frame.
    TooLong {
        /// The frame's length.
        len: usize,
    },
    /// The PCI type (high nibble of byte 0) is 4..=15.
    UnknownType {
        /// The high nibble.
        pci_type: u8,
    },
    /// A Single Frame announcing 0 bytes, or more than 7 (on CAN FD: a short form in a frame
    /// longer than 8 bytes, an escaped length of 7 or less, or longer than the frame).
    SingleLength {
        /// The announced length (low nibble of byte 0).
        len: u8,
    },
    /// A First Frame announcing a length that a shorter encoding could carry: 0..=7 with the
    /// 12-bit length, 0..=4095 with the escape.
    FirstLength {
        /// The announced length.
        len: u32,
    },
    /// The frame ends before the bytes its PCI announces.
    Truncated {
        /// Bytes the PCI requires.
        needed: usize,
        /// Bytes the frame has.
        got: usize,
    },
    /// A Flow Control with a reserved flow status (3..=15).
    InvalidFlowStatus {
        /// The low nibble of byte 0.
        status: u8,
    },
    /// A length that is not a CAN FD one (0..=8, 12, 16, 20, 24, 32, 48, 64): [`fd::decode`](super::fd::decode)
    /// only.
    FdLength {
        /// The frame's length.
        len: usize,
    },
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FrameError::Empty => f.write_str("ISO-TP frame without data"),
            FrameError::TooLong { len } => write!(f, "{len} data bytes: not a classic CAN frame"),
            FrameError::FdLength { len } => write!(f, "{len} data bytes: not a CAN FD frame"),
            FrameError::UnknownType { pci_type } => write!(f, "unknown ISO-TP PCI type {pci_type}"),
            FrameError::SingleLength { len } => {
                write!(f, "ISO-TP single frame announcing {len} bytes, not 1..=7")
            }
            FrameError::FirstLength { len } => write!(
                f,
                "ISO-TP first frame announcing {len} bytes, which a shorter encoding carries"
            ),
            FrameError::Truncated { needed, got } => {
                write!(f, "ISO-TP frame of {got} bytes, its PCI needs {needed}")
            }
            FrameError::InvalidFlowStatus { status } => {
                write!(
                    f,
                    "ISO-TP flow control with the reserved flow status {status}"
                )
            }
        }
    }
}

impl core::error::Error for FrameError {}

// Not `#[non_exhaustive]`: the PCI types and their checks are ISO 15765-2's, not ours to extend.
/// Why a frame could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// A Single Frame needs 1..=7 payload bytes, a Consecutive Frame 1..=7.
    PayloadLength {
        /// The length given.
        len: usize,
    },
    /// A First Frame's message must be 8 bytes or longer.
    MessageTooShort {
        /// The length given.
        len: u32,
    },
    /// Fewer payload bytes than the First Frame carries (6, or 2 when escaped).
    NotEnoughData {
        /// Bytes the frame carries.
        needed: usize,
        /// Bytes given.
        got: usize,
    },
    /// A sequence number above 15.
    SequenceNumber {
        /// The number given.
        sn: u8,
    },
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EncodeError::PayloadLength { len } => {
                write!(
                    f,
                    "{len} payload bytes for an ISO-TP frame that carries 1..=7"
                )
            }
            EncodeError::MessageTooShort { len } => write!(
                f,
                "ISO-TP first frame for a message of {len} bytes, fewer than 8"
            ),
            EncodeError::NotEnoughData { needed, got } => write!(
                f,
                "{got} payload bytes for an ISO-TP first frame that carries {needed}"
            ),
            EncodeError::SequenceNumber { sn } => {
                write!(f, "ISO-TP sequence number {sn}, above 15")
            }
        }
    }
}

impl core::error::Error for EncodeError {}

/// Reads one frame's data field: its PCI and the payload bytes it carries.
///
/// The payload is exactly what the PCI announces: the `L` bytes of a Single Frame (padding after
/// them is dropped), the 6 (or 2) bytes of a First Frame, every byte after the PCI of a Consecutive
/// Frame (the receiver, which knows how many remain, drops the padding of the last one), and
/// nothing for a Flow Control (bytes after STmin are padding).
///
/// Costs a few comparisons; never reads outside `data`. Fails with a [`FrameError`] when the frame
/// is longer than 8 bytes, has an unknown PCI type, announces an invalid length or status, or is
/// shorter than what its PCI announces (a Consecutive Frame must carry at least one byte).
pub fn decode(data: &[u8]) -> Result<(Pci, &[u8]), FrameError> {
    if data.len() > FRAME_LEN {
        return Err(FrameError::TooLong { len: data.len() });
    }
    let (&pci, rest) = data.split_first().ok_or(FrameError::Empty)?;
    let low = pci & 0x0F;
    match pci >> 4 {
        0 => {
            // L = 0 is CAN FD's escape for longer Single Frames; on classic CAN it is malformed.
            if low == 0 || usize::from(low) > MAX_SINGLE_LEN {
                return Err(FrameError::SingleLength { len: low });
            }
            let payload = take(rest, usize::from(low), 1)?;
            Ok((Pci::Single { len: low }, payload))
        }
        1 => {
            let (&second, rest) = rest.split_first().ok_or(FrameError::Truncated {
                needed: FRAME_LEN,
                got: data.len(),
            })?;
            let short = u32::from(low) << 8 | u32::from(second);
            if short != 0 {
                if short <= MAX_SINGLE_LEN as u32 {
                    return Err(FrameError::FirstLength { len: short });
                }
                let payload = take(rest, FIRST_DATA_LEN, 2)?;
                return Ok((Pci::First { len: short }, payload));
            }
            // The 2016 escape: a 12-bit length of 0 is followed by a 32-bit big-endian length.
            let bytes = take(rest, 4 + FIRST_ESCAPED_DATA_LEN, 2)?;
            let (length, payload) = bytes.split_at_checked(4).ok_or(FrameError::Truncated {
                needed: FRAME_LEN,
                got: data.len(),
            })?;
            let mut be = [0u8; 4];
            be.copy_from_slice(length);
            let len = u32::from_be_bytes(be);
            if len <= MAX_SHORT_FIRST_LEN {
                return Err(FrameError::FirstLength { len });
            }
            Ok((Pci::First { len }, payload))
        }
        2 => {
            if rest.is_empty() {
                return Err(FrameError::Truncated { needed: 2, got: 1 });
            }
            Ok((Pci::Consecutive { sn: low }, rest))
        }
        3 => {
            let status = FlowStatus::from_nibble(low)
                .ok_or(FrameError::InvalidFlowStatus { status: low })?;
            match rest {
                [block_size, st_min, ..] => Ok((
                    Pci::FlowControl {
                        status,
                        block_size: *block_size,
                        st_min: StMin::from_byte(*st_min),
                    },
                    &[],
                )),
                _ => Err(FrameError::Truncated {
                    needed: 3,
                    got: data.len(),
                }),
            }
        }
        pci_type => Err(FrameError::UnknownType { pci_type }),
    }
}

/// The first `len` bytes of `rest`, which starts `offset` bytes into the frame.
fn take(rest: &[u8], len: usize, offset: usize) -> Result<&[u8], FrameError> {
    rest.get(..len).ok_or(FrameError::Truncated {
        needed: offset.saturating_add(len),
        got: offset.saturating_add(rest.len()),
    })
}

/// A frame of padding with `pci_bytes` at its start, then as much of `data` as fits.
fn frame(pci_bytes: &[u8], data: &[u8], padding: u8) -> [u8; FRAME_LEN] {
    let mut frame = [padding; FRAME_LEN];
    for (slot, byte) in frame.iter_mut().zip(pci_bytes.iter().chain(data)) {
        *slot = *byte;
    }
    frame
}

/// A Single Frame carrying all of `payload` (1..=7 bytes), padded to 8 bytes.
///
/// Fails with [`EncodeError::PayloadLength`] for an empty payload or one longer than 7 bytes.
pub fn encode_single(payload: &[u8], padding: u8) -> Result<[u8; FRAME_LEN], EncodeError> {
    match payload.len() {
        // 1..=7 fits the low nibble.
        len @ 1..=MAX_SINGLE_LEN => Ok(frame(&[len as u8], payload, padding)),
        len => Err(EncodeError::PayloadLength { len }),
    }
}

/// How many payload bytes the First Frame of a `len`-byte message carries: 6, or 2 when the
/// length needs the escape (above 4095).
pub const fn first_data_len(len: u32) -> usize {
    if len <= MAX_SHORT_FIRST_LEN {
        FIRST_DATA_LEN
    } else {
        FIRST_ESCAPED_DATA_LEN
    }
}

/// The First Frame of a message of `len` bytes (8..=u32::MAX) that starts with `start`, and how
/// many bytes of `start` it carries ([`first_data_len`]; extra bytes of `start` are not used).
///
/// Uses the 12-bit length up to 4095 and the escape above, as the standard requires. Fails with
/// [`EncodeError::MessageTooShort`] below 8 bytes and [`EncodeError::NotEnoughData`] when `start`
/// is shorter than what the frame carries.
pub fn encode_first(len: u32, start: &[u8]) -> Result<([u8; FRAME_LEN], usize), EncodeError> {
    if len <= MAX_SINGLE_LEN as u32 {
        return Err(EncodeError::MessageTooShort { len });
    }
    let carried = first_data_len(len);
    let data = start.get(..carried).ok_or(EncodeError::NotEnoughData {
        needed: carried,
        got: start.len(),
    })?;
    let frame = if len <= MAX_SHORT_FIRST_LEN {
        // 8..=4095: the high nibble of the length goes into the PCI byte.
        let [_, _, high, low] = len.to_be_bytes();
        frame(&[0x10 | high, low], data, 0)
    } else {
        let [b3, b2, b1, b0] = len.to_be_bytes();
        frame(&[0x10, 0x00, b3, b2, b1, b0], data, 0)
    };
    Ok((frame, carried))
}

/// A Consecutive Frame with sequence number `sn` (0..=15) carrying `data` (1..=7 bytes), padded.
///
/// Fails with [`EncodeError::SequenceNumber`] above 15 and [`EncodeError::PayloadLength`] for
/// an empty `data` or one longer than 7 bytes.
pub fn encode_consecutive(
    sn: u8,
    data: &[u8],
    padding: u8,
) -> Result<[u8; FRAME_LEN], EncodeError> {
    if sn > 0x0F {
        return Err(EncodeError::SequenceNumber { sn });
    }
    if data.is_empty() || data.len() > CONSECUTIVE_DATA_LEN {
        return Err(EncodeError::PayloadLength { len: data.len() });
    }
    Ok(frame(&[0x20 | sn], data, padding))
}

/// A Flow Control frame, padded. Cannot fail.
pub fn encode_flow_control(
    status: FlowStatus,
    block_size: u8,
    st_min: StMin,
    padding: u8,
) -> [u8; FRAME_LEN] {
    frame(
        &[0x30 | status.nibble(), block_size, st_min.byte()],
        &[],
        padding,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every first byte at every frame length 0..=8: decoding never panics, and what it accepts is
    /// consistent with the layout (payload lengths, minimum frame lengths).
    #[test]
    fn every_pci_byte_at_every_length() {
        let mut accepted = 0;
        for first in 0..=255u8 {
            for len in 0..=FRAME_LEN {
                // Second byte 0x20 so that First Frames announce 12-bit lengths ≥ 32.
                let mut data = [0x20u8; FRAME_LEN];
                data[0] = first;
                let frame = &data[..len];
                let result = decode(frame);
                let (low, high) = (first & 0x0F, first >> 4);
                match result {
                    Ok((Pci::Single { len: l }, payload)) => {
                        assert_eq!(high, 0);
                        assert_eq!(l, low);
                        assert!((1..=7).contains(&l));
                        assert!(len > usize::from(l));
                        assert_eq!(payload, &frame[1..=usize::from(l)]);
                    }
                    Ok((Pci::First { len: l }, payload)) => {
                        assert_eq!(high, 1);
                        assert_eq!(len, 8);
                        assert_eq!(l, u32::from(low) << 8 | 0x20);
                        assert_eq!(payload, &frame[2..]);
                    }
                    Ok((Pci::Consecutive { sn }, payload)) => {
                        assert_eq!(high, 2);
                        assert_eq!(sn, low);
                        assert!(len >= 2);
                        assert_eq!(payload, &frame[1..]);
                    }
                    Ok((
                        Pci::FlowControl {
                            status,
                            block_size,
                            st_min,
                        },
                        payload,
                    )) => {
                        assert_eq!(high, 3);
                        assert!(low <= 2);
                        assert_eq!(status.nibble(), low);
                        assert!(len >= 3);
                        assert_eq!((block_size, st_min.byte()), (0x20, 0x20));
                        assert!(payload.is_empty());
                    }
                    Err(FrameError::Empty) => assert_eq!(len, 0),
                    Err(FrameError::Truncated { needed, got }) => {
                        assert_eq!(got, len);
                        assert!(needed > got);
                    }
                    Err(FrameError::SingleLength { len: l }) => {
                        assert_eq!(high, 0);
                        assert!(l == 0 || l > 7);
                    }
                    Err(FrameError::InvalidFlowStatus { status }) => {
                        assert_eq!(high, 3);
                        assert!(status >= 3);
                    }
                    Err(FrameError::UnknownType { pci_type }) => {
                        assert!(pci_type >= 4);
                        assert_eq!(pci_type, high);
                    }
                    Err(other) => panic!("{first:#04x} len {len}: {other:?}"),
                }
                if result.is_ok() {
                    accepted += 1;
                }
            }
        }
        // SF L=1..7 at lengths L+1..=8: 7+6+..+1 = 28; FF 16 (8 bytes only); CF 16 × 7;
        // FC 3 statuses × 6 lengths.
        assert_eq!(accepted, 28 + 16 + 16 * 7 + 3 * 6);
        assert_eq!(decode(&[0; 9]), Err(FrameError::TooLong { len: 9 }));
    }

    #[test]
    fn st_min_every_byte() {
        for byte in 0..=255u8 {
            let st_min = StMin::from_byte(byte);
            assert_eq!(st_min.byte(), byte);
            let expected = match byte {
                0x00..=0x7F => u32::from(byte) * 1000,
                0xF1..=0xF9 => u32::from(byte - 0xF0) * 100,
                _ => 127_000,
            };
            assert_eq!(st_min.as_micros(), expected, "{byte:#04x}");
            assert_eq!(
                st_min.is_reserved(),
                !(byte <= 0x7F || (0xF1..=0xF9).contains(&byte))
            );
            // Every valid value is the shortest encoding of its own duration (0xF1..0xF9 never
            // collide with whole milliseconds).
            if !st_min.is_reserved() {
                assert_eq!(StMin::at_least_micros(expected), st_min);
            }
        }
    }
}
