//! `pabctl check`'s warnings about `[dynamics.*]` groups (`check::dynamics`), on small networks
//! with one defect each: a weak exclusion, a presupposition cycle, contexts that can never
//! saturate; each warning at the line and column of the offending key, and none on the door
//! example.

use pab_lang::check;
use pab_tests::{example_text, network};

const BASE: &str = r#"[nodes.base]
id = 5
[topics.seen]
can_id = 0x121
[ports."base.p"]
[connections.SEEN]
topic = "seen"
port = "base.p"
st = 1.0
tc = 0.1
[dynamics.door]
node = "base"
"#;

/// The warnings of BASE + `extra` (which must parse and be consistent), as `pabctl check`
/// prints them.
fn warnings(extra: &str) -> Vec<String> {
    let network = network("dyn", &format!("{BASE}{extra}"));
    assert!(check::check(&network).is_consistent());
    check::dynamics::warnings(&network)
        .iter()
        .map(ToString::to_string)
        .collect()
}

/// The one warning of BASE + `extra`: at `extra`'s line `line` (1-based), column `column`, and
/// containing each of `parts`.
fn expect_warning(extra: &str, line: usize, column: usize, parts: &[&str]) {
    let found = warnings(extra);
    assert_eq!(found.len(), 1, "{found:#?}\nfor:\n{extra}");
    let at = format!(
        "dyn.toml:{}:{column}: warning: dynamics group `door`: ",
        BASE.lines().count() + line
    );
    assert!(found[0].starts_with(&at), "expected {at} in:\n{}", found[0]);
    for part in parts {
        assert!(found[0].contains(part), "{part:?} not in:\n{}", found[0]);
    }
}

#[test]
fn the_door_example_has_no_warning() {
    let network = network("door-dynamics", &example_text("door-dynamics"));
    assert_eq!(check::dynamics::warnings(&network), []);
}

#[test]
fn an_exclusion_with_the_papers_gamma_is_too_weak() {
    // The group's γ, at the `excludes` entry.
    expect_warning(
        "gamma = 1.0\n[dynamics.door.behaviours.search]\ncontext = \"SEEN\"\nexcludes = [\"recognise\"]\n[dynamics.door.behaviours.recognise]\ncontext = \"SEEN\"\n",
        4,
        13,
        &[
            "`search` excludes `recognise` with γ = 1 (the group's `gamma`), below 1.5",
            "both stay half-active, n² = 0.5, and their gates chatter",
        ],
    );
    // A per-pair γ, at its value.
    expect_warning(
        "[dynamics.door.behaviours.search]\ncontext = \"SEEN\"\n[dynamics.door.behaviours.recognise]\ncontext = \"SEEN\"\ngamma = { search = 1.4 }\n",
        5,
        20,
        &["`recognise` excludes `search` with γ = 1.4, below 1.5"],
    );
    // 1.5 is enough.
    assert_eq!(
        warnings(
            "gamma = 1.5\n[dynamics.door.behaviours.search]\ncontext = \"SEEN\"\nexcludes = [\"recognise\"]\n[dynamics.door.behaviours.recognise]\ncontext = \"SEEN\"\n"
        ),
        Vec::<String>::new()
    );
}

#[test]
fn a_presupposition_cycle_is_named_in_order() {
    expect_warning(
        "[dynamics.door.behaviours.search]\ncontext = \"SEEN\"\n\
         [dynamics.door.behaviours.approach]\ncontext = \"SEEN\"\nrequires = [\"recognise\"]\n\
         [dynamics.door.behaviours.recognise]\ncontext = \"SEEN\"\nrequires = [\"search\", \"pass\"]\n\
         [dynamics.door.behaviours.pass]\ncontext = \"SEEN\"\nrequires = [\"approach\"]\n",
        5,
        13,
        &[
            "presupposition cycle approach → recognise → pass → approach (each requires the next)",
            "none of them can ever start",
        ],
    );
}

#[test]
fn contexts_that_can_never_saturate() {
    expect_warning(
        "[dynamics.door.behaviours.search]\ncontext = 0.9\n",
        2,
        11,
        &["behaviour `search` can never start: its constant context 0.9 stays below 0.9564"],
    );
    expect_warning(
        "[dynamics.door.behaviours.search]\ncontext = { topic = \"seen\", value = { offset = 0, size = 1 }, scale = 300.0, timeout = 0.2 }\n",
        2,
        11,
        &[
            "its context from topic `seen` (unsigned field of 1 byte, at most 255, / scale 300 = at most 0.8500) stays below 0.9564",
        ],
    );
    // τ_ρ2 = 5 τ_ρ1: the threshold is (−4 + √56) / 4 = 0.8708, so 0.9 can start and 0.85
    // cannot.
    expect_warning(
        "tau_rho_slow = 5.0\n[dynamics.door.behaviours.search]\ncontext = 0.9\n[dynamics.door.behaviours.recognise]\ncontext = 0.85\n",
        5,
        11,
        &["`recognise` can never start: its constant context 0.85 stays below 0.8708"],
    );
    // A full byte over 255 saturates.
    assert_eq!(
        warnings(
            "[dynamics.door.behaviours.search]\ncontext = { topic = \"seen\", value = { offset = 0, size = 1 }, scale = 255.0, timeout = 0.2 }\n"
        ),
        Vec::<String>::new()
    );
}
