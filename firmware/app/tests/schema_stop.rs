//! A stop that stays stopped (DESIGN, "A stop that stays stopped"): an EmergencyStop or a
//! SchemaAbort ends everything that was about to run, and only a high-priority schema that
//! acknowledges the stop leaves it. On the in-process bus, the node's own code.

use crate::common;
use crate::schema_rig;

use common::*;
use pab_core::Instant;
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{BROADCAST, Message, SchemaOutcome, SchemaSafety, SchemaTrigger, TOOL};
use pab_core::schema::{Schema, build};
use schema_rig::*;

/// Ticks come every 1 000 µs from boot: the time just after the next one.
fn just_after_a_tick(h: &mut Harness) {
    let next = (h.now / 1000 + 1) * 1000 + 10;
    h.advance_to(next);
}

/// The node running a queued move towards +x, its drive following 30 µm behind.
fn moving() -> Harness {
    let mut h = booted();
    report(&mut h, [0, 0, 0]);
    h.advance_to(h.now + 2_000);
    let ack = send(
        &mut h,
        0,
        &build::move_to(1, [100_000, 0, 0, 0, 0, 0], 50_000),
    );
    assert_eq!(ack.outcome, SchemaOutcome::Accepted);
    follow(&mut h, 10);
    h
}

/// `ticks` periods of the drive following the attractor 30 µm behind.
fn follow(h: &mut Harness, ticks: usize) {
    for _ in 0..ticks {
        let last = attractors(h, 0).last().map_or([0; 3], |a| a.1);
        report(h, [last[0] - 30, 0, 0]);
        h.advance_to(h.now + 1000);
    }
}

/// (ended, installed, trigger) of every transition since `since`.
fn changes(h: &Harness, since: u64) -> Vec<(u16, u16, SchemaTrigger)> {
    transitions(h, since)
        .into_iter()
        .map(|(_, t)| (t.ended, t.installed, t.trigger))
        .collect()
}

#[test]
fn a_high_priority_schema_pending_at_an_emergency_stop_is_discarded_and_the_stop_holds() {
    let mut h = moving();
    just_after_a_tick(&mut h);
    // The client's high-priority move away (accepted, waiting for the next tick) races the
    // operator's stop button: both reach the node between two ticks.
    let away = build::move_to(9, [-50_000, 0, 0, 0, 0, 0], 100_000);
    let stop_seen = h.now;
    let ack = send(&mut h, 1, &away);
    assert_eq!(ack.outcome, SchemaOutcome::Accepted);
    h.feed(&Message::EmergencyStop.to_frame(TOOL, BROADCAST));
    let halted = attractors(&h, 0).last().unwrap().1[0] - 30;
    follow(&mut h, 200);
    assert_eq!(
        changes(&h, stop_seen),
        [
            (1, Schema::SAFETY, SchemaTrigger::Safety),
            (
                Schema::SAFETY,
                Schema::WAIT_HIGH_PRIORITY,
                SchemaTrigger::Reaction
            ),
        ],
        "the stop, then the wait for the high-priority channel, and nothing else"
    );
    // The attractor stays where the robot was, the fault stays raised.
    let after = attractors(&h, stop_seen + 1000);
    assert!(after.iter().all(|a| a.1[0] == halted), "{:?}", &after[..3]);
    let state = h
        .messages_since(stop_seen + 150_000)
        .into_iter()
        .find_map(|(_, _, m)| match m {
            Message::SchemaState(s) => Some(s),
            _ => None,
        })
        .expect("a SchemaState");
    assert_eq!(state.fault, Some(SchemaSafety::EmergencyStop));
    assert_eq!(state.current, Schema::WAIT_HIGH_PRIORITY);
}

#[test]
fn only_a_high_priority_schema_that_names_the_stop_leaves_it() {
    let mut h = moving();
    h.feed(&Message::EmergencyStop.to_frame(TOOL, BROADCAST));
    follow(&mut h, 5);
    // Sent by a client that has not seen the stop: refused, and the answer names the stop.
    let stale = send(&mut h, 1, &build::move_to(9, [0; 6], 10_000));
    assert_eq!(
        (stale.outcome, stale.stop),
        (SchemaOutcome::StopNotAcknowledged, 1)
    );
    let state = latest_state(&mut h);
    assert_eq!(
        (state.stop, state.fault),
        (1, Some(SchemaSafety::EmergencyStop))
    );
    // Acknowledged: installed at the next tick, the fault cleared.
    let since = h.now;
    let ack = send(&mut h, 1 | state.stop << 2, &build::idle(10, 0));
    assert_eq!(ack.outcome, SchemaOutcome::Accepted);
    follow(&mut h, 3);
    assert_eq!(
        changes(&h, since),
        [(Schema::WAIT_HIGH_PRIORITY, 10, SchemaTrigger::HighPriority)]
    );
    assert_eq!(latest_state(&mut h).fault, None);
    // The queue is not an acknowledgement: a queued schema waits, the stop holds.
    h.feed(&Message::EmergencyStop.to_frame(TOOL, BROADCAST));
    follow(&mut h, 5);
    let since = h.now;
    assert_eq!(
        send(&mut h, 0, &build::idle(11, 0)).outcome,
        SchemaOutcome::Accepted
    );
    follow(&mut h, 50);
    assert_eq!(changes(&h, since), []);
    assert_eq!(latest_state(&mut h).stop, 2);
}

#[test]
fn an_abort_discards_a_pending_high_priority_schema_too() {
    let mut h = moving();
    just_after_a_tick(&mut h);
    let since = h.now;
    assert_eq!(
        send(&mut h, 1, &build::idle(9, 0)).outcome,
        SchemaOutcome::Accepted
    );
    h.feed(&Message::SchemaAbort.to_frame(TOOL, Harness::NODE_ID));
    follow(&mut h, 50);
    assert_eq!(
        changes(&h, since),
        [(1, Schema::WAIT_HIGH_PRIORITY, SchemaTrigger::Abort)]
    );
    let state = latest_state(&mut h);
    assert_eq!(
        (state.stop, state.fault, state.current),
        (1, None, Schema::WAIT_HIGH_PRIORITY)
    );
}

#[test]
fn a_high_priority_schema_whose_transfer_spans_the_stop_is_refused() {
    let mut h = moving();
    // A move of several frames on the high-priority channel (stop 0, the latest when it began):
    // its first frame before the stop, its last after it.
    let mut message = vec![1u8];
    let mut buf = [0u8; 300];
    let away = build::move_to(9, [-50_000, 0, 0, 0, 0, 0], 100_000);
    message.extend_from_slice(postcard::to_slice(&away, &mut buf).unwrap());
    assert!(message.len() > 7, "several frames");
    let since = h.now;
    let ack = send_paced(&mut h, &message, 100, 100_000, |h, sent| {
        if sent == 1 {
            // The stop, and a few ticks, between the first frame and the rest.
            h.feed(&Message::EmergencyStop.to_frame(TOOL, BROADCAST));
            follow(h, 3);
        }
    });
    let ack = ack.expect("a SchemaAck");
    assert_eq!(
        (ack.outcome, ack.stop),
        (SchemaOutcome::StopNotAcknowledged, 1)
    );
    follow(&mut h, 20);
    assert!(
        changes(&h, since)
            .iter()
            .all(|c| c.2 != SchemaTrigger::HighPriority),
        "{:?}",
        changes(&h, since)
    );
}

#[test]
fn a_trickled_transfer_loses_the_slot_within_its_budget() {
    let mut h = moving();
    // 250 bytes: a first frame and 35 consecutive frames; its budget 1 s + 35 x 10 ms.
    let mut message = vec![0u8];
    let mut buf = [0u8; 300];
    message.extend_from_slice(postcard::to_slice(&build::idle(20, 0), &mut buf).unwrap());
    message.resize(250, 0);
    let started = h.now;
    // One frame every 900 ms: never N_Cr (1 s) apart.
    let ack = send_paced(&mut h, &message, 900_000, 5_000_000, |_, _| {});
    let ack = ack.expect("the trickle's SchemaAck");
    assert_eq!(ack.outcome, SchemaOutcome::TimedOut);
    let answered = h
        .messages_since(started)
        .into_iter()
        .find_map(|(t, _, m)| matches!(m, Message::SchemaAck(_)).then_some(t))
        .unwrap();
    // Exactly its budget after the first frame: the node polls at that deadline.
    let budget = 1_000_000 + 35 * 10_000;
    assert!(
        answered - started <= budget,
        "answered {} µs after the first frame",
        answered - started
    );
    // The slot is free: another sender's schema goes through at once.
    assert_eq!(
        send(&mut h, 0, &build::idle(21, 0)).outcome,
        SchemaOutcome::Accepted
    );
}

/// The node's next SchemaState (it comes every 100 ms).
fn latest_state(h: &mut Harness) -> pab_core::protocol::SchemaState {
    let since = h.now;
    follow(h, 101);
    h.messages_since(since)
        .into_iter()
        .rev()
        .find_map(|(_, _, m)| match m {
            Message::SchemaState(s) => Some(s),
            _ => None,
        })
        .expect("a SchemaState")
}

/// A schema message sent frame by frame as the node's flow control allows, a frame every
/// `pace_us` µs, `before(h, sent)` called once before each frame and once after the last (`sent`:
/// the frames sent so far). Returns the node's SchemaAck, if it sent one within `limit_us`.
fn send_paced(
    h: &mut Harness,
    message: &[u8],
    pace_us: u64,
    limit_us: u64,
    mut before: impl FnMut(&mut Harness, usize),
) -> Option<pab_core::protocol::SchemaAck> {
    let mut sender = Sender::new(message, TxConfig::default()).unwrap();
    let until = h.now + limit_us;
    let mut seen = h.sent.len();
    let total = if message.len() <= 7 {
        1
    } else {
        1 + (message.len() - 6).div_ceil(7)
    };
    let (mut frames, mut called, mut ack) = (0, None, None);
    // Past the answer only to make the call after the last frame.
    while (ack.is_none() || (frames == total && called != Some(frames))) && h.now < until {
        if called != Some(frames) {
            before(h, frames);
            called = Some(frames);
        }
        if let TxEvent::Send(data) = sender.poll(Instant::from_micros(h.now)) {
            h.feed(&Message::SchemaTransfer { data, len: 8 }.to_frame(TOOL, Harness::NODE_ID));
            frames += 1;
        }
        for (_, frame) in &h.sent[seen..] {
            match Message::decode(frame) {
                Ok((id, Message::SchemaTransfer { data, len })) if id.destination == TOOL => {
                    let now = Instant::from_micros(h.now);
                    let _ = sender.on_flow_control(&data[..usize::from(len)], now);
                }
                Ok((id, Message::SchemaAck(a))) if id.destination == TOOL => ack = Some(a),
                _ => {}
            }
        }
        seen = h.sent.len();
        h.advance_to(h.now + pace_us);
    }
    ack
}

/// Stops interleaved at every point of a transfer: an emergency stop or an abort before the
/// first frame, between any two, or after the last, of a high-priority message that names the
/// stop number of its start. Whatever the point, the stop holds: no schema of the channel is
/// installed after it, and the answer is the refusal (the message completed after the stop's
/// tick) or an acceptance that the stop's tick discarded.
#[test]
fn a_stop_at_every_point_of_a_high_priority_transfer_holds() {
    let away = build::move_to(9, [-50_000, 0, 0, 0, 0, 0], 100_000);
    let mut message = vec![1u8];
    let mut buf = [0u8; 300];
    message.extend_from_slice(postcard::to_slice(&away, &mut buf).unwrap());
    let frames = 1 + (message.len() - 6).div_ceil(7);
    assert!(frames >= 3, "{frames} frames");
    let stops = [
        Message::EmergencyStop.to_frame(TOOL, BROADCAST),
        Message::SchemaAbort.to_frame(TOOL, Harness::NODE_ID),
    ];
    for stop in &stops {
        for at in 0..=frames {
            let mut h = moving();
            just_after_a_tick(&mut h);
            let since = h.now;
            let mut fed = false;
            let ack = send_paced(&mut h, &message, 100, 200_000, |h, sent| {
                if sent == at {
                    h.feed(stop);
                    fed = true;
                }
            });
            assert!(fed);
            follow(&mut h, 30);
            let ack = ack.unwrap_or_else(|| panic!("no SchemaAck, stop after {at} frames"));
            let installed: Vec<_> = changes(&h, since);
            assert!(
                installed.iter().all(|c| c.2 != SchemaTrigger::HighPriority),
                "stop after {at} of {frames} frames: {installed:?}"
            );
            assert!(
                matches!(
                    ack.outcome,
                    SchemaOutcome::Accepted | SchemaOutcome::StopNotAcknowledged
                ),
                "stop after {at} frames: {ack:?}"
            );
            assert!(
                installed.first().is_some_and(|c| c.1 >= Schema::WAIT_QUEUE),
                "the stop's tick installs the server's own schema: {installed:?}"
            );
            assert_eq!(latest_state(&mut h).current, Schema::WAIT_HIGH_PRIORITY);
        }
    }
}

#[test]
fn a_forged_pose_just_before_a_stop_does_not_move_where_the_stop_holds_the_robot() {
    let mut h = moving();
    let measured = attractors(&h, 0).last().unwrap().1[0] - 30;
    report(&mut h, [measured, 0, 0]);
    h.advance_to(h.now + 100);
    // A participant's pose frame, 400 mm away, then the operator's stop.
    h.feed(&frame(
        POSE,
        &pab_core::schema::drive::pack([400_000, 0, 0], false),
    ));
    let stop_at = h.now;
    h.feed(&Message::EmergencyStop.to_frame(TOOL, BROADCAST));
    // Ten seconds of true poses.
    for _ in 0..10_000 {
        report(&mut h, [measured, 0, 0]);
        h.advance_to(h.now + 1000);
    }
    let held = attractors(&h, stop_at);
    assert!(!held.is_empty());
    assert!(
        held.iter().all(|a| a.1 == [measured, 0, 0]),
        "the stop held {:?}",
        held.iter().find(|a| a.1 != [measured, 0, 0])
    );
}
