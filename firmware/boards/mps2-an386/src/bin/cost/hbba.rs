//! What HBBA's message filters cost a board per frame (issue 14): the `walk-16` node of the
//! arbiter's cases (one port, a priority chain of 16 connections, the frame on the last, alone
//! active) with that connection filtered at φ = 3, so one frame in three passes. `passed`: a frame
//! the filter lets through (then arbitrated as in `walk-16`); `dropped`: one it drops (counted,
//! nothing else). Against `walk-16`, which has no filter, `passed` shows what the filter's count
//! adds to a frame, `dropped` what a throttled frame costs.

use embedded_can::StandardId;
use pab_core::hbba::filters::MessageFilters;
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Id, Instant, NodeRef, Stimulation, Table,
};

use crate::{fail, measured_receive, report};

const N: usize = 16;
/// Frames measured: two rounds of φ.
const FRAMES: u64 = 6;

fn id(k: usize) -> Id {
    match StandardId::new(0x100 + k as u16) {
        Some(id) => Id::Standard(id),
        None => fail(format_args!("id {k}")),
    }
}

fn arbiter() -> Arbiter {
    let Ok(stimulation) = Stimulation::from_seconds(1.0, 3600.0, 0.0) else {
        fail(format_args!("parameters"))
    };
    let connections: [Connection; N] = core::array::from_fn(|k| {
        let Ok(filter) = Filter::exact(0x100 + k as u32, false) else {
            fail(format_args!("filter"))
        };
        Connection {
            filter,
            stimulation,
        }
    });
    let chain: [DecisionNode; N] = core::array::from_fn(|k| {
        let low = if k + 1 < N {
            NodeRef::node(k as u16 + 1)
        } else {
            Some(NodeRef::NOBODY)
        };
        match (low, NodeRef::deliver(k as u8)) {
            (Some(low), Some(high)) => DecisionNode {
                var: k as u8,
                low,
                high,
            },
            _ => fail(format_args!("chain node {k}")),
        }
    });
    let mut table = Table::new();
    let root = NodeRef::node(0).unwrap_or(NodeRef::NOBODY);
    if let Err(error) = table.push_port(&connections, &chain, root) {
        fail(format_args!("port: {error}"));
    }
    let mut filters = MessageFilters::default();
    if filters.connections.push(N as u16 - 1).is_err() || filters.push_profile(&[3]).is_err() {
        fail(format_args!("filters"));
    }
    if let Err(error) = table.set_filters(filters) {
        fail(format_args!("filters: {error}"));
    }
    let mut arbiter =
        Arbiter::new(table).unwrap_or_else(|error| fail(format_args!("table: {error}")));
    if arbiter.set_filter_profile(1).is_err() {
        fail(format_args!("profile"));
    }
    arbiter
}

pub fn run() {
    let mut arbiter = arbiter();
    let frame = id(N - 1);
    for k in 0..FRAMES {
        let reception = measured_receive(&mut arbiter, &frame, Instant::from_micros(k));
        // One frame in three passes, the first after the switch included.
        let passes = k % 3 == 0;
        if reception.fed.contains(0) != passes {
            fail(format_args!(
                "hbba frame {k}: fed {}",
                reception.fed.contains(0)
            ));
        }
        report("hbba-phi-3", if passes { "passed" } else { "dropped" });
    }
}
