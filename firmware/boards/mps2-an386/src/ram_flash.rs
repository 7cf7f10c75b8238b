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
//! plants it, and re-plants it at every system reset, which a key page does not mind).
//!
//! Semantics as strict as the STM32G474's flash (and `pab-storage`'s test flash): 4 KiB erase
//! pages set to 0xFF; programming in aligned 8-byte words, each of which must be erased (all
//! 0xFF) or be written with zeros, else the write fails with [`RamFlashError::NotErased`] and
//! changes nothing; reads are byte-granular. A program that relies on AND-writes fails here as it
//! would on the G4.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Where the region starts (memory.x ends the program region here).
pub const FLASH_BASE: usize = 0x0004_0000;
/// Its length: 60 KiB, fifteen pages.
pub const FLASH_LEN: usize = 0xF000;
/// The table store: 48 KiB, twelve pages (four 12 KiB slots).
pub const STORE_RANGE: core::ops::Range<u32> = 0..0xC000;
/// The boot counter: two pages.
pub const BOOT_COUNTER_RANGE: core::ops::Range<u32> = 0xC000..0xE000;
/// The key page (its address is `FLASH_BASE + KEY_PAGE` = 0x0004_E000).
pub const KEY_PAGE: u32 = 0xE000;
const _: () = assert!(
    STORE_RANGE.end == BOOT_COUNTER_RANGE.start
        && BOOT_COUNTER_RANGE.end == KEY_PAGE
        && KEY_PAGE as usize + PAGE == FLASH_LEN
);
/// Erase page, as on the G474 in single-bank mode.
pub const PAGE: usize = 4096;
/// Program word, as on the G474 (a double word).
pub const WORD: usize = 8;

/// Why an operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RamFlashError {
    /// Not aligned to the word (writes) or page (erases) size.
    NotAligned,
    /// Outside the region.
    OutOfBounds,
    /// A write touched a word that is neither erased nor written with zeros.
    NotErased,
}

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
        RamFlash { memory }
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

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let len = to.checked_sub(from).ok_or(RamFlashError::OutOfBounds)? as usize;
        let range = self.range(from, len)?;
        if range.start % PAGE != 0 || range.end % PAGE != 0 {
            return Err(RamFlashError::NotAligned);
        }
        self.memory
            .get_mut(range)
            .ok_or(RamFlashError::OutOfBounds)?
            .fill(0xFF);
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
        Ok(())
    }
}
