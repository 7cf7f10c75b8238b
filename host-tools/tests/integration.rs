//! pabctl's integration tests, one module per file of this directory, in one test binary: compiled
//! and linked once instead of once per file. `cargo test -p pabctl --test integration NAME::` runs
//! the tests of NAME.rs. A file of this directory is built only once declared here (`autotests =
//! false` in Cargo.toml); tests/tests/test_files.rs fails while one is not.
//!
//! live.rs, schema_live.rs are test binaries of their own (Cargo.toml says why).

mod common;

mod cli;
mod cross_runner;
mod flash;
mod hbba;
mod keyed_board;
mod pabctl_reference;
mod protocol_doc;
mod replay_cli;
mod tutorial;
mod value_ports;
