//! Who receives what a port delivers: the node's own application, or also the bus.
//!
//! A node in front of an actuator that cannot be changed (a third-party drive that listens on
//! 0x300) arbitrates the competing streams and re-publishes the winner's frames on the identifier
//! the actuator listens to: a gateway. The port's [`Consumer`] records that identifier; the
//! runner that owns the CAN driver does the sending (`pab-core` has no I/O).

use embedded_can::{ExtendedId, Id, StandardId};
use serde::{Deserialize, Serialize};

use crate::filter::{MAX_EXTENDED_ID, MAX_STANDARD_ID};

/// Where the frames a port delivers go.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Consumer {
    /// Delivered frames go to the node's own application only.
    #[default]
    Local,
    /// Delivered frames are also re-published on the bus with this identifier (a gateway in front
    /// of an unchanged actuator).
    Republish(OutputId),
}

impl Consumer {
    /// Checks the identifier of a [`Consumer::Republish`]; [`Consumer::Local`] is always valid.
    /// Costs two comparisons.
    pub const fn validate(&self) -> Result<(), OutputIdError> {
        match self {
            Consumer::Local => Ok(()),
            Consumer::Republish(id) => id.validate(),
        }
    }
}

/// A CAN identifier to publish on: 11-bit (standard) or 29-bit (extended).
///
/// Invariant (checked by [`OutputId::new`] and by the table loader): `raw` fits the format,
/// at most [`MAX_STANDARD_ID`] for a standard identifier, at most [`MAX_EXTENDED_ID`] for an
/// extended one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OutputId {
    raw: u32,
    extended: bool,
}

// Not `#[non_exhaustive]`: an identifier is standard or extended: there is no third way to be too
// wide.
/// Why an [`OutputId`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OutputIdError {
    /// A standard identifier above [`MAX_STANDARD_ID`].
    StandardTooWide,
    /// An extended identifier above [`MAX_EXTENDED_ID`].
    ExtendedTooWide,
}

impl core::fmt::Display for OutputIdError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            OutputIdError::StandardTooWide => write!(
                f,
                "a standard (11-bit) output id is at most {MAX_STANDARD_ID:#x}"
            ),
            OutputIdError::ExtendedTooWide => write!(
                f,
                "an extended (29-bit) output id is at most {MAX_EXTENDED_ID:#x}"
            ),
        }
    }
}

impl core::error::Error for OutputIdError {}

impl OutputId {
    /// The identifier `raw`, extended (29-bit) or standard (11-bit). Fails if `raw` does not fit.
    pub const fn new(raw: u32, extended: bool) -> Result<OutputId, OutputIdError> {
        let id = OutputId { raw, extended };
        match id.validate() {
            Ok(()) => Ok(id),
            Err(error) => Err(error),
        }
    }

    /// Checks the invariant (an `OutputId` decoded from bytes has not been checked yet; the table
    /// loader calls this).
    pub const fn validate(&self) -> Result<(), OutputIdError> {
        if self.extended {
            if self.raw > MAX_EXTENDED_ID {
                return Err(OutputIdError::ExtendedTooWide);
            }
        } else if self.raw > MAX_STANDARD_ID {
            return Err(OutputIdError::StandardTooWide);
        }
        Ok(())
    }

    /// The identifier's number.
    pub const fn raw(&self) -> u32 {
        self.raw
    }

    /// Whether it is a 29-bit identifier.
    pub const fn is_extended(&self) -> bool {
        self.extended
    }

    /// The identifier for a CAN driver. For an `OutputId` that breaks the invariant (possible only
    /// by decoding bytes without validating them) the bits above the format's width are dropped.
    pub fn id(&self) -> Id {
        if self.extended {
            Id::Extended(ExtendedId::new(self.raw & MAX_EXTENDED_ID).unwrap_or(ExtendedId::ZERO))
        } else {
            // The mask keeps 11 bits, so the conversion to u16 cannot fail.
            let raw = u16::try_from(self.raw & MAX_STANDARD_ID).unwrap_or(0);
            Id::Standard(StandardId::new(raw).unwrap_or(StandardId::ZERO))
        }
    }
}

crate::wire::decode_struct!(OutputId { raw, extended });

impl crate::wire::Decode for Consumer {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        match r.variant(2) {
            0 => Consumer::Local,
            _ => Consumer::Republish(r.decode()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_are_checked_against_their_format() {
        assert_eq!(
            OutputId::new(0x7FF, false).map(|id| id.id()),
            Ok(Id::Standard(StandardId::new(0x7FF).unwrap()))
        );
        assert_eq!(
            OutputId::new(0x800, false),
            Err(OutputIdError::StandardTooWide)
        );
        assert_eq!(
            OutputId::new(0x1FFF_FFFF, true).map(|id| id.id()),
            Ok(Id::Extended(ExtendedId::new(0x1FFF_FFFF).unwrap()))
        );
        assert_eq!(
            OutputId::new(0x2000_0000, true),
            Err(OutputIdError::ExtendedTooWide)
        );
        let id = OutputId::new(0x300, false).unwrap();
        assert_eq!((id.raw(), id.is_extended()), (0x300, false));
        assert_eq!(Consumer::Republish(id).validate(), Ok(()));
        assert_eq!(Consumer::default(), Consumer::Local);
    }

    #[test]
    fn an_unchecked_identifier_is_masked_not_trusted() {
        let bad = OutputId {
            raw: 0x1234,
            extended: false,
        };
        assert_eq!(
            Consumer::Republish(bad).validate(),
            Err(OutputIdError::StandardTooWide)
        );
        assert_eq!(bad.id(), Id::Standard(StandardId::new(0x234).unwrap()));
    }
}
