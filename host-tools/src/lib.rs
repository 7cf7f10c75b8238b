//! pabctl: the workstation side of port arbitration.
//!
//! Reads a network file ([`network`]), proves its rules consistent ([`check`]), compiles one
//! table image per node ([`compile`]), simulates the whole network ([`sim`]) with `pab-core`,
//! the code the boards run, and describes its traffic as a DBC file ([`dbc`]). It runs HBBA's
//! intention solver on a network's strategies and a set of desires ([`solve`]). It replays recorded
//! candump captures ([`candump`]) through a network's tables ([`replay`]). On a live bus
//! ([`bus`]) it pushes tables to the nodes ([`push`]), lists them ([`observe`]) and shows their
//! arbitration as it happens ([`monitor`]).

pub mod args;
pub mod bus;
pub mod candump;
pub mod check;
pub mod compile;
pub mod dbc;
pub mod diagnostic;
pub mod keys;
pub mod kinds;
pub mod monitor;
pub mod network;
pub mod observe;
pub mod plot;
pub mod push;
pub mod replay;
pub mod rule;
pub mod shown;
pub mod sim;
pub mod solve;
