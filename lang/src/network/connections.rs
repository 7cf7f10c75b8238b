//! `[connections.NAME]`: what links a topic to a port: its kind (docs/ayllu.md), its parameters
//! (σ, τ and τr, or a special kind's period), and the inhibits, each expanded into one connection
//! at every port the topic it inhibits feeds.

use std::ops::Range;

use indexmap::IndexMap;
use pab_core::integrator::ParamError;
use pab_core::{MAX_CONNECTIONS_PER_PORT, Stimulation};
use schemars::JsonSchema;
use serde::Deserialize;

use super::spanned::Spanned;
use super::{Builder, Port, Topic, list_or_none, suggest};
use crate::rule::{self, Rule};
use crate::shown;

/// The topic of a connection that no topic feeds (a gate, [`Kind::Gate`]): no index of
/// [`Network::topics`](super::Network::topics).
pub const NO_TOPIC: usize = usize::MAX;

/// `[connections.NAME]`: a connection from a topic to a port (docs/ayllu.md for the kinds).
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConnection {
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
    pub(super) rule: Option<Spanned<String>>,
    /// Optional, default "normal": what the connection does at its port.
    #[schemars(extend("enum" = Kind::ALL.map(Kind::name)))]
    kind: Option<Spanned<String>>,
    /// Seconds, (0, 3600], kept in whole microseconds: required for special kinds (all but
    /// normal), refused on normal ones.
    period: Option<Spanned<f64>>,
    /// The topic an inhibit or write-inhibit connection holds back: required for those kinds.
    inhibits: Option<Spanned<String>>,
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
    /// rule that names a group (`[ble.NAME]`) adds one, named after it
    /// ([`BleGroup`](super::BleGroup)). Its `topic` is the node's eligibility topic for the group,
    /// which never feeds it.
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
    /// [`Network::topics`](super::Network::topics).
    pub inhibits: Option<usize>,
    /// Its topic, as an index into [`Network::topics`](super::Network::topics).
    pub topic: usize,
    /// Its port, as an index into [`Network::ports`](super::Network::ports).
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

impl Builder<'_> {
    pub(super) fn connections(
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::tests::{errors, parse};

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
}
