//! Ayllu's connection kinds through the whole pipeline (parse, prove, compile to images, load
//! them into `pab-core` arbiters, simulate), at exact virtual times.
//!
//! What the core's integrator does with a special connection (σ = 1, τ = period, τr = 0): a frame
//! at t makes it active at once, and it is active at every instant up to t + period inclusive
//! (`Integrator::is_active`: elapsed ≤ τ), inactive from t + period + 1 µs. A frame while it is
//! active restarts the period from that frame. Frames of one microsecond are handled in bus order,
//! lower identifier first: a special frame that goes first acts on the frames after it in that
//! microsecond; one that goes after them does not.

use pab_lang::network::Network;
use pab_lang::sim::{self, Outcome};
use pab_lang::{check, compile};
use pab_tests::network;

/// Proves, compiles and simulates `text` to its default end.
fn run(text: &str) -> (Network, Outcome) {
    let network = network("kinds", text);
    let report = check::check(&network);
    assert!(report.is_consistent(), "{:?}", report.errors(&network));
    let nodes = compile::compile(&network).unwrap_or_else(|errors| panic!("{errors:?}"));
    let outcome = sim::simulate(&network, &nodes, &sim::Options::default())
        .unwrap_or_else(|error| panic!("{error}"));
    (network, outcome)
}

fn port(network: &Network, name: &str) -> usize {
    network
        .ports
        .iter()
        .position(|p| p.name == name)
        .unwrap_or_else(|| panic!("no port {name}"))
}

/// The changes of `port`'s selected connection, as (µs, connection name or "nobody").
fn timeline(network: &Network, outcome: &Outcome, port_name: &str) -> Vec<(u64, String)> {
    outcome.timelines[port(network, port_name)]
        .iter()
        .map(|change| {
            let who = change.selected.map_or("nobody".to_string(), |c| {
                network.connections[c].name.clone()
            });
            (change.t_us, who)
        })
        .collect()
}

/// The times (µs) of the frames of connection `name` at `port_name`, with whether each was
/// delivered.
fn frames(network: &Network, outcome: &Outcome, port_name: &str, name: &str) -> Vec<(u64, bool)> {
    let port = port(network, port_name);
    let connection = network
        .connections
        .iter()
        .position(|c| c.port == port && c.name == name)
        .unwrap_or_else(|| panic!("no connection {name} at {port_name}"));
    outcome
        .rows_of(connection, 0, u64::MAX)
        .map(|row| (row.t_us, row.delivered))
        .collect()
}

fn changes(list: &[(u64, &str)]) -> Vec<(u64, String)> {
    list.iter().map(|(t, who)| (*t, who.to_string())).collect()
}

/// One node, port `n.p`: C (normal, topic 0x200, σ = 1, τ = 10 s) and S (suppress, topic
/// `s_id`, period 0.5 s), with C's and S's frames at the given times.
fn suppressed(s_id: u32, c_at: &str, s_at: &str) -> String {
    format!(
        r#"
[nodes.n]
id = 1
[ports."n.p"]
[topics.c]
can_id = 0x200
[topics.s]
can_id = {s_id:#x}
[connections.C]
topic = "c"
port = "n.p"
st = 1
tc = 10
[connections.S]
topic = "s"
port = "n.p"
kind = "suppress"
period = 0.5
[[events]]
topic = "c"
at = [{c_at}]
[[events]]
topic = "s"
at = [{s_at}]
"#
    )
}

#[test]
fn a_suppressor_blocks_from_its_frame_to_its_period_inclusive() {
    // S (0x100) wins bus arbitration over C (0x200): at 2.0 it goes first.
    let (network, outcome) = run(&suppressed(0x100, "1.0, 2.0, 2.5, 2.500001, 3.0", "2.0"));
    assert_eq!(
        frames(&network, &outcome, "n.p", "C"),
        [
            (1_000_000, true),
            // S's frame went first in this microsecond: C is suppressed at once ...
            (2_000_000, false),
            // ... and still at 2.0 + 0.5 s ...
            (2_500_000, false),
            // ... not a microsecond later.
            (2_500_001, true),
            (3_000_000, true),
        ]
    );
    assert_eq!(
        timeline(&network, &outcome, "n.p"),
        changes(&[
            (0, "nobody"),
            (1_000_000, "C"),
            (2_000_000, "nobody"),
            (2_500_001, "C"),
            (13_000_001, "nobody"),
        ])
    );
    // The suppressor is never delivered.
    assert!(
        frames(&network, &outcome, "n.p", "S")
            .iter()
            .all(|(_, d)| !d)
    );
}

#[test]
fn a_suppressor_after_the_frame_in_bus_order_acts_from_the_next_frame() {
    // S (0x300) loses bus arbitration to C (0x200): C's frame at 2.0 is delivered first.
    let (network, outcome) = run(&suppressed(
        0x300,
        "1.0, 2.0, 2.000001, 2.5, 2.500001",
        "2.0",
    ));
    assert_eq!(
        frames(&network, &outcome, "n.p", "C"),
        [
            (1_000_000, true),
            (2_000_000, true),
            (2_000_001, false),
            (2_500_000, false),
            (2_500_001, true),
        ]
    );
    assert_eq!(
        timeline(&network, &outcome, "n.p")[..4],
        changes(&[
            (0, "nobody"),
            (1_000_000, "C"),
            (2_000_000, "nobody"),
            (2_500_001, "C"),
        ])[..]
    );
}

#[test]
fn a_frame_within_the_period_retriggers_it() {
    let (network, outcome) = run(&suppressed(0x100, "1.0, 2.75, 2.8, 2.800001", "2.0, 2.3"));
    assert_eq!(
        frames(&network, &outcome, "n.p", "C"),
        [
            (1_000_000, true),
            // 2.75 is past 2.0 + 0.5 but within 2.3 + 0.5.
            (2_750_000, false),
            (2_800_000, false),
            (2_800_001, true),
        ]
    );
    assert_eq!(
        timeline(&network, &outcome, "n.p")[..4],
        changes(&[
            (0, "nobody"),
            (1_000_000, "C"),
            (2_000_000, "nobody"),
            (2_800_001, "C"),
        ])[..]
    );
}

#[test]
fn two_suppressors_both_block_and_never_block_each_other() {
    let text = suppressed(0x100, "1.0, 2.2, 2.6, 2.9, 2.900001", "2.0").replace(
        "[[events]]\ntopic = \"c\"",
        "[topics.s2]\ncan_id = 0x101\n[connections.S2]\ntopic = \"s2\"\nport = \"n.p\"\nkind = \"suppress\"\nperiod = 0.5\n[[events]]\ntopic = \"s2\"\nat = [2.4]\n[[events]]\ntopic = \"c\"",
    );
    let (network, outcome) = run(&text);
    assert_eq!(
        frames(&network, &outcome, "n.p", "C"),
        [
            (1_000_000, true),
            (2_200_000, false),
            // S has lapsed (2.5), S2 (2.4 + 0.5) holds.
            (2_600_000, false),
            (2_900_000, false),
            (2_900_001, true),
        ]
    );
    // S2's frame made it active although S was: suppressors do not suppress each other.
    let s2 = network
        .connections
        .iter()
        .position(|c| c.name == "S2")
        .unwrap();
    let rows: Vec<_> = outcome.rows_of(s2, 0, u64::MAX).collect();
    assert_eq!(rows.len(), 1);
    assert!(rows[0].active && !rows[0].delivered);
}

/// One node, port `n.p`, a subsumption stack: O1 (override, 0x101, 1 s) over O2 (override,
/// 0x102, 1 s) over C (normal, 0x200, σ = 1, τ = 0.6 s); W (0x103, 1 s) write-inhibits O2.
const STACK: &str = r#"
[nodes.n]
id = 1
[ports."n.p"]
[topics.o1]
can_id = 0x101
[topics.o2]
can_id = 0x102
[topics.w]
can_id = 0x103
[topics.c]
can_id = 0x200
[connections.O1]
topic = "o1"
port = "n.p"
kind = "override"
period = 1.0
[connections.O2]
topic = "o2"
port = "n.p"
kind = "override"
period = 1.0
[connections.C]
topic = "c"
port = "n.p"
st = 1
tc = 0.6
[connections.W]
topic = "w"
port = "n.p"
kind = "write-inhibit"
inhibits = "o2"
period = 1.0
[[events]]
topic = "c"
at = [0.5, 1.5, 2.0, 2.5, 3.0, 3.7, 4.2, 4.6, 5.0, 7.2]
[[events]]
topic = "o2"
at = [1.0, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0]
[[events]]
topic = "o1"
at = [3.0]
[[events]]
topic = "w"
at = [2.0, 3.5]
"#;

#[test]
fn an_override_stack_with_a_write_inhibited_middle_layer() {
    let (network, outcome) = run(STACK);
    assert_eq!(
        timeline(&network, &outcome, "n.p"),
        changes(&[
            (0, "nobody"),
            (500_000, "C"),
            // O2 subsumes C (active until 1.1).
            (1_000_000, "O2"),
            // At 2.0, O2's frame goes before W's: delivered. Then W write-inhibits O2, which no
            // longer subsumes C (active since its frame at 1.5, not delivered then).
            (2_000_000, "C"),
            // W lasts until 3.0 inclusive; at 3.0 O1 (0x101) goes first and subsumes all.
            (3_000_000, "O1"),
            // O1 lapses after 4.0; W (retriggered at 3.5, until 4.5) still write-inhibits O2,
            // so the port goes to C (active from its frame at 3.7 until 4.3, then from 4.2).
            (4_000_001, "C"),
            // W lapses: O2 subsumes C again.
            (4_500_001, "O2"),
            // O2's last frame was at 6.0; C's at 5.0 lapsed at 5.6.
            (7_000_001, "nobody"),
            (7_200_000, "C"),
            (7_800_001, "nobody"),
        ])
    );
    assert_eq!(
        frames(&network, &outcome, "n.p", "O2"),
        [
            (1_000_000, true),
            (2_000_000, true),
            (2_500_000, false),
            (3_000_000, false),
            (3_500_000, false),
            (4_000_000, false),
            (4_500_000, false),
            (5_000_000, true),
            (5_500_000, true),
            (6_000_000, true),
        ]
    );
    assert_eq!(
        frames(&network, &outcome, "n.p", "C"),
        [
            (500_000, true),
            (1_500_000, false),
            (2_000_000, true),
            (2_500_000, true),
            // O1 went first at 3.0.
            (3_000_000, false),
            // O1 is active (until 4.0): the lower layer waits although O2 is write-inhibited.
            (3_700_000, false),
            (4_200_000, true),
            (4_600_000, false),
            (5_000_000, false),
            (7_200_000, true),
        ]
    );
}

/// Nodes a and b: topic m feeds a.p (with a fallback F) and b.q; I inhibits m everywhere.
const INHIBIT: &str = r#"
[nodes.a]
id = 1
[nodes.b]
id = 2
[ports."a.p"]
[ports."b.q"]
[topics.m]
can_id = 0x200
[topics.f]
can_id = 0x210
[topics.i]
can_id = 0x100
[connections.M]
topic = "m"
port = "a.p"
st = 1
tc = 1
[connections.F]
topic = "f"
port = "a.p"
st = 1
tc = 1
rule = "F & !M"
[connections.MB]
topic = "m"
port = "b.q"
st = 1
tc = 1
[connections.I]
topic = "i"
kind = "inhibit"
inhibits = "m"
period = 0.5
[[events]]
topic = "m"
rate_hz = 10
from = 1.0
to = 4.0
[[events]]
topic = "f"
at = [2.2]
[[events]]
topic = "i"
at = [2.0]
"#;

#[test]
fn an_inhibitor_blocks_its_topic_at_every_port_on_every_node() {
    let (network, outcome) = run(INHIBIT);
    for (port, name) in [("a.p", "M"), ("b.q", "MB")] {
        let blocked: Vec<u64> = frames(&network, &outcome, port, name)
            .into_iter()
            .filter(|(_, delivered)| !delivered)
            .map(|(t, _)| t)
            .collect();
        // I's frame (0x100) goes before m's at 2.0; it acts until 2.5 inclusive.
        assert_eq!(
            blocked,
            [
                2_000_000, 2_100_000, 2_200_000, 2_300_000, 2_400_000, 2_500_000
            ],
            "{port}"
        );
    }
    assert_eq!(
        timeline(&network, &outcome, "b.q"),
        changes(&[
            (0, "nobody"),
            (1_000_000, "MB"),
            (2_000_000, "nobody"),
            (2_500_001, "MB"),
            (4_900_001, "nobody"),
        ])
    );
    // F's rule yields to M's activity, not to M's delivery: inhibiting M does not hand a.p to F.
    assert_eq!(frames(&network, &outcome, "a.p", "F"), [(2_200_000, false)]);
    // The trace names the inhibitor at both ports.
    let mut csv = Vec::new();
    outcome.write_csv(&network, &mut csv).unwrap();
    let csv = String::from_utf8(csv).unwrap();
    assert!(csv.contains("\n2.000000,a.p,I,1.0000,1,0\n"), "{csv}");
    assert!(csv.contains("\n2.000000,b.q,I,1.0000,1,0\n"), "{csv}");
}

#[test]
fn a_stopped_node_receives_nothing_and_delivers_nothing() {
    let text = format!("{INHIBIT}[[faults]]\nnode = \"b\"\nat = 3.0\n");
    let (network, outcome) = run(&text);
    let times: Vec<u64> = frames(&network, &outcome, "b.q", "MB")
        .into_iter()
        .map(|(t, _)| t)
        .collect();
    assert_eq!(times.first(), Some(&1_000_000));
    // A frame of the stop's own microsecond is not received.
    assert_eq!(times.last(), Some(&2_900_000));
    assert_eq!(
        timeline(&network, &outcome, "b.q"),
        changes(&[
            (0, "nobody"),
            (1_000_000, "MB"),
            (2_000_000, "nobody"),
            (2_500_001, "MB"),
            (3_000_000, "nobody"),
        ])
    );
    // Node a is unaffected.
    assert_eq!(
        frames(&network, &outcome, "a.p", "M").last(),
        Some(&(3_900_000, true))
    );
}

#[test]
fn event_frames_carry_their_data() {
    // Topic f's frames carry 2 bytes; the other topics' the default 8, zeros without `data`.
    let text = INHIBIT
        .replace("at = [2.2]", "at = [2.2]\ndata = [0x0A, 0x00]")
        .replace("can_id = 0x210\n", "can_id = 0x210\nlength = 2\n");
    let network = network("kinds", &text);
    let frames = sim::event_frames(&network).unwrap();
    let f = frames
        .iter()
        .find(|f| f.t_us == 2_200_000 && f.frame.payload() == [0x0A, 0x00]);
    assert!(f.is_some(), "{frames:?}");
    assert!(
        frames
            .iter()
            .filter(|f| f.t_us != 2_200_000)
            .all(|f| f.frame.payload() == [0; 8])
    );
}
