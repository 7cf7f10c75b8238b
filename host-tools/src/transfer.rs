//! The tools' side of an ISO-TP transfer to a node: one message, segmented into the frames of the
//! bus's [`Framing`] (classic frames of 8 bytes, or CAN FD frames of 64 with the bit-rate switch:
//! ISO 15765-2:2016), paced by the node's flow control, on one service's identifiers (a table
//! push, a schema, a firmware update's messages). One segmenter for all of them: pab-core's
//! [`FdSender`], at TX_DL 8 for classic frames (the same bytes as the classic sender).

use pab_core::Frame;
use pab_core::isotp::fd::TxDl;
use pab_core::isotp::{FdSender, FlowControlEffect, TxConfig, TxError, TxEvent, TxSetupError};
use pab_core::protocol::{self, FrameId, Service};

use crate::bus::Framing;

/// Sends one message from the tool to a node over ISO-TP: call [`TransferSender::poll`], send
/// the frames it hands out, and give it the node's flow controls.
pub struct TransferSender<'a> {
    sender: FdSender<'a>,
    /// The identifier of the data frames: the service, from the tool to the node.
    id: embedded_can::Id,
    framing: Framing,
    frames: usize,
}

impl<'a> TransferSender<'a> {
    /// A transfer of `message` on `service` to `node`, framed as `framing` says. Fails for an
    /// empty message or one beyond ISO-TP's 32-bit length.
    pub fn new(
        message: &'a [u8],
        service: Service,
        node: u8,
        framing: Framing,
    ) -> Result<TransferSender<'a>, TxSetupError> {
        let tx_dl = match framing {
            Framing::Classic => TxDl::CLASSIC,
            Framing::Fd => TxDl::MAX,
        };
        Ok(TransferSender {
            sender: FdSender::new(message, TxConfig::default(), tx_dl)?,
            id: FrameId::new(service, protocol::TOOL, node).id(),
            framing,
            frames: 0,
        })
    }

    /// The next step at `now`: a frame to send now (`Send`), a wait, `Done` or `Failed`, as
    /// [`FdSender::poll`].
    pub fn poll(&mut self, now: pab_core::Instant) -> TxEvent<Frame> {
        match self.sender.poll(now) {
            TxEvent::Send(data) => {
                let frame = match self.framing {
                    Framing::Classic => Frame::data(self.id, data.as_bytes()),
                    Framing::Fd => Frame::fd(self.id, data.as_bytes(), true),
                };
                match frame {
                    Some(frame) => {
                        self.frames += 1;
                        TxEvent::Send(frame)
                    }
                    // A frame the sender made longer than its kind: never; fail, send nothing.
                    None => TxEvent::Failed(TxError::Overflow),
                }
            }
            TxEvent::WaitUntil(at) => TxEvent::WaitUntil(at),
            TxEvent::Done => TxEvent::Done,
            TxEvent::Failed(error) => TxEvent::Failed(error),
        }
    }

    /// A flow control's bytes from the node (in a classic or a CAN FD frame: its fields are
    /// the first three bytes), received at `now`.
    pub fn on_flow_control(&mut self, data: &[u8], now: pab_core::Instant) -> FlowControlEffect {
        self.sender.on_flow_control(data, now)
    }

    /// `(message bytes handed out, message length)`.
    pub fn progress(&self) -> (usize, usize) {
        self.sender.progress()
    }

    /// The frames handed out so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// How the frames are framed.
    pub fn framing(&self) -> Framing {
        self.framing
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pab_core::isotp::{Sender, TxEvent};
    use pab_core::protocol::Message;

    fn frames(message: &[u8], framing: Framing) -> Vec<Frame> {
        let mut sender = TransferSender::new(message, Service::TableTransfer, 3, framing).unwrap();
        let now = pab_core::Instant::from_micros(0);
        let mut out = Vec::new();
        loop {
            match sender.poll(now) {
                TxEvent::Send(frame) => out.push(frame),
                TxEvent::WaitUntil(_) => {
                    sender.on_flow_control(&[0x30, 0, 0], now);
                }
                TxEvent::Done => break,
                TxEvent::Failed(error) => panic!("{error:?}"),
            }
        }
        assert_eq!(sender.frames(), out.len());
        out
    }

    /// Classic framing sends what the tools sent before: the classic sender's frames, as
    /// TableTransfer messages from the tool.
    #[test]
    fn classic_frames_are_the_classic_senders() {
        let message: Vec<u8> = (0..500u32).map(|i| (i * 7) as u8).collect();
        let mut classic = Sender::new(&message, TxConfig::default()).unwrap();
        let now = pab_core::Instant::from_micros(0);
        let mut expected = Vec::new();
        loop {
            match classic.poll(now) {
                TxEvent::Send(data) => expected
                    .push(Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, 3)),
                TxEvent::WaitUntil(_) => {
                    classic.on_flow_control(&[0x30, 0, 0], now);
                }
                TxEvent::Done => break,
                TxEvent::Failed(error) => panic!("{error:?}"),
            }
        }
        assert_eq!(frames(&message, Framing::Classic), expected);
    }

    /// CAN FD framing: 64-byte CAN FD frames with the bit-rate switch, the last one shorter.
    #[test]
    fn fd_frames_are_64_bytes_with_brs() {
        let message = vec![0xA5; 500];
        let sent = frames(&message, Framing::Fd);
        // 62 bytes in the First Frame, 63 in each Consecutive Frame: 1 + ceil(438 / 63).
        assert_eq!(sent.len(), 1 + 438usize.div_ceil(63));
        assert!(sent.iter().all(|f| f.is_fd() && f.is_brs()));
        assert!(
            sent[..sent.len() - 1]
                .iter()
                .all(|f| f.payload().len() == 64)
        );
        assert_eq!(
            sent[0].id(),
            FrameId::new(Service::TableTransfer, 0, 3).id(),
            "from the tool to the node"
        );
    }
}
