//! pabctl's `--json` outputs: one JSON object on standard output per run, for scripts and CI,
//! beside the human text on standard error. Each shape is documented in docs/pabctl.md ("JSON
//! output") and held to it by the command-line tests; a field is added, never renamed.

use pab_lang::check::Report;
use pab_lang::compile::CompiledNode;
use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;
use serde_json::{Value, json};
use std::path::Path;

/// A diagnostic: `file`, `line` and `column` (1-based; null for a whole-file one), `message`.
pub fn diagnostic(d: &Diagnostic) -> Value {
    json!({
        "file": d.path.display().to_string(),
        "line": d.position.map(|(line, _)| line),
        "column": d.position.map(|(_, column)| column),
        "message": d.message,
    })
}

/// `pabctl check --json` on a file that could not be read or is invalid: `valid` false and its
/// `errors`.
pub fn invalid(path: &Path, errors: &[Diagnostic]) -> Value {
    json!({
        "file": path.display().to_string(),
        "valid": false,
        "consistent": null,
        "errors": errors.iter().map(diagnostic).collect::<Vec<_>>(),
        "warnings": [],
        "ports": [],
    })
}

/// `pabctl check --json`: `valid` true, `consistent`, per port its name, node, connections,
/// masks, the masks in which nothing delivers, every overlap (two connections and a smallest
/// set of active connections under which both deliver) and every connection that can never
/// deliver; the `errors` (the same as the text's) and the `warnings`.
pub fn check(path: &Path, network: &Network, report: &Report, warnings: &[&Diagnostic]) -> Value {
    let ports: Vec<Value> = report
        .ports
        .iter()
        .map(|port| {
            let names = network.port_connection_names(port.port);
            let name = |index: usize| names.get(index).cloned().unwrap_or_default();
            let active = |mask: u32| {
                (0..names.len())
                    .filter(|bit| mask & (1 << bit) != 0)
                    .map(name)
                    .collect::<Vec<_>>()
            };
            let (port_name, node) = network.ports.get(port.port).map_or(("?", "?"), |p| {
                (
                    p.name.as_str(),
                    network.nodes.get(p.node).map_or("?", |n| n.name.as_str()),
                )
            });
            json!({
                "port": port_name,
                "node": node,
                "consistent": port.is_consistent(),
                "connections": names,
                "masks": port.masks(),
                "idle_masks": port.idle_masks,
                "overlaps": port.overlaps.iter().map(|o| json!({
                    "first": name(o.first),
                    "second": name(o.second),
                    "active": active(o.mask),
                })).collect::<Vec<_>>(),
                "never_deliver": port.dead.iter().map(|&d| name(d)).collect::<Vec<_>>(),
            })
        })
        .collect();
    json!({
        "file": path.display().to_string(),
        "valid": true,
        "consistent": report.is_consistent(),
        "errors": report.errors(network).iter().map(diagnostic).collect::<Vec<_>>(),
        "warnings": warnings.iter().map(|d| diagnostic(d)).collect::<Vec<_>>(),
        "ports": ports,
    })
}

/// `pabctl compile --json`: per image written, its node, node id, file, size, table version,
/// ports, connections and decision nodes.
pub fn compiled(output: &Path, nodes: &[CompiledNode], table_version: u32) -> Value {
    Value::Array(
        nodes
            .iter()
            .map(|node| {
                json!({
                    "node": node.name,
                    "id": node.id,
                    "file": output.join(format!("{}.pab", node.name)).display().to_string(),
                    "bytes": node.image.len(),
                    "table_version": table_version,
                    "ports": node.ports,
                    "connections": node.connections,
                    "decision_nodes": node.decision_nodes,
                })
            })
            .collect(),
    )
}
