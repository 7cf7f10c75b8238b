//! embassy-time's driver on TIM2, the F446's 32-bit general-purpose timer: 1 MHz ticks whose
//! count no flash stall can lose.
//!
//! Why not embassy-stm32's driver (`time-driver-tim2`): it runs every timer as a 16-bit counter
//! and counts its half-wraps in the timer's interrupts, one every 32.8 ms at 1 MHz; a flag can
//! hold one of each kind, so a CPU that cannot take interrupts for 65.5 ms or more loses whole
//! wraps, and the clock goes back by multiples of 65.5 ms. Erasing a sector of this single-bank
//! flash stalls every fetch from it, the interrupts' included, for 250 ms typical (16 KiB
//! sector, up to 500 ms; 1 to 2 s for the boot counter's 128 KiB sectors: `crate::sector_flash`):
//! every table save would set the node's clock back.
//!
//! - **Clock**: TIM2 counts up at 1 MHz (its 80 MHz kernel clock, [`crate::TIM2_HZ`], divided by
//!   80) over all 32 bits and wraps every 2^32 µs, 71.6 minutes; its update interrupt counts the
//!   wraps. Now, in µs, is `wraps · 2^32 + count`. A stall would have to last half an hour to
//!   lose a wrap.
//! - **Monotonic across a wrap**: `now` reads the count, then the update flag, in a critical
//!   section (so the interrupt cannot count the wrap in between): a pending flag with a count in
//!   the lower half means the counter wrapped before it was read and the wrap is not counted yet,
//!   so it adds one; with a count in the upper half the count was read just before the wrap.
//! - **Alarm**: compare channel 1, armed for the next expiration of the timer queue, at most half
//!   a wrap ahead (a later one fires early and is re-armed). A compare that falls due while the
//!   CPU stalls sets its flag all the same, and its interrupt runs when the stall ends.
//! - **Queue**: embassy-time-queue-utils' queue in a critical-section mutex, as the
//!   embassy-time-driver documentation shows.
//!
//! Not run on hardware yet (docs/nucleo-f446re.md says so).

use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;

use critical_section::{CriticalSection, Mutex};
use embassy_stm32::Peri;
use embassy_stm32::interrupt::typelevel::{Handler, Interrupt as _, TIM2 as Tim2Interrupt};
use embassy_stm32::pac::timer::regs::SrGp16;
use embassy_stm32::pac::{RCC, TIM2};
use embassy_stm32::peripherals::TIM2 as Tim2Peripheral;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

/// TIM2's prescaler: its kernel clock down to embassy-time's 1 MHz tick.
const PRESCALER: u32 = crate::TIM2_HZ / 1_000_000 - 1;
const _: () = assert!(
    (PRESCALER + 1) * 1_000_000 == crate::TIM2_HZ
        && PRESCALER <= 0xFFFF
        && embassy_time_driver::TICK_HZ == 1_000_000,
    "TIM2's clock must be a whole number of MHz, and embassy-time's tick 1 MHz"
);
/// The farthest ahead an alarm is armed, in ticks: half a wrap, so that the compare value is
/// never mistaken for one a wrap earlier.
const MAX_ALARM_TICKS: u64 = 1 << 31;

/// The driver's state, registered with [`embassy_time_driver::time_driver_impl`] below.
pub struct TimeDriver {
    /// Counter wraps counted by the update interrupt.
    wraps: AtomicU32,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: TimeDriver = TimeDriver {
    wraps: AtomicU32::new(0),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Starts the clock at 0 and enables TIM2's interrupt. Call once, after the clocks are set up
/// (`embassy_stm32::init`) and before anything reads the time: until then it reads 0. Takes the
/// peripheral, so that nothing else drives TIM2.
pub fn start(_tim2: Peri<'static, Tim2Peripheral>) {
    RCC.apb1enr().modify(|w| w.set_tim2en(true));
    // The prescaler takes effect at the next update event: generate one (the update interrupt
    // is still off, so it only loads the prescaler and zeroes the count).
    TIM2.psc().write_value(PRESCALER as u16);
    TIM2.arr().write_value(u32::MAX);
    TIM2.egr().write(|w| w.set_ug(true));
    TIM2.sr().write_value(SrGp16(0));
    TIM2.dier().write(|w| w.set_uie(true));
    TIM2.cr1().modify(|w| w.set_cen(true));
    Tim2Interrupt::unpend();
    // SAFETY: the handler ([`Interrupt`]) is bound in main.rs and touches only this driver's
    // state, under critical sections.
    unsafe { Tim2Interrupt::enable() };
}

/// TIM2's interrupt: counts a wrap, and wakes what is due when the alarm fires.
pub struct Interrupt;

impl Handler<Tim2Interrupt> for Interrupt {
    unsafe fn on_interrupt() {
        critical_section::with(|cs| {
            let sr = TIM2.sr().read();
            let alarm = sr.ccif(0) && TIM2.dier().read().ccie(0);
            // The flags are cleared by writing 0: clear those that were read set, and only
            // those (a flag set since the read stays).
            TIM2.sr().write_value(SrGp16(!sr.0));
            if sr.uif() {
                DRIVER.wraps.fetch_add(1, Ordering::Relaxed);
            }
            if alarm {
                DRIVER.arm_next(cs);
            }
        });
    }
}

impl TimeDriver {
    fn now_in(&self, _cs: CriticalSection<'_>) -> u64 {
        let count = TIM2.cnt().read();
        let pending = TIM2.sr().read().uif() && count < 1 << 31;
        let wraps = u64::from(self.wraps.load(Ordering::Relaxed)) + u64::from(pending);
        wraps << 32 | u64::from(count)
    }

    fn arm_next(&self, cs: CriticalSection<'_>) {
        let mut queue = self.queue.borrow_ref_mut(cs);
        let mut next = queue.next_expiration(self.now_in(cs));
        while !self.set_alarm(cs, next) {
            next = queue.next_expiration(self.now_in(cs));
        }
    }

    /// Arms compare channel 1 for `at` (or for at most [`MAX_ALARM_TICKS`] ahead); false if `at`
    /// has passed (the caller then wakes what is due and asks again).
    fn set_alarm(&self, cs: CriticalSection<'_>, at: u64) -> bool {
        TIM2.dier().modify(|w| w.set_ccie(0, false));
        if at == u64::MAX {
            return true;
        }
        let now = self.now_in(cs);
        if at <= now {
            return false;
        }
        let target = at.min(now + MAX_ALARM_TICKS);
        // The low 32 bits: the count the counter reaches at `target`, within half a wrap.
        TIM2.ccr(0).write_value(target as u32);
        // A match of an earlier compare value must not fire this alarm.
        let mut clear = SrGp16(u32::MAX);
        clear.set_ccif(0, false);
        TIM2.sr().write_value(clear);
        TIM2.dier().modify(|w| w.set_ccie(0, true));
        // A counter that passed the compare value before it was written matches only a wrap
        // later: then the alarm's time has come, and the caller wakes what is due.
        self.now_in(cs) < target
    }
}

impl Driver for TimeDriver {
    /// Out of line, as the emulated board's: embassy-time's and the node's callers would each
    /// inline the critical section.
    #[inline(never)]
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_in(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let scheduled = self.queue.borrow_ref_mut(cs).schedule_wake(at, waker);
            if scheduled {
                self.arm_next(cs);
            }
        });
    }
}
