//! `docs/can-protocol.md` against `pab_core::protocol`: the code tables, the services table and
//! the worked identifiers must say what the code does. On drift, the failure prints the table as
//! it should be, ready to paste.

use std::path::Path;

use pab_core::protocol::{
    AuthFailure, BROADCAST, FaultCode, FrameId, NodeState, SchemaOutcome, SchemaSafety, Service,
    StoreFailure, TransferStatusCode,
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
