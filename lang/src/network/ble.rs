//! `[ble.NAME]`: Broadcast of Local Eligibility peer groups (docs/ayllu.md,
//! "Broadcast of Local Eligibility"), and the claim connections their names become in rules.
//!
//! A group is one task shared by its nodes. A rule that names the group (`rule = "OBS11 &
//! observe_t1"`) reads "this node holds the task": the port gets one more connection, a
//! [`Kind::Claim`] named after the group, after its own connections. No frame feeds it (the
//! table gives it `pab_core::ble::CLAIM_SLOT_FILTER`); the node's group state sets it. So the
//! claim is an ordinary variable for the checker, and the boards' arbiter needs nothing new at
//! the port.

use std::ops::Range;

use super::spanned::Spanned;
use indexmap::IndexMap;
use pab_core::ble::{EligibilityField, MAX_GROUP_PORTS, MAX_GROUPS, MAX_PEERS, MAX_PERIOD_US};
use pab_core::{Endian, MAX_CONNECTIONS_PER_PORT, Stimulation};
use schemars::JsonSchema;
use serde::Deserialize;

use super::connections::RawConnection;
use super::ports::RawField;
use super::{Builder, Connection, Kind, Node, Port, Topic, list_or_none};
use crate::rule::{self, Rule};
use crate::shown;

/// `[ble.NAME] period = 0.1, value = { offset = 0, size = 2 }` and `[ble.NAME.nodes] r1 =
/// "TOPIC", ...`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBle {
    /// Required: seconds between a node's claims, whole microseconds in (0, 3600].
    #[schemars(required)]
    period: Option<Spanned<f64>>,
    /// Required: where each node's eligibility is in its topic's frames: size 1 or 2 bytes,
    /// unsigned; endian "little" (default) or "big".
    #[schemars(required)]
    value: Option<Spanned<RawField>>,
    /// Its nodes (2 to 8): node = the topic that carries its own eligibility for the task (a
    /// node may be in at most 4 groups).
    #[serde(default)]
    nodes: IndexMap<Spanned<String>, Spanned<String>>,
}

/// A BLE peer group: one task, one behaviour instance per node.
#[derive(Clone, Debug)]
pub struct BleGroup {
    /// Its name, usable in the rules of its nodes' ports.
    pub name: String,
    /// Its number on the bus (byte 0 of its claims): its position among the file's groups.
    pub number: u8,
    /// The broadcast period, seconds, as written.
    pub period: f64,
    /// The broadcast period, µs.
    pub period_us: u32,
    /// Where each node's eligibility is in the frames of its topic.
    pub field: EligibilityField,
    /// Its nodes, in file order.
    pub members: Vec<BleMember>,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// A node of a BLE group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BleMember {
    /// The node, as an index into [`super::Network::nodes`].
    pub node: usize,
    /// The topic that carries its own eligibility, as an index into [`super::Network::topics`].
    pub topic: usize,
}

impl BleGroup {
    /// The member that node `node` (index into the network's nodes) is, if any.
    pub fn member(&self, node: usize) -> Option<&BleMember> {
        self.members.iter().find(|m| m.node == node)
    }
}

impl Builder<'_> {
    /// The `[ble.*]` sections, numbered in file order; a name that a connection already has is
    /// refused (rules could not tell them apart).
    pub(super) fn ble_groups(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawBle>>,
        nodes: &[Node],
        topics: &[Topic],
        connection_names: &[&str],
    ) -> Vec<BleGroup> {
        let mut groups: Vec<BleGroup> = Vec::new();
        for (position, (name, group)) in raw.iter().enumerate() {
            let text = name.get_ref();
            if !self.printable(name, "BLE group name") {
                continue;
            }
            if !rule::is_valid_name(text) {
                self.error(
                    name.span(),
                    format!(
                        "BLE group name `{text}` cannot be used in rules: start with a letter or `_`, then letters, digits, `_`"
                    ),
                );
                continue;
            }
            if connection_names.contains(&text.as_str()) {
                self.error(
                    name.span(),
                    format!(
                        "BLE group `{text}` has the name of a connection: rules name both, so give them different names"
                    ),
                );
                continue;
            }
            let Ok(number) = u8::try_from(position) else {
                self.error(
                    name.span(),
                    "more than 256 BLE groups: a claim numbers its group in one byte",
                );
                continue;
            };
            let raw_group = group.get_ref();
            let period = self.ble_period(raw_group, group.span(), text);
            let field = self.ble_field(raw_group, group.span(), text);
            let members = self.ble_members(raw_group, group.span(), text, nodes, topics);
            let (Some((period, period_us)), Some(field), Some(members)) = (period, field, members)
            else {
                continue;
            };
            groups.push(BleGroup {
                name: text.clone(),
                number,
                period,
                period_us,
                field,
                members,
                span: group.span(),
            });
        }
        self.ble_capacities(&groups, nodes);
        groups
    }

    fn ble_period(&mut self, raw: &RawBle, span: Range<usize>, name: &str) -> Option<(f64, u32)> {
        let Some(period) = &raw.period else {
            self.error(
                span,
                format!(
                    "missing field `period`: BLE group `{name}` broadcasts every `period = SECONDS` (0.1 is typical)"
                ),
            );
            return None;
        };
        let seconds = *period.get_ref();
        let max = f64::from(MAX_PERIOD_US) / 1e6;
        let micros = (seconds * 1e6).round();
        if !(seconds.is_finite() && micros >= 1.0 && micros <= f64::from(MAX_PERIOD_US)) {
            self.error(
                period.span(),
                format!("period {seconds}: a BLE period is whole microseconds in [0.000001, {max}] seconds"),
            );
            return None;
        }
        Some((seconds, micros as u32))
    }

    /// `value = { offset, size, endian }`: an unsigned eligibility of 1 or 2 bytes.
    fn ble_field(
        &mut self,
        raw: &RawBle,
        span: Range<usize>,
        name: &str,
    ) -> Option<EligibilityField> {
        let Some(value) = &raw.value else {
            self.error(
                span,
                format!(
                    "missing field `value`: where BLE group `{name}`'s eligibility is in its nodes' frames, e.g. `value = {{ offset = 0, size = 2 }}`"
                ),
            );
            return None;
        };
        let field = value.get_ref();
        let size = *field.size.get_ref();
        if !matches!(size, 1 | 2) {
            self.error(
                field.size.span(),
                format!("value: size = {size}: an eligibility is 1 or 2 bytes (0 to 65535)"),
            );
            return None;
        }
        if field.signed {
            self.error(
                value.span(),
                "value: an eligibility is unsigned (0: not a candidate); remove `signed = true`",
            );
            return None;
        }
        let field = self.field(value, "value")?;
        Some(EligibilityField {
            offset: field.offset,
            size: field.size,
            big_endian: field.endian == Endian::Big,
        })
    }

    fn ble_members(
        &mut self,
        raw: &RawBle,
        span: Range<usize>,
        name: &str,
        nodes: &[Node],
        topics: &[Topic],
    ) -> Option<Vec<BleMember>> {
        let mut members: Vec<BleMember> = Vec::new();
        let mut ok = true;
        for (node_name, topic_name) in &raw.nodes {
            let Some(node) = nodes.iter().position(|n| &n.name == node_name.get_ref()) else {
                let known: Vec<&str> = nodes.iter().map(|n| n.name.as_str()).collect();
                self.error(
                    node_name.span(),
                    format!(
                        "BLE group `{name}`: node `{}` is not defined (nodes: {})",
                        shown::escaped(node_name.get_ref()),
                        list_or_none(&known)
                    ),
                );
                ok = false;
                continue;
            };
            let Some(topic) = self.topic_index(topic_name, topics) else {
                ok = false;
                continue;
            };
            members.push(BleMember { node, topic });
        }
        if !ok {
            return None;
        }
        if members.len() < 2 {
            self.error(
                span,
                format!(
                    "BLE group `{name}` has {} node{}: a task is shared by two or more; list them under [ble.{name}.nodes] (node = \"its eligibility topic\")",
                    members.len(),
                    if members.len() == 1 { "" } else { "s" }
                ),
            );
            return None;
        }
        if members.len() > MAX_PEERS + 1 {
            self.error(
                span,
                format!(
                    "BLE group `{name}` has {} nodes, more than {} (a node keeps the claims of at most {MAX_PEERS} peers)",
                    members.len(),
                    MAX_PEERS + 1
                ),
            );
            return None;
        }
        Some(members)
    }

    /// Each node in at most [`MAX_GROUPS`] groups.
    fn ble_capacities(&mut self, groups: &[BleGroup], nodes: &[Node]) {
        for (index, node) in nodes.iter().enumerate() {
            let mine: Vec<&BleGroup> = groups
                .iter()
                .filter(|g| g.member(index).is_some())
                .collect();
            if let Some(extra) = mine.get(MAX_GROUPS) {
                self.error(
                    extra.span.clone(),
                    format!(
                        "node `{}` is in more than {MAX_GROUPS} BLE groups (a node keeps the state of at most {MAX_GROUPS})",
                        node.name
                    ),
                );
            }
        }
    }

    /// Adds a claim connection, named after the group, to every port with a rule that names a
    /// group its node is in, in the order the rules first name them. A rule that names a group
    /// its node is not in is reported when the rules are resolved.
    pub(super) fn claims(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawConnection>>,
        groups: &[BleGroup],
        connections: &mut Vec<Connection>,
        ports: &mut [Port],
    ) {
        if groups.is_empty() {
            return;
        }
        let mut wanted: Vec<(usize, usize, Range<usize>)> = Vec::new(); // (port, group, rule span)
        for connection in connections.iter() {
            let Some((_, written)) = raw.get_key_value(connection.name.as_str()) else {
                continue;
            };
            let Some(text) = &written.get_ref().rule else {
                continue;
            };
            let Some(node) = ports.get(connection.port).map(|p| p.node) else {
                continue;
            };
            let named = std::cell::RefCell::new(Vec::new());
            let record = |name: &str| -> Result<usize, String> {
                if let Some(group) = groups
                    .iter()
                    .position(|g| g.name == name && g.member(node).is_some())
                {
                    named.borrow_mut().push(group);
                }
                Ok(0)
            };
            // Syntax errors are reported when the rules are resolved.
            let _ = rule::parse(text.get_ref(), &record);
            for group in named.into_inner() {
                if !wanted
                    .iter()
                    .any(|(p, g, _)| *p == connection.port && *g == group)
                {
                    wanted.push((connection.port, group, text.span()));
                }
            }
        }
        for (port, group, span) in wanted {
            let Some(node) = ports.get(port).map(|p| p.node) else {
                continue;
            };
            let on_node = connections
                .iter()
                .filter(|c| c.kind == Kind::Claim)
                .filter(|c| groups.get(group).is_some_and(|g| g.name == c.name))
                .filter(|c| ports.get(c.port).is_some_and(|p| p.node == node))
                .count();
            let (Some(entry), Some(group)) = (ports.get_mut(port), groups.get(group)) else {
                continue;
            };
            let Some(member) = group.member(entry.node) else {
                continue;
            };
            let index = entry.connections.len();
            if index >= MAX_CONNECTIONS_PER_PORT {
                self.error(
                    span,
                    format!(
                        "naming BLE group `{}` adds its claim to port `{}` as one more connection, but that port already has {MAX_CONNECTIONS_PER_PORT} connections, the most a port may have",
                        group.name, entry.name
                    ),
                );
                continue;
            }
            if on_node >= MAX_GROUP_PORTS {
                self.error(
                    span,
                    format!(
                        "BLE group `{}` is named at more than {MAX_GROUP_PORTS} ports of one node (a node gates at most {MAX_GROUP_PORTS} ports by a group)",
                        group.name
                    ),
                );
                continue;
            }
            // σ = 1 and τ = the period: never used (no frame feeds a claim), but a valid
            // connection for the table, and a τ that does not lengthen a simulation.
            let Ok(stimulation) = Stimulation::new(pab_core::Gain::ONE, group.period_us, 0) else {
                continue;
            };
            entry.connections.push(connections.len());
            connections.push(Connection {
                name: group.name.clone(),
                kind: Kind::Claim,
                inhibits: None,
                topic: member.topic,
                port,
                index,
                sigma: 1.0,
                tau: group.period,
                rest: 0.0,
                stimulation,
                rule: Rule::Constant(false),
                rule_text: "false".to_string(),
                rule_written: false,
                rule_span: group.span.clone(),
                span: group.span.clone(),
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::diagnostic::Source;
    use crate::network::{Kind, Network};

    const BASE: &str = r#"
[nodes.r1]
id = 1
[nodes.r2]
id = 2
[nodes.r3]
id = 3
[topics.obs_1]
can_id = 0x111
[topics.obs_2]
can_id = 0x121
[ports."r1.drive"]
[ports."r2.drive"]
[connections.OBS1]
topic = "obs_1"
port = "r1.drive"
st = 1.0
tc = 0.3
rule = "OBS1 & task"
[connections.OBS2]
topic = "obs_2"
port = "r2.drive"
st = 1.0
tc = 0.3
rule = "OBS2 & task"
"#;

    fn parse(extra: &str) -> Result<Network, String> {
        Network::parse(Source::new("ble.toml", format!("{BASE}{extra}"))).map_err(|e| e.to_string())
    }

    fn error(extra: &str) -> String {
        match parse(extra) {
            Ok(_) => panic!("accepted:\n{extra}"),
            Err(message) => message,
        }
    }

    #[test]
    fn a_group_adds_its_claim_to_the_ports_whose_rules_name_it() {
        let network =
            parse("[ble.task]\nperiod = 0.1\nvalue = { offset = 2, size = 2, endian = \"big\" }\n[ble.task.nodes]\nr1 = \"obs_1\"\nr2 = \"obs_2\"\n")
                .unwrap();
        let group = &network.groups[0];
        assert_eq!((group.number, group.period_us), (0, 100_000));
        assert_eq!(
            (group.field.offset, group.field.size, group.field.big_endian),
            (2, 2, true)
        );
        for port in 0..2 {
            let names: Vec<(String, Kind)> = network
                .port_connections(port)
                .map(|c| (c.name.clone(), c.kind))
                .collect();
            assert_eq!(names[1], ("task".to_string(), Kind::Claim));
            assert_eq!(names.len(), 2);
        }
    }

    #[test]
    fn mistakes_are_reported_at_their_line_with_their_cause() {
        let nodes = "[ble.task.nodes]\nr1 = \"obs_1\"\nr2 = \"obs_2\"\n";
        for (extra, expected) in [
            (
                format!("[ble.task]\nvalue = {{ offset = 0, size = 2 }}\n{nodes}"),
                "missing field `period`",
            ),
            (
                format!("[ble.task]\nperiod = 0\nvalue = {{ offset = 0, size = 2 }}\n{nodes}"),
                "a BLE period is whole microseconds",
            ),
            (
                format!("[ble.task]\nperiod = 0.1\nvalue = {{ offset = 0, size = 4 }}\n{nodes}"),
                "an eligibility is 1 or 2 bytes",
            ),
            (
                format!("[ble.task]\nperiod = 0.1\nvalue = {{ offset = 7, size = 2 }}\n{nodes}"),
                "beyond the 8 bytes",
            ),
            (
                format!("[ble.task]\nperiod = 0.1\nvalue = {{ offset = 0, size = 2, signed = true }}\n{nodes}"),
                "an eligibility is unsigned",
            ),
            (
                format!("[ble.task]\nperiod = 0.1\n{nodes}"),
                "missing field `value`",
            ),
            (
                "[ble.task]\nperiod = 0.1\nvalue = { offset = 0, size = 2 }\n[ble.task.nodes]\nr1 = \"obs_1\"\n".to_string(),
                "has 1 node: a task is shared by two or more",
            ),
            (
                "[ble.task]\nperiod = 0.1\nvalue = { offset = 0, size = 2 }\n[ble.task.nodes]\nr1 = \"obs_1\"\nr9 = \"obs_2\"\n".to_string(),
                "node `r9` is not defined",
            ),
            (
                "[ble.task]\nperiod = 0.1\nvalue = { offset = 0, size = 2 }\n[ble.task.nodes]\nr1 = \"obs_1\"\nr2 = \"nope\"\n".to_string(),
                "topic `nope` is not defined",
            ),
            (
                // r2's rule names `task`, but only r1 and r3 are in it.
                "[ble.task]\nperiod = 0.1\nvalue = { offset = 0, size = 2 }\n[ble.task.nodes]\nr1 = \"obs_1\"\nr3 = \"obs_2\"\n".to_string(),
                "`task` is a BLE group that node `r2` is not in (its nodes: r1, r3)",
            ),
            (
                "[ble.OBS1]\nperiod = 0.1\nvalue = { offset = 0, size = 2 }\n[ble.OBS1.nodes]\nr1 = \"obs_1\"\nr2 = \"obs_2\"\n".to_string(),
                "has the name of a connection",
            ),
            (
                format!("[ble.task]\nperiod = 0.1\nvalue = {{ offset = 0, size = 2 }}\nwho = 1\n{nodes}"),
                "unknown key `who`",
            ),
        ] {
            let message = error(&extra);
            assert!(message.contains(expected), "{expected:?} not in:\n{message}");
            assert!(message.starts_with("ble.toml:"), "{message}");
        }
    }

    #[test]
    fn a_node_is_in_at_most_four_groups() {
        let mut extra = String::new();
        for k in 0..5 {
            extra.push_str(&format!(
                "[ble.g{k}]\nperiod = 0.1\nvalue = {{ offset = 0, size = 1 }}\n[ble.g{k}.nodes]\nr1 = \"obs_1\"\nr2 = \"obs_2\"\n"
            ));
        }
        extra.push_str("[ble.task]\nperiod = 0.1\nvalue = { offset = 0, size = 1 }\n[ble.task.nodes]\nr1 = \"obs_1\"\nr2 = \"obs_2\"\n");
        let message = error(&extra);
        assert!(
            message.contains("node `r1` is in more than 4 BLE groups"),
            "{message}"
        );
    }
}
