//! [`SettingsPage`]: a node's configuration (node id, bit rate: a 16-bit record that
//! `pab-app` defines) in flash pages of its own, power-fail safe.
//!
//! It is a [`BootCounter`] whose count carries the record: count = sequence << 16 | record.
//! Each write records a count with a sequence one above the newest, so the boot counter's
//! guarantee is this page's: the newest record that reads back is the one in force, a write cut
//! by a power loss leaves either it or the one before, never a mixture (a cut record verifies
//! only if it holds exactly the count it was meant to). 65 535 writes exhaust it
//! ([`CounterError::Exhausted`]): [`SettingsPage::format`] starts again, since here nothing
//! depends on the sequence never repeating.
//!
//! Cost: as the boot counter's (a read of every record, one program and its read-back, an
//! erase once in `page / record` writes).

use core::ops::Range;

use embedded_storage::nor_flash::NorFlash;

use crate::{BootCounter, CounterError};

/// A node's configuration record in a range of NOR flash pages (at least two).
pub struct SettingsPage<F: NorFlash> {
    log: BootCounter<F>,
}

/// The count after `count` that carries `record`: the next sequence in the high half.
fn next_record(count: u32, record: u32) -> Option<u32> {
    let sequence = (count >> 16).checked_add(1)?;
    (sequence <= 0xFFFF).then_some(sequence << 16 | record & 0xFFFF)
}

impl<F: NorFlash> SettingsPage<F> {
    /// The page in `range` of `flash`: the boot counter's layout rules
    /// ([`BootCounter::new`]). Touches no flash.
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, CounterError> {
        Ok(SettingsPage {
            log: BootCounter::new(flash, range)?,
        })
    }

    /// The record in force; `None` if none was ever written (erased or foreign pages).
    pub fn read(&mut self) -> Result<Option<u16>, CounterError> {
        let count = self.log.current()?;
        let [low, high, ..] = count.to_le_bytes();
        Ok((count != 0).then_some(u16::from_le_bytes([low, high])))
    }

    /// Writes `record`: in force once this returns `Ok` (and after any power loss from then on).
    pub fn write(&mut self, record: u16) -> Result<(), CounterError> {
        self.log.advance(next_record, u32::from(record)).map(|_| ())
    }

    /// Erases the pages: the compiled defaults apply again.
    pub fn format(&mut self) -> Result<(), CounterError> {
        self.log.format()
    }
}
