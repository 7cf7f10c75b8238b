//! `pabctl compile`: one table image per node; and the compilation that `push`, `sim` and
//! `replay` share.

use std::fs;
use std::path::Path;

use pab_lang::compile::{self, CompiledNode};
use pab_lang::network::Network;

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
    for node in &nodes {
        let file = output.join(format!("{}.pab", node.name));
        write_atomically(&file, &node.image)?;
        say(format!(
            "{}  {} bytes  (node id {}, table version {}, {} port{}, {} connection{}, {} decision node{})",
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
        ));
    }
    if json {
        let version = table_version.unwrap_or(network.version);
        println!("{}", pabctl::json::compiled(output, &nodes, version));
    }
    Ok(())
}
