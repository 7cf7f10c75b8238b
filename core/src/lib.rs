//! # pab-core: port arbitration for CAN
//!
//! The arbitration engine of the project, shared by every runner: the boards' firmware, the Linux
//! node and the workstation simulator run this code and nothing else decides who delivers.
//!
//! A node receives CAN frames. Each frame feeds the **connections** whose [`Filter`] matches its
//! identifier; each connection has a stimulation [`Integrator`] (⟨σ, τ, τr⟩, [`Stimulation`]) that
//! makes it **active** when enough frames arrive; each **port** has a precompiled decision
//! ([`decision`]) that picks, from the activity mask, the one connection allowed to deliver. The
//! [`Arbiter`] runs all this per frame.
//!
//! Tables come from the workstation as [`image`]s: a checked header and a postcard body that the
//! loader validates field by field. They travel over CAN with ISO-TP ([`isotp`]), sans-I/O.
//!
//! ## Guarantees
//!
//! - `no_std`, no allocator, no `unsafe`. Capacities are compile-time constants: const generic
//!   parameters of [`Table`] and [`Arbiter`], with the maxima below as defaults and a smaller
//!   profile for boards ([`BoardTable`], [`BoardArbiter`]).
//! - No panics: no indexing, no unwrapping, no unchecked division (enforced by clippy lints on this
//!   crate), and every arithmetic operation is either checked, saturating, or bounded by an
//!   invariant stated next to it.
//! - Deterministic: fixed-point integer arithmetic gives the same result on every target.
//! - Whatever bytes arrive (as a frame or as an image), the result is a verdict or a typed error.

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::panic,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo,
        clippy::unimplemented
    )
)]

pub mod arbiter;
pub mod auth;
pub mod ble;
mod const_exp;
pub mod consumer;
pub mod crc32;
mod decay;
pub mod decimal;
pub mod decision;
pub mod dynamics;
pub mod filter;
pub mod frame;
pub mod hbba;
pub mod identity;
pub mod image;
mod index;
pub mod integrator;
pub mod isotp;
mod isqrt;
pub mod level;
pub mod protocol;
#[cfg(feature = "schema")]
pub mod schema;
pub mod seal;
pub mod table;
pub mod time;
pub mod update;
pub mod value_port;
mod wire;

#[cfg(feature = "dynamics")]
pub use arbiter::dynamics::GatesLost;
pub use arbiter::{Arbiter, FrameReception, PortSet, PortVerdict, Reception};
pub use consumer::{Consumer, OutputId, OutputIdError};
pub use decision::{ConnectionSet, DecisionNode, NodeRef};
pub use embedded_can::Id;
pub use filter::Filter;
pub use frame::Frame;
pub use integrator::{Integrator, ParamError, Stimulation};
pub use level::{Gain, Level};
pub use table::{Connection, PortView, Refused, Table, TableError, Verdict};
pub use time::Instant;
pub use value_port::{
    Combine, Combined, Endian, Field, MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS, ValueSpec,
};

/// Ports per node: the default capacity of a [`Table`], and the most any table can have (a
/// [`PortSet`] is a `u16`).
pub const MAX_PORTS: usize = 16;
/// Connections per port: an activity mask is a `u32`.
pub const MAX_CONNECTIONS_PER_PORT: usize = 32;
/// Connections per node, over all its ports: every port can be full. The default capacity of a
/// [`Table`].
pub const MAX_CONNECTIONS: usize = MAX_PORTS * MAX_CONNECTIONS_PER_PORT;
/// Decision nodes per node, over all its ports: the default capacity of a [`Table`].
pub const MAX_DECISION_NODES: usize = 2048;

/// Ports of the board profile ([`BoardTable`]).
pub const BOARD_PORTS: usize = 4;
/// Connections of the board profile, over all its ports.
pub const BOARD_CONNECTIONS: usize = 64;
/// Decision nodes of the board profile, over all its ports.
pub const BOARD_DECISION_NODES: usize = 256;

/// The table of a board with little RAM (an STM32G474 has 128 KiB): 4 ports, 64 connections,
/// 256 decision nodes, about 3 KiB instead of about 24 KiB at the default capacities, so that a
/// board can keep its current table running while it receives the next one. Loads any image
/// that fits ([`image::LoadError::ExceedsCapacity`] otherwise).
pub type BoardTable = Table<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;

/// The arbiter of a board with little RAM, around a [`BoardTable`]: about 9.1 KiB instead of
/// about 71 KiB at the default capacities (most of it the run-time form of the table that keeps
/// a frame's cost low on a Cortex-M4: see [`Arbiter`]).
pub type BoardArbiter = Arbiter<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;
