//! An in-process bus: every frame one endpoint sends reaches every other endpoint, in order, as on
//! a CAN bus (and, as with SocketCAN's default, not the sender itself). For tests that run nodes
//! on threads next to the tool's code.

use std::io;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use pab_core::Frame;

use super::{Bus, Framing};

/// The stations of a hub: a key and the way into its inbox.
type Stations = Vec<(usize, Sender<Frame>)>;

/// The bus itself: hands out endpoints.
#[derive(Clone, Default)]
pub struct MemoryHub {
    endpoints: Arc<Mutex<Stations>>,
}

/// One station on a [`MemoryHub`].
pub struct MemoryBus {
    key: usize,
    hub: MemoryHub,
    inbox: Receiver<Frame>,
    framing: Framing,
}

impl MemoryHub {
    /// A bus with no stations.
    pub fn new() -> MemoryHub {
        MemoryHub::default()
    }

    /// A new station.
    pub fn connect(&self) -> MemoryBus {
        let (sender, inbox) = mpsc::channel();
        let mut endpoints = self
            .endpoints
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        let key = endpoints.last().map_or(0, |(key, _)| key + 1);
        endpoints.push((key, sender));
        MemoryBus {
            key,
            hub: self.clone(),
            inbox,
            framing: Framing::Classic,
        }
    }

    fn broadcast(&self, from: usize, frame: &Frame) {
        let mut endpoints = self
            .endpoints
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        // A station that hung up is removed from the bus.
        endpoints.retain(|(key, sender)| *key == from || sender.send(*frame).is_ok());
    }
}

impl MemoryBus {
    /// The same station, the tools' transfers through it framed as `framing` says (the bus
    /// carries CAN FD frames as it carries classic ones).
    pub fn with_framing(mut self, framing: Framing) -> MemoryBus {
        self.framing = framing;
        self
    }

    /// The next frame if one is waiting, without blocking.
    pub fn try_receive(&mut self) -> Option<Frame> {
        self.inbox.try_recv().ok()
    }
}

impl Bus for MemoryBus {
    fn send(&mut self, frame: &Frame) -> io::Result<()> {
        self.hub.broadcast(self.key, frame);
        Ok(())
    }

    fn framing(&self) -> Framing {
        self.framing
    }

    fn receive(&mut self, timeout: Duration) -> io::Result<Option<Frame>> {
        match self.inbox.recv_timeout(timeout) {
            Ok(frame) => Ok(Some(frame)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                "the in-process bus is gone",
            )),
        }
    }
}

impl Drop for MemoryBus {
    fn drop(&mut self) {
        let mut endpoints = self
            .hub
            .endpoints
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        endpoints.retain(|(key, _)| *key != self.key);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_reach_every_other_station_in_order() {
        let hub = MemoryHub::new();
        let mut a = hub.connect();
        let mut b = hub.connect();
        let mut c = hub.connect();
        let first = Frame::with_raw_id(0x100, false, &[1]).unwrap();
        let second = Frame::with_raw_id(0x101, false, &[2]).unwrap();
        a.send(&first).unwrap();
        a.send(&second).unwrap();
        for station in [&mut b, &mut c] {
            assert_eq!(station.try_receive(), Some(first));
            assert_eq!(station.try_receive(), Some(second));
            assert_eq!(station.try_receive(), None);
        }
        assert_eq!(a.try_receive(), None, "no echo to the sender");
        drop(c);
        b.send(&first).unwrap();
        assert_eq!(a.receive(Duration::from_millis(10)).unwrap(), Some(first));
    }
}
