//! The dynamics at run time on a node: the groups it runs (stepped at their rate, their gates
//! broadcast) and the groups whose gates it reads from the bus.
//!
//! # Steps
//!
//! A group starts at the node's first poll, t_0. At t_k (k ≥ 1) the node takes the step from
//! t_(k−1) to t_k with the contexts it sampled at t_(k−1), then samples the contexts at t_k for
//! the next step; so the state at t_k is the state after k steps, a gate opens at the instant of
//! the step that opened it, and a frame at exactly t_k counts for the context sampled at t_k (the
//! node handles it before the poll; of several frames handled at t_k, the first: the node polls
//! after each). A poll that comes late takes every step due, up to
//! [`MAX_CATCH_UP`]; a longer backlog (the node stalled) is dropped, the group restarts its grid
//! at the poll (the contexts sampled there feed its next step), and [`GroupRun::skipped`] counts
//! the steps it lost.
//!
//! # Gates on the bus
//!
//! The owner sends [`Gates`] when the mask changes (at that step) and otherwise every
//! [`Gates::PERIOD_US`], the first at t_0. A reader that hears nothing from a group for
//! [`Gates::SILENCE_US`] (from its start or from the last frame) reads all its gates as closed
//! and reports the loss once, until the group is heard again.

use crate::frame::Frame;
use crate::protocol::Gates;
use crate::time::Instant;

use super::spec::{Context, GateSource, GroupSpec};
use super::{Dynamics, MAX_BEHAVIOURS, ONE, ParamsError};

/// The most steps a poll takes: a backlog beyond (a stalled node) is dropped.
pub const MAX_CATCH_UP: u32 = 100;

/// A group the node runs.
///
/// Memory: the [`Dynamics`] (about 2.7 KiB) and 12 bytes per behaviour of capacity.
#[derive(Clone, Debug)]
pub struct GroupRun {
    dynamics: Dynamics,
    number: u8,
    step_us: u64,
    /// t_k of the next step; `None` before the first poll.
    next: Option<Instant>,
    /// The contexts sampled at the last step's instant, for the next step.
    contexts: [i32; MAX_BEHAVIOURS],
    /// Per behaviour with a topic context: the last reading (already a context) and when.
    readings: [(i32, Instant); MAX_BEHAVIOURS],
    heard: u32,
    /// The mask last sent, and when the next repeat is due.
    sent: u32,
    repeat: Instant,
    changes: u8,
    skipped: u32,
}

/// What one step of a group looked like, for traces: the instant t_k, the contexts sampled at it
/// (fed to the step from t_k) and the state after k steps.
pub struct StepView<'a> {
    /// The group's position among the node's groups.
    pub group: usize,
    /// t_k.
    pub at: Instant,
    /// C_i at t_k, Q2.29.
    pub contexts: &'a [i32],
    /// The group after k steps.
    pub dynamics: &'a Dynamics,
}

impl GroupRun {
    /// The group of `spec` in its initial state, or why its parameters are invalid.
    pub fn new(spec: &GroupSpec) -> Result<GroupRun, ParamsError> {
        spec.params.validate()?;
        let mut run = GroupRun::BLANK;
        run.start(spec);
        Ok(run)
    }

    /// All zeros: what [`GroupRun::start`] fills in place.
    pub(crate) const BLANK: GroupRun = GroupRun {
        dynamics: Dynamics::BLANK,
        number: 0,
        step_us: 0,
        next: None,
        contexts: [0; MAX_BEHAVIOURS],
        readings: [(0, Instant::from_micros(0)); MAX_BEHAVIOURS],
        heard: 0,
        sent: 0,
        repeat: Instant::from_micros(0),
        changes: 0,
        skipped: 0,
    };

    /// [`GroupRun::new`] written into `self`, a [`GroupRun::BLANK`], for a validated `spec`
    /// (see [`Dynamics::start`]).
    // Out of line: inlined into `Arbiter::build`, it took 52 bytes more of the NUCLEO-G474RE's
    // flash. Run once per group and table.
    #[inline(never)]
    pub(crate) fn start(&mut self, spec: &GroupSpec) {
        self.dynamics.start(&spec.params);
        self.number = spec.number;
        self.step_us = u64::from(spec.params.step_us);
    }

    /// The integrator and its state.
    pub fn dynamics(&self) -> &Dynamics {
        &self.dynamics
    }

    /// The gates: bit i set while behaviour i's gate is open.
    pub fn gates(&self) -> u32 {
        self.dynamics.gates()
    }

    /// The group's number in the network.
    pub fn number(&self) -> u8 {
        self.number
    }

    /// The last step taken, as the poll's `view` saw it (`position`: the group's position among
    /// the node's groups): t_k, the contexts sampled at t_k and the state after k steps; t_0 and
    /// the initial state after the first poll, `None` before it. After a backlog was dropped, the
    /// poll's instant and the contexts sampled there.
    ///
    /// For an observer that reads the node between its polls (the simulator's traces) instead of
    /// taking part in them: it sees every step when the node is polled at each step's instant,
    /// as [`GroupRun::deadline`] asks.
    pub fn last_step(&self, position: usize) -> Option<StepView<'_>> {
        let next = self.next?;
        let at = Instant::from_micros(next.as_micros().wrapping_sub(self.step_us));
        Some(self.view(position, at))
    }

    /// Steps dropped because a poll came more than [`MAX_CATCH_UP`] steps late.
    pub fn skipped(&self) -> u32 {
        self.skipped
    }

    /// A frame seen at `now`: a reading for each topic context whose filter it matches.
    // Out of line: inlined into `Arbiter::observe`, the walk over the groups and their contexts
    // kept four running pointers on the stack, 96 bytes more of the NUCLEO-G474RE's flash. A
    // table with groups pays a call per group and frame; one without, nothing.
    #[inline(never)]
    pub fn on_frame(&mut self, spec: &GroupSpec, frame: &Frame, now: Instant) {
        let id = frame.id();
        for (b, context) in spec.contexts.iter().enumerate() {
            if let Context::Topic {
                filter,
                field,
                scale,
                ..
            } = context
                && filter.matches(&id)
                && let Some(reading) = self.readings.get_mut(b)
            {
                let value = field.read(frame.payload()).unwrap_or(0);
                *reading = (Context::of_value(value, *scale), now);
                self.heard |= 1 << b;
            }
        }
    }

    /// When the next poll has work: the next step, or the next repeat of the gates if sooner.
    pub fn deadline(&self) -> Option<Instant> {
        let next = self.next?;
        Some(if self.repeat.micros_since(next).is_some() {
            next
        } else {
            self.repeat
        })
    }

    /// Takes the steps due at `now`. `activity(port, connection, at)` says whether a connection
    /// of the node is active at `at`; `view` sees each step's instant, contexts and state;
    /// `send` gets the gates to broadcast. Returns whether the gates changed.
    pub fn poll(
        &mut self,
        spec: &GroupSpec,
        position: usize,
        now: Instant,
        activity: &impl Fn(u8, u8, Instant) -> bool,
        view: &mut impl FnMut(StepView<'_>),
        send: &mut impl FnMut(Gates),
    ) -> bool {
        let before = self.dynamics.gates();
        let due = |at: Instant| now.micros_since(at).is_some();
        let mut next = match self.next {
            Some(next) => next,
            None => {
                // t_0: the initial state and its contexts; the first broadcast now.
                self.sample(spec, now, activity);
                view(self.view(position, now));
                self.repeat = now;
                now.wrapping_add_micros(self.step_us)
            }
        };
        let mut taken = 0;
        while due(next) {
            if taken == MAX_CATCH_UP {
                let behind = now.micros_since(next).unwrap_or(0) / self.step_us.max(1);
                let dropped = u32::try_from(behind).unwrap_or(u32::MAX).saturating_add(1);
                self.skipped = self.skipped.saturating_add(dropped);
                // The grid restarts at the poll: the next step takes the contexts of now, not
                // those of the last step taken (long past).
                self.sample(spec, now, activity);
                next = now.wrapping_add_micros(self.step_us);
                break;
            }
            let gates = self.dynamics.step(&self.contexts);
            if gates != self.sent {
                self.changes = self.changes.wrapping_add(1);
                self.broadcast(gates, next, send);
            }
            self.sample(spec, next, activity);
            view(self.view(position, next));
            next = next.wrapping_add_micros(self.step_us);
            taken += 1;
        }
        self.next = Some(next);
        if due(self.repeat) {
            self.broadcast(self.dynamics.gates(), now, send);
        }
        self.dynamics.gates() != before
    }

    fn broadcast(&mut self, mask: u32, at: Instant, send: &mut impl FnMut(Gates)) {
        send(Gates {
            group: self.number,
            behaviours: self.dynamics.len() as u8,
            mask,
            changes: self.changes,
        });
        self.sent = mask;
        self.repeat = at.wrapping_add_micros(Gates::PERIOD_US);
    }

    fn view(&self, position: usize, at: Instant) -> StepView<'_> {
        StepView {
            group: position,
            at,
            contexts: self.contexts.get(..self.dynamics.len()).unwrap_or(&[]),
            dynamics: &self.dynamics,
        }
    }

    /// C_i at `at` into `contexts`.
    fn sample(
        &mut self,
        spec: &GroupSpec,
        at: Instant,
        activity: &impl Fn(u8, u8, Instant) -> bool,
    ) {
        for (b, (context, out)) in spec
            .contexts
            .iter()
            .zip(self.contexts.iter_mut())
            .enumerate()
        {
            *out = match *context {
                Context::Constant(value) => value.min(ONE as u32) as i32,
                Context::Connection { port, connection } => {
                    if activity(port, connection, at) {
                        ONE
                    } else {
                        0
                    }
                }
                Context::Topic { timeout_us, .. } => match self.readings.get(b) {
                    Some(&(value, when)) if self.heard & (1 << b) != 0 => {
                        // A reading newer than `at` (heard while the node caught up) counts.
                        let fresh = at
                            .micros_since(when)
                            .is_none_or(|age| age <= u64::from(timeout_us));
                        if fresh { value } else { 0 }
                    }
                    _ => 0,
                },
            };
        }
    }
}

/// What a node knows of a group whose gates it reads.
#[derive(Clone, Copy, Debug)]
pub struct SourceState {
    /// The gates as the node reads them: all closed while the group is silent.
    pub mask: u32,
    /// When the group was last heard (or the node started reading it).
    since: Option<Instant>,
    /// Whether the group is reported lost (silent for [`Gates::SILENCE_US`]).
    pub lost: bool,
}

/// Why a gate frame was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum GateError {
    /// The group has another number of behaviours than the table says.
    Count,
}

impl core::fmt::Display for GateError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            GateError::Count => {
                "gates of a group with another number of behaviours than the table's"
            }
        })
    }
}

impl core::error::Error for GateError {}

impl SourceState {
    /// A group never heard yet: gates closed, the silence counted from the first poll.
    pub const fn new() -> SourceState {
        SourceState {
            mask: 0,
            since: None,
            lost: false,
        }
    }

    /// Gates from the group's owner, heard at `now`.
    pub fn on_gates(
        &mut self,
        source: &GateSource,
        gates: &Gates,
        now: Instant,
    ) -> Result<(), GateError> {
        if gates.behaviours != source.behaviours {
            return Err(GateError::Count);
        }
        self.mask = gates.mask;
        self.since = Some(now);
        self.lost = false;
        Ok(())
    }

    /// Closes the gates of a group silent at `now`; returns `true` the first time (the loss to
    /// report).
    pub fn poll(&mut self, now: Instant) -> bool {
        let since = *self.since.get_or_insert(now);
        let silent = now
            .micros_since(since)
            .is_some_and(|age| age >= Gates::SILENCE_US);
        if !silent || self.lost {
            return false;
        }
        self.mask = 0;
        self.lost = true;
        true
    }

    /// Whether the node has started counting the group's silence (its first poll).
    pub fn is_started(&self) -> bool {
        self.since.is_some()
    }

    /// When the group goes silent if nothing comes.
    pub fn deadline(&self) -> Option<Instant> {
        if self.lost {
            return None;
        }
        self.since
            .map(|since| since.wrapping_add_micros(Gates::SILENCE_US))
    }
}

impl Default for SourceState {
    fn default() -> Self {
        SourceState::new()
    }
}
