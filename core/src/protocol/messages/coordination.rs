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
