//! The end-to-end tests, one module per file of this directory, in one test binary: compiled and
//! linked once instead of once per file. `cargo test -p pab-tests --test integration NAME::` runs
//! the tests of NAME.rs. A file of this directory is built only once declared here (`autotests =
//! false` in Cargo.toml); tests/tests/test_files.rs fails while one is not.

mod board_tables;
mod check_variants;
mod connection_kinds;
mod door_dynamics;
mod door_gates;
mod dynamics_scenarios;
mod dynamics_warnings;
mod figure_one;
mod hbba_tour_guide;
mod intention_node;
mod multi_target_observation;
mod subsumption;
mod take_and_return;
mod take_and_return_dynamics;
mod test_files;
mod timed_bus;
