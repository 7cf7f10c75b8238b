//! The search: exact branch and bound over the classes, in the order of the tie-break.

use super::instance::{HbbaError, Instance, Intensities};
use super::{MAX_CLASSES, MAX_RESOURCES, MAX_STRATEGIES};

/// The class (or strategy) index that means "none" in [`Selection::strategy_of`]'s storage.
const NONE: u8 = u8::MAX;

/// What the solver chose: at most one strategy per class, the objective and each resource's use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Selection {
    /// Bit s: strategy s is chosen.
    chosen: u64,
    /// Per class, its chosen strategy or [`NONE`].
    of_class: [u8; MAX_CLASSES],
    /// Σ intensity × utility over the classes with a desire.
    objective: u64,
    /// Per resource, the sum of the chosen strategies' costs.
    used: [u64; MAX_RESOURCES],
    /// How many resources the instance has.
    resources: u8,
    /// Search nodes visited.
    visits: u32,
}

impl Selection {
    /// The chosen strategies' indices, ascending (file order).
    pub fn strategies(&self) -> impl Iterator<Item = usize> + '_ {
        let mut mask = self.chosen;
        core::iter::from_fn(move || {
            if mask == 0 {
                return None;
            }
            let index = mask.trailing_zeros();
            mask &= mask - 1;
            usize::try_from(index).ok()
        })
    }

    /// Whether strategy `strategy` is chosen.
    pub fn is_chosen(&self, strategy: usize) -> bool {
        strategy < MAX_STRATEGIES && self.chosen >> strategy & 1 == 1
    }

    /// The strategy chosen for class `class`, if any.
    pub fn strategy_of(&self, class: usize) -> Option<usize> {
        match self.of_class.get(class) {
            Some(&NONE) | None => None,
            Some(&strategy) => Some(usize::from(strategy)),
        }
    }

    /// Σ intensity × utility over the classes with a desire (a class chosen only because another
    /// strategy requires it adds nothing).
    pub const fn objective(&self) -> u64 {
        self.objective
    }

    /// Each resource's use (the sum of the chosen strategies' costs), indexed like the
    /// instance's capacities.
    pub fn usage(&self) -> &[u64] {
        self.used
            .get(..usize::from(self.resources))
            .unwrap_or(&self.used)
    }

    /// How many search nodes the solve visited (the root, each partial selection that passed
    /// the checks, each leaf).
    pub const fn visits(&self) -> u32 {
        self.visits
    }
}

/// An instance, checked and prepared for solving many sets of desires: the class order of the
/// tie-break, a compatibility matrix of the strategies, and per class its strategies and the
/// classes that may require it.
///
/// Memory: 880 bytes beside the instance it borrows; a solve uses about 2.5 KiB of stack. [`Solver::new`] costs O(S² · F²) for S
/// strategies of F filters (at most 64² · 64 filter comparisons, a few hundred microseconds at
/// full capacity); build it once per instance.
#[derive(Clone, Debug)]
pub struct Solver<'a> {
    instance: &'a Instance,
    /// The classes that have strategies, in order of first appearance among the strategies.
    order: [u8; MAX_CLASSES],
    /// How many entries of `order` are used.
    ordered: usize,
    /// `later[d]`: the classes `order[d..]`, as a mask.
    later: [u16; MAX_CLASSES + 1],
    /// Per strategy, the strategies it cannot be chosen with: a filter set to another φ, or a
    /// requirement the other (the only strategy its class can then have) does not meet.
    conflicts: [u64; MAX_STRATEGIES],
    /// Per strategy, the classes it requires.
    requires: [u16; MAX_STRATEGIES],
    /// Per class, its strategies.
    strategies_of: [u64; MAX_CLASSES],
    /// Per class, the classes with a strategy that requires it.
    requirers: [u16; MAX_CLASSES],
    /// The strategies that can never be chosen: they require a class none of whose strategies
    /// has the utility they need (or that has no strategy at all).
    impossible: u64,
}

/// A partial selection: the classes decided so far.
#[derive(Clone, Copy)]
struct Partial {
    chosen: u64,
    /// Classes decided to have no strategy.
    none: u16,
    /// Classes the chosen strategies require.
    required: u16,
    value: u64,
    used: [u64; MAX_RESOURCES],
    of_class: [u8; MAX_CLASSES],
}

/// One solve's bookkeeping.
struct Search<'d> {
    intensities: &'d Intensities,
    budget: u32,
    visits: u32,
    best: Option<Partial>,
    /// Per resource, the strategies by value (intensity × utility) per unit of that resource,
    /// highest first (free ones first of all); ties by index.
    by_density: [[u8; MAX_STRATEGIES]; MAX_RESOURCES],
    /// How many entries of each `by_density` row are used: the instance's strategies.
    ranked: usize,
}

const fn bit16(class: usize) -> u16 {
    if class < 16 { 1 << class } else { 0 }
}

const fn bit64(strategy: usize) -> u64 {
    if strategy < 64 { 1 << strategy } else { 0 }
}

impl<'a> Solver<'a> {
    /// Checks `instance` ([`Instance::validate`]) and prepares it.
    pub fn new(instance: &'a Instance) -> Result<Solver<'a>, HbbaError> {
        instance.validate()?;
        let mut solver = Solver {
            instance,
            order: [NONE; MAX_CLASSES],
            ordered: 0,
            later: [0; MAX_CLASSES + 1],
            conflicts: [0; MAX_STRATEGIES],
            requires: [0; MAX_STRATEGIES],
            strategies_of: [0; MAX_CLASSES],
            requirers: [0; MAX_CLASSES],
            impossible: 0,
        };
        let strategies = &instance.strategies;
        for (index, strategy) in strategies.iter().enumerate() {
            let class = usize::from(strategy.class);
            if let Some(mask) = solver.strategies_of.get_mut(class) {
                if *mask == 0 {
                    if let Some(slot) = solver.order.get_mut(solver.ordered) {
                        *slot = strategy.class;
                    }
                    solver.ordered += 1;
                }
                *mask |= bit64(index);
            }
            let mut required = 0;
            for requirement in &strategy.requires {
                required |= bit16(usize::from(requirement.class));
                if let Some(requirers) = solver.requirers.get_mut(usize::from(requirement.class)) {
                    *requirers |= bit16(class);
                }
            }
            if let Some(slot) = solver.requires.get_mut(index) {
                *slot = required;
            }
        }
        for (index, strategy) in strategies.iter().enumerate() {
            let unmeetable = strategy.requires.iter().any(|r| {
                !strategies
                    .iter()
                    .any(|t| t.class == r.class && t.utility >= r.min_utility)
            });
            if unmeetable {
                solver.impossible |= bit64(index);
            }
        }
        // Validated: at most MAX_CLASSES classes, so `ordered` ≤ MAX_CLASSES.
        for depth in (0..solver.ordered).rev() {
            let class = solver.order.get(depth).map_or(NONE, |&c| c);
            let after = solver.later.get(depth + 1).copied().unwrap_or(0);
            if let Some(slot) = solver.later.get_mut(depth) {
                *slot = after | bit16(usize::from(class));
            }
        }
        for (i, a) in strategies.iter().enumerate() {
            for (j, b) in strategies.iter().enumerate().skip(i + 1) {
                let filters_disagree = a.filters.iter().any(|fa| {
                    b.filters
                        .iter()
                        .any(|fb| fa.connection == fb.connection && fa.phi != fb.phi)
                });
                let unmet = |x: &super::Strategy, y: &super::Strategy| {
                    x.requires
                        .iter()
                        .any(|r| r.class == y.class && y.utility < r.min_utility)
                };
                if a.class != b.class && (filters_disagree || unmet(a, b) || unmet(b, a)) {
                    if let Some(slot) = solver.conflicts.get_mut(i) {
                        *slot |= bit64(j);
                    }
                    if let Some(slot) = solver.conflicts.get_mut(j) {
                        *slot |= bit64(i);
                    }
                }
            }
        }
        Ok(solver)
    }

    /// The instance.
    pub const fn instance(&self) -> &'a Instance {
        self.instance
    }

    /// The classes that have strategies, in order of first appearance among the strategies: the
    /// order in which the tie-break compares selections.
    pub fn class_order(&self) -> &[u8] {
        self.order.get(..self.ordered).unwrap_or(&[])
    }

    /// The best selection for `intensities` (module documentation: constraints, objective and
    /// tie-break), visiting at most `budget` search nodes ([`super::DEFAULT_BUDGET`] is a
    /// sensible one). Fails with [`HbbaError::UnknownDesire`] for a desire on a class past the
    /// instance's, and with [`HbbaError::BudgetExceeded`] when the search needs more nodes than
    /// `budget`: never with a selection that might not be the best. Each node costs at most
    /// one bound (O(S · R) for S strategies and R resources) and one check per option of its
    /// class (O(R)); no allocation, recursion at most [`MAX_CLASSES`] + 1 deep.
    pub fn solve(&self, intensities: &Intensities, budget: u32) -> Result<Selection, HbbaError> {
        for (class, &intensity) in (0u8..).zip(intensities.iter()) {
            if intensity != 0 && class >= self.instance.classes {
                return Err(HbbaError::UnknownDesire { class });
            }
        }
        let mut search = Search {
            intensities,
            budget,
            visits: 0,
            best: None,
            by_density: [[0; MAX_STRATEGIES]; MAX_RESOURCES],
            ranked: self.instance.strategies.len(),
        };
        self.rank(&mut search);
        let root = Partial {
            chosen: 0,
            none: 0,
            required: 0,
            value: 0,
            used: [0; MAX_RESOURCES],
            of_class: [NONE; MAX_CLASSES],
        };
        self.visit(&mut search, 0, &root)?;
        // The selection that chooses nothing is always valid, so the search found one.
        let best = search.best.unwrap_or(root);
        Ok(Selection {
            chosen: best.chosen,
            of_class: best.of_class,
            objective: best.value,
            used: best.used,
            resources: u8::try_from(self.instance.capacities.len()).unwrap_or(0),
            visits: search.visits,
        })
    }

    /// Fills `search.by_density`: O(R · S log S).
    fn rank(&self, search: &mut Search<'_>) {
        let strategies = &self.instance.strategies;
        let value = |index: u8| {
            strategies.get(usize::from(index)).map_or(0, |s| {
                Self::intensity(search, usize::from(s.class)) * u64::from(s.utility)
            })
        };
        let mut rows = search.by_density;
        let resources = self.instance.capacities.len();
        for (resource, row) in rows.iter_mut().enumerate().take(resources) {
            let cost = |index: u8| {
                strategies
                    .get(usize::from(index))
                    .and_then(|s| s.costs.get(resource))
                    .map_or(0, |&c| u64::from(c))
            };
            for (slot, index) in row.iter_mut().zip(0u8..) {
                *slot = index;
            }
            if let Some(used) = row.get_mut(..search.ranked) {
                // Free strategies of some value first, then by value / cost, highest first
                // (compared without dividing: products below 2^64 · 2^32), the worthless last;
                // ties by index. A total order, as sorting requires.
                let rank = |index: u8| match (value(index), cost(index)) {
                    (0, _) => 2u8,
                    (_, 0) => 0,
                    _ => 1,
                };
                used.sort_unstable_by(|&a, &b| {
                    let by_ratio = if rank(a) == 1 && rank(b) == 1 {
                        let left = u128::from(value(b)) * u128::from(cost(a));
                        let right = u128::from(value(a)) * u128::from(cost(b));
                        left.cmp(&right)
                    } else {
                        core::cmp::Ordering::Equal
                    };
                    rank(a).cmp(&rank(b)).then(by_ratio).then(a.cmp(&b))
                });
            }
        }
        search.by_density = rows;
    }

    fn intensity(search: &Search<'_>, class: usize) -> u64 {
        search.intensities.get(class).map_or(0, |&i| u64::from(i))
    }

    /// Visits the node `at`, whose classes `order[..depth]` are decided, and below it the
    /// options of class `order[depth]`: its strategies in file order, then none.
    fn visit(&self, search: &mut Search<'_>, depth: usize, at: &Partial) -> Result<(), HbbaError> {
        search.visits = search.visits.saturating_add(1);
        if search.visits > search.budget {
            return Err(HbbaError::BudgetExceeded {
                budget: search.budget,
            });
        }
        let class = match self.order.get(depth) {
            Some(&class) if depth < self.ordered => usize::from(class),
            _ => {
                // A leaf: every class decided. Leaves come in tie-break order, so only a
                // strictly better one replaces the best so far.
                if self.rooted(search, at) && search.best.is_none_or(|best| at.value > best.value) {
                    search.best = Some(*at);
                }
                return Ok(());
            }
        };
        if let Some(best) = search.best {
            // Everything below comes after the best so far in tie-break order: it must do
            // strictly better, and cannot do better than the bound.
            if !self.may_exceed(search, depth, at, best.value) {
                return Ok(());
            }
        }
        let desired = Self::intensity(search, class) != 0;
        let later = self.later.get(depth + 1).copied().unwrap_or(0);
        let mut options = self.strategies_of.get(class).copied().unwrap_or(0);
        while options != 0 {
            let index = options.trailing_zeros() as usize;
            options &= options - 1;
            // A class without a desire takes a strategy only for a strategy that requires it:
            // one chosen already, or possibly one of a class still to decide (the leaf checks).
            if !desired
                && at.required & bit16(class) == 0
                && self.requirers.get(class).is_none_or(|&r| r & later == 0)
            {
                break;
            }
            if let Some(next) = self.choose(search, at, class, index) {
                self.visit(search, depth + 1, &next)?;
            }
        }
        if at.required & bit16(class) == 0 {
            let mut next = *at;
            next.none |= bit16(class);
            self.visit(search, depth + 1, &next)?;
        }
        Ok(())
    }

    /// `at` with strategy `index` chosen for `class`, if it is compatible: no conflict with the
    /// chosen strategies, none of its required classes decided empty, within every capacity.
    fn choose(
        &self,
        search: &Search<'_>,
        at: &Partial,
        class: usize,
        index: usize,
    ) -> Option<Partial> {
        let strategy = self.instance.strategies.get(index)?;
        if self.fits(at, index)? {
            let mut next = *at;
            next.chosen |= bit64(index);
            next.required |= self.requires.get(index).copied().unwrap_or(0);
            // Intensity and utility are u16: their product is below 2^32, a sum of 16 below 2^36.
            next.value = next.value.saturating_add(
                Self::intensity(search, class).saturating_mul(u64::from(strategy.utility)),
            );
            for (used, &cost) in next.used.iter_mut().zip(strategy.costs.iter()) {
                *used = used.saturating_add(u64::from(cost));
            }
            if let Some(slot) = next.of_class.get_mut(class) {
                *slot = u8::try_from(index).ok()?;
            }
            Some(next)
        } else {
            None
        }
    }

    /// Whether strategy `index` can join `at` (`None` for an index past the strategies).
    fn fits(&self, at: &Partial, index: usize) -> Option<bool> {
        let strategy = self.instance.strategies.get(index)?;
        let conflicts = self.conflicts.get(index).copied().unwrap_or(0);
        let requires = self.requires.get(index).copied().unwrap_or(0);
        if conflicts & at.chosen != 0
            || requires & at.none != 0
            || self.impossible & bit64(index) != 0
        {
            return Some(false);
        }
        Some(
            at.used
                .iter()
                .zip(strategy.costs.iter())
                .zip(self.instance.capacities.iter())
                .all(|((&used, &cost), &capacity)| {
                    used.saturating_add(u64::from(cost)) <= u64::from(capacity)
                }),
        )
    }

    /// Whether a leaf below `at` may have an objective above `threshold`: whether an upper bound
    /// on their objective exceeds it. The bound is `at`'s value plus the least of these
    /// relaxations of what the classes still to decide can add (`I_k · u_s` is the value
    /// of strategy s of class k, its candidates those that could still join `at` on their own:
    /// no conflict with the chosen strategies, no required class decided empty, within the
    /// remaining capacities):
    ///
    /// - each class with a desire its best candidate's value (the capacities ignored);
    /// - per resource, the fractional knapsack of the candidates within its remaining capacity,
    ///   each class's value capped at its best candidate's (the other resources ignored): taken
    ///   greedily by value per unit of the resource (`Search::by_density`), which is the exact
    ///   optimum of that linear relaxation, rounded up.
    ///
    /// O(S · R): one [`Solver::fits`] per strategy of a class still to decide, then one pass
    /// over the strategies per resource, until a relaxation falls to the threshold.
    fn may_exceed(&self, search: &Search<'_>, depth: usize, at: &Partial, threshold: u64) -> bool {
        let Some(threshold) = threshold.checked_sub(at.value) else {
            return true;
        };
        let mut candidates = 0u64;
        let mut caps = [0u64; MAX_CLASSES];
        for &class in self.order.get(depth..self.ordered).unwrap_or(&[]) {
            let class = usize::from(class);
            let intensity = Self::intensity(search, class);
            if intensity == 0 {
                continue;
            }
            let mut options = self.strategies_of.get(class).copied().unwrap_or(0);
            while options != 0 {
                let index = options.trailing_zeros() as usize;
                options &= options - 1;
                if let Some(strategy) = self.instance.strategies.get(index)
                    && strategy.utility != 0
                    && self.fits(at, index) == Some(true)
                {
                    candidates |= bit64(index);
                    if let Some(cap) = caps.get_mut(class) {
                        *cap = (*cap).max(intensity * u64::from(strategy.utility));
                    }
                }
            }
        }
        // Intensity × utility < 2^32, 16 of them < 2^36.
        if caps.iter().sum::<u64>() <= threshold {
            return false;
        }
        for (resource, (&capacity, &used)) in self
            .instance
            .capacities
            .iter()
            .zip(at.used.iter())
            .enumerate()
        {
            let Some(order) = search.by_density.get(resource) else {
                break;
            };
            let mut left = u128::from(u64::from(capacity).saturating_sub(used));
            let mut room = caps;
            let mut total = 0u64;
            for &index in order.get(..search.ranked).unwrap_or(&[]) {
                let index = usize::from(index);
                if candidates & bit64(index) == 0 {
                    continue;
                }
                let Some(strategy) = self.instance.strategies.get(index) else {
                    continue;
                };
                let class = usize::from(strategy.class);
                let Some(room) = room.get_mut(class) else {
                    continue;
                };
                let value = Self::intensity(search, class) * u64::from(strategy.utility);
                let take = value.min(*room);
                if take == 0 || value == 0 {
                    continue;
                }
                let cost = u128::from(strategy.costs.get(resource).copied().unwrap_or(0));
                // What `take` of the value costs, rounded down (a cheaper relaxation is still
                // one). `value` > 0.
                let paid = cost * u128::from(take) / u128::from(value);
                if paid <= left {
                    left -= paid;
                    total += take;
                    *room -= take;
                    if total > threshold {
                        // This relaxation cannot cut: the next might.
                        break;
                    }
                } else {
                    // The fraction that fits, rounded up: left · value / cost (< take).
                    let part = (left * u128::from(value)).div_ceil(cost.max(1));
                    total += u64::try_from(part).unwrap_or(take).min(take);
                    break;
                }
            }
            if total <= threshold {
                return false;
            }
        }
        true
    }

    /// Whether every chosen strategy of a class without a desire is required, directly or
    /// through other such strategies, by a chosen strategy of a class with a desire.
    fn rooted(&self, search: &Search<'_>, at: &Partial) -> bool {
        let mut undesired_chosen = 0u16;
        let mut reached = 0u16;
        for (class, &strategy) in at.of_class.iter().enumerate() {
            if strategy == NONE {
                continue;
            }
            let requires = self
                .requires
                .get(usize::from(strategy))
                .copied()
                .unwrap_or(0);
            if Self::intensity(search, class) != 0 {
                reached |= requires;
            } else {
                undesired_chosen |= bit16(class);
            }
        }
        if undesired_chosen == 0 {
            return true;
        }
        // Each round adds at least one class or stops: at most MAX_CLASSES rounds.
        loop {
            let mut next = reached;
            for (class, &strategy) in at.of_class.iter().enumerate() {
                if strategy != NONE && reached & bit16(class) != 0 {
                    next |= self
                        .requires
                        .get(usize::from(strategy))
                        .copied()
                        .unwrap_or(0);
                }
            }
            if next == reached {
                break;
            }
            reached = next;
        }
        undesired_chosen & !reached == 0
    }
}
