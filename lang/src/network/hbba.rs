//! `[hbba]`: the resources, strategies and classes of HBBA's intention solver (docs/hbba.md),
//! checked at their lines, and the [`pab_core::hbba::Instance`] they make.
//!
//! ```toml
//! [hbba]
//! resources = { cpu = 100, bus = 60 }   # named capacities; `bus` is a percentage of `bitrate`
//! bitrate = 500000                      # bit/s, with a `bus` resource only
//!
//! [hbba.strategies.face_full]
//! class = "face"                        # the class of desire it fulfils
//! utility = 2
//! costs = { cpu = 40 }                  # every resource but `bus`, which is computed
//! filters = { C8 = 3 }                  # connection = φ (0 closes, 1 passes all, N one in N)
//! requires = { nav = 1 }                # class = minimum utility of its strategy
//! ```
//!
//! Classes are numbered in order of first appearance among the strategies, strategies in file
//! order: the solver's tie-break uses both. A strategy's **bus cost** is computed from the
//! frames its filters let through: for each connection it sets to φ ≥ 1, its topic's `rate_hz`
//! / φ frames a second of the worst-case length with bit stuffing, 55 + 10·n bits for an 11-bit
//! identifier and 80 + 10·n for a 29-bit one, n the topic's data `length` (8 by default);
//! the sum as a percentage of `bitrate`, rounded up ([`bus_cost`]). On a CAN FD bus (`[bus]
//! data_bitrate`) it is the percentage of the bus's time ([`bus_cost_at`]): a CAN FD topic's
//! frames take their CAN FD time, the data phase at the data rate, classic ones their bits at
//! `bitrate` as above. A strategy whose cost of a resource exceeds that resource's capacity can
//! never be selected, and is refused.

use std::ops::Range;

use super::spanned::Spanned;
use indexmap::IndexMap;
use pab_core::hbba::{
    self, FilterSetting, Instance, Intensities, MAX_CLASSES, MAX_FILTERS, MAX_REQUIRES,
    MAX_RESOURCES, MAX_STRATEGIES, Requirement, Solver, Strategy,
};
use schemars::JsonSchema;
use serde::Deserialize;

use pab_core::hbba::intention::{MAX_FILTERED, Target};

use super::{
    Builder, Bus, Connection, Kind, Network, PLAIN_NAME, Topic, is_plain_name, list_or_none,
};
use crate::shown;

/// The resource whose capacity is a percentage of the bus's bit rate and whose costs are
/// computed from the strategies' filters.
pub const BUS: &str = "bus";
/// The fastest `bitrate`: classic CAN's 1 Mbit/s.
pub const MAX_BITRATE: i64 = 1_000_000;

type RawMap = Spanned<IndexMap<Spanned<String>, Spanned<i64>>>;

/// `[hbba] resources = { ... }, bitrate = N` and `[hbba.strategies.NAME]`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawHbba {
    /// Optional: named capacities, 1 to 8 resources, each a whole number 1..=4294967295; `bus`
    /// is a percentage (1 to 100) of bitrate, and its costs are computed, never written.
    resources: Option<RawMap>,
    /// Bit/s, 1 to 1000000: the older place of `[bus] bitrate`, read in a file without
    /// `[bus]` and with a `bus` resource only (refused with `[bus]`, and without that resource).
    bitrate: Option<Spanned<i64>>,
    /// The strategies (1 to 64, file order), by name: letters, digits, _ -.
    #[serde(default)]
    strategies: IndexMap<Spanned<String>, Spanned<RawStrategy>>,
}

/// `[hbba.strategies.NAME] class, utility, costs, filters, requires`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawStrategy {
    /// Required: the class of desire it fulfils (up to 16 classes).
    #[schemars(required)]
    class: Option<Spanned<String>>,
    /// Required: 0..=65535; choosing it adds intensity × utility.
    #[schemars(required)]
    utility: Option<Spanned<i64>>,
    /// Optional: resource = its cost, 0..=4294967295 (default 0); not `bus`, whose cost is
    /// computed.
    costs: Option<RawMap>,
    /// Optional, up to 8: connection = φ, 0..=255 (0 closes, 1 passes every frame, N one frame
    /// in N).
    filters: Option<RawMap>,
    /// Optional, up to 4: class = the least utility of the strategy chosen for it.
    requires: Option<RawMap>,
}

/// `[[desires]] class, intensity, from, to`: a desire the simulation issues.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDesire {
    /// Required: a class of the strategies.
    class: Spanned<String>,
    /// Required: 1..=65535.
    intensity: Spanned<i64>,
    /// Required: issued at (seconds), refreshed while it lasts.
    from: Spanned<f64>,
    /// Required: withdrawn at (seconds), after `from`.
    to: Spanned<f64>,
}

/// A scripted desire (`[[desires]]`, simulation only): the simulated motivation issues it at
/// `from`, keeps it alive, and withdraws it at `to`.
#[derive(Clone, Debug, PartialEq)]
pub struct ScriptedDesire {
    /// Its class, as an index into [`Hbba::classes`].
    pub class: usize,
    /// Its intensity, 1..=65535.
    pub intensity: u16,
    /// When it is issued, seconds.
    pub from: f64,
    /// When it is withdrawn, seconds (after `from`).
    pub to: f64,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// A resource: a name and a capacity.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Resource {
    /// Its name (`cpu`, `bus`, ...).
    pub name: String,
    /// Its capacity; for [`BUS`], a percentage of the bit rate.
    pub capacity: u32,
}

/// A filter a strategy sets.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StrategyFilter {
    /// The connection, as an index into [`super::Network::connections`] (the first of that name:
    /// an inhibit connection is one per port, all named alike).
    pub connection: usize,
    /// Its name.
    pub name: String,
    /// φ: 0 closes, 1 passes all, N one frame in N.
    pub phi: u16,
}

/// A strategy of `[hbba.strategies.NAME]`.
#[derive(Clone, Debug)]
pub struct HbbaStrategy {
    /// Its name.
    pub name: String,
    /// Its class, as an index into [`Hbba::classes`].
    pub class: usize,
    /// Its utility.
    pub utility: u16,
    /// Its cost of each resource, in the order of [`Hbba::resources`] (the bus's computed).
    pub costs: Vec<u32>,
    /// The filters it sets, in file order.
    pub filters: Vec<StrategyFilter>,
    /// The classes it requires (index into [`Hbba::classes`]) with the least utility of their
    /// strategy, in file order.
    pub requires: Vec<(usize, u16)>,
    /// Where it is defined (its `[hbba.strategies.NAME]` header).
    pub span: Range<usize>,
}

/// The `[hbba]` section, checked.
#[derive(Clone, Debug)]
pub struct Hbba {
    /// The resources, in file order.
    pub resources: Vec<Resource>,
    /// The bus's bit rate, bit/s (with a [`BUS`] resource).
    pub bitrate: Option<u32>,
    /// The classes of desire, in order of first appearance among the strategies.
    pub classes: Vec<String>,
    /// The strategies, in file order.
    pub strategies: Vec<HbbaStrategy>,
}

/// A strategy's bus cost, in percent of `bitrate` (> 0), rounded up: its filtered frames are
/// `(rate in µHz, φ, extended, data length)` per connection; each φ ≥ 1 lets through rate / φ
/// frames a second of 55 + 10·n bits (11-bit identifier, n data bytes) or 80 + 10·n (29-bit), the
/// frame's length with worst-case bit stuffing: 47 + 8n + ⌊(34 + 8n − 1)/4⌋ and
/// 67 + 8n + ⌊(54 + 8n − 1)/4⌋ bits, which are exactly those. Each connection's bit rate is
/// rounded up to a whole µbit/s, then the sum to a whole percent, so the cost is never below the
/// exact one. φ = 0 (closed) costs nothing. A classic bus's frames: [`bus_cost_at`] for CAN FD.
pub fn bus_cost(frames: &[(u64, u16, bool, u8)], bitrate: u32) -> u64 {
    let classic: Vec<(u64, u16, bool, u8, bool)> = frames
        .iter()
        .map(|&(rate, phi, extended, length)| (rate, phi, extended, length, false))
        .collect();
    bus_cost_at(&classic, bitrate, None)
}

/// A strategy's bus cost on a bus at `bitrate` and, for CAN FD, `data_bitrate`, in percent of
/// the bus's time (> 0), rounded up: its filtered frames are `(rate in µHz, φ, extended, data
/// length, CAN FD)` per connection, each φ ≥ 1 letting through rate / φ frames a second, each
/// frame taking its transmission time with worst-case stuffing
/// ([`TimeBase::frame`](crate::can_frame::TimeBase::frame): a CAN FD frame's data phase at the
/// data rate). On a classic bus that is [`bus_cost`]'s percentage of the bit rate, exactly.
/// Each connection's share is rounded up to a whole µunit of time a second, then the sum to a
/// whole percent: never below the exact cost.
pub fn bus_cost_at(
    frames: &[(u64, u16, bool, u8, bool)],
    bitrate: u32,
    data_bitrate: Option<u32>,
) -> u64 {
    let base = crate::can_frame::TimeBase::new(bitrate, data_bitrate);
    let micro_units: u128 = frames
        .iter()
        .filter(|&&(_, phi, _, _, _)| phi != 0)
        .map(|&(rate_uhz, phi, extended, length, fd)| {
            let units = base.frame(fd, length, extended);
            (u128::from(rate_uhz) * u128::from(units)).div_ceil(u128::from(phi))
        })
        .sum();
    let percent = (micro_units * 100).div_ceil(u128::from(base.per_second.max(1)) * 1_000_000);
    u64::try_from(percent).unwrap_or(u64::MAX)
}

impl Hbba {
    /// The solver's instance: classes, capacities and strategies in order, each filter's
    /// connection by its index in the network. Valid by construction (the parser checked every
    /// count and name).
    pub fn instance(&self) -> Instance {
        let mut instance = Instance {
            classes: u8::try_from(self.classes.len()).unwrap_or(u8::MAX),
            ..Instance::default()
        };
        for resource in &self.resources {
            let _ = instance.capacities.push(resource.capacity);
        }
        for s in &self.strategies {
            let mut strategy = Strategy::new(u8::try_from(s.class).unwrap_or(u8::MAX), s.utility);
            for (slot, &cost) in strategy.costs.iter_mut().zip(&s.costs) {
                *slot = cost;
            }
            for filter in &s.filters {
                let _ = strategy.filters.push(FilterSetting {
                    connection: u16::try_from(filter.connection).unwrap_or(u16::MAX),
                    phi: filter.phi,
                });
            }
            for &(class, min_utility) in &s.requires {
                let _ = strategy.requires.push(Requirement {
                    class: u8::try_from(class).unwrap_or(u8::MAX),
                    min_utility,
                });
            }
            let _ = instance.strategies.push(strategy);
        }
        instance
    }

    /// The intensities of `--desires "class=intensity,..."`: each a class of the strategies, at
    /// most once, with an intensity in 1..=65535; an empty text is no desire. `Err` says what is
    /// wrong.
    pub fn intensities(&self, text: &str) -> Result<Intensities, String> {
        let mut intensities = [0u16; MAX_CLASSES];
        let known = || {
            let names: Vec<&str> = self.classes.iter().map(String::as_str).collect();
            list_or_none(&names)
        };
        for item in text
            .split(',')
            .map(str::trim)
            .filter(|item| !item.is_empty())
        {
            let Some((class, intensity)) = item.split_once('=') else {
                return Err(format!(
                    "`{}` is not CLASS=INTENSITY (e.g. \"face=2,voice=5\")",
                    shown::escaped(item)
                ));
            };
            let (class, intensity) = (class.trim(), intensity.trim());
            let Some(index) = self.classes.iter().position(|c| c == class) else {
                return Err(format!(
                    "no strategy has class `{}` (classes: {})",
                    shown::escaped(class),
                    known()
                ));
            };
            let value = match intensity.parse::<u64>() {
                Ok(0) => {
                    return Err(format!(
                        "`{class}=0`: an intensity is 1 to 65535 (leave a class out for no desire)"
                    ));
                }
                Ok(value) if value <= u64::from(u16::MAX) => value as u16,
                _ => {
                    return Err(format!(
                        "`{}`: an intensity is a whole number, 1 to 65535",
                        shown::escaped(item)
                    ));
                }
            };
            let Some(slot) = intensities.get_mut(index) else {
                return Err(format!("class `{class}` is past the solver's capacity"));
            };
            if *slot != 0 {
                return Err(format!(
                    "class `{class}` has two desires: give it one intensity"
                ));
            }
            *slot = value;
        }
        Ok(intensities)
    }

    /// The resource named [`BUS`], if any, as an index into [`Hbba::resources`].
    pub fn bus(&self) -> Option<usize> {
        self.resources.iter().position(|r| r.name == BUS)
    }
}

impl Builder<'_> {
    /// The `[hbba]` section, if any; `None` also after reporting its mistakes (every one).
    /// With the bus `[bus]` gave: the bus, from `[hbba] bitrate` in a file without `[bus]`.
    pub(super) fn hbba(
        &mut self,
        raw: Option<&Spanned<RawHbba>>,
        bus: Option<Bus>,
        topics: &[Topic],
        connections: &[Connection],
        connection_names: &[&str],
    ) -> (Option<Hbba>, Option<Bus>) {
        let Some(raw) = raw else {
            return (None, bus);
        };
        let (bitrate, bus) = self.hbba_bitrate(raw.get_ref(), raw.span(), bus);
        let hbba = self.hbba_section(raw, bitrate, topics, connections, connection_names);
        (hbba, bus)
    }

    fn hbba_section(
        &mut self,
        raw: &Spanned<RawHbba>,
        bitrate: Option<u32>,
        topics: &[Topic],
        connections: &[Connection],
        connection_names: &[&str],
    ) -> Option<Hbba> {
        let errors = self.errors.len();
        let section = raw.get_ref();
        let resources = self.hbba_resources(section);
        // Classes first: a requirement may name a class that appears further down.
        let mut classes: Vec<String> = Vec::new();
        let mut refused: Vec<&str> = Vec::new();
        for (name, strategy) in &section.strategies {
            let Some(class) = &strategy.get_ref().class else {
                continue;
            };
            let text = class.get_ref();
            if !classes.contains(text)
                && !refused.contains(&text.as_str())
                && self.printable(class, "class name")
                && self.plain(class, "class name")
            {
                if classes.len() == MAX_CLASSES {
                    refused.push(text);
                    self.error(
                        class.span(),
                        format!(
                            "strategy `{}`: class `{text}` is a {}th class; the intention solver takes at most {MAX_CLASSES}",
                            name.get_ref(),
                            MAX_CLASSES + 1
                        ),
                    );
                    continue;
                }
                classes.push(text.clone());
            }
        }
        let mut strategies = Vec::new();
        for (position, (name, strategy)) in section.strategies.iter().enumerate() {
            if position == MAX_STRATEGIES {
                self.error(
                    name.span(),
                    format!(
                        "strategy `{}` is the {}th: the intention solver takes at most {MAX_STRATEGIES}",
                        name.get_ref(),
                        MAX_STRATEGIES + 1
                    ),
                );
                break;
            }
            if let Some(strategy) = self.hbba_strategy(
                name,
                strategy.get_ref(),
                &classes,
                &resources,
                bitrate,
                (topics, connections, connection_names),
            ) {
                strategies.push(strategy);
            }
        }
        if self.errors.len() > errors {
            return None;
        }
        let hbba = Hbba {
            resources,
            bitrate,
            classes,
            strategies,
        };
        // Everything the solver checks was checked above, at its line; this is a safety net.
        if let Err(error) = Solver::new(&hbba.instance()) {
            self.error(raw.span(), format!("[hbba]: {error}"));
            return None;
        }
        Some(hbba)
    }

    /// The `[[desires]]`, each checked at its line: a class of the strategies, an intensity in
    /// 1..=65535, times within the simulation's range, `from` before `to`; at most
    /// [`hbba::MAX_DESIRES`] of them (the intention workspace's capacity). `hbba` is the
    /// checked section; `has_section` whether the file has one (if it does and `hbba` is `None`,
    /// its errors are reported already and the classes are not checked).
    pub(super) fn desires(
        &mut self,
        raw: &[Spanned<RawDesire>],
        hbba: Option<&Hbba>,
        has_section: bool,
    ) -> Vec<ScriptedDesire> {
        let mut desires = Vec::new();
        for (position, desire) in raw.iter().enumerate() {
            let fields = desire.get_ref();
            if position == hbba::MAX_DESIRES {
                self.error(
                    desire.span(),
                    format!(
                        "more than {0} [[desires]]: the intention workspace holds at most {0} desires",
                        hbba::MAX_DESIRES
                    ),
                );
                break;
            }
            let class = match hbba {
                Some(hbba) => {
                    let index = hbba
                        .classes
                        .iter()
                        .position(|c| c == fields.class.get_ref());
                    if index.is_none() {
                        let names: Vec<&str> = hbba.classes.iter().map(String::as_str).collect();
                        self.error(
                            fields.class.span(),
                            format!(
                                "desire for class `{}`, which no strategy has (classes: {})",
                                shown::escaped(fields.class.get_ref()),
                                list_or_none(&names)
                            ),
                        );
                    }
                    index
                }
                None => {
                    if !has_section {
                        self.error(
                            desire.span(),
                            "[[desires]] are for HBBA's intention solver: the file has no [hbba] section (its resources and strategies)",
                        );
                    }
                    None
                }
            };
            let value = *fields.intensity.get_ref();
            let intensity = match u16::try_from(value) {
                Ok(intensity) if intensity >= 1 => Some(intensity),
                _ => {
                    self.error(
                        fields.intensity.span(),
                        format!(
                            "intensity = {value}: a whole number, 1 to 65535 (a desire of intensity 0 is no desire)"
                        ),
                    );
                    None
                }
            };
            let (Some(from), Some(to)) =
                (self.time(&fields.from, "from"), self.time(&fields.to, "to"))
            else {
                continue;
            };
            if to <= from {
                self.error(
                    fields.to.span(),
                    format!("`to` ({to}) must be after `from` ({from})"),
                );
                continue;
            }
            if let (Some(class), Some(intensity)) = (class, intensity) {
                desires.push(ScriptedDesire {
                    class,
                    intensity,
                    from,
                    to,
                    span: desire.span(),
                });
            }
        }
        desires
    }

    fn plain(&mut self, name: &Spanned<String>, what: &str) -> bool {
        if is_plain_name(name.get_ref()) {
            return true;
        }
        self.error(
            name.span(),
            format!("{what} `{}`: {PLAIN_NAME}", name.get_ref()),
        );
        false
    }

    fn hbba_resources(&mut self, raw: &RawHbba) -> Vec<Resource> {
        let Some(map) = &raw.resources else {
            return Vec::new();
        };
        let mut resources = Vec::new();
        if map.get_ref().len() > MAX_RESOURCES {
            self.error(
                map.span(),
                format!(
                    "{} resources: the intention solver takes at most {MAX_RESOURCES}",
                    map.get_ref().len()
                ),
            );
            return resources;
        }
        for (name, capacity) in map.get_ref() {
            if !self.printable(name, "resource name") || !self.plain(name, "resource name") {
                continue;
            }
            let value = *capacity.get_ref();
            let (max, what) = if name.get_ref() == BUS {
                (
                    100,
                    "the bus's capacity is a percentage of `bitrate`, 1 to 100",
                )
            } else {
                (
                    i64::from(u32::MAX),
                    "a capacity is a whole number, 1 to 4294967295",
                )
            };
            match u32::try_from(value) {
                Ok(capacity) if capacity >= 1 && i64::from(capacity) <= max => {
                    resources.push(Resource {
                        name: name.get_ref().clone(),
                        capacity,
                    })
                }
                _ => self.error(
                    capacity.span(),
                    format!("resource `{}` = {value}: {what}", name.get_ref()),
                ),
            }
        }
        resources
    }

    /// The bit rate the `bus` resource is a percentage of (`None` without one), and the bus:
    /// `[bus]`'s, or `[hbba] bitrate` (the older place of the same number) in a file without
    /// `[bus]`.
    fn hbba_bitrate(
        &mut self,
        raw: &RawHbba,
        span: Range<usize>,
        bus: Option<Bus>,
    ) -> (Option<u32>, Option<Bus>) {
        let has_bus = raw
            .resources
            .as_ref()
            .is_some_and(|map| map.get_ref().keys().any(|name| name.get_ref() == BUS));
        match (&raw.bitrate, bus, has_bus) {
            (Some(bitrate), Some(bus), _) => {
                self.error(
                    bitrate.span(),
                    "the bus's bit rate is `[bus] bitrate` (one number for one bus): remove `bitrate` from [hbba]",
                );
                (None, Some(bus))
            }
            (Some(bitrate), None, false) => {
                self.error(
                    bitrate.span(),
                    "`bitrate` goes with a `bus` resource (its capacity in percent of it): add `bus = PERCENT` to `resources`, or write the bus's bit rate as `[bus] bitrate`",
                );
                (None, None)
            }
            (Some(bitrate), None, true) => {
                let bus = self.bitrate(bitrate);
                (bus.as_ref().map(|bus| bus.bitrate), bus)
            }
            (None, Some(bus), has_bus) => (has_bus.then_some(bus.bitrate), Some(bus)),
            (None, None, true) => {
                let at = raw.resources.as_ref().map_or(span, Spanned::span);
                self.error(
                    at,
                    "the `bus` resource is a percentage of the bus's bit rate: add `bitrate = 500000` (bit/s) to [bus]",
                );
                (None, None)
            }
            (None, None, false) => (None, None),
        }
    }

    /// One strategy, or `None` after reporting its mistakes.
    fn hbba_strategy(
        &mut self,
        name: &Spanned<String>,
        raw: &RawStrategy,
        classes: &[String],
        resources: &[Resource],
        bitrate: Option<u32>,
        (topics, connections, connection_names): (&[Topic], &[Connection], &[&str]),
    ) -> Option<HbbaStrategy> {
        let errors = self.errors.len();
        let text = name.get_ref();
        if self.printable(name, "strategy name") {
            self.plain(name, "strategy name");
        }
        let class = match &raw.class {
            None => {
                self.error(
                    name.span(),
                    format!(
                        "strategy `{text}`: missing field `class`: the class of desire it fulfils, e.g. class = \"face\""
                    ),
                );
                None
            }
            Some(class) => classes.iter().position(|c| c == class.get_ref()),
        };
        let utility = match &raw.utility {
            None => {
                self.error(
                    name.span(),
                    format!(
                        "strategy `{text}`: missing field `utility`: what choosing it is worth per unit of its desire's intensity, 0 to 65535"
                    ),
                );
                None
            }
            Some(utility) => match u16::try_from(*utility.get_ref()) {
                Ok(value) => Some(value),
                Err(_) => {
                    self.error(
                        utility.span(),
                        format!(
                            "utility = {}: a whole number, 0 to 65535",
                            utility.get_ref()
                        ),
                    );
                    None
                }
            },
        };
        let mut costs = vec![0u32; resources.len()];
        if let Some(map) = &raw.costs {
            for (resource, cost) in map.get_ref() {
                let Some(index) = resources.iter().position(|r| &r.name == resource.get_ref())
                else {
                    let names: Vec<&str> = resources.iter().map(|r| r.name.as_str()).collect();
                    self.error(
                        resource.span(),
                        format!(
                            "strategy `{text}` costs `{}`, which is not a resource of [hbba] (resources: {})",
                            shown::escaped(resource.get_ref()),
                            list_or_none(&names)
                        ),
                    );
                    continue;
                };
                if resource.get_ref() == BUS {
                    self.error(
                        resource.span(),
                        format!(
                            "strategy `{text}`: the bus cost is computed from the rates its filters let through (its connections' topics' rate_hz / φ): remove `bus` from `costs`"
                        ),
                    );
                    continue;
                }
                match u32::try_from(*cost.get_ref()) {
                    Ok(value) => {
                        if let Some(slot) = costs.get_mut(index) {
                            *slot = value;
                        }
                    }
                    Err(_) => self.error(
                        cost.span(),
                        format!(
                            "cost {} of `{}`: a whole number, 0 to 4294967295",
                            cost.get_ref(),
                            resource.get_ref()
                        ),
                    ),
                }
            }
        }
        let mut filters: Vec<StrategyFilter> = Vec::new();
        let mut frames: Vec<(u64, u16, bool, u8, bool)> = Vec::new();
        if let Some(map) = &raw.filters {
            if map.get_ref().len() > MAX_FILTERS {
                self.error(
                    map.span(),
                    format!(
                        "strategy `{text}` sets {} filters: the intention solver takes at most {MAX_FILTERS} per strategy",
                        map.get_ref().len()
                    ),
                );
            }
            for (connection, phi) in map.get_ref().iter().take(MAX_FILTERS) {
                let wanted = connection.get_ref();
                if !connection_names.contains(&wanted.as_str()) {
                    self.error(
                        connection.span(),
                        format!(
                            "strategy `{text}` filters `{}`, which is not a connection (connections: {})",
                            shown::escaped(wanted),
                            list_or_none(connection_names)
                        ),
                    );
                    continue;
                }
                // The boards count a filter's frames in one byte, as FilterSet carries φ.
                let Ok(phi_value) = u8::try_from(*phi.get_ref()).map(u16::from) else {
                    self.error(
                        phi.span(),
                        format!(
                            "φ = {} for `{wanted}`: 0 closes, 1 passes every frame, N one frame in N (up to 255, the boards' filters count in one byte)",
                            phi.get_ref()
                        ),
                    );
                    continue;
                };
                // A connection that failed its own checks is not there: its error is reported.
                let Some(index) = connections
                    .iter()
                    .position(|c| &c.name == wanted && !matches!(c.kind, Kind::Claim | Kind::Gate))
                else {
                    continue;
                };
                if bitrate.is_some() && phi_value != 0 {
                    let topic = connections.get(index).and_then(|c| topics.get(c.topic));
                    match topic {
                        Some(topic) => match topic.rate_uhz {
                            Some(rate) => frames.push((
                                rate,
                                phi_value,
                                topic.filter.is_extended(),
                                topic.length,
                                topic.fd,
                            )),
                            None => self.error(
                                connection.span(),
                                format!(
                                    "strategy `{text}` lets frames of `{wanted}` through, but its topic `{}` has no `rate_hz`: the bus cost is computed from it (add rate_hz = FRAMES_PER_SECOND, or period = SECONDS, to [topics.{}])",
                                    topic.name, topic.name
                                ),
                            ),
                        },
                        None => continue,
                    }
                }
                filters.push(StrategyFilter {
                    connection: index,
                    name: wanted.clone(),
                    phi: phi_value,
                });
            }
        }
        let mut requires: Vec<(usize, u16)> = Vec::new();
        if let Some(map) = &raw.requires {
            if map.get_ref().len() > MAX_REQUIRES {
                self.error(
                    map.span(),
                    format!(
                        "strategy `{text}` requires {} classes: the intention solver takes at most {MAX_REQUIRES} per strategy",
                        map.get_ref().len()
                    ),
                );
            }
            for (required, minimum) in map.get_ref().iter().take(MAX_REQUIRES) {
                let Some(index) = classes.iter().position(|c| c == required.get_ref()) else {
                    let names: Vec<&str> = classes.iter().map(String::as_str).collect();
                    self.error(
                        required.span(),
                        format!(
                            "strategy `{text}` requires class `{}`, which no strategy has (classes: {})",
                            shown::escaped(required.get_ref()),
                            list_or_none(&names)
                        ),
                    );
                    continue;
                };
                if Some(index) == class {
                    self.error(
                        required.span(),
                        format!(
                            "strategy `{text}` requires its own class `{}`: the strategy of that class is itself",
                            required.get_ref()
                        ),
                    );
                    continue;
                }
                match u16::try_from(*minimum.get_ref()) {
                    Ok(value) => requires.push((index, value)),
                    Err(_) => self.error(
                        minimum.span(),
                        format!(
                            "minimum utility {} for class `{}`: a whole number, 0 to 65535",
                            minimum.get_ref(),
                            required.get_ref()
                        ),
                    ),
                }
            }
        }
        if let (Some(bus), Some(bitrate)) = (resources.iter().position(|r| r.name == BUS), bitrate)
        {
            let cost = bus_cost_at(&frames, bitrate, self.data_bitrate);
            if let Some(slot) = costs.get_mut(bus) {
                *slot = u32::try_from(cost).unwrap_or(u32::MAX);
            }
        }
        for (resource, &cost) in resources.iter().zip(&costs) {
            if cost > resource.capacity {
                let how = if resource.name == BUS {
                    let data = self
                        .data_bitrate
                        .map_or(String::new(), |rate| format!(" (data phase {rate} bit/s)"));
                    format!(
                        "its filters let through {cost} % of {} bit/s{data} on the bus, above the bus's capacity of {} %",
                        bitrate.unwrap_or(0),
                        resource.capacity
                    )
                } else {
                    format!(
                        "it costs {cost} of `{}`, above its capacity of {}",
                        resource.name, resource.capacity
                    )
                };
                self.error(
                    name.span(),
                    format!("strategy `{text}` can never be selected: {how}"),
                );
            }
        }
        if self.errors.len() > errors {
            return None;
        }
        Some(HbbaStrategy {
            name: text.clone(),
            class: class?,
            utility: utility?,
            costs,
            filters,
            requires,
            span: name.span(),
        })
    }
}

impl Network {
    /// Where each connection the `[hbba]` strategies filter is, in the order of first
    /// appearance among them: its node id, its port in the node's order (the table's) and its
    /// index in the port: what FilterSet addresses (`pab-intent` and `pabctl sim` use it). Empty
    /// without `[hbba]`. `Err` says which connection cannot be addressed (more than
    /// [`MAX_FILTERED`], or beyond a byte's port or index: the parser's limits keep them within).
    pub fn filter_targets(&self) -> Result<Vec<Target>, String> {
        let Some(hbba) = &self.hbba else {
            return Ok(Vec::new());
        };
        let mut targets: Vec<Target> = Vec::new();
        for filter in hbba.strategies.iter().flat_map(|s| &s.filters) {
            if targets
                .iter()
                .any(|t| usize::from(t.connection) == filter.connection)
            {
                continue;
            }
            let located = self.connections.get(filter.connection).and_then(|c| {
                let port = self.ports.get(c.port)?;
                let node = self.nodes.get(port.node)?;
                let port_order = node.ports.iter().position(|&p| p == c.port)?;
                Some(Target {
                    connection: u16::try_from(filter.connection).ok()?,
                    node: node.id,
                    port: u8::try_from(port_order).ok()?,
                    index: u8::try_from(c.index).ok()?,
                })
            });
            let Some(target) = located else {
                return Err(format!(
                    "connection `{}` has no node and port to filter it on",
                    filter.name
                ));
            };
            targets.push(target);
        }
        if targets.len() > MAX_FILTERED {
            return Err(format!(
                "the strategies filter {} connections: the intention workspace takes at most {MAX_FILTERED}",
                targets.len()
            ));
        }
        Ok(targets)
    }
}

/// The solver's answer, with names: what `pabctl solve` prints.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Solved {
    /// The chosen strategies' indices into [`Hbba::strategies`], in file order.
    pub strategies: Vec<usize>,
    /// Σ intensity × utility over the classes with a desire.
    pub objective: u64,
    /// Each resource's use, in the order of [`Hbba::resources`].
    pub usage: Vec<u64>,
    /// Search nodes visited.
    pub visits: u32,
}

impl Hbba {
    /// Solves for `intensities` within `budget` search nodes ([`hbba::DEFAULT_BUDGET`]).
    pub fn solve(&self, intensities: &Intensities, budget: u32) -> Result<Solved, hbba::HbbaError> {
        let instance = self.instance();
        let selection = hbba::solve(&instance, intensities, budget)?;
        Ok(Solved {
            strategies: selection.strategies().collect(),
            objective: selection.objective(),
            usage: selection.usage().to_vec(),
            visits: selection.visits(),
        })
    }
}
