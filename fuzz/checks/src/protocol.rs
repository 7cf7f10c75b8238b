//! The protocol codecs (`pab_core::protocol`): decode → encode gives back the frame, and encode →
//! decode gives back the message.
//!
//! A decoder that accepted a frame with a reserved bit set, or read a field it then dropped, would
//! fail the first; an encoder that wrote a field where the decoder does not read it, the second.

use arbitrary::{Result, Unstructured};
use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use pab_core::Frame;
use pab_core::protocol::{
    self, DiagnosticControl, DiagnosticFlags, DiagnosticSample, Errors, Fault, FaultCode, FrameId,
    Gates, Heartbeat, Message, NodeState, OPEN_REPLACE, Service, TableStatus, Traffic,
    TransferOpen, TransferStatus, TransferStatusCode,
};

/// The services a node acts on: the only ones `Message::decode_for_node` decodes.
fn node_service(service: Service) -> bool {
    matches!(
        service,
        Service::Gates
            | Service::DiagnosticControl
            | Service::TableTransfer
            | Service::ChallengeRequest
            | Service::TransferOpen
            | Service::FilterProfile
            | Service::FilterSet
    )
}

/// Any frame, decoded; what decodes must encode to the same frame (at its service's priority).
/// The nodes' decoder agrees with the full one: the same framing errors, the same message for a
/// service a node acts on, nothing (and no error from its payload) for the others.
pub fn decode(data: &[u8]) {
    let Ok(frame) = any_frame(&mut Unstructured::new(data)) else {
        return;
    };
    let full = Message::decode(&frame);
    match (&full, Message::decode_for_node(&frame)) {
        (Ok((id, message)), Ok(Some((node_id, node_message)))) => {
            assert!(node_service(id.service));
            assert_eq!((*id, message), (node_id, &node_message));
        }
        (Ok((id, _)), Ok(None)) => assert!(!node_service(id.service)),
        (Err(protocol::DecodeError::Value { service }), Ok(None)) => {
            assert!(!node_service(*service));
        }
        (Err(error), Err(node_error)) => assert_eq!(*error, node_error),
        (full, node) => panic!("decode {full:?}, decode_for_node {node:?}"),
    }
    match full {
        Ok((id, message)) => {
            assert!(protocol::is_ours(&frame.id()));
            assert!(!frame.is_remote());
            assert_eq!(FrameId::decode(&frame.id()), Some(id));
            assert_eq!(message.service(), id.service);
            let again = message.to_frame(id.source, id.destination);
            // The priority bits are not part of the message: the encoder uses the service's.
            assert_eq!(
                again.id(),
                FrameId::new(id.service, id.source, id.destination).id()
            );
            assert_eq!(again.payload(), frame.payload(), "{message:?}");
            let (id_again, message_again) = Message::decode(&again)
                .unwrap_or_else(|error| panic!("{message:?} encodes to a refused frame: {error}"));
            assert_eq!(message_again, message);
            assert_eq!(
                (id_again.source, id_again.destination, id_again.service),
                (id.source, id.destination, id.service)
            );
        }
        Err(error) => {
            assert!(!error.to_string().is_empty());
            if FrameId::decode(&frame.id()).is_none() {
                assert_eq!(error, protocol::DecodeError::NotOurs);
            }
        }
    }
}

/// Any valid message, encoded; it must decode to itself, from the same addresses.
pub fn encode(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let Ok((message, source, destination)) = any_message(&mut u) else {
        return;
    };
    let frame = message.to_frame(source, destination);
    let decoded = Message::decode(&frame);
    if let Message::Gates(gates) = message
        && !gates.is_valid()
    {
        assert_eq!(
            decoded,
            Err(protocol::DecodeError::Value {
                service: Service::Gates
            })
        );
        return;
    }
    if let Message::DiagnosticControl(control) = message
        && control.rate_hz > DiagnosticControl::MAX_RATE_HZ
    {
        // Not a valid message: the decoder must refuse it.
        assert_eq!(
            decoded,
            Err(protocol::DecodeError::Value {
                service: Service::DiagnosticControl
            })
        );
        return;
    }
    let (id, back) = decoded.unwrap_or_else(|error| panic!("{message:?}: {error}"));
    assert_eq!(id, FrameId::new(message.service(), source, destination));
    assert_eq!(back, normalized(message));
    let len = match message {
        Message::TableTransfer { len, .. } => usize::from(len),
        // DiagnosticControl's keyed form: the 4 bytes and the tag.
        Message::AuthenticatedDiagnosticControl { .. } => 8,
        _ => message.service().payload_len(),
    };
    assert_eq!(frame.payload().len(), len, "{message:?}");
}

/// What the wire can carry of a message: the uptime saturates at 24 bits; a transfer frame's bytes
/// beyond its length are not sent.
fn normalized(message: Message) -> Message {
    match message {
        Message::Heartbeat(heartbeat) => Message::Heartbeat(Heartbeat {
            uptime_s: heartbeat.uptime_s.min(0x00FF_FFFF),
            ..heartbeat
        }),
        Message::TableTransfer { mut data, len } => {
            data[usize::from(len)..].fill(0);
            Message::TableTransfer { data, len }
        }
        other => other,
    }
}

fn any_frame(u: &mut Unstructured<'_>) -> Result<Frame> {
    let id = if u.ratio(1u8, 8)? {
        Id::Standard(StandardId::new(u.int_in_range(0..=0x7FF)?).unwrap_or(StandardId::ZERO))
    } else if u.ratio(1u8, 2)? {
        // One of ours, any service code, any priority and addresses.
        let raw = u32::from(u.int_in_range(0u8..=7)?) << 26
            | 0b10 << 24
            | u32::from(u.arbitrary::<u8>()?) << 16
            | u32::from(u.arbitrary::<u16>()?);
        Id::Extended(ExtendedId::new(raw).unwrap_or(ExtendedId::ZERO))
    } else {
        Id::Extended(ExtendedId::new(u.int_in_range(0..=0x1FFF_FFFF)?).unwrap_or(ExtendedId::ZERO))
    };
    let len = match u.int_in_range(0u8..=3)? {
        0 => u.int_in_range(0..=8)?,
        _ => 8,
    };
    if u.ratio(1u8, 32)? {
        return Ok(Frame::new_remote(id, len).unwrap_or_else(|| unreachable!("dlc {len}")));
    }
    let mut bytes = [0u8; 8];
    u.fill_buffer(&mut bytes[..len])?;
    Ok(Frame::data(id, &bytes[..len]).unwrap_or_else(|| unreachable!("8 bytes")))
}

fn pick<T: Copy>(u: &mut Unstructured<'_>, all: &[T]) -> Result<T> {
    u.choose(all).copied()
}

fn any_message(u: &mut Unstructured<'_>) -> Result<(Message, u8, u8)> {
    let message = match u.int_in_range(0u8..=14)? {
        0 => Message::Fault(Fault {
            code: pick(u, FaultCode::ALL)?,
            count: u.arbitrary()?,
            detail: u.arbitrary()?,
        }),
        1 => Message::Heartbeat(Heartbeat {
            state: pick(u, NodeState::ALL)?,
            uptime_s: u.arbitrary()?,
            table_version: u.arbitrary()?,
        }),
        2 => Message::TableStatus(TableStatus {
            crc: u.arbitrary()?,
            image_len: u.arbitrary()?,
            ports: u.arbitrary()?,
            stored: u.arbitrary()?,
            diagnostic: u.arbitrary()?,
            keyed: u.arbitrary()?,
        }),
        3 => Message::Traffic(Traffic {
            received: u.arbitrary()?,
            delivered: u.arbitrary()?,
        }),
        4 => Message::Errors(Errors {
            discarded: u.arbitrary()?,
            errors: u.arbitrary()?,
        }),
        5 => Message::Diagnostic(DiagnosticSample {
            port: u.arbitrary()?,
            connection: u.arbitrary()?,
            flags: DiagnosticFlags {
                active: u.arbitrary()?,
                resting: u.arbitrary()?,
                delivering: u.arbitrary()?,
                end_of_round: u.arbitrary()?,
            },
            sequence: u.arbitrary()?,
            level: u.arbitrary()?,
        }),
        6 => Message::DiagnosticControl(DiagnosticControl {
            rate_hz: if u.ratio(1u8, 8)? {
                u.arbitrary()?
            } else {
                u.int_in_range(0..=DiagnosticControl::MAX_RATE_HZ)?
            },
            ports: u.arbitrary()?,
        }),
        7 => Message::TableTransfer {
            data: u.arbitrary()?,
            len: u.int_in_range(1..=8)?,
        },
        8 => Message::AuthenticatedDiagnosticControl {
            control: DiagnosticControl {
                rate_hz: u.int_in_range(0..=DiagnosticControl::MAX_RATE_HZ)?,
                ports: u.arbitrary()?,
            },
            tag: u.arbitrary()?,
        },
        9 => Message::ChallengeRequest,
        10 => Message::Challenge {
            nonce: u.arbitrary()?,
        },
        11 => Message::TransferOpen(TransferOpen {
            length: u.arbitrary()?,
            flags: if u.arbitrary()? { OPEN_REPLACE } else { 0 },
            tag: u.arbitrary()?,
        }),
        12 => Message::Receipt {
            tag: u.arbitrary()?,
        },
        13 => Message::Gates(if u.ratio(1u8, 8)? {
            // Anything: a count of 0 or above 32, gates beyond the count.
            Gates {
                group: u.arbitrary()?,
                behaviours: u.arbitrary()?,
                mask: u.arbitrary()?,
                changes: u.arbitrary()?,
            }
        } else {
            let behaviours = u.int_in_range(1..=32u8)?;
            let mask: u32 = u.arbitrary()?;
            Gates {
                group: u.arbitrary()?,
                behaviours,
                // The gates below the count (all 32 bits for 32).
                mask: mask
                    & 1u32
                        .checked_shl(behaviours.into())
                        .map_or(u32::MAX, |b| b - 1),
                changes: u.arbitrary()?,
            }
        }),
        _ => Message::TransferStatus(TransferStatus {
            status: pick(u, TransferStatusCode::ALL)?,
            detail: u.arbitrary()?,
            running_version: u.arbitrary()?,
        }),
    };
    Ok((message, u.arbitrary()?, u.arbitrary()?))
}
