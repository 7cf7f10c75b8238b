//! The server: the loop's state and its seven steps.

use heapless::{Deque, Vec};

use super::action::Progress;
use super::limits::{allowance, axis_excess, too_fast};
use super::{
    AXES, Event, Gripper, Joint, Limits, LimitsError, MAX_INNATE, MAX_JOINTS, MAX_SENSORS, Measure,
    Pose, QUEUE_DEPTH, Reaction, SPEED_WINDOW_US, Schema, SchemaError, Setpoint, Source, Wrench,
};
use crate::time::Instant;

/// The built-in safety events, in the order they are tested: before any reaction of any
/// schema, and no schema can remove them.
///
/// Order: the emergency stop first (it is handled with the high-priority channel, step 2), then a
/// stale sensor (the tests after it would read stale values), an implausible pose, the workspace
/// limit, a joint's limit, the speed, the force limit, the watchdog and the overrun. (The numbers
/// are the wire codes, in the order the events came to be.)
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Safety {
    /// An emergency-stop frame arrived.
    EmergencyStop = 0,
    /// The pose or wrench (or a sensor the current reactions read) is older than the board's
    /// timeout, or was never received.
    StaleSensor = 1,
    /// The measured pose or the attractor went farther outside the workspace than when the
    /// schema was installed (so that a schema bringing the robot back in is not stopped).
    Limit = 2,
    /// The force (or torque) magnitude is above the board's safety limit.
    Force = 3,
    /// The schema ran longer than its budget: failure to progress.
    Watchdog = 4,
    /// A tick came later than the board's overrun bound after the previous one.
    Overrun = 5,
    /// The measured pose jumped farther than the drive can move since the previous one (its
    /// speed limits, [`Config::drive_speed`], and the sensor's noise): a forged or broken pose
    /// frame. The pose is not taken; the stop holds the last plausible one.
    ImplausibleSensor = 6,
    /// A joint went farther outside its range than when the schema was installed.
    JointLimit = 7,
    /// The measured translation or rotation, or a joint, moved faster than its limit over the
    /// speed window ([`super::SPEED_WINDOW_US`]).
    Speed = 8,
}

impl Safety {
    /// The event's name, as the status frames and traces give it (`safety:<name>`).
    pub const fn name(self) -> &'static str {
        match self {
            Safety::EmergencyStop => "estop",
            Safety::StaleSensor => "stale",
            Safety::Limit => "limit",
            Safety::Force => "force",
            Safety::Watchdog => "watchdog",
            Safety::Overrun => "overrun",
            Safety::ImplausibleSensor => "implausible",
            Safety::JointLimit => "joint",
            Safety::Speed => "speed",
        }
    }

    /// The event from its number (a fault frame's byte).
    pub const fn from_u8(v: u8) -> Option<Safety> {
        Some(match v {
            0 => Safety::EmergencyStop,
            1 => Safety::StaleSensor,
            2 => Safety::Limit,
            3 => Safety::Force,
            4 => Safety::Watchdog,
            5 => Safety::Overrun,
            6 => Safety::ImplausibleSensor,
            7 => Safety::JointLimit,
            8 => Safety::Speed,
            _ => return None,
        })
    }
}

/// What ended a schema.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Trigger {
    /// A schema arrived on the high-priority channel.
    HighPriority,
    /// An abort command.
    Abort,
    /// A safety event.
    Safety(Safety),
    /// The reaction at this index of the ended schema's table, and its event.
    Reaction(u8, Event),
}

/// A schema change: `ended` was replaced by `installed`, from `source`, because of `by`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Transition {
    /// The schema that ended.
    pub ended: u16,
    /// Why.
    pub by: Trigger,
    /// The schema installed.
    pub installed: u16,
    /// Where it came from: a safety recovery counts as innate (the paper's hard-coded schema),
    /// the waits as their channel.
    pub source: Origin,
}

/// Where an installed schema came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Origin {
    /// The board's own: an innate schema, or a safety recovery.
    Innate,
    /// The client's queue (or the wait for it).
    Queue,
    /// The high-priority channel (or the wait for it).
    HighPriority,
}

impl Origin {
    /// `innate`, `queue` or `high-priority`.
    pub const fn name(self) -> &'static str {
        match self {
            Origin::Innate => "innate",
            Origin::Queue => "queue",
            Origin::HighPriority => "high-priority",
        }
    }
}

/// Why the server refused a schema or a command.
#[derive(Clone, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// The schema is invalid.
    Invalid(SchemaError),
    /// A reaction names an innate schema the board does not have.
    UnknownInnate,
    /// The queue holds [`QUEUE_DEPTH`] schemas: a full queue refuses, never overwrites.
    QueueFull,
    /// A high-priority schema is already waiting for the next tick.
    Busy,
    /// A high-priority schema that names another stop than the server's latest
    /// ([`Server::stop_number`]): sent before the client saw a stop, it must not leave it.
    StopNotAcknowledged,
    /// Run-time limits looser than the table's, or inconsistent ([`Server::set_limits`];
    /// [`Limits::check_within`] says which).
    Looser,
}

/// Where a client's schema goes ([`Server::submit`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Channel {
    /// The queue: installed when a reaction takes the next queued schema.
    Queue,
    /// The high-priority channel: installed at the next tick, replacing the running schema and
    /// ending a stop. It names the stop the client acknowledges ([`Server::stop_number`]): one
    /// that names another is refused, so that a schema sent before a stop never leaves it.
    HighPriority {
        /// The stop number the client saw and acknowledges, `0..STOP_NUMBERS`.
        stop: u8,
    },
}

/// Stop numbers count the server's stops modulo this ([`Server::stop_number`]): six bits, what
/// the SchemaTransfer message's channel byte and SchemaState's flags byte have room for. A
/// schema in flight could be taken for an acknowledgement of a later stop only if exactly a
/// multiple of 64 stops came during its flight, and the server takes at most one stop a tick.
pub const STOP_NUMBERS: u8 = 64;

/// A board's set-up: its loop, its safety bounds and its innate schemas.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// The loop's period, µs (1 000 on the boards: 1 kHz).
    pub period_us: u32,
    /// A tick later than this after the previous one is an overrun, µs.
    pub overrun_us: u32,
    /// The safety bounds: the loosest the board runs with ([`Server::set_limits`] may tighten
    /// them at run time).
    pub limits: Limits,
    /// The pose and wrench are stale this long after their last frame, µs.
    pub stale_us: u32,
    /// The extra sensors are stale this long after their last frame, µs.
    pub sensor_stale_us: u32,
    /// Added to 1.5 × an action's nominal time to make its default watchdog budget, ms.
    pub watchdog_margin_ms: u32,
    /// The drive's top speed on each translational axis, µm/s: a measured pose that moved
    /// farther since the previous one (and [`Config::pose_noise`]) is implausible.
    pub drive_speed: u32,
    /// The drive's top rate on each rotational axis, µrad/s.
    pub drive_rate: u32,
    /// The pose sensor's noise: what a pose may move beyond the drive's speed between two
    /// frames, µm on the translational axes and µrad on the rotational ones.
    pub pose_noise: u32,
    /// The impedance at start-up: stiffness N/m.
    pub stiffness: u32,
    /// Damping N·s/m.
    pub damping: u32,
    /// The innate schemas, by index.
    pub innate: Vec<Schema, MAX_INNATE>,
}

/// Why a [`Config`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// A period of 0, or an overrun bound shorter than the period.
    Period,
    /// The safety bounds are inconsistent.
    Limits(LimitsError),
    /// A drive speed or rate of 0: every move would be implausible.
    DriveLimits,
    /// An innate schema (its index) is invalid or names an innate schema beyond the table.
    Innate(u8),
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ConfigError::Period => {
                f.write_str("loop period of 0, or an overrun bound shorter than the period")
            }
            ConfigError::Limits(error) => write!(f, "safety limits: {error}"),
            ConfigError::DriveLimits => f.write_str("drive speed or rate of 0"),
            ConfigError::Innate(index) => write!(
                f,
                "innate schema {index} is invalid or names an innate schema beyond the table"
            ),
        }
    }
}

impl core::error::Error for ConfigError {}

impl Config {
    /// A set-up at `period_us` with the defaults: overrun at two periods, [`Limits::new`] (a
    /// ±1 m (rad) workspace, 50 N, no other bound), sensors stale after 20 periods (at least 50 ms), 1 s
    /// watchdog margin, a drive of at most 2 m/s and 2π rad/s on each axis with a pose noise of
    /// 1 mm (mrad), 2 000 N/m and 100 N·s/m, no innate schema.
    pub fn new(period_us: u32) -> Config {
        let stale = period_us.saturating_mul(20).max(50_000);
        Config {
            period_us,
            overrun_us: period_us.saturating_mul(2),
            limits: Limits::new(),
            stale_us: stale,
            sensor_stale_us: stale,
            watchdog_margin_ms: 1000,
            drive_speed: 2_000_000,
            drive_rate: 6_283_185,
            pose_noise: 1000,
            stiffness: 2000,
            damping: 100,
            innate: Vec::new(),
        }
    }

    /// Checks the set-up ([`ConfigError`] says what is wrong).
    pub fn check(&self) -> Result<(), ConfigError> {
        if self.period_us == 0 || self.overrun_us < self.period_us {
            return Err(ConfigError::Period);
        }
        self.limits.check().map_err(ConfigError::Limits)?;
        if self.drive_speed == 0 || self.drive_rate == 0 {
            return Err(ConfigError::DriveLimits);
        }
        for (i, s) in self.innate.iter().enumerate() {
            if admit(s, self.innate.len()).is_err() {
                return Err(ConfigError::Innate(i as u8));
            }
        }
        Ok(())
    }
}

/// Checks `s` ([`Schema::check`]) and that every innate source of it is within a table of
/// `count`: a client's schema against the board's table, an innate one against its own.
// Out of line: the set-up's check and a client's schema each inlined a copy.
#[inline(never)]
fn admit(s: &Schema, count: usize) -> Result<(), Refusal> {
    s.check().map_err(Refusal::Invalid)?;
    let known = s.reactions.iter().all(|r| match r.next {
        Source::Innate(i) => usize::from(i) < count,
        Source::Queue | Source::HighPriority => true,
    });
    if known {
        Ok(())
    } else {
        Err(Refusal::UnknownInnate)
    }
}

/// What a tick produced.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Tick {
    /// The command for the drive (none until a pose has been received: the server has nothing
    /// to hold the robot at before).
    pub setpoint: Option<Setpoint>,
    /// The schema changes of this tick, in order (at most three: the high-priority channel, a
    /// triggering event, a limit the action's own iteration met).
    pub transitions: Vec<Transition, 3>,
}

/// One reading and when it arrived.
type Stamped<T> = Option<(T, Instant)>;

/// The schema server of one board. See the [module](super) for the loop.
pub struct Server {
    config: Config,
    current: Schema,
    origin: Origin,
    progress: Progress,
    installed_at: Instant,
    /// The measured pose when the current schema was installed ([`Measure::Displacement`]).
    pose_at_install: Pose,
    /// How far outside the workspace the measured pose and the attractor were then, per axis.
    excess_at_install: [u32; AXES],
    attractor_excess_at_install: [u32; AXES],
    /// How far outside its range each joint was then.
    joint_excess_at_install: [u32; MAX_JOINTS],
    /// Bounds set at run time, in force instead of the table's (`None`: the table's, so that a
    /// server is made without a copy of them).
    limits: Option<Limits>,
    /// The watchdog's budget for the current schema, µs.
    budget_us: Option<u64>,
    queue: Deque<Schema, QUEUE_DEPTH>,
    high_priority: Option<Schema>,
    estop: bool,
    abort: bool,
    /// A pose frame jumped farther than the drive can move (checked at the next tick).
    implausible: bool,
    /// The pose or a joint moved faster than its limit (checked at the next tick).
    speeding: bool,
    /// The pose, and each joint's reading, at the start of the speed window.
    speed_from: Stamped<Pose>,
    joint_from: [Stamped<i32>; MAX_JOINTS],
    /// Stops so far (emergency stops, aborts, safety events), wrapping.
    stops: u8,
    fault: Option<Safety>,
    setpoint: Setpoint,
    /// A pose has been received: the attractor means something.
    armed: bool,
    pose: Stamped<Pose>,
    wrench: Stamped<Wrench>,
    sensors: [Stamped<i32>; MAX_SENSORS],
    last_tick: Option<Instant>,
}

impl Server {
    /// A server with `config`, waiting on the queue.
    ///
    /// Fails when the set-up is invalid ([`Config::check`]).
    pub fn new(config: Config) -> Result<Server, ConfigError> {
        let server = Server::unchecked(config);
        // Checked once built, in place: a check of the argument before the move kept a copy of
        // the set-up (2 KB with its innate schemas) for it, and its code.
        server.config.check()?;
        Ok(server)
    }

    /// A server with `config`, not checked: for a caller that builds the server inside a larger
    /// value and checks [`Server::config`] there, where a `Result` around the server made the
    /// compiler build it aside and copy it in (5 KB, twice).
    pub fn unchecked(config: Config) -> Server {
        let setpoint = Setpoint {
            attractor: [0; AXES],
            stiffness: config.stiffness,
            damping: config.damping,
            gripper: Gripper::Open,
        };
        Server {
            current: wait_queue(),
            origin: Origin::Queue,
            progress: Progress::default(),
            installed_at: Instant::default(),
            pose_at_install: [0; AXES],
            excess_at_install: [0; AXES],
            attractor_excess_at_install: [0; AXES],
            joint_excess_at_install: [0; MAX_JOINTS],
            limits: None,
            budget_us: None,
            queue: Deque::new(),
            high_priority: None,
            estop: false,
            abort: false,
            implausible: false,
            speeding: false,
            speed_from: None,
            joint_from: [None; MAX_JOINTS],
            stops: 0,
            fault: None,
            setpoint,
            armed: false,
            pose: None,
            wrench: None,
            sensors: [None; MAX_SENSORS],
            last_tick: None,
            config,
        }
    }

    /// The set-up.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The installed schema's identifier.
    pub fn current(&self) -> u16 {
        self.current.id
    }

    /// The installed schema.
    pub fn schema(&self) -> &Schema {
        &self.current
    }

    /// Where the installed schema came from.
    pub fn origin(&self) -> Origin {
        self.origin
    }

    /// Milliseconds from the installed schema's installation to `now` (0 if `now` is before).
    pub fn elapsed_ms(&self, now: Instant) -> u64 {
        self.elapsed_us(now) / 1000
    }

    /// Microseconds from the installed schema's installation to `now` (0 if `now` is before):
    /// the watchdog's, the reactions' and the action's one clock.
    // Left to the inliner again (out of line it once saved 28 bytes of the NUCLEO-G474RE's
    // flash): it now took 24 bytes more of the NUCLEO-G474RE's flash, 20 of the emulated
    // board's.
    fn elapsed_us(&self, now: Instant) -> u64 {
        now.micros_since(self.installed_at).unwrap_or(0)
    }

    /// The safety event the server is stopped on, until the high-priority channel installs a
    /// schema.
    pub fn fault(&self) -> Option<Safety> {
        self.fault
    }

    /// Schemas in the queue. Out of line: three callers inlined its length (48 bytes of the
    /// NUCLEO-G474RE's flash).
    #[inline(never)]
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// The server's stops so far (emergency stops, aborts, safety events), modulo
    /// [`STOP_NUMBERS`]: what a high-priority schema names to acknowledge the latest stop
    /// ([`Channel::HighPriority`]), and what SchemaState reports. 0 at start; a stop counts from
    /// the tick that handles it.
    pub fn stop_number(&self) -> u8 {
        self.stops % STOP_NUMBERS
    }

    /// Queues a client's schema; returns the queue's new length.
    ///
    /// Refused when invalid, when it names an unknown innate schema, or when the queue is full.
    pub fn enqueue(&mut self, schema: Schema) -> Result<usize, Refusal> {
        self.submit(schema, Channel::Queue)?;
        Ok(self.queue.len())
    }

    /// Hands a schema to the high-priority channel, acknowledging stop `stop`: installed at the
    /// next tick, replacing the current one (and ending a stop), unless a stop comes first.
    ///
    /// Refused when invalid, when it names an unknown innate schema, when `stop` is not the
    /// server's [`Server::stop_number`], or when one is already waiting.
    pub fn high_priority(&mut self, schema: Schema, stop: u8) -> Result<(), Refusal> {
        self.submit(schema, Channel::HighPriority { stop })
    }

    /// [`Server::high_priority`] or [`Server::enqueue`] by `channel`: for a runner that takes
    /// both channels' schemas from one kind of message (one call site, one move of the schema).
    pub fn submit(&mut self, schema: Schema, channel: Channel) -> Result<(), Refusal> {
        admit(&schema, self.config.innate.len())?;
        let Channel::HighPriority { stop } = channel else {
            return self.queue.push_back(schema).map_err(|_| Refusal::QueueFull);
        };
        if stop != self.stop_number() {
            return Err(Refusal::StopNotAcknowledged);
        }
        if self.high_priority.is_some() {
            return Err(Refusal::Busy);
        }
        self.high_priority = Some(schema);
        Ok(())
    }

    /// Abort: at the next tick the current schema ends, the queue is emptied, a high-priority
    /// schema waiting for that tick is discarded, and the server waits on the high-priority
    /// channel for a schema that acknowledges the abort, holding the attractor where it is.
    pub fn abort(&mut self) {
        self.abort = true;
    }

    /// Emergency stop: at the next tick, forces relieved, fault, a high-priority schema waiting
    /// for that tick discarded, and the wait on the high-priority channel for a schema that
    /// acknowledges the stop; the queue is kept, not run.
    pub fn emergency_stop(&mut self) {
        self.estop = true;
    }

    /// The bounds in force: the table's ([`Config::limits`]) until [`Server::set_limits`].
    pub fn limits(&self) -> &Limits {
        self.limits.as_ref().unwrap_or(&self.config.limits)
    }

    /// Sets the bounds in force from the next tick: each within the table's (tighter, or back to
    /// the table's), never looser ([`Limits::check_within`]). A robot outside a tightened
    /// workspace or joint range stops at the next tick (it is farther outside than when its
    /// schema was installed); the schema that brings it back in is not stopped.
    pub fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
        limits
            .check_within(&self.config.limits)
            .map_err(|_| Refusal::Looser)?;
        self.limits = Some(limits);
        Ok(())
    }

    /// The measured pose, from its topic. Taken only if plausible: no axis moved farther since the
    /// last pose taken than the drive's speed (rate) allows in the time between (plus the
    /// lateness a frame may have, [`Config::overrun_us`]), plus the pose noise; otherwise the next
    /// tick raises [`Safety::ImplausibleSensor`] and the server keeps the last plausible pose
    /// (what a stop holds the robot at).
    // Out of line: the node's frame path inlined it, its speed window and all.
    #[inline(never)]
    pub fn set_pose(&mut self, pose: Pose, at: Instant) {
        if let Some((last, then)) = &self.pose
            && !plausible(&self.config, last, &pose, self.span(at, *then))
        {
            self.implausible = true;
            return;
        }
        self.pose = Some((pose, at));
        // The speed over the window: from the pose at its start to this one.
        match self.speed_from {
            Some((from, then)) => {
                if at.micros_since(then).unwrap_or(0) >= SPEED_WINDOW_US {
                    let span = self.span(at, then);
                    self.speeding |=
                        too_fast(self.limits(), &from, &pose, span, self.config.pose_noise);
                    self.speed_from = Some((pose, at));
                }
            }
            None => self.speed_from = Some((pose, at)),
        }
        if !self.armed {
            // The first pose: hold the robot where it is.
            self.setpoint.attractor = pose;
            self.armed = true;
        }
    }

    /// How long the sensor may have had between two readings that arrived at `then` and `at`:
    /// the time between their arrivals, plus how late the first may have arrived. A frame that
    /// waited behind others (on the bus, in a driver's queue) and arrives with the next is
    /// counted as late as a tick may be ([`Config::overrun_us`]), so that two frames arriving
    /// together are not taken for a jump; a later one is a loop overrun anyway.
    fn span(&self, at: Instant, then: Instant) -> u64 {
        at.micros_since(then)
            .unwrap_or(0)
            .saturating_add(u64::from(self.config.overrun_us))
    }

    /// The measured wrench, from its topic.
    pub fn set_wrench(&mut self, wrench: Wrench, at: Instant) {
        self.wrench = Some((wrench, at));
    }

    /// An extra sensor's value, from its topic; `false` for an index beyond [`MAX_SENSORS`].
    // Out of line: the node's frame path inlined it, with its joints' speed.
    #[inline(never)]
    pub fn set_sensor(&mut self, index: usize, value: i32, at: Instant) -> bool {
        let Some(s) = self.sensors.get_mut(index) else {
            return false;
        };
        *s = Some((value, at));
        // The joints it measures: their speed over the window, within one count of noise.
        let limits = self.limits.as_ref().unwrap_or(&self.config.limits);
        let late = u64::from(self.config.overrun_us);
        for (joint, from) in limits.joints.iter().zip(&mut self.joint_from) {
            if usize::from(joint.sensor) != index {
                continue;
            }
            match *from {
                Some((last, then)) => {
                    let dt = at.micros_since(then).unwrap_or(0);
                    if dt >= SPEED_WINDOW_US {
                        // As `span`: the frame may have waited as long as a tick may.
                        let span = dt.saturating_add(late);
                        self.speeding |= joint.rate != 0
                            && u64::from(last.abs_diff(value)) > allowance(joint.rate, span, 1);
                        *from = Some((value, at));
                    }
                }
                None => *from = Some((value, at)),
            }
        }
        true
    }

    /// One pass of the loop at `now` (steps 2 to 6; the runner's timer is step 1).
    ///
    /// Costs a scan of the current reaction table and one iteration of its action; a schema
    /// change copies one schema.
    pub fn tick(&mut self, now: Instant) -> Tick {
        let mut tick = Tick::default();
        self.tick_into(now, &mut tick);
        tick
    }

    /// [`Server::tick`], its result written into `out` (what `out` held is replaced): for a
    /// runner that keeps it in place.
    // The board's: a `Tick` returned was built aside and moved out (20 bytes of the
    // NUCLEO-G474RE's flash).
    pub fn tick_into(&mut self, now: Instant, out: &mut Tick) {
        let transitions = &mut out.transitions;
        transitions.clear();
        // Through `fresh`: a gap beyond the bound is a stale tick (24 bytes of the
        // NUCLEO-G474RE's flash less than its own test).
        let overrun = self
            .last_tick
            .is_some_and(|last| !fresh(now, last, self.config.overrun_us));
        self.last_tick = Some(now);

        // Step 2: the high-priority channel. A stop ends everything that was about to run: a
        // high-priority schema waiting for this tick was sent before the stop was seen (it
        // named the stop number before this one), so it is discarded, not deferred.
        // An abort in the same tick as an emergency stop still empties the queue; the two are
        // one stop.
        let estop = core::mem::take(&mut self.estop);
        let abort = core::mem::take(&mut self.abort);
        if estop || abort {
            self.high_priority = None;
        }
        if abort {
            self.queue.clear();
        }
        if estop {
            self.recover(Safety::EmergencyStop, now, transitions);
        } else if abort {
            self.stops = self.stops.wrapping_add(1);
            self.install(
                wait_high_priority(),
                Origin::HighPriority,
                Trigger::Abort,
                now,
                transitions,
            );
        } else if let Some(schema) = self.high_priority.take() {
            self.fault = None;
            self.install(
                schema,
                Origin::HighPriority,
                Trigger::HighPriority,
                now,
                transitions,
            );
        }

        // Steps 3 and 4: the sensor table and the triggering event.
        let implausible = core::mem::take(&mut self.implausible);
        let speeding = core::mem::take(&mut self.speeding);
        match self.trigger(now, overrun, implausible, speeding) {
            Some(Err(cause)) => self.recover(cause, now, transitions),
            Some(Ok((index, event, next))) => {
                let by = Trigger::Reaction(index, event);
                // Step 5.
                let innate = match next {
                    Source::Innate(i) => self.config.innate.get(usize::from(i)),
                    Source::Queue | Source::HighPriority => None,
                };
                // One install for every source: a call each cost more code than choosing its
                // schema.
                let (s, origin) = match (next, innate) {
                    (_, Some(s)) => (s.clone(), Origin::Innate),
                    (Source::Queue, None) => (
                        self.queue.pop_front().unwrap_or_else(wait_queue),
                        Origin::Queue,
                    ),
                    // One wait for the high-priority source and an unknown innate index (checked
                    // when the schema was admitted; a wait is the safe answer): a copy of the
                    // built-in schema less.
                    (Source::Innate(_) | Source::HighPriority, None) => {
                        (wait_high_priority(), Origin::HighPriority)
                    }
                };
                self.install(s, origin, by, now, transitions);
            }
            None => {}
        }

        // Step 6: one iteration; an attractor leaving the workspace is not commanded.
        let before = self.setpoint.attractor;
        self.iterate(now);
        if self.fault.is_none()
            && self.excess_grew(&self.setpoint.attractor, &self.attractor_excess_at_install)
        {
            self.setpoint.attractor = before;
            self.recover(Safety::Limit, now, transitions);
            self.iterate(now);
        }

        out.setpoint = self.armed.then_some(self.setpoint);
    }

    fn iterate(&mut self, now: Instant) {
        let elapsed = self.elapsed_us(now);
        // By reference: a copy of the pose (or the attractor) each tick otherwise.
        self.current.action.iterate(
            &mut self.progress,
            &mut self.setpoint,
            elapsed,
            self.config.period_us,
            self.pose.as_ref().map(|(p, _)| p),
        );
    }

    /// Steps 3 and 4: the safety event, or the first reaction that holds (its index, event and
    /// source), or nothing.
    fn trigger(
        &self,
        now: Instant,
        overrun: bool,
        implausible: bool,
        speeding: bool,
    ) -> Option<Result<(u8, Event, Source), Safety>> {
        // Read once for the watchdog and every reaction.
        let elapsed_us = self.elapsed_us(now);
        if self.fault.is_none()
            && let Some(cause) = self.safety(now, elapsed_us, overrun, implausible, speeding)
        {
            return Some(Err(cause));
        }
        let one_shot = self.progress.iterations >= 1;
        for (i, r) in self.current.reactions.iter().enumerate() {
            if self.holds(r, one_shot, elapsed_us) {
                return Some(Ok((i as u8, r.event, r.next)));
            }
        }
        None
    }

    fn safety(
        &self,
        now: Instant,
        elapsed_us: u64,
        overrun: bool,
        implausible: bool,
        speeding: bool,
    ) -> Option<Safety> {
        let c = &self.config;
        let limits = self.limits();
        // The waits move nothing: a drive that is off while the board waits is no fault.
        let waiting = self.current.id >= super::BUILTIN_IDS;
        if !waiting {
            let pose_ok = self.pose.is_some_and(|(_, at)| fresh(now, at, c.stale_us));
            let wrench_ok = self
                .wrench
                .is_some_and(|(_, at)| fresh(now, at, c.stale_us));
            // The sensors' test inlined, not `fresh`: up to 24 calls a tick. The sensors the
            // reactions read, and those of the joints (a joint's limit needs its reading).
            let sensor_ok = |s: u8| {
                self.sensors
                    .get(usize::from(s))
                    .copied()
                    .flatten()
                    .is_some_and(|(_, at)| {
                        now.micros_since(at)
                            .is_none_or(|age| age <= u64::from(c.sensor_stale_us))
                    })
            };
            let sensors_ok = self.current.reactions.iter().all(|r| match r.event {
                Event::Above(Measure::Sensor(s), _) | Event::Below(Measure::Sensor(s), _) => {
                    sensor_ok(s)
                }
                _ => true,
            }) && limits.joints.iter().all(|j| sensor_ok(j.sensor));
            if !(pose_ok && wrench_ok && sensors_ok) {
                return Some(Safety::StaleSensor);
            }
        }
        if implausible {
            return Some(Safety::ImplausibleSensor);
        }
        if let Some((pose, _)) = &self.pose
            && self.excess_grew(pose, &self.excess_at_install)
        {
            return Some(Safety::Limit);
        }
        if limits
            .joints
            .iter()
            .zip(&self.joint_excess_at_install)
            .any(|(j, then)| joint_excess(&self.sensors, j) > *then)
        {
            return Some(Safety::JointLimit);
        }
        if speeding {
            return Some(Safety::Speed);
        }
        if let Some((w, _)) = &self.wrench {
            let (force, torque) = w.split_at(3);
            if magnitude_above(force, limits.force_limit)
                || (limits.torque_limit != 0 && magnitude_above(torque, limits.torque_limit))
            {
                return Some(Safety::Force);
            }
        }
        if self.budget_us.is_some_and(|budget| elapsed_us > budget) {
            return Some(Safety::Watchdog);
        }
        if overrun {
            return Some(Safety::Overrun);
        }
        None
    }

    fn holds(&self, r: &Reaction, one_shot: bool, elapsed_us: u64) -> bool {
        let (m, threshold, above) = match r.event {
            Event::OneShot => return one_shot,
            Event::Done => return self.progress.done,
            Event::Elapsed(ms) => return elapsed_us >= u64::from(ms) * 1000,
            Event::QueueReady => return !self.queue.is_empty(),
            Event::Above(Measure::Contact, t) => (Measure::Contact, self.limits().contact(t), true),
            Event::Above(m, t) => (m, t, true),
            Event::Below(m, t) => (m, t, false),
        };
        let Some(value) = self.measure(m) else {
            return false;
        };
        if above {
            value >= i64::from(threshold)
        } else {
            value <= i64::from(threshold)
        }
    }

    /// A value of the sensor table, or `None` when it has never been received.
    fn measure(&self, m: Measure) -> Option<i64> {
        // The three measures of an axis share one read of it.
        let (values, axis, relative) = match m {
            Measure::Position(a) => (&self.pose.as_ref()?.0, a, false),
            Measure::Displacement(a) => (&self.pose.as_ref()?.0, a, true),
            Measure::Force(a) => (&self.wrench.as_ref()?.0, a, false),
            Measure::Contact => {
                let (w, _) = self.wrench.as_ref()?;
                let (d, norm) = self.current.action.heading(&self.progress);
                if norm == 0 {
                    return Some(0);
                }
                // |F| ≤ 2^31, and |d| < 2^32 (a goal within MAX_COORD, from an attractor that a
                // pose topic may have put anywhere in i32): each product below 2^63, a plain
                // multiply; three of them summed saturating, so the sum may be i64::MIN, whose
                // plain negation overflows (a panic, or no contact at all once wrapped).
                let dot = w
                    .iter()
                    .zip(d)
                    .fold(0i64, |s, (f, d)| s.saturating_add(i64::from(*f) * d));
                return Some(super::action::div_toward_zero(dot.saturating_neg(), norm));
            }
            Measure::Sensor(s) => {
                return self.sensors.get(usize::from(s))?.map(|(v, _)| i64::from(v));
            }
        };
        let axis = usize::from(axis);
        let value = i64::from(*values.get(axis)?);
        if relative {
            Some(value - i64::from(*self.pose_at_install.get(axis)?))
        } else {
            Some(value)
        }
    }

    /// Whether `p` is farther outside the workspace than `then`, on some axis.
    // Left to the inliner: out of line (one copy for the limit's test and the tick's step 6) it
    // took 28 bytes more of the NUCLEO-G474RE's flash than its two inlined copies.
    fn excess_grew(&self, p: &Pose, then: &[u32; AXES]) -> bool {
        let l = self.limits();
        // Axis by axis, without an array of the excesses.
        p.iter()
            .zip(&l.workspace_min)
            .zip(&l.workspace_max)
            .zip(then)
            .any(|(((v, lo), hi), then)| axis_excess(*v, *lo, *hi) > *then)
    }

    /// Step 5 for a safety event: the recovery schema (relieve, then wait on the high-priority
    /// channel), and the fault kept until that channel installs a schema.
    // Out of line: the tick's three callers each inlined a copy of the recovery schema.
    #[inline(never)]
    fn recover(&mut self, cause: Safety, now: Instant, out: &mut Vec<Transition, 3>) {
        self.fault = Some(cause);
        self.stops = self.stops.wrapping_add(1);
        let recovery = Schema::builtin(Schema::SAFETY + cause as u16);
        self.install(recovery, Origin::Innate, Trigger::Safety(cause), now, out);
    }

    /// Step 5: the new reaction table, one-shot false, the new action from the current
    /// attractor, the watchdog restarted.
    fn install(
        &mut self,
        schema: Schema,
        origin: Origin,
        by: Trigger,
        now: Instant,
        out: &mut Vec<Transition, 3>,
    ) {
        let attractor = self.setpoint.attractor;
        let measured = self.pose.map_or(attractor, |(p, _)| p);
        schema.action.start(&attractor, &mut self.progress);
        self.budget_us = if schema.id >= super::BUILTIN_IDS {
            None
        } else if schema.watchdog_ms != 0 {
            Some(u64::from(schema.watchdog_ms) * 1000)
        } else {
            schema.action.nominal_us(&self.progress).map(|t| {
                t.saturating_add(t / 2)
                    .saturating_add(u64::from(self.config.watchdog_margin_ms) * 1000)
            })
        };
        self.installed_at = now;
        self.pose_at_install = measured;
        let limits = self.limits.as_ref().unwrap_or(&self.config.limits);
        excess(limits, &measured, &mut self.excess_at_install);
        excess(limits, &attractor, &mut self.attractor_excess_at_install);
        for (then, j) in self.joint_excess_at_install.iter_mut().zip(&limits.joints) {
            *then = joint_excess(&self.sensors, j);
        }
        // At most three installs a tick (see `Tick`); a fourth could not be reported, and cannot
        // happen: step 2, step 5 and step 6 install one each.
        let _ = out.push(Transition {
            ended: self.current.id,
            by,
            installed: schema.id,
            source: origin,
        });
        self.origin = origin;
        self.current = schema;
    }
}

/// How far `p` is outside the workspace, per axis, into `out` (in place: install's two are
/// the server's own fields, not copies made and moved in).
// Out of line: three callers (install's two, the limit's test) each inlined a copy.
#[inline(never)]
fn excess(l: &Limits, p: &Pose, out: &mut [u32; AXES]) {
    for (((o, v), lo), hi) in out
        .iter_mut()
        .zip(p)
        .zip(&l.workspace_min)
        .zip(&l.workspace_max)
    {
        *o = axis_excess(*v, *lo, *hi);
    }
}

/// How far outside its range joint `j` is, by its sensor's last reading (0 before one).
// Out of line: the joint limit's test and the install each inlined a copy.
#[inline(never)]
fn joint_excess(sensors: &[Stamped<i32>; MAX_SENSORS], j: &Joint) -> u32 {
    match sensors.get(usize::from(j.sensor)) {
        Some(Some((v, _))) => axis_excess(*v, j.min, j.max),
        _ => 0,
    }
}

/// Whether `next` is a pose the drive can reach from `last` in `dt_us`: no translational axis
/// moved more than `drive_speed` × dt + noise, no rotational one more than `drive_rate` × dt +
/// noise. Per axis and in integers: a difference of two `i32` fits a `u32`, the allowance a
/// saturating `u64`.
// Left to the inliner: its one caller, `Server::set_pose`, is out of line (not in the node's
// frame path); out of line too, it took 36 bytes more of both boards' flash.
fn plausible(c: &Config, last: &Pose, next: &Pose, dt_us: u64) -> bool {
    let (translation, rotation) = (
        allowance(c.drive_speed, dt_us, c.pose_noise),
        allowance(c.drive_rate, dt_us, c.pose_noise),
    );
    last.iter().zip(next).enumerate().all(|(axis, (a, b))| {
        u64::from(a.abs_diff(*b)) <= if axis < 3 { translation } else { rotation }
    })
}

/// Whether a reading from `at` is at most `limit` µs old at `now` (one from the future is).
// Out of line: the pose's and the wrench's tests and the overrun's each inlined a copy.
#[inline(never)]
fn fresh(now: Instant, at: Instant, limit: u32) -> bool {
    now.micros_since(at)
        .is_none_or(|age| age <= u64::from(limit))
}

/// |v| > limit, without a root; `v` is a force's or a torque's three components.
// Out of line: the force's and the torque's tests each inlined a copy.
#[inline(never)]
fn magnitude_above(v: &[i32], limit: u32) -> bool {
    // Each square is at most 2^62 (|c| ≤ 2^31), three of them (a force, a torque) below 2^64:
    // plain adds.
    let sum = v.iter().fold(0u64, |s, c| {
        s + u64::from(c.unsigned_abs()) * u64::from(c.unsigned_abs())
    });
    sum > u64::from(limit) * u64::from(limit)
}

fn wait_queue() -> Schema {
    Schema::builtin(Schema::WAIT_QUEUE)
}

fn wait_high_priority() -> Schema {
    Schema::builtin(Schema::WAIT_HIGH_PRIORITY)
}
