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
//!
//! A **value port** ([`crate::value_port`]) delivers no frame as it came: [`Arbiter::receive_frame`]
//! keeps each of its connections' last frame and hands the consumer the combined output when it
//! changes, and [`Arbiter::poll`] does so at [`Arbiter::deadline`], when a value ages out. Ordinary
//! ports pay nothing for it: [`Arbiter::receive`] is unchanged, and [`Arbiter::receive_frame`] on a
//! table without value ports is [`Arbiter::receive`] plus one test.
//!
//! ## How a frame stays cheap
//!
//! What a frame needs is built once, when the table is loaded, so that its cost does not grow
//! with the node:
//!
//! - a filter index (`index.rs`): the connections a frame feeds are found by hashing its
//!   identifier into buckets of exact filters (plus a test per masked filter), not by testing
//!   every connection of the node; when its bucket names the one connection the frame feeds
//!   (a topic that feeds one port, no masked filter), the frame goes straight to it
//!   ([`Arbiter::receive`]'s `feed_one`);
//! - per port, its activity kept up to date by the frames, with the interval of instants in
//!   which it holds (`Port`): a frame reads it instead of evaluating every connection, and the
//!   last decision, reused while the activity does not change;
//! - per port, the decision as steps that test several connections at once (`decision.rs`): a
//!   priority run is one step;
//! - per connection, everything a frame reads of it in one place (`Slot`).
//!
//! The stimulation uses 32-bit arithmetic once the time since the last frame is known to be
//! within τ, and skips the decay when the frame saturates the level anyway (`decay.rs`). On a
//! Cortex-M4 a frame that feeds one connection costs about 120 to 500 instructions (150 for most
//! frames of Take and Return; more when the decay is evaluated, an activity lapses or the
//! decision is walked), one that feeds none about 25 (docs/figures.md;
//! `scripts/cortex-m4-cost.sh`). The decisions are those of the straightforward evaluation, bit
//! for bit: `core/tests/equivalence.rs` compares them with it on random tables and frames.

use embedded_can::Id;
use heapless::Vec;

mod ble;
mod build;
mod carry;
#[cfg(feature = "dynamics")]
pub(crate) mod dynamics;
mod filters;
mod port;
mod values;

pub use carry::Carried;
use port::{Port, Slot, decide};

use crate::ble::{Eligibility, MAX_PEERS};
use crate::decision::{ConnectionSet, Step};
#[cfg(feature = "dynamics")]
use crate::dynamics::{GroupRun, MAX_DYNAMICS_GROUPS, MAX_GATE_SOURCES, SourceState};
use crate::hbba::filters::{Throttles, UNFILTERED};
use crate::index::{Cursor, FilterIndex, Lookup};
use crate::integrator::{Integrator, Stimulated};
use crate::level::Level;
use crate::table::Table;
use crate::time::Instant;
use crate::value_port::{MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS, ValueSlot, ValueState};
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

    /// The set of port `index` alone; a port's index is below [`MAX_PORTS`] (16), as a table's
    /// capacity is.
    const fn of(index: u8) -> Self {
        PortSet(1 << (index & 15))
    }

    /// Out of line: six callers inlined it (24 bytes of the NUCLEO-G474RE's flash; a frame's
    /// instructions as before).
    #[inline(never)]
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

/// What one frame did on the whole node, value ports included ([`Arbiter::receive_frame`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameReception {
    /// The ports the frame fed.
    pub fed: PortSet,
    /// The ordinary ports it was delivered to, as it came.
    pub delivered: PortSet,
    /// The value ports whose output it changed (each handed to `on_value`).
    pub combined: PortSet,
    /// The value ports it fed that refused it: too short for their fields.
    pub refused: PortSet,
}

/// A node's arbitration: owns its table (of the same capacities, see [`Table`]) and the state of
/// every connection.
///
/// Memory: the table plus, per connection of capacity, 40 bytes of run-time state and 16 of
/// filter index, 8 bytes per decision node of capacity (the decision in the form it is walked),
/// 56 bytes per port of capacity, and the value ports' fixed 832 bytes
/// ([`crate::value_port`]): about 71 KiB in all at the default capacities, 10.1 KiB for
/// [`crate::BoardArbiter`]. `size_of::<Arbiter<P, C, N>>()` tells exactly (`cargo run -p
/// pab-core --example footprint`).
// repr(C), hot fields first: on a 32-bit core the ports and the index are then reached with
// small offsets from the arbiter's address (the table, large and cold, comes last).
#[derive(Clone, Debug)]
#[repr(C)]
pub struct Arbiter<
    const PORTS: usize = MAX_PORTS,
    const CONNECTIONS: usize = MAX_CONNECTIONS,
    const NODES: usize = MAX_DECISION_NODES,
> {
    ports: Vec<Port, PORTS>,
    index: FilterIndex<CONNECTIONS>,
    slots: Vec<Slot, CONNECTIONS>,
    steps: Vec<Step, NODES>,
    value_ports: PortSet,
    values: Vec<ValueState, MAX_VALUE_PORTS>,
    value_slots: Vec<ValueSlot, MAX_VALUE_CONNECTIONS>,
    /// The state of each BLE group of the table, in the table's order.
    groups: Vec<Eligibility<MAX_PEERS>, { crate::ble::TABLE_GROUPS }>,
    /// The competitive-dynamics groups the node runs, in the table's order.
    #[cfg(feature = "dynamics")]
    runs: Vec<GroupRun, MAX_DYNAMICS_GROUPS>,
    /// What the node reads of each gate source, in the table's order.
    #[cfg(feature = "dynamics")]
    sources: Vec<SourceState, MAX_GATE_SOURCES>,
    /// HBBA's message filters, one per filtered connection of the table.
    throttles: Throttles,
    table: Table<PORTS, CONNECTIONS, NODES>,
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// The table in use.
    pub fn table(&self) -> &Table<PORTS, CONNECTIONS, NODES> {
        &self.table
    }

    /// The first instant after `now` at which a connection active at `now` stops being active
    /// if no frame comes: when a port's decision may change by itself. `None` when none is
    /// active. A node with message filters wakes then to report exploitation edges. Read-only;
    /// costs a test per connection.
    pub fn activity_deadline(&self, now: Instant) -> Option<Instant> {
        // A fold from the largest value, with a flag for "none" (an end may saturate to it):
        // `min` takes the first element apart, a second inlined copy of the test.
        let (any, soonest) = self
            .slots
            .iter()
            .filter(|slot| slot.is_active(now))
            .fold((false, u64::MAX), |(_, soonest), slot| {
                (true, soonest.min(slot.end().saturating_add(1)))
            });
        any.then_some(Instant::from_micros(soonest))
    }

    /// The slot of connection `connection` of port `port`. Out of line: the readings and the
    /// filter commands look slots up with it.
    #[inline(never)]
    fn slot_of(&self, port: u8, connection: u8) -> Option<&Slot> {
        let record = self.ports.get(usize::from(port))?;
        if connection >= record.connections {
            return None;
        }
        self.slots
            .get(usize::from(record.first_connection) + usize::from(connection))
    }

    /// Returns every connection to S = 0, inactive.
    pub fn reset(&mut self) {
        for slot in self.slots.iter_mut() {
            slot.integrator = Integrator::new();
        }
        for port in self.ports.iter_mut() {
            port.idle();
        }
        for state in self.values.iter_mut() {
            state.clear(&mut self.value_slots);
        }
        for port in self.ports.iter_mut() {
            port.external = 0;
        }
        for (state, group) in self.groups.iter_mut().zip(self.table.groups()) {
            if let Ok(fresh) =
                Eligibility::new(group.number, group.node, u64::from(group.period_us))
            {
                *state = fresh;
            }
        }
        #[cfg(feature = "dynamics")]
        for (run, spec) in self.runs.iter_mut().zip(self.table.dynamics()) {
            if let Ok(fresh) = GroupRun::new(spec) {
                *run = fresh;
            }
        }
        #[cfg(feature = "dynamics")]
        for source in self.sources.iter_mut() {
            *source = SourceState::new();
        }
    }

    /// Arbitrates a frame with identifier `id` that arrived at `now`. Calls `on_verdict` once per
    /// port the frame fed, in port order, and sums up.
    ///
    /// Cost: a hash of the identifier and one comparison when its bucket answers (the
    /// identifier is alone there and feeds one connection, or is not the bucket's), else a
    /// comparison per exact filter in its bucket and a test per masked filter; then per fed port
    /// a stimulation per connection it feeds, the port's activity (read from its state, or a
    /// test per active connection after a deadline), and, if the activity changed, a decision
    /// walk of at most one step per connection of the port (a priority run is one step). On a
    /// Cortex-M4, from about 25 instructions (a frame for other nodes) to a few hundred (docs/figures.md).
    #[inline(always)]
    pub fn receive(
        &mut self,
        id: &Id,
        now: Instant,
        mut on_verdict: impl FnMut(&PortVerdict),
    ) -> Reception {
        match self.index.lookup(id) {
            Lookup::One(connection) => self.feed_one(connection, now, &mut on_verdict),
            Lookup::Several => self.feed(id, now, &mut on_verdict),
            // A frame for other nodes (the common case on a shared bus): done.
            Lookup::Nothing => Reception::default(),
        }
    }

    /// Feeds the one connection a frame feeds (the index knows it is the only one), then its
    /// port's activity, decision and verdict: a frame of a topic that feeds one port of the
    /// node, without the cursor of [`Arbiter::feed`].
    #[inline(never)]
    fn feed_one(
        &mut self,
        connection: usize,
        now: Instant,
        on_verdict: &mut impl FnMut(&PortVerdict),
    ) -> Reception {
        let Some(slot) = self.slots.get_mut(connection) else {
            return Reception::default();
        };
        // A frame its HBBA filter drops never came, for this connection. (Without the feature
        // no connection has a filter.)
        if cfg!(feature = "filters")
            && slot.filter != UNFILTERED
            && !self.throttles.pass(slot.filter)
        {
            return Reception::default();
        }
        let number = slot.port;
        let Some(port) = self.ports.get_mut(usize::from(number)) else {
            return Reception::default();
        };
        // A slot's index in its port is below 32.
        let bit = 1u32 << (slot.index & 31);
        let resting = match slot.stimulate(now) {
            Stimulated::Resting => bit,
            Stimulated::Accepted => {
                port.accepted(bit, slot.integrator.active_flag(), slot.end(), now);
                0
            }
        };
        // With the claims of the BLE groups held (0 without groups).
        let active = port.update_activity(&self.slots, now) | port.external;
        let selected = port.decide(&self.steps, active);
        let delivered = selected.filter(|&index| bit == 1 << (index & 31));
        on_verdict(&PortVerdict {
            port: number,
            fed: ConnectionSet::from_bits(bit),
            resting: ConnectionSet::from_bits(resting),
            active: ConnectionSet::from_bits(active),
            selected,
            delivered,
        });
        let fed = PortSet::of(number);
        Reception {
            fed,
            delivered: if delivered.is_some() {
                fed
            } else {
                PortSet::default()
            },
        }
    }

    /// Feeds the connections the frame feeds (as the index `found` them), port after port, and
    /// calls `on_verdict` for each port. Out of line so that a frame that feeds nothing does not
    /// pay for its set-up.
    #[inline(never)]
    fn feed(
        &mut self,
        id: &Id,
        now: Instant,
        on_verdict: &mut impl FnMut(&PortVerdict),
    ) -> Reception {
        let mut reception = Reception::default();
        // The first connection through the same out-of-line step as the others: inlined here it
        // was a copy of the cursor's step, ~100 bytes of the NUCLEO-G474RE's flash.
        let mut cursor = self.index.cursor(self.index.find(id));
        let mut next = self.next_passing(&mut cursor, id);
        while let Some(connection) = next {
            next = self.feed_port(connection, &mut cursor, id, now, on_verdict, &mut reception);
        }
        reception
    }

    /// Feeds `connection` and the frame's next connections while they belong to the same port
    /// (several when filters overlap); then the port's activity, decision and verdict. Returns
    /// the frame's next connection (of a later port), if any. Out of line, one copy for the
    /// first port and the others (fan-out), and one loop for a port's first connection and the
    /// others: a copy for each took 1.5 KB more of the NUCLEO-G474RE's flash. The frames that
    /// take this path (several connections or a masked filter for their identifier;
    /// `Arbiter::feed_one` takes the others) cost about what they did (on the emulated board, a
    /// frame for two ports 642 -> 618 instructions, for three 877 either way, for one masked
    /// filter 378 -> 392, for two overlapping connections of a port 693 -> 610).
    // Left to the inliner now that its one call is in `Arbiter::feed`'s loop: out of line it
    // took 60 bytes more of the NUCLEO-G474RE's flash, 64 of the emulated board's, and the
    // counted frames (scripts/cortex-m4-cost.sh) cost the same either way.
    fn feed_port(
        &mut self,
        connection: usize,
        cursor: &mut Cursor,
        id: &Id,
        now: Instant,
        on_verdict: &mut impl FnMut(&PortVerdict),
        reception: &mut Reception,
    ) -> Option<usize> {
        let number = self.slots.get(connection)?.port;
        let (mut fed, mut resting) = (0, 0);
        let mut connection = connection;
        let next = loop {
            if let Some((_, bit, rest)) = self.stimulate(connection, now) {
                fed |= bit;
                resting |= rest;
            }
            match self.next_passing(cursor, id) {
                Some(more) if self.slots.get(more).is_some_and(|slot| slot.port == number) => {
                    connection = more;
                }
                other => break other,
            }
        };
        self.conclude(number, fed, resting, now, on_verdict, reception);
        next
    }

    /// After the connections of port `number` that a frame feeds have been stimulated (`fed`,
    /// of which `resting` ignored it): the port's activity, its decision, the verdict.
    #[inline(always)]
    fn conclude(
        &mut self,
        number: u8,
        fed: u32,
        resting: u32,
        now: Instant,
        on_verdict: &mut impl FnMut(&PortVerdict),
        reception: &mut Reception,
    ) {
        let Some(port) = self.ports.get_mut(usize::from(number)) else {
            return;
        };
        // With the claims of the BLE groups held (0 without groups).
        let active = port.update_activity(&self.slots, now) | port.external;
        let selected = port.decide(&self.steps, active);
        let delivered = selected.filter(|&index| fed & (1 << (index & 31)) != 0);
        reception.fed = reception.fed.with(number);
        if delivered.is_some() {
            reception.delivered = reception.delivered.with(number);
        }
        on_verdict(&PortVerdict {
            port: number,
            fed: ConnectionSet::from_bits(fed),
            resting: ConnectionSet::from_bits(resting),
            active: ConnectionSet::from_bits(active),
            selected,
            delivered,
        });
    }

    /// Whether the frame gets through connection `connection`'s HBBA filter (the connections it
    /// does not get through never see it). One byte compared for a connection without a filter.
    #[inline(always)]
    fn passes(&mut self, connection: usize) -> bool {
        if !cfg!(feature = "filters") {
            return true;
        }
        let filter = self.slots.get(connection).map_or(UNFILTERED, |s| s.filter);
        filter == UNFILTERED || self.throttles.pass(filter)
    }

    /// The frame's next connection whose HBBA filter lets it through. Out of line: its loop
    /// would otherwise be inlined at each place a frame's connections are walked (396 bytes of
    /// the NUCLEO-G474RE's flash more); the cursor's step is in it alone.
    #[inline(never)]
    fn next_passing(&mut self, cursor: &mut Cursor, id: &Id) -> Option<usize> {
        loop {
            let candidate = self.index.next(cursor, id, self.table.connections())?;
            if self.passes(candidate) {
                return Some(candidate);
            }
        }
    }

    /// Applies a frame at `now` to connection `connection` (index in the table) and records it in
    /// its port's state: (its port, its bit as fed, its bit if it was resting).
    #[inline(always)]
    fn stimulate(&mut self, connection: usize, now: Instant) -> Option<(u8, u32, u32)> {
        let slot = self.slots.get_mut(connection)?;
        // A slot's index in its port is below 32.
        let bit = 1u32 << (slot.index & 31);
        match slot.stimulate(now) {
            Stimulated::Resting => Some((slot.port, bit, bit)),
            Stimulated::Accepted => {
                let port = self.ports.get_mut(usize::from(slot.port))?;
                port.accepted(bit, slot.integrator.active_flag(), slot.end(), now);
                Some((slot.port, bit, 0))
            }
        }
    }

    /// The connection of port `port` whose frames would get through at `now`, or `None` (also for
    /// a port that does not exist). Read-only.
    pub fn selected(&self, port: u8, now: Instant) -> Option<u8> {
        self.selected_holding(port, now, 0)
    }

    /// [`Arbiter::selected`] with the connections of `held` taken as active too (a BLE group's
    /// claim, [`Arbiter::offered`]). Out of line: one copy for both.
    #[inline(never)]
    fn selected_holding(&self, port: u8, now: Instant, held: u32) -> Option<u8> {
        let record = self.ports.get(usize::from(port))?;
        let active = record.activity(&self.slots, now) | record.external | held;
        decide(record.steps(&self.steps), record.root, active)
    }

    /// Port `port`'s activity mask at `now` (empty for a port that does not exist). Read-only;
    /// costs what a frame's activity costs.
    pub fn activity(&self, port: u8, now: Instant) -> ConnectionSet {
        self.ports
            .get(usize::from(port))
            .map_or(ConnectionSet::EMPTY, |record| {
                ConnectionSet::from_bits(record.activity(&self.slots, now) | record.external)
            })
    }

    /// The stimulation level of connection `connection` of port `port` at `now`. Read-only.
    pub fn level(&self, port: u8, connection: u8, now: Instant) -> Option<Level> {
        let slot = self.slot_of(port, connection)?;
        Some(slot.integrator.level_with(&slot.decay(), now))
    }

    /// Whether connection `connection` of port `port` is in its rest time at `now` (ignoring
    /// frames); `false` for a connection that does not exist. Read-only.
    pub fn is_resting(&self, port: u8, connection: u8, now: Instant) -> bool {
        self.slot_of(port, connection)
            .is_some_and(|slot| slot.integrator.is_resting(&slot.decay(), slot.rest_us, now))
    }

    /// Takes the schema server's set-up out of the running table ([`Table::take_schema`]).
    #[cfg(feature = "schema")]
    pub fn take_schema(&mut self) -> Option<crate::schema::Setup> {
        self.table.take_schema()
    }

    /// The number of ports.
    pub fn port_count(&self) -> usize {
        self.ports.len()
    }

    /// The number of connections of port `port` (0 for a port that does not exist).
    pub fn connection_count(&self, port: u8) -> usize {
        self.port_slots(port).map_or(0, <[Slot]>::len)
    }

    fn port_slots(&self, port: u8) -> Option<&[Slot]> {
        Some(self.ports.get(usize::from(port))?.slots(&self.slots))
    }
}

/// Bit `index` of a mask (0 for an index of 32 or more). Out of line: eight callers inlined it
/// (48 bytes of the NUCLEO-G474RE's flash; a frame's instructions as before).
#[inline(never)]
fn bit(index: u8) -> u32 {
    1u32.checked_shl(u32::from(index)).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decision::NodeRef;
    use crate::filter::Filter;
    use crate::integrator::Stimulation;
    use crate::level::Gain;
    use crate::table::Connection;
    use embedded_can::StandardId;

    /// `Port::idle` sets the empty mask's decision without a walk: whatever the diagram says
    /// (here a root that delivers connection 0 at once), nobody is selected.
    #[test]
    fn nobody_is_selected_under_the_empty_mask() {
        let root = NodeRef::deliver(0).unwrap();
        assert_eq!(decide(&[], root, 0), None);
        assert_eq!(decide(&[], root, 1), Some(0));
    }

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
