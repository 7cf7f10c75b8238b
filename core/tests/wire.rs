//! The node's table-body decoder (`image::decode_body`, written by hand) against postcard with
//! serde's derive, which the workstation encodes with: on every body of the committed seeds and on
//! every one-byte change and truncation of them, both accept the same bytes and build the same
//! table, or both refuse.

use std::path::Path;

use pab_core::image::{self, HEADER_LEN};
use pab_core::{
    BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, MAX_CONNECTIONS, MAX_DECISION_NODES,
    MAX_PORTS, Table,
};

/// The table bodies of the fuzzer's seed images (`pabctl compile`'s images of `examples/`).
fn seed_bodies() -> Vec<(String, Vec<u8>)> {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/image_fixed_crc");
    let mut bodies: Vec<_> = std::fs::read_dir(&corpus)
        .expect("the fuzz corpus")
        .map(|entry| entry.expect("a corpus entry").path())
        .filter(|path| {
            path.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("seed-"))
        })
        .map(|path| {
            let bytes = std::fs::read(&path).expect("a seed image");
            (path.display().to_string(), bytes[HEADER_LEN..].to_vec())
        })
        .collect();
    bodies.sort();
    assert!(bodies.len() >= 10, "too few seeds in {}", corpus.display());
    bodies
}

/// Whether the two decoders agree on `body`, at both capacities; `Some(accepted)` if they do.
fn agree(body: &[u8]) -> Result<bool, String> {
    fn at<const P: usize, const C: usize, const N: usize>(body: &[u8]) -> Result<bool, String> {
        let ours = image::decode_body::<P, C, N>(body);
        let theirs = postcard::take_from_bytes::<Table<P, C, N>>(body);
        match (&ours, &theirs) {
            (Ok(a), Ok(b)) if a == b => Ok(true),
            (Err(_), Err(_)) => Ok(false),
            _ => Err(format!("ours {ours:?}\npostcard {theirs:?}")),
        }
    }
    let full = at::<MAX_PORTS, MAX_CONNECTIONS, MAX_DECISION_NODES>(body)?;
    at::<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>(body)?;
    Ok(full)
}

#[test]
fn every_seed_body_decodes_to_postcards_table() {
    for (name, body) in seed_bodies() {
        assert_eq!(agree(&body), Ok(true), "{name}");
    }
}

#[test]
fn every_one_byte_change_and_truncation_of_the_seeds_gets_postcards_verdict() {
    let mut accepted = 0usize;
    let mut refused = 0usize;
    for (name, body) in seed_bodies() {
        for position in 0..body.len() {
            let mut changed = body.clone();
            for value in 0..=255u8 {
                changed[position] = value;
                match agree(&changed) {
                    Ok(true) => accepted += 1,
                    Ok(false) => refused += 1,
                    Err(why) => panic!("{name}, byte {position} = {value:#04x}:\n{why}"),
                }
            }
            if let Err(why) = agree(&body[..position]) {
                panic!("{name} cut at {position}:\n{why}");
            }
        }
    }
    // Both outcomes occur, so the comparison has something to compare.
    assert!(
        accepted > 1000 && refused > 1000,
        "accepted {accepted}, refused {refused}"
    );
}
