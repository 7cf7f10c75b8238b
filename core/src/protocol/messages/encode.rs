//! Encoding: each message's payload at fixed offsets of one little-endian word, reports (what a
//! node sends) apart from commands (what it never sends, so that it does not link them).

use super::{DiagnosticControl, Message, SchemaAck, SchemaState};
use crate::frame::Frame;
use crate::protocol::{FrameId, SchemaChannel, SchemaSafety, Service};

impl Message {
    /// The frame carrying this message from `source` to `destination`.
    ///
    /// Each payload is built as one 8-byte array at fixed offsets (the bytes past its length
    /// zero): no writer, no copy loop, no bounds check. Each arm hands it over as one
    /// little-endian `u64`: as arrays, the arms' results were merged byte by byte, eight
    /// registers taken apart and put back together into words after the match (488 bytes of
    /// the boards' flash, and 142 instructions of the heartbeat group).
    pub fn to_frame(&self, source: u8, destination: u8) -> Frame {
        let (data, len) = match self.report_payload() {
            Some(payload) => payload,
            None => self.command_payload(),
        };
        frame(self.service(), source, destination, data, len)
    }

    /// [`Message::to_frame`] for what a node sends: its reports, answers and gates; `None` for
    /// a command (the tool's, the intention node's, a stop), which no node sends. A node links
    /// only this encoder: the commands' took about 100 bytes of the boards' flash.
    pub fn report_frame(&self, source: u8, destination: u8) -> Option<Frame> {
        let (data, len) = self.report_payload()?;
        Some(frame(self.service(), source, destination, data, len))
    }

    /// The 8 bytes of a report's payload as it goes on the wire (zeros past its length); `None`
    /// for a command. What a Receipt's tag covers, without building the frame.
    pub fn report_bytes(&self) -> Option<[u8; 8]> {
        self.report_payload().map(|(word, _)| word.to_le_bytes())
    }

    /// The payload of a message a node sends, and its length; `None` for a command.
    fn report_payload(&self) -> Option<(u64, u8)> {
        Some(match self {
            Message::Fault(fault) => {
                let [c0, c1] = fault.code.code().to_le_bytes();
                let [d0, d1, d2, d3, d4] = fault.detail;
                (le_word([c0, c1, fault.count, d0, d1, d2, d3, d4]), 8)
            }
            Message::Heartbeat(heartbeat) => {
                let [u0, u1, u2, _] = heartbeat.uptime_s.min(0x00FF_FFFF).to_le_bytes();
                let [v0, v1, v2, v3] = heartbeat.table_version.to_le_bytes();
                (
                    le_word([heartbeat.state.code(), u0, u1, u2, v0, v1, v2, v3]),
                    8,
                )
            }
            Message::TableStatus(status) => {
                let [c0, c1, c2, c3] = status.crc.to_le_bytes();
                let [l0, l1] = status.image_len.to_le_bytes();
                let flags = status.stored as u8
                    | (status.diagnostic as u8) << 1
                    | (status.keyed as u8) << 2;
                (le_word([c0, c1, c2, c3, l0, l1, status.ports, flags]), 8)
            }
            Message::Traffic(traffic) => (words(traffic.received, traffic.delivered), 8),
            Message::Errors(errors) => (words(errors.discarded, errors.errors), 8),
            Message::Diagnostic(sample) => {
                let [l0, l1, l2, l3] = sample.level.to_le_bytes();
                let flags = sample.flags.bits();
                let (port, connection) = (sample.port, sample.connection);
                (
                    le_word([port, connection, flags, sample.sequence, l0, l1, l2, l3]),
                    8,
                )
            }
            Message::TableTransfer { data, len } | Message::SchemaTransfer { data, len } => {
                // The bytes the frame carries; a length beyond 8 carries all 8.
                let len = (*len).min(8);
                let mut bytes = *data;
                for (at, byte) in bytes.iter_mut().enumerate() {
                    if at >= usize::from(len) {
                        *byte = 0;
                    }
                }
                (le_word(bytes), len)
            }
            Message::TransferStatus(status) => {
                let [v0, v1, v2, v3] = status.running_version.to_le_bytes();
                (
                    le_word([status.status.code(), status.detail, v0, v1, v2, v3, 0, 0]),
                    8,
                )
            }
            // The schema server's reports as two words each: fewer instructions than eight byte
            // stores on the boards (their encoders took 200 bytes of flash as byte arrays).
            Message::SchemaAck(ack) => {
                let channel = ack
                    .channel
                    .map_or(SchemaAck::NO_CHANNEL, SchemaChannel::code);
                let low = u32::from(ack.outcome.code())
                    | u32::from(channel) << 8
                    | u32::from(ack.id) << 16;
                // The stop number is below 64 (the server's own): not masked here.
                let high = u32::from(ack.queued) | u32::from(ack.stop) << 8;
                (words(low, high), 8)
            }
            Message::SchemaTransition(change) => {
                let low = u32::from(change.ended) | u32::from(change.installed) << 16;
                let high = u32::from_le_bytes([
                    change.trigger.code(),
                    change.detail,
                    change.source.code(),
                    change.queued,
                ]);
                (words(low, high), 8)
            }
            Message::SchemaState(state) => {
                let fault = state
                    .fault
                    .map_or(SchemaState::NO_FAULT, SchemaSafety::code);
                let flags = state.armed as u8 | (state.gripper_closed as u8) << 1 | state.stop << 2;
                let low = u32::from(state.current)
                    | u32::from(state.source.code()) << 16
                    | u32::from(fault) << 24;
                let high = u32::from(state.queued)
                    | u32::from(flags) << 8
                    | u32::from(state.elapsed_ms) << 16;
                (words(low, high), 8)
            }
            Message::Challenge {
                node_nonce,
                binding: [b0, b1],
            } => (
                *node_nonce & crate::auth::NODE_NONCE_MAX
                    | u64::from(u16::from_le_bytes([*b0, *b1])) << 48,
                8,
            ),
            Message::Receipt { tag } => (le_word(*tag), 8),
            Message::Seal(seal) => {
                let [c0, c1] = seal.counter.to_le_bytes();
                let [t0, t1, t2, t3] = seal.tag;
                (le_word([seal.kind, seal.digest, c0, c1, t0, t1, t2, t3]), 8)
            }
            Message::FreshnessRequest { nonce } => (*nonce, 8),
            Message::Freshness { epoch, counter } => (words(*epoch, *counter), 8),
            #[cfg(feature = "identity")]
            Message::Identity { payload, .. } => (le_word(*payload), 8),
            #[cfg(feature = "identity")]
            Message::ConfigStatus(status) => {
                let [b0, b1] = status.bitrate_kbps.to_le_bytes();
                (
                    le_word([
                        status.command,
                        status.status.code(),
                        status.node_id,
                        0,
                        b0,
                        b1,
                        0,
                        0,
                    ]),
                    8,
                )
            }
            #[cfg(feature = "update")]
            Message::UpdateTransfer { data, len } => {
                // As a table transfer's frame.
                let len = (*len).min(8);
                let mut bytes = *data;
                for (at, byte) in bytes.iter_mut().enumerate() {
                    if at >= usize::from(len) {
                        *byte = 0;
                    }
                }
                (le_word(bytes), len)
            }
            #[cfg(feature = "update")]
            Message::UpdateStatus(status) => {
                // Saturated to 24 bits: `UpdateStatus::MAX_OFFSET` says why not modulo 2^24.
                let offset = status.offset.min(super::UpdateStatus::MAX_OFFSET);
                (
                    words(u32::from(status.status.code()) | offset << 8, status.value),
                    8,
                )
            }
            Message::Gates(gates) => {
                let [m0, m1, m2, m3] = gates.mask.to_le_bytes();
                (
                    le_word([
                        gates.group,
                        gates.behaviours,
                        m0,
                        m1,
                        m2,
                        m3,
                        gates.changes,
                        0,
                    ]),
                    8,
                )
            }
            Message::FilterStatus(status) => {
                let [s0, s1] = status.sequence.to_le_bytes();
                (
                    le_word([
                        status.profile,
                        0,
                        s0,
                        s1,
                        status.filtered,
                        status.closed,
                        status.throttled,
                        0,
                    ]),
                    8,
                )
            }
            Message::Exploitation(edge) => (
                le_word([
                    edge.port,
                    edge.connection,
                    edge.delivering as u8,
                    0,
                    0,
                    0,
                    0,
                    0,
                ]),
                4,
            ),
            // Named one by one, so that a new message is put on one side or the other.
            Message::DiagnosticControl(_)
            | Message::AuthenticatedDiagnosticControl { .. }
            | Message::ChallengeRequest { .. }
            | Message::TransferOpen(_)
            | Message::Desire(_)
            | Message::Intention(_)
            | Message::FilterProfile(_)
            | Message::FilterSet(_)
            | Message::EmergencyStop
            | Message::SchemaAbort => return None,
            #[cfg(feature = "identity")]
            Message::IdentityRequest | Message::Assign(_) | Message::Configure(_) => return None,
        })
    }

    /// The payload of a command, and its length (a message a node sends has none here: see
    /// [`Message::report_payload`]).
    fn command_payload(&self) -> (u64, u8) {
        match self {
            Message::DiagnosticControl(control) => (le_word(control_bytes(control, [0; 4])), 4),
            Message::AuthenticatedDiagnosticControl { control, tag } => {
                (le_word(control_bytes(control, *tag)), 8)
            }
            Message::ChallengeRequest { tool_nonce } => (*tool_nonce, 8),
            Message::EmergencyStop | Message::SchemaAbort => (0, 0),
            #[cfg(feature = "identity")]
            Message::IdentityRequest => (0, 0),
            #[cfg(feature = "identity")]
            Message::Assign(assign) => tagged(assign.payload(), assign.tag),
            #[cfg(feature = "identity")]
            Message::Configure(configure) => tagged(configure.payload(), configure.tag),
            Message::TransferOpen(open) => {
                let [l0, l1] = open.length.to_le_bytes();
                let [t0, t1, t2, t3, t4] = open.tag;
                (le_word([l0, l1, open.flags, t0, t1, t2, t3, t4]), 8)
            }
            Message::Desire(desire) => {
                let [i0, i1] = desire.intensity.to_le_bytes();
                let [l0, l1] = desire.lease_ms.to_le_bytes();
                let [d0, d1] = desire.id.to_le_bytes();
                (le_word([desire.class, 0, i0, i1, l0, l1, d0, d1]), 8)
            }
            Message::Intention(intention) => (intention.strategies, 8),
            Message::FilterProfile(switch) => {
                let [s0, s1] = switch.sequence.to_le_bytes();
                (le_word([switch.profile, 0, s0, s1, 0, 0, 0, 0]), 4)
            }
            Message::FilterSet(set) => {
                let [s0, s1] = set.sequence.to_le_bytes();
                (
                    le_word([set.port, set.connection, set.phi, 0, s0, s1, 0, 0]),
                    6,
                )
            }
            _ => (0, 0),
        }
    }
}

/// The frame of `service` from `source` to `destination` with the first `len` bytes of `data`
/// (little endian).
fn frame(service: Service, source: u8, destination: u8, data: u64, len: u8) -> Frame {
    Frame::from_buffer(
        FrameId::new(service, source, destination).id(),
        data.to_le_bytes(),
        len,
    )
}

/// Two little-endian `u32`s, one after the other.
fn words(first: u32, second: u32) -> u64 {
    u64::from(first) | u64::from(second) << 32
}

/// Eight payload bytes as one little-endian word.
fn le_word(bytes: [u8; 8]) -> u64 {
    u64::from_le_bytes(bytes)
}

/// A 4-byte command and, in its keyed form, its tag (8 bytes then).
#[cfg(feature = "identity")]
fn tagged(payload: [u8; 4], tag: Option<[u8; 4]>) -> (u64, u8) {
    let [p0, p1, p2, p3] = payload;
    match tag {
        Some([t0, t1, t2, t3]) => (le_word([p0, p1, p2, p3, t0, t1, t2, t3]), 8),
        None => (le_word([p0, p1, p2, p3, 0, 0, 0, 0]), 4),
    }
}

/// A DiagnosticControl's payload: rate and ports, then `tag` (zeros in the plain form, whose
/// length stops before it).
fn control_bytes(control: &DiagnosticControl, tag: [u8; 4]) -> [u8; 8] {
    let [r0, r1] = control.rate_hz.to_le_bytes();
    let [p0, p1] = control.ports.to_le_bytes();
    let [t0, t1, t2, t3] = tag;
    [r0, r1, p0, p1, t0, t1, t2, t3]
}
