//! Random tables, frames and instants for the property tests that compare the arbiter with the
//! reference (`reference.rs`), and the comparison of everything read-only at an instant.

#![allow(dead_code)]

use super::reference::Reference;
use embedded_can::{ExtendedId, StandardId};
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Gain, Id, Instant, NodeRef, Stimulation, Table,
};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// xorshift64*: the test's own random stream, seeded by proptest (which reports the seed of a
/// failing case, so it can be replayed).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed | 1)
    }

    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in 0..n (n > 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    pub fn chance(&mut self, percent: u64) -> bool {
        self.below(100) < percent
    }
}

/// The identifiers frames use: a small pool, so that filters collide, overlap and fan out. Raw
/// numbers, each both standard and extended.
pub const POOL: [u32; 8] = [0x100, 0x101, 0x102, 0x110, 0x111, 0x1F0, 0x7FF, 0x000];

pub fn id(raw: u32, extended: bool) -> Id {
    if extended {
        Id::Extended(ExtendedId::new(raw).expect("29-bit id"))
    } else {
        Id::Standard(StandardId::new(raw as u16).expect("11-bit id"))
    }
}

/// A random filter: exact, or masked with probability `masked` percent.
pub fn random_filter(rng: &mut Rng, masked: u64) -> Filter {
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

pub fn random_stimulation(rng: &mut Rng) -> Stimulation {
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
pub fn random_diagram(rng: &mut Rng, n: u8) -> (Vec<DecisionNode>, NodeRef) {
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
pub fn random_table<const P: usize, const C: usize, const N: usize>(
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
pub fn next_instant(rng: &mut Rng, now: u64) -> u64 {
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
pub fn compare_at<const P: usize, const C: usize, const N: usize>(
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
