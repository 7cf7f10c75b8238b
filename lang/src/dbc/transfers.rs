//! Table, firmware-update and schema transfers: the ISO-TP frames between the tool and each node,
//! described frame by frame.

use pab_core::protocol::{FrameId, Service, TOOL};

use super::{DbcMessage, DbcSignal, Names, TOOL_NODE, extended, serves, signal};
use crate::network::Network;

/// The two messages of one node's ISO-TP transfer on `service` (table, update or schema): the tool's
/// data frames to the node and the node's flow control back. Both 8 bytes (our ISO-TP pads
/// every frame): the PCI type and low nibble as signals, bytes 1..7 raw.
fn transfer_messages(
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    service: Service,
    node: &crate::network::Node,
    dbc_node: &str,
) {
    let what = match service {
        Service::TableTransfer => "a table image",
        Service::UpdateTransfer => "a firmware-update message (Begin, Chunk, Commit or Abort)",
        _ => "a schema (a channel byte, then the schema)",
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
        fd: false,
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
        fd: false,
        cycle_ms: None,
    });
}

/// Table, firmware-update and schema transfers: ISO-TP frames (docs/can-protocol.md), always
/// padded to 8 bytes, so a capture of a transfer decodes byte by byte; the PCI's type and low
/// nibble are signals, the reassembled message is not (a DBC describes single frames). Every
/// node gets the update's two messages: the network file does not say which nodes take updates
/// (one that cannot answers UpdateStatus Unsupported).
pub(super) fn transfers(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
    for (index, (node, dbc_node)) in network.nodes.iter().zip(nodes.iter().skip(1)).enumerate() {
        transfer_messages(messages, names, Service::TableTransfer, node, dbc_node);
        transfer_messages(messages, names, Service::UpdateTransfer, node, dbc_node);
        if serves(network, index) {
            transfer_messages(messages, names, Service::SchemaTransfer, node, dbc_node);
        }
    }
}
