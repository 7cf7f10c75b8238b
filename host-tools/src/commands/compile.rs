//! `pabctl compile`: one table image per node, and the intention node's setup for a network with
//! an `[hbba]` section; and the compilation that `push`, `sim` and `replay` share.

use std::fs;
use std::path::Path;

use pab_lang::compile::{self, CompiledNode};
use pab_lang::network::Network;
use pab_lang::push_frames::PushRates;

use crate::failure::Failure;
use crate::output::{eprintln_line, plural, println_line, write_atomically};

/// The network's tables, at the command line's table version when it gives one.
pub fn compiled(
    network: &Network,
    table_version: Option<u32>,
) -> Result<Vec<CompiledNode>, Failure> {
    let mut network = network.clone();
    if let Some(version) = table_version {
        network.version = version;
    }
    compile::compile(&network).map_err(Failure::Inconsistent)
}

pub fn run(
    path: &Path,
    output: &Path,
    table_version: Option<u32>,
    json: bool,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let nodes = compiled(&network, table_version)?;
    fs::create_dir_all(output)
        .map_err(|error| Failure::Output(format!("cannot create {}: {error}", output.display())))?;
    let say = if json { eprintln_line } else { println_line };
    let rates = PushRates::of(&network);
    let mut pushes = Vec::new();
    for node in &nodes {
        let file = output.join(format!("{}.pab", node.name));
        write_atomically(&file, &node.image)?;
        // What a board must be built with to load it (docs/footprint.md): a board without one
        // of these refuses the table.
        let needs = pabctl::identity::mechanisms(&node.image)
            .map_err(|why| Failure::Output(format!("{}: {why}", file.display())))?;
        say(format!(
            "{}  {} bytes  (node id {}, table version {}, {} port{}, {} connection{}, {} decision node{}; needs {})",
            file.display(),
            node.image.len(),
            node.id,
            table_version.unwrap_or(network.version),
            node.ports,
            plural(node.ports),
            node.connections,
            plural(node.connections),
            node.decision_nodes,
            plural(node.decision_nodes),
            if needs.is_empty() {
                "no mechanism: any build".to_string()
            } else {
                needs.join(", ")
            },
        ));
        let push = rates
            .push(&node.image, node.id)
            .map_err(|why| Failure::Output(format!("{}: {why}", file.display())))?;
        say(format!("  {}", rates.describe(&push)));
        pushes.push(push);
    }
    // HBBA's intention node loads its setup as a board loads its table: pab-intent reads this
    // file, not the network.
    if let Some(hbba) = &network.hbba {
        let setup = compile::intention_setup(&network)
            .map_err(|why| Failure::Output(format!("{}: [hbba]: {why}", path.display())))?;
        let file = output.join("intention.json");
        let text = setup.to_json();
        write_atomically(&file, text.as_bytes())?;
        say(format!(
            "{}  {} bytes  (HBBA's intention node: {} strateg{}, {} filtered connection{}; pab-intent --setup {})",
            file.display(),
            text.len(),
            hbba.strategies.len(),
            if hbba.strategies.len() == 1 {
                "y"
            } else {
                "ies"
            },
            setup.targets.len(),
            plural(setup.targets.len()),
            file.display(),
        ));
    }
    if json {
        let version = table_version.unwrap_or(network.version);
        println!(
            "{}",
            pabctl::json::compiled(output, &nodes, version, &rates, &pushes)
        );
    }
    Ok(())
}
