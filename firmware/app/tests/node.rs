//! The node application against an in-process bus with virtual time: arbitration, heartbeat,
//! faults, diagnostic stream, gateway consumer.

use crate::common;

use common::*;
use pab_app::Step;
use pab_core::protocol::{
    self, DiagnosticControl, FaultCode, Message, NodeState, Service, TransferStatusCode,
};
use pab_core::{Frame, Instant};

const MS: u64 = 1_000;
const S: u64 = 1_000_000;

fn heartbeats(h: &Harness) -> Vec<(u64, protocol::Heartbeat)> {
    h.messages_since(0)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            Message::Heartbeat(hb) => Some((t, hb)),
            _ => None,
        })
        .collect()
}

fn faults(h: &Harness) -> Vec<(u64, protocol::Fault)> {
    h.messages_since(0)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            Message::Fault(f) => Some((t, f)),
            _ => None,
        })
        .collect()
}

#[test]
fn arbitrates_frames_and_hands_the_winners_to_the_consumer() {
    let table = priority_table(&[TOPIC_A, TOPIC_B], None);
    let mut h = Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)));
    assert_eq!(h.node.state(), NodeState::Operational);
    // B alone, 10 Hz for 1 s: every frame gets through.
    for k in 0..10 {
        h.advance_to(k * 100 * MS);
        h.feed(&frame(TOPIC_B, &[k as u8]));
    }
    assert_eq!(h.deliveries.0.len(), 10);
    assert!(
        h.deliveries
            .0
            .iter()
            .all(|(port, f, _)| *port == 0 && f.raw_id().0 == TOPIC_B)
    );
    // A starts: A wins, B's frames are discarded while A is active.
    for k in 10..20 {
        h.advance_to(k * 100 * MS);
        h.feed(&frame(TOPIC_A, &[0xA0, k as u8]));
        h.advance_to(k * 100 * MS + 50 * MS);
        h.feed(&frame(TOPIC_B, &[k as u8]));
    }
    let after: Vec<_> = h.deliveries.0[10..]
        .iter()
        .map(|(_, f, _)| f.raw_id().0)
        .collect();
    assert_eq!(after, vec![TOPIC_A; 10]);
    let counters = h.node.counters();
    assert_eq!(counters.received, 30);
    assert_eq!(counters.delivered, 20);
    assert_eq!(counters.discarded, 10);
    // A stops; once it has decayed (τ = 0.5 s), B gets through again.
    h.advance_to(2 * S + 600 * MS);
    h.feed(&frame(TOPIC_B, &[0xBB]));
    assert_eq!(h.deliveries.0.last().unwrap().1.payload(), &[0xBB]);
    // Payloads reach the consumer unchanged.
    assert_eq!(h.deliveries.0[12].1.payload(), &[0xA0, 12]);
}

#[test]
fn without_a_table_nothing_is_delivered() {
    let mut h = Harness::boot(None);
    assert_eq!(h.node.state(), NodeState::NoTable);
    h.feed(&frame(TOPIC_A, &[1]));
    assert!(h.deliveries.0.is_empty());
    assert_eq!(h.node.counters().received, 1);
}

#[test]
fn heartbeat_group_every_second_with_state_version_and_counters() {
    let table = priority_table(&[TOPIC_A], None);
    let bytes = image(&table, Harness::NODE_ID, 7);
    let header = pab_core::image::read_header(&bytes).unwrap();
    let mut h = Harness::boot(Some(&bytes));
    h.advance_to(500 * MS);
    h.feed(&frame(TOPIC_A, &[1]));
    h.feed(&frame(0x7FF, &[1])); // matches nothing
    h.advance_to(3 * S + 500 * MS);
    let beats = heartbeats(&h);
    let times: Vec<u64> = beats.iter().map(|(t, _)| *t).collect();
    assert_eq!(times, vec![0, S, 2 * S, 3 * S]);
    for (t, beat) in &beats {
        assert_eq!(beat.state, NodeState::Operational);
        assert_eq!(beat.table_version, 7);
        assert_eq!(u64::from(beat.uptime_s), t / S);
    }
    // Each heartbeat is followed by the table status and the counters, in this order.
    let group: Vec<Service> = h
        .messages_since(S)
        .iter()
        .take(4)
        .map(|(_, id, _)| id.service)
        .collect();
    assert_eq!(
        group,
        [
            Service::Heartbeat,
            Service::TableStatus,
            Service::Traffic,
            Service::Errors
        ]
    );
    let status = h
        .messages_since(S)
        .into_iter()
        .find_map(|(_, _, m)| match m {
            Message::TableStatus(s) => Some(s),
            _ => None,
        });
    let status = status.unwrap();
    assert_eq!(status.crc, header.crc);
    assert_eq!(usize::from(status.image_len), bytes.len());
    assert_eq!(
        (status.ports, status.stored, status.diagnostic),
        (1, true, false)
    );
    let traffic = h
        .messages_since(S)
        .into_iter()
        .find_map(|(_, _, m)| match m {
            Message::Traffic(t) => Some(t),
            _ => None,
        });
    assert_eq!(traffic.unwrap().received, 2);
    assert_eq!(traffic.unwrap().delivered, 1);
    // All from our node, to everyone.
    for (_, id, _) in h.messages_since(0) {
        assert_eq!(
            (id.source, id.destination),
            (Harness::NODE_ID, protocol::BROADCAST)
        );
    }
}

#[test]
fn diagnostic_stream_reports_levels_activity_and_the_deliverer_at_the_requested_rate() {
    let table = priority_table(&[TOPIC_A, TOPIC_B], None);
    let mut h = Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)));
    h.feed(&frame(TOPIC_B, &[1]));
    let control = Message::DiagnosticControl(DiagnosticControl {
        rate_hz: 10,
        ports: 1,
    })
    .to_frame(protocol::TOOL, Harness::NODE_ID);
    h.advance_to(100 * MS);
    h.feed(&control);
    h.advance_to(S + 50 * MS);
    let samples: Vec<(u64, protocol::DiagnosticSample)> = h
        .messages_since(100 * MS)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            Message::Diagnostic(s) => Some((t, s)),
            _ => None,
        })
        .collect();
    // Rounds at 100, 200, ..., 1000 ms: ten rounds of two samples.
    assert_eq!(samples.len(), 20, "{samples:?}");
    for (k, pair) in samples.chunks(2).enumerate() {
        let (t0, first) = pair[0];
        let (t1, second) = pair[1];
        assert_eq!(t0, 100 * MS * (k as u64 + 1));
        assert_eq!(t1, t0);
        assert_eq!((first.port, first.connection), (0, 0));
        assert_eq!((second.port, second.connection), (0, 1));
        assert!(!first.flags.end_of_round && second.flags.end_of_round);
        assert_eq!(first.sequence, second.sequence);
        // Values are the arbiter's at that time.
        let arbiter = h.node.arbiter().unwrap();
        let now = Instant::from_micros(t0);
        assert_eq!(second.level, arbiter.level(0, 1, now).unwrap().raw());
        assert_eq!(second.flags.active, arbiter.activity(0, now).contains(1));
        assert_eq!(second.flags.delivering, arbiter.selected(0, now) == Some(1));
    }
    // B was fed at 0 with σ = 1 and τ = 0.5 s: delivering until it decays.
    assert!(samples[1].1.flags.delivering && samples[1].1.flags.active);
    assert!(samples[1].1.level > 0);
    assert!(!samples[19].1.flags.active && samples[19].1.level == 0);
    // The heartbeat says the stream is on; rate 0 switches it off.
    let off = Message::DiagnosticControl(DiagnosticControl {
        rate_hz: 0,
        ports: 1,
    })
    .to_frame(protocol::TOOL, Harness::NODE_ID);
    h.feed(&off);
    let before = h.sent.len();
    h.advance_to(3 * S);
    assert!(
        h.sent[before..].iter().all(
            |(_, f)| protocol::FrameId::decode(&f.id()).unwrap().service != Service::Diagnostic
        )
    );
}

#[test]
fn a_malformed_command_is_counted_and_reported_as_a_fault() {
    let mut h = Harness::boot(None);
    let id = protocol::FrameId::new(Service::DiagnosticControl, protocol::TOOL, Harness::NODE_ID);
    // Rate above the maximum.
    h.feed(&Frame::data(id.id(), &[0xFF, 0xFF, 1, 0]).unwrap());
    // Wrong length.
    h.advance_to(200 * MS);
    h.feed(&Frame::data(id.id(), &[1]).unwrap());
    // Addressed to another node: not ours to complain about.
    let other = protocol::FrameId::new(Service::DiagnosticControl, protocol::TOOL, 9);
    h.feed(&Frame::data(other.id(), &[1]).unwrap());
    assert_eq!(h.node.counters().errors, 2);
    let reported = faults(&h);
    assert_eq!(reported.len(), 2);
    assert!(reported.iter().all(|(_, f)| f.code == FaultCode::BadCommand
        && f.detail[0] == Service::DiagnosticControl.code()));
}

#[test]
fn faults_are_rate_limited_with_an_occurrence_count() {
    let mut h = Harness::boot(None);
    for k in 0..50 {
        h.advance_to(k * MS);
        h.bus_error(pab_app::BusError::Other(3));
    }
    h.advance_to(500 * MS);
    let reported = faults(&h);
    // One at once, then one per 100 ms with the occurrences in between.
    assert_eq!(reported[0].0, 0);
    assert_eq!(reported[0].1.count, 1);
    assert_eq!(reported[1].0, 100 * MS);
    assert_eq!(reported[1].1.count, 49);
    assert_eq!(reported.len(), 2);
    assert!(
        reported
            .iter()
            .all(|(_, f)| f.code == FaultCode::BusError && f.detail[0] == 3)
    );
    assert_eq!(h.node.counters().errors, 50);
}

#[test]
fn frames_the_driver_counted_as_lost_are_errors_and_their_total_is_the_rx_overrun_detail() {
    let mut h = Harness::boot(None);
    // Three losses within one fault interval: one frame at once, one 100 ms later carrying the
    // total of all three, not only the latest.
    h.advance_to(10 * MS);
    h.bus_error(pab_app::BusError::Dropped(1000));
    h.advance_to(20 * MS);
    h.bus_error(pab_app::BusError::Dropped(234));
    h.advance_to(30 * MS);
    h.bus_error(pab_app::BusError::Dropped(66));
    h.advance_to(150 * MS);
    let reported: Vec<_> = faults(&h)
        .into_iter()
        .filter(|(_, f)| f.code == FaultCode::RxOverrun)
        .collect();
    assert_eq!(reported.len(), 2, "{reported:?}");
    let total = |f: &protocol::Fault| u32::from_le_bytes(f.detail[..4].try_into().unwrap());
    assert_eq!(
        (reported[0].0, reported[0].1.count, total(&reported[0].1)),
        (10 * MS, 1, 1000)
    );
    assert_eq!(
        (reported[1].0, reported[1].1.count, total(&reported[1].1)),
        (110 * MS, 2, 1300)
    );
    assert_eq!(h.node.counters().lost, 1300);
    // Each lost frame is one error, in the heartbeat's Errors frame too.
    assert_eq!(h.node.counters().errors, 1300);
    h.advance_to(S);
    let errors = h
        .messages_since(0)
        .into_iter()
        .rev()
        .find_map(|(_, _, m)| match m {
            Message::Errors(e) => Some(e.errors),
            _ => None,
        });
    assert_eq!(errors, Some(1300));
    // An overrun the driver cannot count is one error, and the total stays what was counted.
    h.bus_error(pab_app::BusError::Overrun);
    assert_eq!(h.node.counters().errors, 1301);
    h.advance_to(2 * S);
    let last = faults(&h)
        .into_iter()
        .rev()
        .find(|(_, f)| f.code == FaultCode::RxOverrun);
    assert_eq!(total(&last.unwrap().1), 1300);
    // The total saturates; the error counter wraps, like every counter.
    h.bus_error(pab_app::BusError::Dropped(u32::MAX));
    assert_eq!(h.node.counters().lost, u32::MAX);
    assert_eq!(h.node.counters().errors, 1300);
    h.advance_to(3 * S);
    let last = faults(&h)
        .into_iter()
        .rev()
        .find(|(_, f)| f.code == FaultCode::RxOverrun);
    assert_eq!(total(&last.unwrap().1), u32::MAX);
}

#[test]
fn bus_off_puts_the_node_in_fault_until_it_recovers() {
    let table = priority_table(&[TOPIC_A], None);
    let mut h = Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)));
    h.bus_error(pab_app::BusError::BusOff);
    assert_eq!(h.node.state(), NodeState::Fault);
    h.advance_to(S);
    assert_eq!(heartbeats(&h).last().unwrap().1.state, NodeState::Fault);
    h.bus_error(pab_app::BusError::Recovered);
    assert_eq!(h.node.state(), NodeState::Operational);
}

#[test]
fn a_gateway_port_republishes_the_winners_frames_on_its_output_id() {
    let table = priority_table(&[TOPIC_A, TOPIC_B], Some(GATEWAY_OUT));
    let mut h = Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)));
    h.advance_to(10 * MS);
    h.feed(&frame(TOPIC_A, &[1, 2, 3]));
    h.feed(&frame(TOPIC_B, &[9, 9])); // loses: A is active
    h.feed(&frame(TOPIC_A, &[4, 5, 6, 7, 8, 9, 10, 11]));
    let republished: Vec<&Frame> = h
        .sent
        .iter()
        .map(|(_, f)| f)
        .filter(|f| f.raw_id() == (GATEWAY_OUT, false))
        .collect();
    assert_eq!(republished.len(), 2);
    assert_eq!(republished[0].payload(), &[1, 2, 3]);
    assert_eq!(republished[1].payload(), &[4, 5, 6, 7, 8, 9, 10, 11]);
    // The local consumer still sees the deliveries.
    assert_eq!(h.deliveries.0.len(), 2);
}

#[test]
fn a_bad_stored_table_leaves_the_node_without_a_table_and_says_why() {
    let table = priority_table(&[TOPIC_A], None);
    let mut bytes = image(&table, Harness::NODE_ID, 3);
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    let mut h = Harness::boot(Some(&bytes));
    assert_eq!(h.node.state(), NodeState::NoTable);
    h.advance_to(10 * MS);
    let reported = faults(&h);
    assert_eq!(reported.len(), 1);
    assert_eq!(reported[0].1.code, FaultCode::BadStoredTable);
    assert_eq!(
        reported[0].1.detail[0],
        TransferStatusCode::CrcMismatch.code()
    );
}

#[test]
fn a_stored_table_for_another_node_is_refused_at_boot_as_a_transfer_would_be() {
    // An image compiled for node 1 on node 5 (`pab-node --node-id 5 --table arm.pab`).
    let table = priority_table(&[TOPIC_A], None);
    let mut h = Harness::boot(Some(&image(&table, 1, 3)));
    assert_eq!(h.node.state(), NodeState::NoTable);
    assert_eq!(h.node.running(), None);
    h.feed(&frame(TOPIC_A, &[1]));
    assert!(h.deliveries.0.is_empty(), "no table, no delivery");
    h.advance_to(10 * MS);
    let reported = faults(&h);
    assert_eq!(reported.len(), 1, "{reported:?}");
    assert_eq!(reported[0].1.code, FaultCode::BadStoredTable);
    // The same status and detail as a transfer of that image gets: WrongNode, the image's node.
    assert_eq!(
        reported[0].1.detail,
        [TransferStatusCode::WrongNode.code(), 1, 0, 0, 0]
    );
    let (_, first) = heartbeats(&h)[0];
    assert_eq!((first.state, first.table_version), (NodeState::NoTable, 0));
}

#[test]
fn a_stored_table_of_version_0_is_refused_at_boot_as_a_transfer_would_be() {
    let table = priority_table(&[TOPIC_A], None);
    let mut h = Harness::boot(Some(&image(&table, Harness::NODE_ID, 0)));
    assert_eq!(h.node.state(), NodeState::NoTable);
    h.advance_to(10 * MS);
    let reported = faults(&h);
    assert_eq!(reported.len(), 1, "{reported:?}");
    assert_eq!(reported[0].1.code, FaultCode::BadStoredTable);
    assert_eq!(
        reported[0].1.detail,
        [TransferStatusCode::OlderVersion.code(), 0, 0, 0, 0]
    );
}

#[test]
fn the_stored_table_fault_is_repeated_with_each_heartbeat_until_a_table_runs() {
    // A tool that starts listening after the boot still learns why the node has no table.
    let table = priority_table(&[TOPIC_A], None);
    let mut bytes = image(&table, Harness::NODE_ID, 3);
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    let mut h = Harness::boot(Some(&bytes));
    h.advance_to(3 * S + 10 * MS);
    let reported = faults(&h);
    let times: Vec<u64> = reported.iter().map(|(t, _)| *t).collect();
    assert_eq!(times, vec![0, S, 2 * S, 3 * S], "{reported:?}");
    for (_, fault) in &reported {
        assert_eq!(fault.code, FaultCode::BadStoredTable);
        assert_eq!(fault.count, 1);
        assert_eq!(fault.detail[0], TransferStatusCode::CrcMismatch.code());
    }
    // A table pushed meanwhile ends it.
    h.push(&image(&table, Harness::NODE_ID, 4));
    assert_eq!(h.running_version(), Some(4));
    let pushed_at = h.now;
    h.advance_to(pushed_at + 3 * S);
    assert!(
        faults(&h)
            .iter()
            .all(|(t, f)| *t <= pushed_at || f.code != FaultCode::BadStoredTable),
        "{:?}",
        faults(&h)
    );
}

/// A topic frame skips the node's duties while none waits (`Node::on_frame`, before the next
/// heartbeat, with no transfer, fault, diagnostic stream or per-frame mechanism): the shortcut
/// must never hold back what the duties would have sent. Two nodes take the same frames and no
/// poll between them; one also runs its duties after every frame (`Node::poll`). Heartbeats fall
/// due between frames, faults are raised by malformed commands and by a full outbox (gateway
/// re-publications not drained), the diagnostic stream goes on and off: both send the same
/// frames at the same instants.
#[test]
fn a_topic_frame_that_skips_the_duties_holds_back_nothing_they_would_send() {
    let table = priority_table(&[TOPIC_A, TOPIC_B], Some(GATEWAY_OUT));
    let bytes = image(&table, Harness::NODE_ID, 1);
    let mut shortcut = Harness::boot(Some(&bytes));
    let mut polled = Harness::boot(Some(&bytes));
    assert_eq!(shortcut.sent, polled.sent);
    let command = |rate_hz| {
        Message::DiagnosticControl(DiagnosticControl { rate_hz, ports: 1 })
            .to_frame(protocol::TOOL, Harness::NODE_ID)
    };
    let malformed = Frame::data(
        protocol::FrameId::new(Service::DiagnosticControl, protocol::TOOL, Harness::NODE_ID).id(),
        &[1],
    )
    .unwrap();
    let mut seed = 0x2545_f491_u32;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed % 100
    };
    let (mut sent_a, mut sent_b) = (Vec::new(), Vec::new());
    let (mut skipped_polls, mut faults_raised) = (0, 0);
    let mut t = 0;
    while t < 4 * S {
        t += MS + u64::from(next()) * 100;
        let now = Instant::from_micros(t);
        // 300 ms of every second, as on a congested bus, topic frames only and nothing drained:
        // the outbox fills, and the frames' re-publications raise TxOverrun faults between two
        // heartbeats, which go out at the first frame after.
        let congested = (8..14).contains(&((t / (50 * MS)) % 20));
        let frame = match next() % if congested { 70 } else { 100 } {
            0..=44 => frame(TOPIC_A, &[t as u8]),
            45..=69 => frame(TOPIC_B, &[t as u8]),
            70..=84 => frame(0x555, &[]),
            85..=89 => {
                faults_raised += 1;
                malformed
            }
            90..=92 => command(10),
            _ => command(0),
        };
        for (h, also_poll) in [(&mut shortcut, false), (&mut polled, true)] {
            let step = h.node.on_frame(&frame, now, &mut h.deliveries);
            assert_eq!(step, Step::Continue);
            if also_poll {
                assert_eq!(h.node.poll(now, &mut h.deliveries), Step::Continue);
            }
        }
        if !congested {
            while let Some(f) = shortcut.node.next_outgoing() {
                sent_a.push((t, f));
            }
            while let Some(f) = polled.node.next_outgoing() {
                sent_b.push((t, f));
            }
            assert_eq!(sent_a, sent_b, "at {t} µs");
        } else {
            skipped_polls += 1;
        }
    }
    let kinds = |sent: &[(u64, Frame)]| {
        sent.iter()
            .filter_map(|(_, f)| protocol::FrameId::decode(&f.id()).map(|id| id.service))
            .collect::<Vec<_>>()
    };
    // What the comparison covered: heartbeats, faults (malformed commands and the outbox's
    // overruns), the diagnostic stream.
    let services = kinds(&sent_a);
    for service in [Service::Heartbeat, Service::Fault, Service::Diagnostic] {
        assert!(
            services.contains(&service),
            "{service:?} never sent: {services:?}"
        );
    }
    assert!(skipped_polls > 0 && faults_raised > 0);
    assert!(
        shortcut.node.counters().errors > faults_raised,
        "no outbox overrun: {:?}",
        shortcut.node.counters()
    );
}
