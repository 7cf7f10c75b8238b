//! The node, as a state machine without I/O: frames and the time go in, frames to send and the
//! image to store come out. The async runner ([`crate::run`]) and the tests drive the same code.
//!
//! Why sans-I/O: the board, the Linux process and the in-process tests differ only in how frames
//! and time arrive. Keeping every decision here makes the tests exercise exactly what the boards
//! run, with virtual time and byte-exact frames.

use heapless::Deque;
use pab_core::Consumer as PortConsumer;
use pab_core::image::{self, Header, LoadError};
use pab_core::isotp::{self, RxError, RxEvent};
use pab_core::protocol::{
    self, Errors, FaultCode, FrameId, Heartbeat, Message, NodeState, STORE_UNREADABLE, Service,
    StoreFailure, TableStatus, Traffic, TransferStatus, TransferStatusCode,
};
use pab_core::{Arbiter, Frame, Instant, PortVerdict};
use pab_storage::StoreError;

use crate::bus::BusError;
use crate::diagnostic::DiagnosticStream;
use crate::faults::FaultLimiter;
use crate::{Config, Consumer};

/// Frames waiting to be sent. Heartbeat groups (4 frames), faults and transfer answers fit with
/// room to spare; the diagnostic stream only fills what is left.
pub const OUTBOX_LEN: usize = 16;
/// Room the diagnostic stream leaves free in the outbox for everything else.
const DIAGNOSTIC_RESERVE: usize = 6;

/// What the runner must do after [`Node::on_frame`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Step {
    /// Nothing beyond sending the outbox.
    Continue,
    /// A new table is running: store [`Node::image_to_store`], then call [`Node::stored`].
    Store,
}

/// The running table's identity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Running {
    /// The image header.
    pub header: Header,
    /// Image length in bytes.
    pub image_len: u32,
    /// Whether the node will boot with it.
    pub stored: bool,
}

/// Counters since boot, wrapping.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Frames read from the bus.
    pub received: u32,
    /// Deliveries to ports.
    pub delivered: u32,
    /// Frames that fed a port and were delivered to none.
    pub discarded: u32,
    /// Bus errors, overruns, malformed frames addressed to us, dropped outgoing frames; each
    /// frame the driver counted as lost before it was read ([`BusError::Dropped`]) counts one.
    pub errors: u32,
    /// Frames the driver counted as lost before they were read, saturating: the
    /// [`FaultCode::RxOverrun`] detail (bytes 0-3, little endian).
    pub lost: u32,
}

/// What a transfer frame asks of the node, detached from the receiver's borrow.
enum Event {
    Nothing,
    FlowControl([u8; 8]),
    Refused(Option<[u8; 8]>),
    Complete(usize),
}

/// A transfer in progress.
#[derive(Clone, Copy, Debug)]
struct Incoming {
    source: u8,
}

/// A node: its table, its arbiter, its protocol state.
///
/// Capacities: `P` ports, `C` connections, `N` decision nodes (see [`pab_core::Table`]) and
/// `IMG`, the largest image it accepts (its receive buffer). Memory is
/// `size_of::<Node<P, C, N, IMG>>()`, dominated by the arbiter and the `IMG`-byte buffer.
pub struct Node<const P: usize, const C: usize, const N: usize, const IMG: usize> {
    config: Config,
    booted: Instant,
    arbiter: Option<Arbiter<P, C, N>>,
    running: Option<Running>,
    store_failed: bool,
    bus_trouble: bool,
    /// Why the node booted without a table, if its store held one it could not take: the
    /// BadStoredTable detail, repeated with every heartbeat group until a table runs.
    boot_fault: Option<[u8; 5]>,
    receiver: isotp::Receiver<IMG>,
    incoming: Option<Incoming>,
    /// The answer owed once the runner has stored the image: (source, outcome).
    awaiting_store: Option<u8>,
    counters: Counters,
    next_heartbeat: Instant,
    diagnostic: DiagnosticStream,
    faults: FaultLimiter,
    outbox: Deque<Frame, OUTBOX_LEN>,
}

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// A node without a table, booted at `now`. Its first heartbeat goes out at once.
    pub fn new(config: Config, now: Instant) -> Self {
        Node {
            receiver: isotp::Receiver::new(config.isotp),
            config,
            booted: now,
            arbiter: None,
            running: None,
            store_failed: false,
            bus_trouble: false,
            boot_fault: None,
            incoming: None,
            awaiting_store: None,
            counters: Counters::default(),
            next_heartbeat: now,
            diagnostic: DiagnosticStream::default(),
            faults: FaultLimiter::new(config.fault_interval_us),
            outbox: Deque::new(),
        }
    }

    /// The buffer to read a stored image into at boot (the transfer buffer, idle at boot), so the
    /// node needs no second `IMG`-byte buffer. Pass the bytes read to [`Node::boot`].
    pub fn boot_buffer(&mut self) -> &mut [u8] {
        // At boot no transfer is in progress; if one were, the empty slice reads as "no room".
        self.receiver.buffer_mut().unwrap_or(&mut [])
    }

    /// Starts with the image found in storage: its first `len` bytes of [`Node::boot_buffer`]
    /// (`None`: storage was empty; a store that could not be read: [`Node::boot_unreadable`]).
    /// The image passes the checks a pushed one passes (header, node id, CRC, loader); one that
    /// fails them leaves the node without a table and raises [`FaultCode::BadStoredTable`] with the
    /// status and detail a transfer of it would get (an image for another node: `WrongNode`,
    /// detail the image's node id), repeated after every heartbeat group until a table runs.
    pub fn boot(&mut self, stored_len: Option<usize>, now: Instant) {
        let Some(len) = stored_len else {
            info!("no stored table");
            return;
        };
        let node_id = self.config.node_id;
        let bytes = self.receiver.buffer().get(..len).unwrap_or(&[]);
        let verdict = check_target(bytes, node_id)
            .and_then(|()| load::<P, C, N>(bytes))
            .and_then(|(header, arbiter)| check_version(&header, None).map(|()| (header, arbiter)));
        match verdict {
            Ok((header, arbiter)) => {
                info!("booted with stored table version {}", header.table_version);
                self.arbiter = Some(arbiter);
                self.running = Some(Running {
                    header,
                    image_len: u32::try_from(len).unwrap_or(u32::MAX),
                    stored: true,
                });
            }
            Err((TransferStatusCode::WrongNode, image_node)) => {
                warn!(
                    "stored table refused: the image is for node {}, this node is {}; starting without a table",
                    image_node, node_id
                );
                self.boot_fault = Some([TransferStatusCode::WrongNode.code(), image_node, 0, 0, 0]);
            }
            Err((status, detail)) => {
                warn!(
                    "stored table refused: {:?} (detail {}); starting without a table",
                    status, detail
                );
                self.boot_fault = Some([status.code(), detail, 0, 0, 0]);
            }
        }
        // The first heartbeat group goes out now, and the fault (if any) with it.
        self.poll(now);
    }

    /// Starts without a table because the store could not be read (`error`): raises
    /// [`FaultCode::BadStoredTable`] with detail [`STORE_UNREADABLE`] and the [`StoreFailure`],
    /// repeated after every heartbeat group until a table runs.
    pub fn boot_unreadable(&mut self, error: StoreError, now: Instant) {
        warn!(
            "the stored table could not be read ({:?}); starting without a table",
            error
        );
        let failure = match error {
            StoreError::Flash(_) => StoreFailure::Read,
            StoreError::BufferTooSmall { .. } | StoreError::ImageTooLarge { .. } => {
                StoreFailure::TooLarge
            }
            StoreError::Corrupt => StoreFailure::Corrupt,
            StoreError::Layout(_) | StoreError::SequenceExhausted | StoreError::VerifyFailed => {
                StoreFailure::Other
            }
        };
        self.boot_fault = Some([STORE_UNREADABLE, failure.code(), 0, 0, 0]);
        self.poll(now);
    }

    /// Handles one frame read from the bus at `now`: arbitrates it, or handles it as a frame of
    /// our protocol. Delivered frames go to `consumer` (and are re-published where the table says
    /// so); a consumer that observes verdicts ([`Consumer::OBSERVES_VERDICTS`]) sees each one
    /// first. Protocol frames are never arbitrated.
    pub fn on_frame(&mut self, frame: &Frame, now: Instant, consumer: &mut impl Consumer) -> Step {
        self.counters.received = self.counters.received.wrapping_add(1);
        let step = if protocol::is_ours(&frame.id()) {
            self.on_protocol_frame(frame, now)
        } else {
            self.arbitrate(frame, now, consumer);
            Step::Continue
        };
        self.poll(now);
        step
    }

    /// Reports a bus error the driver saw. Frames lost before they were read raise
    /// [`FaultCode::RxOverrun`] with the frames lost since boot as counted (saturating u32, little
    /// endian, detail bytes 0-3; 0 from a driver that cannot count): a total rather than the
    /// latest loss, so that the rate-limited fault frames, which carry only the latest detail,
    /// never lose count.
    pub fn on_bus_error(&mut self, error: BusError, now: Instant) {
        let occurrences = match error {
            BusError::Dropped(lost) => {
                self.counters.lost = self.counters.lost.saturating_add(lost);
                lost
            }
            _ => 1,
        };
        self.counters.errors = self.counters.errors.wrapping_add(occurrences);
        let (code, detail) = match error {
            BusError::Overrun | BusError::Dropped(_) => {
                let [a, b, c, d] = self.counters.lost.to_le_bytes();
                (FaultCode::RxOverrun, [a, b, c, d, 0])
            }
            BusError::BusOff => {
                self.bus_trouble = true;
                (FaultCode::BusOff, [1, 0, 0, 0, 0])
            }
            BusError::ErrorPassive => {
                self.bus_trouble = true;
                (FaultCode::BusOff, [0; 5])
            }
            BusError::Recovered => {
                self.bus_trouble = false;
                return;
            }
            BusError::Other(kind) => (FaultCode::BusError, [kind, 0, 0, 0, 0]),
        };
        self.raise(code, detail);
        self.poll(now);
    }

    /// Reports a frame that could not be sent (the bus is congested or the controller is off).
    pub fn on_transmit_error(&mut self, now: Instant) {
        self.counters.errors = self.counters.errors.wrapping_add(1);
        self.raise(FaultCode::TxOverrun, [0; 5]);
        self.poll(now);
    }

    /// The image to store after [`Step::Store`]: the one now running.
    pub fn image_to_store(&self) -> &[u8] {
        let len = self.running.map_or(0, |running| running.image_len);
        let len = usize::try_from(len).unwrap_or(0);
        self.receiver.buffer().get(..len).unwrap_or(&[])
    }

    /// Reports the outcome of storing [`Node::image_to_store`]; answers the transfer.
    pub fn stored(&mut self, ok: bool, now: Instant) {
        if let Some(running) = self.running.as_mut() {
            running.stored = ok;
        }
        self.store_failed = !ok;
        let status = if ok {
            TransferStatusCode::Applied
        } else {
            self.raise(FaultCode::StoreFailed, [0; 5]);
            TransferStatusCode::AppliedNotStored
        };
        if let Some(source) = self.awaiting_store.take() {
            self.answer(source, status, 0);
        }
        self.poll(now);
    }

    /// Emits what is due at `now` (heartbeat, faults, diagnostic samples) and handles transfer
    /// timeouts. Call it whenever [`Node::deadline`] passes; [`Node::on_frame`] calls it too.
    ///
    /// Cost: each duty first checks, in a comparison or two, whether it has anything to do (a
    /// transfer in progress, the heartbeat's instant, a fault pending, the diagnostic stream on),
    /// so that the poll of a frame, which usually finds nothing due, costs a few instructions.
    #[inline]
    pub fn poll(&mut self, now: Instant) {
        if self.receiver.poll(now).is_some() {
            self.transfer_timed_out();
        }
        if now.micros_since(self.next_heartbeat).is_some() {
            self.heartbeat_due(now);
        }
        if self.faults.has_pending() {
            self.send_faults(now);
        }
        if self.diagnostic.is_on() {
            self.send_samples(now);
        }
    }

    /// The reception of a transfer timed out: its sender learns why.
    #[inline(never)]
    fn transfer_timed_out(&mut self) {
        if let Some(incoming) = self.incoming.take() {
            warn!("table transfer from {} timed out", incoming.source);
            self.refuse(incoming.source, TransferStatusCode::Timeout, 0);
        }
    }

    /// The heartbeat group, and the next one's instant.
    #[inline(never)]
    fn heartbeat_due(&mut self, now: Instant) {
        self.heartbeat(now);
        let next = self
            .next_heartbeat
            .wrapping_add_micros(self.config.heartbeat_period_us);
        // After a long stall, resume from now instead of sending a burst of heartbeats.
        self.next_heartbeat = match next.micros_since(now) {
            Some(_) => next,
            None => now.wrapping_add_micros(self.config.heartbeat_period_us),
        };
    }

    /// The faults due at `now`, as the outbox has room.
    #[inline(never)]
    fn send_faults(&mut self, now: Instant) {
        while self.outbox.len() < OUTBOX_LEN {
            let Some(fault) = self.faults.next_due(now) else {
                break;
            };
            self.send(Message::Fault(fault), protocol::BROADCAST);
        }
    }

    /// The diagnostic samples due at `now`, as the outbox has room beyond what it keeps for
    /// everything else.
    #[inline(never)]
    fn send_samples(&mut self, now: Instant) {
        if let Some(arbiter) = self.arbiter.as_ref() {
            while self.outbox.len() + DIAGNOSTIC_RESERVE < OUTBOX_LEN {
                let Some(sample) = self.diagnostic.next_sample(arbiter, now) else {
                    break;
                };
                let frame =
                    Message::Diagnostic(sample).to_frame(self.config.node_id, protocol::BROADCAST);
                if self.outbox.push_back(frame).is_err() {
                    break;
                }
            }
        }
    }

    /// The latest instant by which [`Node::poll`] must run again.
    pub fn deadline(&self, now: Instant) -> Instant {
        let mut deadline = self.next_heartbeat;
        let candidates = [
            self.receiver.deadline(),
            self.faults.deadline(),
            self.arbiter
                .as_ref()
                .and_then(|_| self.diagnostic.deadline(now)),
        ];
        for candidate in candidates.into_iter().flatten() {
            if candidate.micros_since(deadline).is_none() {
                deadline = candidate;
            }
        }
        deadline
    }

    /// The next frame to send, oldest first.
    pub fn next_outgoing(&mut self) -> Option<Frame> {
        self.outbox.pop_front()
    }

    /// The node's state, as its heartbeat reports it.
    pub fn state(&self) -> NodeState {
        if self.arbiter.is_none() {
            NodeState::NoTable
        } else if self.store_failed || self.bus_trouble {
            NodeState::Fault
        } else {
            NodeState::Operational
        }
    }

    /// The running table, if any.
    pub fn running(&self) -> Option<Running> {
        self.running
    }

    /// The arbiter, if a table is running (read-only: for inspection and tests).
    pub fn arbiter(&self) -> Option<&Arbiter<P, C, N>> {
        self.arbiter.as_ref()
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// The node's configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    fn arbitrate<K: Consumer>(&mut self, frame: &Frame, now: Instant, consumer: &mut K) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        // Two calls, so that a consumer that does not observe (`OBSERVES_VERDICTS` is a
        // constant) runs exactly the plain arbitration: the other branch is compiled out.
        let reception = if K::OBSERVES_VERDICTS {
            // A frame feeds each port at most once: P entries always suffice.
            let mut verdicts: heapless::Vec<PortVerdict, P> = heapless::Vec::new();
            let reception = arbiter.receive(&frame.id(), now, |verdict| {
                let _ = verdicts.push(*verdict);
            });
            for verdict in &verdicts {
                consumer.verdict(frame, now, verdict, arbiter);
            }
            reception
        } else {
            arbiter.receive(&frame.id(), now, |_| {})
        };
        if reception.fed.is_empty() {
            return;
        }
        if reception.delivered.is_empty() {
            self.counters.discarded = self.counters.discarded.wrapping_add(1);
            return;
        }
        // The ports it was delivered to, in increasing order (usually one).
        let mut ports = reception.delivered.bits();
        while ports != 0 {
            self.deliver(ports.trailing_zeros() as u8, frame, now, consumer);
            ports &= ports - 1;
        }
    }

    /// Hands `frame`, delivered at `port`, to the consumer, and queues its re-publication if the
    /// port is a gateway. Out of line: the loop over the delivered ports then keeps nothing of
    /// the node in registers across it.
    #[inline(never)]
    fn deliver<K: Consumer>(&mut self, port: u8, frame: &Frame, now: Instant, consumer: &mut K) {
        self.counters.delivered = self.counters.delivered.wrapping_add(1);
        consumer.deliver(port, frame, now);
        let republish = self
            .arbiter
            .as_ref()
            .and_then(|arbiter| arbiter.table().consumer(usize::from(port)));
        if let Some(PortConsumer::Republish(output)) = republish
            && self
                .outbox
                .push_back(frame.republished(output.id()))
                .is_err()
        {
            self.counters.errors = self.counters.errors.wrapping_add(1);
            self.faults.raise(FaultCode::TxOverrun, [1, 0, 0, 0, 0]);
        }
    }

    fn on_protocol_frame(&mut self, frame: &Frame, now: Instant) -> Step {
        let node_id = self.config.node_id;
        let (id, message) = match Message::decode(frame) {
            Ok(decoded) => decoded,
            Err(_) => {
                // Count malformed frames addressed to us; other nodes' business is not ours.
                let addressed = FrameId::decode(&frame.id()).is_some_and(|id| id.is_for(node_id));
                if addressed {
                    self.counters.errors = self.counters.errors.wrapping_add(1);
                    let service = FrameId::decode(&frame.id()).map_or(0, |id| id.service.code());
                    self.raise(FaultCode::BadCommand, [service, 0, 0, 0, 0]);
                }
                return Step::Continue;
            }
        };
        if !id.is_for(node_id) || id.source == node_id {
            return Step::Continue;
        }
        match message {
            Message::DiagnosticControl(control) => {
                self.diagnostic.configure(control, now);
                info!("diagnostic stream at {} Hz", control.rate_hz);
                Step::Continue
            }
            // Transfers are point to point: a broadcast transfer would make every node answer
            // flow control at once.
            Message::TableTransfer { data, len } if id.destination == node_id => {
                let data = data.get(..usize::from(len)).unwrap_or(&data);
                self.on_transfer_frame(id.source, data, now)
            }
            _ => Step::Continue,
        }
    }

    fn on_transfer_frame(&mut self, source: u8, data: &[u8], now: Instant) -> Step {
        if let Some(incoming) = self.incoming
            && incoming.source != source
        {
            // One transfer at a time; the other sender learns why.
            self.answer(source, TransferStatusCode::Busy, 0);
            return Step::Continue;
        }
        if self.awaiting_store.is_some() {
            self.answer(source, TransferStatusCode::Busy, 0);
            return Step::Continue;
        }
        let outcome = self.receiver.on_frame(data, now);
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
            self.refuse(incoming.source, status, 0);
        }
        match event {
            Event::Nothing => Step::Continue,
            Event::FlowControl(flow_control) => {
                self.incoming = Some(Incoming { source });
                self.send_transfer(source, flow_control);
                Step::Continue
            }
            Event::Refused(flow_control) => {
                if let Some(flow_control) = flow_control {
                    self.send_transfer(source, flow_control);
                }
                self.incoming = None;
                self.refuse(source, TransferStatusCode::TooLarge, 0);
                Step::Continue
            }
            Event::Complete(len) => {
                self.incoming = None;
                self.apply(source, len)
            }
        }
    }

    /// Checks a complete image in the documented order (header, node id, CRC and loader, then
    /// version) and, if it passes, swaps it in.
    fn apply(&mut self, source: u8, len: usize) -> Step {
        let bytes = self.receiver.buffer().get(..len).unwrap_or(&[]);
        let verdict = check_target(bytes, self.config.node_id)
            .and_then(|()| load::<P, C, N>(bytes))
            .and_then(|(header, arbiter)| {
                check_version(&header, self.running.as_ref()).map(|()| (header, arbiter))
            });
        match verdict {
            Ok((header, arbiter)) => {
                // The swap: one assignment. The old arbiter ran every frame until here.
                self.arbiter = Some(arbiter);
                self.running = Some(Running {
                    header,
                    image_len: u32::try_from(len).unwrap_or(u32::MAX),
                    stored: false,
                });
                self.diagnostic.restart_round();
                self.awaiting_store = Some(source);
                info!("table version {} applied", header.table_version);
                Step::Store
            }
            Err((TransferStatusCode::AlreadyCurrent, detail)) => {
                self.answer(source, TransferStatusCode::AlreadyCurrent, detail);
                Step::Continue
            }
            Err((status, detail)) => {
                self.refuse(source, status, detail);
                Step::Continue
            }
        }
    }

    fn refuse(&mut self, source: u8, status: TransferStatusCode, detail: u8) {
        warn!("table transfer refused: {:?}", status);
        self.answer(source, status, detail);
        self.raise(FaultCode::TableRefused, [status.code(), detail, 0, 0, 0]);
    }

    fn answer(&mut self, source: u8, status: TransferStatusCode, detail: u8) {
        let running_version = self
            .running
            .map_or(0, |running| running.header.table_version);
        self.send(
            Message::TransferStatus(TransferStatus {
                status,
                detail,
                running_version,
            }),
            source,
        );
    }

    fn send_transfer(&mut self, destination: u8, data: [u8; 8]) {
        self.send(Message::TableTransfer { data, len: 8 }, destination);
    }

    fn heartbeat(&mut self, now: Instant) {
        let uptime_s = now.micros_since(self.booted).map_or(0, |micros| {
            u32::try_from(micros / 1_000_000).unwrap_or(u32::MAX)
        });
        let running = self.running;
        let state = self.state();
        let diagnostic = self.diagnostic.is_on();
        self.send(
            Message::Heartbeat(Heartbeat {
                state,
                uptime_s,
                table_version: running.map_or(0, |r| r.header.table_version),
            }),
            protocol::BROADCAST,
        );
        self.send(
            Message::TableStatus(TableStatus {
                crc: running.map_or(0, |r| r.header.crc),
                image_len: running.map_or(0, |r| u16::try_from(r.image_len).unwrap_or(u16::MAX)),
                ports: self
                    .arbiter
                    .as_ref()
                    .map_or(0, |a| u8::try_from(a.port_count()).unwrap_or(u8::MAX)),
                stored: running.is_some_and(|r| r.stored),
                diagnostic,
            }),
            protocol::BROADCAST,
        );
        let counters = self.counters;
        self.send(
            Message::Traffic(Traffic {
                received: counters.received,
                delivered: counters.delivered,
            }),
            protocol::BROADCAST,
        );
        self.send(
            Message::Errors(Errors {
                discarded: counters.discarded,
                errors: counters.errors,
            }),
            protocol::BROADCAST,
        );
        if self.arbiter.is_none()
            && let Some(detail) = self.boot_fault
        {
            self.raise(FaultCode::BadStoredTable, detail);
        }
    }

    fn send(&mut self, message: Message, destination: u8) {
        let frame = message.to_frame(self.config.node_id, destination);
        if self.outbox.push_back(frame).is_err() {
            // Make room for protocol traffic by dropping the oldest diagnostic sample, if any.
            let diagnostic = FrameId::new(
                Service::Diagnostic,
                self.config.node_id,
                protocol::BROADCAST,
            )
            .id();
            let position = self
                .outbox
                .iter()
                .position(|queued| queued.id() == diagnostic);
            if position.is_some() {
                let mut kept: Deque<Frame, OUTBOX_LEN> = Deque::new();
                let mut dropped = false;
                while let Some(queued) = self.outbox.pop_front() {
                    if !dropped && queued.id() == diagnostic {
                        dropped = true;
                    } else {
                        let _ = kept.push_back(queued);
                    }
                }
                self.outbox = kept;
                let _ = self.outbox.push_back(frame);
            } else {
                self.counters.errors = self.counters.errors.wrapping_add(1);
                self.faults.raise(FaultCode::TxOverrun, [0; 5]);
            }
        }
    }

    fn raise(&mut self, code: FaultCode, detail: [u8; 5]) {
        self.faults.raise(code, detail);
    }
}

/// The header checks a node makes before loading: a readable header, for this node.
fn check_target(bytes: &[u8], node_id: u8) -> Result<(), (TransferStatusCode, u8)> {
    let header = image::read_header(bytes).map_err(|error| status_of(&error))?;
    if header.node_id != node_id {
        return Err((TransferStatusCode::WrongNode, header.node_id));
    }
    Ok(())
}

/// The version rule: only a newer table replaces the running one; the very same table is
/// `AlreadyCurrent` (nothing to do).
fn check_version(
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

/// Loads and validates an image for this node's capacities, and builds its arbiter.
fn load<const P: usize, const C: usize, const N: usize>(
    bytes: &[u8],
) -> Result<(Header, Arbiter<P, C, N>), (TransferStatusCode, u8)> {
    let loaded = image::load::<P, C, N>(bytes).map_err(|error| status_of(&error))?;
    let arbiter = Arbiter::new(loaded.table).map_err(|_| (TransferStatusCode::InvalidTable, 0))?;
    Ok((loaded.header, arbiter))
}

/// The transfer status (and detail byte) a loader error maps to.
pub fn status_of(error: &LoadError) -> (TransferStatusCode, u8) {
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
