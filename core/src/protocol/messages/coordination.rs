//! The frames nodes coordinate behaviours with: competitive dynamics' gates, HBBA's desires,
//! intention and message filters (their commands and status), and exploitation edges.

/// The gates of a competitive-dynamics group (service 0x07), sent by the node that runs the group
/// to [`BROADCAST`](crate::protocol::BROADCAST) whenever a gate changes and every [`Gates::PERIOD_US`] otherwise
/// ([`crate::dynamics`]).
///
/// ```text
/// byte 0     group: its number in the network (the file's order of [dynamics.*], from 0)
/// byte 1     behaviours in the group, 1..=32
/// bytes 2-5  gates, u32 LE: bit i set while behaviour i's gate is open; bits at and above the
///            count are 0
/// byte 6     changes: how many times the mask changed since the group started, mod 256
/// byte 7     reserved, 0
/// ```
///
/// The count travels so that a node whose table imports the group refuses the gates of a group
/// of another size (two networks on one bus, or a table not pushed yet) instead of reading the
/// wrong bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Gates {
    /// The group's number in the network.
    pub group: u8,
    /// How many behaviours the group has, 1..=32.
    pub behaviours: u8,
    /// Bit i: behaviour i's gate is open.
    pub mask: u32,
    /// Changes of the mask since the group started, mod 256.
    pub changes: u8,
}

impl Gates {
    /// The longest a group's owner stays silent: it repeats its gates at this period, 100 ms.
    pub const PERIOD_US: u64 = 100_000;
    /// A group not heard for this long (three periods) reads as all gates closed, with a fault.
    pub const SILENCE_US: u64 = 3 * Gates::PERIOD_US;

    /// Whether the fields are in range: 1..=32 behaviours, no gate at or above the count.
    pub const fn is_valid(&self) -> bool {
        self.behaviours >= 1
            && self.behaviours <= 32
            && (self.behaviours == 32 || self.mask >> self.behaviours == 0)
    }
}

/// A desire (service 0x08), sent by a motivation (any node, or the tool) to
/// [`BROADCAST`](crate::protocol::BROADCAST); the intention node keeps it for its lease ([`crate::hbba::Desires`]).
///
/// ```text
/// byte 0     class: its number in the network (first appearance among [hbba.strategies.*])
/// byte 1     reserved, 0
/// bytes 2-3  intensity, u16 LE: 0 withdraws the desire, else 1..65535
/// bytes 4-5  lease in ms, u16 LE: the desire lapses unless refreshed within it (1..65535)
/// bytes 6-7  the sender's number for this desire, u16 LE: (source, id) names it
/// ```
///
/// A sender refreshes a desire by sending it again before its lease runs out (at half the lease,
/// say, so that one lost frame costs nothing).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DesireFrame {
    /// The class desired.
    pub class: u8,
    /// How much; 0 withdraws.
    pub intensity: u16,
    /// Lease, milliseconds.
    pub lease_ms: u16,
    /// The sender's number for the desire.
    pub id: u16,
}

/// The intention (service 0x09): the strategies the intention node selected, sent to
/// [`BROADCAST`](crate::protocol::BROADCAST) after every solve that changed them and once a second.
///
/// ```text
/// bytes 0-7  u64 LE: bit s set when strategy s (the file's order of [hbba.strategies.*]) runs
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Intention {
    /// Bit s: strategy s is selected.
    pub strategies: u64,
}

/// A node's message filters (service 0x0A), sent to [`BROADCAST`](crate::protocol::BROADCAST) after every filter
/// command it applied and after every heartbeat group, by nodes whose table has filters.
///
/// ```text
/// byte 0     the profile last switched to (0..=15), or 0xFF once a FilterSet changed one since
/// byte 1     reserved, 0
/// bytes 2-3  the sequence number of the last filter command applied, u16 LE (0 since boot)
/// byte 4     filtered connections: how many the table names
/// byte 5     of them closed (φ = 0)
/// byte 6     of them throttled (φ ≥ 2)
/// byte 7     reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterStatus {
    /// The profile in force, or [`FilterStatus::SET_ONE_BY_ONE`].
    pub profile: u8,
    /// The last applied command's sequence number.
    pub sequence: u16,
    /// Connections with a filter.
    pub filtered: u8,
    /// Of them, closed.
    pub closed: u8,
    /// Of them, passing one frame in φ ≥ 2.
    pub throttled: u8,
}

impl FilterStatus {
    /// [`FilterStatus::profile`] once a single filter was set after the last profile switch.
    pub const SET_ONE_BY_ONE: u8 = 0xFF;
}

/// Behaviour exploitation (service 0x0B), sent by a node to [`BROADCAST`](crate::protocol::BROADCAST) when a
/// connection of one of its ports starts or stops delivering: edges only, so that motivations
/// can watch what is used without a stream.
///
/// ```text
/// byte 0     port (the node's order)
/// byte 1     connection (the port's order)
/// byte 2     1: started delivering, 0: stopped
/// byte 3     reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Exploitation {
    /// The port.
    pub port: u8,
    /// The connection.
    pub connection: u8,
    /// Started (true) or stopped (false) delivering.
    pub delivering: bool,
}

/// Switches all of a node's message filters to one of its table's profiles (service 0x17), from
/// the intention node; the node answers with [`FilterStatus`], or a `FilterRefused` fault.
///
/// ```text
/// byte 0     profile, 0..=15 (profile 0: every filtered connection closed, as at boot)
/// byte 1     reserved, 0
/// bytes 2-3  sequence number, u16 LE, echoed in FilterStatus
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterProfile {
    /// The profile.
    pub profile: u8,
    /// Echoed in [`FilterStatus::sequence`].
    pub sequence: u16,
}

/// Sets one message filter of a node (service 0x18), from the intention node; the node answers
/// with [`FilterStatus`], or a `FilterRefused` fault.
///
/// ```text
/// byte 0     port (the node's order)
/// byte 1     connection (the port's order): one the table gives a filter
/// byte 2     φ: 0 closes, 1 passes every frame, N passes one in N
/// byte 3     reserved, 0
/// bytes 4-5  sequence number, u16 LE, echoed in FilterStatus
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterSet {
    /// The port.
    pub port: u8,
    /// The connection.
    pub connection: u8,
    /// The filter's φ.
    pub phi: u8,
    /// Echoed in [`FilterStatus::sequence`].
    pub sequence: u16,
}

use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Values};

impl Gates {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Gates,
        &[
            Field::new(
                "group",
                0,
                8,
                "the group's number in the network (the order of [dynamics.*], from 0)",
            ),
            Field::new("behaviours", 8, 8, "the group's behaviours, 1..32").max(32),
            Field::new(
                "gates",
                16,
                32,
                "bit i set while behaviour i's gate is open; bits at and above the count are 0",
            ),
            Field::new(
                "changes",
                48,
                8,
                "changes of the gates since the group started, mod 256",
            ),
            Field::reserved("reserved", 56, 8),
        ],
        "the gates of a competitive-dynamics group, from the node that runs it, whenever they \
         change and every 100 ms otherwise; a group not heard for 300 ms reads as all gates \
         closed.",
    );
}

impl DesireFrame {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Desire,
        &[
            Field::new(
                "class",
                0,
                8,
                "the class desired: its number in the network (first appearance among \
                 [hbba.strategies.*], from 0)",
            ),
            Field::reserved("reserved", 8, 8),
            Field::new(
                "intensity",
                16,
                16,
                "how much the class is desired; 0 withdraws the desire",
            ),
            Field::new(
                "lease",
                32,
                16,
                "the desire lapses unless sent again within this many ms",
            )
            .unit("ms"),
            Field::new(
                "id",
                48,
                16,
                "the sender's number for the desire: (source, id) names it",
            ),
        ],
        "a motivation's desire for the intention workspace; it lapses unless sent again within \
         its lease; intensity 0 withdraws it.",
    );
}

impl Intention {
    /// The payload's layout: the u64 of selected strategies as two halves, since not every
    /// DBC tool reads a 64-bit signal.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Intention,
        &[
            Field::new(
                "strategies_low",
                0,
                32,
                "bit s set when strategy s (file order of [hbba.strategies.*]) is selected, s < 32",
            ),
            Field::new(
                "strategies_high",
                32,
                32,
                "bit s - 32 set when strategy s is selected, 32 <= s < 64",
            ),
        ],
        "the strategies the intention node selected, after every solve that changed them and \
         once a second.",
    );
}

impl FilterStatus {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::FilterStatus,
        &[
            Field::new(
                "profile",
                0,
                8,
                "the filter profile last switched to (0..15), or 255 once a FilterSet changed a \
                 filter since",
            ),
            Field::reserved("reserved", 8, 8),
            Field::new(
                "sequence",
                16,
                16,
                "the sequence number of the last filter command applied (0 since boot)",
            ),
            Field::new("filtered", 32, 8, "connections with a message filter"),
            Field::new("closed", 40, 8, "of them closed (phi = 0)"),
            Field::new("throttled", 48, 8, "of them passing one frame in phi >= 2"),
            Field::reserved("reserved2", 56, 8),
        ],
        "a node's message filters, after every filter command it applied and after every \
         heartbeat group.",
    );
}

impl Exploitation {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Exploitation,
        &[
            Field::new("port", 0, 8, "the port, in the node's order"),
            Field::new("connection", 8, 8, "the connection, in the port's order"),
            Field::new("delivering", 16, 8, "the edge").values(Values::Edge),
            Field::reserved("reserved", 24, 8),
        ],
        "a connection of the node started or stopped delivering (edges only).",
    );
}

impl FilterProfile {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::FilterProfile,
        &[
            Field::new(
                "profile",
                0,
                8,
                "the profile of the node's table to switch every filter to (0: all closed)",
            ),
            Field::reserved("reserved", 8, 8),
            Field::new("sequence", 16, 16, "echoed in the node's FilterStatus"),
        ],
        "switches every message filter of a node to one of its table's profiles; answered by \
         FilterStatus or a FilterRefused fault.",
    );
}

impl FilterSet {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::FilterSet,
        &[
            Field::new("port", 0, 8, "the port, in the node's order"),
            Field::new("connection", 8, 8, "the connection, in the port's order"),
            Field::new(
                "phi",
                16,
                8,
                "0 closes, 1 passes every frame, N passes one frame in N",
            ),
            Field::reserved("reserved", 24, 8),
            Field::new("sequence", 32, 16, "echoed in the node's FilterStatus"),
        ],
        "sets one message filter of a node; answered by FilterStatus or a FilterRefused fault.",
    );
}
