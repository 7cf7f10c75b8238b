//! The paper's "Take and Return" (section V, Tables I-III) through the checker, the compiler and
//! the simulator: which connection delivers at Arm, Gaze and Hand Control, phase by phase.
//!
//! Windows start once the arbitration has settled: a behaviour at 10 Hz with σ = 0.2 is active
//! 0.5 s after its first frame, and its connections lapse 3 s after its last. The comments of the
//! example files derive every time used here.

use pab_tests::{Phase, Scenario, phase};

#[test]
fn take_an_object() {
    let scenario = Scenario::run("take-an-object");
    scenario.expect_phases(&[
        phase("nothing in view", 0.0, 2.0, None, None, None),
        phase("B", 2.6, 6.0, Some("C1"), Some("C3"), None),
        phase("C", 6.6, 9.0, None, None, Some("C5")),
        // Grasp Detect lapsed at 11.9 s and the object is still seen: without Grasped, the
        // subsystem reaches for the object again.
        phase("B again", 12.0, 14.0, Some("C1"), Some("C3"), None),
    ]);
}

#[test]
fn return_an_object() {
    let scenario = Scenario::run("return-an-object");
    scenario.expect_phases(&[
        phase("nobody in view", 0.0, 2.0, None, None, None),
        phase("E", 2.6, 6.0, Some("C6"), Some("C8"), None),
        phase("F", 6.6, 8.0, None, None, Some("C10")),
        phase("E again", 11.0, 12.0, Some("C6"), Some("C8"), None),
    ]);
}

/// Cycle 1 of the example: A to F, then back to A.
const CYCLE: [Phase; 7] = [
    phase("A", 2.1, 10.0, Some("C14"), Some("C11"), Some("C16")),
    phase("B", 10.6, 14.0, Some("C1"), Some("C3"), Some("C16")),
    phase("C", 14.6, 16.4, None, None, Some("C5")),
    phase("D", 21.0, 26.0, None, Some("C11"), None),
    phase("E", 26.6, 30.0, Some("C6"), Some("C8"), None),
    phase("F", 30.6, 31.9, None, None, Some("C10")),
    phase("A again", 39.0, 50.0, Some("C14"), Some("C11"), Some("C16")),
];

/// Cycle 2: the person takes the object back during the approach; the system returns to A.
const TAKE_BACK: [Phase; 5] = [
    phase("B", 50.6, 54.0, Some("C1"), Some("C3"), Some("C16")),
    phase("C", 54.6, 56.4, None, None, Some("C5")),
    phase("D", 61.0, 64.0, None, Some("C11"), None),
    phase("E", 64.6, 68.0, Some("C6"), Some("C8"), None),
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
fn take_and_return_goes_through_a_to_f_in_order() {
    let scenario = Scenario::run("take-and-return");
    scenario.expect_phases(&CYCLE);
    // The object is handed over: the hand received the release commands while it held it.
    assert!(scenario.delivered("C10", 30.0, 32.0) >= 10);
}

/// The same network on a CAN FD bus (examples/take-and-return-fd.toml: its behaviours' topics
/// classic, two sensor topics CAN FD that no connection reads) goes through the same phases.
#[test]
fn take_and_return_on_can_fd_goes_through_the_same_phases() {
    let scenario = Scenario::run("take-and-return-fd");
    scenario.expect_phases(&CYCLE);
    scenario.expect_phases(&TAKE_BACK);
    assert!(scenario.delivered("C10", 30.0, 32.0) >= 10);
}

#[test]
fn taking_the_object_back_during_the_approach_returns_to_a() {
    let scenario = Scenario::run("take-and-return");
    scenario.expect_phases(&TAKE_BACK);
    // Return an object never completes in this cycle: no release command gets through.
    assert_eq!(scenario.delivered("C10", 45.0, 80.0), 0);
    // The approach stops when Grasped lapses (70.9 s), Rest Arm takes the arm once the face has
    // gone (71.9 s); in between the arm is nobody's.
    scenario.expect("take-back", 71.0, 71.9, "arm.target", None);
    scenario.expect("take-back", 69.1, 72.0, "hand.command", Some("C16"));
}

#[test]
fn grasped_inhibits_the_object_detector_while_the_hand_holds_the_object() {
    // The paper's Fig. 5: Object Detector is stimulated and active in D, but its output is
    // inhibited by Grasped.
    let scenario = Scenario::run("take-and-return");
    let c1 = scenario.connection("C1");
    let rows: Vec<_> = scenario
        .outcome
        .rows_of(c1, 16_600_000, 18_000_000)
        .collect();
    assert_eq!(
        rows.len(),
        14,
        "Object Detector publishes at 10 Hz until 18 s"
    );
    assert!(
        rows.iter().all(|row| row.active && !row.delivered),
        "{rows:?}"
    );
}

#[test]
fn rest_arm_is_silent_and_inactive_while_the_hand_holds_the_object() {
    let scenario = Scenario::run("take-and-return");
    for name in ["C14", "C16"] {
        let connection = scenario.connection(name);
        assert_eq!(
            scenario
                .outcome
                .rows_of(connection, 16_000_000, 31_500_000)
                .count(),
            0
        );
    }
}
