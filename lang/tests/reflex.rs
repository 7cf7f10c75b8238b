//! examples/reflex.toml in virtual time: an innate schema installed by a reaction to an extra
//! sensor (the plant's range finder, published as the sensor's frames and read by the board's
//! own code), and the same move without the reaction.

use std::path::Path;

use pab_core::schema::{Event, Measure, Safety, Source};
use pab_lang::network::Network;
use pab_lang::sim::plant::PartState;
use pab_lang::sim::schema::{Limits, simulate};

fn example() -> Network {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/reflex.toml");
    Network::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

const LIMITS: Limits = Limits {
    until_us: 60_000_000,
    settle_us: 100_000,
};

#[test]
fn the_range_finder_installs_the_innate_touch_down_and_the_part_is_taken() {
    let network = example();
    let run = simulate(&network, LIMITS).unwrap();
    let rows: Vec<(&str, &str, &str)> = run
        .installed
        .iter()
        .map(|i| (i.name.as_str(), i.source.name(), i.event.as_str()))
        .collect();
    assert_eq!(
        rows,
        [
            ("move_to(into_part)", "queue", "queue-ready"),
            ("careful", "innate", "below:gap"),
            ("grasp()", "queue", "above:contact"),
            ("move_to(lift)", "queue", "done"),
            ("wait-queue", "queue", "done"),
        ]
    );
    assert_eq!(run.fault, None);
    assert!(matches!(run.plant.parts()[0], PartState::Held(_)));
    // The reflex fired where the range finder said 5 mm: the tip 20 mm up (the part is 15 mm
    // tall), within what one tick at 50 mm/s and the rounding to 0.01 mm allow.
    let fired = run.installed[1].t_us;
    let sample = run.samples.iter().find(|s| s.t_us == fired).unwrap();
    assert!(
        (19_940..=20_010).contains(&sample.pose[2]),
        "z = {} µm at the reflex",
        sample.pose[2]
    );
}

#[test]
fn without_the_reaction_the_move_presses_the_part_into_the_force_limit() {
    let mut network = example();
    let call = &mut network.client.as_mut().unwrap().program[0];
    assert_eq!(
        (
            call.schema.reactions[0].event,
            call.schema.reactions[0].next
        ),
        (Event::Below(Measure::Sensor(0), 500), Source::Innate(0)),
        "5 mm is 500 counts of 0.01 mm"
    );
    call.schema.reactions.remove(0);
    let run = simulate(&network, LIMITS).unwrap();
    assert_eq!(run.fault, Some(Safety::Force));
    assert!(run.installed.iter().all(|i| i.name != "careful"));
}
