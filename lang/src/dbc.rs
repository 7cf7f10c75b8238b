//! A DBC description of a network's traffic, for cantools, SavvyCAN, Wireshark and the like.
//!
//! Three kinds of messages:
//!
//! - **The project's own frames** (`docs/can-protocol.md`), one message per (service, node): the
//!   node → all services (heartbeat, table status, traffic, errors, fault, diagnostic samples),
//!   the transfer status each node sends to the tool, and the diagnostic control the tool sends
//!   to each node (and to all nodes); for a schema server's board, its answers, transitions and
//!   state, and the emergency stop and abort the tool sends it (and all). Identifiers come from
//!   [`FrameId::raw`], the same code the nodes run; nothing here recomputes the layout. Table
//!   and schema transfer frames (ISO-TP) are not signals: they are only named in the comments.
//! - **A schema server's drive and sensors**: the drive's frames (`Drive_*`: attractor, pose,
//!   wrench, signed 21-bit signals) on the ids of `[schema.NODE] drive`, and one `Sensor_*`
//!   message per identifier its extra sensors read (`[schema.NODE.sensors.NAME]`), one signal
//!   per sensor at its field, with the sensor's scale as factor and its unit.
//! - **The network's topics**, one message per topic named after it, its DLC the topic's
//!   `length`: each field the network reads from its frames (a value port's value and priority,
//!   a BLE group's eligibility, a dynamics behaviour's context) is a signal with its size, sign
//!   and byte order, and every other byte a one-byte signal `dataN`. What else a topic carries
//!   is its publisher's business; a capture then shows which topic each frame belongs to and
//!   what the network reads from it, and decodes strictly (`cantools decode` without
//!   `--no-strict`) when the frames have the topic's length.
//!
//! Conventions: extended identifiers are written `raw | 0x8000_0000` (the DBC convention);
//! payloads are little endian (`@1`) but a sensor's big-endian field (`@0`, Motorola);
//! enumerations get `VAL_` tables from the enums' `ALL` and `description()`; the heartbeat and
//! its status frames carry `GenMsgCycleTime` 1000.

use std::collections::HashSet;
use std::fmt::Write as _;

use pab_core::protocol::{
    BROADCAST, FaultCode, FrameId, INTENTION, NodeState, PROTOCOL_MASK, PROTOCOL_VALUE, SchemaAck,
    SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety, SchemaState, SchemaTrigger, Service,
    TOOL, TransferStatusCode,
};

use pab_core::ble::Claim;
use pab_core::value_port::{Endian, Field};

use crate::diagnostic::Diagnostics;
use crate::network::{Network, SchemaBoard, SensorTopic};

/// The DBC node name of the workstation tool.
pub const TOOL_NODE: &str = "PABCTL";
/// The DBC node of the intention node (pab-intent), in networks with an `[hbba]` section.
pub const INTENTION_NODE: &str = "PAB_INTENT";
/// The DBC placeholder for "no node / unknown node".
pub const UNKNOWN_NODE: &str = "Vector__XXX";
/// The flag DBC files set on extended identifiers.
pub const EXTENDED_FLAG: u32 = 0x8000_0000;
/// 2^-31: the scale of a Q1.31 level, written exactly.
pub const Q31_FACTOR: &str = "0.0000000004656612873077392578125";

/// One signal of a message.
#[derive(Clone, Debug, PartialEq)]
pub struct DbcSignal {
    /// Its name (a C identifier).
    pub name: String,
    /// Its start bit, in DBC's numbering (byte * 8 + bit, bit 0 the byte's least significant):
    /// its least significant bit when little endian (`@1`), its most significant bit when big
    /// endian (`@0`, Motorola: a field from byte `b` on starts at `b * 8 + 7`).
    pub start: u32,
    /// Its width in bits.
    pub len: u32,
    /// Its byte order: `@1` little endian (Intel), `@0` big endian (Motorola).
    pub endian: Endian,
    /// The scale, as written: physical = raw × factor.
    pub factor: String,
    /// The smallest physical value, as written.
    pub min: String,
    /// The largest physical value, as written.
    pub max: String,
    /// Its unit.
    pub unit: String,
    /// Its value table: code, description.
    pub values: Vec<(u32, &'static str)>,
    /// What it means.
    pub comment: String,
    /// Two's complement (`@1-`), else unsigned (`@1+`).
    pub signed: bool,
}

/// One message.
#[derive(Clone, Debug, PartialEq)]
pub struct DbcMessage {
    /// The identifier as a DBC file writes it (extended ones with [`EXTENDED_FLAG`]).
    pub id: u32,
    /// Its name (a C identifier, unique in the file).
    pub name: String,
    /// Its length in bytes.
    pub dlc: u8,
    /// The sending node, or [`UNKNOWN_NODE`].
    pub transmitter: String,
    /// The receiving nodes (at least one; [`UNKNOWN_NODE`] if none is known).
    pub receivers: Vec<String>,
    /// Its signals.
    pub signals: Vec<DbcSignal>,
    /// What it is.
    pub comment: String,
    /// The period in milliseconds, for periodic messages.
    pub cycle_ms: Option<u32>,
}

/// A whole DBC database.
#[derive(Clone, Debug, PartialEq)]
pub struct Dbc {
    /// Node names: [`TOOL_NODE`], then the network's nodes in file order.
    pub nodes: Vec<String>,
    /// A comment per node, in the order of `nodes`.
    pub node_comments: Vec<String>,
    /// The messages: protocol messages node by node, then diagnostic control, then topics.
    pub messages: Vec<DbcMessage>,
    /// The comment on the whole database.
    pub comment: String,
}

/// Turns `name` into a C identifier: characters other than ASCII letters, digits and `_` become
/// `_`, and a name that would start with a digit (or be empty) gets `prefix` in front.
pub fn identifier(name: &str, prefix: &str) -> String {
    let mut out: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert_str(0, prefix);
    }
    out
}

/// Makes names unique: the first keeps its name, later ones get `_2`, `_3`, ...
struct Names(HashSet<String>);

impl Names {
    fn unique(&mut self, name: String) -> String {
        if self.0.insert(name.clone()) {
            return name;
        }
        let mut n = 2;
        loop {
            let candidate = format!("{name}_{n}");
            if self.0.insert(candidate.clone()) {
                return candidate;
            }
            n += 1;
        }
    }
}

fn extended(frame: FrameId) -> u32 {
    frame.raw() | EXTENDED_FLAG
}

fn signal(name: &str, start: u32, len: u32, comment: &str) -> DbcSignal {
    DbcSignal {
        name: name.to_string(),
        start,
        len,
        endian: Endian::Little,
        factor: "1".to_string(),
        min: "0".to_string(),
        max: ((1u64 << len) - 1).to_string(),
        unit: String::new(),
        values: Vec::new(),
        comment: comment.to_string(),
        signed: false,
    }
}

fn with_unit(mut signal: DbcSignal, unit: &str) -> DbcSignal {
    signal.unit = unit.to_string();
    signal
}

fn with_values(mut signal: DbcSignal, values: Vec<(u32, &'static str)>) -> DbcSignal {
    if let Some(max) = values.iter().map(|(code, _)| *code).max() {
        signal.max = max.to_string();
    }
    signal.values = values;
    signal
}

/// The value table of [`NodeState`].
pub fn node_states() -> Vec<(u32, &'static str)> {
    NodeState::ALL
        .iter()
        .map(|s| (u32::from(s.code()), s.description()))
        .collect()
}

/// The value table of [`FaultCode`].
pub fn fault_codes() -> Vec<(u32, &'static str)> {
    FaultCode::ALL
        .iter()
        .map(|c| (u32::from(c.code()), c.description()))
        .collect()
}

/// The value table of [`TransferStatusCode`].
pub fn transfer_status_codes() -> Vec<(u32, &'static str)> {
    TransferStatusCode::ALL
        .iter()
        .map(|c| (u32::from(c.code()), c.description()))
        .collect()
}

/// The value table of a `wire_enum!` enumeration of the protocol, from its `ALL` and
/// `description()`.
macro_rules! wire_values {
    ($enum:ty) => {
        <$enum>::ALL
            .iter()
            .map(|c| (u32::from(c.code()), c.description()))
            .collect::<Vec<(u32, &'static str)>>()
    };
}

/// The value table of [`SchemaOutcome`].
pub fn schema_outcomes() -> Vec<(u32, &'static str)> {
    wire_values!(SchemaOutcome)
}

/// The value table of [`SchemaSafety`], and 255: none.
pub fn schema_safeties() -> Vec<(u32, &'static str)> {
    let mut values = wire_values!(SchemaSafety);
    values.push((u32::from(SchemaState::NO_FAULT), "none"));
    values
}

/// The signals of a service's payload, as `docs/can-protocol.md` lays them out; `None` for table
/// and schema transfer (ISO-TP segments, not a fixed layout).
pub fn service_signals(service: Service) -> Option<Vec<DbcSignal>> {
    Some(match service {
        Service::Fault => {
            let mut signals = vec![
                with_values(
                    signal("code", 0, 16, "what happened (FaultCode)"),
                    fault_codes(),
                ),
                signal(
                    "count",
                    16,
                    8,
                    "occurrences since the last frame with this code, at least 1, saturating at 255",
                ),
            ];
            let details = [
                "detail byte 0: for BadStoredTable and TableRefused the TransferStatusCode of the \
                 verdict (BadStoredTable: 0xFF when the store could not be read); for BusError a \
                 driver-specific kind; for BadCommand the service code of the malformed frame; \
                 for RxOverrun the low byte of the frames lost (bytes 0-3: u32 LE); otherwise 0",
                "detail byte 1: for BadStoredTable and TableRefused the verdict's detail (for \
                 WrongNode the image's node id); after 0xFF in byte 0, the StoreFailure: 1 the \
                 store could not be read, 2 the image is too large, 3 no stored copy verifies, \
                 4 other; for RxOverrun the frames lost, byte 1; otherwise 0",
                "detail byte 2, code-specific (RxOverrun: the frames lost, byte 2), 0 where unused",
                "detail byte 3, code-specific (RxOverrun: the frames lost, byte 3), 0 where unused",
                "detail byte 4, code-specific, 0 where unused",
            ];
            for (i, comment) in (0u32..).zip(details) {
                signals.push(signal(&format!("detail{i}"), 24 + 8 * i, 8, comment));
            }
            signals
        }
        Service::Heartbeat => vec![
            with_values(signal("state", 0, 8, "the node's state"), node_states()),
            with_unit(
                signal(
                    "uptime",
                    8,
                    24,
                    "seconds since boot, saturating at 2^24-1 (194 days)",
                ),
                "s",
            ),
            signal(
                "table_version",
                32,
                32,
                "version of the running table, 0 without a table",
            ),
        ],
        Service::Gates => vec![
            signal(
                "group",
                0,
                8,
                "the group's number in the network (the order of [dynamics.*], from 0)",
            ),
            signal("behaviours", 8, 8, "the group's behaviours, 1..32"),
            signal(
                "gates",
                16,
                32,
                "bit i set while behaviour i's gate is open; bits at and above the count are 0",
            ),
            signal(
                "changes",
                48,
                8,
                "changes of the gates since the group started, mod 256",
            ),
            signal("reserved", 56, 8, "0"),
        ],
        Service::TableStatus => vec![
            signal(
                "crc",
                0,
                32,
                "CRC-32 of the running image (its header's CRC field), 0 without a table",
            ),
            with_unit(signal("image_len", 32, 16, "image length"), "B"),
            signal("ports", 48, 8, "number of ports of the table"),
            signal(
                "stored",
                56,
                1,
                "1: the table is stored, the node boots with it",
            ),
            signal("diagnostic", 57, 1, "1: the diagnostic stream is on"),
            signal(
                "keyed",
                58,
                1,
                "1: the node has a key and takes only authenticated configuration; 0: it \
                 accepts configuration from anyone on the bus",
            ),
        ],
        Service::Traffic => vec![
            signal(
                "received",
                0,
                32,
                "frames received from the bus since boot, wrapping",
            ),
            signal(
                "delivered",
                32,
                32,
                "deliveries since boot (one per port a frame was delivered to), wrapping",
            ),
        ],
        Service::Errors => vec![
            signal(
                "discarded",
                0,
                32,
                "frames that fed at least one port and were delivered to none, since boot, wrapping",
            ),
            signal(
                "errors",
                32,
                32,
                "bus errors, overruns and malformed frames of the protocol, since boot, wrapping",
            ),
        ],
        Service::Diagnostic => vec![
            signal("port", 0, 8, "port index in the node's table"),
            signal("connection", 8, 8, "connection index within the port"),
            signal("active", 16, 1, "1: the connection is active"),
            signal("resting", 17, 1, "1: the connection is in its rest time"),
            signal(
                "delivering",
                18,
                1,
                "1: the port's decision selects this connection",
            ),
            signal("end_of_round", 19, 1, "1: the last sample of the round"),
            signal(
                "sequence",
                24,
                8,
                "round sequence number, shared by the round's samples, wrapping",
            ),
            DbcSignal {
                factor: Q31_FACTOR.to_string(),
                max: "1".into(),
                unit: "S".to_string(),
                comment: "stimulation S in 0..1 (Q1.31 on the wire: raw 2^31 = 1.0)".into(),
                ..signal("level", 32, 32, "")
            },
        ],
        Service::DiagnosticControl => vec![
            DbcSignal {
                max: "200".into(),
                ..with_unit(
                    signal(
                        "rate",
                        0,
                        16,
                        "rounds per second, 0 switches the stream off, at most 200",
                    ),
                    "Hz",
                )
            },
            signal("ports", 16, 16, "ports to sample: bit i = port i"),
        ],
        Service::TableTransfer => return None,
        Service::ChallengeRequest => Vec::new(),
        Service::Challenge => vec![
            signal("counter", 0, 32, "the node's challenge counter since boot"),
            signal(
                "boot_salt",
                32,
                32,
                "the boot salt: never repeats for one key (boot counter, or random)",
            ),
        ],
        Service::TransferOpen => vec![
            with_unit(
                signal(
                    "length",
                    0,
                    16,
                    "ISO-TP message length the first frame must announce (image + 16-byte MAC)",
                ),
                "B",
            ),
            signal(
                "replace",
                16,
                1,
                "1: replace whatever version runs (the keyed version reset)",
            ),
            signal(
                "tag",
                24,
                40,
                "CMAC (domain 2, node, nonce, length, flags), first 5 bytes",
            ),
        ],
        Service::Receipt => vec![
            signal(
                "tag_low",
                0,
                32,
                "CMAC (domain 4, node, nonce, the TransferStatus bytes, running CRC, stored \
                 flag): bytes 0-3",
            ),
            signal("tag_high", 32, 32, "the same CMAC: bytes 4-7"),
        ],
        Service::Desire => vec![
            signal(
                "class",
                0,
                8,
                "the class desired: its number in the network (first appearance among \
                 [hbba.strategies.*], from 0)",
            ),
            signal("reserved", 8, 8, "0"),
            signal(
                "intensity",
                16,
                16,
                "how much the class is desired; 0 withdraws the desire",
            ),
            with_unit(
                signal(
                    "lease",
                    32,
                    16,
                    "the desire lapses unless sent again within this many ms",
                ),
                "ms",
            ),
            signal(
                "id",
                48,
                16,
                "the sender's number for the desire: (source, id) names it",
            ),
        ],
        Service::Intention => vec![
            signal(
                "strategies_low",
                0,
                32,
                "bit s set when strategy s (file order of [hbba.strategies.*]) is selected, s < 32",
            ),
            signal(
                "strategies_high",
                32,
                32,
                "bit s - 32 set when strategy s is selected, 32 <= s < 64",
            ),
        ],
        Service::FilterStatus => vec![
            signal(
                "profile",
                0,
                8,
                "the filter profile last switched to (0..15), or 255 once a FilterSet changed a \
                 filter since",
            ),
            signal("reserved", 8, 8, "0"),
            signal(
                "sequence",
                16,
                16,
                "the sequence number of the last filter command applied (0 since boot)",
            ),
            signal("filtered", 32, 8, "connections with a message filter"),
            signal("closed", 40, 8, "of them closed (phi = 0)"),
            signal("throttled", 48, 8, "of them passing one frame in phi >= 2"),
            signal("reserved2", 56, 8, "0"),
        ],
        Service::Exploitation => vec![
            signal("port", 0, 8, "the port, in the node's order"),
            signal("connection", 8, 8, "the connection, in the port's order"),
            with_values(
                signal("delivering", 16, 8, "the edge"),
                vec![(0, "stopped delivering"), (1, "started delivering")],
            ),
            signal("reserved", 24, 8, "0"),
        ],
        Service::FilterProfile => vec![
            signal(
                "profile",
                0,
                8,
                "the profile of the node's table to switch every filter to (0: all closed)",
            ),
            signal("reserved", 8, 8, "0"),
            signal("sequence", 16, 16, "echoed in the node's FilterStatus"),
        ],
        Service::FilterSet => vec![
            signal("port", 0, 8, "the port, in the node's order"),
            signal("connection", 8, 8, "the connection, in the port's order"),
            signal(
                "phi",
                16,
                8,
                "0 closes, 1 passes every frame, N passes one frame in N",
            ),
            signal("reserved", 24, 8, "0"),
            signal("sequence", 32, 16, "echoed in the node's FilterStatus"),
        ],
        Service::EmergencyStop | Service::SchemaAbort => Vec::new(),
        Service::SchemaTransfer => return None,
        Service::SchemaAck => vec![
            with_values(
                signal(
                    "outcome",
                    0,
                    8,
                    "0 accepted, else why the schema was refused (SchemaOutcome)",
                ),
                schema_outcomes(),
            ),
            with_values(
                signal(
                    "channel",
                    8,
                    8,
                    "channel of the message: 0 queue, 1 high-priority, 255 unreadable",
                ),
                {
                    let mut values = wire_values!(SchemaChannel);
                    values.push((u32::from(SchemaAck::NO_CHANNEL), "unreadable"));
                    values
                },
            ),
            signal(
                "id",
                16,
                16,
                "the schema's id (65535 when it could not be decoded)",
            ),
            signal("queued", 32, 8, "schemas in the queue after it"),
            signal(
                "stop",
                40,
                8,
                "the server's stop number (stops modulo 64) when it answered",
            ),
            signal("reserved", 48, 16, "0"),
        ],
        Service::SchemaTransition => vec![
            signal("ended", 0, 16, "the schema that ended"),
            signal(
                "installed",
                16,
                16,
                "the schema installed (0xFF00 the wait for the queue, 0xFF01 the wait for the \
                 high-priority channel, 0xFF10 + cause the recovery after a safety event)",
            ),
            with_values(
                signal("trigger", 32, 8, "what ended the schema"),
                wire_values!(SchemaTrigger),
            ),
            signal(
                "detail",
                40,
                8,
                "trigger 2 (safety): the cause, 0 emergency stop, 1 sensor stale, 2 workspace \
                 limit, 3 force limit, 4 watchdog, 5 loop overrun; trigger 3 (reaction): the \
                 reaction's index in the ended schema's table; otherwise 0",
            ),
            with_values(
                signal("source", 48, 8, "where the installed schema came from"),
                wire_values!(SchemaOrigin),
            ),
            signal("queued", 56, 8, "schemas in the queue after it"),
        ],
        Service::SchemaState => vec![
            signal("current", 0, 16, "the installed schema"),
            with_values(
                signal("source", 16, 8, "where the installed schema came from"),
                wire_values!(SchemaOrigin),
            ),
            with_values(
                signal(
                    "fault",
                    24,
                    8,
                    "the safety event the server is stopped on, 255 when none",
                ),
                schema_safeties(),
            ),
            signal("queued", 32, 8, "schemas in the queue"),
            signal("armed", 40, 1, "1: a pose has been received"),
            signal("gripper_closed", 41, 1, "1: the gripper is closed"),
            signal(
                "stop",
                42,
                6,
                "the stop number: the server's stops (emergency stops, aborts, safety events) \
                 modulo 64, which a high-priority schema names to leave the latest one",
            ),
            with_unit(
                signal(
                    "elapsed",
                    48,
                    16,
                    "ms since the schema was installed, saturating",
                ),
                "ms",
            ),
        ],
        Service::TransferStatus => vec![
            with_values(
                signal("status", 0, 8, "the outcome of the transfer"),
                transfer_status_codes(),
            ),
            signal(
                "detail",
                8,
                8,
                "for InvalidTable, which check of the loader failed; otherwise 0",
            ),
            signal(
                "running_version",
                16,
                32,
                "version of the table running after this transfer",
            ),
        ],
    })
}

/// Whether node `index` has message filters: a connection of one of its ports that an HBBA
/// strategy filters.
fn has_filters(network: &Network, index: usize) -> bool {
    network.hbba.as_ref().is_some_and(|hbba| {
        hbba.strategies
            .iter()
            .flat_map(|s| &s.filters)
            .filter_map(|f| network.connections.get(f.connection))
            .filter_map(|c| network.ports.get(c.port))
            .any(|port| port.node == index)
    })
}

fn service_comment(service: Service) -> &'static str {
    match service {
        Service::Fault => {
            "Fault (service 0x01, priority 0): sent when it happens, at most once per code per \
             100 ms; occurrences in between are counted."
        }
        Service::Heartbeat => {
            "Heartbeat (service 0x02, priority 4): every heartbeat period (1 s by default), \
             followed by TableStatus, Traffic and Errors."
        }
        Service::TableStatus => {
            "TableStatus (service 0x03, priority 4): the running table, after every heartbeat."
        }
        Service::Traffic => {
            "Traffic (service 0x04, priority 5): counters since boot, after every heartbeat."
        }
        Service::Errors => {
            "Errors (service 0x05, priority 5): loss and error counters since boot, after every \
             heartbeat."
        }
        Service::Diagnostic => {
            "Diagnostic (service 0x06, priority 7): one connection's stimulation; while the \
             stream is on, one round (a sample per connection of the selected ports, one \
             sequence number, the last flagged end_of_round) at the requested rate."
        }
        Service::Gates => {
            "Gates (service 0x07, priority 3): the gates of a competitive-dynamics group, from the \
             node that runs it, whenever they change and every 100 ms otherwise; a group not \
             heard for 300 ms reads as all gates closed."
        }
        Service::DiagnosticControl => {
            "DiagnosticControl (service 0x10, priority 3): switches the diagnostic stream; the \
             node refuses rates above 200. To a node with a key, the frame is 8 bytes: these 4 \
             and a 4-byte tag over the node's challenge."
        }
        Service::ChallengeRequest => {
            "ChallengeRequest (service 0x13, priority 3, no payload): asks a node with a key for \
             a challenge."
        }
        Service::Challenge => {
            "Challenge (service 0x14, priority 2): the nonce the next configuration message must \
             be tagged over; valid 1 s, re-sent unchanged while outstanding."
        }
        Service::TransferOpen => {
            "TransferOpen (service 0x15, priority 3): opens an authenticated table transfer of \
             this length."
        }
        Service::Receipt => {
            "Receipt (service 0x16, priority 2): authenticates the TransferStatus that ended an \
             opened transfer."
        }
        Service::Desire => {
            "Desire (service 0x08, priority 4): a motivation's desire for the intention \
             workspace; it lapses unless sent again within its lease; intensity 0 withdraws it."
        }
        Service::Intention => {
            "Intention (service 0x09, priority 4): the strategies the intention node selected, \
             after every solve that changed them and once a second."
        }
        Service::FilterStatus => {
            "FilterStatus (service 0x0A, priority 4): a node's message filters, after every \
             filter command it applied and after every heartbeat group."
        }
        Service::Exploitation => {
            "Exploitation (service 0x0B, priority 5): a connection of the node started or \
             stopped delivering (edges only)."
        }
        Service::FilterProfile => {
            "FilterProfile (service 0x17, priority 3): switches every message filter of a node \
             to one of its table's profiles; answered by FilterStatus or a FilterRefused fault."
        }
        Service::FilterSet => {
            "FilterSet (service 0x18, priority 3): sets one message filter of a node; answered \
             by FilterStatus or a FilterRefused fault."
        }
        Service::EmergencyStop => {
            "EmergencyStop (service 0x00, priority 0, no payload): the lowest identifier of the \
             protocol; a schema server halts within one loop period (attractor on the measured \
             pose, SchemaSafety fault, waits on the high-priority channel). Accepted from any \
             source."
        }
        Service::SchemaAbort => {
            "SchemaAbort (service 0x19, priority 1, no payload): the client abandons its \
             program; the schema server empties its queue and waits on the high-priority \
             channel. Accepted from any source."
        }
        Service::SchemaAck => {
            "SchemaAck (service 0x1B, priority 2): the answer to one SchemaTransfer message \
             (ISO-TP, service 0x1A), to its sender."
        }
        Service::SchemaTransition => {
            "SchemaTransition (service 0x1C, priority 2): a schema change of the server, on \
             every change (several in one tick: in order)."
        }
        Service::SchemaState => {
            "SchemaState (service 0x1D, priority 5): the schema server's state, every 100 ms."
        }
        Service::TableTransfer | Service::SchemaTransfer => "",
        Service::TransferStatus => {
            "TransferStatus (service 0x12, priority 2): the outcome of a table transfer, to the \
             tool."
        }
    }
}

/// Three signed 21-bit values and a flag (bit 63) in 8 bytes.
fn triple(names: [&str; 3], unit: &str, what: &str, flag: Option<(&str, &str)>) -> Vec<DbcSignal> {
    let mut signals: Vec<DbcSignal> = names
        .iter()
        .enumerate()
        .map(|(i, name)| DbcSignal {
            unit: unit.to_string(),
            min: (-(1i64 << 20)).to_string(),
            max: ((1u64 << 20) - 1).to_string(),
            signed: true,
            ..signal(
                name,
                21 * i as u32,
                21,
                &format!("{what}, {name}; saturated at ±2^20"),
            )
        })
        .collect();
    if let Some((name, comment)) = flag {
        signals.push(signal(name, 63, 1, comment));
    }
    signals
}

/// The Drive_* messages of one schema server's board.
fn drive_messages(
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    board: &SchemaBoard,
    node_name: &str,
    dbc_node: &str,
) {
    let id = |base: pab_core::OutputId, offset: u32| {
        let raw = base.raw().saturating_add(offset);
        if base.is_extended() {
            raw | EXTENDED_FLAG
        } else {
            raw
        }
    };
    let period_ms = (board.config.period_us / 1000).max(1);
    let d = board.drive;
    let out = |name: &str, base, offset, signals, comment: &str, cycle| DbcMessage {
        id: id(base, offset),
        name: name.to_string(),
        dlc: 8,
        transmitter: dbc_node.to_string(),
        receivers: vec![UNKNOWN_NODE.to_string()],
        signals,
        comment: format!("{comment} Sent by node `{node_name}`'s schema server to its drive."),
        cycle_ms: Some(cycle),
    };
    let inward = |name: &str, base, offset, signals, comment: &str| DbcMessage {
        id: id(base, offset),
        name: name.to_string(),
        dlc: 8,
        transmitter: UNKNOWN_NODE.to_string(),
        receivers: vec![dbc_node.to_string()],
        signals,
        comment: format!("{comment} Read by node `{node_name}`'s schema server."),
        cycle_ms: None,
    };
    let attractor = triple(
        ["x", "y", "z"],
        "um",
        "the attractor",
        Some(("gripper_closed", "1: the gripper is commanded closed")),
    );
    let rotation = triple(["rx", "ry", "rz"], "urad", "the attractor's rotation", None);
    let impedance = vec![
        DbcSignal {
            unit: "N/m".to_string(),
            ..signal("stiffness", 0, 32, "the drive's stiffness")
        },
        DbcSignal {
            unit: "N.s/m".to_string(),
            ..signal("damping", 32, 32, "the drive's damping")
        },
    ];
    let made = [
        out(
            &names.unique(format!("Drive_Attractor_{dbc_node}")),
            d.setpoint,
            0,
            attractor,
            "The impedance controller's attractor, every loop period.",
            period_ms,
        ),
        out(
            &names.unique(format!("Drive_AttractorRotation_{dbc_node}")),
            d.setpoint,
            1,
            rotation,
            "The attractor's rotation, every loop period.",
            period_ms,
        ),
        out(
            &names.unique(format!("Drive_Impedance_{dbc_node}")),
            d.setpoint,
            2,
            impedance,
            "The drive's impedance, on change and every 100 ms.",
            100,
        ),
        inward(
            &names.unique(format!("Drive_Pose_{dbc_node}")),
            d.pose,
            0,
            triple(["x", "y", "z"], "um", "the measured position", None),
            "The drive's measured position.",
        ),
        inward(
            &names.unique(format!("Drive_PoseRotation_{dbc_node}")),
            d.pose,
            1,
            triple(["rx", "ry", "rz"], "urad", "the measured rotation", None),
            "The drive's measured rotation.",
        ),
        inward(
            &names.unique(format!("Drive_Wrench_{dbc_node}")),
            d.wrench,
            0,
            triple(
                ["fx", "fy", "fz"],
                "mN",
                "the contact force on the robot",
                None,
            ),
            "The wrist sensor's force (pressing down on a surface reads +z).",
        ),
        inward(
            &names.unique(format!("Drive_Torque_{dbc_node}")),
            d.wrench,
            1,
            triple(["tx", "ty", "tz"], "mN.m", "the torque", None),
            "The wrist sensor's torque.",
        ),
    ];
    messages.extend(made);
}

/// The signal of one extra sensor: its field where the board's `value_port::Field` reads it
/// (byte offset, size, sign, byte order), scaled to the sensor's unit. DBC's physical value is
/// raw × factor and the sensor's scale is units per count, so the factor is the scale; the board
/// itself compares the raw counts.
fn sensor_signal(topic: &SensorTopic, index: usize, range_finder: bool) -> DbcSignal {
    let field: Field = topic.sensor.field;
    let len = 8 * u32::from(field.size);
    let (low, high) = field.range();
    let physical = |raw: i64| (raw as f64 * topic.scale).to_string();
    let per_count = if topic.unit.is_empty() {
        format!("{} per count", topic.scale)
    } else {
        format!("{} {} per count", topic.scale, topic.unit)
    };
    let order = match field.endian {
        Endian::Big if field.size > 1 => " big endian",
        Endian::Little if field.size > 1 => " little endian",
        _ => "",
    };
    let mut comment = format!(
        "Sensor `{}` (index {index}): {}{len}{order} at byte {}, {per_count} (the factor). The \
         board compares the raw counts",
        topic.name,
        if field.signed { "i" } else { "u" },
        field.offset,
    );
    if !field.signed && field.size == 4 {
        // Sensor::read: the server's sensor table holds i32.
        comment.push_str(" (a raw value above 2^31 - 1 reads as 2^31 - 1)");
    }
    comment.push('.');
    if range_finder {
        comment.push_str(
            " The plant's range finder ([plant] range_finder): pabctl sim and pabctl plant publish \
             the height under the tip on it, every loop period.",
        );
    }
    DbcSignal {
        factor: topic.scale.to_string(),
        min: physical(low),
        max: physical(high),
        unit: topic.unit.clone(),
        ..field_signal(&topic.name, field, &comment)
    }
}

/// The signal of a field as a board's `value_port::Field` reads it (byte offset, size, sign,
/// byte order), in raw counts.
fn field_signal(name: &str, field: Field, comment: &str) -> DbcSignal {
    let len = 8 * u32::from(field.size);
    let first_bit = 8 * u32::from(field.offset);
    // A single byte has no byte order: written little endian, which every tool reads alike.
    // Big endian (Motorola) names the field by its most significant bit: bit 7 of its first byte.
    let (endian, start) = match field.endian {
        Endian::Big if field.size > 1 => (Endian::Big, first_bit + 7),
        _ => (Endian::Little, first_bit),
    };
    let (low, high) = field.range();
    DbcSignal {
        endian,
        min: low.to_string(),
        max: high.to_string(),
        signed: field.signed,
        ..signal(name, start, len, comment)
    }
}

/// The signals of a topic's message: each field the network reads from its frames
/// ([`Network::topic_fields`]: value ports, BLE eligibilities, dynamics contexts), then one byte
/// signal `dataN` for each byte of its `length` that no field covers. A field that overlaps one
/// listed before it is named in the comment instead (cantools refuses overlapping signals).
fn topic_signals(network: &Network, topic: usize, length: u8) -> (Vec<DbcSignal>, String) {
    let mut covered = [false; 8];
    let mut signals = Vec::new();
    let mut also = String::new();
    for field in network.topic_fields(topic) {
        let bytes = usize::from(field.offset)..usize::from(field.offset) + usize::from(field.size);
        let inside = covered.get(bytes.clone());
        if inside.is_none_or(|bytes| bytes.iter().any(|&b| b)) {
            let _ = write!(
                also,
                " {} reads bytes {}..{} too (`{}`).",
                field.reader, bytes.start, bytes.end, field.name
            );
            continue;
        }
        covered[bytes].iter_mut().for_each(|b| *b = true);
        let core = Field {
            offset: field.offset,
            size: field.size,
            signed: field.signed,
            endian: if field.big_endian {
                Endian::Big
            } else {
                Endian::Little
            },
        };
        let comment = format!(
            "{}{} at byte {}{}, read by {}.",
            if field.signed { "i" } else { "u" },
            8 * u32::from(field.size),
            field.offset,
            match (field.size > 1, field.big_endian) {
                (false, _) => "",
                (true, true) => ", big endian",
                (true, false) => ", little endian",
            },
            field.reader
        );
        // `dataN` names the raw bytes below: a field of that name (port `a.data1`) is prefixed.
        let mut name = identifier(&field.name, "field_");
        if name
            .strip_prefix("data")
            .is_some_and(|n| n.parse::<u8>().is_ok())
        {
            name.insert_str(0, "field_");
        }
        signals.push(field_signal(&name, core, &comment));
    }
    for byte in 0..length.min(8) {
        if !covered[usize::from(byte)] {
            let name = format!("data{byte}");
            signals.push(signal(
                &name,
                8 * u32::from(byte),
                8,
                &format!("payload byte {byte}"),
            ));
        }
    }
    (signals, also)
}

/// The Sensor_* messages of one schema server's board: one per identifier its extra sensors
/// (`[schema.NODE.sensors.NAME]`) read, with one signal per sensor on it (several may share an
/// identifier, each its own field: DBC allows one message per identifier). Their frames are the
/// user's (a device's, or the plant's range finder): the board only reads them. `range_finder`
/// is the index of the sensor `[plant] range_finder` names, if it is this board's.
fn sensor_messages(
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    board: &SchemaBoard,
    range_finder: Option<usize>,
    node_name: &str,
    dbc_node: &str,
) {
    let mut topics: Vec<(pab_core::OutputId, Vec<usize>)> = Vec::new();
    for (i, topic) in board.sensors.iter().enumerate() {
        match topics.iter_mut().find(|(id, _)| *id == topic.sensor.id) {
            Some((_, sensors)) => sensors.push(i),
            None => topics.push((topic.sensor.id, vec![i])),
        }
    }
    for (id, sensors) in topics {
        let on_it: Vec<&SensorTopic> = sensors.iter().map(|&i| &board.sensors[i]).collect();
        let joined: Vec<&str> = on_it.iter().map(|t| t.name.as_str()).collect();
        let sections: Vec<String> = joined
            .iter()
            .map(|name| format!("[schema.{node_name}.sensors.{name}]"))
            .collect();
        // The shortest frame the board reads all of them from: longer ones decode the same.
        let dlc = on_it
            .iter()
            .map(|t| t.sensor.field.offset + t.sensor.field.size)
            .max()
            .unwrap_or(8);
        messages.push(DbcMessage {
            id: if id.is_extended() {
                id.raw() | EXTENDED_FLAG
            } else {
                id.raw()
            },
            name: names.unique(format!("Sensor_{}_{dbc_node}", joined.join("_"))),
            dlc,
            transmitter: UNKNOWN_NODE.to_string(),
            receivers: vec![dbc_node.to_string()],
            signals: sensors
                .iter()
                .map(|&i| sensor_signal(&board.sensors[i], i, range_finder == Some(i)))
                .collect(),
            comment: format!(
                "A sensor topic of node `{node_name}`'s schema server ({}): the user's frames on \
                 {} id 0x{:X}, from an unnamed sender, read by the board (value_port::Field) \
                 into its sensor table for the reactions that name it. DLC is the shortest frame \
                 it reads.",
                sections.join(", "),
                if id.is_extended() {
                    "extended"
                } else {
                    "standard"
                },
                id.raw()
            ),
            cycle_ms: None,
        });
    }
}

/// The two messages of one node's ISO-TP transfer on `service` (table or schema): the tool's
/// data frames to the node and the node's flow control back. Both 8 bytes (our ISO-TP pads
/// every frame): the PCI type and low nibble as signals, bytes 1..7 raw.
fn transfer_messages(
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    service: Service,
    node: &crate::network::Node,
    dbc_node: &str,
) {
    let what = if service == Service::TableTransfer {
        "a table image"
    } else {
        "a schema (a channel byte, then the schema)"
    };
    let signals = |direction: &str| {
        let mut signals = vec![
            DbcSignal {
                values: vec![
                    (0, "single frame"),
                    (1, "first frame"),
                    (2, "consecutive frame"),
                    (3, "flow control"),
                ],
                ..signal(
                    "pci_type",
                    4,
                    4,
                    &format!(
                        "ISO-TP protocol control information, high nibble of byte 0 ({direction})"
                    ),
                )
            },
            signal(
                "pci_low",
                0,
                4,
                "low nibble of byte 0: a single frame's length, the high bits of a first frame's \
                 length (byte 1 the low bits; 0 with a 32-bit length in bytes 2-5), a consecutive \
                 frame's sequence number, or a flow control's status (0 continue, 1 wait, 2 \
                 overflow)",
            ),
        ];
        signals.extend((1..8u32).map(|i| {
            signal(
                &format!("data{i}"),
                8 * i,
                8,
                &format!("byte {i}: the message's bytes, or a first frame's length, or a flow control's block size (1) and STmin (2); 0xCC pads"),
            )
        }));
        signals
    };
    let code = service as u8;
    messages.push(DbcMessage {
        id: extended(FrameId::new(service, TOOL, node.id)),
        name: names.unique(format!("PAB_{service:?}_{dbc_node}")),
        dlc: 8,
        transmitter: TOOL_NODE.to_string(),
        receivers: vec![dbc_node.to_string()],
        signals: signals("tool to node"),
        comment: format!(
            "{service:?} (service 0x{code:02X}): ISO-TP (ISO 15765-2) frames carrying {what} from \
             the tool to node `{}` (id {}), padded to 8 bytes with 0xCC. See \
             docs/can-protocol.md.",
            node.name, node.id
        ),
        cycle_ms: None,
    });
    messages.push(DbcMessage {
        id: extended(FrameId::new(service, node.id, TOOL)),
        name: names.unique(format!("PAB_{service:?}Flow_{dbc_node}")),
        dlc: 8,
        transmitter: dbc_node.to_string(),
        receivers: vec![TOOL_NODE.to_string()],
        signals: signals("node to tool"),
        comment: format!(
            "{service:?} (service 0x{code:02X}): node `{}`'s ISO-TP flow control frames to the \
             tool during a transfer to it, padded to 8 bytes.",
            node.name
        ),
        cycle_ms: None,
    });
}

/// The BLE claims of a capture, for [`build`]: every frame with a claim's identifier must
/// decode as one (`Claim::decode`, the nodes' own check) from a node that is in a BLE group of
/// `network`; each that does not is reported at its line. Claims are listed once per (node,
/// eligibility).
pub fn claims_in(
    network: &Network,
    capture: &crate::candump::Capture,
    path: &std::path::Path,
) -> Result<Vec<Claim>, Diagnostics> {
    let mut claims: Vec<Claim> = Vec::new();
    let mut errors = Vec::new();
    let members: Vec<u8> = network
        .nodes
        .iter()
        .enumerate()
        .filter(|(index, _)| network.groups.iter().any(|g| g.member(*index).is_some()))
        .map(|(_, node)| node.id)
        .collect();
    for captured in &capture.frames {
        if pab_core::protocol::classify(&captured.frame) != pab_core::protocol::FrameKind::Claim {
            continue;
        }
        let at =
            |message: String| crate::diagnostic::Diagnostic::at(path, captured.line, 1, message);
        match Claim::decode(&captured.frame) {
            Ok(claim) if !members.contains(&claim.node) => errors.push(at(format!(
                "a BLE claim from node id {}, which is in no BLE group of {}",
                claim.node,
                network.source.path().display()
            ))),
            Ok(claim) => {
                if !claims
                    .iter()
                    .any(|c| c.node == claim.node && c.eligibility == claim.eligibility)
                {
                    claims.push(claim);
                }
            }
            Err(error) => errors.push(at(format!(
                "a frame with a BLE claim's identifier that is not a claim: {error}"
            ))),
        }
    }
    if errors.is_empty() {
        return Ok(claims);
    }
    // A capture of another network has thousands: the first twenty say what is wrong.
    const SHOWN: usize = 20;
    if errors.len() > SHOWN {
        let more = errors.len() - SHOWN;
        errors.truncate(SHOWN);
        errors.push(crate::diagnostic::Diagnostic::file(
            path,
            format!("{more} more frames like these"),
        ));
    }
    Err(Diagnostics(errors))
}

/// The DBC database of `network`. Fails, with a diagnostic at the topic, if a topic lies in the
/// protocol's identifier space (extended, bits 25..24 = 0b10): nodes never arbitrate such frames.
///
/// `claims` are BLE claims to list beyond each group member's claim at eligibility 0 (those of a
/// capture, [`claims_in`]): a claim's identifier carries its eligibility, and a DBC names whole
/// identifiers, so a tool that matches identifiers exactly (cantools) decodes only the claims
/// listed. A claim of a node that is in no group is not listed.
pub fn build(network: &Network, claims: &[Claim]) -> Result<Dbc, Diagnostics> {
    let mut errors = Vec::new();
    let mut node_names = Names(HashSet::from([TOOL_NODE.to_string()]));
    let mut nodes = vec![TOOL_NODE.to_string()];
    let mut node_comments =
        vec!["The workstation tool (pabctl), address 0 in the pab protocol.".to_string()];
    let serves = |index: usize| network.schema_boards.iter().any(|b| b.node == index);
    for (index, node) in network.nodes.iter().enumerate() {
        nodes.push(node_names.unique(identifier(&node.name, "node_")));
        let transfer = FrameId::new(Service::TableTransfer, TOOL, node.id).raw();
        let flow = FrameId::new(Service::TableTransfer, node.id, TOOL).raw();
        let mut comment = format!(
            "Node `{}`, id {} ({} port{}). Table images reach it by ISO-TP (ISO 15765-2) on \
             service 0x11, not described here: data 0x{transfer:08X} (tool to node), flow control \
             0x{flow:08X} (node to tool).",
            node.name,
            node.id,
            node.ports.len(),
            if node.ports.len() == 1 { "" } else { "s" },
        );
        if let Some(description) = &node.description {
            comment.insert_str(0, &format!("{description}. "));
        }
        if serves(index) {
            let transfer = FrameId::new(Service::SchemaTransfer, TOOL, node.id).raw();
            let flow = FrameId::new(Service::SchemaTransfer, node.id, TOOL).raw();
            let _ = write!(
                comment,
                " It runs a schema server: schemas reach it by ISO-TP on service 0x1A (a channel \
                 byte, then the schema), not described here: data 0x{transfer:08X} (tool to \
                 node), flow control 0x{flow:08X} (node to tool). Its drive's frames are the \
                 Drive_* messages."
            );
        }
        node_comments.push(comment);
    }

    let mut names = Names(HashSet::new());
    let mut messages = Vec::new();
    let periodic = [
        Service::Heartbeat,
        Service::TableStatus,
        Service::Traffic,
        Service::Errors,
    ];
    for (index, (node, dbc_node)) in network.nodes.iter().zip(nodes.iter().skip(1)).enumerate() {
        // Gates come from the nodes that run a dynamics group only; filter status and
        // exploitation from the nodes with message filters.
        let runs_dynamics = network.dynamics.iter().any(|g| g.node == index);
        let filtered = has_filters(network, index);
        let schema_server = serves(index);
        for service in Service::ALL {
            let destination = match service {
                Service::DiagnosticControl
                | Service::TableTransfer
                | Service::ChallengeRequest
                | Service::TransferOpen
                | Service::Desire
                | Service::Intention
                | Service::FilterProfile
                | Service::FilterSet
                | Service::EmergencyStop
                | Service::SchemaAbort
                | Service::SchemaTransfer => continue,
                Service::Gates if !runs_dynamics => continue,
                Service::FilterStatus | Service::Exploitation if !filtered => continue,
                Service::SchemaAck | Service::SchemaTransition | Service::SchemaState
                    if !schema_server =>
                {
                    continue;
                }
                // The answer goes to the schema's sender: described from the tool.
                Service::TransferStatus
                | Service::Challenge
                | Service::Receipt
                | Service::SchemaAck => TOOL,
                _ => BROADCAST,
            };
            let Some(signals) = service_signals(service) else {
                continue;
            };
            let frame = FrameId::new(service, node.id, destination);
            messages.push(DbcMessage {
                id: extended(frame),
                name: names.unique(format!("PAB_{service:?}_{dbc_node}")),
                dlc: service.payload_len() as u8,
                transmitter: dbc_node.clone(),
                receivers: vec![TOOL_NODE.to_string()],
                signals,
                comment: format!(
                    "{} From node `{}` (id {}) to {}.",
                    service_comment(service),
                    node.name,
                    node.id,
                    if destination == TOOL {
                        "the tool (0)"
                    } else {
                        "all (0xFF)"
                    }
                ),
                cycle_ms: if matches!(service, Service::Gates | Service::SchemaState) {
                    Some(100)
                } else {
                    (periodic.contains(&service) || service == Service::FilterStatus)
                        .then_some(1000)
                },
            });
        }
    }
    // The schema servers' drives: the set-point the board sends every period, the pose and the
    // wrench it reads (docs/can-protocol.md, "The drive's frames"), on the ids of the board's
    // `drive`; then its extra sensors' topics. A network topic on a sensor's identifier joins
    // the sensor's message (below): its signals say more than raw bytes.
    let mut sensor_ids: Vec<(u32, usize)> = Vec::new();
    for (index, board) in network.schema_boards.iter().enumerate() {
        let Some(dbc_node) = nodes.get(board.node + 1) else {
            continue;
        };
        let Some(node) = network.nodes.get(board.node) else {
            continue;
        };
        drive_messages(&mut messages, &mut names, board, &node.name, dbc_node);
        // `[plant] range_finder` is a sensor of the first board (the network file's reading).
        let range_finder = network
            .plant
            .as_ref()
            .and_then(|p| p.range_finder)
            .filter(|_| index == 0);
        let first = messages.len();
        sensor_messages(
            &mut messages,
            &mut names,
            board,
            range_finder,
            &node.name,
            dbc_node,
        );
        sensor_ids.extend(
            messages[first..]
                .iter()
                .enumerate()
                .map(|(i, m)| (m.id, first + i)),
        );
    }
    // BLE claims: messages per node of a group. A DBC names whole identifiers, and a claim's
    // identifier carries its eligibility (higher eligibility, lower identifier), so each node gets
    // its claim at eligibility 0 ("not a candidate") and one per eligibility of `claims`; the
    // payload reads the same at every eligibility.
    for (index, (node, dbc_node)) in network.nodes.iter().zip(nodes.iter().skip(1)).enumerate() {
        let groups: Vec<&crate::network::BleGroup> = network
            .groups
            .iter()
            .filter(|g| g.member(index).is_some())
            .collect();
        let Some(period) = groups.iter().map(|g| g.period_us).min() else {
            continue;
        };
        let mut eligibilities: Vec<u16> = claims
            .iter()
            .filter(|c| c.node == node.id)
            .map(|c| c.eligibility)
            .chain([0])
            .collect();
        eligibilities.sort_unstable();
        eligibilities.dedup();
        let peers: Vec<String> = network
            .nodes
            .iter()
            .zip(nodes.iter().skip(1))
            .enumerate()
            .filter(|(other, _)| {
                *other != index && groups.iter().any(|g| g.member(*other).is_some())
            })
            .map(|(_, (_, name))| name.clone())
            .collect();
        let names_of: Vec<String> = groups
            .iter()
            .map(|g| format!("{} = {}", g.number, g.name))
            .collect();
        for eligibility in eligibilities {
            let Some(frame) = (Claim {
                group: 0,
                node: node.id,
                eligibility,
            })
            .frame() else {
                continue;
            };
            messages.push(DbcMessage {
            id: frame.raw_id().0 | EXTENDED_FLAG,
            name: names.unique(if eligibility == 0 {
                format!("PAB_Claim_{dbc_node}")
            } else {
                format!("PAB_Claim_{dbc_node}_e{eligibility}")
            }),
            dlc: 4,
            transmitter: dbc_node.clone(),
            receivers: if peers.is_empty() {
                vec![UNKNOWN_NODE.to_string()]
            } else {
                peers.clone()
            },
            signals: vec![
                signal(
                    "Group",
                    0,
                    8,
                    &format!("the BLE group, numbered in file order ({})", names_of.join(", ")),
                ),
                signal(
                    "Eligibility",
                    8,
                    16,
                    "the node's eligibility for the group's task (0: not a candidate); the identifier carries 0xFFFF minus it in bits 22..7",
                ),
                signal("Reserved", 24, 8, "0"),
            ],
            comment: format!(
                "BLE claim of node `{}` (id {}), once per period per group. The identifier ranks the claim (bits 22..7: 0xFFFF - eligibility; bits 6..0: the node id), so it changes with the eligibility: this message is the claim at eligibility {eligibility}; every claim of the node has this payload layout (pabctl dbc --claims-from CAPTURE lists the eligibilities of a capture). See docs/can-protocol.md, Broadcast of Local Eligibility.",
                node.name, node.id
            ),
            cycle_ms: Some(period.div_ceil(1000)),
        });
        }
    }

    // Table and schema transfers: ISO-TP frames (docs/can-protocol.md), always padded to 8
    // bytes, so a capture of a transfer decodes byte by byte; the PCI's type and low nibble are
    // signals, the reassembled message is not (a DBC describes single frames).
    for (index, (node, dbc_node)) in network.nodes.iter().zip(nodes.iter().skip(1)).enumerate() {
        transfer_messages(
            &mut messages,
            &mut names,
            Service::TableTransfer,
            node,
            dbc_node,
        );
        if serves(index) {
            transfer_messages(
                &mut messages,
                &mut names,
                Service::SchemaTransfer,
                node,
                dbc_node,
            );
        }
    }
    // Ports that re-publish what they deliver: the delivered frame's payload on the port's id.
    for port in &network.ports {
        let pab_core::Consumer::Republish(output) = port.consumer else {
            continue;
        };
        let Some(dbc_node) = nodes.get(port.node + 1) else {
            continue;
        };
        let topics: Vec<usize> = port
            .connections
            .iter()
            .filter_map(|&c| network.connections.get(c))
            .map(|c| c.topic)
            .filter(|&t| t < network.topics.len())
            .collect();
        let length = topics
            .iter()
            .filter_map(|&t| network.topics.get(t))
            .map(|t| t.length)
            .max()
            .unwrap_or(8);
        let mut signals = Vec::new();
        if let Some(spec) = &port.value {
            let name = port.name.rsplit('.').next().unwrap_or(&port.name);
            signals.push(field_signal(
                &identifier(name, "field_"),
                spec.value,
                &format!(
                    "the port's value (combine = \"{}\"), as in the delivered frame",
                    crate::network::combine_name(spec.combine)
                ),
            ));
        }
        let covered = |byte: u8| {
            port.value.as_ref().is_some_and(|spec| {
                (spec.value.offset..spec.value.offset.saturating_add(spec.value.size))
                    .contains(&byte)
            })
        };
        for byte in (0..length.min(8)).filter(|&b| !covered(b)) {
            signals.push(signal(
                &format!("data{byte}"),
                8 * u32::from(byte),
                8,
                &format!("payload byte {byte} of the delivered frame"),
            ));
        }
        let id = if output.is_extended() {
            output.raw() | EXTENDED_FLAG
        } else {
            output.raw()
        };
        let lengths: Vec<u8> = topics
            .iter()
            .filter_map(|&t| network.topics.get(t))
            .map(|t| t.length)
            .collect();
        let uneven = if lengths.iter().any(|&l| l != length) {
            " Its topics' lengths differ: frames shorter than the DLC come from the shorter ones."
        } else {
            ""
        };
        messages.push(DbcMessage {
            id,
            name: names.unique(format!("{}_out", identifier(&port.name, "port_"))),
            dlc: length,
            transmitter: dbc_node.clone(),
            receivers: vec![UNKNOWN_NODE.to_string()],
            signals,
            comment: format!(
                "Port `{}` re-publishes every frame it delivers (`republish`): the delivered \
                 frame's payload, from node `{}`.{uneven}",
                port.name,
                network
                    .nodes
                    .get(port.node)
                    .map_or("?", |n| n.name.as_str())
            ),
            cycle_ms: None,
        });
    }

    let control = Service::DiagnosticControl;
    let targets = network
        .nodes
        .iter()
        .zip(nodes.iter().skip(1))
        .map(|(node, dbc_node)| (node.id, dbc_node.clone(), format!("node `{}`", node.name)))
        .chain([(BROADCAST, "all".to_string(), "all nodes (0xFF)".to_string())]);
    for (destination, suffix, whom) in targets {
        let receivers = if destination == BROADCAST {
            nodes.iter().skip(1).cloned().collect::<Vec<_>>()
        } else {
            vec![suffix.clone()]
        };
        messages.push(DbcMessage {
            id: extended(FrameId::new(control, TOOL, destination)),
            name: names.unique(format!("PAB_{control:?}_{suffix}")),
            dlc: control.payload_len() as u8,
            transmitter: TOOL_NODE.to_string(),
            receivers: if receivers.is_empty() {
                vec![UNKNOWN_NODE.to_string()]
            } else {
                receivers
            },
            signals: service_signals(control).unwrap_or_default(),
            comment: format!("{} From the tool to {whom}.", service_comment(control)),
            cycle_ms: None,
        });
    }

    // The schema servers' stops: the emergency stop and the abort, from the tool (anyone may
    // send them) to each board and to all.
    let boards: Vec<(u8, String, String)> = network
        .nodes
        .iter()
        .zip(nodes.iter().skip(1))
        .enumerate()
        .filter(|(index, _)| serves(*index))
        .map(|(_, (node, dbc_node))| (node.id, dbc_node.clone(), format!("node `{}`", node.name)))
        .collect();
    if !boards.is_empty() {
        let every: Vec<String> = boards.iter().map(|(_, name, _)| name.clone()).collect();
        let all = (BROADCAST, "all".to_string(), "all nodes (0xFF)".to_string());
        for service in [Service::EmergencyStop, Service::SchemaAbort] {
            for (destination, suffix, whom) in boards.iter().chain([&all]) {
                messages.push(DbcMessage {
                    id: extended(FrameId::new(service, TOOL, *destination)),
                    name: names.unique(format!("PAB_{service:?}_{suffix}")),
                    dlc: service.payload_len() as u8,
                    transmitter: TOOL_NODE.to_string(),
                    receivers: if *destination == BROADCAST {
                        every.clone()
                    } else {
                        vec![suffix.clone()]
                    },
                    signals: service_signals(service).unwrap_or_default(),
                    comment: format!(
                        "{} From the tool to {whom}; any node sends the same from its own \
                         address.",
                        service_comment(service)
                    ),
                    cycle_ms: None,
                });
            }
        }
    }

    // HBBA: desires (described from the tool; any node may send them), the intention node's
    // intention and its filter commands to each node with filters.
    if network.hbba.is_some() {
        nodes.push(INTENTION_NODE.to_string());
        node_comments.push(format!(
            "The intention node (pab-intent), at the address it uses unless told otherwise \
             ({INTENTION}): it solves the desires and sets the nodes' message filters."
        ));
        let desire = Service::Desire;
        messages.push(DbcMessage {
            id: extended(FrameId::new(desire, TOOL, BROADCAST)),
            name: names.unique(format!("PAB_{desire:?}_{TOOL_NODE}")),
            dlc: desire.payload_len() as u8,
            transmitter: TOOL_NODE.to_string(),
            receivers: vec![INTENTION_NODE.to_string()],
            signals: service_signals(desire).unwrap_or_default(),
            comment: format!(
                "{} From the tool to all (0xFF); a motivation on any node sends the same from \
                 its own address.",
                service_comment(desire)
            ),
            cycle_ms: None,
        });
        let intention = Service::Intention;
        messages.push(DbcMessage {
            id: extended(FrameId::new(intention, INTENTION, BROADCAST)),
            name: names.unique(format!("PAB_{intention:?}_{INTENTION_NODE}")),
            dlc: intention.payload_len() as u8,
            transmitter: INTENTION_NODE.to_string(),
            receivers: vec![TOOL_NODE.to_string()],
            signals: service_signals(intention).unwrap_or_default(),
            comment: format!(
                "{} From the intention node to all (0xFF).",
                service_comment(intention)
            ),
            cycle_ms: Some(1000),
        });
        for (index, (node, dbc_node)) in network.nodes.iter().zip(nodes.iter().skip(1)).enumerate()
        {
            if !has_filters(network, index) {
                continue;
            }
            for service in [Service::FilterProfile, Service::FilterSet] {
                messages.push(DbcMessage {
                    id: extended(FrameId::new(service, INTENTION, node.id)),
                    name: names.unique(format!("PAB_{service:?}_{dbc_node}")),
                    dlc: service.payload_len() as u8,
                    transmitter: INTENTION_NODE.to_string(),
                    receivers: vec![dbc_node.clone()],
                    signals: service_signals(service).unwrap_or_default(),
                    comment: format!(
                        "{} From the intention node to node `{}`.",
                        service_comment(service),
                        node.name
                    ),
                    cycle_ms: None,
                });
            }
        }
    }

    // The tool's authentication frames go to one node each (a tag is over one node's challenge).
    for (node, dbc_node) in network.nodes.iter().zip(nodes.iter().skip(1)) {
        for service in [Service::ChallengeRequest, Service::TransferOpen] {
            messages.push(DbcMessage {
                id: extended(FrameId::new(service, TOOL, node.id)),
                name: names.unique(format!("PAB_{service:?}_{dbc_node}")),
                dlc: service.payload_len() as u8,
                transmitter: TOOL_NODE.to_string(),
                receivers: vec![dbc_node.clone()],
                signals: service_signals(service).unwrap_or_default(),
                comment: format!(
                    "{} From the tool to node `{}`.",
                    service_comment(service),
                    node.name
                ),
                cycle_ms: None,
            });
        }
    }

    let mut seen_ids = sensor_ids;
    for (index, topic) in network.topics.iter().enumerate() {
        let filter = topic.filter;
        if filter.is_extended() && filter.id() & PROTOCOL_MASK == PROTOCOL_VALUE {
            errors.push(network.error(
                topic.span.clone(),
                format!(
                    "topic `{}`: can_id {:#x} lies in the pab protocol's identifier space \
                     (extended, bits 25..24 = 0b10); nodes never arbitrate such frames",
                    topic.name,
                    filter.id()
                ),
            ));
            continue;
        }
        let id = if filter.is_extended() {
            filter.id() | EXTENDED_FLAG
        } else {
            filter.id()
        };
        let feeds: Vec<String> = network
            .connections
            .iter()
            .filter(|c| network.topics.get(c.topic).map(|t| &t.name) == Some(&topic.name))
            .filter_map(|c| {
                network
                    .ports
                    .get(c.port)
                    .map(|port| format!("{} ({})", c.name, port.name))
            })
            .collect();
        let mut receivers: Vec<String> = Vec::new();
        for connection in network
            .connections
            .iter()
            .filter(|c| network.topics.get(c.topic).map(|t| &t.name) == Some(&topic.name))
        {
            let node = network
                .ports
                .get(connection.port)
                .and_then(|port| nodes.get(port.node + 1));
            if let Some(node) = node.filter(|node| !receivers.contains(node)) {
                receivers.push(node.clone());
            }
        }
        if receivers.is_empty() {
            receivers.push(UNKNOWN_NODE.to_string());
        }
        let widest = if filter.is_extended() {
            0x1FFF_FFFF
        } else {
            0x7FF
        };
        // What the topic is; its own message's comment starts with its name, and a message it
        // joins says "Also topic `NAME`: " before it.
        let mut comment = format!(
            "{} id 0x{:X}",
            if filter.is_extended() {
                "extended"
            } else {
                "standard"
            },
            filter.id()
        );
        if filter.mask() != widest {
            let _ = write!(
                comment,
                " under mask 0x{:X} (every id with (id & mask) == 0x{:X} belongs to it; only \
                 this one is listed)",
                filter.mask(),
                filter.id()
            );
        }
        comment.push('.');
        // What the file says the topic carries, first among what is said about it.
        if let Some(description) = &topic.description {
            comment.insert_str(0, &format!("{description}. "));
        }
        let feeds = if feeds.is_empty() {
            String::new()
        } else {
            format!(" Feeds {}.", feeds.join(", "))
        };
        if let Some(&(_, first)) = seen_ids.iter().find(|(seen, _)| *seen == id) {
            // Two topics with one base id and different masks, or a topic a schema server's
            // sensor reads: DBC allows one message per id, and the first one describes it.
            if let Some(message) = messages.get_mut(first) {
                let _ = write!(
                    message.comment,
                    " Also topic `{}`: {comment}{feeds}",
                    topic.name
                );
                message.receivers.retain(|r| r != UNKNOWN_NODE);
                for receiver in receivers {
                    if !message.receivers.contains(&receiver) {
                        message.receivers.push(receiver);
                    }
                }
                if message.receivers.is_empty() {
                    message.receivers.push(UNKNOWN_NODE.to_string());
                }
            }
            continue;
        }
        comment.insert_str(0, &format!("Topic `{}`: ", topic.name));
        let (signals, also) = topic_signals(network, index, topic.length);
        let _ = write!(
            comment,
            " {} data bytes (its `length`): the fields the network reads from them as signals, \
             the other bytes raw (dataN).{also}",
            topic.length
        );
        comment.push_str(&feeds);
        seen_ids.push((id, messages.len()));
        messages.push(DbcMessage {
            id,
            name: names.unique(identifier(&topic.name, "topic_")),
            dlc: topic.length,
            transmitter: UNKNOWN_NODE.to_string(),
            receivers,
            signals,
            comment,
            cycle_ms: None,
        });
    }
    if !errors.is_empty() {
        return Err(Diagnostics(errors));
    }
    Ok(Dbc {
        nodes,
        node_comments,
        messages,
        comment: format!(
            "{}Generated by pabctl dbc from {}. Messages PAB_* are the pab protocol \
             (docs/can-protocol.md): 29-bit ids, priority in bits 28..26, marker 0b10 in bits \
             25..24 (raw & 0x{PROTOCOL_MASK:08X} == 0x{PROTOCOL_VALUE:08X}), service in 23..16, \
             destination in 15..8, source in 7..0. Table and schema transfers (services 0x11 and \
             0x1A, ISO-TP) are not listed: see the node comments for their ids. Messages \
             Drive_* and Sensor_* are a schema server's drive and sensor topics. The other \
             messages are the network's topics.",
            network
                .description
                .as_ref()
                .map_or(String::new(), |d| format!("{d}. ")),
            network.source.path().display()
        ),
    })
}

/// Strips what a DBC string cannot hold.
fn text(s: &str) -> String {
    s.replace('"', "'").replace(['\n', '\r'], " ")
}

impl Dbc {
    /// The DBC text.
    pub fn render(&self) -> String {
        let mut out = String::new();
        // Writing to a String cannot fail.
        let _ = self.write(&mut out);
        out
    }

    fn write(&self, out: &mut String) -> std::fmt::Result {
        writeln!(out, "VERSION \"\"")?;
        writeln!(out)?;
        writeln!(out)?;
        writeln!(out, "NS_ :")?;
        for keyword in [
            "NS_DESC_",
            "CM_",
            "BA_DEF_",
            "BA_",
            "VAL_",
            "BA_DEF_DEF_",
            "VAL_TABLE_",
            "SIG_VALTYPE_",
            "BO_TX_BU_",
        ] {
            writeln!(out, "\t{keyword}")?;
        }
        writeln!(out)?;
        writeln!(out, "BS_:")?;
        writeln!(out)?;
        writeln!(out, "BU_: {}", self.nodes.join(" "))?;
        writeln!(out)?;
        for message in &self.messages {
            writeln!(out)?;
            writeln!(
                out,
                "BO_ {} {}: {} {}",
                message.id, message.name, message.dlc, message.transmitter
            )?;
            for signal in &message.signals {
                let sign = if signal.signed { '-' } else { '+' };
                let order = match signal.endian {
                    Endian::Little => 1,
                    Endian::Big => 0,
                };
                writeln!(
                    out,
                    " SG_ {} : {}|{}@{order}{sign} ({},0) [{}|{}] \"{}\" {}",
                    signal.name,
                    signal.start,
                    signal.len,
                    signal.factor,
                    signal.min,
                    signal.max,
                    text(&signal.unit),
                    message.receivers.join(",")
                )?;
            }
        }
        writeln!(out)?;
        writeln!(out)?;
        writeln!(out, "CM_ \"{}\";", text(&self.comment))?;
        for (node, comment) in self.nodes.iter().zip(&self.node_comments) {
            writeln!(out, "CM_ BU_ {node} \"{}\";", text(comment))?;
        }
        for message in &self.messages {
            writeln!(
                out,
                "CM_ BO_ {} \"{}\";",
                message.id,
                text(&message.comment)
            )?;
            for signal in &message.signals {
                writeln!(
                    out,
                    "CM_ SG_ {} {} \"{}\";",
                    message.id,
                    signal.name,
                    text(&signal.comment)
                )?;
            }
        }
        writeln!(out, "BA_DEF_ BO_ \"GenMsgCycleTime\" INT 0 65535;")?;
        writeln!(out, "BA_DEF_DEF_ \"GenMsgCycleTime\" 0;")?;
        for message in &self.messages {
            if let Some(cycle) = message.cycle_ms {
                writeln!(out, "BA_ \"GenMsgCycleTime\" BO_ {} {cycle};", message.id)?;
            }
        }
        for message in &self.messages {
            for signal in message.signals.iter().filter(|s| !s.values.is_empty()) {
                write!(out, "VAL_ {} {}", message.id, signal.name)?;
                for (code, description) in &signal.values {
                    write!(out, " {code} \"{}\"", text(description))?;
                }
                writeln!(out, " ;")?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;

    const NET: &str = r#"
[nodes.arm]
id = 1
[nodes.2nd-hand]
id = 2
[topics.object_pos]
can_id = 0x110
[topics.wide]
can_id = 0x1A0000
extended = true
mask = 0x1FFF0000
[ports."arm.target"]
[ports."2nd-hand.command"]
[connections.C1]
topic = "object_pos"
port = "arm.target"
st = 0.2
tc = 3.0
[connections.C2]
topic = "object_pos"
port = "2nd-hand.command"
st = 0.2
tc = 3.0
"#;

    fn network(text: &str) -> Network {
        Network::parse(Source::new("net.toml", text)).unwrap()
    }

    #[test]
    fn a_captures_claims_are_listed_and_frames_that_are_not_claims_of_members_refused() {
        let net = network(include_str!("../../examples/multi-target-observation.toml"));
        let claim = |node: u8, eligibility: u16| Claim {
            group: 1,
            node,
            eligibility,
        };
        let good = claim(2, 500).frame().unwrap();
        let stranger = claim(99, 7).frame().unwrap();
        // The identifier says 500, the payload 501: a claim no node would keep.
        let mut bytes = [1, 0xF4, 0x01, 0];
        bytes[1] = 0xF5;
        let forged = pab_core::Frame::data(good.id(), &bytes).unwrap();
        let path = std::path::Path::new("bus.log");
        let capture = |frames: &[pab_core::Frame]| {
            let timed: Vec<(u64, pab_core::Frame)> = frames.iter().map(|f| (0, *f)).collect();
            crate::candump::Capture::from_frames("vcan0", &timed)
        };
        let claims = claims_in(&net, &capture(&[good, good]), path).unwrap();
        assert_eq!(claims, [claim(2, 500)]);
        let dbc = build(&net, &claims).unwrap();
        let listed: Vec<u32> = dbc
            .messages
            .iter()
            .filter(|m| m.name.starts_with("PAB_Claim_r2"))
            .map(|m| m.id & !EXTENDED_FLAG)
            .collect();
        assert_eq!(
            listed,
            [claim(2, 0).frame().unwrap().raw_id().0, good.raw_id().0]
        );
        let errors = claims_in(&net, &capture(&[good, stranger, forged]), path).unwrap_err();
        let text: Vec<String> = errors.0.iter().map(|e| e.render(false)).collect();
        assert_eq!(text.len(), 2, "{text:#?}");
        assert!(
            text[0].starts_with(
                "bus.log:2:1: error: a BLE claim from node id 99, which is in no BLE group"
            ),
            "{text:#?}"
        );
        assert!(
            text[1].starts_with(
                "bus.log:3:1: error: a frame with a BLE claim's identifier that is not a claim"
            ),
            "{text:#?}"
        );
    }

    #[test]
    fn identifiers_are_c_identifiers() {
        assert_eq!(identifier("arm", "n_"), "arm");
        assert_eq!(identifier("2nd-hand", "n_"), "n_2nd_hand");
        assert_eq!(identifier("", "n_"), "n_");
    }

    #[test]
    fn the_node_that_runs_a_dynamics_group_sends_gates_and_no_other_does() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/door-dynamics.toml"
        );
        let text = std::fs::read_to_string(path).unwrap();
        let dbc = build(&network(&text), &[]).unwrap();
        let gates: Vec<_> = dbc
            .messages
            .iter()
            .filter(|m| m.name.starts_with("PAB_Gates"))
            .collect();
        assert_eq!(gates.len(), 1);
        let gates = gates[0];
        assert_eq!(gates.name, "PAB_Gates_base");
        assert_eq!(
            gates.id,
            FrameId::new(Service::Gates, 5, BROADCAST).raw() | EXTENDED_FLAG
        );
        assert_eq!((gates.dlc, gates.cycle_ms), (8, Some(100)));
        let names: Vec<&str> = gates.signals.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            ["group", "behaviours", "gates", "changes", "reserved"]
        );
        // Without dynamics: no gates.
        assert!(
            build(&network(NET), &[])
                .unwrap()
                .messages
                .iter()
                .all(|m| !m.name.starts_with("PAB_Gates"))
        );
    }

    #[test]
    fn an_hbba_network_has_desires_the_intention_and_each_filtered_nodes_filter_frames() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/tour-guide.toml");
        let text = std::fs::read_to_string(path).unwrap();
        let dbc = build(&network(&text), &[]).unwrap();
        assert!(dbc.nodes.iter().any(|n| n == INTENTION_NODE));
        let find = |name: &str| {
            dbc.messages
                .iter()
                .find(|m| m.name == name)
                .unwrap_or_else(|| panic!("no {name}"))
        };
        let desire = find("PAB_Desire_PABCTL");
        assert_eq!(
            (desire.id, desire.dlc, desire.transmitter.as_str()),
            (
                FrameId::new(Service::Desire, TOOL, BROADCAST).raw() | EXTENDED_FLAG,
                8,
                TOOL_NODE
            )
        );
        let intention = find("PAB_Intention_PAB_INTENT");
        assert_eq!(
            (intention.id, intention.cycle_ms),
            (
                FrameId::new(Service::Intention, INTENTION, BROADCAST).raw() | EXTENDED_FLAG,
                Some(1000)
            )
        );
        // Both nodes have filtered connections (head: FACE, VOICE, QR; base: NAV, AVOID).
        for (node, id) in [("head", 1), ("base", 2)] {
            let status = find(&format!("PAB_FilterStatus_{node}"));
            assert_eq!((status.dlc, status.cycle_ms), (8, Some(1000)));
            let edge = find(&format!("PAB_Exploitation_{node}"));
            assert_eq!(
                (edge.id, edge.dlc),
                (
                    FrameId::new(Service::Exploitation, id, BROADCAST).raw() | EXTENDED_FLAG,
                    4
                )
            );
            let set = find(&format!("PAB_FilterSet_{node}"));
            assert_eq!(
                (set.id, set.dlc, set.transmitter.as_str()),
                (
                    FrameId::new(Service::FilterSet, INTENTION, id).raw() | EXTENDED_FLAG,
                    6,
                    INTENTION_NODE
                )
            );
            assert_eq!(find(&format!("PAB_FilterProfile_{node}")).dlc, 4);
        }
        // Without [hbba]: none of them.
        let plain = build(&network(NET), &[]).unwrap();
        assert!(plain.messages.iter().all(|m| {
            [
                "PAB_Desire",
                "PAB_Intention",
                "PAB_Filter",
                "PAB_Exploitation",
            ]
            .iter()
            .all(|prefix| !m.name.starts_with(prefix))
        }));
        assert!(plain.nodes.iter().all(|n| n != INTENTION_NODE));
    }

    #[test]
    fn a_schema_servers_board_has_its_reports_and_the_stops_to_it_and_to_all() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/assembly.toml");
        let text = std::fs::read_to_string(path).unwrap();
        let dbc = build(&network(&text), &[]).unwrap();
        let find = |name: &str| {
            dbc.messages
                .iter()
                .find(|m| m.name == name)
                .unwrap_or_else(|| panic!("no {name}"))
        };
        // Node `arm`, id 10, runs the server.
        let ack = find("PAB_SchemaAck_arm");
        assert_eq!(
            (ack.id, ack.dlc),
            (
                FrameId::new(Service::SchemaAck, 10, TOOL).raw() | EXTENDED_FLAG,
                8
            )
        );
        let change = find("PAB_SchemaTransition_arm");
        assert_eq!(
            change.id,
            FrameId::new(Service::SchemaTransition, 10, BROADCAST).raw() | EXTENDED_FLAG
        );
        let state = find("PAB_SchemaState_arm");
        assert_eq!((state.dlc, state.cycle_ms), (8, Some(100)));
        let fault = state.signals.iter().find(|s| s.name == "fault").unwrap();
        assert_eq!(fault.values.last(), Some(&(255, "none")));
        let stop_number = state.signals.iter().find(|s| s.name == "stop").unwrap();
        assert_eq!((stop_number.start, stop_number.len), (42, 6));
        assert_eq!(fault.max, "255");
        let stop = find("PAB_EmergencyStop_all");
        assert_eq!(
            (stop.id, stop.dlc, stop.signals.len()),
            (0x0200_FF00 | EXTENDED_FLAG, 0, 0)
        );
        assert_eq!(stop.receivers, ["arm"]);
        assert_eq!(
            find("PAB_EmergencyStop_arm").id,
            FrameId::new(Service::EmergencyStop, TOOL, 10).raw() | EXTENDED_FLAG
        );
        let abort = find("PAB_SchemaAbort_arm");
        assert_eq!(
            (abort.id, abort.dlc),
            (
                FrameId::new(Service::SchemaAbort, TOOL, 10).raw() | EXTENDED_FLAG,
                0
            )
        );
        assert!(find("PAB_SchemaAbort_all").comment.contains("0x19"));
        // ISO-TP: the tool's frames and the board's flow control, 8 bytes each (padded).
        let transfer = FrameId::new(Service::SchemaTransfer, TOOL, 10).raw();
        assert!(dbc.node_comments[1].contains(&format!("0x{transfer:08X}")));
        let data = find("PAB_SchemaTransfer_arm");
        assert_eq!((data.id, data.dlc), (transfer | EXTENDED_FLAG, 8));
        let flow = find("PAB_SchemaTransferFlow_arm");
        assert_eq!(
            (flow.id, flow.dlc),
            (
                FrameId::new(Service::SchemaTransfer, 10, TOOL).raw() | EXTENDED_FLAG,
                8
            )
        );
        fits_without_overlap(&dbc);
        // Without a schema server: none of them.
        let plain = build(&network(NET), &[]).unwrap();
        assert!(plain.messages.iter().all(|m| {
            ["PAB_Schema", "PAB_EmergencyStop"]
                .iter()
                .all(|prefix| !m.name.starts_with(prefix))
        }));
    }

    #[test]
    fn messages_per_node_service_and_topic() {
        let dbc = build(&network(NET), &[]).unwrap();
        assert_eq!(dbc.nodes, ["PABCTL", "arm", "node_2nd_hand"]);
        let find = |name: &str| {
            dbc.messages
                .iter()
                .find(|m| m.name == name)
                .unwrap_or_else(|| panic!("no message {name}"))
        };
        let heartbeat = find("PAB_Heartbeat_arm");
        assert_eq!(
            heartbeat.id,
            FrameId::new(Service::Heartbeat, 1, BROADCAST).raw() | EXTENDED_FLAG
        );
        assert_eq!(heartbeat.id, 0x9202_FF01);
        assert_eq!(heartbeat.cycle_ms, Some(1000));
        let status = find("PAB_TransferStatus_node_2nd_hand");
        assert_eq!(
            status.id,
            FrameId::new(Service::TransferStatus, 2, TOOL).raw() | EXTENDED_FLAG
        );
        let control = find("PAB_DiagnosticControl_arm");
        assert_eq!(control.dlc, 4);
        assert_eq!(control.transmitter, "PABCTL");
        assert_eq!(control.receivers, ["arm"]);
        let all = find("PAB_DiagnosticControl_all");
        assert_eq!(
            all.id,
            FrameId::new(Service::DiagnosticControl, TOOL, BROADCAST).raw() | EXTENDED_FLAG
        );
        // 9 services per node (7 + Challenge, Receipt), a table transfer's two directions per
        // node, diagnostic control per node and broadcast, ChallengeRequest and TransferOpen
        // per node, 2 topics.
        assert_eq!(dbc.messages.len(), 2 * 9 + 2 * 2 + 3 + 2 * 2 + 2);
        let open = find("PAB_TransferOpen_arm");
        assert_eq!(open.dlc, 8);
        assert_eq!(open.transmitter, "PABCTL");
        assert_eq!(find("PAB_ChallengeRequest_arm").dlc, 0);
        assert_eq!(find("PAB_Receipt_arm").signals.len(), 2);
        let transfer = find("PAB_TableTransfer_arm");
        assert_eq!(
            (transfer.id, transfer.dlc, transfer.transmitter.as_str()),
            (
                FrameId::new(Service::TableTransfer, TOOL, 1).raw() | EXTENDED_FLAG,
                8,
                "PABCTL"
            )
        );
        assert_eq!(transfer.signals[0].name, "pci_type");
        assert_eq!(transfer.signals[0].values.len(), 4);
        let topic = find("object_pos");
        assert_eq!(topic.id, 0x110);
        assert_eq!(topic.receivers, ["arm", "node_2nd_hand"]);
        assert_eq!(topic.signals.len(), 8);
        let wide = find("wide");
        assert_eq!(wide.id, 0x1A_0000 | EXTENDED_FLAG);
        assert!(wide.comment.contains("mask 0x1FFF0000"), "{}", wide.comment);
        fits_without_overlap(&dbc);
    }

    #[test]
    fn the_text_has_the_dbc_sections() {
        let text = build(&network(NET), &[]).unwrap().render();
        assert!(text.contains("BU_: PABCTL arm node_2nd_hand\n"), "{text}");
        assert!(
            text.contains("BO_ 2449669889 PAB_Heartbeat_arm: 8 arm\n"),
            "{text}"
        );
        assert!(text.contains(" SG_ uptime : 8|24@1+ (1,0) [0|16777215] \"s\" PABCTL\n"));
        assert!(text.contains(&format!(
            " SG_ level : 32|32@1+ ({Q31_FACTOR},0) [0|1] \"S\""
        )));
        assert!(
            text.contains("VAL_ 2449669889 state 0 \"no table\" 1 \"operational\" 2 \"fault\" ;\n")
        );
        assert!(text.contains("BA_ \"GenMsgCycleTime\" BO_ 2449669889 1000;\n"));
        assert!(text.contains("BO_ 272 object_pos: 8 Vector__XXX\n"));
    }

    #[test]
    fn topics_in_the_protocol_space_are_refused() {
        let text = NET.replace("can_id = 0x1A0000", "can_id = 0x12020000");
        let text = text.replace("mask = 0x1FFF0000", "mask = 0x1FFFFFFF");
        let errors = build(&network(&text), &[]).unwrap_err();
        let message = errors.to_string();
        assert!(
            message.starts_with("net.toml:8:1: error: topic `wide`"),
            "{message}"
        );
        assert!(message.contains("identifier space"), "{message}");
    }

    /// The payload bits `signal` covers, in DBC's numbering (byte * 8 + bit), most significant
    /// first: a little-endian signal counts up from its start, a big-endian (Motorola) one
    /// counts down from its start within a byte and goes on at bit 7 of the next byte.
    fn bits(signal: &DbcSignal) -> Vec<u32> {
        match signal.endian {
            Endian::Little => (signal.start..signal.start + signal.len).rev().collect(),
            Endian::Big => {
                let mut bit = signal.start;
                let mut out = vec![bit];
                while out.len() < signal.len as usize {
                    bit = if bit.is_multiple_of(8) {
                        bit + 15
                    } else {
                        bit - 1
                    };
                    out.push(bit);
                }
                out
            }
        }
    }

    /// The raw value a DBC reader takes from `payload` for `signal`.
    fn dbc_raw(signal: &DbcSignal, payload: &[u8; 8]) -> i64 {
        let raw = bits(signal).iter().fold(0u64, |acc, &bit| {
            acc << 1 | u64::from(payload[(bit / 8) as usize] >> (bit % 8) & 1)
        });
        if signal.signed && raw >> (signal.len - 1) & 1 == 1 {
            raw as i64 - (1i64 << signal.len)
        } else {
            raw as i64
        }
    }

    /// Every signal lies within its message and no two overlap.
    fn fits_without_overlap(dbc: &Dbc) {
        for message in &dbc.messages {
            let mut used = 0u64;
            for signal in &message.signals {
                for bit in bits(signal) {
                    assert!(
                        bit < 8 * u32::from(message.dlc),
                        "{}.{} is beyond its DLC",
                        message.name,
                        signal.name
                    );
                    assert_eq!(used >> bit & 1, 0, "{} overlaps", signal.name);
                    used |= 1 << bit;
                }
            }
        }
    }

    /// host-tools/tests/fixtures/sensors.toml: a board with one sensor of each kind of field
    /// (the file cantools checks in ./test.sh).
    fn sensors_network() -> Network {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../host-tools/tests/fixtures/sensors.toml"
        );
        network(&std::fs::read_to_string(path).unwrap())
    }

    #[test]
    fn a_schema_servers_sensor_topics_are_messages_with_one_signal_per_field() {
        let dbc = build(&sensors_network(), &[]).unwrap();
        let sensors: Vec<(&str, u32, u8)> = dbc
            .messages
            .iter()
            .filter(|m| m.name.starts_with("Sensor_"))
            .map(|m| (m.name.as_str(), m.id, m.dlc))
            .collect();
        // One message per identifier (pressure and temperature share 0x331), the DLC the
        // shortest frame the board reads.
        assert_eq!(
            sensors,
            [
                ("Sensor_gap_arm", 0x330, 2),
                ("Sensor_pressure_temperature_arm", 0x331, 8),
                ("Sensor_ticks_arm", 0x123_4567 | EXTENDED_FLAG, 8),
                ("Sensor_torque_arm", 0x332, 5),
            ]
        );
        let signal = |message: &str, name: &str| {
            let message = dbc.messages.iter().find(|m| m.name == message).unwrap();
            assert_eq!(message.transmitter, UNKNOWN_NODE);
            message
                .signals
                .iter()
                .find(|s| s.name == name)
                .unwrap()
                .clone()
        };
        let gap = signal("Sensor_gap_arm", "gap");
        assert_eq!(
            (gap.start, gap.len, gap.endian, gap.signed),
            (0, 16, Endian::Little, false)
        );
        // physical = raw × factor: the factor is the scale, the bounds the field's in mm.
        assert_eq!(
            (gap.factor.as_str(), gap.min.as_str(), gap.max.as_str()),
            ("0.01", "0", "655.35")
        );
        assert_eq!(gap.unit, "mm");
        assert!(gap.comment.contains("range finder"), "{}", gap.comment);
        let pressure = signal("Sensor_pressure_temperature_arm", "pressure");
        // Motorola: the most significant bit, bit 7 of byte 2.
        assert_eq!(
            (
                pressure.start,
                pressure.len,
                pressure.endian,
                pressure.signed
            ),
            (23, 16, Endian::Big, true)
        );
        assert_eq!(
            (pressure.min.as_str(), pressure.max.as_str()),
            ("-16384", "16383.5")
        );
        let temperature = signal("Sensor_pressure_temperature_arm", "temperature");
        assert_eq!((temperature.start, temperature.len), (56, 8));
        let ticks = signal("Sensor_ticks_arm", "ticks");
        assert_eq!(
            (ticks.start, ticks.endian, ticks.unit.as_str()),
            (39, Endian::Big, "")
        );
        assert!(ticks.comment.contains("2^31 - 1"), "{}", ticks.comment);
        // The network's topic on the range finder's id joins its message: no second one.
        let joined = dbc.messages.iter().find(|m| m.id == 0x330).unwrap();
        assert_eq!(joined.receivers, ["arm", "eye"]);
        assert!(
            joined.comment.contains("Also topic `range`"),
            "{}",
            joined.comment
        );
        assert_eq!(dbc.messages.iter().filter(|m| m.id == 0x330).count(), 1);
        fits_without_overlap(&dbc);

        let text = dbc.render();
        assert!(text.contains(" SG_ gap : 0|16@1+ (0.01,0) [0|655.35] \"mm\" arm,eye\n"));
        assert!(
            text.contains(" SG_ pressure : 23|16@0- (0.5,0) [-16384|16383.5] \"kPa\" arm\n"),
            "{text}"
        );
        assert!(text.contains(&format!(
            "BO_ {} Sensor_ticks_arm: 8 Vector__XXX\n",
            0x123_4567 | EXTENDED_FLAG
        )));
    }

    #[test]
    fn a_dbc_reader_takes_from_a_sensor_frame_the_count_the_board_reads() {
        let network = sensors_network();
        let dbc = build(&network, &[]).unwrap();
        for topic in &network.schema_boards[0].sensors {
            let signal = dbc
                .messages
                .iter()
                .flat_map(|m| &m.signals)
                .find(|s| s.name == topic.name)
                .unwrap();
            let field = topic.sensor.field;
            let (low, high) = field.range();
            // The bounds, and a value whose bytes all differ (a byte-order mistake shows).
            for value in [low, high, 0x0102_0304 % (high + 1)] {
                let mut payload = [0u8; 8];
                field.write(&mut payload, value);
                assert_eq!(field.read(&payload), Some(value));
                assert_eq!(dbc_raw(signal, &payload), value, "{}", topic.name);
            }
        }
    }
}
