//! A schema server's board, its robot and its client on a live bus, in real time: the node
//! application on a thread (`pab-app`, the Linux node's code), the plant of `pabctl plant` on
//! another, and the Rust client (`pabctl::client`) here, on the in-process bus. One insertion,
//! and an emergency stop.
//!
//! The loop's overrun bound and the sensors' staleness are loose here (50 ms, 200 ms): the
//! threads share two cores with the rest of the test suite, and the test is about what the
//! frames do, not about a real-time host.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use pab_core::auth::{Authenticator, Key};
use pab_core::protocol::{SchemaOutcome, SchemaSafety};
use pab_core::schema::{Channel, build};
use pab_lang::compile;
use pab_lang::diagnostic::Source;
use pab_lang::network::Network;
use pab_lang::sim::plant::PartState;
use pabctl::bus::memory::MemoryHub;
use pabctl::client::{self, Client};
use pabctl::plant;

mod common;
use common::LiveNode;

const NETWORK: &str = r#"
[nodes.arm]
id = 10

[schema.arm]
period_ms = 1
overrun_ms = 50
stale_ms = 200
force_limit_n = 30
workspace_mm = { min = [-50, -50, -20], max = [50, 50, 60] }
drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }

[plant]
start_mm = [0, 0, 17]
parts_mm = [[0, 0]]
holes_mm = [[10.12, 0.06]]

[client]
node = "arm"
speed_mm_s = 50
touch_speed_mm_s = 10
search_speed_mm_s = 4
program = [
    "move_to_touch(down)", "grasp(settle=50)", "move_to(above_part)", "move_to(above_slot)",
    "move_to_touch(down)", "blind_search()", "release(settle=50)", "move_to(above_slot)",
]

[client.places]
down = [0, 0, -1]
above_part = [0, 0, 20]
above_slot = [10, 0, 20]
"#;

/// One rig at a time: each runs a node and a plant in real time at 1 kHz, and several at once on
/// two cores (with the rest of the suite) starve each other into overruns that are the machine's,
/// not the board's.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

struct Rig {
    network: Network,
    hub: MemoryHub,
    _node: LiveNode,
    stop: Arc<AtomicBool>,
    plant: Option<std::thread::JoinHandle<pab_lang::sim::plant::Plant>>,
    /// Last: released once the node and the plant are gone.
    _turn: std::sync::MutexGuard<'static, ()>,
}

impl Rig {
    fn start() -> Rig {
        Self::start_with(None)
    }

    /// The rig, its node with `key` when given.
    fn start_with(key: Option<Key>) -> Rig {
        // A test that failed while holding the lock poisons it; the next rig still runs.
        let turn = ONE_AT_A_TIME
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let network = Network::parse(Source::new("insertion.toml", NETWORK)).unwrap();
        let image = compile::compile(&network).unwrap().remove(0).image;
        let hub = MemoryHub::new();
        let node = LiveNode::spawn_with(&hub, 10, Some(image), key);
        let stop = Arc::new(AtomicBool::new(false));
        let board = &network.schema_boards[0];
        let (board, plant_config) = (board.clone(), network.plant.clone().unwrap());
        let mut bus = hub.connect();
        let flag = stop.clone();
        let (ready, started) = mpsc::channel();
        let plant = std::thread::spawn(move || {
            let _ = ready.send(());
            plant::run(
                &mut bus,
                &board,
                plant_config,
                board.config.period_us,
                None,
                &flag,
                &mut |_| {},
            )
            .unwrap()
        });
        started.recv().unwrap();
        Rig {
            network,
            hub,
            _node: node,
            stop,
            plant: Some(plant),
            _turn: turn,
        }
    }

    fn finish(mut self) -> pab_lang::sim::plant::Plant {
        self.stop.store(true, Ordering::SeqCst);
        self.plant.take().unwrap().join().unwrap()
    }
}

#[test]
fn one_insertion_on_a_live_bus() {
    let rig = Rig::start();
    let mut tool = rig.hub.connect();
    let mut arm = Client::new(&mut tool, 10);
    // The board arms on the plant's first pose frames.
    arm.pump(Duration::from_millis(300)).unwrap();
    assert!(arm.status().is_some_and(|s| s.armed), "{:?}", arm.status());
    let program = &rig.network.client.as_ref().unwrap().program;
    let board = &rig.network.schema_boards[0];
    let outcome = client::run_program(
        &mut arm,
        program,
        board,
        Duration::from_secs(60),
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(outcome.safety, None, "{:#?}", outcome.rows);
    assert_eq!(outcome.sent, 8);
    let events: Vec<(&str, &str)> = outcome
        .rows
        .iter()
        .map(|r| (r.schema.as_str(), r.event.as_str()))
        .collect();
    assert_eq!(
        events,
        [
            ("move_to_touch(down)", "queue-ready"),
            ("grasp(settle=50)", "above:contact"),
            ("move_to(above_part)", "done"),
            ("move_to(above_slot)", "done"),
            ("move_to_touch(down)", "done"),
            ("blind_search()", "above:contact"),
            ("release(settle=50)", "below:displacement.z"),
            ("move_to(above_slot)", "done"),
            ("wait-queue", "done"),
        ]
    );
    let plant = rig.finish();
    assert_eq!(plant.parts(), [PartState::Inserted(0)]);
}

#[test]
fn an_emergency_stop_frame_halts_the_live_board() {
    let rig = Rig::start();
    let mut tool = rig.hub.connect();
    let mut arm = Client::new(&mut tool, 10);
    arm.pump(Duration::from_millis(300)).unwrap();
    // A long move, stopped half way.
    let id = arm.move_to([0, 40_000, 17_000, 0, 0, 0], 20_000).unwrap();
    arm.pump(Duration::from_millis(300)).unwrap();
    arm.estop(true).unwrap();
    let ended = arm.wait_finished(id, Duration::from_secs(2)).unwrap();
    assert_eq!(ended.safety(), Some(SchemaSafety::EmergencyStop));
    arm.pump(Duration::from_millis(200)).unwrap();
    let state = arm.status().unwrap();
    assert_eq!(state.fault, Some(SchemaSafety::EmergencyStop));
    assert_eq!(state.current, pab_core::schema::Schema::WAIT_HIGH_PRIORITY);
    // Queued schemas wait for the high-priority channel.
    let queued = arm.idle(5).unwrap();
    assert!(
        arm.wait_finished(queued, Duration::from_millis(300))
            .is_err()
    );
    let plant = rig.finish();
    // Stopped well before the end of the move.
    assert!(plant.pose()[1] < 30_000, "{:?}", plant.pose());
}

#[test]
fn a_keyed_board_takes_the_key_holders_schemas_and_leaves_a_stop_only_when_told() {
    let key = Key::from_bytes([0x3C; 16]);
    let rig = Rig::start_with(Some(key));
    let mut tool = rig.hub.connect();
    // Without the key: no flow control, no answer.
    let mut plain = Client::new(&mut tool, 10);
    plain.pump(Duration::from_millis(300)).unwrap();
    assert!(matches!(
        plain.install(&build::idle(1, 0), Channel::Queue),
        Err(client::ClientError::Timeout(_))
    ));
    // Another key: no challenge answered for it, so no open either: no answer.
    let mut wrong = Client::with_key(&mut tool, 10, Authenticator::new(&Key::from_bytes([1; 16])));
    assert!(matches!(
        wrong.install(&build::idle(2, 0), Channel::Queue),
        Err(client::ClientError::Timeout(_))
    ));
    let mut arm = Client::with_key(&mut tool, 10, Authenticator::new(&key));
    let id = arm.move_to([0, 40_000, 17_000, 0, 0, 0], 20_000).unwrap();
    arm.pump(Duration::from_millis(300)).unwrap();
    arm.estop(true).unwrap();
    let ended = arm.wait_finished(id, Duration::from_secs(2)).unwrap();
    assert_eq!(ended.safety(), Some(SchemaSafety::EmergencyStop));
    arm.pump(Duration::from_millis(200)).unwrap();
    let stop = arm.stop_number().expect("a SchemaState");
    assert_eq!(stop, 1);
    // A high-priority schema that names the stop before: refused, the robot stays stopped.
    match arm.install(&build::idle(20, 0), Channel::HighPriority { stop: 0 }) {
        Err(client::ClientError::Refused(ack)) => {
            assert_eq!(
                (ack.outcome, ack.stop),
                (SchemaOutcome::StopNotAcknowledged, 1)
            )
        }
        other => panic!("{other:?}"),
    }
    // The key holder acknowledges it: the stop ends.
    arm.install(&build::idle(21, 0), Channel::HighPriority { stop })
        .unwrap();
    arm.pump(Duration::from_millis(100)).unwrap();
    let started = arm
        .transitions()
        .iter()
        .find(|(_, t)| t.installed == 21)
        .map(|(_, t)| *t)
        .expect("schema 21 installed");
    assert_eq!(started.ended, pab_core::schema::Schema::WAIT_HIGH_PRIORITY);
    assert!(arm.transitions().iter().all(|(_, t)| t.installed != 20));
    rig.finish();
}

#[test]
fn limits_tightened_on_a_live_board_stop_a_push_the_table_allowed() {
    let rig = Rig::start();
    let mut tool = rig.hub.connect();
    let mut arm = Client::new(&mut tool, 10);
    arm.pump(Duration::from_millis(300)).unwrap();
    let table = rig.network.schema_boards[0].config.limits.clone();
    // Looser than the table's 30 N: refused, Looser, on the limits channel.
    let mut loose = table.clone();
    loose.force_limit = 40_000;
    match arm.set_limits(&loose) {
        Err(client::ClientError::Refused(ack)) => {
            assert_eq!(ack.outcome, SchemaOutcome::Looser);
            assert_eq!(ack.channel, Some(pab_core::protocol::SchemaChannel::Limits));
        }
        other => panic!("{other:?}"),
    }
    // A touch that presses 5 N into the part: fine under the table's limit, a force stop under
    // a 2 N one.
    let mut tight = table.clone();
    tight.force_limit = 2_000;
    arm.set_limits(&tight).unwrap();
    let id = arm
        .move_to_touch([0, 0, -1, 0, 0, 0], 10_000, 5_000, 30_000)
        .unwrap();
    let ended = arm.wait_finished(id, Duration::from_secs(5)).unwrap();
    assert_eq!(ended.safety(), Some(SchemaSafety::Force), "{ended:?}");
    rig.finish();
}

/// A participant floods a keyed board with bad tags (and asks for challenges now and then): the
/// board's checks for each second are used up, and the key holder's client says so, as `pabctl
/// push --key` does, instead of asking whether the board has a key.
#[test]
fn a_keyed_client_under_a_flood_of_bad_tags_says_the_board_refused_them() {
    let key = Key::from_bytes([0x3C; 16]);
    let rig = Rig::start_with(Some(key));
    let flood = common::TagFlood::start(&rig.hub, 10);
    std::thread::sleep(Duration::from_millis(200));
    let mut tool = rig.hub.connect();
    let mut arm = Client::with_key(&mut tool, 10, Authenticator::new(&key));
    // The window after each second's reset lets a few checks through before the flood uses them
    // up again: a schema may land in it. Of five, one fails, and says why.
    let mut failure = None;
    for id in 1..=5 {
        if let Err(error) = arm.install(&build::idle(id, 0), Channel::Queue) {
            failure = Some(error);
            break;
        }
    }
    drop(flood);
    rig.finish();
    match failure {
        Some(client::ClientError::Denied(why)) => {
            assert!(why.contains("someone is flooding"), "{why}")
        }
        other => panic!("every schema got through the flood, or failed otherwise: {other:?}"),
    }
}
