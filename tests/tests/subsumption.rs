//! `examples/subsumption.toml`: a subsumption stack with every connection kind. The timeline its
//! comment states, to the microsecond: a special connection acts until its period has passed
//! since its last frame, inclusive, so each hand-over after a lapse comes 1 µs after it.

use pab_tests::Scenario;

#[test]
fn the_stack_hands_the_drive_over_as_the_example_says() {
    let scenario = Scenario::run("subsumption");
    let name = |selected: Option<usize>| {
        selected.map_or("nobody".to_string(), |c| {
            scenario.network.connections[c].name.clone()
        })
    };
    let timeline: Vec<(u64, String)> = scenario.outcome.timelines[0]
        .iter()
        .map(|change| (change.t_us, name(change.selected)))
        .collect();
    let expected = [
        (0, "nobody"),
        (0, "WANDER"),
        (3_000_000, "SEEK"),
        (6_000_000, "AVOID"),
        (7_700_001, "SEEK"),
        (9_000_000, "WANDER"),
        (10_500_001, "SEEK"),
        (12_000_000, "nobody"),
        (13_000_001, "SEEK"),
        (15_400_001, "WANDER"),
        (16_000_000, "nobody"),
        (19_000_001, "WANDER"),
        (20_400_001, "nobody"),
    ];
    let expected: Vec<(u64, String)> = expected
        .iter()
        .map(|(t, who)| (*t, who.to_string()))
        .collect();
    assert_eq!(timeline, expected);
    // Each phase of the file: the one connection that delivers in it.
    for (from, to, who) in [
        (0.0, 3.0, Some("WANDER")),
        (3.0, 6.0, Some("SEEK")),
        (6.0, 7.7, Some("AVOID")),
        (7.71, 9.0, Some("SEEK")),
        (9.0, 10.5, Some("WANDER")),
        (10.51, 12.0, Some("SEEK")),
        (12.0, 13.0, None),
        (13.01, 15.4, Some("SEEK")),
        (15.41, 16.0, Some("WANDER")),
        (16.0, 19.0, None),
        (19.01, 20.4, Some("WANDER")),
    ] {
        scenario.expect("example", from, to, "base.drive", who);
    }
    // The coordinating connections never deliver; the overriders' frames in the lower layers'
    // times are discarded: SEEK during AVOID (6.0 to 7.7), LOST (9.0 to 10.5), HALT (12.0 to
    // 13.0), 45 in all.
    for virtual_connection in ["HALT", "LOST", "QUIET"] {
        assert_eq!(scenario.delivered(virtual_connection, 0.0, 30.0), 0);
    }
    assert_eq!(scenario.delivered("SEEK", 0.0, 30.0), 120 - 45);
}
