//! A node with a schema server on the in-process bus, for the schema tests: its set-up, the
//! drive's reports, schemas sent over ISO-TP, and what the node answered and sent.
#![allow(dead_code)]

use crate::common::*;
use pab_core::Instant;
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{BROADCAST, Message, SchemaAck, SchemaTransition, TOOL};
use pab_core::schema::{Config, Drive, Gripper, Schema, Sensor, Setup, build, drive};
use pab_core::{Endian, Field, OutputId};

pub const SETPOINT: u32 = 0x300;
pub const POSE: u32 = 0x310;
pub const WRENCH: u32 = 0x320;
/// The gripper's proximity sensor: mm, u16 big endian in bytes 2-3.
pub const PROXIMITY: u32 = 0x330;
/// Innate schema 0's id: close the gripper.
pub const CLOSE: u16 = 60;

pub fn setup() -> Setup {
    let mut config = Config::new(1000);
    config.limits.workspace_min = [-500_000; 6];
    config.limits.workspace_max = [500_000; 6];
    config
        .innate
        .push(build::gripper(CLOSE, Gripper::Closed))
        .unwrap();
    let mut sensors = heapless::Vec::new();
    sensors
        .push(Sensor {
            id: OutputId::new(PROXIMITY, false).unwrap(),
            field: Field {
                offset: 2,
                size: 2,
                signed: false,
                endian: Endian::Big,
            },
        })
        .unwrap();
    Setup {
        config,
        drive: Drive {
            setpoint: OutputId::new(SETPOINT, false).unwrap(),
            pose: OutputId::new(POSE, false).unwrap(),
            wrench: OutputId::new(WRENCH, false).unwrap(),
        },
        sensors,
    }
}

pub fn schema_table() -> TestTable {
    let mut table = priority_table(&[TOPIC_A], None);
    table.set_schema(Some(setup()));
    table
}

pub fn booted() -> Harness {
    Harness::boot(Some(&image(&schema_table(), Harness::NODE_ID, 1)))
}

/// The drive reports `pose` (translation, rotation 0) and no force.
pub fn report(h: &mut Harness, pose: [i32; 3]) {
    h.feed(&frame(POSE, &drive::pack(pose, false)));
    h.feed(&frame(POSE + 1, &drive::pack([0; 3], false)));
    h.feed(&frame(WRENCH, &drive::pack([0; 3], false)));
    h.feed(&frame(WRENCH + 1, &drive::pack([0; 3], false)));
}

/// Sends `schema` on `channel` from the tool over ISO-TP (SchemaTransfer), one frame per 100 µs,
/// answering the node's flow control; returns the SchemaAck.
pub fn send(h: &mut Harness, channel: u8, schema: &Schema) -> SchemaAck {
    let mut message = vec![channel];
    let mut buf = [0u8; 300];
    message.extend_from_slice(postcard::to_slice(schema, &mut buf).unwrap());
    send_bytes(h, &message)
}

pub fn send_bytes(h: &mut Harness, message: &[u8]) -> SchemaAck {
    try_send_bytes(h, message).expect("a SchemaAck")
}

/// [`send_bytes`], `None` when the node sent no SchemaAck (a node that ignored the transfer).
pub fn try_send_bytes(h: &mut Harness, message: &[u8]) -> Option<SchemaAck> {
    let since = h.now;
    let mut sender = Sender::new(message, TxConfig::default()).unwrap();
    let mut seen = h.sent.len();
    for _ in 0..1000 {
        match sender.poll(Instant::from_micros(h.now)) {
            TxEvent::Send(data) => {
                let frame =
                    Message::SchemaTransfer { data, len: 8 }.to_frame(TOOL, Harness::NODE_ID);
                h.feed(&frame);
                h.advance_to(h.now + 100);
            }
            TxEvent::WaitUntil(until) => {
                let mut answered = false;
                while seen < h.sent.len() {
                    let (_, frame) = h.sent[seen];
                    seen += 1;
                    if let Ok((id, Message::SchemaTransfer { data, len })) = Message::decode(&frame)
                        && id.destination == TOOL
                    {
                        let _ = sender.on_flow_control(
                            &data[..usize::from(len)],
                            Instant::from_micros(h.now),
                        );
                        answered = true;
                    }
                }
                if !answered {
                    h.advance_to(until.as_micros().max(h.now + 100));
                }
            }
            TxEvent::Done | TxEvent::Failed(_) => break,
        }
    }
    acks(h, since).pop()
}

pub fn acks(h: &Harness, since: u64) -> Vec<SchemaAck> {
    h.messages_since(since)
        .into_iter()
        .filter_map(|(_, id, m)| match m {
            Message::SchemaAck(a) if id.destination == TOOL => Some(a),
            _ => None,
        })
        .collect()
}

pub fn transitions(h: &Harness, since: u64) -> Vec<(u64, SchemaTransition)> {
    h.messages_since(since)
        .into_iter()
        .filter_map(|(t, id, m)| match m {
            Message::SchemaTransition(tr) if id.destination == BROADCAST => Some((t, tr)),
            _ => None,
        })
        .collect()
}

/// The attractor frames the node sent since `since`: (time, x, y, z, gripper closed).
pub fn attractors(h: &Harness, since: u64) -> Vec<(u64, [i32; 3], bool)> {
    h.sent
        .iter()
        .filter(|(t, f)| *t >= since && f.raw_id() == (SETPOINT, false))
        .map(|(t, f)| {
            let (values, flag) = drive::unpack(f.payload()).unwrap();
            (*t, values, flag)
        })
        .collect()
}
