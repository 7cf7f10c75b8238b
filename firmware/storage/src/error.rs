//! The store's typed errors.

use embedded_storage::nor_flash::{NorFlashError, NorFlashErrorKind};
use pab_core::decimal::Decimal;

/// What went wrong in the flash driver (from [`NorFlashError::kind`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashErrorKind {
    /// An address or length was not aligned to the flash's read, write or erase size.
    NotAligned,
    /// An address was outside the flash.
    OutOfBounds,
    /// Any other driver error (programming error, write protection, power loss in a simulation).
    Other,
}

impl FlashErrorKind {
    /// The kind of a driver error.
    pub fn of<E: NorFlashError>(error: &E) -> Self {
        match error.kind() {
            NorFlashErrorKind::NotAligned => FlashErrorKind::NotAligned,
            NorFlashErrorKind::OutOfBounds => FlashErrorKind::OutOfBounds,
            _ => FlashErrorKind::Other,
        }
    }
}

/// Why a flash range cannot hold a store (from [`crate::FlashStore::new`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LayoutError {
    /// The range's start or end is not on an erase-page boundary.
    RangeNotPageAligned,
    /// The range ends beyond the flash's capacity, or is empty or reversed.
    RangeOutOfBounds,
    /// The slot size is zero or not a whole number of erase pages.
    SlotSizeNotPageMultiple,
    /// The range is not a whole number of slots.
    RangeNotSlotMultiple,
    /// The range holds fewer than two slots (a store) or two erase pages (a boot counter).
    RangeTooSmall,
    /// The flash's read or write size does not divide the store's 256-byte transfer buffer, or
    /// its erase size is not a multiple of them.
    UnsupportedGeometry,
}

// Not `#[non_exhaustive]`: a node maps each variant to its own StoreFailure code on the bus
// (pab-app's `node/mod.rs`), so that a new variant gets a code rather than `Other`.
/// Why a [`crate::TableStore`] operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash driver failed.
    Flash(FlashErrorKind),
    /// The flash range given to [`crate::FlashStore::new`] cannot hold a store.
    Layout(LayoutError),
    /// The image is larger than a slot holds (the slot size less its header).
    ImageTooLarge {
        /// Bytes of the image.
        len: usize,
        /// The largest image a slot holds, in bytes ([`crate::FlashStore::capacity`]).
        capacity: u32,
    },
    /// The buffer given to `load` is smaller than the stored image.
    BufferTooSmall {
        /// Bytes of the stored image.
        needed: usize,
        /// Bytes of the buffer.
        got: usize,
    },
    /// Images were committed (at least one slot header verifies), but no committed slot holds
    /// the bytes its header describes: the flash was altered behind the store's back.
    Corrupt,
    /// The newest slot's sequence number is `u32::MAX`, so no newer one can be written. Four
    /// billion saves are beyond any flash's endurance: in practice the range holds a header
    /// planted by something else. [`crate::FlashStore::format`] clears it.
    SequenceExhausted,
    /// After programming, the slot does not read back as written (a failing flash).
    VerifyFailed,
    /// [`crate::TableStore::continue_save`] without a save in progress, or with another image
    /// than the one [`crate::TableStore::start_save`] was given (nothing was committed).
    NoSave,
}

/// Why a [`crate::BootCounter`] operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CounterError {
    /// The flash driver failed (or the power went during the call: the next boot's
    /// `increment` still returns a value never returned before).
    Flash(FlashErrorKind),
    /// The flash range given to [`crate::BootCounter::new`] cannot hold a counter.
    Layout(LayoutError),
    /// The count is `u32::MAX`: no new value exists. Four billion boots are beyond any flash's
    /// endurance, so in practice the pages hold a planted record;
    /// [`crate::BootCounter::format`] clears it (together with a new key only: the count
    /// starts again at 1).
    Exhausted,
    /// The new record does not read back as written (a failing flash).
    VerifyFailed,
}

impl CounterError {
    /// A number for this error, for a fault's detail byte (the boards report it with the
    /// `KeyPageInvalid` fault, docs/can-protocol.md): 1 flash, 2 layout, 3 exhausted,
    /// 4 verify failed.
    pub const fn code(self) -> u8 {
        match self {
            CounterError::Flash(_) => 1,
            CounterError::Layout(_) => 2,
            CounterError::Exhausted => 3,
            CounterError::VerifyFailed => 4,
        }
    }
}

impl core::fmt::Display for CounterError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CounterError::Flash(kind) => write!(f, "boot counter flash: {kind}"),
            CounterError::Layout(error) => write!(f, "boot counter layout: {error}"),
            CounterError::Exhausted => f.write_str("boot count exhausted (new key, then format)"),
            CounterError::VerifyFailed => {
                f.write_str("boot counter record does not read back as written")
            }
        }
    }
}

impl core::error::Error for CounterError {}

impl core::fmt::Display for FlashErrorKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FlashErrorKind::NotAligned => "unaligned access",
            FlashErrorKind::OutOfBounds => "access out of bounds",
            FlashErrorKind::Other => "driver error",
        })
    }
}

impl core::fmt::Display for LayoutError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            LayoutError::RangeNotPageAligned => "range not aligned to erase pages",
            LayoutError::RangeOutOfBounds => "range empty or beyond the flash",
            LayoutError::SlotSizeNotPageMultiple => {
                "slot size not a positive whole number of erase pages"
            }
            LayoutError::RangeNotSlotMultiple => "range not a whole number of slots",
            LayoutError::RangeTooSmall => "range smaller than two slots",
            LayoutError::UnsupportedGeometry => "unsupported read, write or erase size",
        })
    }
}

impl core::error::Error for LayoutError {}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            // Written in two pieces, not through `write!`: the same text without the
            // arguments' formatting (the kind's and the error's `Display` through a reference,
            // two copies of some 46 bytes on the emulated board).
            StoreError::Flash(kind) => {
                f.write_str("flash: ")?;
                kind.fmt(f)
            }
            StoreError::Layout(error) => {
                f.write_str("store layout: ")?;
                error.fmt(f)
            }
            StoreError::ImageTooLarge { len, capacity } => {
                let (len, capacity) = (Bytes(*len), Decimal::new(*capacity));
                write!(
                    f,
                    "image of {len} bytes exceeds the {capacity} bytes a slot holds"
                )
            }
            StoreError::BufferTooSmall { needed, got } => {
                let (needed, got) = (Bytes(*needed), Bytes(*got));
                write!(f, "buffer of {got} bytes, the stored image has {needed}")
            }
            StoreError::Corrupt => f.write_str("no committed image verifies (flash corrupted)"),
            StoreError::SequenceExhausted => {
                f.write_str("sequence numbers exhausted (format the range)")
            }
            StoreError::VerifyFailed => f.write_str("slot does not read back as written"),
            StoreError::NoSave => f.write_str("no save in progress for this image"),
        }
    }
}

impl core::error::Error for StoreError {}

/// A byte count, written through [`Decimal`] whenever it fits in a `u32` (always on the boards,
/// where `usize` is 32 bits): the same digits as `{}`, but the emulated board, which logs through
/// `core::fmt`, needs no integer formatter of `core::fmt` in its flash (`usize`'s took 224 bytes,
/// `u32`'s and its padding some 630).
struct Bytes(usize);

impl core::fmt::Display for Bytes {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match u32::try_from(self.0) {
            Ok(bytes) => Decimal::new(bytes).fmt(f),
            Err(_) => self.0.fmt(f),
        }
    }
}

impl From<CounterError> for StoreError {
    /// A configuration page's failure as the store's ([`crate::SettingsPage`] is a boot counter).
    fn from(error: CounterError) -> StoreError {
        match error {
            CounterError::Flash(kind) => StoreError::Flash(kind),
            CounterError::Layout(layout) => StoreError::Layout(layout),
            CounterError::Exhausted => StoreError::SequenceExhausted,
            CounterError::VerifyFailed => StoreError::VerifyFailed,
        }
    }
}
