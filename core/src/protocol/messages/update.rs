//! Firmware update over the bus: the status a node sends of an update (service 0x2C), and the
//! layout of the update's ISO-TP frames (service 0x2B, framed as a table transfer's). The
//! messages those frames carry (Begin, Chunk, Commit, Abort: [`Service::UpdateTransfer`]) are
//! the update session's business (`crate::update`), not a payload of this module.

use crate::protocol::Service;
use crate::protocol::UpdateStatusCode;
use crate::protocol::layout::{Field, Layout, Values};

/// The state of a firmware update (service 0x2C), node → tool: the answer to each
/// UpdateTransfer message, or a report at start (Swapped, Refused).
///
/// ```text
/// byte 0     status (UpdateStatusCode)
/// bytes 1-3  the next image byte the node expects, u24 LE
/// bytes 4-7  value, u32 LE: Ack, Committed, OutOfOrder, Mismatch: the CRC-32 of the image
///            bytes before the offset; Refused: the refusal's code (1-7); Ready: the largest
///            chunk the node takes, bytes; otherwise 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateStatus {
    /// What happened.
    pub status: UpdateStatusCode,
    /// The next image byte the node expects (24 bits on the wire: at most 0xFF_FFFF).
    pub offset: u32,
    /// Ack, Committed, OutOfOrder and Mismatch: the CRC-32 of the image bytes before `offset`;
    /// Refused: the refusal's code (pab_core::update::UpdateRefusal::code, 1-7);
    /// Ready: the largest chunk the node takes, bytes; otherwise 0.
    pub value: u32,
}

impl UpdateStatus {
    /// The largest offset the frame carries (24 bits): 16 MiB - 1, far above any update
    /// partition here.
    ///
    /// The encoder cannot fail (no encoder of this protocol does), so an `offset` above it is
    /// sent **saturated** to this value, as [`super::Heartbeat`]'s 24-bit uptime is: a tool that
    /// reads 0xFF_FFFF knows the offset is out of range, where one taken modulo 2^24 would
    /// name a plausible, smaller position in the image and could send a tool back to it without
    /// a sign of error. The field stays a `u32`, like the image offsets of the update session
    /// and the Chunk message, so that a node's offset needs no conversion.
    pub const MAX_OFFSET: u32 = 0x00FF_FFFF;

    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::UpdateStatus,
        &[
            Field::new("status", 0, 8, "what happened").values(Values::UpdateStatusCode),
            Field::new(
                "offset",
                8,
                24,
                "the next image byte the node expects (FlashError: where the write failed)",
            )
            .unit("B"),
            Field::new(
                "value",
                32,
                32,
                "Ack, Committed, OutOfOrder, Mismatch: CRC-32 of the image bytes before offset; \
                 Refused: the refusal's code (1-7); Ready: the largest chunk, bytes; otherwise 0",
            ),
        ],
        "the state of a firmware update, to the tool: the answer to each UpdateTransfer message, \
         or at start the bootloader's verdict on a new image (Swapped, Refused).",
    );
}

/// The layout of a firmware update's frames (service 0x2B): ISO-TP.
pub const UPDATE_TRANSFER_LAYOUT: Layout = Layout::isotp(
    Service::UpdateTransfer,
    "ISO 15765-2 frames of a firmware-update message (Begin, Chunk, Commit, Abort), padded to 8 \
     bytes; the node's flow control back on the same service.",
);
