//! The arbiter makes the same decisions as the straightforward one it replaced
//! (`common/reference.rs`): on random tables and random frame sequences, every frame gives the
//! same verdicts (port, fed, resting, active, selected, delivered) and the same reception, and at
//! the frame's instant and at random other instants (before, between and long after frames)
//! every port has the same activity and selection and every connection the same level (the raw
//! Q1.31 integer) and rest state.
//!
//! What the tables and frames exercise: exact and masked filters, standard and extended
//! identifiers with the same number, several connections of a port fed by one frame, fan-out to
//! several ports, σ from 2^-16 to 1, short τ (so activities lapse between frames) and rest times,
//! random reduced decision diagrams, priority chains (one step at run time) and mixtures, frames
//! out of order, repeated instants, long silences, and clocks that start anywhere, up to just
//! before the 64-bit counter wraps.

use crate::common::{random, reference};

use pab_core::{Arbiter, Instant, Table};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use random::{POOL, Rng, compare_at, id, next_instant, random_table};
use reference::Reference;

fn run_case<const P: usize, const C: usize, const N: usize>(
    seed: u64,
    frames: usize,
) -> Result<(), TestCaseError> {
    run_tables::<P, C, N>(seed, frames, 20)
}

/// [`run_case`] with `masked` percent of masked filters.
fn run_tables<const P: usize, const C: usize, const N: usize>(
    seed: u64,
    frames: usize,
    masked: u64,
) -> Result<(), TestCaseError> {
    let mut rng = Rng::new(seed);
    let table: Table<P, C, N> = random_table(&mut rng, masked);
    let mut reference = Reference::new(&table);
    let mut arbiter = Arbiter::new(table).expect("a valid table");
    let mut now = match rng.below(4) {
        0 => 0,
        1 => u64::MAX - rng.below(10_000_000),
        2 => (1 << 63) - rng.below(10_000_000),
        _ => rng.next(),
    };
    for frame in 0..frames {
        now = next_instant(&mut rng, now);
        let at = Instant::from_micros(now);
        if rng.chance(1) {
            arbiter.reset();
            reference.reset();
        }
        let raw = POOL[rng.below(POOL.len() as u64) as usize];
        let frame_id = id(raw, rng.chance(20));
        let mut verdicts = Vec::new();
        let reception = arbiter.receive(&frame_id, at, |v| verdicts.push(*v));
        let (fed, delivered, expected) = reference.receive(&frame_id, at);
        let what = format!("frame {frame} ({frame_id:?} at {now})");
        prop_assert_eq!(&verdicts, &expected, "{}: verdicts", what);
        prop_assert_eq!(reception.fed.bits(), fed, "{}: fed ports", what);
        prop_assert_eq!(reception.delivered.bits(), delivered, "{}: delivered", what);
        compare_at(&arbiter, &reference, at, &what)?;
        // Read-only accessors at other instants: they must not disturb anything either.
        for _ in 0..2 {
            let probe = Instant::from_micros(next_instant(&mut rng, now));
            compare_at(&arbiter, &reference, probe, &format!("{what}, probe"))?;
        }
    }
    Ok(())
}

fn runner(cases: u32) -> TestRunner {
    TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    })
}

#[test]
fn same_decisions_as_the_reference_at_default_capacities() {
    runner(600)
        .run(&any::<u64>(), |seed| run_case::<16, 512, 2048>(seed, 300))
        .unwrap();
}

#[test]
fn same_decisions_as_the_reference_at_board_capacities() {
    runner(600)
        .run(&any::<u64>(), |seed| run_case::<4, 64, 256>(seed, 300))
        .unwrap();
}

#[test]
fn same_decisions_as_the_reference_with_exact_filters_only() {
    // Without masked filters the index answers most frames from the bucket alone (one
    // connection, or nothing): those paths, at both capacities and with crowded buckets.
    runner(400)
        .run(&any::<u64>(), |seed| {
            run_tables::<16, 512, 2048>(seed, 300, 0)
        })
        .unwrap();
    runner(400)
        .run(&any::<u64>(), |seed| run_tables::<4, 64, 256>(seed, 300, 0))
        .unwrap();
    runner(300)
        .run(&any::<u64>(), |seed| run_tables::<2, 3, 8>(seed, 100, 0))
        .unwrap();
}

#[test]
fn same_decisions_as_the_reference_at_tiny_capacities() {
    // One connection of capacity: no room for the index's buckets, the filter is scanned.
    runner(300)
        .run(&any::<u64>(), |seed| run_case::<1, 1, 4>(seed, 100))
        .unwrap();
    runner(300)
        .run(&any::<u64>(), |seed| run_case::<2, 3, 8>(seed, 100))
        .unwrap();
}

#[test]
fn the_take_and_return_images_decide_as_the_reference() {
    // The images the boards run, under a long random stream of their topics.
    let dir = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../firmware/boards/mps2-an386/tables/take-and-return"
    );
    for node in ["arm", "gaze", "hand"] {
        let bytes = std::fs::read(format!("{dir}/{node}.pab")).expect("image");
        let loaded = pab_core::image::load::<4, 64, 256>(&bytes).expect("loads");
        let mut reference = Reference::new(&loaded.table);
        let mut arbiter = Arbiter::new(loaded.table).expect("valid");
        let mut rng = Rng::new(0x7A6E_u64 + node.len() as u64);
        let ids = [
            0x110, 0x111, 0x112, 0x113, 0x120, 0x121, 0x122, 0x130, 0x200,
        ];
        let mut now = 0u64;
        for frame in 0..20_000 {
            now = now.wrapping_add(rng.below(400_000));
            let at = Instant::from_micros(now);
            let frame_id = id(ids[rng.below(ids.len() as u64) as usize], false);
            let mut verdicts = Vec::new();
            arbiter.receive(&frame_id, at, |v| verdicts.push(*v));
            let (_, _, expected) = reference.receive(&frame_id, at);
            assert_eq!(verdicts, expected, "{node}: frame {frame}");
            for port in 0..arbiter.port_count() as u8 {
                assert_eq!(arbiter.activity(port, at), reference.activity(port, at));
            }
        }
    }
}
