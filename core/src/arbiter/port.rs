//! A port at run time and its connections' slots: what a frame reads and updates on its way
//! through the arbiter, kept so that the frame's cost does not grow with the node.

use crate::decay::Decay;
use crate::decision::{self, ConnectionSet, NodeRef, Step};
use crate::integrator::{Integrator, Stimulated};
use crate::level::Gain;
use crate::time::Instant;

/// One connection's run-time state and what a frame needs of its parameters, in one place: its
/// integrator, σ, τr, τ's evaluation form, and where it is (port, index in the port). 40 bytes:
/// τ's two parts are kept apart (a [`Decay`] would bring its padding).
#[derive(Clone, Copy, Debug)]
pub(super) struct Slot {
    pub(super) integrator: Integrator,
    /// τ's reciprocal ([`Decay`]).
    pub(super) reciprocal: u64,
    /// τ in µs ([`Decay`]).
    pub(super) tau: u32,
    pub(super) gain: Gain,
    pub(super) rest_us: u32,
    pub(super) port: u8,
    pub(super) index: u8,
    /// The position of the connection's HBBA filter among the node's ([`Throttles`](crate::hbba::filters::Throttles)), or
    /// [`UNFILTERED`](crate::hbba::filters::UNFILTERED).
    pub(super) filter: u8,
}

impl Slot {
    /// τ's evaluation form.
    #[inline(always)]
    pub(super) fn decay(&self) -> Decay {
        Decay::from_parts(self.tau, self.reciprocal)
    }

    /// Whether the connection is active at `now`.
    pub(super) fn is_active(&self, now: Instant) -> bool {
        self.integrator.is_active_with(&self.decay(), now)
    }

    /// The last accepted frame's instant, as a counter value.
    pub(super) fn last(&self) -> u64 {
        self.integrator.last().as_micros()
    }

    /// When its activity ends if it is active: its last accepted frame plus τ, saturated at the
    /// end of the counter (every later instant is then within τ; see [`Port`]).
    #[inline(always)]
    pub(super) fn end(&self) -> u64 {
        self.last().saturating_add(u64::from(self.tau))
    }

    /// Applies a frame at `now` (see [`Integrator::stimulate`]).
    #[inline(always)]
    pub(super) fn stimulate(&mut self, now: Instant) -> Stimulated {
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
/// [`Arbiter::activity`](super::Arbiter::activity) reads the same way without changing anything; the tests compare both
/// with a straightforward evaluation of every connection at every instant they look at.
///
/// **Decision.** The decision is a function of the activity alone: the last mask and what it
/// selected are kept, and a frame that leaves the mask as it was reuses the answer.
#[derive(Clone, Copy, Debug)]
pub(super) struct Port {
    pub(super) flagged: u32,
    pub(super) steady: u32,
    pub(super) from: u64,
    pub(super) until: u64,
    pub(super) lapsed_from: u64,
    pub(super) lapsed_until: u64,
    pub(super) decided_for: u32,
    pub(super) decided: Option<u8>,
    /// The claim connections of BLE groups this node holds ([`crate::ble`]): active whatever
    /// their integrators say (no frame feeds them), ORed into the mask the decision reads.
    pub(super) external: u32,
    pub(super) first_connection: u16,
    pub(super) connections: u8,
    pub(super) first_step: u16,
    pub(super) steps: u16,
    pub(super) root: NodeRef,
}

impl Port {
    /// The port's connections among all the slots.
    pub(super) fn slots<'a>(&self, slots: &'a [Slot]) -> &'a [Slot] {
        let first = usize::from(self.first_connection);
        slots
            .get(first..first.saturating_add(usize::from(self.connections)))
            .unwrap_or(&[])
    }

    /// The port's decision steps among all the steps.
    pub(super) fn steps<'a>(&self, steps: &'a [Step]) -> &'a [Step] {
        let first = usize::from(self.first_step);
        steps
            .get(first..first.saturating_add(usize::from(self.steps)))
            .unwrap_or(&[])
    }

    /// Whether `now` is in the steady interval.
    #[inline]
    pub(super) fn is_steady(&self, now: Instant) -> bool {
        let at = now.as_micros();
        self.from <= at && at <= self.until
    }

    /// The activity at `now`. Read-only: two comparisons in the steady interval, one activity
    /// test per flagged connection outside it.
    pub(super) fn activity(&self, slots: &[Slot], now: Instant) -> u32 {
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
    pub(super) fn update_activity(&mut self, slots: &[Slot], now: Instant) -> u32 {
        if self.is_steady(now) {
            self.steady
        } else {
            self.refresh(slots, now)
        }
    }

    /// After `until`: the connections of `steady` whose activity ended move out of it, and the
    /// interval is set again around `now`. Costs a comparison per connection of `steady`, and
    /// the bookkeeping of the lapsed intervals per connection that lapsed.
    ///
    /// Two passes, so that the first, over every connection of `steady`, keeps only `now`, the
    /// least time left and a mask in registers (one 64-bit subtraction and comparison each); the
    /// second, over the few that did not pass it, tells a lapse from a frame out of order and
    /// keeps the lapsed interval. In one pass the lapsed interval's four words were live across
    /// the loop and spilled: ~43 instructions a connection on the emulated board.
    #[inline(never)]
    pub(super) fn refresh(&mut self, slots: &[Slot], now: Instant) -> u32 {
        let at = now.as_micros();
        let all = slots;
        let slots = self.slots(all);
        // The least time left before one of those still active ends (32 bits: τ < 2^32), and
        // those that are not active by the plain test: lapsed, or out of order. Before the
        // intervals are read, so that none of them is held in a register across the loop.
        let (mut left, mut active, mut ended) = (u32::MAX, false, 0u32);
        let mut rest = self.steady;
        while rest != 0 {
            let index = rest.trailing_zeros();
            rest &= rest - 1;
            let Some(slot) = slots.get(index as usize) else {
                continue;
            };
            // Wrapping: a last frame after `now` makes it huge, as does one 2^32 µs before.
            let since = at.wrapping_sub(slot.last());
            match u32::try_from(since) {
                Ok(since) if since <= slot.tau => {
                    left = left.min(slot.tau - since);
                    active = true;
                }
                _ => ended |= 1 << index,
            }
        }
        if at < self.from || at < self.lapsed_from || at > self.lapsed_until {
            return self.recompute(all, now);
        }
        let (mut lapsed_from, mut lapsed_until) = (self.lapsed_from, self.lapsed_until);
        let mut rest = ended;
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
            // Lapsed: inactive until 2^63 after its last frame.
            lapsed_from = lapsed_from.max(slot.end().saturating_add(1));
            lapsed_until = lapsed_until.min(slot.last().saturating_add(HALF - 1));
        }
        self.steady &= !ended;
        self.lapsed_from = lapsed_from;
        self.lapsed_until = lapsed_until;
        // The earliest end among those still active is `now` plus the least time left
        // (saturated, as their ends are: each one's end is its last frame plus τ).
        let mut until = lapsed_until;
        if active {
            until = until.min(at.saturating_add(u64::from(left)));
        }
        self.from = self.from.max(lapsed_from);
        self.until = until;
        self.steady
    }

    /// Evaluates every flagged connection at `now` and sets both intervals around `now` (empty
    /// when a connection's last frame is after `now`: the next frame evaluates again).
    #[inline(never)]
    pub(super) fn recompute(&mut self, slots: &[Slot], now: Instant) -> u32 {
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
    pub(super) fn accepted(&mut self, bit: u32, flag: bool, end: u64, now: Instant) {
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
    pub(super) fn decide(&mut self, steps: &[Step], active: u32) -> Option<u8> {
        if active != self.decided_for {
            self.decided_for = active;
            self.decided = decide(self.steps(steps), self.root, active);
        }
        self.decided
    }

    /// Inactive, no connection flagged; the decision for the empty mask.
    pub(super) fn idle(&mut self) {
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

/// The decision of a port (its `steps`, entered at `root`) under `active`. Only an active
/// connection can be selected (x_i ∧ Φ_i(x)): a valid diagram may still name an inactive one
/// (e.g. a root that is a terminal).
#[inline]
pub(super) fn decide(steps: &[Step], root: NodeRef, active: u32) -> Option<u8> {
    let active = ConnectionSet::from_bits(active);
    decision::walk(steps, root, active).filter(|&index| active.contains(index))
}
