//! `[schema.NODE]` and `[client]`: a schema server's board and the workstation client's program
//! (docs/schema-server.md). The `[plant]` of the example, the robot the board drives in
//! simulation, is read by `plant.rs`.
//!
//! ```toml
//! [schema.arm]                 # node `arm` runs a schema server
//! period_ms = 1                # the loop (1 kHz)
//! drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }   # its drive's frames
//! force_limit_n = 30           # the safety limit on |F|
//! workspace_mm = { min = [-200, -200, -20], max = [200, 200, 100] }
//!
//! [schema.arm.sensors.gap]     # an extra sensor: a topic and a field, named in reactions
//! can_id = 0x330
//! value = { offset = 0, size = 2 }
//! scale = 0.01                 # mm per count: the board compares counts
//! unit = "mm"
//!
//! [schema.arm.innate]          # the board's own schemas, installed by reactions
//! careful = "move_to_touch(down, speed=2); done -> high_priority"
//! [schema.arm.places]
//! down = [0, 0, -1]
//!
//! [plant]                      # simulation only: the robot, the plate and the parts
//! parts_mm = [[-100, -60]]     # where the parts stand
//! holes_mm = [[-99.7, 60]]     # where the holes really are
//!
//! [client]                     # the client's program, in the paper's API
//! node = "arm"
//! program = ["move_to(above_part)", "move_to_touch(down)", "grasp()"]
//! [client.places]
//! above_part = [-100, -60, 35] # mm (and mrad for rotations, when six values)
//! down = [0, 0, -1]            # a direction: only its direction counts
//! ```
//!
//! A call is written `name(argument, key=value, …)` with numbers in the units of the client's
//! defaults (mm, mm/s, N, ms, mrad); each becomes one schema made by
//! [`pab_core::schema::build`], so a file's program sends exactly what the Rust and Python
//! clients send for the same calls. Reactions may follow it, `; EVENT -> SOURCE` each
//! (`"move_to(p); below(gap, 5) -> careful"`), placed before the call's own.

use std::collections::HashMap;
use std::ops::Range;

use super::spanned::Spanned;
use indexmap::IndexMap;
use pab_core::OutputId;
use pab_core::schema::{
    AXES, Action, BUILTIN_IDS, Config, Drive, Event, Gripper, Joint, MAX_COORD, MAX_INNATE,
    MAX_REACTIONS, MAX_SENSORS, Measure, Pose, Reaction, Schema, Sensor, Source, build,
};
use schemars::JsonSchema;
use serde::Deserialize;

use super::ports::RawField;
use super::{Builder, Node, list_or_none};

// The sections' parts: the board's keys, the client's program, and the calls both are written in.
mod board;
mod calls;
mod client;
#[cfg(test)]
mod tests;

// What the board's innate schemas and the client's program both read calls with.
use calls::{Made, call_name, is_identifier, is_measure_word};

/// The longest program a file may hold, and the most commands (a typo in a generated file should
/// not run for ever; ids stay below the board's reserved ones).
pub const MAX_CALLS: usize = 10_000;

/// `[schema.NODE]`: a board's set-up.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSchema {
    /// The loop's period in ms, above 0, default 1 (1 kHz).
    period_ms: Option<Spanned<f64>>,
    /// Ms: a tick later than this after the previous one is the overrun safety event (default two
    /// periods; at least period_ms).
    overrun_ms: Option<Spanned<f64>>,
    /// The workspace limit on x, y, z in mm (default ±1000 mm).
    workspace_mm: Option<Spanned<RawBox>>,
    /// The workspace's bound on the three rotations, ± mrad, default 1000.
    rotation_limit_mrad: Option<Spanned<f64>>,
    /// The force safety limit on |F| in N, default 50.
    force_limit_n: Option<Spanned<f64>>,
    /// The torque safety limit on |T| in N·m, default 0 (none).
    torque_limit_nm: Option<Spanned<f64>>,
    /// The highest contact force in N a schema may wait for, default 0 (none).
    contact_limit_n: Option<Spanned<f64>>,
    /// The measured pose's top translation speed in mm/s over a 20 ms window, default 0 (none).
    speed_limit_mm_s: Option<Spanned<f64>>,
    /// The measured pose's top rotation rate in rad/s over a 20 ms window, default 0 (none).
    rate_limit_rad_s: Option<Spanned<f64>>,
    /// Ms after their last reading the pose and wrench are stale (default 20 periods, at least
    /// 50 ms).
    stale_ms: Option<Spanned<f64>>,
    /// The same for the extra sensors, ms (default: as stale_ms).
    sensor_stale_ms: Option<Spanned<f64>>,
    /// A schema's default watchdog budget is 1.5 × its action's nominal time plus this, ms
    /// (default 1000).
    watchdog_margin_ms: Option<Spanned<f64>>,
    /// The drive's top speed on each of x, y, z in mm/s (default 2000): a measured pose that
    /// moved farther is implausible.
    drive_speed_mm_s: Option<Spanned<f64>>,
    /// The drive's top rate on each rotation in rad/s (default 6.283).
    drive_rate_rad_s: Option<Spanned<f64>>,
    /// The pose sensor's noise in mm on x, y, z (and mrad on the rotations), default 1.
    pose_noise_mm: Option<Spanned<f64>>,
    /// The impedance's stiffness at start-up, N/m, default 2000.
    stiffness_n_per_m: Option<Spanned<f64>>,
    /// The impedance's damping at start-up, N·s/m, default 100.
    damping_ns_per_m: Option<Spanned<f64>>,
    /// Required: the drive's frames (docs/can-protocol.md, "The drive's frames").
    drive: Spanned<RawDrive>,
    /// Optional: extra sensors (at most 8, indexed in file order), by the name reactions read:
    /// letters, digits, _, not `contact`, `position`, `displacement` or `force`.
    #[serde(default)]
    sensors: IndexMap<Spanned<String>, Spanned<RawSensor>>,
    /// Optional: places for the innate schemas' calls, as `[client.places]`: name = [x, y, z]
    /// in mm (six values: rotations in mrad too).
    #[serde(default)]
    places: IndexMap<Spanned<String>, Spanned<Vec<f64>>>,
    /// Optional: the board's innate schemas (at most 8): name = a call of `[client]`'s program,
    /// reactions included; a name is letters, digits, _, not `queue` or `high_priority`.
    #[serde(default)]
    innate: IndexMap<Spanned<String>, Spanned<String>>,
}

/// `[schema.NODE.sensors.NAME]`: an extra sensor's topic.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawSensor {
    /// Required: its one identifier, matched exactly: 11-bit, or 29-bit with `extended = true`;
    /// not one of the drive's.
    can_id: Spanned<i64>,
    /// Optional, default false: a 29-bit identifier.
    #[serde(default)]
    extended: bool,
    /// Required: the field that carries the reading (keys as a value port's value).
    value: Spanned<RawField>,
    /// Optional, default 1: `unit`s per count of the field.
    scale: Option<Spanned<f64>>,
    /// Optional: the unit the file's thresholds are written in.
    unit: Option<Spanned<String>>,
    /// Optional: the sensor reads a joint, whose range and top speed are safety limits.
    joint: Option<Spanned<RawJoint>>,
}

/// `joint = { min = -90, max = 90, speed = 60 }`: the sensor reads a joint, whose range (and top
/// speed per second) in the sensor's unit are safety limits.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawJoint {
    /// Required: the joint's lowest reading, in the sensor's unit.
    min: Spanned<f64>,
    /// Required: its highest reading, in the sensor's unit.
    max: Spanned<f64>,
    /// Optional: its top speed per second in the sensor's unit, default none.
    speed: Option<Spanned<f64>>,
}

/// `drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320, extended = false }`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawDrive {
    /// Required: the attractor's identifier (its rotation on +1, the impedance on +2).
    setpoint: Spanned<i64>,
    /// Required: the measured pose's identifier (its rotation on +1).
    pose: Spanned<i64>,
    /// Required: the force's identifier (the torque on +1).
    wrench: Spanned<i64>,
    /// Optional, default false: 29-bit identifiers.
    #[serde(default)]
    extended: bool,
}

/// `workspace_mm = { min = [-200, -200, -20], max = [200, 200, 100] }`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawBox {
    /// Required: the lowest x, y, z, mm.
    min: Spanned<Vec<f64>>,
    /// Required: the highest x, y, z, mm.
    max: Spanned<Vec<f64>>,
}

/// `[client]`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct RawClient {
    /// Required: a node with `[schema.NODE]`.
    node: Spanned<String>,
    /// The calls, sent to the queue in order (e.g. "move_to(above_part)"), each optionally
    /// followed by reactions `; EVENT -> SOURCE`.
    #[serde(default)]
    program: Vec<Spanned<String>>,
    /// Named places and directions: name = [x, y, z] in mm (six values: rotations in mrad too).
    #[serde(default)]
    places: IndexMap<Spanned<String>, Spanned<Vec<f64>>>,
    /// Optional: calls at a time, on the high-priority channel.
    #[serde(default)]
    commands: Vec<Spanned<RawCommand>>,
    /// move_to's speed, mm/s, default 50.
    speed_mm_s: Option<Spanned<f64>>,
    /// move_to_touch's speed, mm/s, default 5.
    touch_speed_mm_s: Option<Spanned<f64>>,
    /// move_to_touch's contact force, N, default 3.
    contact_n: Option<Spanned<f64>>,
    /// move_to_touch's distance, mm, default 50.
    touch_distance_mm: Option<Spanned<f64>>,
    /// grasp's and release's settling time, ms, default 200.
    settle_ms: Option<Spanned<f64>>,
    /// blind_search's preload, mm, default 2.
    preload_mm: Option<Spanned<f64>>,
    /// blind_search's spiral pitch, mm, default 0.08.
    pitch_mm: Option<Spanned<f64>>,
    /// blind_search's speed, mm/s, default 2.
    search_speed_mm_s: Option<Spanned<f64>>,
    /// blind_search's radius, mm, default 1 (sets its watchdog budget).
    search_radius_mm: Option<Spanned<f64>>,
    /// blind_search's wobble about z, mrad, default 20.
    wobble_mrad: Option<Spanned<f64>>,
    /// blind_search's wobble period, ms, default 500.
    wobble_period_ms: Option<Spanned<f64>>,
    /// blind_search's depth (the part's drop that ends it), mm, default 1.
    insert_depth_mm: Option<Spanned<f64>>,
}

/// `[[client.commands]] at = 12.0, call = "estop()"`.
#[derive(Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
struct RawCommand {
    /// Required: when, in seconds.
    at: Spanned<f64>,
    /// Required: estop(), abort(), or any call (a schema installed at once).
    call: Spanned<String>,
}

/// A schema server's board (`[schema.NODE]`).
#[derive(Clone, Debug, PartialEq)]
pub struct SchemaBoard {
    /// Its node, as an index into [`super::Network::nodes`].
    pub node: usize,
    /// The server's set-up (its innate schemas included, in file order).
    pub config: Config,
    /// The drive's frames' identifiers.
    pub drive: Drive,
    /// Its extra sensors, in file order (their index in the server's sensor table).
    pub sensors: Vec<SensorTopic>,
    /// The innate schemas' names, by index.
    pub innate: Vec<String>,
    /// Where it is defined.
    pub span: Range<usize>,
}

/// An extra sensor of a board (`[schema.NODE.sensors.NAME]`): what the board reads, and how
/// the file's numbers relate to it.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorTopic {
    /// Its name in events (`above(NAME, 5)`).
    pub name: String,
    /// Its topic and field, as the board reads them.
    pub sensor: Sensor,
    /// `unit`s per count of the field: the board compares counts, the file writes units.
    pub scale: f64,
    /// The unit the file's thresholds are written in (text, for messages and plots).
    pub unit: String,
    /// The joint it reads, when it has limits (`joint = { … }`), in counts.
    pub joint: Option<Joint>,
}

/// The first id of the innate schemas: innate schema i has id `INNATE_IDS + i`, below the
/// server's own and above any a program's calls take.
pub const INNATE_IDS: u16 = BUILTIN_IDS - MAX_INNATE as u16;

/// The names a call's reactions may use: the board's sensors and innate schemas.
#[derive(Clone, Copy, Default)]
struct Names<'a> {
    sensors: &'a [SensorTopic],
    innate: &'a [String],
}

/// One call of the client's program: the schema it sends, and its name in traces.
#[derive(Clone, Debug, PartialEq)]
pub struct Call {
    /// The call as written (`move_to(above_part_1)`, `grasp()`, …).
    pub name: String,
    /// The schema (its id is the client's: the call's position, from 1).
    pub schema: Schema,
}

/// What the client sends besides its program.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// A schema on the high-priority channel.
    HighPriority(Box<Call>),
    /// Abort.
    Abort,
    /// The emergency-stop frame.
    EmergencyStop,
}

/// A command and when it reaches the board, µs.
#[derive(Clone, Debug, PartialEq)]
pub struct Timed {
    /// When, µs.
    pub t_us: u64,
    /// What.
    pub command: Command,
}

/// The client (`[client]`).
#[derive(Clone, Debug, PartialEq)]
pub struct Client {
    /// The board it programs, as an index into [`super::Network::nodes`].
    pub node: usize,
    /// Its program, in order.
    pub program: Vec<Call>,
    /// Its timed commands, in time order.
    pub commands: Vec<Timed>,
    /// The named places and directions (µm, µrad).
    pub places: Vec<(String, Pose)>,
    /// The defaults its calls use.
    pub defaults: Defaults,
}

/// The client's defaults: the paper's API's optional arguments, in the board's units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Defaults {
    /// `move_to`'s speed, µm/s (50 mm/s).
    pub speed: u32,
    /// `move_to_touch`'s speed, µm/s (5 mm/s).
    pub touch_speed: u32,
    /// `move_to_touch`'s contact threshold, mN (3 N).
    pub contact: i32,
    /// `move_to_touch`'s farthest travel, µm (50 mm).
    pub touch_distance: u32,
    /// `grasp` and `release`'s settling time, ms (200).
    pub settle_ms: u32,
    /// `blind_search`'s preload, µm (2 mm).
    pub preload: u32,
    /// Its spiral's pitch, µm (0.08 mm: at most twice the clearance).
    pub pitch: u32,
    /// Its speed along the spiral, µm/s (2 mm/s).
    pub search_speed: u32,
    /// The half-width it is expected to cover, µm (1 mm): its watchdog budget.
    pub search_radius: u32,
    /// Its rocking about z, µrad (20 mrad).
    pub wobble: u32,
    /// The rocking's period, ms (500).
    pub wobble_ms: u32,
    /// How far the part must drop for the search to end, µm (1 mm).
    pub insert_depth: u32,
}

impl Default for Defaults {
    fn default() -> Self {
        Defaults {
            speed: 50_000,
            touch_speed: 5_000,
            contact: 3_000,
            touch_distance: 50_000,
            settle_ms: 200,
            preload: 2_000,
            pitch: 80,
            search_speed: 2_000,
            search_radius: 1_000,
            wobble: 20_000,
            wobble_ms: 500,
            insert_depth: 1_000,
        }
    }
}

/// The calls a program may hold, with their arguments: for `--help`-like messages.
pub const CALLS: &str = "move_to(PLACE, speed=mm/s), move_to_touch(DIRECTION, speed=mm/s, contact=N, distance=mm), \
     grasp(settle=ms), release(settle=ms), blind_search(preload=mm, pitch=mm, speed=mm/s, radius=mm, wobble=mrad, period=ms, depth=mm), \
     idle(ms), open(), close(), relieve(), set_impedance(stiffness=N/m, damping=Ns/m); any of them also watchdog=ms";
