//! The `pabctl` binary as a user runs it: exit statuses, messages, files written or not.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

fn pabctl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(args)
        .output()
        .expect("pabctl runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn example(name: &str) -> String {
    examples().join(name).display().to_string()
}

/// Take and Return with Table I's rule for C1 instead of Table III's: inconsistent.
fn inconsistent_variant(dir: &Path) -> String {
    let text = std::fs::read_to_string(examples().join("take-and-return.toml")).unwrap();
    let variant = text.replace("rule = \"(C1 & !C2) & !C13\"", "rule = \"C1 & !C2\"");
    assert_ne!(text, variant);
    let path = dir.join("variant.toml");
    std::fs::write(&path, variant).unwrap();
    path.display().to_string()
}

#[test]
fn check_exits_0_on_a_consistent_network() {
    let output = pabctl(&["check", &example("take-and-return.toml")]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    assert!(
        stdout.contains("arm.target (node arm): 6 connections, 64 activity masks"),
        "{stdout}"
    );
    assert!(
        stdout.contains("consistent (3 ports, 16 connections)"),
        "{stdout}"
    );
}

#[test]
fn check_prints_every_streams_response_time_and_the_lowest_bit_rate() {
    let output = pabctl(&["check", &example("take-and-return.toml")]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    for expected in [
        "bus at 500 kbit/s: 23 streams analysed",
        "stream                      id          bytes       period     deadline          C            R        slack",
        "  object_pos                  0x110           8       100 ms       100 ms   0.270 ms     0.590 ms    99.410 ms",
        "  gaze: Heartbeat             0x1202FF03      8          1 s          1 s   0.320 ms",
        "bus load: 2.8 % of 500 kbit/s",
        "lowest standard bit rate at which every deadline holds: 20 kbit/s",
    ] {
        assert!(stdout.contains(expected), "{expected}\n{stdout}");
    }
    let json = pabctl(&["check", &example("take-and-return.toml"), "--json"]);
    assert_eq!(json.status.code(), Some(0));
    let value: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    let bus = &value["bus"];
    assert_eq!(bus["bitrate"], 500_000);
    assert_eq!(bus["holds"], true);
    assert_eq!(bus["lowest_bitrate"], 20_000);
    let first = &bus["streams"][0];
    assert_eq!(first["name"], "object_pos");
    assert_eq!(first["kind"], "topic");
    assert_eq!(first["id"], 0x110);
    assert_eq!(first["r_s"], 0.00059);
    assert_eq!(bus["streams"].as_array().unwrap().len(), 23);
    // A network without a bit rate: no table, `bus` null.
    let json = pabctl(&["check", &example("figure-1.toml"), "--json"]);
    let value: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(value["bus"], serde_json::Value::Null);
}

#[test]
fn check_exits_1_when_a_frame_can_miss_its_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let text_of = std::fs::read_to_string(examples().join("take-and-return.toml")).unwrap();
    // grasped ten times a millisecond: the bus is overloaded.
    let variant = text_of.replace(
        "can_id = 0x130\nperiod = 0.1\n",
        "can_id = 0x130\nperiod = 0.0001\n",
    );
    assert_ne!(text_of, variant);
    let path = dir.path().join("overloaded.toml");
    std::fs::write(&path, &variant).unwrap();
    let output = pabctl(&["check", &path.display().to_string()]);
    assert_eq!(output.status.code(), Some(1));
    let stderr = text(&output.stderr);
    let line = |needle: &str| variant.lines().position(|l| l == needle).unwrap() + 1;
    let file = path.display().to_string();
    assert!(
        stderr.contains(&format!(
            "{file}:{}:11: error: the bus is loaded",
            line("bitrate = 500000")
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!(
            "{file}:{}:10: error: `grasped` (0x130) can miss its deadline at 500 kbit/s",
            line("period = 0.0001")
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains("frames can miss their deadlines on the bus:"),
        "{stderr}"
    );
    // The rules are still consistent: said, and the table shows the misses.
    let stdout = text(&output.stdout);
    assert!(
        stdout.contains("consistent (3 ports, 16 connections)"),
        "{stdout}"
    );
    assert!(stdout.contains("MISSED"), "{stdout}");
    assert!(
        stdout.contains("no standard bit rate up to 1 Mbit/s meets every deadline"),
        "{stdout}"
    );
    let json = pabctl(&["check", &path.display().to_string(), "--json"]);
    assert_eq!(json.status.code(), Some(1));
    let value: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(value["bus"]["holds"], false);
    assert_eq!(value["bus"]["errors"][0]["line"], line("bitrate = 500000"));
}

#[test]
fn check_analyses_the_bus_at_the_bit_rate_given_on_the_command_line() {
    let network = examples()
        .join("take-and-return.toml")
        .display()
        .to_string();
    // Take and Return holds from 20 kbit/s: at 1 Mbit/s too, each frame's C an eighth of it.
    let fast = pabctl(&["check", &network, "--bitrate", "1000000"]);
    assert_eq!(fast.status.code(), Some(0), "{}", text(&fast.stderr));
    let stdout = text(&fast.stdout);
    assert!(stdout.contains("bus at 1 Mbit/s: 23 streams"), "{stdout}");
    assert!(
        stdout.contains("lowest standard bit rate at which every deadline holds: 20 kbit/s"),
        "{stdout}"
    );
    // At 10 kbit/s the periodic streams need 142 % of the bus: the streams that cannot keep
    // up fail the check at their lines, at the rate given (not at the file's [bus] line, which
    // says 500 kbit/s).
    let slow = pabctl(&["check", &network, "--bitrate", "10000"]);
    assert_eq!(slow.status.code(), Some(1));
    let stderr = text(&slow.stderr);
    assert!(
        stderr.contains("error: `grasped` (0x130) can miss its deadline at 10 kbit/s"),
        "{stderr}"
    );
    assert!(!stderr.contains("the bus is loaded"), "{stderr}");
    assert!(text(&slow.stdout).contains("bus load: 142.1 % of 10 kbit/s"));
    // Out of range: refused by the command line, before the file is read.
    let refused = pabctl(&["check", &network, "--bitrate", "2000000"]);
    assert_eq!(refused.status.code(), Some(2));
}

#[test]
fn check_analyses_a_can_fd_bus_with_its_data_phase() {
    let network = example("take-and-return-fd.toml");
    let output = pabctl(&["check", &network]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    for expected in [
        "bus at 500 kbit/s, data phase 2 Mbit/s (CAN FD with bit-rate switching): 25 streams analysed",
        "  stream                      id          bytes  frame         period     deadline          C            R        slack",
        "  hand_skin                   0x141          48  FD BRS         20 ms         5 ms   0.324 ms     3.180 ms     1.820 ms",
        "  object_pos                  0x110           8  classic       100 ms       100 ms   0.270 ms     0.722 ms",
        "  background: table transfer (one at a time, ISO-TP on CAN FD: 64-byte frames) (0x1A110100)",
        "lowest standard bit rate at which every deadline holds: 500 kbit/s (data phase at 2 Mbit/s)",
    ] {
        assert!(stdout.contains(expected), "{expected}\n{stdout}");
    }
    let json = pabctl(&["check", &network, "--json"]);
    assert_eq!(json.status.code(), Some(0));
    let value: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    let bus = &value["bus"];
    assert_eq!(
        (&bus["bitrate"], &bus["data_bitrate"]),
        (&500_000.into(), &2_000_000.into())
    );
    let skin = bus["streams"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "hand_skin")
        .unwrap();
    assert_eq!(
        (&skin["fd"], &skin["bytes"], &skin["c_s"]),
        (&true.into(), &48.into(), &0.000324.into())
    );
    assert_eq!(bus["streams"][0]["fd"], false);
    assert_eq!(bus["background"][0]["fd"], true);
    assert_eq!(bus["background"][0]["bytes"], 64);
    // A classic bus: `data_bitrate` null, every stream classic.
    let classic = pabctl(&["check", &example("take-and-return.toml"), "--json"]);
    let value: serde_json::Value = serde_json::from_slice(&classic.stdout).unwrap();
    assert_eq!(value["bus"]["data_bitrate"], serde_json::Value::Null);
    assert_eq!(value["bus"]["streams"][0]["fd"], false);
    // --data-bitrate: the data phase at another rate, which only the CAN FD frames' C follows
    // (64 µs nominal, 104 µs of data at 5 Mbit/s).
    let fast = pabctl(&["check", &network, "--data-bitrate", "5000000"]);
    assert_eq!(fast.status.code(), Some(0), "{}", text(&fast.stderr));
    let stdout = text(&fast.stdout);
    assert!(
        stdout.contains("bus at 500 kbit/s, data phase 5 Mbit/s"),
        "{stdout}"
    );
    assert!(stdout.contains("  hand_skin                   0x141          48  FD BRS         20 ms         5 ms   0.168 ms"), "{stdout}");
    // Refused: a classic network (the file says whether its bus is CAN FD), a data phase below
    // the nominal rate, above 8 Mbit/s.
    let classic = pabctl(&[
        "check",
        &example("take-and-return.toml"),
        "--data-bitrate",
        "2000000",
    ]);
    assert_eq!(classic.status.code(), Some(2));
    assert!(
        text(&classic.stderr).contains(
            "--data-bitrate 2000000: the network's bus is classic CAN (no `data_bitrate` in [bus])"
        ),
        "{}",
        text(&classic.stderr)
    );
    let slow = pabctl(&[
        "check",
        &network,
        "--bitrate",
        "1000000",
        "--data-bitrate",
        "800000",
    ]);
    assert_eq!(slow.status.code(), Some(2));
    assert!(
        text(&slow.stderr).contains("--data-bitrate 800000: below the nominal bit rate 1000000")
    );
    let refused = pabctl(&["check", &network, "--data-bitrate", "10000000"]);
    assert_eq!(refused.status.code(), Some(2));
}

#[test]
fn check_exits_1_when_a_can_fd_frame_can_miss_its_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let original = std::fs::read_to_string(examples().join("take-and-return-fd.toml")).unwrap();
    // The tactile array wanted within 2 ms: its frames wait for the eight classic topics above it.
    let variant = original.replace("deadline = 0.005", "deadline = 0.002");
    assert_ne!(original, variant);
    let path = dir.path().join("late.toml");
    std::fs::write(&path, &variant).unwrap();
    let output = pabctl(&["check", &path.display().to_string()]);
    assert_eq!(output.status.code(), Some(1));
    let line = variant
        .lines()
        .position(|l| l.starts_with("deadline = 0.002"))
        .unwrap()
        + 1;
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains(&format!(
            "{}:{line}:12: error: `hand_skin` (0x141) can miss its deadline at 500 kbit/s (data phase 2 Mbit/s): worst-case response time 3.180 ms > deadline 2 ms (every deadline holds from 1 Mbit/s with the data phase at 2 Mbit/s)",
            path.display()
        )),
        "{stderr}"
    );
    assert!(text(&output.stdout).contains("MISSED"));
    // With the data phase at 8 Mbit/s it still misses: the classic frames above it are the cost.
    let fast = pabctl(&[
        "check",
        &path.display().to_string(),
        "--data-bitrate",
        "8000000",
    ]);
    assert_eq!(fast.status.code(), Some(1));
}

#[test]
fn check_exits_1_with_the_counterexample_and_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = inconsistent_variant(dir.path());
    let output = pabctl(&["check", &path]);
    assert_eq!(output.status.code(), Some(1));
    let stderr = text(&output.stderr);
    let line = std::fs::read_to_string(&path)
        .unwrap()
        .lines()
        .position(|l| l.contains("rule = \"(C6 & !C7) & C13\""))
        .unwrap()
        + 1;
    assert!(
        stderr.contains(&format!(
            "{path}:{line}:8: error: port `arm.target`: C1 (rule \"C1 & !C2\") and C6"
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains("{C1, C6, C13} and no other (mask 0x00000015"),
        "{stderr}"
    );
    assert!(
        stderr.contains("the rules are inconsistent: 1 error"),
        "{stderr}"
    );
}

#[test]
fn check_warns_about_dynamics_that_cannot_work_and_still_exits_0() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("weak.toml");
    let network = std::fs::read_to_string(examples().join("door-dynamics.toml"))
        .unwrap()
        .replace("gamma = 3.0", "gamma = 1.0");
    std::fs::write(&path, &network).unwrap();
    let path = path.display().to_string();
    let output = pabctl(&["check", &path]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stderr = text(&output.stderr);
    let line = network
        .lines()
        .position(|l| l.starts_with("excludes = [\"recognise\", \"approach\"]"))
        .unwrap()
        + 1;
    assert!(
        stderr.contains(&format!(
            "{path}:{line}:13: warning: dynamics group `door`: `search` excludes `recognise` with γ = 1 (the group's `gamma`), below 1.5"
        )),
        "{stderr}"
    );
    assert!(stderr.ends_with("3 warnings\n"), "{stderr}");
    // Five ports: three contexts, the wheels and the gaze; six connections and three gates.
    assert!(text(&output.stdout).contains(": consistent (5 ports, 9 connections)"));
    // The example as written: no warning.
    let output = pabctl(&["check", &example("door-dynamics.toml")]);
    assert_eq!(output.status.code(), Some(0));
    assert_eq!(text(&output.stderr), "");
}

#[test]
fn check_exits_2_on_unreadable_or_invalid_input() {
    let output = pabctl(&["check", "/nonexistent/net.toml"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).starts_with("/nonexistent/net.toml: error: cannot read"));

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(
        &path,
        "[nodes.arm]\nid = 1\n[ports.\"arm.target\"]\n[connections.C1]\ntopic = \"x\"\n",
    )
    .unwrap();
    let output = pabctl(&["check", path.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains("bad.toml:4:1: error: missing field `port`"),
        "{stderr}"
    );
}

#[test]
fn compile_writes_one_image_per_node_and_prints_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tables");
    let output = pabctl(&[
        "compile",
        &example("take-and-return.toml"),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    for (node, id) in [("arm", 1), ("hand", 2), ("gaze", 3)] {
        let file = out.join(format!("{node}.pab"));
        let bytes = std::fs::read(&file).unwrap();
        assert_eq!(&bytes[..4], b"PABT");
        assert_eq!(bytes[6], id);
        assert!(
            stdout.contains(&format!(
                "{}  {} bytes  (node id {id}",
                file.display(),
                bytes.len()
            )),
            "{stdout}"
        );
    }
    // Take and Return uses no mechanism: any board build loads its tables (docs/footprint.md).
    assert_eq!(
        stdout
            .matches("decision nodes; needs no mechanism: any build)")
            .count(),
        3,
        "{stdout}"
    );
    assert!(!out.join("arm.pab.part").exists());
    // No [hbba]: no intention node to set up.
    assert!(!out.join("intention.json").exists());
}

#[test]
fn compile_writes_the_intention_nodes_setup_for_a_network_with_hbba() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tables");
    let output = pabctl(&[
        "compile",
        &example("tour-guide.toml"),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let file = out.join("intention.json");
    let setup = std::fs::read_to_string(&file).unwrap();
    let network =
        pab_lang::network::Network::load(std::path::Path::new(&example("tour-guide.toml")))
            .unwrap();
    // What pab-intent reads back is what the simulator runs the intention node on.
    assert_eq!(
        pab_intent::Setup::from_json(&setup).unwrap(),
        pab_lang::compile::intention_setup(&network).unwrap()
    );
    let stdout = text(&output.stdout);
    assert!(
        stdout.contains(&format!(
            "{}  {} bytes  (HBBA's intention node: 6 strategies, 5 filtered connections; pab-intent --setup {})",
            file.display(),
            setup.len(),
            file.display()
        )),
        "{stdout}"
    );
    // The boards' tables have filters: a board built without `filters` refuses them.
    assert_eq!(stdout.matches("; needs filters)").count(), 2, "{stdout}");
}

#[test]
fn compile_writes_nothing_for_an_inconsistent_network() {
    let dir = tempfile::tempdir().unwrap();
    let path = inconsistent_variant(dir.path());
    let out = dir.path().join("tables");
    let output = pabctl(&["compile", &path, "-o", out.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(1));
    assert!(!out.exists());
}

#[test]
fn compile_takes_the_table_version_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let output = pabctl(&[
        "compile",
        &example("figure-1.toml"),
        "-o",
        dir.path().to_str().unwrap(),
        "--table-version",
        "42",
    ]);
    assert_eq!(output.status.code(), Some(0));
    let bytes = std::fs::read(dir.path().join("gaze.pab")).unwrap();
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 42);
}

#[test]
fn sim_prints_timelines_and_writes_trace_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("trace.csv");
    let plot = dir.path().join("plot.png");
    let output = pabctl(&[
        "sim",
        &example("figure-1.toml"),
        "--trace",
        trace.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    assert!(
        stdout.contains("       6.500000  C2 (object_pos)"),
        "{stdout}"
    );
    let csv = std::fs::read_to_string(&trace).unwrap();
    assert!(csv.starts_with(
        "t,port,connection,stimulation,active,delivered\n0.000000,gaze.target,C1,0.2000,0,0\n"
    ));
    let png = std::fs::read(&plot).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
}

#[test]
fn sim_until_stops_early_and_rejects_nonsense() {
    let output = pabctl(&["sim", &example("figure-1.toml"), "--until", "5"]);
    assert_eq!(output.status.code(), Some(0));
    let stdout = text(&output.stdout);
    assert!(stdout.contains("until t = 5.000000 s"), "{stdout}");
    assert!(!stdout.contains("6.500000"), "{stdout}");
    let output = pabctl(&["sim", &example("figure-1.toml"), "--until", "-1"]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains("invalid value '-1' for '--until <SECONDS>': must be positive"),
        "{stderr}"
    );
}

#[test]
fn unwritable_outputs_exit_3() {
    let output = pabctl(&[
        "sim",
        &example("figure-1.toml"),
        "--trace",
        "/proc/forbidden/trace.csv",
    ]);
    assert_eq!(output.status.code(), Some(3));
    assert!(text(&output.stderr).contains("cannot write /proc/forbidden/trace.csv"));
}

/// `pabctl schema` is the command that regenerates docs/network-file.schema.json: it prints the
/// committed file byte for byte (lang/tests/json_schema.rs checks that file against the parser).
#[test]
fn schema_prints_the_committed_json_schema() {
    let output = pabctl(&["schema"]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let committed = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/network-file.schema.json"),
    )
    .expect("docs/network-file.schema.json");
    assert!(
        text(&output.stdout) == committed,
        "pabctl schema differs from docs/network-file.schema.json: regenerate it with \
         `cargo run -q -p pabctl -- schema > docs/network-file.schema.json`"
    );
    assert!(output.stderr.is_empty(), "{}", text(&output.stderr));
}

#[test]
fn help_explains_the_concepts() {
    let output = pabctl(&["--help"]);
    assert_eq!(output.status.code(), Some(0));
    let help = text(&output.stdout);
    for needle in [
        "stimulation",
        "active",
        "rule",
        "virtual",
        "[connections.NAME]",
        "Exit status",
    ] {
        assert!(help.contains(needle), "--help lacks {needle}");
    }
    let output = pabctl(&["sim", "--help"]);
    assert!(text(&output.stdout).contains("t,port,connection,stimulation,active,delivered"));
}

#[test]
fn compile_writes_a_port_consumer_and_refuses_a_bad_one() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tables");
    let output = pabctl(&[
        "compile",
        &example("figure-1.toml"),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let bytes = std::fs::read(out.join("gaze.pab")).unwrap();
    let loaded: pab_core::image::Loaded = pab_core::image::load(&bytes).unwrap();
    let port = loaded.table.port(0).unwrap();
    assert_eq!(
        port.consumer,
        pab_core::Consumer::Republish(pab_core::OutputId::new(0x300, false).unwrap())
    );

    let source = std::fs::read_to_string(examples().join("figure-1.toml")).unwrap();
    let line = source
        .lines()
        .position(|l| l.starts_with("republish = "))
        .unwrap()
        + 1;
    let bad = source.replace(
        "republish = { can_id = 0x300 }",
        "republish = { can_id = 0x1234 }",
    );
    assert_ne!(bad, source);
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, bad).unwrap();
    let bad_out = dir.path().join("bad-tables");
    let output = pabctl(&[
        "compile",
        path.to_str().unwrap(),
        "-o",
        bad_out.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains(&format!(
            "bad.toml:{line}:24: error: republish can_id 0x1234 does not fit a standard (11-bit) id"
        )),
        "{stderr}"
    );
    assert!(!bad_out.join("gaze.pab").exists());
}

#[test]
fn dbc_writes_the_protocol_and_topic_messages() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sub/take-and-return.dbc");
    let output = pabctl(&[
        "dbc",
        &example("take-and-return.toml"),
        "-o",
        &path.display().to_string(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    assert!(
        text(&output.stdout).contains("112 messages"),
        "{}",
        text(&output.stdout)
    );
    let dbc = std::fs::read_to_string(&path).unwrap();
    assert!(dbc.starts_with("VERSION \"\""), "{dbc}");
    assert!(dbc.contains("BU_: PABCTL arm hand gaze\n"), "{dbc}");
    // Heartbeat of gaze (node 3): 0x1202FF03 with the extended flag.
    let heartbeat = pab_core::protocol::FrameId::new(
        pab_core::protocol::Service::Heartbeat,
        3,
        pab_core::protocol::BROADCAST,
    )
    .raw();
    assert!(
        dbc.contains(&format!(
            "BO_ {} PAB_Heartbeat_gaze: 8 gaze\n",
            heartbeat | 0x8000_0000
        )),
        "{dbc}"
    );
    assert!(dbc.contains("BO_ 272 object_pos: 8 Vector__XXX\n"), "{dbc}");
    // Diagnostic control from the tool to all: 0x0E10FF00, 4 bytes.
    assert!(
        dbc.contains("BO_ 2383478528 PAB_DiagnosticControl_all: 4 PABCTL\n"),
        "{dbc}"
    );
    // The tool's table transfer to gaze: ISO-TP frames, padded to 8 bytes.
    let transfer = pab_core::protocol::FrameId::new(
        pab_core::protocol::Service::TableTransfer,
        pab_core::protocol::TOOL,
        3,
    )
    .raw();
    assert!(
        dbc.contains(&format!(
            "BO_ {} PAB_TableTransfer_gaze: 8 PABCTL\n",
            transfer | 0x8000_0000
        )),
        "{dbc}"
    );
    // gaze.target re-publishes on 0x201 (513).
    assert!(dbc.contains("BO_ 513 gaze_target_out: 8 gaze\n"), "{dbc}");
    assert!(!dir.path().join("sub/take-and-return.dbc.part").exists());

    let stdout = pabctl(&["dbc", &example("take-and-return.toml"), "-o", "-"]);
    assert_eq!(stdout.status.code(), Some(0));
    assert_eq!(text(&stdout.stdout), dbc);
}

#[test]
fn dbc_exit_statuses() {
    let dir = tempfile::tempdir().unwrap();
    // Invalid input: 2, with file:line:col.
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[nodes.arm]\nid = 1\n[topics.ours]\ncan_id = 0x1202FF03\nextended = true\n",
    )
    .unwrap();
    let output = pabctl(&[
        "dbc",
        &bad.display().to_string(),
        "-o",
        &dir.path().join("x.dbc").display().to_string(),
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains(&format!("{}:3:1: error: topic `ours`", bad.display())),
        "{stderr}"
    );
    assert!(!dir.path().join("x.dbc").exists());
    // Unwritable output: 3.
    let output = pabctl(&[
        "dbc",
        &example("figure-1.toml"),
        "-o",
        &dir.path().join("bad.toml/x.dbc").display().to_string(),
    ]);
    assert_eq!(output.status.code(), Some(3), "{}", text(&output.stderr));
    // Help explains the conventions.
    let help = pabctl(&["dbc", "--help"]);
    let help = text(&help.stdout);
    assert!(help.contains("PAB_<Service>_<node>"), "{help}");
    assert!(help.contains("dataN"), "{help}");
    assert!(help.contains("--claims-from"), "{help}");
}

#[test]
fn dbc_lists_the_claims_of_a_capture_and_refuses_frames_that_are_not_claims_of_members() {
    let dir = tempfile::tempdir().unwrap();
    let network = example("multi-target-observation.toml");
    let log = dir.path().join("bus.log");
    let sim = pabctl(&["sim", &network, "--candump", log.to_str().unwrap()]);
    assert_eq!(sim.status.code(), Some(0), "{}", text(&sim.stderr));
    let dbc = dir.path().join("net.dbc");
    let written = |claims: Option<&std::path::Path>| {
        let mut args = vec![
            "dbc".to_string(),
            network.clone(),
            "-o".to_string(),
            dbc.display().to_string(),
        ];
        if let Some(capture) = claims {
            args.extend(["--claims-from".to_string(), capture.display().to_string()]);
        }
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        pabctl(&refs)
    };
    let output = written(None);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let without = std::fs::read_to_string(&dbc).unwrap();
    let output = written(Some(&log));
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let with = std::fs::read_to_string(&dbc).unwrap();
    // Every claim identifier of the capture is a message of the second database only.
    let claims: std::collections::BTreeSet<u32> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .filter_map(|line| line.split_whitespace().nth(2)?.split_once('#'))
        .filter_map(|(id, _)| u32::from_str_radix(id, 16).ok())
        .filter(|&id| pab_core::ble::is_claim_id(id))
        .collect();
    assert!(claims.len() > 3, "{claims:?}");
    for id in &claims {
        let declared = format!("BO_ {} PAB_Claim_", id | 0x8000_0000);
        assert!(with.contains(&declared), "{declared}");
    }
    assert!(
        claims
            .iter()
            .any(|id| !without.contains(&format!("BO_ {} ", id | 0x8000_0000)))
    );
    // A claim from node 99, in no group, on line 2: exit 2, the line named, nothing written.
    let bad = dir.path().join("bad.log");
    std::fs::write(
        &bad,
        "(0.000000) vcan0 110#0000000000000000\n(0.100000) vcan0 12FFFFE3#01000000\n",
    )
    .unwrap();
    std::fs::remove_file(&dbc).unwrap();
    let output = written(Some(&bad));
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains(&format!(
            "{}:2:1: error: a BLE claim from node id 99, which is in no BLE group",
            bad.display()
        )),
        "{stderr}"
    );
    assert!(!dbc.exists());
}

#[test]
fn bus_commands_name_a_missing_interface_and_exit_4() {
    let figure = example("figure-1.toml");
    for args in [
        vec!["push", &figure, "--iface", "pabnosuch0"],
        vec!["nodes", "--iface", "pabnosuch0"],
        vec![
            "monitor",
            &figure,
            "--iface",
            "pabnosuch0",
            "--duration",
            "1",
        ],
    ] {
        let output = pabctl(&args);
        assert_eq!(output.status.code(), Some(4), "{args:?}");
        let stderr = text(&output.stderr);
        assert!(
            stderr.contains("cannot open CAN interface \"pabnosuch0\""),
            "{stderr}"
        );
        assert!(stderr.contains("type vcan"), "{stderr}");
    }
}

#[test]
fn push_to_an_unknown_node_name_lists_the_nodes() {
    let output = pabctl(&[
        "push",
        &example("take-and-return.toml"),
        "--iface",
        "pabnosuch0",
        "--node",
        "elbow",
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains("no node named \"elbow\" (nodes: arm, hand, gaze)"),
        "{stderr}"
    );
}

/// Figure 1 with C1's rule (line 34, text from column 9) replaced by `rule`.
fn figure_one_with_rule(dir: &Path, rule: &str) -> String {
    let text = std::fs::read_to_string(examples().join("figure-1.toml")).unwrap();
    let variant = text.replace("rule = \"C1 & !C2\"", &format!("rule = \"{rule}\""));
    assert_ne!(text, variant);
    let path = dir.join("deep.toml");
    std::fs::write(&path, variant).unwrap();
    path.display().to_string()
}

#[test]
fn deeply_nested_rules_are_an_error_at_their_place_not_a_crash() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        // 20 000 nested parentheses: the 129th `(` is one level too many.
        (
            format!("{}C1{}", "(".repeat(20_000), ")".repeat(20_000)),
            9 + 128,
        ),
        // A chain of 100 000 `!`.
        (format!("{}C1", "!".repeat(100_000)), 9 + 128),
        // Both, mixed, starting after some text.
        (format!("C1 & {}C2", "!(".repeat(50_000)), 9 + 5 + 128),
    ];
    for (rule, column) in cases {
        let path = figure_one_with_rule(dir.path(), &rule);
        for command in [
            &["check", &path][..],
            &["sim", &path],
            &["dbc", &path, "-o", "-"],
        ] {
            let output = pabctl(command);
            let stderr = text(&output.stderr);
            assert_eq!(output.status.code(), Some(2), "{command:?}: {stderr}");
            assert!(
                stderr.starts_with(&format!("{path}:34:{column}: error: in rule \"")),
                "{command:?}: {stderr}"
            );
            assert!(
                stderr.contains("nested more than 128 levels deep"),
                "{stderr}"
            );
            // The rule is shown shortened, not 100 000 characters long.
            assert!(stderr.len() < 400, "{} bytes: {stderr}", stderr.len());
        }
    }
}

#[test]
fn long_flat_rules_are_checked_without_overflowing_the_stack() {
    let dir = tempfile::tempdir().unwrap();
    // 100 000 operands, left to right: no nesting at all, so no limit applies.
    let and_chain = vec!["C1"; 100_000].join(" & ") + " & !C2";
    let path = figure_one_with_rule(dir.path(), &and_chain);
    let output = pabctl(&["check", &path]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    assert!(text(&output.stdout).contains("consistent"));
    let out = dir.path().join("tables");
    let output = pabctl(&["compile", &path, "-o", out.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    // An inconsistent one: the overlap is reported at the rule, with the rule shortened.
    let or_chain = vec!["C1 & C2"; 100_000].join(" | ");
    let path = figure_one_with_rule(dir.path(), &or_chain);
    let output = pabctl(&["check", &path]);
    let stderr = text(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("C1 & C2 | C1 & C2"), "{stderr}");
    assert!(stderr.len() < 1_000, "{} bytes: {stderr}", stderr.len());
}

#[test]
fn deeply_nested_toml_is_an_error_not_a_crash() {
    let dir = tempfile::tempdir().unwrap();
    let original = std::fs::read_to_string(examples().join("figure-1.toml")).unwrap();
    for value in [
        format!("{}1{}", "[".repeat(100_000), "]".repeat(100_000)),
        format!("{}1{}", "{ a = ".repeat(100_000), " }".repeat(100_000)),
    ] {
        let variant = original.replace(
            "[nodes.gaze]\n",
            &format!("[nodes.gaze]\ndescription = {value}\n"),
        );
        let path = dir.path().join("deep.toml");
        std::fs::write(&path, variant).unwrap();
        let output = pabctl(&["check", path.to_str().unwrap()]);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.starts_with(&format!("{}:16:", path.display())),
            "{stderr}"
        );
        assert!(stderr.len() < 400, "{} bytes: {stderr}", stderr.len());
    }
}

#[test]
fn every_duration_rate_time_and_version_argument_is_checked() {
    let dir = tempfile::tempdir().unwrap();
    let net = example("take-and-return.toml");
    let out = dir.path().join("tables");
    let out = out.to_str().unwrap();
    let seconds = [
        ("-1", "must be positive"),
        ("-0.5", "must be positive"),
        ("0", "must be positive"),
        ("NaN", "is not a number"),
        ("inf", "must be at most"),
        ("-inf", "must be positive"),
        ("1e30", "must be at most"),
        ("ten", "is not a number"),
    ];
    let versions = [
        ("0", "version 0 is reserved"),
        ("-1", "must be positive"),
        ("4294967296", "must be at most 4294967295"),
        ("1.5", "is not a whole number"),
        ("NaN", "is not a whole number"),
    ];
    let rates = [
        ("-1", "must be positive"),
        ("0", "must be positive"),
        ("201", "must be at most 200"),
        ("1e30", "is not a whole number"),
        ("NaN", "is not a whole number"),
    ];
    let iface = "pabnosuch0";
    type Case<'a> = (Vec<&'a str>, &'a str, &'a [(&'a str, &'a str)]);
    let cases: Vec<Case> = vec![
        (
            vec!["compile", &net, "-o", out],
            "--table-version",
            &versions,
        ),
        (
            vec!["push", &net, "--iface", iface],
            "--table-version",
            &versions,
        ),
        (vec!["sim", &net], "--until", &seconds),
        (vec!["nodes", "--iface", iface], "--listen", &seconds),
        (
            vec!["monitor", &net, "--iface", iface],
            "--duration",
            &seconds,
        ),
        (vec!["monitor", &net, "--iface", iface], "--rate", &rates),
    ];
    for (command, option, values) in cases {
        for (value, message) in values {
            let mut args = command.clone();
            args.extend([option, value]);
            let output = pabctl(&args);
            let stderr = text(&output.stderr);
            assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(
                stderr.contains(option) && stderr.contains(message),
                "{args:?}: expected {message:?}: {stderr}"
            );
            assert!(
                !stderr.contains("unexpected argument"),
                "{args:?}: {stderr}"
            );
        }
    }
    assert!(!Path::new(out).exists(), "nothing compiled");
}

#[test]
fn table_version_0_in_the_file_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let original = std::fs::read_to_string(examples().join("take-and-return.toml")).unwrap();
    let variant = original.replace("version = 1", "version = 0");
    assert_ne!(original, variant);
    let line = variant
        .lines()
        .position(|l| l.starts_with("version = 0"))
        .unwrap()
        + 1;
    let path = dir.path().join("v0.toml");
    std::fs::write(&path, variant).unwrap();
    let path = path.display().to_string();
    let out = dir.path().join("tables");
    for args in [
        vec!["compile", &path, "-o", out.to_str().unwrap()],
        vec!["push", &path, "--iface", "pabnosuch0"],
    ] {
        let output = pabctl(&args);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.starts_with(&format!(
                "{path}:{line}:11: error: table version 0 is reserved"
            )),
            "{stderr}"
        );
    }
    assert!(!out.exists());
}

#[test]
fn names_with_control_characters_are_refused_and_shown_escaped() {
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(examples().join("figure-1.toml")).unwrap();
    let cases = [
        // A node name with an ANSI escape (TOML `\u001b` in a quoted key).
        (
            base.replace("[nodes.gaze]", "[nodes.\"gaze\\u001b[31m\"]"),
            "node name `gaze\\u{1b}[31m` holds a control character",
        ),
        // A topic name with a newline.
        (
            base.replace("[topics.face_pos]", "[topics.\"face\\npos\"]"),
            "topic name `face\\npos` holds a control character",
        ),
        // A port name whose node part carries an escape.
        (
            base.replace(
                "[ports.\"gaze.target\"]",
                "[ports.\"gaze\\u001b[2J.target\"]",
            ),
            "port name `gaze\\u{1b}[2J.target` holds a control character",
        ),
        // A connection name with a carriage return.
        (
            base.replace("[connections.C2]", "[connections.\"C2\\r\"]"),
            "connection name `C2\\r` holds a control character",
        ),
        // A reference to a topic with an escape in it.
        (
            base.replace(
                "topic = \"face_pos\"\nport",
                "topic = \"face_pos\\u001b[0m\"\nport",
            ),
            "topic `face_pos\\u{1b}[0m` is not defined",
        ),
        // A phase name.
        (
            format!("{base}\n[[phases]]\nname = \"A\\u001b]0;pwned\\u0007\"\nfrom = 0\nto = 1\n"),
            "phase name `A\\u{1b}]0;pwned\\u{7}` holds a control character",
        ),
    ];
    for (text_of_file, message) in cases {
        let path = dir.path().join("names.toml");
        std::fs::write(&path, &text_of_file).unwrap();
        let output = pabctl(&["check", path.to_str().unwrap()]);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(message), "expected {message:?}: {stderr:?}");
        // No raw control character, and no message split over lines by one: every line is a
        // message, a line of the file shown under it (a gutter `NN |`), blank, or the count.
        let shown = path.display().to_string();
        let snippet = |line: &str| {
            let gutter = line
                .trim_start()
                .trim_start_matches(|c: char| c.is_ascii_digit());
            gutter.starts_with(" |") || gutter.starts_with('|')
        };
        assert!(
            !stderr.contains(['\u{1b}', '\r', '\u{7}'])
                && stderr.lines().all(|line| line.starts_with(&shown)
                    || snippet(line)
                    || line.is_empty()
                    || line.ends_with(" errors")),
            "raw control characters on stderr: {stderr:?}"
        );
    }
}

#[test]
fn a_reader_that_stops_early_ends_pabctl_quietly_not_with_a_panic() {
    // `pabctl sim NET.toml --trace /dev/stdout | head -1`: the first line is read, the pipe
    // closed. pabctl must end as any Unix tool does (SIGPIPE), not panic on its next write. The
    // trace (100 000 rows, megabytes) cannot fit the pipe's buffer, so the write after the close
    // is certain.
    use std::io::{BufRead, BufReader};
    use std::os::unix::process::ExitStatusExt;
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let network = dir.path().join("busy.toml");
    std::fs::write(
        &network,
        "[nodes.n]\nid = 1\n[topics.t]\ncan_id = 0x100\n[ports.\"n.p\"]\n\
         [connections.C1]\ntopic = \"t\"\nport = \"n.p\"\nst = 0.5\ntc = 1.0\n\
         [[events]]\ntopic = \"t\"\nrate_hz = 1000.0\nto = 100.0\n",
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(["sim", network.to_str().unwrap(), "--trace", "/dev/stdout"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("pabctl runs");
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    // The reader is dropped here: the pipe is closed.
    let output = child.wait_with_output().unwrap();
    assert!(first.contains("100000 frames"), "{first}");
    let stderr = text(&output.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(output.status.signal(), Some(SIGPIPE), "{:?}", output.status);
}

/// SIGPIPE's number on Linux.
const SIGPIPE: i32 = 13;

#[test]
fn sim_writes_the_schema_servers_trace_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("assembly.csv");
    let png = dir.path().join("assembly.png");
    let output = pabctl(&[
        "sim",
        &example("assembly.toml"),
        "--schema-trace",
        csv.to_str().unwrap(),
        "--schema-plot",
        png.to_str().unwrap(),
        "--until",
        "17",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    assert!(
        stdout.contains("schema server on `arm`: 10 schemas installed"),
        "{stdout}"
    );
    assert!(stdout.contains("parts inserted: 1 of 6"), "{stdout}");
    let trace = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = trace.lines().collect();
    assert_eq!(lines[0], "t,node,schema,source,event");
    // The board is the node: its first tick runs as it boots, at 0, before the client's first
    // SchemaTransfer reaches it, so the first call is installed at the next tick, 1 ms later,
    // and everything after it follows 1 ms later too.
    assert_eq!(
        lines[1],
        "0.001000,arm,move_to(above_part_1),queue,queue-ready"
    );
    assert_eq!(
        lines[8],
        "16.140000,arm,release(),queue,below:displacement.z"
    );
    assert_eq!(lines.len(), 11);
    let png = std::fs::read(&png).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

#[test]
fn schema_trace_without_a_client_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("x.csv");
    let output = pabctl(&[
        "sim",
        &example("figure-1.toml"),
        "--schema-trace",
        csv.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output.stderr));
    assert!(
        text(&output.stderr).contains(
            "--schema-trace, --schema-plot and --schema-program need a schema server with a [client] in the file"
        ),
        "{}",
        text(&output.stderr)
    );
    assert!(!csv.exists());
}

#[test]
fn the_live_schema_verbs_check_the_file_before_the_bus() {
    // No [client]: an input error, before any bus is opened.
    for verb in ["plant", "run"] {
        let output = pabctl(&[verb, &example("figure-1.toml"), "--iface", "nosuch0"]);
        assert_eq!(
            output.status.code(),
            Some(2),
            "{verb}: {}",
            text(&output.stderr)
        );
        assert!(
            text(&output.stderr).contains("the file has no [client]"),
            "{}",
            text(&output.stderr)
        );
    }
    // A schema server's file on an interface that does not exist: a bus error.
    let output = pabctl(&["run", &example("assembly.toml"), "--iface", "nosuch0"]);
    assert_eq!(output.status.code(), Some(4), "{}", text(&output.stderr));
    assert!(
        text(&output.stderr).contains("cannot open CAN interface \"nosuch0\""),
        "{}",
        text(&output.stderr)
    );
}

#[test]
fn limits_are_checked_against_the_table_before_anything_is_sent() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("arm.toml");
    std::fs::write(
        &path,
        "[nodes.arm]\nid = 10\n[schema.arm]\nforce_limit_n = 30\nspeed_limit_mm_s = 250\n\
         drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }\n\
         [schema.arm.sensors.elbow]\ncan_id = 0x331\nvalue = { offset = 0, size = 2, signed = true }\n\
         scale = 0.1\nunit = \"deg\"\njoint = { min = -90, max = 120, speed = 45 }\n",
    )
    .unwrap();
    let net = path.display().to_string();
    let output = pabctl(&[
        "limits",
        &net,
        "--dry-run",
        "--force-limit-n",
        "10",
        "--workspace-max-mm",
        "100,100,50",
        "--joint",
        "elbow=-45:90:30",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    for line in [
        "arm: force limit 10 N",
        "arm: speed limit 250 mm/s",
        "arm: workspace [-1000, -1000, -1000] to [100, 100, 50] mm",
        "arm: joint elbow: -45 to 90 deg, speed 30 deg/s",
        "arm: within the table's limits (dry run: nothing sent)",
    ] {
        assert!(stdout.contains(line), "{line:?} in {stdout}");
    }
    // Every looser bound named at once, exit 2, nothing sent (no --iface needed to fail).
    let output = pabctl(&[
        "limits",
        &net,
        "--dry-run",
        "--force-limit-n",
        "40",
        "--speed-limit-mm-s",
        "0",
        "--workspace-min-mm",
        "-1300,0,0",
        "--joint",
        "elbow=-100:90",
        "--joint",
        "wrist=0:1",
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    for line in [
        "error: arm: --joint wrist: no such sensor (sensors: elbow)",
        "error: arm: force_limit_n: 40 N is looser than the table's 30 N (limits may only tighten)",
        "error: arm: speed_limit_mm_s: none is looser than the table's 250 mm/s",
        "error: arm: workspace x: a lowest -1300 mm is below the table's -1000 mm",
        "error: arm: joint elbow: a lowest -100 deg is below the table's -90 deg",
    ] {
        assert!(stderr.contains(line), "{line:?} in {stderr}");
    }
    assert!(text(&output.stdout).is_empty());
    // Without --dry-run, a bus is needed.
    let output = pabctl(&["limits", &net]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).contains("--iface"));
}

#[test]
fn init_writes_the_tutorials_network_which_check_accepts_and_never_overwrites() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("network.toml");
    let path = file.display().to_string();
    let written = pabctl(&["init", &path]);
    assert!(written.status.success(), "{}", text(&written.stderr));
    assert!(text(&written.stdout).contains("next: pabctl check"));
    let tutorial = std::fs::read_to_string(examples().join("first-network.toml")).unwrap();
    assert_eq!(std::fs::read_to_string(&file).unwrap(), tutorial);
    let checked = pabctl(&["check", &path]);
    assert_eq!(checked.status.code(), Some(0), "{}", text(&checked.stdout));

    // A second init leaves the file as it is, whatever it holds now.
    std::fs::write(&file, "# mine\n").unwrap();
    let again = pabctl(&["init", &path]);
    assert_eq!(again.status.code(), Some(3));
    assert!(
        text(&again.stderr).contains("already exists"),
        "{}",
        text(&again.stderr)
    );
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "# mine\n");
}

#[test]
fn init_with_an_example_writes_it_and_a_slip_of_its_name_gets_the_nearest() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("tour.toml");
    let path = file.display().to_string();
    let written = pabctl(&["init", &path, "--example", "tour-guide"]);
    assert!(written.status.success(), "{}", text(&written.stderr));
    assert_eq!(
        std::fs::read_to_string(&file).unwrap(),
        std::fs::read_to_string(examples().join("tour-guide.toml")).unwrap()
    );
    let other = dir.path().join("other.toml");
    let slip = pabctl(&[
        "init",
        &other.display().to_string(),
        "--example",
        "tour-guid",
    ]);
    assert_eq!(slip.status.code(), Some(2));
    assert!(
        text(&slip.stderr).contains("did you mean `tour-guide`?"),
        "{}",
        text(&slip.stderr)
    );
    assert!(!other.exists(), "nothing written for an unknown example");
}

fn json(output: &Output) -> serde_json::Value {
    serde_json::from_slice(&output.stdout).unwrap_or_else(|error| {
        panic!(
            "stdout is not one JSON value ({error}):\n{}",
            text(&output.stdout)
        )
    })
}

#[test]
fn check_json_gives_the_verdict_port_by_port_and_keeps_stdout_for_the_json() {
    let consistent = pabctl(&["check", &example("first-network.toml"), "--json"]);
    assert_eq!(consistent.status.code(), Some(0));
    let found = json(&consistent);
    assert_eq!(found["valid"], true);
    assert_eq!(found["consistent"], true);
    assert_eq!(found["errors"], serde_json::json!([]));
    let port = &found["ports"][0];
    assert_eq!(port["port"], "hand.command");
    assert_eq!(port["node"], "hand");
    assert_eq!(port["connections"], serde_json::json!(["GRASP", "RELEASE"]));
    assert_eq!(port["masks"], 4);
    assert_eq!(port["idle_masks"], 1);
    // The person's text went to standard error.
    assert!(text(&consistent.stderr).contains("consistent (1 port, 2 connections)"));

    let dir = tempfile::tempdir().unwrap();
    let variant = inconsistent_variant(dir.path());
    let inconsistent = pabctl(&["check", &variant, "--json"]);
    assert_eq!(inconsistent.status.code(), Some(1));
    let found = json(&inconsistent);
    assert_eq!(found["consistent"], false);
    let overlaps: Vec<&serde_json::Value> = found["ports"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|p| p["overlaps"].as_array().unwrap())
        .collect();
    assert!(!overlaps.is_empty(), "{found}");
    assert!(
        overlaps[0]["active"]
            .as_array()
            .is_some_and(|a| !a.is_empty())
    );
    let error = &found["errors"][0];
    assert!(
        error["line"].as_u64().is_some_and(|line| line > 0),
        "{error}"
    );
    assert!(
        error["message"]
            .as_str()
            .unwrap()
            .contains("can both deliver")
    );
}

#[test]
fn check_json_on_an_invalid_file_lists_its_errors_with_their_lines() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, "[nodes.a]\nidd = 1\n").unwrap();
    let output = pabctl(&["check", &file.display().to_string(), "--json"]);
    assert_eq!(output.status.code(), Some(2));
    let found = json(&output);
    assert_eq!(found["valid"], false);
    assert_eq!(found["errors"][0]["line"], 2);
    assert_eq!(found["errors"][0]["column"], 1);
    assert!(
        found["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("did you mean `id`?")
    );
}

#[test]
fn compile_json_lists_each_image_as_written() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tables");
    let output = pabctl(&[
        "compile",
        &example("take-and-return.toml"),
        "-o",
        &out.display().to_string(),
        "--json",
    ]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let found = json(&output);
    let images = found.as_array().unwrap();
    assert_eq!(images.len(), 3, "{found}");
    for image in images {
        let file = PathBuf::from(image["file"].as_str().unwrap());
        assert_eq!(
            std::fs::metadata(&file).unwrap().len(),
            image["bytes"].as_u64().unwrap(),
            "{image}"
        );
        assert_eq!(image["table_version"], 1);
        // The push's frames, counted through the core's ISO-TP: fewer in CAN FD, in less bus
        // time, at the network's 500 kbit/s and (no data rate on this classic bus) 2 Mbit/s.
        let push = &image["push"];
        assert_eq!(
            (push["bitrate"].as_u64(), push["data_bitrate"].as_u64()),
            (Some(500_000), Some(2_000_000))
        );
        let (classic, fd) = (&push["classic"], &push["fd"]);
        let bytes = image["bytes"].as_u64().unwrap();
        assert_eq!(
            classic["frames"].as_u64().unwrap(),
            1 + (bytes - 6).div_ceil(7),
            "{image}"
        );
        assert_eq!(
            fd["frames"].as_u64().unwrap(),
            1 + (bytes - 62).div_ceil(63),
            "{image}"
        );
        assert!(fd["seconds"].as_f64().unwrap() * 4.0 < classic["seconds"].as_f64().unwrap());
    }
    // The text says the same.
    let output = pabctl(&[
        "compile",
        &example("take-and-return.toml"),
        "-o",
        &out.display().to_string(),
    ]);
    let said = text(&output.stdout);
    assert!(
        said.contains("  push: 28 classic CAN frames + 4 flow controls, 9.00 ms of bus at 500 kbit/s; CAN FD: 4 frames + 1 flow control, 1.51 ms at 500 kbit/s / 2 Mbit/s\n"),
        "{said}"
    );
}

#[test]
fn sim_refuses_outputs_it_could_not_write_before_it_runs() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-such-dir").join("trace.csv");
    let pdf = dir.path().join("plot.pdf");
    let not_drawn = pabctl(&[
        "sim",
        &example("first-network.toml"),
        "--plot",
        &pdf.display().to_string(),
    ]);
    assert_eq!(not_drawn.status.code(), Some(2));
    let said = text(&not_drawn.stderr);
    assert!(
        said.contains(
            "--plot: plots are drawn as PNG or SVG: give a file name ending in .png or .svg"
        ),
        "{said}"
    );
    // Refused before the run: nothing simulated, nothing written.
    assert_eq!(text(&not_drawn.stdout), "");
    assert!(!pdf.exists());

    let no_dir = pabctl(&[
        "sim",
        &example("first-network.toml"),
        "--trace",
        &missing.display().to_string(),
    ]);
    assert_eq!(no_dir.status.code(), Some(3));
    let said = text(&no_dir.stderr);
    assert!(said.contains("(--trace): the directory"), "{said}");
    assert_eq!(text(&no_dir.stdout), "");

    let trace = dir.path().join("dynamics.csv");
    let nothing = pabctl(&[
        "sim",
        &example("first-network.toml"),
        "--dynamics-trace",
        &trace.display().to_string(),
    ]);
    assert_eq!(nothing.status.code(), Some(2));
    assert!(text(&nothing.stderr).contains("no [dynamics.*] group"));
    assert!(!trace.exists(), "no empty trace written");
}

#[test]
fn sim_json_gives_who_gets_through_when_and_each_connections_counts() {
    let output = pabctl(&["sim", &example("first-network.toml"), "--json"]);
    assert!(output.status.success(), "{}", text(&output.stderr));
    let found = json(&output);
    assert_eq!(found["nodes"], 1);
    let port = &found["ports"][0];
    assert_eq!(port["port"], "hand.command");
    let changes: Vec<(f64, Option<&str>)> = port["changes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["t_s"].as_f64().unwrap(), c["delivers"].as_str()))
        .collect();
    // The tutorial's story: the grasp, the release while pressed, the grasp again, nobody.
    let who: Vec<Option<&str>> = changes.iter().map(|c| c.1).collect();
    assert_eq!(
        who,
        [None, Some("GRASP"), Some("RELEASE"), Some("GRASP"), None],
        "{changes:?}"
    );
    let mut frames = 0;
    for connection in port["connections"].as_array().unwrap() {
        let n = connection["frames"].as_u64().unwrap();
        assert_eq!(
            connection["delivered"].as_u64().unwrap() + connection["discarded"].as_u64().unwrap(),
            n
        );
        frames += n;
    }
    assert_eq!(found["frames"].as_u64().unwrap(), frames);
    // The text went to standard error.
    assert!(text(&output.stderr).contains("63 frames on 1 node"));

    // A schema server's run: its text to standard error too, standard output stays JSON.
    let schema = pabctl(&["sim", &example("assembly.toml"), "--json"]);
    assert!(schema.status.success(), "{}", text(&schema.stderr));
    assert_eq!(json(&schema)["ports"], serde_json::json!([]));
}

/// The book's tables of `pabctl sim --timed-bus` (docs/response-times.md, "The simulator's timed
/// bus") are what the command prints today: each ```text block after the command that names it
/// is in its output, as it is.
#[test]
fn sim_timed_bus_prints_the_books_tables() {
    let book_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/response-times.md");
    let book = std::fs::read_to_string(&book_path).unwrap();
    for name in ["take-and-return.toml", "take-and-return-fd.toml"] {
        let command = format!("`pabctl sim examples/{name} --timed-bus");
        let at = book
            .find(&command)
            .unwrap_or_else(|| panic!("docs/response-times.md names no {command}"));
        let rest = &book[at..];
        let start = rest.find("```text\n").expect("a text block") + "```text\n".len();
        let block = &rest[start..start + rest[start..].find("```").expect("its end")];
        let output = pabctl(&["sim", &example(name), "--timed-bus"]);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
        let stdout = text(&output.stdout);
        assert!(
            stdout.contains(block),
            "docs/response-times.md's table for {name} is not what `pabctl sim --timed-bus` prints:\n{block}\n---\n{stdout}"
        );
    }
}

#[test]
fn sim_timed_bus_needs_a_bus_and_adds_its_json_only_when_asked() {
    let refused = pabctl(&["sim", &example("first-network.toml"), "--timed-bus"]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(
        text(&refused.stderr).contains("first-network.toml: error: --timed-bus: the network has no [bus], so no bit rate to time its frames at"),
        "{}",
        text(&refused.stderr)
    );
    let timed = pabctl(&[
        "sim",
        &example("take-and-return-fd.toml"),
        "--timed-bus",
        "--json",
    ]);
    assert_eq!(timed.status.code(), Some(0), "{}", text(&timed.stderr));
    let found = json(&timed);
    let bus = &found["timed_bus"];
    assert_eq!(
        (&bus["bitrate"], &bus["data_bitrate"], &bus["holds"]),
        (&500_000.into(), &2_000_000.into(), &true.into())
    );
    let streams = bus["streams"].as_array().unwrap();
    assert_eq!(streams.len(), 25);
    assert_eq!(streams[0]["name"], "object_pos");
    assert_eq!(streams[0]["verdict"], "within");
    assert_eq!(streams[0]["bound_s"], 0.000722);
    assert_eq!(streams[0]["worst_latency_s"], 0.000248);
    let skin = streams.iter().find(|s| s["name"] == "hand_skin").unwrap();
    assert_eq!(
        (&skin["verdict"], &skin["worst_latency_s"]),
        (&"no frames".into(), &serde_json::Value::Null)
    );
    let errors = streams
        .iter()
        .find(|s| s["name"] == "gaze: Errors")
        .unwrap();
    assert_eq!(errors["behind"]["frames"], 1);
    assert_eq!(errors["behind"]["worst_latency_s"], 0.009478);
    assert_eq!(bus["unmatched"].as_array().unwrap().len(), 18);
    // The table went to standard error with the rest of the text.
    assert!(text(&timed.stderr).contains("every compared latency within its bound: 23 streams"));
    // Without the option the object is the ideal bus's, as it was.
    let ideal = pabctl(&["sim", &example("take-and-return-fd.toml"), "--json"]);
    assert!(json(&ideal).get("timed_bus").is_none());
}

/// The `<text>` elements' contents of an SVG, trimmed, after checking that it is one `<svg>`
/// element (a cheap well-formedness check: no XML parser among the dependencies).
fn svg_texts(svg: &str) -> Vec<String> {
    assert!(svg.starts_with("<svg "), "{}", &svg[..svg.len().min(200)]);
    assert!(svg.trim_end().ends_with("</svg>"));
    assert_eq!(svg.matches("<text").count(), svg.matches("</text>").count());
    svg.split("<text")
        .skip(1)
        .filter_map(|part| {
            let body = part.split_once('>')?.1;
            Some(body.split_once("</text>")?.0.trim().to_string())
        })
        .collect()
}

#[test]
fn sim_draws_an_svg_whose_texts_are_text_with_its_gates_and_windows() {
    let dir = tempfile::tempdir().unwrap();
    let door = dir.path().join("door.svg");
    let output = pabctl(&[
        "sim",
        &example("door-dynamics.toml"),
        "--plot",
        door.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let svg = std::fs::read_to_string(&door).unwrap();
    let texts = svg_texts(&svg);
    for name in ["WANDER", "APPROACH", "LOOK", "CORRIDOR"] {
        assert!(
            texts.iter().any(|t| t.starts_with(name)),
            "{name}: {texts:?}"
        );
    }
    // The gates' strips: their names and a band named inside while open, not "?".
    for gate in ["door.search", "door.recognise", "door.approach"] {
        let label = format!("{gate}  gate of [dynamics.door]");
        assert!(texts.contains(&label), "{label}: {texts:?}");
    }
    assert!(texts.iter().any(|t| t == "door.search open"), "{texts:?}");
    assert!(!texts.iter().any(|t| t.contains(" ? ")), "{texts:?}");
    // Decimals with a plain point.
    assert!(texts.iter().any(|t| t.contains("τ 0.1 s")), "{texts:?}");
    assert!(!svg.contains('·'));
    // The gate's green.
    assert!(svg.contains("fill=\"#C4E8C4\""));

    let subsumption = dir.path().join("subsumption.svg");
    let output = pabctl(&[
        "sim",
        &example("subsumption.toml"),
        "--plot",
        subsumption.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let texts = svg_texts(&std::fs::read_to_string(&subsumption).unwrap());
    for kind in ["suppress", "inhibit", "write-inhibit", "override"] {
        assert!(texts.iter().any(|t| t == kind), "{kind}: {texts:?}");
    }
}

#[test]
fn sim_draws_the_schema_plot_as_svg() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("assembly.svg");
    let output = pabctl(&[
        "sim",
        &example("assembly.toml"),
        "--schema-plot",
        svg.to_str().unwrap(),
        "--until",
        "17",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let texts = svg_texts(&std::fs::read_to_string(&svg).unwrap());
    for expected in ["assembly.toml", "contact force (N)", "installed schema"] {
        assert!(texts.iter().any(|t| t == expected), "{expected}: {texts:?}");
    }
}

#[test]
fn inputs_that_are_no_files_are_refused_at_once_and_repeated_errors_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    // A FIFO without a writer: opening it would block forever; pabctl does not open it.
    let fifo = dir.path().join("net.toml");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let output = pabctl(&["check", fifo.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output.stderr).contains("error: a FIFO (named pipe) is not a regular file"),
        "{}",
        text(&output.stderr)
    );
    // /dev/zero as a capture: refused before a byte is read.
    let output = pabctl(&["replay", &example("figure-1.toml"), "/dev/zero"]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output.stderr)
            .starts_with("/dev/zero: error: a character device is not a regular file"),
        "{}",
        text(&output.stderr)
    );
    // 10 000 connections of one topic on one port: 9 999 errors of one message, three shown.
    let mut network =
        String::from("[nodes.a]\nid = 1\n[topics.t]\ncan_id = 0x100\n[ports.\"a.p\"]\n");
    for index in 0..10_000 {
        network.push_str(&format!(
            "[connections.C{index}]\ntopic = \"t\"\nport = \"a.p\"\nst = 1.0\ntc = 1.0\n"
        ));
    }
    let path = dir.path().join("big.toml");
    std::fs::write(&path, network).unwrap();
    let output = pabctl(&["check", path.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert_eq!(
        stderr
            .matches("error: topic `t` is already connected")
            .count(),
        3,
        "{stderr}"
    );
    assert!(
        stderr.contains(
            "… 9996 more errors not shown: 9996 × topic `t` is already connected to port `a.p` by `C0`"
        ),
        "{stderr}"
    );
    assert!(stderr.ends_with("9999 errors\n"), "{stderr}");
}

/// `keygen --signing` and `sign` as a user runs them: the key file private, its public key
/// printed; the signed image what pab-core admits under that public key, and refuses under
/// another; bad arguments refused before anything is written.
#[test]
fn a_firmware_signed_with_a_new_signing_key_is_admitted_under_its_public_key_only() {
    use pab_core::identity::Firmware;
    use pab_core::update::{SignedImage, UpdateRefusal};
    use std::os::unix::fs::PermissionsExt;

    let dir = tempfile::tempdir().unwrap();
    let key = dir.path().join("release.sign");
    let key_arg = key.display().to_string();
    let made = pabctl(&["keygen", "--signing", "-o", &key_arg]);
    assert!(made.status.success(), "{}", text(&made.stderr));
    let printed = text(&made.stdout);
    let public = printed
        .lines()
        .find_map(|line| line.strip_prefix("public key: "))
        .expect("the public key is printed");
    let public: Vec<u8> = (0..32)
        .map(|i| u8::from_str_radix(&public[2 * i..2 * i + 2], 16).unwrap())
        .collect();
    let public: [u8; 32] = public.try_into().unwrap();
    let mode = std::fs::metadata(&key).unwrap().permissions().mode();
    assert_eq!(mode & 0o777, 0o600);
    let again = pabctl(&["keygen", "--signing", "-o", &key_arg]);
    assert_eq!(again.status.code(), Some(3));
    assert!(text(&again.stderr).contains("never overwrites"));

    let firmware = dir.path().join("fw.bin");
    let image: Vec<u8> = (0..3000u32).map(|i| (i % 251) as u8).collect();
    std::fs::write(&firmware, &image).unwrap();
    let signed = dir.path().join("fw.signed");
    let args = |board: &'static str, version: &'static str, build: &'static str| {
        vec![
            "sign".to_string(),
            firmware.display().to_string(),
            "--key".into(),
            key_arg.clone(),
            "--board".into(),
            board.into(),
            "--version".into(),
            version.into(),
            "--build".into(),
            build.into(),
            "-o".into(),
            signed.display().to_string(),
        ]
    };
    let run = |args: Vec<String>| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        pabctl(&args)
    };
    // Every bad argument: exit 2, nothing written.
    for (board, version, build) in [
        ("nucleo-g474re", "1.0.0", "ab"),
        ("fw-g474", "1.0", "ab"),
        ("fw-g474", "1.0.256", "ab"),
        ("fw-g474", "1.0.0", "xyz"),
    ] {
        let refused = run(args(board, version, build));
        assert_eq!(refused.status.code(), Some(2), "{board} {version} {build}");
        assert!(!signed.exists());
    }
    let ok = run(args("fw-g474", "1.3.0", "0123456789abcdef0123"));
    assert!(ok.status.success(), "{}", text(&ok.stderr));
    assert!(text(&ok.stdout).contains("signed as fw-g474 1.3.0, build 0123456789abcdef"));
    let bytes = std::fs::read(&signed).unwrap();
    let parsed = SignedImage::parse(&bytes).unwrap();
    assert_eq!(parsed.image(), image.as_slice());
    let running = Firmware::new("fw-g474", "1.2.9", "0");
    let trailer = parsed.check(&running, 64 * 1024, &public).unwrap();
    assert_eq!(
        trailer.firmware,
        Firmware::new("fw-g474", "1.3.0", "0123456789abcdef")
    );
    assert!(!trailer.downgrade);
    let other = [0x42u8; 32];
    assert!(parsed.check(&running, 64 * 1024, &other).is_err());
    let newer = Firmware::new("fw-g474", "2.0.0", "0");
    assert_eq!(
        parsed.check(&newer, 64 * 1024, &public),
        Err(UpdateRefusal::Downgrade)
    );
}

/// `keypage --update-key`: the update key's record at offset 64, as the bootloader reads it,
/// with or without the node key's record before it; a key that is not one refused.
#[test]
fn a_key_page_carries_the_update_key_for_the_bootloader() {
    use pab_core::update::stored;

    let dir = tempfile::tempdir().unwrap();
    let signing = dir.path().join("release.sign");
    let made = pabctl(&["keygen", "--signing", "-o", &signing.display().to_string()]);
    let printed = text(&made.stdout);
    let public = printed
        .lines()
        .find_map(|line| line.strip_prefix("public key: "))
        .unwrap()
        .to_string();
    let node_key = dir.path().join("node.key");
    assert!(
        pabctl(&["keygen", "-o", &node_key.display().to_string()])
            .status
            .success()
    );
    let public_file = dir.path().join("release.pub");
    std::fs::write(&public_file, format!("{public}\n")).unwrap();

    for (node, update) in [
        (false, public.clone()),
        (true, public_file.display().to_string()),
    ] {
        let page = dir.path().join(format!("page-{node}.bin"));
        let mut args = vec!["keypage".to_string()];
        if node {
            args.push(node_key.display().to_string());
        }
        args.extend([
            "--update-key".into(),
            update,
            "-o".into(),
            page.display().to_string(),
        ]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let written = pabctl(&args);
        assert!(written.status.success(), "{}", text(&written.stderr));
        let bytes = std::fs::read(&page).unwrap();
        assert_eq!(
            bytes.len(),
            stored::KEY_RECORD_OFFSET + stored::KEY_RECORD_LEN
        );
        let key = stored::decode_key(&bytes[stored::KEY_RECORD_OFFSET..]).unwrap();
        assert_eq!(pabctl::signing::hex(&key), public);
        assert_eq!(
            pab_core::auth::page::decode(&bytes).unwrap().is_some(),
            node,
            "the node key's record"
        );
    }
    // 64 hexadecimal digits that are not a point of the curve, and nothing at all.
    let not_a_point = (2u8..)
        .map(|y| {
            let mut bytes = [0u8; 32];
            bytes[0] = y;
            bytes
        })
        .find(|bytes| ed25519_dalek::VerifyingKey::from_bytes(bytes).is_err())
        .unwrap();
    let not_a_point = pabctl::signing::hex(&not_a_point);
    let out = dir.path().join("refused.bin");
    let out = out.display().to_string();
    let bad = pabctl(&["keypage", "--update-key", &not_a_point, "-o", &out]);
    assert_eq!(bad.status.code(), Some(2), "{}", text(&bad.stderr));
    assert!(
        text(&bad.stderr).contains("not an Ed25519 public key"),
        "{}",
        text(&bad.stderr)
    );
    assert_eq!(pabctl(&["keypage", "-o", &out]).status.code(), Some(2));
    assert!(!Path::new(&out).exists());
}
