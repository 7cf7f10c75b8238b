//! Sealed coordination on a keyed node (docs/can-protocol.md, "Sealed coordination"): Gates, BLE
//! claims and filter commands are applied only once their seal verifies with a freshness above
//! the last accepted from their sender; a forged frame, a forged seal and a replayed frame with
//! its seal are refused and counted. The senders are played by the test with pab-core's
//! `Sealer`, the code the nodes and `pab-intent` seal with; the node is the boards' code.

use crate::common;

use common::*;
use pab_core::Frame;
use pab_core::auth::{Authenticator, Key};
use pab_core::protocol::{
    AuthFailure, BROADCAST, FaultCode, FilterProfile, FrameId, INTENTION, Message, Seal,
};
use pab_core::seal::{HOLD_US, Sealer};

const MS: u64 = 1_000;
const KEY: Key = Key::from_bytes(*b"sealed-key-16byt");

/// A sender on the bus: its id and its seals.
struct Sender {
    id: u8,
    authenticator: Authenticator,
    sealer: Sealer,
}

impl Sender {
    fn new(id: u8, epoch: u32) -> Sender {
        Sender {
            id,
            authenticator: Authenticator::new(&KEY),
            sealer: Sealer::new(epoch),
        }
    }

    /// `frame` and its seal, as the sender puts them on the bus.
    fn sealed(&mut self, frame: Frame) -> [Frame; 2] {
        let seal = self
            .sealer
            .seal(&self.authenticator, self.id, &frame)
            .expect("a sealable frame");
        [frame, seal]
    }

    /// Answers the freshness requests the node sent it since `from` (sent index).
    fn answer(&mut self, h: &mut Harness, from: usize) -> usize {
        let requests: Vec<u64> = h.sent[from..]
            .iter()
            .filter_map(|(_, frame)| match Message::decode(frame) {
                Ok((id, Message::FreshnessRequest { nonce })) if id.destination == self.id => {
                    Some(nonce)
                }
                _ => None,
            })
            .collect();
        for &nonce in &requests {
            let frames = self
                .sealer
                .answer(&self.authenticator, self.id, Harness::NODE_ID, nonce)
                .unwrap();
            feed_all(h, &frames);
        }
        requests.len()
    }
}

fn feed_all(h: &mut Harness, frames: &[Frame]) {
    for frame in frames {
        h.feed(frame);
    }
}

/// The Unauthenticated faults since `from`: (reason, sealed kind, source).
fn refusals(h: &Harness, from: u64) -> Vec<(AuthFailure, u8, u8)> {
    h.messages_since(from)
        .into_iter()
        .filter_map(|(_, _, message)| match message {
            Message::Fault(fault) if fault.code == FaultCode::Unauthenticated => Some((
                AuthFailure::from_code(fault.detail[0])?,
                fault.detail[1],
                fault.detail[2],
            )),
            _ => None,
        })
        .collect()
}

/// Brings `sender` in sync with the node: a first sealed frame is refused `Unsynced` and makes
/// the node ask; the answer makes the sender known. Then the node's errors are counted from 0.
fn synchronise(h: &mut Harness, sender: &mut Sender, first: Frame) {
    let from = h.sent.len();
    let since = h.now;
    feed_all(h, &sender.sealed(first));
    assert_eq!(
        refusals(h, since),
        [(AuthFailure::Unsynced, kind_of(&first), sender.id)]
    );
    assert_eq!(sender.answer(h, from), 1, "the node asked once");
    h.advance_to(h.now + 150 * MS);
}

/// What a seal of `frame` names as its kind.
fn kind_of(frame: &Frame) -> u8 {
    pab_core::seal::sealed_kind(frame).unwrap().0
}

/// A rogue's seal for `frame`: a made-up tag with a plausible counter.
fn forged_seal(frame: &Frame, source: u8, destination: u8, counter: u16) -> Frame {
    Message::Seal(Seal {
        kind: kind_of(frame),
        digest: Seal::digest_of(frame.payload()),
        counter,
        tag: [0xA5, 0x5A, 0x0F, 0xF0],
    })
    .to_frame(source, destination)
}

#[test]
fn filter_commands_apply_only_sealed_and_a_forged_or_replayed_one_is_refused() {
    let mut h = Harness::boot_keyed(Some(&crate::filters::filtered_image()), &KEY, 1);
    let mut intention = Sender::new(INTENTION, 0xC0FFEE);
    let profile = |profile: u8, sequence: u16| {
        Message::FilterProfile(FilterProfile { profile, sequence })
            .to_frame(INTENTION, Harness::NODE_ID)
    };
    // The profile in force.
    let profile_now = |h: &Harness| h.node.arbiter().unwrap().filter_profile();
    // Unsealed on a keyed node: held, never applied (a node without a key would apply it).
    assert_eq!(profile_now(&h), Some(0));
    h.feed(&profile(1, 1));
    h.advance_to(h.now + 150 * MS);
    assert_eq!(profile_now(&h), Some(0));

    synchronise(&mut h, &mut intention, profile(1, 2));
    assert_eq!(profile_now(&h), Some(0), "refused until synchronised");
    let since = h.now;
    let opened = intention.sealed(profile(1, 3));
    feed_all(&mut h, &opened);
    assert_eq!(profile_now(&h), Some(1), "sealed and fresh: applied");
    assert_eq!(
        crate::filters::statuses(&h, since)
            .iter()
            .map(|status| status.sequence)
            .collect::<Vec<_>>(),
        [3],
        "and answered"
    );

    // A rogue's profile 0 (every filtered connection closed) under the intention node's id:
    // with a made-up seal, then with none.
    h.advance_to(h.now + 150 * MS);
    let since = h.now;
    let errors = h.node.counters().errors;
    let rogue = profile(0, 4);
    feed_all(
        &mut h,
        &[rogue, forged_seal(&rogue, INTENTION, Harness::NODE_ID, 4)],
    );
    h.advance_to(h.now + 150 * MS);
    assert_eq!(
        refusals(&h, since),
        [(AuthFailure::BadSeal, 0x17, INTENTION)]
    );
    assert_eq!(profile_now(&h), Some(1));
    assert_eq!(h.node.counters().errors, errors + 1);

    // The intention node moves on to profile 2; the rogue replays its recorded profile 1 with
    // its seal: an older counter, refused.
    feed_all(&mut h, &intention.sealed(profile(2, 5)));
    assert_eq!(profile_now(&h), Some(2));
    h.advance_to(h.now + 150 * MS);
    let since = h.now;
    feed_all(&mut h, &opened);
    h.advance_to(h.now + 150 * MS);
    assert_eq!(
        refusals(&h, since),
        [(AuthFailure::BadSeal, 0x17, INTENTION)]
    );
    assert_eq!(profile_now(&h), Some(2), "the replay changed nothing");

    // The unsealed rogue frame sent earlier is refused once it outwaits its seal.
    let since = h.now;
    h.feed(&rogue);
    h.advance_to(h.now + HOLD_US + 10 * MS);
    feed_all(&mut h, &intention.sealed(profile(1, 6)));
    assert!(refusals(&h, since).contains(&(AuthFailure::Unsealed, 0x17, INTENTION)));
    assert_eq!(profile_now(&h), Some(1));
}

#[test]
fn claims_apply_only_sealed_and_a_replayed_one_does_not_hold_the_task() {
    use crate::ble::{delivered_at, peer, sees};
    let mut h = Harness::boot_keyed(Some(&crate::ble::image_with_group()), &KEY, 7);
    let mut rival = Sender::new(2, 0xB0B);
    // The node sees its target (eligibility 50); its rival offers 80, sealed.
    sees(&mut h, 0, 50);
    synchronise(&mut h, &mut rival, peer(2, 80));
    let better = rival.sealed(peer(2, 80));
    feed_all(&mut h, &better);
    for _ in 0..3 {
        let t = h.now + 50 * MS;
        sees(&mut h, t, 50);
        assert!(
            !delivered_at(&h, h.now),
            "the sealed better claim holds the task"
        );
    }
    // The rival falls silent; a rogue replays its last claim and seal every period: refused,
    // so the rival's claim goes stale and the node takes the task over.
    let since = h.now;
    for _ in 0..4 {
        h.advance_to(h.now + 100 * MS);
        feed_all(&mut h, &better);
        let t = h.now + 10 * MS;
        sees(&mut h, t, 50);
    }
    assert!(delivered_at(&h, h.now), "a replayed claim keeps no task");
    assert!(
        refusals(&h, since)
            .iter()
            .all(|r| *r == (AuthFailure::BadSeal, Seal::CLAIM, 2))
    );
    assert!(!refusals(&h, since).is_empty());
    // A forged claim of 0xFFFF from a node that is not a member, with a made-up seal: refused.
    let since = h.now;
    let forged = peer(9, 0xFFFF);
    feed_all(&mut h, &[forged, forged_seal(&forged, 9, BROADCAST, 1)]);
    let t = h.now + 10 * MS;
    sees(&mut h, t, 50);
    assert!(delivered_at(&h, h.now));
    h.advance_to(h.now + 150 * MS);
    assert_eq!(
        refusals(&h, since),
        [(AuthFailure::Unsynced, Seal::CLAIM, 9)]
    );
}

#[cfg(feature = "dynamics")]
mod gates {
    use super::*;
    use pab_core::dynamics::{GATE_SLOT_FILTER, GateLink, GateSource};
    use pab_core::protocol::Gates;
    use pab_core::{Connection, DecisionNode, Filter, Gain, NodeRef, Stimulation, Table};

    const CMD: u32 = 0x100;
    const OWNER: u8 = 1;

    /// Port 0: CMD delivers iff the gate of behaviour 0 of node 1's group 0 (2 behaviours) is
    /// open.
    fn reader_image() -> Vec<u8> {
        let connection = |filter| Connection {
            filter,
            stimulation: Stimulation::new(Gain::ONE, 50_000, 0).unwrap(),
        };
        let nodes = [
            DecisionNode {
                var: 0,
                low: NodeRef::NOBODY,
                high: NodeRef::node(1).unwrap(),
            },
            DecisionNode {
                var: 1,
                low: NodeRef::NOBODY,
                high: NodeRef::deliver(0).unwrap(),
            },
        ];
        let mut table: Table = Table::new();
        table
            .push_port(
                &[
                    connection(Filter::exact(CMD, false).unwrap()),
                    connection(GATE_SLOT_FILTER),
                ],
                &nodes,
                NodeRef::node(0).unwrap(),
            )
            .unwrap();
        let source = GateSource {
            owner: OWNER,
            group: 0,
            behaviours: 2,
        };
        let link = GateLink {
            source: 0,
            behaviour: 0,
            port: 0,
            connection: 1,
        };
        table.push_dynamics(&[], &[source], &[link]).unwrap();
        image(&table, Harness::NODE_ID, 1)
    }

    fn gates(mask: u32, changes: u8) -> Frame {
        Message::Gates(Gates {
            group: 0,
            behaviours: 2,
            mask,
            changes,
        })
        .to_frame(OWNER, BROADCAST)
    }

    fn delivers(h: &mut Harness) -> bool {
        let before = h.deliveries.0.len();
        h.feed(&frame(CMD, &[1]));
        h.deliveries.0.len() > before
    }

    #[test]
    fn gates_apply_only_sealed_and_a_forged_or_replayed_frame_is_refused() {
        let mut h = Harness::boot_keyed(Some(&reader_image()), &KEY, 3);
        let mut owner = Sender::new(OWNER, 0xD00D);
        synchronise(&mut h, &mut owner, gates(0, 0));
        let closed = owner.sealed(gates(0, 0));
        feed_all(&mut h, &closed);
        assert!(!delivers(&mut h));
        // Unsealed, an open gate is not read.
        h.feed(&gates(1, 1));
        assert!(!delivers(&mut h));
        feed_all(&mut h, &owner.sealed(gates(1, 1)));
        assert!(delivers(&mut h), "sealed: the gate is open");

        // A rogue closes the gate with a made-up seal, then replays the owner's recorded
        // closed frame with its seal: both refused, the gate stays open. The owner repeats its
        // gates every 100 ms meanwhile (a reader closes a silent group's gates after 300 ms).
        let since = h.now;
        let errors = h.node.counters().errors;
        h.advance_to(h.now + 100 * MS);
        feed_all(&mut h, &owner.sealed(gates(1, 1)));
        let rogue = gates(0, 2);
        feed_all(&mut h, &[rogue, forged_seal(&rogue, OWNER, BROADCAST, 3)]);
        assert!(delivers(&mut h));
        h.advance_to(h.now + 100 * MS);
        feed_all(&mut h, &owner.sealed(gates(1, 1)));
        h.advance_to(h.now + 50 * MS);
        feed_all(&mut h, &closed);
        assert!(delivers(&mut h), "the replayed frame closed nothing");
        h.advance_to(h.now + 50 * MS);
        feed_all(&mut h, &owner.sealed(gates(1, 1)));
        assert_eq!(
            refusals(&h, since),
            [
                (AuthFailure::BadSeal, 0x07, OWNER),
                (AuthFailure::BadSeal, 0x07, OWNER)
            ]
        );
        assert_eq!(h.node.counters().errors, errors + 2);
        // The owner's own next frame still applies.
        feed_all(&mut h, &owner.sealed(gates(0, 3)));
        assert!(!delivers(&mut h));
    }
}

#[test]
fn a_keyed_node_seals_its_claims_and_answers_freshness_requests() {
    let salt = 11;
    let mut h = Harness::boot_keyed(Some(&crate::ble::image_with_group()), &KEY, salt);
    h.advance_to(250 * MS);
    let authenticator = Authenticator::new(&KEY);
    // Every claim is followed by its seal, its counter counting from 1 in epoch `salt`.
    let sent: Vec<Frame> = h.sent.iter().map(|(_, frame)| *frame).collect();
    let mut counter = 0u32;
    let mut claims = 0;
    for (at, claim) in sent.iter().enumerate() {
        if pab_core::ble::Claim::decode(claim).is_err() {
            continue;
        }
        claims += 1;
        // Its seal ranks after it (priority 5): the heartbeat group's reports may go between.
        let seal = sent[at + 1..]
            .iter()
            .find_map(|frame| match Message::decode(frame) {
                Ok((id, Message::Seal(seal))) => Some((id, seal)),
                _ => None,
            });
        let Some((id, seal)) = seal else {
            panic!("a claim without its seal after it");
        };
        counter += 1;
        assert_eq!((id.source, id.destination), (Harness::NODE_ID, BROADCAST));
        assert_eq!((seal.kind, seal.counter), (Seal::CLAIM, counter as u16));
        let freshness = u64::from(salt) << 32 | u64::from(counter);
        assert!(authenticator.verify_seal(
            Harness::NODE_ID,
            claim.raw_id().0,
            claim.payload(),
            freshness,
            &seal.tag
        ));
    }
    assert_eq!(claims, 3, "claims at 0, 100 and 200 ms");
    // A freshness request: the answer says where the counter stands, sealed over the nonce.
    let from = h.sent.len();
    h.feed(&Message::FreshnessRequest { nonce: 0x1234 }.to_frame(40, Harness::NODE_ID));
    let answer: Vec<(FrameId, Message, Frame)> = h.sent[from..]
        .iter()
        .map(|(_, frame)| {
            let (id, message) = Message::decode(frame).unwrap();
            (id, message, *frame)
        })
        .collect();
    let [
        (a_id, Message::Freshness { epoch, counter: c }, a_frame),
        (_, Message::Seal(seal), _),
    ] = answer.as_slice()
    else {
        panic!("not a Freshness and its seal: {answer:?}");
    };
    assert_eq!((a_id.destination, *epoch, *c), (40, salt, counter));
    assert!(authenticator.verify_seal(
        Harness::NODE_ID,
        a_frame.raw_id().0,
        a_frame.payload(),
        0x1234,
        &seal.tag
    ));
}
