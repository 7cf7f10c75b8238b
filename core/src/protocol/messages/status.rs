//! What every node reports of itself: its heartbeat and the status that follows it (table,
//! traffic, errors), and its faults.

use crate::protocol::{FaultCode, NodeState};

/// A node's heartbeat (service 0x02), sent every heartbeat period (1 s by default) to
/// [`BROADCAST`](crate::protocol::BROADCAST), followed by [`TableStatus`], [`Traffic`] and [`Errors`].
///
/// ```text
/// byte 0     state (NodeState)
/// bytes 1-3  uptime in seconds, 24-bit little endian, saturating at 2^24-1 (194 days)
/// bytes 4-7  running table version, u32 LE (0 without a table)
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Heartbeat {
    /// The node's state.
    pub state: NodeState,
    /// Seconds since boot (saturates at 2^24-1 on the wire).
    pub uptime_s: u32,
    /// The running table's version, 0 without one.
    pub table_version: u32,
}

/// The running table (service 0x03).
///
/// ```text
/// bytes 0-3  image CRC-32 (the CRC field of its header), u32 LE; 0 without a table
/// bytes 4-5  image length in bytes, u16 LE
/// byte 6     number of ports
/// byte 7     flags: bit 0 the table is stored (the node boots with it);
///                   bit 1 the diagnostic stream is on;
///                   bit 2 the node has a key (it takes only authenticated configuration)
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TableStatus {
    /// CRC-32 from the image header.
    pub crc: u32,
    /// Image length in bytes.
    pub image_len: u16,
    /// Number of ports.
    pub ports: u8,
    /// Whether the node will boot with this table.
    pub stored: bool,
    /// Whether the diagnostic stream is on.
    pub diagnostic: bool,
    /// Whether the node has a key: without one, it accepts configuration from anyone on the bus.
    pub keyed: bool,
}

/// Traffic counters since boot (service 0x04), wrapping at 2^32.
///
/// ```text
/// bytes 0-3  frames received from the bus, u32 LE
/// bytes 4-7  deliveries (one per port a frame was delivered to), u32 LE
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Traffic {
    /// Frames received from the bus, of every kind.
    pub received: u32,
    /// Deliveries to ports.
    pub delivered: u32,
}

/// Loss and error counters since boot (service 0x05), wrapping at 2^32.
///
/// ```text
/// bytes 0-3  frames discarded: they fed at least one port and were delivered to none, u32 LE
/// bytes 4-7  errors: bus errors, overruns, malformed frames of our protocol, u32 LE
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Errors {
    /// Frames that lost arbitration at every port they fed.
    pub discarded: u32,
    /// Errors of every kind.
    pub errors: u32,
}

/// A fault (service 0x01), to [`BROADCAST`](crate::protocol::BROADCAST) at the highest priority, at most once per code
/// per rate-limit interval (100 ms by default); occurrences in between are counted.
///
/// ```text
/// bytes 0-1  code (FaultCode), u16 LE
/// byte 2     occurrences since the last frame with this code, saturating at 255 (at least 1)
/// bytes 3-7  detail, code-specific, 0 where unused
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Fault {
    /// What happened.
    pub code: FaultCode,
    /// How many times since the last frame with this code.
    pub count: u8,
    /// Code-specific detail.
    pub detail: [u8; 5],
}

use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Values};

impl Heartbeat {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Heartbeat,
        &[
            Field::new("state", 0, 8, "the node's state").values(Values::NodeState),
            Field::new(
                "uptime",
                8,
                24,
                "seconds since boot, saturating at 2^24-1 (194 days)",
            )
            .unit("s"),
            Field::new(
                "table_version",
                32,
                32,
                "version of the running table, 0 without a table",
            ),
        ],
        "every heartbeat period (1 s by default), followed by TableStatus, Traffic and Errors.",
    );
}

impl TableStatus {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::TableStatus,
        &[
            Field::new(
                "crc",
                0,
                32,
                "CRC-32 of the running image (its header's CRC field), 0 without a table",
            ),
            Field::new("image_len", 32, 16, "image length").unit("B"),
            Field::new("ports", 48, 8, "number of ports of the table"),
            Field::new(
                "stored",
                56,
                1,
                "1: the table is stored, the node boots with it",
            ),
            Field::new("diagnostic", 57, 1, "1: the diagnostic stream is on"),
            Field::new(
                "keyed",
                58,
                1,
                "1: the node has a key and takes only authenticated configuration; 0: it \
                 accepts configuration from anyone on the bus",
            ),
        ],
        "the running table, after every heartbeat.",
    );
}

impl Traffic {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Traffic,
        &[
            Field::new(
                "received",
                0,
                32,
                "frames received from the bus since boot, wrapping",
            ),
            Field::new(
                "delivered",
                32,
                32,
                "deliveries since boot (one per port a frame was delivered to), wrapping",
            ),
        ],
        "counters since boot, after every heartbeat.",
    );
}

impl Errors {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Errors,
        &[
            Field::new(
                "discarded",
                0,
                32,
                "frames that fed at least one port and were delivered to none, since boot, \
                 wrapping",
            ),
            Field::new(
                "errors",
                32,
                32,
                "bus errors, overruns and malformed frames of the protocol, since boot, wrapping",
            ),
        ],
        "loss and error counters since boot, after every heartbeat.",
    );
}

impl Fault {
    /// The payload's layout: the detail is five bytes, each a field, since what they hold
    /// depends on the code (the FaultCode table of `docs/can-protocol.md`).
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Fault,
        &[
            Field::new("code", 0, 16, "what happened (FaultCode)").values(Values::FaultCode),
            Field::new(
                "count",
                16,
                8,
                "occurrences since the last frame with this code, at least 1, saturating at 255",
            ),
            Field::new(
                "detail0",
                24,
                8,
                "detail byte 0: for BadStoredTable and TableRefused the TransferStatusCode of the \
                 verdict (BadStoredTable: 0xFF when the store could not be read); for BusError a \
                 driver-specific kind; for BadCommand the service code of the malformed frame; \
                 for RxOverrun the low byte of the frames lost (bytes 0-3: u32 LE); otherwise 0",
            ),
            Field::new(
                "detail1",
                32,
                8,
                "detail byte 1: for BadStoredTable and TableRefused the verdict's detail (for \
                 WrongNode the image's node id); after 0xFF in byte 0, the StoreFailure: 1 the \
                 store could not be read, 2 the image is too large, 3 no stored copy verifies, \
                 4 other; for RxOverrun the frames lost, byte 1; otherwise 0",
            ),
            Field::new(
                "detail2",
                40,
                8,
                "detail byte 2, code-specific (RxOverrun: the frames lost, byte 2), 0 where unused",
            ),
            Field::new(
                "detail3",
                48,
                8,
                "detail byte 3, code-specific (RxOverrun: the frames lost, byte 3), 0 where unused",
            ),
            Field::new(
                "detail4",
                56,
                8,
                "detail byte 4, code-specific, 0 where unused",
            ),
        ],
        "sent when it happens, at most once per code per 100 ms; occurrences in between are \
         counted.",
    );
}
