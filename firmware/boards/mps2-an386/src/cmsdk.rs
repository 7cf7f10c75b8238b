//! Register access to the CMSDK APB peripherals of the AN386 (timers, dual timer, UART), at the
//! addresses of QEMU's model (`hw/arm/mps2.c`). Layouts: Arm DDI0479C, and QEMU's
//! `hw/timer/cmsdk-apb-timer.c`, `hw/timer/cmsdk-apb-dualtimer.c`, `hw/char/cmsdk-apb-uart.c`.
//!
//! Every access is one volatile 32-bit load or store; nothing here keeps state.

use core::ptr;

/// The peripheral clock (PCLK) of the AN386 in QEMU: 25 MHz, which clocks the timers and UARTs.
pub const PCLK_HZ: u32 = 25_000_000;

/// One 32-bit register.
#[derive(Clone, Copy)]
struct Reg(usize);

impl Reg {
    #[inline(always)]
    fn read(self) -> u32 {
        // SAFETY: the address is a register of a peripheral of this machine, 4-byte aligned.
        unsafe { ptr::read_volatile(self.0 as *const u32) }
    }

    #[inline(always)]
    fn write(self, value: u32) {
        // SAFETY: as for `read`; these registers have no memory side effects beyond the device.
        unsafe { ptr::write_volatile(self.0 as *mut u32, value) }
    }
}

/// A CMSDK APB timer: a 32-bit down-counter at PCLK that interrupts on reaching zero, then
/// reloads (`RELOAD + 1` ticks per period).
#[derive(Clone, Copy)]
pub struct Timer {
    base: usize,
}

/// Timer 0 (IRQ 8).
pub const TIMER0: Timer = Timer { base: 0x4000_0000 };
/// Timer 1 (IRQ 9).
pub const TIMER1: Timer = Timer { base: 0x4000_1000 };

impl Timer {
    /// CTRL: counting.
    pub const ENABLE: u32 = 1 << 0;
    /// CTRL: interrupt on reaching zero.
    pub const IRQ_ENABLE: u32 = 1 << 3;

    /// Writes CTRL.
    #[inline(always)]
    pub fn set_control(self, value: u32) {
        Reg(self.base).write(value);
    }

    /// The counter.
    #[inline(always)]
    pub fn value(self) -> u32 {
        Reg(self.base + 0x4).read()
    }

    /// Sets RELOAD and the counter.
    #[inline(always)]
    pub fn set_reload(self, value: u32) {
        Reg(self.base + 0x8).write(value);
    }

    /// Whether the interrupt is pending (INTSTATUS).
    #[inline(always)]
    pub fn pending(self) -> bool {
        Reg(self.base + 0xC).read() & 1 != 0
    }

    /// Clears the interrupt (INTCLEAR).
    #[inline(always)]
    pub fn clear(self) {
        Reg(self.base + 0xC).write(1);
    }
}

/// The first half of the CMSDK APB dual timer (0x4000_2000).
#[derive(Clone, Copy)]
pub struct DualTimer1;

impl DualTimer1 {
    const BASE: usize = 0x4000_2000;
    /// CONTROL: one-shot.
    pub const ONE_SHOT: u32 = 1 << 0;
    /// CONTROL: 32-bit counter.
    pub const SIZE_32: u32 = 1 << 1;
    /// CONTROL: periodic mode (the counter reloads from LOAD).
    pub const PERIODIC: u32 = 1 << 6;
    /// CONTROL: counting.
    pub const ENABLE: u32 = 1 << 7;

    /// Writes CONTROL.
    #[inline(always)]
    pub fn set_control(self, value: u32) {
        Reg(Self::BASE + 0x8).write(value);
    }

    /// Writes LOAD (and the counter); a one-shot timer that had expired starts again.
    #[inline(always)]
    pub fn set_load(self, value: u32) {
        Reg(Self::BASE).write(value);
    }
}

/// A CMSDK APB UART: 8N1, one byte of buffer each way.
#[derive(Clone, Copy)]
pub struct Uart {
    base: usize,
}

/// UART0 (RX IRQ 0, TX IRQ 1): QEMU's first serial port (`-serial`).
pub const UART0: Uart = Uart { base: 0x4000_4000 };

impl Uart {
    /// STATE: a byte waits in the transmit buffer.
    pub const TX_FULL: u32 = 1 << 0;
    /// STATE: a byte waits in the receive buffer.
    pub const RX_FULL: u32 = 1 << 1;
    /// STATE: a byte arrived while the receive buffer was full (write 1 to clear).
    pub const RX_OVERRUN: u32 = 1 << 3;
    /// CTRL: transmitter on.
    pub const TX_ENABLE: u32 = 1 << 0;
    /// CTRL: receiver on.
    pub const RX_ENABLE: u32 = 1 << 1;
    /// CTRL: interrupt when the transmit buffer empties.
    pub const TX_IRQ: u32 = 1 << 2;
    /// CTRL: interrupt when a byte arrives.
    pub const RX_IRQ: u32 = 1 << 3;
    /// INTSTATUS/INTCLEAR: transmit interrupt.
    pub const INT_TX: u32 = 1 << 0;
    /// INTSTATUS/INTCLEAR: receive interrupt.
    pub const INT_RX: u32 = 1 << 1;

    /// Reads the receive buffer (and empties it).
    #[inline(always)]
    pub fn read_data(self) -> u8 {
        Reg(self.base).read() as u8
    }

    /// Writes the transmit buffer.
    #[inline(always)]
    pub fn write_data(self, byte: u8) {
        Reg(self.base).write(u32::from(byte));
    }

    /// STATE.
    #[inline(always)]
    pub fn state(self) -> u32 {
        Reg(self.base + 0x4).read()
    }

    /// Clears STATE's overrun bits given in `bits`.
    #[inline(always)]
    pub fn clear_state(self, bits: u32) {
        Reg(self.base + 0x4).write(bits);
    }

    /// CTRL.
    #[inline(always)]
    pub fn control(self) -> u32 {
        Reg(self.base + 0x8).read()
    }

    /// Writes CTRL.
    #[inline(always)]
    pub fn set_control(self, value: u32) {
        Reg(self.base + 0x8).write(value);
    }

    /// Clears the interrupts given in `bits` (INTCLEAR).
    #[inline(always)]
    pub fn clear_interrupts(self, bits: u32) {
        Reg(self.base + 0xC).write(bits);
    }

    /// Writes BAUDDIV (PCLK cycles per bit, at least 16, or the UART neither sends nor receives).
    #[inline(always)]
    pub fn set_baud_divisor(self, value: u32) {
        Reg(self.base + 0x10).write(value);
    }
}

/// The CMSDK APB watchdog (0x4000_8000), as QEMU's `mps2-an386` maps it (a real model since QEMU
/// 6.0, clocked by the 25 MHz system clock; its interrupt is the core's NMI). It counts LOAD down
/// at PCLK; at zero it raises its interrupt and reloads; at zero again with the interrupt still
/// raised and RESEN set it resets the system (in QEMU: `watchdog_perform_action`, whose default
/// action is a system reset, the same as the monitor's `system_reset`). Writing INTCLR clears the
/// interrupt and reloads the counter: that is the feed. Layout: Arm DDI0479C, section 4.4.
#[derive(Clone, Copy)]
pub struct Watchdog;

impl Watchdog {
    const BASE: usize = 0x4000_8000;
    /// CONTROL: counter and interrupt on.
    pub const INTEN: u32 = 1 << 0;
    /// CONTROL: reset output on.
    pub const RESEN: u32 = 1 << 1;
    /// The LOCK key that opens the registers; any other value closes them.
    const UNLOCK: u32 = 0x1ACC_E551;

    /// Writes LOAD (and the counter).
    #[inline(always)]
    pub fn set_load(self, value: u32) {
        Reg(Self::BASE).write(value);
    }

    /// Writes CONTROL.
    #[inline(always)]
    pub fn set_control(self, value: u32) {
        Reg(Self::BASE + 0x8).write(value);
    }

    /// Clears the interrupt and reloads the counter (INTCLR).
    #[inline(always)]
    pub fn clear(self) {
        Reg(Self::BASE + 0xC).write(1);
    }

    /// Opens (`true`) or closes the registers to writes (LOCK).
    #[inline(always)]
    pub fn unlock(self, open: bool) {
        Reg(Self::BASE + 0xC00).write(if open { Self::UNLOCK } else { 0 });
    }
}
