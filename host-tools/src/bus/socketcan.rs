//! SocketCAN, through the `socketcan` crate's blocking CAN FD socket (`CAN_RAW_FD_FRAMES`): it
//! reads and writes classic and CAN FD frames, converted to and from `pab_core::Frame` here (the
//! bit-rate switch kept). On an interface that carries only classic frames (MTU 16) the option
//! is accepted all the same and classic frames go as before; a CAN FD frame sent there fails
//! with an error that says so.

use std::io;
use std::time::Duration;

use embedded_can::Frame as _;
use pab_core::Frame;
use socketcan::id::FdFlags;
use socketcan::{CanAnyFrame, CanFdFrame, CanFdSocket, CanFrame, Socket};

use super::{Bus, Framing};

/// A CAN interface's MTU when it carries CAN FD frames (`struct canfd_frame`).
pub const CANFD_MTU: u32 = 72;

/// A raw CAN FD socket on one interface. Error frames are not requested: `pabctl` reads the
/// nodes' own fault frames instead.
pub struct SocketCanBus {
    socket: CanFdSocket,
    iface: String,
    /// The interface's MTU when it was opened (`None`: not known).
    mtu: Option<u32>,
    framing: Framing,
}

impl SocketCanBus {
    /// Opens `iface`, its transfers in classic frames.
    pub fn open(iface: &str) -> io::Result<SocketCanBus> {
        Ok(SocketCanBus {
            socket: CanFdSocket::open(iface)?,
            iface: iface.to_string(),
            mtu: mtu(iface),
            framing: Framing::Classic,
        })
    }

    /// The same bus, its transfers framed as `framing` says.
    pub fn with_framing(self, framing: Framing) -> SocketCanBus {
        SocketCanBus { framing, ..self }
    }

    /// Whether the interface carries CAN FD frames (its MTU is 72; an interface whose MTU could
    /// not be read is given the benefit of the doubt: the kernel refuses the first frame).
    pub fn carries_fd(&self) -> bool {
        self.mtu.is_none_or(|mtu| mtu >= CANFD_MTU)
    }
}

/// `iface`'s MTU, from sysfs.
pub fn mtu(iface: &str) -> Option<u32> {
    std::fs::read_to_string(format!("/sys/class/net/{iface}/mtu"))
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// Why a CAN FD frame cannot go on `iface`, and what to do about it.
pub fn classic_only(iface: &str) -> String {
    format!(
        "the interface carries classic CAN frames only (MTU 16, not 72): for a virtual bus `sudo \
         ip link set {iface} down; sudo ip link set {iface} mtu 72; sudo ip link set {iface} up`; \
         for a controller, `sudo ip link set {iface} type can bitrate ... dbitrate ... fd on`; or \
         send classic frames (without --fd)"
    )
}

impl Bus for SocketCanBus {
    fn send(&mut self, frame: &Frame) -> io::Result<()> {
        let too_long = || io::Error::new(io::ErrorKind::InvalidInput, "frame too long");
        let written = if frame.is_fd() {
            let flags = if frame.is_brs() {
                FdFlags::BRS
            } else {
                FdFlags::empty()
            };
            let outgoing =
                CanFdFrame::with_flags(frame.id(), frame.payload(), flags).ok_or_else(too_long)?;
            self.socket.write_frame_insist(&outgoing)
        } else if frame.is_remote() {
            let outgoing =
                CanFrame::new_remote(frame.id(), frame.payload().len()).ok_or_else(too_long)?;
            self.socket.write_frame_insist(&outgoing)
        } else {
            let outgoing = CanFrame::new(frame.id(), frame.payload()).ok_or_else(too_long)?;
            self.socket.write_frame_insist(&outgoing)
        };
        written.map_err(|error| {
            // The kernel refuses a CAN FD frame's size on a classic interface (EINVAL).
            if frame.is_fd() && error.raw_os_error() == Some(libc::EINVAL) {
                io::Error::new(
                    io::ErrorKind::Unsupported,
                    format!(
                        "a CAN FD frame on {}: {}",
                        self.iface,
                        classic_only(&self.iface)
                    ),
                )
            } else {
                error
            }
        })
    }

    fn receive(&mut self, timeout: Duration) -> io::Result<Option<Frame>> {
        let timeout = timeout.max(Duration::from_micros(1));
        match self.socket.read_frame_timeout(timeout) {
            Ok(CanAnyFrame::Normal(frame)) => Ok(Some(pab_core::frame::from_frame(&frame))),
            Ok(CanAnyFrame::Remote(frame)) => Ok(Some(pab_core::frame::from_frame(&frame))),
            Ok(CanAnyFrame::Fd(frame)) => Ok(Frame::fd(frame.id(), frame.data(), frame.is_brs())),
            Ok(CanAnyFrame::Error(_)) => Ok(None),
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

    fn framing(&self) -> Framing {
        self.framing
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// This machine's kernel may have no SocketCAN: the MTU is read from any interface's sysfs
    /// entry, and an interface that does not exist has none.
    #[test]
    fn the_mtu_comes_from_sysfs() {
        assert!(mtu("lo").is_some_and(|mtu| mtu > 0));
        assert_eq!(mtu("no-such-can-interface"), None);
    }

    #[test]
    fn a_classic_interface_is_named_with_what_to_do() {
        let why = classic_only("vcan7");
        assert!(why.contains("MTU 16"), "{why}");
        assert!(why.contains("ip link set vcan7 mtu 72"), "{why}");
        assert!(why.contains("fd on"), "{why}");
        assert!(why.contains("without --fd"), "{why}");
    }
}
