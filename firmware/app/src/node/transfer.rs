//! Table transfers: a push opened (plain or keyed), its ISO-TP frames, the image checked whole and
//! swapped in, the answers; and the checks an image passes before it runs.

use super::*;

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// The transfer in progress lost its slot (Timeout), and its sender learns why: its
    /// reception timed out (`too_slow` false: detail 0), or it used up its time budget
    /// ([`TRANSFER_BASE_US`]; `too_slow`: detail 1, the reception aborted). One function for
    /// both, which differ only in these, so that the taking and the refusal are in the flash once.
    #[inline(never)]
    pub(super) fn transfer_timeout(&mut self, too_slow: bool) {
        if too_slow {
            self.receiver.abort();
        }
        if let Some(incoming) = self.incoming.take() {
            let source = int(u32::from(incoming.source));
            // Two messages; with logging compiled out (no `log` or `defmt`) both branches are
            // empty.
            #[allow(clippy::if_same_then_else)]
            if too_slow {
                warn!("table transfer from {} too slow", source);
            } else {
                warn!("table transfer from {} timed out", source);
            }
            self.refuse(
                incoming.source,
                TransferStatusCode::Timeout,
                u8::from(too_slow),
                incoming.nonce,
            );
        }
    }

    /// A configuration message refused by the authentication rules: counted, and a fault says
    /// why, which service and from whom. Out of line: nine refusals inlined it. The identifier
    /// by value here and in the transfer handlers (4 bytes, one register): by reference, each
    /// caller first stored it on its stack.
    #[inline(never)]
    pub(super) fn unauthenticated(&mut self, failure: AuthFailure, id: FrameId) {
        warn!("configuration refused: {}", code(failure, failure.code()));
        self.error(
            FaultCode::Unauthenticated,
            [failure.code(), id.service.code(), id.source, 0, 0],
        );
    }

    /// A ChallengeRequest to this node: the new challenge to its sender, or the refusal. Out of
    /// line: in the frame handler it cost 180 bytes of flash (registers the other arms then
    /// lacked).
    #[inline(never)]
    pub(super) fn on_challenge_request(&mut self, id: FrameId, tool_nonce: u64, now: Instant) {
        match self.guard.challenge(self.config.node_id, tool_nonce, now) {
            Ok((node_nonce, binding)) => self.send(
                Message::Challenge {
                    node_nonce,
                    binding,
                },
                id.source,
            ),
            Err(failure) => self.unauthenticated(failure, id),
        }
    }

    /// A TransferOpen: if its tag verifies over the outstanding challenge, the next first frame
    /// from the tool with exactly its length (within a second) starts an authenticated transfer.
    /// A valid open replaces a transfer in progress (the key holder restarted its push).
    pub(super) fn on_transfer_open(&mut self, id: FrameId, open: &TransferOpen, now: Instant) {
        if id.source != protocol::TOOL {
            self.unauthenticated(AuthFailure::NotTool, id);
            return;
        }
        match self.guard.open(self.config.node_id, open, now) {
            Ok(nonce) => {
                // An open for a table interrupts a table transfer in progress; one for a schema
                // or an update leaves it alone (neither waits behind a table).
                if open.flags & (protocol::OPEN_SCHEMA | protocol::OPEN_UPDATE) == 0
                    && self.receiver.abort()
                    && let Some(incoming) = self.incoming.take()
                {
                    self.refuse(
                        incoming.source,
                        TransferStatusCode::Interrupted,
                        0,
                        incoming.nonce,
                    );
                }
                self.opened = Some(Opened {
                    nonce,
                    length: open.length,
                    flags: open.flags,
                    expires: now.wrapping_add_micros(CHALLENGE_LIFETIME_US),
                });
            }
            Err(failure) => self.unauthenticated(failure, id),
        }
    }

    /// On a node with a key, whether a transfer frame may reach the receiver: a first (or single)
    /// frame only if a TransferOpen announced its length, a consecutive frame only with the
    /// sequence number expected. Refused frames are counted, raise a fault, and never disturb a
    /// transfer in progress. Returns the open that a first frame consumes.
    /// `next`: the sequence number the receiver expects (`None` when idle); `schema`: the frame
    /// is a SchemaTransfer's, whose first frame needs an open for a schema (and a table's one for
    /// a table).
    pub(super) fn admit_keyed(
        &mut self,
        data: &[u8],
        wire: Wire,
        next: Option<u8>,
        schema: bool,
        now: Instant,
    ) -> Result<Option<Opened>, AuthFailure> {
        // By the codec of the frame's kind: a CAN FD first frame that the classic codec calls
        // malformed must still need its open.
        match wire.decode(data) {
            Ok((Pci::First { len }, _)) => self.take_open(usize::try_from(len).ok(), schema, now),
            Ok((Pci::Single { len }, _)) => self.take_open(Some(usize::from(len)), schema, now),
            Ok((Pci::Consecutive { sn }, _)) if next.is_some_and(|next| next != sn) => {
                Err(AuthFailure::Sequence)
            }
            // In sequence, flow controls and malformed frames: the receiver decides.
            _ => Ok(None),
        }
    }

    pub(super) fn take_open(
        &mut self,
        len: Option<usize>,
        schema: bool,
        now: Instant,
    ) -> Result<Option<Opened>, AuthFailure> {
        let opened = self
            .opened
            .filter(|opened| {
                opened
                    .expires
                    .micros_since(now)
                    .is_some_and(|left| left > 0)
            })
            .filter(|opened| len == Some(usize::from(opened.length)))
            // A schema's open for a schema, a table's for a table; an update's for neither
            // (one comparison: two took 10 bytes more of the NUCLEO-G474RE's flash).
            .filter(|opened| {
                opened.flags & (protocol::OPEN_SCHEMA | protocol::OPEN_UPDATE)
                    == if schema { protocol::OPEN_SCHEMA } else { 0 }
            })
            .ok_or(AuthFailure::Unopened)?;
        self.opened = None;
        Ok(Some(opened))
    }

    pub(super) fn on_transfer_frame(
        &mut self,
        id: FrameId,
        data: &[u8],
        wire: Wire,
        now: Instant,
    ) -> Step {
        let source = id.source;
        if let Some(reason) = self.guard.locked() {
            let _ = reason;
            self.unauthenticated(AuthFailure::Locked, id);
            return Step::Continue;
        }
        // Only the tool transfers tables: a participant with another source id cannot take the
        // slot (nor learn anything from the node's answers).
        if source != protocol::TOOL {
            self.unauthenticated(AuthFailure::NotTool, id);
            return Step::Continue;
        }
        if self.awaiting_store.is_some() {
            self.answer(source, TransferStatusCode::Busy, 0, None);
            return Step::Continue;
        }
        let opened = if self.guard.is_keyed() {
            match self.admit_keyed(data, wire, self.receiver.next_sequence_number(), false, now) {
                Ok(opened) => opened,
                Err(failure) => {
                    self.unauthenticated(failure, id);
                    return Step::Continue;
                }
            }
        } else {
            None
        };
        let outcome = wire.receive(&mut self.receiver, data, now);
        // A reception this frame ended (wrong sequence number, or a new First Frame that
        // interrupted it, or N_Cr passed): the sender of that reception learns why.
        let aborted = outcome.aborted;
        let event = match outcome.event {
            RxEvent::Nothing => Event::Nothing,
            RxEvent::Ignored(_) => Event::Nothing,
            RxEvent::SendFlowControl(flow_control) => Event::FlowControl(flow_control),
            RxEvent::Refused { flow_control, .. } => Event::Refused(flow_control),
            RxEvent::Complete(message) => Event::Complete(message.len()),
        };
        if let Some(error) = aborted
            && let Some(incoming) = self.incoming.take()
        {
            let status = match error {
                RxError::Timeout => TransferStatusCode::Timeout,
                RxError::WrongSequenceNumber { .. } | RxError::Interrupted => {
                    TransferStatusCode::Interrupted
                }
            };
            self.refuse(incoming.source, status, 0, incoming.nonce);
        }
        let nonce = opened.map(|opened| opened.nonce);
        let flags = opened.map_or(0, |opened| opened.flags);
        match event {
            Event::Nothing => Step::Continue,
            Event::FlowControl(flow_control) => {
                if self.incoming.is_none() {
                    let length = self.receiver.message_len().unwrap_or(0);
                    self.incoming = Some(Incoming {
                        source,
                        nonce,
                        flags,
                        deadline: transfer_deadline(now, length),
                    });
                }
                self.send_transfer(source, flow_control, wire);
                Step::Continue
            }
            Event::Refused(flow_control) => {
                if let Some(flow_control) = flow_control {
                    self.send_transfer(source, flow_control, wire);
                }
                self.incoming = None;
                self.refuse(source, TransferStatusCode::TooLarge, 0, nonce);
                Step::Continue
            }
            Event::Complete(len) => {
                // A single frame completes at once: it carries its own open.
                let (nonce, flags) = match self.incoming.take() {
                    Some(incoming) => (incoming.nonce, incoming.flags),
                    None => (nonce, flags),
                };
                match nonce {
                    Some(nonce) => self.apply_authenticated(source, len, nonce, flags, now),
                    None => self.apply(source, len, None, 0, now),
                }
            }
        }
    }

    /// A complete authenticated message: the image and its MAC. The MAC is checked first, before
    /// anything in the image is read.
    pub(super) fn apply_authenticated(
        &mut self,
        source: u8,
        len: usize,
        nonce: u64,
        flags: u8,
        now: Instant,
    ) -> Step {
        let node_id = self.config.node_id;
        let image_len = len.checked_sub(IMAGE_MAC_LEN);
        let verified = image_len.is_some_and(|image_len| {
            let buffer = self.receiver.buffer();
            match (buffer.get(..image_len), buffer.get(image_len..len)) {
                (Some(image), Some(mac)) => self.guard.image(node_id, nonce, flags, image, mac),
                _ => false,
            }
        });
        match image_len {
            Some(image_len) if verified => self.apply(source, image_len, Some(nonce), flags, now),
            _ => {
                self.refuse(source, TransferStatusCode::Unauthenticated, 0, Some(nonce));
                Step::Continue
            }
        }
    }

    /// Checks a complete image in the documented order (header, node id, CRC and loader, then
    /// version) and, if it passes, swaps it in.
    pub(super) fn apply(
        &mut self,
        source: u8,
        len: usize,
        nonce: Option<u64>,
        flags: u8,
        now: Instant,
    ) -> Step {
        // The keyed version reset: the key holder may replace any running version.
        let running = if flags & OPEN_REPLACE != 0 && nonce.is_some() {
            None
        } else {
            self.running
        };
        match self.take_image(len, running, now) {
            Ok(header) => {
                self.diagnostic.restart_round();
                self.awaiting_store = Some((source, nonce));
                info!("table version {} applied", int(header.table_version));
                Step::Store
            }
            Err((TransferStatusCode::AlreadyCurrent, detail)) => {
                self.answer(source, TransferStatusCode::AlreadyCurrent, detail, nonce);
                Step::Continue
            }
            Err((status, detail)) => {
                self.refuse(source, status, detail, nonce);
                Step::Continue
            }
        }
    }

    /// The first `len` bytes of the transfer buffer checked in the documented order (header, node
    /// id, CRC and loader, then the version rule against `running`) and, if they pass, swapped in
    /// as the running table, not yet stored; its header. Shared by [`Node::boot`] and
    /// [`Node::apply`]: their own copies of the checks and of the arbiter's swap took 966 bytes
    /// more of the NUCLEO-G474RE's flash with the schema server.
    ///
    /// So that the node holds one arbiter, not two ([`replace`]): the image is checked whole
    /// first, its table decoded and validated aside, so a refused image leaves the running
    /// arbiter as it was; then what the new table may carry over is moved out of the running
    /// arbiter and the new one is built in its place, around the decoded table. Built beside
    /// the running one, the new arbiter was the deepest stack the boards had (32 KB of the
    /// NUCLEO-G474RE's full build, docs/footprint.md).
    pub(super) fn take_image(
        &mut self,
        len: usize,
        running: Option<Running>,
        now: Instant,
    ) -> Result<Header, (TransferStatusCode, u8)> {
        let bytes = self.receiver.buffer().get(..len).unwrap_or(&[]);
        check_target(bytes, self.config.node_id)?;
        let header = match replace(&mut self.arbiter, bytes, running.as_ref()) {
            Ok(header) => header,
            Err(refused) => {
                // Refused once the build had started (it cannot be: see `swap_in`), the
                // running arbiter is gone, and so is the running table.
                if self.arbiter.is_none() {
                    self.running = None;
                }
                return Err(refused);
            }
        };
        // The schema server's set-up leaves the table only now, from its place in the node:
        // taken out before, it was one more large value in the loader's frame.
        self.start_schema(now);
        self.running = Some(Running {
            header,
            image_len: u32::try_from(len).unwrap_or(u32::MAX),
            stored: false,
        });
        Ok(header)
    }

    pub(super) fn refuse(
        &mut self,
        source: u8,
        status: TransferStatusCode,
        detail: u8,
        nonce: Option<u64>,
    ) {
        warn!("table transfer refused: {}", code(status, status.code()));
        self.answer(source, status, detail, nonce);
        self.raise(FaultCode::TableRefused, [status.code(), detail, 0, 0, 0]);
    }

    /// Sends the TransferStatus and, for an opened transfer (`nonce`), its Receipt. Out of line:
    /// two of its four callers had inlined it.
    #[inline(never)]
    pub(super) fn answer(
        &mut self,
        source: u8,
        status: TransferStatusCode,
        detail: u8,
        nonce: Option<u64>,
    ) {
        let running_version = self
            .running
            .map_or(0, |running| running.header.table_version);
        let Some(frame) = Message::TransferStatus(TransferStatus {
            status,
            detail,
            running_version,
        })
        .report_frame(self.config.node_id, source) else {
            return;
        };
        self.queue(frame);
        if let Some(nonce) = nonce {
            // The Receipt is over the bytes of the TransferStatus just queued.
            let mut payload = [0u8; 8];
            for (slot, byte) in payload.iter_mut().zip(frame.payload()) {
                *slot = *byte;
            }
            let crc = self.running.map_or(0, |running| running.header.crc);
            let stored = self.running.is_some_and(|running| running.stored);
            let tag = self
                .guard
                .receipt(self.config.node_id, nonce, &payload, crc, stored);
            self.send(Message::Receipt { tag }, source);
        }
    }

    /// A flow control to `destination`, in the kind of frame its transfer came in (`wire`).
    #[inline(never)]
    pub(super) fn send_transfer(&mut self, destination: u8, data: [u8; 8], wire: Wire) {
        #[cfg(feature = "fd")]
        {
            let message = Message::TableTransfer { data, len: 8 };
            if let Some(frame) = message.report_frame(self.config.node_id, destination) {
                self.queue(wire.answer(frame));
            }
        }
        #[cfg(not(feature = "fd"))]
        {
            let _ = wire;
            self.send(Message::TableTransfer { data, len: 8 }, destination);
        }
    }
}

/// The header checks a node makes before loading: a readable header, for this node.
pub(super) fn check_target(bytes: &[u8], node_id: u8) -> Result<(), (TransferStatusCode, u8)> {
    let header = image::read_header_as::<Refused>(bytes).map_err(|error| status_of(&error))?;
    if header.node_id != node_id {
        return Err((TransferStatusCode::WrongNode, header.node_id));
    }
    Ok(())
}

/// The version rule: only a newer table replaces the running one; the very same table is
/// `AlreadyCurrent` (nothing to do).
pub(super) fn check_version(
    header: &Header,
    running: Option<&Running>,
) -> Result<(), (TransferStatusCode, u8)> {
    if let Some(running) = running {
        let current = running.header;
        if header.table_version == current.table_version && header.crc == current.crc {
            return Err((TransferStatusCode::AlreadyCurrent, 0));
        }
    }
    // No table counts as version 0, as the heartbeat reports it: a table of version 0 is never
    // newer, so none ever runs and "version 0" on the bus always means "no table".
    let current_version = running.map_or(0, |running| running.header.table_version);
    if header.table_version <= current_version {
        return Err((TransferStatusCode::OlderVersion, 0));
    }
    Ok(())
}

/// The image `bytes` checked (header, CRC, the table decoded and validated by the loader, then
/// the version rule against `running`) and, if it passes, its arbiter built in `place`
/// ([`swap_in`]); its header. Out of line: its frame holds the decoded table (a table of the
/// node's capacities, 11 KB on the boards' full build), which the schema server's start after
/// it ([`Node::take_image`]) need not stand on.
#[inline(never)]
pub(super) fn replace<const P: usize, const C: usize, const N: usize>(
    place: &mut Option<Arbiter<P, C, N>>,
    bytes: &[u8],
    running: Option<&Running>,
) -> Result<Header, (TransferStatusCode, u8)> {
    let mut table = pab_core::Table::<P, C, N>::new();
    let header = pab_core::image::load_into_as::<P, C, N, Refused>(bytes, &mut table)
        .map_err(|error| status_of(&error))?;
    check_version(&header, running)?;
    swap_in(place, &mut table)?;
    Ok(header)
}

/// The arbiter of `table` (decoded and validated by the loader), built in `place` where the
/// running one was, with what it carries over from that one ([`Arbiter::carry_over_from`]); the
/// table is moved into it (`table` is left empty). The running arbiter is gone once the build
/// starts: a validated table cannot be refused here (were it, the node would be left without a
/// table, and say why). Out of line: its frame holds what is carried over (5.2 KB on the boards).
#[inline(never)]
pub(super) fn swap_in<const P: usize, const C: usize, const N: usize>(
    place: &mut Option<Arbiter<P, C, N>>,
    table: &mut pab_core::Table<P, C, N>,
) -> Result<(), (TransferStatusCode, u8)> {
    let mut carried = pab_core::arbiter::Carried::default();
    let replaces = place.is_some();
    if let Some(running) = place.as_mut() {
        running.take_carried(&mut carried);
    }
    let built = Arbiter::new_in::<Refused, (), core::convert::Infallible>(place, |blank| {
        core::mem::swap(blank, table);
        Ok(())
    });
    let Ok(Ok(((), arbiter))) = built else {
        return Err((TransferStatusCode::InvalidTable, 0));
    };
    // The connections the new table leaves unchanged go on where they are (a re-push of the
    // same rules is no blackout); the others start at S = 0. At boot there is none.
    if replaces {
        arbiter.carry_over_from(&carried);
    }
    Ok(())
}

/// The transfer status (and detail byte) a loader error maps to.
// Out of line: the loader and the header check before it both map errors with it, and the
// inlined copies took 36 bytes more of the NUCLEO-G474RE's flash with competitive dynamics, 44
// without.
#[inline(never)]
pub fn status_of<T>(error: &LoadError<T>) -> (TransferStatusCode, u8) {
    match error {
        LoadError::Crc { .. } => (TransferStatusCode::CrcMismatch, 0),
        LoadError::Truncated { .. } => (TransferStatusCode::BadHeader, 1),
        LoadError::TrailingBytes { .. } => (TransferStatusCode::BadHeader, 2),
        LoadError::BadMagic => (TransferStatusCode::BadHeader, 3),
        LoadError::UnsupportedFormat { .. } => (TransferStatusCode::BadHeader, 4),
        LoadError::ReservedByte => (TransferStatusCode::BadHeader, 5),
        LoadError::TooLarge { .. } => (TransferStatusCode::TooLarge, 0),
        LoadError::Body(_) => (TransferStatusCode::InvalidTable, 1),
        LoadError::BodyTrailingBytes => (TransferStatusCode::InvalidTable, 2),
        LoadError::Table(_) => (TransferStatusCode::InvalidTable, 3),
        LoadError::ExceedsCapacity { .. } => (TransferStatusCode::InvalidTable, 4),
    }
}
