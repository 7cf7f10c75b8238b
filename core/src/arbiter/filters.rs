//! HBBA's message filters in the arbiter: the intention's commands, and what the node reports of
//! them. A frame's pass through a filter is on the frame's path ([`Arbiter::receive`]).

use super::Arbiter;
use crate::hbba::filters::{CommandError, FilterCounts, UNFILTERED};

impl<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>
    Arbiter<PORTS, CONNECTIONS, NODES>
{
    /// Switches every HBBA filter to profile `profile` of the table (0: all closed, as after
    /// [`Arbiter::new`]). Fails, changing nothing, with [`CommandError::NoFilters`] on a table
    /// without filters and [`CommandError::NoSuchProfile`]. Costs one pass over the filters.
    pub fn set_filter_profile(&mut self, profile: u8) -> Result<(), CommandError> {
        // Without the feature no table has filters: the rest is left out of the build.
        if !cfg!(feature = "filters") {
            return Err(CommandError::NoFilters);
        }
        self.throttles.set_profile(self.table.filters(), profile)
    }

    /// Sets the HBBA filter of connection `connection` of port `port` to φ = `phi` (0 closes, 1
    /// passes every frame, N one in N; the next frame passes unless φ = 0). Fails, changing
    /// nothing, with [`CommandError::NoFilters`] on a table without filters and
    /// [`CommandError::NotFiltered`] for a connection without a filter.
    pub fn set_filter(&mut self, port: u8, connection: u8, phi: u8) -> Result<(), CommandError> {
        if !cfg!(feature = "filters") {
            return Err(CommandError::NoFilters);
        }
        let position = self
            .slot_of(port, connection)
            .map(|slot| slot.filter)
            .filter(|&f| f != UNFILTERED)
            .map(usize::from);
        self.throttles.set(position, phi)
    }

    /// φ of the HBBA filter of connection `connection` of port `port`, or `None` if it has none.
    pub fn filter_phi(&self, port: u8, connection: u8) -> Option<u8> {
        let slot = self.slot_of(port, connection)?;
        self.throttles
            .get(usize::from(slot.filter))
            .map(|t| t.phi())
    }

    /// The HBBA filter profile last switched to, or `None` once a single filter changed since.
    pub fn filter_profile(&self) -> Option<u8> {
        self.throttles.profile()
    }

    /// How many connections have a filter, and how many of them are closed or throttled.
    pub fn filter_counts(&self) -> FilterCounts {
        self.throttles.counts()
    }

    /// Whether the table gives some connection an HBBA filter. Always false without the feature
    /// `filters` (whose loader refuses a table with filters): the node's filter commands and
    /// reports, behind this test, are then left out of the build.
    #[inline]
    pub fn has_filters(&self) -> bool {
        cfg!(feature = "filters") && !self.table.filters().is_empty()
    }
}
