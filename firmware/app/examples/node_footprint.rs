//! The static RAM a node needs, per capacity set: `cargo run -p pab-app --example node_footprint`.
//!
//! A board keeps its node in a `static` (`pab-fw-g474` does), so this is part of the firmware's
//! `.bss`; the Linux node keeps it on the heap.

use core::mem::size_of;

fn main() {
    println!(
        "BoardNode: {} bytes ({} ports, {} connections, {} decision nodes, 8 KiB transfer buffer)",
        size_of::<pab_app::BoardNode>(),
        pab_core::BOARD_PORTS,
        pab_core::BOARD_CONNECTIONS,
        pab_core::BOARD_DECISION_NODES,
    );
    println!(
        "  of which the arbiter (pab_core::BoardArbiter): {} bytes",
        size_of::<pab_core::BoardArbiter>()
    );
    println!(
        "FullNode:  {} bytes (the Linux node: full capacities, {}-byte transfer buffer)",
        size_of::<pab_app::FullNode>(),
        pab_core::image::MAX_IMAGE_LEN,
    );
}
