//! Take and Return driven by competitive dynamics (examples/take-and-return-dynamics.toml): the
//! group on the arm node, its gates read by the gaze and hand nodes from the arm's Gates frames.
//! The same deliverers as the rule-only example (tests/tests/take_and_return.rs) phase by phase;
//! a phase's window starts once its gate has opened, some 0.3 s after its context connection
//! became active (the example's comment says why).

use pab_tests::{Phase, Scenario, phase};

/// Cycle 1: A to F, then back to A (take-and-return.rs's CYCLE, B, E and F from their gates).
const CYCLE: [Phase; 7] = [
    phase("A", 2.1, 10.0, Some("C14"), Some("C11"), Some("C16")),
    phase("B", 10.9, 14.0, Some("C1"), Some("C3"), Some("C16")),
    phase("C", 14.6, 16.4, None, None, Some("C5")),
    phase("D", 21.0, 26.0, None, Some("C11"), None),
    phase("E", 26.9, 30.0, Some("C6"), Some("C8"), None),
    phase("F", 30.9, 31.9, None, None, Some("C10")),
    phase("A again", 39.0, 50.0, Some("C14"), Some("C11"), Some("C16")),
];

/// Cycle 2: the person takes the object back during the approach; the system returns to A.
const TAKE_BACK: [Phase; 5] = [
    phase("B", 50.9, 54.0, Some("C1"), Some("C3"), Some("C16")),
    phase("C", 54.6, 56.4, None, None, Some("C5")),
    phase("D", 61.0, 64.0, None, Some("C11"), None),
    phase("E", 64.9, 68.0, Some("C6"), Some("C8"), None),
    phase(
        "A after the take-back",
        72.0,
        78.0,
        Some("C14"),
        Some("C11"),
        Some("C16"),
    ),
];

#[test]
fn the_dynamics_take_the_robot_through_a_to_f_in_order() {
    let scenario = Scenario::run("take-and-return-dynamics");
    scenario.expect_phases(&CYCLE);
    // The object is handed over: the hand received the release commands while it held it.
    assert!(scenario.delivered("C10", 30.0, 32.0) >= 10);
}

#[test]
fn taking_the_object_back_during_the_approach_returns_to_a() {
    let scenario = Scenario::run("take-and-return-dynamics");
    scenario.expect_phases(&TAKE_BACK);
    // Release never opens in this cycle: no release command gets through.
    assert_eq!(scenario.delivered("C10", 45.0, 80.0), 0);
    // Grasped lapses at 70.9 s: hold's gate closes, bring loses its presupposition as hold's
    // memory fades and closes (71.2 s), Rest Arm takes the arm once the face has gone (71.9 s);
    // in between the arm is nobody's.
    scenario.expect("take-back", 71.3, 71.9, "arm.target", None);
    scenario.expect("take-back", 69.1, 72.0, "hand.command", Some("C16"));
}

#[test]
fn the_gaze_and_the_hand_follow_the_arms_gates_at_the_instant_they_change() {
    let scenario = Scenario::run("take-and-return-dynamics");
    // The arm's Gates frames: one at every change and a repeat every 100 ms otherwise, so about
    // ten a second (the figure docs/dynamics.md gives for a group's bus load).
    let gates = &scenario.outcome.gates;
    let seconds = scenario.outcome.until_us as f64 / 1e6;
    let rate = gates.len() as f64 / seconds;
    assert!((10.0..10.5).contains(&rate), "{rate} Gates frames a second");
    assert!(
        gates.windows(2).all(|w| w[1].t_us - w[0].t_us <= 100_000),
        "never 100 ms without"
    );
    // Grasp stops reaching the hand the instant hold's gate opens on the arm (16.8 s), in the
    // simulation as on a bus without delay: the hand's timeline changes at a step's instant.
    let hand = scenario.outcome.timelines[scenario
        .network
        .ports
        .iter()
        .position(|p| p.name == "hand.command")
        .unwrap()]
    .clone();
    let released = hand
        .iter()
        .find(|c| (16_000_000..17_500_000).contains(&c.t_us) && c.selected.is_none())
        .expect("the hand lets go of C5 once hold opens");
    assert!(
        gates.iter().any(|f| f.t_us == released.t_us),
        "a Gates frame at {} µs",
        released.t_us
    );
}
