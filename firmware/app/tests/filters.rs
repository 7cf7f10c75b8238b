//! HBBA's filter commands before the boards run message filters: a FilterProfile or FilterSet
//! addressed to a node is refused aloud (FilterRefused, detail 3: the table has no filters,
//! with what was asked and its sequence number), one for another node or for all is not this
//! node's business, and nothing else changes.

mod common;

use common::*;
use pab_core::Frame;
use pab_core::protocol::{BROADCAST, FaultCode, FilterProfile, FilterSet, INTENTION, Message};

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
