//! Fault reporting with a rate limit: at most one frame per fault code per interval, with the
//! number of occurrences since the previous frame, so a bus in trouble is not flooded by reports of
//! its own trouble and no occurrence goes uncounted.

use pab_core::Instant;
use pab_core::protocol::{Fault, FaultCode};

/// The default rate-limit interval: 100 ms.
pub const DEFAULT_INTERVAL_US: u64 = 100_000;

#[derive(Clone, Copy, Debug, Default)]
struct Slot {
    /// Occurrences not yet reported.
    pending: u32,
    /// Detail of the latest occurrence.
    detail: [u8; 5],
    /// When the last frame for this code went out.
    last_sent: Option<Instant>,
}

impl Slot {
    /// No occurrence, never sent. A constant rather than `Default::default()`: the node's
    /// construction then clears the slots instead of building them one by one on the stack and
    /// copying them twice.
    const EMPTY: Slot = Slot {
        pending: 0,
        detail: [0; 5],
        last_sent: None,
    };
}

/// One slot per [`FaultCode`]: 8 codes × 16 bytes, and which of them have occurrences pending.
#[derive(Clone, Debug)]
pub struct FaultLimiter {
    interval_us: u64,
    slots: [Slot; FaultCode::ALL.len()],
    /// Bit i: slot i has occurrences not yet reported (`pending > 0`).
    pending: u32,
}

impl FaultLimiter {
    /// A limiter sending at most one frame per code every `interval_us`.
    pub fn new(interval_us: u64) -> Self {
        FaultLimiter {
            interval_us,
            slots: [Slot::EMPTY; FaultCode::ALL.len()],
            pending: 0,
        }
    }

    /// Whether any occurrence waits to be reported: without one, [`FaultLimiter::next_due`] has
    /// nothing to send whatever the time. One comparison.
    #[inline]
    pub fn has_pending(&self) -> bool {
        self.pending != 0
    }

    /// Records one occurrence of `code`. Out of line: a node raises faults from a dozen places,
    /// and each inlined copy cost flash for a path that is never hot.
    #[inline(never)]
    pub fn raise(&mut self, code: FaultCode, detail: [u8; 5]) {
        let Some(index) = FaultCode::ALL.iter().position(|known| *known == code) else {
            return;
        };
        if let Some(slot) = self.slots.get_mut(index) {
            slot.pending = slot.pending.saturating_add(1);
            slot.detail = detail;
            self.pending |= bit(index);
        }
    }

    /// The next fault frame due at `now`, if any; marks it sent.
    pub fn next_due(&mut self, now: Instant) -> Option<Fault> {
        if !self.has_pending() {
            return None;
        }
        let interval = self.interval_us;
        for (index, (code, slot)) in FaultCode::ALL.iter().zip(self.slots.iter_mut()).enumerate() {
            if slot.pending > 0 && is_due(slot.last_sent, interval, now) {
                let fault = Fault {
                    code: *code,
                    count: u8::try_from(slot.pending).unwrap_or(u8::MAX),
                    detail: slot.detail,
                };
                slot.pending = 0;
                slot.last_sent = Some(now);
                self.pending &= !bit(index);
                return Some(fault);
            }
        }
        None
    }

    /// When the next pending fault may be sent (`None` if nothing is pending).
    pub fn deadline(&self) -> Option<Instant> {
        // A loop rather than `min_by_key`, whose key closure was inlined four times (76 bytes of
        // flash). The earliest of equal instants is the same instant either way.
        let mut earliest: Option<u64> = None;
        for slot in self.slots.iter().filter(|slot| slot.pending > 0) {
            let at = match slot.last_sent {
                Some(sent) => sent.wrapping_add_micros(self.interval_us).as_micros(),
                None => 0,
            };
            if earliest.is_none_or(|e| at < e) {
                earliest = Some(at);
            }
        }
        earliest.map(Instant::from_micros)
    }
}

// A bit of `FaultLimiter::pending` per code.
const _: () = assert!(FaultCode::ALL.len() <= 32, "one bit per fault code");

/// Slot `index`'s bit in `FaultLimiter::pending`.
fn bit(index: usize) -> u32 {
    u32::try_from(index)
        .ok()
        .and_then(|index| 1u32.checked_shl(index))
        .unwrap_or(0)
}

fn is_due(last_sent: Option<Instant>, interval_us: u64, now: Instant) -> bool {
    match last_sent {
        None => true,
        // A clock that went backwards counts as "not yet": the fault goes out one interval later.
        Some(sent) => now
            .micros_since(sent)
            .is_some_and(|since| since >= interval_us),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn occurrences_within_an_interval_are_counted_in_one_frame() {
        let mut limiter = FaultLimiter::new(100_000);
        let t0 = Instant::from_micros(1_000);
        limiter.raise(FaultCode::BusError, [1, 0, 0, 0, 0]);
        let first = limiter.next_due(t0).unwrap();
        assert_eq!((first.code, first.count), (FaultCode::BusError, 1));
        for _ in 0..300 {
            limiter.raise(FaultCode::BusError, [2, 0, 0, 0, 0]);
        }
        assert_eq!(limiter.next_due(t0.wrapping_add_micros(99_999)), None);
        assert_eq!(limiter.deadline(), Some(t0.wrapping_add_micros(100_000)));
        let second = limiter.next_due(t0.wrapping_add_micros(100_000)).unwrap();
        assert_eq!((second.count, second.detail[0]), (255, 2));
        assert_eq!(limiter.next_due(t0.wrapping_add_micros(500_000)), None);
        assert_eq!(limiter.deadline(), None);
    }

    #[test]
    fn pending_is_known_without_looking_at_every_code() {
        // `has_pending` is what the node's poll reads to skip the faults: it must say whether
        // any code has an occurrence to report, through raises and reports in any order.
        let mut limiter = FaultLimiter::new(100_000);
        assert!(!limiter.has_pending());
        let mut now = Instant::from_micros(0);
        let mut seed = 0x9E37_79B9u32;
        for _ in 0..2_000 {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            let code = FaultCode::ALL[seed as usize % FaultCode::ALL.len()];
            if seed.is_multiple_of(3) {
                limiter.raise(code, [0; 5]);
            } else {
                now = now.wrapping_add_micros(u64::from(seed % 60_000));
                limiter.next_due(now);
            }
            let any = limiter.slots.iter().any(|slot| slot.pending > 0);
            assert_eq!(limiter.has_pending(), any);
        }
    }

    #[test]
    fn codes_are_limited_independently() {
        let mut limiter = FaultLimiter::new(100_000);
        let now = Instant::from_micros(5);
        limiter.raise(FaultCode::BusError, [0; 5]);
        limiter.raise(FaultCode::TableRefused, [0x16, 0, 0, 0, 0]);
        let a = limiter.next_due(now).unwrap();
        let b = limiter.next_due(now).unwrap();
        assert_ne!(a.code, b.code);
        assert_eq!(limiter.next_due(now), None);
    }
}
