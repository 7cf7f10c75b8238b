//! A table swap keeps the state of the connections it leaves unchanged (`Arbiter::carry_over`):
//! on random tables and frames, an arbiter swapped for a copy of its own table decides every
//! later frame exactly as the one that was not swapped; and after a swap to a changed table, the
//! swapped arbiter decides as the reference (`common/reference.rs`) on the new table whose
//! unchanged connections took the old reference's state and whose changed ones started afresh.

use crate::common::{random, reference};

use pab_core::{Arbiter, Connection, Filter, Instant, Table};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use random::{
    POOL, Rng, compare_at, id, next_instant, random_diagram, random_filter, random_stimulation,
    random_table,
};
use reference::Reference;

fn runner(cases: u32) -> TestRunner {
    TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    })
}

/// Feeds `frames` random frames to `arbiter` and `reference` from `now`, checking that they
/// agree on every frame; returns the last instant.
fn run_frames<const P: usize, const C: usize, const N: usize>(
    rng: &mut Rng,
    arbiter: &mut Arbiter<P, C, N>,
    reference: &mut Reference,
    mut now: u64,
    frames: usize,
    what: &str,
) -> Result<u64, TestCaseError> {
    for frame in 0..frames {
        now = next_instant(rng, now);
        let at = Instant::from_micros(now);
        let frame_id = id(POOL[rng.below(POOL.len() as u64) as usize], rng.chance(20));
        let mut verdicts = Vec::new();
        let reception = arbiter.receive(&frame_id, at, |v| verdicts.push(*v));
        let (fed, delivered, expected) = reference.receive(&frame_id, at);
        let what = format!("{what}: frame {frame} ({frame_id:?} at {now})");
        prop_assert_eq!(&verdicts, &expected, "{}: verdicts", what);
        prop_assert_eq!(reception.fed.bits(), fed, "{}: fed ports", what);
        prop_assert_eq!(reception.delivered.bits(), delivered, "{}: delivered", what);
        compare_at(arbiter, reference, at, &what)?;
    }
    Ok(now)
}

/// A start on the clock, anywhere (including just before the counter wraps).
fn start(rng: &mut Rng) -> u64 {
    match rng.below(3) {
        0 => 0,
        1 => u64::MAX - rng.below(10_000_000),
        _ => rng.next(),
    }
}

/// Mostly the frames come within the short τs, so that connections are active at the swap.
fn steady_instant(rng: &mut Rng, now: u64) -> u64 {
    if rng.chance(80) {
        now.wrapping_add(rng.below(50))
    } else {
        next_instant(rng, now)
    }
}

fn self_swap_case<const P: usize, const C: usize, const N: usize>(
    seed: u64,
) -> Result<(), TestCaseError> {
    let mut rng = Rng::new(seed);
    let table: Table<P, C, N> = random_table(&mut rng, 20);
    let mut kept = Arbiter::new(table.clone()).expect("a valid table");
    let mut now = start(&mut rng);
    for _ in 0..rng.below(300) {
        now = steady_instant(&mut rng, now);
        let frame_id = id(POOL[rng.below(POOL.len() as u64) as usize], rng.chance(20));
        kept.receive(&frame_id, Instant::from_micros(now), |_| {});
    }
    // The swap: a new arbiter on the same table takes over the old one's state.
    let mut swapped = Arbiter::new(table.clone()).expect("a valid table");
    let carried = swapped.carry_over(&kept);
    prop_assert_eq!(
        carried,
        table.connection_count(),
        "every connection is unchanged"
    );
    for frame in 0..300 {
        now = next_instant(&mut rng, now);
        let at = Instant::from_micros(now);
        let frame_id = id(POOL[rng.below(POOL.len() as u64) as usize], rng.chance(20));
        let mut expected = Vec::new();
        let mut verdicts = Vec::new();
        let want = kept.receive(&frame_id, at, |v| expected.push(*v));
        let got = swapped.receive(&frame_id, at, |v| verdicts.push(*v));
        prop_assert_eq!(&verdicts, &expected, "frame {} after the swap", frame);
        prop_assert_eq!(got, want, "frame {} after the swap", frame);
        for port in 0..kept.port_count() as u8 {
            prop_assert_eq!(swapped.activity(port, at), kept.activity(port, at));
            for connection in 0..kept.connection_count(port) as u8 {
                prop_assert_eq!(
                    swapped.level(port, connection, at),
                    kept.level(port, connection, at)
                );
            }
        }
    }
    Ok(())
}

#[test]
fn swapping_a_table_for_itself_changes_no_future_decision() {
    runner(400)
        .run(&any::<u64>(), self_swap_case::<16, 512, 2048>)
        .unwrap();
    runner(400)
        .run(&any::<u64>(), self_swap_case::<4, 64, 256>)
        .unwrap();
    runner(200)
        .run(&any::<u64>(), self_swap_case::<2, 3, 8>)
        .unwrap();
}

/// `table` with random changes: connections with another filter or other parameters, ports
/// with a connection more or less (and then another decision), new decisions, ports dropped or
/// added at the end.
fn changed<const P: usize, const C: usize, const N: usize>(
    rng: &mut Rng,
    table: &Table<P, C, N>,
) -> Table<P, C, N> {
    let mut out = Table::new();
    let ports: Vec<_> = table.ports().collect();
    let keep = if rng.chance(20) {
        rng.below(ports.len() as u64 + 1) as usize
    } else {
        ports.len()
    };
    for view in ports.iter().take(keep) {
        let mut connections: Vec<Connection> = view.connections.to_vec();
        for connection in connections.iter_mut() {
            match rng.below(10) {
                0 => connection.filter = random_filter(rng, 20),
                1 => connection.stimulation = random_stimulation(rng),
                _ => {}
            }
        }
        let room = C - out.connection_count();
        let resized = match rng.below(10) {
            0 if !connections.is_empty() => {
                connections.pop();
                true
            }
            1 if connections.len() < 32 && connections.len() < room => {
                connections.push(Connection {
                    filter: random_filter(rng, 20),
                    stimulation: random_stimulation(rng),
                });
                true
            }
            _ => false,
        };
        connections.truncate(room);
        let (nodes, root) =
            if resized || rng.chance(10) || connections.len() != view.connections.len() {
                random_diagram(rng, connections.len() as u8)
            } else {
                (view.nodes.to_vec(), view.root)
            };
        if out.node_count() + nodes.len() > N || out.push_port(&connections, &nodes, root).is_err()
        {
            let _ = out.push_port(&[], &[], pab_core::NodeRef::NOBODY);
        }
    }
    if rng.chance(20) && out.port_count() < P {
        let n = rng.below(4.min((C - out.connection_count()) as u64) + 1) as u8;
        let connections: Vec<Connection> = (0..n)
            .map(|_| Connection {
                filter: random_filter(rng, 20),
                stimulation: random_stimulation(rng),
            })
            .collect();
        let (nodes, root) = random_diagram(rng, n);
        if out.node_count() + nodes.len() <= N {
            let _ = out.push_port(&connections, &nodes, root);
        }
    }
    out
}

/// How many connections of `new` are unchanged from `old` (same port, same index, same filter
/// and parameters), and how many of those had a level above zero in `arbiter` at `now`.
fn unchanged<const P: usize, const C: usize, const N: usize>(
    old: &Table<P, C, N>,
    new: &Table<P, C, N>,
    arbiter: &Arbiter<P, C, N>,
    now: Instant,
) -> (usize, usize) {
    let (mut same, mut live) = (0, 0);
    for (p, (a, b)) in old.ports().zip(new.ports()).enumerate() {
        for (k, (x, y)) in a.connections.iter().zip(b.connections).enumerate() {
            if x == y {
                same += 1;
                if arbiter
                    .level(p as u8, k as u8, now)
                    .is_some_and(|level| level.raw() > 0)
                {
                    live += 1;
                }
            }
        }
    }
    (same, live)
}

/// Returns (connections carried over with a level above zero, connections that started afresh).
fn changed_swap_case<const P: usize, const C: usize, const N: usize>(
    seed: u64,
) -> Result<(usize, usize), TestCaseError> {
    let mut rng = Rng::new(seed);
    let old: Table<P, C, N> = random_table(&mut rng, 20);
    let mut reference = Reference::new(&old);
    let mut arbiter = Arbiter::new(old.clone()).expect("a valid table");
    let mut now = start(&mut rng);
    let frames = rng.below(300) as usize;
    for _ in 0..frames {
        now = steady_instant(&mut rng, now);
        let frame_id = id(POOL[rng.below(POOL.len() as u64) as usize], rng.chance(20));
        let at = Instant::from_micros(now);
        arbiter.receive(&frame_id, at, |_| {});
        reference.receive(&frame_id, at);
    }
    compare_at(
        &arbiter,
        &reference,
        Instant::from_micros(now),
        "before the swap",
    )?;
    let new = changed(&mut rng, &old);
    let (same, live) = unchanged(&old, &new, &arbiter, Instant::from_micros(now));
    let mut swapped = Arbiter::new(new.clone()).expect("a valid table");
    prop_assert_eq!(swapped.carry_over(&arbiter), same);
    let mut carried = Reference::new(&new);
    carried.carry_from(&reference);
    compare_at(&swapped, &carried, Instant::from_micros(now), "at the swap")?;
    for _ in 0..3 {
        let probe = Instant::from_micros(next_instant(&mut rng, now));
        compare_at(&swapped, &carried, probe, "probe after the swap")?;
    }
    run_frames(
        &mut rng,
        &mut swapped,
        &mut carried,
        now,
        300,
        "after the swap",
    )?;
    Ok((live, new.connection_count() - same))
}

#[test]
fn after_a_swap_unchanged_connections_go_on_and_changed_ones_start_fresh() {
    for (cases, case) in [
        (
            400,
            changed_swap_case::<16, 512, 2048> as fn(u64) -> Result<(usize, usize), TestCaseError>,
        ),
        (400, changed_swap_case::<4, 64, 256>),
        (200, changed_swap_case::<2, 3, 8>),
    ] {
        let (live, fresh) = (std::cell::Cell::new(0), std::cell::Cell::new(0));
        runner(cases)
            .run(&any::<u64>(), |seed| {
                let (l, f) = case(seed)?;
                live.set(live.get() + l);
                fresh.set(fresh.get() + f);
                Ok(())
            })
            .unwrap();
        let (live, fresh) = (live.get(), fresh.get());
        // Both kinds happened: the comparison was not made on idle or identical tables only.
        assert!(
            live > 0,
            "no case carried a connection with a level above zero"
        );
        assert!(fresh > 0, "no case changed a connection");
    }
}

#[test]
fn a_changed_filter_or_parameter_restarts_that_connection_only() {
    // Two connections σ = 1, τ = 1 s: both active after one frame each. The new table changes
    // the second's τ; the first goes on (active), the second starts at S = 0 (inactive).
    let s = pab_core::Stimulation::from_seconds(1.0, 1.0, 0.0).unwrap();
    let c0 = Connection {
        filter: Filter::exact(0x100, false).unwrap(),
        stimulation: s,
    };
    let c1 = Connection {
        filter: Filter::exact(0x101, false).unwrap(),
        stimulation: s,
    };
    let chain = [
        pab_core::DecisionNode {
            var: 0,
            low: pab_core::NodeRef::node(1).unwrap(),
            high: pab_core::NodeRef::deliver(0).unwrap(),
        },
        pab_core::DecisionNode {
            var: 1,
            low: pab_core::NodeRef::NOBODY,
            high: pab_core::NodeRef::deliver(1).unwrap(),
        },
    ];
    let mut old: Table = Table::new();
    old.push_port(&[c0, c1], &chain, pab_core::NodeRef::node(0).unwrap())
        .unwrap();
    let mut arbiter = Arbiter::new(old).unwrap();
    let t = Instant::from_micros(5_000_000);
    arbiter.receive(&id(0x100, false), t, |_| {});
    arbiter.receive(&id(0x101, false), t, |_| {});
    assert_eq!(arbiter.activity(0, t).bits(), 0b11);
    let mut new: Table = Table::new();
    let c1_changed = Connection {
        stimulation: pab_core::Stimulation::from_seconds(1.0, 2.0, 0.0).unwrap(),
        ..c1
    };
    new.push_port(
        &[c0, c1_changed],
        &chain,
        pab_core::NodeRef::node(0).unwrap(),
    )
    .unwrap();
    let mut swapped = Arbiter::new(new).unwrap();
    assert_eq!(swapped.carry_over(&arbiter), 1);
    assert_eq!(swapped.activity(0, t).bits(), 0b01);
    assert_eq!(swapped.selected(0, t), Some(0));
    assert_eq!(swapped.level(0, 1, t).unwrap().raw(), 0);
    // A filter changed: same.
    let mut other: Table = Table::new();
    let c0_moved = Connection {
        filter: Filter::exact(0x102, false).unwrap(),
        ..c0
    };
    other
        .push_port(&[c0_moved, c1], &chain, pab_core::NodeRef::node(0).unwrap())
        .unwrap();
    let mut swapped = Arbiter::new(other).unwrap();
    assert_eq!(swapped.carry_over(&arbiter), 1);
    assert_eq!(swapped.activity(0, t).bits(), 0b10);
    assert_eq!(swapped.selected(0, t), Some(1));
}
