//! Broadcast of Local Eligibility (BLE): a team of nodes (robots) allocates a task without a
//! coordinator, and survives the death of the node that claimed it.
//!
//! Each node of a peer group (one task, one behaviour instance per node) broadcasts its local
//! eligibility for the task every period, in a [`Claim`] frame. A node **holds** the task while
//! its own eligibility is fresh and positive and no peer frame younger than two periods ranks
//! better. A node that stops broadcasting (killed, unplugged) stops ranking after two periods, so
//! the next node in rank takes the task without anyone having to notice the death: the claim is
//! an active process, as in the paper (Werger and Matarić's Ayllu, section 4.1).
//!
//! # The frame ranks itself
//!
//! A claim's identifier carries the inverted eligibility above the node id, below our priority and
//! marker bits:
//!
//! ```text
//!  28..26    25..24   23    22..7                  6..0
//! priority   marker   1     0xFFFF - eligibility   node id
//!   4         0b10
//! ```
//!
//! So a better claim (higher eligibility; on a tie, the lower node id) has a lower identifier and
//! wins CAN arbitration: the bus itself orders the claims, and two claims can never collide (node
//! ids are unique). Bit 23 is the top bit of the service byte of every other frame of ours, whose
//! services are all below 0x80: claims live in the upper half of our service space, which no
//! [`crate::protocol::Service`] uses. The group is in the payload, not the identifier: 16 bits of
//! eligibility and 7 of node id fill the identifier, and the ranking only matters within a group.
//!
//! Payload, 4 bytes: the group (u8), the eligibility again (u16, little endian) and a reserved
//! byte (0). The repeated eligibility lets a receiver refuse a frame whose identifier and payload
//! disagree rather than guess which one to believe.
//!
//! # Decisions the paper leaves open (see DESIGN.md, "Ayllu: decisions")
//!
//! - Ties go to the lower node id: the paper's "better than or equal" lets two equal robots
//!   block each other (both claim, or both inhibit).
//! - Eligibility 0 means "not a candidate": a node with nothing fresh to offer broadcasts 0 and
//!   never holds. The application decides when its effective eligibility is 0 (for example, when
//!   its behaviour for the task is subsumed locally); this module only ranks.
//! - Freshness is two periods, for peers and for the node's own eligibility, so one lost frame
//!   does not hand the task over.

use embedded_can::Id;
use heapless::Vec;
use serde::{Deserialize, Serialize};

use crate::filter::{Filter, FilterError};
use crate::frame::Frame;
use crate::protocol::{MAX_NODE_ID, Priority};
use crate::time::Instant;

/// The priority claims are sent with: that of heartbeats.
pub const PRIORITY: Priority = Priority::NOMINAL;
/// The payload length of a claim.
pub const PAYLOAD_LEN: usize = 4;
/// Bits 25..23 of every claim's identifier: our marker and the claim bit.
const MARKER_AND_CLAIM: u32 = 0b10 << 24 | 1 << 23;
/// How many periods a claim (or the node's own eligibility) stays fresh.
pub const FRESH_PERIODS: u64 = 2;

/// One node's eligibility for one group's task, as broadcast.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Claim {
    /// The peer group (the task), as numbered by the table.
    pub group: u8,
    /// The sender, 1..=127.
    pub node: u8,
    /// Its eligibility; 0: not a candidate.
    pub eligibility: u16,
}

// Not `#[non_exhaustive]`: the fuzz check's reference decoder (fuzz/checks/src/ble.rs) names
// every variant, so that a new check of the frame gets its reference and its coverage.
/// Why a frame is not a valid claim.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClaimError {
    /// Not a claim identifier (standard, not ours, or the claim bit clear): not for this module.
    NotAClaim,
    /// A claim identifier with another priority than [`PRIORITY`].
    WrongPriority,
    /// The payload is not [`PAYLOAD_LEN`] bytes.
    WrongLength,
    /// Node id 0 or above 127 in the identifier.
    BadNode,
    /// The payload's eligibility differs from the identifier's.
    Mismatch,
    /// The reserved byte is not 0 (a frame of a newer protocol version).
    Reserved,
}

impl core::fmt::Display for ClaimError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ClaimError::NotAClaim => "not a claim",
            ClaimError::WrongPriority => "claim with a wrong priority",
            ClaimError::WrongLength => "claim of a wrong length",
            ClaimError::BadNode => "claim from node 0 or above 127",
            ClaimError::Mismatch => "claim whose identifier and payload disagree",
            ClaimError::Reserved => "claim with a non-zero reserved byte",
        })
    }
}

impl core::error::Error for ClaimError {}

/// Whether a raw 29-bit extended identifier is a claim's (ours, with the claim bit set), whatever
/// its other bits. Costs a mask and a compare.
pub const fn is_claim_id(raw: u32) -> bool {
    raw >> 29 == 0 && raw & (0b11 << 24 | 1 << 23) == MARKER_AND_CLAIM
}

impl Claim {
    /// The 29-bit identifier: lower for a better claim.
    pub const fn raw_id(&self) -> u32 {
        (PRIORITY.value() as u32) << 26
            | MARKER_AND_CLAIM
            | ((u16::MAX - self.eligibility) as u32) << 7
            | (self.node & 0x7F) as u32
    }

    /// The frame to broadcast; `None` for a node id outside 1..=127.
    pub fn frame(&self) -> Option<Frame> {
        if self.node == 0 || self.node > MAX_NODE_ID {
            return None;
        }
        let [low, high] = self.eligibility.to_le_bytes();
        Frame::with_raw_id(self.raw_id(), true, &[self.group, low, high, 0])
    }

    /// Decodes a claim frame. Remote frames are not claims.
    pub fn decode(frame: &Frame) -> Result<Claim, ClaimError> {
        let Id::Extended(id) = frame.id() else {
            return Err(ClaimError::NotAClaim);
        };
        let raw = id.as_raw();
        if !is_claim_id(raw) || frame.is_remote() {
            return Err(ClaimError::NotAClaim);
        }
        if raw >> 26 != PRIORITY.value() as u32 {
            return Err(ClaimError::WrongPriority);
        }
        let &[group, low, high, reserved] = frame.payload() else {
            return Err(ClaimError::WrongLength);
        };
        let node = (raw & 0x7F) as u8;
        if node == 0 {
            return Err(ClaimError::BadNode);
        }
        // 16 bits between 22 and 7: the shift and mask bound it.
        let eligibility = u16::MAX - ((raw >> 7) & 0xFFFF) as u16;
        if u16::from_le_bytes([low, high]) != eligibility {
            return Err(ClaimError::Mismatch);
        }
        if reserved != 0 {
            return Err(ClaimError::Reserved);
        }
        Ok(Claim {
            group,
            node,
            eligibility,
        })
    }

    /// Whether this claim ranks strictly better than `other`: higher eligibility, or equal
    /// eligibility and a lower node id. Exactly "has the lower identifier".
    pub const fn ranks_above(&self, other: &Claim) -> bool {
        self.eligibility > other.eligibility
            || (self.eligibility == other.eligibility && self.node < other.node)
    }
}

/// Why a group's state was refused or a claim not kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum BleError {
    /// A period of 0 µs, or one whose freshness (two periods) overflows.
    BadPeriod,
    /// The node id is 0 or above 127.
    BadNode,
    /// More peers broadcast than the group has room for, all fresh and all ranking better than
    /// the newcomer: the newcomer's claim was dropped. It could not have won anyway.
    TooManyPeers,
    /// Another sender uses this node's own id: a configuration error on the bus.
    OwnIdClash,
}

impl core::fmt::Display for BleError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            BleError::BadPeriod => "BLE period must be positive and below 2^62 µs",
            BleError::BadNode => "BLE node id must be 1..=127",
            BleError::TooManyPeers => "more BLE peers than the group holds",
            BleError::OwnIdClash => "another node broadcasts claims with this node's id",
        })
    }
}

impl core::error::Error for BleError {}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Heard {
    claim: Claim,
    at: Instant,
}

/// One node's view of one peer group: its own eligibility, the peers' latest claims, and when
/// to broadcast next. Holds up to `PEERS` peers (the group's other nodes).
///
/// Memory: about 16 bytes per peer plus 40. Every operation is a scan of at most `PEERS`
/// entries, without division.
#[derive(Clone, Debug)]
pub struct Eligibility<const PEERS: usize> {
    group: u8,
    node: u8,
    period_us: u64,
    own: Option<(u16, Instant)>,
    peers: Vec<Heard, PEERS>,
    next_broadcast: Option<Instant>,
}

impl<const PEERS: usize> Eligibility<PEERS> {
    /// Node `node`'s state for group `group`, broadcasting every `period_us`. Fails on a node id
    /// outside 1..=127 or a period of 0 (or one so long that two of them overflow).
    pub fn new(group: u8, node: u8, period_us: u64) -> Result<Self, BleError> {
        if node == 0 || node > MAX_NODE_ID {
            return Err(BleError::BadNode);
        }
        if period_us == 0 || period_us > 1 << 62 {
            return Err(BleError::BadPeriod);
        }
        Ok(Eligibility {
            group,
            node,
            period_us,
            own: None,
            peers: Vec::new(),
            next_broadcast: None,
        })
    }

    /// [`Eligibility::new`] for `group`, which [`Group::validate`] accepted: without the checks
    /// it made.
    pub(crate) const fn of(group: &Group) -> Self {
        Eligibility {
            group: group.number,
            node: group.node,
            period_us: group.period_us as u64,
            own: None,
            peers: Vec::new(),
            next_broadcast: None,
        }
    }

    /// The group.
    pub const fn group(&self) -> u8 {
        self.group
    }

    /// How long a claim stays fresh: two periods.
    const fn fresh_us(&self) -> u64 {
        // `new` bounds the period by 2^62.
        self.period_us.saturating_mul(FRESH_PERIODS)
    }

    fn is_fresh(&self, at: Instant, now: Instant) -> bool {
        // A time before `at` (a clock that went back) counts as fresh, as the integrators do.
        now.micros_since(at).is_none_or(|age| age < self.fresh_us())
    }

    /// The node's own eligibility, read from its local topic at `now`.
    pub fn on_local(&mut self, eligibility: u16, now: Instant) {
        self.own = Some((eligibility, now));
    }

    /// The node's own eligibility if fresh at `now` (a local reading younger than two periods).
    pub fn own(&self, now: Instant) -> Option<u16> {
        self.own
            .filter(|&(_, at)| self.is_fresh(at, now))
            .map(|(value, _)| value)
    }

    /// A peer's claim heard at `now`. Claims of other groups are ignored (`Ok`). When the group
    /// is full, the newcomer replaces a stale peer, else the worst-ranked one if it ranks better;
    /// otherwise it is dropped ([`BleError::TooManyPeers`]: it could not have won).
    pub fn on_peer(&mut self, claim: Claim, now: Instant) -> Result<(), BleError> {
        if claim.group != self.group {
            return Ok(());
        }
        if claim.node == self.node {
            return Err(BleError::OwnIdClash);
        }
        let heard = Heard { claim, at: now };
        if let Some(slot) = self.peers.iter_mut().find(|h| h.claim.node == claim.node) {
            *slot = heard;
            return Ok(());
        }
        let Err(heard) = self.peers.push(heard) else {
            return Ok(());
        };
        let stale = self.peers.iter().position(|h| !self.is_fresh(h.at, now));
        let worst = self
            .peers
            .iter()
            .enumerate()
            .reduce(|worst, h| {
                if worst.1.claim.ranks_above(&h.1.claim) {
                    h
                } else {
                    worst
                }
            })
            .filter(|(_, h)| claim.ranks_above(&h.claim))
            .map(|(index, _)| index);
        match stale.or(worst).and_then(|index| self.peers.get_mut(index)) {
            Some(slot) => {
                *slot = heard;
                Ok(())
            }
            None => Err(BleError::TooManyPeers),
        }
    }

    /// The best fresh peer claim at `now`, if any.
    pub fn best_peer(&self, now: Instant) -> Option<Claim> {
        self.peers
            .iter()
            .filter(|h| self.is_fresh(h.at, now))
            .map(|h| h.claim)
            .reduce(|best, c| if c.ranks_above(&best) { c } else { best })
    }

    /// Whether this node holds the task at `now`, given the eligibility it offers (its own
    /// reading, or 0 where the application withdraws it): the offer is positive, its own reading
    /// is fresh, and no fresh peer claim ranks above it.
    pub fn holds(&self, offered: u16, now: Instant) -> bool {
        if offered == 0 || self.own(now).is_none() {
            return false;
        }
        let mine = Claim {
            group: self.group,
            node: self.node,
            eligibility: offered,
        };
        self.peers
            .iter()
            .all(|h| !self.is_fresh(h.at, now) || !h.claim.ranks_above(&mine))
    }

    /// The claim to broadcast at `now`, if one is due, with the eligibility offered (0 when the
    /// node's own reading is stale). The first is due at once; then one per period on the grid
    /// of the first; after a gap of more than a period (a node that was not polled), the grid
    /// restarts at `now`.
    pub fn broadcast(&mut self, offered: u16, now: Instant) -> Option<Claim> {
        // One look at the instant due, for all three answers (not yet, on the grid, late): a
        // look per question took 56 bytes more of the boards' flash.
        let base = match self.next_broadcast {
            Some(next) => {
                // `None`: not due yet.
                let late = now.micros_since(next)?;
                if late < self.period_us { next } else { now }
            }
            None => now,
        };
        self.next_broadcast = Some(base.wrapping_add_micros(self.period_us));
        let eligibility = if self.own(now).is_some() { offered } else { 0 };
        Some(Claim {
            group: self.group,
            node: self.node,
            eligibility,
        })
    }

    /// The next instant at which this group's state changes by itself: a broadcast falls due
    /// (`now` before the first one), or a claim (the node's own reading included) goes stale.
    /// Always `Some`: there is always a next broadcast.
    pub fn deadline(&self, now: Instant) -> Option<Instant> {
        Some(now.wrapping_add_micros(self.due_in(now)))
    }

    /// [`Eligibility::deadline`] as microseconds after `now` (0: already due). One pass over the
    /// peers, in plain `u64` offsets from `now`: comparing instants pairwise cost the boards half
    /// a kilobyte of flash.
    pub(crate) fn due_in(&self, now: Instant) -> u64 {
        let mut soonest = self
            .next_broadcast
            .map_or(0, |next| next.micros_since(now).unwrap_or(0));
        let fresh = self.fresh_us();
        let heard = self.peers.iter().map(|h| h.at);
        for at in heard.chain(self.own.map(|(_, at)| at)) {
            // Fresh until `at + fresh`: an expiry still ahead is a deadline, a past one is not.
            match at.wrapping_add_micros(fresh).micros_since(now) {
                Some(left) if left > 0 => soonest = soonest.min(left),
                _ => {}
            }
        }
        soonest
    }
}

/// Ports of a node at which one group's claim is a rule variable.
pub const MAX_GROUP_PORTS: usize = 4;
/// BLE groups a node takes part in (a task each).
pub const MAX_GROUPS: usize = 4;
/// Peers a node keeps the claims of, per group: a group has at most 8 nodes.
pub const MAX_PEERS: usize = 7;

// A table's and an arbiter's room for groups: none without the `ble` feature (a table's list must
// then be empty, and a board keeps no RAM for the groups' claims).
pub(crate) const TABLE_GROUPS: usize = if cfg!(feature = "ble") { MAX_GROUPS } else { 0 };

/// The filter of a group's claim connection (the rule variable whose activity is `holds`): every
/// claim identifier. Nodes never arbitrate frames of ours, so no frame ever feeds it; the loader
/// requires it on every claim connection, so that no topic can.
pub const CLAIM_SLOT_FILTER: Filter = match Filter::new(MARKER_AND_CLAIM, 0b111 << 23, true) {
    Ok(filter) => filter,
    Err(_) => panic!("the claim filter is valid"),
};
/// The longest period: an hour, in µs (fits the table's `u32`).
pub const MAX_PERIOD_US: u32 = 3_600_000_000;

/// Where a node reads its own eligibility in the frames of its local topic: an unsigned field of
/// 1 or 2 bytes (a claim's identifier ranks 16 bits).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EligibilityField {
    /// The first byte.
    pub offset: u8,
    /// 1 or 2.
    pub size: u8,
    /// Byte order of a 2-byte field.
    pub big_endian: bool,
}

impl EligibilityField {
    /// Checks that the field has 1 or 2 bytes within a classic frame's 8.
    pub const fn validate(&self) -> Result<(), GroupError> {
        if (self.size == 1 || self.size == 2) && self.offset as usize + self.size as usize <= 8 {
            Ok(())
        } else {
            Err(GroupError::Field)
        }
    }

    /// The field's value in `payload`; `None` when the frame is too short to carry it (no
    /// reading: a frame that says nothing about eligibility does not make it fresh).
    pub fn read(&self, payload: &[u8]) -> Option<u16> {
        let start = self.offset as usize;
        match self.size {
            1 => payload.get(start).map(|&b| u16::from(b)),
            2 => {
                let &[a, b] = payload.get(start..start.checked_add(2)?)? else {
                    return None;
                };
                Some(if self.big_endian {
                    u16::from_be_bytes([a, b])
                } else {
                    u16::from_le_bytes([a, b])
                })
            }
            _ => None,
        }
    }
}

/// One port at which a group's claim is a rule variable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GroupPort {
    /// The port.
    pub port: u8,
    /// The connection of the port whose activity is the claim (`holds`): a rule variable that
    /// no frame feeds.
    pub claim: u8,
    /// The connections whose rule names the group (bit i: connection i): the node offers its
    /// eligibility only while one of them could deliver with the claim taken as held.
    pub gated: u32,
}

/// A node's part in one BLE peer group, as its table describes it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Group {
    /// The group's number on the bus (byte 0 of its claims).
    pub number: u8,
    /// This node's id, 1..=127: its claims carry it, and ties go to the lower one.
    pub node: u8,
    /// The broadcast period, µs (1..=[`MAX_PERIOD_US`]).
    pub period_us: u32,
    /// The node's own eligibility topic.
    pub local: Filter,
    /// Where the eligibility is in its frames.
    pub field: EligibilityField,
    /// How many other nodes the group has: the room kept for their claims.
    pub peers: u8,
    /// Where the claim is a rule variable.
    pub ports: Vec<GroupPort, MAX_GROUP_PORTS>,
}

/// Why a group of a table was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum GroupError {
    /// A period of 0 or above [`MAX_PERIOD_US`].
    Period,
    /// An eligibility field that is not 1 or 2 bytes within 8.
    Field,
    /// The node id is 0 or above 127, or (when an image is loaded) not the image's node id.
    Node,
    /// The local topic's filter is invalid.
    Filter(FilterError),
    /// More peers than the node has room for.
    TooManyPeers,
    /// A port the table does not have.
    NoSuchPort {
        /// The port.
        port: u8,
    },
    /// A port listed twice for one group.
    DuplicatePort {
        /// The port.
        port: u8,
    },
    /// A claim or gated connection beyond the port's connections, or a claim among the gated.
    Connection {
        /// The port.
        port: u8,
    },
    /// Two groups with one number.
    DuplicateGroup {
        /// The number.
        number: u8,
    },
    /// One connection is the claim of two groups.
    SharedClaim {
        /// The port.
        port: u8,
    },
}

impl core::fmt::Display for GroupError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GroupError::Period => write!(f, "BLE period must be 1..={MAX_PERIOD_US} µs"),
            GroupError::Field => f.write_str("BLE eligibility field must be 1 or 2 bytes within 8"),
            GroupError::Node => f.write_str("BLE node id must be 1..=127 and the image's"),
            GroupError::Filter(error) => write!(f, "BLE local topic: {error}"),
            GroupError::TooManyPeers => f.write_str("more BLE peers than the node holds"),
            GroupError::NoSuchPort { port } => write!(f, "BLE group names port {port}, absent"),
            GroupError::DuplicatePort { port } => write!(f, "BLE group lists port {port} twice"),
            GroupError::Connection { port } => {
                write!(
                    f,
                    "BLE claim or gated connection out of range at port {port}"
                )
            }
            GroupError::DuplicateGroup { number } => write!(f, "two BLE groups numbered {number}"),
            GroupError::SharedClaim { port } => {
                write!(
                    f,
                    "one connection of port {port} is the claim of two BLE groups"
                )
            }
        }
    }
}

impl core::error::Error for GroupError {}

impl Group {
    /// Checks what the group says by itself, for a table of `ports` ports and room for
    /// `max_peers` peers: period, node id, field, local filter, peers, and each port existing
    /// and named once. What each port's entry says about its connections (the claim's filter,
    /// the ranges, a claim shared between groups) the table checks port by port, where it has
    /// the connections at hand. Costs a pass over the group's ports.
    // Left to the inliner: out of line (inlined, it once took 64 bytes more) it now takes 4
    // bytes more of both boards' flash. Run once per group and table.
    pub fn validate(&self, ports: usize, max_peers: usize) -> Result<(), GroupError> {
        if self.period_us == 0 || self.period_us > MAX_PERIOD_US {
            return Err(GroupError::Period);
        }
        if self.node == 0 || self.node > MAX_NODE_ID {
            return Err(GroupError::Node);
        }
        self.field.validate()?;
        self.local.validate().map_err(GroupError::Filter)?;
        if usize::from(self.peers) > max_peers {
            return Err(GroupError::TooManyPeers);
        }
        let mut seen = 0u32;
        for entry in &self.ports {
            let port = entry.port;
            if usize::from(port) >= ports {
                return Err(GroupError::NoSuchPort { port });
            }
            // A table has at most 16 ports: the shift is in range.
            let bit = 1u32.checked_shl(u32::from(port)).unwrap_or(0);
            if bit == 0 || seen & bit != 0 {
                return Err(GroupError::DuplicatePort { port });
            }
            seen |= bit;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000;
    const PERIOD: u64 = 100 * MS;

    fn at(ms: u64) -> Instant {
        Instant::from_micros(ms * MS)
    }

    fn claim(node: u8, eligibility: u16) -> Claim {
        Claim {
            group: 3,
            node,
            eligibility,
        }
    }

    #[test]
    fn a_claim_round_trips_and_its_identifier_ranks_it() {
        let c = claim(5, 1234);
        let frame = c.frame().unwrap();
        assert_eq!(Claim::decode(&frame), Ok(c));
        assert_eq!(frame.payload(), &[3, 0xD2, 0x04, 0]);
        assert_eq!(c.raw_id() >> 26, 4);
        assert!(is_claim_id(c.raw_id()));
        // Lower identifier exactly when ranking above, over a grid of pairs.
        for (a, b) in [
            (0u16, 1u16),
            (1, 1),
            (500, 499),
            (u16::MAX, u16::MAX),
            (7, 0),
        ] {
            for (n, m) in [(1u8, 2u8), (2, 1), (127, 1), (4, 4)] {
                let (x, y) = (claim(n, a), claim(m, b));
                assert_eq!(x.ranks_above(&y), x.raw_id() < y.raw_id(), "{x:?} {y:?}");
            }
        }
    }

    #[test]
    fn the_identifiers_of_the_protocol_document() {
        // docs/can-protocol.md, "Broadcast of Local Eligibility".
        assert_eq!(claim(2, 1000).raw_id(), 0x12FE_0B82);
        assert_eq!(claim(3, 1000).raw_id(), 0x12FE_0B83);
        assert_eq!(claim(1, 999).raw_id(), 0x12FE_0C01);
    }

    #[test]
    fn frames_that_are_not_valid_claims_are_refused_with_their_reason() {
        let good = claim(5, 1234);
        let raw = good.raw_id();
        let frame = |raw: u32, data: &[u8]| Frame::with_raw_id(raw, true, data).unwrap();
        assert_eq!(
            Claim::decode(&frame(raw, &[3, 0xD2, 0x04])),
            Err(ClaimError::WrongLength)
        );
        assert_eq!(
            Claim::decode(&frame(raw, &[3, 0xD3, 0x04, 0])),
            Err(ClaimError::Mismatch)
        );
        assert_eq!(
            Claim::decode(&frame(raw, &[3, 0xD2, 0x04, 1])),
            Err(ClaimError::Reserved)
        );
        assert_eq!(
            Claim::decode(&frame(raw & !0x7F, &[3, 0xD2, 0x04, 0])),
            Err(ClaimError::BadNode)
        );
        let other_priority = raw & !(0b111 << 26) | 2 << 26;
        assert_eq!(
            Claim::decode(&frame(other_priority, &[3, 0xD2, 0x04, 0])),
            Err(ClaimError::WrongPriority)
        );
        // A heartbeat (service 0x02) is ours but not a claim; a standard frame neither.
        let heartbeat = crate::protocol::FrameId::new(crate::protocol::Service::Heartbeat, 5, 0xFF);
        assert_eq!(
            Claim::decode(&frame(heartbeat.raw(), &[0; 8])),
            Err(ClaimError::NotAClaim)
        );
        let standard = Frame::with_raw_id(0x123, false, &[3, 0xD2, 0x04, 0]).unwrap();
        assert_eq!(Claim::decode(&standard), Err(ClaimError::NotAClaim));
        assert_eq!(claim(0, 1).frame(), None);
        assert_eq!(claim(128, 1).frame(), None);
    }

    #[test]
    fn no_service_of_ours_carries_the_claim_bit() {
        for service in crate::protocol::Service::ALL {
            let id = crate::protocol::FrameId::new(service, 1, 2);
            assert!(!is_claim_id(id.raw()), "{service:?}");
        }
    }

    #[test]
    fn the_best_fresh_node_holds_and_a_silent_one_frees_the_task_after_two_periods() {
        let mut r1 = Eligibility::<4>::new(3, 1, PERIOD).unwrap();
        r1.on_local(50, at(0));
        assert!(r1.holds(50, at(0)), "nobody else heard: it holds");
        r1.on_peer(claim(2, 80), at(10)).unwrap();
        assert!(!r1.holds(50, at(10)));
        // r2 falls silent: its claim is fresh for two periods from when it was heard.
        r1.on_local(50, at(150));
        assert!(!r1.holds(50, at(209)));
        assert!(r1.holds(50, at(210)));
        // Its own reading goes stale the same way.
        assert!(r1.holds(50, at(349)));
        assert!(!r1.holds(50, at(350)));
    }

    #[test]
    fn equal_eligibilities_go_to_the_lower_node_id_and_zero_never_holds() {
        let mut r1 = Eligibility::<4>::new(3, 1, PERIOD).unwrap();
        let mut r2 = Eligibility::<4>::new(3, 2, PERIOD).unwrap();
        r1.on_local(70, at(0));
        r2.on_local(70, at(0));
        r1.on_peer(claim(2, 70), at(1)).unwrap();
        r2.on_peer(claim(1, 70), at(1)).unwrap();
        assert!(r1.holds(70, at(1)));
        assert!(!r2.holds(70, at(1)));
        assert!(!r1.holds(0, at(1)), "eligibility 0 is not a candidate");
        // A peer offering 0 never ranks above a positive offer.
        r2.on_peer(claim(1, 0), at(2)).unwrap();
        assert!(r2.holds(70, at(2)));
    }

    #[test]
    fn broadcasts_follow_the_period_grid_and_say_zero_when_the_reading_is_stale() {
        let mut r = Eligibility::<2>::new(3, 9, PERIOD).unwrap();
        assert_eq!(r.broadcast(40, at(5)), Some(claim(9, 0)));
        assert_eq!(r.broadcast(40, at(104)), None);
        r.on_local(40, at(100));
        assert_eq!(r.broadcast(40, at(105)).map(|c| c.eligibility), Some(40));
        assert_eq!(r.deadline(at(106)), Some(at(205)));
        // Late by more than a period: the grid restarts.
        assert!(r.broadcast(40, at(420)).is_some());
        assert_eq!(r.deadline(at(420)), Some(at(520)));
        assert_eq!(r.broadcast(40, at(420)).map(|c| c.eligibility), None);
        assert_eq!(r.broadcast(40, at(520)).map(|c| c.eligibility), Some(0));
    }

    #[test]
    fn a_full_group_keeps_the_best_claims_and_replaces_stale_ones_first() {
        let mut r = Eligibility::<2>::new(3, 1, PERIOD).unwrap();
        r.on_peer(claim(2, 10), at(0)).unwrap();
        r.on_peer(claim(3, 20), at(0)).unwrap();
        assert_eq!(r.on_peer(claim(4, 5), at(1)), Err(BleError::TooManyPeers));
        r.on_peer(claim(5, 30), at(1)).unwrap();
        assert_eq!(r.best_peer(at(1)), Some(claim(5, 30)));
        // Node 2's claim was the one replaced; at 250 both are stale and 6 replaces one.
        r.on_peer(claim(6, 1), at(250)).unwrap();
        assert_eq!(r.best_peer(at(250)), Some(claim(6, 1)));
        assert_eq!(r.on_peer(claim(1, 9), at(251)), Err(BleError::OwnIdClash));
        // Other groups are not ours.
        let other = Claim {
            group: 4,
            ..claim(7, 999)
        };
        assert_eq!(r.on_peer(other, at(252)), Ok(()));
        assert_eq!(r.best_peer(at(252)), Some(claim(6, 1)));
    }

    fn group(ports: &[(u8, u8, u32)]) -> Group {
        Group {
            number: 1,
            node: 1,
            period_us: 100_000,
            local: Filter::exact(0x180, false).unwrap(),
            field: EligibilityField {
                offset: 2,
                size: 2,
                big_endian: false,
            },
            peers: 2,
            ports: ports
                .iter()
                .map(|&(port, claim, gated)| GroupPort { port, claim, gated })
                .collect(),
        }
    }

    #[test]
    fn the_eligibility_field_reads_its_bytes_or_nothing() {
        let le = EligibilityField {
            offset: 2,
            size: 2,
            big_endian: false,
        };
        assert_eq!(le.read(&[0, 0, 0x34, 0x12]), Some(0x1234));
        assert_eq!(
            EligibilityField {
                big_endian: true,
                ..le
            }
            .read(&[0, 0, 0x34, 0x12]),
            Some(0x3412)
        );
        assert_eq!(le.read(&[0, 0, 0x34]), None, "too short: no reading");
        let byte = EligibilityField {
            offset: 7,
            size: 1,
            big_endian: false,
        };
        assert_eq!(byte.read(&[0, 0, 0, 0, 0, 0, 0, 9]), Some(9));
        assert_eq!(byte.validate(), Ok(()));
        assert_eq!(
            EligibilityField { size: 2, ..byte }.validate(),
            Err(GroupError::Field)
        );
        assert_eq!(
            EligibilityField {
                size: 4,
                offset: 0,
                ..byte
            }
            .validate(),
            Err(GroupError::Field)
        );
    }

    #[test]
    fn a_group_is_checked_by_itself() {
        // The checks against the ports' connections are the table's (core/tests/image_corruption.rs).
        assert_eq!(
            group(&[(0, 2, 0b011), (1, 0, 0b110)]).validate(2, 2),
            Ok(())
        );
        assert_eq!(
            group(&[(0, 2, 0b011)]).validate(2, 1),
            Err(GroupError::TooManyPeers)
        );
        assert_eq!(
            group(&[(2, 0, 0)]).validate(2, 2),
            Err(GroupError::NoSuchPort { port: 2 })
        );
        assert_eq!(
            group(&[(0, 0, 0), (0, 1, 0)]).validate(2, 2),
            Err(GroupError::DuplicatePort { port: 0 })
        );
        for period_us in [0, MAX_PERIOD_US + 1] {
            let g = Group {
                period_us,
                ..group(&[])
            };
            assert_eq!(g.validate(2, 2), Err(GroupError::Period));
        }
        for node in [0, 128] {
            let g = Group { node, ..group(&[]) };
            assert_eq!(g.validate(2, 2), Err(GroupError::Node));
        }
    }

    #[test]
    fn configuration_is_checked() {
        assert_eq!(
            Eligibility::<1>::new(0, 0, PERIOD).err(),
            Some(BleError::BadNode)
        );
        assert_eq!(
            Eligibility::<1>::new(0, 128, PERIOD).err(),
            Some(BleError::BadNode)
        );
        assert_eq!(
            Eligibility::<1>::new(0, 1, 0).err(),
            Some(BleError::BadPeriod)
        );
        assert_eq!(
            Eligibility::<1>::new(0, 1, u64::MAX).err(),
            Some(BleError::BadPeriod)
        );
    }
}

crate::wire::decode_struct!(EligibilityField {
    offset,
    size,
    big_endian
});
crate::wire::decode_struct!(GroupPort { port, claim, gated });

impl crate::wire::Decode for Group {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        Group {
            number: r.decode(),
            node: r.decode(),
            period_us: r.decode(),
            local: r.decode(),
            field: r.decode(),
            peers: r.decode(),
            ports: r.vec(),
        }
    }
}
