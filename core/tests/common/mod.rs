//! What every test that drives an `Arbiter` checks on every frame.

use pab_core::{Arbiter, Id, Instant, PortVerdict, Reception};

/// Receives a frame and returns the reception with the verdicts, after checking that every
/// verdict agrees with the read-only accessors at the same instant.
pub fn receive(arbiter: &mut Arbiter, id: Id, now: Instant) -> (Reception, Vec<PortVerdict>) {
    let mut verdicts = Vec::new();
    let reception = arbiter.receive(&id, now, |verdict| verdicts.push(*verdict));
    let mut fed = 0u16;
    let mut delivered = 0u16;
    for (k, verdict) in verdicts.iter().enumerate() {
        if k > 0 {
            assert!(
                verdict.port > verdicts[k - 1].port,
                "verdicts in port order"
            );
        }
        fed |= 1 << verdict.port;
        assert_eq!(verdict.selected, arbiter.selected(verdict.port, now));
        assert_eq!(verdict.active, arbiter.activity(verdict.port, now));
        // Only an active connection is selected, and the frame is delivered iff it fed it.
        assert!(
            verdict
                .selected
                .is_none_or(|index| verdict.active.contains(index))
        );
        assert_eq!(
            verdict.delivered,
            verdict
                .selected
                .filter(|&index| verdict.fed.contains(index))
        );
        if verdict.delivered.is_some() {
            delivered |= 1 << verdict.port;
        }
    }
    assert_eq!(reception.fed.bits(), fed);
    assert_eq!(reception.delivered.bits(), delivered);
    (reception, verdicts)
}
