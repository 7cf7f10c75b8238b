//! The network file (host-tools' language): parsing, the consistency proof and compilation return
//! a value or errors that name a line and a cause, never panic; and what compiles loads. A file
//! with an `[hbba]` section that parses is solved (no desire, then every class desired at 1), and
//! the answer obeys the solver's constraints: at most one strategy per class, every resource
//! within capacity and its use the chosen costs' sum, filters that agree, requirements met, a
//! class without a desire only when a chosen strategy requires it, the objective Σ intensity ×
//! utility; or the search ran out of its budget.

use pab_core::hbba::{HbbaError, Intensities, MAX_CLASSES};
use pab_core::image::{self, Loaded};
use pab_lang::diagnostic::{Diagnostic, Source};
use pab_lang::network::{Hbba, Network, Solved};

/// The search budget of the solves here: enough for the examples, small enough to keep the
/// fuzzer fast.
const BUDGET: u32 = 20_000;

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
    if let Some(hbba) = &network.hbba {
        let mut all: Intensities = [0; MAX_CLASSES];
        for intensity in all.iter_mut().take(hbba.classes.len()) {
            *intensity = 1;
        }
        for intensities in [[0; MAX_CLASSES], all] {
            match hbba.solve(&intensities, BUDGET) {
                Ok(solved) => valid(hbba, &intensities, &solved),
                Err(HbbaError::BudgetExceeded { budget }) => assert_eq!(budget, BUDGET),
                Err(error) => panic!("the solver refused a parsed [hbba]: {error}"),
            }
        }
    }
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

/// The solver's answer obeys every constraint of the problem.
fn valid(hbba: &Hbba, intensities: &Intensities, solved: &Solved) {
    let chosen: Vec<_> = solved
        .strategies
        .iter()
        .map(|&s| &hbba.strategies[s])
        .collect();
    for (i, a) in chosen.iter().enumerate() {
        for b in &chosen[i + 1..] {
            assert_ne!(a.class, b.class, "two strategies of one class");
            for fa in &a.filters {
                for fb in &b.filters {
                    assert!(
                        fa.connection != fb.connection || fa.phi == fb.phi,
                        "{} and {} disagree on {}",
                        a.name,
                        b.name,
                        fa.name
                    );
                }
            }
        }
        for &(class, minimum) in &a.requires {
            assert!(
                chosen
                    .iter()
                    .any(|t| t.class == class && t.utility >= minimum),
                "{}'s requirement unmet",
                a.name
            );
        }
        if intensities[a.class] == 0 {
            assert!(
                chosen
                    .iter()
                    .any(|t| t.requires.iter().any(|&(class, _)| class == a.class)),
                "{} chosen without a desire or a requirement",
                a.name
            );
        }
    }
    for (r, resource) in hbba.resources.iter().enumerate() {
        let used: u64 = chosen.iter().map(|s| u64::from(s.costs[r])).sum();
        assert_eq!(solved.usage[r], used);
        assert!(
            used <= u64::from(resource.capacity),
            "{} over capacity",
            resource.name
        );
    }
    let objective: u64 = chosen
        .iter()
        .map(|s| u64::from(intensities[s.class]) * u64::from(s.utility))
        .sum();
    assert_eq!(solved.objective, objective);
}
