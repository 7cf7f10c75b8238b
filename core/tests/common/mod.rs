//! Shared by the core's integration tests: decision builders, and what every test that drives an
//! `Arbiter` checks on every frame.

#![allow(dead_code)]

// The arbiter as it was (`reference`) and the random tables and frames the property tests feed it
// and the arbiter alike (`random`): equivalence.rs and swap.rs.
pub mod random;
pub mod reference;

use pab_core::{Arbiter, DecisionNode, Id, Instant, NodeRef, PortVerdict, Reception};

pub fn node(var: u8, low: NodeRef, high: NodeRef) -> DecisionNode {
    DecisionNode { var, low, high }
}

pub fn at(index: u16) -> NodeRef {
    NodeRef::node(index).expect("node index")
}

pub fn deliver(index: u8) -> NodeRef {
    NodeRef::deliver(index).expect("connection index")
}

/// Connection k delivers iff x_k and no lower-indexed connection is active.
pub fn priority_chain(n: u8) -> Vec<DecisionNode> {
    (0..n)
        .map(|k| {
            let low = if k + 1 < n {
                at(u16::from(k) + 1)
            } else {
                NodeRef::NOBODY
            };
            node(k, low, deliver(k))
        })
        .collect()
}

/// Receives a frame and returns the reception with the verdicts, after checking that every
/// verdict agrees with the read-only accessors at the same instant.
pub fn receive(arbiter: &mut Arbiter, id: Id, now: Instant) -> (Reception, Vec<PortVerdict>) {
    let mut verdicts = Vec::new();
    let reception = arbiter.receive(&id, now, |verdict| verdicts.push(*verdict));
    let mut fed = 0u16;
    let mut delivered = 0u16;
    for (k, verdict) in verdicts.iter().enumerate() {
        if k > 0 {
            assert!(
                verdict.port > verdicts[k - 1].port,
                "verdicts in port order"
            );
        }
        fed |= 1 << verdict.port;
        assert_eq!(verdict.selected, arbiter.selected(verdict.port, now));
        assert_eq!(verdict.active, arbiter.activity(verdict.port, now));
        // Only an active connection is selected, and the frame is delivered iff it fed it.
        assert!(
            verdict
                .selected
                .is_none_or(|index| verdict.active.contains(index))
        );
        assert_eq!(
            verdict.delivered,
            verdict
                .selected
                .filter(|&index| verdict.fed.contains(index))
        );
        if verdict.delivered.is_some() {
            delivered |= 1 << verdict.port;
        }
    }
    assert_eq!(reception.fed.bits(), fed);
    assert_eq!(reception.delivered.bits(), delivered);
    (reception, verdicts)
}
