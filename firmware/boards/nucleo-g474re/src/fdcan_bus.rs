//! The application's [`CanBus`] over embassy-stm32's FDCAN driver in buffered mode.
//!
//! Receiving: the FDCAN interrupt drains the hardware RX FIFO (3 frames on the G4) into a
//! [`RxQueue`] of [`RX_QUEUE`] entries, so frames that arrive while the node task is busy
//! (arbitrating, waiting to transmit) wait there instead of overflowing the hardware FIFO.
//!
//! **Cancel safety.** The runner drops a pending [`CanBus::receive`] when its timer fires first.
//! `receive` awaits `BufferedCan::read`, which is `Channel::receive` on that queue: it takes an
//! entry out of the channel only in the poll that returns it, so dropping the future before it
//! completed leaves every frame in the queue for the next call. The periodic check of the
//! controller state in between keeps its memory in `self.mode`, updated only in the poll that
//! returns the change, so no transition is lost either.
//!
//! Transmitting: frames go into a [`TxQueue`] that the interrupt feeds into the controller's TX
//! FIFO (FIFO mode: frames leave in the order they were queued, which ISO-TP needs, and a full
//! FIFO never aborts a pending frame as the driver's priority mode would). When the queue stays
//! full for [`TX_TIMEOUT`] (nobody acknowledges, bus-off) the frame is dropped and reported, so
//! the node keeps reading instead of blocking behind a dead bus. Identifier order is the node's
//! outbox's work (`pab_app::node::OUTBOX_LEN`): frames already in this queue and the TX FIFO leave
//! first in first out. The FDCAN's TX queue mode (`TxBufferMode::Priority`) is not used: it
//! sends equal identifiers by buffer number, not in queue order, which would reorder a
//! diagnostic round.
//!
//! Errors: the driver reports protocol errors (the controller's last error code: stuff, form,
//! acknowledge, bit, CRC) as they are seen; error-passive and bus-off are states it does not
//! report, so `receive` also looks at the controller state every [`STATE_POLL`] and reports each
//! change (`ErrorPassive`, `BusOff`, `Recovered`). Bus-off recovery is automatic (the driver
//! restarts the controller after the bus-off sequence). Known limit: when the RX queue is full
//! the interrupt drops frames silently (the driver does not count them), so no
//! [`BusError::Overrun`] is reported for them.

use embassy_futures::select::{Either, select};
use embassy_stm32::can::enums::BusErrorMode;
use embassy_stm32::can::frame::Header;
use embassy_stm32::can::{self, BufferedCan};
use embassy_time::{Duration, Instant, Timer, with_deadline};
use pab_app::{BusError, CanBus};
use pab_core::Frame;

/// Frames the RX queue holds (about 8 ms of a fully loaded bus at 500 kbit/s).
pub const RX_QUEUE: usize = 32;
/// Frames the TX queue holds (a heartbeat group and an ISO-TP flow control with room to spare).
pub const TX_QUEUE: usize = 16;
/// How long `transmit` waits for room in the TX queue before it drops the frame.
pub const TX_TIMEOUT: Duration = Duration::from_millis(10);
/// How often `receive` looks at the controller state (error-active, error-passive, bus-off).
pub const STATE_POLL: Duration = Duration::from_millis(50);

/// The receive queue's storage (a `static`: the driver keeps a reference).
pub type RxQueue = can::RxBuf<RX_QUEUE>;
/// The transmit queue's storage.
pub type TxQueue = can::TxBuf<TX_QUEUE>;

/// The controller state as last reported to the node.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Active,
    Passive,
    Off,
}

/// FDCAN1 as the node's bus.
pub struct FdcanBus {
    can: BufferedCan<'static, TX_QUEUE, RX_QUEUE>,
    mode: Mode,
}

impl FdcanBus {
    /// Wraps a started, buffered FDCAN instance.
    pub fn new(can: BufferedCan<'static, TX_QUEUE, RX_QUEUE>) -> Self {
        FdcanBus {
            can,
            mode: Mode::Active,
        }
    }

    /// The controller state's change since the last report, as the error to report; `None` if
    /// it did not change.
    fn state_change(&mut self) -> Option<BusError> {
        let mode = match self.can.properties().bus_error_mode() {
            BusErrorMode::ErrorActive => Mode::Active,
            BusErrorMode::ErrorPassive => Mode::Passive,
            BusErrorMode::BusOff => Mode::Off,
        };
        if mode == self.mode {
            return None;
        }
        self.mode = mode;
        Some(match mode {
            Mode::Active => BusError::Recovered,
            Mode::Passive => BusError::ErrorPassive,
            Mode::Off => BusError::BusOff,
        })
    }
}

impl CanBus for FdcanBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        loop {
            if let Some(change) = self.state_change() {
                return Err(change);
            }
            match select(self.can.read(), Timer::at(after(STATE_POLL))).await {
                Either::First(Ok(envelope)) => {
                    return Ok(pab_core::frame::from_frame(&envelope.frame));
                }
                Either::First(Err(error)) => return Err(protocol_error(&error)),
                Either::Second(()) => {}
            }
        }
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        // One constructor for data and remote frames (the driver's `new_data` and `new_remote`
        // were two inlined copies, 112 bytes of flash). A remote frame's payload is empty, so its
        // DLC is 0, as `new_remote(id, frame.payload().len())` made it; a payload has at most 8
        // bytes, so its length fits the header's `u8`.
        let payload = frame.payload();
        let header = Header::new(frame.id(), payload.len() as u8, frame.is_remote());
        let Ok(outgoing) = can::frame::Frame::new(header, payload) else {
            // Unreachable for a pab_core::Frame (at most 8 bytes, valid id); reported all the same.
            return Err(BusError::Other(0xFF));
        };
        with_deadline(after(TX_TIMEOUT), self.can.write(outgoing))
            .await
            .map_err(|_| BusError::Overrun)
    }
}

/// `delay` from now, on the clock the node loop reads out of line ([`pab_app::now`]):
/// `Timer::after` and `with_timeout` inlined a copy of the time driver's read each, and an
/// overflow check (132 bytes of flash).
fn after(delay: Duration) -> Instant {
    Instant::from_micros(pab_app::now().as_micros().saturating_add(delay.as_micros()))
}

/// The driver's protocol errors as [`BusError::Other`], with the FDCAN's last-error-code number
/// as the detail byte (1 stuff, 2 form, 3 acknowledge, 4 bit recessive, 5 bit dominant, 6 CRC).
fn protocol_error(error: &can::enums::BusError) -> BusError {
    use can::enums::BusError as Driver;
    BusError::Other(match error {
        Driver::Stuff => 1,
        Driver::Form => 2,
        Driver::Acknowledge => 3,
        Driver::BitRecessive => 4,
        Driver::BitDominant => 5,
        Driver::Crc => 6,
        Driver::Software => 7,
    })
}
