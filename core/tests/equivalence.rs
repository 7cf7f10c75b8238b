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

#[path = "common/reference.rs"]
mod reference;

use embedded_can::{ExtendedId, StandardId};
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Gain, Id, Instant, NodeRef, Stimulation, Table,
};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use reference::Reference;

/// xorshift64*: the test's own random stream, seeded by proptest (which reports the seed of a
/// failing case, so it can be replayed).
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(seed | 1)
    }

    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in 0..n (n > 0).
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
}

/// The identifiers frames use: a small pool, so that filters collide, overlap and fan out. Raw
/// numbers, each both standard and extended.
const POOL: [u32; 8] = [0x100, 0x101, 0x102, 0x110, 0x111, 0x1F0, 0x7FF, 0x000];

fn id(raw: u32, extended: bool) -> Id {
    if extended {
        Id::Extended(ExtendedId::new(raw).expect("29-bit id"))
    } else {
        Id::Standard(StandardId::new(raw as u16).expect("11-bit id"))
    }
}

/// A random filter: exact, or masked with probability `masked` percent.
fn random_filter(rng: &mut Rng, masked: u64) -> Filter {
    let raw = POOL[rng.below(POOL.len() as u64) as usize];
    let extended = rng.chance(20);
    if rng.chance(masked) {
        // A masked filter: clear some low bits of the mask (and of the id).
        let width = if extended { 0x1FFF_FFFF } else { 0x7FF };
        let mask = width & !((1u32 << rng.below(6)) - 1) & !(rng.below(2) as u32 * 0x10);
        Filter::new(raw & mask, mask, extended).expect("valid masked filter")
    } else {
        Filter::exact(raw, extended).expect("valid filter")
    }
}

fn random_stimulation(rng: &mut Rng) -> Stimulation {
    let gain = match rng.below(5) {
        0 => Gain::ONE.raw(),
        1 => 1 << 30,
        2 => 429_496_730,
        3 => 1 << 15,
        _ => (1 << 15) + rng.below((1 << 31) - (1 << 15) + 1) as u32,
    };
    let tau = match rng.below(4) {
        0 => 1 + rng.below(50) as u32,
        1 => 100 + rng.below(5_000) as u32,
        2 => 1_000_000,
        _ => 3_600_000_000,
    };
    let rest = match rng.below(3) {
        0 => 0,
        1 => rng.below(3_000) as u32,
        _ => rng.below(20) as u32,
    };
    Stimulation::new(Gain::from_raw(gain).expect("gain"), tau, rest).expect("parameters")
}

/// A random valid diagram over `n` connections: nodes with increasing variables along every path
/// and children after their parents; some are priority chains (low to the next, high "this
/// connection delivers"), some random, some a mixture.
fn random_diagram(rng: &mut Rng, n: u8) -> (Vec<DecisionNode>, NodeRef) {
    let terminal = |rng: &mut Rng| {
        if n == 0 || rng.chance(30) {
            NodeRef::NOBODY
        } else {
            NodeRef::deliver(rng.below(u64::from(n)) as u8).expect("terminal")
        }
    };
    if n == 0 {
        return (Vec::new(), terminal(rng));
    }
    let style = rng.below(3);
    if style == 0 {
        // A priority chain over a random increasing subset, possibly ending in a random terminal
        // or node-free tail.
        let vars: Vec<u8> = (0..n).filter(|_| rng.chance(70)).collect();
        let count = vars.len();
        let nodes: Vec<DecisionNode> = vars
            .iter()
            .enumerate()
            .map(|(k, &var)| DecisionNode {
                var,
                low: if k + 1 < count {
                    NodeRef::node(k as u16 + 1).expect("node")
                } else {
                    terminal(rng)
                },
                high: if rng.chance(85) {
                    NodeRef::deliver(var).expect("terminal")
                } else {
                    terminal(rng)
                },
            })
            .collect();
        let root = if nodes.is_empty() {
            terminal(rng)
        } else {
            NodeRef::node(0).expect("node")
        };
        return (nodes, root);
    }
    // Random nodes, built from the last: node k tests var[k], children among later nodes with a
    // larger variable, or terminals. Style 2 biases towards priority shapes.
    let count = 1 + rng.below(2 * u64::from(n)) as usize;
    let mut vars: Vec<u8> = (0..count).map(|_| rng.below(u64::from(n)) as u8).collect();
    vars.sort_unstable();
    let mut nodes = vec![
        DecisionNode {
            var: 0,
            low: NodeRef::NOBODY,
            high: NodeRef::NOBODY,
        };
        count
    ];
    for k in (0..count).rev() {
        let var = vars[k];
        let later: Vec<usize> = (k + 1..count).filter(|&j| vars[j] > var).collect();
        let child = |rng: &mut Rng| {
            if !later.is_empty() && rng.chance(60) {
                NodeRef::node(later[rng.below(later.len() as u64) as usize] as u16).expect("node")
            } else {
                terminal(rng)
            }
        };
        let low = child(rng);
        let high = if style == 2 && rng.chance(60) {
            NodeRef::deliver(var).expect("terminal")
        } else {
            child(rng)
        };
        nodes[k] = DecisionNode { var, low, high };
    }
    let root = if rng.chance(90) {
        NodeRef::node(0).expect("node")
    } else {
        terminal(rng)
    };
    (nodes, root)
}

/// A random table; `masked`: the percentage of masked filters.
fn random_table<const P: usize, const C: usize, const N: usize>(
    rng: &mut Rng,
    masked: u64,
) -> Table<P, C, N> {
    let mut table = Table::new();
    let ports = 1 + rng.below(P.min(5) as u64) as usize;
    for _ in 0..ports {
        let room = C - table.connection_count();
        let wide = rng.chance(15);
        let most = if wide { 32 } else { 8 }.min(room);
        let n = rng.below(most as u64 + 1) as u8;
        let connections: Vec<Connection> = (0..n)
            .map(|_| Connection {
                filter: random_filter(rng, masked),
                stimulation: random_stimulation(rng),
            })
            .collect();
        let (nodes, root) = random_diagram(rng, n);
        if table.node_count() + nodes.len() > N {
            continue;
        }
        table
            .push_port(&connections, &nodes, root)
            .expect("a valid port");
    }
    table
}

/// The next instant: mostly forward by a little (within the short τs), sometimes the same
/// instant, out of order, or a long silence; the counter wraps as it wraps.
fn next_instant(rng: &mut Rng, now: u64) -> u64 {
    match rng.below(40) {
        0 | 1 => now,
        2 | 3 => now.wrapping_sub(rng.below(3_000)),
        4 | 5 => now.wrapping_add(1_000_000 + rng.below(4_000_000_000)),
        6 => now.wrapping_add(rng.below(1 << 40)),
        // Half the counter and around: a frame that old is in the past again.
        7 => now.wrapping_add((1 << 63) - 2_000 + rng.below(4_000)),
        8 => now.wrapping_add(rng.next()),
        _ => now.wrapping_add(rng.below(2_000)),
    }
}

/// Compares everything read-only at `now`.
fn compare_at<const P: usize, const C: usize, const N: usize>(
    arbiter: &Arbiter<P, C, N>,
    reference: &Reference,
    now: Instant,
    what: &str,
) -> Result<(), TestCaseError> {
    prop_assert_eq!(arbiter.port_count(), reference.port_count());
    for port in 0..arbiter.port_count() as u8 {
        prop_assert_eq!(
            arbiter.activity(port, now),
            reference.activity(port, now),
            "{}: activity of port {} at {:?}",
            what,
            port,
            now
        );
        prop_assert_eq!(
            arbiter.selected(port, now),
            reference.selected(port, now),
            "{}: selected at port {} at {:?}",
            what,
            port,
            now
        );
        prop_assert_eq!(
            arbiter.connection_count(port),
            reference.connection_count(port)
        );
        for connection in 0..arbiter.connection_count(port) as u8 {
            prop_assert_eq!(
                arbiter.level(port, connection, now),
                reference.level(port, connection, now),
                "{}: level of {}.{} at {:?}",
                what,
                port,
                connection,
                now
            );
            prop_assert_eq!(
                arbiter.is_resting(port, connection, now),
                reference.is_resting(port, connection, now),
                "{}: rest of {}.{} at {:?}",
                what,
                port,
                connection,
                now
            );
        }
    }
    Ok(())
}

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
