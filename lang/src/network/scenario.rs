//! The scenario a simulation plays: `[[events]]` (frames published on a topic, at a rate or at
//! given times), `[[phases]]` (labels for the plot's bottom strip) and `[[faults]]` (nodes that
//! stop).

use std::ops::Range;

use schemars::JsonSchema;
use serde::Deserialize;

use super::spanned::Spanned;
use super::{Builder, Node, Topic, list_or_none, suggest};
use crate::can_frame::{CLASSIC_DATA_LEN, FD_DATA_LEN};
use crate::shown;

/// The most frames the `[[events]]` of one file may generate, so that a typo in a rate cannot
/// exhaust memory.
pub const MAX_EVENT_FRAMES: u64 = 10_000_000;

/// The latest time an event or phase may have, in seconds (about 11.6 days).
pub const MAX_TIME_S: f64 = 1_000_000.0;

/// `[[faults]] node = "r2", at = 12.0`: the node stops.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawFault {
    /// Required: the node that stops (receives nothing, sends nothing, its ports deliver nothing).
    node: Spanned<String>,
    /// Required: from when, in seconds (a frame of that microsecond included).
    at: Spanned<f64>,
    /// Optional: a remark for the reader; not used.
    #[allow(dead_code)]
    note: Option<String>,
}

/// `[[events]]`: frames published on a topic in a simulation, either at `rate_hz` from `from` to
/// `to` or at the times of `at`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawEvent {
    /// Required: the topic the frames are published on.
    topic: Spanned<String>,
    /// Optional: the frames' payload, as many bytes 0..=255 as its topic's `length` (at most 8,
    /// or 64 on a CAN FD topic); default that many zeros.
    data: Option<Spanned<Vec<Spanned<i64>>>>,
    /// Frames per second: at from, from + 1/rate_hz, ... while t < to.
    rate_hz: Option<Spanned<f64>>,
    /// Optional, with rate_hz: the first frame's time in seconds, default 0.
    from: Option<Spanned<f64>>,
    /// With rate_hz: the end in seconds (exclusive).
    to: Option<Spanned<f64>>,
    /// Or explicit times, in seconds.
    at: Option<Spanned<Vec<f64>>>,
    /// Optional: a remark for the reader; not used.
    #[allow(dead_code)]
    note: Option<String>,
}

/// `[[phases]]`: a label for the plot's bottom strip.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPhase {
    /// Required: the label.
    name: Spanned<String>,
    /// Required: its start, seconds.
    from: Spanned<f64>,
    /// Required: its end, seconds.
    to: Spanned<f64>,
    /// Optional: a remark shown with it.
    note: Option<Spanned<String>>,
}

/// When an event's frames are sent.
#[derive(Clone, Debug, PartialEq)]
pub enum Schedule {
    /// Frames at `from`, `from + 1/rate_hz`, ... while t < `to`.
    Rate {
        /// Frames per second.
        rate_hz: f64,
        /// First frame, seconds.
        from: f64,
        /// End (exclusive), seconds.
        to: f64,
    },
    /// Frames at these times, seconds.
    At(Vec<f64>),
}

impl Schedule {
    /// The number of frames, without generating them.
    pub fn count(&self) -> u64 {
        match self {
            Schedule::Rate { rate_hz, from, to } => {
                let span = ((to - from) * rate_hz).ceil();
                if span.is_finite() && span > 0.0 {
                    span as u64
                } else {
                    0
                }
            }
            Schedule::At(times) => times.len() as u64,
        }
    }

    /// The frame times, in seconds, in the order the schedule gives them.
    pub fn times(&self) -> Vec<f64> {
        match self {
            Schedule::Rate { rate_hz, from, to } => (0..self.count())
                .map(|k| from + k as f64 / rate_hz)
                .filter(|t| t < to)
                .collect(),
            Schedule::At(times) => times.clone(),
        }
    }
}

/// Frames published on a topic in a simulation.
#[derive(Clone, Debug)]
pub struct Event {
    /// The topic, as an index into [`Network::topics`](super::Network::topics).
    pub topic: usize,
    /// The frames' payload (`data = [...]`, its topic's `length` bytes; default that many
    /// zeros).
    pub data: Vec<u8>,
    /// When.
    pub schedule: Schedule,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// A named interval of the scenario, shown on plots.
#[derive(Clone, Debug, PartialEq)]
pub struct Phase {
    /// Its name, e.g. "A".
    pub name: String,
    /// Start, seconds.
    pub from: f64,
    /// End, seconds.
    pub to: f64,
    /// What happens in it.
    pub note: Option<String>,
}

/// A node that stops in a simulation (`[[faults]]`): from `at` on it receives nothing, sends
/// nothing, and its ports deliver nothing.
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    /// The node, as an index into [`Network::nodes`](super::Network::nodes).
    pub node: usize,
    /// When it stops, seconds.
    pub at: f64,
}

impl Builder<'_> {
    pub(super) fn time(&mut self, value: &Spanned<f64>, what: &str) -> Option<f64> {
        let t = *value.get_ref();
        if t.is_finite() && (0.0..=MAX_TIME_S).contains(&t) {
            Some(t)
        } else {
            self.error(
                value.span(),
                format!("{what} must be a time in [0, {MAX_TIME_S}] seconds"),
            );
            None
        }
    }

    pub(super) fn events(&mut self, raw: &[Spanned<RawEvent>], topics: &[Topic]) -> Vec<Event> {
        let mut events = Vec::new();
        let mut frames: u64 = 0;
        for event in raw {
            let raw_event = event.get_ref();
            let topic_name = raw_event.topic.get_ref();
            let Some(topic) = topics.iter().position(|topic| &topic.name == topic_name) else {
                if self.declared.topics.contains(topic_name.as_str()) {
                    continue;
                }
                let known: Vec<&str> = topics.iter().map(|topic| topic.name.as_str()).collect();
                self.error(
                    raw_event.topic.span(),
                    format!(
                        "topic `{topic_name}` is not defined (topics: {}){}",
                        list_or_none(&known),
                        suggest(topic_name, &known)
                    ),
                );
                continue;
            };
            let schedule = match (&raw_event.at, &raw_event.rate_hz) {
                (Some(_), Some(rate)) => {
                    self.error(rate.span(), "an event has either `at = [...]` or `rate_hz` with `from` and `to`, not both");
                    continue;
                }
                (None, None) => {
                    self.error(
                        event.span(),
                        "an event needs `at = [times...]` or `rate_hz` with `to` (and optionally `from`)",
                    );
                    continue;
                }
                (Some(at), None) => {
                    let times = at.get_ref();
                    if let Some(bad) = times
                        .iter()
                        .find(|t| !(t.is_finite() && (0.0..=MAX_TIME_S).contains(*t)))
                    {
                        self.error(
                            at.span(),
                            format!("time {bad} is not in [0, {MAX_TIME_S}] seconds"),
                        );
                        continue;
                    }
                    if raw_event.from.is_some() || raw_event.to.is_some() {
                        self.error(
                            at.span(),
                            "`from` and `to` go with `rate_hz`, not with `at`",
                        );
                        continue;
                    }
                    Schedule::At(times.clone())
                }
                (None, Some(rate)) => {
                    let rate_hz = *rate.get_ref();
                    if !(rate_hz.is_finite() && rate_hz > 0.0) {
                        self.error(
                            rate.span(),
                            "rate_hz must be a positive number of frames per second",
                        );
                        continue;
                    }
                    let Some(to) = &raw_event.to else {
                        self.error(
                            event.span(),
                            "an event with `rate_hz` needs `to` (the end time, exclusive)",
                        );
                        continue;
                    };
                    let from = match &raw_event.from {
                        Some(from) => self.time(from, "from"),
                        None => Some(0.0),
                    };
                    let (Some(from), Some(to_value)) = (from, self.time(to, "to")) else {
                        continue;
                    };
                    if to_value <= from {
                        self.error(
                            to.span(),
                            format!("`to` ({to_value}) must be after `from` ({from})"),
                        );
                        continue;
                    }
                    Schedule::Rate {
                        rate_hz,
                        from,
                        to: to_value,
                    }
                }
            };
            let Some(data) = self.payload(raw_event.data.as_ref(), &topics[topic]) else {
                continue;
            };
            frames = frames.saturating_add(schedule.count());
            if frames > MAX_EVENT_FRAMES {
                self.error(
                    event.span(),
                    format!("the events generate more than {MAX_EVENT_FRAMES} frames"),
                );
                return events;
            }
            events.push(Event {
                topic,
                data,
                schedule,
                span: event.span(),
            });
        }
        events
    }

    /// An event's `data = [...]`: as many bytes as its topic's `length`, each 0..=255 (default:
    /// that many zeros). `None` after reporting what is wrong.
    fn payload(
        &mut self,
        raw: Option<&Spanned<Vec<Spanned<i64>>>>,
        topic: &Topic,
    ) -> Option<Vec<u8>> {
        let Some(raw) = raw else {
            return Some(vec![0; usize::from(topic.length)]);
        };
        let most = if topic.fd {
            FD_DATA_LEN
        } else {
            CLASSIC_DATA_LEN
        };
        if raw.get_ref().len() > most {
            let frame = if topic.fd { "a CAN FD" } else { "a CAN" };
            self.error(
                raw.span(),
                format!(
                    "data has {} bytes; {frame} frame carries at most {most}",
                    raw.get_ref().len()
                ),
            );
            return None;
        }
        let mut bytes = Vec::new();
        for byte in raw.get_ref() {
            match u8::try_from(*byte.get_ref()) {
                Ok(value) => bytes.push(value),
                Err(_) => {
                    self.error(
                        byte.span(),
                        format!("data byte {} is not in 0..=255", byte.get_ref()),
                    );
                    return None;
                }
            }
        }
        if bytes.len() != usize::from(topic.length) {
            let length = if topic.length as usize == CLASSIC_DATA_LEN {
                format!("{CLASSIC_DATA_LEN} (its `length`, {CLASSIC_DATA_LEN} by default)")
            } else {
                format!("{} (its `length`)", topic.length)
            };
            self.error(
                raw.span(),
                format!(
                    "data has {} byte{}, but topic `{}`'s frames carry {length}: write {} bytes, or set `length = {}` on the topic",
                    bytes.len(),
                    if bytes.len() == 1 { "" } else { "s" },
                    topic.name,
                    topic.length,
                    bytes.len()
                ),
            );
            return None;
        }
        Some(bytes)
    }

    pub(super) fn faults(&mut self, raw: &[Spanned<RawFault>], nodes: &[Node]) -> Vec<Fault> {
        let mut faults: Vec<Fault> = Vec::new();
        for fault in raw {
            let raw_fault = fault.get_ref();
            let wanted = raw_fault.node.get_ref();
            let Some(node) = nodes.iter().position(|node| &node.name == wanted) else {
                if self.declared.nodes.contains(wanted.as_str()) {
                    continue;
                }
                let known: Vec<&str> = nodes.iter().map(|node| node.name.as_str()).collect();
                self.error(
                    raw_fault.node.span(),
                    format!(
                        "node `{}` is not defined (nodes: {}){}",
                        shown::escaped(wanted),
                        list_or_none(&known),
                        suggest(wanted, &known)
                    ),
                );
                continue;
            };
            let Some(at) = self.time(&raw_fault.at, "at") else {
                continue;
            };
            if let Some(earlier) = faults.iter().find(|f| f.node == node) {
                self.error(
                    raw_fault.node.span(),
                    format!(
                        "node `{wanted}` already stops at {} s; a stopped node stays stopped",
                        earlier.at
                    ),
                );
                continue;
            }
            faults.push(Fault { node, at });
        }
        faults
    }

    pub(super) fn phases(&mut self, raw: &[Spanned<RawPhase>]) -> Vec<Phase> {
        let mut phases = Vec::new();
        for phase in raw {
            let raw_phase = phase.get_ref();
            let name_ok = self.printable(&raw_phase.name, "phase name");
            let note_ok = raw_phase
                .note
                .as_ref()
                .is_none_or(|note| self.printable(note, "phase note"));
            if !(name_ok && note_ok) {
                continue;
            }
            let (Some(from), Some(to)) = (
                self.time(&raw_phase.from, "from"),
                self.time(&raw_phase.to, "to"),
            ) else {
                continue;
            };
            if to <= from {
                self.error(
                    raw_phase.to.span(),
                    format!("`to` ({to}) must be after `from` ({from})"),
                );
                continue;
            }
            phases.push(Phase {
                name: raw_phase.name.get_ref().clone(),
                from,
                to,
                note: raw_phase.note.as_ref().map(|note| note.get_ref().clone()),
            });
        }
        phases
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::tests::{FIGURE_1, errors, parse};

    #[test]
    fn events_are_checked() {
        let base = FIGURE_1.split("[[events]]").next().unwrap().to_string();
        let cases = [
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 0\nto = 1\n",
                "rate_hz must be a positive number",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 1\n",
                "needs `to`",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 1\nfrom = 2\nto = 1\n",
                "must be after `from`",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nat = [1.0, -1.0]\n",
                "time -1 is not in",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\n",
                "needs `at = [times...]`",
            ),
            (
                "[[events]]\ntopic = \"face_pos\"\nrate_hz = 1e9\nto = 1000\n",
                "more than 10000000 frames",
            ),
        ];
        for (event, message) in cases {
            let errors = errors(&format!("{base}{event}"));
            assert!(
                errors.iter().any(|e| e.contains(message)),
                "{event}: {errors:?}"
            );
        }
    }

    #[test]
    fn events_carry_data_and_faults_stop_nodes() {
        // object_pos's frames carry 2 bytes; face_pos's the default 8, zeros without `data`.
        let two = FIGURE_1.replace("can_id = 0x111\n", "can_id = 0x111\nlength = 2\n");
        let text = format!("{two}data = [0x0A, 0]\n[[faults]]\nnode = \"gaze\"\nat = 12.5\n");
        let network = parse(&text).unwrap();
        assert_eq!(network.topics[0].length, 8);
        assert_eq!(network.topics[1].length, 2);
        assert_eq!(network.events[0].data, vec![0; 8]);
        assert_eq!(network.events[1].data, vec![0x0A, 0]);
        assert_eq!(network.faults, vec![Fault { node: 0, at: 12.5 }]);
        let bad = [
            (
                "data = [1, 2, 3, 4, 5, 6, 7, 8, 9]\n",
                "data has 9 bytes; a CAN frame carries at most 8",
            ),
            (
                "data = [1, 2, 3]\n",
                "data has 3 bytes, but topic `object_pos`'s frames carry 8 (its `length`, 8 by default): write 8 bytes, or set `length = 3` on the topic",
            ),
            ("data = [0x100]\n", "data byte 256 is not in 0..=255"),
            ("data = [-1]\n", "data byte -1 is not in 0..=255"),
            (
                "[[faults]]\nnode = \"arm\"\nat = 1\n",
                "node `arm` is not defined (nodes: gaze)",
            ),
            (
                "[[faults]]\nnode = \"gaze\"\nat = -1\n",
                "at must be a time in [0, 1000000] seconds",
            ),
            (
                "[[faults]]\nnode = \"gaze\"\nat = 1\n[[faults]]\nnode = \"gaze\"\nat = 2\n",
                "node `gaze` already stops at 1 s",
            ),
        ];
        for (extra, message) in bad {
            let errors = errors(&format!("{FIGURE_1}{extra}"));
            assert_eq!(errors.len(), 1, "{extra}: {errors:?}");
            assert!(errors[0].contains(message), "{extra}: {errors:?}");
        }
    }

    #[test]
    fn rate_schedules_exclude_the_end() {
        let schedule = Schedule::Rate {
            rate_hz: 10.0,
            from: 1.0,
            to: 2.0,
        };
        let times = schedule.times();
        assert_eq!(times.len(), 10);
        assert_eq!(times[0], 1.0);
        assert!(times[9] < 2.0);
    }
}
