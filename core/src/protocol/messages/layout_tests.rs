//! The codec against the layouts (`crate::protocol::layout`): every message's fields, read
//! from its encoded bytes through its service's layout, are its values; a payload written field
//! by field through the layout decodes to the message; and arbitrary payloads that decode read
//! the same through both. So a layout that says the wrong offset, width or field fails here, and
//! the DBC, the document and the Python client, checked against the layout, follow the codec.

use std::vec::Vec;

use proptest::prelude::*;

use super::tests::samples;
use crate::frame::Frame;
use crate::protocol::layout::{Framing, Scale, layout};
use crate::protocol::*;

/// Every field of the message's fixed payload as its layout names it, from the typed message;
/// `None` for the ISO-TP frames (no fixed fields). Reserved fields are 0.
fn view(message: &Message) -> Option<Vec<(&'static str, u64)>> {
    let le = |bytes: &[u8]| {
        bytes
            .iter()
            .rev()
            .fold(0u64, |acc, byte| acc << 8 | u64::from(*byte))
    };
    let fields: Vec<(&'static str, u64)> = match *message {
        Message::Fault(f) => {
            let mut v = vec![("code", f.code.code().into()), ("count", f.count.into())];
            for (name, byte) in ["detail0", "detail1", "detail2", "detail3", "detail4"]
                .into_iter()
                .zip(f.detail)
            {
                v.push((name, byte.into()));
            }
            v
        }
        Message::Heartbeat(h) => vec![
            ("state", h.state.code().into()),
            ("uptime", h.uptime_s.min(0xFF_FFFF).into()),
            ("table_version", h.table_version.into()),
        ],
        Message::TableStatus(t) => vec![
            ("crc", t.crc.into()),
            ("image_len", t.image_len.into()),
            ("ports", t.ports.into()),
            ("stored", t.stored.into()),
            ("diagnostic", t.diagnostic.into()),
            ("keyed", t.keyed.into()),
        ],
        Message::Traffic(t) => vec![
            ("received", t.received.into()),
            ("delivered", t.delivered.into()),
        ],
        Message::Errors(e) => vec![
            ("discarded", e.discarded.into()),
            ("errors", e.errors.into()),
        ],
        Message::Diagnostic(d) => vec![
            ("port", d.port.into()),
            ("connection", d.connection.into()),
            ("active", d.flags.active.into()),
            ("resting", d.flags.resting.into()),
            ("delivering", d.flags.delivering.into()),
            ("end_of_round", d.flags.end_of_round.into()),
            ("sequence", d.sequence.into()),
            ("level", d.level.into()),
        ],
        Message::Gates(g) => vec![
            ("group", g.group.into()),
            ("behaviours", g.behaviours.into()),
            ("gates", g.mask.into()),
            ("changes", g.changes.into()),
            ("reserved", 0),
        ],
        Message::Desire(d) => vec![
            ("class", d.class.into()),
            ("reserved", 0),
            ("intensity", d.intensity.into()),
            ("lease", d.lease_ms.into()),
            ("id", d.id.into()),
        ],
        Message::Intention(i) => vec![
            ("strategies_low", i.strategies & 0xFFFF_FFFF),
            ("strategies_high", i.strategies >> 32),
        ],
        Message::FilterStatus(f) => vec![
            ("profile", f.profile.into()),
            ("reserved", 0),
            ("sequence", f.sequence.into()),
            ("filtered", f.filtered.into()),
            ("closed", f.closed.into()),
            ("throttled", f.throttled.into()),
            ("reserved2", 0),
        ],
        Message::Exploitation(e) => vec![
            ("port", e.port.into()),
            ("connection", e.connection.into()),
            ("delivering", e.delivering.into()),
            ("reserved", 0),
        ],
        Message::FilterProfile(f) => vec![
            ("profile", f.profile.into()),
            ("reserved", 0),
            ("sequence", f.sequence.into()),
        ],
        Message::FilterSet(f) => vec![
            ("port", f.port.into()),
            ("connection", f.connection.into()),
            ("phi", f.phi.into()),
            ("reserved", 0),
            ("sequence", f.sequence.into()),
        ],
        Message::DiagnosticControl(c)
        | Message::AuthenticatedDiagnosticControl { control: c, .. } => {
            vec![("rate", c.rate_hz.into()), ("ports", c.ports.into())]
        }
        Message::TableTransfer { .. } | Message::SchemaTransfer { .. } => return None,
        #[cfg(feature = "update")]
        Message::UpdateTransfer { .. } => return None,
        Message::TransferStatus(t) => vec![
            ("status", t.status.code().into()),
            ("detail", t.detail.into()),
            ("running_version", t.running_version.into()),
            ("reserved", 0),
        ],
        Message::EmergencyStop | Message::SchemaAbort => Vec::new(),
        Message::ChallengeRequest { tool_nonce } => vec![
            ("tool_nonce_low", tool_nonce & 0xFFFF_FFFF),
            ("tool_nonce_high", tool_nonce >> 32),
        ],
        Message::Challenge {
            node_nonce,
            binding,
        } => vec![
            ("node_nonce_low", node_nonce & 0xFFFF_FFFF),
            ("node_nonce_high", node_nonce >> 32),
            ("binding", u16::from_le_bytes(binding).into()),
        ],
        Message::TransferOpen(o) => vec![
            ("length", o.length.into()),
            ("replace", u64::from(o.flags & OPEN_REPLACE != 0)),
            ("schema", u64::from(o.flags & OPEN_SCHEMA != 0)),
            ("update", u64::from(o.flags & OPEN_UPDATE != 0)),
            ("tag", le(&o.tag)),
        ],
        Message::Receipt { tag } => vec![("tag_low", le(&tag[..4])), ("tag_high", le(&tag[4..]))],
        Message::Seal(s) => vec![
            ("kind", s.kind.into()),
            ("digest", s.digest.into()),
            ("counter", s.counter.into()),
            ("tag", le(&s.tag)),
        ],
        Message::FreshnessRequest { nonce } => vec![
            ("nonce_low", nonce & 0xFFFF_FFFF),
            ("nonce_high", nonce >> 32),
        ],
        Message::Freshness { epoch, counter } => {
            vec![("epoch", epoch.into()), ("counter", counter.into())]
        }
        #[cfg(feature = "identity")]
        Message::IdentityRequest => vec![],
        #[cfg(feature = "identity")]
        Message::Assign(a) => vec![
            ("uid_check", a.uid_check.into()),
            ("node_id", a.node_id.into()),
        ],
        #[cfg(feature = "identity")]
        Message::Configure(c) => vec![("bitrate", c.bitrate_kbps.into()), ("reserved", 0)],
        #[cfg(feature = "identity")]
        Message::ConfigStatus(c) => vec![
            ("command", c.command.into()),
            ("status", c.status.code().into()),
            ("node_id", c.node_id.into()),
            ("reserved", 0),
            ("bitrate", c.bitrate_kbps.into()),
            ("reserved_2", 0),
        ],
        #[cfg(feature = "identity")]
        Message::Identity { part, payload } => {
            let identity = {
                let mut parts = crate::identity::IdentityParts::new();
                for other in crate::identity::IdentityPart::ALL {
                    parts.add(other, [0; 8]);
                }
                parts.add(part, payload);
                parts.complete().unwrap()
            };
            let uid = |range: core::ops::Range<usize>| le(&identity.uid[range]);
            let name = |range: core::ops::Range<usize>| le(&identity.firmware.name[range]);
            let build = |range: core::ops::Range<usize>| le(&identity.firmware.build[range]);
            let [major, minor, patch] = identity.firmware.version;
            let c = identity.capacity;
            let bit = |b: u8| u64::from(identity.flags >> b & 1);
            let feature = |b: u16| u64::from(identity.features >> b & 1);
            match part {
                crate::identity::IdentityPart::Uid => {
                    vec![("uid_low", uid(0..4)), ("uid_mid", uid(4..8))]
                }
                crate::identity::IdentityPart::Version => vec![
                    ("uid_high", uid(8..12)),
                    ("major", major.into()),
                    ("minor", minor.into()),
                    ("patch", patch.into()),
                    ("protocol", identity.protocol.into()),
                ],
                crate::identity::IdentityPart::Build => {
                    vec![("build_high", build(0..4)), ("build_low", build(4..8))]
                }
                crate::identity::IdentityPart::Capacity => vec![
                    ("ports", c.ports.into()),
                    ("connections", c.connections.into()),
                    ("decision_nodes", c.decision_nodes.into()),
                    ("image", c.image_len.into()),
                    ("reserved", 0),
                ],
                crate::identity::IdentityPart::Features => vec![
                    ("format_min", identity.formats[0].into()),
                    ("format_max", identity.formats[1].into()),
                    ("ble", feature(0)),
                    ("dynamics", feature(1)),
                    ("filters", feature(2)),
                    ("schema", feature(3)),
                    ("fd", feature(4)),
                    ("reserved_features", 0),
                    ("keyed", bit(0)),
                    ("locked", bit(1)),
                    ("unassigned", bit(2)),
                    ("bitrate_trial", bit(3)),
                    ("bitrate_fell_back", bit(4)),
                    ("reserved_flags", 0),
                    ("reserved", 0),
                    ("bitrate", identity.bitrate_kbps.into()),
                ],
                crate::identity::IdentityPart::Name => {
                    vec![("name_low", name(0..4)), ("name_high", name(4..8))]
                }
            }
        }
        #[cfg(feature = "update")]
        Message::UpdateStatus(u) => vec![
            ("status", u.status.code().into()),
            ("offset", u.offset.min(UpdateStatus::MAX_OFFSET).into()),
            ("value", u.value.into()),
        ],
        Message::SchemaAck(a) => vec![
            ("outcome", a.outcome.code().into()),
            (
                "channel",
                a.channel
                    .map_or(SchemaAck::NO_CHANNEL, SchemaChannel::code)
                    .into(),
            ),
            ("id", a.id.into()),
            ("queued", a.queued.into()),
            ("stop", a.stop.into()),
            ("reserved", 0),
        ],
        Message::SchemaTransition(t) => vec![
            ("ended", t.ended.into()),
            ("installed", t.installed.into()),
            ("trigger", t.trigger.code().into()),
            ("detail", t.detail.into()),
            ("source", t.source.code().into()),
            ("queued", t.queued.into()),
        ],
        Message::SchemaState(s) => vec![
            ("current", s.current.into()),
            ("source", s.source.code().into()),
            (
                "fault",
                s.fault
                    .map_or(SchemaState::NO_FAULT, SchemaSafety::code)
                    .into(),
            ),
            ("queued", s.queued.into()),
            ("armed", s.armed.into()),
            ("gripper_closed", s.gripper_closed.into()),
            ("stop", s.stop.into()),
            ("elapsed", s.elapsed_ms.into()),
        ],
    };
    Some(fields)
}

/// A command in its keyed form: its tag follows the layout's fields.
pub(super) fn is_tagged(message: &Message) -> bool {
    #[cfg(feature = "identity")]
    if matches!(
        message,
        Message::Assign(Assign { tag: Some(_), .. })
            | Message::Configure(Configure { tag: Some(_), .. })
    ) {
        return true;
    }
    matches!(message, Message::AuthenticatedDiagnosticControl { .. })
}

/// The view names exactly the layout's fields, in its order.
fn assert_names(message: &Message, fields: &[(&'static str, u64)]) {
    let layout = layout(message.service());
    let names: Vec<&str> = layout.fields.iter().map(|f| f.name).collect();
    let viewed: Vec<&str> = fields.iter().map(|(name, _)| *name).collect();
    assert_eq!(
        viewed,
        names,
        "{:?}: the test's view and the layout",
        message.service()
    );
}

/// The message's fields read from its bytes through the layout.
fn read(message: &Message, payload: &[u8]) -> Vec<(&'static str, u64)> {
    layout(message.service())
        .fields
        .iter()
        .map(|field| {
            let raw = field.read(payload).unwrap_or_else(|| {
                panic!("{:?}.{}: past the payload", message.service(), field.name)
            });
            (field.name, raw)
        })
        .collect()
}

#[test]
fn every_sample_reads_through_its_layout_as_its_values() {
    for message in samples() {
        let frame = message.to_frame(3, BROADCAST);
        let layout = layout(message.service());
        let Some(fields) = view(&message) else {
            assert_eq!(layout.framing, Framing::IsoTp, "{message:?}");
            continue;
        };
        assert_eq!(layout.framing, Framing::Fixed, "{message:?}");
        assert_names(&message, &fields);
        let payload = frame.payload();
        if !is_tagged(&message) {
            assert_eq!(payload.len(), usize::from(layout.len), "{message:?}");
        }
        assert_eq!(read(&message, payload), fields, "{message:?}");
    }
}

#[test]
fn a_payload_written_through_the_layout_decodes_to_the_message() {
    for message in samples() {
        let Some(fields) = view(&message) else {
            continue;
        };
        if is_tagged(&message) {
            continue; // its tag is outside the layout: the plain form is the same fields.
        }
        let layout = layout(message.service());
        let mut payload = [0u8; 8];
        for (field, (_, raw)) in layout.fields.iter().zip(&fields) {
            assert!(field.write(&mut payload, *raw));
        }
        let sent = message.to_frame(3, BROADCAST);
        let frame = Frame::data(sent.id(), &payload[..usize::from(layout.len)]).unwrap();
        let (_, decoded) = Message::decode(&frame).unwrap_or_else(|e| {
            panic!("{message:?}: the layout's bytes {payload:02X?} do not decode: {e:?}")
        });
        assert_eq!(decoded, message);
    }
}

/// The services with fixed fields, each with a sample message (for its identifier).
fn fixed_services() -> Vec<Message> {
    samples()
        .into_iter()
        .filter(|m| layout(m.service()).framing == Framing::Fixed && !is_tagged(m))
        .collect()
}

/// A payload made from arbitrary bytes through the layout: each field takes its bits of
/// `bytes` (an enumerated field one of its values, chosen by them), the reserved fields and the
/// bits no field covers stay 0, so that most payloads decode.
fn arbitrary_payload(layout: &crate::protocol::layout::Layout, bytes: &[u8; 8]) -> [u8; 8] {
    let mut payload = [0u8; 8];
    for field in layout.fields.iter().filter(|f| !f.is_reserved()) {
        let raw = field.read(bytes).unwrap_or(0);
        let raw = match field.values.iter().count() as u64 {
            0 => raw,
            count => field
                .values
                .get((raw % count) as usize)
                .map_or(raw, |(code, _)| u64::from(code)),
        };
        field.write(&mut payload, raw);
    }
    payload
}

proptest! {
    /// Arbitrary payloads for every service ([`arbitrary_payload`]): whatever decodes reads the same through the typed message
    /// and through the layout, encodes back to its bytes, and keeps each field within its
    /// layout's maximum and named values.
    #[test]
    fn arbitrary_payloads_read_the_same_through_codec_and_layout(
        bytes in proptest::array::uniform8(any::<u8>()),
    ) {
        for message in fixed_services() {
            let layout = layout(message.service());
            let len = usize::from(layout.len);
            let payload = arbitrary_payload(layout, &bytes);
            let id = message.to_frame(3, BROADCAST).id();
            let frame = Frame::data(id, &payload[..len]).unwrap();
            if let Ok((_, decoded)) = Message::decode(&frame) {
                let fields = view(&decoded).unwrap();
                assert_names(&decoded, &fields);
                prop_assert_eq!(read(&decoded, &payload[..len]), fields);
                let again = decoded.to_frame(3, BROADCAST);
                prop_assert_eq!(again.payload(), &payload[..len]);
                for field in layout.fields {
                    let raw = field.read(&payload).unwrap();
                    if let Some(max) = field.max.filter(|_| field.scale == Scale::Unit) {
                        prop_assert!(raw <= u64::from(max), "{}: {} above its maximum", field.name, raw);
                    }
                    if field.values.get(0).is_some() {
                        prop_assert!(
                            field.values.iter().any(|(code, _)| u64::from(code) == raw),
                            "{}: {} is not one of its values", field.name, raw
                        );
                    }
                }
            }
        }
    }
}

/// Of many arbitrary payloads, each service decodes some: the property above is not vacuous.
#[test]
fn arbitrary_payloads_decode_for_every_service() {
    for message in fixed_services() {
        let layout = layout(message.service());
        let len = usize::from(layout.len);
        let decoded = (0u64..512).filter(|seed| {
            let payload = arbitrary_payload(
                layout,
                &seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).to_le_bytes(),
            );
            let frame = Frame::data(message.to_frame(3, BROADCAST).id(), &payload[..len]).unwrap();
            Message::decode(&frame).is_ok()
        });
        assert!(
            decoded.count() > 0,
            "{:?}: no arbitrary payload decodes",
            message.service()
        );
    }
}

/// Every bit that the decoder reads is in a field of the layout: flipping a bit of a payload
/// that decodes either gets it refused or changes the message, and a change comes only from a
/// bit inside a field that is not reserved. (A field the layout makes too narrow, or a field
/// it forgets, fails here.)
#[test]
fn every_bit_the_decoder_reads_is_in_a_field() {
    for message in fixed_services() {
        let layout = layout(message.service());
        let len = usize::from(layout.len);
        let id = message.to_frame(3, BROADCAST).id();
        let mut checked = 0;
        for seed in 0u64..64 {
            let payload = arbitrary_payload(
                layout,
                &seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).to_le_bytes(),
            );
            let Ok((_, original)) = Message::decode(&Frame::data(id, &payload[..len]).unwrap())
            else {
                continue;
            };
            for bit in 0..8 * len {
                let mut flipped = payload;
                flipped[bit / 8] ^= 1 << (bit % 8);
                let frame = Frame::data(id, &flipped[..len]).unwrap();
                let Ok((_, decoded)) = Message::decode(&frame) else {
                    continue;
                };
                assert_ne!(
                    decoded,
                    original,
                    "{:?}: bit {bit} is ignored by the decoder",
                    message.service()
                );
                let in_field = layout.fields.iter().any(|f| {
                    !f.is_reserved()
                        && (usize::from(f.bit)..usize::from(f.bit) + usize::from(f.bits))
                            .contains(&bit)
                });
                assert!(
                    in_field,
                    "{:?}: the decoder reads bit {bit}, which no field of the layout holds",
                    message.service()
                );
                checked += 1;
            }
        }
        assert!(
            checked > 0 || layout.fields.is_empty(),
            "{:?}: no flip decoded",
            message.service()
        );
    }
}
