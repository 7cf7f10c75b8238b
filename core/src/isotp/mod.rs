//! ISO 15765-2 (ISO-TP) transport: messages of any length over classic CAN's 8-byte frames and,
//! by ISO 15765-2:2016, over CAN FD frames of up to 64 bytes ([`fd`]'s codec, [`FdSender`], and
//! with the feature `fd` `Receiver::on_fd_frame`).
//!
//! Table images (up to 32 KiB) travel from the workstation to the nodes with ISO-TP, because
//! python `can-isotp`, Linux's `can-isotp` sockets and Wireshark already speak it. This module is
//! sans-I/O: it turns payloads into frame data fields and back, and leaves the rest to the caller:
//!
//! - Addressing: the caller picks the CAN ids (one for data, one for Flow Controls) and passes only
//!   the frames of its transfer. Normal addressing: the PCI is byte 0 (no extended or mixed
//!   addressing byte).
//! - Time: there is no clock here. Every call takes `now` ([`Instant`], µs); the state machines
//!   tell the caller when they next need attention ([`Receiver::deadline`],
//!   [`TxEvent::WaitUntil`]). Comparisons are wrap-safe.
//! - Transmission: frames to send are returned as `[u8; 8]`, always padded to 8 bytes; on CAN FD
//!   as an [`fd::FdFrame`] of a CAN FD length, 8 bytes at least.
//!
//! Layers: [`pci`] is the pure frame codec (also for decoding captures); [`Receiver`] reassembles
//! (the node's side), [`Sender`] segments (the workstation's side). Both handle one message at a
//! time.
//!
//! What ISO-TP does not protect against: losing exactly a multiple of 16 consecutive Consecutive
//! Frames inside one block leaves the 4-bit sequence number in step, and the message arrives with
//! a hole. The table image's CRC-32 catches that; do not trust an ISO-TP message without a check
//! of its own.
//!
//! [`Instant`]: crate::time::Instant

pub mod fd;
pub mod pci;
mod rx;
mod tx;

pub use pci::{FlowStatus, FrameError, Pci, StMin};
pub use rx::{Ignored, Receiver, Refusal, RxConfig, RxError, RxEvent, RxOutcome};
pub use tx::{FdSender, FlowControlEffect, Sender, TxConfig, TxError, TxEvent, TxSetupError};

use crate::time::Instant;

/// The instant `micros` after `now` (wrapping).
fn deadline_after(now: Instant, micros: u64) -> Instant {
    now.wrapping_add_micros(micros)
}

/// Whether `deadline` has been reached at `now`: true from the deadline itself on, wrap-safe
/// (`now` before `deadline` by less than 2^63 µs counts as not yet).
fn expired(now: Instant, deadline: Instant) -> bool {
    now.micros_since(deadline).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadlines_across_the_counter_wrap() {
        let now = Instant::from_micros(u64::MAX - 10);
        let deadline = deadline_after(now, 100);
        assert_eq!(deadline.as_micros(), 89);
        assert!(!expired(now, deadline));
        assert!(!expired(deadline.wrapping_add_micros(u64::MAX), deadline));
        assert!(expired(deadline, deadline));
        assert!(expired(deadline.wrapping_add_micros(1), deadline));
    }
}
