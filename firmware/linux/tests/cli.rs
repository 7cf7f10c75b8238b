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
    for id in ["0", "128", "x"] {
        let (code, stderr) = pab_node(&["--iface", "pabnosuch0", "--node-id", id]);
        assert_eq!(code, Some(2), "{stderr}");
        assert!(stderr.contains("--node-id"), "{stderr}");
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
        stderr.contains("cannot read /nonexistent/arm.pab"),
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
