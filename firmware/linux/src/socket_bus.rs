//! The application's [`CanBus`] over a SocketCAN socket, async through `async-io` (the reactor
//! behind `socketcan`'s smol support; embassy's std executor can poll it: `async-io` drives its
//! own reactor thread). Frames are read with `recvmsg`, so that the kernel's drop counter comes
//! with each (see [`crate::receive_queue`]).
//!
//! The socket is a CAN FD one (`CAN_RAW_FD_FRAMES`): on an interface that carries CAN FD frames
//! (MTU 72) the node reads and sends both kinds, converted to and from `pab_core::Frame` here with
//! the bit-rate switch kept (a table pushed in CAN FD frames, its flow control answered in CAN FD,
//! an FD topic re-published as FD). On a classic interface (MTU 16) the kernel accepts the option
//! all the same and only classic frames come; a CAN FD frame the node would send there (it never
//! has one to send: it answers in the kind it received) is refused by the kernel and logged.

use std::os::fd::AsFd;

use async_io::Async;
use embedded_can::Frame as _;
use pab_app::{BusError, CanBus};
use pab_core::Frame;
use socketcan::id::FdFlags;
use socketcan::{CanError, CanFdFrame, CanFrame, Socket as _, SocketOptions};

use crate::receive_queue::{self, DropCount, Sizing};

/// A SocketCAN interface, with error frames switched on so bus trouble reaches the node, a
/// receive buffer of the size asked, and the kernel's drop counter read with every frame.
pub struct SocketBus {
    socket: Async<socketcan::CanFdSocket>,
    iface: String,
    /// Whether the interface carries CAN FD frames (MTU 72), as it said at the start.
    fd: bool,
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
        let socket = socketcan::CanFdSocket::open(iface)?;
        socket.set_error_filter_accept_all()?;
        let sizing = receive_queue::set_size(socket.as_fd(), rcvbuf_bytes)?;
        receive_queue::count_drops(socket.as_fd())?;
        let mtu = interface_mtu(iface);
        let bus = SocketBus {
            socket: Async::new(socket)?,
            iface: iface.to_string(),
            fd: mtu.is_none_or(|mtu| mtu >= CANFD_MTU),
            drops: DropCount::default(),
            held: None,
        };
        Ok((bus, sizing))
    }

    /// Whether the interface carries CAN FD frames (its MTU is 72; an MTU that could not be
    /// read counts as CAN FD: the kernel says otherwise at the first CAN FD frame).
    pub fn carries_fd(&self) -> bool {
        self.fd
    }
}

/// A CAN interface's MTU when it carries CAN FD frames (`struct canfd_frame`).
pub const CANFD_MTU: u32 = 72;

/// `iface`'s MTU, from sysfs.
pub fn interface_mtu(iface: &str) -> Option<u32> {
    std::fs::read_to_string(format!("/sys/class/net/{iface}/mtu"))
        .ok()?
        .trim()
        .parse()
        .ok()
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
            Read::Classic(CanFrame::Data(frame)) => Ok(pab_core::frame::from_frame(&frame)),
            Read::Classic(CanFrame::Remote(frame)) => Ok(pab_core::frame::from_frame(&frame)),
            Read::Classic(CanFrame::Error(frame)) => Err(bus_error(frame.into_error())),
            Read::Fd(frame) => {
                Frame::fd(frame.id(), frame.data(), frame.is_brs()).ok_or(BusError::Other(0xFE))
            }
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
        let written = if frame.is_fd() {
            let flags = if frame.is_brs() {
                FdFlags::BRS
            } else {
                FdFlags::empty()
            };
            let Some(outgoing) = CanFdFrame::with_flags(frame.id(), frame.payload(), flags) else {
                return Err(BusError::Other(0xFF));
            };
            self.socket
                .write_with(|socket| socket.write_frame(&outgoing))
                .await
        } else {
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
        };
        written.map_err(|error| {
            if frame.is_fd() && error.raw_os_error() == Some(libc::EINVAL) {
                log::warn!(
                    "a CAN FD frame cannot go on {}: the interface carries classic CAN only \
                     (MTU 16; for a vcan, `ip link set {} mtu 72` while it is down)",
                    self.iface,
                    self.iface
                );
            } else {
                log::warn!("writing to the CAN socket failed: {error}");
            }
            BusError::Overrun
        })
    }
}

/// A frame as the socket read it.
enum Read {
    /// A classic data, remote or error frame (`struct can_frame`, 16 bytes).
    Classic(CanFrame),
    /// A CAN FD frame (`struct canfd_frame`, 72 bytes).
    Fd(CanFdFrame),
}

/// One frame from the socket, classic or CAN FD by the datagram's size, with the kernel's drop
/// counter. A datagram of another size is `InvalidData`.
fn read_frame(socket: &socketcan::CanFdSocket) -> std::io::Result<(Read, Option<u32>)> {
    // struct can_frame: can_id (native endian, with the EFF/RTR/ERR flags), len, 3 bytes of
    // padding and len8_dlc, 8 data bytes (16 bytes). struct canfd_frame: can_id, len, flags,
    // 2 reserved bytes, 64 data bytes (72).
    let mut bytes = [0u8; 72];
    let (len, counter) = receive_queue::receive(socket, &mut bytes)?;
    let (id, rest) = bytes.split_at(4);
    let can_id = u32::from_ne_bytes(id.try_into().unwrap_or_default());
    let read = match len {
        16 => {
            let mut raw = socketcan::frame::can_frame_default();
            raw.can_id = can_id;
            raw.can_dlc = rest.first().copied().unwrap_or(0);
            raw.data.copy_from_slice(rest.get(4..12).unwrap_or(&[0; 8]));
            Read::Classic(CanFrame::from(raw))
        }
        72 => {
            let mut raw = socketcan::frame::canfd_frame_default();
            raw.can_id = can_id;
            raw.len = rest.first().copied().unwrap_or(0);
            raw.flags = rest.get(1).copied().unwrap_or(0);
            raw.data
                .copy_from_slice(rest.get(4..68).unwrap_or(&[0; 64]));
            Read::Fd(CanFdFrame::from(raw))
        }
        _ => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("a {len}-byte datagram on a CAN socket"),
            ));
        }
    };
    Ok((read, counter))
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
