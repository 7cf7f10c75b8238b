//! Payload codecs, one type per service. Every decoder checks the exact length and every enumerated
//! or reserved field; a frame that fails is refused with a [`DecodeError`], never half-read.
//!
//! One file per family of services (`status`, `coordination`, `diagnostic`, `transfer`,
//! `schema_server`, `identity`, `seal`, `update`) for the payload types and their documented layouts; one for the encoder
//! and one for the decoder, each a single match over every message, so that a board links one
//! copy of each and a new message is put in both.

mod coordination;
mod decode;
mod diagnostic;
mod encode;
mod identity;
#[cfg(test)]
mod layout_tests;
mod schema_server;
mod seal;
mod status;
#[cfg(test)]
mod tests;
mod transfer;
mod update;

pub use coordination::{
    DesireFrame, Exploitation, FilterProfile, FilterSet, FilterStatus, Gates, Intention,
};
pub use decode::DecodeError;
pub use diagnostic::{DiagnosticControl, DiagnosticFlags, DiagnosticSample};
pub use identity::{Assign, ConfigStatus, Configure, identity_part, identity_service};
pub(super) use identity::{
    IDENTITY_BUILD_LAYOUT, IDENTITY_CAPACITY_LAYOUT, IDENTITY_FEATURES_LAYOUT, IDENTITY_LAYOUT,
    IDENTITY_NAME_LAYOUT, IDENTITY_REQUEST_LAYOUT, IDENTITY_VERSION_LAYOUT,
};
pub(super) use schema_server::{
    EMERGENCY_STOP_LAYOUT, SCHEMA_ABORT_LAYOUT, SCHEMA_TRANSFER_LAYOUT,
};
pub use schema_server::{SchemaAck, SchemaState, SchemaTransition};
pub use seal::Seal;
pub(super) use seal::{FRESHNESS_LAYOUT, FRESHNESS_REQUEST_LAYOUT};
pub use status::{Errors, Fault, Heartbeat, TableStatus, Traffic};
pub(super) use transfer::{
    CHALLENGE_LAYOUT, CHALLENGE_REQUEST_LAYOUT, RECEIPT_LAYOUT, TABLE_TRANSFER_LAYOUT,
};
pub use transfer::{OPEN_REPLACE, OPEN_SCHEMA, OPEN_UPDATE, TransferOpen, TransferStatus};
pub(super) use update::UPDATE_TRANSFER_LAYOUT;
pub use update::UpdateStatus;

use super::Service;

/// Any frame of our protocol, decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Message {
    /// See [`Fault`].
    Fault(Fault),
    /// See [`Heartbeat`].
    Heartbeat(Heartbeat),
    /// See [`TableStatus`].
    TableStatus(TableStatus),
    /// See [`Traffic`].
    Traffic(Traffic),
    /// See [`Errors`].
    Errors(Errors),
    /// See [`DiagnosticSample`].
    Diagnostic(DiagnosticSample),
    /// See [`Gates`].
    Gates(Gates),
    /// See [`DesireFrame`].
    Desire(DesireFrame),
    /// See [`Intention`].
    Intention(Intention),
    /// See [`FilterStatus`].
    FilterStatus(FilterStatus),
    /// See [`Exploitation`].
    Exploitation(Exploitation),
    /// See [`FilterProfile`].
    FilterProfile(FilterProfile),
    /// See [`FilterSet`].
    FilterSet(FilterSet),
    /// See [`DiagnosticControl`].
    DiagnosticControl(DiagnosticControl),
    /// One ISO-TP frame of a table transfer (or its flow control), passed to [`crate::isotp`].
    TableTransfer {
        /// The frame's bytes.
        data: [u8; 8],
        /// How many of them the frame carried.
        len: u8,
    },
    /// See [`TransferStatus`].
    TransferStatus(TransferStatus),
    /// A [`DiagnosticControl`] followed by its tag (service 0x10, 8 bytes): the form a node with
    /// a key takes.
    AuthenticatedDiagnosticControl {
        /// The command.
        control: DiagnosticControl,
        /// CMAC (domain 1, node, service, both nonces, the 4 bytes of `control`), first 4 bytes.
        tag: [u8; crate::auth::COMMAND_TAG_LEN],
    },
    /// Asks a node for a challenge (service 0x13): the tool's nonce, u64 LE.
    ChallengeRequest {
        /// The tool's nonce: random, one per exchange ([`crate::auth::Authenticator::exchange`]).
        tool_nonce: u64,
    },
    /// A node's challenge (service 0x14): its nonce (48 bits LE) and the binding to the request
    /// it answers.
    Challenge {
        /// The node's nonce, at most [`crate::auth::NODE_NONCE_MAX`]: the bits above are not
        /// sent.
        node_nonce: u64,
        /// [`crate::auth::Exchange::binding`] of the node and both nonces.
        binding: [u8; crate::auth::BINDING_LEN],
    },
    /// See [`TransferOpen`].
    TransferOpen(TransferOpen),
    /// Authenticates the TransferStatus that ended an opened transfer (service 0x16): CMAC
    /// (domain 4, node, both nonces, that TransferStatus's 8 bytes, the running image's CRC, its stored
    /// flag), first 8 bytes.
    Receipt {
        /// The tag.
        tag: [u8; crate::auth::RECEIPT_TAG_LEN],
    },
    /// Stop (service 0x00, no payload): from anyone, to a node or to all; never refused.
    EmergencyStop,
    /// Abandon the client's program (service 0x19, no payload): from anyone, to a node or to
    /// all; never refused.
    SchemaAbort,
    /// One ISO-TP frame of a schema message (or its flow control), passed to [`crate::isotp`]:
    /// the message is a channel byte ([`SchemaChannel`](crate::protocol::SchemaChannel)) and the schema's postcard bytes, or on
    /// the limits channel the postcard bytes of [`crate::schema::Limits`].
    SchemaTransfer {
        /// The frame's bytes.
        data: [u8; 8],
        /// How many of them the frame carried.
        len: u8,
    },
    /// See [`SchemaAck`].
    SchemaAck(SchemaAck),
    /// See [`SchemaTransition`].
    SchemaTransition(SchemaTransition),
    /// See [`SchemaState`].
    SchemaState(SchemaState),
    /// See [`Seal`].
    Seal(Seal),
    /// A keyed receiver asks a sender for its freshness (service 0x1F): the receiver's nonce,
    /// u64 LE ([`crate::seal`]).
    FreshnessRequest {
        /// Unpredictable without the key, new for every request.
        nonce: u64,
    },
    /// A sender's answer to a freshness request (service 0x20), followed by its seal over the
    /// request's nonce ([`crate::seal`]).
    Freshness {
        /// The sender's epoch: its boot salt.
        epoch: u32,
        /// The last counter it used in that epoch.
        counter: u32,
    },
    #[cfg(feature = "identity")]
    /// Asks for a node's identity (service 0x21, no payload).
    IdentityRequest,
    #[cfg(feature = "identity")]
    /// One of a node's six identity frames (services 0x22-0x27, [`crate::identity`]).
    Identity {
        /// Which.
        part: crate::identity::IdentityPart,
        /// Its 8 bytes ([`crate::identity::Identity::payload`]).
        payload: [u8; 8],
    },
    #[cfg(feature = "identity")]
    /// See [`Assign`].
    Assign(Assign),
    #[cfg(feature = "identity")]
    /// See [`Configure`].
    Configure(Configure),
    #[cfg(feature = "identity")]
    /// See [`ConfigStatus`].
    ConfigStatus(ConfigStatus),
    #[cfg(feature = "update")]
    /// One ISO-TP frame of a firmware-update message (or its flow control), passed to
    /// [`crate::isotp`]: the message is a Begin, a Chunk, a Commit or an Abort
    /// ([`Service::UpdateTransfer`]).
    UpdateTransfer {
        /// The frame's bytes.
        data: [u8; 8],
        /// How many of them the frame carried.
        len: u8,
    },
    #[cfg(feature = "update")]
    /// See [`UpdateStatus`].
    UpdateStatus(UpdateStatus),
}

impl Message {
    /// The service this message belongs to.
    pub const fn service(&self) -> Service {
        match self {
            Message::Fault(_) => Service::Fault,
            Message::Heartbeat(_) => Service::Heartbeat,
            Message::TableStatus(_) => Service::TableStatus,
            Message::Traffic(_) => Service::Traffic,
            Message::Errors(_) => Service::Errors,
            Message::Diagnostic(_) => Service::Diagnostic,
            Message::Gates(_) => Service::Gates,
            Message::Desire(_) => Service::Desire,
            Message::Intention(_) => Service::Intention,
            Message::FilterStatus(_) => Service::FilterStatus,
            Message::Exploitation(_) => Service::Exploitation,
            Message::FilterProfile(_) => Service::FilterProfile,
            Message::FilterSet(_) => Service::FilterSet,
            Message::DiagnosticControl(_) => Service::DiagnosticControl,
            Message::TableTransfer { .. } => Service::TableTransfer,
            Message::TransferStatus(_) => Service::TransferStatus,
            Message::AuthenticatedDiagnosticControl { .. } => Service::DiagnosticControl,
            Message::ChallengeRequest { .. } => Service::ChallengeRequest,
            Message::Challenge { .. } => Service::Challenge,
            Message::TransferOpen(_) => Service::TransferOpen,
            Message::Receipt { .. } => Service::Receipt,
            Message::EmergencyStop => Service::EmergencyStop,
            Message::SchemaAbort => Service::SchemaAbort,
            Message::SchemaTransfer { .. } => Service::SchemaTransfer,
            Message::SchemaAck(_) => Service::SchemaAck,
            Message::SchemaTransition(_) => Service::SchemaTransition,
            Message::SchemaState(_) => Service::SchemaState,
            Message::Seal(_) => Service::Seal,
            Message::FreshnessRequest { .. } => Service::FreshnessRequest,
            Message::Freshness { .. } => Service::Freshness,
            #[cfg(feature = "identity")]
            Message::IdentityRequest => Service::IdentityRequest,
            #[cfg(feature = "identity")]
            Message::Identity { part, .. } => identity_service(*part),
            #[cfg(feature = "identity")]
            Message::Assign(_) => Service::Assign,
            #[cfg(feature = "identity")]
            Message::Configure(_) => Service::Configure,
            #[cfg(feature = "identity")]
            Message::ConfigStatus(_) => Service::ConfigStatus,
            #[cfg(feature = "update")]
            Message::UpdateTransfer { .. } => Service::UpdateTransfer,
            #[cfg(feature = "update")]
            Message::UpdateStatus(_) => Service::UpdateStatus,
        }
    }
}
