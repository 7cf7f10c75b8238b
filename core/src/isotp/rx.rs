//! The receiving side: frames in, Flow Controls and whole messages out.
//!
//! With the feature `fd`, one receiver takes both kinds of transfer (ISO 15765-2:2016): classic
//! ISO-TP from classic frames ([`Receiver::on_frame`]) and CAN FD ISO-TP from CAN FD frames
//! (`Receiver::on_fd_frame`). A reception is of the kind of its First Frame, whose length is the
//! sender's TX_DL (the receiver's RX_DL); a Consecutive Frame of the other kind is ignored, as the
//! standard ignores a frame of an invalid length, and a Single or First Frame of either kind
//! starts a new message.

use super::pci::{self, FRAME_LEN, FlowStatus, FrameError, Pci, StMin};
use super::{deadline_after, expired};
use crate::time::Instant;

/// How a [`Receiver`] paces its sender.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxConfig {
    /// BS sent in every Flow Control: Consecutive Frames per block, 0 for a single block (no Flow
    /// Control after the first). Default 0.
    pub block_size: u8,
    /// STmin sent in every Flow Control. Default 0 (back to back).
    pub st_min: StMin,
    /// N_Cr: the longest wait for a Consecutive Frame after the First Frame, a Flow Control or the
    /// previous Consecutive Frame, in microseconds. Default 1 000 000 (1 s, the standard's value).
    pub n_cr_micros: u64,
    /// The byte that pads Flow Controls to 8 bytes. Default 0xCC.
    pub padding: u8,
}

impl Default for RxConfig {
    fn default() -> Self {
        RxConfig {
            block_size: 0,
            st_min: StMin::ZERO,
            n_cr_micros: 1_000_000,
            padding: pci::DEFAULT_PADDING,
        }
    }
}

// Not `#[non_exhaustive]`: a node maps each variant to its TransferStatus (pab-app's `node.rs`).
/// Why a reception in progress ended without a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RxError {
    /// A Consecutive Frame with an unexpected sequence number (N_WRONG_SN): a frame was lost or
    /// repeated.
    WrongSequenceNumber {
        /// The sequence number expected.
        expected: u8,
        /// The sequence number received.
        got: u8,
    },
    /// No Consecutive Frame within N_Cr (N_TIMEOUT_Cr).
    Timeout,
    /// A new Single or First Frame arrived (N_UNEXP_PDU): the standard ends the current reception
    /// and starts the new one.
    Interrupted,
}

impl core::fmt::Display for RxError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RxError::WrongSequenceNumber { expected, got } => write!(
                f,
                "ISO-TP consecutive frame with sequence number {got}, expected {expected}"
            ),
            RxError::Timeout => f.write_str("no ISO-TP consecutive frame within N_Cr"),
            RxError::Interrupted => f.write_str("ISO-TP reception interrupted by a new message"),
        }
    }
}

impl core::error::Error for RxError {}

/// Why a well-formed message was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// The message is longer than the receiver's buffer.
    TooLarge {
        /// The announced length.
        len: u32,
    },
}

/// Why a frame was ignored. Ignoring leaves a reception in progress untouched, as the standard
/// says for frames with an invalid length and for unexpected Consecutive and Flow Control frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Ignored {
    /// The frame does not decode.
    Malformed(FrameError),
    /// A Consecutive Frame while no reception is in progress.
    UnexpectedConsecutive,
    /// A Consecutive Frame, not the last of its message, that carries fewer than 7 bytes; or the
    /// last one, carrying fewer bytes than remain.
    ShortConsecutive {
        /// Bytes the message needed from this frame.
        needed: usize,
        /// Bytes it carried.
        got: usize,
    },
    /// A Flow Control: a receiver sends those, it does not take them.
    FlowControl,
    /// A Consecutive Frame of the other kind than the reception's First Frame: a classic frame
    /// during a CAN FD reception, or a CAN FD frame during a classic one (`Receiver::on_fd_frame`,
    /// feature `fd`).
    OtherFormat,
    /// A CAN FD Consecutive Frame longer than RX_DL (the First Frame's length), or shorter and not
    /// the last of its message (feature `fd`).
    FdLength {
        /// RX_DL: the First Frame's length.
        rx_dl: usize,
        /// The frame's length.
        got: usize,
    },
}

/// What the caller must do about the frame just passed to [`Receiver::on_frame`].
#[derive(Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RxEvent<'a> {
    /// Nothing: a Consecutive Frame was stored, or a reception ended (see
    /// [`RxOutcome::aborted`]).
    Nothing,
    /// Transmit this Flow Control (ContinueToSend) now, on the reply identifier.
    SendFlowControl([u8; FRAME_LEN]),
    /// A whole message. The receiver is idle again; the bytes stay valid until the next call.
    Complete(&'a [u8]),
    /// A Single or First Frame announced a message the receiver does not take. Transmit the
    /// Flow Control if there is one (Overflow, after a First Frame). The receiver stays idle.
    Refused {
        /// Why.
        reason: Refusal,
        /// The Flow Control to transmit, if any.
        flow_control: Option<[u8; FRAME_LEN]>,
    },
    /// The frame was ignored; count it if you like.
    Ignored(Ignored),
}

/// The result of one frame: a reception it ended, and what to do about the frame itself.
///
/// Both are needed because one frame can do both: a First Frame that arrives during a reception
/// ends that reception (`aborted: Some(Interrupted)`) and starts its own (`event:
/// SendFlowControl`). Likewise a Consecutive Frame that arrives after N_Cr reports the timeout and
/// is then ignored as unexpected.
#[must_use]
#[derive(Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxOutcome<'a> {
    /// The reception in progress that this frame (or the time it arrived at) ended, if any.
    pub aborted: Option<RxError>,
    /// What to do about the frame.
    pub event: RxEvent<'a>,
}

#[derive(Clone, Copy, Debug)]
enum State {
    Idle,
    Receiving {
        /// The announced length; at most the buffer's.
        total: usize,
        /// Bytes stored so far, `received < total`.
        received: usize,
        /// The sequence number of the next Consecutive Frame.
        next_sn: u8,
        /// Consecutive Frames left before the next Flow Control; `None` when BS = 0.
        block_left: Option<u8>,
        /// N_Cr expires at this instant.
        deadline: Instant,
        /// RX_DL of a CAN FD reception (its First Frame's length, 8..=64); 0 for a classic one.
        #[cfg(feature = "fd")]
        rx_dl: u8,
    },
}

/// Reassembles one message at a time into an owned `[u8; N]`; `N` is the longest message taken.
///
/// Memory: `N` bytes plus about 48. Every call costs a few comparisons plus copying the frame's
/// payload (at most 7 bytes). Never allocates, never panics: whatever the bytes, the result is an
/// event. The caller routes frames (by CAN id) and transmits the Flow Controls it is handed.
#[derive(Clone, Debug)]
pub struct Receiver<const N: usize> {
    core: Core,
    buffer: [u8; N],
}

/// A [`Receiver`] but its buffer: the frame handling is written once over `&mut [u8]`, so a
/// node with receivers of two sizes (tables and schemas) has one copy of it, not one per `N`.
#[derive(Clone, Debug)]
struct Core {
    config: RxConfig,
    state: State,
}

impl<const N: usize> Receiver<N> {
    /// An idle receiver. Costs zeroing `N` bytes.
    // Out of line: inlined into `Node::new` and the schema server's runtime (the node's two
    // receivers), it took 8 bytes more of both boards' flash.
    #[inline(never)]
    pub fn new(config: RxConfig) -> Self {
        Receiver {
            core: Core {
                config,
                state: State::Idle,
            },
            buffer: [0; N],
        }
    }

    /// The configuration.
    pub fn config(&self) -> &RxConfig {
        &self.core.config
    }

    /// Handles one received frame's data field (1..=8 bytes), received at `now`.
    ///
    /// A reception whose N_Cr has expired at `now` is aborted first, so the outcome does not depend
    /// on how often [`Receiver::poll`] is called. Then:
    ///
    /// - Single Frame: `Complete` (or `Refused` without Flow Control if longer than `N`).
    /// - First Frame: `SendFlowControl` (CTS with the configured BS and STmin), or `Refused` with
    ///   an Overflow Flow Control if longer than `N`.
    /// - Consecutive Frame: stored (`Nothing`), or `SendFlowControl` after a full block, or
    ///   `Complete` after the last; a wrong sequence number aborts the reception.
    /// - Anything else: `Ignored`, and a reception in progress goes on.
    ///
    /// A Single or First Frame during a reception aborts it (`aborted: Some(Interrupted)`) and is
    /// then handled as above.
    pub fn on_frame(&mut self, data: &[u8], now: Instant) -> RxOutcome<'_> {
        self.core.on_frame(&mut self.buffer, data, now)
    }

    /// Handles one received CAN FD frame's data field (a CAN FD length, up to 64 bytes), as
    /// [`Receiver::on_frame`] does a classic one, by ISO 15765-2:2016 (feature `fd`):
    ///
    /// - The frame decodes with [`fd::decode`](super::fd::decode): an escaped Single Frame, a
    ///   First Frame of any TX_DL, the escaped First Frame above 4095 bytes.
    /// - A First Frame's length is RX_DL for its reception: every Consecutive Frame but the last
    ///   must be RX_DL long, and none longer (others are ignored, [`Ignored::FdLength`]); each
    ///   carries RX_DL − 1 bytes.
    /// - A classic frame's Consecutive Frame during a CAN FD reception, and a CAN FD one during a
    ///   classic reception, are ignored ([`Ignored::OtherFormat`]): the sender then fails on its
    ///   next Flow Control wait or the next frame in sequence ends the reception.
    ///
    /// The Flow Controls it hands out are the classic ones (3 bytes, padded to 8): the caller
    /// sends them in a CAN FD frame, the kind of the frame that asked for them.
    #[cfg(feature = "fd")]
    pub fn on_fd_frame(&mut self, data: &[u8], now: Instant) -> RxOutcome<'_> {
        self.core.on_fd_frame(&mut self.buffer, data, now)
    }

    /// Whether the reception in progress is a CAN FD one (`None` when idle; feature `fd`).
    #[cfg(feature = "fd")]
    pub fn is_fd(&self) -> Option<bool> {
        match self.core.state {
            State::Receiving { rx_dl, .. } => Some(rx_dl != 0),
            State::Idle => None,
        }
    }

    /// Aborts the reception in progress if N_Cr has expired at `now` (then `Some(Timeout)`).
    /// Call it at [`Receiver::deadline`]. Costs one comparison.
    pub fn poll(&mut self, now: Instant) -> Option<RxError> {
        self.core.poll(now)
    }

    /// When N_Cr expires for the reception in progress: the next Consecutive Frame must arrive
    /// before. `None` when idle.
    pub fn deadline(&self) -> Option<Instant> {
        match self.core.state {
            State::Receiving { deadline, .. } => Some(deadline),
            State::Idle => None,
        }
    }

    /// `(bytes received, message length)` of the reception in progress, `None` when idle.
    pub fn in_progress(&self) -> Option<(usize, usize)> {
        match self.core.state {
            State::Receiving {
                total, received, ..
            } => Some((received, total)),
            State::Idle => None,
        }
    }

    /// The sequence number the next Consecutive Frame must carry, `None` when idle: a caller that
    /// must not let a stray frame abort the reception (a node with a key) drops the others
    /// before [`Receiver::on_frame`].
    pub fn next_sequence_number(&self) -> Option<u8> {
        match self.core.state {
            State::Receiving { next_sn, .. } => Some(next_sn),
            State::Idle => None,
        }
    }

    /// The length announced by the First Frame of the reception in progress, `None` when idle.
    ///
    /// To refuse a message by its length: after the First Frame, call [`Receiver::abort`] instead
    /// of transmitting the Flow Control (or transmit an Overflow Flow Control built with
    /// [`pci::encode_flow_control`]); the sender then fails with N_Bs (or Overflow).
    pub fn message_len(&self) -> Option<usize> {
        self.in_progress().map(|(_, total)| total)
    }

    /// The bytes of the reception in progress received so far (empty when idle): a header can be
    /// checked before the rest arrives, and the reception [aborted](Receiver::abort) early.
    pub fn received(&self) -> &[u8] {
        match self.core.state {
            State::Receiving { received, .. } => self.buffer.get(..received).unwrap_or(&[]),
            State::Idle => &[],
        }
    }

    /// The whole buffer. After [`RxEvent::Complete`] the message is at its start and stays there
    /// until the next Single or First Frame: a node can store the image it just applied without a
    /// second buffer.
    pub fn buffer(&self) -> &[u8] {
        &self.buffer
    }

    /// The whole buffer, writable, when idle (`None` during a reception). A node reads its stored
    /// image into it at boot, so the transfer buffer is the only image-sized buffer it has.
    pub fn buffer_mut(&mut self) -> Option<&mut [u8]> {
        match self.core.state {
            State::Idle => Some(&mut self.buffer),
            State::Receiving { .. } => None,
        }
    }

    /// Drops the reception in progress, if any (returns whether there was one).
    ///
    /// The sender is not told (the standard has no frame for it mid-message): its remaining
    /// Consecutive Frames are ignored as unexpected, and it fails on N_Bs at its next Flow Control
    /// wait if the block size is not 0.
    pub fn abort(&mut self) -> bool {
        self.core.abort()
    }
}

impl Core {
    fn on_frame<'b>(&mut self, buffer: &'b mut [u8], data: &[u8], now: Instant) -> RxOutcome<'b> {
        let mut aborted = self.poll(now);
        let event = match pci::decode(data) {
            Err(error) => RxEvent::Ignored(Ignored::Malformed(error)),
            Ok((Pci::FlowControl { .. }, _)) => RxEvent::Ignored(Ignored::FlowControl),
            Ok((Pci::Single { len }, payload)) => {
                aborted = aborted.or(self.interrupt());
                single(buffer, len, payload)
            }
            Ok((Pci::First { len }, payload)) => {
                aborted = aborted.or(self.interrupt());
                self.first(
                    buffer,
                    len,
                    payload,
                    #[cfg(feature = "fd")]
                    0,
                    now,
                )
            }
            Ok((Pci::Consecutive { sn }, payload)) => {
                let (error, event) = self.consecutive(
                    buffer,
                    sn,
                    payload,
                    #[cfg(feature = "fd")]
                    0,
                    now,
                );
                aborted = aborted.or(error);
                event
            }
        };
        RxOutcome { aborted, event }
    }

    /// [`Core::on_frame`] for a CAN FD frame: its decoder, and its length as RX_DL.
    #[cfg(feature = "fd")]
    fn on_fd_frame<'b>(
        &mut self,
        buffer: &'b mut [u8],
        data: &[u8],
        now: Instant,
    ) -> RxOutcome<'b> {
        let mut aborted = self.poll(now);
        // A CAN FD length (fd::decode refuses any other): at most 64, so it fits.
        let dl = u8::try_from(data.len()).unwrap_or(u8::MAX);
        let event = match super::fd::decode(data) {
            Err(error) => RxEvent::Ignored(Ignored::Malformed(error)),
            Ok((Pci::FlowControl { .. }, _)) => RxEvent::Ignored(Ignored::FlowControl),
            Ok((Pci::Single { len }, payload)) => {
                aborted = aborted.or(self.interrupt());
                single(buffer, len, payload)
            }
            Ok((Pci::First { len }, payload)) => {
                aborted = aborted.or(self.interrupt());
                self.first(buffer, len, payload, dl, now)
            }
            Ok((Pci::Consecutive { sn }, payload)) => {
                let (error, event) = self.consecutive(buffer, sn, payload, dl, now);
                aborted = aborted.or(error);
                event
            }
        };
        RxOutcome { aborted, event }
    }

    /// Ends a reception in progress because a new message starts.
    fn interrupt(&mut self) -> Option<RxError> {
        self.abort().then_some(RxError::Interrupted)
    }

    fn first<'b>(
        &mut self,
        buffer: &'b mut [u8],
        len: u32,
        payload: &[u8],
        #[cfg(feature = "fd")] rx_dl: u8,
        now: Instant,
    ) -> RxEvent<'b> {
        let total = usize::try_from(len)
            .ok()
            .filter(|total| *total <= buffer.len());
        let (Some(total), Some(slot)) = (total, buffer.get_mut(..payload.len())) else {
            // FS = Overflow: the message does not fit; the sender gives up at once (N_BUFFER_OVFLW)
            // instead of waiting N_Bs.
            return RxEvent::Refused {
                reason: Refusal::TooLarge { len },
                flow_control: Some(self.flow_control(FlowStatus::Overflow)),
            };
        };
        slot.copy_from_slice(payload);
        self.state = State::Receiving {
            total,
            received: payload.len(),
            // The First Frame counts as segment 0; the first Consecutive Frame carries SN = 1.
            next_sn: 1,
            block_left: self.fresh_block(),
            // N_Cr runs from the Flow Control's transmission, which the caller does right away.
            deadline: deadline_after(now, self.config.n_cr_micros),
            #[cfg(feature = "fd")]
            rx_dl,
        };
        RxEvent::SendFlowControl(self.flow_control(FlowStatus::ContinueToSend))
    }

    fn consecutive<'b>(
        &mut self,
        buffer: &'b mut [u8],
        sn: u8,
        payload: &[u8],
        #[cfg(feature = "fd")] frame_dl: u8,
        now: Instant,
    ) -> (Option<RxError>, RxEvent<'b>) {
        let State::Receiving {
            total,
            received,
            next_sn,
            block_left,
            #[cfg(feature = "fd")]
            rx_dl,
            ..
        } = self.state
        else {
            return (None, RxEvent::Ignored(Ignored::UnexpectedConsecutive));
        };
        // Before the sequence number: a frame of the wrong kind or length is ignored (as the
        // standard ignores a frame of an invalid length), never taken as a lost frame.
        #[cfg(feature = "fd")]
        let per_frame = match fd_consecutive_len(rx_dl, frame_dl, total.saturating_sub(received)) {
            Ok(per_frame) => per_frame,
            Err(ignored) => return (None, RxEvent::Ignored(ignored)),
        };
        #[cfg(not(feature = "fd"))]
        let per_frame = pci::CONSECUTIVE_DATA_LEN;
        if sn != next_sn {
            // N_WRONG_SN: the standard aborts; the rest of the message's frames will be ignored as
            // unexpected, and the sender notices at its next Flow Control wait (N_Bs) if BS > 0.
            self.state = State::Idle;
            return (
                Some(RxError::WrongSequenceNumber {
                    expected: next_sn,
                    got: sn,
                }),
                RxEvent::Nothing,
            );
        }
        let remaining = total.saturating_sub(received);
        let needed = remaining.min(per_frame);
        // Bytes after `needed` in the last frame are padding. A frame with fewer bytes than needed
        // is ignored (invalid length); the next one then has an unexpected SN and aborts.
        // Both sides are cut to exactly `needed` bytes, so the copy's length check folds away
        // (a range `received..received + needed` would leave the compiler a panic to keep).
        let (Some(data), Some(slot)) = (
            payload.get(..needed),
            buffer
                .get_mut(received..)
                .and_then(|rest| rest.get_mut(..needed)),
        ) else {
            return (
                None,
                RxEvent::Ignored(Ignored::ShortConsecutive {
                    needed,
                    got: payload.len(),
                }),
            );
        };
        slot.copy_from_slice(data);
        let received = received.saturating_add(needed);
        if received >= total {
            self.state = State::Idle;
            return match buffer.get(..total) {
                Some(message) => (None, RxEvent::Complete(message)),
                None => (None, RxEvent::Nothing),
            };
        }
        // Block accounting: after BS Consecutive Frames the sender stops and waits for our next
        // Flow Control; N_Cr then runs from that Flow Control.
        let (block_left, event) = match block_left {
            Some(1) => (
                self.fresh_block(),
                RxEvent::SendFlowControl(self.flow_control(FlowStatus::ContinueToSend)),
            ),
            Some(left) => (Some(left.saturating_sub(1)), RxEvent::Nothing),
            None => (None, RxEvent::Nothing),
        };
        self.state = State::Receiving {
            total,
            received,
            // SN counts modulo 16: ..., 14, 15, 0, 1, ...
            next_sn: next_sn.wrapping_add(1) & 0x0F,
            block_left,
            deadline: deadline_after(now, self.config.n_cr_micros),
            #[cfg(feature = "fd")]
            rx_dl,
        };
        (None, event)
    }

    fn fresh_block(&self) -> Option<u8> {
        match self.config.block_size {
            0 => None,
            bs => Some(bs),
        }
    }

    /// Out of line: three callers inlined it (20 bytes of the NUCLEO-G474RE's flash).
    #[inline(never)]
    fn flow_control(&self, status: FlowStatus) -> [u8; FRAME_LEN] {
        pci::encode_flow_control(
            status,
            self.config.block_size,
            self.config.st_min,
            self.config.padding,
        )
    }

    fn poll(&mut self, now: Instant) -> Option<RxError> {
        match self.state {
            State::Receiving { deadline, .. } if expired(now, deadline) => {
                self.state = State::Idle;
                Some(RxError::Timeout)
            }
            _ => None,
        }
    }

    fn abort(&mut self) -> bool {
        let was_receiving = matches!(self.state, State::Receiving { .. });
        self.state = State::Idle;
        was_receiving
    }
}

/// The payload bytes a full Consecutive Frame of the reception carries (7 on classic CAN, RX_DL −
/// 1 on CAN FD), or why a Consecutive Frame of length `frame_dl` (0: a classic frame) is ignored
/// by a reception of RX_DL `rx_dl` (0: a classic reception) with `remaining` bytes to come: of
/// the other kind; longer than RX_DL; shorter and not the last (the Linux kernel's checks).
#[cfg(feature = "fd")]
fn fd_consecutive_len(rx_dl: u8, frame_dl: u8, remaining: usize) -> Result<usize, Ignored> {
    match (rx_dl, frame_dl) {
        (0, 0) => Ok(pci::CONSECUTIVE_DATA_LEN),
        (0, _) | (_, 0) => Err(Ignored::OtherFormat),
        (rx_dl, frame_dl) => {
            let per_frame = usize::from(rx_dl).saturating_sub(1);
            let last = remaining <= per_frame;
            if frame_dl > rx_dl || (frame_dl < rx_dl && !last) {
                Err(Ignored::FdLength {
                    rx_dl: usize::from(rx_dl),
                    got: usize::from(frame_dl),
                })
            } else {
                Ok(per_frame)
            }
        }
    }
}

/// A Single Frame's message into `buffer`.
fn single<'b>(buffer: &'b mut [u8], len: u8, payload: &[u8]) -> RxEvent<'b> {
    match buffer.get_mut(..payload.len()) {
        Some(slot) => {
            slot.copy_from_slice(payload);
            RxEvent::Complete(slot)
        }
        // Single Frames get no Flow Control, so there is no way to tell the sender.
        None => RxEvent::Refused {
            reason: Refusal::TooLarge {
                len: u32::from(len),
            },
            flow_control: None,
        },
    }
}
