//! The schema server on a node: `pab_core::schema::Server` ticked at its period, schemas taken
//! over ISO-TP, the emergency stop and the abort, the drive's frames in and out, and the
//! server's reports (docs/can-protocol.md, "Schema server").
//!
//! Sans-I/O like the node: frames and the time go in, frames to send come out through a sink
//! ([`Out`]); the node routes them into its outbox. What a tick decides is the server's.
//!
//! Timing: the node calls [`SchemaRuntime::poll`] whenever its deadline passes, which includes
//! [`SchemaRuntime::deadline`], the next tick. A late call runs one tick at the time it is
//! called (never a burst of catch-up ticks: the attractor would jump), and the server sees the
//! gap: beyond the overrun bound, that is its overrun safety event.

use pab_core::isotp::{self, RxEvent};
use pab_core::protocol::{
    self, FaultCode, Message, SchemaAck, SchemaChannel, SchemaOrigin, SchemaOutcome, SchemaSafety,
    SchemaState, SchemaTransition,
};

use crate::auth::Guard;
use crate::node::{Wire, earlier, transfer_deadline};
use pab_core::auth;

/// What a node with a key contributes to a schema transfer: its guard (the key), its id, and
/// the nonce of the TransferOpen that the frame at hand consumed (a first or single frame the
/// node admitted). An unkeyed node's guard says so, and no frame carries a nonce.
pub struct Keys<'a> {
    /// The node's authentication state.
    pub(crate) guard: &'a Guard,
    /// The node's id.
    pub node: u8,
    /// The nonce of the open this frame consumed.
    pub opened: Option<u64>,
}
use pab_core::schema::{
    self, AXES, Drive, Limits, MAX_ENCODED, MAX_SENSORS, Pose, Schema, Sensor, Server, Setpoint,
    Setup, drive,
};
use pab_core::{Frame, Instant, OutputId};

/// The longest SchemaTransfer message: the channel byte and a schema, and on a node with a key
/// its 16-byte MAC.
pub const TRANSFER_LEN: usize = MAX_ENCODED + 1 + auth::IMAGE_MAC_LEN;
/// SchemaState and the impedance frame go out this often, µs.
const REPORT_PERIOD_US: u64 = 100_000;

/// What the runtime asks the node to send or raise.
pub enum Out {
    /// A frame sent as it is: the drive's, or (CAN FD) a transfer's flow control.
    Drive(Frame),
    /// A frame of our protocol, to a destination (0xFF: all).
    Protocol(Message, u8),
    /// A fault (rate-limited by the node).
    Fault(FaultCode, [u8; 5]),
}

/// A node's schema server.
// Fields in declaration order (`repr(C)`): the small state read at every frame and tick first,
// where its offsets fit in a load's or a store's immediate, the server and the transfer buffer
// after it.
#[repr(C)]
pub struct SchemaRuntime {
    next_tick: Instant,
    next_report: Instant,
    /// The impedance last sent.
    impedance: Option<(u32, u32)>,
    /// The source of the transfer in progress, and when it must be complete: its whole budget,
    /// 1 s + 10 ms per consecutive frame, as a table's (a sender that trickles one frame per
    /// N_Cr would otherwise hold the one slot for 37 s a message, and for ever by starting again).
    sender: Option<(u8, Instant)>,
    /// The nonce of the transfer in progress, on a node with a key.
    nonce: Option<u64>,
    drive: Drive,
    /// The pose as its two frames last said (translation, rotation).
    pose: Pose,
    wrench: Pose,
    sensors: heapless::Vec<Sensor, MAX_SENSORS>,
    server: Server,
    receiver: isotp::Receiver<TRANSFER_LEN>,
}

impl SchemaRuntime {
    /// The runtime of `setup`, its first tick at `now`. The set-up is not checked here: it must
    /// have passed [`Setup::check`] (a table's does, when its arbiter is built).
    pub fn new(setup: Setup, isotp: isotp::RxConfig, now: Instant) -> SchemaRuntime {
        SchemaRuntime {
            server: Server::unchecked(setup.config),
            drive: setup.drive,
            sensors: setup.sensors,
            pose: [0; AXES],
            wrench: [0; AXES],
            next_tick: now,
            next_report: now,
            impedance: None,
            receiver: isotp::Receiver::new(isotp),
            sender: None,
            nonce: None,
        }
    }

    /// The server.
    pub fn server(&self) -> &Server {
        &self.server
    }

    /// When the runtime next has work: the next tick, or the transfer's N_Cr or budget if
    /// sooner.
    pub fn deadline(&self) -> Instant {
        let mut deadline = self.next_tick;
        earlier(&mut deadline, self.receiver.deadline());
        earlier(&mut deadline, self.sender.map(|(_, budget)| budget));
        deadline
    }

    /// A frame that is not ours: the drive's pose or wrench, or an extra sensor's, read.
    /// Returns whether it was one.
    pub fn on_drive_frame(&mut self, frame: &Frame, now: Instant) -> bool {
        if schema::feed_sensors(&self.sensors, frame, &mut self.server, now) {
            return true;
        }
        let (raw, extended) = frame.raw_id();
        let offset = |base: OutputId| {
            (base.is_extended() == extended)
                .then(|| raw.checked_sub(base.raw()))
                .flatten()
                .filter(|o| *o < 2)
        };
        let Some((values, _)) = drive::unpack(frame.payload()) else {
            return false;
        };
        if let Some(o) = offset(self.drive.pose) {
            drive::place(&mut self.pose, 3 * o as usize, values);
            self.server.set_pose(self.pose, now);
            true
        } else if let Some(o) = offset(self.drive.wrench) {
            drive::place(&mut self.wrench, 3 * o as usize, values);
            self.server.set_wrench(self.wrench, now);
            true
        } else {
            false
        }
    }

    /// An EmergencyStop frame: handled at the next tick.
    pub fn emergency_stop(&mut self) {
        self.server.emergency_stop();
    }

    /// A SchemaAbort frame: handled at the next tick.
    pub fn abort(&mut self) {
        self.server.abort();
    }

    /// The sequence number the transfer in progress expects next (`None` when idle): a node
    /// with a key drops a consecutive frame out of sequence before it reaches the receiver.
    pub fn next_sequence_number(&self) -> Option<u8> {
        self.receiver.next_sequence_number()
    }

    /// One ISO-TP frame of a SchemaTransfer from `source`. On a node with a key (`keys`), the
    /// node admitted the frame, a first frame with its open's nonce, and the message is checked
    /// against its MAC before anything in it is read; after the SchemaAck a Receipt confirms it.
    pub(crate) fn on_transfer_frame(
        &mut self,
        source: u8,
        data: &[u8],
        wire: Wire,
        now: Instant,
        keys: Keys<'_>,
        out: &mut impl FnMut(Out),
    ) {
        let keyed = keys.guard.is_keyed();
        if keys.opened.is_some() {
            self.nonce = keys.opened;
        }
        // One transfer at a time: another sender's frames wait until it ends (N_Cr, or its
        // budget).
        if self.sender.is_some_and(|(s, _)| s != source) && self.receiver.in_progress().is_some() {
            return;
        }
        let outcome = wire.receive(&mut self.receiver, data, now);
        let aborted = outcome.aborted.is_some();
        // The flow control to send and the answer (outcome, channel, id) of a refused or
        // complete message, sent after the match: one copy of each frame's construction.
        let (flow_control, answer) = match outcome.event {
            RxEvent::SendFlowControl(fc) => (Some(fc), None),
            RxEvent::Refused { flow_control, .. } => {
                (flow_control, Some((SchemaOutcome::TooLong, None, 0xFFFF)))
            }
            RxEvent::Complete(message) => {
                // With a key: the message and its MAC, checked first (a message too short for
                // one is no message).
                let message = match (keyed, self.nonce) {
                    (false, _) => Some(message),
                    (true, Some(nonce)) => message
                        .len()
                        .checked_sub(auth::IMAGE_MAC_LEN)
                        .and_then(|len| message.split_at_checked(len))
                        .filter(|(body, mac)| {
                            keys.guard
                                .image(keys.node, nonce, protocol::OPEN_SCHEMA, body, mac)
                        })
                        .map(|(body, _)| body),
                    (true, None) => None,
                };
                let (channel, bytes) = match message.and_then(|m| m.split_first()) {
                    Some((c, rest)) => (*c, rest),
                    None => (0xFF, &[][..]),
                };
                let named = SchemaChannel::of_message(channel);
                let limits = channel == SchemaChannel::Limits.code();
                let (verdict, id) = match (message, named) {
                    (None, _) => (Err(SchemaOutcome::Unauthenticated), SchemaAck::NO_ID),
                    // The limits channel: the bounds in force, within the table's (no id).
                    (Some(_), None) if limits => {
                        (set_limits(&mut self.server, bytes), SchemaAck::NO_ID)
                    }
                    (Some(_), _) => {
                        let decoded = Schema::decode(bytes).map_err(|e| SchemaOutcome::from(&e));
                        let id = decoded.as_ref().map_or(SchemaAck::NO_ID, |s| s.id);
                        let verdict = match named {
                            Some(named) => decoded.and_then(|s| {
                                self.server
                                    .submit(s, named)
                                    .map_err(|r| SchemaOutcome::from(&r))
                            }),
                            None => Err(SchemaOutcome::BadChannel),
                        };
                        (verdict, id)
                    }
                };
                let channel = match named {
                    Some(named) => Some(SchemaChannel::of(named)),
                    None => limits.then_some(SchemaChannel::Limits),
                };
                (
                    None,
                    Some((
                        verdict.err().unwrap_or(SchemaOutcome::Accepted),
                        channel,
                        id,
                    )),
                )
            }
            RxEvent::Nothing | RxEvent::Ignored(_) => (None, None),
        };
        if aborted || answer.is_some() {
            self.sender = None;
        }
        if let Some(fc) = flow_control {
            // The budget runs from the first frame; a flow control later in the transfer (the
            // next block) keeps it, and an overflow's ends it.
            if answer.is_none() && self.sender.is_none_or(|(s, _)| s != source) {
                let length = self.receiver.message_len().unwrap_or(0);
                self.sender = Some((source, transfer_deadline(now, length)));
            }
            out(flow_control_out(fc, source, wire, keys.node));
        }
        if let Some((outcome, channel, id)) = answer {
            let ack = self.answer(source, outcome, channel, id, out);
            // The Receipt of an opened transfer: a tag over its nonce and the SchemaAck's bytes
            // (the running table's CRC and stored flag, which a table's receipt confirms, 0).
            if let Some(nonce) = self.nonce.take() {
                let payload = Message::SchemaAck(ack).report_bytes().unwrap_or_default();
                let tag = keys.guard.receipt(keys.node, nonce, &payload, 0, false);
                out(Out::Protocol(Message::Receipt { tag }, source));
            }
        }
    }

    /// The SchemaAck for `source`; returns it.
    fn answer(
        &self,
        source: u8,
        outcome: SchemaOutcome,
        channel: Option<SchemaChannel>,
        id: u16,
        out: &mut impl FnMut(Out),
    ) -> SchemaAck {
        let ack = SchemaAck {
            outcome,
            channel,
            id,
            queued: self.server.queued().min(usize::from(u8::MAX)) as u8,
            stop: self.server.stop_number(),
        };
        out(Out::Protocol(Message::SchemaAck(ack), source));
        ack
    }

    /// The work due by `now`: a tick (its set-point frames, its transitions and faults), the
    /// periodic reports, a transfer's timeout.
    pub fn poll(&mut self, now: Instant, out: &mut impl FnMut(Out)) {
        // A transfer that ran out of time, between two frames (N_Cr) or as a whole (its
        // budget): the slot is free, and its sender learns why. (A transfer in progress has a
        // sender: it is set at the first frame, and cleared when the message ends.)
        if let Some((source, budget)) = self.sender
            && (self.receiver.poll(now).is_some() || now.micros_since(budget).is_some())
        {
            self.receiver.abort();
            self.sender = None;
            self.nonce = None;
            self.answer(source, SchemaOutcome::TimedOut, None, 0xFFFF, out);
        }
        if now.micros_since(self.next_tick).is_none() {
            return;
        }
        let period = u64::from(self.server.config().period_us);
        // The next tick a period after this one's due time, unless this one is late by more
        // than a period: then a period after now (no burst of catch-up ticks).
        let due = self.next_tick.wrapping_add_micros(period);
        self.next_tick = if now.micros_since(due).is_some() {
            now.wrapping_add_micros(period)
        } else {
            due
        };
        // Into place: see `Server::tick_into`.
        let mut tick = schema::Tick::default();
        self.server.tick_into(now, &mut tick);
        // Read once: nothing below changes the queue.
        let queued = self.server.queued();
        for t in &tick.transitions {
            if let schema::Trigger::Safety(cause) = t.by {
                out(Out::Fault(
                    FaultCode::SchemaSafety,
                    FaultCode::schema_safety_detail(cause, t.ended),
                ));
            }
            out(Out::Protocol(
                Message::SchemaTransition(SchemaTransition::from_transition(t, queued)),
                0xFF,
            ));
        }
        if let Some(s) = &tick.setpoint {
            self.send_setpoint(s, now, out);
        }
        if now.micros_since(self.next_report).is_some() {
            self.next_report = now.wrapping_add_micros(REPORT_PERIOD_US);
            let elapsed = self.server.elapsed_ms(now);
            out(Out::Protocol(
                Message::SchemaState(SchemaState {
                    current: self.server.current(),
                    source: SchemaOrigin::from(self.server.origin()),
                    fault: self.server.fault().map(SchemaSafety::from),
                    queued: queued.min(255) as u8,
                    armed: tick.setpoint.is_some(),
                    gripper_closed: tick
                        .setpoint
                        .is_some_and(|s| s.gripper == schema::Gripper::Closed),
                    stop: self.server.stop_number(),
                    elapsed_ms: SchemaState::saturate_ms(elapsed),
                }),
                0xFF,
            ));
        }
    }

    /// The attractor's two frames every tick; the impedance's when it changed and with every
    /// report.
    fn send_setpoint(&mut self, s: &Setpoint, now: Instant, out: &mut impl FnMut(Out)) {
        let base = self.drive.setpoint;
        let frame = |offset: u32, data: &[u8; 8]| {
            Frame::with_raw_id(base.raw().saturating_add(offset), base.is_extended(), data)
        };
        let impedance = (s.stiffness, s.damping);
        let with_impedance =
            self.impedance != Some(impedance) || now.micros_since(self.next_report).is_some();
        if with_impedance {
            self.impedance = Some(impedance);
        }
        // The three frames through one loop: one copy of the frame's construction.
        let [translation, rotation] = drive::attractor_frames(s);
        let frames = [translation, rotation, drive::impedance_frame(s)];
        for (offset, data) in (0..).zip(&frames).take(2 + usize::from(with_impedance)) {
            if let Some(f) = frame(offset, data) {
                out(Out::Drive(f));
            }
        }
    }
}

/// The limits in a message on the limits channel, set on `server` if they are within the
/// table's.
// Out of line, and of the server alone: the message's bytes are the receiver's.
#[inline(never)]
fn set_limits(server: &mut Server, bytes: &[u8]) -> Result<(), SchemaOutcome> {
    let limits = Limits::decode(bytes).map_err(|e| SchemaOutcome::from(&e))?;
    server
        .set_limits(limits)
        .map_err(|r| SchemaOutcome::from(&r))
}

/// A flow control to `source`, in the kind of frame its transfer came in (`wire`): a CAN FD one as
/// the frame itself (`node`: this node, its source).
#[cfg_attr(not(feature = "fd"), allow(unused_variables))]
#[inline(always)]
fn flow_control_out(fc: [u8; 8], source: u8, wire: Wire, node: u8) -> Out {
    #[cfg(feature = "fd")]
    if let Some(frame) = transfer(fc).report_frame(node, source) {
        return Out::Drive(wire.answer(frame));
    }
    Out::Protocol(transfer(fc), source)
}

fn transfer(flow_control: [u8; 8]) -> Message {
    Message::SchemaTransfer {
        data: flow_control,
        len: 8,
    }
}
