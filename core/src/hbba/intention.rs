//! The intention workspace as a state machine without I/O: desires in, a selection of strategies
//! and filter commands out. `pab-intent` runs it on the bus and `pabctl sim` in virtual time; both
//! use this code and nothing else decides what to select or in which order filters change.
//!
//! # What it does
//!
//! - Keeps the desires ([`Desires`]) heard in Desire frames, with their leases.
//! - When the intensity served for some class changes (a new desire, a withdrawal, a lease that
//!   ran out), solves ([`Solver`]); when the selection changes, plans the filters.
//! - **The filter plan.** Every connection named by some strategy has a filter on its node
//!   (a [`Target`]: node, port, connection in the port's order). The selection wants φ for it:
//!   the φ its selected strategy sets, or 0 (closed) when no selected strategy names it (DESIGN.md,
//!   "HBBA: decisions": connections named by a strategy start closed). Each filter whose node is
//!   not known to apply that φ gets FilterSet commands, in two phases: first every
//!   **reduction** (the new φ passes fewer frames than the node may be passing now: 0 passes
//!   the fewest, then the larger N), then, once every reduction is settled, every **increase**
//!   ("every disable before any enable"). What a node applies is known as a range, from the φ
//!   that passes fewest to the one that passes most: exact once acknowledged, closed to
//!   all-passing at start, widened by a command whose fate is unknown. A filter whose wanted φ
//!   lies strictly inside its range may be a reduction and an increase at once: phase 1 sets it
//!   to the least of the range (which can only reduce), phase 2 to the wanted φ.
//! - **Acknowledgement.** Each command carries a sequence number, which the node echoes in
//!   FilterStatus once applied; a `FilterRefused` fault echoes it for a command the node cannot
//!   apply (nothing changed there). A command is *settled* when acknowledged, refused, or given
//!   up after [`MAX_SENDS`] sends [`ACK_TIMEOUT_US`] apart. Phase 2 starts when every command of
//!   phase 1 is settled: a refused or lost disable cannot become possible by waiting, and holding
//!   the enables back would keep the new intention from ever running; both are reported
//!   ([`Event::Refused`], [`Event::GaveUp`]). Faults are rate-limited per code on the nodes (one
//!   frame per 100 ms, the latest detail and a count), so a refusal of sequence S settles as
//!   refused every command to that node sent up to S and not yet acknowledged. A refused φ is
//!   not asked again while the selection wants it: a node refuses for its table, and a new
//!   table or a restart (below) has every filter of the node commanded again.
//! - **Restarts.** A node's heartbeat whose uptime went back, or whose table version changed,
//!   means its filters are back to their boot state (closed): every filter of that node is
//!   commanded again, the closed ones included, and the other nodes' commands go on. The first
//!   heartbeat heard from a node commands again its filters that are not known to be in force
//!   and that it did not refuse (it was off when their commands went out, or has run under
//!   another intention node).
//!
//! # Profiles (not yet)
//!
//! A FilterProfile frame switches every filter of a node at once to one of the profiles its table
//! carries; table images carry no profiles yet, so every command is a FilterSet. When they do,
//! [`Workspace::next_command`] is where a profile replaces FilterSets: when the filters of one
//! node that have a command waiting in the current phase, together with that node's other
//! filters as they stand, equal one profile of its table, one FilterProfile command (with its
//! own sequence number, settling all of them) replaces those FilterSets. It may do so only within
//! a phase: a profile that reduces some filters and increases others would break the ordering.
//!
//! # Costs
//!
//! Fixed capacity: [`MAX_FILTERED`] filtered connections on [`MAX_FILTER_NODES`] nodes, the
//! desires of [`Desires`], [`MAX_EVENTS`] events waiting to be read (older ones are dropped and
//! counted): 5 456 bytes on x86-64 beside the instance it borrows (`core/tests/hbba_intention.rs`
//! holds it under 5.5 KiB). Every call is O(F) for F filtered connections, but
//! [`Workspace::poll`], which may solve (see [`Solver::solve`]).

use heapless::{Deque, Vec};

use super::{
    DEFAULT_BUDGET, Desires, HbbaError, Instance, Intensities, MAX_CLASSES, Selection, Solver,
};
use crate::protocol::{DesireFrame, Fault, FaultCode, FilterSet, FilterStatus, Heartbeat};
use crate::time::Instant;

pub use super::DesireError;

/// Filtered connections, at most: the connections the strategies of one network name.
pub const MAX_FILTERED: usize = 64;
/// Nodes with filtered connections, at most.
pub const MAX_FILTER_NODES: usize = 16;
/// Events held until read ([`Workspace::next_event`]).
pub const MAX_EVENTS: usize = 32;
/// How long a command waits for its FilterStatus before it is sent again: 250 ms, above the
/// nodes' fault rate limit (100 ms), so that a refusal delayed by it still arrives in time.
pub const ACK_TIMEOUT_US: u64 = 250_000;
/// How many times one command is sent before it is given up.
pub const MAX_SENDS: u8 = 3;

/// Where a filtered connection is: what a FilterSet addresses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Target {
    /// The connection as the instance's filters name it ([`super::FilterSetting::connection`]).
    pub connection: u16,
    /// The node id, 1..=127.
    pub node: u8,
    /// The port, in the node's order.
    pub port: u8,
    /// The connection, in the port's order.
    pub index: u8,
}

/// Why a workspace could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum IntentionError {
    /// The instance is invalid ([`Instance::validate`]).
    Instance(HbbaError),
    /// A strategy sets a φ above 255: FilterSet carries it in one byte.
    PhiTooLarge {
        /// The strategy.
        strategy: u8,
    },
    /// A connection some strategy filters has no [`Target`].
    MissingTarget {
        /// The connection.
        connection: u16,
    },
    /// Two targets for one connection.
    DuplicateTarget {
        /// The connection.
        connection: u16,
    },
    /// A target on a node id outside 1..=127.
    InvalidNode {
        /// The connection.
        connection: u16,
    },
    /// More filtered connections than [`MAX_FILTERED`].
    TooManyFilters,
    /// Filtered connections on more nodes than [`MAX_FILTER_NODES`].
    TooManyNodes,
}

impl core::fmt::Display for IntentionError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            IntentionError::Instance(error) => write!(f, "{error}"),
            IntentionError::PhiTooLarge { strategy } => write!(
                f,
                "strategy {strategy} sets a φ above 255 (FilterSet carries one byte)"
            ),
            IntentionError::MissingTarget { connection } => {
                write!(f, "filtered connection {connection} has no node and port")
            }
            IntentionError::DuplicateTarget { connection } => {
                write!(f, "filtered connection {connection} has two targets")
            }
            IntentionError::InvalidNode { connection } => write!(
                f,
                "filtered connection {connection} is on a node id outside 1..=127"
            ),
            IntentionError::TooManyFilters => write!(
                f,
                "the strategies filter more than {MAX_FILTERED} connections"
            ),
            IntentionError::TooManyNodes => write!(
                f,
                "the filtered connections are on more than {MAX_FILTER_NODES} nodes"
            ),
        }
    }
}

impl core::error::Error for IntentionError {}

/// A FilterSet to send to `node`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Command {
    /// The destination node id.
    pub node: u8,
    /// The command.
    pub set: FilterSet,
    /// Which phase it belongs to: reductions come first.
    pub reduction: bool,
    /// How many times it was sent, this time included (a resend keeps the sequence number).
    pub send: u8,
}

/// What happened, for a log or a plot: read with [`Workspace::next_event`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The selection changed: bit s set when strategy s runs, and its objective.
    Selected {
        /// The strategies.
        strategies: u64,
        /// Σ intensity × utility.
        objective: u64,
    },
    /// A solve failed; the previous selection stays.
    SolveFailed(HbbaError),
    /// A desire's lease ran out (at least one), so the intensities are looked at again.
    Expired,
    /// A node applied a command.
    Acknowledged {
        /// The filter.
        target: Target,
        /// Its φ now.
        phi: u8,
    },
    /// A node refused a command: its filter did not change.
    Refused {
        /// The filter.
        target: Target,
        /// The φ asked for.
        phi: u8,
        /// The fault's reason (detail byte 0: 1 no such profile, 2 not a filtered connection, 3
        /// the table has no message filters).
        why: u8,
    },
    /// A command went unanswered [`MAX_SENDS`] times: the filter's state is unknown.
    GaveUp {
        /// The filter.
        target: Target,
        /// The φ asked for.
        phi: u8,
    },
    /// A node restarted (or changed tables, or was heard first while its filters were not in
    /// force): its filters are commanded again.
    Restarted {
        /// The node id.
        node: u8,
    },
    /// Every command of the plan is settled.
    Settled {
        /// Of them, refused.
        refused: u8,
        /// Of them, given up.
        gave_up: u8,
    },
}

/// One filtered connection, as [`Workspace::filters`] shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterView {
    /// Where it is.
    pub target: Target,
    /// The φ the selection wants.
    pub wanted: u8,
    /// The φ its node is known to apply (`None`: not known exactly).
    pub known: Option<u8>,
    /// The φ of the command waiting for its acknowledgement (or to be sent), if any.
    pub commanded: Option<u8>,
}

/// Whether φ `a` passes strictly fewer frames than φ `b`: 0 passes none, then the larger N
/// passes fewer.
pub const fn passes_fewer(a: u8, b: u8) -> bool {
    match (a, b) {
        _ if a == b => false,
        (0, _) => true,
        (_, 0) => false,
        _ => a > b,
    }
}

/// A command not yet settled.
#[derive(Clone, Copy, Debug)]
struct Pending {
    phi: u8,
    sequence: u16,
    /// When it was last sent; `None`: to send.
    sent: Option<Instant>,
    sends: u8,
    reduction: bool,
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    target: Target,
    wanted: u8,
    /// What the node may be applying: from the φ that passes fewest to the one that passes most.
    least: u8,
    most: u8,
    pending: Option<Pending>,
    /// An increase waiting for phase 2.
    increase: bool,
    /// Send even if known to apply the wanted φ (a restarted node).
    force: bool,
    /// Its node answered its last command (applied or refused): it is there.
    answered: bool,
    /// The φ its node last refused: not asked again while the selection wants that φ (a node
    /// refuses for its table, which a restart or a new table changes, and then it is asked).
    refused: Option<u8>,
}

impl Slot {
    /// The φ the node applies, when known exactly.
    fn known(&self) -> Option<u8> {
        (self.least == self.most).then_some(self.least)
    }

    /// The node may also be applying `phi` (a command whose fate is unknown).
    fn widen(&mut self, phi: u8) {
        if passes_fewer(phi, self.least) {
            self.least = phi;
        }
        if passes_fewer(self.most, phi) {
            self.most = phi;
        }
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct NodeTrack {
    node: u8,
    /// The last heartbeat's uptime and table version (`None`: not heard yet).
    heard: Option<(u32, u32)>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Idle,
    Reducing,
    Increasing,
}

/// The intention workspace: desires, the selection, the filters and their commands.
#[derive(Debug)]
pub struct Workspace<'a> {
    solver: Solver<'a>,
    desires: Desires,
    /// The intensities the selection was solved for (`None`: not solved yet).
    served: Option<Intensities>,
    selection: Option<Selection>,
    strategies: u64,
    slots: Vec<Slot, MAX_FILTERED>,
    nodes: Vec<NodeTrack, MAX_FILTER_NODES>,
    stage: Stage,
    refused: u8,
    gave_up: u8,
    sequence: u16,
    /// A desire changed since the last poll: the next poll is due at once.
    dirty: bool,
    events: Deque<Event, MAX_EVENTS>,
    lost_events: u32,
    budget: u32,
}

fn bit64(index: usize) -> u64 {
    1u64.checked_shl(u32::try_from(index).unwrap_or(u32::MAX))
        .unwrap_or(0)
}

impl<'a> Workspace<'a> {
    /// A workspace for `instance`, whose filtered connections are at `targets` (targets of
    /// connections no strategy filters are ignored). Nothing is selected and nothing is known of
    /// the filters until the first [`Workspace::poll`], which closes every filter (no desire
    /// yet). Fails when the instance is invalid, a φ does not fit a byte, a filtered connection
    /// has no target or two, or capacities are exceeded. Costs [`Solver::new`] plus O(S · F · T).
    pub fn new(
        instance: &'a Instance,
        targets: &[Target],
    ) -> Result<Workspace<'a>, IntentionError> {
        let solver = Solver::new(instance).map_err(IntentionError::Instance)?;
        let mut slots: Vec<Slot, MAX_FILTERED> = Vec::new();
        let mut nodes: Vec<NodeTrack, MAX_FILTER_NODES> = Vec::new();
        for (index, strategy) in (0u8..).zip(instance.strategies.iter()) {
            for filter in &strategy.filters {
                if filter.phi > u16::from(u8::MAX) {
                    return Err(IntentionError::PhiTooLarge { strategy: index });
                }
                let connection = filter.connection;
                if slots.iter().any(|s| s.target.connection == connection) {
                    continue;
                }
                let mut found = targets.iter().filter(|t| t.connection == connection);
                let target = *found
                    .next()
                    .ok_or(IntentionError::MissingTarget { connection })?;
                if found.next().is_some() {
                    return Err(IntentionError::DuplicateTarget { connection });
                }
                if !(1..=crate::protocol::MAX_NODE_ID).contains(&target.node) {
                    return Err(IntentionError::InvalidNode { connection });
                }
                if !nodes.iter().any(|n| n.node == target.node) {
                    nodes
                        .push(NodeTrack {
                            node: target.node,
                            heard: None,
                        })
                        .map_err(|_| IntentionError::TooManyNodes)?;
                }
                slots
                    .push(Slot {
                        target,
                        wanted: 0,
                        least: 0,
                        most: 1,
                        pending: None,
                        increase: false,
                        force: false,
                        answered: false,
                        refused: None,
                    })
                    .map_err(|_| IntentionError::TooManyFilters)?;
            }
        }
        Ok(Workspace {
            solver,
            desires: Desires::new(instance.classes),
            served: None,
            selection: None,
            strategies: 0,
            slots,
            nodes,
            stage: Stage::Idle,
            refused: 0,
            gave_up: 0,
            sequence: 0,
            dirty: false,
            events: Deque::new(),
            lost_events: 0,
            budget: DEFAULT_BUDGET,
        })
    }

    /// Sets the solver's work budget, in search nodes ([`DEFAULT_BUDGET`] unless set).
    pub fn set_budget(&mut self, budget: u32) {
        self.budget = budget;
    }

    /// Marks every filter as known to apply `phi`: for a runner that knows the nodes' state (the
    /// simulator's nodes boot with every filter closed, φ 0). Call before the first poll.
    pub fn assume_filters(&mut self, phi: u8) {
        for slot in &mut self.slots {
            slot.least = phi;
            slot.most = phi;
        }
    }

    /// Takes a Desire frame from `source` heard at `now` ([`Desires::heard`]); returns whether
    /// the desires changed in a way the solver must see. The solve waits for the next
    /// [`Workspace::poll`], which [`Workspace::deadline`] then says is due now. Fails, changing
    /// nothing, on a class the network does not have, a zero lease, or a new desire when the
    /// workspace is full.
    pub fn on_desire(
        &mut self,
        source: u8,
        desire: &DesireFrame,
        now: Instant,
    ) -> Result<bool, DesireError> {
        let changed = self.desires.heard(
            source,
            desire.id,
            desire.class,
            desire.intensity,
            desire.lease_ms,
            now,
        )?;
        self.dirty |= changed;
        Ok(changed)
    }

    /// Takes a FilterStatus from node `source`: settles the command it acknowledges, if any is
    /// waiting (the increases may then be due: [`Workspace::next_command`]); returns whether one
    /// was. O(F).
    pub fn on_filter_status(&mut self, source: u8, status: &FilterStatus) -> bool {
        let Some(slot) = self.slots.iter_mut().find(|s| {
            // A late answer to an earlier send counts too (a resend keeps the number).
            s.target.node == source
                && s.pending
                    .is_some_and(|p| p.sends > 0 && p.sequence == status.sequence)
        }) else {
            return false;
        };
        let phi = slot.pending.map_or(slot.wanted, |p| p.phi);
        slot.pending = None;
        slot.least = phi;
        slot.most = phi;
        slot.answered = true;
        slot.refused = None;
        let target = slot.target;
        self.event(Event::Acknowledged { target, phi });
        self.advance();
        true
    }

    /// Takes a fault from node `source`: a `FilterRefused` settles as refused every command to
    /// that node sent up to the sequence number it echoes and not yet acknowledged (the node's
    /// rate limit may have folded several refusals into one frame). Returns how many. O(F).
    pub fn on_fault(&mut self, source: u8, fault: &Fault) -> u8 {
        if fault.code != FaultCode::FilterRefused {
            return 0;
        }
        let [why, _, _, s0, s1] = fault.detail;
        let last = u16::from_le_bytes([s0, s1]);
        // Sequence numbers grow by one per command, so "sent up to `last`" is a wrapping
        // distance below half the space.
        let sent_by = |sequence: u16| last.wrapping_sub(sequence) < 0x8000;
        let mut count = 0u8;
        let mut refusals: Vec<Event, MAX_FILTERED> = Vec::new();
        for slot in &mut self.slots {
            if slot.target.node != source {
                continue;
            }
            if let Some(p) = slot.pending
                && p.sends > 0
                && sent_by(p.sequence)
            {
                slot.pending = None;
                slot.answered = true;
                slot.refused = Some(p.phi);
                let _ = refusals.push(Event::Refused {
                    target: slot.target,
                    phi: p.phi,
                    why,
                });
                count = count.saturating_add(1);
            }
        }
        self.refused = self.refused.saturating_add(count);
        for event in refusals {
            self.event(event);
        }
        if count > 0 {
            self.advance();
        }
        count
    }

    /// Takes a heartbeat from node `source`. A restart (uptime back, another table version)
    /// commands all of its filters again, from their boot state (closed); the first heartbeat of
    /// a node commands again those of its filters not known to be in force that it did not
    /// refuse. Returns whether it did either. O(F) plus a plan.
    ///
    /// Uptime counts whole seconds: a node that restarts twice within its first second is seen
    /// restarting once (its table version aside).
    pub fn on_heartbeat(&mut self, source: u8, heartbeat: &Heartbeat) -> bool {
        let Some(track) = self.nodes.iter_mut().find(|n| n.node == source) else {
            return false;
        };
        let now = (heartbeat.uptime_s, heartbeat.table_version);
        let before = track.heard.replace(now);
        match before {
            Some((uptime, version)) if heartbeat.uptime_s < uptime || version != now.1 => {
                for slot in self.slots.iter_mut().filter(|s| s.target.node == source) {
                    // Whatever was on its way died with the node, and its filters are closed
                    // again (their boot state); each is commanded all the same.
                    slot.pending = None;
                    slot.least = 0;
                    slot.most = 0;
                    slot.force = true;
                    slot.answered = false;
                    slot.refused = None;
                }
            }
            Some(_) => return false,
            None => {
                // Heard for the first time: it may have been off when its commands went out, or
                // have run for hours under another intention node. What is not known to be in
                // force, and was not refused by the node itself, is commanded again.
                let stale = self
                    .slots
                    .iter()
                    .filter(|s| s.target.node == source)
                    .any(|s| s.pending.is_none() && !s.answered && s.known() != Some(s.wanted));
                if !stale {
                    return false;
                }
            }
        }
        self.event(Event::Restarted { node: source });
        self.plan(Some(source));
        true
    }

    /// Brings everything up to `now`: drops the desires whose lease ran out, solves when the
    /// served intensities changed (the first call solves for none), plans the filters when the
    /// selection changed, resends or gives up commands past their timeout, and moves from
    /// reductions to increases once every reduction is settled. The commands to send then come
    /// from [`Workspace::next_command`]. Costs one solve when the intensities changed (see
    /// [`Solver::solve`]), O(F) otherwise.
    pub fn poll(&mut self, now: Instant) {
        self.dirty = false;
        if self.desires.expire(now) {
            self.event(Event::Expired);
        }
        let intensities = self.desires.intensities();
        if self.served != Some(intensities) {
            self.served = Some(intensities);
            match self.solver.solve(&intensities, self.budget) {
                Ok(selection) => {
                    let strategies = selection.strategies().fold(0u64, |m, s| m | bit64(s));
                    let first = self.selection.is_none();
                    self.selection = Some(selection);
                    if first || strategies != self.strategies {
                        self.strategies = strategies;
                        self.event(Event::Selected {
                            strategies,
                            objective: selection.objective(),
                        });
                        self.plan(None);
                    }
                }
                Err(error) => self.event(Event::SolveFailed(error)),
            }
        }
        let mut gave_up: Vec<Event, MAX_FILTERED> = Vec::new();
        for slot in &mut self.slots {
            let Some(pending) = slot.pending.as_mut() else {
                continue;
            };
            let Some(sent) = pending.sent else {
                continue;
            };
            if now
                .micros_since(sent)
                .is_none_or(|waited| waited < ACK_TIMEOUT_US)
            {
                continue;
            }
            if pending.sends < MAX_SENDS {
                pending.sent = None;
            } else {
                let phi = pending.phi;
                let _ = gave_up.push(Event::GaveUp {
                    target: slot.target,
                    phi,
                });
                slot.pending = None;
                slot.answered = false;
                slot.widen(phi);
            }
        }
        self.gave_up = self
            .gave_up
            .saturating_add(u8::try_from(gave_up.len()).unwrap_or(u8::MAX));
        for event in gave_up {
            self.event(event);
        }
        self.advance();
    }

    /// The next command to send now, if any: marks it sent at `now` (its timeout runs from
    /// there). Reductions while any is unsettled, then increases. O(F).
    pub fn next_command(&mut self, now: Instant) -> Option<Command> {
        // Profiles hook (module documentation, "Profiles (not yet)"): here, before a node's
        // first FilterSet of this phase, a profile of its table that matches its filters would
        // be sent instead. Tables carry no profiles yet, so every command is a FilterSet.
        let slot = self
            .slots
            .iter_mut()
            .find(|s| s.pending.is_some_and(|p| p.sent.is_none()))?;
        let pending = slot.pending.as_mut()?;
        pending.sent = Some(now);
        pending.sends = pending.sends.saturating_add(1);
        Some(Command {
            node: slot.target.node,
            set: FilterSet {
                port: slot.target.port,
                connection: slot.target.index,
                phi: pending.phi,
                sequence: pending.sequence,
            },
            reduction: pending.reduction,
            send: pending.sends,
        })
    }

    /// When [`Workspace::poll`] next has work, at the latest: a lease running out, a command's
    /// timeout; `now` when a command waits to be sent. `None`: nothing until a frame arrives.
    pub fn deadline(&self, now: Instant) -> Option<Instant> {
        let mut soonest = self.desires.deadline(now);
        let mut consider = |at: Instant| {
            let sooner = match soonest {
                Some(current) => current.micros_since(at).is_some_and(|d| d > 0),
                None => true,
            };
            if sooner {
                soonest = Some(at);
            }
        };
        for pending in self.slots.iter().filter_map(|s| s.pending) {
            match pending.sent {
                None => consider(now),
                Some(sent) => consider(sent.wrapping_add_micros(ACK_TIMEOUT_US)),
            }
        }
        if self.served.is_none() || self.dirty {
            consider(now);
        }
        soonest
    }

    /// The next event, oldest first.
    pub fn next_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// Events dropped because [`MAX_EVENTS`] were waiting.
    pub const fn lost_events(&self) -> u32 {
        self.lost_events
    }

    /// The selected strategies: bit s set when strategy s runs (0 before the first poll).
    pub const fn strategies(&self) -> u64 {
        self.strategies
    }

    /// The last selection, with its objective and resource use (`None` before the first poll).
    pub const fn selection(&self) -> Option<&Selection> {
        self.selection.as_ref()
    }

    /// The desires held.
    pub const fn desires(&self) -> &Desires {
        &self.desires
    }

    /// Whether every command is settled (nothing waits to be sent or acknowledged).
    pub fn is_settled(&self) -> bool {
        self.stage == Stage::Idle
    }

    /// The filtered connections, in the order of first appearance among the strategies.
    pub fn filters(&self) -> impl Iterator<Item = FilterView> + '_ {
        self.slots.iter().map(|s| FilterView {
            target: s.target,
            wanted: s.wanted,
            known: s.known(),
            commanded: s.pending.map(|p| p.phi),
        })
    }

    /// The φ each filtered connection gets from the selection (0 when no selected strategy
    /// names it), and the commands that bring the nodes there: reductions now, increases once
    /// every reduction is settled. `scope`: only the filters of that node (a restart); the
    /// others' commands go on as they were.
    fn plan(&mut self, scope: Option<u8>) {
        let instance = self.solver.instance();
        for slot in &mut self.slots {
            let connection = slot.target.connection;
            slot.wanted = instance
                .strategies
                .iter()
                .enumerate()
                .filter(|(index, _)| self.strategies & bit64(*index) != 0)
                .flat_map(|(_, s)| s.filters.iter())
                .find(|f| f.connection == connection)
                // Checked by `new`: every φ fits a byte.
                .map_or(0, |f| u8::try_from(f.phi).unwrap_or(u8::MAX));
        }
        if scope.is_none() {
            self.refused = 0;
            self.gave_up = 0;
        }
        for slot in &mut self.slots {
            if scope.is_some_and(|node| node != slot.target.node) {
                continue;
            }
            slot.increase = false;
            if let Some(pending) = slot.pending {
                if pending.phi == slot.wanted && pending.sent.is_some() {
                    // Already on its way: it goes on waiting, in the phase it now belongs to.
                    let reduction = passes_fewer(slot.wanted, slot.most);
                    if let Some(p) = slot.pending.as_mut() {
                        p.reduction = reduction;
                    }
                    continue;
                }
                // Superseded: once sent, the node may or may not have applied it.
                if pending.sends > 0 {
                    slot.widen(pending.phi);
                }
                slot.pending = None;
            }
            let wanted = slot.wanted;
            if (slot.known() == Some(wanted) || slot.refused == Some(wanted)) && !slot.force {
                continue;
            }
            slot.force = false;
            let may_reduce = passes_fewer(wanted, slot.most) || slot.known() == Some(wanted);
            let may_increase = passes_fewer(slot.least, wanted);
            if may_reduce {
                // Inside the range: first down to its least (which can only reduce), then up.
                let first = if may_increase { slot.least } else { wanted };
                self.sequence = next_sequence(self.sequence);
                slot.pending = Some(Pending {
                    phi: first,
                    sequence: self.sequence,
                    sent: None,
                    sends: 0,
                    reduction: true,
                });
            }
            if may_increase {
                slot.increase = true;
            }
        }
        // Over every filter, those out of `scope` included: no increase while any reduction
        // is unsettled.
        self.stage = if self
            .slots
            .iter()
            .any(|s| s.pending.is_some_and(|p| p.reduction))
        {
            Stage::Reducing
        } else {
            self.start_increases();
            if self.slots.iter().any(|s| s.pending.is_some()) {
                Stage::Increasing
            } else {
                Stage::Idle
            }
        };
    }

    fn start_increases(&mut self) {
        for slot in self.slots.iter_mut().filter(|s| s.increase) {
            slot.increase = false;
            if slot.known() == Some(slot.wanted) {
                continue;
            }
            self.sequence = next_sequence(self.sequence);
            slot.pending = Some(Pending {
                phi: slot.wanted,
                sequence: self.sequence,
                sent: None,
                sends: 0,
                reduction: false,
            });
        }
    }

    /// Moves on when the current phase is settled.
    fn advance(&mut self) {
        if self.stage == Stage::Reducing
            && !self
                .slots
                .iter()
                .any(|s| s.pending.is_some_and(|p| p.reduction))
        {
            self.start_increases();
            self.stage = Stage::Increasing;
        }
        if self.stage == Stage::Increasing && self.slots.iter().all(|s| s.pending.is_none()) {
            self.stage = Stage::Idle;
            let (refused, gave_up) = (self.refused, self.gave_up);
            self.event(Event::Settled { refused, gave_up });
        }
    }

    fn event(&mut self, event: Event) {
        if self.events.is_full() {
            let _ = self.events.pop_front();
            self.lost_events = self.lost_events.saturating_add(1);
        }
        let _ = self.events.push_back(event);
    }

    /// The intensities served now, per class (0: no desire).
    pub fn intensities(&self) -> [u16; MAX_CLASSES] {
        self.desires.intensities()
    }
}

/// The sequence number after `sequence`, skipping 0 (FilterStatus's "nothing since boot").
const fn next_sequence(sequence: u16) -> u16 {
    match sequence.wrapping_add(1) {
        0 => 1,
        next => next,
    }
}
