//! The protocol messages of a network: what each node sends (heartbeat, status, traffic, and the
//! services of the mechanisms it runs), the diagnostic control and authentication the tool sends
//! each node, and, with `[hbba]`, the desires, the intention and the filter commands.

use pab_core::protocol::{BROADCAST, FrameId, INTENTION, Service, TOOL};

use super::services::{service_comment, service_signals};
use super::{DbcMessage, INTENTION_NODE, Names, TOOL_NODE, UNKNOWN_NODE, extended, serves};
use crate::network::Network;

/// Whether node `index` has message filters: a connection of one of its ports that an HBBA
/// strategy filters.
pub(super) fn has_filters(network: &Network, index: usize) -> bool {
    network.hbba.as_ref().is_some_and(|hbba| {
        hbba.strategies
            .iter()
            .flat_map(|s| &s.filters)
            .filter_map(|f| network.connections.get(f.connection))
            .filter_map(|c| network.ports.get(c.port))
            .any(|port| port.node == index)
    })
}

/// Each node's own frames: one message per service it sends, to all or to the tool.
pub(super) fn from_nodes(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
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
        let schema_server = serves(network, index);
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
                | Service::SchemaTransfer
                | Service::UpdateTransfer
                | Service::IdentityRequest
                | Service::Assign
                | Service::Configure
                // Sealed coordination's frames: `sealing.rs`.
                | Service::Seal
                | Service::FreshnessRequest
                | Service::Freshness => continue,
                Service::Gates if !runs_dynamics => continue,
                Service::FilterStatus | Service::Exploitation if !filtered => continue,
                Service::SchemaAck | Service::SchemaTransition | Service::SchemaState
                    if !schema_server =>
                {
                    continue;
                }
                // The answer goes to the schema's sender: described from the tool. The
                // identity answers the tool's request (the announcement at start-up is the same
                // six frames to all, 0xFF).
                Service::TransferStatus
                | Service::Challenge
                | Service::Receipt
                | Service::SchemaAck
                | Service::Identity
                | Service::IdentityVersion
                | Service::IdentityBuild
                | Service::IdentityCapacity
                | Service::IdentityFeatures
                | Service::IdentityName
                | Service::ConfigStatus
                | Service::UpdateStatus => TOOL,
                _ => BROADCAST,
            };
            let Some(signals) = service_signals(service) else {
                continue;
            };
            // The identity goes to the tool that asked, and once at start-up to all (0xFF): a
            // capture holds both.
            let announced = pab_core::protocol::identity_part(service).is_some();
            if announced {
                let frame = FrameId::new(service, node.id, BROADCAST);
                messages.push(DbcMessage {
                    id: extended(frame),
                    name: names.unique(format!("PAB_{service:?}_{dbc_node}_all")),
                    dlc: service.payload_len() as u8,
                    transmitter: dbc_node.clone(),
                    receivers: vec![TOOL_NODE.to_string()],
                    signals: signals.clone(),
                    comment: format!(
                        "{} From node `{}` (id {}) to all (0xFF), at start-up.",
                        service_comment(service),
                        node.name,
                        node.id
                    ),
                    fd: false,
                    cycle_ms: None,
                });
            }
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
                fd: false,
                cycle_ms: if matches!(service, Service::Gates | Service::SchemaState) {
                    Some(100)
                } else {
                    (periodic.contains(&service) || service == Service::FilterStatus)
                        .then_some(1000)
                },
            });
        }
    }
}

/// The diagnostic control and the identity request the tool sends to each node and to all.
pub(super) fn diagnostic_control(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
    for control in [Service::DiagnosticControl, Service::IdentityRequest] {
        to_each_and_all(network, nodes, messages, names, control);
    }
}

fn to_each_and_all(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
    control: Service,
) {
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
            fd: false,
            cycle_ms: None,
        });
    }
}

/// HBBA: desires (described from the tool; any node may send them), the intention node's
/// intention and its filter commands to each node with filters.
pub(super) fn intention(
    network: &Network,
    nodes: &mut Vec<String>,
    node_comments: &mut Vec<String>,
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
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
            fd: false,
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
            fd: false,
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
                    fd: false,
                    cycle_ms: None,
                });
            }
        }
    }
}

/// The tool's authentication frames go to one node each (a tag is over one node's challenge), and
/// so do its configuration commands (Assign: to the node at its node id; an unassigned node's
/// provisional address is not in the network file).
pub(super) fn authentication(
    network: &Network,
    nodes: &[String],
    messages: &mut Vec<DbcMessage>,
    names: &mut Names,
) {
    for (node, dbc_node) in network.nodes.iter().zip(nodes.iter().skip(1)) {
        for service in [
            Service::ChallengeRequest,
            Service::TransferOpen,
            Service::Assign,
            Service::Configure,
        ] {
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
                fd: false,
                cycle_ms: None,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dbc::tests::{NET, network};
    use crate::dbc::{EXTENDED_FLAG, build};

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
}
