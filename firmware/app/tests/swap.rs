//! Table swaps under repeated pushes: the connections a push leaves unchanged keep their state
//! (no blackout of deliveries), and saves are rate-limited without losing the newest image.

use crate::common;

use common::*;
use pab_app::DEFAULT_STORE_INTERVAL_US;
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, Message, TransferStatusCode};
use pab_core::{Connection, DecisionNode, Filter, NodeRef, Stimulation};

/// Frames of topic A every 50 ms, of topic B every 30 ms.
const A_EVERY_US: u64 = 50_000;
const B_EVERY_US: u64 = 30_000;
/// A push of the same rules, version + 1, every 300 ms.
const PUSH_EVERY_US: u64 = 300_000;
const RUN_US: u64 = 10_000_000;

/// One port, A over B, both σ = 0.1 and τ = 0.5 s: ten frames within τ make a connection active,
/// so that a connection reset every 300 ms (six frames of A) never becomes active again.
fn slow_table() -> TestTable {
    let stimulation = Stimulation::from_seconds(0.1, 0.5, 0.0).unwrap();
    let connections = [TOPIC_A, TOPIC_B].map(|id| Connection {
        filter: Filter::exact(id, false).unwrap(),
        stimulation,
    });
    let nodes = [
        DecisionNode {
            var: 0,
            high: NodeRef::deliver(0).unwrap(),
            low: NodeRef::node(1).unwrap(),
        },
        DecisionNode {
            var: 1,
            high: NodeRef::deliver(1).unwrap(),
            low: NodeRef::NOBODY,
        },
    ];
    let mut table = TestTable::new();
    table
        .push_port(&connections, &nodes, NodeRef::node(0).unwrap())
        .unwrap();
    table
}

/// What a run gave: the deliveries, the images stored, the statuses the tool got.
struct Run {
    harness: Harness,
    pushes: u32,
}

/// Runs the node for 10 s on topics A and B, with a push of the same table (version + 1) every
/// 300 ms if `pushing`; every push is driven frame by frame between the topics' frames, and
/// flow control is obeyed as the tool would. Steps of 100 µs.
fn run(pushing: bool) -> Run {
    let table = slow_table();
    let mut harness = Harness::boot(Some(&image(&table, Harness::NODE_ID, 1)));
    let mut version = 1;
    let mut pushes = 0;
    let mut sender: Option<Sender<'static>> = None;
    let mut seen = harness.sent.len();
    let mut t = 0;
    while t < RUN_US {
        if t % A_EVERY_US == 0 {
            harness.feed(&frame(TOPIC_A, &[1]));
        }
        if t % B_EVERY_US == 0 {
            harness.feed(&frame(TOPIC_B, &[2]));
        }
        if pushing && t % PUSH_EVERY_US == 0 && t > 0 {
            version += 1;
            pushes += 1;
            let bytes: &'static [u8] = image(&table, Harness::NODE_ID, version).leak();
            sender = Some(Sender::new(bytes, TxConfig::default()).unwrap());
            seen = harness.sent.len();
        }
        if let Some(tx) = sender.as_mut() {
            // Flow control the node sent to the tool since the last look.
            for (_, sent) in &harness.sent[seen..] {
                if let Ok((id, Message::TableTransfer { data, len })) = Message::decode(sent)
                    && id.destination == protocol::TOOL
                {
                    tx.on_flow_control(&data[..usize::from(len)], harness_now(&harness));
                }
            }
            seen = harness.sent.len();
            match tx.poll(harness_now(&harness)) {
                TxEvent::Send(data) => {
                    let transfer =
                        Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, 5);
                    harness.feed(&transfer);
                }
                TxEvent::WaitUntil(_) => {}
                TxEvent::Done | TxEvent::Failed(_) => sender = None,
            }
        }
        t += 100;
        harness.advance_to(t);
    }
    Run { harness, pushes }
}

fn harness_now(harness: &Harness) -> pab_core::Instant {
    pab_core::Instant::from_micros(harness.now)
}

#[test]
fn re_pushing_the_same_rules_keeps_delivering_as_without_the_pushes() {
    let quiet = run(false);
    let pushed = run(true);
    assert!(
        !quiet.harness.deliveries.0.is_empty(),
        "the scenario delivers without pushes"
    );
    // The pushes took effect: tables were applied and run.
    let applied = pushed
        .harness
        .statuses(protocol::TOOL)
        .iter()
        .filter(|status| status.status == TransferStatusCode::Applied)
        .count();
    assert!(applied >= 5, "only {applied} pushes applied");
    assert!(pushed.harness.running_version().unwrap() > 5);
    // Every delivery as without the pushes, at the same instant.
    assert_eq!(
        pushed.harness.deliveries.0.len(),
        quiet.harness.deliveries.0.len(),
        "deliveries with and without the pushes"
    );
    assert!(pushed.harness.deliveries.0 == quiet.harness.deliveries.0);
}

#[test]
fn saves_are_rate_limited_and_the_newest_image_is_stored() {
    let mut pushed = run(true);
    let saves = pushed.harness.stored.len();
    // 33 pushes in 10 s; at most one save per store interval (plus the one at the start).
    let most = (RUN_US / DEFAULT_STORE_INTERVAL_US + 1) as usize;
    assert!(pushed.pushes >= 30);
    assert!(
        (2..=most).contains(&saves),
        "{saves} saves in 10 s, at most {most} allowed"
    );
    // The saves started at least an interval apart (the harness stores at once when asked).
    let status_times: Vec<u64> = pushed
        .harness
        .messages_since(0)
        .iter()
        .filter_map(|(t, _, message)| match message {
            Message::TransferStatus(status) if status.status == TransferStatusCode::Applied => {
                Some(*t)
            }
            _ => None,
        })
        .collect();
    assert_eq!(status_times.len(), saves, "one Applied answer per save");
    for pair in status_times.windows(2) {
        assert!(pair[1] - pair[0] >= DEFAULT_STORE_INTERVAL_US, "{pair:?}");
    }
    // Once the last interval has passed, the newest running image is the last one stored.
    let end = pushed.harness.now + DEFAULT_STORE_INTERVAL_US;
    pushed.harness.advance_to(end);
    let running = pushed.harness.node.running().unwrap();
    assert!(running.stored, "the running table is stored in the end");
    let last = pushed.harness.stored.last().unwrap();
    let version = u32::from_le_bytes(last[8..12].try_into().unwrap());
    assert_eq!(version, running.header.table_version);
    assert_eq!(
        pushed.harness.node.image_to_store(),
        &last[..],
        "the stored image is the running one"
    );
}

#[test]
fn a_table_applied_within_the_interval_is_answered_once_it_is_stored() {
    let table = priority_table(&[TOPIC_A], None);
    let mut h = Harness::boot(None);
    assert_eq!(h.push(&image(&table, Harness::NODE_ID, 1)), TxEvent::Done);
    assert_eq!(h.stored.len(), 1, "the first save goes at once");
    let first_save = h.now;
    assert_eq!(h.push(&image(&table, Harness::NODE_ID, 2)), TxEvent::Done);
    // Version 2 runs at once, but is not stored yet, and the tool has no answer for it yet.
    assert_eq!(h.running_version(), Some(2));
    assert!(!h.node.running().unwrap().stored);
    assert_eq!(h.stored.len(), 1);
    assert_eq!(h.statuses(protocol::TOOL).len(), 1);
    // A third push meanwhile: the node is busy with the second.
    let before = h.statuses(protocol::TOOL).len();
    let third = image(&table, Harness::NODE_ID, 3);
    h.push_with(&third, protocol::TOOL, |_, index, data| {
        (index == 0).then_some(data)
    });
    let statuses = h.statuses(protocol::TOOL);
    assert_eq!(statuses[before].status, TransferStatusCode::Busy);
    assert_eq!(h.running_version(), Some(2));
    // The interval passes: version 2 is stored and then answered.
    h.advance_to(first_save + DEFAULT_STORE_INTERVAL_US);
    assert_eq!(h.stored.len(), 2);
    let last = h.statuses(protocol::TOOL).last().copied().unwrap();
    assert_eq!(last.status, TransferStatusCode::Applied);
    assert_eq!(last.running_version, 2);
    assert!(h.node.running().unwrap().stored);
}
