//! Which CAN frames feed a connection: an identifier and a mask, standard or extended.
//!
//! Connections match raw identifiers so that frames from devices we do not control (a sensor that
//! sends on 0x1A0) can be arbitrated as they are. A standard and an extended identifier with the
//! same number are different topics, as on the bus.

use embedded_can::Id;
use serde::{Deserialize, Serialize};

/// The largest 11-bit identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;
/// The largest 29-bit identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// A frame matches when it has the same format and `frame_id & mask == id`.
///
/// Invariants (checked by [`Filter::new`] and the table loader): `id` and `mask` fit the format's
/// width, and `id` has no bit outside `mask` (such a filter could never match anything).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Filter {
    id: u32,
    mask: u32,
    extended: bool,
}

impl Filter {
    /// A filter on `id` under `mask`.
    pub const fn new(id: u32, mask: u32, extended: bool) -> Result<Filter, FilterError> {
        let filter = Filter { id, mask, extended };
        match filter.validate() {
            Ok(()) => Ok(filter),
            Err(error) => Err(error),
        }
    }

    /// A filter that matches exactly one identifier.
    pub const fn exact(id: u32, extended: bool) -> Result<Filter, FilterError> {
        let mask = if extended {
            MAX_EXTENDED_ID
        } else {
            MAX_STANDARD_ID
        };
        Filter::new(id, mask, extended)
    }

    /// Checks the invariants.
    // Out of line: the loader checks a connection's, a BLE group's and a dynamics topic's
    // filters, and inlined at the three it took 76 bytes more of the NUCLEO-G474RE's flash (128
    // without the schema server). Run once per table.
    #[inline(never)]
    pub const fn validate(&self) -> Result<(), FilterError> {
        let widest = if self.extended {
            MAX_EXTENDED_ID
        } else {
            MAX_STANDARD_ID
        };
        if self.id > widest {
            Err(FilterError::IdTooWide)
        } else if self.mask > widest {
            Err(FilterError::MaskTooWide)
        } else if self.id & !self.mask != 0 {
            Err(FilterError::IdOutsideMask)
        } else {
            Ok(())
        }
    }

    /// Whether a frame with identifier `frame` feeds this filter's connection. Two comparisons.
    pub fn matches(&self, frame: &Id) -> bool {
        match frame {
            Id::Standard(id) => !self.extended && u32::from(id.as_raw()) & self.mask == self.id,
            Id::Extended(id) => self.extended && id.as_raw() & self.mask == self.id,
        }
    }

    /// The filter as a key of the arbiter's index ([`key_of`]) when it matches exactly one
    /// identifier (its mask is the format's full width), `None` when it matches a range.
    pub(crate) const fn exact_key(&self) -> Option<u32> {
        let widest = if self.extended {
            MAX_EXTENDED_ID
        } else {
            MAX_STANDARD_ID
        };
        if self.mask == widest {
            Some(key(self.id, self.extended))
        } else {
            None
        }
    }

    /// The identifier.
    pub const fn id(&self) -> u32 {
        self.id
    }

    /// The mask.
    pub const fn mask(&self) -> u32 {
        self.mask
    }

    /// Whether the identifier is 29 bits.
    pub const fn is_extended(&self) -> bool {
        self.extended
    }
}

/// An identifier as one number, the format in bit 31 (free in both: 29 bits at most), so that a
/// standard and an extended identifier with the same number are different keys.
const fn key(raw: u32, extended: bool) -> u32 {
    raw | (extended as u32) << 31
}

/// The key of a frame's identifier, as [`Filter::exact_key`] gives it for the filter that
/// matches exactly that identifier.
pub(crate) fn key_of(frame: &Id) -> u32 {
    match frame {
        Id::Standard(id) => key(u32::from(id.as_raw()), false),
        Id::Extended(id) => key(id.as_raw(), true),
    }
}

/// Why a filter was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FilterError {
    /// The identifier does not fit 11 bits (standard) or 29 bits (extended).
    IdTooWide,
    /// The mask does not fit 11 bits (standard) or 29 bits (extended).
    MaskTooWide,
    /// The identifier has bits that the mask clears: no frame could ever match.
    IdOutsideMask,
}

impl core::fmt::Display for FilterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FilterError::IdTooWide => {
                "CAN id does not fit its format (0x7FF standard, 0x1FFFFFFF extended)"
            }
            FilterError::MaskTooWide => {
                "CAN mask does not fit its format (0x7FF standard, 0x1FFFFFFF extended)"
            }
            FilterError::IdOutsideMask => {
                "CAN id has bits outside the mask, so no frame could ever match"
            }
        })
    }
}

impl core::error::Error for FilterError {}

crate::wire::decode_struct!(Filter { id, mask, extended });

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::{ExtendedId, StandardId};

    fn standard(raw: u16) -> Id {
        Id::Standard(StandardId::new(raw).unwrap())
    }

    fn extended(raw: u32) -> Id {
        Id::Extended(ExtendedId::new(raw).unwrap())
    }

    #[test]
    fn exact_filters_match_one_id_of_one_format() {
        let filter = Filter::exact(0x110, false).unwrap();
        assert!(filter.matches(&standard(0x110)));
        assert!(!filter.matches(&standard(0x111)));
        assert!(!filter.matches(&extended(0x110)));
        let filter = Filter::exact(0x1ABC_DEF0, true).unwrap();
        assert!(filter.matches(&extended(0x1ABC_DEF0)));
        assert!(!filter.matches(&extended(0x0ABC_DEF0)));
    }

    #[test]
    fn masks_select_ranges() {
        let filter = Filter::new(0x100, 0x7F0, false).unwrap();
        for raw in 0x100..=0x10F {
            assert!(filter.matches(&standard(raw)));
        }
        assert!(!filter.matches(&standard(0x110)));
        assert!(!filter.matches(&standard(0x0FF)));
    }

    #[test]
    fn invalid_filters_are_refused() {
        assert_eq!(Filter::exact(0x800, false), Err(FilterError::IdTooWide));
        assert_eq!(
            Filter::exact(0x2000_0000, true),
            Err(FilterError::IdTooWide)
        );
        assert_eq!(
            Filter::new(0x1, 0xFFF, false),
            Err(FilterError::MaskTooWide)
        );
        assert_eq!(
            Filter::new(0x101, 0x7F0, false),
            Err(FilterError::IdOutsideMask)
        );
    }
}
