//! HBBA's message filters in the arbiter: the semantics of DESIGN.md ("HBBA: decisions") exactly
//! (φ = 3 on a 30 Hz topic delivers frames 0, 3, 6, ...; the first frame after each change
//! passes; φ = 0 leaves S unchanged; filtered connections start closed), on fan-out and value
//! ports, across a table swap, through the image format; and a property test against a model
//! of the counters on random frames and commands.

use crate::common;

use common::{deliver, priority_chain};

use pab_core::hbba::filters::{CommandError, FilterCounts, MessageFilters};
use pab_core::image;
use pab_core::{
    Arbiter, Combine, Connection, Endian, Field, Filter, Frame, Gain, Id, Instant, NodeRef,
    Stimulation, Table, ValueSpec,
};
use proptest::prelude::*;

/// τ of every connection: 10 ms, shorter than the 33 ms between frames of a 30 Hz topic, so
/// each frame that passes makes its connection active and delivered, and each dropped one finds
/// it inactive.
const TAU: u32 = 10_000;
/// A 30 Hz topic's period, µs.
const PERIOD: u64 = 33_333;

fn t(micros: u64) -> Instant {
    Instant::from_micros(micros)
}

fn sensor(id: u32) -> Connection {
    Connection {
        filter: Filter::exact(id, false).unwrap(),
        stimulation: Stimulation::new(Gain::ONE, TAU, 0).unwrap(),
    }
}

fn id(raw: u16) -> Id {
    Id::Standard(embedded_can::StandardId::new(raw).unwrap())
}

fn filters(connections: &[u16], profiles: &[&[u8]]) -> MessageFilters {
    let mut f = MessageFilters::default();
    f.connections.extend_from_slice(connections).unwrap();
    for profile in profiles {
        let mut p = heapless::Vec::new();
        p.extend_from_slice(profile).unwrap();
        f.profiles.push(p).unwrap();
    }
    f
}

/// `ports` one-connection ports on ids 0x100 + k; the connections of `filtered` have filters.
fn arbiter(ports: u16, filtered: &[u16], profiles: &[&[u8]]) -> Arbiter {
    let mut table: Table = Table::new();
    for k in 0..ports {
        table
            .push_port(&[sensor(0x100 + u32::from(k))], &[], deliver(0))
            .unwrap();
    }
    table.set_filters(filters(filtered, profiles)).unwrap();
    Arbiter::new(table).unwrap()
}

/// The frames of `count` at the topic's rate that port `port` delivers, by their number.
fn delivered(arbiter: &mut Arbiter, raw: u16, port: u8, first: u64, count: u64) -> Vec<u64> {
    (0..count)
        .filter(|&k| {
            let reception = arbiter.receive(&id(raw), t((first + k) * PERIOD), |_| {});
            reception.delivered.contains(port)
        })
        .collect()
}

#[test]
fn phi_three_on_a_30_hz_topic_delivers_frames_0_3_6() {
    let mut a = arbiter(1, &[0], &[&[3]]);
    a.set_filter_profile(1).unwrap();
    assert_eq!(delivered(&mut a, 0x100, 0, 0, 10), [0, 3, 6, 9]);
    a.set_filter(0, 0, 1).unwrap();
    assert_eq!(delivered(&mut a, 0x100, 0, 10, 4), [0, 1, 2, 3]);
}

#[test]
fn the_first_frame_after_each_change_passes() {
    let mut a = arbiter(1, &[0], &[]);
    a.set_filter(0, 0, 4).unwrap();
    assert_eq!(delivered(&mut a, 0x100, 0, 0, 6), [0, 4]);
    // Mid-count: the change restarts it.
    a.set_filter(0, 0, 2).unwrap();
    assert_eq!(delivered(&mut a, 0x100, 0, 6, 5), [0, 2, 4]);
    // Setting the same φ again changes nothing: the count goes on (frame 5 of φ = 2 was the
    // third since the change, so the next to pass is the one after).
    a.set_filter(0, 0, 2).unwrap();
    assert_eq!(delivered(&mut a, 0x100, 0, 11, 3), [1]);
}

#[test]
fn filtered_connections_start_closed_and_phi_zero_leaves_s_unchanged() {
    let mut a = arbiter(2, &[1], &[&[1]]);
    assert_eq!(
        a.filter_counts(),
        FilterCounts {
            filtered: 1,
            closed: 1,
            throttled: 0
        }
    );
    assert_eq!(a.filter_profile(), Some(0));
    // The unfiltered connection is fed as always; the filtered one is not, and its port is not
    // even told of the frame.
    assert!(a.receive(&id(0x100), t(0), |_| {}).delivered.contains(0));
    let before = a.level(1, 0, t(5)).unwrap();
    let mut verdicts = 0;
    let reception = a.receive(&id(0x101), t(5), |_| verdicts += 1);
    assert!(reception.fed.is_empty() && verdicts == 0);
    assert_eq!(a.level(1, 0, t(5)).unwrap(), before);
    // Opened by the profile: the next frame passes and stimulates.
    a.set_filter_profile(1).unwrap();
    assert!(a.receive(&id(0x101), t(6), |_| {}).delivered.contains(1));
    assert!(a.level(1, 0, t(6)).unwrap() > before);
    // Closed again: S stays where it was, decaying only with time.
    a.set_filter(1, 0, 0).unwrap();
    let level = a.level(1, 0, t(7)).unwrap();
    a.receive(&id(0x101), t(7), |_| {});
    assert_eq!(a.level(1, 0, t(7)).unwrap(), level);
}

#[test]
fn commands_are_refused_whole() {
    let mut a = arbiter(2, &[1], &[&[2]]);
    assert_eq!(a.set_filter_profile(2), Err(CommandError::NoSuchProfile));
    assert_eq!(a.set_filter(0, 0, 1), Err(CommandError::NotFiltered));
    assert_eq!(a.set_filter(1, 1, 1), Err(CommandError::NotFiltered));
    assert_eq!(a.set_filter(7, 0, 1), Err(CommandError::NotFiltered));
    assert_eq!(a.filter_phi(1, 0), Some(0));
    assert_eq!(a.filter_phi(0, 0), None);
    let mut plain = arbiter(1, &[], &[]);
    assert_eq!(plain.set_filter_profile(0), Err(CommandError::NoFilters));
    assert_eq!(plain.set_filter(0, 0, 1), Err(CommandError::NoFilters));
}

#[test]
fn a_frame_that_fans_out_is_dropped_only_where_filtered() {
    // One id, three ports: the middle one filtered.
    let mut table: Table = Table::new();
    for _ in 0..3 {
        table.push_port(&[sensor(0x200)], &[], deliver(0)).unwrap();
    }
    table.set_filters(filters(&[1], &[])).unwrap();
    let mut a = Arbiter::new(table).unwrap();
    let reception = a.receive(&id(0x200), t(0), |_| {});
    assert!(reception.fed.contains(0) && !reception.fed.contains(1) && reception.fed.contains(2));
    // The first port filtered instead, and two connections of one port on the id.
    let mut table: Table = Table::new();
    table.push_port(&[sensor(0x200)], &[], deliver(0)).unwrap();
    table
        .push_port(
            &[sensor(0x200), sensor(0x200)],
            &priority_chain(2),
            NodeRef::node(0).unwrap(),
        )
        .unwrap();
    table.set_filters(filters(&[0, 2], &[&[0, 1]])).unwrap();
    let mut a = Arbiter::new(table).unwrap();
    let mut fed = Vec::new();
    let reception = a.receive(&id(0x200), t(0), |v| fed.push((v.port, v.fed)));
    assert!(!reception.fed.contains(0) && reception.fed.contains(1));
    assert_eq!(fed.len(), 1);
    // Port 1: only connection 0 fed (connection 1 closed).
    assert_eq!(fed[0].1.iter().collect::<Vec<_>>(), [0]);
    a.set_filter_profile(1).unwrap();
    let reception = a.receive(&id(0x200), t(1), |_| {});
    assert!(!reception.fed.contains(0) && reception.fed.contains(1));
}

#[test]
fn a_value_port_takes_no_value_from_a_dropped_frame() {
    let connections = [sensor(0x300), sensor(0x301)];
    let spec = ValueSpec {
        combine: Combine::Max,
        value: Field {
            offset: 0,
            size: 1,
            signed: false,
            endian: Endian::Little,
        },
        priority: None,
    };
    let mut table: Table = Table::new();
    table
        .push_value_port(&connections, &[], spec, &[deliver(0), deliver(1)])
        .unwrap();
    table.set_filters(filters(&[1], &[])).unwrap();
    let mut a = Arbiter::new(table).unwrap();
    let mut outputs = Vec::new();
    a.receive_frame(
        &Frame::with_raw_id(0x300, false, &[5]).unwrap(),
        t(0),
        |_| {},
        |o| outputs.push((o.connection, o.value)),
    );
    // The larger value comes through the closed connection: not taken.
    a.receive_frame(
        &Frame::with_raw_id(0x301, false, &[9]).unwrap(),
        t(1),
        |_| {},
        |o| outputs.push((o.connection, o.value)),
    );
    assert_eq!(outputs, [(0, 5)]);
    a.set_filter(0, 1, 1).unwrap();
    a.receive_frame(
        &Frame::with_raw_id(0x301, false, &[9]).unwrap(),
        t(2),
        |_| {},
        |o| outputs.push((o.connection, o.value)),
    );
    assert_eq!(outputs, [(0, 5), (1, 9)]);
}

#[test]
fn a_table_swap_keeps_the_filters_of_unchanged_connections() {
    let mut old = arbiter(3, &[1, 2], &[&[1, 3]]);
    old.set_filter_profile(1).unwrap();
    // Same filters part: the profile holds.
    let mut same = arbiter(3, &[1, 2], &[&[1, 3]]);
    same.carry_over(&old);
    assert_eq!(same.filter_profile(), Some(1));
    assert_eq!(
        (same.filter_phi(1, 0), same.filter_phi(2, 0)),
        (Some(1), Some(3))
    );
    // Connection 0 filtered too now: it starts closed, the others keep their φ.
    let mut more = arbiter(3, &[0, 1, 2], &[]);
    more.carry_over(&old);
    assert_eq!(
        (
            more.filter_phi(0, 0),
            more.filter_phi(1, 0),
            more.filter_phi(2, 0)
        ),
        (Some(0), Some(1), Some(3))
    );
    assert_eq!(more.filter_profile(), None);
}

#[test]
fn filters_travel_in_the_image() {
    let mut table: Table = Table::new();
    for k in 0..3 {
        table
            .push_port(&[sensor(0x100 + k)], &[], deliver(0))
            .unwrap();
    }
    table
        .set_filters(filters(&[0, 2], &[&[1, 0], &[2, 5]]))
        .unwrap();
    let mut buffer = [0u8; 1024];
    let len = image::encode(&table, 3, 7, &mut buffer).unwrap();
    let loaded = image::load::<4, 64, 256>(&buffer[..len]).unwrap();
    assert_eq!(loaded.table.filters(), table.filters());
    // A filtered connection beyond the table is refused by the builder as by the loader.
    let mut small: Table = Table::new();
    small.push_port(&[sensor(0x100)], &[], deliver(0)).unwrap();
    assert!(small.set_filters(filters(&[1], &[])).is_err());
}

/// One frame or command of a random history.
#[derive(Clone, Debug)]
enum Event {
    Frame(u8),
    Set(u8, u8),
    Profile(u8),
}

fn event() -> impl Strategy<Value = Event> {
    prop_oneof![
        6 => (0u8..4).prop_map(Event::Frame),
        2 => (0u8..4, 0u8..6).prop_map(|(c, phi)| Event::Set(c, phi)),
        1 => (0u8..4).prop_map(Event::Profile),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 500, failure_persistence: None, ..ProptestConfig::default() })]

    /// Four one-connection ports, 1 and 3 filtered, two stored profiles: every frame is fed
    /// exactly when a model of the counters says it passes (φ ≠ 0 and a multiple of φ frames
    /// since the last change), and every command is refused exactly when it should be.
    #[test]
    fn frames_pass_as_the_model_says(events in prop::collection::vec(event(), 1..200)) {
        let profiles: [[u8; 2]; 2] = [[1, 3], [2, 0]];
        let mut a = arbiter(4, &[1, 3], &[&profiles[0], &profiles[1]]);
        // Model: per port, Some((φ, frames since the change)) if filtered.
        let mut model: [Option<(u8, u32)>; 4] = [None, Some((0, 0)), None, Some((0, 0))];
        for (k, event) in events.into_iter().enumerate() {
            let now = t(k as u64 * 100_000);
            match event {
                Event::Frame(port) => {
                    let reception = a.receive(&id(0x100 + u16::from(port)), now, |_| {});
                    let expected = match &mut model[usize::from(port)] {
                        None => true,
                        Some((phi, since)) => {
                            let passes = *phi != 0 && *since % u32::from(*phi) == 0;
                            *since += 1;
                            passes
                        }
                    };
                    prop_assert_eq!(reception.fed.contains(port), expected);
                }
                Event::Set(port, phi) => {
                    let result = a.set_filter(port, 0, phi);
                    match &mut model[usize::from(port)] {
                        None => prop_assert_eq!(result, Err(CommandError::NotFiltered)),
                        Some(state) => {
                            prop_assert_eq!(result, Ok(()));
                            if state.0 != phi {
                                *state = (phi, 0);
                            }
                        }
                    }
                }
                Event::Profile(profile) => {
                    let result = a.set_filter_profile(profile);
                    if profile > 2 {
                        prop_assert_eq!(result, Err(CommandError::NoSuchProfile));
                        continue;
                    }
                    prop_assert_eq!(result, Ok(()));
                    for (position, port) in [1usize, 3].into_iter().enumerate() {
                        let phi = match profile {
                            0 => 0,
                            p => profiles[usize::from(p) - 1][position],
                        };
                        let state = model[port].as_mut().unwrap();
                        if state.0 != phi {
                            *state = (phi, 0);
                        }
                    }
                    prop_assert_eq!(a.filter_profile(), Some(profile));
                }
            }
            for port in [1u8, 3] {
                prop_assert_eq!(a.filter_phi(port, 0), model[usize::from(port)].map(|s| s.0));
            }
        }
    }
}
