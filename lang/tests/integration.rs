//! The network language's integration tests, one module per file of this directory, in one test
//! binary: compiled and linked once instead of once per file. `cargo test -p pab-lang --test
//! integration NAME::` runs the tests of NAME.rs. A file of this directory is built only once
//! declared here (`autotests = false` in Cargo.toml); tests/tests/test_files.rs fails while one is
//! not.

mod assembly;
mod client_golden;
mod description;
mod diagnostics;
mod json_schema;
mod reference;
mod reflex;
