//! Broadcast of Local Eligibility in the arbiter ([`crate::ble`]).

use super::{Arbiter, bit};
use crate::ble::{BleError, Claim};
use crate::frame::Frame;
use crate::time::Instant;

/// Broadcast of Local Eligibility ([`crate::ble`]): the groups of the table, their claims as rule
/// variables. A table without groups pays nothing here but an emptiness test where the node calls
/// in.
impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// Whether the table has BLE groups. Always false without the feature `ble` (whose loader
    /// refuses a table with groups): the node's claims, behind this test, are then left out of
    /// the build.
    #[inline]
    pub fn has_groups(&self) -> bool {
        cfg!(feature = "ble") && !self.groups.is_empty()
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
        self.has_groups() || runs
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
        if !self.has_groups() {
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
