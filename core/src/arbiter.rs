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

use crate::ble::{BleError, Claim, Eligibility, MAX_GROUPS, MAX_PEERS};
#[cfg(feature = "dynamics")]
use crate::dynamics::{GroupRun, MAX_DYNAMICS_GROUPS, MAX_GATE_SOURCES, SourceState};

#[cfg(feature = "dynamics")]
pub(crate) mod dynamics;
use crate::decay::Decay;
use crate::decision::{self, ConnectionSet, NodeRef, Step};
use crate::frame::Frame;
use crate::hbba::filters::{CommandError, FilterCounts, Throttles, UNFILTERED};
use crate::index::{Cursor, FilterIndex, Lookup};
use crate::integrator::{Integrator, Stimulated};
use crate::level::{Gain, Level};
use crate::table::{Connection, Table, TableError, Verdict};
use crate::time::Instant;
use crate::value_port::{
    Combined, Earliest, MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS, ValueSlot, ValueState,
};
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

/// One connection's run-time state and what a frame needs of its parameters, in one place: its
/// integrator, σ, τr, τ's evaluation form, and where it is (port, index in the port). 40 bytes:
/// τ's two parts are kept apart (a [`Decay`] would bring its padding).
#[derive(Clone, Copy, Debug)]
struct Slot {
    integrator: Integrator,
    /// τ's reciprocal ([`Decay`]).
    reciprocal: u64,
    /// τ in µs ([`Decay`]).
    tau: u32,
    gain: Gain,
    rest_us: u32,
    port: u8,
    index: u8,
    /// The position of the connection's HBBA filter among the node's ([`Throttles`]), or
    /// [`UNFILTERED`].
    filter: u8,
}

impl Slot {
    /// τ's evaluation form.
    #[inline(always)]
    fn decay(&self) -> Decay {
        Decay::from_parts(self.tau, self.reciprocal)
    }

    /// Whether the connection is active at `now`.
    fn is_active(&self, now: Instant) -> bool {
        self.integrator.is_active_with(&self.decay(), now)
    }

    /// The last accepted frame's instant, as a counter value.
    fn last(&self) -> u64 {
        self.integrator.last().as_micros()
    }

    /// When its activity ends if it is active: its last accepted frame plus τ, saturated at the
    /// end of the counter (every later instant is then within τ; see [`Port`]).
    #[inline(always)]
    fn end(&self) -> u64 {
        self.last().saturating_add(u64::from(self.tau))
    }

    /// Applies a frame at `now` (see [`Integrator::stimulate`]).
    #[inline(always)]
    fn stimulate(&mut self, now: Instant) -> Stimulated {
        let decay = self.decay();
        self.integrator
            .stimulate_parts(self.gain, self.rest_us, &decay, now)
    }
}

/// Half the counter: a connection's last frame up to this far in the future of `now` counts as
/// simultaneous (an out-of-order timestamp), any further is in the past ([`Instant::micros_since`]).
const HALF: u64 = 1 << 63;

/// A port at run time: where its connections and decision steps are, its activity kept up to
/// date by the frames, and its last decision.
///
/// **Activity.** A connection is active at t when its integrator's flag is set and
/// `t − last` (wrapping) is at most τ or at least 2^63 (a `t` before its last frame counts as
/// simultaneous with it). Over plain `u64` instants, a flagged connection with `last ≤ t` is
/// thus active in `[last − 2^63, last + τ]` and inactive in `(last + τ, last + 2^63)`. The
/// port's activity changes only when a frame stimulates one of its connections or when a
/// deadline passes, so the port keeps:
///
/// - `flagged`: the connections whose flag is set (all others are inactive at every instant);
/// - `steady` and `[from, until]`: every connection in `steady` is active throughout the
///   interval, every other flagged one inactive throughout it;
/// - `[lapsed_from, lapsed_until]`, containing `[from, until]`: every flagged connection not in
///   `steady` is inactive throughout it.
///
/// A frame within `[from, until]` reads `steady`. One after `until` re-examines the connections
/// of `steady` only (their `end`), moving those that lapsed out of it ([`Port::refresh`]); the
/// lapsed ones stay lapsed until they are stimulated again. Anything else (a frame out of order,
/// a clock that wrapped) re-evaluates every flagged connection from scratch
/// ([`Port::recompute`]). A frame that stimulates a connection only narrows the interval.
/// [`Arbiter::activity`] reads the same way without changing anything; the tests compare both
/// with a straightforward evaluation of every connection at every instant they look at.
///
/// **Decision.** The decision is a function of the activity alone: the last mask and what it
/// selected are kept, and a frame that leaves the mask as it was reuses the answer.
#[derive(Clone, Copy, Debug)]
struct Port {
    flagged: u32,
    steady: u32,
    from: u64,
    until: u64,
    lapsed_from: u64,
    lapsed_until: u64,
    decided_for: u32,
    decided: Option<u8>,
    /// The claim connections of BLE groups this node holds ([`crate::ble`]): active whatever
    /// their integrators say (no frame feeds them), ORed into the mask the decision reads.
    external: u32,
    first_connection: u16,
    connections: u8,
    first_step: u16,
    steps: u16,
    root: NodeRef,
}

impl Port {
    /// The port's connections among all the slots.
    fn slots<'a>(&self, slots: &'a [Slot]) -> &'a [Slot] {
        let first = usize::from(self.first_connection);
        slots
            .get(first..first.saturating_add(usize::from(self.connections)))
            .unwrap_or(&[])
    }

    /// The port's decision steps among all the steps.
    fn steps<'a>(&self, steps: &'a [Step]) -> &'a [Step] {
        let first = usize::from(self.first_step);
        steps
            .get(first..first.saturating_add(usize::from(self.steps)))
            .unwrap_or(&[])
    }

    /// Whether `now` is in the steady interval.
    #[inline]
    fn is_steady(&self, now: Instant) -> bool {
        let at = now.as_micros();
        self.from <= at && at <= self.until
    }

    /// The activity at `now`. Read-only: two comparisons in the steady interval, one activity
    /// test per flagged connection outside it.
    fn activity(&self, slots: &[Slot], now: Instant) -> u32 {
        if self.is_steady(now) {
            return self.steady;
        }
        let slots = self.slots(slots);
        let mut active = 0;
        let mut rest = self.flagged;
        while rest != 0 {
            let index = rest.trailing_zeros();
            rest &= rest - 1;
            if slots
                .get(index as usize)
                .is_some_and(|slot| slot.is_active(now))
            {
                active |= 1 << index;
            }
        }
        active
    }

    /// [`Port::activity`], bringing the state up to `now` when `now` is outside the steady
    /// interval.
    #[inline]
    fn update_activity(&mut self, slots: &[Slot], now: Instant) -> u32 {
        if self.is_steady(now) {
            self.steady
        } else {
            self.refresh(slots, now)
        }
    }

    /// After `until`: the connections of `steady` whose activity ended move out of it, and the
    /// interval is set again around `now`. Costs a comparison per connection of `steady`.
    #[inline(never)]
    fn refresh(&mut self, slots: &[Slot], now: Instant) -> u32 {
        let at = now.as_micros();
        if at < self.from || at < self.lapsed_from || at > self.lapsed_until {
            return self.recompute(slots, now);
        }
        let all = slots;
        let slots = self.slots(all);
        // The least time left before one of those still active ends (32 bits: τ < 2^32).
        let (mut left, mut active) = (u32::MAX, false);
        let mut rest = self.steady;
        while rest != 0 {
            let index = rest.trailing_zeros();
            rest &= rest - 1;
            let Some(slot) = slots.get(index as usize) else {
                continue;
            };
            let (since, before) = at.overflowing_sub(slot.last());
            if before || since >= HALF {
                // Its last frame is after `now` (out of order), or half the counter before it:
                // start from scratch.
                return self.recompute(all, now);
            }
            match u32::try_from(since) {
                Ok(since) if since <= slot.tau => {
                    left = left.min(slot.tau - since);
                    active = true;
                }
                _ => {
                    // Lapsed: inactive until 2^63 after its last frame.
                    self.steady &= !(1 << index);
                    self.lapsed_from = self.lapsed_from.max(slot.end().saturating_add(1));
                    self.lapsed_until = self.lapsed_until.min(slot.last().saturating_add(HALF - 1));
                }
            }
        }
        // The earliest end among those still active is `now` plus the least time left
        // (saturated, as their ends are: each one's end is its last frame plus τ).
        let mut until = self.lapsed_until;
        if active {
            until = until.min(at.saturating_add(u64::from(left)));
        }
        self.from = self.from.max(self.lapsed_from);
        self.until = until;
        self.steady
    }

    /// Evaluates every flagged connection at `now` and sets both intervals around `now` (empty
    /// when a connection's last frame is after `now`: the next frame evaluates again).
    #[inline(never)]
    fn recompute(&mut self, slots: &[Slot], now: Instant) -> u32 {
        let slots = self.slots(slots);
        let at = now.as_micros();
        let (mut from, mut until) = (0u64, u64::MAX);
        let (mut lapsed_from, mut lapsed_until) = (0u64, u64::MAX);
        let mut steady = 0;
        let mut rest = self.flagged;
        while rest != 0 {
            let index = rest.trailing_zeros();
            rest &= rest - 1;
            let Some(slot) = slots.get(index as usize) else {
                continue;
            };
            let last = slot.last();
            if slot.is_active(now) {
                steady |= 1 << index;
            }
            if last > at {
                // Its last frame is after `now`: no interval, not even for the lapsed ones, so
                // that the next frame evaluates everything again.
                (from, until) = (1, 0);
                (lapsed_from, lapsed_until) = (1, 0);
            } else if at - last >= HALF {
                // Half the counter after its last frame: in its past again, so active from
                // there to the end of the counter.
                from = from.max(last.saturating_add(HALF));
            } else if at <= slot.end() {
                from = from.max(last.saturating_sub(HALF));
                until = until.min(slot.end());
            } else {
                lapsed_from = lapsed_from.max(slot.end().saturating_add(1));
                lapsed_until = lapsed_until.min(last.saturating_add(HALF - 1));
            }
        }
        self.steady = steady;
        self.lapsed_from = lapsed_from;
        self.lapsed_until = lapsed_until;
        self.from = from.max(lapsed_from);
        self.until = until.min(lapsed_until);
        steady
    }

    /// Records that connection `bit` accepted a frame at `now`, its flag now `flag` and its
    /// activity ending at `end`. Narrows the interval to what the connection's new state allows;
    /// does not evaluate.
    #[inline]
    fn accepted(&mut self, bit: u32, flag: bool, end: u64, now: Instant) {
        if flag {
            self.flagged |= bit;
            self.steady |= bit;
            // Active in [now − 2^63, end].
            self.until = self.until.min(end);
            let at = now.as_micros();
            if at >= HALF {
                self.from = self.from.max(at - HALF);
            }
        } else {
            // Unflagged: inactive at every instant, whatever the intervals.
            self.flagged &= !bit;
            self.steady &= !bit;
        }
    }

    /// The connection selected under `active`: the kept answer if the mask is the last one,
    /// else a walk (kept for the next frame).
    #[inline]
    fn decide(&mut self, steps: &[Step], active: u32) -> Option<u8> {
        if active != self.decided_for {
            self.decided_for = active;
            self.decided = decide(self.steps(steps), self.root, active);
        }
        self.decided
    }

    /// Inactive, no connection flagged; the decision for the empty mask.
    fn idle(&mut self) {
        self.flagged = 0;
        self.steady = 0;
        self.from = 0;
        self.until = u64::MAX;
        self.lapsed_from = 0;
        self.lapsed_until = u64::MAX;
        self.decided_for = 0;
        // `decide` under the empty mask, without its walk: only an active connection can be
        // selected, and none is.
        self.decided = None;
    }
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
    groups: Vec<Eligibility<MAX_PEERS>, MAX_GROUPS>,
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
    /// Starts arbitrating with `table`, every connection at S = 0 and inactive.
    ///
    /// Validates the table again (it is cheap, and a `Table` can be deserialized without the
    /// loader), and fails with the first [`TableError`] found. Costs one pass over the table and
    /// the sort of its filters. [`Arbiter::new_in`] builds it in a place of the caller's instead.
    pub fn new(table: Table<PORTS, CONNECTIONS, NODES>) -> Result<Self, TableError> {
        let mut slot = None;
        match Self::new_in::<TableError, (), TableError>(&mut slot, |blank| {
            *blank = table;
            Ok(())
        }) {
            Ok(Ok(_)) => slot.ok_or(TableError::TooManyNodes),
            Ok(Err(error)) | Err(error) => Err(error),
        }
    }

    /// [`Arbiter::new`], built in `slot` with the table that `fill` writes into the (empty)
    /// table there, and left there: whatever `slot` held is replaced, by `None` when `fill`
    /// fails (its error, outside) or the table is refused (inside). Returns what `fill` did and
    /// the arbiter; an invalid table is refused with the verdict `R` ([`TableError`] says what is
    /// wrong, [`Refused`](crate::Refused) only that something is). For a caller with a place for
    /// it, as a node has for the arbiter that replaces its running one, and a table to decode:
    /// [`crate::image::load_into_as`].
    // Built where it stays, its table decoded where it stays: returned by value, the arbiter
    // was in the frames of both `new` and the node's loader (the table three times there), 87
    // KB of stack, more than the NUCLEO-G474RE had left with the schema server, and each move
    // was a copy of 10 or 25 KB. Left to be inlined: kept out of line, the loader's error went
    // through memory to the node, 256 bytes more of the NUCLEO-G474RE's flash.
    pub fn new_in<R: Verdict, T, E>(
        slot: &mut Option<Self>,
        fill: impl FnOnce(&mut Table<PORTS, CONNECTIONS, NODES>) -> Result<T, E>,
    ) -> Result<Result<(T, &mut Self), R>, E> {
        Self::build_in(slot, fill, true)
    }

    /// [`Arbiter::new_in`] with the table of the image `bytes`, decoded in place
    /// ([`crate::image::load_into_as`]): the image's header and the arbiter. The loader refuses
    /// an invalid table (its [`LoadError::Table`](crate::image::LoadError::Table)), so the
    /// table is not validated a second time; the verdict inside is the one [`Arbiter::new_in`]
    /// gives a table it cannot build.
    // The loader's validation is the arbiter's: a second pass (a call and its refusal) was 16
    // bytes of the NUCLEO-G474RE's flash.
    pub fn load_in<'a, R: Verdict>(
        slot: &'a mut Option<Self>,
        bytes: &[u8],
    ) -> Result<Result<(crate::image::Header, &'a mut Self), R>, crate::image::LoadError<R>> {
        Self::build_in(
            slot,
            |table| crate::image::load_into_as::<PORTS, CONNECTIONS, NODES, R>(bytes, table),
            false,
        )
    }

    /// [`Arbiter::new_in`], the table validated again only if `validate` (a table `fill` has
    /// validated is valid).
    #[inline(always)]
    fn build_in<R: Verdict, T, E>(
        slot: &mut Option<Self>,
        fill: impl FnOnce(&mut Table<PORTS, CONNECTIONS, NODES>) -> Result<T, E>,
        validate: bool,
    ) -> Result<Result<(T, &mut Self), R>, E> {
        // Part by part in place (the literal: empty lists are their lengths), not built aside
        // and moved: each move was code, reaching the parts at large offsets in a frame.
        let arbiter = slot.insert(Arbiter {
            ports: Vec::new(),
            index: FilterIndex::empty(),
            slots: Vec::new(),
            steps: Vec::new(),
            value_ports: PortSet::default(),
            values: Vec::new(),
            value_slots: Vec::new(),
            groups: Vec::new(),
            #[cfg(feature = "dynamics")]
            runs: Vec::new(),
            #[cfg(feature = "dynamics")]
            sources: Vec::new(),
            throttles: Throttles::default(),
            table: Table::new(),
        });
        let filled = match fill(&mut arbiter.table) {
            Ok(filled) => filled,
            Err(error) => {
                *slot = None;
                return Err(error);
            }
        };
        let checked = if validate {
            arbiter.table.check::<R>()
        } else {
            Ok(())
        };
        let built = match checked {
            Ok(()) => {
                arbiter.throttles = Throttles::new(arbiter.table.filters());
                arbiter
                    .build()
                    .ok_or_else(|| R::refuse(|| TableError::TooManyNodes))
            }
            Err(error) => Err(error),
        };
        if let Err(error) = built {
            *slot = None;
            return Ok(Err(error));
        }
        Ok(slot
            .as_mut()
            .map(|arbiter| (filled, arbiter))
            .ok_or_else(|| R::refuse(|| TableError::TooManyNodes)))
    }

    /// Builds the run-time form of `self.table`, which [`Table::validate`] accepted, into this
    /// arbiter's empty parts. Every `?` below but one is a capacity that a validated table
    /// cannot exceed (its own, which this arbiter shares; at most 16 ports of 32 connections;
    /// the value ports' and groups' fixed ones) or a parameter it has checked. They are kept (a
    /// `None`, never a panic) but no longer each with an error of its own: that was 108 bytes
    /// of the NUCLEO-G474RE's flash for paths no table takes. The one a validated table can
    /// take is more than 2^16 decision nodes before a port (a capacity `NODES` beyond 65 536;
    /// the steps' positions are `u16`): [`Arbiter::new`]'s [`TableError::TooManyNodes`], as
    /// before.
    fn build(&mut self) -> Option<()> {
        let Arbiter {
            ports,
            index,
            slots,
            steps,
            value_ports,
            values,
            value_slots,
            groups,
            #[cfg(feature = "dynamics")]
            runs,
            #[cfg(feature = "dynamics")]
            sources,
            throttles: _,
            table,
        } = self;
        for (position, parts) in table.parts().enumerate() {
            // At most 16 ports (a table's `CAPACITIES_FIT`): the cast keeps the index whole.
            let port = position as u8;
            let (record, views, nodes, roots) = parts?;
            let first_connection = u16::try_from(slots.len()).ok()?;
            push_slots(slots, views, port)?;
            let first_step = u16::try_from(steps.len()).ok()?;
            let end = usize::from(first_step).saturating_add(nodes.len());
            steps.resize(end, Step::NOBODY).ok()?;
            decision::compile(nodes, steps.get_mut(usize::from(first_step)..)?);
            let run = Port {
                first_connection,
                connections: u8::try_from(views.len()).ok()?,
                first_step,
                steps: u16::try_from(nodes.len()).ok()?,
                root: record.root(),
                // Idle (`Port::idle`): inactive, no connection flagged, nobody selected.
                flagged: 0,
                steady: 0,
                from: 0,
                until: u64::MAX,
                lapsed_from: 0,
                lapsed_until: u64::MAX,
                decided_for: 0,
                decided: None,
                external: 0,
            };
            ports.push(run).ok()?;
            if let Some(spec) = record.value() {
                let first = u8::try_from(value_slots.len()).ok()?;
                let own = slots.get(usize::from(first_connection)..).unwrap_or(&[]);
                push_value_slots(value_slots, own, roots)?;
                let count = u8::try_from(roots.len()).ok()?;
                values
                    .push(ValueState::new(port, first, count, spec))
                    .ok()?;
                *value_ports = value_ports.with(port);
            }
        }
        index.build(table.connections())?;
        // Validated: the filtered connections exist, at most MAX_FILTERED (< UNFILTERED) of them.
        for (position, &connection) in table.filters().connections.iter().enumerate() {
            if let Some(slot) = slots.get_mut(usize::from(connection)) {
                slot.filter = position as u8;
            }
        }
        // Validated with the table (`Group::validate`): `Eligibility::new`'s checks again were
        // 28 bytes of the NUCLEO-G474RE's flash.
        for group in table.groups() {
            groups.push(Eligibility::of(group)).ok()?;
        }
        // Each group started where it lives (`GroupRun::start`; built and moved, it was copied),
        // its parameters validated with the table. The blanks in one `resize`, cleared in
        // place: pushed one at a time they were copied from a 3.4 KiB constant of zeros that
        // LLVM kept in the flash.
        #[cfg(feature = "dynamics")]
        runs.resize(table.dynamics().len(), GroupRun::BLANK).ok()?;
        #[cfg(feature = "dynamics")]
        for (run, spec) in runs.iter_mut().zip(table.dynamics()) {
            run.start(spec);
        }
        // The sources, all unheard, in one `resize`: a push per source was 8 bytes more of the
        // NUCLEO-G474RE's flash.
        #[cfg(feature = "dynamics")]
        sources
            .resize(table.gate_sources().len(), SourceState::new())
            .ok()?;
        Some(())
    }

    /// The table in use.
    pub fn table(&self) -> &Table<PORTS, CONNECTIONS, NODES> {
        &self.table
    }

    /// Switches every HBBA filter to profile `profile` of the table (0: all closed, as after
    /// [`Arbiter::new`]). Fails, changing nothing, with [`CommandError::NoFilters`] on a table
    /// without filters and [`CommandError::NoSuchProfile`]. Costs one pass over the filters.
    pub fn set_filter_profile(&mut self, profile: u8) -> Result<(), CommandError> {
        self.throttles.set_profile(self.table.filters(), profile)
    }

    /// Sets the HBBA filter of connection `connection` of port `port` to φ = `phi` (0 closes, 1
    /// passes every frame, N one in N; the next frame passes unless φ = 0). Fails, changing
    /// nothing, with [`CommandError::NoFilters`] on a table without filters and
    /// [`CommandError::NotFiltered`] for a connection without a filter.
    pub fn set_filter(&mut self, port: u8, connection: u8, phi: u8) -> Result<(), CommandError> {
        let position = self
            .slot_of(port, connection)
            .map(|slot| slot.filter)
            .filter(|&f| f != UNFILTERED)
            .map(usize::from);
        self.throttles.set(position, phi)
    }

    /// φ of the HBBA filter of connection `connection` of port `port`, or `None` if it has none.
    pub fn filter_phi(&self, port: u8, connection: u8) -> Option<u8> {
        let slot = self.slot_of(port, connection)?;
        self.throttles
            .get(usize::from(slot.filter))
            .map(|t| t.phi())
    }

    /// The HBBA filter profile last switched to, or `None` once a single filter changed since.
    pub fn filter_profile(&self) -> Option<u8> {
        self.throttles.profile()
    }

    /// How many connections have a filter, and how many of them are closed or throttled.
    pub fn filter_counts(&self) -> FilterCounts {
        self.throttles.counts()
    }

    /// Whether the table gives some connection an HBBA filter.
    pub fn has_filters(&self) -> bool {
        !self.table.filters().is_empty()
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
    /// Call it on a freshly built arbiter (its own state is replaced). Costs one comparison of
    /// a connection (filter and parameters) per connection of this table, and a port reset per
    /// port; no allocation.
    // Out of line: inlined into the node's table swap, where both arbiters are far down its
    // frame, it took 68 bytes more of the NUCLEO-G474RE's flash with competitive dynamics, 76
    // without. Run once per table swap.
    #[inline(never)]
    pub fn carry_over(&mut self, previous: &Self) -> usize {
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
            if let (Some(old_slot), Some(old_connection)) = (
                previous.slots.get(old),
                previous.table.connections().get(old),
            ) && old_connection == connection
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
            self.table.filters() == previous.table.filters(),
        );
        carried
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
        // A frame its HBBA filter drops never came, for this connection.
        if slot.filter != UNFILTERED && !self.throttles.pass(slot.filter) {
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
    #[inline(never)]
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

    /// Arbitrates `frame`, which arrived at `now`, as [`Arbiter::receive`] does, and takes its
    /// value at the value ports it feeds: `on_value` gets each value port's output when the
    /// frame changes it ([`crate::value_port`]). What every runner calls.
    ///
    /// Cost: [`Arbiter::receive`] plus one test on a table without value ports; per value port
    /// fed, a filter test per connection of the port, the fields read once and the frame copied
    /// into each connection it feeds, a decision walk per connection of the port only when the
    /// port's activity changed since its last combination, and two passes over its connections
    /// (docs/figures.md, "Cortex-M4").
    pub fn receive_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
        on_verdict: impl FnMut(&PortVerdict),
        mut on_value: impl FnMut(&Combined),
    ) -> FrameReception {
        let reception = self.receive(&frame.id(), now, on_verdict);
        let mut result = FrameReception {
            fed: reception.fed,
            delivered: reception.delivered,
            ..FrameReception::default()
        };
        if reception.fed.bits() & self.value_ports.bits() != 0 {
            self.take_values(frame, now, &mut result, &mut on_value);
        }
        result
    }

    /// Stores `frame` at the value ports it fed (`result.fed`) and combines them. The
    /// connections it fed there are found again by their filters (at most
    /// [`MAX_VALUE_CONNECTIONS`] tests), so that [`Arbiter::receive`] needs no observer of its
    /// own: the arbitration is compiled once whatever the caller. Out of line and not generic:
    /// one copy in flash.
    #[inline(never)]
    fn take_values(
        &mut self,
        frame: &Frame,
        now: Instant,
        result: &mut FrameReception,
        on_value: &mut dyn FnMut(&Combined),
    ) {
        let id = frame.id();
        for position in 0..self.values.len() {
            let Some(state) = self.values.get_mut(position) else {
                continue;
            };
            let port = state.port;
            if !result.fed.contains(port) {
                continue;
            }
            let Some(record) = self.ports.get(usize::from(port)) else {
                continue;
            };
            let first = usize::from(record.first_connection);
            let connections = self
                .table
                .connections()
                .get(first..first.saturating_add(usize::from(record.connections)))
                .unwrap_or(&[]);
            let mut fed = 0u32;
            let slots = self.slots.get(first..).unwrap_or(&[]);
            for (index, (connection, slot)) in connections.iter().zip(slots).enumerate() {
                // A frame the connection's HBBA filter dropped was not taken there either.
                if connection.filter.matches(&id) && self.throttles.last_passed(slot.filter) {
                    fed |= 1u32.checked_shl(index as u32).unwrap_or(0);
                }
            }
            if !state.store(&mut self.value_slots, fed, frame, now) {
                result.refused = result.refused.with(port);
            }
            if self.combine(position, now, on_value) {
                result.combined = result.combined.with(port);
            }
        }
    }

    /// Re-evaluates the value ports whose deadline has passed at `now` (a value that aged out,
    /// an activity that ended) and hands `on_value` each output that changed. Returns the ports
    /// whose output changed (also when it became "nothing", which delivers no frame). Call it
    /// at [`Arbiter::deadline`]; calling it earlier does no harm. Costs a comparison per value
    /// port, and what a frame's combination costs per port due.
    pub fn poll(&mut self, now: Instant, mut on_value: impl FnMut(&Combined)) -> PortSet {
        if self.values.is_empty() {
            return PortSet::default();
        }
        self.poll_values(now, &mut on_value)
    }

    /// [`Arbiter::poll`] on a table with value ports. Out of line and not generic.
    #[inline(never)]
    fn poll_values(&mut self, now: Instant, on_value: &mut dyn FnMut(&Combined)) -> PortSet {
        let mut changed = PortSet::default();
        for position in 0..self.values.len() {
            let Some(state) = self.values.get(position) else {
                continue;
            };
            let port = state.port;
            if state.due.is_some_and(|due| now.micros_since(due).is_some())
                && self.combine(position, now, on_value)
            {
                changed = changed.with(port);
            }
        }
        changed
    }

    /// Whether a value port's deadline has passed at `now`: [`Arbiter::poll`] would re-evaluate
    /// it. Costs a test on a table without value ports, a comparison per value port otherwise.
    #[inline]
    pub fn is_due(&self, now: Instant) -> bool {
        self.values
            .iter()
            .any(|state| state.due.is_some_and(|due| now.micros_since(due).is_some()))
    }

    /// The earliest instant at which a value port's output may change without a frame, seen
    /// from `now` (an instant already passed counts as `now`); `None` without value ports or
    /// values. Costs a comparison per value port.
    pub fn deadline(&self, now: Instant) -> Option<Instant> {
        let mut earliest = Earliest::new(now);
        for due in self.values.iter().filter_map(|state| state.due) {
            earliest.offer(due);
        }
        earliest.get()
    }

    /// Whether port `port` is a value port.
    pub fn is_value_port(&self, port: u8) -> bool {
        self.value_ports.contains(port)
    }

    /// Value port `port`'s current output, as last evaluated (by a frame or [`Arbiter::poll`]):
    /// the connection whose frame it handed over and the combined value; `None` while it has no
    /// contributor, and for a port that is not a value port. Read-only; a look-up among at most
    /// [`MAX_VALUE_PORTS`].
    pub fn output(&self, port: u8) -> Option<(u8, i64)> {
        self.values
            .iter()
            .find(|state| state.port == port)
            .and_then(ValueState::output)
    }

    /// Combines value port `position` (among the value ports) at `now`; hands a changed output to
    /// `on_value`. Returns whether the output changed.
    #[inline(never)]
    fn combine(
        &mut self,
        position: usize,
        now: Instant,
        on_value: &mut dyn FnMut(&Combined),
    ) -> bool {
        let Some(state) = self.values.get_mut(position) else {
            return false;
        };
        let Some(port) = self.ports.get_mut(usize::from(state.port)) else {
            return false;
        };
        let active = port.update_activity(&self.slots, now);
        // Which connections their own rules let through: a function of the activity alone,
        // walked again only when it changed since the last combination.
        if active != state.decided_for {
            let steps = port.steps(&self.steps);
            let mut lets_through = 0u32;
            for (index, slot) in state.slots(&self.value_slots).iter().enumerate() {
                if decide(steps, slot.root, active) == u8::try_from(index).ok() {
                    lets_through |= 1u32.checked_shl(index as u32).unwrap_or(0);
                }
            }
            state.decided_for = active;
            state.lets_through = lets_through;
        }
        // The next instant an activity of the port ends: one after a flagged connection's end.
        let at = now.as_micros();
        let mut due = Earliest::new(now);
        for slot in port.slots(&self.slots) {
            let end = slot.end();
            if slot.integrator.active_flag() && end >= at && end < u64::MAX {
                due.offer(Instant::from_micros(end.saturating_add(1)));
            }
        }
        state.combine(&self.value_slots, state.lets_through, due, now, on_value)
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

/// Broadcast of Local Eligibility ([`crate::ble`]): the groups of the table, their claims as rule
/// variables. A table without groups pays nothing here but an emptiness test where the node calls
/// in.
impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// Whether the table has BLE groups.
    #[inline]
    pub fn has_groups(&self) -> bool {
        !self.groups.is_empty()
    }

    /// Whether [`Arbiter::observe`] has anything to do: the table has BLE groups (local
    /// readings) or runs dynamics groups (topic contexts). Two loads; the node tests it on every
    /// frame.
    #[inline]
    pub fn observes_frames(&self) -> bool {
        #[cfg(feature = "dynamics")]
        let runs = !self.runs.is_empty();
        #[cfg(not(feature = "dynamics"))]
        let runs = false;
        !self.groups.is_empty() || runs
    }

    /// A frame (not one of ours) after it was arbitrated at `now`, for what reads frames besides
    /// the ports: [`Arbiter::ble_frame`] and [`Arbiter::dynamics_frame`]. Out of line: inlined
    /// into the node's frame path, the two kept its registers busy on every frame, also on
    /// tables that have neither (6 to 11 instructions a frame on the arm node).
    #[inline(never)]
    pub fn observe(&mut self, frame: &Frame, now: Instant) {
        self.ble_frame(frame, now);
        #[cfg(feature = "dynamics")]
        self.dynamics_frame(frame, now);
    }

    /// A frame (not one of ours) seen at `now`: if it is on a group's local topic and carries the
    /// group's field, it is the node's own eligibility for that task. Call it for every frame
    /// the node arbitrates, after arbitrating it: the holding decision it may take reads the
    /// activity the frame left (the eligibility often comes in the same frame as the behaviour's
    /// output). Holding is decided again at each local reading, each claim heard and each
    /// [`Arbiter::ble_poll`] (at least once a period), not at every change of activity: a
    /// gated connection that becomes active is seen at the next of those. Costs a filter test per
    /// group.
    pub fn ble_frame(&mut self, frame: &Frame, now: Instant) {
        if self.groups.is_empty() {
            return;
        }
        let mut changed = false;
        for (state, group) in self.groups.iter_mut().zip(self.table.groups()) {
            if group.local.matches(&frame.id())
                && let Some(value) = group.field.read(frame.payload())
            {
                state.on_local(value, now);
                changed = true;
            }
        }
        if changed {
            self.refresh_claims(now);
        }
    }

    /// A peer's claim heard at `now` (a claim of a group the node is not in is ignored). Fails
    /// when the claim carries this node's own id or finds no room ([`BleError`]); the claims
    /// kept then decide as before.
    pub fn on_claim(&mut self, claim: Claim, now: Instant) -> Result<(), BleError> {
        let mut outcome = Ok(());
        for state in self.groups.iter_mut() {
            if state.group() == claim.group {
                outcome = state.on_peer(claim, now);
            }
        }
        self.refresh_claims(now);
        outcome
    }

    /// The claims due at `now`, each handed to `send` with the eligibility this node offers;
    /// and the holding decisions brought up to `now` (claims that went stale).
    pub fn ble_poll(&mut self, now: Instant, mut send: impl FnMut(Claim)) {
        for position in 0..self.groups.len() {
            let offered = self.offered(position, now);
            if let Some(claim) = self
                .groups
                .get_mut(position)
                .and_then(|state| state.broadcast(offered, now))
            {
                send(claim);
            }
        }
        self.refresh_claims(now);
    }

    /// The next instant at which [`Arbiter::ble_poll`] has work: a claim due, or one going stale.
    pub fn ble_deadline(&self, now: Instant) -> Option<Instant> {
        if self.groups.is_empty() {
            return None;
        }
        // A fold from the largest offset rather than `min`, which would inline `due_in` twice
        // (once for the first group, once for the rest).
        let soonest = self
            .groups
            .iter()
            .fold(u64::MAX, |soonest, state| soonest.min(state.due_in(now)));
        Some(now.wrapping_add_micros(soonest))
    }

    /// Whether this node holds group `position`'s task (in the table's order), as last decided.
    pub fn holds(&self, position: usize) -> bool {
        self.table.groups().get(position).is_some_and(|group| {
            group.ports.iter().any(|entry| {
                self.ports
                    .get(usize::from(entry.port))
                    .is_some_and(|port| port.external & bit(entry.claim) != 0)
            })
        })
    }

    /// The eligibility the node offers for group `position` at `now`: its own fresh reading while
    /// one of the group's gated connections would deliver with the claim taken as held, else 0.
    fn offered(&self, position: usize, now: Instant) -> u16 {
        let (Some(state), Some(group)) =
            (self.groups.get(position), self.table.groups().get(position))
        else {
            return 0;
        };
        let Some(own) = state.own(now) else {
            return 0;
        };
        let candidate = group.ports.iter().any(|entry| {
            self.selected_holding(entry.port, now, bit(entry.claim))
                .is_some_and(|winner| entry.gated & bit(winner) != 0)
        });
        if candidate { own } else { 0 }
    }

    /// Sets every group's claim connections to whether the node holds its task at `now`.
    fn refresh_claims(&mut self, now: Instant) {
        for position in 0..self.groups.len() {
            let offered = self.offered(position, now);
            let held = self
                .groups
                .get(position)
                .is_some_and(|state| state.holds(offered, now));
            let Some(group) = self.table.groups().get(position) else {
                continue;
            };
            for entry in &group.ports {
                if let Some(port) = self.ports.get_mut(usize::from(entry.port)) {
                    let claim = bit(entry.claim);
                    port.external = (port.external & !claim) | if held { claim } else { 0 };
                }
            }
        }
    }
}

/// A value port's slots, its connections' τ (`own`) with their `roots`, appended to
/// `value_slots`.
// Out of line: inlined into `Arbiter::build`, deep in the node's loader, each slot's fields were
// reached through addresses kept on the stack, 36 bytes more of the NUCLEO-G474RE's flash. Run
// once per value port and table.
#[inline(never)]
fn push_value_slots(
    value_slots: &mut Vec<ValueSlot, MAX_VALUE_CONNECTIONS>,
    own: &[Slot],
    roots: &[NodeRef],
) -> Option<()> {
    for (slot, &root) in own.iter().zip(roots) {
        value_slots.push(ValueSlot::new(slot.tau, root)).ok()?;
    }
    Some(())
}

/// The slots of port `port`, its connections `views` (validated with the table) at S = 0,
/// appended to `slots`.
// Out of line: inlined into `Arbiter::build`, deep in the node's loader, each slot's fields were
// reached through addresses kept on the stack, 72 bytes more of the NUCLEO-G474RE's flash. Run
// once per port and table.
#[inline(never)]
fn push_slots<const CONNECTIONS: usize>(
    slots: &mut Vec<Slot, CONNECTIONS>,
    views: &[Connection],
    port: u8,
) -> Option<()> {
    for (index, connection) in views.iter().enumerate() {
        // `Runtime::new` less the checks `table.validate()` made: they cannot fail again, and
        // inlined a second time they took 160 bytes of the NUCLEO-G474RE's flash. The decay's
        // (τ > 0, validated too) is kept.
        let (tau, reciprocal) = Decay::new(connection.stimulation.decay_us())?.parts();
        let slot = Slot {
            integrator: Integrator::new(),
            reciprocal,
            tau,
            gain: connection.stimulation.gain(),
            rest_us: connection.stimulation.rest_us(),
            port,
            index: u8::try_from(index).ok()?,
            filter: UNFILTERED,
        };
        slots.push(slot).ok()?;
    }
    Some(())
}

/// Bit `index` of a mask (0 for an index of 32 or more).
#[inline]
fn bit(index: u8) -> u32 {
    1u32.checked_shl(u32::from(index)).unwrap_or(0)
}

/// The decision of a port (its `steps`, entered at `root`) under `active`. Only an active
/// connection can be selected (x_i ∧ Φ_i(x)): a valid diagram may still name an inactive one
/// (e.g. a root that is a terminal).
#[inline]
fn decide(steps: &[Step], root: NodeRef, active: u32) -> Option<u8> {
    let active = ConnectionSet::from_bits(active);
    decision::walk(steps, root, active).filter(|&index| active.contains(index))
}

#[cfg(test)]
mod tests {
    use super::*;
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
