//! The stimulation integrator of one connection: how frames make it active.
//!
//! On a frame at time t (DESIGN.md, "Stimulation: the reference semantics"):
//! S = min(1, S(t) + σ), t0 = t, S0 = S. The connection becomes active when S reaches 1 and stays
//! active until S(t) is 0, that is until more than τ has passed without an accepted frame.
//!
//! Rest time τr: once the activity has ended (at t0 + τ), frames that arrive during the next τr
//! neither stimulate the connection nor make it active. A burst that keeps a sensor's connection
//! alive therefore cannot re-trigger it immediately after it lapsed: a refractory period.
//!
//! Everything is evaluated lazily from (S0, t0): the integrator never needs a timer tick, and
//! reading it never changes it.

use serde::{Deserialize, Serialize};

use crate::decay::Decay;
use crate::level::{Gain, GainError, Level};
use crate::time::Instant;

/// The longest decay time and rest time accepted: one hour.
pub const MAX_TIME_US: u32 = 3_600_000_000;

/// A connection's stimulation parameters ⟨σ, τ, τr⟩, as stored in a table image.
///
/// Times are whole microseconds. Validated by [`Stimulation::new`] and by the table loader:
/// σ in [2^-16, 1], τ in [1 µs, 1 h], τr in [0, 1 h].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stimulation {
    gain: Gain,
    decay_us: u32,
    rest_us: u32,
}

impl Stimulation {
    /// Parameters from a gain and times in microseconds.
    pub const fn new(gain: Gain, decay_us: u32, rest_us: u32) -> Result<Self, ParamError> {
        let parameters = Stimulation {
            gain,
            decay_us,
            rest_us,
        };
        match parameters.validate() {
            Ok(()) => Ok(parameters),
            Err(error) => Err(error),
        }
    }

    /// Parameters from σ and times in seconds, as a network file writes them. Times are rounded to
    /// the nearest microsecond; NaN, infinities and values out of range are errors.
    pub fn from_seconds(sigma: f64, tau: f64, rest: f64) -> Result<Self, ParamError> {
        let gain = Gain::from_f64(sigma).map_err(ParamError::Gain)?;
        let decay_us = micros_from_seconds(tau).ok_or(ParamError::DecayTime)?;
        let rest_us = micros_from_seconds(rest).ok_or(ParamError::RestTime)?;
        Stimulation::new(gain, decay_us, rest_us)
    }

    /// Checks the invariants; the table loader calls it on every connection it reads.
    pub const fn validate(&self) -> Result<(), ParamError> {
        if let Err(error) = Gain::from_raw(self.gain.raw()) {
            return Err(ParamError::Gain(error));
        }
        if self.decay_us == 0 || self.decay_us > MAX_TIME_US {
            return Err(ParamError::DecayTime);
        }
        if self.rest_us > MAX_TIME_US {
            return Err(ParamError::RestTime);
        }
        Ok(())
    }

    /// σ.
    pub const fn gain(&self) -> Gain {
        self.gain
    }

    /// τ in microseconds.
    pub const fn decay_us(&self) -> u32 {
        self.decay_us
    }

    /// τr in microseconds.
    pub const fn rest_us(&self) -> u32 {
        self.rest_us
    }
}

/// `seconds` as whole microseconds, if it is finite and within [0, [`MAX_TIME_US`]].
fn micros_from_seconds(seconds: f64) -> Option<u32> {
    let micros = seconds * 1e6;
    if micros.is_finite() && (0.0..=f64::from(MAX_TIME_US)).contains(&micros) {
        Some((micros + 0.5) as u32)
    } else {
        None
    }
}

// Not `#[non_exhaustive]`: the compiler's diagnostics (lang/src/network.rs) point at each variant's
// own field.
/// Why stimulation parameters were refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamError {
    /// σ is out of range.
    Gain(GainError),
    /// τ is not in [1 µs, 1 h] (zero, negative, NaN, too long).
    DecayTime,
    /// τr is not in [0, 1 h].
    RestTime,
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParamError::Gain(error) => write!(f, "st (σ): {error}"),
            ParamError::DecayTime => f.write_str(
                "tc (τ): decay time must be a number of seconds in [0.000001, 3600] (it is kept in whole microseconds)",
            ),
            ParamError::RestTime => {
                f.write_str("tr (τr): rest time must be a number of seconds in [0, 3600]")
            }
        }
    }
}

impl core::error::Error for ParamError {}

/// What a frame did to a connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Stimulated {
    /// The frame raised the level (possibly to full).
    Accepted,
    /// The connection was resting after an activity: the frame changed nothing.
    Resting,
}

/// The state of one connection's integrator: 16 bytes. Starts at S = 0, inactive.
///
/// The parameters are not stored here: the same [`Stimulation`] must be passed to every call.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Integrator {
    /// S0: the level right after the last accepted frame.
    level: Level,
    /// t0: when the last accepted frame arrived (meaningless while `level` is zero and inactive).
    last: Instant,
    /// Whether S reached 1 since the connection was last inactive.
    active: bool,
}

impl Integrator {
    /// S = 0, inactive, never stimulated.
    pub const fn new() -> Self {
        Integrator {
            level: Level::ZERO,
            last: Instant::from_micros(0),
            active: false,
        }
    }

    /// Time since the last accepted frame; a frame timestamped before it counts as simultaneous.
    fn elapsed(&self, now: Instant) -> u64 {
        now.micros_since(self.last).unwrap_or(0)
    }

    /// S(now). Read-only; costs one decay evaluation.
    pub fn level(&self, parameters: &Runtime, now: Instant) -> Level {
        self.level_with(&parameters.decay, now)
    }

    /// x(now): active from S reaching 1 until τ has passed without an accepted frame.
    pub fn is_active(&self, parameters: &Runtime, now: Instant) -> bool {
        self.is_active_with(&parameters.decay, now)
    }

    /// Applies a frame that arrived at `now`.
    pub fn stimulate(&mut self, parameters: &Runtime, now: Instant) -> Stimulated {
        self.stimulate_with(&parameters.stimulation, &parameters.decay, now)
    }

    /// [`Integrator::level`] with τ's evaluation form alone (the arbiter keeps the parameters in
    /// its table and only the decay beside the integrator).
    pub(crate) fn level_with(&self, decay: &Decay, now: Instant) -> Level {
        decay.apply(self.level, self.elapsed(now))
    }

    /// [`Integrator::is_active`] with τ's evaluation form alone.
    pub(crate) fn is_active_with(&self, decay: &Decay, now: Instant) -> bool {
        self.active && self.elapsed(now) <= u64::from(decay.micros())
    }

    /// Whether `now` falls in the rest phase that follows the end of an activity.
    pub(crate) fn is_resting(&self, decay: &Decay, rest_us: u32, now: Instant) -> bool {
        let elapsed = self.elapsed(now);
        let decay = u64::from(decay.micros());
        self.active && elapsed > decay && elapsed <= decay.saturating_add(u64::from(rest_us))
    }

    /// [`Integrator::stimulate`] with the parameters and τ's evaluation form apart. `decay` must
    /// be built from `stimulation`'s τ.
    pub(crate) fn stimulate_with(
        &mut self,
        stimulation: &Stimulation,
        decay: &Decay,
        now: Instant,
    ) -> Stimulated {
        self.stimulate_parts(stimulation.gain, stimulation.rest_us, decay, now)
    }

    /// [`Integrator::stimulate`] from σ, τr and τ's evaluation form, the time since the last frame
    /// computed once: what the arbiter calls for every frame that feeds a connection.
    #[inline]
    pub(crate) fn stimulate_parts(
        &mut self,
        gain: Gain,
        rest_us: u32,
        decay: &Decay,
        now: Instant,
    ) -> Stimulated {
        let elapsed = self.elapsed(now);
        let tau = decay.micros();
        let (level, was_active) = match u32::try_from(elapsed) {
            // Within τ: S(now) from the decay, active as before.
            Ok(elapsed) if elapsed <= tau => {
                (decay.apply_then_add(self.level, elapsed, gain), self.active)
            }
            // Past τ: S(now) is 0, the activity has ended; during the rest phase after an activity
            // the frame is ignored (`is_resting`: elapsed − τ ≤ τr).
            _ => {
                if self.active && elapsed - u64::from(tau) <= u64::from(rest_us) {
                    return Stimulated::Resting;
                }
                (Level::ZERO.saturating_add(gain), false)
            }
        };
        *self = Integrator {
            level,
            last: now,
            active: was_active || level == Level::FULL,
        };
        Stimulated::Accepted
    }

    /// Whether the connection was active when its last frame was accepted: with
    /// [`Integrator::last`] and τ, what its activity at any instant follows from.
    pub(crate) const fn active_flag(&self) -> bool {
        self.active
    }

    /// When its last frame was accepted.
    pub(crate) const fn last(&self) -> Instant {
        self.last
    }
}

/// A connection's parameters in the form the integrator evaluates them: [`Stimulation`] plus the
/// reciprocal of τ, so that a frame costs no division. 24 bytes. Built once when a table is loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Runtime {
    stimulation: Stimulation,
    decay: Decay,
}

impl Runtime {
    /// Precomputes the evaluation form. Fails only on parameters that [`Stimulation::validate`]
    /// refuses.
    pub const fn new(stimulation: Stimulation) -> Result<Self, ParamError> {
        if let Err(error) = stimulation.validate() {
            return Err(error);
        }
        match Decay::new(stimulation.decay_us) {
            Some(decay) => Ok(Runtime { stimulation, decay }),
            None => Err(ParamError::DecayTime),
        }
    }

    /// The parameters it was built from.
    pub const fn stimulation(&self) -> &Stimulation {
        &self.stimulation
    }
}

crate::wire::decode_struct!(Stimulation {
    gain,
    decay_us,
    rest_us
});

#[cfg(test)]
mod tests {
    use super::*;

    fn runtime(sigma: f64, tau: f64, rest: f64) -> Runtime {
        Runtime::new(Stimulation::from_seconds(sigma, tau, rest).unwrap()).unwrap()
    }

    fn at(seconds: f64) -> Instant {
        Instant::from_micros((seconds * 1e6).round() as u64)
    }

    #[test]
    fn worked_numbers_of_the_design_notes() {
        // σ = 0.2, τ = 3 s, one frame every 0.6 s.
        let parameters = runtime(0.2, 3.0, 0.0);
        let mut integrator = Integrator::new();
        let expected = [0.2, 0.3977, 0.5931, 0.7862, 0.9771, 1.0];
        for (k, want) in expected.iter().enumerate() {
            let now = at(0.6 * k as f64);
            assert_eq!(integrator.stimulate(&parameters, now), Stimulated::Accepted);
            let got = integrator.level(&parameters, now).to_f64();
            assert!((got - want).abs() < 1e-4, "frame {k}: {got} vs {want}");
            assert_eq!(integrator.is_active(&parameters, now), k == 5, "frame {k}");
        }
        // Active until τ has passed after the last frame (t = 3.0), not a microsecond longer.
        assert!(integrator.is_active(&parameters, at(6.0)));
        assert!(!integrator.is_active(&parameters, at(6.0).wrapping_add_micros(1)));
        assert_eq!(
            integrator.level(&parameters, at(6.0).wrapping_add_micros(1)),
            Level::ZERO
        );
    }

    #[test]
    fn activity_lasts_while_frames_keep_coming() {
        let parameters = runtime(1.0, 1.0, 0.0);
        let mut integrator = Integrator::new();
        integrator.stimulate(&parameters, at(0.0));
        assert!(integrator.is_active(&parameters, at(0.0)));
        // Frames every 0.9 s keep it active even though S dips below 1 between them.
        for k in 1..10 {
            integrator.stimulate(&parameters, at(0.9 * k as f64));
            assert!(integrator.is_active(&parameters, at(0.9 * k as f64 + 0.5)));
        }
    }

    #[test]
    fn rest_time_ignores_frames_after_an_activity() {
        let parameters = runtime(1.0, 1.0, 2.0);
        let mut integrator = Integrator::new();
        integrator.stimulate(&parameters, at(0.0));
        assert!(integrator.is_active(&parameters, at(1.0)));
        // Activity ended after t = 1.0; frames in (1.0, 3.0] are ignored.
        for t in [1.000_001, 2.0, 3.0] {
            assert_eq!(
                integrator.stimulate(&parameters, at(t)),
                Stimulated::Resting
            );
            assert!(!integrator.is_active(&parameters, at(t)));
        }
        assert_eq!(
            integrator.stimulate(&parameters, at(3.000_001)),
            Stimulated::Accepted
        );
        assert!(integrator.is_active(&parameters, at(3.000_001)));
    }

    #[test]
    fn without_rest_time_a_lapsed_connection_restarts_from_zero() {
        let parameters = runtime(0.5, 1.0, 0.0);
        let mut integrator = Integrator::new();
        integrator.stimulate(&parameters, at(0.0));
        integrator.stimulate(&parameters, at(0.0));
        assert!(integrator.is_active(&parameters, at(0.0)));
        integrator.stimulate(&parameters, at(5.0));
        assert!(!integrator.is_active(&parameters, at(5.0)));
        assert_eq!(
            integrator.level(&parameters, at(5.0)),
            Level::from_raw(1 << 30).unwrap()
        );
    }

    #[test]
    fn out_of_order_frames_count_as_simultaneous() {
        let parameters = runtime(0.5, 1.0, 0.0);
        let mut integrator = Integrator::new();
        integrator.stimulate(&parameters, at(10.0));
        integrator.stimulate(&parameters, at(9.0));
        assert!(integrator.is_active(&parameters, at(10.0)));
    }

    #[test]
    fn parameters_are_validated() {
        use ParamError::*;
        assert!(Stimulation::from_seconds(0.2, 3.0, 0.0).is_ok());
        assert_eq!(Stimulation::from_seconds(0.2, 0.0, 0.0), Err(DecayTime));
        assert_eq!(Stimulation::from_seconds(0.2, -1.0, 0.0), Err(DecayTime));
        assert_eq!(
            Stimulation::from_seconds(0.2, f64::NAN, 0.0),
            Err(DecayTime)
        );
        assert_eq!(Stimulation::from_seconds(0.2, 3601.0, 0.0), Err(DecayTime));
        assert_eq!(Stimulation::from_seconds(0.2, 1e-7, 0.0), Err(DecayTime));
        assert_eq!(Stimulation::from_seconds(0.2, 1.0, -0.5), Err(RestTime));
        assert_eq!(
            Stimulation::from_seconds(0.2, 1.0, f64::INFINITY),
            Err(RestTime)
        );
        assert_eq!(
            Stimulation::from_seconds(f64::NAN, 1.0, 0.0),
            Err(Gain(GainError::NotInRange))
        );
    }
}
