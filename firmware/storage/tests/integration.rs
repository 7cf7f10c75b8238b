//! The storage's integration tests, one module per file of this directory, in one test binary:
//! compiled and linked once instead of once per file. `cargo test -p pab-storage --test integration
//! NAME::` runs the tests of NAME.rs. A file of this directory is built only once declared here
//! (`autotests = false` in Cargo.toml); tests/tests/test_files.rs fails while one is not.

mod common;

mod boot_counter;
mod power_loss;
mod steps;
mod store;
mod update_slot;
mod wear;
