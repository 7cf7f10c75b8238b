//! A schema server's board, its client and its plant in virtual time, on a bus of their own.
//!
//! The board is the node itself (`pab_app::FullNode`, booted from the compiled image of the
//! client's node, as the simulator's `Station` boots every node of a simulation): its schema
//! server (`pab_app::schema::SchemaRuntime`) ticks at its period, takes schemas over ISO-TP,
//! drives the drive and reports, with the code a board runs. The simulator only carries the
//! frames, tells the node the time and reads it:
//!
//! - the client sends its program's calls (schemas made by `pab_core::schema::build`) as
//!   SchemaTransfer messages (pab-core's ISO-TP sender, as `pabctl`'s client sends them), one
//!   transfer at a time: the next call once the board has acknowledged the last, again after
//!   the next schema change when the board answered that its queue was full. Its timed commands
//!   go out at their times: an EmergencyStop frame, a SchemaAbort frame, a schema on the
//!   high-priority channel naming the latest stop number the board reported;
//! - the plant ([`super::plant::BusPlant`]) reads the node's set-point frames and, half a period
//!   after each tick, steps once and publishes the drive's pose and wrench frames, and its range
//!   finder as a board sensor's frame when `[plant]` names one, as the topics would.
//!
//! Each schema change the node reports (SchemaTransition) is a row of the trace ([`Installed`]):
//! its time, name, source and the event that triggered it (named from the ended schema's
//! reaction, which the client knows). Each tick is a [`Sample`]: the plant and its last
//! set-point, and the installed schema read from the node's server.

use std::cell::OnceCell;
use std::collections::VecDeque;

use pab_core::isotp::{FlowControlEffect, Sender, TxConfig, TxEvent};
use pab_core::protocol::SchemaTrigger;
use pab_core::protocol::{self, Message, SchemaChannel, SchemaOutcome, SchemaTransition};
use pab_core::schema::{Channel, Event, MAX_ENCODED, Measure, Origin, Safety, Schema, Server};
use pab_core::{Frame, Instant};

use super::SimError;
use super::plant::{BusPlant, Plant, PlantConfig};
use super::station::Station;
pub use crate::network::{Call, Command, Timed};
use crate::network::{Network, SchemaBoard, SensorTopic};

/// One installed schema.
#[derive(Clone, Debug, PartialEq)]
pub struct Installed {
    /// When (the tick), µs.
    pub t_us: u64,
    /// The schema's id.
    pub id: u16,
    /// Its name: the call's, or the server's own (`wait-queue`, `wait-high-priority`,
    /// `safety:<name>`).
    pub name: String,
    /// Where it came from.
    pub source: Origin,
    /// The triggering event: the reaction's ([`event_name`]), `high-priority`, `abort` or
    /// `safety:<name>`.
    pub event: String,
}

/// One tick's state, for plots.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// µs.
    pub t_us: u64,
    /// The measured pose before the tick, µm.
    pub pose: [i32; 3],
    /// The attractor after it, µm.
    pub attractor: [i32; 3],
    /// The contact force's magnitude, N.
    pub force_n: f64,
    /// The installed schema.
    pub schema: u16,
}

/// What a run produced.
#[derive(Clone, Debug)]
pub struct Run {
    /// Every installed schema, in order.
    pub installed: Vec<Installed>,
    /// One sample per tick.
    pub samples: Vec<Sample>,
    /// The plant at the end.
    pub plant: Plant,
    /// The program's calls sent (all of them, unless the run ended first).
    pub sent: usize,
    /// When the run ended, µs.
    pub end_us: u64,
    /// The first safety event, if any.
    pub fault: Option<Safety>,
}

/// How long a run may go on.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Stop at this time, µs.
    pub until_us: u64,
    /// Stop once every call has been sent and the board waits (on the queue, or on the
    /// high-priority channel with nothing timed left), or once a safety event has stopped it
    /// with nothing timed left, this long after.
    pub settle_us: u64,
}

/// The name of a reaction's event in traces: `one-shot`, `done`, `elapsed`, `queue-ready`,
/// `above:<measure>` or `below:<measure>` with `position.z`, `displacement.z`, `force.x`,
/// `contact`, `sensor.3`, ….
pub fn event_name(event: &Event) -> String {
    let measure = |m: &Measure| {
        const AXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];
        let axis = |a: &u8| AXES.get(usize::from(*a)).copied().unwrap_or("?");
        match m {
            Measure::Position(a) => format!("position.{}", axis(a)),
            Measure::Displacement(a) => format!("displacement.{}", axis(a)),
            Measure::Force(a) => format!("force.{}", axis(a)),
            Measure::Contact => "contact".to_string(),
            Measure::Sensor(s) => format!("sensor.{s}"),
        }
    };
    match event {
        Event::OneShot => "one-shot".into(),
        Event::Done => "done".into(),
        Event::Elapsed(_) => "elapsed".into(),
        Event::QueueReady => "queue-ready".into(),
        Event::Above(m, _) => format!("above:{}", measure(m)),
        Event::Below(m, _) => format!("below:{}", measure(m)),
    }
}

/// `name` with a sensor's index replaced by its name in the file (`below:gap`, not
/// `below:sensor.0`).
fn sensor_named(name: String, event: &Event, board: &SchemaBoard) -> String {
    match event {
        Event::Above(Measure::Sensor(i), _) | Event::Below(Measure::Sensor(i), _) => {
            match board.sensors.get(usize::from(*i)) {
                Some(topic) => format!("{}:{}", name.split(':').next().unwrap_or(""), topic.name),
                None => name,
            }
        }
        _ => name,
    }
}

/// The server's own schemas' names.
pub fn builtin_name(id: u16) -> Option<String> {
    match id {
        Schema::WAIT_QUEUE => Some("wait-queue".into()),
        Schema::WAIT_HIGH_PRIORITY => Some("wait-high-priority".into()),
        _ => {
            let cause = id.checked_sub(Schema::SAFETY)?;
            let cause = Safety::from_u8(u8::try_from(cause).ok()?)?;
            Some(format!("safety:{}", cause.name()))
        }
    }
}

/// The frame the range finder's reading (µm) makes on `topic`: the reading in mm over the
/// topic's scale, rounded and saturated to its field (`value_port::Field::write`). The one
/// encoding of the plant's range finder: [`super::plant::BusPlant`] publishes it with this, in
/// the simulator and in `pabctl plant`, so a board sees the same counts in virtual time and on a
/// live bus. `None` only for an identifier no frame can carry (the
/// network file refuses those).
pub fn range_frame(topic: &SensorTopic, range_um: f64) -> Option<Frame> {
    let counts = (range_um / 1000.0 / topic.scale).round();
    let mut data = [0u8; pab_core::frame::MAX_DATA_LEN];
    topic.sensor.field.write(
        &mut data,
        counts.clamp(i64::MIN as f64, i64::MAX as f64) as i64,
    );
    let classic = data.get(..pab_core::frame::CLASSIC_DATA_LEN)?;
    Frame::with_raw_id(
        topic.sensor.id.raw(),
        topic.sensor.id.is_extended(),
        classic,
    )
}

/// A transfer of the client: a call of the program, or the high-priority schema of a timed
/// command (their indices).
#[derive(Clone, Copy, Debug)]
enum Transfer {
    Call(usize),
    HighPriority(usize),
}

/// A timed command's high-priority schema: its bytes, and its message once its transfer starts.
struct Urgent {
    body: Option<Vec<u8>>,
    message: OnceCell<Option<Vec<u8>>>,
}

/// The client on the bus: its messages go out over ISO-TP from the tool's address, one transfer
/// at a time; it hears the board's flow controls, answers and reports.
struct Client<'m> {
    node: u8,
    program: &'m [Call],
    commands: &'m [Timed],
    /// The program's messages: the queue's channel byte, then the schema.
    messages: &'m [Vec<u8>],
    /// Per timed command, a high-priority schema's bytes and its message, made when its
    /// transfer starts (it names the latest stop number the client has heard of then).
    urgent_messages: &'m [Urgent],
    /// The calls the board accepted; the next to send.
    sent: usize,
    /// Timed high-priority schemas due, not sent yet.
    urgent: VecDeque<usize>,
    /// The transfer in progress.
    sending: Option<(Sender<'m>, Transfer)>,
    /// The transfer sent whose SchemaAck has not come yet.
    awaiting: Option<Transfer>,
    /// The board answered QueueFull: the same call again after its next schema change.
    queue_full: bool,
    /// The latest stop number the board reported (SchemaAck, SchemaState).
    stop_seen: u8,
    /// When the sender next has something to send (STmin, or its wait for a flow control).
    wake: Option<u64>,
}

/// A schema's bytes, as a SchemaTransfer message carries them after its channel byte.
fn encoded(call: &Call) -> Result<Vec<u8>, SimError> {
    let mut buffer = [0u8; MAX_ENCODED];
    postcard::to_slice(&call.schema, &mut buffer)
        .map(|bytes| bytes.to_vec())
        .map_err(|_| {
            SimError(format!(
                "{}: its schema is longer than {MAX_ENCODED} bytes",
                call.name
            ))
        })
}

impl<'m> Client<'m> {
    fn transfer_name(&self, transfer: Transfer) -> String {
        match transfer {
            Transfer::Call(i) => format!(
                "call {} ({})",
                i + 1,
                self.program.get(i).map_or("?", |c| c.name.as_str())
            ),
            Transfer::HighPriority(i) => match self.commands.get(i).map(|t| &t.command) {
                Some(Command::HighPriority(call)) => call.name.clone(),
                _ => "?".into(),
            },
        }
    }

    /// Whether it has nothing to send and nothing in flight.
    fn idle(&self) -> bool {
        self.urgent.is_empty() && self.sending.is_none() && self.awaiting.is_none()
    }

    /// Its next frame at `now_us`, if it has one to send now.
    fn next_frame(&mut self, now_us: u64) -> Result<Option<Frame>, SimError> {
        self.wake = None;
        if self.sending.is_none() && self.awaiting.is_none() {
            let next = if let Some(index) = self.urgent.pop_front() {
                let channel = SchemaChannel::message_byte(Channel::HighPriority {
                    stop: self.stop_seen,
                });
                self.urgent_messages.get(index).and_then(|urgent| {
                    let message = urgent.message.get_or_init(|| {
                        let mut message = vec![channel];
                        message.extend_from_slice(urgent.body.as_deref()?);
                        Some(message)
                    });
                    Some((message.as_ref()?, Transfer::HighPriority(index)))
                })
            } else if !self.queue_full {
                self.messages
                    .get(self.sent)
                    .map(|m| (m, Transfer::Call(self.sent)))
            } else {
                None
            };
            if let Some((bytes, transfer)) = next {
                let sender = Sender::new(bytes, TxConfig::default())
                    .map_err(|e| SimError(format!("{}: {e:?}", self.transfer_name(transfer))))?;
                self.sending = Some((sender, transfer));
            }
        }
        let Some((sender, transfer)) = self.sending.as_mut() else {
            return Ok(None);
        };
        match sender.poll(Instant::from_micros(now_us)) {
            TxEvent::Send(data) => Ok(Some(
                Message::SchemaTransfer { data, len: 8 }.to_frame(protocol::TOOL, self.node),
            )),
            TxEvent::WaitUntil(until) => {
                self.wake = Some(until.as_micros());
                Ok(None)
            }
            TxEvent::Done => {
                self.awaiting = Some(*transfer);
                self.sending = None;
                Ok(None)
            }
            TxEvent::Failed(error) => {
                let transfer = *transfer;
                let name = self.transfer_name(transfer);
                Err(SimError(format!(
                    "the transfer of {name} failed: {error:?}"
                )))
            }
        }
    }

    /// A frame the board sent at `now_us`.
    fn hear(&mut self, frame: &Frame, now_us: u64) -> Result<(), SimError> {
        let Ok((id, message)) = Message::decode(frame) else {
            return Ok(());
        };
        if id.source != self.node {
            return Ok(());
        }
        let to_us = id.destination == protocol::TOOL;
        match message {
            Message::SchemaTransfer { data, len } if to_us => {
                if let Some((sender, transfer)) = self.sending.as_mut() {
                    let data = data.get(..usize::from(len)).unwrap_or(&data);
                    let now = Instant::from_micros(now_us);
                    if let FlowControlEffect::Failed(error) = sender.on_flow_control(data, now) {
                        let transfer = *transfer;
                        let name = self.transfer_name(transfer);
                        return Err(SimError(format!(
                            "the transfer of {name} failed: {error:?}"
                        )));
                    }
                }
            }
            Message::SchemaState(state) => self.stop_seen = state.stop,
            // The board answers as the last frame completes the message, before the sender has
            // said it is done: the transfer in flight is answered either way.
            Message::SchemaAck(ack) if to_us => {
                self.stop_seen = ack.stop;
                let transfer = self
                    .awaiting
                    .take()
                    .or_else(|| self.sending.take().map(|(_, t)| t));
                self.sending = None;
                match (ack.outcome, transfer) {
                    (_, None) => {}
                    (SchemaOutcome::Accepted, Some(Transfer::Call(_))) => self.sent += 1,
                    (SchemaOutcome::Accepted, Some(Transfer::HighPriority(_))) => {}
                    (SchemaOutcome::QueueFull, Some(Transfer::Call(_))) => self.queue_full = true,
                    (outcome, Some(transfer)) => {
                        return Err(SimError(format!(
                            "the board refused {}: {outcome:?}",
                            self.transfer_name(transfer)
                        )));
                    }
                }
            }
            Message::SchemaTransition(_) => self.queue_full = false,
            _ => {}
        }
        Ok(())
    }
}

/// What the simulator observes of the board: the schema changes it reports.
struct Watch<'a> {
    node: u8,
    board: &'a SchemaBoard,
    /// The schemas the client and the board know, by name: the program's, the timed commands',
    /// the innate ones.
    known: Vec<(&'a str, &'a Schema)>,
    installed: Vec<Installed>,
    fault: Option<Safety>,
}

impl Watch<'_> {
    fn known(&self, id: u16) -> Option<(&str, &Schema)> {
        self.known.iter().find(|(_, s)| s.id == id).copied()
    }

    /// A frame the board sent at `now_us`: a schema change is a row.
    fn hear(&mut self, frame: &Frame, now_us: u64) {
        let Ok((id, Message::SchemaTransition(t))) = Message::decode(frame) else {
            return;
        };
        if id.source != self.node {
            return;
        }
        let event = self.event(&t);
        let name = builtin_name(t.installed)
            .or_else(|| self.known(t.installed).map(|(n, _)| n.to_string()))
            .unwrap_or_else(|| format!("schema {}", t.installed));
        self.installed.push(Installed {
            t_us: now_us,
            id: t.installed,
            name,
            source: Origin::from(t.source),
            event,
        });
    }

    /// The event that triggered `t` ([`transition_event`]); a safety event is the run's fault.
    fn event(&mut self, t: &SchemaTransition) -> String {
        if let Some(cause) = t.safety().map(Safety::from) {
            self.fault.get_or_insert(cause);
        }
        transition_event(t, |id| self.known(id).map(|(_, s)| s), Some(self.board))
    }
}

/// The event that triggered the schema change `t`, as traces name it: `high-priority`,
/// `abort`, `safety:<cause>`, or for a reaction the ended schema's reaction at the index the
/// board reported, its sensor named as `board` names it (the server's own wait for the queue
/// reacts to a ready queue, a recovery once). `known` finds a schema the client knows by its
/// id. The simulator's trace and `pabctl run`'s rows both name events with this.
pub fn transition_event<'s>(
    t: &SchemaTransition,
    known: impl Fn(u16) -> Option<&'s Schema>,
    board: Option<&SchemaBoard>,
) -> String {
    match t.trigger {
        SchemaTrigger::HighPriority => "high-priority".into(),
        SchemaTrigger::Abort => "abort".into(),
        SchemaTrigger::Safety => match t.safety().map(Safety::from) {
            Some(cause) => format!("safety:{}", cause.name()),
            None => "safety:?".into(),
        },
        SchemaTrigger::Reaction => match known(t.ended) {
            Some(schema) => schema
                .reactions
                .get(usize::from(t.detail))
                .map_or("?".into(), |r| {
                    let name = event_name(&r.event);
                    match board {
                        Some(board) => sensor_named(name, &r.event, board),
                        None => name,
                    }
                }),
            None if t.ended == Schema::WAIT_QUEUE => event_name(&Event::QueueReady),
            None if t.ended >= Schema::SAFETY => event_name(&Event::OneShot),
            None => "?".into(),
        },
    }
}

/// The bus: the node, the plant, the client and the observer, in virtual time.
struct Bus<'a, 'm> {
    station: Station,
    plant: BusPlant,
    client: Client<'m>,
    watch: Watch<'a>,
}

impl Bus<'_, '_> {
    /// What the node sent goes to the plant, the client and the observer.
    fn carry(&mut self, now_us: u64) -> Result<(), SimError> {
        while let Some(frame) = self.station.app.next_outgoing() {
            self.plant.on_frame(&frame);
            self.client.hear(&frame, now_us)?;
            self.watch.hear(&frame, now_us);
        }
        Ok(())
    }

    /// `frame` to the node, and what it sent in answer on.
    fn send(&mut self, frame: &Frame, now_us: u64) -> Result<(), SimError> {
        self.station.feed(frame, now_us, &mut ());
        self.carry(now_us)
    }

    /// The node polled while its deadline has come, and the client's frames sent, until
    /// neither has anything left at `now_us`.
    fn settle(&mut self, now_us: u64) -> Result<(), SimError> {
        loop {
            while let Some(due) = self.station.due().filter(|&due| due <= now_us) {
                self.station.poll(due, now_us, &mut ());
                self.carry(now_us)?;
            }
            let mut sent = false;
            while let Some(frame) = self.client.next_frame(now_us)? {
                self.send(&frame, now_us)?;
                sent = true;
            }
            if !sent {
                return Ok(());
            }
        }
    }

    fn server(&self) -> Option<&Server> {
        self.station.app.schema().map(|runtime| runtime.server())
    }
}

/// Runs the client's program (and its timed commands) on `board`, the node booted from `image`,
/// driving a plant with `plant`.
///
/// Fails when the image does not boot or runs no schema server, or the board refuses a call for
/// any reason but a full queue (a malformed call is the file's error, not something to
/// simulate).
pub fn run(
    network: &Network,
    board: &SchemaBoard,
    image: &[u8],
    plant: PlantConfig,
    program: &[Call],
    commands: &[Timed],
    limits: Limits,
) -> Result<Run, SimError> {
    let node = network
        .nodes
        .get(board.node)
        .ok_or_else(|| SimError("the schema server's node is not in the file".into()))?;
    let mut records = String::new();
    let station = Station::boot(board.node, node, image, None, &mut records)?;
    if station.app.schema().is_none() {
        return Err(SimError(format!(
            "node `{}`: its table runs no schema server",
            node.name
        )));
    }
    let period = board.config.period_us;
    let period_us = u64::from(period.max(1));
    let half = period_us / 2;
    let queue = SchemaChannel::message_byte(Channel::Queue);
    let messages = program
        .iter()
        .map(|call| Ok([vec![queue], encoded(call)?].concat()))
        .collect::<Result<Vec<_>, SimError>>()?;
    let urgent_messages = commands
        .iter()
        .map(|t| {
            let body = match &t.command {
                Command::HighPriority(call) => Some(encoded(call)?),
                _ => None,
            };
            Ok(Urgent {
                body,
                message: OnceCell::new(),
            })
        })
        .collect::<Result<Vec<_>, SimError>>()?;
    let known = program
        .iter()
        .map(|c| (c.name.as_str(), &c.schema))
        .chain(commands.iter().filter_map(|t| match &t.command {
            Command::HighPriority(c) => Some((c.name.as_str(), &c.schema)),
            _ => None,
        }))
        .chain(
            board
                .innate
                .iter()
                .map(String::as_str)
                .zip(board.config.innate.iter()),
        )
        .collect();
    let mut bus = Bus {
        station,
        plant: BusPlant::new(board, plant),
        client: Client {
            node: node.id,
            program,
            commands,
            messages: &messages,
            urgent_messages: &urgent_messages,
            sent: 0,
            urgent: VecDeque::new(),
            sending: None,
            awaiting: None,
            queue_full: false,
            stop_seen: 0,
            wake: None,
        },
        watch: Watch {
            node: node.id,
            board,
            known,
            installed: Vec::new(),
            fault: None,
        },
    };
    // What the node sent as it booted (its first tick, its first reports).
    bus.carry(0)?;
    let mut samples = Vec::new();
    let mut pending = commands.iter().enumerate().peekable();
    let mut idle_since: Option<u64> = None;
    let mut t_us = 0u64;
    let end_us = loop {
        // The plant, half a period after each tick: one step under the last set-point, then
        // its frames.
        if t_us % period_us == half {
            bus.plant.step(period);
            for frame in bus.plant.frames() {
                bus.send(&frame, t_us)?;
            }
        }
        while let Some((index, timed)) = pending.next_if(|(_, c)| c.t_us <= t_us) {
            let node = bus.client.node;
            match &timed.command {
                Command::EmergencyStop => bus.send(
                    &Message::EmergencyStop.to_frame(protocol::TOOL, protocol::BROADCAST),
                    t_us,
                )?,
                Command::Abort => {
                    bus.send(&Message::SchemaAbort.to_frame(protocol::TOOL, node), t_us)?;
                }
                Command::HighPriority(_) => bus.client.urgent.push_back(index),
            }
        }
        bus.settle(t_us)?;
        let next_tick = (t_us / period_us + 1) * period_us;
        if t_us.is_multiple_of(period_us) {
            let plant = bus.plant.plant();
            let pose = plant.pose();
            let attractor = bus.plant.setpoint().map_or(pose, |s| s.attractor);
            let server = bus.server();
            samples.push(Sample {
                t_us,
                pose: [pose[0], pose[1], pose[2]],
                attractor: [attractor[0], attractor[1], attractor[2]],
                force_n: plant.force_n(),
                schema: server.map_or(Schema::WAIT_QUEUE, Server::current),
            });
            let current = server.map_or(Schema::WAIT_QUEUE, Server::current);
            let nothing_timed = pending.peek().is_none() && bus.client.idle();
            let waiting = current == Schema::WAIT_QUEUE
                || (current == Schema::WAIT_HIGH_PRIORITY && nothing_timed);
            // Stopped on a safety event with nothing timed left: the queue will not run again,
            // and the client cannot send what it still has (the queue does not drain).
            let fault = server.and_then(Server::fault);
            let queued = server.map_or(0, Server::queued);
            let stopped = fault.is_some() && waiting;
            if stopped || (bus.client.sent == program.len() && waiting && queued == 0) {
                let since = *idle_since.get_or_insert(t_us);
                if t_us - since >= limits.settle_us {
                    break t_us;
                }
            } else {
                idle_since = None;
            }
        }
        let next = [
            Some(next_tick),
            Some((t_us / period_us) * period_us + half).filter(|&t| t > t_us),
            Some(next_tick + half),
            pending.peek().map(|(_, c)| c.t_us),
            bus.station.due(),
            bus.client.wake,
        ]
        .into_iter()
        .flatten()
        .filter(|&t| t > t_us)
        .min()
        .unwrap_or(next_tick);
        if next > limits.until_us {
            // As many ticks as fit, the end a period after the last.
            break (limits.until_us / period_us + 1) * period_us;
        }
        t_us = next;
    };
    Ok(Run {
        installed: bus.watch.installed,
        samples,
        plant: bus.plant.into_plant(),
        sent: bus.client.sent,
        end_us,
        fault: bus.watch.fault,
    })
}

/// Runs the file's schema server: its board's set-up, its plant (the default one without
/// `[plant]`), its client's program and commands.
///
/// Fails when the file has no `[client]` (nothing would happen) or the board refuses a call.
pub fn simulate(network: &Network, limits: Limits) -> Result<Run, SimError> {
    let client = network.client.as_ref().ok_or_else(|| {
        SimError("the file has no [client]: a schema server with nothing to do".into())
    })?;
    let board = network
        .schema_boards
        .iter()
        .find(|b| b.node == client.node)
        .ok_or_else(|| SimError("the client's node runs no schema server".into()))?;
    let node = network.nodes.get(client.node);
    let compiled = crate::compile::compile(network)
        .map_err(|diagnostics| SimError(crate::diagnostic::Diagnostics(diagnostics).to_string()))?;
    let image = compiled
        .iter()
        .find(|c| node.is_some_and(|n| n.id == c.id))
        .map(|c| c.image.as_slice())
        .ok_or_else(|| SimError("the client's node has no table".into()))?;
    run(
        network,
        board,
        image,
        network.plant.clone().unwrap_or_default(),
        &client.program,
        &client.commands,
        limits,
    )
}

/// Writes `run`'s installed schemas as CSV: `t,node,schema,source,event`, one row per installed
/// schema (t in seconds with six decimals, `node` the board's name in `network`).
pub fn write_trace(
    run: &Run,
    network: &Network,
    out: &mut impl std::io::Write,
) -> std::io::Result<()> {
    let node = network
        .client
        .as_ref()
        .and_then(|c| network.nodes.get(c.node))
        .map_or("", |n| n.name.as_str());
    writeln!(out, "t,node,schema,source,event")?;
    for i in &run.installed {
        writeln!(
            out,
            "{},{},{},{},{}",
            super::seconds_text(i.t_us),
            csv_field(node),
            csv_field(&i.name),
            i.source.name(),
            csv_field(&i.event)
        )?;
    }
    Ok(())
}

/// A CSV field, quoted when it holds a comma or a quote (a call's keyword arguments do).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// A report of `run` for a terminal: the board, what was installed, the parts, the fault.
pub fn report(run: &Run, network: &Network) -> String {
    let node = network
        .client
        .as_ref()
        .and_then(|c| network.nodes.get(c.node))
        .map_or("?", |n| n.name.as_str());
    let program = network.client.as_ref().map_or(0, |c| c.program.len());
    let mut text = format!(
        "schema server on `{node}`: {} schemas installed, {} of {program} calls sent, until t = {} s\n",
        run.installed.len(),
        run.sent,
        super::seconds_text(run.end_us)
    );
    let parts = run.plant.parts().len();
    if parts > 0 {
        text.push_str(&format!(
            "  parts inserted: {} of {parts}\n",
            run.plant.inserted()
        ));
    }
    match run.fault {
        Some(cause) => {
            let at = run
                .installed
                .iter()
                .find(|i| i.event == format!("safety:{}", cause.name()))
                .map_or(0, |i| i.t_us);
            text.push_str(&format!(
                "  safety event: {} at t = {} s; the board waits on the high-priority channel\n",
                cause.name(),
                super::seconds_text(at)
            ));
        }
        None => text.push_str("  no safety event\n"),
    }
    text
}
