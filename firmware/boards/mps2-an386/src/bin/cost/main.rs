//! # pab-an386-cost: Cortex-M4 instructions per frame, counted exactly
//!
//! Runs on the emulated board (QEMU `mps2-an386`) under `scripts/cortex-m4-cost.sh`, which loads
//! a TCG plugin (`scripts/cortex-m4/insn-count.c`) that counts the instructions executed between
//! a call to [`pab_cost_begin`] and the next call to [`pab_cost_end`] (a *region*). After each
//! region this program prints on the semihosting console what the region measured:
//!
//! ```text
//! insn-count region 7: 1043          <- the plugin
//! pab-cost walk-16 frame             <- this program: case, class
//! ```
//!
//! The script pairs each `pab-cost` line with the count before it, subtracts the count of an
//! empty region (the calls of the markers themselves) and prints a table. What is measured:
//!
//! - `calibrate`: an empty region, and hand-written loops whose length is known exactly (the
//!   method's validation: the plugin must count 2N+1 for N iterations);
//! - the benchmark nodes of `core/benches/common` (priority chains; longest walk, all active,
//!   full 16 × 32), each with the same frames as the x86_64 figures;
//! - the Take and Return nodes (`examples/take-and-return.toml`, loaded from the images
//!   `pabctl compile` makes, in `tables/`) under the example's traffic, frame by frame:
//!   `Arbiter::receive`, and for the arm node also `pab_app::BoardNode::on_frame`, the whole frame
//!   path of the node application (verdict, recipient, re-publication queued, poll);
//! - `systick`: the same region also timed by SysTick, for the cross-check under
//!   `-icount shift=0` (one instruction per ns; SysTick on the 25 MHz CPU clock ticks every 40).
//!
//! Every measured frame is the call as a caller pays it: argument set-up, the call, the return.

#![no_std]
#![no_main]

mod auth;
mod ble;
mod cases;
mod hbba;
mod take_and_return;
#[cfg(feature = "update-cost")]
mod update;
mod value_port;

use core::hint::black_box;

use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::entry;
use pab_core::{Arbiter, Id, Instant, PortVerdict, Reception};
use pab_fw_an386::semihosting;

/// Opens a region: the plugin starts counting after this function's first instruction. Its
/// address (`llvm-nm`) is the plugin's `begin`. Distinct from [`pab_cost_end`] by its body, so
/// that no pass merges the two.
#[inline(never)]
#[unsafe(no_mangle)]
pub extern "C" fn pab_cost_begin() {
    // SAFETY: a no-op; as an `asm!` without `nomem`, it is also a compiler barrier.
    unsafe { core::arch::asm!("nop", options(nostack, preserves_flags)) }
}

/// Closes a region: the plugin stops counting at this function's first instruction.
#[inline(never)]
#[unsafe(no_mangle)]
pub extern "C" fn pab_cost_end() {
    // SAFETY: no-ops; a compiler barrier, as above.
    unsafe { core::arch::asm!("nop", "nop", options(nostack, preserves_flags)) }
}

/// Prints what the region just closed measured: `pab-cost CASE CLASS`.
pub fn report(case: &str, class: &str) {
    semihosting::eprint(format_args!("pab-cost {case} {class}\n"));
}

/// Stops with a message: the script fails on the exit status.
pub fn fail(what: core::fmt::Arguments<'_>) -> ! {
    semihosting::eprint(format_args!("pab-an386-cost: {what}\n"));
    semihosting::exit(false)
}

/// One `Arbiter::receive` as the benchmarks make it (the verdict handed to an opaque consumer),
/// measured as one region. Out of line and given the arbiter by reference, as the node
/// application holds its own: the arbiter is then reached through a pointer, not at some large
/// offset in the caller's stack frame, and this function's own set-up is outside the region.
#[inline(never)]
pub fn measured_receive<const P: usize, const C: usize, const N: usize>(
    arbiter: &mut Arbiter<P, C, N>,
    id: &Id,
    now: Instant,
) -> Reception {
    measure(|| {
        arbiter.receive(id, now, |verdict: &PortVerdict| {
            black_box(verdict);
        })
    })
}

/// `Arbiter::receive` unmeasured (set-up, and the SysTick cross-check's loop).
#[inline(always)]
pub fn receive<const P: usize, const C: usize, const N: usize>(
    arbiter: &mut Arbiter<P, C, N>,
    id: &Id,
    now: Instant,
) -> Reception {
    arbiter.receive(id, now, |verdict: &PortVerdict| {
        black_box(verdict);
    })
}

/// Runs `body` as one region; the caller then [`report`]s what it was. The result goes through
/// `black_box` after the region closes, so that nothing computed from it is scheduled inside.
#[inline(always)]
pub fn measure<R>(body: impl FnOnce() -> R) -> R {
    pab_cost_begin();
    let result = body();
    pab_cost_end();
    black_box(result)
}

#[entry]
fn main() -> ! {
    let mut peripherals =
        cortex_m::Peripherals::take().unwrap_or_else(|| fail(format_args!("peripherals taken")));
    calibrate(&mut peripherals.SYST);
    cases::run(&mut peripherals.SYST);
    take_and_return::run();
    auth::run();
    ble::run();
    value_port::run();
    hbba::run();
    #[cfg(feature = "update-cost")]
    update::run();
    semihosting::eprint(format_args!("pab-an386-cost: done\n"));
    semihosting::exit(true)
}

/// One whole region in a single `asm!`: the begin marker, `N` iterations of a two-instruction
/// loop after one `movw` (exactly 2N + 1 instructions), the end marker. Nothing the compiler
/// schedules can land inside it, so the empty region (N = 0: no loop at all) is exactly the
/// markers' own cost, and the loops must count exactly 2N + 1 more.
macro_rules! known_region {
    () => {
        // SAFETY: calls the two markers, `extern "C"` functions without arguments that change no
        // memory; the clobbers are what the AAPCS lets a call overwrite (`clobber_abi("C")` would
        // also name D16-D31, which this FPU does not have).
        unsafe {
            core::arch::asm!(
                "bl {begin}",
                "bl {end}",
                begin = sym pab_cost_begin,
                end = sym pab_cost_end,
                out("r0") _, out("r1") _, out("r2") _, out("r3") _, out("r12") _, out("lr") _,
                out("s0") _, out("s1") _, out("s2") _, out("s3") _, out("s4") _, out("s5") _,
                out("s6") _, out("s7") _, out("s8") _, out("s9") _, out("s10") _, out("s11") _,
                out("s12") _, out("s13") _, out("s14") _, out("s15") _,
            )
        }
    };
    ($n:literal) => {
        // SAFETY: as above; the loop counts a scratch register down to zero.
        unsafe {
            core::arch::asm!(
                "bl {begin}",
                concat!("movw {n}, #", $n),
                "2:",
                "subs {n}, {n}, #1",
                "bne 2b",
                "bl {end}",
                begin = sym pab_cost_begin,
                end = sym pab_cost_end,
                n = out(reg) _,
                out("r0") _, out("r1") _, out("r2") _, out("r3") _, out("r12") _, out("lr") _,
                out("s0") _, out("s1") _, out("s2") _, out("s3") _, out("s4") _, out("s5") _,
                out("s6") _, out("s7") _, out("s8") _, out("s9") _, out("s10") _, out("s11") _,
                out("s12") _, out("s13") _, out("s14") _, out("s15") _,
            )
        }
    };
}

/// `N` iterations of the same loop without markers, for the SysTick cross-check's region.
macro_rules! known_loop {
    ($n:literal) => {
        // SAFETY: counts a scratch register down to zero; touches nothing else.
        unsafe {
            core::arch::asm!(
                concat!("movw {n}, #", $n),
                "2:",
                "subs {n}, {n}, #1",
                "bne 2b",
                n = out(reg) _,
                options(nomem, nostack),
            )
        }
    };
}

/// The method's own checks: an empty region (subtracted from every other), and loops of known
/// length, which the script requires to be counted exactly.
fn calibrate(syst: &mut SYST) {
    known_region!();
    report("calibrate", "empty");
    known_region!(10);
    report("calibrate", "loop-10");
    known_region!(1000);
    report("calibrate", "loop-1000");
    // The SysTick cross-check on the known loop: 2 · 60000 + 1 instructions, 3000 ticks.
    start_systick(syst);
    let ticks = measure(|| {
        let before = SYST::get_current();
        known_loop!(60000);
        let after = SYST::get_current();
        elapsed_ticks(before, after)
    });
    report("systick", "loop-60000");
    semihosting::eprint(format_args!("pab-systick loop-60000 1 {ticks}\n"));
}

/// SysTick counting down from 2^24 − 1 on the processor clock, without interrupts.
pub fn start_systick(syst: &mut SYST) {
    syst.disable_interrupt();
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_counter();
}

/// Ticks from `before` to `after` on the 24-bit down-counter (at most one wrap).
pub fn elapsed_ticks(before: u32, after: u32) -> u32 {
    before.wrapping_sub(after) & 0x00FF_FFFF
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    fail(format_args!("panic: {info}"))
}
