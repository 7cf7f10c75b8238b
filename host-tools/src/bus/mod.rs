//! Where `pabctl` meets a CAN bus: one small blocking trait, and its implementations, chosen by the
//! interface name (python-can's "one Bus API, interfaces as plug-ins").
//!
//! - `vcan0`, `can0`, ...: a SocketCAN interface ([`socketcan::SocketCanBus`]), through a CAN FD
//!   socket: classic and CAN FD frames both ways.
//! - [`memory::MemoryHub`]: an in-process bus, for tests that run nodes as threads.
//!
//! A bus also says how the tools send their ISO-TP transfers on it ([`Framing`]): classic frames,
//! which every node takes, unless it was opened for CAN FD transfers ([`open_with`], `--fd`).

pub mod memory;
pub mod socketcan;

use std::io;
use std::time::Duration;

use pab_core::Frame;

/// How the tools send their ISO-TP transfers (a table push, a schema, a firmware update) on a
/// bus (docs/can-protocol.md, "Table transfer").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Framing {
    /// Classic CAN frames of 8 bytes, 7 of the message a frame: what every node takes.
    #[default]
    Classic,
    /// CAN FD frames of up to 64 bytes (ISO-TP's TX_DL 64, ISO 15765-2:2016), 63 of the message a
    /// frame, with the bit-rate switch: for nodes built with CAN FD (`pab-node`) on a CAN FD bus.
    Fd,
}

impl Framing {
    /// "classic CAN" or "CAN FD", for what the tools print.
    pub fn name(self) -> &'static str {
        match self {
            Framing::Classic => "classic CAN",
            Framing::Fd => "CAN FD",
        }
    }
}

/// A CAN bus as `pabctl` uses it: send a frame, wait for the next one.
pub trait Bus: Send {
    /// Sends `frame` (blocks while the interface's queue is full).
    fn send(&mut self, frame: &Frame) -> io::Result<()>;
    /// The next frame from the bus, or `None` if none arrived within `timeout`.
    fn receive(&mut self, timeout: Duration) -> io::Result<Option<Frame>>;
    /// How the tools send ISO-TP transfers on this bus. Classic unless it was opened for CAN FD
    /// transfers.
    fn framing(&self) -> Framing {
        Framing::Classic
    }
}

/// Opens the bus an interface name designates, its transfers in classic frames.
pub fn open(iface: &str) -> io::Result<Box<dyn Bus>> {
    open_with(iface, Framing::Classic)
}

/// Opens the bus an interface name designates, its transfers framed as `framing` says. For CAN
/// FD transfers the interface must carry CAN FD frames (MTU 72): a classic one (MTU 16) is
/// refused here, before anything is sent, saying how to switch it.
pub fn open_with(iface: &str, framing: Framing) -> io::Result<Box<dyn Bus>> {
    let bus = socketcan::SocketCanBus::open(iface).map_err(|error| {
        io::Error::new(
            error.kind(),
            format!(
                "cannot open CAN interface {iface:?}: {error} (is it up? `ip link show {iface}`; \
                 for a virtual bus: sudo modprobe vcan; sudo ip link add dev {iface} type vcan; \
                 sudo ip link set up {iface})"
            ),
        )
    })?;
    if framing == Framing::Fd && !bus.carries_fd() {
        return Err(io::Error::new(
            io::ErrorKind::Unsupported,
            format!(
                "CAN FD transfers (--fd) on {iface}: {}",
                socketcan::classic_only(iface)
            ),
        ));
    }
    Ok(Box::new(bus.with_framing(framing)))
}
