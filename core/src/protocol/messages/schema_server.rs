//! The schema server's answers and reports: the acknowledgement of a schema message, its
//! transitions and its periodic state.

use crate::protocol::{SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety, SchemaTrigger};

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

use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Values};

impl SchemaAck {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::SchemaAck,
        &[
            Field::new(
                "outcome",
                0,
                8,
                "0 accepted, else why the schema was refused (SchemaOutcome)",
            )
            .values(Values::SchemaOutcome),
            Field::new(
                "channel",
                8,
                8,
                "channel of the message: 0 queue, 1 high-priority, 255 unreadable",
            )
            .values(Values::SchemaChannel),
            Field::new(
                "id",
                16,
                16,
                "the schema's id (65535 when it could not be decoded)",
            ),
            Field::new("queued", 32, 8, "schemas in the queue after it"),
            Field::new(
                "stop",
                40,
                8,
                "the server's stop number (stops modulo 64) when it answered",
            )
            .max(63),
            Field::reserved("reserved", 48, 16),
        ],
        "the answer to one SchemaTransfer message (ISO-TP, service 0x1A), to its sender.",
    );
}

impl SchemaTransition {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::SchemaTransition,
        &[
            Field::new("ended", 0, 16, "the schema that ended"),
            Field::new(
                "installed",
                16,
                16,
                "the schema installed (0xFF00 the wait for the queue, 0xFF01 the wait for the \
                 high-priority channel, 0xFF10 + cause the recovery after a safety event)",
            ),
            Field::new("trigger", 32, 8, "what ended the schema").values(Values::SchemaTrigger),
            Field::new(
                "detail",
                40,
                8,
                "trigger 2 (safety): the cause, 0 emergency stop, 1 sensor stale, 2 workspace \
                 limit, 3 force limit, 4 watchdog, 5 loop overrun; trigger 3 (reaction): the \
                 reaction's index in the ended schema's table; otherwise 0",
            ),
            Field::new("source", 48, 8, "where the installed schema came from")
                .values(Values::SchemaOrigin),
            Field::new("queued", 56, 8, "schemas in the queue after it"),
        ],
        "a schema change of the server, on every change (several in one tick: in order).",
    );
}

impl SchemaState {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::SchemaState,
        &[
            Field::new("current", 0, 16, "the installed schema"),
            Field::new("source", 16, 8, "where the installed schema came from")
                .values(Values::SchemaOrigin),
            Field::new(
                "fault",
                24,
                8,
                "the safety event the server is stopped on, 255 when none",
            )
            .values(Values::SchemaSafety),
            Field::new("queued", 32, 8, "schemas in the queue"),
            Field::new("armed", 40, 1, "1: a pose has been received"),
            Field::new("gripper_closed", 41, 1, "1: the gripper is closed"),
            Field::new(
                "stop",
                42,
                6,
                "the stop number: the server's stops (emergency stops, aborts, safety events) \
                 modulo 64, which a high-priority schema names to leave the latest one",
            ),
            Field::new(
                "elapsed",
                48,
                16,
                "ms since the schema was installed, saturating",
            )
            .unit("ms"),
        ],
        "the schema server's state, every 100 ms.",
    );
}

/// The layout of an emergency stop (service 0x00): no payload.
pub const EMERGENCY_STOP_LAYOUT: Layout = Layout::fixed(
    Service::EmergencyStop,
    &[],
    "the lowest identifier of the protocol; a schema server halts within one loop period \
     (attractor on the measured pose, SchemaSafety fault, waits on the high-priority channel). \
     Accepted from any source.",
);

/// The layout of a schema abort (service 0x19): no payload.
pub const SCHEMA_ABORT_LAYOUT: Layout = Layout::fixed(
    Service::SchemaAbort,
    &[],
    "the client abandons its program; the schema server empties its queue and waits on the \
     high-priority channel. Accepted from any source.",
);

/// The layout of a schema message's frames (service 0x1A): ISO-TP.
pub const SCHEMA_TRANSFER_LAYOUT: Layout = Layout::isotp(
    Service::SchemaTransfer,
    "ISO 15765-2 frames of one schema message (a channel byte and the schema's postcard \
     bytes), padded to 8 bytes; the node's flow control back on the same service.",
);
