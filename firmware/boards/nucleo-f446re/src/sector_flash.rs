//! The F446's flash for the table store and the boot counter: one bank of sectors of 16, 64 and
//! 128 KiB, in which an erase or a program stalls every fetch from the flash.
//!
//! [`SectorFlash`] is embassy's blocking driver for reads and programs, with a sector erase of
//! its own, and a `NorFlash` whose erase unit is one sector size: the store's 16 KiB sectors
//! ([`crate::SMALL_SECTOR`]) or the boot counter's 128 KiB ones ([`crate::LARGE_SECTOR`]), each
//! restricted to its own range, so that no erase can reach the program, the vector table or the
//! key page. (embassy's own `NorFlash` gives the whole flash one erase size, the largest, 128 KiB,
//! and erases by looking the sector up in its table of regions.)
//!
//! **No erase in the background.** The flash has one bank: while it erases a sector, every read
//! of it stalls the bus, instruction fetches included (RM0390, "Read-while-write" exists only
//! between banks, and the F446 has one). The CPU, running from the flash, stops at its next fetch
//! until the erase is done; interrupts wait too (their vectors and code are in the flash). The
//! store gets the erase through `pab_storage::Blocking`: each page erase one step of a save, over
//! when the step returns. What that costs the node (frames lost beyond the CAN controller's
//! three-frame FIFO, a heartbeat late, a schema server's overrun) is in docs/nucleo-f446re.md.
//!
//! **Parallelism x32.** The erase runs with PSIZE = x32 (the NUCLEO's 3.3 V allows it), the
//! fastest the supply allows without an external VPP: 16 KiB in 250 ms typical, 500 ms at most;
//! 128 KiB in 1 s, 2 s at most (the datasheet's flash table). embassy-stm32 0.6's F4 erase keeps
//! whatever PSIZE the last program left, which its program clears to x8 on the way out (twice
//! as slow: 400 and 800 ms for 16 KiB). Programs are embassy's: one 32-bit word at a time,
//! 16 µs typical, 100 µs at most.
//!
//! **The watchdog during an erase.** A stalled CPU cannot feed the IWDG, and the longest erase
//! (2 s) is far beyond its 500 ms timeout: before each erase [`crate::watchdog_for_erase`]
//! reloads it with a timeout that covers the erase's datasheet maximum, and
//! [`crate::watchdog_after_erase`] puts the 500 ms back once it is done (a hang in the erase
//! itself still ends in a reset, later).
//!
//! **The data cache.** The flash's data cache (ART accelerator, on since boot: `main.rs`) keeps
//! lines read before an erase or a program; RM0390 asks for it to be flushed after an erase
//! that touched cached data. The store reads back what it programs and reads headers before it
//! erases, so the cache is reset after every erase and every program ([`flush_data_cache`]).
//!
//! No ECC: the F4's flash has none, so a word whose program a power loss cut reads back as
//! whatever bits it holds, without a fault, and the store's CRCs reject it. No NMI handler is
//! needed (the G474's clears its flash's double-ECC error).
//!
//! Not run on hardware yet (docs/nucleo-f446re.md says so).

use core::ops::Range;

use embassy_stm32::flash::{Blocking, Error, Flash};
use embassy_stm32::pac::FLASH;
use embassy_stm32::pac::flash::vals::Psize;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

use crate::{LARGE_SECTOR, SMALL_SECTOR};

/// The unlock keys of FLASH_KEYR (RM0390).
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;

/// Offsets (from the flash base) of the first 128 KiB sector, number 5.
const LARGE_SECTORS_START: u32 = 0x2_0000;
/// Sector number of the first 128 KiB sector.
const FIRST_LARGE_SECTOR: u32 = 5;

/// The flash, with erases of `SECTOR`-byte sectors inside one range (offsets from the flash
/// base, as embassy's).
pub struct SectorFlash<'d, const SECTOR: u32> {
    flash: Flash<'d, Blocking>,
    /// The sectors this instance may erase.
    range: Range<u32>,
}

impl<'d, const SECTOR: u32> SectorFlash<'d, SECTOR> {
    /// Wraps embassy's blocking driver; erases are refused outside `range`.
    pub fn new(flash: Flash<'d, Blocking>, range: Range<u32>) -> Self {
        SectorFlash { flash, range }
    }

    /// The sector number (FLASH_CR.SNB) of the sector that starts at `offset`, if it is a
    /// `SECTOR`-byte sector of this instance's range.
    fn sector_number(&self, offset: u32) -> Option<u8> {
        if !self.range.contains(&offset) || !offset.is_multiple_of(SECTOR) {
            return None;
        }
        let number = match SECTOR {
            // Sectors 0 to 3: 16 KiB each from the flash's start.
            SMALL_SECTOR if offset < 4 * SMALL_SECTOR => offset / SMALL_SECTOR,
            // Sectors 5 to 7: 128 KiB each from 0x2_0000.
            LARGE_SECTOR if offset >= LARGE_SECTORS_START => {
                FIRST_LARGE_SECTOR + (offset - LARGE_SECTORS_START) / LARGE_SECTOR
            }
            _ => return None,
        };
        u8::try_from(number).ok().filter(|&number| number <= 7)
    }

    /// Erases the sector at `offset`, waiting for it: the CPU stalls at its next fetch from the
    /// flash until the erase is done (the module documentation says why).
    fn erase_sector(&mut self, offset: u32) -> Result<(), Error> {
        let Some(number) = self.sector_number(offset) else {
            return Err(Error::Size);
        };
        while FLASH.sr().read().bsy() {}
        if FLASH.cr().read().lock() {
            FLASH.keyr().write_value(KEY1);
            FLASH.keyr().write_value(KEY2);
        }
        // Clears every write-1-to-clear flag (writes back what it reads).
        FLASH.sr().modify(|_| {});
        crate::watchdog_for_erase();
        FLASH.cr().write(|w| {
            w.set_ser(true);
            w.set_snb(number);
            w.set_psize(Psize::PSIZE32);
        });
        FLASH.cr().modify(|w| w.set_strt(true));
        while FLASH.sr().read().bsy() {}
        let sr = FLASH.sr().read();
        // SER off and the controller locked again, in one write.
        FLASH.cr().write(|w| w.set_lock(true));
        FLASH.sr().modify(|_| {});
        flush_data_cache();
        crate::watchdog_after_erase();
        // Any error flag (write protection, programming alignment, parallelism, sequence,
        // operation) as one: the store and the boot counter report every flash error alike.
        if sr.wrperr() || sr.pgaerr() || sr.pgperr() || sr.pgserr() || sr.operr() {
            Err(Error::Prog)
        } else {
            Ok(())
        }
    }
}

/// Resets the flash's data cache if it is on (RM0390: DCRST only with the cache off), so that no
/// line read before an erase or a program is served after it.
fn flush_data_cache() {
    let acr = FLASH.acr();
    if acr.read().dcen() {
        acr.modify(|w| w.set_dcen(false));
        acr.modify(|w| w.set_dcrst(true));
        acr.modify(|w| w.set_dcrst(false));
        acr.modify(|w| w.set_dcen(true));
    }
}

impl<const SECTOR: u32> ErrorType for SectorFlash<'_, SECTOR> {
    type Error = Error;
}

impl<const SECTOR: u32> ReadNorFlash for SectorFlash<'_, SECTOR> {
    const READ_SIZE: usize = <Flash<'static, Blocking> as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        self.flash.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<const SECTOR: u32> NorFlash for SectorFlash<'_, SECTOR> {
    const WRITE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = SECTOR as usize;

    /// Each sector in `from..to` in turn, waiting for each.
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        if !to.is_multiple_of(SECTOR) {
            return Err(Error::Unaligned);
        }
        let mut sector = from;
        while sector < to {
            self.erase_sector(sector)?;
            sector = sector.saturating_add(SECTOR);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        let written = self.flash.write(offset, bytes);
        flush_data_cache();
        written
    }
}
