//! Gates as rule variables: a rule may name `GROUP.BEHAVIOUR` (`door.search`), the gate of a
//! behaviour of a `[dynamics.GROUP]`. Each port whose rules name a gate gets one connection of
//! [`Kind::Gate`] named after it, after its own connections and claims, in the order the rules
//! first name them. No frame feeds it: on the boards its filter is the Gates service's
//! (`pab_core::dynamics::GATE_SLOT_FILTER`), and its activity is the gate, stepped on the node
//! that runs the group and read from that node's Gates frames anywhere else. A gate is proved
//! like any other connection: the checker knows nothing of the dynamics but what it is told
//! ([`crate::check`]).

use std::ops::Range;

use super::spanned::Spanned;
use indexmap::IndexMap;
use pab_core::MAX_CONNECTIONS_PER_PORT;
use pab_core::Stimulation;
use pab_core::dynamics::{MAX_GATE_LINKS, MAX_GATE_SOURCES};

use super::connections::RawConnection;
use super::{Builder, Connection, DynamicsGroup, Kind, NO_TOPIC, Port};
use crate::rule::{self, Rule};

/// σ = 1 and τ = 0.1 s: never used (no frame feeds a gate), but a valid connection for the
/// table, as Gates frames come at least every 0.1 s.
const GATE_TAU_S: f64 = 0.1;

/// `GROUP.BEHAVIOUR` split, if `name` has that form.
pub(super) fn split(name: &str) -> Option<(&str, &str)> {
    name.split_once('.')
}

/// The group and behaviour a gate's name names, as indices.
pub fn lookup(groups: &[DynamicsGroup], name: &str) -> Option<(usize, usize)> {
    let (group, behaviour) = split(name)?;
    let g = groups.iter().position(|g| g.name == group)?;
    let b = groups
        .get(g)?
        .behaviours
        .iter()
        .position(|b| b.name == behaviour)?;
    Some((g, b))
}

/// Why `name` (with a dot) is not a gate, for the rule's error.
pub(super) fn unknown(groups: &[DynamicsGroup], name: &str) -> String {
    let Some((group, behaviour)) = split(name) else {
        return format!("`{name}` is not a gate");
    };
    match groups.iter().find(|g| g.name == group) {
        Some(g) => {
            let names: Vec<&str> = g.behaviours.iter().map(|b| b.name.as_str()).collect();
            format!(
                "dynamics group `{group}` has no behaviour `{behaviour}` (its behaviours: {})",
                names.join(", ")
            )
        }
        None => {
            let names: Vec<&str> = groups.iter().map(|g| g.name.as_str()).collect();
            format!(
                "`{name}` names no dynamics group `{group}` ({})",
                if names.is_empty() {
                    "the file declares none: [dynamics.NAME]".to_string()
                } else {
                    format!("declared: {}", names.join(", "))
                }
            )
        }
    }
}

impl Builder<'_> {
    /// Adds a gate connection to every port whose rules name a gate, once per port and gate.
    /// A name that is no gate is reported when the rules are resolved.
    pub(super) fn gates(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawConnection>>,
        groups: &[DynamicsGroup],
        connections: &mut Vec<Connection>,
        ports: &mut [Port],
    ) {
        if groups.is_empty() {
            return;
        }
        // (port, gate name, group, rule span), in the order the rules name them.
        let mut wanted: Vec<(usize, String, usize, Range<usize>)> = Vec::new();
        for connection in connections.iter() {
            let Some((_, written)) = raw.get_key_value(connection.name.as_str()) else {
                continue;
            };
            let Some(text) = &written.get_ref().rule else {
                continue;
            };
            let named = std::cell::RefCell::new(Vec::new());
            let record = |name: &str| -> Result<usize, String> {
                if let Some((group, _)) = lookup(groups, name) {
                    named.borrow_mut().push((name.to_string(), group));
                }
                Ok(0)
            };
            // Syntax errors are reported when the rules are resolved.
            let _ = rule::parse(text.get_ref(), &record);
            for (name, group) in named.into_inner() {
                if !wanted
                    .iter()
                    .any(|(p, n, _, _)| *p == connection.port && *n == name)
                {
                    wanted.push((connection.port, name, group, text.span()));
                }
            }
        }
        for (port, name, group, span) in wanted {
            let Some(entry) = ports.get(port) else {
                continue;
            };
            let node = entry.node;
            let on_node: Vec<&Connection> = connections
                .iter()
                .filter(|c| c.kind == Kind::Gate)
                .filter(|c| ports.get(c.port).is_some_and(|p| p.node == node))
                .collect();
            let sources: Vec<usize> = on_node
                .iter()
                .filter_map(|c| lookup(groups, &c.name).map(|(g, _)| g))
                .collect();
            let index = entry.connections.len();
            if index >= MAX_CONNECTIONS_PER_PORT {
                self.error(
                    span,
                    format!(
                        "naming gate `{name}` adds it to port `{}` as one more connection, but that port already has {MAX_CONNECTIONS_PER_PORT} connections, the most a port may have",
                        entry.name
                    ),
                );
                continue;
            }
            if on_node.len() >= MAX_GATE_LINKS {
                self.error(
                    span,
                    format!(
                        "gate `{name}` would be the {}th gate connection of port `{}`'s node; a node has room for {MAX_GATE_LINKS}",
                        on_node.len() + 1,
                        entry.name
                    ),
                );
                continue;
            }
            if !sources.contains(&group) {
                let mut distinct = sources.clone();
                distinct.sort_unstable();
                distinct.dedup();
                if distinct.len() >= MAX_GATE_SOURCES {
                    self.error(
                        span,
                        format!(
                            "gate `{name}`: port `{}`'s node would read the gates of more than {MAX_GATE_SOURCES} dynamics groups, the most a node keeps",
                            entry.name
                        ),
                    );
                    continue;
                }
            }
            let Ok(stimulation) = Stimulation::new(pab_core::Gain::ONE, 100_000, 0) else {
                continue;
            };
            let Some(entry) = ports.get_mut(port) else {
                continue;
            };
            let span = groups.get(group).map_or(span, |g| g.span.clone());
            entry.connections.push(connections.len());
            connections.push(Connection {
                name,
                kind: Kind::Gate,
                inhibits: None,
                topic: NO_TOPIC,
                port,
                index,
                sigma: 1.0,
                tau: GATE_TAU_S,
                rest: 0.0,
                stimulation,
                rule: Rule::Constant(false),
                rule_text: "false".to_string(),
                rule_written: false,
                rule_span: span.clone(),
                span,
            });
        }
    }
}
