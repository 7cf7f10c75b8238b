//! The node, as a state machine without I/O: frames and the time go in, frames to send and the
//! image to store come out. The async runner (`crate::run`, with the feature `embassy`) or the poll loop ([`crate::PollLoop`]) and the tests drive the same code.
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
use crate::fmt::{code, int};
use crate::{Config, Recipient};

// The node's parts, each an `impl Node` of its own: what it says and hears to coordinate with
// the other nodes, what it says of itself, table transfers, and the outbox they all send through.
mod coordination;
#[cfg(feature = "identity")]
mod identity;
mod outbox;
mod status;
mod transfer;
#[cfg(feature = "update")]
mod update;

pub use transfer::status_of;

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
    /// A configuration record to store: [`Node::settings_to_store`] with
    /// [`pab_storage::TableStore::save_settings`], then call [`Node::settings_stored`] (feature
    /// `identity`).
    #[cfg(feature = "identity")]
    SaveSettings,
    /// An update's chunk to write: [`Node::update_chunk`] with
    /// [`pab_storage::TableStore::write_update`], then call [`Node::update_written`] (feature
    /// `update`).
    #[cfg(feature = "update")]
    WriteUpdate,
    /// An update's manifest and request to store: [`Node::update_manifest`] with
    /// [`pab_storage::TableStore::request_update`], then call [`Node::update_requested`], and
    /// restart if it says so (feature `update`).
    #[cfg(feature = "update")]
    RequestUpdate,
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

/// The kind of frame a transfer's frame came in (ISO 15765-2:2016): a node built with the
/// feature `fd` takes classic ISO-TP from classic frames and CAN FD ISO-TP from CAN FD frames,
/// and answers each transfer's flow control in the kind of frame the transfer came in (a Linux
/// ISO-TP socket on CAN FD takes only CAN FD frames). Without the feature every frame is classic
/// and this is empty: the boards' transfer code is what it was.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Wire {
    /// A CAN FD frame.
    #[cfg(feature = "fd")]
    fd: bool,
    /// Its bit-rate switch: the flow control keeps it.
    #[cfg(feature = "fd")]
    brs: bool,
}

impl Wire {
    /// The kind of `frame`.
    #[inline(always)]
    #[cfg_attr(not(feature = "fd"), allow(unused_variables))]
    pub(crate) fn of(frame: &Frame) -> Wire {
        Wire {
            #[cfg(feature = "fd")]
            fd: frame.is_fd(),
            #[cfg(feature = "fd")]
            brs: frame.is_brs(),
        }
    }

    /// The data field a transfer frame carries: the decoded message's bytes (up to 8), or a CAN
    /// FD frame's whole payload (up to 64).
    #[inline(always)]
    #[cfg_attr(not(feature = "fd"), allow(unused_variables))]
    pub(crate) fn data<'f>(self, frame: &'f Frame, data: &'f [u8]) -> &'f [u8] {
        #[cfg(feature = "fd")]
        if self.fd {
            return frame.payload();
        }
        data
    }

    /// `data` into `receiver`, by the rules of its kind.
    #[inline(always)]
    pub(crate) fn receive<'r, const N: usize>(
        self,
        receiver: &'r mut isotp::Receiver<N>,
        data: &[u8],
        now: Instant,
    ) -> isotp::RxOutcome<'r> {
        #[cfg(feature = "fd")]
        if self.fd {
            return receiver.on_fd_frame(data, now);
        }
        receiver.on_frame(data, now)
    }

    /// `data`'s protocol control information, by the codec of its kind.
    #[inline(always)]
    pub(crate) fn decode(self, data: &[u8]) -> Result<(Pci, &[u8]), isotp::FrameError> {
        #[cfg(feature = "fd")]
        if self.fd {
            return isotp::fd::decode(data);
        }
        isotp::pci::decode(data)
    }

    /// `frame` (a classic flow control) as this kind sends it: a CAN FD frame of the same
    /// identifier and bytes, with the bit-rate switch of the frame it answers.
    #[cfg(feature = "fd")]
    #[inline(always)]
    pub(crate) fn answer(self, frame: Frame) -> Frame {
        if self.fd
            && let Some(fd) = Frame::fd(frame.id(), frame.payload(), self.brs)
        {
            return fd;
        }
        frame
    }
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

/// The deadline of a transfer of `length` bytes that starts at `start`. Out of line: the table's
/// and the schema server's transfers inlined it (28 bytes of the NUCLEO-G474RE's flash).
#[inline(never)]
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
    /// Whether a topic frame before `idle_until` finds no duty due ([`Node::is_idle`]): nothing
    /// but the heartbeat waits for an instant (no transfer, the diagnostic stream off, no
    /// mechanism that works at every frame). Set by every run of the duties; a frame of our
    /// protocol, a poll and a save's outcome clear it, so that their duties run whole. A pending
    /// fault is tested apart. In the padding after the flags: an `Option<Instant>` among the
    /// first fields moved every later one, 190 bytes of the NUCLEO-G474RE's flash.
    idle: bool,
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
    /// The next heartbeat as the last run of the duties saw it (see `idle`).
    idle_until: Instant,
    diagnostic: DiagnosticStream,
    /// HBBA: the sequence number of the last filter command applied (0 since boot), and per port
    /// the connection last reported delivering (exploitation edges), on a table with filters.
    filter_sequence: u16,
    exploited: [Option<u8>; pab_core::MAX_PORTS],
    guard: Guard,
    #[cfg(feature = "identity")]
    me: identity::Me,
    arbiter: Option<Arbiter<P, C, N>>,
    receiver: isotp::Receiver<IMG>,
    /// The schema server of the running table, if it has one.
    #[cfg(feature = "schema")]
    schema: Option<crate::schema::SchemaRuntime>,
    /// Firmware update over the bus: its receiver and session.
    #[cfg(feature = "update")]
    update: update::Update,
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
    #[cfg_attr(not(feature = "identity"), allow(unused_mut))]
    pub fn new(mut config: Config, now: Instant) -> Self {
        // Unassigned (no node id): its provisional address until it knows its uid
        // (`set_identity`).
        #[cfg(feature = "identity")]
        let unassigned = config.node_id == 0;
        #[cfg(feature = "identity")]
        if unassigned {
            config.node_id = pab_core::identity::provisional_address(&[0; 12]);
        }
        Node {
            #[cfg(feature = "identity")]
            me: identity::Me::new(unassigned, now),
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
            idle: false,
            idle_until: now,
            diagnostic: DiagnosticStream::default(),
            faults: FaultLimiter::new(config.fault_interval_us),
            filter_sequence: 0,
            exploited: NOTHING_EXPLOITED,
            outbox: heapless::Vec::new(),
            #[cfg(feature = "schema")]
            schema: None,
            #[cfg(feature = "update")]
            update: update::Update::new(config.isotp),
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
        // Who it is, to all, once: how `pabctl nodes` hears an unassigned node.
        #[cfg(feature = "identity")]
        {
            self.send_identity(protocol::BROADCAST);
            if self.me.unassigned {
                info!("unassigned: no node id, waiting for one (pabctl assign)");
                return;
            }
        }
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
                        code(status, status.code()),
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
        warn!(
            "the stored table could not be read ({}); starting without a table",
            code(error, failure.code())
        );
        self.boot_fault = Some([STORE_UNREADABLE, failure.code(), 0, 0, 0]);
        #[cfg(feature = "identity")]
        self.send_identity(protocol::BROADCAST);
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
                match self.on_protocol_frame(frame, now, false) {
                    Step::Store => self.schedule_store(now),
                    Step::Continue => Step::Continue,
                    #[cfg(feature = "identity")]
                    Step::SaveSettings => Step::SaveSettings,
                    #[cfg(feature = "update")]
                    step @ (Step::WriteUpdate | Step::RequestUpdate) => step,
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
            #[cfg(feature = "identity")]
            Step::SaveSettings => Step::SaveSettings,
            #[cfg(feature = "update")]
            step @ (Step::WriteUpdate | Step::RequestUpdate) => step,
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
    // Out of line: the runner's two save steps each inlined it (28 bytes of the NUCLEO-G474RE's
    // flash, 4 of the emulated board's).
    #[inline(never)]
    pub fn image_to_store(&self) -> &[u8] {
        let len = self.running.map_or(0, |running| running.image_len);
        let len = usize::try_from(len).unwrap_or(0);
        self.receiver.buffer().get(..len).unwrap_or(&[])
    }

    /// Reports the outcome of storing [`Node::image_to_store`]; answers the transfer.
    pub fn stored(&mut self, ok: bool, now: Instant) {
        // Its duties run whole (see `idle`).
        self.idle = false;
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
        // Its duties run whole (see `idle`).
        self.idle = false;
        self.values_due(now, recipient);
        self.duties(now);
        #[cfg(feature = "identity")]
        if let step @ Step::SaveSettings = self.trial_due(now) {
            return step;
        }
        self.store_step(now)
    }

    /// The value ports' outputs that changed by `now` without a frame, delivered. A comparison
    /// per value port (none on a table without value ports: one test here, inlined).
    #[inline]
    fn values_due<K: Recipient>(&mut self, now: Instant, recipient: &mut K) {
        if self.arbiter.as_ref().is_some_and(Arbiter::has_values) {
            self.deliver_values_due(now, recipient);
        }
    }

    /// [`Node::values_due`] on a table with value ports. The value ports' comparisons here, out
    /// of line: inlined into the three callers of `values_due`, their loop took 80 bytes more of
    /// the NUCLEO-G474RE's flash.
    #[inline(never)]
    fn deliver_values_due<K: Recipient>(&mut self, now: Instant, recipient: &mut K) {
        let Some(arbiter) = self.arbiter.as_mut() else {
            return;
        };
        if !arbiter.is_due(now) {
            return;
        }
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
    /// transfer in progress, the heartbeat's instant, a fault pending, the diagnostic stream on,
    /// a mechanism's own work). A topic frame skips them all while the node is idle
    /// ([`Node::is_idle`]): on the emulated board, 26 instructions less a frame.
    #[inline]
    fn duties(&mut self, now: Instant) {
        // Here rather than in `on_frame` before the call: there it took 140 bytes more of the
        // NUCLEO-G474RE's flash (in the runner's loop, where `on_frame` is inlined), and saved
        // 18 instructions of a frame.
        if self.is_idle(now) {
            return;
        }
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
        #[cfg(feature = "update")]
        if self.update.is_busy() {
            self.update_due(now);
        }
        self.idle = self.nothing_waits();
        self.idle_until = self.next_heartbeat;
    }

    /// Whether the duties have nothing to do at `now`: `idle`, the next heartbeat still ahead
    /// (`idle_until`), and no fault pending. (The faults are tested here rather than `idle` cleared where one
    /// is raised: a store at each of two dozen call sites took 60 bytes of the NUCLEO-G474RE's
    /// flash.)
    #[inline(always)]
    fn is_idle(&self, now: Instant) -> bool {
        self.idle && now.micros_since(self.idle_until).is_none() && !self.faults.has_pending()
    }

    /// Whether no duty but the heartbeat waits for an instant (see `idle`).
    fn nothing_waits(&self) -> bool {
        let every_frame = self.arbiter.as_ref().is_some_and(|arbiter| {
            arbiter.has_groups() || arbiter.has_filters() || {
                #[cfg(feature = "dynamics")]
                let dynamics = arbiter.has_dynamics();
                #[cfg(not(feature = "dynamics"))]
                let dynamics = false;
                dynamics
            }
        });
        #[cfg(feature = "schema")]
        let every_frame = every_frame || self.schema_on;
        #[cfg(feature = "update")]
        let every_frame = every_frame || self.update.is_busy();
        !every_frame
            && self.receiver.deadline().is_none()
            && self.incoming.is_none()
            && !self.diagnostic.is_on()
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
        #[cfg(feature = "update")]
        earlier(&mut deadline, self.update.deadline());
        earlier(&mut deadline, self.store_due);
        #[cfg(feature = "identity")]
        earlier(&mut deadline, self.me.deadline());
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

    /// The authentication state and the diagnostic setting, for the fuzz target `node_keyed`
    /// ([`crate::AuthProbe`]). Not an API.
    #[doc(hidden)]
    #[inline]
    pub fn auth_probe(&self) -> crate::AuthProbe {
        let (challenge, window_start, checks_in_window) = self.guard.probe();
        crate::AuthProbe {
            challenge,
            window_start,
            checks_in_window,
            diagnostic: self.diagnostic.setting(),
        }
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
    ///
    /// `sealed`: the frame's seal verified ([`Node::on_seal`] hands it back here), so a keyed
    /// node applies it instead of holding it. One handler for both: a second entry point after
    /// the decoding took 900 bytes of the NUCLEO-G474RE's flash.
    pub(super) fn on_protocol_frame(&mut self, frame: &Frame, now: Instant, sealed: bool) -> Step {
        // Its duties run whole (see `idle`).
        self.idle = false;
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
        // An unassigned node takes only what gives it an id (and, keyed, the challenge that
        // authenticates it) and says who it is.
        #[cfg(feature = "identity")]
        if self.me.unassigned
            && !matches!(
                message,
                Message::IdentityRequest | Message::Assign(_) | Message::ChallengeRequest { .. }
            )
        {
            return Step::Continue;
        }
        // On a keyed node, what other nodes coordinate with waits for its seal
        // (pab_core::seal): applied by `on_seal` once the seal verifies, never before. Filter
        // commands and freshness answers are point to point, as below.
        if self.guard.is_keyed() && !sealed {
            let point_to_point = id.destination == node_id;
            let held = match message {
                #[cfg(feature = "dynamics")]
                Message::Gates(_) => true,
                Message::FilterProfile(_) | Message::FilterSet(_) | Message::Freshness { .. } => {
                    point_to_point
                }
                _ => false,
            };
            if held {
                self.hold(id.source, id.service.code(), frame, now);
                return Step::Continue;
            }
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
            Message::ChallengeRequest { tool_nonce } if id.destination == node_id => {
                self.on_challenge_request(id, tool_nonce, now);
                Step::Continue
            }
            Message::TransferOpen(open) if id.destination == node_id => {
                self.on_transfer_open(id, &open, now);
                Step::Continue
            }
            // Transfers are point to point: a broadcast transfer would make every node answer
            // flow control at once.
            Message::TableTransfer { data, len } if id.destination == node_id => {
                let wire = Wire::of(frame);
                let data = wire.data(frame, data.get(..usize::from(len)).unwrap_or(&data));
                self.on_transfer_frame(id, data, wire, now)
            }
            #[cfg(feature = "update")]
            Message::UpdateTransfer { data, len } if id.destination == node_id => {
                let wire = Wire::of(frame);
                let data = wire.data(frame, data.get(..usize::from(len)).unwrap_or(&data));
                self.on_update_frame(id, data, wire, now)
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
            // Sealed coordination (pab_core::seal): a node without a key has no use for seals.
            Message::Seal(seal) if self.guard.is_keyed() => {
                self.on_seal(id.source, &seal, now);
                Step::Continue
            }
            Message::FreshnessRequest { nonce } if id.destination == node_id => {
                match self.guard.answer_freshness(node_id, id.source, nonce, now) {
                    Ok([answer, seal]) => {
                        self.queue(answer);
                        self.queue(seal);
                    }
                    Err(failure) => self.unauthenticated(failure, id),
                }
                Step::Continue
            }
            #[cfg(feature = "identity")]
            Message::IdentityRequest => {
                self.on_identity_request(id.source, now);
                Step::Continue
            }
            // Point to point: each names one node (its uid check, its challenge).
            #[cfg(feature = "identity")]
            Message::Assign(assign) if id.destination == node_id => {
                self.on_assign(id, &assign, now)
            }
            #[cfg(feature = "identity")]
            Message::Configure(configure) if id.destination == node_id => {
                self.on_configure(id, &configure, now)
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
                let wire = Wire::of(frame);
                let data = wire.data(frame, data.get(..usize::from(len)).unwrap_or(&data));
                self.on_schema_transfer(id, data, wire, now);
                Step::Continue
            }
            _ => Step::Continue,
        }
    }

    /// Starts the schema server of the table that runs from `now`, or stops the previous
    /// table's (a new table restarts it: its queue is the old table's business).
    // Out of line: the server's runtime is built in its frame (8.5 KB on the boards) and moved
    // into place; inlined into the loader, that frame sat on top of the table's check.
    #[cfg(feature = "schema")]
    #[inline(never)]
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
    fn on_schema_transfer(&mut self, id: FrameId, data: &[u8], wire: Wire, now: Instant) {
        let source = id.source;
        let mut opened = None;
        if self.guard.is_keyed() && self.schema.is_some() {
            let next = self.schema.as_ref().and_then(|r| r.next_sequence_number());
            let admitted = if source == protocol::TOOL {
                self.admit_keyed(data, wire, next, true, now)
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
                wire,
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
                wire.decode(data),
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
