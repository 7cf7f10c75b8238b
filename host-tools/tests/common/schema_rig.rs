//! A schema server's board, its robot and its client in virtual time, with the bus captured: the
//! node application (`FullNode`, the Linux node's code, its schema server included) driven frame
//! by frame through `pab_app::replay::feed_with`, exactly as a replay wakes it; the plant of
//! `pabctl plant` and of the simulator (`pab_lang::sim::plant::BusPlant`), stepped every period
//! half a period after the board's ticks; and a client that sends the file's program over ISO-TP (pab-core's sender) as
//! the queue takes it, and its timed commands (emergency stop, abort, high-priority schemas) at
//! their times.
//!
//! The capture holds the frames the node received, in order: the client's and the plant's (not
//! its own, which a CAN controller does not receive back, and which would count in its Traffic
//! report). A replay of it must make the node send exactly what it sent here.

use pab_app::replay::{self, Recorder, job::TimedFrame};
use pab_app::{Config, FullNode};
use pab_core::isotp::{FlowControlEffect, Sender, TxConfig, TxEvent};
use std::cell::OnceCell;

use pab_core::protocol::{self, Message, SchemaChannel, SchemaOutcome, SchemaTransition};
use pab_core::schema::{Channel, MAX_ENCODED, Schema};
use pab_core::{Frame, Instant};
use pab_lang::candump::Capture;
use pab_lang::compile::CompiledNode;
use pab_lang::network::{Command, Network};
use pab_lang::sim::plant::Plant;
use pabctl::plant::BusPlant;

/// The rig's clock step, µs: the client's frames go out on this grid.
const STEP_US: u64 = 50;

/// What a rig run produced.
pub struct RigRun {
    /// Every frame the node received, in the order it received them.
    pub capture: Capture,
    /// The record the live node's sends make (`>` lines, `pab_app::replay::records`).
    pub sent_lines: Vec<String>,
    /// The node's schema transitions, in order.
    pub transitions: Vec<SchemaTransition>,
    /// The plant at the end.
    pub plant: Plant,
    /// Schemas the client had accepted (program and high-priority).
    pub accepted: usize,
}

/// What the client sends at a time: a frame, or a schema on the high-priority channel (its
/// message made when it is due: it names the latest stop number the client saw).
enum Out<'a> {
    HighPriority(usize, &'a Schema),
    Frame(Frame),
}

fn transfer(schema: &Schema, channel: u8) -> Vec<u8> {
    let mut buffer = [0u8; MAX_ENCODED];
    let bytes = postcard::to_slice(schema, &mut buffer).expect("a schema fits MAX_ENCODED");
    let mut message = vec![channel];
    message.extend_from_slice(bytes);
    message
}

/// Runs `network`'s schema server (its first `[schema.NODE]`, with its `[client]` and `[plant]`)
/// for `until_us` of virtual time.
pub fn run(network: &Network, compiled: &[CompiledNode], until_us: u64) -> RigRun {
    let board = &network.schema_boards[0];
    let client = network
        .client
        .as_ref()
        .expect("the rig's file has a [client]");
    let node_id = network.nodes[client.node].id;
    let image = &compiled.iter().find(|c| c.id == node_id).unwrap().image;
    let period = u64::from(board.config.period_us);

    let mut node = Box::new(FullNode::new(
        Config::new(node_id).unwrap(),
        Instant::from_micros(0),
    ));
    node.boot_buffer()[..image.len()].copy_from_slice(image);
    let mut preamble = String::new();
    replay::boot(
        &mut node,
        image.len(),
        Instant::from_micros(0),
        &mut preamble,
    )
    .unwrap();
    assert!(node.schema().is_some(), "the node runs a schema server");
    let mut recorder = Recorder::new(String::new());
    recorder.node_id = node_id;

    let mut plant = BusPlant::new(board, network.plant.clone().unwrap_or_default());
    // The client's messages, program first, then the timed commands at their times.
    let program: Vec<Vec<u8>> = client
        .program
        .iter()
        .map(|call| transfer(&call.schema, SchemaChannel::message_byte(Channel::Queue)))
        .collect();
    let timed: Vec<(u64, Out<'_>)> = client
        .commands
        .iter()
        .enumerate()
        .map(|(index, t)| {
            let out = match &t.command {
                Command::EmergencyStop => {
                    Out::Frame(Message::EmergencyStop.to_frame(protocol::TOOL, protocol::BROADCAST))
                }
                Command::Abort => {
                    Out::Frame(Message::SchemaAbort.to_frame(protocol::TOOL, node_id))
                }
                Command::HighPriority(call) => Out::HighPriority(index, &call.schema),
            };
            (t.t_us, out)
        })
        .collect();

    let mut bus: Vec<(u64, Frame)> = Vec::new();
    let mut sent_by_node: Vec<(u64, Frame)> = Vec::new();
    let mut transitions = Vec::new();
    // The transfer in progress (its message), the next program call, a high-priority schema due.
    let mut sending: Option<Sender<'_>> = None;
    let mut awaiting_ack = false;
    let mut next_call = 0usize;
    let mut urgent: Vec<&[u8]> = Vec::new();
    // The high-priority messages, made when due; the latest stop number the node reported.
    let high_priority: Vec<OnceCell<Vec<u8>>> = timed.iter().map(|_| OnceCell::new()).collect();
    let mut stop_seen = 0u8;
    let mut next_timed = 0usize;
    let mut queue_full = false;
    let mut accepted = 0usize;
    let mut transfer_is_program = false;

    let mut t = 0u64;
    while t <= until_us {
        let mut to_node: Vec<Frame> = Vec::new();
        // The plant: half a period after each tick, one step under the last set-point, then its
        // pose and wrench.
        if t % period == period / 2 {
            plant.step(board.config.period_us);
            to_node.extend(plant.frames());
        }
        // The timed commands.
        while let Some((at, out)) = timed.get(next_timed).filter(|(at, _)| *at <= t) {
            let _ = at;
            match out {
                Out::Frame(frame) => to_node.push(*frame),
                Out::HighPriority(index, schema) => {
                    let channel =
                        SchemaChannel::message_byte(Channel::HighPriority { stop: stop_seen });
                    urgent.push(high_priority[*index].get_or_init(|| transfer(schema, channel)));
                }
            }
            next_timed += 1;
        }
        // The client: one transfer at a time, a high-priority schema before the program's next.
        if sending.is_none() && !awaiting_ack {
            if let Some(message) = urgent.first().copied() {
                urgent.remove(0);
                sending = Some(Sender::new(message, TxConfig::default()).unwrap());
                transfer_is_program = false;
            } else if !queue_full && let Some(message) = program.get(next_call) {
                sending = Some(Sender::new(message, TxConfig::default()).unwrap());
                transfer_is_program = true;
            }
        }
        if let Some(sender) = sending.as_mut() {
            match sender.poll(Instant::from_micros(t)) {
                TxEvent::Send(data) => to_node.push(
                    Message::SchemaTransfer { data, len: 8 }.to_frame(protocol::TOOL, node_id),
                ),
                TxEvent::WaitUntil(_) => {}
                TxEvent::Done => {
                    sending = None;
                    awaiting_ack = true;
                }
                TxEvent::Failed(error) => panic!("a schema transfer failed at {t} µs: {error:?}"),
            }
        }

        for frame in to_node {
            bus.push((t, frame));
            let timed = TimedFrame { t_us: t, frame };
            replay::feed_with(
                &mut node,
                &timed,
                &mut recorder,
                &mut |recorder, out, at| {
                    recorder.sent(&out, at);
                    sent_by_node.push((at.as_micros(), out));
                },
            );
        }
        // What the node sent reaches the plant and the client.
        for (at, frame) in sent_by_node.drain(..) {
            plant.on_frame(&frame);
            let Ok((id, message)) = Message::decode(&frame) else {
                continue;
            };
            if id.source != node_id {
                continue;
            }
            match message {
                Message::SchemaTransfer { data, len } if id.destination == protocol::TOOL => {
                    if let Some(sender) = sending.as_mut() {
                        let effect = sender
                            .on_flow_control(&data[..usize::from(len)], Instant::from_micros(at));
                        assert!(
                            !matches!(effect, FlowControlEffect::Failed(_)),
                            "flow control at {at} µs"
                        );
                    }
                }
                // The node answers as the last frame completes the message, before the sender
                // has said it is done: the transfer in flight is answered either way.
                Message::SchemaState(state) => stop_seen = state.stop,
                Message::SchemaAck(ack)
                    if id.destination == protocol::TOOL && (awaiting_ack || sending.is_some()) =>
                {
                    stop_seen = ack.stop;
                    awaiting_ack = false;
                    sending = None;
                    match ack.outcome {
                        SchemaOutcome::Accepted => {
                            accepted += 1;
                            if transfer_is_program {
                                next_call += 1;
                            }
                        }
                        // A full queue: the same call again after the next schema change.
                        SchemaOutcome::QueueFull if transfer_is_program => queue_full = true,
                        other => panic!("the board refused a schema at {at} µs: {other:?}"),
                    }
                }
                Message::SchemaTransition(transition) => {
                    queue_full = false;
                    transitions.push(transition);
                }
                _ => {}
            }
        }
        t += STEP_US;
    }

    let capture = Capture::from_frames("vcan0", &bus);
    let record = recorder.finish(0).unwrap();
    RigRun {
        capture,
        sent_lines: sent_lines(&record),
        transitions,
        plant: plant.into_plant(),
        accepted,
    }
}

/// The `>` lines of a record.
pub fn sent_lines(record: &str) -> Vec<String> {
    record
        .lines()
        .filter(|line| line.starts_with("> "))
        .map(str::to_string)
        .collect()
}
