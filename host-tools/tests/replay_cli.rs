//! `pabctl replay` and `pabctl sim --candump` as a user runs them: output, errors with their
//! line, exit statuses, files written or not.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
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

fn path(relative: &str) -> String {
    root().join(relative).display().to_string()
}

const NETWORK: &str = "examples/take-and-return.toml";
const HIL_LOG: &str = "host-tools/tests/fixtures/take-and-return-hil.log";

#[test]
fn the_help_teaches_the_capture_format_with_examples() {
    let output = pabctl(&["replay", "--help"]);
    assert_eq!(output.status.code(), Some(0));
    let help = text(&output.stdout);
    for expected in [
        "candump -L can0 > yesterday.log",
        "(1700000000.123456) can0 123#DEADBEEF",
        "pabctl replay arm-v2.toml yesterday.log",
        "not fed",
        "FILE:LINE:COLUMN",
        "t,port,connection,stimulation,active,delivered",
    ] {
        assert!(help.contains(expected), "missing {expected:?} in:\n{help}");
    }
}

#[test]
fn a_recorded_hil_run_is_replayed_with_a_summary_and_the_port_timelines() {
    let dir = tempfile::tempdir().unwrap();
    let trace = dir.path().join("replay.csv");
    let records = dir.path().join("records.txt");
    let plot = dir.path().join("replay.png");
    let output = pabctl(&[
        "replay",
        &path(NETWORK),
        &path(HIL_LOG),
        "--trace",
        trace.to_str().unwrap(),
        "--records",
        records.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    // The fixture: 4790 frames, 4331 of them the nodes' own (pushes, heartbeats, the diagnostic
    // stream), 37 written out of time order by the recorder, and the gateways' re-published
    // frames on 0x200..0x202, which no topic matches.
    for expected in [
        "4790 frames over 23.877701 s on vcan0",
        "459 replayed on 3 nodes, 4331 of the pab protocol not fed",
        "37 frames out of time order in the file (at most 0.009299 s early)",
        "161 frames match no topic: 0x200 ×66, 0x201 ×54, 0x202 ×41",
        "arm.target (node arm)",
        "C14 (rest_pose)",
    ] {
        assert!(
            stdout.contains(expected),
            "missing {expected:?} in:\n{stdout}"
        );
    }
    let csv = std::fs::read_to_string(&trace).unwrap();
    assert!(csv.starts_with("t,port,connection,stimulation,active,delivered\n"));
    assert_eq!(csv.lines().count(), 541, "one row per fed connection");
    let records = std::fs::read_to_string(&records).unwrap();
    assert!(records.starts_with("# pab replay records 2\n# node 1: table version 1, crc 0x"));
    assert!(
        records.ends_with("# end: 459 frames, 540 verdicts, 0 sent\n"),
        "{records}"
    );
    assert!(std::fs::metadata(&plot).unwrap().len() > 10_000);
}

#[test]
fn every_malformed_line_is_reported_with_its_place_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("bad.log");
    std::fs::write(
        &capture,
        "(1700000000.000000) can0 110#01\n\
         (1700000000.100000) can0 110#0G\n\
         garbage\n\
         (1700000000.200000) can0 123##\n\
         (1700000000.300000) can0 1234#00\n\
         (1700000000.400000) can0 113#\n",
    )
    .unwrap();
    let trace = dir.path().join("trace.csv");
    let output = pabctl(&[
        "replay",
        &path(NETWORK),
        capture.to_str().unwrap(),
        "--trace",
        trace.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    let name = capture.display();
    for expected in [
        format!("{name}:2:31: error: `G` is not a hex digit of the data"),
        format!("{name}:3:1: error: not a candump -L line"),
        format!("{name}:4:31: error: a CAN FD frame needs one hex digit of flags after `##`"),
        format!("{name}:5:26: error: CAN id `1234` has 4 digits"),
    ] {
        assert!(
            stderr.contains(&expected),
            "missing {expected:?} in:\n{stderr}"
        );
    }
    assert_eq!(
        stderr.lines().filter(|l| l.contains(": error: ")).count(),
        4,
        "{stderr}"
    );
    assert!(stderr.ends_with("\n4 errors\n"), "{stderr}");
    assert!(output.stdout.is_empty());
    assert!(!trace.exists());
}

#[test]
fn an_output_that_is_an_input_is_refused_before_anything_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("yesterday.log");
    std::fs::write(&capture, "(1.000000) can0 110#01\n").unwrap();
    let output = pabctl(&[
        "replay",
        &path(NETWORK),
        capture.to_str().unwrap(),
        "--trace",
        capture.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output.stderr).contains("--trace would overwrite an input file"),
        "{}",
        text(&output.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(&capture).unwrap(),
        "(1.000000) can0 110#01\n"
    );
}

#[test]
fn a_missing_or_empty_capture_is_an_input_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.log");
    let output = pabctl(&["replay", &path(NETWORK), missing.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).contains("missing.log: error: cannot read"));
    let empty = dir.path().join("empty.log");
    std::fs::write(&empty, "\n").unwrap();
    let output = pabctl(&["replay", &path(NETWORK), empty.to_str().unwrap()]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).contains("no CAN frame in this file"));
}

#[test]
fn sim_writes_its_bus_as_a_candump_log() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("bus.log");
    let output = pabctl(&[
        "sim",
        &path("examples/figure-1.toml"),
        "--candump",
        log.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let written = std::fs::read_to_string(&log).unwrap();
    let lines: Vec<&str> = written.lines().collect();
    assert!(text(&output.stdout).contains(&format!("({} frames)", lines.len())));
    // The nodes boot at 0: their first heartbeats lead (node 3's status first, 0x1202FF03).
    assert_eq!(
        lines[0],
        "(0000000000.000000) vcan0 1202FF03#0100000001000000"
    );
    // No `data` on figure 1's events: the topic's length (8 by default) of zeros.
    assert!(
        lines.contains(&"(0000000000.000000) vcan0 110#0000000000000000"),
        "{written}"
    );
    assert!(
        lines
            .iter()
            .all(|line| line.starts_with('(') && line.contains(" vcan0 "))
    );
}

#[test]
fn replay_json_gives_the_capture_s_counts_and_the_port_timelines() {
    let output = pabctl(&["replay", &path(NETWORK), &path(HIL_LOG), "--json"]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let found: serde_json::Value = serde_json::from_slice(&output.stdout)
        .unwrap_or_else(|error| panic!("not JSON ({error}): {}", text(&output.stdout)));
    // The same fixture as the text's test above.
    assert_eq!(found["captured"], 4790);
    assert_eq!(found["replayed"], 459);
    assert_eq!(found["protocol_frames"], 4331);
    let unmatched: u64 = found["unmatched"]
        .as_array()
        .unwrap()
        .iter()
        .map(|u| u["count"].as_u64().unwrap())
        .sum();
    assert_eq!(unmatched, 161);
    assert_eq!(found["ports"][0]["port"], "arm.target");
    assert!(
        found["ports"][0]["changes"]
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c["delivers"] == "C14" && c["topic"] == "rest_pose")
    );
    // The text went to standard error.
    assert!(text(&output.stderr).contains("4790 frames over 23.877701 s on vcan0"));
}

#[test]
fn replay_draws_its_plot_as_svg_too() {
    let dir = tempfile::tempdir().unwrap();
    let plot = dir.path().join("replay.svg");
    let output = pabctl(&[
        "replay",
        &path(NETWORK),
        &path(HIL_LOG),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(svg.starts_with("<svg "));
    assert!(svg.trim_end().ends_with("</svg>"));
    assert!(svg.contains("<text"));
}

#[test]
fn a_can_fd_capture_is_replayed_with_the_verdicts_of_its_classic_twin() {
    // The HIL capture with every frame written as a CAN FD frame with bit-rate switching, the
    // way candump logs a CAN FD bus: the tables decide on ids and payloads, not on the format,
    // so the record is the classic capture's, verdict for verdict.
    let dir = tempfile::tempdir().unwrap();
    let classic = std::fs::read_to_string(path(HIL_LOG)).unwrap();
    let fd: String = classic
        .lines()
        .map(|line| line.replacen('#', "##1", 1) + "\n")
        .collect();
    assert!(fd.contains("##1"), "the fixture has frames");
    let fd_log = dir.path().join("fd.log");
    std::fs::write(&fd_log, fd).unwrap();
    let records = |capture: &str, name: &str| {
        let out = dir.path().join(name);
        let output = pabctl(&[
            "replay",
            &path(NETWORK),
            capture,
            "--records",
            out.to_str().unwrap(),
        ]);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
        std::fs::read_to_string(out).unwrap()
    };
    let fd_records = records(fd_log.to_str().unwrap(), "fd.txt");
    assert!(fd_records.ends_with("# end: 459 frames, 540 verdicts, 0 sent\n"));
    assert_eq!(fd_records, records(&path(HIL_LOG), "classic.txt"));

    // The emulated board is a classic node: no board job of CAN FD frames.
    let job = dir.path().join("job.bin");
    let output = pabctl(&[
        "replay",
        &path(NETWORK),
        fd_log.to_str().unwrap(),
        "--board-job",
        job.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2), "{}", text(&output.stdout));
    let stderr = text(&output.stderr);
    assert!(stderr.contains("is a CAN FD frame"), "{stderr}");
    assert!(stderr.contains("classic frames only"), "{stderr}");
    assert!(!job.exists());
}

#[test]
fn a_capture_of_the_hil_suite_s_can_fd_bus_is_replayed() {
    // hil-sim's Take and Return on a CAN FD vcan (test_can_fd.py), its tables pushed in CAN FD
    // frames: candump -L wrote them `ID##5...` (BRS, and the FDF flag Linux 6.1 sets).
    let capture = "host-tools/tests/fixtures/take-and-return-fd-hil.log";
    let log = std::fs::read_to_string(path(capture)).unwrap();
    assert!(log.lines().filter(|line| line.contains("##5")).count() >= 10);
    let dir = tempfile::tempdir().unwrap();
    let records = dir.path().join("records.txt");
    let output = pabctl(&[
        "replay",
        &path(NETWORK),
        &path(capture),
        "--records",
        records.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
    let stdout = text(&output.stdout);
    for expected in [
        "4360 frames over 20.243304 s on vcan1",
        "430 replayed on 3 nodes, 3930 of the pab protocol not fed",
        "150 frames match no topic: 0x200 ×62, 0x201 ×44, 0x202 ×44",
        "C14 (rest_pose)",
    ] {
        assert!(
            stdout.contains(expected),
            "missing {expected:?} in:\n{stdout}"
        );
    }
    let records = std::fs::read_to_string(&records).unwrap();
    assert!(records.contains("# end: 430 frames,"), "{records}");
}

/// `network` as the HIL suite runs it (`hil-sim/pab_hil/response_times.py`): its nodes beat every
/// 250 ms (`pab-node --heartbeat-ms 250`) and its behaviours, Python processes, wake up to 20 ms
/// late for their periods.
fn as_the_hil_runs(network: &str, dir: &Path) -> String {
    let mut text = std::fs::read_to_string(root().join(network)).unwrap();
    for (name, _) in [("arm", 1), ("hand", 2), ("gaze", 3)] {
        let header = format!("[nodes.{name}]");
        let at = text.find(&header).unwrap() + header.len();
        let end = at + text[at..].find('\n').unwrap();
        text.insert_str(end + 1, "heartbeat = 0.25\n");
    }
    let text = text.replace("\nperiod = ", "\njitter = 0.02\nperiod = ");
    let path = dir.join("as-run.toml");
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

/// The JSON's `timed_bus` streams that carried frames: (name, frames, compared, verdict).
fn timed_streams(json: &serde_json::Value) -> Vec<(String, u64, u64, String)> {
    json["timed_bus"]["streams"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|s| s["frames"].as_u64().unwrap() > 0)
        .map(|s| {
            (
                s["name"].as_str().unwrap().to_string(),
                s["frames"].as_u64().unwrap(),
                s["compared"].as_u64().unwrap(),
                s["verdict"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

/// The HIL suite's captures, classic and CAN FD, each frame queued at its timestamp on a bus at
/// the network's rates: every analysed stream is compared, within its bound. As the suite runs
/// the network (250 ms heartbeats, publishers' jitter) most of the frames are compared; with the
/// file as it is (1 s heartbeats, no jitter) the heartbeats come four times too often and most
/// are outside the analysis, reported and not compared.
#[test]
fn the_hil_suite_s_captures_keep_their_bounds_on_the_timed_bus() {
    let dir = tempfile::tempdir().unwrap();
    for (network, log, carried, compared_at_least) in [
        (NETWORK, HIL_LOG, 4790, 1000),
        (
            "examples/take-and-return-fd.toml",
            "host-tools/tests/fixtures/take-and-return-fd-hil.log",
            4360,
            900,
        ),
    ] {
        let as_run = as_the_hil_runs(network, dir.path());
        let output = pabctl(&["replay", &as_run, &path(log), "--timed-bus", "--json"]);
        let stderr = text(&output.stderr);
        assert_eq!(output.status.code(), Some(0), "{stderr}");
        let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        assert_eq!(json["timed_bus"]["carried"], carried);
        assert_eq!(json["timed_bus"]["unsent"], 0);
        assert_eq!(json["timed_bus"]["holds"], true);
        let streams = timed_streams(&json);
        assert_eq!(streams.len(), 23, "{streams:?}");
        assert!(
            streams
                .iter()
                .all(|(_, _, compared, verdict)| *compared > 0 && verdict == "within"),
            "{streams:?}"
        );
        let compared: u64 = streams.iter().map(|s| s.2).sum();
        assert!(compared >= compared_at_least, "{compared}: {streams:?}");
        assert!(
            stderr.contains(&format!(
                "every compared latency within its bound: 23 streams, {compared} frames"
            )),
            "{stderr}"
        );

        // The file as it is: its heartbeat groups at 1 s, a quarter of the capture's.
        let output = pabctl(&[
            "replay",
            &path(network),
            &path(log),
            "--timed-bus",
            "--json",
        ]);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output.stderr));
        let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
        let heartbeat = json["timed_bus"]["streams"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == "arm: Heartbeat")
            .unwrap();
        let frames = heartbeat["frames"].as_u64().unwrap();
        let beyond = heartbeat["beyond_period"]["frames"].as_u64().unwrap();
        assert!(beyond * 2 > frames, "{heartbeat}");
        assert!(
            heartbeat["beyond_period"]["detail"]
                .as_str()
                .unwrap()
                .contains("less than 1 × 1 s − 0 ms"),
            "{heartbeat}"
        );
    }
}

/// Without [bus] there is no bit rate to carry the frames at: refused, nothing replayed.
#[test]
fn timed_bus_needs_the_network_s_bus() {
    let output = pabctl(&[
        "replay",
        &path("examples/figure-1.toml"),
        &path(HIL_LOG),
        "--timed-bus",
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = text(&output.stderr);
    assert!(
        stderr.contains(
            "--timed-bus: the network has no [bus], so no bit rate to time the capture's frames at"
        ),
        "{stderr}"
    );
    assert!(output.stdout.is_empty());
}
