//! A table swap: what a new arbiter takes over from the one it replaces.
//!
//! What is taken over is moved aside first ([`Carried`], a few kilobytes), so that a node can
//! build the new arbiter where the old one was: one arbiter in RAM, not two. A node that held
//! both during the swap needed some 26 KB more of RAM at its worst (the NUCLEO-G474RE's full
//! build; docs/footprint.md).

use heapless::Vec;

use super::{Arbiter, Port, Slot, bit};
use crate::hbba::filters::{MessageFilters, Throttles};
use crate::integrator::Integrator;
use crate::table::Connection;

/// What [`Arbiter::carry_over`] reads of the arbiter a new one replaces, taken out of it
/// ([`Arbiter::take_carried`]): its ports, its connections (their definitions and run-time
/// slots), its filters' state and the table's filter part.
///
/// Memory: at the capacities, 56 bytes per port and 68 per connection, the filters' run-time
/// state and their table part: 5.2 KB at the boards' capacities.
#[derive(Clone, Debug, Default)]
pub struct Carried<const PORTS: usize, const CONNECTIONS: usize> {
    ports: Vec<Port, PORTS>,
    slots: Vec<Slot, CONNECTIONS>,
    connections: Vec<Connection, CONNECTIONS>,
    throttles: Throttles,
    filters: MessageFilters,
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// What a new arbiter takes over from this one ([`Arbiter::carry_over_from`]), moved out of
    /// it into `into` (what `into` held is replaced): this arbiter is left without ports or
    /// connections, to be replaced. For a node that builds the new arbiter in this one's place.
    /// Costs a copy of the lists moved.
    // Moved rather than copied element by element, and into the caller's place rather than
    // returned: five block copies of code, one `Carried` in the caller's frame.
    pub fn take_carried(&mut self, into: &mut Carried<PORTS, CONNECTIONS>) {
        into.ports = core::mem::take(&mut self.ports);
        into.slots = core::mem::take(&mut self.slots);
        into.connections = self.table.take_connections();
        into.throttles = core::mem::take(&mut self.throttles);
        into.filters = self.table.take_filters();
    }

    /// Takes over, from `previous` (the arbiter this one replaces), the state of every
    /// connection that is **unchanged**: connection `k` of port `p` here, connection `k` of port
    /// `p` there (positions in the table, the network file's order), with the same filter (id,
    /// mask, standard or extended) and the same ⟨σ, τ, τr⟩. Its integrator (S0, t0, active flag:
    /// hence its level, activity and rest time) goes on as if no swap had happened; every other
    /// connection starts at S = 0, inactive, as after [`Arbiter::new`]. The ports' decisions are
    /// this table's, taken again from the carried activity at the next frame or reading: a port
    /// whose connections are all unchanged, and whose decision is too, decides exactly as
    /// `previous` would have. The port's consumer plays no part. Value ports start without
    /// values or output (their connections' activity is carried like any other's). An unchanged
    /// connection with an HBBA filter in both tables keeps its filter; the others start closed.
    /// Returns how many connections were carried over.
    ///
    /// Call it on a freshly built arbiter (its own state is replaced). Costs a copy of
    /// `previous`, then [`Arbiter::carry_over_from`]'s work: a node that builds the new arbiter
    /// in the old one's place calls [`Arbiter::take_carried`] and that instead.
    pub fn carry_over(&mut self, previous: &Self) -> usize {
        let mut carried = Carried::default();
        previous.clone().take_carried(&mut carried);
        self.carry_over_from(&carried)
    }

    /// [`Arbiter::carry_over`] from what was taken out of the replaced arbiter
    /// ([`Arbiter::take_carried`]) before this one was built, perhaps in its place. Costs one
    /// comparison of a connection (filter and parameters) per connection of this table, and a
    /// port reset per port; no allocation.
    // Run once per table swap.
    pub fn carry_over_from(&mut self, previous: &Carried<PORTS, CONNECTIONS>) -> usize {
        for port in self.ports.iter_mut() {
            port.idle();
        }
        let mut carried = 0;
        let connections = self.table.connections();
        for (slot, connection) in self.slots.iter_mut().zip(connections) {
            slot.integrator = Integrator::new();
            let Some(old_port) = previous.ports.get(usize::from(slot.port)) else {
                continue;
            };
            if slot.index >= old_port.connections {
                continue;
            }
            let old =
                usize::from(old_port.first_connection).saturating_add(usize::from(slot.index));
            if let (Some(old_slot), Some(old_connection)) =
                (previous.slots.get(old), previous.connections.get(old))
                && old_connection == connection
            {
                slot.integrator = old_slot.integrator;
                // An unchanged connection filtered in both keeps its filter (φ and count): a
                // push that changes other rules does not close what the intention opened.
                if let Some(&throttle) = previous.throttles.get(usize::from(old_slot.filter)) {
                    self.throttles.carry(slot.filter, throttle);
                }
                carried += 1;
                // A carried connection that is flagged flags its port (marked here rather than
                // in a second pass over each port's slots), with both intervals empty: the next
                // frame or reading evaluates every flagged connection ([`Port::recompute`]), as
                // after a frame out of order. (A port's connections are fewer than 32.)
                if slot.integrator.active_flag()
                    && let Some(port) = self.ports.get_mut(usize::from(slot.port))
                {
                    port.flagged |= bit(slot.index);
                    (port.from, port.until) = (1, 0);
                    (port.lapsed_from, port.lapsed_until) = (1, 0);
                }
            }
        }
        self.throttles.settle(
            previous.throttles.profile(),
            *self.table.filters() == previous.filters,
        );
        carried
    }
}
