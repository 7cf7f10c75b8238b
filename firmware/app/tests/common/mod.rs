//! An in-process bus with virtual time around one node: frames in, frames out, every decision made
//! by the node's own code. Tables are built with pab-core and pushed with pab-core's ISO-TP sender.
#![allow(dead_code)]

use pab_app::{Config, Node, Recipient, Step};
use pab_core::auth::{Authenticator, Key};
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{
    self, AuthFailure, DiagnosticControl, FaultCode, FrameId, Message, TransferOpen, TransferStatus,
};
use pab_core::{
    Connection, Consumer as PortConsumer, DecisionNode, Filter, Frame, Instant, NodeRef, OutputId,
    Stimulation, Table,
};

/// Board capacities: 4 ports, 64 connections, 256 decision nodes, 8 KiB images.
pub type TestNode = Node<4, 64, 256, 8192>;
pub type TestTable = Table<4, 64, 256>;

pub const TOPIC_A: u32 = 0x100;
pub const TOPIC_B: u32 = 0x101;
pub const GATEWAY_OUT: u32 = 0x300;

/// One port, connections in priority order (connection 0 wins over 1...), each fed by one
/// standard id, every one with σ = 1 (active at its first frame), τ = 0.5 s, no rest.
pub fn priority_table(ids: &[u32], republish: Option<u32>) -> TestTable {
    let stimulation = Stimulation::from_seconds(1.0, 0.5, 0.0).unwrap();
    let connections: Vec<Connection> = ids
        .iter()
        .map(|&id| Connection {
            filter: Filter::exact(id, false).unwrap(),
            stimulation,
        })
        .collect();
    // Node k tests connection k: active → deliver k, else go on to node k+1.
    let nodes: Vec<DecisionNode> = (0..ids.len())
        .map(|k| DecisionNode {
            var: k as u8,
            high: NodeRef::deliver(k as u8).unwrap(),
            low: if k + 1 < ids.len() {
                NodeRef::node(k as u16 + 1).unwrap()
            } else {
                NodeRef::NOBODY
            },
        })
        .collect();
    let mut table = TestTable::new();
    table
        .push_port(&connections, &nodes, NodeRef::node(0).unwrap())
        .unwrap();
    if let Some(id) = republish {
        table
            .set_consumer(
                0,
                PortConsumer::Republish(OutputId::new(id, false).unwrap()),
            )
            .unwrap();
    }
    table
}

/// The image of `table` for `node_id`, version `version`.
pub fn image<const P: usize, const C: usize, const N: usize>(
    table: &Table<P, C, N>,
    node_id: u8,
    version: u32,
) -> Vec<u8> {
    let mut out = vec![0u8; pab_core::image::MAX_IMAGE_LEN];
    let len = pab_core::image::encode(table, node_id, version, &mut out).unwrap();
    out.truncate(len);
    out
}

pub fn frame(id: u32, data: &[u8]) -> Frame {
    Frame::with_raw_id(id, false, data).unwrap()
}

/// Frames delivered to the node's application: (port, frame, time in µs).
#[derive(Default)]
pub struct Deliveries(pub Vec<(u8, Frame, u64)>);

impl Recipient for Deliveries {
    fn deliver(&mut self, port: u8, frame: &Frame, now: Instant) {
        self.0.push((port, *frame, now.as_micros()));
    }
}

/// One node on a virtual bus.
pub struct Harness {
    pub node: TestNode,
    pub now: u64,
    /// Everything the node sent, with the time.
    pub sent: Vec<(u64, Frame)>,
    pub deliveries: Deliveries,
    /// Images the node asked to store.
    pub stored: Vec<Vec<u8>>,
    /// Whether storing succeeds.
    pub store_ok: bool,
    /// Configuration records the node asked to store.
    pub settings_saved: Vec<u16>,
    /// What storing a configuration record answers (`Ok(true)`: stored).
    pub settings_result: Result<bool, pab_app::StoreError>,
    /// Restarts the node asked for after a record was stored (or an update committed).
    pub restarts: u32,
    /// The ISO-TP service `push_with` sends on: TableTransfer, or UpdateTransfer.
    pub channel: Channel,
    /// The update slot as the runner writes it (`Step::WriteUpdate`), 0xFF where unwritten.
    pub update_slot: Vec<u8>,
    /// Whether writing the update slot succeeds.
    pub update_write_ok: bool,
    /// The manifests the node asked to store with a request (`Step::RequestUpdate`).
    pub update_requests: Vec<Vec<u8>>,
}

/// Which ISO-TP service a push goes over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    Table,
    #[cfg(feature = "update")]
    Update,
}

impl Channel {
    fn message(self, data: [u8; 8]) -> Message {
        match self {
            Channel::Table => Message::TableTransfer { data, len: 8 },
            #[cfg(feature = "update")]
            Channel::Update => Message::UpdateTransfer { data, len: 8 },
        }
    }

    fn flow_control(self, message: &Message) -> Option<([u8; 8], u8)> {
        match (self, message) {
            (Channel::Table, Message::TableTransfer { data, len }) => Some((*data, *len)),
            #[cfg(feature = "update")]
            (Channel::Update, Message::UpdateTransfer { data, len }) => Some((*data, *len)),
            _ => None,
        }
    }
}

impl Harness {
    pub const NODE_ID: u8 = 5;

    /// A node booted at t = 0 with `stored` as its stored image.
    pub fn boot(stored: Option<&[u8]>) -> Harness {
        Self::boot_with(stored, |_| {})
    }

    /// A node with `key`, booted at t = 0 with boot salt `salt`.
    pub fn boot_keyed(stored: Option<&[u8]>, key: &Key, salt: u32) -> Harness {
        Self::boot_with(stored, |node| node.set_key(key, salt))
    }

    /// A node booted at t = 0 after `setup` (a key, a lock).
    pub fn boot_with(stored: Option<&[u8]>, setup: impl FnOnce(&mut TestNode)) -> Harness {
        Self::boot_config(Config::new(Self::NODE_ID).unwrap(), stored, setup)
    }

    /// A node of `config` booted at t = 0 after `setup`.
    pub fn boot_config(
        config: Config,
        stored: Option<&[u8]>,
        setup: impl FnOnce(&mut TestNode),
    ) -> Harness {
        let mut node = TestNode::new(config, Instant::from_micros(0));
        setup(&mut node);
        let len = stored.map(|bytes| {
            node.boot_buffer()[..bytes.len()].copy_from_slice(bytes);
            bytes.len()
        });
        node.boot(len, Instant::from_micros(0));
        let mut harness = Harness {
            node,
            now: 0,
            sent: Vec::new(),
            deliveries: Deliveries::default(),
            stored: Vec::new(),
            store_ok: true,
            settings_saved: Vec::new(),
            settings_result: Ok(true),
            restarts: 0,
            channel: Channel::Table,
            update_slot: vec![0xFF; 16 * 1024],
            update_write_ok: true,
            update_requests: Vec::new(),
        };
        harness.drain();
        harness
    }

    /// Runs the node's timers up to `t` µs.
    pub fn advance_to(&mut self, t: u64) {
        let mut polls_at_same_time = 0;
        loop {
            let deadline = self
                .node
                .deadline(Instant::from_micros(self.now))
                .as_micros();
            if deadline > t {
                break;
            }
            if deadline <= self.now {
                // Work due now (a diagnostic round being sent): it must finish.
                polls_at_same_time += 1;
                assert!(
                    polls_at_same_time < 10_000,
                    "the node is stuck at {} µs",
                    self.now
                );
            } else {
                polls_at_same_time = 0;
                self.now = deadline;
            }
            let step = self
                .node
                .poll(Instant::from_micros(self.now), &mut self.deliveries);
            self.store_if(step);
            self.drain();
        }
        self.now = t;
        let step = self
            .node
            .poll(Instant::from_micros(t), &mut self.deliveries);
        self.store_if(step);
        self.drain();
    }

    /// Stores the running image if the node asked for it (`Step::Store`), as a runner does.
    fn store_if(&mut self, step: Step) {
        #[cfg(feature = "identity")]
        if step == Step::SaveSettings {
            self.settings_saved.push(self.node.settings_to_store());
            if self
                .node
                .settings_stored(self.settings_result, Instant::from_micros(self.now))
            {
                self.restarts += 1;
            }
        }
        if step == Step::Store {
            self.stored.push(self.node.image_to_store().to_vec());
            self.node
                .stored(self.store_ok, Instant::from_micros(self.now));
        }
        #[cfg(feature = "update")]
        if step == Step::WriteUpdate {
            let (offset, data) = self.node.update_chunk().expect("a chunk owed");
            let at = offset as usize;
            let ok = self.update_write_ok && at + data.len() <= self.update_slot.len();
            if ok {
                self.update_slot[at..at + data.len()].copy_from_slice(data);
            }
            self.node.update_written(ok);
        }
        #[cfg(feature = "update")]
        if step == Step::RequestUpdate {
            let manifest = self
                .node
                .update_manifest()
                .expect("a manifest owed")
                .to_vec();
            self.update_requests.push(manifest);
            if self.node.update_requested(self.update_write_ok) {
                self.restarts += 1;
            }
        }
    }

    /// A frame from the bus at the current time.
    pub fn feed(&mut self, frame: &Frame) {
        let now = Instant::from_micros(self.now);
        let step = self.node.on_frame(frame, now, &mut self.deliveries);
        self.store_if(step);
        self.drain();
    }

    /// A bus error reported by the driver at the current time.
    pub fn bus_error(&mut self, error: pab_app::BusError) {
        self.node
            .on_bus_error(error, Instant::from_micros(self.now));
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(frame) = self.node.next_outgoing() {
            self.sent.push((self.now, frame));
        }
    }

    /// Our protocol's messages the node sent since `from` µs.
    pub fn messages_since(&self, from: u64) -> Vec<(u64, FrameId, Message)> {
        self.sent
            .iter()
            .filter(|(t, _)| *t >= from)
            .filter_map(|(t, frame)| {
                Message::decode(frame)
                    .ok()
                    .map(|(id, message)| (*t, id, message))
            })
            .collect()
    }

    /// The transfer statuses the node sent to `source`.
    pub fn statuses(&self, source: u8) -> Vec<TransferStatus> {
        self.messages_since(0)
            .into_iter()
            .filter_map(|(_, id, message)| match message {
                Message::TransferStatus(status) if id.destination == source => Some(status),
                _ => None,
            })
            .collect()
    }

    /// Pushes `bytes` from `source` with pab-core's ISO-TP sender, one frame per 100 µs;
    /// `tamper(harness, index, frame data)` runs before each transfer frame: it may change or
    /// drop (None) the frame, and use the harness (feed other frames between transfer frames).
    /// Returns how the sender ended.
    pub fn push_with(
        &mut self,
        bytes: &[u8],
        source: u8,
        mut tamper: impl FnMut(&mut Harness, usize, [u8; 8]) -> Option<[u8; 8]>,
    ) -> TxEvent {
        let mut sender = Sender::new(bytes, TxConfig::default()).unwrap();
        let mut index = 0;
        let mut seen = self.sent.len();
        loop {
            let event = sender.poll(Instant::from_micros(self.now));
            match event {
                TxEvent::Send(data) => {
                    if let Some(data) = tamper(self, index, data) {
                        let frame = self.channel.message(data).to_frame(source, Self::NODE_ID);
                        self.feed(&frame);
                    }
                    index += 1;
                    self.advance_to(self.now + 100);
                }
                TxEvent::WaitUntil(until) => {
                    // Deliver the node's flow control, if it sent one.
                    let mut delivered = false;
                    while seen < self.sent.len() {
                        let (_, frame) = self.sent[seen];
                        seen += 1;
                        if let Ok((id, message)) = Message::decode(&frame)
                            && let Some((data, len)) = self.channel.flow_control(&message)
                            && id.destination == source
                        {
                            {
                                sender.on_flow_control(
                                    &data[..len as usize],
                                    Instant::from_micros(self.now),
                                );
                                delivered = true;
                            }
                        }
                    }
                    if !delivered {
                        self.advance_to(until.as_micros().max(self.now + 1));
                    }
                }
                TxEvent::Done | TxEvent::Failed(_) => return event,
            }
        }
    }

    pub fn push(&mut self, bytes: &[u8]) -> TxEvent {
        self.push_with(bytes, protocol::TOOL, |_, _, data| Some(data))
    }

    /// [`Harness::push_with`] in CAN FD frames of `tx_dl` bytes with the bit-rate switch, by
    /// pab-core's [`FdSender`](pab_core::isotp::FdSender): `tamper(harness, index, frame)` may
    /// change the frame (its kind too) or drop it. The node's flow controls are taken whatever
    /// their kind, and kept in `flow_controls` as they came.
    #[cfg(feature = "fd")]
    pub fn push_fd_with(
        &mut self,
        bytes: &[u8],
        source: u8,
        tx_dl: pab_core::isotp::fd::TxDl,
        mut tamper: impl FnMut(&mut Harness, usize, Frame) -> Option<Frame>,
    ) -> (TxEvent<pab_core::isotp::fd::FdFrame>, Vec<Frame>) {
        let mut sender = pab_core::isotp::FdSender::new(bytes, TxConfig::default(), tx_dl).unwrap();
        let id = self
            .channel
            .message([0; 8])
            .to_frame(source, Self::NODE_ID)
            .id();
        let mut index = 0;
        let mut seen = self.sent.len();
        let mut flow_controls = Vec::new();
        loop {
            let event = sender.poll(Instant::from_micros(self.now));
            match event {
                TxEvent::Send(data) => {
                    let frame = Frame::fd(id, data.as_bytes(), true).unwrap();
                    if let Some(frame) = tamper(self, index, frame) {
                        self.feed(&frame);
                    }
                    index += 1;
                    self.advance_to(self.now + 100);
                }
                TxEvent::WaitUntil(until) => {
                    let mut delivered = false;
                    while seen < self.sent.len() {
                        let (_, frame) = self.sent[seen];
                        seen += 1;
                        if let Ok((id, message)) = Message::decode(&frame)
                            && self.channel.flow_control(&message).is_some()
                            && id.destination == source
                        {
                            flow_controls.push(frame);
                            sender.on_flow_control(frame.payload(), Instant::from_micros(self.now));
                            delivered = true;
                        }
                    }
                    if !delivered {
                        self.advance_to(until.as_micros().max(self.now + 1));
                    }
                }
                TxEvent::Done | TxEvent::Failed(_) => return (event, flow_controls),
            }
        }
    }

    pub fn running_version(&self) -> Option<u32> {
        self.node
            .running()
            .map(|running| running.header.table_version)
    }

    /// Asks the node for a challenge from `source` with a tool nonce of its own (a new one at
    /// every call): the exchange nonce under `key` (what tags are over, for the holder of
    /// `key`), if the node answered.
    pub fn challenge(&mut self, source: u8, key: &Key) -> Option<u64> {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0x5EED_0000);
        let tool = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.challenge_with(source, tool, key)
    }

    /// [`Harness::challenge`] with this tool nonce.
    pub fn challenge_with(&mut self, source: u8, tool: u64, key: &Key) -> Option<u64> {
        let (node_nonce, _) = self.challenge_answer(source, tool)?;
        Some(
            Authenticator::new(key)
                .exchange(Self::NODE_ID, tool, node_nonce)
                .nonce,
        )
    }

    /// Asks the node for a challenge from `source` with this tool nonce: the Challenge's node
    /// nonce and binding, if the node answered.
    pub fn challenge_answer(&mut self, source: u8, tool: u64) -> Option<(u64, [u8; 2])> {
        let from = self.sent.len();
        self.feed(&Message::ChallengeRequest { tool_nonce: tool }.to_frame(source, Self::NODE_ID));
        self.sent[from..]
            .iter()
            .find_map(|(_, frame)| match Message::decode(frame) {
                Ok((
                    id,
                    Message::Challenge {
                        node_nonce,
                        binding,
                    },
                )) if id.destination == source => Some((node_nonce, binding)),
                _ => None,
            })
    }

    /// The authenticated DiagnosticControl frame for `nonce` under `key`.
    pub fn tagged_control(key: &Key, nonce: u64, control: DiagnosticControl) -> Frame {
        let mut payload = [0u8; 4];
        payload[..2].copy_from_slice(&control.rate_hz.to_le_bytes());
        payload[2..].copy_from_slice(&control.ports.to_le_bytes());
        let tag = Authenticator::new(key).command_tag(Self::NODE_ID, 0x10, nonce, &payload);
        Message::AuthenticatedDiagnosticControl { control, tag }
            .to_frame(protocol::TOOL, Self::NODE_ID)
    }

    /// What the key holder does to send a command: a challenge, then the tagged command. Returns
    /// the frame sent (for replays).
    pub fn keyed_command(&mut self, key: &Key, control: DiagnosticControl) -> Frame {
        let nonce = self.challenge(protocol::TOOL, key).expect("a challenge");
        let frame = Self::tagged_control(key, nonce, control);
        self.feed(&frame);
        frame
    }

    /// What `pabctl push --key` does: a challenge, a TransferOpen, then the image and its MAC
    /// over ISO-TP. Returns how the sender ended and the nonce.
    pub fn push_keyed(&mut self, bytes: &[u8], key: &Key, flags: u8) -> (TxEvent, u64) {
        self.push_keyed_with(bytes, key, flags, |_, _, data| Some(data))
    }

    /// [`Harness::push_keyed`] with a `tamper` hook as [`Harness::push_with`]'s.
    pub fn push_keyed_with(
        &mut self,
        bytes: &[u8],
        key: &Key,
        flags: u8,
        tamper: impl FnMut(&mut Harness, usize, [u8; 8]) -> Option<[u8; 8]>,
    ) -> (TxEvent, u64) {
        let nonce = self.challenge(protocol::TOOL, key).expect("a challenge");
        let auth = Authenticator::new(key);
        let mut message = bytes.to_vec();
        message.extend_from_slice(&auth.image_mac(Self::NODE_ID, nonce, flags, bytes));
        let length = u16::try_from(message.len()).unwrap();
        let open = TransferOpen {
            length,
            flags,
            tag: auth.open_tag(Self::NODE_ID, nonce, length, flags),
        };
        self.feed(&Message::TransferOpen(open).to_frame(protocol::TOOL, Self::NODE_ID));
        (self.push_with(&message, protocol::TOOL, tamper), nonce)
    }

    /// The Receipt tags the node sent to `destination`, each after the TransferStatus it
    /// confirms.
    pub fn receipts(&self, destination: u8) -> Vec<(TransferStatus, [u8; 8])> {
        let mut last = None;
        let mut out = Vec::new();
        for (_, id, message) in self.messages_since(0) {
            if id.destination != destination {
                continue;
            }
            match message {
                Message::TransferStatus(status) => last = Some(status),
                Message::Receipt { tag } => out.push((last.expect("a status first"), tag)),
                _ => {}
            }
        }
        out
    }

    /// The reasons of the Unauthenticated faults the node raised since `from` µs.
    pub fn auth_failures_since(&self, from: u64) -> Vec<AuthFailure> {
        self.messages_since(from)
            .into_iter()
            .filter_map(|(_, _, message)| match message {
                Message::Fault(fault) if fault.code == FaultCode::Unauthenticated => {
                    AuthFailure::from_code(fault.detail[0])
                }
                _ => None,
            })
            .collect()
    }
}
