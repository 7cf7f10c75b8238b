//! Connection kinds as rules: what a port's suppressors, inhibitors, overriders and
//! write-inhibitors make of its connections' written rules.
//!
//! Every special connection is an ordinary connection of its port (σ = 1, τ = period, τr = 0: a
//! frame makes it active until `period` has passed without one) whose activity x appears in the
//! rules the port compiles. With R_c the written rule of connection c (default: its own x):
//!
//! ```text
//! passes(c)  = x_c ∧ R_c ∧ ¬(an inhibit or write-inhibit of c's topic at the port is active)
//!                        ∧ ¬(a suppressor of the port is active)
//! overrider O_k delivers  iff passes(O_k) ∧ no overrider O_j declared before it passes
//! normal c delivers       iff passes(c)   ∧ no overrider passes
//! suppress, inhibit, write-inhibit: never deliver
//! ```
//!
//! So an overrider subsumes the layers below it exactly when it delivers itself: a layer that is
//! write-inhibited, inhibited, or whose own rule holds it back (a BLE group held elsewhere, say)
//! leaves the port to the next layer down. With R = true this is DESIGN.md's
//! `x_k ∧ ¬W_k ∧ no j < k has x_j ∧ ¬W_j`.
//!
//! The result is plain rules over the port's connections: [`crate::check`] proves them and
//! [`crate::compile`] turns them into the same decision tables as any port. A port without special
//! connections keeps its written rules unchanged.

use crate::network::{Kind, Network};
use crate::rule::Rule;

/// The rule Φ_c each connection of port `port` is compiled with, in the port's order: the
/// written rule combined with the port's special connections as the module describes. Costs one
/// pass over the port's connections per connection (at most 32 × 32).
pub fn port_rules(network: &Network, port: usize) -> Vec<Rule> {
    let connections: Vec<_> = network.port_connections(port).collect();
    if connections.iter().all(|c| c.kind == Kind::Normal) {
        return connections.iter().map(|c| c.rule.clone()).collect();
    }
    let suppressors: Vec<usize> = connections
        .iter()
        .filter(|c| c.kind == Kind::Suppress)
        .map(|c| c.index)
        .collect();
    // passes(c) of connection `c` (by index in the port), or `None` for those that never deliver.
    let passes = |index: usize| -> Option<Rule> {
        let connection = connections.get(index)?;
        if !connection.kind.delivers() {
            return None;
        }
        let mut all = vec![Rule::Active(index), connection.rule.clone()];
        let blockers = connections.iter().filter(|other| {
            matches!(other.kind, Kind::Inhibit | Kind::WriteInhibit)
                && other.inhibits == Some(connection.topic)
        });
        all.extend(blockers.map(|other| not(other.index)));
        all.extend(suppressors.iter().map(|&s| not(s)));
        Some(Rule::And(all))
    };
    let overriders: Vec<usize> = connections
        .iter()
        .filter(|c| c.kind == Kind::Override)
        .map(|c| c.index)
        .collect();
    connections
        .iter()
        .map(|connection| {
            let Some(own) = passes(connection.index) else {
                return Rule::Constant(false);
            };
            // The overriders that subsume this connection when they deliver: all of them for a
            // normal connection, those declared before it for an overrider.
            let above = overriders
                .iter()
                .copied()
                .filter(|&o| match connection.kind {
                    Kind::Override => o < connection.index,
                    _ => true,
                });
            let mut all = vec![own];
            all.extend(above.filter_map(passes).map(|p| Rule::Not(Box::new(p))));
            Rule::And(all)
        })
        .collect()
}

fn not(index: usize) -> Rule {
    Rule::Not(Box::new(Rule::Active(index)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;

    /// A port `n.p` with connections `(name, kind, extra keys)` on topics t1, t2, ... in order.
    fn network(connections: &[(&str, &str, &str)]) -> Network {
        let mut text = String::from("[nodes.n]\nid = 1\n[ports.\"n.p\"]\n");
        for (k, (name, kind, extra)) in connections.iter().enumerate() {
            let topic = k + 1;
            text += &format!("[topics.t{topic}]\ncan_id = {topic}\n");
            text += &format!("[connections.{name}]\ntopic = \"t{topic}\"\n{extra}\n");
            if *kind == "normal" {
                text += "port = \"n.p\"\nst = 1\ntc = 1\n";
            } else {
                if *kind != "inhibit" {
                    text += "port = \"n.p\"\n";
                }
                text += &format!("kind = \"{kind}\"\nperiod = 0.5\n");
            }
        }
        Network::parse(Source::new("net.toml", text)).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Who delivers under `mask` (bit i: the port's connection i), by the compiled rules.
    fn winners(network: &Network, mask: u64) -> Vec<String> {
        network
            .port_connections(0)
            .zip(port_rules(network, 0))
            .filter(|(c, rule)| mask & (1 << c.index) != 0 && rule.eval(mask))
            .map(|(c, _)| c.name.clone())
            .collect()
    }

    #[test]
    fn ports_without_special_connections_keep_their_rules() {
        let net = network(&[("A", "normal", "rule = \"A & !B\""), ("B", "normal", "")]);
        assert_eq!(
            port_rules(&net, 0),
            vec![
                net.connections[0].rule.clone(),
                net.connections[1].rule.clone()
            ]
        );
    }

    #[test]
    fn a_suppressor_blocks_everything_and_never_delivers() {
        let net = network(&[
            ("O", "override", ""),
            ("C", "normal", ""),
            ("S", "suppress", ""),
            ("S2", "suppress", ""),
        ]);
        for mask in 0..16u64 {
            let suppressed = mask & 0b1100 != 0;
            let expected: Vec<&str> = match (suppressed, mask & 1 != 0, mask & 2 != 0) {
                (true, _, _) | (false, false, false) => vec![],
                (false, true, _) => vec!["O"],
                (false, false, true) => vec!["C"],
            };
            assert_eq!(winners(&net, mask), expected, "mask {mask:#06b}");
        }
    }

    #[test]
    fn an_overrider_subsumes_lower_layers_exactly_when_it_delivers() {
        // Layers O1 > O2 > C (normal, bottom); W write-inhibits O2's topic (t2).
        let net = network(&[
            ("O1", "override", ""),
            ("O2", "override", ""),
            ("C", "normal", ""),
            ("W", "write-inhibit", "inhibits = \"t2\""),
        ]);
        let (o1, o2, c, w) = (1, 2, 4, 8);
        assert_eq!(winners(&net, o1 | o2 | c), ["O1"]);
        assert_eq!(winners(&net, o2 | c), ["O2"]);
        // O2 write-inhibited: it neither delivers nor subsumes C.
        assert_eq!(winners(&net, o2 | c | w), ["C"]);
        // ... but O1 still subsumes C.
        assert_eq!(winners(&net, o1 | o2 | c | w), ["O1"]);
        assert_eq!(winners(&net, o2 | w), Vec::<String>::new());
        assert_eq!(winners(&net, w | c), ["C"]);
    }

    #[test]
    fn an_overriders_own_rule_decides_whether_it_subsumes() {
        // O1 delivers only while G (a normal connection standing for a condition) is inactive:
        // while G is active, O1 passes nothing and leaves the port to O2.
        let net = network(&[
            ("O1", "override", "rule = \"O1 & !G\""),
            ("O2", "override", ""),
            ("G", "normal", "rule = \"false\""),
        ]);
        assert_eq!(winners(&net, 0b011), ["O1"]);
        assert_eq!(winners(&net, 0b111), ["O2"]);
    }

    #[test]
    fn an_inhibitor_blocks_its_topic_only() {
        let net = network(&[
            ("A", "normal", "rule = \"A & !B\""),
            ("B", "normal", ""),
            ("I", "inhibit", "inhibits = \"t2\""),
        ]);
        // I is the port's third connection (added after the written ones).
        assert_eq!(net.connections[2].name, "I");
        assert_eq!(net.connections[2].index, 2);
        assert_eq!(winners(&net, 0b010), ["B"]);
        assert_eq!(winners(&net, 0b110), Vec::<String>::new());
        assert_eq!(winners(&net, 0b101), ["A"]);
        // A yields to B by its written rule even while B is inhibited.
        assert_eq!(winners(&net, 0b111), Vec::<String>::new());
    }
}
