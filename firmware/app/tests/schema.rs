//! The schema server on a node (docs/can-protocol.md, "Schema server"), on the in-process bus:
//! schemas over ISO-TP answered with SchemaAck, the loop ticked at its period with the drive's
//! set-point on the bus every tick, transitions and faults reported, the emergency stop halting
//! within one period, abort, SchemaState every 100 ms, and the refusals.

use crate::common;
use crate::schema_rig;

use common::*;
use pab_core::Frame;
use pab_core::protocol::{
    BROADCAST, FaultCode, Message, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety,
    SchemaTrigger, TOOL,
};
use pab_core::schema::{Event, Measure, Reaction, Schema, Source, build};
use schema_rig::*;

#[test]
fn a_queued_schema_is_acknowledged_installed_and_drives_the_attractor_every_tick() {
    let mut h = booted();
    report(&mut h, [1000, 0, 0]);
    h.advance_to(h.now + 5_000);
    let ack = send(
        &mut h,
        0,
        &build::move_to(7, [1000 + 50, 0, 0, 0, 0, 0], 1000),
    );
    assert_eq!(ack.outcome, SchemaOutcome::Accepted);
    assert_eq!((ack.channel, ack.id), (Some(SchemaChannel::Queue), 7));
    let from = h.now;
    // The drive follows the attractor.
    for _ in 0..80 {
        let target = attractors(&h, 0).last().map_or([1000, 0, 0], |a| a.1);
        report(&mut h, target);
        h.advance_to(h.now + 1000);
    }
    let tr = transitions(&h, from);
    assert_eq!(tr[0].1.ended, Schema::WAIT_QUEUE);
    assert_eq!(tr[0].1.installed, 7);
    assert_eq!(tr[0].1.source, SchemaOrigin::Queue);
    assert_eq!(tr[1].1.ended, 7, "done, back to the wait: {tr:?}");
    assert_eq!(tr[1].1.trigger, SchemaTrigger::Reaction, "{tr:?}");
    assert_eq!(tr[1].1.trigger, SchemaTrigger::Reaction);
    // One attractor frame per 1 ms tick, 1 µm a tick at 1 mm/s, ending on the goal.
    let a = attractors(&h, tr[0].0);
    assert!(a.len() >= 60, "{}", a.len());
    for w in a.windows(2).take(40) {
        assert_eq!(w[1].0 - w[0].0, 1000, "{w:?}");
    }
    let xs: Vec<i32> = a.iter().map(|a| a.1[0]).collect();
    assert_eq!(&xs[..5], &[1001, 1002, 1003, 1004, 1005]);
    assert_eq!(*xs.last().unwrap(), 1050);
    // The rotation and impedance frames are there too.
    assert!(
        h.sent
            .iter()
            .any(|(_, f)| f.raw_id() == (SETPOINT + 1, false))
    );
    assert!(
        h.sent
            .iter()
            .any(|(_, f)| f.raw_id() == (SETPOINT + 2, false))
    );
}

#[test]
fn an_emergency_stop_halts_within_one_period_and_raises_its_fault() {
    let mut h = booted();
    report(&mut h, [0, 0, 0]);
    h.advance_to(h.now + 2_000);
    send(
        &mut h,
        0,
        &build::move_to(1, [100_000, 0, 0, 0, 0, 0], 50_000),
    );
    for _ in 0..20 {
        let last = attractors(&h, 0).last().unwrap().1;
        report(&mut h, [last[0] - 30, 0, 0]);
        h.advance_to(h.now + 1000);
    }
    let measured = attractors(&h, 0).last().unwrap().1[0] - 30;
    report(&mut h, [measured, 0, 0]);
    h.advance_to(h.now + 300);
    let stop_at = h.now;
    h.feed(&Message::EmergencyStop.to_frame(TOOL, BROADCAST));
    h.advance_to(h.now + 5_000);
    let tr = transitions(&h, stop_at);
    let (t, stop) = tr[0];
    assert!(
        t - stop_at <= 1000,
        "halted {} µs after the frame",
        t - stop_at
    );
    assert_eq!(stop.trigger, SchemaTrigger::Safety);
    assert_eq!(stop.safety(), Some(SchemaSafety::EmergencyStop));
    assert_eq!(stop.installed, Schema::SAFETY);
    // The halting tick's set-point is the measured pose, and stays there.
    let after = attractors(&h, t);
    assert_eq!(after[0].1[0], measured);
    assert!(after.iter().all(|a| a.1[0] == measured));
    let fault = h
        .messages_since(stop_at)
        .into_iter()
        .find_map(|(_, _, m)| match m {
            Message::Fault(f) if f.code == FaultCode::SchemaSafety => Some(f),
            _ => None,
        })
        .expect("a SchemaSafety fault");
    assert_eq!(fault.detail, [0, 1, 0, 0, 0]);
    // Then the wait for the high-priority channel.
    assert_eq!(tr[1].1.installed, Schema::WAIT_HIGH_PRIORITY);
}

#[test]
fn a_sensor_frame_triggers_a_reaction_into_an_innate_schema() {
    let mut h = booted();
    report(&mut h, [0, 0, 0]);
    h.advance_to(h.now + 2_000);
    // Wait until the proximity sensor reads 20 mm or less, then close the gripper (innate 0).
    let mut wait = build::idle(5, 0);
    wait.reactions[0] = Reaction {
        event: Event::Below(Measure::Sensor(0), 20),
        next: Source::Innate(0),
    };
    assert_eq!(send(&mut h, 0, &wait).outcome, SchemaOutcome::Accepted);
    let proximity = |mm: u16| {
        let [hi, lo] = mm.to_be_bytes();
        frame(PROXIMITY, &[0xFF, 0xFF, hi, lo])
    };
    let since = h.now;
    for mm in [60u16, 40, 21] {
        report(&mut h, [0, 0, 0]);
        h.feed(&proximity(mm));
        h.advance_to(h.now + 1000);
    }
    // A frame too short for the field is no reading: 21 mm still holds.
    report(&mut h, [0, 0, 0]);
    h.feed(&frame(PROXIMITY, &[0, 0, 0]));
    h.advance_to(h.now + 1000);
    let tr = transitions(&h, since);
    assert_eq!(
        tr.iter().map(|t| t.1.installed).collect::<Vec<_>>(),
        [5],
        "installed from the queue, no reaction yet: {tr:?}"
    );
    report(&mut h, [0, 0, 0]);
    h.feed(&proximity(20));
    let read_at = h.now;
    h.advance_to(h.now + 1000);
    let tr = transitions(&h, read_at);
    let (t, close) = tr[0];
    assert!(t - read_at <= 1000, "{} µs after the frame", t - read_at);
    assert_eq!(
        (close.ended, close.installed, close.trigger, close.detail),
        (5, CLOSE, SchemaTrigger::Reaction, 0)
    );
    assert_eq!(close.source, SchemaOrigin::Innate);
    // And the gripper closes on that tick's set-point.
    assert!(attractors(&h, t).first().is_some_and(|a| a.2));
}

#[test]
fn abort_and_the_high_priority_channel() {
    let mut h = booted();
    report(&mut h, [0, 0, 0]);
    h.advance_to(h.now + 2_000);
    send(&mut h, 0, &build::idle(1, 0));
    send(&mut h, 0, &build::idle(2, 0));
    let since = h.now;
    h.feed(&Message::SchemaAbort.to_frame(TOOL, Harness::NODE_ID));
    h.advance_to(h.now + 2_000);
    let tr = transitions(&h, since);
    assert_eq!(tr[0].1.trigger, SchemaTrigger::Abort);
    assert_eq!(tr[0].1.installed, Schema::WAIT_HIGH_PRIORITY);
    assert_eq!(tr[0].1.queued, 0);
    // The abort is the server's first stop: a high-priority schema leaves it by naming stop 1
    // (channel byte: 1, the stop number in bits 2-7).
    assert_eq!(ack_stop(&send(&mut h, 1, &build::idle(8, 0))), 1);
    let since = h.now;
    let ack = send(&mut h, 1 | 1 << 2, &build::idle(9, 0));
    assert_eq!(
        (ack.outcome, ack.channel),
        (SchemaOutcome::Accepted, Some(SchemaChannel::HighPriority))
    );
    h.advance_to(h.now + 2_000);
    let tr = transitions(&h, since);
    assert_eq!(
        (tr[0].1.installed, tr[0].1.trigger),
        (9, SchemaTrigger::HighPriority)
    );
}

/// The stop number a refusal for want of an acknowledgement names.
fn ack_stop(ack: &pab_core::protocol::SchemaAck) -> u8 {
    assert_eq!(ack.outcome, SchemaOutcome::StopNotAcknowledged, "{ack:?}");
    ack.stop
}

#[test]
fn bad_schemas_are_refused_with_their_reason_and_a_full_queue_refuses() {
    let mut h = booted();
    report(&mut h, [0, 0, 0]);
    // A move keeps the queue from running.
    send(&mut h, 1, &build::move_to(1, [400_000, 0, 0, 0, 0, 0], 1));
    let ack = send_bytes(&mut h, &[0, 1, 2, 3]);
    assert_eq!(ack.outcome, SchemaOutcome::Malformed);
    let mut reserved = build::idle(1, 0);
    reserved.id = 0xFF00;
    assert_eq!(
        send(&mut h, 0, &reserved).outcome,
        SchemaOutcome::ReservedId
    );
    assert_eq!(
        send(&mut h, 3, &build::idle(3, 0)).outcome,
        SchemaOutcome::BadChannel
    );
    // Channel 2 is the limits': a schema's bytes are no limits.
    assert_eq!(
        send(&mut h, 2, &build::idle(3, 0)).outcome,
        SchemaOutcome::Malformed
    );
    let mut innate = build::idle(4, 0);
    // The board has one innate schema.
    innate.reactions[0].next = pab_core::schema::Source::Innate(1);
    assert_eq!(
        send(&mut h, 0, &innate).outcome,
        SchemaOutcome::UnknownInnate
    );
    for k in 0..8u16 {
        let ack = send(&mut h, 0, &build::idle(10 + k, 0));
        assert_eq!(
            (ack.outcome, ack.queued),
            (SchemaOutcome::Accepted, k as u8 + 1)
        );
    }
    let ack = send(&mut h, 0, &build::idle(20, 0));
    assert_eq!(
        (ack.outcome, ack.queued, ack.id),
        (SchemaOutcome::QueueFull, 8, 20)
    );
}

#[test]
fn a_node_without_a_schema_server_refuses_schemas() {
    let mut h = Harness::boot(Some(&image(
        &priority_table(&[TOPIC_A], None),
        Harness::NODE_ID,
        1,
    )));
    assert_eq!(
        send(&mut h, 0, &build::idle(1, 0)).outcome,
        SchemaOutcome::NoServer
    );
    // A node with a key: tests/schema_keyed.rs.
}

#[test]
fn the_state_is_streamed_every_100_ms() {
    let mut h = booted();
    report(&mut h, [0, 0, 0]);
    let since = h.now;
    h.advance_to(h.now + 1_000_000);
    let states: Vec<(u64, pab_core::protocol::SchemaState)> = h
        .messages_since(since)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            Message::SchemaState(s) => Some((t, s)),
            _ => None,
        })
        .collect();
    assert!((10..=11).contains(&states.len()), "{}", states.len());
    for w in states.windows(2) {
        assert_eq!(w[1].0 - w[0].0, 100_000);
    }
    assert_eq!(states[0].1.current, Schema::WAIT_QUEUE);
    assert!(states.last().unwrap().1.armed);
    let _ = Frame::empty();
}

/// A schema in CAN FD frames, at TX_DL 16 (a First Frame, Consecutive Frames and a flow control)
/// and 64 (one escaped Single Frame): accepted as a classic transfer is, the flow control a CAN FD
/// frame with the transfer's bit-rate switch.
#[cfg(feature = "fd")]
#[test]
fn a_schema_in_can_fd_frames_is_accepted_and_its_flow_control_is_can_fd() {
    use pab_core::isotp::fd::TxDl;
    use pab_core::isotp::{FdSender, TxConfig, TxEvent};
    use pab_core::protocol::{Message, TOOL};
    use pab_core::{Frame, Instant};
    for (tx, id) in [(16, 7), (64, 8)] {
        let mut h = booted();
        report(&mut h, [1000, 0, 0]);
        h.advance_to(h.now + 5_000);
        let mut message = vec![0];
        let mut buf = [0u8; 300];
        let schema = build::move_to(id, [1000 + 50, 0, 0, 0, 0, 0], 1000);
        message.extend_from_slice(postcard::to_slice(&schema, &mut buf).unwrap());
        let since = h.now;
        let transfer_id = Message::SchemaTransfer {
            data: [0; 8],
            len: 8,
        }
        .to_frame(TOOL, Harness::NODE_ID)
        .id();
        let mut sender =
            FdSender::new(&message, TxConfig::default(), TxDl::new(tx).unwrap()).unwrap();
        let mut seen = h.sent.len();
        let mut flow_controls = Vec::new();
        for _ in 0..100 {
            match sender.poll(Instant::from_micros(h.now)) {
                TxEvent::Send(data) => {
                    h.feed(&Frame::fd(transfer_id, data.as_bytes(), true).unwrap());
                    h.advance_to(h.now + 100);
                }
                TxEvent::WaitUntil(until) => {
                    while seen < h.sent.len() {
                        let (_, frame) = h.sent[seen];
                        seen += 1;
                        if let Ok((fc_id, Message::SchemaTransfer { .. })) = Message::decode(&frame)
                            && fc_id.destination == TOOL
                        {
                            flow_controls.push(frame);
                            sender.on_flow_control(frame.payload(), Instant::from_micros(h.now));
                        }
                    }
                    h.advance_to(until.as_micros().min(h.now + 100).max(h.now + 1));
                }
                TxEvent::Done | TxEvent::Failed(_) => break,
            }
        }
        let ack = acks(&h, since).pop().expect("a SchemaAck");
        assert_eq!(ack.outcome, SchemaOutcome::Accepted, "TX_DL {tx}");
        assert_eq!(ack.id, id);
        assert_eq!(
            flow_controls.is_empty(),
            message.len() <= tx - 2,
            "TX_DL {tx}"
        );
        assert!(flow_controls.iter().all(|f| f.is_fd() && f.is_brs()));
    }
}
