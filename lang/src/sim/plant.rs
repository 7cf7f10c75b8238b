//! The plant a schema server drives in simulation and in the HIL suite: an impedance-controlled
//! end-effector over a plate with holes, a wrist force sensor, a gripper, and parts to pick.
//!
//! One model for every run that needs a robot: the deterministic tests and `pabctl sim` step it
//! in virtual time; the HIL suite runs it as a process on the bus (`pabctl plant`). It is host
//! code in f64 (a model of physics, not a mechanism: nothing here decides anything the board
//! decides).
//!
//! # The model
//!
//! - A point mass `m` on x, y, z, pulled by the drive's impedance toward the attractor:
//!   m·a = K·(attractor − x) − D·v + F_contact, integrated with semi-implicit Euler in
//!   [`SUBSTEPS`] steps per board period (the contact is 100 times stiffer than the drive).
//!   Rotations follow their attractor at once (no inertia, no contact): the paper's wobble only
//!   reaches the trace.
//! - The plate's top is z = 0. Parts stand on it at their feeder positions: blocks
//!   2 × `part_half_width` wide and `part_height` tall. Holes are square, as wide as a part plus
//!   twice `clearance` (±0.05 mm in the paper), `hole_depth` deep, with no chamfer: a held part
//!   goes below the surface only with its centre within `clearance` of a hole's on both axes,
//!   and the hole's walls then hold it there.
//! - Contacts are penalty springs (`contact_stiffness`, `contact_damping`) along the surface's
//!   normal: the plate and the parts' tops under the gripper's tip (empty) or under the held
//!   part's bottom; the holes' walls; boxes ([`Obstacle`]) against the tip. Frictionless: the
//!   tip slides under preload exactly where the attractor pulls it (a real plate's friction
//!   would make it lag by μ × preload / K, which a stiffer lateral impedance cancels).
//! - The wrist sensor reads the contact force on the robot (mN): pressing down on the plate reads
//!   +z.
//! - A range finder looks straight down from the tip (from the held part's bottom when it holds
//!   one): the height above the tallest surface under it (the plate, a part's top, an obstacle's
//!   top), 0 in contact or in a hole. The simulator and `pabctl plant` publish it on the board
//!   sensor `[plant]`'s `range_finder` names (`super::schema::range_frame`).
//! - Closing the gripper takes the part whose top the tip is on (centre within
//!   `grasp_tolerance`, tip within 1 mm of its top), at the offset it has; opening it lets the
//!   part go: into the hole it is in (inserted once it is `insert_depth` below the surface, then
//!   it drops to the bottom), or onto the plate.

use pab_core::Frame;
use pab_core::schema::{AXES, Drive, Gripper, Pose, Setpoint, Wrench, drive};

use super::schema::range_frame;
use crate::network::{SchemaBoard, SensorTopic};

// The configuration is the network file's `[plant]`, so the model owns it.
pub use crate::network::{Obstacle, PlantConfig};

/// Integration steps per board period.
pub const SUBSTEPS: u32 = 10;

/// Where a part is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PartState {
    /// Standing on the plate, centre (x, y), µm.
    OnPlate([f64; 2]),
    /// In the gripper, its centre this far from the tip (x, y), µm.
    Held([f64; 2]),
    /// In hole `usize`, seated.
    Inserted(usize),
}

/// The plant's state.
#[derive(Clone, Debug)]
pub struct Plant {
    config: PlantConfig,
    /// Tip position and velocity, metres and m/s.
    x: [f64; 3],
    v: [f64; 3],
    rotation: [f64; 3],
    /// The contact force on the robot, N.
    force: [f64; 3],
    parts: Vec<PartState>,
    gripper: Gripper,
    /// The hole the held part is in (its bottom below the surface), if any.
    in_hole: Option<usize>,
}

const UM: f64 = 1e-6;

impl Plant {
    /// The plant at rest at `config.start`, every part on the plate, the gripper open.
    pub fn new(config: PlantConfig) -> Plant {
        let parts = config
            .parts
            .iter()
            .map(|p| PartState::OnPlate(*p))
            .collect();
        Plant {
            x: config.start.map(|c| c * UM),
            v: [0.0; 3],
            rotation: [0.0; 3],
            force: [0.0; 3],
            parts,
            gripper: Gripper::Open,
            in_hole: None,
            config,
        }
    }

    /// The geometry.
    pub fn config(&self) -> &PlantConfig {
        &self.config
    }

    /// The measured pose, µm and µrad, rounded.
    pub fn pose(&self) -> Pose {
        let mut p = [0; AXES];
        for (o, x) in p.iter_mut().zip(self.x.iter().chain(&self.rotation)) {
            *o = (x / UM).round() as i32;
        }
        p
    }

    /// The wrist sensor: the contact force on the robot, mN (no torque).
    pub fn wrench(&self) -> Wrench {
        let mut w = [0; AXES];
        for (o, f) in w.iter_mut().zip(self.force) {
            *o = (f * 1000.0).round() as i32;
        }
        w
    }

    /// The range finder: the height of the tip (or the held part's bottom) above the tallest
    /// surface under it, µm, 0 at or below it.
    pub fn range(&self) -> f64 {
        let c = &self.config;
        let tip = [self.x[0] / UM, self.x[1] / UM, self.x[2] / UM];
        let under = |centre: &[f64; 2], half: [f64; 2]| {
            (tip[0] - centre[0]).abs() <= half[0] && (tip[1] - centre[1]).abs() <= half[1]
        };
        let mut surface: f64 = 0.0;
        for p in &self.parts {
            if let PartState::OnPlate(at) = p
                && under(at, [c.part_half_width; 2])
            {
                surface = surface.max(c.part_height);
            }
        }
        for o in &c.obstacles {
            let centre = [(o.min[0] + o.max[0]) / 2.0, (o.min[1] + o.max[1]) / 2.0];
            let half = [(o.max[0] - o.min[0]) / 2.0, (o.max[1] - o.min[1]) / 2.0];
            if under(&centre, half) && o.max[2] <= tip[2] {
                surface = surface.max(o.max[2]);
            }
        }
        let bottom = match self.held() {
            Some(_) => tip[2] - c.part_height,
            None => tip[2],
        };
        (bottom - surface).max(0.0)
    }

    /// The contact force's magnitude, N.
    pub fn force_n(&self) -> f64 {
        self.force.iter().map(|f| f * f).sum::<f64>().sqrt()
    }

    /// Where each part is.
    pub fn parts(&self) -> &[PartState] {
        &self.parts
    }

    /// Parts seated in a hole.
    pub fn inserted(&self) -> usize {
        self.parts
            .iter()
            .filter(|p| matches!(p, PartState::Inserted(_)))
            .count()
    }

    /// Runs the plant for `period_us` under `setpoint`.
    pub fn step(&mut self, setpoint: &Setpoint, period_us: u32) {
        if setpoint.gripper != self.gripper {
            self.gripper = setpoint.gripper;
            match self.gripper {
                Gripper::Closed => self.grasp(),
                Gripper::Open => self.release(),
            }
        }
        let k = f64::from(setpoint.stiffness);
        let d = f64::from(setpoint.damping);
        let attractor = [0, 1, 2].map(|i| f64::from(setpoint.attractor[i]) * UM);
        for (r, a) in self.rotation.iter_mut().zip(&setpoint.attractor[3..]) {
            *r = f64::from(*a) * UM;
        }
        let dt = f64::from(period_us) * 1e-6 / f64::from(SUBSTEPS);
        for _ in 0..SUBSTEPS {
            let contact = self.contact();
            for i in 0..3 {
                let f = k * (attractor[i] - self.x[i]) - d * self.v[i] + contact[i];
                self.v[i] += f / self.config.mass_kg * dt;
                self.x[i] += self.v[i] * dt;
            }
            self.force = contact;
        }
    }

    /// The held part (index and offset from the tip, metres).
    fn held(&self) -> Option<(usize, [f64; 2])> {
        self.parts.iter().enumerate().find_map(|(i, p)| match p {
            PartState::Held(o) => Some((i, [o[0] * UM, o[1] * UM])),
            _ => None,
        })
    }

    /// The contact force on the robot at the current state, N.
    fn contact(&mut self) -> [f64; 3] {
        let c = &self.config;
        let (ks, ds) = (c.contact_stiffness, c.contact_damping);
        let mut f = [0.0; 3];
        let normal = |pen: f64, v: f64| (ks * pen - ds * v).max(0.0);
        match self.held() {
            Some((_, offset)) => {
                let centre = [self.x[0] + offset[0], self.x[1] + offset[1]];
                let bottom = self.x[2] - c.part_height * UM;
                let half_gap = c.clearance * UM;
                if bottom < 0.0 && self.in_hole.is_none() {
                    // Only within the clearance does the part go in: no chamfer.
                    self.in_hole = c.holes.iter().position(|h| {
                        (centre[0] - h[0] * UM).abs() <= half_gap
                            && (centre[1] - h[1] * UM).abs() <= half_gap
                    });
                } else if bottom >= 0.0 {
                    self.in_hole = None;
                }
                match self.in_hole.and_then(|h| c.holes.get(h)) {
                    Some(h) => {
                        for axis in 0..2 {
                            let e = centre[axis] - h[axis] * UM;
                            if e.abs() > half_gap {
                                f[axis] = -ks * (e.abs() - half_gap) * e.signum();
                            }
                        }
                        let floor = -c.hole_depth * UM;
                        if bottom < floor {
                            f[2] = normal(floor - bottom, self.v[2]);
                        }
                    }
                    None if bottom < 0.0 => f[2] = normal(-bottom, self.v[2]),
                    None => {}
                }
            }
            None => {
                // The empty gripper's tip: on the tallest surface under it.
                let mut surface: f64 = 0.0;
                for p in &self.parts {
                    if let PartState::OnPlate(at) = p
                        && (self.x[0] - at[0] * UM).abs() <= c.part_half_width * UM
                        && (self.x[1] - at[1] * UM).abs() <= c.part_half_width * UM
                    {
                        surface = surface.max(c.part_height * UM);
                    }
                }
                if self.x[2] < surface {
                    f[2] = normal(surface - self.x[2], self.v[2]);
                }
            }
        }
        for o in &self.config.obstacles {
            let inside = (0..3).all(|i| self.x[i] > o.min[i] * UM && self.x[i] < o.max[i] * UM);
            if inside {
                // Out along the axis of least penetration.
                let mut best = (f64::INFINITY, 0usize, 0.0f64);
                for i in 0..3 {
                    for (pen, sign) in [
                        (self.x[i] - o.min[i] * UM, -1.0),
                        (o.max[i] * UM - self.x[i], 1.0),
                    ] {
                        if pen < best.0 {
                            best = (pen, i, sign);
                        }
                    }
                }
                let (pen, i, sign) = best;
                f[i] += sign * (ks * pen - ds * self.v[i] * sign).max(0.0);
            }
        }
        f
    }

    fn grasp(&mut self) {
        let c = &self.config;
        let tip = [self.x[0] / UM, self.x[1] / UM, self.x[2] / UM];
        let found = self.parts.iter().position(|p| {
            matches!(p, PartState::OnPlate(at)
                if (at[0] - tip[0]).abs() <= c.grasp_tolerance
                    && (at[1] - tip[1]).abs() <= c.grasp_tolerance
                    && (tip[2] - c.part_height).abs() <= 1000.0)
        });
        if let Some(i) = found
            && let Some(PartState::OnPlate(at)) = self.parts.get(i).copied()
            && let Some(p) = self.parts.get_mut(i)
        {
            *p = PartState::Held([at[0] - tip[0], at[1] - tip[1]]);
        }
    }

    fn release(&mut self) {
        let Some((i, offset)) = self.held() else {
            return;
        };
        let bottom = self.x[2] / UM - self.config.part_height;
        let state = match self.in_hole {
            Some(h) if bottom <= -self.config.insert_depth => PartState::Inserted(h),
            _ => PartState::OnPlate([(self.x[0] + offset[0]) / UM, (self.x[1] + offset[1]) / UM]),
        };
        if let Some(p) = self.parts.get_mut(i) {
            *p = state;
        }
        self.in_hole = None;
    }
}

/// The plant as the bus sees it, without I/O: it reads the board's set-point frames and makes
/// the drive's pose and wrench frames, and its range finder's. `pabctl plant` paces it in real
/// time on a bus; the simulator ([`super::schema`]) and the schema server's replay rig drive it
/// frame by frame in virtual time.
pub struct BusPlant {
    plant: Plant,
    ids: Drive,
    range_finder: Option<SensorTopic>,
    setpoint: Option<Setpoint>,
    partial: (Option<[i32; 3]>, bool, Option<[i32; 3]>),
    received: u64,
}

impl BusPlant {
    /// `config`'s plant in front of `board`: its drive's identifiers, and the sensor
    /// `config.range_finder` names (an index into `board.sensors`, as the simulator reads it).
    pub fn new(board: &SchemaBoard, config: PlantConfig) -> BusPlant {
        let range_finder = config
            .range_finder
            .and_then(|i| board.sensors.get(i))
            .cloned();
        BusPlant {
            plant: Plant::new(config),
            ids: board.drive,
            range_finder,
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

    /// The drive's pose and the wrist's wrench now: four frames (translation, rotation of each),
    /// then the range finder's frame when the plant has one.
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
        .chain(
            self.range_finder
                .as_ref()
                .and_then(|topic| range_frame(topic, self.plant.range())),
        )
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
