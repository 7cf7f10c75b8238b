//! A classic CAN frame (up to 8 data bytes), owned and `Copy`.
//!
//! Every runner converts its driver's frame type to this one at the edge (the embassy FDCAN frame on
//! a board, `socketcan::CanFrame` on Linux, the simulator's own), through the
//! [`embedded_can::Frame`] trait that all of them implement, so the node application and the tools
//! share one frame type.

use embedded_can::{ExtendedId, Id, StandardId};

use crate::filter::{MAX_EXTENDED_ID, MAX_STANDARD_ID};

/// Data bytes of a classic CAN frame.
pub const MAX_DATA_LEN: usize = 8;

/// `KEEP[n]`: the low 8·n bits set, n = 0..=8 (a table, as 64-bit shifts by a variable cost a
/// dozen instructions on a 32-bit core).
// Evaluated at compile time: an index out of bounds would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
const KEEP: [u64; MAX_DATA_LEN + 1] = {
    let mut table = [0; MAX_DATA_LEN + 1];
    let mut n = 1;
    while n <= MAX_DATA_LEN {
        table[n] = (table[n - 1] << 8) | 0xFF;
        n += 1;
    }
    table
};

/// A classic CAN data or remote frame. 16 bytes; no allocation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Frame {
    id: Id,
    remote: bool,
    len: u8,
    data: [u8; MAX_DATA_LEN],
}

impl Frame {
    /// A data frame on standard identifier 0 without data: a placeholder for storage that is
    /// filled before it is read.
    pub const fn empty() -> Frame {
        Frame {
            id: Id::Standard(StandardId::ZERO),
            remote: false,
            len: 0,
            data: [0; MAX_DATA_LEN],
        }
    }

    /// A data frame; `None` when `data` is longer than 8 bytes.
    pub fn data(id: impl Into<Id>, data: &[u8]) -> Option<Frame> {
        let len = u8::try_from(data.len()).ok().filter(|&len| len <= 8)?;
        let mut bytes = [0; MAX_DATA_LEN];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Frame {
            id: id.into(),
            remote: false,
            len,
            data: bytes,
        })
    }

    /// A data frame from a full 8-byte buffer of which the first `len` bytes are sent (`len` is
    /// clamped to 8). Infallible, for encoders that fill a fixed buffer.
    pub fn from_buffer(id: impl Into<Id>, data: [u8; MAX_DATA_LEN], len: u8) -> Frame {
        Frame {
            id: id.into(),
            remote: false,
            len: len.min(8),
            data,
        }
    }

    /// A data frame with an identifier given as a raw number; `None` when the number does not fit
    /// the format or `data` is longer than 8 bytes.
    pub fn with_raw_id(raw: u32, extended: bool, data: &[u8]) -> Option<Frame> {
        Frame::data(raw_id(raw, extended)?, data)
    }

    /// The identifier.
    pub const fn id(&self) -> Id {
        self.id
    }

    /// The identifier as a number and whether it is extended.
    pub fn raw_id(&self) -> (u32, bool) {
        match self.id {
            Id::Standard(id) => (u32::from(id.as_raw()), false),
            Id::Extended(id) => (id.as_raw(), true),
        }
    }

    /// The whole 8-byte data buffer, the bytes after the payload included: for an encoder that
    /// rewrites a field in place.
    pub(crate) fn buffer_mut(&mut self) -> &mut [u8; MAX_DATA_LEN] {
        &mut self.data
    }

    /// The data bytes (empty for a remote frame).
    pub fn payload(&self) -> &[u8] {
        if self.remote {
            return &[];
        }
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// The frame a gateway re-publishes for this one: a data frame on `id` with this frame's
    /// payload (none for a remote frame), the bytes after it zero. The same frame as
    /// `Frame::from_buffer(id, payload padded with zeros, payload length)`, without the copy
    /// byte by byte.
    pub fn republished(&self, id: impl Into<Id>) -> Frame {
        // As `payload()`: nothing for a remote frame (or a length beyond 8, which no
        // constructor makes).
        let len = if self.remote || self.len > 8 {
            0
        } else {
            self.len
        };
        // The first `len` bytes kept: read little endian, the low 8·len bits.
        let keep = KEEP.get(usize::from(len)).copied().unwrap_or(0);
        let data = (u64::from_le_bytes(self.data) & keep).to_le_bytes();
        Frame {
            id: id.into(),
            remote: false,
            len,
            data,
        }
    }

    /// Whether this is a remote (RTR) frame.
    pub const fn is_remote(&self) -> bool {
        self.remote
    }

    /// The frame's rank in bus arbitration: of two frames, the one with the lower rank wins
    /// (a dominant bit earlier in the arbitration field). Bits, from the top: the 11 base
    /// identifier bits, the IDE bit (a standard frame beats an extended one with the same base
    /// identifier), the 18 extension bits, then RTR (a data frame beats a remote frame with
    /// the same identifier). Equal ranks mean the same identifier and kind. A few instructions.
    pub fn arbitration_rank(&self) -> u32 {
        let remote = u32::from(self.remote);
        match self.id {
            Id::Standard(id) => u32::from(id.as_raw()) << 20 | remote,
            Id::Extended(id) => {
                let raw = id.as_raw();
                (raw >> 18) << 20 | 1 << 19 | (raw & 0x3_FFFF) << 1 | remote
            }
        }
    }
}

/// An identifier from a raw number; `None` when it does not fit the format.
pub fn raw_id(raw: u32, extended: bool) -> Option<Id> {
    if extended {
        (raw <= MAX_EXTENDED_ID)
            .then(|| ExtendedId::new(raw))
            .flatten()
            .map(Id::Extended)
    } else {
        (raw <= MAX_STANDARD_ID)
            .then(|| u16::try_from(raw).ok().and_then(StandardId::new))
            .flatten()
            .map(Id::Standard)
    }
}

impl embedded_can::Frame for Frame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        Frame::data(id, data)
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        let len = u8::try_from(dlc).ok().filter(|&len| len <= 8)?;
        Some(Frame {
            id: id.into(),
            remote: true,
            len,
            data: [0; MAX_DATA_LEN],
        })
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        self.remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.len)
    }

    fn data(&self) -> &[u8] {
        self.payload()
    }
}

/// Converts any [`embedded_can::Frame`] (a driver's frame) to a [`Frame`].
pub fn from_frame(frame: &impl embedded_can::Frame) -> Frame {
    if frame.is_remote_frame() {
        Frame {
            id: frame.id(),
            remote: true,
            len: u8::try_from(frame.dlc().min(8)).unwrap_or(8),
            data: [0; MAX_DATA_LEN],
        }
    } else {
        let data = frame.data();
        let data = data.get(..data.len().min(MAX_DATA_LEN)).unwrap_or(&[]);
        Frame::data(frame.id(), data).unwrap_or(Frame {
            id: frame.id(),
            remote: false,
            len: 0,
            data: [0; MAX_DATA_LEN],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::Frame as _;

    #[test]
    fn a_republished_frame_is_the_payload_padded_with_zeros() {
        // What the node application built before `republished`: the payload copied into a
        // zeroed buffer, the payload's length.
        let padded = |frame: &Frame, id: Id| {
            let mut data = [0; MAX_DATA_LEN];
            for (to, from) in data.iter_mut().zip(frame.payload()) {
                *to = *from;
            }
            Frame::from_buffer(id, data, frame.payload().len() as u8)
        };
        let out = Id::Standard(StandardId::new(0x300).unwrap());
        let bytes = [0xA1, 0xB2, 0xC3, 0xD4, 0xE5, 0xF6, 0x17, 0x28];
        for len in 0..=8u8 {
            // Bytes after the length that are not zero (a buffer filled by a driver).
            let frames = [
                Frame::from_buffer(out, bytes, len),
                Frame::data(out, &bytes[..usize::from(len)]).unwrap(),
                Frame::new_remote(out, usize::from(len)).unwrap(),
            ];
            for frame in frames {
                let id = Id::Extended(ExtendedId::new(0x1234_5678).unwrap());
                assert_eq!(frame.republished(id), padded(&frame, id), "{frame:?}");
            }
        }
    }

    #[test]
    fn data_longer_than_eight_bytes_is_refused() {
        assert!(Frame::with_raw_id(0x10, false, &[0; 9]).is_none());
        let frame = Frame::with_raw_id(0x10, false, &[1, 2, 3]).unwrap();
        assert_eq!(frame.payload(), &[1, 2, 3]);
        assert_eq!(frame.dlc(), 3);
        assert_eq!(frame.raw_id(), (0x10, false));
    }

    #[test]
    fn the_arbitration_rank_orders_frames_as_the_bus_does() {
        let std = |raw| Frame::with_raw_id(raw, false, &[]).unwrap();
        let ext = |raw| Frame::with_raw_id(raw, true, &[]).unwrap();
        let remote = |raw, extended| Frame::new_remote(raw_id(raw, extended).unwrap(), 0).unwrap();
        // In the order the bus lets them through.
        let order = [
            std(0x000),
            remote(0x000, false),
            ext(0x0000_0001),
            // TransferStatus of node 3: base identifier 0x284.
            ext(0x0A12_0003),
            std(0x300),
            remote(0x300, false),
            ext(0x300 << 18),
            remote(0x300 << 18, true),
            ext((0x300 << 18) | 1),
            std(0x301),
            // A diagnostic sample of node 3: base identifier 0x781.
            ext(0x1E06_FF03),
            std(0x7FF),
            ext(0x1FFF_FFFF),
        ];
        for pair in order.windows(2) {
            assert!(
                pair[0].arbitration_rank() < pair[1].arbitration_rank(),
                "{:?} before {:?}",
                pair[0],
                pair[1]
            );
        }
        for frame in order {
            assert_eq!(frame.arbitration_rank(), frame.arbitration_rank());
        }
        // As embedded-can orders identifiers (by arbitration) for data frames.
        for a in order.iter().filter(|frame| !frame.is_remote()) {
            for b in order.iter().filter(|frame| !frame.is_remote()) {
                assert_eq!(
                    a.arbitration_rank().cmp(&b.arbitration_rank()),
                    a.id().cmp(&b.id())
                );
            }
        }
    }

    #[test]
    fn raw_ids_are_checked_against_their_format() {
        assert!(raw_id(0x7FF, false).is_some());
        assert!(raw_id(0x800, false).is_none());
        assert!(raw_id(0x1FFF_FFFF, true).is_some());
        assert!(raw_id(0x2000_0000, true).is_none());
    }

    #[test]
    fn remote_frames_carry_no_data() {
        let id = raw_id(0x123, false).unwrap();
        let frame = Frame::new_remote(id, 4).unwrap();
        assert!(frame.is_remote_frame());
        assert_eq!(frame.dlc(), 4);
        assert_eq!(embedded_can::Frame::data(&frame), &[] as &[u8]);
        assert_eq!(from_frame(&frame), frame);
    }
}
