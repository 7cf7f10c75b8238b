//! Page erases that run while the caller does other work.
//!
//! A page erase takes tens of milliseconds (the STM32G474: 22 ms typical, 40 ms at most). A node
//! that waited for it would leave the bus unread for that long: at 2 000 frames a second, 44
//! frames, more than the controller and the driver's queue hold (3 + 32 on the G474). A flash
//! whose controller erases one bank while the CPU runs from the other (the G474 in dual-bank mode)
//! can start the erase and report later when it is done; [`FlashStore`](crate::FlashStore)'s
//! step-wise save ([`TableStore::continue_save`](crate::TableStore::continue_save)) uses that to
//! read frames while the page erases.
//!
//! Programming stays blocking ([`NorFlash::write`]): the store programs one chunk per step
//! ([`crate::SAVE_CHUNK`] bytes, 164 µs of double-word programs on the G474), shorter than one
//! frame on the bus.

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// A NOR flash that can erase a page in the background.
///
/// Between [`start_erase`](Self::start_erase) and the [`erase_done`](Self::erase_done) that
/// answers `Ok(true)`, the caller must not read, write or erase the flash (its contents are
/// undefined there, and the controller is busy); it may do anything else.
pub trait BackgroundErase: NorFlash {
    /// Starts erasing the page at `offset` (a multiple of `ERASE_SIZE`) and returns without
    /// waiting for it. Fails as [`NorFlash::erase`] does (misaligned, out of range, locked).
    fn start_erase(&mut self, offset: u32) -> Result<(), Self::Error>;
    /// Whether the erase started last has completed: `Ok(false)` while it runs. An erase that
    /// failed answers its error. Costs a register read on a board.
    fn erase_done(&mut self) -> Result<bool, Self::Error>;
}

/// Any [`NorFlash`] as a [`BackgroundErase`] whose erases complete before
/// [`start_erase`](BackgroundErase::start_erase) returns: for flashes that cannot erase in the
/// background (the CPU stalls anyway on a single-bank part), and for the tests and tools that
/// need no overlap. The store then still saves in steps, one page erase per step.
#[derive(Clone, Debug, Default)]
pub struct Blocking<F>(pub F);

impl<F: ErrorType> ErrorType for Blocking<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Blocking<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> NorFlash for Blocking<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes)
    }
}

impl<F: NorFlash> BackgroundErase for Blocking<F> {
    fn start_erase(&mut self, offset: u32) -> Result<(), Self::Error> {
        // ERASE_SIZE fits in u32 for any flash a u32 offset can address.
        let end = offset.saturating_add(F::ERASE_SIZE as u32);
        self.0.erase(offset, end)
    }

    fn erase_done(&mut self) -> Result<bool, Self::Error> {
        Ok(true)
    }
}
