//! The network language of port arbitration.
//!
//! A network file ([`network`]) names the nodes, topics, ports and their connections, the rules
//! that decide which connection a port lets through, and the mechanisms that feed them (BLE
//! groups, competitive-dynamics groups). This crate reads it with errors at their line
//! ([`diagnostic`]), proves each port's rules consistent ([`check`]), compiles one table image per
//! node ([`compile`]), simulates the whole network in virtual time with `pab-core`, the code the
//! boards run ([`sim`]), replays recorded candump captures ([`candump`], [`replay`]) and
//! describes the traffic as a DBC file ([`dbc`]). What a plot shows is data here ([`series`]);
//! drawing it, and everything on a live bus, belongs to `pabctl`.
//!
//! # Layers
//!
//! A module imports only from modules listed before it here, never from one after it, so that
//! the model can be read, tested and fuzzed without the simulator:
//!
//! 1. text and numbers: [`shown`], [`diagnostic`], [`input`] (files checked before they are
//!    read), [`rule`], [`time`], [`series`], [`can_frame`] (frame lengths and transmission
//!    times), [`candump`];
//! 2. the model: [`network`], the file parsed and its names, numbers and rules checked;
//! 3. its meaning: [`kinds`] → [`check`] → [`compile`];
//! 4. running the tables: [`sim`] → [`replay`];
//! 5. describing the traffic: [`dbc`] (from the model, and the claims of a capture).

pub mod can_frame;
pub mod candump;
pub mod check;
pub mod compile;
pub mod dbc;
pub mod diagnostic;
pub mod input;
pub mod kinds;
pub mod network;
pub mod push_frames;
pub mod replay;
pub mod rule;
pub mod series;
pub mod shown;
pub mod sim;
pub mod time;
