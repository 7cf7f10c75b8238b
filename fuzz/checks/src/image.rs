//! The image loader, `pab_core::image::load`: whatever the bytes, a validated table or a
//! [`LoadError`], never a panic; and what it accepts is what it means.
//!
//! Two targets: [`raw`] takes the bytes as they come (so mostly exercises the header, length and
//! CRC checks); [`fixed_crc`] first sets the header's body length and CRC right, so that mutations
//! of real images (the seeds are `pabctl compile`'s images of `examples/`) reach the body's decoder
//! and the table's validation.

use pab_core::image::{self, HEADER_LEN, LoadError, Loaded};
use pab_core::{
    Arbiter, BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, MAX_CONNECTIONS,
    MAX_DECISION_NODES, MAX_PORTS,
};

use crate::crc::crc32;

type Full = Loaded<MAX_PORTS, MAX_CONNECTIONS, MAX_DECISION_NODES>;
type Board = Loaded<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;

/// The loader on raw bytes.
pub fn raw(data: &[u8]) {
    let _ = check(data);
}

/// The loader on `data` with the header's body length (bytes 12..16) and CRC (bytes 16..20) made
/// right, so that only the body (and the other header fields) can be wrong: the result is never
/// a length or CRC error. The CRC is computed here, independently of pab-core's.
pub fn fixed_crc(data: &[u8]) {
    let bytes = fix_up(data);
    let result = check(&bytes);
    if bytes.len() >= HEADER_LEN && bytes.len() <= image::MAX_IMAGE_LEN {
        assert!(
            !matches!(
                result,
                Err(LoadError::Crc { .. }
                    | LoadError::Truncated { .. }
                    | LoadError::TrailingBytes { .. }
                    | LoadError::TooLarge { .. })
            ),
            "length and CRC were set right, yet: {result:?}"
        );
    }
}

/// `data` with a right body length and CRC (unchanged when shorter than a header).
pub fn fix_up(data: &[u8]) -> Vec<u8> {
    let mut bytes = data.to_vec();
    if bytes.len() >= HEADER_LEN {
        let body_len = u32::try_from(bytes.len() - HEADER_LEN).unwrap_or(u32::MAX);
        bytes[12..16].copy_from_slice(&body_len.to_le_bytes());
        let crc = crc32(&[&bytes[..16], &bytes[HEADER_LEN..]]);
        bytes[16..20].copy_from_slice(&crc.to_le_bytes());
    }
    bytes
}

/// The node's body decoder (`image::decode_body`, a hand-written reader) against postcard and
/// serde's derive, the workstation's encoding: both accept the same bytes and build the same
/// table with the same rest. Their errors may differ in kind, never in whether there is one.
pub fn same_as_postcard<const P: usize, const C: usize, const N: usize>(body: &[u8]) {
    let ours = image::decode_body::<P, C, N>(body);
    let theirs = postcard::take_from_bytes::<pab_core::Table<P, C, N>>(body);
    match (&ours, &theirs) {
        (Ok(a), Ok(b)) => assert_eq!(
            a, b,
            "the node's decoder and postcard built different tables"
        ),
        (Err(_), Err(_)) => {}
        _ => panic!("the node's decoder says {ours:?}, postcard says {theirs:?}"),
    }
}

/// Loads `bytes` into the largest and the board's capacities and checks that the two agree with
/// each other, with the header reader, and with the encoder. Returns the full load's result.
fn check(bytes: &[u8]) -> Result<(), LoadError> {
    if let Some(body) = bytes.get(HEADER_LEN..) {
        same_as_postcard::<MAX_PORTS, MAX_CONNECTIONS, MAX_DECISION_NODES>(body);
        same_as_postcard::<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>(body);
    }
    let header = image::read_header(bytes);
    let full: Result<Full, LoadError> = image::load(bytes);
    let board: Result<Board, LoadError> = image::load(bytes);
    if let Err(error) = &full {
        assert!(!error.to_string().is_empty());
    }
    // The loader reads the header first: its error is the loader's.
    if let Err(error) = &header {
        assert_eq!(
            full.as_ref().err(),
            Some(error),
            "header error not the loader's"
        );
    }
    match &full {
        Ok(loaded) => {
            assert_eq!(
                Ok(loaded.header),
                header,
                "loaded header differs from read_header's"
            );
            assert_eq!(
                bytes.len(),
                HEADER_LEN + loaded.header.body_len as usize,
                "an image of the wrong length was accepted"
            );
            let reencoded = reencode(loaded);
            // Validated tables always build an arbiter (a node maps a failure to InvalidTable).
            assert!(
                Arbiter::new(loaded.table.clone()).is_ok(),
                "a validated table builds no arbiter"
            );
            let fits = loaded.table.port_count() <= BOARD_PORTS
                && loaded.table.connection_count() <= BOARD_CONNECTIONS
                && loaded.table.node_count() <= BOARD_DECISION_NODES;
            match &board {
                Ok(small) => {
                    assert!(fits, "the board took a table larger than its capacities");
                    assert_eq!(small.header, loaded.header);
                    assert_eq!(reencode(small), reencoded, "board and full tables differ");
                    assert!(Arbiter::new(small.table.clone()).is_ok());
                }
                Err(LoadError::ExceedsCapacity { needed, .. }) => {
                    assert!(!fits, "a table within the board's capacities was refused");
                    assert_eq!(needed.ports, loaded.table.port_count());
                    assert_eq!(needed.connections, loaded.table.connection_count());
                    assert_eq!(needed.nodes, loaded.table.node_count());
                }
                Err(error) => panic!("full capacities load, the board says {error:?}"),
            }
        }
        Err(error) => {
            let board = board.as_ref().err();
            match error {
                // Header, length and CRC: nothing depends on capacities.
                LoadError::Truncated { .. }
                | LoadError::TrailingBytes { .. }
                | LoadError::BadMagic
                | LoadError::UnsupportedFormat { .. }
                | LoadError::ReservedByte
                | LoadError::TooLarge { .. }
                | LoadError::Crc { .. } => assert_eq!(board, Some(error)),
                // Too large for the largest table: too large for the board.
                LoadError::ExceedsCapacity { needed, .. } => assert!(
                    matches!(board, Some(LoadError::ExceedsCapacity { needed: n, .. }) if n == needed),
                    "full: {error:?}, board: {board:?}"
                ),
                // The board refuses the same table, or refuses it earlier for its size.
                LoadError::Table(_) => assert!(
                    board == Some(error)
                        || matches!(board, Some(LoadError::ExceedsCapacity { .. })),
                    "full: {error:?}, board: {board:?}"
                ),
                // Likewise; but a table too large for the board *followed by bytes* is `Body` on
                // the board: it tells ExceedsCapacity only for a body that is a table and
                // nothing else (`Reader::fill_within`, by design), and this one is not.
                LoadError::BodyTrailingBytes => assert!(
                    matches!(
                        board,
                        Some(
                            LoadError::BodyTrailingBytes
                                | LoadError::ExceedsCapacity { .. }
                                | LoadError::Body(_)
                        )
                    ),
                    "full: {error:?}, board: {board:?}"
                ),
                LoadError::Body(_) => assert!(
                    matches!(
                        board,
                        Some(LoadError::Body(_) | LoadError::ExceedsCapacity { .. })
                    ),
                    "full: {error:?}, board: {board:?}"
                ),
            }
        }
    }
    full.map(|_| ())
}

/// Encodes a loaded table again with its header's node and version, checks that the result loads
/// to the same table, and returns it.
fn reencode<const P: usize, const C: usize, const N: usize>(loaded: &Loaded<P, C, N>) -> Vec<u8> {
    let mut out = vec![0u8; image::MAX_IMAGE_LEN];
    let len = image::encode(
        &loaded.table,
        loaded.header.node_id,
        loaded.header.table_version,
        &mut out,
    )
    .unwrap_or_else(|error| panic!("a loaded table does not encode: {error:?}"));
    out.truncate(len);
    let again: Loaded<P, C, N> = image::load(&out)
        .unwrap_or_else(|error| panic!("a re-encoded table does not load: {error:?}"));
    assert_eq!(
        again.table, loaded.table,
        "the table changed through encode and load"
    );
    assert_eq!(again.header.node_id, loaded.header.node_id);
    assert_eq!(again.header.table_version, loaded.header.table_version);
    out
}
