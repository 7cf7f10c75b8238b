//! HBBA's tour guide (examples/tour-guide.toml) in the simulator: its scripted `[[desires]]`
//! through the intention workspace, the paper's scenario from the simulation's output (touring:
//! every detector at full rate; a loud noise: face detection throttled and QR detection closed,
//! then voice localisation opened; the noise gone: back), the plot's lanes, and the `[[desires]]`
//! keys' mistakes at their lines.

use pab_lang::diagnostic::Source;
use pab_lang::network::Network;
use pab_lang::sim::{self, IntentionRun, Options};
use pab_lang::{check, compile};
use pab_tests::example_text;

fn tour_guide() -> (Network, IntentionRun, sim::Outcome) {
    let network = Network::parse(Source::new("tour-guide.toml", example_text("tour-guide")))
        .unwrap_or_else(|errors| panic!("{errors}"));
    assert!(check::check(&network).is_consistent());
    let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let outcome = sim::simulate(&network, &nodes, &Options::default())
        .unwrap_or_else(|error| panic!("{error}"));
    let run = outcome
        .intention
        .clone()
        .expect("the tour guide has [hbba]");
    (network, run, outcome)
}

fn strategy(network: &Network, name: &str) -> u64 {
    let hbba = network.hbba.as_ref().unwrap();
    1 << hbba.strategies.iter().position(|s| s.name == name).unwrap()
}

fn connection(network: &Network, name: &str) -> usize {
    network
        .connections
        .iter()
        .position(|c| c.name == name)
        .unwrap()
}

const S: u64 = 1_000_000;

#[test]
fn a_loud_noise_throttles_faces_closes_qr_then_opens_voice_and_back() {
    let (network, run, _) = tour_guide();
    let s = |name| strategy(&network, name);
    let touring = s("face_full") | s("qr_full") | s("nav_follow") | s("avoid_laser");
    let noise = s("face_throttled") | s("voice_localise") | s("nav_follow") | s("avoid_laser");
    let changes: Vec<(u64, u64, u64)> = run
        .selections
        .iter()
        .map(|c| (c.t_us, c.strategies, c.objective))
        .collect();
    // The intention node's first solve, as it starts (nothing desired yet); touring at once
    // (objective 2·3 + 1·2 + 2·2), the noise from 8 s to 12 s (3·3 + 2·2 + 2·2), touring again,
    // nothing once the tour ends at 20 s.
    assert_eq!(
        changes,
        [
            (0, 0, 0),
            (0, touring, 12),
            (8 * S, noise, 17),
            (12 * S, touring, 12),
            (20 * S, 0, 0)
        ]
    );

    let (face, qr, voice) = (
        connection(&network, "FACE"),
        connection(&network, "QR"),
        connection(&network, "VOICE"),
    );
    // At 8 s, in this order: the reductions (FACE to 1 in 3, QR closed), then the increase
    // (VOICE opened), on the head node (id 1), port head.gaze 0 / head.display 1.
    let at_noise: Vec<(usize, u8, bool)> = run
        .commands
        .iter()
        .filter(|c| c.t_us == 8 * S)
        .map(|c| (c.connection, c.set.phi, c.reduction))
        .collect();
    assert_eq!(
        at_noise,
        [(face, 3, true), (qr, 0, true), (voice, 1, false)]
    );
    let voice_command = run
        .commands
        .iter()
        .find(|c| c.t_us == 8 * S && c.connection == voice)
        .unwrap();
    assert_eq!(
        (
            voice_command.node,
            voice_command.set.port,
            voice_command.set.connection
        ),
        (1, 0, 1)
    );
    // At 12 s the reverse: VOICE closed first, then FACE and QR back to full rate.
    let at_quiet: Vec<(usize, u8, bool)> = run
        .commands
        .iter()
        .filter(|c| c.t_us == 12 * S)
        .map(|c| (c.connection, c.set.phi, c.reduction))
        .collect();
    assert_eq!(
        at_quiet,
        [(voice, 0, true), (face, 1, false), (qr, 1, false)]
    );

    // The commanded φ over time.
    for (t, phis) in [
        (S, [1, 1, 0]),
        (9 * S, [3, 0, 1]),
        (13 * S, [1, 1, 0]),
        (20 * S, [0, 0, 0]),
    ] {
        assert_eq!(
            [face, qr, voice].map(|c| run.phi_at(c, t)),
            phis,
            "at {t} µs"
        );
    }
    assert!(run.notes.is_empty(), "{:?}", run.notes);
}

#[test]
fn the_plot_gets_a_lane_per_strategy_and_per_filtered_connection() {
    let (network, _, outcome) = tour_guide();
    let data = outcome.plot_data(&network, "tour guide");
    assert_eq!(data.lanes.len(), 2);
    let names: Vec<&str> = data.lanes[0]
        .lanes
        .iter()
        .map(|l| l.name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "face_full",
            "face_throttled",
            "qr_full",
            "voice_localise",
            "nav_follow",
            "avoid_laser"
        ]
    );
    let filters: Vec<&str> = data.lanes[1]
        .lanes
        .iter()
        .map(|l| l.name.as_str())
        .collect();
    assert_eq!(filters, ["FACE", "QR", "VOICE", "NAV", "AVOID"]);
    // FACE's pass rate: 1 from 0 s, a third from 8 s, 1 from 12 s, 0 from 20 s.
    let face: Vec<(f64, f64)> = data.lanes[1].lanes[0]
        .steps
        .iter()
        .map(|s| (s.t, s.value))
        .collect();
    assert_eq!(
        face,
        [(0.0, 1.0), (8.0, 1.0 / 3.0), (12.0, 1.0), (20.0, 0.0)]
    );
    let face_throttled: Vec<(f64, f64)> = data.lanes[0].lanes[1]
        .steps
        .iter()
        .map(|s| (s.t, s.value))
        .filter(|s| s.1 > 0.0)
        .collect();
    assert_eq!(face_throttled, [(8.0, 1.0)]);
}

/// The tour guide, then a `[[desires]]` after an empty line; the line of its first key.
fn with_desire(desire: &str) -> (String, usize) {
    let text = example_text("tour-guide");
    let line = text.lines().count() + 3;
    (format!("{text}\n[[desires]]\n{desire}"), line)
}

#[test]
fn desire_mistakes_are_reported_at_their_lines() {
    let cases = [
        (
            "class = \"dance\"\nintensity = 1\nfrom = 0.0\nto = 1.0\n",
            0,
            9,
            "desire for class `dance`, which no strategy has (classes: face, qr, voice, nav, avoid)",
        ),
        (
            "class = \"face\"\nintensity = 0\nfrom = 0.0\nto = 1.0\n",
            1,
            13,
            "intensity = 0: a whole number, 1 to 65535",
        ),
        (
            "class = \"face\"\nintensity = 65536\nfrom = 0.0\nto = 1.0\n",
            1,
            13,
            "intensity = 65536: a whole number, 1 to 65535",
        ),
        (
            "class = \"face\"\nintensity = 1\nfrom = 2.0\nto = 2.0\n",
            3,
            6,
            "`to` (2) must be after `from` (2)",
        ),
        (
            "class = \"face\"\nintensity = 1\nfrom = -1.0\nto = 2.0\n",
            2,
            8,
            "from must be a time in [0, 1000000] seconds",
        ),
    ];
    for (desire, offset, column, message) in cases {
        let (text, line) = with_desire(desire);
        let errors = Network::parse(Source::new("net.toml", text))
            .unwrap_err()
            .to_string();
        let expected = format!("net.toml:{}:{column}: error: {message}", line + offset);
        assert!(
            errors.contains(&expected),
            "expected {expected:?}, got:\n{errors}"
        );
    }
    // At most 32: the workspace's capacity.
    let mut text = example_text("tour-guide");
    // The 33rd is the 29th added: its header 2 lines after the file's end, then 6 lines each.
    let first_extra = text.lines().count() + 2 + 28 * 6;
    for _ in 0..29 {
        text.push_str("\n[[desires]]\nclass = \"qr\"\nintensity = 1\nfrom = 0.0\nto = 1.0\n");
    }
    let errors = Network::parse(Source::new("net.toml", text))
        .unwrap_err()
        .to_string();
    assert!(
        errors.contains(&format!(
            "net.toml:{first_extra}:1: error: more than 32 [[desires]]: the intention workspace holds at most 32 desires"
        )),
        "{errors}"
    );
    // Exactly these keys.
    let (text, _) =
        with_desire("class = \"face\"\nintensity = 1\nfrom = 0.0\nto = 1.0\nlease = 3\n");
    let errors = Network::parse(Source::new("net.toml", text))
        .unwrap_err()
        .to_string();
    assert!(errors.contains("unknown key `lease`"), "{errors}");
    let (text, _) = with_desire("class = \"face\"\nintensity = 1\nfrom = 0.0\n");
    let errors = Network::parse(Source::new("net.toml", text))
        .unwrap_err()
        .to_string();
    assert!(errors.contains("missing key `to`"), "{errors}");
    // Without [hbba].
    let text =
        "[nodes.a]\nid = 1\n[[desires]]\nclass = \"face\"\nintensity = 1\nfrom = 0.0\nto = 1.0\n";
    let errors = Network::parse(Source::new("net.toml", text.to_string()))
        .unwrap_err()
        .to_string();
    assert!(
        errors.contains("net.toml:3:1: error: [[desires]] are for HBBA's intention solver: the file has no [hbba] section"),
        "{errors}"
    );
}

#[test]
fn a_stopped_node_does_not_answer_and_its_commands_are_given_up() {
    let text = example_text("tour-guide").replace(
        "[[phases]]\nname = \"touring\"\nfrom = 0.0",
        "[[faults]]\nnode = \"head\"\nat = 5.0\n\n[[phases]]\nname = \"touring\"\nfrom = 0.0",
    );
    let network =
        Network::parse(Source::new("tour-guide.toml", text)).unwrap_or_else(|e| panic!("{e}"));
    let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let outcome = sim::simulate(&network, &nodes, &Options::default()).unwrap();
    let run = outcome.intention.unwrap();
    let voice = connection(&network, "VOICE");
    // At 8 s the head has stopped: its reductions go unanswered, are sent three times 250 ms
    // apart, then given up; the increase (VOICE) follows.
    let sends: Vec<u64> = run
        .commands
        .iter()
        .filter(|c| c.connection == connection(&network, "QR") && (8 * S..9 * S).contains(&c.t_us))
        .map(|c| c.t_us)
        .collect();
    assert_eq!(sends, [8 * S, 8 * S + 250_000, 8 * S + 500_000]);
    let opened = run
        .commands
        .iter()
        .find(|c| c.connection == voice && c.set.phi == 1)
        .unwrap();
    assert_eq!(opened.t_us, 8 * S + 750_000);
    assert!(
        run.notes.iter().any(|(t, note)| *t == 8 * S + 750_000
            && note == "node 1 did not answer QR (head.display) φ 0 after 3 sends (stopped)"),
        "{:?}",
        run.notes
    );
}

/// What FilterSet addresses (node, port in the node's order, index in the port) is where the
/// compiled table has the connection's topic: the boards' numbering.
#[test]
fn filter_targets_follow_the_compiled_tables() {
    let (network, _, _) = tour_guide();
    let targets = network.filter_targets().unwrap();
    let names: Vec<(&str, u8, u8, u8)> = targets
        .iter()
        .map(|t| {
            let c = &network.connections[usize::from(t.connection)];
            (c.name.as_str(), t.node, t.port, t.index)
        })
        .collect();
    assert_eq!(
        names,
        [
            ("FACE", 1, 0, 0),
            ("QR", 1, 1, 0),
            ("VOICE", 1, 0, 1),
            ("NAV", 2, 0, 0),
            ("AVOID", 2, 0, 1)
        ]
    );
    let compiled = compile::compile(&network).unwrap();
    for target in &targets {
        let image = &compiled.iter().find(|c| c.id == target.node).unwrap().image;
        let loaded: pab_core::image::Loaded = pab_core::image::load(image).unwrap();
        let port = loaded.table.port(usize::from(target.port)).unwrap();
        let in_table = port.connections[usize::from(target.index)].filter;
        let connection = &network.connections[usize::from(target.connection)];
        assert_eq!(
            in_table, network.topics[connection.topic].filter,
            "{}",
            connection.name
        );
    }
}
