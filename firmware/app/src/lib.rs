//! # pab-app: the node application
//!
//! What every node runs, on a board under embassy or as the Linux process `pab-node`:
//!
//! - arbitrates each frame from the bus with [`pab_core::Arbiter`] and hands the winner to the
//!   port's [`Recipient`] (and re-publishes it where the table makes the port a gateway);
//! - sends a heartbeat group every second (state, uptime, table version and CRC, counters);
//! - reports faults, at most once per code per 100 ms with an occurrence count;
//! - streams diagnostic samples (stimulation, activity, deliverer) when the tool asks;
//! - receives new tables over ISO-TP, checks them whole, swaps them in atomically, stores them.
//!
//! [`replay`] feeds recorded frames to nodes in virtual time and records every verdict, so that
//! the simulator, the Linux node and the boards can be compared byte for byte.
//!
//! The frames are those of [`pab_core::protocol`]; `docs/can-protocol.md` describes them.
//!
//! Structure: [`Node`] is the whole behaviour as a state machine without I/O (frames and time in,
//! frames out); `run` (feature `embassy`) drives it on a [`CanBus`] with a [`TableStore`]. Boards
//! and the Linux node provide those two traits and nothing else. Without embassy, [`PollLoop`]
//! drives it over any `embedded-can` driver ([`EmbeddedCan`]) on a clock of the integrator's.

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

#[macro_use]
mod fmt;

mod auth;
pub mod bus;
pub mod can;
mod config;
mod diagnostic;
mod faults;
pub mod keying;
pub mod node;
mod poll_loop;
pub mod replay;
mod runner;
#[cfg(feature = "schema")]
pub mod schema;
mod settings;
#[cfg(feature = "test-bus")]
pub mod testing;

pub use auth::{CHALLENGE_LIFETIME_US, TAG_CHECKS_PER_SECOND};
pub use bus::{BusError, CanBus};
pub use can::{Clock, EmbeddedCan};
pub use config::{
    Config, ConfigError, DEFAULT_STORE_INTERVAL_US, MAX_STORE_INTERVAL_US, parse_node_id,
};
#[cfg(feature = "log")]
pub use fmt::log;
pub use keying::{BOOT_COUNTER_FAILED, Keying, key_from_page};
pub use node::{Counters, Node, Running, Step};
pub use pab_core::identity::{Firmware, Identity};
pub use pab_storage::{SaveProgress, StoreError, TableStore};
pub use poll_loop::{PollLoop, RECEIVES_PER_TURN};
pub use runner::{SAVE_POLL_US, SAVE_STARVED_US, SENDS_PER_TURN, Watchdog};
#[cfg(feature = "embassy")]
pub use runner::{now, run, run_watched};
pub use settings::{BITRATE_TRIAL_US, Settings};

/// The git commit this build comes from, as hex (`PAB_BUILD_ID` at build time overrides it;
/// empty when unknown): what a node states as its build ([`Firmware::new`]).
pub const BUILD_ID: &str = env!("PAB_BUILD_ID");

/// This firmware's [`Firmware`]: `name` (at most 8 ASCII bytes), the calling crate's version and
/// [`BUILD_ID`]. `pab_app::firmware!("fw-g474")` in a `const`.
#[macro_export]
macro_rules! firmware {
    ($name:expr) => {
        $crate::Firmware::new(
            $name,
            // A test build may say another version (the update tests' v1 and v2).
            match option_env!("PAB_FIRMWARE_VERSION") {
                Some(version) => version,
                None => env!("CARGO_PKG_VERSION"),
            },
            $crate::BUILD_ID,
        )
    };
}

/// What the fuzz target `node_keyed` (fuzz/checks) reads of a node's authentication state and
/// configuration, to hold them to what it saw on the bus ([`Node::auth_probe`]). Not an API.
#[doc(hidden)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AuthProbe {
    /// The outstanding challenge: its exchange nonce and when it expires (kept after it expires,
    /// until replaced or consumed).
    pub challenge: Option<(u64, Instant)>,
    /// The start of the tag-check budget's current window.
    pub window_start: Instant,
    /// Tag checks (and challenges) spent in that window.
    pub checks_in_window: u16,
    /// The diagnostic stream's setting: round period in µs and ports, if it is on.
    pub diagnostic: Option<(u64, u16)>,
}

/// Re-exported so runners name one store trait.
pub mod store {
    pub use pab_storage::{SaveProgress, StoreError, TableStore};
}

use pab_core::{Arbiter, Frame, Instant, PortVerdict};

/// The recipient of what the node's ports deliver: the application's own use of a port (a motor
/// loop, a gripper driver). Every port hands it its frames; a gateway port (the table's
/// [`pab_core::Consumer::Republish`]) also has them re-published, by the node itself.
///
/// A recipient may also observe every verdict of the node's arbiter ([`Recipient::verdict`]): a
/// replay records them to compare runners, a test asserts on them. Observation is opt-in through
/// [`Recipient::OBSERVES_VERDICTS`], a constant, so that a recipient that does not observe (every
/// board's) pays nothing for it: the compiler removes the code.
pub trait Recipient {
    /// Whether the node calls [`Recipient::verdict`]. `false` (the default): the node keeps no
    /// verdict and reads no level. `true`: the node keeps the frame's verdicts (one
    /// [`PortVerdict`] per port of its capacity, on the stack) and calls `verdict` for each.
    const OBSERVES_VERDICTS: bool = false;

    /// Frame `frame`, received at `now`, was delivered at port `port`.
    fn deliver(&mut self, port: u8, frame: &Frame, now: Instant);

    /// The arbiter's verdict on `frame` at one port it fed (only if
    /// [`Recipient::OBSERVES_VERDICTS`]). Called once per fed port, in port order, after the whole
    /// frame has been arbitrated and before any [`Recipient::deliver`] for it. `arbiter` is the
    /// node's, read-only: [`Arbiter::level`] at `now` gives each connection's level after the
    /// frame (a port's levels do not change when another port is arbitrated), without changing
    /// anything.
    fn verdict<const P: usize, const C: usize, const N: usize>(
        &mut self,
        frame: &Frame,
        now: Instant,
        verdict: &PortVerdict,
        arbiter: &Arbiter<P, C, N>,
    ) {
        let _ = (frame, now, verdict, arbiter);
    }
}

/// No local recipient: the node only re-publishes (a pure gateway).
impl Recipient for () {
    fn deliver(&mut self, _port: u8, _frame: &Frame, _now: Instant) {}
}

/// Node capacities for a board (see [`pab_core::BoardArbiter`]) with an 8 KiB transfer buffer.
pub type BoardNode = Node<
    { pab_core::BOARD_PORTS },
    { pab_core::BOARD_CONNECTIONS },
    { pab_core::BOARD_DECISION_NODES },
    8192,
>;

/// Node capacities for Linux: the full table capacities and the largest image.
pub type FullNode = Node<
    { pab_core::MAX_PORTS },
    { pab_core::MAX_CONNECTIONS },
    { pab_core::MAX_DECISION_NODES },
    { pab_core::image::MAX_IMAGE_LEN },
>;
