//! Identical decisions on every runner: the same frames, in virtual time, through
//!
//! (a) the simulator's arbiters (`pabctl sim`'s and `pabctl replay`'s engine),
//! (b) the node application, one `pab_app::FullNode` per node (what `pab-node` runs on Linux),
//! (c) the firmware on the emulated Cortex-M4 (`pab-an386-replay`, `pab_app::BoardNode`s, in QEMU),
//!
//! must give byte-identical records (`pab_app::replay::records`: every verdict, with the levels as
//! raw Q1.31 integers). The frames are those of a recorded hardware-in-the-loop run (the committed
//! candump log of Take and Return, `tests/fixtures/take-and-return-hil.log`) and the bus traffic of
//! every example network (`pabctl sim --candump`).
//!
//! (a) against (b) runs in `cargo test`. (c) needs QEMU and the firmware: the test that runs it
//! is ignored by plain `cargo test` and run by `scripts/cross-runner.sh` (from `./test.sh`), which
//! builds the firmware and passes its path in `PAB_AN386_REPLAY`; `PAB_REPLAY_CAPTURE` adds a
//! capture (a fresh HIL log) replayed with `examples/take-and-return.toml`.
//!
//! A node that runs a schema server decides what it sends (the drive's set-points, its schema
//! transitions): its runners' records hold its sent frames too. Its case is the bus of a closed
//! loop in virtual time (`common::schema_rig`: the node application, the plant, a client): the
//! node application replaying that bus must send exactly what the live node sent, in the order
//! of the simulator's schemas, and the board must record exactly what the node application does.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use pab_app::{Config, FullNode, Step};
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, Message};
use pab_core::{Frame, Instant as At};
use pab_lang::candump::{self, Capture};
use pab_lang::compile::{self, CompiledNode};
use pab_lang::network::Network;
use pab_lang::replay::{self, Feed};
use pab_lang::sim::{self, Options};

use crate::common;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

const HIL_FIXTURE: &str = "host-tools/tests/fixtures/take-and-return-hil.log";
const TAKE_AND_RETURN: &str = "examples/take-and-return.toml";

/// A network, its tables and the frames to feed.
struct Case {
    name: String,
    network: Network,
    compiled: Vec<CompiledNode>,
    capture: Capture,
    feed: Feed,
}

impl Case {
    fn new(name: &str, network: &Path, capture: Capture) -> Case {
        let network = Network::load(network).unwrap_or_else(|e| panic!("{e}"));
        let compiled = compile::compile(&network).unwrap_or_else(|e| panic!("{e:?}"));
        Case::of(name, network, compiled, capture)
    }

    /// `network` (already parsed and compiled) on `capture`.
    fn of(name: &str, network: Network, compiled: Vec<CompiledNode>, capture: Capture) -> Case {
        let feed = Feed::from_capture(&capture);
        Case {
            name: name.to_string(),
            network,
            compiled,
            capture,
            feed,
        }
    }

    fn from_log(name: &str, network: &Path, log: &Path) -> Case {
        let capture = candump::read(log, &mut |_| {}).unwrap_or_else(|e| panic!("{e}"));
        Case::new(name, network, capture)
    }

    /// The example's bus traffic, as `pabctl sim --candump` writes it.
    fn from_example(network: &Path) -> Case {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("bus.log");
        let status = Command::new(env!("CARGO_BIN_EXE_pabctl"))
            .args(["sim".as_ref(), network.as_os_str(), "--candump".as_ref()])
            .arg(&log)
            .stdout(Stdio::null())
            .status()
            .unwrap();
        assert!(
            status.success(),
            "pabctl sim --candump failed for {}",
            network.display()
        );
        let name = network.file_name().unwrap().to_string_lossy().into_owned();
        Case::from_log(&name, network, &log)
    }

    fn simulator(&self) -> String {
        let options = Options {
            records: true,
            ..Options::default()
        };
        let until = sim::settled_until(&self.network, &self.feed.frames);
        sim::run(
            &self.network,
            &self.compiled,
            &self.feed.frames,
            until,
            &options,
            &mut |_| {},
        )
        .unwrap()
        .records
    }

    fn node_application(&self) -> String {
        replay::node_records(&self.network, &self.compiled, &self.feed.frames).unwrap()
    }

    /// Runs the board's replay binary in QEMU on this case; it must succeed.
    fn board(&self, elf: &Path) -> String {
        let (success, stderr, records) = self.run_board(elf);
        assert!(success, "{}: the board replay failed: {stderr}", self.name);
        records
    }

    /// Runs the board's replay binary in QEMU on this case: (success, its standard error, the
    /// record it wrote).
    fn run_board(&self, elf: &Path) -> (bool, String, String) {
        let dir = tempfile::tempdir().unwrap();
        let job = dir.path().join("job.bin");
        let records = dir.path().join("records.txt");
        let bytes = replay::job(&self.network, &self.compiled, &self.feed.frames).unwrap();
        std::fs::write(&job, bytes).unwrap();
        let config = format!(
            "enable=on,target=native,arg=pab-an386-replay,arg={},arg={}",
            job.display(),
            records.display()
        );
        let mut child = Command::new("qemu-system-arm")
            .args(["-M", "mps2-an386", "-nographic", "-monitor", "none"])
            .args(["-semihosting-config", &config, "-kernel"])
            .arg(elf)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|error| {
                panic!(
                    "cannot start qemu-system-arm ({error}): scripts/cross-runner.sh installs it"
                )
            });
        let started = Instant::now();
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break status;
            }
            if started.elapsed() > Duration::from_secs(300) {
                let _ = child.kill();
                panic!("{}: the board replay ran for more than 300 s", self.name);
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let output = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr).trim().to_string();
        eprintln!(
            "{}: board replay in {:.1} s: {stderr}",
            self.name,
            started.elapsed().as_secs_f64(),
        );
        let records = std::fs::read_to_string(&records).unwrap_or_default();
        (status.success(), stderr, records)
    }
}

/// Fails with the first line where the two records differ.
fn assert_identical(case: &str, (a_name, a): (&str, &str), (b_name, b): (&str, &str)) {
    if a == b {
        return;
    }
    let mut a_lines = a.lines();
    let mut b_lines = b.lines();
    for number in 1.. {
        match (a_lines.next(), b_lines.next()) {
            (Some(x), Some(y)) if x == y => continue,
            (x, y) => panic!(
                "{case}: the records differ at line {number}:\n  {a_name}: {}\n  {b_name}: {}",
                x.unwrap_or("(end)"),
                y.unwrap_or("(end)")
            ),
        }
    }
}

/// What a record holds: (verdicts, deliveries, connections seen delivering). A comparison of
/// empty records would prove nothing.
fn substance(records: &str) -> (usize, usize) {
    let rows: Vec<&str> = records
        .lines()
        .filter(|line| !line.starts_with('#') && !line.starts_with("t_us"))
        .collect();
    let delivered = rows
        .iter()
        .filter(|row| row.split(',').nth(9).is_some_and(|d| d != "-"))
        .count();
    (rows.len(), delivered)
}

/// The examples whose runs the record format describes whole, those with ports. Not those with value ports: a
/// value port's output is a combined frame, for which the record format (one line per verdict)
/// has no column yet; `host-tools/tests/value_ports.rs` and the node's fuzz check compare those.
fn examples() -> Vec<PathBuf> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(root().join("examples"))
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "toml"))
        .filter(|path| {
            let network = Network::load(path).unwrap_or_else(|e| panic!("{e}"));
            // A file without ports (the schema server's assembly) has no verdicts to compare.
            !network.ports.is_empty() && network.ports.iter().all(|port| port.value.is_none())
        })
        .collect();
    paths.sort();
    assert!(paths.len() >= 4, "examples: {paths:?}");
    paths
}

fn hil_case() -> Case {
    Case::from_log(
        "the recorded HIL run",
        &root().join(TAKE_AND_RETURN),
        &root().join(HIL_FIXTURE),
    )
}

#[test]
fn simulator_and_node_application_agree_on_every_example() {
    for path in examples() {
        let case = Case::from_example(&path);
        let simulator = case.simulator();
        let node = case.node_application();
        let (verdicts, delivered) = substance(&simulator);
        assert!(
            verdicts > 50 && delivered > 10,
            "{}: {verdicts} verdicts, {delivered} deliveries",
            case.name
        );
        assert_identical(
            &case.name,
            ("simulator", &simulator),
            ("node application", &node),
        );
    }
}

#[test]
fn simulator_and_node_application_agree_on_the_recorded_hil_run() {
    let case = hil_case();
    // The log is a real closed-loop run: the behaviours' traffic, the gateways' re-published
    // frames, the nodes' heartbeats and diagnostic stream, the pushes at its start.
    assert!(
        case.feed.protocol_frames > 1000,
        "{}",
        case.feed.protocol_frames
    );
    let simulator = case.simulator();
    let node = case.node_application();
    let (verdicts, delivered) = substance(&simulator);
    assert!(
        verdicts > 500 && delivered > 150,
        "{verdicts} verdicts, {delivered} deliveries"
    );
    assert_identical(
        &case.name,
        ("simulator", &simulator),
        ("node application", &node),
    );
}

#[test]
fn the_replay_of_the_recorded_hil_run_delivers_what_the_live_nodes_re_published() {
    // In that run the nodes were gateways: each re-published the frames its port delivered, with
    // the payload unchanged (every behaviour's payload carries its id and a sequence number). The
    // replay, at the kernel's timestamps, delivers the very same payloads in the same order at
    // every port. (A property of this recording, not of every capture: a live node reads frames
    // at its own time and in its socket's order, which can differ from the stamps.)
    let case = hil_case();
    let records = case.simulator();
    let mut payloads = std::collections::HashMap::new();
    for frame in &case.feed.frames {
        payloads
            .entry((frame.t_us, frame.frame.raw_id()))
            .or_insert_with(|| frame.frame.payload().to_vec());
    }
    for (port_index, port) in case.network.ports.iter().enumerate() {
        let pab_core::Consumer::Republish(output) = port.consumer else {
            panic!("{} is not a gateway", port.name);
        };
        let node = &case.network.nodes[port.node];
        let local = node.ports.iter().position(|&p| p == port_index).unwrap();
        let replayed: Vec<Vec<u8>> = records
            .lines()
            .filter(|line| !line.starts_with('#') && !line.starts_with("t_us"))
            .map(|line| line.split(',').collect::<Vec<_>>())
            .filter(|row| {
                row[3] == node.id.to_string() && row[4] == local.to_string() && row[9] != "-"
            })
            .map(|row| {
                let t_us: u64 = row[0].parse().unwrap();
                let id = u32::from_str_radix(row[1], 16).unwrap();
                payloads[&(t_us, (id, row[2] == "1"))].clone()
            })
            .collect();
        let live: Vec<Vec<u8>> = case
            .capture
            .frames
            .iter()
            .filter(|c| c.frame.id() == output.id())
            .map(|c| c.frame.payload().to_vec())
            .collect();
        assert!(
            live.len() > 30,
            "{}: {} re-published",
            port.name,
            live.len()
        );
        assert_eq!(replayed, live, "{}", port.name);
    }
}

/// `t` seconds with six decimals to µs.
fn micros_of(text: &str) -> u64 {
    let (seconds, fraction) = text.split_once('.').unwrap();
    seconds.parse::<u64>().unwrap() * 1_000_000 + fraction.parse::<u64>().unwrap()
}

#[test]
fn the_replay_of_a_simulated_bus_traces_exactly_what_the_simulation_traced() {
    for path in examples() {
        let dir = tempfile::tempdir().unwrap();
        let (log, sim_csv, replay_csv) = (
            dir.path().join("bus.log"),
            dir.path().join("sim.csv"),
            dir.path().join("replay.csv"),
        );
        let pabctl = |args: &[&std::ffi::OsStr]| {
            let output = Command::new(env!("CARGO_BIN_EXE_pabctl"))
                .args(args)
                .output()
                .unwrap();
            assert!(
                output.status.success(),
                "{}",
                String::from_utf8_lossy(&output.stderr)
            );
            String::from_utf8(output.stdout).unwrap()
        };
        pabctl(&[
            "sim".as_ref(),
            path.as_os_str(),
            "--candump".as_ref(),
            log.as_os_str(),
            "--trace".as_ref(),
            sim_csv.as_os_str(),
        ]);
        pabctl(&[
            "replay".as_ref(),
            path.as_os_str(),
            log.as_os_str(),
            "--trace".as_ref(),
            replay_csv.as_os_str(),
        ]);
        // The replay's time 0 is the capture's first frame: shift the simulation's times by it.
        let capture = std::fs::read_to_string(&log).unwrap();
        let first = micros_of(&capture[1..capture.find(')').unwrap()]);
        let simulated: String = std::fs::read_to_string(&sim_csv)
            .unwrap()
            .lines()
            .enumerate()
            .map(|(index, line)| match (index, line.split_once(',')) {
                (0, _) | (_, None) => format!("{line}\n"),
                (_, Some((t, rest))) => {
                    format!("{},{rest}\n", sim::seconds_text(micros_of(t) - first))
                }
            })
            .collect();
        let replayed = std::fs::read_to_string(&replay_csv).unwrap();
        // A replay has no `[[faults]]`: the capture holds the frames a stopped node would have
        // heard, and the replayed node hears them. The traces agree up to the first stop.
        let network = Network::load(&path).unwrap();
        let stop = network
            .faults
            .iter()
            .map(|f| sim::micros(f.at))
            .min()
            .map(|t| t - first);
        let before = |trace: &str| -> String {
            trace
                .lines()
                .enumerate()
                .filter(|(index, line)| {
                    *index == 0
                        || stop.is_none_or(|stop| {
                            micros_of(line.split(',').next().unwrap_or("0")) < stop
                        })
                })
                .map(|(_, line)| format!("{line}\n"))
                .collect()
        };
        let (simulated, replayed) = (before(&simulated), before(&replayed));
        assert!(simulated.lines().count() > 50);
        assert_identical(
            &path.display().to_string(),
            ("sim --trace", &simulated),
            ("replay --trace", &replayed),
        );
    }
}

/// The frames of a real push of `image` to node `node_id` by the tool, starting at `from_us`:
/// pab-core's ISO-TP sender against a `FullNode` running `running`, in virtual time, one frame
/// per 200 µs. Returns every frame on the bus (both ways) with its time, and the version the node
/// runs afterwards.
fn recorded_push(
    running: &[u8],
    image: &[u8],
    node_id: u8,
    from_us: u64,
) -> (Vec<(u64, Frame)>, u32) {
    let mut node = Box::new(FullNode::new(
        Config::new(node_id).unwrap(),
        At::from_micros(0),
    ));
    node.boot_buffer()[..running.len()].copy_from_slice(running);
    node.boot(Some(running.len()), At::from_micros(0));
    while node.next_outgoing().is_some() {}
    let mut bus = Vec::new();
    let mut now = from_us;
    let mut sender = Sender::new(image, TxConfig::default()).unwrap();
    let mut answers: Vec<Frame> = Vec::new();
    loop {
        match sender.poll(At::from_micros(now)) {
            TxEvent::Send(data) => {
                let frame =
                    Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, node_id);
                bus.push((now, frame));
                if node.on_frame(&frame, At::from_micros(now), &mut ()) == Step::Store {
                    node.stored(true, At::from_micros(now));
                }
                while let Some(out) = node.next_outgoing() {
                    bus.push((now, out));
                    answers.push(out);
                }
                now += 200;
            }
            TxEvent::WaitUntil(until) => {
                let mut heard = false;
                for frame in answers.drain(..) {
                    if let Ok((id, Message::TableTransfer { data, len })) = Message::decode(&frame)
                        && id.destination == protocol::TOOL
                    {
                        sender.on_flow_control(&data[..usize::from(len)], At::from_micros(now));
                        heard = true;
                    }
                }
                if !heard {
                    now = until.as_micros().max(now + 1);
                }
            }
            TxEvent::Done => break,
            TxEvent::Failed(error) => panic!("the push failed: {error:?}"),
        }
    }
    let version = node.running().unwrap().header.table_version;
    (bus, version)
}

#[test]
fn protocol_frames_of_a_capture_are_not_fed_so_a_recorded_push_does_not_switch_tables() {
    // A capture of Take and Return with, 20 s in, a push of a different table (version 2: Rest
    // Arm's C14 stimulated ten times harder) to the arm node, heartbeats around it.
    let path = root().join(TAKE_AND_RETURN);
    let clean = Case::from_example(&path);
    let text = std::fs::read_to_string(&path).unwrap();
    let changed_text = text.replacen("version = 1", "version = 2", 1).replacen(
        "[connections.C14]",
        "[connections.C14]\n# replay test: a different table",
        1,
    );
    let c14 = changed_text.find("[connections.C14]").unwrap();
    let st = c14 + changed_text[c14..].find("st = ").unwrap();
    let end = st + changed_text[st..].find('\n').unwrap();
    let changed_text = format!("{}st = 1.0{}", &changed_text[..st], &changed_text[end..]);
    let changed =
        Network::parse(pab_lang::diagnostic::Source::new("v2.toml", changed_text)).unwrap();
    assert_eq!(changed.version, 2);
    let v2 = compile::compile(&changed).unwrap();
    let arm = clean
        .network
        .nodes
        .iter()
        .find(|n| n.name == "arm")
        .unwrap()
        .id;
    let image =
        |compiled: &[CompiledNode]| compiled.iter().find(|c| c.id == arm).unwrap().image.clone();
    let (push, version) = recorded_push(&image(&clean.compiled), &image(&v2), arm, 20_000_000);
    assert_eq!(
        version, 2,
        "the recorded push must switch a node that hears it"
    );
    assert!(push.len() > 20, "{} frames", push.len());
    let heartbeat = Message::Heartbeat(protocol::Heartbeat {
        state: protocol::NodeState::Operational,
        uptime_s: 20,
        table_version: 1,
    })
    .to_frame(arm, protocol::BROADCAST);
    let mut injected: Vec<(u64, Frame)> = push;
    injected.push((19_000_000, heartbeat));
    injected.push((25_000_000, heartbeat));
    let mut frames: Vec<(u64, Frame)> = clean
        .capture
        .frames
        .iter()
        .map(|c| (c.t_us, c.frame))
        .chain(injected.iter().copied())
        .collect();
    frames.sort_by_key(|(t, _)| *t);
    let capture = Capture::from_frames("vcan0", &frames);
    let with_push = Case::new("with a recorded push", &path, capture);
    // The simulated bus already carries the nodes' heartbeats: protocol frames, not fed either.
    assert_eq!(
        with_push.feed.protocol_frames,
        clean.feed.protocol_frames + injected.len()
    );
    assert_eq!(with_push.feed.frames, clean.feed.frames);

    // Fed everything (protocol included), a node would switch to version 2 halfway and decide
    // differently: the difference the rule avoids is real.
    let mut node = Box::new(FullNode::new(Config::new(arm).unwrap(), At::from_micros(0)));
    let original = image(&clean.compiled);
    node.boot_buffer()[..original.len()].copy_from_slice(&original);
    node.boot(Some(original.len()), At::from_micros(0));
    for (t, frame) in &frames {
        if node.on_frame(frame, At::from_micros(*t), &mut ()) == Step::Store {
            node.stored(true, At::from_micros(*t));
        }
        while node.next_outgoing().is_some() {}
    }
    assert_eq!(node.running().unwrap().header.table_version, 2);
    let v2_case = Case::new("version 2", &path, clean.capture.clone());
    let v2_records = replay::node_records(&changed, &v2, &v2_case.feed.frames).unwrap();
    assert_ne!(
        substance(&v2_records),
        substance(&clean.simulator()),
        "version 2 must decide differently for this test to mean anything"
    );

    // Replayed, the push is not fed: every runner decides with the tables it was given.
    let expected = clean.simulator();
    assert_identical(
        "simulator",
        ("clean", &expected),
        ("with push", &with_push.simulator()),
    );
    assert_identical(
        "node application",
        ("clean", &expected),
        ("with push", &with_push.node_application()),
    );
}

/// The schema server's rig: one insertion (nine calls), an emergency stop during the last move
/// and a high-priority move after it, at the boards' 1 kHz.
const SCHEMA_RIG: &str = r#"[nodes.arm]
id = 10

[schema.arm]
period_ms = 1
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
    "move_to(away)",
]

[client.places]
down = [0, 0, -1]
above_part = [0, 0, 20]
above_slot = [10, 0, 20]
away = [30, 20, 40]

[[client.commands]]
at = 2.0
call = "estop()"

[[client.commands]]
at = 2.2
call = "move_to(above_slot)"
"#;

/// The rig's run long enough for its program and commands (the simulator's run ends at 2.6 s).
const SCHEMA_RIG_US: u64 = 2_800_000;

fn schema_case() -> (Case, common::schema_rig::RigRun) {
    let network = Network::parse(pab_lang::diagnostic::Source::new(
        "schema-rig.toml",
        SCHEMA_RIG,
    ))
    .unwrap();
    let compiled = compile::compile(&network).unwrap();
    let run = common::schema_rig::run(&network, &compiled, SCHEMA_RIG_US);
    let case = Case::of(
        "the schema server's closed loop",
        network,
        compiled,
        run.capture.clone(),
    );
    (case, run)
}

#[test]
fn the_schema_servers_replay_sends_what_the_live_node_sent() {
    let (case, run) = schema_case();
    // The loop did what the program says: the part went in, every call and the high-priority
    // move were accepted, the stop stopped the board.
    assert_eq!(run.plant.inserted(), 1);
    assert_eq!(run.accepted, 10);
    let safety = protocol::SchemaTrigger::Safety;
    assert_eq!(
        run.transitions
            .iter()
            .filter(|t| t.trigger == safety)
            .map(|t| protocol::SchemaSafety::from_code(t.detail))
            .collect::<Vec<_>>(),
        [Some(protocol::SchemaSafety::EmergencyStop)]
    );
    // The same schemas, from the same sources, in the same order as the simulator's (both run
    // the node and send the schemas over ISO-TP; the rig's times may differ: its client sends
    // on a 50 µs grid, and only as far as the rig runs).
    let simulated = pab_lang::sim::schema::simulate(
        &case.network,
        pab_lang::sim::schema::Limits {
            until_us: SCHEMA_RIG_US,
            settle_us: 100_000,
        },
    )
    .unwrap();
    let expected: Vec<(u16, &str)> = simulated
        .installed
        .iter()
        .map(|i| (i.id, i.source.name()))
        .collect();
    let live: Vec<(u16, &str)> = run
        .transitions
        .iter()
        .map(|t| {
            let origin = pab_core::schema::Origin::from(t.source);
            (t.installed, origin.name())
        })
        .collect();
    assert_eq!(live, expected);
    assert!(
        run.sent_lines.len() > 2 * 2600,
        "{} frames sent",
        run.sent_lines.len()
    );

    // Replayed from the capture, the node sends exactly what it sent live, at the same instants.
    let node = case.node_application();
    let replayed = common::schema_rig::sent_lines(&node);
    assert_eq!(replayed.len(), run.sent_lines.len());
    for (number, (r, l)) in replayed.iter().zip(&run.sent_lines).enumerate() {
        assert_eq!(r, l, "sent frame {number}: replay against live");
    }
}

/// The board (c) against the simulator (a), on every example, the committed HIL log and the
/// capture in `PAB_REPLAY_CAPTURE` if set; and against the node application (b) on the schema
/// server's rig. Needs QEMU and the firmware: run by
/// scripts/cross-runner.sh, which sets `PAB_AN386_REPLAY`.
#[test]
#[ignore = "needs qemu-system-arm and the firmware: run by scripts/cross-runner.sh (./test.sh)"]
fn board_firmware_agrees_with_the_simulator_and_the_node_application() {
    let elf = std::env::var_os("PAB_AN386_REPLAY")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            panic!(
                "PAB_AN386_REPLAY is not set: run scripts/cross-runner.sh, which builds \
             pab-an386-replay and runs this test"
            )
        });
    assert!(elf.exists(), "{} does not exist", elf.display());
    // Every example, competitive dynamics included: the board steps its groups with the same
    // code at the same instants, and reads other nodes' Gates from the capture.
    let examples = examples();
    assert!(
        examples.iter().any(|p| !Network::load(p)
            .unwrap_or_else(|e| panic!("{e}"))
            .dynamics
            .is_empty()),
        "an example with dynamics"
    );
    let mut cases: Vec<Case> = examples.iter().map(|p| Case::from_example(p)).collect();
    cases.push(hil_case());
    if let Some(extra) = std::env::var_os("PAB_REPLAY_CAPTURE") {
        cases.push(Case::from_log(
            &format!("{}", Path::new(&extra).display()),
            &root().join(TAKE_AND_RETURN),
            Path::new(&extra),
        ));
    }
    // Every example fits the boards' capacities. A network that does not is not replayed
    // silently with fewer nodes: the board records the refusal and fails.
    let mut ports = String::from("[nodes.wide]\nid = 9\n[topics.t]\ncan_id = 0x100\n");
    for port in 0..5 {
        ports.push_str(&format!(
            "[ports.\"wide.p{port}\"]\n[connections.C{port}]\ntopic = \"t\"\n\
             port = \"wide.p{port}\"\nst = 1.0\ntc = 1.0\n"
        ));
    }
    ports.push_str("[[events]]\ntopic = \"t\"\nat = [0.0, 0.5]\n");
    let dir = tempfile::tempdir().unwrap();
    let wide = dir.path().join("wide.toml");
    std::fs::write(&wide, ports).unwrap();
    let case = Case::from_example(&wide);
    let (verdicts, _) = substance(&case.simulator());
    assert_eq!(verdicts, 10, "the host runners take the 5-port table");
    let (success, stderr, records) = case.run_board(&elf);
    assert!(!success, "{records}");
    assert!(stderr.contains("refused their image"), "{stderr}");
    assert!(
        records.contains(
            "# node 9: image refused: table refused by the loader (status 0x17, detail 4)"
        ),
        "{records}"
    );

    for case in &cases {
        let simulator = case.simulator();
        let node = case.node_application();
        let board = case.board(&elf);
        let (verdicts, delivered) = substance(&board);
        eprintln!(
            "{}: {} frames, {verdicts} verdicts ({delivered} deliveries): simulator, node \
             application and board identical ({} bytes of record)",
            case.name,
            case.feed.frames.len(),
            board.len()
        );
        assert_identical(
            &case.name,
            ("simulator", &simulator),
            ("node application", &node),
        );
        assert_identical(&case.name, ("simulator", &simulator), ("board", &board));
    }

    // The schema server on the board: the same sent frames, at the same instants, as the node
    // application (the simulator's arbiters have no schema server: its order of schemas is
    // checked against the rig in `the_schema_servers_replay_sends_what_the_live_node_sent`).
    let (case, run) = schema_case();
    let node = case.node_application();
    let board = case.board(&elf);
    let sent = common::schema_rig::sent_lines(&board);
    eprintln!(
        "{}: {} frames, {} sent by the board's schema server: node application and board \
         identical ({} bytes of record)",
        case.name,
        case.feed.frames.len(),
        sent.len(),
        board.len()
    );
    assert_eq!(
        sent, run.sent_lines,
        "{}: the board against the live node",
        case.name
    );
    assert_identical(&case.name, ("node application", &node), ("board", &board));
}
