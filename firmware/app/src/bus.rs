//! The seam between the application and a CAN driver: two async methods. The board wraps
//! embassy-stm32's FDCAN, the Linux node a SocketCAN socket, the tests an in-process bus.

use pab_core::Frame;

/// What a driver reports instead of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum BusError {
    /// Frames were lost before they were read (receive FIFO or socket buffer overflow), how many
    /// unknown.
    Overrun,
    /// Exactly this many frames were lost before the frame the driver read next (the Linux
    /// kernel's drop counter). A driver reports it only with a frame in hand, which its next
    /// `receive` returns at once: the runner reads on without pausing.
    Dropped(u32),
    /// The controller went error-passive.
    ErrorPassive,
    /// The controller went bus-off.
    BusOff,
    /// The controller is back to error-active after [`BusError::ErrorPassive`] or
    /// [`BusError::BusOff`].
    Recovered,
    /// Any other error the controller flagged (a driver-specific code: stuff, form, ack, CRC...).
    Other(u8),
}

impl core::fmt::Display for BusError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            BusError::Overrun => f.write_str("received frames were lost before they were read"),
            BusError::Dropped(count) => write!(f, "{count} received frames were lost"),
            BusError::ErrorPassive => f.write_str("the controller is error-passive"),
            BusError::BusOff => f.write_str("the controller is bus-off"),
            BusError::Recovered => f.write_str("the controller is back to error-active"),
            BusError::Other(kind) => write!(f, "bus error (driver kind {kind})"),
        }
    }
}

impl core::error::Error for BusError {}

/// A CAN interface as the application needs it.
///
/// Both futures must be cancel-safe: the runner drops a pending `receive` when a timer fires
/// first, and no frame may be lost by that (embassy's FDCAN and async SocketCAN reads are).
#[allow(async_fn_in_trait)]
pub trait CanBus {
    /// The next frame from the bus, or what went wrong instead.
    async fn receive(&mut self) -> Result<Frame, BusError>;
    /// Queues `frame` for transmission; an error means it was not sent.
    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError>;
}
