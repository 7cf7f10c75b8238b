use crate::frame::Frame;
#[cfg(feature = "identity")]
use crate::identity::{Capacity, Firmware, Identity, IdentityPart};
use crate::protocol::*;

pub(super) fn samples() -> Vec<Message> {
    // `mut` for the identity and update messages' extensions below.
    #[cfg_attr(not(any(feature = "identity", feature = "update")), allow(unused_mut))]
    let mut all = vec![
        Message::Fault(Fault {
            code: FaultCode::TableRefused,
            count: 3,
            detail: [0x16, 0, 0, 0, 9],
        }),
        Message::Heartbeat(Heartbeat {
            state: NodeState::Operational,
            uptime_s: 0x12_3456,
            table_version: 7,
        }),
        Message::TableStatus(TableStatus {
            crc: 0xDEAD_BEEF,
            image_len: 177,
            ports: 1,
            stored: true,
            diagnostic: false,
            keyed: true,
        }),
        Message::Traffic(Traffic {
            received: 1_000_000,
            delivered: 42,
        }),
        Message::Errors(Errors {
            discarded: 5,
            errors: u32::MAX,
        }),
        Message::Diagnostic(DiagnosticSample {
            port: 2,
            connection: 15,
            flags: DiagnosticFlags {
                active: true,
                resting: false,
                delivering: true,
                end_of_round: true,
            },
            sequence: 200,
            level: 1 << 30,
        }),
        Message::DiagnosticControl(DiagnosticControl {
            rate_hz: 20,
            ports: 0b101,
        }),
        Message::TableTransfer {
            data: [0x10, 0x14, 1, 2, 3, 4, 5, 6],
            len: 8,
        },
        Message::TransferStatus(TransferStatus {
            status: TransferStatusCode::OlderVersion,
            detail: 0,
            running_version: 9,
        }),
        Message::AuthenticatedDiagnosticControl {
            control: DiagnosticControl {
                rate_hz: 200,
                ports: 1,
            },
            tag: [1, 2, 3, 4],
        },
        Message::ChallengeRequest {
            tool_nonce: 0x0102_0304_0506_0708,
        },
        Message::Challenge {
            node_nonce: 0x0000_0304_0506_0708,
            binding: [0xA1, 0xB2],
        },
        Message::TransferOpen(TransferOpen {
            length: 300,
            flags: OPEN_REPLACE,
            tag: [9, 8, 7, 6, 5],
        }),
        Message::Receipt {
            tag: [1, 2, 3, 4, 5, 6, 7, 8],
        },
        Message::Seal(Seal {
            kind: Seal::CLAIM,
            digest: 0x5C,
            counter: 0x1234,
            tag: [0xDE, 0xAD, 0xBE, 0xEF],
        }),
        Message::FreshnessRequest {
            nonce: 0x1122_3344_5566_7788,
        },
        Message::Freshness {
            epoch: 0x0A0B_0C0D,
            counter: 0x0102_0304,
        },
        Message::Desire(DesireFrame {
            class: 2,
            intensity: 65_535,
            lease_ms: 500,
            id: 0x0102,
        }),
        Message::Intention(Intention {
            strategies: 1 << 63 | 0b101,
        }),
        Message::FilterStatus(FilterStatus {
            profile: FilterStatus::SET_ONE_BY_ONE,
            sequence: 0xBEEF,
            filtered: 5,
            closed: 2,
            throttled: 3,
        }),
        Message::Exploitation(Exploitation {
            port: 1,
            connection: 4,
            delivering: true,
        }),
        Message::FilterProfile(FilterProfile {
            profile: 15,
            sequence: 7,
        }),
        Message::FilterSet(FilterSet {
            port: 0,
            connection: 3,
            phi: 3,
            sequence: 0xFFFF,
        }),
        Message::EmergencyStop,
        Message::SchemaAbort,
        Message::SchemaTransfer {
            data: [0x05, 1, 7, 0, 2, 0, 0, 0],
            len: 6,
        },
        Message::SchemaAck(SchemaAck {
            outcome: SchemaOutcome::QueueFull,
            channel: Some(SchemaChannel::Queue),
            id: 0x0102,
            queued: 8,
            stop: 63,
        }),
        Message::SchemaTransition(SchemaTransition {
            ended: 7,
            installed: 0xFF12,
            trigger: SchemaTrigger::Safety,
            detail: SchemaSafety::Limit.code(),
            source: SchemaOrigin::Innate,
            queued: 3,
        }),
        Message::SchemaState(SchemaState {
            current: 0xFF01,
            source: SchemaOrigin::HighPriority,
            fault: Some(SchemaSafety::Overrun),
            queued: 2,
            armed: true,
            gripper_closed: false,
            stop: 63,
            elapsed_ms: u16::MAX,
        }),
    ];
    #[cfg(feature = "update")]
    all.extend([
        Message::TransferOpen(TransferOpen {
            length: 97,
            flags: OPEN_UPDATE,
            tag: [1, 2, 3, 4, 5],
        }),
        // A Chunk's first frame: 1 + 4 + 1024 bytes (0x405).
        Message::UpdateTransfer {
            data: [0x14, 0x05, 2, 0, 0x04, 0, 0, 0xAA],
            len: 8,
        },
        // An Abort as a single frame, unpadded.
        Message::UpdateTransfer {
            data: [0x01, 4, 0, 0, 0, 0, 0, 0],
            len: 2,
        },
        Message::UpdateStatus(UpdateStatus {
            status: UpdateStatusCode::Ack,
            offset: 0x01_2345,
            value: 0xDEAD_BEEF,
        }),
        Message::UpdateStatus(UpdateStatus {
            status: UpdateStatusCode::Ready,
            offset: 0,
            value: 1024,
        }),
        Message::UpdateStatus(UpdateStatus {
            status: UpdateStatusCode::Busy,
            offset: UpdateStatus::MAX_OFFSET,
            value: 0,
        }),
    ]);
    #[cfg(feature = "identity")]
    all.extend([
        Message::IdentityRequest,
        Message::Assign(Assign {
            uid_check: 0x00AB_CDEF,
            node_id: 127,
            tag: None,
        }),
        Message::Assign(Assign {
            uid_check: 0x0012_3456,
            node_id: 1,
            tag: Some([1, 2, 3, 4]),
        }),
        Message::Configure(Configure {
            bitrate_kbps: 1000,
            tag: None,
        }),
        Message::Configure(Configure {
            bitrate_kbps: 250,
            tag: Some([0xFF, 0, 0xFF, 0]),
        }),
        Message::ConfigStatus(ConfigStatus {
            command: Service::Assign.code(),
            status: ConfigStatusCode::Stored,
            node_id: 9,
            bitrate_kbps: 500,
        }),
        Message::ConfigStatus(ConfigStatus {
            command: Service::Configure.code(),
            status: ConfigStatusCode::BadValue,
            node_id: 0,
            bitrate_kbps: 0xFFFF,
        }),
        identity_sample(IdentityPart::Uid),
        identity_sample(IdentityPart::Version),
        identity_sample(IdentityPart::Build),
        identity_sample(IdentityPart::Capacity),
        identity_sample(IdentityPart::Features),
        identity_sample(IdentityPart::Name),
    ]);
    all
}

/// Each schema report and its bytes, as docs/can-protocol.md lays them out.
#[test]
fn schema_frames_are_byte_exact() {
    let ack = Message::SchemaAck(SchemaAck {
        outcome: SchemaOutcome::Accepted,
        channel: Some(SchemaChannel::HighPriority),
        id: 0x0304,
        queued: 5,
        stop: 9,
    });
    assert_eq!(ack.to_frame(10, 0).payload(), &[0, 1, 4, 3, 5, 9, 0, 0]);
    let unreadable = Message::SchemaAck(SchemaAck {
        outcome: SchemaOutcome::TooLong,
        channel: None,
        id: SchemaAck::NO_ID,
        queued: 0,
        stop: 0,
    });
    assert_eq!(
        unreadable.to_frame(10, 0).payload(),
        &[0x0B, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0]
    );
    let change = Message::SchemaTransition(SchemaTransition {
        ended: 0x0102,
        installed: 0x0304,
        trigger: SchemaTrigger::Reaction,
        detail: 2,
        source: SchemaOrigin::Queue,
        queued: 6,
    });
    assert_eq!(
        change.to_frame(10, BROADCAST).payload(),
        &[2, 1, 4, 3, 3, 2, 1, 6]
    );
    let state = Message::SchemaState(SchemaState {
        current: 0x0102,
        source: SchemaOrigin::Queue,
        fault: None,
        queued: 4,
        armed: true,
        gripper_closed: true,
        stop: 5,
        elapsed_ms: 0x0304,
    });
    assert_eq!(
        state.to_frame(10, BROADCAST).payload(),
        &[2, 1, 1, 0xFF, 4, 0b0001_0111, 4, 3]
    );
    assert_eq!(SchemaState::saturate_ms(70_000), u16::MAX);
    assert_eq!(SchemaState::saturate_ms(1_234), 1_234);
    // The emergency stop from the tool to all: the lowest identifier of ours, no payload.
    let stop = Message::EmergencyStop.to_frame(0, BROADCAST);
    assert!(stop.payload().is_empty());
    assert_eq!(
        FrameId::decode(&stop.id()).map(|id| id.raw()),
        Some(0x0200_FF00)
    );
}

#[test]
fn schema_frames_refuse_unknown_codes_reserved_bits_and_bytes() {
    let refused = |service: Service, payload: &[u8]| {
        let id = FrameId::new(service, 10, BROADCAST).id();
        let frame = Frame::data(id, payload).unwrap();
        let full = Message::decode(&frame) == Err(DecodeError::Value { service });
        // A node reads none of these reports: well framed, they are not its business.
        full && Message::decode_for_node(&frame) == Ok(None)
    };
    let accepted = |service: Service, payload: &[u8]| {
        let id = FrameId::new(service, 10, BROADCAST).id();
        Message::decode(&Frame::data(id, payload).unwrap()).is_ok()
    };
    // SchemaAck: outcome past 0x11, channel neither 0, 1, 2 nor 0xFF, a stop number of 64 or
    // more, reserved bytes 6-7.
    assert!(accepted(
        Service::SchemaAck,
        &[0x11, 0xFF, 0, 0, 0, 63, 0, 0]
    ));
    assert!(accepted(
        Service::SchemaAck,
        &[0x11, 2, 0xFF, 0xFF, 0, 0, 0, 0]
    ));
    assert!(refused(Service::SchemaAck, &[0x12, 0, 0, 0, 0, 0, 0, 0]));
    assert!(refused(Service::SchemaAck, &[0, 3, 0, 0, 0, 0, 0, 0]));
    assert!(refused(Service::SchemaAck, &[0, 0, 0, 0, 0, 64, 0, 0]));
    for at in 6..8 {
        let mut payload = [0u8; 8];
        payload[at] = 1;
        assert!(refused(Service::SchemaAck, &payload), "byte {at}");
    }
    // SchemaTransition: trigger past 3, source past 2, a detail that contradicts its trigger.
    assert!(accepted(
        Service::SchemaTransition,
        &[1, 0, 0, 0xFF, 3, 255, 2, 8]
    ));
    assert!(accepted(
        Service::SchemaTransition,
        &[1, 0, 0x15, 0xFF, 2, 5, 0, 8]
    ));
    assert!(refused(
        Service::SchemaTransition,
        &[1, 0, 0, 0, 4, 0, 0, 0]
    ));
    assert!(refused(
        Service::SchemaTransition,
        &[1, 0, 0, 0, 0, 0, 3, 0]
    ));
    assert!(refused(
        Service::SchemaTransition,
        &[1, 0, 0x19, 0xFF, 2, 9, 0, 0]
    ));
    assert!(refused(
        Service::SchemaTransition,
        &[1, 0, 0, 0, 0, 1, 2, 0]
    ));
    assert!(refused(
        Service::SchemaTransition,
        &[1, 0, 1, 0xFF, 1, 1, 2, 0]
    ));
    // SchemaState: source past 2, an unknown safety event; every flags byte is valid (its
    // bits 2-7 are the stop number).
    assert!(accepted(
        Service::SchemaState,
        &[0, 0, 2, 5, 8, 0xFF, 0xFF, 0xFF]
    ));
    assert!(refused(Service::SchemaState, &[0, 0, 3, 0xFF, 0, 0, 0, 0]));
    assert!(refused(Service::SchemaState, &[0, 0, 0, 9, 0, 0, 0, 0]));
}

#[test]
fn a_node_reads_the_stop_the_abort_and_schema_transfers_only() {
    for message in samples() {
        let frame = message.to_frame(0, 10);
        let for_node = Message::decode_for_node(&frame).unwrap();
        let acts = matches!(
            message.service(),
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
        );
        assert_eq!(for_node.is_some(), acts, "{message:?}");
        if let Some((_, decoded)) = for_node {
            assert_eq!(decoded, message);
        }
    }
    // The stop and the abort have no payload: any byte makes them malformed, for a node too.
    for service in [Service::EmergencyStop, Service::SchemaAbort] {
        let id = FrameId::new(service, 0, BROADCAST).id();
        let padded = Frame::data(id, &[0]).unwrap();
        let error = DecodeError::Length { service, len: 1 };
        assert_eq!(Message::decode_for_node(&padded), Err(error));
        assert_eq!(Message::decode(&padded), Err(error));
    }
}

#[test]
fn every_message_round_trips() {
    for message in samples() {
        let frame = message.to_frame(3, BROADCAST);
        let (id, decoded) = Message::decode(&frame).unwrap();
        assert_eq!(decoded, message);
        assert_eq!(id.source, 3);
        assert_eq!(id.destination, BROADCAST);
        assert_eq!(id.service, message.service());
        if super::layout_tests::is_tagged(&message) {
            assert_eq!(frame.payload().len(), 8);
        } else if let Message::SchemaTransfer { len, .. } = message {
            assert_eq!(frame.payload().len(), usize::from(len));
        } else if message.service() == Service::UpdateTransfer {
            assert!(!frame.payload().is_empty());
        } else if message.service() != Service::TableTransfer {
            assert_eq!(frame.payload().len(), message.service().payload_len());
        }
    }
}

#[test]
fn a_nodes_encoder_is_to_frame_without_the_commands() {
    for message in samples() {
        let command = matches!(
            message.service(),
            Service::DiagnosticControl
                | Service::ChallengeRequest
                | Service::TransferOpen
                | Service::Desire
                | Service::Intention
                | Service::FilterProfile
                | Service::FilterSet
                | Service::EmergencyStop
                | Service::SchemaAbort
                | Service::IdentityRequest
                | Service::Assign
                | Service::Configure
        );
        let expected = (!command).then(|| message.to_frame(3, 9));
        assert_eq!(message.report_frame(3, 9), expected, "{message:?}");
    }
}

#[test]
fn payloads_are_byte_exact() {
    let heartbeat = Message::Heartbeat(Heartbeat {
        state: NodeState::Fault,
        uptime_s: 0x0102_0304, // saturates to 2^24 - 1 on the wire
        table_version: 0x0A0B_0C0D,
    });
    assert_eq!(
        heartbeat.to_frame(5, BROADCAST).payload(),
        &[2, 0xFF, 0xFF, 0xFF, 0x0D, 0x0C, 0x0B, 0x0A]
    );
    let status = Message::TransferStatus(TransferStatus {
        status: TransferStatusCode::Applied,
        detail: 0,
        running_version: 0x0102_0304,
    });
    assert_eq!(status.to_frame(5, 0).payload(), &[0, 0, 4, 3, 2, 1, 0, 0]);
    let control = Message::DiagnosticControl(DiagnosticControl {
        rate_hz: 10,
        ports: 0xFFFF,
    });
    assert_eq!(control.to_frame(0, 5).payload(), &[10, 0, 0xFF, 0xFF]);
    let desire = Message::Desire(DesireFrame {
        class: 3,
        intensity: 0x0102,
        lease_ms: 0x0304,
        id: 0x0506,
    });
    assert_eq!(
        desire.to_frame(9, BROADCAST).payload(),
        &[3, 0, 2, 1, 4, 3, 6, 5]
    );
    let set = Message::FilterSet(FilterSet {
        port: 1,
        connection: 2,
        phi: 3,
        sequence: 0x0405,
    });
    assert_eq!(set.to_frame(9, 2).payload(), &[1, 2, 3, 0, 5, 4]);
    let status = Message::FilterStatus(FilterStatus {
        profile: 4,
        sequence: 0x0102,
        filtered: 6,
        closed: 1,
        throttled: 2,
    });
    assert_eq!(
        status.to_frame(2, BROADCAST).payload(),
        &[4, 0, 2, 1, 6, 1, 2, 0]
    );
}

#[test]
fn hbba_frames_refuse_reserved_bytes_and_impossible_counts() {
    let refused = |service: Service, payload: &[u8]| {
        let id = FrameId::new(service, 1, BROADCAST).id();
        let frame = Frame::data(id, payload).unwrap();
        matches!(Message::decode(&frame), Err(DecodeError::Value { .. }))
    };
    assert!(refused(Service::Desire, &[0, 1, 1, 0, 1, 0, 0, 0]));
    // More closed and throttled filters than filtered ones; a profile past 15; reserved bytes.
    assert!(refused(Service::FilterStatus, &[0, 0, 0, 0, 2, 2, 1, 0]));
    assert!(refused(Service::FilterStatus, &[16, 0, 0, 0, 2, 0, 0, 0]));
    assert!(refused(Service::FilterStatus, &[0, 1, 0, 0, 2, 0, 0, 0]));
    assert!(refused(Service::FilterStatus, &[0, 0, 0, 0, 2, 0, 0, 1]));
    assert!(refused(Service::Exploitation, &[0, 0, 2, 0]));
    assert!(refused(Service::Exploitation, &[0, 0, 1, 1]));
    assert!(refused(Service::FilterProfile, &[0, 1, 0, 0]));
    assert!(refused(Service::FilterSet, &[0, 0, 1, 1, 0, 0]));
}

#[test]
fn wrong_lengths_and_values_are_refused() {
    for message in samples() {
        let frame = message.to_frame(1, 0);
        let payload = frame.payload();
        if matches!(
            message.service(),
            Service::TableTransfer | Service::SchemaTransfer | Service::UpdateTransfer
        ) {
            let empty = Frame::data(frame.id(), &[]).unwrap();
            assert!(matches!(
                Message::decode(&empty),
                Err(DecodeError::Length { .. })
            ));
            continue;
        }
        for len in 0..=8 {
            // DiagnosticControl has two valid lengths: its plain and its tagged form.
            let other_form = matches!(
                message.service(),
                Service::DiagnosticControl | Service::Assign | Service::Configure
            ) && (len == 4 || len == 8);
            if len == payload.len() || other_form {
                continue;
            }
            let mut data = [0u8; 8];
            data[..payload.len()].copy_from_slice(payload);
            let short = Frame::data(frame.id(), &data[..len]).unwrap();
            assert_eq!(
                Message::decode(&short),
                Err(DecodeError::Length {
                    service: message.service(),
                    len: len as u8
                })
            );
        }
    }
    let id = FrameId::new(Service::Heartbeat, 1, BROADCAST).id();
    let bad_state = Frame::data(id, &[9, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    assert!(matches!(
        Message::decode(&bad_state),
        Err(DecodeError::Value { .. })
    ));
    let id = FrameId::new(Service::DiagnosticControl, 0, 1).id();
    let too_fast = Frame::data(id, &[201, 0, 1, 0]).unwrap();
    assert!(matches!(
        Message::decode(&too_fast),
        Err(DecodeError::Value { .. })
    ));
    let id = FrameId::new(Service::TransferStatus, 1, 0).id();
    let reserved = Frame::data(id, &[0, 0, 1, 0, 0, 0, 0, 1]).unwrap();
    assert!(matches!(
        Message::decode(&reserved),
        Err(DecodeError::Value { .. })
    ));
    // TransferOpen: a reserved flag bit, and two kinds together (replace and schema, update
    // with either), are refused.
    let id = FrameId::new(Service::TransferOpen, 0, 1).id();
    for flags in [
        8,
        0x80,
        OPEN_REPLACE | OPEN_SCHEMA,
        OPEN_UPDATE | OPEN_REPLACE,
        OPEN_UPDATE | OPEN_SCHEMA,
        OPEN_UPDATE | OPEN_SCHEMA | OPEN_REPLACE,
    ] {
        let refused = Frame::data(id, &[0, 1, flags, 0, 0, 0, 0, 0]).unwrap();
        assert!(
            matches!(Message::decode(&refused), Err(DecodeError::Value { .. })),
            "flags {flags:#04x}"
        );
    }
    for flags in [0, OPEN_REPLACE, OPEN_SCHEMA, OPEN_UPDATE] {
        let taken = Frame::data(id, &[0, 1, flags, 0, 0, 0, 0, 0]).unwrap();
        assert!(Message::decode(&taken).is_ok(), "flags {flags:#04x}");
    }
    let id = FrameId::new(Service::TableStatus, 1, BROADCAST).id();
    let reserved_bit = Frame::data(id, &[0, 0, 0, 0, 0, 0, 0, 8]).unwrap();
    assert!(matches!(
        Message::decode(&reserved_bit),
        Err(DecodeError::Value { .. })
    ));
    let id = FrameId::new(Service::TransferStatus, 1, 0).id();
    let remote = <Frame as embedded_can::Frame>::new_remote(id, 8).unwrap();
    assert_eq!(Message::decode(&remote), Err(DecodeError::Remote));
}

#[test]
fn arbitrary_frames_never_panic() {
    // Every service, every length, a spread of byte patterns.
    let mut seed = 0x1234_5678u32;
    for _ in 0..20_000 {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        let raw = (seed & 0x1FFF_FFFF) | 0b10 << 24;
        let len = (seed >> 29) as usize + 1;
        let data = seed.to_le_bytes();
        let mut bytes = [0u8; 8];
        bytes[..4].copy_from_slice(&data);
        bytes[4..].copy_from_slice(&data.map(|b| b.rotate_left(3)));
        let frame = Frame::with_raw_id(raw, true, &bytes[..len.min(8)]).unwrap();
        let _ = Message::decode(&frame);
    }
}

/// One part of a sample identity (every field non-zero, every flag set).
#[cfg(feature = "identity")]
pub(super) fn identity_sample(part: IdentityPart) -> Message {
    let identity = Identity {
        uid: [
            0x10, 0x21, 0x32, 0x43, 0x54, 0x65, 0x76, 0x87, 0x98, 0xA9, 0xBA, 0xCB,
        ],
        firmware: Firmware::new("fw-g474", "1.2.3", "89abcdef01234567"),
        protocol: crate::identity::PROTOCOL_VERSION,
        formats: [9, 10],
        capacity: Capacity {
            ports: 16,
            connections: 512,
            decision_nodes: 2048,
            image_len: 32768,
        },
        features: 0b1111,
        flags: 0x1F,
        bitrate_kbps: 1000,
    };
    Message::Identity {
        part,
        payload: identity.payload(part),
    }
}

#[test]
#[cfg(feature = "identity")]
fn identity_frames_with_reserved_bits_or_unknown_codes_are_refused() {
    let refused = |service: Service, payload: &[u8]| {
        let frame = Frame::data(FrameId::new(service, 3, TOOL).id(), payload).unwrap();
        matches!(Message::decode(&frame), Err(DecodeError::Value { .. }))
    };
    assert!(refused(
        Service::IdentityCapacity,
        &[1, 0, 0, 0, 0, 0, 0, 1]
    ));
    assert!(refused(
        Service::IdentityFeatures,
        &[10, 10, 0, 0, 0x20, 0, 0, 0]
    ));
    assert!(refused(
        Service::IdentityFeatures,
        &[10, 10, 0, 0, 0, 1, 0, 0]
    ));
    assert!(refused(
        Service::IdentityFeatures,
        &[11, 10, 0, 0, 0, 0, 0, 0]
    ));
    assert!(refused(Service::IdentityName, b"pab\0x\0\0\0"));
    // Assign: node id 0 or above 127; Configure: its reserved half.
    let to_node = |service: Service, payload: &[u8]| {
        let frame = Frame::data(FrameId::new(service, TOOL, 5).id(), payload).unwrap();
        Message::decode_for_node(&frame)
    };
    assert!(to_node(Service::Assign, &[1, 2, 3, 0]).is_err());
    assert!(to_node(Service::Assign, &[1, 2, 3, 128]).is_err());
    assert!(to_node(Service::Configure, &[0xF4, 1, 0, 1]).is_err());
    // A 5- to 7-byte command is neither form.
    assert!(to_node(Service::Assign, &[1, 2, 3, 4, 5]).is_err());
    // ConfigStatus: an unknown command or status, a reserved byte.
    assert!(refused(Service::ConfigStatus, &[0x27, 0, 1, 0, 0, 0, 0, 0]));
    assert!(refused(
        Service::ConfigStatus,
        &[0x28, 0x09, 1, 0, 0, 0, 0, 0]
    ));
    assert!(refused(Service::ConfigStatus, &[0x28, 0, 1, 1, 0, 0, 0, 0]));
}

/// UpdateStatus's bytes as docs/can-protocol.md lays them out, and what its decoder refuses.
#[test]
#[cfg(feature = "update")]
fn update_status_is_byte_exact_and_refuses_other_lengths_and_codes() {
    let ack = Message::UpdateStatus(UpdateStatus {
        status: UpdateStatusCode::Ack,
        offset: 0x01_2345,
        value: 0xDEAD_BEEF,
    });
    let frame = ack.to_frame(3, TOOL);
    assert_eq!(
        frame.payload(),
        &[2, 0x45, 0x23, 0x01, 0xEF, 0xBE, 0xAD, 0xDE]
    );
    assert_eq!(Message::decode(&frame).map(|(_, m)| m), Ok(ack));
    assert_eq!(
        FrameId::decode(&frame.id()).map(|id| id.raw()),
        Some(0x0A2C_0003)
    );
    // An offset beyond 24 bits is sent saturated (`UpdateStatus::MAX_OFFSET`).
    let beyond = Message::UpdateStatus(UpdateStatus {
        status: UpdateStatusCode::FlashError,
        offset: 0x0100_0000,
        value: 0,
    });
    assert_eq!(
        beyond.to_frame(3, TOOL).payload(),
        &[7, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0]
    );
    let id = FrameId::new(Service::UpdateStatus, 3, TOOL).id();
    let decode = |payload: &[u8]| Message::decode(&Frame::data(id, payload).unwrap());
    assert_eq!(
        decode(&[2, 0x45, 0x23, 0x01, 0xEF, 0xBE, 0xAD]),
        Err(DecodeError::Length {
            service: Service::UpdateStatus,
            len: 7
        })
    );
    for status in [0, 13, 0xFF] {
        assert_eq!(
            decode(&[status, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::Value {
                service: Service::UpdateStatus
            }),
            "status {status}"
        );
    }
    // A node reads none: it sends them.
    let well_formed = Frame::data(id, &[1, 0, 0, 0, 0, 4, 0, 0]).unwrap();
    assert_eq!(Message::decode_for_node(&well_formed), Ok(None));
    // UpdateTransfer: ISO-TP frames at the table transfer's priority, for a node.
    let transfer = Message::UpdateTransfer {
        data: [0x05, 3, 0x78, 0x56, 0x34, 0x12, 0, 0],
        len: 6,
    }
    .to_frame(TOOL, 3);
    assert_eq!(
        FrameId::decode(&transfer.id()).map(|id| id.raw()),
        Some(0x1A2B_0300)
    );
    assert!(matches!(
        Message::decode_for_node(&transfer),
        Ok(Some((_, Message::UpdateTransfer { len: 6, .. })))
    ));
}
