//! Gates as rule variables: examples/door-dynamics.toml, whose base runs the door group and
//! whose head reads its Gates frames. Every port delivers exactly while its rule's gates say so,
//! at every step; the head loses the gates 300 ms after a stopped base's last Gates frame; the
//! checker proves gates like connections and takes two gates that exclude each other both ways
//! as never open together; rules naming no gate are errors at their line.

use pab_lang::network::Network;
use pab_lang::sim::{self, Change, DynamicsRow, Options, Outcome};
use pab_lang::{check, compile};
use pab_tests::{example_text, network};

const SEARCH: usize = 0;
const RECOGNISE: usize = 1;
const APPROACH: usize = 2;

fn simulate(network: &Network) -> Outcome {
    let nodes = compile::compile(network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let options = Options {
        dynamics: true,
        ..Options::default()
    };
    sim::simulate(network, &nodes, &options).unwrap_or_else(|error| panic!("{error}"))
}

fn port(network: &Network, name: &str) -> usize {
    network
        .ports
        .iter()
        .position(|p| p.name == name)
        .unwrap_or_else(|| panic!("no port {name}"))
}

fn connection(network: &Network, name: &str) -> usize {
    network
        .connections
        .iter()
        .position(|c| c.name == name)
        .unwrap_or_else(|| panic!("no connection {name}"))
}

/// The port's selected connection at `t_us` (the last change at or before it).
fn selected_at(timeline: &[Change], t_us: u64) -> Option<usize> {
    timeline
        .iter()
        .take_while(|c| c.t_us <= t_us)
        .last()
        .and_then(|c| c.selected)
}

/// Per step t_k, the three gates after k steps.
fn gates(rows: &[DynamicsRow]) -> Vec<(u64, [bool; 3])> {
    let mut out: Vec<(u64, [bool; 3])> = Vec::new();
    for row in rows.iter().filter(|r| r.group == 0) {
        if out.last().is_none_or(|(t, _)| *t != row.t_us) {
            out.push((row.t_us, [false; 3]));
        }
        if let Some((_, g)) = out.last_mut() {
            g[row.behaviour] = row.gate;
        }
    }
    out
}

#[test]
fn every_port_delivers_exactly_while_its_gates_say_so_on_both_nodes() {
    let net = network("door-dynamics.toml", &example_text("door-dynamics"));
    let report = check::check(&net);
    assert!(report.is_consistent());
    let outcome = simulate(&net);
    let (wheels, gaze) = (port(&net, "base.wheels"), port(&net, "head.gaze"));
    let (wander, approach, look) = (
        connection(&net, "WANDER"),
        connection(&net, "APPROACH"),
        connection(&net, "LOOK"),
    );
    let steps = gates(&outcome.dynamics);
    let end = outcome.until_us;
    assert_eq!(steps.len() as u64, end / 1_000 + 1, "0 to the end at 1 ms");
    let mut seen = [false; 3];
    // The commands come every 50 ms from 0 to 3.95 s and hold 0.1 s: active until 4.05 s.
    for &(t, g) in steps.iter().filter(|(t, _)| *t < 4_050_000) {
        let expected_wheels = if g[APPROACH] {
            Some(approach)
        } else if g[SEARCH] {
            Some(wander)
        } else {
            None
        };
        assert_eq!(
            selected_at(&outcome.timelines[wheels], t),
            expected_wheels,
            "base.wheels at {t} µs, gates {g:?}"
        );
        // The head hears the base's Gates at the instant they are sent (a simulated bus).
        let expected_gaze = g[RECOGNISE].then_some(look);
        assert_eq!(
            selected_at(&outcome.timelines[gaze], t),
            expected_gaze,
            "head.gaze at {t} µs, gates {g:?}"
        );
        for (s, &open) in seen.iter_mut().zip(&g) {
            *s |= open;
        }
    }
    assert_eq!(seen, [true; 3], "every gate opened");
    // Gates on the bus: one frame at 0, one at each change, and otherwise a repeat exactly
    // 100 ms after the frame before.
    let times: Vec<u64> = outcome.gates.iter().map(|f| f.t_us).collect();
    let changes: Vec<u64> = steps
        .windows(2)
        .filter(|w| w[0].1 != w[1].1)
        .map(|w| w[1].0)
        .collect();
    assert_eq!(times.first(), Some(&0));
    for w in times.windows(2) {
        assert!(
            changes.contains(&w[1]) || w[1] - w[0] == 100_000,
            "a frame at {} µs, {} after the one before, at no change",
            w[1],
            w[1] - w[0]
        );
    }
    assert!(
        changes.iter().all(|t| times.contains(t)),
        "{changes:?} {times:?}"
    );
    assert!(end - times.last().unwrap() < 100_000);
}

#[test]
fn the_head_closes_the_gates_three_periods_after_a_stopped_base_went_silent() {
    // The base stops at 1.5 s, recognise's gate open.
    let text = example_text("door-dynamics")
        + "\n[[faults]]\nnode = \"base\"\nat = 1.5\nnote = \"the base is switched off\"\n";
    let net = network("door-stopped.toml", &text);
    let outcome = simulate(&net);
    let last = outcome
        .gates
        .iter()
        .map(|f| f.t_us)
        .filter(|&t| t < 1_500_000)
        .max()
        .unwrap();
    assert!(outcome.gates.iter().all(|f| f.t_us < 1_500_000));
    let gaze = &outcome.timelines[port(&net, "head.gaze")];
    let look = connection(&net, "LOOK");
    assert_eq!(selected_at(gaze, 1_499_999), Some(look));
    assert_eq!(selected_at(gaze, last + 299_999), Some(look));
    assert_eq!(selected_at(gaze, last + 300_000), None, "{gaze:?}");
}

#[test]
fn two_gates_that_exclude_each_other_both_ways_are_never_open_together_for_the_checker() {
    let text = example_text("door-dynamics");
    // Without `!door.approach` the wander rule overlaps approach's where both gates are open.
    let overlapping = text.replace(
        "rule = \"WANDER & door.search & !door.approach\"",
        "rule = \"WANDER & door.search\"",
    );
    let net = network("door-overlap.toml", &overlapping);
    let report = check::check(&net);
    assert!(!report.is_consistent());
    let summary = report.summary(&net);
    assert!(summary.contains("INCONSISTENT"), "{summary}");
    let errors = format!("{:?}", report.errors(&net));
    assert!(
        errors.contains("door.search") && errors.contains("door.approach"),
        "{errors}"
    );
    // If approach also pushes search off with γ ≥ 2.5, both cannot be open: consistent.
    let exclusive = overlapping.replace(
        "excludes = [\"recognise\"]\n",
        "excludes = [\"recognise\", \"search\"]\n",
    );
    assert_ne!(exclusive, overlapping);
    let net = network("door-exclusive.toml", &exclusive);
    let report = check::check(&net);
    let summary = report.summary(&net);
    assert!(report.is_consistent(), "{summary}");
    assert!(
        summary.contains("treated as impossible: door.search and door.approach open together"),
        "{summary}"
    );
    // Below 2.5 the argument does not hold: the overlap is back.
    let weak = exclusive.replace("gamma = 3.0", "gamma = 2.4");
    assert!(!check::check(&network("door-weak.toml", &weak)).is_consistent());
}

#[test]
fn the_reading_node_compiles_a_source_and_a_link_and_the_owner_its_group() {
    let net = network("door-dynamics.toml", &example_text("door-dynamics"));
    let nodes = compile::compile(&net).unwrap();
    let image = |name: &str| {
        let node = nodes.iter().find(|n| n.name == name).unwrap();
        pab_core::image::load::<16, 512, 2048>(&node.image)
            .unwrap()
            .table
    };
    let base = image("base");
    assert_eq!(base.dynamics().len(), 1);
    assert_eq!(base.dynamics()[0].contexts.len(), 3);
    // Its own group is read as OWN (0).
    assert_eq!(base.gate_sources().len(), 1);
    assert_eq!(base.gate_sources()[0].owner, pab_core::dynamics::OWN);
    assert_eq!(base.gate_links().len(), 2);
    let head = image("head");
    assert!(head.dynamics().is_empty());
    let source = head.gate_sources()[0];
    assert_eq!((source.owner, source.group, source.behaviours), (5, 0, 3));
    let link = head.gate_links()[0];
    assert_eq!((link.behaviour, link.port), (RECOGNISE as u8, 0));
}

#[test]
fn a_rule_naming_no_gate_is_an_error_at_its_line() {
    let text = example_text("door-dynamics");
    for (rule, expected) in [
        (
            "LOOK & door.nothing",
            "dynamics group `door` has no behaviour `nothing` (its behaviours: search, recognise, approach)",
        ),
        (
            "LOOK & room.search",
            "`room.search` names no dynamics group `room` (declared: door)",
        ),
        ("LOOK & door.", "a `.` in a rule joins a dynamics group"),
    ] {
        let bad = text.replace("LOOK & door.recognise", rule);
        let line = bad
            .lines()
            .position(|l| l.contains(rule))
            .map(|i| i + 1)
            .unwrap();
        let errors = match pab_lang::network::Network::parse(pab_lang::diagnostic::Source::new(
            "door.toml",
            bad.clone(),
        )) {
            Ok(_) => panic!("{rule} accepted"),
            Err(errors) => errors.to_string(),
        };
        assert!(errors.contains(expected), "{rule}: {errors}");
        assert!(
            errors.contains(&format!("door.toml:{line}:")),
            "{rule}: {errors}"
        );
    }
}

#[test]
fn a_topic_context_the_boards_cannot_hold_is_an_error_at_its_key() {
    let text = example_text("door-dynamics");
    for (context, expected) in [
        (
            "{ topic = \"path_clear\", value = { offset = 0, size = 1 }, scale = 0.001, timeout = 0.2 }",
            "scale = 0.001: the divisor of the field, from 1/256 (0.00390625) to 16777215",
        ),
        (
            "{ topic = \"path_clear\", value = { offset = 0, size = 1 }, scale = 255.0, timeout = 4000.0 }",
            "timeout = 4000: how long a frame's value holds, in seconds, from 0.000001 to 3600",
        ),
    ] {
        let bad = text.replace("context = \"PATH\"", &format!("context = {context}"));
        let line = bad
            .lines()
            .position(|l| l.contains(context))
            .map(|i| i + 1)
            .unwrap();
        let errors = match pab_lang::network::Network::parse(pab_lang::diagnostic::Source::new(
            "door.toml",
            bad.clone(),
        )) {
            Ok(_) => panic!("{context} accepted"),
            Err(errors) => errors.to_string(),
        };
        assert!(errors.contains(expected), "{errors}");
        assert!(errors.contains(&format!("door.toml:{line}:")), "{errors}");
    }
    // At the limits: accepted, and compiled.
    let good = text.replace(
        "context = \"PATH\"",
        "context = { topic = \"path_clear\", value = { offset = 0, size = 1 }, scale = 0.00390625, timeout = 3600.0 }",
    );
    let net = network("door-limits.toml", &good);
    compile::compile(&net).unwrap_or_else(|errors| panic!("{errors:?}"));
}
