//! [`BootCounter`]: a count of boots in its own flash pages that never returns a value twice,
//! whatever power cuts happen.
//!
//! A keyed node's challenges start with a *boot salt* that must never repeat for one key
//! (docs/can-protocol.md, "Authenticated configuration"): a board takes it from
//! [`BootCounter::increment`], called once per boot.
//!
//! ## The guarantee
//!
//! - `increment` returns `Ok(n)` only after a record of `n` is in flash and reads back; every
//!   later `increment` (after any number of power cuts, at any point of any call) returns a
//!   larger value. So no value is ever returned twice, and the count never goes backwards.
//! - A cut `increment` returns an error (the board then fails closed: it takes no
//!   configuration, see the boards' `main.rs`) and the value it was writing may or may not count;
//!   either way the next `increment` returns something larger than everything returned before.
//! - After `u32::MAX` boots, or when the pages hold a record of `u32::MAX` (planted, or garbage
//!   that happens to verify, a chance of about 2^-96), `increment` answers
//!   [`CounterError::Exhausted`] for good: [`BootCounter::format`] starts again at 1, which
//!   repeats salts, so do that only together with a new key.
//! - Whatever the pages hold (erased, garbage, another program's data, a zeroed RAM), it answers
//!   with a value or a typed [`CounterError`]; nothing panics (no indexing, no unwrapping, no
//!   division: the crate's lints).
//!
//! ## Layout and algorithm
//!
//! The range given to [`BootCounter::new`] is P ≥ 2 erase pages. Each page holds records, one
//! after another from its start, each [`RECORD_LEN`] bytes (rounded up to the flash's write
//! size): magic `PABB`, count (u32 LE), the count's bitwise complement (u32 LE), CRC-32 of the
//! 12 bytes before it. The count is the largest count of a record that verifies (0 if none).
//!
//! `increment`:
//!
//! 1. Reads every record of every page: the largest count M, the page that holds it, and that
//!    page's last record that is not erased (not all 0xFF: a valid record, or one that a cut
//!    left half programmed).
//! 2. The new count is M + 1 ([`CounterError::Exhausted`] if M is `u32::MAX`).
//! 3. It goes in the record after that last non-erased one, in M's page; if that page is full,
//!    in the first record of the next page in ring order, which is erased first. Nothing found
//!    at all (erased, garbage): the first page is erased and gets the first record, count 1.
//! 4. Reads the record back: it must verify with the new count ([`CounterError::VerifyFailed`]
//!    otherwise).
//!
//! Only the page *after* M's page is ever erased (never M's own: P ≥ 2), and a record is only
//! ever written into erased space, so the record of M survives every cut: the count never goes
//! backwards. A record whose write is cut is skipped unless it verifies. Why the complement:
//! programming NOR flash only clears bits, and a cut program leaves some bits that should have
//! cleared at 1 (a cut erase sets bits to 1). A record that reads as (count | a, !count | b) with
//! stray bits a, b verifies only if count | a = count & !b, that is, only if a and b are empty:
//! a cut record that verifies holds exactly the count it was meant to, never another one. The
//! magic and the CRC keep garbage (another program's data) from passing as a record.
//!
//! ## Cost
//!
//! Per boot: P × (page / record) record reads (on the STM32G474 with two 4 KiB pages and 16-byte
//! records: 512 reads of 16 bytes, 8 KiB, well under a millisecond from memory-mapped flash),
//! one program of one record (two double words on the G4) and its read-back, and on one boot
//! in `page / record` (256 on the G4) one page erase (up to 40 ms on the G4). No RAM beyond a
//! record on the stack.
//!
//! ## Wear
//!
//! Each page is erased once every P × (page / record) boots: on the G474 layout (two 4 KiB
//! pages), once per 512 boots, so the G4's 10 000 guaranteed cycles last 5 million boots.
//!
//! ## NOR flash rules
//!
//! Every record is programmed once into erased words (the G4's rule, enforced by
//! `testing::MemFlash`, behind the `mem-flash` feature). On the G4, reading a word whose program or erase was cut can
//! raise a double-ECC NMI, as for the table store (see the crate documentation): the board's
//! NMI handler must tolerate it inside the counter's pages too.

use core::ops::Range;

use embedded_storage::nor_flash::NorFlash;
use pab_core::crc32::crc32;

use crate::{CounterError, FlashErrorKind, LayoutError};

/// Bytes of a record before rounding up to the flash's write and read sizes: magic, count,
/// complement, CRC-32.
pub const RECORD_LEN: usize = 16;
/// The largest record area: the write (or read) size may round a record up to this.
const MAX_RECORD_AREA: usize = 64;
/// The record's magic bytes ("PAB boot").
const MAGIC: [u8; 4] = *b"PABB";

/// A boot counter in a range of NOR flash pages (see the module documentation for the layout,
/// the algorithm, the guarantee and the cost).
pub struct BootCounter<F: NorFlash> {
    flash: F,
    start: u32,
    pages: u32,
    page_size: u32,
    /// Bytes a record occupies: [`RECORD_LEN`] rounded up to the write and read sizes.
    record: u32,
}

/// Where the largest count was found.
#[derive(Clone, Copy)]
struct Newest {
    count: u32,
    page: u32,
    /// The page's last record that is not erased (at least the newest's own).
    last_used: u32,
}

fn encode(count: u32) -> [u8; RECORD_LEN] {
    let mut out = [0u8; RECORD_LEN];
    let words = [u32::from_le_bytes(MAGIC), count, !count];
    for (bytes, word) in out.chunks_exact_mut(4).zip(words) {
        bytes.copy_from_slice(&word.to_le_bytes());
    }
    let (body, tail) = out.split_at_mut(RECORD_LEN - 4);
    tail.copy_from_slice(&crc32(body).to_le_bytes());
    out
}

/// The count after `count`: what `increment` records.
fn next_count(count: u32, _: u32) -> Option<u32> {
    count.checked_add(1)
}

/// The count of a record that verifies.
fn decode(bytes: &[u8]) -> Option<u32> {
    let mut words = [0u32; RECORD_LEN / 4];
    for (word, chunk) in words
        .iter_mut()
        .zip(bytes.get(..RECORD_LEN)?.chunks_exact(4))
    {
        *word = u32::from_le_bytes(chunk.try_into().ok()?);
    }
    let [magic, count, complement, crc] = words;
    let ok = magic == u32::from_le_bytes(MAGIC)
        && complement == !count
        && crc == crc32(bytes.get(..RECORD_LEN - 4)?);
    ok.then_some(count)
}

impl<F: NorFlash> BootCounter<F> {
    /// A counter in `range` of `flash` (offsets as the driver counts them): at least two whole
    /// erase pages, inside the flash. Touches no flash.
    ///
    /// Fails with [`CounterError::Layout`]: [`LayoutError::RangeNotPageAligned`],
    /// [`LayoutError::RangeOutOfBounds`], [`LayoutError::RangeTooSmall`] (fewer than two pages),
    /// or [`LayoutError::UnsupportedGeometry`] (a write or read size above 64 bytes, or not
    /// dividing the erase size).
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, CounterError> {
        let geometry = CounterError::Layout(LayoutError::UnsupportedGeometry);
        let unit = F::WRITE_SIZE.max(F::READ_SIZE);
        let record = RECORD_LEN.checked_next_multiple_of(unit).ok_or(geometry)?;
        let geometry_ok = F::WRITE_SIZE > 0
            && F::READ_SIZE > 0
            && record <= MAX_RECORD_AREA
            && F::ERASE_SIZE >= record
            && F::ERASE_SIZE.is_multiple_of(F::WRITE_SIZE)
            && F::ERASE_SIZE.is_multiple_of(F::READ_SIZE)
            && F::ERASE_SIZE.is_multiple_of(record);
        if !geometry_ok {
            return Err(geometry);
        }
        let page_size = u32::try_from(F::ERASE_SIZE).map_err(|_| geometry)?;
        let record = u32::try_from(record).map_err(|_| geometry)?;
        let capacity = u32::try_from(flash.capacity()).unwrap_or(u32::MAX);
        if range.start >= range.end || range.end > capacity {
            return Err(CounterError::Layout(LayoutError::RangeOutOfBounds));
        }
        if !range.start.is_multiple_of(page_size) || !range.end.is_multiple_of(page_size) {
            return Err(CounterError::Layout(LayoutError::RangeNotPageAligned));
        }
        let pages = (range.end - range.start) / page_size;
        if pages < 2 {
            return Err(CounterError::Layout(LayoutError::RangeTooSmall));
        }
        Ok(BootCounter {
            flash,
            start: range.start,
            pages,
            page_size,
            record,
        })
    }

    /// Counts this boot: returns the new count, larger than every value any earlier call
    /// returned (see the module documentation). Call it once per boot.
    ///
    /// Fails with [`CounterError::Flash`] (the driver failed, e.g. the power went: the next
    /// boot's call still returns a new value), [`CounterError::VerifyFailed`] (the record does
    /// not read back) or [`CounterError::Exhausted`] (the count is `u32::MAX`).
    pub fn increment(&mut self) -> Result<u32, CounterError> {
        self.advance(next_count, 0)
    }

    /// Records the count `next(current, argument)` returns (the configuration page's way: a
    /// sequence in the high bits, a value in the low ones), with `increment`'s guarantee: it must
    /// be larger than the current count ([`CounterError::Exhausted`] otherwise, or when `next`
    /// returns `None`), and it is returned only once it reads back.
    // A function pointer rather than a closure: the boot count and the configuration page share
    // one copy of this where both are linked.
    pub fn advance(
        &mut self,
        next: fn(u32, u32) -> Option<u32>,
        argument: u32,
    ) -> Result<u32, CounterError> {
        let newest = self.newest()?;
        let current = newest.map_or(0, |newest| newest.count);
        let count = next(current, argument)
            .filter(|&count| count > current)
            .ok_or(CounterError::Exhausted)?;
        let records = self.page_size.checked_div(self.record).ok_or(geometry())?;
        let (page, index) = match newest {
            None => (0, 0),
            Some(newest) => {
                match newest.last_used.checked_add(1) {
                    Some(next) if next < records => (newest.page, next),
                    // Full: the next page in ring order, by comparison rather than `%`.
                    _ => match newest.page.saturating_add(1) {
                        next if next < self.pages => (next, 0),
                        _ => (0, 0),
                    },
                }
            }
        };
        let page_start = self
            .start
            .saturating_add(page.saturating_mul(self.page_size));
        if index == 0 {
            self.flash
                .erase(page_start, page_start.saturating_add(self.page_size))
                .map_err(flash_error::<F>)?;
        }
        let address = page_start.saturating_add(index.saturating_mul(self.record));
        let mut area = [0xFFu8; MAX_RECORD_AREA];
        let area = area.get_mut(..self.record as usize).ok_or(geometry())?;
        area.get_mut(..RECORD_LEN)
            .ok_or(geometry())?
            .copy_from_slice(&encode(count));
        self.flash.write(address, area).map_err(flash_error::<F>)?;
        area.fill(0);
        self.flash.read(address, area).map_err(flash_error::<F>)?;
        if decode(area) != Some(count) {
            return Err(CounterError::VerifyFailed);
        }
        Ok(count)
    }

    /// The count: the largest one recorded, 0 if none (erased or garbage pages). Reads every
    /// record, writes nothing. Fails only if the driver does.
    pub fn current(&mut self) -> Result<u32, CounterError> {
        Ok(self.newest()?.map_or(0, |newest| newest.count))
    }

    /// Erases the counter's pages: the next [`Self::increment`] returns 1. That repeats boot
    /// salts: format only together with a new key (to clear [`CounterError::Exhausted`], or
    /// pages another program used). One erase of P pages.
    pub fn format(&mut self) -> Result<(), CounterError> {
        let end = self
            .start
            .saturating_add(self.pages.saturating_mul(self.page_size));
        self.flash.erase(self.start, end).map_err(flash_error::<F>)
    }

    /// The flash, for inspection (tests, diagnostics). Writing to the counter's pages through it
    /// voids the guarantee.
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back (for the table store, once the boot is counted).
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// The largest count of a record that verifies, with its page and that page's last
    /// non-erased record.
    fn newest(&mut self) -> Result<Option<Newest>, CounterError> {
        let records = self.page_size.checked_div(self.record).ok_or(geometry())?;
        let mut newest: Option<Newest> = None;
        let mut area = [0u8; MAX_RECORD_AREA];
        let area = area.get_mut(..self.record as usize).ok_or(geometry())?;
        for page in 0..self.pages {
            let page_start = self
                .start
                .saturating_add(page.saturating_mul(self.page_size));
            let mut best: Option<u32> = None;
            let mut last_used = 0;
            for index in 0..records {
                let address = page_start.saturating_add(index.saturating_mul(self.record));
                self.flash.read(address, area).map_err(flash_error::<F>)?;
                if area.iter().any(|&byte| byte != 0xFF) {
                    last_used = index;
                }
                if let Some(count) = decode(area) {
                    best = Some(best.map_or(count, |best| best.max(count)));
                }
            }
            if let Some(count) = best
                && newest.is_none_or(|newest| count > newest.count)
            {
                newest = Some(Newest {
                    count,
                    page,
                    last_used,
                });
            }
        }
        Ok(newest)
    }
}

fn geometry() -> CounterError {
    CounterError::Layout(LayoutError::UnsupportedGeometry)
}

fn flash_error<F: NorFlash>(error: F::Error) -> CounterError {
    CounterError::Flash(FlashErrorKind::of(&error))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_erased_or_zeroed_ones_do_not_verify() {
        for count in [0, 1, 0x1234_5678, u32::MAX] {
            assert_eq!(decode(&encode(count)), Some(count));
        }
        assert_eq!(decode(&[0xFF; RECORD_LEN]), None);
        assert_eq!(decode(&[0; RECORD_LEN]), None);
        assert_eq!(decode(&encode(7)[..RECORD_LEN - 1]), None);
    }

    #[test]
    fn a_record_with_stray_ones_never_verifies_with_another_count() {
        // Every single stray bit (a cut program or erase leaves bits at 1) fails the record.
        let record = encode(0x0F0F_0F0F);
        for bit in 0..RECORD_LEN * 8 {
            let mut cut = record;
            if let Some(byte) = cut.get_mut(bit / 8) {
                *byte |= 1 << (bit % 8);
            }
            if cut != record {
                assert_eq!(decode(&cut), None, "bit {bit}");
            }
        }
    }
}
