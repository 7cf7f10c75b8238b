//! HBBA's intention in virtual time: the intention node itself (`pab_intent::IntentNode`, what
//! the process `pab-intent` runs, on the setup `pabctl compile` writes) on the simulated bus,
//! with the nodes; what it selects and commands, recorded.
//!
//! A scripted desire is a Desire frame on the bus, issued at `from` by the tool (source 0, its
//! position in the file as its number) with a lease of [`LEASE_MS`], refreshed every half lease
//! while it lasts, and withdrawn (intensity 0) at `to`: the frames a motivation would send. The
//! intention node's FilterSet commands go to the simulated nodes, which apply and acknowledge
//! them (FilterStatus) in the same microsecond (the bus is ideal), so a plan's reductions and
//! increases share an instant, in that order ([`IntentionRun::commands`]); it hears the nodes'
//! first heartbeats at 0 and commands their filters then, as it does on a bus. A node of the
//! file's `[[faults]]` answers nothing from its time on: its commands are sent again and given
//! up, as on the bus. The lanes record the pass rate each filter is commanded (1/φ, 0 closed).

use pab_core::hbba::intention::{Event, Target};
use pab_core::protocol::{BROADCAST, DesireFrame, FilterSet, Message, TOOL};

use super::micros;
use crate::network::Network;
use crate::series::{Lane, LaneGroup, LaneStep};

/// The lease of a scripted desire, ms: refreshed every half of it.
pub const LEASE_MS: u16 = 60_000;

/// One filter command as the workspace sent it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SentCommand {
    /// When, µs.
    pub t_us: u64,
    /// The connection, as an index into the network's connections.
    pub connection: usize,
    /// The destination node id.
    pub node: u8,
    /// The command.
    pub set: FilterSet,
    /// Whether it belongs to the plan's reductions (sent first).
    pub reduction: bool,
}

/// A change of the selected strategies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SelectionChange {
    /// When, µs.
    pub t_us: u64,
    /// Bit s: strategy s (the file's order) runs.
    pub strategies: u64,
    /// Σ intensity × utility.
    pub objective: u64,
}

/// What the intention did in a simulation.
#[derive(Clone, Debug, Default)]
pub struct IntentionRun {
    /// The selection's changes, the first at 0 (nothing desired yet).
    pub selections: Vec<SelectionChange>,
    /// Every filter command, in the order sent.
    pub commands: Vec<SentCommand>,
    /// The filtered connections (network indices), in the order of first appearance among the
    /// strategies.
    pub filtered: Vec<usize>,
    /// What the workspace reported besides: refusals, give-ups, solve failures, as text with
    /// their time, µs.
    pub notes: Vec<(u64, String)>,
}

impl IntentionRun {
    /// A run of the intention node on `setup`: nothing selected, nothing sent yet.
    pub(super) fn new(setup: &pab_intent::Setup) -> IntentionRun {
        IntentionRun {
            filtered: setup
                .targets
                .iter()
                .map(|t| usize::from(t.connection))
                .collect(),
            ..IntentionRun::default()
        }
    }

    /// What the intention node did at `t_us` ([`pab_intent::Observed`]), recorded.
    pub(super) fn observe(
        &mut self,
        network: &Network,
        targets: &[Target],
        t_us: u64,
        observed: pab_intent::Observed,
    ) {
        match observed {
            pab_intent::Observed::Command(command) => self.commands.push(SentCommand {
                t_us,
                connection: targets
                    .iter()
                    .find(|t| {
                        t.node == command.node
                            && t.port == command.set.port
                            && t.index == command.set.connection
                    })
                    .map_or(usize::MAX, |t| usize::from(t.connection)),
                node: command.node,
                set: command.set,
                reduction: command.reduction,
            }),
            pab_intent::Observed::Event(event) => self.event(network, t_us, event),
            _ => {}
        }
    }

    fn event(&mut self, network: &Network, t_us: u64, event: Event) {
        let note = match event {
            Event::Selected {
                strategies,
                objective,
            } => {
                self.selections.push(SelectionChange {
                    t_us,
                    strategies,
                    objective,
                });
                return;
            }
            Event::SolveFailed(error) => {
                format!("solving failed, the previous selection stays: {error}")
            }
            Event::Refused { target, phi, why } => format!(
                "node {} refused {} φ {phi} (FilterRefused, detail {why})",
                target.node,
                filter_name(network, &target)
            ),
            Event::GaveUp { target, phi } => format!(
                "node {} did not answer {} φ {phi} after {} sends (stopped)",
                target.node,
                filter_name(network, &target),
                pab_core::hbba::intention::MAX_SENDS
            ),
            Event::Restarted { node } => format!("node {node}: its filters commanded again"),
            _ => return,
        };
        self.notes.push((t_us, note));
    }
}

/// "CONNECTION (PORT)" of a filter target.
fn filter_name(network: &Network, target: &Target) -> String {
    let connection = network.connections.get(usize::from(target.connection));
    let port = connection
        .and_then(|c| network.ports.get(c.port))
        .map_or("?", |p| p.name.as_str());
    format!("{} ({port})", connection.map_or("?", |c| c.name.as_str()))
}

/// The Desire frames of the `[[desires]]`, in time order (file order within an instant): each
/// issued at `from`, refreshed every half lease, withdrawn at `to`; none after `until_us`.
pub(super) fn desire_frames(network: &Network, until_us: u64) -> Vec<super::BusFrame> {
    let mut frames = Vec::new();
    let refresh = u64::from(LEASE_MS) * 1000 / 2;
    for (number, desire) in network.desires.iter().enumerate() {
        let id = u16::try_from(number).unwrap_or(u16::MAX);
        let class = u8::try_from(desire.class).unwrap_or(u8::MAX);
        let (from, to) = (micros(desire.from), micros(desire.to));
        let mut t = from;
        while t < to && t <= until_us {
            frames.push((
                t,
                TOOL,
                DesireFrame {
                    class,
                    intensity: desire.intensity,
                    lease_ms: LEASE_MS,
                    id,
                },
            ));
            t = t.saturating_add(refresh);
        }
        if to <= until_us {
            frames.push((
                to,
                TOOL,
                DesireFrame {
                    class,
                    intensity: 0,
                    lease_ms: LEASE_MS,
                    id,
                },
            ));
        }
    }
    // Stable: the file's order within an instant.
    frames.sort_by_key(|(t, ..)| *t);
    frames
        .into_iter()
        .map(|(t_us, source, desire)| super::BusFrame {
            t_us,
            // To all, as a motivation sends it (the intention node takes a desire addressed to
            // it or to all).
            frame: Message::Desire(desire).to_frame(source, BROADCAST),
        })
        .collect()
}

impl IntentionRun {
    /// The plot's lanes: one per strategy (full while it is selected), then one per filtered
    /// connection (its commanded pass rate, 1/φ, 0 while closed; boot: closed).
    pub fn lanes(&self, network: &Network) -> Vec<LaneGroup> {
        let Some(hbba) = &network.hbba else {
            return Vec::new();
        };
        let strategies = hbba
            .strategies
            .iter()
            .enumerate()
            .map(|(index, strategy)| {
                let bit = 1u64.checked_shl(index as u32).unwrap_or(0);
                let class = hbba.classes.get(strategy.class).map_or("?", String::as_str);
                let filters: Vec<String> = strategy
                    .filters
                    .iter()
                    .map(|f| format!("{} φ {}", f.name, f.phi))
                    .collect();
                Lane {
                    name: strategy.name.clone(),
                    label: format!(
                        "{}  {class}  u {}  {}",
                        strategy.name,
                        strategy.utility,
                        filters.join(", ")
                    ),
                    steps: self
                        .selections
                        .iter()
                        .map(|s| LaneStep {
                            t: s.t_us as f64 / 1e6,
                            value: if s.strategies & bit != 0 { 1.0 } else { 0.0 },
                            text: None,
                        })
                        .collect(),
                }
            })
            .collect();
        let filters = self
            .filtered
            .iter()
            .map(|&connection| {
                let c = network.connections.get(connection);
                let name = c.map_or("?".to_string(), |c| c.name.clone());
                let port = c
                    .and_then(|c| network.ports.get(c.port))
                    .map_or("?", |p| p.name.as_str());
                let mut steps = vec![LaneStep {
                    t: 0.0,
                    value: 0.0,
                    text: Some("φ 0".to_string()),
                }];
                for command in self.commands.iter().filter(|c| c.connection == connection) {
                    let phi = command.set.phi;
                    let step = LaneStep {
                        t: command.t_us as f64 / 1e6,
                        value: pass_rate(phi),
                        text: Some(format!("φ {phi}")),
                    };
                    // Several commands in one microsecond (a two-step, or the boot state and
                    // the first command): the last one holds.
                    match steps.last_mut() {
                        Some(last) if last.t == step.t => *last = step,
                        _ => steps.push(step),
                    }
                }
                Lane {
                    name: name.clone(),
                    label: format!("{name}  {port}  pass rate"),
                    steps,
                }
            })
            .collect();
        vec![
            LaneGroup {
                name: "HBBA intention: selected strategies".to_string(),
                lanes: strategies,
            },
            LaneGroup {
                name: "HBBA filters: commanded pass rate (1/φ, 0 closed)".to_string(),
                lanes: filters,
            },
        ]
    }

    /// What the report of `pabctl sim` says: each change of the selection with the filter
    /// commands of that instant, in the order sent, then the workspace's notes.
    pub fn report(&self, network: &Network) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        let Some(hbba) = &network.hbba else {
            return out;
        };
        let _ = writeln!(
            out,
            "HBBA intention ({} scripted desire{}): selected strategies and filter commands",
            network.desires.len(),
            if network.desires.len() == 1 { "" } else { "s" }
        );
        let mut instants: Vec<u64> = self
            .selections
            .iter()
            .map(|s| s.t_us)
            .chain(self.commands.iter().map(|c| c.t_us))
            .collect();
        instants.sort_unstable();
        instants.dedup();
        for t in instants {
            for change in self.selections.iter().filter(|s| s.t_us == t) {
                let names: Vec<&str> = hbba
                    .strategies
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| change.strategies >> i & 1 == 1)
                    .map(|(_, s)| s.name.as_str())
                    .collect();
                let names = if names.is_empty() {
                    "none".to_string()
                } else {
                    names.join(", ")
                };
                let _ = writeln!(
                    out,
                    "  {:>14}  {names} (objective {})",
                    super::seconds_text(t),
                    change.objective
                );
            }
            for command in self.commands.iter().filter(|c| c.t_us == t) {
                let name = network
                    .connections
                    .get(command.connection)
                    .map_or("?", |c| c.name.as_str());
                let _ = writeln!(
                    out,
                    "  {:>14}    {} {name} φ {} (node {} port {} connection {}, seq {})",
                    "",
                    if command.reduction {
                        "reduce  "
                    } else {
                        "increase"
                    },
                    command.set.phi,
                    command.node,
                    command.set.port,
                    command.set.connection,
                    command.set.sequence
                );
            }
        }
        for (t, note) in &self.notes {
            let _ = writeln!(out, "  {:>14}  {note}", super::seconds_text(*t));
        }
        out
    }

    /// The commanded φ of network connection `connection` at `t_us` (after the commands of that
    /// microsecond): 0 before any.
    pub fn phi_at(&self, connection: usize, t_us: u64) -> u8 {
        self.commands
            .iter()
            .rfind(|c| c.connection == connection && c.t_us <= t_us)
            .map_or(0, |c| c.set.phi)
    }

    /// The selected strategies at `t_us` (after the changes of that microsecond).
    pub fn strategies_at(&self, t_us: u64) -> u64 {
        self.selections
            .iter()
            .rfind(|s| s.t_us <= t_us)
            .map_or(0, |s| s.strategies)
    }
}

/// 1/φ, 0 for φ 0.
pub fn pass_rate(phi: u8) -> f64 {
    if phi == 0 { 0.0 } else { 1.0 / f64::from(phi) }
}
