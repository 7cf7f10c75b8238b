//! The G474's flash in dual-bank mode (the factory setting, option bit DBANK = 1): two banks of
//! 256 KiB in 2 KiB pages. The program runs from bank 1; the key page, the boot counter and the
//! table store live in bank 2 ([`crate::BANK2`]), so that erasing or programming them never
//! stalls the CPU's instruction fetches (RM0440, "Read-while-write": a bank can be read while the
//! other is written). With the feature `update`, the bootloader's DFU, STATE and REQUEST
//! partitions too, at the bottom of bank 2, each through a driver of its own over this one
//! (src/boot.rs, which says how its operations meet a store's erase running in the background).
//!
//! [`BankFlash`] is embassy's blocking driver for reads and programs, and a page erase of its own
//! that runs in the background ([`BackgroundErase`]): it starts the erase and returns, and the
//! store checks `BSY` between the node's frames. embassy's driver waits for the erase (22 ms
//! typical, 40 ms at most), in which a busy bus brings more frames than the FDCAN's FIFO and the
//! driver's queue hold. The register sequence is the one embassy-stm32 0.6 uses for a blocking
//! erase (`flash/g.rs`: unlock, clear the error flags, data cache off, PER, BKER, PNB and STRT in
//! one write; at the end PER off, errors cleared, the data cache reset and back on, lock): kept
//! in step with it at every embassy upgrade.
//!
//! Not run on hardware yet (docs/nucleo-g474re.md says so).

use embassy_stm32::flash::{Blocking, Error, Flash};
use embassy_stm32::pac::FLASH;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use pab_storage::BackgroundErase;

use crate::{BANK2, PAGE};

/// The unlock keys of FLASH_KEYR (RM0440).
const KEY1: u32 = 0x4567_0123;
const KEY2: u32 = 0xCDEF_89AB;

/// The flash, for the store and the boot counter (offsets from the flash base, as embassy's).
pub struct BankFlash {
    flash: Flash<'static, Blocking>,
    /// Whether the data cache was on when the running erase turned it off.
    data_cache: bool,
}

impl BankFlash {
    /// Wraps embassy's blocking driver.
    pub fn new(flash: Flash<'static, Blocking>) -> Self {
        BankFlash {
            flash,
            data_cache: false,
        }
    }
}

impl ErrorType for BankFlash {
    type Error = Error;
}

impl ReadNorFlash for BankFlash {
    const READ_SIZE: usize = <Flash<'static, Blocking> as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        self.flash.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for BankFlash {
    const WRITE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::ERASE_SIZE;

    /// Each page of bank 2 in `from..to` in turn, waiting for it (the boot counter's at boot).
    /// Through [`BackgroundErase`]'s sequence rather than embassy's erase, which would link its
    /// sector lookup for both banks along (676 bytes of flash) for the same registers.
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        if !to.is_multiple_of(PAGE) {
            return Err(Error::Unaligned);
        }
        let mut page = from;
        while page < to {
            self.start_erase(page)?;
            while !self.erase_done()? {}
            page = page.saturating_add(PAGE);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        self.flash.write(offset, bytes)
    }
}

impl BackgroundErase for BankFlash {
    /// Bank 2 only: a page of bank 1 (the program's) would stall the CPU, and is not the store's.
    fn start_erase(&mut self, offset: u32) -> Result<(), Error> {
        // One refusal for every misplaced page (below bank 2, unaligned, past the end): the store
        // reports any flash error alike.
        let within = offset.wrapping_sub(BANK2);
        let page = within / PAGE;
        if offset < BANK2 || !within.is_multiple_of(PAGE) || page >= 128 {
            return Err(Error::Size);
        }
        while FLASH.sr().read().bsy() {}
        if FLASH.cr().read().lock() {
            FLASH.keyr().write_value(KEY1);
            FLASH.keyr().write_value(KEY2);
        }
        // Clears every write-1-to-clear error flag (writes back what it reads).
        FLASH.sr().modify(|_| {});
        self.data_cache = FLASH.acr().read().dcen();
        if self.data_cache {
            FLASH.acr().modify(|w| w.set_dcen(false));
        }
        cortex_m::interrupt::free(|_| {
            FLASH.cr().modify(|w| {
                w.set_per(true);
                w.set_bker(true);
                // page < 128: the 7 bits of PNB in dual-bank mode.
                w.set_pnb(page as u8);
                w.set_strt(true);
            });
        });
        Ok(())
    }

    fn erase_done(&mut self) -> Result<bool, Error> {
        let sr = FLASH.sr().read();
        if sr.bsy() {
            return Ok(false);
        }
        FLASH.cr().modify(|w| w.set_per(false));
        FLASH.sr().modify(|_| {});
        if self.data_cache {
            FLASH.acr().modify(|w| w.set_dcrst(true));
            FLASH.acr().modify(|w| w.set_dcrst(false));
            FLASH.acr().modify(|w| w.set_dcen(true));
        }
        FLASH.cr().modify(|w| w.set_lock(true));
        // Any error flag (programming, write protection, alignment, size, sequence) as one: the
        // store reports every flash error alike (StoreFailed); the five variants, with
        // `start_erase`'s three refusals, took 64 bytes of flash more.
        if sr.progerr() || sr.wrperr() || sr.pgaerr() || sr.sizerr() || sr.pgserr() {
            Err(Error::Prog)
        } else {
            Ok(true)
        }
    }
}
