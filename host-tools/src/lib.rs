//! pabctl: the workstation side of port arbitration.
//!
//! Reads a network file ([`network`]), proves its rules consistent ([`check`]), compiles one
//! table image per node ([`compile`]), simulates the whole network ([`sim`]) with `pab-core`,
//! the code the boards run, and describes its traffic as a DBC file ([`dbc`]).

pub mod check;
pub mod compile;
pub mod dbc;
pub mod diagnostic;
pub mod network;
pub mod plot;
pub mod rule;
pub mod sim;
