//! The competitive-dynamics part of a node's table: the groups the node runs, where their
//! contexts come from, and where gates (its own groups' and other nodes') are rule variables.
//!
//! A gate is a rule variable the way a BLE claim is: a connection of the port with
//! [`GATE_SLOT_FILTER`] (no frame feeds it), whose activity is the gate. [`GateSource`] names a
//! group whose gates the node reads (its own, or another node's through [`crate::protocol::Gates`]
//! frames), [`GateLink`] ties one behaviour's gate to one such connection.
//!
//! Capacities: [`MAX_DYNAMICS_GROUPS`] groups run by a node, [`MAX_GATE_SOURCES`] groups read,
//! [`MAX_GATE_LINKS`] gate connections. Memory in the table: about 1.4 KiB per group run (its
//! [`Params`], most of it the room for 256 exclusions) and 6 bytes per link.

use heapless::Vec;
use serde::{Deserialize, Serialize};

use super::{MAX_BEHAVIOURS, ONE, Params, ParamsError};
use crate::filter::{Filter, FilterError};
use crate::value_port::{Field, FieldError};

/// Groups a node runs, at most.
pub const MAX_DYNAMICS_GROUPS: usize = 2;
/// Groups whose gates a node reads (its own included), at most.
pub const MAX_GATE_SOURCES: usize = 4;
/// Gate connections in a table, at most.
pub const MAX_GATE_LINKS: usize = 32;

// A table's room for the three lists: none without the `dynamics` feature (the lists must then
// be empty, and a board keeps no RAM for them).
pub(crate) const TABLE_GROUPS: usize = if cfg!(feature = "dynamics") {
    MAX_DYNAMICS_GROUPS
} else {
    0
};
pub(crate) const TABLE_SOURCES: usize = if cfg!(feature = "dynamics") {
    MAX_GATE_SOURCES
} else {
    0
};
pub(crate) const TABLE_LINKS: usize = if cfg!(feature = "dynamics") {
    MAX_GATE_LINKS
} else {
    0
};
/// The longest topic-context timeout: an hour, in µs.
pub const MAX_TIMEOUT_US: u32 = 3_600_000_000;

/// The source of the node "itself" in a [`GateSource`]: node ids are 1..=127, and the tool (0)
/// runs no group.
pub const OWN: u8 = 0;

/// The filter of a gate connection: the identifiers of the Gates service, which nodes never
/// arbitrate (frames of ours are protocol traffic), so no frame ever feeds it; the loader requires
/// it on every gate connection, so that no topic can.
pub const GATE_SLOT_FILTER: Filter = match Filter::new(
    0b10 << 24 | (crate::protocol::Service::Gates as u32) << 16,
    0b11 << 24 | 0xFF << 16,
    true,
) {
    Ok(filter) => filter,
    Err(_) => panic!("the gate filter is valid"),
};

/// Where behaviour i's context C_i comes from, sampled at every step's instant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Context {
    /// A constant, Q2.29 in [0, [`ONE`]].
    Constant(u32),
    /// The activity of a connection of the node: 1 while active, else 0.
    Connection {
        /// Its port.
        port: u8,
        /// Its index in the port.
        connection: u8,
    },
    /// The field of the last frame on a topic, divided by `scale` and clamped into [0, 1]; 0
    /// before any frame and once `timeout_us` has passed since the last one (a frame that is
    /// too short for the field counts as a reading of 0).
    Topic {
        /// The topic's frames.
        filter: Filter,
        /// Where the value is.
        field: Field,
        /// The value that reads as 1, in Q24.8 (`scale` · 256, rounded), at least 1.
        scale: u32,
        /// How long a reading holds, µs, 1..=[`MAX_TIMEOUT_US`].
        timeout_us: u32,
    },
}

impl Context {
    /// The context a topic value reads as: value / scale in Q2.29, clamped into [0, [`ONE`]],
    /// rounded down. One 64-bit division, once per frame (not per step).
    // Out of line: inlined into `GroupRun::on_frame`, it took 12 bytes more of the
    // NUCLEO-G474RE's flash.
    #[inline(never)]
    pub fn of_value(value: i64, scale_q8: u32) -> i32 {
        if value <= 0 || scale_q8 == 0 {
            return 0;
        }
        // value · 256 ≥ scale: saturated. Below it, value < 2^24, so value · 2^37 < 2^61.
        let Ok(value) = u64::try_from(value) else {
            return 0;
        };
        if value.saturating_mul(256) >= u64::from(scale_q8) {
            return ONE;
        }
        let context = (value << 37) / u64::from(scale_q8);
        i32::try_from(context).unwrap_or(ONE).min(ONE)
    }
}

/// A group the node runs: its number in the network, its parameters and a context per behaviour.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GroupSpec {
    /// The group's number in the network (byte 0 of its [`crate::protocol::Gates`] frames).
    pub number: u8,
    /// The equations' parameters.
    pub params: Params,
    /// C_i, one per behaviour, in the behaviours' order.
    pub contexts: Vec<Context, MAX_BEHAVIOURS>,
}

/// A group whose gates the node reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GateSource {
    /// The node that runs it, or [`OWN`] for one of the node's own [`GroupSpec`]s.
    pub owner: u8,
    /// Its number in the network.
    pub group: u8,
    /// How many behaviours it has: gate frames with another count are refused.
    pub behaviours: u8,
}

/// A gate as a rule variable: behaviour `behaviour` of source `source` is connection `connection`
/// of port `port`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GateLink {
    /// An index into the table's [`GateSource`]s.
    pub source: u8,
    /// The behaviour, below the source's count.
    pub behaviour: u8,
    /// The port.
    pub port: u8,
    /// The connection of the port whose activity is the gate.
    pub connection: u8,
}

/// Why the dynamics part of a table was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum DynamicsError {
    /// More groups than [`MAX_DYNAMICS_GROUPS`], sources than [`MAX_GATE_SOURCES`] or links
    /// than [`MAX_GATE_LINKS`].
    TooMany,
    /// Group `group` (its position in the table): invalid parameters.
    Params {
        /// The group's position.
        group: u8,
        /// Why.
        error: ParamsError,
    },
    /// Group `group` has not one context per behaviour.
    ContextCount {
        /// The group's position.
        group: u8,
    },
    /// A constant above 1, a connection the table does not have, a scale of 0 or a timeout of
    /// 0 or above [`MAX_TIMEOUT_US`].
    Context {
        /// The group's position.
        group: u8,
        /// The behaviour.
        behaviour: u8,
    },
    /// A topic context's filter.
    ContextFilter {
        /// The group's position.
        group: u8,
        /// The behaviour.
        behaviour: u8,
        /// Why.
        error: FilterError,
    },
    /// A topic context's field.
    ContextField {
        /// The group's position.
        group: u8,
        /// The behaviour.
        behaviour: u8,
        /// Why.
        error: FieldError,
    },
    /// Two groups run, or two sources read, under one number.
    DuplicateGroup {
        /// The number.
        number: u8,
    },
    /// Source `source`: an owner above 127 or the image's own node id (its own groups are
    /// [`OWN`]), a count of 0 or above 32, or [`OWN`] with no group run under its number and
    /// count.
    Source {
        /// The source's position.
        source: u8,
    },
    /// Link `link`: a source, port or connection the table does not have, a behaviour at or
    /// beyond the source's count, a connection without [`GATE_SLOT_FILTER`], or a connection
    /// linked twice.
    Link {
        /// The link's position.
        link: u8,
    },
}

impl core::fmt::Display for DynamicsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DynamicsError::TooMany => write!(
                f,
                "more than {MAX_DYNAMICS_GROUPS} dynamics groups, {MAX_GATE_SOURCES} gate \
                 sources or {MAX_GATE_LINKS} gate connections"
            ),
            DynamicsError::Params { group, error } => {
                write!(f, "dynamics group {group}: {error}")
            }
            DynamicsError::ContextCount { group } => {
                write!(f, "dynamics group {group}: not one context per behaviour")
            }
            DynamicsError::Context { group, behaviour } => write!(
                f,
                "dynamics group {group}, behaviour {behaviour}: context out of range"
            ),
            DynamicsError::ContextFilter {
                group,
                behaviour,
                error,
            } => write!(
                f,
                "dynamics group {group}, behaviour {behaviour}: context topic: {error}"
            ),
            DynamicsError::ContextField {
                group,
                behaviour,
                error,
            } => write!(
                f,
                "dynamics group {group}, behaviour {behaviour}: context field: {error}"
            ),
            DynamicsError::DuplicateGroup { number } => {
                write!(f, "dynamics group number {number} given twice")
            }
            DynamicsError::Source { source } => write!(f, "gate source {source} is invalid"),
            DynamicsError::Link { link } => write!(f, "gate connection {link} is invalid"),
        }
    }
}

impl core::error::Error for DynamicsError {}

#[cfg(feature = "dynamics")]
/// The dynamics part of a table, checked as a whole: `filter(port, connection)` is a
/// connection's filter (`None` for a connection the table does not have). `node` is the image's
/// node id when an image is loaded (0 when a table is built). One copy for every table type (it
/// takes slices and a `dyn` look-up); the loader runs it once per table. Left to the inliner: a
/// board has one table type, so one caller, into which it inlines (52 bytes of the
/// NUCLEO-G474RE's flash less than out of line).
pub(crate) fn validate(
    groups: &[GroupSpec],
    sources: &[GateSource],
    links: &[GateLink],
    node: u8,
    filter: &dyn Fn(u8, u8) -> Option<Filter>,
) -> Result<(), DynamicsError> {
    for (position, group) in groups.iter().enumerate() {
        let g = position as u8;
        group
            .params
            .validate()
            .map_err(|error| DynamicsError::Params { group: g, error })?;
        if group.contexts.len() != group.params.behaviours.len() {
            return Err(DynamicsError::ContextCount { group: g });
        }
        for (b, context) in group.contexts.iter().enumerate() {
            validate_context(context, g, b as u8, filter)?;
        }
        // Over a sub-slice: `take(position)` cost a board a counter in each of the three loops.
        if groups
            .get(..position)
            .is_some_and(|before| before.iter().any(|o| o.number == group.number))
        {
            return Err(DynamicsError::DuplicateGroup {
                number: group.number,
            });
        }
    }
    for (position, source) in sources.iter().enumerate() {
        let error = DynamicsError::Source {
            source: position as u8,
        };
        let count_ok = (1..=MAX_BEHAVIOURS).contains(&usize::from(source.behaviours));
        // The group run under the source's number: at most one, the numbers were checked above.
        let run = groups.iter().find(|g| g.number == source.group);
        let owner_ok = if source.owner == OWN {
            run.is_some_and(|g| g.params.behaviours.len() == usize::from(source.behaviours))
        } else {
            source.owner <= crate::protocol::MAX_NODE_ID && source.owner != node
        };
        if !count_ok || !owner_ok {
            return Err(error);
        }
        // Group numbers are the network's: one number, one group, whoever runs it.
        let clash = sources
            .get(..position)
            .is_some_and(|before| before.iter().any(|o| o.group == source.group))
            || (source.owner != OWN && run.is_some());
        if clash {
            return Err(DynamicsError::DuplicateGroup {
                number: source.group,
            });
        }
    }
    for (position, link) in links.iter().enumerate() {
        let error = DynamicsError::Link {
            link: position as u8,
        };
        let behaviour_ok = sources
            .get(usize::from(link.source))
            .is_some_and(|s| link.behaviour < s.behaviours);
        if !behaviour_ok || filter(link.port, link.connection) != Some(GATE_SLOT_FILTER) {
            return Err(error);
        }
        if links.get(..position).is_some_and(|before| {
            before
                .iter()
                .any(|o| o.port == link.port && o.connection == link.connection)
        }) {
            return Err(error);
        }
    }
    Ok(())
}

#[cfg(feature = "dynamics")]
fn validate_context(
    context: &Context,
    group: u8,
    behaviour: u8,
    filter: &dyn Fn(u8, u8) -> Option<Filter>,
) -> Result<(), DynamicsError> {
    let error = DynamicsError::Context { group, behaviour };
    match *context {
        Context::Constant(value) => {
            if value > ONE as u32 {
                return Err(error);
            }
        }
        Context::Connection { port, connection } => {
            if filter(port, connection).is_none() {
                return Err(error);
            }
        }
        Context::Topic {
            filter,
            field,
            scale,
            timeout_us,
        } => {
            filter
                .validate()
                .map_err(|error| DynamicsError::ContextFilter {
                    group,
                    behaviour,
                    error,
                })?;
            field
                .validate()
                .map_err(|error| DynamicsError::ContextField {
                    group,
                    behaviour,
                    error,
                })?;
            if scale == 0 || timeout_us == 0 || timeout_us > MAX_TIMEOUT_US {
                return Err(error);
            }
        }
    }
    Ok(())
}

impl crate::wire::Decode for Context {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        match r.variant(3) {
            0 => Context::Constant(r.decode()),
            1 => Context::Connection {
                port: r.decode(),
                connection: r.decode(),
            },
            _ => Context::Topic {
                filter: r.decode(),
                field: r.decode(),
                scale: r.decode(),
                timeout_us: r.decode(),
            },
        }
    }
}

impl crate::wire::Decode for GroupSpec {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        // Params read in place: decoded apart, its 2 KiB were copied into the group.
        let mut group = GroupSpec {
            number: r.decode(),
            params: Params::new(),
            contexts: Vec::new(),
        };
        group.params.decode_in_place(r);
        r.fill(&mut group.contexts);
        group
    }
}
crate::wire::decode_struct!(GateSource {
    owner,
    group,
    behaviours
});
crate::wire::decode_struct!(GateLink {
    source,
    behaviour,
    port,
    connection
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_values_divide_by_the_scale_and_saturate() {
        let scale = 255 * 256;
        assert_eq!(Context::of_value(0, scale), 0);
        assert_eq!(Context::of_value(-5, scale), 0);
        assert_eq!(Context::of_value(255, scale), ONE);
        assert_eq!(Context::of_value(70_000, scale), ONE);
        assert_eq!(Context::of_value(i64::MAX, scale), ONE);
        let half = Context::of_value(51, 102 * 256);
        assert_eq!(half, ONE / 2);
        // Rounded down: 1/255 of 2^29.
        assert_eq!(Context::of_value(1, scale), ((1u64 << 29) / 255) as i32);
        // A fractional scale: 0.5 reads 1 from a value of 1.
        assert_eq!(Context::of_value(1, 128), ONE);
        assert_eq!(Context::of_value(1, 0), 0);
    }

    #[test]
    fn the_gate_filter_matches_only_gate_frames() {
        use crate::protocol::{BROADCAST, FrameId, Service};
        let gates = FrameId::new(Service::Gates, 5, BROADCAST).id();
        assert!(GATE_SLOT_FILTER.matches(&gates));
        for service in Service::ALL.into_iter().filter(|&s| s != Service::Gates) {
            assert!(!GATE_SLOT_FILTER.matches(&FrameId::new(service, 5, BROADCAST).id()));
        }
        assert_eq!(GATE_SLOT_FILTER.validate(), Ok(()));
    }
}
