//! Random intention-solver instances for the benchmark (`benches/hbba.rs`) and the test that
//! prints the nodes visited (`tests/hbba_solver.rs`, `work_at_each_size_is_printed`): the same
//! seeds give the same instances in both.
//!
//! A size is (classes, strategies, resources): strategies spread round-robin over the classes
//! (so each class has strategies/classes of them), utilities 1..=100, each resource's costs
//! 1..=40 against a capacity of 100 (about five strategies fit at once: the knapsack binds),
//! one filter in four on one of 8 shared connections with φ 1..=3 (filter agreement binds), a
//! requirement in eight on another class with a minimum utility up to 50, every class desired
//! with intensity 1..=10.

#![allow(dead_code)]

use pab_core::hbba::{FilterSetting, Instance, Intensities, MAX_CLASSES, Requirement, Strategy};

/// xorshift64*, seeded.
pub struct Random(u64);

impl Random {
    pub fn new(seed: u64) -> Random {
        Random(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform-ish in `low..=high`.
    pub fn within(&mut self, low: u64, high: u64) -> u64 {
        low + self.next() % (high - low + 1)
    }
}

/// The sizes measured: (classes, strategies, resources).
pub const SIZES: [(u8, usize, usize); 5] =
    [(4, 8, 2), (6, 16, 2), (8, 24, 3), (12, 40, 4), (16, 64, 8)];

/// Instances per size.
pub const SEEDS: u64 = 20;

/// Instance `seed` of a size, with its intensities.
pub fn instance(
    classes: u8,
    strategies: usize,
    resources: usize,
    seed: u64,
) -> (Instance, Intensities) {
    let mut random = Random::new(seed ^ (u64::from(classes) << 32) ^ (strategies as u64) << 40);
    let mut instance = Instance {
        classes,
        ..Instance::default()
    };
    for _ in 0..resources {
        instance.capacities.push(100).unwrap();
    }
    for index in 0..strategies {
        let class = (index % usize::from(classes)) as u8;
        let mut strategy = Strategy::new(class, random.within(1, 100) as u16);
        for cost in strategy.costs.iter_mut().take(resources) {
            *cost = random.within(1, 40) as u32;
        }
        if random.within(0, 3) == 0 {
            strategy
                .filters
                .push(FilterSetting {
                    connection: random.within(0, 7) as u16,
                    phi: random.within(1, 3) as u16,
                })
                .unwrap();
        }
        if classes > 1 && random.within(0, 7) == 0 {
            let other =
                (u64::from(class) + random.within(1, u64::from(classes) - 1)) % u64::from(classes);
            strategy
                .requires
                .push(Requirement {
                    class: other as u8,
                    min_utility: random.within(0, 50) as u16,
                })
                .unwrap();
        }
        instance.strategies.push(strategy).unwrap();
    }
    let mut intensities = [0u16; MAX_CLASSES];
    for intensity in intensities.iter_mut().take(usize::from(classes)) {
        *intensity = random.within(1, 10) as u16;
    }
    (instance, intensities)
}

/// An instance the bound cannot cut (`tests/hbba_solver.rs`, `the_work_budget_is_enforced_exactly`):
/// 16 classes of `per_class` strategies of utility 1 over `resources` resources of capacity 100,
/// every class desired at 1; strategy j of class k costs 25 of resource (j + k) mod `resources`
/// and 5 of each other. Few strategies fit together (6 with 2 resources, 11 with 8), but each
/// resource's relaxation alone lets every class in through a strategy cheap on it (16 × 5 =
/// 80), so the search is long: (2, 2), 32 strategies, needs 288 439 nodes; (4, 8), 64
/// strategies, 937 435. Both exceed the default budget.
pub fn adversarial(per_class: usize, resources: usize) -> (Instance, Intensities) {
    let mut instance = Instance {
        classes: 16,
        ..Instance::default()
    };
    for _ in 0..resources {
        instance.capacities.push(100).unwrap();
    }
    for class in 0..16usize {
        for j in 0..per_class {
            let mut strategy = Strategy::new(class as u8, 1);
            for (resource, cost) in strategy.costs.iter_mut().take(resources).enumerate() {
                *cost = if resource == (j + class) % resources {
                    25
                } else {
                    5
                };
            }
            instance.strategies.push(strategy).unwrap();
        }
    }
    (instance, [1; MAX_CLASSES])
}
