//! What a stimulation plot shows, as data: the simulator and a replay build it from the boards'
//! code's states; `pabctl`'s plot draws it (PNG or SVG). Kept apart from the drawing so that the network
//! language carries no image library.

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
    /// Competitive-dynamics groups, drawn under the ports (may be empty).
    pub dynamics: Vec<DynamicsSeries>,
    /// Step lanes drawn under the dynamics (may be empty): HBBA's selected strategies and its
    /// filters' commanded pass rates.
    pub lanes: Vec<LaneGroup>,
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
    /// What its strip shows.
    pub shows: Shows,
    /// Samples in increasing time order (several samples may share a time: a jump).
    pub samples: Vec<Sample>,
}

/// What a connection's strip shows of its samples.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Shows {
    /// The stimulation level, coloured by whether the connection is selected.
    #[default]
    Stimulation,
    /// The windows in which a special connection (suppress, inhibit, write-inhibit, override) is
    /// active: from a frame until its period has passed without one.
    Window {
        /// The kind as the file writes it, e.g. "suppress".
        kind: String,
        /// Whether its frames can get through (an override): then the window also shows when
        /// it is selected.
        delivers: bool,
    },
    /// A competitive-dynamics gate (a rule naming `group.behaviour`): open while active.
    Gate,
}

/// The state of one connection at one time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Seconds.
    pub t: f64,
    /// Stimulation level in [0, 1].
    pub level: f64,
    /// Whether the connection is active (its x in the rules): for a special connection, within
    /// its period after a frame; for a gate, while the port's node reads it open.
    pub active: bool,
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

/// One group's lanes.
#[derive(Clone, Debug, Default)]
pub struct DynamicsSeries {
    /// The header, e.g. "dynamics door (node base, step 1 ms)".
    pub name: String,
    /// Its behaviours in the file's order.
    pub behaviours: Vec<BehaviourSeries>,
}

/// One behaviour's states over time.
#[derive(Clone, Debug, Default)]
pub struct BehaviourSeries {
    /// `group.behaviour`.
    pub name: String,
    /// A longer label, e.g. "door.search  context CORRIDOR".
    pub label: String,
    /// Its states in increasing time order.
    pub samples: Vec<DynamicsSample>,
}

/// A behaviour's state at one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynamicsSample {
    /// Seconds.
    pub t: f64,
    /// Activity n.
    pub n: f64,
    /// Refractory filter ρ.
    pub rho: f64,
    /// Memory m.
    pub m: f64,
    /// Whether its gate is open.
    pub gate: bool,
}

/// A header and its lanes.
#[derive(Clone, Debug, Default)]
pub struct LaneGroup {
    /// The header, e.g. "HBBA intention: selected strategies".
    pub name: String,
    /// The lanes, top to bottom.
    pub lanes: Vec<Lane>,
}

/// A value in [0, 1] that holds from one step to the next: drawn filled up to its height.
#[derive(Clone, Debug, Default)]
pub struct Lane {
    /// A short name.
    pub name: String,
    /// The label drawn left of the lane.
    pub label: String,
    /// The steps in increasing time order; the value before the first is 0.
    pub steps: Vec<LaneStep>,
}

/// From `t` on, the lane holds `value`.
#[derive(Clone, Debug, PartialEq)]
pub struct LaneStep {
    /// Seconds.
    pub t: f64,
    /// In [0, 1] (clamped when drawn).
    pub value: f64,
    /// A note written at the step, e.g. "φ 3".
    pub text: Option<String>,
}
