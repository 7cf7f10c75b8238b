//! The application's [`CanBus`] over SLCAN on UART0: the board is the adapter end of a serial
//! line CAN link (`pab-slcan`), and the host's `slcan` driver turns the other end into a
//! SocketCAN interface.
//!
//! - **Receiving**: bytes from the UART's ring go through a [`LineReader`] and a [`Device`];
//!   every frame line the host sends (`t`, `T`, `r`, `R`) is a frame from the bus. Commands
//!   (`O`, `C`, `S6`, `V`...) are answered and not passed on. A malformed line is answered with
//!   BEL and reported as [`BusError::Other`]`(`[`MALFORMED_LINE`]`)`, a line too long as
//!   [`BusError::Other`]`(`[`LINE_TOO_LONG`]`)`; bytes the UART lost as [`BusError::Overrun`];
//!   frames the modelled controller lost while a single-bank flash stalled the CPU (feature
//!   `single-bank`, [`uart::stalled_receive`]) as [`BusError::Dropped`] with their count.
//! - **Transmitting**: each frame of the node becomes one line (`format_frame`), queued whole in
//!   the UART's transmit ring; when the ring stays full for [`TX_TIMEOUT`] (nobody reads the
//!   line) the frame is dropped and reported. While the host has closed the channel (`C`), the
//!   node's frames are dropped and reported (`Err(`[`BusError::Other`]`(`[`CHANNEL_CLOSED`]`))`;
//!   the runner counts every failed transmission as a `TxOverrun` fault), as a
//!   controller that is off the bus.
//!
//! **Cancel safety.** The runner drops a pending `receive` when its timer fires. All of the
//! link's state (the partial line, the channel state) lives in [`SlcanBus`], and each poll
//! handles every byte it takes from the ring before it returns, so dropping the future loses no
//! byte. `transmit` queues a line whole or not at all, so a dropped `transmit` leaves no half line.
//! The adapter's answers (`z`, CR, BEL) are queued if the ring has room and otherwise dropped:
//! the kernel driver ignores them.

use core::future::poll_fn;
use core::task::Poll;

use embassy_time::{Duration, with_timeout};
use pab_app::{BusError, CanBus};
use pab_core::Frame;
use pab_slcan::{Device, LineError, LineReader, format_frame};

use crate::uart;

/// [`BusError::Other`] detail: a line from the host that is not an SLCAN command.
pub const MALFORMED_LINE: u8 = 0x20;
/// [`BusError::Other`] detail: a line from the host longer than any SLCAN command.
pub const LINE_TOO_LONG: u8 = 0x21;
/// What `transmit` returns, as [`BusError::Other`], for a frame the node sent while the host had
/// closed the channel.
pub const CHANNEL_CLOSED: u8 = 0x22;
/// What `transmit` would return, as [`BusError::Other`], for a CAN FD frame, which SLCAN cannot
/// carry: never, as this board is built without CAN FD (pab-core's `fd`).
pub const NOT_CLASSIC: u8 = 0x23;
/// How long `transmit` waits for room in the UART's transmit ring before it drops the frame.
pub const TX_TIMEOUT: Duration = Duration::from_millis(10);

/// The node's bus: SLCAN on UART0 ([`uart::init`] first).
pub struct SlcanBus {
    reader: LineReader,
    device: Device,
    overruns_reported: u32,
    stall_lost_reported: u32,
}

impl SlcanBus {
    /// The link, open; `N` answers `serial` (the node id in hex, say).
    pub fn new(serial: [u8; 4]) -> Self {
        SlcanBus {
            reader: LineReader::new(),
            device: Device::new(serial),
            overruns_reported: uart::overruns(),
            stall_lost_reported: uart::stall_lost(),
        }
    }

    /// Handles the bytes waiting in the ring until a frame or an error comes out of them.
    fn next(&mut self) -> Option<Result<Frame, BusError>> {
        let overruns = uart::overruns();
        if overruns != self.overruns_reported {
            self.overruns_reported = overruns;
            self.device.note_overrun();
            return Some(Err(BusError::Overrun));
        }
        // Frames the modelled controller lost while a single-bank flash stalled the CPU.
        let lost = uart::stall_lost().wrapping_sub(self.stall_lost_reported);
        if lost != 0 {
            self.stall_lost_reported = uart::stall_lost();
            return Some(Err(BusError::Dropped(lost)));
        }
        while let Some(byte) = uart::take() {
            let Some(line) = self.reader.push(byte) else {
                continue;
            };
            let outcome = self.device.handle(line);
            let _ = uart::try_send(outcome.reply.as_bytes());
            if let Some(frame) = outcome.frame {
                return Some(Ok(frame));
            }
            match outcome.error {
                Some(LineError::TooLong) => return Some(Err(BusError::Other(LINE_TOO_LONG))),
                Some(LineError::Malformed(_)) => {
                    return Some(Err(BusError::Other(MALFORMED_LINE)));
                }
                None => {}
            }
        }
        None
    }
}

impl CanBus for SlcanBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        poll_fn(|cx| {
            // Registered before looking, so a byte arriving after the last look wakes us.
            uart::register_rx_waker(cx.waker());
            match self.next() {
                Some(result) => Poll::Ready(result),
                None => Poll::Pending,
            }
        })
        .await
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        if !self.device.is_open() {
            return Err(BusError::Other(CHANNEL_CLOSED));
        }
        // Never `None` here: this board is built without CAN FD.
        let line = format_frame(frame).ok_or(BusError::Other(NOT_CLASSIC))?;
        with_timeout(TX_TIMEOUT, uart::send(line.as_bytes()))
            .await
            .map_err(|_| BusError::Overrun)
    }
}
