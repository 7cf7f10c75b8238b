//! Table transfer over ISO-TP against every fault the protocol names: the node keeps its table
//! unless a new one arrived whole, for it, newer, with the right CRC, and loadable.

use crate::common;

use common::*;
use pab_core::isotp::{TxError, TxEvent};
use pab_core::protocol::{self, FaultCode, Message, NodeState, TransferStatusCode};

const MS: u64 = 1_000;

/// A node running version 1 of a one-connection table.
fn running_v1() -> Harness {
    let table = priority_table(&[TOPIC_A], None);
    Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)))
}

/// Version 2: a different table (topic B wins over A).
fn v2() -> Vec<u8> {
    image(
        &priority_table(&[TOPIC_B, TOPIC_A], None),
        Harness::NODE_ID,
        2,
    )
}

/// The old table still runs: version 1, and A's frames still get through.
fn assert_still_v1(h: &mut Harness) {
    assert_eq!(h.running_version(), Some(1));
    let before = h.deliveries.0.len();
    let t = h.now + 10 * MS;
    h.advance_to(t);
    h.feed(&frame(TOPIC_A, &[1]));
    assert_eq!(h.deliveries.0.len(), before + 1);
    assert!(h.stored.is_empty(), "nothing may be stored");
}

fn last_status(h: &Harness) -> protocol::TransferStatus {
    *h.statuses(protocol::TOOL).last().expect("the node answers")
}

fn refused_with(h: &Harness, status: TransferStatusCode) {
    let answer = last_status(h);
    assert_eq!(answer.status, status);
    assert_eq!(answer.running_version, 1);
    let fault = h
        .messages_since(0)
        .into_iter()
        .rev()
        .find_map(|(_, _, m)| match m {
            Message::Fault(f) if f.code == FaultCode::TableRefused => Some(f),
            _ => None,
        });
    assert_eq!(fault.expect("a fault frame").detail[0], status.code());
}

#[test]
fn a_new_table_is_applied_stored_and_shown_in_the_heartbeat() {
    let mut h = running_v1();
    let bytes = v2();
    let header = pab_core::image::read_header(&bytes).unwrap();
    assert_eq!(h.push(&bytes), TxEvent::Done);
    let answer = last_status(&h);
    assert_eq!(answer.status, TransferStatusCode::Applied);
    assert_eq!(answer.running_version, 2);
    assert_eq!(h.stored, vec![bytes.clone()], "the exact image is stored");
    assert_eq!(h.running_version(), Some(2));
    // The new rules run: B now wins over A.
    h.advance_to(h.now + 10 * MS);
    h.feed(&frame(TOPIC_B, &[2]));
    h.feed(&frame(TOPIC_A, &[1]));
    assert_eq!(h.deliveries.0.last().unwrap().1.raw_id().0, TOPIC_B);
    // The next heartbeat group shows version 2 and the CRC, stored.
    let from = h.now;
    h.advance_to(from + 1_100 * MS);
    let messages = h.messages_since(from);
    assert!(messages.iter().any(|(_, _, m)| matches!(m,
        Message::Heartbeat(hb) if hb.table_version == 2 && hb.state == NodeState::Operational)));
    assert!(messages.iter().any(|(_, _, m)| matches!(m,
        Message::TableStatus(s) if s.crc == header.crc && s.stored)));
}

#[test]
fn flow_control_is_sent_to_the_sender_every_block_of_eight() {
    let mut h = running_v1();
    let bytes = v2();
    assert_eq!(h.push(&bytes), TxEvent::Done);
    let flow_controls: Vec<[u8; 8]> = h
        .messages_since(0)
        .into_iter()
        .filter_map(|(_, id, m)| match m {
            Message::TableTransfer { data, .. } if id.destination == protocol::TOOL => Some(data),
            _ => None,
        })
        .collect();
    // FF carries 6 bytes, then blocks of 8 CFs of 7 bytes: one FC after the FF and one per full
    // block that is not the last.
    let consecutive = (bytes.len() - 6).div_ceil(7);
    assert_eq!(flow_controls.len(), 1 + (consecutive - 1) / 8);
    for fc in flow_controls {
        assert_eq!(fc, [0x30, 8, 0, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]);
    }
}

#[test]
fn pushing_the_running_table_again_changes_nothing() {
    let table = priority_table(&[TOPIC_A], None);
    let bytes = image(&table, Harness::NODE_ID, 1);
    let mut h = Harness::boot(Some(&bytes));
    assert_eq!(h.push(&bytes), TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::AlreadyCurrent);
    assert_still_v1(&mut h);
}

#[test]
fn an_older_version_or_the_same_version_with_other_contents_is_refused() {
    let mut h = running_v1();
    let old = image(&priority_table(&[TOPIC_B], None), Harness::NODE_ID, 0);
    h.push(&old);
    refused_with(&h, TransferStatusCode::OlderVersion);
    let same_version = image(&priority_table(&[TOPIC_B], None), Harness::NODE_ID, 1);
    h.push(&same_version);
    refused_with(&h, TransferStatusCode::OlderVersion);
    assert_still_v1(&mut h);
}

#[test]
fn a_table_of_version_0_is_never_applied() {
    // Heartbeats say "version 0" for "no table": a node without a table refuses version 0 as
    // not newer than what it runs, so that reading never lies.
    let mut h = Harness::boot(None);
    h.push(&image(
        &priority_table(&[TOPIC_A], None),
        Harness::NODE_ID,
        0,
    ));
    assert_eq!(last_status(&h).status, TransferStatusCode::OlderVersion);
    assert_eq!(h.running_version(), None);
    assert_eq!(h.node.state(), NodeState::NoTable);
    h.push(&image(
        &priority_table(&[TOPIC_A], None),
        Harness::NODE_ID,
        1,
    ));
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
}

#[test]
fn a_table_for_another_node_is_refused() {
    let mut h = running_v1();
    let other = image(&priority_table(&[TOPIC_B], None), Harness::NODE_ID + 1, 2);
    h.push(&other);
    refused_with(&h, TransferStatusCode::WrongNode);
    assert_eq!(last_status(&h).detail, Harness::NODE_ID + 1);
    assert_still_v1(&mut h);
}

#[test]
fn a_corrupted_image_is_refused_by_its_crc() {
    let mut h = running_v1();
    let mut bytes = v2();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x01;
    h.push(&bytes);
    refused_with(&h, TransferStatusCode::CrcMismatch);
    assert_still_v1(&mut h);
}

#[test]
fn the_crc_is_checked_before_the_version() {
    // A corrupted image is reported as corrupted, whatever version its header claims.
    let mut h = running_v1();
    let mut old = image(&priority_table(&[TOPIC_B], None), Harness::NODE_ID, 0);
    let last = old.len() - 1;
    old[last] ^= 0x10;
    h.push(&old);
    refused_with(&h, TransferStatusCode::CrcMismatch);
    assert_still_v1(&mut h);
}

#[test]
fn a_frame_corrupted_in_flight_is_refused_by_the_crc() {
    let mut h = running_v1();
    let bytes = v2();
    h.push_with(&bytes, protocol::TOOL, |_, index, mut data| {
        if index == 5 {
            data[3] ^= 0x80;
        }
        Some(data)
    });
    refused_with(&h, TransferStatusCode::CrcMismatch);
    assert_still_v1(&mut h);
}

#[test]
fn something_that_is_not_an_image_is_refused_by_its_header() {
    let mut h = running_v1();
    h.push(&[0x55; 100]);
    refused_with(&h, TransferStatusCode::BadHeader);
    assert_still_v1(&mut h);
}

#[test]
fn a_table_beyond_the_nodes_capacities_is_refused_by_the_loader() {
    let mut h = running_v1();
    // Five ports: valid for the workstation, too many for this 4-port board.
    let mut table: pab_core::Table = pab_core::Table::new();
    let port = priority_table(&[TOPIC_A], None);
    let view = port.port(0).unwrap();
    for _ in 0..5 {
        table
            .push_port(view.connections, view.nodes, view.root)
            .unwrap();
    }
    let bytes = image(&table, Harness::NODE_ID, 2);
    assert_eq!(h.push(&bytes), TxEvent::Done);
    refused_with(&h, TransferStatusCode::InvalidTable);
    assert_eq!(
        last_status(&h).detail,
        4,
        "detail 4: exceeds this node's capacities"
    );
    assert_still_v1(&mut h);
}

#[test]
fn an_image_larger_than_the_buffer_is_refused_at_the_first_frame() {
    let mut h = running_v1();
    let big = vec![0u8; 8193];
    let end = h.push(&big);
    assert_eq!(end, TxEvent::Failed(TxError::Overflow));
    refused_with(&h, TransferStatusCode::TooLarge);
    // The overflow flow control went to the sender.
    assert!(h.messages_since(0).iter().any(|(_, id, m)| matches!(m,
        Message::TableTransfer { data, .. } if id.destination == protocol::TOOL && data[0] == 0x32)));
    assert_still_v1(&mut h);
}

#[test]
fn a_lost_consecutive_frame_cuts_the_transfer() {
    let mut h = running_v1();
    let bytes = v2();
    h.push_with(&bytes, protocol::TOOL, |_, index, data| {
        (index != 4).then_some(data)
    });
    refused_with(&h, TransferStatusCode::Interrupted);
    assert_still_v1(&mut h);
}

#[test]
fn a_sender_that_stops_half_way_times_out_after_n_cr() {
    let mut h = running_v1();
    let bytes = v2();
    // Everything after the fifth frame is lost.
    let end = h.push_with(&bytes, protocol::TOOL, |_, index, data| {
        (index < 5).then_some(data)
    });
    // The sender itself gives up when no flow control comes (N_Bs).
    assert_eq!(end, TxEvent::Failed(TxError::Timeout));
    h.advance_to(h.now + 2_000 * MS);
    // The node answered once, Timeout, 1 s (N_Cr) after the last frame it received.
    let answers: Vec<(u64, protocol::TransferStatus)> = h
        .messages_since(0)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            Message::TransferStatus(s) => Some((t, s)),
            _ => None,
        })
        .collect();
    assert_eq!(answers.len(), 1, "{answers:?}");
    let last_frame_at = 4 * 100; // frames 0..=4, one per 100 µs from t = 0
    assert_eq!(answers[0].0, last_frame_at + 1_000 * MS);
    refused_with(&h, TransferStatusCode::Timeout);
    assert_still_v1(&mut h);
}

#[test]
fn a_table_that_cannot_be_stored_runs_but_the_node_says_so() {
    let mut h = running_v1();
    h.store_ok = false;
    h.push(&v2());
    assert_eq!(last_status(&h).status, TransferStatusCode::AppliedNotStored);
    assert_eq!(h.running_version(), Some(2));
    assert_eq!(h.node.state(), NodeState::Fault);
    let from = h.now;
    h.advance_to(from + 1_100 * MS);
    assert!(h.messages_since(from).iter().any(|(_, _, m)| matches!(m,
        Message::TableStatus(s) if !s.stored)));
    assert!(h.messages_since(0).iter().any(|(_, _, m)| matches!(m,
        Message::Fault(f) if f.code == FaultCode::StoreFailed)));
}

#[test]
fn frames_keep_being_arbitrated_with_the_old_table_during_a_transfer() {
    let mut h = running_v1();
    let v2 = v2();
    // Topic A's frames between the transfer frames: version 1 delivers them until the swap.
    let mut delivered_during = 0;
    let end = h.push_with(&v2, protocol::TOOL, |h, _, data| {
        let before = h.deliveries.0.len();
        h.feed(&frame(TOPIC_A, &[0x11]));
        if h.running_version() == Some(1) {
            delivered_during += h.deliveries.0.len() - before;
        }
        Some(data)
    });
    assert_eq!(end, TxEvent::Done);
    let frames = v2.len().div_ceil(7);
    assert!(
        delivered_during + 1 >= frames,
        "{delivered_during} of about {frames}"
    );
    assert_eq!(h.running_version(), Some(2));
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
}
