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

use super::seconds_text;
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
