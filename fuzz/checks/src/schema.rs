//! The schema server (`pab_core::schema`): its schema decoder on any bytes, and a `Server` under a
//! script of client calls, sensor readings and ticks, against a model of its documented loop
//! (`core/src/schema.rs`, `core/src/schema/server.rs`).
//!
//! **Decoding.** The whole input, and every schema a script sends as bytes, goes through
//! `Schema::decode`: a schema or a `SchemaError`, never a panic. It agrees with postcard's own
//! serde decoder: `Malformed` exactly when postcard refuses the bytes (the error's kind may
//! differ, as for the table decoder), `TrailingBytes` for bytes after a whole schema, else
//! `check()`'s verdict on postcard's schema (the same schema, or its range error); a decoded
//! schema passes `check()`, encodes with postcard within `MAX_ENCODED` bytes, and those bytes
//! decode to the same schema.
//!
//! **The set-up.** The script starts with a `Config` whose fields come from the input (period,
//! overrun bound, workspace corners, force and torque limits, stale timeouts, watchdog margin,
//! impedance, up to `MAX_INNATE` innate schemas, any of them invalid). `Server::new` refuses it
//! exactly when a reference check written here from `ConfigError`'s documentation does, with
//! the same error; a server it makes has that config, waits on the queue, has no fault and an
//! empty queue.
//!
//! **The script**: enqueue and high-priority calls (schemas as postcard bytes through the decoder,
//! built by `pab_core::schema::build`'s calls, or assembled field by field, reserved ids, bad
//! axes and unknown innate indices included), abort, emergency stop, pose, wrench and sensor
//! readings (any index, stamped now or up to 65 ms ago), ticks at times moving forward by 0 to 4
//! periods or by up to 2^32 periods (as far as 2^62 µs from the start), and runs of ticks one
//! period apart with a robot that follows the attractor (a perfectly stiff drive, with an offset
//! and a wrench from the input). Properties:
//!
//! - **Admission**: `enqueue` returns `Invalid` with `check()`'s error, else `UnknownInnate` for a
//!   reaction naming an innate index beyond the table, else `QueueFull` exactly when the queue
//!   holds `QUEUE_DEPTH`, else the new length; `high_priority` the same with `Busy` exactly when a
//!   schema is already waiting. A refusal leaves the queue as it was; the queue never exceeds
//!   `QUEUE_DEPTH` and `queued()` is the model's length after every call and tick.
//!   `set_sensor` takes exactly the indices below `MAX_SENSORS`.
//! - **Transitions** (every tick; never a panic): each one ends the schema installed before it
//!   (the chain starts at the model's current schema) and installs what the loop's steps say:
//!   step 2 first, an emergency stop before an abort before a waiting high-priority schema (the
//!   ones not taken wait for the next tick), then a safety event or the reaction at the index
//!   reported, whose source gives the schema: the innate one at its index (always within the
//!   table), the oldest queued schema (the wait for the queue when it is empty), or the wait for
//!   the high-priority channel. Every installed id was admitted (innate, or accepted by
//!   `enqueue`/`high_priority`) or is a built-in one (>= `BUILTIN_IDS`); `Safety(cause)` installs
//!   `Schema::SAFETY + cause` (relieve, then wait on the high-priority channel) from the innate
//!   origin; an abort empties the queue. After the tick `schema()` is the chain's last schema.
//! - **Faults**: a safety event other than the emergency stop occurs only while the server is not
//!   stopped on a fault; after a tick `fault()` is the cause of its last safety event, else `None`
//!   if it had a high-priority transition, else what it was (so a fault stays until the
//!   high-priority channel installs a schema). An emergency stop called before a tick is that
//!   tick's first transition, `Safety(EmergencyStop)`.
//! - **The attractor**: the setpoint is there exactly when a pose has been set. A tick with a
//!   safety event ends with the attractor on the last pose set (the recovery's `Relieve`: the one
//!   way the attractor goes wherever the robot is). A tick that starts and ends stopped on a fault,
//!   with no safety event and no high-priority transition, leaves the attractor where it was. A
//!   tick that ends with no fault leaves the attractor, and the last pose set, no farther outside
//!   the workspace on any axis than each was at the start of the tick that installed the current
//!   schema (checked when a pose was known then): what `Safety::Limit` documents, for the
//!   attractor the step-6 check that keeps it from being commanded.

use std::collections::{BTreeSet, VecDeque};

use arbitrary::{Result, Unstructured};
use pab_core::Instant;
use pab_core::schema::{
    AXES, Action, BUILTIN_IDS, Config, ConfigError, Event, Gripper, Joint, Limits, LimitsError,
    MAX_COORD, MAX_ENCODED, MAX_INNATE, MAX_JOINTS, MAX_REACTIONS, MAX_SENSORS, Measure, Origin,
    Pose, QUEUE_DEPTH, Reaction, Refusal, SPEED_WINDOW_US, STOP_NUMBERS, Safety, Schema,
    SchemaError, Server, Source, Trigger, Wrench, build,
};

/// Time never runs further than this from the start (`Instant` compares instants less than
/// 2^63 µs apart).
const HORIZON: u64 = 1 << 62;
/// Operations in one script at most (a run of ticks counts as one).
const MAX_OPS: usize = 4096;

/// Runs the decoder on the whole input, then the input as a script against one server.
pub fn check(data: &[u8]) {
    let _ = decode_checked(data);
    let mut u = Unstructured::new(data);
    let Ok(config) = read_config(&mut u) else {
        return;
    };
    let Some(mut world) = World::new(config) else {
        return;
    };
    for _ in 0..MAX_OPS {
        if u.is_empty() {
            break;
        }
        let op = match read_op(&mut u, &world.config.limits) {
            Ok(Some(op)) => op,
            Ok(None) => continue,
            Err(_) => break,
        };
        if !world.apply(op) {
            break;
        }
    }
}

/// `Schema::decode` on `bytes`, with the decoding properties asserted.
fn decode_checked(bytes: &[u8]) -> Option<Schema> {
    let decoded = Schema::decode(bytes);
    match (postcard::take_from_bytes::<Schema>(bytes), &decoded) {
        // Postcard's error kind may differ from the hand-written reader's (`pab_core::wire`
        // refuses a list length beyond u32 at once, postcard reads on until the bytes run out),
        // never whether there is one.
        (Err(_), Err(SchemaError::Malformed(_))) => {}
        (Ok((_, rest)), Err(SchemaError::TrailingBytes)) if !rest.is_empty() => {}
        (Ok((schema, [])), _) => {
            assert_eq!(decoded, schema.check().map(|()| schema), "{bytes:02x?}");
        }
        (theirs, ours) => panic!("{bytes:02x?}: decode says {ours:?}, postcard {theirs:?}"),
    }
    let schema = decoded.ok()?;
    assert_eq!(schema.check(), Ok(()));
    let mut buf = [0u8; 2 * MAX_ENCODED];
    let again = postcard::to_slice(&schema, &mut buf).expect("a schema encodes");
    assert!(
        again.len() <= MAX_ENCODED,
        "{} bytes: {schema:?}",
        again.len()
    );
    assert_eq!(Schema::decode(again).as_ref(), Ok(&schema));
    Some(schema)
}

/// One step of a script.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Op {
    /// `enqueue`.
    Enqueue(Schema),
    /// `high_priority`, naming a stop number: the server's latest, as a client that saw every
    /// stop names it, or this one (taken modulo 64), as one that did not.
    HighPriority(Schema, Ack),
    /// `abort`.
    Abort,
    /// `emergency_stop`.
    EmergencyStop,
    /// `set_pose`, stamped `age` µs before now.
    Pose(Pose, u16),
    /// `set_wrench`, stamped `age` µs before now.
    Wrench(Wrench, u16),
    /// `set_sensor` (any index), stamped now.
    Sensor(u8, i32),
    /// `set_limits`: the table's limits with some fields replaced by any value.
    Limits(Limits),
    /// A tick this many periods after the previous time (0: at the same time).
    Tick(u32),
    /// This many ticks one period apart, each after the pose (the attractor plus `offset`, or
    /// `offset` before a pose was set) and the wrench were set.
    Run {
        /// Ticks.
        ticks: u8,
        /// The measured pose minus the attractor.
        offset: Pose,
        /// The measured wrench.
        wrench: Wrench,
    },
}

/// The stop number a high-priority operation names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ack {
    /// The server's latest ([`Server::stop_number`]).
    Latest,
    /// This one, below [`STOP_NUMBERS`].
    Number(u8),
}

/// The bytes that `check` reads as `config` and then `ops` (schemas as postcard bytes, every
/// config field raw): for hand-written seeds (`examples/seeds.rs`). `None` when a schema's
/// encoding does not fit the 255 bytes a script gives it.
pub fn encode_script(config: &Config, ops: &[Op]) -> Option<Vec<u8>> {
    let mut out = vec![0xFF];
    let c = config;
    for v in [c.period_us, c.overrun_us] {
        out.extend(v.to_le_bytes());
    }
    for v in c.limits.workspace_min.iter().chain(&c.limits.workspace_max) {
        out.extend(v.to_le_bytes());
    }
    for v in [
        c.limits.force_limit,
        c.limits.torque_limit,
        c.stale_us,
        c.sensor_stale_us,
        c.watchdog_margin_ms,
        c.stiffness,
        c.damping,
        c.drive_speed,
        c.drive_rate,
        c.pose_noise,
    ] {
        out.extend(v.to_le_bytes());
    }
    encode_extra_limits(&c.limits, &mut out);
    out.push(c.innate.len() as u8);
    for s in &c.innate {
        encode_schema(s, &mut out)?;
    }
    for op in ops {
        match op {
            Op::Enqueue(s) => {
                out.push(0);
                encode_schema(s, &mut out)?;
            }
            Op::HighPriority(s, ack) => {
                out.push(1);
                encode_schema(s, &mut out)?;
                out.push(match ack {
                    Ack::Latest => 0,
                    Ack::Number(n) => 0x80 | (n % STOP_NUMBERS),
                });
            }
            Op::Abort => out.push(2),
            Op::EmergencyStop => out.push(3),
            Op::Pose(p, age) => {
                out.push(4);
                p.iter().for_each(|v| out.extend(v.to_le_bytes()));
                out.extend(age.to_le_bytes());
            }
            Op::Wrench(w, age) => {
                out.push(5);
                w.iter().for_each(|v| out.extend(v.to_le_bytes()));
                out.extend(age.to_le_bytes());
            }
            Op::Sensor(index, value) => {
                out.push(6);
                out.push(*index);
                out.extend(value.to_le_bytes());
            }
            Op::Limits(l) => {
                out.push(12);
                // Every field raw.
                out.extend(0xFFFF_u16.to_le_bytes());
                for v in l.workspace_min.iter().chain(&l.workspace_max) {
                    out.extend(v.to_le_bytes());
                }
                for v in [l.force_limit, l.torque_limit] {
                    out.extend(v.to_le_bytes());
                }
                encode_extra_limits(l, &mut out);
            }
            Op::Tick(periods) => {
                out.push(7);
                if *periods < 5 {
                    out.push(*periods as u8);
                } else {
                    out.push(0xFF);
                    out.extend(periods.to_le_bytes());
                }
            }
            Op::Run {
                ticks,
                offset,
                wrench,
            } => {
                out.push(8);
                out.push(*ticks);
                for v in offset.iter().chain(wrench) {
                    out.extend(v.to_le_bytes());
                }
            }
        }
    }
    Some(out)
}

/// The contact, speed and rate limits and the joints, as `read_extra_limits` reads them.
fn encode_extra_limits(l: &Limits, out: &mut Vec<u8>) {
    for v in [l.contact_limit, l.speed_limit, l.rate_limit] {
        out.extend(v.to_le_bytes());
    }
    out.push(l.joints.len() as u8);
    for j in &l.joints {
        out.push(j.sensor);
        out.extend(j.min.to_le_bytes());
        out.extend(j.max.to_le_bytes());
        out.extend(j.rate.to_le_bytes());
    }
}

fn read_extra_limits(u: &mut Unstructured, l: &mut Limits) -> Result<()> {
    l.contact_limit = u.arbitrary()?;
    l.speed_limit = u.arbitrary()?;
    l.rate_limit = u.arbitrary()?;
    l.joints.clear();
    for _ in 0..usize::from(u.arbitrary::<u8>()?) % (MAX_JOINTS + 1) {
        // Capacity MAX_JOINTS: never refused.
        let _ = l.joints.push(Joint {
            sensor: u.arbitrary()?,
            min: u.arbitrary()?,
            max: u.arbitrary()?,
            rate: u.arbitrary()?,
        });
    }
    Ok(())
}

/// Run-time limits: `table`'s, with the fields whose bit is set read raw.
fn read_limits(u: &mut Unstructured, table: &Limits) -> Result<Limits> {
    let flags: u16 = u.arbitrary()?;
    let raw = |bit: u8| flags & (1 << bit) != 0;
    let mut l = table.clone();
    if raw(0) {
        for v in l.workspace_min.iter_mut().chain(&mut l.workspace_max) {
            *v = u.arbitrary()?;
        }
    }
    if raw(1) {
        l.force_limit = u.arbitrary()?;
        l.torque_limit = u.arbitrary()?;
    }
    if raw(2) {
        read_extra_limits(u, &mut l)?;
    } else if raw(3) {
        // Each joint's range narrowed by an amount from the input (a tighter one, mostly).
        for j in &mut l.joints {
            let (a, b): (u16, u16) = (u.arbitrary()?, u.arbitrary()?);
            j.min = j.min.saturating_add(i32::from(a));
            j.max = j.max.saturating_sub(i32::from(b));
        }
    }
    Ok(l)
}

/// A schema as a script's postcard-bytes form: kind 0, length, bytes.
fn encode_schema(s: &Schema, out: &mut Vec<u8>) -> Option<()> {
    let mut buf = [0u8; 2 * MAX_ENCODED];
    let bytes = postcard::to_slice(s, &mut buf).ok()?;
    out.push(0);
    out.push(u8::try_from(bytes.len()).ok()?);
    out.extend_from_slice(bytes);
    Some(())
}

/// The config and operations `check` reads from `data` (schemas that do not decode left out):
/// what `encode_script`'s output must give back.
pub fn decode_script(data: &[u8]) -> Option<(Config, Vec<Op>)> {
    let mut u = Unstructured::new(data);
    let config = read_config(&mut u).ok()?;
    let mut ops = Vec::new();
    while !u.is_empty() && ops.len() < MAX_OPS {
        match read_op(&mut u, &config.limits).ok()? {
            Some(op) => ops.push(op),
            None => continue,
        }
    }
    Some((config, ops))
}

fn read_config(u: &mut Unstructured) -> Result<Config> {
    let flags: u8 = u.arbitrary()?;
    let raw = |bit: u8| flags & (1 << bit) != 0;
    let period = if raw(0) {
        u.arbitrary()?
    } else {
        [1000, 100, 250, 2000, 10_000][usize::from(u.arbitrary::<u8>()? % 5)]
    };
    let mut config = Config::new(period);
    if raw(0) {
        config.overrun_us = u.arbitrary()?;
    }
    if raw(1) {
        for v in config
            .limits
            .workspace_min
            .iter_mut()
            .chain(&mut config.limits.workspace_max)
        {
            *v = u.arbitrary()?;
        }
    } else {
        let half = [1_000_000, 100, 50_000, MAX_COORD][usize::from(u.arbitrary::<u8>()? % 4)];
        config.limits.workspace_min = [-half; AXES];
        config.limits.workspace_max = [half; AXES];
    }
    if raw(2) {
        config.limits.force_limit = u.arbitrary()?;
        config.limits.torque_limit = u.arbitrary()?;
    }
    if raw(3) {
        config.stale_us = u.arbitrary()?;
        config.sensor_stale_us = u.arbitrary()?;
    }
    if raw(4) {
        config.watchdog_margin_ms = u.arbitrary()?;
    }
    if raw(5) {
        config.stiffness = u.arbitrary()?;
        config.damping = u.arbitrary()?;
    }
    if raw(6) {
        config.drive_speed = u.arbitrary()?;
        config.drive_rate = u.arbitrary()?;
        config.pose_noise = u.arbitrary()?;
    }
    if raw(7) {
        read_extra_limits(u, &mut config.limits)?;
    }
    let count = usize::from(u.arbitrary::<u8>()?) % (MAX_INNATE + 1);
    for _ in 0..count {
        if let Some(s) = read_schema(u)? {
            // Capacity MAX_INNATE: never refused.
            let _ = config.innate.push(s);
        }
    }
    Ok(config)
}

/// The next operation (`None`: a schema that did not decode, nothing to do).
fn read_op(u: &mut Unstructured, table: &Limits) -> Result<Option<Op>> {
    let kind: u8 = u.arbitrary()?;
    Ok(Some(match kind % 13 {
        0 => match read_schema(u)? {
            Some(s) => Op::Enqueue(s),
            None => return Ok(None),
        },
        1 => match read_schema(u)? {
            Some(s) => {
                let ack: u8 = u.arbitrary()?;
                let ack = if ack < 0x80 {
                    Ack::Latest
                } else {
                    Ack::Number(ack % STOP_NUMBERS)
                };
                Op::HighPriority(s, ack)
            }
            None => return Ok(None),
        },
        2 => Op::Abort,
        3 => Op::EmergencyStop,
        4 => Op::Pose(u.arbitrary()?, u.arbitrary()?),
        5 => Op::Wrench(u.arbitrary()?, u.arbitrary()?),
        6 => Op::Sensor(u.arbitrary()?, u.arbitrary()?),
        7 | 9 | 10 => {
            let n: u8 = u.arbitrary()?;
            Op::Tick(if n == 0xFF {
                u.arbitrary()?
            } else {
                u32::from(n % 5)
            })
        }
        12 => Op::Limits(read_limits(u, table)?),
        _ => Op::Run {
            ticks: u.arbitrary()?,
            offset: u.arbitrary()?,
            wrench: u.arbitrary()?,
        },
    }))
}

/// A schema: postcard bytes through the decoder (kind 0), one of `build`'s calls (1), or
/// assembled field by field, not necessarily valid (2).
fn read_schema(u: &mut Unstructured) -> Result<Option<Schema>> {
    Ok(match u.arbitrary::<u8>()? % 3 {
        0 => {
            let len = usize::from(u.arbitrary::<u8>()?).min(u.len());
            decode_checked(u.bytes(len)?)
        }
        1 => Some(built(u)?),
        _ => Some(assembled(u)?),
    })
}

/// A coordinate within `MAX_COORD`, mostly small.
fn coord(u: &mut Unstructured) -> Result<i32> {
    let v: i32 = u.arbitrary()?;
    Ok(if v & 1 == 0 {
        (v >> 1) % 100_000
    } else {
        v % (MAX_COORD + 1)
    })
}

fn pose(u: &mut Unstructured) -> Result<Pose> {
    let mut p = [0; AXES];
    for c in &mut p {
        *c = coord(u)?;
    }
    Ok(p)
}

/// A speed, distance or time within `MAX_COORD` (0 included).
fn amount(u: &mut Unstructured) -> Result<u32> {
    Ok(coord(u)?.unsigned_abs())
}

fn built(u: &mut Unstructured) -> Result<Schema> {
    let id: u16 = u.arbitrary()?;
    Ok(match u.arbitrary::<u8>()? % 9 {
        0 => build::move_to(id, pose(u)?, amount(u)?),
        1 => build::move_to_touch(id, pose(u)?, amount(u)?, u.arbitrary()?, amount(u)?),
        2 => build::grasp(id, amount(u)?),
        3 => build::release(id, amount(u)?),
        4 => {
            let search = Action::BlindSearch {
                preload: amount(u)?,
                pitch: amount(u)?,
                speed: amount(u)?,
                radius: amount(u)?,
                wobble: amount(u)?,
                wobble_ms: amount(u)?,
            };
            build::blind_search(id, search, u.arbitrary()?)
        }
        5 => build::idle(id, amount(u)?),
        6 => build::atomic(
            id,
            Action::SetImpedance {
                stiffness: amount(u)?,
                damping: amount(u)?,
            },
        ),
        7 => build::atomic(id, Action::Relieve),
        _ => build::gripper(
            id,
            if u.arbitrary()? {
                Gripper::Closed
            } else {
                Gripper::Open
            },
        ),
    })
}

fn assembled(u: &mut Unstructured) -> Result<Schema> {
    let id = u.arbitrary()?;
    // Any u32 for the amounts here: out-of-range schemas are refused, not run.
    let action = match u.arbitrary::<u8>()? % 9 {
        0 => Action::Idle { ms: u.arbitrary()? },
        1 => Action::Gripper(if u.arbitrary()? {
            Gripper::Closed
        } else {
            Gripper::Open
        }),
        2 => Action::SetImpedance {
            stiffness: u.arbitrary()?,
            damping: u.arbitrary()?,
        },
        3 => Action::Relieve,
        4 => Action::MoveTo {
            goal: u.arbitrary()?,
            speed: u.arbitrary()?,
        },
        5 => Action::MoveToTouch {
            direction: u.arbitrary()?,
            speed: u.arbitrary()?,
            distance: u.arbitrary()?,
        },
        6 => Action::BlindSearch {
            preload: u.arbitrary()?,
            pitch: u.arbitrary()?,
            speed: u.arbitrary()?,
            radius: u.arbitrary()?,
            wobble: u.arbitrary()?,
            wobble_ms: u.arbitrary()?,
        },
        7 => Action::Grasp {
            settle_ms: u.arbitrary()?,
        },
        _ => Action::Release {
            settle_ms: u.arbitrary()?,
        },
    };
    let mut reactions = Vec::new();
    for _ in 0..usize::from(u.arbitrary::<u8>()?) % (MAX_REACTIONS + 1) {
        let measure = |u: &mut Unstructured| -> Result<Measure> {
            let index = u.arbitrary::<u8>()? % 10;
            Ok(match u.arbitrary::<u8>()? % 5 {
                0 => Measure::Position(index),
                1 => Measure::Displacement(index),
                2 => Measure::Force(index),
                3 => Measure::Contact,
                _ => Measure::Sensor(index),
            })
        };
        let event = match u.arbitrary::<u8>()? % 6 {
            0 => Event::OneShot,
            1 => Event::Done,
            2 => Event::Elapsed(u.arbitrary::<u16>()?.into()),
            3 => Event::QueueReady,
            4 => Event::Above(measure(u)?, u.arbitrary()?),
            _ => Event::Below(measure(u)?, u.arbitrary()?),
        };
        let next = match u.arbitrary::<u8>()? % 3 {
            0 => Source::Innate(u.arbitrary::<u8>()? % 10),
            1 => Source::Queue,
            _ => Source::HighPriority,
        };
        reactions.push(Reaction { event, next });
    }
    let watchdog_ms = if u.arbitrary()? { u.arbitrary()? } else { 0 };
    Ok(Schema {
        id,
        action,
        // At most MAX_REACTIONS: never too many for the schema's table.
        reactions: reactions.into_iter().collect(),
        watchdog_ms,
    })
}

/// `Config::check` as `ConfigError` documents it.
fn reference_check(c: &Config) -> std::result::Result<(), ConfigError> {
    if c.period_us == 0 || c.overrun_us < c.period_us {
        return Err(ConfigError::Period);
    }
    reference_limits(&c.limits).map_err(ConfigError::Limits)?;
    if c.drive_speed == 0 || c.drive_rate == 0 {
        return Err(ConfigError::DriveLimits);
    }
    for (i, s) in c.innate.iter().enumerate() {
        if s.check().is_err() || !innate_known(s, c.innate.len()) {
            return Err(ConfigError::Innate(i as u8));
        }
    }
    Ok(())
}

/// `Limits::check` as `LimitsError` documents it.
fn reference_limits(l: &Limits) -> std::result::Result<(), LimitsError> {
    if (0..AXES).any(|a| l.workspace_min[a] > l.workspace_max[a]) {
        return Err(LimitsError::Workspace);
    }
    if l.force_limit == 0 {
        return Err(LimitsError::ForceLimit);
    }
    match l.joints.iter().position(|j| j.min > j.max) {
        Some(i) => Err(LimitsError::Joint(i as u8)),
        None => Ok(()),
    }
}

/// `Server::set_limits`'s verdict as documented: consistent, and each bound within the
/// table's (a corner or range inside, a limit at most the table's and not none where it has
/// one, the same joints in the same order).
fn reference_within(l: &Limits, table: &Limits) -> std::result::Result<(), Refusal> {
    reference_limits(l).map_err(|_| Refusal::Looser)?;
    let within = |new: u32, old: u32| old == 0 || (1..=old).contains(&new);
    let inside = (0..AXES).all(|a| {
        l.workspace_min[a] >= table.workspace_min[a] && l.workspace_max[a] <= table.workspace_max[a]
    }) && within(l.force_limit, table.force_limit)
        && within(l.torque_limit, table.torque_limit)
        && within(l.contact_limit, table.contact_limit)
        && within(l.speed_limit, table.speed_limit)
        && within(l.rate_limit, table.rate_limit)
        && l.joints.len() == table.joints.len()
        && l.joints.iter().zip(&table.joints).all(|(n, o)| {
            n.sensor == o.sensor && n.min >= o.min && n.max <= o.max && within(n.rate, o.rate)
        });
    if inside { Ok(()) } else { Err(Refusal::Looser) }
}

/// Whether the pose moved faster than `l` allows from `last` to `next` in `dt` µs, in i128:
/// the translation's (rotation's) magnitude above the limit × dt (rounded up) plus twice the
/// noise, a limit of 0 none, an allowance of 2^32 or more none (as documented).
fn reference_too_fast(l: &Limits, last: &Pose, next: &Pose, dt: u64, noise: u32) -> bool {
    [(0usize, l.speed_limit), (3, l.rate_limit)]
        .iter()
        .any(|&(axis, limit)| {
            let allowed =
                (i128::from(limit) * i128::from(dt) + 999_999) / 1_000_000 + 2 * i128::from(noise);
            let moved: i128 = (axis..axis + 3)
                .map(|a| (i128::from(next[a]) - i128::from(last[a])).pow(2))
                .sum();
            limit != 0 && allowed <= i128::from(u32::MAX) && moved > allowed * allowed
        })
}

fn innate_known(s: &Schema, count: usize) -> bool {
    s.reactions
        .iter()
        .all(|r| !matches!(r.next, Source::Innate(i) if usize::from(i) >= count))
}

/// How far `v` is outside `lo..=hi`.
fn outside(v: i32, lo: i32, hi: i32) -> u64 {
    let (v, lo, hi) = (i64::from(v), i64::from(lo), i64::from(hi));
    (lo - v).max(v - hi).max(0) as u64
}

/// How far `p` is outside the workspace, per axis.
fn excess(l: &Limits, p: &Pose) -> [u64; AXES] {
    let mut out = [0; AXES];
    for (a, o) in out.iter_mut().enumerate() {
        *o = outside(p[a], l.workspace_min[a], l.workspace_max[a]);
    }
    out
}

/// How far each joint is outside its range, by its sensor's last reading (0 before one).
fn joint_excess(l: &Limits, sensors: &[Option<i32>; MAX_SENSORS]) -> [u64; MAX_JOINTS] {
    let mut out = [0; MAX_JOINTS];
    for (o, j) in out.iter_mut().zip(&l.joints) {
        if let Some(Some(v)) = sensors.get(usize::from(j.sensor)) {
            *o = outside(*v, j.min, j.max);
        }
    }
    out
}

fn no_farther(now: &[u64], then: &[u64]) -> bool {
    now.iter().zip(then).all(|(n, t)| n <= t)
}

/// The built-in schemas as the module documents them.
fn builtin(id: u16, action: Action, reaction: Option<Reaction>) -> Schema {
    Schema {
        id,
        action,
        reactions: reaction.into_iter().collect(),
        watchdog_ms: 0,
    }
}

fn wait_queue() -> Schema {
    builtin(
        Schema::WAIT_QUEUE,
        Action::Idle { ms: 0 },
        Some(Reaction {
            event: Event::QueueReady,
            next: Source::Queue,
        }),
    )
}

fn wait_high_priority() -> Schema {
    builtin(Schema::WAIT_HIGH_PRIORITY, Action::Idle { ms: 0 }, None)
}

fn recovery(cause: Safety) -> Schema {
    builtin(
        Schema::SAFETY + cause as u16,
        Action::Relieve,
        Some(Reaction {
            event: Event::OneShot,
            next: Source::HighPriority,
        }),
    )
}

/// What step 2 takes at the next tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Step2 {
    EmergencyStop,
    Abort,
    HighPriority,
}

struct World {
    server: Server,
    config: Config,
    /// µs since the start.
    now: u64,
    admitted: BTreeSet<u16>,
    queue: VecDeque<Schema>,
    waiting: Option<Schema>,
    estop: bool,
    abort: bool,
    /// Stops counted so far (the reference's own count of the server's).
    stops: u64,
    current: Schema,
    /// The last pose the server took (a plausible one).
    pose: Option<Pose>,
    /// That pose and when it was measured (µs since the start).
    plausible: Option<(Pose, u64)>,
    /// A pose frame since the last tick was implausible.
    implausible: bool,
    /// The bounds in force.
    limits: Limits,
    /// The pose and each joint at the start of their speed windows (µs since the start).
    speed_from: Option<(Pose, u64)>,
    joint_from: [Option<(i32, u64)>; MAX_JOINTS],
    /// A pose or joint moved too fast since the last tick.
    speeding: bool,
    /// The sensors' last readings.
    sensors: [Option<i32>; MAX_SENSORS],
    /// The joints' excess when the current schema was installed.
    joint_excess: [u64; MAX_JOINTS],
    /// The attractor, once a pose has been set (before, the server's is not commanded).
    attractor: Option<Pose>,
    /// The attractor's and the last pose's excess at the start of the tick that installed the
    /// current schema, when known then.
    attractor_excess: Option<[u64; AXES]>,
    pose_excess: Option<[u64; AXES]>,
}

impl World {
    fn new(config: Config) -> Option<World> {
        let made = Server::new(config.clone());
        let expected = reference_check(&config);
        assert_eq!(made.as_ref().err().copied(), expected.err(), "{config:?}");
        let server = made.ok()?;
        assert_eq!(server.config(), &config);
        assert_eq!(server.limits(), &config.limits);
        assert_eq!(server.schema(), &wait_queue());
        assert_eq!((server.fault(), server.queued()), (None, 0));
        Some(World {
            server,
            admitted: config.innate.iter().map(|s| s.id).collect(),
            limits: config.limits.clone(),
            config,
            now: 0,
            queue: VecDeque::new(),
            waiting: None,
            estop: false,
            abort: false,
            stops: 0,
            current: wait_queue(),
            pose: None,
            plausible: None,
            implausible: false,
            speed_from: None,
            joint_from: [None; MAX_JOINTS],
            speeding: false,
            sensors: [None; MAX_SENSORS],
            joint_excess: [0; MAX_JOINTS],
            attractor: None,
            attractor_excess: None,
            pose_excess: None,
        })
    }

    fn at(&self, age: u16) -> Instant {
        Instant::from_micros(self.now.saturating_sub(u64::from(age)))
    }

    fn admission(&self, s: &Schema) -> std::result::Result<(), Refusal> {
        s.check().map_err(Refusal::Invalid)?;
        if innate_known(s, self.config.innate.len()) {
            Ok(())
        } else {
            Err(Refusal::UnknownInnate)
        }
    }

    /// One operation; `false` when time would run past the horizon.
    fn apply(&mut self, op: Op) -> bool {
        match op {
            Op::Enqueue(s) => {
                let expected = self.admission(&s).and_then(|()| {
                    if self.queue.len() == QUEUE_DEPTH {
                        Err(Refusal::QueueFull)
                    } else {
                        Ok(self.queue.len() + 1)
                    }
                });
                let got = self.server.enqueue(s.clone());
                assert_eq!(got, expected, "{s:?}");
                if got.is_ok() {
                    self.admitted.insert(s.id);
                    self.queue.push_back(s);
                }
                assert_eq!(self.server.queued(), self.queue.len());
            }
            Op::HighPriority(s, ack) => {
                let latest = (self.stops % u64::from(STOP_NUMBERS)) as u8;
                assert_eq!(self.server.stop_number(), latest);
                let stop = match ack {
                    Ack::Latest => latest,
                    Ack::Number(n) => n,
                };
                let acknowledged = if stop == latest {
                    Ok(())
                } else {
                    Err(Refusal::StopNotAcknowledged)
                };
                let busy = match self.waiting {
                    Some(_) => Err(Refusal::Busy),
                    None => Ok(()),
                };
                let expected = self.admission(&s).and(acknowledged).and(busy);
                let got = self.server.high_priority(s.clone(), stop);
                assert_eq!(got, expected, "{s:?}");
                if got.is_ok() {
                    self.admitted.insert(s.id);
                    self.waiting = Some(s);
                }
                assert_eq!(self.server.queued(), self.queue.len());
            }
            Op::Abort => {
                self.server.abort();
                self.abort = true;
            }
            Op::EmergencyStop => {
                self.server.emergency_stop();
                self.estop = true;
            }
            Op::Pose(p, age) => self.set_pose(p, age),
            Op::Wrench(w, age) => self.server.set_wrench(w, self.at(age)),
            Op::Sensor(index, value) => {
                let taken = self
                    .server
                    .set_sensor(usize::from(index), value, self.at(0));
                assert_eq!(taken, usize::from(index) < MAX_SENSORS);
                if let Some(slot) = self.sensors.get_mut(usize::from(index)) {
                    *slot = Some(value);
                    // The joints it reads: their speed over the window, within one count.
                    let now = self.now;
                    for (j, from) in self.limits.joints.iter().zip(&mut self.joint_from) {
                        if j.sensor != index {
                            continue;
                        }
                        match *from {
                            Some((last, then)) if now - then >= SPEED_WINDOW_US => {
                                // The frame may have arrived as late as a tick may.
                                let span = (now - then) + u64::from(self.config.overrun_us);
                                let allowed = (i128::from(j.rate) * i128::from(span) + 999_999)
                                    / 1_000_000
                                    + 1;
                                let moved = (i128::from(value) - i128::from(last)).abs();
                                self.speeding |= j.rate != 0 && moved > allowed;
                                *from = Some((value, now));
                            }
                            Some(_) => {}
                            None => *from = Some((value, now)),
                        }
                    }
                }
            }
            Op::Limits(l) => {
                let expected = reference_within(&l, &self.config.limits);
                let got = self.server.set_limits(l.clone());
                assert_eq!(got, expected, "{l:?}");
                if got.is_ok() {
                    self.limits = l;
                }
                assert_eq!(self.server.limits(), &self.limits);
            }
            Op::Tick(periods) => {
                let step = u64::from(periods).saturating_mul(self.config.period_us.into());
                if step > HORIZON - self.now {
                    return false;
                }
                self.now += step;
                self.tick();
            }
            Op::Run {
                ticks,
                offset,
                wrench,
            } => {
                for _ in 0..ticks {
                    let step = u64::from(self.config.period_us);
                    if step > HORIZON - self.now {
                        return false;
                    }
                    self.now += step;
                    let base = self.attractor.unwrap_or([0; AXES]);
                    let mut p = [0; AXES];
                    for a in 0..AXES {
                        p[a] = base[a].saturating_add(offset[a]);
                    }
                    self.set_pose(p, 0);
                    self.server.set_wrench(wrench, self.at(0));
                    self.tick();
                }
            }
        }
        true
    }

    /// A pose frame: the server takes it only if the drive could have got there from the last
    /// pose it took (the reference's own arithmetic, in i128), and otherwise raises an
    /// implausible sensor at the next tick; `pose` is the last pose taken.
    fn set_pose(&mut self, p: Pose, age: u16) {
        let at = self.now.saturating_sub(u64::from(age));
        self.server.set_pose(p, self.at(age));
        if let Some((last, then)) = self.plausible {
            // The time between the arrivals, plus the lateness a frame may have (the overrun
            // bound).
            let dt = i128::from(at.saturating_sub(then)) + i128::from(self.config.overrun_us);
            let c = &self.config;
            let fits = (0..AXES).all(|a| {
                let speed = if a < 3 { c.drive_speed } else { c.drive_rate };
                // ceil(speed * dt / 1e6) + noise
                let allowed =
                    (i128::from(speed) * dt + 999_999) / 1_000_000 + i128::from(c.pose_noise);
                (i128::from(p[a]) - i128::from(last[a])).abs() <= allowed
            });
            if !fits {
                self.implausible = true;
                return;
            }
        }
        self.plausible = Some((p, at));
        self.pose = Some(p);
        match self.speed_from {
            Some((from, then)) if at.saturating_sub(then) >= SPEED_WINDOW_US => {
                let dt = (at - then).saturating_add(u64::from(self.config.overrun_us));
                self.speeding |=
                    reference_too_fast(&self.limits, &from, &p, dt, self.config.pose_noise);
                self.speed_from = Some((p, at));
            }
            Some(_) => {}
            None => self.speed_from = Some((p, at)),
        }
        // The first pose arms the server: the attractor is set to it.
        self.attractor.get_or_insert(p);
    }

    fn tick(&mut self) {
        let fault_before = self.server.fault();
        let attractor_before = self.attractor;
        let implausible = std::mem::take(&mut self.implausible);
        let speeding = std::mem::take(&mut self.speeding);
        // A stop ends everything that was about to run: the schema waiting on the high-priority
        // channel is discarded, not installed at a later tick; an abort with the stop still
        // empties the queue.
        let step2 = if std::mem::take(&mut self.estop) {
            self.waiting = None;
            if std::mem::take(&mut self.abort) {
                self.queue.clear();
            }
            Some(Step2::EmergencyStop)
        } else if std::mem::take(&mut self.abort) {
            self.waiting = None;
            Some(Step2::Abort)
        } else if self.waiting.is_some() {
            Some(Step2::HighPriority)
        } else {
            None
        };

        let out = self.server.tick(Instant::from_micros(self.now));

        let mut current = self.current.clone();
        let mut fault = fault_before;
        let mut safety = false;
        let mut high_priority = false;
        for (k, t) in out.transitions.iter().enumerate() {
            assert_eq!(t.ended, current.id, "{t:?} in {:?}", out.transitions);
            let from_step2 = match t.by {
                Trigger::Safety(Safety::EmergencyStop) => Some(Step2::EmergencyStop),
                Trigger::Abort => Some(Step2::Abort),
                Trigger::HighPriority => Some(Step2::HighPriority),
                Trigger::Safety(_) | Trigger::Reaction(..) => None,
            };
            if k == 0 {
                assert_eq!(from_step2, step2, "{:?}", out.transitions);
            } else {
                assert_eq!(from_step2, None, "{:?}", out.transitions);
            }
            let (schema, origin) = match t.by {
                Trigger::HighPriority => {
                    fault = None;
                    high_priority = true;
                    let s = self.waiting.take().expect("a schema was waiting");
                    (s, Origin::HighPriority)
                }
                Trigger::Abort => {
                    self.queue.clear();
                    self.stops += 1;
                    (wait_high_priority(), Origin::HighPriority)
                }
                Trigger::Safety(cause) => {
                    self.stops += 1;
                    if cause == Safety::ImplausibleSensor {
                        assert!(implausible, "an implausible pose nobody sent");
                    }
                    if cause == Safety::Speed {
                        assert!(speeding, "a speed event with nothing too fast");
                    }
                    if cause != Safety::EmergencyStop {
                        assert_eq!(fault, None, "{cause:?} while stopped on a fault");
                    }
                    fault = Some(cause);
                    safety = true;
                    (recovery(cause), Origin::Innate)
                }
                Trigger::Reaction(index, event) => {
                    let r = current
                        .reactions
                        .get(usize::from(index))
                        .unwrap_or_else(|| panic!("{t:?}: no such reaction in {current:?}"));
                    assert_eq!(
                        r.event, event,
                        "{t:?}: the reported event is the reaction's"
                    );
                    match r.next {
                        Source::Innate(i) => {
                            let s = self.config.innate.get(usize::from(i));
                            (
                                s.expect("an innate index within the table").clone(),
                                Origin::Innate,
                            )
                        }
                        Source::Queue => (
                            self.queue.pop_front().unwrap_or_else(wait_queue),
                            Origin::Queue,
                        ),
                        Source::HighPriority => (wait_high_priority(), Origin::HighPriority),
                    }
                }
            };
            assert_eq!(
                (t.installed, t.source),
                (schema.id, origin),
                "{:?}",
                out.transitions
            );
            assert!(t.installed >= BUILTIN_IDS || self.admitted.contains(&t.installed));
            current = schema;
        }
        // An implausible pose stops a running server at the next tick (a stale sensor tested
        // before it may stop it first).
        let running = (fault_before.is_none() && step2 != Some(Step2::EmergencyStop))
            || step2 == Some(Step2::HighPriority);
        if implausible && running {
            assert!(
                safety,
                "an implausible pose did not stop the server: {:?}",
                out.transitions
            );
        }
        if speeding && running {
            assert!(
                safety,
                "a pose or joint too fast did not stop the server: {:?}",
                out.transitions
            );
        }
        assert_eq!(self.server.schema(), &current);
        assert_eq!(self.server.fault(), fault, "{:?}", out.transitions);
        assert_eq!(
            u64::from(self.server.stop_number()),
            self.stops % u64::from(STOP_NUMBERS)
        );
        // A stop holds: after this tick's emergency stop or abort, the only way out is a schema
        // that was accepted on the high-priority channel after it (none is waiting now).
        if matches!(step2, Some(Step2::EmergencyStop | Step2::Abort)) {
            assert!(self.waiting.is_none());
            assert!(
                current.id >= BUILTIN_IDS,
                "a stop's tick ends on the server's own schema: {current:?}"
            );
        }
        assert_eq!(self.server.queued(), self.queue.len());
        assert!(self.server.queued() <= QUEUE_DEPTH);
        self.current = current;

        // The attractor.
        assert_eq!(out.setpoint.is_some(), self.pose.is_some());
        if let Some(setpoint) = out.setpoint {
            let attractor = setpoint.attractor;
            self.attractor = Some(attractor);
            if safety {
                assert_eq!(Some(attractor), self.pose, "{:?}", out.transitions);
            } else if fault_before.is_some() && fault.is_some() && !high_priority {
                assert_eq!(Some(attractor), attractor_before, "held on a fault");
            }
        }
        if !out.transitions.is_empty() {
            self.attractor_excess = attractor_before.map(|a| excess(&self.limits, &a));
            self.pose_excess = self.pose.map(|p| excess(&self.limits, &p));
            self.joint_excess = joint_excess(&self.limits, &self.sensors);
        }
        if fault.is_none() {
            let joints = joint_excess(&self.limits, &self.sensors);
            assert!(
                no_farther(&joints, &self.joint_excess),
                "joints farther out ({joints:?}) than at install ({:?}) without a fault",
                self.joint_excess
            );
            if let (Some(then), Some(a)) = (self.attractor_excess, self.attractor) {
                let now = excess(&self.limits, &a);
                assert!(
                    no_farther(&now, &then),
                    "attractor {a:?} farther out ({now:?}) than at install ({then:?}): {:?}",
                    self.current
                );
            }
            if let (Some(then), Some(p)) = (self.pose_excess, self.pose) {
                let now = excess(&self.limits, &p);
                assert!(
                    no_farther(&now, &then),
                    "pose {p:?} farther out ({now:?}) than at install ({then:?}) without a fault"
                );
            }
        }
    }
}
