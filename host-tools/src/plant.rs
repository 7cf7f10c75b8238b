//! The simulated robot on a live bus (`pabctl plant`): the simulator's plant on the bus
//! (`pab_lang::sim::plant::BusPlant`) stepped in real time, reading the board's set-point frames
//! and publishing the drive's pose and the wrist's wrench (docs/can-protocol.md, "The drive's
//! frames"), and its range finder on the board sensor `[plant] range_finder` names, if any (the
//! frame the simulator makes, `pab_lang::sim::schema::range_frame`). What the HIL suite puts in
//! front of a schema server's board.
//!
//! Each step integrates the model for exactly one period (so the physics is the simulator's,
//! whatever the host's timing), then publishes; steps are paced by the wall clock, and a late
//! one is not made up twice (the model never sees a longer step).

use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use pab_lang::network::SchemaBoard;
pub use pab_lang::sim::plant::BusPlant;
use pab_lang::sim::plant::{Plant, PlantConfig};

use crate::bus::Bus;

/// One published step, for logs and assertions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Seconds since the plant started.
    pub t: f64,
    /// The measured pose (x, y, z), µm.
    pub pose: [i32; 3],
    /// The set-point's attractor, µm (the start pose before the first set-point).
    pub attractor: [i32; 3],
    /// The contact force's magnitude, N.
    pub force_n: f64,
    /// Parts in a hole.
    pub inserted: usize,
    /// Set-point frames received so far.
    pub setpoints: u64,
}

/// Runs `config`'s plant in front of `board` ([`BusPlant::new`]) on `bus` at `period_us` until
/// `stop` is set (or `duration` has passed), handing each step's sample to `log`; returns the
/// plant at the end.
pub fn run(
    bus: &mut dyn Bus,
    board: &SchemaBoard,
    config: PlantConfig,
    period_us: u32,
    duration: Option<Duration>,
    stop: &AtomicBool,
    log: &mut dyn FnMut(&Sample),
) -> io::Result<Plant> {
    let mut robot = BusPlant::new(board, config);
    let start = Instant::now();
    let period = Duration::from_micros(u64::from(period_us.max(1)));
    let mut next = start;
    while !stop.load(Ordering::SeqCst) && duration.is_none_or(|d| start.elapsed() < d) {
        // Read until this step is due.
        loop {
            let wait = next.saturating_duration_since(Instant::now());
            let frame = match bus.receive(wait) {
                Ok(Some(frame)) => frame,
                Ok(None) => break,
                // A signal (the SIGTERM that ends the run) interrupted the wait: the loop looks
                // at `stop` next.
                Err(e) if e.kind() == io::ErrorKind::Interrupted => break,
                Err(e) => return Err(e),
            };
            robot.on_frame(&frame);
            if Instant::now() >= next {
                break;
            }
        }
        next += period;
        if next < Instant::now() {
            // Late: the next step a period from now, not a burst.
            next = Instant::now() + period;
        }
        robot.step(period_us);
        for frame in robot.frames() {
            match bus.send(&frame) {
                Err(e) if e.kind() == io::ErrorKind::Interrupted => break,
                Err(e) => return Err(e),
                Ok(()) => {}
            }
        }
        let plant = robot.plant();
        let pose = plant.pose();
        let attractor = robot.setpoint().map_or([pose[0], pose[1], pose[2]], |s| {
            [s.attractor[0], s.attractor[1], s.attractor[2]]
        });
        log(&Sample {
            t: start.elapsed().as_secs_f64(),
            pose: [pose[0], pose[1], pose[2]],
            attractor,
            force_n: plant.force_n(),
            inserted: plant.inserted(),
            setpoints: robot.received(),
        });
    }
    Ok(robot.into_plant())
}

#[cfg(test)]
mod tests {
    use super::*;
    use pab_core::Frame;
    use pab_core::schema::drive;
    use pab_lang::diagnostic::Source;
    use pab_lang::network::Network;
    use pab_lang::sim::schema::range_frame;

    /// A board with a range finder `gap` (u16, 0.01 mm a count) on 0x330 and another sensor
    /// before it, so that the plant must pick the sensor `range_finder` names, not the first.
    fn network(range_finder: bool) -> Network {
        let text = format!(
            r#"
[nodes.arm]
id = 10

[schema.arm]
drive = {{ setpoint = 0x300, pose = 0x310, wrench = 0x320 }}

[schema.arm.sensors.grip]
can_id = 0x340
value = {{ offset = 0, size = 1 }}

[schema.arm.sensors.gap]
can_id = 0x330
value = {{ offset = 2, size = 2, endian = "big" }}
scale = 0.01
unit = "mm"

[plant]
start_mm = [0, 0, 50]
parts_mm = [[0, 0]]
{}
"#,
            if range_finder {
                "range_finder = \"gap\""
            } else {
                ""
            }
        );
        Network::parse(Source::new("plant.toml", &text)).unwrap()
    }

    fn plant(network: &Network) -> BusPlant {
        BusPlant::new(
            &network.schema_boards[0],
            network.plant.clone().unwrap_or_default(),
        )
    }

    /// The drive's four frames: pose and wrench, translation then rotation.
    fn drive_ids(frames: &[Frame]) -> Vec<u32> {
        frames.iter().take(4).map(|f| f.raw_id().0).collect()
    }

    #[test]
    fn the_range_finder_goes_out_after_the_pose_and_wrench_as_the_simulator_makes_it() {
        let network = network(true);
        let topic = &network.schema_boards[0].sensors[1];
        let mut robot = plant(&network);
        // At the start the tip is 50 mm up over a 15 mm part: 35 mm, 3500 counts of 0.01 mm.
        let frames = robot.frames();
        assert_eq!(frames.len(), 5);
        assert_eq!(drive_ids(&frames), [0x310, 0x311, 0x320, 0x321]);
        assert_eq!(frames[4].raw_id(), (0x330, false));
        assert_eq!(topic.sensor.read(&frames[4]), Some(3500));
        // The field is big endian at byte 2: what the board's Field reads is where it was put.
        assert_eq!(frames[4].payload()[2..4], 3500u16.to_be_bytes());

        // Moved down toward the part for 200 ms: the same frame as the simulator's at that
        // state, and its value the plant's range in counts.
        let setpoint = Frame::with_raw_id(0x300, false, &drive::pack([0, 0, 40_000], false));
        assert!(robot.on_frame(&setpoint.unwrap()));
        for _ in 0..200 {
            robot.step(1000);
        }
        let range_um = robot.plant().range();
        assert!(range_um < 34_000.0, "the tip moved down: {range_um} µm");
        let frames = robot.frames();
        assert_eq!(frames.get(4).copied(), range_frame(topic, range_um));
        let counts = (range_um / 10.0).round() as i32;
        assert_eq!(topic.sensor.read(&frames[4]), Some(counts));
    }

    #[test]
    fn without_a_range_finder_the_plant_sends_the_drives_four_frames() {
        let network = network(false);
        let frames = plant(&network).frames();
        assert_eq!(drive_ids(&frames), [0x310, 0x311, 0x320, 0x321]);
        assert_eq!(frames.len(), 4);
    }
}
