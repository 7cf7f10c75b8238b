//! HBBA's filter commands at a node. On a table without message filters a FilterProfile or
//! FilterSet addressed to the node is refused aloud (FilterRefused, detail 3, with what was asked
//! and its sequence number); on one with filters it is applied and answered with FilterStatus
//! (or refused with detail 1 or 2, nothing changed); the heartbeat group carries FilterStatus;
//! Exploitation frames mark each connection that starts or stops delivering. One for another
//! node or for all is not this node's business.

use crate::common;

use common::*;
use pab_core::Frame;
use pab_core::hbba::filters::MessageFilters;
use pab_core::protocol::{
    BROADCAST, Exploitation, FaultCode, FilterProfile, FilterSet, FilterStatus, INTENTION, Message,
};

fn refusals(h: &Harness, since: u64) -> Vec<[u8; 5]> {
    h.messages_since(since)
        .into_iter()
        .filter_map(|(_, _, message)| match message {
            Message::Fault(fault) if fault.code == FaultCode::FilterRefused => Some(fault.detail),
            _ => None,
        })
        .collect()
}

fn booted() -> Harness {
    Harness::boot(Some(&image(
        &priority_table(&[TOPIC_A], None),
        Harness::NODE_ID,
        1,
    )))
}

#[test]
fn a_filter_command_for_this_node_is_refused_with_what_it_asked() {
    let mut h = booted();
    let since = h.now;
    let set = Message::FilterSet(FilterSet {
        port: 0,
        connection: 1,
        phi: 3,
        sequence: 0x0203,
    });
    h.feed(&set.to_frame(INTENTION, Harness::NODE_ID));
    h.advance_to(h.now + 150_000);
    assert_eq!(refusals(&h, since), [[3, 0, 1, 0x03, 0x02]]);

    let since = h.now;
    let profile = Message::FilterProfile(FilterProfile {
        profile: 4,
        sequence: 9,
    });
    h.feed(&profile.to_frame(INTENTION, Harness::NODE_ID));
    h.advance_to(h.now + 150_000);
    assert_eq!(refusals(&h, since), [[3, 4, 0, 9, 0]]);
    assert_eq!(h.node.counters().errors, 0);
}

#[test]
fn a_filter_command_for_another_node_or_for_all_is_not_answered() {
    let mut h = booted();
    let since = h.now;
    let set = Message::FilterSet(FilterSet {
        port: 0,
        connection: 0,
        phi: 0,
        sequence: 1,
    });
    let frames: [Frame; 2] = [
        set.to_frame(INTENTION, Harness::NODE_ID + 1),
        set.to_frame(INTENTION, BROADCAST),
    ];
    for frame in &frames {
        h.feed(frame);
    }
    h.advance_to(h.now + 150_000);
    assert!(refusals(&h, since).is_empty());
}

/// Two connections (TOPIC_A wins over TOPIC_B), TOPIC_B's filtered; profile 1 opens it, profile 2
/// passes one frame in 3.
fn filtered() -> Harness {
    Harness::boot(Some(&filtered_image()))
}

/// [`filtered`]'s image.
pub(crate) fn filtered_image() -> Vec<u8> {
    let mut table = priority_table(&[TOPIC_A, TOPIC_B], None);
    let mut filters = MessageFilters::default();
    filters.connections.push(1).unwrap();
    filters.push_profile(&[1]).unwrap();
    filters.push_profile(&[3]).unwrap();
    table.set_filters(filters).unwrap();
    image(&table, Harness::NODE_ID, 1)
}

pub(crate) fn statuses(h: &Harness, since: u64) -> Vec<FilterStatus> {
    h.messages_since(since)
        .into_iter()
        .filter_map(|(_, _, message)| match message {
            Message::FilterStatus(status) => Some(status),
            _ => None,
        })
        .collect()
}

fn edges(h: &Harness, since: u64) -> Vec<(u64, Exploitation)> {
    h.messages_since(since)
        .into_iter()
        .filter_map(|(at, _, message)| match message {
            Message::Exploitation(edge) => Some((at, edge)),
            _ => None,
        })
        .collect()
}

fn command(h: &mut Harness, message: Message) {
    h.feed(&message.to_frame(INTENTION, Harness::NODE_ID));
}

fn delivered_b(h: &Harness) -> usize {
    h.deliveries
        .0
        .iter()
        .filter(|(_, f, _)| f.raw_id().0 == TOPIC_B)
        .count()
}

#[test]
fn a_filtered_connection_starts_closed_and_opens_with_a_profile() {
    let mut h = filtered();
    // The heartbeat group at boot reported the filters: one, closed, profile 0.
    let boot = statuses(&h, 0);
    assert_eq!(
        boot,
        [FilterStatus {
            profile: 0,
            sequence: 0,
            filtered: 1,
            closed: 1,
            throttled: 0
        }]
    );
    h.advance_to(10_000);
    h.feed(&frame(TOPIC_B, &[1]));
    assert_eq!(delivered_b(&h), 0);
    let since = h.now;
    command(
        &mut h,
        Message::FilterProfile(FilterProfile {
            profile: 1,
            sequence: 7,
        }),
    );
    assert_eq!(
        statuses(&h, since),
        [FilterStatus {
            profile: 1,
            sequence: 7,
            filtered: 1,
            closed: 0,
            throttled: 0
        }]
    );
    h.advance_to(20_000);
    h.feed(&frame(TOPIC_B, &[2]));
    assert_eq!(delivered_b(&h), 1);
    // One in three, from the first after the change.
    command(
        &mut h,
        Message::FilterProfile(FilterProfile {
            profile: 2,
            sequence: 8,
        }),
    );
    for k in 0..6 {
        h.advance_to(30_000 + k * 10_000);
        h.feed(&frame(TOPIC_B, &[3]));
    }
    assert_eq!(delivered_b(&h), 3);
    // A single filter: the status says "one by one".
    let since = h.now;
    command(
        &mut h,
        Message::FilterSet(FilterSet {
            port: 0,
            connection: 1,
            phi: 0,
            sequence: 9,
        }),
    );
    assert_eq!(
        statuses(&h, since),
        [FilterStatus {
            profile: FilterStatus::SET_ONE_BY_ONE,
            sequence: 9,
            filtered: 1,
            closed: 1,
            throttled: 0
        }]
    );
    h.advance_to(200_000);
    h.feed(&frame(TOPIC_B, &[4]));
    assert_eq!(delivered_b(&h), 3);
    // The next heartbeat group repeats the status.
    let since = h.now;
    h.advance_to(1_100_000);
    assert_eq!(statuses(&h, since).len(), 1);
    assert_eq!(statuses(&h, since)[0].sequence, 9);
}

#[test]
fn commands_it_cannot_apply_are_refused_and_change_nothing() {
    let mut h = filtered();
    // Past the boot's heartbeat group and its FilterStatus.
    h.advance_to(1_000);
    let since = h.now;
    command(
        &mut h,
        Message::FilterProfile(FilterProfile {
            profile: 3,
            sequence: 0x0102,
        }),
    );
    command(
        &mut h,
        Message::FilterSet(FilterSet {
            port: 0,
            connection: 0,
            phi: 1,
            sequence: 5,
        }),
    );
    h.advance_to(h.now + 150_000);
    // Rate-limited per code: the first refusal goes out at once, the second with the next
    // fault frame; both are counted.
    let refused = refusals(&h, since);
    assert_eq!(refused.first(), Some(&[1, 3, 0, 0x02, 0x01]));
    assert!(statuses(&h, since).is_empty());
    assert_eq!(h.node.arbiter().unwrap().filter_phi(0, 1), Some(0));
    assert_eq!(h.node.arbiter().unwrap().filter_profile(), Some(0));
}

#[test]
fn exploitation_edges_mark_each_start_and_stop() {
    let mut h = filtered();
    command(
        &mut h,
        Message::FilterProfile(FilterProfile {
            profile: 1,
            sequence: 1,
        }),
    );
    let since = h.now;
    h.advance_to(10_000);
    h.feed(&frame(TOPIC_B, &[1]));
    // TOPIC_A wins while active.
    h.advance_to(20_000);
    h.feed(&frame(TOPIC_A, &[1]));
    // Both lapse after τ = 0.5 s without frames: A at 0.52 s, then B (last at 0.01 s) is
    // already gone, so the port delivers nobody.
    h.advance_to(900_000);
    let got: Vec<(u64, u8, bool)> = edges(&h, since)
        .into_iter()
        .map(|(at, e)| (at, e.connection, e.delivering))
        .collect();
    assert_eq!(
        got,
        [
            (10_000, 1, true),
            (20_000, 1, false),
            (20_000, 0, true),
            (520_001, 0, false)
        ]
    );
}

#[test]
fn a_node_without_filters_sends_no_filter_status_or_edges() {
    let mut h = booted();
    h.advance_to(10_000);
    h.feed(&frame(TOPIC_A, &[1]));
    h.advance_to(2_100_000);
    assert!(statuses(&h, 0).is_empty());
    assert!(edges(&h, 0).is_empty());
}
