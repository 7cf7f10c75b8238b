//! The node, as a state machine without I/O: frames and the time go in, frames to send and the
//! image to store come out. The async runner ([`crate::run`]) and the tests drive the same code.
//!
//! Why sans-I/O: the board, the Linux process and the in-process tests differ only in how frames
//! and time arrive. Keeping every decision here makes the tests exercise exactly what the boards
//! run, with virtual time and byte-exact frames.

use pab_core::Consumer;
#[cfg(feature = "dynamics")]
use pab_core::GatesLost;
use pab_core::auth::{IMAGE_MAC_LEN, Key};
use pab_core::ble::{self, BleError, Claim};
#[cfg(feature = "dynamics")]
use pab_core::dynamics;
use pab_core::hbba::filters::CommandError;
use pab_core::image::{self, Header, LoadError};
use pab_core::isotp::{self, Pci, RxError, RxEvent};
use pab_core::protocol::{
    self, AuthFailure, Errors, Exploitation, FaultCode, FilterStatus, FrameId, FrameKind,
    Heartbeat, Message, NodeState, OPEN_REPLACE, STORE_UNREADABLE, Service, StoreFailure,
    TableStatus, Traffic, TransferOpen, TransferStatus, TransferStatusCode,
};
use pab_core::{Arbiter, Combined, Frame, Instant, MAX_VALUE_PORTS, PortVerdict, Refused};
use pab_storage::StoreError;

use crate::auth::{CHALLENGE_LIFETIME_US, Guard};
use crate::bus::BusError;
use crate::diagnostic::DiagnosticStream;
use crate::faults::FaultLimiter;
use crate::fmt::int;
use crate::{Config, Recipient};

/// Frames waiting to be sent. Heartbeat groups (4 frames), faults and transfer answers fit with
/// room to spare; the diagnostic stream only fills what is left.
///
/// The outbox sends in identifier order, as the bus would arbitrate them: the frame with the
/// lowest [`Frame::arbitration_rank`] first, and frames with the same identifier in the order
/// they were queued (a diagnostic round, ISO-TP flow control). A gateway's re-publication or a
/// fault thus never waits behind the diagnostic stream queued before it.
pub const OUTBOX_LEN: usize = 16;
/// Room the diagnostic stream leaves free in the outbox for everything else.
const DIAGNOSTIC_RESERVE: usize = 6;

/// No connection reported delivering yet, at any port. A constant rather than a repeat
/// expression in [`Node::new`], which wrote it on the stack tag by tag and then copied it.
const NOTHING_EXPLOITED: [Option<u8>; pab_core::MAX_PORTS] = [None; pab_core::MAX_PORTS];

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
    /// The challenge of the TransferOpen that announced it (a node with a key); `None` on a node
    /// without one.
    nonce: Option<u64>,
    /// The TransferOpen's flags.
    flags: u8,
    /// The transfer must be complete by then, however steadily its frames come
    /// ([`transfer_deadline`]).
    deadline: Instant,
}

/// A valid TransferOpen waiting for its first frame.
#[derive(Clone, Copy, Debug)]
struct Opened {
    nonce: u64,
    length: u16,
    flags: u8,
    expires: Instant,
}

/// A transfer's whole time budget: 1 s plus 10 ms per consecutive frame its length needs. The
/// tool sends a block of 8 frames per flow control, so it needs a fraction of that; a sender that
/// trickles one frame per N_Cr (which once held an 8 KiB slot for 19 minutes) loses the slot.
pub const TRANSFER_BASE_US: u64 = 1_000_000;
/// See [`TRANSFER_BASE_US`].
pub const TRANSFER_PER_FRAME_US: u64 = 10_000;

pub(crate) fn transfer_deadline(start: Instant, length: usize) -> Instant {
    let frames = u64::try_from(length.saturating_sub(6).div_ceil(7)).unwrap_or(u64::MAX);
    start.wrapping_add_micros(
        TRANSFER_BASE_US.saturating_add(frames.saturating_mul(TRANSFER_PER_FRAME_US)),
    )
}

/// A node: its table, its arbiter, its protocol state.
///
/// Capacities: `P` ports, `C` connections, `N` decision nodes (see [`pab_core::Table`]) and
/// `IMG`, the largest image it accepts (its receive buffer). Memory is
/// `size_of::<Node<P, C, N, IMG>>()`, dominated by the arbiter and the `IMG`-byte buffer.
// In declaration order (`repr(C)`): the small state that code all over the node reads and writes
// first, at offsets a load or store encodes in itself, and the large parts (arbiter, transfer
// buffer, schema server) last. Laid out by the compiler, the large parts came first and nearly
// every access to a counter, the configuration or the outbox took an instruction more to form
// its offset (400 bytes of the NUCLEO-G474RE's flash with the schema server, and 8 to 18
// instructions of a node's frame).
#[repr(C)]
pub struct Node<const P: usize, const C: usize, const N: usize, const IMG: usize> {
    faults: FaultLimiter,
    config: Config,
    counters: Counters,
    next_heartbeat: Instant,
    booted: Instant,
    /// Kept sorted by rank, highest first, equal ranks newest first: the next frame to send
    /// is the last one ([`Node::next_outgoing`] pops it).
    outbox: heapless::Vec<Frame, OUTBOX_LEN>,
    running: Option<Running>,
    store_failed: bool,
    bus_trouble: bool,
    /// `schema` is `Some`. Tested at every frame: read from `schema` itself, past the large
    /// parts, it cost a node with the server compiled in (running or not) 15 instructions more
    /// a frame (the offset's forming, and the registers kept for it), and 68 bytes of flash.
    #[cfg(feature = "schema")]
    schema_on: bool,
    /// Why the node booted without a table, if its store held one it could not take: the
    /// BadStoredTable detail, repeated with every heartbeat group until a table runs.
    boot_fault: Option<[u8; 5]>,
    incoming: Option<Incoming>,
    /// A TransferOpen that verified, waiting for its first frame.
    opened: Option<Opened>,
    /// The answer owed once the runner has stored the image: its source and, on a node with a
    /// key, the nonce its Receipt is over.
    awaiting_store: Option<(u8, Option<u64>)>,
    /// When the image awaiting its save may be stored (`None`: no save waits for its turn).
    store_due: Option<Instant>,
    /// When the last save was handed to the runner ([`Step::Store`]).
    last_store: Option<Instant>,
    diagnostic: DiagnosticStream,
    /// HBBA: the sequence number of the last filter command applied (0 since boot), and per port
    /// the connection last reported delivering (exploitation edges), on a table with filters.
    filter_sequence: u16,
    exploited: [Option<u8>; pab_core::MAX_PORTS],
    guard: Guard,
    arbiter: Option<Arbiter<P, C, N>>,
    receiver: isotp::Receiver<IMG>,
    /// The schema server of the running table, if it has one.
    #[cfg(feature = "schema")]
    schema: Option<crate::schema::SchemaRuntime>,
}

/// What one call into the schema server sends: at most a tick's set-point (3 frames), its
/// transitions (3) and their faults (3), a report.
#[cfg(feature = "schema")]
use crate::schema::Keys;

#[cfg(feature = "schema")]
type SchemaOuts = heapless::Vec<crate::schema::Out, 12>;

/// Keeps one of the schema server's outputs for the node to send.
// Out of line: each output the server's runtime makes inlined a copy of the push.
#[cfg(feature = "schema")]
#[inline(never)]
fn collect(outs: &mut SchemaOuts, out: crate::schema::Out) {
    // At most 12 a call (SchemaOuts): never refused.
    let _ = outs.push(out);
}

impl<const P: usize, const C: usize, const N: usize, const IMG: usize> Node<P, C, N, IMG> {
    /// A node without a table, booted at `now`. Its first heartbeat goes out at once.
    ///
    /// Out of line: a board builds its node once, at boot, in a `static`; inlined into the
    /// start-up task it took 12 bytes more of the NUCLEO-G474RE's flash.
    #[inline(never)]
    pub fn new(config: Config, now: Instant) -> Self {
        Node {
            receiver: isotp::Receiver::new(config.isotp),
            config,
            booted: now,
            arbiter: None,
            running: None,
            store_failed: false,
            bus_trouble: false,
            #[cfg(feature = "schema")]
            schema_on: false,
            boot_fault: None,
            incoming: None,
            opened: None,
            awaiting_store: None,
            store_due: None,
            last_store: None,
            guard: Guard::unkeyed(now),
            counters: Counters::default(),
            next_heartbeat: now,
            diagnostic: DiagnosticStream::default(),
            faults: FaultLimiter::new(config.fault_interval_us),
            filter_sequence: 0,
            exploited: NOTHING_EXPLOITED,
            outbox: heapless::Vec::new(),
            #[cfg(feature = "schema")]
            schema: None,
        }
    }

    /// Gives the node its key: from now on it takes only authenticated configuration
    /// (docs/can-protocol.md, "Authenticated configuration"). `boot_salt` is the high half of
    /// every challenge: it must never repeat for one key (boards: a boot counter in flash;
    /// `pab-node`: random bits from the OS), or challenges of an earlier boot become valid again.
    /// Costs the AES key expansion.
    pub fn set_key(&mut self, key: &Key, boot_salt: u32) {
        self.guard.set_key(key, boot_salt);
    }

    /// The key page did not verify (`reason`: [`pab_core::auth::page::PageError::code`]): the
    /// node fails closed, accepting no configuration, and raises
    /// [`FaultCode::KeyPageInvalid`] after every heartbeat group.
    pub fn lock_configuration(&mut self, reason: u8) {
        self.guard.lock(reason);
    }

    /// Whether the node takes only authenticated configuration (it has a key, or is locked).
    pub fn is_keyed(&self) -> bool {
        self.guard.is_keyed()
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
        match self.take_image(len, None, now) {
            Ok(header) => {
                info!(
                    "booted with stored table version {}",
                    int(header.table_version)
                );
                if let Some(running) = self.running.as_mut() {
                    running.stored = true;
                }
            }
            Err((status, detail)) => {
                if status == TransferStatusCode::WrongNode {
                    warn!(
                        "stored table refused: the image is for node {}, this node is {}; starting without a table",
                        int(u32::from(detail)),
                        int(u32::from(node_id))
                    );
                } else {
                    warn!(
                        "stored table refused: {} (detail {}); starting without a table",
                        status,
                        int(u32::from(detail))
                    );
                }
                // For WrongNode, the detail is the image's node id.
                self.boot_fault = Some([status.code(), detail, 0, 0, 0]);
            }
        }
        // The first heartbeat group goes out now, and the fault (if any) with it.
        self.duties(now);
    }

    /// Starts without a table because the store could not be read (`error`): raises
    /// [`FaultCode::BadStoredTable`] with detail [`STORE_UNREADABLE`] and the [`StoreFailure`],
    /// repeated after every heartbeat group until a table runs.
    pub fn boot_unreadable(&mut self, error: StoreError, now: Instant) {
        warn!(
            "the stored table could not be read ({}); starting without a table",
            error
        );
        let failure = match error {
            StoreError::Flash(_) => StoreFailure::Read,
            StoreError::BufferTooSmall { .. } | StoreError::ImageTooLarge { .. } => {
                StoreFailure::TooLarge
            }
            StoreError::Corrupt => StoreFailure::Corrupt,
            StoreError::Layout(_)
            | StoreError::SequenceExhausted
            | StoreError::VerifyFailed
            | StoreError::NoSave => StoreFailure::Other,
        };
        self.boot_fault = Some([STORE_UNREADABLE, failure.code(), 0, 0, 0]);
        self.duties(now);
    }

    /// Handles one frame read from the bus at `now`: arbitrates it, or handles it as a frame of
    /// our protocol. Delivered frames go to `recipient` (and are re-published where the table says
    /// so); a recipient that observes verdicts ([`Recipient::OBSERVES_VERDICTS`]) sees each one
    /// first. Protocol frames are never arbitrated.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
        recipient: &mut impl Recipient,
    ) -> Step {
        self.counters.received = self.counters.received.wrapping_add(1);
        let step = match protocol::classify(frame) {
            FrameKind::Claim => {
                self.on_claim_frame(frame, now);
                Step::Continue
            }
            // An unknown service goes the same way: the decoder refuses it as not ours, and
            // the node neither counts nor answers it.
            FrameKind::Service(_) | FrameKind::UnknownService => {
                // A new table runs (`Store`): its save now or when its turn comes.
                match self.on_protocol_frame(frame, now) {
                    Step::Store => self.schedule_store(now),
                    Step::Continue => Step::Continue,
                }
            }
            FrameKind::Topic => {
                // The drive's pose and wrench are topics too: read by the schema server, and
                // arbitrated like any frame.
                #[cfg(feature = "schema")]
                if self.schema_on
                    && let Some(runtime) = self.schema.as_mut()
                {
                    runtime.on_drive_frame(frame, now);
                }
                self.arbitrate(frame, now, recipient);
                if let Some(arbiter) = self.arbiter.as_mut()
                    && arbiter.observes_frames()
                {
                    arbiter.observe(frame, now);
                }
                Step::Continue
            }
        };
        self.values_due(now, recipient);
        self.duties(now);
        match step {
            Step::Store => Step::Store,
            Step::Continue => self.store_step(now),
        }
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
        self.duties(now);
    }

    /// Reports a frame that could not be sent (the bus is congested or the controller is off).
    pub fn on_transmit_error(&mut self, now: Instant) {
        self.error(FaultCode::TxOverrun, [0; 5]);
        self.duties(now);
    }

    /// The image to store after [`Step::Store`]: the one now running. It stays in the node's
    /// transfer buffer until [`Node::stored`] (transfers are refused `Busy` meanwhile), so the
    /// newest applied image is never lost before it is stored.
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
        if let Some((source, nonce)) = self.awaiting_store.take() {
            self.answer(source, status, 0, nonce);
        }
        self.duties(now);
    }

    /// Emits what is due at `now` (heartbeat, faults, diagnostic samples), handles transfer
    /// timeouts, and says whether a save that waited for its turn is due now ([`Step::Store`]:
    /// store [`Node::image_to_store`], then call [`Node::stored`]). Call it whenever
    /// [`Node::deadline`] passes; [`Node::on_frame`] does the same work.
    ///
    /// Saves are rate-limited: a table applied less than [`crate::Config::store_interval_us`]
    /// after the start of the last save runs at once, and is stored (and its transfer answered)
    /// when the interval has passed, through this call.
    ///
    /// Value ports whose output changes by then (a value aged out) hand it to `recipient`.
    #[must_use = "a Step::Store asks the runner to store the running image and call Node::stored"]
    pub fn poll(&mut self, now: Instant, recipient: &mut impl Recipient) -> Step {
        self.values_due(now, recipient);
        self.duties(now);
        self.store_step(now)
    }

    /// The value ports' outputs that changed by `now` without a frame, delivered. A comparison
    /// per value port (none on a table without value ports).
    #[inline]
    fn values_due<K: Recipient>(&mut self, now: Instant, recipient: &mut K) {
        if self
            .arbiter
            .as_ref()
            .is_some_and(|arbiter| arbiter.is_due(now))
        {
            self.deliver_values_due(now, recipient);
        }
    }

    #[inline(never)]
    fn deliver_values_due<K: Recipient>(&mut self, now: Instant, recipient: &mut K) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        let mut outputs: heapless::Vec<Combined, MAX_VALUE_PORTS> = heapless::Vec::new();
        arbiter.poll(now, |output| {
            let _ = outputs.push(*output);
        });
        for output in &outputs {
            self.deliver(output.port, &output.frame, now, recipient);
        }
    }

    /// [`Step::Store`] if the image awaiting its save may be stored at `now` (and it is then
    /// handed out once), else [`Step::Continue`]. One comparison when no save waits.
    #[inline]
    fn store_step(&mut self, now: Instant) -> Step {
        match self.store_due {
            Some(due) if now.micros_since(due).is_some() => {
                self.store_due = None;
                self.last_store = Some(now);
                Step::Store
            }
            _ => Step::Continue,
        }
    }

    /// A new table runs since `now`: its save now, or when the store interval since the last
    /// save has passed.
    fn schedule_store(&mut self, now: Instant) -> Step {
        let due = self
            .last_store
            .map(|last| last.wrapping_add_micros(self.config.store_interval_us));
        match due {
            // The interval has not passed (and the clock did not go backwards past the last
            // save: then the save goes now rather than wait for an instant that may be far).
            Some(due)
                if due.micros_since(now).is_some_and(|wait| wait > 0)
                    && self
                        .last_store
                        .and_then(|last| now.micros_since(last))
                        .is_some() =>
            {
                self.store_due = Some(due);
                Step::Continue
            }
            _ => {
                self.store_due = None;
                self.last_store = Some(now);
                Step::Store
            }
        }
    }

    /// The work [`Node::poll`] does, but the save: what every event runs.
    ///
    /// Cost: each duty first checks, in a comparison or two, whether it has anything to do (a
    /// transfer in progress, the heartbeat's instant, a fault pending, the diagnostic stream on),
    /// so that the poll of a frame, which usually finds nothing due, costs a few instructions.
    #[inline]
    fn duties(&mut self, now: Instant) {
        if self.receiver.poll(now).is_some() {
            self.transfer_timeout(false);
        }
        if let Some(incoming) = self.incoming
            && now.micros_since(incoming.deadline).is_some()
        {
            self.transfer_timeout(true);
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
        if self.arbiter.as_ref().is_some_and(Arbiter::has_groups) {
            self.send_claims(now);
        }
        #[cfg(feature = "dynamics")]
        if self.arbiter.as_ref().is_some_and(Arbiter::has_dynamics) {
            self.step_dynamics(now);
        }
        if self.arbiter.as_ref().is_some_and(Arbiter::has_filters) {
            self.exploitation(now);
        }
        // One test of the server's presence, here: inside `schema_due`, behind its deadline's
        // comparisons, a node without a server paid 3 instructions more a frame.
        #[cfg(feature = "schema")]
        if self.schema_on {
            self.schema_due(now);
        }
    }

    /// HBBA's exploitation edges: for each port whose delivering connection (the one its
    /// decision selects) changed since the last look, the one that stopped and the one that
    /// started. Only on a table with message filters.
    #[inline(never)]
    fn exploitation(&mut self, now: Instant) {
        let Some(arbiter) = self.arbiter.as_ref() else {
            return;
        };
        let mut edges: heapless::Vec<Exploitation, { 2 * pab_core::MAX_PORTS }> =
            heapless::Vec::new();
        for (port, last) in self.exploited.iter_mut().enumerate() {
            let port = port as u8;
            let now_selected = arbiter.selected(port, now);
            if now_selected == *last {
                continue;
            }
            for (connection, delivering) in [(*last, false), (now_selected, true)] {
                if let Some(connection) = connection {
                    let _ = edges.push(Exploitation {
                        port,
                        connection,
                        delivering,
                    });
                }
            }
            *last = now_selected;
        }
        // By reference: the vector's by-value iterator slices, with a bounds check.
        for edge in edges.iter() {
            self.send(Message::Exploitation(*edge), protocol::BROADCAST);
        }
    }

    /// A filter command applied: FilterStatus with its sequence number; refused: FilterRefused
    /// with why, what it named (`what`) and its sequence number, nothing changed.
    fn filter_answer(&mut self, result: Result<(), CommandError>, what: [u8; 2], sequence: u16) {
        match result {
            Ok(()) => {
                self.filter_sequence = sequence;
                self.send_filter_status();
            }
            Err(error) => {
                let [s0, s1] = sequence.to_le_bytes();
                self.raise(
                    FaultCode::FilterRefused,
                    [error.code(), what[0], what[1], s0, s1],
                );
            }
        }
    }

    /// FilterStatus: the active profile (or one by one), the last command's sequence number and
    /// the counts; nothing on a table without filters.
    fn send_filter_status(&mut self) {
        let Some(arbiter) = self.arbiter.as_ref().filter(|a| a.has_filters()) else {
            return;
        };
        let counts = arbiter.filter_counts();
        let status = FilterStatus {
            profile: arbiter
                .filter_profile()
                .unwrap_or(FilterStatus::SET_ONE_BY_ONE),
            sequence: self.filter_sequence,
            filtered: counts.filtered,
            closed: counts.closed,
            throttled: counts.throttled,
        };
        self.send(Message::FilterStatus(status), protocol::BROADCAST);
    }

    /// The dynamics brought up to `now`: the steps due of the groups the node runs, their
    /// gates queued, and the groups it reads that fell silent reported.
    #[cfg(feature = "dynamics")]
    #[inline(never)]
    fn step_dynamics(&mut self, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if arbiter
            .dynamics_deadline(now)
            .is_some_and(|due| now.micros_since(due).is_none())
        {
            return;
        }
        let skipped = |arbiter: &Arbiter<P, C, N>| {
            arbiter
                .dynamics_runs()
                .iter()
                .map(|run| run.skipped())
                .fold(0u32, u32::saturating_add)
        };
        let before = skipped(arbiter);
        // One Gates frame per group a poll, its last: a poll that catches up several steps may
        // see several changes, and the frames would all leave at this instant, each stale but
        // the last (its `changes` counts them all). The groups are polled one after the other
        // and their numbers differ (the table is validated), so a group's frames come in a row:
        // only the last kept can be the same group's.
        let mut gates: heapless::Vec<protocol::Gates, { dynamics::MAX_DYNAMICS_GROUPS }> =
            heapless::Vec::new();
        // A fault is only recorded, not sent: raised in the poll, no list to keep.
        let faults = &mut self.faults;
        arbiter.dynamics_poll(
            now,
            |_| {},
            |g| match gates.last_mut() {
                Some(kept) if kept.group == g.group => *kept = g,
                _ => {
                    let _ = gates.push(g);
                }
            },
            |l: GatesLost| faults.raise(FaultCode::GatesLost, [l.owner, l.group, 0, 0, 0]),
        );
        let after = skipped(arbiter);
        let late = arbiter
            .dynamics_runs()
            .iter()
            .position(|run| run.skipped() != 0);
        for g in gates.iter() {
            self.send(Message::Gates(*g), protocol::BROADCAST);
        }
        if after != before {
            let [a, b, c, d] = after.to_le_bytes();
            let group = late.and_then(|p| u8::try_from(p).ok()).unwrap_or(0);
            self.raise(FaultCode::DynamicsLate, [a, b, c, d, group]);
        }
    }

    /// Gates from another node: read if the table reads the group, refused with a fault if the
    /// group has another size here.
    #[cfg(feature = "dynamics")]
    #[inline(never)]
    fn on_gates(&mut self, source: u8, gates: &protocol::Gates, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if arbiter.on_gates(source, gates, now).is_err() {
            self.error(
                FaultCode::GatesRefused,
                [source, gates.group, gates.behaviours, 0, 0],
            );
        }
    }

    /// The BLE claims due at `now`, and the holding decisions brought up to it.
    #[inline(never)]
    fn send_claims(&mut self, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        // Work due by `now`, seen from the microsecond before: a claim going stale at exactly
        // `now` is a deadline then, where `ble_deadline(now)` counts it as past (and the holding
        // decision would wait for the next claim, a period late). Polling twice in one
        // microsecond changes nothing the second time.
        let before = Instant::from_micros(now.as_micros().wrapping_sub(1));
        if arbiter
            .ble_deadline(before)
            .is_some_and(|due| now.micros_since(due).is_none())
        {
            return;
        }
        // A node is in at most MAX_GROUPS groups: one claim each per poll.
        let mut claims: heapless::Vec<Claim, { ble::MAX_GROUPS }> = heapless::Vec::new();
        arbiter.ble_poll(now, |claim| {
            let _ = claims.push(claim);
        });
        // By reference: the vector's by-value iterator slices, with a bounds check.
        for claim in claims.iter() {
            if let Some(frame) = claim.frame() {
                self.queue(frame);
            }
        }
    }

    /// A peer's BLE claim: kept by the arbiter's group state, or refused with a fault
    /// (ClaimRefused: malformed, this node's own id, no room). Without a table there is no
    /// group to keep it for.
    #[inline(never)]
    fn on_claim_frame(&mut self, frame: &Frame, now: Instant) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if !arbiter.has_groups() {
            return;
        }
        let (reason, node, group) = match Claim::decode(frame) {
            Err(_) => (1, 0, 0),
            Ok(claim) => match arbiter.on_claim(claim, now) {
                Ok(()) => return,
                Err(BleError::OwnIdClash) => (2, claim.node, claim.group),
                Err(_) => (3, claim.node, claim.group),
            },
        };
        self.error(FaultCode::ClaimRefused, [reason, node, group, 0, 0]);
    }

    /// The transfer in progress lost its slot (Timeout), and its sender learns why: its
    /// reception timed out (`too_slow` false: detail 0), or it used up its time budget
    /// ([`TRANSFER_BASE_US`]; `too_slow`: detail 1, the reception aborted). One function for
    /// both, which differ only in these, so that the taking and the refusal are in the flash once.
    #[inline(never)]
    fn transfer_timeout(&mut self, too_slow: bool) {
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
                let Some(frame) = Message::Diagnostic(sample)
                    .report_frame(self.config.node_id, protocol::BROADCAST)
                else {
                    break;
                };
                if enqueue_cold(&mut self.outbox, frame).is_err() {
                    break;
                }
            }
        }
    }

    /// The latest instant by which [`Node::poll`] must run again.
    pub fn deadline(&self, now: Instant) -> Instant {
        let mut deadline = self.next_heartbeat;
        earlier(&mut deadline, self.receiver.deadline());
        earlier(
            &mut deadline,
            self.incoming.map(|incoming| incoming.deadline),
        );
        earlier(&mut deadline, self.faults.deadline());
        earlier(&mut deadline, self.store_due);
        #[cfg(feature = "schema")]
        earlier(&mut deadline, self.schema.as_ref().map(|s| s.deadline()));
        if let Some(arbiter) = self.arbiter.as_ref() {
            earlier(&mut deadline, self.diagnostic.deadline(now));
            earlier(&mut deadline, arbiter.deadline(now));
            if arbiter.has_groups() {
                earlier(&mut deadline, arbiter.ble_deadline(now));
            }
            #[cfg(feature = "dynamics")]
            if arbiter.has_dynamics() {
                earlier(&mut deadline, arbiter.dynamics_deadline(now));
            }
            if arbiter.has_filters() {
                earlier(&mut deadline, arbiter.activity_deadline(now));
            }
        }
        deadline
    }

    /// The next frame to send: the lowest identifier queued (the one that would win bus
    /// arbitration), the oldest of those with that identifier. One step.
    pub fn next_outgoing(&mut self) -> Option<Frame> {
        self.outbox.pop()
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

    /// The running table's schema server, if it has one.
    #[cfg(feature = "schema")]
    pub fn schema(&self) -> Option<&crate::schema::SchemaRuntime> {
        self.schema.as_ref()
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

    fn arbitrate<K: Recipient>(&mut self, frame: &Frame, now: Instant, recipient: &mut K) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        // A frame changes the output of each value port at most once.
        let mut outputs: heapless::Vec<Combined, MAX_VALUE_PORTS> = heapless::Vec::new();
        let mut on_value = |output: &Combined| {
            let _ = outputs.push(*output);
        };
        // Two calls, so that a recipient that does not observe (`OBSERVES_VERDICTS` is a
        // constant) runs exactly the plain arbitration: the other branch is compiled out.
        let reception = if K::OBSERVES_VERDICTS {
            // A frame feeds each port at most once: P entries always suffice.
            let mut verdicts: heapless::Vec<PortVerdict, P> = heapless::Vec::new();
            let reception = arbiter.receive_frame(
                frame,
                now,
                |verdict| {
                    let _ = verdicts.push(*verdict);
                },
                &mut on_value,
            );
            for verdict in &verdicts {
                recipient.verdict(frame, now, verdict, arbiter);
            }
            reception
        } else {
            arbiter.receive_frame(frame, now, |_| {}, &mut on_value)
        };
        if reception.fed.is_empty() {
            return;
        }
        // A value port's output: the combination, not the frame as it came.
        for output in &outputs {
            self.deliver(output.port, &output.frame, now, recipient);
        }
        if reception.delivered.is_empty() {
            if outputs.is_empty() {
                self.counters.discarded = self.counters.discarded.wrapping_add(1);
            }
            return;
        }
        // The ports it was delivered to, in increasing order (usually one).
        let mut ports = reception.delivered.bits();
        while ports != 0 {
            self.deliver(ports.trailing_zeros() as u8, frame, now, recipient);
            ports &= ports - 1;
        }
    }

    /// Hands `frame`, delivered at `port`, to the recipient, and queues its re-publication if the
    /// port is a gateway. Out of line: the loop over the delivered ports then keeps nothing of
    /// the node in registers across it.
    #[inline(never)]
    fn deliver<K: Recipient>(&mut self, port: u8, frame: &Frame, now: Instant, recipient: &mut K) {
        self.counters.delivered = self.counters.delivered.wrapping_add(1);
        recipient.deliver(port, frame, now);
        let republish = self
            .arbiter
            .as_ref()
            .and_then(|arbiter| arbiter.table().consumer(usize::from(port)));
        if let Some(Consumer::Republish(output)) = republish
            && self
                .enqueue_over_diagnostic(frame.republished(output.id()))
                .is_err()
        {
            self.error(FaultCode::TxOverrun, [1, 0, 0, 0, 0]);
        }
    }

    /// A frame of our protocol (not a claim). Out of line: inlined into [`Node::on_frame`], and
    /// with it into the runner's async loop, it took 1.5 KB more of a board's flash, and its
    /// decoding weighed on the register allocation of the path of every arbitrated frame.
    #[inline(never)]
    fn on_protocol_frame(&mut self, frame: &Frame, now: Instant) -> Step {
        let node_id = self.config.node_id;
        // Only what a node acts on is decoded; another service's well-framed frame (a report,
        // a desire) is not this node's business.
        let (id, message) = match Message::decode_for_node(frame) {
            Ok(Some(decoded)) => decoded,
            Ok(None) => return Step::Continue,
            Err(_) => {
                // Count malformed frames addressed to us; other nodes' business is not ours.
                if let Some(id) = FrameId::decode(&frame.id())
                    && id.is_for(node_id)
                {
                    self.error(FaultCode::BadCommand, [id.service.code(), 0, 0, 0, 0]);
                }
                return Step::Continue;
            }
        };
        if !id.is_for(node_id) || id.source == node_id {
            return Step::Continue;
        }
        match message {
            #[cfg(feature = "dynamics")]
            Message::Gates(gates) => {
                self.on_gates(id.source, &gates, now);
                Step::Continue
            }
            Message::DiagnosticControl(control) => {
                match self.guard.plain_allowed() {
                    Ok(()) => self.configure_diagnostic(control, now),
                    Err(failure) => self.unauthenticated(failure, id),
                }
                Step::Continue
            }
            Message::AuthenticatedDiagnosticControl { control, tag } => {
                // Each tag is over one node's challenge: a broadcast cannot be valid for all.
                let verdict = if id.destination != node_id {
                    Err(AuthFailure::Broadcast)
                } else {
                    let [r0, r1] = control.rate_hz.to_le_bytes();
                    let [p0, p1] = control.ports.to_le_bytes();
                    let payload = [r0, r1, p0, p1];
                    self.guard
                        .command(node_id, id.service.code(), &payload, &tag, now)
                };
                match verdict {
                    Ok(()) => self.configure_diagnostic(control, now),
                    Err(failure) => self.unauthenticated(failure, id),
                }
                Step::Continue
            }
            Message::ChallengeRequest if id.destination == node_id => {
                match self.guard.challenge(now) {
                    Ok(nonce) => self.send(Message::Challenge { nonce }, id.source),
                    Err(failure) => self.unauthenticated(failure, id),
                }
                Step::Continue
            }
            Message::TransferOpen(open) if id.destination == node_id => {
                self.on_transfer_open(id, &open, now);
                Step::Continue
            }
            // Transfers are point to point: a broadcast transfer would make every node answer
            // flow control at once.
            Message::TableTransfer { data, len } if id.destination == node_id => {
                let data = data.get(..usize::from(len)).unwrap_or(&data);
                self.on_transfer_frame(id, data, now)
            }
            // HBBA's filter commands: applied and answered with FilterStatus, or refused aloud
            // (never dropped unseen), so that the intention node learns whether its intention is
            // in force here. Point to point: the answer names one node's filters.
            Message::FilterProfile(switch) if id.destination == node_id => {
                let result = self
                    .arbiter
                    .as_mut()
                    .map_or(Err(CommandError::NoFilters), |a| {
                        a.set_filter_profile(switch.profile)
                    });
                self.filter_answer(result, [switch.profile, 0], switch.sequence);
                Step::Continue
            }
            Message::FilterSet(set) if id.destination == node_id => {
                let result = self
                    .arbiter
                    .as_mut()
                    .map_or(Err(CommandError::NoFilters), |a| {
                        a.set_filter(set.port, set.connection, set.phi)
                    });
                self.filter_answer(result, [set.port, set.connection], set.sequence);
                Step::Continue
            }
            // The schema server's: stopping is accepted from anyone (docs/can-protocol.md,
            // "Schema server"); a node without one ignores it.
            #[cfg(feature = "schema")]
            Message::EmergencyStop => {
                if let Some(runtime) = self.schema.as_mut() {
                    runtime.emergency_stop();
                }
                Step::Continue
            }
            #[cfg(feature = "schema")]
            Message::SchemaAbort => {
                if let Some(runtime) = self.schema.as_mut() {
                    runtime.abort();
                }
                Step::Continue
            }
            // Point to point, as table transfers.
            #[cfg(feature = "schema")]
            Message::SchemaTransfer { data, len } if id.destination == node_id => {
                let data = data.get(..usize::from(len)).unwrap_or(&data);
                self.on_schema_transfer(id, data, now);
                Step::Continue
            }
            _ => Step::Continue,
        }
    }

    /// Starts the schema server of the table that runs from `now`, or stops the previous
    /// table's (a new table restarts it: its queue is the old table's business).
    #[cfg(feature = "schema")]
    fn start_schema(&mut self, now: Instant) {
        let setup = self.arbiter.as_mut().and_then(Arbiter::take_schema);
        // Not checked again: the set-up comes from the arbiter just built, and `Arbiter::new`
        // refused any table whose set-up fails `Setup::check` (its server's set-up included).
        self.schema = setup.map(|s| crate::schema::SchemaRuntime::new(s, self.config.isotp, now));
        self.schema_on = self.schema.is_some();
    }

    #[cfg(not(feature = "schema"))]
    #[inline(always)]
    fn start_schema(&mut self, _: Instant) {}

    /// A SchemaTransfer frame: to the server, or refused by a node that runs none. On a node
    /// with a key, as a table's: only from the tool, a first frame only after a TransferOpen
    /// for a schema ([`protocol::OPEN_SCHEMA`]) of its length, consecutive frames in sequence.
    #[cfg(feature = "schema")]
    fn on_schema_transfer(&mut self, id: FrameId, data: &[u8], now: Instant) {
        let source = id.source;
        let mut opened = None;
        if self.guard.is_keyed() && self.schema.is_some() {
            let next = self.schema.as_ref().and_then(|r| r.next_sequence_number());
            let admitted = if source == protocol::TOOL {
                self.admit_keyed(data, next, true, now)
            } else {
                Err(AuthFailure::NotTool)
            };
            match admitted {
                Ok(open) => opened = open.map(|open| open.nonce),
                Err(failure) => {
                    self.unauthenticated(failure, id);
                    return;
                }
            }
        }
        let mut outs = SchemaOuts::new();
        match self.schema.as_mut() {
            Some(runtime) => runtime.on_transfer_frame(
                source,
                data,
                now,
                Keys {
                    guard: &self.guard,
                    node: self.config.node_id,
                    opened,
                },
                &mut |o| collect(&mut outs, o),
            ),
            // Only a message's first frame is answered: a multi-frame one gets no flow control.
            None if matches!(
                pab_core::isotp::pci::decode(data),
                Ok((Pci::Single { .. } | Pci::First { .. }, _))
            ) =>
            {
                self.send(
                    Message::SchemaAck(protocol::SchemaAck {
                        stop: 0,
                        outcome: protocol::SchemaOutcome::NoServer,
                        channel: None,
                        id: protocol::SchemaAck::NO_ID,
                        queued: 0,
                    }),
                    source,
                );
            }
            None => {}
        }
        self.schema_outs(outs);
    }

    /// The schema server's work due by `now` (a tick, its reports).
    #[cfg(feature = "schema")]
    #[inline]
    fn schema_due(&mut self, now: Instant) {
        let Some(runtime) = self.schema.as_mut() else {
            return;
        };
        if now.micros_since(runtime.deadline()).is_none() {
            return;
        }
        let mut outs = SchemaOuts::new();
        runtime.poll(now, &mut |o| collect(&mut outs, o));
        self.schema_outs(outs);
    }

    #[cfg(feature = "schema")]
    fn schema_outs(&mut self, outs: SchemaOuts) {
        // By reference: walked by value, each element was moved out of the vector first (78
        // bytes of flash).
        for out in &outs {
            match out {
                crate::schema::Out::Drive(frame) => self.queue(*frame),
                crate::schema::Out::Protocol(message, destination) => {
                    self.send(*message, *destination)
                }
                crate::schema::Out::Fault(code, detail) => self.raise(*code, *detail),
            }
        }
    }

    #[inline(never)]
    fn configure_diagnostic(&mut self, control: protocol::DiagnosticControl, now: Instant) {
        self.diagnostic.configure(control, now);
        info!(
            "diagnostic stream at {} Hz",
            int(u32::from(control.rate_hz))
        );
    }

    /// A configuration message refused by the authentication rules: counted, and a fault says
    /// why, which service and from whom. Out of line: nine refusals inlined it. The identifier
    /// by value here and in the transfer handlers (4 bytes, one register): by reference, each
    /// caller first stored it on its stack.
    #[inline(never)]
    fn unauthenticated(&mut self, failure: AuthFailure, id: FrameId) {
        warn!("configuration refused: {}", failure);
        self.error(
            FaultCode::Unauthenticated,
            [failure.code(), id.service.code(), id.source, 0, 0],
        );
    }

    /// A TransferOpen: if its tag verifies over the outstanding challenge, the next first frame
    /// from the tool with exactly its length (within a second) starts an authenticated transfer.
    /// A valid open replaces a transfer in progress (the key holder restarted its push).
    fn on_transfer_open(&mut self, id: FrameId, open: &TransferOpen, now: Instant) {
        if id.source != protocol::TOOL {
            self.unauthenticated(AuthFailure::NotTool, id);
            return;
        }
        match self.guard.open(self.config.node_id, open, now) {
            Ok(nonce) => {
                // An open for a table interrupts a table transfer in progress; one for a schema
                // leaves it alone (a schema never waits behind a table).
                if open.flags & protocol::OPEN_SCHEMA == 0
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
    fn admit_keyed(
        &mut self,
        data: &[u8],
        next: Option<u8>,
        schema: bool,
        now: Instant,
    ) -> Result<Option<Opened>, AuthFailure> {
        match isotp::pci::decode(data) {
            Ok((Pci::First { len }, _)) => self.take_open(usize::try_from(len).ok(), schema, now),
            Ok((Pci::Single { len }, _)) => self.take_open(Some(usize::from(len)), schema, now),
            Ok((Pci::Consecutive { sn }, _)) if next.is_some_and(|next| next != sn) => {
                Err(AuthFailure::Sequence)
            }
            // In sequence, flow controls and malformed frames: the receiver decides.
            _ => Ok(None),
        }
    }

    fn take_open(
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
            .filter(|opened| (opened.flags & protocol::OPEN_SCHEMA != 0) == schema)
            .ok_or(AuthFailure::Unopened)?;
        self.opened = None;
        Ok(Some(opened))
    }

    fn on_transfer_frame(&mut self, id: FrameId, data: &[u8], now: Instant) -> Step {
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
            match self.admit_keyed(data, self.receiver.next_sequence_number(), false, now) {
                Ok(opened) => opened,
                Err(failure) => {
                    self.unauthenticated(failure, id);
                    return Step::Continue;
                }
            }
        } else {
            None
        };
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
                self.send_transfer(source, flow_control);
                Step::Continue
            }
            Event::Refused(flow_control) => {
                if let Some(flow_control) = flow_control {
                    self.send_transfer(source, flow_control);
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
    fn apply_authenticated(
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
    fn apply(
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
    fn take_image(
        &mut self,
        len: usize,
        running: Option<Running>,
        now: Instant,
    ) -> Result<Header, (TransferStatusCode, u8)> {
        let bytes = self.receiver.buffer().get(..len).unwrap_or(&[]);
        // The new arbiter is built here, beside the running one: a refused image leaves
        // `self.arbiter` as it was.
        let mut fresh = None;
        let (header, arbiter) = check_target(bytes, self.config.node_id)
            .and_then(|()| load::<P, C, N>(&mut fresh, bytes))?;
        check_version(&header, running.as_ref())?;
        // The connections the new table leaves unchanged go on where they are (a re-push of the
        // same rules is no blackout); the others start at S = 0. At boot there is none.
        if let Some(previous) = self.arbiter.as_ref() {
            arbiter.carry_over(previous);
        }
        // The swap: one assignment of the `Some` already built, one 25 KB copy. The old
        // arbiter ran every frame until here.
        self.arbiter = fresh;
        // The schema server's set-up leaves the table only now, from its place in the node:
        // taken out before, it was one more large value in this function's frame, which with
        // the arbiter being built is the deepest stack the board ever has.
        self.start_schema(now);
        self.running = Some(Running {
            header,
            image_len: u32::try_from(len).unwrap_or(u32::MAX),
            stored: false,
        });
        Ok(header)
    }

    fn refuse(&mut self, source: u8, status: TransferStatusCode, detail: u8, nonce: Option<u64>) {
        warn!("table transfer refused: {}", status);
        self.answer(source, status, detail, nonce);
        self.raise(FaultCode::TableRefused, [status.code(), detail, 0, 0, 0]);
    }

    /// Sends the TransferStatus and, for an opened transfer (`nonce`), its Receipt. Out of line:
    /// two of its four callers had inlined it.
    #[inline(never)]
    fn answer(&mut self, source: u8, status: TransferStatusCode, detail: u8, nonce: Option<u64>) {
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

    #[inline(never)]
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
                keyed: self.guard.is_keyed(),
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
        self.send_filter_status();
        if self.arbiter.is_none()
            && let Some(detail) = self.boot_fault
        {
            self.raise(FaultCode::BadStoredTable, detail);
        }
        if let Some(reason) = self.guard.locked() {
            self.raise(FaultCode::KeyPageInvalid, [reason, 0, 0, 0, 0]);
        }
    }

    /// Out of line: eleven senders (answers, statuses, the heartbeat group) each inlined the
    /// encoding's call and the queueing. A node sends no command: [`Message::report_frame`]
    /// has none to encode.
    #[inline(never)]
    fn send(&mut self, message: Message, destination: u8) {
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
    fn queue(&mut self, frame: Frame) {
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
    fn enqueue_over_diagnostic(&mut self, frame: Frame) -> Result<(), Frame> {
        match enqueue(&mut self.outbox, frame) {
            Ok(()) => Ok(()),
            Err(frame) => self.enqueue_in_place_of_diagnostic(frame),
        }
    }

    /// The full outbox's case of [`Node::enqueue_over_diagnostic`], out of line.
    #[inline(never)]
    fn enqueue_in_place_of_diagnostic(&mut self, frame: Frame) -> Result<(), Frame> {
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

    fn raise(&mut self, code: FaultCode, detail: [u8; 5]) {
        self.faults.raise(code, detail);
    }

    /// An error: counted ([`Counters::errors`]), and its fault raised. Out of line: one copy of
    /// the count for its seven callers.
    #[inline(never)]
    fn error(&mut self, code: FaultCode, detail: [u8; 5]) {
        self.counters.errors = self.counters.errors.wrapping_add(1);
        self.raise(code, detail);
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
fn enqueue(outbox: &mut heapless::Vec<Frame, OUTBOX_LEN>, frame: Frame) -> Result<(), Frame> {
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
fn enqueue_cold(outbox: &mut heapless::Vec<Frame, OUTBOX_LEN>, frame: Frame) -> Result<(), Frame> {
    let rank = frame.arbitration_rank();
    if outbox.push(Frame::empty()).is_err() {
        return Err(frame);
    }
    let mut slots = outbox.iter_mut().rev();
    let Some(mut new) = slots.next() else {
        return Ok(());
    };
    *new = frame;
    for before in slots {
        if before.arbitration_rank() > rank {
            break;
        }
        core::mem::swap(before, new);
        new = before;
    }
    Ok(())
}

/// Removes the frame at `position` from `outbox`, keeping the others in order.
fn remove(outbox: &mut heapless::Vec<Frame, OUTBOX_LEN>, position: usize) {
    let mut slots = outbox.iter_mut().skip(position);
    if let Some(mut hole) = slots.next() {
        for next in slots {
            core::mem::swap(hole, next);
            hole = next;
        }
        outbox.pop();
    }
}

/// Moves `deadline` to `candidate` if that comes first. Out of line: one copy for the seven
/// candidates of [`Node::deadline`] and the schema server's own.
#[inline(never)]
pub(crate) fn earlier(deadline: &mut Instant, candidate: Option<Instant>) {
    if let Some(candidate) = candidate
        && candidate.micros_since(*deadline).is_none()
    {
        *deadline = candidate;
    }
}

/// The header checks a node makes before loading: a readable header, for this node.
fn check_target(bytes: &[u8], node_id: u8) -> Result<(), (TransferStatusCode, u8)> {
    let header = image::read_header_as::<Refused>(bytes).map_err(|error| status_of(&error))?;
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

/// Loads and validates an image for this node's capacities, and builds its arbiter in `slot`
/// (the table decoded in its place there).
fn load<'a, const P: usize, const C: usize, const N: usize>(
    slot: &'a mut Option<Arbiter<P, C, N>>,
    bytes: &[u8],
) -> Result<(Header, &'a mut Arbiter<P, C, N>), (TransferStatusCode, u8)> {
    // `Refused`: the status says only that the table is invalid, so the details are not built.
    match Arbiter::load_in::<Refused>(slot, bytes) {
        Ok(Ok(built)) => Ok(built),
        Ok(Err(Refused)) => Err((TransferStatusCode::InvalidTable, 0)),
        Err(error) => Err(status_of(&error)),
    }
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
