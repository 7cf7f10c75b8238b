//! What Broadcast of Local Eligibility costs a board (issue 12), per claim frame heard and per
//! claim sent: the comparator of `pab_core::ble` with the room a group of 3 robots (2 peers)
//! and one of 8 robots (7 peers) keeps, each full of fresh claims (the longest scans).

use core::hint::black_box;

use pab_core::Instant;
use pab_core::ble::{Claim, Eligibility};

use crate::{measure, report};

/// Measured repetitions of each case.
const TIMES: usize = 4;
const PERIOD_US: u64 = 100_000;

fn group<const PEERS: usize>(robots: u8) -> Eligibility<PEERS> {
    let Ok(mut state) = Eligibility::<PEERS>::new(0, 1, PERIOD_US) else {
        crate::fail(format_args!("BLE group refused"));
    };
    state.on_local(500, Instant::from_micros(0));
    for node in 2..=robots {
        let claim = Claim {
            group: 0,
            node,
            eligibility: 100 * u16::from(node),
        };
        let _ = state.on_peer(claim, Instant::from_micros(0));
    }
    state
}

/// One peer's claim heard (decode, keep) and the holding decision after it.
fn heard<const PEERS: usize>(state: &mut Eligibility<PEERS>, name: &'static str) {
    for round in 0..TIMES {
        let claim = Claim {
            group: 0,
            node: 2,
            eligibility: 300 + round as u16,
        };
        let Some(frame) = claim.frame() else {
            crate::fail(format_args!("claim frame"));
        };
        let frame = black_box(frame);
        let now = black_box(Instant::from_micros(1_000 + round as u64));
        black_box(measure(|| {
            let holds = match Claim::decode(&frame) {
                Ok(claim) => state.on_peer(claim, now).is_ok(),
                Err(_) => false,
            };
            holds && state.holds(500, now)
        }));
        report("ble", name);
    }
}

pub fn run() {
    heard(&mut group::<2>(3), "heard-3-robots");
    heard(&mut group::<7>(8), "heard-8-robots");
    let mut state = group::<2>(3);
    for round in 0..TIMES {
        let now = black_box(Instant::from_micros(round as u64 * PERIOD_US));
        black_box(measure(|| {
            state.broadcast(500, now).and_then(|c| c.frame())
        }));
        report("ble", "broadcast");
    }
}
