//! Cost of one frame's arbitration, `Arbiter::receive`, on a node whose port(s) use a priority
//! chain: connection k delivers iff x_k and no lower-indexed connection is active. The diagram
//! tests x_0, x_1, ... in order, so its walk is long when the low connections are inactive.
//!
//! - `receive/longest_walk/N`: one port of N connections; only the last one is active and the
//!   frame is on it: the walk visits all N nodes and the frame is delivered. The worst case of
//!   the decision.
//! - `receive/all_active/N`: the same port with every connection fed and active, the frame on the
//!   last one: every integrator reports active, the walk stops at x_0 and the frame is discarded.
//! - `receive/full_capacity_16x32`: 16 ports of 32 connections (512, the node's capacity), the
//!   frame on the last connection of the last port, only that one active: adds the filter scan
//!   over all 512 connections.
//!
//! σ = 1 and τ = 1 h, and every iteration is 1 µs after the previous one, so the activity mask
//! stays the same for the whole measurement (a verdict is checked before measuring).

use std::hint::black_box;
use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use embedded_can::StandardId;
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Id, Instant, MAX_CONNECTIONS_PER_PORT, MAX_PORTS,
    NodeRef, Stimulation, Table,
};

/// Frame id of connection `k` of port `port`.
fn id_of(port: usize, k: usize) -> u16 {
    (0x100 + port * MAX_CONNECTIONS_PER_PORT + k) as u16
}

fn frame(port: usize, k: usize) -> Id {
    Id::Standard(StandardId::new(id_of(port, k)).expect("11-bit id"))
}

/// Connection k delivers iff x_k and no lower-indexed connection is active.
fn priority_chain(n: usize) -> Vec<DecisionNode> {
    (0..n)
        .map(|k| DecisionNode {
            var: k as u8,
            low: if k + 1 < n {
                NodeRef::node(k as u16 + 1).expect("node")
            } else {
                NodeRef::NOBODY
            },
            high: NodeRef::deliver(k as u8).expect("connection"),
        })
        .collect()
}

/// `ports` ports of `n` chained connections each.
fn arbiter(ports: usize, n: usize) -> Arbiter {
    let stimulation = Stimulation::from_seconds(1.0, 3600.0, 0.0).expect("parameters");
    let mut table = Table::new();
    for port in 0..ports {
        let connections: Vec<Connection> = (0..n)
            .map(|k| Connection {
                filter: Filter::exact(u32::from(id_of(port, k)), false).expect("filter"),
                stimulation,
            })
            .collect();
        let root = NodeRef::node(0).expect("node");
        table
            .push_port(&connections, &priority_chain(n), root)
            .expect("valid port");
    }
    Arbiter::new(table).expect("valid table")
}

/// Measures frames on connection `k` of port `port`, each 1 µs after the previous, and checks
/// first that such a frame gets the expected delivery on that port.
fn measure(
    b: &mut criterion::Bencher<'_>,
    mut arbiter: Arbiter,
    port: usize,
    k: usize,
    delivered: Option<u8>,
) {
    let id = frame(port, k);
    let mut now = Instant::from_micros(1);
    let mut verdict = None;
    arbiter.receive(&id, now, |v| verdict = Some(*v));
    let verdict = verdict.expect("the frame feeds its port");
    assert_eq!(
        (usize::from(verdict.port), verdict.delivered),
        (port, delivered)
    );
    b.iter(|| {
        now = now.wrapping_add_micros(1);
        arbiter.receive(black_box(&id), black_box(now), |verdict| {
            black_box(verdict);
        })
    });
}

fn receive(c: &mut Criterion) {
    let mut group = c.benchmark_group("receive/longest_walk");
    for n in [4, 16, 32] {
        let mut node = arbiter(1, n);
        // Only the last connection active.
        node.receive(&frame(0, n - 1), Instant::from_micros(0), |_| {});
        group.bench_function(BenchmarkId::from_parameter(n), |b| {
            measure(b, node.clone(), 0, n - 1, Some(n as u8 - 1))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("receive/all_active");
    for n in [4, 16, 32] {
        let mut node = arbiter(1, n);
        for k in 0..n {
            node.receive(&frame(0, k), Instant::from_micros(0), |_| {});
        }
        group.bench_function(BenchmarkId::from_parameter(n), |b| {
            measure(b, node.clone(), 0, n - 1, None)
        });
    }
    group.finish();

    let (ports, n) = (MAX_PORTS, MAX_CONNECTIONS_PER_PORT);
    let mut node = arbiter(ports, n);
    node.receive(&frame(ports - 1, n - 1), Instant::from_micros(0), |_| {});
    c.bench_function("receive/full_capacity_16x32", |b| {
        measure(b, node.clone(), ports - 1, n - 1, Some(n as u8 - 1))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .sample_size(50);
    targets = receive
}
criterion_main!(benches);
