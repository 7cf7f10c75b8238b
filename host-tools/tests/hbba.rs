//! HBBA on the host: the network file's `[hbba]` keys and the topics' `rate_hz`, every mistake
//! at its file:line:column, the bus cost computed from the filters, and `pabctl solve` as a user
//! runs it (the tour-guide example, its text and JSON answers, exit statuses, help).

use std::path::Path;
use std::process::{Command, Output};

use pab_lang::diagnostic::Source;
use pab_lang::network::{Network, bus_cost, bus_cost_at};

fn parse(text: &str) -> Result<Network, String> {
    Network::parse(Source::new("net.toml", text.to_string())).map_err(|errors| errors.to_string())
}

/// Lines 1-16: a node, two topics (11-bit at 30 Hz, 29-bit at 100 Hz), a port, C and D.
const HEAD: &str = "\
[nodes.b]
id = 1
[topics.t]
can_id = 0x10
rate_hz = 30.0
[topics.u]
can_id = 0x1000
extended = true
rate_hz = 100
[ports.\"b.p\"]
[connections.C]
topic = \"t\"
port = \"b.p\"
st = 1
tc = 1
rule = \"C & !D\"
[connections.D]
topic = \"u\"
port = \"b.p\"
st = 1
tc = 1
";

/// HEAD (21 lines), then `hbba` from line 22.
fn with(hbba: &str) -> String {
    format!("{HEAD}{hbba}")
}

const STRATEGIES: &str = "\
[hbba]
resources = { cpu = 100, bus = 10 }
bitrate = 125000
[hbba.strategies.c_full]
class = \"c\"
utility = 3
costs = { cpu = 60 }
filters = { C = 1 }
[hbba.strategies.c_low]
class = \"c\"
utility = 1
costs = { cpu = 10 }
filters = { C = 3 }
[hbba.strategies.d_on]
class = \"d\"
utility = 2
costs = { cpu = 50 }
filters = { D = 1, C = 3 }
requires = { c = 1 }
";

#[test]
fn the_section_is_read_in_file_order_with_computed_bus_costs() {
    let network = parse(&with(&STRATEGIES.replace("bus = 10", "bus = 20"))).unwrap();
    let t = &network.topics[0];
    assert_eq!((t.rate_hz, t.rate_uhz), (Some(30.0), Some(30_000_000)));
    assert_eq!(network.topics[1].rate_uhz, Some(100_000_000));
    let hbba = network.hbba.as_ref().unwrap();
    assert_eq!(hbba.classes, ["c", "d"]);
    let names: Vec<&str> = hbba.resources.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["cpu", "bus"]);
    assert_eq!(hbba.bitrate, Some(125_000));
    assert_eq!(hbba.bus(), Some(1));
    // c_full: 30 Hz × 135 bits = 4050 bit/s = 3.24 % of 125 kbit/s -> 4.
    // c_low: 10 Hz × 135 = 1350 bit/s = 1.08 % -> 2.
    // d_on: 100 Hz × 160 (29-bit) = 16 000 + 1350 = 17 350 bit/s = 13.88 % -> 14 (above the
    // bus = 10 of STRATEGIES: refused, see below).
    let costs: Vec<&[u32]> = hbba.strategies.iter().map(|s| s.costs.as_slice()).collect();
    assert_eq!(costs, [&[60, 4][..], &[10, 2], &[50, 14]]);
    let d_on = &hbba.strategies[2];
    assert_eq!(d_on.class, 1);
    assert_eq!(d_on.requires, [(0, 1)]);
    let filters: Vec<(&str, usize, u16)> = d_on
        .filters
        .iter()
        .map(|f| (f.name.as_str(), f.connection, f.phi))
        .collect();
    assert_eq!(filters, [("D", 1, 1), ("C", 0, 3)]);
    // The solver's instance: the same numbers.
    let instance = hbba.instance();
    assert_eq!(instance.classes, 2);
    assert_eq!(instance.capacities.as_slice(), [100, 20]);
    assert_eq!(instance.strategies[2].costs[..2], [50, 14]);
    // d=2, c=1: d_on needs C at φ 3, so c_low (1) with d_on (4): 5; c_full alone 3.
    let intensities = hbba.intensities("c=1, d=2").unwrap();
    let solved = hbba
        .solve(&intensities, pab_core::hbba::DEFAULT_BUDGET)
        .unwrap();
    assert_eq!(solved.strategies, [1, 2]);
    assert_eq!(solved.objective, 5);
    assert_eq!(solved.usage, [60, 16]);
}

#[test]
fn the_bus_cost_is_rounded_up_per_strategy_and_closed_filters_cost_nothing() {
    // 30 Hz, φ 1, 11-bit: 4050 bit/s of 500 kbit/s = 0.81 % -> 1.
    assert_eq!(bus_cost(&[(30_000_000, 1, false, 8)], 500_000), 1);
    // Exactly 1 %: 5000 bit/s = 1 %, not 2.
    assert_eq!(bus_cost(&[(37_037_037, 1, false, 8)], 500_000), 1);
    assert_eq!(
        bus_cost(&[(1_000_000 * 5000 / 135 + 1, 1, false, 8)], 500_000),
        2
    );
    // 100 Hz through φ 3 on a 29-bit id: 33.3 Hz × 160 = 5333.3 bit/s of 125 kbit/s = 4.27 % -> 5.
    assert_eq!(bus_cost(&[(100_000_000, 3, true, 8)], 125_000), 5);
    // φ 0 closes: nothing on the bus.
    assert_eq!(bus_cost(&[(100_000_000, 0, true, 8)], 125_000), 0);
    assert_eq!(bus_cost(&[], 125_000), 0);
    // A 2-byte frame on an 11-bit id: 55 + 10·2 = 75 bits; 100 Hz of them, 7 500 bit/s of
    // 500 kbit/s = 1.5 % -> 2, where 8-byte frames would cost 2.7 % -> 3.
    assert_eq!(bus_cost(&[(100_000_000, 1, false, 2)], 500_000), 2);
    assert_eq!(bus_cost(&[(100_000_000, 1, false, 8)], 500_000), 3);
    // Several connections: summed, then rounded: 2 × 0.81 % = 1.62 % -> 2.
    assert_eq!(
        bus_cost(
            &[(30_000_000, 1, false, 8), (30_000_000, 1, false, 8)],
            500_000
        ),
        2
    );
}

/// On a CAN FD bus the bus cost is the share of the bus's time: a CAN FD topic's frames take
/// their CAN FD time (the data phase at the data rate), classic ones as on a classic bus.
#[test]
fn on_a_can_fd_bus_the_cost_is_the_share_of_the_bus_time() {
    // Classic frames: bus_cost's, whatever the data rate.
    for frames in [
        &[(30_000_000u64, 1u16, false, 8u8)][..],
        &[(100_000_000, 3, true, 8), (30_000_000, 1, false, 2)],
    ] {
        let classic: Vec<_> = frames
            .iter()
            .map(|&(r, p, e, l)| (r, p, e, l, false))
            .collect();
        assert_eq!(
            bus_cost_at(&classic, 500_000, Some(2_000_000)),
            bus_cost(frames, 500_000)
        );
        assert_eq!(
            bus_cost_at(&classic, 125_000, None),
            bus_cost(frames, 125_000)
        );
    }
    // 100 Hz of 64-byte CAN FD frames, 11-bit id, at 500 kbit/s and 2 Mbit/s: 32 nominal bits
    // (64 µs) and 680 data bits (340 µs), 404 µs each: 4.04 % -> 5. Without switching (the data
    // rate 500 kbit/s): 712 bits, 1.424 ms each: 14.24 % -> 15.
    assert_eq!(
        bus_cost_at(
            &[(100_000_000, 1, false, 64, true)],
            500_000,
            Some(2_000_000)
        ),
        5
    );
    assert_eq!(
        bus_cost_at(&[(100_000_000, 1, false, 64, true)], 500_000, Some(500_000)),
        15
    );
    // In a file: the topic `t` as a CAN FD topic of 64 bytes on a CAN FD bus. c_full: 30 Hz
    // × 404 µs = 1.212 % of the time -> 2 (classic 8-byte frames at 125 kbit/s: 4).
    let fd = with(&STRATEGIES.replace("bitrate = 125000\n", ""))
        .replace("can_id = 0x10\n", "can_id = 0x10\nfd = true\nlength = 64\n");
    let network = parse(&format!(
        "[bus]\nbitrate = 500000\ndata_bitrate = 2000000\n{fd}"
    ))
    .unwrap();
    let hbba = network.hbba.as_ref().unwrap();
    assert_eq!(hbba.strategies[0].costs, [60, 2]);
}

#[test]
fn every_mistake_is_reported_at_its_line() {
    let base = with(&STRATEGIES.replace("bus = 10", "bus = 20"));
    let cases: Vec<(String, &str)> = vec![
        (
            base.replace("rate_hz = 30.0", "rate_hz = -1"),
            "net.toml:5:11: error: rate_hz = -1: frames per second, positive, at most 100000",
        ),
        (
            base.replace("rate_hz = 30.0", "rate_hz = 2e5"),
            "net.toml:5:11: error: rate_hz = 200000: frames per second",
        ),
        (
            base.replace("rate_hz = 30.0\n", ""),
            "net.toml:28:13: error: strategy `c_full` lets frames of `C` through, but its topic `t` has no `rate_hz`",
        ),
        (
            base.replace("cpu = 100, bus", "cpu = 0, bus"),
            "net.toml:23:21: error: resource `cpu` = 0: a capacity is a whole number, 1 to 4294967295",
        ),
        (
            base.replace("bus = 20", "bus = 101"),
            "net.toml:23:32: error: resource `bus` = 101: the bus's capacity is a percentage of `bitrate`, 1 to 100",
        ),
        (
            base.replace("bitrate = 125000\n", ""),
            "net.toml:23:13: error: the `bus` resource is a percentage of the bus's bit rate: add `bitrate = 500000`",
        ),
        (
            base.replace("bitrate = 125000", "bitrate = 2000000"),
            "net.toml:24:11: error: bitrate = 2000000: bit/s, 1 to 1000000",
        ),
        (
            base.replace(", bus = 20", ""),
            "net.toml:24:11: error: `bitrate` goes with a `bus` resource",
        ),
        (
            base.replace("class = \"c\"\nutility = 3\n", "utility = 3\n"),
            "net.toml:25:18: error: strategy `c_full`: missing field `class`",
        ),
        (
            base.replace("utility = 3\n", ""),
            "net.toml:25:18: error: strategy `c_full`: missing field `utility`",
        ),
        (
            base.replace("utility = 3", "utility = 65536"),
            "net.toml:27:11: error: utility = 65536: a whole number, 0 to 65535",
        ),
        (
            base.replace("costs = { cpu = 60 }", "costs = { gpu = 60 }"),
            "net.toml:28:11: error: strategy `c_full` costs `gpu`, which is not a resource of [hbba] (resources: cpu, bus)",
        ),
        (
            base.replace("costs = { cpu = 60 }", "costs = { cpu = 60, bus = 3 }"),
            "net.toml:28:21: error: strategy `c_full`: the bus cost is computed from the rates its filters let through",
        ),
        (
            base.replace("costs = { cpu = 60 }", "costs = { cpu = -1 }"),
            "net.toml:28:17: error: cost -1 of `cpu`: a whole number, 0 to 4294967295",
        ),
        (
            base.replace("filters = { C = 1 }", "filters = { X = 1 }"),
            "net.toml:29:13: error: strategy `c_full` filters `X`, which is not a connection (connections: C, D)",
        ),
        (
            base.replace("filters = { C = 1 }", "filters = { C = 256 }"),
            "net.toml:29:17: error: φ = 256 for `C`: 0 closes, 1 passes every frame, N one frame in N (up to 255, the boards' filters count in one byte)",
        ),
        (
            base.replace("requires = { c = 1 }", "requires = { e = 1 }"),
            "net.toml:40:14: error: strategy `d_on` requires class `e`, which no strategy has (classes: c, d)",
        ),
        (
            base.replace("requires = { c = 1 }", "requires = { d = 1 }"),
            "net.toml:40:14: error: strategy `d_on` requires its own class `d`",
        ),
        (
            base.replace("requires = { c = 1 }", "requires = { c = -2 }"),
            "net.toml:40:18: error: minimum utility -2 for class `c`: a whole number, 0 to 65535",
        ),
        (
            base.replace("[hbba.strategies.c_low]", "[hbba.strategies.\"c low\"]"),
            "net.toml:30:18: error: strategy name `c low`: use letters, digits, `_` and `-`",
        ),
        (
            base.replace("class = \"d\"", "class = \"d d\""),
            "net.toml:36:9: error: class name `d d`: use letters, digits, `_` and `-`",
        ),
        (
            base.replace(
                "[hbba.strategies.c_low]",
                "[hbba.strategies.c_low]\nflavour = 1",
            ),
            "net.toml:31:1: error: unknown key `flavour`",
        ),
        (
            base.replace("resources = {", "resource = {"),
            "unknown key `resource`",
        ),
        (
            base.replace("rate_hz = 30.0", "rate = 30.0"),
            "net.toml:5:1: error: unknown key `rate`",
        ),
        (
            base.replace("[nodes.b]\nid = 1", "[nodes.b]\nid = 126"),
            "net.toml:1:1: error: node `b` has id 126, the intention node's address in a network with [hbba]: use another id",
        ),
    ];
    for (text, expected) in &cases {
        let errors = parse(text).unwrap_err();
        assert!(
            errors.contains(expected),
            "expected {expected:?}, got:\n{errors}"
        );
    }
}

/// A strategy that can never fit is refused at its header: a cost above a capacity, or a bus
/// share above the bus's.
#[test]
fn a_strategy_that_can_never_fit_is_refused_at_its_line() {
    let errors = parse(&with(STRATEGIES)).unwrap_err();
    assert!(
        errors.contains(
            "net.toml:35:18: error: strategy `d_on` can never be selected: its filters let through 14 % of 125000 bit/s on the bus, above the bus's capacity of 10 %"
        ),
        "{errors}"
    );
    let errors = parse(&with(
        &STRATEGIES
            .replace("bus = 10", "bus = 20")
            .replace("cpu = 60", "cpu = 160"),
    ))
    .unwrap_err();
    assert!(
        errors.contains(
            "net.toml:25:18: error: strategy `c_full` can never be selected: it costs 160 of `cpu`, above its capacity of 100"
        ),
        "{errors}"
    );
    // A closed filter costs nothing on the bus: d_on with D closed fits.
    let network = parse(&with(&STRATEGIES.replace("D = 1, C = 3", "D = 0, C = 3"))).unwrap();
    assert_eq!(network.hbba.unwrap().strategies[2].costs, [50, 2]);
}

/// The solver's capacities are checked at the line that exceeds them.
#[test]
fn capacities_are_reported_where_they_are_exceeded() {
    let mut text = with("[hbba]\nresources = { cpu = 100 }\n");
    for i in 0..65 {
        text += &format!(
            "[hbba.strategies.s{i}]\nclass = \"k{}\"\nutility = 1\n",
            i % 17
        );
    }
    let errors = parse(&text).unwrap_err();
    // Class k16 first appears with s16, whose class is at line 24 + 3·16 + 1; it is reported
    // there only.
    assert_eq!(errors.matches("17th class").count(), 1, "{errors}");
    assert!(
        errors.contains("net.toml:73:9: error: strategy `s16`: class `k16` is a 17th class; the intention solver takes at most 16"),
        "{errors}"
    );
    assert!(
        errors.contains("net.toml:216:18: error: strategy `s64` is the 65th: the intention solver takes at most 64"),
        "{errors}"
    );
    let many = with(
        "[hbba]\nresources = { a = 1, b = 1, c = 1, d = 1, e = 1, f = 1, g = 1, h = 1, i = 1 }\n",
    );
    let errors = parse(&many).unwrap_err();
    assert!(
        errors.contains("net.toml:23:13: error: 9 resources: the intention solver takes at most 8"),
        "{errors}"
    );
    let filters = with(
        "[hbba]\n[hbba.strategies.s]\nclass = \"k\"\nutility = 1\nfilters = { C = 1, D = 1, E = 1, F = 1, G = 1, H = 1, I = 1, J = 1, K = 1 }\n",
    );
    let errors = parse(&filters).unwrap_err();
    assert!(
        errors.contains("net.toml:26:11: error: strategy `s` sets 9 filters: the intention solver takes at most 8 per strategy"),
        "{errors}"
    );
}

/// `compile` gives a file with `[hbba]` the tables of the same file without it, plus the message
/// filters of the connections its strategies name (which start closed on the boards).
#[test]
fn the_section_adds_the_filters_and_changes_nothing_else() {
    let with_section = parse(&with(&STRATEGIES.replace("bus = 10", "bus = 20"))).unwrap();
    let without = parse(HEAD).unwrap();
    let tables = |network: &Network| -> Vec<pab_core::Table> {
        pab_lang::compile::compile(network)
            .unwrap()
            .into_iter()
            .map(|node| pab_core::image::load(&node.image).unwrap().table)
            .collect()
    };
    let mut filtered = 0;
    for (mut a, b) in tables(&with_section).into_iter().zip(tables(&without)) {
        assert!(b.filters().is_empty());
        filtered += a.filters().connections.len();
        a.set_filters(Default::default()).unwrap();
        assert_eq!(a, b);
    }
    let targets = with_section.filter_targets().unwrap();
    assert!(
        filtered > 0 && filtered == targets.len(),
        "{filtered} {targets:?}"
    );
    assert!(without.hbba.is_none());
}

// ---------------------------------------------------------------------------------------------
// `pabctl solve`.

fn pabctl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pabctl"))
        .args(args)
        .output()
        .expect("pabctl runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn tour_guide() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/tour-guide.toml")
        .display()
        .to_string()
}

/// The paper's tour guide: touring, then a loud noise opens voice localisation, throttles face
/// detection and closes QR-code detection, within the CPU and the bus.
#[test]
fn solve_prints_the_tour_guides_intentions() {
    let path = tour_guide();
    let touring = pabctl(&["solve", &path, "--desires", "face=2,qr=1,nav=2"]);
    assert_eq!(touring.status.code(), Some(0), "{}", text(&touring.stderr));
    assert_eq!(
        text(&touring.stdout),
        "\
desires: face=2, qr=1, nav=2
objective 12
  face   face_full    utility 3 × intensity 2 = 6
  qr     qr_full      utility 2 × intensity 1 = 2
  voice  none
  nav    nav_follow   utility 2 × intensity 2 = 4
  avoid  avoid_laser  required (no desire)
use
  cpu  100 of 100
  bus  10 of 15 (% of 250000 bit/s)
"
    );
    let noise = pabctl(&["solve", &path, "--desires", "face=2,qr=1,nav=2,voice=3"]);
    assert_eq!(noise.status.code(), Some(0), "{}", text(&noise.stderr));
    assert_eq!(
        text(&noise.stdout),
        "\
desires: face=2, qr=1, voice=3, nav=2
objective 17
  face   face_throttled  utility 2 × intensity 2 = 4
  qr     none            (desire 1 not fulfilled)
  voice  voice_localise  utility 3 × intensity 3 = 9
  nav    nav_follow      utility 2 × intensity 2 = 4
  avoid  avoid_laser     required (no desire)
use
  cpu  95 of 100
  bus  14 of 15 (% of 250000 bit/s)
"
    );
    let json = pabctl(&[
        "solve",
        &path,
        "--desires",
        "face=2,qr=1,nav=2,voice=3",
        "--json",
    ]);
    assert_eq!(json.status.code(), Some(0));
    assert_eq!(
        text(&json.stdout),
        "{\"strategies\":[\"avoid_laser\",\"face_throttled\",\"nav_follow\",\"voice_localise\"],\"objective\":17,\"use\":{\"cpu\":95,\"bus\":14}}\n"
    );
    let none = pabctl(&["solve", &path, "--desires", "", "--json"]);
    assert_eq!(
        text(&none.stdout),
        "{\"strategies\":[],\"objective\":0,\"use\":{\"cpu\":0,\"bus\":0}}\n"
    );
}

#[test]
fn solve_exit_statuses_and_messages() {
    let path = tour_guide();
    for (desires, message) in [
        (
            "face=2,bogus=3",
            "--desires: no strategy has class `bogus` (classes: face, qr, voice, nav, avoid)",
        ),
        ("face=0", "--desires: `face=0`: an intensity is 1 to 65535"),
        (
            "face=65536",
            "--desires: `face=65536`: an intensity is a whole number, 1 to 65535",
        ),
        ("face", "--desires: `face` is not CLASS=INTENSITY"),
        ("face=1,face=2", "--desires: class `face` has two desires"),
    ] {
        let output = pabctl(&["solve", &path, "--desires", desires]);
        assert_eq!(output.status.code(), Some(2), "{desires}");
        let stderr = text(&output.stderr);
        assert!(
            stderr.contains(&format!("{path}: error: {message}")),
            "{desires}: {stderr}"
        );
        assert!(output.stdout.is_empty());
    }
    let figure = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/figure-1.toml")
        .display()
        .to_string();
    let output = pabctl(&["solve", &figure, "--desires", ""]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output.stderr).contains("error: no [hbba] section"));
    // An instance the solver gives up on: exit 2, and no selection printed.
    let dir = tempfile::tempdir().unwrap();
    let hard = dir.path().join("hard.toml");
    let mut network = String::from("[hbba]\nresources = { r0 = 100, r1 = 100 }\n");
    for class in 0..16 {
        for j in 0..2 {
            let (c0, c1) = if (j + class) % 2 == 0 {
                (25, 5)
            } else {
                (5, 25)
            };
            network += &format!(
                "[hbba.strategies.s{class}_{j}]\nclass = \"k{class}\"\nutility = 1\ncosts = {{ r0 = {c0}, r1 = {c1} }}\n"
            );
        }
    }
    std::fs::write(&hard, network).unwrap();
    let desires: Vec<String> = (0..16).map(|k| format!("k{k}=1")).collect();
    let output = pabctl(&[
        "solve",
        &hard.display().to_string(),
        "--desires",
        &desires.join(","),
    ]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output.stderr).contains(
            "error: the intention solver gave up after visiting 100000 nodes (its work budget)"
        ),
        "{}",
        text(&output.stderr)
    );
    assert!(output.stdout.is_empty());
}

#[test]
fn solve_help_teaches_the_problem() {
    let output = pabctl(&["solve", "--help"]);
    let help = text(&output.stdout);
    for phrase in [
        "CLASS=INTENSITY",
        "at most one strategy per class",
        "intensity × utility",
        "set the same φ",
        "a class without a desire gets a strategy only when a chosen strategy requires it",
        "rate_hz / φ",
        "first appearance among the strategies",
        "100000 nodes",
        "--json",
        "pabctl solve examples/tour-guide.toml",
    ] {
        assert!(help.contains(phrase), "{phrase}: {help}");
    }
    let top = text(&pabctl(&["--help"]).stdout);
    assert!(top.contains("solve"), "{top}");
}
