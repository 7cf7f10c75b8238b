//! The schema server on a node with a key (docs/can-protocol.md, "Authenticated configuration"):
//! schemas move the robot, so only the key holder's are taken, each transfer opened as a table's
//! is (a challenge, a TransferOpen for a schema, the message and its MAC) and confirmed by a
//! Receipt; the emergency stop and the abort stay open to anyone.

use crate::common;
use crate::schema_rig;

use common::*;
use pab_core::auth::{Authenticator, Key};
use pab_core::protocol::{
    AuthFailure, BROADCAST, Message, OPEN_REPLACE, OPEN_SCHEMA, SchemaAck, SchemaOutcome,
    SchemaTrigger, TOOL, TransferOpen,
};
use pab_core::schema::{Schema, build};
use schema_rig::*;

const KEY: Key = Key::from_bytes([0x5A; 16]);

fn keyed() -> Harness {
    let mut h = Harness::boot_keyed(Some(&image(&schema_table(), Harness::NODE_ID, 1)), &KEY, 7);
    report(&mut h, [0, 0, 0]);
    h.advance_to(h.now + 2_000);
    h
}

/// The schema message for `channel` (its byte 0) and `schema`.
fn message(channel: u8, schema: &Schema) -> Vec<u8> {
    let mut bytes = vec![channel];
    let mut buf = [0u8; 300];
    bytes.extend_from_slice(postcard::to_slice(schema, &mut buf).unwrap());
    bytes
}

/// What the key holder's client does: a challenge, a TransferOpen for a schema of the message's
/// length and its MAC, the message and the MAC over ISO-TP. Returns the SchemaAck and the
/// Receipt tag that followed it, and the nonce, with `key` and `flags` for the open.
fn send_keyed_with(
    h: &mut Harness,
    body: &[u8],
    key: &Key,
    flags: u8,
) -> (Option<SchemaAck>, Option<[u8; 8]>, u64) {
    let nonce = h.challenge(TOOL, key).expect("a challenge");
    let auth = Authenticator::new(key);
    let mut bytes = body.to_vec();
    bytes.extend_from_slice(&auth.image_mac(Harness::NODE_ID, nonce, flags, body));
    let length = u16::try_from(bytes.len()).unwrap();
    let open = TransferOpen {
        length,
        flags,
        tag: auth.open_tag(Harness::NODE_ID, nonce, length, flags),
    };
    h.feed(&Message::TransferOpen(open).to_frame(TOOL, Harness::NODE_ID));
    let since = h.now;
    let ack = try_send_bytes(h, &bytes);
    let receipt = h
        .messages_since(since)
        .into_iter()
        .find_map(|(_, id, m)| match m {
            Message::Receipt { tag } if id.destination == TOOL => Some(tag),
            _ => None,
        });
    (ack, receipt, nonce)
}

fn receipt_verifies(ack: &SchemaAck, nonce: u64, tag: &[u8; 8]) -> bool {
    let frame = Message::SchemaAck(*ack).to_frame(Harness::NODE_ID, TOOL);
    let mut payload = [0u8; 8];
    payload.copy_from_slice(frame.payload());
    Authenticator::new(&KEY).verify_receipt(Harness::NODE_ID, nonce, &payload, 0, false, tag)
}

#[test]
fn the_key_holders_schemas_are_taken_and_confirmed_by_a_receipt() {
    let mut h = keyed();
    let since = h.now;
    let (ack, receipt, nonce) =
        send_keyed_with(&mut h, &message(0, &build::idle(4, 0)), &KEY, OPEN_SCHEMA);
    let ack = ack.expect("a SchemaAck");
    assert_eq!((ack.outcome, ack.id), (SchemaOutcome::Accepted, 4));
    assert!(receipt_verifies(&ack, nonce, &receipt.expect("a Receipt")));
    h.advance_to(h.now + 2_000);
    assert_eq!(transitions(&h, since)[0].1.installed, 4);
    // The high-priority channel too, acknowledging the stop after an emergency stop from anyone.
    h.feed(&Message::EmergencyStop.to_frame(77, BROADCAST));
    h.advance_to(h.now + 5_000);
    let since = h.now;
    let (ack, _, _) = send_keyed_with(
        &mut h,
        &message(1 | 1 << 2, &build::idle(5, 0)),
        &KEY,
        OPEN_SCHEMA,
    );
    assert_eq!(ack.unwrap().outcome, SchemaOutcome::Accepted);
    h.advance_to(h.now + 2_000);
    assert_eq!(
        transitions(&h, since)
            .iter()
            .map(|(_, t)| (t.installed, t.trigger))
            .collect::<Vec<_>>(),
        [(5, SchemaTrigger::HighPriority)]
    );
}

#[test]
fn a_plain_schema_on_a_keyed_node_is_ignored_and_counted() {
    let mut h = keyed();
    let since = h.now;
    // A single frame and a multi-frame message, without an open: no flow control, no answer.
    for schema in [
        build::idle(6, 0),
        build::move_to(7, [1000, 0, 0, 0, 0, 0], 1000),
    ] {
        let body = message(0, &schema);
        assert_eq!(
            try_send_bytes(&mut h, &body),
            None,
            "a plain schema got an answer"
        );
    }
    h.advance_to(h.now + 5_000);
    assert!(transitions(&h, since).is_empty());
    assert!(
        h.auth_failures_since(since)
            .contains(&AuthFailure::Unopened)
    );
    // From another source than the tool, even opened by the tool: NotTool.
    let from = h.now;
    h.feed(
        &Message::SchemaTransfer {
            data: [0x03, 0, 8, 0, 0, 0, 0, 0],
            len: 8,
        }
        .to_frame(42, Harness::NODE_ID),
    );
    assert_eq!(h.auth_failures_since(from), [AuthFailure::NotTool]);
}

#[test]
fn a_wrong_key_a_table_open_or_a_changed_message_gets_no_schema_in() {
    let mut h = keyed();
    let since = h.now;
    let body = message(0, &build::idle(8, 0));
    // Another key: the open's tag fails, so the transfer is unopened.
    let (ack, _, _) = send_keyed_with(&mut h, &body, &Key::from_bytes([1; 16]), OPEN_SCHEMA);
    assert!(ack.is_none());
    // The key holder's open for a table (no schema flag): a schema's first frame does not
    // consume it.
    let (ack, _, _) = send_keyed_with(&mut h, &body, &KEY, OPEN_REPLACE);
    assert!(ack.is_none());
    h.advance_to(h.now + 1_200_000); // the unused open expires
    // The message changed after the MAC was made: refused Unauthenticated, with a Receipt.
    let nonce = h.challenge(TOOL, &KEY).unwrap();
    let auth = Authenticator::new(&KEY);
    let mut bytes = body.clone();
    bytes.extend_from_slice(&auth.image_mac(Harness::NODE_ID, nonce, OPEN_SCHEMA, &body));
    bytes[1] ^= 1;
    let length = u16::try_from(bytes.len()).unwrap();
    let open = TransferOpen {
        length,
        flags: OPEN_SCHEMA,
        tag: auth.open_tag(Harness::NODE_ID, nonce, length, OPEN_SCHEMA),
    };
    h.feed(&Message::TransferOpen(open).to_frame(TOOL, Harness::NODE_ID));
    let ack = send_bytes(&mut h, &bytes);
    assert_eq!(ack.outcome, SchemaOutcome::Unauthenticated);
    h.advance_to(h.now + 5_000);
    assert!(transitions(&h, since).is_empty(), "nothing installed");
    assert_eq!(latest_queue(&h), 0);
}

#[test]
fn a_table_image_with_its_mac_cannot_stand_for_a_schema() {
    // The same bytes under the table's flags (0) and the schema's: different MACs.
    let auth = Authenticator::new(&KEY);
    let body = message(0, &build::idle(9, 0));
    assert_ne!(
        auth.image_mac(Harness::NODE_ID, 1, 0, &body),
        auth.image_mac(Harness::NODE_ID, 1, OPEN_SCHEMA, &body)
    );
    // Both flags at once mean nothing: the open is malformed.
    let open = TransferOpen {
        length: 40,
        flags: OPEN_REPLACE | OPEN_SCHEMA,
        tag: [0; 5],
    };
    let frame = Message::TransferOpen(open).to_frame(TOOL, Harness::NODE_ID);
    assert!(Message::decode(&frame).is_err());
}

#[test]
fn stopping_a_keyed_node_needs_no_key() {
    let mut h = keyed();
    let (ack, _, _) = send_keyed_with(
        &mut h,
        &message(0, &build::move_to(3, [100_000, 0, 0, 0, 0, 0], 50_000)),
        &KEY,
        OPEN_SCHEMA,
    );
    assert_eq!(ack.unwrap().outcome, SchemaOutcome::Accepted);
    h.advance_to(h.now + 20_000);
    let since = h.now;
    h.feed(&Message::SchemaAbort.to_frame(99, Harness::NODE_ID));
    h.advance_to(h.now + 2_000);
    let since_abort = transitions(&h, since);
    assert_eq!(since_abort[0].1.trigger, SchemaTrigger::Abort);
    let since = h.now;
    h.feed(&Message::EmergencyStop.to_frame(99, BROADCAST));
    h.advance_to(h.now + 2_000);
    assert_eq!(transitions(&h, since)[0].1.trigger, SchemaTrigger::Safety);
}

/// The queue's length in the node's last SchemaState.
fn latest_queue(h: &Harness) -> u8 {
    h.messages_since(0)
        .into_iter()
        .rev()
        .find_map(|(_, _, m)| match m {
            Message::SchemaState(s) => Some(s.queued),
            _ => None,
        })
        .expect("a SchemaState")
}

/// The limits channel's message: byte 2, then the limits.
fn limits_message(limits: &pab_core::schema::Limits) -> Vec<u8> {
    let mut bytes = vec![2];
    let mut buf = [0u8; 300];
    bytes.extend_from_slice(postcard::to_slice(limits, &mut buf).unwrap());
    bytes
}

#[test]
fn only_the_key_holder_tightens_the_limits_and_never_beyond_the_tables() {
    let mut h = keyed();
    let table = setup().config.limits;
    let mut tight = table.clone();
    tight.force_limit = 10_000;
    // Without the key: no answer, and the limits in force are the table's.
    let plain = try_send_bytes(&mut h, &limits_message(&tight));
    assert!(plain.is_none());
    let in_force = |h: &Harness| h.node.schema().unwrap().server().limits().clone();
    assert_eq!(in_force(&h), table);
    // With it: accepted on the limits channel, confirmed by a Receipt.
    let (ack, receipt, nonce) = send_keyed_with(&mut h, &limits_message(&tight), &KEY, OPEN_SCHEMA);
    let ack = ack.expect("a SchemaAck");
    assert_eq!(
        (ack.outcome, ack.channel, ack.id),
        (
            SchemaOutcome::Accepted,
            Some(pab_core::protocol::SchemaChannel::Limits),
            SchemaAck::NO_ID
        )
    );
    assert!(receipt_verifies(&ack, nonce, &receipt.expect("a Receipt")));
    assert_eq!(in_force(&h), tight);
    // Looser than the table's, even with the key: refused, nothing changed.
    let mut loose = table.clone();
    loose.force_limit += 1;
    let (ack, _, _) = send_keyed_with(&mut h, &limits_message(&loose), &KEY, OPEN_SCHEMA);
    assert_eq!(ack.unwrap().outcome, SchemaOutcome::Looser);
    assert_eq!(in_force(&h), tight);
    // Bytes that are no limits: Malformed.
    let (ack, _, _) = send_keyed_with(&mut h, &[2, 0xFF], &KEY, OPEN_SCHEMA);
    assert_eq!(ack.unwrap().outcome, SchemaOutcome::Malformed);
}
