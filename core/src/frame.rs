//! A CAN frame, owned and `Copy`: classic (up to 8 data bytes) and, with the feature `fd`, CAN FD
//! (up to 64).
//!
//! Every runner converts its driver's frame type to this one at the edge (the embassy FDCAN frame on
//! a board, `socketcan::CanFrame` on Linux, the simulator's own), through the
//! [`embedded_can::Frame`] trait that all of them implement, so the node application and the tools
//! share one frame type.
//!
//! Why CAN FD is a feature: every queued frame carries the whole data buffer, so a 64-byte
//! capacity costs a board 56 bytes of RAM per queue slot and the frame path its 8-byte word
//! (a classic payload is masked and copied as one `u64`). A board whose controller or bridge is
//! classic (the emulated board's SLCAN) builds without it and keeps both; the host tools, the
//! Linux node and an FD board build with it. The semantics are the same: an FD frame is filtered,
//! integrated, arbitrated and re-published as a classic one is; only its payload may be longer,
//! and a gateway re-publishes it as an FD frame with its bit-rate switch.

use embedded_can::{ExtendedId, Id, StandardId};

use crate::filter::{MAX_EXTENDED_ID, MAX_STANDARD_ID};

/// Data bytes of a classic CAN frame.
pub const CLASSIC_DATA_LEN: usize = 8;

/// Data bytes of a CAN FD frame.
pub const FD_DATA_LEN: usize = 64;

/// The data bytes a [`Frame`] holds: [`FD_DATA_LEN`] with the feature `fd`, else
/// [`CLASSIC_DATA_LEN`].
#[cfg(feature = "fd")]
pub const MAX_DATA_LEN: usize = FD_DATA_LEN;
/// The data bytes a [`Frame`] holds: [`FD_DATA_LEN`] with the feature `fd`, else
/// [`CLASSIC_DATA_LEN`].
#[cfg(not(feature = "fd"))]
pub const MAX_DATA_LEN: usize = CLASSIC_DATA_LEN;

/// The data lengths a CAN FD frame can have (ISO 11898-1:2015: DLC 9 to 15 stand for 12, 16, 20,
/// 24, 32, 48 and 64 bytes). A controller pads a payload of any other length to the next one.
pub const FD_LENGTHS: [u8; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// The shortest CAN FD data length that holds `len` bytes; `None` above 64.
pub const fn fd_length(len: usize) -> Option<u8> {
    match len {
        0..=8 => Some(len as u8),
        9..=12 => Some(12),
        13..=16 => Some(16),
        17..=20 => Some(20),
        21..=24 => Some(24),
        25..=32 => Some(32),
        33..=48 => Some(48),
        49..=64 => Some(64),
        _ => None,
    }
}

/// `KEEP[n]`: the low 8·n bits set, n = 0..=8 (a table, as 64-bit shifts by a variable cost a
/// dozen instructions on a 32-bit core).
// Evaluated at compile time: an index out of bounds would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
const KEEP: [u64; CLASSIC_DATA_LEN + 1] = {
    let mut table = [0; CLASSIC_DATA_LEN + 1];
    let mut n = 1;
    while n <= CLASSIC_DATA_LEN {
        table[n] = (table[n - 1] << 8) | 0xFF;
        n += 1;
    }
    table
};

/// A CAN data or remote frame: classic, or with the feature `fd` CAN FD too. 16 bytes (72 with
/// `fd`); no allocation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Frame {
    id: Id,
    remote: bool,
    len: u8,
    /// A CAN FD frame (FDF set): its data up to 64 bytes, never remote.
    #[cfg(feature = "fd")]
    fd: bool,
    /// Its data phase at the data bit rate (BRS set); only on an FD frame.
    #[cfg(feature = "fd")]
    brs: bool,
    data: [u8; MAX_DATA_LEN],
}

impl Frame {
    /// A data frame on standard identifier 0 without data: a placeholder for storage that is
    /// filled before it is read.
    pub const fn empty() -> Frame {
        // A literal, not `Frame::classic`: through the call, the node's outbox zeroed the
        // placeholder it writes over at once (14 bytes of the boards' flash).
        Frame {
            id: Id::Standard(StandardId::ZERO),
            remote: false,
            len: 0,
            #[cfg(feature = "fd")]
            fd: false,
            #[cfg(feature = "fd")]
            brs: false,
            data: [0; MAX_DATA_LEN],
        }
    }

    /// A classic frame of these parts (`len` at most 8: the callers' to see to).
    const fn classic(id: Id, remote: bool, len: u8, data: [u8; MAX_DATA_LEN]) -> Frame {
        Frame {
            id,
            remote,
            len,
            #[cfg(feature = "fd")]
            fd: false,
            #[cfg(feature = "fd")]
            brs: false,
            data,
        }
    }

    /// A classic data frame; `None` when `data` is longer than 8 bytes.
    pub fn data(id: impl Into<Id>, data: &[u8]) -> Option<Frame> {
        let len = u8::try_from(data.len())
            .ok()
            .filter(|&len| usize::from(len) <= CLASSIC_DATA_LEN)?;
        let mut bytes = [0; MAX_DATA_LEN];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Frame::classic(id.into(), false, len, bytes))
    }

    /// A CAN FD data frame, with its data phase at the data bit rate when `brs`. `data` is padded
    /// with zeros to the next CAN FD length (12, 16, 20, 24, 32, 48 or 64 bytes above 8), as a
    /// controller sends it; `None` when it is longer than 64 bytes.
    #[cfg(feature = "fd")]
    pub fn fd(id: impl Into<Id>, data: &[u8], brs: bool) -> Option<Frame> {
        let len = fd_length(data.len())?;
        let mut bytes = [0; MAX_DATA_LEN];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Frame {
            id: id.into(),
            remote: false,
            len,
            fd: true,
            brs,
            data: bytes,
        })
    }

    /// A classic data frame from a full 8-byte buffer of which the first `len` bytes are sent
    /// (`len` is clamped to 8). Infallible, for encoders that fill a fixed buffer.
    pub fn from_buffer(id: impl Into<Id>, data: [u8; CLASSIC_DATA_LEN], len: u8) -> Frame {
        #[cfg(feature = "fd")]
        let data = {
            let mut bytes = [0; MAX_DATA_LEN];
            if let Some(head) = bytes.first_chunk_mut::<CLASSIC_DATA_LEN>() {
                *head = data;
            }
            bytes
        };
        Frame::classic(id.into(), false, len.min(8), data)
    }

    /// Whether this is a CAN FD frame (always `false` without the feature `fd`).
    pub const fn is_fd(&self) -> bool {
        #[cfg(feature = "fd")]
        return self.fd;
        #[cfg(not(feature = "fd"))]
        false
    }

    /// Whether this CAN FD frame's data phase runs at the data bit rate (BRS; always `false` for
    /// a classic frame).
    pub const fn is_brs(&self) -> bool {
        #[cfg(feature = "fd")]
        return self.brs;
        #[cfg(not(feature = "fd"))]
        false
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

    /// The whole data buffer, the bytes after the payload included: for an encoder that
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
    /// payload (none for a remote frame), the bytes after it zero, classic or FD (with its bit-rate
    /// switch) as this one. The same frame as `Frame::from_buffer(id, payload padded with zeros,
    /// payload length)` for a classic frame, without the copy byte by byte.
    pub fn republished(&self, id: impl Into<Id>) -> Frame {
        // As `payload()`: nothing for a remote frame (or a length beyond the buffer, which no
        // constructor makes).
        let len = if self.remote || usize::from(self.len) > MAX_DATA_LEN {
            0
        } else {
            self.len
        };
        #[cfg(feature = "fd")]
        if self.fd || usize::from(len) > CLASSIC_DATA_LEN {
            let mut data = [0; MAX_DATA_LEN];
            let keep = usize::from(len);
            if let (Some(to), Some(from)) = (data.get_mut(..keep), self.data.get(..keep)) {
                to.copy_from_slice(from);
            }
            return Frame {
                id: id.into(),
                remote: false,
                len,
                fd: self.fd,
                brs: self.brs,
                data,
            };
        }
        // A classic payload: read little endian, the low 8·len bits.
        let keep = KEEP.get(usize::from(len)).copied().unwrap_or(0);
        let head = self
            .data
            .first_chunk::<CLASSIC_DATA_LEN>()
            .copied()
            .unwrap_or([0; CLASSIC_DATA_LEN]);
        let head = (u64::from_le_bytes(head) & keep).to_le_bytes();
        Frame::from_buffer(id, head, len)
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
        Some(Frame::classic(id.into(), true, len, [0; MAX_DATA_LEN]))
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

/// Converts any [`embedded_can::Frame`] (a driver's frame) to a [`Frame`]. A data frame longer
/// than 8 bytes becomes, with the feature `fd`, a CAN FD frame without bit-rate switch (the trait
/// does not tell it: a driver with FD frames uses [`Frame::fd`]); without it, its first 8 bytes.
pub fn from_frame(frame: &impl embedded_can::Frame) -> Frame {
    if frame.is_remote_frame() {
        let len = u8::try_from(frame.dlc().min(CLASSIC_DATA_LEN)).unwrap_or(8);
        return Frame::classic(frame.id(), true, len, [0; MAX_DATA_LEN]);
    }
    let data = frame.data();
    #[cfg(feature = "fd")]
    if data.len() > CLASSIC_DATA_LEN {
        let data = data.get(..data.len().min(FD_DATA_LEN)).unwrap_or(&[]);
        if let Some(fd) = Frame::fd(frame.id(), data, false) {
            return fd;
        }
    }
    let data = data.get(..data.len().min(CLASSIC_DATA_LEN)).unwrap_or(&[]);
    Frame::data(frame.id(), data).unwrap_or(Frame::classic(frame.id(), false, 0, [0; MAX_DATA_LEN]))
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
            let mut data = [0; CLASSIC_DATA_LEN];
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
    fn fd_lengths_are_the_dlc_table() {
        for len in 0..=FD_DATA_LEN {
            let fd = fd_length(len).unwrap();
            assert!(FD_LENGTHS.contains(&fd) && usize::from(fd) >= len, "{len}");
            // The shortest: no valid length between.
            assert!(
                FD_LENGTHS.iter().all(|&l| usize::from(l) < len || l >= fd),
                "{len}"
            );
        }
        assert_eq!(fd_length(FD_DATA_LEN + 1), None);
    }

    #[cfg(feature = "fd")]
    #[test]
    fn fd_frames_are_padded_to_their_length_and_republished_as_fd() {
        let id = raw_id(0x123, false).unwrap();
        let data: Vec<u8> = (1..=13).collect();
        let frame = Frame::fd(id, &data, true).unwrap();
        assert!(frame.is_fd() && frame.is_brs());
        assert_eq!(frame.payload().len(), 16);
        assert_eq!(&frame.payload()[..13], &data[..]);
        assert_eq!(&frame.payload()[13..], &[0, 0, 0]);
        let out = raw_id(0x1234_5678, true).unwrap();
        let again = frame.republished(out);
        assert!(again.is_fd() && again.is_brs());
        assert_eq!((again.id(), again.payload()), (out, frame.payload()));
        // Short FD frames stay FD; classic ones stay classic.
        let short = Frame::fd(id, &[7], false).unwrap();
        assert!(short.republished(out).is_fd() && !short.republished(out).is_brs());
        assert!(!Frame::data(id, &[7]).unwrap().republished(out).is_fd());
        assert!(Frame::fd(id, &[0; 65], true).is_none());
        // A driver's frame of 20 bytes: FD.
        let driver = from_frame(&Frame::fd(id, &[9; 20], true).unwrap());
        assert!(driver.is_fd() && driver.payload() == [9; 20]);
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
