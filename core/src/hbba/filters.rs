//! HBBA's message filters on a node: which connections the intention node may throttle, the
//! profiles the table carries for them, and each filter's state at run time.
//!
//! A filter sits in front of one connection's integrator (DESIGN.md, "HBBA: decisions"): φ = 0
//! drops every frame, φ = 1 passes every frame, φ = N passes one frame in N. A frame it drops is,
//! for that connection, a frame that never came: it neither stimulates nor is delivered, nor is
//! its value taken. The count restarts at every change of φ, so the first frame after a change
//! passes (hbba_lite's filters behave so). A connection that some strategy filters starts closed,
//! as the strategy that would open it is not running yet; every other connection has no filter.
//!
//! The table lists the filtered connections ([`MessageFilters::connections`]) and up to
//! [`MAX_PROFILES`] − 1 profiles, each a φ per filtered connection; profile 0 is implicit: all
//! closed, the state at boot. One `FilterProfile` frame switches every filter at once
//! ([`Throttles::set_profile`]), one `FilterSet` frame one filter ([`Throttles::set`]).
//!
//! Cost on the frame path: a connection without a filter costs the arbiter one byte load and a
//! comparison per frame; one with a filter, a counter update ([`Throttle::pass`]).

use heapless::Vec;
use serde::{Deserialize, Serialize};

/// Filtered connections per node, at most: a node's throttled perception and behaviour inputs.
pub const MAX_FILTERED: usize = 32;
/// Profiles per node, at most, profile 0 (all closed) included: a profile number is 4 bits.
pub const MAX_PROFILES: usize = 16;
/// The profiles a table stores: all but profile 0, which is implicit.
pub const STORED_PROFILES: usize = MAX_PROFILES - 1;

/// The slot of a connection without a filter ([`crate::Arbiter`] keeps one byte per
/// connection: the position of its filter among the node's, or this).
pub(crate) const UNFILTERED: u8 = u8::MAX;

/// The message-filter part of a node's table.
///
/// Memory: 2 bytes per filtered connection and one per filtered connection and stored profile
/// (at most 64 + 480 bytes and the lists' lengths).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MessageFilters {
    /// The filtered connections, as indices into the table's connections (all ports, in table
    /// order), strictly increasing.
    pub connections: Vec<u16, MAX_FILTERED>,
    /// Profiles 1, 2, ...: for each, φ of every filtered connection in the order of
    /// [`MessageFilters::connections`].
    pub profiles: Vec<Vec<u8, MAX_FILTERED>, STORED_PROFILES>,
}

/// Why a table's message filters were refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FiltersError {
    /// A filtered connection beyond the table's connections, or listed out of order or twice.
    Connection {
        /// Its position in [`MessageFilters::connections`].
        position: u8,
    },
    /// A profile without exactly one φ per filtered connection.
    ProfileLength {
        /// The profile's number (1 for the first stored).
        profile: u8,
    },
    /// More than [`STORED_PROFILES`] profiles besides profile 0.
    TooManyProfiles,
}

impl core::fmt::Display for FiltersError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FiltersError::Connection { position } => write!(
                f,
                "message filter {position} names no connection of the table, or not in order"
            ),
            FiltersError::ProfileLength { profile } => write!(
                f,
                "filter profile {profile} has not one φ per filtered connection"
            ),
            FiltersError::TooManyProfiles => {
                write!(
                    f,
                    "more than {STORED_PROFILES} filter profiles besides profile 0"
                )
            }
        }
    }
}

impl core::error::Error for FiltersError {}

impl MessageFilters {
    /// Whether the table gives no connection a filter.
    pub fn is_empty(&self) -> bool {
        self.connections.is_empty()
    }

    /// Checks the part against a table of `connections` connections. Costs one pass over each
    /// list.
    pub fn validate(&self, connections: usize) -> Result<(), FiltersError> {
        // The lowest connection the next may be (strictly increasing), widened so that the one
        // after 65 535 is 65 536: a bound rather than an `Option` of the previous one.
        let mut lowest = 0u32;
        for (position, &connection) in self.connections.iter().enumerate() {
            let connection = u32::from(connection);
            if connection < lowest || connection as usize >= connections {
                return Err(FiltersError::Connection {
                    position: position as u8,
                });
            }
            lowest = connection + 1;
        }
        for (k, profile) in self.profiles.iter().enumerate() {
            if profile.len() != self.connections.len() {
                return Err(FiltersError::ProfileLength {
                    profile: k as u8 + 1,
                });
            }
        }
        Ok(())
    }

    /// Appends a profile: φ per filtered connection, in [`MessageFilters::connections`]' order.
    /// Fails, changing nothing, when there is not one φ per filtered connection or the table has
    /// [`STORED_PROFILES`] already.
    pub fn push_profile(&mut self, phis: &[u8]) -> Result<(), FiltersError> {
        let profile = self.profiles.len() as u8 + 1;
        let error = FiltersError::ProfileLength { profile };
        if phis.len() != self.connections.len() {
            return Err(error);
        }
        let stored = Vec::from_slice(phis).map_err(|_| error)?;
        self.profiles
            .push(stored)
            .map_err(|_| FiltersError::TooManyProfiles)
    }

    /// φ of filtered connection `position` in profile `profile` (0: closed), or `None` for a
    /// profile the table does not have.
    pub fn phi(&self, profile: u8, position: usize) -> Option<u8> {
        match usize::from(profile).checked_sub(1) {
            None => Some(0),
            Some(stored) => self.profiles.get(stored)?.get(position).copied(),
        }
    }
}

crate::wire::decode_struct!(MessageFilters {
    connections,
    profiles
});

/// One filter at run time: φ and the frames seen since the last one passed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Throttle {
    phi: u8,
    /// Frames dropped since the last that passed (below φ).
    since: u8,
    /// Whether the last frame offered passed.
    passed: bool,
}

impl Throttle {
    /// A filter at φ, whose next frame passes (unless φ = 0).
    pub const fn new(phi: u8) -> Throttle {
        Throttle {
            phi,
            since: 0,
            passed: false,
        }
    }

    /// φ.
    pub const fn phi(&self) -> u8 {
        self.phi
    }

    /// Sets φ; any change restarts the count, so the next frame passes.
    pub fn set(&mut self, phi: u8) {
        if phi != self.phi {
            *self = Throttle::new(phi);
        }
    }

    /// A frame offered: whether it passes. φ = 0 passes none; otherwise the first after a change
    /// and then one in φ. Costs a comparison and an increment.
    pub fn pass(&mut self) -> bool {
        let passes = self.phi != 0 && self.since == 0;
        if self.phi != 0 {
            self.since += 1;
            if self.since >= self.phi {
                self.since = 0;
            }
        }
        self.passed = passes;
        passes
    }

    /// Whether the last frame offered passed (`false` before any).
    pub const fn last_passed(&self) -> bool {
        self.passed
    }
}

/// Why a filter command was refused (the `FilterRefused` fault's byte 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CommandError {
    /// A profile the table does not have (1).
    NoSuchProfile,
    /// A connection the table gives no filter (2).
    NotFiltered,
    /// The table has no message filters at all (3).
    NoFilters,
}

impl core::fmt::Display for CommandError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            CommandError::NoSuchProfile => "filter profile the table does not have",
            CommandError::NotFiltered => "connection the table gives no filter",
            CommandError::NoFilters => "the table has no message filters",
        })
    }
}

impl core::error::Error for CommandError {}

impl CommandError {
    /// The code of the `FilterRefused` fault's byte 0.
    pub const fn code(self) -> u8 {
        match self {
            CommandError::NoSuchProfile => 1,
            CommandError::NotFiltered => 2,
            CommandError::NoFilters => 3,
        }
    }
}

/// The counts a `FilterStatus` frame reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterCounts {
    /// Filtered connections.
    pub filtered: u8,
    /// Of them closed (φ = 0).
    pub closed: u8,
    /// Of them throttled (φ ≥ 2).
    pub throttled: u8,
}

/// The filters of a node at run time, one per filtered connection of its table, and which
/// profile they were last switched to.
///
/// Memory: 3 bytes per filter of capacity and 2 more.
#[derive(Clone, Debug, Default)]
pub struct Throttles {
    throttles: Vec<Throttle, MAX_FILTERED>,
    /// The profile last switched to, or `None` once [`Throttles::set`] changed a filter.
    profile: Option<u8>,
}

impl Throttles {
    /// Every filter of `filters` closed: profile 0.
    pub fn new(filters: &MessageFilters) -> Throttles {
        let mut throttles = Vec::new();
        for _ in filters.connections.iter() {
            // Same capacity as the list iterated.
            let _ = throttles.push(Throttle::new(0));
        }
        Throttles {
            throttles,
            profile: Some(0),
        }
    }

    /// The filter at `position` among the node's filtered connections.
    pub fn get(&self, position: usize) -> Option<&Throttle> {
        self.throttles.get(position)
    }

    /// Offers a frame to the filter at `position`: whether it passes (`true` for a position
    /// the node has no filter at).
    #[inline(never)]
    pub fn pass(&mut self, position: u8) -> bool {
        self.throttles
            .get_mut(usize::from(position))
            .is_none_or(|t| t.pass())
    }

    /// Whether the last frame offered to the filter at `position` passed (`true` where none).
    pub fn last_passed(&self, position: u8) -> bool {
        self.throttles
            .get(usize::from(position))
            .is_none_or(|t| t.last_passed())
    }

    /// Switches every filter to `profile` of `filters` (the table these throttles were made
    /// from). A filter whose φ does not change keeps its count.
    pub fn set_profile(
        &mut self,
        filters: &MessageFilters,
        profile: u8,
    ) -> Result<(), CommandError> {
        if self.throttles.is_empty() {
            return Err(CommandError::NoFilters);
        }
        if usize::from(profile) > filters.profiles.len() {
            return Err(CommandError::NoSuchProfile);
        }
        for (position, throttle) in self.throttles.iter_mut().enumerate() {
            throttle.set(filters.phi(profile, position).unwrap_or(0));
        }
        self.profile = Some(profile);
        Ok(())
    }

    /// Sets the filter at `position` to φ = `phi`.
    pub fn set(&mut self, position: Option<usize>, phi: u8) -> Result<(), CommandError> {
        if self.throttles.is_empty() {
            return Err(CommandError::NoFilters);
        }
        let throttle = position
            .and_then(|p| self.throttles.get_mut(p))
            .ok_or(CommandError::NotFiltered)?;
        if throttle.phi() != phi {
            self.profile = None;
        }
        throttle.set(phi);
        Ok(())
    }

    /// Takes over `throttle` (an unchanged connection's filter in the table replaced) at
    /// `position`; nothing where there is no filter.
    pub fn carry(&mut self, position: u8, throttle: Throttle) {
        if let Some(slot) = self.throttles.get_mut(usize::from(position)) {
            *slot = throttle;
        }
    }

    /// After [`Throttles::carry`]: the profile of the replaced table still holds if the filters'
    /// part is the same (`same`); otherwise the filters are profile 0 only if all are closed.
    pub fn settle(&mut self, previous: Option<u8>, same: bool) {
        self.profile = if same {
            previous
        } else if self.throttles.iter().all(|t| t.phi() == 0) {
            Some(0)
        } else {
            None
        };
    }

    /// The profile last switched to, or `None` once a single filter changed since.
    pub fn profile(&self) -> Option<u8> {
        self.profile
    }

    /// The counts of a `FilterStatus` frame.
    pub fn counts(&self) -> FilterCounts {
        let mut counts = FilterCounts {
            filtered: self.throttles.len() as u8,
            ..FilterCounts::default()
        };
        for throttle in &self.throttles {
            match throttle.phi() {
                0 => counts.closed += 1,
                1 => {}
                _ => counts.throttled += 1,
            }
        }
        counts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn passed(throttle: &mut Throttle, frames: usize) -> std::vec::Vec<usize> {
        (0..frames).filter(|_| throttle.pass()).collect()
    }

    #[test]
    fn phi_three_passes_frames_0_3_6() {
        assert_eq!(passed(&mut Throttle::new(3), 10), [0, 3, 6, 9]);
        assert_eq!(passed(&mut Throttle::new(1), 4), [0, 1, 2, 3]);
        assert_eq!(passed(&mut Throttle::new(0), 4), [] as [usize; 0]);
        assert_eq!(passed(&mut Throttle::new(255), 600), [0, 255, 510]);
    }

    #[test]
    fn the_first_frame_after_a_change_passes() {
        let mut t = Throttle::new(3);
        assert_eq!(passed(&mut t, 2), [0]);
        t.set(4);
        assert_eq!(passed(&mut t, 5), [0, 4]);
        // The same φ again is no change: the count goes on.
        t.set(4);
        assert_eq!(passed(&mut t, 4), [3]);
        t.set(0);
        assert_eq!(passed(&mut t, 3), [] as [usize; 0]);
        t.set(2);
        assert_eq!(passed(&mut t, 3), [0, 2]);
    }

    fn filters() -> MessageFilters {
        let mut f = MessageFilters::default();
        f.connections.extend_from_slice(&[1, 4, 5]).unwrap();
        let mut one = Vec::new();
        one.extend_from_slice(&[1, 3, 0]).unwrap();
        let mut two = Vec::new();
        two.extend_from_slice(&[0, 1, 1]).unwrap();
        f.profiles.push(one).unwrap();
        f.profiles.push(two).unwrap();
        f
    }

    #[test]
    fn profiles_switch_every_filter_and_zero_closes_all() {
        let f = filters();
        assert_eq!(f.validate(6), Ok(()));
        let mut t = Throttles::new(&f);
        assert_eq!(t.profile(), Some(0));
        let closed = FilterCounts {
            filtered: 3,
            closed: 3,
            throttled: 0,
        };
        assert_eq!(t.counts(), closed);
        assert!(!t.pass(0) && !t.pass(1) && !t.pass(2));
        // No filter at that position: passes.
        assert!(t.pass(3) && t.pass(UNFILTERED));
        t.set_profile(&f, 1).unwrap();
        assert_eq!(
            t.counts(),
            FilterCounts {
                filtered: 3,
                closed: 1,
                throttled: 1
            }
        );
        assert_eq!(
            (t.pass(0), t.pass(1), t.pass(1), t.pass(2)),
            (true, true, false, false)
        );
        assert_eq!(t.set_profile(&f, 3), Err(CommandError::NoSuchProfile));
        assert_eq!(t.profile(), Some(1));
        t.set_profile(&f, 0).unwrap();
        assert_eq!(t.counts(), closed);
    }

    #[test]
    fn single_filters_leave_the_profile() {
        let f = filters();
        let mut t = Throttles::new(&f);
        t.set_profile(&f, 2).unwrap();
        // Setting a filter to the φ it has keeps the profile.
        t.set(Some(1), 1).unwrap();
        assert_eq!(t.profile(), Some(2));
        t.set(Some(1), 5).unwrap();
        assert_eq!(t.profile(), None);
        assert_eq!(t.get(1).map(Throttle::phi), Some(5));
        assert_eq!(t.set(None, 1), Err(CommandError::NotFiltered));
        assert_eq!(t.set(Some(3), 1), Err(CommandError::NotFiltered));
        let mut none = Throttles::new(&MessageFilters::default());
        assert_eq!(none.set(Some(0), 1), Err(CommandError::NoFilters));
        assert_eq!(
            none.set_profile(&MessageFilters::default(), 0),
            Err(CommandError::NoFilters)
        );
    }

    #[test]
    fn the_loader_refuses_what_cannot_be() {
        let mut f = filters();
        assert_eq!(f.validate(5), Err(FiltersError::Connection { position: 2 }));
        f.connections.swap(0, 1);
        assert_eq!(f.validate(6), Err(FiltersError::Connection { position: 1 }));
        let mut f = filters();
        f.profiles[1].pop();
        assert_eq!(
            f.validate(6),
            Err(FiltersError::ProfileLength { profile: 2 })
        );
        let mut f = filters();
        f.connections[1] = 1;
        assert_eq!(f.validate(6), Err(FiltersError::Connection { position: 1 }));
    }
}
