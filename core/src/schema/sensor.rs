//! The board's extra sensors: topics beyond the drive's pose and wrench whose frames carry one
//! integer each, read into the server's sensor table ([`super::Measure::Sensor`]).
//!
//! The value the server sees is the field's integer as the frame carries it (counts): no scale
//! on the board. The network file writes a sensor's thresholds in its unit and the compiler
//! turns them into counts, so the board's comparisons stay exact and its code a field read.
//! This is the one reading of a sensor frame: the node and the simulator both call [`feed_sensors`].

use serde::{Deserialize, Serialize};

use super::Server;
use crate::consumer::OutputIdError;
use crate::value_port::{Field, FieldError};
use crate::wire::decode_struct;
use crate::{Frame, Instant, OutputId};

/// One extra sensor: the frames on `id` carry its value in `field`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sensor {
    /// The topic's identifier (exact: standard or extended).
    pub id: OutputId,
    /// Where the value is in the payload.
    pub field: Field,
}

/// Why a [`Sensor`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SensorError {
    /// Its identifier does not fit its format.
    Id(OutputIdError),
    /// Its field is not 1, 2 or 4 bytes within a classic frame.
    Field(FieldError),
    /// Its identifier is one of the drive's frames.
    DriveOverlap,
}

impl core::fmt::Display for SensorError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SensorError::Id(error) => write!(f, "sensor identifier: {error}"),
            SensorError::Field(error) => write!(f, "sensor field: {error}"),
            SensorError::DriveOverlap => {
                f.write_str("sensor identifier is one of the drive's frames")
            }
        }
    }
}

impl core::error::Error for SensorError {}

impl Sensor {
    /// The value `frame` carries for this sensor: `None` for another identifier or a payload
    /// too short for the field. An unsigned 4-byte value above `i32::MAX` reads as `i32::MAX`.
    pub fn read(&self, frame: &Frame) -> Option<i32> {
        if frame.raw_id() != (self.id.raw(), self.id.is_extended()) {
            return None;
        }
        let value = self.field.read(frame.payload())?;
        Some(i32::try_from(value).unwrap_or(i32::MAX))
    }
}

/// Hands `server` every value of `sensors` (by index) that `frame` carries; whether it carried
/// one. Several sensors may share a frame (each its own field).
pub fn feed_sensors(sensors: &[Sensor], frame: &Frame, server: &mut Server, now: Instant) -> bool {
    let mut read = false;
    for (i, sensor) in sensors.iter().enumerate() {
        if let Some(value) = sensor.read(frame) {
            read |= server.set_sensor(i, value, now);
        }
    }
    read
}

decode_struct!(Sensor { id, field });
