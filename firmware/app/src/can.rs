//! Any CAN driver that implements `embedded-can`'s non-blocking trait, [`embedded_can::nb::Can`],
//! as the node's bus: [`EmbeddedCan`]. HALs' CAN drivers commonly do (the `bxcan` crate, which
//! stm32f4xx-hal's CAN is, among them; `socketcan`'s sockets on Linux too).
//!
//! One adapter serves both loops: [`crate::PollLoop`] calls its non-blocking
//! [`EmbeddedCan::try_receive`] and [`EmbeddedCan::try_transmit`] from a loop of yours (no
//! executor, no embassy), and it is a [`CanBus`] for the async loop (`run_watched`, feature
//! `embassy`) or a loop on another executor.
//!
//! `embedded_can::blocking::Can` is not adapted: its `receive` waits for a frame, and a loop that
//! waits there misses its deadlines on a quiet bus (no heartbeat, no fed watchdog). A driver
//! that offers only the blocking trait usually has a non-blocking read underneath: implement
//! [`embedded_can::nb::Can`] over that.
//!
//! The adapter is classic CAN: `embedded-can` 0.4's frame trait has no CAN FD (no FDF, no
//! bit-rate switch). A frame of more than 8 bytes read through it becomes a CAN FD frame without
//! the bit-rate switch, one of 8 bytes or fewer a classic one, and every frame is written with
//! the trait's `new`. A node on a CAN FD bus writes a [`CanBus`] of its own that keeps the kind
//! of each frame, as `pab-node`'s socket does (`firmware/linux/src/socket_bus.rs`).

use core::future::poll_fn;
use core::task::Poll;

use embedded_can::nb::Can;
use embedded_can::{Error as _, ErrorKind};
use pab_core::{Frame, Instant};

use crate::bus::{BusError, CanBus};

/// How long [`EmbeddedCan`]'s async `transmit` waits for room in the driver's transmit buffer
/// before it gives the frame up, µs: the NUCLEO-G474RE's driver waits as long. A bus where nobody
/// acknowledges keeps the controller's mailboxes full for ever; the loop must not wait with them
/// (it sends at most [`crate::SENDS_PER_TURN`] frames a turn, so a turn of failures takes at
/// most 160 ms). [`crate::PollLoop`] keeps a frame that found no room as long.
pub const TRANSMIT_TIMEOUT_US: u64 = 10_000;

/// [`BusError::Other`] detail for a frame given up after [`TRANSMIT_TIMEOUT_US`] without room in
/// the driver's transmit buffer.
pub const TRANSMIT_TIMED_OUT: u8 = 0x10;

/// [`BusError::Other`] detail for a frame the driver's frame type cannot represent (its
/// `embedded_can::Frame::new` refused it: a driver for fewer than 8 data bytes, say).
pub const FRAME_REFUSED: u8 = 0x11;

/// `embedded-can`'s error kinds as the node reports them. Lost received frames are
/// [`BusError::Overrun`]; the protocol errors become [`BusError::Other`] with the number the
/// CAN controllers' last-error-code fields give them (bxCAN's and FDCAN's alike): 1 stuff,
/// 2 form, 3 acknowledge, 4 bit, 6 CRC; anything else (`ErrorKind::Other` and kinds added to
/// `embedded-can` later) 0x0F. `embedded-can` has no kind for error-passive or bus-off: a driver
/// that knows them reports them through a [`CanBus`] of its own.
impl From<ErrorKind> for BusError {
    fn from(kind: ErrorKind) -> BusError {
        match kind {
            ErrorKind::Overrun => BusError::Overrun,
            ErrorKind::Stuff => BusError::Other(1),
            ErrorKind::Form => BusError::Other(2),
            ErrorKind::Acknowledge => BusError::Other(3),
            ErrorKind::Bit => BusError::Other(4),
            ErrorKind::Crc => BusError::Other(6),
            _ => BusError::Other(0x0F),
        }
    }
}

/// The time the node runs on. Any `FnMut() -> Instant` is one: `pab_app::now` under embassy, a
/// free-running hardware timer read by your own function, a test's virtual clock.
///
/// It must be monotonic and count microseconds; it may start anywhere. A 32-bit timer wraps (a
/// 1 MHz one after 71 minutes): extend it to 64 bits (keep the last reading and add what the
/// counter advanced since, with a wrapping subtraction); the loop reads the clock at every turn,
/// far more often than once per wrap.
pub trait Clock {
    /// Now.
    fn now(&mut self) -> Instant;
}

impl<F: FnMut() -> Instant> Clock for F {
    fn now(&mut self) -> Instant {
        self()
    }
}

/// An [`embedded_can::nb::Can`] driver `D` with clock `C`, as the node's bus.
///
/// - **Frames** convert both ways through [`embedded_can::Frame`] (pab's [`Frame`] is classic
///   CAN, at most 8 data bytes; remote frames pass).
/// - **Errors** are mapped by their [`embedded_can::Error::kind`] (`From<ErrorKind>` for
///   [`BusError`]).
/// - **Priority**: when the driver's transmit buffer is full, `transmit` may take out a pending
///   frame of lower priority for the new one and hand it back (bxCAN does). The adapter keeps
///   that frame and sends it before any other, so none is lost and frames of one identifier stay
///   in order (ISO-TP's depend on it).
/// - **Cost**: the adapter is the driver, the clock, one frame of the driver's type and a word;
///   a frame costs a conversion (a copy of at most 8 bytes) each way.
///
/// As a [`CanBus`] (for an async loop) it polls: a `receive` with no frame waiting wakes its
/// task again at once, so the executor never sleeps while the loop waits, and the core runs at
/// full power. On a board that must sleep between frames, write a [`CanBus`] around your driver's
/// receive interrupt instead (the NUCLEO-G474RE's is `fdcan_bus.rs`), or run [`crate::PollLoop`]
/// and sleep until the instant its turn returns, or the CAN interrupt, whichever comes first.
/// `transmit` waits for room in the driver's buffer at most [`TRANSMIT_TIMEOUT_US`] on the clock,
/// then fails with [`BusError::Other`]`(`[`TRANSMIT_TIMED_OUT`]`)`. Both futures are cancel-safe:
/// nothing is taken from the driver before it is returned.
pub struct EmbeddedCan<D: Can, C> {
    driver: D,
    clock: C,
    /// The frame the driver handed back for a higher-priority one, sent before any other.
    displaced: Option<D::Frame>,
}

impl<D: Can, C: Clock> EmbeddedCan<D, C> {
    /// `driver`, configured and running (bit timing, filters that let the node's traffic in),
    /// with `clock`.
    pub const fn new(driver: D, clock: C) -> EmbeddedCan<D, C> {
        EmbeddedCan {
            driver,
            clock,
            displaced: None,
        }
    }

    /// The driver, for what the node does not do (an interrupt acknowledged, a filter changed).
    pub fn driver(&mut self) -> &mut D {
        &mut self.driver
    }

    /// The driver and the clock back.
    pub fn into_parts(self) -> (D, C) {
        (self.driver, self.clock)
    }

    /// Now, on the adapter's clock: the time [`crate::PollLoop`] runs the node on.
    pub fn now(&mut self) -> Instant {
        self.clock.now()
    }

    /// The next received frame, `WouldBlock` if there is none, or the driver's error.
    pub fn try_receive(&mut self) -> nb::Result<Frame, BusError> {
        match self.driver.receive() {
            Ok(frame) => Ok(pab_core::frame::from_frame(&frame)),
            Err(nb::Error::WouldBlock) => Err(nb::Error::WouldBlock),
            Err(nb::Error::Other(error)) => Err(nb::Error::Other(error.kind().into())),
        }
    }

    /// Hands the frame the driver handed back earlier (if any) to the driver again: `Ok` once
    /// none is held, `WouldBlock` while there is no room for it, or the driver's error (the frame
    /// is lost). [`EmbeddedCan::try_transmit`] does it first; a loop calls it when it has nothing
    /// else to send, so that the frame does not wait for the next.
    pub fn try_flush(&mut self) -> nb::Result<(), BusError> {
        let Some(displaced) = self.displaced.take() else {
            return Ok(());
        };
        match self.driver.transmit(&displaced) {
            Ok(None) => Ok(()),
            // Another frame came back for it, of lower priority still: it goes next.
            Ok(Some(handed_back)) => {
                self.displaced = Some(handed_back);
                Err(nb::Error::WouldBlock)
            }
            Err(nb::Error::WouldBlock) => {
                self.displaced = Some(displaced);
                Err(nb::Error::WouldBlock)
            }
            Err(nb::Error::Other(error)) => Err(nb::Error::Other(error.kind().into())),
        }
    }

    /// Hands `frame` to the driver's transmit buffer: `Ok` once it is there, `WouldBlock` if there
    /// is no room (`frame` was not taken: offer it again later), or the driver's error (`frame`
    /// was not sent). A frame that the driver handed back earlier goes first: while it finds no
    /// room, `frame` waits too, and if the driver fails it, it is lost and the error returned.
    pub fn try_transmit(&mut self, frame: &Frame) -> nb::Result<(), BusError> {
        self.try_flush()?;
        let Some(outgoing) = to_driver_frame::<D::Frame>(frame) else {
            return Err(nb::Error::Other(BusError::Other(FRAME_REFUSED)));
        };
        match self.driver.transmit(&outgoing) {
            // Only a frame of lower priority than `frame` comes back, and `displaced` is empty
            // here: nothing is overwritten.
            Ok(handed_back) => {
                self.displaced = handed_back;
                Ok(())
            }
            Err(nb::Error::WouldBlock) => Err(nb::Error::WouldBlock),
            Err(nb::Error::Other(error)) => Err(nb::Error::Other(error.kind().into())),
        }
    }
}

/// pab's frame as the driver's; `None` when the driver's type cannot hold it.
fn to_driver_frame<F: embedded_can::Frame>(frame: &Frame) -> Option<F> {
    if frame.is_remote() {
        F::new_remote(frame.id(), embedded_can::Frame::dlc(frame))
    } else {
        F::new(frame.id(), frame.payload())
    }
}

impl<D: Can, C: Clock> CanBus for EmbeddedCan<D, C> {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        poll_fn(|context| match self.try_receive() {
            Ok(frame) => Poll::Ready(Ok(frame)),
            Err(nb::Error::Other(error)) => Poll::Ready(Err(error)),
            Err(nb::Error::WouldBlock) => {
                // A frame handed back by the driver goes out while the loop waits (a failure
                // to send it loses it: the next `transmit` would report the driver's state).
                let _ = self.try_flush();
                // Polled: see the type's documentation for what that costs.
                context.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        let start = self.clock.now();
        poll_fn(|context| match self.try_transmit(frame) {
            Ok(()) => Poll::Ready(Ok(())),
            Err(nb::Error::Other(error)) => Poll::Ready(Err(error)),
            Err(nb::Error::WouldBlock) => {
                let waited = self.clock.now().micros_since(start).unwrap_or(0);
                if waited >= TRANSMIT_TIMEOUT_US {
                    return Poll::Ready(Err(BusError::Other(TRANSMIT_TIMED_OUT)));
                }
                context.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await
    }
}
