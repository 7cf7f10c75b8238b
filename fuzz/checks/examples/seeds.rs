//! Writes the seed inputs of every fuzz target into `fuzz/corpus/<target>/seed-*` (run once when
//! the corpus was made; the committed corpus is this plus what campaigns found, minimised):
//!
//!     cargo run -p pab-fuzz-checks --example seeds [TARGET...]
//!
//! (only the named targets' seeds, when targets are named: `-- ble` writes the `ble` seeds alone).
//!
//! Images and network files are the examples' own (`pabctl compile` of `examples/*.toml`); the
//! structured targets get a few pseudo-random byte strings (a fixed-seed generator), which their
//! `Unstructured` readers turn into scripts and campaigns then grow. The `ble` and `gates` targets'
//! seeds are chosen among a few thousand such strings: each is kept when its script reaches
//! something no kept one reached (`pab_fuzz_checks::ble::features`: a reading, a claim held, a
//! grid restart, a refused claim, the counter's wrap, ...; `pab_fuzz_checks::gates::features`: a
//! step, a change sent, a backlog dropped, a loss, a refused count, ...), then the ones reaching
//! the most up to 20. The `node_keyed` target's the same way, up to 6
//! (`pab_fuzz_checks::node_keyed::features`: a challenge, a command or an open taken, a table
//! swapped in, a receipt, the budget used up), and the `node_schema` target's, up to 8
//! (`pab_fuzz_checks::node_schema::features`: a schema accepted, a receipt, a stop handled and
//! left, limits set, refusals, a liveness check, a stop in the middle of a transfer).

use std::collections::BTreeSet;
use std::path::Path;

use pab_fuzz_checks::TARGETS;
use pab_lang::diagnostic::Source;
use pab_lang::network::Network;

const NETWORKS: [&str; 9] = [
    "figure-1",
    "take-an-object",
    "return-an-object",
    "take-and-return",
    "value-ports",
    "subsumption",
    "tour-guide",
    "assembly",
    "reflex",
];

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let corpus = root.join("fuzz/corpus");
    let only: Vec<String> = std::env::args().skip(1).collect();
    let wanted = |target: &str| only.is_empty() || only.iter().any(|name| name == target);
    let write = |target: &str, name: &str, bytes: &[u8]| {
        if !wanted(target) {
            return;
        }
        let dir = corpus.join(target);
        std::fs::create_dir_all(&dir).expect("corpus directory");
        std::fs::write(dir.join(format!("seed-{name}")), bytes).expect("seed written");
    };
    let images = ["network", "image_raw", "image_fixed_crc"];
    for name in NETWORKS
        .into_iter()
        .filter(|_| images.iter().any(|t| wanted(t)))
    {
        let path = root.join("examples").join(format!("{name}.toml"));
        let text = std::fs::read_to_string(&path).expect("example readable");
        write("network", name, text.as_bytes());
        let network = Network::parse(Source::new(&path, text)).expect("example parses");
        for node in pab_lang::compile::compile(&network).expect("example compiles") {
            let id = format!("{name}-{}", node.name);
            write("image_raw", &id, &node.image);
            write("image_fixed_crc", &id, &node.image);
        }
    }
    // A little xorshift: the same seeds on every machine.
    let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for target in TARGETS {
        if matches!(target.name, "network" | "image_raw" | "image_fixed_crc") {
            continue;
        }
        for (i, len) in [16usize, 64, 256, 1024].into_iter().enumerate() {
            let bytes: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            write(target.name, &format!("random-{i}"), &bytes);
        }
    }
    // Signed firmware images, one per board kind and metadata case.
    if wanted("update") {
        for (name, bytes) in pab_fuzz_checks::update::seeds() {
            write("update", &name, &bytes);
        }
    }
    // ISO-TP frames on CAN FD, one of each kind at each TX_DL.
    if wanted("isotp_fd") {
        for (name, bytes) in pab_fuzz_checks::isotp_fd::seeds() {
            write("isotp_fd", &name, &bytes);
        }
    }
    // One frame and one message per protocol service.
    for (service, decode, encode) in pab_fuzz_checks::protocol::service_seeds() {
        write("protocol_decode", &format!("service-{service:?}"), &decode);
        write("protocol_encode", &format!("service-{service:?}"), &encode);
    }
    if wanted("ble") {
        script_seeds(
            &write,
            "ble",
            0xB1E5_EED5_0000_0001,
            pab_fuzz_checks::ble::features,
            20,
        );
    }
    if wanted("gates") {
        script_seeds(
            &write,
            "gates",
            0x6A7E_5EED_0000_0001,
            pab_fuzz_checks::gates::features,
            20,
        );
    }
    if wanted("schema") {
        schema_seeds(&write);
    }
    if wanted("node_keyed") {
        script_seeds(
            &write,
            "node_keyed",
            0x4E7E_5EED_0000_0001,
            pab_fuzz_checks::node_keyed::features,
            6,
        );
    }
    if wanted("node_schema") {
        script_seeds(
            &write,
            "node_schema",
            0x5C4E_5EED_0000_0001,
            pab_fuzz_checks::node_schema::features,
            8,
        );
    }
}

/// The `schema` target's scripts, written by hand (`pab_fuzz_checks::schema::encode_script`):
/// a queue of moves and a grasp run to the end, an emergency stop in a move and the way back
/// through the high-priority channel, a blind search that finds its hole, a move into the
/// workspace's limit, late ticks and a robot that stops reporting, innate reflexes with an
/// abort, and a contact measured at the ends of the pose and wrench ranges.
fn schema_seeds(write: &dyn Fn(&str, &str, &[u8])) {
    use pab_core::schema::{
        Action, Config, Event, Gripper, Joint, Measure, Reaction, Source, build,
    };
    use pab_fuzz_checks::schema::{Ack, Op, decode_script, encode_script};

    let still = |ticks: u8| Op::Run {
        ticks,
        offset: [0; 6],
        wrench: [0; 6],
    };
    let start = [Op::Pose([0; 6], 0), Op::Wrench([0; 6], 0)];
    let config = Config::new(1000);
    let mut scripts: Vec<(&str, Config, Vec<Op>)> = Vec::new();

    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to(1, [10_000, 0, 0, 0, 0, 0], 100_000)),
        Op::Enqueue(build::move_to(2, [10_000, 5_000, -2_000, 0, 0, 0], 50_000)),
        Op::Enqueue(build::grasp(3, 20)),
        Op::Enqueue(build::move_to(4, [0, 0, 0, 0, 0, 100_000], 100_000)),
        Op::Enqueue(build::gripper(5, Gripper::Open)),
        still(255),
        still(255),
    ]);
    scripts.push(("moves", config.clone(), ops));

    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to(1, [20_000, 0, 0, 0, 0, 0], 100_000)),
        Op::Enqueue(build::idle(2, 50)),
        still(50),
        Op::EmergencyStop,
        Op::Tick(1),
        still(10),
        Op::HighPriority(build::move_to(3, [0; 6], 100_000), Ack::Latest),
        still(100),
        Op::Enqueue(build::idle(4, 0)),
        still(5),
    ]);
    scripts.push(("estop", config.clone(), ops));

    // The client's high-priority move races the stop: accepted before the stop's tick, it is
    // discarded there; one naming the old stop is refused; one naming the latest leaves it.
    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to(1, [20_000, 0, 0, 0, 0, 0], 100_000)),
        still(20),
        Op::HighPriority(
            build::move_to(2, [-20_000, 0, 0, 0, 0, 0], 100_000),
            Ack::Latest,
        ),
        Op::EmergencyStop,
        still(20),
        Op::HighPriority(build::idle(3, 0), Ack::Number(0)),
        still(5),
        Op::Abort,
        Op::HighPriority(build::idle(4, 0), Ack::Latest),
        still(5),
        Op::HighPriority(build::idle(5, 0), Ack::Latest),
        still(5),
    ]);
    scripts.push(("stop-race", config.clone(), ops));

    // A forged pose 400 mm away just before a stop: refused as implausible, the stop holds the
    // last plausible pose; true poses after it are taken again.
    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to(1, [20_000, 0, 0, 0, 0, 0], 100_000)),
        still(10),
        Op::Pose([400_000, 0, 0, 0, 0, 0], 0),
        Op::EmergencyStop,
        Op::Tick(1),
        still(20),
    ]);
    scripts.push(("implausible", config.clone(), ops));

    let search = Action::BlindSearch {
        preload: 2_000,
        pitch: 200,
        speed: 5_000,
        radius: 2_000,
        wobble: 10_000,
        wobble_ms: 100,
    };
    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to_touch(
            1,
            [0, 0, -1, 0, 0, 0],
            10_000,
            3_000,
            5_000,
        )),
        still(20),
        // The surface pushes back with 4 N: contact.
        Op::Run {
            ticks: 5,
            offset: [0, 0, 0, 0, 0, 0],
            wrench: [0, 0, 4_000, 0, 0, 0],
        },
        Op::Enqueue(build::blind_search(2, search, 1_000)),
        Op::Enqueue(build::grasp(3, 10)),
    ]);
    // The robot stays on the surface (z = -200 µm) under the preload while the attractor
    // spirals, then the peg drops in.
    for _ in 0..40 {
        ops.extend([
            Op::Pose([0, 0, -200, 0, 0, 0], 0),
            Op::Wrench([0, 0, 3_000, 0, 0, 0], 0),
            Op::Tick(1),
        ]);
    }
    ops.extend([Op::Pose([0, 0, -1_400, 0, 0, 0], 0), Op::Tick(1), still(20)]);
    scripts.push(("blind-search", config.clone(), ops));

    let mut near = Config::new(1000);
    near.limits.workspace_max = [5_000; 6];
    near.limits.workspace_min = [-5_000; 6];
    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to(1, [8_000, 0, 0, 0, 0, 0], 100_000)),
        still(100),
        Op::HighPriority(build::move_to(2, [0; 6], 100_000), Ack::Latest),
        still(100),
        Op::Pose([7_000, 0, 0, 0, 0, 0], 0),
        Op::Tick(1),
        Op::Tick(1),
    ]);
    scripts.push(("limit", near, ops));

    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(build::move_to(1, [8_000, 0, 0, 0, 0, 0], 10_000)),
        Op::Sensor(3, 7),
        Op::Tick(1),
        Op::Tick(4),
        Op::Tick(100),
        Op::Tick(1_000_000),
        Op::HighPriority(build::idle(2, 0), Ack::Latest),
        Op::Tick(1),
    ]);
    scripts.push(("stale", config.clone(), ops));

    let mut reflex = Config::new(1000);
    reflex
        .innate
        .push(build::move_to(100, [0; 6], 20_000))
        .expect("room for an innate schema");
    // A touch that meets nothing in 300 µm goes to the innate move home, then the queue.
    let mut guarded = build::move_to_touch(1, [1, 0, 0, 0, 0, 0], 10_000, 1_000, 300);
    guarded.reactions[1].next = Source::Innate(0);
    let mut watch = build::idle(2, 0);
    watch.reactions[0] = Reaction {
        event: Event::Above(Measure::Sensor(0), 100),
        next: Source::Innate(0),
    };
    let mut ops = start.to_vec();
    ops.extend([
        Op::Enqueue(guarded),
        Op::Enqueue(watch),
        still(40),
        Op::Sensor(0, 0),
        still(10),
        Op::Sensor(0, 500),
        still(2),
        Op::Enqueue(build::idle(3, 10)),
        Op::Enqueue(build::idle(4, 10)),
        Op::Abort,
        Op::Tick(1),
        Op::HighPriority(build::idle(5, 10), Ack::Latest),
        still(15),
    ]);
    scripts.push(("innate-abort", reflex, ops));

    // A pose at the end of i32's range arms the attractor there; a move back with a contact
    // reaction, against a wrench at the end of its range: the contact's dot product saturates
    // (its negation overflowed, until the fix with core/tests/schema_server.rs's
    // `contact_against_a_move_from_the_end_of_the_pose_range_does_not_overflow`).
    let mut wide = Config::new(1000);
    wide.limits.workspace_min = [i32::MIN; 6];
    wide.limits.workspace_max = [i32::MAX; 6];
    wide.limits.force_limit = u32::MAX;
    let max = pab_core::schema::MAX_COORD;
    let mut touch = build::move_to(1, [max, max, max, 0, 0, 0], 1);
    touch.reactions[0] = Reaction {
        event: Event::Above(Measure::Contact, 0),
        next: Source::Queue,
    };
    let ops = vec![
        Op::Enqueue(touch),
        Op::Run {
            ticks: 3,
            offset: [i32::MIN; 6],
            wrench: [i32::MIN; 6],
        },
    ];
    scripts.push(("contact-range", wide, ops));

    // A joint on sensor 0 and a speed limit of 50 mm/s: the limits tightened at run time (and
    // a looser set refused), a move too fast for them, the joint driven out of its range.
    let mut bounded = Config::new(1000);
    bounded.limits.speed_limit = 50_000;
    bounded
        .limits
        .joints
        .push(Joint {
            sensor: 0,
            min: -1000,
            max: 1000,
            rate: 2000,
        })
        .expect("room for a joint");
    let mut tight = bounded.limits.clone();
    tight.speed_limit = 20_000;
    tight.joints[0].max = 500;
    let mut loose = bounded.limits.clone();
    loose.force_limit += 1;
    let mut ops = start.to_vec();
    ops.extend([
        Op::Sensor(0, 0),
        Op::Limits(loose),
        Op::Limits(tight),
        Op::Enqueue(build::move_to(1, [10_000, 0, 0, 0, 0, 0], 40_000)),
    ]);
    for step in 0..30 {
        ops.extend([Op::Sensor(0, 20 * step), still(1)]);
    }
    ops.extend([
        Op::HighPriority(build::idle(2, 0), Ack::Latest),
        Op::Sensor(0, 700),
        still(2),
        Op::Limits(bounded.limits.clone()),
        Op::HighPriority(build::idle(3, 0), Ack::Latest),
        still(30),
    ]);
    scripts.push(("limits", bounded, ops));

    for (name, config, ops) in scripts {
        let bytes = encode_script(&config, &ops).expect("every schema fits its length byte");
        assert_eq!(
            decode_script(&bytes),
            Some((config, ops)),
            "the {name} script reads back as written"
        );
        write("schema", &format!("script-{name}"), &bytes);
    }
}

/// The seeds of a structured target (`ble`, `gates`): scripts that reach something new
/// (`features`), then the ones that reach the most, up to 20.
fn script_seeds(
    write: &dyn Fn(&str, &str, &[u8]),
    target: &str,
    mut state: u64,
    features: fn(&[u8]) -> BTreeSet<&'static str>,
    most: usize,
) {
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut reached = BTreeSet::new();
    let mut kept: Vec<Vec<u8>> = Vec::new();
    let mut others: Vec<(usize, Vec<u8>)> = Vec::new();
    for i in 0..3_000 {
        let len = [48usize, 96, 192, 384, 768, 1536][i % 6];
        let bytes: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        let features = features(&bytes);
        if features.is_subset(&reached) {
            others.push((features.len(), bytes));
        } else {
            reached.extend(features);
            kept.push(bytes);
        }
    }
    others.sort_by_key(|(count, _)| std::cmp::Reverse(*count));
    let room = most.saturating_sub(kept.len());
    kept.extend(others.into_iter().take(room).map(|(_, bytes)| bytes));
    for (i, bytes) in kept.iter().enumerate() {
        write(target, &format!("script-{i:02}"), bytes);
    }
    println!(
        "{target}: {} seeds reaching {} features: {reached:?}",
        kept.len(),
        reached.len()
    );
}
