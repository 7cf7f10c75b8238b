//! # pab-boot-g474: the NUCLEO-G474RE's bootloader, and what its application shares with it
//!
//! The binary (`src/main.rs`, feature `bootloader`) is the bootloader: at every reset it decides
//! on a stored update (pab-core's `update::stored`: the signature is checked there, not in the
//! application), lets embassy-boot swap or revert, and jumps to the application.
//!
//! The library is the flash map the two share ([`layout`]): the bootloader's partitions and the
//! application's `update` build (`pab-fw-g474`, which writes the DFU partition and the request
//! page and confirms itself on the state partition) read their addresses here, written once.
//! It has no code and no dependency beyond pab-core's constants.

#![no_std]
#![warn(missing_docs)]

/// The memory map (addresses; embassy's flash driver counts offsets from [`layout::FLASH_BASE`]).
///
/// ```text
/// bank 1  0x0800_0000..0x0800_8000   32 KiB  the bootloader (its ELF; goal 24 KiB)
///         0x0800_8000..0x0801_8800   66 KiB  ACTIVE: the application (at most 66 KiB - 96), its manifest in the last 96 bytes
///         0x0801_8800..0x0804_0000  158 KiB  free
/// bank 2  0x0804_0000..0x0805_1000   68 KiB  DFU: the update's slot (ACTIVE's length), one page more for the swap
///         0x0805_1000..0x0805_1800    2 KiB  STATE: embassy-boot's state
///         0x0805_1800..0x0805_2000    2 KiB  REQUEST: update::stored's request and verdict
///         0x0805_2000..0x0807_3800  134 KiB  free
///         0x0807_3800..0x0808_0000   50 KiB  the application's: configuration, key page, boot counter, table store (unchanged)
/// ```
///
/// What the application writes while it runs (DFU, STATE, REQUEST) is in bank 2 with its store,
/// so that its erases never stall the CPU's fetches from bank 1; only the bootloader's swap
/// erases bank 1, when nothing else runs.
pub mod layout {
    /// The flash's first byte.
    pub const FLASH_BASE: u32 = 0x0800_0000;
    /// The erase page (dual-bank mode).
    pub const PAGE: u32 = 2048;
    /// Bank 2's first byte.
    pub const BANK2: u32 = 0x0804_0000;
    /// The bootloader's region (memory.x).
    pub const BOOTLOADER_LEN: u32 = 0x8000;
    /// The active partition: where the application runs from (its vector table first).
    pub const ACTIVE: u32 = 0x0800_8000;
    /// The active partition's length, and the DFU slot's: the 64 KiB application and its
    /// 96-byte manifest, rounded up to whole pages (33).
    pub const ACTIVE_LEN: u32 = 0x1_0800;
    /// The DFU partition: the update's slot, then the page embassy-boot's swap needs.
    pub const DFU: u32 = BANK2;
    /// The DFU partition's length: the active partition's and one page.
    pub const DFU_LEN: u32 = ACTIVE_LEN + PAGE;
    /// embassy-boot's state partition: one page.
    pub const STATE: u32 = DFU + DFU_LEN;
    /// The state partition's length.
    pub const STATE_LEN: u32 = PAGE;
    /// The request page (`pab_core::update::stored::Request`, the verdict at
    /// `stored::VERDICT_OFFSET`).
    pub const REQUEST: u32 = STATE + STATE_LEN;
    /// The request page's length.
    pub const REQUEST_LEN: u32 = PAGE;
    /// The application's configuration page (its `SETTINGS_RANGE`), the lowest of what it
    /// keeps at the top of bank 2.
    pub const APPLICATION_DATA: u32 = 0x0807_3800;
    /// The key page (the application's `KEY_PAGE`, 0x7_4800 from the flash base); the update
    /// key's record lies at `stored::KEY_RECORD_OFFSET` in it.
    pub const KEY_PAGE: u32 = 0x0807_4800;
    /// The state partition's write unit: the G474 programs double words (embassy-stm32's
    /// `flash::WRITE_SIZE`, which the bootloader checks against it).
    pub const WORD: usize = 8;
    /// Data RAM: an application's initial stack pointer lies in `RAM` (its end included).
    pub const RAM: core::ops::Range<u32> = 0x2000_0000..0x2002_0000;
    /// The firmware name of the board's application (`pab_app::firmware!("fw-g474")`, its
    /// identity): an update's trailer must name it.
    pub const BOARD_NAME: [u8; 8] = *b"fw-g474\0";

    const _: () = assert!(
        FLASH_BASE + BOOTLOADER_LEN == ACTIVE
            && ACTIVE + ACTIVE_LEN <= BANK2
            && ACTIVE_LEN >= 64 * 1024 + pab_core::update::MANIFEST_LEN as u32
            && ACTIVE_LEN.is_multiple_of(PAGE)
            && ACTIVE.is_multiple_of(PAGE)
            && DFU.is_multiple_of(PAGE)
            && REQUEST + REQUEST_LEN <= APPLICATION_DATA
            && KEY_PAGE >= APPLICATION_DATA
            // embassy-boot's state: magic, progress validity, then swap and revert progress.
            && WORD == 8
            && (2 + 4 * ACTIVE_LEN / PAGE) * WORD as u32 <= STATE_LEN
    );
}
