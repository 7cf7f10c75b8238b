//! `[dynamics.NAME]`: a group of elementary behaviours selected by competitive dynamics (DESIGN.md,
//! "Competitive dynamics: decisions"), run by one node, and `[dynamics.NAME.behaviours.B]`, its
//! behaviours in file order.
//!
//! Times are written in seconds (`step`, `unit`) or in units of the equations (every τ and
//! `memory`); [`DynamicsGroup::params`] holds them as `pab_core::dynamics::Params` stores them
//! (µs, Q8.8, Q16.16, Q0.32), checked by `Params::validate`. Gates do not enter rules yet.

use std::borrow::Cow;
use std::fmt;
use std::ops::Range;

use super::spanned::Spanned;
use indexmap::IndexMap;
use pab_core::Field;
use pab_core::dynamics::{C_ONE, GAMMA_ONE, MAX_BEHAVIOURS, Params, ParamsError, Time};
use schemars::{JsonSchema, Schema, SchemaGenerator, json_schema};
use serde::Deserialize;
use serde::de::{self, Deserializer, MapAccess, Visitor};

use super::ports::RawField;
use super::{Builder, Connection, Node, Port, Topic, list_or_none};
use crate::rule;
use crate::shown;

/// `[dynamics.NAME] node = "base", step = 0.001, ...` and its behaviours.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDynamics {
    /// Required: the node that runs the group.
    #[schemars(required)]
    node: Option<Spanned<String>>,
    /// Seconds per integration step, default 0.001; steps at t = k * step.
    step: Option<Spanned<f64>>,
    /// Seconds per time unit of the equations, default 0.01.
    unit: Option<Spanned<f64>>,
    /// q, per square-root unit, in (0, 1), default 0.001.
    noise: Option<Spanned<f64>>,
    /// The noise generator's seed, 1..=4294967295, default 1.
    seed: Option<Spanned<i64>>,
    /// Steepness of the presupposition's tanh, default 10.
    c: Option<Spanned<f64>>,
    /// τ in units, default 1 (kept in whole microseconds).
    tau: Option<Spanned<f64>>,
    /// τ_ρ1 in units, default 1 (kept in whole microseconds).
    tau_rho_fast: Option<Spanned<f64>>,
    /// τ_ρ2 in units, default 20 (kept in whole microseconds).
    tau_rho_slow: Option<Spanned<f64>>,
    /// τ_n in units, default 1 (kept in whole microseconds).
    tau_n: Option<Spanned<f64>>,
    /// γ of every declared exclusion in this group, [0, 255], default 3.
    gamma: Option<Spanned<f64>>,
    /// Its behaviours, in file order (1 to 32), by name.
    #[serde(default)]
    behaviours: IndexMap<Spanned<String>, Spanned<RawBehaviour>>,
}

/// `[dynamics.NAME.behaviours.B] context = ..., memory = 50.0, excludes = [...], gamma = {...},
/// requires = [...]`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawBehaviour {
    /// Required: its sensor context, a connection's name, a constant in [0, 1], or a topic's
    /// field.
    #[schemars(required)]
    context: Option<Spanned<RawContext>>,
    /// τ_i in units, optional, default 50.
    memory: Option<Spanned<f64>>,
    /// Optional: behaviours of the group that push this one off while active (γ = the group's
    /// gamma).
    #[serde(default)]
    excludes: Vec<Spanned<String>>,
    /// Optional: per-pair γ, behaviour = γ (declares the exclusion if excludes does not).
    #[serde(default)]
    gamma: IndexMap<Spanned<String>, Spanned<f64>>,
    /// Optional: behaviours that must have been active before this one can start.
    #[serde(default)]
    requires: Vec<Spanned<String>>,
}

/// `context = "C3"`, `context = 1.0` or `context = { topic, value, scale, timeout }`.
enum RawContext {
    Connection(String),
    Constant(f64),
    Topic(RawTopicContext),
}

/// `context = { topic, value, scale, timeout }`: the last frame's field / scale, 0 before any
/// frame and once timeout seconds have passed.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawTopicContext {
    /// Required: the topic whose frames carry the context.
    topic: Spanned<String>,
    /// Required: the field, with the keys of a value port's value.
    value: Spanned<RawField>,
    /// Required: the divisor, from 1/256 to 16777215, kept in 1/256.
    scale: Spanned<f64>,
    /// Required: seconds a frame's value holds, up to 3600.
    timeout: Spanned<f64>,
}

/// As its `Deserialize` takes it: a string, a number or a table.
impl JsonSchema for RawContext {
    fn schema_name() -> Cow<'static, str> {
        "RawContext".into()
    }

    fn json_schema(generator: &mut SchemaGenerator) -> Schema {
        json_schema!({
            "anyOf": [
                {
                    "description": "The activity (0 or 1) of a connection on the group's node, by name.",
                    "type": "string",
                },
                {
                    "description": "A constant in [0, 1].",
                    "type": "number",
                },
                generator.subschema_for::<RawTopicContext>(),
            ],
        })
    }
}

impl<'de> Deserialize<'de> for RawContext {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct ContextVisitor;
        impl<'de> Visitor<'de> for ContextVisitor {
            type Value = RawContext;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(
                    "a connection name, a constant in [0, 1], or { topic, value, scale, timeout }",
                )
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<RawContext, E> {
                Ok(RawContext::Connection(v.to_string()))
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<RawContext, E> {
                Ok(RawContext::Constant(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<RawContext, E> {
                Ok(RawContext::Constant(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<RawContext, E> {
                Ok(RawContext::Constant(v as f64))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<RawContext, A::Error> {
                RawTopicContext::deserialize(de::value::MapAccessDeserializer::new(map))
                    .map(RawContext::Topic)
            }
        }
        deserializer.deserialize_any(ContextVisitor)
    }
}

/// A behaviour's sensor context C_i, sampled at each step's time.
#[derive(Clone, Debug, PartialEq)]
pub enum Context {
    /// The activity (0 or 1) of a connection on the group's node.
    Connection {
        /// The connection, as an index into [`super::Network::connections`].
        connection: usize,
    },
    /// The last frame's field of a topic, divided by `scale`; 0 before any frame and once
    /// `timeout_us` has passed since the last one.
    Topic {
        /// The topic, as an index into [`super::Network::topics`].
        topic: usize,
        /// Where the value is in the frames.
        field: Field,
        /// The divisor.
        scale: f64,
        /// How long a frame's value holds, µs.
        timeout_us: u64,
    },
    /// A constant in [0, 1].
    Constant(f64),
}

/// One behaviour of a group.
#[derive(Clone, Debug)]
pub struct DynamicsBehaviour {
    /// Its name (`door.search` in traces).
    pub name: String,
    /// Its context.
    pub context: Context,
    /// Where its keys are written and their values in the file's terms, for the checker's
    /// warnings (`check::dynamics`).
    pub written: WrittenBehaviour,
}

/// A behaviour's keys as written: spans into the network file, γ as a number.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WrittenBehaviour {
    /// Its `context` value.
    pub context: Range<usize>,
    /// Its declared exclusions (`excludes` and `gamma`), in the file's order.
    pub exclusions: Vec<WrittenExclusion>,
    /// Its `requires` entries: the required behaviour's index and the entry's span.
    pub requires: Vec<(usize, Range<usize>)>,
}

/// One declared exclusion γ_ij: this behaviour is pushed off while `by` is active.
#[derive(Clone, Debug, PartialEq)]
pub struct WrittenExclusion {
    /// j, as an index into the group's behaviours.
    pub by: usize,
    /// γ_ij as written (the group's `gamma` unless a per-pair `gamma` sets it).
    pub gamma: f64,
    /// Whether γ is the group's `gamma` (else the behaviour's `gamma = { by = ... }`).
    pub from_group: bool,
    /// The key that sets γ: the per-pair `gamma` value, else the `excludes` entry.
    pub span: Range<usize>,
}

/// A group of behaviours whose competition one node runs.
#[derive(Clone, Debug)]
pub struct DynamicsGroup {
    /// Its name.
    pub name: String,
    /// The node that runs it, as an index into [`super::Network::nodes`].
    pub node: usize,
    /// Its behaviours, in file order (the order of the noise and of the gate bits).
    pub behaviours: Vec<DynamicsBehaviour>,
    /// Its parameters as a board stores them, valid (`Params::validate`).
    pub params: Params,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// DESIGN.md's defaults, in the file's terms.
const STEP: f64 = 0.001;
const UNIT: f64 = 0.01;
const NOISE: f64 = 0.001;
const C: f64 = 10.0;
const TAU: f64 = 1.0;
const TAU_RHO_FAST: f64 = 1.0;
const TAU_RHO_SLOW: f64 = 20.0;
const TAU_N: f64 = 1.0;
const GAMMA: f64 = 3.0;
const MEMORY: f64 = 50.0;

impl Builder<'_> {
    /// The `[dynamics.*]` sections, in file order.
    pub(super) fn dynamics_groups(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawDynamics>>,
        nodes: &[Node],
        topics: &[Topic],
        ports: &[Port],
        connections: &[Connection],
    ) -> Vec<DynamicsGroup> {
        let mut groups = Vec::new();
        for (name, group) in raw {
            let text = name.get_ref();
            if !self.printable(name, "dynamics group name") {
                continue;
            }
            if !rule::is_valid_name(text) {
                self.error(
                    name.span(),
                    format!(
                        "dynamics group name `{text}` cannot be used in rules: start with a letter or `_`, then letters, digits, `_`"
                    ),
                );
                continue;
            }
            if let Some(group) = self.dynamics_group(name, group, nodes, topics, ports, connections)
            {
                groups.push(group);
            }
        }
        groups
    }

    fn dynamics_group(
        &mut self,
        written_name: &Spanned<String>,
        raw: &Spanned<RawDynamics>,
        nodes: &[Node],
        topics: &[Topic],
        ports: &[Port],
        connections: &[Connection],
    ) -> Option<DynamicsGroup> {
        let name = written_name.get_ref().as_str();
        let span = raw.span();
        let group = raw.get_ref();
        let mut ok = true;
        let node = match &group.node {
            None => {
                self.error(
                    span.clone(),
                    format!(
                        "missing field `node`: dynamics group `{name}` is run by one node, `node = \"NAME\"`"
                    ),
                );
                None
            }
            Some(node) => {
                let found = nodes.iter().position(|n| &n.name == node.get_ref());
                if found.is_none() {
                    let known: Vec<&str> = nodes.iter().map(|n| n.name.as_str()).collect();
                    self.error(
                        node.span(),
                        format!(
                            "dynamics group `{name}`: node `{}` is not defined (nodes: {})",
                            shown::escaped(node.get_ref()),
                            list_or_none(&known)
                        ),
                    );
                }
                found
            }
        };
        let mut params = Params::new();
        let step = self.positive(&group.step, STEP, "step", "seconds");
        let unit = self.positive(&group.unit, UNIT, "unit", "seconds");
        let (Some(step), Some(unit)) = (step, unit) else {
            return None;
        };
        let unit_us = unit * 1e6;
        ok &= self.store_micros(
            &mut params.step_us,
            (step * 1e6).round(),
            &group.step,
            span.clone(),
            "step",
        );
        ok &= self.store_micros(
            &mut params.unit_us,
            unit_us.round(),
            &group.unit,
            span.clone(),
            "unit",
        );
        for (slot, written, default, key) in [
            (&mut params.tau_us, &group.tau, TAU, "tau"),
            (
                &mut params.tau_rho_fast_us,
                &group.tau_rho_fast,
                TAU_RHO_FAST,
                "tau_rho_fast",
            ),
            (
                &mut params.tau_rho_slow_us,
                &group.tau_rho_slow,
                TAU_RHO_SLOW,
                "tau_rho_slow",
            ),
            (&mut params.tau_n_us, &group.tau_n, TAU_N, "tau_n"),
        ] {
            match self.positive(written, default, key, "units") {
                Some(units) => {
                    ok &= self.store_micros(
                        slot,
                        (units * unit_us).round(),
                        written,
                        span.clone(),
                        key,
                    );
                }
                None => ok = false,
            }
        }
        let noise = group.noise.as_ref().map_or(NOISE, |n| *n.get_ref());
        if !(0.0..1.0).contains(&noise) {
            self.error(
                group.noise.as_ref().map_or(span.clone(), Spanned::span),
                format!("noise = {noise}: q is in (0, 1) per √unit (default {NOISE})"),
            );
            ok = false;
        } else {
            params.noise = (noise * 4_294_967_296.0).round().min(f64::from(u32::MAX)) as u32;
        }
        if let Some(seed) = &group.seed {
            match u32::try_from(*seed.get_ref()) {
                Ok(value) => params.seed = value,
                Err(_) => {
                    self.error(
                        seed.span(),
                        format!(
                            "seed = {}: a seed is an integer from 1 to {}",
                            seed.get_ref(),
                            u32::MAX
                        ),
                    );
                    ok = false;
                }
            }
        }
        let c = group.c.as_ref().map_or(C, |c| *c.get_ref());
        let c_max = f64::from(u32::MAX) / f64::from(C_ONE);
        if !(c.is_finite() && c > 0.0 && c <= c_max) {
            self.error(
                group.c.as_ref().map_or(span.clone(), Spanned::span),
                format!("c = {c}: the steepness c is in (0, {c_max:.0}]"),
            );
            ok = false;
        } else {
            params.c = (c * f64::from(C_ONE)).round() as u32;
        }
        let gamma = match &group.gamma {
            None => Some(GAMMA),
            Some(gamma) => self.gamma(gamma, "gamma"),
        };
        ok &= gamma.is_some();
        let behaviours = self.dynamics_behaviours(
            name,
            group,
            span.clone(),
            node,
            unit_us,
            gamma.unwrap_or(GAMMA),
            &mut params,
            nodes,
            topics,
            ports,
            connections,
        );
        let (Some(node), Some(behaviours), true) = (node, behaviours, ok) else {
            return None;
        };
        if let Err(error) = params.validate() {
            let names: Vec<&str> = behaviours.iter().map(|b| b.name.as_str()).collect();
            // At the group's header line.
            self.error(
                written_name.span(),
                format!(
                    "dynamics group `{name}`: {}",
                    explain(&error, &names, &params)
                ),
            );
            return None;
        }
        Some(DynamicsGroup {
            name: name.to_string(),
            node,
            behaviours,
            params,
            span,
        })
    }

    /// A positive finite number written at `written` (or `default`); `None` after reporting.
    fn positive(
        &mut self,
        written: &Option<Spanned<f64>>,
        default: f64,
        key: &str,
        what: &str,
    ) -> Option<f64> {
        let Some(written) = written else {
            return Some(default);
        };
        let value = *written.get_ref();
        if value.is_finite() && value > 0.0 {
            Some(value)
        } else {
            self.error(
                written.span(),
                format!("{key} = {value}: a time in {what}, positive and finite"),
            );
            None
        }
    }

    /// Stores `micros` (already rounded) in `slot` if it is a whole number of µs in 1..=u32::MAX.
    fn store_micros(
        &mut self,
        slot: &mut u32,
        micros: f64,
        written: &Option<Spanned<f64>>,
        span: Range<usize>,
        key: &str,
    ) -> bool {
        if (1.0..=f64::from(u32::MAX)).contains(&micros) {
            *slot = micros as u32;
            true
        } else {
            self.error(
                written.as_ref().map_or(span, Spanned::span),
                format!(
                    "{key}: {micros} µs, a time the boards cannot store (1 µs to {} µs)",
                    u32::MAX
                ),
            );
            false
        }
    }

    /// γ in Q8.8: a number in [0, 255].
    fn gamma(&mut self, written: &Spanned<f64>, key: &str) -> Option<f64> {
        let value = *written.get_ref();
        if value.is_finite() && (0.0..=255.0).contains(&value) {
            Some(value)
        } else {
            self.error(written.span(), format!("{key} = {value}: γ is in [0, 255]"));
            None
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn dynamics_behaviours(
        &mut self,
        group_name: &str,
        group: &RawDynamics,
        span: Range<usize>,
        node: Option<usize>,
        unit_us: f64,
        gamma: f64,
        params: &mut Params,
        nodes: &[Node],
        topics: &[Topic],
        ports: &[Port],
        connections: &[Connection],
    ) -> Option<Vec<DynamicsBehaviour>> {
        if group.behaviours.is_empty() {
            self.error(
                span,
                format!(
                    "dynamics group `{group_name}` has no behaviour: add [dynamics.{group_name}.behaviours.NAME] sections"
                ),
            );
            return None;
        }
        if group.behaviours.len() > MAX_BEHAVIOURS {
            self.error(
                span,
                format!(
                    "dynamics group `{group_name}` has {} behaviours, more than {MAX_BEHAVIOURS}",
                    group.behaviours.len()
                ),
            );
            return None;
        }
        let names: Vec<&str> = group
            .behaviours
            .keys()
            .map(|k| k.get_ref().as_str())
            .collect();
        let mut ok = true;
        let mut behaviours = Vec::new();
        for (name, raw) in &group.behaviours {
            let text = name.get_ref();
            if !self.printable(name, "behaviour name") {
                ok = false;
                continue;
            }
            if !rule::is_valid_name(text) {
                self.error(
                    name.span(),
                    format!(
                        "behaviour name `{text}` cannot be used in rules: start with a letter or `_`, then letters, digits, `_`"
                    ),
                );
                ok = false;
                continue;
            }
            let behaviour = raw.get_ref();
            let memory = self.positive(&behaviour.memory, MEMORY, "memory", "units");
            let memory_us = memory.and_then(|m| {
                let mut slot = 0;
                self.store_micros(
                    &mut slot,
                    (m * unit_us).round(),
                    &behaviour.memory,
                    raw.span(),
                    "memory",
                )
                .then_some(slot)
            });
            let context = self.context(
                group_name,
                text,
                &behaviour.context,
                raw.span(),
                node.and_then(|n| Some((n, nodes.get(n)?.name.as_str()))),
                topics,
                ports,
                connections,
            );
            let (Some(memory_us), Some(context)) = (memory_us, context) else {
                ok = false;
                continue;
            };
            if params.add_behaviour(memory_us).is_err() {
                ok = false;
                continue;
            }
            behaviours.push(DynamicsBehaviour {
                name: text.clone(),
                context,
                written: WrittenBehaviour {
                    context: behaviour.context.as_ref().map_or(0..0, Spanned::span),
                    ..WrittenBehaviour::default()
                },
            });
        }
        if !ok {
            return None;
        }
        // Exclusions and requirements, now that every behaviour has its index.
        for (i, (name, raw)) in group.behaviours.iter().enumerate() {
            let behaviour = raw.get_ref();
            let mut pairs: Vec<(u8, f64, bool, Range<usize>)> = Vec::new();
            for other in &behaviour.excludes {
                let Some(j) =
                    self.behaviour_index(group_name, name.get_ref(), other, &names, "excludes")
                else {
                    ok = false;
                    continue;
                };
                if pairs.iter().any(|(k, ..)| *k == j) {
                    self.error(
                        other.span(),
                        format!("excludes: `{}` is listed twice", other.get_ref()),
                    );
                    ok = false;
                    continue;
                }
                pairs.push((j, gamma, true, other.span()));
            }
            for (other, value) in &behaviour.gamma {
                let Some(j) =
                    self.behaviour_index(group_name, name.get_ref(), other, &names, "gamma")
                else {
                    ok = false;
                    continue;
                };
                let span = value.span();
                let Some(value) = self.gamma(value, &format!("gamma.{}", other.get_ref())) else {
                    ok = false;
                    continue;
                };
                // A per-pair γ declares the exclusion too, or overrides the group's γ for it.
                match pairs.iter_mut().find(|(k, ..)| *k == j) {
                    Some(pair) => *pair = (j, value, false, span),
                    None => pairs.push((j, value, false, span)),
                }
            }
            for (j, value, from_group, span) in pairs {
                if usize::from(j) == i {
                    self.error(
                        raw.span(),
                        format!(
                            "behaviour `{}` of dynamics group `{group_name}` excludes itself (γ_ii must be 0)",
                            name.get_ref()
                        ),
                    );
                    ok = false;
                    continue;
                }
                let q88 = (value * f64::from(GAMMA_ONE)).round() as u16;
                ok &= params.exclude(i as u8, j, q88).is_ok();
                if let Some(written) = behaviours.get_mut(i).map(|b| &mut b.written) {
                    written.exclusions.push(WrittenExclusion {
                        by: usize::from(j),
                        gamma: value,
                        from_group,
                        span,
                    });
                }
            }
            for other in &behaviour.requires {
                let Some(j) =
                    self.behaviour_index(group_name, name.get_ref(), other, &names, "requires")
                else {
                    ok = false;
                    continue;
                };
                if usize::from(j) == i {
                    self.error(
                        other.span(),
                        format!(
                            "behaviour `{}` of dynamics group `{group_name}` requires itself",
                            name.get_ref()
                        ),
                    );
                    ok = false;
                    continue;
                }
                ok &= params.require(i as u8, j).is_ok();
                if let Some(written) = behaviours.get_mut(i).map(|b| &mut b.written) {
                    written.requires.push((usize::from(j), other.span()));
                }
            }
        }
        ok.then_some(behaviours)
    }

    fn behaviour_index(
        &mut self,
        group: &str,
        behaviour: &str,
        other: &Spanned<String>,
        names: &[&str],
        key: &str,
    ) -> Option<u8> {
        let found = names.iter().position(|n| n == other.get_ref());
        if found.is_none() {
            self.error(
                other.span(),
                format!(
                    "{key} of behaviour `{behaviour}`: `{}` is not a behaviour of dynamics group `{group}` (its behaviours: {})",
                    shown::escaped(other.get_ref()),
                    list_or_none(names)
                ),
            );
        }
        found.and_then(|i| u8::try_from(i).ok())
    }

    #[allow(clippy::too_many_arguments)]
    fn context(
        &mut self,
        group: &str,
        behaviour: &str,
        written: &Option<Spanned<RawContext>>,
        span: Range<usize>,
        node: Option<(usize, &str)>,
        topics: &[Topic],
        ports: &[Port],
        connections: &[Connection],
    ) -> Option<Context> {
        let Some(written) = written else {
            self.error(
                span,
                format!(
                    "missing field `context`: behaviour `{behaviour}` of dynamics group `{group}` needs a context: a connection name, a constant, or {{ topic, value, scale, timeout }}"
                ),
            );
            return None;
        };
        match written.get_ref() {
            RawContext::Constant(value) => {
                if (0.0..=1.0).contains(value) {
                    Some(Context::Constant(*value))
                } else {
                    self.error(
                        written.span(),
                        format!("context = {value}: a constant context is in [0, 1]"),
                    );
                    None
                }
            }
            RawContext::Connection(name) => {
                // An unknown node is reported already.
                let (node, node_name) = node?;
                let found = connections.iter().position(|c| {
                    &c.name == name && ports.get(c.port).is_some_and(|p| p.node == node)
                });
                if found.is_none() {
                    let mut known: Vec<&str> = connections
                        .iter()
                        .filter(|c| ports.get(c.port).is_some_and(|p| p.node == node))
                        .map(|c| c.name.as_str())
                        .collect();
                    known.dedup();
                    self.error(
                        written.span(),
                        format!(
                            "context: `{}` is not a connection on node `{node_name}`, which runs dynamics group `{group}` (its connections: {})",
                            shown::escaped(name),
                            list_or_none(&known)
                        ),
                    );
                }
                found.map(|connection| Context::Connection { connection })
            }
            RawContext::Topic(raw) => {
                let topic = self.topic_index(&raw.topic, topics);
                let field = self.field(&raw.value, "context value");
                let scale = *raw.scale.get_ref();
                let mut ok = true;
                // The boards keep the scale in Q24.8 (a u32: 1/256 to 16 777 215) and the
                // timeout in whole microseconds up to an hour.
                if !(scale.is_finite() && (1.0 / 256.0..=16_777_215.0).contains(&scale)) {
                    self.error(
                        raw.scale.span(),
                        format!(
                            "scale = {scale}: the divisor of the field, from 1/256 (0.00390625) to 16777215"
                        ),
                    );
                    ok = false;
                }
                let timeout = *raw.timeout.get_ref();
                let timeout_us = (timeout * 1e6).round();
                if !(timeout.is_finite()
                    && (1.0..=f64::from(pab_core::dynamics::MAX_TIMEOUT_US)).contains(&timeout_us))
                {
                    self.error(
                        raw.timeout.span(),
                        format!(
                            "timeout = {timeout}: how long a frame's value holds, in seconds, from 0.000001 to 3600"
                        ),
                    );
                    ok = false;
                }
                let (Some(topic), Some(field), true) = (topic, field, ok) else {
                    return None;
                };
                Some(Context::Topic {
                    topic,
                    field,
                    scale,
                    timeout_us: timeout_us as u64,
                })
            }
        }
    }
}

/// `error` in the file's terms: behaviours by name, times by key.
fn explain(error: &ParamsError, names: &[&str], params: &Params) -> String {
    let name = |i: u8| {
        names
            .get(usize::from(i))
            .copied()
            .unwrap_or("?")
            .to_string()
    };
    match error {
        ParamsError::NonPositiveTime(time) => {
            let key = match time {
                Time::Step => "step".to_string(),
                Time::Unit => "unit".to_string(),
                Time::Tau => "tau".to_string(),
                Time::TauRhoFast => "tau_rho_fast".to_string(),
                Time::TauRhoSlow => "tau_rho_slow".to_string(),
                Time::TauN => "tau_n".to_string(),
                Time::Memory(i) => format!("memory of `{}`", name(*i)),
            };
            format!("{key} is 0 µs; every time must be positive")
        }
        ParamsError::StepAboveQuarter => {
            let fastest = [
                params.tau_us,
                params.tau_rho_fast_us,
                params.tau_rho_slow_us,
                params.tau_n_us,
            ]
            .into_iter()
            .chain(params.behaviours.iter().map(|b| b.memory_us))
            .min()
            .unwrap_or(0);
            format!(
                "step {} µs is above a quarter of the fastest time constant ({fastest} µs): Euler's step would be too coarse; lower `step` or raise the time constants",
                params.step_us
            )
        }
        ParamsError::StepUnstable { behaviour } => format!(
            "step · (2 + Σ γ) / tau is above 1 for behaviour `{}` (its γ sum is too large for the step): lower `step` or the γ of its exclusions",
            name(*behaviour)
        ),
        ParamsError::ZeroNoise => {
            "noise rounds to 0: n = 0 would be a fixed point, a decayed behaviour would never start again; use noise ≥ 1e-9".to_string()
        }
        ParamsError::ZeroSeed => "seed = 0: xorshift32 would output only zeros; use 1 or more".to_string(),
        ParamsError::SelfExclusion { behaviour } => {
            format!("behaviour `{}` excludes itself (γ_ii must be 0)", name(*behaviour))
        }
        ParamsError::DuplicateExclusion { behaviour, by } => format!(
            "γ of `{}` by `{}` given twice",
            name(*behaviour),
            name(*by)
        ),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use pab_core::dynamics::{GAMMA_ONE, Params};

    use crate::diagnostic::Source;
    use crate::network::{Context, Network};

    /// Every key of the issue, with non-default values where a mix-up would show.
    const TEXT: &str = r#"
[nodes.base]
id = 1
[topics.cue]
can_id = 0x100
[ports."base.p"]
[connections.C3]
topic = "cue"
port = "base.p"
st = 1.0
tc = 0.1
[dynamics.door]
node = "base"
step = 0.0005
unit = 0.02
noise = 0.002
seed = 7
c = 12.5
tau = 1.5
tau_rho_fast = 2.0
tau_rho_slow = 30.0
tau_n = 1.25
gamma = 2.75
[dynamics.door.behaviours.search]
context = "C3"
memory = 40.0
excludes = ["recognise", "approach"]
gamma = { recognise = 4.0 }
[dynamics.door.behaviours.recognise]
context = { topic = "cue", value = { offset = 2, size = 2, endian = "big" }, scale = 1000.0, timeout = 0.25 }
[dynamics.door.behaviours.approach]
context = 1
requires = ["recognise", "search"]
"#;

    #[test]
    fn every_key_reaches_the_boards_parameters() {
        let network = Network::parse(Source::new("d.toml", TEXT)).unwrap();
        let group = &network.dynamics[0];
        let mut expected = Params::new();
        expected.step_us = 500;
        expected.unit_us = 20_000;
        expected.noise = 8_589_935; // round(0.002 · 2^32)
        expected.seed = 7;
        expected.c = 819_200; // 12.5 · 2^16
        expected.tau_us = 30_000;
        expected.tau_rho_fast_us = 40_000;
        expected.tau_rho_slow_us = 600_000;
        expected.tau_n_us = 25_000;
        assert_eq!(expected.add_behaviour(800_000), Ok(0));
        assert_eq!(expected.add_behaviour(1_000_000), Ok(1));
        assert_eq!(expected.add_behaviour(1_000_000), Ok(2));
        expected.exclude(0, 1, 4 * GAMMA_ONE).unwrap();
        expected.exclude(0, 2, 704).unwrap(); // 2.75 · 256
        expected.require(2, 1).unwrap();
        expected.require(2, 0).unwrap();
        assert_eq!(group.params, expected);
        let names: Vec<&str> = group.behaviours.iter().map(|b| b.name.as_str()).collect();
        assert_eq!(names, ["search", "recognise", "approach"]);
        assert_eq!(
            group.behaviours[0].context,
            Context::Connection { connection: 0 }
        );
        let Context::Topic {
            topic,
            field,
            scale,
            timeout_us,
        } = &group.behaviours[1].context
        else {
            panic!("{:?}", group.behaviours[1].context);
        };
        assert_eq!(
            (*topic, field.offset, field.size, *scale, *timeout_us),
            (0, 2, 2, 1000.0, 250_000)
        );
        assert_eq!(group.behaviours[2].context, Context::Constant(1.0));
    }
}
