//! A schema as the client sends it: postcard bytes (over ISO-TP), decoded and checked whole.
//!
//! A schema is refused whole when its bytes are malformed, too long or out of range (DESIGN.md):
//! the server never runs part of one, and nothing in it can make a tick panic or overflow.

use heapless::Vec;
use serde::{Deserialize, Serialize};

use super::{
    AXES, Action, BUILTIN_IDS, Event, MAX_COORD, MAX_REACTIONS, MAX_SENSORS, Reaction, Source,
};
use crate::wire::decode_struct;

/// One action primitive and its reaction table, in priority order (the first event that holds
/// wins; the server's safety events come before them all).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Schema {
    /// The client's name for it, echoed in every status frame about it; below [`BUILTIN_IDS`].
    pub id: u16,
    /// What each tick does while the schema is installed.
    pub action: Action,
    /// Stimulus → source of the next schema, highest priority first.
    pub reactions: Vec<Reaction, MAX_REACTIONS>,
    /// The watchdog's budget, ms; 0 for the default (the action's nominal time × 1.5 plus the
    /// board's margin; none for an idle without end).
    pub watchdog_ms: u32,
}

/// Why a schema's bytes were refused.
#[derive(Clone, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SchemaError {
    /// Not postcard's encoding of a [`Schema`] (or more than [`MAX_REACTIONS`] reactions).
    Malformed(postcard::Error),
    /// Bytes after the schema.
    TrailingBytes,
    /// An identifier from [`BUILTIN_IDS`] up: those name the server's own schemas.
    ReservedId,
    /// An axis index of 6 or more.
    BadAxis,
    /// A sensor index of [`MAX_SENSORS`] or more.
    BadSensor,
    /// A coordinate, speed, distance or time beyond [`MAX_COORD`].
    OutOfRange,
    /// A motion with speed 0, a touch-down with no direction, a search with pitch 0, or a wobble
    /// with period 0: actions that would never progress.
    Degenerate,
}

impl core::fmt::Display for SchemaError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SchemaError::Malformed(error) => write!(f, "not a schema's encoding: {error}"),
            SchemaError::TrailingBytes => f.write_str("bytes after the schema"),
            SchemaError::ReservedId => write!(
                f,
                "schema id {BUILTIN_IDS} or above: reserved for the server's own schemas"
            ),
            SchemaError::BadAxis => f.write_str("axis index of 6 or more"),
            SchemaError::BadSensor => write!(f, "sensor index of {MAX_SENSORS} or more"),
            SchemaError::OutOfRange => {
                write!(f, "coordinate, speed, distance or time beyond {MAX_COORD}")
            }
            SchemaError::Degenerate => f.write_str(
                "an action that would never progress (a speed, direction, pitch or period of 0)",
            ),
        }
    }
}

impl core::error::Error for SchemaError {}

/// The most bytes a valid schema takes: the receive buffer's size.
pub const MAX_ENCODED: usize = 256;

impl Schema {
    /// The built-in schema installed from an empty queue: idle until the queue is not empty.
    pub const WAIT_QUEUE: u16 = BUILTIN_IDS;
    /// The built-in schema that waits for the high-priority channel.
    pub const WAIT_HIGH_PRIORITY: u16 = BUILTIN_IDS + 1;
    /// The built-in recovery after a safety event: `SAFETY + cause` ([`super::Safety`]'s
    /// number).
    pub const SAFETY: u16 = BUILTIN_IDS + 0x10;

    /// Decodes and checks a schema; the bytes must hold exactly one.
    ///
    /// Costs one pass over the bytes (at most [`MAX_ENCODED`] valid ones) and a check of every
    /// field; copies the schema (about 300 bytes) out.
    pub fn decode(bytes: &[u8]) -> Result<Schema, SchemaError> {
        let (schema, rest) = crate::wire::take::<Schema>(bytes).map_err(SchemaError::Malformed)?;
        if !rest.is_empty() {
            return Err(SchemaError::TrailingBytes);
        }
        schema.check()?;
        Ok(schema)
    }

    /// Checks every field against the ranges a tick relies on ([`SchemaError`] says which).
    pub fn check(&self) -> Result<(), SchemaError> {
        if self.id >= BUILTIN_IDS {
            return Err(SchemaError::ReservedId);
        }
        check_action(&self.action)?;
        for r in &self.reactions {
            match r.event {
                Event::Above(m, _) | Event::Below(m, _) => match m.index() {
                    Some((a, false)) if usize::from(a) >= AXES => return Err(SchemaError::BadAxis),
                    Some((s, true)) if usize::from(s) >= MAX_SENSORS => {
                        return Err(SchemaError::BadSensor);
                    }
                    _ => {}
                },
                Event::OneShot | Event::Done | Event::Elapsed(_) | Event::QueueReady => {}
            }
        }
        Ok(())
    }

    /// The built-in schema `id`: [`Schema::WAIT_QUEUE`] and [`Schema::WAIT_HIGH_PRIORITY`]
    /// idle, the first until the queue is not empty; a safety recovery (`SAFETY + cause`)
    /// relieves the forces once, then waits for the high-priority channel.
    // From the identifier alone: the server's five built-in schemas each inlined their
    // construction (8 bytes of the NUCLEO-G474RE's flash). Left to the inliner now: out of
    // line it took 8 bytes more of the NUCLEO-G474RE's flash, 4 of the emulated board's.
    pub(crate) fn builtin(id: u16) -> Schema {
        let (action, reaction) = match id {
            Schema::WAIT_QUEUE => (
                Action::Idle { ms: 0 },
                Some(Reaction {
                    event: Event::QueueReady,
                    next: Source::Queue,
                }),
            ),
            Schema::WAIT_HIGH_PRIORITY => (Action::Idle { ms: 0 }, None),
            _ => (
                Action::Relieve,
                Some(Reaction {
                    event: Event::OneShot,
                    next: Source::HighPriority,
                }),
            ),
        };
        Schema {
            id,
            action,
            // From an array: no capacity check to inline (16 > 1).
            reactions: match reaction {
                Some(r) => Vec::from_array([r]),
                None => Vec::new(),
            },
            watchdog_ms: 0,
        }
    }
}

fn within(v: u32) -> bool {
    v <= MAX_COORD as u32
}

fn pose_within(p: &super::Pose) -> bool {
    p.iter().all(|c| c.unsigned_abs() <= MAX_COORD as u32)
}

fn check_action(a: &Action) -> Result<(), SchemaError> {
    // Each action's largest integer and its pose, then one range check for them all.
    let (largest, pose, degenerate) = match *a {
        Action::Idle { ms }
        | Action::Grasp { settle_ms: ms }
        | Action::Release { settle_ms: ms } => (ms, None, false),
        Action::Gripper(_) | Action::Relieve => (0, None, false),
        Action::SetImpedance { stiffness, damping } => (stiffness.max(damping), None, false),
        Action::MoveTo { ref goal, speed } => (speed, Some(goal), speed == 0),
        Action::MoveToTouch {
            ref direction,
            speed,
            distance,
        } => (
            speed.max(distance),
            Some(direction),
            speed == 0 || direction[..3] == [0; 3],
        ),
        Action::BlindSearch {
            preload,
            pitch,
            speed,
            radius,
            wobble,
            wobble_ms,
        } => (
            preload
                .max(pitch)
                .max(speed)
                .max(radius)
                .max(wobble)
                .max(wobble_ms),
            None,
            speed == 0 || pitch == 0 || (wobble != 0 && wobble_ms == 0),
        ),
    };
    let ranged = within(largest) && pose.is_none_or(pose_within);
    if !ranged {
        Err(SchemaError::OutOfRange)
    } else if degenerate {
        Err(SchemaError::Degenerate)
    } else {
        Ok(())
    }
}

decode_struct!(Schema {
    id,
    action,
    reactions,
    watchdog_ms
});
