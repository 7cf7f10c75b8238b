//! `examples/multi-target-observation.toml`: three robots, four prioritised targets, Broadcast
//! of Local Eligibility between the robots' base controllers. Who holds each target and who
//! drives each robot, to the microsecond, as the example's comment states; and what the nodes
//! broadcast, read from the claims on the simulated bus.

use pab_core::ble::Claim;
use pab_tests::Scenario;

const MS: u64 = 1_000;

fn holders(scenario: &Scenario, group: &str) -> Vec<(u64, Vec<String>)> {
    let index = scenario
        .network
        .groups
        .iter()
        .position(|g| g.name == group)
        .unwrap_or_else(|| panic!("no group {group}"));
    scenario.outcome.holdings[index]
        .iter()
        .map(|change| {
            let names = change
                .holders
                .iter()
                .map(|&n| scenario.network.nodes[n].name.clone())
                .collect();
            (change.t_us, names)
        })
        .collect()
}

fn timeline(scenario: &Scenario, port: &str) -> Vec<(u64, String)> {
    let index = scenario
        .network
        .ports
        .iter()
        .position(|p| p.name == port)
        .unwrap_or_else(|| panic!("no port {port}"));
    scenario.outcome.timelines[index]
        .iter()
        .map(|change| {
            let who = change.selected.map_or("nobody".to_string(), |c| {
                scenario.network.connections[c].name.clone()
            });
            (change.t_us, who)
        })
        .collect()
}

fn expect(list: &[(u64, &[&str])]) -> Vec<(u64, Vec<String>)> {
    list.iter()
        .map(|(t, who)| (*t, who.iter().map(|s| s.to_string()).collect()))
        .collect()
}

fn expect_timeline(list: &[(u64, &str)]) -> Vec<(u64, String)> {
    list.iter().map(|(t, who)| (*t, who.to_string())).collect()
}

#[test]
fn each_target_is_held_by_the_most_eligible_robot_that_watches_it_and_a_dead_robot_is_replaced() {
    let scenario = Scenario::run("multi-target-observation");
    // The robots boot at 0 and claim at once, before their first readings: every first claim
    // offers 0, and the holders of the first period are those that heard no better offer, a
    // start-up transient of a period (two for t2, whose order settles on the second claims).
    // t1: r1 (900) over r2 (600); r1 stops at 3.0, its last claim (2.9) is stale at 3.1.
    assert_eq!(
        holders(&scenario, "observe_t1"),
        expect(&[
            (0, &[]),
            (0, &["r1", "r2"]),
            (100 * MS, &["r1"]),
            (3_000 * MS, &[]),
            (3_100 * MS, &["r2"]),
            // The observers' last frames at 5.95: readings two periods old at 6.15.
            (6_150 * MS, &[]),
        ])
    );
    // t2: r2 (500) over r3 (400). At 0.1 r2 still takes r3's first claim (0) for its best
    // rival and r3 r2's: both hold until their claims of 0.2.
    // From 3.1 r2 watches t1 and offers 0 for t2 (its t2 observer is subsumed by its own t1
    // layer): nobody holds t2 until r3's next claim turn (3.2), when r3 takes it.
    assert_eq!(
        holders(&scenario, "observe_t2"),
        expect(&[
            (0, &[]),
            (0, &["r3"]),
            (100 * MS, &["r2", "r3"]),
            (200 * MS, &["r2"]),
            (3_100 * MS, &[]),
            (3_200 * MS, &["r3"]),
            (6_150 * MS, &[]),
        ])
    );
    // t3: r3 alone sees it; it offers it from its claim of 0.2 (outranked on t2 by then), and
    // gives it up for t2 at 3.2: t3, lower in priority than t2, is left uncovered.
    assert_eq!(
        holders(&scenario, "observe_t3"),
        expect(&[(0, &[]), (200 * MS, &["r3"]), (3_200 * MS, &[])])
    );
    // t4: nobody sees it.
    assert_eq!(holders(&scenario, "observe_t4"), expect(&[(0, &[])]));

    assert_eq!(
        timeline(&scenario, "r1.drive"),
        expect_timeline(&[(0, "nobody"), (0, "OBS11"), (3_000 * MS, "nobody")])
    );
    assert_eq!(
        timeline(&scenario, "r2.drive"),
        expect_timeline(&[
            (0, "nobody"),
            (0, "OBS21"),
            (100 * MS, "OBS22"),
            (3_100 * MS, "OBS21"),
            (6_150 * MS, "WANDER2"),
            // WANDER2's last frame at 5.8, τ 0.5 s.
            (6_300 * MS + 1, "nobody"),
        ])
    );
    assert_eq!(
        timeline(&scenario, "r3.drive"),
        expect_timeline(&[
            (0, "nobody"),
            (0, "OBS32"),
            (200 * MS, "OBS33"),
            (3_200 * MS, "OBS32"),
            (6_150 * MS, "WANDER3"),
            (6_300 * MS + 1, "nobody"),
        ])
    );
}

#[test]
fn every_node_claims_every_group_once_a_period_and_offers_zero_for_a_target_it_does_not_watch() {
    let scenario = Scenario::run("multi-target-observation");
    let claims: Vec<(u64, Claim)> = scenario
        .outcome
        .claims
        .iter()
        .map(|f| {
            (
                f.t_us,
                Claim::decode(&f.frame).expect("a claim the nodes sent decodes"),
            )
        })
        .collect();
    for node in 1..=3u8 {
        for group in 0..4u8 {
            let times: Vec<u64> = claims
                .iter()
                .filter(|(_, c)| c.node == node && c.group == group)
                .map(|(t, _)| *t)
                .collect();
            // Every 0.1 s from 0 to the end (6.5, inclusive); r1 stops at 3.0 (its last claim
            // at 2.9).
            let end = if node == 1 {
                3_000 * MS
            } else {
                6_500 * MS + 1
            };
            let expected: Vec<u64> = (0..)
                .map(|k| k * 100 * MS)
                .take_while(|&t| t < end)
                .collect();
            assert_eq!(times, expected, "node {node}, group {group}");
        }
    }
    let offered = |node: u8, group: u8, t: u64| {
        claims
            .iter()
            .find(|(at, c)| *at == t && c.node == node && c.group == group)
            .map(|(_, c)| c.eligibility)
    };
    // While r1 runs, r2 offers 600 for t1 and 500 for t2; from 3.2 on it watches t1 and offers
    // 0 for t2. r3 offers 0 for t3 once it watches t2.
    assert_eq!(offered(2, 0, 2_000 * MS), Some(600));
    assert_eq!(offered(2, 1, 2_000 * MS), Some(500));
    assert_eq!(offered(2, 1, 4_000 * MS), Some(0));
    assert_eq!(offered(3, 2, 2_000 * MS), Some(300));
    assert_eq!(offered(3, 2, 4_000 * MS), Some(0));
    assert_eq!(offered(3, 1, 4_000 * MS), Some(400));
    // Nobody sees t4: every claim for it offers 0.
    assert!(
        claims
            .iter()
            .filter(|(_, c)| c.group == 3)
            .all(|(_, c)| c.eligibility == 0)
    );
    // The bus carries them in arbitration order within an instant: better claims first (one
    // node's claims for several groups may share an identifier: it sends them one after another).
    for pair in scenario.outcome.claims.windows(2) {
        if pair[0].t_us == pair[1].t_us {
            assert!(
                pair[0].frame.raw_id().0 <= pair[1].frame.raw_id().0,
                "{pair:?}"
            );
        }
    }
}

/// Two robots, one target, equal eligibilities: from the second claims on, exactly one holds it,
/// the lower node id, and keeps it; the other's observer delivers nothing. In both orders of the
/// robots' frames at each instant (the topics' ids decide the bus order). Both boot at 0 and
/// claim at once, before any reading (they offer 0), so both hold until their claims of 0.1 s.
#[test]
fn with_equal_eligibilities_exactly_one_robot_holds_the_task_the_lower_id() {
    for (id_a, id_b) in [(0x111, 0x121), (0x121, 0x111)] {
        let start = vec![(0, vec![]), (0, vec![0, 1]), (100 * MS, vec![0])];
        let text = format!(
            r#"
[nodes.a]
id = 4
[nodes.b]
id = 9
[topics.obs_a]
can_id = {id_a:#x}
length = 2
[topics.obs_b]
can_id = {id_b:#x}
length = 2
[ports."a.drive"]
[ports."b.drive"]
[connections.OA]
topic = "obs_a"
port = "a.drive"
kind = "override"
period = 0.3
rule = "OA & task"
[connections.OB]
topic = "obs_b"
port = "b.drive"
kind = "override"
period = 0.3
rule = "OB & task"
[ble.task]
period = 0.1
value = {{ offset = 0, size = 2 }}
[ble.task.nodes]
a = "obs_a"
b = "obs_b"
[[events]]
topic = "obs_a"
rate_hz = 20.0
to = 2.0
data = [0xF4, 0x01]
[[events]]
topic = "obs_b"
rate_hz = 20.0
to = 2.0
data = [0xF4, 0x01]
"#
        );
        let network = pab_tests::network("tie", &text);
        let nodes = pab_lang::compile::compile(&network).unwrap_or_else(|e| panic!("{e:?}"));
        let outcome = pab_lang::sim::simulate(&network, &nodes, &pab_lang::sim::Options::default())
            .unwrap_or_else(|e| panic!("{e}"));
        let holders: Vec<(u64, Vec<usize>)> = outcome.holdings[0]
            .iter()
            .map(|c| (c.t_us, c.holders.clone()))
            .collect();
        let mut expected = start;
        // The readings' freshness ends two periods after the last frames (1.95 s).
        expected.push((2_150 * MS, vec![]));
        assert_eq!(
            holders, expected,
            "frames of a at {id_a:#x}, of b at {id_b:#x}"
        );
        let b_port = 1;
        let b_at_first_claims = outcome.selected_at(b_port, 100 * MS);
        assert!(
            outcome.timelines[b_port]
                .iter()
                .filter(|c| c.t_us >= 100 * MS)
                .all(|c| c.selected.is_none())
                && b_at_first_claims.is_none(),
            "b's observer delivered after 0.1 s: {:?}",
            outcome.timelines[b_port]
        );
    }
}
