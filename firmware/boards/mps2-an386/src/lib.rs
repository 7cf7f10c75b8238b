//! # pab-fw-an386: board support for the emulated Cortex-M4 (QEMU `mps2-an386`)
//!
//! Arm's MPS2 board with the AN386 FPGA image is a Cortex-M4 that QEMU emulates faithfully
//! enough to run the node firmware unchanged: the same `pab-app`, built for
//! `thumbv7em-none-eabihf` like the NUCLEO-G474RE's. It has no CAN controller, so its CAN
//! traffic goes over UART0 as SLCAN ([`slcan_bus`]), which the host's `slcan` driver turns into a
//! SocketCAN interface; and no flash controller, so its table store is a region of its code RAM
//! with flash semantics ([`ram_flash`]). What is here is what the binaries share:
//!
//! - [`interrupts`]: the vector table (cortex-m-rt's `device` feature) and the NVIC lines;
//! - [`cmsdk`]: the CMSDK APB timers and UART, register by register;
//! - [`time_driver`]: embassy-time's driver (TIMER0 as the clock, TIMER1 as the alarm);
//! - [`uart`], [`slcan_bus`]: UART0 with rings, and the node's bus over it;
//! - [`ram_flash`]: the table store's flash;
//! - [`logger`], [`semihosting`]: text on QEMU's standard error, and the exit status.
//! - [`watchdog`]: the node loop's watchdog (the CMSDK APB watchdog at 0x4000_8000).
//! - `boot` (feature `boot`): the application's side of the bootloader (firmware/boot/mps2-an386).
//!
//! Memory map (QEMU's model of AN386, `memory.x`): code RAM (SSRAM1) at 0x0000_0000 (program
//! below 0x0004_0000, table store 0x0004_0000..0x0004_C000), data RAM (SSRAM2/3) at 0x2000_0000,
//! APB peripherals at 0x4000_0000 (timers 0x4000_0000 and 0x4000_1000, IRQ 8 and 9; dual timer
//! 0x4000_2000; UART0 0x4000_4000, RX IRQ 0, TX IRQ 1).

#![no_std]

// The boards' memcpy, memset, memcmp and 64-bit division (firmware/builtins): 2.5 KB less flash
// than compiler_builtins'.
use pab_builtins as _;

#[cfg(feature = "boot")]
pub mod boot;
pub mod cmsdk;
pub mod interrupts;
pub mod logger;
pub mod ram_flash;
pub mod semihosting;
pub mod slcan_bus;
pub mod time_driver;
pub mod uart;
pub mod watchdog;

/// `cell.borrow_mut()` (the RefCells of [`time_driver`] and [`uart`], within their critical
/// sections), and the same panic if it is borrowed already: the caller's location and
/// RefCell's message, here a literal. RefCell's own panic formats its `BorrowMutError`, whose
/// `Display` was the last user of `core::fmt`'s padding in the firmware (642 bytes of flash).
#[track_caller]
pub(crate) fn borrow_mut<T>(cell: &core::cell::RefCell<T>) -> core::cell::RefMut<'_, T> {
    match cell.try_borrow_mut() {
        Ok(borrowed) => borrowed,
        Err(_) => panic!("RefCell already borrowed"),
    }
}
