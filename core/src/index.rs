//! Which connections a frame feeds, found without testing every connection's filter.
//!
//! Built when a table is loaded. The filters that match exactly one identifier (nearly all of
//! them: a topic is one CAN identifier) are hashed by identifier into buckets (as many as there
//! are such filters, rounded to a power of two, multiplicative hashing, which spreads the runs of
//! consecutive identifiers that networks use); the filters that match a range (a mask) are few and
//! tested one by one. A frame then costs a multiplication, two loads and a comparison per filter
//! in its bucket (about one), plus a test per masked filter, instead of a test per connection of
//! the node. The connections come out in table order, so the arbiter meets them port after port,
//! as a scan of the table would.

use embedded_can::Id;
use heapless::Vec;

use crate::filter;
use crate::table::Connection;

/// Knuth's multiplicative hash constant, 2^32 / φ: consecutive keys land far apart.
const GOLDEN: u32 = 0x9E37_79B1;

/// A node's filters, indexed. `C` is the capacity in connections. Memory: 6 bytes per exact
/// filter, 2 per masked one, 4 per bucket (at most `C`).
#[derive(Clone, Debug)]
pub(crate) struct FilterIndex<const C: usize> {
    /// Each bucket's entries in `keys`: start in the low half, end in the high half. A power of
    /// two of buckets, or none when there are no exact filters.
    buckets: Vec<u32, C>,
    /// `32 − log2(number of buckets)`: a key's bucket is the top bits of `key · GOLDEN`.
    shift: u32,
    /// The exact filters' keys ([`filter::key_of`]), bucket after bucket; within a bucket by key,
    /// equal keys in table order.
    keys: Vec<u32, C>,
    /// The connection (index in the table) of each key, with [`MORE`] set when the next entry
    /// has the same key.
    connections: Vec<u16, C>,
    /// Connections with a masked filter, in table order.
    masked: Vec<u16, C>,
}

/// Where a frame's search stands: the next of its exact entries ([`NO_MORE`] when there are no
/// others: equal keys are consecutive and flagged with [`MORE`]), and the next masked filter to
/// test. Made by [`FilterIndex::cursor`], advanced by
/// [`FilterIndex::next`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cursor {
    next: u16,
    masked: u16,
}

/// What [`FilterIndex::find`] found: the position of the frame's first exact entry, if any.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Found {
    position: Option<u16>,
}

/// In an entry of `FilterIndex::connections`: the next entry has the same key (another
/// connection fed by the same identifier). Connections are numbered below 2^15.
const MORE: u16 = 1 << 15;

/// `Cursor::next` when the frame's exact entries are exhausted.
const NO_MORE: u16 = u16::MAX;

/// The bucket of `key` among `2^(32 − shift)`.
fn bucket(key: u32, shift: u32) -> usize {
    key.wrapping_mul(GOLDEN).checked_shr(shift).unwrap_or(0) as usize
}

impl<const C: usize> FilterIndex<C> {
    /// The index of `connections` (a table's, in table order). `None` if there are more than `C`
    /// of them, or more than 2^16. Costs a sort of the exact filters.
    pub(crate) fn new(connections: &[Connection]) -> Option<Self> {
        // Positions are u16 (below 2^15 in `connections`, which keeps a flag in the top bit),
        // and so is the cursor over the masked filters.
        if connections.len() >= usize::from(MORE) {
            return None;
        }
        let mut exact: Vec<(u32, u16), C> = Vec::new();
        let mut masked: Vec<u16, C> = Vec::new();
        for (position, connection) in connections.iter().enumerate() {
            let position = u16::try_from(position).ok()?;
            match connection.filter.exact_key() {
                Some(key) => exact.push((key, position)).ok()?,
                None => masked.push(position).ok()?,
            }
        }
        // About one exact filter per bucket: a power of two of buckets, at least half as many as
        // filters, at most `C`.
        let mut count = 1usize;
        while count < exact.len() && count.saturating_mul(2) <= C {
            count = count.saturating_mul(2);
        }
        let shift = 32u32.saturating_sub(count.trailing_zeros());
        // An insertion sort: a table is indexed once, when it is loaded (at most n²/2 moves, a
        // fraction of a millisecond at the board's 64 connections), and it costs a hundred bytes
        // of flash where the library's sort costs kilobytes.
        let order = |&(key, connection): &(u32, u16)| (bucket(key, shift), key, connection);
        for sorted in 1..exact.len() {
            let mut at = sorted;
            while at > 0 {
                let (Some(before), Some(this)) = (exact.get(at - 1), exact.get(at)) else {
                    break;
                };
                if order(before) <= order(this) {
                    break;
                }
                exact.swap(at - 1, at);
                at -= 1;
            }
        }
        let mut index = FilterIndex {
            buckets: Vec::new(),
            shift,
            keys: Vec::new(),
            connections: Vec::new(),
            masked,
        };
        if exact.is_empty() {
            return Some(index);
        }
        let mut start = 0usize;
        for b in 0..count {
            let mut end = start;
            while exact
                .get(end)
                .is_some_and(|&(key, _)| bucket(key, shift) == b)
            {
                end = end.saturating_add(1);
            }
            let bounds =
                u32::from(u16::try_from(start).ok()?) | u32::from(u16::try_from(end).ok()?) << 16;
            index.buckets.push(bounds).ok()?;
            start = end;
        }
        let mut entries = exact.iter().peekable();
        while let Some(&(key, connection)) = entries.next() {
            let more = entries.peek().is_some_and(|&&(next, _)| next == key);
            index.keys.push(key).ok()?;
            index
                .connections
                .push(if more { connection | MORE } else { connection })
                .ok()?;
        }
        Some(index)
    }

    /// The first exact entry of a frame with identifier `id`: the hash, then a comparison per
    /// filter of its bucket up to the frame's key.
    #[inline(always)]
    pub(crate) fn find(&self, id: &Id) -> Found {
        let key = filter::key_of(id);
        let bounds = self
            .buckets
            .get(bucket(key, self.shift))
            .copied()
            .unwrap_or(0);
        let (mut next, end) = (bounds as u16, (bounds >> 16) as u16);
        // Within the bucket, keys are sorted.
        while next < end {
            match self.keys.get(usize::from(next)) {
                Some(&k) if k < key => next = next.wrapping_add(1),
                Some(&k) if k == key => {
                    return Found {
                        position: Some(next),
                    };
                }
                _ => break,
            }
        }
        Found { position: None }
    }

    /// Whether a frame whose search gave `found` may feed a connection: it has an exact entry,
    /// or there are masked filters to test.
    #[inline(always)]
    pub(crate) fn may_feed(&self, found: &Found) -> bool {
        found.position.is_some() || !self.masked.is_empty()
    }

    /// Starts the iteration over the connections of what [`FilterIndex::find`] found: the
    /// cursor, and the first connection (without masked filters, the exact entry found).
    #[inline(always)]
    pub(crate) fn first(
        &self,
        found: Found,
        id: &Id,
        connections: &[Connection],
    ) -> (Cursor, Option<usize>) {
        let mut cursor = Cursor {
            next: found.position.unwrap_or(NO_MORE),
            masked: 0,
        };
        let first = self.next(&mut cursor, id, connections);
        (cursor, first)
    }

    /// The next connection (index in the table) the frame of `cursor` (identifier `id`) feeds,
    /// in table order; `connections` are the table's, for the masked filters. Costs a comparison,
    /// and a test per masked filter it passes.
    #[inline]
    pub(crate) fn next(
        &self,
        cursor: &mut Cursor,
        id: &Id,
        connections: &[Connection],
    ) -> Option<usize> {
        // NO_MORE is beyond any entry (there are fewer than 2^15).
        let entry = self.connections.get(usize::from(cursor.next)).copied();
        let exact = entry.map(|entry| entry & !MORE);
        if usize::from(cursor.masked) < self.masked.len()
            && let Some(connection) = self.next_masked(cursor, exact, id, connections)
        {
            return Some(connection);
        }
        let entry = entry?;
        cursor.next = if entry & MORE != 0 {
            cursor.next.wrapping_add(1)
        } else {
            NO_MORE
        };
        Some(usize::from(entry & !MORE))
    }

    /// The next masked filter that matches, if it comes before the next exact match `exact`.
    #[inline(never)]
    fn next_masked(
        &self,
        cursor: &mut Cursor,
        exact: Option<u16>,
        id: &Id,
        connections: &[Connection],
    ) -> Option<usize> {
        while let Some(&connection) = self.masked.get(usize::from(cursor.masked)) {
            if exact.is_some_and(|exact| exact < connection) {
                break;
            }
            cursor.masked = cursor.masked.wrapping_add(1);
            let matches = connections
                .get(usize::from(connection))
                .is_some_and(|c| c.filter.matches(id));
            if matches {
                return Some(usize::from(connection));
            }
        }
        None
    }
}
