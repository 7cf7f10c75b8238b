//! # pab-schema-cost: Cortex-M4 instructions per tick of the schema server
//!
//! Runs on the emulated board under `scripts/cortex-m4/schema-cost.sh`, which loads the TCG
//! plugin of `scripts/cortex-m4/insn-count.c`: it counts the instructions executed between a call
//! to [`pab_cost_begin`] and the next call to [`pab_cost_end`] and prints
//! `insn-count region N: COUNT`; after each region this program prints `pab-cost CASE CLASS`. An
//! empty region (the markers' own cost) comes first; the script subtracts it.
//!
//! Each region is one `Server::tick` (steps 2 to 6 of the loop), the server reached through a
//! pointer as a node's loop would. The pose and wrench are set between ticks, outside the
//! regions (a node sets them as their frames arrive). Cases, 1 500 ticks each:
//!
//! - `move`: `move_to` 100 mm away at 50 mm/s, the robot on its attractor;
//! - `touch`: `move_to_touch` down at 5 mm/s (its contact force evaluated every tick);
//! - `search`: the blind search's spiral and rocking (its displacement reaction every tick);
//! - `scan-16`: an idle schema with 16 reactions on fresh extra sensors, none holding: the
//!   longest reaction scan, with the staleness check of every sensor it reads;
//! - `install`: a queue of 1 ms idles, so that every other tick installs the next one (class
//!   `change`) and the others run it (class `run`);
//! - `estop`: the tick that handles an emergency stop (class `change`: the recovery installed and
//!   run), alternating with a high-priority schema that ends the fault.

#![no_std]
#![no_main]

use core::hint::black_box;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, heprint};
use pab_builtins as _;
use pab_core::Instant;
use pab_core::schema::{
    Action, Config, Event, Measure, Pose, Reaction, Schema, Server, Source, Tick, build,
};

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
    heprint!("pab-schema-cost: {}\n", what);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}

/// One tick as a node pays it, out of line, the server reached through a pointer.
#[inline(never)]
fn measured_tick(server: &mut Server, now: Instant) -> Tick {
    // Into place, as the node's runner does (`Server::tick_into`).
    let mut out = Tick::default();
    pab_cost_begin();
    server.tick_into(now, &mut out);
    pab_cost_end();
    black_box(out)
}

const PERIOD: u32 = 1000;

struct Rig {
    server: Server,
    tick: u64,
    pose: Pose,
}

impl Rig {
    fn new() -> Rig {
        let mut config = Config::new(PERIOD);
        config.limits.workspace_min = [-500_000; 6];
        config.limits.workspace_max = [500_000; 6];
        let Ok(mut server) = Server::new(config) else {
            fail("config")
        };
        server.set_pose([0; 6], Instant::from_micros(0));
        server.set_wrench([0; 6], Instant::from_micros(0));
        Rig {
            server,
            tick: 0,
            pose: [0; 6],
        }
    }

    /// One measured tick, the robot then on its attractor (z held at 0 when `surface`).
    fn step(&mut self, case: &str, surface: bool) -> usize {
        self.tick += 1;
        let now = Instant::from_micros(self.tick * u64::from(PERIOD));
        self.server.set_pose(self.pose, now);
        self.server.set_wrench([0, 0, if surface { 7000 } else { 0 }, 0, 0, 0], now);
        for s in 0..8 {
            self.server.set_sensor(s, 0, now);
        }
        let out = measured_tick(&mut self.server, now);
        let class = if out.transitions.is_empty() { "run" } else { "change" };
        heprint!("pab-cost {} {}\n", case, class);
        if let Some(s) = out.setpoint {
            self.pose = s.attractor;
            if surface {
                self.pose[2] = 0;
            }
        }
        out.transitions.len()
    }

    fn enqueue(&mut self, schema: Schema) {
        if self.server.enqueue(schema).is_err() {
            fail("enqueue");
        }
    }
}

fn case(name: &str, schema: Schema, surface: bool) {
    let mut rig = Rig::new();
    rig.enqueue(schema);
    // The install tick is measured too (class `change`).
    for _ in 0..1_500 {
        rig.step(name, surface);
    }
    if rig.server.current() != 1 {
        fail("the schema ended before its ticks were measured");
    }
}

#[entry]
fn main() -> ! {
    pab_cost_begin();
    pab_cost_end();
    heprint!("pab-cost calibrate empty\n");

    case("move", build::move_to(1, [100_000, 50_000, -20_000, 0, 0, 0], 50_000), false);
    case(
        "touch",
        build::move_to_touch(1, [0, 0, -1, 0, 0, 0], 5_000, 3_000, 50_000),
        false,
    );
    let search = Action::BlindSearch {
        preload: 2_000,
        pitch: 80,
        speed: 2_000,
        radius: 1_000,
        wobble: 20_000,
        wobble_ms: 500,
    };
    case("search", build::blind_search(1, search, 1_000), true);
    let mut scan = build::idle(1, 0);
    scan.reactions.clear();
    for k in 0..16u8 {
        let reaction = Reaction {
            event: Event::Above(Measure::Sensor(k % 8), 1_000_000),
            next: Source::Queue,
        };
        if scan.reactions.push(reaction).is_err() {
            fail("reactions");
        }
    }
    case("scan-16", scan, false);

    let mut rig = Rig::new();
    for id in 1..=1_500u16 {
        if rig.server.queued() < 4 {
            rig.enqueue(build::idle(id, 1));
        }
        rig.step("install", false);
    }

    let mut rig = Rig::new();
    rig.enqueue(build::move_to(1, [100_000, 0, 0, 0, 0, 0], 50_000));
    for id in 2..=300u16 {
        rig.server.emergency_stop();
        if rig.step("estop", false) == 0 {
            fail("no transition on an emergency stop");
        }
        rig.step("estop", false);
        let stop = rig.server.stop_number();
        if rig
            .server
            .high_priority(build::move_to(id, [0; 6], 50_000), stop)
            .is_err()
        {
            fail("high priority");
        }
        rig.step("estop-resume", false);
    }

    heprint!("pab-schema-cost: done\n");
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    fail("panic")
}
