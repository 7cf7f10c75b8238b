//! Prints the RAM footprint of pab-core's types, at the default capacities and for the board
//! profile, for docs/figures.md:
//!
//!     cargo run -p pab-core --example footprint
//!
//! Sizes are those of the host build. On a 32-bit board they are the same except for the
//! arbiter's per-port index (four `usize`s per port), which is 16 bytes smaller per port.

use core::mem::size_of;

use pab_core::table::Port;
use pab_core::{
    Arbiter, BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, BoardArbiter, BoardTable,
    Connection, Consumer, DecisionNode, Integrator, MAX_CONNECTIONS, MAX_DECISION_NODES, MAX_PORTS,
    Table,
};

fn main() {
    println!("Connection    {:>6} B", size_of::<Connection>());
    println!("DecisionNode  {:>6} B", size_of::<DecisionNode>());
    println!("Port          {:>6} B", size_of::<Port>());
    println!("Consumer      {:>6} B", size_of::<Consumer>());
    println!("Integrator    {:>6} B", size_of::<Integrator>());
    println!();
    println!(
        "default capacities: {MAX_PORTS} ports, {MAX_CONNECTIONS} connections, {MAX_DECISION_NODES} decision nodes per node"
    );
    println!("Table         {:>6} B", size_of::<Table>());
    println!(
        "Arbiter       {:>6} B  (table included)",
        size_of::<Arbiter>()
    );
    println!();
    println!(
        "board profile: {BOARD_PORTS} ports, {BOARD_CONNECTIONS} connections, {BOARD_DECISION_NODES} decision nodes per node"
    );
    println!("BoardTable    {:>6} B", size_of::<BoardTable>());
    println!(
        "BoardArbiter  {:>6} B  (table included)",
        size_of::<BoardArbiter>()
    );
}
