//! BLE groups in the arbiter: a claim is a rule variable (`OBS & task`) whose activity is
//! "this node holds the task". Nodes simulated by arbiters that pass each other their claims in
//! bus order, in exact virtual time: the better claim holds, a silent node frees the task after
//! two periods, equal eligibilities go to the lower node id, and a node whose gated connection
//! could not deliver offers 0.

use crate::common;

use common::{at, deliver, node};
use pab_core::ble::{CLAIM_SLOT_FILTER, Claim, EligibilityField, Group, GroupPort};
use pab_core::table::TableError;
use pab_core::{Arbiter, Connection, Filter, Frame, Gain, Instant, NodeRef, Stimulation, Table};

const MS: u64 = 1_000;
const PERIOD_US: u32 = 100_000;
const OBS_ID: u32 = 0x180;

fn t(ms: u64) -> Instant {
    Instant::from_micros(ms * MS)
}

/// Node `id`'s arbiter: port 0 has OBS (σ = 1, τ = 0.5 s) and the claim of group 0; OBS delivers
/// iff OBS & claim. Its eligibility topic is 0x190 + id, bytes 0-1.
fn robot(id: u8) -> Arbiter {
    let obs = Connection {
        filter: Filter::exact(OBS_ID, false).unwrap(),
        stimulation: Stimulation::new(Gain::ONE, 500_000, 0).unwrap(),
    };
    let claim = Connection {
        filter: CLAIM_SLOT_FILTER,
        stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).unwrap(),
    };
    let nodes = [
        node(0, NodeRef::NOBODY, at(1)),
        node(1, NodeRef::NOBODY, deliver(0)),
    ];
    let mut table: Table = Table::new();
    table.push_port(&[obs, claim], &nodes, at(0)).unwrap();
    table.push_group(group(id)).unwrap();
    Arbiter::new(table).unwrap()
}

fn group(id: u8) -> Group {
    Group {
        number: 0,
        node: id,
        period_us: PERIOD_US,
        local: Filter::exact(0x190 + u32::from(id), false).unwrap(),
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
    }
}

/// Robot `id` reads its own eligibility `value` and sees its target (an OBS frame), at `now`.
fn sees(arbiter: &mut Arbiter, id: u8, value: u16, now: Instant) {
    let obs = Frame::with_raw_id(OBS_ID, false, &[0; 8]).unwrap();
    let _ = arbiter.receive(&obs.id(), now, |_| {});
    arbiter.ble_frame(&obs, now);
    let local = Frame::with_raw_id(0x190 + u32::from(id), false, &value.to_le_bytes()).unwrap();
    let _ = arbiter.receive(&local.id(), now, |_| {});
    arbiter.ble_frame(&local, now);
}

/// Whether OBS would be delivered at `now`.
fn drives(arbiter: &Arbiter, now: Instant) -> bool {
    arbiter.selected(0, now) == Some(0)
}

/// Every robot's due claims at `now`, delivered to every other robot in bus order (lowest
/// identifier first), each through its frame and back, as on the bus.
fn exchange(robots: &mut [(u8, &mut Arbiter)], now: Instant) {
    let mut claims = Vec::new();
    for (_, arbiter) in robots.iter_mut() {
        arbiter.ble_poll(now, |claim| claims.push(claim));
    }
    claims.sort_by_key(|claim| claim.raw_id());
    for claim in claims {
        let frame = claim.frame().unwrap();
        for (id, arbiter) in robots.iter_mut() {
            if *id != claim.node {
                arbiter
                    .on_claim(Claim::decode(&frame).unwrap(), now)
                    .unwrap();
            }
        }
    }
}

#[test]
fn the_more_eligible_robot_holds_and_a_silent_one_frees_the_task_within_two_periods() {
    let (mut r1, mut r2) = (robot(1), robot(2));
    sees(&mut r1, 1, 50, t(0));
    sees(&mut r2, 2, 80, t(0));
    // Before any claim is heard both hold: the transient the issue allows (< two periods).
    assert!(r1.holds(0) && r2.holds(0));
    exchange(&mut [(1, &mut r1), (2, &mut r2)], t(0));
    assert!(!r1.holds(0) && r2.holds(0));
    assert!(!drives(&r1, t(0)) && drives(&r2, t(0)));
    // Robot 2 stops at 150 ms (its last claim at 100 ms); robot 1 goes on seeing its target.
    let mut now = 0;
    let mut taken = None;
    while now < 600 {
        now += 10;
        sees(&mut r1, 1, 50, t(now));
        if now <= 150 {
            sees(&mut r2, 2, 80, t(now));
            exchange(&mut [(1, &mut r1), (2, &mut r2)], t(now));
        } else {
            exchange(&mut [(1, &mut r1)], t(now));
        }
        if taken.is_none() && drives(&r1, t(now)) {
            taken = Some(now);
        }
    }
    // Robot 2's last claim went out at 100 ms: stale from 300 ms, when robot 1 takes over.
    assert_eq!(taken, Some(300));
}

#[test]
fn equal_eligibilities_go_to_the_lower_node_id_in_both_bus_orders() {
    for first in [1u8, 2] {
        let (mut r1, mut r2) = (robot(1), robot(2));
        sees(&mut r1, 1, 70, t(0));
        sees(&mut r2, 2, 70, t(0));
        let mut claims = Vec::new();
        r1.ble_poll(t(0), |c| claims.push(c));
        r2.ble_poll(t(0), |c| claims.push(c));
        if first == 2 {
            claims.reverse();
        }
        for claim in claims {
            let target = if claim.node == 1 { &mut r2 } else { &mut r1 };
            target.on_claim(claim, t(0)).unwrap();
        }
        assert!(
            r1.holds(0) && !r2.holds(0),
            "claims heard robot {first}'s first"
        );
    }
}

#[test]
fn a_robot_whose_gated_connection_could_not_deliver_offers_zero() {
    let (mut r1, mut r2) = (robot(1), robot(2));
    sees(&mut r1, 1, 50, t(0));
    // Robot 2 reads a high eligibility but its OBS is not active (no target frame): it offers 0.
    let local = Frame::with_raw_id(0x192, false, &900u16.to_le_bytes()).unwrap();
    r2.ble_frame(&local, t(0));
    let mut offered = Vec::new();
    r2.ble_poll(t(0), |c| offered.push(c.eligibility));
    assert_eq!(offered, [0]);
    exchange(&mut [(1, &mut r1), (2, &mut r2)], t(1));
    assert!(r1.holds(0) && !r2.holds(0));
}

#[test]
fn claims_are_due_once_per_period_and_stale_readings_offer_zero() {
    let mut r1 = robot(1);
    sees(&mut r1, 1, 50, t(0));
    let mut sent = Vec::new();
    for ms in 0..=450 {
        r1.ble_poll(t(ms), |c| sent.push((ms, c.eligibility)));
    }
    // Its reading (at 0) is fresh until 200 ms exclusive.
    assert_eq!(sent, [(0, 50), (100, 50), (200, 0), (300, 0), (400, 0)]);
    assert_eq!(r1.ble_deadline(t(401)), Some(t(500)));
    assert!(!r1.holds(0));
}

#[test]
fn a_table_refuses_a_claim_connection_that_frames_could_feed() {
    let obs = Connection {
        filter: Filter::exact(OBS_ID, false).unwrap(),
        stimulation: Stimulation::new(Gain::ONE, 500_000, 0).unwrap(),
    };
    let mut table: Table = Table::new();
    table.push_port(&[obs, obs], &[], NodeRef::NOBODY).unwrap();
    assert_eq!(
        table.push_group(group(1)),
        Err(TableError::ClaimFilter {
            port: 0,
            connection: 1
        })
    );
    let mut twice = group(1);
    twice.ports.push(twice.ports[0]).unwrap();
    let claim = Connection {
        filter: CLAIM_SLOT_FILTER,
        ..obs
    };
    let mut table: Table = Table::new();
    table
        .push_port(&[obs, claim], &[], NodeRef::NOBODY)
        .unwrap();
    assert!(matches!(
        table.push_group(twice),
        Err(TableError::Group { .. })
    ));
    let too_many = Group {
        peers: 8,
        ..group(1)
    };
    assert!(matches!(
        table.push_group(too_many),
        Err(TableError::Group { .. })
    ));
}
