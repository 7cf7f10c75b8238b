//! The store's typed errors.

use embedded_storage_async::nor_flash::{NorFlashError, NorFlashErrorKind};

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
pub enum LayoutError {
    /// The range's start or end is not on an erase-page boundary.
    RangeNotPageAligned,
    /// The range ends beyond the flash's capacity, or is empty or reversed.
    RangeOutOfBounds,
    /// The slot size is zero or not a whole number of erase pages.
    SlotSizeNotPageMultiple,
    /// Two slots and a commit log of at least two pages do not fit in the range.
    RangeTooSmall,
    /// The flash's read or write size does not divide the store's 256-byte transfer buffer, or
    /// its erase size is not a multiple of them.
    UnsupportedGeometry,
    /// `sequential-storage` refused the commit log's range (pages too small, words too large).
    LogRefused,
}

/// What the commit log (`sequential-storage`) reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LogErrorKind {
    /// The log's pages hold data that is not a log, and repairing them failed (for example a
    /// range full of unrelated bytes).
    Corrupted,
    /// The log is full (cannot happen with two keys and two pages unless the flash misbehaves).
    Full,
    /// A commit record did not decode (unknown record format).
    BadRecord,
    /// Any other report of the log crate (a buffer or logic error on its side).
    Internal,
}

/// Why a [`crate::TableStore`] operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The flash driver failed.
    Flash(FlashErrorKind),
    /// The flash range given to [`crate::FlashStore::new`] cannot hold a store.
    Layout(LayoutError),
    /// The image is larger than a slot.
    ImageTooLarge {
        /// Bytes of the image.
        len: usize,
        /// Bytes of a slot.
        slot_size: u32,
    },
    /// The buffer given to `load` is smaller than the stored image.
    BufferTooSmall {
        /// Bytes of the stored image.
        needed: usize,
        /// Bytes of the buffer.
        got: usize,
    },
    /// Images were committed, but no committed slot holds the bytes its commit describes (the
    /// flash was altered behind the store's back: both copies are damaged).
    Corrupt,
    /// The commit log failed.
    Log(LogErrorKind),
    /// After programming, the slot does not read back as the image (a failing flash).
    VerifyFailed,
}

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
            LayoutError::RangeTooSmall => "range smaller than two slots and two log pages",
            LayoutError::UnsupportedGeometry => "unsupported read, write or erase size",
            LayoutError::LogRefused => "commit log refused its range",
        })
    }
}

impl core::fmt::Display for LogErrorKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            LogErrorKind::Corrupted => "corrupted beyond repair",
            LogErrorKind::Full => "full",
            LogErrorKind::BadRecord => "commit record does not decode",
            LogErrorKind::Internal => "internal error",
        })
    }
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StoreError::Flash(kind) => write!(f, "flash: {kind}"),
            StoreError::Layout(error) => write!(f, "store layout: {error}"),
            StoreError::ImageTooLarge { len, slot_size } => {
                write!(f, "image of {len} bytes exceeds the {slot_size}-byte slot")
            }
            StoreError::BufferTooSmall { needed, got } => {
                write!(f, "buffer of {got} bytes, the stored image has {needed}")
            }
            StoreError::Corrupt => f.write_str("no committed image verifies (flash corrupted)"),
            StoreError::Log(kind) => write!(f, "commit log: {kind}"),
            StoreError::VerifyFailed => f.write_str("slot does not read back as written"),
        }
    }
}

impl core::error::Error for StoreError {}

impl<E: NorFlashError> From<sequential_storage::Error<E>> for StoreError {
    fn from(error: sequential_storage::Error<E>) -> Self {
        use sequential_storage::Error;
        match error {
            Error::Storage { value, .. } => StoreError::Flash(FlashErrorKind::of(&value)),
            Error::Corrupted { .. } => StoreError::Log(LogErrorKind::Corrupted),
            Error::FullStorage => StoreError::Log(LogErrorKind::Full),
            Error::SerializationError(_) => StoreError::Log(LogErrorKind::BadRecord),
            _ => StoreError::Log(LogErrorKind::Internal),
        }
    }
}
