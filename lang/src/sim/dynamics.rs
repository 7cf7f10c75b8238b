//! The competitive-dynamics groups (`[dynamics.NAME]`) in virtual time, run by the nodes'
//! arbiters with the board's code (`pab_core::dynamics`, through `Arbiter::dynamics_poll`).
//!
//! A node that runs a group polls it at each t_k = k · step (from 0): at t_k it takes the step
//! from t_(k−1) with the contexts sampled then, samples the contexts at t_k (after the frames, wakes
//! and BLE work of that instant: a frame at exactly t_k counts), and records one [`DynamicsRow`]
//! per behaviour (the state after k steps, the context at t_k). Its Gates frames go on the
//! simulated bus at once, in arbitration order, to every other running node; a node reading a
//! group closes its gates after 300 ms without them. A stopped node (`[[faults]]`) polls no
//! more: its groups stop and their readers lose them.

use std::io::{self, Write};

use pab_core::dynamics::ONE;
use pab_core::protocol::{BROADCAST, Gates, Message};
use pab_core::{Frame, Instant};

use super::{BusFrame, Run, seconds_text};
use crate::network::{Context, Network};
use crate::series::{BehaviourSeries, DynamicsSample, DynamicsSeries};

/// One behaviour's state at one step of its group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynamicsRow {
    /// t_k, µs.
    pub t_us: u64,
    /// The group, as an index into the network's `dynamics`.
    pub group: usize,
    /// The behaviour, as an index into the group's behaviours.
    pub behaviour: usize,
    /// The context at t_k, as fed to the step from t_k (clamped into [0, 1]).
    pub context: f64,
    /// n after k steps.
    pub n: f64,
    /// ρ after k steps.
    pub rho: f64,
    /// m after k steps.
    pub m: f64,
    /// Whether its gate is open after k steps.
    pub gate: bool,
}

impl Run<'_> {
    /// The next instant at which a running node has dynamics work (a step, a repeat of its
    /// gates, a group it reads going silent), µs.
    pub(super) fn dynamics_deadline(&self) -> Option<u64> {
        self.stations
            .iter()
            .filter(|s| s.arbiter.has_dynamics())
            .filter_map(|s| {
                s.next_due(s.dynamics_last_us, |last| s.arbiter.dynamics_deadline(last))
            })
            .min()
    }

    /// Every running node with dynamics work at `now` polls; the gates they send are heard by
    /// every other running node, in arbitration order.
    pub(super) fn dynamics_tick(&mut self, now_us: u64) {
        let now = Instant::from_micros(now_us);
        let network = self.network;
        let record = self.options.dynamics;
        let mut sent: Vec<(usize, Frame)> = Vec::new();
        for station in 0..self.stations.len() {
            let Some(entry) = self.stations.get_mut(station) else {
                continue;
            };
            if entry.stopped(now_us) || !entry.arbiter.has_dynamics() {
                continue;
            }
            let due = match entry.dynamics_last_us {
                None => true,
                Some(last) => entry
                    .arbiter
                    .dynamics_deadline(Instant::from_micros(last))
                    .is_some_and(|d| now.micros_since(d).is_some()),
            };
            if !due {
                continue;
            }
            entry.dynamics_last_us = Some(now_us);
            self.dynamics_polled.push(station);
            // The node's groups in network order: its run `p` is its `p`-th.
            let groups: Vec<usize> = network
                .dynamics
                .iter()
                .enumerate()
                .filter(|(_, g)| g.node == entry.node)
                .map(|(index, _)| index)
                .collect();
            let id = entry.id;
            let rows = &mut self.dynamics_rows;
            let mut gates: Vec<Gates> = Vec::new();
            entry.arbiter.dynamics_poll(
                now,
                |view| {
                    if !record {
                        return;
                    }
                    let Some(&group) = groups.get(view.group) else {
                        return;
                    };
                    let q = |x: i32| f64::from(x) / f64::from(ONE);
                    let open = view.dynamics.gates();
                    for (behaviour, &context) in view.contexts.iter().enumerate() {
                        let Some(state) = view.dynamics.state(behaviour) else {
                            continue;
                        };
                        rows.push(DynamicsRow {
                            t_us: view.at.as_micros(),
                            group,
                            behaviour,
                            context: q(context),
                            n: q(state.n),
                            rho: q(state.rho),
                            m: q(state.m),
                            gate: open & (1 << behaviour) != 0,
                        });
                    }
                },
                |g| gates.push(g),
                |_| {},
            );
            sent.extend(
                gates
                    .into_iter()
                    .map(|g| (station, Message::Gates(g).to_frame(id, BROADCAST))),
            );
        }
        // On the bus: lower identifier first (the sender's id breaks ties between groups).
        sent.sort_by_key(|(_, frame)| match frame.id() {
            embedded_can::Id::Extended(id) => id.as_raw(),
            embedded_can::Id::Standard(id) => u32::from(id.as_raw()),
        });
        let polled = !self.dynamics_polled.is_empty();
        self.dynamics_polled.clear();
        // A replay feeds the Gates of its capture: what the nodes would send is dropped.
        if !self.broadcast {
            sent.clear();
        }
        for (sender, frame) in sent {
            self.gates.push(BusFrame {
                t_us: now_us,
                frame,
            });
            for station in 0..self.stations.len() {
                if station != sender {
                    self.hear_gates(station, &frame, now_us);
                }
            }
        }
        // Gates change ports' selections without a frame at them (a step, a frame heard, a
        // source gone silent): note every port at an instant some node polled (noting what did
        // not change adds nothing).
        if polled {
            self.note_all(now_us);
            if self.options.samples {
                self.sample_gate_changes(now_us);
            }
        }
    }

    /// Station `station` hears a Gates frame (a node that stopped hears nothing; gates of a group
    /// of another size are dropped, as a node drops them after its fault).
    pub(super) fn hear_gates(&mut self, station: usize, frame: &Frame, now_us: u64) {
        let Some(entry) = self.stations.get_mut(station) else {
            return;
        };
        if entry.stopped(now_us) {
            return;
        }
        if let Ok((id, Message::Gates(gates))) = Message::decode(frame) {
            let _ = entry
                .arbiter
                .on_gates(id.source, &gates, Instant::from_micros(now_us));
        }
    }
}

/// Whether `frame` is a Gates frame of the protocol.
pub(super) fn is_gates(frame: &Frame) -> bool {
    matches!(Message::decode(frame), Ok((_, Message::Gates(_))))
}

/// Writes `rows` as CSV: `t,group,behaviour,context,n,rho,m,gate`, six decimals.
pub fn write_csv(rows: &[DynamicsRow], network: &Network, out: &mut dyn Write) -> io::Result<()> {
    writeln!(out, "t,group,behaviour,context,n,rho,m,gate")?;
    for row in rows {
        let group = network.dynamics.get(row.group);
        let behaviour = group.and_then(|g| g.behaviours.get(row.behaviour));
        writeln!(
            out,
            "{},{},{},{},{},{},{},{}",
            seconds_text(row.t_us),
            group.map_or("?", |g| g.name.as_str()),
            behaviour.map_or("?", |b| b.name.as_str()),
            decimals(row.context),
            decimals(row.n),
            decimals(row.rho),
            decimals(row.m),
            u8::from(row.gate)
        )?;
    }
    Ok(())
}

/// `x` with six decimals, without a sign on a value that rounds to 0.
fn decimals(x: f64) -> String {
    let text = format!("{x:.6}");
    if text == "-0.000000" {
        "0.000000".to_string()
    } else {
        text
    }
}

/// The plot's lanes of `rows`: per group that has rows, one lane per behaviour.
pub fn plot_series(rows: &[DynamicsRow], network: &Network) -> Vec<DynamicsSeries> {
    let mut series: Vec<DynamicsSeries> = network
        .dynamics
        .iter()
        .map(|group| {
            let node = network
                .nodes
                .get(group.node)
                .map_or("?", |n| n.name.as_str());
            DynamicsSeries {
                name: format!(
                    "dynamics {} (node {node}, step {} ms)",
                    group.name,
                    f64::from(group.params.step_us) / 1000.0
                ),
                behaviours: group
                    .behaviours
                    .iter()
                    .map(|behaviour| {
                        let context = match &behaviour.context {
                            Context::Connection { connection } => network
                                .connections
                                .get(*connection)
                                .map_or("?".to_string(), |c| c.name.clone()),
                            Context::Topic { topic, scale, .. } => format!(
                                "{} / {scale}",
                                network.topics.get(*topic).map_or("?", |t| t.name.as_str())
                            ),
                            Context::Constant(value) => value.to_string(),
                        };
                        BehaviourSeries {
                            name: format!("{}.{}", group.name, behaviour.name),
                            label: format!("{}.{}  context {context}", group.name, behaviour.name),
                            samples: Vec::new(),
                        }
                    })
                    .collect(),
            }
        })
        .collect();
    for row in rows {
        if let Some(lane) = series
            .get_mut(row.group)
            .and_then(|g| g.behaviours.get_mut(row.behaviour))
        {
            lane.samples.push(DynamicsSample {
                t: row.t_us as f64 / 1e6,
                n: row.n,
                rho: row.rho,
                m: row.m,
                gate: row.gate,
            });
        }
    }
    // A group that was not stepped has no lanes.
    series.retain(|g| g.behaviours.iter().any(|b| !b.samples.is_empty()));
    series
}
