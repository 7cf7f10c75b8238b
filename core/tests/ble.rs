//! Broadcast of Local Eligibility: the fixed-capacity state (`pab_core::ble::Eligibility`) against
//! a reference that keeps every claim ever heard (std, unbounded), on random histories; and the
//! frame codec over every identifier bit pattern that matters.

use std::collections::BTreeMap;

use pab_core::Instant;
use pab_core::ble::{Claim, ClaimError, Eligibility};
use pab_core::frame::Frame;
use proptest::prelude::*;

const GROUP: u8 = 2;
const ME: u8 = 4;

/// The whole history, kept: the latest claim per peer and the latest local reading.
#[derive(Default)]
struct Reference {
    peers: BTreeMap<u8, (u16, u64)>,
    own: Option<(u16, u64)>,
}

impl Reference {
    fn fresh(at: u64, now: u64, period: u64) -> bool {
        now - at < 2 * period
    }

    /// Holds: positive offer, fresh own reading, no fresh peer with a higher eligibility or an
    /// equal one from a lower node id.
    fn holds(&self, offered: u16, now: u64, period: u64) -> bool {
        offered > 0
            && self.own.is_some_and(|(_, at)| Self::fresh(at, now, period))
            && self.peers.iter().all(|(&node, &(e, at))| {
                !Self::fresh(at, now, period) || !(e > offered || (e == offered && node < ME))
            })
    }
}

#[derive(Clone, Debug)]
enum Event {
    Local(u16),
    Peer(u8, u16),
}

fn event() -> impl Strategy<Value = (u64, Event)> {
    let peer = (1u8..=8).prop_filter("not me", |&n| n != ME);
    (
        0u64..150_000,
        prop_oneof![
            (0u16..4).prop_map(|e| Event::Local(e * 30)),
            (peer, 0u16..4).prop_map(|(n, e)| Event::Peer(n, e * 30)),
        ],
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2_000, failure_persistence: None, ..ProptestConfig::default() })]

    /// With room for every peer (7 here), the bounded state decides exactly as the reference,
    /// after every event and for every offer.
    #[test]
    fn holds_as_the_reference_when_every_peer_fits(
        period in 1_000u64..200_000,
        events in prop::collection::vec(event(), 1..60),
    ) {
        let mut state = Eligibility::<7>::new(GROUP, ME, period).unwrap();
        let mut reference = Reference::default();
        let mut now = 0u64;
        for (gap, event) in events {
            now += gap;
            let at = Instant::from_micros(now);
            match event {
                Event::Local(e) => {
                    state.on_local(e, at);
                    reference.own = Some((e, now));
                }
                Event::Peer(node, e) => {
                    let claim = Claim { group: GROUP, node, eligibility: e };
                    prop_assert_eq!(state.on_peer(claim, at), Ok(()));
                    reference.peers.insert(node, (e, now));
                }
            }
            for offered in [0, 30, 60, 90] {
                for later in [0, period / 2, 2 * period - 1, 2 * period] {
                    let then = Instant::from_micros(now + later);
                    prop_assert_eq!(
                        state.holds(offered, then),
                        reference.holds(offered, now + later, period),
                        "offer {} at +{} µs", offered, later
                    );
                }
            }
        }
    }

    /// With room for fewer peers than broadcast (2 here; a table sizes the group for all its
    /// nodes, so only a rogue sender can overflow it), the state keeps a subset of the latest
    /// claims: it never gives up a task the reference holds, and it holds one the reference does
    /// not only within two periods of a moment when more peers were fresh than it has room for.
    #[test]
    fn a_full_group_errs_only_towards_holding_and_only_under_pressure(
        period in 1_000u64..200_000,
        events in prop::collection::vec(event(), 1..60),
    ) {
        let mut state = Eligibility::<2>::new(GROUP, ME, period).unwrap();
        let mut reference = Reference::default();
        let mut pressure: Option<u64> = None;
        let mut now = 0u64;
        for (gap, event) in events {
            now += gap;
            let at = Instant::from_micros(now);
            match event {
                Event::Local(e) => {
                    state.on_local(e, at);
                    reference.own = Some((e, now));
                }
                Event::Peer(node, e) => {
                    let claim = Claim { group: GROUP, node, eligibility: e };
                    let _ = state.on_peer(claim, at);
                    reference.peers.insert(node, (e, now));
                    let fresh = reference
                        .peers
                        .values()
                        .filter(|(_, heard)| Reference::fresh(*heard, now, period))
                        .count();
                    if fresh > 2 {
                        pressure = Some(now);
                    }
                }
            }
            for offered in [0, 30, 60, 90] {
                let (bounded, full) = (state.holds(offered, at), reference.holds(offered, now, period));
                prop_assert!(bounded || !full, "gave up a task the reference holds");
                if bounded && !full {
                    prop_assert!(
                        pressure.is_some_and(|p| now - p < 2 * period),
                        "held without pressure in the last two periods"
                    );
                }
            }
        }
    }

    /// Whatever frame arrives, decoding returns a claim or a reason, and every claim decoded
    /// encodes back to the same frame.
    #[test]
    fn any_frame_decodes_to_a_claim_or_a_reason(
        raw in 0u32..(1 << 29),
        extended in any::<bool>(),
        data in prop::collection::vec(any::<u8>(), 0..=8),
    ) {
        let raw = if extended { raw } else { raw & 0x7FF };
        let frame = Frame::with_raw_id(raw, extended, &data).unwrap();
        match Claim::decode(&frame) {
            Ok(claim) => {
                prop_assert_eq!(claim.frame(), Some(frame));
            }
            Err(ClaimError::NotAClaim) => {
                prop_assert!(!extended || !pab_core::ble::is_claim_id(raw));
            }
            Err(_) => prop_assert!(extended && pab_core::ble::is_claim_id(raw)),
        }
    }
}

/// The property above cannot reach most claim identifiers at random: every eligibility's
/// identifier decodes back, for every node id.
#[test]
fn every_eligibility_and_node_round_trips() {
    for node in 1..=127u8 {
        for eligibility in (0..=u16::MAX).step_by(257).chain([1, u16::MAX - 1]) {
            let claim = Claim {
                group: 9,
                node,
                eligibility,
            };
            let frame = claim.frame().unwrap();
            assert_eq!(Claim::decode(&frame), Ok(claim));
        }
    }
}
