//! The schema server's sections: every key read, every mistake at its place.

use crate::diagnostic::Source;
use crate::network::{Command, Network};

const BASE: &str = r#"
[nodes.arm]
id = 10

[schema.arm]
period_ms = 1
force_limit_n = 30
drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }

[client]
node = "arm"
"#;

fn errors(extra: &str) -> Vec<String> {
    match Network::parse(Source::new("net.toml", format!("{BASE}{extra}"))) {
        Ok(_) => Vec::new(),
        Err(d) => d.0.iter().map(|d| d.to_string()).collect(),
    }
}

#[test]
fn a_program_in_the_papers_api_becomes_the_builders_schemas() {
    let text = format!(
        "{BASE}program = [\"move_to(p, speed=20)\", \"move_to_touch(down, contact=5)\", \"grasp()\", \"idle(250)\"]\n\
         [client.places]\np = [1, 2, 3]\ndown = [0, 0, -1]\n\
         [[client.commands]]\nat = 1.5\ncall = \"estop()\"\n"
    );
    let network = Network::parse(Source::new("net.toml", text)).unwrap();
    let client = network.client.unwrap();
    let schemas: Vec<_> = client.program.iter().map(|c| c.schema.clone()).collect();
    use pab_core::schema::build;
    assert_eq!(
        schemas,
        vec![
            build::move_to(1, [1000, 2000, 3000, 0, 0, 0], 20_000),
            build::move_to_touch(2, [0, 0, -1000, 0, 0, 0], 5000, 5000, 50_000),
            build::grasp(3, 200),
            build::idle(4, 250),
        ]
    );
    assert_eq!(network.schema_boards[0].config.limits.force_limit, 30_000);
    assert_eq!(client.commands[0].t_us, 1_500_000);
    assert_eq!(client.commands[0].command, Command::EmergencyStop);
}

#[test]
fn mistakes_are_reported_at_their_line() {
    let e = errors("program = [\"move_to(nowhere)\"]\n[client.places]\nhere = [0, 0, 0]\n");
    assert_eq!(
        e,
        ["net.toml:12:21: error: place `nowhere` is not in [client.places] (here)"]
    );
    let e = errors("program = [\"fly()\"]\n");
    assert!(
        e[0].starts_with("net.toml:12:13: error: unknown call `fly`: the calls are move_to("),
        "{e:?}"
    );
    let e = errors("program = [\"grasp(force=3)\"]\n");
    assert_eq!(
        e,
        ["net.toml:12:19: error: `grasp` takes no `force` (it takes: settle)"]
    );
    let e = errors("program = [\"grasp(settle=-1)\"]\n");
    assert_eq!(
        e,
        ["net.toml:12:19: error: `settle=-1`: a keyword's value is a number, 0 or more"]
    );
    let e = errors("program = [\"move_to(speed=3, p)\"]\n");
    assert_eq!(
        e,
        ["net.toml:12:30: error: `p`: positional arguments come before keywords"]
    );
    let e = errors("program = [\"grasp(\"]\n");
    assert_eq!(e, ["net.toml:12:19: error: the call's `)` is missing"]);
    let e = errors("program = [\"estop()\"]\n");
    assert!(
        e[0].contains("unknown call `estop`") && !e[0].contains("estop() or abort()"),
        "{e:?}"
    );
    let e = errors("[[client.commands]]\nat = 1\ncall = \"move_to()\"\n");
    assert_eq!(
        e,
        ["net.toml:14:9: error: `move_to` needs a PLACE: `move_to(PLACE)`"]
    );
}

/// A board with two sensors and two innate schemas, and a program whose call reacts to
/// them.
const REFLEXES: &str =
    "program = [\"move_to(p); below(gap, 0.25) -> retreat; above(grip, 1) -> high_priority\"]
[client.places]
p = [0, 0, -5]
[schema.arm.sensors.gap]
can_id = 0x330
value = { offset = 0, size = 2 }
scale = 0.1
unit = \"mm\"
[schema.arm.sensors.grip]
can_id = 0x12345
extended = true
value = { offset = 1, size = 1, signed = true }
unit = \"N\"
[schema.arm.places]
safe = [0, 0, 80]
[schema.arm.innate]
retreat = \"move_to(safe, speed=20); done -> high_priority\"
hold = \"idle(); below(gap, 0.3) -> retreat\"
";

#[test]
fn innate_schemas_and_sensors_are_named_in_reactions() {
    use pab_core::schema::{Event, Measure, Reaction, Sensor, Source as From, build};
    use pab_core::{Endian, Field, OutputId};
    let network = Network::parse(Source::new("net.toml", format!("{BASE}{REFLEXES}")))
        .unwrap_or_else(|e| panic!("{e:?}"));
    let board = &network.schema_boards[0];
    let names: Vec<_> = board.sensors.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["gap", "grip"]);
    assert_eq!(
        board.sensors[1].sensor,
        Sensor {
            id: OutputId::new(0x12345, true).unwrap(),
            field: Field {
                offset: 1,
                size: 1,
                signed: true,
                endian: Endian::Little
            }
        }
    );
    assert_eq!(
        (board.sensors[0].scale, board.sensors[0].unit.as_str()),
        (0.1, "mm")
    );
    assert_eq!(board.innate, ["retreat", "hold"]);
    let on = |event, next| Reaction { event, next };
    let mut retreat = build::move_to(crate::network::INNATE_IDS, [0, 0, 80_000, 0, 0, 0], 20_000);
    retreat
        .reactions
        .insert(0, on(Event::Done, From::HighPriority))
        .unwrap();
    // 0.3 mm is 3 counts of 0.1 mm, though 0.3 / 0.1 is 2.999… in floating point.
    let mut hold = build::idle(crate::network::INNATE_IDS + 1, 0);
    hold.reactions
        .insert(0, on(Event::Below(Measure::Sensor(0), 3), From::Innate(0)))
        .unwrap();
    assert_eq!(board.config.innate.as_slice(), [retreat, hold]);
    // At most 0.25 mm is at most 2 counts (0.2 mm): the board's comparison of counts holds
    // exactly when the reading in mm would.
    let mut call = build::move_to(1, [0, 0, -5000, 0, 0, 0], 50_000);
    call.reactions
        .insert(0, on(Event::Below(Measure::Sensor(0), 2), From::Innate(0)))
        .unwrap();
    call.reactions
        .insert(
            1,
            on(Event::Above(Measure::Sensor(1), 1), From::HighPriority),
        )
        .unwrap();
    let client = network.client.as_ref().unwrap();
    assert_eq!(client.program[0].schema, call);
    assert_eq!(client.program[0].name, "move_to(p)");
}

#[test]
fn reactions_sensors_and_innate_schemas_report_mistakes_at_their_line() {
    let places = "[client.places]\np = [0, 0, 0]\n";
    let sensor = "[schema.arm.sensors.gap]\ncan_id = 0x330\nvalue = { offset = 0, size = 1 }\nscale = 0.5\nunit = \"mm\"\n";
    let e = errors(&format!(
        "program = [\"move_to(p); done -> nowhere\"]\n{places}"
    ));
    assert_eq!(
        e,
        [
            "net.toml:12:33: error: `nowhere` is not a source: queue, high_priority or an innate schema of the board (innate: none)"
        ]
    );
    let e = errors(&format!("program = [\"move_to(p);done queue\"]\n{places}"));
    assert!(
        e[0].starts_with("net.toml:12:24: error: a reaction is written `EVENT -> SOURCE`"),
        "{e:?}"
    );
    let e = errors(&format!(
        "program = [\"move_to(p); below(gap2, 1) -> queue\"]\n{places}{sensor}"
    ));
    assert!(
        e[0].starts_with(
            "net.toml:12:31: error: `gap2` is not a measure: contact (N), position.AXIS"
        ) && e[0].ends_with("(sensors: gap)"),
        "{e:?}"
    );
    let e = errors(&format!(
        "program = [\"move_to(p); above(gap, 200) -> queue\"]\n{places}{sensor}"
    ));
    assert_eq!(
        e,
        [
            "net.toml:12:31: error: `above(gap, 200)` can never hold: sensor `gap` reads 0 to 127.5 mm"
        ]
    );
    let e = errors(&format!(
        "program = [\"move_to(p); above(force.w, 2) -> queue; elapsed(1, 2) -> queue\"]\n{places}"
    ));
    assert_eq!(
        e,
        ["net.toml:12:31: error: `force.w`: the axes are x, y, z, rx, ry and rz"]
    );
    let e = errors(&format!(
        "program = [\"move_to(p); elapsed(1, 2) -> queue\"]\n{places}"
    ));
    assert_eq!(
        e,
        ["net.toml:12:25: error: `elapsed` takes 1 argument: a time in ms"]
    );
    let e = errors("[[client.commands]]\nat = 1\ncall = \"estop(); done -> queue\"\n");
    assert_eq!(
        e,
        ["net.toml:14:17: error: `estop()` is a command, not a schema: it takes no reactions"]
    );
    // The sensors' own keys.
    let e = errors("[schema.arm.sensors.s]\ncan_id = 0x311\nvalue = { offset = 0, size = 2 }\n");
    assert_eq!(
        e,
        ["net.toml:13:10: error: sensor `s`: can_id is one of the drive's frames"]
    );
    let e = errors("[schema.arm.sensors.s]\ncan_id = 0x800\nvalue = { offset = 0, size = 2 }\n");
    assert_eq!(
        e,
        ["net.toml:13:10: error: sensor `s`: can_id is 0..=0x7FF (extended = false)"]
    );
    let e = errors(
        "[schema.arm.sensors.s]\ncan_id = 0x330\nvalue = { offset = 0, size = 3 }\nscale = 0\n",
    );
    assert_eq!(
        e,
        ["net.toml:14:30: error: sensor `s`: value: size = 3 is not 1, 2 or 4 (bytes)"]
    );
    let e = errors(
        "[schema.arm.sensors.s]\ncan_id = 0x330\nvalue = { offset = 0, size = 2 }\nscale = 0\n",
    );
    assert_eq!(
        e,
        ["net.toml:15:9: error: sensor `s`: scale is a positive number (units per count)"]
    );
    let e =
        errors("[schema.arm.sensors.contact]\ncan_id = 0x330\nvalue = { offset = 0, size = 2 }\n");
    assert!(
        e[0].starts_with("net.toml:12:21: error: sensor `contact`: a sensor's name is"),
        "{e:?}"
    );
    let e = errors(
        "[schema.arm.sensors.s]\ncan_id = 0x330\nvalue = { offset = 0, size = 2 }\nrate = 3\n",
    );
    assert!(
        e[0].starts_with("net.toml:15:1: error: unknown key `rate`"),
        "{e:?}"
    );
    // Innate schemas: their calls and reactions, their names, their number.
    let e = errors("[schema.arm.innate]\nx = \"idle(); done -> y\"\n");
    assert_eq!(
        e,
        [
            "net.toml:13:22: error: `y` is not a source: queue, high_priority or an innate schema of the board (innate: x)"
        ]
    );
    let e = errors("[schema.arm.innate]\nx = \"move_to(nowhere)\"\n");
    assert_eq!(
        e,
        ["net.toml:13:14: error: place `nowhere` is not in [client.places] (none)"]
    );
    let e = errors("[schema.arm.innate]\nqueue = \"idle()\"\n");
    assert!(
        e[0].starts_with("net.toml:13:1: error: innate schema `queue`: a name is"),
        "{e:?}"
    );
    let many: String = (0..9).map(|i| format!("s{i} = \"idle()\"\n")).collect();
    let e = errors(&format!("[schema.arm.innate]\n{many}"));
    assert_eq!(
        e,
        ["net.toml:21:1: error: [schema.arm.innate]: 9 schemas; a board stores at most 8"]
    );
    // The plant's range finder publishes mm on a board sensor.
    let e = errors(&format!(
        "{}[plant]\nrange_finder = \"gap\"\n",
        sensor.replace("\"mm\"", "\"cm\"")
    ));
    assert_eq!(
        e,
        [
            "net.toml:18:16: error: range_finder: sensor `gap` must have unit = \"mm\": the plant publishes mm"
        ]
    );
}

#[test]
fn the_board_and_client_sections_are_checked() {
    let e = errors("[schema.hand]\ndrive = { setpoint = 1, pose = 4, wrench = 6 }\n");
    assert!(
        e[0].contains("[schema.hand]: node `hand` is not defined (nodes: arm)"),
        "{e:?}"
    );
    let text = "[nodes.arm]\nid = 10\n[nodes.hand]\nid = 11\n[client]\nnode = \"hand\"\n";
    let e: Vec<String> = Network::parse(Source::new("net.toml", text))
        .unwrap_err()
        .0
        .iter()
        .map(|d| d.to_string())
        .collect();
    assert_eq!(
        e,
        [
            "net.toml:6:8: error: [client] node `hand` runs no schema server: add a [schema.hand] section"
        ]
    );
    let text = "[nodes.arm]\nid = 10\n[schema.arm]\nperiod_ms = 0\nforce_limit_n = -1\noverrun_ms = 0.5\nworkspace_mm = { min = [0, 0, 0], max = [1, -1, 1] }\ndrive = { setpoint = 0x7FE, pose = 0x310, wrench = 0x311 }\n";
    let e: Vec<String> = Network::parse(Source::new("net.toml", text))
        .unwrap_err()
        .0
        .iter()
        .map(|d| d.to_string())
        .collect();
    assert_eq!(
        e,
        [
            "net.toml:4:13: error: period_ms must be above 0 and at most 500000 ms",
            "net.toml:5:17: error: force_limit_n must be above 0 and at most 500000 N",
            "net.toml:6:14: error: overrun_ms must be at least period_ms",
            "net.toml:7:16: error: workspace_mm: min is above max on some axis",
            "net.toml:8:9: error: drive: schema server: a drive identifier: a standard (11-bit) output id is at most 0x7ff (the set-point takes 3 identifiers from its own, the pose and the wrench 2 each)",
        ]
    );
}

#[test]
fn safety_limits_and_joints_come_from_the_file_in_their_units() {
    let base = "[nodes.arm]\nid = 10\n[schema.arm]\ndrive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }\n";
    let text = format!(
        "{base}speed_limit_mm_s = 250\nrate_limit_rad_s = 0.5\ncontact_limit_n = 4\n\
         [schema.arm.sensors.gap]\ncan_id = 0x330\nvalue = {{ offset = 0, size = 2 }}\n\
         [schema.arm.sensors.elbow]\ncan_id = 0x331\nvalue = {{ offset = 0, size = 2, signed = true }}\n\
         scale = 0.1\nunit = \"deg\"\njoint = {{ min = -90.05, max = 120, speed = 45 }}\n"
    );
    let network = Network::parse(Source::new("net.toml", text)).unwrap();
    let limits = &network.schema_boards[0].config.limits;
    assert_eq!(
        (limits.speed_limit, limits.rate_limit, limits.contact_limit),
        (250_000, 500_000, 4_000)
    );
    // Sensor 1, in counts of 0.1 degree: the range rounded inwards, the speed down.
    assert_eq!(
        limits.joints.as_slice(),
        [pab_core::schema::Joint {
            sensor: 1,
            min: -900,
            max: 1200,
            rate: 450
        }]
    );
    // None by default.
    let network = Network::parse(Source::new("net.toml", base)).unwrap();
    let limits = &network.schema_boards[0].config.limits;
    assert_eq!(
        (
            limits.speed_limit,
            limits.rate_limit,
            limits.contact_limit,
            limits.joints.len()
        ),
        (0, 0, 0, 0)
    );
    // A range the sensor cannot read, crossed, and a speed below a count a second.
    let bad = |joint: &str| {
        let text = format!(
            "{base}[schema.arm.sensors.elbow]\ncan_id = 0x331\nvalue = {{ offset = 0, size = 1 }}\njoint = {joint}\n"
        );
        Network::parse(Source::new("net.toml", text))
            .unwrap_err()
            .0
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
    };
    assert_eq!(
        bad("{ min = -1, max = 10 }"),
        [
            "net.toml:8:17: error: sensor `elbow`: joint.min is outside what the sensor reads (0 to 255)"
        ]
    );
    assert_eq!(
        bad("{ min = 10, max = 5 }"),
        [
            "net.toml:8:9: error: sensor `elbow`: joint.min is above joint.max (in whole counts of the sensor)"
        ]
    );
    assert_eq!(
        bad("{ min = 0, max = 5, speed = 0.5 }"),
        [
            "net.toml:8:37: error: sensor `elbow`: joint.speed is at least one count a second (1 a second)"
        ]
    );
}

#[test]
fn the_drives_limits_come_from_the_file_in_its_units() {
    let base = "[nodes.arm]\nid = 10\n[schema.arm]\ndrive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }\n";
    let network = Network::parse(Source::new(
        "net.toml",
        format!("{base}drive_speed_mm_s = 250\ndrive_rate_rad_s = 1.5\npose_noise_mm = 0.2\n"),
    ))
    .unwrap();
    let config = &network.schema_boards[0].config;
    assert_eq!(
        (config.drive_speed, config.drive_rate, config.pose_noise),
        (250_000, 1_500_000, 200)
    );
    // The defaults: 2 m/s, 2π rad/s, 1 mm.
    let config = &Network::parse(Source::new("net.toml", base))
        .unwrap()
        .schema_boards[0]
        .config;
    assert_eq!(
        (config.drive_speed, config.drive_rate, config.pose_noise),
        (2_000_000, 6_283_185, 1000)
    );
    let e: Vec<String> = Network::parse(Source::new(
        "net.toml",
        format!("{base}drive_speed_mm_s = 0\npose_noise_mm = -1\n"),
    ))
    .unwrap_err()
    .0
    .iter()
    .map(|d| d.to_string())
    .collect();
    assert_eq!(
        e,
        [
            "net.toml:5:20: error: drive_speed_mm_s must be above 0 and at most 500000 mm/s",
            "net.toml:6:17: error: pose_noise_mm must be 0 and at most 500000 mm",
        ]
    );
}
