//! Every service has a fixed priority: a frame of ours with other priority bits is malformed,
//! counted in Errors and reported as BadCommand, never acted on.

use crate::common;

use common::*;
use pab_core::Frame;
use pab_core::protocol::{self, FaultCode, FrameId, Message, Priority, Service};

/// A valid payload for each service.
fn payload(service: Service) -> Vec<u8> {
    match service {
        Service::Fault => vec![0x01, 0x00, 1, 0, 0, 0, 0, 0],
        Service::Heartbeat => vec![1, 0, 0, 0, 1, 0, 0, 0],
        Service::TableStatus | Service::Traffic | Service::Errors | Service::Diagnostic => {
            vec![0; 8]
        }
        Service::DiagnosticControl => vec![10, 0, 0xFF, 0xFF],
        // Group 0 of one behaviour, its gate closed.
        Service::Gates => vec![0, 1, 0, 0, 0, 0, 0, 0],
        // A first frame announcing a 100-byte image.
        Service::TableTransfer => vec![0x10, 100, b'P', b'A', b'B', b'T', 1, 5],
        Service::TransferStatus => vec![0; 8],
        // The tool's nonce.
        Service::ChallengeRequest => vec![1, 2, 3, 4, 5, 6, 7, 8],
        // Length 100, no flags, a (wrong) tag: well formed, not authentic.
        Service::TransferOpen => vec![100, 0, 0, 1, 2, 3, 4, 5],
        Service::Challenge | Service::Receipt => vec![0; 8],
        // Class 0 at intensity 1 for 100 ms; strategy 0; no filters, none closed.
        Service::Desire => vec![0, 0, 1, 0, 100, 0, 0, 0],
        Service::Intention => vec![1, 0, 0, 0, 0, 0, 0, 0],
        Service::FilterStatus => vec![0; 8],
        Service::Exploitation => vec![0, 0, 1, 0],
        Service::FilterProfile => vec![0; 4],
        Service::FilterSet => vec![0, 0, 1, 0, 0, 0],
        Service::EmergencyStop | Service::SchemaAbort => vec![],
        // A first frame announcing a 20-byte schema message, channel 0 (the queue).
        Service::SchemaTransfer => vec![0x10, 20, 0, 1, 0, 2, 0, 0],
        // Accepted on the queue, schema 1, one queued; schema 1 ended by its reaction 0, the
        // wait for the queue installed; waiting on the queue, armed.
        Service::SchemaAck => vec![0, 0, 1, 0, 1, 0, 0, 0],
        Service::SchemaTransition => vec![1, 0, 0x00, 0xFF, 3, 0, 1, 0],
        Service::SchemaState => vec![0x00, 0xFF, 1, 0xFF, 0, 1, 0, 0],
        // A seal of a Gates frame (a wrong tag), a freshness request's nonce, an answer.
        Service::Seal => vec![0x07, 0, 1, 0, 1, 2, 3, 4],
        Service::FreshnessRequest | Service::Freshness => vec![1, 2, 3, 4, 5, 6, 7, 8],
        Service::IdentityRequest => vec![],
        Service::Identity
        | Service::IdentityVersion
        | Service::IdentityBuild
        | Service::IdentityCapacity
        | Service::IdentityName => vec![0; 8],
        Service::IdentityFeatures => vec![10, 10, 0, 0, 0, 0, 0, 0],
        // Node 5 by a uid check no node has: well formed, taken by nobody.
        Service::Assign => vec![1, 2, 3, 6],
        // 500 kbit/s.
        Service::Configure => vec![0xF4, 1, 0, 0],
        Service::ConfigStatus => vec![0x28, 0, 5, 0, 0xF4, 1, 0, 0],
        // A firmware update's Abort, as a single frame; a chunk acknowledged at offset 0.
        Service::UpdateTransfer => vec![0x01, 4, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC],
        Service::UpdateStatus => vec![2, 0, 0, 0, 0, 0, 0, 0],
    }
}

/// `service`'s frame from the tool (or node 9 for node services) to node 5, with priority bits
/// `priority`.
fn frame_with(service: Service, priority: u8) -> Frame {
    let source = match service {
        Service::DiagnosticControl
        | Service::TableTransfer
        | Service::ChallengeRequest
        | Service::TransferOpen
        | Service::EmergencyStop
        | Service::SchemaAbort
        | Service::SchemaTransfer
        | Service::IdentityRequest
        | Service::Assign
        | Service::Configure
        | Service::UpdateTransfer => protocol::TOOL,
        _ => 9,
    };
    let mut id = FrameId::new(service, source, Harness::NODE_ID);
    id.priority = Priority::new(priority).unwrap();
    Frame::with_raw_id(id.raw(), true, &payload(service)).unwrap()
}

fn bad_commands(h: &Harness, since: u64) -> Vec<[u8; 5]> {
    h.messages_since(since)
        .into_iter()
        .filter_map(|(_, _, message)| match message {
            Message::Fault(fault) if fault.code == FaultCode::BadCommand => Some(fault.detail),
            _ => None,
        })
        .collect()
}

#[test]
fn a_frame_with_its_services_priority_is_well_formed() {
    // The payloads are valid: at the right priority, every frame decodes and none is an error.
    let mut h = Harness::boot(Some(&image(
        &priority_table(&[TOPIC_A], None),
        Harness::NODE_ID,
        1,
    )));
    for service in Service::ALL {
        let frame = frame_with(service, service.priority().value());
        assert!(Message::decode(&frame).is_ok(), "{service:?}");
        // Transfers and authentication requests are well formed but not for an unkeyed node's
        // error-free path (it answers them with faults): decoding is what this test checks.
        if !matches!(
            service,
            Service::TableTransfer
                | Service::ChallengeRequest
                | Service::TransferOpen
                | Service::FreshnessRequest
        ) {
            h.feed(&frame);
        }
    }
    assert_eq!(h.node.counters().errors, 0);
}

#[test]
fn a_frame_with_another_priority_than_its_services_is_refused_as_malformed() {
    let mut h = Harness::boot(Some(&image(
        &priority_table(&[TOPIC_A], None),
        Harness::NODE_ID,
        1,
    )));
    let mut expected_errors = 0;
    for service in Service::ALL {
        for priority in (0..=7).filter(|&p| p != service.priority().value()) {
            let frame = frame_with(service, priority);
            assert!(
                matches!(
                    Message::decode(&frame),
                    Err(protocol::DecodeError::Priority { .. })
                ),
                "{service:?} at priority {priority}"
            );
            let since = h.now;
            h.feed(&frame);
            expected_errors += 1;
            assert_eq!(
                h.node.counters().errors,
                expected_errors,
                "{service:?} at priority {priority}: counted"
            );
            // Past the fault's rate limit: the fault names the service.
            h.advance_to(h.now + 150_000);
            assert_eq!(
                bad_commands(&h, since),
                [[service.code(), 0, 0, 0, 0]],
                "{service:?} at priority {priority}: BadCommand"
            );
            // Never acted on: no flow control for a first frame, no diagnostic stream, no answer
            // to a schema, no schema change.
            let acted = h.messages_since(since).into_iter().any(|(_, _, message)| {
                matches!(
                    message,
                    Message::TableTransfer { .. }
                        | Message::Diagnostic(_)
                        | Message::TransferStatus(_)
                        | Message::SchemaTransfer { .. }
                        | Message::SchemaAck(_)
                        | Message::SchemaTransition(_)
                )
            });
            assert!(!acted, "{service:?} at priority {priority}: acted on");
        }
    }
    // The stream was never switched on, and a real push still goes through.
    h.advance_to(h.now + 1_000_000);
    let table_status = h
        .messages_since(h.now - 1_000_000)
        .into_iter()
        .find_map(|(_, _, message)| match message {
            Message::TableStatus(status) => Some(status),
            _ => None,
        })
        .unwrap();
    assert!(!table_status.diagnostic);
    let v2 = image(
        &priority_table(&[TOPIC_A, TOPIC_B], None),
        Harness::NODE_ID,
        2,
    );
    assert_eq!(h.push(&v2), pab_core::isotp::TxEvent::Done);
    assert_eq!(h.running_version(), Some(2));
}
