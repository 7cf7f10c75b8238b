//! The network file and its model: [`Network`], built section by section, one file each in
//! `network/`: nodes, topics, ports, connections and their rules, BLE groups, competitive-dynamics
//! groups and their gates, HBBA's resources and strategies, a schema server's board and client,
//! the plant it drives in simulation, and a scenario of events, phases and faults. This file holds
//! the whole file's table, the model and the builder that runs the sections in order.
//!
//! Parsing is in two steps. `toml` turns the text into raw tables, keeping the byte span of every
//! value; then [`Network::parse`] checks every name, number and rule and reports each mistake at
//! its line and column. All mistakes of a file are reported in one run, not just the first.
//!
//! Orders matter and are kept: connections in the order of the file are the variables of their
//! port's rules (bit i of an activity mask), and ties in traces are broken in that order.

use std::collections::HashSet;
use std::ops::Range;
use std::path::Path;

use indexmap::IndexMap;
use schemars::JsonSchema;
use serde::Deserialize;
use spanned::Spanned;

use crate::diagnostic::{Diagnostic, Diagnostics, Source};
use crate::shown;

mod ble;
mod bus;
mod connections;
mod dynamics;
mod fields;
mod gates;
mod hbba;
mod json_schema;
mod nodes;
mod plant;
mod ports;
mod rules;
mod scenario;
mod schema;
mod spanned;
mod structure;
mod topics;

pub use ble::{BleGroup, BleMember};
pub use bus::Bus;
pub use connections::{Connection, Kind, NO_TOPIC};
pub use dynamics::{Context, DynamicsBehaviour, DynamicsGroup, WrittenBehaviour, WrittenExclusion};
pub use fields::TopicField;
pub use gates::lookup as gate;
pub use hbba::{
    BUS, Hbba, HbbaStrategy, MAX_BITRATE, Resource, ScriptedDesire, Solved, StrategyFilter,
    bus_cost, bus_cost_at,
};
pub use json_schema::json_schema;
pub use nodes::Node;
pub use plant::{Obstacle, PlantConfig};
pub use ports::{Port, combine_name};
pub use rules::RULE_EXCERPT;
pub use scenario::{Event, Fault, MAX_EVENT_FRAMES, MAX_TIME_S, Phase, Schedule};
pub use schema::{
    CALLS, Call, Client, Command, Defaults, INNATE_IDS, MAX_CALLS, SchemaBoard, SensorTopic, Timed,
};
pub use topics::{MAX_RATE_HZ, MAX_TOPIC_SECONDS, Topic, TopicTiming};

/// A network file (docs/network-file.md): nodes, topics, ports, connections, BLE groups,
/// competitive dynamics, HBBA, a schema server, and a simulation's scenario. Unknown keys are
/// errors.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawFile {
    /// Optional: the network's version and description.
    network: Option<RawMeta>,
    /// Optional: the CAN bus, its bit rate (and a CAN FD bus's data rate).
    bus: Option<Spanned<bus::RawBus>>,
    /// The nodes (controller boards or their Linux stand-ins), by name.
    #[serde(default)]
    nodes: IndexMap<Spanned<String>, Spanned<nodes::RawNode>>,
    /// The topics (streams of CAN frames), by name.
    #[serde(default)]
    topics: IndexMap<Spanned<String>, Spanned<topics::RawTopic>>,
    /// The ports (a node's inputs), by `"<node>.<port>"`.
    #[serde(default)]
    ports: IndexMap<Spanned<String>, Spanned<ports::RawPort>>,
    /// The connections from topics to ports, by the name rules refer to (letters, digits, _); in
    /// file order, the variables of their port's rules.
    #[serde(default)]
    connections: IndexMap<Spanned<String>, Spanned<connections::RawConnection>>,
    /// Simulation only: frames published on a topic.
    #[serde(default)]
    events: Vec<Spanned<scenario::RawEvent>>,
    /// Simulation only, optional: labels for the plot's bottom strip.
    #[serde(default)]
    phases: Vec<Spanned<scenario::RawPhase>>,
    /// Simulation only, optional, with `[hbba]`: desires `pabctl sim` issues (at most 32).
    #[serde(default)]
    desires: Vec<Spanned<hbba::RawDesire>>,
    /// Simulation only, optional: nodes that stop (one per node).
    #[serde(default)]
    faults: Vec<Spanned<scenario::RawFault>>,
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
    /// The bus's bit rate (`[bus] bitrate`, or `[hbba] bitrate` in a file without `[bus]`), and a
    /// CAN FD bus's data rate (`[bus] data_bitrate`).
    pub bus: Option<Bus>,
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

impl Network {
    /// Reads and checks the network file at `path`.
    pub fn load(path: &Path) -> Result<Network, Diagnostics> {
        // A regular file of at most 16 MiB: a FIFO or /dev/zero given by mistake is refused
        // before it is opened (crate::input).
        let text = crate::input::read_text(path, "network file", crate::input::MAX_NETWORK_BYTES)?;
        Network::parse(Source::new(path, text))
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
            data_bitrate: None,
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
    /// A CAN FD bus's data rate (`[bus] data_bitrate`): a field of a topic's frames may then lie
    /// past byte 8 (within its topic's `length`), and HBBA's bus costs count CAN FD topics'
    /// frames with their data phase at this rate.
    data_bitrate: Option<u32>,
}

/// The names the file declares, whether or not their declaration was accepted. A reference to a
/// declared name that was refused is a consequence of that refusal, reported at the declaration:
/// not reported again where it is used (a cascade before its cause, otherwise).
struct Declared {
    nodes: HashSet<String>,
    topics: HashSet<String>,
    ports: HashSet<String>,
    connections: HashSet<String>,
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
        let bus = self.bus(raw.bus.as_ref());
        self.data_bitrate = bus.as_ref().and_then(|bus| bus.data_bitrate);
        let nodes = self.nodes(&raw.nodes, bus.as_ref());
        let topics = self.topics(&raw.topics, bus.as_ref(), raw.bus.is_some());
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
        let (hbba, bus) = self.hbba(raw.hbba.as_ref(), bus, &topics, &connections, &names);
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
            bus,
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
    use crate::rule::Rule;

    /// The paper's figure 1: the base every section's tests vary.
    pub(super) const FIGURE_1: &str = r#"
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

    pub(super) fn parse(text: &str) -> Result<Network, Diagnostics> {
        Network::parse(Source::new("net.toml", text))
    }

    pub(super) fn errors(text: &str) -> Vec<String> {
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
}
