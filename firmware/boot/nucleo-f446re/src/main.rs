//! # pab-boot-f446: the NUCLEO-F446RE's bootloader, on embassy-boot
//!
//! The emulated board's bootloader (`firmware/boot/mps2-an386`) is the model, and the
//! NUCLEO-G474RE's (`firmware/boot/nucleo-g474re`) the same steps on an STM32; this one runs them
//! over the STM32F446RE's flash (one bank of sectors of 16, 64 and 128 KiB), at every reset
//! (`pab_boot_common::boot` over this board's partitions):
//!
//! 1. **A pending request** in the request sector: `pab_boot_common::decide` (the DFU slot
//!    checked by `pab_core::update::stored::check` for the board name `fw-f446` under the key
//!    page's update key record, the verdict written, and only then, if it passed, embassy-boot's
//!    `mark_updated`; a request while the state says Swap is dropped).
//! 2. **embassy-boot's `prepare_boot`**: swaps, resumes a cut swap, or reverts an update that
//!    did not mark itself booted before this reset.
//! 3. **Jump** to ACTIVE if it starts with a vector table; else wait.
//!
//! **The sectors.** embassy-boot swaps in pages of one size, the larger of the active and DFU
//! partitions' erase units, and every page of both must be one erase. An application of 64 KiB
//! and its 96-byte manifest need more than the one 64 KiB sector, so ACTIVE is a 128 KiB sector
//! (5, where the firmware's program already lies) and DFU the two others (6 and 7): one page for
//! the slot, one for the swap. That is the layout embassy's own examples for chips with uneven
//! sectors (the STM32F7's) follow: every partition of the swap in the largest sectors, the
//! bootloader in the small ones at the start. The state and the request, which embassy-boot
//! does not swap, take one 16 KiB sector each ([`Sectors`] gives them their own erase unit).
//!
//! **What that leaves the application**: the key page (sector 4) where it was, and no sector for
//! the table store (sectors 1 to 3 without the bootloader) nor the boot counter (6 and 7): the
//! application's `boot` build runs without either (docs/nucleo-f446re.md, "Bootloader").
//!
//! No factory install, no clock set-up (the reset clock, HSI 16 MHz, at zero wait states), no log.
//! The flash's caches stay as the reset leaves them, off (FLASH_ACR resets to 0), so every read
//! sees what was just programmed or erased; the application turns them on.
//! A 128 KiB sector's erase takes 1 to 4 s (embassy's driver erases at the parallelism its last
//! program left, x8); a swap erases two, a revert two more; no watchdog runs meanwhile (a system
//! reset stops the IWDG unless the option byte WDG_SW selects the hardware watchdog).
//!
//! **Not run on a board**: built and sized only.

#![no_std]
#![no_main]

use core::cell::RefCell;

// The boards' memcpy and memset: smaller than compiler_builtins' (the crate's Cargo.toml).
use pab_builtins as _;

use embassy_stm32::flash::{Blocking, Error, Flash, WRITE_SIZE};
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use pab_boot_common::Map;

/// The memory map (addresses; the flash driver counts offsets from [`layout::FLASH_BASE`]).
///
/// ```text
/// sectors 0-1  0x0800_0000..0x0800_8000   32 KiB  the bootloader (its ELF; goal 24 KiB)
/// sector 2     0x0800_8000..0x0800_C000   16 KiB  STATE: embassy-boot's state
/// sector 3     0x0800_C000..0x0801_0000   16 KiB  REQUEST: update::stored's request and verdict
/// sector 4     0x0801_0000..0x0802_0000   64 KiB  the key page (the application's KEY_PAGE, unchanged)
/// sector 5     0x0802_0000..0x0804_0000  128 KiB  ACTIVE: the application (at most 128 KiB - 96), its manifest in the last 96 bytes
/// sectors 6-7  0x0804_0000..0x0808_0000  256 KiB  DFU: the update's slot (sector 6), the swap's page (sector 7)
/// ```
mod layout {
    /// The flash's first byte.
    pub const FLASH_BASE: u32 = 0x0800_0000;
    /// The small sectors' size (0 to 3).
    pub const SMALL_SECTOR: u32 = 16 * 1024;
    /// The large sectors' size (5 to 7): embassy-boot's page.
    pub const LARGE_SECTOR: u32 = 128 * 1024;
    /// The bootloader's region (memory.x): sectors 0 and 1.
    pub const BOOTLOADER_LEN: u32 = 2 * SMALL_SECTOR;
    /// embassy-boot's state partition: sector 2.
    pub const STATE: u32 = FLASH_BASE + BOOTLOADER_LEN;
    /// The state partition's length.
    pub const STATE_LEN: u32 = SMALL_SECTOR;
    /// The request sector (`pab_core::update::stored::Request`, the verdict at
    /// `stored::VERDICT_OFFSET`): sector 3.
    pub const REQUEST: u32 = STATE + STATE_LEN;
    /// The request sector's length.
    pub const REQUEST_LEN: u32 = SMALL_SECTOR;
    /// The key page: sector 4 (the application's `KEY_PAGE`, 0x1_0000 from the flash base);
    /// the update key's record lies at `stored::KEY_RECORD_OFFSET` in it.
    pub const KEY_PAGE: u32 = REQUEST + REQUEST_LEN;
    /// The active partition: sector 5.
    pub const ACTIVE: u32 = KEY_PAGE + 64 * 1024;
    /// The active partition's length, and the DFU slot's: one large sector, the smallest erase
    /// unit that holds the 64 KiB application and its 96-byte manifest.
    pub const ACTIVE_LEN: u32 = LARGE_SECTOR;
    /// The DFU partition: sectors 6 and 7.
    pub const DFU: u32 = ACTIVE + ACTIVE_LEN;
    /// The DFU partition's length: the active partition's and one page.
    pub const DFU_LEN: u32 = ACTIVE_LEN + LARGE_SECTOR;
    /// The state partition's write unit (embassy's F4 driver programs words).
    pub const WORD: usize = super::WRITE_SIZE;
    /// Data RAM: an application's initial stack pointer lies in `RAM` (its end included).
    pub const RAM: core::ops::Range<u32> = 0x2000_0000..0x2002_0000;
    /// The firmware name of the board's application (`pab_app::firmware!("fw-f446")`, its
    /// identity): an update's trailer must name it.
    pub const BOARD_NAME: [u8; 8] = *b"fw-f446\0";

    const _: () = assert!(
        KEY_PAGE == FLASH_BASE + 0x1_0000
            && ACTIVE == FLASH_BASE + 0x2_0000
            && DFU + DFU_LEN == FLASH_BASE + 512 * 1024
            && ACTIVE_LEN >= 64 * 1024 + pab_core::update::MANIFEST_LEN as u32
            // embassy-boot's state: magic, progress validity, then swap and revert progress.
            && (2 + 4 * ACTIVE_LEN / LARGE_SECTOR) * WORD as u32 <= STATE_LEN
    );
}

/// The interrupt table: one entry, never enabled (cortex-m-rt needs the table longer than the
/// exceptions'; its own default has 240 entries).
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
static __INTERRUPTS: [unsafe extern "C" fn(); 1] = [DefaultHandler];

unsafe extern "C" {
    /// cortex-m-rt's default handler.
    fn DefaultHandler();
}

/// One partition of the flash, whose every erase unit is one sector of `ERASE` bytes: embassy's
/// `NorFlash` gives the whole flash one erase size, the largest (128 KiB), which the 16 KiB
/// sectors of the state and the request are not; its `blocking_erase` erases each sector of a
/// range by looking it up, whatever its size, and refuses a range that does not start and end
/// on sector boundaries. Offsets count from `start`.
struct Sectors<'a, const ERASE: u32> {
    flash: &'a RefCell<Flash<'static, Blocking>>,
    /// The partition's first byte, as an offset from the flash base.
    start: u32,
    len: u32,
}

impl<'a, const ERASE: u32> Sectors<'a, ERASE> {
    /// The partition at `address` (an address of the layout), `len` bytes.
    fn new(flash: &'a RefCell<Flash<'static, Blocking>>, address: u32, len: u32) -> Self {
        Sectors {
            flash,
            start: address - layout::FLASH_BASE,
            len,
        }
    }

    /// `offset..offset + len` from the flash base, if inside the partition.
    fn span(&self, offset: u32, len: usize) -> Result<u32, Error> {
        let len = u32::try_from(len).map_err(|_| Error::Size)?;
        match offset.checked_add(len) {
            Some(end) if end <= self.len => Ok(self.start + offset),
            _ => Err(Error::Size),
        }
    }
}

impl<const ERASE: u32> ErrorType for Sectors<'_, ERASE> {
    type Error = Error;
}

impl<const ERASE: u32> ReadNorFlash for Sectors<'_, ERASE> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        let at = self.span(offset, bytes.len())?;
        self.flash.borrow_mut().blocking_read(at, bytes)
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

impl<const ERASE: u32> NorFlash for Sectors<'_, ERASE> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        let len = to.checked_sub(from).ok_or(Error::Size)?;
        let at = self.span(from, len as usize)?;
        if !from.is_multiple_of(ERASE) || !len.is_multiple_of(ERASE) {
            return Err(Error::Unaligned);
        }
        self.flash.borrow_mut().blocking_erase(at, at + len)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        let at = self.span(offset, bytes.len())?;
        self.flash.borrow_mut().blocking_write(at, bytes)
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    // SAFETY: the only handle to the flash controller in this program (no `init`: nothing else
    // takes peripherals).
    let flash = RefCell::new(Flash::new_blocking(unsafe {
        embassy_stm32::peripherals::FLASH::steal()
    }));
    let dfu = Sectors::<{ layout::LARGE_SECTOR }>::new(&flash, layout::DFU, layout::DFU_LEN);
    let state = Sectors::<{ layout::SMALL_SECTOR }>::new(&flash, layout::STATE, layout::STATE_LEN);
    let request =
        Sectors::<{ layout::SMALL_SECTOR }>::new(&flash, layout::REQUEST, layout::REQUEST_LEN);
    let map = Map {
        key_page: layout::KEY_PAGE,
        active: layout::ACTIVE,
        active_len: layout::ACTIVE_LEN,
        request_len: layout::REQUEST_LEN,
        ram: layout::RAM,
        board: &layout::BOARD_NAME,
    };
    // The swap's buffer: 4 KiB of the stack, a 32nd of a page.
    let active =
        Sectors::<{ layout::LARGE_SECTOR }>::new(&flash, layout::ACTIVE, layout::ACTIVE_LEN);
    // SAFETY: the key page and ACTIVE are the chip's flash, which nothing else writes while
    // this runs; ACTIVE is 128 KiB aligned.
    unsafe {
        pab_boot_common::boot::<_, _, _, _, 4096, { layout::WORD }>(
            &map, active, dfu, state, request,
        )
    }
}

/// A panic (embassy-boot's assertions on the partitions, which the layout's constants satisfy)
/// halts; no message is formatted (flash).
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    pab_boot_common::halt()
}
