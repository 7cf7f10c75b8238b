//! The intention solver (`pab_core::hbba`): hbba_lite's four published solver cases with their
//! exact answers, a brute-force enumeration on random small instances (same objective,
//! constraints and tie-break), the tie-break order, the overflow case at 65 535², the work
//! budget, and the checks of an instance.

#[path = "../benches/common/hbba.rs"]
mod hbba_instances;

use pab_core::hbba::{
    DEFAULT_BUDGET, FilterSetting, HbbaError, Instance, Intensities, MAX_CLASSES, MAX_FILTERS,
    MAX_REQUIRES, MAX_RESOURCES, MAX_STRATEGIES, Requirement, Selection, Solver, Strategy, solve,
};
use proptest::prelude::*;
use proptest::strategy::Strategy as _;

/// A strategy: class, utility, costs by resource index, filters (connection, φ), requirements
/// (class, minimum utility).
fn strategy(
    class: u8,
    utility: u16,
    costs: &[u32],
    filters: &[(u16, u16)],
    requires: &[(u8, u16)],
) -> Strategy {
    let mut s = Strategy::new(class, utility);
    for (slot, &cost) in s.costs.iter_mut().zip(costs) {
        *slot = cost;
    }
    for &(connection, phi) in filters {
        s.filters.push(FilterSetting { connection, phi }).unwrap();
    }
    for &(class, min_utility) in requires {
        s.requires.push(Requirement { class, min_utility }).unwrap();
    }
    s
}

fn build(classes: u8, capacities: &[u32], strategies: Vec<Strategy>) -> Instance {
    let mut instance = Instance {
        classes,
        ..Instance::default()
    };
    for &capacity in capacities {
        instance.capacities.push(capacity).unwrap();
    }
    for s in strategies {
        instance.strategies.push(s).unwrap();
    }
    instance
}

fn intensities(values: &[u16]) -> Intensities {
    let mut all = [0; MAX_CLASSES];
    all[..values.len()].copy_from_slice(values);
    all
}

fn chosen(selection: &Selection) -> Vec<usize> {
    selection.strategies().collect()
}

// hbba_lite's four solver cases (introlab/hbba_lite, test/hbba_lite_cpp/core/
// GecodeSolverTests.cpp: solve_compatibleFilters1, solve_compatibleFilters2,
// solve_incompatibleFilters1, solve_incompatibleFilters2), translated:
//
// - hbba_lite solves over a list of desires, several per class, and answers (desire index,
//   strategy index within the desire's class). Here the intention workspace has already kept the
//   most intense desire per class (its `selectMostIntenseEnabledDesireIndexes`), so the solver
//   gets one intensity per class, and answers strategy indices over the whole file. The classes
//   are its desire types DesireA, DesireB, DesireC = classes 0, 1, 2; DesireC's intensity is 1
//   (its test fixture's default constructor).
// - Its strategies are listed per desire type, in the order registered; here in file order, A's
//   then B's then C's: the same order within a class, which is all its indices say.
// - Its resources `ra`, `rb` are resources 0, 1; a resource a strategy does not name costs 0, as
//   in hbba_lite.
// - Its filters are named (`fa`, `fb`, `fc` = connections 0, 1, 2) and are of two types:
//   throttling(N) is φ = N; onOff() (enabled) passes everything, φ = 1 here. hbba_lite compares
//   an on/off filter's placeholder rate (0) with a throttling rate and would call on/off and
//   throttling(1) on one filter a conflict; no case mixes them on one filter.
// - hbba_lite has no `requires`, and breaks ties in no fixed order: every one of these cases has
//   a single best selection, so the tie-break is not exercised by them (it is below).
// - Objective: hbba_lite maximises Σ intensity × utility, as here (not the paper's Ω, which
//   adds I · F).

/// solve_compatibleFilters1: desires A (2, and 1, which the workspace drops), B (3), C (1);
/// ra = 20, rb = 30; every strategy sets fa to throttling(1). Expected: A's first strategy and
/// B's first: 2·1 + 3·10 = 32 (ra 10 + 10 = 20, rb 20). B1 alone is 30, C alone 1, A3 alone 6.
#[test]
fn hbba_lite_compatible_filters_1() {
    let fa = 0;
    let instance = build(
        3,
        &[20, 30],
        vec![
            strategy(0, 1, &[10], &[(fa, 1)], &[]),      // 0: A1
            strategy(0, 2, &[20], &[(fa, 1)], &[]),      // 1: A2
            strategy(0, 3, &[20], &[(fa, 1)], &[]),      // 2: A3
            strategy(1, 10, &[10, 20], &[(fa, 1)], &[]), // 3: B1
            strategy(1, 1, &[10], &[(fa, 1)], &[]),      // 4: B2
            strategy(2, 1, &[20, 30], &[(fa, 1)], &[]),  // 5: C
        ],
    );
    let selection = solve(&instance, &intensities(&[2, 3, 1]), DEFAULT_BUDGET).unwrap();
    // hbba_lite: {SolverResult(0, 0), SolverResult(2, 0)}: desire 0 (A) with A's strategy 0,
    // desire 2 (B) with B's strategy 0.
    assert_eq!(chosen(&selection), [0, 3]);
    assert_eq!(selection.strategy_of(0), Some(0));
    assert_eq!(selection.strategy_of(1), Some(3));
    assert_eq!(selection.strategy_of(2), None);
    assert_eq!(selection.objective(), 32);
    assert_eq!(selection.usage(), [20, 20]);
}

/// solve_compatibleFilters2: desires A (2), B (3), C (1); the same strategies but B's set fb and
/// C's (utility 50) sets fc. Expected: C alone, 1·50 = 50, which takes all of ra and rb.
#[test]
fn hbba_lite_compatible_filters_2() {
    let (fa, fb, fc) = (0, 1, 2);
    let instance = build(
        3,
        &[20, 30],
        vec![
            strategy(0, 1, &[10], &[(fa, 1)], &[]),
            strategy(0, 2, &[20], &[(fa, 1)], &[]),
            strategy(0, 3, &[20], &[(fa, 1)], &[]),
            strategy(1, 10, &[10, 20], &[(fb, 1)], &[]),
            strategy(1, 1, &[10], &[(fb, 1)], &[]),
            strategy(2, 50, &[20, 30], &[(fc, 1)], &[]),
        ],
    );
    let selection = solve(&instance, &intensities(&[2, 3, 1]), DEFAULT_BUDGET).unwrap();
    // hbba_lite: {SolverResult(2, 0)}: desire 2 (C) with C's strategy 0.
    assert_eq!(chosen(&selection), [5]);
    assert_eq!(selection.objective(), 50);
    assert_eq!(selection.usage(), [20, 30]);
}

/// solve_incompatibleFilters1: desires A (1), B (1), no resources; A1 (utility 1) and B1
/// (utility 1) set fa to throttling(2), A2 (utility 3) to throttling(1). Expected: A2 alone (3),
/// better than A1 with B1 (2); A2 and B1 disagree on fa.
#[test]
fn hbba_lite_incompatible_filters_1() {
    let fa = 0;
    let instance = build(
        2,
        &[],
        vec![
            strategy(0, 1, &[], &[(fa, 2)], &[]), // 0: A1
            strategy(0, 3, &[], &[(fa, 1)], &[]), // 1: A2
            strategy(1, 1, &[], &[(fa, 2)], &[]), // 2: B1
        ],
    );
    let selection = solve(&instance, &intensities(&[1, 1]), DEFAULT_BUDGET).unwrap();
    // hbba_lite: {SolverResult(0, 1)}: desire 0 (A) with A's strategy 1.
    assert_eq!(chosen(&selection), [1]);
    assert_eq!(selection.objective(), 3);
    assert_eq!(selection.usage(), [] as [u64; 0]);
}

/// solve_incompatibleFilters2: desires A (1), B (1), C (1); ra = 20, each strategy costs 10;
/// A1 (utility 2) sets fa on and fb to throttling(1), A2 (5) fa on, B1 (3) fa on and fb
/// throttling(2), C (50) fc throttling(1). (The test also builds a second B strategy, utility 2,
/// that it never registers: left out.) Expected: A2 and C, 5 + 50 = 55; C with B1 is 53, and A1
/// with B1 disagree on fb.
#[test]
fn hbba_lite_incompatible_filters_2() {
    let (fa, fb, fc) = (0, 1, 2);
    let instance = build(
        3,
        &[20],
        vec![
            strategy(0, 2, &[10], &[(fa, 1), (fb, 1)], &[]), // 0: A1
            strategy(0, 5, &[10], &[(fa, 1)], &[]),          // 1: A2
            strategy(1, 3, &[10], &[(fa, 1), (fb, 2)], &[]), // 2: B1
            strategy(2, 50, &[10], &[(fc, 1)], &[]),         // 3: C
        ],
    );
    let selection = solve(&instance, &intensities(&[1, 1, 1]), DEFAULT_BUDGET).unwrap();
    // hbba_lite: {SolverResult(0, 1), SolverResult(2, 0)}: A's strategy 1, C's strategy 0.
    assert_eq!(chosen(&selection), [1, 3]);
    assert_eq!(selection.objective(), 55);
    assert_eq!(selection.usage(), [20]);
}

// ---------------------------------------------------------------------------------------------
// The brute-force reference: every selection (per class: none or one of its strategies),
// checked against the constraints as the module documentation states them, the best by
// objective and then by the tie-break.

struct Reference<'a> {
    instance: &'a Instance,
    intensities: &'a Intensities,
}

impl Reference<'_> {
    /// Classes in order of first appearance among the strategies.
    fn class_order(&self) -> Vec<usize> {
        let mut order = Vec::new();
        for s in &self.instance.strategies {
            if !order.contains(&usize::from(s.class)) {
                order.push(usize::from(s.class));
            }
        }
        order
    }

    fn desired(&self, class: usize) -> bool {
        self.intensities[class] != 0
    }

    /// `choice[class]`: the chosen strategy's index, if any. `None` if invalid, else the
    /// objective.
    fn evaluate(&self, choice: &[Option<usize>]) -> Option<u64> {
        let strategies = &self.instance.strategies;
        let picked: Vec<usize> = choice.iter().flatten().copied().collect();
        for (resource, &capacity) in self.instance.capacities.iter().enumerate() {
            let used: u64 = picked
                .iter()
                .map(|&s| u64::from(strategies[s].costs[resource]))
                .sum();
            if used > u64::from(capacity) {
                return None;
            }
        }
        for &a in &picked {
            for &b in &picked {
                for fa in &strategies[a].filters {
                    for fb in &strategies[b].filters {
                        if fa.connection == fb.connection && fa.phi != fb.phi {
                            return None;
                        }
                    }
                }
            }
            for r in &strategies[a].requires {
                match choice[usize::from(r.class)] {
                    Some(t) if strategies[t].utility >= r.min_utility => {}
                    _ => return None,
                }
            }
        }
        // Pulled-in classes: reachable through requirements from the desired classes' choices.
        let mut reached: Vec<usize> = Vec::new();
        let mut frontier: Vec<usize> = (0..choice.len())
            .filter(|&c| self.desired(c) && choice[c].is_some())
            .collect();
        while let Some(class) = frontier.pop() {
            if let Some(s) = choice[class] {
                for r in &strategies[s].requires {
                    let c = usize::from(r.class);
                    if !reached.contains(&c) {
                        reached.push(c);
                        frontier.push(c);
                    }
                }
            }
        }
        for (class, s) in choice.iter().enumerate() {
            if s.is_some() && !self.desired(class) && !reached.contains(&class) {
                return None;
            }
        }
        Some(
            choice
                .iter()
                .enumerate()
                .filter_map(|(class, s)| {
                    s.map(|s| u64::from(self.intensities[class]) * u64::from(strategies[s].utility))
                })
                .sum(),
        )
    }

    /// The tie-break key: per class in order, the chosen index or "none" (after every index).
    fn key(&self, choice: &[Option<usize>]) -> Vec<usize> {
        self.class_order()
            .iter()
            .map(|&c| choice[c].unwrap_or(usize::MAX))
            .collect()
    }

    /// The best selection: (choice, objective).
    fn solve(&self) -> (Vec<Option<usize>>, u64) {
        let classes = usize::from(self.instance.classes);
        let options: Vec<Vec<Option<usize>>> = (0..classes)
            .map(|c| {
                let mut o: Vec<Option<usize>> = vec![None];
                o.extend(
                    self.instance
                        .strategies
                        .iter()
                        .enumerate()
                        .filter(|(_, s)| usize::from(s.class) == c)
                        .map(|(i, _)| Some(i)),
                );
                o
            })
            .collect();
        let mut best: Option<(Vec<Option<usize>>, u64)> = None;
        let mut counters = vec![0usize; classes];
        loop {
            let choice: Vec<Option<usize>> =
                (0..classes).map(|c| options[c][counters[c]]).collect();
            if let Some(value) = self.evaluate(&choice) {
                let better = match &best {
                    None => true,
                    Some((incumbent, best_value)) => {
                        value > *best_value
                            || (value == *best_value && self.key(&choice) < self.key(incumbent))
                    }
                };
                if better {
                    best = Some((choice, value));
                }
            }
            // Next combination.
            let mut c = 0;
            loop {
                if c == classes {
                    return best.expect("choosing nothing is always valid");
                }
                counters[c] += 1;
                if counters[c] < options[c].len() {
                    break;
                }
                counters[c] = 0;
                c += 1;
            }
        }
    }
}

/// Random instances of up to `classes` classes, `strategies` strategies and 3 resources, with
/// utilities up to `utility` and intensities up to `intensity` (small ones make ties common);
/// filters on 3 connections with φ 0..=2; requirements with minimum utilities around the
/// utilities; some classes without a desire.
fn random_instance(
    classes: u8,
    strategies: usize,
    utility: u16,
    intensity: u16,
) -> impl proptest::strategy::Strategy<Value = (Instance, Intensities)> {
    (1u8..=classes, 0usize..=3)
        .prop_flat_map(move |(classes, resources)| {
            let strategy = (
                0..classes,
                0u16..=utility,
                prop::collection::vec(0u32..=12, resources),
                prop::collection::vec((0u16..3, 0u16..=2), 0..=3),
                prop::collection::vec((0..classes, 0u16..=utility), 0..=2),
            );
            (
                Just(classes),
                prop::collection::vec(1u32..=20, resources),
                prop::collection::vec(strategy, 0..=strategies),
                prop::collection::vec(
                    prop_oneof![2 => Just(0u16), 3 => 1u16..=intensity],
                    usize::from(classes),
                ),
            )
        })
        .prop_map(|(classes, capacities, strategies, desires)| {
            let mut instance = Instance {
                classes,
                ..Instance::default()
            };
            for capacity in capacities {
                instance.capacities.push(capacity).unwrap();
            }
            for (class, utility, costs, filters, requires) in strategies {
                let mut s = Strategy::new(class, utility);
                for (slot, cost) in s.costs.iter_mut().zip(costs) {
                    *slot = cost;
                }
                for (connection, phi) in filters {
                    if s.filters.iter().all(|f| f.connection != connection) {
                        s.filters.push(FilterSetting { connection, phi }).unwrap();
                    }
                }
                for (required, min_utility) in requires {
                    if required != class && s.requires.iter().all(|r| r.class != required) {
                        s.requires
                            .push(Requirement {
                                class: required,
                                min_utility,
                            })
                            .unwrap();
                    }
                }
                instance.strategies.push(s).unwrap();
            }
            let mut intensities = [0u16; MAX_CLASSES];
            for (slot, desire) in intensities
                .iter_mut()
                .zip(desires)
                .take(usize::from(classes))
            {
                *slot = desire;
            }
            (instance, intensities)
        })
}

fn agrees_with_brute_force(
    instance: &Instance,
    intensities: &Intensities,
) -> Result<(), TestCaseError> {
    let instance = instance.clone();
    let reference = Reference {
        instance: &instance,
        intensities,
    };
    let (choice, objective) = reference.solve();
    let selection = solve(&instance, intensities, DEFAULT_BUDGET).unwrap();
    let expected: Vec<usize> = choice.iter().flatten().copied().collect();
    let mut got = chosen(&selection);
    got.sort_unstable();
    let mut expected_sorted = expected.clone();
    expected_sorted.sort_unstable();
    prop_assert_eq!(got, expected_sorted);
    prop_assert_eq!(selection.objective(), objective);
    for (class, s) in choice.iter().enumerate() {
        prop_assert_eq!(selection.strategy_of(class), *s);
    }
    for (resource, &used) in selection.usage().iter().enumerate() {
        let costs: u64 = expected
            .iter()
            .map(|&s| u64::from(instance.strategies[s].costs[resource]))
            .sum();
        prop_assert_eq!(used, costs);
    }
    prop_assert_eq!(selection.usage().len(), instance.capacities.len());
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4_000, failure_persistence: None, ..ProptestConfig::default() })]

    /// The solver's selection is exactly the brute force's: same strategies (so the same
    /// tie-break), same objective, and the use it reports is the chosen strategies' costs. Up to
    /// 5 classes and 10 strategies, small numbers: many ties.
    #[test]
    fn the_solver_agrees_with_brute_force((instance, intensities) in random_instance(5, 10, 6, 3)) {
        agrees_with_brute_force(&instance, &intensities)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 500, failure_persistence: None, ..ProptestConfig::default() })]

    /// The same on larger instances (up to 8 classes, 16 strategies, wider utilities and
    /// intensities), where the bound cuts more of the search.
    #[test]
    fn the_solver_agrees_with_brute_force_on_larger_instances(
        (instance, intensities) in random_instance(8, 16, 1000, 50),
    ) {
        agrees_with_brute_force(&instance, &intensities)?;
    }
}

// ---------------------------------------------------------------------------------------------
// The tie-break, case by case.

/// Equal objectives: the class that comes first among the strategies decides, whatever its
/// index. Class 1 appears first (strategy 0); choosing class 1's strategy or class 0's gives 4
/// either way (only one fits): class 1's wins.
#[test]
fn ties_go_to_the_class_that_appears_first_among_the_strategies() {
    let instance = build(
        2,
        &[10],
        vec![
            strategy(1, 2, &[10], &[], &[]), // 0: class 1, first to appear
            strategy(0, 4, &[10], &[], &[]), // 1: class 0
        ],
    );
    let solver = Solver::new(&instance).unwrap();
    assert_eq!(solver.class_order(), [1, 0]);
    let selection = solver.solve(&intensities(&[1, 2]), DEFAULT_BUDGET).unwrap();
    assert_eq!(selection.objective(), 4);
    assert_eq!(chosen(&selection), [0]);
    // With the intensities swapped the objectives differ (8 against 2): no tie.
    let selection = solver.solve(&intensities(&[2, 1]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [1]);
}

/// Within a class, the strategy first in the file wins a tie.
#[test]
fn ties_within_a_class_go_to_the_strategy_first_in_the_file() {
    let instance = build(
        1,
        &[10],
        vec![
            strategy(0, 3, &[9], &[], &[]),
            strategy(0, 3, &[1], &[], &[]),
            strategy(0, 3, &[5], &[], &[]),
        ],
    );
    let selection = solve(&instance, &intensities(&[7]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [0]);
    assert_eq!(selection.objective(), 21);
}

/// At the first class where two best selections differ, choosing a strategy beats choosing
/// none: a strategy of utility 0 is chosen over nothing for a desire, and an undesired class
/// pulled in by one best selection beats the other that leaves it empty.
#[test]
fn ties_prefer_a_strategy_over_none() {
    let instance = build(1, &[], vec![strategy(0, 0, &[], &[], &[])]);
    let selection = solve(&instance, &intensities(&[5]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [0]);
    assert_eq!(selection.objective(), 0);

    // Class 1 (no desire) appears first. a1 requires it, a2 does not; both have utility 2.
    // {b, a1} and {a2} tie at 2; at class 1, the first compared, {b, a1} chose a strategy.
    let instance = build(
        2,
        &[],
        vec![
            strategy(1, 1, &[], &[], &[]),       // 0: b
            strategy(0, 2, &[], &[], &[(1, 0)]), // 1: a1, requires class 1
            strategy(0, 2, &[], &[], &[]),       // 2: a2
        ],
    );
    let selection = solve(&instance, &intensities(&[1, 0]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [0, 1]);
    assert_eq!(selection.objective(), 2);
}

/// A class without a desire has no strategy unless one is required; a required one adds
/// nothing to the objective; requirements are met by utility; two desire-less classes that
/// require each other do not pull each other in.
#[test]
fn classes_without_a_desire_are_only_pulled_in() {
    let instance = build(
        4,
        &[100],
        vec![
            strategy(0, 5, &[10], &[], &[(1, 3)]), // 0: go-to, needs a base strategy of utility ≥ 3
            strategy(1, 2, &[5], &[], &[]),        // 1: base, too weak
            strategy(1, 4, &[20], &[], &[]),       // 2: base, enough
            strategy(2, 1, &[1], &[], &[(3, 0)]),  // 3: class 2, requires class 3
            strategy(3, 1, &[1], &[], &[(2, 0)]),  // 4: class 3, requires class 2
        ],
    );
    let selection = solve(&instance, &intensities(&[3]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [0, 2]);
    assert_eq!(selection.objective(), 15);
    assert_eq!(selection.usage(), [30]);
    // Without the desire nothing runs.
    let selection = solve(&instance, &intensities(&[]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [] as [usize; 0]);
    // A desire on class 2 pulls in class 3 (and 3's requirement is met by 2).
    let selection = solve(&instance, &intensities(&[0, 0, 1]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [3, 4]);
    assert_eq!(selection.objective(), 1);
    // A requirement that cannot be met (capacity too small for go-to with a base of utility ≥ 3)
    // leaves the desire unfulfilled.
    let mut tight = instance.clone();
    tight.capacities[0] = 29;
    let selection = solve(&tight, &intensities(&[3]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [] as [usize; 0]);
}

/// φ = 0 (closed) is a setting like any other: two strategies that both close a connection
/// agree; one that closes it and one that opens it do not.
#[test]
fn closing_a_connection_is_a_filter_setting_that_must_agree() {
    let instance = build(
        3,
        &[],
        vec![
            strategy(0, 1, &[], &[(7, 0)], &[]),
            strategy(1, 1, &[], &[(7, 0)], &[]),
            strategy(2, 3, &[], &[(7, 1)], &[]),
        ],
    );
    let selection = solve(&instance, &intensities(&[1, 1, 1]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [2]);
    let selection = solve(&instance, &intensities(&[2, 2, 1]), DEFAULT_BUDGET).unwrap();
    assert_eq!(chosen(&selection), [0, 1]);
}

// ---------------------------------------------------------------------------------------------
// Numbers and bounds.

/// 16 classes, each desired at 65 535 with a strategy of utility 65 535: the objective is
/// 16 · 65 535² = 68 717 379 600 (far above u32), exact.
#[test]
fn intensity_times_utility_at_65535_squared_does_not_overflow() {
    let strategies = (0..16u8)
        .map(|class| strategy(class, u16::MAX, &[u32::MAX], &[], &[]))
        .collect();
    let mut instance = build(16, &[u32::MAX], strategies);
    let all = [u16::MAX; MAX_CLASSES];
    // Only one fits the capacity u32::MAX: the first class's.
    let selection = solve(&instance, &all, DEFAULT_BUDGET).unwrap();
    assert_eq!(selection.objective(), 65_535 * 65_535);
    assert_eq!(chosen(&selection), [0]);
    assert_eq!(selection.usage(), [u64::from(u32::MAX)]);
    // Costs of 2^32 − 1 each add up past u32 in the use too; free costs let all 16 run.
    for s in instance.strategies.iter_mut() {
        s.costs[0] = 0;
    }
    let selection = solve(&instance, &all, DEFAULT_BUDGET).unwrap();
    assert_eq!(selection.objective(), 16 * 65_535u64 * 65_535);
    assert_eq!(selection.objective(), 68_717_379_600);
    assert_eq!(selection.strategies().count(), 16);
}

/// The budget is enforced: a solve that needs N nodes succeeds with a budget of N and fails
/// with `BudgetExceeded` at N − 1; never a different selection.
#[test]
fn the_work_budget_is_enforced_exactly() {
    let (instance, intensities) = hbba_instances::instance(16, 64, 8, 3);
    let solver = Solver::new(&instance).unwrap();
    let selection = solver.solve(&intensities, DEFAULT_BUDGET).unwrap();
    let needed = selection.visits();
    assert!(needed > 16, "{needed}");
    assert_eq!(solver.solve(&intensities, needed), Ok(selection));
    assert_eq!(
        solver.solve(&intensities, needed - 1),
        Err(HbbaError::BudgetExceeded { budget: needed - 1 })
    );
    assert_eq!(
        solver.solve(&intensities, 0),
        Err(HbbaError::BudgetExceeded { budget: 0 })
    );
    // Instances the bound cannot cut (`hbba_instances::adversarial`): the default budget
    // refuses them.
    let (hard, all) = hbba_instances::adversarial(4, 8);
    assert_eq!(
        solve(&hard, &all, DEFAULT_BUDGET),
        Err(HbbaError::BudgetExceeded {
            budget: DEFAULT_BUDGET
        })
    );
    let (hard, all) = hbba_instances::adversarial(2, 2);
    assert_eq!(
        solve(&hard, &all, DEFAULT_BUDGET),
        Err(HbbaError::BudgetExceeded {
            budget: DEFAULT_BUDGET
        })
    );
}

/// The nodes visited by the benchmark's instances (`cargo bench -p pab-core --bench hbba` times
/// them), per size: printed for the documentation (`--nocapture`), and each within the default
/// budget.
#[test]
fn work_at_each_size_is_printed() {
    for (classes, strategies, resources) in hbba_instances::SIZES {
        let mut visits: Vec<u32> = (0..hbba_instances::SEEDS)
            .map(|seed| {
                let (instance, intensities) =
                    hbba_instances::instance(classes, strategies, resources, seed);
                let selection = solve(&instance, &intensities, DEFAULT_BUDGET).unwrap();
                selection.visits()
            })
            .collect();
        visits.sort_unstable();
        println!(
            "{classes} classes, {strategies} strategies, {resources} resources: nodes visited median {}, max {}",
            visits[visits.len() / 2],
            visits[visits.len() - 1]
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Checks of an instance and of desires.

#[test]
fn invalid_instances_and_desires_are_refused_with_the_offender() {
    let ok = || build(2, &[10], vec![strategy(0, 1, &[1], &[(0, 1)], &[(1, 0)])]);
    assert!(Solver::new(&ok()).is_ok());

    let mut bad = ok();
    bad.classes = 17;
    assert_eq!(Solver::new(&bad).err(), Some(HbbaError::TooManyClasses));

    let mut bad = ok();
    bad.capacities[0] = 0;
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::ZeroCapacity { resource: 0 })
    );

    let mut bad = ok();
    bad.strategies.push(strategy(2, 1, &[], &[], &[])).unwrap();
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::UnknownClass { strategy: 1 })
    );

    let mut bad = ok();
    bad.strategies[0].requires[0].class = 5;
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::UnknownClass { strategy: 0 })
    );

    let mut bad = ok();
    bad.strategies[0].costs[1] = 3;
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::UnknownResource { strategy: 0 })
    );

    let mut bad = ok();
    bad.strategies[0]
        .filters
        .push(FilterSetting {
            connection: 0,
            phi: 1,
        })
        .unwrap();
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::DuplicateFilter { strategy: 0 })
    );

    let mut bad = ok();
    bad.strategies[0]
        .requires
        .push(Requirement {
            class: 1,
            min_utility: 2,
        })
        .unwrap();
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::DuplicateRequirement { strategy: 0 })
    );

    let mut bad = ok();
    bad.strategies[0].requires[0].class = 0;
    assert_eq!(
        Solver::new(&bad).err(),
        Some(HbbaError::SelfRequirement { strategy: 0 })
    );

    let instance = ok();
    let solver = Solver::new(&instance).unwrap();
    assert_eq!(
        solver.solve(&intensities(&[1, 1, 1]), DEFAULT_BUDGET),
        Err(HbbaError::UnknownDesire { class: 2 })
    );
    // Intensity 0 is no desire, on any class.
    assert!(
        solver
            .solve(&intensities(&[1, 1, 0, 0]), DEFAULT_BUDGET)
            .is_ok()
    );

    // The capacities are the types' own: a 65th strategy, a 9th resource, filter or
    // requirement cannot be pushed.
    let mut full = Instance::default();
    for _ in 0..MAX_STRATEGIES {
        full.strategies.push(Strategy::new(0, 0)).unwrap();
    }
    assert!(full.strategies.push(Strategy::new(0, 0)).is_err());
    for _ in 0..MAX_RESOURCES {
        full.capacities.push(1).unwrap();
    }
    assert!(full.capacities.push(1).is_err());
    let mut s = Strategy::new(0, 0);
    for connection in 0..MAX_FILTERS as u16 {
        s.filters
            .push(FilterSetting { connection, phi: 1 })
            .unwrap();
    }
    assert!(
        s.filters
            .push(FilterSetting {
                connection: 99,
                phi: 1
            })
            .is_err()
    );
    for class in 1..=MAX_REQUIRES as u8 {
        s.requires
            .push(Requirement {
                class,
                min_utility: 0,
            })
            .unwrap();
    }
    assert!(
        s.requires
            .push(Requirement {
                class: 9,
                min_utility: 0
            })
            .is_err()
    );
}

/// An instance without strategies, or without desires, selects nothing with objective 0.
#[test]
fn nothing_to_choose_selects_nothing() {
    let empty = Instance::default();
    let selection = solve(&empty, &[0; MAX_CLASSES], DEFAULT_BUDGET).unwrap();
    assert_eq!(selection.strategies().count(), 0);
    assert_eq!(selection.objective(), 0);
    assert_eq!(selection.visits(), 1);
    assert_eq!(
        solve(&empty, &intensities(&[1]), DEFAULT_BUDGET),
        Err(HbbaError::UnknownDesire { class: 0 })
    );
}
