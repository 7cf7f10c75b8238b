//! The checks behind the fuzz targets: one function per target, taking the fuzzer's bytes and
//! panicking when a property fails.
//!
//! They run two ways: under libFuzzer (`fuzz/fuzz_targets/*.rs`, nightly, `cargo fuzz run
//! <target>`), and over the committed corpus (`fuzz/corpus/<target>/`) and any crash reproducers
//! (`fuzz/artifacts/<target>/`) by `cargo test -p pab-fuzz-checks` on stable (`tests/corpus.rs`), so
//! that `./test.sh` keeps every input that once found something, and every seed, passing.
//!
//! Each target's bytes are read with [`arbitrary::Unstructured`] where structure helps (a sequence
//! of frames and times, a transfer); the same bytes give the same run in both ways. A check never
//! returns an error for bad input: bad input is what it feeds the code under test; only a broken
//! property panics.

pub mod aes_cmac;
pub mod ble;
pub mod gates;
pub mod image;
pub mod intention;
pub mod isotp_fd;
pub mod isotp_rx;
pub mod isotp_tx;
pub mod network;
pub mod node;
pub mod node_keyed;
pub mod node_schema;
pub mod node_update;
pub mod protocol;
pub mod schema;
pub mod seal;
pub mod update;
pub mod update_session;

mod crc;
mod examples;

/// A fuzz target: its name (the file in `fuzz/fuzz_targets/`, the directories in `fuzz/corpus/`
/// and `fuzz/artifacts/`) and its check.
#[derive(Clone, Copy)]
pub struct Target {
    /// The target's name.
    pub name: &'static str,
    /// Runs one input; panics when a property fails.
    pub check: fn(&[u8]),
}

/// Every target, in the order `./test.sh` runs them.
pub const TARGETS: &[Target] = &[
    Target {
        name: "image_raw",
        check: image::raw,
    },
    Target {
        name: "image_fixed_crc",
        check: image::fixed_crc,
    },
    Target {
        name: "isotp_rx",
        check: isotp_rx::check,
    },
    Target {
        name: "isotp_tx",
        check: isotp_tx::check,
    },
    Target {
        name: "protocol_decode",
        check: protocol::decode,
    },
    Target {
        name: "protocol_encode",
        check: protocol::encode,
    },
    Target {
        name: "node",
        check: node::check,
    },
    Target {
        name: "network",
        check: network::check,
    },
    Target {
        name: "ble",
        check: ble::check,
    },
    Target {
        name: "gates",
        check: gates::check,
    },
    Target {
        name: "intention",
        check: intention::check,
    },
    Target {
        name: "schema",
        check: schema::check,
    },
    Target {
        name: "aes_cmac",
        check: aes_cmac::check,
    },
    Target {
        name: "node_keyed",
        check: node_keyed::check,
    },
    Target {
        name: "node_schema",
        check: node_schema::check,
    },
    Target {
        name: "seal",
        check: seal::check,
    },
    Target {
        name: "update",
        check: update::check,
    },
    Target {
        name: "update_session",
        check: update_session::check,
    },
    Target {
        name: "node_update",
        check: node_update::check,
    },
    Target {
        name: "isotp_fd",
        check: isotp_fd::check,
    },
    Target {
        name: "node_fd",
        check: node::check_fd,
    },
];

/// The target named `name`. Panics for an unknown name (a fuzz target's file and its entry in
/// [`TARGETS`] disagree).
pub fn target(name: &str) -> Target {
    TARGETS
        .iter()
        .copied()
        .find(|target| target.name == name)
        .unwrap_or_else(|| panic!("no fuzz target named {name}"))
}
