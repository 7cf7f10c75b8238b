//! Nodes for measuring `Arbiter::receive`, shared by the criterion benchmark
//! (`benches/receive.rs`) and the instruction-count loop (`examples/receive_loop.rs`).
//!
//! Every port uses a priority chain: connection k delivers iff x_k and no lower-indexed connection
//! is active. The diagram tests x_0, x_1, ... in order, so its walk is long when the low
//! connections are inactive. σ = 1 and τ = 1 h: the activity set up before measuring lasts.

#![allow(dead_code)]

use embedded_can::StandardId;
use pab_core::{
    Arbiter, Connection, DecisionNode, Filter, Id, Instant, MAX_CONNECTIONS_PER_PORT, MAX_PORTS,
    NodeRef, Stimulation, Table,
};

/// Frame id of connection `k` of port `port`.
pub fn id_of(port: usize, k: usize) -> u16 {
    (0x100 + port * MAX_CONNECTIONS_PER_PORT + k) as u16
}

pub fn frame(port: usize, k: usize) -> Id {
    Id::Standard(StandardId::new(id_of(port, k)).expect("11-bit id"))
}

/// Connection k delivers iff x_k and no lower-indexed connection is active.
pub fn priority_chain(n: usize) -> Vec<DecisionNode> {
    (0..n)
        .map(|k| DecisionNode {
            var: k as u8,
            low: if k + 1 < n {
                NodeRef::node(k as u16 + 1).expect("node")
            } else {
                NodeRef::NOBODY
            },
            high: NodeRef::deliver(k as u8).expect("connection"),
        })
        .collect()
}

/// `ports` ports of `n` chained connections each.
pub fn arbiter(ports: usize, n: usize) -> Arbiter {
    let stimulation = Stimulation::from_seconds(1.0, 3600.0, 0.0).expect("parameters");
    let mut table = Table::new();
    for port in 0..ports {
        let connections: Vec<Connection> = (0..n)
            .map(|k| Connection {
                filter: Filter::exact(u32::from(id_of(port, k)), false).expect("filter"),
                stimulation,
            })
            .collect();
        let root = NodeRef::node(0).expect("node");
        table
            .push_port(&connections, &priority_chain(n), root)
            .expect("valid port");
    }
    Arbiter::new(table).expect("valid table")
}

/// What is measured: a node, the frame, its port and the delivery it must get.
pub struct Case {
    /// The node, its activity set up.
    pub arbiter: Arbiter,
    /// The measured frame.
    pub id: Id,
    /// The port it feeds.
    pub port: usize,
    /// Through which connection it must be delivered.
    pub delivered: Option<u8>,
}

/// One port of `n` connections; only the last one active and the frame on it: the walk visits
/// all n nodes and the frame is delivered.
pub fn longest_walk(n: usize) -> Case {
    let mut arbiter = arbiter(1, n);
    arbiter.receive(&frame(0, n - 1), Instant::from_micros(0), |_| {});
    Case {
        arbiter,
        id: frame(0, n - 1),
        port: 0,
        delivered: Some(n as u8 - 1),
    }
}

/// One port of `n` connections, all active, the frame on the last: the walk stops at x_0 and the
/// frame is discarded.
pub fn all_active(n: usize) -> Case {
    let mut arbiter = arbiter(1, n);
    for k in 0..n {
        arbiter.receive(&frame(0, k), Instant::from_micros(0), |_| {});
    }
    Case {
        arbiter,
        id: frame(0, n - 1),
        port: 0,
        delivered: None,
    }
}

/// 16 ports of 32 connections (the node's capacity), the frame on the last connection of the last
/// port, only that one active: adds the filter scan over all 512 connections.
pub fn full_capacity() -> Case {
    let (ports, n) = (MAX_PORTS, MAX_CONNECTIONS_PER_PORT);
    let mut arbiter = arbiter(ports, n);
    arbiter.receive(&frame(ports - 1, n - 1), Instant::from_micros(0), |_| {});
    Case {
        arbiter,
        id: frame(ports - 1, n - 1),
        port: ports - 1,
        delivered: Some(n as u8 - 1),
    }
}

impl Case {
    /// Panics unless a frame at `now` gets the expected delivery on the expected port.
    pub fn verify(&mut self, now: Instant) {
        let mut verdict = None;
        self.arbiter.receive(&self.id, now, |v| verdict = Some(*v));
        let verdict = verdict.expect("the frame feeds its port");
        assert_eq!(
            (usize::from(verdict.port), verdict.delivered),
            (self.port, self.delivered)
        );
    }
}
