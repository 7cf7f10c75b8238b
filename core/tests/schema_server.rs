//! The schema server (`pab_core::schema`): the loop's steps as DESIGN.md ("Schema server:
//! decisions") fixes them, each safety event, the queue and the high-priority channel, the
//! fixed-point motion against an f64 reference, and properties over random schemas and inputs.

use pab_core::Instant;
use pab_core::schema::build;
use pab_core::schema::{
    AXES, Action, Config, Event, Gripper, MAX_COORD, MAX_ENCODED, Measure, Origin, Pose,
    QUEUE_DEPTH, Reaction, Refusal, Safety, Schema, SchemaError, Server, Source, Tick, Trigger,
};
use proptest::prelude::*;

const PERIOD: u32 = 1000;

fn at(tick: u64) -> Instant {
    Instant::from_micros(tick * u64::from(PERIOD))
}

/// A server, and a robot that follows its attractor exactly (a perfectly stiff drive) with no
/// force on it: the loop's logic without a plant.
struct Rig {
    server: Server,
    tick: u64,
    pose: Pose,
    wrench: [i32; AXES],
}

impl Rig {
    fn new(config: Config) -> Rig {
        let mut server = Server::new(config).expect("valid config");
        server.set_pose([0; AXES], at(0));
        server.set_wrench([0; AXES], at(0));
        Rig {
            server,
            tick: 0,
            pose: [0; AXES],
            wrench: [0; AXES],
        }
    }

    fn step(&mut self) -> Tick {
        self.tick += 1;
        let now = at(self.tick);
        self.server.set_pose(self.pose, now);
        self.server.set_wrench(self.wrench, now);
        let out = self.server.tick(now);
        if let Some(s) = out.setpoint {
            self.pose = s.attractor;
        }
        out
    }

    /// Steps until a transition, at most `limit` ticks: the tick count and the transition.
    fn until_transition(&mut self, limit: u64) -> (u64, pab_core::schema::Transition) {
        for _ in 0..limit {
            let out = self.step();
            if let Some(t) = out.transitions.first() {
                return (self.tick, *t);
            }
        }
        panic!("no transition within {limit} ticks");
    }
}

fn goal_x(x: i32) -> Pose {
    [x, 0, 0, 0, 0, 0]
}

#[test]
fn a_queued_schema_is_installed_from_the_wait_and_runs_in_the_same_tick() {
    let mut rig = Rig::new(Config::new(PERIOD));
    assert_eq!(rig.server.current(), Schema::WAIT_QUEUE);
    rig.step();
    assert_eq!(
        rig.server.enqueue(build::move_to(1, goal_x(10), 1000)),
        Ok(1)
    );
    let out = rig.step();
    assert_eq!(out.transitions.len(), 1);
    let t = out.transitions[0];
    assert_eq!(
        (t.ended, t.installed, t.by, t.source),
        (
            Schema::WAIT_QUEUE,
            1,
            Trigger::Reaction(0, Event::QueueReady),
            Origin::Queue
        )
    );
    // Installed in step 5 and iterated in step 6 of the same tick: 1 mm/s is 1 µm a tick.
    assert_eq!(out.setpoint.unwrap().attractor, goal_x(1));
}

#[test]
fn one_millimetre_per_second_at_one_kilohertz_is_one_micrometre_a_tick_and_ends_on_the_goal() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(250), 1000))
        .unwrap();
    rig.server.enqueue(build::idle(2, 0)).unwrap();
    for k in 1..=250 {
        let out = rig.step();
        assert_eq!(out.setpoint.unwrap().attractor[0], k, "tick {k}");
        if k < 250 {
            assert_eq!(rig.server.current(), 1);
        }
    }
    // Done on tick 250 (the attractor is on the goal); the event is seen at the next tick.
    let out = rig.step();
    assert_eq!(out.transitions[0].ended, 1);
    assert_eq!(out.transitions[0].installed, 2);
    assert_eq!(out.transitions[0].by, Trigger::Reaction(0, Event::Done));
}

#[test]
fn speeds_that_are_not_whole_micrometres_a_tick_lose_nothing() {
    // 1.5 mm/s: 1.5 µm a tick, so 3 µm every two ticks exactly.
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(1_000_000), 1500))
        .unwrap();
    for k in 1..=1000u64 {
        let x = rig.step().setpoint.unwrap().attractor[0];
        assert_eq!(x as u64, k * 3 / 2, "tick {k}");
    }
    // 0.3 mm/s at 1 kHz: the attractor moves once every three or four ticks, 300 µm a second.
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(-1_000_000), 300))
        .unwrap();
    for _ in 0..1000 {
        rig.step();
    }
    assert_eq!(rig.pose[0], -300);
}

#[test]
fn an_atomic_action_runs_once_then_one_shot_installs_the_next() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::gripper(1, Gripper::Closed))
        .unwrap();
    rig.server.enqueue(build::idle(2, 0)).unwrap();
    let out = rig.step();
    assert_eq!(out.transitions[0].installed, 1);
    assert_eq!(out.setpoint.unwrap().gripper, Gripper::Closed);
    let out = rig.step();
    assert_eq!(out.transitions[0].ended, 1);
    assert_eq!(out.transitions[0].installed, 2);
    assert_eq!(out.transitions[0].by, Trigger::Reaction(0, Event::OneShot));
}

#[test]
fn a_high_priority_schema_preempts_at_the_next_tick_and_has_not_run_before_one_shot() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(1000), 1000))
        .unwrap();
    rig.step();
    rig.step();
    let mut hp = build::gripper(7, Gripper::Closed);
    hp.reactions[0].next = Source::HighPriority;
    rig.server.high_priority(hp.clone(), 0).unwrap();
    assert_eq!(rig.server.high_priority(hp, 0), Err(Refusal::Busy));
    let out = rig.step();
    assert_eq!(
        out.transitions.len(),
        1,
        "one-shot must not fire before the action ran"
    );
    assert_eq!(out.transitions[0].installed, 7);
    assert_eq!(out.transitions[0].by, Trigger::HighPriority);
    assert_eq!(out.transitions[0].source, Origin::HighPriority);
    let out = rig.step();
    assert_eq!(out.transitions[0].installed, Schema::WAIT_HIGH_PRIORITY);
    // The queue still holds nothing new; the move was pre-empted, not resumed.
    assert_eq!(rig.server.queued(), 0);
}

#[test]
fn an_emergency_stop_relieves_in_the_tick_it_is_seen_and_the_queue_waits_for_the_high_priority_channel()
 {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(100_000), 10_000))
        .unwrap();
    rig.server
        .enqueue(build::move_to(2, goal_x(0), 10_000))
        .unwrap();
    for _ in 0..10 {
        rig.step();
    }
    // The robot lags its attractor by 30 µm (the drive is soft): a stop holds it where it is.
    rig.pose[0] -= 30;
    let measured = rig.pose;
    rig.server.emergency_stop();
    rig.tick += 1;
    rig.server.set_pose(measured, at(rig.tick));
    let out = rig.server.tick(at(rig.tick));
    assert_eq!(
        out.transitions[0].by,
        Trigger::Safety(Safety::EmergencyStop)
    );
    assert_eq!(
        out.transitions[0].installed,
        Schema::SAFETY + Safety::EmergencyStop as u16
    );
    assert_eq!(out.transitions[0].source, Origin::Innate);
    assert_eq!(out.setpoint.unwrap().attractor, measured);
    assert_eq!(rig.server.fault(), Some(Safety::EmergencyStop));
    let (_, t) = rig.until_transition(5);
    assert_eq!(t.installed, Schema::WAIT_HIGH_PRIORITY);
    for _ in 0..100 {
        assert!(rig.step().transitions.is_empty(), "the queue must not run");
    }
    assert_eq!(rig.server.queued(), 1);
    assert_eq!(rig.pose, measured);
    // The high-priority channel installs a schema that acknowledges the stop (the first) and
    // clears the fault; the queue runs after.
    assert_eq!(
        rig.server.high_priority(build::idle(9, 5), 0),
        Err(Refusal::StopNotAcknowledged)
    );
    assert_eq!(rig.server.stop_number(), 1);
    rig.server.high_priority(build::idle(9, 5), 1).unwrap();
    let (_, t) = rig.until_transition(2);
    assert_eq!((t.installed, t.by), (9, Trigger::HighPriority));
    assert_eq!(rig.server.fault(), None);
    let (_, t) = rig.until_transition(10);
    assert_eq!(t.installed, 2);
}

#[test]
fn abort_empties_the_queue_and_holds_the_attractor() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(100_000), 10_000))
        .unwrap();
    rig.server
        .enqueue(build::move_to(2, goal_x(0), 10_000))
        .unwrap();
    for _ in 0..10 {
        rig.step();
    }
    let held = rig.pose;
    rig.server.abort();
    let out = rig.step();
    assert_eq!(out.transitions[0].by, Trigger::Abort);
    assert_eq!(out.transitions[0].installed, Schema::WAIT_HIGH_PRIORITY);
    assert_eq!(out.setpoint.unwrap().attractor, held);
    assert_eq!(rig.server.queued(), 0);
    assert_eq!(rig.server.fault(), None);
}

#[test]
fn force_above_the_limit_is_a_safety_event_before_any_reaction() {
    let mut config = Config::new(PERIOD);
    config.limits.force_limit = 20_000;
    let mut rig = Rig::new(config);
    // A touch-down whose contact threshold is above the safety limit: safety wins.
    rig.server
        .enqueue(build::move_to_touch(
            1,
            [0, 0, -1, 0, 0, 0],
            1000,
            30_000,
            100_000,
        ))
        .unwrap();
    rig.step();
    rig.wrench = [0, 0, 25_000, 0, 0, 0];
    let (_, t) = rig.until_transition(2);
    assert_eq!(t.by, Trigger::Safety(Safety::Force));
    // At 19.9 N along a diagonal the magnitude is below the limit: no event.
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server.enqueue(build::idle(1, 0)).unwrap();
    rig.step();
    rig.wrench = [14_000, 14_000, 0, 0, 0, 0];
    for _ in 0..10 {
        assert!(rig.step().transitions.is_empty());
    }
    rig.wrench = [30_000, 30_000, 30_000, 0, 0, 0];
    assert_eq!(rig.step().transitions[0].by, Trigger::Safety(Safety::Force));
}

#[test]
fn move_to_touch_ends_on_contact_against_its_direction() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to_touch(
            1,
            [0, 0, -5, 0, 0, 0],
            1000,
            3000,
            100_000,
        ))
        .unwrap();
    rig.server.enqueue(build::idle(2, 0)).unwrap();
    for _ in 0..20 {
        rig.step();
    }
    assert_eq!(rig.pose[2], -20);
    // A sideways force is no contact; an upward one is.
    rig.wrench = [5000, 0, 0, 0, 0, 0];
    assert!(rig.step().transitions.is_empty());
    rig.wrench = [0, 0, 3000, 0, 0, 0];
    let t = rig.step().transitions[0];
    assert_eq!(
        (t.ended, t.installed, t.by),
        (
            1,
            2,
            Trigger::Reaction(0, Event::Above(Measure::Contact, 3000))
        )
    );
}

#[test]
fn move_to_touch_that_meets_nothing_asks_the_high_priority_channel() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to_touch(1, [0, 0, -1, 0, 0, 0], 1000, 3000, 50))
        .unwrap();
    let (tick, t) = rig.until_transition(100);
    assert_eq!(t.installed, 1);
    let (end, t) = rig.until_transition(100);
    assert_eq!(
        (t.by, t.installed),
        (
            Trigger::Reaction(1, Event::Done),
            Schema::WAIT_HIGH_PRIORITY
        )
    );
    assert_eq!(end - tick, 50);
    assert_eq!(rig.pose[2], -50);
}

#[test]
fn the_attractor_is_never_commanded_outside_the_workspace() {
    let mut config = Config::new(PERIOD);
    config.limits.workspace_max[0] = 100;
    let mut rig = Rig::new(config);
    rig.server
        .enqueue(build::move_to(1, goal_x(1000), 1000))
        .unwrap();
    let mut last = 0;
    for _ in 0..200 {
        let out = rig.step();
        let x = out.setpoint.unwrap().attractor[0];
        assert!(x <= 100, "commanded {x}");
        if let Some(t) = out
            .transitions
            .iter()
            .find(|t| matches!(t.by, Trigger::Safety(_)))
        {
            assert_eq!(t.by, Trigger::Safety(Safety::Limit));
            assert_eq!(x, 100);
            last = rig.tick;
            break;
        }
    }
    assert_eq!(last, 101, "the 101st µm is refused on its own tick");
}

#[test]
fn a_robot_pushed_out_of_the_workspace_may_be_brought_back() {
    let mut config = Config::new(PERIOD);
    config.limits.workspace_max[0] = 100;
    let mut rig = Rig::new(config);
    rig.server.enqueue(build::idle(1, 0)).unwrap();
    rig.step();
    // Pushed out by hand.
    rig.pose[0] = 150;
    let t = rig.step().transitions[0];
    assert_eq!(t.by, Trigger::Safety(Safety::Limit));
    rig.until_transition(3);
    // Back in through the high-priority channel: no limit event while coming back.
    let stop = rig.server.stop_number();
    rig.server
        .high_priority(build::move_to(2, goal_x(50), 1000), stop)
        .unwrap();
    rig.until_transition(2);
    for _ in 0..100 {
        let out = rig.step();
        assert!(
            out.transitions
                .iter()
                .all(|t| t.installed != Schema::SAFETY + Safety::Limit as u16)
        );
    }
    assert_eq!(rig.pose[0], 50);
}

#[test]
fn the_watchdog_ends_a_schema_that_overruns_its_budget() {
    let mut config = Config::new(PERIOD);
    config.watchdog_margin_ms = 100;
    let mut rig = Rig::new(config);
    // 10 ms nominal (10 µm at 1 mm/s): budget 10 × 1.5 + 100 ms. No reaction ends it.
    let mut s = build::move_to(1, goal_x(10), 1000);
    s.reactions.clear();
    rig.server.enqueue(s).unwrap();
    let (installed, _) = rig.until_transition(2);
    let (end, t) = rig.until_transition(1000);
    assert_eq!(t.by, Trigger::Safety(Safety::Watchdog));
    assert_eq!(
        end - installed,
        116,
        "115 ms of budget, exceeded on the next tick"
    );
}

#[test]
fn an_explicit_watchdog_budget_replaces_the_default() {
    let mut rig = Rig::new(Config::new(PERIOD));
    let mut s = build::idle(1, 0);
    s.reactions.clear();
    s.watchdog_ms = 20;
    rig.server.enqueue(s).unwrap();
    let (start, _) = rig.until_transition(2);
    let (end, t) = rig.until_transition(100);
    assert_eq!(t.by, Trigger::Safety(Safety::Watchdog));
    assert_eq!(end - start, 21);
}

#[test]
fn a_stale_pose_stops_a_moving_schema_but_not_a_wait() {
    let mut server = Server::new(Config::new(PERIOD)).unwrap();
    server.set_pose([0; AXES], at(0));
    server.set_wrench([0; AXES], at(0));
    // Waiting on the queue with no frames: no fault (nothing moves).
    for k in 1..200 {
        assert!(server.tick(at(k)).transitions.is_empty());
    }
    server.enqueue(build::move_to(1, goal_x(10), 1000)).unwrap();
    // Installed from the wait (whose reactions step 4 scans), it runs one iteration; its own
    // safety events are tested from the next tick on.
    let out = server.tick(at(200));
    assert_eq!(out.transitions[0].installed, 1);
    let out = server.tick(at(201));
    assert_eq!(out.transitions[0].by, Trigger::Safety(Safety::StaleSensor));
}

#[test]
fn a_sensor_the_reactions_read_must_be_fresh() {
    let mut rig = Rig::new(Config::new(PERIOD));
    let mut s = build::idle(1, 0);
    s.reactions[0] = Reaction {
        event: Event::Above(Measure::Sensor(3), 10),
        next: Source::Queue,
    };
    rig.server.enqueue(s).unwrap();
    rig.server.set_sensor(3, 5, at(1));
    let (_, t) = rig.until_transition(2);
    assert_eq!(t.installed, 1);
    rig.server.set_sensor(3, 11, at(2));
    let t = rig.step().transitions[0];
    assert_eq!(
        t.by,
        Trigger::Reaction(0, Event::Above(Measure::Sensor(3), 10))
    );
    assert!(!rig.server.set_sensor(8, 0, at(3)));
    // Never refreshed: stale after 50 ms.
    let mut s = build::idle(2, 0);
    s.reactions[0].event = Event::Above(Measure::Sensor(4), 10);
    rig.server.high_priority(s, 0).unwrap();
    // Installed in step 2, its sensor found stale in step 3 of the same tick.
    let out = rig.step();
    assert_eq!(out.transitions[0].installed, 2);
    assert_eq!(out.transitions[1].by, Trigger::Safety(Safety::StaleSensor));
}

#[test]
fn a_late_tick_is_an_overrun() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server.enqueue(build::idle(1, 0)).unwrap();
    rig.step();
    rig.tick += 2; // 3 ms since the previous tick: more than two periods.
    let t = rig.step().transitions[0];
    assert_eq!(t.by, Trigger::Safety(Safety::Overrun));
}

#[test]
fn innate_schemas_are_installed_by_index_and_unknown_ones_refused() {
    let mut config = Config::new(PERIOD);
    config
        .innate
        .push(build::gripper(40, Gripper::Closed))
        .unwrap();
    let mut rig = Rig::new(config);
    let mut s = build::idle(1, 2);
    s.reactions[0].next = Source::Innate(0);
    rig.server.enqueue(s.clone()).unwrap();
    rig.until_transition(2);
    let (_, t) = rig.until_transition(10);
    assert_eq!((t.installed, t.source), (40, Origin::Innate));
    s.reactions[0].next = Source::Innate(1);
    assert_eq!(rig.server.enqueue(s), Err(Refusal::UnknownInnate));
}

#[test]
fn a_full_queue_refuses_and_keeps_what_it_holds() {
    let mut server = Server::new(Config::new(PERIOD)).unwrap();
    for i in 0..QUEUE_DEPTH {
        assert_eq!(server.enqueue(build::idle(i as u16 + 1, 1)), Ok(i + 1));
    }
    assert_eq!(server.enqueue(build::idle(99, 1)), Err(Refusal::QueueFull));
    assert_eq!(server.queued(), QUEUE_DEPTH);
}

#[test]
fn the_blind_search_presses_spirals_and_ends_when_the_part_drops() {
    let mut rig = Rig::new(Config::new(PERIOD));
    let search = Action::BlindSearch {
        preload: 2000,
        pitch: 100,
        speed: 10_000,
        radius: 1000,
        wobble: 10_000,
        wobble_ms: 400,
    };
    rig.server
        .enqueue(build::blind_search(1, search, 1000))
        .unwrap();
    rig.server.enqueue(build::idle(2, 0)).unwrap();
    // The measured pose does not follow z (the surface holds the part): keep it at 0.
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..300 {
        let out = rig.step();
        let a = out.setpoint.unwrap().attractor;
        assert_eq!(a[2], -2000);
        assert!(a[5].abs() <= 10_000);
        seen.insert((a[0], a[1]));
        rig.pose[2] = 0;
    }
    // 3 mm of spiral at 100 µm pitch: legs 100, 100, 200, 200, 300, 300, 400, 400, 500, 500
    // end at 3 000 µm, at (300, 300).
    assert!(seen.contains(&(100, 0)) && seen.contains(&(100, 100)) && seen.contains(&(-100, 100)));
    assert!(seen.contains(&(-100, -100)) && seen.contains(&(200, -100)));
    assert_eq!(rig.pose[0..2], [300, 300][..]);
    rig.pose[2] = -1000;
    let t = rig.step().transitions[0];
    assert_eq!((t.ended, t.installed), (1, 2));
}

#[test]
fn schemas_round_trip_through_postcard_and_bad_bytes_are_refused_whole() {
    let s = build::move_to_touch(1, [0, 0, -1, 0, 0, 0], 2000, 3000, 40_000);
    let mut buf = [0u8; MAX_ENCODED];
    let bytes = postcard::to_slice(&s, &mut buf).unwrap();
    assert_eq!(Schema::decode(bytes), Ok(s.clone()));
    let mut longer = bytes.to_vec();
    longer.push(0);
    assert_eq!(Schema::decode(&longer), Err(SchemaError::TrailingBytes));
    assert!(matches!(
        Schema::decode(&bytes[..bytes.len() - 1]),
        Err(SchemaError::Malformed(_))
    ));
    let mut reserved = s.clone();
    reserved.id = Schema::WAIT_QUEUE;
    let bytes = postcard::to_slice(&reserved, &mut buf).unwrap();
    assert_eq!(Schema::decode(bytes), Err(SchemaError::ReservedId));
    let mut far = build::move_to(1, [600_000_000, 0, 0, 0, 0, 0], 1);
    let bytes = postcard::to_slice(&far, &mut buf).unwrap();
    assert_eq!(Schema::decode(bytes), Err(SchemaError::OutOfRange));
    far.action = Action::MoveTo {
        goal: [0; AXES],
        speed: 0,
    };
    let bytes = postcard::to_slice(&far, &mut buf).unwrap();
    assert_eq!(Schema::decode(bytes), Err(SchemaError::Degenerate));
    let mut axis = build::idle(1, 0);
    axis.reactions[0].event = Event::Above(Measure::Force(6), 0);
    let bytes = postcard::to_slice(&axis, &mut buf).unwrap();
    assert_eq!(Schema::decode(bytes), Err(SchemaError::BadAxis));
}

// ---- Properties ----

fn pose() -> impl Strategy<Value = Pose> {
    prop::array::uniform6(-2_000_000i32..2_000_000)
}

fn measure() -> impl Strategy<Value = Measure> {
    prop_oneof![
        (0u8..8).prop_map(Measure::Position),
        (0u8..8).prop_map(Measure::Displacement),
        (0u8..8).prop_map(Measure::Force),
        Just(Measure::Contact),
        (0u8..10).prop_map(Measure::Sensor),
    ]
}

fn event() -> impl Strategy<Value = Event> {
    prop_oneof![
        Just(Event::OneShot),
        Just(Event::Done),
        (0u32..50).prop_map(Event::Elapsed),
        Just(Event::QueueReady),
        (measure(), any::<i32>()).prop_map(|(m, t)| Event::Above(m, t)),
        (measure(), any::<i32>()).prop_map(|(m, t)| Event::Below(m, t)),
    ]
}

fn source() -> impl Strategy<Value = Source> {
    prop_oneof![
        (0u8..3).prop_map(Source::Innate),
        Just(Source::Queue),
        Just(Source::HighPriority)
    ]
}

fn action() -> impl Strategy<Value = Action> {
    let speed = 0u32..2_000_000;
    prop_oneof![
        (0u32..100).prop_map(|ms| Action::Idle { ms }),
        any::<bool>().prop_map(|c| Action::Gripper(if c {
            Gripper::Closed
        } else {
            Gripper::Open
        })),
        (any::<u32>(), any::<u32>())
            .prop_map(|(stiffness, damping)| Action::SetImpedance { stiffness, damping }),
        Just(Action::Relieve),
        (pose(), speed.clone()).prop_map(|(goal, speed)| Action::MoveTo { goal, speed }),
        (pose(), speed.clone(), 0u32..5_000_000).prop_map(|(direction, speed, distance)| {
            Action::MoveToTouch {
                direction,
                speed,
                distance,
            }
        }),
        (
            0u32..5000,
            0u32..500,
            speed,
            0u32..10_000,
            0u32..50_000,
            0u32..1000
        )
            .prop_map(|(preload, pitch, speed, radius, wobble, wobble_ms)| {
                Action::BlindSearch {
                    preload,
                    pitch,
                    speed,
                    radius,
                    wobble,
                    wobble_ms,
                }
            }),
        (0u32..100).prop_map(|settle_ms| Action::Grasp { settle_ms }),
        (0u32..100).prop_map(|settle_ms| Action::Release { settle_ms }),
    ]
}

fn schema() -> impl Strategy<Value = Schema> {
    (
        1u16..0x1000,
        action(),
        prop::collection::vec((event(), source()), 0..5),
        0u32..200,
    )
        .prop_map(|(id, action, reactions, watchdog_ms)| Schema {
            id,
            action,
            reactions: reactions
                .into_iter()
                .map(|(event, next)| Reaction { event, next })
                .collect(),
            watchdog_ms,
        })
}

#[derive(Debug, Clone)]
enum Op {
    Enqueue(Schema),
    HighPriority(Schema),
    Abort,
    Stop,
    Pose(Pose),
    Wrench([i32; AXES]),
    Sensor(usize, i32),
    Tick(u64),
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        2 => schema().prop_map(Op::Enqueue),
        1 => schema().prop_map(Op::HighPriority),
        1 => Just(Op::Abort),
        1 => Just(Op::Stop),
        3 => pose().prop_map(Op::Pose),
        3 => prop::array::uniform6(-60_000i32..60_000).prop_map(Op::Wrench),
        1 => (0usize..10, any::<i32>()).prop_map(|(i, v)| Op::Sensor(i, v)),
        8 => (1u64..4).prop_map(Op::Tick),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Whatever a client, the sensors and the clock do: no panic, every installed schema is one
    /// that was admitted or a built-in one, a safety event always installs its recovery and
    /// leaves a fault, the attractor is never commanded farther outside the workspace than it
    /// was, and the queue never exceeds its depth.
    #[test]
    fn the_loop_keeps_its_invariants(ops in prop::collection::vec(op(), 1..300)) {
        let mut config = Config::new(PERIOD);
        config.limits.workspace_min = [-1_500_000; AXES];
        config.limits.workspace_max = [1_500_000; AXES];
        config.innate.push(build::idle(500, 3)).unwrap();
        config.innate.push(build::gripper(501, Gripper::Closed)).unwrap();
        config.innate.push(build::move_to(502, [0; AXES], 5000)).unwrap();
        let mut server = Server::new(config.clone()).unwrap();
        let mut admitted = std::collections::BTreeSet::from([500u16, 501, 502]);
        let mut now = 0u64;
        for op in ops {
            match op {
                Op::Enqueue(s) => {
                    let id = s.id;
                    if server.enqueue(s).is_ok() { admitted.insert(id); }
                }
                Op::HighPriority(s) => {
                    let id = s.id;
                    // A client that acknowledges every stop it saw.
                    let stop = server.stop_number();
                    if server.high_priority(s, stop).is_ok() { admitted.insert(id); }
                }
                Op::Abort => server.abort(),
                Op::Stop => server.emergency_stop(),
                Op::Pose(p) => server.set_pose(p, Instant::from_micros(now)),
                Op::Wrench(w) => server.set_wrench(w, Instant::from_micros(now)),
                Op::Sensor(i, v) => { server.set_sensor(i, v, Instant::from_micros(now)); }
                Op::Tick(n) => {
                    now += n * u64::from(PERIOD);
                    let out = server.tick(Instant::from_micros(now));
                    for t in &out.transitions {
                        prop_assert!(admitted.contains(&t.installed) || t.installed >= pab_core::schema::BUILTIN_IDS);
                        if let Trigger::Safety(cause) = t.by {
                            prop_assert_eq!(t.installed, Schema::SAFETY + cause as u16);
                        }
                    }
                    if out.transitions.iter().any(|t| matches!(t.by, Trigger::Safety(_))) {
                        prop_assert!(server.fault().is_some());
                    }
                    prop_assert!(server.queued() <= QUEUE_DEPTH);
                }
            }
        }
    }

    /// A move's attractor is the f64 straight line at constant speed, to within 1 µm, and ends
    /// exactly on the goal on the tick its progress reaches the distance.
    #[test]
    // Speeds and periods such that a move takes at most 34 600 ticks (87 mm at 5 mm/s, 0.5 ms):
    // the loop below runs to the tick the move must have ended.
    fn moves_follow_the_f64_line(goal in prop::array::uniform3(-50_000i32..50_000), speed in 5_000u32..200_000, period in 500u32..5000) {
        let goal: Pose = [goal[0], goal[1], goal[2], 0, 0, 0];
        let mut config = Config::new(period);
        config.overrun_us = period * 2;
        let mut server = Server::new(config).unwrap();
        server.enqueue(build::move_to(1, goal, speed)).unwrap();
        let length = goal.iter().take(3).map(|c| f64::from(*c).powi(2)).sum::<f64>().sqrt();
        let mut reached = None;
        let ticks = (length.floor() * 1e6 / (f64::from(speed) * f64::from(period))).ceil() as u64 + 1;
        for k in 1..=ticks {
            let now = Instant::from_micros(k * u64::from(period));
            server.set_pose([0; AXES], now);
            server.set_wrench([0; AXES], now);
            let a = server.tick(now).setpoint.unwrap().attractor;
            // Progress after k ticks, from the exact integer product: floor(k·speed·period / 1e6).
            let progress = ((k as u128 * u128::from(speed) * u128::from(period)) / 1_000_000) as f64;
            if progress >= length.floor() && reached.is_none() {
                prop_assert_eq!(a, goal, "tick {}", k);
                reached = Some(k);
                break;
            }
            for axis in 0..3 {
                let expected = f64::from(goal[axis]) * progress / length.floor();
                prop_assert!((f64::from(a[axis]) - expected).abs() <= 1.0, "tick {} axis {}: {} vs {}", k, axis, a[axis], expected);
            }
        }
        prop_assert!(reached.is_some() || length < 1.0);
    }

    /// Any bytes: a schema or a typed error, never a panic; what decodes re-encodes to the same
    /// bytes.
    #[test]
    fn any_bytes_decode_or_are_refused(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        if let Ok(s) = Schema::decode(&bytes) {
            let mut buf = [0u8; 512];
            let again = postcard::to_slice(&s, &mut buf).unwrap();
            prop_assert_eq!(Schema::decode(again), Ok(s));
        }
    }

    /// Every valid schema round-trips, within MAX_ENCODED bytes.
    #[test]
    fn valid_schemas_round_trip(s in schema()) {
        let mut buf = [0u8; 1024];
        let bytes = postcard::to_slice(&s, &mut buf).unwrap();
        match s.check() {
            Ok(()) => {
                prop_assert!(bytes.len() <= MAX_ENCODED);
                prop_assert_eq!(Schema::decode(bytes), Ok(s));
            }
            Err(e) => prop_assert_eq!(Schema::decode(bytes), Err(e)),
        }
    }
}

#[test]
fn contact_against_a_move_from_the_end_of_the_pose_range_does_not_overflow() {
    // A pose topic may report any i32 (a robot far beyond MAX_COORD, a broken sensor): the first
    // one arms the attractor there, and a move's direction from it to a goal within MAX_COORD
    // is then up to 2^31 + MAX_COORD per axis. Against a wrench at the end of its range the
    // contact's dot product saturates at i64::MIN, whose negation overflowed (the fuzz target
    // `schema` reads any pose).
    let mut config = Config::new(PERIOD);
    config.limits.workspace_min = [i32::MIN; AXES];
    config.limits.workspace_max = [i32::MAX; AXES];
    config.limits.force_limit = u32::MAX;
    let mut server = Server::new(config).unwrap();
    let mut touch = build::move_to(1, [MAX_COORD, MAX_COORD, MAX_COORD, 0, 0, 0], 1);
    touch.reactions[0] = Reaction {
        event: Event::Above(Measure::Contact, 0),
        next: Source::Queue,
    };
    server.enqueue(touch).unwrap();
    for tick in 1..=2 {
        server.set_pose([i32::MIN; AXES], at(tick));
        server.set_wrench([i32::MIN; AXES], at(tick));
        let out = server.tick(at(tick));
        assert!(
            out.transitions
                .iter()
                .all(|t| !matches!(t.by, Trigger::Safety(_))),
            "{out:?}"
        );
    }
    // The move goes +x, +y, +z and the force points the other way, as hard as it can: contact,
    // which a wrapped negation read as a pull (so no contact).
    assert_eq!(server.current(), Schema::WAIT_QUEUE);
}

// ---- The table image's schema server (format 10) ----

/// A sensor on `id` reading an unsigned little-endian field at `offset` of `size` bytes.
fn sensor(id: pab_core::OutputId, offset: u8, size: u8) -> pab_core::schema::Sensor {
    pab_core::schema::Sensor {
        id,
        field: pab_core::Field {
            offset,
            size,
            signed: false,
            endian: pab_core::Endian::Little,
        },
    }
}

fn setup() -> pab_core::schema::Setup {
    let mut config = Config::new(PERIOD);
    config.limits.force_limit = 30_000;
    config
        .innate
        .push(build::gripper(40, Gripper::Open))
        .unwrap();
    // An innate reflex on a sensor: wait, and open the gripper once sensor 1 reads 500 or more.
    let mut reflex = build::idle(41, 0);
    reflex.reactions[0] = Reaction {
        event: Event::Above(Measure::Sensor(1), 500),
        next: Source::Innate(0),
    };
    config.innate.push(reflex).unwrap();
    let mut sensors = heapless::Vec::new();
    sensors
        .push(sensor(pab_core::OutputId::new(0x330, false).unwrap(), 0, 2))
        .unwrap();
    sensors
        .push(sensor(pab_core::OutputId::new(0x330, false).unwrap(), 4, 4))
        .unwrap();
    pab_core::schema::Setup {
        config,
        drive: pab_core::schema::Drive {
            setpoint: pab_core::OutputId::new(0x300, false).unwrap(),
            pose: pab_core::OutputId::new(0x310, false).unwrap(),
            wrench: pab_core::OutputId::new(0x1234_5678, true).unwrap(),
        },
        sensors,
    }
}

/// An image of `table` for node 5 whatever it holds (the encoder would validate it first).
fn raw_image(table: &pab_core::Table) -> Vec<u8> {
    let mut area = vec![0u8; pab_core::image::MAX_IMAGE_LEN];
    let body = postcard::to_slice(table, &mut area).unwrap().to_vec();
    let mut image = b"PABT".to_vec();
    image.extend_from_slice(&pab_core::image::FORMAT_VERSION.to_le_bytes());
    image.extend_from_slice(&[5, 0]);
    image.extend_from_slice(&1u32.to_le_bytes());
    image.extend_from_slice(&(body.len() as u32).to_le_bytes());
    let crc = pab_core::crc32::Crc32::new()
        .update(&image)
        .update(&body)
        .finish();
    image.extend_from_slice(&crc.to_le_bytes());
    image.extend_from_slice(&body);
    image
}

#[test]
fn a_table_image_carries_the_schema_server_and_the_loader_checks_it() {
    use pab_core::image::{self, LoadError};
    use pab_core::schema::SetupError;
    use pab_core::{Table, TableError};
    let mut table: Table = Table::new();
    table.set_schema(Some(setup()));
    let mut buffer = vec![0u8; image::MAX_IMAGE_LEN];
    let len = image::encode(&table, 5, 1, &mut buffer).unwrap();
    let loaded: image::Loaded = image::load(&buffer[..len]).unwrap();
    assert_eq!(loaded.table.schema(), Some(&setup()));
    // A board's capacities read it too.
    let board: image::Loaded<4, 64, 256> = image::load(&buffer[..len]).unwrap();
    assert_eq!(board.table.schema(), Some(&setup()));

    let refused = |s: pab_core::schema::Setup| {
        let mut t: Table = Table::new();
        t.set_schema(Some(s));
        image::load::<16, 512, 2048>(&raw_image(&t)).map(|_| ())
    };
    let mut overlap = setup();
    overlap.drive.pose = pab_core::OutputId::new(0x302, false).unwrap();
    assert_eq!(
        refused(overlap),
        Err(LoadError::Table(TableError::Schema(
            SetupError::DriveOverlap
        )))
    );
    let mut last = setup();
    last.drive.setpoint = pab_core::OutputId::new(0x7FE, false).unwrap();
    assert!(matches!(
        refused(last),
        Err(LoadError::Table(TableError::Schema(SetupError::DriveId(_))))
    ));
    let mut period = setup();
    period.config.period_us = 0;
    assert_eq!(
        refused(period),
        Err(LoadError::Table(TableError::Schema(SetupError::Config(
            pab_core::schema::ConfigError::Period
        ))))
    );
    let mut innate = setup();
    let mut bad = build::idle(42, 0);
    bad.reactions[0].next = Source::Innate(5);
    innate.config.innate.push(bad).unwrap();
    assert_eq!(
        refused(innate),
        Err(LoadError::Table(TableError::Schema(SetupError::Config(
            pab_core::schema::ConfigError::Innate(2)
        ))))
    );
    assert_eq!(refused(setup()), Ok(()));
}

#[test]
fn the_loader_refuses_bad_sensor_topics_with_a_typed_error() {
    use pab_core::image::LoadError;
    use pab_core::schema::{SensorError, SetupError};
    use pab_core::value_port::FieldError;
    use pab_core::{OutputId, OutputIdError, Table, TableError};
    let refused = |s: pab_core::schema::Setup| {
        let mut t: Table = Table::new();
        t.set_schema(Some(s));
        pab_core::image::load::<16, 512, 2048>(&raw_image(&t)).map(|_| ())
    };
    let with = |i: usize, s: pab_core::schema::Sensor| {
        let mut setup = setup();
        setup.sensors[i] = s;
        setup
    };
    let schema_error = |e| Err(LoadError::Table(TableError::Schema(e)));
    // An identifier too wide for its format (the encoder would refuse it: raw bytes).
    let wide = unchecked_output_id(0x800, false);
    assert_eq!(
        refused(with(1, sensor(wide, 0, 2))),
        schema_error(SetupError::Sensor(
            1,
            SensorError::Id(OutputIdError::StandardTooWide)
        ))
    );
    let id = OutputId::new(0x330, false).unwrap();
    assert_eq!(
        refused(with(0, sensor(id, 0, 3))),
        schema_error(SetupError::Sensor(
            0,
            SensorError::Field(FieldError::BadSize { size: 3 })
        ))
    );
    assert_eq!(
        refused(with(
            0,
            sensor(id, pab_core::frame::MAX_DATA_LEN as u8 - 2, 4)
        )),
        schema_error(SetupError::Sensor(
            0,
            SensorError::Field(FieldError::OutOfFrame {
                offset: pab_core::frame::MAX_DATA_LEN as u8 - 2,
                size: 4
            })
        ))
    );
    // The pose's rotation frame (0x311) is the drive's.
    let on_drive = OutputId::new(0x311, false).unwrap();
    assert_eq!(
        refused(with(0, sensor(on_drive, 0, 2))),
        schema_error(SetupError::Sensor(0, SensorError::DriveOverlap))
    );
    // The same number as an extended identifier is another frame.
    let extended = OutputId::new(0x311, true).unwrap();
    assert_eq!(refused(with(0, sensor(extended, 0, 2))), Ok(()));
    // The reflex reads sensor 1: with one sensor only it would go stale whenever it ran.
    let mut one = setup();
    one.sensors.pop();
    assert_eq!(refused(one), schema_error(SetupError::UnknownSensor(1)));
}

/// An `OutputId` with any raw value, as bytes from the bus could hold (its constructor refuses
/// a value beyond the format).
fn unchecked_output_id(raw: u32, extended: bool) -> pab_core::OutputId {
    let mut bytes = [0u8; 8];
    let used = postcard::to_slice(&(raw, extended), &mut bytes)
        .unwrap()
        .len();
    postcard::from_bytes(&bytes[..used]).unwrap()
}

#[test]
fn a_sensor_frame_reaches_the_server_through_its_field() {
    use pab_core::Frame;
    use pab_core::schema::feed_sensors;
    let setup = setup();
    let mut server = Server::new(setup.config.clone()).unwrap();
    server.set_pose([0; AXES], at(0));
    server.set_wrench([0; AXES], at(0));
    // The reflex (innate 1) waits for sensor 1 to read 500 or more; sent on the high-priority
    // channel, as a client could.
    server
        .high_priority(setup.config.innate[1].clone(), 0)
        .unwrap();
    let frame =
        |id: u32, extended: bool, data: &[u8]| Frame::with_raw_id(id, extended, data).unwrap();
    let sensors = setup.sensors.as_slice();
    let reading = |v: u32| {
        let mut d = [0u8; 8];
        d[4..].copy_from_slice(&v.to_le_bytes());
        d
    };
    // Another identifier, or the same number extended: not the sensors' frame.
    assert!(!feed_sensors(
        sensors,
        &frame(0x331, false, &reading(600)),
        &mut server,
        at(0)
    ));
    assert!(!feed_sensors(
        sensors,
        &frame(0x330, true, &reading(600)),
        &mut server,
        at(0)
    ));
    // A payload too short for sensor 1's field (bytes 4..8): sensor 0 alone is read, so the
    // reflex, which reads sensor 1, meets a sensor never read: the stale-sensor event.
    assert!(feed_sensors(
        sensors,
        &frame(0x330, false, &[1, 2, 3]),
        &mut server,
        at(0)
    ));
    let t = server.tick(at(1)).transitions;
    assert_eq!(
        t.iter().map(|t| t.by).collect::<Vec<_>>(),
        [Trigger::HighPriority, Trigger::Safety(Safety::StaleSensor)]
    );
    // Read: 499 holds nothing; 500 (little endian) sends the reflex to innate 0. The stale
    // sensor was the server's first stop: acknowledged.
    server
        .high_priority(setup.config.innate[1].clone(), 1)
        .unwrap();
    assert!(feed_sensors(
        sensors,
        &frame(0x330, false, &reading(499)),
        &mut server,
        at(1)
    ));
    let t = server.tick(at(2)).transitions;
    assert_eq!(
        t.iter().map(|t| t.by).collect::<Vec<_>>(),
        [Trigger::HighPriority]
    );
    assert!(server.tick(at(3)).transitions.is_empty());
    assert!(feed_sensors(
        sensors,
        &frame(0x330, false, &reading(500)),
        &mut server,
        at(3)
    ));
    let t = server.tick(at(4)).transitions;
    assert_eq!(
        (t[0].by, t[0].installed, t[0].source),
        (
            Trigger::Reaction(0, Event::Above(Measure::Sensor(1), 500)),
            40,
            Origin::Innate
        )
    );
    // An unsigned 32-bit reading beyond i32 saturates rather than wrapping negative.
    assert_eq!(
        setup.sensors[1].read(&frame(0x330, false, &reading(u32::MAX))),
        Some(i32::MAX)
    );
}

/// Every truncation of an image with a schema server (innate schemas and sensors) is refused,
/// and every byte of its body corrupted (three ways, the CRC made right again) either loads a
/// set-up that passes its own check or is refused with a typed error: the loader's checks, not
/// luck, stand between the bytes and the server.
#[test]
fn corrupted_schema_server_images_never_load_a_bad_set_up() {
    use pab_core::Table;
    use pab_core::image::{self, HEADER_LEN};
    let mut table: Table = Table::new();
    table.set_schema(Some(setup()));
    let mut buffer = vec![0u8; image::MAX_IMAGE_LEN];
    let len = image::encode(&table, 5, 1, &mut buffer).unwrap();
    let valid = &buffer[..len];
    for cut in 0..len {
        assert!(
            image::load::<16, 512, 2048>(&valid[..cut]).is_err(),
            "{cut}"
        );
    }
    let (mut loaded, mut refused) = (0, 0);
    for at in HEADER_LEN..len {
        for mask in [0x01u8, 0x80, 0xFF] {
            let mut bad = valid.to_vec();
            bad[at] ^= mask;
            let crc = pab_core::crc32::Crc32::new()
                .update(&bad[..16])
                .update(&bad[HEADER_LEN..])
                .finish();
            bad[16..20].copy_from_slice(&crc.to_le_bytes());
            match image::load::<16, 512, 2048>(&bad) {
                Ok(l) => {
                    loaded += 1;
                    if let Some(s) = l.table.schema() {
                        assert_eq!(s.check(), Ok(()), "byte {at} ^ {mask:#x}");
                        assert!(Server::new(s.config.clone()).is_ok());
                    }
                }
                Err(_) => refused += 1,
            }
        }
    }
    // Most corruptions are caught; some land on a value that is merely different (a threshold,
    // a speed) and still valid.
    assert!(refused > loaded, "{refused} refused, {loaded} loaded");
}

#[test]
fn a_pose_that_jumps_farther_than_the_drive_can_move_stops_the_server_where_the_robot_is() {
    let mut config = Config::new(PERIOD);
    config.drive_speed = 500_000; // 0.5 m/s: 500 µm a tick
    config.drive_rate = 1_000_000;
    config.pose_noise = 200;
    let mut rig = Rig::new(config);
    rig.server
        .enqueue(build::move_to(1, goal_x(50_000), 100_000))
        .unwrap();
    for _ in 0..20 {
        rig.step();
    }
    // The robot measured where the attractor took it, then a forged pose 400 mm away just before
    // the stop: not taken.
    let true_pose = rig.pose;
    let now = at(rig.tick);
    rig.server.set_pose(true_pose, now);
    rig.server.set_pose(goal_x(400_000), now);
    rig.server.emergency_stop();
    rig.tick += 1;
    let out = rig.server.tick(at(rig.tick));
    assert_eq!(
        out.transitions[0].by,
        Trigger::Safety(Safety::EmergencyStop)
    );
    // The stop's set-point is the last plausible pose, not the forged one.
    assert_eq!(out.setpoint.unwrap().attractor, true_pose);
    // True poses after it are taken, and the attractor stays on the robot.
    for _ in 0..50 {
        rig.step();
    }
    assert_eq!(rig.pose, true_pose);
    // Running, an implausible pose is a safety event of its own.
    let mut rig = Rig::new(config_with_drive());
    rig.server
        .enqueue(build::move_to(1, goal_x(50_000), 100_000))
        .unwrap();
    for _ in 0..5 {
        rig.step();
    }
    let before = rig.pose;
    rig.server.set_pose(before, at(rig.tick));
    rig.server.set_pose(goal_x(-30_000), at(rig.tick));
    rig.tick += 1;
    let out = rig.server.tick(at(rig.tick));
    assert_eq!(
        out.transitions[0].by,
        Trigger::Safety(Safety::ImplausibleSensor)
    );
    assert_eq!(out.setpoint.unwrap().attractor, before);
    assert_eq!(rig.server.fault(), Some(Safety::ImplausibleSensor));
}

#[test]
fn the_drive_moving_at_its_top_speed_is_plausible_on_every_axis() {
    let mut config = config_with_drive();
    config.pose_noise = 0;
    let mut server = Server::new(config).unwrap();
    let mut pose = [0; AXES];
    server.set_pose(pose, at(0));
    server.set_wrench([0; AXES], at(0));
    // 500 µm a tick on x, 1 000 µrad a tick on rz: exactly the limits.
    for tick in 1..=100u64 {
        pose[0] += 500;
        pose[5] -= 1000;
        server.set_pose(pose, at(tick));
        server.set_wrench([0; AXES], at(tick));
        let out = server.tick(at(tick));
        assert!(
            out.transitions.is_empty(),
            "tick {tick}: {:?}",
            out.transitions
        );
    }
    // Two frames arriving together (the first waited behind others): plausible as long as the
    // drive could have moved that far while the first may have been late, the overrun bound
    // (2 ms here: 1 000 µm).
    pose[0] += 1000;
    server.set_pose(pose, at(100));
    assert!(server.tick(at(100)).transitions.is_empty());
    // One µm more than the drive can do in a tick and a frame's lateness: a safety event, also
    // while the server waits on its queue (a wait is not tested for stale sensors, but an
    // implausible pose is a sign).
    pose[1] += 1501;
    server.set_pose(pose, at(101));
    let out = server.tick(at(101));
    assert_eq!(
        out.transitions[0].by,
        Trigger::Safety(Safety::ImplausibleSensor)
    );
    assert_eq!(server.fault(), Some(Safety::ImplausibleSensor));
}

fn config_with_drive() -> Config {
    let mut config = Config::new(PERIOD);
    config.drive_speed = 500_000;
    config.drive_rate = 1_000_000;
    config.pose_noise = 200;
    config
}

#[test]
fn a_drive_that_cannot_move_is_a_refused_set_up() {
    let mut config = Config::new(PERIOD);
    config.drive_speed = 0;
    assert_eq!(
        Server::new(config).err(),
        Some(pab_core::schema::ConfigError::DriveLimits)
    );
    let mut config = Config::new(PERIOD);
    config.drive_rate = 0;
    assert!(Server::new(config).is_err());
}

// ---- Joint and speed limits, and limits tightened at run time ----

fn joint(sensor: u8, min: i32, max: i32, rate: u32) -> pab_core::schema::Joint {
    pab_core::schema::Joint {
        sensor,
        min,
        max,
        rate,
    }
}

/// A rig whose board reads joint 0 on sensor 0, in [-1000, 1000] counts at most 2000 counts/s,
/// with an idle schema installed.
fn joint_rig(reading: i32) -> Rig {
    let mut config = Config::new(PERIOD);
    config
        .limits
        .joints
        .push(joint(0, -1000, 1000, 2000))
        .unwrap();
    let mut rig = Rig::new(config);
    rig.server.set_sensor(0, reading, at(0));
    rig.server.enqueue(build::idle(1, 0)).unwrap();
    rig.step();
    assert_eq!(rig.server.current(), 1);
    rig
}

/// Steps once with the joint reading `value`.
fn joint_step(rig: &mut Rig, value: i32) -> Tick {
    rig.server.set_sensor(0, value, at(rig.tick + 1));
    rig.step()
}

#[test]
fn a_joint_driven_out_of_its_range_stops_the_server() {
    let mut rig = joint_rig(0);
    // One count a tick (1000 counts/s, within its rate) up to its highest position...
    for count in 1..=1000 {
        assert!(
            joint_step(&mut rig, count).transitions.is_empty(),
            "{count}"
        );
    }
    // ...and one beyond: the joint limit, the robot held where it is.
    let out = joint_step(&mut rig, 1001);
    assert_eq!(out.transitions[0].by, Trigger::Safety(Safety::JointLimit));
    assert_eq!(rig.server.fault(), Some(Safety::JointLimit));
    assert_eq!(out.setpoint.unwrap().attractor, rig.pose);
}

#[test]
fn a_schema_that_brings_a_joint_back_into_its_range_is_not_stopped() {
    // A joint 500 counts out of its range when the server starts: stopped at once (as a robot
    // outside its workspace is).
    let mut config = Config::new(PERIOD);
    config
        .limits
        .joints
        .push(joint(0, -1000, 1000, 2000))
        .unwrap();
    let mut rig = Rig::new(config);
    rig.server.set_sensor(0, 1500, at(0));
    let out = rig.step();
    assert_eq!(out.transitions[0].by, Trigger::Safety(Safety::JointLimit));
    // A schema installed there, acknowledging the stop: no stop while the joint comes back in
    // or stays as far out, one when it goes farther.
    let stop = rig.server.stop_number();
    rig.server.high_priority(build::idle(1, 0), stop).unwrap();
    joint_step(&mut rig, 1500);
    assert_eq!((rig.server.current(), rig.server.fault()), (1, None));
    for count in (1400..1500).rev().chain(1400..=1500) {
        assert!(joint_step(&mut rig, count).transitions.is_empty());
    }
    let out = joint_step(&mut rig, 1501);
    assert_eq!(out.transitions[0].by, Trigger::Safety(Safety::JointLimit));
}

#[test]
fn a_joint_faster_than_its_rate_over_the_window_is_a_speed_event() {
    let window = pab_core::schema::SPEED_WINDOW_US / u64::from(PERIOD);
    assert_eq!(window, 20);
    // 2000 counts/s is 40 counts in the 20 ms window (and a count of noise): two counts a tick
    // run for ever...
    let mut rig = joint_rig(0);
    let mut reading = 0;
    for _ in 0..10 * window {
        reading += 2;
        assert!(joint_step(&mut rig, reading).transitions.is_empty());
    }
    // ...three (60 counts a window) are stopped within two windows.
    for tick in 1..=2 * window {
        reading += 3;
        if let Some(t) = joint_step(&mut rig, reading).transitions.first() {
            assert_eq!(t.by, Trigger::Safety(Safety::Speed), "tick {tick}");
            return;
        }
    }
    panic!("no speed event");
}

/// A server with a 100 mm/s speed limit and 0.1 mm of pose noise, its robot moving to
/// x = 20 mm at `speed` µm/s: the first safety event, if any, within 0.5 s.
fn move_under_speed_limit(speed: u32) -> Option<(u64, Safety)> {
    let mut config = Config::new(PERIOD);
    config.limits.speed_limit = 100_000;
    config.pose_noise = 100;
    let mut rig = Rig::new(config);
    rig.server
        .enqueue(build::move_to(1, goal_x(20_000), speed))
        .unwrap();
    for _ in 0..500 {
        let out = rig.step();
        for t in &out.transitions {
            if let Trigger::Safety(cause) = t.by {
                // The stop holds the robot where it is.
                assert_eq!(out.setpoint.unwrap().attractor, rig.pose);
                return Some((rig.tick, cause));
            }
        }
    }
    None
}

#[test]
fn the_pose_faster_than_the_speed_limit_is_a_speed_event_and_a_slower_move_is_not() {
    assert_eq!(move_under_speed_limit(80_000), None);
    assert_eq!(move_under_speed_limit(100_000), None);
    // 150 mm/s: 3 mm in a window, above 2 mm + 0.2 mm; stopped at the end of the first window
    // the robot moved through.
    let (tick, cause) = move_under_speed_limit(150_000).expect("stopped");
    assert_eq!(cause, Safety::Speed);
    assert!(tick <= 1 + 2 * 20, "stopped at tick {tick}");
}

#[test]
fn limits_tightened_at_run_time_stop_what_the_table_allowed_and_never_loosen() {
    let mut config = Config::new(PERIOD);
    config.limits.force_limit = 30_000;
    let table = config.limits.clone();
    let mut rig = Rig::new(config);
    rig.server.enqueue(build::idle(1, 0)).unwrap();
    rig.step();
    // 20 N is within the table's 30 N...
    rig.wrench = [0, 0, 20_000, 0, 0, 0];
    assert!(rig.step().transitions.is_empty());
    // ...a limit of 50 N is refused (looser than the table's), one of 15 N taken: the next tick
    // stops on the force.
    let mut loose = table.clone();
    loose.force_limit = 50_000;
    assert_eq!(rig.server.set_limits(loose), Err(Refusal::Looser));
    assert_eq!(rig.server.limits(), &table);
    let mut tight = table.clone();
    tight.force_limit = 15_000;
    rig.server.set_limits(tight.clone()).unwrap();
    assert_eq!(rig.server.limits(), &tight);
    let out = rig.step();
    assert_eq!(out.transitions[0].by, Trigger::Safety(Safety::Force));
    // Back to the table's: allowed, and 20 N runs again.
    rig.server.set_limits(table.clone()).unwrap();
    let stop = rig.server.stop_number();
    rig.server.high_priority(build::idle(2, 0), stop).unwrap();
    rig.step();
    assert_eq!((rig.server.current(), rig.server.fault()), (2, None));
    assert!(rig.step().transitions.is_empty());
}

#[test]
fn a_workspace_tightened_around_the_robot_stops_it_and_the_way_back_in_is_allowed() {
    let mut rig = Rig::new(Config::new(PERIOD));
    rig.server
        .enqueue(build::move_to(1, goal_x(10_000), 100_000))
        .unwrap();
    for _ in 0..200 {
        rig.step();
    }
    assert_eq!(rig.pose[0], 10_000);
    let mut tight = rig.server.limits().clone();
    tight.workspace_max[0] = 5_000;
    rig.server.set_limits(tight).unwrap();
    let out = rig.step();
    assert_eq!(out.transitions[0].by, Trigger::Safety(Safety::Limit));
    // A move back inside, acknowledging the stop, runs to its end.
    let stop = rig.server.stop_number();
    rig.server
        .high_priority(build::move_to(2, goal_x(0), 100_000), stop)
        .unwrap();
    for _ in 0..200 {
        assert!(
            rig.step()
                .transitions
                .iter()
                .all(|t| !matches!(t.by, Trigger::Safety(_)))
        );
    }
    assert_eq!(rig.pose[0], 0);
}

#[test]
fn the_contact_limit_ends_a_touch_at_a_lighter_contact() {
    let touch = || build::move_to_touch(1, [1, 0, 0, 0, 0, 0], 10_000, 3_000, 50_000);
    // 2 N against the motion: below the touch's 3 N, it goes on; with a 1.5 N contact limit,
    // the touch ends on contact.
    for (limit, ends) in [(0, false), (1_500, true)] {
        let mut config = Config::new(PERIOD);
        config.limits.contact_limit = 2_500;
        let mut rig = Rig::new(config);
        if limit != 0 {
            let mut l = rig.server.limits().clone();
            l.contact_limit = limit;
            rig.server.set_limits(l).unwrap();
        }
        rig.server.enqueue(touch()).unwrap();
        rig.step();
        rig.wrench = [-2_000, 0, 0, 0, 0, 0];
        let out = rig.step();
        let ended = out.transitions.iter().any(|t| {
            matches!(
                t.by,
                Trigger::Reaction(_, Event::Above(Measure::Contact, _))
            )
        });
        assert_eq!(ended, ends, "contact limit {limit}");
    }
}
