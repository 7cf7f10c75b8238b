//! The checker on the examples and on inconsistent variants of Take and Return: each overlap is
//! reported with the minimal set of active connections that shows it, at the line of the rule.

use pab_lang::check::{self, Overlap};
use pab_tests::{example_text, network};

#[test]
fn every_example_is_consistent() {
    for name in [
        "figure-1",
        "take-an-object",
        "return-an-object",
        "take-and-return",
        "take-and-return-fd",
        "subsumption",
    ] {
        let network = network(name, &example_text(name));
        let report = check::check(&network);
        assert!(
            report.is_consistent(),
            "{name}: {:?}",
            report.errors(&network)
        );
        assert!(report.ports.iter().all(|port| port.dead.is_empty()));
    }
}

/// The 1-based line of the first line of `text` containing `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|line| line.contains(needle))
        .expect("needle")
        + 1
}

#[test]
fn forgetting_grasped_in_reaching_overlaps_with_the_approach() {
    // Table I's rule without Table III's "& !C13": reaching (C1) and approaching (C6) can both
    // drive the arm when the object and a face are seen while the hand holds the object.
    let text = example_text("take-and-return")
        .replace("rule = \"(C1 & !C2) & !C13\"", "rule = \"C1 & !C2\"");
    let network = network("variant", &text);
    let report = check::check(&network);
    assert!(!report.is_consistent());
    let arm = &report.ports[0];
    assert_eq!(network.ports[arm.port].name, "arm.target");
    // Arm's connections in file order: C1, C2, C6, C7, C13, C14 (bits 0 to 5).
    assert_eq!(
        arm.overlaps,
        vec![Overlap {
            first: 0,
            second: 2,
            mask: 0b01_0101
        }]
    );
    assert!(report.ports[1].is_consistent() && report.ports[2].is_consistent());
    let errors = report.errors(&network);
    assert_eq!(errors.len(), 1);
    assert_eq!(
        errors[0].line(),
        Some(line_of(&text, "rule = \"(C6 & !C7) & C13\""))
    );
    assert!(
        errors[0].message.contains(
            "C1 (rule \"C1 & !C2\") and C6 (rule \"(C6 & !C7) & C13\") can both deliver when the active connections are {C1, C6, C13} and no other"
        ),
        "{}",
        errors[0]
    );
}

#[test]
fn a_hand_that_grasps_and_releases_at_once_is_refused() {
    // Without "& !C15", Grasp Detect (C5) and Release Detect (C10) both command the hand when
    // both are active while the object is held.
    let text = example_text("take-and-return").replace("rule = \"C5 & !C15\"", "rule = \"C5\"");
    let network = network("variant", &text);
    let report = check::check(&network);
    let hand = report
        .ports
        .iter()
        .find(|p| network.ports[p.port].name == "hand.command")
        .unwrap();
    // Hand's connections: C5, C10, C15, C16.
    assert_eq!(
        hand.overlaps,
        vec![Overlap {
            first: 0,
            second: 1,
            mask: 0b0111
        }]
    );
}

#[test]
fn several_overlaps_are_all_reported() {
    // Rest Arm that ignores every other behaviour overlaps with each of them.
    let text = example_text("take-and-return")
        .replace("rule = \"!(C1 | C2 | C6 | C7)\"", "rule = \"C14\"");
    let network = network("variant", &text);
    let report = check::check(&network);
    let arm = &report.ports[0];
    // C14 (bit 5) overlaps with C1 ({C1, C14}) and with C6 ({C6, C13, C14}).
    assert_eq!(
        arm.overlaps,
        vec![
            Overlap {
                first: 0,
                second: 5,
                mask: 0b10_0001
            },
            Overlap {
                first: 2,
                second: 5,
                mask: 0b11_0100
            },
        ]
    );
    assert_eq!(report.errors(&network).len(), 2);
}

#[test]
fn a_rule_that_can_never_deliver_is_refused() {
    let text = example_text("take-and-return")
        .replace("rule = \"C10 & C15\"", "rule = \"C10 & C15 & !C10\"");
    let network = network("variant", &text);
    let report = check::check(&network);
    let errors = report.errors(&network);
    assert_eq!(errors.len(), 1);
    assert!(
        errors[0].message.contains("C10 can never deliver"),
        "{}",
        errors[0]
    );
    assert_eq!(errors[0].line(), Some(line_of(&text, "C10 & C15 & !C10")));
}
