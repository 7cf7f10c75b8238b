//! What a run shows: its timelines and frame counts as a report, its trace as CSV, and the data
//! of its plot.

use std::fmt::Write as _;
use std::io::{self, Write};

use super::{Outcome, TraceRow, dynamics, seconds_text};
use crate::network::Network;
use crate::series::{ConnectionSeries, Phase, PlotData, PortSeries, Sample, Shows};

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
