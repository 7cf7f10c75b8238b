//! Decoding: the framing every frame gets (ours, not remote, its service's priority and
//! length), then the payload of a service a node acts on, or of one it only reports.

#[cfg(feature = "update")]
use super::UpdateStatus;
#[cfg(feature = "identity")]
use super::{Assign, ConfigStatus, Configure};
use super::{
    DesireFrame, DiagnosticControl, DiagnosticFlags, DiagnosticSample, Errors, Exploitation, Fault,
    FilterProfile, FilterSet, FilterStatus, Gates, Heartbeat, Intention, Message, OPEN_REPLACE,
    OPEN_SCHEMA, OPEN_UPDATE, SchemaAck, SchemaState, SchemaTransition, Seal, TableStatus, Traffic,
    TransferOpen, TransferStatus,
};
use crate::frame::Frame;
#[cfg(feature = "identity")]
use crate::protocol::ConfigStatusCode;
#[cfg(feature = "update")]
use crate::protocol::UpdateStatusCode;
use crate::protocol::{
    FaultCode, FrameId, NodeState, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety,
    SchemaTrigger, Service, TransferStatusCode,
};

/// Why a frame in our identifier space was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum DecodeError {
    /// Not one of our identifiers (standard, other marker or unknown service).
    NotOurs,
    /// A remote frame: our protocol uses none.
    Remote,
    /// The payload length is not the service's.
    Length {
        /// The service.
        service: Service,
        /// The length received.
        len: u8,
    },
    /// An enumerated field holds an unknown code or a reserved bit or byte is set.
    Value {
        /// The service.
        service: Service,
    },
    /// The identifier's priority bits are not the service's ([`Service::priority`]).
    Priority {
        /// The service.
        service: Service,
        /// The priority received.
        priority: u8,
    },
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecodeError::NotOurs => f.write_str("not a frame of the pab protocol"),
            DecodeError::Remote => f.write_str("remote frame"),
            DecodeError::Length { service, len } => write!(
                f,
                "{service:?} frame with {len} bytes, expected {}",
                service.payload_len()
            ),
            DecodeError::Value { service } => {
                write!(
                    f,
                    "{service:?} frame with an unknown code or reserved bits set"
                )
            }
            DecodeError::Priority { service, priority } => write!(
                f,
                "{service:?} frame with priority {priority}, expected {}",
                service.priority().value()
            ),
        }
    }
}

impl core::error::Error for DecodeError {}

/// The little-endian `u32` at `at` of a padded payload (`at` + 4 <= 8 at every call).
fn u32_at(data: &[u8; 8], at: usize) -> u32 {
    u32::from_le_bytes([
        byte(data, at),
        byte(data, at + 1),
        byte(data, at + 2),
        byte(data, at + 3),
    ])
}

/// The little-endian `u16` at `at` of a padded payload.
fn u16_at(data: &[u8; 8], at: usize) -> u16 {
    u16::from_le_bytes([byte(data, at), byte(data, at + 1)])
}

/// Byte `at` of a padded payload (0 past its end, which no call reaches).
fn byte(data: &[u8; 8], at: usize) -> u8 {
    data.get(at).copied().unwrap_or(0)
}

/// `N` bytes from `at` of a padded payload.
fn bytes_at<const N: usize>(data: &[u8; 8], at: usize) -> [u8; N] {
    core::array::from_fn(|i| byte(data, at + i))
}

impl Message {
    /// Decodes a frame of our protocol: its addresses and its message.
    pub fn decode(frame: &Frame) -> Result<(FrameId, Message), DecodeError> {
        let (id, padded, len) = Self::framing(frame)?;
        let message = match Self::node_message(id.service, padded, len)? {
            Some(message) => message,
            None => Self::report(id.service, padded)?,
        };
        Ok((id, message))
    }

    /// [`Message::decode`] for a node: the same checks of every frame's identifier, priority
    /// and length, but the payload decoded (and its values checked) only for the services a node
    /// acts on (Gates, DiagnosticControl, TableTransfer, ChallengeRequest, TransferOpen,
    /// FilterProfile, FilterSet, EmergencyStop, SchemaAbort, SchemaTransfer, Seal,
    /// FreshnessRequest, Freshness, IdentityRequest, Assign, Configure, UpdateTransfer);
    /// `Ok(None)` for a well-framed frame of another service (a report, a desire, another node's
    /// status or schema answers), which a node does not read. The boards link only this: the other services' decoders took 596 bytes of the NUCLEO-G474RE's flash.
    pub fn decode_for_node(frame: &Frame) -> Result<Option<(FrameId, Message)>, DecodeError> {
        let (id, padded, len) = Self::framing(frame)?;
        Ok(Self::node_message(id.service, padded, len)?.map(|message| (id, message)))
    }

    /// The checks every frame gets (ours, not remote, its service's priority and length), and
    /// its payload zero-padded to 8 bytes with its length.
    fn framing(frame: &Frame) -> Result<(FrameId, [u8; 8], u8), DecodeError> {
        let id = FrameId::decode(&frame.id()).ok_or(DecodeError::NotOurs)?;
        if frame.is_remote() {
            return Err(DecodeError::Remote);
        }
        let service = id.service;
        // Every service has one priority: a frame with another is malformed, whatever it holds.
        if !id.has_service_priority() {
            return Err(DecodeError::Priority {
                service,
                priority: id.priority.value(),
            });
        }
        let data = frame.payload();
        let len = u8::try_from(data.len()).unwrap_or(u8::MAX);
        let expected = service.payload_len();
        let length_ok = match service {
            // ISO-TP frames may be unpadded: the transport checks their length.
            Service::TableTransfer | Service::SchemaTransfer | Service::UpdateTransfer => {
                !data.is_empty()
            }
            // The plain form, or the plain form and its tag.
            Service::DiagnosticControl | Service::Assign | Service::Configure => {
                data.len() == expected || data.len() == expected + crate::auth::COMMAND_TAG_LEN
            }
            _ => data.len() == expected,
        };
        if !length_ok {
            return Err(DecodeError::Length { service, len });
        }
        // The payload zero-padded to 8 bytes: every read is at a constant offset within the
        // length checked above, so none needs a bounds check (less flash than reads from the
        // slice, each with its own).
        let mut padded = [0u8; 8];
        for (slot, byte) in padded.iter_mut().zip(data) {
            *slot = *byte;
        }
        Ok((id, padded, len))
    }

    /// The payload of a service a node acts on, or `None` for another service.
    fn node_message(
        service: Service,
        padded: [u8; 8],
        len: u8,
    ) -> Result<Option<Message>, DecodeError> {
        let bad = DecodeError::Value { service };
        let expected = service.payload_len();
        let data = &padded;
        let message = match service {
            Service::Gates => {
                let gates = Gates {
                    group: byte(data, 0),
                    behaviours: byte(data, 1),
                    mask: u32_at(data, 2),
                    changes: byte(data, 6),
                };
                if !gates.is_valid() || byte(data, 7) != 0 {
                    return Err(bad);
                }
                Message::Gates(gates)
            }
            Service::DiagnosticControl => {
                let rate_hz = u16_at(data, 0);
                if rate_hz > DiagnosticControl::MAX_RATE_HZ {
                    return Err(bad);
                }
                let control = DiagnosticControl {
                    rate_hz,
                    ports: u16_at(data, 2),
                };
                // The length is the plain form's (4) or with its tag (8).
                if usize::from(len) > expected {
                    Message::AuthenticatedDiagnosticControl {
                        control,
                        tag: bytes_at(data, 4),
                    }
                } else {
                    Message::DiagnosticControl(control)
                }
            }
            // The bytes past the frame's length are zero, as the padding made them.
            Service::TableTransfer => Message::TableTransfer { data: padded, len },
            Service::SchemaTransfer => Message::SchemaTransfer { data: padded, len },
            #[cfg(feature = "update")]
            Service::UpdateTransfer => Message::UpdateTransfer { data: padded, len },
            Service::ChallengeRequest => Message::ChallengeRequest {
                tool_nonce: u64::from_le_bytes(padded),
            },
            Service::EmergencyStop => Message::EmergencyStop,
            Service::SchemaAbort => Message::SchemaAbort,
            Service::TransferOpen => {
                let flags = byte(data, 2);
                // One kind of transfer: a table image (replacing the running version or not), a
                // schema, or a firmware update's Begin. Replacing a version means nothing to a
                // schema nor to an update (whose image says itself whether it may downgrade).
                // So each flag alone, or none: one comparison of the byte (three tests of its
                // bits took 20 bytes more of the NUCLEO-G474RE's flash).
                if !matches!(flags, 0 | OPEN_REPLACE | OPEN_SCHEMA | OPEN_UPDATE) {
                    return Err(bad);
                }
                Message::TransferOpen(TransferOpen {
                    length: u16_at(data, 0),
                    flags,
                    tag: bytes_at(data, 3),
                })
            }
            Service::FilterProfile => {
                if byte(data, 1) != 0 {
                    return Err(bad);
                }
                Message::FilterProfile(FilterProfile {
                    profile: byte(data, 0),
                    sequence: u16_at(data, 2),
                })
            }
            Service::FilterSet => {
                if byte(data, 3) != 0 {
                    return Err(bad);
                }
                Message::FilterSet(FilterSet {
                    port: byte(data, 0),
                    connection: byte(data, 1),
                    phi: byte(data, 2),
                    sequence: u16_at(data, 4),
                })
            }
            Service::Seal => {
                let kind = byte(data, 0);
                if !Seal::is_sealable(kind) {
                    return Err(bad);
                }
                Message::Seal(Seal {
                    kind,
                    digest: byte(data, 1),
                    counter: u16_at(data, 2),
                    tag: bytes_at(data, 4),
                })
            }
            Service::FreshnessRequest => Message::FreshnessRequest {
                nonce: u64::from_le_bytes(padded),
            },
            Service::Freshness => Message::Freshness {
                epoch: u32_at(data, 0),
                counter: u32_at(data, 4),
            },
            #[cfg(feature = "identity")]
            Service::IdentityRequest => Message::IdentityRequest,
            #[cfg(feature = "identity")]
            Service::Assign => {
                let node_id = byte(data, 3);
                if node_id == 0 || node_id > crate::protocol::MAX_NODE_ID {
                    return Err(bad);
                }
                Message::Assign(Assign {
                    uid_check: u32_at(data, 0) & 0x00FF_FFFF,
                    node_id,
                    tag: (usize::from(len) > expected).then(|| bytes_at(data, 4)),
                })
            }
            #[cfg(feature = "identity")]
            Service::Configure => {
                if u16_at(data, 2) != 0 {
                    return Err(bad);
                }
                Message::Configure(Configure {
                    bitrate_kbps: u16_at(data, 0),
                    tag: (usize::from(len) > expected).then(|| bytes_at(data, 4)),
                })
            }
            _ => return Ok(None),
        };
        Ok(Some(message))
    }

    /// The payload of a service a node does not act on (reports, HBBA's desires and status).
    fn report(service: Service, padded: [u8; 8]) -> Result<Message, DecodeError> {
        let bad = DecodeError::Value { service };
        let data = &padded;
        Ok(match service {
            Service::Fault => Message::Fault(Fault {
                code: FaultCode::from_code(u16_at(data, 0)).ok_or(bad)?,
                count: byte(data, 2),
                detail: bytes_at(data, 3),
            }),
            Service::Heartbeat => Message::Heartbeat(Heartbeat {
                state: NodeState::from_code(byte(data, 0)).ok_or(bad)?,
                uptime_s: u32::from_le_bytes([byte(data, 1), byte(data, 2), byte(data, 3), 0]),
                table_version: u32_at(data, 4),
            }),
            Service::TableStatus => {
                let flags = byte(data, 7);
                if flags & !0b111 != 0 {
                    return Err(bad);
                }
                Message::TableStatus(TableStatus {
                    crc: u32_at(data, 0),
                    image_len: u16_at(data, 4),
                    ports: byte(data, 6),
                    stored: flags & 1 != 0,
                    diagnostic: flags & 2 != 0,
                    keyed: flags & 4 != 0,
                })
            }
            Service::Traffic => Message::Traffic(Traffic {
                received: u32_at(data, 0),
                delivered: u32_at(data, 4),
            }),
            Service::Errors => Message::Errors(Errors {
                discarded: u32_at(data, 0),
                errors: u32_at(data, 4),
            }),
            Service::Diagnostic => Message::Diagnostic(DiagnosticSample {
                port: byte(data, 0),
                connection: byte(data, 1),
                flags: DiagnosticFlags::from_bits(byte(data, 2)).ok_or(bad)?,
                sequence: byte(data, 3),
                level: u32_at(data, 4),
            }),
            Service::TransferStatus => {
                if u16_at(data, 6) != 0 {
                    return Err(bad);
                }
                Message::TransferStatus(TransferStatus {
                    status: TransferStatusCode::from_code(byte(data, 0)).ok_or(bad)?,
                    detail: byte(data, 1),
                    running_version: u32_at(data, 2),
                })
            }
            Service::Challenge => Message::Challenge {
                node_nonce: u64::from_le_bytes(padded) & crate::auth::NODE_NONCE_MAX,
                binding: bytes_at(data, crate::auth::NODE_NONCE_LEN),
            },
            Service::Receipt => Message::Receipt { tag: padded },
            Service::Desire => {
                if byte(data, 1) != 0 {
                    return Err(bad);
                }
                Message::Desire(DesireFrame {
                    class: byte(data, 0),
                    intensity: u16_at(data, 2),
                    lease_ms: u16_at(data, 4),
                    id: u16_at(data, 6),
                })
            }
            Service::Intention => Message::Intention(Intention {
                strategies: u64::from_le_bytes(padded),
            }),
            Service::FilterStatus => {
                let status = FilterStatus {
                    profile: byte(data, 0),
                    sequence: u16_at(data, 2),
                    filtered: byte(data, 4),
                    closed: byte(data, 5),
                    throttled: byte(data, 6),
                };
                let counts_fit = u16::from(status.closed) + u16::from(status.throttled)
                    <= u16::from(status.filtered);
                let profile_ok =
                    status.profile < 16 || status.profile == FilterStatus::SET_ONE_BY_ONE;
                if byte(data, 1) != 0 || byte(data, 7) != 0 || !counts_fit || !profile_ok {
                    return Err(bad);
                }
                Message::FilterStatus(status)
            }
            Service::Exploitation => {
                let delivering = match byte(data, 2) {
                    0 => false,
                    1 => true,
                    _ => return Err(bad),
                };
                if byte(data, 3) != 0 {
                    return Err(bad);
                }
                Message::Exploitation(Exploitation {
                    port: byte(data, 0),
                    connection: byte(data, 1),
                    delivering,
                })
            }
            Service::SchemaAck => {
                if bytes_at::<2>(data, 6) != [0; 2] || byte(data, 5) >= 64 {
                    return Err(bad);
                }
                let channel = match byte(data, 1) {
                    SchemaAck::NO_CHANNEL => None,
                    code => Some(SchemaChannel::from_code(code).ok_or(bad)?),
                };
                Message::SchemaAck(SchemaAck {
                    outcome: SchemaOutcome::from_code(byte(data, 0)).ok_or(bad)?,
                    channel,
                    id: u16_at(data, 2),
                    queued: byte(data, 4),
                    stop: byte(data, 5),
                })
            }
            Service::SchemaTransition => {
                let change = SchemaTransition {
                    ended: u16_at(data, 0),
                    installed: u16_at(data, 2),
                    trigger: SchemaTrigger::from_code(byte(data, 4)).ok_or(bad)?,
                    detail: byte(data, 5),
                    source: SchemaOrigin::from_code(byte(data, 6)).ok_or(bad)?,
                    queued: byte(data, 7),
                };
                if !change.is_valid() {
                    return Err(bad);
                }
                Message::SchemaTransition(change)
            }
            Service::SchemaState => {
                let flags = byte(data, 5);
                let fault = match byte(data, 3) {
                    SchemaState::NO_FAULT => None,
                    code => Some(SchemaSafety::from_code(code).ok_or(bad)?),
                };
                Message::SchemaState(SchemaState {
                    current: u16_at(data, 0),
                    source: SchemaOrigin::from_code(byte(data, 2)).ok_or(bad)?,
                    fault,
                    queued: byte(data, 4),
                    armed: flags & 1 != 0,
                    gripper_closed: flags & 2 != 0,
                    stop: flags >> 2,
                    elapsed_ms: u16_at(data, 6),
                })
            }
            #[cfg(feature = "identity")]
            Service::Identity
            | Service::IdentityVersion
            | Service::IdentityBuild
            | Service::IdentityCapacity
            | Service::IdentityFeatures
            | Service::IdentityName => {
                let part = super::identity_part(service).ok_or(bad)?;
                if !crate::identity::Identity::part_is_valid(part, &padded) {
                    return Err(bad);
                }
                Message::Identity {
                    part,
                    payload: padded,
                }
            }
            #[cfg(feature = "identity")]
            Service::ConfigStatus => {
                let command = byte(data, 0);
                let known =
                    command == Service::Assign.code() || command == Service::Configure.code();
                if !known || byte(data, 3) != 0 || u16_at(data, 6) != 0 || byte(data, 2) > 127 {
                    return Err(bad);
                }
                Message::ConfigStatus(ConfigStatus {
                    command: byte(data, 0),
                    status: ConfigStatusCode::from_code(byte(data, 1)).ok_or(bad)?,
                    node_id: byte(data, 2),
                    bitrate_kbps: u16_at(data, 4),
                })
            }
            #[cfg(feature = "update")]
            Service::UpdateStatus => Message::UpdateStatus(UpdateStatus {
                status: UpdateStatusCode::from_code(byte(data, 0)).ok_or(bad)?,
                offset: u32_at(data, 0) >> 8,
                value: u32_at(data, 4),
            }),
            // Decoded by `node_message`.
            _ => return Err(bad),
        })
    }
}
