//! The schema server (Bekey, Newman and co., "A client/server approach to open-architecture,
//! behavior-based robot programming"): a fixed-rate reactive loop on a joint or hand board, in
//! front of an impedance-controlled drive.
//!
//! A **schema** is one action primitive ([`Action`]) and a prioritised reaction table
//! ([`Reaction`]: an [`Event`] and the [`Source`] of the next schema). Exactly one schema is
//! installed at a time. Every period the [`Server`] runs the paper's loop, as DESIGN.md
//! ("Schema server: decisions") fixes it:
//!
//! 1. the runner waits for the tick and calls [`Server::tick`];
//! 2. the high-priority channel: an emergency stop, an abort or a schema received there is handled
//!    at once (a schema there replaces the current one);
//! 3. the sensor table (kept current by the runner between ticks, [`Server::set_pose`] and its
//!    siblings) is checked for staleness, and one-shot is set once the action has run;
//! 4. the reaction table is scanned in priority order, the built-in [`Safety`] events first; the
//!    first event that holds is the triggering event;
//! 5. the triggered schema is installed: its reaction table, one-shot false, its action, its
//!    watchdog restarted;
//! 6. one iteration of the action moves the attractor ([`Setpoint`]).
//!
//! Safety events (emergency stop, stale sensor, implausible pose, workspace and joint limits,
//! speed, force limit, watchdog, loop overrun) are the server's, not the client's: a schema cannot remove them. Each one sets the
//! attractor to the measured pose (so the impedance controller relieves every force), reports
//! a fault, and leaves the server waiting on the high-priority channel with the queue kept but
//! not run.
//!
//! # Numbers
//!
//! Positions are µm on the three translational axes and µrad on the three rotational ones, in
//! `i32` ([`Pose`]); forces mN and torques mN·m ([`Wrench`]). A move's progress accumulates the
//! sub-µm remainder of speed × period, so 1 mm/s at 1 kHz is exactly 1 µm a tick, and the move
//! ends on the tick its progress reaches the distance, with the attractor exactly on the goal.
//! Coordinates are bounded by [`MAX_COORD`] (±500 m or rad), so that every square and product is
//! an exact `i64`; a schema with larger values is refused when it is decoded.
//!
//! # Costs
//!
//! A [`Server`] holds the current schema, the innate table, the queue and the high-priority slot
//! by value: about 5.4 KiB at the default capacities. A tick makes no allocation and no
//! division except one per moving axis; a schema is installed by copy.

mod action;
pub mod build;
pub mod drive;
mod event;
mod limits;
mod message;
mod sensor;
mod server;
mod setup;

pub use action::{Action, Gripper, Setpoint};
pub use event::{Event, Measure, Reaction, Source};
pub use limits::{Joint, Limits, LimitsError, MAX_JOINTS, SPEED_WINDOW_US};
pub use message::{MAX_ENCODED, Schema, SchemaError};
pub use sensor::{Sensor, SensorError, feed_sensors};
pub use server::{
    Channel, Config, ConfigError, Origin, Refusal, STOP_NUMBERS, Safety, Server, Tick, Transition,
    Trigger,
};
pub use setup::{Drive, Setup, SetupError};

/// Axes of a pose: x, y, z (µm), then rotations about x, y, z (µrad).
pub const AXES: usize = 6;
/// Reactions per schema: the paper leaves it open; 16 holds the assembly's largest schema with
/// room (DESIGN.md).
pub const MAX_REACTIONS: usize = 16;
/// Schemas the client may queue: a full queue refuses, never overwrites (DESIGN.md).
pub const QUEUE_DEPTH: usize = 8;
/// Innate schemas a board's set-up can store.
pub const MAX_INNATE: usize = 8;
/// Extra sensors (beyond pose and wrench) a board reads from topics.
pub const MAX_SENSORS: usize = 8;
/// The largest coordinate, speed or distance a schema may carry, in µm or µrad (500 m): every
/// difference of two coordinates fits 2^30, every square 2^60 and a sum of six squares an `i64`.
pub const MAX_COORD: i32 = 500_000_000;
/// Identifiers from here up name the server's own schemas ([`Schema::WAIT_QUEUE`] and the
/// others); a client's schema has a smaller one.
pub const BUILTIN_IDS: u16 = 0xFF00;

/// A pose: µm on x, y, z and µrad about x, y, z.
pub type Pose = [i32; AXES];
/// A wrench: mN along x, y, z and mN·m about x, y, z.
pub type Wrench = [i32; AXES];

pub(crate) use crate::isqrt::isqrt;

/// The Euclidean length of `v`, three differences of coordinates (a translation, µm, or a
/// rotation, µrad), floor.
// Out of line: a move's translation and its rotation each inlined a copy.
#[inline(never)]
pub(crate) fn length(v: &[i64]) -> u64 {
    let mut sum = 0u64;
    for c in v {
        // A difference of two `i32` coordinates is below 2^32 in magnitude: its square is a
        // 32 × 32-bit product (the conversion saturates only what cannot occur), and three of
        // them are summed saturating.
        let a = u64::from(u32::try_from(c.unsigned_abs()).unwrap_or(u32::MAX));
        sum = sum.saturating_add(a * a);
    }
    isqrt(sum)
}
