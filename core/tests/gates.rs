//! Competitive-dynamics gates as rule variables, on the node that runs the group and on a node
//! that reads its Gates frames: two arbiters in exact virtual time (1 ms polls), the frames
//! passed through their bus encoding. The owner's gate opens from a topic context, both nodes
//! deliver CMD exactly while it is open, the gates go on the bus on every change and at least
//! every 100 ms, and a silent owner closes the reader's gates after 300 ms with one loss.

use crate::common;

use common::{at, deliver, node};
use pab_core::dynamics::{
    Context, DynamicsError, GATE_SLOT_FILTER, GateError, GateLink, GateSource, GroupSpec, OWN,
    Params,
};
use pab_core::image::{self, LoadError};
use pab_core::protocol::{BROADCAST, Gates, Message};
use pab_core::table::TableError;
use pab_core::{
    Arbiter, Connection, Endian, Field, Filter, Frame, Gain, GatesLost, Instant, NodeRef,
    Stimulation, Table,
};

const CMD: u32 = 0x100;
const SEEN: u32 = 0x150;
const OWNER: u8 = 1;
const READER: u8 = 2;

fn t(us: u64) -> Instant {
    Instant::from_micros(us)
}

fn connection(filter: Filter) -> Connection {
    Connection {
        filter,
        stimulation: Stimulation::new(Gain::ONE, 50_000, 0).unwrap(),
    }
}

/// Port 0: CMD and the gate of behaviour 0; CMD delivers iff CMD & gate.
fn port(table: &mut Table) {
    let nodes = [
        node(0, NodeRef::NOBODY, at(1)),
        node(1, NodeRef::NOBODY, deliver(0)),
    ];
    table
        .push_port(
            &[
                connection(Filter::exact(CMD, false).unwrap()),
                connection(GATE_SLOT_FILTER),
            ],
            &nodes,
            at(0),
        )
        .unwrap();
}

/// Group 0: "search" from the SEEN topic's byte 0 (255 reads 1, 50 ms timeout), "idle" never.
fn group() -> GroupSpec {
    let mut params = Params::new();
    params.add_behaviour(500_000).unwrap();
    params.add_behaviour(500_000).unwrap();
    params.exclude(0, 1, 3 << 8).unwrap();
    params.exclude(1, 0, 3 << 8).unwrap();
    let seen = Context::Topic {
        filter: Filter::exact(SEEN, false).unwrap(),
        field: Field {
            offset: 0,
            size: 1,
            signed: false,
            endian: Endian::Little,
        },
        scale: 255 * 256,
        timeout_us: 50_000,
    };
    GroupSpec {
        number: 0,
        params,
        contexts: [seen, Context::Constant(0)].into_iter().collect(),
    }
}

fn link(source: u8) -> GateLink {
    GateLink {
        source,
        behaviour: 0,
        port: 0,
        connection: 1,
    }
}

fn owner_table() -> Table {
    let mut table = Table::new();
    port(&mut table);
    let source = GateSource {
        owner: OWN,
        group: 0,
        behaviours: 2,
    };
    table
        .push_dynamics(&[group()], &[source], &[link(0)])
        .unwrap();
    table
}

fn reader_table() -> Table {
    let mut table = Table::new();
    port(&mut table);
    let source = GateSource {
        owner: OWNER,
        group: 0,
        behaviours: 2,
    };
    table.push_dynamics(&[], &[source], &[link(0)]).unwrap();
    table
}

fn frame(id: u32, byte: u8) -> Frame {
    Frame::with_raw_id(id, false, &[byte]).unwrap()
}

/// Whether the node delivers CMD at `now`.
fn delivers(arbiter: &Arbiter, now: Instant) -> bool {
    arbiter.selected(0, now) == Some(0)
}

/// Polls the owner at `now`; its gates, through their frames, reach the reader (if given).
fn poll_owner(owner: &mut Arbiter, reader: Option<&mut Arbiter>, now: Instant) -> Vec<Gates> {
    let mut sent = Vec::new();
    owner.dynamics_poll(
        now,
        |_| {},
        |g| sent.push(g),
        |_| panic!("the owner reads no one"),
    );
    if let Some(reader) = reader {
        for gates in &sent {
            let bytes = Message::Gates(*gates).to_frame(OWNER, BROADCAST);
            let (id, message) = Message::decode(&bytes).unwrap();
            let Message::Gates(decoded) = message else {
                panic!("not gates")
            };
            assert_eq!((id.source, decoded), (OWNER, *gates));
            reader.on_gates(id.source, &decoded, now).unwrap();
        }
    }
    sent
}

#[test]
fn a_gate_opens_from_its_context_and_both_nodes_deliver_while_it_is_open() {
    let mut owner = Arbiter::new(owner_table()).unwrap();
    let mut reader = Arbiter::new(reader_table()).unwrap();
    let mut lost = Vec::new();
    let mut sends: Vec<(u64, Gates)> = Vec::new();
    let mut opened = None;
    let mut closed = None;
    for ms in 0..=1_500u64 {
        let now = t(ms * 1_000);
        // The target is seen from 100 ms to 800 ms (every 10 ms), commands come every ms.
        if (100..=800).contains(&ms) && ms % 10 == 0 {
            let seen = frame(SEEN, 255);
            owner.dynamics_frame(&seen, now);
            let _ = owner.receive(&seen.id(), now, |_| {});
        }
        for arbiter in [&mut owner, &mut reader] {
            let _ = arbiter.receive(&frame(CMD, 0).id(), now, |_| {});
        }
        for gates in poll_owner(&mut owner, Some(&mut reader), now) {
            sends.push((ms, gates));
        }
        reader.dynamics_poll(
            now,
            |_| {},
            |_| panic!("the reader runs no group"),
            |l| lost.push(l),
        );
        let open = owner.dynamics_runs()[0].gates() & 1 != 0;
        assert_eq!(reader.source_gates(0), Some(u32::from(open)), "at {ms} ms");
        assert_eq!(delivers(&owner, now), open, "owner at {ms} ms");
        assert_eq!(delivers(&reader, now), open, "reader at {ms} ms");
        if open && opened.is_none() {
            opened = Some(ms);
        }
        if !open && opened.is_some() && closed.is_none() {
            closed = Some(ms);
        }
    }
    let (opened, closed) = (
        opened.expect("the gate opened"),
        closed.expect("and closed"),
    );
    // ρ must pass ½ first: at least τ_ρ2 · ln 2 = 139 ms after the context appeared.
    assert!(opened >= 100 + 139, "opened at {opened} ms");
    assert!(opened < 500, "opened at {opened} ms");
    // The context lapses at 850 ms (50 ms after the last frame); ρ falls in τ_ρ1 = 10 ms, then n.
    assert!((850..950).contains(&closed), "closed at {closed} ms");
    assert!(lost.is_empty());
    // The first gates at 0; one frame per change, at its step; never 100 ms without one.
    assert_eq!(sends.first().map(|&(ms, g)| (ms, g.mask)), Some((0, 0)));
    assert!(
        sends
            .iter()
            .any(|&(ms, g)| ms == opened && g.mask == 1 && g.changes == 1)
    );
    assert!(
        sends
            .iter()
            .any(|&(ms, g)| ms == closed && g.mask == 0 && g.changes == 2)
    );
    for pair in sends.windows(2) {
        assert!(pair[1].0 - pair[0].0 <= 100, "{:?}", pair);
    }
    // About one frame per 100 ms, plus the two changes.
    assert!((16..=20).contains(&sends.len()), "{} frames", sends.len());
}

#[test]
fn a_silent_owner_closes_the_readers_gates_after_three_periods_and_is_reported_once() {
    let mut owner = Arbiter::new(owner_table()).unwrap();
    let mut reader = Arbiter::new(reader_table()).unwrap();
    let mut lost = Vec::new();
    let mut last_frame = 0;
    let mut closed_at = None;
    for ms in 0..=2_000u64 {
        let now = t(ms * 1_000);
        let seen = frame(SEEN, 255);
        owner.dynamics_frame(&seen, now);
        // The owner dies at 1 s, its gate open.
        if ms <= 1_000 && !poll_owner(&mut owner, Some(&mut reader), now).is_empty() {
            last_frame = ms;
        }
        reader.dynamics_poll(now, |_| {}, |_| {}, |l| lost.push((ms, l)));
        if ms == 1_000 {
            assert_eq!(reader.source_gates(0), Some(1), "open when the owner dies");
        }
        if ms > 1_000 && closed_at.is_none() && reader.source_gates(0) == Some(0) {
            closed_at = Some(ms);
        }
    }
    let closed_at = closed_at.expect("the reader closed the gates");
    assert_eq!(closed_at, last_frame + 300);
    assert_eq!(
        lost,
        vec![(
            closed_at,
            GatesLost {
                owner: OWNER,
                group: 0
            }
        )]
    );
}

#[test]
fn a_reader_never_hearing_its_owner_reports_the_loss_after_three_periods() {
    let mut reader = Arbiter::new(reader_table()).unwrap();
    let mut lost = Vec::new();
    // The node starts reading at its first poll (500 ms) and polls at its deadlines only.
    let mut polls = 0;
    for ms in 500..=900u64 {
        let now = t(ms * 1_000);
        let due = reader
            .dynamics_deadline(now)
            .is_some_and(|d| now.micros_since(d).is_some());
        if due {
            polls += 1;
            reader.dynamics_poll(now, |_| {}, |_| {}, |_| lost.push(ms));
        }
    }
    assert_eq!(lost, vec![800]);
    assert_eq!(polls, 2, "one poll to start, one when the silence is up");
}

#[test]
fn gates_of_a_group_of_another_size_are_refused_and_change_nothing() {
    let mut reader = Arbiter::new(reader_table()).unwrap();
    let now = t(0);
    let good = Gates {
        group: 0,
        behaviours: 2,
        mask: 1,
        changes: 1,
    };
    reader.on_gates(OWNER, &good, now).unwrap();
    let other = Gates {
        behaviours: 3,
        mask: 0,
        ..good
    };
    assert_eq!(reader.on_gates(OWNER, &other, now), Err(GateError::Count));
    assert_eq!(reader.source_gates(0), Some(1));
    // Another owner, another group: not read.
    reader.on_gates(9, &Gates { mask: 0, ..good }, now).unwrap();
    reader
        .on_gates(
            OWNER,
            &Gates {
                group: 1,
                mask: 0,
                ..good
            },
            now,
        )
        .unwrap();
    assert_eq!(reader.source_gates(0), Some(1));
}

#[test]
fn the_trace_sees_the_state_after_k_steps_with_the_contexts_sampled_at_t_k() {
    let mut owner = Arbiter::new(owner_table()).unwrap();
    let mut shadow = pab_core::dynamics::Dynamics::new(&group().params).unwrap();
    let mut rows: Vec<(u64, Vec<i32>, Vec<i32>)> = Vec::new();
    for ms in 0..=400u64 {
        let now = t(ms * 1_000);
        if ms >= 50 && ms % 10 == 0 {
            owner.dynamics_frame(&frame(SEEN, 128), now);
        }
        owner.dynamics_poll(
            now,
            |view| {
                let n = (0..view.dynamics.len())
                    .map(|i| view.dynamics.state(i).unwrap().n)
                    .collect();
                rows.push((view.at.as_micros(), view.contexts.to_vec(), n));
            },
            |_| {},
            |_| {},
        );
    }
    assert_eq!(rows.len(), 401);
    for (k, (at, contexts, n)) in rows.iter().enumerate() {
        assert_eq!(*at, k as u64 * 1_000);
        // The shadow has taken k steps, each with the contexts of the row before.
        let shadow_n: Vec<i32> = (0..2).map(|i| shadow.state(i).unwrap().n).collect();
        assert_eq!(*n, shadow_n, "row {k}");
        // A frame at exactly t_k counts: 128/255 from 50 ms on (until 50 ms after the last).
        let expected = if k >= 50 {
            pab_core::dynamics::Context::of_value(128, 255 * 256)
        } else {
            0
        };
        assert_eq!(contexts[0], expected, "row {k}");
        shadow.step(contexts);
    }
}

#[test]
fn a_late_poll_takes_every_step_due_and_a_stall_drops_the_backlog() {
    let mut owner = Arbiter::new(owner_table()).unwrap();
    let mut steps = 0;
    owner.dynamics_poll(t(0), |_| steps += 1, |_| {}, |_| {});
    owner.dynamics_poll(t(40_000), |_| steps += 1, |_| {}, |_| {});
    assert_eq!(steps, 41);
    assert_eq!(owner.dynamics_runs()[0].skipped(), 0);
    // 10 s late: 100 steps taken, the rest dropped and counted, the grid restarted.
    owner.dynamics_poll(t(10_040_000), |_| steps += 1, |_| {}, |_| {});
    assert_eq!(steps, 141);
    // Due: 41 ms to 10 040 ms, 10 000 steps; 100 taken.
    assert_eq!(owner.dynamics_runs()[0].skipped(), 10_000 - 100);
    assert_eq!(owner.dynamics_deadline(t(10_040_000)), Some(t(10_041_000)));
}

fn load_error(table: &Table, node: u8) -> LoadError {
    let mut out = vec![0; image::MAX_IMAGE_LEN];
    let len = image::encode(table, node, 1, &mut out).unwrap();
    image::load::<16, 512, 2048>(&out[..len]).unwrap_err()
}

#[test]
fn images_carry_the_dynamics_and_the_loader_refuses_what_is_invalid() {
    for (table, node) in [(owner_table(), OWNER), (reader_table(), READER)] {
        let mut out = vec![0; image::MAX_IMAGE_LEN];
        let len = image::encode(&table, node, 1, &mut out).unwrap();
        let loaded = image::load::<16, 512, 2048>(&out[..len]).unwrap();
        assert_eq!(loaded.table, table);
    }
    // A reader whose owner has its own id.
    assert_eq!(
        load_error(&reader_table(), OWNER),
        LoadError::Table(TableError::Dynamics(DynamicsError::Source { source: 0 }))
    );
    let refused = |groups: &[GroupSpec], sources: &[GateSource], links: &[GateLink]| {
        let mut table = Table::new();
        port(&mut table);
        let before = table.clone();
        let error = table.push_dynamics(groups, sources, links).unwrap_err();
        assert_eq!(table, before, "unchanged on error");
        error
    };
    let own = GateSource {
        owner: OWN,
        group: 0,
        behaviours: 2,
    };
    let dynamics = |error| TableError::Dynamics(error);
    // A link to CMD (not a gate connection), to behaviour 2 of 2, to a source not there.
    for bad in [
        GateLink {
            connection: 0,
            ..link(0)
        },
        GateLink {
            behaviour: 2,
            ..link(0)
        },
        GateLink {
            source: 1,
            ..link(0)
        },
        GateLink { port: 1, ..link(0) },
    ] {
        assert_eq!(
            refused(&[group()], &[own], &[bad]),
            dynamics(DynamicsError::Link { link: 0 })
        );
    }
    assert_eq!(
        refused(&[group()], &[own], &[link(0), link(0)]),
        dynamics(DynamicsError::Link { link: 1 })
    );
    // OWN without the group, or with another count.
    assert_eq!(
        refused(&[], &[own], &[]),
        dynamics(DynamicsError::Source { source: 0 })
    );
    assert_eq!(
        refused(
            &[group()],
            &[GateSource {
                behaviours: 3,
                ..own
            }],
            &[]
        ),
        dynamics(DynamicsError::Source { source: 0 })
    );
    // An owner above 127; a count of 0.
    for bad in [
        GateSource { owner: 128, ..own },
        GateSource {
            owner: 5,
            behaviours: 0,
            ..own
        },
    ] {
        assert_eq!(
            refused(&[], &[bad], &[]),
            dynamics(DynamicsError::Source { source: 0 })
        );
    }
    // One number, two groups: run twice, read twice, or run here and read from another node.
    assert_eq!(
        refused(&[group(), group()], &[], &[]),
        dynamics(DynamicsError::DuplicateGroup { number: 0 })
    );
    assert_eq!(
        refused(&[group()], &[GateSource { owner: 5, ..own }], &[]),
        dynamics(DynamicsError::DuplicateGroup { number: 0 })
    );
    // Contexts: count, a constant above 1, a connection not there, scale 0, timeout 0.
    let with_context = |context: Context| {
        let mut spec = group();
        spec.contexts[1] = context;
        spec
    };
    let mut short = group();
    short.contexts.pop();
    assert_eq!(
        refused(&[short], &[], &[]),
        dynamics(DynamicsError::ContextCount { group: 0 })
    );
    for bad in [
        Context::Constant((1 << 29) + 1),
        Context::Connection {
            port: 0,
            connection: 2,
        },
        Context::Connection {
            port: 1,
            connection: 0,
        },
    ] {
        assert_eq!(
            refused(&[with_context(bad)], &[], &[]),
            dynamics(DynamicsError::Context {
                group: 0,
                behaviour: 1
            })
        );
    }
    let Context::Topic {
        filter,
        field,
        scale,
        timeout_us,
    } = group().contexts[0]
    else {
        unreachable!()
    };
    for (scale, timeout_us) in [(0, timeout_us), (scale, 0), (scale, 3_600_000_001)] {
        let bad = Context::Topic {
            filter,
            field,
            scale,
            timeout_us,
        };
        assert_eq!(
            refused(&[with_context(bad)], &[], &[]),
            dynamics(DynamicsError::Context {
                group: 0,
                behaviour: 1
            })
        );
    }
    // Parameters: the integrator's own checks.
    let mut zero_noise = group();
    zero_noise.params.noise = 0;
    assert_eq!(
        refused(&[zero_noise], &[], &[]),
        dynamics(DynamicsError::Params {
            group: 0,
            error: pab_core::dynamics::ParamsError::ZeroNoise
        })
    );
}

#[test]
fn gates_frames_refuse_counts_beyond_32_gates_beyond_the_count_and_reserved_bits() {
    let good = Gates {
        group: 3,
        behaviours: 5,
        mask: 0b10101,
        changes: 7,
    };
    let frame = Message::Gates(good).to_frame(OWNER, BROADCAST);
    assert_eq!(frame.payload(), &[3, 5, 0b10101, 0, 0, 0, 7, 0]);
    assert_eq!(Message::decode(&frame).unwrap().1, Message::Gates(good));
    let all = Gates {
        behaviours: 32,
        mask: u32::MAX,
        ..good
    };
    assert_eq!(
        Message::decode(&Message::Gates(all).to_frame(OWNER, BROADCAST))
            .unwrap()
            .1,
        Message::Gates(all)
    );
    for bad in [
        Gates {
            behaviours: 0,
            mask: 0,
            ..good
        },
        Gates {
            behaviours: 33,
            ..good
        },
        Gates {
            mask: 0b100000,
            ..good
        },
    ] {
        let frame = Message::Gates(bad).to_frame(OWNER, BROADCAST);
        assert!(Message::decode(&frame).is_err(), "{bad:?}");
    }
    let mut payload = [3, 5, 0b10101, 0, 0, 0, 7, 0];
    payload[7] = 1;
    let raw =
        pab_core::protocol::FrameId::new(pab_core::protocol::Service::Gates, OWNER, BROADCAST)
            .raw();
    let reserved = Frame::with_raw_id(raw, true, &payload).unwrap();
    assert!(Message::decode(&reserved).is_err());
    payload[7] = 0;
    assert!(Message::decode(&Frame::with_raw_id(raw, true, &payload).unwrap()).is_ok());
    assert!(Message::decode(&Frame::with_raw_id(raw, true, &payload[..7]).unwrap()).is_err());
}

#[test]
fn a_stall_restarts_the_grid_with_the_contexts_sampled_at_the_poll() {
    let mut owner = Arbiter::new(owner_table()).unwrap();
    for ms in 0..=40u64 {
        let now = t(ms * 1_000);
        owner.dynamics_frame(&frame(SEEN, 255), now);
        owner.dynamics_poll(now, |_| {}, |_| {}, |_| {});
    }
    // Heard at 130 ms, then the node stalls until 10 s: the backlog's last step (140 ms) samples
    // that reading, 10 ms old and fresh; at 10 s it is 9.87 s old and lapsed (50 ms timeout).
    owner.dynamics_frame(&frame(SEEN, 255), t(130_000));
    let mut last = None;
    owner.dynamics_poll(
        t(10_000_000),
        |view| last = Some((view.at, view.contexts.to_vec(), view.dynamics.clone())),
        |_| {},
        |_| {},
    );
    let (at, contexts, mut expected) = last.expect("steps taken");
    assert_eq!(at, t(140_000));
    assert_eq!(contexts, [1 << 29, 0]);
    assert_eq!(owner.dynamics_runs()[0].skipped(), 10_000 - 140);
    // The grid restarts at 10 s: its first step takes the contexts of 10 s (none), not those of
    // 140 ms.
    expected.step(&[0, 0]);
    let mut after = None;
    owner.dynamics_poll(
        t(10_001_000),
        |view| after = Some(view.dynamics.clone()),
        |_| {},
        |_| {},
    );
    let after = after.expect("one step");
    for i in 0..2 {
        assert_eq!(after.state(i), expected.state(i), "behaviour {i}");
    }
}
