//! embassy-time's driver on the AN386: 1 MHz ticks from two CMSDK APB timers.
//!
//! - **Clock**: TIMER0 counts down at PCLK (25 MHz) from [`RELOAD`] and wraps every
//!   `RELOAD + 1` = 2.5·10⁹ ticks, exactly 100 s; its interrupt counts the periods. Now, in µs,
//!   is `periods · 10⁸ + (RELOAD − VALUE) / 25`: a 32-bit division (one `udiv`) and a 32×32→64
//!   multiplication, no 64-bit division (a library call on the Cortex-M4). 32 bits of periods
//!   last 13 600 years.
//! - **Alarm**: TIMER1, armed for the next expiration of the timer queue (at most 100 s ahead:
//!   a later one is reached by re-arming), stopped in its interrupt, which wakes what is due.
//! - **Queue**: embassy-time-queue-utils' queue in a critical-section mutex, as the
//!   embassy-time-driver documentation shows.
//!
//! Monotonic across a wrap: `now` reads the pending flag, the counter and the flag again inside
//! a critical section (so the period interrupt cannot run in between) and retries if the flag
//! changed. A pending flag with the counter already reloaded means the period is over but not
//! yet counted: it adds one. (In QEMU the flag and the reload happen together; on silicon the
//! counter holds 0 for one PCLK cycle after the flag, which counts as the end of the period.)
//!
//! Cost: `now` is three peripheral reads and a handful of instructions in a critical section.

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use core::task::Waker;

use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use crate::cmsdk::{PCLK_HZ, TIMER0, TIMER1, Timer};
use crate::interrupts::{self, Interrupt};

/// PCLK ticks per microsecond.
const TICKS_PER_US: u32 = PCLK_HZ / 1_000_000;
const _: () = assert!(TICKS_PER_US * 1_000_000 == PCLK_HZ);
/// Microseconds per TIMER0 period.
pub const PERIOD_US: u32 = 100_000_000;
/// TIMER0's reload value: `RELOAD + 1` ticks are one period of [`PERIOD_US`].
pub const RELOAD: u32 = PERIOD_US * TICKS_PER_US - 1;
/// The farthest an alarm is armed ahead, in µs (its tick count must fit TIMER1's 32 bits).
const MAX_ALARM_US: u64 = PERIOD_US as u64;

/// The driver's state. One instance, registered with [`embassy_time_driver::time_driver_impl`]
/// by the binary, which also routes the TIMER0 and TIMER1 interrupts to [`Self::on_period`] and
/// [`Self::on_alarm`].
pub struct TimeDriver {
    started: AtomicBool,
    periods: AtomicU32,
    queue: Mutex<RefCell<Queue>>,
}

impl Default for TimeDriver {
    fn default() -> Self {
        Self::new()
    }
}

impl TimeDriver {
    /// A driver whose clock reads 0 until [`Self::start`].
    pub const fn new() -> Self {
        TimeDriver {
            started: AtomicBool::new(false),
            periods: AtomicU32::new(0),
            queue: Mutex::new(RefCell::new(Queue::new())),
        }
    }

    /// Starts the clock at 0 and enables both timers' interrupts. Call once, before the executor.
    pub fn start(&self) {
        critical_section::with(|_| {
            TIMER1.set_control(0);
            TIMER1.clear();
            TIMER0.set_control(0);
            TIMER0.clear();
            TIMER0.set_reload(RELOAD);
            TIMER0.set_control(Timer::ENABLE | Timer::IRQ_ENABLE);
            self.periods.store(0, Ordering::Relaxed);
            self.started.store(true, Ordering::Relaxed);
        });
        interrupts::enable(Interrupt::TIMER0);
        interrupts::enable(Interrupt::TIMER1);
    }

    /// TIMER0's interrupt: one more period.
    pub fn on_period(&self) {
        critical_section::with(|_| {
            if TIMER0.pending() {
                TIMER0.clear();
                self.periods.fetch_add(1, Ordering::Relaxed);
            }
        });
    }

    /// TIMER1's interrupt: wakes what is due and arms the next alarm.
    pub fn on_alarm(&self) {
        critical_section::with(|cs| {
            TIMER1.set_control(0);
            TIMER1.clear();
            self.arm_next(cs);
        });
    }

    fn arm_next(&self, cs: CriticalSection<'_>) {
        let mut queue = crate::borrow_mut(self.queue.borrow(cs));
        let mut next = queue.next_expiration(self.now_in(cs));
        while !self.set_alarm(cs, next) {
            next = queue.next_expiration(self.now_in(cs));
        }
    }

    /// Arms TIMER1 to fire at `at` (or at most [`MAX_ALARM_US`] ahead); false if `at` has
    /// passed (the caller then wakes what is due and asks again).
    fn set_alarm(&self, cs: CriticalSection<'_>, at: u64) -> bool {
        TIMER1.set_control(0);
        TIMER1.clear();
        if at == u64::MAX {
            return true;
        }
        let now = self.now_in(cs);
        if at <= now {
            return false;
        }
        // ≤ 10⁸ µs, so ≤ 2.5·10⁹ ticks: fits in u32. The alarm fires `ticks` ticks after now,
        // so never before `at`.
        let delta_us = (at - now).min(MAX_ALARM_US) as u32;
        TIMER1.set_reload(delta_us * TICKS_PER_US);
        TIMER1.set_control(Timer::ENABLE | Timer::IRQ_ENABLE);
        true
    }

    fn now_in(&self, _cs: CriticalSection<'_>) -> u64 {
        if !self.started.load(Ordering::Relaxed) {
            return 0;
        }
        let (pending, value) = loop {
            let before = TIMER0.pending();
            let value = TIMER0.value();
            if TIMER0.pending() == before {
                break (before, value);
            }
        };
        // A pending flag with a reloaded counter: the period ended and is not counted yet.
        let wrapped = pending && value != 0;
        let periods = u64::from(self.periods.load(Ordering::Relaxed)) + u64::from(wrapped);
        let elapsed_ticks = RELOAD.saturating_sub(value);
        periods * u64::from(PERIOD_US) + u64::from(elapsed_ticks / TICKS_PER_US)
    }
}

impl Driver for TimeDriver {
    /// Out of line: five callers (embassy-time's and the node's) inlined its critical section
    /// (28 bytes of the emulated board's flash).
    #[inline(never)]
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_in(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let scheduled = crate::borrow_mut(self.queue.borrow(cs)).schedule_wake(at, waker);
            if scheduled {
                self.arm_next(cs);
            }
        });
    }
}
