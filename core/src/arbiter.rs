//! A node's arbitration at run time: a table plus the integrators of its connections.
//!
//! For each frame, on each port that has a connection matching the frame's identifier:
//!
//! 1. every matching connection of the port is stimulated (usually one; several if filters
//!    overlap);
//! 2. the port's activity mask x is evaluated at the frame's time;
//! 3. the port's decision gives the connection i with x_i ∧ Φ_i(x), if any;
//! 4. the frame is delivered to the port's consumer iff i is one of the connections it fed.
//!
//! The same frame can thus be delivered to several ports of a node (fan-out), at most once per
//! port. Everything runs in the caller's context: no timers, no allocation, no panics.

use embedded_can::Id;
use heapless::Vec;

use crate::decay::Decay;
use crate::decision::{self, ConnectionSet, DecisionNode, NodeRef};
use crate::integrator::{Integrator, Runtime, Stimulated};
use crate::level::Level;
use crate::table::{Table, TableError};
use crate::time::Instant;
use crate::{MAX_CONNECTIONS, MAX_DECISION_NODES, MAX_PORTS};

/// What one frame did on one port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PortVerdict {
    /// The port, by its index in the table.
    pub port: u8,
    /// The port's connections that the frame fed.
    pub fed: ConnectionSet,
    /// Of those, the ones that were resting and ignored the frame.
    pub resting: ConnectionSet,
    /// The port's activity mask after the update.
    pub active: ConnectionSet,
    /// The connection the decision selects under that mask: the one whose frames get through now.
    pub selected: Option<u8>,
    /// The connection through which this frame was delivered: `selected` if the frame fed it.
    pub delivered: Option<u8>,
}

/// A set of ports, bit i for port i.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PortSet(u16);

impl PortSet {
    /// Whether port `index` is in the set.
    pub const fn contains(self, index: u8) -> bool {
        match 1u16.checked_shl(index as u32) {
            Some(bit) => self.0 & bit != 0,
            None => false,
        }
    }

    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The bits.
    pub const fn bits(self) -> u16 {
        self.0
    }

    const fn with(self, index: u8) -> Self {
        match 1u16.checked_shl(index as u32) {
            Some(bit) => PortSet(self.0 | bit),
            None => self,
        }
    }
}

/// What one frame did on the whole node.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reception {
    /// The ports the frame fed.
    pub fed: PortSet,
    /// The ports it was delivered to.
    pub delivered: PortSet,
}

/// Where a port's connections and nodes are in the table, cached so that a frame does not walk the
/// ports to find them.
#[derive(Clone, Copy, Debug)]
struct Layout {
    first_connection: usize,
    connections: usize,
    first_node: usize,
    nodes: usize,
    root: NodeRef,
}

/// One connection's run-time state: its integrator and τ's evaluation form. The rest of its
/// parameters (σ, τr) are read from the table, which the frame's filter test has just read.
#[derive(Clone, Copy, Debug)]
struct Slot {
    decay: Decay,
    integrator: Integrator,
}

/// A node's arbitration: owns its table (of the same capacities, see [`Table`]) and the state of
/// every connection.
///
/// Memory: the table plus 32 bytes per connection of capacity and 40 per port of capacity on a
/// 64-bit host (about 41 KiB in all at the default capacities, 5.3 KiB for
/// [`crate::BoardArbiter`]; `size_of::<Arbiter<P, C, N>>()` tells exactly).
#[derive(Clone, Debug)]
pub struct Arbiter<
    const PORTS: usize = MAX_PORTS,
    const CONNECTIONS: usize = MAX_CONNECTIONS,
    const NODES: usize = MAX_DECISION_NODES,
> {
    table: Table<PORTS, CONNECTIONS, NODES>,
    layout: Vec<Layout, PORTS>,
    slots: Vec<Slot, CONNECTIONS>,
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// Starts arbitrating with `table`, every connection at S = 0 and inactive.
    ///
    /// Validates the table again (it is cheap, and a `Table` can be deserialized without the
    /// loader), and fails with the first [`TableError`] found. Costs one pass over the table.
    pub fn new(table: Table<PORTS, CONNECTIONS, NODES>) -> Result<Self, TableError> {
        table.validate()?;
        let mut layout = Vec::new();
        let mut slots = Vec::new();
        for (port, connections, nodes) in table.ranges() {
            let entry = Layout {
                first_connection: connections.start,
                connections: connections.len(),
                first_node: nodes.start,
                nodes: nodes.len(),
                root: port.root(),
            };
            layout.push(entry).map_err(|_| TableError::TooManyPorts)?;
        }
        for (position, view) in table.ports().enumerate() {
            for (index, connection) in view.connections.iter().enumerate() {
                let runtime = Runtime::new(connection.stimulation).map_err(|error| {
                    TableError::Parameter {
                        port: u8::try_from(position).unwrap_or(u8::MAX),
                        connection: u8::try_from(index).unwrap_or(u8::MAX),
                        error,
                    }
                })?;
                let slot = Slot {
                    decay: runtime.decay(),
                    integrator: Integrator::new(),
                };
                slots
                    .push(slot)
                    .map_err(|_| TableError::TooManyConnections)?;
            }
        }
        Ok(Arbiter {
            table,
            layout,
            slots,
        })
    }

    /// The table in use.
    pub fn table(&self) -> &Table<PORTS, CONNECTIONS, NODES> {
        &self.table
    }

    /// Returns every connection to S = 0, inactive.
    pub fn reset(&mut self) {
        for slot in self.slots.iter_mut() {
            slot.integrator = Integrator::new();
        }
    }

    /// Arbitrates a frame with identifier `id` that arrived at `now`. Calls `on_verdict` once per
    /// port the frame fed, in port order, and sums up.
    ///
    /// Cost: one filter comparison per connection of the node, and per fed port one decay
    /// evaluation per connection of the port plus a decision walk of at most one step per
    /// connection of the port.
    pub fn receive(
        &mut self,
        id: &Id,
        now: Instant,
        mut on_verdict: impl FnMut(&PortVerdict),
    ) -> Reception {
        let mut reception = Reception::default();
        // Disjoint fields: the table is read while the slots are mutated.
        let connections = self.table.connections();
        for (port, layout) in self.layout.iter().enumerate() {
            let port = u8::try_from(port).unwrap_or(u8::MAX);
            let range =
                layout.first_connection..layout.first_connection.saturating_add(layout.connections);
            let (Some(slots), Some(filters)) =
                (self.slots.get_mut(range.clone()), connections.get(range))
            else {
                continue;
            };
            let mut fed = ConnectionSet::EMPTY;
            let mut resting = ConnectionSet::EMPTY;
            for (index, (slot, connection)) in slots.iter_mut().zip(filters).enumerate() {
                if connection.filter.matches(id) {
                    let index = u8::try_from(index).unwrap_or(u8::MAX);
                    fed = fed.with(index);
                    if slot
                        .integrator
                        .stimulate_with(&connection.stimulation, &slot.decay, now)
                        == Stimulated::Resting
                    {
                        resting = resting.with(index);
                    }
                }
            }
            if fed.is_empty() {
                continue;
            }
            let active = activity(slots, now);
            let selected = decide(self.table.nodes(), layout, active);
            let delivered = selected.filter(|&index| fed.contains(index));
            reception.fed = reception.fed.with(port);
            if delivered.is_some() {
                reception.delivered = reception.delivered.with(port);
            }
            on_verdict(&PortVerdict {
                port,
                fed,
                resting,
                active,
                selected,
                delivered,
            });
        }
        reception
    }

    /// The connection of port `port` whose frames would get through at `now`, or `None` (also for
    /// a port that does not exist). Read-only.
    pub fn selected(&self, port: u8, now: Instant) -> Option<u8> {
        let layout = self.layout.get(usize::from(port))?;
        decide(self.table.nodes(), layout, self.activity(port, now))
    }

    /// Port `port`'s activity mask at `now` (empty for a port that does not exist). Read-only.
    pub fn activity(&self, port: u8, now: Instant) -> ConnectionSet {
        self.port_slots(port)
            .map_or(ConnectionSet::EMPTY, |slots| activity(slots, now))
    }

    /// The stimulation level of connection `connection` of port `port` at `now`. Read-only.
    pub fn level(&self, port: u8, connection: u8, now: Instant) -> Option<Level> {
        let slot = self.port_slots(port)?.get(usize::from(connection))?;
        Some(slot.integrator.level_with(&slot.decay, now))
    }

    /// Whether connection `connection` of port `port` is in its rest time at `now` (ignoring
    /// frames); `false` for a connection that does not exist. Read-only.
    pub fn is_resting(&self, port: u8, connection: u8, now: Instant) -> bool {
        let rest_us = self
            .table
            .port(usize::from(port))
            .and_then(|view| view.connections.get(usize::from(connection)))
            .map(|connection| connection.stimulation.rest_us());
        let slot = self
            .port_slots(port)
            .and_then(|slots| slots.get(usize::from(connection)));
        match (slot, rest_us) {
            (Some(slot), Some(rest_us)) => slot.integrator.is_resting(&slot.decay, rest_us, now),
            _ => false,
        }
    }

    /// The number of ports.
    pub fn port_count(&self) -> usize {
        self.layout.len()
    }

    /// The number of connections of port `port` (0 for a port that does not exist).
    pub fn connection_count(&self, port: u8) -> usize {
        self.port_slots(port).map_or(0, <[Slot]>::len)
    }

    fn port_slots(&self, port: u8) -> Option<&[Slot]> {
        let layout = self.layout.get(usize::from(port))?;
        let end = layout.first_connection.checked_add(layout.connections)?;
        self.slots.get(layout.first_connection..end)
    }
}

/// The activity mask of a port's connections at `now`.
fn activity(slots: &[Slot], now: Instant) -> ConnectionSet {
    slots
        .iter()
        .enumerate()
        .filter(|(_, slot)| slot.integrator.is_active_with(&slot.decay, now))
        .fold(ConnectionSet::EMPTY, |set, (index, _)| {
            set.with(u8::try_from(index).unwrap_or(u8::MAX))
        })
}

/// The port's decision under `active`. Only an active connection can be selected (x_i ∧ Φ_i(x)):
/// a valid diagram may still name an inactive one (e.g. a root that is a terminal).
fn decide(nodes: &[DecisionNode], layout: &Layout, active: ConnectionSet) -> Option<u8> {
    let end = layout.first_node.checked_add(layout.nodes)?;
    let nodes = nodes.get(layout.first_node..end)?;
    decision::evaluate(nodes, layout.root, active).filter(|&index| active.contains(index))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::Filter;
    use crate::integrator::Stimulation;
    use crate::level::Gain;
    use crate::table::Connection;
    use embedded_can::StandardId;

    #[test]
    fn an_inactive_connection_is_never_selected() {
        // A valid diagram that names C0 whatever the mask (root = terminal "C0 delivers"): C0 is
        // selected only while it is active, so that `delivered` is `selected` whenever the frame
        // fed it.
        let mut table: Table = Table::new();
        let connection = Connection {
            filter: Filter::exact(0x110, false).unwrap(),
            stimulation: Stimulation::new(Gain::from_raw(1 << 30).unwrap(), 1_000_000, 0).unwrap(),
        };
        table
            .push_port(&[connection], &[], NodeRef::deliver(0).unwrap())
            .unwrap();
        let mut arbiter = Arbiter::new(table).unwrap();
        let id = Id::Standard(StandardId::new(0x110).unwrap());
        assert_eq!(arbiter.selected(0, Instant::from_micros(0)), None);
        let mut verdicts = std::vec::Vec::new();
        arbiter.receive(&id, Instant::from_micros(0), |v| verdicts.push(*v));
        // S = 0.5: fed, inactive, not delivered, and so not selected either.
        assert_eq!(verdicts[0].active, ConnectionSet::EMPTY);
        assert_eq!((verdicts[0].selected, verdicts[0].delivered), (None, None));
        // A second frame at the same instant: S = 1, active, selected and delivered.
        arbiter.receive(&id, Instant::from_micros(0), |v| verdicts.push(*v));
        assert_eq!(
            (verdicts[1].selected, verdicts[1].delivered),
            (Some(0), Some(0))
        );
        assert_eq!(arbiter.selected(0, Instant::from_micros(1_000_001)), None);
    }
}
