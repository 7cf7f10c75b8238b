//! Sealed coordination on a keyed network (`docs/can-protocol.md`, "Sealed coordination"): the
//! seals each coordination sender sends after its Gates and claims (to all) and the intention
//! node after its filter commands (to each node with filters), and between each receiver and
//! each sender it hears, the freshness request, the answer and the answer's seal. A network
//! without keys sends none of them; its DBC lists them all the same, as a network file does
//! not say which nodes get keys.

use std::collections::BTreeSet;

use pab_core::protocol::{BROADCAST, FrameId, INTENTION, Service};

use super::protocol::has_filters;
use super::services::{service_comment, service_signals};
use super::{DbcMessage, INTENTION_NODE, Names, extended};
use crate::network::{Kind, Network};

/// A party to sealed coordination: its id and DBC node name.
type Party = (u8, String);

/// The senders node `index` hears coordination from: the owners of the dynamics groups whose
/// gates its rules read, its BLE groups' other members, and the intention node if it has
/// message filters.
fn senders_of(network: &Network, nodes: &[String], index: usize) -> BTreeSet<Party> {
    let party = |i: usize| {
        let node = network.nodes.get(i)?;
        Some((node.id, nodes.get(i + 1)?.clone()))
    };
    let mut senders = BTreeSet::new();
    if let Some(node) = network.nodes.get(index) {
        for &port in &node.ports {
            for connection in network
                .port_connections(port)
                .filter(|c| c.kind == Kind::Gate)
            {
                let owner = crate::network::gate(&network.dynamics, &connection.name)
                    .and_then(|(g, _)| network.dynamics.get(g))
                    .map(|group| group.node);
                if let Some(owner) = owner.filter(|&owner| owner != index) {
                    senders.extend(party(owner));
                }
            }
        }
    }
    for group in network
        .groups
        .iter()
        .filter(|g| g.members.iter().any(|m| m.node == index))
    {
        for member in group.members.iter().filter(|m| m.node != index) {
            senders.extend(party(member.node));
        }
    }
    if network.hbba.is_some() && has_filters(network, index) {
        senders.insert((INTENTION, INTENTION_NODE.to_string()));
    }
    senders
}

/// The messages of sealed coordination. `nodes` are the DBC's node names (the tool first, the
/// intention node last when the network has `[hbba]`).
pub(super) fn sealing(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
    let receivers: Vec<String> = nodes.iter().skip(1).cloned().collect();
    let mut push = |service: Service,
                    (from, from_name): &Party,
                    (to, to_name): (u8, &str),
                    name: String,
                    what: &str| {
        // A broadcast is for every node of the network.
        let receivers = if to == BROADCAST {
            receivers
                .iter()
                .filter(|name| *name != from_name)
                .cloned()
                .collect()
        } else {
            vec![to_name.to_string()]
        };
        messages.push(DbcMessage {
            id: extended(FrameId::new(service, *from, to)),
            name: names.unique(name),
            dlc: service.payload_len() as u8,
            transmitter: from_name.clone(),
            receivers,
            signals: service_signals(service).unwrap_or_default(),
            comment: format!(
                "{} {what} On a keyed network only.",
                service_comment(service)
            ),
            fd: false,
            cycle_ms: None,
        });
    };
    // The seals of what coordination senders broadcast.
    for (index, node) in network.nodes.iter().enumerate() {
        let sends = network.dynamics.iter().any(|g| g.node == index)
            || network
                .groups
                .iter()
                .any(|g| g.members.iter().any(|m| m.node == index));
        let Some(name) = nodes.get(index + 1) else {
            continue;
        };
        if sends {
            push(
                Service::Seal,
                &(node.id, name.clone()),
                (BROADCAST, ""),
                format!("PAB_Seal_{name}"),
                &format!(
                    "From node `{}` to all (0xFF), after each of its Gates and claims.",
                    node.name
                ),
            );
        }
    }
    // Each receiver with each sender it hears: the intention node's seals of its commands, and
    // the freshness exchange.
    for (index, node) in network.nodes.iter().enumerate() {
        let Some(name) = nodes.get(index + 1) else {
            continue;
        };
        let receiver: Party = (node.id, name.clone());
        for sender in senders_of(network, nodes, index) {
            let (sender_name, receiver_name) = (&sender.1, &receiver.1);
            if sender.0 == INTENTION {
                push(
                    Service::Seal,
                    &sender,
                    (receiver.0, receiver_name),
                    format!("PAB_Seal_{sender_name}_{receiver_name}"),
                    &format!(
                        "From the intention node to node `{}`, after each filter command.",
                        node.name
                    ),
                );
            }
            push(
                Service::FreshnessRequest,
                &receiver,
                (sender.0, sender_name),
                format!("PAB_FreshnessRequest_{receiver_name}_{sender_name}"),
                &format!("From node `{}` to {sender_name}.", node.name),
            );
            push(
                Service::Freshness,
                &sender,
                (receiver.0, receiver_name),
                format!("PAB_Freshness_{sender_name}_{receiver_name}"),
                &format!("From {sender_name} to node `{}`.", node.name),
            );
            if sender.0 != INTENTION {
                push(
                    Service::Seal,
                    &sender,
                    (receiver.0, receiver_name),
                    format!("PAB_Seal_{sender_name}_{receiver_name}"),
                    &format!(
                        "From {sender_name} to node `{}`, after its Freshness answer.",
                        node.name
                    ),
                );
            }
        }
    }
}
