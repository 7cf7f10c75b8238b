//! The node's outbox sends in identifier order, as the bus arbitrates: a gateway's re-publication
//! or a fault never waits behind the diagnostic stream queued before it, and frames with the same
//! identifier (a diagnostic round, ISO-TP flow control) keep their order.

use crate::common;

use common::*;
use pab_app::Config;
use pab_core::protocol::{self, DiagnosticControl, FrameId, Message, Service};
use pab_core::{Frame, Instant};

/// A gateway node (port 0 re-publishes on 0x300) with 12 connections, booted at t = 0 with its
/// diagnostic stream at 200 rounds/s on every port, and nothing left in its outbox.
fn streaming_gateway() -> TestNode {
    let ids: Vec<u32> = (0..12).map(|k| TOPIC_A + k).collect();
    let table = priority_table(&ids, Some(GATEWAY_OUT));
    let bytes = image(&table, Harness::NODE_ID, 1);
    let mut node = TestNode::new(
        Config::new(Harness::NODE_ID).unwrap(),
        Instant::from_micros(0),
    );
    node.boot_buffer()[..bytes.len()].copy_from_slice(&bytes);
    node.boot(Some(bytes.len()), Instant::from_micros(0));
    let control = Message::DiagnosticControl(DiagnosticControl {
        rate_hz: 200,
        ports: 0xFFFF,
    })
    .to_frame(protocol::TOOL, Harness::NODE_ID);
    let _ = node.on_frame(&control, Instant::from_micros(10), &mut ());
    while node.next_outgoing().is_some() {}
    node
}

fn samples(frames: &[Frame]) -> Vec<(u8, u8, u8)> {
    frames
        .iter()
        .filter_map(|frame| match Message::decode(frame) {
            Ok((_, Message::Diagnostic(sample))) => {
                Some((sample.sequence, sample.port, sample.connection))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn a_republication_queued_behind_a_diagnostic_round_goes_out_first() {
    let mut node = streaming_gateway();
    // The next round is due: the poll fills the outbox with samples (all it leaves them).
    let step = node.poll(Instant::from_micros(5_010), &mut ());
    assert_eq!(step, pab_app::Step::Continue);
    // A frame of the winning topic arrives before any of them went out.
    let mut deliveries = Deliveries::default();
    let _ = node.on_frame(
        &frame(TOPIC_A, &[7, 8]),
        Instant::from_micros(5_020),
        &mut deliveries,
    );
    assert_eq!(deliveries.0.len(), 1, "delivered");
    let mut out = Vec::new();
    while let Some(frame) = node.next_outgoing() {
        out.push(frame);
    }
    let diagnostic = FrameId::new(Service::Diagnostic, Harness::NODE_ID, protocol::BROADCAST).id();
    let queued_samples = out.iter().filter(|f| f.id() == diagnostic).count();
    assert!(
        queued_samples >= 8,
        "a round was queued: {queued_samples} samples"
    );
    assert_eq!(
        out[0],
        Frame::with_raw_id(GATEWAY_OUT, false, &[7, 8]).unwrap(),
        "the re-publication leaves first"
    );
    // The samples keep their order: by round, then port, then connection.
    let order = samples(&out);
    let mut sorted = order.clone();
    sorted.sort();
    assert_eq!(order, sorted, "the round in order");
}

#[test]
fn frames_leave_in_identifier_order_and_in_queue_order_among_equal_identifiers() {
    let mut node = streaming_gateway();
    let _ = node.poll(Instant::from_micros(5_010), &mut ());
    // Fill what the stream left with re-publications of frames of several payloads, and a
    // malformed command that raises a fault (priority 0).
    for k in 0..3u8 {
        let _ = node.on_frame(
            &frame(TOPIC_A, &[k]),
            Instant::from_micros(5_020 + u64::from(k)),
            &mut (),
        );
    }
    let bad = Frame::with_raw_id(
        FrameId::new(Service::DiagnosticControl, protocol::TOOL, Harness::NODE_ID).raw(),
        true,
        &[1],
    )
    .unwrap();
    let _ = node.on_frame(&bad, Instant::from_micros(5_030), &mut ());
    let mut out = Vec::new();
    while let Some(frame) = node.next_outgoing() {
        out.push(frame);
    }
    let ranks: Vec<u32> = out.iter().map(Frame::arbitration_rank).collect();
    let mut sorted = ranks.clone();
    sorted.sort();
    assert_eq!(ranks, sorted, "identifier order: {out:?}");
    // The fault (extended base 0x080) beats the re-publications on 0x300.
    assert!(matches!(
        Message::decode(&out[0]),
        Ok((_, Message::Fault(_)))
    ));
    let republished: Vec<u8> = out
        .iter()
        .filter(|f| f.raw_id() == (GATEWAY_OUT, false))
        .map(|f| f.payload()[0])
        .collect();
    assert_eq!(republished, [0, 1, 2], "equal identifiers in queue order");
}
