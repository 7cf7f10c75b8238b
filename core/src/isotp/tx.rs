//! The sending side: a borrowed payload in, frames out, paced by the receiver's Flow Controls.
//!
//! One state machine for both kinds of frame: [`Sender`] hands out classic CAN's 8-byte frames,
//! [`FdSender`] CAN FD frames of up to TX_DL bytes (ISO 15765-2:2016); at TX_DL 8 the two send
//! the same bytes.

use super::fd::{self, FdFrame, TxDl};
use super::pci::{self, FRAME_LEN, FlowStatus, Pci};
use super::{deadline_after, expired};
use crate::time::Instant;

/// How a [`Sender`] frames and waits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TxConfig {
    /// The byte that pads every frame to 8 bytes. Default 0xCC.
    pub padding: u8,
    /// N_Bs: the longest wait for a Flow Control after the First Frame, after the last Consecutive
    /// Frame of a block, or after a WAIT, in microseconds. Default 1 000 000 (1 s, the standard's
    /// value).
    pub n_bs_micros: u64,
    /// N_WFTmax: how many WAIT Flow Controls in a row are accepted; one more fails the transfer.
    /// 0 refuses any WAIT. Default 10.
    pub max_wait_frames: u8,
}

impl Default for TxConfig {
    fn default() -> Self {
        TxConfig {
            padding: pci::DEFAULT_PADDING,
            n_bs_micros: 1_000_000,
            max_wait_frames: 10,
        }
    }
}

/// Why a [`Sender`] cannot be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TxSetupError {
    /// ISO-TP has no empty messages.
    Empty,
    /// Longer than the escaped First Frame's 32-bit length can announce.
    TooLong {
        /// The payload's length.
        len: usize,
    },
}

impl core::fmt::Display for TxSetupError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TxSetupError::Empty => f.write_str("ISO-TP has no empty messages"),
            TxSetupError::TooLong { len } => write!(
                f,
                "{len} bytes: longer than an ISO-TP first frame can announce"
            ),
        }
    }
}

impl core::error::Error for TxSetupError {}

// Not `#[non_exhaustive]`: pabctl explains each variant to its user (host-tools/src/push.rs).
/// Why a transfer failed. The sender then stays failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TxError {
    /// No Flow Control within N_Bs (N_TIMEOUT_Bs).
    Timeout,
    /// The receiver answered Overflow: the message is too long for it (N_BUFFER_OVFLW).
    Overflow,
    /// More than N_WFTmax WAIT Flow Controls in a row (N_WFT_OVRN).
    TooManyWaits,
    /// A Flow Control with a reserved flow status 3..=15 (N_INVALID_FS).
    InvalidFlowStatus {
        /// The status nibble received.
        status: u8,
    },
}

impl core::fmt::Display for TxError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TxError::Timeout => f.write_str("no ISO-TP flow control within N_Bs"),
            TxError::Overflow => {
                f.write_str("the receiver answered overflow: the message is too long for it")
            }
            TxError::TooManyWaits => {
                f.write_str("more ISO-TP wait flow controls in a row than allowed")
            }
            TxError::InvalidFlowStatus { status } => {
                write!(
                    f,
                    "ISO-TP flow control with the reserved flow status {status}"
                )
            }
        }
    }
}

impl core::error::Error for TxError {}

/// What the caller must do next for a [`Sender`] (frames of 8 bytes) or an [`FdSender`] (`F`:
/// [`FdFrame`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TxEvent<F = [u8; FRAME_LEN]> {
    /// Transmit this frame now, then poll again.
    Send(F),
    /// Nothing to send before this instant: STmin pacing, or the N_Bs deadline while waiting for
    /// a Flow Control (deliver it with [`Sender::on_flow_control`] when it comes). Poll again then.
    WaitUntil(Instant),
    /// Every frame has been handed out.
    Done,
    /// The transfer failed.
    Failed(TxError),
}

/// What [`Sender::on_flow_control`] did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlowControlEffect {
    /// ContinueToSend: the next block may go.
    Resumed,
    /// WAIT: N_Bs restarted.
    Waiting,
    /// The transfer failed (also reported by the next [`Sender::poll`]).
    Failed(TxError),
    /// The frame was ignored: no Flow Control was awaited, or it is not a (decodable) Flow
    /// Control.
    Ignored,
}

#[derive(Clone, Copy, Debug)]
enum State {
    /// Nothing sent yet.
    Start,
    /// Waiting for a Flow Control until `deadline`; `waits` WAITs received in a row.
    AwaitFlowControl {
        deadline: Instant,
        waits: u8,
    },
    /// Sending Consecutive Frames.
    Sending {
        /// Frames left in the block; `None` when BS = 0 (no more Flow Control).
        block_left: Option<u8>,
        /// STmin of the last ContinueToSend, in µs.
        st_min_micros: u32,
        /// The next frame may not go before this instant; `None`: at once.
        not_before: Option<Instant>,
    },
    Done,
    Failed(TxError),
}

/// Segments one message, borrowed for the whole transfer, into frames.
///
/// Memory: the borrow plus about 40 bytes. Each call costs a few comparisons plus copying at most
/// 7 bytes. Never panics. The caller transmits what [`Sender::poll`] hands out, in order, and
/// passes the Flow Controls that arrive on the reply identifier to [`Sender::on_flow_control`].
///
/// Timing: the `now` of the `poll` that returned a frame is taken as its transmission time; N_Bs
/// and STmin are measured from it.
#[derive(Clone, Debug)]
pub struct Sender<'a> {
    payload: &'a [u8],
    config: TxConfig,
    /// The length of full frames: 8 for [`Sender`] itself, TX_DL for an [`FdSender`].
    tx_dl: TxDl,
    /// Payload bytes handed out so far.
    sent: usize,
    /// The sequence number of the next Consecutive Frame.
    sn: u8,
    state: State,
}

impl<'a> Sender<'a> {
    /// A sender of `payload`. Costs nothing; the first [`poll`](Sender::poll) yields the first frame.
    ///
    /// Fails with [`TxSetupError::Empty`] for an empty payload and [`TxSetupError::TooLong`] above
    /// u32::MAX bytes.
    pub fn new(payload: &'a [u8], config: TxConfig) -> Result<Self, TxSetupError> {
        if payload.is_empty() {
            return Err(TxSetupError::Empty);
        }
        if u32::try_from(payload.len()).is_err() {
            return Err(TxSetupError::TooLong { len: payload.len() });
        }
        Ok(Sender {
            payload,
            config,
            tx_dl: TxDl::CLASSIC,
            sent: 0,
            // The First Frame is segment 0; Consecutive Frames start at 1.
            sn: 1,
            state: State::Start,
        })
    }

    /// The next step at `now`. Costs a few comparisons and at most one frame's encoding.
    ///
    /// Returns `Send` for the Single or First Frame, then for each Consecutive Frame when STmin
    /// and the block allow it; `WaitUntil` when it must wait (for STmin, or for a Flow Control until
    /// N_Bs expires); `Done` once every byte has been handed out; `Failed` after N_Bs expired,
    /// an Overflow, too many WAITs or an invalid flow status. `Done` and `Failed` are final.
    pub fn poll(&mut self, now: Instant) -> TxEvent {
        match self.step(now) {
            // Always 8 bytes at TX_DL 8 (`new`'s): the classic frame, byte for byte.
            TxEvent::Send(frame) => TxEvent::Send(
                frame
                    .as_bytes()
                    .first_chunk::<FRAME_LEN>()
                    .copied()
                    .unwrap_or([self.config.padding; FRAME_LEN]),
            ),
            TxEvent::WaitUntil(at) => TxEvent::WaitUntil(at),
            TxEvent::Done => TxEvent::Done,
            TxEvent::Failed(error) => TxEvent::Failed(error),
        }
    }

    /// [`Sender::poll`] with frames of up to TX_DL bytes.
    fn step(&mut self, now: Instant) -> TxEvent<FdFrame> {
        match self.state {
            State::Start => self.start(now),
            State::AwaitFlowControl { deadline, .. } => {
                if expired(now, deadline) {
                    self.fail(TxError::Timeout)
                } else {
                    TxEvent::WaitUntil(deadline)
                }
            }
            State::Sending {
                block_left,
                st_min_micros,
                not_before,
            } => match not_before {
                Some(at) if !expired(now, at) => TxEvent::WaitUntil(at),
                _ => self.consecutive(block_left, st_min_micros, now),
            },
            State::Done => TxEvent::Done,
            State::Failed(error) => TxEvent::Failed(error),
        }
    }

    fn fail(&mut self, error: TxError) -> TxEvent<FdFrame> {
        self.state = State::Failed(error);
        TxEvent::Failed(error)
    }

    fn start(&mut self, now: Instant) -> TxEvent<FdFrame> {
        if let Ok(frame) = fd::encode_single(self.payload, self.tx_dl, self.config.padding) {
            self.sent = self.payload.len();
            self.state = State::Done;
            return TxEvent::Send(frame);
        }
        // `new` checked that the length fits in u32, and it is over what a Single Frame carries
        // here.
        let len = u32::try_from(self.payload.len()).unwrap_or(u32::MAX);
        match fd::encode_first(len, self.payload, self.tx_dl) {
            Ok((frame, carried)) => {
                self.sent = carried;
                self.await_flow_control(now, 0);
                TxEvent::Send(frame)
            }
            // Unreachable with the checks in `new`; fail rather than send something wrong.
            Err(_) => self.fail(TxError::Overflow),
        }
    }

    fn await_flow_control(&mut self, now: Instant, waits: u8) {
        self.state = State::AwaitFlowControl {
            deadline: deadline_after(now, self.config.n_bs_micros),
            waits,
        };
    }

    fn consecutive(
        &mut self,
        block_left: Option<u8>,
        st_min_micros: u32,
        now: Instant,
    ) -> TxEvent<FdFrame> {
        let rest = self.payload.get(self.sent..).unwrap_or(&[]);
        let data = rest
            .get(..self.tx_dl.consecutive_data_len())
            .unwrap_or(rest);
        let Ok(frame) = fd::encode_consecutive(self.sn, data, self.tx_dl, self.config.padding)
        else {
            // Only an empty `data`, which `Done` prevents.
            self.state = State::Done;
            return TxEvent::Done;
        };
        self.sent = self.sent.saturating_add(data.len());
        self.sn = self.sn.wrapping_add(1) & 0x0F;
        if self.sent >= self.payload.len() {
            self.state = State::Done;
        } else if block_left == Some(1) {
            // The block is complete: stop until the receiver's next Flow Control.
            self.await_flow_control(now, 0);
        } else {
            self.state = State::Sending {
                block_left: block_left.map(|left| left.saturating_sub(1)),
                st_min_micros,
                // STmin is the gap from one Consecutive Frame to the next; 0 sends back to back.
                not_before: (st_min_micros > 0)
                    .then(|| deadline_after(now, u64::from(st_min_micros))),
            };
        }
        TxEvent::Send(frame)
    }

    /// Takes a frame from the receiver, received at `now`.
    ///
    /// Only used while a Flow Control is awaited (after the First Frame or a full block);
    /// otherwise ignored, as the standard says. ContinueToSend takes its BS and STmin (every CTS,
    /// as python `can-isotp` does; Linux keeps those of the first: a receiver that keeps them
    /// constant, as [`Receiver`](super::Receiver) does, sees no difference) and the first
    /// Consecutive Frame may go at once; WAIT restarts N_Bs; Overflow and reserved statuses fail
    /// the transfer. Malformed frames are ignored. Costs a few comparisons.
    pub fn on_flow_control(&mut self, data: &[u8], now: Instant) -> FlowControlEffect {
        let State::AwaitFlowControl { waits, .. } = self.state else {
            return FlowControlEffect::Ignored;
        };
        match pci::decode(data) {
            Ok((
                Pci::FlowControl {
                    status,
                    block_size,
                    st_min,
                },
                _,
            )) => match status {
                FlowStatus::ContinueToSend => {
                    self.state = State::Sending {
                        block_left: (block_size > 0).then_some(block_size),
                        // Reserved STmin values count as 127 ms (`StMin::as_micros`).
                        st_min_micros: st_min.as_micros(),
                        not_before: None,
                    };
                    FlowControlEffect::Resumed
                }
                FlowStatus::Wait => {
                    if waits >= self.config.max_wait_frames {
                        self.fail(TxError::TooManyWaits);
                        FlowControlEffect::Failed(TxError::TooManyWaits)
                    } else {
                        self.await_flow_control(now, waits.saturating_add(1));
                        FlowControlEffect::Waiting
                    }
                }
                FlowStatus::Overflow => {
                    self.fail(TxError::Overflow);
                    FlowControlEffect::Failed(TxError::Overflow)
                }
            },
            Err(pci::FrameError::InvalidFlowStatus { status }) => {
                let error = TxError::InvalidFlowStatus { status };
                self.fail(error);
                FlowControlEffect::Failed(error)
            }
            _ => FlowControlEffect::Ignored,
        }
    }

    /// `(payload bytes handed out, payload length)`.
    pub fn progress(&self) -> (usize, usize) {
        (self.sent, self.payload.len())
    }

    /// The payload being sent.
    pub fn payload(&self) -> &'a [u8] {
        self.payload
    }
}

/// Segments one message into CAN FD frames of TX_DL bytes (ISO 15765-2:2016): [`Sender`]'s state
/// machine (the same Flow Control handling, N_Bs, STmin and WAITs), with frames of up to 64
/// bytes. Single Frames of up to TX_DL − 2 bytes use the escape, longer messages a First Frame
/// of TX_DL bytes, then Consecutive Frames of TX_DL bytes but the last, padded to the smallest
/// CAN FD length that holds it (and 8 at least). The caller sends each frame as a CAN FD frame.
///
/// Memory: [`Sender`]'s. Each call copies at most one frame (65 bytes). Never panics.
#[derive(Clone, Debug)]
pub struct FdSender<'a>(Sender<'a>);

impl<'a> FdSender<'a> {
    /// A sender of `payload` in frames of `tx_dl` bytes. Fails as [`Sender::new`].
    pub fn new(payload: &'a [u8], config: TxConfig, tx_dl: TxDl) -> Result<Self, TxSetupError> {
        let mut sender = Sender::new(payload, config)?;
        sender.tx_dl = tx_dl;
        Ok(FdSender(sender))
    }

    /// The next step at `now`, as [`Sender::poll`]: `Send` hands out a CAN FD frame's data field
    /// (8 to TX_DL bytes, a valid CAN FD length).
    pub fn poll(&mut self, now: Instant) -> TxEvent<FdFrame> {
        self.0.step(now)
    }

    /// Takes a frame from the receiver, received at `now`, as [`Sender::on_flow_control`] (a Flow
    /// Control's fields are its first 3 bytes, whatever the frame's length).
    pub fn on_flow_control(&mut self, data: &[u8], now: Instant) -> FlowControlEffect {
        // A Flow Control in a CAN FD frame may be longer than 8 bytes; its fields are the first 3.
        let data = data.get(..FRAME_LEN).unwrap_or(data);
        self.0.on_flow_control(data, now)
    }

    /// `(payload bytes handed out, payload length)`.
    pub fn progress(&self) -> (usize, usize) {
        self.0.progress()
    }

    /// The payload being sent.
    pub fn payload(&self) -> &'a [u8] {
        self.0.payload()
    }

    /// TX_DL, the length of its full frames.
    pub fn tx_dl(&self) -> TxDl {
        self.0.tx_dl
    }
}
