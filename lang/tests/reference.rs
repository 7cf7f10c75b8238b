//! The book's reference of the network file (docs/network-file.md, its annotated TOML block)
//! against the parser: every table the reference shows must list exactly the keys the parser
//! accepts there, so that neither can drift from the other.
//!
//! How the parser is asked: a key no table has (`zz_not_a_key`) is written under one table
//! header of the reference's block at a time, and the parser's "unknown key" error for that line
//! lists the keys it knows there ("known here: ..."). The reference's keys of a table are the
//! lines `key = ...` under its header, joined over the tables of one kind (`[connections.C1]`,
//! `[connections.HALT]`, ... are all `connections.*`); a table under another (`[ble.t.nodes]`)
//! documents its key in the one above. Not probed: the keys of inline tables (`value = { offset,
//! size, ... }`), which the reference explains in their comments.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use pab_lang::diagnostic::Source;
use pab_lang::network::Network;

const PROBE: &str = "zz_not_a_key";

/// Tables whose keys are names the file chooses (a map), not a fixed set: the probe is one more
/// name there. Each is checked to be taken as such, so a table cannot be skipped by mistake.
const MAPS: &[&str] = &[
    "ble.*.nodes",
    "schema.*.places",
    "schema.*.innate",
    "client.places",
];

/// The reference's TOML block: the first fenced `toml` block of the page.
fn reference_block() -> String {
    let page = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/network-file.md");
    let text = std::fs::read_to_string(&page).expect("docs/network-file.md");
    let start = text.find("```toml\n").expect("a toml block") + "```toml\n".len();
    let end = start + text[start..].find("\n```").expect("the block's end");
    text[start..end].to_string()
}

/// A table header's kind: its path with the names the file chooses as `*`. `None` for a line
/// that is not a header.
fn header_kind(line: &str) -> Option<String> {
    let line = line.trim_start();
    let header = if let Some(rest) = line.strip_prefix("[[") {
        &rest[..rest.find("]]")?]
    } else if let Some(rest) = line.strip_prefix('[') {
        &rest[..rest.find(']')?]
    } else {
        return None;
    };
    let mut parts = Vec::new();
    let mut rest = header.trim();
    while !rest.is_empty() {
        let (part, after) = if let Some(quoted) = rest.strip_prefix('"') {
            let end = quoted.find('"')?;
            (&quoted[..end], &quoted[end + 1..])
        } else {
            match rest.find('.') {
                Some(dot) => (&rest[..dot], &rest[dot..]),
                None => (rest, ""),
            }
        };
        parts.push(part.to_string());
        rest = after.trim_start_matches('.');
    }
    // The tables whose second part is a name the file chooses, and the tables under those.
    let named = [
        "nodes",
        "topics",
        "ports",
        "connections",
        "ble",
        "dynamics",
        "schema",
    ];
    let mut kind = Vec::new();
    for (index, part) in parts.iter().enumerate() {
        let chosen = (index == 1 && named.contains(&parts[0].as_str()))
            || (index == 3
                && matches!(
                    (parts[0].as_str(), parts[2].as_str()),
                    ("dynamics", "behaviours") | ("schema", "sensors")
                ))
            || (index == 2 && parts[0] == "hbba" && parts[1] == "strategies");
        kind.push(if chosen {
            "*".to_string()
        } else {
            part.clone()
        });
    }
    Some(kind.join("."))
}

/// The key a reference line sets (`key = ...` at the line's start), if any.
fn key_of(line: &str) -> Option<&str> {
    if line.starts_with([' ', '#', '[']) {
        return None;
    }
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    (!key.is_empty() && key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')).then_some(key)
}

#[test]
fn every_table_of_the_reference_lists_exactly_the_keys_the_parser_accepts() {
    let block = reference_block();
    let lines: Vec<&str> = block.lines().collect();
    // Each header's line index and kind, and the keys the reference documents per kind.
    let mut headers: Vec<(usize, String)> = Vec::new();
    let mut documented: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut current: Option<String> = None;
    for (index, line) in lines.iter().enumerate() {
        if let Some(kind) = header_kind(line) {
            documented.entry(kind.clone()).or_default();
            // A table under another documents its key there: `[ble.t.nodes]` is `ble.*`'s
            // `nodes`, `[dynamics.d.behaviours.b]` is `dynamics.*`'s `behaviours`.
            for (_, parent) in &headers {
                if let Some(rest) = kind.strip_prefix(&format!("{parent}.")) {
                    let key = rest.split('.').next().unwrap_or(rest).to_string();
                    documented.entry(parent.clone()).or_default().insert(key);
                }
            }
            headers.push((index, kind.clone()));
            current = Some(kind);
        } else if let (Some(kind), Some(key)) = (&current, key_of(line)) {
            documented
                .get_mut(kind)
                .expect("entered at its header")
                .insert(key.to_string());
        }
    }
    assert!(
        headers.len() >= 20,
        "only {} tables found in the reference",
        headers.len()
    );

    let mut accepted: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut maps_seen = BTreeSet::new();
    for (index, kind) in &headers {
        if accepted.contains_key(kind) {
            continue;
        }
        let mut probed: Vec<&str> = lines.clone();
        let probe = format!("{PROBE} = 0");
        probed.insert(index + 1, &probe);
        let text = probed.join("\n") + "\n";
        let errors = Network::parse(Source::new("network-file.md", text)).err();
        let line = index + 2;
        let said = errors.as_ref().and_then(|errors| {
            errors
                .0
                .iter()
                .find(|d| d.line() == Some(line) && d.message.contains(PROBE))
        });
        let known = said.and_then(|d| {
            let (_, list) = d.message.split_once("(known here: ")?;
            Some(
                list.trim_end_matches(')')
                    .split(", ")
                    .map(str::to_string)
                    .collect::<BTreeSet<_>>(),
            )
        });
        match known {
            Some(known) => {
                assert!(
                    !MAPS.contains(&kind.as_str()),
                    "[{kind}] is listed as a map but refuses unknown keys"
                );
                accepted.insert(kind.clone(), known);
            }
            None => {
                assert!(
                    MAPS.contains(&kind.as_str()),
                    "[{kind}]: the parser did not name the keys it knows for a key written on \
                     line {line} of the reference's block (a map of names? add it to MAPS); it \
                     said: {:?}",
                    errors.map(|e| e.0.into_iter().map(|d| d.message).collect::<Vec<_>>())
                );
                maps_seen.insert(kind.clone());
            }
        }
    }
    assert_eq!(
        maps_seen,
        MAPS.iter().map(|m| m.to_string()).collect(),
        "every table listed as a map is in the reference"
    );

    let mut wrong = Vec::new();
    for (kind, known) in &accepted {
        let shown = &documented[kind];
        let missing: Vec<_> = known.difference(shown).collect();
        let extra: Vec<_> = shown.difference(known).collect();
        if !missing.is_empty() {
            wrong.push(format!(
                "[{kind}]: accepted but not in the reference: {missing:?}"
            ));
        }
        if !extra.is_empty() {
            wrong.push(format!("[{kind}]: in the reference but refused: {extra:?}"));
        }
    }
    assert!(
        wrong.is_empty(),
        "docs/network-file.md and the parser disagree:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn header_kinds_name_the_tables_not_the_files_choices() {
    assert_eq!(header_kind("[nodes.gaze]").as_deref(), Some("nodes.*"));
    assert_eq!(
        header_kind("[ports.\"gaze.target\"]   # x").as_deref(),
        Some("ports.*")
    );
    assert_eq!(
        header_kind("[dynamics.door.behaviours.search]").as_deref(),
        Some("dynamics.*.behaviours.*")
    );
    assert_eq!(
        header_kind("[[client.commands]]").as_deref(),
        Some("client.commands")
    );
    assert_eq!(header_kind("[hbba]").as_deref(), Some("hbba"));
    assert_eq!(header_kind("rule = \"C1\""), None);
    assert_eq!(key_of("tc = 3.0   # τ"), Some("tc"));
    assert_eq!(key_of("# rule = x"), None);
    assert_eq!(key_of("                          # x = 1"), None);
}
