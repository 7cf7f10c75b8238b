//! Measures the two candidate representations of a port's decision, for docs/figures.md:
//!
//! - one multi-terminal decision diagram per port (what the tables hold): mask -> winner;
//! - one BDD per connection for D_i = x_i & rule_i, evaluated for the frame's connection only.
//!
//! For each, the number of nodes (6 bytes each in RAM) and the longest walk (steps per frame).
//!
//!     cargo run --release -p pab-lang --example decision_sizes

use std::path::Path;

use biodivine_lib_bdd::{Bdd, BddPointer};
use pab_core::MAX_DECISION_NODES;
use pab_core::decision::{DecisionNode, NodeRef, Target};
use pab_lang::check::PortLogic;
use pab_lang::compile;
use pab_lang::diagnostic::Source;
use pab_lang::network::Network;

fn bdd_depth(bdd: &Bdd, pointer: BddPointer) -> usize {
    if pointer.is_terminal() {
        0
    } else {
        1 + bdd_depth(bdd, bdd.low_link_of(pointer)).max(bdd_depth(bdd, bdd.high_link_of(pointer)))
    }
}

fn diagram_depth(nodes: &[DecisionNode], at: NodeRef) -> usize {
    match at.target() {
        Target::Node(index) => {
            let node = nodes[usize::from(index)];
            1 + diagram_depth(nodes, node.low).max(diagram_depth(nodes, node.high))
        }
        _ => 0,
    }
}

fn measure(label: &str, network: &Network) {
    for (index, port) in network.ports.iter().enumerate() {
        let logic = PortLogic::new(network, index);
        let decision = compile::decision(&logic, MAX_DECISION_NODES).expect("consistent");
        let per_rule_nodes: usize = logic
            .delivers
            .iter()
            .map(|d| d.size().saturating_sub(2))
            .sum();
        let per_rule_depth = logic
            .delivers
            .iter()
            .map(|d| bdd_depth(d, d.root_pointer()))
            .max()
            .unwrap_or(0);
        println!(
            "| {label} | {} | {} | {} nodes, {} B, {} steps | {} nodes, {} B, {} steps |",
            port.name,
            logic.len(),
            decision.nodes.len(),
            decision.nodes.len() * 6,
            diagram_depth(&decision.nodes, decision.root),
            per_rule_nodes,
            per_rule_nodes * 6,
            per_rule_depth,
        );
    }
}

fn synthetic(label: &str, connections: usize, rule: impl Fn(usize) -> String) -> Network {
    let mut text = String::from("[nodes.n]\nid = 1\n[ports.\"n.p\"]\n");
    for k in 0..connections {
        text += &format!(
            "[topics.t{k}]\ncan_id = {}\n[connections.C{k}]\ntopic = \"t{k}\"\nport = \"n.p\"\nst = 0.2\ntc = 3.0\nrule = \"{}\"\n",
            0x100 + k,
            rule(k)
        );
    }
    Network::parse(Source::new(label, text)).expect("valid")
}

fn main() {
    println!("| network | port | connections | per-port diagram | one BDD per rule |");
    println!("|---|---|---|---|---|");
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    for name in ["figure-1", "take-and-return"] {
        let network = Network::load(&examples.join(format!("{name}.toml"))).expect("example");
        measure(name, &network);
    }
    for n in [4, 16, 32] {
        // Strict priority: the first active connection delivers.
        let chain = synthetic("priority", n, |k| {
            std::iter::once(format!("C{k}"))
                .chain((0..k).map(|j| format!("!C{j}")))
                .collect::<Vec<_>>()
                .join(" & ")
        });
        measure(&format!("priority chain ({n})"), &chain);
    }
}
