//! A NOR flash in the AN386's code RAM, for the table store, the boot counter and the key page:
//! the machine has no flash controller.
//!
//! The region [`FLASH_BASE`]..+[`FLASH_LEN`] lies above the program in SSRAM1 and outside the
//! ELF, so QEMU's `system_reset` (which reloads the ELF's segments) leaves it as it was, like
//! flash across a board reset. It does not outlive the QEMU process: a new QEMU starts with it
//! zeroed (which the store reads as "no table", the boot counter as "no boot yet", and the board
//! as an erased key page: see `main.rs`).
//!
//! Layout (offsets from [`FLASH_BASE`]): the table store [`STORE_RANGE`] (0x0004_0000, 48 KiB),
//! the boot counter [`BOOT_COUNTER_RANGE`] (0x0004_C000, two pages), the key page [`KEY_PAGE`]
//! (0x0004_E000, one page; QEMU's `-device loader,file=PAGE.bin,addr=0x4e000,force-raw=on`
//! plants it, and re-plants it at every system reset, which a key page does not mind), the
//! configuration page [`SETTINGS_RANGE`] (0x0004_F000, two pages: node id and bit rate set over
//! the bus) and the uid page [`UID_PAGE`] (0x0005_1000: the board's 12-byte unique id, planted by
//! a test as the key page is; all zeros when nothing was planted).
//!
//! Semantics as strict as the STM32G474's flash (and `pab-storage`'s test flash): 4 KiB erase
//! pages set to 0xFF; programming in aligned 8-byte words, each of which must be erased (all
//! 0xFF) or be written with zeros, else the write fails with [`RamFlashError::NotErased`] and
//! changes nothing; reads are byte-granular. A program that relies on AND-writes fails here as it
//! would on the G4.
//!
//! **Times, as on the G474** (datasheet typical): a page erase takes [`ERASE_US`], a double word's
//! program [`PROGRAM_WORD_US`], in one of two layouts ([`LAYOUT`]):
//!
//! - [`Layout::DualBank`] (the default, as the NUCLEO-G474RE runs: the store in the bank the code
//!   does not run from): an erase runs in the background ([`BackgroundErase`]) while the CPU goes
//!   on; a program keeps the CPU waiting for the controller, interrupts served.
//! - [`Layout::SingleBank`] (feature `single-bank`, a test build: the code and the store share
//!   the bank): every erase and program stalls the CPU, interrupts included, for its whole time,
//!   while the modelled CAN controller keeps three frames and loses the rest
//!   ([`crate::uart::stalled_receive`]).
//!
//! The time is spent on the board's clock (embassy-time, which QEMU runs at the host's pace), so
//! HIL tests see what a save costs the node.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use pab_storage::BackgroundErase;

/// A page erase on the G474, µs (datasheet typical; 40 ms at most).
pub const ERASE_US: u64 = 22_000;
/// A double word's program on the G474, µs (datasheet typical; 91 µs at most).
pub const PROGRAM_WORD_US: u64 = 82;
/// Which of the G474's flash layouts the model follows (module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Erases in the background; programs wait with interrupts served.
    DualBank,
    /// Every erase and program stalls the CPU with interrupts masked.
    SingleBank,
}

/// The layout of this build: [`Layout::SingleBank`] with the `single-bank` feature.
pub const LAYOUT: Layout = if cfg!(feature = "single-bank") {
    Layout::SingleBank
} else {
    Layout::DualBank
};

/// Where the region starts (memory.x ends the program region here).
pub const FLASH_BASE: usize = 0x0004_0000;
/// Its length: 72 KiB, eighteen pages.
pub const FLASH_LEN: usize = 0x12000;
/// The table store: 48 KiB, twelve pages (four 12 KiB slots).
pub const STORE_RANGE: core::ops::Range<u32> = 0..0xC000;
/// The boot counter: two pages.
pub const BOOT_COUNTER_RANGE: core::ops::Range<u32> = 0xC000..0xE000;
/// The key page (its address is `FLASH_BASE + KEY_PAGE` = 0x0004_E000).
pub const KEY_PAGE: u32 = 0xE000;
/// The configuration page: two pages (`pab_storage::SettingsPage`).
pub const SETTINGS_RANGE: core::ops::Range<u32> = 0xF000..0x11000;
/// The uid page (its address is `FLASH_BASE + UID_PAGE` = 0x0005_1000): the first 12 bytes are
/// the board's unique id, what the G474's factory UID is to a NUCLEO.
pub const UID_PAGE: u32 = 0x11000;
const _: () = assert!(
    STORE_RANGE.end == BOOT_COUNTER_RANGE.start
        && BOOT_COUNTER_RANGE.end == KEY_PAGE
        && KEY_PAGE + PAGE as u32 == SETTINGS_RANGE.start
        && SETTINGS_RANGE.end == UID_PAGE
        && UID_PAGE as usize + PAGE == FLASH_LEN
);
/// Erase page, as on the G474 in single-bank mode.
pub const PAGE: usize = 4096;
/// Program word, as on the G474 (a double word).
pub const WORD: usize = 8;

/// Why an operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum RamFlashError {
    /// Not aligned to the word (writes) or page (erases) size.
    NotAligned,
    /// Outside the region.
    OutOfBounds,
    /// A write touched a word that is neither erased nor written with zeros.
    NotErased,
}

impl core::fmt::Display for RamFlashError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RamFlashError::NotAligned => "not aligned to the flash's write or erase size",
            RamFlashError::OutOfBounds => "outside the flash",
            RamFlashError::NotErased => "written where the flash was not erased",
        })
    }
}

impl core::error::Error for RamFlashError {}

impl NorFlashError for RamFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            RamFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            RamFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            RamFlashError::NotErased => NorFlashErrorKind::Other,
        }
    }
}

/// The region as a NOR flash; offsets count from [`FLASH_BASE`].
pub struct RamFlash {
    memory: &'static mut [u8],
    /// When the erase running in the background ends, µs on the board's clock.
    erase_until: u64,
}

impl RamFlash {
    /// The region at [`FLASH_BASE`].
    ///
    /// # Safety
    ///
    /// Call it once: the result owns the region. Nothing else (program, stack, statics) may live
    /// there; memory.x keeps the program below [`FLASH_BASE`].
    pub unsafe fn take() -> Self {
        // SAFETY: the region is RAM of this machine, unused by the program (see above), and
        // any byte value is a valid u8.
        let memory = unsafe { core::slice::from_raw_parts_mut(FLASH_BASE as *mut u8, FLASH_LEN) };
        RamFlash {
            memory,
            erase_until: 0,
        }
    }

    /// Spends `us` as the flash controller would: in a critical section on a single bank (the
    /// CPU stalls, nothing runs), else waiting with interrupts served.
    // Out of line: erases and writes share it.
    #[inline(never)]
    fn spend(&self, us: u64) {
        let end = pab_app::now().as_micros().saturating_add(us);
        #[cfg(feature = "single-bank")]
        critical_section::with(|cs| {
            let mut fifo = crate::uart::StallFifo::default();
            while pab_app::now().as_micros() < end {
                crate::uart::stalled_receive(cs, &mut fifo);
                // A pause without device accesses: under QEMU every access to a device takes
                // the emulator's global lock, and a loop of nothing but accesses kept QEMU's
                // main loop, which hands over the serial line's bytes, from getting it.
                cortex_m::asm::delay(2_000);
            }
        });
        #[cfg(not(feature = "single-bank"))]
        while pab_app::now().as_micros() < end {
            core::hint::spin_loop();
        }
    }

    /// Sets the pages of `from..to` to 0xFF, checking the range.
    fn clear(&mut self, from: u32, to: u32) -> Result<usize, RamFlashError> {
        let len = to.checked_sub(from).ok_or(RamFlashError::OutOfBounds)? as usize;
        let range = self.range(from, len)?;
        if range.start % PAGE != 0 || range.end % PAGE != 0 {
            return Err(RamFlashError::NotAligned);
        }
        self.memory
            .get_mut(range)
            .ok_or(RamFlashError::OutOfBounds)?
            .fill(0xFF);
        Ok(len / PAGE)
    }

    fn range(&self, offset: u32, len: usize) -> Result<core::ops::Range<usize>, RamFlashError> {
        let start = usize::try_from(offset).map_err(|_| RamFlashError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(RamFlashError::OutOfBounds)?;
        if end > self.memory.len() {
            return Err(RamFlashError::OutOfBounds);
        }
        Ok(start..end)
    }
}

impl ErrorType for RamFlash {
    type Error = RamFlashError;
}

impl ReadNorFlash for RamFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let range = self.range(offset, bytes.len())?;
        let source = self.memory.get(range).ok_or(RamFlashError::OutOfBounds)?;
        bytes.copy_from_slice(source);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.memory.len()
    }
}

impl NorFlash for RamFlash {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = PAGE;

    /// Waits for every page's erase (the boot counter's, a store's format).
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let pages = self.clear(from, to)?;
        self.spend(ERASE_US.saturating_mul(pages as u64));
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let range = self.range(offset, bytes.len())?;
        if range.start % WORD != 0 || range.end % WORD != 0 {
            return Err(RamFlashError::NotAligned);
        }
        let target = self
            .memory
            .get_mut(range)
            .ok_or(RamFlashError::OutOfBounds)?;
        // Check every word before changing any: a refused write changes nothing.
        let programmable = target
            .chunks_exact(WORD)
            .zip(bytes.chunks_exact(WORD))
            .all(|(old, new)| old.iter().all(|&b| b == 0xFF) || new.iter().all(|&b| b == 0));
        if !programmable {
            return Err(RamFlashError::NotErased);
        }
        target.copy_from_slice(bytes);
        self.spend(PROGRAM_WORD_US.saturating_mul((bytes.len() / WORD) as u64));
        Ok(())
    }
}

impl BackgroundErase for RamFlash {
    /// The page reads erased at once (what it holds while the erase runs is undefined on the
    /// G474, and nothing reads it then); the time is spent in the background on a dual bank, at
    /// once and stalled on a single bank.
    fn start_erase(&mut self, offset: u32) -> Result<(), Self::Error> {
        self.clear(offset, offset.saturating_add(PAGE as u32))?;
        match LAYOUT {
            Layout::SingleBank => self.spend(ERASE_US),
            Layout::DualBank => {
                self.erase_until = pab_app::now().as_micros().saturating_add(ERASE_US);
            }
        }
        Ok(())
    }

    fn erase_done(&mut self) -> Result<bool, Self::Error> {
        Ok(pab_app::now().as_micros() >= self.erase_until)
    }
}
