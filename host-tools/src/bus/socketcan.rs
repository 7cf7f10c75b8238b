//! SocketCAN, through the `socketcan` crate's blocking socket.

use std::io;
use std::time::Duration;

use embedded_can::Frame as _;
use pab_core::Frame;
use socketcan::{CanFrame, CanSocket, Socket};

use super::Bus;

/// A raw CAN socket on one interface. Error frames are not requested: `pabctl` reads the nodes'
/// own fault frames instead.
pub struct SocketCanBus {
    socket: CanSocket,
}

impl SocketCanBus {
    /// Opens `iface`.
    pub fn open(iface: &str) -> io::Result<SocketCanBus> {
        Ok(SocketCanBus {
            socket: CanSocket::open(iface)?,
        })
    }
}

impl Bus for SocketCanBus {
    fn send(&mut self, frame: &Frame) -> io::Result<()> {
        let outgoing = CanFrame::new(frame.id(), frame.payload())
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "frame too long"))?;
        self.socket.write_frame_insist(&outgoing)
    }

    fn receive(&mut self, timeout: Duration) -> io::Result<Option<Frame>> {
        let timeout = timeout.max(Duration::from_micros(1));
        match self.socket.read_frame_timeout(timeout) {
            Ok(CanFrame::Data(frame)) => Ok(Some(pab_core::frame::from_frame(&frame))),
            Ok(CanFrame::Remote(frame)) => Ok(Some(pab_core::frame::from_frame(&frame))),
            Ok(CanFrame::Error(_)) => Ok(None),
            Err(error)
                if matches!(
                    error.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(None)
            }
            Err(error) => Err(error),
        }
    }
}
