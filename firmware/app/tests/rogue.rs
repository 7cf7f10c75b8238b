//! Rogue participants on the bus (issue 11), against the node's own code in virtual time: each
//! attack the threat model in docs/can-protocol.md names, and what stops it. A rogue here is any
//! station that can send and receive frames but does not hold the node's key.

use crate::common;

use common::*;
use pab_core::auth::Key;
use pab_core::isotp::{TxEvent, pci};
use pab_core::protocol::{
    self, AuthFailure, DiagnosticControl, FaultCode, Message, OPEN_REPLACE, TransferStatusCode,
};

const MS: u64 = 1_000;
const KEY: Key = Key::from_bytes([0x5A; 16]);
const WRONG_KEY: Key = Key::from_bytes([0xA5; 16]);
const SALT: u32 = 0x0BAD_5EED;

fn v(version: u32) -> Vec<u8> {
    image(
        &priority_table(&[TOPIC_B, TOPIC_A], None),
        Harness::NODE_ID,
        version,
    )
}

fn v1() -> Vec<u8> {
    image(&priority_table(&[TOPIC_A], None), Harness::NODE_ID, 1)
}

fn keyed_v1() -> Harness {
    Harness::boot_keyed(Some(&v1()), &KEY, SALT)
}

fn last_status(h: &Harness) -> protocol::TransferStatus {
    *h.statuses(protocol::TOOL).last().expect("the node answers")
}

const STREAM_ON: DiagnosticControl = DiagnosticControl {
    rate_hz: 200,
    ports: 0xFFFF,
};

fn stream_on(h: &mut Harness) -> bool {
    h.advance_to(h.now + 1_100 * MS);
    let from = h.now - 1_000 * MS;
    h.messages_since(from)
        .iter()
        .any(|(_, _, m)| matches!(m, Message::TableStatus(s) if s.diagnostic))
}

#[test]
fn a_keyed_node_says_so_in_its_heartbeat_and_an_unkeyed_one_does_not() {
    let keyed = keyed_v1();
    assert!(keyed.messages_since(0).iter().any(|(_, _, m)| matches!(m,
        Message::TableStatus(s) if s.keyed)));
    let unkeyed = Harness::boot(Some(&v1()));
    assert!(unkeyed.messages_since(0).iter().any(|(_, _, m)| matches!(m,
        Message::TableStatus(s) if !s.keyed)));
}

#[test]
fn the_key_holder_pushes_and_gets_a_receipt_that_verifies() {
    let mut h = keyed_v1();
    let bytes = v(2);
    let (end, nonce) = h.push_keyed(&bytes, &KEY, 0);
    assert_eq!(end, TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
    assert_eq!(h.running_version(), Some(2));
    assert_eq!(
        h.stored,
        vec![bytes.clone()],
        "the image is stored without its MAC"
    );
    let (status, tag) = *h.receipts(protocol::TOOL).last().expect("a receipt");
    let payload: [u8; 8] = Message::TransferStatus(status)
        .to_frame(Harness::NODE_ID, 0)
        .payload()
        .try_into()
        .unwrap();
    let crc = pab_core::image::read_header(&bytes).unwrap().crc;
    let auth = pab_core::auth::Authenticator::new(&KEY);
    assert!(auth.verify_receipt(Harness::NODE_ID, nonce, &payload, crc, true, &tag));
    // A receipt is bound to its nonce, status, CRC and stored flag: none other verifies.
    assert!(!auth.verify_receipt(Harness::NODE_ID, nonce + 1, &payload, crc, true, &tag));
    assert!(!auth.verify_receipt(Harness::NODE_ID, nonce, &payload, crc, false, &tag));
    let wrong = pab_core::auth::Authenticator::new(&WRONG_KEY);
    assert!(!wrong.verify_receipt(Harness::NODE_ID, nonce, &payload, crc, true, &tag));
}

/// Attack: replace a node's table without the key (a plain push, as pabctl did before keys).
#[test]
fn a_table_pushed_without_the_key_is_ignored_and_the_old_table_runs() {
    let mut h = keyed_v1();
    let end = h.push(&v(2));
    assert_ne!(
        end,
        TxEvent::Done,
        "the node gives no flow control to an unopened transfer"
    );
    assert_eq!(h.running_version(), Some(1));
    assert!(h.stored.is_empty());
    assert!(h.auth_failures_since(0).contains(&AuthFailure::Unopened));
}

/// Attack: push version 0xFFFFFFFF, after which no later table would ever be accepted.
#[test]
fn the_version_lockout_needs_the_key_and_the_key_holder_can_undo_it() {
    let mut h = keyed_v1();
    h.push(&v(u32::MAX));
    assert_eq!(h.running_version(), Some(1), "no lockout without the key");
    // A node that does run version 0xFFFFFFFF (pushed before it had a key): the key holder
    // replaces it with the keyed version reset, and only with it.
    let mut h = Harness::boot_keyed(Some(&v(u32::MAX)), &KEY, SALT);
    h.push_keyed(&v(2), &KEY, 0);
    assert_eq!(last_status(&h).status, TransferStatusCode::OlderVersion);
    assert_eq!(h.running_version(), Some(u32::MAX));
    h.advance_to(h.now + 10 * MS);
    h.push_keyed(&v(2), &KEY, OPEN_REPLACE);
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
    assert_eq!(h.running_version(), Some(2));
}

/// Attack: hold the single transfer slot with a trickle (a first frame announcing 8 KiB, then
/// one consecutive frame every 990 ms, just inside N_Cr): it held the slot about 19 minutes.
#[test]
fn a_trickle_loses_the_slot_within_its_length_budget() {
    let mut h = Harness::boot(Some(&v1()));
    let big = vec![0u8; 8192];
    let (first, _) = pci::encode_first(8192, &big).unwrap();
    h.feed(
        &Message::TableTransfer {
            data: first,
            len: 8,
        }
        .to_frame(protocol::TOOL, Harness::NODE_ID),
    );
    // 1 s + 10 ms per consecutive frame: 1170 frames, 12.7 s.
    let budget = 1_000 * MS + 1170 * 10 * MS;
    let mut sn = 1u8;
    while h.now < budget + 1_000 * MS {
        h.advance_to(h.now + 990 * MS);
        let cf = pci::encode_consecutive(sn, &[0; 7], 0xCC).unwrap();
        sn = (sn + 1) & 0x0F;
        h.feed(
            &Message::TableTransfer { data: cf, len: 8 }.to_frame(protocol::TOOL, Harness::NODE_ID),
        );
    }
    let timeouts: Vec<_> = h
        .messages_since(0)
        .into_iter()
        .filter_map(|(t, _, m)| match m {
            Message::TransferStatus(s) if s.status == TransferStatusCode::Timeout => Some((t, s)),
            _ => None,
        })
        .collect();
    assert_eq!(timeouts.len(), 1, "{timeouts:?}");
    assert_eq!(
        timeouts[0].0, budget,
        "the slot is lost at the budget's end"
    );
    assert_eq!(timeouts[0].1.detail, 1, "detail 1: too slow, not N_Cr");
    // The tool's push goes through right after.
    assert_eq!(h.push(&v(2)), TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
}

/// A station with another source id cannot take the slot at all (it used to get `Busy` answers
/// and could hold the slot against the tool).
#[test]
fn a_transfer_from_another_source_than_the_tool_is_ignored() {
    let mut h = Harness::boot(Some(&v1()));
    let bytes = v(2);
    let (first, _) = pci::encode_first(bytes.len() as u32, &bytes).unwrap();
    let intruder = 42;
    h.feed(
        &Message::TableTransfer {
            data: first,
            len: 8,
        }
        .to_frame(intruder, Harness::NODE_ID),
    );
    assert!(h.statuses(intruder).is_empty(), "no answer to a rogue");
    assert!(
        h.messages_since(0)
            .iter()
            .all(|(_, id, _)| id.destination != intruder)
    );
    h.advance_to(h.now + 200 * MS);
    assert!(h.auth_failures_since(0).contains(&AuthFailure::NotTool));
    assert_eq!(h.push(&bytes), TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::Applied);
}

/// Attack: a first frame with the tool's source id in the middle of a real push. On a node
/// without a key it interrupts the push (ISO-TP cannot tell who sent it); on a keyed node it is
/// ignored, and so is a consecutive frame out of sequence.
#[test]
fn a_forged_first_frame_does_not_abort_a_keyed_push() {
    let forge = |h: &mut Harness, index: usize, data: [u8; 8]| {
        if index == 3 {
            let (first, _) = pci::encode_first(100, &[0; 100]).unwrap();
            h.feed(
                &Message::TableTransfer {
                    data: first,
                    len: 8,
                }
                .to_frame(protocol::TOOL, Harness::NODE_ID),
            );
            let stray = pci::encode_consecutive(9, &[0; 7], 0xCC).unwrap();
            h.feed(
                &Message::TableTransfer {
                    data: stray,
                    len: 8,
                }
                .to_frame(protocol::TOOL, Harness::NODE_ID),
            );
        }
        Some(data)
    };
    let mut keyed = keyed_v1();
    let (end, _) = keyed.push_keyed_with(&v(2), &KEY, 0, forge);
    assert_eq!(end, TxEvent::Done);
    assert_eq!(last_status(&keyed).status, TransferStatusCode::Applied);
    let failures = keyed.auth_failures_since(0);
    assert!(failures.contains(&AuthFailure::Unopened), "{failures:?}");
    // The limit without a key, stated by the threat model.
    let mut unkeyed = Harness::boot(Some(&v1()));
    unkeyed.push_with(&v(2), protocol::TOOL, forge);
    assert!(
        unkeyed
            .statuses(protocol::TOOL)
            .iter()
            .any(|s| s.status == TransferStatusCode::Interrupted)
    );
    assert_eq!(unkeyed.running_version(), Some(1));
}

/// Attack: switch the diagnostic stream to its highest rate without the key.
#[test]
fn switching_the_diagnostic_stream_needs_the_key() {
    let mut h = keyed_v1();
    let plain = Message::DiagnosticControl(STREAM_ON);
    h.feed(&plain.to_frame(protocol::TOOL, Harness::NODE_ID));
    h.feed(&plain.to_frame(protocol::TOOL, protocol::BROADCAST));
    assert!(!stream_on(&mut h));
    assert!(h.auth_failures_since(0).contains(&AuthFailure::Missing));
    // A tagged broadcast is refused too: a tag is over one node's challenge.
    let nonce = h.challenge(protocol::TOOL, &KEY).unwrap();
    let tagged = Harness::tagged_control(&KEY, nonce, STREAM_ON);
    let broadcast = Message::decode(&tagged)
        .unwrap()
        .1
        .to_frame(protocol::TOOL, protocol::BROADCAST);
    h.feed(&broadcast);
    assert!(!stream_on(&mut h));
    assert!(h.auth_failures_since(0).contains(&AuthFailure::Broadcast));
    // The key holder switches it.
    h.keyed_command(&KEY, STREAM_ON);
    assert!(stream_on(&mut h));
}

/// Attack: replay a captured command or push (the same frames, the tool's challenge request
/// included, later), also after the node rebooted (a new boot salt: no challenge of an earlier
/// boot ever comes back).
#[test]
fn replayed_commands_and_pushes_are_refused_also_after_a_reboot() {
    let mut h = keyed_v1();
    let off = DiagnosticControl {
        rate_hz: 0,
        ports: 0,
    };
    let captured_on = h.keyed_command(&KEY, STREAM_ON);
    assert!(stream_on(&mut h));
    h.keyed_command(&KEY, off);
    assert!(!stream_on(&mut h));
    // Replay, without and with a fresh challenge outstanding (the rogue can ask for one).
    h.feed(&captured_on);
    h.challenge(42, &KEY).unwrap();
    h.feed(&captured_on);
    assert!(!stream_on(&mut h));
    let failures = h.auth_failures_since(0);
    assert!(failures.contains(&AuthFailure::Stale), "{failures:?}");
    // A captured push: record the tool's frames, then replay them all.
    let mut push = keyed_v1();
    const TOOL_NONCE: u64 = 0x70_0150;
    let mut captured = vec![
        Message::ChallengeRequest {
            tool_nonce: TOOL_NONCE,
        }
        .to_frame(protocol::TOOL, Harness::NODE_ID),
    ];
    let nonce = push
        .challenge_with(protocol::TOOL, TOOL_NONCE, &KEY)
        .unwrap();
    let auth = pab_core::auth::Authenticator::new(&KEY);
    let bytes = v(2);
    let mut message = bytes.clone();
    message.extend_from_slice(&auth.image_mac(Harness::NODE_ID, nonce, 0, &bytes));
    let length = message.len() as u16;
    let open = Message::TransferOpen(protocol::TransferOpen {
        length,
        flags: 0,
        tag: auth.open_tag(Harness::NODE_ID, nonce, length, 0),
    })
    .to_frame(protocol::TOOL, Harness::NODE_ID);
    captured.push(open);
    push.feed(&open);
    push.push_with(&message, protocol::TOOL, |_, _, data| {
        captured.push(
            Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, Harness::NODE_ID),
        );
        Some(data)
    });
    assert_eq!(push.running_version(), Some(2), "the original push works");
    // Replayed to the same node in the same boot (the rogue first asks for a fresh challenge):
    // the replayed request gets a new node nonce, so the open's tag is over another exchange
    // than the node's, and no transfer even starts.
    let statuses = push.statuses(protocol::TOOL).len();
    push.challenge(42, &KEY).unwrap();
    for frame in &captured {
        push.feed(frame);
        push.advance_to(push.now + 100);
    }
    push.advance_to(push.now + 2_000 * MS);
    assert_eq!(
        push.statuses(protocol::TOOL).len(),
        statuses,
        "no transfer started"
    );
    assert_eq!(push.stored.len(), 1);
    let failures = push.auth_failures_since(0);
    assert!(failures.contains(&AuthFailure::BadTag), "{failures:?}");
    // Replayed after a reboot to a node that runs version 1 (a new boot salt).
    let replay = |salt: u32| {
        let mut victim = Harness::boot_keyed(Some(&v1()), &KEY, salt);
        for frame in &captured {
            victim.feed(frame);
            victim.advance_to(victim.now + 100);
        }
        victim.advance_to(victim.now + 2_000 * MS);
        victim.running_version()
    };
    assert_eq!(replay(SALT.wrapping_add(1)), Some(1));
    // Why the salt must never repeat for one key (boards count boots in flash, pab-node draws
    // it from the OS): with the same salt, the first challenge of a boot is the same node nonce,
    // and the replayed request brings back the tool's: the same exchange.
    assert_eq!(replay(SALT), Some(2));
    // And the command after a reboot, with the rogue holding a fresh challenge.
    let mut rebooted = Harness::boot_keyed(Some(&v1()), &KEY, SALT.wrapping_add(1));
    rebooted.challenge(42, &KEY).unwrap();
    rebooted.feed(&captured_on);
    assert!(!stream_on(&mut rebooted));
}

/// Attack: the right frames under the wrong key.
#[test]
fn a_wrong_key_is_refused_for_commands_opens_and_images() {
    let mut h = keyed_v1();
    h.keyed_command(&WRONG_KEY, STREAM_ON);
    assert!(!stream_on(&mut h));
    h.push_keyed(&v(2), &WRONG_KEY, 0);
    assert_eq!(h.running_version(), Some(1));
    let failures = h.auth_failures_since(0);
    assert!(failures.contains(&AuthFailure::BadTag), "{failures:?}");
    // A wrong tag does not use up the tool's challenge.
    let nonce = h.challenge(protocol::TOOL, &KEY).unwrap();
    h.feed(&Harness::tagged_control(&WRONG_KEY, nonce, STREAM_ON));
    h.feed(&Harness::tagged_control(&KEY, nonce, STREAM_ON));
    assert!(stream_on(&mut h));
}

/// An image whose MAC does not verify (its bytes changed after the open) is refused before its
/// header is read, with a receipt.
#[test]
fn an_image_changed_in_flight_is_refused_by_its_mac() {
    let mut h = keyed_v1();
    let (end, _) = h.push_keyed_with(&v(2), &KEY, 0, |_, index, mut data| {
        if index == 2 {
            data[3] ^= 1;
        }
        Some(data)
    });
    assert_eq!(end, TxEvent::Done);
    assert_eq!(last_status(&h).status, TransferStatusCode::Unauthenticated);
    assert_eq!(h.running_version(), Some(1));
    assert_eq!(h.receipts(protocol::TOOL).len(), 1);
}

/// Attack: use a challenge after its lifetime.
#[test]
fn a_stale_challenge_is_refused() {
    let mut h = keyed_v1();
    let nonce = h.challenge(protocol::TOOL, &KEY).unwrap();
    h.advance_to(h.now + 1_001 * MS);
    h.feed(&Harness::tagged_control(&KEY, nonce, STREAM_ON));
    assert!(!stream_on(&mut h));
    assert!(h.auth_failures_since(0).contains(&AuthFailure::Stale));
    // A new request gets a new nonce.
    assert_ne!(h.challenge(protocol::TOOL, &KEY), Some(nonce));
}

/// The node's nonce is a CMAC under its key of boot salt and counter: the key holder could
/// compute it, nobody else can predict it (with salt ‖ counter as the nonce, a rogue queued a
/// forged challenge of the next one, harvested the tool's tags and replayed them once the node
/// issued it). The Challenge binds it to the request's tool nonce.
#[test]
fn node_nonces_are_unpredictable_and_bound_to_the_request() {
    let mut h = keyed_v1();
    let auth = pab_core::auth::Authenticator::new(&KEY);
    let (node_nonce, binding) = h.challenge_answer(protocol::TOOL, 7).unwrap();
    assert_eq!(node_nonce, auth.node_nonce(Harness::NODE_ID, SALT, 1));
    assert_ne!(
        node_nonce,
        (u64::from(SALT) << 32 | 1) & pab_core::auth::NODE_NONCE_MAX
    );
    let wrong = pab_core::auth::Authenticator::new(&WRONG_KEY);
    assert_ne!(node_nonce, wrong.node_nonce(Harness::NODE_ID, SALT, 1));
    let exchange = auth.exchange(Harness::NODE_ID, 7, node_nonce);
    assert_eq!(binding, exchange.binding);
    assert_ne!(
        binding,
        auth.exchange(Harness::NODE_ID, 8, node_nonce).binding
    );
    // Every request is a new challenge, the same tool nonce again too.
    let (again, _) = h.challenge_answer(protocol::TOOL, 7).unwrap();
    assert_eq!(again, auth.node_nonce(Harness::NODE_ID, SALT, 2));
    // The tags of the exchange are over its nonce.
    let nonce = h.challenge_with(protocol::TOOL, 9, &KEY).unwrap();
    h.feed(&Harness::tagged_control(&KEY, nonce, STREAM_ON));
    assert!(stream_on(&mut h));
}

/// A request replaces the outstanding challenge: a challenge kept for a tool nonce nobody else
/// can use would let a rogue hold the node with one request a second. The rogue can so deny an
/// exchange it sees start (the tool asks again), never steer one: the tool's tag over the replaced
/// challenge is refused, and the rogue has no tag over its own.
#[test]
fn a_rogue_request_replaces_the_challenge_and_gains_nothing() {
    let mut h = keyed_v1();
    let tools = h.challenge(protocol::TOOL, &KEY).unwrap();
    let rogues = h.challenge(42, &KEY).unwrap();
    assert_ne!(rogues, tools);
    h.feed(&Harness::tagged_control(&KEY, tools, STREAM_ON));
    assert!(!stream_on(&mut h));
    assert!(h.auth_failures_since(0).contains(&AuthFailure::BadTag));
    // The tool asks again and gets through.
    h.keyed_command(&KEY, STREAM_ON);
    assert!(stream_on(&mut h));
}

/// Guessing tags: at most TAG_CHECKS_PER_SECOND checks a second, then refused unchecked.
#[test]
fn tag_checks_are_rate_limited() {
    let mut h = keyed_v1();
    let nonce = h.challenge(protocol::TOOL, &KEY).unwrap();
    let errors_before = h.node.counters().errors;
    // The challenge took one check of the second's budget (two CMACs).
    for guess in 0..u32::from(pab_app::TAG_CHECKS_PER_SECOND) - 1 {
        let mut frame = Harness::tagged_control(&WRONG_KEY, nonce, STREAM_ON);
        let mut data = [0u8; 8];
        data.copy_from_slice(frame.payload());
        data[4..].copy_from_slice(&guess.to_le_bytes());
        frame = pab_core::Frame::data(frame.id(), &data).unwrap();
        h.feed(&frame);
    }
    // The right tag in the same second is refused unchecked.
    h.feed(&Harness::tagged_control(&KEY, nonce, STREAM_ON));
    h.advance_to(h.now + 150 * MS);
    assert!(h.auth_failures_since(0).contains(&AuthFailure::RateLimited));
    assert_eq!(
        h.node.counters().errors - errors_before,
        u32::from(pab_app::TAG_CHECKS_PER_SECOND),
        "every failure is counted"
    );
    assert!(!stream_on(&mut h));
}

/// A board whose key page does not verify fails closed: no configuration at all, and a fault
/// that says why after every heartbeat group.
#[test]
fn a_locked_node_takes_no_configuration() {
    let mut h = Harness::boot_with(Some(&v1()), |node| node.lock_configuration(5));
    h.push(&v(2));
    h.feed(&Message::DiagnosticControl(STREAM_ON).to_frame(protocol::TOOL, Harness::NODE_ID));
    assert!(h.challenge(protocol::TOOL, &KEY).is_none());
    let open = protocol::TransferOpen {
        length: 300,
        flags: 0,
        tag: [0; 5],
    };
    h.feed(&Message::TransferOpen(open).to_frame(protocol::TOOL, Harness::NODE_ID));
    assert!(!stream_on(&mut h));
    assert_eq!(h.running_version(), Some(1));
    let faults: Vec<_> = h
        .messages_since(0)
        .into_iter()
        .filter_map(|(_, _, m)| match m {
            Message::Fault(f) if f.code == FaultCode::KeyPageInvalid => Some(f.detail[0]),
            _ => None,
        })
        .collect();
    assert!(
        faults.len() >= 2 && faults.iter().all(|&d| d == 5),
        "{faults:?}"
    );
    assert!(h.auth_failures_since(0).contains(&AuthFailure::Locked));
}
