//! `pab-node`'s start-up errors: each names its cause and exits 2, before any bus traffic. (The
//! node on a live SocketCAN bus is exercised by the hardware-in-the-loop suite; this kernel has
//! no CAN.)

use std::process::Command;

fn pab_node(args: &[&str]) -> (Option<i32>, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_pab-node"))
        .args(args)
        .output()
        .unwrap();
    (
        output.status.code(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn a_missing_interface_is_named_with_a_hint() {
    let (code, stderr) = pab_node(&["--iface", "pabnosuch0", "--node-id", "1"]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("opening CAN interface \"pabnosuch0\""),
        "{stderr}"
    );
    assert!(stderr.contains("ip link show pabnosuch0"), "{stderr}");
}

#[test]
fn node_ids_outside_1_to_127_are_refused() {
    for (id, message) in [
        ("0", "must be in 1..=127"),
        ("128", "must be in 1..=127"),
        ("99999999999999999999", "must be in 1..=127"),
        ("x", "`x` is not a whole number"),
        ("-1", "must be positive"),
    ] {
        let (code, stderr) = pab_node(&["--iface", "pabnosuch0", "--node-id", id]);
        assert_eq!(code, Some(2), "{stderr}");
        assert!(
            stderr.contains("--node-id") && stderr.contains(message),
            "{stderr}"
        );
    }
}

#[test]
fn heartbeat_periods_outside_10_ms_to_1_hour_are_refused() {
    for (period, message) in [
        ("-1", "must be positive"),
        ("9", "must be in 10..=3600000"),
        ("3600001", "must be in 10..=3600000"),
        ("1.5", "not a whole number"),
        ("NaN", "not a whole number"),
    ] {
        let (code, stderr) = pab_node(&[
            "--iface",
            "pabnosuch0",
            "--node-id",
            "1",
            "--heartbeat-ms",
            period,
        ]);
        assert_eq!(code, Some(2), "{stderr}");
        assert!(
            stderr.contains("--heartbeat-ms") && stderr.contains(message),
            "{stderr}"
        );
    }
}

#[test]
fn receive_buffers_outside_8_kib_to_1_gib_are_refused() {
    for (bytes, message) in [
        ("-1", "must be positive"),
        ("8191", "must be in 8192..=1073741824"),
        ("1073741825", "must be in 8192..=1073741824"),
        ("2M", "not a whole number"),
    ] {
        let (code, stderr) =
            pab_node(&["--iface", "pabnosuch0", "--node-id", "1", "--rcvbuf", bytes]);
        assert_eq!(code, Some(2), "{stderr}");
        assert!(
            stderr.contains("--rcvbuf") && stderr.contains(message),
            "{stderr}"
        );
    }
}

#[test]
fn a_missing_boot_table_is_reported_before_the_bus_is_opened() {
    let (code, stderr) = pab_node(&[
        "--iface",
        "pabnosuch0",
        "--node-id",
        "3",
        "--table",
        "/nonexistent/arm.pab",
    ]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("--table /nonexistent/arm.pab: no such file"),
        "{stderr}"
    );
}

#[test]
fn help_shows_the_vcan_recipe() {
    let output = Command::new(env!("CARGO_BIN_EXE_pab-node"))
        .arg("--help")
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&output.stdout);
    assert!(help.contains("ip link add dev vcan0 type vcan"), "{help}");
    assert!(help.contains("--store"), "{help}");
}

/// Runs pab-node and fails if it has not exited within 10 s (a FIFO would block it for ever).
fn pab_node_within_10_s(args: &[&str]) -> (Option<i32>, String) {
    use std::time::{Duration, Instant};
    let mut child = Command::new(env!("CARGO_BIN_EXE_pab-node"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("pab-node {args:?} still running after 10 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let output = child.wait_with_output().unwrap();
    (
        output.status.code(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn a_boot_table_that_is_not_a_regular_file_of_image_size_is_refused_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("fifo.pab");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let big = dir.path().join("big.pab");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(200 << 20)
        .unwrap();
    let folder = dir.path().join("folder.pab");
    std::fs::create_dir(&folder).unwrap();
    for (path, cause) in [
        (&fifo, "a FIFO (named pipe), not a regular file"),
        (
            &big,
            "209715200 bytes, more than the 32768-byte image limit",
        ),
        (&folder, "a directory, not a regular file"),
    ] {
        let table = path.to_str().unwrap();
        let (code, stderr) =
            pab_node_within_10_s(&["--iface", "pabnosuch0", "--node-id", "3", "--table", table]);
        assert_eq!(code, Some(2), "{stderr}");
        assert!(
            stderr.contains(&format!("--table {table}: {cause}")),
            "{stderr}"
        );
        assert!(!stderr.contains("opening CAN interface"), "{stderr}");
    }
}
