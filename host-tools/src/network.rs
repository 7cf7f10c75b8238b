//! The network file: nodes, topics, ports, connections, and a scenario of events.
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
use pab_core::integrator::ParamError;
use pab_core::value_port::{MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS};
use pab_core::{
    Combine, Consumer, Endian, Field, Filter, MAX_CONNECTIONS_PER_PORT, MAX_PORTS, OutputId,
    Stimulation, ValueSpec,
};
use serde::Deserialize;
use toml::Spanned;

use crate::diagnostic::{Diagnostic, Diagnostics, Source};
use crate::rule::{self, Rule};
use crate::shown;

/// The most frames the `[[events]]` of one file may generate, so that a typo in a rate cannot
/// exhaust memory.
pub const MAX_EVENT_FRAMES: u64 = 10_000_000;
/// The latest time an event or phase may have, in seconds (about 11.6 days).
pub const MAX_TIME_S: f64 = 1_000_000.0;
/// How much of a rule's text a message repeats (characters); longer rules are shortened with `…`.
pub const RULE_EXCERPT: usize = 80;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    network: Option<RawMeta>,
    #[serde(default)]
    nodes: IndexMap<Spanned<String>, Spanned<RawNode>>,
    #[serde(default)]
    topics: IndexMap<Spanned<String>, Spanned<RawTopic>>,
    #[serde(default)]
    ports: IndexMap<Spanned<String>, Spanned<RawPort>>,
    #[serde(default)]
    connections: IndexMap<Spanned<String>, Spanned<RawConnection>>,
    #[serde(default)]
    events: Vec<Spanned<RawEvent>>,
    #[serde(default)]
    phases: Vec<Spanned<RawPhase>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMeta {
    version: Option<Spanned<i64>>,
    #[allow(dead_code)]
    description: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawNode {
    id: Spanned<i64>,
    #[allow(dead_code)]
    description: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTopic {
    can_id: Spanned<i64>,
    #[serde(default)]
    extended: bool,
    mask: Option<Spanned<i64>>,
    #[allow(dead_code)]
    description: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPort {
    republish: Option<Spanned<RawRepublish>>,
    combine: Option<Spanned<String>>,
    value: Option<Spanned<RawField>>,
    priority: Option<Spanned<RawField>>,
    #[allow(dead_code)]
    description: Option<String>,
}

/// `value = { offset = 0, size = 2, signed = false, endian = "little" }` (or `priority = ...`)
/// on a value port.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawField {
    offset: Spanned<i64>,
    size: Spanned<i64>,
    #[serde(default)]
    signed: bool,
    endian: Option<Spanned<String>>,
}

/// `republish = { can_id = 0x300, extended = false }` on a port.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRepublish {
    can_id: Spanned<i64>,
    #[serde(default)]
    extended: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConnection {
    topic: Spanned<String>,
    port: Spanned<String>,
    st: Spanned<f64>,
    tc: Spanned<f64>,
    tr: Option<Spanned<f64>>,
    rule: Option<Spanned<String>>,
    #[allow(dead_code)]
    description: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEvent {
    topic: Spanned<String>,
    rate_hz: Option<Spanned<f64>>,
    from: Option<Spanned<f64>>,
    to: Option<Spanned<f64>>,
    at: Option<Spanned<Vec<f64>>>,
    #[allow(dead_code)]
    note: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPhase {
    name: Spanned<String>,
    from: Spanned<f64>,
    to: Spanned<f64>,
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

/// A connection from a topic to a port, with its parameters and rule.
#[derive(Clone, Debug)]
pub struct Connection {
    /// Its name, usable in rules.
    pub name: String,
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
    /// Φ: when the connection may deliver, given that it is active.
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
    /// Whether the rule is literally `false`: a virtual connection, which coordinates but never
    /// delivers.
    pub fn is_virtual(&self) -> bool {
        self.rule == Rule::Constant(false)
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

/// A parsed and checked network file.
#[derive(Clone, Debug)]
pub struct Network {
    /// The file.
    pub source: Source,
    /// The version its tables get (`[network] version`, default 1).
    pub version: u32,
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
        let source = Source::read(path)?;
        Network::parse(source)
    }

    /// Checks the network file held by `source`.
    pub fn parse(source: Source) -> Result<Network, Diagnostics> {
        let raw: RawFile = toml::from_str(source.text()).map_err(|error| {
            let span = error.span().unwrap_or(0..0);
            source.error(span, error.message().trim_end().to_string())
        })?;
        let mut errors = Vec::new();
        let network = Builder {
            source: &source,
            errors: &mut errors,
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
        self.rules(&raw.connections, &mut connections, &ports);
        self.value_capacities(&ports, &nodes);
        let events = self.events(&raw.events, &topics);
        let phases = self.phases(&raw.phases);
        let mut nodes = nodes;
        for (index, port) in ports.iter().enumerate() {
            if let Some(node) = nodes.get_mut(port.node) {
                node.ports.push(index);
            }
        }
        Network {
            source: self.source.clone(),
            version,
            nodes,
            topics,
            ports,
            connections,
            events,
            phases,
        }
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
            nodes.push(Node {
                name: name.get_ref().clone(),
                id,
                ports: Vec::new(),
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
            topics.push(Topic {
                name: name.get_ref().clone(),
                filter,
                span: topic.span(),
            });
        }
        topics
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
                let known: Vec<&str> = nodes.iter().map(|node| node.name.as_str()).collect();
                self.error(
                    name.span(),
                    format!(
                        "port `{full}` is on node `{node_name}`, which is not defined (nodes: {})",
                        list_or_none(&known)
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
        let combine = match combine_text.get_ref().as_str() {
            "max" => Some(Combine::Max),
            "min" => Some(Combine::Min),
            "sum" => Some(Combine::Sum),
            "priority" => Some(Combine::Priority),
            other => {
                self.error(
                    combine_text.span(),
                    format!(
                        "combine = \"{}\" is not a combination: \"max\", \"min\", \"sum\" or \"priority\"",
                        shown::escaped(other)
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
        let endian = match field
            .endian
            .as_ref()
            .map(|endian| endian.get_ref().as_str())
        {
            None | Some("little") => Endian::Little,
            Some("big") => Endian::Big,
            Some(other) => {
                let span = field.endian.as_ref().map_or(raw.span(), Spanned::span);
                self.error(
                    span,
                    format!(
                        "{key}: endian = \"{}\" is not \"little\" or \"big\"",
                        shown::escaped(other)
                    ),
                );
                return None;
            }
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
            let Some(topic) = topics.iter().position(|topic| &topic.name == topic_name) else {
                let known: Vec<&str> = topics.iter().map(|topic| topic.name.as_str()).collect();
                self.error(
                    raw_connection.topic.span(),
                    format!(
                        "topic `{topic_name}` is not defined (topics: {})",
                        list_or_none(&known)
                    ),
                );
                continue;
            };
            let port_name = raw_connection.port.get_ref();
            let Some(port) = ports.iter().position(|port| &port.name == port_name) else {
                let known: Vec<&str> = ports.iter().map(|port| port.name.as_str()).collect();
                self.error(
                    raw_connection.port.span(),
                    format!(
                        "port `{port_name}` is not defined (ports: {})",
                        list_or_none(&known)
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
            let sigma = *raw_connection.st.get_ref();
            let tau = *raw_connection.tc.get_ref();
            let rest = raw_connection.tr.as_ref().map_or(0.0, |tr| *tr.get_ref());
            let stimulation = match Stimulation::from_seconds(sigma, tau, rest) {
                Ok(stimulation) => stimulation,
                Err(error) => {
                    let span = match error {
                        ParamError::Gain(_) => raw_connection.st.span(),
                        ParamError::DecayTime => raw_connection.tc.span(),
                        ParamError::RestTime => raw_connection
                            .tr
                            .as_ref()
                            .map_or(name.span(), |tr| tr.span()),
                    };
                    self.error(span, error.to_string());
                    continue;
                }
            };
            let index = siblings;
            if let Some(port) = ports.get_mut(port) {
                port.connections.push(connections.len());
            }
            connections.push(Connection {
                name: name.get_ref().clone(),
                topic,
                port,
                index,
                sigma,
                tau,
                rest,
                stimulation,
                rule: Rule::Active(index),
                rule_text: name.get_ref().clone(),
                rule_written: false,
                rule_span: name.span(),
                span: connection.span(),
            });
        }
        connections
    }

    fn rules(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawConnection>>,
        connections: &mut [Connection],
        ports: &[Port],
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
            let resolve = |name: &str| -> Result<usize, String> {
                if let Some((_, index)) = names.iter().find(|(n, _)| n == name) {
                    return Ok(*index);
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
                        "unknown connection `{name}`; the connections of port `{port_name}` are {}",
                        listed.join(", ")
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
                let known: Vec<&str> = topics.iter().map(|topic| topic.name.as_str()).collect();
                self.error(
                    raw_event.topic.span(),
                    format!(
                        "topic `{topic_name}` is not defined (topics: {})",
                        list_or_none(&known)
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
                schedule,
                span: event.span(),
            });
        }
        events
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
            errors[0].starts_with("net.toml:12:31: error: unknown field `priority`"),
            "{errors:?}"
        );
        let errors = with("{ extended = true }");
        assert!(
            errors[0].starts_with("net.toml:12:13: error: missing field `can_id`"),
            "{errors:?}"
        );
    }

    #[test]
    fn syntax_errors_name_file_line_and_cause() {
        let errors = errors("[nodes.gaze]\nid = 3\nspeed = 4\n");
        assert_eq!(errors.len(), 1);
        assert!(
            errors[0].starts_with("net.toml:3:1: error: unknown field `speed`"),
            "{errors:?}"
        );
        let errors = self::errors("[nodes.gaze]\nid = \"three\"\n");
        assert!(
            errors[0].starts_with("net.toml:2:6: error: invalid type"),
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
