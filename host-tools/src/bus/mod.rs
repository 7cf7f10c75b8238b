//! Where `pabctl` meets a CAN bus: one small blocking trait, and its implementations, chosen by the
//! interface name (python-can's "one Bus API, interfaces as plug-ins").
//!
//! - `vcan0`, `can0`, ...: a SocketCAN interface ([`socketcan::SocketCanBus`]).
//! - [`memory::MemoryHub`]: an in-process bus, for tests that run nodes as threads.

pub mod memory;
pub mod socketcan;

use std::io;
use std::time::Duration;

use pab_core::Frame;

/// A CAN bus as `pabctl` uses it: send a frame, wait for the next one.
pub trait Bus: Send {
    /// Sends `frame` (blocks while the interface's queue is full).
    fn send(&mut self, frame: &Frame) -> io::Result<()>;
    /// The next frame from the bus, or `None` if none arrived within `timeout`.
    fn receive(&mut self, timeout: Duration) -> io::Result<Option<Frame>>;
}

/// Opens the bus an interface name designates.
pub fn open(iface: &str) -> io::Result<Box<dyn Bus>> {
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
    Ok(Box::new(bus))
}
