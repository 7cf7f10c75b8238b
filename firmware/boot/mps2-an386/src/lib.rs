//! # pab-boot-an386: the emulated board's bootloader, and what its application shares with it
//!
//! The binary (`src/main.rs`, feature `bootloader`) is the bootloader of QEMU's `mps2-an386`:
//! at every reset it installs the factory image into an empty active partition, decides on a
//! stored update (pab-core's `update::stored`: the signature is checked here, not in the
//! application), lets embassy-boot swap or revert, and jumps to the application.
//!
//! The library is what the board's application (`pab-fw-an386` with its `boot` feature) needs
//! to talk to it: the memory map ([`layout`]) and the flash model of its partitions ([`Nor`]).
//!
//! ## Memory map (SSRAM1, the board's code RAM)
//!
//! ```text
//! 0x0000_0000..0x0000_8000  the bootloader (its ELF: QEMU's -kernel)
//! 0x0000_8000..0x0001_9000  ACTIVE: the application (at most 68 KiB - 96), its manifest in the last 96 bytes
//! 0x0001_9000..0x0002_B000  DFU: the update's slot (ACTIVE's length), one page more for the swap
//! 0x0002_B000..0x0002_C000  STATE: embassy-boot's state (magic, swap and revert progress)
//! 0x0002_C000..0x0002_D000  REQUEST: update::stored's request and verdict records
//! 0x0003_0000..0x0003_0008  the reset test's two words (feature `reset-test` only: [`reset_test`])
//! 0x0004_0000..0x0005_2000  the board's RAM-backed flash (table store, key page, ...), unchanged
//! 0x0010_0000..0x0011_1000  FACTORY: the application's binary, planted by QEMU's loader
//! ```
//!
//! Everything but the bootloader lies outside every ELF: QEMU reloads ELF segments and loader
//! blobs at each system reset and leaves the rest of its RAM as it was, which is how these
//! partitions keep their contents across a reset, as flash would (not across QEMU processes: a
//! new one starts with them zeroed).

#![no_std]
#![warn(missing_docs)]

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// The memory map: addresses and lengths of the partitions (module documentation of the crate).
pub mod layout {
    /// The bootloader's region (its ELF).
    pub const BOOTLOADER: usize = 0x0000_0000;
    /// The active partition: where the application runs from (its vector table first).
    pub const ACTIVE: usize = 0x0000_8000;
    /// The active partition's length, and the DFU slot's: the application and its manifest.
    pub const ACTIVE_LEN: usize = 0x11000;
    /// The DFU partition: the update's slot, then the page embassy-boot's swap needs.
    pub const DFU: usize = 0x0001_9000;
    /// The DFU partition's length: the active partition's and one page.
    pub const DFU_LEN: usize = ACTIVE_LEN + PAGE;
    /// embassy-boot's state partition.
    pub const STATE: usize = 0x0002_B000;
    /// The state partition's length: one page (embassy-boot needs 2 + 4 × 17 words of it).
    pub const STATE_LEN: usize = PAGE;
    /// The request page (`pab_core::update::stored::Request`, the verdict at
    /// `stored::VERDICT_OFFSET`).
    pub const REQUEST: usize = 0x0002_C000;
    /// The request page's length.
    pub const REQUEST_LEN: usize = PAGE;
    /// The reset test's page (feature `reset-test`: [`crate::reset_test`]): two words, outside
    /// every partition, image and ELF; a release bootloader never reads it.
    pub const RESET_TEST: usize = 0x0003_0000;
    /// The board's key page (the application's `ram_flash::FLASH_BASE + KEY_PAGE`); the update
    /// key's record lies at `stored::KEY_RECORD_OFFSET` in it.
    pub const KEY_PAGE: usize = 0x0004_E000;
    /// The factory image: the application's raw binary as QEMU's loader plants it
    /// (`-device loader,file=APP.bin,addr=0x100000,force-raw=on`), the stand-in for a probe's
    /// flashing. The bootloader copies [`ACTIVE_LEN`] bytes from here into an empty active
    /// partition: the binary and whatever follows it (zeros in a fresh QEMU), no header.
    pub const FACTORY: usize = 0x0010_0000;
    /// The erase page of every partition (the G474's, as the board's RAM-backed flash).
    pub const PAGE: usize = 4096;
    /// The program word (a double word, as on the G474).
    pub const WORD: usize = 8;
    /// Data RAM (SSRAM2/3): an application's initial stack pointer lies in
    /// `RAM_START..=RAM_END`.
    pub const RAM_START: u32 = 0x2000_0000;
    /// Data RAM's end (exclusive; a full descending stack may start there).
    pub const RAM_END: u32 = 0x2040_0000;
    /// The firmware name of the board's application (`pab_app::firmware!("fw-an386")`, its
    /// identity): an update's trailer must name it.
    pub const BOARD_NAME: [u8; 8] = *b"fw-an386";

    const _: () = assert!(
        BOOTLOADER + 0x8000 == ACTIVE
            && ACTIVE + ACTIVE_LEN == DFU
            && DFU + DFU_LEN == STATE
            && STATE + STATE_LEN == REQUEST
            && REQUEST + REQUEST_LEN <= RESET_TEST
            && RESET_TEST + PAGE <= 0x0004_0000
            && FACTORY >= 0x0005_2000
            && ACTIVE_LEN.is_multiple_of(PAGE)
            // embassy-boot's state: magic, progress validity, then swap and revert progress.
            && (2 + 4 * ACTIVE_LEN / PAGE) * WORD <= STATE_LEN
    );

    /// Whether `vector_table` (its first two words) starts an application: an initial stack
    /// pointer in data RAM and a reset vector (Thumb) inside the active partition. A fresh QEMU
    /// reads zeros, an erased partition 0xFF: neither is one.
    pub fn is_application(vector_table: [u32; 2]) -> bool {
        let [sp, reset] = vector_table;
        let reset = reset & !1;
        (RAM_START..=RAM_END).contains(&sp)
            && (ACTIVE as u32..(ACTIVE + ACTIVE_LEN) as u32).contains(&reset)
    }
}

/// Why a partition's operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum NorError {
    /// Not aligned to the word (writes) or page (erases) size.
    NotAligned,
    /// Outside the partition.
    OutOfBounds,
    /// A write touched a word that is neither erased nor written with zeros.
    NotErased,
}

impl NorFlashError for NorError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            NorError::NotAligned => NorFlashErrorKind::NotAligned,
            NorError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            NorError::NotErased => NorFlashErrorKind::Other,
        }
    }
}

/// One partition of code RAM as a NOR flash, with the rules of the board's RAM-backed flash
/// (`pab_fw_an386::ram_flash`): 4 KiB pages erased to 0xFF, programs in aligned 8-byte words
/// onto erased words only (or writing zeros), a refused write changing nothing. Unlike it, no
/// time is spent: the bootloader has no clock, and the swap's 35 pages of erases at the G474's
/// 22 ms would only slow the tests. Offsets count from `BASE`.
pub struct Nor<const BASE: usize, const LEN: usize>(());

/// The active partition.
pub type Active = Nor<{ layout::ACTIVE }, { layout::ACTIVE_LEN }>;
/// The DFU partition, where an update is written before it is swapped in.
pub type Dfu = Nor<{ layout::DFU }, { layout::DFU_LEN }>;
/// embassy-boot's state partition.
pub type State = Nor<{ layout::STATE }, { layout::STATE_LEN }>;
/// The request page.
pub type RequestPage = Nor<{ layout::REQUEST }, { layout::REQUEST_LEN }>;

impl<const BASE: usize, const LEN: usize> Nor<BASE, LEN> {
    /// The partition.
    ///
    /// # Safety
    ///
    /// `BASE..BASE + LEN` is RAM of this machine that nothing else (program, stack, statics,
    /// another `Nor` over it in use) uses meanwhile: [`layout`]'s partitions are, one handle at a
    /// time.
    pub const unsafe fn take() -> Self {
        Nor(())
    }

    /// The partition's bytes at `offset..offset + len`, checked against the partition.
    fn span(offset: u32, len: usize) -> Result<(*mut u8, usize), NorError> {
        let start = usize::try_from(offset).map_err(|_| NorError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(NorError::OutOfBounds)?;
        if end > LEN {
            return Err(NorError::OutOfBounds);
        }
        // The address only: nothing is dereferenced here.
        Ok((BASE.wrapping_add(start) as *mut u8, len))
    }
}

impl<const BASE: usize, const LEN: usize> ErrorType for Nor<BASE, LEN> {
    type Error = NorError;
}

impl<const BASE: usize, const LEN: usize> ReadNorFlash for Nor<BASE, LEN> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), NorError> {
        let (at, len) = Self::span(offset, bytes.len())?;
        // SAFETY: `at..at + len` lies in the partition (checked), which this handle owns
        // (`take`'s contract); `bytes` is another object.
        unsafe { core::ptr::copy_nonoverlapping(at, bytes.as_mut_ptr(), len) };
        Ok(())
    }

    fn capacity(&self) -> usize {
        LEN
    }
}

impl<const BASE: usize, const LEN: usize> NorFlash for Nor<BASE, LEN> {
    const WRITE_SIZE: usize = layout::WORD;
    const ERASE_SIZE: usize = layout::PAGE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), NorError> {
        let len = to.checked_sub(from).ok_or(NorError::OutOfBounds)? as usize;
        let (at, len) = Self::span(from, len)?;
        if !(from as usize).is_multiple_of(layout::PAGE) || !len.is_multiple_of(layout::PAGE) {
            return Err(NorError::NotAligned);
        }
        #[cfg(feature = "reset-test")]
        reset_test::operation();
        // SAFETY: as in `read`.
        unsafe { core::ptr::write_bytes(at, 0xFF, len) };
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), NorError> {
        let (at, len) = Self::span(offset, bytes.len())?;
        if !(offset as usize).is_multiple_of(layout::WORD) || !len.is_multiple_of(layout::WORD) {
            return Err(NorError::NotAligned);
        }
        // SAFETY: as in `read`; the slice lives until this function returns and nothing else
        // touches the partition meanwhile.
        let target = unsafe { core::slice::from_raw_parts_mut(at, len) };
        // Every word checked before any changes: a refused write changes nothing.
        let programmable = target
            .chunks_exact(layout::WORD)
            .zip(bytes.chunks_exact(layout::WORD))
            .all(|(old, new)| old.iter().all(|&b| b == 0xFF) || new.iter().all(|&b| b == 0));
        if !programmable {
            return Err(NorError::NotErased);
        }
        #[cfg(feature = "reset-test")]
        reset_test::operation();
        target.copy_from_slice(bytes);
        Ok(())
    }
}

/// The reset test (feature `reset-test`: a test build of the bootloader, never a release one):
/// a system reset in place of one partition operation, to show that a reset at any step of the
/// bootloader (the verdict, the swap's mark, every page copy, progress record and erase of
/// embassy-boot's swap and revert) leaves the old or the new firmware running.
///
/// Every erase and write of a [`Nor`] partition that passed its checks is an **operation**;
/// they are numbered from 1 across all partitions and all resets of one QEMU process, in
/// [`COUNT`]. Before operation `N` is made, where `N` is the word at [`CUT_AT`], the bootloader
/// says `boot: reset-test: reset at operation N` and resets the system
/// (`SCB::sys_reset`): the operation is lost whole (a torn erase or write, half made, is not
/// modelled), and the next boot finds the partitions as the operations before it left them.
///
/// Both words lie in [`layout::RESET_TEST`]'s page, outside every partition, image and ELF, so
/// a system reset keeps them and a fresh QEMU starts with zeros. The test plants `N` with
/// QEMU's loader (`-device loader,data=N,data-len=4,addr=0x30000`), which re-plants it at every
/// reset; the count goes on across the cut (the lost operation, made again, is `N + 1`), so it
/// never meets `N` again and the cut happens once per QEMU process, with no flag of its own. A
/// zero `N` (nothing planted) never cuts. The words are plain RAM, written outside the flash
/// model.
#[cfg(feature = "reset-test")]
pub mod reset_test {
    use super::layout;

    /// The operation to cut (`u32`, little endian), planted by the test: 0 for none.
    pub const CUT_AT: usize = layout::RESET_TEST;
    /// The operations made so far in this QEMU process (`u32`), the cut one included.
    pub const COUNT: usize = layout::RESET_TEST + 4;

    /// The operations made so far in this QEMU process.
    pub fn count() -> u32 {
        // SAFETY: a word of RAM of this machine outside every partition and program (the
        // module's documentation), word aligned.
        unsafe { core::ptr::read_volatile(COUNT as *const u32) }
    }

    /// Counts one operation, and resets the system in its place if it is the one to cut.
    pub(crate) fn operation() {
        let count = count().wrapping_add(1);
        // SAFETY: as in `count`; nothing else writes the word.
        unsafe { core::ptr::write_volatile(COUNT as *mut u32, count) };
        // SAFETY: as in `count`.
        let cut_at = unsafe { core::ptr::read_volatile(CUT_AT as *const u32) };
        if count == cut_at {
            say_number(b"boot: reset-test: reset at operation ", count);
            cortex_m::peripheral::SCB::sys_reset();
        }
    }

    /// Writes `text`, `number` in decimal and a newline to QEMU's standard error
    /// (semihosting); errors are ignored.
    pub fn say_number(text: &[u8], number: u32) {
        let mut digits = [0u8; 10];
        let mut at = digits.len();
        let mut rest = number;
        loop {
            at -= 1;
            // A digit: below 10.
            digits[at] = b'0' + (rest % 10) as u8;
            rest /= 10;
            if rest == 0 {
                break;
            }
        }
        if let Ok(mut stderr) = cortex_m_semihosting::hio::hstderr() {
            let _ = stderr.write_all(text);
            let _ = stderr.write_all(&digits[at..]);
            let _ = stderr.write_all(b"\n");
        }
    }
}
