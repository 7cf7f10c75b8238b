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
//!
//! [`build`] adds the messages in a fixed order, each kind from its own file in `dbc/`: the
//! protocol's frames of every node (`protocol.rs`, with the services' layouts in
//! `services.rs`), a schema server's drive, sensors and stops (`schema.rs`), BLE claims
//! (`claims.rs`), ISO-TP transfers (`transfers.rs`), sealed coordination (`sealing.rs`) and the
//! topics and re-published ports (`topics.rs`); `render.rs` writes the text.

use std::collections::HashSet;
use std::fmt::Write as _;

use pab_core::ble::Claim;
use pab_core::protocol::{FrameId, PROTOCOL_MASK, PROTOCOL_VALUE, Service, TOOL};
use pab_core::value_port::{Endian, Field};

use crate::diagnostic::Diagnostics;
use crate::network::Network;

mod claims;
mod protocol;
mod render;
mod schema;
mod sealing;
mod services;
mod topics;
mod transfers;

pub use claims::claims_in;
pub use services::service_signals;

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
    /// A CAN FD frame (a topic's `fd = true`, or a port re-publishing one): its `VFrameFormat`
    /// says so, and its DLC may be a CAN FD length up to 64.
    pub fd: bool,
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
    /// On a CAN FD bus, whether its FD frames switch to the data bit rate (`data_bitrate` above
    /// `bitrate`); `None` on a classic bus: the file then declares no CAN FD attribute.
    pub fd_brs: Option<bool>,
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

/// Whether node `index` runs a schema server: its board gets the schema server's frames.
fn serves(network: &Network, index: usize) -> bool {
    network.schema_boards.iter().any(|b| b.node == index)
}

/// The DBC database of `network`. Fails, with a diagnostic at the topic, if a topic lies in the
/// protocol's identifier space (extended, bits 25..24 = 0b10): nodes never arbitrate such frames.
///
/// `claims` are BLE claims to list beyond each group member's claim at eligibility 0 (those of a
/// capture, [`claims_in`]): a claim's identifier carries its eligibility, and a DBC names whole
/// identifiers, so a tool that matches identifiers exactly (cantools) decodes only the claims
/// listed. A claim of a node that is in no group is not listed.
pub fn build(network: &Network, claims: &[Claim]) -> Result<Dbc, Diagnostics> {
    let mut node_names = Names(HashSet::from([TOOL_NODE.to_string()]));
    let mut nodes = vec![TOOL_NODE.to_string()];
    let mut node_comments =
        vec!["The workstation tool (pabctl), address 0 in the pab protocol.".to_string()];
    for (index, node) in network.nodes.iter().enumerate() {
        nodes.push(node_names.unique(identifier(&node.name, "node_")));
        let transfer = FrameId::new(Service::TableTransfer, TOOL, node.id).raw();
        let flow = FrameId::new(Service::TableTransfer, node.id, TOOL).raw();
        let mut comment = format!(
            "Node `{}`, id {} ({} port{}). Table images reach it by ISO-TP (ISO 15765-2) on \
             service 0x11, not described here: data 0x{transfer:08X} (tool to node), flow control \
             0x{flow:08X} (node to tool). Firmware updates likewise on service 0x2B.",
            node.name,
            node.id,
            node.ports.len(),
            if node.ports.len() == 1 { "" } else { "s" },
        );
        if let Some(description) = &node.description {
            comment.insert_str(0, &format!("{description}. "));
        }
        if serves(network, index) {
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
    protocol::from_nodes(network, &nodes, &mut messages, &mut names);
    let sensor_ids = schema::drives_and_sensors(network, &nodes, &mut messages, &mut names);
    claims::claim_messages(network, claims, &nodes, &mut messages, &mut names);
    transfers::transfers(network, &nodes, &mut messages, &mut names);
    topics::republished(network, &nodes, &mut messages, &mut names);
    protocol::diagnostic_control(network, &nodes, &mut messages, &mut names);
    schema::stops(network, &nodes, &mut messages, &mut names);
    protocol::intention(
        network,
        &mut nodes,
        &mut node_comments,
        &mut messages,
        &mut names,
    );
    protocol::authentication(network, &nodes, &mut messages, &mut names);
    sealing::sealing(network, &nodes, &mut messages, &mut names);
    let errors = topics::topic_messages(network, &nodes, sensor_ids, &mut messages, &mut names);
    if !errors.is_empty() {
        return Err(Diagnostics(errors));
    }
    Ok(Dbc {
        nodes,
        node_comments,
        messages,
        fd_brs: network
            .bus
            .as_ref()
            .and_then(|bus| bus.data_bitrate.map(|data| data > bus.bitrate)),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;
    use pab_core::protocol::BROADCAST;

    pub(super) const NET: &str = r#"
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

    pub(super) fn network(text: &str) -> Network {
        Network::parse(Source::new("net.toml", text)).unwrap()
    }

    #[test]
    fn identifiers_are_c_identifiers() {
        assert_eq!(identifier("arm", "n_"), "arm");
        assert_eq!(identifier("2nd-hand", "n_"), "n_2nd_hand");
        assert_eq!(identifier("", "n_"), "n_");
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
        // 17 services per node (7 + Challenge, Receipt, six identity frames, ConfigStatus,
        // UpdateStatus) and the identity's six to all at start-up, a table transfer's and an
        // update's two directions per node, diagnostic control and identity request per node
        // and broadcast, ChallengeRequest, TransferOpen, Assign and Configure per node, 2 topics.
        assert_eq!(dbc.messages.len(), 2 * 23 + 2 * 4 + 2 * 3 + 2 * 4 + 2);
        assert_eq!(
            find("PAB_Identity_arm_all").id,
            FrameId::new(Service::Identity, 1, BROADCAST).raw() | EXTENDED_FLAG
        );
        assert_eq!(find("PAB_IdentityName_arm").transmitter, "arm");
        assert_eq!(find("PAB_IdentityRequest_all").dlc, 0);
        assert_eq!(find("PAB_Assign_arm").receivers, ["arm"]);
        let open = find("PAB_TransferOpen_arm");
        assert_eq!(open.dlc, 8);
        assert_eq!(open.transmitter, "PABCTL");
        assert_eq!(find("PAB_ChallengeRequest_arm").dlc, 8);
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
        let update = find("PAB_UpdateTransferFlow_arm");
        assert_eq!(
            (update.id, update.dlc, update.transmitter.as_str()),
            (
                FrameId::new(Service::UpdateTransfer, 1, TOOL).raw() | EXTENDED_FLAG,
                8,
                "arm"
            )
        );
        assert_eq!(
            find("PAB_UpdateStatus_arm").id,
            FrameId::new(Service::UpdateStatus, 1, TOOL).raw() | EXTENDED_FLAG
        );
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

    /// The payload bits `signal` covers, in DBC's numbering (byte * 8 + bit), most significant
    /// first: a little-endian signal counts up from its start, a big-endian (Motorola) one
    /// counts down from its start within a byte and goes on at bit 7 of the next byte.
    pub(super) fn bits(signal: &DbcSignal) -> Vec<u32> {
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
    pub(super) fn dbc_raw(signal: &DbcSignal, payload: &[u8; 8]) -> i64 {
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
    pub(super) fn fits_without_overlap(dbc: &Dbc) {
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
}
