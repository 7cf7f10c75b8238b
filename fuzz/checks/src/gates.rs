//! Competitive-dynamics gates on a board arbiter (`pab_core::dynamics` in a `pab_core::Arbiter` of
//! board capacities) under a script of operations: frames on the topics the contexts read (and
//! the ports' commands), Gates frames from other nodes (well formed, of another size, mutated, or
//! any payload, all through `Message::decode`), `dynamics_poll` at any instant (the same one twice,
//! or after a stall long enough to drop a backlog), resets, and time that moves on by 0 µs to
//! 2^62 µs from any start (across the counter's wrap). A script ends after `STEP_BUDGET` steps.
//!
//! The table is valid by construction: 1 to 4 ports, each with a command topic (connection 0) and
//! 0 to 31 gate connections ([`GATE_SLOT_FILTER`], 32 at most in all); connection 0 delivers iff
//! it and the port's first gate connection are active. 0 to 2 groups the node runs (1..=32
//! behaviours, a step of 1 ms or 1 µs..20 ms, every τ at least 4 steps, γ's within
//! dt · (2 + Σγ) / τ ≤ 1, requirements, noise, seeds and c from the input; contexts constant, a
//! connection's activity, or a topic's field), gate sources (the node's own groups, other nodes'
//! with any owner and count) and gate links from most gate connections to a behaviour of a source.
//!
//! The expectations come from a reference kept here in plain `u64` microseconds since the start
//! (no `Instant`, no wrap), written from `core/src/dynamics/run.rs`'s documentation: the step grid
//! t_k = t_0 + k·dt, the contexts sampled at t_(k−1) (topics read by a field reader and a divider
//! of its own; connections through `Arbiter::activity` at t_(k−1)), an integrator of the same
//! parameters stepped with them (`Dynamics`, itself checked against a floating-point reference in
//! `core/tests/integrator_reference.rs`), the broadcasts, and each source's mask and silence.
//! Properties, after every operation:
//!
//! - **Steps**: a poll takes one step per grid point passed, each seen by `view` with its instant,
//!   the contexts sampled there and the reference's state; at most `MAX_CATCH_UP`, the rest counted
//!   in `skipped()`, the grid restarted at the poll with the contexts sampled then.
//! - **Broadcasts**: the Gates sent are exactly the reference's: one at each step whose mask differs
//!   from the last sent (its `changes` counted), one at a poll 100 ms or more after the last
//!   (or at t_0); each decodes from its frame to itself with the group's number and count, and
//!   the last one sent carries the run's gates; 100 ms after a send, the next poll sends.
//! - **Sources**: a source's mask (`source_gates`) is the last accepted frame's while heard within
//!   300 ms, 0 once silent (from the first poll or the last frame), with exactly one loss report
//!   per silence; a frame of another count is refused with `GateError::Count` and changes
//!   nothing; own sources read the run's gates as of the last poll.
//! - **Gate connections**: each linked one is active exactly while its gate is open, an unlinked
//!   one never; connection 0 is selected exactly while it and the first gate connection are.
//! - **Deadline**: `dynamics_deadline` is the reference's (the next step or repeat of each run,
//!   the silence of each source heard, now for what has not started); after a poll it is later
//!   than now, and a poll at it takes a step, sends or reports a loss.
//! - **Decoding**: a Gates frame with the service's identifier decodes exactly when its payload is
//!   the documented layout (8 bytes, 1..=32 behaviours, no gate at or above the count, byte 7 = 0).

use std::collections::BTreeSet;

use arbitrary::{Result, Unstructured};
use embedded_can::{Id, StandardId};
use pab_core::dynamics::{
    Behaviour, Context, Dynamics, Exclusion, GATE_SLOT_FILTER, GateError, GateLink, GateSource,
    GroupSpec, MAX_BEHAVIOURS, MAX_CATCH_UP, MAX_DYNAMICS_GROUPS, MAX_GATE_LINKS, MAX_GATE_SOURCES,
    MAX_TIMEOUT_US, ONE, OWN, Params,
};
use pab_core::protocol::{BROADCAST, FrameId, Gates, Message, Service};
use pab_core::{
    Arbiter, BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, Connection, DecisionNode,
    Endian, Field, Filter, Frame, Gain, GatesLost, Instant, NodeRef, Stimulation, Table,
};

type BoardTable = Table<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;
type BoardArbiter = Arbiter<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;

/// Time never runs further than this from the start (`Instant` compares instants less than 2^63
/// µs apart).
const HORIZON: u64 = 1 << 62;
/// Port p's command topic: 0x100 + p (standard).
const CMD_BASE: u32 = 0x100;
/// The topics contexts read: 0x150..=0x153 (standard).
const TOPIC_BASE: u32 = 0x150;
/// Gates::PERIOD_US and Gates::SILENCE_US, as `docs/can-protocol.md` gives them.
const PERIOD_US: u64 = 100_000;
const SILENCE_US: u64 = 300_000;
/// A script ends once its groups have taken this many steps: a step of 32 behaviours is the
/// costly part of a run (twice: the arbiter's and the reference's), and short scripts let the
/// fuzzer try more tables.
const STEP_BUDGET: u64 = 1_500;

/// Runs the fuzzer's script against one arbiter.
pub fn check(data: &[u8]) {
    let _ = features(data);
}

/// Runs the check and names what the script reached (a step, a change sent, a backlog dropped, a
/// loss, a refused count, ...): the seed generator (`examples/seeds.rs`) keeps scripts that
/// reach something new.
pub fn features(data: &[u8]) -> BTreeSet<&'static str> {
    let mut seen = BTreeSet::new();
    let _ = run(&mut Unstructured::new(data), &mut seen);
    seen
}

/// A field's value in a payload, from `Field`'s documentation: `None` when the payload is short.
fn reference_field(field: &Field, payload: &[u8]) -> Option<i64> {
    let start = usize::from(field.offset);
    let bytes = payload.get(start..start + usize::from(field.size))?;
    let mut raw: u64 = 0;
    for k in 0..bytes.len() {
        let byte = match field.endian {
            Endian::Little => bytes[bytes.len() - 1 - k],
            Endian::Big => bytes[k],
        };
        raw = raw << 8 | u64::from(byte);
    }
    let bits = 8 * u32::from(field.size);
    Some(if field.signed && raw >> (bits - 1) & 1 == 1 {
        raw as i64 - (1i64 << bits)
    } else {
        raw as i64
    })
}

/// value / (scale / 256) in Q2.29, clamped into [0, 1], rounded down.
fn reference_context(value: i64, scale_q8: u32) -> i32 {
    if value <= 0 {
        return 0;
    }
    let ratio = (value as u128) << 37;
    let context = ratio / u128::from(scale_q8);
    context.min(ONE as u128) as i32
}

/// The Gates layout of `docs/can-protocol.md` (`protocol::Gates`), read from a payload.
fn reference_gates(payload: &[u8]) -> Option<Gates> {
    let &[group, behaviours, m0, m1, m2, m3, changes, reserved] = payload else {
        return None;
    };
    let mask = u32::from_le_bytes([m0, m1, m2, m3]);
    let valid = (1..=32).contains(&behaviours)
        && (behaviours == 32 || mask >> behaviours == 0)
        && reserved == 0;
    valid.then_some(Gates {
        group,
        behaviours,
        mask,
        changes,
    })
}

/// The reference's view of a group the node runs. Times are µs since the start.
struct RunModel {
    spec: GroupSpec,
    shadow: Dynamics,
    /// t_k of the next step; `None` before the first poll.
    next: Option<u64>,
    /// The contexts sampled at the last grid point.
    contexts: Vec<i32>,
    /// Per behaviour, the last reading of its topic and when.
    readings: Vec<Option<(i32, u64)>>,
    sent: u32,
    changes: u8,
    repeat: u64,
    skipped: u32,
    /// The last poll that sent this group's gates, and what it sent last.
    last_send: Option<(u64, u32)>,
}

impl RunModel {
    fn new(spec: &GroupSpec) -> RunModel {
        let count = spec.params.behaviours.len();
        RunModel {
            spec: spec.clone(),
            shadow: Dynamics::new(&spec.params).expect("valid parameters"),
            next: None,
            contexts: vec![0; count],
            readings: vec![None; count],
            sent: 0,
            changes: 0,
            repeat: 0,
            skipped: 0,
            last_send: None,
        }
    }

    fn step_us(&self) -> u64 {
        u64::from(self.spec.params.step_us)
    }

    fn count(&self) -> u8 {
        self.spec.params.behaviours.len() as u8
    }
}

/// What the reference knows of a source.
struct SourceModel {
    source: GateSource,
    mask: u32,
    since: Option<u64>,
    lost: bool,
}

/// One step as `view` showed it.
#[derive(Debug, PartialEq)]
struct Row {
    group: usize,
    at: u64,
    contexts: Vec<i32>,
    gates: u32,
    states: Vec<(i32, i32, i32)>,
}

fn states(dynamics: &Dynamics) -> Vec<(i32, i32, i32)> {
    (0..dynamics.len())
        .map(|i| {
            let state = dynamics.state(i).expect("a behaviour of the group");
            (state.n, state.rho, state.m)
        })
        .collect()
}

struct World {
    arbiter: BoardArbiter,
    node: u8,
    /// Gate connections per port (connections 1..=k).
    gate_counts: Vec<u8>,
    links: Vec<GateLink>,
    runs: Vec<RunModel>,
    sources: Vec<SourceModel>,
    start: u64,
    now: u64,
    /// Steps taken so far, all groups ([`STEP_BUDGET`]).
    steps: u64,
    seen: BTreeSet<&'static str>,
}

impl World {
    fn at(&self, elapsed: u64) -> Instant {
        Instant::from_micros(self.start.wrapping_add(elapsed))
    }

    /// C_i of run `r` at `t`, sampled from the arbiter's state now (before a poll changes it).
    fn sample(&self, r: usize, t: u64) -> Vec<i32> {
        let run = &self.runs[r];
        run.spec
            .contexts
            .iter()
            .enumerate()
            .map(|(b, context)| match *context {
                Context::Constant(value) => value as i32,
                Context::Connection { port, connection } => {
                    if self.arbiter.activity(port, self.at(t)).contains(connection) {
                        ONE
                    } else {
                        0
                    }
                }
                Context::Topic { timeout_us, .. } => match run.readings[b] {
                    // A reading heard after t (while the node catches up) counts as fresh.
                    Some((value, when)) if when > t || t - when <= u64::from(timeout_us) => value,
                    _ => 0,
                },
            })
            .collect()
    }

    /// The gate of (port, connection) as the reference reads it.
    fn gate(&self, port: u8, connection: u8) -> bool {
        self.links
            .iter()
            .find(|link| link.port == port && link.connection == connection)
            .is_some_and(|link| {
                self.sources[usize::from(link.source)].mask >> link.behaviour & 1 == 1
            })
    }

    /// The reference's deadline, µs since the start.
    fn deadline(&self) -> Option<u64> {
        let runs = self.runs.iter().map(|run| match run.next {
            Some(next) => next.min(run.repeat),
            None => self.now,
        });
        let sources = self
            .sources
            .iter()
            .filter(|s| s.source.owner != OWN && !s.lost)
            .map(|s| s.since.map_or(self.now, |since| since + SILENCE_US));
        runs.chain(sources).min()
    }

    /// The properties that hold between operations.
    fn verify(&mut self) {
        let now = self.at(self.now);
        for (i, model) in self.sources.iter().enumerate() {
            assert_eq!(
                self.arbiter.source_gates(i),
                Some(model.mask),
                "source {i} ({:?}) at {} µs",
                model.source,
                self.now
            );
        }
        assert_eq!(self.arbiter.source_gates(self.sources.len()), None);
        for (p, &gates) in self.gate_counts.iter().enumerate() {
            let port = p as u8;
            let activity = self.arbiter.activity(port, now);
            for connection in 1..=gates {
                let open = self.gate(port, connection);
                assert_eq!(
                    activity.contains(connection),
                    open,
                    "gate connection {connection} of port {port} at {} µs",
                    self.now
                );
                if open {
                    self.seen.insert("gate connection active");
                }
            }
            let command = activity.contains(0);
            let delivers = command && (gates == 0 || activity.contains(1));
            assert_eq!(
                self.arbiter.selected(port, now),
                delivers.then_some(0),
                "port {port}: the command delivers iff it and the first gate are active"
            );
            if command && gates > 0 && activity.contains(1) {
                self.seen.insert("command through a gate");
            }
        }
        let runs = self.arbiter.dynamics_runs();
        assert_eq!(runs.len(), self.runs.len());
        for (run, model) in runs.iter().zip(&self.runs) {
            assert_eq!(
                run.gates(),
                model.shadow.gates(),
                "gates of group {}",
                model.spec.number
            );
            assert_eq!(
                run.skipped(),
                model.skipped,
                "skipped of group {}",
                model.spec.number
            );
            assert_eq!(states(run.dynamics()), states(&model.shadow));
        }
        let deadline = self.arbiter.dynamics_deadline(now);
        let expected = self.deadline().map(|d| self.at(d));
        assert_eq!(deadline, expected, "dynamics_deadline at {} µs", self.now);
    }

    /// A frame that is not ours: arbitrated, then shown to the groups, as the node does.
    fn frame(&mut self, frame: &Frame) {
        let now = self.at(self.now);
        let _ = self.arbiter.receive(&frame.id(), now, |_| {});
        self.arbiter.dynamics_frame(frame, now);
        let Id::Standard(id) = frame.id() else {
            return;
        };
        for run in &mut self.runs {
            for (b, context) in run.spec.contexts.iter().enumerate() {
                if let Context::Topic {
                    filter,
                    field,
                    scale,
                    ..
                } = context
                    && filter.id() == u32::from(id.as_raw())
                    && !filter.is_extended()
                {
                    let value = match reference_field(field, frame.payload()) {
                        Some(value) => value,
                        None => {
                            self.seen.insert("short reading");
                            0
                        }
                    };
                    let context = reference_context(value, *scale);
                    self.seen.insert(match context {
                        0 => "reading 0",
                        ONE => "reading 1",
                        _ => "reading between",
                    });
                    run.readings[b] = Some((context, self.now));
                }
            }
        }
    }

    /// A Gates frame from the bus, through the decoder, to `on_gates`.
    fn gates_frame(&mut self, frame: &Frame, canonical: bool) {
        let decoded = Message::decode(frame);
        if canonical {
            // The service's own identifier: the payload alone decides.
            let expected = reference_gates(frame.payload());
            match (&decoded, expected) {
                (Ok((_, Message::Gates(gates))), Some(expected)) => assert_eq!(*gates, expected),
                (Err(_), None) => {
                    self.seen.insert("malformed refused");
                }
                _ => panic!("{frame:?} decodes to {decoded:?}, the layout says {expected:?}"),
            }
        }
        let Ok((id, Message::Gates(gates))) = decoded else {
            return;
        };
        assert_eq!(Some(gates), reference_gates(frame.payload()), "{frame:?}");
        let now = self.at(self.now);
        let outcome = self.arbiter.on_gates(id.source, &gates, now);
        let mut expected = Ok(());
        if id.source != OWN {
            for model in &mut self.sources {
                if model.source.owner == id.source && model.source.group == gates.group {
                    if model.source.behaviours != gates.behaviours {
                        expected = Err(GateError::Count);
                        self.seen.insert("count refused");
                    } else {
                        model.mask = gates.mask;
                        model.since = Some(self.now);
                        model.lost = false;
                        self.seen.insert("gates accepted");
                        if gates.mask != 0 {
                            self.seen.insert("remote gate open");
                        }
                    }
                }
            }
        }
        assert_eq!(outcome, expected, "on_gates({}, {gates:?})", id.source);
    }

    fn poll(&mut self) {
        let deadline = self.deadline();
        let at_deadline = deadline == Some(self.now);
        // The reference first: steps, rows and sends per run, sampling the arbiter before the
        // poll changes its gate connections.
        let mut rows = Vec::new();
        let mut sends = Vec::new();
        let mut steps_taken = 0u64;
        let mut started = false;
        for r in 0..self.runs.len() {
            let step = self.runs[r].step_us();
            let next = match self.runs[r].next {
                Some(next) => next,
                None => {
                    let contexts = self.sample(r, self.now);
                    let run = &mut self.runs[r];
                    run.contexts = contexts;
                    rows.push(Row {
                        group: r,
                        at: self.now,
                        contexts: run.contexts.clone(),
                        gates: run.shadow.gates(),
                        states: states(&run.shadow),
                    });
                    run.repeat = self.now;
                    started = true;
                    self.seen.insert("started");
                    self.now + step
                }
            };
            let due = if self.now >= next {
                (self.now - next) / step + 1
            } else {
                0
            };
            let taken = due.min(u64::from(MAX_CATCH_UP));
            for k in 0..taken {
                let t = next + k * step;
                let run = &mut self.runs[r];
                let gates = run.shadow.step(&run.contexts);
                if gates != run.sent {
                    run.changes = run.changes.wrapping_add(1);
                    sends.push(Gates {
                        group: run.spec.number,
                        behaviours: run.count(),
                        mask: gates,
                        changes: run.changes,
                    });
                    run.sent = gates;
                    run.repeat = t + PERIOD_US;
                    self.seen.insert("change sent");
                }
                let contexts = self.sample(r, t);
                let run = &mut self.runs[r];
                run.contexts = contexts;
                rows.push(Row {
                    group: r,
                    at: t,
                    contexts: run.contexts.clone(),
                    gates,
                    states: states(&run.shadow),
                });
            }
            steps_taken += taken;
            self.steps += taken;
            if taken > 0 {
                self.seen.insert("step");
            }
            let new_next = if due > taken {
                let dropped = u32::try_from(due - taken).unwrap_or(u32::MAX);
                self.runs[r].skipped = self.runs[r].skipped.saturating_add(dropped);
                self.seen.insert("backlog dropped");
                // The grid restarts at the poll: t_0 = now, its contexts sampled now.
                let contexts = self.sample(r, self.now);
                self.runs[r].contexts = contexts;
                self.now + step
            } else {
                next + taken * step
            };
            let run = &mut self.runs[r];
            run.next = Some(new_next);
            if self.now >= run.repeat {
                let mask = run.shadow.gates();
                sends.push(Gates {
                    group: run.spec.number,
                    behaviours: run.count(),
                    mask,
                    changes: run.changes,
                });
                run.sent = mask;
                run.repeat = self.now + PERIOD_US;
                self.seen.insert("repeat sent");
            }
        }
        // Sources: own ones follow their run, others may fall silent.
        let mut losses = Vec::new();
        for model in &mut self.sources {
            if model.source.owner == OWN {
                let run = self
                    .runs
                    .iter()
                    .find(|run| run.spec.number == model.source.group)
                    .expect("an own source has its run");
                model.mask = run.shadow.gates();
                if model.mask != 0 {
                    self.seen.insert("own gate open");
                }
                continue;
            }
            started |= model.since.is_none();
            let since = *model.since.get_or_insert(self.now);
            if self.now - since >= SILENCE_US && !model.lost {
                model.mask = 0;
                model.lost = true;
                losses.push(GatesLost {
                    owner: model.source.owner,
                    group: model.source.group,
                });
                self.seen.insert("loss reported");
            }
        }
        // The arbiter.
        let now = self.at(self.now);
        let mut seen_rows = Vec::new();
        let mut sent = Vec::new();
        let mut lost = Vec::new();
        self.arbiter.dynamics_poll(
            now,
            |view| {
                assert!(view.dynamics.len() <= MAX_BEHAVIOURS);
                seen_rows.push(Row {
                    group: view.group,
                    at: view.at.as_micros().wrapping_sub(self.start),
                    contexts: view.contexts.to_vec(),
                    gates: view.dynamics.gates(),
                    states: states(view.dynamics),
                });
            },
            |gates| sent.push(gates),
            |l| lost.push(l),
        );
        assert_eq!(seen_rows.len(), rows.len(), "steps seen at {} µs", self.now);
        for (seen, expected) in seen_rows.iter().zip(&rows) {
            assert_eq!(seen, expected, "a step at {} µs", self.now);
        }
        assert_eq!(sent, sends, "gates sent at {} µs", self.now);
        assert_eq!(lost, losses, "losses reported at {} µs", self.now);
        for gates in &sent {
            let frame = Message::Gates(*gates).to_frame(self.node, BROADCAST);
            let (id, message) = Message::decode(&frame)
                .unwrap_or_else(|error| panic!("{gates:?} does not decode: {error:?}"));
            assert_eq!(message, Message::Gates(*gates));
            assert_eq!((id.source, id.destination), (self.node, BROADCAST));
            assert_eq!(reference_gates(frame.payload()), Some(*gates));
            let run = self
                .runs
                .iter()
                .find(|run| run.spec.number == gates.group)
                .unwrap_or_else(|| panic!("{gates:?} of no group of ours"));
            assert_eq!(gates.behaviours, run.count());
        }
        // Every run: polled 100 ms or more after its last send, it sent; the last sent is its
        // gates.
        for run in &mut self.runs {
            let mine: Vec<&Gates> = sent.iter().filter(|g| g.group == run.spec.number).collect();
            if let Some((at, _)) = run.last_send {
                assert!(
                    self.now - at < PERIOD_US || !mine.is_empty(),
                    "group {}: nothing sent from {at} µs to {} µs",
                    run.spec.number,
                    self.now
                );
            }
            if let Some(last) = mine.last() {
                run.last_send = Some((self.now, last.mask));
            }
            if let Some((_, mask)) = run.last_send {
                assert_eq!(
                    mask,
                    run.shadow.gates(),
                    "the last gates sent are the gates"
                );
            }
        }
        if at_deadline {
            assert!(
                started || steps_taken > 0 || !sent.is_empty() || !lost.is_empty(),
                "a poll at the deadline ({} µs) did nothing",
                self.now
            );
            self.seen.insert("poll at the deadline");
        }
        // After a poll, the deadline is later than now.
        if let Some(deadline) = self.deadline() {
            assert!(
                deadline > self.now,
                "deadline {deadline} µs at {} µs",
                self.now
            );
        }
    }

    fn reset(&mut self) {
        self.seen.insert("reset");
        self.arbiter.reset();
        for run in &mut self.runs {
            *run = RunModel::new(&run.spec);
        }
        for model in &mut self.sources {
            model.mask = 0;
            model.since = None;
            model.lost = false;
        }
    }

    /// Time moves on by `step`; with `polled`, the arbiter is polled at each deadline on the way
    /// (a node's loop), a bounded number of times.
    fn advance(&mut self, step: u64, polled: bool) {
        let target = self.now + step.min(HORIZON - self.now);
        if polled {
            for _ in 0..64 {
                if self.steps > STEP_BUDGET {
                    break;
                }
                let Some(deadline) = self.deadline() else {
                    break;
                };
                if deadline > target {
                    break;
                }
                self.now = self.now.max(deadline);
                self.poll();
                self.verify();
            }
        }
        if self.start.checked_add(target).is_none() && self.start.checked_add(self.now).is_some() {
            self.seen.insert("counter wraps");
        }
        self.now = target;
    }
}

/// Parameters valid by construction: every τ at least 4 steps, Σγ within the stability bound.
fn params(u: &mut Unstructured<'_>) -> Result<Params> {
    let mut params = Params::new();
    params.step_us = match u.int_in_range(0u8..=3)? {
        0..=1 => 1_000,
        2 => u.int_in_range(1..=2_000)?,
        _ => u.int_in_range(1..=20_000)?,
    };
    let step = params.step_us;
    let tau = |u: &mut Unstructured<'_>| -> Result<u32> {
        Ok(match u.int_in_range(0u8..=3)? {
            0 => 4 * step,
            1..=2 => 4 * step + u.int_in_range(0..=50 * step)?,
            _ => u.int_in_range(4 * step..=4 * step + 10_000_000)?,
        })
    };
    params.tau_us = tau(u)?;
    params.tau_rho_fast_us = tau(u)?;
    params.tau_rho_slow_us = tau(u)?;
    params.tau_n_us = tau(u)?;
    if u.ratio(1u8, 2)? {
        params.unit_us = u.int_in_range(1..=1_000_000)?;
        params.noise = u.int_in_range(1..=u32::MAX)?;
        params.seed = u.int_in_range(1..=u32::MAX)?;
        params.c = u.arbitrary()?;
    }
    let count = u.int_in_range(1..=MAX_BEHAVIOURS)?;
    let members = u32::MAX >> (32 - count);
    for _ in 0..count {
        let memory_us = tau(u)?;
        let requires = if u.ratio(1u8, 4)? {
            u.arbitrary::<u32>()? & members
        } else {
            0
        };
        params
            .behaviours
            .push(Behaviour {
                memory_us,
                requires,
            })
            .expect("32 behaviours at most");
    }
    // Σ_j γ_ij ≤ 256 τ / dt − 512 (Q8.8), so that dt (2 + Σγ) / τ ≤ 1.
    let budget = (256 * u64::from(params.tau_us) / u64::from(step)).saturating_sub(512);
    let mut sums = [0u64; MAX_BEHAVIOURS];
    let exclusions = u.int_in_range(0..=64usize)?;
    for _ in 0..exclusions {
        let i = u.int_in_range(0..=count as u8 - 1)?;
        let j = u.int_in_range(0..=count as u8 - 1)?;
        let room = budget - sums[usize::from(i)];
        let declared = params
            .exclusions
            .iter()
            .any(|e| e.behaviour == i && e.by == j);
        if i == j || declared || room == 0 {
            continue;
        }
        let gamma = u.int_in_range(1..=room.min(u64::from(u16::MAX)) as u16)?;
        sums[usize::from(i)] += u64::from(gamma);
        params
            .exclusions
            .push(Exclusion {
                behaviour: i,
                by: j,
                gamma,
            })
            .expect("64 exclusions fit");
    }
    debug_assert_eq!(params.validate(), Ok(()));
    Ok(params)
}

fn context(u: &mut Unstructured<'_>, gate_counts: &[u8]) -> Result<Context> {
    Ok(match u.int_in_range(0u8..=5)? {
        0 => Context::Constant(match u.int_in_range(0u8..=2)? {
            0 => 0,
            1 => ONE as u32,
            _ => u.int_in_range(0..=ONE as u32)?,
        }),
        1..=2 => {
            let port = u.int_in_range(0..=gate_counts.len() - 1)?;
            Context::Connection {
                port: port as u8,
                connection: u.int_in_range(0..=gate_counts[port])?,
            }
        }
        _ => {
            let size = *u.choose(&[1u8, 2, 4])?;
            Context::Topic {
                filter: Filter::exact(TOPIC_BASE + u32::from(u.int_in_range(0u8..=3)?), false)
                    .expect("a standard id"),
                field: Field {
                    offset: u.int_in_range(0..=8 - size)?,
                    size,
                    signed: u.arbitrary()?,
                    endian: if u.arbitrary()? {
                        Endian::Big
                    } else {
                        Endian::Little
                    },
                },
                scale: match u.int_in_range(0u8..=2)? {
                    0 => 255 * 256,
                    1 => u.int_in_range(1..=1 << 16)?,
                    _ => u.int_in_range(1..=u32::MAX)?,
                },
                timeout_us: match u.int_in_range(0u8..=2)? {
                    0 => u.int_in_range(1..=10_000)?,
                    1 => u.int_in_range(1..=500_000)?,
                    _ => u.int_in_range(1..=MAX_TIMEOUT_US)?,
                },
            }
        }
    })
}

fn payload(u: &mut Unstructured<'_>) -> Result<Vec<u8>> {
    let len = u.int_in_range(0..=8)?;
    (0..len).map(|_| u.arbitrary()).collect()
}

/// A Gates frame: mostly for a source the node reads (its count, or another now and then), from
/// its owner; sometimes another group or owner, a mutated payload or any payload. Returns the
/// frame and whether its identifier is the service's own (priority, source, broadcast).
fn gates_frame(u: &mut Unstructured<'_>, world: &World) -> Result<(Frame, bool)> {
    let remote: Vec<&GateSource> = world
        .sources
        .iter()
        .map(|s| &s.source)
        .filter(|s| s.owner != OWN)
        .collect();
    let (mut owner, mut group, mut count) = if !remote.is_empty() && u.ratio(7u8, 8)? {
        let source = *u.choose(&remote)?;
        (source.owner, source.group, source.behaviours)
    } else {
        (
            u.int_in_range(0..=127)?,
            u.arbitrary()?,
            u.int_in_range(1..=32)?,
        )
    };
    if u.ratio(1u8, 8)? {
        count = u.int_in_range(0..=40)?;
    }
    if u.ratio(1u8, 16)? {
        owner = u.int_in_range(0..=127)?;
    }
    if u.ratio(1u8, 16)? {
        group = u.arbitrary()?;
    }
    let raw_mask: u32 = u.arbitrary()?;
    let mask = if u.ratio(7u8, 8)? {
        raw_mask
            & u32::MAX
                .checked_shr(32 - u32::from(count.clamp(1, 32)))
                .unwrap_or(0)
    } else {
        raw_mask
    };
    let gates = Gates {
        group,
        behaviours: count,
        mask,
        changes: u.arbitrary()?,
    };
    let destination = if u.ratio(7u8, 8)? {
        BROADCAST
    } else {
        u.arbitrary()?
    };
    let frame = Message::Gates(gates).to_frame(owner, destination);
    let (raw, _) = frame.raw_id();
    let canonical = raw == FrameId::new(Service::Gates, owner, destination).raw();
    Ok(match u.int_in_range(0u8..=15)? {
        0 => {
            let mut data = frame.payload().to_vec();
            let at = u.choose_index(data.len())?;
            data[at] = u.arbitrary()?;
            (
                Frame::with_raw_id(raw, true, &data).expect("8 bytes"),
                canonical,
            )
        }
        1 => (
            Frame::with_raw_id(raw, true, &payload(u)?).expect("8 bytes"),
            canonical,
        ),
        2 => {
            // Another priority.
            let raw = raw & !(0b111 << 26) | u32::from(u.int_in_range(0u8..=7)?) << 26;
            (
                Frame::with_raw_id(raw, true, frame.payload()).expect("29 bits"),
                false,
            )
        }
        _ => (frame, canonical),
    })
}

fn time_step(u: &mut Unstructured<'_>, step: u64) -> Result<u64> {
    Ok(match u.int_in_range(0u8..=15)? {
        0 => 0,
        1..=4 => u.int_in_range(0..=step)?,
        5..=6 => step * u.int_in_range(1..=20)?,
        7..=8 => u.int_in_range(90_000..=110_000)?,
        9..=10 => u.int_in_range(250_000..=350_000)?,
        11 => step * u.int_in_range(90..=110)?,
        12 => step * u.int_in_range(100..=10_000)?,
        13 => u.int_in_range(0..=10_000_000_000)?,
        14 => u.int_in_range(0..=1 << 40)?,
        _ => u.int_in_range(0..=HORIZON)?,
    })
}

fn run(u: &mut Unstructured<'_>, seen: &mut BTreeSet<&'static str>) -> Result<()> {
    let start = match u.int_in_range(0u8..=3)? {
        0 => 0,
        1 => u64::MAX - u.int_in_range(0..=1_000_000)?,
        _ => u.arbitrary()?,
    };
    let node = u.int_in_range(1..=127)?;
    // Ports: the command, then gate connections (32 in all at most).
    let port_count = u.int_in_range(1..=BOARD_PORTS)?;
    let mut gate_counts = Vec::new();
    let mut room = MAX_GATE_LINKS;
    for _ in 0..port_count {
        let gates = u.int_in_range(0..=room.min(8))?;
        room -= gates;
        gate_counts.push(gates as u8);
    }
    let mut table = BoardTable::new();
    for (p, &gates) in gate_counts.iter().enumerate() {
        let decay = if u.ratio(3u8, 4)? {
            50_000
        } else {
            u.int_in_range(1..=5_000_000)?
        };
        let command = Connection {
            filter: Filter::exact(CMD_BASE + p as u32, false).expect("a standard id"),
            stimulation: Stimulation::new(Gain::ONE, decay, 0).expect("valid parameters"),
        };
        let gate = Connection {
            filter: GATE_SLOT_FILTER,
            stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).expect("valid parameters"),
        };
        let connections: Vec<Connection> = std::iter::once(command)
            .chain(std::iter::repeat_n(gate, usize::from(gates)))
            .collect();
        // The command (var 0) & the first gate (var 1) delivers the command.
        let (nodes, root) = if gates == 0 {
            (Vec::new(), NodeRef::deliver(0).expect("connection 0"))
        } else {
            (
                vec![
                    DecisionNode {
                        var: 0,
                        low: NodeRef::NOBODY,
                        high: NodeRef::node(1).expect("node 1"),
                    },
                    DecisionNode {
                        var: 1,
                        low: NodeRef::NOBODY,
                        high: NodeRef::deliver(0).expect("connection 0"),
                    },
                ],
                NodeRef::node(0).expect("node 0"),
            )
        };
        table
            .push_port(&connections, &nodes, root)
            .expect("a port of at most 9 connections fits the board");
    }
    // Groups the node runs, then the sources in any order, then the links.
    let mut numbers: Vec<u8> = Vec::new();
    let unique = |u: &mut Unstructured<'_>, numbers: &mut Vec<u8>| -> Result<u8> {
        let mut number: u8 = u.arbitrary()?;
        while numbers.contains(&number) {
            number = number.wrapping_add(1);
        }
        numbers.push(number);
        Ok(number)
    };
    let mut groups = Vec::new();
    for _ in 0..u.int_in_range(0..=MAX_DYNAMICS_GROUPS)? {
        let params = params(u)?;
        let contexts = (0..params.behaviours.len())
            .map(|_| context(u, &gate_counts))
            .collect::<Result<Vec<Context>>>()?;
        groups.push(GroupSpec {
            number: unique(u, &mut numbers)?,
            params,
            contexts: contexts.into_iter().collect(),
        });
    }
    let mut sources: Vec<GateSource> = Vec::new();
    for group in &groups {
        if u.ratio(3u8, 4)? {
            let at = u.int_in_range(0..=sources.len())?;
            sources.insert(
                at,
                GateSource {
                    owner: OWN,
                    group: group.number,
                    behaviours: group.params.behaviours.len() as u8,
                },
            );
        }
    }
    let remote = u.int_in_range(0..=MAX_GATE_SOURCES - sources.len())?;
    let remote = if groups.is_empty() && sources.is_empty() {
        remote.max(1)
    } else {
        remote
    };
    for _ in 0..remote {
        let mut owner = u.int_in_range(1..=127)?;
        if owner == node {
            owner = owner % 127 + 1;
        }
        let source = GateSource {
            owner,
            group: unique(u, &mut numbers)?,
            behaviours: u.int_in_range(1..=32)?,
        };
        let at = u.int_in_range(0..=sources.len())?;
        sources.insert(at, source);
    }
    let mut links = Vec::new();
    for (p, &gates) in gate_counts.iter().enumerate() {
        for connection in 1..=gates {
            if sources.is_empty() || u.ratio(1u8, 8)? {
                continue;
            }
            let source = u.choose_index(sources.len())?;
            links.push(GateLink {
                source: source as u8,
                behaviour: u.int_in_range(0..=sources[source].behaviours - 1)?,
                port: p as u8,
                connection,
            });
        }
    }
    table
        .push_dynamics(&groups, &sources, &links)
        .unwrap_or_else(|error| panic!("a valid dynamics part refused: {error}"));
    let arbiter = BoardArbiter::new(table).expect("a valid table builds an arbiter");
    assert!(arbiter.has_dynamics());
    let mut world = World {
        arbiter,
        node,
        gate_counts,
        links,
        runs: groups.iter().map(RunModel::new).collect(),
        sources: sources
            .iter()
            .map(|&source| SourceModel {
                source,
                mask: 0,
                since: None,
                lost: false,
            })
            .collect(),
        start,
        now: 0,
        steps: 0,
        seen: BTreeSet::new(),
    };
    world.seen.insert(match groups.len() {
        0 => "reader only",
        1 => "one group",
        _ => "two groups",
    });
    world.verify();
    let outcome = script(u, &mut world);
    seen.append(&mut world.seen);
    outcome
}

fn script(u: &mut Unstructured<'_>, world: &mut World) -> Result<()> {
    for _ in 0..256 {
        if u.is_empty() || world.steps > STEP_BUDGET {
            break;
        }
        match u.int_in_range(0u8..=15)? {
            0..=3 => {
                // A topic a context reads, a command, or anything standard.
                let id = match u.int_in_range(0u8..=7)? {
                    0..=4 => TOPIC_BASE + u32::from(u.int_in_range(0u8..=3)?),
                    5..=6 => CMD_BASE + u32::from(u.int_in_range(0u8..=3)?),
                    _ => u.int_in_range(0..=0x7FF)?,
                };
                let id = StandardId::new(id as u16).expect("11 bits");
                let frame = Frame::data(id, &payload(u)?).expect("8 bytes");
                world.frame(&frame);
            }
            4..=7 => {
                let (frame, canonical) = gates_frame(u, world)?;
                world.gates_frame(&frame, canonical);
            }
            8..=10 => {
                world.poll();
                if u.ratio(1u8, 4)? {
                    world.seen.insert("same instant twice");
                    world.poll();
                }
            }
            11..=14 => {
                let step = world.runs.first().map_or(1_000, RunModel::step_us);
                let step = time_step(u, step)?;
                let polled = u.arbitrary()?;
                world.advance(step, polled);
            }
            _ => {
                if u.ratio(1u8, 4)? {
                    world.reset();
                } else {
                    world.poll();
                }
            }
        }
        world.verify();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_reads_fields_and_scales_as_documented() {
        let field = Field {
            offset: 1,
            size: 2,
            signed: true,
            endian: Endian::Big,
        };
        assert_eq!(reference_field(&field, &[0, 0xFF, 0xFE]), Some(-2));
        assert_eq!(reference_field(&field, &[0, 0xFF]), None);
        let little = Field {
            endian: Endian::Little,
            signed: false,
            ..field
        };
        assert_eq!(reference_field(&little, &[0, 0x34, 0x12]), Some(0x1234));
        assert_eq!(reference_context(255, 255 * 256), ONE);
        assert_eq!(reference_context(51, 102 * 256), ONE / 2);
        assert_eq!(reference_context(-3, 256), 0);
        assert_eq!(reference_context(1, 128), ONE);
        assert_eq!(
            reference_gates(&[3, 5, 0b10101, 0, 0, 0, 7, 0]),
            Some(Gates {
                group: 3,
                behaviours: 5,
                mask: 0b10101,
                changes: 7
            })
        );
        assert_eq!(reference_gates(&[3, 5, 0b100000, 0, 0, 0, 7, 0]), None);
        assert_eq!(reference_gates(&[3, 0, 0, 0, 0, 0, 7, 0]), None);
        assert_eq!(reference_gates(&[3, 5, 0, 0, 0, 0, 7, 1]), None);
    }

    #[test]
    fn random_scripts_pass() {
        let mut state: u64 = 0x6A7E_5EED_0000_0001;
        let mut reached = BTreeSet::new();
        for i in 0..200 {
            let len = [64usize, 256, 1024, 4096][i % 4];
            let bytes: Vec<u8> = (0..len)
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    state as u8
                })
                .collect();
            reached.extend(features(&bytes));
        }
        for feature in ["step", "change sent", "repeat sent", "gates accepted"] {
            assert!(
                reached.contains(feature),
                "{feature} never reached: {reached:?}"
            );
        }
    }
}
