//! Stimulation plots in the style of the paper's Fig. 5.
//!
//! One strip per connection, grouped by port; each strip draws the connection's stimulation over
//! time, green while the connection is the one selected at its port (its frames get through) and
//! orange otherwise. An optional bottom strip names the scenario's phases.

use std::path::Path;

/// Everything a plot shows. Built by the simulator; the plot only draws it.
#[derive(Clone, Debug, Default)]
pub struct PlotData {
    /// Title on top of the image, e.g. the network file's name.
    pub title: String,
    /// The time axis runs from 0 to `until` seconds.
    pub until: f64,
    /// Ports in the network file's order.
    pub ports: Vec<PortSeries>,
    /// Named time intervals drawn in a strip at the bottom (may be empty: then no strip).
    pub phases: Vec<Phase>,
}

/// One port and its connections.
#[derive(Clone, Debug, Default)]
pub struct PortSeries {
    /// The port's name, e.g. "arm.target".
    pub name: String,
    /// Connections in the network file's order.
    pub connections: Vec<ConnectionSeries>,
}

/// One connection's stimulation over time.
#[derive(Clone, Debug, Default)]
pub struct ConnectionSeries {
    /// The connection's name, e.g. "C1".
    pub name: String,
    /// A longer label, e.g. "C1  object_pos  σ 0.2  τ 3 s".
    pub label: String,
    /// Samples in increasing time order (several samples may share a time: a jump).
    pub samples: Vec<Sample>,
}

/// The state of one connection at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Seconds.
    pub t: f64,
    /// Stimulation level in [0, 1].
    pub level: f64,
    /// Whether the connection is the one selected at its port at this time.
    pub selected: bool,
}

/// A named interval of the scenario, e.g. phase "B" from 10 s to 14 s.
#[derive(Clone, Debug, PartialEq)]
pub struct Phase {
    /// Short name drawn in the strip.
    pub name: String,
    /// Start, seconds.
    pub from: f64,
    /// End, seconds.
    pub to: f64,
}

/// Draws `data` into a PNG file at `path`.
pub fn render_png(data: &PlotData, path: &Path) -> anyhow::Result<()> {
    let _ = (data, path);
    anyhow::bail!("plot rendering is not written yet")
}
