//! The competitive-dynamics part of a node's table ([`pab_core::dynamics`]): the groups the node
//! runs (their parameters and contexts in the boards' integers), the groups whose gates its rules
//! read, and which connection is which gate.
//!
//! Group numbers are the network's (the file's order of `[dynamics.*]`); the node's own groups
//! are read as source [`OWN`], another node's under that node's id.

use pab_core::dynamics::{Context as BoardContext, GateLink, GateSource, GroupSpec, ONE, OWN};

use crate::diagnostic::Diagnostic;
use crate::network::{Context, DynamicsGroup, Kind, Network, Node};

/// What a node's table says of the dynamics.
pub(super) struct NodeDynamics {
    /// The groups it runs.
    pub specs: Vec<GroupSpec>,
    /// The groups whose gates its rules read.
    pub sources: Vec<GateSource>,
    /// Which connection is which gate.
    pub links: Vec<GateLink>,
}

/// What `node`'s table says of the dynamics.
pub(super) fn dynamics_of(network: &Network, node: &Node) -> Result<NodeDynamics, Diagnostic> {
    let node_index = network
        .nodes
        .iter()
        .position(|n| n.name == node.name)
        .unwrap_or(usize::MAX);
    let mut specs = Vec::new();
    for (number, group) in network.dynamics.iter().enumerate() {
        if group.node == node_index {
            specs.push(spec(network, node, group, number)?);
        }
    }
    let mut sources: Vec<GateSource> = Vec::new();
    let mut links = Vec::new();
    for (local_port, &port_index) in node.ports.iter().enumerate() {
        for connection in network
            .port_connections(port_index)
            .filter(|c| c.kind == Kind::Gate)
        {
            let invalid = |what: &str| {
                network.error(
                    connection.span.clone(),
                    format!("gate `{}` on node `{}`: {what}", connection.name, node.name),
                )
            };
            let (g, behaviour) = crate::network::gate(&network.dynamics, &connection.name)
                .ok_or_else(|| invalid("no such behaviour"))?;
            let group = network.dynamics.get(g).ok_or_else(|| invalid("no group"))?;
            let number = u8::try_from(g).map_err(|_| invalid("more than 256 dynamics groups"))?;
            let owner = if group.node == node_index {
                OWN
            } else {
                network
                    .nodes
                    .get(group.node)
                    .ok_or_else(|| invalid("its group's node is missing"))?
                    .id
            };
            let source = match sources.iter().position(|s| s.group == number) {
                Some(position) => position,
                None => {
                    sources.push(GateSource {
                        owner,
                        group: number,
                        behaviours: u8::try_from(group.behaviours.len())
                            .map_err(|_| invalid("too many behaviours"))?,
                    });
                    sources.len() - 1
                }
            };
            links.push(GateLink {
                source: u8::try_from(source).map_err(|_| invalid("too many groups read"))?,
                behaviour: u8::try_from(behaviour).map_err(|_| invalid("too many behaviours"))?,
                port: u8::try_from(local_port).map_err(|_| invalid("too many ports"))?,
                connection: u8::try_from(connection.index)
                    .map_err(|_| invalid("too many connections"))?,
            });
        }
    }
    Ok(NodeDynamics {
        specs,
        sources,
        links,
    })
}

/// Group `group` (number `number`) as the node that runs it stores it.
fn spec(
    network: &Network,
    node: &Node,
    group: &DynamicsGroup,
    number: usize,
) -> Result<GroupSpec, Diagnostic> {
    let invalid = |what: String| {
        network.error(
            group.span.clone(),
            format!(
                "dynamics group `{}` on node `{}`: {what}",
                group.name, node.name
            ),
        )
    };
    let mut spec = GroupSpec {
        number: u8::try_from(number)
            .map_err(|_| invalid("more than 256 dynamics groups".into()))?,
        params: group.params.clone(),
        contexts: Default::default(),
    };
    for behaviour in &group.behaviours {
        let context = match &behaviour.context {
            // Q2.29, rounded; [0, 1] was checked when the file was read.
            Context::Constant(value) => {
                BoardContext::Constant((value.clamp(0.0, 1.0) * f64::from(ONE)).round() as u32)
            }
            Context::Connection { connection } => {
                let c = network
                    .connections
                    .get(*connection)
                    .ok_or_else(|| invalid(format!("`{}`: no such connection", behaviour.name)))?;
                let port = node
                    .ports
                    .iter()
                    .position(|&p| p == c.port)
                    .ok_or_else(|| {
                        invalid(format!(
                            "`{}`: its context `{}` is not on the group's node",
                            behaviour.name, c.name
                        ))
                    })?;
                BoardContext::Connection {
                    port: u8::try_from(port).map_err(|_| invalid("too many ports".into()))?,
                    connection: u8::try_from(c.index)
                        .map_err(|_| invalid("too many connections".into()))?,
                }
            }
            Context::Topic {
                topic,
                field,
                scale,
                timeout_us,
            } => {
                let filter = network
                    .topics
                    .get(*topic)
                    .ok_or_else(|| invalid(format!("`{}`: no such topic", behaviour.name)))?
                    .filter;
                BoardContext::Topic {
                    filter,
                    field: *field,
                    scale: scale_q8(*scale).ok_or_else(|| {
                        invalid(format!(
                            "`{}`: a context scale must be between 1/256 and 16 777 215 (got {scale})",
                            behaviour.name
                        ))
                    })?,
                    timeout_us: u32::try_from(*timeout_us).map_err(|_| {
                        invalid(format!("`{}`: context timeout too long", behaviour.name))
                    })?,
                }
            }
        };
        spec.contexts
            .push(context)
            .map_err(|_| invalid("too many behaviours".into()))?;
    }
    Ok(spec)
}

/// A context scale in the boards' Q24.8, rounded; `None` outside [1/256, 2^24).
pub fn scale_q8(scale: f64) -> Option<u32> {
    let q = (scale * 256.0).round();
    (q >= 1.0 && q <= f64::from(u32::MAX)).then_some(q as u32)
}
