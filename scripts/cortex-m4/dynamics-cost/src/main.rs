//! # pab-dynamics-cost: Cortex-M4 instructions per step of the competitive dynamics
//!
//! Runs on the emulated board under `scripts/cortex-m4/dynamics-cost.sh`, which loads the TCG
//! plugin of `scripts/cortex-m4/insn-count.c`: it counts the instructions executed between a call
//! to [`pab_cost_begin`] and the next call to [`pab_cost_end`] and prints
//! `insn-count region N: COUNT`; after each region this program prints `pab-cost CASE CLASS`. An
//! empty region (the markers' own cost) comes first; the script subtracts it.
//!
//! Cases: groups of 4, 16 and 32 behaviours at DESIGN.md's defaults (dt = 1 ms, γ = 3), in two
//! shapes:
//!
//! - `chain-B`: behaviour i and i + 1 exclude each other (γ = 3 both ways: two exclusions per
//!   behaviour, the most a row may hold at dt/τ = 0.1), and every odd behaviour requires the one
//!   before it (the door's shape, repeated);
//! - `dense-B`: the same exclusions, and every behaviour requires every one before it (B − 1
//!   tanh per step, B (B − 1) / 2 presupposition factors: about the dearest a group can be at
//!   the defaults; requiring every other behaviour would add one tanh and B / 2 factors, and a
//!   cycle in which nothing can ever start).
//!
//! Each case runs 1 500 steps with every context on (activations, competition, saturation), each
//! step its own region; the script reports the median and the largest.

#![no_std]
#![no_main]

use core::hint::black_box;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, heprint};
use pab_core::dynamics::{Dynamics, GAMMA_ONE, ONE, Params};

/// Opens a region (the plugin's `begin`). Distinct from [`pab_cost_end`] by its body, so that no
/// pass merges the two.
#[inline(never)]
#[unsafe(no_mangle)]
pub extern "C" fn pab_cost_begin() {
    // SAFETY: a no-op; as an `asm!` without `nomem`, it is also a compiler barrier.
    unsafe { core::arch::asm!("nop", options(nostack, preserves_flags)) }
}

/// Closes a region (the plugin's `end`).
#[inline(never)]
#[unsafe(no_mangle)]
pub extern "C" fn pab_cost_end() {
    // SAFETY: no-ops; a compiler barrier, as above.
    unsafe { core::arch::asm!("nop", "nop", options(nostack, preserves_flags)) }
}

fn fail(what: &str) -> ! {
    heprint!("pab-dynamics-cost: {}\n", what);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}

/// One step as a caller pays it, out of line, the group reached through a pointer.
#[inline(never)]
fn measured_step(group: &mut Dynamics, contexts: &[i32]) -> u32 {
    pab_cost_begin();
    let gates = group.step(contexts);
    pab_cost_end();
    black_box(gates)
}

fn params(count: u8, dense: bool) -> Params {
    let mut p = Params::new();
    for _ in 0..count {
        if p.add_behaviour(500_000).is_err() {
            fail("add_behaviour");
        }
    }
    for i in 0..count.saturating_sub(1) {
        let both = p
            .exclude(i, i + 1, 3 * GAMMA_ONE)
            .and_then(|()| p.exclude(i + 1, i, 3 * GAMMA_ONE));
        if both.is_err() {
            fail("exclude");
        }
    }
    for i in 0..count {
        for j in 0..count {
            let wanted = if dense {
                j < i
            } else {
                i % 2 == 1 && j + 1 == i
            };
            if wanted && p.require(i, j).is_err() {
                fail("require");
            }
        }
    }
    p
}

fn run(name: &str, count: u8, dense: bool) {
    let mut group = match Dynamics::new(&params(count, dense)) {
        Ok(group) => group,
        Err(_) => fail("invalid parameters"),
    };
    let contexts = [ONE; 32];
    let mut opened = 0;
    for _ in 0..1_500 {
        opened |= measured_step(&mut group, black_box(&contexts[..usize::from(count)]));
        heprint!("pab-cost {}-{} step\n", name, count);
    }
    heprint!("pab-gates {}-{} {:#x}\n", name, count, opened);
}

#[entry]
fn main() -> ! {
    pab_cost_begin();
    pab_cost_end();
    heprint!("pab-cost calibrate empty\n");
    for count in [4, 16, 32] {
        run("chain", count, false);
        run("dense", count, true);
    }
    heprint!("pab-dynamics-cost: done\n");
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    fail("panic")
}
