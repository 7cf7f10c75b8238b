//! Cost of one intention solve, `Solver::solve` (the instances: `common/hbba.rs`):
//!
//! - `hbba/solve/C-S-R`: the 20 random instances of C classes, S strategies and R resources,
//!   solved one after the other with the default budget (the time reported is for all 20:
//!   divide by 20 for one solve).
//!
//! - `hbba/budget_exceeded/C-S-R`: the adversarial instances (`common/hbba.rs`), which exhaust
//!   the default budget of 100 000 nodes and fail: the longest a solve of that size takes with
//!   that budget.
//!
//! `Solver::new` (the conflict matrix) is built outside the measurement, as the intention node
//! builds it once per network.

#[path = "common/hbba.rs"]
mod hbba_instances;

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use hbba_instances::{SEEDS, SIZES, instance};
use pab_core::hbba::{DEFAULT_BUDGET, Solver};

/// Each instance's own solve time (the best of 5 runs, to shed the noise of a shared machine),
/// printed per size as median and maximum: what the module documentation quotes.
fn print_each_solve_time() {
    for (classes, strategies, resources) in SIZES {
        let mut times: Vec<Duration> = (0..SEEDS)
            .map(|seed| {
                let (instance, intensities) = instance(classes, strategies, resources, seed);
                let solver = Solver::new(&instance).unwrap();
                (0..5)
                    .map(|_| {
                        let start = Instant::now();
                        let _ = black_box(solver.solve(black_box(&intensities), DEFAULT_BUDGET));
                        start.elapsed()
                    })
                    .min()
                    .unwrap()
            })
            .collect();
        times.sort_unstable();
        println!(
            "hbba: {classes} classes, {strategies} strategies, {resources} resources: one solve median {:.1} µs, max {:.1} µs ({SEEDS} instances)",
            times[times.len() / 2].as_secs_f64() * 1e6,
            times[times.len() - 1].as_secs_f64() * 1e6
        );
    }
}

fn solve(c: &mut Criterion) {
    // Under `cargo bench` (which passes --bench), not when `cargo test --benches` runs each
    // benchmark once in a debug build.
    if std::env::args().any(|arg| arg == "--bench") {
        print_each_solve_time();
    }
    let mut group = c.benchmark_group("hbba");
    for (classes, strategies, resources) in SIZES {
        let cases: Vec<_> = (0..SEEDS)
            .map(|seed| instance(classes, strategies, resources, seed))
            .collect();
        let solvers: Vec<_> = cases
            .iter()
            .map(|(instance, intensities)| (Solver::new(instance).unwrap(), intensities))
            .collect();
        group.bench_function(
            BenchmarkId::new("solve", format!("{classes}-{strategies}-{resources}")),
            |b| {
                b.iter(|| {
                    for (solver, intensities) in &solvers {
                        let _ = black_box(solver.solve(black_box(intensities), DEFAULT_BUDGET));
                    }
                })
            },
        );
    }
    for (per_class, resources) in [(2, 2), (4, 8)] {
        let (instance, intensities) = hbba_instances::adversarial(per_class, resources);
        let solver = Solver::new(&instance).unwrap();
        assert!(solver.solve(&intensities, DEFAULT_BUDGET).is_err());
        group.bench_function(
            BenchmarkId::new(
                "budget_exceeded",
                format!("16-{}-{resources}", 16 * per_class),
            ),
            |b| b.iter(|| black_box(solver.solve(black_box(&intensities), DEFAULT_BUDGET))),
        );
    }
    group.finish();
}

criterion_group!(benches, solve);
criterion_main!(benches);
