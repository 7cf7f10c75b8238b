//! Competitive dynamics in the arbiter ([`crate::dynamics`]): the groups the node runs, stepped
//! by [`Arbiter::dynamics_poll`], and the gates as rule variables. A gate connection is active
//! while its behaviour's gate is open (its own group's, as stepped here; another node's, as its
//! last [`Gates`] frame says, closed once the group has been silent for [`Gates::SILENCE_US`]).
//! A table without dynamics pays an emptiness test where the node calls in.

use super::{Arbiter, bit};
use crate::dynamics::{GateError, OWN, StepView};
use crate::frame::Frame;
use crate::protocol::Gates;
use crate::time::Instant;

/// A gate source that went silent: the node reports it (a `GatesLost` fault).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GatesLost {
    /// The node that runs the group.
    pub owner: u8,
    /// The group's number.
    pub group: u8,
}

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// Whether the table runs or reads any dynamics group.
    #[inline]
    pub fn has_dynamics(&self) -> bool {
        !self.runs.is_empty() || !self.sources.is_empty()
    }

    /// A frame (not one of ours) seen at `now`: a reading for every topic context it feeds. Call
    /// it for every frame the node receives, with [`Arbiter::ble_frame`].
    pub fn dynamics_frame(&mut self, frame: &Frame, now: Instant) {
        for (run, spec) in self.runs.iter_mut().zip(self.table.dynamics()) {
            run.on_frame(spec, frame, now);
        }
    }

    /// Gates from node `owner` heard at `now`. Gates of a group the table does not read are
    /// ignored (`Ok`); a group read with another number of behaviours is refused
    /// ([`GateError::Count`]) and its gates stay as they were.
    // Out of line: inlined into the node's handling of a Gates frame, which keeps the frame's
    // fields for its fault, it took 50 bytes more of the NUCLEO-G474RE's flash.
    #[inline(never)]
    pub fn on_gates(&mut self, owner: u8, gates: &Gates, now: Instant) -> Result<(), GateError> {
        if owner == OWN {
            return Ok(());
        }
        let mut outcome = Ok(());
        for (state, source) in self.sources.iter_mut().zip(self.table.gate_sources()) {
            if source.owner == owner && source.group == gates.group {
                outcome = state.on_gates(source, gates, now);
            }
        }
        self.apply_gates();
        outcome
    }

    /// Brings the dynamics up to `now`: every group the node runs takes the steps due (`view`
    /// sees each, `send` gets the gates to broadcast), and every group read from another node
    /// that has fallen silent closes its gates (`lost` hears of it once). Then the gate
    /// connections follow the gates.
    pub fn dynamics_poll(
        &mut self,
        now: Instant,
        mut view: impl FnMut(StepView<'_>),
        mut send: impl FnMut(Gates),
        mut lost: impl FnMut(GatesLost),
    ) {
        // No test of `has_dynamics` here: on a table without groups every loop below is empty,
        // and the node tests it before calling (a second test was 20 bytes of a board's flash).
        let ports = &self.ports;
        let slots = &self.slots;
        let activity = |port: u8, connection: u8, at: Instant| {
            ports.get(usize::from(port)).is_some_and(|record| {
                (record.activity(slots, at) | record.external) & bit(connection) != 0
            })
        };
        for (position, (run, spec)) in self.runs.iter_mut().zip(self.table.dynamics()).enumerate() {
            run.poll(spec, position, now, &activity, &mut view, &mut send);
        }
        for (state, source) in self.sources.iter_mut().zip(self.table.gate_sources()) {
            if source.owner == OWN {
                // The run knows its number: no walk over the table's groups beside the runs.
                let own = self.runs.iter().find(|run| run.number() == source.group);
                state.mask = own.map_or(0, |run| run.gates());
            } else if state.poll(now) {
                lost(GatesLost {
                    owner: source.owner,
                    group: source.group,
                });
            }
        }
        self.apply_gates();
    }

    /// The next instant at which [`Arbiter::dynamics_poll`] has work: a step, a repeat of the
    /// gates, or a source going silent.
    pub fn dynamics_deadline(&self, now: Instant) -> Option<Instant> {
        let mut soonest: Option<Instant> = None;
        // One candidate at a time, so that the comparison is written once: on a tie the
        // candidate (the same instant) is kept.
        let mut consider = |due: Instant| {
            if soonest.is_none_or(|soonest| soonest.micros_since(due).is_some()) {
                soonest = Some(due);
            }
        };
        for run in self.runs.iter() {
            // A group not started yet starts at the next poll.
            consider(run.deadline().unwrap_or(now));
        }
        for (state, source) in self.sources.iter().zip(self.table.gate_sources()) {
            if source.owner != OWN {
                // A source not polled yet starts its silence at the next poll.
                let due = if state.is_started() {
                    state.deadline()
                } else {
                    Some(now)
                };
                if let Some(due) = due {
                    consider(due);
                }
            }
        }
        soonest
    }

    /// The groups the node runs, in the table's order: their state and gates.
    pub fn dynamics_runs(&self) -> &[crate::dynamics::GroupRun] {
        &self.runs
    }

    /// The gates of gate source `position` (in the table's order) as the node reads them.
    pub fn source_gates(&self, position: usize) -> Option<u32> {
        self.sources.get(position).map(|state| state.mask)
    }

    /// Sets every gate connection to its gate.
    fn apply_gates(&mut self) {
        for link in self.table.gate_links() {
            let open = self
                .sources
                .get(usize::from(link.source))
                .is_some_and(|state| state.mask & bit(link.behaviour) != 0);
            if let Some(port) = self.ports.get_mut(usize::from(link.port)) {
                if open {
                    port.external |= bit(link.connection);
                } else {
                    port.external &= !bit(link.connection);
                }
            }
        }
    }
}
