//! Table transfers in CAN FD frames (ISO 15765-2:2016) on a node built with the feature `fd`: a
//! table pushed in CAN FD frames of any TX_DL is applied as a classic push is, the node answers
//! its flow control in CAN FD frames (with the push's bit-rate switch), classic pushes go on as
//! before, a transfer that mixes the two kinds is refused cleanly with the old table running,
//! and on a node with a key a CAN FD first frame needs its TransferOpen as a classic one does.

use crate::common;

use common::*;
use pab_core::Frame;
use pab_core::auth::Key;
use pab_core::isotp::TxEvent;
use pab_core::isotp::fd::TxDl;
use pab_core::protocol::{self, AuthFailure, Message, TransferStatusCode};

const MS: u64 = 1_000;
const KEY: Key = Key::from_bytes([0x5A; 16]);

/// A node running version 1 of a one-connection table.
fn running_v1() -> Harness {
    let table = priority_table(&[TOPIC_A], None);
    Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)))
}

/// Version 2 with 30 connections: long enough for blocks of CAN FD frames.
fn v2() -> Vec<u8> {
    let ids: Vec<u32> = (0..30).map(|k| 0x120 + k).collect();
    image(&priority_table(&ids, None), Harness::NODE_ID, 2)
}

fn last_status(h: &Harness) -> protocol::TransferStatus {
    *h.statuses(protocol::TOOL).last().expect("the node answers")
}

/// The old table still runs and answers A's frames.
fn assert_still_v1(h: &mut Harness) {
    assert_eq!(h.running_version(), Some(1));
    let before = h.deliveries.0.len();
    h.advance_to(h.now + 10 * MS);
    h.feed(&frame(TOPIC_A, &[1]));
    assert_eq!(h.deliveries.0.len(), before + 1);
    assert!(h.stored.is_empty(), "nothing may be stored");
}

/// `frame` as a classic frame of the same identifier and first 8 bytes.
fn classic(frame: &Frame) -> Frame {
    Frame::data(frame.id(), &frame.payload()[..8]).unwrap()
}

#[test]
fn a_table_pushed_in_can_fd_frames_is_applied_and_answered_in_can_fd() {
    for tx in [8, 12, 16, 20, 24, 32, 48, 64] {
        let mut h = running_v1();
        let bytes = v2();
        let tx_dl = TxDl::new(tx).unwrap();
        let mut frames = 0;
        let (end, flow_controls) = h.push_fd_with(&bytes, protocol::TOOL, tx_dl, |_, _, f| {
            frames += 1;
            Some(f)
        });
        assert_eq!(end, TxEvent::Done, "TX_DL {tx}");
        let answer = last_status(&h);
        assert_eq!(answer.status, TransferStatusCode::Applied, "TX_DL {tx}");
        assert_eq!(h.running_version(), Some(2));
        assert_eq!(h.stored, vec![bytes.clone()], "the exact image is stored");
        // The frames the push took: the First Frame, then full Consecutive Frames.
        let consecutive = (bytes.len() - (tx - 2)).div_ceil(tx - 1);
        assert_eq!(frames, 1 + consecutive, "TX_DL {tx}");
        // A flow control after the First Frame and each block of 8 but the last, every one a
        // CAN FD frame with the push's bit-rate switch, 8 bytes.
        assert_eq!(flow_controls.len(), 1 + (consecutive - 1) / 8, "TX_DL {tx}");
        for fc in &flow_controls {
            assert!(fc.is_fd() && fc.is_brs(), "{fc:?}");
            assert_eq!(fc.payload(), [0x30, 8, 0, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]);
        }
    }
}

#[test]
fn a_classic_push_is_still_answered_in_classic_frames() {
    let mut h = running_v1();
    let bytes = v2();
    assert_eq!(h.push(&bytes), TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
    let flow_controls: Vec<Frame> = h
        .sent
        .iter()
        .map(|(_, f)| *f)
        .filter(|f| matches!(Message::decode(f), Ok((id, Message::TableTransfer { .. })) if id.destination == protocol::TOOL))
        .collect();
    assert!(!flow_controls.is_empty());
    assert!(flow_controls.iter().all(|f| !f.is_fd()));
}

#[test]
fn an_fd_push_with_classic_consecutive_frames_is_refused_cleanly() {
    let mut h = running_v1();
    let bytes = v2();
    // The third frame goes as a classic frame: ignored by the CAN FD reception, so the fourth
    // is out of sequence and ends it.
    h.push_fd_with(&bytes, protocol::TOOL, TxDl::MAX, |_, index, f| {
        Some(if index == 2 { classic(&f) } else { f })
    });
    assert_eq!(
        last_status(&h).status,
        TransferStatusCode::Interrupted,
        "{:?}",
        h.statuses(protocol::TOOL)
    );
    assert_still_v1(&mut h);
}

#[test]
fn a_classic_push_with_fd_consecutive_frames_is_refused_cleanly() {
    let mut h = running_v1();
    let bytes = v2();
    let mut first = None;
    h.push_with(&bytes, protocol::TOOL, |h, index, data| {
        if index == 0 {
            first = Some(data);
        }
        if index == 3 {
            // The same bytes in a CAN FD frame: not the classic reception's kind, ignored.
            let id = Message::TableTransfer { data, len: 8 }
                .to_frame(protocol::TOOL, Harness::NODE_ID)
                .id();
            h.feed(&Frame::fd(id, &data, true).unwrap());
            return None;
        }
        Some(data)
    });
    assert_eq!(last_status(&h).status, TransferStatusCode::Interrupted);
    assert_still_v1(&mut h);
}

#[test]
fn an_fd_push_whose_frames_stop_times_out_and_the_next_one_is_applied() {
    let mut h = running_v1();
    let bytes = v2();
    // Every Consecutive Frame after the second comes classic: the node never sees the rest.
    h.push_fd_with(&bytes, protocol::TOOL, TxDl::MAX, |_, index, f| {
        Some(if index >= 2 { classic(&f) } else { f })
    });
    h.advance_to(h.now + 2_000 * MS);
    assert_eq!(last_status(&h).status, TransferStatusCode::Timeout);
    assert_eq!(h.running_version(), Some(1));
    let (end, _) = h.push_fd_with(&bytes, protocol::TOOL, TxDl::MAX, |_, _, f| Some(f));
    assert_eq!(end, TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
}

#[test]
fn a_corrupted_fd_frame_is_refused_by_the_crc() {
    let mut h = running_v1();
    let bytes = v2();
    h.push_fd_with(&bytes, protocol::TOOL, TxDl::MAX, |_, index, f| {
        if index != 3 {
            return Some(f);
        }
        let mut data = f.payload().to_vec();
        data[30] ^= 0x40;
        Frame::fd(f.id(), &data, true)
    });
    assert_eq!(last_status(&h).status, TransferStatusCode::CrcMismatch);
    assert_still_v1(&mut h);
}

#[test]
fn on_a_keyed_node_an_fd_first_frame_needs_its_open() {
    let table = priority_table(&[TOPIC_A], None);
    let mut h = Harness::boot_keyed(Some(&image(&table, Harness::NODE_ID, 1)), &KEY, 7);
    let bytes = v2();
    let from = h.now;
    // No TransferOpen: the CAN FD first frame is refused before the receiver sees it, so the
    // node sends no flow control and nothing is applied.
    let (end, flow_controls) = h.push_fd_with(&bytes, protocol::TOOL, TxDl::MAX, |_, _, f| Some(f));
    assert!(matches!(end, TxEvent::Failed(_)), "{end:?}");
    assert!(flow_controls.is_empty());
    assert!(
        h.auth_failures_since(from).contains(&AuthFailure::Unopened),
        "{:?}",
        h.auth_failures_since(from)
    );
    assert_eq!(h.running_version(), Some(1));
}
