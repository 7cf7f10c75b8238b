//! `pab-intent`'s command line: its help, and the start-up errors, each naming its cause (the
//! setup file, and the line and column for a mistake in it) with exit status 2, before any bus
//! traffic.

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

/// The tour guide's setup as `pabctl compile` writes it.
fn tour_guide_setup() -> String {
    let text = std::fs::read_to_string(example("tour-guide")).unwrap();
    let network = pab_lang::network::Network::parse(pab_lang::diagnostic::Source::new(
        "tour-guide.toml",
        text,
    ))
    .unwrap();
    pab_lang::compile::intention_setup(&network)
        .unwrap()
        .to_json()
}

#[test]
fn help_says_what_it_does_and_how_to_run_it() {
    let output = pab_intent(&["--help"]);
    assert_eq!(output.status.code(), Some(0));
    let help = String::from_utf8_lossy(&output.stdout);
    for needle in [
        "--interface",
        "--setup",
        "pabctl compile",
        "intention.json",
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
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path.to_str().unwrap().to_string()
    };
    let run = |setup: &str| pab_intent(&["--interface", "vcan0", "--setup", setup]);

    let missing = run("/nonexistent/intention.json");
    assert_eq!(missing.status.code(), Some(2));
    for needle in ["/nonexistent/intention.json", "pabctl compile"] {
        assert!(stderr(&missing).contains(needle), "{}", stderr(&missing));
    }

    // A network file where the setup belongs: not JSON, said with the line and column.
    let network = run(&example("tour-guide"));
    assert_eq!(network.status.code(), Some(2));
    assert!(
        stderr(&network).contains("tour-guide.toml: not an intention setup")
            && stderr(&network).contains("line 1"),
        "{}",
        stderr(&network)
    );

    let good = tour_guide_setup();
    let other = write(
        "other.json",
        &good.replace("pab intention setup 1", "pab intention setup 9"),
    );
    let other = run(&other);
    assert_eq!(other.status.code(), Some(2));
    assert!(
        stderr(&other).contains("\"pab intention setup 9\"")
            && stderr(&other).contains("compile the network again"),
        "{}",
        stderr(&other)
    );

    // A resource of capacity 0: the solver refuses the instance.
    let capacity = good.replacen(
        "\"capacities\": [\n      100,",
        "\"capacities\": [\n      0,",
        1,
    );
    assert_ne!(capacity, good);
    let capacity = run(&write("capacity.json", &capacity));
    assert_eq!(capacity.status.code(), Some(2));
    assert!(
        stderr(&capacity).contains("capacity.json: [hbba]:"),
        "{}",
        stderr(&capacity)
    );

    let tour = write("intention.json", &good);
    let no_bus = pab_intent(&["--interface", "nosuchcan9", "--setup", &tour]);
    assert_eq!(no_bus.status.code(), Some(2));
    assert!(
        stderr(&no_bus).contains("opening CAN interface \"nosuchcan9\""),
        "{}",
        stderr(&no_bus)
    );
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
