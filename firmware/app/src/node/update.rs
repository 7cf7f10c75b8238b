//! Firmware update over the bus (feature `update`): the UpdateTransfer service's ISO-TP
//! messages, judged by `pab_core::update::session`, written into the store's update slot by the
//! runner ([`Step::WriteUpdate`], [`Step::RequestUpdate`]), answered with UpdateStatus; and,
//! at start, the bootloader's verdict on the last request.
//!
//! **Who may update**: only the tool (source 0), point to point. On a keyed node the Begin
//! needs a TransferOpen with [`OPEN_UPDATE`] for its length (97 bytes), as a table needs its
//! own: a participant without the key cannot start an update, nor restart the node through one.
//! The image itself is the signature's business, checked by the bootloader before it swaps
//! (docs/firmware-update.md): whatever the bus carries into the slot, nothing unsigned runs.
//!
//! **Its own receiver**: an update's chunk (up to 1 029 bytes) never waits for a table's
//! transfer buffer, and a table transfer goes on during an update (the node keeps running its
//! table until it restarts).

use pab_core::update::MANIFEST_LEN;
use pab_core::update::session::{self, Outcome, Updater};
use pab_core::update::stored::Verdict;

use super::*;
use protocol::{OPEN_UPDATE, UpdateStatus, UpdateStatusCode};

/// The UpdateFailed fault's detail byte 0 when the update partition could not be written (1 to
/// 7 are the refusals' codes).
const PARTITION_FAILED: u8 = 8;
/// The UpdateFailed fault's detail byte 0 when an accepted image does not run (reverted).
const NOT_RUNNING: u8 = 9;

/// The update receiver's buffer: the longest message.
const UPDATE_MESSAGE_LEN: usize = session::MESSAGE_MAX;

/// What the runner owes the session.
#[derive(Clone, Copy, Debug)]
enum Owed {
    Nothing,
    /// Write the chunk at `offset`: `len` bytes at offset 5 of the receiver's message.
    Write {
        offset: u32,
        len: usize,
    },
    /// Store the manifest and the request.
    Request([u8; MANIFEST_LEN]),
}

/// A node's update state: its receiver, its session, what it owes.
pub(crate) struct Update {
    receiver: isotp::Receiver<UPDATE_MESSAGE_LEN>,
    updater: Updater,
    owed: Owed,
    /// The store's slot length; 0 until the runner says, and on a board without a slot.
    slot_len: u32,
}

impl Update {
    pub(crate) fn new(config: isotp::RxConfig) -> Self {
        Update {
            receiver: isotp::Receiver::new(config),
            updater: Updater::new(),
            owed: Owed::Nothing,
            slot_len: 0,
        }
    }

    /// Whether a session or a reception is under way (the duties then run at every frame).
    pub(crate) fn is_busy(&self) -> bool {
        self.updater.is_open() || self.receiver.deadline().is_some()
    }

    /// The earliest instant the update needs the node's duties.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        match (self.receiver.deadline(), self.updater.deadline()) {
            (Some(a), Some(b)) => Some(if a.micros_since(b).is_some() { b } else { a }),
            (a, b) => a.or(b),
        }
    }
}

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// The store's update slot, `slot_len` bytes (`TableStore::update_slot_len`: 0 without
    /// one, and every Begin is answered Unsupported). The runner says it once, at start.
    pub fn set_update_slot(&mut self, slot_len: u32) {
        self.update.slot_len = slot_len;
    }

    /// The bootloader's verdict on the last request (`TableStore::take_update_verdict`), at
    /// start: to the tool, Swapped if the firmware that runs is the one asked for, NotRunning if
    /// the bootloader accepted it but another runs (it was reverted), Refused with the refusal's
    /// code; a fault for the last two.
    pub fn update_verdict(&mut self, verdict: Verdict) {
        match verdict.outcome {
            Ok(()) if verdict.requested.map(|t| t.firmware) == Some(self.me.firmware) => {
                info!("firmware update: the bootloader swapped the image in");
                self.update_status(protocol::TOOL, UpdateStatusCode::Swapped, 0, 0);
            }
            Ok(()) => {
                warn!("firmware update: accepted by the bootloader, but not what runs (reverted)");
                self.update_status(protocol::TOOL, UpdateStatusCode::NotRunning, 0, 0);
                self.raise(FaultCode::UpdateFailed, [NOT_RUNNING, 0, 0, 0, 0]);
            }
            Err(refusal) => {
                warn!(
                    "firmware update refused by the bootloader: {}",
                    int(u32::from(refusal))
                );
                self.update_refused(protocol::TOOL, refusal);
            }
        }
    }

    /// An UpdateTransfer frame from `id.source`.
    pub(super) fn on_update_frame(
        &mut self,
        id: FrameId,
        data: &[u8],
        wire: Wire,
        now: Instant,
    ) -> Step {
        let source = id.source;
        if self.guard.locked().is_some() {
            self.unauthenticated(AuthFailure::Locked, id);
            return Step::Continue;
        }
        if source != protocol::TOOL {
            self.unauthenticated(AuthFailure::NotTool, id);
            return Step::Continue;
        }
        if !matches!(self.update.owed, Owed::Nothing) {
            self.update_status(source, UpdateStatusCode::Busy, 0, 0);
            return Step::Continue;
        }
        if self.guard.is_keyed()
            && let Err(failure) = self.admit_update(data, wire, now)
        {
            self.unauthenticated(failure, id);
            return Step::Continue;
        }
        let outcome = wire.receive(&mut self.update.receiver, data, now);
        match outcome.event {
            RxEvent::SendFlowControl(flow_control) => {
                self.send_update_flow_control(source, flow_control, wire);
                Step::Continue
            }
            RxEvent::Refused { flow_control, .. } => {
                if let Some(flow_control) = flow_control {
                    self.send_update_flow_control(source, flow_control, wire);
                }
                Step::Continue
            }
            RxEvent::Complete(message) => {
                let len = message.len();
                self.on_update_message(source, len, now)
            }
            RxEvent::Nothing | RxEvent::Ignored(_) => Step::Continue,
        }
    }

    /// On a keyed node, whether an update frame may reach the receiver: a first (or single)
    /// frame only with an open for an update of its length, a consecutive frame only in
    /// sequence. Chunks and commits need no open of their own: the session the open began
    /// admits them, and the bootloader's signature check whatever they carry.
    fn admit_update(&mut self, data: &[u8], wire: Wire, now: Instant) -> Result<(), AuthFailure> {
        let first_len = match wire.decode(data) {
            Ok((Pci::First { len }, _)) => usize::try_from(len).ok(),
            Ok((Pci::Single { len }, _)) => Some(usize::from(len)),
            Ok((Pci::Consecutive { sn }, _)) => {
                return match self.update.receiver.next_sequence_number() {
                    Some(next) if next != sn => Err(AuthFailure::Sequence),
                    _ => Ok(()),
                };
            }
            _ => return Ok(()),
        };
        // Within a session, its chunks and its commit.
        if self.update.updater.is_open() {
            return Ok(());
        }
        let open = self
            .opened
            .filter(|opened| {
                opened
                    .expires
                    .micros_since(now)
                    .is_some_and(|left| left > 0)
            })
            .filter(|opened| first_len == Some(usize::from(opened.length)))
            .filter(|opened| opened.flags == OPEN_UPDATE)
            .ok_or(AuthFailure::Unopened)?;
        let _ = open;
        self.opened = None;
        Ok(())
    }

    /// An update's flow control to `destination`, in the kind of frame its transfer came in.
    // Inlined: without the feature `fd`, the two sends the receiver's events made before.
    #[inline(always)]
    fn send_update_flow_control(&mut self, destination: u8, data: [u8; 8], wire: Wire) {
        let message = Message::UpdateTransfer { data, len: 8 };
        #[cfg(feature = "fd")]
        if let Some(frame) = message.report_frame(self.config.node_id, destination) {
            self.queue(wire.answer(frame));
        }
        #[cfg(not(feature = "fd"))]
        {
            let _ = wire;
            self.send(message, destination);
        }
    }

    /// A complete update message of `len` bytes in the receiver's buffer.
    fn on_update_message(&mut self, source: u8, len: usize, now: Instant) -> Step {
        let firmware = self.me.firmware;
        if self.update.slot_len == 0 {
            self.update_status(source, UpdateStatusCode::Unsupported, 0, 0);
            return Step::Continue;
        }
        let update = &mut self.update;
        let message = update.receiver.buffer().get(..len).unwrap_or(&[]);
        let outcome = update
            .updater
            .on_message(message, &firmware, update.slot_len, now);
        match outcome {
            Outcome::Write { offset, data } => {
                update.owed = Owed::Write {
                    offset,
                    len: data.len(),
                };
                Step::WriteUpdate
            }
            Outcome::Request { manifest } => {
                update.owed = Owed::Request(manifest);
                Step::RequestUpdate
            }
            other => {
                // A Write is matched above: the fallback is never taken.
                let answer = other.detached().unwrap_or(Outcome::Malformed);
                self.answer_update(source, answer);
                Step::Continue
            }
        }
    }

    /// The chunk the runner is to write ([`Step::WriteUpdate`]): its offset in the slot and its
    /// bytes; `None` when no write is owed.
    pub fn update_chunk(&self) -> Option<(u32, &[u8])> {
        match self.update.owed {
            Owed::Write { offset, len } => {
                let bytes = self.update.receiver.buffer().get(5..5 + len)?;
                Some((offset, bytes))
            }
            _ => None,
        }
    }

    /// The manifest the runner is to store with the request ([`Step::RequestUpdate`]).
    pub fn update_manifest(&self) -> Option<&[u8; MANIFEST_LEN]> {
        match &self.update.owed {
            Owed::Request(manifest) => Some(manifest),
            _ => None,
        }
    }

    /// How the runner's write of [`Node::update_chunk`] went: the chunk's answer.
    pub fn update_written(&mut self, ok: bool) {
        if matches!(self.update.owed, Owed::Write { .. }) {
            self.update.owed = Owed::Nothing;
            let outcome = self.update.updater.written(ok);
            self.answer_update(protocol::TOOL, outcome);
        }
    }

    /// How the runner's storing of [`Node::update_manifest`] and the request went: the
    /// Commit's answer; `true` when the runner must now send the outbox and restart the board
    /// into its bootloader.
    #[must_use = "true: restart the board once the answer is sent"]
    pub fn update_requested(&mut self, ok: bool) -> bool {
        if !matches!(self.update.owed, Owed::Request(_)) {
            return false;
        }
        self.update.owed = Owed::Nothing;
        let outcome = self.update.updater.requested(ok);
        let restart = matches!(outcome, Outcome::Committed { .. });
        if restart {
            info!("firmware update committed: restarting into the bootloader");
        }
        self.answer_update(protocol::TOOL, outcome);
        restart
    }

    /// The duties of an update: the reception's N_Cr and the session's timeout.
    pub(super) fn update_due(&mut self, now: Instant) {
        if self.update.receiver.poll(now).is_some() {
            warn!("firmware update: a message's reception timed out");
        }
        if self.update.updater.expire(now) {
            warn!("firmware update: the session timed out");
        }
    }

    /// An outcome as the UpdateStatus it is answered with.
    fn answer_update(&mut self, source: u8, outcome: Outcome<'_>) {
        let (status, offset, value) = match outcome {
            Outcome::Ready { chunk } => (UpdateStatusCode::Ready, 0, chunk),
            Outcome::Ack { offset, crc } => (UpdateStatusCode::Ack, offset, crc),
            Outcome::Committed { offset, crc } => (UpdateStatusCode::Committed, offset, crc),
            Outcome::Refused(refusal) => {
                self.update_refused(source, refusal.code());
                return;
            }
            Outcome::OutOfOrder { offset, crc } => (UpdateStatusCode::OutOfOrder, offset, crc),
            Outcome::Mismatch { offset, crc } => (UpdateStatusCode::Mismatch, offset, crc),
            Outcome::FlashError { offset } => {
                self.error(FaultCode::UpdateFailed, [PARTITION_FAILED, 0, 0, 0, 0]);
                (UpdateStatusCode::FlashError, offset, 0)
            }
            Outcome::NoSession => (UpdateStatusCode::NoSession, 0, 0),
            // A malformed message is counted, not answered: the tool's own timeout tells it.
            Outcome::Malformed => {
                self.error(
                    FaultCode::BadCommand,
                    [Service::UpdateTransfer.code(), 0, 0, 0, 0],
                );
                return;
            }
            Outcome::Aborted => return,
            // Asked of the runner, never answered as such.
            Outcome::Write { .. } | Outcome::Request { .. } => return,
        };
        self.update_status(source, status, offset, value);
    }

    /// A refused image: its answer, and a fault with the refusal's code.
    fn update_refused(&mut self, source: u8, refusal: u8) {
        self.update_status(source, UpdateStatusCode::Refused, 0, u32::from(refusal));
        self.raise(FaultCode::UpdateFailed, [refusal, 0, 0, 0, 0]);
    }

    fn update_status(
        &mut self,
        destination: u8,
        status: UpdateStatusCode,
        offset: u32,
        value: u32,
    ) {
        self.send(
            Message::UpdateStatus(UpdateStatus {
                status,
                offset,
                value,
            }),
            destination,
        );
    }
}
