//! The simulated bus in virtual time: the nodes ([`Station`]), the frames given to it, and what
//! the simulator observes of them (traces, timelines, samples, holdings, the dynamics' rows).
//!
//! At each instant, in this order: the nodes of the `[[faults]]` stop; the given frames of the
//! instant go to every running node, one after the other; every node whose deadline has come is
//! polled (`Node::poll`, as its runner wakes it: heartbeats, BLE claims, dynamics steps,
//! value ports ageing out); then what the nodes sent goes on the bus in arbitration order, each
//! frame to every other running node, whose answers follow in the same instant. A replay drops
//! what the nodes send (its bus is the capture) and otherwise runs the same way, which is how
//! `pab_app::replay::feed` runs a node, so the two record the same verdicts.
//!
//! On the timed bus ([`super::timed`]) nothing reaches the nodes when it is sent: the given
//! frames of an instant and what the nodes send are queued, and each instant begins with the bus:
//! the frame whose EOF has ended goes to every node but its sender (their answers are queued
//! then), and the next frame starts if its start has passed.
//!
//! The observation only reads the nodes: a port's selection when an activity may lapse (a
//! microsecond after τ has passed since a connection's last accepted frame), every port and BLE
//! group after the instant's work, the stimulation samples for plots.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use embedded_can::Id;
use pab_app::replay::Recorder;
use pab_core::protocol::{self, FrameKind, Message};
use pab_core::{Arbiter, Frame, Instant};

use super::station::{IntentStation, Observer, Station};
use super::timed::{Sender, TimedBus, Transmission};
use super::{BusFrame, Change, DynamicsRow, Holding, Options, SimError, TraceRow};
use crate::network::{Kind, Network};
use crate::series::Sample;

/// The most rounds of answers the nodes may exchange within one instant: each round is every
/// frame sent in answer to the previous round's. Nodes that keep answering each other without
/// time passing are a fault of the tables, reported rather than simulated for ever.
const MAX_ROUNDS: usize = 1_000;

/// The sender of the intention node's frames in [`Run::outgoing`] (the stations are numbered
/// from 0).
const INTENT: usize = usize::MAX;

pub(super) struct Run<'a> {
    pub network: &'a Network,
    pub stations: Vec<Station>,
    pub options: &'a Options,
    /// Whether the nodes' frames go on the bus ([`super::simulate`]) or are dropped (a replay).
    pub broadcast: bool,
    pub recorder: Option<Recorder<String>>,
    pub rows: Vec<TraceRow>,
    pub timelines: Vec<Vec<Change>>,
    pub samples: Vec<Vec<Sample>>,
    pub holdings: Vec<Vec<Holding>>,
    pub dynamics_rows: Vec<DynamicsRow>,
    /// Instants at which a port's selection may change without a frame (µs, network port).
    pub wakes: BinaryHeap<Reverse<(u64, usize)>>,
    /// What the nodes sent and the bus has not carried yet: (sender station, frame).
    pub outgoing: Vec<(usize, Frame)>,
    /// Every frame the nodes put on the bus, in bus order.
    pub sent: Vec<BusFrame>,
    /// Every frame on the bus, the given ones included, in bus order (not in a replay).
    pub bus: Vec<BusFrame>,
    /// HBBA's intention node (with `[hbba]`, in a simulation; never in a replay).
    pub intent: Option<IntentStation<'a>>,
    /// The timed bus, with [`Options::timed_bus`]; the ideal bus without.
    pub timed: Option<TimedBus>,
}

impl Run<'_> {
    /// Runs the bus on `frames` (time order) until `until_us`; returns the number of frames of
    /// `frames` sent. `progress` hears of it every 65 536 frames.
    pub fn go(
        &mut self,
        frames: &[BusFrame],
        until_us: u64,
        progress: &mut dyn FnMut(usize),
    ) -> Result<usize, SimError> {
        let grid = (until_us / 1500).max(1);
        let mut next_grid = 0u64;
        let mut sent = 0usize;
        let mut pending = frames.iter().peekable();
        let mut halts: Vec<(u64, usize)> = self
            .stations
            .iter()
            .enumerate()
            .filter_map(|(station, entry)| Some((entry.stop_us?, station)))
            .collect();
        halts.sort_unstable();
        let mut halts = halts.into_iter().peekable();
        // What the nodes sent as they booted (their first heartbeats) goes on the bus at 0, with
        // the intention node's first Intention.
        let mut now = 0;
        for station in 0..self.stations.len() {
            self.collect(station, 0);
            self.note_dynamics(station);
        }
        self.poll_intent(0);
        self.exchange(0)?;
        loop {
            let next_frame = pending.peek().map(|frame| frame.t_us);
            let next_wake = self.wakes.peek().map(|Reverse((t, _))| *t);
            let next_sample = self.options.samples.then_some(next_grid);
            let next_halt = halts.peek().map(|(t, _)| *t);
            let next_on_bus = self.timed.as_ref().and_then(TimedBus::next_us);
            // A deadline already past (the node was busy then) is served now.
            let next_poll = self
                .stations
                .iter()
                .filter_map(Station::due)
                .chain(self.intent.as_ref().and_then(IntentStation::due))
                .min();
            let Some(next) = [next_frame, next_wake, next_sample, next_halt, next_on_bus]
                .into_iter()
                .flatten()
                .chain(next_poll.map(|t| t.max(now)))
                .min()
                .filter(|&t| t <= until_us)
            else {
                break;
            };
            now = next;
            // A node stops before the frames of its instant: it receives none of them.
            while let Some((_, station)) = halts.next_if(|(t, _)| *t == now) {
                self.halt(station, now);
            }
            if next_sample == Some(now) {
                self.sample_all(now);
                next_grid = next_grid.saturating_add(grid);
            }
            if let Some(delivered) = self.timed.as_mut().and_then(|bus| bus.deliver(now)) {
                if delivered.sender == Sender::Scenario {
                    sent += 1;
                    if sent.is_multiple_of(65_536) {
                        progress(sent);
                    }
                }
                self.deliver(&delivered, now);
            }
            if let Some(bus) = self.timed.as_mut() {
                bus.start(now);
            }
            while let Some(frame) = pending.next_if(|frame| frame.t_us == now) {
                if let Some(bus) = self.timed.as_mut() {
                    bus.queue(now, Sender::Scenario, frame.frame);
                    continue;
                }
                for station in 0..self.stations.len() {
                    self.feed(station, &frame.frame, now);
                }
                self.feed_intent(&frame.frame, now);
                if self.broadcast {
                    self.bus.push(*frame);
                }
                sent += 1;
                if sent.is_multiple_of(65_536) {
                    progress(sent);
                }
            }
            self.poll_due(now);
            self.exchange(now)?;
            while self.wakes.peek().is_some_and(|Reverse((t, _))| *t == now) {
                if let Some(Reverse((_, port))) = self.wakes.pop() {
                    self.note_port(port, now);
                    if self.options.samples
                        && let Some((station, local)) = self.locate(port)
                    {
                        self.sample_port(station, local, port, now);
                    }
                }
            }
            // BLE and the dynamics change ports' selections without a frame at them (a claim
            // heard, a step, a group gone silent): every port and group after the instant's
            // work (noting what did not change adds nothing).
            self.note_all(now);
            if self.options.samples {
                self.sample_gate_changes(now);
            }
        }
        if self.options.samples {
            self.sample_all(until_us);
        }
        progress(sent);
        Ok(sent)
    }

    /// The intention node, polled at `now` if its deadline has come, until it has no work left
    /// then.
    fn poll_intent(&mut self, now_us: u64) {
        for _ in 0..MAX_ROUNDS {
            let Some(intent) = self.intent.as_mut() else {
                return;
            };
            let Some(due) = intent.due().filter(|&due| due <= now_us) else {
                return;
            };
            intent.polled_for = Some(due);
            intent.node.poll(Instant::from_micros(now_us));
            intent.served_us = now_us;
            self.collect_intent(now_us);
        }
    }

    /// The intention node hears `frame` at `now`.
    fn feed_intent(&mut self, frame: &Frame, now_us: u64) {
        let Some(intent) = self.intent.as_mut() else {
            return;
        };
        intent.node.on_frame(frame, Instant::from_micros(now_us));
        intent.served_us = now_us;
        // A frame may have made work due at once (a desire to solve for).
        intent.polled_for = None;
        self.collect_intent(now_us);
    }

    /// What the intention node sent (on the bus next) and did (recorded); its reports in
    /// words are its log's, not the simulation's.
    fn collect_intent(&mut self, now_us: u64) {
        let network = self.network;
        let Some(intent) = self.intent.as_mut() else {
            return;
        };
        while let Some(frame) = intent.node.next_outgoing() {
            self.outgoing.push((INTENT, frame));
        }
        while intent.node.next_report().is_some() {}
        while let Some(observed) = intent.node.next_observed() {
            intent
                .run
                .observe(network, intent.targets, now_us, observed);
        }
    }

    /// Every running node whose deadline has come by `now` is polled, until none has work left
    /// at `now`.
    fn poll_due(&mut self, now_us: u64) {
        self.poll_intent(now_us);
        for station in 0..self.stations.len() {
            for _ in 0..MAX_ROUNDS {
                let Some(entry) = self.stations.get_mut(station) else {
                    break;
                };
                let Some(due) = entry.due().filter(|&due| due <= now_us) else {
                    break;
                };
                let mut observer = Observer::new(self.recorder.as_mut(), entry.id);
                entry.poll(due, now_us, &mut observer);
                self.collect(station, now_us);
                self.note_dynamics(station);
                self.note_station(station, now_us);
            }
        }
    }

    /// The frames the nodes sent by `now` on the bus, lower identifier first, each heard by
    /// every other running node; their answers follow, round after round. On the timed bus they
    /// are queued instead, and carried later.
    fn exchange(&mut self, now_us: u64) -> Result<(), SimError> {
        if let Some(bus) = self.timed.as_mut() {
            for (sender, frame) in std::mem::take(&mut self.outgoing) {
                let sender = if sender == INTENT {
                    Sender::Intention
                } else {
                    Sender::Node(sender)
                };
                bus.queue(now_us, sender, frame);
            }
            return Ok(());
        }
        for _ in 0..MAX_ROUNDS {
            if self.outgoing.is_empty() {
                return Ok(());
            }
            let mut batch = std::mem::take(&mut self.outgoing);
            // Stable: frames with the same identifier in the order they were sent.
            batch.sort_by_key(|(_, frame)| arbitration_order(&frame.id()));
            for (sender, frame) in batch {
                if !self.broadcast {
                    continue;
                }
                let carried = BusFrame {
                    t_us: now_us,
                    frame,
                };
                self.sent.push(carried);
                self.bus.push(carried);
                for station in 0..self.stations.len() {
                    if station != sender {
                        self.feed(station, &frame, now_us);
                    }
                }
                if sender != INTENT {
                    self.feed_intent(&frame, now_us);
                }
            }
            self.poll_due(now_us);
        }
        Err(SimError(format!(
            "at {} s the nodes were still answering each other after {MAX_ROUNDS} rounds",
            super::seconds_text(now_us)
        )))
    }

    /// The timed bus's frame `delivered`, at `now`, the microsecond its EOF ended in: to every
    /// running node but its sender, and to the intention node unless it sent it.
    fn deliver(&mut self, delivered: &Transmission, now_us: u64) {
        let frame = delivered.frame;
        let carried = BusFrame {
            t_us: now_us,
            frame,
        };
        if delivered.sender != Sender::Scenario {
            self.sent.push(carried);
        }
        self.bus.push(carried);
        for station in 0..self.stations.len() {
            if delivered.sender != Sender::Node(station) {
                self.feed(station, &frame, now_us);
            }
        }
        if delivered.sender != Sender::Intention {
            self.feed_intent(&frame, now_us);
        }
    }

    /// What station `station` sent, taken from it: on the bus next ([`Run::exchange`]). A node
    /// that runs a schema server has it recorded too, as `pab_app::replay::feed` records it.
    fn collect(&mut self, station: usize, now_us: u64) {
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        let schema = entry.app.schema().is_some();
        while let Some(frame) = entry.app.next_outgoing() {
            if schema && let Some(recorder) = self.recorder.as_mut() {
                recorder.node_id = entry.id;
                recorder.sent(&frame, Instant::from_micros(now_us));
            }
            self.outgoing.push((station, frame));
        }
    }

    /// Station `station` receives `frame` at `now` (a stopped node receives nothing): the node
    /// handles it; the verdicts become trace rows and timeline changes.
    fn feed(&mut self, station: usize, frame: &Frame, now_us: u64) {
        let Some(entry) = self.stations.get(station) else {
            return;
        };
        if entry.stopped(now_us) {
            return;
        }
        let id = frame.id();
        let topic = protocol::classify(frame) == FrameKind::Topic;
        if self.options.samples && topic {
            self.sample_ports_fed_by(station, &id, now_us);
        }
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        let mut observer = Observer::new(self.recorder.as_mut(), entry.id);
        entry.feed(frame, now_us, &mut observer);
        let Observer {
            verdicts,
            delivered,
            ..
        } = observer;
        self.collect(station, now_us);
        self.note_dynamics(station);
        for (verdict, levels) in verdicts {
            let Some(port) = self.port_of(station, verdict.port) else {
                continue;
            };
            let Some(arbiter) = self.stations.get(station).and_then(Station::arbiter) else {
                continue;
            };
            // A value port hands over its combined output, whose connection is the output's.
            let handed_over = (arbiter.is_value_port(verdict.port)
                && delivered.contains(&verdict.port))
            .then(|| {
                arbiter
                    .output(verdict.port)
                    .map(|(connection, _)| connection)
            })
            .flatten();
            let selected = selected_or_output(arbiter, verdict.port, verdict.selected);
            for (local, level) in levels {
                let Some(connection) = self.connection_of(port, local) else {
                    continue;
                };
                self.rows.push(TraceRow {
                    t_us: now_us,
                    connection,
                    level,
                    active: verdict.active.contains(local),
                    delivered: verdict.delivered == Some(local) || handed_over == Some(local),
                });
                if !verdict.resting.contains(local) {
                    let decay = self
                        .network
                        .connections
                        .get(connection)
                        .map_or(0, |c| u64::from(c.stimulation.decay_us()));
                    self.wakes.push(Reverse((now_us + decay + 1, port)));
                }
            }
            let selected = selected.and_then(|local| self.connection_of(port, local));
            self.note(port, now_us, selected);
        }
        if self.options.samples && topic {
            self.sample_ports_fed_by(station, &id, now_us);
        }
    }

    /// The steps station `station`'s groups took since the last look, as rows (with
    /// [`Options::dynamics`]).
    fn note_dynamics(&mut self, station: usize) {
        if !self.options.dynamics {
            return;
        }
        let network = self.network;
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        let Some(arbiter) = entry.app.arbiter() else {
            return;
        };
        if !arbiter.has_dynamics() {
            return;
        }
        // The node's groups in network order: its run `p` is its `p`-th.
        let groups: Vec<usize> = network
            .dynamics
            .iter()
            .enumerate()
            .filter(|(_, g)| g.node == entry.node)
            .map(|(index, _)| index)
            .collect();
        let runs = arbiter.dynamics_runs();
        entry.stepped.resize(runs.len(), None);
        for (position, (run, stepped)) in runs.iter().zip(entry.stepped.iter_mut()).enumerate() {
            let Some(view) = run.last_step(position) else {
                continue;
            };
            let at = view.at.as_micros();
            if *stepped == Some(at) {
                continue;
            }
            *stepped = Some(at);
            let Some(&group) = groups.get(position) else {
                continue;
            };
            let q = |x: i32| f64::from(x) / f64::from(pab_core::dynamics::ONE);
            let open = view.dynamics.gates();
            for (behaviour, &context) in view.contexts.iter().enumerate() {
                let Some(state) = view.dynamics.state(behaviour) else {
                    continue;
                };
                self.dynamics_rows.push(DynamicsRow {
                    t_us: at,
                    group,
                    behaviour,
                    context: q(context),
                    n: q(state.n),
                    rho: q(state.rho),
                    m: q(state.m),
                    gate: open & (1 << behaviour) != 0,
                });
            }
        }
    }

    /// Station `station` stops at `t_us`: its ports select nobody from then on, and what it had
    /// not sent yet stays unsent.
    fn halt(&mut self, station: usize, t_us: u64) {
        self.outgoing.retain(|(sender, _)| *sender != station);
        if let Some(bus) = self.timed.as_mut() {
            bus.drop_from(Sender::Node(station));
        }
        for port in self.ports_of(station) {
            self.note(port, t_us, None);
        }
    }

    /// The network indices of station `station`'s ports.
    fn ports_of(&self, station: usize) -> Vec<usize> {
        self.stations
            .get(station)
            .and_then(|s| self.network.nodes.get(s.node))
            .map(|n| n.ports.clone())
            .unwrap_or_default()
    }

    /// Every port's selection and every group's holders at `now`.
    fn note_all(&mut self, now_us: u64) {
        for port in 0..self.network.ports.len() {
            self.note_port(port, now_us);
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
                if entry.arbiter().is_some_and(|a| a.holds(position)) {
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

    /// The ports of station `station`, noted at `now`.
    fn note_station(&mut self, station: usize, now_us: u64) {
        for port in self.ports_of(station) {
            self.note_port(port, now_us);
        }
    }

    /// Network port `port`'s selection at `now`, read from its node (nobody once it stopped).
    fn note_port(&mut self, port: usize, now_us: u64) {
        let Some((station, local)) = self.locate(port) else {
            return;
        };
        let Some(entry) = self.stations.get(station) else {
            return;
        };
        if entry.stopped(now_us) {
            return;
        }
        let now = Instant::from_micros(now_us);
        let selected = entry
            .arbiter()
            .and_then(|arbiter| selected_or_output(arbiter, local, arbiter.selected(local, now)))
            .and_then(|local| self.connection_of(port, local));
        self.note(port, now_us, selected);
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
        let Some(arbiter) = entry.arbiter() else {
            return;
        };
        let now = Instant::from_micros(t_us);
        let stopped = entry.stopped(t_us);
        let selected = selected_or_output(arbiter, local_port, arbiter.selected(local_port, now))
            .filter(|_| !stopped);
        let connections = self
            .network
            .ports
            .get(port)
            .map(|p| p.connections.clone())
            .unwrap_or_default();
        let activity = arbiter.activity(local_port, now);
        for (local, connection) in connections.into_iter().enumerate() {
            let Ok(local) = u8::try_from(local) else {
                continue;
            };
            let level = arbiter
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
            let Some(arbiter) = entry.arbiter() else {
                continue;
            };
            let stopped = entry.stopped(t_us);
            let activity = arbiter.activity(local_port, now);
            let Some(connections) = self.network.ports.get(port).map(|p| &p.connections) else {
                continue;
            };
            let changed = connections.iter().enumerate().any(|(local, &connection)| {
                let is_gate = self
                    .network
                    .connections
                    .get(connection)
                    .is_some_and(|c| c.kind == Kind::Gate);
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

    /// The records, ended: `frames` frames fed (empty without [`Options::records`]).
    pub fn finish_records(&mut self, frames: usize) -> String {
        // A String takes every write: finishing cannot fail.
        self.recorder
            .take()
            .and_then(|recorder| recorder.finish(frames as u64).ok())
            .unwrap_or_default()
    }
}

/// CAN arbitration order: the 11 base bits first, a standard frame before an extended one with
/// the same base bits, then the extended identifier's other 18 bits.
fn arbitration_order(id: &Id) -> (u32, bool, u32) {
    match id {
        Id::Standard(id) => (u32::from(id.as_raw()), false, 0),
        Id::Extended(id) => (id.as_raw() >> 18, true, id.as_raw() & 0x3_FFFF),
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

/// Whether `frame` is a Gates frame of the protocol.
pub(super) fn is_gates(frame: &Frame) -> bool {
    matches!(Message::decode(frame), Ok((_, Message::Gates(_))))
}
