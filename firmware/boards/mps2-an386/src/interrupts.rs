//! The AN386's interrupt lines and its vector table (what a PAC would provide).
//!
//! QEMU's model (`hw/arm/mps2.c`) has 32 external interrupts. The table names the ones this
//! crate uses; a binary defines a handler by its name (`#[unsafe(no_mangle)] extern "C" fn
//! TIMER0()`), and `device.x` points every name no binary defines at `DefaultHandler`.

use cortex_m::interrupt::InterruptNumber;

/// The external interrupts this crate uses, by their line number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Interrupt {
    /// UART0 received a byte.
    UART0RX = 0,
    /// UART0's transmit holding register emptied.
    UART0TX = 1,
    /// UART1 received a byte.
    UART1RX = 2,
    /// UART1 transmitted.
    UART1TX = 3,
    /// UART2 received a byte.
    UART2RX = 4,
    /// UART2 transmitted.
    UART2TX = 5,
    /// CMSDK APB timer 0 (0x4000_0000) reached zero.
    TIMER0 = 8,
    /// CMSDK APB timer 1 (0x4000_1000) reached zero.
    TIMER1 = 9,
    /// The dual timer (0x4000_2000), either half.
    DUALTIMER = 10,
    /// An overrun of any UART.
    UARTOVF = 12,
    /// The last line, which no peripheral raises unless the firmware enables it (none does):
    /// pended in software, for embassy's interrupt executor.
    SOFTWARE = 31,
}

// SAFETY: every variant is a line number of the AN386 (below its 32 interrupts).
unsafe impl InterruptNumber for Interrupt {
    fn number(self) -> u16 {
        self as u16
    }
}

/// Lines of the AN386 (QEMU's `num-irq` for mps2-an386).
pub const LINES: usize = 32;

type Vector = unsafe extern "C" fn();

unsafe extern "C" {
    fn UART0RX();
    fn UART0TX();
    fn UART1RX();
    fn UART1TX();
    fn UART2RX();
    fn UART2TX();
    fn TIMER0();
    fn TIMER1();
    fn DUALTIMER();
    fn UARTOVF();
    fn SOFTWARE();
    fn DefaultHandler();
}

/// The device-specific part of the vector table, after cortex-m-rt's 16 exception vectors.
#[doc(hidden)]
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
pub static __INTERRUPTS: [Vector; LINES] = {
    let mut table: [Vector; LINES] = [DefaultHandler; LINES];
    table[Interrupt::UART0RX as usize] = UART0RX;
    table[Interrupt::UART0TX as usize] = UART0TX;
    table[Interrupt::UART1RX as usize] = UART1RX;
    table[Interrupt::UART1TX as usize] = UART1TX;
    table[Interrupt::UART2RX as usize] = UART2RX;
    table[Interrupt::UART2TX as usize] = UART2TX;
    table[Interrupt::TIMER0 as usize] = TIMER0;
    table[Interrupt::TIMER1 as usize] = TIMER1;
    table[Interrupt::DUALTIMER as usize] = DUALTIMER;
    table[Interrupt::UARTOVF as usize] = UARTOVF;
    table[Interrupt::SOFTWARE as usize] = SOFTWARE;
    table
};

/// Sets `interrupt`'s priority (0 highest; the top bits count, the AN386 has at least 3).
pub fn set_priority(interrupt: Interrupt, priority: u8) {
    // SAFETY: changing a priority cannot break a critical section (cortex-m's single-core
    // critical sections mask all interrupts, whatever their priority).
    unsafe {
        let mut peripherals = cortex_m::Peripherals::steal();
        peripherals.NVIC.set_priority(interrupt, priority);
    }
}

/// Enables `interrupt` in the NVIC.
pub fn enable(interrupt: Interrupt) {
    // SAFETY: the handlers of this crate's interrupts are ready before their sources are
    // configured; unmasking cannot break a critical section (this is not one).
    unsafe { cortex_m::peripheral::NVIC::unmask(interrupt) }
}
