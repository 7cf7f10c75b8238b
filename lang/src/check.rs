//! The consistency proof of a network's rules, port by port, with binary decision diagrams.
//!
//! For a port with connections 0..n, connection i delivers in the activity masks of
//! D_i = x_i ∧ Φ_i(x). The port is consistent when:
//!
//! - no two connections can deliver under the same mask: D_i ∧ D_j = ∅ for every i < j. A failure
//!   comes with a counterexample mask, made minimal (no active connection can be dropped from it
//!   without the overlap disappearing), so it reads as the smallest situation that goes wrong;
//! - no connection whose rule is written otherwise than `false` is dead: D_i ≠ ∅.
//!
//! For information, it reports the masks in which nothing delivers (the port's consumer hears
//! nobody), with minimal examples among those where some connection is active.
//!
//! A value port (`combine = ...`) combines every connection its rules let through: several
//! contribute at once by design, so the at-most-one proof is skipped there; dead rules are still
//! reported.
//!
//! Why BDDs: each D_i is built once in time linear in its rule; the pairwise conjunctions and the
//! counts are then cheap even with 32 connections (2^32 masks) on a port.

use std::fmt::Write as _;

/// The bus's frame streams and their response times at the network's bit rate.
pub mod bus;
/// Warnings about connections and the network as a whole (`pabctl check` prints them).
pub mod connections;
/// Warnings about `[dynamics.*]` groups (`pabctl check` prints them; they fail nothing).
pub mod dynamics;
/// Worst-case response times of CAN frame streams (Davis et al. 2007), in bit times.
pub mod response;

use biodivine_lib_bdd::{Bdd, BddValuation, BddVariable, BddVariableSet};

use crate::diagnostic::Diagnostic;
use crate::kinds;
use crate::network::{Connection, Kind, Network, RULE_EXCERPT, combine_name};
use crate::rule::Rule;
use crate::shown;

/// The logic of one port: a BDD variable per connection (in the port's order) and, per
/// connection, the set D_i of masks in which it delivers.
pub struct PortLogic {
    /// One variable per connection, named after it.
    pub variables: BddVariableSet,
    /// D_i = x_i ∧ Φ_i ∧ ¬impossible, in the port's order.
    pub delivers: Vec<Bdd>,
    /// The pairs of gate connections (port indices) that are never active together: two
    /// behaviours of one group that exclude each other with γ ≥ [`EXCLUSIVE_GAMMA`] both ways.
    /// In a mask with both, nobody delivers (it cannot happen; if noise ever made it happen,
    /// the port would stay silent rather than deliver twice).
    pub exclusive: Vec<(usize, usize)>,
}

/// γ at which two gates are taken as never open together, both ways (DESIGN.md: while
/// n_j² ≥ 0.4, d(n_i²)/dt ≤ 2 n_i² (1 − γ_ij · 0.4)/τ < 0 once γ_ij > 2.5). The argument leaves
/// the noise out: the core's property test holds at the default noise and up to 100 times it; at
/// 200 times, both gates opened in 3 of 40 seeds at γ = 2.5.
pub const EXCLUSIVE_GAMMA: f64 = 2.5;

/// The pairs of gate connections of port `port` that exclude each other with γ ≥
/// [`EXCLUSIVE_GAMMA`] both ways.
fn exclusive_gates(network: &Network, port: usize) -> Vec<(usize, usize)> {
    let gates: Vec<(usize, (usize, usize))> = network
        .port_connections(port)
        .filter(|c| c.kind == Kind::Gate)
        .filter_map(|c| Some((c.index, crate::network::gate(&network.dynamics, &c.name)?)))
        .collect();
    let gamma = |g: usize, i: usize, j: usize| {
        network.dynamics.get(g).map_or(0.0, |group| {
            group
                .params
                .exclusions
                .iter()
                .filter(|e| usize::from(e.behaviour) == i && usize::from(e.by) == j)
                .map(|e| f64::from(e.gamma) / f64::from(pab_core::dynamics::GAMMA_ONE))
                .sum()
        })
    };
    let mut pairs = Vec::new();
    for (k, &(a, (ga, ba))) in gates.iter().enumerate() {
        for &(b, (gb, bb)) in gates.iter().skip(k + 1) {
            if ga == gb
                && gamma(ga, ba, bb) >= EXCLUSIVE_GAMMA
                && gamma(ga, bb, ba) >= EXCLUSIVE_GAMMA
            {
                pairs.push((a, b));
            }
        }
    }
    pairs
}

impl PortLogic {
    /// Builds the logic of port `port` of `network`, its special connections compiled in
    /// ([`crate::kinds::port_rules`]).
    pub fn new(network: &Network, port: usize) -> PortLogic {
        let names = network.port_connection_names(port);
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let variables = BddVariableSet::new(&refs);
        let mut logic = PortLogic {
            variables,
            delivers: Vec::new(),
            exclusive: exclusive_gates(network, port),
        };
        let impossible = logic.impossible();
        let variables = &logic.variables;
        let delivers = network
            .port_connections(port)
            .zip(kinds::port_rules(network, port))
            .map(|(connection, rule)| {
                let own = variables.mk_var(BddVariable::from_index(connection.index));
                own.and(&to_bdd(&rule, variables)).and_not(&impossible)
            })
            .collect();
        logic.delivers = delivers;
        logic
    }

    /// The number of connections.
    pub fn len(&self) -> usize {
        self.delivers.len()
    }

    /// Whether the port has no connections.
    pub fn is_empty(&self) -> bool {
        self.delivers.is_empty()
    }

    /// The masks that cannot happen: two exclusive gates open together.
    pub fn impossible(&self) -> Bdd {
        self.exclusive
            .iter()
            .fold(self.variables.mk_false(), |all, &(a, b)| {
                let both = self
                    .variables
                    .mk_var(BddVariable::from_index(a))
                    .and(&self.variables.mk_var(BddVariable::from_index(b)));
                all.or(&both)
            })
    }

    /// The masks in which some connection delivers.
    pub fn anyone(&self) -> Bdd {
        self.delivers
            .iter()
            .fold(self.variables.mk_false(), |all, d| all.or(d))
    }

    fn mask_of(&self, valuation: &BddValuation) -> u32 {
        self.variables
            .variables()
            .into_iter()
            .filter(|&variable| valuation.value(variable))
            .fold(0, |mask, variable| mask | 1u32 << variable.to_index())
    }

    /// A satisfying mask of `set`, made minimal by clearing active connections one by one while
    /// the mask stays in the set.
    fn minimal_mask(&self, set: &Bdd) -> Option<u32> {
        let mut valuation = set.sat_witness()?;
        for variable in self.variables.variables() {
            if valuation.value(variable) {
                valuation.clear(variable);
                if !set.eval_in(&valuation) {
                    valuation.set(variable);
                }
            }
        }
        Some(self.mask_of(&valuation))
    }

    /// The set of masks that contain every connection of `mask`.
    fn supersets(&self, mask: u32) -> Bdd {
        self.variables
            .variables()
            .into_iter()
            .filter(|variable| mask & (1 << variable.to_index()) != 0)
            .fold(self.variables.mk_true(), |all, variable| {
                all.and(&self.variables.mk_var(variable))
            })
    }
}

/// A rule as a BDD over the port's variables. Recurses once per level of the rule's tree (see
/// [`crate::rule::MAX_DEPTH`]); long `&` and `|` chains are folded in a loop.
pub fn to_bdd(rule: &Rule, variables: &BddVariableSet) -> Bdd {
    match rule {
        Rule::Constant(true) => variables.mk_true(),
        Rule::Constant(false) => variables.mk_false(),
        Rule::Active(index) => variables.mk_var(BddVariable::from_index(*index)),
        Rule::Not(inner) => to_bdd(inner, variables).not(),
        Rule::And(operands) => operands.iter().fold(variables.mk_true(), |all, operand| {
            all.and(&to_bdd(operand, variables))
        }),
        Rule::Or(operands) => operands.iter().fold(variables.mk_false(), |any, operand| {
            any.or(&to_bdd(operand, variables))
        }),
    }
}

/// Two connections that can deliver under the same mask.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Overlap {
    /// The earlier connection, by index in the port.
    pub first: usize,
    /// The later connection, by index in the port.
    pub second: usize,
    /// A minimal mask under which both deliver (bit i: connection i of the port is active).
    pub mask: u32,
}

/// What the proof found on one port.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PortReport {
    /// The port, as an index into the network's ports.
    pub port: usize,
    /// Its number of connections.
    pub connections: usize,
    /// Every pair of connections that can both deliver.
    pub overlaps: Vec<Overlap>,
    /// Connections (by index in the port) that can never deliver although their rule is not
    /// written `false`.
    pub dead: Vec<usize>,
    /// How many of the 2^n masks let nobody deliver (the empty mask included).
    pub idle_masks: u64,
    /// Minimal masks, with some connection active, in which nobody delivers (at most three).
    pub idle_examples: Vec<u32>,
    /// Gate connections never active together ([`PortLogic::exclusive`]); their masks are
    /// neither overlaps nor idle.
    pub exclusive: Vec<(usize, usize)>,
}

impl PortReport {
    /// Whether the port passed.
    pub fn is_consistent(&self) -> bool {
        self.overlaps.is_empty() && self.dead.is_empty()
    }

    /// 2^n.
    pub fn masks(&self) -> u64 {
        1u64 << self.connections
    }
}

/// What the proof found on the whole network.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Report {
    /// One entry per port, in file order.
    pub ports: Vec<PortReport>,
}

impl Report {
    /// Whether every port passed.
    pub fn is_consistent(&self) -> bool {
        self.ports.iter().all(PortReport::is_consistent)
    }

    /// The failures, as diagnostics located at the rules involved, in file order.
    pub fn errors(&self, network: &Network) -> Vec<Diagnostic> {
        let mut errors = Vec::new();
        for report in &self.ports {
            let names = network.port_connection_names(report.port);
            let connections: Vec<_> = network.port_connections(report.port).collect();
            let port_name = network
                .ports
                .get(report.port)
                .map_or("?", |p| p.name.as_str());
            for overlap in &report.overlaps {
                let (Some(first), Some(second)) = (
                    connections.get(overlap.first),
                    connections.get(overlap.second),
                ) else {
                    continue;
                };
                errors.push(network.error(
                    second.rule_span.clone(),
                    format!(
                        "port `{port_name}`: {} (rule \"{}\") and {} (rule \"{}\") can both deliver when the active connections are {}",
                        first.name,
                        shown::excerpt(&first.rule_text, RULE_EXCERPT),
                        second.name,
                        shown::excerpt(&second.rule_text, RULE_EXCERPT),
                        describe_mask(overlap.mask, &names),
                    ),
                ));
            }
            let specials: Vec<String> = connections
                .iter()
                .filter(|c| c.kind.is_special())
                .map(|c| format!("{} ({})", c.name, c.kind.name()))
                .collect();
            for &dead in &report.dead {
                let Some(connection) = connections.get(dead) else {
                    continue;
                };
                if !specials.is_empty() && written_alone_delivers(&names, connection) {
                    errors.push(network.error(
                        connection.rule_span.clone(),
                        format!(
                            "port `{port_name}`: {name} can never deliver: its rule \"{rule}\" holds only while the port's special connections block it ({})",
                            specials.join(", "),
                            name = connection.name,
                            rule = shown::excerpt(&connection.rule_text, RULE_EXCERPT),
                        ),
                    ));
                    continue;
                }
                errors.push(network.error(
                    connection.rule_span.clone(),
                    format!(
                        "port `{port_name}`: {name} can never deliver: \"{name} & ({rule})\" is false in all {} masks; write rule = \"false\" if {name} only coordinates (a virtual connection)",
                        report.masks(),
                        name = connection.name,
                        rule = shown::excerpt(&connection.rule_text, RULE_EXCERPT),
                    ),
                ));
            }
        }
        errors.sort_by_key(|error| error.position);
        errors
    }

    /// The per-port summary `pabctl check` prints.
    pub fn summary(&self, network: &Network) -> String {
        let mut out = String::new();
        for report in &self.ports {
            let Some(port) = network.ports.get(report.port) else {
                continue;
            };
            let node = network
                .nodes
                .get(port.node)
                .map_or("?", |n| n.name.as_str());
            let names = network.port_connection_names(report.port);
            let _ = writeln!(
                out,
                "{} (node {node}): {} connection{}, {} activity masks",
                port.name,
                report.connections,
                if report.connections == 1 { "" } else { "s" },
                report.masks()
            );
            if let (true, Some(spec)) = (report.is_consistent(), port.value) {
                let _ = writeln!(
                    out,
                    "  value port ({}): every connection its rule lets through contributes, no overlap proof; no dead rule",
                    combine_name(spec.combine)
                );
            } else if report.is_consistent() {
                let _ = writeln!(
                    out,
                    "  consistent: at most one connection delivers in every mask"
                );
            } else {
                let _ = writeln!(
                    out,
                    "  INCONSISTENT: {} overlap{}, {} dead rule{}",
                    report.overlaps.len(),
                    if report.overlaps.len() == 1 { "" } else { "s" },
                    report.dead.len(),
                    if report.dead.len() == 1 { "" } else { "s" }
                );
            }
            let specials: Vec<String> = network
                .port_connections(report.port)
                .filter(|c| c.kind.is_special())
                .map(|c| {
                    let target = c
                        .inhibits
                        .and_then(|t| network.topics.get(t))
                        .map_or(String::new(), |t| format!(" of `{}`", t.name));
                    format!("{} ({}{target}, {} s)", c.name, c.kind.name(), c.tau)
                })
                .collect();
            if !specials.is_empty() {
                let _ = writeln!(
                    out,
                    "  special (σ = 1, τ = period, compiled into the rules): {}",
                    specials.join(", ")
                );
            }
            let claims: Vec<String> = network
                .port_connections(report.port)
                .filter(|c| c.kind == Kind::Claim)
                .map(|c| format!("{} (every {} s)", c.name, c.tau))
                .collect();
            if !claims.is_empty() {
                let _ = writeln!(
                    out,
                    "  BLE claims (active while this node holds the group's task; proved like any connection): {}",
                    claims.join(", ")
                );
            }
            let gates: Vec<&str> = network
                .port_connections(report.port)
                .filter(|c| c.kind == Kind::Gate)
                .map(|c| c.name.as_str())
                .collect();
            if !gates.is_empty() {
                let _ = writeln!(
                    out,
                    "  gates (active while the behaviour's gate is open; proved like any connection): {}",
                    gates.join(", ")
                );
            }
            for &(a, b) in &report.exclusive {
                let name = |i: usize| names.get(i).map_or("?", String::as_str);
                let _ = writeln!(
                    out,
                    "  treated as impossible: {} and {} open together (they exclude each other with γ ≥ {EXCLUSIVE_GAMMA} both ways; the argument ignores the noise, and if it ever happened nobody would deliver here)",
                    name(a),
                    name(b)
                );
            }
            let virtuals: Vec<&str> = network
                .port_connections(report.port)
                .filter(|c| c.is_virtual() && c.kind != Kind::Claim && c.kind != Kind::Gate)
                .map(|c| c.name.as_str())
                .collect();
            if !virtuals.is_empty() {
                let _ = writeln!(
                    out,
                    "  virtual (coordinate, never deliver): {}",
                    virtuals.join(", ")
                );
            }
            let _ = write!(
                out,
                "  nothing delivers in {} of {} masks",
                report.idle_masks,
                report.masks()
            );
            if report.idle_examples.is_empty() {
                let _ = writeln!(out, " (only when no connection is active)");
            } else {
                let examples: Vec<String> = report
                    .idle_examples
                    .iter()
                    .map(|&mask| describe_set(mask, &names))
                    .collect();
                let _ = writeln!(
                    out,
                    ", among them with some connection active, e.g. {}",
                    examples.join(", ")
                );
            }
        }
        out
    }
}

/// Whether `connection`'s written rule alone (x ∧ R, before the port's special connections are
/// compiled in) lets it deliver in some mask.
fn written_alone_delivers(names: &[String], connection: &Connection) -> bool {
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let variables = BddVariableSet::new(&refs);
    let own = variables.mk_var(BddVariable::from_index(connection.index));
    !own.and(&to_bdd(&connection.rule, &variables)).is_false()
}

/// `{C1, C6}` for a mask.
pub fn describe_set(mask: u32, names: &[String]) -> String {
    let active: Vec<&str> = names
        .iter()
        .enumerate()
        .filter(|(index, _)| mask & (1 << index) != 0)
        .map(|(_, name)| name.as_str())
        .collect();
    format!("{{{}}}", active.join(", "))
}

/// `{C1, C6} (mask 0x00000021, bit i = i-th connection of the port)`.
pub fn describe_mask(mask: u32, names: &[String]) -> String {
    format!(
        "{} and no other (mask {mask:#010x}, bit i = the port's i-th connection)",
        describe_set(mask, names)
    )
}

/// Proves every port of `network`.
pub fn check(network: &Network) -> Report {
    let ports = (0..network.ports.len())
        .map(|port| check_port(network, port))
        .collect();
    Report { ports }
}

fn check_port(network: &Network, port: usize) -> PortReport {
    let logic = PortLogic::new(network, port);
    let connections: Vec<_> = network.port_connections(port).collect();
    let mut overlaps = Vec::new();
    // A value port combines every connection its rules let through: overlaps are its purpose.
    let value_port = network.ports.get(port).is_some_and(|p| p.value.is_some());
    for (first, d_first) in logic.delivers.iter().enumerate() {
        if value_port {
            break;
        }
        for (second, d_second) in logic.delivers.iter().enumerate().skip(first + 1) {
            let both = d_first.and(d_second);
            if let Some(mask) = logic.minimal_mask(&both) {
                overlaps.push(Overlap {
                    first,
                    second,
                    mask,
                });
            }
        }
    }
    let dead = logic
        .delivers
        .iter()
        .enumerate()
        .filter(|(index, d)| {
            d.is_false() && connections.get(*index).is_some_and(|c| !c.is_virtual())
        })
        .map(|(index, _)| index)
        .collect();
    let idle = logic.anyone().not().and_not(&logic.impossible());
    // Exact: at most 2^32 masks, well within an f64's 53-bit mantissa.
    let idle_masks = idle.cardinality() as u64;
    let mut idle_examples = Vec::new();
    let some_active = logic
        .variables
        .variables()
        .into_iter()
        .fold(logic.variables.mk_false(), |any, v| {
            any.or(&logic.variables.mk_var(v))
        });
    let mut remaining = idle.and(&some_active);
    while idle_examples.len() < 3 {
        let Some(mask) = logic.minimal_mask(&remaining) else {
            break;
        };
        idle_examples.push(mask);
        remaining = remaining.and_not(&logic.supersets(mask));
    }
    PortReport {
        port,
        connections: logic.len(),
        overlaps,
        dead,
        idle_masks,
        idle_examples,
        exclusive: logic.exclusive.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;

    /// A port's name and its connections' names and written rules.
    type PortSpec<'a> = (&'a str, &'a [(&'a str, Option<&'a str>)]);

    fn network(ports: &[PortSpec<'_>]) -> Network {
        let mut text = String::from("[nodes.n]\nid = 1\n");
        let mut topic = 0;
        for (port, connections) in ports {
            text += &format!("[ports.\"n.{port}\"]\n");
            for (name, rule) in connections.iter() {
                topic += 1;
                text += &format!("[topics.t{topic}]\ncan_id = {topic}\n");
                text += &format!(
                    "[connections.{name}]\ntopic = \"t{topic}\"\nport = \"n.{port}\"\nst = 1\ntc = 1\n"
                );
                if let Some(rule) = rule {
                    text += &format!("rule = \"{rule}\"\n");
                }
            }
        }
        Network::parse(Source::new("net.toml", text)).unwrap()
    }

    #[test]
    fn figure_one_is_consistent() {
        let net = network(&[("p", &[("C1", Some("C1 & !C2")), ("C2", None)])]);
        let report = check(&net);
        assert!(report.is_consistent());
        assert_eq!(report.ports[0].idle_masks, 1);
        assert!(report.ports[0].idle_examples.is_empty());
        assert!(
            report
                .summary(&net)
                .contains("only when no connection is active")
        );
    }

    #[test]
    fn overlaps_come_with_a_minimal_counterexample() {
        // C1 and C3 both deliver whenever both are active, whatever C2 does.
        let net = network(&[(
            "p",
            &[
                ("C1", Some("C1 & !C2")),
                ("C2", Some("false")),
                ("C3", None),
            ],
        )]);
        let report = check(&net);
        assert!(!report.is_consistent());
        assert_eq!(
            report.ports[0].overlaps,
            vec![Overlap {
                first: 0,
                second: 2,
                mask: 0b101
            }]
        );
        let errors = report.errors(&net);
        assert_eq!(errors.len(), 1);
        assert!(
            errors[0].to_string().contains("C1 (rule \"C1 & !C2\") and C3 (rule \"C3\") can both deliver when the active connections are {C1, C3} and no other (mask 0x00000005"),
            "{}",
            errors[0]
        );
    }

    #[test]
    fn dead_rules_are_errors_unless_written_false() {
        let net = network(&[(
            "p",
            &[
                ("C1", Some("C1 & !C1")),
                ("C2", Some("false")),
                ("C3", Some("!C3")),
            ],
        )]);
        let report = check(&net);
        assert_eq!(report.ports[0].dead, vec![0, 2]);
        let errors = report.errors(&net);
        assert!(
            errors[0].to_string().contains("C1 can never deliver"),
            "{}",
            errors[0]
        );
        assert!(
            errors[1].to_string().contains("C3 can never deliver"),
            "{}",
            errors[1]
        );
    }

    #[test]
    fn counterexamples_name_the_special_connections_they_need() {
        // C2 takes over while I inhibits C1's topic; C3 was meant as an alternative "while I
        // acts", but nothing orders it against C2: both deliver while C2, C3 and I are active.
        let text = r#"
[nodes.n]
id = 1
[ports."n.p"]
[topics.t1]
can_id = 1
[topics.t2]
can_id = 2
[topics.t3]
can_id = 3
[topics.ti]
can_id = 4
[connections.C1]
topic = "t1"
port = "n.p"
st = 1
tc = 1
[connections.C2]
topic = "t2"
port = "n.p"
st = 1
tc = 1
rule = "C2 & (!C1 | I)"
[connections.C3]
topic = "t3"
port = "n.p"
st = 1
tc = 1
rule = "C3 & I"
[connections.I]
topic = "ti"
kind = "inhibit"
inhibits = "t1"
period = 0.5
"#;
        let net = Network::parse(Source::new("net.toml", text)).unwrap();
        let report = check(&net);
        assert!(!report.is_consistent());
        let errors: Vec<String> = report.errors(&net).iter().map(|e| e.to_string()).collect();
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(
            errors[0].starts_with(
                "net.toml:29:8: error: port `n.p`: C2 (rule \"C2 & (!C1 | I)\") and C3 (rule \"C3 & I\") can both deliver when the active connections are {C2, C3, I} and no other (mask 0x0000000e"
            ),
            "{errors:#?}"
        );
        let summary = report.summary(&net);
        assert!(
            summary.contains(
                "special (σ = 1, τ = period, compiled into the rules): I (inhibit of `t1`, 0.5 s)"
            ),
            "{summary}"
        );
    }

    #[test]
    fn a_rule_that_only_holds_while_blocked_is_reported_as_such() {
        let net = {
            let text = "[nodes.n]\nid = 1\n[ports.\"n.p\"]\n[topics.a]\ncan_id = 1\n[topics.s]\ncan_id = 2\n\
                [connections.A]\ntopic = \"a\"\nport = \"n.p\"\nst = 1\ntc = 1\nrule = \"A & S\"\n\
                [connections.S]\ntopic = \"s\"\nport = \"n.p\"\nkind = \"suppress\"\nperiod = 1\n";
            Network::parse(Source::new("net.toml", text)).unwrap()
        };
        let errors: Vec<String> = check(&net)
            .errors(&net)
            .iter()
            .map(|e| e.to_string())
            .collect();
        assert_eq!(
            errors,
            [
                "net.toml:13:8: error: port `n.p`: A can never deliver: its rule \"A & S\" holds only while the port's special connections block it (S (suppress))"
            ]
        );
    }

    #[test]
    fn idle_masks_are_counted_and_exemplified() {
        // C1 delivers only if C2 is active too; C2 never delivers: {C1} alone is idle.
        let net = network(&[("p", &[("C1", Some("C1 & C2")), ("C2", Some("false"))])]);
        let report = &check(&net).ports[0];
        assert!(report.is_consistent());
        // Idle: {}, {C1}, {C2}; C1 delivers only in {C1, C2}.
        assert_eq!(report.idle_masks, 3);
        assert_eq!(report.idle_examples, vec![0b01, 0b10]);
    }

    #[test]
    fn thirty_two_connections_on_one_port() {
        // A priority chain: Ck delivers if active and no earlier connection is.
        let names: Vec<String> = (0..32).map(|k| format!("C{k}")).collect();
        let rules: Vec<String> = (0..32)
            .map(|k| {
                let mut rule = names[k].clone();
                for earlier in &names[..k] {
                    rule += &format!(" & !{earlier}");
                }
                rule
            })
            .collect();
        let connections: Vec<(&str, Option<&str>)> = names
            .iter()
            .zip(&rules)
            .map(|(n, r)| (n.as_str(), Some(r.as_str())))
            .collect();
        let net = network(&[("p", &connections)]);
        let report = &check(&net).ports[0];
        assert!(report.is_consistent());
        assert_eq!(report.masks(), 1 << 32);
        assert_eq!(report.idle_masks, 1);
    }
}
