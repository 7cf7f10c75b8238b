//! The network file (host-tools' language): parsing, the consistency proof and compilation return
//! a value or errors that name a line and a cause, never panic; and what compiles loads.

use pab_core::image::{self, Loaded};
use pab_lang::diagnostic::{Diagnostic, Source};
use pab_lang::network::Network;

/// Parses, checks and compiles the text (invalid UTF-8 is replaced, as an editor would show it).
pub fn check(data: &[u8]) {
    let text = String::from_utf8_lossy(data).into_owned();
    let lines = text.lines().count().max(1);
    let clear = |diagnostics: &[Diagnostic]| {
        assert!(!diagnostics.is_empty(), "refused without a reason");
        for diagnostic in diagnostics {
            assert!(!diagnostic.message.trim().is_empty(), "an empty message");
            if let Some((line, column)) = diagnostic.position {
                assert!(line >= 1 && line <= lines + 1, "line {line} of {lines}");
                assert!(column >= 1);
            }
            assert!(!diagnostic.to_string().is_empty());
        }
    };
    let network = match Network::parse(Source::new("fuzz.toml", text.as_str())) {
        Ok(network) => network,
        Err(diagnostics) => {
            clear(&diagnostics.0);
            return;
        }
    };
    let report = pab_lang::check::check(&network);
    let _ = report.summary(&network);
    let errors = report.errors(&network);
    if !report.is_consistent() {
        clear(&errors);
    }
    match pab_lang::compile::compile(&network) {
        Ok(nodes) => {
            assert!(report.is_consistent(), "an inconsistent network compiled");
            assert_eq!(nodes.len(), network.nodes.len());
            for node in nodes {
                let loaded: Loaded = image::load(&node.image)
                    .unwrap_or_else(|error| panic!("node {}'s image: {error}", node.name));
                assert_eq!(loaded.header.node_id, node.id);
                assert_eq!(loaded.header.table_version, network.version);
                assert_eq!(loaded.table.port_count(), node.ports);
                assert_eq!(loaded.table.connection_count(), node.connections);
                assert_eq!(loaded.table.node_count(), node.decision_nodes);
            }
        }
        Err(diagnostics) => clear(&diagnostics),
    }
}
