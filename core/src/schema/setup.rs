//! A board's schema server as its table image carries it: the loop's set-up ([`Config`]), the
//! identifiers of its drive's frames (docs/can-protocol.md, "The drive's frames") and its extra
//! sensors' topics ([`Sensor`]).

use heapless::Vec;
use serde::{Deserialize, Serialize};

use super::{Config, ConfigError, Event, MAX_SENSORS, Measure, Sensor, SensorError};
use crate::OutputId;
use crate::consumer::OutputIdError;
use crate::wire::decode_struct;

/// The drive's frames: each a base identifier, the frames after it on the next ones.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Drive {
    /// The attractor (x, y, z); the rotation on the next identifier, the impedance on the one
    /// after: three identifiers.
    pub setpoint: OutputId,
    /// The measured pose; its rotation on the next identifier.
    pub pose: OutputId,
    /// The measured force; the torque on the next identifier.
    pub wrench: OutputId,
}

/// The schema server of a board.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setup {
    /// The loop, its bounds and its innate schemas.
    pub config: Config,
    /// Where its drive listens and speaks.
    pub drive: Drive,
    /// Its extra sensors, by index ([`Measure::Sensor`]).
    pub sensors: Vec<Sensor, MAX_SENSORS>,
}

/// Why a [`Setup`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SetupError {
    /// The loop's set-up.
    Config(ConfigError),
    /// A drive identifier (or one of those after it) does not fit its format.
    DriveId(OutputIdError),
    /// Two of the drive's frames would share an identifier.
    DriveOverlap,
    /// An extra sensor's topic (its index, and why).
    Sensor(u8, SensorError),
    /// An innate schema (its index) reads a sensor beyond the set-up's topics: it would stop on
    /// a stale sensor every time it ran.
    UnknownSensor(u8),
    /// A joint's limits (its index) name a sensor beyond the set-up's topics: every schema would
    /// stop on a stale sensor.
    UnknownJointSensor(u8),
}

impl Drive {
    /// The identifiers it uses, each with the count from it: 3, 2 and 2.
    // Out of line: both checks inlined a copy.
    #[inline(never)]
    fn ranges(&self) -> [(OutputId, u32); 3] {
        [(self.setpoint, 3), (self.pose, 2), (self.wrench, 2)]
    }

    /// Checks that every identifier, the following ones included, fits its format and that no
    /// two frames share one.
    pub fn check(&self) -> Result<(), SetupError> {
        let ranges = self.ranges();
        for (id, count) in &ranges {
            // The last identifier of the range fits its format only if the first does, and
            // refuses with the same error (the format's) when either does not.
            OutputId::new(id.raw().saturating_add(count - 1), id.is_extended())
                .map_err(SetupError::DriveId)?;
        }
        for (i, a) in ranges.iter().enumerate() {
            if ranges.iter().skip(i + 1).any(|b| overlap(*a, *b)) {
                return Err(SetupError::DriveOverlap);
            }
        }
        Ok(())
    }
}

/// Whether two ranges of identifiers (the first, and the count from it) share one.
fn overlap((a, n): (OutputId, u32), (b, m): (OutputId, u32)) -> bool {
    a.is_extended() == b.is_extended()
        && a.raw() < b.raw().saturating_add(m)
        && b.raw() < a.raw().saturating_add(n)
}

impl Setup {
    /// Checks the loop's set-up, the drive's identifiers and the sensors' topics (each within
    /// its format, off the drive's frames, its field within a frame), and that the innate
    /// schemas read only sensors it has.
    pub fn check(&self) -> Result<(), SetupError> {
        self.config.check().map_err(SetupError::Config)?;
        self.drive.check()?;
        let ranges = self.drive.ranges();
        for (i, s) in self.sensors.iter().enumerate() {
            let refuse = |e| SetupError::Sensor(i as u8, e);
            s.id.validate().map_err(|e| refuse(SensorError::Id(e)))?;
            s.field
                .validate()
                .map_err(|e| refuse(SensorError::Field(e)))?;
            if ranges.iter().any(|r| overlap(*r, (s.id, 1))) {
                return Err(refuse(SensorError::DriveOverlap));
            }
        }
        if let Some(i) = self
            .config
            .limits
            .joints
            .iter()
            .position(|j| usize::from(j.sensor) >= self.sensors.len())
        {
            return Err(SetupError::UnknownJointSensor(i as u8));
        }
        for (i, schema) in self.config.innate.iter().enumerate() {
            let unknown = schema.reactions.iter().any(|r| match r.event {
                Event::Above(Measure::Sensor(s), _) | Event::Below(Measure::Sensor(s), _) => {
                    usize::from(s) >= self.sensors.len()
                }
                _ => false,
            });
            if unknown {
                return Err(SetupError::UnknownSensor(i as u8));
            }
        }
        Ok(())
    }
}

impl core::fmt::Display for SetupError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SetupError::Config(ConfigError::Period) => {
                f.write_str("schema server: a period of 0, or an overrun bound below the period")
            }
            SetupError::Config(ConfigError::Limits(e)) => write!(f, "schema server: {e}"),
            SetupError::Config(ConfigError::DriveLimits) => {
                f.write_str("schema server: a drive speed or rate of 0")
            }
            SetupError::Config(ConfigError::Innate(i)) => {
                write!(f, "schema server: innate schema {i} is invalid")
            }
            SetupError::DriveId(e) => write!(f, "schema server: a drive identifier: {e}"),
            SetupError::DriveOverlap => {
                f.write_str("schema server: two of the drive's frames share an identifier")
            }
            SetupError::Sensor(i, SensorError::Id(e)) => {
                write!(f, "schema server: sensor {i}'s identifier: {e}")
            }
            SetupError::Sensor(i, SensorError::Field(e)) => {
                write!(f, "schema server: sensor {i}'s field: {e}")
            }
            SetupError::Sensor(i, SensorError::DriveOverlap) => {
                write!(
                    f,
                    "schema server: sensor {i} is on one of the drive's frames"
                )
            }
            SetupError::UnknownJointSensor(i) => write!(
                f,
                "schema server: joint {i} is read from a sensor the set-up has no topic for"
            ),
            SetupError::UnknownSensor(i) => write!(
                f,
                "schema server: innate schema {i} reads a sensor the set-up has no topic for"
            ),
        }
    }
}

impl core::error::Error for SetupError {}

decode_struct!(Config {
    period_us,
    overrun_us,
    limits,
    stale_us,
    sensor_stale_us,
    watchdog_margin_ms,
    drive_speed,
    drive_rate,
    pose_noise,
    stiffness,
    damping,
    innate
});
decode_struct!(Drive {
    setpoint,
    pose,
    wrench
});
decode_struct!(Setup {
    config,
    drive,
    sensors
});
