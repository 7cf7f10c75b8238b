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
//! The flash map is the library's (`pab_boot_g474::layout`, src/lib.rs), which the application
//! that takes updates reads too.
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
// The memory map, shared with the application's `update` build (src/lib.rs).
use pab_boot_g474::layout;
use pab_core::update::stored;

// The state partition's write unit, as the layout says it, is the flash driver's.
const _: () = assert!(layout::WORD == WRITE_SIZE);

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
