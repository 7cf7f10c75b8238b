//! A network file's mistakes as a person meets them: every one in one run, in the file's order,
//! each with its line and a caret, causes without their cascades, and "did you mean".

use pab_lang::diagnostic::{Diagnostics, Source};
use pab_lang::network::Network;

const GOOD: &str = r#"[nodes.hand]
id = 2

[topics.grasp]
can_id = 0x120

[topics.release]
can_id = 0x121

[ports."hand.command"]

[connections.GRASP]
topic = "grasp"
port = "hand.command"
st = 0.5
tc = 1.0
rule = "GRASP & !RELEASE"

[connections.RELEASE]
topic = "release"
port = "hand.command"
st = 1.0
tc = 0.5
"#;

fn errors(text: &str) -> Diagnostics {
    match Network::parse(Source::new("net.toml", text)) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(errors) => errors,
    }
}

fn edit(changes: &[(&str, &str)]) -> String {
    let mut text = GOOD.to_string();
    for (old, new) in changes {
        assert_eq!(text.matches(old).count(), 1, "{old}");
        text = text.replacen(old, new, 1);
    }
    text
}

#[test]
fn the_example_is_valid() {
    Network::parse(Source::new("net.toml", GOOD)).expect("valid");
}

#[test]
fn three_independent_structural_mistakes_are_three_errors_in_file_order_with_snippets() {
    let text = edit(&[
        ("id = 2\n", "idd = 2\n"),
        ("st = 0.5\ntc = 1.0\n", "st = 0.5\ntcc = 1.0\n"),
        ("tc = 0.5\n", "tc = \"500ms\"\n"),
    ]);
    let found = errors(&text);
    let lines: Vec<String> = found.0.iter().map(ToString::to_string).collect();
    assert_eq!(found.0.len(), 3, "{lines:#?}");
    assert!(
        lines[0].starts_with("net.toml:2:1: error: unknown key `idd`; did you mean `id`?"),
        "{lines:#?}"
    );
    assert!(
        lines[1].starts_with("net.toml:16:1: error: unknown key `tcc`; did you mean `tc`?"),
        "{lines:#?}"
    );
    assert!(
        lines[2].starts_with(
            "net.toml:23:6: error: `tc` is seconds, a number: tc = 0.5, not the string \"500ms\""
        ),
        "{lines:#?}"
    );
    assert!(
        lines[2].contains("durations here are numbers of seconds: 0.5"),
        "{lines:#?}"
    );
    // Each rendered with its line and a caret under the cause.
    let rendered = found.render(false);
    assert!(
        rendered.contains("16 | tcc = 1.0\n   | ^^^\n"),
        "{rendered}"
    );
    assert!(
        rendered.contains("23 | tc = \"500ms\"\n   |      ^^^^^^^"),
        "{rendered}"
    );
}

#[test]
fn a_key_with_the_wrong_type_is_not_also_reported_missing() {
    // `topic` blanked for its type would otherwise be "missing" next: one mistake, one error.
    let text = edit(&[("topic = \"grasp\"\n", "topic = 5\n")]);
    let found = errors(&text);
    assert_eq!(found.0.len(), 1, "{found}");
    assert!(
        found.0[0]
            .to_string()
            .contains("`topic` is a topic's name, a string"),
        "{found}"
    );
}

#[test]
fn an_unknown_section_is_named_a_section_with_the_known_ones() {
    let found = errors(&format!("{GOOD}\n[conections.X]\ntopic = \"grasp\"\n"));
    assert_eq!(found.0.len(), 1, "{found}");
    let line = found.0[0].to_string();
    assert!(
        line.contains("unknown section `conections`; did you mean `connections`?"),
        "{line}"
    );
}

#[test]
fn an_undefined_topic_is_one_error_with_a_suggestion_and_no_cascade() {
    // GRASP's topic is misspelt: GRASP is refused, and RELEASE's rule, which names GRASP,
    // is not reported as naming an unknown connection.
    let text = edit(&[
        ("topic = \"grasp\"\n", "topic = \"grsp\"\n"),
        ("tc = 0.5\n", "tc = 0.5\nrule = \"RELEASE & !GRASP\"\n"),
    ]);
    let found = errors(&text);
    let lines: Vec<String> = found.0.iter().map(ToString::to_string).collect();
    assert_eq!(lines.len(), 1, "{lines:#?}");
    assert!(
        lines[0].contains(
            "topic `grsp` is not defined (topics: grasp, release); did you mean `grasp`?"
        ),
        "{lines:#?}"
    );
}

#[test]
fn an_unknown_connection_in_a_rule_gets_a_suggestion() {
    let text = edit(&[(
        "rule = \"GRASP & !RELEASE\"",
        "rule = \"GRASP & !RELEASEE\"",
    )]);
    let found = errors(&text);
    assert_eq!(found.0.len(), 1, "{found}");
    assert!(
        found.0[0]
            .to_string()
            .contains("unknown connection `RELEASEE`")
            && found.0[0].to_string().contains("did you mean `RELEASE`?"),
        "{found}"
    );
}
