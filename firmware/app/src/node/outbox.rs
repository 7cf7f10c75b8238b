//! The outbox: frames waiting to be sent, lowest identifier first, the diagnostic stream in the
//! room the rest leaves.

use super::*;

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// Out of line: eleven senders (answers, statuses, the heartbeat group) each inlined the
    /// encoding's call and the queueing. A node sends no command: [`Message::report_frame`]
    /// has none to encode.
    #[inline(never)]
    pub(super) fn send(&mut self, message: Message, destination: u8) {
        if let Some(frame) = message.report_frame(self.config.node_id, destination) {
            self.queue(frame);
        }
    }

    /// Queues a frame of our protocol (an answer, a claim) over the diagnostic stream if need
    /// be; when even that fails, the frame is lost and counted, with a TxOverrun fault. Out of
    /// line: one copy for every sender. Through [`enqueue_cold`] rather than an inlined
    /// [`Node::enqueue_over_diagnostic`]: these frames are not the frame path, and the inlined
    /// copy of the insertion took 228 bytes of the NUCLEO-G474RE's flash (a call more per
    /// frame: the heartbeat group 54 instructions dearer).
    #[inline(never)]
    pub(super) fn queue(&mut self, frame: Frame) {
        let queued = match enqueue_cold(&mut self.outbox, frame) {
            Ok(()) => Ok(()),
            Err(frame) => self.enqueue_in_place_of_diagnostic(frame),
        };
        if queued.is_err() {
            self.error(FaultCode::TxOverrun, [0; 5]);
        }
    }

    /// [`enqueue`], making room in a full outbox by dropping the oldest diagnostic sample
    /// queued, if any: the stream yields to everything else.
    #[inline]
    pub(super) fn enqueue_over_diagnostic(&mut self, frame: Frame) -> Result<(), Frame> {
        match enqueue(&mut self.outbox, frame) {
            Ok(()) => Ok(()),
            Err(frame) => self.enqueue_in_place_of_diagnostic(frame),
        }
    }

    /// The full outbox's case of [`Node::enqueue_over_diagnostic`], out of line.
    #[inline(never)]
    pub(super) fn enqueue_in_place_of_diagnostic(&mut self, frame: Frame) -> Result<(), Frame> {
        let diagnostic = FrameId::new(
            Service::Diagnostic,
            self.config.node_id,
            protocol::BROADCAST,
        )
        .id();
        // The oldest sample is the one that leaves first: the last with that identifier.
        let oldest = self
            .outbox
            .iter()
            .rposition(|queued| queued.id() == diagnostic && !queued.is_remote());
        match oldest {
            Some(position) => {
                remove(&mut self.outbox, position);
                enqueue_cold(&mut self.outbox, frame)
            }
            None => Err(frame),
        }
    }
}

/// Queues `frame` in `outbox` (sorted by rank, highest first, equal ranks newest first) in
/// identifier order: it leaves after every queued frame that would win arbitration over it or has
/// its identifier, before the others. Fails when the outbox is full. Cost: a rank comparison and
/// a frame swap per queued frame that leaves before it (usually none or few: protocol answers
/// and re-publications rank low, the diagnostic stream high).
///
/// Inlined only into the frame path (a re-publication: out of line it cost 100 instructions more
/// per delivered frame, the frame copied twice); the other paths share [`enqueue_cold`] and
/// [`Node::queue`].
#[inline]
pub(super) fn enqueue(
    outbox: &mut heapless::Vec<Frame, OUTBOX_LEN>,
    frame: Frame,
) -> Result<(), Frame> {
    let rank = frame.arbitration_rank();
    outbox.push(frame)?;
    // Move it down from the end past the frames that leave before it.
    let mut slots = outbox.iter_mut().rev();
    let Some(mut new) = slots.next() else {
        return Ok(());
    };
    for before in slots {
        if before.arbitration_rank() > rank {
            break;
        }
        core::mem::swap(before, new);
        new = before;
    }
    Ok(())
}

/// [`enqueue`] out of line, for what is not the frame path (our protocol's frames, diagnostic
/// samples, the full outbox's case): one copy of it instead of one per caller.
///
/// It pushes a placeholder and writes the frame over it: pushed as it came, the frame was copied
/// by a byte-by-byte `memcpy` (the 18 bytes past its identifier's tag: 90 instructions), a word
/// at a time this way.
#[inline(never)]
pub(super) fn enqueue_cold(
    outbox: &mut heapless::Vec<Frame, OUTBOX_LEN>,
    frame: Frame,
) -> Result<(), Frame> {
    let ranked = rank(&frame);
    if outbox.push(Frame::empty()).is_err() {
        return Err(frame);
    }
    let mut slots = outbox.iter_mut().rev();
    let Some(mut new) = slots.next() else {
        return Ok(());
    };
    *new = frame;
    for before in slots {
        if rank(before) > ranked {
            break;
        }
        core::mem::swap(before, new);
        new = before;
    }
    Ok(())
}

/// [`Frame::arbitration_rank`] out of line, for [`enqueue_cold`]: inlined, its two copies there
/// took 24 bytes of the NUCLEO-G474RE's flash. ([`enqueue`], the frame path, keeps its own.)
#[inline(never)]
fn rank(frame: &Frame) -> u32 {
    frame.arbitration_rank()
}

/// Removes the frame at `position` from `outbox`, keeping the others in order.
pub(super) fn remove(outbox: &mut heapless::Vec<Frame, OUTBOX_LEN>, position: usize) {
    let mut slots = outbox.iter_mut().skip(position);
    if let Some(mut hole) = slots.next() {
        for next in slots {
            core::mem::swap(hole, next);
            hole = next;
        }
        outbox.pop();
    }
}
