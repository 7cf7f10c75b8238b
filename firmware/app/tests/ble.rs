//! BLE on a node: it broadcasts its claims every period through its outbox, keeps its peers'
//! claims from the bus, gates its connection by the task it holds, and refuses claims it cannot
//! keep with a fault. The peer is played by the test, frame by frame, in virtual time.

use crate::common;

use common::{Harness, frame, image};
use pab_core::ble::{CLAIM_SLOT_FILTER, Claim, EligibilityField, Group, GroupPort};
use pab_core::protocol::{FaultCode, Message};
use pab_core::{Connection, DecisionNode, Filter, Frame, Gain, NodeRef, Stimulation, Table};

const MS: u64 = 1_000;
pub(crate) const OBS: u32 = 0x180;
pub(crate) const ELIGIBILITY: u32 = 0x195;

/// Port 0: OBS (σ = 1, τ = 0.5 s) delivers iff OBS & the task of group 0 (period 100 ms,
/// eligibility in bytes 0-1 of 0x195).
pub(crate) fn image_with_group() -> Vec<u8> {
    let obs = Connection {
        filter: Filter::exact(OBS, false).unwrap(),
        stimulation: Stimulation::new(Gain::ONE, 500_000, 0).unwrap(),
    };
    let claim = Connection {
        filter: CLAIM_SLOT_FILTER,
        stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).unwrap(),
    };
    let nodes = [
        DecisionNode {
            var: 0,
            low: NodeRef::NOBODY,
            high: NodeRef::node(1).unwrap(),
        },
        DecisionNode {
            var: 1,
            low: NodeRef::NOBODY,
            high: NodeRef::deliver(0).unwrap(),
        },
    ];
    let mut table: Table = Table::new();
    table
        .push_port(&[obs, claim], &nodes, NodeRef::node(0).unwrap())
        .unwrap();
    table
        .push_group(Group {
            number: 0,
            node: Harness::NODE_ID,
            period_us: 100_000,
            local: Filter::exact(ELIGIBILITY, false).unwrap(),
            field: EligibilityField {
                offset: 0,
                size: 2,
                big_endian: false,
            },
            peers: 2,
            ports: [GroupPort {
                port: 0,
                claim: 1,
                gated: 0b01,
            }]
            .into_iter()
            .collect(),
        })
        .unwrap();
    image(&table, Harness::NODE_ID, 1)
}

fn claims_sent(h: &Harness, from: u64) -> Vec<(u64, u16)> {
    h.sent
        .iter()
        .filter(|(t, _)| *t >= from)
        .filter_map(|(t, f)| Claim::decode(f).ok().map(|c| (*t, c.eligibility)))
        .collect()
}

pub(crate) fn delivered_at(h: &Harness, t: u64) -> bool {
    h.deliveries
        .0
        .iter()
        .any(|(port, _, at)| *port == 0 && *at == t)
}

/// The robot sees its target: its observer's frame, then its eligibility.
pub(crate) fn sees(h: &mut Harness, t: u64, eligibility: u16) {
    h.advance_to(t);
    h.feed(&frame(OBS, &[1; 8]));
    h.feed(&frame(ELIGIBILITY, &eligibility.to_le_bytes()));
}

pub(crate) fn peer(node: u8, eligibility: u16) -> Frame {
    Claim {
        group: 0,
        node,
        eligibility,
    }
    .frame()
    .unwrap()
}

#[test]
fn a_node_claims_every_period_yields_to_a_better_peer_and_takes_over_when_it_falls_silent() {
    let stored = image_with_group();
    let mut h = Harness::boot(Some(&stored));
    // Every 50 ms the robot sees its target with eligibility 50.
    sees(&mut h, 0, 50);
    sees(&mut h, 50 * MS, 50);
    assert!(delivered_at(&h, 50 * MS), "alone, it holds the task");
    // A better peer (node 2, 80) is heard at 60 ms: from then on, nothing is delivered.
    h.advance_to(60 * MS);
    h.feed(&peer(2, 80));
    for k in 2..=5 {
        sees(&mut h, k * 50 * MS, 50);
        assert!(!delivered_at(&h, k * 50 * MS), "at {} ms", k * 50);
    }
    // The peer falls silent: its claim (60 ms) is stale from 260 ms.
    sees(&mut h, 300 * MS, 50);
    assert!(delivered_at(&h, 300 * MS));
    // Claims went out once per period on the grid of the first, which left at boot, before
    // any reading (offering 0), then offering 50 (its target in view, its reading fresh).
    let sent: Vec<(u64, u16)> = claims_sent(&h, 0)
        .into_iter()
        .map(|(t, e)| (t / MS, e))
        .collect();
    assert_eq!(sent, [(0, 0), (100, 50), (200, 50), (300, 50)]);
}

#[test]
fn a_node_whose_connection_is_inactive_offers_zero() {
    let stored = image_with_group();
    let mut h = Harness::boot(Some(&stored));
    h.advance_to(10 * MS);
    h.feed(&frame(ELIGIBILITY, &900u16.to_le_bytes()));
    h.advance_to(150 * MS);
    assert_eq!(claims_sent(&h, 0).last().map(|&(_, e)| e), Some(0));
}

#[test]
fn claims_the_node_cannot_keep_are_refused_with_a_fault() {
    let stored = image_with_group();
    let mut h = Harness::boot(Some(&stored));
    sees(&mut h, 0, 50);
    // Its own id from another sender, then a claim whose payload disagrees with its id.
    h.feed(&peer(Harness::NODE_ID, 10));
    h.advance_to(200 * MS);
    let mut forged = peer(3, 10).payload().to_vec();
    forged[1] ^= 1;
    h.feed(&Frame::with_raw_id(peer(3, 10).raw_id().0, true, &forged).unwrap());
    h.advance_to(400 * MS);
    let refusals: Vec<[u8; 5]> = h
        .messages_since(0)
        .into_iter()
        .filter_map(|(_, _, m)| match m {
            Message::Fault(f) if f.code == FaultCode::ClaimRefused => Some(f.detail),
            _ => None,
        })
        .collect();
    assert_eq!(refusals, [[2, Harness::NODE_ID, 0, 0, 0], [1, 0, 0, 0, 0]]);
    // Neither counted as a peer: with a fresh reading again (its last was at 0), it holds.
    sees(&mut h, 420 * MS, 50);
    sees(&mut h, 430 * MS, 50);
    assert!(delivered_at(&h, 430 * MS));
}
