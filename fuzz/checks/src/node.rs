//! The node state machine (`pab_app::Node`, board capacities) under whatever the bus and the
//! clock do: arbitrary frames, times that jump and go backwards, bus errors, stores that succeed,
//! fail or finish late, and well-formed ISO-TP transfers (through pab-core's sender, obeying the
//! node's flow control) carrying images made from the examples' real ones, mutated.
//!
//! Properties, checked after every step:
//!
//! - **Deliveries equal a shadow arbiter's.** A second `pab_core::Arbiter`, built from the running
//!   image each time the node swaps one in, is fed the same non-protocol frames at the same times;
//!   the ports the node delivers each frame to are the shadow's. With BLE groups (the example of
//!   multi-target observation) the shadow also hears the BLE claims among the frames and polls
//!   its groups when the node's duties would, and every claim the node sends carries its id. With
//!   competitive dynamics (the door example) the shadow also hears the Gates frames among the
//!   protocol frames (some made well formed for the groups its table runs or reads), steps its
//!   groups when the node's duties would (at boot and at a swap too), and every Gates frame the
//!   node sends is of a group its table runs, with that group's count.
//! - **A refused transfer never changes the running table.** The running table (its header) only
//!   changes on a table-transfer frame, and then to the image the node will ask to store, which
//!   loads, is for this node and is newer than the one before. The node asks to store it
//!   (`Step::Store`, from `on_frame` or `poll`: saves are rate-limited) once, later or at once.
//! - **A swap keeps what the new table leaves unchanged**: the shadow is rebuilt from the new image
//!   and given the old shadow's state through `Arbiter::carry_over`, the same rule the node uses
//!   (`core/tests/swap.rs` checks that rule against an independent reference).
//! - **Only the tool transfers**: a push from any other source gets no answer and changes nothing.
//! - **The node's answer is the documented one.** A transfer that arrives whole, untampered, to a
//!   node not busy with another, is answered with the status `docs/can-protocol.md` ("What the
//!   node checks, in order") gives its image, computed here from the loader alone.
//! - **The node boots with a stored image exactly when a transfer of it would be applied.**
//! - **Everything the node sends decodes** and comes from its id; `Step::Store` never comes while
//!   a store is still owed.
//!
//! The target `node_fd` ([`check_fd`]) runs the same script on the node built with the feature
//! `fd`, and makes it CAN FD's too: transfers in CAN FD frames of any TX_DL (with or without the
//! bit-rate switch) or classic ones, a transfer's frame changed into the other kind (a classic
//! consecutive frame in a CAN FD transfer, or the reverse), and frames of up to 64 bytes on the
//! topics and the protocol's identifiers. On top of the properties above: every flow control the
//! node answers an untampered transfer with is of that transfer's kind (a CAN FD one with its
//! bit-rate switch for a CAN FD transfer, a classic one for a classic transfer).

use arbitrary::{Result, Unstructured};
use embedded_can::{ExtendedId, Id, StandardId};
use pab_app::{BusError, Config, Node, Recipient, Step};
use pab_core::image::{self, LoadError, Loaded};
use pab_core::isotp::fd::TxDl;
use pab_core::isotp::{FdSender, Sender, TxConfig, TxEvent};
use pab_core::protocol::{
    self, FrameId, FrameKind, Message, Service, TransferStatus, TransferStatusCode,
};
use pab_core::{Arbiter, BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, Frame, Instant};

use crate::examples::examples;
use crate::isotp_rx::next_time;

const IMG: usize = 8192;
type TestNode = Node<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES, IMG>;
type Shadow = Arbiter<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;
type BoardLoaded = Loaded<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;

/// The node's id.
pub const NODE_ID: u8 = 5;

/// Runs the fuzzer's script against one node.
pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data), false);
}

/// Runs the fuzzer's script against one node, with CAN FD transfers and frames among the
/// classic ones (the target `node_fd`).
pub fn check_fd(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data), true);
}

/// How a push sends its frames: classic ISO-TP, or CAN FD frames of TX_DL bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Framing {
    Classic,
    Fd { tx_dl: TxDl, brs: bool },
}

/// What a push does to one of its frames.
#[derive(Clone, Debug)]
enum Tamper {
    /// Not sent.
    Drop,
    /// Sent as a classic frame with these bytes.
    Bytes([u8; 8]),
    /// The same bytes in the other kind of frame: a CAN FD frame's first 8 bytes as a classic
    /// frame, a classic frame's as a CAN FD one.
    OtherKind,
    /// Sent as a CAN FD frame with these bytes (padded to a CAN FD length).
    FdBytes(Vec<u8>),
}

/// The examples' images, for this node, version 1 (their tables as `pabctl compile` wrote them).
fn base_images() -> &'static [Vec<u8>] {
    static IMAGES: std::sync::OnceLock<Vec<Vec<u8>>> = std::sync::OnceLock::new();
    IMAGES.get_or_init(|| {
        examples()
            .images
            .iter()
            .map(|bytes| {
                let loaded: Loaded = image::load(bytes).expect("an example image loads");
                assert_eq!(loaded.header.node_id, NODE_ID);
                assert_eq!(loaded.header.table_version, 1);
                bytes.clone()
            })
            .collect()
    })
}

/// The status `docs/can-protocol.md` gives a whole image, in its order of checks: length against
/// the buffer, header, node id, length and CRC, loader, version. `running`: (version, CRC).
fn documented_status(bytes: &[u8], running: Option<(u32, u32)>) -> (TransferStatusCode, u8) {
    use TransferStatusCode::*;
    if bytes.len() > IMG {
        return (TooLarge, 0);
    }
    let by_load_error = |error: LoadError| match error {
        LoadError::Truncated { .. } => (BadHeader, 1),
        LoadError::TrailingBytes { .. } => (BadHeader, 2),
        LoadError::BadMagic => (BadHeader, 3),
        LoadError::UnsupportedFormat { .. } => (BadHeader, 4),
        LoadError::ReservedByte => (BadHeader, 5),
        LoadError::TooLarge { .. } => (TooLarge, 0),
        LoadError::Crc { .. } => (CrcMismatch, 0),
        LoadError::Body(_) => (InvalidTable, 1),
        LoadError::BodyTrailingBytes => (InvalidTable, 2),
        LoadError::Table(_) => (InvalidTable, 3),
        LoadError::ExceedsCapacity { .. } => (InvalidTable, 4),
    };
    let header = match image::read_header(bytes) {
        Ok(header) => header,
        Err(error) => return by_load_error(error),
    };
    if header.node_id != NODE_ID {
        return (WrongNode, header.node_id);
    }
    if let Err(error) = image::load::<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>(bytes) {
        return by_load_error(error);
    }
    let (version, crc) = running.unwrap_or((0, 0));
    if running.is_some() && header.table_version == version && header.crc == crc {
        return (AlreadyCurrent, 0);
    }
    if header.table_version <= version {
        return (OlderVersion, 0);
    }
    (Applied, 0)
}

/// Records the ports each frame is delivered to.
#[derive(Default)]
struct Ports(Vec<u8>);

impl Recipient for Ports {
    fn deliver(&mut self, port: u8, _frame: &Frame, _now: Instant) {
        self.0.push(port);
    }
}

struct World {
    node: TestNode,
    shadow: Option<Shadow>,
    now: u64,
    /// `Step::Store` came and `stored` has not been called yet.
    store_owed: bool,
    /// A table was swapped in and its `Step::Store` has not come yet (saves are rate-limited).
    store_pending: bool,
    /// Transfer statuses the node sent, with their destination.
    statuses: Vec<(u8, TransferStatus)>,
    /// ISO-TP frames (flow controls) the node sent: their destination, bytes, and whether
    /// the frame was CAN FD and had its bit-rate switch.
    flow_controls: Vec<(u8, [u8; 8], bool, bool)>,
}

fn running_key(node: &TestNode) -> Option<(u32, u32)> {
    node.running()
        .map(|running| (running.header.table_version, running.header.crc))
}

/// What a node does with its BLE groups after each frame and poll: its claims due, and the
/// holding decisions brought up to `at` (what it sends is checked by [`World::drain`]).
fn ble_duties(shadow: &mut Shadow, at: Instant) {
    // As the node: the work due by `at`, seen from the microsecond before, so that a claim going
    // stale at exactly `at` is due then.
    let before = Instant::from_micros(at.as_micros().wrapping_sub(1));
    let due = shadow
        .ble_deadline(before)
        .is_some_and(|due| at.micros_since(due).is_some());
    if shadow.has_groups() && due {
        shadow.ble_poll(at, |_| {});
    }
}

/// What a node does with its competitive dynamics after its BLE duties: the groups it runs
/// stepped, and the silences of those it reads counted, unless their deadline is still ahead.
fn dynamics_duties(shadow: &mut Shadow, at: Instant) {
    let ahead = shadow
        .dynamics_deadline(at)
        .is_some_and(|due| at.micros_since(due).is_none());
    if shadow.has_dynamics() && !ahead {
        shadow.dynamics_poll(at, |_| {}, |_| {}, |_| {});
    }
}

fn shadow_of(bytes: &[u8]) -> Shadow {
    let loaded: BoardLoaded = image::load(bytes)
        .unwrap_or_else(|error| panic!("the node runs an image that does not load: {error}"));
    Arbiter::new(loaded.table).expect("a loaded table builds an arbiter")
}

/// The names of the counts that are not zero: what a script reached, for choosing seeds
/// (`examples/seeds.rs`).
pub(crate) fn reached<const N: usize>(
    counts: [(&'static str, usize); N],
) -> std::collections::BTreeSet<&'static str> {
    counts
        .into_iter()
        .filter(|&(_, count)| count > 0)
        .map(|(name, _)| name)
        .collect()
}

/// A frame of ours that a node under check sent (`kind` is its `protocol::classify`), held to what
/// every node target asks of them: a BLE claim well formed and under [`NODE_ID`] (`None`), any
/// other frame decoded and from [`NODE_ID`]. Panics, the fuzzer's failure, otherwise.
pub(crate) fn sent_by_node(frame: &Frame, kind: FrameKind) -> Option<(FrameId, Message)> {
    if kind == FrameKind::Claim {
        let claim = pab_core::ble::Claim::decode(frame)
            .unwrap_or_else(|error| panic!("the node sent {frame:?}: {error:?}"));
        assert_eq!(claim.node, NODE_ID, "a claim under another node's id");
        return None;
    }
    let (id, message) =
        Message::decode(frame).unwrap_or_else(|error| panic!("the node sent {frame:?}: {error}"));
    assert_eq!(id.source, NODE_ID, "the node sent {frame:?}");
    Some((id, message))
}

impl World {
    fn at(&self) -> Instant {
        Instant::from_micros(self.now)
    }

    /// Collects what the node sent; every protocol frame must decode and come from the node.
    fn drain(&mut self) {
        while let Some(frame) = self.node.next_outgoing() {
            let kind = protocol::classify(&frame);
            if !kind.is_ours() {
                continue; // a gateway port's re-publication
            }
            // A BLE claim of a table with groups: well formed, and this node's.
            let Some((id, message)) = sent_by_node(&frame, kind) else {
                continue;
            };
            match message {
                Message::TransferStatus(status) => self.statuses.push((id.destination, status)),
                Message::TableTransfer { data, len } => {
                    assert_eq!(len, 8, "flow controls are padded");
                    self.flow_controls
                        .push((id.destination, data, frame.is_fd(), frame.is_brs()));
                }
                Message::Gates(gates) => {
                    let runs = self
                        .shadow
                        .as_ref()
                        .map_or(&[][..], |s| s.table().dynamics());
                    assert!(
                        runs.iter().any(|group| group.number == gates.group
                            && group.params.behaviours.len() == usize::from(gates.behaviours)),
                        "the node sent {gates:?}, not of a group it runs"
                    );
                }
                _ => {}
            }
        }
    }

    /// One frame from the bus, now.
    fn feed(&mut self, u: &mut Unstructured<'_>, frame: &Frame) -> Result<()> {
        let before = running_key(&self.node);
        let mut ports = Ports::default();
        let step = self.node.on_frame(frame, self.at(), &mut ports);
        let kind = protocol::classify(frame);
        if kind.is_ours() {
            // Never delivered itself; value outputs that aged out by now may be.
            // (After a swap the new arbiter has no values yet: nothing.)
            let mut expected = Vec::new();
            let at = self.at();
            if running_key(&self.node) == before
                && let Some(shadow) = self.shadow.as_mut()
            {
                // A peer's BLE claim goes to the group state, as on the node.
                if kind == FrameKind::Claim
                    && let Ok(claim) = pab_core::ble::Claim::decode(frame)
                {
                    let _ = shadow.on_claim(claim, at);
                }
                // Gates from another node, broadcast or to this one, go to the gate sources.
                if let Ok((id, Message::Gates(gates))) = Message::decode(frame)
                    && id.is_for(NODE_ID)
                    && id.source != NODE_ID
                {
                    let _ = shadow.on_gates(id.source, &gates, at);
                }
                shadow.poll(at, |output| expected.push(output.port));
                ble_duties(shadow, at);
                dynamics_duties(shadow, at);
            }
            assert_eq!(ports.0, expected, "a protocol frame was delivered");
        } else {
            let mut expected = Vec::new();
            let at = self.at();
            if let Some(shadow) = self.shadow.as_mut() {
                // Value ports' outputs first (the node hands them over before the frame's
                // deliveries), then the ports the frame is delivered to, then the value ports
                // whose deadline passed.
                let mut delivered = shadow
                    .receive_frame(frame, at, |_| {}, |output| expected.push(output.port))
                    .delivered
                    .bits();
                let mut ordinary = Vec::new();
                while delivered != 0 {
                    ordinary.push(delivered.trailing_zeros() as u8);
                    delivered &= delivered - 1;
                }
                expected.extend(ordinary);
                if shadow.has_groups() {
                    shadow.ble_frame(frame, at);
                }
                if shadow.has_dynamics() {
                    shadow.dynamics_frame(frame, at);
                }
                shadow.poll(at, |output| expected.push(output.port));
                ble_duties(shadow, at);
                dynamics_duties(shadow, at);
            }
            assert_eq!(ports.0, expected, "deliveries of {frame:?} at {}", self.now);
        }
        let after = running_key(&self.node);
        if after != before {
            self.swapped(frame, before);
        }
        self.on_step(step);
        if self.store_owed && u.int_in_range(0u8..=7)? > 0 {
            self.finish_store(u)?;
        }
        self.drain();
        Ok(())
    }

    /// The running table changed during `frame`: it must be a transfer's last frame, and the new
    /// table an image a transfer may apply.
    fn swapped(&mut self, frame: &Frame, before: Option<(u32, u32)>) {
        assert!(
            matches!(protocol::classify(frame), FrameKind::Service(id)
                if id.service == Service::TableTransfer && id.source == protocol::TOOL),
            "the table changed on {frame:?}"
        );
        assert!(
            !self.store_owed && !self.store_pending,
            "a second table before the first was stored"
        );
        let bytes = self.node.image_to_store().to_vec();
        let (status, _) = documented_status(&bytes, before);
        assert_eq!(
            status,
            TransferStatusCode::Applied,
            "the node applied a refusable image"
        );
        let running = self.node.running().expect("a table runs after a swap");
        let header = image::read_header(&bytes).expect("the stored image has a header");
        assert_eq!(running.header, header);
        assert_eq!(running.image_len as usize, bytes.len());
        assert!(!running.stored);
        let mut shadow = shadow_of(&bytes);
        if let Some(previous) = self.shadow.as_ref() {
            shadow.carry_over(previous);
        }
        // The node's duties after the frame ran on the new table.
        dynamics_duties(&mut shadow, self.at());
        self.shadow = Some(shadow);
        self.store_pending = true;
    }

    /// What a `Step` from `on_frame` or `poll` asks: `Store` only for a swapped-in table whose
    /// save has not been asked for yet.
    fn on_step(&mut self, step: Step) {
        if step == Step::Store {
            assert!(
                !self.store_owed,
                "a second Store before the first was stored"
            );
            assert!(self.store_pending, "a Store without a new table");
            let running = self
                .node
                .running()
                .expect("a table runs when it is to be stored");
            let header = image::read_header(self.node.image_to_store())
                .expect("the image to store has a header");
            assert_eq!(
                running.header, header,
                "the image to store is the running one"
            );
            self.store_pending = false;
            self.store_owed = true;
        }
    }

    fn finish_store(&mut self, u: &mut Unstructured<'_>) -> Result<()> {
        if !self.store_owed {
            return Ok(());
        }
        let ok = u.int_in_range(0u8..=7)? > 0;
        let before = running_key(&self.node);
        let answers = self.statuses.len();
        self.node.stored(ok, self.at());
        self.store_owed = false;
        self.drain();
        assert_eq!(running_key(&self.node), before);
        assert_eq!(self.node.running().map(|running| running.stored), Some(ok));
        let expected = if ok {
            TransferStatusCode::Applied
        } else {
            TransferStatusCode::AppliedNotStored
        };
        let position = self.statuses[answers..]
            .iter()
            .position(|(_, status)| status.status == expected);
        assert!(position.is_some(), "no {expected:?} after the store");
        // That answer belongs to the transfer whose table was stored, which may have ended long
        // ago (saves are rate-limited): a push under way must not take it for its own.
        if let Some(position) = position {
            self.statuses.remove(answers + position);
        }
        Ok(())
    }

    /// Time passes up to `t`: the node is polled at each of its deadlines on the way (when `t` is
    /// a little later), or once (a jump, or a clock set back).
    fn advance(&mut self, t: u64) {
        let before = running_key(&self.node);
        let forward = t.wrapping_sub(self.now);
        if forward <= 2_000_000 {
            for _ in 0..2_000 {
                let deadline = self.node.deadline(self.at()).as_micros();
                let ahead = deadline.wrapping_sub(self.now);
                if ahead > forward || ahead > 1 << 63 {
                    break;
                }
                self.now = deadline;
                let step = self.poll_both();
                self.on_step(step);
                self.drain();
            }
        }
        self.now = t;
        let step = self.poll_both();
        self.on_step(step);
        self.drain();
        assert_eq!(running_key(&self.node), before, "a poll changed the table");
    }

    /// Polls the node and the shadow at the same instant: the value ports' outputs the node
    /// hands over are the shadow's.
    fn poll_both(&mut self) -> Step {
        let at = self.at();
        let mut ports = Ports::default();
        let step = self.node.poll(at, &mut ports);
        let mut expected = Vec::new();
        if let Some(shadow) = self.shadow.as_mut() {
            shadow.poll(at, |output| expected.push(output.port));
            ble_duties(shadow, at);
            dynamics_duties(shadow, at);
        }
        assert_eq!(ports.0, expected, "value outputs of a poll at {}", self.now);
        step
    }

    /// Pushes `bytes` from `source` with pab-core's ISO-TP sender (classic, or CAN FD by
    /// `framing`), delivering the node's flow controls; `tamper`: a frame index and what is done
    /// to that frame.
    fn push(
        &mut self,
        u: &mut Unstructured<'_>,
        bytes: &[u8],
        source: u8,
        tamper: Option<(usize, Tamper)>,
        framing: Framing,
    ) -> Result<()> {
        enum Either<'a> {
            Classic(Sender<'a>),
            Fd(FdSender<'a>),
        }
        let sender = match framing {
            Framing::Classic => Sender::new(bytes, TxConfig::default()).map(Either::Classic),
            Framing::Fd { tx_dl, .. } => {
                FdSender::new(bytes, TxConfig::default(), tx_dl).map(Either::Fd)
            }
        };
        let Ok(mut sender) = sender else {
            return Ok(());
        };
        let brs = matches!(framing, Framing::Fd { brs: true, .. });
        let transfer_id = Message::TableTransfer {
            data: [0; 8],
            len: 8,
        }
        .to_frame(source, NODE_ID)
        .id();
        let running = running_key(&self.node);
        let answers = self.statuses.len();
        let flow_controls = self.flow_controls.len();
        let mut index = 0;
        let mut seen = self.flow_controls.len();
        for _ in 0..10_000 {
            let event = match &mut sender {
                Either::Classic(sender) => match sender.poll(self.at()) {
                    TxEvent::Send(data) => TxEvent::Send(Frame::data(transfer_id, &data)),
                    TxEvent::WaitUntil(at) => TxEvent::WaitUntil(at),
                    TxEvent::Done => TxEvent::Done,
                    TxEvent::Failed(error) => TxEvent::Failed(error),
                },
                Either::Fd(sender) => match sender.poll(self.at()) {
                    TxEvent::Send(data) => {
                        TxEvent::Send(Frame::fd(transfer_id, data.as_bytes(), brs))
                    }
                    TxEvent::WaitUntil(at) => TxEvent::WaitUntil(at),
                    TxEvent::Done => TxEvent::Done,
                    TxEvent::Failed(error) => TxEvent::Failed(error),
                },
            };
            match event {
                TxEvent::Send(frame) => {
                    let frame = match &tamper {
                        Some((at, change)) if *at == index => {
                            frame.and_then(|frame| tampered(&frame, change, brs))
                        }
                        _ => frame,
                    };
                    index += 1;
                    if let Some(frame) = frame {
                        self.feed(u, &frame)?;
                    }
                    self.advance(self.now.wrapping_add(100));
                }
                TxEvent::WaitUntil(until) => {
                    let next = self.flow_controls[seen..]
                        .iter()
                        .position(|(to, ..)| *to == source);
                    if let Some(offset) = next {
                        let (_, fc, ..) = self.flow_controls[seen + offset];
                        seen += offset + 1;
                        match &mut sender {
                            Either::Classic(sender) => sender.on_flow_control(&fc, self.at()),
                            Either::Fd(sender) => sender.on_flow_control(&fc, self.at()),
                        };
                    } else {
                        let wait = until.as_micros().wrapping_sub(self.now).clamp(1, 2_000_000);
                        self.advance(self.now.wrapping_add(wait));
                    }
                }
                TxEvent::Done | TxEvent::Failed(_) => break,
            }
        }
        if tamper.is_some() {
            return Ok(());
        }
        // An untampered transfer's flow controls are of its kind (a node answers in the kind of
        // frame the transfer came in).
        if source == protocol::TOOL {
            let fd = framing != Framing::Classic;
            for (to, fc, is_fd, is_brs) in &self.flow_controls[flow_controls..] {
                if *to == source && fc[0] & 0xF0 == 0x30 {
                    assert_eq!(
                        (*is_fd, *is_brs),
                        (fd, brs),
                        "a flow control of another kind than its {framing:?} transfer"
                    );
                }
            }
        }
        // The node's last answer to this source during the push, unless it was busy with another
        // transfer, or a store it still owes.
        let answer = self.statuses[answers..]
            .iter()
            .rev()
            .find(|(to, _)| *to == source)
            .map(|(_, status)| *status);
        if source != protocol::TOOL {
            assert_eq!(answer, None, "a push from source {source} was answered");
            assert_eq!(
                running_key(&self.node),
                running,
                "a push from source {source} applied"
            );
            return Ok(());
        }
        let Some(answer) = answer else { return Ok(()) };
        use TransferStatusCode::*;
        if matches!(answer.status, Busy | Interrupted | Timeout) {
            return Ok(());
        }
        let (expected, detail) = documented_status(bytes, running);
        let expected = match (expected, answer.status) {
            (Applied, AppliedNotStored) => AppliedNotStored,
            (other, _) => other,
        };
        assert_eq!(
            (answer.status, answer.detail),
            (expected, detail),
            "the answer to a whole transfer of {} bytes",
            bytes.len()
        );
        Ok(())
    }
}

/// `frame` (a transfer's, CAN FD with `brs` or classic) changed as `change` says; `None`:
/// dropped.
fn tampered(frame: &Frame, change: &Tamper, brs: bool) -> Option<Frame> {
    match change {
        Tamper::Drop => None,
        Tamper::Bytes(data) => Frame::data(frame.id(), data),
        Tamper::OtherKind if frame.is_fd() => {
            let data = frame.payload();
            Frame::data(frame.id(), data.get(..8).unwrap_or(data))
        }
        Tamper::OtherKind => Frame::fd(frame.id(), frame.payload(), brs),
        Tamper::FdBytes(data) => Frame::fd(frame.id(), data, brs),
    }
}

/// An image made from an example's: a version near the running one, sometimes another node id,
/// a few byte changes, insertions, deletions or a cut, and (mostly) the length and CRC made right
/// again so that the changes reach the loader.
pub(crate) fn mutated_image(u: &mut Unstructured<'_>, running_version: u32) -> Result<Vec<u8>> {
    let mut bytes = u.choose(base_images())?.clone();
    let version = match u.int_in_range(0u8..=7)? {
        0..=3 => running_version.wrapping_add(1),
        4 => running_version,
        5 => running_version.wrapping_sub(1),
        _ => u.arbitrary()?,
    };
    bytes[8..12].copy_from_slice(&version.to_le_bytes());
    if u.ratio(1u8, 8)? {
        bytes[6] = u.arbitrary()?;
    }
    for _ in 0..u.int_in_range(0u8..=4)? {
        let at = u.int_in_range(0..=bytes.len())?;
        match u.int_in_range(0u8..=5)? {
            0..=2 if at < bytes.len() => bytes[at] = u.arbitrary()?,
            3 => bytes.insert(at, u.arbitrary()?),
            4 if at < bytes.len() => {
                bytes.remove(at);
            }
            _ => bytes.truncate(at),
        }
    }
    if u.int_in_range(0u8..=7)? > 0 {
        bytes = crate::image::fix_up(&bytes);
    } else if bytes.len() >= 20 && u.ratio(1u8, 2)? {
        // The body length right, the CRC not recomputed.
        let body = u32::try_from(bytes.len() - 20).unwrap_or(u32::MAX);
        bytes[12..16].copy_from_slice(&body.to_le_bytes());
    }
    Ok(bytes)
}

pub(crate) fn any_id(u: &mut Unstructured<'_>) -> Result<Id> {
    let topics = &examples().topics;
    Ok(match u.int_in_range(0u8..=7)? {
        0..=5 if !topics.is_empty() => {
            let &(id, extended) = u.choose(topics)?;
            if extended {
                Id::Extended(ExtendedId::new(id).unwrap_or(ExtendedId::ZERO))
            } else {
                Id::Standard(StandardId::new(id as u16).unwrap_or(StandardId::ZERO))
            }
        }
        6 => Id::Standard(StandardId::new(u.int_in_range(0..=0x7FF)?).unwrap_or(StandardId::ZERO)),
        _ => Id::Extended(
            ExtendedId::new(u.int_in_range(0..=0x1FFF_FFFF)?).unwrap_or(ExtendedId::ZERO),
        ),
    })
}

pub(crate) fn payload(u: &mut Unstructured<'_>) -> Result<Vec<u8>> {
    let len = u.int_in_range(0..=8)?;
    (0..len).map(|_| u.arbitrary()).collect()
}

/// Up to 64 bytes, for a CAN FD frame (padded to a CAN FD length by `Frame::fd`).
fn fd_payload(u: &mut Unstructured<'_>) -> Result<Vec<u8>> {
    let len = u.int_in_range(0..=64)?;
    (0..len).map(|_| u.arbitrary()).collect()
}

/// `frame` as a CAN FD frame of the same identifier now and then, with a longer payload from the
/// input or its own (the target `node_fd`).
fn maybe_fd(u: &mut Unstructured<'_>, frame: Frame) -> Result<Frame> {
    if !u.ratio(1u8, 3)? {
        return Ok(frame);
    }
    let data = if u.arbitrary()? {
        fd_payload(u)?
    } else {
        frame.payload().to_vec()
    };
    Ok(Frame::fd(frame.id(), &data, u.arbitrary()?).unwrap_or(frame))
}

/// A transfer's framing: classic a quarter of the time, else CAN FD at any TX_DL.
fn framing(u: &mut Unstructured<'_>) -> Result<Framing> {
    if u.ratio(1u8, 4)? {
        return Ok(Framing::Classic);
    }
    let tx_dl = *u.choose(&[8usize, 12, 16, 20, 24, 32, 48, 64])?;
    Ok(Framing::Fd {
        tx_dl: TxDl::new(tx_dl).unwrap_or(TxDl::MAX),
        brs: u.ratio(3u8, 4)?,
    })
}

/// A frame of our protocol: any service, mostly to this node or everyone, any priority.
pub(crate) fn protocol_frame(u: &mut Unstructured<'_>) -> Result<Frame> {
    let service = *u.choose(&Service::ALL)?;
    let destination = match u.int_in_range(0u8..=3)? {
        0 | 1 => NODE_ID,
        2 => protocol::BROADCAST,
        _ => u.arbitrary()?,
    };
    let source = if u.ratio(1u8, 2)? {
        protocol::TOOL
    } else {
        u.arbitrary()?
    };
    let raw = FrameId::new(service, source, destination).raw() & !(0b111 << 26)
        | u32::from(u.int_in_range(0u8..=7)?) << 26;
    let data = match service {
        Service::DiagnosticControl if u.ratio(3u8, 4)? => {
            let rate: u16 = u.int_in_range(0..=210)?;
            let ports: u16 = u.arbitrary()?;
            let [a, b] = rate.to_le_bytes();
            let [c, d] = ports.to_le_bytes();
            vec![a, b, c, d]
        }
        _ => payload(u)?,
    };
    Ok(Frame::with_raw_id(raw, true, &data).unwrap_or_else(|| unreachable!("29 bits, 8 bytes")))
}

/// A well-formed Gates frame, mostly of a group the running table runs or reads (from the
/// source's owner, or any node), with its count or now and then another.
fn gates_frame(u: &mut Unstructured<'_>, shadow: Option<&Shadow>) -> Result<Frame> {
    let mut known: Vec<(u8, u8, u8)> = Vec::new();
    if let Some(shadow) = shadow {
        let table = shadow.table();
        known.extend(table.dynamics().iter().map(|g| {
            (
                NODE_ID,
                g.number,
                u8::try_from(g.params.behaviours.len()).unwrap_or(32),
            )
        }));
        known.extend(
            table
                .gate_sources()
                .iter()
                .map(|s| (s.owner, s.group, s.behaviours)),
        );
    }
    let (mut owner, group, mut behaviours) = if !known.is_empty() && u.ratio(3u8, 4)? {
        *u.choose(&known)?
    } else {
        (
            u.int_in_range(1..=127)?,
            u.arbitrary()?,
            u.int_in_range(1..=32)?,
        )
    };
    if owner == NODE_ID || owner == 0 || u.ratio(1u8, 8)? {
        owner = u.int_in_range(1..=127)?;
    }
    if u.ratio(1u8, 8)? {
        behaviours = u.int_in_range(1..=32)?;
    }
    let mask = u.arbitrary::<u32>()? & (u32::MAX >> (32 - u32::from(behaviours)));
    let gates = protocol::Gates {
        group,
        behaviours,
        mask,
        changes: u.arbitrary()?,
    };
    Ok(Message::Gates(gates).to_frame(owner, protocol::BROADCAST))
}

fn run(u: &mut Unstructured<'_>, fd: bool) -> Result<()> {
    let config = Config::new(NODE_ID).expect("node 5 is valid");
    let now: u64 = if u.ratio(1u8, 4)? { u.arbitrary()? } else { 0 };
    let mut node = TestNode::new(config, Instant::from_micros(now));
    // Boot: no stored image, or one made like the pushed ones.
    let stored = if u.ratio(1u8, 4)? {
        None
    } else {
        let bytes = mutated_image(u, 0)?;
        Some(bytes).filter(|bytes| bytes.len() <= IMG)
    };
    if let Some(bytes) = &stored {
        node.boot_buffer()[..bytes.len()].copy_from_slice(bytes);
    }
    node.boot(stored.as_ref().map(Vec::len), Instant::from_micros(now));
    let shadow = match &stored {
        Some(bytes) => {
            let applies = documented_status(bytes, None).0 == TransferStatusCode::Applied;
            assert_eq!(
                node.running().is_some(),
                applies,
                "boot with {} bytes",
                bytes.len()
            );
            applies.then(|| {
                // The node's duties at boot.
                let mut shadow = shadow_of(bytes);
                dynamics_duties(&mut shadow, Instant::from_micros(now));
                shadow
            })
        }
        None => None,
    };
    assert_eq!(node.running().is_some(), shadow.is_some());
    let mut world = World {
        node,
        shadow,
        now,
        store_owed: false,
        store_pending: false,
        statuses: Vec::new(),
        flow_controls: Vec::new(),
    };
    world.drain();
    for _ in 0..300 {
        if u.is_empty() {
            break;
        }
        match u.int_in_range(0u8..=15)? {
            0..=6 => {
                let id = any_id(u)?;
                let data = payload(u)?;
                let mut frame = Frame::data(id, &data).unwrap_or_else(|| unreachable!("8 bytes"));
                if fd {
                    frame = maybe_fd(u, frame)?;
                }
                world.feed(u, &frame)?;
            }
            7..=8 => {
                let mut frame = if u.ratio(1u8, 3)? {
                    gates_frame(u, world.shadow.as_ref())?
                } else {
                    protocol_frame(u)?
                };
                if fd {
                    frame = maybe_fd(u, frame)?;
                }
                world.feed(u, &frame)?;
            }
            9..=10 => {
                let t = next_time(u, world.now)?;
                world.advance(t);
            }
            11..=12 => {
                let version = world.node.running().map_or(0, |r| r.header.table_version);
                let bytes = mutated_image(u, version)?;
                let source = match u.int_in_range(0u8..=7)? {
                    0 => u.arbitrary()?,
                    _ => protocol::TOOL,
                };
                let framing = if fd { framing(u)? } else { Framing::Classic };
                let tamper = if u.ratio(1u8, 8)? {
                    let at = u.int_in_range(0..=bytes.len() / 7)?;
                    let change = if !fd {
                        if u.arbitrary()? {
                            Tamper::Bytes(u.arbitrary()?)
                        } else {
                            Tamper::Drop
                        }
                    } else {
                        match u.int_in_range(0u8..=3)? {
                            0 => Tamper::Drop,
                            1 => Tamper::Bytes(u.arbitrary()?),
                            2 => Tamper::OtherKind,
                            _ => Tamper::FdBytes(fd_payload(u)?),
                        }
                    };
                    Some((at, change))
                } else {
                    None
                };
                world.push(u, &bytes, source, tamper, framing)?;
            }
            13 => {
                let error = match u.int_in_range(0u8..=5)? {
                    0 => BusError::Overrun,
                    1 => BusError::ErrorPassive,
                    2 => BusError::BusOff,
                    3 => BusError::Recovered,
                    4 => BusError::Other(u.arbitrary()?),
                    _ => {
                        world.node.on_transmit_error(world.at());
                        world.drain();
                        continue;
                    }
                };
                world.node.on_bus_error(error, world.at());
                world.drain();
            }
            _ => world.finish_store(u)?,
        }
    }
    Ok(())
}
