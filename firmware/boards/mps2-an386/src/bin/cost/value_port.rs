//! What a value port costs a board (issue 12), per frame: `Arbiter::receive_frame` on a port of
//! 3 range sensors combined by `min`, and on one of 8 combined by `sum` (the longest scan a
//! node's 16 value connections allow on one port with room to spare), σ = 1, τ = 1 h. Frames
//! whose output changes (the combination handed over) and frames whose output stays are
//! reported apart.

use core::hint::black_box;

use pab_core::{
    BoardArbiter, BoardTable, Combine, Connection, Endian, Field, Filter, Frame, Gain, Instant,
    NodeRef, Stimulation, ValueSpec,
};

use crate::{fail, measure, report};

const TAU_US: u32 = 3_600_000_000;

fn value_arbiter(n: u8, combine: Combine) -> BoardArbiter {
    let mut connections = heapless::Vec::<Connection, 8>::new();
    let mut roots = heapless::Vec::<NodeRef, 8>::new();
    for k in 0..n {
        let (Ok(filter), Ok(stimulation), Some(root)) = (
            Filter::exact(0x1A0 + u32::from(k), false),
            Stimulation::new(Gain::ONE, TAU_US, 0),
            NodeRef::deliver(k),
        ) else {
            fail(format_args!("value-port connection {k}"));
        };
        let _ = connections.push(Connection {
            filter,
            stimulation,
        });
        let _ = roots.push(root);
    }
    let spec = ValueSpec {
        combine,
        value: Field {
            offset: 0,
            size: 2,
            signed: false,
            endian: Endian::Little,
        },
        priority: None,
    };
    let mut table = BoardTable::new();
    if let Err(error) = table.push_value_port(&connections, &[], spec, &roots) {
        fail(format_args!("value-port table: {error}"));
    }
    BoardArbiter::new(table).unwrap_or_else(|error| fail(format_args!("value arbiter: {error}")))
}

/// Sensor `k`'s frame carrying `value`.
fn frame(k: u8, value: u16) -> Frame {
    Frame::with_raw_id(0x1A0 + u32::from(k), false, &value.to_le_bytes())
        .unwrap_or_else(|| fail(format_args!("sensor frame")))
}

/// Feeds every sensor once (unmeasured), then measures `rounds` rounds of a frame per sensor,
/// with values from `value(round, k)`.
fn case(name: &'static str, n: u8, combine: Combine, value: impl Fn(u16, u8) -> u16) {
    let mut arbiter = value_arbiter(n, combine);
    let mut now = 0u64;
    for k in 0..n {
        now += 1;
        let _ = arbiter.receive_frame(
            &frame(k, value(0, k)),
            Instant::from_micros(now),
            |_| {},
            |_| {},
        );
    }
    for round in 1..4u16 {
        for k in 0..n {
            now += 1;
            let frame = black_box(frame(k, value(round, k)));
            let at = black_box(Instant::from_micros(now));
            let mut changed = false;
            black_box(measure(|| {
                arbiter.receive_frame(
                    &frame,
                    at,
                    |_| {},
                    |output| {
                        changed = true;
                        black_box(output);
                    },
                )
            }));
            report(name, if changed { "changed" } else { "same" });
        }
    }
}

pub fn run() {
    // Sensor 0 is nearest in even rounds, sensor 2 in odd ones: some frames change the minimum.
    case("value-min-3", 3, Combine::Min, |round, k| {
        if k == 2 && round % 2 == 1 {
            500
        } else {
            1000 + 100 * u16::from(k)
        }
    });
    // Every frame changes the sum.
    case("value-sum-8", 8, Combine::Sum, |round, k| {
        10 * round + u16::from(k)
    });
}
