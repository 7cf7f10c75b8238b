//! The network file: nodes, topics, ports, connections, BLE groups (`network/ble.rs`), competitive-dynamics
//! groups (`network/dynamics.rs`), HBBA's resources and strategies (`network/hbba.rs`), a schema
//! server's board, plant and client (`network/schema.rs`), and a scenario of events.
//!
//! Parsing is in two steps. `toml` turns the text into raw tables, keeping the byte span of every
//! value; then [`Network::parse`] checks every name, number and rule and reports each mistake at
//! its line and column. All mistakes of a file are reported in one run, not just the first.
//!
//! Orders matter and are kept: connections in the order of the file are the variables of their
//! port's rules (bit i of an activity mask), and ties in traces are broken in that order.

use std::collections::HashMap;
use std::ops::Range;
use std::path::Path;

use indexmap::IndexMap;
use pab_core::filter::{MAX_EXTENDED_ID, MAX_STANDARD_ID};
use pab_core::frame::MAX_DATA_LEN;
use pab_core::integrator::ParamError;
use pab_core::value_port::{MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS};
use pab_core::{
    Combine, Consumer, Endian, Field, Filter, MAX_CONNECTIONS_PER_PORT, MAX_PORTS, OutputId,
    Stimulation, ValueSpec,
};
use schemars::transform::RecursiveTransform;
use schemars::{JsonSchema, Schema};
use serde::Deserialize;
use spanned::Spanned;

use crate::diagnostic::{Diagnostic, Diagnostics, Source};
use crate::rule::{self, Rule};
use crate::shown;

mod ble;
mod dynamics;
mod fields;
mod gates;
mod hbba;
mod plant;
mod schema;
mod spanned;
mod structure;

pub use ble::{BleGroup, BleMember};
pub use dynamics::{Context, DynamicsBehaviour, DynamicsGroup, WrittenBehaviour, WrittenExclusion};
pub use fields::TopicField;
pub use gates::lookup as gate;
pub use hbba::{
    BUS, Hbba, HbbaStrategy, MAX_BITRATE, Resource, ScriptedDesire, Solved, StrategyFilter,
    bus_cost,
};
pub use plant::{Obstacle, PlantConfig};
pub use schema::{
    CALLS, Call, Client, Command, Defaults, INNATE_IDS, MAX_CALLS, SchemaBoard, SensorTopic, Timed,
};

/// The network file's word for a combination (`combine = "min"`).
pub fn combine_name(combine: Combine) -> &'static str {
    match combine {
        Combine::Max => "max",
        Combine::Min => "min",
        Combine::Sum => "sum",
        Combine::Priority => "priority",
    }
}

/// The topic of a connection that no topic feeds (a gate, [`Kind::Gate`]): no index of
/// [`Network::topics`].
pub const NO_TOPIC: usize = usize::MAX;

/// The most frames the `[[events]]` of one file may generate, so that a typo in a rate cannot
/// exhaust memory.
pub const MAX_EVENT_FRAMES: u64 = 10_000_000;
/// The latest time an event or phase may have, in seconds (about 11.6 days).
pub const MAX_TIME_S: f64 = 1_000_000.0;
/// The highest `rate_hz` of a topic: more frames a second than a 1 Mbit/s bus carries.
pub const MAX_RATE_HZ: f64 = 100_000.0;
/// A value port's combinations, as the file writes them (`combine = "..."`): what the parser
/// takes and the JSON Schema lists.
const COMBINES: [(&str, Combine); 4] = [
    ("max", Combine::Max),
    ("min", Combine::Min),
    ("sum", Combine::Sum),
    ("priority", Combine::Priority),
];
/// A field's byte orders (`endian = "..."`; "little" when not written), as [`COMBINES`].
const ENDIANS: [(&str, Endian); 2] = [("little", Endian::Little), ("big", Endian::Big)];
/// How much of a rule's text a message repeats (characters); longer rules are shortened with `…`.
pub const RULE_EXCERPT: usize = 80;

/// A network file (docs/network-file.md): nodes, topics, ports, connections, BLE groups,
/// competitive dynamics, HBBA, a schema server, and a simulation's scenario. Unknown keys are
/// errors.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawFile {
    /// Optional: the network's version and description.
    network: Option<RawMeta>,
    /// The nodes (controller boards or their Linux stand-ins), by name.
    #[serde(default)]
    nodes: IndexMap<Spanned<String>, Spanned<RawNode>>,
    /// The topics (streams of CAN frames), by name.
    #[serde(default)]
    topics: IndexMap<Spanned<String>, Spanned<RawTopic>>,
    /// The ports (a node's inputs), by `"<node>.<port>"`.
    #[serde(default)]
    ports: IndexMap<Spanned<String>, Spanned<RawPort>>,
    /// The connections from topics to ports, by the name rules refer to (letters, digits, _); in
    /// file order, the variables of their port's rules.
    #[serde(default)]
    connections: IndexMap<Spanned<String>, Spanned<RawConnection>>,
    /// Simulation only: frames published on a topic.
    #[serde(default)]
    events: Vec<Spanned<RawEvent>>,
    /// Simulation only, optional: labels for the plot's bottom strip.
    #[serde(default)]
    phases: Vec<Spanned<RawPhase>>,
    /// Simulation only, optional, with `[hbba]`: desires `pabctl sim` issues (at most 32).
    #[serde(default)]
    desires: Vec<Spanned<hbba::RawDesire>>,
    /// Simulation only, optional: nodes that stop (one per node).
    #[serde(default)]
    faults: Vec<Spanned<RawFault>>,
    /// Broadcast of Local Eligibility peer groups, by the name rules refer to.
    #[serde(default)]
    ble: IndexMap<Spanned<String>, Spanned<ble::RawBle>>,
    /// Competitive-dynamics groups, by name (rules name a gate as `GROUP.BEHAVIOUR`).
    #[serde(default)]
    dynamics: IndexMap<Spanned<String>, Spanned<dynamics::RawDynamics>>,
    /// Optional: HBBA's intention solver, its resources and strategies (hbba.md).
    hbba: Option<Spanned<hbba::RawHbba>>,
    /// The node that runs a schema server (at most one), by its node's name (schema-server.md).
    #[serde(default)]
    schema: IndexMap<Spanned<String>, Spanned<schema::RawSchema>>,
    /// Simulation only: the robot a schema server drives; every key optional.
    plant: Option<Spanned<plant::RawPlant>>,
    /// The schema server's client: its program and commands.
    client: Option<Spanned<schema::RawClient>>,
}

/// `[[faults]] node = "r2", at = 12.0`: the node stops.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawFault {
    /// Required: the node that stops (receives nothing, sends nothing, its ports deliver nothing).
    node: Spanned<String>,
    /// Required: from when, in seconds (a frame of that microsecond included).
    at: Spanned<f64>,
    /// Optional: a remark for the reader; not used.
    #[allow(dead_code)]
    note: Option<String>,
}

/// `[network]`: the network as a whole.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawMeta {
    /// Optional: the table version compiled into the images, 1..=4294967295 (default 1; 0 is
    /// reserved: heartbeats report it for "no table").
    version: Option<Spanned<i64>>,
    /// Optional: what the network is; the DBC export's comment on the whole database.
    description: Option<Spanned<String>>,
}

/// `[nodes.NAME]`: a node; its name is used in port names and image file names.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawNode {
    /// Required: the node's id on the bus, 1..=127, unique.
    id: Spanned<i64>,
    /// Optional: what the board is; its node comment in the DBC export.
    description: Option<Spanned<String>>,
}

/// `[topics.NAME]`: a stream of CAN frames.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawTopic {
    /// Required: the frames' identifier, 11-bit (0..=0x7FF), or 29-bit (0..=0x1FFFFFFF) with
    /// `extended = true`.
    can_id: Spanned<i64>,
    /// Optional, default false: a 29-bit identifier.
    #[serde(default)]
    extended: bool,
    /// Optional: a frame matches when (frame_id & mask) == can_id; default all bits (exact
    /// match); can_id may not have bits outside mask.
    mask: Option<Spanned<i64>>,
    /// Optional: frames per second the publisher sends, (0, 100000], kept in whole µHz; what
    /// HBBA's bus costs are computed from (required on a topic whose connection a strategy lets
    /// through when `[hbba]` has a `bus` resource).
    rate_hz: Option<Spanned<f64>>,
    /// Optional, default 8: the data bytes of its frames, 0..=8; the DLC of its DBC message and
    /// the length of its simulated frames (an event's `data` has exactly this many bytes); every
    /// field read from its frames must lie within it.
    length: Option<Spanned<i64>>,
    /// Optional: what the frames carry; their message's comment in the DBC export.
    description: Option<Spanned<String>>,
}

/// `[ports."NODE.PORT"]`: an input of a node; an arbitrated port (one winner) unless `combine`
/// makes it a value port.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawPort {
    /// Optional: the node also re-publishes the frames this port delivers on this id (a gateway in
    /// front of an actuator that cannot be changed). Default: the node's application only.
    republish: Option<Spanned<RawRepublish>>,
    /// Optional: a value port and how it combines its connections' values. Default: an
    /// arbitrated port (one winner).
    #[schemars(extend("enum" = COMBINES.map(|(name, _)| name)))]
    combine: Option<Spanned<String>>,
    /// The field a value port combines: required with `combine`, refused without.
    value: Option<Spanned<RawField>>,
    /// The field that ranks frames: required for `combine = "priority"` and only there.
    priority: Option<Spanned<RawField>>,
}

/// `value = { offset = 0, size = 2, signed = false, endian = "little" }` (or `priority = ...`)
/// on a value port: where an integer is in a frame's data.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawField {
    /// Required: the field's first byte, offset + size <= 8.
    offset: Spanned<i64>,
    /// Required: its size in bytes, 1, 2 or 4 (1 or 2 for a BLE group's eligibility).
    size: Spanned<i64>,
    /// Optional, default false: a two's-complement integer.
    #[serde(default)]
    signed: bool,
    /// Optional, default "little": its byte order.
    #[schemars(extend("enum" = ENDIANS.map(|(name, _)| name)))]
    endian: Option<Spanned<String>>,
}

/// `republish = { can_id = 0x300, extended = false }` on a port.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawRepublish {
    /// Required: the identifier, 11-bit up to 0x7FF, or 29-bit up to 0x1FFFFFFF with `extended`.
    can_id: Spanned<i64>,
    /// Optional, default false: a 29-bit identifier.
    #[serde(default)]
    extended: bool,
}

/// `[connections.NAME]`: a connection from a topic to a port (docs/ayllu.md for the kinds).
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawConnection {
    /// Required: the topic whose frames feed it.
    topic: Spanned<String>,
    /// The port (`"<node>.<port>"`) they compete for; none for `kind = "inhibit"`, which acts at
    /// every port the topic it inhibits feeds.
    port: Option<Spanned<String>>,
    /// σ, the stimulation each frame adds, in (0, 1] (at least 2^-16); normal connections only.
    st: Option<Spanned<f64>>,
    /// τ in seconds, (0, 3600], kept in whole microseconds: the decay time; normal connections
    /// only.
    tc: Option<Spanned<f64>>,
    /// τr in seconds, [0, 3600]; optional, default 0; normal connections only.
    tr: Option<Spanned<f64>>,
    /// Optional: when it may deliver while active, a formula of its port's connections (`!`,
    /// `&`, `|`, parentheses, true, false); default: the connection's own name. Not on suppress,
    /// inhibit or write-inhibit connections.
    rule: Option<Spanned<String>>,
    /// Optional, default "normal": what the connection does at its port.
    #[schemars(extend("enum" = Kind::ALL.map(Kind::name)))]
    kind: Option<Spanned<String>>,
    /// Seconds, (0, 3600], kept in whole microseconds: required for special kinds (all but
    /// normal), refused on normal ones.
    period: Option<Spanned<f64>>,
    /// The topic an inhibit or write-inhibit connection holds back: required for those kinds.
    inhibits: Option<Spanned<String>>,
}

/// `[[events]]`: frames published on a topic in a simulation, either at `rate_hz` from `from` to
/// `to` or at the times of `at`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawEvent {
    /// Required: the topic the frames are published on.
    topic: Spanned<String>,
    /// Optional: the frames' payload, at most 8 bytes 0..=255; default none.
    data: Option<Spanned<Vec<Spanned<i64>>>>,
    /// Frames per second: at from, from + 1/rate_hz, ... while t < to.
    rate_hz: Option<Spanned<f64>>,
    /// Optional, with rate_hz: the first frame's time in seconds, default 0.
    from: Option<Spanned<f64>>,
    /// With rate_hz: the end in seconds (exclusive).
    to: Option<Spanned<f64>>,
    /// Or explicit times, in seconds.
    at: Option<Spanned<Vec<f64>>>,
    /// Optional: a remark for the reader; not used.
    #[allow(dead_code)]
    note: Option<String>,
}

/// `[[phases]]`: a label for the plot's bottom strip.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawPhase {
    /// Required: the label.
    name: Spanned<String>,
    /// Required: its start, seconds.
    from: Spanned<f64>,
    /// Required: its end, seconds.
    to: Spanned<f64>,
    /// Optional: a remark shown with it.
    note: Option<Spanned<String>>,
}

/// A node: a controller board or its Linux stand-in.
#[derive(Clone, Debug)]
pub struct Node {
    /// Its name in the file (`[nodes.<name>]`).
    pub name: String,
    /// Its node id on the bus, 1..=127.
    pub id: u8,
    /// Its ports, as indices into [`Network::ports`], in file order.
    pub ports: Vec<usize>,
    /// What the file says it is (`description`): the DBC export's comment on it.
    pub description: Option<String>,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// A stream of frames from one publisher, matched by CAN id and mask.
#[derive(Clone, Debug)]
pub struct Topic {
    /// Its name in the file.
    pub name: String,
    /// The frames it designates.
    pub filter: Filter,
    /// How many frames a second it carries (`rate_hz`, optional), as written: what the HBBA
    /// strategies' bus costs are computed from.
    pub rate_hz: Option<f64>,
    /// The same in whole µHz (rounded to nearest).
    pub rate_uhz: Option<u64>,
    /// How many data bytes its frames carry (`length`, 0 to 8; default 8): the DBC export's
    /// DLC, the simulated frames' length, and the bytes a field of its frames may read.
    pub length: u8,
    /// What the file says it carries (`description`): the DBC export's comment on its message.
    pub description: Option<String>,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// An arbitrated input of a node.
#[derive(Clone, Debug)]
pub struct Port {
    /// Its full name, `<node>.<port>`.
    pub name: String,
    /// Its node, as an index into [`Network::nodes`].
    pub node: usize,
    /// Its connections, as indices into [`Network::connections`], in file order: the variables
    /// of its rules.
    pub connections: Vec<usize>,
    /// Who receives what it delivers (`republish = { ... }` in the file; default: the node's
    /// application only).
    pub consumer: Consumer,
    /// For a value port (`combine = ...`), what it reads and how it combines; `None` for an
    /// ordinary port.
    pub value: Option<ValueSpec>,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// What a connection does at its port (`kind = "..."` in the file; docs/ayllu.md). Every kind compiles into ordinary connections and rules ([`crate::kinds`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Delivers by its own rule: today's connections (the default).
    Normal,
    /// Never delivers; while active, no connection of its port delivers.
    Suppress,
    /// Never delivers; while active, the connections of the topic it inhibits deliver at no
    /// port. One virtual connection, with the same name, at every port that topic feeds.
    Inhibit,
    /// Delivers; while it delivers, no connection of its port delivers but the overriders
    /// declared before it (higher layers).
    Override,
    /// Never delivers; while active, the connection of the topic it inhibits at its port neither
    /// delivers nor subsumes the layers below it.
    WriteInhibit,
    /// Never delivers; active while the node holds a BLE group's task. Not written in a file: a
    /// rule that names a group (`[ble.NAME]`) adds one, named after it ([`BleGroup`]). Its
    /// `topic` is the node's eligibility topic for the group, which never feeds it.
    Claim,
    /// Never delivers; active while a competitive-dynamics behaviour's gate is open. Not written
    /// in a file: a rule that names `GROUP.BEHAVIOUR` adds one, named so. No topic feeds it
    /// ([`NO_TOPIC`]).
    Gate,
}

impl Kind {
    /// Every kind, in the order docs/ayllu.md lists them.
    pub const ALL: [Kind; 5] = [
        Kind::Normal,
        Kind::Suppress,
        Kind::Inhibit,
        Kind::Override,
        Kind::WriteInhibit,
    ];

    /// The name the file writes.
    pub const fn name(self) -> &'static str {
        match self {
            Kind::Normal => "normal",
            Kind::Suppress => "suppress",
            Kind::Inhibit => "inhibit",
            Kind::Override => "override",
            Kind::WriteInhibit => "write-inhibit",
            Kind::Claim => "claim",
            Kind::Gate => "gate",
        }
    }

    /// Its name after "a" or "an", for messages ("an inhibit", "a suppress").
    pub const fn with_article(self) -> &'static str {
        match self {
            Kind::Normal => "a normal",
            Kind::Suppress => "a suppress",
            Kind::Inhibit => "an inhibit",
            Kind::Override => "an override",
            Kind::WriteInhibit => "a write-inhibit",
            Kind::Claim => "a claim",
            Kind::Gate => "a gate",
        }
    }

    /// The kind written `name`, if any.
    pub fn from_name(name: &str) -> Option<Kind> {
        Kind::ALL.into_iter().find(|kind| kind.name() == name)
    }

    /// Whether it acts for a period (σ = 1, τ = period, τr = 0) rather than by `st`/`tc`/`tr`.
    pub const fn is_special(self) -> bool {
        !matches!(self, Kind::Normal | Kind::Claim | Kind::Gate)
    }

    /// Whether its frames can be delivered (normal and override); the others only coordinate.
    pub const fn delivers(self) -> bool {
        matches!(self, Kind::Normal | Kind::Override)
    }
}

/// A connection from a topic to a port, with its parameters and rule.
#[derive(Clone, Debug)]
pub struct Connection {
    /// Its name, usable in rules. An inhibit connection is one connection per port it acts at,
    /// each with this name.
    pub name: String,
    /// What it does at its port.
    pub kind: Kind,
    /// For inhibit and write-inhibit connections: the topic it inhibits, as an index into
    /// [`Network::topics`].
    pub inhibits: Option<usize>,
    /// Its topic, as an index into [`Network::topics`].
    pub topic: usize,
    /// Its port, as an index into [`Network::ports`].
    pub port: usize,
    /// Its index among its port's connections (its bit in activity masks).
    pub index: usize,
    /// σ, τ (s) and τr (s) as written.
    pub sigma: f64,
    /// τ in seconds as written.
    pub tau: f64,
    /// τr in seconds as written.
    pub rest: f64,
    /// The parameters as the boards store them.
    pub stimulation: Stimulation,
    /// R: when the connection may deliver, given that it is active, as written (special kinds
    /// other than override: `false`). What the port compiles is [`crate::kinds::port_rules`].
    pub rule: Rule,
    /// The rule as written, or the connection's own name when no rule is written.
    pub rule_text: String,
    /// Whether the file writes a rule (a default rule is never reported as "never delivers").
    pub rule_written: bool,
    /// Where the rule is (or, without one, the connection).
    pub rule_span: Range<usize>,
    /// Where the connection is defined.
    pub span: Range<usize>,
}

impl Connection {
    /// Whether it never delivers: a suppress, inhibit or write-inhibit connection, or one whose
    /// rule is literally `false` (a virtual connection, which coordinates).
    pub fn is_virtual(&self) -> bool {
        !self.kind.delivers() || self.rule == Rule::Constant(false)
    }
}

/// When an event's frames are sent.
#[derive(Clone, Debug, PartialEq)]
pub enum Schedule {
    /// Frames at `from`, `from + 1/rate_hz`, ... while t < `to`.
    Rate {
        /// Frames per second.
        rate_hz: f64,
        /// First frame, seconds.
        from: f64,
        /// End (exclusive), seconds.
        to: f64,
    },
    /// Frames at these times, seconds.
    At(Vec<f64>),
}

impl Schedule {
    /// The number of frames, without generating them.
    pub fn count(&self) -> u64 {
        match self {
            Schedule::Rate { rate_hz, from, to } => {
                let span = ((to - from) * rate_hz).ceil();
                if span.is_finite() && span > 0.0 {
                    span as u64
                } else {
                    0
                }
            }
            Schedule::At(times) => times.len() as u64,
        }
    }

    /// The frame times, in seconds, in the order the schedule gives them.
    pub fn times(&self) -> Vec<f64> {
        match self {
            Schedule::Rate { rate_hz, from, to } => (0..self.count())
                .map(|k| from + k as f64 / rate_hz)
                .filter(|t| t < to)
                .collect(),
            Schedule::At(times) => times.clone(),
        }
    }
}

/// Frames published on a topic in a simulation.
#[derive(Clone, Debug)]
pub struct Event {
    /// The topic, as an index into [`Network::topics`].
    pub topic: usize,
    /// The frames' payload (`data = [...]`, at most 8 bytes; default none).
    pub data: Vec<u8>,
    /// When.
    pub schedule: Schedule,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// A named interval of the scenario, shown on plots.
#[derive(Clone, Debug, PartialEq)]
pub struct Phase {
    /// Its name, e.g. "A".
    pub name: String,
    /// Start, seconds.
    pub from: f64,
    /// End, seconds.
    pub to: f64,
    /// What happens in it.
    pub note: Option<String>,
}

/// A node that stops in a simulation (`[[faults]]`): from `at` on it receives nothing, sends
/// nothing, and its ports deliver nothing.
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    /// The node, as an index into [`Network::nodes`].
    pub node: usize,
    /// When it stops, seconds.
    pub at: f64,
}

/// A parsed and checked network file.
#[derive(Clone, Debug)]
pub struct Network {
    /// The file.
    pub source: Source,
    /// The version its tables get (`[network] version`, default 1).
    pub version: u32,
    /// What the file says the network is (`[network] description`): the DBC export's comment on
    /// the whole database.
    pub description: Option<String>,
    /// Nodes in file order.
    pub nodes: Vec<Node>,
    /// Topics in file order.
    pub topics: Vec<Topic>,
    /// Ports in file order.
    pub ports: Vec<Port>,
    /// Connections in file order.
    pub connections: Vec<Connection>,
    /// Events in file order.
    pub events: Vec<Event>,
    /// Phases in file order.
    pub phases: Vec<Phase>,
    /// Faults in file order, at most one per node.
    pub faults: Vec<Fault>,
    /// BLE peer groups in file order (their numbers on the bus).
    pub groups: Vec<BleGroup>,
    /// Competitive-dynamics groups (`[dynamics.NAME]`) in file order.
    pub dynamics: Vec<DynamicsGroup>,
    /// HBBA's resources and strategies (`[hbba]`), if the file has the section.
    pub hbba: Option<Hbba>,
    /// Scripted desires (`[[desires]]`, simulation only) in file order.
    pub desires: Vec<ScriptedDesire>,
    /// The schema servers' boards (`[schema.NODE]`): at most one.
    pub schema_boards: Vec<SchemaBoard>,
    /// The robot a schema server drives in simulation (`[plant]`).
    pub plant: Option<PlantConfig>,
    /// The schema server's client (`[client]`).
    pub client: Option<Client>,
}

fn is_plain_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

const PLAIN_NAME: &str = "use letters, digits, `_` and `-`";

/// The network file's JSON Schema (draft 7), for editors that complete and check TOML with one
/// (taplo, Even Better TOML): pretty-printed, with a final newline, as committed in
/// docs/network-file.schema.json and printed by `pabctl schema`.
///
/// It is derived from the raw tables the parser reads the file into, so it takes exactly their
/// keys (an unknown key is refused: `additionalProperties: false`), with their types and their
/// doc comments as descriptions, and the values of `combine`, `endian` and `kind` from the lists
/// the parser checks them against. It checks a file's shape only: names, ranges and everything
/// else [`Network::parse`] reports stay the parser's.
pub fn json_schema() -> String {
    let mut settings = schemars::generate::SchemaSettings::draft07();
    // Before the draft-7 transforms, which move a `$ref`'s siblings into an `allOf`.
    settings
        .transforms
        .insert(0, Box::new(RecursiveTransform(for_toml as fn(&mut Schema))));
    let mut schema = settings.into_generator().into_root_schema_for::<RawFile>();
    schema.insert("title".into(), "pab network file".into());
    let mut text = serde_json::to_string_pretty(&schema).expect("a schema is JSON");
    text.push('\n');
    text
}

/// `schema` as a TOML file's, not a Rust type's: without the null that schemars allows for an
/// `Option` (TOML has none: an optional key is one left out), so `"type": ["integer", "null"]`
/// becomes `"type": "integer"` and `"anyOf": [X, {"type": "null"}]` becomes X with the schema's
/// own keys (its description); without `format`s that name Rust's types (`int64`, `double`);
/// with each description's lines, wrapped as a doc comment, joined into one.
fn for_toml(schema: &mut Schema) {
    use serde_json::Value;
    let Some(object) = schema.as_object_mut() else {
        return;
    };
    if let Some(Value::Array(types)) = object.get_mut("type") {
        types.retain(|t| t != "null");
        if let [only] = types.as_slice() {
            let only = only.clone();
            object.insert("type".into(), only);
        }
    }
    let is_null = |value: &Value| value.get("type").is_some_and(|t| t == "null");
    if let Some(Value::Array(options)) = object.get_mut("anyOf") {
        options.retain(|option| !is_null(option));
        if let [Value::Object(only)] = options.as_slice() {
            let only = only.clone();
            object.remove("anyOf");
            for (key, value) in only {
                object.entry(key).or_insert(value);
            }
        }
    }
    object.remove("format");
    if let Some(Value::String(description)) = object.get_mut("description") {
        *description = description.replace('\n', " ");
    }
}

impl Network {
    /// Reads and checks the network file at `path`.
    pub fn load(path: &Path) -> Result<Network, Diagnostics> {
        let source = Source::read(path)?;
        Network::parse(source)
    }

    /// Checks the network file held by `source`.
    pub fn parse(source: Source) -> Result<Network, Diagnostics> {
        // Every structural mistake at once; the meaning is checked only on a file without any.
        let raw: RawFile = structure::read(&source)?;
        let mut errors = Vec::new();
        let declared = Declared {
            nodes: raw.nodes.keys().map(|k| k.get_ref().clone()).collect(),
            topics: raw.topics.keys().map(|k| k.get_ref().clone()).collect(),
            ports: raw.ports.keys().map(|k| k.get_ref().clone()).collect(),
            connections: raw
                .connections
                .keys()
                .map(|k| k.get_ref().clone())
                .collect(),
        };
        let network = Builder {
            source: &source,
            errors: &mut errors,
            declared,
        }
        .build(raw);
        if errors.is_empty() {
            Ok(network)
        } else {
            errors.sort_by_key(|error: &Diagnostic| error.position);
            Err(Diagnostics(errors))
        }
    }

    /// The connections of port `port`, in order.
    pub fn port_connections(&self, port: usize) -> impl Iterator<Item = &Connection> {
        self.ports
            .get(port)
            .into_iter()
            .flat_map(|port| port.connections.iter())
            .filter_map(|&index| self.connections.get(index))
    }

    /// The names of port `port`'s connections, in order (the names of its rule variables).
    pub fn port_connection_names(&self, port: usize) -> Vec<String> {
        self.port_connections(port)
            .map(|c| c.name.clone())
            .collect()
    }

    /// A diagnostic at `span` of the network file.
    pub fn error(&self, span: Range<usize>, message: impl Into<String>) -> Diagnostic {
        self.source.error(span, message)
    }
}

struct Builder<'a> {
    source: &'a Source,
    errors: &'a mut Vec<Diagnostic>,
    declared: Declared,
}

/// The names the file declares, whether or not their declaration was accepted. A reference to a
/// declared name that was refused is a consequence of that refusal, reported at the declaration:
/// not reported again where it is used (a cascade before its cause, otherwise).
struct Declared {
    nodes: std::collections::HashSet<String>,
    topics: std::collections::HashSet<String>,
    ports: std::collections::HashSet<String>,
    connections: std::collections::HashSet<String>,
}

impl Builder<'_> {
    fn error(&mut self, span: Range<usize>, message: impl Into<String>) {
        self.errors.push(self.source.error(span, message));
    }

    /// Whether `name` (of a `what`) is free of control characters and escape sequences; reports
    /// it, escaped, if not. Names end up on terminals, in plots and in DBC files.
    fn printable(&mut self, name: &Spanned<String>, what: &str) -> bool {
        let text = name.get_ref();
        let Some(bad) = text.chars().find(|&c| shown::needs_escape(c)) else {
            return true;
        };
        self.error(
            name.span(),
            format!(
                "{what} `{}` holds a control character (U+{:04X}); names and notes are printed on terminals: use printable characters",
                shown::escaped(text),
                u32::from(bad)
            ),
        );
        false
    }

    fn build(mut self, raw: RawFile) -> Network {
        let version = self.version(raw.network.as_ref());
        let nodes = self.nodes(&raw.nodes);
        let topics = self.topics(&raw.topics);
        let mut ports = self.ports(&raw.ports, &nodes);
        let mut connections = self.connections(&raw.connections, &topics, &mut ports);
        let names: Vec<&str> = raw
            .connections
            .keys()
            .map(|k| k.get_ref().as_str())
            .collect();
        let groups = self.ble_groups(&raw.ble, &nodes, &topics, &names);
        let dynamics = self.dynamics_groups(&raw.dynamics, &nodes, &topics, &ports, &connections);
        self.claims(&raw.connections, &groups, &mut connections, &mut ports);
        self.gates(&raw.connections, &dynamics, &mut connections, &mut ports);
        self.rules(
            &raw.connections,
            &mut connections,
            &ports,
            &groups,
            &dynamics,
            &nodes,
        );
        self.value_capacities(&ports, &nodes);
        let events = self.events(&raw.events, &topics);
        let phases = self.phases(&raw.phases);
        let faults = self.faults(&raw.faults, &nodes);
        let hbba = self.hbba(raw.hbba.as_ref(), &topics, &connections, &names);
        let desires = self.desires(&raw.desires, hbba.as_ref(), raw.hbba.is_some());
        if hbba.is_some() {
            // The intention node sends its commands from this address (the DBC names it there).
            for node in nodes
                .iter()
                .filter(|n| n.id == pab_core::protocol::INTENTION)
            {
                self.error(
                    node.span.clone(),
                    format!(
                        "node `{}` has id {}, the intention node's address in a network with \
                         [hbba]: use another id",
                        node.name,
                        pab_core::protocol::INTENTION
                    ),
                );
            }
        }
        let schema_boards = self.schema_boards(&raw.schema, &nodes);
        let plant = self.plant(raw.plant.as_ref(), &schema_boards);
        let declared: Vec<&str> = raw.schema.keys().map(|k| k.get_ref().as_str()).collect();
        let client = self.client(raw.client.as_ref(), &nodes, &schema_boards, &declared);
        let mut nodes = nodes;
        for (index, port) in ports.iter().enumerate() {
            if let Some(node) = nodes.get_mut(port.node) {
                node.ports.push(index);
            }
        }
        let description =
            self.description(raw.network.as_ref().and_then(|m| m.description.as_ref()));
        let network = Network {
            source: self.source.clone(),
            version,
            description,
            nodes,
            topics,
            ports,
            connections,
            events,
            phases,
            faults,
            groups,
            dynamics,
            hbba,
            desires,
            schema_boards,
            plant,
            client,
        };
        self.fields_within_lengths(&raw.topics, &network);
        network
    }

    /// A `description`, if printable (it goes into DBC files and onto terminals).
    fn description(&mut self, text: Option<&Spanned<String>>) -> Option<String> {
        let text = text?;
        self.printable(text, "description")
            .then(|| text.get_ref().clone())
    }

    fn version(&mut self, meta: Option<&RawMeta>) -> u32 {
        let Some(version) = meta.and_then(|meta| meta.version.as_ref()) else {
            return 1;
        };
        match u32::try_from(*version.get_ref()) {
            Ok(0) => {
                self.error(
                    version.span(),
                    "table version 0 is reserved (heartbeats report version 0 for \"no table\"); use 1 or more",
                );
                1
            }
            Ok(value) => value,
            Err(_) => {
                self.error(
                    version.span(),
                    "version must be an integer in 1..=4294967295",
                );
                1
            }
        }
    }

    fn nodes(&mut self, raw: &IndexMap<Spanned<String>, Spanned<RawNode>>) -> Vec<Node> {
        let mut nodes: Vec<Node> = Vec::new();
        let mut ids: HashMap<u8, String> = HashMap::new();
        for (name, node) in raw {
            if self.printable(name, "node name") && !is_plain_name(name.get_ref()) {
                self.error(
                    name.span(),
                    format!("node name `{}`: {PLAIN_NAME}", name.get_ref()),
                );
            }
            let id = node.get_ref().id.get_ref();
            let Some(id) = u8::try_from(*id).ok().filter(|id| (1..=127).contains(id)) else {
                self.error(
                    node.get_ref().id.span(),
                    format!("node id {id} is not in 1..=127"),
                );
                continue;
            };
            if let Some(other) = ids.get(&id) {
                self.error(
                    node.get_ref().id.span(),
                    format!("node id {id} is already used by node `{other}`"),
                );
                continue;
            }
            ids.insert(id, name.get_ref().clone());
            let description = self.description(node.get_ref().description.as_ref());
            nodes.push(Node {
                name: name.get_ref().clone(),
                id,
                ports: Vec::new(),
                description,
                span: node.span(),
            });
        }
        nodes
    }

    fn topics(&mut self, raw: &IndexMap<Spanned<String>, Spanned<RawTopic>>) -> Vec<Topic> {
        let mut topics: Vec<Topic> = Vec::new();
        for (name, topic) in raw {
            if self.printable(name, "topic name") && !is_plain_name(name.get_ref()) {
                self.error(
                    name.span(),
                    format!("topic name `{}`: {PLAIN_NAME}", name.get_ref()),
                );
            }
            let raw_topic = topic.get_ref();
            let extended = raw_topic.extended;
            let widest = if extended {
                MAX_EXTENDED_ID
            } else {
                MAX_STANDARD_ID
            };
            let format = if extended {
                "extended (29-bit)"
            } else {
                "standard (11-bit)"
            };
            let id = *raw_topic.can_id.get_ref();
            let Some(id) = u32::try_from(id).ok().filter(|&id| id <= widest) else {
                let hint = if extended {
                    ""
                } else {
                    "; write `extended = true` for a 29-bit id"
                };
                self.error(
                    raw_topic.can_id.span(),
                    format!(
                        "can_id {id:#x} does not fit a {format} id (at most {widest:#x}){hint}"
                    ),
                );
                continue;
            };
            let mask = match &raw_topic.mask {
                None => widest,
                Some(mask) => match u32::try_from(*mask.get_ref()).ok().filter(|&m| m <= widest) {
                    Some(mask) => mask,
                    None => {
                        self.error(
                            mask.span(),
                            format!(
                                "mask {:#x} does not fit a {format} id (at most {widest:#x})",
                                mask.get_ref()
                            ),
                        );
                        continue;
                    }
                },
            };
            let filter = match Filter::new(id, mask, extended) {
                Ok(filter) => filter,
                Err(error) => {
                    self.error(
                        raw_topic.can_id.span(),
                        format!("can_id {id:#x} under mask {mask:#x}: {error}"),
                    );
                    continue;
                }
            };
            if let Some(other) = topics.iter().find(|other| other.filter == filter) {
                self.error(
                    raw_topic.can_id.span(),
                    format!(
                        "topic `{}` matches the same frames as topic `{}`",
                        name.get_ref(),
                        other.name
                    ),
                );
                continue;
            }
            let Some((rate_hz, rate_uhz)) = self.topic_rate(raw_topic) else {
                continue;
            };
            let Some(length) = self.topic_length(raw_topic) else {
                continue;
            };
            let description = self.description(raw_topic.description.as_ref());
            topics.push(Topic {
                name: name.get_ref().clone(),
                filter,
                rate_hz,
                rate_uhz,
                length,
                description,
                span: topic.span(),
            });
        }
        topics
    }

    /// A topic's `rate_hz`, as written and in µHz: `Some((None, None))` without one, `None`
    /// after reporting a bad one.
    fn topic_rate(&mut self, raw: &RawTopic) -> Option<(Option<f64>, Option<u64>)> {
        let Some(rate) = &raw.rate_hz else {
            return Some((None, None));
        };
        let hz = *rate.get_ref();
        let micro = (hz * 1e6).round();
        if !(hz.is_finite() && hz > 0.0 && hz <= MAX_RATE_HZ && micro >= 1.0) {
            self.error(
                rate.span(),
                format!(
                    "rate_hz = {hz}: frames per second, positive, at most {MAX_RATE_HZ} (kept in whole µHz)"
                ),
            );
            return None;
        }
        Some((Some(hz), Some(micro as u64)))
    }

    /// A topic's `length`: 8 without one, `None` after reporting a bad one.
    fn topic_length(&mut self, raw: &RawTopic) -> Option<u8> {
        let Some(length) = &raw.length else {
            return Some(MAX_DATA_LEN as u8);
        };
        let value = *length.get_ref();
        match u8::try_from(value)
            .ok()
            .filter(|&l| usize::from(l) <= MAX_DATA_LEN)
        {
            Some(length) => Some(length),
            None => {
                self.error(
                    length.span(),
                    format!(
                        "length = {value}: the data bytes of the topic's frames, 0 to {MAX_DATA_LEN} (a classic CAN frame)"
                    ),
                );
                None
            }
        }
    }

    /// Every field the network reads from a topic's frames (value ports, BLE eligibilities,
    /// dynamics contexts) must lie within the topic's `length`: a field past it would never
    /// read a byte. Reported at the `length` that cut it short.
    fn fields_within_lengths(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawTopic>>,
        network: &Network,
    ) {
        for (index, topic) in network.topics.iter().enumerate() {
            let Some(length) = raw
                .iter()
                .find(|(name, _)| name.get_ref() == &topic.name)
                .and_then(|(_, raw)| raw.get_ref().length.as_ref())
            else {
                continue;
            };
            for field in network.topic_fields(index) {
                let end = u16::from(field.offset) + u16::from(field.size);
                if end > u16::from(topic.length) {
                    self.error(
                        length.span(),
                        format!(
                            "topic `{}` carries {} bytes (`length = {}`), but {} reads bytes {}..{} of its frames",
                            topic.name, topic.length, topic.length, field.reader, field.offset, end
                        ),
                    );
                }
            }
        }
    }

    fn ports(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawPort>>,
        nodes: &[Node],
    ) -> Vec<Port> {
        let mut ports: Vec<Port> = Vec::new();
        for (name, port) in raw {
            if !self.printable(name, "port name") {
                continue;
            }
            let full = name.get_ref();
            let Some((node_name, local)) = full.split_once('.') else {
                self.error(
                    name.span(),
                    format!("port name `{full}` must be `<node>.<port>`, e.g. \"arm.target\""),
                );
                continue;
            };
            if !is_plain_name(local) {
                self.error(
                    name.span(),
                    format!("port name `{local}` in `{full}`: {PLAIN_NAME}"),
                );
                continue;
            }
            let Some(node) = nodes.iter().position(|node| node.name == node_name) else {
                if self.declared.nodes.contains(node_name) {
                    continue;
                }
                let known: Vec<&str> = nodes.iter().map(|node| node.name.as_str()).collect();
                self.error(
                    name.span(),
                    format!(
                        "port `{full}` is on node `{node_name}`, which is not defined (nodes: {}){}",
                        list_or_none(&known),
                        suggest(node_name, &known)
                    ),
                );
                continue;
            };
            let on_node = ports.iter().filter(|port| port.node == node).count();
            if on_node >= MAX_PORTS {
                self.error(
                    name.span(),
                    format!("node `{node_name}` has more than {MAX_PORTS} ports"),
                );
                continue;
            }
            let consumer = match &port.get_ref().republish {
                None => Consumer::Local,
                // A bad id is reported; the port is kept so that its connections are checked too.
                Some(republish) => self
                    .output_id(republish.get_ref())
                    .map_or(Consumer::Local, Consumer::Republish),
            };
            let value = self.value_spec(port.get_ref(), port.span());
            ports.push(Port {
                name: full.clone(),
                node,
                connections: Vec::new(),
                consumer,
                value,
                span: port.span(),
            });
        }
        ports
    }

    /// The `combine`, `value` and `priority` keys of a port: `None` for an ordinary port (and
    /// after reporting any mistake).
    fn value_spec(&mut self, raw: &RawPort, span: Range<usize>) -> Option<ValueSpec> {
        let Some(combine_text) = &raw.combine else {
            for (key, field) in [("value", &raw.value), ("priority", &raw.priority)] {
                if let Some(field) = field {
                    self.error(
                        field.span(),
                        format!(
                            "`{key}` belongs to a value port: add `combine = \"max\"` (or \"min\", \"sum\", \"priority\")"
                        ),
                    );
                }
            }
            return None;
        };
        let written = combine_text.get_ref().as_str();
        let combine = match COMBINES.iter().find(|(name, _)| *name == written) {
            Some(&(_, combine)) => Some(combine),
            None => {
                self.error(
                    combine_text.span(),
                    format!(
                        "combine = \"{}\" is not a combination: \"max\", \"min\", \"sum\" or \"priority\"",
                        shown::escaped(written)
                    ),
                );
                None
            }
        };
        let value = match &raw.value {
            Some(field) => self.field(field, "value"),
            None => {
                self.error(
                    span.clone(),
                    "a value port needs the field it combines: `value = { offset = 0, size = 2 }` (size 1, 2 or 4; signed = false and endian = \"little\" by default)",
                );
                None
            }
        };
        let priority = match (&raw.priority, combine) {
            (Some(field), Some(Combine::Priority)) => Some(self.field(field, "priority")?),
            (None, Some(Combine::Priority)) => {
                self.error(
                    combine_text.span(),
                    "combine = \"priority\" needs the field that ranks the frames: `priority = { offset = 2, size = 1 }`",
                );
                return None;
            }
            (Some(field), Some(_)) => {
                self.error(
                    field.span(),
                    "`priority` is only for `combine = \"priority\"`: the other combinations read `value` alone",
                );
                return None;
            }
            (_, _) => None,
        };
        Some(ValueSpec {
            combine: combine?,
            value: value?,
            priority,
        })
    }

    /// A `value` or `priority` field, or `None` after reporting why not.
    fn field(&mut self, raw: &Spanned<RawField>, key: &str) -> Option<Field> {
        let field = raw.get_ref();
        let mut ok = true;
        let size = *field.size.get_ref();
        if !matches!(size, 1 | 2 | 4) {
            self.error(
                field.size.span(),
                format!("{key}: size = {size} is not 1, 2 or 4 (bytes)"),
            );
            ok = false;
        }
        let offset = *field.offset.get_ref();
        if !(0..8).contains(&offset) {
            self.error(
                field.offset.span(),
                format!("{key}: offset = {offset} is not a byte of a frame (0 to 7)"),
            );
            ok = false;
        } else if ok && offset + size > 8 {
            self.error(
                raw.span(),
                format!(
                    "{key}: offset {offset} + size {size} = {} is beyond the 8 bytes of a frame",
                    offset + size
                ),
            );
            ok = false;
        }
        let endian = match &field.endian {
            None => Endian::Little,
            Some(written) => match ENDIANS.iter().find(|(name, _)| name == written.get_ref()) {
                Some(&(_, endian)) => endian,
                None => {
                    self.error(
                        written.span(),
                        format!(
                            "{key}: endian = \"{}\" is not \"little\" or \"big\"",
                            shown::escaped(written.get_ref())
                        ),
                    );
                    return None;
                }
            },
        };
        if !ok {
            return None;
        }
        Some(Field {
            offset: u8::try_from(offset).ok()?,
            size: u8::try_from(size).ok()?,
            signed: field.signed,
            endian,
        })
    }

    /// Each node's value ports within the board runtime's fixed capacities.
    fn value_capacities(&mut self, ports: &[Port], nodes: &[Node]) {
        for (index, node) in nodes.iter().enumerate() {
            let mut count = 0usize;
            let mut connections = 0usize;
            for port in ports
                .iter()
                .filter(|port| port.node == index && port.value.is_some())
            {
                count += 1;
                connections += port.connections.len();
                if count > MAX_VALUE_PORTS {
                    self.error(
                        port.span.clone(),
                        format!(
                            "node `{}` has more than {MAX_VALUE_PORTS} value ports (a node keeps the values of at most {MAX_VALUE_PORTS} ports)",
                            node.name
                        ),
                    );
                } else if connections > MAX_VALUE_CONNECTIONS {
                    self.error(
                        port.span.clone(),
                        format!(
                            "node `{}`: its value ports have {connections} connections in all, more than {MAX_VALUE_CONNECTIONS} (a node keeps the last frame of at most {MAX_VALUE_CONNECTIONS})",
                            node.name
                        ),
                    );
                }
            }
        }
    }

    /// The identifier of a `republish` table, or `None` after reporting why not.
    fn output_id(&mut self, raw: &RawRepublish) -> Option<OutputId> {
        let id = *raw.can_id.get_ref();
        let (widest, format, hint) = if raw.extended {
            (MAX_EXTENDED_ID, "an extended (29-bit)", "")
        } else {
            (
                MAX_STANDARD_ID,
                "a standard (11-bit)",
                "; write `extended = true` for a 29-bit id",
            )
        };
        let output = u32::try_from(id)
            .ok()
            .and_then(|id| OutputId::new(id, raw.extended).ok());
        if output.is_none() {
            self.error(
                raw.can_id.span(),
                format!(
                    "republish can_id {id:#x} does not fit {format} id (at most {widest:#x}){hint}"
                ),
            );
        }
        output
    }

    fn connections(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawConnection>>,
        topics: &[Topic],
        ports: &mut [Port],
    ) -> Vec<Connection> {
        let mut connections: Vec<Connection> = Vec::new();
        // Inhibit connections act at the ports their target topic feeds, which are known once
        // every connection is; write-inhibits are checked against their port's connections then.
        let mut inhibits: Vec<(Connection, Range<usize>)> = Vec::new();
        let mut write_inhibits: Vec<(usize, Range<usize>)> = Vec::new();
        for (name, connection) in raw {
            let raw_connection = connection.get_ref();
            if !self.printable(name, "connection name") {
                continue;
            }
            if !rule::is_valid_name(name.get_ref()) {
                self.error(
                    name.span(),
                    format!(
                        "connection name `{}` cannot be used in rules: start with a letter or `_`, then letters, digits, `_`",
                        name.get_ref()
                    ),
                );
                continue;
            }
            let topic_name = raw_connection.topic.get_ref();
            let topic = self.topic_index(&raw_connection.topic, topics);
            let kind = match &raw_connection.kind {
                None => Kind::Normal,
                Some(kind) => match Kind::from_name(kind.get_ref()) {
                    Some(kind) => kind,
                    None => {
                        let known: Vec<String> = Kind::ALL
                            .iter()
                            .map(|k| format!("\"{}\"", k.name()))
                            .collect();
                        self.error(
                            kind.span(),
                            format!(
                                "unknown kind \"{}\": a connection is {}",
                                shown::escaped(kind.get_ref()),
                                known.join(", ")
                            ),
                        );
                        continue;
                    }
                },
            };
            if kind != Kind::Inhibit && raw_connection.port.is_none() {
                self.error(
                    connection.span(),
                    format!(
                        "missing field `port`: the input `{}` feeds (\"<node>.<port>\")",
                        name.get_ref()
                    ),
                );
                continue;
            }
            let Some(topic) = topic else {
                continue;
            };
            let Some((sigma, tau, rest, stimulation)) =
                self.parameters(raw_connection, connection.span(), kind)
            else {
                continue;
            };
            let target = match (kind, &raw_connection.inhibits) {
                (Kind::Inhibit | Kind::WriteInhibit, Some(target)) => {
                    let Some(index) = self.topic_index(target, topics) else {
                        continue;
                    };
                    if index == topic {
                        self.error(
                            target.span(),
                            format!(
                                "`{}` would inhibit its own topic `{topic_name}`",
                                name.get_ref()
                            ),
                        );
                        continue;
                    }
                    Some((index, target.span()))
                }
                (Kind::Inhibit | Kind::WriteInhibit, None) => {
                    self.error(
                        connection.span(),
                        format!(
                            "missing field `inhibits`: {} connection names the topic it inhibits (inhibits = \"TOPIC\")",
                            kind.with_article()
                        ),
                    );
                    continue;
                }
                (_, Some(target)) => {
                    self.error(
                        target.span(),
                        format!(
                            "`inhibits` goes with kind = \"inhibit\" or \"write-inhibit\"; `{}` is {} connection",
                            name.get_ref(),
                            kind.with_article()
                        ),
                    );
                    continue;
                }
                (_, None) => None,
            };
            if !kind.delivers()
                && let Some(rule) = &raw_connection.rule
            {
                self.error(
                    rule.span(),
                    format!(
                        "{} connection never delivers, so it has no rule (the rules of its port may name it)",
                        kind.with_article()
                    ),
                );
                continue;
            }
            let (inhibited, target_span) = match target {
                Some((topic, span)) => (Some(topic), Some(span)),
                None => (None, None),
            };
            let new = |port: usize, index: usize| Connection {
                name: name.get_ref().clone(),
                kind,
                inhibits: inhibited,
                topic,
                port,
                index,
                sigma,
                tau,
                rest,
                stimulation,
                rule: if kind.delivers() {
                    Rule::Active(index)
                } else {
                    Rule::Constant(false)
                },
                rule_text: if kind.delivers() {
                    name.get_ref().clone()
                } else {
                    "false".to_string()
                },
                rule_written: false,
                rule_span: name.span(),
                span: connection.span(),
            };
            if kind == Kind::Inhibit {
                if let Some(port) = &raw_connection.port {
                    self.error(
                        port.span(),
                        format!(
                            "an inhibit connection has no `port`: `{}` acts at every port that its `inhibits` topic feeds (kind = \"write-inhibit\" acts at one port)",
                            name.get_ref()
                        ),
                    );
                    continue;
                }
                if let Some(span) = target_span {
                    inhibits.push((new(usize::MAX, 0), span));
                }
                continue;
            }
            let Some(port_value) = &raw_connection.port else {
                continue;
            };
            let port_name = port_value.get_ref();
            let Some(port) = ports.iter().position(|port| &port.name == port_name) else {
                if self.declared.ports.contains(port_name.as_str()) {
                    continue;
                }
                let known: Vec<&str> = ports.iter().map(|port| port.name.as_str()).collect();
                self.error(
                    port_value.span(),
                    format!(
                        "port `{port_name}` is not defined (ports: {}){}",
                        list_or_none(&known),
                        suggest(port_name, &known)
                    ),
                );
                continue;
            };
            let siblings = ports.get(port).map_or(0, |port| port.connections.len());
            if siblings >= MAX_CONNECTIONS_PER_PORT {
                self.error(
                    name.span(),
                    format!(
                        "port `{port_name}` has more than {MAX_CONNECTIONS_PER_PORT} connections"
                    ),
                );
                continue;
            }
            if let Some(twin) = connections
                .iter()
                .find(|other| other.port == port && other.topic == topic)
            {
                self.error(
                    raw_connection.topic.span(),
                    format!(
                        "topic `{topic_name}` is already connected to port `{port_name}` by `{}`",
                        twin.name
                    ),
                );
                continue;
            }
            if let (Kind::WriteInhibit, Some(span)) = (kind, target_span) {
                write_inhibits.push((connections.len(), span));
            }
            if let Some(port) = ports.get_mut(port) {
                port.connections.push(connections.len());
            }
            connections.push(new(port, siblings));
        }
        self.check_write_inhibits(&write_inhibits, &connections, topics, ports);
        for (inhibit, span) in inhibits {
            self.expand_inhibit(inhibit, span, &mut connections, topics, ports);
        }
        connections
    }

    /// The index of the topic `name` names, or `None` after reporting that it is not defined.
    fn topic_index(&mut self, name: &Spanned<String>, topics: &[Topic]) -> Option<usize> {
        let wanted = name.get_ref();
        let found = topics.iter().position(|topic| &topic.name == wanted);
        if found.is_none() && !self.declared.topics.contains(wanted.as_str()) {
            let known: Vec<&str> = topics.iter().map(|topic| topic.name.as_str()).collect();
            self.error(
                name.span(),
                format!(
                    "topic `{wanted}` is not defined (topics: {}){}",
                    list_or_none(&known),
                    suggest(wanted, &known)
                ),
            );
        }
        found
    }

    /// σ, τ, τr and their stored form: written for a normal connection, from the period for a
    /// special one (σ = 1, τ = period, τr = 0: one frame makes it active, and it stays active
    /// until `period` has passed without a frame). `None` after reporting what is wrong.
    fn parameters(
        &mut self,
        raw: &RawConnection,
        span: Range<usize>,
        kind: Kind,
    ) -> Option<(f64, f64, f64, Stimulation)> {
        if kind.is_special() {
            let mut written = false;
            for (key, value) in [("st", &raw.st), ("tc", &raw.tc), ("tr", &raw.tr)] {
                if let Some(value) = value {
                    self.error(
                        value.span(),
                        format!(
                            "σ, τ and τr of a special connection follow from its period (σ = 1, τ = period, τr = 0): remove `{key}`"
                        ),
                    );
                    written = true;
                }
            }
            let Some(period) = &raw.period else {
                self.error(
                    span,
                    format!(
                        "missing field `period`: {} connection acts for `period = SECONDS` after each of its frames",
                        kind.with_article()
                    ),
                );
                return None;
            };
            let seconds = *period.get_ref();
            if !(seconds.is_finite() && seconds > 0.0) {
                self.error(
                    period.span(),
                    format!("period {seconds}: must be a positive number of seconds"),
                );
                return None;
            }
            let Ok(stimulation) = Stimulation::from_seconds(1.0, seconds, 0.0) else {
                self.error(
                    period.span(),
                    format!(
                        "period {seconds} s cannot be stored: it becomes the connection's τ, whole microseconds in [0.000001, 3600] seconds"
                    ),
                );
                return None;
            };
            return (!written).then_some((1.0, seconds, 0.0, stimulation));
        }
        if let Some(period) = &raw.period {
            self.error(
                period.span(),
                "`period` is for special connections (kind = \"suppress\", \"inhibit\", \"override\" or \"write-inhibit\"); a normal connection has `st`, `tc` and `tr`",
            );
            return None;
        }
        let (Some(st), Some(tc)) = (&raw.st, &raw.tc) else {
            let missing = if raw.st.is_none() { "st" } else { "tc" };
            self.error(
                span,
                format!(
                    "missing field `{missing}`: a normal connection has `st` (σ) and `tc` (τ), or a `kind` with a `period`"
                ),
            );
            return None;
        };
        let sigma = *st.get_ref();
        let tau = *tc.get_ref();
        let rest = raw.tr.as_ref().map_or(0.0, |tr| *tr.get_ref());
        match Stimulation::from_seconds(sigma, tau, rest) {
            Ok(stimulation) => Some((sigma, tau, rest, stimulation)),
            Err(error) => {
                let at = match error {
                    ParamError::Gain(_) => st.span(),
                    ParamError::DecayTime => tc.span(),
                    ParamError::RestTime => raw.tr.as_ref().map_or(span, |tr| tr.span()),
                };
                self.error(at, error.to_string());
                None
            }
        }
    }

    /// A write-inhibit must name a topic that feeds a delivering connection of its own port.
    fn check_write_inhibits(
        &mut self,
        write_inhibits: &[(usize, Range<usize>)],
        connections: &[Connection],
        topics: &[Topic],
        ports: &[Port],
    ) {
        for (index, span) in write_inhibits {
            let Some(connection) = connections.get(*index) else {
                continue;
            };
            let Some(target) = connection.inhibits else {
                continue;
            };
            let fed = |c: &&Connection| c.port == connection.port && c.kind.delivers();
            if connections.iter().filter(fed).any(|c| c.topic == target) {
                continue;
            }
            let layers: Vec<&str> = connections
                .iter()
                .filter(fed)
                .filter_map(|c| topics.get(c.topic).map(|t| t.name.as_str()))
                .collect();
            self.error(
                span.clone(),
                format!(
                    "topic `{}` feeds no connection of port `{}` that delivers, so `{}` has no layer to write-inhibit (the port's delivering topics: {})",
                    topics.get(target).map_or("?", |t| t.name.as_str()),
                    ports.get(connection.port).map_or("?", |p| p.name.as_str()),
                    connection.name,
                    list_or_none(&layers)
                ),
            );
        }
    }

    /// Adds inhibit connection `inhibit` to every port that its target topic feeds (through a
    /// normal or override connection), as a virtual connection with the same name, after the
    /// port's own connections.
    fn expand_inhibit(
        &mut self,
        inhibit: Connection,
        span: Range<usize>,
        connections: &mut Vec<Connection>,
        topics: &[Topic],
        ports: &mut [Port],
    ) {
        let Some(target) = inhibit.inhibits else {
            return;
        };
        let mut fed: Vec<usize> = connections
            .iter()
            .filter(|c| c.topic == target && c.kind.delivers())
            .map(|c| c.port)
            .collect();
        fed.sort_unstable();
        fed.dedup();
        let target_name = topics.get(target).map_or("?", |t| t.name.as_str());
        if fed.is_empty() {
            self.error(
                span,
                format!(
                    "topic `{target_name}` feeds no port (no normal or override connection has it), so `{}` would inhibit nothing",
                    inhibit.name
                ),
            );
            return;
        }
        for port in fed {
            let Some(entry) = ports.get_mut(port) else {
                continue;
            };
            let index = entry.connections.len();
            if index >= MAX_CONNECTIONS_PER_PORT {
                self.error(
                    span.clone(),
                    format!(
                        "inhibit `{}` acts at port `{}` (fed by `{target_name}`) as one more connection, but that port already has {MAX_CONNECTIONS_PER_PORT} connections, the most a port may have",
                        inhibit.name, entry.name
                    ),
                );
                continue;
            }
            entry.connections.push(connections.len());
            connections.push(Connection {
                port,
                index,
                ..inhibit.clone()
            });
        }
    }

    fn rules(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawConnection>>,
        connections: &mut [Connection],
        ports: &[Port],
        groups: &[BleGroup],
        dynamics: &[DynamicsGroup],
        nodes: &[Node],
    ) {
        for connection_index in 0..connections.len() {
            let Some(connection) = connections.get(connection_index) else {
                continue;
            };
            let Some((_, raw_connection)) = raw.get_key_value(connection.name.as_str()) else {
                continue;
            };
            let Some(rule) = &raw_connection.get_ref().rule else {
                continue;
            };
            let Some(port) = ports.get(connection.port) else {
                continue;
            };
            let names: Vec<(String, usize)> = port
                .connections
                .iter()
                .filter_map(|&index| connections.get(index))
                .map(|c| (c.name.clone(), c.index))
                .collect();
            let port_name = port.name.clone();
            let port_node = port.node;
            let declared = &self.declared.connections;
            let resolve = |name: &str| -> Result<usize, String> {
                if let Some((_, index)) = names.iter().find(|(n, _)| n == name) {
                    return Ok(*index);
                }
                if declared.contains(name) && !connections.iter().any(|c| c.name == name) {
                    // Declared but refused (its own error says why): no mistake of this rule's.
                    return Err(String::new());
                }
                if gates::split(name).is_some() {
                    return Err(gates::unknown(dynamics, name));
                }
                if let Some(group) = groups.iter().find(|g| g.name == name) {
                    let node = nodes.get(port_node).map_or("?", |n| n.name.as_str());
                    let members: Vec<&str> = group
                        .members
                        .iter()
                        .filter_map(|m| nodes.get(m.node).map(|n| n.name.as_str()))
                        .collect();
                    return Err(format!(
                        "`{name}` is a BLE group that node `{node}` is not in (its nodes: {}): add `{node} = \"TOPIC\"` to [ble.{name}.nodes], TOPIC carrying its eligibility",
                        members.join(", ")
                    ));
                }
                let elsewhere = connections.iter().find(|c| c.name == name).map(|c| c.port);
                let listed: Vec<&str> = names.iter().map(|(n, _)| n.as_str()).collect();
                Err(match elsewhere.and_then(|port| ports.get(port)) {
                    Some(other) => format!(
                        "`{name}` is a connection of port `{}`, not of `{port_name}`: a rule may only name connections of its own port ({})",
                        other.name,
                        listed.join(", ")
                    ),
                    None => format!(
                        "unknown connection `{name}`; the connections of port `{port_name}` are {}{}",
                        listed.join(", "),
                        suggest(name, &listed)
                    ),
                })
            };
            let text = rule.get_ref();
            let parsed = rule::parse(text, &resolve);
            // The value's span includes its opening quote; rule offsets count from the text.
            let text_start = rule.span().start + 1;
            match parsed {
                Ok(parsed) => {
                    if let Some(connection) = connections.get_mut(connection_index) {
                        connection.rule = parsed;
                        connection.rule_text = text.clone();
                        connection.rule_written = true;
                        connection.rule_span = rule.span();
                    }
                }
                // A cascade of a refused connection: reported at its declaration.
                Err(error) if error.message.is_empty() => {}
                Err(error) => {
                    let at = text_start + error.offset;
                    self.error(
                        at..at,
                        format!(
                            "in rule \"{}\": {}",
                            shown::excerpt(text, RULE_EXCERPT),
                            error.message
                        ),
                    );
                }
            }
        }
    }

    fn time(&mut self, value: &Spanned<f64>, what: &str) -> Option<f64> {
        let t = *value.get_ref();
        if t.is_finite() && (0.0..=MAX_TIME_S).contains(&t) {
            Some(t)
        } else {
            self.error(
                value.span(),
                format!("{what} must be a time in [0, {MAX_TIME_S}] seconds"),
            );
            None
        }
    }

    fn events(&mut self, raw: &[Spanned<RawEvent>], topics: &[Topic]) -> Vec<Event> {
        let mut events = Vec::new();
        let mut frames: u64 = 0;
        for event in raw {
            let raw_event = event.get_ref();
            let topic_name = raw_event.topic.get_ref();
            let Some(topic) = topics.iter().position(|topic| &topic.name == topic_name) else {
                if self.declared.topics.contains(topic_name.as_str()) {
                    continue;
                }
                let known: Vec<&str> = topics.iter().map(|topic| topic.name.as_str()).collect();
                self.error(
                    raw_event.topic.span(),
                    format!(
                        "topic `{topic_name}` is not defined (topics: {}){}",
                        list_or_none(&known),
                        suggest(topic_name, &known)
                    ),
                );
                continue;
            };
            let schedule = match (&raw_event.at, &raw_event.rate_hz) {
                (Some(_), Some(rate)) => {
                    self.error(rate.span(), "an event has either `at = [...]` or `rate_hz` with `from` and `to`, not both");
                    continue;
                }
                (None, None) => {
                    self.error(
                        event.span(),
                        "an event needs `at = [times...]` or `rate_hz` with `to` (and optionally `from`)",
                    );
                    continue;
                }
                (Some(at), None) => {
                    let times = at.get_ref();
                    if let Some(bad) = times
                        .iter()
                        .find(|t| !(t.is_finite() && (0.0..=MAX_TIME_S).contains(*t)))
                    {
                        self.error(
                            at.span(),
                            format!("time {bad} is not in [0, {MAX_TIME_S}] seconds"),
                        );
                        continue;
                    }
                    if raw_event.from.is_some() || raw_event.to.is_some() {
                        self.error(
                            at.span(),
                            "`from` and `to` go with `rate_hz`, not with `at`",
                        );
                        continue;
                    }
                    Schedule::At(times.clone())
                }
                (None, Some(rate)) => {
                    let rate_hz = *rate.get_ref();
                    if !(rate_hz.is_finite() && rate_hz > 0.0) {
                        self.error(
                            rate.span(),
                            "rate_hz must be a positive number of frames per second",
                        );
                        continue;
                    }
                    let Some(to) = &raw_event.to else {
                        self.error(
                            event.span(),
                            "an event with `rate_hz` needs `to` (the end time, exclusive)",
                        );
                        continue;
                    };
                    let from = match &raw_event.from {
                        Some(from) => self.time(from, "from"),
                        None => Some(0.0),
                    };
                    let (Some(from), Some(to_value)) = (from, self.time(to, "to")) else {
                        continue;
                    };
                    if to_value <= from {
                        self.error(
                            to.span(),
                            format!("`to` ({to_value}) must be after `from` ({from})"),
                        );
                        continue;
                    }
                    Schedule::Rate {
                        rate_hz,
                        from,
                        to: to_value,
                    }
                }
            };
            let Some(data) = self.payload(raw_event.data.as_ref(), &topics[topic]) else {
                continue;
            };
            frames = frames.saturating_add(schedule.count());
            if frames > MAX_EVENT_FRAMES {
                self.error(
                    event.span(),
                    format!("the events generate more than {MAX_EVENT_FRAMES} frames"),
                );
                return events;
            }
            events.push(Event {
                topic,
                data,
                schedule,
                span: event.span(),
            });
        }
        events
    }

    /// An event's `data = [...]`: as many bytes as its topic's `length`, each 0..=255 (default:
    /// that many zeros). `None` after reporting what is wrong.
    fn payload(
        &mut self,
        raw: Option<&Spanned<Vec<Spanned<i64>>>>,
        topic: &Topic,
    ) -> Option<Vec<u8>> {
        let Some(raw) = raw else {
            return Some(vec![0; usize::from(topic.length)]);
        };
        if raw.get_ref().len() > MAX_DATA_LEN {
            self.error(
                raw.span(),
                format!(
                    "data has {} bytes; a CAN frame carries at most {MAX_DATA_LEN}",
                    raw.get_ref().len()
                ),
            );
            return None;
        }
        let mut bytes = Vec::new();
        for byte in raw.get_ref() {
            match u8::try_from(*byte.get_ref()) {
                Ok(value) => bytes.push(value),
                Err(_) => {
                    self.error(
                        byte.span(),
                        format!("data byte {} is not in 0..=255", byte.get_ref()),
                    );
                    return None;
                }
            }
        }
        if bytes.len() != usize::from(topic.length) {
            let length = if topic.length as usize == MAX_DATA_LEN {
                format!("{MAX_DATA_LEN} (its `length`, {MAX_DATA_LEN} by default)")
            } else {
                format!("{} (its `length`)", topic.length)
            };
            self.error(
                raw.span(),
                format!(
                    "data has {} byte{}, but topic `{}`'s frames carry {length}: write {} bytes, or set `length = {}` on the topic",
                    bytes.len(),
                    if bytes.len() == 1 { "" } else { "s" },
                    topic.name,
                    topic.length,
                    bytes.len()
                ),
            );
            return None;
        }
        Some(bytes)
    }

    fn faults(&mut self, raw: &[Spanned<RawFault>], nodes: &[Node]) -> Vec<Fault> {
        let mut faults: Vec<Fault> = Vec::new();
        for fault in raw {
            let raw_fault = fault.get_ref();
            let wanted = raw_fault.node.get_ref();
            let Some(node) = nodes.iter().position(|node| &node.name == wanted) else {
                if self.declared.nodes.contains(wanted.as_str()) {
                    continue;
                }
                let known: Vec<&str> = nodes.iter().map(|node| node.name.as_str()).collect();
                self.error(
                    raw_fault.node.span(),
                    format!(
                        "node `{}` is not defined (nodes: {}){}",
                        shown::escaped(wanted),
                        list_or_none(&known),
                        suggest(wanted, &known)
                    ),
                );
                continue;
            };
            let Some(at) = self.time(&raw_fault.at, "at") else {
                continue;
            };
            if let Some(earlier) = faults.iter().find(|f| f.node == node) {
                self.error(
                    raw_fault.node.span(),
                    format!(
                        "node `{wanted}` already stops at {} s; a stopped node stays stopped",
                        earlier.at
                    ),
                );
                continue;
            }
            faults.push(Fault { node, at });
        }
        faults
    }

    fn phases(&mut self, raw: &[Spanned<RawPhase>]) -> Vec<Phase> {
        let mut phases = Vec::new();
        for phase in raw {
            let raw_phase = phase.get_ref();
            let name_ok = self.printable(&raw_phase.name, "phase name");
            let note_ok = raw_phase
                .note
                .as_ref()
                .is_none_or(|note| self.printable(note, "phase note"));
            if !(name_ok && note_ok) {
                continue;
            }
            let (Some(from), Some(to)) = (
                self.time(&raw_phase.from, "from"),
                self.time(&raw_phase.to, "to"),
            ) else {
                continue;
            };
            if to <= from {
                self.error(
                    raw_phase.to.span(),
                    format!("`to` ({to}) must be after `from` ({from})"),
                );
                continue;
            }
            phases.push(Phase {
                name: raw_phase.name.get_ref().clone(),
                from,
                to,
                note: raw_phase.note.as_ref().map(|note| note.get_ref().clone()),
            });
        }
        phases
    }
}

/// "; did you mean `x`?" when `wanted` is a slip of one of `known`, else nothing.
fn suggest(wanted: &str, known: &[&str]) -> String {
    crate::diagnostic::did_you_mean(wanted, known.iter().copied())
        .map(|near| format!("; did you mean `{}`?", shown::escaped(near)))
        .unwrap_or_default()
}

fn list_or_none(names: &[&str]) -> String {
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FIGURE_1: &str = r#"
[nodes.gaze]
id = 3

[topics.face_pos]
can_id = 0x110            # extended = true for a 29-bit id; mask optional

[topics.object_pos]
can_id = 0x111

[ports."gaze.target"]

[connections.C1]
topic = "face_pos"
port = "gaze.target"
st = 0.2
tc = 3.0
rule = "C1 & !C2"

[connections.C2]
topic = "object_pos"
port = "gaze.target"
st = 0.2
tc = 3.0                  # no rule: its own activity, "C2"

[[events]]                # frames at from, from + 1/rate_hz, ... while t < to
topic = "face_pos"
rate_hz = 10.0
from = 0.0
to = 12.0

[[events]]
topic = "object_pos"
at = [4.0, 4.5, 5.0, 5.5, 6.0, 6.5]   # or explicit times
"#;

    fn parse(text: &str) -> Result<Network, Diagnostics> {
        Network::parse(Source::new("net.toml", text))
    }

    fn errors(text: &str) -> Vec<String> {
        parse(text)
            .unwrap_err()
            .0
            .iter()
            .map(|d| d.to_string())
            .collect()
    }

    #[test]
    fn figure_one_is_accepted_as_written() {
        let network = parse(FIGURE_1).unwrap();
        assert_eq!(network.nodes.len(), 1);
        assert_eq!(network.nodes[0].id, 3);
        assert_eq!(network.ports[0].name, "gaze.target");
        assert_eq!(network.ports[0].connections, vec![0, 1]);
        let c1 = &network.connections[0];
        assert_eq!(
            c1.rule,
            Rule::And(vec![Rule::Active(0), Rule::Not(Box::new(Rule::Active(1)))])
        );
        assert!(c1.rule_written);
        let c2 = &network.connections[1];
        assert_eq!(c2.rule, Rule::Active(1));
        assert!(!c2.rule_written);
        assert_eq!(network.events[0].schedule.count(), 120);
        assert_eq!(network.events[0].schedule.times().len(), 120);
        assert_eq!(
            network.events[1].schedule.times(),
            vec![4.0, 4.5, 5.0, 5.5, 6.0, 6.5]
        );
        assert_eq!(network.version, 1);
    }

    #[test]
    fn ports_may_republish_what_they_deliver() {
        let text = FIGURE_1.replace(
            "[ports.\"gaze.target\"]\n",
            "[ports.\"gaze.target\"]\nrepublish = { can_id = 0x300 }\n[ports.\"gaze.other\"]\nrepublish = { can_id = 0x1ABCDEF, extended = true }\n[ports.\"gaze.third\"]\n",
        );
        let network = parse(&text).unwrap();
        assert_eq!(
            network.ports[0].consumer,
            Consumer::Republish(OutputId::new(0x300, false).unwrap())
        );
        assert_eq!(
            network.ports[1].consumer,
            Consumer::Republish(OutputId::new(0x1AB_CDEF, true).unwrap())
        );
        assert_eq!(network.ports[2].consumer, Consumer::Local);
    }

    #[test]
    fn bad_republish_values_are_reported_where_they_are() {
        let with = |republish: &str| {
            errors(&FIGURE_1.replace(
                "[ports.\"gaze.target\"]\n",
                &format!("[ports.\"gaze.target\"]\nrepublish = {republish}\n"),
            ))
        };
        // The port header is on line 11, so `republish` is on line 12.
        let errors = with("{ can_id = 0x800 }");
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].starts_with(
                "net.toml:12:24: error: republish can_id 0x800 does not fit a standard (11-bit) id (at most 0x7ff); write `extended = true`"
            ),
            "{errors:?}"
        );
        let errors = with("{ can_id = 0x20000000, extended = true }");
        assert!(
            errors[0].starts_with(
                "net.toml:12:24: error: republish can_id 0x20000000 does not fit an extended (29-bit) id (at most 0x1fffffff)"
            ),
            "{errors:?}"
        );
        let errors = with("{ can_id = -1 }");
        assert!(
            errors[0].starts_with("net.toml:12:24: error: republish can_id"),
            "{errors:?}"
        );
        let errors = with("{ can_id = 0x300, priority = 1 }");
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].starts_with("net.toml:12:31: error: unknown key `priority`"),
            "{errors:?}"
        );
        let errors = with("{ extended = true }");
        assert!(
            errors[0].starts_with("net.toml:12:13: error: missing key `can_id`"),
            "{errors:?}"
        );
    }

    #[test]
    fn syntax_errors_name_file_line_and_cause() {
        let errors = errors("[nodes.gaze]\nid = 3\nspeed = 4\n");
        assert_eq!(errors.len(), 1);
        assert!(
            errors[0].starts_with("net.toml:3:1: error: unknown key `speed`"),
            "{errors:?}"
        );
        let errors = self::errors("[nodes.gaze]\nid = \"three\"\n");
        assert!(
            errors[0].starts_with("net.toml:2:6: error: `id` is a node id, an integer 1 to 127: id = 1, not the string"),
            "{errors:?}"
        );
    }

    #[test]
    fn every_semantic_error_is_reported_with_its_line() {
        let text = r#"
[nodes.arm]
id = 1
[nodes.hand]
id = 1
[topics.a]
can_id = 0x900
[topics.b]
can_id = 0x120
[ports."arm.target"]
[ports."leg.target"]
[connections.C1]
topic = "b"
port = "arm.target"
st = 1.5
tc = 1.0
[connections.C2]
topic = "b"
port = "arm.target"
st = 0.5
tc = 0.0
[connections.C3]
topic = "nope"
port = "arm.target"
st = 0.5
tc = 1.0
"#;
        let errors = errors(text);
        let expected = [
            "net.toml:5:6: error: node id 1 is already used by node `arm`",
            "net.toml:7:10: error: can_id 0x900 does not fit a standard (11-bit) id",
            "net.toml:11:8: error: port `leg.target` is on node `leg`, which is not defined",
            "net.toml:15:6: error: st (σ): gain must be a number in (0, 1]",
            "net.toml:21:6: error: tc (τ): decay time",
            "net.toml:23:9: error: topic `nope` is not defined (topics: b)",
        ];
        assert_eq!(errors.len(), expected.len(), "{errors:#?}");
        for (error, expected) in errors.iter().zip(expected) {
            assert!(
                error.starts_with(expected),
                "{error}\n  expected: {expected}"
            );
        }
    }

    #[test]
    fn rule_errors_point_inside_the_rule() {
        let text = FIGURE_1.replace("rule = \"C1 & !C2\"", "rule = \"C1 & !C7\"");
        let errors = errors(&text);
        assert_eq!(errors.len(), 1);
        // Line 18 is the rule (the text starts with a newline); `C7` starts at column 15.
        assert!(
            errors[0].starts_with("net.toml:18:15: error: in rule \"C1 & !C7\": unknown connection `C7`; the connections of port `gaze.target` are C1, C2"),
            "{}",
            errors[0]
        );
    }

    #[test]
    fn rules_may_only_name_their_own_port() {
        let text = format!(
            "{FIGURE_1}\n[ports.\"gaze.other\"]\n[connections.C3]\ntopic = \"face_pos\"\nport = \"gaze.other\"\nst = 1\ntc = 1\nrule = \"C3 & !C1\"\n"
        );
        let errors = errors(&text);
        assert!(
            errors[0].contains("`C1` is a connection of port `gaze.target`, not of `gaze.other`"),
            "{errors:?}"
        );
    }

    #[test]
    fn events_are_checked() {
        let base = FIGURE_1.split("[[events]]").next().unwrap().to_string();
        let cases = [
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 0\nto = 1\n",
                "rate_hz must be a positive number",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 1\n",
                "needs `to`",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 1\nfrom = 2\nto = 1\n",
                "must be after `from`",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nat = [1.0, -1.0]\n",
                "time -1 is not in",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\n",
                "needs `at = [times...]`",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 1e9\nto = 1000\n",
                "more than 10000000 frames",
            ),
        ];
        for (event, message) in cases {
            let errors = errors(&format!("{base}{event}"));
            assert!(
                errors.iter().any(|e| e.contains(message)),
                "{event}: {errors:?}"
            );
        }
    }

    /// Nodes a and b, ports a.p and b.q, topics t1..t4 (t1 feeds a.p and b.q, t2 feeds a.p),
    /// then `extra`. The fixed part is 31 lines: `extra` starts on line 32.
    fn kinds_file(extra: &str) -> String {
        format!(
            r#"[nodes.a]
id = 1
[nodes.b]
id = 2
[ports."a.p"]
[ports."b.q"]
[topics.t1]
can_id = 1
[topics.t2]
can_id = 2
[topics.t3]
can_id = 3
[topics.t4]
can_id = 4
[connections.A1]
topic = "t1"
port = "a.p"
st = 1
tc = 1
[connections.A2]
topic = "t2"
port = "a.p"
st = 1
tc = 1
[connections.B1]
topic = "t1"
port = "b.q"
st = 1
tc = 1
[connections.X]
topic = "t3"
{extra}"#
        )
    }

    #[test]
    fn special_connections_compile_to_sigma_one_tau_period_rest_zero() {
        let network = parse(&kinds_file(
            "port = \"a.p\"\nkind = \"suppress\"\nperiod = 0.25\n",
        ))
        .unwrap();
        let x = &network.connections[3];
        assert_eq!(
            (x.kind, x.sigma, x.tau, x.rest),
            (Kind::Suppress, 1.0, 0.25, 0.0)
        );
        assert_eq!(
            x.stimulation,
            Stimulation::from_seconds(1.0, 0.25, 0.0).unwrap()
        );
        assert_eq!(x.stimulation.decay_us(), 250_000);
        assert!(x.is_virtual());
        for kind in ["override", "write-inhibit"] {
            let extra =
                format!("port = \"a.p\"\nkind = \"{kind}\"\nperiod = 2\ninhibits = \"t2\"\n");
            let extra = if kind == "override" {
                extra.replace("inhibits = \"t2\"\n", "")
            } else {
                extra
            };
            let network = parse(&kinds_file(&extra)).unwrap();
            assert_eq!(network.connections[3].kind.name(), kind);
            assert_eq!(network.connections[3].stimulation.decay_us(), 2_000_000);
        }
    }

    #[test]
    fn an_inhibit_acts_at_every_port_its_topic_feeds_under_its_own_name() {
        let network = parse(&kinds_file(
            "kind = \"inhibit\"\ninhibits = \"t1\"\nperiod = 0.5\n",
        ))
        .unwrap();
        let at: Vec<(String, usize)> = network
            .connections
            .iter()
            .filter(|c| c.name == "X")
            .map(|c| (network.ports[c.port].name.clone(), c.index))
            .collect();
        assert_eq!(at, [("a.p".to_string(), 2), ("b.q".to_string(), 1)]);
        assert_eq!(network.port_connection_names(0), ["A1", "A2", "X"]);
        assert_eq!(network.port_connection_names(1), ["B1", "X"]);
        assert!(
            network
                .connections
                .iter()
                .filter(|c| c.name == "X")
                .all(|c| {
                    c.is_virtual()
                        && c.inhibits == Some(0)
                        && c.topic == 2
                        && c.kind == Kind::Inhibit
                })
        );
    }

    #[test]
    fn every_misuse_of_a_kind_is_reported_where_it_is() {
        // (the connection's extra lines, the expected errors)
        let cases: &[(&str, &[&str])] = &[
            (
                "port = \"a.p\"\nst = 1\ntc = 1\nperiod = 0.5\n",
                &["net.toml:35:10: error: `period` is for special connections"],
            ),
            (
                "port = \"a.p\"\nkind = \"suppress\"\nperiod = 0.5\nst = 1\ntc = 1\ntr = 0\n",
                &[
                    "net.toml:35:6: error: σ, τ and τr of a special connection follow from its period (σ = 1, τ = period, τr = 0): remove `st`",
                    "net.toml:36:6: error: σ, τ and τr of a special connection follow from its period (σ = 1, τ = period, τr = 0): remove `tc`",
                    "net.toml:37:6: error: σ, τ and τr of a special connection follow from its period (σ = 1, τ = period, τr = 0): remove `tr`",
                ],
            ),
            (
                "port = \"a.p\"\nkind = \"inhibit\"\ninhibits = \"t1\"\nperiod = 0.5\n",
                &[
                    "net.toml:32:8: error: an inhibit connection has no `port`: `X` acts at every port",
                ],
            ),
            (
                "kind = \"inhibit\"\nperiod = 0.5\n",
                &[
                    "net.toml:30:1: error: missing field `inhibits`: an inhibit connection names the topic it inhibits",
                ],
            ),
            (
                "port = \"a.p\"\nkind = \"write-inhibit\"\nperiod = 0.5\n",
                &["net.toml:30:1: error: missing field `inhibits`: a write-inhibit connection"],
            ),
            (
                "kind = \"inhibit\"\ninhibits = \"t9\"\nperiod = 0.5\n",
                &["net.toml:33:12: error: topic `t9` is not defined (topics: t1, t2, t3, t4)"],
            ),
            (
                "kind = \"inhibit\"\ninhibits = \"t4\"\nperiod = 0.5\n",
                &[
                    "net.toml:33:12: error: topic `t4` feeds no port (no normal or override connection has it), so `X` would inhibit nothing",
                ],
            ),
            (
                "kind = \"inhibit\"\ninhibits = \"t3\"\nperiod = 0.5\n",
                &["net.toml:33:12: error: `X` would inhibit its own topic `t3`"],
            ),
            (
                "port = \"b.q\"\nkind = \"write-inhibit\"\ninhibits = \"t2\"\nperiod = 0.5\n",
                &[
                    "net.toml:34:12: error: topic `t2` feeds no connection of port `b.q` that delivers, so `X` has no layer to write-inhibit (the port's delivering topics: t1)",
                ],
            ),
            (
                "port = \"a.p\"\nkind = \"override\"\ninhibits = \"t1\"\nperiod = 0.5\n",
                &[
                    "net.toml:34:12: error: `inhibits` goes with kind = \"inhibit\" or \"write-inhibit\"; `X` is an override connection",
                ],
            ),
            (
                "port = \"a.p\"\nkind = \"suppress\"\nperiod = 0.5\nrule = \"X & A1\"\n",
                &["net.toml:35:8: error: a suppress connection never delivers, so it has no rule"],
            ),
            (
                "port = \"a.p\"\nkind = \"suppress\"\n",
                &[
                    "net.toml:30:1: error: missing field `period`: a suppress connection acts for `period = SECONDS`",
                ],
            ),
            (
                "port = \"a.p\"\nkind = \"subsume\"\nperiod = 1\n",
                &[
                    "net.toml:33:8: error: unknown kind \"subsume\": a connection is \"normal\", \"suppress\", \"inhibit\", \"override\", \"write-inhibit\"",
                ],
            ),
            (
                "port = \"a.p\"\n",
                &[
                    "net.toml:30:1: error: missing field `st`: a normal connection has `st` (σ) and `tc` (τ), or a `kind` with a `period`",
                ],
            ),
            (
                "kind = \"override\"\nperiod = 1\n",
                &["net.toml:30:1: error: missing field `port`"],
            ),
        ];
        for (extra, expected) in cases {
            let errors = errors(&kinds_file(extra));
            assert_eq!(errors.len(), expected.len(), "{extra}\n{errors:#?}");
            for (error, expected) in errors.iter().zip(*expected) {
                assert!(
                    error.starts_with(expected),
                    "{extra}\n{error}\n  expected: {expected}"
                );
            }
        }
    }

    #[test]
    fn periods_must_be_positive_finite_and_storable_in_microseconds() {
        for period in ["0", "-1", "nan", "inf", "-inf"] {
            let errors = errors(&kinds_file(&format!(
                "port = \"a.p\"\nkind = \"suppress\"\nperiod = {period}\n"
            )));
            assert_eq!(errors.len(), 1, "{period}: {errors:?}");
            assert!(
                errors[0].starts_with("net.toml:34:10: error: period")
                    && errors[0].contains("must be a positive number of seconds"),
                "{period}: {errors:?}"
            );
        }
        for period in ["1e-7", "3600.5"] {
            let errors = errors(&kinds_file(&format!(
                "port = \"a.p\"\nkind = \"override\"\nperiod = {period}\n"
            )));
            assert!(
                errors[0].starts_with("net.toml:34:10: error: period")
                    && errors[0].contains("cannot be stored: it becomes the connection's τ, whole microseconds in [0.000001, 3600] seconds"),
                "{period}: {errors:?}"
            );
        }
        // The extremes that can.
        for period in ["0.000001", "3600"] {
            parse(&kinds_file(&format!(
                "port = \"a.p\"\nkind = \"override\"\nperiod = {period}\n"
            )))
            .unwrap();
        }
    }

    #[test]
    fn an_inhibit_that_overflows_a_port_names_the_port() {
        let mut text = kinds_file("kind = \"inhibit\"\ninhibits = \"t1\"\nperiod = 0.5\n");
        // Fill b.q up to the limit with 31 more connections (B1 is the first).
        for k in 0..(MAX_CONNECTIONS_PER_PORT - 1) {
            text += &format!(
                "[topics.f{k}]\ncan_id = {}\n[connections.F{k}]\ntopic = \"f{k}\"\nport = \"b.q\"\nst = 1\ntc = 1\n",
                0x100 + k
            );
        }
        let errors = errors(&text);
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(
            errors[0].starts_with(
                "net.toml:33:12: error: inhibit `X` acts at port `b.q` (fed by `t1`) as one more connection, but that port already has 32 connections, the most a port may have"
            ),
            "{errors:#?}"
        );
    }

    #[test]
    fn events_carry_data_and_faults_stop_nodes() {
        // object_pos's frames carry 2 bytes; face_pos's the default 8, zeros without `data`.
        let two = FIGURE_1.replace("can_id = 0x111\n", "can_id = 0x111\nlength = 2\n");
        let text = format!("{two}data = [0x0A, 0]\n[[faults]]\nnode = \"gaze\"\nat = 12.5\n");
        let network = parse(&text).unwrap();
        assert_eq!(network.topics[0].length, 8);
        assert_eq!(network.topics[1].length, 2);
        assert_eq!(network.events[0].data, vec![0; 8]);
        assert_eq!(network.events[1].data, vec![0x0A, 0]);
        assert_eq!(network.faults, vec![Fault { node: 0, at: 12.5 }]);
        let bad = [
            (
                "data = [1, 2, 3, 4, 5, 6, 7, 8, 9]\n",
                "data has 9 bytes; a CAN frame carries at most 8",
            ),
            (
                "data = [1, 2, 3]\n",
                "data has 3 bytes, but topic `object_pos`'s frames carry 8 (its `length`, 8 by default): write 8 bytes, or set `length = 3` on the topic",
            ),
            ("data = [0x100]\n", "data byte 256 is not in 0..=255"),
            ("data = [-1]\n", "data byte -1 is not in 0..=255"),
            (
                "[[faults]]\nnode = \"arm\"\nat = 1\n",
                "node `arm` is not defined (nodes: gaze)",
            ),
            (
                "[[faults]]\nnode = \"gaze\"\nat = -1\n",
                "at must be a time in [0, 1000000] seconds",
            ),
            (
                "[[faults]]\nnode = \"gaze\"\nat = 1\n[[faults]]\nnode = \"gaze\"\nat = 2\n",
                "node `gaze` already stops at 1 s",
            ),
        ];
        for (extra, message) in bad {
            let errors = errors(&format!("{FIGURE_1}{extra}"));
            assert_eq!(errors.len(), 1, "{extra}: {errors:?}");
            assert!(errors[0].contains(message), "{extra}: {errors:?}");
        }
    }

    #[test]
    fn a_topic_length_is_0_to_8_and_bounds_the_fields_read_from_it() {
        for (length, message) in [
            (
                "9",
                "length = 9: the data bytes of the topic's frames, 0 to 8",
            ),
            (
                "-1",
                "length = -1: the data bytes of the topic's frames, 0 to 8",
            ),
        ] {
            let text = FIGURE_1.replace(
                "can_id = 0x111\n",
                &format!("can_id = 0x111\nlength = {length}\n"),
            );
            let errors = errors(&text);
            assert_eq!(errors.len(), 1, "{errors:?}");
            assert!(errors[0].contains(message), "{errors:?}");
        }
        let ports = |length: u8| {
            format!(
                "[nodes.base]\nid = 4\n[topics.range]\ncan_id = 0x1A0\nlength = {length}\n\
                 [ports.\"base.nearest\"]\ncombine = \"min\"\nvalue = {{ offset = 1, size = 2 }}\n\
                 [connections.R]\ntopic = \"range\"\nport = \"base.nearest\"\nst = 1.0\ntc = 0.3\n"
            )
        };
        let network = parse(&ports(3)).unwrap();
        let fields = network.topic_fields(0);
        assert_eq!(fields.len(), 1, "{fields:?}");
        assert_eq!(
            (fields[0].name.as_str(), fields[0].offset, fields[0].size),
            ("nearest", 1, 2)
        );
        let errors = errors(&ports(2));
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].contains(
                "topic `range` carries 2 bytes (`length = 2`), but port `base.nearest` (combine = \"min\") reads bytes 1..3 of its frames"
            ),
            "{errors:?}"
        );
    }

    #[test]
    fn rate_schedules_exclude_the_end() {
        let schedule = Schedule::Rate {
            rate_hz: 10.0,
            from: 1.0,
            to: 2.0,
        };
        let times = schedule.times();
        assert_eq!(times.len(), 10);
        assert_eq!(times[0], 1.0);
        assert!(times[9] < 2.0);
    }
}
