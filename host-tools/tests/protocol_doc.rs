//! `docs/can-protocol.md` against `pab_core::protocol`: the code tables, the services table, the
//! worked identifiers and the payload sections (against the core's layouts, as are the payload
//! types' own documented layouts) must say what the code does. On drift, the failure prints the table as
//! it should be, ready to paste.

use std::path::Path;

use pab_core::protocol::layout::{Framing, layout};
use pab_core::protocol::{
    AuthFailure, BROADCAST, FaultCode, FrameId, NodeState, SchemaOutcome, SchemaSafety, Service,
    StoreFailure, TransferStatusCode, UpdateStatusCode,
};

fn document() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/can-protocol.md");
    std::fs::read_to_string(&path).unwrap_or_else(|error| panic!("{}: {error}", path.display()))
}

/// The rows of the markdown table that follows `<!-- marker -->`: cells trimmed, header and
/// separator dropped, with each row's line number.
fn table(document: &str, marker: &str) -> Vec<(usize, Vec<String>)> {
    let comment = format!("<!-- {marker} -->");
    let start = document
        .lines()
        .position(|line| line.trim() == comment)
        .unwrap_or_else(|| panic!("docs/can-protocol.md: no `{comment}` before a table"));
    document
        .lines()
        .enumerate()
        .skip(start + 1)
        .skip_while(|(_, line)| line.trim().is_empty())
        .take_while(|(_, line)| line.trim_start().starts_with('|'))
        .skip(2)
        .map(|(index, line)| {
            let cells = line
                .trim()
                .trim_matches('|')
                .split('|')
                .map(|cell| cell.trim().to_string())
                .collect();
            (index + 1, cells)
        })
        .collect()
}

fn number(text: &str) -> Option<u32> {
    match text.strip_prefix("0x") {
        Some(hex) => u32::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

/// Compares the first three columns (code, name, description) of the table at `marker` with
/// `expected`; panics with every difference and the expected rows.
fn compare_enum(marker: &str, expected: &[(u32, String, &str)], width: usize) {
    let document = document();
    let rows = table(&document, marker);
    let mut problems = Vec::new();
    for (i, (code, name, description)) in expected.iter().enumerate() {
        match rows.get(i) {
            None => problems.push(format!("missing row for {name} ({code:#x})")),
            Some((line, cells)) => {
                let got = (
                    cells.first().and_then(|c| number(c)),
                    cells.get(1).map(String::as_str),
                    cells.get(2).map(String::as_str),
                );
                if got != (Some(*code), Some(name.as_str()), Some(*description)) {
                    problems.push(format!(
                        "line {line}: has {:?} | {:?} | {:?}, the code says {code:#x} | {name} | {description}",
                        cells.first(),
                        cells.get(1),
                        cells.get(2)
                    ));
                }
            }
        }
    }
    for (line, cells) in rows.iter().skip(expected.len()) {
        problems.push(format!("line {line}: row {cells:?} is not in the code"));
    }
    if !problems.is_empty() {
        let rows: Vec<String> = expected
            .iter()
            .map(|(code, name, description)| {
                format!(
                    "| {code:#0width$x} | {name} | {description} | ... |",
                    width = width + 2
                )
            })
            .collect();
        panic!(
            "docs/can-protocol.md, table `{marker}` has drifted from pab_core::protocol:\n  {}\n\
             The first three columns should be:\n{}",
            problems.join("\n  "),
            rows.join("\n")
        );
    }
}

#[test]
fn node_states_match_the_code() {
    let expected: Vec<_> = NodeState::ALL
        .iter()
        .map(|s| (u32::from(s.code()), format!("{s:?}"), s.description()))
        .collect();
    compare_enum("enum: NodeState", &expected, 1);
}

#[test]
fn fault_codes_match_the_code() {
    let expected: Vec<_> = FaultCode::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: FaultCode", &expected, 4);
}

#[test]
fn transfer_status_codes_match_the_code() {
    let expected: Vec<_> = TransferStatusCode::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: TransferStatusCode", &expected, 2);
}

#[test]
fn store_failures_match_the_code() {
    let expected: Vec<_> = StoreFailure::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: StoreFailure", &expected, 2);
}

#[test]
fn config_status_codes_match_the_code() {
    let expected: Vec<_> = pab_core::protocol::ConfigStatusCode::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: ConfigStatusCode", &expected, 2);
}

#[test]
fn update_status_codes_match_the_code() {
    let expected: Vec<_> = UpdateStatusCode::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: UpdateStatusCode", &expected, 1);
}

#[test]
fn auth_failures_match_the_code() {
    let expected: Vec<_> = AuthFailure::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: AuthFailure", &expected, 2);
}

#[test]
fn schema_outcomes_match_the_code() {
    let expected: Vec<_> = SchemaOutcome::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: SchemaOutcome", &expected, 2);
}

#[test]
fn schema_safety_events_match_the_code() {
    let expected: Vec<_> = SchemaSafety::ALL
        .iter()
        .map(|c| (u32::from(c.code()), format!("{c:?}"), c.description()))
        .collect();
    compare_enum("enum: SchemaSafety", &expected, 1);
}

#[test]
fn services_match_the_code() {
    let document = document();
    let rows = table(&document, "table: services");
    let mut problems = Vec::new();
    for service in Service::ALL {
        let name = format!("{service:?}");
        let Some((line, cells)) = rows.iter().find(|(_, cells)| cells.get(1) == Some(&name)) else {
            problems.push(format!("no row for service {name}"));
            continue;
        };
        let code = cells.first().and_then(|c| number(c));
        let priority = cells.get(2).and_then(|c| number(c));
        let len = cells
            .get(4)
            .and_then(|c| c.split_whitespace().next())
            .and_then(number);
        let expected = (
            Some(u32::from(service.code())),
            Some(u32::from(service.priority().value())),
            Some(service.payload_len() as u32),
        );
        if (code, priority, len) != expected {
            problems.push(format!(
                "line {line}: {name}: code, priority, payload {:?}, the code says {:?}",
                (code, priority, len),
                expected
            ));
        }
    }
    if rows.len() != Service::ALL.len() {
        problems.push(format!(
            "{} rows for {} services",
            rows.len(),
            Service::ALL.len()
        ));
    }
    assert!(
        problems.is_empty(),
        "docs/can-protocol.md, services table has drifted:\n  {}",
        problems.join("\n  ")
    );
}

#[test]
fn worked_identifiers_match_the_code() {
    let document = document();
    let rows = table(&document, "table: example-ids");
    assert!(rows.len() >= 5, "too few worked examples: {rows:?}");
    let mut problems = Vec::new();
    for (line, cells) in &rows {
        let service = Service::ALL
            .into_iter()
            .find(|s| Some(&format!("{s:?}")) == cells.get(1));
        let source = cells.get(2).and_then(|c| number(c));
        let destination = cells.get(3).and_then(|c| number(c));
        let id = cells.get(4).and_then(|c| number(c));
        let (Some(service), Some(source), Some(destination), Some(id)) =
            (service, source, destination, id)
        else {
            problems.push(format!("line {line}: cannot read {cells:?}"));
            continue;
        };
        let (Ok(source), Ok(destination)) = (u8::try_from(source), u8::try_from(destination))
        else {
            problems.push(format!("line {line}: addresses out of range"));
            continue;
        };
        let raw = FrameId::new(service, source, destination).raw();
        if raw != id {
            problems.push(format!(
                "line {line}: {service:?} {source} -> {destination} is 0x{raw:08X}, not 0x{id:08X}"
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "docs/can-protocol.md, worked identifiers are wrong:\n  {}",
        problems.join("\n  ")
    );
    // The text's running example.
    assert_eq!(
        FrameId::new(Service::Heartbeat, 3, BROADCAST).raw(),
        0x1202_FF03
    );
    assert!(document.contains("0x1202FF03"));
}

/// The byte ranges of a ```text layout block (`byte N`, `bytes A-B`), each with its line; the
/// lines that continue a range's description are skipped.
fn byte_ranges(lines: &[(usize, &str)]) -> Vec<(usize, usize, usize)> {
    lines
        .iter()
        .filter_map(|(line, text)| {
            let text = text.trim_start();
            let range = if let Some(rest) = text.strip_prefix("bytes ") {
                let (a, b) = rest.split_whitespace().next()?.split_once('-')?;
                (a.parse().ok()?, b.parse().ok()?)
            } else {
                let n = text
                    .strip_prefix("byte ")?
                    .split_whitespace()
                    .next()?
                    .parse()
                    .ok()?;
                (n, n)
            };
            Some((*line, range.0, range.1))
        })
        .collect()
}

/// Checks one described layout (`where`: the place, for messages) against the core's: its
/// ranges tile the payload from byte 0, and every field lies inside one range (a range may
/// hold several fields: flags, a nonce's halves).
fn compare_layout(
    place: &str,
    service: Service,
    ranges: &[(usize, usize, usize)],
    problems: &mut Vec<String>,
) {
    let layout = layout(service);
    let mut next = 0;
    for &(line, first, last) in ranges {
        if first != next || last < first {
            problems.push(format!(
                "{place}:{line}: {service:?}: bytes {first}-{last}, expected a range from byte {next}"
            ));
        }
        next = last + 1;
    }
    if next != usize::from(layout.len) {
        problems.push(format!(
            "{place}: {service:?}: the ranges end at byte {next}, the payload has {} bytes",
            layout.len
        ));
    }
    for field in layout.fields {
        let (first, last) = field.bytes();
        if !ranges.iter().any(|&(_, a, b)| a <= first && last <= b) {
            problems.push(format!(
                "{place}: {service:?}: field `{}` (bytes {first}-{last}) is split across, or \
                 outside, the described ranges",
                field.name
            ));
        }
    }
}

/// Every payload section of the document (`### Name (0xNN), L bytes`) says the core's length,
/// and its byte ranges agree with the core's layout (`pab_core::protocol::layout`).
#[test]
fn payload_sections_match_the_layouts() {
    let document = document();
    let lines: Vec<(usize, &str)> = document
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .collect();
    let mut problems = Vec::new();
    let mut described = Vec::new();
    for (index, (line, text)) in lines.iter().enumerate() {
        let Some(heading) = text.strip_prefix("### ") else {
            continue;
        };
        let Some((name, rest)) = heading.split_once(" (0x") else {
            continue;
        };
        let Some(service) = Service::ALL.into_iter().find(|s| format!("{s:?}") == name) else {
            continue;
        };
        let (code, size) = rest.split_once("), ").unwrap_or((rest, ""));
        if number(&format!("0x{code}")) != Some(u32::from(service.code())) {
            problems.push(format!(
                "docs/can-protocol.md:{line}: {name}: code 0x{code}"
            ));
        }
        described.push(service);
        let layout = layout(service);
        if layout.framing == Framing::IsoTp {
            if !size.starts_with("ISO-TP") {
                problems.push(format!("docs/can-protocol.md:{line}: {name} is ISO-TP"));
            }
            continue;
        }
        let len = size.split_whitespace().next().and_then(number);
        if len != Some(u32::from(layout.len)) {
            problems.push(format!(
                "docs/can-protocol.md:{line}: {name}: {size:?}, the core's payload is {} bytes",
                layout.len
            ));
        }
        if layout.len == 0 {
            continue;
        }
        // The section's first ```text block.
        let block: Vec<(usize, &str)> = lines[index + 1..]
            .iter()
            .take_while(|(_, l)| !l.starts_with("### ") && !l.starts_with("## "))
            .skip_while(|(_, l)| l.trim() != "```text")
            .skip(1)
            .take_while(|(_, l)| l.trim() != "```")
            .copied()
            .collect();
        compare_layout(
            "docs/can-protocol.md",
            service,
            &byte_ranges(&block),
            &mut problems,
        );
    }
    for service in Service::ALL {
        if !described.contains(&service) && layout(service).len > 0 {
            problems.push(format!(
                "docs/can-protocol.md: no payload section for {service:?}"
            ));
        }
    }
    assert!(
        problems.is_empty(),
        "docs/can-protocol.md's payloads have drifted from pab_core::protocol::layout:\n  {}",
        problems.join("\n  ")
    );
}

/// The layout block in each payload type's documentation (core/src/protocol/messages/) agrees
/// with the type's layout the same way.
#[test]
fn payload_types_documentation_matches_the_layouts() {
    let types = [
        ("Fault", Service::Fault),
        ("Heartbeat", Service::Heartbeat),
        ("TableStatus", Service::TableStatus),
        ("Traffic", Service::Traffic),
        ("Errors", Service::Errors),
        ("DiagnosticSample", Service::Diagnostic),
        ("DiagnosticControl", Service::DiagnosticControl),
        ("Gates", Service::Gates),
        ("DesireFrame", Service::Desire),
        ("Intention", Service::Intention),
        ("FilterStatus", Service::FilterStatus),
        ("Exploitation", Service::Exploitation),
        ("FilterProfile", Service::FilterProfile),
        ("FilterSet", Service::FilterSet),
        ("TransferOpen", Service::TransferOpen),
        ("TransferStatus", Service::TransferStatus),
        ("SchemaAck", Service::SchemaAck),
        ("SchemaTransition", Service::SchemaTransition),
        ("SchemaState", Service::SchemaState),
        ("UpdateStatus", Service::UpdateStatus),
    ];
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../core/src/protocol/messages");
    let mut problems = Vec::new();
    let mut found = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        let place = format!(
            "core/src/protocol/messages/{}",
            path.file_name().unwrap().to_string_lossy()
        );
        let lines: Vec<(usize, &str)> = text.lines().enumerate().map(|(i, l)| (i + 1, l)).collect();
        let mut block: Option<Vec<(usize, &str)>> = None;
        let mut inside = false;
        for &(line, text) in &lines {
            let doc = text.trim_start().strip_prefix("///").map(str::trim_start);
            match doc {
                Some("```text") => {
                    inside = true;
                    block = Some(Vec::new());
                }
                Some("```") => inside = false,
                Some(body) if inside => {
                    if let Some(block) = block.as_mut() {
                        block.push((line, body));
                    }
                }
                Some(_) => {}
                None => {
                    let name = text
                        .strip_prefix("pub struct ")
                        .and_then(|rest| rest.split([' ', '{']).next());
                    if let Some(name) = name {
                        let ranges = block.take();
                        let service = types.iter().find(|(n, _)| *n == name);
                        if let (Some(&(_, service)), Some(ranges)) = (service, ranges) {
                            found.push(name.to_string());
                            compare_layout(&place, service, &byte_ranges(&ranges), &mut problems);
                        }
                    } else if !text.trim_start().starts_with("#[") {
                        block = None;
                    }
                }
            }
        }
    }
    for (name, _) in types {
        if !found.iter().any(|f| f == name) {
            problems.push(format!("no layout block in the documentation of `{name}`"));
        }
    }
    assert!(
        problems.is_empty(),
        "payload types' documented layouts have drifted from their LAYOUT:\n  {}",
        problems.join("\n  ")
    );
}
