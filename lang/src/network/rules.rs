//! Each connection's `rule = "..."`: parsed over the connections of its port, where a name may
//! also be a BLE group the node is in or a dynamics behaviour's gate; a mistake is reported at
//! its column inside the rule.

use indexmap::IndexMap;

use super::connections::RawConnection;
use super::spanned::Spanned;
use super::{BleGroup, Builder, Connection, DynamicsGroup, Node, Port, gates, suggest};
use crate::rule;
use crate::shown;

/// How much of a rule's text a message repeats (characters); longer rules are shortened with `…`.
pub const RULE_EXCERPT: usize = 80;

impl Builder<'_> {
    pub(super) fn rules(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawConnection>>,
        connections: &mut [Connection],
        ports: &[Port],
        groups: &[BleGroup],
        dynamics: &[DynamicsGroup],
        nodes: &[Node],
    ) {
        for connection_index in 0..connections.len() {
            let Some(connection) = connections.get(connection_index) else {
                continue;
            };
            let Some((_, raw_connection)) = raw.get_key_value(connection.name.as_str()) else {
                continue;
            };
            let Some(rule) = &raw_connection.get_ref().rule else {
                continue;
            };
            let Some(port) = ports.get(connection.port) else {
                continue;
            };
            let names: Vec<(String, usize)> = port
                .connections
                .iter()
                .filter_map(|&index| connections.get(index))
                .map(|c| (c.name.clone(), c.index))
                .collect();
            let port_name = port.name.clone();
            let port_node = port.node;
            let declared = &self.declared.connections;
            let resolve = |name: &str| -> Result<usize, String> {
                if let Some((_, index)) = names.iter().find(|(n, _)| n == name) {
                    return Ok(*index);
                }
                if declared.contains(name) && !connections.iter().any(|c| c.name == name) {
                    // Declared but refused (its own error says why): no mistake of this rule's.
                    return Err(String::new());
                }
                if gates::split(name).is_some() {
                    return Err(gates::unknown(dynamics, name));
                }
                if let Some(group) = groups.iter().find(|g| g.name == name) {
                    let node = nodes.get(port_node).map_or("?", |n| n.name.as_str());
                    let members: Vec<&str> = group
                        .members
                        .iter()
                        .filter_map(|m| nodes.get(m.node).map(|n| n.name.as_str()))
                        .collect();
                    return Err(format!(
                        "`{name}` is a BLE group that node `{node}` is not in (its nodes: {}): add `{node} = \"TOPIC\"` to [ble.{name}.nodes], TOPIC carrying its eligibility",
                        members.join(", ")
                    ));
                }
                let elsewhere = connections.iter().find(|c| c.name == name).map(|c| c.port);
                let listed: Vec<&str> = names.iter().map(|(n, _)| n.as_str()).collect();
                Err(match elsewhere.and_then(|port| ports.get(port)) {
                    Some(other) => format!(
                        "`{name}` is a connection of port `{}`, not of `{port_name}`: a rule may only name connections of its own port ({})",
                        other.name,
                        listed.join(", ")
                    ),
                    None => format!(
                        "unknown connection `{name}`; the connections of port `{port_name}` are {}{}",
                        listed.join(", "),
                        suggest(name, &listed)
                    ),
                })
            };
            let text = rule.get_ref();
            let parsed = rule::parse(text, &resolve);
            // The value's span includes its opening quote; rule offsets count from the text.
            let text_start = rule.span().start + 1;
            match parsed {
                Ok(parsed) => {
                    if let Some(connection) = connections.get_mut(connection_index) {
                        connection.rule = parsed;
                        connection.rule_text = text.clone();
                        connection.rule_written = true;
                        connection.rule_span = rule.span();
                    }
                }
                // A cascade of a refused connection: reported at its declaration.
                Err(error) if error.message.is_empty() => {}
                Err(error) => {
                    let at = text_start + error.offset;
                    self.error(
                        at..at,
                        format!(
                            "in rule \"{}\": {}",
                            shown::excerpt(text, RULE_EXCERPT),
                            error.message
                        ),
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::network::tests::{FIGURE_1, errors};

    #[test]
    fn rule_errors_point_inside_the_rule() {
        let text = FIGURE_1.replace("rule = \"C1 & !C2\"", "rule = \"C1 & !C7\"");
        let errors = errors(&text);
        assert_eq!(errors.len(), 1);
        // Line 18 is the rule (the text starts with a newline); `C7` starts at column 15.
        assert!(
            errors[0].starts_with("net.toml:18:15: error: in rule \"C1 & !C7\": unknown connection `C7`; the connections of port `gaze.target` are C1, C2"),
            "{}",
            errors[0]
        );
    }

    #[test]
    fn rules_may_only_name_their_own_port() {
        let text = format!(
            "{FIGURE_1}\n[ports.\"gaze.other\"]\n[connections.C3]\ntopic = \"face_pos\"\nport = \"gaze.other\"\nst = 1\ntc = 1\nrule = \"C3 & !C1\"\n"
        );
        let errors = errors(&text);
        assert!(
            errors[0].contains("`C1` is a connection of port `gaze.target`, not of `gaze.other`"),
            "{errors:?}"
        );
    }
}
