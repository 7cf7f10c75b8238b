//! Value ports in the arbiter ([`crate::value_port`]): each frame a value port's connections
//! take, their combination when it changes, and the deadlines at which a value ages out.

use super::{Arbiter, FrameReception, PortSet, PortVerdict, decide};
use crate::frame::Frame;
use crate::time::Instant;
use crate::value_port::{Combined, Earliest, ValueState};

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
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
    /// [`MAX_VALUE_CONNECTIONS`](crate::value_port::MAX_VALUE_CONNECTIONS) tests), so that [`Arbiter::receive`] needs no observer of its
    /// own: the arbitration is compiled once whatever the caller. Not generic: one copy in
    /// flash.
    // Left to the inliner (its one caller on a board): out of line it took 196 bytes more of
    // the NUCLEO-G474RE's flash, 72 of the emulated board's; the counted frames
    // (scripts/cortex-m4-cost.sh, value ports included) cost the same either way.
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

    /// [`Arbiter::poll`] on a table with value ports. Not generic.
    // Left to the inliner (its one caller on a board): out of line it took 16 bytes more of
    // the NUCLEO-G474RE's flash, 28 of the emulated board's.
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

    /// Whether the table has value ports (whose outputs [`Arbiter::is_due`] and
    /// [`Arbiter::poll`] look after).
    pub fn has_values(&self) -> bool {
        !self.values.is_empty()
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
    /// [`MAX_VALUE_PORTS`](crate::value_port::MAX_VALUE_PORTS).
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
}
