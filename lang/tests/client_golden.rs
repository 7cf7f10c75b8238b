//! The Python client's golden vectors (`client/python/tests/golden_schemas.json`): builder calls
//! with their arguments, and the schema `pab_core::schema::build` makes for them, with the
//! network file's defaults (`pab_lang::network::Defaults`) for every argument a call leaves out,
//! as serde_json shows it, as postcard's bytes, and with what the board's check answers; and
//! safety bounds (`pab_core::schema::Limits`, the limits channel's body) with their bytes and
//! what a board with one table's limits answers for them.
//! `client/python/tests/test_schema.py` asserts that `pab_client.schema` makes the same bytes
//! for the same calls; this test asserts that the file holds what the Rust builders make now.
//! `golden_codes.json` holds the schema server's wire codes, names and descriptions
//! (`client/python/tests/test_protocol.py` holds `pab_client.protocol` to them).
//!
//! After a deliberate change of the builders, the defaults or the encoding, rewrite the file:
//! `PAB_BLESS=1 cargo test -p pab-lang --test integration client_golden::`, and commit it with
//! the change (the Python client must then follow).

use std::path::PathBuf;

use pab_core::protocol::layout::{Framing, layout};
use pab_core::protocol::{
    AuthFailure, FaultCode, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety,
    SchemaTrigger, Service,
};
use pab_core::schema::{
    Action, Event, Gripper, Joint, Limits, MAX_ENCODED, MAX_JOINTS, Measure, Pose, Reaction,
    Refusal, Schema, Source, build,
};
use pab_lang::network::Defaults;
use serde_json::{Value, json};

/// One vector: the Python builder's name, its keyword arguments, and the schema Rust makes.
struct Vector {
    call: &'static str,
    args: Value,
    schema: Schema,
}

fn v(call: &'static str, args: Value, schema: Schema) -> Vector {
    Vector { call, args, schema }
}

fn with_watchdog(mut schema: Schema, watchdog_ms: u32) -> Schema {
    schema.watchdog_ms = watchdog_ms;
    schema
}

fn search(d: &Defaults) -> Action {
    search_with(d, d.pitch, d.wobble, d.wobble_ms)
}

/// The defaults' search with another pitch or rocking.
fn search_with(d: &Defaults, pitch: u32, wobble: u32, wobble_ms: u32) -> Action {
    Action::BlindSearch {
        preload: d.preload,
        pitch,
        speed: d.search_speed,
        radius: d.search_radius,
        wobble,
        wobble_ms,
    }
}

/// `set_impedance()`'s defaults in a network file's program (lang/src/network/schema.rs).
const STIFFNESS: u32 = 2000;
const DAMPING: u32 = 100;

fn vectors() -> Vec<Vector> {
    let d = Defaults::default();
    let far: Pose = [i32::MAX, i32::MIN, -1, 1, -64, 64];
    let limits: Pose = [500_000_000, -500_000_000, 0, 1_000_000, -1_000_000, 0];
    let all_fields = Action::BlindSearch {
        preload: 2500,
        pitch: 75,
        speed: 1500,
        radius: 3000,
        wobble: 15_000,
        wobble_ms: 400,
    };
    let mut out = vec![
        // move_to: the network file's test program, defaults, every varint length, signs,
        // limits, and the refusals the board's check makes.
        v(
            "move_to",
            json!({"id": 1, "goal": [1000, 2000, 3000, 0, 0, 0], "speed": 20_000}),
            build::move_to(1, [1000, 2000, 3000, 0, 0, 0], 20_000),
        ),
        v(
            "move_to",
            json!({"id": 2, "goal": [-100_000, -60_000, 35_000, 0, 0, 0]}),
            build::move_to(2, [-100_000, -60_000, 35_000, 0, 0, 0], d.speed),
        ),
        v(
            "move_to",
            json!({"id": 0xFEFF, "goal": [-1, 1, -64, 64, -8192, 8191], "speed": 1}),
            build::move_to(0xFEFF, [-1, 1, -64, 64, -8192, 8191], 1),
        ),
        v(
            "move_to",
            json!({"id": 0x3FFF, "goal": limits, "speed": 500_000_000}),
            build::move_to(0x3FFF, limits, 500_000_000),
        ),
        v(
            "move_to",
            json!({"id": 0x4000, "goal": far, "speed": u32::MAX}),
            build::move_to(0x4000, far, u32::MAX),
        ),
        v(
            "move_to",
            json!({"id": 127, "goal": [0, 0, 0, 0, 0, 0], "speed": 0}),
            build::move_to(127, [0; 6], 0),
        ),
        v(
            "move_to",
            json!({"id": 0xFF00, "goal": [1, 2, 3, 4, 5, 6], "speed": 128}),
            build::move_to(0xFF00, [1, 2, 3, 4, 5, 6], 128),
        ),
        v(
            "move_to",
            json!({"id": 128, "goal": [5000, 0, -5000, 0, 0, 0], "speed": 16_384, "watchdog_ms": 2_000_000}),
            with_watchdog(
                build::move_to(128, [5000, 0, -5000, 0, 0, 0], 16_384),
                2_000_000,
            ),
        ),
        // move_to_touch.
        v(
            "move_to_touch",
            json!({"id": 2, "direction": [0, 0, -1000, 0, 0, 0], "speed": 5000, "contact": 5000, "distance": 50_000}),
            build::move_to_touch(2, [0, 0, -1000, 0, 0, 0], 5000, 5000, 50_000),
        ),
        v(
            "move_to_touch",
            json!({"id": 3, "direction": [0, 0, -1, 0, 0, 0]}),
            build::move_to_touch(
                3,
                [0, 0, -1, 0, 0, 0],
                d.touch_speed,
                d.contact,
                d.touch_distance,
            ),
        ),
        v(
            "move_to_touch",
            json!({"id": 0xABCD, "direction": [-7, 3, -1_000_000, 0, 0, 0], "speed": 300, "contact": -1, "distance": 0}),
            build::move_to_touch(0xABCD, [-7, 3, -1_000_000, 0, 0, 0], 300, -1, 0),
        ),
        v(
            "move_to_touch",
            json!({"id": 9, "direction": [0, 0, 0, 0, 0, 1000], "contact": i32::MIN, "distance": u32::MAX}),
            build::move_to_touch(9, [0, 0, 0, 0, 0, 1000], d.touch_speed, i32::MIN, u32::MAX),
        ),
        // grasp and release.
        v(
            "grasp",
            json!({"id": 3, "settle_ms": 200}),
            build::grasp(3, 200),
        ),
        v("grasp", json!({"id": 40}), build::grasp(40, d.settle_ms)),
        v(
            "grasp",
            json!({"id": 0xFEFE, "settle_ms": 500_000_000}),
            build::grasp(0xFEFE, 500_000_000),
        ),
        v(
            "release",
            json!({"id": 41}),
            build::release(41, d.settle_ms),
        ),
        v(
            "release",
            json!({"id": 42, "settle_ms": 0, "watchdog_ms": 1}),
            with_watchdog(build::release(42, 0), 1),
        ),
        v(
            "release",
            json!({"id": 43, "settle_ms": 500_000_001}),
            build::release(43, 500_000_001),
        ),
        // blind_search: defaults, every field, the depth's saturation, its refusals.
        v(
            "blind_search",
            json!({"id": 5}),
            build::blind_search(5, search(&d), d.insert_depth),
        ),
        v(
            "blind_search",
            json!({"id": 0x1234, "preload": 2500, "pitch": 75, "speed": 1500, "radius": 3000,
                   "wobble": 15_000, "wobble_ms": 400, "depth": 1200, "watchdog_ms": 60_000}),
            with_watchdog(build::blind_search(0x1234, all_fields, 1200), 60_000),
        ),
        v(
            "blind_search",
            json!({"id": 6, "depth": 0, "wobble": 0, "wobble_ms": 0}),
            build::blind_search(6, search_with(&d, d.pitch, 0, 0), 0),
        ),
        v(
            "blind_search",
            json!({"id": 7, "depth": u32::MAX}),
            build::blind_search(7, search(&d), u32::MAX),
        ),
        v(
            "blind_search",
            json!({"id": 8, "pitch": 0}),
            build::blind_search(8, search_with(&d, 0, d.wobble, d.wobble_ms), d.insert_depth),
        ),
        v(
            "blind_search",
            json!({"id": 9, "wobble_ms": 0}),
            build::blind_search(9, search_with(&d, d.pitch, d.wobble, 0), d.insert_depth),
        ),
        // idle.
        v("idle", json!({"id": 4, "ms": 250}), build::idle(4, 250)),
        v("idle", json!({"id": 10}), build::idle(10, 0)),
        v(
            "idle",
            json!({"id": 11, "ms": 16_384}),
            build::idle(11, 16_384),
        ),
        // The atomic actions.
        v(
            "open_gripper",
            json!({"id": 12}),
            build::gripper(12, Gripper::Open),
        ),
        v(
            "close_gripper",
            json!({"id": 13}),
            build::gripper(13, Gripper::Closed),
        ),
        v(
            "gripper",
            json!({"id": 14, "g": 1}),
            build::gripper(14, Gripper::Closed),
        ),
        v(
            "relieve",
            json!({"id": 15}),
            build::atomic(15, Action::Relieve),
        ),
        v(
            "set_impedance",
            json!({"id": 16}),
            build::atomic(
                16,
                Action::SetImpedance {
                    stiffness: STIFFNESS,
                    damping: DAMPING,
                },
            ),
        ),
        v(
            "set_impedance",
            json!({"id": 17, "stiffness": 0, "damping": 500_000_000}),
            build::atomic(
                17,
                Action::SetImpedance {
                    stiffness: 0,
                    damping: 500_000_000,
                },
            ),
        ),
    ];
    // Schemas no builder makes, for the encoding of every event, measure and source: the Python
    // side builds them from their serde_json form ("schema" calls take no arguments).
    out.extend(
        literal_schemas()
            .into_iter()
            .map(|s| v("schema", json!({}), s)),
    );
    out
}

fn literal_schemas() -> Vec<Schema> {
    let on = |event, next| Reaction { event, next };
    let every = [
        on(Event::OneShot, Source::Innate(0)),
        on(Event::Done, Source::Innate(255)),
        on(Event::Elapsed(0), Source::Queue),
        on(Event::Elapsed(u32::MAX), Source::HighPriority),
        on(Event::QueueReady, Source::Queue),
        on(Event::Above(Measure::Position(0), i32::MIN), Source::Queue),
        on(
            Event::Above(Measure::Displacement(5), i32::MAX),
            Source::Queue,
        ),
        on(Event::Above(Measure::Force(2), -3000), Source::HighPriority),
        on(Event::Above(Measure::Contact, 0), Source::Queue),
        on(Event::Above(Measure::Sensor(7), 1), Source::Innate(3)),
        on(Event::Below(Measure::Position(3), -1), Source::Queue),
        on(Event::Below(Measure::Displacement(2), 63), Source::Queue),
        on(Event::Below(Measure::Force(5), 64), Source::Queue),
        on(Event::Below(Measure::Contact, -65), Source::Queue),
        on(Event::Below(Measure::Sensor(0), 8191), Source::Queue),
        on(
            Event::Below(Measure::Sensor(1), -8192),
            Source::HighPriority,
        ),
    ];
    let schema = |id, action, reactions: &[Reaction], watchdog_ms| Schema {
        id,
        action,
        reactions: reactions.iter().copied().collect(),
        watchdog_ms,
    };
    vec![
        // Sixteen reactions, the most a schema holds.
        schema(
            0x0100,
            Action::MoveTo {
                goal: [0, 0, 0, 0, 0, 0],
                speed: 1000,
            },
            &every,
            u32::MAX,
        ),
        // No reaction: only the server's safety events end it.
        schema(0x0101, Action::Idle { ms: 0 }, &[], 0),
        schema(
            0x0102,
            Action::Gripper(Gripper::Open),
            &[on(Event::Elapsed(100), Source::Innate(1))],
            5,
        ),
        // The board's refusals of events: an axis of 6, a sensor of 8.
        schema(
            0x0103,
            Action::Relieve,
            &[on(Event::Above(Measure::Force(6), 1), Source::Queue)],
            0,
        ),
        schema(
            0x0104,
            Action::Relieve,
            &[on(Event::Below(Measure::Sensor(8), 1), Source::Queue)],
            0,
        ),
        schema(
            0x0105,
            Action::MoveToTouch {
                direction: [0, 0, 0, 1, 0, 0],
                speed: 10,
                distance: 10,
            },
            &[on(Event::Done, Source::Queue)],
            0,
        ),
    ]
}

fn golden_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../client/python/tests/golden_schemas.json")
}

fn entry(vector: &Vector) -> Value {
    let mut buffer = [0u8; 2 * MAX_ENCODED];
    let bytes = postcard::to_slice(&vector.schema, &mut buffer).expect("a schema fits");
    let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
    let check = vector
        .schema
        .check()
        .err()
        .map(|e| format!("{:?}", SchemaOutcome::from(&e)));
    // The board's decoder reads the bytes back into the same schema (or refuses it as the check
    // does).
    match Schema::decode(bytes) {
        Ok(decoded) => assert_eq!(decoded, vector.schema, "{}", vector.call),
        Err(e) => assert_eq!(
            Some(format!("{:?}", SchemaOutcome::from(&e))),
            check,
            "{}",
            vector.call
        ),
    }
    json!({
        "call": vector.call,
        "args": vector.args,
        "schema": serde_json::to_value(&vector.schema).expect("serialisable"),
        "hex": hex,
        "check": check,
    })
}

/// The table's limits the `limits` vectors are checked against: a speed limit, a torque
/// limit, two joints (one without a speed).
fn limits_table() -> Limits {
    let mut table = Limits::new();
    table.torque_limit = 5_000;
    table.speed_limit = 250_000;
    table.workspace_min[2] = -20_000;
    table.workspace_max[2] = 100_000;
    table.joints.push(joint(1, -900, 1200, 450)).unwrap();
    table.joints.push(joint(3, 0, 4095, 0)).unwrap();
    table
}

fn joint(sensor: u8, min: i32, max: i32, rate: u32) -> Joint {
    Joint {
        sensor,
        min,
        max,
        rate,
    }
}

/// Limits for the limits channel: the table's, tighter ones, every varint length and extreme,
/// the most joints, and the refusals (looser somewhere, other joints, inconsistent).
fn limits_vectors() -> Vec<Limits> {
    let table = limits_table();
    let with = |change: &dyn Fn(&mut Limits)| {
        let mut l = table.clone();
        change(&mut l);
        l
    };
    let mut extremes = Limits::new();
    extremes.workspace_min = [i32::MIN, -1, -64, -65, -8192, 0];
    extremes.workspace_max = [i32::MAX, 0, 63, 64, 8191, 8192];
    extremes.force_limit = u32::MAX;
    extremes.torque_limit = 127;
    extremes.contact_limit = 128;
    extremes.speed_limit = 16_383;
    extremes.rate_limit = 16_384;
    for i in 0..MAX_JOINTS as u8 {
        let j = match i {
            0 => joint(255, i32::MIN, i32::MAX, u32::MAX),
            _ => joint(i, -i32::from(i) * 1000, i32::from(i) * 1000, u32::from(i)),
        };
        extremes.joints.push(j).unwrap();
    }
    vec![
        Limits::new(),
        table.clone(),
        // Tighter everywhere.
        with(&|l| {
            l.workspace_min = [-200_000, -200_000, -10_000, -500_000, -500_000, -1_000_000];
            l.workspace_max = [200_000, 150_000, 90_000, 500_000, 500_000, 1_000_000];
            l.force_limit = 20_000;
            l.torque_limit = 1_000;
            l.contact_limit = 4_000;
            l.speed_limit = 100_000;
            l.rate_limit = 0;
            l.joints[0] = joint(1, -450, 600, 100);
            l.joints[1] = joint(3, 100, 4000, 50);
        }),
        extremes,
        // Looser: a corner, a limit, none where the table has one, a joint's range or speed,
        // other joints.
        with(&|l| l.workspace_max[2] = 100_001),
        with(&|l| l.workspace_min[5] = -1_000_001),
        with(&|l| l.force_limit = 50_001),
        with(&|l| l.speed_limit = 0),
        with(&|l| l.torque_limit = 5_001),
        with(&|l| l.joints[0].min = -901),
        with(&|l| l.joints[0].rate = 0),
        with(&|l| l.joints[1].sensor = 2),
        with(&|l| {
            l.joints.pop();
        }),
        // Inconsistent: a crossed corner or joint, a force limit of 0.
        with(&|l| {
            l.workspace_min[0] = 10;
            l.workspace_max[0] = -10;
        }),
        with(&|l| l.joints[1] = joint(3, 20, 10, 0)),
        with(&|l| l.force_limit = 0),
    ]
}

fn limits_entry(limits: &Limits) -> Value {
    let mut buffer = [0u8; 2 * MAX_ENCODED];
    let bytes = postcard::to_slice(limits, &mut buffer).expect("limits fit");
    assert!(
        bytes.len() <= MAX_ENCODED,
        "the limits channel's body fits a message"
    );
    // The board's decoder reads them back.
    assert_eq!(Limits::decode(bytes).as_ref(), Ok(limits));
    let within = limits
        .check_within(&limits_table())
        .err()
        .map(|_| format!("{:?}", SchemaOutcome::from(&Refusal::Looser)));
    json!({
        "limits": serde_json::to_value(limits).expect("serialisable"),
        "hex": bytes.iter().map(|b| format!("{b:02x}")).collect::<String>(),
        "within": within,
    })
}

fn golden() -> Value {
    json!({
        "about": "Golden vectors of the Python client (pab_client.schema): each builder call \
                  with its keyword arguments (those left out take the network file's defaults), \
                  the schema pab_core::schema::build makes for it (serde_json's form), its \
                  postcard bytes, and the board's check (null: accepted, else the SchemaOutcome); \
                  and under `limits`, safety bounds (pab_core::schema::Limits, serde_json's \
                  form) with their postcard bytes and what a board whose table has the limits \
                  `table` answers for them on the limits channel (`within`: null accepted, else \
                  the SchemaOutcome). \
                  Written and checked by lang/tests/client_golden.rs \
                  (PAB_BLESS=1 cargo test -p pab-lang --test integration client_golden:: \
                  rewrites it); \
                  client/python/tests/test_schema.py checks the Python builders against it.",
        "vectors": vectors().iter().map(entry).collect::<Vec<_>>(),
        "limits": {
            "table": serde_json::to_value(limits_table()).expect("serialisable"),
            "vectors": limits_vectors().iter().map(limits_entry).collect::<Vec<_>>(),
        },
    })
}

#[test]
fn the_python_clients_golden_vectors_are_what_the_rust_builders_make() {
    let expected = golden();
    let path = golden_path();
    let Some(found) = blessed_or_read(&path, &expected) else {
        return;
    };
    let (Some(found_vectors), Some(expected_vectors)) =
        (found["vectors"].as_array(), expected["vectors"].as_array())
    else {
        panic!("{}: no `vectors` list", path.display());
    };
    for (i, (f, e)) in found_vectors.iter().zip(expected_vectors).enumerate() {
        assert_eq!(
            f, e,
            "vector {i} ({}) differs from what the Rust builders make: after a deliberate \
             change, rewrite the file with PAB_BLESS=1 cargo test -p pab-lang --test \
             integration client_golden:: and update the Python client",
            e["call"]
        );
    }
    assert_eq!(
        found_vectors.len(),
        expected_vectors.len(),
        "the golden file's vector count (PAB_BLESS=1 rewrites it)"
    );
    assert_eq!(found, expected, "the golden file (PAB_BLESS=1 rewrites it)");
}

#[test]
fn the_vectors_cover_every_builder_and_variant() {
    let vectors = vectors();
    for call in [
        "move_to",
        "move_to_touch",
        "grasp",
        "release",
        "blind_search",
        "idle",
        "gripper",
        "open_gripper",
        "close_gripper",
        "relieve",
        "set_impedance",
        "schema",
    ] {
        assert!(vectors.iter().any(|v| v.call == call), "{call}");
    }
    // Every action variant, and the encodings' extremes.
    let actions: Vec<_> = vectors.iter().map(|v| v.schema.action).collect();
    assert!(actions.iter().any(|a| matches!(a, Action::Idle { .. })));
    assert!(actions.iter().any(|a| matches!(a, Action::Gripper(_))));
    assert!(
        actions
            .iter()
            .any(|a| matches!(a, Action::SetImpedance { .. }))
    );
    assert!(actions.iter().any(|a| matches!(a, Action::Relieve)));
    assert!(actions.iter().any(|a| matches!(a, Action::MoveTo { .. })));
    assert!(
        actions
            .iter()
            .any(|a| matches!(a, Action::MoveToTouch { .. }))
    );
    assert!(
        actions
            .iter()
            .any(|a| matches!(a, Action::BlindSearch { .. }))
    );
    assert!(actions.iter().any(|a| matches!(a, Action::Grasp { .. })));
    assert!(actions.iter().any(|a| matches!(a, Action::Release { .. })));
    assert!(vectors.iter().any(|v| v.schema.reactions.len() == 16));
    assert!(vectors.iter().any(|v| v.schema.id == 0xFEFF));
}

/// The authentication vectors of the Python client (`client/python/tests/golden_auth.json`):
/// the tags and MACs `pab_core::auth::Authenticator` makes for a keyed schema transfer, which
/// `pab_client.auth` must make byte for byte (`client/python/tests/test_auth.py`).
fn golden_auth() -> Value {
    use pab_core::auth::{Authenticator, Key};
    use pab_core::protocol::{Message, OPEN_SCHEMA, SchemaAck, SchemaChannel};
    let key_bytes: [u8; 16] = core::array::from_fn(|i| (i as u8).wrapping_mul(17).wrapping_add(3));
    let auth = Authenticator::new(&Key::from_bytes(key_bytes));
    let hex = |bytes: &[u8]| bytes.iter().map(|b| format!("{b:02x}")).collect::<String>();
    let mut buffer = [0u8; MAX_ENCODED];
    let schema = build::move_to(7, [100_000, -60_000, 35_000, 0, 0, 0], 50_000);
    let mut message = vec![1 | 5 << 2];
    message.extend_from_slice(postcard::to_slice(&schema, &mut buffer).expect("fits"));
    let ack = Message::SchemaAck(SchemaAck {
        outcome: pab_core::protocol::SchemaOutcome::Accepted,
        channel: Some(SchemaChannel::HighPriority),
        id: 7,
        queued: 0,
        stop: 5,
    })
    .to_frame(10, 0);
    let vectors: Vec<Value> = [
        (10u8, 0x0102_0304_0506_0708u64, 0x0000_0003_0000_0001u64),
        (127, u64::MAX, pab_core::auth::NODE_NONCE_MAX),
    ]
    .into_iter()
    .map(|(node, tool, node_nonce)| {
        let exchange = auth.exchange(node, tool, node_nonce);
        let nonce = exchange.nonce;
        let length = (message.len() + 16) as u16;
        json!({
            "node": node,
            "tool_nonce": tool.to_string(),
            "node_nonce": node_nonce.to_string(),
            "binding": hex(&exchange.binding),
            "nonce": nonce.to_string(),
            "message": hex(&message),
            "length": length,
            "open_tag": hex(&auth.open_tag(node, nonce, length, OPEN_SCHEMA)),
            "image_mac": hex(&auth.image_mac(node, nonce, OPEN_SCHEMA, &message)),
            "ack": hex(ack.payload()),
            "receipt_tag": hex(&auth.receipt_tag(node, nonce, ack.payload().try_into().expect("8 bytes"), 0, false)),
        })
    })
    .collect();
    json!({
        "about": "Golden vectors of the Python client's authentication (pab_client.auth): a key, \
                  and for two nodes and exchanges (tool nonce, node nonce) the exchange's nonce \
                  and the Challenge's binding, a keyed schema transfer's TransferOpen tag, the \
                  message's MAC and the Receipt tag of its SchemaAck, as pab_core::auth makes \
                  them. Written and checked by lang/tests/client_golden.rs (PAB_BLESS=1 cargo \
                  test -p pab-lang --test integration client_golden:: rewrites it); \
                  client/python/tests/test_auth.py checks pab_client.auth against it.",
        "key": hex(&key_bytes),
        "vectors": vectors,
    })
}

#[test]
fn the_python_clients_authentication_vectors_are_what_the_core_makes() {
    let expected = golden_auth();
    let Some(found) = blessed_or_read(&golden_path().with_file_name("golden_auth.json"), &expected)
    else {
        return;
    };
    assert_eq!(found, expected, "the golden file (PAB_BLESS=1 rewrites it)");
}

/// The wire codes a client reads (`pab_core::protocol`'s `wire_enum!`s): the schema server's,
/// and the faults with the authentication refusals (a keyed client tells a flood of bad tags
/// from a silent node by them): each enumeration's values with their code, name and
/// description, which `pab_client.protocol` must repeat.
fn golden_codes() -> Value {
    macro_rules! codes {
        ($enum:ty) => {
            <$enum>::ALL
                .iter()
                .map(|v| json!({"code": v.code(), "name": format!("{v:?}"), "description": v.description()}))
                .collect::<Vec<_>>()
        };
    }
    json!({
        "about": "The wire codes, names and descriptions a client reads (pab_core::protocol): the \
                  schema server's, the faults' and the authentication refusals', \
                  which pab_client.protocol repeats. Written and checked by \
                  lang/tests/client_golden.rs (PAB_BLESS=1 cargo test -p pab-lang --test \
                  integration client_golden:: rewrites it); client/python/tests/test_protocol.py checks \
                  pab_client.protocol against it.",
        "SchemaOutcome": codes!(SchemaOutcome),
        "SchemaSafety": codes!(SchemaSafety),
        "SchemaChannel": codes!(SchemaChannel),
        "SchemaTrigger": codes!(SchemaTrigger),
        "SchemaOrigin": codes!(SchemaOrigin),
        "FaultCode": codes!(FaultCode),
        "AuthFailure": codes!(AuthFailure),
    })
}

#[test]
fn the_python_clients_codes_are_the_wire_enums() {
    let expected = golden_codes();
    let Some(found) = blessed_or_read(
        &golden_path().with_file_name("golden_codes.json"),
        &expected,
    ) else {
        return;
    };
    assert_eq!(found, expected, "the golden file (PAB_BLESS=1 rewrites it)");
}

/// Every service's payload layout (`pab_core::protocol::layout`, the one description of each
/// frame): its code, priority, length and fields, which the Python client's and the HIL
/// harness's codecs are checked against (client/python/tests/test_layouts.py,
/// hil-sim/unit/test_layouts.py).
fn golden_layouts() -> Value {
    let services: Vec<Value> = Service::ALL
        .into_iter()
        .map(|service| {
            let layout = layout(service);
            let fields: Vec<Value> = layout
                .fields
                .iter()
                .map(|f| {
                    json!({
                        "name": f.name,
                        "bit": f.bit,
                        "bits": f.bits,
                        "signed": f.signed,
                        "scale": format!("{:?}", f.scale),
                        "max": f.max,
                        "unit": f.unit,
                        "reserved": f.is_reserved(),
                        "values": f.values.iter().map(|(code, text)| json!([code, text])).collect::<Vec<_>>(),
                    })
                })
                .collect();
            json!({
                "name": format!("{service:?}"),
                "code": service.code(),
                "priority": service.priority().value(),
                "length": layout.len,
                "framing": match layout.framing {
                    Framing::IsoTp => "isotp",
                    _ => "fixed",
                },
                "fields": fields,
            })
        })
        .collect();
    json!({
        "about": "Every payload of the pab protocol, field by field (pab_core::protocol::layout). \
                  Written and checked by lang/tests/client_golden.rs (PAB_BLESS=1 cargo test -p \
                  pab-lang --test integration client_golden:: rewrites it); the Python client's \
                  and the HIL harness's codecs and constants are tested against it. Bits: 8 x byte \
                  + bit, little endian.",
        "services": services,
    })
}

#[test]
fn the_python_layouts_are_the_cores() {
    let expected = golden_layouts();
    let Some(found) = blessed_or_read(
        &golden_path().with_file_name("golden_layouts.json"),
        &expected,
    ) else {
        return;
    };
    assert_eq!(found, expected, "the golden file (PAB_BLESS=1 rewrites it)");
}

/// With `PAB_BLESS` set: writes `expected` to `path` and returns `None`. Otherwise the file's
/// JSON, to compare.
fn blessed_or_read(path: &std::path::Path, expected: &Value) -> Option<Value> {
    if std::env::var_os("PAB_BLESS").is_some() {
        let text = serde_json::to_string_pretty(expected).expect("serialisable") + "\n";
        std::fs::write(path, text).expect("writes the golden vectors");
        return None;
    }
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| {
        panic!(
            "{}: {e}; write it with PAB_BLESS=1 cargo test -p pab-lang --test integration \
             client_golden::",
            path.display()
        )
    });
    Some(serde_json::from_str(&text).expect("the golden file is JSON"))
}
