//! The intention workspace (`pab_core::hbba::intention::Workspace`, what `pab-intent` runs on the
//! bus) under a script of what the bus brings: Desire frames (any class, intensity, lease and
//! name, from any sender), arbitrary frames through `Message::decode` (so FilterStatus, faults,
//! heartbeats and desires with any payload), the simulated nodes' answers to its commands
//! (applied and acknowledged, refused with the nodes' rate-limited `FilterRefused`, or lost),
//! node restarts, and time that moves on by 0 µs to 2^40 µs from any start (across the counter's
//! wrap). Instances are small and valid by construction: 1 to 4 classes, 1 to 8 strategies of one
//! resource with up to 3 filters (any φ of a byte) on 8 connections of 3 nodes and at most one
//! requirement.
//!
//! Properties, after every step:
//!
//! - **No panic**, whatever the frames and times.
//! - **The selection is the solver's**: after a poll, the selected strategies are
//!   `hbba::solve`'s for the intensities the workspace serves, and every filtered connection
//!   wants the φ of its selected strategy, 0 when none names it.
//! - **Commands address filters**: every command is a FilterSet to a connection's own node, port
//!   and index, with a sequence number other than 0, and a resend keeps its number.
//! - **The deadline is honest**: after a poll and the commands it released, the deadline is not
//!   in the past unless a lease runs out exactly then.
//! - **It converges**: at the end, on a clean bus, once every node restarted, the workspace
//!   settles and every node applies the φ its filters want.

use std::collections::BTreeMap;

use arbitrary::{Result, Unstructured};
use embedded_can::{ExtendedId, Id};
use pab_core::hbba::intention::{Target, Workspace};
use pab_core::hbba::{self, FilterSetting, Instance, Requirement, Strategy};
use pab_core::protocol::{
    DesireFrame, Fault, FaultCode, FilterSet, FilterStatus, Heartbeat, Message, NodeState,
};
use pab_core::{Frame, Instant};

/// Connections 0..CONNECTIONS; connection c is on node 1 + c % 3, port c % 2, index c.
const CONNECTIONS: u16 = 8;
/// Steps of a script at most.
const STEP_BUDGET: usize = 400;

fn target(connection: u16) -> Target {
    Target {
        connection,
        node: 1 + (connection % 3) as u8,
        port: (connection % 2) as u8,
        index: connection as u8,
    }
}

/// Runs the fuzzer's script against one workspace.
pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data));
}

fn instance(u: &mut Unstructured) -> Result<Instance> {
    let classes: u8 = u.int_in_range(1..=4)?;
    let mut instance = Instance {
        classes,
        ..Instance::default()
    };
    let _ = instance.capacities.push(u.int_in_range(1..=20)?);
    for _ in 0..u.int_in_range(1..=8)? {
        let class = u.int_in_range(0..=classes - 1)?;
        let mut strategy = Strategy::new(class, u.int_in_range(0..=5)?);
        strategy.costs[0] = u.int_in_range(0..=12)?;
        let mut used = Vec::new();
        for _ in 0..u.int_in_range(0..=3)? {
            let connection = u.int_in_range(0..=CONNECTIONS - 1)?;
            if used.contains(&connection) {
                continue;
            }
            used.push(connection);
            let phi = u16::from(u.arbitrary::<u8>()?);
            let _ = strategy.filters.push(FilterSetting { connection, phi });
        }
        if classes > 1 && u.ratio(1, 4)? {
            let other = u.int_in_range(0..=classes - 1)?;
            if other != class {
                let _ = strategy.requires.push(Requirement {
                    class: other,
                    min_utility: u.int_in_range(0..=5)?,
                });
            }
        }
        let _ = instance.strategies.push(strategy);
    }
    Ok(instance)
}

/// The simulated nodes and the answers on their way.
struct Nodes {
    /// Per node id: per connection index, its φ (boot: closed).
    filters: BTreeMap<u8, BTreeMap<u8, u8>>,
    /// Per node id: its uptime in its last heartbeat and its table version.
    beat: BTreeMap<u8, (u32, u32)>,
    /// Answers not yet delivered: (node, answer).
    answers: Vec<(u8, Answer)>,
    /// Sequence number of each (node, port, index) last sent, to check resends.
    sequences: BTreeMap<(u8, u8, u8), u16>,
}

#[derive(Clone, Copy, Debug)]
enum Answer {
    Applied(FilterStatus),
    Refused(Fault),
}

impl Nodes {
    fn new() -> Nodes {
        let mut nodes = Nodes {
            filters: BTreeMap::new(),
            beat: BTreeMap::new(),
            answers: Vec::new(),
            sequences: BTreeMap::new(),
        };
        for node in 1..=3 {
            nodes.boot(node);
        }
        nodes
    }

    fn boot(&mut self, node: u8) {
        let filters = (0..CONNECTIONS)
            .filter(|&c| target(c).node == node)
            .map(|c| (c as u8, 0))
            .collect();
        self.filters.insert(node, filters);
        self.answers.retain(|(n, _)| *n != node);
    }
}

/// How the nodes treat the next commands.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    Apply,
    Refuse,
    Lose,
}

fn run(u: &mut Unstructured) -> Result<()> {
    let instance = instance(u)?;
    let targets: Vec<Target> = (0..CONNECTIONS).map(target).collect();
    let Ok(mut ws) = Workspace::new(&instance, &targets) else {
        panic!("a valid instance with every target was refused");
    };
    let start: u64 = u.arbitrary()?;
    let mut now = 0u64;
    let at = |t: u64| Instant::from_micros(start.wrapping_add(t));
    let mut nodes = Nodes::new();
    let mut mode = Mode::Apply;
    for _ in 0..STEP_BUDGET {
        if u.is_empty() {
            break;
        }
        match u.int_in_range(0..=8)? {
            0 => {
                let frame = DesireFrame {
                    class: u.int_in_range(0..=4)?,
                    intensity: if u.ratio(1, 4)? {
                        0
                    } else {
                        u.int_in_range(1..=9)?
                    },
                    lease_ms: if u.ratio(1, 8)? {
                        0
                    } else {
                        u.int_in_range(1..=3000)?
                    },
                    id: u.int_in_range(0..=3)?,
                };
                let source = u.int_in_range(1..=9)?;
                let _ = ws.on_desire(source, &frame, at(now));
            }
            1 => {
                // Anything with one of our identifiers.
                let raw: u32 = u.arbitrary::<u32>()? & 0x1FFF_FFFF;
                let len = u.int_in_range(0..=8)?;
                let mut data = [0u8; 8];
                for byte in data.iter_mut().take(len) {
                    *byte = u.arbitrary()?;
                }
                let id = ExtendedId::new(raw).map_or(Id::Extended(ExtendedId::ZERO), Id::Extended);
                if let Some(frame) = Frame::data(id, data.get(..len).unwrap_or(&[]))
                    && let Ok((id, message)) = Message::decode(&frame)
                {
                    dispatch(&mut ws, id.source, &message, at(now));
                }
            }
            2 => {
                let step: u64 = match u.int_in_range(0..=3)? {
                    0 => 0,
                    1 => u.int_in_range(1..=1_000)?,
                    2 => u.int_in_range(1..=1_000_000)?,
                    _ => u.int_in_range(1..=1 << 40)?,
                };
                now += step;
                for (node, beat) in nodes.beat.iter_mut() {
                    beat.0 = beat
                        .0
                        .saturating_add(u32::try_from(step / 1_000_000).unwrap_or(u32::MAX));
                    let heartbeat = Heartbeat {
                        state: NodeState::Operational,
                        uptime_s: beat.0,
                        table_version: beat.1,
                    };
                    ws.on_heartbeat(*node, &heartbeat);
                }
                poll(&mut ws, &instance, at(now), &mut nodes, mode);
            }
            3 => poll(&mut ws, &instance, at(now), &mut nodes, mode),
            4 => {
                // Some answers arrive.
                let count = u.int_in_range(0..=nodes.answers.len())?;
                deliver(&mut ws, &mut nodes, count);
            }
            5 => {
                let node = u.int_in_range(1..=3)?;
                nodes.boot(node);
                let version = nodes.beat.get(&node).map_or(1, |b| b.1);
                nodes.beat.insert(node, (0, version));
                ws.on_heartbeat(
                    node,
                    &Heartbeat {
                        state: NodeState::Operational,
                        uptime_s: 0,
                        table_version: version,
                    },
                );
            }
            6 => {
                mode = match u.int_in_range(0..=2)? {
                    0 => Mode::Apply,
                    1 => Mode::Refuse,
                    _ => Mode::Lose,
                };
            }
            7 => {
                let node = u.int_in_range(1..=3)?;
                let heartbeat = Heartbeat {
                    state: NodeState::Operational,
                    uptime_s: u.arbitrary()?,
                    table_version: u.int_in_range(0..=2)?,
                };
                nodes
                    .beat
                    .insert(node, (heartbeat.uptime_s, heartbeat.table_version));
                ws.on_heartbeat(node, &heartbeat);
            }
            _ => while ws.next_event().is_some() {},
        }
        send(&mut ws, at(now), &mut nodes, mode);
    }
    // A clean bus: every node restarts (its heartbeat's uptime back to 0), everything answered.
    for node in 1..=3u8 {
        let version = nodes.beat.get(&node).map_or(1, |b| b.1);
        for uptime in [u32::MAX, 0] {
            ws.on_heartbeat(
                node,
                &Heartbeat {
                    state: NodeState::Operational,
                    uptime_s: uptime,
                    table_version: version,
                },
            );
        }
        nodes.boot(node);
    }
    for _ in 0..50 {
        poll(&mut ws, &instance, at(now), &mut nodes, Mode::Apply);
        let all = nodes.answers.len();
        deliver(&mut ws, &mut nodes, all);
        send(&mut ws, at(now), &mut nodes, Mode::Apply);
        if ws.is_settled() && nodes.answers.is_empty() {
            break;
        }
        now += 1_000;
    }
    assert!(
        ws.is_settled(),
        "the workspace did not settle on a clean bus"
    );
    for view in ws.filters() {
        let t = view.target;
        let applied = nodes
            .filters
            .get(&t.node)
            .and_then(|f| f.get(&t.index))
            .copied();
        assert_eq!(
            applied,
            Some(view.wanted),
            "node {} connection {} does not apply its wanted φ",
            t.node,
            t.index
        );
    }
    Ok(())
}

/// What `pab-intent` does with a decoded frame.
fn dispatch(ws: &mut Workspace, source: u8, message: &Message, now: Instant) {
    match message {
        Message::Desire(desire) => {
            let _ = ws.on_desire(source, desire, now);
        }
        Message::FilterStatus(status) => {
            ws.on_filter_status(source, status);
        }
        Message::Fault(fault) => {
            ws.on_fault(source, fault);
        }
        Message::Heartbeat(heartbeat) => {
            ws.on_heartbeat(source, heartbeat);
        }
        _ => {}
    }
}

/// Polls, then checks the selection, the wanted φ and the deadline.
fn poll(ws: &mut Workspace, instance: &Instance, now: Instant, nodes: &mut Nodes, mode: Mode) {
    ws.poll(now);
    send(ws, now, nodes, mode);
    let intensities = ws.intensities();
    if let Ok(selection) = hbba::solve(instance, &intensities, hbba::DEFAULT_BUDGET) {
        let mask = selection.strategies().fold(0u64, |m, s| m | 1 << s);
        assert_eq!(ws.strategies(), mask, "the selection is not the solver's");
        for view in ws.filters() {
            let wanted = selection
                .strategies()
                .filter_map(|s| instance.strategies.get(s))
                .flat_map(|s| s.filters.iter())
                .find(|f| f.connection == view.target.connection)
                .map_or(0, |f| f.phi as u8);
            assert_eq!(view.wanted, wanted, "connection {}", view.target.connection);
        }
    }
    if let Some(deadline) = ws.deadline(now) {
        let lease = ws.desires().deadline(now);
        assert!(
            deadline.micros_since(now).is_some() || Some(deadline) == lease,
            "a deadline in the past"
        );
    }
}

/// Takes every command out and hands it to the nodes as `mode` says.
fn send(ws: &mut Workspace, now: Instant, nodes: &mut Nodes, mode: Mode) {
    while let Some(command) = ws.next_command(now) {
        let set: FilterSet = command.set;
        assert_ne!(set.sequence, 0, "sequence number 0");
        let addressed = (0..CONNECTIONS)
            .map(target)
            .any(|t| t.node == command.node && t.port == set.port && t.index == set.connection);
        assert!(addressed, "a command to no filter: {command:?}");
        let key = (command.node, set.port, set.connection);
        if command.send > 1 {
            assert_eq!(
                nodes.sequences.get(&key),
                Some(&set.sequence),
                "a resend with another sequence number"
            );
        }
        nodes.sequences.insert(key, set.sequence);
        match mode {
            Mode::Lose => {}
            Mode::Apply => {
                if let Some(filters) = nodes.filters.get_mut(&command.node) {
                    filters.insert(set.connection, set.phi);
                }
                let status = FilterStatus {
                    profile: FilterStatus::SET_ONE_BY_ONE,
                    sequence: set.sequence,
                    filtered: 0,
                    closed: 0,
                    throttled: 0,
                };
                nodes.answers.push((command.node, Answer::Applied(status)));
            }
            Mode::Refuse => {
                let [s0, s1] = set.sequence.to_le_bytes();
                let fault = Fault {
                    code: FaultCode::FilterRefused,
                    count: 1,
                    detail: [3, set.port, set.connection, s0, s1],
                };
                nodes.answers.push((command.node, Answer::Refused(fault)));
            }
        }
    }
}

/// Delivers the first `count` answers, in order.
fn deliver(ws: &mut Workspace, nodes: &mut Nodes, count: usize) {
    let count = count.min(nodes.answers.len());
    let answers: Vec<(u8, Answer)> = nodes.answers.drain(..count).collect();
    for (node, answer) in answers {
        match answer {
            Answer::Applied(status) => {
                ws.on_filter_status(node, &status);
            }
            Answer::Refused(fault) => {
                ws.on_fault(node, &fault);
            }
        }
    }
}
