//! Boot check of the emulated board: prints one line through semihosting and exits with 0.
//! (The node firmware replaces it.)

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use pab_fw_an386::semihosting;

#[entry]
fn main() -> ! {
    semihosting::eprint(format_args!("pab-fw-an386: booted\n"));
    semihosting::exit(true)
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    semihosting::exit(false)
}
