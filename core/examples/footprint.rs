//! Prints the RAM footprint of pab-core's types at the compiled-in capacities, for the README:
//!
//!     cargo run -p pab-core --example footprint
//!
//! Sizes are those of the host build. On a 32-bit board they are the same except for the
//! arbiter's per-port index (four `usize`s per port), which is 16 bytes smaller per port.

use core::mem::size_of;

use pab_core::{
    Arbiter, Connection, DecisionNode, Integrator, MAX_CONNECTIONS, MAX_DECISION_NODES, MAX_PORTS,
    Table,
};

fn main() {
    println!(
        "capacities: {MAX_PORTS} ports, {MAX_CONNECTIONS} connections, {MAX_DECISION_NODES} decision nodes per node"
    );
    println!("Connection    {:>6} B", size_of::<Connection>());
    println!("DecisionNode  {:>6} B", size_of::<DecisionNode>());
    println!("Integrator    {:>6} B", size_of::<Integrator>());
    println!("Table         {:>6} B", size_of::<Table>());
    println!(
        "Arbiter       {:>6} B  (table included)",
        size_of::<Arbiter>()
    );
}
