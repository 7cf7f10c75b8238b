//! The pab protocol's services as DBC signals: each service's payload as `docs/can-protocol.md`
//! lays it out, the value tables of its enumerations, and a comment per service.

use pab_core::protocol::{
    FaultCode, NodeState, SchemaAck, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety,
    SchemaState, SchemaTrigger, Service, TransferStatusCode,
};

use super::{DbcSignal, Q31_FACTOR, signal, with_unit, with_values};

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

pub(super) fn service_comment(service: Service) -> &'static str {
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
