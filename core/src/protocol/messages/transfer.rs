//! Table transfer and its authentication: the open that starts a keyed transfer and the status
//! that ends every transfer. (The ISO-TP frames themselves, the challenge and the receipt carry
//! raw bytes: they are [`super::Message`] variants without a type of their own.)

use crate::protocol::TransferStatusCode;

/// Flag bit of [`TransferOpen::flags`]: replace whatever version runs (the keyed version reset:
/// the image's version need not be newer; version 0 is still refused).
pub const OPEN_REPLACE: u8 = 0x01;
/// Flag bit of [`TransferOpen::flags`]: the open is for a schema message (SchemaTransfer), not a
/// table image. Its MAC is the image MAC with this flag, so neither can stand for the other.
pub const OPEN_SCHEMA: u8 = 0x02;
/// Flag bit of [`TransferOpen::flags`]: the open authorises a firmware update's Begin message
/// (UpdateTransfer; its `length` is then the Begin's, 97 bytes), not a table image. Alone: not
/// with [`OPEN_REPLACE`] (an image's trailer says whether it may downgrade) nor [`OPEN_SCHEMA`].
/// Covered by the tag like the other flags, so no open can stand for another kind's.
pub const OPEN_UPDATE: u8 = 0x04;

/// Opens an authenticated transfer (service 0x15), tool → node, on a node with a key: a table
/// image (TableTransfer), with [`OPEN_SCHEMA`] a schema message (SchemaTransfer), or with
/// [`OPEN_UPDATE`] a firmware update's Begin message (UpdateTransfer).
///
/// ```text
/// bytes 0-1  ISO-TP message length (the image or schema message and its 16-byte MAC; an
///            update's Begin: 97), u16 LE
/// byte 2     flags: bit 0 replace whatever version runs (OPEN_REPLACE), bit 1 a schema
///            (OPEN_SCHEMA), bit 2 an update's Begin (OPEN_UPDATE); bit 1 and bit 2 each
///            alone; bits 3-7 reserved, 0
/// bytes 3-7  tag: CMAC (domain 2, node, both nonces, length, flags), first 5 bytes
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TransferOpen {
    /// The ISO-TP message length that the first frame must announce.
    pub length: u16,
    /// [`OPEN_REPLACE`], [`OPEN_SCHEMA`], [`OPEN_UPDATE`] or 0.
    pub flags: u8,
    /// The tag over the challenge.
    pub tag: [u8; crate::auth::OPEN_TAG_LEN],
}

/// The outcome of a table transfer (service 0x12), node → tool.
///
/// ```text
/// byte 0     status (TransferStatusCode)
/// byte 1     detail: for InvalidTable, which check failed (see docs); otherwise 0
/// bytes 2-5  version of the table running after this transfer, u32 LE
/// bytes 6-7  reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TransferStatus {
    /// What happened.
    pub status: TransferStatusCode,
    /// Status-specific detail.
    pub detail: u8,
    /// The version running now.
    pub running_version: u32,
}

use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Values};

impl TransferOpen {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::TransferOpen,
        &[
            Field::new(
                "length",
                0,
                16,
                "ISO-TP message length the first frame must announce (image + 16-byte MAC; an \
                 update's Begin: 97)",
            )
            .unit("B"),
            Field::new(
                "replace",
                16,
                1,
                "1: replace whatever version runs (the keyed version reset)",
            ),
            Field::new(
                "schema",
                17,
                1,
                "1: the transfer is a schema message (SchemaTransfer), not a table image",
            ),
            Field::new(
                "update",
                18,
                1,
                "1: the transfer is a firmware update's Begin (UpdateTransfer, length 97), alone",
            ),
            Field::new(
                "tag",
                24,
                40,
                "CMAC (domain 2, node, both nonces, length, flags), first 5 bytes",
            ),
        ],
        "opens an authenticated transfer of this length: a table image, a schema message \
         (schema) or a firmware update's Begin (update).",
    );
}

impl TransferStatus {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::TransferStatus,
        &[
            Field::new("status", 0, 8, "the outcome of the transfer")
                .values(Values::TransferStatusCode),
            Field::new(
                "detail",
                8,
                8,
                "for InvalidTable, which check of the loader failed; otherwise 0",
            ),
            Field::new(
                "running_version",
                16,
                32,
                "version of the table running after this transfer",
            ),
            Field::reserved("reserved", 48, 16),
        ],
        "the outcome of a table transfer, to the tool.",
    );
}

/// The layout of a table transfer's frames (service 0x11): ISO-TP.
pub const TABLE_TRANSFER_LAYOUT: Layout = Layout::isotp(
    Service::TableTransfer,
    "ISO 15765-2 frames of a table image, padded to 8 bytes; the node's flow control back on \
     the same service.",
);

/// The layout of a challenge request (service 0x13): the tool's nonce, u64 LE, as its two halves.
pub const CHALLENGE_REQUEST_LAYOUT: Layout = Layout::fixed(
    Service::ChallengeRequest,
    &[
        Field::new("tool_nonce_low", 0, 32, "the tool's nonce: bits 0-31"),
        Field::new("tool_nonce_high", 32, 32, "the tool's nonce: bits 32-63"),
    ],
    "asks a node with a key for a challenge, with the tool's nonce: 64 random bits, new for \
     every exchange.",
);

/// The layout of a challenge (service 0x14): the node's nonce (48 bits LE, as a low word and a
/// high half-word) and the binding.
pub const CHALLENGE_LAYOUT: Layout = Layout::fixed(
    Service::Challenge,
    &[
        Field::new("node_nonce_low", 0, 32, "the node's nonce: bits 0-31"),
        Field::new("node_nonce_high", 32, 16, "the node's nonce: bits 32-47"),
        Field::new(
            "binding",
            48,
            16,
            "CMAC (domain 5, node, tool nonce, node nonce): bytes 0-1",
        ),
    ],
    "the node's nonce (a CMAC under its key of boot salt and counter: unpredictable), bound to \
     the request's tool nonce; every tag of the exchange covers both nonces. Valid 1 s; re-sent \
     unchanged to a request with the same tool nonce.",
);

/// The layout of a receipt (service 0x16): the 8-byte tag, as its two halves.
pub const RECEIPT_LAYOUT: Layout = Layout::fixed(
    Service::Receipt,
    &[
        Field::new(
            "tag_low",
            0,
            32,
            "CMAC (domain 4, node, both nonces, the TransferStatus bytes, running CRC, stored flag): \
             bytes 0-3",
        ),
        Field::new("tag_high", 32, 32, "the same CMAC: bytes 4-7"),
    ],
    "authenticates the TransferStatus that ended an opened transfer.",
);
