//! HBBA's intention solver (Ferland, Michaud et al., the Hybrid Behavior-Based Architecture):
//! given the desires of the moment, which strategies to run.
//!
//! Motivations issue desires (a class and an intensity, with a lease: [`Desires`]); per class the
//! intention workspace keeps the most intense one, so the solver sees one intensity per class
//! ([`Intensities`], 0: no desire). Each [`Strategy`] fulfils one class with a utility, costs some of each resource, sets
//! filters (connection, φ) and may require other classes. The solver picks the strategies; the
//! filters they set are what the boards then apply ([`intention`]: the workspace that keeps the
//! desires, solves and plans the filter commands, disables before enables; the boards do not
//! run filters yet: docs/hbba.md).
//!
//! # The problem (DESIGN.md, "HBBA: decisions")
//!
//! Choose at most one strategy per class so that:
//!
//! - every resource's capacity is at least the sum of the chosen strategies' costs;
//! - two chosen strategies that set the same connection set the same φ (filter agreement);
//! - each requirement (class → minimum utility) of a chosen strategy is met by the strategy
//!   chosen for that class;
//! - a class without a desire has a strategy only when it is required, directly or through
//!   other such strategies, by a chosen strategy of a class with a desire (the original HBBA
//!   pulls in a mobile-base strategy for a go-to desire). This is DESIGN's "only when a chosen
//!   strategy requires that class", read so that two desire-less classes requiring each other
//!   do not pull each other in;
//!
//! and maximise Σ intensity × utility over the classes with a desire (a pulled-in class adds
//! nothing), in `u64`: intensities and utilities are `u16`, so 16 products of at most 65 535²
//! sum below 2^36, where hbba_lite's constraint model (variables bounded by 10^6) gives up.
//!
//! **Ties.** Among the best selections, compare two class by class, classes in order of first
//! appearance among the strategies ([`Solver::class_order`]); at the first class where they
//! differ, prefer the one that chose a strategy over none, then the strategy that comes first
//! (the lower index). So the answer is a function of the instance and the intensities alone.
//!
//! # The search
//!
//! Depth-first branch and bound over the classes in tie-break order, each class's options in
//! preference order (its strategies by index, then none), so leaves come in tie-break order and
//! the first best leaf is the answer: a later leaf replaces it only if strictly better, and a
//! node whose optimistic bound (the value so far plus an upper bound on what the classes still
//! to decide can add) does not exceed the best so far is cut.
//!
//! Bound. For the classes still to decide, the least of these relaxations of what they can add
//! (a strategy's value is its class's intensity times its utility; its candidates are the
//! strategies that could still join on their own: no conflict with the chosen ones, no required
//! class decided empty, within the remaining capacities): each class with a desire its best
//! candidate's value; and per resource, the fractional knapsack of the candidates within that
//! resource's remaining capacity, each class's value capped at its best candidate's, taken
//! greedily by value per unit of the resource (the exact optimum of that linear relaxation,
//! rounded up). Conflicts (filters set to different φ, requirements the other strategy's utility
//! cannot meet) are a precomputed 64 × 64 bit matrix, so checking an option is a few masks and
//! one addition per resource.
//!
//! **Work bound.** A solve visits at most its `budget` nodes (the root, each partial selection
//! that passed the checks, each leaf) and fails with [`HbbaError::BudgetExceeded`] beyond it:
//! never a selection that might not be the best. A node costs at most one bound, O(S · R) for S
//! strategies and R resources, and one O(R) check per option of its class. [`DEFAULT_BUDGET`]
//! is 100 000 nodes.
//!
//! Measured on the development machine (2 shared x86-64 cores, release build; `cargo bench -p
//! pab-core --bench hbba` prints each instance's time, best of 5; `core/tests/hbba_solver.rs`
//! prints the nodes visited), over 20 random instances per size in which every class has a
//! desire, each resource's capacity holds about five strategies' costs, one strategy in four
//! sets one of 8 shared filters and one in eight requires another class
//! (`core/benches/common/hbba.rs`):
//!
//! | classes, strategies, resources | nodes (median, max) | one solve (median, max) |
//! | --- | --- | --- |
//! | 4, 8, 2 | 19, 34 | 2.0 µs, 3.3 µs |
//! | 6, 16, 2 | 95, 164 | 10.5 µs, 18.6 µs |
//! | 8, 24, 3 | 245, 740 | 31 µs, 81 µs |
//! | 12, 40, 4 | 1 275, 2 482 | 0.34 ms, 0.67 ms |
//! | 16, 64, 8 | 3 769, 15 889 | 2.5 ms, 8.0 ms |
//!
//! So instances up to 12 classes, 40 strategies and 4 resources solve within 1 ms here (in a
//! run under load from other sessions the slowest of those 20 took 0.96 ms). Where the
//! bound cannot cut (classes whose strategies each fit alone but few together: the
//! `adversarial` instances there) the search is long: 288 439 nodes (40 ms) for 16 classes of
//! 2 strategies and 2 resources, 937 435 (1.2 s) for 16 classes of 4 and 8 resources. The
//! default budget stops them after 100 000 nodes, 10 ms and 89 ms (about 0.9 µs a node with 64
//! strategies and 8 resources), with `BudgetExceeded`.
//!
//! # Capacities
//!
//! [`MAX_CLASSES`] classes, [`MAX_STRATEGIES`] strategies, [`MAX_RESOURCES`] resources,
//! [`MAX_FILTERS`] filters and [`MAX_REQUIRES`] requirements per strategy: chosen for a robot's
//! intention workspace (`examples/tour-guide.toml` has 5 classes and 6 strategies),
//! and so that a set of classes is a `u16` and a set of strategies a `u64`.

mod desires;
pub mod filters;
mod instance;
pub mod intention;
mod solver;

pub use desires::{Desire, DesireError, Desires, MAX_DESIRES};
pub use instance::{FilterSetting, HbbaError, Instance, Intensities, Requirement, Strategy};
pub use solver::{Selection, Solver};

/// Classes of desire, at most: a set of classes is a `u16`.
pub const MAX_CLASSES: usize = 16;
/// Strategies, at most: a set of strategies is a `u64`.
pub const MAX_STRATEGIES: usize = 64;
/// Resources (CPU, the bus, ...), at most.
pub const MAX_RESOURCES: usize = 8;
/// Filters one strategy sets, at most.
pub const MAX_FILTERS: usize = 8;
/// Classes one strategy requires, at most.
pub const MAX_REQUIRES: usize = 4;

/// The work budget `pabctl solve` gives a solve, in search nodes: 100 000 (module
/// documentation: about 10 to 90 ms when it runs out).
pub const DEFAULT_BUDGET: u32 = 100_000;

/// Checks `instance` and solves it for `intensities` within `budget` search nodes: a
/// [`Solver::new`] followed by [`Solver::solve`]. To solve one instance for many sets of desires,
/// keep the [`Solver`].
pub fn solve(
    instance: &Instance,
    intensities: &Intensities,
    budget: u32,
) -> Result<Selection, HbbaError> {
    Solver::new(instance)?.solve(intensities, budget)
}
