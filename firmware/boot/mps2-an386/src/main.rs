//! # pab-boot-an386: the emulated board's bootloader (QEMU `mps2-an386`), on embassy-boot
//!
//! At every reset (power-on, the application's `SCB::sys_reset`, the watchdog's):
//!
//! 1. **Factory install**: when the active partition holds no application (its first two words
//!    are not an initial stack pointer in data RAM and a reset vector in the partition: a fresh
//!    QEMU reads zeros) and no swap is under way, copy the factory image
//!    ([`layout::FACTORY`], planted by QEMU's loader) into it and erase the DFU, state and
//!    request pages. This stands in for flashing the board with a probe: QEMU would re-plant a
//!    blob loaded into the active partition itself at every reset, undoing every swap.
//! 2. **A pending request** (`update::stored::Request::Pending` in the request page;
//!    `pab_boot_common::decide`, shared with the NUCLEO boards' bootloaders): check the
//!    DFU slot (`update::stored::check`: manifest, capacity, board name, the Ed25519 signature
//!    under the key page's update key; no key, no update: `BadSignature`), write the verdict,
//!    and only then, if it passed, mark the swap in the state partition (embassy-boot's
//!    `mark_updated`). A reset between the two leaves a verdict of `Ok` without a swap: the
//!    update is lost and the old firmware runs, so an application must check its own version
//!    against the one it asked for before it believes an `Ok`; the other order could swap in
//!    an image with no verdict written for it (update::stored's documentation).
//! 3. **embassy-boot's `prepare_boot`**: swaps when the state says Swap and the swap has not
//!    been done (its progress records say so, so a reset mid-swap resumes it); **reverts** when
//!    the state still says Swap after a completed swap, that is, when the swapped-in application
//!    did not mark itself booted before the next reset (its watchdog's, or its own); afterwards
//!    the state says Revert, which boots.
//! 4. **Jump** to the active partition: VTOR, MSP and the reset vector, with no interrupt
//!    enabled or pending (this program enables none).
//!
//! It never depends on the application being sane: an application that hangs is reset by its
//! own watchdog (the CMSDK watchdog's reset is a system reset in QEMU), and this runs again.
//!
//! Messages (`boot: ...`) go to QEMU's standard error through semihosting.
//!
//! The feature `reset-test` makes a test build (never a release one) that replaces one
//! partition operation, chosen per QEMU run, with a system reset and says how many operations
//! each boot made (`pab_boot_an386::reset_test`; scripts/boot-reset-test.sh).

#![no_std]
#![no_main]

use core::cell::RefCell;

// The boards' memcpy and memset: smaller than compiler_builtins' (the crate's Cargo.toml).
use pab_builtins as _;

use embassy_boot::{BootLoader, BootLoaderConfig, State as BootState};
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use pab_boot_an386::{Active, Dfu, RequestPage, State, layout};
use pab_boot_common::{Decision, Slot};
use pab_core::update::stored;

/// The interrupt table: one entry, never enabled (cortex-m-rt needs the table longer than the
/// exceptions'; its own default has 240 entries).
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
static __INTERRUPTS: [unsafe extern "C" fn(); 1] = [DefaultHandler];

unsafe extern "C" {
    /// cortex-m-rt's default handler.
    fn DefaultHandler();
}

/// What failed on the way to the application; each ends the boot with its message.
#[derive(Clone, Copy, Debug)]
enum Halt {
    /// Neither the active partition nor the factory image holds an application.
    NoApplication,
    /// Copying the factory image failed (a flash error: a layout mistake).
    FactoryInstall,
}

#[cortex_m_rt::entry]
fn main() -> ! {
    match boot() {
        // SAFETY: `boot` checked the vector table (`layout::is_application`).
        Ok(()) => unsafe { jump() },
        Err(Halt::NoApplication) => halt(b"boot: no application in ACTIVE nor FACTORY\n"),
        Err(Halt::FactoryInstall) => halt(b"boot: factory install failed\n"),
    }
}

/// Steps 1 to 3 (the crate's documentation): `Ok` when the active partition holds an
/// application to jump to.
fn boot() -> Result<(), Halt> {
    // SAFETY: the partitions are RAM outside this program (memory.x), one handle each.
    let (mut active, mut dfu, mut state, mut request) = unsafe {
        (
            Active::take(),
            Dfu::take(),
            State::take(),
            RequestPage::take(),
        )
    };
    let mut word = [0u8; layout::WORD];
    let swapping = state_of(&mut state, &mut word) == BootState::Swap;
    if !layout::is_application(vector_table(layout::ACTIVE)) && !swapping {
        factory_install(&mut active, &mut dfu, &mut state, &mut request)?;
    }

    decide(&mut dfu, &mut state, &mut request, swapping);
    // The test build's count (src/lib.rs, `reset_test`): where the factory install and the
    // request's handling end and embassy-boot's swap or revert begins.
    #[cfg(feature = "reset-test")]
    pab_boot_an386::reset_test::say_number(
        b"boot: reset-test: operations before prepare_boot ",
        pab_boot_an386::reset_test::count(),
    );

    let mut buffer = [0u8; 1024];
    let flashes = (RefCell::new(active), RefCell::new(dfu), RefCell::new(state));
    let mut loader = BootLoader::new(BootLoaderConfig {
        active: Shared(&flashes.0),
        dfu: Shared(&flashes.1),
        state: Shared(&flashes.2),
    });
    // `prepare_boot` returns the state it found: Swap both when it swapped and when it
    // reverted; the state it leaves tells them apart (Swap after a swap, Revert after a revert).
    let prepared = loader.prepare_boot(&mut buffer);
    let left = state_of(&mut flashes.2.borrow_mut(), &mut word);
    match (prepared, left) {
        (Ok(BootState::Swap), BootState::Swap) => say(b"boot: swapped in the update\n"),
        (Ok(BootState::Swap), _) => say(b"boot: reverted the unconfirmed update\n"),
        (Ok(_), _) => {}
        // Nothing to do but boot what is there: the progress records let the next reset
        // resume.
        (Err(_), _) => say(b"boot: prepare_boot failed\n"),
    }
    #[cfg(feature = "reset-test")]
    pab_boot_an386::reset_test::say_number(
        b"boot: reset-test: operations after prepare_boot ",
        pab_boot_an386::reset_test::count(),
    );
    if layout::is_application(vector_table(layout::ACTIVE)) {
        Ok(())
    } else {
        Err(Halt::NoApplication)
    }
}

/// embassy-boot's state, as `prepare_boot` reads it (a zeroed page, a fresh QEMU's, reads as
/// Boot: neither magic).
fn state_of(state: &mut State, word: &mut [u8; layout::WORD]) -> BootState {
    pab_boot_common::state_of(state, word)
}

/// Step 1: the factory image into the active partition, and the other partitions erased (what a
/// probe's full-chip erase and flashing leave).
fn factory_install(
    active: &mut Active,
    dfu: &mut Dfu,
    state: &mut State,
    request: &mut RequestPage,
) -> Result<(), Halt> {
    if !layout::is_application(vector_table(layout::FACTORY)) {
        return Err(Halt::NoApplication);
    }
    say(b"boot: factory install\n");
    // SAFETY: the factory region is RAM of this machine outside every partition and this
    // program, read only.
    let image =
        unsafe { core::slice::from_raw_parts(layout::FACTORY as *const u8, layout::ACTIVE_LEN) };
    // The lengths are the layout's constants, far below u32::MAX.
    active
        .erase(0, layout::ACTIVE_LEN as u32)
        .and_then(|()| active.write(0, image))
        .and_then(|()| dfu.erase(0, layout::DFU_LEN as u32))
        .and_then(|()| state.erase(0, layout::STATE_LEN as u32))
        .and_then(|()| request.erase(0, layout::REQUEST_LEN as u32))
        .map_err(|_| Halt::FactoryInstall)
}

/// Step 2: decides on a pending request, writes the verdict, then marks the swap of an image
/// that passed (`pab_boot_common::decide`), and says what it did. `swapping`: the state says
/// Swap (an update swapped in that has not confirmed itself, or one marked whose swap has not
/// run), in which case a new request is dropped: the revert (or the swap) comes first, and the
/// DFU partition is its working space.
fn decide(dfu: &mut Dfu, state: &mut State, request: &mut RequestPage, swapping: bool) {
    // SAFETY: the key page is RAM of this machine outside this program, read only here.
    let key_record = unsafe {
        pab_boot_common::mapped(
            (layout::KEY_PAGE + stored::KEY_RECORD_OFFSET) as u32,
            stored::KEY_RECORD_LEN,
        )
    };
    let slot = Slot {
        len: layout::ACTIVE_LEN as u32,
        board: &layout::BOARD_NAME,
        key_record,
    };
    let mut word = [0u8; layout::WORD];
    let decision = pab_boot_common::decide(
        dfu,
        state,
        request,
        layout::REQUEST_LEN as u32,
        slot,
        swapping,
        &mut word,
    );
    match decision {
        Decision::Nothing | Decision::Unreadable => {}
        Decision::Dropped => say(b"boot: request dropped: the last update is not confirmed\n"),
        Decision::Decided { code, marked } => {
            say_verdict(code);
            if code == 0 && !marked {
                say(b"boot: cannot mark the swap\n");
            }
        }
        Decision::VerdictUnwritable { code } => {
            say_verdict(code);
            // A verdict that cannot be written (the word was not erased: the application broke
            // the page's protocol): no swap without one.
            say(b"boot: cannot write the verdict: no swap\n");
        }
    }
}

/// `boot: request: verdict N`, the line scripts/boot_test.py reads.
fn say_verdict(code: u8) {
    say(b"boot: request: verdict ");
    say(&[b'0' + code, b'\n']);
}

/// One of the partitions, shared between the boot loader's three roles by a `RefCell` (each is
/// borrowed for one operation at a time): embassy-boot takes its flashes by value.
struct Shared<'a, F>(&'a RefCell<F>);

impl<F: embedded_storage::nor_flash::ErrorType> embedded_storage::nor_flash::ErrorType
    for Shared<'_, F>
{
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Shared<'_, F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), F::Error> {
        self.0.borrow_mut().read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.borrow().capacity()
    }
}

impl<F: NorFlash> NorFlash for Shared<'_, F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), F::Error> {
        self.0.borrow_mut().erase(from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), F::Error> {
        self.0.borrow_mut().write(offset, bytes)
    }
}

/// The first two words at `address`: an initial stack pointer and a reset vector, if a vector
/// table lies there.
fn vector_table(address: usize) -> [u32; 2] {
    // SAFETY: `address` is one of the layout's regions, RAM of this machine, word aligned.
    unsafe { pab_boot_common::vector_table(address as u32) }
}

/// Step 4: into the application at [`layout::ACTIVE`].
///
/// # Safety
///
/// The active partition starts with an application's vector table (`layout::is_application`).
unsafe fn jump() -> ! {
    // SAFETY: the caller's contract; the application's vector table is 128-byte aligned at
    // ACTIVE (its linker script).
    unsafe { pab_boot_common::jump(layout::ACTIVE as u32) }
}

/// Writes `text` to QEMU's standard error (semihosting); errors are ignored: nobody to tell.
fn say(text: &[u8]) {
    if let Ok(mut stderr) = cortex_m_semihosting::hio::hstderr() {
        let _ = stderr.write_all(text);
    }
}

/// Says why and ends the emulation with a failure status (on a bare board: waits at a
/// breakpoint for a debugger).
fn halt(why: &[u8]) -> ! {
    say(why);
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}

/// A panic (embassy-boot's assertions on the partitions' sizes, which the layout's constants
/// satisfy) ends the emulation; no message or location is formatted (flash).
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    halt(b"boot: panic\n")
}
