//! HBBA's intention in virtual time: the network's `[[desires]]` fed to the intention workspace
//! (`pab_core::hbba::intention::Workspace`, the code `pab-intent` runs), its filter commands
//! answered by simulated nodes, the selected strategies and each filtered connection's commanded
//! φ recorded.
//!
//! A scripted desire is issued at `from` by the tool (source 0, its position in the file as its
//! number) with a lease of [`LEASE_MS`], refreshed every half lease while it lasts, and withdrawn
//! (intensity 0) at `to`: the frames a motivation would send. The simulated bus is ideal, as for
//! the arbitrated frames: a node applies a filter command and acknowledges it (FilterStatus) at
//! the microsecond it is sent, so a plan's reductions and increases share an instant, in that
//! order ([`IntentionRun::commands`]). Nodes boot with every filter closed. A node of the file's
//! `[[faults]]` answers nothing from its time on: its commands are sent again and given up, as
//! on the bus.
//!
//! The commands are frames on the simulated bus ([`IntentionRun::command_frames`]): the
//! arbitration ([`super::simulate`]) applies each to the node it addresses at the instant it is
//! sent, so the ports see the filters the intention commands (filtered connections start closed,
//! as on the boards). The lanes record the pass rate each filter is commanded (1/φ, 0 closed).

use pab_core::Instant;
use pab_core::hbba::intention::{Event, Target, Workspace};
use pab_core::protocol::{DesireFrame, FilterSet, FilterStatus, TOOL};

use super::{SimError, micros};
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

/// Runs the intention on the network's `[[desires]]` until `until_us`; `None` without `[hbba]`.
pub fn simulate(network: &Network, until_us: u64) -> Result<Option<IntentionRun>, SimError> {
    let Some(hbba) = &network.hbba else {
        return Ok(None);
    };
    let instance = hbba.instance();
    let targets = network.filter_targets().map_err(SimError)?;
    let mut workspace = Workspace::new(&instance, &targets)
        .map_err(|error| SimError(format!("[hbba]: {error}")))?;
    workspace.assume_filters(0);
    let stops: Vec<(u8, u64)> = network
        .faults
        .iter()
        .filter_map(|f| Some((network.nodes.get(f.node)?.id, micros(f.at))))
        .collect();
    let stopped = |node: u8, t_us: u64| stops.iter().any(|&(id, at)| id == node && at <= t_us);
    let script = desire_frames(network, until_us);
    let mut run = IntentionRun {
        filtered: targets.iter().map(|t| usize::from(t.connection)).collect(),
        ..IntentionRun::default()
    };
    let mut pending = script.iter().peekable();
    let mut now_us = 0u64;
    loop {
        let at = Instant::from_micros(now_us);
        while let Some((_, source, frame)) = pending.next_if(|(t, ..)| *t <= now_us) {
            if let Err(error) = workspace.on_desire(*source, frame, at) {
                run.notes
                    .push((now_us, format!("desire {} refused: {error:?}", frame.id)));
            }
        }
        workspace.poll(at);
        // The ideal bus: a running node applies and acknowledges at once, which may let the
        // increases go in the same instant.
        while let Some(command) = workspace.next_command(at) {
            run.commands.push(SentCommand {
                t_us: now_us,
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
            });
            if !stopped(command.node, now_us) {
                let status = FilterStatus {
                    profile: FilterStatus::SET_ONE_BY_ONE,
                    sequence: command.set.sequence,
                    filtered: 0,
                    closed: 0,
                    throttled: 0,
                };
                workspace.on_filter_status(command.node, &status);
            }
        }
        while let Some(event) = workspace.next_event() {
            match event {
                Event::Selected {
                    strategies,
                    objective,
                } => run.selections.push(SelectionChange {
                    t_us: now_us,
                    strategies,
                    objective,
                }),
                Event::Acknowledged { .. } | Event::Settled { .. } | Event::Expired => {}
                Event::SolveFailed(error) => run.notes.push((
                    now_us,
                    format!("solving failed, the previous selection stays: {error}"),
                )),
                Event::Refused { target, phi, why } => run.notes.push((
                    now_us,
                    format!(
                        "node {} refused {} φ {phi} (FilterRefused, detail {why})",
                        target.node,
                        filter_name(network, &target)
                    ),
                )),
                Event::GaveUp { target, phi } => run.notes.push((
                    now_us,
                    format!(
                        "node {} did not answer {} φ {phi} after {} sends (stopped)",
                        target.node,
                        filter_name(network, &target),
                        pab_core::hbba::intention::MAX_SENDS
                    ),
                )),
                Event::Restarted { node } => run
                    .notes
                    .push((now_us, format!("node {node}: its filters commanded again"))),
            }
        }
        let next_script = pending.peek().map(|(t, ..)| *t);
        let next_workspace = workspace
            .deadline(at)
            .map(Instant::as_micros)
            .map(|t| t.max(now_us + 1));
        let Some(next) = [next_script, next_workspace].into_iter().flatten().min() else {
            break;
        };
        if next > until_us {
            break;
        }
        now_us = next;
    }
    Ok(Some(run))
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
fn desire_frames(network: &Network, until_us: u64) -> Vec<(u64, u8, DesireFrame)> {
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
    frames.sort_by_key(|(t, ..)| *t);
    frames
}

impl IntentionRun {
    /// The filter commands as the frames the intention node sends (from
    /// [`pab_core::protocol::INTENTION`] to each command's node), in the order sent.
    pub fn command_frames(&self) -> Vec<super::BusFrame> {
        self.commands
            .iter()
            .map(|c| super::BusFrame {
                t_us: c.t_us,
                frame: pab_core::protocol::Message::FilterSet(c.set)
                    .to_frame(pab_core::protocol::INTENTION, c.node),
            })
            .collect()
    }

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
