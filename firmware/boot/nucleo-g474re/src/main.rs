//! # pab-boot-g474: the NUCLEO-G474RE's bootloader, on embassy-boot
//!
//! The emulated board's bootloader (`firmware/boot/mps2-an386`) is the model; this one runs the
//! same steps over the STM32G474RE's flash (dual-bank, DBANK = 1, 2 KiB pages), at every reset:
//!
//! 1. **A pending request** in the request page: `pab_boot_common::decide` (the DFU slot checked
//!    by `pab_core::update::stored::check` for the board name `fw-g474` under the key page's
//!    update key record, the verdict written, and only then, if it passed, embassy-boot's
//!    `mark_updated`; a request while the state says Swap is dropped).
//! 2. **embassy-boot's `prepare_boot`** (through embassy-boot-stm32's `try_prepare`): swaps,
//!    resumes a cut swap, or reverts an update that did not mark itself booted before this
//!    reset. A flash error leaves the progress records for the next reset and boots what is
//!    there.
//! 3. **Jump** to ACTIVE (`pab_boot_common::jump`) if it starts with a vector table; else wait
//!    (nothing to run: flash an application with a probe).
//!
//! No factory install (that is the emulation's stand-in for a probe); no clock set-up (the reset
//! clock, HSI16, is the flash's fastest at zero wait states); no log (no console without a
//! probe: the verdict in the request page is what the application reports). The application's
//! own watchdog does not run here: a system reset stops the IWDG unless the option byte
//! `IWDG_SW` selects the hardware watchdog, which this board's firmware does not use.
//!
//! **Not run on a board**: built and sized only (docs/nucleo-g474re.md, "Bootloader").

#![no_std]
#![no_main]

use core::cell::RefCell;

// The boards' memcpy and memset: smaller than compiler_builtins' (the crate's Cargo.toml).
use pab_builtins as _;

use embassy_boot_stm32::{BootLoader, BootLoaderConfig, State as BootState};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_stm32::flash::{Blocking, Flash, WRITE_SIZE};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use pab_boot_common::Slot;
use pab_core::update::stored;

/// The memory map (addresses; the flash driver counts offsets from [`layout::FLASH_BASE`]).
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
mod layout {
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
    /// The state partition's write unit (the G474 programs double words).
    pub const WORD: usize = super::WRITE_SIZE;
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

/// The interrupt table: one entry, never enabled (cortex-m-rt needs the table longer than the
/// exceptions'; its own default has 240 entries).
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
static __INTERRUPTS: [unsafe extern "C" fn(); 1] = [DefaultHandler];

unsafe extern "C" {
    /// cortex-m-rt's default handler.
    fn DefaultHandler();
}

/// The flash, shared by the partitions (each borrows it for one operation at a time).
type Shared = Mutex<NoopRawMutex, RefCell<Flash<'static, Blocking>>>;

/// One partition of the flash, at an address of the layout.
fn partition(
    flash: &Shared,
    address: u32,
    len: u32,
) -> BlockingPartition<'_, NoopRawMutex, Flash<'static, Blocking>> {
    BlockingPartition::new(flash, address - layout::FLASH_BASE, len)
}

#[cortex_m_rt::entry]
fn main() -> ! {
    // The flash's data cache (on at reset: FLASH_ACR.DCEN) off and reset, so that no line read
    // before a program is served after it: embassy-boot reads back the state words it writes,
    // and the swap reads pages it has just programmed. embassy's erase resets the cache itself;
    // its program does not. The application turns the caches on again.
    let acr = embassy_stm32::pac::FLASH.acr();
    acr.modify(|w| w.set_dcen(false));
    acr.modify(|w| w.set_dcrst(true));
    acr.modify(|w| w.set_dcrst(false));
    // SAFETY: the only handle to the flash controller in this program (no `init`: nothing else
    // takes peripherals).
    let flash: Shared = Mutex::new(RefCell::new(Flash::new_blocking(unsafe {
        embassy_stm32::peripherals::FLASH::steal()
    })));
    let mut dfu = partition(&flash, layout::DFU, layout::DFU_LEN);
    let mut state = partition(&flash, layout::STATE, layout::STATE_LEN);
    let mut request = partition(&flash, layout::REQUEST, layout::REQUEST_LEN);
    let mut word = [0u8; layout::WORD];
    let swapping = pab_boot_common::state_of(&mut state, &mut word) == BootState::Swap;
    // SAFETY: the key page is the chip's flash, which nothing writes while this runs.
    let key_record = unsafe {
        pab_boot_common::mapped(
            layout::KEY_PAGE + stored::KEY_RECORD_OFFSET as u32,
            stored::KEY_RECORD_LEN,
        )
    };
    let slot = Slot {
        len: layout::ACTIVE_LEN,
        board: &layout::BOARD_NAME,
        key_record,
    };
    let _ = pab_boot_common::decide(
        &mut dfu,
        &mut state,
        &mut request,
        layout::REQUEST_LEN,
        slot,
        swapping,
        &mut word,
    );

    // A flash error leaves the progress records as they are: the next reset resumes; meanwhile
    // boot what is there.
    let _ = BootLoader::try_prepare::<_, _, _, { layout::PAGE as usize }>(BootLoaderConfig {
        active: partition(&flash, layout::ACTIVE, layout::ACTIVE_LEN),
        dfu,
        state,
    });

    // SAFETY: ACTIVE is the chip's flash, word aligned.
    let table = unsafe { pab_boot_common::vector_table(layout::ACTIVE) };
    if pab_boot_common::is_application(
        table,
        layout::RAM,
        layout::ACTIVE..layout::ACTIVE + layout::ACTIVE_LEN,
    ) {
        // SAFETY: a vector table at ACTIVE (checked), 2 KiB aligned; nothing of this program
        // is used afterwards.
        unsafe { pab_boot_common::jump(layout::ACTIVE) }
    }
    halt()
}

/// Nothing to run (an erased ACTIVE), or a panic: wait for a debugger or a reset.
fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// A panic (embassy-boot's assertions on the partitions, which the layout's constants satisfy;
/// the flash driver's refusal of a chip whose DBANK is cleared) halts; no message is formatted
/// (flash).
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    halt()
}
