//! Cost of one frame's arbitration, `Arbiter::receive` (see `common/mod.rs` for the nodes):
//!
//! - `receive/longest_walk/N`: one port of N connections, only the last one active, the frame on
//!   it: the walk visits all N nodes and the frame is delivered. The worst case of the decision.
//! - `receive/all_active/N`: every connection active, the frame on the last one: the walk stops at
//!   x_0 and the frame is discarded.
//! - `receive/full_capacity_16x32`: 16 ports of 32 connections (512, the node's capacity), the
//!   frame on the last connection of the last port: adds the filter scan over all connections.
//!
//! Every iteration is 1 µs after the previous one, so the activity mask stays the same for the
//! whole measurement (a verdict is checked before measuring).

mod common;

use std::hint::black_box;
use std::time::Duration;

use common::Case;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use pab_core::Instant;

fn measure(b: &mut criterion::Bencher<'_>, mut case: Case) {
    let mut now = Instant::from_micros(1);
    case.verify(now);
    b.iter(|| {
        now = now.wrapping_add_micros(1);
        case.arbiter
            .receive(black_box(&case.id), black_box(now), |verdict| {
                black_box(verdict);
            })
    });
}

fn receive(c: &mut Criterion) {
    let mut group = c.benchmark_group("receive/longest_walk");
    for n in [4, 16, 32] {
        group.bench_function(BenchmarkId::from_parameter(n), |b| {
            measure(b, common::longest_walk(n))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("receive/all_active");
    for n in [4, 16, 32] {
        group.bench_function(BenchmarkId::from_parameter(n), |b| {
            measure(b, common::all_active(n))
        });
    }
    group.finish();

    c.bench_function("receive/full_capacity_16x32", |b| {
        measure(b, common::full_capacity())
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
