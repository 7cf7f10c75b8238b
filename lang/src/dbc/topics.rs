//! The network's own frames: one message per topic, with the fields the network reads from it as
//! signals, and the frames ports re-publish.

use std::fmt::Write as _;

use pab_core::protocol::{PROTOCOL_MASK, PROTOCOL_VALUE};
use pab_core::value_port::{Endian, Field};

use super::{
    DbcMessage, DbcSignal, EXTENDED_FLAG, Names, UNKNOWN_NODE, field_signal, identifier, signal,
};
use crate::can_frame::FD_DATA_LEN;
use crate::diagnostic::Diagnostic;
use crate::network::Network;

/// The signals of a topic's message: each field the network reads from its frames
/// ([`Network::topic_fields`]: value ports, BLE eligibilities, dynamics contexts), then one byte
/// signal `dataN` for each byte of its `length` that no field covers. A field that overlaps one
/// listed before it is named in the comment instead (cantools refuses overlapping signals).
fn topic_signals(network: &Network, topic: usize, length: u8) -> (Vec<DbcSignal>, String) {
    let mut covered = [false; FD_DATA_LEN];
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
    for byte in 0..length.min(FD_DATA_LEN as u8) {
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

/// Ports that re-publish what they deliver: the delivered frame's payload on the port's id.
pub(super) fn republished(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
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
        for byte in (0..length.min(FD_DATA_LEN as u8)).filter(|&b| !covered(b)) {
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
        // A gateway re-publishes an FD frame as FD and a classic one as classic; a DBC message
        // has one format, so a port fed by both is declared FD (its longer frames).
        let fd_topics = topics
            .iter()
            .filter_map(|&t| network.topics.get(t))
            .filter(|t| t.fd)
            .count();
        let fd = fd_topics > 0;
        let mixed = if fd && fd_topics < topics.len() {
            " Its frames are CAN FD from its CAN FD topics, classic from the others."
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
                 frame's payload, from node `{}`.{uneven}{mixed}",
                port.name,
                network
                    .nodes
                    .get(port.node)
                    .map_or("?", |n| n.name.as_str())
            ),
            fd,
            cycle_ms: None,
        });
    }
}

/// The network's topics, one message each; a topic on an identifier that already has a message
/// (a sensor's, or another topic's under another mask) joins that message. A topic in the
/// protocol's identifier space is an error.
pub(super) fn topic_messages(
    network: &Network,
    nodes: &[String],
    sensor_ids: Vec<(u32, usize)>,
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) -> Vec<Diagnostic> {
    let mut errors = Vec::new();
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
            fd: topic.fd,
            cycle_ms: None,
        });
    }
    errors
}

#[cfg(test)]
mod tests {
    use crate::dbc::build;
    use crate::dbc::tests::{NET, network};

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
}
