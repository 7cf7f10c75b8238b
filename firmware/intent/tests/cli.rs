//! `pab-intent`'s command line: its help, and the start-up errors, each naming its cause (the
//! file, and the line for a mistake in it) with exit status 2, before any bus traffic.

use std::process::{Command, Output};

fn pab_intent(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pab-intent"))
        .args(args)
        .env("RUST_LOG", "off")
        .output()
        .unwrap()
}

fn example(name: &str) -> String {
    format!("{}/../../examples/{name}.toml", env!("CARGO_MANIFEST_DIR"))
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn help_says_what_it_does_and_how_to_run_it() {
    let output = pab_intent(&["--help"]);
    assert_eq!(output.status.code(), Some(0));
    let help = String::from_utf8_lossy(&output.stdout);
    for needle in [
        "--interface",
        "--network",
        "Desire",
        "FilterSet",
        "every reduction first",
        "Intention",
        "restart",
        "FilterRefused",
    ] {
        assert!(help.contains(needle), "--help lacks {needle}:\n{help}");
    }
}

#[test]
fn start_up_errors_name_their_cause() {
    let missing = pab_intent(&["--interface", "vcan0", "--network", "/nonexistent/net.toml"]);
    assert_eq!(missing.status.code(), Some(2));
    assert!(
        stderr(&missing).contains("/nonexistent/net.toml"),
        "{}",
        stderr(&missing)
    );

    let figure = example("figure-1");
    let no_hbba = pab_intent(&["--interface", "vcan0", "--network", &figure]);
    assert_eq!(no_hbba.status.code(), Some(2));
    assert!(
        stderr(&no_hbba).contains("figure-1.toml: the network has no [hbba] section"),
        "{}",
        stderr(&no_hbba)
    );

    let dir = std::env::temp_dir().join(format!("pab-intent-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    let text = std::fs::read_to_string(example("tour-guide"))
        .unwrap()
        .replace(
            "utility = 3\ncosts = { cpu = 40 }",
            "utility = -3\ncosts = { cpu = 40 }",
        );
    std::fs::write(&bad, text).unwrap();
    let invalid = pab_intent(&["--interface", "vcan0", "--network", bad.to_str().unwrap()]);
    assert_eq!(invalid.status.code(), Some(2));
    assert!(
        stderr(&invalid).contains("bad.toml:") && stderr(&invalid).contains("utility = -3"),
        "{}",
        stderr(&invalid)
    );

    let tour = example("tour-guide");
    let no_bus = pab_intent(&["--interface", "nosuchcan9", "--network", &tour]);
    assert_eq!(no_bus.status.code(), Some(2));
    assert!(
        stderr(&no_bus).contains("opening CAN interface \"nosuchcan9\""),
        "{}",
        stderr(&no_bus)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The desire the help's example sends with cansend is what it says: node 9, class 2 (the tour
/// guide's `voice`), intensity 3, a lease of 10 s.
#[test]
fn the_help_example_frame_is_the_desire_it_claims() {
    use pab_core::protocol::{BROADCAST, DesireFrame, Message};
    let output = pab_intent(&["--help"]);
    let help = String::from_utf8_lossy(&output.stdout);
    let line = help
        .split_whitespace()
        .find(|word| word.contains('#') && word.len() > 10)
        .expect("a cansend example");
    let (id, data) = line.split_once('#').unwrap();
    let id = u32::from_str_radix(id, 16).unwrap();
    let data: Vec<u8> = (0..data.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&data[i..i + 2], 16).unwrap())
        .collect();
    let frame = pab_core::Frame::with_raw_id(id, true, &data).unwrap();
    let (id, message) = Message::decode(&frame).unwrap();
    assert_eq!((id.source, id.destination), (9, BROADCAST));
    assert_eq!(
        message,
        Message::Desire(DesireFrame {
            class: 2,
            intensity: 3,
            lease_ms: 10_000,
            id: 1
        })
    );
    let tour = std::fs::read_to_string(example("tour-guide")).unwrap();
    let network = pab_lang::network::Network::parse(pab_lang::diagnostic::Source::new(
        "tour-guide.toml",
        tour,
    ))
    .unwrap();
    assert_eq!(network.hbba.unwrap().classes[2], "voice");
    // The book gives the same line.
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/nodes.md"))
            .unwrap();
    assert!(readme.contains(&format!("cansend vcan0 {line}")));
}
