//! The schema server's client on a live bus (the paper's deliberative layer): schemas built by
//! `pab_core::schema::build`, sent over ISO-TP (SchemaTransfer) and answered by SchemaAck; the
//! emergency stop and the abort; the board's reports (SchemaTransition, SchemaState) kept as
//! they arrive (docs/can-protocol.md, "Schema server").
//!
//! Blocking, on one [`Bus`]: every wait reads the bus and keeps what the node reports, so a
//! program is a sequence of calls. Units are the board's: µm, µrad, µm/s, mN, ms.
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use pabctl::client::Client;
//! let mut bus = pabctl::bus::open("vcan0")?;
//! let mut arm = Client::new(bus.as_mut(), 10);
//! let id = arm.move_to([100_000, -60_000, 35_000, 0, 0, 0], 50_000)?;
//! let ended = arm.wait_finished(id, std::time::Duration::from_secs(10))?;
//! # Ok(()) }
//! ```

use std::collections::BTreeMap;
use std::io;
use std::time::{Duration, Instant};

use pab_core::auth::Authenticator;
use pab_core::isotp::{FlowControlEffect, TxEvent};
use pab_core::protocol::{
    self, BROADCAST, Message, OPEN_SCHEMA, SchemaAck, SchemaChannel, SchemaOutcome, SchemaState,
    SchemaTransition, Service, TransferOpen,
};
use pab_core::schema::{Action, Channel, Gripper, Limits, MAX_ENCODED, Pose, Schema, build};

use crate::bus::Bus;
use crate::push;
use crate::transfer::TransferSender;

/// Why a call failed.
#[derive(Debug)]
#[non_exhaustive]
pub enum ClientError {
    /// The bus failed.
    Io(io::Error),
    /// The board refused the schema.
    Refused(SchemaAck),
    /// No answer in time (what was awaited).
    Timeout(&'static str),
    /// With a key: the board's Receipt for the SchemaAck did not verify (a forged answer, or
    /// another key), so the answer does not count.
    BadReceipt(SchemaAck),
    /// The schema could not be encoded (more than the board takes).
    TooLarge,
    /// With a key: no challenge, and the board said why: it refused tags meanwhile (a flood of
    /// bad tags uses up its checks for the second). The reason, as `pabctl push` gives it.
    Denied(String),
}

impl std::fmt::Display for ClientError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ClientError::Io(e) => write!(f, "bus: {e}"),
            ClientError::Refused(ack) => write!(
                f,
                "schema {} refused: {} ({} queued)",
                ack.id,
                ack.outcome.description(),
                ack.queued
            ),
            ClientError::Timeout(what) => write!(f, "no {what} in time"),
            ClientError::BadReceipt(ack) => write!(
                f,
                "schema {}: the receipt of the board's answer does not verify (another key, or a \
                 forged answer)",
                ack.id
            ),
            ClientError::TooLarge => write!(f, "the schema is longer than {MAX_ENCODED} bytes"),
            ClientError::Denied(why) => write!(f, "no challenge: {why}"),
        }
    }
}

impl std::error::Error for ClientError {}

impl From<io::Error> for ClientError {
    fn from(e: io::Error) -> Self {
        ClientError::Io(e)
    }
}

/// How long the board may take to answer a schema, after its last frame.
pub const ACK_TIMEOUT: Duration = Duration::from_secs(1);

/// A client of one board's schema server.
pub struct Client<'b> {
    bus: &'b mut dyn Bus,
    node: u8,
    /// The board's key, for a board that has one (each schema opened and its answer confirmed).
    key: Option<Authenticator>,
    next_id: u16,
    /// The board's schema changes as they arrived, and when.
    transitions: Vec<(Instant, SchemaTransition)>,
    state: Option<SchemaState>,
    /// For each schema of ours that ended: the transition that ended it.
    ended: BTreeMap<u16, SchemaTransition>,
}

impl<'b> Client<'b> {
    /// A client of node `node` on `bus`, sending as the tool (source 0).
    pub fn new(bus: &'b mut dyn Bus, node: u8) -> Client<'b> {
        Client {
            bus,
            node,
            key: None,
            next_id: 1,
            transitions: Vec::new(),
            state: None,
            ended: BTreeMap::new(),
        }
    }

    /// A client of a board that has a key: every schema goes as the key holder's (a challenge,
    /// a TransferOpen for a schema, the message and its MAC), and its SchemaAck counts only with
    /// a Receipt that verifies (docs/can-protocol.md, "Authenticated configuration").
    pub fn with_key(bus: &'b mut dyn Bus, node: u8, key: Authenticator) -> Client<'b> {
        Client {
            key: Some(key),
            ..Client::new(bus, node)
        }
    }

    /// The next id this client gives a schema (1, 2, …, below the board's reserved 0xFF00).
    pub fn take_id(&mut self) -> u16 {
        let id = self.next_id;
        self.next_id = if self.next_id >= pab_core::schema::BUILTIN_IDS - 1 {
            1
        } else {
            self.next_id + 1
        };
        id
    }

    /// Sends `schema` on `channel` and waits for its SchemaAck. A high-priority schema names the
    /// stop number it acknowledges ([`Channel::HighPriority`]; the board's latest is
    /// [`Client::stop_number`]): name it deliberately, once the program knows why the robot
    /// stopped, since the board refuses a schema that names an older one.
    ///
    /// Fails with [`ClientError::Refused`] when the board refuses it (a full queue included:
    /// see [`Client::install_waiting`]).
    pub fn install(&mut self, schema: &Schema, channel: Channel) -> Result<SchemaAck, ClientError> {
        let mut buffer = [0u8; MAX_ENCODED];
        let bytes = postcard::to_slice(schema, &mut buffer).map_err(|_| ClientError::TooLarge)?;
        self.transfer(SchemaChannel::message_byte(channel), bytes)
    }

    /// Sets the bounds the board runs with ([`Limits`]): each within its table's, tighter or
    /// back up to the table's, never looser; from the board's next tick. Waits for the
    /// SchemaAck (on the limits channel).
    ///
    /// Fails with [`ClientError::Refused`] when the board refuses them
    /// ([`SchemaOutcome::Looser`]: looser than the table's somewhere, other joints than the
    /// table's, or inconsistent), or when it runs no schema server.
    pub fn set_limits(&mut self, limits: &Limits) -> Result<SchemaAck, ClientError> {
        let mut buffer = [0u8; MAX_ENCODED];
        let bytes = postcard::to_slice(limits, &mut buffer).map_err(|_| ClientError::TooLarge)?;
        self.transfer(SchemaChannel::Limits.code(), bytes)
    }

    /// One SchemaTransfer message: `channel` (its byte 0) then `body`; with a key, after a
    /// challenge and its open, and confirmed by the board's Receipt.
    fn transfer(&mut self, channel: u8, body: &[u8]) -> Result<SchemaAck, ClientError> {
        let mut message = vec![channel];
        message.extend_from_slice(body);
        // With a key: the challenge, the open for a schema, and the MAC after the message.
        let mut opened = None;
        if let Some(key) = &self.key {
            // The node's refusals are read on the way: a flood of bad tags is said as such.
            let mut watched = push::Refusals::new(&mut *self.bus, self.node);
            let answer = push::challenge(&mut watched, key, self.node, ACK_TIMEOUT)?;
            let nonce = match (answer, watched.reason()) {
                (push::Challenged::Bound(nonce), _) => nonce,
                (push::Challenged::Nothing { .. }, Some(why)) => {
                    return Err(ClientError::Denied(why));
                }
                (push::Challenged::Nothing { unbound: 0 }, None) => {
                    return Err(ClientError::Timeout(
                        "challenge (does the board have a key?)",
                    ));
                }
                (push::Challenged::Nothing { .. }, None) => {
                    return Err(ClientError::Timeout(
                        "challenge answering this request (others came that did not verify: \
                         a key that is not the board's, another tool, or a participant making \
                         them up)",
                    ));
                }
            };
            message.extend_from_slice(&key.image_mac(self.node, nonce, OPEN_SCHEMA, &message));
            let length = u16::try_from(message.len()).map_err(|_| ClientError::TooLarge)?;
            let open = TransferOpen {
                length,
                flags: OPEN_SCHEMA,
                tag: key.open_tag(self.node, nonce, length, OPEN_SCHEMA),
            };
            self.bus
                .send(&Message::TransferOpen(open).to_frame(protocol::TOOL, self.node))?;
            opened = Some(nonce);
        }
        let start = Instant::now();
        let clock = |now: Instant| {
            pab_core::Instant::from_micros(now.duration_since(start).as_micros() as u64)
        };
        let framing = self.bus.framing();
        let mut sender = TransferSender::new(&message, Service::SchemaTransfer, self.node, framing)
            .map_err(|_| ClientError::TooLarge)?;
        loop {
            match sender.poll(clock(Instant::now())) {
                TxEvent::Send(frame) => self.bus.send(&frame)?,
                TxEvent::WaitUntil(until) => {
                    let wait = Duration::from_micros(
                        until.micros_since(clock(Instant::now())).unwrap_or(0),
                    );
                    if let Some(frame) = self.bus.receive(wait)? {
                        if let Ok((id, Message::SchemaTransfer { data, len })) =
                            Message::decode(&frame)
                            && id.source == self.node
                            && id.destination == protocol::TOOL
                        {
                            let data = data.get(..usize::from(len)).unwrap_or(&data);
                            if let FlowControlEffect::Failed(_) =
                                sender.on_flow_control(data, clock(Instant::now()))
                            {
                                return Err(ClientError::Timeout("flow control"));
                            }
                        } else {
                            self.keep(&frame);
                        }
                    }
                }
                TxEvent::Done => break,
                TxEvent::Failed(_) => return Err(ClientError::Timeout("flow control")),
            }
        }
        let deadline = Instant::now() + ACK_TIMEOUT;
        // The Receipt may come first: its identifier ranks above SchemaAck's, so the board's
        // outbox sends it first when both wait there.
        let mut receipt = None;
        while let Some(wait) = deadline.checked_duration_since(Instant::now()) {
            let Some(frame) = self.bus.receive(wait)? else {
                continue;
            };
            match Message::decode(&frame) {
                Ok((id, Message::Receipt { tag }))
                    if id.source == self.node && id.destination == protocol::TOOL =>
                {
                    receipt = Some(tag);
                    continue;
                }
                _ => {}
            }
            if let Ok((id, Message::SchemaAck(ack))) = Message::decode(&frame)
                && id.source == self.node
                && id.destination == protocol::TOOL
            {
                if let Some(nonce) = opened {
                    self.confirm(&frame, &ack, nonce, receipt, deadline)?;
                }
                return if ack.outcome == SchemaOutcome::Accepted {
                    Ok(ack)
                } else {
                    Err(ClientError::Refused(ack))
                };
            }
            self.keep(&frame);
        }
        Err(ClientError::Timeout("SchemaAck"))
    }

    /// With a key: the Receipt that follows the SchemaAck `ack_frame`, verified under the key for
    /// the transfer's exchange nonce (the running table's CRC and stored flag 0: a schema's receipt).
    /// `early`: a Receipt that came before the SchemaAck.
    fn confirm(
        &mut self,
        ack_frame: &pab_core::Frame,
        ack: &SchemaAck,
        nonce: u64,
        early: Option<[u8; 8]>,
        deadline: Instant,
    ) -> Result<(), ClientError> {
        let mut payload = [0u8; 8];
        for (slot, byte) in payload.iter_mut().zip(ack_frame.payload()) {
            *slot = *byte;
        }
        let mut tag = early;
        while tag.is_none() {
            let Some(wait) = deadline.checked_duration_since(Instant::now()) else {
                return Err(ClientError::Timeout("Receipt"));
            };
            let Some(frame) = self.bus.receive(wait)? else {
                continue;
            };
            match Message::decode(&frame) {
                Ok((id, Message::Receipt { tag: received }))
                    if id.source == self.node && id.destination == protocol::TOOL =>
                {
                    tag = Some(received);
                }
                _ => self.keep(&frame),
            }
        }
        let node = self.node;
        let verifies = |tag: [u8; 8]| {
            self.key
                .as_ref()
                .is_some_and(|key| key.verify_receipt(node, nonce, &payload, 0, false, &tag))
        };
        if tag.is_some_and(verifies) {
            Ok(())
        } else {
            Err(ClientError::BadReceipt(*ack))
        }
    }

    /// [`Client::install`] to the queue, sending again while the queue is full (every 20 ms,
    /// up to `patience`): what a program does to keep the queue topped up.
    pub fn install_waiting(
        &mut self,
        schema: &Schema,
        patience: Duration,
    ) -> Result<SchemaAck, ClientError> {
        let deadline = Instant::now() + patience;
        loop {
            match self.install(schema, Channel::Queue) {
                Err(ClientError::Refused(ack))
                    if ack.outcome == SchemaOutcome::QueueFull && Instant::now() < deadline =>
                {
                    self.pump(Duration::from_millis(20))?;
                }
                other => return other,
            }
        }
    }

    /// `moveTo(pose)`, queued: returns its id.
    pub fn move_to(&mut self, goal: Pose, speed: u32) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(&build::move_to(id, goal, speed), Channel::Queue)
            .map(|_| id)
    }

    /// `moveToTouch(dir)`, queued.
    pub fn move_to_touch(
        &mut self,
        direction: Pose,
        speed: u32,
        contact: i32,
        distance: u32,
    ) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(
            &build::move_to_touch(id, direction, speed, contact, distance),
            Channel::Queue,
        )
        .map(|_| id)
    }

    /// `grasp()`, queued.
    pub fn grasp(&mut self, settle_ms: u32) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(&build::grasp(id, settle_ms), Channel::Queue)
            .map(|_| id)
    }

    /// `release()`, queued.
    pub fn release(&mut self, settle_ms: u32) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(&build::release(id, settle_ms), Channel::Queue)
            .map(|_| id)
    }

    /// `blind_search()`, queued: `search` is an [`Action::BlindSearch`].
    pub fn blind_search(&mut self, search: Action, depth: u32) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(&build::blind_search(id, search, depth), Channel::Queue)
            .map(|_| id)
    }

    /// `idle(ms)`, queued.
    pub fn idle(&mut self, ms: u32) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(&build::idle(id, ms), Channel::Queue)
            .map(|_| id)
    }

    /// Opens or closes the gripper at once, queued.
    pub fn gripper(&mut self, g: Gripper) -> Result<u16, ClientError> {
        let id = self.take_id();
        self.install(&build::gripper(id, g), Channel::Queue)
            .map(|_| id)
    }

    /// Sends SchemaAbort to the board.
    pub fn abort(&mut self) -> io::Result<()> {
        self.bus
            .send(&Message::SchemaAbort.to_frame(protocol::TOOL, self.node))
    }

    /// Sends the EmergencyStop frame, to this board or to every board.
    pub fn estop(&mut self, broadcast: bool) -> io::Result<()> {
        let destination = if broadcast { BROADCAST } else { self.node };
        self.bus
            .send(&Message::EmergencyStop.to_frame(protocol::TOOL, destination))
    }

    /// The board's last SchemaState.
    pub fn status(&self) -> Option<SchemaState> {
        self.state
    }

    /// Every schema change the client has seen, in order, with when it arrived.
    pub fn transitions(&self) -> &[(Instant, SchemaTransition)] {
        &self.transitions
    }

    /// Waits until schema `id` has ended; returns the transition that ended it (which event:
    /// its trigger and detail).
    pub fn wait_finished(
        &mut self,
        id: u16,
        timeout: Duration,
    ) -> Result<SchemaTransition, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(t) = self.ended.get(&id) {
                return Ok(*t);
            }
            let Some(wait) = deadline.checked_duration_since(Instant::now()) else {
                return Err(ClientError::Timeout("end of the schema"));
            };
            if let Some(frame) = self.bus.receive(wait)? {
                self.keep(&frame);
            }
        }
    }

    /// Reads the bus for `duration`, keeping the board's reports.
    pub fn pump(&mut self, duration: Duration) -> io::Result<()> {
        let deadline = Instant::now() + duration;
        while let Some(wait) = deadline.checked_duration_since(Instant::now()) {
            if let Some(frame) = self.bus.receive(wait)? {
                self.keep(&frame);
            }
        }
        Ok(())
    }

    /// Keeps a report of our board.
    fn keep(&mut self, frame: &pab_core::Frame) {
        match Message::decode(frame) {
            Ok((id, Message::SchemaTransition(t))) if id.source == self.node => {
                self.ended.insert(t.ended, t);
                self.transitions.push((Instant::now(), t));
            }
            Ok((id, Message::SchemaState(s))) if id.source == self.node => self.state = Some(s),
            _ => {}
        }
    }

    /// The board's latest stop number, from its last SchemaState (`None` before one came).
    pub fn stop_number(&self) -> Option<u8> {
        self.state.map(|s| s.stop)
    }
}

/// The channel of an acknowledged schema, for messages.
pub fn channel_name(channel: Option<SchemaChannel>) -> &'static str {
    match channel {
        Some(SchemaChannel::Queue) => "queue",
        Some(SchemaChannel::HighPriority) => "high-priority",
        Some(SchemaChannel::Limits) => "limits",
        None => "?",
    }
}

/// One installed schema as a live run reports it: the row of `pabctl sim --schema-trace`.
#[derive(Clone, Debug, PartialEq)]
pub struct TraceRow {
    /// Seconds since the program started.
    pub t: f64,
    /// The installed schema's name.
    pub schema: String,
    /// `innate`, `queue` or `high-priority`.
    pub source: &'static str,
    /// The triggering event (`done`, `above:contact`, `safety:force`, …).
    pub event: String,
}

/// How a program run ended.
#[derive(Clone, Debug, PartialEq)]
pub struct ProgramOutcome {
    /// Every installed schema, in order.
    pub rows: Vec<TraceRow>,
    /// The safety event that stopped the board, if one did.
    pub safety: Option<protocol::SchemaSafety>,
    /// The calls the board accepted.
    pub sent: usize,
}

/// Runs `program` (the calls of a network file's `[client]`, their schemas' ids as compiled) on
/// `board` (whose sensors name the events): each call queued as the queue takes it, then waits until the last one has ended,
/// or a safety event stops the board, or `timeout` passes. `progress` sees each row as it comes.
pub fn run_program(
    client: &mut Client<'_>,
    program: &[pab_lang::network::Call],
    board: &pab_lang::network::SchemaBoard,
    timeout: Duration,
    progress: &mut dyn FnMut(&TraceRow),
) -> Result<ProgramOutcome, ClientError> {
    let start = Instant::now();
    let deadline = start + timeout;
    let mut seen = client.transitions.len();
    let mut rows = Vec::new();
    let mut safety = None;
    let mut sent = 0;
    let mut follow = |client: &Client<'_>,
                      rows: &mut Vec<TraceRow>,
                      safety: &mut Option<protocol::SchemaSafety>| {
        for (at, t) in client.transitions.iter().skip(seen) {
            let row = trace_row(program, board, t, at.duration_since(start).as_secs_f64());
            if let Some(cause) = t.safety() {
                safety.get_or_insert(cause);
            }
            progress(&row);
            rows.push(row);
        }
        seen = client.transitions.len();
    };
    for call in program {
        let patience = deadline.saturating_duration_since(Instant::now());
        client.install_waiting(&call.schema, patience)?;
        sent += 1;
        follow(client, &mut rows, &mut safety);
        if safety.is_some() {
            break;
        }
    }
    let last = program.last().map(|c| c.schema.id);
    while safety.is_none() && last.is_some_and(|id| !client.ended.contains_key(&id)) {
        let Some(left) = deadline.checked_duration_since(Instant::now()) else {
            return Err(ClientError::Timeout("the program's end"));
        };
        client.pump(left.min(Duration::from_millis(20)))?;
        follow(client, &mut rows, &mut safety);
    }
    // The transition into the last wait, if it came with the end.
    client.pump(Duration::from_millis(20))?;
    follow(client, &mut rows, &mut safety);
    Ok(ProgramOutcome { rows, safety, sent })
}

/// Names a transition as the simulator's trace does.
fn trace_row(
    program: &[pab_lang::network::Call],
    board: &pab_lang::network::SchemaBoard,
    t: &SchemaTransition,
    at: f64,
) -> TraceRow {
    use pab_lang::sim::schema::{builtin_name, transition_event};
    use protocol::SchemaOrigin;
    let call = |id: u16| program.iter().find(|c| c.schema.id == id);
    let schema = builtin_name(t.installed)
        .or_else(|| call(t.installed).map(|c| c.name.clone()))
        .unwrap_or_else(|| format!("schema {}", t.installed));
    let event = transition_event(t, |id| call(id).map(|c| &c.schema), Some(board));
    let source = match t.source {
        SchemaOrigin::Innate => "innate",
        SchemaOrigin::Queue => "queue",
        SchemaOrigin::HighPriority => "high-priority",
    };
    TraceRow {
        t: at,
        schema,
        source,
        event,
    }
}
