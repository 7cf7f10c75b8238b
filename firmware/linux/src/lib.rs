//! The Linux node's SocketCAN code, shared by its binaries: `pab-node` (a node) and `pab-intent`
//! (HBBA's intention node, whose logic is the `pab-intent` library, `firmware/intent`). Both reach the bus through
//! [`socket_bus::SocketBus`], the application's `CanBus` over a SocketCAN socket with a sized
//! receive queue and the kernel's drop counter.

pub mod key_file;
pub mod receive_queue;
pub mod socket_bus;
