//! ISO-TP frames on CAN FD (ISO 15765-2:2016, normal addressing): the codec's CAN FD forms.
//!
//! On CAN FD a sender picks TX_DL, the length of its full frames: 8, 12, 16, 20, 24, 32, 48 or
//! 64 data bytes ([`TxDl`]). The PCI types are classic CAN's ([`pci`]); what changes
//! is how much a frame carries, and one escape:
//!
//! ```text
//! Single Frame        0x0L  d1 .. dL                 L = 1..=7, in a frame of at most 8 bytes
//! Single Frame (esc)  0x00  LL  d1 .. dLL            LL = 8..=TX_DL-2, in a frame longer than 8
//! First Frame         0x1L  LL  d1 .. d(TX_DL-2)     12-bit length, TX_DL-1..=4095
//! First Frame (esc)   0x10  00  L3 L2 L1 L0  d1 .. d(TX_DL-6)      32-bit length > 4095
//! Consecutive Frame   0x2N  d1 .. d(TX_DL-1)         the last one shorter
//! Flow Control        0x3S  BS  STmin                as on classic CAN
//! ```
//!
//! With TX_DL = 8 every frame is the classic one, byte for byte ([`pci`]'s encoders).
//!
//! Decisions, each from the standard unless said otherwise:
//!
//! - A frame is padded to the smallest valid CAN FD length that holds it, and to 8 bytes at
//!   least (ours: the classic codec pads every frame to 8, and a CAN FD frame of fewer bytes is
//!   no faster to send; python `can-isotp` does the same with `tx_data_min_length = 8`). The
//!   First Frame and every Consecutive Frame but the last are TX_DL long.
//! - A received frame must have a valid CAN FD length (0..=8, 12, 16, 20, 24, 32, 48, 64).
//! - A Single Frame in a frame longer than 8 bytes must use the escape (can-isotp refuses it
//!   otherwise too); an escape in a frame of 8 bytes or fewer is refused, as the classic codec
//!   refuses L = 0, and so is an escaped length of 7 or less (the short form carries it): every
//!   message has one encoding.
//! - A First Frame's length must need a First Frame at that frame's length: more than an escaped
//!   Single Frame of the same length carries (CAN_DL − 2), and 8 or more on a frame of 8. The
//!   escaped First Frame only above 4095, as on classic CAN.
//! - That the Consecutive Frames have the First Frame's length (RX_DL) but the last is the
//!   receiver's check, not the codec's: it knows which one is the last.

use super::pci::{self, FrameError, MAX_SHORT_FIRST_LEN, MAX_SINGLE_LEN, Pci};

/// The longest CAN FD data field.
pub const MAX_FD_FRAME_LEN: usize = 64;

/// The CAN FD data lengths above 8 (DLC 9 to 15).
const LONG_LENGTHS: [usize; 7] = [12, 16, 20, 24, 32, 48, 64];

/// The smallest valid CAN FD data length that holds `len` bytes: `len` itself up to 8, then 12,
/// 16, 20, 24, 32, 48, 64; `None` above 64.
pub fn fd_length(len: usize) -> Option<usize> {
    if len <= pci::FRAME_LEN {
        return Some(len);
    }
    LONG_LENGTHS.into_iter().find(|&long| long >= len)
}

/// Whether `len` is a CAN FD data length (0..=8, 12, 16, 20, 24, 32, 48 or 64).
pub fn is_fd_length(len: usize) -> bool {
    fd_length(len) == Some(len)
}

/// A sender's full frame length, TX_DL: 8 (classic CAN's frames, also on CAN FD), 12, 16, 20,
/// 24, 32, 48 or 64.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TxDl(u8);

impl TxDl {
    /// Classic CAN's 8 bytes.
    pub const CLASSIC: TxDl = TxDl(8);
    /// The longest, 64 bytes: the fewest frames a message.
    pub const MAX: TxDl = TxDl(64);

    /// `len` if it is one of the eight TX_DL values, else `None`.
    pub fn new(len: usize) -> Option<TxDl> {
        if len >= pci::FRAME_LEN && is_fd_length(len) {
            u8::try_from(len).ok().map(TxDl)
        } else {
            None
        }
    }

    /// The length in bytes.
    pub const fn len(self) -> usize {
        self.0 as usize
    }

    /// Always false (a TX_DL is 8 bytes or more); for clippy's `len` convention.
    pub const fn is_empty(self) -> bool {
        false
    }

    /// The most payload bytes a Single Frame carries: 7 at 8, else TX_DL − 2 (the escape).
    pub const fn max_single(self) -> usize {
        if self.0 as usize == pci::FRAME_LEN {
            MAX_SINGLE_LEN
        } else {
            self.0 as usize - 2
        }
    }

    /// Payload bytes in a First Frame of a `len`-byte message: TX_DL − 2, or TX_DL − 6 when the
    /// length needs the escape (above 4095).
    pub const fn first_data_len(self, len: u32) -> usize {
        if len <= MAX_SHORT_FIRST_LEN {
            self.0 as usize - 2
        } else {
            self.0 as usize - 6
        }
    }

    /// Payload bytes in a full Consecutive Frame: TX_DL − 1.
    pub const fn consecutive_data_len(self) -> usize {
        self.0 as usize - 1
    }
}

/// One frame's data field, up to 64 bytes. 65 bytes; `Copy`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FdFrame {
    bytes: [u8; MAX_FD_FRAME_LEN],
    len: u8,
}

impl FdFrame {
    /// The data field, 8..=64 bytes (a valid CAN FD length).
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// `pci_bytes` then `data`, padded with `padding` to the smallest CAN FD length that holds
    /// them and 8 at least (`None` above 64 bytes).
    fn new(pci_bytes: &[u8], data: &[u8], padding: u8) -> Option<FdFrame> {
        let used = pci_bytes.len().checked_add(data.len())?;
        let len = fd_length(used.max(pci::FRAME_LEN))?;
        let mut bytes = [padding; MAX_FD_FRAME_LEN];
        for (slot, byte) in bytes.iter_mut().zip(pci_bytes.iter().chain(data)) {
            *slot = *byte;
        }
        Some(FdFrame {
            bytes,
            len: u8::try_from(len).ok()?,
        })
    }
}

/// Why an ISO-TP frame could not be encoded for CAN FD.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FdEncodeError {
    /// A Single Frame carries 1..=`max` payload bytes, a Consecutive Frame 1..=`max`.
    PayloadLength {
        /// The length given.
        len: usize,
        /// The most the frame carries at this TX_DL.
        max: usize,
    },
    /// The message fits a Single Frame at this TX_DL: no First Frame for it.
    MessageTooShort {
        /// The length given.
        len: u32,
        /// The shortest message a First Frame carries at this TX_DL.
        min: u32,
    },
    /// Fewer payload bytes than the First Frame carries.
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

impl core::fmt::Display for FdEncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FdEncodeError::PayloadLength { len, max } => write!(
                f,
                "{len} payload bytes for an ISO-TP frame that carries 1..={max}"
            ),
            FdEncodeError::MessageTooShort { len, min } => write!(
                f,
                "ISO-TP first frame for a message of {len} bytes, which a single frame carries (a first frame from {min})"
            ),
            FdEncodeError::NotEnoughData { needed, got } => write!(
                f,
                "{got} payload bytes for an ISO-TP first frame that carries {needed}"
            ),
            FdEncodeError::SequenceNumber { sn } => {
                write!(f, "ISO-TP sequence number {sn}, above 15")
            }
        }
    }
}

impl core::error::Error for FdEncodeError {}

/// Reads one CAN FD frame's data field: its PCI and the payload bytes it carries, as
/// [`pci::decode`] does on classic CAN, with the escaped Single Frame and frames up to 64 bytes.
///
/// The payload is exactly what the PCI announces for a Single Frame, every byte after the PCI
/// for a First or Consecutive Frame (the receiver drops the last one's padding), nothing for a
/// Flow Control. Fails with [`FrameError::FdLength`] for a length that is not a CAN FD one, and
/// otherwise as [`pci::decode`], by the rules of the module's documentation. Never reads outside
/// `data`.
pub fn decode(data: &[u8]) -> Result<(Pci, &[u8]), FrameError> {
    let len = data.len();
    if !is_fd_length(len) {
        return Err(FrameError::FdLength { len });
    }
    if len <= pci::FRAME_LEN {
        // Classic CAN's forms and rules, the escape refused as L = 0 (a frame of 8 or fewer).
        return pci::decode(data);
    }
    let (&first, rest) = data.split_first().ok_or(FrameError::Empty)?;
    let low = first & 0x0F;
    match first >> 4 {
        0 => {
            // A frame longer than 8 bytes: the escape, with a length that needs it.
            let (&escaped, rest) = rest.split_first().ok_or(FrameError::Empty)?;
            if low != 0 || usize::from(escaped) <= MAX_SINGLE_LEN || usize::from(escaped) > len - 2
            {
                return Err(FrameError::SingleLength {
                    len: if low != 0 { low } else { escaped },
                });
            }
            let payload = rest.get(..usize::from(escaped)).unwrap_or(&[]);
            Ok((Pci::Single { len: escaped }, payload))
        }
        1 => {
            let (&second, rest) = rest.split_first().ok_or(FrameError::Empty)?;
            let short = u32::from(low) << 8 | u32::from(second);
            // What an escaped Single Frame of this length carries: the First Frame must need more.
            let single = (len - 2) as u32;
            if short != 0 {
                if short <= single {
                    return Err(FrameError::FirstLength { len: short });
                }
                return Ok((Pci::First { len: short }, rest));
            }
            let (length, payload) = rest.split_at_checked(4).ok_or(FrameError::Truncated {
                needed: 6,
                got: len,
            })?;
            let mut be = [0u8; 4];
            be.copy_from_slice(length);
            let total = u32::from_be_bytes(be);
            if total <= MAX_SHORT_FIRST_LEN {
                return Err(FrameError::FirstLength { len: total });
            }
            Ok((Pci::First { len: total }, payload))
        }
        // A Consecutive Frame's bytes, a Flow Control's fields: as on classic CAN (the Flow
        // Control's bytes after STmin are padding).
        2 => Ok((Pci::Consecutive { sn: low }, rest)),
        _ => pci::decode(data.get(..pci::FRAME_LEN).unwrap_or(data)).map(|(pci, _)| (pci, &[][..])),
    }
}

/// A Single Frame carrying all of `payload` at `tx_dl`: the short form for 1..=7 bytes (8 bytes
/// long), the escape for 8..=TX_DL − 2 (padded to a CAN FD length).
///
/// Fails with [`FdEncodeError::PayloadLength`] for an empty payload or one longer than the
/// frame carries ([`TxDl::max_single`]).
pub fn encode_single(payload: &[u8], tx_dl: TxDl, padding: u8) -> Result<FdFrame, FdEncodeError> {
    let max = tx_dl.max_single();
    let error = FdEncodeError::PayloadLength {
        len: payload.len(),
        max,
    };
    let frame = match payload.len() {
        0 => return Err(error),
        len @ 1..=MAX_SINGLE_LEN => FdFrame::new(&[len as u8], payload, padding),
        len if len <= max => FdFrame::new(&[0x00, len as u8], payload, padding),
        _ => return Err(error),
    };
    frame.ok_or(error)
}

/// The First Frame of a message of `len` bytes that starts with `start`, at `tx_dl` (TX_DL bytes
/// long), and how many bytes of `start` it carries ([`TxDl::first_data_len`]).
///
/// Fails with [`FdEncodeError::MessageTooShort`] for a message a Single Frame carries and
/// [`FdEncodeError::NotEnoughData`] when `start` is shorter than what the frame carries.
pub fn encode_first(
    len: u32,
    start: &[u8],
    tx_dl: TxDl,
) -> Result<(FdFrame, usize), FdEncodeError> {
    let single = tx_dl.max_single() as u32;
    if len <= single {
        return Err(FdEncodeError::MessageTooShort {
            len,
            min: single + 1,
        });
    }
    let carried = tx_dl.first_data_len(len);
    let data = start.get(..carried).ok_or(FdEncodeError::NotEnoughData {
        needed: carried,
        got: start.len(),
    })?;
    let frame = if len <= MAX_SHORT_FIRST_LEN {
        let [_, _, high, low] = len.to_be_bytes();
        FdFrame::new(&[0x10 | high, low], data, 0)
    } else {
        let [b3, b2, b1, b0] = len.to_be_bytes();
        FdFrame::new(&[0x10, 0x00, b3, b2, b1, b0], data, 0)
    };
    frame
        .map(|frame| (frame, carried))
        .ok_or(FdEncodeError::NotEnoughData {
            needed: carried,
            got: start.len(),
        })
}

/// A Consecutive Frame with sequence number `sn` (0..=15) carrying `data` (1..=TX_DL − 1 bytes):
/// TX_DL long when full, the last one padded to the smallest CAN FD length that holds it.
///
/// Fails with [`FdEncodeError::SequenceNumber`] above 15 and [`FdEncodeError::PayloadLength`]
/// for an empty `data` or one longer than the frame carries.
pub fn encode_consecutive(
    sn: u8,
    data: &[u8],
    tx_dl: TxDl,
    padding: u8,
) -> Result<FdFrame, FdEncodeError> {
    if sn > 0x0F {
        return Err(FdEncodeError::SequenceNumber { sn });
    }
    let max = tx_dl.consecutive_data_len();
    let error = FdEncodeError::PayloadLength {
        len: data.len(),
        max,
    };
    if data.is_empty() || data.len() > max {
        return Err(error);
    }
    FdFrame::new(&[0x20 | sn], data, padding).ok_or(error)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_can_fd_lengths() {
        let valid: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];
        for len in 0..=80 {
            assert_eq!(is_fd_length(len), valid.contains(&len), "{len}");
            let rounded = fd_length(len);
            assert_eq!(rounded, valid.iter().copied().find(|&v| v >= len), "{len}");
        }
        let tx: [usize; 8] = [8, 12, 16, 20, 24, 32, 48, 64];
        for len in 0..=80 {
            assert_eq!(
                TxDl::new(len).map(TxDl::len),
                tx.contains(&len).then_some(len)
            );
        }
    }

    /// At TX_DL = 8 the encoders write classic CAN's frames, byte for byte.
    #[test]
    fn at_eight_bytes_the_frames_are_the_classic_ones() {
        let data: [u8; 8] = [1, 2, 3, 4, 5, 6, 7, 8];
        for len in 1..=7 {
            let fd = encode_single(&data[..len], TxDl::CLASSIC, 0xCC).unwrap();
            let classic = pci::encode_single(&data[..len], 0xCC).unwrap();
            assert_eq!(fd.as_bytes(), &classic[..]);
        }
        for len in [8u32, 100, 4095, 4096, 70_000] {
            let (fd, n) = encode_first(len, &data, TxDl::CLASSIC).unwrap();
            let (classic, m) = pci::encode_first(len, &data).unwrap();
            assert_eq!((fd.as_bytes(), n), (&classic[..], m));
        }
        for len in 1..=7 {
            let fd = encode_consecutive(5, &data[..len], TxDl::CLASSIC, 0xAA).unwrap();
            let classic = pci::encode_consecutive(5, &data[..len], 0xAA).unwrap();
            assert_eq!(fd.as_bytes(), &classic[..]);
        }
        assert!(encode_single(&data, TxDl::CLASSIC, 0).is_err());
        assert!(encode_first(7, &data, TxDl::CLASSIC).is_err());
    }

    /// Every frame the encoders write decodes to what was encoded, at every TX_DL and length.
    #[test]
    fn what_is_encoded_decodes_back() {
        let message: [u8; 64] = core::array::from_fn(|i| i as u8 ^ 0x5A);
        for tx in [8, 12, 16, 20, 24, 32, 48, 64] {
            let tx_dl = TxDl::new(tx).unwrap();
            for len in 1..=tx_dl.max_single() {
                let frame = encode_single(&message[..len], tx_dl, 0xCC).unwrap();
                assert!(is_fd_length(frame.as_bytes().len()) && frame.as_bytes().len() >= 8);
                let (pci, payload) = decode(frame.as_bytes()).unwrap();
                assert_eq!(pci, Pci::Single { len: len as u8 });
                assert_eq!(payload, &message[..len]);
            }
            assert!(encode_single(&message[..tx_dl.max_single() + 1], tx_dl, 0).is_err());
            for len in [tx_dl.max_single() as u32 + 1, 4095, 4096, 1 << 20] {
                let (frame, carried) = encode_first(len, &message, tx_dl).unwrap();
                assert_eq!(frame.as_bytes().len(), tx);
                let (pci, payload) = decode(frame.as_bytes()).unwrap();
                assert_eq!(pci, Pci::First { len });
                assert_eq!(payload, &message[..carried]);
            }
            for len in 1..=tx_dl.consecutive_data_len() {
                let frame = encode_consecutive(3, &message[..len], tx_dl, 0xCC).unwrap();
                let (pci, payload) = decode(frame.as_bytes()).unwrap();
                assert_eq!(pci, Pci::Consecutive { sn: 3 });
                assert_eq!(&payload[..len], &message[..len]);
                assert!(payload[len..].iter().all(|&b| b == 0xCC));
            }
        }
    }

    /// Every first byte, a few second bytes, at every length 0..=64: decoding never panics, what
    /// it accepts follows the module's rules, and a length that is not a CAN FD one is refused.
    #[test]
    fn every_pci_byte_at_every_length() {
        for first in 0..=255u8 {
            for second in [0u8, 1, 7, 8, 9, 40, 62, 63, 255] {
                for len in 0..=MAX_FD_FRAME_LEN + 1 {
                    let mut data = [0x33u8; MAX_FD_FRAME_LEN + 1];
                    data[0] = first;
                    data[1] = second;
                    let frame = &data[..len];
                    let result = decode(frame);
                    if !is_fd_length(len) {
                        assert_eq!(result, Err(FrameError::FdLength { len }));
                        continue;
                    }
                    if len <= 8 {
                        assert_eq!(result, pci::decode(frame));
                        continue;
                    }
                    match result {
                        Ok((Pci::Single { len: l }, payload)) => {
                            assert_eq!(first, 0);
                            assert_eq!(l, second);
                            assert!(usize::from(l) >= 8 && usize::from(l) <= len - 2);
                            assert_eq!(payload, &frame[2..2 + usize::from(l)]);
                        }
                        Ok((Pci::First { len: total }, _)) => {
                            assert_eq!(first >> 4, 1);
                            assert!(total as usize > len - 2);
                        }
                        Ok((Pci::Consecutive { sn }, payload)) => {
                            assert_eq!(first, 0x20 | sn);
                            assert_eq!(payload.len(), len - 1);
                        }
                        Ok((Pci::FlowControl { .. }, payload)) => {
                            assert_eq!(first >> 4, 3);
                            assert!(payload.is_empty());
                        }
                        Err(_) => {}
                    }
                }
            }
        }
    }

    #[test]
    fn what_is_refused() {
        // A short Single Frame in a long frame (the escape is missing).
        let mut frame = [0xCCu8; 12];
        frame[0] = 0x05;
        assert_eq!(decode(&frame), Err(FrameError::SingleLength { len: 5 }));
        // An escaped length the short form carries.
        frame[0] = 0x00;
        frame[1] = 7;
        assert_eq!(decode(&frame), Err(FrameError::SingleLength { len: 7 }));
        // An escaped length longer than the frame.
        frame[1] = 11;
        assert_eq!(decode(&frame), Err(FrameError::SingleLength { len: 11 }));
        frame[1] = 10;
        assert!(decode(&frame).is_ok());
        // The escape in a frame of 8.
        assert_eq!(
            decode(&[0x00, 5, 1, 2, 3, 4, 5, 0xCC]),
            Err(FrameError::SingleLength { len: 0 })
        );
        // A First Frame of a message an escaped Single Frame of its length carries.
        let mut first = [0u8; 64];
        first[0] = 0x10;
        first[1] = 62;
        assert_eq!(decode(&first), Err(FrameError::FirstLength { len: 62 }));
        first[1] = 63;
        assert!(decode(&first).is_ok());
        // An escaped First Frame of a length the 12-bit form carries.
        let escaped = [0x10, 0, 0, 0, 0x0F, 0xFF, 1, 2, 3, 4, 5, 6];
        assert_eq!(decode(&escaped), Err(FrameError::FirstLength { len: 4095 }));
        // Lengths that are not CAN FD's.
        assert_eq!(decode(&[0x21; 9]), Err(FrameError::FdLength { len: 9 }));
        assert_eq!(decode(&[0x21; 65]), Err(FrameError::FdLength { len: 65 }));
    }
}
