//! The arbiter end to end, on hand-built tables: the paper's Figure 1 scenario, fan-out,
//! overlapping filters, rest times, frames that match nothing, and the read-only accessors.

use crate::common;

use common::{at, deliver, node, priority_chain};

use common::receive;
use embedded_can::{ExtendedId, StandardId};
use pab_core::{
    Arbiter, Connection, ConnectionSet, Filter, Id, Instant, NodeRef, Reception, Stimulation, Table,
};

fn stimulation(sigma: f64, tau: f64, rest: f64) -> Stimulation {
    Stimulation::from_seconds(sigma, tau, rest).expect("valid parameters")
}

fn connection(filter: Filter, stimulation: Stimulation) -> Connection {
    Connection {
        filter,
        stimulation,
    }
}

fn exact(id: u32) -> Filter {
    Filter::exact(id, false).expect("valid filter")
}

fn std_id(raw: u16) -> Id {
    Id::Standard(StandardId::new(raw).expect("11-bit id"))
}

fn micros(t: u64) -> Instant {
    Instant::from_micros(t)
}

fn set(indices: &[u8]) -> ConnectionSet {
    indices
        .iter()
        .fold(ConnectionSet::EMPTY, |set, &index| set.with(index))
}

// ---------------------------------------------------------------------------------------------
// Figure 1 of the paper.

const FACE: u16 = 0x110;
const OBJECT: u16 = 0x111;

/// C0 (face, 0x110) delivers iff x0 ∧ ¬x1; C1 (object, 0x111) iff x1. σ = 0.2, τ = 3 s.
fn figure1() -> Arbiter {
    let s = stimulation(0.2, 3.0, 0.0);
    let mut table = Table::new();
    table
        .push_port(
            &[
                connection(exact(FACE.into()), s),
                connection(exact(OBJECT.into()), s),
            ],
            &[
                node(0, at(1), at(2)),
                node(1, NodeRef::NOBODY, deliver(1)),
                node(1, deliver(0), deliver(1)),
            ],
            at(0),
        )
        .expect("valid port");
    Arbiter::new(table).expect("valid table")
}

#[test]
fn figure1_the_object_takes_the_port_and_returns_it() {
    let mut arbiter = figure1();
    // Face frames at 10 Hz from 0 to 12 s; object frames at 4.0, 4.5, ..., 6.5 s. At equal times
    // the face frame comes first.
    let mut events: Vec<(u64, u16)> = (0..=120).map(|k| (k * 100_000, FACE)).collect();
    events.extend((0..6).map(|k| (4_000_000 + k * 500_000, OBJECT)));
    events.sort_by_key(|&(t, id)| (t, id));
    assert_eq!(events.len(), 127);

    let mut face = Vec::new();
    let mut object = Vec::new();
    let mut object_levels = Vec::new();
    for &(t, id) in &events {
        let (reception, verdicts) = receive(&mut arbiter, std_id(id), micros(t));
        assert_eq!(verdicts.len(), 1, "one port fed at {t}");
        let verdict = verdicts[0];
        assert_eq!(verdict.port, 0);
        assert_eq!(verdict.resting, ConnectionSet::EMPTY);
        let own = if id == FACE { 0 } else { 1 };
        assert_eq!(verdict.fed, set(&[own]));
        assert_eq!(reception.delivered.contains(0), verdict.delivered.is_some());
        if id == FACE {
            face.push((t, verdict));
        } else {
            object.push((t, verdict));
            object_levels.push(arbiter.level(0, 1, micros(t)).unwrap().to_f64());
        }
    }

    for &(t, verdict) in &face {
        let expected = match t {
            // Five frames bring the face to 0.9976: active on the sixth, at 0.5 s.
            0..500_000 => None,
            // Delivered while the object is inactive; at 6.5 s the face frame comes before the
            // object's sixth frame.
            500_000..=6_500_000 => Some(0),
            // The object is active from 6.5 s until τ after its last frame: 9.5 s included.
            6_500_001..=9_500_000 => None,
            // Then the face has the port again.
            _ => Some(0),
        };
        assert_eq!(
            verdict.delivered, expected,
            "face frame at {t} µs: {verdict:?}"
        );
        let active = match t {
            0..500_000 => set(&[]),
            500_000..=6_500_000 => set(&[0]),
            6_500_001..=9_500_000 => set(&[0, 1]),
            _ => set(&[0]),
        };
        assert_eq!(verdict.active, active, "face frame at {t} µs");
    }
    for &(t, verdict) in &object {
        // Levels 0.2, 0.398, 0.595, 0.790, 0.983: only the sixth frame (6.5 s) activates it, and
        // that frame is delivered; before it the face was selected and the object's frames were
        // discarded.
        if t < 6_500_000 {
            assert_eq!(verdict.delivered, None, "object frame at {t} µs");
            assert_eq!(verdict.selected, Some(0));
            assert_eq!(verdict.active, set(&[0]));
        } else {
            assert_eq!(verdict.delivered, Some(1), "object frame at {t} µs");
            assert_eq!(verdict.active, set(&[0, 1]));
        }
    }
    let expected = [0.2, 0.3982, 0.5948, 0.7895, 0.9826, 1.0];
    for (got, want) in object_levels.iter().zip(expected) {
        assert!((got - want).abs() < 1e-4, "{object_levels:?}");
    }

    // Read-only afterwards: the face's last frame was at 12 s, so it keeps the port until 15 s.
    assert_eq!(arbiter.selected(0, micros(15_000_000)), Some(0));
    assert_eq!(arbiter.activity(0, micros(15_000_000)), set(&[0]));
    assert_eq!(arbiter.selected(0, micros(15_000_001)), None);
    assert_eq!(
        arbiter.activity(0, micros(15_000_001)),
        ConnectionSet::EMPTY
    );
    assert_eq!(
        arbiter.level(0, 0, micros(15_000_001)).unwrap().to_f64(),
        0.0
    );
    // Reading changed nothing.
    assert_eq!(arbiter.selected(0, micros(12_000_000)), Some(0));
}

#[test]
fn figure1_selected_tracks_the_phases_between_frames() {
    let mut arbiter = figure1();
    let mut events: Vec<(u64, u16)> = (0..=120).map(|k| (k * 100_000, FACE)).collect();
    events.extend((0..6).map(|k| (4_000_000 + k * 500_000, OBJECT)));
    events.sort_by_key(|&(t, id)| (t, id));
    let mut phases = Vec::new();
    for window in events.windows(2) {
        let (t, id) = window[0];
        receive(&mut arbiter, std_id(id), micros(t));
        // Just before the next frame.
        let probe = window[1].0.saturating_sub(1).max(t);
        let selected = arbiter.selected(0, micros(probe));
        if phases.last().map(|&(_, s)| s) != Some(selected) {
            phases.push((probe, selected));
        }
    }
    // Nobody, then the face, then the object, then the face again: exactly four phases.
    let kinds: Vec<Option<u8>> = phases.iter().map(|&(_, s)| s).collect();
    assert_eq!(kinds, [None, Some(0), Some(1), Some(0)], "{phases:?}");
    assert_eq!(phases[1].0, 599_999);
    assert_eq!(phases[2].0, 6_599_999);
    assert_eq!(phases[3].0, 9_599_999);
}

// ---------------------------------------------------------------------------------------------
// Fan-out and overlapping filters.

#[test]
fn one_frame_feeds_and_is_delivered_on_several_ports() {
    let s = stimulation(1.0, 1.0, 0.0);
    let mut table = Table::new();
    // Port 0: 0x200 alone.
    table
        .push_port(&[connection(exact(0x200), s)], &[], deliver(0))
        .unwrap();
    // Port 1: 0x201 has priority over 0x200..0x2FF.
    table
        .push_port(
            &[
                connection(exact(0x201), s),
                connection(Filter::new(0x200, 0x700, false).unwrap(), s),
            ],
            &priority_chain(2),
            at(0),
        )
        .unwrap();
    // Port 2: another topic.
    table
        .push_port(&[connection(exact(0x300), s)], &[], deliver(0))
        .unwrap();
    let mut arbiter = Arbiter::new(table).unwrap();

    let (reception, verdicts) = receive(&mut arbiter, std_id(0x200), micros(0));
    assert_eq!(
        (reception.fed.bits(), reception.delivered.bits()),
        (0b011, 0b011)
    );
    assert_eq!(verdicts.len(), 2);
    assert_eq!((verdicts[0].port, verdicts[0].delivered), (0, Some(0)));
    assert_eq!((verdicts[1].port, verdicts[1].delivered), (1, Some(1)));
    assert_eq!(verdicts[1].fed, set(&[1]));

    // 0x250 only feeds port 1's masked connection.
    let (reception, verdicts) = receive(&mut arbiter, std_id(0x250), micros(10));
    assert_eq!(
        (reception.fed.bits(), reception.delivered.bits()),
        (0b010, 0b010)
    );
    assert_eq!(verdicts.len(), 1);

    // Once 0x201 is active, 0x200 is still delivered on port 0 but no longer on port 1.
    let (reception, _) = receive(&mut arbiter, std_id(0x201), micros(20));
    assert_eq!(
        (reception.fed.bits(), reception.delivered.bits()),
        (0b010, 0b010)
    );
    let (reception, verdicts) = receive(&mut arbiter, std_id(0x200), micros(30));
    assert_eq!(
        (reception.fed.bits(), reception.delivered.bits()),
        (0b011, 0b001)
    );
    assert_eq!(verdicts[1].selected, Some(0));
    assert_eq!(verdicts[1].delivered, None);
    assert_eq!(verdicts[1].active, set(&[0, 1]));

    let (reception, verdicts) = receive(&mut arbiter, std_id(0x300), micros(40));
    assert_eq!(
        (reception.fed.bits(), reception.delivered.bits()),
        (0b100, 0b100)
    );
    assert_eq!(verdicts[0].port, 2);
}

#[test]
fn overlapping_filters_deliver_a_frame_at_most_once_per_port() {
    let s = stimulation(1.0, 1.0, 0.0);
    for (nodes, root, winner) in [
        // C0 has priority.
        (priority_chain(2), at(0), 0),
        // C1 has priority: C1 iff x1, C0 iff x0 ∧ ¬x1.
        (
            vec![
                node(0, at(1), at(2)),
                node(1, NodeRef::NOBODY, deliver(1)),
                node(1, deliver(0), deliver(1)),
            ],
            at(0),
            1,
        ),
    ] {
        let mut table = Table::new();
        table
            .push_port(
                &[
                    connection(exact(0x300), s),
                    connection(Filter::new(0x300, 0x7F0, false).unwrap(), s),
                ],
                &nodes,
                root,
            )
            .unwrap();
        let mut arbiter = Arbiter::new(table).unwrap();
        let mut calls = 0;
        let reception = arbiter.receive(&std_id(0x300), micros(0), |verdict| {
            calls += 1;
            assert_eq!(verdict.fed, set(&[0, 1]));
            assert_eq!(verdict.active, set(&[0, 1]));
            assert_eq!(verdict.delivered, Some(winner));
        });
        assert_eq!(calls, 1);
        assert_eq!((reception.fed.bits(), reception.delivered.bits()), (1, 1));
        // Both integrators were stimulated.
        assert_eq!(arbiter.level(0, 0, micros(0)).unwrap().to_f64(), 1.0);
        assert_eq!(arbiter.level(0, 1, micros(0)).unwrap().to_f64(), 1.0);
        // 0x301 feeds only C1: delivered iff C1 is the winner.
        let (reception, verdicts) = receive(&mut arbiter, std_id(0x301), micros(1));
        assert_eq!(verdicts.len(), 1);
        assert_eq!(verdicts[0].fed, set(&[1]));
        assert_eq!(reception.delivered.contains(0), winner == 1);
    }
}

// ---------------------------------------------------------------------------------------------
// Rest times, virtual connections.

#[test]
fn resting_connections_ignore_frames_and_are_reported() {
    let mut table = Table::new();
    table
        .push_port(
            &[connection(exact(0x500), stimulation(1.0, 1.0, 2.0))],
            &[],
            deliver(0),
        )
        .unwrap();
    let mut arbiter = Arbiter::new(table).unwrap();
    assert!(!arbiter.is_resting(0, 0, micros(0)), "never stimulated");
    let (_, v) = receive(&mut arbiter, std_id(0x500), micros(0));
    assert_eq!((v[0].delivered, v[0].resting), (Some(0), set(&[])));
    assert!(
        !arbiter.is_resting(0, 0, micros(1_000_000)),
        "still active at τ"
    );
    // The activity ends after 1 s; frames up to 3 s are ignored. The port's decision names C0
    // whatever the mask, yet a resting C0 is not selected: its frames do not get through.
    for t in [1_000_001, 2_000_000, 3_000_000] {
        let (reception, v) = receive(&mut arbiter, std_id(0x500), micros(t));
        assert_eq!(v[0].resting, set(&[0]), "{t}");
        assert_eq!(v[0].active, set(&[]), "{t}");
        assert_eq!((v[0].selected, v[0].delivered), (None, None), "{t}");
        assert_eq!(arbiter.selected(0, micros(t)), None);
        assert!(reception.fed.contains(0) && reception.delivered.is_empty());
        assert_eq!(arbiter.level(0, 0, micros(t)).unwrap().to_f64(), 0.0);
        // The read-only query agrees with the verdicts.
        assert!(arbiter.is_resting(0, 0, micros(t)), "{t}");
    }
    assert!(!arbiter.is_resting(0, 0, micros(3_000_001)));
    assert!(
        !arbiter.is_resting(0, 1, micros(2_000_000)),
        "no such connection"
    );
    assert!(!arbiter.is_resting(1, 0, micros(2_000_000)), "no such port");
    let (_, v) = receive(&mut arbiter, std_id(0x500), micros(3_000_001));
    assert_eq!((v[0].delivered, v[0].resting), (Some(0), set(&[])));
}

#[test]
fn a_virtual_connection_inhibits_but_never_delivers() {
    // C0 delivers iff x0 ∧ ¬x1; C1 is virtual (rule `false`).
    let s = stimulation(1.0, 1.0, 0.0);
    let mut table = Table::new();
    table
        .push_port(
            &[connection(exact(0x600), s), connection(exact(0x601), s)],
            &[
                node(0, NodeRef::NOBODY, at(1)),
                node(1, deliver(0), NodeRef::NOBODY),
            ],
            at(0),
        )
        .unwrap();
    let mut arbiter = Arbiter::new(table).unwrap();
    let (_, v) = receive(&mut arbiter, std_id(0x600), micros(0));
    assert_eq!(v[0].delivered, Some(0));
    let (reception, v) = receive(&mut arbiter, std_id(0x601), micros(1));
    assert_eq!(
        (v[0].active, v[0].selected, v[0].delivered),
        (set(&[0, 1]), None, None)
    );
    assert!(reception.fed.contains(0) && reception.delivered.is_empty());
    let (_, v) = receive(&mut arbiter, std_id(0x600), micros(2));
    assert_eq!(v[0].delivered, None);
    // After τ without frames on C1 (its last at 1 µs), C0 gets through again.
    let (_, v) = receive(&mut arbiter, std_id(0x600), micros(1_000_002));
    assert_eq!((v[0].active, v[0].delivered), (set(&[0]), Some(0)));
}

// ---------------------------------------------------------------------------------------------
// Frames that match nothing, accessors out of range, reset.

#[test]
fn frames_that_match_nothing_change_nothing() {
    let mut arbiter = figure1();
    receive(&mut arbiter, std_id(FACE), micros(0));
    let before = arbiter.level(0, 0, micros(5));
    for id in [
        std_id(0x112),
        std_id(0),
        // Same number, other format: another topic.
        Id::Extended(ExtendedId::new(FACE.into()).unwrap()),
        Id::Extended(ExtendedId::MAX),
    ] {
        let mut calls = 0;
        let reception = arbiter.receive(&id, micros(5), |_| calls += 1);
        assert_eq!(reception, Reception::default(), "{id:?}");
        assert!(reception.fed.is_empty() && reception.delivered.is_empty());
        assert_eq!(calls, 0, "{id:?}");
    }
    assert_eq!(arbiter.level(0, 0, micros(5)), before);
    assert_eq!(arbiter.level(0, 1, micros(5)).unwrap().to_f64(), 0.0);
}

#[test]
fn accessors_out_of_range_answer_none_or_empty() {
    let mut arbiter = figure1();
    receive(&mut arbiter, std_id(OBJECT), micros(0));
    let now = micros(0);
    assert_eq!(arbiter.port_count(), 1);
    assert_eq!(arbiter.connection_count(0), 2);
    assert!(arbiter.level(0, 1, now).is_some());
    for port in [1, 15, 16, 255] {
        assert_eq!(arbiter.selected(port, now), None, "port {port}");
        assert_eq!(arbiter.activity(port, now), ConnectionSet::EMPTY);
        assert_eq!(arbiter.level(port, 0, now), None);
        assert_eq!(arbiter.connection_count(port), 0);
        assert!(arbiter.table().port(usize::from(port)).is_none());
    }
    for connection in [2, 31, 32, 255] {
        assert_eq!(
            arbiter.level(0, connection, now),
            None,
            "connection {connection}"
        );
    }
}

#[test]
fn reset_returns_every_connection_to_rest() {
    let mut arbiter = figure1();
    for k in 0..6 {
        receive(&mut arbiter, std_id(OBJECT), micros(k));
    }
    assert_eq!(arbiter.selected(0, micros(10)), Some(1));
    arbiter.reset();
    assert_eq!(arbiter.selected(0, micros(10)), None);
    assert_eq!(arbiter.activity(0, micros(10)), ConnectionSet::EMPTY);
    assert_eq!(arbiter.level(0, 1, micros(10)).unwrap().to_f64(), 0.0);
}
