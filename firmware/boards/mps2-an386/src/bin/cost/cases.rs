//! The benchmark nodes of `core/benches/common` (the x86_64 figures' cases), rebuilt without
//! allocation: every port a priority chain (connection k delivers iff x_k and no lower-indexed
//! connection is active), σ = 1, τ = 1 h, frames 1 µs apart, so the activity stays as it was set
//! up while the frames are measured.

use core::hint::black_box;

use cortex_m::peripheral::SYST;
use embedded_can::StandardId;
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Id, Instant, MAX_CONNECTIONS_PER_PORT, MAX_PORTS,
    NodeRef, Stimulation, Table,
};

use crate::{
    elapsed_ticks, fail, measure, measured_receive, receive, report, semihosting, start_systick,
};

/// Frames measured per case: they all cost the same (the state does not change), which the
/// script's table shows as min = max.
const FRAMES: u64 = 4;
/// Frames of the SysTick cross-check.
const SYSTICK_FRAMES: u32 = 1000;

/// Frame id of connection `k` of port `port`.
fn id_of(port: usize, k: usize) -> u16 {
    (0x100 + port * MAX_CONNECTIONS_PER_PORT + k) as u16
}

fn frame(port: usize, k: usize) -> Id {
    match StandardId::new(id_of(port, k)) {
        Some(id) => Id::Standard(id),
        None => fail(format_args!("id of port {port} connection {k}")),
    }
}

/// `ports` ports of `n` chained connections each, every connection at rest.
fn arbiter(ports: usize, n: usize) -> Arbiter {
    with_diagram(ports, n, 3600.0, false)
}

/// `ports` ports of `n` connections with τ = `tau` s; their decision a priority chain, or with
/// `generic` a chain that is not one (node k goes to node k + 1 whatever x_k, the last delivers
/// its own connection): no node can be merged with another, a walk visits every node.
fn with_diagram(ports: usize, n: usize, tau: f64, generic: bool) -> Arbiter {
    let Ok(stimulation) = Stimulation::from_seconds(1.0, tau, 0.0) else {
        fail(format_args!("parameters"))
    };
    let mut table = Table::new();
    for port in 0..ports {
        let connections: [Connection; MAX_CONNECTIONS_PER_PORT] = core::array::from_fn(|k| {
            let Ok(filter) = Filter::exact(u32::from(id_of(port, k)), false) else {
                fail(format_args!("filter"))
            };
            Connection {
                filter,
                stimulation,
            }
        });
        let chain: [DecisionNode; MAX_CONNECTIONS_PER_PORT] = core::array::from_fn(|k| {
            let low = if k + 1 < n {
                NodeRef::node(k as u16 + 1)
            } else {
                Some(NodeRef::NOBODY)
            };
            let high = if generic && k + 1 < n {
                NodeRef::node(k as u16 + 1)
            } else {
                NodeRef::deliver(k as u8)
            };
            match (low, high) {
                (Some(low), Some(high)) => DecisionNode {
                    var: k as u8,
                    low,
                    high,
                },
                _ => fail(format_args!("chain node {k}")),
            }
        });
        let root = NodeRef::node(0).unwrap_or(NodeRef::NOBODY);
        if let Err(error) = table.push_port(&connections[..n], &chain[..n], root) {
            fail(format_args!("port {port}: {error}"));
        }
    }
    Arbiter::new(table).unwrap_or_else(|error| fail(format_args!("table: {error}")))
}

/// A node, the frame measured on it, and the delivery that frame must get (port, connection).
struct Case {
    name: &'static str,
    arbiter: Arbiter,
    id: Id,
    expected: Option<(u8, Option<u8>)>,
}

/// One port of `n` connections, only the last active, the frame on it: the walk visits all `n`
/// nodes and the frame is delivered.
fn longest_walk(name: &'static str, n: usize) -> Case {
    let mut arbiter = arbiter(1, n);
    receive(&mut arbiter, &frame(0, n - 1), Instant::from_micros(0));
    Case {
        name,
        arbiter,
        id: frame(0, n - 1),
        expected: Some((0, Some(n as u8 - 1))),
    }
}

/// One port of `n` connections, all active, the frame on the last: the walk stops at x_0 and the
/// frame is discarded.
fn all_active(name: &'static str, n: usize) -> Case {
    let mut arbiter = arbiter(1, n);
    for k in 0..n {
        receive(&mut arbiter, &frame(0, k), Instant::from_micros(0));
    }
    Case {
        name,
        arbiter,
        id: frame(0, n - 1),
        expected: Some((0, None)),
    }
}

/// 16 ports of 32 connections, only the last connection of the last port active. With `matched`
/// the frame is on that connection; without, on an identifier no connection has.
fn full(name: &'static str, matched: bool) -> Case {
    let (ports, n) = (MAX_PORTS, MAX_CONNECTIONS_PER_PORT);
    let mut arbiter = arbiter(ports, n);
    receive(
        &mut arbiter,
        &frame(ports - 1, n - 1),
        Instant::from_micros(0),
    );
    let (id, expected) = if matched {
        (
            frame(ports - 1, n - 1),
            Some((ports as u8 - 1, Some(n as u8 - 1))),
        )
    } else {
        (frame(0, 0x7FF - 0x100), None)
    };
    Case {
        name,
        arbiter,
        id,
        expected,
    }
}

impl Case {
    /// Fails unless a frame at `now` gets the expected verdict.
    fn verify(&mut self, now: Instant) {
        let mut verdict = None;
        self.arbiter
            .receive(&self.id, now, |v| verdict = Some((v.port, v.delivered)));
        if verdict != self.expected {
            fail(format_args!(
                "{}: verdict {verdict:?}, expected {:?}",
                self.name, self.expected
            ));
        }
    }

    fn measure(&mut self) {
        let mut now = Instant::from_micros(1);
        self.verify(now);
        for _ in 0..FRAMES {
            now = now.wrapping_add_micros(1);
            measured_receive(&mut self.arbiter, &self.id, now);
            report(self.name, "frame");
        }
    }
}

/// One port of `n` connections whose decision is not a priority chain, with the activity changing
/// at every measured frame (so the last decision cannot be reused): each measured frame comes
/// after every activity has lapsed and a frame on connection 0, and activates connection n − 1;
/// the walk visits all n nodes and the frame is delivered.
fn generic_walk(name: &'static str, n: usize) {
    let mut arbiter = with_diagram(1, n, 1.0, true);
    let mut now = Instant::from_micros(0);
    for _ in 0..FRAMES {
        now = now.wrapping_add_micros(2_000_000);
        receive(&mut arbiter, &frame(0, 0), now);
        let reception = measured_receive(&mut arbiter, &frame(0, n - 1), now);
        report(name, "frame");
        if !reception.delivered.contains(0) {
            fail(format_args!("{name}: not delivered"));
        }
    }
}

pub fn run(syst: &mut SYST) {
    longest_walk("walk-4", 4).measure();
    let mut walk16 = longest_walk("walk-16", 16);
    walk16.measure();
    longest_walk("walk-32", 32).measure();
    all_active("active-4", 4).measure();
    all_active("active-16", 16).measure();
    all_active("active-32", 32).measure();
    generic_walk("generic-16", 16);
    generic_walk("generic-32", 32);
    full("full", true).measure();
    full("full-none", false).measure();

    // The cross-check: SYSTICK_FRAMES frames of walk-16 in one region, timed by SysTick too.
    start_systick(syst);
    let mut now = Instant::from_micros(1_000);
    let ticks = measure(|| {
        let before = SYST::get_current();
        for _ in 0..SYSTICK_FRAMES {
            now = now.wrapping_add_micros(1);
            black_box(receive(&mut walk16.arbiter, &walk16.id, now));
        }
        let after = SYST::get_current();
        elapsed_ticks(before, after)
    });
    report("systick", "walk-16");
    semihosting::eprint(format_args!(
        "pab-systick walk-16 {SYSTICK_FRAMES} {ticks}\n"
    ));
}
