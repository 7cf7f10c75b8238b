//! # pab-an386-boottest: the bootloader's test application (feature `boot`)
//!
//! Runs behind the bootloader (firmware/boot/mps2-an386) from the active partition and does, at
//! each boot, what a script planted by QEMU's loader says, so that one QEMU run goes through a
//! whole update: the factory install, the request, the swap, the confirmation or the revert.
//! scripts/boot-test.sh builds it, signs it and runs it (see there for the scenarios).
//!
//! Its version is the last byte of [`VERSION`] ("PABBTVER1"): the test patches it to 2 in a
//! copy of the binary, so that the two firmwares differ by that byte only.
//!
//! At every boot it prints one line on QEMU's standard error,
//! `boottest: version V step N state S verdict R action A`, then does action A, the N-th byte of
//! the script at [`SCRIPT`] (N counts boots in a RAM word, [`STEP`], outside every image, that a
//! reset keeps and a fresh QEMU zeroes):
//!
//! - `U`: copy the update slot planted at [`UPDATE`] into the DFU partition, ask for it, reset;
//! - `B`: mark this firmware booted, reset;
//! - `N`: reset without marking it booted;
//! - `H`: hang with the watchdog running (its reset is a system reset), not marked booted;
//! - `E`: end the emulation with success.
//!
//! Anything else, or a step past the script, ends it with failure.

#![no_std]
#![no_main]

use pab_boot_an386::layout;
use pab_fw_an386::boot;
use pab_fw_an386::semihosting;
use pab_fw_an386::watchdog::{self, BoardWatchdog};

/// This firmware's version: its last byte, patched by the test (module documentation).
#[used]
static VERSION: [u8; 9] = *b"PABBTVER1";
/// Where the test plants the script: one action byte per boot, a 0 after the last.
const SCRIPT: usize = 0x0020_0000;
/// The script's longest length.
const SCRIPT_LEN: usize = 64;
/// Where the test plants the update's slot (`layout::ACTIVE_LEN` bytes: the image, the
/// manifest in the last 96).
const UPDATE: usize = 0x0012_0000;
/// The boot counter: a word of SSRAM1 beyond every image and partition.
const STEP: usize = 0x0030_0000;

#[cortex_m_rt::entry]
fn main() -> ! {
    // SAFETY: VERSION is a static of this program; volatile so that the patched byte is read,
    // not the compiled one.
    let version = unsafe { core::ptr::read_volatile(core::ptr::addr_of!(VERSION[8])) };
    // SAFETY: STEP is a word of RAM of this machine that nothing else uses.
    let step = unsafe { core::ptr::read_volatile(STEP as *const u32) };
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile(STEP as *mut u32, step.wrapping_add(1)) };
    let action = usize::try_from(step)
        .ok()
        .filter(|&step| step < SCRIPT_LEN)
        // SAFETY: the script's bytes are RAM of this machine, read only.
        .map(|step| unsafe { core::ptr::read_volatile((SCRIPT + step) as *const u8) })
        .unwrap_or(0);

    let mut line = semihosting::Text::line();
    let _ = core::fmt::Write::write_fmt(
        &mut line,
        format_args!(
            "boottest: version {} step {} state {} verdict {} action {}\n",
            char::from(version),
            step,
            match boot::state() {
                Ok(embassy_boot::State::Boot) => "Boot",
                Ok(embassy_boot::State::Swap) => "Swap",
                Ok(embassy_boot::State::Revert) => "Revert",
                Ok(embassy_boot::State::DfuDetach) => "DfuDetach",
                Err(_) => "unreadable",
            },
            Verdict(boot::take_verdict()),
            char::from(action),
        ),
    );
    line.flush();

    match action {
        b'U' => {
            // SAFETY: the test planted ACTIVE_LEN bytes there; RAM of this machine, read only.
            let slot =
                unsafe { core::slice::from_raw_parts(UPDATE as *const u8, layout::ACTIVE_LEN) };
            if boot::store_update(slot).is_err() {
                fail("cannot store the update");
            }
            if let Err(error) = boot::request_update() {
                fail(match error {
                    boot::BootError::NotConfirmed => "request refused: not confirmed",
                    _ => "cannot write the request",
                });
            }
            cortex_m::peripheral::SCB::sys_reset()
        }
        b'B' => {
            if boot::mark_booted().is_err() {
                fail("cannot mark booted");
            }
            cortex_m::peripheral::SCB::sys_reset()
        }
        b'N' => cortex_m::peripheral::SCB::sys_reset(),
        b'H' => {
            let _watchdog = BoardWatchdog::start();
            loop {
                core::hint::spin_loop();
            }
        }
        b'E' => semihosting::exit(true),
        _ => fail("no such action, or the script ended"),
    }
}

/// [`boot::take_verdict`]'s result as the test reads it: `none`, `ok`, `refused N`,
/// `unreadable`.
struct Verdict(Result<Option<Result<(), u8>>, boot::BootError>);

impl core::fmt::Display for Verdict {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            Ok(None) => f.write_str("none"),
            Ok(Some(Ok(()))) => f.write_str("ok"),
            Ok(Some(Err(code))) => write!(f, "refused {code}"),
            Err(_) => f.write_str("unreadable"),
        }
    }
}

/// Says why and fails the emulation.
fn fail(why: &str) -> ! {
    semihosting::eprint(format_args!("boottest: {why}\n"));
    semihosting::exit(false)
}

/// The watchdog's interrupt (the NMI): says so before its reset.
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    watchdog::on_nmi();
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    fail("panic")
}
