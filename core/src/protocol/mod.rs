//! The project's own frames: node heartbeat and status, faults, the diagnostic stream, its control,
//! table transfer, firmware update, and the schema server's (emergency stop, abort, schema transfer and reports). `docs/can-protocol.md` is the user-facing description of the same thing;
//! this module is its only implementation (nodes and `pabctl` both use it).
//!
//! # Identifier layout (29-bit extended)
//!
//! ```text
//!  28..26   25..24   23..16    15..8         7..0
//! priority  marker   service   destination   source
//!   0-7      0b10     8 bits    node or 0xFF  node or 0
//! ```
//!
//! - **Priority** first, as in Cyphal/CAN, so that the bus itself ranks our traffic: the
//!   emergency stop and faults (0) win arbitration over everything else we send (the emergency
//!   stop, service 0, over faults too), the diagnostic stream (7) loses to everything.
//! - **Marker** `0b10`: our frames occupy one quarter of the extended space, and a node tells
//!   them from the topics it arbitrates with one mask. Any other value means "not ours".
//! - **Service**: what the payload is ([`Service`]).
//! - **Destination / source**: node ids are 1..=127; [`TOOL`] (0) is the workstation (`pabctl`);
//!   [`BROADCAST`] (0xFF) as a destination addresses every node. Carrying both addresses in the
//!   identifier is what ISO 15765-2 calls normal fixed addressing: a table transfer to node 3 and
//!   its flow control back use the same service with the addresses swapped.
//!
//! Payloads are little endian and fixed length; a frame whose length differs from its service's is
//! refused by [`Message::decode`] (never guessed at).

mod classify;
mod codes;
pub mod layout;
mod messages;
#[cfg(feature = "schema")]
mod schema;

pub use classify::{FrameKind, classify, classify_id};
pub use codes::{
    AuthFailure, ConfigStatusCode, FaultCode, NodeState, STORE_UNREADABLE, SchemaChannel,
    SchemaOrigin, SchemaOutcome, SchemaSafety, SchemaTrigger, StoreFailure, TransferStatusCode,
    UpdateStatusCode,
};
pub use messages::DecodeError;
pub use messages::{
    Assign, ConfigStatus, Configure, DesireFrame, DiagnosticControl, DiagnosticFlags,
    DiagnosticSample, Errors, Exploitation, Fault, FilterProfile, FilterSet, FilterStatus, Gates,
    Heartbeat, Intention, Message, OPEN_REPLACE, OPEN_SCHEMA, OPEN_UPDATE, SchemaAck, SchemaState,
    SchemaTransition, Seal, TableStatus, Traffic, TransferOpen, TransferStatus, UpdateStatus,
};
pub use messages::{identity_part, identity_service};

use embedded_can::{ExtendedId, Id};

/// The address of the workstation tool (`pabctl`).
pub const TOOL: u8 = 0;
/// The destination that addresses every node.
pub const BROADCAST: u8 = 0xFF;
/// The address the intention node (HBBA's intention workspace) uses unless told otherwise: the
/// DBC export describes its frames ([`Service::Intention`], [`Service::FilterProfile`],
/// [`Service::FilterSet`]) from it. A network's nodes may not use it when the network has an
/// `[hbba]` section.
pub const INTENTION: u8 = 126;
/// The largest node id.
pub const MAX_NODE_ID: u8 = 127;

/// Bits 25..24 of every identifier of ours.
const MARKER: u32 = 0b10;

/// Bus priority, 0 (wins arbitration) to 7.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Priority(u8);

impl Priority {
    /// Safety traffic: the emergency stop and faults.
    pub const EXCEPTIONAL: Priority = Priority(0);
    /// Stopping a program: the schema server's abort.
    pub const URGENT: Priority = Priority(1);
    /// Answers the tool waits for (transfer status), and the schema server's transfers and
    /// answers.
    pub const HIGH: Priority = Priority(2);
    /// Commands from the tool.
    pub const COMMAND: Priority = Priority(3);
    /// Heartbeats and status.
    pub const NOMINAL: Priority = Priority(4);
    /// Counters.
    pub const LOW: Priority = Priority(5);
    /// Bulk transfer (table and firmware images).
    pub const BULK: Priority = Priority(6);
    /// Diagnostic stream.
    pub const OPTIONAL: Priority = Priority(7);

    /// A priority from its 3-bit value; `None` above 7.
    pub const fn new(value: u8) -> Option<Priority> {
        if value <= 7 {
            Some(Priority(value))
        } else {
            None
        }
    }

    /// The 3-bit value.
    pub const fn value(self) -> u8 {
        self.0
    }
}

/// What a frame of ours carries (bits 23..16 of the identifier).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Service {
    /// Anyone → node(s): stop (no payload). The schema server halts within one loop period; the
    /// lowest identifier of all our frames.
    EmergencyStop = 0x00,
    /// Node → all: a fault, rate-limited ([`Fault`]).
    Fault = 0x01,
    /// Node → all: state, uptime, table version ([`Heartbeat`]).
    Heartbeat = 0x02,
    /// Node → all: table CRC and size, with every heartbeat ([`TableStatus`]).
    TableStatus = 0x03,
    /// Node → all: frames received and delivered, with every heartbeat ([`Traffic`]).
    Traffic = 0x04,
    /// Node → all: frames discarded, errors, with every heartbeat ([`Errors`]).
    Errors = 0x05,
    /// Node → all: one connection's stimulation, when the stream is on ([`DiagnosticSample`]).
    Diagnostic = 0x06,
    /// Node → all: the gates of a competitive-dynamics group the node runs ([`Gates`]).
    Gates = 0x07,
    /// Motivation → all: a desire for the intention workspace ([`DesireFrame`]).
    Desire = 0x08,
    /// Intention node → all: the strategies it selected ([`Intention`]).
    Intention = 0x09,
    /// Node → all: its message filters' profile and counts ([`FilterStatus`]).
    FilterStatus = 0x0A,
    /// Node → all: a connection started or stopped delivering ([`Exploitation`]).
    Exploitation = 0x0B,
    /// Tool → node(s): switches the diagnostic stream ([`DiagnosticControl`]).
    DiagnosticControl = 0x10,
    /// Tool ↔ node: ISO-TP frames of a table image (tool → node) and flow control (node → tool).
    TableTransfer = 0x11,
    /// Node → tool: the outcome of a table transfer ([`TransferStatus`]).
    TransferStatus = 0x12,
    /// Tool → node: asks a keyed node for a challenge, with the tool's nonce.
    ChallengeRequest = 0x13,
    /// Node → tool: the node's nonce, bound to the request's; every tag of the exchange covers both.
    Challenge = 0x14,
    /// Tool → node: opens an authenticated table transfer ([`TransferOpen`]).
    TransferOpen = 0x15,
    /// Node → tool: authenticates the TransferStatus that ended an opened transfer.
    Receipt = 0x16,
    /// Intention node → node: switches every message filter to a profile ([`FilterProfile`]).
    FilterProfile = 0x17,
    /// Intention node → node: sets one message filter ([`FilterSet`]).
    FilterSet = 0x18,
    /// Client → node(s): abandons the client's program (no payload): the schema server empties
    /// its queue and waits on the high-priority channel.
    SchemaAbort = 0x19,
    /// Client ↔ node: ISO-TP frames of a schema message (client → node) and flow control (node
    /// → client).
    SchemaTransfer = 0x1A,
    /// Node → the schema's sender: whether a schema message was accepted ([`SchemaAck`]).
    SchemaAck = 0x1B,
    /// Node → all: a schema change of the server ([`SchemaTransition`]).
    SchemaTransition = 0x1C,
    /// Node → all: the schema server's state, every 100 ms ([`SchemaState`]).
    SchemaState = 0x1D,
    /// Keyed node → the sealed frame's destination: authenticates the coordination frame it
    /// sent just before ([`Seal`], [`crate::seal`]).
    Seal = 0x1E,
    /// Keyed node → a sender: asks where the sender's freshness stands, with a nonce.
    FreshnessRequest = 0x1F,
    /// Keyed node → the requester: its epoch and counter, sealed over the request's nonce.
    Freshness = 0x20,
    /// Tool → node(s): asks for the node's identity (no payload; [`crate::identity`]).
    IdentityRequest = 0x21,
    /// Node → the requester, or all at start-up: identity part 0, uid bytes 0-7.
    Identity = 0x22,
    /// Node → the requester: identity part 1, uid bytes 8-11, firmware and protocol versions.
    IdentityVersion = 0x23,
    /// Node → the requester: identity part 2, the build id.
    IdentityBuild = 0x24,
    /// Node → the requester: identity part 3, capacities.
    IdentityCapacity = 0x25,
    /// Node → the requester: identity part 4, table formats, features, flags, bit rate.
    IdentityFeatures = 0x26,
    /// Node → the requester: identity part 5, the firmware's name.
    IdentityName = 0x27,
    /// Tool → node: gives the node (named by a check of its uid) its node id ([`Assign`]).
    Assign = 0x28,
    /// Tool → node: sets the bit rate from the next start ([`Configure`]).
    Configure = 0x29,
    /// Node → tool: answers an Assign or a Configure ([`ConfigStatus`]).
    ConfigStatus = 0x2A,
    /// Tool ↔ node: ISO-TP frames of a firmware-update message (tool → node) and flow control
    /// (node → tool), as [`Service::TableTransfer`]'s. The messages (little endian; their codec
    /// is `crate::update`'s session, not this module's):
    ///
    /// ```text
    /// Begin   byte 0 = 1, bytes 1-96: the signed image's manifest (its 32-byte trailer, then
    ///         its 64-byte Ed25519 signature: crate::update, crate::update::stored): 97 bytes
    /// Chunk   byte 0 = 2, bytes 1-4: offset in the image (u32), then 1 to 1024 bytes of the
    ///         image at that offset
    /// Commit  byte 0 = 3, bytes 1-4: CRC-32 of the whole image (u32): 5 bytes
    /// Abort   byte 0 = 4: 1 byte
    /// ```
    ///
    /// On a keyed node the Begin is authorised by a [`TransferOpen`] with [`OPEN_UPDATE`].
    /// The node answers each message with an [`UpdateStatus`].
    UpdateTransfer = 0x2B,
    /// Node → tool: the state of a firmware update ([`UpdateStatus`]).
    UpdateStatus = 0x2C,
}

impl Service {
    /// Every service, for tables (DBC export, documentation tests).
    pub const ALL: [Service; 41] = [
        Service::EmergencyStop,
        Service::Fault,
        Service::Heartbeat,
        Service::TableStatus,
        Service::Traffic,
        Service::Errors,
        Service::Diagnostic,
        Service::Gates,
        Service::Desire,
        Service::Intention,
        Service::FilterStatus,
        Service::Exploitation,
        Service::DiagnosticControl,
        Service::TableTransfer,
        Service::TransferStatus,
        Service::ChallengeRequest,
        Service::Challenge,
        Service::TransferOpen,
        Service::Receipt,
        Service::FilterProfile,
        Service::FilterSet,
        Service::SchemaAbort,
        Service::SchemaTransfer,
        Service::SchemaAck,
        Service::SchemaTransition,
        Service::SchemaState,
        Service::Seal,
        Service::FreshnessRequest,
        Service::Freshness,
        Service::IdentityRequest,
        Service::Identity,
        Service::IdentityVersion,
        Service::IdentityBuild,
        Service::IdentityCapacity,
        Service::IdentityFeatures,
        Service::IdentityName,
        Service::Assign,
        Service::Configure,
        Service::ConfigStatus,
        Service::UpdateTransfer,
        Service::UpdateStatus,
    ];

    /// The service with this code. A match, not a search of [`Service::ALL`]: the codes are two
    /// runs (0x00..=0x0B, 0x10..=0x2C), which the compiler turns into two range checks, and a
    /// node parses the service of every frame of ours it reads.
    pub const fn from_code(code: u8) -> Option<Service> {
        Some(match code {
            0x00 => Service::EmergencyStop,
            0x01 => Service::Fault,
            0x02 => Service::Heartbeat,
            0x03 => Service::TableStatus,
            0x04 => Service::Traffic,
            0x05 => Service::Errors,
            0x06 => Service::Diagnostic,
            0x07 => Service::Gates,
            0x08 => Service::Desire,
            0x09 => Service::Intention,
            0x0A => Service::FilterStatus,
            0x0B => Service::Exploitation,
            0x10 => Service::DiagnosticControl,
            0x11 => Service::TableTransfer,
            0x12 => Service::TransferStatus,
            0x13 => Service::ChallengeRequest,
            0x14 => Service::Challenge,
            0x15 => Service::TransferOpen,
            0x16 => Service::Receipt,
            0x17 => Service::FilterProfile,
            0x18 => Service::FilterSet,
            0x19 => Service::SchemaAbort,
            0x1A => Service::SchemaTransfer,
            0x1B => Service::SchemaAck,
            0x1C => Service::SchemaTransition,
            0x1D => Service::SchemaState,
            0x1E => Service::Seal,
            0x1F => Service::FreshnessRequest,
            0x20 => Service::Freshness,
            0x21 => Service::IdentityRequest,
            0x22 => Service::Identity,
            0x23 => Service::IdentityVersion,
            0x24 => Service::IdentityBuild,
            0x25 => Service::IdentityCapacity,
            0x26 => Service::IdentityFeatures,
            0x27 => Service::IdentityName,
            0x28 => Service::Assign,
            0x29 => Service::Configure,
            0x2A => Service::ConfigStatus,
            0x2B => Service::UpdateTransfer,
            0x2C => Service::UpdateStatus,
            _ => return None,
        })
    }

    /// The 8-bit code.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The priority frames of this service are sent with.
    pub const fn priority(self) -> Priority {
        match self {
            // The emergency stop beats everything of ours, faults included (service 0 < 1).
            Service::EmergencyStop | Service::Fault => Priority::EXCEPTIONAL,
            Service::SchemaAbort => Priority::URGENT,
            // A schema, its answer and the schema changes a client follows its program with never
            // wait behind commands, a table image or reports.
            Service::TransferStatus
            | Service::Challenge
            | Service::Receipt
            | Service::SchemaTransfer
            | Service::SchemaAck
            | Service::SchemaTransition
            | Service::ConfigStatus
            | Service::UpdateStatus => Priority::HIGH,
            // Gates are decisions other nodes' rules read: they wait for faults and the tool's
            // answers only, never behind heartbeats, claims or counters.
            // Filter commands likewise: a disable must not queue behind a board's counters.
            Service::Gates
            | Service::DiagnosticControl
            | Service::ChallengeRequest
            | Service::TransferOpen
            | Service::FilterProfile
            | Service::FilterSet
            | Service::IdentityRequest
            | Service::Assign
            | Service::Configure => Priority::COMMAND,
            Service::Heartbeat
            | Service::TableStatus
            | Service::Desire
            | Service::Intention
            | Service::FilterStatus
            | Service::FreshnessRequest
            | Service::Freshness
            | Service::Identity
            | Service::IdentityVersion
            | Service::IdentityBuild
            | Service::IdentityCapacity
            | Service::IdentityFeatures
            | Service::IdentityName => Priority::NOMINAL,
            Service::Traffic
            | Service::Errors
            | Service::Exploitation
            | Service::SchemaState
            | Service::Seal => Priority::LOW,
            Service::TableTransfer | Service::UpdateTransfer => Priority::BULK,
            Service::Diagnostic => Priority::OPTIONAL,
        }
    }

    /// The payload length of this service's frames (ISO-TP frames are always padded to 8). A
    /// command's authenticated form is longer by its tag ([`crate::auth::COMMAND_TAG_LEN`]).
    // Out of line: the framing's length check and the node's message decoder (both in the
    // node's protocol-frame handler) each inlined it (56 bytes of the NUCLEO-G474RE's flash, 52
    // of the emulated board's).
    #[inline(never)]
    pub const fn payload_len(self) -> usize {
        match self {
            Service::DiagnosticControl
            | Service::Exploitation
            | Service::FilterProfile
            | Service::Assign
            | Service::Configure => 4,
            Service::FilterSet => 6,
            Service::EmergencyStop | Service::SchemaAbort | Service::IdentityRequest => 0,
            _ => 8,
        }
    }
}

/// A decoded identifier of ours.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameId {
    /// Bus priority.
    pub priority: Priority,
    /// What the frame carries.
    pub service: Service,
    /// The addressed node, [`TOOL`] or [`BROADCAST`].
    pub destination: u8,
    /// The sender: a node or [`TOOL`].
    pub source: u8,
}

impl FrameId {
    /// The identifier of a `service` frame from `source` to `destination`, at the service's
    /// priority.
    pub const fn new(service: Service, source: u8, destination: u8) -> FrameId {
        FrameId {
            priority: service.priority(),
            service,
            destination,
            source,
        }
    }

    /// The 29-bit number.
    pub const fn raw(self) -> u32 {
        (self.priority.0 as u32) << 26
            | MARKER << 24
            | (self.service as u32) << 16
            | (self.destination as u32) << 8
            | self.source as u32
    }

    /// As an `embedded_can` identifier.
    pub fn id(self) -> Id {
        // Cannot fail: the priority has 3 bits, so `raw` fits 29 bits.
        ExtendedId::new(self.raw()).map_or(Id::Extended(ExtendedId::ZERO), Id::Extended)
    }

    /// Decodes an identifier: `None` when it is a standard identifier, does not carry our marker,
    /// or names an unknown service (a frame of a newer protocol version, say).
    pub fn decode(id: &Id) -> Option<FrameId> {
        let Id::Extended(id) = id else {
            return None;
        };
        FrameId::from_raw(id.as_raw())
    }

    /// Decodes a raw 29-bit identifier, as [`FrameId::decode`].
    // Out of line: inlined into the node's frame path (through `classify`) and its protocol
    // frames' decoder, it took 246 bytes more of the emulated board's flash than one copy.
    #[inline(never)]
    pub fn from_raw(raw: u32) -> Option<FrameId> {
        if raw >> 29 != 0 || (raw >> 24) & 0b11 != MARKER {
            return None;
        }
        let [_, service, destination, source] = raw.to_be_bytes();
        Some(FrameId {
            priority: Priority(u8::try_from(raw >> 26).ok()? & 0b111),
            service: Service::from_code(service)?,
            destination,
            source,
        })
    }

    /// Whether the frame carries its service's priority ([`Service::priority`]): every service
    /// has one, and a frame with another is malformed (nodes refuse it, as they refuse a wrong
    /// length).
    pub const fn has_service_priority(&self) -> bool {
        self.priority.0 == self.service.priority().0
    }

    /// Whether a node with id `node` should read this frame.
    pub fn is_for(&self, node: u8) -> bool {
        self.destination == node || self.destination == BROADCAST
    }
}

/// Whether `id` lies in our part of the identifier space (extended, marker `0b10`), whatever the
/// service: [`classify_id`] says anything but [`FrameKind::Topic`]. Nodes never arbitrate such
/// frames.
#[inline]
pub fn is_ours(id: &Id) -> bool {
    classify_id(id).is_ours()
}

/// The mask and value that select all our frames, for a CAN controller's acceptance filter or a
/// DBC comment: `raw & PROTOCOL_MASK == PROTOCOL_VALUE`.
pub const PROTOCOL_MASK: u32 = 0b11 << 24;
/// See [`PROTOCOL_MASK`].
pub const PROTOCOL_VALUE: u32 = MARKER << 24;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_round_trip_for_every_service_and_address() {
        for service in Service::ALL {
            for source in [0u8, 1, 3, 127] {
                for destination in [0u8, 1, 127, BROADCAST] {
                    let id = FrameId::new(service, source, destination);
                    assert_eq!(FrameId::from_raw(id.raw()), Some(id));
                    assert_eq!(FrameId::decode(&id.id()), Some(id));
                    assert!(id.raw() <= 0x1FFF_FFFF);
                    assert!(is_ours(&id.id()));
                }
            }
        }
    }

    #[test]
    fn the_layout_is_as_documented() {
        // Heartbeat (priority 4, service 0x02) from node 3 to everyone.
        let id = FrameId::new(Service::Heartbeat, 3, BROADCAST);
        assert_eq!(id.raw(), 4 << 26 | 0b10 << 24 | 0x02 << 16 | 0xFF << 8 | 3);
        assert_eq!(id.raw(), 0x1202_FF03);
        // A fault outranks everything we send but the emergency stop, which outranks it too.
        let fault = FrameId::new(Service::Fault, 127, BROADCAST).raw();
        let stop = FrameId::new(Service::EmergencyStop, 127, BROADCAST).raw();
        assert_eq!(
            FrameId::new(Service::EmergencyStop, TOOL, BROADCAST).raw(),
            0x0200_FF00
        );
        assert!(stop < FrameId::new(Service::Fault, 1, 0).raw());
        for service in Service::ALL {
            if !matches!(service, Service::Fault | Service::EmergencyStop) {
                assert!(fault < FrameId::new(service, 1, 0).raw());
                assert!(stop < FrameId::new(service, 1, 0).raw());
            }
        }
        // Service 0 is a service: its frames are ours, not an unknown code.
        assert_eq!(
            FrameId::from_raw(0x0200_0300).map(|id| id.service),
            Some(Service::EmergencyStop)
        );
    }

    #[test]
    fn every_code_names_the_service_of_that_code() {
        for code in 0..=u8::MAX {
            assert_eq!(
                Service::from_code(code),
                Service::ALL.into_iter().find(|s| s.code() == code),
                "{code:#04x}"
            );
        }
    }

    #[test]
    fn foreign_identifiers_are_not_ours() {
        let standard = Id::Standard(embedded_can::StandardId::new(0x123).unwrap());
        assert_eq!(FrameId::decode(&standard), None);
        assert!(!is_ours(&standard));
        // Wrong marker.
        assert_eq!(FrameId::from_raw(0x1102_FF03), None);
        assert_eq!(FrameId::from_raw(0x1302_FF03), None);
        // Unknown service.
        assert_eq!(FrameId::from_raw(0x1277_FF03), None);
        // Wider than 29 bits.
        assert_eq!(FrameId::from_raw(0x2000_0000 | 0x1202_FF03), None);
    }
}
