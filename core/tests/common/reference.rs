//! The arbiter as it was before it was made fast on the boards (commit 781dd74), kept here as the
//! reference the optimised one must agree with bit for bit: every connection's filter tested per
//! frame, every connection's activity evaluated per fed port, the decision diagram walked node by
//! node, and the decay with its divisions by small constants in 64-bit arithmetic. Only the
//! public API of pab-core is used (tables, filters, parameters, levels, diagrams), so nothing
//! here shares code with the optimised path beyond the table it reads.

#![allow(dead_code)]

use pab_core::decision::Target;
use pab_core::{ConnectionSet, DecisionNode, Id, Instant, Level, NodeRef, PortVerdict, Table};

// ---------------------------------------------------------------------------------------------
// The decay, as decay.rs computed it.

const LAMBDA: f64 = 5.0;
const SEGMENT_SHIFT: u32 = 6;
const SEGMENTS: usize = 1 << SEGMENT_SHIFT;
const SEGMENT_BITS: u32 = 32 - SEGMENT_SHIFT;
const RECIPROCAL_SHIFT: u32 = 56;
const Q32: f64 = 4_294_967_296.0;

const fn exp(x: f64) -> f64 {
    let y = x / 1024.0;
    let mut term = 1.0;
    let mut sum = 1.0;
    let mut k = 1;
    while k < 10 {
        term = term * y / k as f64;
        sum += term;
        k += 1;
    }
    let mut squarings = 0;
    while squarings < 10 {
        sum *= sum;
        squarings += 1;
    }
    sum
}

const fn to_q32(value: f64) -> u32 {
    (value * Q32 + 0.5) as u32
}

const LOSS_AT: [u32; SEGMENTS + 1] = {
    let mut table = [0; SEGMENTS + 1];
    let mut i = 0;
    while i <= SEGMENTS {
        let u = i as f64 / SEGMENTS as f64;
        table[i] = to_q32(exp(-LAMBDA) * (exp(LAMBDA * u) - 1.0));
        i += 1;
    }
    table
};

const SLOPE_AT: [u32; SEGMENTS] = {
    let mut table = [0; SEGMENTS];
    let mut i = 0;
    while i < SEGMENTS {
        let u = i as f64 / SEGMENTS as f64;
        table[i] = to_q32(exp(LAMBDA * (u - 1.0)));
        i += 1;
    }
    table
};

fn expm1_small(r: u32) -> u32 {
    const ONE: u64 = 1 << 32;
    let r = u64::from(r);
    let z = ONE + r / 6;
    let a = ONE + ((r * z) >> 32) / 5;
    let b = ONE + ((r * a) >> 32) / 4;
    let c = ONE + ((r * b) >> 32) / 3;
    let d = ONE + ((r * c) >> 32) / 2;
    ((r * d + (1 << 31)) >> 32) as u32
}

fn loss(u: u64) -> u32 {
    let segment = (u >> SEGMENT_BITS) as usize;
    let rest = (u & ((1 << SEGMENT_BITS) - 1)) as u32;
    match (LOSS_AT.get(segment), SLOPE_AT.get(segment)) {
        (Some(&base), Some(&slope)) => {
            let lambda_r = rest * LAMBDA as u32;
            let within = (u64::from(slope) * u64::from(expm1_small(lambda_r)) + (1 << 31)) >> 32;
            base.saturating_add(within as u32)
        }
        _ => LOSS_AT[SEGMENTS],
    }
}

#[derive(Clone, Copy, Debug)]
struct Decay {
    micros: u32,
    reciprocal: u64,
}

impl Decay {
    fn new(micros: u32) -> Decay {
        Decay {
            micros,
            reciprocal: (1u64 << RECIPROCAL_SHIFT) / u64::from(micros),
        }
    }

    fn apply(&self, level: u32, elapsed: u64) -> u32 {
        if elapsed > u64::from(self.micros) {
            return 0;
        }
        let u = elapsed.saturating_mul(self.reciprocal) >> (RECIPROCAL_SHIFT - 32);
        let lost = (u64::from(level) * u64::from(loss(u))) >> 32;
        level.saturating_sub(lost as u32)
    }
}

// ---------------------------------------------------------------------------------------------
// The integrator, as integrator.rs ran it.

const FULL: u32 = 1 << 31;

#[derive(Clone, Copy, Debug, Default)]
struct Integrator {
    level: u32,
    last: u64,
    active: bool,
}

impl Integrator {
    fn elapsed(&self, now: Instant) -> u64 {
        now.micros_since(Instant::from_micros(self.last))
            .unwrap_or(0)
    }

    fn level(&self, decay: &Decay, now: Instant) -> u32 {
        decay.apply(self.level, self.elapsed(now))
    }

    fn is_active(&self, decay: &Decay, now: Instant) -> bool {
        self.active && self.elapsed(now) <= u64::from(decay.micros)
    }

    fn is_resting(&self, decay: &Decay, rest_us: u32, now: Instant) -> bool {
        let elapsed = self.elapsed(now);
        let tau = u64::from(decay.micros);
        self.active && elapsed > tau && elapsed <= tau.saturating_add(u64::from(rest_us))
    }

    /// `true` if accepted, `false` if resting.
    fn stimulate(&mut self, gain: u32, rest_us: u32, decay: &Decay, now: Instant) -> bool {
        if self.is_resting(decay, rest_us, now) {
            return false;
        }
        let was_active = self.is_active(decay, now);
        let sum = self.level(decay, now).saturating_add(gain);
        let level = if sum >= FULL { FULL } else { sum };
        *self = Integrator {
            level,
            last: now.as_micros(),
            active: was_active || level == FULL,
        };
        true
    }
}

// ---------------------------------------------------------------------------------------------
// The arbiter, as arbiter.rs ran it.

struct Connection {
    filter: pab_core::Filter,
    gain: u32,
    rest_us: u32,
    decay: Decay,
    integrator: Integrator,
}

struct Port {
    connections: Vec<Connection>,
    nodes: Vec<DecisionNode>,
    root: NodeRef,
}

/// The reference arbiter over a table.
pub struct Reference {
    ports: Vec<Port>,
}

/// The diagram walked node by node, as decision::evaluate did (at most 33 steps).
fn evaluate(nodes: &[DecisionNode], root: NodeRef, active: ConnectionSet) -> Option<u8> {
    let mut at = root;
    for _ in 0..=32 {
        match at.target() {
            Target::Nobody => return None,
            Target::Deliver(index) => return Some(index),
            Target::Node(index) => {
                let node = nodes.get(usize::from(index))?;
                at = if active.contains(node.var) {
                    node.high
                } else {
                    node.low
                };
            }
        }
    }
    None
}

impl Reference {
    pub fn new<const P: usize, const C: usize, const N: usize>(table: &Table<P, C, N>) -> Self {
        let ports = table
            .ports()
            .map(|view| Port {
                connections: view
                    .connections
                    .iter()
                    .map(|c| Connection {
                        filter: c.filter,
                        gain: c.stimulation.gain().raw(),
                        rest_us: c.stimulation.rest_us(),
                        decay: Decay::new(c.stimulation.decay_us()),
                        integrator: Integrator::default(),
                    })
                    .collect(),
                nodes: view.nodes.to_vec(),
                root: view.root,
            })
            .collect();
        Reference { ports }
    }

    pub fn reset(&mut self) {
        for port in &mut self.ports {
            for connection in &mut port.connections {
                connection.integrator = Integrator::default();
            }
        }
    }

    /// The verdicts, and the fed and delivered ports as bits.
    pub fn receive(&mut self, id: &Id, now: Instant) -> (u16, u16, Vec<PortVerdict>) {
        let mut fed_ports = 0u16;
        let mut delivered_ports = 0u16;
        let mut verdicts = Vec::new();
        for (index, port) in self.ports.iter_mut().enumerate() {
            let mut fed = ConnectionSet::EMPTY;
            let mut resting = ConnectionSet::EMPTY;
            for (k, connection) in port.connections.iter_mut().enumerate() {
                if connection.filter.matches(id) {
                    fed = fed.with(k as u8);
                    let accepted = connection.integrator.stimulate(
                        connection.gain,
                        connection.rest_us,
                        &connection.decay,
                        now,
                    );
                    if !accepted {
                        resting = resting.with(k as u8);
                    }
                }
            }
            if fed.is_empty() {
                continue;
            }
            let active = Self::port_activity(port, now);
            let selected = evaluate(&port.nodes, port.root, active).filter(|&i| active.contains(i));
            let delivered = selected.filter(|&i| fed.contains(i));
            fed_ports |= 1 << index;
            if delivered.is_some() {
                delivered_ports |= 1 << index;
            }
            verdicts.push(PortVerdict {
                port: index as u8,
                fed,
                resting,
                active,
                selected,
                delivered,
            });
        }
        (fed_ports, delivered_ports, verdicts)
    }

    fn port_activity(port: &Port, now: Instant) -> ConnectionSet {
        port.connections
            .iter()
            .enumerate()
            .filter(|(_, c)| c.integrator.is_active(&c.decay, now))
            .fold(ConnectionSet::EMPTY, |set, (k, _)| set.with(k as u8))
    }

    pub fn activity(&self, port: u8, now: Instant) -> ConnectionSet {
        self.ports
            .get(usize::from(port))
            .map_or(ConnectionSet::EMPTY, |p| Self::port_activity(p, now))
    }

    pub fn selected(&self, port: u8, now: Instant) -> Option<u8> {
        let p = self.ports.get(usize::from(port))?;
        let active = Self::port_activity(p, now);
        evaluate(&p.nodes, p.root, active).filter(|&i| active.contains(i))
    }

    pub fn level(&self, port: u8, connection: u8, now: Instant) -> Option<Level> {
        let c = self
            .ports
            .get(usize::from(port))?
            .connections
            .get(usize::from(connection))?;
        Level::from_raw(c.integrator.level(&c.decay, now))
    }

    pub fn is_resting(&self, port: u8, connection: u8, now: Instant) -> bool {
        self.ports
            .get(usize::from(port))
            .and_then(|p| p.connections.get(usize::from(connection)))
            .is_some_and(|c| c.integrator.is_resting(&c.decay, c.rest_us, now))
    }

    pub fn port_count(&self) -> usize {
        self.ports.len()
    }

    pub fn connection_count(&self, port: u8) -> usize {
        self.ports
            .get(usize::from(port))
            .map_or(0, |p| p.connections.len())
    }
}

impl Reference {
    /// Takes over `previous`'s state for every connection that is unchanged: same port, same
    /// index in the port, same filter and the same σ, τ and τr (the rule of
    /// `Arbiter::carry_over`, written out plainly); every other connection starts afresh.
    pub fn carry_from(&mut self, previous: &Reference) {
        for (p, port) in self.ports.iter_mut().enumerate() {
            for (k, connection) in port.connections.iter_mut().enumerate() {
                connection.integrator = Integrator::default();
                let Some(old) = previous.ports.get(p).and_then(|old| old.connections.get(k)) else {
                    continue;
                };
                if old.filter == connection.filter
                    && old.gain == connection.gain
                    && old.rest_us == connection.rest_us
                    && old.decay.micros == connection.decay.micros
                {
                    connection.integrator = old.integrator;
                }
            }
        }
    }
}
