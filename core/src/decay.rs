//! The decay of a stimulation level between two frames, in integer arithmetic.
//!
//! The reference semantics (DESIGN.md, from the authors' YARP implementation): with λ = 5,
//! u = dt / τ and dt ≤ τ,
//!
//! ```text
//! S(t) = S0 · f(u),   f(u) = 1 − e^(λ(u − 1)) + e^(−λ)
//! ```
//!
//! and S(t) = 0 for dt > τ. We compute the loss g(u) = 1 − f(u) = e^(−λ) · (e^(λu) − 1) rather
//! than f. Why: frames usually arrive much faster than τ, so u is small and f is within 1e-3 of 1;
//! in a steady state (a connection fed at a constant rate without saturating) the level settles at
//! σ / g, so the *relative* accuracy of g is what bounds the integrator's error. Written as a sum of
//! positive terms g has no cancellation near u = 0.
//!
//! Evaluation: u (Q32) selects one of 64 segments; within a segment,
//! g(u) = G_i + E_i · expm1(λ·r) with G_i = e^(−λ)(e^(λ i/64) − 1), E_i = e^(λ(i/64 − 1)) and r
//! the remainder of u in the segment. `expm1` is a degree-6 Taylor polynomial (λ·r < 0.079, so its
//! truncation error is below 5e-12 absolute). The 130 table constants are computed by `const fn`
//! at compile time, so they cannot drift from the formula.
//!
//! Cost per evaluation, written for a 32-bit core: one 32 × 64-bit multiplication for u, and
//! eight 32 × 32 → 64-bit multiplications (one `UMULL` each on a Cortex-M4) plus three divisions
//! of a `u32` by 3, 5 and 6, which compilers turn into multiplications by a reciprocal (exact
//! for every `u32`). No 64-bit division (a call to `__aeabi_uldivmod` on a Cortex-M4, around
//! 100 instructions), no float.

use crate::level::{Gain, Level};

/// λ, the decay constant of the reference implementation.
const LAMBDA: f64 = 5.0;
/// log2 of the number of table segments over u ∈ [0, 1].
const SEGMENT_SHIFT: u32 = 6;
const SEGMENTS: usize = 1 << SEGMENT_SHIFT;
/// Width of one segment in Q32 units of u.
const SEGMENT_BITS: u32 = 32 - SEGMENT_SHIFT;
/// u is formed in Q56 from the elapsed time and the reciprocal of τ (see [`Decay::new`]).
const RECIPROCAL_SHIFT: u32 = 56;
/// 2^32 as a float, to scale table constants to Q32.
const Q32: f64 = 4_294_967_296.0;

/// e^x for the tables below ([`crate::const_exp::exp`] with 10 Taylor terms).
const fn exp(x: f64) -> f64 {
    crate::const_exp::exp(x, 10)
}

/// `value` in Q32, rounded to nearest. `value` must be in [0, 1).
const fn to_q32(value: f64) -> u32 {
    (value * Q32 + 0.5) as u32
}

/// G_i + [`CEILING_MARGIN`], with G_i = e^(−λ)(e^(λ i/64) − 1), i = 0..=64, in Q32 (G_64 =
/// 1 − e^(−λ), the loss at u = 1), and entry 65 the same as entry 64. One table for two uses:
/// [`loss`] starts segment i at entry i (and takes the margin off), and [`ceiling`] bounds the
/// loss over segment i by entry i + 1.
// Why the margin is in the table: the ceiling, on every frame's path, is then a load, and loss()
// takes it off in a rounding constant it adds anyway. A table of ceilings of its own was 260
// bytes of flash, which the NUCLEO-G474RE's firmware needed for the schema server.
// Evaluated at compile time: an index out of bounds would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
static LOSS_AT: [u32; SEGMENTS + 2] = {
    let mut table = [0; SEGMENTS + 2];
    let mut i = 0;
    while i <= SEGMENTS {
        let u = i as f64 / SEGMENTS as f64;
        table[i] = to_q32(exp(-LAMBDA) * (exp(LAMBDA * u) - 1.0)) + CEILING_MARGIN;
        i += 1;
    }
    table[SEGMENTS + 1] = table[SEGMENTS];
    table
};

/// E_i = e^(λ(i/64 − 1)), i = 0..64, in Q32: the slope factor within segment i.
// Evaluated at compile time: an index out of bounds would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
const SLOPE_AT: [u32; SEGMENTS] = {
    let mut table = [0; SEGMENTS];
    let mut i = 0;
    while i < SEGMENTS {
        let u = i as f64 / SEGMENTS as f64;
        table[i] = to_q32(exp(LAMBDA * (u - 1.0)));
        i += 1;
    }
    table
};

/// The loss at u = 1: what remains after exactly τ is e^(−λ) of the level.
const LOSS_AT_ONE: u32 = LOSS_AT[SEGMENTS] - CEILING_MARGIN;

/// How far above the loss at the end of its segment [`loss`] may be, in Q32 units, at most: the
/// loss is within 1.5 units of g, which grows with u (`tests::loss_is_within_its_ceiling`).
const CEILING_MARGIN: u32 = 16;

/// An upper bound of [`loss`] over segment `segment`, i = 0..=64 (64: u = 1 exactly): the next
/// segment's start plus the margin; `None` past u = 1. With it a frame that saturates the level
/// anyway skips the evaluation of the loss.
#[inline(always)]
fn ceiling(segment: usize) -> Option<u32> {
    LOSS_AT.get(1..).and_then(|next| next.get(segment)).copied()
}

/// e^r − 1 for r in [0, 0.08), r in Q32, result in Q32.
///
/// Horner form of r(1 + r/2(1 + r/3(1 + r/4(1 + r/5(1 + r/6))))). Every factor (1 + …) is in
/// [1, 1.05): it is held as its fraction below 1, in Q32, so that each step is a 32 × 32 → 64-bit
/// multiplication: with a factor 1 + f, `(r · (1 + f)) >> 32` is exactly `r + (r · f) >> 32`
/// (r · 2^32 contributes exactly r to the upper word). The divisions by 2 to 6 apply to values
/// below 2^30 and truncate, as they did when this was written with 64-bit factors: the result is
/// bit for bit that of the 64-bit Horner form (`tests::expm1_is_the_64_bit_horner_form`). The
/// first omitted term, r^7/7!, is under 0.02 Q32 units.
fn expm1_small(r: u32) -> u32 {
    // r < 2^29, so r + (r · f) >> 32 < 2^30 for every fraction f < 2^32: no step overflows.
    let step = |fraction: u32| r + ((u64::from(r) * u64::from(fraction)) >> 32) as u32;
    let z = r / 6;
    let a = step(z) / 5;
    let b = step(a) / 4;
    let c = step(b) / 3;
    let d = step(c) / 2;
    // r · (1 + d) rounded to nearest: r + (r · d + 2^31) >> 32, with r · d + 2^31 < 2^62.
    r + ((u64::from(r) * u64::from(d) + (1 << 31)) >> 32) as u32
}

/// g(u) = 1 − f(u) in Q32, for u in Q32 within [0, 2^32].
fn loss(u: u64) -> u32 {
    let segment = (u >> SEGMENT_BITS) as usize;
    let rest = (u & ((1 << SEGMENT_BITS) - 1)) as u32;
    match (LOSS_AT.get(segment), SLOPE_AT.get(segment)) {
        (Some(&base), Some(&slope)) => {
            // λ · rest, in Q32: rest < 2^26, so 5 · rest < 2^29.
            let lambda_r = rest * LAMBDA as u32;
            // Rounded to nearest, less the margin that `base` carries: slope < 2^32 and expm1
            // < 2^29, so the product and the rounding stay below 2^62; what is taken off, an
            // integer of the upper word, only wraps it when `within` is below the margin.
            let within = (u64::from(slope) * u64::from(expm1_small(lambda_r)))
                .wrapping_add((1u64 << 31).wrapping_sub(u64::from(CEILING_MARGIN) << 32))
                >> 32;
            // G_i + margin + (within − margin), modulo 2^32: G_(i+1) + a few units < 2^32.
            base.wrapping_add(within as u32)
        }
        // Only u = 2^32 exactly (dt = τ) reaches the last table entry.
        _ => LOSS_AT_ONE,
    }
}

/// A decay time τ in whole microseconds, with its reciprocal precomputed so that evaluating the
/// decay costs no division.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub(crate) struct Decay {
    micros: u32,
    /// floor(2^56 / τ): u in Q56 is `elapsed · reciprocal`, at most 2^56 for elapsed ≤ τ. The
    /// floor makes u short of the exact value by at most τ / 2^56 relative (5e-8 for τ = 1 h,
    /// 4e-11 for τ = 3 s).
    reciprocal: u64,
}

impl Decay {
    /// τ = `micros`; `None` for zero. Costs one 64-bit division.
    pub(crate) const fn new(micros: u32) -> Option<Decay> {
        match (1u64 << RECIPROCAL_SHIFT).checked_div(micros as u64) {
            Some(reciprocal) => Some(Decay { micros, reciprocal }),
            None => None,
        }
    }

    /// τ in microseconds and the reciprocal, for a caller that stores them apart (without the
    /// struct's padding); [`Decay::from_parts`] puts them back together.
    pub(crate) const fn parts(&self) -> (u32, u64) {
        (self.micros, self.reciprocal)
    }

    /// The decay whose [`Decay::parts`] these are.
    #[inline(always)]
    pub(crate) const fn from_parts(micros: u32, reciprocal: u64) -> Decay {
        Decay { micros, reciprocal }
    }

    /// τ in microseconds.
    pub(crate) const fn micros(&self) -> u32 {
        self.micros
    }

    /// The level `elapsed` µs after it was `level`: `level · f(elapsed / τ)`, or zero once more than
    /// τ has passed. Rounds towards the larger level by less than 1e-9.
    pub(crate) fn apply(&self, level: Level, elapsed: u64) -> Level {
        match u32::try_from(elapsed) {
            Ok(elapsed) if elapsed <= self.micros => self.apply_within(level, elapsed),
            _ => Level::ZERO,
        }
    }

    /// `apply_within(level, elapsed).saturating_add(gain)`, the step of a frame: when the sum
    /// saturates whatever the loss within u's segment (a connection fed faster than it decays),
    /// the loss is not evaluated. Same result, bit for bit
    /// (`tests::stimulation_step_is_decay_then_gain`).
    #[inline]
    pub(crate) fn apply_then_add(&self, level: Level, elapsed: u32, gain: Gain) -> Level {
        let elapsed = elapsed.min(self.micros);
        // As in `apply_within`: at most 2^56, it cannot wrap.
        let u = u64::from(elapsed).wrapping_mul(self.reciprocal) >> (RECIPROCAL_SHIFT - 32);
        if let Some(ceiling) = ceiling((u >> SEGMENT_BITS) as usize) {
            // level − lost ≥ level − most_lost, and level + gain ≤ 2^32: no overflow.
            let most_lost = (u64::from(level.raw()) * u64::from(ceiling)) >> 32;
            if level.raw() - most_lost as u32 + gain.raw() >= Level::FULL.raw() {
                return Level::FULL;
            }
        }
        let lost = (u64::from(level.raw()) * u64::from(loss(u))) >> 32;
        Level::from_raw(level.raw().saturating_sub(lost as u32))
            .unwrap_or(Level::ZERO)
            .saturating_add(gain)
    }

    /// [`Decay::apply`] for an `elapsed` already known to be at most τ (a larger one is treated
    /// as τ): 32-bit arithmetic only, for the frame path.
    #[inline]
    pub(crate) fn apply_within(&self, level: Level, elapsed: u32) -> Level {
        let elapsed = elapsed.min(self.micros);
        // elapsed ≤ τ and reciprocal ≤ 2^56 / τ, so the product is at most 2^56: it cannot wrap.
        let u = u64::from(elapsed).wrapping_mul(self.reciprocal) >> (RECIPROCAL_SHIFT - 32);
        let lost = (u64::from(level.raw()) * u64::from(loss(u))) >> 32;
        // lost ≤ level because loss < 1.
        Level::from_raw(level.raw().saturating_sub(lost as u32)).unwrap_or(Level::ZERO)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reference_f(u: f64) -> f64 {
        1.0 - (LAMBDA * (u - 1.0)).exp() + (-LAMBDA).exp()
    }

    /// The 64-bit Horner form `expm1_small` was first written in (divisions of `u64`s, which a
    /// Cortex-M4 makes calls to `__aeabi_uldivmod`): the reference its 32-bit form must equal.
    fn expm1_64(r: u32) -> u32 {
        const ONE: u64 = 1 << 32;
        let r = u64::from(r);
        let z = ONE + r / 6;
        let a = ONE + ((r * z) >> 32) / 5;
        let b = ONE + ((r * a) >> 32) / 4;
        let c = ONE + ((r * b) >> 32) / 3;
        let d = ONE + ((r * c) >> 32) / 2;
        ((r * d + (1 << 31)) >> 32) as u32
    }

    #[test]
    fn expm1_is_the_64_bit_horner_form() {
        // Every argument the decay can pass is below 5 · 2^26: the low 2^20 of them, a stride
        // through all, and the top of the range.
        let top = 5u32 << SEGMENT_BITS;
        let arguments = (0..1u32 << 20)
            .chain((0..top).step_by(997))
            .chain(top - (1 << 16)..top);
        for r in arguments {
            assert_eq!(expm1_small(r), expm1_64(r), "r = {r}");
        }
    }

    #[test]
    fn loss_is_within_its_ceiling() {
        // A dense sweep, and the top 2^12 arguments of every segment, where the loss is largest.
        let sweep = (0..=2_000_000u64).map(|k| k * (1 << 32) / 2_000_000);
        let tops = (1..=SEGMENTS as u64)
            .flat_map(|i| (i << SEGMENT_BITS) - (1 << 12)..(i << SEGMENT_BITS).min(1 << 32) + 1);
        for u in sweep.chain(tops) {
            let ceiling = ceiling((u >> SEGMENT_BITS) as usize).unwrap();
            assert!(loss(u) <= ceiling, "u {u}: {} > {ceiling}", loss(u));
        }
    }

    #[test]
    fn stimulation_step_is_decay_then_gain() {
        // Levels and gains around saturation and far from it, elapsed over all of τ.
        let decay = Decay::new(3_000_000).unwrap();
        let levels = [
            0,
            1,
            1 << 20,
            1 << 30,
            (1 << 31) - (1 << 24),
            (1 << 31) - 1,
            1 << 31,
        ];
        let gains = [
            1 << 15,
            1 << 24,
            429_496_730,
            1 << 30,
            (1 << 31) - 1,
            1 << 31,
        ];
        let mut seed = 0x2545_F491u64;
        for &level in &levels {
            for &gain in &gains {
                let (level, gain) = (
                    Level::from_raw(level).unwrap(),
                    Gain::from_raw(gain).unwrap(),
                );
                for k in 0..=3_000u32 {
                    seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                    let elapsed = (k * 1_000).saturating_sub((seed >> 40) as u32 % 1_000);
                    let expected = decay.apply_within(level, elapsed).saturating_add(gain);
                    assert_eq!(decay.apply_then_add(level, elapsed, gain), expected);
                }
            }
        }
    }

    #[test]
    fn tables_match_std_exp() {
        assert_eq!(LOSS_AT[SEGMENTS + 1], LOSS_AT[SEGMENTS]);
        for (i, &g) in LOSS_AT.iter().take(SEGMENTS + 1).enumerate() {
            let g = g - CEILING_MARGIN;
            let u = i as f64 / SEGMENTS as f64;
            let exact = (-LAMBDA).exp() * (LAMBDA * u).exp_m1() * Q32;
            assert!((f64::from(g) - exact).abs() <= 1.0, "G_{i}: {g} vs {exact}");
        }
        for (i, &e) in SLOPE_AT.iter().enumerate() {
            let u = i as f64 / SEGMENTS as f64;
            let exact = (LAMBDA * (u - 1.0)).exp() * Q32;
            assert!((f64::from(e) - exact).abs() <= 1.0, "E_{i}: {e} vs {exact}");
        }
    }

    #[test]
    fn worked_numbers_of_the_design_notes() {
        // f(0) = 1, f(0.5) = 0.9246, f(0.9) = 0.4002, f(1) = e^-5.
        let tau = Decay::new(1_000_000).unwrap();
        for (elapsed, expected) in [(0, 1.0), (500_000, 0.9246), (900_000, 0.4002)] {
            let got = tau.apply(Level::FULL, elapsed).to_f64();
            // The design notes round to four decimals.
            assert!((got - expected).abs() < 1e-4, "f({elapsed}) = {got}");
        }
        let at_tau = tau.apply(Level::FULL, 1_000_000).to_f64();
        assert!((at_tau - (-5f64).exp()).abs() < 1e-8, "{at_tau}");
        assert_eq!(tau.apply(Level::FULL, 1_000_001), Level::ZERO);
    }

    #[test]
    fn loss_is_within_one_and_a_half_q32_units_everywhere() {
        // g straight from its Q32 argument: a dense sweep plus every argument below 2^16. 1.5
        // units (3.5e-10) absolute is what the steady-state argument needs: a connection fed at
        // a constant rate settles at σ / g, so its error is at most 1.5 · 2^-32 / σ ≤ 2.3e-5.
        let mut worst: f64 = 0.0;
        let sweep = (0..=2_000_000u64).map(|k| k * (1 << 32) / 2_000_000);
        for u in sweep.chain(0..1 << 16) {
            let exact = (1.0 - reference_f(u as f64 / Q32)) * Q32;
            let units = (f64::from(loss(u)) - exact).abs();
            worst = worst.max(units);
        }
        assert!(worst <= 1.5, "g off by {worst} Q32 units");
    }

    #[test]
    fn applied_decay_is_accurate_in_absolute_terms() {
        // Error sources: Q31 rounding (~1e-9) and the floor of the reciprocal of τ, which makes u
        // short by at most τ / 2^56 relative; |f'| ≤ 5, so at most 5 τ / 2^56 (2.5e-7 at 1 h).
        for tau_us in [1u32, 1_000, 3_000_000, 60_000_000, 3_600_000_000] {
            let decay = Decay::new(tau_us).unwrap();
            let bound = 2e-9 + 5.0 * f64::from(tau_us) / 2f64.powi(56);
            let steps = 20_000u64;
            for k in 0..=steps {
                let elapsed = u64::from(tau_us) * k / steps;
                let exact = reference_f(elapsed as f64 / f64::from(tau_us));
                let got = decay.apply(Level::FULL, elapsed).to_f64();
                let error = (got - exact).abs();
                assert!(
                    error <= bound,
                    "τ {tau_us} µs, dt {elapsed}: error {error:e} > {bound:e}"
                );
            }
        }
    }

    #[test]
    fn decay_never_raises_a_level() {
        let decay = Decay::new(3_000_000).unwrap();
        for raw in [0, 1, 2, 1 << 20, (1 << 31) - 1, 1 << 31] {
            let level = Level::from_raw(raw).unwrap();
            let mut previous = level;
            for elapsed in (0..=3_000_000).step_by(7_919) {
                let now = decay.apply(level, elapsed);
                assert!(now <= previous, "raw {raw} at {elapsed}");
                previous = now;
            }
        }
    }

    #[test]
    fn zero_decay_time_is_refused() {
        assert_eq!(Decay::new(0), None);
        assert_eq!(Decay::new(1).map(|d| d.reciprocal), Some(1 << 56));
    }
}
