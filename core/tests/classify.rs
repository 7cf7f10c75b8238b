//! `protocol::classify`: every frame is of exactly one kind, and the kind agrees with the
//! decoders that read it (`FrameId` parsing, `Message::decode`, `Claim::decode`) and with the
//! identifier layout (`PROTOCOL_MASK`, bit 23).

use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use pab_core::ble::{Claim, ClaimError};
use pab_core::frame::Frame;
use pab_core::protocol::{
    self, BROADCAST, DecodeError, FrameId, FrameKind, Message, PROTOCOL_MASK, PROTOCOL_VALUE,
    Service,
};
use proptest::prelude::*;

/// The kind a frame must have, from the layout alone, written out as the documentation says it.
fn expected(id: &Id) -> FrameKind {
    let Id::Extended(id) = id else {
        return FrameKind::Topic;
    };
    let raw = id.as_raw();
    if raw & PROTOCOL_MASK != PROTOCOL_VALUE {
        FrameKind::Topic
    } else if raw & 1 << 23 != 0 {
        FrameKind::Claim
    } else {
        match Service::ALL
            .into_iter()
            .find(|s| s.code() == (raw >> 16) as u8)
        {
            Some(service) => FrameKind::Service(FrameId {
                priority: protocol::Priority::new((raw >> 26) as u8).unwrap(),
                service,
                destination: (raw >> 8) as u8,
                source: raw as u8,
            }),
            None => FrameKind::UnknownService,
        }
    }
}

/// What the kind says of the decoders.
fn agrees(frame: &Frame) -> Result<(), TestCaseError> {
    let kind = protocol::classify(frame);
    prop_assert_eq!(kind, protocol::classify_id(&frame.id()));
    prop_assert_eq!(kind, expected(&frame.id()));
    prop_assert_eq!(kind.is_ours(), protocol::is_ours(&frame.id()));
    let decoded = Message::decode(frame);
    let claim = Claim::decode(frame);
    match kind {
        FrameKind::Service(id) => {
            prop_assert_eq!(FrameId::decode(&frame.id()), Some(id));
            prop_assert_ne!(decoded.err(), Some(DecodeError::NotOurs));
            prop_assert_eq!(claim, Err(ClaimError::NotAClaim));
        }
        FrameKind::Claim => {
            prop_assert_eq!(FrameId::decode(&frame.id()), None);
            prop_assert_eq!(decoded.err(), Some(DecodeError::NotOurs));
            // By identifier: a remote claim is a claim the decoder refuses.
            prop_assert!(frame.is_remote() || claim != Err(ClaimError::NotAClaim));
        }
        FrameKind::Topic | FrameKind::UnknownService => {
            prop_assert_eq!(FrameId::decode(&frame.id()), None);
            prop_assert_eq!(decoded.err(), Some(DecodeError::NotOurs));
            prop_assert_eq!(claim, Err(ClaimError::NotAClaim));
        }
    }
    Ok(())
}

/// Identifiers that reach every kind often: a third anywhere, the rest with our marker.
fn any_id() -> impl Strategy<Value = Id> {
    prop_oneof![
        (0u16..=0x7FF).prop_map(|raw| Id::Standard(StandardId::new(raw).unwrap())),
        (0u32..(1 << 29)).prop_map(|raw| Id::Extended(ExtendedId::new(raw).unwrap())),
        (0u32..(1 << 29)).prop_map(|raw| {
            let raw = raw & !PROTOCOL_MASK | PROTOCOL_VALUE;
            Id::Extended(ExtendedId::new(raw).unwrap())
        }),
    ]
}

proptest! {
    #[test]
    fn every_frame_is_of_one_kind_the_decoders_agree_with(
        id in any_id(),
        remote in any::<bool>(),
        data in prop::collection::vec(any::<u8>(), 0..=8),
    ) {
        let frame = if remote {
            Frame::new_remote(id, data.len()).unwrap()
        } else {
            Frame::data(id, &data).unwrap()
        };
        agrees(&frame)?;
    }
}

/// The frames we send are of the kind they are sent as.
#[test]
fn our_own_frames_are_of_their_kind() {
    for service in Service::ALL {
        let id = FrameId::new(service, 3, BROADCAST);
        let frame = Frame::data(id.id(), &[]).unwrap();
        assert_eq!(protocol::classify(&frame), FrameKind::Service(id));
    }
    for eligibility in [0, 1, 0x7FFF, 0x8000, u16::MAX] {
        let claim = Claim {
            group: 1,
            node: 127,
            eligibility,
        };
        let frame = claim.frame().unwrap();
        assert_eq!(
            protocol::classify(&frame),
            FrameKind::Claim,
            "{eligibility}"
        );
    }
    // A claim's bits 23..16 are bit 23 and the top of its inverted eligibility (0x80 for
    // eligibility 0xFFFF, 0xFF for 0): never a service code, all of which stay below 0x80.
    let standard = Frame::data(StandardId::new(0x123).unwrap(), &[1]).unwrap();
    assert_eq!(protocol::classify(&standard), FrameKind::Topic);
    let unknown = Frame::data(ExtendedId::new(0x1277_FF03).unwrap(), &[0; 8]).unwrap();
    assert_eq!(protocol::classify(&unknown), FrameKind::UnknownService);
}
