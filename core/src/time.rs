//! Timestamps: microseconds on a free-running 64-bit counter.
//!
//! Why 64 bits: the integrators evaluate their stimulation lazily, from the time of the last
//! accepted frame. With a 32-bit microsecond counter (71.6 minutes per wrap) a connection that stayed
//! silent for longer than half a wrap would look recent again. A 64-bit counter does not wrap in
//! practice, and every comparison here is still made on wrapping differences, so a counter that
//! starts anywhere (a board's timer, an `embassy_time::Instant`, a simulation clock) works unchanged.

/// A point in time, in microseconds, on a free-running counter.
///
/// Only differences between instants mean anything. Two instants are compared through
/// [`Instant::micros_since`], which is correct across a wrap of the counter as long as the two are
/// less than 2^63 µs apart.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instant(u64);

impl Instant {
    /// The instant `micros` microseconds after the counter's zero.
    pub const fn from_micros(micros: u64) -> Self {
        Self(micros)
    }

    /// The raw counter value.
    pub const fn as_micros(self) -> u64 {
        self.0
    }

    /// Microseconds from `earlier` to `self`, or `None` when `self` is before `earlier`.
    ///
    /// Costs one subtraction and one comparison. "Before" means the wrapping difference is 2^63 µs
    /// or more: that happens when frames are timestamped out of order (two CAN controllers, a clock
    /// that was set back). The integrator treats such a frame as simultaneous with the last one.
    pub const fn micros_since(self, earlier: Instant) -> Option<u64> {
        let difference = self.0.wrapping_sub(earlier.0);
        if difference > i64::MAX as u64 {
            None
        } else {
            Some(difference)
        }
    }

    /// The instant `micros` microseconds later, wrapping around the counter.
    pub const fn wrapping_add_micros(self, micros: u64) -> Self {
        Self(self.0.wrapping_add(micros))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_are_wrap_safe() {
        let before = Instant::from_micros(u64::MAX - 5);
        let after = before.wrapping_add_micros(10);
        assert_eq!(after.as_micros(), 4);
        assert_eq!(after.micros_since(before), Some(10));
        assert_eq!(before.micros_since(after), None);
        assert_eq!(after.micros_since(after), Some(0));
    }
}
