//! The application's [`CanBus`] over a SocketCAN socket, async through `async-io` (the reactor
//! behind `socketcan`'s smol support; embassy's std executor can poll it: `async-io` drives its
//! own reactor thread). Frames are read with `recvmsg`, so that the kernel's drop counter comes
//! with each (see [`crate::receive_queue`]).

use std::os::fd::AsFd;

use async_io::Async;
use embedded_can::Frame as _;
use pab_app::{BusError, CanBus};
use pab_core::Frame;
use socketcan::{CanError, CanFrame, Socket as _, SocketOptions};

use crate::receive_queue::{self, DropCount, Sizing};

/// A SocketCAN interface, with error frames switched on so bus trouble reaches the node, a
/// receive buffer of the size asked, and the kernel's drop counter read with every frame.
pub struct SocketBus {
    socket: Async<socketcan::CanSocket>,
    drops: DropCount,
    /// The frame (or error frame) read together with a drop report: [`CanBus::receive`] reports
    /// the loss first, then returns this at its next call.
    held: Option<Result<Frame, BusError>>,
}

impl SocketBus {
    /// Opens `iface` (e.g. `vcan0`, `can0`) with a receive buffer of `rcvbuf_bytes` as the kernel
    /// counts them (see [`receive_queue::set_size`]); returns how it was sized. Fails if the
    /// interface cannot be opened or the socket refuses an option.
    pub fn open(iface: &str, rcvbuf_bytes: u64) -> std::io::Result<(SocketBus, Sizing)> {
        let socket = socketcan::CanSocket::open(iface)?;
        socket.set_error_filter_accept_all()?;
        let sizing = receive_queue::set_size(socket.as_fd(), rcvbuf_bytes)?;
        receive_queue::count_drops(socket.as_fd())?;
        let bus = SocketBus {
            socket: Async::new(socket)?,
            drops: DropCount::default(),
            held: None,
        };
        Ok((bus, sizing))
    }
}

impl CanBus for SocketBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        if let Some(held) = self.held.take() {
            return held;
        }
        let read = self.socket.read_with(read_frame).await;
        let (frame, counter) = read.map_err(|error| {
            log::warn!("reading from the CAN socket failed: {error}");
            BusError::Overrun
        })?;
        let received = match frame {
            CanFrame::Data(frame) => Ok(pab_core::frame::from_frame(&frame)),
            CanFrame::Remote(frame) => Ok(pab_core::frame::from_frame(&frame)),
            CanFrame::Error(frame) => Err(bus_error(frame.into_error())),
        };
        let lost = self.drops.lost_since_last(counter);
        if lost > 0 {
            // The loss happened before this frame: reported first, the frame next time.
            self.held = Some(received);
            return Err(BusError::Dropped(lost));
        }
        received
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        let outgoing = if frame.is_remote() {
            CanFrame::new_remote(frame.id(), frame.payload().len())
        } else {
            CanFrame::new(frame.id(), frame.payload())
        };
        let Some(outgoing) = outgoing else {
            return Err(BusError::Other(0xFF));
        };
        self.socket
            .write_with(|socket| socket.write_frame(&outgoing))
            .await
            .map_err(|error| {
                log::warn!("writing to the CAN socket failed: {error}");
                BusError::Overrun
            })
    }
}

/// One classic frame from the socket, with the kernel's drop counter. A datagram of another size
/// (a CAN FD frame: this socket never asks for them) is `InvalidData`.
fn read_frame(socket: &socketcan::CanSocket) -> std::io::Result<(CanFrame, Option<u32>)> {
    // struct can_frame: can_id (native endian, with the EFF/RTR/ERR flags), len, 3 bytes of
    // padding and len8_dlc, 8 data bytes.
    let mut bytes = [0u8; 16];
    let (len, counter) = receive_queue::receive(socket, &mut bytes)?;
    if len != bytes.len() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("a {len}-byte datagram on a classic CAN socket"),
        ));
    }
    let mut raw = socketcan::frame::can_frame_default();
    let (id, rest) = bytes.split_at(4);
    raw.can_id = u32::from_ne_bytes(id.try_into().unwrap_or_default());
    raw.can_dlc = rest.first().copied().unwrap_or(0);
    raw.data.copy_from_slice(rest.get(4..12).unwrap_or(&[0; 8]));
    Ok((CanFrame::from(raw), counter))
}

/// Maps the kernel's error frame classes to the application's, most serious first.
fn bus_error(error: CanError) -> BusError {
    use socketcan::errors::ControllerProblems as Problems;
    if error.is_bus_off() {
        return BusError::BusOff;
    }
    if let Some(problems) = error.controller() {
        if problems.intersects(Problems::RX_OVERFLOW | Problems::TX_OVERFLOW) {
            return BusError::Overrun;
        }
        if problems.intersects(Problems::RX_PASSIVE | Problems::TX_PASSIVE) {
            return BusError::ErrorPassive;
        }
        if problems.contains(Problems::ACTIVE) {
            return BusError::Recovered;
        }
    }
    if error.is_restarted() {
        return BusError::Recovered;
    }
    // The remaining classes become the fault's detail byte.
    let kind = match error.first() {
        socketcan::errors::ErrorCause::TransmitTimeout => 1,
        socketcan::errors::ErrorCause::LostArbitration(_) => 2,
        socketcan::errors::ErrorCause::Protocol { .. } => 3,
        socketcan::errors::ErrorCause::Transceiver { .. } => 4,
        socketcan::errors::ErrorCause::NoAck => 5,
        socketcan::errors::ErrorCause::BusError => 6,
        _ => 0,
    };
    BusError::Other(kind)
}
