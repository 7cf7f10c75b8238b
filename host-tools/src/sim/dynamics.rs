//! The competitive-dynamics groups (`[dynamics.NAME]`) in virtual time, stepped with the board's
//! code ([`pab_core::dynamics::Dynamics`]).
//!
//! Group g steps at t_k = k · step. At t_k, after the frames, wakes and BLE work of that instant,
//! it records one [`DynamicsRow`] per behaviour (the state after k steps, with the context at t_k),
//! then steps once with those contexts, unless t_(k+1) is beyond the end of the run. A context
//! from a connection is its activity (`Arbiter::activity`) on the group's node at t_k; one from a
//! topic is the field of the last frame of that topic (a frame at t_k included) divided by its
//! scale, 0 before any frame and once `timeout` has passed since the last; contexts are clamped
//! into [0, 1] and fed in Q2.29. A stopped node (`[[faults]]`) hears no more frames, so its
//! connections lapse and its topic contexts time out; its groups keep stepping.
//!
//! Gates do not enter rules yet.

use std::io::{self, Write};

use embedded_can::Id;
use pab_core::dynamics::{Dynamics, ONE};
use pab_core::{Frame, Instant};

use super::{Run, SimError, seconds_text};
use crate::network::{Context, Network};
use crate::plot::{BehaviourSeries, DynamicsSample, DynamicsSeries};

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

/// A running group.
pub(super) struct GroupRun {
    dynamics: Dynamics,
    /// Its node's station.
    station: usize,
    step_us: u64,
    /// t_k of the next row.
    pub(super) next_us: u64,
    /// Per behaviour with a topic context: the last frame's value (already divided) and when.
    last: Vec<Option<(u64, f64)>>,
}

/// The groups of `network`, in their initial state; `station_of` maps a node index to its
/// station.
pub(super) fn start(
    network: &Network,
    station_of: impl Fn(usize) -> Option<usize>,
) -> Result<Vec<GroupRun>, SimError> {
    network
        .dynamics
        .iter()
        .map(|group| {
            let dynamics = Dynamics::new(&group.params)
                .map_err(|error| SimError(format!("dynamics group `{}`: {error}", group.name)))?;
            let station = station_of(group.node)
                .ok_or_else(|| SimError(format!("dynamics group `{}`: no station", group.name)))?;
            Ok(GroupRun {
                dynamics,
                station,
                step_us: u64::from(group.params.step_us),
                next_us: 0,
                last: vec![None; group.behaviours.len()],
            })
        })
        .collect()
}

impl Run<'_> {
    /// The next t_k of any group, if any.
    pub(super) fn dynamics_deadline(&self) -> Option<u64> {
        self.dynamics.iter().map(|g| g.next_us).min()
    }

    /// Records a frame on a topic that feeds a context, for groups whose node still runs.
    pub(super) fn dynamics_frame(&mut self, id: &Id, frame: &Frame, t_us: u64) {
        let network = self.network;
        for (g, run) in self.dynamics.iter_mut().enumerate() {
            if self
                .stations
                .get(run.station)
                .is_none_or(|s| s.stopped(t_us))
            {
                continue;
            }
            let Some(group) = network.dynamics.get(g) else {
                continue;
            };
            for (behaviour, last) in group.behaviours.iter().zip(run.last.iter_mut()) {
                let Context::Topic {
                    topic,
                    field,
                    scale,
                    ..
                } = &behaviour.context
                else {
                    continue;
                };
                if !network
                    .topics
                    .get(*topic)
                    .is_some_and(|t| t.filter.matches(id))
                {
                    continue;
                }
                // A frame too short for the field reads 0.
                let value = field
                    .read(frame.payload())
                    .map_or(0.0, |v| v as f64 / scale);
                *last = Some((t_us, value));
            }
        }
    }

    /// At `now`: every group due records its rows and steps (unless its next step would be
    /// after `until_us`).
    pub(super) fn dynamics_tick(&mut self, now: u64, until_us: u64) {
        let network = self.network;
        let instant = Instant::from_micros(now);
        for g in 0..self.dynamics.len() {
            let (Some(group), Some(run)) = (network.dynamics.get(g), self.dynamics.get(g)) else {
                continue;
            };
            if run.next_us != now {
                continue;
            }
            let station = self.stations.get(run.station);
            let contexts: Vec<i32> = group
                .behaviours
                .iter()
                .zip(&run.last)
                .map(|(behaviour, last)| {
                    let value = match &behaviour.context {
                        Context::Constant(value) => *value,
                        Context::Topic { timeout_us, .. } => last
                            .filter(|(t, _)| now.saturating_sub(*t) <= *timeout_us)
                            .map_or(0.0, |(_, value)| value),
                        Context::Connection { connection } => {
                            let active = network.connections.get(*connection).and_then(|c| {
                                let node = network.nodes.get(group.node)?;
                                let local = node.ports.iter().position(|&p| p == c.port)?;
                                let arbiter = &station?.arbiter;
                                Some(
                                    arbiter
                                        .activity(u8::try_from(local).ok()?, instant)
                                        .contains(u8::try_from(c.index).ok()?),
                                )
                            });
                            f64::from(u8::from(active.unwrap_or(false)))
                        }
                    };
                    (value.clamp(0.0, 1.0) * f64::from(ONE)).round() as i32
                })
                .collect();
            let Some(run) = self.dynamics.get_mut(g) else {
                continue;
            };
            let gates = run.dynamics.gates();
            for (behaviour, context) in contexts.iter().enumerate() {
                let Some(state) = run.dynamics.state(behaviour) else {
                    continue;
                };
                let q = |x: i32| f64::from(x) / f64::from(ONE);
                self.dynamics_rows.push(DynamicsRow {
                    t_us: now,
                    group: g,
                    behaviour,
                    context: q(*context),
                    n: q(state.n),
                    rho: q(state.rho),
                    m: q(state.m),
                    gate: gates & (1 << behaviour) != 0,
                });
            }
            let next = now.saturating_add(run.step_us);
            if next <= until_us {
                run.dynamics.step(&contexts);
            }
            // Past the end: no more rows (the deadline filter drops it).
            run.next_us = next;
        }
    }
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
