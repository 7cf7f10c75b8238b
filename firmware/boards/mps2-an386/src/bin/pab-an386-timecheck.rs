//! Checks the time driver on the emulated machine, across TIMER0's reloads: embassy's clock
//! never goes back and never jumps, read as fast as the core can around each 100 s wrap (every
//! other one with interrupts masked, so that the reads after the reload must count the pending
//! period themselves), and a timer never fires early. Prints one line per wrap through semihosting and exits 0 (or 1 with
//! what went wrong). Run it with virtual time, so that its 300 s take a second:
//!
//!     cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
//!         --bin pab-an386-timecheck -- -icount shift=10,sleep=off
//!
//! (`shift=10`: one instruction is 1.024 µs of virtual time; the executor's idle loop is not a
//! sleep under QEMU, so a finer shift would execute 10¹¹ instructions to reach the first wrap.)

#![no_std]
#![no_main]

use embassy_executor::Spawner;
use embassy_time::{Instant, Timer};
use pab_fw_an386::semihosting;
use pab_fw_an386::time_driver::{PERIOD_US, TimeDriver};

embassy_time_driver::time_driver_impl!(static TIME: TimeDriver = TimeDriver::new());

/// Wraps to cross.
const WRAPS: u64 = 4;
/// How far before and after each wrap the clock is read without pause, µs.
const WINDOW_US: u64 = 200_000;
/// The largest step allowed between two consecutive reads, µs (a read takes well under 1 µs of
/// emulated time; a lost or doubled period would be a step of 10⁸).
const MAX_STEP_US: u64 = 10_000;

#[embassy_executor::main]
async fn main(_spawner: Spawner) {
    TIME.start();
    let mut last = embassy_time_driver::now();
    for wrap in 1..=WRAPS {
        let boundary = wrap * u64::from(PERIOD_US);
        let wake = boundary - WINDOW_US;
        Timer::at(Instant::from_micros(wake)).await;
        let woke = embassy_time_driver::now();
        if woke < wake {
            fail(format_args!("the timer for {wake} us fired at {woke} us"));
        }
        // Every other wrap with interrupts masked across it: then the period interrupt cannot run
        // and every read after the reload must count the pending period itself.
        let masked = wrap % 2 == 0;
        let reads = if masked {
            critical_section::with(|_| read_across(boundary, &mut last))
        } else {
            read_across(boundary, &mut last)
        };
        semihosting::eprint(format_args!(
            "pab-an386-timecheck: wrap {wrap} at {boundary} us: woke at {woke} us, {reads} reads \
             across it{}, monotonic\n",
            if masked {
                " with interrupts masked"
            } else {
                ""
            }
        ));
    }
    semihosting::exit(true)
}

/// Reads the clock without pause from now to `WINDOW_US` past `boundary`; fails on a step back
/// or a jump. Returns how many reads it made.
fn read_across(boundary: u64, last: &mut u64) -> u32 {
    let mut reads: u32 = 0;
    loop {
        let now = embassy_time_driver::now();
        if now < *last {
            fail(format_args!(
                "the clock went back from {last} us to {now} us"
            ));
        }
        if now - *last > MAX_STEP_US && reads > 0 {
            fail(format_args!("the clock jumped from {last} us to {now} us"));
        }
        *last = now;
        reads = reads.saturating_add(1);
        if now >= boundary + WINDOW_US {
            return reads;
        }
    }
}

fn fail(why: core::fmt::Arguments<'_>) -> ! {
    semihosting::eprint(format_args!("pab-an386-timecheck: {why}\n"));
    semihosting::exit(false)
}

#[unsafe(no_mangle)]
extern "C" fn TIMER0() {
    TIME.on_period();
}

#[unsafe(no_mangle)]
extern "C" fn TIMER1() {
    TIME.on_alarm();
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    fail(format_args!("panic: {info}"))
}
