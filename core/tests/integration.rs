//! The core's integration tests, one module per file of this directory, in one test binary:
//! compiled and linked once instead of once per file. `cargo test -p pab-core --test integration
//! NAME::` runs the tests of NAME.rs. A file of this directory is built only once declared here
//! (`autotests = false` in Cargo.toml); tests/tests/test_files.rs fails while one is not.

mod common;

mod arbiter;
mod ble;
mod ble_arbiter;
mod classify;
mod dynamics;
mod equivalence;
mod hbba_desires;
mod hbba_filters;
mod hbba_intention;
mod hbba_solver;
mod image_corruption;
mod integrator_reference;
mod isotp;
mod isotp_fd;
mod schema_server;
mod seal;
mod swap;
mod update_session;
mod value_ports;
mod wire;

// Tables with dynamics (`Table::push_dynamics`): only with the runtime, so that `cargo test -p
// pab-core --no-default-features` builds every other module.
#[cfg(feature = "dynamics")]
mod gates;
#[cfg(feature = "dynamics")]
mod gates_properties;
// The signed firmware image's check needs its signature.
#[cfg(feature = "signature")]
mod update;
