//! The network file's JSON Schema for editors (docs/network-file.schema.json,
//! `pab_lang::network::json_schema`): the committed file is the one the parser's types generate,
//! every example (and so every `pabctl init` starter, which are the examples' text) and the book's
//! reference block are valid against it, and a file with an unknown key or a value of the wrong
//! type is not, as the parser refuses it too.

use std::path::{Path, PathBuf};

use jsonschema::Validator;
use pab_lang::diagnostic::Source;
use pab_lang::network::{self, Network};
use serde_json::Value;

const REGENERATE: &str = "cargo run -q -p pabctl -- schema > docs/network-file.schema.json";

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn validator() -> Validator {
    let schema: Value = serde_json::from_str(&network::json_schema()).expect("the schema is JSON");
    // Checks the schema against draft 7's meta-schema too.
    jsonschema::draft7::new(&schema).expect("a valid draft-7 schema")
}

/// A TOML text as the JSON value an editor validates, or the TOML error.
fn as_json(text: &str) -> Value {
    let value: toml::Value = toml::from_str(text).expect("TOML");
    serde_json::to_value(value).expect("TOML values are JSON values")
}

/// The schema's complaints about `text`, one line each: where and what.
fn complaints(validator: &Validator, text: &str) -> Vec<String> {
    let instance = as_json(text);
    validator
        .iter_errors(&instance)
        .map(|error| format!("at {}: {error}", error.instance_path()))
        .collect()
}

#[test]
fn the_committed_schema_is_the_generated_one() {
    let path = root().join("docs/network-file.schema.json");
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    let generated = network::json_schema();
    assert!(
        committed == generated,
        "{} is not the schema the parser's types generate (a key of a Raw* table or its doc \
         comment changed?); regenerate it from the repository's root with:\n    {REGENERATE}",
        path.display()
    );
}

/// Every key an editor offers comes with its description: a key added to a `Raw*` table needs a
/// doc comment (its type, unit, default and range, as docs/network-file.md says them).
#[test]
fn every_key_is_described() {
    let schema: Value = serde_json::from_str(&network::json_schema()).expect("JSON");
    let mut tables = vec![("the file".to_string(), &schema)];
    for (name, definition) in schema["definitions"].as_object().expect("definitions") {
        tables.push((name.clone(), definition));
    }
    let mut keys = 0;
    for (table, definition) in tables {
        assert!(
            definition["description"].is_string(),
            "{table} has no description"
        );
        for (key, property) in definition["properties"].as_object().into_iter().flatten() {
            let description = property["description"].as_str().unwrap_or_default();
            assert!(
                !description.is_empty(),
                "{table}: `{key}` has no doc comment"
            );
            keys += 1;
        }
    }
    assert!(keys > 100, "only {keys} keys found");
}

#[test]
fn every_example_is_valid() {
    let validator = validator();
    let mut checked = Vec::new();
    for dir in ["examples", "examples/dynamics", "host-tools/tests/fixtures"] {
        let mut paths: Vec<PathBuf> = std::fs::read_dir(root().join(dir))
            .expect(dir)
            .map(|entry| entry.expect("a directory entry").path())
            .filter(|path| path.extension().is_some_and(|ext| ext == "toml"))
            .collect();
        paths.sort();
        for path in paths {
            let text = std::fs::read_to_string(&path).expect("an example");
            // The parser's verdict first: the schema must accept what the parser accepts.
            if let Err(errors) = Network::parse(Source::new(path.display().to_string(), &text)) {
                panic!("{} does not parse:\n{errors}", path.display());
            }
            let found = complaints(&validator, &text);
            assert!(
                found.is_empty(),
                "{} is a valid network the schema refuses:\n{}",
                path.display(),
                found.join("\n")
            );
            checked.push(path);
        }
    }
    // Not vacuous: the examples are where they are expected (14 in examples/, 8 in dynamics/).
    assert!(checked.len() >= 22, "only {} files checked", checked.len());
}

/// The book's reference (docs/network-file.md, its annotated TOML block) shows every key in
/// place: the schema takes each of them there.
#[test]
fn the_reference_block_is_valid() {
    let page = std::fs::read_to_string(root().join("docs/network-file.md")).expect("the page");
    let start = page.find("```toml\n").expect("a toml block") + "```toml\n".len();
    let end = start + page[start..].find("\n```").expect("the block's end");
    let found = complaints(&validator(), &page[start..end]);
    assert!(found.is_empty(), "{}", found.join("\n"));
}

/// Files the parser refuses for their shape, and the place the schema must refuse each at (a JSON
/// pointer into the file's tables; "" for the file itself).
#[test]
fn unknown_keys_and_wrong_types_are_refused() {
    let validator = validator();
    let base = "[nodes.arm]\nid = 1\n\n[topics.grasp]\ncan_id = 0x100\n\n\
                [ports.\"arm.gripper\"]\n\n[connections.C1]\ntopic = \"grasp\"\n\
                port = \"arm.gripper\"\nst = 1.0\ntc = 0.5\n";
    let source = |text: &str| Source::new("net.toml", text);
    Network::parse(source(base)).expect("the base file is valid");
    assert_eq!(complaints(&validator, base), Vec::<String>::new());
    let cases: &[(&str, &str, &str)] = &[
        ("an unknown table", "[nodez.hand]\nid = 2\n", ""),
        (
            "an unknown key",
            "[nodes.hand]\nid = 2\ncolour = \"red\"\n",
            "/nodes/hand",
        ),
        (
            "an unknown key of an inline table",
            "[ports.\"arm.level\"]\ncombine = \"max\"\nvalue = { offset = 0, size = 2, sign = true }\n",
            "/ports/arm.level/value",
        ),
        (
            "a string for an integer",
            "[nodes.hand]\nid = \"two\"\n",
            "/nodes/hand/id",
        ),
        (
            "a string for a number",
            "[connections.C2]\ntopic = \"grasp\"\nport = \"arm.gripper\"\nst = \"1\"\ntc = 0.5\n",
            "/connections/C2/st",
        ),
        // Not 256.0: JSON has one kind of number, and JSON Schema's "integer" is any number
        // without a fractional part; only the parser tells TOML's 256.0 from 256.
        (
            "a fraction for an integer",
            "[topics.release]\ncan_id = 256.5\n",
            "/topics/release/can_id",
        ),
        (
            "a kind that is none",
            "[connections.C2]\ntopic = \"grasp\"\nport = \"arm.gripper\"\nkind = \"sometimes\"\nperiod = 1.0\n",
            "/connections/C2/kind",
        ),
        (
            "a combination that is none",
            "[ports.\"arm.level\"]\ncombine = \"mean\"\nvalue = { offset = 0, size = 2 }\n",
            "/ports/arm.level/combine",
        ),
        (
            "a missing key",
            "[topics.release]\nextended = true\n",
            "/topics/release",
        ),
        (
            "a table for a list",
            "[events]\ntopic = \"grasp\"\n",
            "/events",
        ),
    ];
    for (what, extra, at) in cases {
        let text = format!("{base}\n{extra}");
        assert!(
            Network::parse(source(&text)).is_err(),
            "the parser takes {what}:\n{text}"
        );
        let found = complaints(&validator, &text);
        assert!(
            found
                .iter()
                .any(|complaint| complaint.starts_with(&format!("at {at}: "))),
            "the schema does not refuse {what} at `{at}`: {found:?}\n{text}"
        );
    }
}
