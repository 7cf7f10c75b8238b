//! Value ports in virtual time: each combination, ages-out at τ, ties, both orders of simultaneous
//! frames, short frames, saturated sums, big endian, rules, capacities; and a property test
//! against a plain i64 reference of the combination.

use crate::common;

use common::{deliver, node};

use pab_core::image::{self, LoadError, Loaded};
use pab_core::table::TableError;
use pab_core::value_port::{FieldError, MAX_VALUE_CONNECTIONS, MAX_VALUE_PORTS, ValueError};
use pab_core::{
    Arbiter, Combine, Combined, Connection, Endian, Field, Filter, Frame, Gain, Instant, NodeRef,
    Stimulation, Table, ValueSpec,
};
use proptest::prelude::*;

const TAU: u32 = 300_000;

fn t(micros: u64) -> Instant {
    Instant::from_micros(micros)
}

/// A connection on standard id `id` that one frame makes active for τ (σ = 1, τr = 0).
fn sensor(id: u32, tau_us: u32) -> Connection {
    Connection {
        filter: Filter::exact(id, false).unwrap(),
        stimulation: Stimulation::new(Gain::ONE, tau_us, 0).unwrap(),
    }
}

fn field(offset: u8, size: u8, signed: bool, endian: Endian) -> Field {
    Field {
        offset,
        size,
        signed,
        endian,
    }
}

fn u16_le() -> Field {
    field(0, 2, false, Endian::Little)
}

fn spec(combine: Combine, value: Field, priority: Option<Field>) -> ValueSpec {
    ValueSpec {
        combine,
        value,
        priority,
    }
}

/// One value port of `n` sensors on ids 0x100 + k, each contributing by its own activity.
fn value_arbiter(n: u8, spec: ValueSpec) -> Arbiter {
    let connections: Vec<Connection> = (0..n).map(|k| sensor(0x100 + u32::from(k), TAU)).collect();
    let roots: Vec<NodeRef> = (0..n).map(deliver).collect();
    let mut table: Table = Table::new();
    table
        .push_value_port(&connections, &[], spec, &roots)
        .unwrap();
    Arbiter::new(table).unwrap()
}

fn frame(k: u8, data: &[u8]) -> Frame {
    Frame::with_raw_id(0x100 + u32::from(k), false, data).unwrap()
}

/// Receives `frame` at `now`; returns the outputs handed over.
fn feed(arbiter: &mut Arbiter, frame: &Frame, now: Instant) -> Vec<Combined> {
    let mut outputs = Vec::new();
    let reception = arbiter.receive_frame(frame, now, |_| {}, |output| outputs.push(*output));
    assert!(
        reception.delivered.is_empty(),
        "a value port delivers no frame as it came"
    );
    assert_eq!(reception.combined.is_empty(), outputs.is_empty());
    outputs
}

fn poll(arbiter: &mut Arbiter, now: Instant) -> Vec<Combined> {
    let mut outputs = Vec::new();
    arbiter.poll(now, |output| outputs.push(*output));
    outputs
}

fn le(value: u16) -> [u8; 2] {
    value.to_le_bytes()
}

fn summary(outputs: &[Combined]) -> Vec<(u8, i64)> {
    outputs
        .iter()
        .map(|output| (output.connection, output.value))
        .collect()
}

#[test]
fn min_follows_the_nearest_and_ages_out_exactly_at_tau() {
    let mut arbiter = value_arbiter(3, spec(Combine::Min, u16_le(), None));
    assert_eq!(arbiter.deadline(t(0)), None);
    assert_eq!(
        summary(&feed(&mut arbiter, &frame(0, &le(900)), t(0))),
        [(0, 900)]
    );
    assert_eq!(
        summary(&feed(&mut arbiter, &frame(1, &le(400)), t(10))),
        [(1, 400)]
    );
    // A larger value changes nothing: not delivered.
    assert!(feed(&mut arbiter, &frame(2, &le(700)), t(20)).is_empty());
    // The same winner, the same value: not delivered again.
    assert!(feed(&mut arbiter, &frame(1, &le(400)), t(30)).is_empty());
    assert_eq!(arbiter.output(0), Some((1, 400)));
    // Sensor 0's frame ages out first, at 0 + τ + 1 µs; it was not the minimum: nothing changes.
    assert_eq!(arbiter.deadline(t(30)), Some(t(u64::from(TAU) + 1)));
    assert!(poll(&mut arbiter, t(u64::from(TAU))).is_empty());
    assert!(poll(&mut arbiter, t(u64::from(TAU) + 1)).is_empty());
    // Sensor 1 (last frame at 30) is fresh at 30 + τ and gone one microsecond later: sensor 2
    // (700, frame at 20, gone at 20 + τ + 1) is gone too, so nothing is left at 30 + τ + 1.
    assert_eq!(
        arbiter.deadline(t(u64::from(TAU) + 1)),
        Some(t(20 + u64::from(TAU) + 1))
    );
    assert!(poll(&mut arbiter, t(20 + u64::from(TAU))).is_empty());
    assert!(poll(&mut arbiter, t(20 + u64::from(TAU) + 1)).is_empty());
    assert_eq!(arbiter.output(0), Some((1, 400)));
    assert!(poll(&mut arbiter, t(30 + u64::from(TAU))).is_empty());
    // Nothing left: the output becomes "nothing", which hands over no frame.
    assert!(poll(&mut arbiter, t(30 + u64::from(TAU) + 1)).is_empty());
    assert_eq!(arbiter.output(0), None);
    assert_eq!(arbiter.deadline(t(30 + u64::from(TAU) + 1)), None);
    // A frame after that is the output again.
    assert_eq!(
        summary(&feed(&mut arbiter, &frame(2, &le(650)), t(1_000_000))),
        [(2, 650)]
    );
}

#[test]
fn an_age_out_of_the_winner_hands_over_the_next_one_at_its_deadline() {
    let mut arbiter = value_arbiter(3, spec(Combine::Min, u16_le(), None));
    feed(&mut arbiter, &frame(0, &le(100)), t(0));
    feed(&mut arbiter, &frame(1, &le(200)), t(100_000));
    assert_eq!(arbiter.output(0), Some((0, 100)));
    let due = arbiter.deadline(t(100_000)).unwrap();
    assert_eq!(due, t(u64::from(TAU) + 1));
    let outputs = poll(&mut arbiter, due);
    assert_eq!(summary(&outputs), [(1, 200)]);
    // The frame handed over is sensor 1's own last frame.
    assert_eq!(outputs[0].frame, frame(1, &le(200)));
    assert_eq!(outputs[0].port, 0);
}

#[test]
fn max_ties_go_to_the_lower_index_whatever_the_order_of_simultaneous_frames() {
    for order in [[0u8, 1], [1, 0]] {
        let mut arbiter = value_arbiter(2, spec(Combine::Max, u16_le(), None));
        let mut outputs = Vec::new();
        for k in order {
            outputs.extend(feed(&mut arbiter, &frame(k, &le(500)), t(50)));
        }
        assert_eq!(arbiter.output(0), Some((0, 500)), "order {order:?}");
        // Delivered once per change: 0 first → one output; 1 first → 1, then 0 takes over.
        let expected: Vec<(u8, i64)> = if order == [0, 1] {
            vec![(0, 500)]
        } else {
            vec![(1, 500), (0, 500)]
        };
        assert_eq!(summary(&outputs), expected, "order {order:?}");
    }
}

#[test]
fn priority_strictly_greater_replaces_and_equal_keeps_the_incumbent() {
    // Value: bytes 0-1; priority: byte 2, unsigned.
    let priority = field(2, 1, false, Endian::Little);
    for order in [[0u8, 1], [1, 0]] {
        let mut arbiter = value_arbiter(2, spec(Combine::Priority, u16_le(), Some(priority)));
        for k in order {
            feed(&mut arbiter, &frame(k, &[k, 0, 5]), t(0));
        }
        // Equal priorities at the same instant: the first one in bus order stays.
        assert_eq!(arbiter.output(0), Some((order[0], i64::from(order[0]))));
        let incumbent = order[0];
        let other = order[1];
        // The other one again with equal priority: the incumbent stays.
        assert!(feed(&mut arbiter, &frame(other, &[9, 0, 5]), t(10)).is_empty());
        // Strictly greater: it replaces.
        let outputs = feed(&mut arbiter, &frame(other, &[9, 0, 6]), t(20));
        assert_eq!(summary(&outputs), [(other, 9)]);
        assert_eq!(outputs[0].frame, frame(other, &[9, 0, 6]));
        // The old incumbent back at the same priority as the new one: no change.
        assert!(feed(&mut arbiter, &frame(incumbent, &[1, 0, 6]), t(30)).is_empty());
        // The new incumbent changes its value: delivered.
        assert_eq!(
            summary(&feed(&mut arbiter, &frame(other, &[3, 0, 6]), t(40))),
            [(other, 3)]
        );
    }
}

#[test]
fn sum_saturates_to_the_unsigned_field_and_carries_the_newest_frame() {
    let value = field(1, 1, false, Endian::Little);
    let mut arbiter = value_arbiter(3, spec(Combine::Sum, value, None));
    let outputs = feed(&mut arbiter, &frame(0, &[0xAA, 100, 0xBB]), t(0));
    assert_eq!(summary(&outputs), [(0, 100)]);
    let outputs = feed(&mut arbiter, &frame(1, &[0x11, 100, 0x22, 0x33]), t(5));
    assert_eq!(summary(&outputs), [(1, 200)]);
    // The newest frame (sensor 1's), its field replaced by the sum, its other bytes kept.
    assert_eq!(outputs[0].frame, frame(1, &[0x11, 200, 0x22, 0x33]));
    let outputs = feed(&mut arbiter, &frame(2, &[0, 100]), t(6));
    assert_eq!(summary(&outputs), [(2, 255)]);
    assert_eq!(outputs[0].frame, frame(2, &[0, 255]));
    // Still saturated: no change, nothing delivered.
    assert!(feed(&mut arbiter, &frame(0, &[0, 90]), t(7)).is_empty());
}

#[test]
fn sum_saturates_signed_fields_both_ways_in_big_endian() {
    let value = field(0, 2, true, Endian::Big);
    let mut arbiter = value_arbiter(3, spec(Combine::Sum, value, None));
    let be = |v: i16| v.to_be_bytes();
    feed(&mut arbiter, &frame(0, &be(30_000)), t(0));
    let outputs = feed(&mut arbiter, &frame(1, &be(30_000)), t(1));
    assert_eq!(summary(&outputs), [(1, 32_767)]);
    assert_eq!(outputs[0].frame, frame(1, &be(32_767)));
    assert_eq!(
        summary(&feed(&mut arbiter, &frame(0, &be(-30_000)), t(2))),
        [(0, 0)]
    );
    let outputs = feed(&mut arbiter, &frame(1, &be(-30_000)), t(3));
    assert_eq!(summary(&outputs), [(1, -32_768)]);
    assert_eq!(outputs[0].frame, frame(1, &be(-32_768)));
    // Below the range already: a third negative value changes nothing.
    assert!(feed(&mut arbiter, &frame(2, &be(-30_000)), t(4)).is_empty());
}

#[test]
fn big_endian_fields_are_read_in_network_order() {
    let value = field(2, 4, false, Endian::Big);
    let mut arbiter = value_arbiter(2, spec(Combine::Max, value, None));
    feed(
        &mut arbiter,
        &frame(0, &[0, 0, 0x00, 0x00, 0x01, 0x00]),
        t(0),
    );
    feed(
        &mut arbiter,
        &frame(1, &[0, 0, 0x00, 0x00, 0x00, 0xFF]),
        t(0),
    );
    assert_eq!(arbiter.output(0), Some((0, 256)));
}

#[test]
fn short_frames_are_refused_and_replace_the_value_by_none() {
    let mut arbiter = value_arbiter(
        2,
        spec(Combine::Min, field(2, 2, false, Endian::Little), None),
    );
    feed(&mut arbiter, &frame(0, &[0, 0, 10, 0]), t(0));
    feed(&mut arbiter, &frame(1, &[0, 0, 20, 0]), t(0));
    assert_eq!(arbiter.output(0), Some((0, 10)));
    // Sensor 0's next frame is too short (3 bytes for a field that ends at byte 4): refused, and
    // sensor 0 no longer contributes; sensor 1 takes over.
    let mut outputs = Vec::new();
    let reception =
        arbiter.receive_frame(&frame(0, &[0, 0, 10]), t(10), |_| {}, |o| outputs.push(*o));
    assert!(reception.refused.contains(0));
    assert!(reception.fed.contains(0));
    assert_eq!(summary(&outputs), [(1, 20)]);
    // A remote-less empty frame, likewise.
    let reception = arbiter.receive_frame(&frame(1, &[]), t(20), |_| {}, |_| {});
    assert!(!reception.refused.is_empty());
    assert_eq!(arbiter.output(0), None);
}

#[test]
fn a_connection_contributes_only_while_its_rule_lets_it_through() {
    // Two sensors; sensor 1's rule is "C1 & !C0": it contributes only while sensor 0 is not
    // active. Diagram for root 1: test C0 (node 0): high → nobody, low → node 1; node 1 tests C1:
    // high → C1 delivers.
    let nodes = [
        node(0, common::at(1), NodeRef::NOBODY),
        node(1, NodeRef::NOBODY, deliver(1)),
    ];
    let roots = [deliver(0), common::at(0)];
    let mut table: Table = Table::new();
    table
        .push_value_port(
            &[sensor(0x100, TAU), sensor(0x101, TAU)],
            &nodes,
            spec(Combine::Max, u16_le(), None),
            &roots,
        )
        .unwrap();
    let mut arbiter = Arbiter::new(table).unwrap();
    feed(&mut arbiter, &frame(1, &le(50)), t(0));
    assert_eq!(arbiter.output(0), Some((1, 50)));
    // Sensor 0 becomes active with a smaller value: sensor 1 no longer contributes.
    assert_eq!(
        summary(&feed(&mut arbiter, &frame(0, &le(10)), t(100))),
        [(0, 10)]
    );
    assert!(feed(&mut arbiter, &frame(1, &le(60)), t(200)).is_empty());
    // Sensor 0's activity ends at 100 + τ: at the next microsecond sensor 1 (frame at 200, fresh
    // until 200 + τ) contributes again, handed over at that deadline.
    let due = arbiter.deadline(t(200)).unwrap();
    assert_eq!(due, t(100 + u64::from(TAU) + 1));
    assert_eq!(summary(&poll(&mut arbiter, due)), [(1, 60)]);
}

#[test]
fn ordinary_ports_beside_a_value_port_are_unchanged() {
    let mut table: Table = Table::new();
    table
        .push_port(&[sensor(0x200, TAU)], &[], deliver(0))
        .unwrap();
    table
        .push_value_port(
            &[sensor(0x100, TAU)],
            &[],
            spec(Combine::Max, u16_le(), None),
            &[deliver(0)],
        )
        .unwrap();
    let mut arbiter = Arbiter::new(table).unwrap();
    let ordinary = Frame::with_raw_id(0x200, false, &[1, 2]).unwrap();
    let reception = arbiter.receive_frame(&ordinary, t(0), |_| {}, |_| panic!("no value"));
    assert!(reception.delivered.contains(0));
    assert!(reception.combined.is_empty());
    let outputs = feed(&mut arbiter, &frame(0, &le(7)), t(1));
    assert_eq!(outputs[0].port, 1);
    assert!(arbiter.is_value_port(1) && !arbiter.is_value_port(0));
}

#[test]
fn value_capacities_and_bad_specs_are_refused_by_the_table() {
    let mut table: Table = Table::new();
    for _ in 0..MAX_VALUE_PORTS {
        table
            .push_value_port(
                &[sensor(0x100, TAU)],
                &[],
                spec(Combine::Max, u16_le(), None),
                &[deliver(0)],
            )
            .unwrap();
    }
    assert_eq!(
        table.push_value_port(
            &[sensor(0x100, TAU)],
            &[],
            spec(Combine::Max, u16_le(), None),
            &[deliver(0)],
        ),
        Err(TableError::TooManyValuePorts)
    );
    let mut table: Table = Table::new();
    let many: Vec<Connection> = (0..=MAX_VALUE_CONNECTIONS as u32)
        .map(|k| sensor(0x100 + k, TAU))
        .collect();
    let roots: Vec<NodeRef> = (0..many.len() as u8).map(deliver).collect();
    assert_eq!(
        table.push_value_port(&many, &[], spec(Combine::Sum, u16_le(), None), &roots),
        Err(TableError::TooManyValueConnections)
    );
    let one = [sensor(0x100, TAU)];
    let cases = [
        (
            spec(
                Combine::Max,
                field(
                    pab_core::frame::MAX_DATA_LEN as u8 - 1,
                    2,
                    false,
                    Endian::Little,
                ),
                None,
            ),
            vec![deliver(0)],
            TableError::Value {
                port: 0,
                error: ValueError::Value(FieldError::OutOfFrame {
                    offset: pab_core::frame::MAX_DATA_LEN as u8 - 1,
                    size: 2,
                }),
            },
        ),
        (
            spec(Combine::Priority, u16_le(), None),
            vec![deliver(0)],
            TableError::Value {
                port: 0,
                error: ValueError::PriorityMissing,
            },
        ),
        (
            spec(Combine::Max, u16_le(), None),
            vec![deliver(1)],
            TableError::Value {
                port: 0,
                error: ValueError::BadRoot { connection: 0 },
            },
        ),
        (
            spec(Combine::Max, u16_le(), None),
            vec![common::at(0)],
            TableError::Value {
                port: 0,
                error: ValueError::BadRoot { connection: 0 },
            },
        ),
        (
            spec(Combine::Max, u16_le(), None),
            vec![deliver(0), deliver(0)],
            TableError::RootCountMismatch,
        ),
    ];
    for (spec, roots, expected) in cases {
        let mut table: Table = Table::new();
        assert_eq!(
            table.push_value_port(&one, &[], spec, &roots),
            Err(expected)
        );
        assert_eq!(table, Table::new(), "unchanged on error");
    }
}

#[test]
fn value_port_images_round_trip_and_every_bit_flip_is_refused() {
    let mut table: Table = Table::new();
    table
        .push_value_port(
            &[sensor(0x100, TAU), sensor(0x101, TAU)],
            &[node(0, NodeRef::NOBODY, deliver(1))],
            spec(
                Combine::Priority,
                field(0, 2, true, Endian::Big),
                Some(field(2, 1, false, Endian::Little)),
            ),
            &[deliver(0), common::at(0)],
        )
        .unwrap();
    let mut buffer = vec![0u8; 1024];
    let len = image::encode(&table, 4, 9, &mut buffer).unwrap();
    let bytes = &buffer[..len];
    let loaded: Loaded = image::load(bytes).unwrap();
    assert_eq!(loaded.table, table);
    let view = loaded.table.port(0).unwrap();
    assert_eq!(view.roots, &[deliver(0), common::at(0)]);
    for bit in 0..len * 8 {
        let mut flipped = bytes.to_vec();
        flipped[bit / 8] ^= 1 << (bit % 8);
        let result: Result<Loaded, LoadError> = image::load(&flipped);
        assert!(result.is_err(), "bit {bit} flipped was accepted");
    }
}

// ---------------------------------------------------------------------------------------------
// The combination against a reference.

/// A step of a random run: a frame from sensor `k` with `value` (or a short frame), `gap` µs
/// after the previous step; or a poll.
#[derive(Clone, Debug)]
enum Event {
    Frame {
        k: u8,
        value: i64,
        short: bool,
        gap: u64,
    },
    Poll {
        gap: u64,
    },
    PollAtDeadline,
}

fn event_strategy(n: u8) -> impl Strategy<Value = Event> {
    prop_oneof![
        8 => (0..n, -40_000i64..70_000, prop::bool::weighted(0.1), prop_oneof![Just(0u64), 0..400_000u64])
            .prop_map(|(k, value, short, gap)| Event::Frame { k, value, short, gap }),
        1 => (0..400_000u64).prop_map(|gap| Event::Poll { gap }),
        1 => Just(Event::PollAtDeadline),
    ]
}

/// A sensor's last frame: its instant and, if it carried the fields, (value, priority).
type LastFrame = (u64, Option<(i64, i64)>);

/// The reference: each sensor's last (time, value or none, priority), fresh while within τ;
/// every sensor's rule is its own activity, which with σ = 1 and τr = 0 is "a frame within τ".
struct Reference {
    spec: ValueSpec,
    last: Vec<Option<LastFrame>>,
    newest: Option<u8>,
    output: Option<(u8, i64)>,
}

impl Reference {
    fn combine(&mut self, now: u64) -> Option<(u8, i64)> {
        let fresh: Vec<(u8, u64, i64, i64)> = self
            .last
            .iter()
            .enumerate()
            .filter_map(|(k, last)| {
                let (time, value) = (*last)?;
                let (value, priority) = value?;
                (now - time <= u64::from(TAU)).then_some((k as u8, time, value, priority))
            })
            .collect();
        match self.spec.combine {
            Combine::Max => fresh
                .iter()
                .fold(None, |best: Option<(u8, i64)>, &(k, _, v, _)| match best {
                    Some((_, b)) if v <= b => best,
                    _ => Some((k, v)),
                }),
            Combine::Min => fresh
                .iter()
                .fold(None, |best: Option<(u8, i64)>, &(k, _, v, _)| match best {
                    Some((_, b)) if v >= b => best,
                    _ => Some((k, v)),
                }),
            Combine::Sum => {
                let (low, high) = self.spec.value.range();
                let total: i64 = fresh.iter().map(|&(_, _, v, _)| v).sum();
                let newest = match self.newest {
                    Some(n) if fresh.iter().any(|&(k, ..)| k == n) => Some(n),
                    _ => fresh
                        .iter()
                        .fold(
                            None,
                            |best: Option<(u8, u64)>, &(k, time, _, _)| match best {
                                Some((_, b)) if time <= b => best,
                                _ => Some((k, time)),
                            },
                        )
                        .map(|(k, _)| k),
                };
                newest.map(|k| (k, total.clamp(low, high)))
            }
            Combine::Priority => {
                let mut top: Option<(u8, i64, i64)> = self.output.and_then(|(incumbent, _)| {
                    fresh
                        .iter()
                        .find(|&&(k, ..)| k == incumbent)
                        .map(|&(k, _, v, p)| (k, p, v))
                });
                for &(k, _, v, p) in &fresh {
                    if top.is_none_or(|(_, best, _)| p > best) {
                        top = Some((k, p, v));
                    }
                }
                top.map(|(k, _, v)| (k, v))
            }
        }
    }
}

fn encode_field(field: &Field, value: i64) -> [u8; pab_core::frame::MAX_DATA_LEN] {
    let mut data = [0u8; pab_core::frame::MAX_DATA_LEN];
    field.write(&mut data, value);
    data
}

fn run_against_reference(spec: ValueSpec, n: u8, events: &[Event]) {
    let mut arbiter = value_arbiter(n, spec);
    let mut reference = Reference {
        spec,
        last: vec![None; usize::from(n)],
        newest: None,
        output: None,
    };
    let mut now = 0u64;
    for event in events {
        let mut outputs = Vec::new();
        match *event {
            Event::Frame {
                k,
                value,
                short,
                gap,
            } => {
                now += gap;
                let value = spec.value.saturate(value);
                let mut data = encode_field(&spec.value, value);
                let priority = (value.rem_euclid(4)) + 1;
                if let Some(field) = spec.priority {
                    field.write(&mut data, priority);
                }
                // Short: the payload ends before the field's last byte.
                let len = if short {
                    usize::from(spec.value.offset + spec.value.size - 1)
                } else {
                    8
                };
                let frame = frame(k, &data[..len]);
                // First what aged out before the frame (a runner polls at the deadline).
                if arbiter
                    .deadline(t(now))
                    .is_some_and(|due| due.as_micros() <= now)
                {
                    let mut before = Vec::new();
                    arbiter.poll(t(now), |o| before.push(*o));
                    let expected = reference.combine(now);
                    assert_eq!(
                        arbiter.output(0),
                        expected,
                        "poll before the frame at {now}"
                    );
                    reference.output = expected;
                }
                arbiter.receive_frame(&frame, t(now), |_| {}, |o| outputs.push(*o));
                reference.last[usize::from(k)] = Some((now, (!short).then_some((value, priority))));
                if !short {
                    reference.newest = Some(k);
                }
            }
            Event::Poll { gap } => {
                now += gap;
                arbiter.poll(t(now), |o| outputs.push(*o));
            }
            Event::PollAtDeadline => {
                let Some(due) = arbiter.deadline(t(now)) else {
                    continue;
                };
                now = now.max(due.as_micros());
                arbiter.poll(t(now), |o| outputs.push(*o));
            }
        }
        let expected = reference.combine(now);
        assert_eq!(arbiter.output(0), expected, "at {now} after {event:?}");
        // Handed over exactly when the output changed to something.
        let changed = match (reference.output, expected) {
            (Some(old), Some(new)) if spec.combine == Combine::Sum => old.1 != new.1,
            (old, new) => old != new,
        };
        match (changed, expected) {
            (true, Some(output)) => assert_eq!(summary(&outputs), [output], "at {now}"),
            _ => assert!(outputs.is_empty(), "at {now}: {outputs:?}"),
        }
        reference.output = expected;
    }
}

fn spec_strategy() -> impl Strategy<Value = ValueSpec> {
    let field = (
        0u8..=4,
        prop_oneof![Just(1u8), Just(2), Just(4)],
        any::<bool>(),
        any::<bool>(),
    )
        .prop_map(|(offset, size, signed, big)| Field {
            offset,
            size,
            signed,
            endian: if big { Endian::Big } else { Endian::Little },
        });
    (
        prop_oneof![
            Just(Combine::Max),
            Just(Combine::Min),
            Just(Combine::Sum),
            Just(Combine::Priority)
        ],
        field,
    )
        .prop_map(|(combine, value)| ValueSpec {
            combine,
            value,
            // The priority in the last byte, which no value field reaches (offset ≤ 4, size ≤ 4
            // ends at byte 7 at most: byte 7 is shared only by offset 4 size 4, kept apart).
            priority: (combine == Combine::Priority).then_some(Field {
                offset: 7,
                size: 1,
                signed: false,
                endian: Endian::Little,
            }),
        })
        .prop_filter("fields apart", |spec| {
            spec.priority.is_none() || spec.value.offset + spec.value.size <= 7
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn the_combination_matches_the_reference(
        spec in spec_strategy(),
        n in 1u8..=5,
        events in prop::collection::vec(event_strategy(5), 1..60),
    ) {
        let events: Vec<Event> = events
            .into_iter()
            .map(|event| match event {
                Event::Frame { k, value, short, gap } => Event::Frame { k: k % n, value, short, gap },
                other => other,
            })
            .collect();
        run_against_reference(spec, n, &events);
    }
}
