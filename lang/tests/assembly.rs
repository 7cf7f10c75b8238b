//! examples/assembly.toml in virtual time: the paper's six-part assembly, the search time
//! against the initial offset, and the safety events (an obstacle on the way, an emergency stop,
//! a plate without a hole).

use std::path::Path;

use pab_core::schema::{Action, Origin, Safety};
use pab_lang::network::{Command, Network, Timed};
use pab_lang::sim::plant::Obstacle;
use pab_lang::sim::schema::{Limits, Run, simulate};

fn example() -> Network {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/assembly.toml");
    Network::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

const LIMITS: Limits = Limits {
    until_us: 1_000_000_000,
    settle_us: 100_000,
};

fn rows(run: &Run) -> Vec<(String, &'static str, String)> {
    run.installed
        .iter()
        .map(|i| (i.name.clone(), i.source.name(), i.event.clone()))
        .collect()
}

/// The first part's nine calls alone.
fn first_part(network: &mut Network) {
    let client = network.client.as_mut().unwrap();
    client.program.truncate(9);
}

#[test]
fn six_parts_are_inserted_with_the_expected_schemas_and_events() {
    let network = example();
    let run = simulate(&network, LIMITS).unwrap();
    assert_eq!(run.fault, None);
    assert_eq!(run.plant.inserted(), 6, "{:?}", run.plant.parts());
    // Each call's schema is installed from the queue by the event that ends the one before:
    // a move by `done`, a touch-down by contact, a search by the part's drop.
    let program = &network.client.as_ref().unwrap().program;
    assert_eq!(program.len(), 54);
    let mut expected = Vec::new();
    let mut event = "queue-ready".to_string();
    for call in program {
        expected.push((call.name.clone(), "queue", event.clone()));
        let verb = call.name.split('(').next().unwrap();
        event = match verb {
            "move_to_touch" => "above:contact",
            "blind_search" => "below:displacement.z",
            _ => "done",
        }
        .to_string();
    }
    expected.push(("wait-queue".into(), "queue", event));
    assert_eq!(rows(&run), expected);
    // Each part went into its own hole.
    for (i, p) in run.plant.parts().iter().enumerate() {
        assert_eq!(*p, pab_lang::sim::plant::PartState::Inserted(i));
    }
}

/// The blind search's duration (its install to the release's), for the first part with its hole
/// `offset` µm from where the client believes it.
fn search_time(offset: [f64; 2]) -> u64 {
    let mut network = example();
    first_part(&mut network);
    let client = network.client.as_mut().unwrap();
    if let Action::BlindSearch { radius, .. } = &mut client.program[6].schema.action {
        *radius = 2_000;
    }
    let plant = network.plant.as_mut().unwrap();
    plant.holes[0] = [-100_000.0 + offset[0], 60_000.0 + offset[1]];
    let run = simulate(&network, LIMITS).unwrap();
    assert_eq!(run.fault, None, "offset {offset:?}");
    assert_eq!(run.plant.inserted(), 1, "offset {offset:?}");
    let start = run
        .installed
        .iter()
        .find(|i| i.name == "blind_search()")
        .unwrap()
        .t_us;
    let end = run
        .installed
        .iter()
        .find(|i| i.name == "release()")
        .unwrap()
        .t_us;
    end - start
}

#[test]
fn the_search_takes_longer_the_farther_the_hole() {
    // The paper's 0.3 mm and 1.2 mm, and two between, along one direction.
    let times: Vec<u64> = [150.0, 300.0, 600.0, 1200.0]
        .iter()
        .map(|d| search_time([d * 0.8, d * 0.6]))
        .collect();
    println!("search times (µs) at 0.15, 0.3, 0.6, 1.2 mm: {times:?}");
    assert!(times.windows(2).all(|w| w[0] < w[1]), "{times:?}");
    // A square spiral of pitch p covers a square of half-width d in about 4d²/p of path:
    // from 0.3 to 1.2 mm the time grows by more than 4 (the paper's cleverer search, 2).
    assert!(times[3] > 4 * times[1], "{times:?}");
}

#[test]
fn an_obstacle_on_the_way_raises_the_force_event_and_the_board_stops() {
    let mut network = example();
    first_part(&mut network);
    // A post between the part and its slot, in the way of the lift at 35 mm.
    network.plant.as_mut().unwrap().obstacles.push(Obstacle {
        min: [-110_000.0, -10_000.0, 0.0],
        max: [-90_000.0, 10_000.0, 60_000.0],
    });
    // A second after the stop, to see the force relieved.
    let run = simulate(
        &network,
        Limits {
            settle_us: 1_000_000,
            ..LIMITS
        },
    )
    .unwrap();
    assert_eq!(run.fault, Some(Safety::Force));
    let names: Vec<String> = run.installed.iter().map(|i| i.name.clone()).collect();
    let at = names.iter().position(|n| n == "safety:force").unwrap();
    assert_eq!(names[at - 1], "move_to(above_slot_1)");
    assert_eq!(run.installed[at].source, Origin::Innate);
    assert_eq!(run.installed[at].event, "safety:force");
    assert_eq!(names[at + 1..], ["wait-high-priority".to_string()]);
    assert_eq!(run.plant.inserted(), 0);
    // Halted: from the fault on, the attractor is where the robot was and no longer moves.
    let t = run.installed[at].t_us;
    let after: Vec<_> = run.samples.iter().filter(|s| s.t_us >= t).collect();
    assert!(after.windows(2).all(|w| w[0].attractor == w[1].attractor));
    assert_eq!(after[0].attractor, after[0].pose);
    // And the force is relieved.
    assert!(
        after.last().unwrap().force_n < 1.0,
        "{}",
        after.last().unwrap().force_n
    );
}

#[test]
fn an_emergency_stop_halts_within_one_period_and_the_queue_waits() {
    let mut network = example();
    let period = 1000;
    for stop in [3_000_000u64, 3_000_400, 15_250_001] {
        network.client.as_mut().unwrap().commands = vec![Timed {
            t_us: stop,
            command: Command::EmergencyStop,
        }];
        let run = simulate(&network, LIMITS).unwrap();
        assert_eq!(run.fault, Some(Safety::EmergencyStop));
        let i = run
            .installed
            .iter()
            .position(|i| i.event == "safety:estop")
            .unwrap();
        let halted = run.installed[i].t_us;
        assert!(
            halted >= stop && halted - stop < period,
            "stop at {stop}, halted at {halted}"
        );
        let after: Vec<_> = run.samples.iter().filter(|s| s.t_us >= halted).collect();
        assert_eq!(
            after[0].attractor, after[0].pose,
            "the set-point of the halting tick"
        );
        assert!(after.windows(2).all(|w| w[0].attractor == w[1].attractor));
        // Nothing from the queue after it: only the wait for the high-priority channel.
        assert_eq!(run.installed.len(), i + 2);
        assert_eq!(run.installed[i + 1].name, "wait-high-priority");
    }
}

#[test]
fn a_blind_search_over_a_plate_without_a_hole_ends_by_the_watchdog() {
    let mut network = example();
    first_part(&mut network);
    network.plant.as_mut().unwrap().holes.clear();
    let run = simulate(&network, LIMITS).unwrap();
    assert_eq!(run.fault, Some(Safety::Watchdog));
    let i = run
        .installed
        .iter()
        .position(|i| i.event == "safety:watchdog")
        .unwrap();
    assert_eq!(run.installed[i - 1].name, "blind_search()");
    // Its budget: 1.5 × the time to cover ±1 mm at 0.08 mm pitch and 2 mm/s, plus 1 s.
    let n = 2 * 1000 / 80;
    let nominal_us = 80 * n * (n + 1) * 1_000_000 / 2000;
    let budget = nominal_us * 3 / 2 + 1_000_000;
    assert_eq!(
        run.installed[i].t_us - run.installed[i - 1].t_us,
        budget + 1000
    );
}
