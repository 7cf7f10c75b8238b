//! The simulated robot on a live bus (`pabctl plant`): the plant model of the simulator
//! (`pab_lang::sim::plant`) stepped in real time, reading the board's set-point frames and
//! publishing the drive's pose and the wrist's wrench (docs/can-protocol.md, "The drive's
//! frames"). What the HIL suite puts in front of a schema server's board.
//!
//! Each step integrates the model for exactly one period (so the physics is the simulator's,
//! whatever the host's timing), then publishes; steps are paced by the wall clock, and a late
//! one is not made up twice (the model never sees a longer step).

use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use pab_core::Frame;
use pab_core::schema::{Drive, Gripper, Setpoint, drive};
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

/// The plant as the bus sees it, without I/O: it reads the board's set-point frames and makes
/// the drive's pose and wrench frames. [`run`] paces it in real time on a bus; a rig in virtual
/// time (the schema server's replay test) drives it frame by frame.
pub struct BusPlant {
    plant: Plant,
    ids: Drive,
    setpoint: Option<Setpoint>,
    partial: (Option<[i32; 3]>, bool, Option<[i32; 3]>),
    received: u64,
}

impl BusPlant {
    /// `config`'s plant in front of a board whose drive is at `ids`.
    pub fn new(ids: Drive, config: PlantConfig) -> BusPlant {
        BusPlant {
            plant: Plant::new(config),
            ids,
            setpoint: None,
            partial: (None, false, None),
            received: 0,
        }
    }

    /// Reads `frame` if it is one of the board's set-point frames; returns whether it was.
    pub fn on_frame(&mut self, frame: &Frame) -> bool {
        let read = read_setpoint(frame, self.ids, &mut self.partial, &mut self.setpoint);
        if read {
            self.received += 1;
        }
        read
    }

    /// Integrates the model for `period_us` under the last set-point (still before the first).
    pub fn step(&mut self, period_us: u32) {
        if let Some(s) = &self.setpoint {
            self.plant.step(s, period_us);
        }
    }

    /// The drive's pose and the wrist's wrench now: four frames (translation, rotation of each).
    pub fn frames(&self) -> Vec<Frame> {
        let pose = self.plant.pose();
        let wrench = self.plant.wrench();
        let ids = self.ids;
        [
            (ids.pose, 0, [pose[0], pose[1], pose[2]]),
            (ids.pose, 1, [pose[3], pose[4], pose[5]]),
            (ids.wrench, 0, [wrench[0], wrench[1], wrench[2]]),
            (ids.wrench, 1, [wrench[3], wrench[4], wrench[5]]),
        ]
        .into_iter()
        .filter_map(|(base, offset, values)| {
            Frame::with_raw_id(
                base.raw().saturating_add(offset),
                base.is_extended(),
                &drive::pack(values, false),
            )
        })
        .collect()
    }

    /// The model.
    pub fn plant(&self) -> &Plant {
        &self.plant
    }

    /// The last set-point read.
    pub fn setpoint(&self) -> Option<Setpoint> {
        self.setpoint
    }

    /// Set-point frames read so far.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// The model, at the end.
    pub fn into_plant(self) -> Plant {
        self.plant
    }
}

/// Runs the plant on `bus` at `period_us` until `stop` is set (or `duration` has passed),
/// handing each step's sample to `log`; returns the plant at the end.
pub fn run(
    bus: &mut dyn Bus,
    drive_ids: Drive,
    config: PlantConfig,
    period_us: u32,
    duration: Option<Duration>,
    stop: &AtomicBool,
    log: &mut dyn FnMut(&Sample),
) -> io::Result<Plant> {
    let mut robot = BusPlant::new(drive_ids, config);
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

/// The board's set-point frames: the attractor (translation with the gripper flag, rotation)
/// and the impedance. Returns whether `frame` was one.
fn read_setpoint(
    frame: &Frame,
    ids: Drive,
    partial: &mut (Option<[i32; 3]>, bool, Option<[i32; 3]>),
    setpoint: &mut Option<Setpoint>,
) -> bool {
    let (raw, extended) = frame.raw_id();
    let base = ids.setpoint;
    if extended != base.is_extended() {
        return false;
    }
    let Some(offset) = raw.checked_sub(base.raw()).filter(|o| *o < 3) else {
        return false;
    };
    let current = setpoint.get_or_insert(Setpoint {
        attractor: [0; 6],
        stiffness: 2000,
        damping: 100,
        gripper: Gripper::Open,
    });
    match offset {
        0 | 1 => {
            let Some((values, flag)) = drive::unpack(frame.payload()) else {
                return false;
            };
            if offset == 0 {
                partial.0 = Some(values);
                partial.1 = flag;
                current.gripper = if flag { Gripper::Closed } else { Gripper::Open };
            } else {
                partial.2 = Some(values);
            }
            drive::place(&mut current.attractor, 3 * offset as usize, values);
        }
        _ => {
            let data = frame.payload();
            if data.len() == 8 {
                let word =
                    |i: usize| u32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]);
                current.stiffness = word(0);
                current.damping = word(4);
            }
        }
    }
    true
}
