//! The job file of a replay on a board: the tables of its nodes and the frames to feed them, in
//! one binary file that the host writes and the board reads in fixed-size pieces (through
//! semihosting on an emulated board), so the board needs no parser and no allocation.
//!
//! ```text
//! offset  size
//!      0     4  magic "PABJ"
//!      4     2  format version, little endian (1)
//!      6     1  node count
//!      7     1  reserved, 0
//!      8     4  frame count, little endian
//!     12        per node, in the order the records list them:
//!                 1  node id   3  reserved, 0   4  image length, little endian   then the image
//!      …        per frame, in replay order, 24 bytes each:
//!                 8  time, µs since the replay's time 0, little endian
//!                 4  CAN id, little endian
//!                 1  flags: bit 0 extended id, bit 1 remote frame, others 0
//!                 1  data length, 0..=8
//!                 2  reserved, 0
//!                 8  data (bytes past the length are 0)
//! ```
//!
//! Frame times never decrease (the host checks; a board refuses a file where they do).

use pab_core::frame::raw_id;
use pab_core::{Frame, Instant};

/// The file's first bytes.
pub const MAGIC: [u8; 4] = *b"PABJ";
/// The format version this code reads and writes.
pub const VERSION: u16 = 1;
/// Bytes of the file header.
pub const HEADER_LEN: usize = 12;
/// Bytes of a node entry before its image.
pub const NODE_LEN: usize = 8;
/// Bytes of one frame.
pub const FRAME_LEN: usize = 24;

const EXTENDED: u8 = 1;
const REMOTE: u8 = 2;

/// Why a piece of a job file was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum JobError {
    /// Not a job file (magic).
    BadMagic,
    /// A format version this code does not read.
    UnsupportedVersion(u16),
    /// A reserved byte or flag bit is not 0.
    Reserved,
    /// A CAN id that does not fit its format.
    BadId(u32),
    /// A data length above 8.
    BadLength(u8),
}

impl core::fmt::Display for JobError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            JobError::BadMagic => f.write_str("not a replay job file (magic)"),
            JobError::UnsupportedVersion(version) => {
                write!(f, "job format {version} (this code reads {VERSION})")
            }
            JobError::Reserved => f.write_str("a reserved byte or flag is not 0"),
            JobError::BadId(id) => write!(f, "CAN id 0x{id:X} does not fit its format"),
            JobError::BadLength(len) => write!(f, "data length {len} is above 8"),
        }
    }
}

impl core::error::Error for JobError {}

/// The file header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JobHeader {
    /// Nodes that follow.
    pub nodes: u8,
    /// Frames that follow the nodes.
    pub frames: u32,
}

impl JobHeader {
    /// Its bytes.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let [v0, v1] = VERSION.to_le_bytes();
        let [f0, f1, f2, f3] = self.frames.to_le_bytes();
        let [m0, m1, m2, m3] = MAGIC;
        [m0, m1, m2, m3, v0, v1, self.nodes, 0, f0, f1, f2, f3]
    }

    /// Reads it back.
    pub fn decode(bytes: &[u8; HEADER_LEN]) -> Result<Self, JobError> {
        let [m0, m1, m2, m3, v0, v1, nodes, reserved, f0, f1, f2, f3] = *bytes;
        if [m0, m1, m2, m3] != MAGIC {
            return Err(JobError::BadMagic);
        }
        let version = u16::from_le_bytes([v0, v1]);
        if version != VERSION {
            return Err(JobError::UnsupportedVersion(version));
        }
        if reserved != 0 {
            return Err(JobError::Reserved);
        }
        Ok(JobHeader {
            nodes,
            frames: u32::from_le_bytes([f0, f1, f2, f3]),
        })
    }
}

/// A node entry, followed in the file by `image_len` bytes of table image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeEntry {
    /// The node id (its `Config`'s).
    pub node_id: u8,
    /// Bytes of its image.
    pub image_len: u32,
}

impl NodeEntry {
    /// Its bytes.
    pub fn encode(&self) -> [u8; NODE_LEN] {
        let [l0, l1, l2, l3] = self.image_len.to_le_bytes();
        [self.node_id, 0, 0, 0, l0, l1, l2, l3]
    }

    /// Reads it back.
    pub fn decode(bytes: &[u8; NODE_LEN]) -> Result<Self, JobError> {
        let [node_id, r0, r1, r2, l0, l1, l2, l3] = *bytes;
        if [r0, r1, r2] != [0; 3] {
            return Err(JobError::Reserved);
        }
        Ok(NodeEntry {
            node_id,
            image_len: u32::from_le_bytes([l0, l1, l2, l3]),
        })
    }
}

/// A frame and its time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TimedFrame {
    /// µs since the replay's time 0.
    pub t_us: u64,
    /// The frame.
    pub frame: Frame,
}

impl TimedFrame {
    /// The instant to feed it at: `t_us` on the node's clock, which starts at 0.
    pub fn instant(&self) -> Instant {
        Instant::from_micros(self.t_us)
    }

    /// Its bytes.
    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let (id, extended) = self.frame.raw_id();
        let mut flags = 0;
        if extended {
            flags |= EXTENDED;
        }
        let len = if self.frame.is_remote() {
            flags |= REMOTE;
            u8::try_from(embedded_can::Frame::dlc(&self.frame)).unwrap_or(8)
        } else {
            u8::try_from(self.frame.payload().len()).unwrap_or(8)
        };
        let mut data = [0u8; 8];
        for (to, from) in data.iter_mut().zip(self.frame.payload()) {
            *to = *from;
        }
        let [t0, t1, t2, t3, t4, t5, t6, t7] = self.t_us.to_le_bytes();
        let [i0, i1, i2, i3] = id.to_le_bytes();
        let [d0, d1, d2, d3, d4, d5, d6, d7] = data;
        [
            t0, t1, t2, t3, t4, t5, t6, t7, i0, i1, i2, i3, flags, len, 0, 0, d0, d1, d2, d3, d4,
            d5, d6, d7,
        ]
    }

    /// Reads it back, checking the id against its format and the length.
    pub fn decode(bytes: &[u8; FRAME_LEN]) -> Result<Self, JobError> {
        let [
            t0,
            t1,
            t2,
            t3,
            t4,
            t5,
            t6,
            t7,
            i0,
            i1,
            i2,
            i3,
            flags,
            len,
            r0,
            r1,
            d0,
            d1,
            d2,
            d3,
            d4,
            d5,
            d6,
            d7,
        ] = *bytes;
        if flags & !(EXTENDED | REMOTE) != 0 || [r0, r1] != [0, 0] {
            return Err(JobError::Reserved);
        }
        let raw = u32::from_le_bytes([i0, i1, i2, i3]);
        let id = raw_id(raw, flags & EXTENDED != 0).ok_or(JobError::BadId(raw))?;
        if len > 8 {
            return Err(JobError::BadLength(len));
        }
        let frame = if flags & REMOTE != 0 {
            <Frame as embedded_can::Frame>::new_remote(id, usize::from(len))
        } else {
            let data = [d0, d1, d2, d3, d4, d5, d6, d7];
            Frame::data(id, data.get(..usize::from(len)).unwrap_or(&[]))
        }
        .ok_or(JobError::BadLength(len))?;
        Ok(TimedFrame {
            t_us: u64::from_le_bytes([t0, t1, t2, t3, t4, t5, t6, t7]),
            frame,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::Frame as _;

    #[test]
    fn frames_round_trip_with_their_format_and_length() {
        let frames = [
            Frame::with_raw_id(0x123, false, &[1, 2, 3]).unwrap(),
            Frame::with_raw_id(0x1ABC_DEF0, true, &[0xFF; 8]).unwrap(),
            Frame::with_raw_id(0x7FF, false, &[]).unwrap(),
            Frame::new_remote(raw_id(0x42, false).unwrap(), 5).unwrap(),
        ];
        for (index, frame) in frames.into_iter().enumerate() {
            let timed = TimedFrame {
                t_us: 1_000_000_007 * index as u64,
                frame,
            };
            assert_eq!(TimedFrame::decode(&timed.encode()), Ok(timed));
        }
    }

    #[test]
    fn bad_frames_are_refused_with_their_reason() {
        let good = TimedFrame {
            t_us: 5,
            frame: Frame::with_raw_id(0x123, false, &[1]).unwrap(),
        }
        .encode();
        let mut bad_id = good;
        bad_id[9] = 0x08; // 0x823 does not fit 11 bits
        assert_eq!(TimedFrame::decode(&bad_id), Err(JobError::BadId(0x823)));
        let mut bad_len = good;
        bad_len[13] = 9;
        assert_eq!(TimedFrame::decode(&bad_len), Err(JobError::BadLength(9)));
        let mut bad_flags = good;
        bad_flags[12] = 4;
        assert_eq!(TimedFrame::decode(&bad_flags), Err(JobError::Reserved));
    }

    #[test]
    fn headers_and_nodes_round_trip_and_bad_ones_are_refused() {
        let header = JobHeader {
            nodes: 3,
            frames: 70_000,
        };
        assert_eq!(JobHeader::decode(&header.encode()), Ok(header));
        let mut bad = header.encode();
        bad[0] = b'X';
        assert_eq!(JobHeader::decode(&bad), Err(JobError::BadMagic));
        let mut newer = header.encode();
        newer[4] = 2;
        assert_eq!(
            JobHeader::decode(&newer),
            Err(JobError::UnsupportedVersion(2))
        );
        let node = NodeEntry {
            node_id: 7,
            image_len: 4321,
        };
        assert_eq!(NodeEntry::decode(&node.encode()), Ok(node));
        let mut reserved = node.encode();
        reserved[2] = 1;
        assert_eq!(NodeEntry::decode(&reserved), Err(JobError::Reserved));
    }
}
