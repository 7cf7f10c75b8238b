//! The node application's integration tests, one module per file of this directory, in one test
//! binary: compiled and linked once instead of once per file. `cargo test -p pab-app --test
//! integration NAME::` runs the tests of NAME.rs. A file of this directory is built only once
//! declared here (`autotests = false` in Cargo.toml); tests/tests/test_files.rs fails while one is
//! not.

mod common;

mod ble;
mod can_adapter;
mod filters;
#[cfg(feature = "identity")]
mod identity;
mod keying;
mod node;
mod outbox;
mod poll_loop;
mod priority;
mod replay;
mod rogue;
mod runner;
mod sealed;
mod swap;
mod transfer;
// Transfers in CAN FD frames: only with the feature (the Linux node enables it, so the
// workspace's `cargo test` runs these).
#[cfg(feature = "fd")]
mod transfer_fd;
#[cfg(feature = "update")]
mod update;

// The schema server on the node: only with its feature (the Linux node enables it, so the
// workspace's `cargo test` runs these).
#[cfg(feature = "schema")]
mod schema;
#[cfg(feature = "schema")]
mod schema_keyed;
#[cfg(feature = "schema")]
mod schema_rig;
#[cfg(feature = "schema")]
mod schema_stop;
