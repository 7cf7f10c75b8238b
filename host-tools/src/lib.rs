//! pabctl: the workstation side of port arbitration.
//!
//! The network language (read, check, compile, simulate, replay, DBC) is the `pab-lang` crate;
//! this one adds what a workstation does with it: draws its plots ([`plot`]), and on a live bus
//! ([`bus`]) pushes tables to the nodes ([`push`]), lists them ([`observe`]) and shows their
//! arbitration as it happens ([`monitor`]); a schema server's client ([`client`]) and the
//! simulated robot in front of its board ([`plant`]). Key files ([`keys`]) and the command
//! line's numbers ([`args`]) are here too, `pabctl solve`'s report of HBBA's intention solver
//! ([`solve`]), firmware signing keys and signed images ([`signing`]), and a signed image's way to a node
//! over the bus ([`flash`]). Every transfer to a node (table, schema, firmware) goes through
//! [`transfer`], in classic or CAN FD frames as its bus says ([`bus::Framing`]).
//!
//! The `pabctl` command itself is the binary's: `main.rs` and the modules it declares beside
//! these (`cli.rs`, `commands/`, `failure.rs`, `output.rs`).

pub mod args;
pub mod bus;
pub mod client;
pub mod flash;
pub mod identity;
pub mod json;
pub mod keys;
pub mod limits;
pub mod monitor;
pub mod observe;
pub mod plant;
pub mod plot;
pub mod push;
pub mod signing;
pub mod solve;
pub mod starter;
pub mod transfer;
