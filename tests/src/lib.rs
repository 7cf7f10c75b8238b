//! Helpers for the end-to-end tests: run an example network through the real pipeline (parse,
//! prove, compile to images, load the images into `pab-core` arbiters, simulate) and state what
//! must deliver where, phase by phase.

use std::path::PathBuf;

use pab_lang::diagnostic::Source;
use pab_lang::network::Network;
use pab_lang::sim::{self, Outcome};
use pab_lang::{check, compile};

/// The repository's `examples/` directory.
pub fn examples_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// The text of `examples/<name>.toml`.
pub fn example_text(name: &str) -> String {
    let path = examples_dir().join(format!("{name}.toml"));
    std::fs::read_to_string(&path).unwrap_or_else(|error| panic!("{}: {error}", path.display()))
}

/// The text of `examples/dynamics/<name>.toml`: DESIGN.md's competitive-dynamics scenarios.
pub fn dynamics_example_text(name: &str) -> String {
    example_text(&format!("dynamics/{name}"))
}

/// A network parsed from `text`, named `name` in diagnostics.
pub fn network(name: &str, text: &str) -> Network {
    Network::parse(Source::new(format!("{name}.toml"), text))
        .unwrap_or_else(|errors| panic!("{errors}"))
}

/// A simulated example.
pub struct Scenario {
    /// The network.
    pub network: Network,
    /// What the simulation produced.
    pub outcome: Outcome,
}

impl Scenario {
    /// Proves, compiles and simulates `examples/<name>.toml` to its default end.
    pub fn run(name: &str) -> Scenario {
        let network = network(name, &example_text(name));
        let report = check::check(&network);
        assert!(
            report.is_consistent(),
            "{name}: {:?}",
            report.errors(&network)
        );
        let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
        let outcome = sim::simulate(&network, &nodes, &sim::Options::default())
            .unwrap_or_else(|error| panic!("{error}"));
        Scenario { network, outcome }
    }

    fn port(&self, name: &str) -> usize {
        self.network
            .ports
            .iter()
            .position(|port| port.name == name)
            .unwrap_or_else(|| panic!("no port {name}"))
    }

    /// The network index of connection `name`.
    pub fn connection(&self, name: &str) -> usize {
        self.network
            .connections
            .iter()
            .position(|connection| connection.name == name)
            .unwrap_or_else(|| panic!("no connection {name}"))
    }

    fn name_of(&self, connection: Option<usize>) -> String {
        connection.map_or("nobody".into(), |c| {
            self.network.connections[c].name.clone()
        })
    }

    /// Asserts that from `from` to `to` seconds, port `port` is held by `expected` (a connection
    /// name, or `None` for nobody): the port's timeline says so at every 10 ms, every frame
    /// delivered on the port comes through `expected`, and, if `expected` is a connection, some
    /// of its frames are delivered.
    pub fn expect(&self, phase: &str, from: f64, to: f64, port: &str, expected: Option<&str>) {
        let port_index = self.port(port);
        let expected_index = expected.map(|name| self.connection(name));
        let (from_us, to_us) = (sim::micros(from), sim::micros(to));
        let mut t = from_us;
        while t < to_us {
            let selected = self.outcome.selected_at(port_index, t);
            assert_eq!(
                selected,
                expected_index,
                "phase {phase}, {port} at {} s: {} is selected, expected {}",
                sim::seconds_text(t),
                self.name_of(selected),
                self.name_of(expected_index)
            );
            t += 10_000;
        }
        let mut delivered = 0;
        for &connection in &self.network.ports[port_index].connections {
            for row in self.outcome.rows_of(connection, from_us, to_us) {
                if row.delivered {
                    assert_eq!(
                        Some(connection),
                        expected_index,
                        "phase {phase}, {port} at {} s: a frame of {} was delivered, expected {}",
                        sim::seconds_text(row.t_us),
                        self.name_of(Some(connection)),
                        self.name_of(expected_index)
                    );
                    delivered += 1;
                }
            }
        }
        if let Some(name) = expected {
            assert!(
                delivered > 0,
                "phase {phase}, {port}: {name} delivered no frame"
            );
        }
    }

    /// Frames delivered through connection `name` between `from` and `to` seconds.
    pub fn delivered(&self, name: &str, from: f64, to: f64) -> usize {
        self.outcome
            .rows_of(self.connection(name), sim::micros(from), sim::micros(to))
            .filter(|row| row.delivered)
            .count()
    }
}

/// One phase of a scenario: a time window in which the arbitration has settled, and the
/// connection that must deliver at Arm, Gaze and Hand Control.
pub struct Phase {
    /// The paper's letter.
    pub name: &'static str,
    /// Start, seconds.
    pub from: f64,
    /// End, seconds.
    pub to: f64,
    /// At `arm.target`.
    pub arm: Option<&'static str>,
    /// At `gaze.target`.
    pub gaze: Option<&'static str>,
    /// At `hand.command`.
    pub hand: Option<&'static str>,
}

/// A [`Phase`] in one line: `phase("B", 2.6, 6.0, Some("C1"), Some("C3"), None)` is phase B
/// from 2.6 s to 6 s with C1 delivering at the arm, C3 at the gaze and nothing at the hand.
pub const fn phase(
    name: &'static str,
    from: f64,
    to: f64,
    arm: Option<&'static str>,
    gaze: Option<&'static str>,
    hand: Option<&'static str>,
) -> Phase {
    Phase {
        name,
        from,
        to,
        arm,
        gaze,
        hand,
    }
}

impl Scenario {
    /// Checks each phase in turn.
    pub fn expect_phases(&self, phases: &[Phase]) {
        let mut previous_end = f64::NEG_INFINITY;
        for phase in phases {
            assert!(
                phase.from >= previous_end,
                "phases must be listed in time order"
            );
            previous_end = phase.to;
            self.expect(phase.name, phase.from, phase.to, "arm.target", phase.arm);
            self.expect(phase.name, phase.from, phase.to, "gaze.target", phase.gaze);
            self.expect(phase.name, phase.from, phase.to, "hand.command", phase.hand);
        }
    }
}
