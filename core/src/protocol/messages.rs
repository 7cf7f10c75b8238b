//! Payload codecs, one type per service. Every decoder checks the exact length and every enumerated
//! or reserved field; a frame that fails is refused with a [`DecodeError`], never half-read.

use super::{
    FaultCode, FrameId, NodeState, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety,
    SchemaTrigger, Service, TransferStatusCode,
};
use crate::frame::Frame;

/// A node's heartbeat (service 0x02), sent every heartbeat period (1 s by default) to
/// [`super::BROADCAST`], followed by [`TableStatus`], [`Traffic`] and [`Errors`].
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

/// The gates of a competitive-dynamics group (service 0x07), sent by the node that runs the group
/// to [`super::BROADCAST`] whenever a gate changes and every [`Gates::PERIOD_US`] otherwise
/// ([`crate::dynamics`]).
///
/// ```text
/// byte 0     group: its number in the network (the file's order of [dynamics.*], from 0)
/// byte 1     behaviours in the group, 1..=32
/// bytes 2-5  gates, u32 LE: bit i set while behaviour i's gate is open; bits at and above the
///            count are 0
/// byte 6     changes: how many times the mask changed since the group started, mod 256
/// byte 7     reserved, 0
/// ```
///
/// The count travels so that a node whose table imports the group refuses the gates of a group
/// of another size (two networks on one bus, or a table not pushed yet) instead of reading the
/// wrong bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Gates {
    /// The group's number in the network.
    pub group: u8,
    /// How many behaviours the group has, 1..=32.
    pub behaviours: u8,
    /// Bit i: behaviour i's gate is open.
    pub mask: u32,
    /// Changes of the mask since the group started, mod 256.
    pub changes: u8,
}

impl Gates {
    /// The longest a group's owner stays silent: it repeats its gates at this period, 100 ms.
    pub const PERIOD_US: u64 = 100_000;
    /// A group not heard for this long (three periods) reads as all gates closed, with a fault.
    pub const SILENCE_US: u64 = 3 * Gates::PERIOD_US;

    /// Whether the fields are in range: 1..=32 behaviours, no gate at or above the count.
    pub const fn is_valid(&self) -> bool {
        self.behaviours >= 1
            && self.behaviours <= 32
            && (self.behaviours == 32 || self.mask >> self.behaviours == 0)
    }
}

/// A desire (service 0x08), sent by a motivation (any node, or the tool) to
/// [`super::BROADCAST`]; the intention node keeps it for its lease ([`crate::hbba::Desires`]).
///
/// ```text
/// byte 0     class: its number in the network (first appearance among [hbba.strategies.*])
/// byte 1     reserved, 0
/// bytes 2-3  intensity, u16 LE: 0 withdraws the desire, else 1..65535
/// bytes 4-5  lease in ms, u16 LE: the desire lapses unless refreshed within it (1..65535)
/// bytes 6-7  the sender's number for this desire, u16 LE: (source, id) names it
/// ```
///
/// A sender refreshes a desire by sending it again before its lease runs out (at half the lease,
/// say, so that one lost frame costs nothing).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DesireFrame {
    /// The class desired.
    pub class: u8,
    /// How much; 0 withdraws.
    pub intensity: u16,
    /// Lease, milliseconds.
    pub lease_ms: u16,
    /// The sender's number for the desire.
    pub id: u16,
}

/// The intention (service 0x09): the strategies the intention node selected, sent to
/// [`super::BROADCAST`] after every solve that changed them and once a second.
///
/// ```text
/// bytes 0-7  u64 LE: bit s set when strategy s (the file's order of [hbba.strategies.*]) runs
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Intention {
    /// Bit s: strategy s is selected.
    pub strategies: u64,
}

/// A node's message filters (service 0x0A), sent to [`super::BROADCAST`] after every filter
/// command it applied and after every heartbeat group, by nodes whose table has filters.
///
/// ```text
/// byte 0     the profile last switched to (0..=15), or 0xFF once a FilterSet changed one since
/// byte 1     reserved, 0
/// bytes 2-3  the sequence number of the last filter command applied, u16 LE (0 since boot)
/// byte 4     filtered connections: how many the table names
/// byte 5     of them closed (φ = 0)
/// byte 6     of them throttled (φ ≥ 2)
/// byte 7     reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterStatus {
    /// The profile in force, or [`FilterStatus::SET_ONE_BY_ONE`].
    pub profile: u8,
    /// The last applied command's sequence number.
    pub sequence: u16,
    /// Connections with a filter.
    pub filtered: u8,
    /// Of them, closed.
    pub closed: u8,
    /// Of them, passing one frame in φ ≥ 2.
    pub throttled: u8,
}

impl FilterStatus {
    /// [`FilterStatus::profile`] once a single filter was set after the last profile switch.
    pub const SET_ONE_BY_ONE: u8 = 0xFF;
}

/// Behaviour exploitation (service 0x0B), sent by a node to [`super::BROADCAST`] when a
/// connection of one of its ports starts or stops delivering: edges only, so that motivations
/// can watch what is used without a stream.
///
/// ```text
/// byte 0     port (the node's order)
/// byte 1     connection (the port's order)
/// byte 2     1: started delivering, 0: stopped
/// byte 3     reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Exploitation {
    /// The port.
    pub port: u8,
    /// The connection.
    pub connection: u8,
    /// Started (true) or stopped (false) delivering.
    pub delivering: bool,
}

/// Switches all of a node's message filters to one of its table's profiles (service 0x17), from
/// the intention node; the node answers with [`FilterStatus`], or a `FilterRefused` fault.
///
/// ```text
/// byte 0     profile, 0..=15 (profile 0: every filtered connection closed, as at boot)
/// byte 1     reserved, 0
/// bytes 2-3  sequence number, u16 LE, echoed in FilterStatus
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterProfile {
    /// The profile.
    pub profile: u8,
    /// Echoed in [`FilterStatus::sequence`].
    pub sequence: u16,
}

/// Sets one message filter of a node (service 0x18), from the intention node; the node answers
/// with [`FilterStatus`], or a `FilterRefused` fault.
///
/// ```text
/// byte 0     port (the node's order)
/// byte 1     connection (the port's order): one the table gives a filter
/// byte 2     φ: 0 closes, 1 passes every frame, N passes one in N
/// byte 3     reserved, 0
/// bytes 4-5  sequence number, u16 LE, echoed in FilterStatus
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterSet {
    /// The port.
    pub port: u8,
    /// The connection.
    pub connection: u8,
    /// The filter's φ.
    pub phi: u8,
    /// Echoed in [`FilterStatus::sequence`].
    pub sequence: u16,
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

/// A fault (service 0x01), to [`super::BROADCAST`] at the highest priority, at most once per code
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

/// Flags of a [`DiagnosticSample`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DiagnosticFlags {
    /// The connection is active (its stimulation crossed the threshold and has not decayed).
    pub active: bool,
    /// The connection is resting (ignoring frames during its rest time).
    pub resting: bool,
    /// The port's decision selects this connection: it is the current deliverer.
    pub delivering: bool,
    /// This is the last sample of the round (the round's samples share a sequence number).
    pub end_of_round: bool,
}

impl DiagnosticFlags {
    const fn bits(self) -> u8 {
        (self.active as u8)
            | (self.resting as u8) << 1
            | (self.delivering as u8) << 2
            | (self.end_of_round as u8) << 3
    }

    const fn from_bits(bits: u8) -> Option<DiagnosticFlags> {
        if bits & !0b1111 != 0 {
            return None;
        }
        Some(DiagnosticFlags {
            active: bits & 1 != 0,
            resting: bits & 2 != 0,
            delivering: bits & 4 != 0,
            end_of_round: bits & 8 != 0,
        })
    }
}

/// One connection's state (service 0x06), when the diagnostic stream is on. A round covers every
/// connection of the selected ports, in port then connection order, at the requested rate.
///
/// ```text
/// byte 0     port index
/// byte 1     connection index within the port
/// byte 2     flags: bit 0 active, bit 1 resting, bit 2 delivering, bit 3 end of round
/// byte 3     round sequence number, wrapping
/// bytes 4-7  stimulation S in Q1.31 (2^31 = 1.0), u32 LE
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DiagnosticSample {
    /// The port.
    pub port: u8,
    /// The connection within the port.
    pub connection: u8,
    /// Activity and selection.
    pub flags: DiagnosticFlags,
    /// The round this sample belongs to.
    pub sequence: u8,
    /// S in Q1.31.
    pub level: u32,
}

impl DiagnosticSample {
    /// S as a number in [0, 1].
    pub fn level_f32(&self) -> f32 {
        self.level as f32 / (1u64 << 31) as f32
    }
}

/// Switches a node's diagnostic stream (service 0x10), tool → node or broadcast.
///
/// ```text
/// bytes 0-1  rounds per second, u16 LE; 0 switches the stream off; at most MAX_RATE_HZ
/// bytes 2-3  ports to sample, bit i = port i, u16 LE
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DiagnosticControl {
    /// Rounds per second, 0 = off.
    pub rate_hz: u16,
    /// Ports to sample.
    pub ports: u16,
}

impl DiagnosticControl {
    /// The highest rate a node accepts (a higher request is refused as malformed).
    pub const MAX_RATE_HZ: u16 = 200;
}

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

/// The answer to a schema message (service 0x1B), node → the schema's sender, once per
/// SchemaTransfer message, when it is complete (or refused at its first frame).
///
/// ```text
/// byte 0     outcome (SchemaOutcome): 0 accepted, else why the schema (or limits) was refused
/// byte 1     channel of the message (0 queue, 1 high-priority, 2 limits; 0xFF when unreadable)
/// bytes 2-3  the schema's id, u16 LE (0xFFFF when it could not be decoded, and for limits)
/// byte 4     schemas in the queue after it
/// byte 5     the server's stop number (0..63, SchemaState byte 5 bits 2-7): what a refusal
///            StopNotAcknowledged wanted
/// bytes 6-7  reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SchemaAck {
    /// Accepted, or why not.
    pub outcome: SchemaOutcome,
    /// The message's channel; `None` (0xFF on the wire) when its channel byte could not be read
    /// (a message refused at its first frame, or a channel byte neither 0, 1 nor 2).
    pub channel: Option<SchemaChannel>,
    /// The schema's id, or [`SchemaAck::NO_ID`] when it could not be decoded.
    pub id: u16,
    /// Schemas in the queue after this one (0..=8 on the boards).
    pub queued: u8,
    /// The server's stop number when it answered (`pab_core::schema::Server::stop_number`,
    /// below 64).
    pub stop: u8,
}

impl SchemaAck {
    /// [`SchemaAck::id`] of a message whose schema could not be decoded (never a client's id:
    /// those are below 0xFF00).
    pub const NO_ID: u16 = 0xFFFF;
    /// Byte 1 of a message whose channel could not be read.
    pub const NO_CHANNEL: u8 = 0xFF;
}

/// A schema change of the server (service 0x1C), node → all, on every change (several in one
/// tick: in order). A client follows its program with these.
///
/// ```text
/// bytes 0-1  the schema that ended, u16 LE
/// bytes 2-3  the schema installed, u16 LE (0xFF00 the wait for the queue, 0xFF01 the wait for the
///            high-priority channel, 0xFF10 + cause the recovery after a safety event)
/// byte 4     trigger (SchemaTrigger): 0 high-priority channel, 1 abort, 2 safety, 3 reaction
/// byte 5     detail: the safety cause (SchemaSafety) or the reaction's index in the ended
///            schema's table; 0 otherwise
/// byte 6     source of the installed schema (SchemaOrigin): 0 innate, 1 queue, 2 high-priority
/// byte 7     schemas in the queue after it
/// ```
///
/// A transition whose detail contradicts its trigger (an unknown safety cause, a detail after
/// the high-priority channel or an abort) is refused ([`SchemaTransition::is_valid`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SchemaTransition {
    /// The schema that ended.
    pub ended: u16,
    /// The schema installed.
    pub installed: u16,
    /// What ended it.
    pub trigger: SchemaTrigger,
    /// For [`SchemaTrigger::Safety`] the [`SchemaSafety`] code, for [`SchemaTrigger::Reaction`]
    /// the reaction's index in the ended schema's table; 0 otherwise.
    pub detail: u8,
    /// Where the installed schema came from.
    pub source: SchemaOrigin,
    /// Schemas in the queue after the change.
    pub queued: u8,
}

impl SchemaTransition {
    /// Whether the detail fits the trigger: a known cause after a safety event, 0 after the
    /// high-priority channel or an abort, any index after a reaction.
    pub fn is_valid(&self) -> bool {
        match self.trigger {
            SchemaTrigger::HighPriority | SchemaTrigger::Abort => self.detail == 0,
            SchemaTrigger::Safety => SchemaSafety::from_code(self.detail).is_some(),
            SchemaTrigger::Reaction => true,
        }
    }

    /// The safety event that ended the schema, for a [`SchemaTrigger::Safety`] trigger.
    pub fn safety(&self) -> Option<SchemaSafety> {
        match self.trigger {
            SchemaTrigger::Safety => SchemaSafety::from_code(self.detail),
            _ => None,
        }
    }
}

/// The schema server's state (service 0x1D), node → all, every 100 ms.
///
/// ```text
/// bytes 0-1  the installed schema, u16 LE
/// byte 2     its source (SchemaOrigin, as SchemaTransition byte 6)
/// byte 3     the safety event the server is stopped on (SchemaSafety), 0xFF when none
/// byte 4     schemas in the queue
/// byte 5     bit 0 armed (a pose has been received), bit 1 gripper closed, bits 2-7 the stop
///            number: the server's stops (emergency stops, aborts, safety events) modulo 64,
///            which a high-priority schema names to leave the latest one
/// bytes 6-7  ms since it was installed, u16 LE, saturating
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SchemaState {
    /// The installed schema's id.
    pub current: u16,
    /// Where it came from.
    pub source: SchemaOrigin,
    /// The safety event the server is stopped on (until the high-priority channel installs a
    /// schema); `None` (0xFF on the wire) when running.
    pub fault: Option<SchemaSafety>,
    /// Schemas in the queue.
    pub queued: u8,
    /// A pose has been received: the attractor means something.
    pub armed: bool,
    /// The gripper is commanded closed.
    pub gripper_closed: bool,
    /// The stop number (`pab_core::schema::Server::stop_number`, below 64).
    pub stop: u8,
    /// Milliseconds since the schema was installed, saturating at 65 535
    /// ([`SchemaState::saturate_ms`]).
    pub elapsed_ms: u16,
}

impl SchemaState {
    /// Byte 3 when the server is not stopped on a safety event.
    pub const NO_FAULT: u8 = 0xFF;

    /// A duration in ms as [`SchemaState::elapsed_ms`] carries it: saturating at 65 535.
    pub fn saturate_ms(ms: u64) -> u16 {
        u16::try_from(ms).unwrap_or(u16::MAX)
    }
}

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
        /// CMAC (domain 1, node, service, nonce, the 4 bytes of `control`), first 4 bytes.
        tag: [u8; crate::auth::COMMAND_TAG_LEN],
    },
    /// Asks a node for a challenge (service 0x13, no payload).
    ChallengeRequest,
    /// A node's challenge (service 0x14): the nonce, u64 LE (boot salt in the high 32 bits).
    Challenge {
        /// The nonce.
        nonce: u64,
    },
    /// See [`TransferOpen`].
    TransferOpen(TransferOpen),
    /// Authenticates the TransferStatus that ended an opened transfer (service 0x16): CMAC
    /// (domain 4, node, nonce, that TransferStatus's 8 bytes, the running image's CRC, its stored
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
    /// the message is a channel byte ([`SchemaChannel`]) and the schema's postcard bytes, or on
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
}

/// Why a frame in our identifier space was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Not one of our identifiers (standard, other marker or unknown service).
    NotOurs,
    /// A remote frame: our protocol uses none.
    Remote,
    /// The payload length is not the service's.
    Length {
        /// The service.
        service: Service,
        /// The length received.
        len: u8,
    },
    /// An enumerated field holds an unknown code or a reserved bit or byte is set.
    Value {
        /// The service.
        service: Service,
    },
    /// The identifier's priority bits are not the service's ([`Service::priority`]).
    Priority {
        /// The service.
        service: Service,
        /// The priority received.
        priority: u8,
    },
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecodeError::NotOurs => f.write_str("not a frame of the pab protocol"),
            DecodeError::Remote => f.write_str("remote frame"),
            DecodeError::Length { service, len } => write!(
                f,
                "{service:?} frame with {len} bytes, expected {}",
                service.payload_len()
            ),
            DecodeError::Value { service } => {
                write!(
                    f,
                    "{service:?} frame with an unknown code or reserved bits set"
                )
            }
            DecodeError::Priority { service, priority } => write!(
                f,
                "{service:?} frame with priority {priority}, expected {}",
                service.priority().value()
            ),
        }
    }
}

/// The little-endian `u32` at `at` of a padded payload (`at` + 4 <= 8 at every call).
fn u32_at(data: &[u8; 8], at: usize) -> u32 {
    u32::from_le_bytes([
        byte(data, at),
        byte(data, at + 1),
        byte(data, at + 2),
        byte(data, at + 3),
    ])
}

/// The little-endian `u16` at `at` of a padded payload.
fn u16_at(data: &[u8; 8], at: usize) -> u16 {
    u16::from_le_bytes([byte(data, at), byte(data, at + 1)])
}

/// Byte `at` of a padded payload (0 past its end, which no call reaches).
fn byte(data: &[u8; 8], at: usize) -> u8 {
    data.get(at).copied().unwrap_or(0)
}

/// `N` bytes from `at` of a padded payload.
fn bytes_at<const N: usize>(data: &[u8; 8], at: usize) -> [u8; N] {
    core::array::from_fn(|i| byte(data, at + i))
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
            Message::ChallengeRequest => Service::ChallengeRequest,
            Message::Challenge { .. } => Service::Challenge,
            Message::TransferOpen(_) => Service::TransferOpen,
            Message::Receipt { .. } => Service::Receipt,
            Message::EmergencyStop => Service::EmergencyStop,
            Message::SchemaAbort => Service::SchemaAbort,
            Message::SchemaTransfer { .. } => Service::SchemaTransfer,
            Message::SchemaAck(_) => Service::SchemaAck,
            Message::SchemaTransition(_) => Service::SchemaTransition,
            Message::SchemaState(_) => Service::SchemaState,
        }
    }

    /// The frame carrying this message from `source` to `destination`.
    ///
    /// Each payload is built as one 8-byte array at fixed offsets (the bytes past its length
    /// zero): no writer, no copy loop, no bounds check. Each arm hands it over as one
    /// little-endian `u64`: as arrays, the arms' results were merged byte by byte, eight
    /// registers taken apart and put back together into words after the match (488 bytes of
    /// the boards' flash, and 142 instructions of the heartbeat group).
    pub fn to_frame(&self, source: u8, destination: u8) -> Frame {
        let (data, len) = match self.report_payload() {
            Some(payload) => payload,
            None => self.command_payload(),
        };
        frame(self.service(), source, destination, data, len)
    }

    /// [`Message::to_frame`] for what a node sends: its reports, answers and gates; `None` for
    /// a command (the tool's, the intention node's, a stop), which no node sends. A node links
    /// only this encoder: the commands' took about 100 bytes of the boards' flash.
    pub fn report_frame(&self, source: u8, destination: u8) -> Option<Frame> {
        let (data, len) = self.report_payload()?;
        Some(frame(self.service(), source, destination, data, len))
    }

    /// The 8 bytes of a report's payload as it goes on the wire (zeros past its length); `None`
    /// for a command. What a Receipt's tag covers, without building the frame.
    pub fn report_bytes(&self) -> Option<[u8; 8]> {
        self.report_payload().map(|(word, _)| word.to_le_bytes())
    }

    /// The payload of a message a node sends, and its length; `None` for a command.
    fn report_payload(&self) -> Option<(u64, u8)> {
        Some(match self {
            Message::Fault(fault) => {
                let [c0, c1] = fault.code.code().to_le_bytes();
                let [d0, d1, d2, d3, d4] = fault.detail;
                (le_word([c0, c1, fault.count, d0, d1, d2, d3, d4]), 8)
            }
            Message::Heartbeat(heartbeat) => {
                let [u0, u1, u2, _] = heartbeat.uptime_s.min(0x00FF_FFFF).to_le_bytes();
                let [v0, v1, v2, v3] = heartbeat.table_version.to_le_bytes();
                (
                    le_word([heartbeat.state.code(), u0, u1, u2, v0, v1, v2, v3]),
                    8,
                )
            }
            Message::TableStatus(status) => {
                let [c0, c1, c2, c3] = status.crc.to_le_bytes();
                let [l0, l1] = status.image_len.to_le_bytes();
                let flags = status.stored as u8
                    | (status.diagnostic as u8) << 1
                    | (status.keyed as u8) << 2;
                (le_word([c0, c1, c2, c3, l0, l1, status.ports, flags]), 8)
            }
            Message::Traffic(traffic) => (words(traffic.received, traffic.delivered), 8),
            Message::Errors(errors) => (words(errors.discarded, errors.errors), 8),
            Message::Diagnostic(sample) => {
                let [l0, l1, l2, l3] = sample.level.to_le_bytes();
                let flags = sample.flags.bits();
                let (port, connection) = (sample.port, sample.connection);
                (
                    le_word([port, connection, flags, sample.sequence, l0, l1, l2, l3]),
                    8,
                )
            }
            Message::TableTransfer { data, len } | Message::SchemaTransfer { data, len } => {
                // The bytes the frame carries; a length beyond 8 carries all 8.
                let len = (*len).min(8);
                let mut bytes = *data;
                for (at, byte) in bytes.iter_mut().enumerate() {
                    if at >= usize::from(len) {
                        *byte = 0;
                    }
                }
                (le_word(bytes), len)
            }
            Message::TransferStatus(status) => {
                let [v0, v1, v2, v3] = status.running_version.to_le_bytes();
                (
                    le_word([status.status.code(), status.detail, v0, v1, v2, v3, 0, 0]),
                    8,
                )
            }
            // The schema server's reports as two words each: fewer instructions than eight byte
            // stores on the boards (their encoders took 200 bytes of flash as byte arrays).
            Message::SchemaAck(ack) => {
                let channel = ack
                    .channel
                    .map_or(SchemaAck::NO_CHANNEL, SchemaChannel::code);
                let low = u32::from(ack.outcome.code())
                    | u32::from(channel) << 8
                    | u32::from(ack.id) << 16;
                // The stop number is below 64 (the server's own): not masked here.
                let high = u32::from(ack.queued) | u32::from(ack.stop) << 8;
                (words(low, high), 8)
            }
            Message::SchemaTransition(change) => {
                let low = u32::from(change.ended) | u32::from(change.installed) << 16;
                let high = u32::from_le_bytes([
                    change.trigger.code(),
                    change.detail,
                    change.source.code(),
                    change.queued,
                ]);
                (words(low, high), 8)
            }
            Message::SchemaState(state) => {
                let fault = state
                    .fault
                    .map_or(SchemaState::NO_FAULT, SchemaSafety::code);
                let flags = state.armed as u8 | (state.gripper_closed as u8) << 1 | state.stop << 2;
                let low = u32::from(state.current)
                    | u32::from(state.source.code()) << 16
                    | u32::from(fault) << 24;
                let high = u32::from(state.queued)
                    | u32::from(flags) << 8
                    | u32::from(state.elapsed_ms) << 16;
                (words(low, high), 8)
            }
            Message::Challenge { nonce } => (*nonce, 8),
            Message::Receipt { tag } => (le_word(*tag), 8),
            Message::Gates(gates) => {
                let [m0, m1, m2, m3] = gates.mask.to_le_bytes();
                (
                    le_word([
                        gates.group,
                        gates.behaviours,
                        m0,
                        m1,
                        m2,
                        m3,
                        gates.changes,
                        0,
                    ]),
                    8,
                )
            }
            Message::FilterStatus(status) => {
                let [s0, s1] = status.sequence.to_le_bytes();
                (
                    le_word([
                        status.profile,
                        0,
                        s0,
                        s1,
                        status.filtered,
                        status.closed,
                        status.throttled,
                        0,
                    ]),
                    8,
                )
            }
            Message::Exploitation(edge) => (
                le_word([
                    edge.port,
                    edge.connection,
                    edge.delivering as u8,
                    0,
                    0,
                    0,
                    0,
                    0,
                ]),
                4,
            ),
            // Named one by one, so that a new message is put on one side or the other.
            Message::DiagnosticControl(_)
            | Message::AuthenticatedDiagnosticControl { .. }
            | Message::ChallengeRequest
            | Message::TransferOpen(_)
            | Message::Desire(_)
            | Message::Intention(_)
            | Message::FilterProfile(_)
            | Message::FilterSet(_)
            | Message::EmergencyStop
            | Message::SchemaAbort => return None,
        })
    }

    /// The payload of a command, and its length (a message a node sends has none here: see
    /// [`Message::report_payload`]).
    fn command_payload(&self) -> (u64, u8) {
        match self {
            Message::DiagnosticControl(control) => (le_word(control_bytes(control, [0; 4])), 4),
            Message::AuthenticatedDiagnosticControl { control, tag } => {
                (le_word(control_bytes(control, *tag)), 8)
            }
            Message::ChallengeRequest | Message::EmergencyStop | Message::SchemaAbort => (0, 0),
            Message::TransferOpen(open) => {
                let [l0, l1] = open.length.to_le_bytes();
                let [t0, t1, t2, t3, t4] = open.tag;
                (le_word([l0, l1, open.flags, t0, t1, t2, t3, t4]), 8)
            }
            Message::Desire(desire) => {
                let [i0, i1] = desire.intensity.to_le_bytes();
                let [l0, l1] = desire.lease_ms.to_le_bytes();
                let [d0, d1] = desire.id.to_le_bytes();
                (le_word([desire.class, 0, i0, i1, l0, l1, d0, d1]), 8)
            }
            Message::Intention(intention) => (intention.strategies, 8),
            Message::FilterProfile(switch) => {
                let [s0, s1] = switch.sequence.to_le_bytes();
                (le_word([switch.profile, 0, s0, s1, 0, 0, 0, 0]), 4)
            }
            Message::FilterSet(set) => {
                let [s0, s1] = set.sequence.to_le_bytes();
                (
                    le_word([set.port, set.connection, set.phi, 0, s0, s1, 0, 0]),
                    6,
                )
            }
            _ => (0, 0),
        }
    }

    /// Decodes a frame of our protocol: its addresses and its message.
    pub fn decode(frame: &Frame) -> Result<(FrameId, Message), DecodeError> {
        let (id, padded, len) = Self::framing(frame)?;
        let message = match Self::node_message(id.service, padded, len)? {
            Some(message) => message,
            None => Self::report(id.service, padded)?,
        };
        Ok((id, message))
    }

    /// [`Message::decode`] for a node: the same checks of every frame's identifier, priority
    /// and length, but the payload decoded (and its values checked) only for the services a node
    /// acts on (Gates, DiagnosticControl, TableTransfer, ChallengeRequest, TransferOpen,
    /// FilterProfile, FilterSet, EmergencyStop, SchemaAbort, SchemaTransfer); `Ok(None)` for a
    /// well-framed frame of another service (a report, a desire, another node's status or schema
    /// answers), which a node does not read. The boards link
    /// only this: the other services' decoders took 596 bytes of the NUCLEO-G474RE's flash.
    pub fn decode_for_node(frame: &Frame) -> Result<Option<(FrameId, Message)>, DecodeError> {
        let (id, padded, len) = Self::framing(frame)?;
        Ok(Self::node_message(id.service, padded, len)?.map(|message| (id, message)))
    }

    /// The checks every frame gets (ours, not remote, its service's priority and length), and
    /// its payload zero-padded to 8 bytes with its length.
    fn framing(frame: &Frame) -> Result<(FrameId, [u8; 8], u8), DecodeError> {
        let id = FrameId::decode(&frame.id()).ok_or(DecodeError::NotOurs)?;
        if frame.is_remote() {
            return Err(DecodeError::Remote);
        }
        let service = id.service;
        // Every service has one priority: a frame with another is malformed, whatever it holds.
        if !id.has_service_priority() {
            return Err(DecodeError::Priority {
                service,
                priority: id.priority.value(),
            });
        }
        let data = frame.payload();
        let len = u8::try_from(data.len()).unwrap_or(u8::MAX);
        let expected = service.payload_len();
        let length_ok = match service {
            // ISO-TP frames may be unpadded: the transport checks their length.
            Service::TableTransfer | Service::SchemaTransfer => !data.is_empty(),
            // The plain form, or the plain form and its tag.
            Service::DiagnosticControl => {
                data.len() == expected || data.len() == expected + crate::auth::COMMAND_TAG_LEN
            }
            _ => data.len() == expected,
        };
        if !length_ok {
            return Err(DecodeError::Length { service, len });
        }
        // The payload zero-padded to 8 bytes: every read is at a constant offset within the
        // length checked above, so none needs a bounds check (less flash than reads from the
        // slice, each with its own).
        let mut padded = [0u8; 8];
        for (slot, byte) in padded.iter_mut().zip(data) {
            *slot = *byte;
        }
        Ok((id, padded, len))
    }

    /// The payload of a service a node acts on, or `None` for another service.
    fn node_message(
        service: Service,
        padded: [u8; 8],
        len: u8,
    ) -> Result<Option<Message>, DecodeError> {
        let bad = DecodeError::Value { service };
        let expected = service.payload_len();
        let data = &padded;
        let message = match service {
            Service::Gates => {
                let gates = Gates {
                    group: byte(data, 0),
                    behaviours: byte(data, 1),
                    mask: u32_at(data, 2),
                    changes: byte(data, 6),
                };
                if !gates.is_valid() || byte(data, 7) != 0 {
                    return Err(bad);
                }
                Message::Gates(gates)
            }
            Service::DiagnosticControl => {
                let rate_hz = u16_at(data, 0);
                if rate_hz > DiagnosticControl::MAX_RATE_HZ {
                    return Err(bad);
                }
                let control = DiagnosticControl {
                    rate_hz,
                    ports: u16_at(data, 2),
                };
                // The length is the plain form's (4) or with its tag (8).
                if usize::from(len) > expected {
                    Message::AuthenticatedDiagnosticControl {
                        control,
                        tag: bytes_at(data, 4),
                    }
                } else {
                    Message::DiagnosticControl(control)
                }
            }
            // The bytes past the frame's length are zero, as the padding made them.
            Service::TableTransfer => Message::TableTransfer { data: padded, len },
            Service::SchemaTransfer => Message::SchemaTransfer { data: padded, len },
            Service::ChallengeRequest => Message::ChallengeRequest,
            Service::EmergencyStop => Message::EmergencyStop,
            Service::SchemaAbort => Message::SchemaAbort,
            Service::TransferOpen => {
                let flags = byte(data, 2);
                // Replacing a version means nothing to a schema.
                if flags & !(OPEN_REPLACE | OPEN_SCHEMA) != 0 || flags == OPEN_REPLACE | OPEN_SCHEMA
                {
                    return Err(bad);
                }
                Message::TransferOpen(TransferOpen {
                    length: u16_at(data, 0),
                    flags,
                    tag: bytes_at(data, 3),
                })
            }
            Service::FilterProfile => {
                if byte(data, 1) != 0 {
                    return Err(bad);
                }
                Message::FilterProfile(FilterProfile {
                    profile: byte(data, 0),
                    sequence: u16_at(data, 2),
                })
            }
            Service::FilterSet => {
                if byte(data, 3) != 0 {
                    return Err(bad);
                }
                Message::FilterSet(FilterSet {
                    port: byte(data, 0),
                    connection: byte(data, 1),
                    phi: byte(data, 2),
                    sequence: u16_at(data, 4),
                })
            }

            _ => return Ok(None),
        };
        Ok(Some(message))
    }

    /// The payload of a service a node does not act on (reports, HBBA's desires and status).
    fn report(service: Service, padded: [u8; 8]) -> Result<Message, DecodeError> {
        let bad = DecodeError::Value { service };
        let data = &padded;
        Ok(match service {
            Service::Fault => Message::Fault(Fault {
                code: FaultCode::from_code(u16_at(data, 0)).ok_or(bad)?,
                count: byte(data, 2),
                detail: bytes_at(data, 3),
            }),
            Service::Heartbeat => Message::Heartbeat(Heartbeat {
                state: NodeState::from_code(byte(data, 0)).ok_or(bad)?,
                uptime_s: u32::from_le_bytes([byte(data, 1), byte(data, 2), byte(data, 3), 0]),
                table_version: u32_at(data, 4),
            }),
            Service::TableStatus => {
                let flags = byte(data, 7);
                if flags & !0b111 != 0 {
                    return Err(bad);
                }
                Message::TableStatus(TableStatus {
                    crc: u32_at(data, 0),
                    image_len: u16_at(data, 4),
                    ports: byte(data, 6),
                    stored: flags & 1 != 0,
                    diagnostic: flags & 2 != 0,
                    keyed: flags & 4 != 0,
                })
            }
            Service::Traffic => Message::Traffic(Traffic {
                received: u32_at(data, 0),
                delivered: u32_at(data, 4),
            }),
            Service::Errors => Message::Errors(Errors {
                discarded: u32_at(data, 0),
                errors: u32_at(data, 4),
            }),
            Service::Diagnostic => Message::Diagnostic(DiagnosticSample {
                port: byte(data, 0),
                connection: byte(data, 1),
                flags: DiagnosticFlags::from_bits(byte(data, 2)).ok_or(bad)?,
                sequence: byte(data, 3),
                level: u32_at(data, 4),
            }),
            Service::TransferStatus => {
                if u16_at(data, 6) != 0 {
                    return Err(bad);
                }
                Message::TransferStatus(TransferStatus {
                    status: TransferStatusCode::from_code(byte(data, 0)).ok_or(bad)?,
                    detail: byte(data, 1),
                    running_version: u32_at(data, 2),
                })
            }
            Service::Challenge => Message::Challenge {
                nonce: u64::from_le_bytes(padded),
            },
            Service::Receipt => Message::Receipt { tag: padded },
            Service::Desire => {
                if byte(data, 1) != 0 {
                    return Err(bad);
                }
                Message::Desire(DesireFrame {
                    class: byte(data, 0),
                    intensity: u16_at(data, 2),
                    lease_ms: u16_at(data, 4),
                    id: u16_at(data, 6),
                })
            }
            Service::Intention => Message::Intention(Intention {
                strategies: u64::from_le_bytes(padded),
            }),
            Service::FilterStatus => {
                let status = FilterStatus {
                    profile: byte(data, 0),
                    sequence: u16_at(data, 2),
                    filtered: byte(data, 4),
                    closed: byte(data, 5),
                    throttled: byte(data, 6),
                };
                let counts_fit = u16::from(status.closed) + u16::from(status.throttled)
                    <= u16::from(status.filtered);
                let profile_ok =
                    status.profile < 16 || status.profile == FilterStatus::SET_ONE_BY_ONE;
                if byte(data, 1) != 0 || byte(data, 7) != 0 || !counts_fit || !profile_ok {
                    return Err(bad);
                }
                Message::FilterStatus(status)
            }
            Service::Exploitation => {
                let delivering = match byte(data, 2) {
                    0 => false,
                    1 => true,
                    _ => return Err(bad),
                };
                if byte(data, 3) != 0 {
                    return Err(bad);
                }
                Message::Exploitation(Exploitation {
                    port: byte(data, 0),
                    connection: byte(data, 1),
                    delivering,
                })
            }
            Service::SchemaAck => {
                if bytes_at::<2>(data, 6) != [0; 2] || byte(data, 5) >= 64 {
                    return Err(bad);
                }
                let channel = match byte(data, 1) {
                    SchemaAck::NO_CHANNEL => None,
                    code => Some(SchemaChannel::from_code(code).ok_or(bad)?),
                };
                Message::SchemaAck(SchemaAck {
                    outcome: SchemaOutcome::from_code(byte(data, 0)).ok_or(bad)?,
                    channel,
                    id: u16_at(data, 2),
                    queued: byte(data, 4),
                    stop: byte(data, 5),
                })
            }
            Service::SchemaTransition => {
                let change = SchemaTransition {
                    ended: u16_at(data, 0),
                    installed: u16_at(data, 2),
                    trigger: SchemaTrigger::from_code(byte(data, 4)).ok_or(bad)?,
                    detail: byte(data, 5),
                    source: SchemaOrigin::from_code(byte(data, 6)).ok_or(bad)?,
                    queued: byte(data, 7),
                };
                if !change.is_valid() {
                    return Err(bad);
                }
                Message::SchemaTransition(change)
            }
            Service::SchemaState => {
                let flags = byte(data, 5);
                let fault = match byte(data, 3) {
                    SchemaState::NO_FAULT => None,
                    code => Some(SchemaSafety::from_code(code).ok_or(bad)?),
                };
                Message::SchemaState(SchemaState {
                    current: u16_at(data, 0),
                    source: SchemaOrigin::from_code(byte(data, 2)).ok_or(bad)?,
                    fault,
                    queued: byte(data, 4),
                    armed: flags & 1 != 0,
                    gripper_closed: flags & 2 != 0,
                    stop: flags >> 2,
                    elapsed_ms: u16_at(data, 6),
                })
            }
            // Decoded by `node_message`.
            _ => return Err(bad),
        })
    }
}

/// The frame of `service` from `source` to `destination` with the first `len` bytes of `data`
/// (little endian).
fn frame(service: Service, source: u8, destination: u8, data: u64, len: u8) -> Frame {
    Frame::from_buffer(
        FrameId::new(service, source, destination).id(),
        data.to_le_bytes(),
        len,
    )
}

/// Two little-endian `u32`s, one after the other.
fn words(first: u32, second: u32) -> u64 {
    u64::from(first) | u64::from(second) << 32
}

/// Eight payload bytes as one little-endian word.
fn le_word(bytes: [u8; 8]) -> u64 {
    u64::from_le_bytes(bytes)
}

/// A DiagnosticControl's payload: rate and ports, then `tag` (zeros in the plain form, whose
/// length stops before it).
fn control_bytes(control: &DiagnosticControl, tag: [u8; 4]) -> [u8; 8] {
    let [r0, r1] = control.rate_hz.to_le_bytes();
    let [p0, p1] = control.ports.to_le_bytes();
    let [t0, t1, t2, t3] = tag;
    [r0, r1, p0, p1, t0, t1, t2, t3]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::BROADCAST;

    fn samples() -> [Message; 26] {
        [
            Message::Fault(Fault {
                code: FaultCode::TableRefused,
                count: 3,
                detail: [0x16, 0, 0, 0, 9],
            }),
            Message::Heartbeat(Heartbeat {
                state: NodeState::Operational,
                uptime_s: 0x12_3456,
                table_version: 7,
            }),
            Message::TableStatus(TableStatus {
                crc: 0xDEAD_BEEF,
                image_len: 177,
                ports: 1,
                stored: true,
                diagnostic: false,
                keyed: true,
            }),
            Message::Traffic(Traffic {
                received: 1_000_000,
                delivered: 42,
            }),
            Message::Errors(Errors {
                discarded: 5,
                errors: u32::MAX,
            }),
            Message::Diagnostic(DiagnosticSample {
                port: 2,
                connection: 15,
                flags: DiagnosticFlags {
                    active: true,
                    resting: false,
                    delivering: true,
                    end_of_round: true,
                },
                sequence: 200,
                level: 1 << 30,
            }),
            Message::DiagnosticControl(DiagnosticControl {
                rate_hz: 20,
                ports: 0b101,
            }),
            Message::TableTransfer {
                data: [0x10, 0x14, 1, 2, 3, 4, 5, 6],
                len: 8,
            },
            Message::TransferStatus(TransferStatus {
                status: TransferStatusCode::OlderVersion,
                detail: 0,
                running_version: 9,
            }),
            Message::AuthenticatedDiagnosticControl {
                control: DiagnosticControl {
                    rate_hz: 200,
                    ports: 1,
                },
                tag: [1, 2, 3, 4],
            },
            Message::ChallengeRequest,
            Message::Challenge {
                nonce: 0x0102_0304_0506_0708,
            },
            Message::TransferOpen(TransferOpen {
                length: 300,
                flags: OPEN_REPLACE,
                tag: [9, 8, 7, 6, 5],
            }),
            Message::Receipt {
                tag: [1, 2, 3, 4, 5, 6, 7, 8],
            },
            Message::Desire(DesireFrame {
                class: 2,
                intensity: 65_535,
                lease_ms: 500,
                id: 0x0102,
            }),
            Message::Intention(Intention {
                strategies: 1 << 63 | 0b101,
            }),
            Message::FilterStatus(FilterStatus {
                profile: FilterStatus::SET_ONE_BY_ONE,
                sequence: 0xBEEF,
                filtered: 5,
                closed: 2,
                throttled: 3,
            }),
            Message::Exploitation(Exploitation {
                port: 1,
                connection: 4,
                delivering: true,
            }),
            Message::FilterProfile(FilterProfile {
                profile: 15,
                sequence: 7,
            }),
            Message::FilterSet(FilterSet {
                port: 0,
                connection: 3,
                phi: 3,
                sequence: 0xFFFF,
            }),
            Message::EmergencyStop,
            Message::SchemaAbort,
            Message::SchemaTransfer {
                data: [0x05, 1, 7, 0, 2, 0, 0, 0],
                len: 6,
            },
            Message::SchemaAck(SchemaAck {
                outcome: SchemaOutcome::QueueFull,
                channel: Some(SchemaChannel::Queue),
                id: 0x0102,
                queued: 8,
                stop: 63,
            }),
            Message::SchemaTransition(SchemaTransition {
                ended: 7,
                installed: 0xFF12,
                trigger: SchemaTrigger::Safety,
                detail: SchemaSafety::Limit.code(),
                source: SchemaOrigin::Innate,
                queued: 3,
            }),
            Message::SchemaState(SchemaState {
                current: 0xFF01,
                source: SchemaOrigin::HighPriority,
                fault: Some(SchemaSafety::Overrun),
                queued: 2,
                armed: true,
                gripper_closed: false,
                stop: 63,
                elapsed_ms: u16::MAX,
            }),
        ]
    }

    /// Each schema report and its bytes, as docs/can-protocol.md lays them out.
    #[test]
    fn schema_frames_are_byte_exact() {
        let ack = Message::SchemaAck(SchemaAck {
            outcome: SchemaOutcome::Accepted,
            channel: Some(SchemaChannel::HighPriority),
            id: 0x0304,
            queued: 5,
            stop: 9,
        });
        assert_eq!(ack.to_frame(10, 0).payload(), &[0, 1, 4, 3, 5, 9, 0, 0]);
        let unreadable = Message::SchemaAck(SchemaAck {
            outcome: SchemaOutcome::TooLong,
            channel: None,
            id: SchemaAck::NO_ID,
            queued: 0,
            stop: 0,
        });
        assert_eq!(
            unreadable.to_frame(10, 0).payload(),
            &[0x0B, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0]
        );
        let change = Message::SchemaTransition(SchemaTransition {
            ended: 0x0102,
            installed: 0x0304,
            trigger: SchemaTrigger::Reaction,
            detail: 2,
            source: SchemaOrigin::Queue,
            queued: 6,
        });
        assert_eq!(
            change.to_frame(10, BROADCAST).payload(),
            &[2, 1, 4, 3, 3, 2, 1, 6]
        );
        let state = Message::SchemaState(SchemaState {
            current: 0x0102,
            source: SchemaOrigin::Queue,
            fault: None,
            queued: 4,
            armed: true,
            gripper_closed: true,
            stop: 5,
            elapsed_ms: 0x0304,
        });
        assert_eq!(
            state.to_frame(10, BROADCAST).payload(),
            &[2, 1, 1, 0xFF, 4, 0b0001_0111, 4, 3]
        );
        assert_eq!(SchemaState::saturate_ms(70_000), u16::MAX);
        assert_eq!(SchemaState::saturate_ms(1_234), 1_234);
        // The emergency stop from the tool to all: the lowest identifier of ours, no payload.
        let stop = Message::EmergencyStop.to_frame(0, BROADCAST);
        assert!(stop.payload().is_empty());
        assert_eq!(
            FrameId::decode(&stop.id()).map(|id| id.raw()),
            Some(0x0200_FF00)
        );
    }

    #[test]
    fn schema_frames_refuse_unknown_codes_reserved_bits_and_bytes() {
        let refused = |service: Service, payload: &[u8]| {
            let id = FrameId::new(service, 10, BROADCAST).id();
            let frame = Frame::data(id, payload).unwrap();
            let full = Message::decode(&frame) == Err(DecodeError::Value { service });
            // A node reads none of these reports: well framed, they are not its business.
            full && Message::decode_for_node(&frame) == Ok(None)
        };
        let accepted = |service: Service, payload: &[u8]| {
            let id = FrameId::new(service, 10, BROADCAST).id();
            Message::decode(&Frame::data(id, payload).unwrap()).is_ok()
        };
        // SchemaAck: outcome past 0x11, channel neither 0, 1, 2 nor 0xFF, a stop number of 64 or
        // more, reserved bytes 6-7.
        assert!(accepted(
            Service::SchemaAck,
            &[0x11, 0xFF, 0, 0, 0, 63, 0, 0]
        ));
        assert!(accepted(
            Service::SchemaAck,
            &[0x11, 2, 0xFF, 0xFF, 0, 0, 0, 0]
        ));
        assert!(refused(Service::SchemaAck, &[0x12, 0, 0, 0, 0, 0, 0, 0]));
        assert!(refused(Service::SchemaAck, &[0, 3, 0, 0, 0, 0, 0, 0]));
        assert!(refused(Service::SchemaAck, &[0, 0, 0, 0, 0, 64, 0, 0]));
        for at in 6..8 {
            let mut payload = [0u8; 8];
            payload[at] = 1;
            assert!(refused(Service::SchemaAck, &payload), "byte {at}");
        }
        // SchemaTransition: trigger past 3, source past 2, a detail that contradicts its trigger.
        assert!(accepted(
            Service::SchemaTransition,
            &[1, 0, 0, 0xFF, 3, 255, 2, 8]
        ));
        assert!(accepted(
            Service::SchemaTransition,
            &[1, 0, 0x15, 0xFF, 2, 5, 0, 8]
        ));
        assert!(refused(
            Service::SchemaTransition,
            &[1, 0, 0, 0, 4, 0, 0, 0]
        ));
        assert!(refused(
            Service::SchemaTransition,
            &[1, 0, 0, 0, 0, 0, 3, 0]
        ));
        assert!(refused(
            Service::SchemaTransition,
            &[1, 0, 0x19, 0xFF, 2, 9, 0, 0]
        ));
        assert!(refused(
            Service::SchemaTransition,
            &[1, 0, 0, 0, 0, 1, 2, 0]
        ));
        assert!(refused(
            Service::SchemaTransition,
            &[1, 0, 1, 0xFF, 1, 1, 2, 0]
        ));
        // SchemaState: source past 2, an unknown safety event; every flags byte is valid (its
        // bits 2-7 are the stop number).
        assert!(accepted(
            Service::SchemaState,
            &[0, 0, 2, 5, 8, 0xFF, 0xFF, 0xFF]
        ));
        assert!(refused(Service::SchemaState, &[0, 0, 3, 0xFF, 0, 0, 0, 0]));
        assert!(refused(Service::SchemaState, &[0, 0, 0, 9, 0, 0, 0, 0]));
    }

    #[test]
    fn a_node_reads_the_stop_the_abort_and_schema_transfers_only() {
        for message in samples() {
            let frame = message.to_frame(0, 10);
            let for_node = Message::decode_for_node(&frame).unwrap();
            let acts = matches!(
                message.service(),
                Service::Gates
                    | Service::DiagnosticControl
                    | Service::TableTransfer
                    | Service::ChallengeRequest
                    | Service::TransferOpen
                    | Service::FilterProfile
                    | Service::FilterSet
                    | Service::EmergencyStop
                    | Service::SchemaAbort
                    | Service::SchemaTransfer
            );
            assert_eq!(for_node.is_some(), acts, "{message:?}");
            if let Some((_, decoded)) = for_node {
                assert_eq!(decoded, message);
            }
        }
        // The stop and the abort have no payload: any byte makes them malformed, for a node too.
        for service in [Service::EmergencyStop, Service::SchemaAbort] {
            let id = FrameId::new(service, 0, BROADCAST).id();
            let padded = Frame::data(id, &[0]).unwrap();
            let error = DecodeError::Length { service, len: 1 };
            assert_eq!(Message::decode_for_node(&padded), Err(error));
            assert_eq!(Message::decode(&padded), Err(error));
        }
    }

    #[test]
    fn every_message_round_trips() {
        for message in samples() {
            let frame = message.to_frame(3, BROADCAST);
            let (id, decoded) = Message::decode(&frame).unwrap();
            assert_eq!(decoded, message);
            assert_eq!(id.source, 3);
            assert_eq!(id.destination, BROADCAST);
            assert_eq!(id.service, message.service());
            if matches!(message, Message::AuthenticatedDiagnosticControl { .. }) {
                assert_eq!(frame.payload().len(), 8);
            } else if let Message::SchemaTransfer { len, .. } = message {
                assert_eq!(frame.payload().len(), usize::from(len));
            } else if message.service() != Service::TableTransfer {
                assert_eq!(frame.payload().len(), message.service().payload_len());
            }
        }
    }

    #[test]
    fn a_nodes_encoder_is_to_frame_without_the_commands() {
        for message in samples() {
            let command = matches!(
                message.service(),
                Service::DiagnosticControl
                    | Service::ChallengeRequest
                    | Service::TransferOpen
                    | Service::Desire
                    | Service::Intention
                    | Service::FilterProfile
                    | Service::FilterSet
                    | Service::EmergencyStop
                    | Service::SchemaAbort
            );
            let expected = (!command).then(|| message.to_frame(3, 9));
            assert_eq!(message.report_frame(3, 9), expected, "{message:?}");
        }
    }

    #[test]
    fn payloads_are_byte_exact() {
        let heartbeat = Message::Heartbeat(Heartbeat {
            state: NodeState::Fault,
            uptime_s: 0x0102_0304, // saturates to 2^24 - 1 on the wire
            table_version: 0x0A0B_0C0D,
        });
        assert_eq!(
            heartbeat.to_frame(5, BROADCAST).payload(),
            &[2, 0xFF, 0xFF, 0xFF, 0x0D, 0x0C, 0x0B, 0x0A]
        );
        let status = Message::TransferStatus(TransferStatus {
            status: TransferStatusCode::Applied,
            detail: 0,
            running_version: 0x0102_0304,
        });
        assert_eq!(status.to_frame(5, 0).payload(), &[0, 0, 4, 3, 2, 1, 0, 0]);
        let control = Message::DiagnosticControl(DiagnosticControl {
            rate_hz: 10,
            ports: 0xFFFF,
        });
        assert_eq!(control.to_frame(0, 5).payload(), &[10, 0, 0xFF, 0xFF]);
        let desire = Message::Desire(DesireFrame {
            class: 3,
            intensity: 0x0102,
            lease_ms: 0x0304,
            id: 0x0506,
        });
        assert_eq!(
            desire.to_frame(9, BROADCAST).payload(),
            &[3, 0, 2, 1, 4, 3, 6, 5]
        );
        let set = Message::FilterSet(FilterSet {
            port: 1,
            connection: 2,
            phi: 3,
            sequence: 0x0405,
        });
        assert_eq!(set.to_frame(9, 2).payload(), &[1, 2, 3, 0, 5, 4]);
        let status = Message::FilterStatus(FilterStatus {
            profile: 4,
            sequence: 0x0102,
            filtered: 6,
            closed: 1,
            throttled: 2,
        });
        assert_eq!(
            status.to_frame(2, BROADCAST).payload(),
            &[4, 0, 2, 1, 6, 1, 2, 0]
        );
    }

    #[test]
    fn hbba_frames_refuse_reserved_bytes_and_impossible_counts() {
        let refused = |service: Service, payload: &[u8]| {
            let id = FrameId::new(service, 1, BROADCAST).id();
            let frame = Frame::data(id, payload).unwrap();
            matches!(Message::decode(&frame), Err(DecodeError::Value { .. }))
        };
        assert!(refused(Service::Desire, &[0, 1, 1, 0, 1, 0, 0, 0]));
        // More closed and throttled filters than filtered ones; a profile past 15; reserved bytes.
        assert!(refused(Service::FilterStatus, &[0, 0, 0, 0, 2, 2, 1, 0]));
        assert!(refused(Service::FilterStatus, &[16, 0, 0, 0, 2, 0, 0, 0]));
        assert!(refused(Service::FilterStatus, &[0, 1, 0, 0, 2, 0, 0, 0]));
        assert!(refused(Service::FilterStatus, &[0, 0, 0, 0, 2, 0, 0, 1]));
        assert!(refused(Service::Exploitation, &[0, 0, 2, 0]));
        assert!(refused(Service::Exploitation, &[0, 0, 1, 1]));
        assert!(refused(Service::FilterProfile, &[0, 1, 0, 0]));
        assert!(refused(Service::FilterSet, &[0, 0, 1, 1, 0, 0]));
    }

    #[test]
    fn wrong_lengths_and_values_are_refused() {
        for message in samples() {
            let frame = message.to_frame(1, 0);
            let payload = frame.payload();
            if matches!(
                message.service(),
                Service::TableTransfer | Service::SchemaTransfer
            ) {
                let empty = Frame::data(frame.id(), &[]).unwrap();
                assert!(matches!(
                    Message::decode(&empty),
                    Err(DecodeError::Length { .. })
                ));
                continue;
            }
            for len in 0..=8 {
                // DiagnosticControl has two valid lengths: its plain and its tagged form.
                let other_form =
                    message.service() == Service::DiagnosticControl && (len == 4 || len == 8);
                if len == payload.len() || other_form {
                    continue;
                }
                let mut data = [0u8; 8];
                data[..payload.len()].copy_from_slice(payload);
                let short = Frame::data(frame.id(), &data[..len]).unwrap();
                assert_eq!(
                    Message::decode(&short),
                    Err(DecodeError::Length {
                        service: message.service(),
                        len: len as u8
                    })
                );
            }
        }
        let id = FrameId::new(Service::Heartbeat, 1, BROADCAST).id();
        let bad_state = Frame::data(id, &[9, 0, 0, 0, 0, 0, 0, 0]).unwrap();
        assert!(matches!(
            Message::decode(&bad_state),
            Err(DecodeError::Value { .. })
        ));
        let id = FrameId::new(Service::DiagnosticControl, 0, 1).id();
        let too_fast = Frame::data(id, &[201, 0, 1, 0]).unwrap();
        assert!(matches!(
            Message::decode(&too_fast),
            Err(DecodeError::Value { .. })
        ));
        let id = FrameId::new(Service::TransferStatus, 1, 0).id();
        let reserved = Frame::data(id, &[0, 0, 1, 0, 0, 0, 0, 1]).unwrap();
        assert!(matches!(
            Message::decode(&reserved),
            Err(DecodeError::Value { .. })
        ));
        // TransferOpen: a reserved flag bit, and replace and schema together, are refused.
        let id = FrameId::new(Service::TransferOpen, 0, 1).id();
        for flags in [4, 0x80, OPEN_REPLACE | OPEN_SCHEMA] {
            let refused = Frame::data(id, &[0, 1, flags, 0, 0, 0, 0, 0]).unwrap();
            assert!(
                matches!(Message::decode(&refused), Err(DecodeError::Value { .. })),
                "flags {flags:#04x}"
            );
        }
        for flags in [0, OPEN_REPLACE, OPEN_SCHEMA] {
            let taken = Frame::data(id, &[0, 1, flags, 0, 0, 0, 0, 0]).unwrap();
            assert!(Message::decode(&taken).is_ok(), "flags {flags:#04x}");
        }
        let id = FrameId::new(Service::TableStatus, 1, BROADCAST).id();
        let reserved_bit = Frame::data(id, &[0, 0, 0, 0, 0, 0, 0, 8]).unwrap();
        assert!(matches!(
            Message::decode(&reserved_bit),
            Err(DecodeError::Value { .. })
        ));
        let id = FrameId::new(Service::TransferStatus, 1, 0).id();
        let remote = <Frame as embedded_can::Frame>::new_remote(id, 8).unwrap();
        assert_eq!(Message::decode(&remote), Err(DecodeError::Remote));
    }

    #[test]
    fn arbitrary_frames_never_panic() {
        // Every service, every length, a spread of byte patterns.
        let mut seed = 0x1234_5678u32;
        for _ in 0..20_000 {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            let raw = (seed & 0x1FFF_FFFF) | 0b10 << 24;
            let len = (seed >> 29) as usize + 1;
            let data = seed.to_le_bytes();
            let mut bytes = [0u8; 8];
            bytes[..4].copy_from_slice(&data);
            bytes[4..].copy_from_slice(&data.map(|b| b.rotate_left(3)));
            let frame = Frame::with_raw_id(raw, true, &bytes[..len.min(8)]).unwrap();
            let _ = Message::decode(&frame);
        }
    }
}
