//! Each payload of the protocol, field by field: the one description of a frame's layout, as
//! DSDL is for Cyphal.
//!
//! Every service's layout is a constant next to its payload type (`Heartbeat::LAYOUT`, …; the
//! services without a payload type have theirs beside the family's types), and [`layout`] finds
//! it from the service. What is derived from it, rather than written again:
//!
//! - the codec is checked against it: the tests of `messages` encode every message and read each
//!   field back through its layout, and decode payloads made field by field;
//! - `pabctl dbc` writes each service's signals, value tables and comment from it;
//! - `docs/can-protocol.md`'s payload sections are checked against it (their byte ranges, their
//!   lengths), and so are the Python client's codecs (through the layouts `pabctl` exports).
//!
//! Cost: constant data that nothing on a board reads; the linker drops it from the firmware.
//!
//! Every field is little endian and unsigned today; `signed` is there so that a field that is
//! not says so in the one place readers look.

use super::{
    ConfigStatusCode, FaultCode, NodeState, SchemaChannel, SchemaOrigin, SchemaOutcome,
    SchemaSafety, SchemaTrigger, Service, TransferStatusCode, UpdateStatusCode,
};

/// How a field's raw value reads as a quantity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Scale {
    /// The raw value is the value.
    Unit,
    /// Q1.31: the value is raw / 2^31 (2^31 = 1.0).
    Q31,
}

/// The named values of an enumerated field: one of the protocol's wire enumerations, with the
/// out-of-band codes some fields add.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Values {
    /// Not an enumeration.
    None,
    /// [`NodeState`].
    NodeState,
    /// [`FaultCode`].
    FaultCode,
    /// [`TransferStatusCode`].
    TransferStatusCode,
    /// [`SchemaOutcome`].
    SchemaOutcome,
    /// [`SchemaChannel`], and [`SchemaAck::NO_CHANNEL`](super::SchemaAck::NO_CHANNEL):
    /// unreadable.
    SchemaChannel,
    /// [`SchemaSafety`], and [`SchemaState::NO_FAULT`](super::SchemaState::NO_FAULT): none.
    SchemaSafety,
    /// [`SchemaTrigger`].
    SchemaTrigger,
    /// [`SchemaOrigin`].
    SchemaOrigin,
    /// An edge: 0 stopped delivering, 1 started delivering.
    Edge,
    /// What a [`Seal`](super::Seal) seals: a service code, or 0x80 for a BLE claim.
    SealKind,
    /// [`ConfigStatusCode`].
    ConfigStatusCode,
    /// The command a [`ConfigStatus`](super::ConfigStatus) answers: Assign's or Configure's
    /// service code.
    ConfigCommand,
    /// [`UpdateStatusCode`].
    UpdateStatusCode,
}

impl Values {
    /// The `index`th value (code, description), in code order; `None` past the last. Walk it
    /// from 0 to list them (no allocation).
    pub fn get(self, index: usize) -> Option<(u32, &'static str)> {
        /// The `index`th entry of a wire enumeration, then `extra`.
        fn entry<T: Copy>(
            all: &[T],
            index: usize,
            code: impl Fn(T) -> u32,
            text: impl Fn(T) -> &'static str,
            extra: Option<(u32, &'static str)>,
        ) -> Option<(u32, &'static str)> {
            match all.get(index) {
                Some(&value) => Some((code(value), text(value))),
                None if index == all.len() => extra,
                None => None,
            }
        }
        match self {
            Values::None => None,
            Values::NodeState => entry(
                NodeState::ALL,
                index,
                |v| v.code().into(),
                NodeState::description,
                None,
            ),
            Values::FaultCode => entry(
                FaultCode::ALL,
                index,
                |v| v.code().into(),
                FaultCode::description,
                None,
            ),
            Values::TransferStatusCode => entry(
                TransferStatusCode::ALL,
                index,
                |v| v.code().into(),
                TransferStatusCode::description,
                None,
            ),
            Values::SchemaOutcome => entry(
                SchemaOutcome::ALL,
                index,
                |v| v.code().into(),
                SchemaOutcome::description,
                None,
            ),
            Values::SchemaChannel => entry(
                SchemaChannel::ALL,
                index,
                |v| v.code().into(),
                SchemaChannel::description,
                Some((super::SchemaAck::NO_CHANNEL.into(), "unreadable")),
            ),
            Values::SchemaSafety => entry(
                SchemaSafety::ALL,
                index,
                |v| v.code().into(),
                SchemaSafety::description,
                Some((super::SchemaState::NO_FAULT.into(), "none")),
            ),
            Values::SchemaTrigger => entry(
                SchemaTrigger::ALL,
                index,
                |v| v.code().into(),
                SchemaTrigger::description,
                None,
            ),
            Values::SchemaOrigin => entry(
                SchemaOrigin::ALL,
                index,
                |v| v.code().into(),
                SchemaOrigin::description,
                None,
            ),
            Values::Edge => [(0, "stopped delivering"), (1, "started delivering")]
                .get(index)
                .copied(),
            Values::SealKind => [
                (0x07, "Gates"),
                (0x17, "FilterProfile"),
                (0x18, "FilterSet"),
                (0x20, "Freshness"),
                (0x80, "BLE claim"),
            ]
            .get(index)
            .copied(),
            Values::ConfigCommand => [(0x28, "Assign"), (0x29, "Configure")].get(index).copied(),
            Values::ConfigStatusCode => entry(
                ConfigStatusCode::ALL,
                index,
                |v| v.code().into(),
                ConfigStatusCode::description,
                None,
            ),
            Values::UpdateStatusCode => entry(
                UpdateStatusCode::ALL,
                index,
                |v| v.code().into(),
                UpdateStatusCode::description,
                None,
            ),
        }
    }

    /// Every value, in code order.
    pub fn iter(self) -> impl Iterator<Item = (u32, &'static str)> {
        (0..).map_while(move |index| self.get(index))
    }
}

/// One field of a payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field {
    /// Its name: a C identifier, the DBC signal's.
    pub name: &'static str,
    /// Its least significant bit: 8 × byte + bit, bit 0 the byte's least significant (DBC's
    /// start bit of an `@1` signal).
    pub bit: u16,
    /// Its width in bits, 1..=64.
    pub bits: u8,
    /// Two's complement, else unsigned.
    pub signed: bool,
    /// How the raw value reads.
    pub scale: Scale,
    /// The largest value it may take, as a quantity, when less than its width allows (a
    /// decoder refuses more); `None`: its width's.
    pub max: Option<u32>,
    /// Its unit, empty when it has none.
    pub unit: &'static str,
    /// Its named values.
    pub values: Values,
    /// What it means, one sentence.
    pub doc: &'static str,
}

impl Field {
    /// An unsigned field of `bits` bits from bit `bit`, without unit or named values.
    pub const fn new(name: &'static str, bit: u16, bits: u8, doc: &'static str) -> Field {
        Field {
            name,
            bit,
            bits,
            signed: false,
            scale: Scale::Unit,
            max: None,
            unit: "",
            values: Values::None,
            doc,
        }
    }

    /// A reserved field: 0 on the wire, refused otherwise.
    pub const fn reserved(name: &'static str, bit: u16, bits: u8) -> Field {
        Field::new(name, bit, bits, "0")
    }

    /// The same field with a unit.
    pub const fn unit(self, unit: &'static str) -> Field {
        Field { unit, ..self }
    }

    /// The same field, enumerated.
    pub const fn values(self, values: Values) -> Field {
        Field { values, ..self }
    }

    /// The same field with a maximum below its width's.
    pub const fn max(self, max: u32) -> Field {
        Field {
            max: Some(max),
            ..self
        }
    }

    /// The same field, scaled.
    pub const fn scale(self, scale: Scale) -> Field {
        Field { scale, ..self }
    }

    /// Whether the field is reserved (must be 0).
    pub fn is_reserved(&self) -> bool {
        self.name.starts_with("reserved")
    }

    /// The field's first and last byte.
    pub const fn bytes(&self) -> (usize, usize) {
        let first = self.bit as usize / 8;
        let last = (self.bit as usize + self.bits as usize).saturating_sub(1) / 8;
        (first, last)
    }

    /// The field's raw value in `payload`; `None` when the payload is too short for it.
    pub fn read(&self, payload: &[u8]) -> Option<u64> {
        let (first, last) = self.bytes();
        let bytes = payload.get(first..=last)?;
        let mut raw: u128 = 0;
        for (i, byte) in bytes.iter().enumerate() {
            raw |= u128::from(*byte) << (8 * i);
        }
        let raw = raw >> (self.bit % 8);
        let mask = if self.bits >= 64 {
            u128::from(u64::MAX)
        } else {
            (1u128 << self.bits) - 1
        };
        u64::try_from(raw & mask).ok()
    }

    /// Writes `raw` (its low `bits` bits) into the field of `payload`; `false`, and nothing
    /// written, when the payload is too short.
    pub fn write(&self, payload: &mut [u8], raw: u64) -> bool {
        let (first, last) = self.bytes();
        let Some(bytes) = payload.get_mut(first..=last) else {
            return false;
        };
        let mask: u128 = if self.bits >= 64 {
            u128::from(u64::MAX)
        } else {
            (1u128 << self.bits) - 1
        };
        let shift = self.bit % 8;
        let value = (u128::from(raw) & mask) << shift;
        let field = mask << shift;
        for (i, byte) in bytes.iter_mut().enumerate() {
            let lane = (field >> (8 * i)) as u8;
            let bits = (value >> (8 * i)) as u8;
            *byte = (*byte & !lane) | bits;
        }
        true
    }
}

/// How a service's payload travels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Framing {
    /// One frame of a fixed length, the fields below.
    Fixed,
    /// ISO 15765-2 frames padded to 8 bytes (a transfer); no fixed fields.
    IsoTp,
}

/// A service's payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// The service.
    pub service: Service,
    /// How it travels.
    pub framing: Framing,
    /// Its length in bytes ([`Service::payload_len`]).
    pub len: u8,
    /// Its fields, in bit order; they do not overlap and cover what is not padding.
    pub fields: &'static [Field],
    /// When it is sent and what it does, one or two sentences (the DBC comment's body).
    pub summary: &'static str,
}

impl Layout {
    /// A fixed payload.
    pub const fn fixed(
        service: Service,
        fields: &'static [Field],
        summary: &'static str,
    ) -> Layout {
        Layout {
            service,
            framing: Framing::Fixed,
            len: service.payload_len() as u8,
            fields,
            summary,
        }
    }

    /// A transfer's ISO-TP frames.
    pub const fn isotp(service: Service, summary: &'static str) -> Layout {
        Layout {
            service,
            framing: Framing::IsoTp,
            len: service.payload_len() as u8,
            fields: &[],
            summary,
        }
    }

    /// The field named `name`.
    pub fn field(&self, name: &str) -> Option<&'static Field> {
        self.fields.iter().find(|field| field.name == name)
    }
}

/// The layout of `service`'s payload.
pub const fn layout(service: Service) -> &'static Layout {
    use super::messages as m;
    match service {
        Service::EmergencyStop => &m::EMERGENCY_STOP_LAYOUT,
        Service::Fault => &m::Fault::LAYOUT,
        Service::Heartbeat => &m::Heartbeat::LAYOUT,
        Service::TableStatus => &m::TableStatus::LAYOUT,
        Service::Traffic => &m::Traffic::LAYOUT,
        Service::Errors => &m::Errors::LAYOUT,
        Service::Diagnostic => &m::DiagnosticSample::LAYOUT,
        Service::Gates => &m::Gates::LAYOUT,
        Service::Desire => &m::DesireFrame::LAYOUT,
        Service::Intention => &m::Intention::LAYOUT,
        Service::FilterStatus => &m::FilterStatus::LAYOUT,
        Service::Exploitation => &m::Exploitation::LAYOUT,
        Service::DiagnosticControl => &m::DiagnosticControl::LAYOUT,
        Service::TableTransfer => &m::TABLE_TRANSFER_LAYOUT,
        Service::TransferStatus => &m::TransferStatus::LAYOUT,
        Service::ChallengeRequest => &m::CHALLENGE_REQUEST_LAYOUT,
        Service::Challenge => &m::CHALLENGE_LAYOUT,
        Service::TransferOpen => &m::TransferOpen::LAYOUT,
        Service::Receipt => &m::RECEIPT_LAYOUT,
        Service::FilterProfile => &m::FilterProfile::LAYOUT,
        Service::FilterSet => &m::FilterSet::LAYOUT,
        Service::SchemaAbort => &m::SCHEMA_ABORT_LAYOUT,
        Service::SchemaTransfer => &m::SCHEMA_TRANSFER_LAYOUT,
        Service::SchemaAck => &m::SchemaAck::LAYOUT,
        Service::SchemaTransition => &m::SchemaTransition::LAYOUT,
        Service::SchemaState => &m::SchemaState::LAYOUT,
        Service::Seal => &m::Seal::LAYOUT,
        Service::FreshnessRequest => &m::FRESHNESS_REQUEST_LAYOUT,
        Service::Freshness => &m::FRESHNESS_LAYOUT,
        Service::IdentityRequest => &m::IDENTITY_REQUEST_LAYOUT,
        Service::Identity => &m::IDENTITY_LAYOUT,
        Service::IdentityVersion => &m::IDENTITY_VERSION_LAYOUT,
        Service::IdentityBuild => &m::IDENTITY_BUILD_LAYOUT,
        Service::IdentityCapacity => &m::IDENTITY_CAPACITY_LAYOUT,
        Service::IdentityFeatures => &m::IDENTITY_FEATURES_LAYOUT,
        Service::IdentityName => &m::IDENTITY_NAME_LAYOUT,
        Service::Assign => &m::Assign::LAYOUT,
        Service::Configure => &m::Configure::LAYOUT,
        Service::ConfigStatus => &m::ConfigStatus::LAYOUT,
        Service::UpdateTransfer => &m::UPDATE_TRANSFER_LAYOUT,
        Service::UpdateStatus => &m::UpdateStatus::LAYOUT,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every layout is well formed: its service's, its fields inside its length, in bit order,
    /// not overlapping, widths 1..=64, names unique C identifiers, maxima within the width.
    #[test]
    fn every_layout_is_well_formed() {
        for service in Service::ALL {
            let layout = layout(service);
            assert_eq!(layout.service, service);
            assert_eq!(
                usize::from(layout.len),
                service.payload_len(),
                "{service:?}"
            );
            assert!(!layout.summary.is_empty(), "{service:?}");
            let mut next = 0u32;
            for (i, field) in layout.fields.iter().enumerate() {
                let at = format!("{service:?}.{}", field.name);
                assert!((1..=64).contains(&field.bits), "{at}");
                assert!(
                    u32::from(field.bit) >= next,
                    "{at} overlaps the field before"
                );
                next = u32::from(field.bit) + u32::from(field.bits);
                assert!(
                    next <= 8 * u32::from(layout.len),
                    "{at} ends past the payload"
                );
                assert!(
                    field
                        .name
                        .chars()
                        .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
                        && field.name.starts_with(|c: char| c.is_ascii_lowercase()),
                    "{at}: not a C identifier"
                );
                assert!(
                    layout.fields[..i].iter().all(|f| f.name != field.name),
                    "{at}: named twice"
                );
                assert!(!field.doc.is_empty(), "{at}");
                if let Some(max) = field.max {
                    assert!(
                        field.bits >= 64
                            || u64::from(max) < 1u64 << field.bits
                            || field.scale != Scale::Unit,
                        "{at}"
                    );
                }
                for (code, _) in field.values.iter() {
                    assert!(
                        field.bits >= 32 || code < 1 << field.bits,
                        "{at}: value {code}"
                    );
                }
            }
            if layout.framing == Framing::IsoTp {
                assert!(layout.fields.is_empty(), "{service:?}");
            }
        }
    }

    #[test]
    fn fields_read_and_write_their_bits_only() {
        let field = Field::new("x", 10, 13, "x");
        let mut payload = [0xFFu8; 4];
        assert!(field.write(&mut payload, 0));
        assert_eq!(payload, [0xFF, 0b0000_0011, 0b1000_0000, 0xFF]);
        assert!(field.write(&mut payload, 0x1ABC));
        assert_eq!(field.read(&payload), Some(0x1ABC));
        assert_eq!(payload[0], 0xFF);
        assert_eq!(payload[3], 0xFF);
        assert!(!Field::new("y", 60, 8, "y").write(&mut payload, 1));
        assert_eq!(Field::new("y", 24, 16, "y").read(&payload), None);
        let wide = Field::new("w", 0, 64, "w");
        let mut eight = [0u8; 8];
        assert!(wide.write(&mut eight, u64::MAX - 1));
        assert_eq!(wide.read(&eight), Some(u64::MAX - 1));
    }

    #[test]
    fn value_tables_list_the_enumerations_and_their_extra_codes() {
        assert_eq!(Values::None.iter().count(), 0);
        assert_eq!(Values::NodeState.iter().count(), NodeState::ALL.len());
        assert_eq!(
            Values::SchemaChannel.iter().last(),
            Some((
                u32::from(crate::protocol::SchemaAck::NO_CHANNEL),
                "unreadable"
            ))
        );
        assert_eq!(
            Values::SchemaSafety.iter().count(),
            SchemaSafety::ALL.len() + 1
        );
        assert_eq!(Values::Edge.iter().count(), 2);
    }
}
