//! Value ports on the host: the network file's keys and their errors at file:line:column, the
//! checker (no overlap proof, dead rules still reported), compilation, and the simulator handing
//! over the combined frames (the trace's `delivered` column and the port's timeline).

use pab_core::Frame;
use pab_lang::diagnostic::Source;
use pab_lang::network::Network;
use pab_lang::sim::{self, BusFrame, Options};

const EXAMPLE: &str = include_str!("../../examples/value-ports.toml");

fn parse(text: &str) -> Result<Network, String> {
    Network::parse(Source::new("net.toml", text.to_string())).map_err(|errors| errors.to_string())
}

const HEAD: &str = "[nodes.b]\nid = 1\n[topics.t]\ncan_id = 0x10\n[topics.u]\ncan_id = 0x11\n";

fn with_port(port: &str, rules: (&str, &str)) -> String {
    format!(
        "{HEAD}[ports.\"b.p\"]\n{port}\n[connections.C]\ntopic = \"t\"\nport = \"b.p\"\nst = 1\ntc = 1\n{}\n[connections.D]\ntopic = \"u\"\nport = \"b.p\"\nst = 1\ntc = 1\n{}\n",
        rules.0, rules.1
    )
}

#[test]
fn the_keys_are_read_and_mistakes_reported_where_they_are() {
    let network = parse(&with_port(
        "combine = \"priority\"\nvalue = { offset = 0, size = 2, signed = true, endian = \"big\" }\npriority = { offset = 2, size = 1 }",
        ("", ""),
    ))
    .unwrap();
    let spec = network.ports[0].value.unwrap();
    assert_eq!(spec.combine, pab_core::Combine::Priority);
    assert!(spec.value.signed);
    assert_eq!(spec.value.endian, pab_core::Endian::Big);
    assert_eq!(spec.priority.unwrap().offset, 2);

    let cases = [
        (
            "combine = \"avg\"\nvalue = { offset = 0, size = 2 }",
            "net.toml:8:11: error: combine = \"avg\" is not a combination",
        ),
        (
            "combine = \"max\"\nvalue = { offset = 0, size = 3 }",
            "net.toml:9:30: error: value: size = 3 is not 1, 2 or 4",
        ),
        (
            "combine = \"max\"\nvalue = { offset = 6, size = 4 }",
            "net.toml:9:9: error: value: offset 6 + size 4 = 10 is beyond the 8 bytes of a frame",
        ),
        (
            "combine = \"max\"\nvalue = { offset = 0, size = 2, endian = \"middle\" }",
            "net.toml:9:42: error: value: endian = \"middle\" is not \"little\" or \"big\"",
        ),
        (
            "combine = \"priority\"\nvalue = { offset = 0, size = 2 }",
            "net.toml:8:11: error: combine = \"priority\" needs the field that ranks the frames",
        ),
        (
            "combine = \"sum\"\nvalue = { offset = 0, size = 2 }\npriority = { offset = 2, size = 1 }",
            "net.toml:10:12: error: `priority` is only for `combine = \"priority\"`",
        ),
        (
            "value = { offset = 0, size = 2 }",
            "net.toml:8:9: error: `value` belongs to a value port",
        ),
        (
            "combine = \"min\"",
            "error: a value port needs the field it combines",
        ),
    ];
    for (port, expected) in cases {
        let errors = parse(&with_port(port, ("", ""))).unwrap_err();
        assert!(
            errors.contains(expected),
            "{port:?}: expected {expected:?} in\n{errors}"
        );
    }
}

#[test]
fn too_many_value_connections_on_a_node_are_refused() {
    let mut text = String::from("[nodes.b]\nid = 1\n");
    for k in 0..=pab_core::MAX_VALUE_CONNECTIONS {
        text += &format!("[topics.t{k}]\ncan_id = {}\n", 0x100 + k);
    }
    text += "[ports.\"b.p\"]\ncombine = \"sum\"\nvalue = { offset = 0, size = 1 }\n";
    for k in 0..=pab_core::MAX_VALUE_CONNECTIONS {
        text += &format!("[connections.C{k}]\ntopic = \"t{k}\"\nport = \"b.p\"\nst = 1\ntc = 1\n");
    }
    let errors = parse(&text).unwrap_err();
    assert!(
        errors.contains("its value ports have 17 connections in all, more than 16"),
        "{errors}"
    );
}

#[test]
fn the_checker_skips_the_overlap_proof_but_reports_dead_rules() {
    // Both connections contribute at once: no overlap error on a value port...
    let network = parse(&with_port(
        "combine = \"max\"\nvalue = { offset = 0, size = 1 }",
        ("", ""),
    ))
    .unwrap();
    let report = pab_lang::check::check(&network);
    assert!(report.is_consistent());
    assert!(report.summary(&network).contains("value port (max)"));
    // ... while the same rules on an ordinary port overlap.
    let ordinary = parse(&with_port("", ("", ""))).unwrap();
    assert!(!pab_lang::check::check(&ordinary).is_consistent());
    // A dead rule is still an error.
    let dead = parse(&with_port(
        "combine = \"max\"\nvalue = { offset = 0, size = 1 }",
        ("rule = \"C & !C\"", ""),
    ))
    .unwrap();
    let report = pab_lang::check::check(&dead);
    assert_eq!(report.ports[0].dead, vec![0]);
    let errors = report.errors(&dead);
    assert!(
        errors[0].to_string().contains("C can never deliver"),
        "{}",
        errors[0]
    );
}

fn range(k: u32, t_us: u64, millimetres: u16) -> BusFrame {
    BusFrame {
        t_us,
        frame: Frame::with_raw_id(0x1A0 + k, false, &millimetres.to_le_bytes()).unwrap(),
    }
}

#[test]
fn the_simulator_hands_over_the_minimum_and_ages_sensors_out() {
    let network = parse(EXAMPLE).unwrap();
    let compiled = pab_lang::compile::compile(&network).unwrap();
    let frames = [
        range(0, 0, 900),
        range(1, 10_000, 400),
        range(2, 20_000, 700),
        range(1, 100_000, 400),
        // LEFT again, nearer: it takes over.
        range(0, 200_000, 300),
    ];
    let outcome = sim::run(
        &network,
        &compiled,
        &frames,
        1_000_000,
        &Options::default(),
        &mut |_| {},
    )
    .unwrap();
    let delivered: Vec<(u64, usize)> = outcome
        .rows
        .iter()
        .filter(|row| row.delivered)
        .map(|row| (row.t_us, row.connection))
        .collect();
    // LEFT (0) at 0, FRONT (1) at 10 ms, LEFT again at 200 ms; FRONT's repeat and RIGHT's larger
    // value change nothing.
    assert_eq!(delivered, [(0, 0), (10_000, 1), (200_000, 0)]);
    // LEFT's last frame (200 ms) ages out at 200 ms + τ + 1 µs; FRONT's (100 ms) earlier, at
    // 400 ms + 1 µs, and RIGHT's (20 ms) at 320 ms + 1 µs: after LEFT, nobody.
    let timeline: Vec<(u64, Option<usize>)> = outcome.timelines[0]
        .iter()
        .map(|change| (change.t_us, change.selected))
        .collect();
    assert_eq!(
        timeline,
        [
            (0, None),
            (0, Some(0)),
            (10_000, Some(1)),
            (200_000, Some(0)),
            (500_001, None)
        ]
    );
}
