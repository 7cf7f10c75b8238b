//! Firmware update over the bus, node side (feature `update`): an update's messages over
//! UpdateTransfer into the runner's slot, the answers, the commit and the restart; what a node
//! refuses (another board, a sender not the tool, a keyed node without an open, a board without
//! a slot); the bootloader's verdict at start.

use crate::common;

use common::*;
use pab_app::Firmware;
use pab_core::auth::{Authenticator, Key};
use pab_core::crc32::crc32;
use pab_core::isotp::TxEvent;
use pab_core::protocol::{
    self, FaultCode, Message, OPEN_UPDATE, TransferOpen, UpdateStatus, UpdateStatusCode,
};
use pab_core::update::session::{self, BEGIN_LEN, CHUNK};
use pab_core::update::stored::{Manifest, Verdict};
use pab_core::update::{MANIFEST_LEN, Trailer};

const SLOT: u32 = 16 * 1024;
const KEY: Key = Key::from_bytes([0x5D; 16]);

fn running() -> Firmware {
    Firmware::new("fw-test", "1.2.0", "0011223344556677")
}

fn manifest(name: &str, version: &str, image_len: usize) -> [u8; MANIFEST_LEN] {
    Manifest {
        trailer: Trailer {
            firmware: Firmware::new(name, version, "8899aabbccddeeff"),
            downgrade: false,
            image_len: image_len as u32,
        },
        signature: [0x77; 64],
    }
    .encode()
}

fn image(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 13 + 1) as u8).collect()
}

fn harness(setup: impl FnOnce(&mut TestNode)) -> Harness {
    let mut h = Harness::boot_with(None, |node| {
        node.set_identity(running(), [1; 12]);
        node.set_update_slot(SLOT);
        setup(node);
    });
    h.channel = Channel::Update;
    h
}

/// The UpdateStatus answers the node sent to the tool since `from` µs.
fn answers(h: &Harness, from: u64) -> Vec<UpdateStatus> {
    h.messages_since(from)
        .into_iter()
        .filter_map(|(_, id, message)| match message {
            Message::UpdateStatus(status) if id.destination == protocol::TOOL => Some(status),
            _ => None,
        })
        .collect()
}

fn faults(h: &Harness, code: FaultCode) -> Vec<[u8; 5]> {
    h.messages_since(0)
        .into_iter()
        .filter_map(|(_, _, message)| match message {
            Message::Fault(fault) if fault.code == code => Some(fault.detail),
            _ => None,
        })
        .collect()
}

/// Sends one update message and returns the answers it brought.
fn send(h: &mut Harness, message: &[u8]) -> Vec<UpdateStatus> {
    let from = h.now;
    assert_eq!(
        h.push(message),
        TxEvent::Done,
        "the ISO-TP transfer of a message"
    );
    answers(h, from)
}

fn status(status: UpdateStatusCode, offset: u32, value: u32) -> UpdateStatus {
    UpdateStatus {
        status,
        offset,
        value,
    }
}

#[test]
fn an_update_goes_into_the_slot_chunk_by_chunk_and_its_commit_restarts_the_node() {
    let image = image(2500);
    let mut h = harness(|_| {});
    let manifest = manifest("fw-test", "1.3.0", image.len());
    assert_eq!(
        send(&mut h, &session::begin(&manifest)),
        [status(UpdateStatusCode::Ready, 0, CHUNK as u32)]
    );
    let mut offset = 0;
    for chunk in image.chunks(CHUNK) {
        let mut message = session::chunk_head(offset as u32).to_vec();
        message.extend_from_slice(chunk);
        offset += chunk.len();
        assert_eq!(
            send(&mut h, &message),
            [status(
                UpdateStatusCode::Ack,
                offset as u32,
                crc32(&image[..offset])
            )]
        );
    }
    assert_eq!(&h.update_slot[..2500], &image[..]);
    assert_eq!(h.restarts, 0);
    assert_eq!(
        send(&mut h, &session::commit(crc32(&image))),
        [status(UpdateStatusCode::Committed, 2500, crc32(&image))]
    );
    assert_eq!(h.update_requests, [manifest.to_vec()]);
    assert_eq!(
        h.restarts, 1,
        "the runner restarts the board into its bootloader"
    );
    // The table's own transfer is another channel: untouched.
    assert!(h.statuses(protocol::TOOL).is_empty());
}

#[test]
fn an_image_for_another_board_or_older_is_refused_at_its_begin_with_a_fault() {
    let mut h = harness(|_| {});
    assert_eq!(
        send(&mut h, &session::begin(&manifest("fw-g474", "1.3.0", 100))),
        [status(UpdateStatusCode::Refused, 0, 4)]
    );
    assert_eq!(
        send(&mut h, &session::begin(&manifest("fw-test", "1.1.9", 100))),
        [status(UpdateStatusCode::Refused, 0, 5)]
    );
    h.advance_to(h.now + 2_000_000);
    assert_eq!(
        faults(&h, FaultCode::UpdateFailed).first(),
        Some(&[4, 0, 0, 0, 0])
    );
    // No session: a chunk is answered NoSession and nothing is written.
    let mut chunk = session::chunk_head(0).to_vec();
    chunk.extend_from_slice(&[9; 8]);
    assert_eq!(
        send(&mut h, &chunk),
        [status(UpdateStatusCode::NoSession, 0, 0)]
    );
    assert!(h.update_slot.iter().all(|&b| b == 0xFF));
}

#[test]
fn a_failed_write_ends_the_session_with_a_fault_and_no_request() {
    let mut h = harness(|_| {});
    send(&mut h, &session::begin(&manifest("fw-test", "1.2.0", 16)));
    h.update_write_ok = false;
    let mut chunk = session::chunk_head(0).to_vec();
    chunk.extend_from_slice(&[3; 16]);
    assert_eq!(
        send(&mut h, &chunk),
        [status(UpdateStatusCode::FlashError, 0, 0)]
    );
    h.update_write_ok = true;
    assert_eq!(
        send(&mut h, &session::commit(0)),
        [status(UpdateStatusCode::NoSession, 0, 0)]
    );
    assert!(h.update_requests.is_empty() && h.restarts == 0);
    h.advance_to(h.now + 2_000_000);
    assert_eq!(
        faults(&h, FaultCode::UpdateFailed).first(),
        Some(&[8, 0, 0, 0, 0])
    );
}

#[test]
fn only_the_tool_updates_and_a_board_without_a_slot_says_so() {
    let mut h = harness(|_| {});
    let begin = session::begin(&manifest("fw-test", "1.3.0", 100));
    let from = h.now;
    h.push_with(&begin, 9, |_, _, data| Some(data));
    assert!(
        answers(&h, from).is_empty(),
        "a node's own id is not the tool"
    );
    h.advance_to(h.now + 2_000_000);
    assert!(!faults(&h, FaultCode::Unauthenticated).is_empty());

    let mut h = harness(|node| node.set_update_slot(0));
    assert_eq!(
        send(&mut h, &begin),
        [status(UpdateStatusCode::Unsupported, 0, 0)]
    );
}

#[test]
fn a_keyed_node_starts_an_update_only_after_an_open_for_one() {
    let begin = session::begin(&manifest("fw-test", "1.3.0", 100));
    let mut h = harness(|node| node.set_key(&KEY, 1));
    // Without an open: refused, no session.
    let from = h.now;
    h.push(&begin);
    assert!(answers(&h, from).is_empty());
    // An open for a table (no OPEN_UPDATE) of the same length does not admit it either.
    let open = |h: &mut Harness, flags: u8| {
        let nonce = h.challenge(protocol::TOOL, &KEY).expect("a challenge");
        let auth = Authenticator::new(&KEY);
        let length = BEGIN_LEN as u16;
        let open = TransferOpen {
            length,
            flags,
            tag: auth.open_tag(Harness::NODE_ID, nonce, length, flags),
        };
        h.feed(&Message::TransferOpen(open).to_frame(protocol::TOOL, Harness::NODE_ID));
    };
    open(&mut h, 0);
    let from = h.now;
    h.push(&begin);
    assert!(
        answers(&h, from).is_empty(),
        "a table's open admitted an update"
    );
    // An open for an update: Ready; and the session's chunks need none of their own.
    open(&mut h, OPEN_UPDATE);
    assert_eq!(
        send(&mut h, &begin),
        [status(UpdateStatusCode::Ready, 0, CHUNK as u32)]
    );
    let mut chunk = session::chunk_head(0).to_vec();
    chunk.extend_from_slice(&image(100));
    assert_eq!(
        send(&mut h, &chunk),
        [status(UpdateStatusCode::Ack, 100, crc32(&image(100)))]
    );
    // An update's open is not a table's: a table's first frame of its length is refused.
    open(&mut h, OPEN_UPDATE);
    h.channel = Channel::Table;
    let failures_from = h.now;
    h.push(&[0; BEGIN_LEN]);
    assert!(!h.auth_failures_since(failures_from).is_empty());
}

#[test]
fn the_bootloaders_verdict_is_reported_at_start() {
    let requested = |version: &str| {
        Some(Trailer {
            firmware: Firmware::new("fw-test", version, "0011223344556677"),
            downgrade: false,
            image_len: 100,
        })
    };
    let refused = Verdict {
        outcome: Err(6),
        requested: requested("1.3.0"),
    };
    let mut h = harness(|node| node.update_verdict(refused));
    h.advance_to(1_000_000);
    assert_eq!(answers(&h, 0), [status(UpdateStatusCode::Refused, 0, 6)]);
    assert_eq!(
        faults(&h, FaultCode::UpdateFailed).first(),
        Some(&[6, 0, 0, 0, 0])
    );

    // Accepted, and what runs is what was asked for (the harness's firmware is 1.2.0).
    let swapped = Verdict {
        outcome: Ok(()),
        requested: requested("1.2.0"),
    };
    let h = harness(|node| node.update_verdict(swapped));
    assert_eq!(answers(&h, 0), [status(UpdateStatusCode::Swapped, 0, 0)]);

    // Accepted, but another firmware runs: the update did not confirm itself and was reverted
    // before anyone read the verdict (or no trailer was stored with the request).
    for requested in [requested("1.3.0"), None] {
        let reverted = Verdict {
            outcome: Ok(()),
            requested,
        };
        let mut h = harness(|node| node.update_verdict(reverted));
        h.advance_to(1_000_000);
        assert_eq!(answers(&h, 0), [status(UpdateStatusCode::NotRunning, 0, 0)]);
        assert_eq!(
            faults(&h, FaultCode::UpdateFailed).first(),
            Some(&[9, 0, 0, 0, 0])
        );
    }
}

/// An update in CAN FD frames (TX_DL 64): the same answers as a classic one, each message's flow
/// control a CAN FD frame, and the image in the slot.
#[cfg(feature = "fd")]
#[test]
fn an_update_in_can_fd_frames_goes_into_the_slot() {
    use pab_core::isotp::fd::TxDl;
    let image = image(2500);
    let mut h = harness(|_| {});
    let send_fd = |h: &mut Harness, message: &[u8]| {
        let from = h.now;
        let (end, flow_controls) =
            h.push_fd_with(message, protocol::TOOL, TxDl::MAX, |_, _, f| Some(f));
        assert_eq!(end, TxEvent::Done);
        assert!(flow_controls.iter().all(|f| f.is_fd() && f.is_brs()));
        answers(h, from)
    };
    let manifest = manifest("fw-test", "1.3.0", image.len());
    assert_eq!(
        send_fd(&mut h, &session::begin(&manifest)),
        [status(UpdateStatusCode::Ready, 0, CHUNK as u32)]
    );
    let mut offset = 0;
    for chunk in image.chunks(CHUNK) {
        let mut message = session::chunk_head(offset as u32).to_vec();
        message.extend_from_slice(chunk);
        offset += chunk.len();
        assert_eq!(
            send_fd(&mut h, &message),
            [status(
                UpdateStatusCode::Ack,
                offset as u32,
                crc32(&image[..offset])
            )]
        );
    }
    assert_eq!(&h.update_slot[..2500], &image[..]);
}
