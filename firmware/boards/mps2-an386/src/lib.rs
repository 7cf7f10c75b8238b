//! # pab-fw-an386: board support for the emulated Cortex-M4 (QEMU `mps2-an386`)
//!
//! Arm's MPS2 board with the AN386 FPGA image is a Cortex-M4 that QEMU emulates faithfully
//! enough to run the node firmware unchanged: the same `pab-app`, built for
//! `thumbv7em-none-eabihf` like the NUCLEO-G474RE's. It has no CAN controller, so its CAN
//! traffic goes over a UART; and no flash controller, so its table store is a region of its
//! code RAM with flash semantics. What is here is what the binaries share.
//!
//! Memory map (QEMU's model of AN386, `memory.x`): code RAM (SSRAM1) at 0x0000_0000, data RAM
//! (SSRAM2/3) at 0x2000_0000, APB peripherals at 0x4000_0000 (timers 0x4000_0000 and
//! 0x4000_1000, IRQ 8 and 9; UART0 0x4000_4000, RX IRQ 0, TX IRQ 1).

#![no_std]

pub mod semihosting;
