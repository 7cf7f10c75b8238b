//! `[dynamics.*]` groups: examples/door-dynamics.toml through the checker, the compiler and the
//! simulator with its dynamics trace (the door sequence search → recognise → approach), the
//! trace's exact format and timing, and the parse errors at their lines.

use pab_lang::diagnostic::Source;
use pab_lang::network::Network;
use pab_lang::sim::{self, DynamicsRow, Options, Outcome};
use pab_lang::{check, compile};
use pab_tests::{example_text, network};

fn simulate(network: &Network) -> Outcome {
    assert!(check::check(network).is_consistent());
    let nodes = compile::compile(network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let options = Options {
        dynamics: true,
        ..Options::default()
    };
    sim::simulate(network, &nodes, &options).unwrap_or_else(|error| panic!("{error}"))
}

fn csv(network: &Network, rows: &[DynamicsRow]) -> String {
    let mut out = Vec::new();
    sim::write_dynamics_csv(rows, network, &mut out).unwrap();
    String::from_utf8(out).unwrap()
}

/// The times (µs) at which behaviour `behaviour` of group 0 opens and closes its gate.
fn transitions(rows: &[DynamicsRow], behaviour: usize) -> (Vec<u64>, Vec<u64>) {
    let (mut opens, mut closes) = (Vec::new(), Vec::new());
    let mut open = false;
    for row in rows
        .iter()
        .filter(|r| r.group == 0 && r.behaviour == behaviour)
    {
        if row.gate != open {
            if row.gate {
                opens.push(row.t_us);
            } else {
                closes.push(row.t_us);
            }
            open = row.gate;
        }
    }
    (opens, closes)
}

const SEARCH: usize = 0;
const RECOGNISE: usize = 1;
const APPROACH: usize = 2;

#[test]
fn the_door_opens_search_then_recognise_then_approach() {
    let network = network("door-dynamics", &example_text("door-dynamics"));
    let outcome = simulate(&network);
    let rows = &outcome.dynamics;
    // One row per behaviour per step, t_0 = 0 to the end of the run (4.1 s) included.
    assert_eq!(outcome.until_us, 4_100_000);
    assert_eq!(rows.len(), 3 * 4101);
    let (search_on, search_off) = transitions(rows, SEARCH);
    let (recognise_on, recognise_off) = transitions(rows, RECOGNISE);
    let (approach_on, approach_off) = transitions(rows, APPROACH);
    let all = format!(
        "search {search_on:?} {search_off:?}, recognise {recognise_on:?} {recognise_off:?}, approach {approach_on:?} {approach_off:?}"
    );
    // Search first, before the door is seen (0.8 s).
    assert!(search_on[0] < 800_000, "{all}");
    // Recognise once, at least τ_ρ2·ln 2 (0.139 s) after the door is seen; search gives way.
    assert_eq!((recognise_on.len(), recognise_off.len()), (1, 1), "{all}");
    assert!(recognise_on[0] >= 800_000 + 138_000, "{all}");
    assert!(search_off[0] <= recognise_on[0] + 20_000, "{all}");
    assert!(search_off[0] + 20_000 >= recognise_on[0], "{all}");
    // Recognise ends when DOOR lapses (its last frame at 1.70 s, τ 0.1 s).
    assert!((1_800_000..=1_810_000).contains(&recognise_off[0]), "{all}");
    // Approach once, only after recognise has closed, for about 0.55-0.69 τ_recognise (0.5 s).
    assert_eq!((approach_on.len(), approach_off.len()), (1, 1), "{all}");
    assert!(approach_on[0] > recognise_off[0], "{all}");
    let lasts = approach_off[0] - 1_800_000;
    assert!((275_000..=345_000).contains(&lasts), "{all}");
    // Search comes back after approach.
    assert!(search_on.last().unwrap() > &approach_off[0], "{all}");
    // Recognise and approach are never open together.
    for pair in rows.chunks(3) {
        assert!(!(pair[RECOGNISE].gate && pair[APPROACH].gate), "{pair:?}");
    }
}

#[test]
fn the_trace_has_its_header_and_rows_at_each_step() {
    let network = network("door-dynamics", &example_text("door-dynamics"));
    let outcome = simulate(&network);
    let text = csv(&network, &outcome.dynamics);
    let lines: Vec<&str> = text.lines().take(7).collect();
    // t_0: the initial state (n = 0, ρ = 0, m = −1), with the contexts the node sampled when it
    // booted at 0, before the frames of that instant: CORRIDOR and PATH's first frames, at
    // exactly 0, count from the first step on. After one step n holds the first noise sample;
    // ρ of a behaviour with context 1 is dt / τ_ρ2 = 0.005 a step later.
    assert_eq!(
        lines,
        [
            "t,group,behaviour,context,n,rho,m,gate",
            "0.000000,door,search,0.000000,0.000000,0.000000,-1.000000,0",
            "0.000000,door,recognise,0.000000,0.000000,0.000000,-1.000000,0",
            "0.000000,door,approach,0.000000,0.000000,0.000000,-1.000000,0",
            "0.001000,door,search,1.000000,-0.000710,0.000000,-1.000000,0",
            "0.001000,door,recognise,0.000000,-0.000558,0.000000,-1.000000,0",
            "0.001000,door,approach,1.000000,0.000062,0.000000,-1.000000,0",
        ]
    );
    // DOOR's first frame at 0.8 s follows CORRIDOR's and PATH's of that microsecond on the bus:
    // the node took the step of 0.8 s on the first of them, so DOOR counts for the context at
    // 0.801, not before; recognise's ρ rises from the step after.
    let row = |t: &str| {
        text.lines()
            .find(|line| line.starts_with(t) && line.contains(",recognise,"))
            .unwrap()
            .to_string()
    };
    assert!(
        row("0.800000,").contains(",recognise,0.000000,"),
        "{}",
        row("0.800000,")
    );
    assert!(
        row("0.801000,").contains(",recognise,1.000000,"),
        "{}",
        row("0.801000,")
    );
    let rho = |t: &str| row(t).split(',').nth(5).unwrap().to_string();
    assert_eq!(rho("0.801000,"), "0.000000");
    assert_eq!(rho("0.802000,"), "0.005000");
}

#[test]
fn topic_and_constant_contexts() {
    let text = r#"
[nodes.base]
id = 5
[topics.seen]
can_id = 0x121
length = 2
[ports."base.p"]
[connections.SEEN]
topic = "seen"
port = "base.p"
st = 1.0
tc = 0.1
[dynamics.g]
node = "base"
[dynamics.g.behaviours.a]
context = { topic = "seen", value = { offset = 1, size = 1 }, scale = 255.0, timeout = 0.002 }
[dynamics.g.behaviours.b]
context = 0.5
[[events]]
topic = "seen"
data = [0, 51]
at = [0.003]
"#;
    let network = network("contexts", text);
    let outcome = simulate(&network);
    // As the trace shows them: the context fed, in Q2.29, to six decimals.
    let contexts: Vec<(u64, String)> = outcome
        .dynamics
        .iter()
        .filter(|r| r.behaviour == 0)
        .map(|r| (r.t_us, format!("{:.6}", r.context)))
        .take(7)
        .collect();
    // 51 / 255 = 0.2 from the frame at 3 ms, through 5 ms (3 + the 2 ms timeout), then 0.
    let expected: Vec<(u64, String)> = [
        (0, "0.000000"),
        (1_000, "0.000000"),
        (2_000, "0.000000"),
        (3_000, "0.200000"),
        (4_000, "0.200000"),
        (5_000, "0.200000"),
        (6_000, "0.000000"),
    ]
    .into_iter()
    .map(|(t, c)| (t, c.to_string()))
    .collect();
    assert_eq!(contexts, expected);
    assert!(
        outcome
            .dynamics
            .iter()
            .filter(|r| r.behaviour == 1)
            .all(|r| r.context == 0.5)
    );
}

const BASE: &str = r#"[nodes.base]
id = 5
[nodes.arm]
id = 6
[topics.seen]
can_id = 0x121
[ports."base.p"]
[ports."arm.q"]
[connections.SEEN]
topic = "seen"
port = "base.p"
st = 1.0
tc = 0.1
[connections.GRIP]
topic = "seen"
port = "arm.q"
st = 1.0
tc = 0.1
"#;

/// Parses BASE + `extra` and returns the one error, which must name `extra`'s line `line`
/// (1-based) of dyn.toml and contain `cause`.
fn expect_error(extra: &str, line: usize, cause: &str) {
    let text = format!("{BASE}{extra}");
    let message = match Network::parse(Source::new("dyn.toml", text)) {
        Ok(_) => panic!("accepted:\n{extra}"),
        Err(errors) => errors.to_string(),
    };
    let at = format!("dyn.toml:{}:", BASE.lines().count() + line);
    assert!(
        message.starts_with(&at),
        "expected {at} in:\n{message}\nfor:\n{extra}"
    );
    assert!(message.contains(cause), "{cause:?} not in:\n{message}");
    assert_eq!(message.lines().count(), 1, "{message}");
}

#[test]
fn mistakes_are_reported_at_their_line_with_their_cause() {
    let group = "[dynamics.door]\nnode = \"base\"\n";
    let a = "[dynamics.door.behaviours.a]\ncontext = \"SEEN\"\n";
    for (extra, line, cause) in [
        (
            "[dynamics.door]\nnode = \"hand\"\n".to_string() + a,
            2,
            "node `hand` is not defined (nodes: base, arm)",
        ),
        (
            format!("{group}[dynamics.door.behaviours.a]\ncontext = \"GRIP\"\n"),
            4,
            "`GRIP` is not a connection on node `base`",
        ),
        (
            format!(
                "{group}[dynamics.door.behaviours.a]\ncontext = {{ topic = \"nope\", value = {{ offset = 0, size = 1 }}, scale = 255.0, timeout = 0.2 }}\n"
            ),
            4,
            "topic `nope` is not defined",
        ),
        (
            format!("{group}{a}excludes = [\"b\"]\n"),
            5,
            "excludes of behaviour `a`: `b` is not a behaviour of dynamics group `door`",
        ),
        (
            format!("{group}{a}requires = [\"zz\"]\n"),
            5,
            "requires of behaviour `a`: `zz` is not a behaviour",
        ),
        (
            format!("{group}{a}gamma = {{ c = 4.0 }}\n"),
            5,
            "gamma of behaviour `a`: `c` is not a behaviour",
        ),
        (format!("{group}speed = 2\n{a}"), 3, "unknown key `speed`"),
        (
            format!("{group}seed = \"one\"\n{a}"),
            3,
            "`seed` is an integer, not the string \"one\"",
        ),
        (
            // 4 ms > 10 ms / 4: Params::validate refuses, at the group's header.
            format!("{group}step = 0.004\n{a}"),
            1,
            "dynamics group `door`: step 4000 µs is above a quarter of the fastest time constant (10000 µs)",
        ),
        (
            format!("{group}seed = 0\n{a}"),
            1,
            "dynamics group `door`: seed = 0",
        ),
        (
            // τ = 1 unit and Σγ = 250: dt (2 + 250) / τ > 1.
            format!(
                "{group}{a}gamma = {{ b = 250.0 }}\n[dynamics.door.behaviours.b]\ncontext = 1.0\n"
            ),
            1,
            "step · (2 + Σ γ) / tau is above 1 for behaviour `a`",
        ),
        (
            format!("{group}[dynamics.door.behaviours.a]\ncontext = 1.5\n"),
            4,
            "a constant context is in [0, 1]",
        ),
        (
            format!("{group}[dynamics.door.behaviours.a]\ncontext = true\n"),
            4,
            "`context` is a connection name, a constant in [0, 1], or { topic, value, scale, timeout }, not boolean `true`",
        ),
        (
            format!(
                "{group}[dynamics.door.behaviours.a]\ncontext = {{ topic = \"seen\", value = {{ offset = 0, size = 1 }}, scale = 255.0, timeout = 0.2, every = 1 }}\n"
            ),
            4,
            "unknown key `every`",
        ),
        (
            format!("{group}{a}excludes = [\"a\"]\n"),
            3,
            "excludes itself",
        ),
        (
            format!("{group}tau = -1.0\n{a}"),
            3,
            "tau = -1: a time in units, positive and finite",
        ),
    ] {
        expect_error(&extra, line, cause);
    }
}

#[test]
fn the_plot_has_a_lane_per_behaviour_with_every_step_and_gate_edge() {
    let network = network("door-dynamics", &example_text("door-dynamics"));
    let outcome = simulate(&network);
    let data = outcome.plot_data(&network, "door-dynamics.toml");
    // The three context ports, the base's wheels and the head's gaze.
    assert_eq!(data.ports.len(), 5);
    assert_eq!(data.dynamics.len(), 1);
    let group = &data.dynamics[0];
    assert_eq!(group.name, "dynamics door (node base, step 1 ms)");
    let names: Vec<&str> = group.behaviours.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, ["door.search", "door.recognise", "door.approach"]);
    assert_eq!(group.behaviours[1].label, "door.recognise  context DOOR");
    for (index, lane) in group.behaviours.iter().enumerate() {
        // Every row, unthinned: the plot thins only what it draws.
        assert_eq!(lane.samples.len(), 4101);
        let (opens, closes) = transitions(&outcome.dynamics, index);
        let edges = |gate: bool| -> Vec<u64> {
            lane.samples
                .windows(2)
                .filter(|w| w[0].gate != w[1].gate && w[1].gate == gate)
                .map(|w| (w[1].t * 1e6).round() as u64)
                .collect()
        };
        assert_eq!(edges(true), opens, "lane {index}");
        assert_eq!(edges(false), closes, "lane {index}");
    }
    // Not stepped: no lanes.
    let nodes = compile::compile(&network).unwrap();
    let plain = sim::simulate(&network, &nodes, &Options::default()).unwrap();
    assert!(plain.plot_data(&network, "door").dynamics.is_empty());
}
