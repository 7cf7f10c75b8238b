//! Which connections a frame feeds, found without testing every connection's filter.
//!
//! Built when a table is loaded. The filters that match exactly one identifier (nearly all of
//! them: a topic is one CAN identifier) are hashed by identifier into buckets (as many as the
//! capacity allows, a power of two; multiplicative hashing, with the multiplier that separates
//! the table's identifiers best among a few, so that a bucket rarely holds two); the filters that
//! match a range (a mask) are few and tested one by one.
//!
//! Each bucket keeps its first identifier beside what a frame with it feeds, so that the common
//! frame costs a multiplication, one load of two words and a comparison: when the identifier is
//! the only one of its bucket and feeds exactly one connection (and the node has no masked
//! filter), the bucket names that connection; when the frame's identifier is not the bucket's
//! and the bucket holds no other, the frame feeds nothing. Everything else (several identifiers
//! in a bucket, an identifier that feeds several connections, masked filters) goes through the
//! bucket's sorted run of identifiers and a cursor, which yields the connections in table order,
//! so that the arbiter meets them port after port, as a scan of the table would.

use embedded_can::Id;
use heapless::Vec;

use crate::filter;
use crate::table::Connection;

/// The multipliers tried, odd constants with well-mixed bits (Knuth's 2^32 / φ first, then
/// MurmurHash3's and xxHash's): the first that leaves the fewest identifiers sharing a bucket is
/// kept.
const MULTIPLIERS: [u32; 8] = [
    0x9E37_79B1,
    0x85EB_CA6B,
    0xC2B2_AE35,
    0x27D4_EB2F,
    0x1656_67B1,
    0xCC9E_2D51,
    0x1B87_3593,
    0x2545_F491,
];

/// A node's filters, indexed. `C` is the capacity in connections. Memory: 6 bytes per exact
/// filter, 2 per masked one, 8 per bucket (at most `C`).
#[derive(Clone, Debug)]
pub(crate) struct FilterIndex<const C: usize> {
    /// Per bucket, its first identifier's key ([`EMPTY`] if it has none) and a word. Bits 0–14:
    /// where its run starts in `keys` and `connections`. Bit 15 ([`ALONE`]): a frame whose key
    /// is not the bucket's first feeds nothing. Bit 31 ([`ONE`]): a frame with the bucket's
    /// first key feeds exactly one connection, whose index is in bits 16–30 (the run is then
    /// that one entry); without it, bits 16–30 are where the run ends. A power of two of
    /// buckets, the largest that `C` allows (none when `C` is 0).
    buckets: Vec<(u32, u32), C>,
    /// The hash's multiplier: a key's bucket is the top bits of `key · multiplier`.
    multiplier: u32,
    /// The exact filters' keys ([`filter::key_of`]), bucket after bucket; within a bucket by key,
    /// equal keys in table order.
    keys: Vec<u32, C>,
    /// The connection (index in the table) of each key, with [`MORE`] set when the next entry
    /// has the same key.
    connections: Vec<u16, C>,
    /// Connections with a masked filter, in table order.
    masked: Vec<u16, C>,
}

/// The key of an empty bucket: no frame has it ([`filter::key_of`] is at most `0x9FFF_FFFF`).
const EMPTY: u32 = u32::MAX;

/// In a bucket's word: the bucket holds at most one key and the node has no masked filter.
const ALONE: u32 = 1 << 15;
/// In a bucket's word: its first key feeds one connection, named in bits 16–30.
const ONE: u32 = 1 << 31;
/// Positions and connections in a bucket's word: 15 bits.
const FIELD: u32 = 0x7FFF;

/// Where a frame's search stands: the next of its exact entries ([`NO_MORE`] when there are no
/// others: equal keys are consecutive and flagged with [`MORE`]), and the next masked filter to
/// test. Made by [`FilterIndex::cursor`], advanced by [`FilterIndex::next`].
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

/// What [`FilterIndex::lookup`] found for a frame.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Lookup {
    /// No connection.
    Nothing,
    /// This connection (index in the table) and no other.
    One(usize),
    /// Maybe several: search with [`FilterIndex::find`] and iterate.
    Several,
}

/// In an entry of `FilterIndex::connections`: the next entry has the same key (another
/// connection fed by the same identifier). Connections are numbered below 2^15.
const MORE: u16 = 1 << 15;

/// `Cursor::next` when the frame's exact entries are exhausted.
const NO_MORE: u16 = u16::MAX;

/// Sorts the exact filters by bucket (of `count`, under `multiplier`), then key, equal keys in
/// table order (the order they come in: the sort is stable). An insertion sort: a table is
/// indexed once, when it is loaded (at most n²/2 moves, a fraction of a millisecond at the
/// board's 64 connections), and it costs a hundred bytes of flash where the library's sort costs
/// kilobytes.
fn sort(exact: &mut [(u32, u16)], multiplier: u32, count: usize) {
    let order = |&(key, _): &(u32, u16)| (bucket(key, multiplier, count), key);
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
}

/// The bucket of `key` among `count` (a power of two): the top bits of `key · multiplier`,
/// as one 32 × 32 → 64-bit multiplication (`count` = 1 gives 0).
#[inline(always)]
fn bucket(key: u32, multiplier: u32, count: usize) -> usize {
    ((u64::from(key.wrapping_mul(multiplier)) * count as u64) >> 32) as usize
}

impl<const C: usize> FilterIndex<C> {
    /// The index of no connection, in an arbiter being built until [`FilterIndex::build`]
    /// fills it.
    pub(crate) const fn empty() -> Self {
        FilterIndex {
            buckets: Vec::new(),
            multiplier: MULTIPLIERS[0],
            keys: Vec::new(),
            connections: Vec::new(),
            masked: Vec::new(),
        }
    }

    /// The index of `connections` (a table's, in table order): [`FilterIndex::build`] into an
    /// empty index.
    #[cfg(test)]
    pub(crate) fn new(connections: &[Connection]) -> Option<Self> {
        let mut index = Self::empty();
        index.build(connections)?;
        Some(index)
    }

    /// Indexes `connections` (a table's, in table order) into `self`, an empty index
    /// ([`FilterIndex::empty`]), where it lives: built apart and returned, the index was moved
    /// into the arbiter (72 bytes of the NUCLEO-G474RE's flash). `None` if there are more than `C` of them, or more than 2^15 (`self` is
    /// then left part-built). Costs, per multiplier tried, a pass over the exact filters (each
    /// compared with those before it) and one over the buckets, then a sort of the exact filters.
    // Out of line: inlined into the loader (and so into the node's loader, whose frame holds a
    // table and an arbiter), each of its locals was reached through a large stack offset, which
    // took 116 bytes more of the NUCLEO-G474RE's flash. Run once per table.
    #[inline(never)]
    pub(crate) fn build(&mut self, connections: &[Connection]) -> Option<()> {
        // Positions are u16 (below 2^15 in `connections`, which keeps a flag in the top bit),
        // and so is the cursor over the masked filters.
        if connections.len() >= usize::from(MORE) {
            return None;
        }
        let mut exact: Vec<(u32, u16), C> = Vec::new();
        for (position, connection) in connections.iter().enumerate() {
            let position = u16::try_from(position).ok()?;
            match connection.filter.exact_key() {
                Some(key) => exact.push((key, position)).ok()?,
                None => self.masked.push(position).ok()?,
            }
        }
        // As many buckets as the capacity allows (a power of two): they cost memory the
        // capacity reserves anyway, and the emptier the buckets, the more frames are answered by
        // one comparison.
        let count = C.checked_ilog2().map_or(0, |log| 1 << log);
        // The multiplier: the first that leaves the fewest keys sharing a bucket with another
        // (counted in `self.buckets`, used as scratch: how many keys each bucket holds).
        let buckets = &mut self.buckets;
        let mut best = (usize::MAX, MULTIPLIERS[0]);
        for multiplier in MULTIPLIERS {
            buckets.clear();
            buckets.resize(count, (EMPTY, 0)).ok()?;
            for (position, &(key, _)) in exact.iter().enumerate() {
                // A key counts once, at its first filter. Found by comparing with the filters
                // before it rather than after a sort by key, whose inlined copy took 140 bytes
                // of the NUCLEO-G474RE's flash: a table is indexed once, when it is loaded (at
                // most 2 016 comparisons per multiplier at the board's 64 connections).
                let before = exact.get(..position).unwrap_or(&[]);
                if before.iter().any(|&(other, _)| other == key) {
                    continue;
                }
                if let Some(entry) = buckets.get_mut(bucket(key, multiplier, count)) {
                    // At most `C` keys in a bucket: no overflow.
                    entry.1 = entry.1.wrapping_add(1);
                }
            }
            let shared: usize = buckets
                .iter()
                .filter(|&&(_, keys)| keys > 1)
                .map(|&(_, keys)| keys as usize)
                .sum();
            if shared < best.0 {
                best = (shared, multiplier);
            }
            if shared == 0 {
                break;
            }
        }
        let multiplier = best.1;
        sort(&mut exact, multiplier, count);
        self.multiplier = multiplier;
        let mut entries = exact.iter().peekable();
        while let Some(&(key, connection)) = entries.next() {
            let more = entries.peek().is_some_and(|&&(next, _)| next == key);
            self.keys.push(key).ok()?;
            self.connections
                .push(if more { connection | MORE } else { connection })
                .ok()?;
        }
        let no_masked = self.masked.is_empty();
        let mut start = 0usize;
        // Every bucket is rewritten: the search left `count` of them.
        for (b, entry) in self.buckets.iter_mut().enumerate() {
            let mut end = start;
            while exact
                .get(end)
                .is_some_and(|&(key, _)| bucket(key, multiplier, count) == b)
            {
                // Below `exact.len()`: no overflow.
                end = end.wrapping_add(1);
            }
            let first = exact.get(start).map_or(EMPTY, |&(key, _)| key);
            let with_first = exact.get(start..end).map_or(0, |run| {
                run.iter().filter(|&&(key, _)| key == first).count()
            });
            // Positions are below 2^15 (checked above): the casts keep them whole.
            let (start_field, end_field) = (start as u32, end as u32);
            // The bucket holds no key but its first (`end` is not below `start`).
            let alone = end.wrapping_sub(start) == with_first;
            let mut word = start_field;
            if alone && no_masked {
                word |= ALONE;
            }
            match exact.get(start) {
                Some(&(_, connection)) if alone && with_first == 1 && no_masked => {
                    word |= ONE | u32::from(connection) << 16;
                }
                _ => word |= end_field << 16,
            }
            *entry = (first, word);
            start = end;
        }
        Some(())
    }

    /// What a frame with identifier `id` feeds, as far as its bucket tells: nothing, exactly one
    /// connection, or possibly several (then [`FilterIndex::find`] and iterate). A
    /// multiplication, a load of the bucket's two words and a comparison.
    #[inline(always)]
    pub(crate) fn lookup(&self, id: &Id) -> Lookup {
        let key = filter::key_of(id);
        let Some(&(first, word)) =
            self.buckets
                .get(bucket(key, self.multiplier, self.buckets.len()))
        else {
            // No bucket: a capacity of 0 connections.
            return Lookup::Several;
        };
        if key == first {
            if word & ONE != 0 {
                return Lookup::One(((word >> 16) & FIELD) as usize);
            }
        } else if word & ALONE != 0 {
            return Lookup::Nothing;
        }
        Lookup::Several
    }

    /// The first exact entry of a frame with identifier `id`: the hash, then a comparison per
    /// key of its bucket up to the frame's key.
    pub(crate) fn find(&self, id: &Id) -> Found {
        let key = filter::key_of(id);
        let word = self
            .buckets
            .get(bucket(key, self.multiplier, self.buckets.len()))
            .map_or(0, |&(_, word)| word);
        let mut next = (word & FIELD) as u16;
        let end = if word & ONE != 0 {
            next.saturating_add(1)
        } else {
            ((word >> 16) & FIELD) as u16
        };
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

    /// The cursor of an iteration over the connections of what [`FilterIndex::find`] found:
    /// [`FilterIndex::next`] yields the first of them (without masked filters, the exact entry
    /// found).
    #[inline(always)]
    pub(crate) fn cursor(&self, found: Found) -> Cursor {
        Cursor {
            next: found.position.unwrap_or(NO_MORE),
            masked: 0,
        }
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
    // Left to the inliner (one caller): out of line it took 64 bytes more of the
    // NUCLEO-G474RE's flash, 68 of the emulated board's; the counted frames, masked filters
    // included (scripts/cortex-m4-cost.sh), cost the same either way.
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::Filter;
    use crate::integrator::Stimulation;
    use crate::level::Gain;
    use embedded_can::{ExtendedId, StandardId};

    /// Every connection a frame feeds, as the index yields them: the bucket's answer, or the
    /// search and the cursor.
    fn fed<const C: usize>(
        index: &FilterIndex<C>,
        connections: &[Connection],
        id: &Id,
    ) -> std::vec::Vec<usize> {
        match index.lookup(id) {
            Lookup::Nothing => std::vec::Vec::new(),
            Lookup::One(connection) => std::vec![connection],
            Lookup::Several => {
                let mut cursor = index.cursor(index.find(id));
                let mut all = std::vec::Vec::new();
                while let Some(connection) = index.next(&mut cursor, id, connections) {
                    all.push(connection);
                }
                all
            }
        }
    }

    fn check<const C: usize>(seed: u64, masked_percent: u64) {
        let mut state = seed | 1;
        let mut random = move |n: u64| {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            state.wrapping_mul(0x2545_F491_4F6C_DD1D) % n
        };
        let stimulation = Stimulation::new(Gain::ONE, 1_000, 0).unwrap();
        // Identifiers from a pool larger than the buckets of small capacities, so that buckets
        // are shared; each both standard and extended.
        let pool: std::vec::Vec<u32> = (0..40).map(|k| 0x100 + k * 3).collect();
        let count = random(C as u64 + 1) as usize;
        let connections: std::vec::Vec<Connection> = (0..count)
            .map(|_| {
                let raw = pool[random(pool.len() as u64) as usize];
                let extended = random(5) == 0;
                let filter = if random(100) < masked_percent {
                    let width = if extended { 0x1FFF_FFFF } else { 0x7FF };
                    let mask = width & !((1u32 << random(6)) - 1);
                    Filter::new(raw & mask, mask, extended).unwrap()
                } else {
                    Filter::exact(raw, extended).unwrap()
                };
                Connection {
                    filter,
                    stimulation,
                }
            })
            .collect();
        let index = FilterIndex::<C>::new(&connections).unwrap();
        for &raw in pool.iter().chain(&[0x000, 0x7FF]) {
            for id in [
                Id::Standard(StandardId::new(raw as u16).unwrap()),
                Id::Extended(ExtendedId::new(raw).unwrap()),
            ] {
                let expected: std::vec::Vec<usize> = connections
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| c.filter.matches(&id))
                    .map(|(k, _)| k)
                    .collect();
                assert_eq!(
                    fed(&index, &connections, &id),
                    expected,
                    "seed {seed}, {id:?}"
                );
            }
        }
    }

    #[test]
    fn yields_the_connections_a_scan_finds_in_table_order() {
        for seed in 0..300 {
            for masked in [0, 20] {
                check::<1>(seed, masked);
                check::<3>(seed, masked);
                check::<8>(seed, masked);
                check::<64>(seed, masked);
                check::<512>(seed, masked);
            }
        }
    }

    #[test]
    fn a_lone_identifier_is_answered_by_its_bucket() {
        // The Take and Return topics of one node: each alone in its bucket, one connection each.
        let stimulation = Stimulation::new(Gain::ONE, 1_000, 0).unwrap();
        let ids = [0x110, 0x111, 0x112, 0x113, 0x120, 0x121, 0x122, 0x130];
        let connections: std::vec::Vec<Connection> = ids
            .iter()
            .map(|&raw| Connection {
                filter: Filter::exact(raw, false).unwrap(),
                stimulation,
            })
            .collect();
        let index = FilterIndex::<64>::new(&connections).unwrap();
        for (k, &raw) in ids.iter().enumerate() {
            let id = Id::Standard(StandardId::new(raw as u16).unwrap());
            assert!(
                matches!(index.lookup(&id), Lookup::One(c) if c == k),
                "{raw:#x}"
            );
        }
        let other = Id::Standard(StandardId::new(0x200).unwrap());
        assert!(matches!(index.lookup(&other), Lookup::Nothing));
    }
}
