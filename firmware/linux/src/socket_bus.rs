//! The application's [`CanBus`] over a SocketCAN socket (async, through `socketcan`'s smol
//! support, which embassy's std executor can poll: `async-io` drives its own reactor thread).

use embedded_can::Frame as _;
use pab_app::{BusError, CanBus};
use pab_core::Frame;
use socketcan::{CanError, CanFrame, SocketOptions};

/// A SocketCAN interface, with error frames switched on so bus trouble reaches the node.
pub struct SocketBus {
    socket: socketcan::smol::CanSocket,
}

impl SocketBus {
    /// Opens `iface` (e.g. `vcan0`, `can0`).
    pub fn open(iface: &str) -> std::io::Result<SocketBus> {
        let socket = socketcan::smol::CanSocket::open(iface)?;
        socket.set_error_filter_accept_all()?;
        Ok(SocketBus { socket })
    }
}

impl CanBus for SocketBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        let frame = self.socket.read_frame().await.map_err(|error| {
            // ENOBUFS and friends: the socket dropped frames.
            log::warn!("reading from the CAN socket failed: {error}");
            BusError::Overrun
        })?;
        match frame {
            CanFrame::Data(frame) => Ok(pab_core::frame::from_frame(&frame)),
            CanFrame::Remote(frame) => Ok(pab_core::frame::from_frame(&frame)),
            CanFrame::Error(frame) => Err(bus_error(frame.into_error())),
        }
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
        self.socket.write_frame(&outgoing).await.map_err(|error| {
            log::warn!("writing to the CAN socket failed: {error}");
            BusError::Overrun
        })
    }
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
