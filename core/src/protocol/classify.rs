//! What a frame is, from its identifier alone: the one place where a runner, a replay, a
//! simulator or a check tells a topic from a claim from a service frame of ours.
//!
//! # Decisions
//!
//! - **By identifier only.** The payload and the remote bit are the decoders' business
//!   ([`super::Message::decode`], [`crate::ble::Claim::decode`]), which refuse a remote frame or a
//!   wrong length with a reason. Classifying a remote frame of ours as ours keeps it away from
//!   arbitration, as every other frame in our space: nodes never arbitrate our identifiers.
//! - **Claims before services.** A claim sets bit 23, the top bit of what is the service byte in
//!   every other frame of ours; no [`Service`] code reaches 0x80, so the two never overlap, and
//!   testing the one bit first keeps claims (sent every BLE period by every member of a group)
//!   from going through the service parse at all. The order matters for the result too: a
//!   claim's bits 22..16 are the top of its inverted eligibility, which a service parse would read
//!   as an unknown service code (0x80..=0xFF).
//! - **An unknown service is ours.** Our marker with a code this version does not know (a newer
//!   protocol's) is [`FrameKind::UnknownService`], never a topic: arbitrating it would deliver
//!   another node's protocol traffic to a port.
//!
//! # Cost
//!
//! A topic (the frames a node arbitrates) costs a test of the identifier's format and one mask
//! and compare ([`super::PROTOCOL_MASK`]); a claim one more mask and compare; a service frame a
//! range check of its service code on top (no table, no loop).

use embedded_can::Id;

use super::{FrameId, PROTOCOL_MASK, PROTOCOL_VALUE};
use crate::ble;
use crate::frame::Frame;

/// What a frame is, by its identifier ([`classify`]). Every frame is exactly one of these.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameKind {
    /// Not ours: a standard identifier, or an extended one without our marker. What a node
    /// arbitrates.
    Topic,
    /// A BLE claim: our marker and bit 23 set. [`crate::ble::Claim::decode`] reads it (and
    /// refuses a malformed one).
    Claim,
    /// A frame of one of our services, its identifier decoded (priority included, as sent:
    /// [`FrameId::has_service_priority`] says whether it is the service's).
    /// [`super::Message::decode`] reads its payload.
    Service(FrameId),
    /// Our marker, bit 23 clear, and a service code this version does not know. Not arbitrated,
    /// not read.
    UnknownService,
}

impl FrameKind {
    /// Whether the frame lies in our part of the identifier space (every kind but
    /// [`FrameKind::Topic`]): nodes never arbitrate it.
    #[inline]
    pub const fn is_ours(&self) -> bool {
        !matches!(self, FrameKind::Topic)
    }
}

/// What `frame` is. See the module's documentation for the decisions and the cost.
#[inline]
pub fn classify(frame: &Frame) -> FrameKind {
    classify_id(&frame.id())
}

/// [`classify`] for an identifier without a frame: an identifier a configuration names (an
/// output, a drive's frames), to refuse one in our space.
#[inline]
pub fn classify_id(id: &Id) -> FrameKind {
    let Id::Extended(id) = id else {
        return FrameKind::Topic;
    };
    let raw = id.as_raw();
    if raw & PROTOCOL_MASK != PROTOCOL_VALUE {
        return FrameKind::Topic;
    }
    if ble::is_claim_id(raw) {
        return FrameKind::Claim;
    }
    match FrameId::from_raw(raw) {
        Some(id) => FrameKind::Service(id),
        None => FrameKind::UnknownService,
    }
}
