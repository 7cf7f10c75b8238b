//! Competitive dynamics (Bergener and Steinhage): elementary behaviours selected by a dynamical
//! system, integrated in fixed point at a fixed step on the board.
//!
//! The equations, as reconstructed in DESIGN.md ("Competitive dynamics: decisions"), time in
//! units of the equations:
//!
//! ```text
//! (1) τ dn_i/dt = α_i n_i − |α_i| n_i³ − Σ_{j≠i} γ_ij n_j² n_i + noise
//! (2) α_i = 2 ρ_i I_i − 1
//! (3) dρ_i/dt = (1 − ρ_i) I_i / τ_ρ2 + ρ_i (I_i − 1) / τ_ρ1
//! (4) I_i = C_i · Π_j [ 1 + ½ A_ij (tanh(c m_j) − 1) ]
//! (5) dm_i/dt = (1 − m_i) n_i² / τ_n + (1 + m_i)(n_i² − 1) / τ_i
//! ```
//!
//! n_i is the activity of behaviour i (its gate opens near ±1), C_i its sensor context in [0, 1],
//! ρ_i its refractory filter, m_i its memory of having been active; γ_ij pushes i off while j is
//! active, A_ij = 1 when j must have been active before i can start.
//!
//! # Numbers
//!
//! - States (n, ρ, m) and contexts are Q2.29 in an `i32` ([`ONE`] = 2^29): n ∈ [−2, 2] fits, and
//!   the resolution (1.9e-9) is far below the slow terms' increments (near 1e-7 per step at the
//!   defaults). Every product is formed in an `i64` and rounded to nearest; wherever both
//!   operands fit 32 bits they are kept there (one SMULL or UMULL on a Cortex-M4).
//! - Parameters are integers, as a table image stores them ([`Params`]): times in µs, γ in Q8.8,
//!   c in Q16.16, q in Q0.32. [`Dynamics::new`] turns each time constant into a rate dt/τ (Q0.32)
//!   and each γ into γ·dt/τ, so that a step costs no division.
//! - tanh(c·m) comes from a 177-entry table of tanh over [0, 11] (step 1/16) and a fourth-order
//!   Taylor polynomial around the nearest entry, within 5e-9 everywhere; above 11 it is 1
//!   (1 − tanh 11 = 5.6e-10). Why this accurate: the refractory filter amplifies an error ε of I
//!   into 20ε of ρ (at τ_ρ2/τ_ρ1 = 20), which a coarse table turns into steps of delay.
//!
//! Against an f64 integration of the same equations fed the same noise (core/tests/dynamics.rs),
//! the states stay within about 1e-5 in most scenarios and the gates switch at the same steps.
//! The error peaks while an activity grows out of the noise: n is then near 1e-3, its Q2.29
//! rounding (1.9e-9 a step) is a relative error near 1e-6 a step, and the slow growth (α just
//! above 0) keeps it there for many steps before amplifying it with n; where two behaviours race
//! out of the noise (the door after recognising) the difference reaches 1e-3.
//!
//! # Integration
//!
//! Explicit Euler–Maruyama: every derivative from the state at the start of the step, then all
//! states updated and saturated (n ∈ [−2, 2], ρ ∈ [0, 1], m ∈ [−1, 1]). Noise: one xorshift32
//! generator per group, four outputs per behaviour per step in declaration order,
//! z = ((u1 + u2 + u3 + u4) / 2^32 − 2)·√3, and n_i gains q·√dt·z (dt in units). The same integers
//! drive the board, the simulator and any reference, so runs replay exactly.
//!
//! Gates, with hysteresis: a gate opens when n_i² ≥ 0.5 and closes when n_i² < 0.4. If γ_ij and
//! γ_ji both exceed 1/0.4 = 2.5, two gates are never open together (DESIGN.md gives the argument).
//!
//! # Cost
//!
//! A step with B behaviours, E declared exclusions and R required behaviours: R tanh evaluations
//! (ten 32-bit multiplications each), E multiply-adds, 4B xorshift outputs, one multiplication
//! per presupposition bit, and about fifteen multiplications per behaviour, most of them 32-bit.
//! No division, no float, no allocation. Measured on a Cortex-M4 (scripts/cortex-m4/
//! dynamics-cost.sh, the boards' `firmware` profile): about 1 700 instructions for 4 behaviours,
//! 5 900 for 16 and 11 500 for 32 with one presupposition per pair, 18 300 for 32 where every
//! behaviour requires all those before it; 1.0 % to 10.8 % of a 170 MHz core at 1 kHz, counting
//! one cycle per instruction. The step's code is about 1.4 KiB, the tanh table 473 bytes
//! (its entries near 1 kept as 16- and 8-bit distances to 1).

use crate::isqrt::isqrt;
use heapless::Vec;
use serde::{Deserialize, Serialize};

#[cfg(feature = "dynamics")]
mod run;
mod spec;

#[cfg(feature = "dynamics")]
pub use run::{GateError, GroupRun, MAX_CATCH_UP, SourceState, StepView};
#[cfg(feature = "dynamics")]
pub(crate) use spec::validate as validate_table_part;
pub use spec::{
    Context, DynamicsError, GATE_SLOT_FILTER, GateLink, GateSource, GroupSpec, MAX_DYNAMICS_GROUPS,
    MAX_GATE_LINKS, MAX_GATE_SOURCES, MAX_TIMEOUT_US, OWN,
};
pub(crate) use spec::{TABLE_GROUPS, TABLE_LINKS, TABLE_SOURCES};

/// Behaviours per group, at most: the gate mask is a `u32`, A_i a `u32` mask.
pub const MAX_BEHAVIOURS: usize = 32;

/// Declared exclusions (non-zero γ_ij) per group, at most. 256 covers a group of 16 behaviours
/// that all exclude each other (240), or 32 that each exclude 8 others; the run-time form costs
/// 8 bytes each.
pub const MAX_EXCLUSIONS: usize = 256;

/// 1.0 in Q2.29, the format of the states and the contexts.
pub const ONE: i32 = 1 << 29;

/// γ = 1.0 in [`Exclusion::gamma`]'s Q8.8.
pub const GAMMA_ONE: u16 = 1 << 8;

/// c = 1.0 in [`Params::c`]'s Q16.16.
pub const C_ONE: u32 = 1 << 16;

/// One behaviour's own parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Behaviour {
    /// τ_i, how long the memory m_i of having been active lasts, in µs (default 50 units).
    pub memory_us: u32,
    /// A_i: bit j set when behaviour j must have been active before this one can start.
    pub requires: u32,
}

/// One declared exclusion γ_ij: `behaviour` (i) is pushed off while `by` (j) is active.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Exclusion {
    /// i, the behaviour pushed off.
    pub behaviour: u8,
    /// j, the behaviour whose activity pushes it.
    pub by: u8,
    /// γ_ij in Q8.8 ([`GAMMA_ONE`] = 1.0; the default of a declared exclusion is 3.0).
    pub gamma: u16,
}

/// The parameters of one group, as a table image stores them: integers only. Undeclared pairs
/// have γ_ij = 0.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Params {
    /// dt, the integration step, in µs (default 1 ms).
    pub step_us: u32,
    /// The time unit of the equations, in µs (default 10 ms). Only the noise depends on it
    /// (q is per √unit); every time constant below is already in µs.
    pub unit_us: u32,
    /// q, the noise amplitude per √unit, in Q0.32 (default 0.001: 4 294 967).
    pub noise: u32,
    /// The noise generator's seed; 0 is refused (xorshift32 stays at 0).
    pub seed: u32,
    /// c, the steepness of the presupposition's tanh, in Q16.16 (default 10.0).
    pub c: u32,
    /// τ, the time scale of the activities, in µs (default 1 unit).
    pub tau_us: u32,
    /// τ_ρ1, how fast the refractory filter falls when the input goes, in µs (default 1 unit).
    pub tau_rho_fast_us: u32,
    /// τ_ρ2, how slowly it rises when the input comes, in µs (default 20 units).
    pub tau_rho_slow_us: u32,
    /// τ_n, how fast the memory follows an activation, in µs (default 1 unit).
    pub tau_n_us: u32,
    /// The behaviours, in declaration order (the order of the noise and of the gate bits).
    pub behaviours: Vec<Behaviour, MAX_BEHAVIOURS>,
    /// The non-zero γ_ij; at most one entry per ordered pair.
    pub exclusions: Vec<Exclusion, MAX_EXCLUSIONS>,
}

/// A time parameter of [`Params`], to say which one is wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Time {
    /// dt.
    Step,
    /// The unit.
    Unit,
    /// τ.
    Tau,
    /// τ_ρ1.
    TauRhoFast,
    /// τ_ρ2.
    TauRhoSlow,
    /// τ_n.
    TauN,
    /// τ_i of this behaviour.
    Memory(u8),
}

// Not `#[non_exhaustive]`: the compiler's diagnostics (lang/src/network/dynamics.rs) explain each
// variant.
/// Why a group's parameters are refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamsError {
    /// More than [`MAX_BEHAVIOURS`] behaviours.
    TooManyBehaviours,
    /// More than [`MAX_EXCLUSIONS`] exclusions.
    TooManyExclusions,
    /// A time (a time constant, the step or the unit) of 0 µs.
    NonPositiveTime(Time),
    /// dt > τ_min / 4, τ_min the smallest of τ, τ_ρ1, τ_ρ2, τ_n and every τ_i: Euler's step would
    /// be too coarse for the fastest time scale.
    StepAboveQuarter,
    /// dt · (2 + Σ_j γ_ij) / τ > 1 for this behaviour: the explicit step of (1) could overshoot.
    StepUnstable {
        /// i, the behaviour with the largest Σ_j γ_ij that fails.
        behaviour: u8,
    },
    /// q = 0: n = 0 is an exact fixed point, a decayed behaviour would never start again.
    ZeroNoise,
    /// Seed 0: xorshift32 would output only zeros.
    ZeroSeed,
    /// An exclusion names a behaviour beyond the group.
    ExclusionOutOfRange {
        /// The exclusion's position in [`Params::exclusions`].
        exclusion: u16,
    },
    /// A behaviour requires a behaviour beyond the group (a bit of A_i at or above the count).
    RequirementOutOfRange {
        /// i.
        behaviour: u8,
    },
    /// γ_ii ≠ 0: a behaviour excluding itself.
    SelfExclusion {
        /// i.
        behaviour: u8,
    },
    /// Two entries for the same γ_ij: the sparse list must say one value per pair.
    DuplicateExclusion {
        /// i.
        behaviour: u8,
        /// j.
        by: u8,
    },
}

impl core::fmt::Display for ParamsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParamsError::TooManyBehaviours => {
                write!(
                    f,
                    "more than {MAX_BEHAVIOURS} behaviours in a dynamics group"
                )
            }
            ParamsError::TooManyExclusions => {
                write!(
                    f,
                    "more than {MAX_EXCLUSIONS} exclusions in a dynamics group"
                )
            }
            ParamsError::NonPositiveTime(time) => {
                f.write_str("dynamics time of 0 µs: ")?;
                match time {
                    Time::Step => f.write_str("step"),
                    Time::Unit => f.write_str("unit"),
                    Time::Tau => f.write_str("tau"),
                    Time::TauRhoFast => f.write_str("tau_rho_fast"),
                    Time::TauRhoSlow => f.write_str("tau_rho_slow"),
                    Time::TauN => f.write_str("tau_n"),
                    Time::Memory(i) => write!(f, "memory of behaviour {i}"),
                }
            }
            ParamsError::StepAboveQuarter => {
                f.write_str("dynamics step above a quarter of the fastest time constant")
            }
            ParamsError::StepUnstable { behaviour } => write!(
                f,
                "dynamics step · (2 + Σ γ) / tau above 1 for behaviour {behaviour}"
            ),
            ParamsError::ZeroNoise => f.write_str("dynamics noise of 0"),
            ParamsError::ZeroSeed => f.write_str("dynamics seed of 0"),
            ParamsError::ExclusionOutOfRange { exclusion } => {
                write!(
                    f,
                    "dynamics exclusion {exclusion} names no behaviour of the group"
                )
            }
            ParamsError::RequirementOutOfRange { behaviour } => write!(
                f,
                "behaviour {behaviour} requires a behaviour beyond the group"
            ),
            ParamsError::SelfExclusion { behaviour } => {
                write!(f, "behaviour {behaviour} excludes itself (γ_ii ≠ 0)")
            }
            ParamsError::DuplicateExclusion { behaviour, by } => {
                write!(f, "γ of behaviour {behaviour} by {by} given twice")
            }
        }
    }
}

impl core::error::Error for ParamsError {}

impl Default for Params {
    fn default() -> Self {
        Params::new()
    }
}

impl Params {
    /// The defaults of DESIGN.md with no behaviour yet: dt = 1 ms, unit = 10 ms, q = 0.001,
    /// seed 1, c = 10, τ = τ_ρ1 = τ_n = 1 unit, τ_ρ2 = 20 units.
    pub const fn new() -> Params {
        Params {
            step_us: 1_000,
            unit_us: 10_000,
            // round(0.001 · 2^32)
            noise: 4_294_967,
            seed: 1,
            c: 10 * C_ONE,
            tau_us: 10_000,
            tau_rho_fast_us: 10_000,
            tau_rho_slow_us: 200_000,
            tau_n_us: 10_000,
            behaviours: Vec::new(),
            exclusions: Vec::new(),
        }
    }

    /// Appends a behaviour with memory τ_i = `memory_us` and no requirement; returns its index.
    /// Fails when the group is full.
    pub fn add_behaviour(&mut self, memory_us: u32) -> Result<u8, ParamsError> {
        let index = self.behaviours.len() as u8;
        self.behaviours
            .push(Behaviour {
                memory_us,
                requires: 0,
            })
            .map_err(|_| ParamsError::TooManyBehaviours)?;
        Ok(index)
    }

    /// Declares γ_ij = `gamma` (Q8.8): `behaviour` is pushed off while `by` is active. Fails when
    /// the list is full; everything else is left to [`Params::validate`].
    pub fn exclude(&mut self, behaviour: u8, by: u8, gamma: u16) -> Result<(), ParamsError> {
        self.exclusions
            .push(Exclusion {
                behaviour,
                by,
                gamma,
            })
            .map_err(|_| ParamsError::TooManyExclusions)
    }

    /// Sets A_ij = 1: `behaviour` needs `prerequisite` to have been active. Fails on an index
    /// beyond the group.
    pub fn require(&mut self, behaviour: u8, prerequisite: u8) -> Result<(), ParamsError> {
        let out_of_range = ParamsError::RequirementOutOfRange { behaviour };
        if usize::from(prerequisite) >= self.behaviours.len() {
            return Err(out_of_range);
        }
        let entry = self
            .behaviours
            .get_mut(usize::from(behaviour))
            .ok_or(out_of_range)?;
        entry.requires |= 1 << prerequisite;
        Ok(())
    }

    /// Checks what DESIGN.md calls invalid, in this order: a time of 0 (the step, the unit, then
    /// τ, τ_ρ1, τ_ρ2, τ_n and each τ_i), q = 0, seed 0, a requirement or an exclusion naming a
    /// behaviour beyond the group, γ_ii ≠ 0, a pair given twice, dt > τ_min / 4, and
    /// dt · (2 + Σ_j γ_ij) / τ > 1. (More than [`MAX_BEHAVIOURS`] behaviours or
    /// [`MAX_EXCLUSIONS`] exclusions cannot be held: [`Params::add_behaviour`],
    /// [`Params::exclude`] and decoding refuse them.)
    ///
    /// Costs one pass over the exclusions and two over the behaviours; no division.
    // Left to the inliner: its one caller on a board is the loader's checks of the dynamics
    // part, where out of line it now took 88 bytes more of the NUCLEO-G474RE's flash, 92 of
    // the emulated board's (inlined, it once took 100 more).
    pub fn validate(&self) -> Result<(), ParamsError> {
        // Tested one by one: a list of (time, which) pairs cost a board the list's stores.
        let zero = if self.step_us == 0 {
            Some(Time::Step)
        } else if self.unit_us == 0 {
            Some(Time::Unit)
        } else if self.tau_us == 0 {
            Some(Time::Tau)
        } else if self.tau_rho_fast_us == 0 {
            Some(Time::TauRhoFast)
        } else if self.tau_rho_slow_us == 0 {
            Some(Time::TauRhoSlow)
        } else if self.tau_n_us == 0 {
            Some(Time::TauN)
        } else {
            None
        };
        if let Some(time) = zero {
            return Err(ParamsError::NonPositiveTime(time));
        }
        let mut fastest = self
            .tau_us
            .min(self.tau_rho_fast_us)
            .min(self.tau_rho_slow_us)
            .min(self.tau_n_us);
        let count = self.behaviours.len();
        // Bits 0..count: the behaviours of the group (count ≤ 32).
        let members = u32::MAX.checked_shr(32 - count as u32).unwrap_or(0);
        // One pass for the memories and the requirements; a requirement out of range is only
        // reported after the checks that come before it (q, the seed). Bit i: behaviour i's is.
        let mut beyond = 0u32;
        for (i, b) in self.behaviours.iter().enumerate() {
            if b.memory_us == 0 {
                return Err(ParamsError::NonPositiveTime(Time::Memory(i as u8)));
            }
            fastest = fastest.min(b.memory_us);
            if b.requires & !members != 0 {
                beyond |= 1 << i;
            }
        }
        if self.noise == 0 {
            return Err(ParamsError::ZeroNoise);
        }
        if self.seed == 0 {
            return Err(ParamsError::ZeroSeed);
        }
        if beyond != 0 {
            return Err(ParamsError::RequirementOutOfRange {
                behaviour: beyond.trailing_zeros() as u8,
            });
        }
        // Per behaviour i: the j already declared, and Σ_j γ_ij (Q8.8; at most 31 · 2^16).
        let mut declared = [0u32; MAX_BEHAVIOURS];
        let mut gamma_sum = [0u32; MAX_BEHAVIOURS];
        for (k, e) in self.exclusions.iter().enumerate() {
            let (i, j) = (usize::from(e.behaviour), usize::from(e.by));
            let (Some(seen), Some(sum)) = (declared.get_mut(i), gamma_sum.get_mut(i)) else {
                return Err(ParamsError::ExclusionOutOfRange {
                    exclusion: k as u16,
                });
            };
            if i >= count || j >= count {
                return Err(ParamsError::ExclusionOutOfRange {
                    exclusion: k as u16,
                });
            }
            if i == j && e.gamma != 0 {
                return Err(ParamsError::SelfExclusion {
                    behaviour: e.behaviour,
                });
            }
            if *seen & (1 << j) != 0 {
                return Err(ParamsError::DuplicateExclusion {
                    behaviour: e.behaviour,
                    by: e.by,
                });
            }
            *seen |= 1 << j;
            *sum = sum.saturating_add(u32::from(e.gamma));
        }
        // dt > τ_min / 4, in integers: 4 dt > τ_min, that is dt > ⌊τ_min / 4⌋.
        if self.step_us > fastest / 4 {
            return Err(ParamsError::StepAboveQuarter);
        }
        // dt (2 + Σγ) / τ > 1 with Σγ in Q8.8: dt (512 + Σγ) > 256 τ. At most 2^32 · 2^22.
        // The heaviest: the first of the largest sums (the sums beyond the group are 0).
        let (mut behaviour, mut sum) = (0, 0);
        for (i, &s) in gamma_sum.iter().enumerate() {
            if s > sum {
                (behaviour, sum) = (i as u8, s);
            }
        }
        if u64::from(self.step_us) * (512 + u64::from(sum)) > 256 * u64::from(self.tau_us) {
            return Err(ParamsError::StepUnstable { behaviour });
        }
        Ok(())
    }
}

/// The state of one behaviour, each in Q2.29 ([`ONE`] = 1.0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct State {
    /// n_i ∈ [−2, 2], the activity.
    pub n: i32,
    /// ρ_i ∈ [0, 1], the refractory filter.
    pub rho: i32,
    /// m_i ∈ [−1, 1], the memory of having been active.
    pub m: i32,
}

impl State {
    /// n = 0, ρ = 0, m = −1: never active, no input yet.
    pub const INITIAL: State = State {
        n: 0,
        rho: 0,
        m: -ONE,
    };
}

/// γ_ij · dt / τ in Q0.32: the run-time form of an [`Exclusion`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Push {
    behaviour: u8,
    by: u8,
    rate: u32,
}

/// A running group: its constants, precomputed from valid [`Params`], and its state.
///
/// Memory: about 2.7 KiB (2 KiB of it the exclusions' run-time form). Built once per table by
/// [`Dynamics::new`]; stepped by [`Dynamics::step`].
#[derive(Clone, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Dynamics {
    count: u8,
    /// dt / τ, dt / τ_ρ1, dt / τ_ρ2, dt / τ_n in Q0.32; each at most 1/4 (validated).
    rate_tau: u32,
    rate_rho_fast: u32,
    rate_rho_slow: u32,
    rate_n: u32,
    /// The behaviours some behaviour requires: only their tanh is needed.
    required: u32,
    /// c in Q16.16.
    c: u32,
    /// q · √(dt / unit) in Q0.32, saturated (a larger noise would swamp n anyway).
    noise_gain: u32,
    pushes: Vec<Push, MAX_EXCLUSIONS>,
    rng: u32,
    lanes: [Lane; MAX_BEHAVIOURS],
    gates: u32,
}

/// One behaviour of a running group: its state and its constants side by side, so that the step
/// walks one array (walking five, it kept as many running pointers: 16 bytes more of the
/// NUCLEO-G474RE's flash, and 3 instructions more per behaviour and step).
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Lane {
    state: State,
    /// dt / τ_i, Q0.32.
    rate_memory: u32,
    /// A_i.
    requires: u32,
}

impl Lane {
    const BLANK: Lane = Lane {
        state: State { n: 0, rho: 0, m: 0 },
        rate_memory: 0,
        requires: 0,
    };
}

/// 1.0 in Q1.31, the format of tanh and of the presupposition factors.
const ONE_Q31: i64 = 1 << 31;
/// √3 in Q2.29, to scale the noise sum: (D / 2^32) · √3 in Q2.29 is ((D / 4) · SQRT3) >> 30.
const SQRT3: i32 = (1.732_050_807_568_877_2 * ONE as f64 + 0.5) as i32;
/// 1/3 in Q2.30.
const THIRD_Q30: i32 = ((1 << 30) + 1) / 3;
/// A gate opens when n² ≥ 0.5: n · n (Q4.58, exact) ≥ 2^57.
const OPEN_Q58: i64 = 1 << 57;
/// A gate closes when n² < 0.4: n · n (Q4.58, exact) < 0.4 · 2^58 = 2^59 / 5, which is not an
/// integer; n · n < ⌈2^59 / 5⌉ is the same test.
const CLOSE_Q58: i64 = ((1i64 << 59) + 4) / 5;

/// log2 of the table's entries per unit of x.
const TANH_SHIFT: u32 = 4;
/// Above this x, tanh x is 1 within 5.6e-10 (a third of a Q1.31 unit).
const TANH_LIMIT: u64 = 11;
const TANH_LEN: usize = (TANH_LIMIT as usize) << TANH_SHIFT;

/// e^x for the tables below ([`crate::const_exp::exp`] with 12 Taylor terms).
const fn exp(x: f64) -> f64 {
    crate::const_exp::exp(x, 12)
}

/// tanh(k / 16) in Q1.31, k = 0..=176, computed at compile time so that it cannot drift from the
/// formula (`tests::table_matches_std_tanh`). Filled without indexing, like every other array here.
const TANH: [u32; TANH_LEN + 1] = {
    let mut table = [0; TANH_LEN + 1];
    let mut k = 0;
    while k <= TANH_LEN {
        let e = exp(-2.0 * k as f64 / (1 << TANH_SHIFT) as f64);
        if let Some((_, [slot, ..])) = table.split_at_mut_checked(k) {
            *slot = ((1.0 - e) / (1.0 + e) * ONE_Q31 as f64 + 0.5) as u32;
        }
        k += 1;
    }
    table
};

/// 1.0 in Q2.30, the format of tanh and of the table's entries as the step reads them.
const ONE_Q30: i32 = 1 << 30;

/// From this k on, 1 − tanh(k / 16) is below 2^16 in Q2.30 (5.5e-5 at k = 84), and from
/// [`TANH_NEARER`] on below 2^8: the board keeps those entries as their distance to 1 in a `u16`
/// ([`TANH_TAIL`]) and a `u8` ([`TANH_END`]), the others in Q2.30 ([`TANH_HEAD`]), 235 bytes of
/// flash fewer than [`TANH`] (708). All are [`TANH`]'s entries exactly
/// (`tests::split_table_is_the_table`).
const TANH_NEAR_ONE: usize = 84;
/// See [`TANH_NEAR_ONE`]: 1 − tanh(8) = 2.3e-7, 241 in Q2.30.
const TANH_NEARER: usize = 128;

/// 1 − tanh(k / 16) in Q2.30 for k ≤ 176, [`TANH`]'s entry rounded to Q2.30: what the tail
/// tables hold.
const fn tanh_rest(k: usize) -> u32 {
    match TANH.split_at_checked(k) {
        Some((_, [t, ..])) => ONE_Q30 as u32 - ((*t + 1) >> 1),
        _ => 0,
    }
}

/// tanh(k / 16) in Q2.30 for k < [`TANH_NEAR_ONE`]: [`TANH`]'s entries rounded to Q2.30.
const TANH_HEAD: [u32; TANH_NEAR_ONE] = {
    let mut head = [0; TANH_NEAR_ONE];
    let mut k = 0;
    while k < TANH_NEAR_ONE {
        if let Some((_, [slot, ..])) = head.split_at_mut_checked(k) {
            *slot = ONE_Q30 as u32 - tanh_rest(k);
        }
        k += 1;
    }
    head
};

/// 1 − tanh(k / 16) in Q2.30 for k from [`TANH_NEAR_ONE`] to [`TANH_NEARER`] − 1.
const TANH_TAIL: [u16; TANH_NEARER - TANH_NEAR_ONE] = {
    let mut tail = [0; TANH_NEARER - TANH_NEAR_ONE];
    let mut k = TANH_NEAR_ONE;
    while k < TANH_NEARER {
        if let Some((_, [slot, ..])) = tail.split_at_mut_checked(k - TANH_NEAR_ONE) {
            assert!(tanh_rest(k) <= u16::MAX as u32, "a tail entry fits 16 bits");
            *slot = tanh_rest(k) as u16;
        }
        k += 1;
    }
    tail
};

/// 1 − tanh(k / 16) in Q2.30 for k from [`TANH_NEARER`] to 176.
const TANH_END: [u8; TANH_LEN + 1 - TANH_NEARER] = {
    let mut end = [0; TANH_LEN + 1 - TANH_NEARER];
    let mut k = TANH_NEARER;
    while k <= TANH_LEN {
        if let Some((_, [slot, ..])) = end.split_at_mut_checked(k - TANH_NEARER) {
            assert!(tanh_rest(k) <= u8::MAX as u32, "an end entry fits 8 bits");
            *slot = tanh_rest(k) as u8;
        }
        k += 1;
    }
    end
};

/// tanh(k / 16) in Q2.30 for k ≤ 176, from the three tables (1.0 beyond, never asked).
#[inline(always)]
fn tanh_entry(k: usize) -> i32 {
    if let Some(&t) = TANH_HEAD.get(k) {
        return t as i32;
    }
    let rest = match TANH_TAIL.get(k - TANH_NEAR_ONE) {
        Some(&rest) => u32::from(rest),
        None => TANH_END
            .get(k - TANH_NEARER)
            .map_or(0, |&rest| u32::from(rest)),
    };
    ONE_Q30 - rest as i32
}

/// (a · b) / 2^shift rounded to nearest, for 1 ≤ shift ≤ 62 and |a · b| + 2^(shift − 1) < 2^63:
/// every caller states why its operands are that small. Plain arithmetic on purpose: the tests, built with
/// overflow checks, would stop on a bound that does not hold.
#[inline(always)]
const fn mul_round(a: i64, b: i64, shift: u32) -> i64 {
    (a * b + ((1 << shift) >> 1)) >> shift
}

/// (a · b) / 2^shift rounded to nearest for two `i32`s (one SMULL on a Cortex-M4), for
/// 1 ≤ shift ≤ 62: cannot overflow (|a · b| ≤ 2^62). Out of line: its thirteen inlined copies
/// (the dynamics' step, once per tick, not the frame path) took 32 bytes more of the
/// NUCLEO-G474RE's flash.
#[inline(never)]
const fn mul32(a: i32, b: i32, shift: u32) -> i64 {
    (a as i64 * b as i64 + ((1 << shift) >> 1)) >> shift
}

/// tanh(x) for x = c · m, c in Q16.16 and m in Q2.29 (|m| ≤ 1), in Q2.30 (at most 2^30 in
/// magnitude); within 1e-8 of the exact value (`tests::tanh_is_within_1e_8`). A table look-up,
/// one 32 × 32-bit multiplication for x and nine for the polynomial (SMULL each).
fn tanh(c: u32, m: i32) -> i32 {
    // |x| in Q17.45: c · |m| < 2^32 · 2^29 (one UMULL); x has m's sign.
    let ax = u64::from(c) * u64::from(m.unsigned_abs());
    let magnitude = if ax >= TANH_LIMIT << 45 {
        ONE_Q30
    } else {
        // The nearest entry k/16 and the rest r = |x| − k/16, |r| ≤ 1/32 (2^25 in Q2.30).
        let k = (ax + (1 << 40)) >> 41;
        let r = ((ax as i64 - (k << 41) as i64 + (1 << 14)) >> 15) as i32;
        // The entry: at most 2^30.
        let t = tanh_entry(k as usize);
        // Taylor around k/16 to the fourth order (the fifth-order term is below 4e-9 for
        // |r| ≤ 1/32; the third order alone would leave 1.6e-7): tanh' = p = 1 − t²,
        // tanh'' / 2 = −t p, tanh''' / 6 = p (3t² − 1) / 3, tanh'''' / 24 = t p (2 − 3t²) / 3.
        // Written as p (t² − 1/3) and t p (2/3 − t²), every factor lies within [−1, 1] and each
        // product is rounded back to Q2.30: every operand fits an i32 (3t² − 1 would not).
        let q30 = |a: i32, b: i32| mul32(a, b, 30) as i32;
        let t2 = q30(t, t);
        let p = ONE_Q30 - t2;
        let tp = q30(t, p);
        let c3 = q30(p, t2) - q30(p, THIRD_Q30);
        let c4 = q30(tp, 2 * THIRD_Q30 - t2);
        let cubic = c3 + q30(r, c4);
        let inner = q30(r, cubic) - tp;
        let slope = p + q30(r, inner);
        (t + q30(r, slope)).clamp(0, ONE_Q30)
    };
    if m < 0 { -magnitude } else { magnitude }
}

/// γ dt / τ in Q0.32 (γ in Q8.8), rounded, saturating: γ · dt · 2^24 / τ (γ · dt < 2^48; a
/// 128-bit division would cost a board kilobytes of flash). Below saturation γ · dt < 2^8 τ <
/// 2^40, so γ · dt · 2^24 fits 64 bits and one rounded division is exact.
// Out of line: inlined into the loop over the exclusions of `Dynamics::start`, it took 24 bytes
// more of the NUCLEO-G474RE's flash. Run once per exclusion and table.
#[inline(never)]
fn gamma_rate(gamma: u16, step_us: u32, tau_us: u32) -> u32 {
    let tau = tau_us.max(1);
    let numerator = u64::from(gamma) * u64::from(step_us);
    if numerator >= u64::from(tau) << 8 {
        return u32::MAX;
    }
    div_round(numerator << 24, tau)
}

/// √(dt / unit) in Q1.31, rounded down, from dt / unit in Q2.62 (long division in 31-bit
/// chunks, 64-bit words only); saturated at √4 = 2.0 (a larger noise swamps n anyway).
fn sqrt_ratio(step_us: u32, unit_us: u32) -> u64 {
    let unit = u64::from(unit_us.max(1));
    let step = u64::from(step_us);
    let (whole, rest) = (step / unit, step % unit);
    if whole >= 4 {
        return 1 << 32;
    }
    // rest < unit < 2^32: each shifted remainder is below 2^63.
    let high = (rest << 31) / unit;
    let low = (((rest << 31) % unit) << 31) / unit;
    isqrt((whole << 62) | (high << 31) | low)
}

/// round(dt · 2^32 / τ): dt / τ in Q0.32, for τ > 0 and dt ≤ τ / 4 (so at most 2^30).
fn rate(step_us: u32, tau_us: u32) -> u32 {
    div_round(u64::from(step_us) << 32, tau_us)
}

/// (numerator + ⌊divisor / 2⌋) / divisor, saturated to a `u32`; 0 for a divisor of 0. For
/// numerator < 2^64 − 2^31, so that the sum cannot overflow. Out of line: inlined at each of its
/// six callers it cost a board a 64-bit division's call set-up each, for code run once per table.
#[inline(never)]
fn div_round(numerator: u64, divisor: u32) -> u32 {
    (numerator + u64::from(divisor / 2))
        .checked_div(u64::from(divisor))
        .map_or(0, |r| u32::try_from(r).unwrap_or(u32::MAX))
}

/// One xorshift32 step (x ^= x << 13; x ^= x >> 17; x ^= x << 5): the new state is the output.
#[inline(always)]
const fn xorshift32(mut x: u32) -> u32 {
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    x
}

impl Dynamics {
    /// The group of `params` in its initial state (n = 0, ρ = 0, m = −1, all gates closed), or why
    /// `params` are invalid ([`Params::validate`]). Costs the validation plus one 64-bit division
    /// per time constant, two per exclusion, three and a 64-bit square root for the noise: done
    /// once per table, so that [`Dynamics::step`] needs none.
    pub fn new(params: &Params) -> Result<Dynamics, ParamsError> {
        params.validate()?;
        let mut dynamics = Dynamics::BLANK;
        dynamics.start(params);
        Ok(dynamics)
    }

    /// All zeros, no behaviour: what [`Dynamics::start`] fills in place.
    pub(crate) const BLANK: Dynamics = Dynamics {
        count: 0,
        rate_tau: 0,
        rate_rho_fast: 0,
        rate_rho_slow: 0,
        rate_n: 0,
        required: 0,
        c: 0,
        noise_gain: 0,
        pushes: Vec::new(),
        rng: 0,
        lanes: [Lane::BLANK; MAX_BEHAVIOURS],
        gates: 0,
    };

    /// [`Dynamics::new`] written into `self`, a [`Dynamics::BLANK`] (its zeros are kept):
    /// a board builds its groups where they live, inside the arbiter (returned by value, each
    /// of the 2.7 KiB struct's moves through `Result`, the run and the arbiter's list was a
    /// copy: 224 bytes of the NUCLEO-G474RE's flash). For `params` that [`Params::validate`]
    /// accepted: the arbiter builds its groups from a validated table and does not check them
    /// again. Invalid parameters give a meaningless group, never a panic (a time of 0 gives a
    /// rate of 0).
    pub(crate) fn start(&mut self, params: &Params) {
        let dt = params.step_us;
        let mut required = 0;
        // The lanes beyond the group keep their zeros: nothing reads them.
        for (b, lane) in params.behaviours.iter().zip(self.lanes.iter_mut()) {
            lane.state.m = -ONE;
            lane.rate_memory = rate(dt, b.memory_us);
            lane.requires = b.requires;
            required |= b.requires;
        }
        for e in params.exclusions.iter().filter(|e| e.gamma != 0) {
            // At most one entry per exclusion, and `params.exclusions` has the same capacity.
            let _ = self.pushes.push(Push {
                behaviour: e.behaviour,
                by: e.by,
                rate: gamma_rate(e.gamma, dt, params.tau_us),
            });
        }
        let gain = (u64::from(params.noise) * sqrt_ratio(dt, params.unit_us) + (1 << 30)) >> 31;
        self.count = params.behaviours.len() as u8;
        self.rate_tau = rate(dt, params.tau_us);
        self.rate_rho_fast = rate(dt, params.tau_rho_fast_us);
        self.rate_rho_slow = rate(dt, params.tau_rho_slow_us);
        self.rate_n = rate(dt, params.tau_n_us);
        self.required = required;
        self.c = params.c;
        self.noise_gain = u32::try_from(gain).unwrap_or(u32::MAX);
        self.rng = params.seed;
    }

    /// The number of behaviours.
    pub const fn len(&self) -> usize {
        self.count as usize
    }

    /// Whether the group has no behaviour.
    pub const fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The gates: bit i set while behaviour i's gate is open.
    pub const fn gates(&self) -> u32 {
        self.gates
    }

    /// Behaviour i's state, or `None` beyond the group.
    pub fn state(&self, i: usize) -> Option<State> {
        if i >= self.len() {
            return None;
        }
        self.lanes.get(i).map(|lane| lane.state)
    }

    /// The noise generator's state (the last xorshift32 output, or the seed before any step).
    pub const fn rng(&self) -> u32 {
        self.rng
    }

    /// One Euler–Maruyama step of dt with the contexts C_i (Q2.29, entry i for behaviour i;
    /// values are clamped into [0, 1], a missing entry reads 0, extra entries are ignored).
    /// Returns the gates after the step.
    ///
    /// Costs no division and no allocation; see the module's documentation for the operation
    /// count. Never fails.
    pub fn step(&mut self, contexts: &[i32]) -> u32 {
        let count = self.len();
        // Why the formats below: a Cortex-M4 multiplies 32 × 32 → 64 bits in one instruction
        // (SMULL, UMULL) and 64 × 64 in three or four, so every product whose operands fit 32
        // bits is written as one, and the rates are applied before the large factors
        // (k (1 − m) n², not ((1 − m) n²) k) to keep them there.
        let rate_tau = self.rate_tau as i32;
        let rate_rho_fast = self.rate_rho_fast as i32;
        let rate_rho_slow = self.rate_rho_slow as i32;
        let rate_n = self.rate_n as i32;
        // (4)'s factors ½(1 + tanh(c m_j)) in Q1.31 (at most 2^31), from the state at the start
        // of the step; 1.0 for the behaviours nobody requires (never read).
        let mut factor = [1u32 << 31; MAX_BEHAVIOURS];
        // n_j² in Q2.29: at most 4 · 2^29 = 2^31, a u32.
        let mut square = [0u32; MAX_BEHAVIOURS];
        for (j, ((f, s), lane)) in factor
            .iter_mut()
            .zip(square.iter_mut())
            .zip(self.lanes.iter())
            .enumerate()
            .take(count)
        {
            let State { n, m, .. } = lane.state;
            if self.required & (1 << j) != 0 {
                // ½(1 + tanh) in Q1.31 is exactly 2^30 + tanh in Q2.30: within [0, 2^31].
                *f = ((1i64 << 30) + i64::from(tanh(self.c, m))) as u32;
            }
            *s = mul32(n, n, 29) as u32;
        }
        // (1)'s Σ_j γ_ij n_j² · dt / τ in Q3.61, unsigned: each term is below 2^32 · 2^31, and
        // their sum below 2^63 because Σ_j γ_ij dt / τ < 1 (validated).
        let mut pressure = [0u64; MAX_BEHAVIOURS];
        for push in &self.pushes {
            let n2 = square.get(usize::from(push.by)).copied().unwrap_or(0);
            if let Some(p) = pressure.get_mut(usize::from(push.behaviour)) {
                *p += u64::from(push.rate) * u64::from(n2);
            }
        }
        let mut gates = self.gates;
        let lanes = self
            .lanes
            .iter_mut()
            .zip(square.iter().zip(pressure.iter()))
            .enumerate()
            .take(count);
        for (i, (lane, (&n2, &pressure))) in lanes {
            // The noise: four outputs, in declaration order, whatever the behaviour's state.
            let mut sum = 0u64;
            for _ in 0..4 {
                self.rng = xorshift32(self.rng);
                sum += u64::from(self.rng);
            }
            // z = (D / 2^32) √3 with D = sum − 2^33 ∈ [−2^33, 2^33): D / 4 fits an i32 (the two
            // bits dropped move z by less than 1e-9), and z in Q2.29 is (D/4) · √3 / 2^30.
            let quarter = ((sum as i64 - (1 << 33)) >> 2) as i32;
            // |z| < 0.87 · 2^31: an i32.
            let z = mul32(quarter, SQRT3, 30) as i32;
            // (4): I_i = C_i · Π over the required j of the factors; stays in [0, 1].
            let mut input = contexts.get(i).map_or(0, |&c| c.clamp(0, ONE)) as u32;
            let mut bits = lane.requires;
            while bits != 0 {
                let j = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let f = factor.get(j).copied().unwrap_or(1 << 31);
                // input · f ≤ 2^29 · 2^31; the result is at most input.
                input = ((u64::from(input) * u64::from(f) + (1 << 30)) >> 31) as u32;
            }
            let input = input as i32;
            let State {
                n: n0,
                rho: rho0,
                m: m0,
            } = lane.state;
            // (2): α = 2ρI − 1 ∈ [−1, 1], an i32 in Q2.29.
            let alpha = (mul32(rho0, input, 28) - i64::from(ONE)) as i32;
            // (1) as n · (kα − k|α| n² − Σ_j kγ_ij n_j²) + q√dt z, k = dt/τ, the bracket in Q2.30:
            // |kα| ≤ 1/4 (2^28), k|α|n² ≤ 1 (2^30), the pressure at most 4 (2^32), so the
            // bracket lies in [−5.25, 0.25] and its product with |n| ≤ 2 below 2^63.
            // kα and z fit 32 bits: their products are one multiplication each.
            let k_alpha = mul32(alpha, rate_tau, 31) as i32;
            let k_alpha_n2 = (u64::from(k_alpha.unsigned_abs()) * u64::from(n2) + (1 << 28)) >> 29;
            let push = ((pressure + (1 << 30)) >> 31) as i64;
            let bracket = i64::from(k_alpha) - k_alpha_n2 as i64 - push;
            // q√dt < 2^32 and |z| < 2^31: the noise's product is below 2^63.
            let dn = mul_round(bracket, i64::from(n0), 30)
                + mul_round(i64::from(self.noise_gain), i64::from(z), 32);
            // (3): (1 − ρ) I ∈ [0, 1] and ρ (I − 1) ∈ [−1, 0]; times rates ≤ 2^30, their sum
            // within ±2^59: dρ within ±2^27, and ρ + dρ fits an i32.
            let rise = mul32(ONE - rho0, input, 29) as i32;
            let fall = mul32(rho0, input - ONE, 29) as i32;
            let drho = ((i64::from(rise) * i64::from(rate_rho_slow)
                + i64::from(fall) * i64::from(rate_rho_fast)
                + (1 << 31))
                >> 32) as i32;
            // (5) as k_n (1 − m) · n² + k_i (1 + m) · (n² − 1), the rated factors in Q1.31: both
            // at most 2 · 1/4, below 2^30; times n² ≤ 2^31 and n² − 1 < 2^31, the sum below 2^62.
            // Each factor fits 32 bits (one UMULL or SMULL a product): up, down ∈ [0, 2^30], n² − 1
            // within [−2^29, 3 · 2^29] (wrapped in 32 bits, read back exactly as an i32). As
            // (1 − m) + (1 + m) = 2, up + down ≤ 2^30 + 1: dm lies within [−2^28 − 1, 2^30 + 1]
            // (n² − 1 ≥ −1, n² ≤ 4), and m + dm fits an i32.
            let up = mul32(ONE - m0, rate_n, 30) as u32;
            let down = mul32(ONE + m0, lane.rate_memory as i32, 30) as i32;
            let n2_less_one = n2.wrapping_sub(ONE as u32) as i32;
            let dm = (((u64::from(up) * u64::from(n2)) as i64
                + i64::from(down) * i64::from(n2_less_one)
                + (1 << 30))
                >> 31) as i32;
            let two = 2 * i64::from(ONE);
            // n + dn can leave an i32: clamped in 64 bits before the cast; ρ and m in 32.
            let n = (i64::from(n0) + dn).clamp(-two, two) as i32;
            lane.state = State {
                n,
                rho: (rho0 + drho).clamp(0, ONE),
                m: (m0 + dm).clamp(-ONE, ONE),
            };
            // The gate, with hysteresis, from the new n: n · n exactly, in Q4.58.
            let q58 = i64::from(n) * i64::from(n);
            if q58 >= OPEN_Q58 {
                gates |= 1 << i;
            } else if q58 < CLOSE_Q58 {
                gates &= !(1 << i);
            }
        }
        self.gates = gates;
        gates
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_std_tanh() {
        for (k, &t) in TANH.iter().enumerate() {
            let exact = (k as f64 / 16.0).tanh() * ONE_Q31 as f64;
            assert!(
                (f64::from(t) - exact).abs() <= 0.51,
                "k {k}: {t} vs {exact}"
            );
        }
    }

    #[test]
    fn split_table_is_the_table() {
        for (k, &t) in TANH.iter().enumerate() {
            assert_eq!(tanh_entry(k), ((t + 1) >> 1) as i32, "k {k}");
        }
    }

    #[test]
    fn tanh_is_within_1e_8() {
        // Every m of a dense sweep, for c = 1, 10 (the default), 10.37 and 100 (saturation).
        let mut worst: f64 = 0.0;
        for c in [C_ONE, 10 * C_ONE, 679_608, 100 * C_ONE] {
            for k in -200_000..=200_000 {
                let m = (i64::from(ONE) * k / 200_000) as i32;
                let x = f64::from(c) / f64::from(C_ONE) * f64::from(m) / f64::from(ONE);
                let got = f64::from(tanh(c, m)) / f64::from(1 << 30);
                worst = worst.max((got - x.tanh()).abs());
            }
        }
        assert!(worst < 1e-8, "tanh off by {worst:e}");
    }

    #[test]
    fn a_group_takes_about_2_7_kib() {
        // The module's and `Dynamics`' documentation say so; on a 32-bit board the Vec's length
        // is 4 bytes smaller.
        let size = core::mem::size_of::<Dynamics>();
        assert!((2_700..2_800).contains(&size), "{size} bytes");
    }

    #[test]
    fn gate_thresholds_are_exact() {
        // 0.5 · 2^58 and the smallest integer at or above 0.4 · 2^58 = 2^59 / 5, in exact integers.
        assert_eq!(2 * i128::from(OPEN_Q58), 1 << 58);
        assert!(5 * i128::from(CLOSE_Q58) >= 1 << 59);
        assert!(5 * i128::from(CLOSE_Q58 - 1) < 1 << 59);
    }

    #[test]
    fn gamma_rate_is_the_long_division_s() {
        // The former form: γ dt · 2^24 / τ by long division in 64-bit words.
        fn long(gamma: u16, step_us: u32, tau_us: u32) -> u32 {
            let tau = u64::from(tau_us.max(1));
            let numerator = u64::from(gamma) * u64::from(step_us);
            let (whole, rest) = (numerator / tau, numerator % tau);
            let fraction = ((rest << 24) + tau / 2) / tau;
            if whole >= 1 << 8 {
                return u32::MAX;
            }
            u32::try_from((whole << 24) + fraction).unwrap_or(u32::MAX)
        }
        let mut x = 0x2545_F491u32;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        for _ in 0..200_000 {
            let (a, b, c) = (next(), next(), next());
            let gamma = a as u16;
            // Every magnitude of dt and τ, the edges included.
            let step = b >> (a >> 27);
            let tau = c >> ((a >> 22) & 31);
            for (g, s, t) in [
                (gamma, step, tau),
                (gamma, step, 0),
                (gamma, step, u32::MAX),
                (u16::MAX, u32::MAX, tau),
                (
                    gamma,
                    step,
                    ((u64::from(gamma) * u64::from(step)) >> 8) as u32,
                ),
                (
                    gamma,
                    step,
                    (((u64::from(gamma) * u64::from(step)) >> 8) as u32).wrapping_add(1),
                ),
            ] {
                assert_eq!(gamma_rate(g, s, t), long(g, s, t), "{g} {s} {t}");
            }
        }
    }

    #[test]
    fn noise_gain_is_q_sqrt_dt() {
        let mut p = Params::new();
        p.add_behaviour(500_000).unwrap();
        let d = Dynamics::new(&p).unwrap();
        let exact = 0.001 * 0.1f64.sqrt() * 2f64.powi(32);
        assert!((f64::from(d.noise_gain) - exact).abs() <= 1.0);
    }
}

crate::wire::decode_struct!(Behaviour {
    memory_us,
    requires
});
crate::wire::decode_struct!(Exclusion {
    behaviour,
    by,
    gamma
});
impl crate::wire::Decode for Params {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        let mut params = Params::new();
        params.decode_in_place(r);
        params
    }
}

impl Params {
    /// [`crate::wire::Decode`] into `self`, whose lists must be empty: filled in place, the
    /// exclusions' room is 1 KiB, a copy of it for each move.
    pub(crate) fn decode_in_place(&mut self, r: &mut crate::wire::Reader<'_>) {
        self.step_us = r.decode();
        self.unit_us = r.decode();
        self.noise = r.decode();
        self.seed = r.decode();
        self.c = r.decode();
        self.tau_us = r.decode();
        self.tau_rho_fast_us = r.decode();
        self.tau_rho_slow_us = r.decode();
        self.tau_n_us = r.decode();
        r.fill(&mut self.behaviours);
        r.fill(&mut self.exclusions);
    }
}
