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

/// A call parsed: its name, positional arguments and keyword arguments, with the byte offset of
/// each within the call's text.
struct Parsed<'a> {
    name: &'a str,
    positional: Vec<(&'a str, usize)>,
    keywords: Vec<(&'a str, &'a str, usize)>,
}

/// Splits `name(a, k=v, …)`; the error names the offending column's cause.
fn split_call(text: &str) -> Result<Parsed<'_>, (usize, String)> {
    let open = text.find('(').ok_or((
        0,
        "a call is written `name(arguments)`, for example `grasp()`".to_string(),
    ))?;
    let name = text[..open].trim();
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err((0, format!("`{}` is not a call's name", name)));
    }
    let inner = text[open + 1..].trim_end();
    let Some(inner) = inner.strip_suffix(')') else {
        return Err((text.len(), "the call's `)` is missing".to_string()));
    };
    let mut positional = Vec::new();
    let mut keywords = Vec::new();
    let mut offset = open + 1;
    if !inner.trim().is_empty() {
        for part in inner.split(',') {
            let at = offset + (part.len() - part.trim_start().len());
            offset += part.len() + 1;
            let part = part.trim();
            if part.is_empty() {
                return Err((at, "an empty argument".to_string()));
            }
            match part.split_once('=') {
                Some((k, v)) => keywords.push((k.trim(), v.trim(), at)),
                None if keywords.is_empty() => positional.push((part, at)),
                None => {
                    return Err((
                        at,
                        format!("`{part}`: positional arguments come before keywords"),
                    ));
                }
            }
        }
    }
    Ok(Parsed {
        name,
        positional,
        keywords,
    })
}

/// The calls a program may hold, with their arguments: for `--help`-like messages.
pub const CALLS: &str = "move_to(PLACE, speed=mm/s), move_to_touch(DIRECTION, speed=mm/s, contact=N, distance=mm), \
     grasp(settle=ms), release(settle=ms), blind_search(preload=mm, pitch=mm, speed=mm/s, radius=mm, wobble=mrad, period=ms, depth=mm), \
     idle(ms), open(), close(), relieve(), set_impedance(stiffness=N/m, damping=Ns/m); any of them also watchdog=ms";

impl Builder<'_> {
    pub(super) fn schema_boards(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawSchema>>,
        nodes: &[Node],
    ) -> Vec<SchemaBoard> {
        let mut boards = Vec::new();
        for (name, section) in raw {
            let Some(node) = nodes.iter().position(|n| &n.name == name.get_ref()) else {
                let known: Vec<&str> = nodes.iter().map(|n| n.name.as_str()).collect();
                self.error(
                    name.span(),
                    format!(
                        "[schema.{}]: node `{}` is not defined (nodes: {})",
                        name.get_ref(),
                        name.get_ref(),
                        list_or_none(&known)
                    ),
                );
                continue;
            };
            if !boards.is_empty() {
                self.error(
                    name.span(),
                    "one schema server per network file: the simulator drives one plant with one client",
                );
                continue;
            }
            let raw = section.get_ref();
            let errors = self.errors.len();
            let drive = self.drive(&raw.drive);
            let sensors = self.sensors(&raw.sensors, drive.as_ref());
            let places = self.places(&raw.places);
            let innate = self.innate(raw, name.get_ref(), &sensors, &places);
            if let (Some(mut config), Some(drive)) = (self.schema_config(raw), drive)
                && self.errors.len() == errors
            {
                // The joints' limits, from their sensors (at most MAX_SENSORS = MAX_JOINTS).
                for joint in sensors.iter().filter_map(|s| s.joint) {
                    let _ = config.limits.joints.push(joint);
                }
                let mut names = Vec::new();
                for (name, schema) in innate {
                    // `innate` took at most MAX_INNATE.
                    let _ = config.innate.push(schema);
                    names.push(name);
                }
                boards.push(SchemaBoard {
                    node,
                    config,
                    drive,
                    sensors,
                    innate: names,
                    span: section.span(),
                });
            }
        }
        boards
    }

    /// `[schema.NODE.sensors.NAME]`: each a topic on its own identifier or sharing one (each
    /// its own field), off the drive's frames.
    fn sensors(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<RawSensor>>,
        drive: Option<&Drive>,
    ) -> Vec<SensorTopic> {
        let mut out = Vec::new();
        if raw.len() > MAX_SENSORS {
            if let Some((name, _)) = raw.get_index(MAX_SENSORS) {
                self.error(
                    name.span(),
                    format!(
                        "sensors: {} of them; a board reads at most {MAX_SENSORS}",
                        raw.len()
                    ),
                );
            }
            return out;
        }
        for (name, section) in raw {
            let s = section.get_ref();
            let what = format!("sensor `{}`", name.get_ref());
            if !self.printable(name, "sensor name") {
                continue;
            }
            if !is_identifier(name.get_ref()) || is_measure_word(name.get_ref()) {
                self.error(
                    name.span(),
                    format!(
                        "{what}: a sensor's name is letters, digits and _ (not starting with a digit), \
                         and not `contact`, `position`, `displacement` or `force`"
                    ),
                );
                continue;
            }
            let id = u32::try_from(*s.can_id.get_ref())
                .ok()
                .and_then(|v| OutputId::new(v, s.extended).ok());
            let Some(id) = id else {
                let max = if s.extended { "0x1FFFFFFF" } else { "0x7FF" };
                self.error(
                    s.can_id.span(),
                    format!("{what}: can_id is 0..={max} (extended = {})", s.extended),
                );
                continue;
            };
            let on_drive = drive.is_some_and(|d| {
                [(d.setpoint, 3), (d.pose, 2), (d.wrench, 2)]
                    .iter()
                    .any(|(base, n)| {
                        base.is_extended() == id.is_extended()
                            && id.raw().wrapping_sub(base.raw()) < *n
                    })
            });
            if on_drive {
                self.error(
                    s.can_id.span(),
                    format!("{what}: can_id is one of the drive's frames"),
                );
                continue;
            }
            if pab_core::protocol::classify_id(&id.id()).is_ours() {
                self.error(
                    s.can_id.span(),
                    format!(
                        "{what}: can_id is in the project's own protocol space (29-bit ids with 0b10 in bits 25..24)"
                    ),
                );
                continue;
            }
            let Some(field) = self.field(&s.value, &format!("{what}: value")) else {
                continue;
            };
            let scale = match &s.scale {
                None => 1.0,
                Some(v) if v.get_ref().is_finite() && *v.get_ref() > 0.0 => *v.get_ref(),
                Some(v) => {
                    self.error(
                        v.span(),
                        format!("{what}: scale is a positive number (units per count)"),
                    );
                    continue;
                }
            };
            let unit = match &s.unit {
                None => String::new(),
                Some(u) if self.printable(u, "unit") => u.get_ref().clone(),
                Some(_) => continue,
            };
            let joint = match &s.joint {
                Some(j) => match self.joint(j, out.len(), field.range(), scale, &what, &unit) {
                    Some(joint) => Some(joint),
                    None => continue,
                },
                None => None,
            };
            out.push(SensorTopic {
                name: name.get_ref().clone(),
                sensor: Sensor { id, field },
                scale,
                unit,
                joint,
            });
        }
        out
    }

    /// `joint = { min, max, speed }` of sensor `index` (its field's `range` of counts, `scale`
    /// units a count): the range in whole counts within the file's (the bounds rounded inwards),
    /// the speed in counts per second (rounded down, at least 1).
    fn joint(
        &mut self,
        raw: &Spanned<RawJoint>,
        index: usize,
        range: (i64, i64),
        scale: f64,
        what: &str,
        unit: &str,
    ) -> Option<Joint> {
        let j = raw.get_ref();
        let errors = self.errors.len();
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        let (low, high) = (range.0 as f64, range.1 as f64);
        // Within rounding of a whole count it is that count (0.3 / 0.1 is 2.999…).
        let counts = |v: f64, inwards: fn(f64) -> f64| {
            let c = v / scale;
            if (c - c.round()).abs() <= 1e-9 * c.abs().max(1.0) {
                c.round()
            } else {
                inwards(c)
            }
        };
        let bound = |this: &mut Self, v: &Spanned<f64>, name: &str, inwards: fn(f64) -> f64| {
            let c = counts(*v.get_ref(), inwards);
            if !c.is_finite() || c < low || c > high {
                this.error(
                    v.span(),
                    format!(
                        "{what}: joint.{name} is outside what the sensor reads ({} to {}{unit})",
                        low * scale,
                        high * scale
                    ),
                );
                0
            } else {
                c as i32
            }
        };
        let min = bound(self, &j.min, "min", f64::ceil);
        let max = bound(self, &j.max, "max", f64::floor);
        if self.errors.len() == errors && min > max {
            self.error(
                raw.span(),
                format!("{what}: joint.min is above joint.max (in whole counts of the sensor)"),
            );
        }
        let rate = match &j.speed {
            None => 0,
            Some(v) => {
                let c = (*v.get_ref() / scale).floor();
                if !c.is_finite() || c < 1.0 || c > f64::from(u32::MAX) {
                    self.error(
                        v.span(),
                        format!(
                            "{what}: joint.speed is at least one count a second ({scale}{unit} a second)"
                        ),
                    );
                }
                c.clamp(0.0, f64::from(u32::MAX)) as u32
            }
        };
        (self.errors.len() == errors).then_some(Joint {
            sensor: index as u8,
            min,
            max,
            rate,
        })
    }

    /// Named places and directions (`[client.places]`, `[schema.NODE.places]`), µm and µrad.
    fn places(
        &mut self,
        raw: &IndexMap<Spanned<String>, Spanned<Vec<f64>>>,
    ) -> Vec<(String, Pose)> {
        let mut places = Vec::new();
        let mut seen = HashMap::new();
        for (name, value) in raw {
            if !self.printable(name, "place name") {
                continue;
            }
            if seen.insert(name.get_ref().clone(), ()).is_some() {
                continue;
            }
            if let Some(p) = self.point(value, &format!("place `{}`", name.get_ref()), 3) {
                places.push((name.get_ref().clone(), p));
            }
        }
        places
    }

    /// `[schema.NODE.innate]`: `NAME = "CALL; EVENT -> SOURCE; …"`, by index in file order, with
    /// the built-in defaults (a board has no client's).
    fn innate(
        &mut self,
        raw: &RawSchema,
        node: &str,
        sensors: &[SensorTopic],
        places: &[(String, Pose)],
    ) -> Vec<(String, Schema)> {
        if raw.innate.len() > MAX_INNATE {
            if let Some((name, _)) = raw.innate.get_index(MAX_INNATE) {
                self.error(
                    name.span(),
                    format!(
                        "[schema.{node}.innate]: {} schemas; a board stores at most {MAX_INNATE}",
                        raw.innate.len()
                    ),
                );
            }
            return Vec::new();
        }
        let names: Vec<String> = raw.innate.keys().map(|k| k.get_ref().clone()).collect();
        let mut out = Vec::new();
        for (i, (name, text)) in raw.innate.iter().enumerate() {
            if !self.printable(name, "innate schema name") {
                continue;
            }
            if !is_identifier(name.get_ref())
                || matches!(name.get_ref().as_str(), "queue" | "high_priority")
            {
                self.error(
                    name.span(),
                    format!(
                        "innate schema `{}`: a name is letters, digits and _ (not starting with a digit), and not `queue` or `high_priority`",
                        name.get_ref()
                    ),
                );
                continue;
            }
            let vocabulary = Names {
                sensors,
                innate: &names,
            };
            let id = INNATE_IDS + i as u16;
            if let Some(Made::Schema(schema)) =
                self.call(text, id, places, &Defaults::default(), false, vocabulary)
            {
                out.push((name.get_ref().clone(), *schema));
            }
        }
        out
    }

    /// The drive's identifiers: each a base with the frames after it (setpoint 3, pose and
    /// wrench 2), within the format, apart, and outside our protocol's identifiers.
    fn drive(&mut self, raw: &Spanned<RawDrive>) -> Option<Drive> {
        let d = raw.get_ref();
        let mut ids = Vec::new();
        for (value, what) in [
            (&d.setpoint, "setpoint"),
            (&d.pose, "pose"),
            (&d.wrench, "wrench"),
        ] {
            let id = u32::try_from(*value.get_ref())
                .ok()
                .and_then(|v| OutputId::new(v, d.extended).ok());
            match id {
                Some(id) => ids.push(id),
                None => {
                    let max = if d.extended { "0x1FFFFFFF" } else { "0x7FF" };
                    self.error(
                        value.span(),
                        format!(
                            "drive.{what}: an identifier is 0..={max} (extended = {})",
                            d.extended
                        ),
                    );
                    return None;
                }
            }
        }
        let [setpoint, pose, wrench] = [ids[0], ids[1], ids[2]];
        let drive = Drive {
            setpoint,
            pose,
            wrench,
        };
        if let Err(e) = drive.check() {
            self.error(
                raw.span(),
                format!(
                    "drive: {e} (the set-point takes 3 identifiers from its own, the pose and the wrench 2 each)"
                ),
            );
            return None;
        }
        if [setpoint, pose, wrench]
            .iter()
            .any(|id| pab_core::protocol::classify_id(&id.id()).is_ours())
        {
            self.error(
                raw.span(),
                "drive: an identifier in the project's own protocol space (29-bit ids with 0b10 in bits 25..24)",
            );
            return None;
        }
        Some(drive)
    }

    /// A positive amount in `[min, max]` of a unit, scaled to an integer (rounded).
    fn scaled(
        &mut self,
        value: Option<&Spanned<f64>>,
        scale: f64,
        default: u32,
        what: &str,
        unit: &str,
        allow_zero: bool,
    ) -> u32 {
        let Some(value) = value else {
            return default;
        };
        let v = *value.get_ref() * scale;
        let max = f64::from(MAX_COORD);
        if !v.is_finite() || v < 0.0 || v > max || (!allow_zero && v.round() < 1.0) {
            let lowest = if allow_zero { "0" } else { "above 0" };
            self.error(
                value.span(),
                format!("{what} must be {lowest} and at most {} {unit}", max / scale),
            );
            return default;
        }
        v.round() as u32
    }

    fn schema_config(&mut self, raw: &RawSchema) -> Option<Config> {
        let errors = self.errors.len();
        let period = self.scaled(
            raw.period_ms.as_ref(),
            1000.0,
            1000,
            "period_ms",
            "ms",
            false,
        );
        let mut config = Config::new(period);
        config.overrun_us = self.scaled(
            raw.overrun_ms.as_ref(),
            1000.0,
            config.overrun_us,
            "overrun_ms",
            "ms",
            false,
        );
        if let Some(o) = &raw.overrun_ms
            && config.overrun_us < config.period_us
        {
            self.error(o.span(), "overrun_ms must be at least period_ms");
        }
        let rotation = self.scaled(
            raw.rotation_limit_mrad.as_ref(),
            1000.0,
            1_000_000,
            "rotation_limit_mrad",
            "mrad",
            false,
        ) as i32;
        let limits = &mut config.limits;
        limits.workspace_min = [
            -1_000_000, -1_000_000, -1_000_000, -rotation, -rotation, -rotation,
        ];
        limits.workspace_max = [
            1_000_000, 1_000_000, 1_000_000, rotation, rotation, rotation,
        ];
        if let Some(w) = &raw.workspace_mm {
            let min = self.point(&w.get_ref().min, "workspace_mm.min", 3);
            let max = self.point(&w.get_ref().max, "workspace_mm.max", 3);
            if let (Some(min), Some(max)) = (min, max) {
                if min.iter().zip(&max).take(3).any(|(lo, hi)| lo > hi) {
                    self.error(w.span(), "workspace_mm: min is above max on some axis");
                }
                config.limits.workspace_min[..3].copy_from_slice(&min[..3]);
                config.limits.workspace_max[..3].copy_from_slice(&max[..3]);
            }
        }
        config.limits.force_limit = self.scaled(
            raw.force_limit_n.as_ref(),
            1000.0,
            config.limits.force_limit,
            "force_limit_n",
            "N",
            false,
        );
        config.limits.torque_limit = self.scaled(
            raw.torque_limit_nm.as_ref(),
            1000.0,
            0,
            "torque_limit_nm",
            "N·m",
            true,
        );
        // The bounds 0 leaves off: a contact threshold, the pose's speed and rate.
        config.limits.contact_limit = self.scaled(
            raw.contact_limit_n.as_ref(),
            1000.0,
            0,
            "contact_limit_n",
            "N",
            true,
        );
        config.limits.speed_limit = self.scaled(
            raw.speed_limit_mm_s.as_ref(),
            1000.0,
            0,
            "speed_limit_mm_s",
            "mm/s",
            true,
        );
        config.limits.rate_limit = self.scaled(
            raw.rate_limit_rad_s.as_ref(),
            1_000_000.0,
            0,
            "rate_limit_rad_s",
            "rad/s",
            true,
        );
        config.stale_us = self.scaled(
            raw.stale_ms.as_ref(),
            1000.0,
            config.stale_us,
            "stale_ms",
            "ms",
            false,
        );
        config.sensor_stale_us = self.scaled(
            raw.sensor_stale_ms.as_ref(),
            1000.0,
            config.sensor_stale_us,
            "sensor_stale_ms",
            "ms",
            false,
        );
        config.watchdog_margin_ms = self.scaled(
            raw.watchdog_margin_ms.as_ref(),
            1.0,
            config.watchdog_margin_ms,
            "watchdog_margin_ms",
            "ms",
            true,
        );
        // The drive's own limits: a pose frame that jumps farther is implausible.
        config.drive_speed = self.scaled(
            raw.drive_speed_mm_s.as_ref(),
            1000.0,
            config.drive_speed,
            "drive_speed_mm_s",
            "mm/s",
            false,
        );
        config.drive_rate = self.scaled(
            raw.drive_rate_rad_s.as_ref(),
            1_000_000.0,
            config.drive_rate,
            "drive_rate_rad_s",
            "rad/s",
            false,
        );
        config.pose_noise = self.scaled(
            raw.pose_noise_mm.as_ref(),
            1000.0,
            config.pose_noise,
            "pose_noise_mm",
            "mm",
            true,
        );
        config.stiffness = self.scaled(
            raw.stiffness_n_per_m.as_ref(),
            1.0,
            config.stiffness,
            "stiffness_n_per_m",
            "N/m",
            false,
        );
        config.damping = self.scaled(
            raw.damping_ns_per_m.as_ref(),
            1.0,
            config.damping,
            "damping_ns_per_m",
            "N·s/m",
            true,
        );
        (self.errors.len() == errors).then_some(config)
    }

    /// A point in mm (three values; six with rotations in mrad) as a pose in µm and µrad.
    pub(super) fn point(
        &mut self,
        value: &Spanned<Vec<f64>>,
        what: &str,
        least: usize,
    ) -> Option<Pose> {
        let v = value.get_ref();
        if v.len() != least && v.len() != AXES {
            self.error(
                value.span(),
                format!(
                    "{what}: {} values; write [x, y, z] in mm{}",
                    v.len(),
                    if least == 3 {
                        ", or six with rotations about x, y, z in mrad"
                    } else {
                        ""
                    }
                ),
            );
            return None;
        }
        let mut p = [0; AXES];
        for (o, c) in p.iter_mut().zip(v) {
            let um = c * 1000.0;
            if !um.is_finite() || um.abs() > f64::from(MAX_COORD) {
                self.error(
                    value.span(),
                    format!("{what}: {c} is beyond ±{} mm", MAX_COORD / 1000),
                );
                return None;
            }
            *o = um.round() as i32;
        }
        Some(p)
    }

    pub(super) fn client(
        &mut self,
        raw: Option<&Spanned<RawClient>>,
        nodes: &[Node],
        boards: &[SchemaBoard],
        declared: &[&str],
    ) -> Option<Client> {
        let raw_span = raw?.span();
        let raw = raw?.get_ref();
        let errors = self.errors.len();
        let node = nodes.iter().position(|n| &n.name == raw.node.get_ref());
        match node {
            None => {
                let known: Vec<&str> = boards
                    .iter()
                    .filter_map(|b| nodes.get(b.node).map(|n| n.name.as_str()))
                    .collect();
                self.error(
                    raw.node.span(),
                    format!(
                        "[client] node `{}` is not defined (schema servers: {})",
                        raw.node.get_ref(),
                        list_or_none(&known)
                    ),
                );
            }
            // A board whose section has mistakes is reported there, not here again.
            Some(_) if declared.iter().any(|d| d == raw.node.get_ref()) => {}
            Some(n) if !boards.iter().any(|b| b.node == n) => self.error(
                raw.node.span(),
                format!(
                    "[client] node `{}` runs no schema server: add a [schema.{}] section",
                    raw.node.get_ref(),
                    raw.node.get_ref()
                ),
            ),
            Some(_) => {}
        }
        let mut d = Defaults::default();
        d.speed = self.scaled(
            raw.speed_mm_s.as_ref(),
            1000.0,
            d.speed,
            "speed_mm_s",
            "mm/s",
            false,
        );
        d.touch_speed = self.scaled(
            raw.touch_speed_mm_s.as_ref(),
            1000.0,
            d.touch_speed,
            "touch_speed_mm_s",
            "mm/s",
            false,
        );
        d.contact = self.scaled(
            raw.contact_n.as_ref(),
            1000.0,
            d.contact as u32,
            "contact_n",
            "N",
            false,
        ) as i32;
        d.touch_distance = self.scaled(
            raw.touch_distance_mm.as_ref(),
            1000.0,
            d.touch_distance,
            "touch_distance_mm",
            "mm",
            false,
        );
        d.settle_ms = self.scaled(
            raw.settle_ms.as_ref(),
            1.0,
            d.settle_ms,
            "settle_ms",
            "ms",
            true,
        );
        d.preload = self.scaled(
            raw.preload_mm.as_ref(),
            1000.0,
            d.preload,
            "preload_mm",
            "mm",
            true,
        );
        d.pitch = self.scaled(
            raw.pitch_mm.as_ref(),
            1000.0,
            d.pitch,
            "pitch_mm",
            "mm",
            false,
        );
        d.search_speed = self.scaled(
            raw.search_speed_mm_s.as_ref(),
            1000.0,
            d.search_speed,
            "search_speed_mm_s",
            "mm/s",
            false,
        );
        d.search_radius = self.scaled(
            raw.search_radius_mm.as_ref(),
            1000.0,
            d.search_radius,
            "search_radius_mm",
            "mm",
            false,
        );
        d.wobble = self.scaled(
            raw.wobble_mrad.as_ref(),
            1000.0,
            d.wobble,
            "wobble_mrad",
            "mrad",
            true,
        );
        d.wobble_ms = self.scaled(
            raw.wobble_period_ms.as_ref(),
            1.0,
            d.wobble_ms,
            "wobble_period_ms",
            "ms",
            false,
        );
        d.insert_depth = self.scaled(
            raw.insert_depth_mm.as_ref(),
            1000.0,
            d.insert_depth,
            "insert_depth_mm",
            "mm",
            false,
        );

        let places = self.places(&raw.places);
        let board = node.and_then(|n| boards.iter().find(|b| b.node == n));
        let vocabulary = board.map_or_else(Names::default, |b| Names {
            sensors: &b.sensors,
            innate: &b.innate,
        });
        if raw.program.len() > MAX_CALLS {
            self.error(
                raw_span.clone(),
                format!(
                    "{} calls: a program holds at most {MAX_CALLS}",
                    raw.program.len()
                ),
            );
        }
        let mut program = Vec::new();
        for text in raw.program.iter().take(MAX_CALLS) {
            let id = program.len() as u16 + 1;
            if let Some(Made::Schema(schema)) = self.call(text, id, &places, &d, false, vocabulary)
            {
                program.push(Call {
                    name: call_name(text.get_ref()),
                    schema: *schema,
                });
            }
        }
        if raw.commands.len() > MAX_CALLS {
            self.error(
                raw_span.clone(),
                format!(
                    "{} commands: a client holds at most {MAX_CALLS}",
                    raw.commands.len()
                ),
            );
        }
        let mut commands: Vec<Timed> = Vec::new();
        for (k, c) in raw.commands.iter().take(MAX_CALLS).enumerate() {
            let c = c.get_ref();
            let Some(at) = self.time(&c.at, "a command's `at`") else {
                continue;
            };
            // High-priority schemas are numbered after the program's.
            let id = (raw.program.len().min(MAX_CALLS) + k + 1) as u16;
            let command = match self.call(&c.call, id, &places, &d, true, vocabulary) {
                Some(Made::Schema(schema)) => Command::HighPriority(Box::new(Call {
                    name: call_name(c.call.get_ref()),
                    schema: *schema,
                })),
                Some(Made::Abort) => Command::Abort,
                Some(Made::EmergencyStop) => Command::EmergencyStop,
                None => continue,
            };
            commands.push(Timed {
                t_us: crate::time::micros(at),
                command,
            });
        }
        commands.sort_by_key(|t| t.t_us);
        if self.errors.len() != errors {
            return None;
        }
        Some(Client {
            node: node?,
            program,
            commands,
            places,
            defaults: d,
        })
    }

    /// One call's schema (with id `id`), or, among commands, an abort or emergency stop.
    ///
    /// `CALL; EVENT -> SOURCE; …`: the reactions written after the call come before the call's
    /// own (the first that holds wins, so `done -> high_priority` there replaces a call's
    /// `done -> queue`).
    fn call(
        &mut self,
        text: &Spanned<String>,
        id: u16,
        places: &[(String, Pose)],
        d: &Defaults,
        command: bool,
        names: Names<'_>,
    ) -> Option<Made> {
        // The string's content starts after its opening quote.
        let base = text.span().start + 1;
        let at = |offset: usize| base + offset..base + offset + 1;
        let full = text.get_ref().as_str();
        let (call_text, reactions_at) = match full.find(';') {
            Some(i) => (&full[..i], Some(i + 1)),
            None => (full, None),
        };
        let parsed = match split_call(call_text) {
            Ok(p) => p,
            Err((offset, message)) => {
                self.error(at(offset), message);
                return None;
            }
        };
        let mut written = Vec::new();
        if let Some(start) = reactions_at {
            let mut offset = start;
            for part in full[start..].split(';') {
                let lead = part.len() - part.trim_start().len();
                match reaction(part.trim(), names) {
                    Ok(r) => written.push(r),
                    Err((o, message)) => {
                        self.error(at(offset + lead + o), message);
                        return None;
                    }
                }
                offset += part.len() + 1;
            }
            if command && matches!(parsed.name, "estop" | "abort") {
                self.error(
                    at(start),
                    format!(
                        "`{}()` is a command, not a schema: it takes no reactions",
                        parsed.name
                    ),
                );
                return None;
            }
        }
        let mut args: HashMap<&str, (f64, usize)> = HashMap::new();
        for (k, v, offset) in &parsed.keywords {
            match v.parse::<f64>() {
                Ok(x) if x.is_finite() && x >= 0.0 => {
                    args.insert(k, (x, *offset));
                }
                _ => {
                    self.error(
                        at(*offset),
                        format!("`{k}={v}`: a keyword's value is a number, 0 or more"),
                    );
                    return None;
                }
            }
        }
        let allowed: &[&str] = match parsed.name {
            "move_to" => &["speed"],
            "move_to_touch" => &["speed", "contact", "distance"],
            "grasp" | "release" => &["settle"],
            "blind_search" => &[
                "preload", "pitch", "speed", "radius", "wobble", "period", "depth",
            ],
            "set_impedance" => &["stiffness", "damping"],
            _ => &[],
        };
        for (k, _, offset) in &parsed.keywords {
            if *k != "watchdog" && !allowed.contains(k) {
                self.error(
                    at(*offset),
                    format!(
                        "`{}` takes no `{k}` (it takes: {})",
                        parsed.name,
                        list_or_none(allowed)
                    ),
                );
                return None;
            }
        }
        let positional = |n: usize| parsed.positional.get(n).copied();
        let expect_args = |b: &mut Self, n: usize| -> bool {
            if let Some((extra, offset)) = positional(n) {
                b.error(
                    at(offset),
                    format!(
                        "`{}` takes {n} positional argument{}; `{extra}` is one too many",
                        parsed.name,
                        if n == 1 { "" } else { "s" }
                    ),
                );
                false
            } else {
                true
            }
        };
        // mm (or mm/s, N) → µm (µm/s, mN); ms stay ms; mrad → µrad.
        let scaled = |b: &mut Self, key: &str, scale: f64, default: u32| -> Option<u32> {
            let Some((v, offset)) = args.get(key).copied() else {
                return Some(default);
            };
            let x = (v * scale).round();
            if x > f64::from(MAX_COORD) {
                b.error(at(offset), format!("`{key}` is too large"));
                return None;
            }
            Some(x as u32)
        };
        let place = |b: &mut Self, what: &str| -> Option<Pose> {
            let Some((name, offset)) = positional(0) else {
                b.error(
                    at(0),
                    format!(
                        "`{}` needs a {what}: `{}({what})`",
                        parsed.name, parsed.name
                    ),
                );
                return None;
            };
            match places.iter().find(|(n, _)| n == name) {
                Some((_, p)) => Some(*p),
                None => {
                    let known: Vec<&str> = places.iter().map(|(n, _)| n.as_str()).collect();
                    b.error(
                        at(offset),
                        format!(
                            "place `{name}` is not in [client.places] ({})",
                            list_or_none(&known)
                        ),
                    );
                    None
                }
            }
        };
        let mut schema = match parsed.name {
            "estop" | "abort" if command => {
                if !expect_args(self, 0) {
                    return None;
                }
                return Some(if parsed.name == "estop" {
                    Made::EmergencyStop
                } else {
                    Made::Abort
                });
            }
            "move_to" => {
                let goal = place(self, "PLACE")?;
                if !expect_args(self, 1) {
                    return None;
                }
                let speed = scaled(self, "speed", 1000.0, d.speed)?;
                build::move_to(id, goal, speed)
            }
            "move_to_touch" => {
                let direction = place(self, "DIRECTION")?;
                if !expect_args(self, 1) {
                    return None;
                }
                let speed = scaled(self, "speed", 1000.0, d.touch_speed)?;
                let contact = scaled(self, "contact", 1000.0, d.contact as u32)?;
                let distance = scaled(self, "distance", 1000.0, d.touch_distance)?;
                build::move_to_touch(id, direction, speed, contact as i32, distance)
            }
            "grasp" | "release" => {
                if !expect_args(self, 0) {
                    return None;
                }
                let settle = scaled(self, "settle", 1.0, d.settle_ms)?;
                if parsed.name == "grasp" {
                    build::grasp(id, settle)
                } else {
                    build::release(id, settle)
                }
            }
            "blind_search" => {
                if !expect_args(self, 0) {
                    return None;
                }
                let search = Action::BlindSearch {
                    preload: scaled(self, "preload", 1000.0, d.preload)?,
                    pitch: scaled(self, "pitch", 1000.0, d.pitch)?,
                    speed: scaled(self, "speed", 1000.0, d.search_speed)?,
                    radius: scaled(self, "radius", 1000.0, d.search_radius)?,
                    wobble: scaled(self, "wobble", 1000.0, d.wobble)?,
                    wobble_ms: scaled(self, "period", 1.0, d.wobble_ms)?,
                };
                let depth = scaled(self, "depth", 1000.0, d.insert_depth)?;
                build::blind_search(id, search, depth)
            }
            "idle" => {
                let ms = match positional(0) {
                    None => 0,
                    Some((v, offset)) => match v.parse::<f64>() {
                        Ok(x) if x.is_finite() && (0.0..=f64::from(MAX_COORD)).contains(&x) => {
                            x.round() as u32
                        }
                        _ => {
                            self.error(
                                at(offset),
                                format!("`idle({v})`: the time is a number of ms"),
                            );
                            return None;
                        }
                    },
                };
                if !expect_args(self, 1) {
                    return None;
                }
                build::idle(id, ms)
            }
            "open" | "close" => {
                if !expect_args(self, 0) {
                    return None;
                }
                build::gripper(
                    id,
                    if parsed.name == "close" {
                        Gripper::Closed
                    } else {
                        Gripper::Open
                    },
                )
            }
            "relieve" => {
                if !expect_args(self, 0) {
                    return None;
                }
                build::atomic(id, Action::Relieve)
            }
            "set_impedance" => {
                if !expect_args(self, 0) {
                    return None;
                }
                let stiffness = scaled(self, "stiffness", 1.0, 2000)?;
                let damping = scaled(self, "damping", 1.0, 100)?;
                build::atomic(id, Action::SetImpedance { stiffness, damping })
            }
            other => {
                let extra = if command {
                    "; a command may also be estop() or abort()"
                } else {
                    ""
                };
                self.error(
                    at(0),
                    format!("unknown call `{other}`: the calls are {CALLS}{extra}"),
                );
                return None;
            }
        };
        if let Some((w, _)) = args.get("watchdog") {
            schema.watchdog_ms = w.round().min(f64::from(MAX_COORD)) as u32;
        }
        if !written.is_empty() {
            let own = std::mem::take(&mut schema.reactions);
            for r in written.iter().chain(&own) {
                if schema.reactions.push(*r).is_err() {
                    self.error(
                        at(reactions_at.unwrap_or(0)),
                        format!(
                            "{} reactions with the call's own {}: a schema holds at most {MAX_REACTIONS}",
                            written.len() + own.len(),
                            own.len()
                        ),
                    );
                    return None;
                }
            }
        }
        if let Err(e) = schema.check() {
            self.error(
                text.span(),
                format!(
                    "`{}` makes a schema the board refuses: {e:?}",
                    text.get_ref()
                ),
            );
            return None;
        }
        Some(Made::Schema(Box::new(schema)))
    }
}

/// A call's name in traces: its text up to its reactions.
fn call_name(text: &str) -> String {
    text.split(';').next().unwrap_or(text).trim().to_string()
}

/// Letters, digits and `_`, not starting with a digit.
fn is_identifier(name: &str) -> bool {
    name.chars().next().is_some_and(|c| !c.is_ascii_digit())
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// The words a measure starts with: no sensor may be called so.
fn is_measure_word(name: &str) -> bool {
    matches!(name, "contact" | "position" | "displacement" | "force")
}

const REACTION_HELP: &str = "a reaction is written `EVENT -> SOURCE`: EVENT one of done, one_shot, \
     queue_ready, elapsed(ms), above(MEASURE, VALUE), below(MEASURE, VALUE); SOURCE queue, \
     high_priority or an innate schema's name";
const MEASURE_HELP: &str = "contact (N), position.AXIS or displacement.AXIS (mm; mrad about rx, \
     ry, rz), force.AXIS (N; N·m about rx, ry, rz), with AXIS x, y, z, rx, ry or rz, or a sensor \
     of [schema.NODE.sensors] (in its unit)";

/// One reaction, `EVENT -> SOURCE`; an error's byte offset within `text` and its cause.
fn reaction(text: &str, names: Names<'_>) -> Result<Reaction, (usize, String)> {
    let list = |v: Vec<&str>| list_or_none(&v);
    let Some(arrow) = text.find("->") else {
        return Err((0, REACTION_HELP.to_string()));
    };
    let (event_text, source_text) = (&text[..arrow], &text[arrow + 2..]);
    let source_at = arrow + 2 + (source_text.len() - source_text.trim_start().len());
    let next = match source_text.trim() {
        "queue" => Source::Queue,
        "high_priority" => Source::HighPriority,
        name => match names.innate.iter().position(|n| n == name) {
            Some(i) => Source::Innate(i as u8),
            None => {
                return Err((
                    source_at,
                    format!(
                        "`{name}` is not a source: queue, high_priority or an innate schema of the board (innate: {})",
                        list(names.innate.iter().map(String::as_str).collect())
                    ),
                ));
            }
        },
    };
    let event_text = event_text.trim_end();
    let event = match event_text {
        "done" => Event::Done,
        "one_shot" => Event::OneShot,
        "queue_ready" => Event::QueueReady,
        _ => {
            let parsed = split_call(event_text).map_err(|_| (0, REACTION_HELP.to_string()))?;
            if let Some((k, _, o)) = parsed.keywords.first() {
                return Err((*o, format!("`{k}=`: an event takes no keywords")));
            }
            let args = &parsed.positional;
            let arity = if parsed.name == "elapsed" { 1 } else { 2 };
            if !matches!(parsed.name, "elapsed" | "above" | "below") {
                return Err((
                    0,
                    format!("unknown event `{}`: {REACTION_HELP}", parsed.name),
                ));
            }
            if args.len() != arity {
                return Err((
                    0,
                    format!(
                        "`{}` takes {arity} argument{}",
                        parsed.name,
                        if arity == 1 {
                            ": a time in ms"
                        } else {
                            "s: a measure and a value"
                        }
                    ),
                ));
            }
            let number = |(v, o): (&str, usize)| match v.parse::<f64>() {
                Ok(x) if x.is_finite() => Ok(x),
                _ => Err((o, format!("`{v}` is not a number"))),
            };
            if parsed.name == "elapsed" {
                let ms = number(args[0])?;
                if !(0.0..=f64::from(MAX_COORD)).contains(&ms) {
                    return Err((
                        args[0].1,
                        format!("elapsed: {ms} ms is not 0 to {MAX_COORD}"),
                    ));
                }
                Event::Elapsed(ms.round() as u32)
            } else {
                let above = parsed.name == "above";
                let value = number(args[1])?;
                let (measure, threshold) = threshold(args[0], value, above, names)?;
                let threshold = threshold.ok_or((
                    args[1].1,
                    format!(
                        "`{}` is beyond what a threshold holds (±2^31 of the board's units)",
                        args[1].0
                    ),
                ))?;
                if above {
                    Event::Above(measure, threshold)
                } else {
                    Event::Below(measure, threshold)
                }
            }
        }
    };
    Ok(Reaction { event, next })
}

/// The measure `m` names and `value` (in the file's units) in the board's: ×1000 for mm, mrad,
/// N and N·m; counts for a sensor, rounded so that the board's integer comparison holds exactly
/// when the value in units would (up for `above`, down for `below`). `None`: beyond `i32`.
fn threshold(
    (m, offset): (&str, usize),
    value: f64,
    above: bool,
    names: Names<'_>,
) -> Result<(Measure, Option<i32>), (usize, String)> {
    const AXES_NAMES: [&str; AXES] = ["x", "y", "z", "rx", "ry", "rz"];
    let fits = |x: f64| {
        (f64::from(i32::MIN)..=f64::from(i32::MAX))
            .contains(&x)
            .then_some(x as i32)
    };
    let physical = |measure| Ok((measure, fits((value * 1000.0).round())));
    let axis = |a: &str| {
        AXES_NAMES
            .iter()
            .position(|n| *n == a)
            .map(|i| i as u8)
            .ok_or((
                offset,
                format!("`{m}`: the axes are x, y, z, rx, ry and rz"),
            ))
    };
    match m.split_once('.') {
        Some(("position", a)) => physical(Measure::Position(axis(a)?)),
        Some(("displacement", a)) => physical(Measure::Displacement(axis(a)?)),
        Some(("force", a)) => physical(Measure::Force(axis(a)?)),
        None if m == "contact" => physical(Measure::Contact),
        _ => {
            let Some(i) = names.sensors.iter().position(|s| s.name == m) else {
                let known: Vec<&str> = names.sensors.iter().map(|s| s.name.as_str()).collect();
                return Err((
                    offset,
                    format!(
                        "`{m}` is not a measure: {MEASURE_HELP} (sensors: {})",
                        list_or_none(&known)
                    ),
                ));
            };
            let topic = &names.sensors[i];
            let counts = value / topic.scale;
            let nearest = counts.round();
            // Within rounding of a whole count it is that count (0.3 mm / 0.1 mm is 2.999…).
            let counts = if (counts - nearest).abs() <= 1e-9 * nearest.abs().max(1.0) {
                nearest
            } else if above {
                counts.ceil()
            } else {
                counts.floor()
            };
            let (low, high) = topic.sensor.field.range();
            let never = if above {
                counts > high as f64
            } else {
                counts < low as f64
            };
            if never {
                return Err((
                    offset,
                    format!(
                        "`{}({m}, {value})` can never hold: sensor `{m}` reads {} to {} {}",
                        if above { "above" } else { "below" },
                        low as f64 * topic.scale,
                        high as f64 * topic.scale,
                        topic.unit
                    ),
                ));
            }
            Ok((Measure::Sensor(i as u8), fits(counts)))
        }
    }
}

/// What a call makes.
enum Made {
    Schema(Box<Schema>),
    Abort,
    EmergencyStop,
}

#[cfg(test)]
mod tests {
    use crate::diagnostic::Source;
    use crate::network::{Command, Network};

    const BASE: &str = r#"
[nodes.arm]
id = 10

[schema.arm]
period_ms = 1
force_limit_n = 30
drive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }

[client]
node = "arm"
"#;

    fn errors(extra: &str) -> Vec<String> {
        match Network::parse(Source::new("net.toml", format!("{BASE}{extra}"))) {
            Ok(_) => Vec::new(),
            Err(d) => d.0.iter().map(|d| d.to_string()).collect(),
        }
    }

    #[test]
    fn a_program_in_the_papers_api_becomes_the_builders_schemas() {
        let text = format!(
            "{BASE}program = [\"move_to(p, speed=20)\", \"move_to_touch(down, contact=5)\", \"grasp()\", \"idle(250)\"]\n\
             [client.places]\np = [1, 2, 3]\ndown = [0, 0, -1]\n\
             [[client.commands]]\nat = 1.5\ncall = \"estop()\"\n"
        );
        let network = Network::parse(Source::new("net.toml", text)).unwrap();
        let client = network.client.unwrap();
        let schemas: Vec<_> = client.program.iter().map(|c| c.schema.clone()).collect();
        use pab_core::schema::build;
        assert_eq!(
            schemas,
            vec![
                build::move_to(1, [1000, 2000, 3000, 0, 0, 0], 20_000),
                build::move_to_touch(2, [0, 0, -1000, 0, 0, 0], 5000, 5000, 50_000),
                build::grasp(3, 200),
                build::idle(4, 250),
            ]
        );
        assert_eq!(network.schema_boards[0].config.limits.force_limit, 30_000);
        assert_eq!(client.commands[0].t_us, 1_500_000);
        assert_eq!(client.commands[0].command, Command::EmergencyStop);
    }

    #[test]
    fn mistakes_are_reported_at_their_line() {
        let e = errors("program = [\"move_to(nowhere)\"]\n[client.places]\nhere = [0, 0, 0]\n");
        assert_eq!(
            e,
            ["net.toml:12:21: error: place `nowhere` is not in [client.places] (here)"]
        );
        let e = errors("program = [\"fly()\"]\n");
        assert!(
            e[0].starts_with("net.toml:12:13: error: unknown call `fly`: the calls are move_to("),
            "{e:?}"
        );
        let e = errors("program = [\"grasp(force=3)\"]\n");
        assert_eq!(
            e,
            ["net.toml:12:19: error: `grasp` takes no `force` (it takes: settle)"]
        );
        let e = errors("program = [\"grasp(settle=-1)\"]\n");
        assert_eq!(
            e,
            ["net.toml:12:19: error: `settle=-1`: a keyword's value is a number, 0 or more"]
        );
        let e = errors("program = [\"move_to(speed=3, p)\"]\n");
        assert_eq!(
            e,
            ["net.toml:12:30: error: `p`: positional arguments come before keywords"]
        );
        let e = errors("program = [\"grasp(\"]\n");
        assert_eq!(e, ["net.toml:12:19: error: the call's `)` is missing"]);
        let e = errors("program = [\"estop()\"]\n");
        assert!(
            e[0].contains("unknown call `estop`") && !e[0].contains("estop() or abort()"),
            "{e:?}"
        );
        let e = errors("[[client.commands]]\nat = 1\ncall = \"move_to()\"\n");
        assert_eq!(
            e,
            ["net.toml:14:9: error: `move_to` needs a PLACE: `move_to(PLACE)`"]
        );
    }

    /// A board with two sensors and two innate schemas, and a program whose call reacts to
    /// them.
    const REFLEXES: &str =
        "program = [\"move_to(p); below(gap, 0.25) -> retreat; above(grip, 1) -> high_priority\"]
[client.places]
p = [0, 0, -5]
[schema.arm.sensors.gap]
can_id = 0x330
value = { offset = 0, size = 2 }
scale = 0.1
unit = \"mm\"
[schema.arm.sensors.grip]
can_id = 0x12345
extended = true
value = { offset = 1, size = 1, signed = true }
unit = \"N\"
[schema.arm.places]
safe = [0, 0, 80]
[schema.arm.innate]
retreat = \"move_to(safe, speed=20); done -> high_priority\"
hold = \"idle(); below(gap, 0.3) -> retreat\"
";

    #[test]
    fn innate_schemas_and_sensors_are_named_in_reactions() {
        use pab_core::schema::{Event, Measure, Reaction, Sensor, Source as From, build};
        use pab_core::{Endian, Field, OutputId};
        let network = Network::parse(Source::new("net.toml", format!("{BASE}{REFLEXES}")))
            .unwrap_or_else(|e| panic!("{e:?}"));
        let board = &network.schema_boards[0];
        let names: Vec<_> = board.sensors.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["gap", "grip"]);
        assert_eq!(
            board.sensors[1].sensor,
            Sensor {
                id: OutputId::new(0x12345, true).unwrap(),
                field: Field {
                    offset: 1,
                    size: 1,
                    signed: true,
                    endian: Endian::Little
                }
            }
        );
        assert_eq!(
            (board.sensors[0].scale, board.sensors[0].unit.as_str()),
            (0.1, "mm")
        );
        assert_eq!(board.innate, ["retreat", "hold"]);
        let on = |event, next| Reaction { event, next };
        let mut retreat =
            build::move_to(crate::network::INNATE_IDS, [0, 0, 80_000, 0, 0, 0], 20_000);
        retreat
            .reactions
            .insert(0, on(Event::Done, From::HighPriority))
            .unwrap();
        // 0.3 mm is 3 counts of 0.1 mm, though 0.3 / 0.1 is 2.999… in floating point.
        let mut hold = build::idle(crate::network::INNATE_IDS + 1, 0);
        hold.reactions
            .insert(0, on(Event::Below(Measure::Sensor(0), 3), From::Innate(0)))
            .unwrap();
        assert_eq!(board.config.innate.as_slice(), [retreat, hold]);
        // At most 0.25 mm is at most 2 counts (0.2 mm): the board's comparison of counts holds
        // exactly when the reading in mm would.
        let mut call = build::move_to(1, [0, 0, -5000, 0, 0, 0], 50_000);
        call.reactions
            .insert(0, on(Event::Below(Measure::Sensor(0), 2), From::Innate(0)))
            .unwrap();
        call.reactions
            .insert(
                1,
                on(Event::Above(Measure::Sensor(1), 1), From::HighPriority),
            )
            .unwrap();
        let client = network.client.as_ref().unwrap();
        assert_eq!(client.program[0].schema, call);
        assert_eq!(client.program[0].name, "move_to(p)");
    }

    #[test]
    fn reactions_sensors_and_innate_schemas_report_mistakes_at_their_line() {
        let places = "[client.places]\np = [0, 0, 0]\n";
        let sensor = "[schema.arm.sensors.gap]\ncan_id = 0x330\nvalue = { offset = 0, size = 1 }\nscale = 0.5\nunit = \"mm\"\n";
        let e = errors(&format!(
            "program = [\"move_to(p); done -> nowhere\"]\n{places}"
        ));
        assert_eq!(
            e,
            [
                "net.toml:12:33: error: `nowhere` is not a source: queue, high_priority or an innate schema of the board (innate: none)"
            ]
        );
        let e = errors(&format!("program = [\"move_to(p);done queue\"]\n{places}"));
        assert!(
            e[0].starts_with("net.toml:12:24: error: a reaction is written `EVENT -> SOURCE`"),
            "{e:?}"
        );
        let e = errors(&format!(
            "program = [\"move_to(p); below(gap2, 1) -> queue\"]\n{places}{sensor}"
        ));
        assert!(
            e[0].starts_with(
                "net.toml:12:31: error: `gap2` is not a measure: contact (N), position.AXIS"
            ) && e[0].ends_with("(sensors: gap)"),
            "{e:?}"
        );
        let e = errors(&format!(
            "program = [\"move_to(p); above(gap, 200) -> queue\"]\n{places}{sensor}"
        ));
        assert_eq!(
            e,
            [
                "net.toml:12:31: error: `above(gap, 200)` can never hold: sensor `gap` reads 0 to 127.5 mm"
            ]
        );
        let e = errors(&format!(
            "program = [\"move_to(p); above(force.w, 2) -> queue; elapsed(1, 2) -> queue\"]\n{places}"
        ));
        assert_eq!(
            e,
            ["net.toml:12:31: error: `force.w`: the axes are x, y, z, rx, ry and rz"]
        );
        let e = errors(&format!(
            "program = [\"move_to(p); elapsed(1, 2) -> queue\"]\n{places}"
        ));
        assert_eq!(
            e,
            ["net.toml:12:25: error: `elapsed` takes 1 argument: a time in ms"]
        );
        let e = errors("[[client.commands]]\nat = 1\ncall = \"estop(); done -> queue\"\n");
        assert_eq!(
            e,
            ["net.toml:14:17: error: `estop()` is a command, not a schema: it takes no reactions"]
        );
        // The sensors' own keys.
        let e =
            errors("[schema.arm.sensors.s]\ncan_id = 0x311\nvalue = { offset = 0, size = 2 }\n");
        assert_eq!(
            e,
            ["net.toml:13:10: error: sensor `s`: can_id is one of the drive's frames"]
        );
        let e =
            errors("[schema.arm.sensors.s]\ncan_id = 0x800\nvalue = { offset = 0, size = 2 }\n");
        assert_eq!(
            e,
            ["net.toml:13:10: error: sensor `s`: can_id is 0..=0x7FF (extended = false)"]
        );
        let e = errors(
            "[schema.arm.sensors.s]\ncan_id = 0x330\nvalue = { offset = 0, size = 3 }\nscale = 0\n",
        );
        assert_eq!(
            e,
            ["net.toml:14:30: error: sensor `s`: value: size = 3 is not 1, 2 or 4 (bytes)"]
        );
        let e = errors(
            "[schema.arm.sensors.s]\ncan_id = 0x330\nvalue = { offset = 0, size = 2 }\nscale = 0\n",
        );
        assert_eq!(
            e,
            ["net.toml:15:9: error: sensor `s`: scale is a positive number (units per count)"]
        );
        let e = errors(
            "[schema.arm.sensors.contact]\ncan_id = 0x330\nvalue = { offset = 0, size = 2 }\n",
        );
        assert!(
            e[0].starts_with("net.toml:12:21: error: sensor `contact`: a sensor's name is"),
            "{e:?}"
        );
        let e = errors(
            "[schema.arm.sensors.s]\ncan_id = 0x330\nvalue = { offset = 0, size = 2 }\nrate = 3\n",
        );
        assert!(
            e[0].starts_with("net.toml:15:1: error: unknown key `rate`"),
            "{e:?}"
        );
        // Innate schemas: their calls and reactions, their names, their number.
        let e = errors("[schema.arm.innate]\nx = \"idle(); done -> y\"\n");
        assert_eq!(
            e,
            [
                "net.toml:13:22: error: `y` is not a source: queue, high_priority or an innate schema of the board (innate: x)"
            ]
        );
        let e = errors("[schema.arm.innate]\nx = \"move_to(nowhere)\"\n");
        assert_eq!(
            e,
            ["net.toml:13:14: error: place `nowhere` is not in [client.places] (none)"]
        );
        let e = errors("[schema.arm.innate]\nqueue = \"idle()\"\n");
        assert!(
            e[0].starts_with("net.toml:13:1: error: innate schema `queue`: a name is"),
            "{e:?}"
        );
        let many: String = (0..9).map(|i| format!("s{i} = \"idle()\"\n")).collect();
        let e = errors(&format!("[schema.arm.innate]\n{many}"));
        assert_eq!(
            e,
            ["net.toml:21:1: error: [schema.arm.innate]: 9 schemas; a board stores at most 8"]
        );
        // The plant's range finder publishes mm on a board sensor.
        let e = errors(&format!(
            "{}[plant]\nrange_finder = \"gap\"\n",
            sensor.replace("\"mm\"", "\"cm\"")
        ));
        assert_eq!(
            e,
            [
                "net.toml:18:16: error: range_finder: sensor `gap` must have unit = \"mm\": the plant publishes mm"
            ]
        );
    }

    #[test]
    fn the_board_and_client_sections_are_checked() {
        let e = errors("[schema.hand]\ndrive = { setpoint = 1, pose = 4, wrench = 6 }\n");
        assert!(
            e[0].contains("[schema.hand]: node `hand` is not defined (nodes: arm)"),
            "{e:?}"
        );
        let text = "[nodes.arm]\nid = 10\n[nodes.hand]\nid = 11\n[client]\nnode = \"hand\"\n";
        let e: Vec<String> = Network::parse(Source::new("net.toml", text))
            .unwrap_err()
            .0
            .iter()
            .map(|d| d.to_string())
            .collect();
        assert_eq!(
            e,
            [
                "net.toml:6:8: error: [client] node `hand` runs no schema server: add a [schema.hand] section"
            ]
        );
        let text = "[nodes.arm]\nid = 10\n[schema.arm]\nperiod_ms = 0\nforce_limit_n = -1\noverrun_ms = 0.5\nworkspace_mm = { min = [0, 0, 0], max = [1, -1, 1] }\ndrive = { setpoint = 0x7FE, pose = 0x310, wrench = 0x311 }\n";
        let e: Vec<String> = Network::parse(Source::new("net.toml", text))
            .unwrap_err()
            .0
            .iter()
            .map(|d| d.to_string())
            .collect();
        assert_eq!(
            e,
            [
                "net.toml:4:13: error: period_ms must be above 0 and at most 500000 ms",
                "net.toml:5:17: error: force_limit_n must be above 0 and at most 500000 N",
                "net.toml:6:14: error: overrun_ms must be at least period_ms",
                "net.toml:7:16: error: workspace_mm: min is above max on some axis",
                "net.toml:8:9: error: drive: schema server: a drive identifier: a standard (11-bit) output id is at most 0x7ff (the set-point takes 3 identifiers from its own, the pose and the wrench 2 each)",
            ]
        );
    }

    #[test]
    fn safety_limits_and_joints_come_from_the_file_in_their_units() {
        let base = "[nodes.arm]\nid = 10\n[schema.arm]\ndrive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }\n";
        let text = format!(
            "{base}speed_limit_mm_s = 250\nrate_limit_rad_s = 0.5\ncontact_limit_n = 4\n\
             [schema.arm.sensors.gap]\ncan_id = 0x330\nvalue = {{ offset = 0, size = 2 }}\n\
             [schema.arm.sensors.elbow]\ncan_id = 0x331\nvalue = {{ offset = 0, size = 2, signed = true }}\n\
             scale = 0.1\nunit = \"deg\"\njoint = {{ min = -90.05, max = 120, speed = 45 }}\n"
        );
        let network = Network::parse(Source::new("net.toml", text)).unwrap();
        let limits = &network.schema_boards[0].config.limits;
        assert_eq!(
            (limits.speed_limit, limits.rate_limit, limits.contact_limit),
            (250_000, 500_000, 4_000)
        );
        // Sensor 1, in counts of 0.1 degree: the range rounded inwards, the speed down.
        assert_eq!(
            limits.joints.as_slice(),
            [pab_core::schema::Joint {
                sensor: 1,
                min: -900,
                max: 1200,
                rate: 450
            }]
        );
        // None by default.
        let network = Network::parse(Source::new("net.toml", base)).unwrap();
        let limits = &network.schema_boards[0].config.limits;
        assert_eq!(
            (
                limits.speed_limit,
                limits.rate_limit,
                limits.contact_limit,
                limits.joints.len()
            ),
            (0, 0, 0, 0)
        );
        // A range the sensor cannot read, crossed, and a speed below a count a second.
        let bad = |joint: &str| {
            let text = format!(
                "{base}[schema.arm.sensors.elbow]\ncan_id = 0x331\nvalue = {{ offset = 0, size = 1 }}\njoint = {joint}\n"
            );
            Network::parse(Source::new("net.toml", text))
                .unwrap_err()
                .0
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
        };
        assert_eq!(
            bad("{ min = -1, max = 10 }"),
            [
                "net.toml:8:17: error: sensor `elbow`: joint.min is outside what the sensor reads (0 to 255)"
            ]
        );
        assert_eq!(
            bad("{ min = 10, max = 5 }"),
            [
                "net.toml:8:9: error: sensor `elbow`: joint.min is above joint.max (in whole counts of the sensor)"
            ]
        );
        assert_eq!(
            bad("{ min = 0, max = 5, speed = 0.5 }"),
            [
                "net.toml:8:37: error: sensor `elbow`: joint.speed is at least one count a second (1 a second)"
            ]
        );
    }

    #[test]
    fn the_drives_limits_come_from_the_file_in_its_units() {
        let base = "[nodes.arm]\nid = 10\n[schema.arm]\ndrive = { setpoint = 0x300, pose = 0x310, wrench = 0x320 }\n";
        let network = Network::parse(Source::new(
            "net.toml",
            format!("{base}drive_speed_mm_s = 250\ndrive_rate_rad_s = 1.5\npose_noise_mm = 0.2\n"),
        ))
        .unwrap();
        let config = &network.schema_boards[0].config;
        assert_eq!(
            (config.drive_speed, config.drive_rate, config.pose_noise),
            (250_000, 1_500_000, 200)
        );
        // The defaults: 2 m/s, 2π rad/s, 1 mm.
        let config = &Network::parse(Source::new("net.toml", base))
            .unwrap()
            .schema_boards[0]
            .config;
        assert_eq!(
            (config.drive_speed, config.drive_rate, config.pose_noise),
            (2_000_000, 6_283_185, 1000)
        );
        let e: Vec<String> = Network::parse(Source::new(
            "net.toml",
            format!("{base}drive_speed_mm_s = 0\npose_noise_mm = -1\n"),
        ))
        .unwrap_err()
        .0
        .iter()
        .map(|d| d.to_string())
        .collect();
        assert_eq!(
            e,
            [
                "net.toml:5:20: error: drive_speed_mm_s must be above 0 and at most 500000 mm/s",
                "net.toml:6:17: error: pose_noise_mm must be 0 and at most 500000 mm",
            ]
        );
    }
}
