//! What the solver is given: classes, resources and strategies, with fixed capacities, and the
//! checks that make an [`Instance`] solvable.

use heapless::Vec;
use serde::{Deserialize, Serialize};

use super::{MAX_CLASSES, MAX_FILTERS, MAX_REQUIRES, MAX_RESOURCES, MAX_STRATEGIES};

/// One desire intensity per class, indexed by class; 0: the class has no desire. Intensities are
/// what the intention workspace selected (per class, the most intense desire): the solver sees
/// one number per class.
pub type Intensities = [u16; MAX_CLASSES];

/// A filter a strategy sets: connection `connection` passes one frame in `phi` (DESIGN.md, "HBBA:
/// decisions": φ = 1 passes all, φ = N one in N, φ = 0 closes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FilterSetting {
    /// The connection, as its user numbers connections (the network's connection index for
    /// `pabctl`); two strategies agree on it when they set the same `phi`.
    pub connection: u16,
    /// φ: 0 closes, 1 passes every frame, N one frame in N.
    pub phi: u16,
}

/// A dependency of a strategy: the strategy chosen for class `class` must have a utility of at
/// least `min_utility` (0: any strategy of that class).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Requirement {
    /// The class that must have a strategy.
    pub class: u8,
    /// The least utility that strategy may have.
    pub min_utility: u16,
}

/// How one class of desire can be fulfilled: its utility, what it costs of each resource, the
/// filters it sets and the classes it depends on.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Strategy {
    /// The class it fulfils, `0..Instance::classes`.
    pub class: u8,
    /// Its utility: the objective gains intensity × utility when it is chosen for a class with
    /// a desire.
    pub utility: u16,
    /// Its cost of each resource, indexed like [`Instance::capacities`]; entries past the
    /// instance's resources must be 0.
    pub costs: [u32; MAX_RESOURCES],
    /// The filters it sets, each connection at most once.
    pub filters: Vec<FilterSetting, MAX_FILTERS>,
    /// The classes it depends on, each at most once, never its own.
    pub requires: Vec<Requirement, MAX_REQUIRES>,
}

impl Strategy {
    /// A strategy of class `class` with utility `utility`, costing nothing, setting no filter and
    /// requiring nothing.
    pub const fn new(class: u8, utility: u16) -> Strategy {
        Strategy {
            class,
            utility,
            costs: [0; MAX_RESOURCES],
            filters: Vec::new(),
            requires: Vec::new(),
        }
    }
}

/// A problem for the solver: classes `0..classes`, one capacity per resource, and the strategies
/// in file order (their indices are what [`super::Selection`] reports, and the tie-break prefers
/// the lower one).
///
/// Memory: 104 bytes per strategy, 6.6 KiB at full capacity.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instance {
    /// How many classes there are, at most [`MAX_CLASSES`].
    pub classes: u8,
    /// Each resource's capacity, positive.
    pub capacities: Vec<u32, MAX_RESOURCES>,
    /// The strategies, in file order.
    pub strategies: Vec<Strategy, MAX_STRATEGIES>,
}

/// Why an instance, a set of desires or a search was refused. Indices are the instance's
/// (strategies, resources, classes as numbered there).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum HbbaError {
    /// More classes than [`MAX_CLASSES`].
    TooManyClasses,
    /// A resource with capacity 0: every strategy that uses it could never run, and one that
    /// does not has no reason to name it.
    ZeroCapacity {
        /// The resource.
        resource: u8,
    },
    /// A strategy of a class, or requiring a class, outside `0..classes`.
    UnknownClass {
        /// The strategy.
        strategy: u8,
    },
    /// A strategy with a non-zero cost past the instance's resources.
    UnknownResource {
        /// The strategy.
        strategy: u8,
    },
    /// A strategy that sets one connection's filter twice.
    DuplicateFilter {
        /// The strategy.
        strategy: u8,
    },
    /// A strategy that requires one class twice.
    DuplicateRequirement {
        /// The strategy.
        strategy: u8,
    },
    /// A strategy that requires its own class (the strategy of that class is itself).
    SelfRequirement {
        /// The strategy.
        strategy: u8,
    },
    /// A desire (non-zero intensity) for a class outside `0..classes`.
    UnknownDesire {
        /// The class.
        class: u8,
    },
    /// The search would have visited more nodes than its budget allows: no answer rather than a
    /// possibly wrong one.
    BudgetExceeded {
        /// The budget, in nodes visited.
        budget: u32,
    },
}

impl core::fmt::Display for HbbaError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            HbbaError::TooManyClasses => {
                write!(f, "more than {MAX_CLASSES} classes of desire")
            }
            HbbaError::ZeroCapacity { resource } => {
                write!(f, "resource {resource} has capacity 0")
            }
            HbbaError::UnknownClass { strategy } => {
                write!(f, "strategy {strategy} names an unknown class")
            }
            HbbaError::UnknownResource { strategy } => {
                write!(f, "strategy {strategy} costs an unknown resource")
            }
            HbbaError::DuplicateFilter { strategy } => {
                write!(f, "strategy {strategy} sets one connection's filter twice")
            }
            HbbaError::DuplicateRequirement { strategy } => {
                write!(f, "strategy {strategy} requires one class twice")
            }
            HbbaError::SelfRequirement { strategy } => {
                write!(f, "strategy {strategy} requires its own class")
            }
            HbbaError::UnknownDesire { class } => {
                write!(f, "desire for unknown class {class}")
            }
            HbbaError::BudgetExceeded { budget } => write!(
                f,
                "the intention solver gave up after visiting {budget} nodes (its work budget)"
            ),
        }
    }
}

impl core::error::Error for HbbaError {}

impl Instance {
    /// Checks every index and count: the classes within [`MAX_CLASSES`], every capacity
    /// positive, every strategy's class and requirements within the classes, no cost past the
    /// resources, no connection or required class twice in one strategy, no strategy requiring
    /// its own class. Reports the first problem, in strategy order. Costs O(S · (F² + Q²)) for S
    /// strategies of F filters and Q requirements, at most 64 · (64 + 16) comparisons.
    pub fn validate(&self) -> Result<(), HbbaError> {
        if usize::from(self.classes) > MAX_CLASSES {
            return Err(HbbaError::TooManyClasses);
        }
        for (resource, &capacity) in (0u8..).zip(self.capacities.iter()) {
            if capacity == 0 {
                return Err(HbbaError::ZeroCapacity { resource });
            }
        }
        let resources = self.capacities.len();
        for (strategy, s) in (0u8..).zip(self.strategies.iter()) {
            if s.class >= self.classes {
                return Err(HbbaError::UnknownClass { strategy });
            }
            if s.costs.iter().skip(resources).any(|&cost| cost != 0) {
                return Err(HbbaError::UnknownResource { strategy });
            }
            for (i, filter) in s.filters.iter().enumerate() {
                if s.filters
                    .iter()
                    .skip(i + 1)
                    .any(|other| other.connection == filter.connection)
                {
                    return Err(HbbaError::DuplicateFilter { strategy });
                }
            }
            for (i, requirement) in s.requires.iter().enumerate() {
                if requirement.class >= self.classes {
                    return Err(HbbaError::UnknownClass { strategy });
                }
                if requirement.class == s.class {
                    return Err(HbbaError::SelfRequirement { strategy });
                }
                if s.requires
                    .iter()
                    .skip(i + 1)
                    .any(|other| other.class == requirement.class)
                {
                    return Err(HbbaError::DuplicateRequirement { strategy });
                }
            }
        }
        Ok(())
    }
}
