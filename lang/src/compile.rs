//! Compiling a checked network into one table image per node.
//!
//! A port's decision is the function mask → the connection i with mask ∈ D_i (or nobody). Since the
//! D_i are disjoint (the proof of [`crate::check`]), it is built by walking all the D_i's BDDs at
//! once, variable by variable: each distinct combination of positions becomes one node of a
//! multi-terminal diagram; where every position is a terminal, the one D_i at "true" names the
//! winner. Identical nodes are shared and nodes whose two children agree are skipped, so the
//! result is the reduced, ordered diagram of the function, with children always after their
//! parents in the array (the order [`pab_core::decision::validate`] demands).

use std::collections::HashMap;

use biodivine_lib_bdd::{Bdd, BddPointer};
use pab_core::ble::{self, Group, GroupPort, MAX_GROUP_PORTS};
use pab_core::decision::{DecisionNode, NodeRef};
use pab_core::image::{self, MAX_IMAGE_LEN};
use pab_core::{Connection, Consumer, MAX_DECISION_NODES, Table, TableError};

mod dynamics;
mod hbba;

use crate::check::{self, PortLogic};
use crate::diagnostic::Diagnostic;
use crate::network::{BleGroup, Kind, Network};

/// A port's compiled decision.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Decision {
    /// Nodes, parents before children.
    pub nodes: Vec<DecisionNode>,
    /// The entry.
    pub root: NodeRef,
}

/// Where a decision walk goes while the diagram is built (indices are not final yet).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Step {
    Node(usize),
    Deliver(u8),
    Nobody,
}

/// Why a port could not be compiled.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum DecisionError {
    /// Two connections deliver under one mask (the network was not checked).
    Inconsistent,
    /// The diagram needs more nodes than a node can hold.
    TooLarge,
}

impl std::fmt::Display for DecisionError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DecisionError::Inconsistent => {
                "two connections deliver under one mask (the network was not checked)"
            }
            DecisionError::TooLarge => "the decision diagram needs more nodes than a node holds",
        })
    }
}

impl std::error::Error for DecisionError {}

/// How many distinct walk positions the builder may visit per node it may create.
const WORK_PER_NODE: usize = 64;

struct Builder<'a> {
    delivers: &'a [Bdd],
    limit: usize,
    nodes: Vec<(u8, Step, Step)>,
    shared: HashMap<(u8, Step, Step), usize>,
    memo: HashMap<Vec<BddPointer>, Step>,
}

impl Builder<'_> {
    fn build(&mut self, positions: Vec<BddPointer>) -> Result<Step, DecisionError> {
        if let Some(step) = self.memo.get(&positions) {
            return Ok(*step);
        }
        // Distinct positions can outnumber the nodes they reduce to; bound the work as well as
        // the result, so that a pathological rule set fails fast instead of running for hours.
        if self.memo.len() >= self.limit.saturating_mul(WORK_PER_NODE) {
            return Err(DecisionError::TooLarge);
        }
        let next = positions
            .iter()
            .zip(self.delivers)
            .filter(|(pointer, _)| !pointer.is_terminal())
            .map(|(pointer, bdd)| bdd.var_of(*pointer))
            .min();
        let step = match next {
            None => {
                let mut winners = positions.iter().enumerate().filter(|(_, p)| p.is_one());
                match (winners.next(), winners.next()) {
                    (None, _) => Step::Nobody,
                    (Some((index, _)), None) => {
                        Step::Deliver(u8::try_from(index).map_err(|_| DecisionError::TooLarge)?)
                    }
                    (Some(_), Some(_)) => return Err(DecisionError::Inconsistent),
                }
            }
            Some(variable) => {
                let follow = |high: bool| -> Vec<BddPointer> {
                    positions
                        .iter()
                        .zip(self.delivers)
                        .map(|(&pointer, bdd)| {
                            if pointer.is_terminal() || bdd.var_of(pointer) != variable {
                                pointer
                            } else if high {
                                bdd.high_link_of(pointer)
                            } else {
                                bdd.low_link_of(pointer)
                            }
                        })
                        .collect()
                };
                let (low_positions, high_positions) = (follow(false), follow(true));
                let low = self.build(low_positions)?;
                let high = self.build(high_positions)?;
                if low == high {
                    low
                } else {
                    let var =
                        u8::try_from(variable.to_index()).map_err(|_| DecisionError::TooLarge)?;
                    self.node(var, low, high)?
                }
            }
        };
        self.memo.insert(positions, step);
        Ok(step)
    }

    /// The nodes built, parents first (children were created before their parents: reversing
    /// puts parents first), and `entries` as references into them.
    fn flatten(
        &self,
        entries: impl IntoIterator<Item = Step>,
    ) -> Result<(Vec<DecisionNode>, Vec<NodeRef>), DecisionError> {
        let count = self.nodes.len();
        let reference = |step: Step| -> Result<NodeRef, DecisionError> {
            match step {
                Step::Nobody => Ok(NodeRef::NOBODY),
                Step::Deliver(index) => NodeRef::deliver(index).ok_or(DecisionError::TooLarge),
                Step::Node(index) => u16::try_from(count - 1 - index)
                    .ok()
                    .and_then(NodeRef::node)
                    .ok_or(DecisionError::TooLarge),
            }
        };
        let nodes = self
            .nodes
            .iter()
            .rev()
            .map(|&(var, low, high)| {
                Ok(DecisionNode {
                    var,
                    low: reference(low)?,
                    high: reference(high)?,
                })
            })
            .collect::<Result<Vec<_>, DecisionError>>()?;
        let entries = entries
            .into_iter()
            .map(reference)
            .collect::<Result<Vec<_>, DecisionError>>()?;
        Ok((nodes, entries))
    }

    fn node(&mut self, var: u8, low: Step, high: Step) -> Result<Step, DecisionError> {
        if let Some(&index) = self.shared.get(&(var, low, high)) {
            return Ok(Step::Node(index));
        }
        if self.nodes.len() >= self.limit {
            return Err(DecisionError::TooLarge);
        }
        let index = self.nodes.len();
        self.nodes.push((var, low, high));
        self.shared.insert((var, low, high), index);
        Ok(Step::Node(index))
    }
}

/// Compiles a port's logic into a decision of at most `limit` nodes.
pub fn decision(logic: &PortLogic, limit: usize) -> Result<Decision, DecisionError> {
    let mut builder = Builder {
        delivers: &logic.delivers,
        limit,
        nodes: Vec::new(),
        shared: HashMap::new(),
        memo: HashMap::new(),
    };
    let roots = logic.delivers.iter().map(Bdd::root_pointer).collect();
    let root = builder.build(roots)?;
    let (nodes, roots) = builder.flatten([root])?;
    let root = roots.first().copied().unwrap_or(NodeRef::NOBODY);
    Ok(Decision { nodes, root })
}

/// Compiles a value port's logic: one diagram per connection i, answering "i delivers" exactly
/// in D_i, all in one array of at most `limit` nodes (shared where they coincide, children after
/// parents). Returns the nodes with the port's root "nobody", and the connections' roots.
pub fn value_decision(
    logic: &PortLogic,
    limit: usize,
) -> Result<(Decision, Vec<NodeRef>), DecisionError> {
    let mut builder = Builder {
        delivers: &logic.delivers,
        limit,
        nodes: Vec::new(),
        shared: HashMap::new(),
        memo: HashMap::new(),
    };
    // Connection i's walk follows D_i alone: the other positions are "false" terminals.
    let mut entries = Vec::with_capacity(logic.len());
    for (index, own) in logic.delivers.iter().enumerate() {
        let positions = (0..logic.len())
            .map(|other| {
                if other == index {
                    own.root_pointer()
                } else {
                    BddPointer::zero()
                }
            })
            .collect();
        entries.push(builder.build(positions)?);
    }
    let (nodes, roots) = builder.flatten(entries)?;
    Ok((
        Decision {
            nodes,
            root: NodeRef::NOBODY,
        },
        roots,
    ))
}

/// One node's compiled table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CompiledNode {
    /// The node's name in the network file.
    pub name: String,
    /// Its node id.
    pub id: u8,
    /// The table image, ready to write or push.
    pub image: Vec<u8>,
    /// Its ports.
    pub ports: usize,
    /// Its connections over all ports.
    pub connections: usize,
    /// Decision nodes over all ports.
    pub decision_nodes: usize,
    /// Nodes that one BDD per rule (the alternative representation) would need over all ports,
    /// for comparison.
    pub per_rule_nodes: usize,
}

/// Compiles every node of `network`. Refuses an inconsistent network with the proof's errors, and
/// table version 0 (reserved for "no table").
pub fn compile(network: &Network) -> Result<Vec<CompiledNode>, Vec<Diagnostic>> {
    if network.version == 0 {
        // A file cannot say 0 (see `Network::parse`); a caller that sets it is told why not.
        return Err(vec![Diagnostic::file(
            network.source.path(),
            "table version 0 is reserved (heartbeats report version 0 for \"no table\"); use 1 or more",
        )]);
    }
    let report = check::check(network);
    if !report.is_consistent() {
        return Err(report.errors(network));
    }
    network
        .nodes
        .iter()
        .map(|node| compile_node(network, node))
        .collect::<Result<Vec<_>, Diagnostic>>()
        .map_err(|error| vec![error])
}

fn compile_node(
    network: &Network,
    node: &crate::network::Node,
) -> Result<CompiledNode, Diagnostic> {
    let mut table: Table = Table::new();
    // The network's connections in the table's order (HBBA's filters name them).
    let mut table_connections: Vec<usize> = Vec::new();
    let mut decision_nodes = 0usize;
    let mut per_rule_nodes = 0usize;
    for &port_index in &node.ports {
        let Some(port) = network.ports.get(port_index) else {
            continue;
        };
        let logic = PortLogic::new(network, port_index);
        let room = MAX_DECISION_NODES.saturating_sub(decision_nodes);
        let compiled = match port.value {
            // A value port: one diagram per connection, "i delivers" where it may contribute,
            // sharing nodes; the port's own root is nobody.
            Some(_) => value_decision(&logic, room),
            None => decision(&logic, room).map(|compiled| (compiled, Vec::new())),
        };
        let (compiled, roots) = compiled.map_err(|error| {
            network.error(
                port.span.clone(),
                match error {
                    DecisionError::TooLarge => format!(
                        "port `{}`: its decision needs more than the {room} decision nodes left on node `{}` (at most {MAX_DECISION_NODES} per node); simplify the rules or split the port",
                        port.name, node.name
                    ),
                    DecisionError::Inconsistent => {
                        format!("port `{}`: two connections deliver under one mask", port.name)
                    }
                },
            )
        })?;
        decision_nodes += compiled.nodes.len();
        per_rule_nodes += logic
            .delivers
            .iter()
            .map(|d| d.size().saturating_sub(2))
            .sum::<usize>();
        table_connections.extend(port.connections.iter().copied());
        let connections: Vec<Connection> = network
            .port_connections(port_index)
            .filter_map(|c| {
                Some(Connection {
                    // A claim is set by the node's group state, never by a frame.
                    filter: match c.kind {
                        Kind::Claim => ble::CLAIM_SLOT_FILTER,
                        // A gate is set by the dynamics (its node's, or Gates frames).
                        Kind::Gate => pab_core::dynamics::GATE_SLOT_FILTER,
                        _ => network.topics.get(c.topic)?.filter,
                    },
                    stimulation: c.stimulation,
                })
            })
            .collect();
        let port_error =
            |error| network.error(port.span.clone(), format!("port `{}`: {error}", port.name));
        match port.value {
            Some(spec) => table.push_value_port(&connections, &compiled.nodes, spec, &roots),
            None => table.push_port(&connections, &compiled.nodes, compiled.root),
        }
        .map_err(port_error)?;
        if port.consumer != Consumer::Local {
            let index = u8::try_from(table.port_count().saturating_sub(1))
                .map_err(|_| port_error(TableError::TooManyPorts))?;
            table
                .set_consumer(index, port.consumer)
                .map_err(port_error)?;
        }
    }
    for group in groups_of(network, node)? {
        table.push_group(group.1).map_err(|error| {
            network.error(
                group.0.span.clone(),
                format!(
                    "BLE group `{}` on node `{}`: {error}",
                    group.0.name, node.name
                ),
            )
        })?;
    }
    let dynamics = dynamics::dynamics_of(network, node)?;
    if !(dynamics.specs.is_empty() && dynamics.sources.is_empty()) {
        table
            .push_dynamics(&dynamics.specs, &dynamics.sources, &dynamics.links)
            .map_err(|error| {
                network.error(
                    node.span.clone(),
                    format!("node `{}`: competitive dynamics: {error}", node.name),
                )
            })?;
    }
    let filters = hbba::filters_of(network, node, &table_connections)
        .map_err(|error| network.error(node.span.clone(), error))?;
    if !filters.is_empty() {
        table.set_filters(filters).map_err(|error| {
            network.error(
                node.span.clone(),
                format!("node `{}`: message filters: {error}", node.name),
            )
        })?;
    }
    let node_index = network.nodes.iter().position(|n| n.name == node.name);
    if let Some(board) = network
        .schema_boards
        .iter()
        .find(|b| Some(b.node) == node_index)
    {
        table.set_schema(Some(pab_core::schema::Setup {
            config: board.config.clone(),
            drive: board.drive,
            sensors: board.sensors.iter().map(|s| s.sensor).collect(),
        }));
    }
    let mut buffer = vec![0u8; MAX_IMAGE_LEN];
    let length = image::encode(&table, node.id, network.version, &mut buffer).map_err(|error| {
        network.error(node.span.clone(), format!("node `{}`: {error}", node.name))
    })?;
    buffer.truncate(length);
    Ok(CompiledNode {
        name: node.name.clone(),
        id: node.id,
        image: buffer,
        ports: table.port_count(),
        connections: table.connection_count(),
        decision_nodes,
        per_rule_nodes,
    })
}

/// The BLE groups node `node` is in, as its table stores them: per port whose rules name the
/// group, the claim connection and the connections gated by it (those whose rule names it). A
/// node whose rules never name a group it is in has no port for it: it broadcasts 0 and never
/// holds the task.
fn groups_of<'n>(
    network: &'n Network,
    node: &crate::network::Node,
) -> Result<Vec<(&'n BleGroup, Group)>, Diagnostic> {
    let node_index = network
        .nodes
        .iter()
        .position(|n| n.name == node.name)
        .unwrap_or(usize::MAX);
    let mut out = Vec::new();
    for group in &network.groups {
        let Some(member) = group.member(node_index) else {
            continue;
        };
        let invalid = |what: &str| {
            network.error(
                group.span.clone(),
                format!("BLE group `{}` on node `{}`: {what}", group.name, node.name),
            )
        };
        let local = network
            .topics
            .get(member.topic)
            .ok_or_else(|| invalid("its eligibility topic is missing"))?
            .filter;
        let mut ports = Vec::new();
        for (local_port, &port_index) in node.ports.iter().enumerate() {
            let Some(claim) = network
                .port_connections(port_index)
                .find(|c| c.kind == Kind::Claim && c.name == group.name)
            else {
                continue;
            };
            let gated = network
                .port_connections(port_index)
                .filter(|c| c.rule_written && c.rule.mentions(claim.index))
                .fold(0u32, |mask, c| {
                    mask | 1u32.checked_shl(c.index as u32).unwrap_or(0)
                });
            let entry = GroupPort {
                port: u8::try_from(local_port).map_err(|_| invalid("too many ports"))?,
                claim: u8::try_from(claim.index).map_err(|_| invalid("too many connections"))?,
                gated,
            };
            ports.push(entry);
        }
        if ports.len() > MAX_GROUP_PORTS {
            return Err(invalid("named at too many ports"));
        }
        out.push((
            group,
            Group {
                number: group.number,
                node: node.id,
                period_us: group.period_us,
                local,
                field: group.field,
                peers: u8::try_from(group.members.len().saturating_sub(1))
                    .map_err(|_| invalid("too many nodes"))?,
                // At most MAX_GROUP_PORTS, checked above.
                ports: ports.into_iter().collect(),
            },
        ));
    }
    Ok(out)
}

/// What `pab-intent`, HBBA's intention node, loads for `network`: the solver's instance of its
/// `[hbba]` section, where each filtered connection is, and the names it logs with. `pabctl
/// compile` writes it as `DIR/intention.json` ([`pab_intent::Setup::to_json`]); the simulator
/// runs the intention node on it. `Err` says why there is none: no `[hbba]` section, or more
/// filtered connections than the intention workspace takes.
pub fn intention_setup(network: &Network) -> Result<pab_intent::Setup, String> {
    let Some(hbba) = &network.hbba else {
        return Err(
            "the network has no [hbba] section: the intention node needs its strategies".into(),
        );
    };
    let targets = network.filter_targets()?;
    let filters = targets
        .iter()
        .map(|t| {
            let connection = network.connections.get(usize::from(t.connection));
            let port = connection
                .and_then(|c| network.ports.get(c.port))
                .map_or("?", |p| p.name.as_str());
            format!("{} ({port})", connection.map_or("?", |c| c.name.as_str()))
        })
        .collect();
    pab_intent::Setup::new(
        hbba.instance(),
        targets,
        network
            .nodes
            .iter()
            .map(|n| (n.id, n.name.clone()))
            .collect(),
        filters,
        hbba.strategies.iter().map(|s| s.name.clone()).collect(),
        hbba.classes.clone(),
    )
    .map_err(|error| error.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;
    use crate::rule::Rule;
    use biodivine_lib_bdd::{BddVariable, BddVariableSet};
    use pab_core::ConnectionSet;
    use proptest::prelude::*;

    /// A random rule over `n` variables, depth-bounded.
    fn arb_rule(n: usize) -> impl Strategy<Value = Rule> {
        let leaf = prop_oneof![
            1 => any::<bool>().prop_map(Rule::Constant),
            6 => (0..n).prop_map(Rule::Active),
        ];
        leaf.prop_recursive(4, 24, 2, |inner| {
            prop_oneof![
                inner.clone().prop_map(|r| Rule::Not(Box::new(r))),
                (inner.clone(), inner.clone()).prop_map(|(a, b)| Rule::And(vec![a, b])),
                (inner.clone(), inner).prop_map(|(a, b)| Rule::Or(vec![a, b])),
            ]
        })
    }

    /// Random rules made consistent the way a designer would: connection k's rule is guarded by
    /// "no earlier connection delivers", so random rule sets are consistent by construction.
    fn consistent_logic(rules: &[Rule]) -> PortLogic {
        let names: Vec<String> = (0..rules.len()).map(|k| format!("C{k}")).collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let variables = BddVariableSet::new(&refs);
        let mut delivers: Vec<Bdd> = Vec::new();
        for (k, rule) in rules.iter().enumerate() {
            let own = variables.mk_var(BddVariable::from_index(k));
            let earlier = delivers
                .iter()
                .fold(variables.mk_false(), |all, d| all.or(d));
            delivers.push(own.and(&check::to_bdd(rule, &variables)).and_not(&earlier));
        }
        PortLogic {
            variables,
            delivers,
            exclusive: Vec::new(),
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// The compiled decision agrees with the direct evaluation of the rules on every mask.
        #[test]
        fn decision_matches_direct_evaluation(
            rules in (1usize..=8).prop_flat_map(|n| proptest::collection::vec(arb_rule(n), n))
        ) {
            let n = rules.len();
            let logic = consistent_logic(&rules);
            let compiled = decision(&logic, MAX_DECISION_NODES).unwrap();
            pab_core::decision::validate(&compiled.nodes, compiled.root, n as u8).unwrap();
            for mask in 0u32..(1 << n) {
                // Direct evaluation: connection k delivers iff x_k, its rule, and no earlier one.
                let mut expected = None;
                for (k, rule) in rules.iter().enumerate() {
                    if mask & (1 << k) != 0 && rule.eval(u64::from(mask)) {
                        expected = Some(k as u8);
                        break;
                    }
                }
                let got = pab_core::decision::evaluate(&compiled.nodes, compiled.root, ConnectionSet::from_bits(mask));
                prop_assert_eq!(got, expected, "mask {:#b}", mask);
            }
        }

        /// Wider ports, checked on random masks. Rules are guarded by strict priority (the first
        /// active connection decides, by its own random rule), the shape of real inhibition
        /// chains; general random rules over 32 connections have exponentially large diagrams.
        #[test]
        fn wide_decisions_match_direct_evaluation(
            rules in (9usize..=32).prop_flat_map(|n| proptest::collection::vec(arb_rule(n), n)),
            masks in proptest::collection::vec(any::<u32>(), 256)
        ) {
            let n = rules.len();
            let names: Vec<String> = (0..n).map(|k| format!("C{k}")).collect();
            let refs: Vec<&str> = names.iter().map(String::as_str).collect();
            let variables = BddVariableSet::new(&refs);
            let delivers: Vec<Bdd> = rules
                .iter()
                .enumerate()
                .map(|(k, rule)| {
                    (0..k).fold(
                        variables.mk_var(BddVariable::from_index(k)).and(&check::to_bdd(rule, &variables)),
                        |d, j| d.and_not(&variables.mk_var(BddVariable::from_index(j))),
                    )
                })
                .collect();
            let logic = PortLogic {
                variables,
                delivers,
                exclusive: Vec::new(),
            };
            let compiled = decision(&logic, MAX_DECISION_NODES).unwrap();
            pab_core::decision::validate(&compiled.nodes, compiled.root, n as u8).unwrap();
            let width = if n == 32 { u32::MAX } else { (1 << n) - 1 };
            for mask in masks.into_iter().map(|m| m & width).chain([0, width]) {
                let expected = (mask != 0)
                    .then(|| mask.trailing_zeros() as usize)
                    .filter(|&first| rules[first].eval(u64::from(mask)))
                    .map(|first| first as u8);
                let got = pab_core::decision::evaluate(&compiled.nodes, compiled.root, ConnectionSet::from_bits(mask));
                prop_assert_eq!(got, expected, "mask {:#x}", mask);
            }
        }
    }

    #[test]
    fn republish_sets_the_port_consumer_in_the_image() {
        let text = "[nodes.arm]\nid = 1\n[topics.a]\ncan_id = 0x110\n[topics.b]\ncan_id = 0x111\n[ports.\"arm.local\"]\n[ports.\"arm.target\"]\nrepublish = { can_id = 0x1ABCDEF, extended = true }\n[connections.C1]\ntopic = \"a\"\nport = \"arm.local\"\nst = 1\ntc = 1\n[connections.C2]\ntopic = \"b\"\nport = \"arm.target\"\nst = 1\ntc = 1\n";
        let network = Network::parse(Source::new("r.toml", text)).unwrap();
        let nodes = compile(&network).unwrap();
        let loaded: image::Loaded = image::load(&nodes[0].image).unwrap();
        let consumers: Vec<Consumer> = loaded.table.ports().map(|p| p.consumer).collect();
        let out = pab_core::OutputId::new(0x1AB_CDEF, true).unwrap();
        assert_eq!(consumers, vec![Consumer::Local, Consumer::Republish(out)]);
        assert_eq!(
            out.id(),
            pab_core::Id::Extended(embedded_can::ExtendedId::new(0x1AB_CDEF).unwrap())
        );
    }

    #[test]
    fn figure_one_compiles_to_a_small_table() {
        let text = "[nodes.gaze]\nid = 3\n[topics.face]\ncan_id = 0x110\n[topics.object]\ncan_id = 0x111\n[ports.\"gaze.target\"]\n[connections.C1]\ntopic = \"face\"\nport = \"gaze.target\"\nst = 0.2\ntc = 3.0\nrule = \"C1 & !C2\"\n[connections.C2]\ntopic = \"object\"\nport = \"gaze.target\"\nst = 0.2\ntc = 3.0\n";
        let network = Network::parse(Source::new("f.toml", text)).unwrap();
        let nodes = compile(&network).unwrap();
        assert_eq!(nodes.len(), 1);
        let loaded: image::Loaded = image::load(&nodes[0].image).unwrap();
        assert_eq!(loaded.header.node_id, 3);
        assert_eq!(loaded.header.table_version, 1);
        let port = loaded.table.port(0).unwrap();
        // x0 ? (x1 ? C2 : C1) : (x1 ? C2 : nobody): three nodes.
        assert_eq!(port.nodes.len(), 3);
        let decide = |mask| {
            pab_core::decision::evaluate(port.nodes, port.root, ConnectionSet::from_bits(mask))
        };
        assert_eq!(
            (decide(0), decide(1), decide(2), decide(3)),
            (None, Some(0), Some(1), Some(1))
        );
    }

    #[test]
    fn decisions_beyond_the_capacity_are_refused() {
        // Connection k delivers iff x_k and an odd number of the others are active, guarded by
        // priority: the parity makes the diagram grow with every variable.
        let n = 24;
        let names: Vec<String> = (0..n).map(|k| format!("C{k}")).collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let variables = BddVariableSet::new(&refs);
        let parity = (0..n).fold(variables.mk_false(), |p, j| {
            p.xor(&variables.mk_var(BddVariable::from_index(j)))
        });
        let mut delivers: Vec<Bdd> = Vec::new();
        for k in 0..n {
            let earlier = delivers
                .iter()
                .fold(variables.mk_false(), |all, d| all.or(d));
            let own = variables.mk_var(BddVariable::from_index(k));
            delivers.push(own.and(&parity).and_not(&earlier));
        }
        let logic = PortLogic {
            variables,
            delivers,
            exclusive: Vec::new(),
        };
        assert_eq!(decision(&logic, 64), Err(DecisionError::TooLarge));
    }

    #[test]
    fn inconsistent_networks_are_refused() {
        let text = "[nodes.n]\nid = 1\n[topics.a]\ncan_id = 1\n[topics.b]\ncan_id = 2\n[ports.\"n.p\"]\n[connections.A]\ntopic = \"a\"\nport = \"n.p\"\nst = 1\ntc = 1\n[connections.B]\ntopic = \"b\"\nport = \"n.p\"\nst = 1\ntc = 1\n";
        let network = Network::parse(Source::new("f.toml", text)).unwrap();
        let errors = compile(&network).unwrap_err();
        assert_eq!(errors.len(), 1);
        assert!(
            errors[0]
                .to_string()
                .contains("can both deliver when the active connections are {A, B}")
        );
    }

    #[test]
    fn a_schema_servers_image_carries_its_sensors_and_innate_schemas() {
        let text = r#"
[nodes.arm]
id = 10

[schema.arm]
period_ms = 1
force_limit_n = 30
drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }

[schema.arm.sensors.gap]
can_id = 0x330
value = { offset = 0, size = 2 }
scale = 0.1
unit = "mm"

[schema.arm.sensors.grip]
can_id = 0x12345
extended = true
value = { offset = 1, size = 1, signed = true }
unit = "N"

[schema.arm.places]
safe = [0, 0, 80]

[schema.arm.innate]
retreat = "move_to(safe, speed=20); done -> high_priority"
hold = "idle(); below(gap, 0.3) -> retreat"
"#;
        let network =
            Network::parse(Source::new("net.toml", text)).unwrap_or_else(|e| panic!("{e:?}"));
        let board = &network.schema_boards[0];
        let nodes = compile(&network).unwrap_or_else(|e| panic!("{e:?}"));
        let loaded: pab_core::image::Loaded = pab_core::image::load(&nodes[0].image).unwrap();
        let setup = loaded.table.schema().unwrap();
        assert_eq!(setup.config.innate, board.config.innate);
        assert_eq!(board.config.innate.len(), 2);
        let sensors: Vec<pab_core::schema::Sensor> =
            board.sensors.iter().map(|s| s.sensor).collect();
        assert_eq!(setup.sensors.as_slice(), sensors.as_slice());
        assert_eq!(sensors.len(), 2);
    }
}
