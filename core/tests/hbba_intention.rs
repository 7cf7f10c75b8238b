//! The intention workspace (`pab_core::hbba::intention`) against simulated nodes: random
//! instances, random scripts of desires, waits, node restarts, lost commands and refusing nodes,
//! in virtual time. Checked: every disable before any enable (when a command raises a
//! connection's pass rate, no connection passes more than the selection wants; after every
//! command, no connection passes more than both the previous and the current selection allow),
//! the plan reaches
//! the solver's φ on every node, a restart is re-applied, leases run out; and the worked cases
//! below by hand.

use std::collections::BTreeMap;

use pab_core::Instant;
use pab_core::hbba::intention::{
    ACK_TIMEOUT_US, Event, IntentionError, MAX_SENDS, Target, Workspace, passes_fewer,
};
use pab_core::hbba::{FilterSetting, Instance, Strategy as Plan};
use pab_core::protocol::{
    DesireFrame, Fault, FaultCode, FilterSet, FilterStatus, Heartbeat, NodeState,
};
use proptest::prelude::*;

/// Connections 0..CONNECTIONS; connection c is on node 1 + c % 3, port 0, index c.
const CONNECTIONS: u16 = 6;

fn target(connection: u16) -> Target {
    Target {
        connection,
        node: 1 + (connection % 3) as u8,
        port: 0,
        index: connection as u8,
    }
}

fn targets() -> Vec<Target> {
    (0..CONNECTIONS).map(target).collect()
}

fn at(us: u64) -> Instant {
    Instant::from_micros(us)
}

/// The simulated nodes and the bus between them and the workspace.
struct World {
    now: u64,
    /// Per node id: per connection index, the φ it applies; boot: all closed.
    filters: BTreeMap<u8, BTreeMap<u8, u8>>,
    /// Per node id: when it booted (µs).
    booted: BTreeMap<u8, u64>,
    /// Frames on their way to the workspace: (due µs, order, what).
    inbox: Vec<(u64, u64, Reply)>,
    order: u64,
    /// Lose this many of the next commands.
    lose: u32,
    /// Nodes that refuse every command (FilterRefused, detail 3).
    refusing: Vec<u8>,
    /// How long a node takes to answer, µs.
    delay: u64,
    /// Whether the disable-before-enable invariant is checked (clean bus, no refusals).
    check_order: bool,
    /// Every command sent: (µs, node, command).
    sent: Vec<(u64, u8, FilterSet, bool)>,
    next_heartbeat: u64,
    /// Per connection, the φ the selection before the current one wanted, and the current's
    /// (boot: closed, nothing selected).
    previous_wanted: BTreeMap<u16, u8>,
    wanted: BTreeMap<u16, u8>,
}

#[derive(Clone, Debug)]
enum Reply {
    Status(u8, FilterStatus),
    Refused(u8, FilterSet),
    Heartbeat(u8, Heartbeat),
}

impl World {
    fn new(delay: u64) -> World {
        let mut world = World {
            now: 0,
            filters: BTreeMap::new(),
            booted: BTreeMap::new(),
            inbox: Vec::new(),
            order: 0,
            lose: 0,
            refusing: Vec::new(),
            delay,
            check_order: true,
            sent: Vec::new(),
            next_heartbeat: 0,
            previous_wanted: BTreeMap::new(),
            wanted: BTreeMap::new(),
        };
        for node in 1..=3 {
            world.boot(node);
        }
        world
    }

    fn boot(&mut self, node: u8) {
        let filters = (0..CONNECTIONS)
            .filter(|&c| target(c).node == node)
            .map(|c| (c as u8, 0))
            .collect();
        self.filters.insert(node, filters);
        self.booted.insert(node, self.now);
        self.heartbeat(node);
    }

    fn heartbeat(&mut self, node: u8) {
        let uptime_s = ((self.now - self.booted[&node]) / 1_000_000) as u32;
        let beat = Heartbeat {
            state: NodeState::Operational,
            uptime_s,
            table_version: 1,
        };
        self.post(self.now, Reply::Heartbeat(node, beat));
    }

    fn post(&mut self, due: u64, reply: Reply) {
        self.order += 1;
        self.inbox.push((due, self.order, reply));
    }

    /// The pass rate of φ, for comparisons: 0 closed, else 1/φ (as a fraction of 255!).
    fn apply(&mut self, ws: &Workspace, node: u8, set: FilterSet) {
        self.sent.push((self.now, node, set, false));
        if self.lose > 0 {
            self.lose -= 1;
            return;
        }
        if self.refusing.contains(&node) {
            self.post(self.now + self.delay, Reply::Refused(node, set));
            return;
        }
        let before = self.filters[&node][&set.connection];
        if self.check_order && passes_fewer(before, set.phi) {
            // An increase: every other filter must already pass no more than wanted.
            for view in ws.filters() {
                let t = view.target;
                if (t.node, t.index) == (node, set.connection) {
                    continue;
                }
                let actual = self.filters[&t.node][&t.index];
                assert!(
                    !passes_fewer(view.wanted, actual),
                    "at {} µs node {node} connection {} goes {before} -> {} while node {} \
                     connection {} still has φ {actual} (wanted {})",
                    self.now,
                    set.connection,
                    set.phi,
                    t.node,
                    t.index,
                    view.wanted
                );
            }
        }
        self.filters
            .get_mut(&node)
            .unwrap()
            .insert(set.connection, set.phi);
        if let Some(last) = self.sent.last_mut() {
            last.3 = true;
        }
        let closed = 0;
        self.post(
            self.now + self.delay,
            Reply::Status(
                node,
                FilterStatus {
                    profile: FilterStatus::SET_ONE_BY_ONE,
                    sequence: set.sequence,
                    filtered: 2,
                    closed,
                    throttled: 0,
                },
            ),
        );
    }

    fn drain(&mut self, ws: &mut Workspace) {
        let wanted: BTreeMap<u16, u8> = ws
            .filters()
            .map(|v| (v.target.connection, v.wanted))
            .collect();
        if wanted != self.wanted {
            self.previous_wanted = std::mem::replace(&mut self.wanted, wanted);
        }
        while let Some(command) = ws.next_command(at(self.now)) {
            self.apply(ws, command.node, command.set);
            if self.check_order {
                self.check_between_selections();
            }
        }
    }

    /// No connection passes more than both the previous and the current selection allow.
    fn check_between_selections(&self) {
        for (&connection, &now) in &self.wanted {
            let t = target(connection);
            let actual = self.filters[&t.node][&t.index];
            let before = self.previous_wanted.get(&connection).copied().unwrap_or(0);
            assert!(
                !passes_fewer(now, actual) || !passes_fewer(before, actual),
                "at {} µs connection {connection} has φ {actual}: the previous selection wanted \
                 {before}, this one {now}",
                self.now
            );
        }
    }

    /// Runs the bus and the workspace to `t` µs.
    fn run_until(&mut self, ws: &mut Workspace, t: u64) {
        let mut guard = 0;
        loop {
            guard += 1;
            assert!(guard < 100_000, "stuck at {} µs", self.now);
            let next_reply = self.inbox.iter().map(|r| r.0).min();
            let next_ws = ws.deadline(at(self.now)).map(Instant::as_micros);
            let next = [next_reply, next_ws, Some(self.next_heartbeat)]
                .into_iter()
                .flatten()
                .min()
                .unwrap();
            if next > t {
                break;
            }
            self.now = self.now.max(next);
            if self.next_heartbeat <= self.now {
                for node in 1..=3 {
                    self.heartbeat(node);
                }
                self.next_heartbeat = self.now + 1_000_000;
            }
            self.inbox.sort_by_key(|r| (r.0, r.1));
            while self.inbox.first().is_some_and(|r| r.0 <= self.now) {
                let (_, _, reply) = self.inbox.remove(0);
                match reply {
                    Reply::Status(node, status) => {
                        ws.on_filter_status(node, &status);
                    }
                    Reply::Refused(node, set) => {
                        let [s0, s1] = set.sequence.to_le_bytes();
                        let fault = Fault {
                            code: FaultCode::FilterRefused,
                            count: 1,
                            detail: [3, set.port, set.connection, s0, s1],
                        };
                        ws.on_fault(node, &fault);
                    }
                    Reply::Heartbeat(node, beat) => {
                        ws.on_heartbeat(node, &beat);
                    }
                }
                self.drain(ws);
            }
            ws.poll(at(self.now));
            self.drain(ws);
        }
        self.now = t;
        ws.poll(at(self.now));
        self.drain(ws);
    }

    fn desire(&mut self, ws: &mut Workspace, source: u8, id: u16, class: u8, intensity: u16) {
        let frame = DesireFrame {
            class,
            intensity,
            lease_ms: 60_000,
            id,
        };
        let _ = ws.on_desire(source, &frame, at(self.now));
        ws.poll(at(self.now));
        self.drain(ws);
    }
}

/// The φ every filtered connection should have under the solver's own answer for the
/// workspace's intensities: the selected strategy's, or 0.
fn expected(instance: &Instance, ws: &Workspace) -> BTreeMap<u16, u8> {
    let selection = pab_core::hbba::solve(instance, &ws.intensities(), 1_000_000).unwrap();
    let mut out = BTreeMap::new();
    for s in &instance.strategies {
        for f in &s.filters {
            out.insert(f.connection, 0);
        }
    }
    for index in selection.strategies() {
        for f in &instance.strategies[index].filters {
            out.insert(f.connection, f.phi as u8);
        }
    }
    out
}

fn assert_reached(instance: &Instance, ws: &Workspace, world: &World) {
    assert!(ws.is_settled(), "the plan is not settled");
    for (connection, phi) in expected(instance, ws) {
        let t = target(connection);
        assert_eq!(
            world.filters[&t.node][&t.index], phi,
            "connection {connection} on node {}",
            t.node
        );
    }
}

fn instance_strategy() -> impl Strategy<Value = Instance> {
    let strategy = (
        0u8..3,
        0u16..5,
        0u32..8,
        prop::collection::btree_map(
            0..CONNECTIONS,
            prop_oneof![Just(0u16), Just(1), Just(2), Just(3), Just(255)],
            0..4,
        ),
    )
        .prop_map(|(class, utility, cost, filters)| {
            let mut s = Plan::new(class, utility);
            s.costs[0] = cost;
            for (connection, phi) in filters {
                s.filters.push(FilterSetting { connection, phi }).unwrap();
            }
            s
        });
    prop::collection::vec(strategy, 1..8).prop_map(|strategies| {
        let mut instance = Instance {
            classes: 3,
            ..Instance::default()
        };
        instance.capacities.push(10).unwrap();
        for s in strategies {
            instance.strategies.push(s).unwrap();
        }
        instance
    })
}

#[derive(Clone, Debug)]
enum Step {
    Desire {
        source: u8,
        class: u8,
        intensity: u16,
    },
    Wait(u64),
    Restart(u8),
    Lose(u32),
    Refuse(u8),
}

fn step(clean: bool) -> impl Strategy<Value = Step> {
    let faults = if clean { 0 } else { 1 };
    prop_oneof![
        4 => (1u8..4, 0u8..3, prop_oneof![Just(0u16), 1u16..6])
            .prop_map(|(source, class, intensity)| Step::Desire { source, class, intensity }),
        3 => (0u64..600_000).prop_map(Step::Wait),
        1 => (1u8..4).prop_map(Step::Restart),
        faults => (1u32..4).prop_map(Step::Lose),
        faults => (1u8..4).prop_map(Step::Refuse),
    ]
}

fn play(instance: &Instance, script: &[Step], delay: u64, clean: bool) {
    let mut ws = Workspace::new(instance, &targets()).unwrap();
    let mut world = World::new(delay);
    world.check_order = clean;
    world.run_until(&mut ws, 0);
    for step in script {
        match *step {
            Step::Desire {
                source,
                class,
                intensity,
            } => world.desire(&mut ws, source, 0, class, intensity),
            Step::Wait(us) => {
                let t = world.now + us;
                world.run_until(&mut ws, t);
            }
            Step::Restart(node) => {
                // Heartbeats count whole seconds: a restart shows once the last one said ≥ 1 s.
                let t = world.now.max(world.booted[&node] + 1_000_000) + 1_000_000;
                world.run_until(&mut ws, t);
                world.boot(node);
                let t = world.now;
                world.run_until(&mut ws, t);
            }
            Step::Lose(n) => world.lose = n,
            Step::Refuse(node) => world.refusing.push(node),
        }
    }
    let t = world.now + 2_000_000;
    world.run_until(&mut ws, t);
    if !clean {
        // Lost and refused commands are not retried until something changes: a restart of
        // every node on a clean bus re-applies everything.
        world.lose = 0;
        world.refusing.clear();
        for node in 1..=3 {
            let t = world.now.max(world.booted[&node] + 1_000_000) + 1_000_000;
            world.run_until(&mut ws, t);
            world.boot(node);
        }
        let t = world.now + 2_000_000;
        world.run_until(&mut ws, t);
    }
    assert_reached(instance, &ws, &world);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn disables_precede_enables_and_the_plan_reaches_the_solver(
        instance in instance_strategy(),
        script in prop::collection::vec(step(true), 0..25),
        delay in prop_oneof![Just(0u64), 1u64..200_000],
    ) {
        play(&instance, &script, delay, true);
    }

    #[test]
    fn lost_and_refused_commands_end_in_the_solver_after_restarts(
        instance in instance_strategy(),
        script in prop::collection::vec(step(false), 0..25),
        delay in 0u64..200_000,
    ) {
        play(&instance, &script, delay, false);
    }
}

/// The tour guide's shape: face (FACE 1 / FACE 3), qr (QR 1), voice (VOICE 1, QR 0); one CPU.
fn tour() -> Instance {
    let mut instance = Instance {
        classes: 3,
        ..Instance::default()
    };
    // 80: face_full and voice_localise do not fit together.
    instance.capacities.push(80).unwrap();
    let mut add = |class, utility, cost, filters: &[(u16, u16)]| {
        let mut s = Plan::new(class, utility);
        s.costs[0] = cost;
        for &(connection, phi) in filters {
            s.filters.push(FilterSetting { connection, phi }).unwrap();
        }
        instance.strategies.push(s).unwrap();
    };
    // FACE = 0 (node 1), QR = 1 (node 2), VOICE = 2 (node 3).
    add(0, 3, 40, &[(0, 1)]);
    add(0, 2, 15, &[(0, 3)]);
    add(1, 2, 30, &[(1, 1)]);
    add(2, 3, 50, &[(2, 1), (1, 0)]);
    instance
}

fn events(ws: &mut Workspace) -> Vec<Event> {
    std::iter::from_fn(|| ws.next_event()).collect()
}

#[test]
fn a_voice_desire_closes_qr_and_throttles_faces_before_opening_voice() {
    let instance = tour();
    let mut ws = Workspace::new(&instance, &targets()).unwrap();
    let mut world = World::new(5_000);
    world.run_until(&mut ws, 10_000);
    world.desire(&mut ws, 9, 1, 0, 2);
    world.desire(&mut ws, 9, 2, 1, 1);
    world.run_until(&mut ws, 100_000);
    assert_eq!(ws.strategies(), 0b0101);
    assert_eq!(world.filters[&1][&0], 1);
    assert_eq!(world.filters[&2][&1], 1);
    assert_eq!(world.filters[&3][&2], 0);
    world.sent.clear();
    let _ = events(&mut ws);
    world.desire(&mut ws, 9, 3, 2, 3);
    world.run_until(&mut ws, 200_000);
    // voice_localise + face_throttled: 3·3 + 2·2 = 13, above face_full + qr_full's 8 and
    // voice alone's 9.
    assert_eq!(ws.strategies(), 0b1010);
    let order: Vec<(u8, u8, u8, u64)> = world
        .sent
        .iter()
        .map(|&(t, node, set, _)| (node, set.connection, set.phi, t))
        .collect();
    // FACE throttled and QR closed at once, VOICE opened once both are acknowledged (the
    // nodes answer in 5 ms).
    assert_eq!(order.len(), 3, "{order:?}");
    assert_eq!((order[0].0, order[0].1, order[0].2), (1, 0, 3));
    assert_eq!((order[1].0, order[1].1, order[1].2), (2, 1, 0));
    assert_eq!((order[2].0, order[2].1, order[2].2), (3, 2, 1));
    assert_eq!(order[2].3 - order[0].3, 5_000);
    let events = events(&mut ws);
    assert!(matches!(
        events[0],
        Event::Selected {
            strategies: 0b1010,
            objective: 13
        }
    ));
    assert_eq!(
        events.last(),
        Some(&Event::Settled {
            refused: 0,
            gave_up: 0
        })
    );
}

#[test]
fn a_lease_that_runs_out_is_dropped_and_the_intention_recomputed() {
    let instance = tour();
    let mut ws = Workspace::new(&instance, &targets()).unwrap();
    let mut world = World::new(1_000);
    world.run_until(&mut ws, 0);
    let frame = DesireFrame {
        class: 2,
        intensity: 3,
        lease_ms: 500,
        id: 7,
    };
    ws.on_desire(4, &frame, at(0)).unwrap();
    world.run_until(&mut ws, 499_999);
    assert_eq!(ws.strategies(), 0b1000);
    assert_eq!(world.filters[&3][&2], 1);
    let _ = events(&mut ws);
    world.run_until(&mut ws, 500_000);
    let seen = events(&mut ws);
    assert_eq!(seen.first(), Some(&Event::Expired));
    assert!(seen.contains(&Event::Selected {
        strategies: 0,
        objective: 0
    }));
    assert_eq!(ws.strategies(), 0);
    world.run_until(&mut ws, 600_000);
    assert_eq!(world.filters[&3][&2], 0);
}

#[test]
fn a_restarted_node_gets_every_filter_again_closed_ones_included() {
    let instance = tour();
    let mut ws = Workspace::new(&instance, &targets()).unwrap();
    let mut world = World::new(1_000);
    world.run_until(&mut ws, 0);
    world.desire(&mut ws, 9, 1, 0, 2);
    world.desire(&mut ws, 9, 2, 2, 3);
    world.run_until(&mut ws, 2_500_000);
    assert_eq!(world.filters[&1][&0], 3);
    world.sent.clear();
    let _ = events(&mut ws);
    world.boot(1);
    world.boot(2);
    world.run_until(&mut ws, 2_600_000);
    assert_eq!(world.filters[&1][&0], 3);
    let mut to: Vec<(u8, u8, u8)> = world
        .sent
        .iter()
        .map(|&(_, node, set, _)| (node, set.connection, set.phi))
        .collect();
    to.sort();
    // Node 2's QR is closed, as at boot: commanded all the same.
    assert_eq!(to, [(1, 0, 3), (2, 1, 0)]);
    let seen = events(&mut ws);
    assert!(seen.contains(&Event::Restarted { node: 1 }));
    assert!(seen.contains(&Event::Restarted { node: 2 }));
}

#[test]
fn an_unanswered_command_is_sent_again_then_given_up() {
    let instance = tour();
    let mut ws = Workspace::new(&instance, &targets()).unwrap();
    ws.assume_filters(0);
    let mut world = World::new(1_000);
    world.check_order = false;
    world.run_until(&mut ws, 0);
    world.lose = u32::from(MAX_SENDS);
    world.desire(&mut ws, 9, 1, 2, 3);
    world.run_until(&mut ws, 2_000_000);
    let voice: Vec<u64> = world
        .sent
        .iter()
        .filter(|(_, node, _, _)| *node == 3)
        .map(|(t, ..)| *t)
        .collect();
    assert_eq!(voice, [0, ACK_TIMEOUT_US, 2 * ACK_TIMEOUT_US]);
    let seen = events(&mut ws);
    assert!(seen.contains(&Event::GaveUp {
        target: target(2),
        phi: 1
    }));
    assert!(seen.contains(&Event::Settled {
        refused: 0,
        gave_up: 1
    }));
}

#[test]
fn one_refusal_settles_every_earlier_command_to_that_node() {
    // Two filters on node 1: connections 0 and 3.
    let mut instance = Instance {
        classes: 1,
        ..Instance::default()
    };
    instance.capacities.push(1).unwrap();
    let mut s = Plan::new(0, 1);
    s.filters
        .push(FilterSetting {
            connection: 0,
            phi: 0,
        })
        .unwrap();
    s.filters
        .push(FilterSetting {
            connection: 3,
            phi: 0,
        })
        .unwrap();
    instance.strategies.push(s).unwrap();
    let mut ws = Workspace::new(&instance, &targets()).unwrap();
    ws.poll(at(0));
    let first = ws.next_command(at(0)).unwrap();
    let second = ws.next_command(at(0)).unwrap();
    assert_eq!(ws.next_command(at(0)), None);
    assert!(first.reduction && second.reduction);
    assert!(first.set.sequence < second.set.sequence);
    let [s0, s1] = second.set.sequence.to_le_bytes();
    let fault = Fault {
        code: FaultCode::FilterRefused,
        count: 2,
        detail: [3, 0, 3, s0, s1],
    };
    assert_eq!(ws.on_fault(1, &fault), 2);
    assert!(ws.is_settled());
    let seen = events(&mut ws);
    assert!(seen.contains(&Event::Refused {
        target: target(0),
        phi: 0,
        why: 3
    }));
    assert!(seen.contains(&Event::Settled {
        refused: 2,
        gave_up: 0
    }));
    // Another node's fault, or another code, settles nothing.
    assert_eq!(ws.on_fault(2, &fault), 0);
}

#[test]
fn instances_the_workspace_cannot_serve_are_refused() {
    let instance = tour();
    assert_eq!(
        Workspace::new(&instance, &targets()[..2]).err(),
        Some(IntentionError::MissingTarget { connection: 2 })
    );
    let mut twice = targets();
    twice.push(target(1));
    assert_eq!(
        Workspace::new(&instance, &twice).err(),
        Some(IntentionError::DuplicateTarget { connection: 1 })
    );
    let mut wide = tour();
    wide.strategies[0].filters[0].phi = 256;
    assert_eq!(
        Workspace::new(&wide, &targets()).err(),
        Some(IntentionError::PhiTooLarge { strategy: 0 })
    );
    let mut nowhere = targets();
    nowhere[0].node = 0;
    assert_eq!(
        Workspace::new(&instance, &nowhere).err(),
        Some(IntentionError::InvalidNode { connection: 0 })
    );
}

#[test]
fn a_refused_phi_is_not_asked_again_until_the_node_restarts() {
    let instance = tour();
    let mut ws = Workspace::new(&instance, &targets()).unwrap();
    ws.assume_filters(0);
    let mut world = World::new(1_000);
    world.check_order = false;
    world.refusing.push(3);
    world.run_until(&mut ws, 0);
    world.desire(&mut ws, 9, 1, 2, 3);
    world.run_until(&mut ws, 500_000);
    let to_voice = |world: &World| {
        world
            .sent
            .iter()
            .filter(|(_, node, set, _)| *node == 3 && set.phi == 1)
            .count()
    };
    assert_eq!(to_voice(&world), 1);
    // Another selection that still wants VOICE at 1: not asked again.
    world.desire(&mut ws, 9, 2, 0, 2);
    world.run_until(&mut ws, 1_500_000);
    assert_eq!(ws.strategies(), 0b1010);
    assert_eq!(to_voice(&world), 1);
    // After a restart it is.
    world.refusing.clear();
    world.boot(3);
    world.run_until(&mut ws, 2_000_000);
    assert_eq!(to_voice(&world), 2);
    assert_eq!(world.filters[&3][&2], 1);
}

#[test]
fn the_workspace_is_as_large_as_documented() {
    // The module documentation says 5 456 bytes on x86-64, under 5.5 KiB.
    let size = std::mem::size_of::<Workspace>();
    assert!(size <= 5 * 1024 + 512, "{size} bytes");
}
