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

/// Opens an authenticated transfer (service 0x15), tool → node, on a node with a key: a table
/// image (TableTransfer) or, with [`OPEN_SCHEMA`], a schema message (SchemaTransfer).
///
/// ```text
/// bytes 0-1  ISO-TP message length (the image or schema message and its 16-byte MAC), u16 LE
/// byte 2     flags: bit 0 replace whatever version runs (OPEN_REPLACE), bit 1 a schema
///            (OPEN_SCHEMA), not both; bits 2-7 reserved, 0
/// bytes 3-7  tag: CMAC (domain 2, node, nonce, length, flags), first 5 bytes
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TransferOpen {
    /// The ISO-TP message length that the first frame must announce.
    pub length: u16,
    /// [`OPEN_REPLACE`], [`OPEN_SCHEMA`] or 0.
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
