//! The simulator: every node of a network on one simulated bus, in virtual time.
//!
//! Each node loads its compiled table image with `pab_core::image::load` and arbitrates with
//! `pab_core::Arbiter`: the same bytes and the same code as a board, so a simulation shows what
//! the robot will do. Nothing here decides who delivers.
//!
//! The bus is ideal (no transmission time, no loss) and deterministic: frames due at the same
//! microsecond go out in CAN arbitration order (lower identifier first; a standard frame before
//! an extended one with the same 11 base bits), then in the order of the `[[events]]`.
//!
//! A node of the file's `[[faults]]` stops at its time: from that microsecond on (a frame sent at
//! the same microsecond included) it receives nothing and its ports deliver nothing; its
//! timelines show nobody from then on and its plotted levels drop to 0. (Nodes send nothing on the
//! simulated bus: every frame comes from `[[events]]`, so a stopped node has nothing to withhold.)
//!
//! Besides frames, the simulator evaluates each port when an activity may lapse (a microsecond
//! after τ has passed since a connection's last accepted frame), so timelines show the moment a
//! port changes hands even when no frame arrives then. These evaluations only read the arbiter.
//!
//! A value port (`combine = ...`) delivers the combined output when it changes
//! ([`pab_core::value_port`]): its trace rows mark `delivered` on the connection whose frame was
//! handed over, and its timeline follows the output's connection; the simulator calls
//! [`Arbiter::poll`] at each wake so that values age out on time.
//!
//! BLE groups (`[ble.NAME]`): every node runs its groups with the board's code
//! ([`Arbiter::ble_poll`] at its [`Arbiter::ble_deadline`] and after each frame it receives, as a
//! node does), and its claims go on the simulated bus at that microsecond, to every other running
//! node, in CAN arbitration order ([`Outcome::claims`]); [`Outcome::holdings`] follows who holds
//! each group's task. A stopped node sends no claim, so its peers take its task over once its last
//! claim is two periods old.
//!
//! [`run`] is the same bus fed with any timed frames: a capture's, for `pabctl replay`
//! (see [`crate::replay`]). With [`Options::records`] it also writes every verdict in the record
//! format of [`pab_app::replay::records`], the one the other runners write.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::fmt::Write as _;
use std::io::{self, Write};

use embedded_can::{ExtendedId, Id, StandardId};
use pab_app::replay::records;
use pab_core::ble::Claim;
use pab_core::image;
use pab_core::{Arbiter, Frame, Instant};

use crate::compile::CompiledNode;
use crate::network::{MAX_TIME_S, Network};
use crate::series::{ConnectionSeries, Phase, PlotData, PortSeries, Sample, Shows};

mod dynamics;
pub mod intention;
pub mod plant;
pub mod schema;

pub use dynamics::{DynamicsRow, write_csv as write_dynamics_csv};
pub use intention::IntentionRun;
// The conversions live with the model, which reads times too; kept here for the tools' paths.
pub use crate::time::{micros, seconds_text};

/// How to run a simulation.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Stop at this time, seconds. Default: when the last frame's effects have decayed (the last
    /// frame plus the longest τ, or the end of the last phase or the last fault, whichever is
    /// later).
    pub until: Option<f64>,
    /// Record stimulation samples for a plot.
    pub samples: bool,
    /// Write every verdict as a record line ([`Outcome::records`]).
    pub records: bool,
    /// Step the `[dynamics.*]` groups and record their states ([`Outcome::dynamics`]).
    pub dynamics: bool,
}

/// A frame on the simulated bus and when it is sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BusFrame {
    /// When, µs.
    pub t_us: u64,
    /// The frame (an event's frames carry its `data`, by default its topic's `length` of zeros).
    pub frame: pab_core::Frame,
}

/// One row of the trace: a frame's effect on one connection it fed, after the update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceRow {
    /// When, µs.
    pub t_us: u64,
    /// The connection, as an index into the network's connections.
    pub connection: usize,
    /// Its stimulation after the frame.
    pub level: f64,
    /// Whether it is active after the frame.
    pub active: bool,
    /// Whether the frame was delivered through it.
    pub delivered: bool,
}

/// A change of the connection selected at a port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Change {
    /// When, µs.
    pub t_us: u64,
    /// The connection whose frames get through from then on (network index), or nobody.
    pub selected: Option<usize>,
}

/// What a simulation produced.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The end of the simulated time, µs.
    pub until_us: u64,
    /// Frames put on the bus.
    pub frames: usize,
    /// Trace rows in time order, ties in the order of the connections in the file.
    pub rows: Vec<TraceRow>,
    /// Per port (network order), the changes of its selected connection, starting with nobody at 0.
    pub timelines: Vec<Vec<Change>>,
    /// Per connection (network order), stimulation samples for plots (empty unless requested).
    pub samples: Vec<Vec<Sample>>,
    /// Every verdict in the record format (empty unless [`Options::records`]).
    pub records: String,
    /// The BLE claims the nodes sent, in bus order (none when the frames were given: [`run`]).
    pub claims: Vec<BusFrame>,
    /// Per BLE group (network order), the changes of who holds its task, starting with nobody at
    /// 0: node indices, in network order (more than one during a transient).
    pub holdings: Vec<Vec<Holding>>,
    /// The `[dynamics.*]` groups' states, one row per behaviour per step, in time order, then
    /// group and behaviour order (empty unless [`Options::dynamics`]).
    pub dynamics: Vec<DynamicsRow>,
    /// The Gates frames the nodes sent, in bus order.
    pub gates: Vec<BusFrame>,
    /// HBBA's intention on the `[[desires]]` ([`intention`]), with `[hbba]` in [`simulate`]
    /// only (a replay has no script).
    pub intention: Option<IntentionRun>,
    /// The intention node's filter commands on the bus (FilterSet frames), in the order sent.
    pub commands: Vec<BusFrame>,
}

/// A change of the nodes that hold a BLE group's task.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Holding {
    /// When, µs.
    pub t_us: u64,
    /// The nodes that hold it from then on (network indices, in order).
    pub holders: Vec<usize>,
}

/// Why a simulation could not run.
#[derive(Debug)]
pub struct SimError(pub String);

impl std::fmt::Display for SimError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SimError {}

struct Station {
    /// Node index in the network.
    node: usize,
    /// Its node id.
    id: u8,
    arbiter: Arbiter,
    /// When it stops (`[[faults]]`), µs.
    stop_us: Option<u64>,
    /// The last instant it polled its BLE groups, µs (`None`: not yet).
    last_us: Option<u64>,
    /// The last instant it polled its dynamics, µs (`None`: not yet).
    dynamics_last_us: Option<u64>,
}

impl Station {
    /// Whether it has stopped by `t_us`.
    fn stopped(&self, t_us: u64) -> bool {
        self.stop_us.is_some_and(|stop| stop <= t_us)
    }

    /// When it next has work of a kind it last polled at `last` (µs; `None`: never, so at 0),
    /// `deadline` saying when from that instant: strictly after `last`, whose work is done, and
    /// `None` once it has stopped.
    fn next_due(
        &self,
        last: Option<u64>,
        deadline: impl Fn(Instant) -> Option<Instant>,
    ) -> Option<u64> {
        let Some(last) = last else {
            return Some(0);
        };
        let from = Instant::from_micros(last);
        let ahead = deadline(from)?.micros_since(from).unwrap_or(0).max(1);
        Some(last.saturating_add(ahead)).filter(|&t| !self.stopped(t))
    }
}

/// Runs `network` with the tables `compiled` (one per node, from [`crate::compile::compile`]) on
/// the frames of its `[[events]]`.
pub fn simulate(
    network: &Network,
    compiled: &[CompiledNode],
    options: &Options,
) -> Result<Outcome, SimError> {
    let frames = event_frames(network)?;
    let until_us = match options.until {
        Some(until) if (0.0..=MAX_TIME_S).contains(&until) => micros(until),
        Some(until) => {
            return Err(SimError(format!(
                "--until {until} is not a time in [0, {MAX_TIME_S}] seconds"
            )));
        }
        None => default_until(network, &frames),
    };
    let stops: Vec<(u64, usize)> = network
        .faults
        .iter()
        .map(|fault| (micros(fault.at), fault.node))
        .collect();
    // HBBA's intention first: its filter commands are frames on the simulated bus like any other
    // (the nodes apply them at the instant they are sent, before the topics' frames of that
    // instant), so the arbitration below sees the filters it commands.
    let intention = intention::simulate(network, until_us)?;
    let commands = intention
        .as_ref()
        .map(IntentionRun::command_frames)
        .unwrap_or_default();
    let mut all: Vec<(u64, u8, BusFrame)> = commands
        .iter()
        .map(|f| (f.t_us, 0, *f))
        .chain(frames.iter().map(|f| (f.t_us, 1, *f)))
        .collect();
    all.sort_by_key(|(t, kind, _)| (*t, *kind));
    let frames: Vec<BusFrame> = all.into_iter().map(|(_, _, f)| f).collect();
    let mut outcome = run_stopping(
        network,
        compiled,
        &frames,
        until_us,
        options,
        &stops,
        true,
        &mut |_| {},
    )?;
    outcome.commands = commands;
    outcome.intention = intention;
    Ok(outcome)
}

/// Runs `network` with the tables `compiled` on `frames` (in the order given, which must be time
/// order) until `until_us`: frames after it are not sent. `progress` is called with the number
/// of frames sent so far, every 65 536 frames and at the end. Nothing here reads
/// [`Options::until`].
pub fn run(
    network: &Network,
    compiled: &[CompiledNode],
    frames: &[BusFrame],
    until_us: u64,
    options: &Options,
    progress: &mut dyn FnMut(usize),
) -> Result<Outcome, SimError> {
    run_stopping(
        network,
        compiled,
        frames,
        until_us,
        options,
        &[],
        false,
        progress,
    )
}

/// [`run`], with nodes that stop: `(t_us, node)`, the node as an index into the network's nodes.
/// With `broadcast`, the nodes' BLE claims go on the bus and nodes poll their groups at their
/// deadlines; without (a replay: the bus is the frames given, claims included), a node polls
/// after each frame it receives and what it would send is dropped, as on a replayed node.
#[allow(clippy::too_many_arguments)]
fn run_stopping(
    network: &Network,
    compiled: &[CompiledNode],
    frames: &[BusFrame],
    until_us: u64,
    options: &Options,
    stops: &[(u64, usize)],
    broadcast: bool,
    progress: &mut dyn FnMut(usize),
) -> Result<Outcome, SimError> {
    let mut records = String::new();
    if options.records {
        let _ = records::write_preamble(&mut records);
    }
    let mut stations = Vec::new();
    for (node_index, node) in network.nodes.iter().enumerate() {
        let Some(table) = compiled.iter().find(|c| c.id == node.id) else {
            return Err(SimError(format!(
                "no compiled table for node `{}`",
                node.name
            )));
        };
        let loaded: image::Loaded = image::load(&table.image).map_err(|error| {
            SimError(format!(
                "node `{}`: its image does not load: {error}",
                node.name
            ))
        })?;
        if options.records {
            let _ = records::write_boot(&mut records, node.id, Ok(&loaded.header));
        }
        let arbiter = Arbiter::new(loaded.table)
            .map_err(|error| SimError(format!("node `{}`: {error}", node.name)))?;
        let stop_us = stops
            .iter()
            .filter(|(_, node)| *node == node_index)
            .map(|(t, _)| *t)
            .min();
        stations.push(Station {
            node: node_index,
            id: node.id,
            arbiter,
            stop_us,
            last_us: None,
            dynamics_last_us: None,
        });
    }
    if options.records {
        let _ = records::write_columns(&mut records);
    }
    if frames
        .windows(2)
        .any(|pair| matches!(pair, [a, b] if b.t_us < a.t_us))
    {
        return Err(SimError("the frames are not in time order".into()));
    }
    let mut run = Run {
        network,
        stations,
        dynamics_rows: Vec::new(),
        gates: Vec::new(),
        dynamics_polled: Vec::new(),
        options,
        rows: Vec::new(),
        timelines: network
            .ports
            .iter()
            .map(|_| {
                vec![Change {
                    t_us: 0,
                    selected: None,
                }]
            })
            .collect(),
        samples: vec![Vec::new(); network.connections.len()],
        wakes: BinaryHeap::new(),
        records: options.records.then_some(records),
        verdicts: 0,
        broadcast,
        outbox: Vec::new(),
        claims: Vec::new(),
        holdings: network
            .groups
            .iter()
            .map(|_| {
                vec![Holding {
                    t_us: 0,
                    holders: Vec::new(),
                }]
            })
            .collect(),
    };
    let has_groups = !network.groups.is_empty();
    let grid = (until_us / 1500).max(1);
    let mut next_grid = 0u64;
    let mut sent = 0usize;
    let mut pending = frames.iter().peekable();
    let mut halts: Vec<(u64, usize)> = run
        .stations
        .iter()
        .enumerate()
        .filter_map(|(station, entry)| Some((entry.stop_us?, station)))
        .collect();
    halts.sort_unstable();
    let mut halts = halts.into_iter().peekable();
    loop {
        let next_frame = pending
            .peek()
            .map(|frame| frame.t_us)
            .filter(|&t| t <= until_us);
        let next_wake = run
            .wakes
            .peek()
            .map(|Reverse((t, _))| *t)
            .filter(|&t| t <= until_us);
        let next_sample = (options.samples && next_grid <= until_us).then_some(next_grid);
        let next_halt = halts.peek().map(|(t, _)| *t).filter(|&t| t <= until_us);
        let next_step = run.dynamics_deadline().filter(|&t| t <= until_us);
        let next_ble = if broadcast && has_groups {
            run.ble_deadline().filter(|&t| t <= until_us)
        } else {
            None
        };
        let Some(now) = [
            next_frame,
            next_wake,
            next_sample,
            next_halt,
            next_ble,
            next_step,
        ]
        .into_iter()
        .flatten()
        .min() else {
            break;
        };
        // A node stops before the frames of its instant: it receives none of them.
        while let Some((_, station)) = halts.next_if(|(t, _)| *t == now) {
            run.halt(station, now);
        }
        if next_sample == Some(now) {
            run.sample_all(now);
            next_grid = next_grid.saturating_add(grid);
        }
        while let Some(frame) = pending.next_if(|frame| frame.t_us == now) {
            run.frame(frame);
            sent += 1;
            if sent.is_multiple_of(65_536) {
                progress(sent);
            }
        }
        while run.wakes.peek().is_some_and(|Reverse((t, _))| *t == now) {
            if let Some(Reverse((_, port))) = run.wakes.pop() {
                run.wake(port, now);
            }
        }
        if has_groups {
            if broadcast {
                for station in 0..run.stations.len() {
                    run.ble_poll(station, now);
                }
                run.send_claims(now);
            }
            run.note_all(now);
        }
        if next_step == Some(now) {
            run.dynamics_tick(now);
        }
    }
    if options.samples {
        run.sample_all(until_us);
    }
    progress(sent);
    let mut records = run.records.unwrap_or_default();
    if options.records {
        // The simulator's arbiters send nothing of their own: the sent frames of a node that runs
        // a schema server are in the node runners' records (pab_app::replay::records).
        let _ = records::write_end(&mut records, sent as u64, run.verdicts, 0);
    }
    let mut rows = run.rows;
    rows.sort_by_key(|row| (row.t_us, row.connection));
    Ok(Outcome {
        until_us,
        frames: sent,
        rows,
        timelines: run.timelines,
        samples: run.samples,
        records,
        claims: run.claims,
        holdings: run.holdings,
        dynamics: run.dynamics_rows,
        gates: run.gates,
        intention: None,
        commands: Vec::new(),
    })
}

/// The frames of the network's events, in bus order: by time, then CAN arbitration order, then
/// the order of the events in the file. Each carries its event's `data`.
pub fn event_frames(network: &Network) -> Result<Vec<BusFrame>, SimError> {
    let mut frames = Vec::new();
    for (sequence, event) in network.events.iter().enumerate() {
        let Some(topic) = network.topics.get(event.topic) else {
            continue;
        };
        let filter = topic.filter;
        let id = if filter.is_extended() {
            ExtendedId::new(filter.id()).map(Id::Extended)
        } else {
            u16::try_from(filter.id())
                .ok()
                .and_then(StandardId::new)
                .map(Id::Standard)
        }
        .ok_or_else(|| SimError(format!("topic `{}` has an invalid CAN id", topic.name)))?;
        // CAN arbitration compares the 11 base bits first; on a tie a standard frame wins.
        let base = if filter.is_extended() {
            filter.id() >> 18
        } else {
            filter.id()
        };
        let frame = pab_core::Frame::data(id, &event.data).ok_or_else(|| {
            SimError(format!(
                "an event of topic `{}` has more than 8 bytes of data",
                topic.name
            ))
        })?;
        for t in event.schedule.times() {
            frames.push((
                (micros(t), base, filter.is_extended(), filter.id(), sequence),
                BusFrame {
                    t_us: micros(t),
                    frame,
                },
            ));
        }
    }
    frames.sort_by_key(|(order, _)| *order);
    Ok(frames.into_iter().map(|(_, frame)| frame).collect())
}

/// The default end of a simulation: once the last frame's effects have decayed, or at the end of
/// the last phase, the last fault or the last scripted desire, whichever is later, rounded up to
/// a tenth of a second.
fn default_until(network: &Network, frames: &[BusFrame]) -> u64 {
    let after_phases = network
        .phases
        .iter()
        .map(|p| micros(p.to))
        .chain(network.faults.iter().map(|f| micros(f.at)))
        .chain(network.desires.iter().map(|d| micros(d.to)))
        .max()
        .unwrap_or(0);
    // Round up to a tenth of a second.
    settled_until(network, frames)
        .max(after_phases)
        .div_ceil(100_000)
        .saturating_mul(100_000)
}

/// The time by which the effects of `frames` on `network` have decayed: the last frame plus the
/// longest τ plus 1 µs (so the last lapse shows in the timelines), rounded up to a tenth of a
/// second.
pub fn settled_until(network: &Network, frames: &[BusFrame]) -> u64 {
    let longest_decay = network
        .connections
        .iter()
        .map(|c| u64::from(c.stimulation.decay_us()))
        .max()
        .unwrap_or(0);
    let after_frames = frames.last().map_or(0, |frame| {
        frame.t_us.saturating_add(longest_decay).saturating_add(1)
    });
    after_frames.div_ceil(100_000).saturating_mul(100_000)
}

struct Run<'a> {
    network: &'a Network,
    stations: Vec<Station>,
    dynamics_rows: Vec<DynamicsRow>,
    /// The Gates frames sent so far.
    gates: Vec<BusFrame>,
    /// The stations that polled their dynamics at the current instant.
    dynamics_polled: Vec<usize>,
    options: &'a Options,
    rows: Vec<TraceRow>,
    timelines: Vec<Vec<Change>>,
    samples: Vec<Vec<Sample>>,
    wakes: BinaryHeap<Reverse<(u64, usize)>>,
    records: Option<String>,
    verdicts: u64,
    /// Whether claims go on the bus ([`simulate`]) or are dropped (a replay, [`run`]).
    broadcast: bool,
    /// Claims sent at the current instant and not yet heard: (sender station, claim).
    outbox: Vec<(usize, Claim)>,
    claims: Vec<BusFrame>,
    holdings: Vec<Vec<Holding>>,
}

impl Run<'_> {
    /// The soonest instant at which a running node has BLE work (a claim due, a claim going
    /// stale), µs.
    fn ble_deadline(&self) -> Option<u64> {
        self.stations
            .iter()
            .filter(|s| s.arbiter.has_groups())
            .filter_map(|s| s.next_due(s.last_us, |last| s.arbiter.ble_deadline(last)))
            .min()
    }

    /// Station `station` polls its groups at `now`: claims due go to the outbox (or nowhere, in a
    /// replay), holding decisions come up to `now`.
    fn ble_poll(&mut self, station: usize, now_us: u64) {
        let broadcast = self.broadcast;
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        if entry.stopped(now_us) || !entry.arbiter.has_groups() {
            return;
        }
        entry.last_us = Some(now_us);
        let mut sent = Vec::new();
        entry
            .arbiter
            .ble_poll(Instant::from_micros(now_us), |claim| sent.push(claim));
        if broadcast {
            self.outbox
                .extend(sent.into_iter().map(|claim| (station, claim)));
        }
    }

    /// The claims of the outbox on the bus at `now`, in arbitration order (lower identifier
    /// first), each heard by every other running node, which then polls as a node does after a
    /// frame (its own claims, if any fall due, follow in the same instant).
    fn send_claims(&mut self, now_us: u64) {
        while !self.outbox.is_empty() {
            let mut batch = std::mem::take(&mut self.outbox);
            batch.sort_by_key(|(_, claim)| claim.raw_id());
            for (sender, claim) in batch {
                let Some(frame) = claim.frame() else {
                    continue;
                };
                self.claims.push(BusFrame {
                    t_us: now_us,
                    frame,
                });
                for station in 0..self.stations.len() {
                    if station == sender {
                        continue;
                    }
                    self.hear_claim(station, &frame, now_us);
                    self.ble_poll(station, now_us);
                }
            }
        }
    }

    /// Station `station` hears claim frame `frame` (a node that stopped hears nothing; a
    /// claim it cannot keep is dropped, as a node drops it after its fault).
    fn hear_claim(&mut self, station: usize, frame: &Frame, now_us: u64) {
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        if entry.stopped(now_us) {
            return;
        }
        if let Ok(claim) = Claim::decode(frame) {
            let _ = entry.arbiter.on_claim(claim, Instant::from_micros(now_us));
        }
    }

    /// Every port's selection and every group's holders at `now` (BLE changes them without a
    /// frame at the port).
    fn note_all(&mut self, now_us: u64) {
        let now = Instant::from_micros(now_us);
        for port in 0..self.network.ports.len() {
            let Some((station, local)) = self.locate(port) else {
                continue;
            };
            let Some(entry) = self.stations.get(station) else {
                continue;
            };
            if entry.stopped(now_us) {
                continue;
            }
            let selected =
                selected_or_output(&entry.arbiter, local, entry.arbiter.selected(local, now))
                    .and_then(|local| self.connection_of(port, local));
            self.note(port, now_us, selected);
        }
        for (index, group) in self.network.groups.iter().enumerate() {
            let mut holders = Vec::new();
            for entry in &self.stations {
                if entry.stopped(now_us) || group.member(entry.node).is_none() {
                    continue;
                }
                // The group's position in the node's table: its rank among the node's groups.
                let position = self
                    .network
                    .groups
                    .iter()
                    .take(index)
                    .filter(|g| g.member(entry.node).is_some())
                    .count();
                if entry.arbiter.holds(position) {
                    holders.push(entry.node);
                }
            }
            if let Some(changes) = self.holdings.get_mut(index)
                && changes.last().map(|c| &c.holders) != Some(&holders)
            {
                changes.push(Holding {
                    t_us: now_us,
                    holders,
                });
            }
        }
    }

    /// The network index of port `local` of station `station`.
    fn port_of(&self, station: usize, local: u8) -> Option<usize> {
        let node = self.stations.get(station)?.node;
        self.network
            .nodes
            .get(node)?
            .ports
            .get(usize::from(local))
            .copied()
    }

    fn connection_of(&self, port: usize, local: u8) -> Option<usize> {
        self.network
            .ports
            .get(port)?
            .connections
            .get(usize::from(local))
            .copied()
    }

    /// A frame of our protocol at `station`: a FilterSet or FilterProfile addressed to it is
    /// applied to its arbiter; anything else is not the arbitration's business.
    fn filter_command(&mut self, station: usize, frame: &Frame) {
        use pab_core::protocol::Message;
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        let Ok((id, message)) = Message::decode(frame) else {
            return;
        };
        if id.destination != entry.id {
            return;
        }
        let _ = match message {
            Message::FilterSet(set) => entry.arbiter.set_filter(set.port, set.connection, set.phi),
            Message::FilterProfile(switch) => entry.arbiter.set_filter_profile(switch.profile),
            _ => Ok(()),
        };
    }

    fn frame(&mut self, frame: &BusFrame) {
        let now = Instant::from_micros(frame.t_us);
        let id = frame.frame.id();
        let kind = pab_core::protocol::classify(&frame.frame);
        for station in 0..self.stations.len() {
            if self
                .stations
                .get(station)
                .is_none_or(|entry| entry.stopped(frame.t_us))
            {
                continue;
            }
            if self.options.samples {
                self.sample_ports_fed_by(station, &id, frame.t_us);
            }
            // A claim is a node's BLE traffic, never arbitrated: its group state keeps it.
            if kind == pab_core::protocol::FrameKind::Claim {
                self.hear_claim(station, &frame.frame, frame.t_us);
                self.ble_poll(station, frame.t_us);
                continue;
            }
            // Gates (a capture's, in a replay): the dynamics' traffic, never arbitrated.
            if dynamics::is_gates(&frame.frame) {
                self.hear_gates(station, &frame.frame, frame.t_us);
                if self.options.samples {
                    self.sample_gate_changes(frame.t_us);
                }
                continue;
            }
            // HBBA's filter commands: applied by the node they address, as a node does (a
            // refused one changes nothing); never arbitrated.
            if kind.is_ours() {
                self.filter_command(station, &frame.frame);
                continue;
            }
            let mut verdicts = Vec::new();
            let mut combined = Vec::new();
            if let Some(entry) = self.stations.get_mut(station) {
                entry.arbiter.receive_frame(
                    &frame.frame,
                    now,
                    |verdict| verdicts.push(*verdict),
                    |output| combined.push(*output),
                );
                if entry.arbiter.has_groups() {
                    entry.arbiter.ble_frame(&frame.frame, now);
                }
                if entry.arbiter.has_dynamics() {
                    entry.arbiter.dynamics_frame(&frame.frame, now);
                }
            }
            if let (Some(out), Some(entry)) = (self.records.as_mut(), self.stations.get(station)) {
                for verdict in &verdicts {
                    let _ = records::write_verdict(
                        out,
                        frame.t_us,
                        &frame.frame,
                        entry.id,
                        verdict,
                        |connection| entry.arbiter.level(verdict.port, connection, now),
                    );
                    self.verdicts += 1;
                }
            }
            for verdict in verdicts {
                let Some(port) = self.port_of(station, verdict.port) else {
                    continue;
                };
                for local in verdict.fed.iter() {
                    let Some(connection) = self.connection_of(port, local) else {
                        continue;
                    };
                    let level = self
                        .stations
                        .get(station)
                        .and_then(|s| s.arbiter.level(verdict.port, local, now))
                        .map_or(0.0, |level| level.to_f64());
                    let handed_over = combined
                        .iter()
                        .any(|output| output.port == verdict.port && output.connection == local);
                    self.rows.push(TraceRow {
                        t_us: frame.t_us,
                        connection,
                        level,
                        active: verdict.active.contains(local),
                        delivered: verdict.delivered == Some(local) || handed_over,
                    });
                    if !verdict.resting.contains(local) {
                        let decay = self
                            .network
                            .connections
                            .get(connection)
                            .map_or(0, |c| u64::from(c.stimulation.decay_us()));
                        self.wakes.push(Reverse((frame.t_us + decay + 1, port)));
                    }
                }
                let selected = self
                    .stations
                    .get(station)
                    .and_then(|s| selected_or_output(&s.arbiter, verdict.port, verdict.selected))
                    .and_then(|local| self.connection_of(port, local));
                self.note(port, frame.t_us, selected);
            }
            self.ble_poll(station, frame.t_us);
            if self.options.samples {
                self.sample_ports_fed_by(station, &id, frame.t_us);
            }
        }
    }

    /// Station `station` stops at `t_us`: its ports select nobody from then on.
    fn halt(&mut self, station: usize, t_us: u64) {
        let Some(node) = self.stations.get(station).map(|s| s.node) else {
            return;
        };
        let ports = self
            .network
            .nodes
            .get(node)
            .map(|n| n.ports.clone())
            .unwrap_or_default();
        for port in ports {
            self.note(port, t_us, None);
        }
    }

    fn wake(&mut self, port: usize, t_us: u64) {
        let Some((station, local)) = self.locate(port) else {
            return;
        };
        if self
            .stations
            .get(station)
            .is_none_or(|entry| entry.stopped(t_us))
        {
            return;
        }
        let now = Instant::from_micros(t_us);
        if let Some(entry) = self.stations.get_mut(station) {
            // Values that aged out, activities that ended: the value ports' outputs now.
            entry.arbiter.poll(now, |_| {});
        }
        let selected = self
            .stations
            .get(station)
            .and_then(|s| selected_or_output(&s.arbiter, local, s.arbiter.selected(local, now)))
            .and_then(|local| self.connection_of(port, local));
        self.note(port, t_us, selected);
        if self.options.samples {
            self.sample_port(station, local, port, t_us);
        }
    }

    /// The station and local port index of network port `port`.
    fn locate(&self, port: usize) -> Option<(usize, u8)> {
        let node = self.network.ports.get(port)?.node;
        let station = self.stations.iter().position(|s| s.node == node)?;
        let local = self
            .network
            .nodes
            .get(node)?
            .ports
            .iter()
            .position(|&p| p == port)?;
        Some((station, u8::try_from(local).ok()?))
    }

    fn note(&mut self, port: usize, t_us: u64, selected: Option<usize>) {
        if let Some(timeline) = self.timelines.get_mut(port)
            && timeline.last().map(|change| change.selected) != Some(selected)
        {
            timeline.push(Change { t_us, selected });
        }
    }

    fn sample_all(&mut self, t_us: u64) {
        for port in 0..self.network.ports.len() {
            if let Some((station, local)) = self.locate(port) {
                self.sample_port(station, local, port, t_us);
            }
        }
    }

    fn sample_ports_fed_by(&mut self, station: usize, id: &Id, t_us: u64) {
        let Some(node) = self.stations.get(station).map(|s| s.node) else {
            return;
        };
        let ports: Vec<usize> = self
            .network
            .nodes
            .get(node)
            .map(|n| n.ports.clone())
            .unwrap_or_default();
        for (local, port) in ports.into_iter().enumerate() {
            let fed = self.network.port_connections(port).any(|c| {
                self.network
                    .topics
                    .get(c.topic)
                    .is_some_and(|t| t.filter.matches(id))
            });
            if fed && let Ok(local) = u8::try_from(local) {
                self.sample_port(station, local, port, t_us);
            }
        }
    }

    fn sample_port(&mut self, station: usize, local_port: u8, port: usize, t_us: u64) {
        let Some(entry) = self.stations.get(station) else {
            return;
        };
        let now = Instant::from_micros(t_us);
        let stopped = entry.stopped(t_us);
        let selected = selected_or_output(
            &entry.arbiter,
            local_port,
            entry.arbiter.selected(local_port, now),
        )
        .filter(|_| !stopped);
        let connections = self
            .network
            .ports
            .get(port)
            .map(|p| p.connections.clone())
            .unwrap_or_default();
        let activity = entry.arbiter.activity(local_port, now);
        for (local, connection) in connections.into_iter().enumerate() {
            let Ok(local) = u8::try_from(local) else {
                continue;
            };
            let level = entry
                .arbiter
                .level(local_port, local, now)
                .filter(|_| !stopped)
                .map_or(0.0, |level| level.to_f64());
            if let Some(samples) = self.samples.get_mut(connection) {
                samples.push(Sample {
                    t: t_us as f64 / 1e6,
                    level,
                    active: activity.contains(local) && !stopped,
                    selected: selected == Some(local),
                });
            }
        }
    }

    /// Samples, at `t_us`, the ports with a gate connection whose gate changed since its last
    /// sample (a step of the dynamics, a Gates frame heard): a gate's strip then opens and
    /// closes at the instants the port's node reads it so, not at the next sample.
    fn sample_gate_changes(&mut self, t_us: u64) {
        let now = Instant::from_micros(t_us);
        for port in 0..self.network.ports.len() {
            let Some((station, local_port)) = self.locate(port) else {
                continue;
            };
            let Some(entry) = self.stations.get(station) else {
                continue;
            };
            let stopped = entry.stopped(t_us);
            let activity = entry.arbiter.activity(local_port, now);
            let Some(connections) = self.network.ports.get(port).map(|p| &p.connections) else {
                continue;
            };
            let changed = connections.iter().enumerate().any(|(local, &connection)| {
                let is_gate = self
                    .network
                    .connections
                    .get(connection)
                    .is_some_and(|c| c.kind == crate::network::Kind::Gate);
                let open = u8::try_from(local).is_ok_and(|l| activity.contains(l)) && !stopped;
                let last = self
                    .samples
                    .get(connection)
                    .and_then(|s| s.last())
                    .map(|s| s.active);
                is_gate && last != Some(open)
            });
            if changed {
                self.sample_port(station, local_port, port, t_us);
            }
        }
    }
}

/// For an ordinary port, `selected`; for a value port, the connection of its current output.
fn selected_or_output(arbiter: &Arbiter, port: u8, selected: Option<u8>) -> Option<u8> {
    if arbiter.is_value_port(port) {
        arbiter.output(port).map(|(connection, _)| connection)
    } else {
        selected
    }
}

impl Outcome {
    /// The connection selected at port `port` at time `t_us` (network indices), from the
    /// timeline.
    pub fn selected_at(&self, port: usize, t_us: u64) -> Option<usize> {
        self.timelines
            .get(port)?
            .iter()
            .take_while(|change| change.t_us <= t_us)
            .last()?
            .selected
    }

    /// The rows of connection `connection` in [from, to) µs.
    pub fn rows_of(
        &self,
        connection: usize,
        from_us: u64,
        to_us: u64,
    ) -> impl Iterator<Item = &TraceRow> {
        self.rows
            .iter()
            .filter(move |row| row.connection == connection && (from_us..to_us).contains(&row.t_us))
    }

    /// Writes the trace as CSV: `t,port,connection,stimulation,active,delivered`.
    pub fn write_csv(&self, network: &Network, out: &mut dyn Write) -> io::Result<()> {
        writeln!(out, "t,port,connection,stimulation,active,delivered")?;
        for row in &self.rows {
            let Some(connection) = network.connections.get(row.connection) else {
                continue;
            };
            let port = network
                .ports
                .get(connection.port)
                .map_or("?", |p| p.name.as_str());
            writeln!(
                out,
                "{},{port},{},{:.4},{},{}",
                seconds_text(row.t_us),
                connection.name,
                row.level,
                u8::from(row.active),
                u8::from(row.delivered)
            )?;
        }
        Ok(())
    }

    /// Per port, the timeline of its selected connection and a count of frames per connection.
    pub fn report(&self, network: &Network) -> String {
        let mut out = String::new();
        for (port_index, port) in network.ports.iter().enumerate() {
            let node = network
                .nodes
                .get(port.node)
                .map_or("?", |n| n.name.as_str());
            let _ = writeln!(out, "{} (node {node})", port.name);
            for change in self.timelines.get(port_index).into_iter().flatten() {
                let who = change
                    .selected
                    .and_then(|c| network.connections.get(c))
                    .map_or("nobody".to_string(), |c| {
                        let topic = network.topics.get(c.topic).map_or("?", |t| t.name.as_str());
                        format!("{} ({topic})", c.name)
                    });
                let _ = writeln!(out, "  {:>14}  {who}", seconds_text(change.t_us));
            }
            for &index in &port.connections {
                let Some(connection) = network.connections.get(index) else {
                    continue;
                };
                let rows: Vec<&TraceRow> = self.rows_of(index, 0, u64::MAX).collect();
                let delivered = rows.iter().filter(|row| row.delivered).count();
                let _ = writeln!(
                    out,
                    "    {:<8} {:>6} frames, {:>6} delivered, {:>6} discarded{}",
                    connection.name,
                    rows.len(),
                    delivered,
                    rows.len() - delivered,
                    match (connection.kind.is_special(), connection.is_virtual()) {
                        _ if connection.kind == crate::network::Kind::Claim => {
                            "  (BLE claim: who holds the task, below)".to_string()
                        }
                        _ if connection.kind == crate::network::Kind::Gate => {
                            "  (gate: set by the dynamics, never by a frame)".to_string()
                        }
                        (true, true) => format!("  ({}, virtual)", connection.kind.name()),
                        (true, false) => format!("  ({})", connection.kind.name()),
                        (false, true) => "  (virtual)".to_string(),
                        (false, false) => String::new(),
                    }
                );
            }
        }
        for (index, group) in network.groups.iter().enumerate() {
            let _ = writeln!(
                out,
                "BLE group {} (claims every {} s): who holds the task",
                group.name, group.period
            );
            for change in self.holdings.get(index).into_iter().flatten() {
                let who: Vec<&str> = change
                    .holders
                    .iter()
                    .filter_map(|&n| network.nodes.get(n).map(|n| n.name.as_str()))
                    .collect();
                let who = if who.is_empty() {
                    "nobody".to_string()
                } else {
                    who.join(", ")
                };
                let _ = writeln!(out, "  {:>14}  {who}", seconds_text(change.t_us));
            }
        }
        if !self.claims.is_empty() {
            let _ = writeln!(out, "BLE claims sent: {}", self.claims.len());
        }
        if !self.gates.is_empty() {
            let _ = writeln!(out, "Gates frames sent: {}", self.gates.len());
        }
        if let Some(run) = &self.intention {
            out.push_str(&run.report(network));
        }
        out
    }

    /// The frames on the simulated bus, in the order they were sent: the events' `frames`
    /// (from [`event_frames`]) and the nodes' claims, each instant's events before its claims.
    pub fn bus_frames(&self, frames: &[BusFrame]) -> Vec<BusFrame> {
        let mut all: Vec<(u64, u8, BusFrame)> = frames
            .iter()
            .filter(|f| f.t_us <= self.until_us)
            .map(|f| (f.t_us, 1, *f))
            // The intention's commands of an instant before its topics' frames, as simulated.
            .chain(self.commands.iter().map(|f| (f.t_us, 0, *f)))
            .chain(self.claims.iter().map(|f| (f.t_us, 2, *f)))
            .chain(self.gates.iter().map(|f| (f.t_us, 2, *f)))
            .collect();
        // Stable: within an instant and a kind, the order they were sent in.
        all.sort_by_key(|(t, kind, _)| (*t, *kind));
        all.into_iter().map(|(_, _, f)| f).collect()
    }

    /// Per BLE group, a strip per node of the group: 1 (and selected) while it holds the task.
    fn group_series(&self, network: &Network) -> Vec<PortSeries> {
        let until = self.until_us as f64 / 1e6;
        network
            .groups
            .iter()
            .enumerate()
            .map(|(index, group)| {
                let changes = self.holdings.get(index).map_or(&[][..], Vec::as_slice);
                let connections = group
                    .members
                    .iter()
                    .map(|member| {
                        let name = network
                            .nodes
                            .get(member.node)
                            .map_or("?", |n| n.name.as_str());
                        let topic = network
                            .topics
                            .get(member.topic)
                            .map_or("?", |t| t.name.as_str());
                        let mut samples = Vec::new();
                        let mut held = false;
                        for change in changes {
                            let t = change.t_us as f64 / 1e6;
                            let now = change.holders.contains(&member.node);
                            let level = |h: bool| if h { 1.0 } else { 0.0 };
                            samples.push(Sample {
                                t,
                                level: level(held),
                                active: held,
                                selected: held,
                            });
                            samples.push(Sample {
                                t,
                                level: level(now),
                                active: now,
                                selected: now,
                            });
                            held = now;
                        }
                        samples.push(Sample {
                            t: until,
                            level: if held { 1.0 } else { 0.0 },
                            active: held,
                            selected: held,
                        });
                        ConnectionSeries {
                            name: name.to_string(),
                            label: format!("{name}  holds the task (eligibility: {topic})"),
                            shows: Shows::Stimulation,
                            samples,
                        }
                    })
                    .collect();
                PortSeries {
                    name: format!("BLE {} (every {} s)", group.name, group.period),
                    connections,
                }
            })
            .collect()
    }

    /// The data of a stimulation plot.
    pub fn plot_data(&self, network: &Network, title: &str) -> PlotData {
        let ports = network
            .ports
            .iter()
            .enumerate()
            .map(|(port_index, port)| PortSeries {
                name: port.name.clone(),
                // A claim has its own lanes, per group, below the ports.
                connections: network
                    .port_connections(port_index)
                    .filter(|c| c.kind != crate::network::Kind::Claim)
                    .map(|c| {
                        let index = port.connections.get(c.index).copied().unwrap_or(0);
                        let topic = network.topics.get(c.topic).map_or("?", |t| t.name.as_str());
                        let rule = if c.is_virtual() {
                            "virtual".to_string()
                        } else {
                            crate::shown::excerpt(&c.rule_text, crate::network::RULE_EXCERPT)
                        };
                        let (label, shows) = if c.kind == crate::network::Kind::Gate {
                            let group = c.name.split_once('.').map_or("?", |(group, _)| group);
                            let label = format!("{}  gate of [dynamics.{group}]", c.name);
                            (label, Shows::Gate)
                        } else if c.kind.is_special() {
                            let target = c
                                .inhibits
                                .and_then(|t| network.topics.get(t))
                                .map_or(String::new(), |t| format!(" {}", t.name));
                            let label = format!(
                                "{}  {topic}  {}{target} for {} s  {rule}",
                                c.name,
                                c.kind.name(),
                                c.tau
                            );
                            let shows = Shows::Window {
                                kind: c.kind.name().to_string(),
                                delivers: c.kind.delivers(),
                            };
                            (label, shows)
                        } else {
                            let label =
                                format!("{}  {topic}  σ {} τ {} s  {rule}", c.name, c.sigma, c.tau);
                            (label, Shows::Stimulation)
                        };
                        ConnectionSeries {
                            name: c.name.clone(),
                            label,
                            shows,
                            samples: self.samples.get(index).cloned().unwrap_or_default(),
                        }
                    })
                    .collect(),
            })
            .collect();
        let mut ports: Vec<PortSeries> = ports;
        ports.extend(self.group_series(network));
        PlotData {
            title: title.to_string(),
            until: self.until_us as f64 / 1e6,
            ports,
            dynamics: dynamics::plot_series(&self.dynamics, network),
            lanes: self
                .intention
                .as_ref()
                .map_or(Vec::new(), |run| run.lanes(network)),
            phases: network
                .phases
                .iter()
                .map(|p| Phase {
                    name: p.name.clone(),
                    from: p.from,
                    to: p.to,
                })
                .collect(),
        }
    }
}
