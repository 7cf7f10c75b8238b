//! The schema server's values ([`crate::schema`]) as its frames carry them: a board running the
//! server turns its refusals, safety events and transitions into [`super::SchemaAck`],
//! [`SchemaTransition`], [`super::SchemaState`] and [`FaultCode::SchemaSafety`] faults with these.

use super::{
    FaultCode, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety, SchemaTransition,
    SchemaTrigger,
};
use crate::schema::{
    Channel, Origin, Refusal, STOP_NUMBERS, Safety, SchemaError, Transition, Trigger,
};

impl From<Safety> for SchemaSafety {
    fn from(safety: Safety) -> SchemaSafety {
        match safety {
            Safety::EmergencyStop => SchemaSafety::EmergencyStop,
            Safety::StaleSensor => SchemaSafety::StaleSensor,
            Safety::Limit => SchemaSafety::Limit,
            Safety::Force => SchemaSafety::Force,
            Safety::Watchdog => SchemaSafety::Watchdog,
            Safety::Overrun => SchemaSafety::Overrun,
            Safety::ImplausibleSensor => SchemaSafety::ImplausibleSensor,
            Safety::JointLimit => SchemaSafety::JointLimit,
            Safety::Speed => SchemaSafety::Speed,
        }
    }
}

impl From<SchemaSafety> for Safety {
    fn from(safety: SchemaSafety) -> Safety {
        match safety {
            SchemaSafety::EmergencyStop => Safety::EmergencyStop,
            SchemaSafety::StaleSensor => Safety::StaleSensor,
            SchemaSafety::Limit => Safety::Limit,
            SchemaSafety::Force => Safety::Force,
            SchemaSafety::Watchdog => Safety::Watchdog,
            SchemaSafety::Overrun => Safety::Overrun,
            SchemaSafety::ImplausibleSensor => Safety::ImplausibleSensor,
            SchemaSafety::JointLimit => Safety::JointLimit,
            SchemaSafety::Speed => Safety::Speed,
        }
    }
}

impl From<Origin> for SchemaOrigin {
    fn from(origin: Origin) -> SchemaOrigin {
        match origin {
            Origin::Innate => SchemaOrigin::Innate,
            Origin::Queue => SchemaOrigin::Queue,
            Origin::HighPriority => SchemaOrigin::HighPriority,
        }
    }
}

impl From<SchemaOrigin> for Origin {
    fn from(origin: SchemaOrigin) -> Origin {
        match origin {
            SchemaOrigin::Innate => Origin::Innate,
            SchemaOrigin::Queue => Origin::Queue,
            SchemaOrigin::HighPriority => Origin::HighPriority,
        }
    }
}

impl From<&SchemaError> for SchemaOutcome {
    fn from(error: &SchemaError) -> SchemaOutcome {
        match error {
            SchemaError::Malformed(_) => SchemaOutcome::Malformed,
            SchemaError::TrailingBytes => SchemaOutcome::TrailingBytes,
            SchemaError::ReservedId => SchemaOutcome::ReservedId,
            SchemaError::BadAxis => SchemaOutcome::BadAxis,
            SchemaError::BadSensor => SchemaOutcome::BadSensor,
            SchemaError::OutOfRange => SchemaOutcome::OutOfRange,
            SchemaError::Degenerate => SchemaOutcome::Degenerate,
        }
    }
}

impl From<&Refusal> for SchemaOutcome {
    fn from(refusal: &Refusal) -> SchemaOutcome {
        match refusal {
            Refusal::Invalid(error) => SchemaOutcome::from(error),
            Refusal::UnknownInnate => SchemaOutcome::UnknownInnate,
            Refusal::QueueFull => SchemaOutcome::QueueFull,
            Refusal::Busy => SchemaOutcome::Busy,
            Refusal::StopNotAcknowledged => SchemaOutcome::StopNotAcknowledged,
            Refusal::Looser => SchemaOutcome::Looser,
        }
    }
}

impl SchemaChannel {
    /// The channel a SchemaTransfer message's byte 0 names: bits 0-1 the channel (0 the queue,
    /// 1 the high-priority channel), bits 2-7 the stop number the high-priority channel
    /// acknowledges (0 for the queue). `None` for any other byte ([`SchemaOutcome::BadChannel`]).
    pub fn of_message(byte: u8) -> Option<Channel> {
        match (byte & 0b11, byte >> 2) {
            (0, 0) => Some(Channel::Queue),
            (1, stop) => Some(Channel::HighPriority { stop }),
            _ => None,
        }
    }

    /// Byte 0 of a SchemaTransfer message for `channel` (a stop number beyond 63 is taken
    /// modulo 64, as the server counts).
    pub fn message_byte(channel: Channel) -> u8 {
        match channel {
            Channel::Queue => 0,
            Channel::HighPriority { stop } => 1 | (stop % STOP_NUMBERS) << 2,
        }
    }

    /// The channel of `channel`, as SchemaAck byte 1 carries it.
    pub fn of(channel: Channel) -> SchemaChannel {
        match channel {
            Channel::Queue => SchemaChannel::Queue,
            Channel::HighPriority { .. } => SchemaChannel::HighPriority,
        }
    }
}

impl SchemaTrigger {
    /// A [`Trigger`] as [`SchemaTransition`] bytes 4-5 carry it: the kind, and its detail (the
    /// safety cause, the reaction's index; 0 otherwise).
    pub fn of(trigger: &Trigger) -> (SchemaTrigger, u8) {
        match *trigger {
            Trigger::HighPriority => (SchemaTrigger::HighPriority, 0),
            Trigger::Abort => (SchemaTrigger::Abort, 0),
            Trigger::Safety(safety) => (SchemaTrigger::Safety, SchemaSafety::from(safety).code()),
            Trigger::Reaction(index, _) => (SchemaTrigger::Reaction, index),
        }
    }
}

impl SchemaTransition {
    /// The frame of `transition`, with `queued` schemas in the queue after it (saturating at
    /// 255). Always valid ([`SchemaTransition::is_valid`]).
    pub fn from_transition(transition: &Transition, queued: usize) -> SchemaTransition {
        let (trigger, detail) = SchemaTrigger::of(&transition.by);
        SchemaTransition {
            ended: transition.ended,
            installed: transition.installed,
            trigger,
            detail,
            source: SchemaOrigin::from(transition.source),
            queued: u8::try_from(queued).unwrap_or(u8::MAX),
        }
    }
}

impl FaultCode {
    /// The detail of a [`FaultCode::SchemaSafety`] fault: byte 0 the cause, bytes 1-2 the
    /// schema it ended (u16 LE), the rest 0.
    pub fn schema_safety_detail(cause: Safety, ended: u16) -> [u8; 5] {
        let [e0, e1] = ended.to_le_bytes();
        [SchemaSafety::from(cause).code(), e0, e1, 0, 0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{BROADCAST, Message};
    use crate::schema::{Event, Schema};

    const SAFETIES: [Safety; 9] = [
        Safety::EmergencyStop,
        Safety::StaleSensor,
        Safety::Limit,
        Safety::Force,
        Safety::Watchdog,
        Safety::Overrun,
        Safety::ImplausibleSensor,
        Safety::JointLimit,
        Safety::Speed,
    ];

    #[test]
    fn safety_codes_are_the_servers_numbers() {
        for safety in SAFETIES {
            let code = SchemaSafety::from(safety);
            assert_eq!(code.code(), safety as u8);
            assert_eq!(Safety::from_u8(code.code()), Some(safety));
            assert_eq!(Safety::from(code), safety);
        }
        assert_eq!(SchemaSafety::ALL.len(), SAFETIES.len());
        for origin in [Origin::Innate, Origin::Queue, Origin::HighPriority] {
            assert_eq!(Origin::from(SchemaOrigin::from(origin)), origin);
            assert_eq!(SchemaOrigin::from(origin).description(), origin.name());
        }
    }

    #[test]
    fn refusals_have_their_outcome() {
        let cases = [
            (
                Refusal::Invalid(SchemaError::Malformed(
                    postcard::Error::DeserializeUnexpectedEnd,
                )),
                SchemaOutcome::Malformed,
            ),
            (
                Refusal::Invalid(SchemaError::TrailingBytes),
                SchemaOutcome::TrailingBytes,
            ),
            (
                Refusal::Invalid(SchemaError::ReservedId),
                SchemaOutcome::ReservedId,
            ),
            (
                Refusal::Invalid(SchemaError::BadAxis),
                SchemaOutcome::BadAxis,
            ),
            (
                Refusal::Invalid(SchemaError::BadSensor),
                SchemaOutcome::BadSensor,
            ),
            (
                Refusal::Invalid(SchemaError::OutOfRange),
                SchemaOutcome::OutOfRange,
            ),
            (
                Refusal::Invalid(SchemaError::Degenerate),
                SchemaOutcome::Degenerate,
            ),
            (Refusal::UnknownInnate, SchemaOutcome::UnknownInnate),
            (Refusal::QueueFull, SchemaOutcome::QueueFull),
            (Refusal::Busy, SchemaOutcome::Busy),
            (
                Refusal::StopNotAcknowledged,
                SchemaOutcome::StopNotAcknowledged,
            ),
            (Refusal::Looser, SchemaOutcome::Looser),
        ];
        for (refusal, outcome) in cases {
            assert_eq!(SchemaOutcome::from(&refusal), outcome, "{refusal:?}");
        }
        // A schema the decoder refuses, end to end.
        let refused = Schema::decode(&[0xFF; 4]).unwrap_err();
        assert_eq!(SchemaOutcome::from(&refused), SchemaOutcome::Malformed);
    }

    #[test]
    fn transitions_become_valid_frames() {
        let mut triggers = vec![Trigger::HighPriority, Trigger::Abort];
        triggers.extend(SAFETIES.map(Trigger::Safety));
        triggers.push(Trigger::Reaction(15, Event::Done));
        for by in triggers {
            let transition = Transition {
                ended: 3,
                by,
                installed: Schema::SAFETY + 2,
                source: Origin::Innate,
            };
            let frame = SchemaTransition::from_transition(&transition, 300);
            assert!(frame.is_valid(), "{by:?}");
            assert_eq!(frame.queued, u8::MAX);
            assert_eq!(
                frame.safety(),
                match by {
                    Trigger::Safety(s) => Some(SchemaSafety::from(s)),
                    _ => None,
                }
            );
            let message = Message::SchemaTransition(frame);
            let (_, decoded) = Message::decode(&message.to_frame(10, BROADCAST)).unwrap();
            assert_eq!(decoded, message);
        }
        let reaction = Transition {
            ended: 1,
            by: Trigger::Reaction(4, Event::OneShot),
            installed: 2,
            source: Origin::Queue,
        };
        let frame = SchemaTransition::from_transition(&reaction, 1);
        assert_eq!(
            (frame.trigger, frame.detail, frame.source, frame.queued),
            (SchemaTrigger::Reaction, 4, SchemaOrigin::Queue, 1)
        );
        assert_eq!(
            FaultCode::schema_safety_detail(Safety::Force, 0x0102),
            [3, 2, 1, 0, 0]
        );
    }
}
