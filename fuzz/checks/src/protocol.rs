//! The protocol codecs (`pab_core::protocol`): decode → encode gives back the frame, and encode →
//! decode gives back the message.
//!
//! A decoder that accepted a frame with a reserved bit set, or read a field it then dropped, would
//! fail the first; an encoder that wrote a field where the decoder does not read it, the second.

use arbitrary::{Result, Unstructured};
use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use pab_core::Frame;
use pab_core::ble::{Claim, ClaimError};
use pab_core::identity::{Capacity, Firmware, Identity, IdentityPart};
use pab_core::protocol::{
    self, Assign, ConfigStatus, ConfigStatusCode, Configure, DesireFrame, DiagnosticControl,
    DiagnosticFlags, DiagnosticSample, Errors, Exploitation, Fault, FaultCode, FilterProfile,
    FilterSet, FilterStatus, FrameId, FrameKind, Gates, Heartbeat, Intention, Message, NodeState,
    OPEN_REPLACE, OPEN_SCHEMA, OPEN_UPDATE, SchemaAck, SchemaChannel, SchemaOrigin, SchemaOutcome,
    SchemaSafety, SchemaState, SchemaTransition, SchemaTrigger, Seal, Service, TableStatus,
    Traffic, TransferOpen, TransferStatus, TransferStatusCode, UpdateStatus, UpdateStatusCode,
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
            | Service::EmergencyStop
            | Service::SchemaAbort
            | Service::SchemaTransfer
            | Service::Seal
            | Service::FreshnessRequest
            | Service::Freshness
            | Service::IdentityRequest
            | Service::Assign
            | Service::Configure
            | Service::UpdateTransfer
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
    classified_as_decoded(&frame, &full);
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
            assert_eq!(protocol::classify(&frame), FrameKind::Service(id));
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

/// `frame` is of exactly one kind, and the decoders agree with it: only a service frame may
/// decode as a message, only a claim as a claim, and a decoder's "not mine" is the kind's.
fn classified_as_decoded(
    frame: &Frame,
    decoded: &Result<(FrameId, Message), protocol::DecodeError>,
) {
    let kind = protocol::classify(frame);
    let claim = Claim::decode(frame);
    assert_eq!(kind.is_ours(), protocol::is_ours(&frame.id()));
    match kind {
        FrameKind::Service(id) => {
            assert_eq!(FrameId::decode(&frame.id()), Some(id));
            assert_eq!(claim, Err(ClaimError::NotAClaim));
            assert_ne!(
                decoded.as_ref().err(),
                Some(&protocol::DecodeError::NotOurs)
            );
        }
        FrameKind::Claim => {
            assert_eq!(FrameId::decode(&frame.id()), None);
            assert_eq!(
                decoded.as_ref().err(),
                Some(&protocol::DecodeError::NotOurs)
            );
            // A remote frame is classified by its identifier; the decoder refuses it.
            assert!(
                frame.is_remote() || claim != Err(ClaimError::NotAClaim),
                "{claim:?}"
            );
        }
        FrameKind::Topic | FrameKind::UnknownService => {
            assert_eq!(FrameId::decode(&frame.id()), None);
            assert_eq!(
                decoded.as_ref().err(),
                Some(&protocol::DecodeError::NotOurs)
            );
            assert_eq!(claim, Err(ClaimError::NotAClaim));
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
    if let Message::SchemaTransition(change) = message
        && !change.is_valid()
    {
        // A detail that contradicts its trigger: the decoder must refuse it.
        assert_eq!(
            decoded,
            Err(protocol::DecodeError::Value {
                service: Service::SchemaTransition
            })
        );
        return;
    }
    if let Message::FilterStatus(status) = message
        && !filter_status_valid(&status)
    {
        assert_eq!(
            decoded,
            Err(protocol::DecodeError::Value {
                service: Service::FilterStatus
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
    if let Message::Seal(seal) = message
        && !Seal::is_sealable(seal.kind)
    {
        // A seal of nothing a seal may follow: the decoder must refuse it.
        assert_eq!(
            decoded,
            Err(protocol::DecodeError::Value {
                service: Service::Seal
            })
        );
        return;
    }
    let (id, back) = decoded.unwrap_or_else(|error| panic!("{message:?}: {error}"));
    assert_eq!(id, FrameId::new(message.service(), source, destination));
    assert_eq!(back, normalized(message));
    let len = match message {
        Message::TableTransfer { len, .. }
        | Message::SchemaTransfer { len, .. }
        | Message::UpdateTransfer { len, .. } => usize::from(len),
        // The keyed forms: the 4 bytes and the tag.
        Message::AuthenticatedDiagnosticControl { .. }
        | Message::Assign(Assign { tag: Some(_), .. })
        | Message::Configure(Configure { tag: Some(_), .. }) => 8,
        _ => message.service().payload_len(),
    };
    assert_eq!(frame.payload().len(), len, "{message:?}");
}

/// What the wire can carry of a message: the uptime and an update's offset saturate at 24 bits; a
/// transfer frame's bytes beyond its length are not sent.
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
        Message::SchemaTransfer { mut data, len } => {
            data[usize::from(len)..].fill(0);
            Message::SchemaTransfer { data, len }
        }
        Message::UpdateTransfer { mut data, len } => {
            data[usize::from(len)..].fill(0);
            Message::UpdateTransfer { data, len }
        }
        Message::UpdateStatus(status) => Message::UpdateStatus(UpdateStatus {
            offset: status.offset.min(UpdateStatus::MAX_OFFSET),
            ..status
        }),
        other => other,
    }
}

/// FilterStatus's checks, as docs/can-protocol.md states them: a profile 0..=15 or 0xFF, no more
/// closed and throttled filters than filtered ones.
fn filter_status_valid(status: &FilterStatus) -> bool {
    (status.profile < 16 || status.profile == FilterStatus::SET_ONE_BY_ONE)
        && u16::from(status.closed) + u16::from(status.throttled) <= u16::from(status.filtered)
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
    let message = match u.int_in_range(0u8..=41)? {
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
        9 => Message::ChallengeRequest {
            tool_nonce: u.arbitrary()?,
        },
        10 => Message::Challenge {
            node_nonce: u.int_in_range(0..=pab_core::auth::NODE_NONCE_MAX)?,
            binding: u.arbitrary()?,
        },
        11 => Message::TransferOpen(TransferOpen {
            length: u.arbitrary()?,
            flags: pick(u, &[0, OPEN_REPLACE, OPEN_SCHEMA, OPEN_UPDATE])?,
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
        15 => Message::Desire(DesireFrame {
            class: u.arbitrary()?,
            intensity: u.arbitrary()?,
            lease_ms: u.arbitrary()?,
            id: u.arbitrary()?,
        }),
        16 => Message::Intention(Intention {
            strategies: u.arbitrary()?,
        }),
        17 => Message::FilterStatus(FilterStatus {
            profile: if u.ratio(1u8, 4)? {
                FilterStatus::SET_ONE_BY_ONE
            } else {
                u.arbitrary()?
            },
            sequence: u.arbitrary()?,
            filtered: u.arbitrary()?,
            closed: u.arbitrary()?,
            throttled: u.arbitrary()?,
        }),
        18 => Message::Exploitation(Exploitation {
            port: u.arbitrary()?,
            connection: u.arbitrary()?,
            delivering: u.arbitrary()?,
        }),
        19 => Message::FilterProfile(FilterProfile {
            profile: u.arbitrary()?,
            sequence: u.arbitrary()?,
        }),
        20 => Message::FilterSet(FilterSet {
            port: u.arbitrary()?,
            connection: u.arbitrary()?,
            phi: u.arbitrary()?,
            sequence: u.arbitrary()?,
        }),
        21 => Message::EmergencyStop,
        22 => Message::SchemaAbort,
        23 => Message::SchemaTransfer {
            data: u.arbitrary()?,
            len: u.int_in_range(1..=8)?,
        },
        24 => Message::SchemaAck(SchemaAck {
            outcome: pick(u, SchemaOutcome::ALL)?,
            channel: if u.arbitrary()? {
                Some(pick(u, SchemaChannel::ALL)?)
            } else {
                None
            },
            id: u.arbitrary()?,
            queued: u.arbitrary()?,
            stop: u.int_in_range(0..=63)?,
        }),
        25 => Message::SchemaTransition(SchemaTransition {
            ended: u.arbitrary()?,
            installed: u.arbitrary()?,
            trigger: pick(u, SchemaTrigger::ALL)?,
            // Any byte: a detail that contradicts the trigger must be refused.
            detail: if u.ratio(1u8, 4)? { 0 } else { u.arbitrary()? },
            source: pick(u, SchemaOrigin::ALL)?,
            queued: u.arbitrary()?,
        }),
        26 => Message::SchemaState(SchemaState {
            current: u.arbitrary()?,
            source: pick(u, SchemaOrigin::ALL)?,
            fault: if u.arbitrary()? {
                Some(pick(u, SchemaSafety::ALL)?)
            } else {
                None
            },
            queued: u.arbitrary()?,
            armed: u.arbitrary()?,
            gripper_closed: u.arbitrary()?,
            stop: u.int_in_range(0..=63)?,
            elapsed_ms: u.arbitrary()?,
        }),
        // Any kind byte: one nothing seals must be refused.
        27 => Message::Seal(Seal {
            kind: if u.ratio(1u8, 4)? {
                u.arbitrary()?
            } else {
                pick(u, &[0x07, 0x17, 0x18, 0x20, Seal::CLAIM])?
            },
            digest: u.arbitrary()?,
            counter: u.arbitrary()?,
            tag: u.arbitrary()?,
        }),
        28 => Message::FreshnessRequest {
            nonce: u.arbitrary()?,
        },
        29 => Message::Freshness {
            epoch: u.arbitrary()?,
            counter: u.arbitrary()?,
        },
        30 => Message::IdentityRequest,
        part @ 31..=36 => {
            // A valid identity part (one variant per part, so that a seed reaches each): reserved bytes zero, known flags and features, an
            // ordered format range, a printable name.
            let identity = Identity {
                uid: u.arbitrary()?,
                firmware: Firmware {
                    name: pick(u, &[*b"pab-node", *b"fw-g474\0", *b"\0\0\0\0\0\0\0\0"])?,
                    version: u.arbitrary()?,
                    build: u.arbitrary()?,
                },
                protocol: u.arbitrary()?,
                formats: {
                    let (a, b): (u8, u8) = (u.arbitrary()?, u.arbitrary()?);
                    [a.min(b), a.max(b)]
                },
                capacity: Capacity {
                    ports: u.arbitrary()?,
                    connections: u.arbitrary()?,
                    decision_nodes: u.arbitrary()?,
                    image_len: u.arbitrary()?,
                },
                features: u.int_in_range(0..=0x0F)?,
                flags: u.int_in_range(0..=0x1F)?,
                bitrate_kbps: u.arbitrary()?,
            };
            let part = IdentityPart::from_index(part - 31).unwrap_or(IdentityPart::Uid);
            Message::Identity {
                part,
                payload: identity.payload(part),
            }
        }
        37 => Message::Assign(Assign {
            uid_check: u.int_in_range(0..=0x00FF_FFFF)?,
            node_id: u.int_in_range(1..=127)?,
            tag: u.arbitrary()?,
        }),
        38 => Message::Configure(Configure {
            bitrate_kbps: u.arbitrary()?,
            tag: u.arbitrary()?,
        }),
        39 => Message::ConfigStatus(ConfigStatus {
            command: pick(u, &[Service::Assign.code(), Service::Configure.code()])?,
            status: pick(u, ConfigStatusCode::ALL)?,
            node_id: u.int_in_range(0..=127)?,
            bitrate_kbps: u.arbitrary()?,
        }),
        40 => Message::UpdateTransfer {
            data: u.arbitrary()?,
            len: u.int_in_range(1..=8)?,
        },
        // Any offset: one beyond 24 bits is sent saturated (`normalized`).
        41 => Message::UpdateStatus(UpdateStatus {
            status: pick(u, UpdateStatusCode::ALL)?,
            offset: u.arbitrary()?,
            value: u.arbitrary()?,
        }),
        _ => Message::TransferStatus(TransferStatus {
            status: pick(u, TransferStatusCode::ALL)?,
            detail: u.arbitrary()?,
            running_version: u.arbitrary()?,
        }),
    };
    Ok((message, u.arbitrary()?, u.arbitrary()?))
}

/// One input per service for each target, named after the service: the `protocol_decode` input
/// makes a frame of that service at its priority with a well-formed payload, the
/// `protocol_encode` input a message of that service (`DiagnosticControl`'s tagged form
/// included), so that the replayed corpus exercises every service whatever campaigns keep.
/// Returns `(service, decode input, encode input)`.
pub fn service_seeds() -> Vec<(Service, Vec<u8>, Vec<u8>)> {
    let filler: Vec<u8> = (0u8..64)
        .map(|i| i.wrapping_mul(37).wrapping_add(11))
        .collect();
    let mut seeds: Vec<(Service, Vec<u8>, Vec<u8>)> = Vec::new();
    // `any_message`'s first byte picks the variant (byte % 42).
    for pick in 0u8..=41 {
        let mut encode = vec![pick];
        encode.extend_from_slice(&filler);
        let Ok((message, source, destination)) = any_message(&mut Unstructured::new(&encode))
        else {
            continue;
        };
        let service = message.service();
        if seeds.iter().any(|(seen, _, _)| *seen == service) {
            continue;
        }
        // `any_frame`: not standard (1), ours (0), the priority, the service code, the two
        // address bytes, then a length of its own (0, then the length), not remote (1), the
        // payload.
        let frame = message.to_frame(source, destination);
        let payload = frame.payload();
        let mut decode = vec![
            1,
            0,
            service.priority().value(),
            service.code(),
            destination,
            source,
            0,
            payload.len() as u8,
            1,
        ];
        decode.extend_from_slice(payload);
        seeds.push((service, decode, encode));
    }
    seeds
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_service_has_a_seed_in_the_committed_corpus() {
        let seeds = service_seeds();
        let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../corpus");
        for service in Service::ALL {
            let (_, decode_input, encode_input) = seeds
                .iter()
                .find(|(seen, _, _)| *seen == service)
                .unwrap_or_else(|| panic!("no seed reaches {service:?}"));
            // The decode input is a frame of the service at its priority, and a node or a tool
            // reads its payload (no framing error).
            let frame = any_frame(&mut Unstructured::new(decode_input)).unwrap();
            let id = FrameId::decode(&frame.id()).unwrap();
            assert_eq!(id.service, service);
            assert!(id.has_service_priority());
            assert!(
                !matches!(
                    Message::decode(&frame),
                    Err(protocol::DecodeError::Length { .. }
                        | protocol::DecodeError::Priority { .. }
                        | protocol::DecodeError::Remote)
                ),
                "{service:?}"
            );
            decode(decode_input);
            encode(encode_input);
            for (target, input) in [
                ("protocol_decode", decode_input),
                ("protocol_encode", encode_input),
            ] {
                let path = corpus
                    .join(target)
                    .join(format!("seed-service-{service:?}"));
                let committed = std::fs::read(&path).unwrap_or_else(|error| {
                    panic!(
                        "{}: {error} (cargo run -p pab-fuzz-checks --example seeds -- {target})",
                        path.display()
                    )
                });
                assert_eq!(&committed, input, "{}", path.display());
            }
        }
    }
}
