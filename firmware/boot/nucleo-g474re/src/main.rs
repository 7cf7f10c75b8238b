//! # pab-boot-g474: the NUCLEO-G474RE's bootloader, on embassy-boot
//!
//! The emulated board's bootloader (`firmware/boot/mps2-an386`) is the model; this one runs the
//! same steps over the STM32G474RE's flash (dual-bank, DBANK = 1, 2 KiB pages), at every reset
//! (`pab_boot_common::boot` over this board's partitions):
//!
//! 1. **A pending request** in the request page: `pab_boot_common::decide` (the DFU slot checked
//!    by `pab_core::update::stored::check` for the board name `fw-g474` under the key page's
//!    update key record, the verdict written, and only then, if it passed, embassy-boot's
//!    `mark_updated`; a request while the state says Swap is dropped).
//! 2. **embassy-boot's `prepare_boot`**: swaps, resumes a cut swap, or reverts an update that
//!    did not mark itself booted before this reset. A flash error leaves the progress records for the next reset and boots what is
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

use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_stm32::flash::{Blocking, Flash, WRITE_SIZE};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use pab_boot_common::Map;
// The memory map, shared with the application's `update` build (src/lib.rs).
use pab_boot_g474::layout;

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
    let dfu = partition(&flash, layout::DFU, layout::DFU_LEN);
    let state = partition(&flash, layout::STATE, layout::STATE_LEN);
    let request = partition(&flash, layout::REQUEST, layout::REQUEST_LEN);
    let map = Map {
        key_page: layout::KEY_PAGE,
        active: layout::ACTIVE,
        active_len: layout::ACTIVE_LEN,
        request_len: layout::REQUEST_LEN,
        ram: layout::RAM,
        board: &layout::BOARD_NAME,
    };
    let active = partition(&flash, layout::ACTIVE, layout::ACTIVE_LEN);
    // SAFETY: the key page and ACTIVE are the chip's flash, which nothing else writes while
    // this runs; ACTIVE is 2 KiB aligned.
    unsafe {
        pab_boot_common::boot::<_, _, _, _, { layout::PAGE as usize }, { layout::WORD }>(
            &map, active, dfu, state, request,
        )
    }
}

/// The flash's double-ECC error raises an NMI: a double word whose programming a power loss cut
/// reads so until its page is erased. This program reads DFU, STATE and REQUEST (bank 2) at
/// every reset, where the application's update, its confirmation or this program's own verdict
/// and swap records may have been cut: halting there would halt every boot, a board that only a
/// probe brings back. So such an error is cleared and the read completes with bad bytes, which
/// what reads them rejects: a state word that is no magic reads as Boot (no swap), a request or
/// verdict that is no record is not taken (`update::stored::Request::read`), a slot's bytes fail
/// the signature's check, and a swap's progress record that reads as written counts its step as
/// done, which it was (embassy-boot writes the record after the step). Anywhere else (this
/// program, the active partition, the key page) it halts, as cortex-m-rt's default handler did.
/// The application's handler does the same for what it reads (pab-fw-g474's src/main.rs).
/// Not run on a board.
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    let flash = embassy_stm32::pac::FLASH;
    let eccr = flash.eccr().read();
    // Dual-bank mode: ADDR_ECC is the byte offset of the failing double word within its bank,
    // BK_ECC the bank (set: bank 2).
    let at = layout::BANK2.saturating_add(eccr.addr_ecc());
    if eccr.eccd()
        && eccr.bk_ecc()
        && (layout::DFU..layout::REQUEST + layout::REQUEST_LEN).contains(&at)
    {
        // ECCD is write-1-to-clear; the other bits written 0 leave ECCC alone and the
        // correction interrupt disabled (its reset state).
        flash.eccr().write(|w| w.set_eccd(true));
        return;
    }
    pab_boot_common::halt()
}

/// A panic (embassy-boot's assertions on the partitions, which the layout's constants satisfy;
/// the flash driver's refusal of a chip whose DBANK is cleared) halts; no message is formatted
/// (flash).
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    pab_boot_common::halt()
}
