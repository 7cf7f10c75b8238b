//! Stimulation levels and gains in Q1.31 fixed point.
//!
//! Why fixed point: the same table must give the same decisions on a Cortex-M0 without an FPU, on a
//! Cortex-M4F and on the workstation that simulates it. Integer arithmetic is identical everywhere;
//! floating point is identical only if every target rounds every operation the same way, and `exp`
//! differs between libm implementations. Q1.31 (1.0 = 2^31) holds every level in [0, 1] exactly at
//! the ends, with a resolution of 4.7e-10, and a level plus a gain never overflows a `u32` before
//! it is clamped.

use serde::{Deserialize, Serialize};

/// 1.0 in Q1.31.
const ONE: u32 = 1 << 31;

/// A stimulation level S in [0, 1], in Q1.31 fixed point. `Level::FULL` is the activation
/// threshold.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Level(u32);

impl Level {
    /// S = 0.
    pub const ZERO: Level = Level(0);
    /// S = 1: a connection that reaches it becomes active.
    pub const FULL: Level = Level(ONE);

    /// The level with raw Q1.31 value `raw`, or `None` above 1.0 (`raw > 2^31`).
    pub const fn from_raw(raw: u32) -> Option<Level> {
        if raw <= ONE { Some(Level(raw)) } else { None }
    }

    /// The raw Q1.31 value, 0..=2^31.
    pub const fn raw(self) -> u32 {
        self.0
    }

    /// The level as a float, exact (every Q1.31 value is representable in an `f64`).
    pub fn to_f64(self) -> f64 {
        f64::from(self.0) / f64::from(ONE)
    }

    /// `self + gain`, clamped to [`Level::FULL`]. Never overflows: both are at most 2^31.
    pub(crate) const fn saturating_add(self, gain: Gain) -> Level {
        let sum = self.0.saturating_add(gain.0);
        if sum >= ONE { Level::FULL } else { Level(sum) }
    }
}

/// The smallest accepted gain, 2^-16 ≈ 1.5e-5 (one in 65 536 frames to activate).
///
/// Why a floor: in a steady state the integrator's error is its per-frame rounding error divided
/// by the gain. Below 2^-16 the promised accuracy (1e-3 against the exact formula) could not be
/// kept, and no practical connection needs more than 65 536 frames to activate.
pub const MIN_GAIN_RAW: u32 = 1 << 15;

/// A stimulation gain σ in (0, 1]: how much one frame raises the level. Q1.31, at least
/// [`MIN_GAIN_RAW`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Gain(u32);

impl Gain {
    /// σ = 1: one frame activates the connection.
    pub const ONE: Gain = Gain(ONE);

    /// The gain with raw Q1.31 value `raw`, if it is in [`MIN_GAIN_RAW`, 2^31].
    pub const fn from_raw(raw: u32) -> Result<Gain, GainError> {
        if raw > ONE {
            Err(GainError::NotInRange)
        } else if raw < MIN_GAIN_RAW {
            Err(GainError::BelowResolution)
        } else {
            Ok(Gain(raw))
        }
    }

    /// The gain nearest to `sigma`, which must be finite and in (0, 1].
    ///
    /// NaN and infinities are rejected, never propagated.
    pub fn from_f64(sigma: f64) -> Result<Gain, GainError> {
        if !(sigma > 0.0 && sigma <= 1.0) {
            return Err(GainError::NotInRange);
        }
        // Round to nearest: sigma * 2^31 is in (0, 2^31], so the sum fits and `as` truncates a
        // non-negative value, which is exact rounding here.
        let raw = (sigma * f64::from(ONE) + 0.5) as u32;
        Gain::from_raw(raw)
    }

    /// The raw Q1.31 value.
    pub const fn raw(self) -> u32 {
        self.0
    }

    /// The gain as a float, exact.
    pub fn to_f64(self) -> f64 {
        f64::from(self.0) / f64::from(ONE)
    }
}

/// Why a gain was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum GainError {
    /// Not a number in (0, 1].
    NotInRange,
    /// Positive but below [`MIN_GAIN_RAW`] (2^-16).
    BelowResolution,
}

impl core::fmt::Display for GainError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GainError::NotInRange => f.write_str("gain must be a number in (0, 1]"),
            GainError::BelowResolution => {
                f.write_str("gain is below the integrator's resolution of 2^-16 (1.53e-5)")
            }
        }
    }
}

impl core::error::Error for GainError {}

impl crate::wire::Decode for Gain {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        Gain(r.u32())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gains_are_validated() {
        assert_eq!(Gain::from_f64(1.0), Ok(Gain::ONE));
        assert_eq!(Gain::from_f64(0.2).map(Gain::raw), Ok(429_496_730));
        for bad in [
            0.0,
            -0.1,
            1.000_001,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert_eq!(Gain::from_f64(bad), Err(GainError::NotInRange), "{bad}");
        }
        assert_eq!(Gain::from_f64(1e-6), Err(GainError::BelowResolution));
        assert!(Gain::from_f64(2f64.powi(-16)).is_ok());
        assert_eq!(Gain::from_raw(ONE + 1), Err(GainError::NotInRange));
    }

    #[test]
    fn levels_clamp_at_full() {
        let almost = Level::from_raw(ONE - 1).unwrap();
        assert_eq!(almost.saturating_add(Gain::ONE), Level::FULL);
        assert_eq!(Level::FULL.saturating_add(Gain::ONE), Level::FULL);
        assert_eq!(Level::from_raw(ONE + 1), None);
        assert_eq!(Level::FULL.to_f64(), 1.0);
    }
}
