//! A schema's reaction table: sensory events and where the next schema comes from.
//!
//! The paper's events are "signal processing results that satisfy triggering conditions": here a
//! threshold on one value of the sensor table ([`Measure`]), or one of the server's virtual
//! sensors (one-shot, the action being done, time since installation, a non-empty queue). Each
//! is evaluated afresh every tick from the table, so the paper's "reset all event flags" on
//! installation is implicit: nothing is remembered from one schema to the next.

use serde::{Deserialize, Serialize};

use crate::wire::{Decode, Reader, decode_struct};

/// One value of the sensor table that an [`Event`] compares with a threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Measure {
    /// The measured pose on one axis (0..6), µm or µrad.
    Position(u8),
    /// The measured pose on one axis minus its value when the schema was installed: how far the
    /// robot went, whatever the attractor did (a peg dropping into its hole).
    Displacement(u8),
    /// The measured wrench on one axis, mN or mN·m.
    Force(u8),
    /// The force against the current action's direction of motion (mN): what a compliant move
    /// meets. Zero for an action that does not move.
    Contact,
    /// One of the board's extra sensors (0..[`super::MAX_SENSORS`]), in its topic's unit.
    Sensor(u8),
}

/// A sensory event: it holds or not, at each tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The current action has run at least one iteration (DESIGN.md: the paper's reading would
    /// fire before an action installed by the high-priority channel ever ran).
    OneShot,
    /// The current action is finished: a move on its goal, an idle's time out, a touch-down that
    /// travelled its whole distance, a search that covered its radius, a grasp settled.
    Done,
    /// At least this many ms since the schema was installed.
    Elapsed(u32),
    /// The queue holds a schema (the built-in wait schema's event).
    QueueReady,
    /// The value is at least the threshold.
    Above(Measure, i32),
    /// The value is at most the threshold.
    Below(Measure, i32),
}

/// Where the next schema comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Source {
    /// An innate schema of the board's set-up, by index: a reflex that needs no client.
    Innate(u8),
    /// The next schema the client queued; with the queue empty, a built-in schema that idles
    /// until it is not ([`super::Schema::WAIT_QUEUE`]).
    Queue,
    /// A built-in schema that idles until the high-priority channel speaks: appealing to the
    /// client for instructions.
    HighPriority,
}

/// One stimulus-response pair: when `event` holds, install a schema from `next`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Reaction {
    /// The stimulus.
    pub event: Event,
    /// The response: where the next schema comes from.
    pub next: Source,
}

impl Measure {
    /// The axis or sensor index it names, and whether that is a sensor's.
    pub(crate) fn index(self) -> Option<(u8, bool)> {
        match self {
            Measure::Position(a) | Measure::Displacement(a) | Measure::Force(a) => Some((a, false)),
            Measure::Sensor(s) => Some((s, true)),
            Measure::Contact => None,
        }
    }
}

impl Decode for Measure {
    fn decode(r: &mut Reader<'_>) -> Self {
        match r.variant(5) {
            0 => Measure::Position(r.u8()),
            1 => Measure::Displacement(r.u8()),
            2 => Measure::Force(r.u8()),
            3 => Measure::Contact,
            _ => Measure::Sensor(r.u8()),
        }
    }
}

impl Decode for Event {
    fn decode(r: &mut Reader<'_>) -> Self {
        match r.variant(6) {
            0 => Event::OneShot,
            1 => Event::Done,
            2 => Event::Elapsed(r.u32()),
            3 => Event::QueueReady,
            variant => {
                // Both thresholds: one read of the measure and the value.
                let (m, t) = (r.decode(), r.i32());
                if variant == 4 {
                    Event::Above(m, t)
                } else {
                    Event::Below(m, t)
                }
            }
        }
    }
}

impl Decode for Source {
    fn decode(r: &mut Reader<'_>) -> Self {
        match r.variant(3) {
            0 => Source::Innate(r.u8()),
            1 => Source::Queue,
            _ => Source::HighPriority,
        }
    }
}

decode_struct!(Reaction { event, next });
