//! `[topics.NAME]`: the streams of CAN frames, each matched by identifier and mask, with the rate
//! its publisher sends at and the data length of its frames.

use std::ops::Range;

use indexmap::IndexMap;
use pab_core::Filter;
use pab_core::filter::{MAX_EXTENDED_ID, MAX_STANDARD_ID};
use schemars::JsonSchema;
use serde::Deserialize;

use super::spanned::Spanned;
use super::{Builder, Bus, Network, PLAIN_NAME, is_plain_name, list_or_none, suggest};
use crate::can_frame::{CLASSIC_DATA_LEN, FD_DATA_LEN, fd_length};

/// The highest `rate_hz` of a topic: more frames a second than a 1 Mbit/s bus carries.
pub const MAX_RATE_HZ: f64 = 100_000.0;

/// `[topics.NAME]`: a stream of CAN frames.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTopic {
    /// Required: the frames' identifier, 11-bit (0..=0x7FF), or 29-bit (0..=0x1FFFFFFF) with
    /// `extended = true`.
    can_id: Spanned<i64>,
    /// Optional, default false: a 29-bit identifier.
    #[serde(default)]
    extended: bool,
    /// Optional: a frame matches when (frame_id & mask) == can_id; default all bits (exact
    /// match); can_id may not have bits outside mask.
    mask: Option<Spanned<i64>>,
    /// Optional: frames per second the publisher sends, (0, 100000], kept in whole µHz; what
    /// HBBA's bus costs are computed from (required on a topic whose connection a strategy lets
    /// through when `[hbba]` has a `bus` resource, unless the topic has a `period`). The same
    /// thing as `period` (1/period): write one or the other.
    rate_hz: Option<Spanned<f64>>,
    /// Optional: seconds, the shortest time between two of its frames, 0.00001 to 3600, kept in
    /// whole nanoseconds; its rate is 1/period. A topic with a period (or a `rate_hz`) is a stream of
    /// `pabctl check`'s response times when the network has `[bus] bitrate`.
    period: Option<Spanned<f64>>,
    /// Optional, default 0: seconds, how late after its period's start a frame may be queued
    /// (its queuing jitter), [0, 3600]; with `period` or `rate_hz` only.
    jitter: Option<Spanned<f64>>,
    /// Optional, default the period: seconds from a period's start by which its frame must
    /// have left the bus, (0, 3600] (may exceed the period); with `period` or `rate_hz` only.
    deadline: Option<Spanned<f64>>,
    /// Optional, default 8: the data bytes of its frames, 0..=8, or with `fd = true` a CAN FD
    /// length (0..=8, 12, 16, 20, 24, 32, 48 or 64); the DLC of its DBC message and the length of
    /// its simulated frames (an event's `data` has exactly this many bytes); every field read
    /// from its frames must lie within it.
    length: Option<Spanned<i64>>,
    /// Optional, default false: its frames are CAN FD frames (with bit-rate switching when
    /// `[bus] data_bitrate` is above `bitrate`), whose `length` may be up to 64; on a CAN FD bus
    /// only (`[bus] data_bitrate`).
    fd: Option<Spanned<bool>>,
    /// Optional: what the frames carry; their message's comment in the DBC export.
    description: Option<Spanned<String>>,
}

/// A stream of frames from one publisher, matched by CAN id and mask.
#[derive(Clone, Debug)]
pub struct Topic {
    /// Its name in the file.
    pub name: String,
    /// The frames it designates.
    pub filter: Filter,
    /// How many frames a second it carries (`rate_hz`, optional), as written: what the HBBA
    /// strategies' bus costs are computed from.
    pub rate_hz: Option<f64>,
    /// The same in whole µHz (rounded to nearest); from `period` when the file gives that.
    pub rate_uhz: Option<u64>,
    /// Its timing on the bus (`period`, or 1/`rate_hz`, with `jitter` and `deadline`): `None`
    /// without either.
    pub timing: Option<TopicTiming>,
    /// How many data bytes its frames carry (`length`, 0 to 8, or a CAN FD length up to 64 with
    /// `fd`; default 8): the DBC export's DLC, the simulated frames' length, and the bytes a
    /// field of its frames may read.
    pub length: u8,
    /// Its frames are CAN FD frames (`fd = true`; on a CAN FD bus only).
    pub fd: bool,
    /// What the file says it carries (`description`): the DBC export's comment on its message.
    pub description: Option<String>,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// The longest `period`, `jitter` or `deadline` of a topic, seconds: an hour.
pub const MAX_TOPIC_SECONDS: f64 = 3600.0;

/// A topic's timing on the bus, in nanoseconds: what `pabctl check`'s response times take.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicTiming {
    /// The shortest time between two frames: `period`, or 1/`rate_hz` rounded down.
    pub period_ns: u64,
    /// The queuing jitter (`jitter`, default 0).
    pub jitter_ns: u64,
    /// The deadline (`deadline`, default the period).
    pub deadline_ns: u64,
    /// Where the file says it: the `deadline` if written, else the `period` or `rate_hz`.
    pub span: Range<usize>,
}

impl Builder<'_> {
    /// The topics; `bus` the network's `[bus]` (`written`: the file has one, maybe mistaken),
    /// which an `fd = true` topic needs to be CAN FD.
    pub(super) fn topics(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawTopic>>,
        bus: Option<&Bus>,
        written: bool,
    ) -> Vec<Topic> {
        let mut topics: Vec<Topic> = Vec::new();
        for (name, topic) in raw {
            if self.printable(name, "topic name") && !is_plain_name(name.get_ref()) {
                self.error(
                    name.span(),
                    format!("topic name `{}`: {PLAIN_NAME}", name.get_ref()),
                );
            }
            let raw_topic = topic.get_ref();
            let extended = raw_topic.extended;
            let widest = if extended {
                MAX_EXTENDED_ID
            } else {
                MAX_STANDARD_ID
            };
            let format = if extended {
                "extended (29-bit)"
            } else {
                "standard (11-bit)"
            };
            let id = *raw_topic.can_id.get_ref();
            let Some(id) = u32::try_from(id).ok().filter(|&id| id <= widest) else {
                let hint = if extended {
                    ""
                } else {
                    "; write `extended = true` for a 29-bit id"
                };
                self.error(
                    raw_topic.can_id.span(),
                    format!(
                        "can_id {id:#x} does not fit a {format} id (at most {widest:#x}){hint}"
                    ),
                );
                continue;
            };
            let mask = match &raw_topic.mask {
                None => widest,
                Some(mask) => match u32::try_from(*mask.get_ref()).ok().filter(|&m| m <= widest) {
                    Some(mask) => mask,
                    None => {
                        self.error(
                            mask.span(),
                            format!(
                                "mask {:#x} does not fit a {format} id (at most {widest:#x})",
                                mask.get_ref()
                            ),
                        );
                        continue;
                    }
                },
            };
            let filter = match Filter::new(id, mask, extended) {
                Ok(filter) => filter,
                Err(error) => {
                    self.error(
                        raw_topic.can_id.span(),
                        format!("can_id {id:#x} under mask {mask:#x}: {error}"),
                    );
                    continue;
                }
            };
            if let Some(other) = topics.iter().find(|other| other.filter == filter) {
                self.error(
                    raw_topic.can_id.span(),
                    format!(
                        "topic `{}` matches the same frames as topic `{}`",
                        name.get_ref(),
                        other.name
                    ),
                );
                continue;
            }
            let Some((rate_hz, rate_uhz)) = self.topic_rate(raw_topic) else {
                continue;
            };
            let Some((timing, rate_uhz)) = self.topic_timing(raw_topic, rate_uhz) else {
                continue;
            };
            let fd = raw_topic.fd.as_ref().is_some_and(|fd| *fd.get_ref());
            if let Some(written_fd) = raw_topic.fd.as_ref().filter(|_| fd)
                && !bus.is_some_and(Bus::is_fd)
            {
                let add = if written || bus.is_some() {
                    "add `data_bitrate = 2000000` (bit/s, the data phase's) to [bus]"
                } else {
                    "add [bus] with its `bitrate` and a `data_bitrate` (e.g. bitrate = 500000, data_bitrate = 2000000)"
                };
                self.error(
                    written_fd.span(),
                    format!(
                        "topic `{}` sends CAN FD frames (`fd = true`), but the bus is classic: {add} to make it a CAN FD bus",
                        name.get_ref()
                    ),
                );
                continue;
            }
            let Some(length) = self.topic_length(raw_topic, fd) else {
                continue;
            };
            let description = self.description(raw_topic.description.as_ref());
            topics.push(Topic {
                name: name.get_ref().clone(),
                filter,
                rate_hz,
                rate_uhz,
                timing,
                length,
                fd,
                description,
                span: topic.span(),
            });
        }
        topics
    }

    /// A topic's `rate_hz`, as written and in µHz: `Some((None, None))` without one, `None`
    /// after reporting a bad one.
    fn topic_rate(&mut self, raw: &RawTopic) -> Option<(Option<f64>, Option<u64>)> {
        let Some(rate) = &raw.rate_hz else {
            return Some((None, None));
        };
        let hz = *rate.get_ref();
        let micro = (hz * 1e6).round();
        if !(hz.is_finite() && hz > 0.0 && hz <= MAX_RATE_HZ && micro >= 1.0) {
            self.error(
                rate.span(),
                format!(
                    "rate_hz = {hz}: frames per second, positive, at most {MAX_RATE_HZ} (kept in whole µHz)"
                ),
            );
            return None;
        }
        Some((Some(hz), Some(micro as u64)))
    }

    /// A number of seconds of a topic's timing, in whole nanoseconds, at least `least` (given
    /// as it reads in the message): `None` after reporting one out of range.
    fn topic_seconds(
        &mut self,
        value: &Spanned<f64>,
        key: &str,
        least: (u64, &str),
    ) -> Option<u64> {
        let seconds = *value.get_ref();
        let ns = (seconds * 1e9).round();
        if seconds.is_finite()
            && seconds >= 0.0
            && ns >= least.0 as f64
            && seconds <= MAX_TOPIC_SECONDS
        {
            return Some(ns as u64);
        }
        self.error(
            value.span(),
            format!(
                "{key} = {seconds}: seconds, {} to {MAX_TOPIC_SECONDS} (kept in whole nanoseconds)",
                least.1
            ),
        );
        None
    }

    /// A topic's `period`, `jitter` and `deadline`, and its rate in µHz (from `period` when the
    /// file gives that instead of `rate_hz`): `Some((None, rate))` without a period or rate,
    /// `None` after reporting a mistake.
    fn topic_timing(
        &mut self,
        raw: &RawTopic,
        rate_uhz: Option<u64>,
    ) -> Option<(Option<TopicTiming>, Option<u64>)> {
        let mut ok = true;
        if let (Some(period), Some(_)) = (&raw.period, &raw.rate_hz) {
            self.error(
                period.span(),
                "a topic's rate is `period` or `rate_hz` (1/period), not both: remove one",
            );
            ok = false;
        }
        let period = match &raw.period {
            Some(period) => match self.topic_seconds(
                period,
                "period",
                (10_000, "0.00001 (100 000 frames a second)"),
            ) {
                Some(ns) => Some((ns, period.span())),
                None => {
                    ok = false;
                    None
                }
            },
            // 1/rate rounded down: a period never longer than the rate says.
            None => rate_uhz.zip(raw.rate_hz.as_ref()).map(|(uhz, rate)| {
                (
                    (1_000_000_000_000_000 / u128::from(uhz.max(1))) as u64,
                    rate.span(),
                )
            }),
        };
        let jitter = match &raw.jitter {
            Some(value) => self.topic_seconds(value, "jitter", (0, "0")).or_else(|| {
                ok = false;
                None
            }),
            None => Some(0),
        };
        let deadline = match &raw.deadline {
            Some(value) => match self.topic_seconds(value, "deadline", (1, "above 0")) {
                Some(ns) => Some(Some((ns, value.span()))),
                None => {
                    ok = false;
                    None
                }
            },
            None => Some(None),
        };
        if period.is_none() {
            for (key, value) in [("jitter", &raw.jitter), ("deadline", &raw.deadline)] {
                if let Some(value) = value {
                    self.error(
                        value.span(),
                        format!(
                            "`{key}` goes with the topic's `period` (or `rate_hz`): add `period = SECONDS`, the shortest time between two of its frames"
                        ),
                    );
                    ok = false;
                }
            }
        }
        if !ok {
            return None;
        }
        let Some((period_ns, period_span)) = period else {
            return Some((None, rate_uhz));
        };
        let (jitter_ns, deadline) = (jitter.unwrap_or(0), deadline.flatten());
        let rate_uhz = rate_uhz.or_else(|| {
            Some(
                ((1_000_000_000_000_000u128 + u128::from(period_ns) / 2) / u128::from(period_ns))
                    as u64,
            )
        });
        let timing = TopicTiming {
            period_ns,
            jitter_ns,
            deadline_ns: deadline.as_ref().map_or(period_ns, |(ns, _)| *ns),
            span: deadline.map_or(period_span, |(_, span)| span),
        };
        Some((Some(timing), rate_uhz))
    }

    /// A topic's `length`: 8 without one, `None` after reporting a bad one. A classic topic's
    /// is 0 to 8; a CAN FD topic's (`fd`) a CAN FD length, 0 to 8, 12, 16, 20, 24, 32, 48 or 64.
    fn topic_length(&mut self, raw: &RawTopic, fd: bool) -> Option<u8> {
        let Some(length) = &raw.length else {
            return Some(CLASSIC_DATA_LEN as u8);
        };
        let value = *length.get_ref();
        let valid = usize::try_from(value).ok().filter(|&l| {
            if fd {
                fd_length(l) == Some(l)
            } else {
                l <= CLASSIC_DATA_LEN
            }
        });
        if let Some(valid) = valid {
            return u8::try_from(valid).ok();
        }
        let next = usize::try_from(value).ok().and_then(fd_length);
        let message = match (fd, next) {
            (true, Some(next)) => format!(
                "length = {value} is not a CAN FD data length (0-8, 12, 16, 20, 24, 32, 48, 64): did you mean {next}?"
            ),
            (false, Some(_)) => format!(
                "length = {value}: a classic CAN frame carries 0 to {CLASSIC_DATA_LEN} bytes; for a CAN FD frame (up to {FD_DATA_LEN} bytes) add `fd = true` to the topic"
            ),
            (true, None) => format!(
                "length = {value}: the data bytes of the topic's frames, 0 to {FD_DATA_LEN} (a CAN FD frame: 0-8, 12, 16, 20, 24, 32, 48, 64)"
            ),
            (false, None) => format!(
                "length = {value}: the data bytes of the topic's frames, 0 to {CLASSIC_DATA_LEN} (a classic CAN frame; up to {FD_DATA_LEN} with `fd = true`)"
            ),
        };
        self.error(length.span(), message);
        None
    }

    /// Every field the network reads from a topic's frames (value ports, BLE eligibilities,
    /// dynamics contexts) must lie within the topic's `length`: a field past it would never
    /// read a byte. Reported at the `length` that cut it short, or, when the topic has none (8
    /// bytes: only on a CAN FD bus may a field lie past byte 8), at its name.
    pub(super) fn fields_within_lengths(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawTopic>>,
        network: &Network,
    ) {
        for (index, topic) in network.topics.iter().enumerate() {
            let Some((name, raw_topic)) =
                raw.iter().find(|(name, _)| name.get_ref() == &topic.name)
            else {
                continue;
            };
            let written = raw_topic.get_ref().length.as_ref();
            for field in network.topic_fields(index) {
                let end = u16::from(field.offset) + u16::from(field.size);
                if end <= u16::from(topic.length) {
                    continue;
                }
                let (span, said) = match written {
                    Some(length) => (length.span(), format!("`length = {}`", topic.length)),
                    None => (name.span(), "its default `length`".to_string()),
                };
                let hint = match (topic.fd, fd_length(usize::from(end))) {
                    (true, Some(next)) => format!(": set `length = {next}`"),
                    (false, Some(next)) if usize::from(end) > CLASSIC_DATA_LEN => format!(
                        ": beyond the {CLASSIC_DATA_LEN} bytes of a classic CAN frame (a CAN FD topic, `fd = true`, may carry `length = {next}`)"
                    ),
                    _ => String::new(),
                };
                self.error(
                    span,
                    format!(
                        "topic `{}` carries {} bytes ({said}), but {} reads bytes {}..{} of its frames{hint}",
                        topic.name, topic.length, field.reader, field.offset, end
                    ),
                );
            }
        }
    }

    /// The index of the topic `name` names, or `None` after reporting that it is not defined.
    pub(super) fn topic_index(
        &mut self,
        name: &Spanned<String>,
        topics: &[Topic],
    ) -> Option<usize> {
        let wanted = name.get_ref();
        let found = topics.iter().position(|topic| &topic.name == wanted);
        if found.is_none() && !self.declared.topics.contains(wanted.as_str()) {
            let known: Vec<&str> = topics.iter().map(|topic| topic.name.as_str()).collect();
            self.error(
                name.span(),
                format!(
                    "topic `{wanted}` is not defined (topics: {}){}",
                    list_or_none(&known),
                    suggest(wanted, &known)
                ),
            );
        }
        found
    }
}

#[cfg(test)]
mod tests {
    use crate::network::tests::{FIGURE_1, errors, parse};

    #[test]
    fn a_topic_length_is_0_to_8_and_bounds_the_fields_read_from_it() {
        for (length, message) in [
            (
                "9",
                "length = 9: a classic CAN frame carries 0 to 8 bytes; for a CAN FD frame (up to 64 bytes) add `fd = true` to the topic",
            ),
            (
                "-1",
                "length = -1: the data bytes of the topic's frames, 0 to 8 (a classic CAN frame; up to 64 with `fd = true`)",
            ),
            (
                "65",
                "length = 65: the data bytes of the topic's frames, 0 to 8",
            ),
        ] {
            let text = FIGURE_1.replace(
                "can_id = 0x111\n",
                &format!("can_id = 0x111\nlength = {length}\n"),
            );
            let errors = errors(&text);
            assert_eq!(errors.len(), 1, "{errors:?}");
            assert!(errors[0].contains(message), "{errors:?}");
        }
        let ports = |length: u8| {
            format!(
                "[nodes.base]\nid = 4\n[topics.range]\ncan_id = 0x1A0\nlength = {length}\n\
                 [ports.\"base.nearest\"]\ncombine = \"min\"\nvalue = {{ offset = 1, size = 2 }}\n\
                 [connections.R]\ntopic = \"range\"\nport = \"base.nearest\"\nst = 1.0\ntc = 0.3\n"
            )
        };
        let network = parse(&ports(3)).unwrap();
        let fields = network.topic_fields(0);
        assert_eq!(fields.len(), 1, "{fields:?}");
        assert_eq!(
            (fields[0].name.as_str(), fields[0].offset, fields[0].size),
            ("nearest", 1, 2)
        );
        let errors = errors(&ports(2));
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(
            errors[0].contains(
                "topic `range` carries 2 bytes (`length = 2`), but port `base.nearest` (combine = \"min\") reads bytes 1..3 of its frames"
            ),
            "{errors:?}"
        );
    }

    #[test]
    fn a_topic_has_a_period_or_a_rate_with_its_jitter_and_deadline() {
        let with =
            |keys: &str| FIGURE_1.replace("can_id = 0x111\n", &format!("can_id = 0x111\n{keys}\n"));
        let network = parse(&with("period = 0.1\njitter = 0.002\ndeadline = 0.05")).unwrap();
        let topic = &network.topics[1];
        let timing = topic.timing.as_ref().unwrap();
        assert_eq!(
            (timing.period_ns, timing.jitter_ns, timing.deadline_ns),
            (100_000_000, 2_000_000, 50_000_000)
        );
        // Its rate for HBBA: 1/period, 10 Hz.
        assert_eq!(topic.rate_uhz, Some(10_000_000));
        assert!(network.topics[0].timing.is_none());
        // rate_hz alone: the period is its inverse (rounded down), the deadline the period.
        let network = parse(&with("rate_hz = 3.0")).unwrap();
        let timing = network.topics[1].timing.clone().unwrap();
        assert_eq!(
            (timing.period_ns, timing.deadline_ns),
            (333_333_333, 333_333_333)
        );
        // A deadline beyond the period is allowed (the busy period covers it).
        assert!(parse(&with("period = 0.1\ndeadline = 0.3")).is_ok());
        for (keys, message) in [
            (
                "period = 0.1\nrate_hz = 10.0",
                "net.toml:10:10: error: a topic's rate is `period` or `rate_hz` (1/period), not both",
            ),
            (
                "period = 0.0",
                "net.toml:10:10: error: period = 0: seconds, 0.00001 (100 000 frames a second) to 3600",
            ),
            (
                "period = -1.0",
                "net.toml:10:10: error: period = -1: seconds",
            ),
            (
                "period = inf",
                "net.toml:10:10: error: period = inf: seconds",
            ),
            (
                "period = 0.1\njitter = -0.1",
                "net.toml:11:10: error: jitter = -0.1: seconds, 0 to 3600",
            ),
            (
                "period = 0.1\ndeadline = 0.0",
                "net.toml:11:12: error: deadline = 0: seconds, above 0 to 3600",
            ),
            (
                "deadline = 0.1",
                "net.toml:10:12: error: `deadline` goes with the topic's `period` (or `rate_hz`)",
            ),
            (
                "jitter = 0.1",
                "net.toml:10:10: error: `jitter` goes with the topic's `period` (or `rate_hz`)",
            ),
        ] {
            let errors = errors(&with(keys));
            assert_eq!(errors.len(), 1, "{keys}: {errors:?}");
            assert!(errors[0].starts_with(message), "{keys}: {errors:?}");
        }
        // A slip of a key: did you mean.
        let errors = errors(&with("perod = 0.1"));
        assert!(
            errors[0].contains("unknown key `perod`; did you mean `period`?"),
            "{errors:?}"
        );
    }

    #[test]
    fn the_bus_has_one_bit_rate() {
        let network = parse(&format!("[bus]\nbitrate = 250000\n{FIGURE_1}")).unwrap();
        assert_eq!(network.bus.as_ref().map(|bus| bus.bitrate), Some(250_000));
        assert!(parse(FIGURE_1).unwrap().bus.is_none());
        let found = errors(&format!("[bus]\nbitrate = 2000000\n{FIGURE_1}"));
        assert!(
            found[0].starts_with("net.toml:2:11: error: bitrate = 2000000: bit/s, 1 to 1000000"),
            "{found:?}"
        );
        let found = errors(&format!("[bus]\nbitrat = 2000\n{FIGURE_1}"));
        assert!(found[0].contains("did you mean `bitrate`?"), "{found:?}");
        // [hbba] bitrate, the older place, with [bus]: two numbers for one bus.
        let hbba = "[hbba]\nresources = { bus = 50 }\nbitrate = 500000\n";
        let found = errors(&format!("[bus]\nbitrate = 500000\n{FIGURE_1}{hbba}"));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].contains("the bus's bit rate is `[bus] bitrate` (one number for one bus)"),
            "{found:?}"
        );
        // Without [bus], it is the bus's bit rate.
        let network = parse(&format!("{FIGURE_1}{hbba}")).unwrap();
        assert_eq!(network.bus.as_ref().map(|bus| bus.bitrate), Some(500_000));
        assert_eq!(network.hbba.as_ref().unwrap().bitrate, Some(500_000));
        // [bus] bitrate gives the `bus` resource its bit rate.
        let network = parse(&format!(
            "[bus]\nbitrate = 125000\n{FIGURE_1}[hbba]\nresources = {{ bus = 50 }}\n"
        ))
        .unwrap();
        assert_eq!(network.hbba.as_ref().unwrap().bitrate, Some(125_000));
    }

    /// FIGURE_1 on a bus: `[bus]` (line 1), `bitrate` (line 2) and, with `data`, `data_bitrate`
    /// (line 3).
    fn on_bus(data: Option<&str>, text: &str) -> String {
        match data {
            Some(data) => format!("[bus]\nbitrate = 500000\ndata_bitrate = {data}\n{text}"),
            None => format!("[bus]\nbitrate = 500000\n{text}"),
        }
    }

    #[test]
    fn a_can_fd_bus_has_a_data_bit_rate_from_its_bit_rate_to_8_mbit_s() {
        let network = parse(&on_bus(Some("2000000"), FIGURE_1)).unwrap();
        let bus = network.bus.as_ref().unwrap();
        assert_eq!((bus.bitrate, bus.data_bitrate), (500_000, Some(2_000_000)));
        assert!(bus.is_fd());
        // Equal to the bit rate: CAN FD without bit-rate switching.
        let network = parse(&on_bus(Some("500000"), FIGURE_1)).unwrap();
        assert_eq!(network.bus.unwrap().data_bitrate, Some(500_000));
        assert!(!parse(&on_bus(None, FIGURE_1)).unwrap().bus.unwrap().is_fd());
        for (data, message) in [
            (
                "250000",
                "net.toml:3:16: error: data_bitrate = 250000: bit/s of the CAN FD data phase, from `bitrate` (500000) to 8000000 (the data phase is never slower than the arbitration; equal to it: CAN FD without bit-rate switching)",
            ),
            (
                "10000000",
                "net.toml:3:16: error: data_bitrate = 10000000: bit/s of the CAN FD data phase, from `bitrate` (500000) to 8000000 (the fastest data phase CAN FD controllers and transceivers commonly offer)",
            ),
            (
                "-1",
                "net.toml:3:16: error: data_bitrate = -1: bit/s of the CAN FD data phase, from `bitrate` (500000) to 8000000",
            ),
        ] {
            let found = errors(&on_bus(Some(data), FIGURE_1));
            assert_eq!(found.len(), 1, "{found:?}");
            assert!(found[0].starts_with(message), "{found:?}");
        }
        // A data rate written as the bit rate: what it is for.
        let found = errors(&format!("[bus]\nbitrate = 2000000\n{FIGURE_1}"));
        assert!(
            found[0].ends_with(
                "bitrate = 2000000: bit/s, 1 to 1000000 (the nominal rate, CAN's arbitration phase); a CAN FD bus's faster data phase is `data_bitrate` in [bus]"
            ),
            "{found:?}"
        );
        let found = errors(&format!(
            "[bus]\nbitrate = 500000\ndata_bitrat = 2000000\n{FIGURE_1}"
        ));
        assert!(
            found[0].contains("did you mean `data_bitrate`?"),
            "{found:?}"
        );
    }

    #[test]
    fn an_fd_topic_has_a_can_fd_length_on_a_can_fd_bus() {
        // object_pos: its `can_id` on line 9 of FIGURE_1, 11 on a bus, 12 on a CAN FD bus.
        let fd_topic = |keys: &str| {
            FIGURE_1.replace(
                "can_id = 0x111\n",
                &format!("can_id = 0x111\nfd = true\n{keys}"),
            )
        };
        let network = parse(&on_bus(Some("2000000"), &fd_topic("length = 64\n"))).unwrap();
        assert!(network.topics[1].fd && !network.topics[0].fd);
        assert_eq!(network.topics[1].length, 64);
        for length in [0, 5, 8, 12, 16, 20, 24, 32, 48, 64] {
            let text = on_bus(Some("2000000"), &fd_topic(&format!("length = {length}\n")));
            assert_eq!(parse(&text).unwrap().topics[1].length, length);
        }
        // Without `length`, 8 as on a classic topic.
        let network = parse(&on_bus(Some("2000000"), &fd_topic(""))).unwrap();
        assert_eq!(network.topics[1].length, 8);
        for (length, message) in [
            (
                "10",
                "net.toml:14:10: error: length = 10 is not a CAN FD data length (0-8, 12, 16, 20, 24, 32, 48, 64): did you mean 12?",
            ),
            (
                "33",
                "net.toml:14:10: error: length = 33 is not a CAN FD data length (0-8, 12, 16, 20, 24, 32, 48, 64): did you mean 48?",
            ),
            (
                "65",
                "net.toml:14:10: error: length = 65: the data bytes of the topic's frames, 0 to 64 (a CAN FD frame: 0-8, 12, 16, 20, 24, 32, 48, 64)",
            ),
        ] {
            let found = errors(&on_bus(
                Some("2000000"),
                &fd_topic(&format!("length = {length}\n")),
            ));
            assert_eq!(found.len(), 1, "{found:?}");
            assert!(found[0].starts_with(message), "{found:?}");
        }
        // Longer than 8 without `fd = true`: said how.
        let found = errors(&on_bus(
            Some("2000000"),
            &FIGURE_1.replace("can_id = 0x111\n", "can_id = 0x111\nlength = 12\n"),
        ));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with(
                "net.toml:13:10: error: length = 12: a classic CAN frame carries 0 to 8 bytes; for a CAN FD frame (up to 64 bytes) add `fd = true` to the topic"
            ),
            "{found:?}"
        );
        // `fd = true` on a classic bus, or without [bus]: at `fd`, saying what to add.
        let found = errors(&on_bus(None, &fd_topic("length = 12\n")));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with(
                "net.toml:12:6: error: topic `object_pos` sends CAN FD frames (`fd = true`), but the bus is classic: add `data_bitrate = 2000000` (bit/s, the data phase's) to [bus] to make it a CAN FD bus"
            ),
            "{found:?}"
        );
        let found = errors(&fd_topic(""));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with(
                "net.toml:10:6: error: topic `object_pos` sends CAN FD frames (`fd = true`), but the bus is classic: add [bus] with its `bitrate` and a `data_bitrate` (e.g. bitrate = 500000, data_bitrate = 2000000) to make it a CAN FD bus"
            ),
            "{found:?}"
        );
        // `fd = false` is a classic topic, on any bus.
        let text = FIGURE_1.replace("can_id = 0x111\n", "can_id = 0x111\nfd = false\n");
        assert!(!parse(&text).unwrap().topics[1].fd);
    }

    #[test]
    fn a_classic_node_is_refused_on_a_can_fd_bus() {
        let classic = FIGURE_1.replace("id = 3\n", "id = 3\nfd = false\n");
        // On a classic bus, or without [bus]: a classic node is what every node is.
        let network = parse(&on_bus(None, &classic)).unwrap();
        assert!(!network.nodes[0].fd);
        assert!(parse(&classic).is_ok());
        assert!(parse(FIGURE_1).unwrap().nodes[0].fd);
        // On a CAN FD bus: refused at its `fd`.
        let found = errors(&on_bus(Some("2000000"), &classic));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with(
                "net.toml:7:6: error: node `gaze` has a classic CAN controller (`fd = false`), but the bus is CAN FD (`data_bitrate = 2000000` in [bus]): a classic controller that is not FD-tolerant destroys every CAN FD frame with an error frame"
            ),
            "{found:?}"
        );
        let fd = FIGURE_1.replace("id = 3\n", "id = 3\nfd = true\n");
        assert!(parse(&on_bus(Some("2000000"), &fd)).unwrap().nodes[0].fd);
    }

    #[test]
    fn fields_past_byte_8_are_read_from_fd_topics_long_enough() {
        let ports = |bus: Option<&str>, topic: &str, offset: u8| {
            on_bus(
                bus,
                &format!(
                    "[nodes.base]\nid = 4\n[topics.range]\ncan_id = 0x1A0\n{topic}\
                     [ports.\"base.nearest\"]\ncombine = \"min\"\nvalue = {{ offset = {offset}, size = 2 }}\n\
                     [connections.R]\ntopic = \"range\"\nport = \"base.nearest\"\nst = 1.0\ntc = 0.3\n"
                ),
            )
        };
        let fd = Some("2000000");
        let network = parse(&ports(fd, "fd = true\nlength = 12\n", 10)).unwrap();
        let fields = network.topic_fields(0);
        assert_eq!((fields[0].offset, fields[0].size), (10, 2));
        // Past the topic's length: at its `length`, with the length that holds it.
        let found = errors(&ports(fd, "fd = true\nlength = 12\n", 11));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with(
                "net.toml:9:10: error: topic `range` carries 12 bytes (`length = 12`), but port `base.nearest` (combine = \"min\") reads bytes 11..13 of its frames: set `length = 16`"
            ),
            "{found:?}"
        );
        // A topic without `length` (8 bytes) on a CAN FD bus: at its name.
        let found = errors(&ports(fd, "", 8));
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with(
                "net.toml:6:9: error: topic `range` carries 8 bytes (its default `length`), but port `base.nearest` (combine = \"min\") reads bytes 8..10 of its frames: beyond the 8 bytes of a classic CAN frame (a CAN FD topic, `fd = true`, may carry `length = 12`)"
            ),
            "{found:?}"
        );
        // Past 64 even on a CAN FD bus; past 8 on a classic one, as always.
        let found = errors(&ports(fd, "fd = true\nlength = 64\n", 63));
        assert!(
            found[0].contains(
                "value: offset 63 + size 2 = 65 is beyond the 64 bytes of a CAN FD frame"
            ),
            "{found:?}"
        );
        let found = errors(&ports(fd, "fd = true\nlength = 64\n", 64));
        assert!(
            found[0].contains("value: offset = 64 is not a byte of a CAN FD frame (0 to 63)"),
            "{found:?}"
        );
        let found = errors(&ports(None, "", 7));
        assert!(
            found[0].contains("value: offset 7 + size 2 = 9 is beyond the 8 bytes of a frame"),
            "{found:?}"
        );
        let found = errors(&ports(None, "", 8));
        assert!(
            found[0].contains("value: offset = 8 is not a byte of a frame (0 to 7)"),
            "{found:?}"
        );
    }

    #[test]
    fn an_fd_topics_events_carry_its_length() {
        let text = on_bus(
            Some("2000000"),
            &FIGURE_1
                .replace(
                    "can_id = 0x111\n",
                    "can_id = 0x111\nfd = true\nlength = 12\n",
                )
                .replace(
                    "at = [4.0, 4.5, 5.0, 5.5, 6.0, 6.5]",
                    "at = [4.0]\ndata = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]",
                ),
        );
        let network = parse(&text).unwrap();
        assert_eq!(network.events[1].data.len(), 12);
        // More than 64: a CAN FD frame's most.
        let long = text.replace("10, 11, 12]", &format!("10, 11, 12{}]", ", 0".repeat(60)));
        let found = errors(&long);
        assert!(
            found[0].contains("data has 72 bytes; a CAN FD frame carries at most 64"),
            "{found:?}"
        );
    }
}
