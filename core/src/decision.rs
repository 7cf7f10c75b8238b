//! The precompiled decision of a port: activity mask → the one connection that may deliver.
//!
//! The host proves that for every mask at most one connection i has x_i ∧ Φ_i(x), then compiles
//! the function mask → i (or none) into a multi-terminal binary decision diagram over the mask's
//! bits, flattened into an array. A node tests one connection's activity bit and goes to its `low`
//! (inactive) or `high` (active) child; a child is another node or a terminal.
//!
//! Why this form: evaluation is a walk of at most one node per connection (≤ 32 steps, a load and
//! a bit test each), and the diagram of typical rule sets (inhibitions, priorities) grows linearly
//! with the number of connections, where a truth table would need 2^n entries.
//!
//! At run time the arbiter walks a form of the diagram built when the table is loaded, where a
//! node tests a set of connections at once: a priority run (a chain of nodes each of which lets
//! its own connection deliver, else goes on) is one step, a count-trailing-zeros of the mask.
//!
//! Why the loader can trust it: [`validate`] checks that every child comes later in the array than
//! its parent and tests a later bit. So every walk ends, in at most one step per connection, and
//! every reference is in bounds, whatever bytes the image held.

use serde::{Deserialize, Serialize};

use crate::MAX_CONNECTIONS_PER_PORT;

/// A set of a port's connections, by their index in the port: bit i is connection i.
///
/// Used both for activity masks (which connections are active) and for the connections a frame
/// fed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConnectionSet(u32);

impl ConnectionSet {
    /// No connection.
    pub const EMPTY: ConnectionSet = ConnectionSet(0);

    /// The set whose bit i is connection i.
    pub const fn from_bits(bits: u32) -> Self {
        ConnectionSet(bits)
    }

    /// The bits.
    pub const fn bits(self) -> u32 {
        self.0
    }

    /// Whether connection `index` is in the set; false for indices ≥ 32. Out of line: four
    /// callers inlined it (36 bytes of the NUCLEO-G474RE's flash; 3 instructions more for a
    /// generic-16 frame on the emulated board, 371 -> 374, none for the arm's frames).
    #[inline(never)]
    pub const fn contains(self, index: u8) -> bool {
        match 1u32.checked_shl(index as u32) {
            Some(bit) => self.0 & bit != 0,
            None => false,
        }
    }

    /// The set with connection `index` added; unchanged for indices ≥ 32.
    pub const fn with(self, index: u8) -> Self {
        match 1u32.checked_shl(index as u32) {
            Some(bit) => ConnectionSet(self.0 | bit),
            None => self,
        }
    }

    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The indices in the set, in increasing order.
    pub fn iter(self) -> impl Iterator<Item = u8> {
        (0..MAX_CONNECTIONS_PER_PORT as u8).filter(move |&index| self.contains(index))
    }
}

/// A reference from a decision node (or a port's root) to a node or a terminal. Two bytes.
///
/// Encoding: `0..0xFF00` is the index of a node of the same port; `0xFF00 + i` is the terminal
/// "connection i delivers"; `0xFFFF` is the terminal "no connection delivers".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NodeRef(u16);

const TERMINAL_BASE: u16 = 0xFF00;
const NOBODY: u16 = 0xFFFF;

/// What a [`NodeRef`] designates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Target {
    /// The node at this index in the port's nodes.
    Node(u16),
    /// Connection i delivers.
    Deliver(u8),
    /// No connection delivers.
    Nobody,
}

impl NodeRef {
    /// The terminal "no connection delivers".
    pub const NOBODY: NodeRef = NodeRef(NOBODY);

    /// A reference to node `index` of the same port (`index < 0xFF00`).
    pub const fn node(index: u16) -> Option<NodeRef> {
        if index < TERMINAL_BASE {
            Some(NodeRef(index))
        } else {
            None
        }
    }

    /// The terminal "connection `index` delivers" (`index < 32`).
    pub const fn deliver(index: u8) -> Option<NodeRef> {
        if (index as usize) < MAX_CONNECTIONS_PER_PORT {
            Some(NodeRef(TERMINAL_BASE | index as u16))
        } else {
            None
        }
    }

    /// What it designates. Encodings between `0xFF20` and `0xFFFE` designate connections ≥ 32,
    /// which [`validate`] refuses.
    pub const fn target(self) -> Target {
        if self.0 == NOBODY {
            Target::Nobody
        } else if self.0 >= TERMINAL_BASE {
            Target::Deliver((self.0 - TERMINAL_BASE) as u8)
        } else {
            Target::Node(self.0)
        }
    }
}

/// One node of a port's decision diagram: test connection `var`'s activity. Six bytes in RAM,
/// three to seven in an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecisionNode {
    /// The index, in the port, of the connection whose activity bit is tested.
    pub var: u8,
    /// Where to go when it is inactive.
    pub low: NodeRef,
    /// Where to go when it is active.
    pub high: NodeRef,
}

// Not `#[non_exhaustive]`: the compiler's diagnostics (lang/src/compile.rs) name each variant.
/// Why a port's decision diagram was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecisionError {
    /// The root refers to a node that does not exist, or to a connection the port does not have.
    BadRoot,
    /// Node `node` tests a connection the port does not have.
    VariableOutOfRange {
        /// Index of the node in the port.
        node: u16,
    },
    /// Node `node` has a child that does not exist, is not after it in the array, tests a bit that
    /// is not after its own, or names a connection the port does not have.
    BadChild {
        /// Index of the node in the port.
        node: u16,
    },
}

impl core::fmt::Display for DecisionError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecisionError::BadRoot => f.write_str("decision root refers to nothing valid"),
            DecisionError::VariableOutOfRange { node } => {
                write!(
                    f,
                    "decision node {node} tests a connection the port does not have"
                )
            }
            DecisionError::BadChild { node } => write!(
                f,
                "decision node {node} has a child that is missing, out of order or names a connection the port does not have"
            ),
        }
    }
}

impl core::error::Error for DecisionError {}

/// Checks a port's diagram: `nodes` are the port's nodes, `root` its entry and `connections` the
/// number of connections on the port. Costs one pass over the nodes.
pub fn validate(
    nodes: &[DecisionNode],
    root: NodeRef,
    connections: u8,
) -> Result<(), DecisionError> {
    if !reference_ok(nodes, connections, root, None) {
        return Err(DecisionError::BadRoot);
    }
    for (index, node) in nodes.iter().enumerate() {
        let position = u16::try_from(index).unwrap_or(u16::MAX);
        if node.var >= connections {
            return Err(DecisionError::VariableOutOfRange { node: position });
        }
        let parent = Some((index, node.var));
        if !reference_ok(nodes, connections, node.low, parent)
            || !reference_ok(nodes, connections, node.high, parent)
        {
            return Err(DecisionError::BadChild { node: position });
        }
    }
    Ok(())
}

/// Whether `reference` is valid in a diagram of `nodes` on a port of `connections` connections:
/// "nobody", a terminal naming one of its connections, or a node that exists (with `after` =
/// `Some((parent, parent_var))`, a node after `parent` testing a connection after `parent_var`).
/// Out of line: a root and two children per node are checked with it, and each inlined copy
/// cost the boards' flash (60 bytes on the NUCLEO-G474RE).
#[inline(never)]
fn reference_ok(
    nodes: &[DecisionNode],
    connections: u8,
    reference: NodeRef,
    after: Option<(usize, u8)>,
) -> bool {
    match reference.target() {
        Target::Nobody => true,
        Target::Deliver(index) => index < connections,
        Target::Node(index) => {
            let index = usize::from(index);
            match (nodes.get(index), after) {
                (None, _) => false,
                (Some(_), None) => true,
                (Some(child), Some((parent, parent_var))) => {
                    index > parent && child.var > parent_var
                }
            }
        }
    }
}

/// Whether `root` may enter a diagram of `nodes` (already [`validate`]d) on a port of
/// `connections` connections: a node that exists, a terminal naming one of its connections, or
/// "nobody". Value ports check their connections' roots with it. One comparison.
pub fn root_ok(nodes: &[DecisionNode], root: NodeRef, connections: u8) -> bool {
    reference_ok(nodes, connections, root, None)
}

/// The connection that may deliver under `active`, or `None`.
///
/// At most one step per connection on a validated diagram. On a diagram that was not validated it
/// still returns, after at most 33 steps, and never indexes out of bounds: an invalid reference
/// answers `None`.
pub fn evaluate(nodes: &[DecisionNode], root: NodeRef, active: ConnectionSet) -> Option<u8> {
    let mut at = root;
    for _ in 0..=MAX_CONNECTIONS_PER_PORT {
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

/// A decision node in the form the arbiter walks it, built from a validated diagram when a table
/// is loaded ([`compile`]); the image keeps [`DecisionNode`]s. Eight bytes.
///
/// A step tests a set of connections at once: when none of `mask` is active the walk goes to
/// `low`; otherwise to `high`, or, when `high` is [`LOWEST`], the lowest active connection of
/// `mask` delivers. A node of the diagram tests one connection (`mask` is its bit); a
/// *priority run*, a path of nodes linked by their `low` children where each node's `high` is
/// "this node's connection delivers" (what a priority chain, an override stack or a
/// subsumption layer compiles to), becomes one step: the first active connection along the path
/// is the lowest set bit of `active & mask` (the diagram tests its variables in increasing
/// order), one count-trailing-zeros instead of a walk along the path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Step {
    mask: u32,
    low: u16,
    high: u16,
}

/// `Step::high` for "the lowest active connection of the mask delivers" (an encoding no
/// validated [`NodeRef`] uses: terminals name connections below 32).
const LOWEST: u16 = 0xFFFE;

impl Step {
    /// A placeholder, overwritten by [`compile`].
    pub(crate) const NOBODY: Step = Step {
        mask: 0,
        low: NOBODY,
        high: NOBODY,
    };
}

/// Writes into `steps` (as long as `nodes`) the steps of a diagram that [`validate`] accepted.
/// Each step's children are after it, as in the diagram, so [`walk`] ends. Costs one pass over
/// the nodes, from the last.
pub(crate) fn compile(nodes: &[DecisionNode], steps: &mut [Step]) {
    for (index, node) in nodes.iter().enumerate().rev() {
        // A validated node tests a connection below 32.
        let Some(bit) = 1u32.checked_shl(u32::from(node.var)) else {
            continue;
        };
        let delivers_own = node.high == NodeRef(TERMINAL_BASE | u16::from(node.var));
        let step = if delivers_own {
            // A priority node: merged with its low child if that is one too (the child, after
            // it, is already compiled: its mask holds the rest of the run, its low where the run
            // ends).
            let run = match node.low.target() {
                Target::Node(child) => steps
                    .get(usize::from(child))
                    .filter(|next| next.high == LOWEST),
                _ => None,
            };
            match run {
                Some(next) => Step {
                    mask: bit | next.mask,
                    low: next.low,
                    high: LOWEST,
                },
                None => Step {
                    mask: bit,
                    low: node.low.0,
                    high: LOWEST,
                },
            }
        } else {
            Step {
                mask: bit,
                low: node.low.0,
                high: node.high.0,
            }
        };
        if let Some(slot) = steps.get_mut(index) {
            *slot = step;
        }
    }
}

/// [`evaluate`] on the steps [`compile`] made of a validated diagram: the same answer for every
/// mask. One step per node on the path, a priority run counting as one; each step is a load, an
/// AND and a branch. Out of line: inlined, its copies took 384 bytes of a board's flash and kept
/// the callers' registers busy (the arbiter's frames cost 6 instructions more).
#[inline(never)]
pub(crate) fn walk(steps: &[Step], root: NodeRef, active: ConnectionSet) -> Option<u8> {
    let mut at = root.0;
    // Ends: every step's children are after it (validated diagram, preserved by `compile`).
    loop {
        if at >= TERMINAL_BASE {
            return if at == NOBODY {
                None
            } else {
                Some((at - TERMINAL_BASE) as u8)
            };
        }
        let step = steps.get(usize::from(at))?;
        let hit = active.0 & step.mask;
        at = if hit == 0 {
            step.low
        } else if step.high == LOWEST {
            return Some(hit.trailing_zeros() as u8);
        } else {
            step.high
        };
    }
}

impl crate::wire::Decode for NodeRef {
    fn decode(r: &mut crate::wire::Reader<'_>) -> Self {
        NodeRef(r.u16())
    }
}

crate::wire::decode_struct!(DecisionNode { var, low, high });

#[cfg(test)]
mod tests {
    use super::*;

    fn node(var: u8, low: NodeRef, high: NodeRef) -> DecisionNode {
        DecisionNode { var, low, high }
    }

    fn deliver(index: u8) -> NodeRef {
        NodeRef::deliver(index).unwrap()
    }

    fn at(index: u16) -> NodeRef {
        NodeRef::node(index).unwrap()
    }

    #[test]
    fn walks_the_diagram() {
        // x1 ? C1 : (x0 ? C0 : nobody), ordered by variable: test x0 first.
        let nodes = [
            node(0, at(1), at(2)),
            node(1, NodeRef::NOBODY, deliver(1)),
            node(1, deliver(0), deliver(1)),
        ];
        validate(&nodes, at(0), 2).unwrap();
        let cases = [
            (0b00, None),
            (0b01, Some(0)),
            (0b10, Some(1)),
            (0b11, Some(1)),
        ];
        for (mask, expected) in cases {
            assert_eq!(
                evaluate(&nodes, at(0), ConnectionSet::from_bits(mask)),
                expected
            );
        }
    }

    #[test]
    fn terminals_can_be_roots() {
        validate(&[], NodeRef::NOBODY, 0).unwrap();
        validate(&[], deliver(0), 1).unwrap();
        assert_eq!(evaluate(&[], deliver(0), ConnectionSet::EMPTY), Some(0));
        assert_eq!(validate(&[], deliver(1), 1), Err(DecisionError::BadRoot));
        assert_eq!(validate(&[], at(0), 1), Err(DecisionError::BadRoot));
    }

    #[test]
    fn cycles_and_backward_references_are_refused() {
        let cycle = [node(0, at(0), deliver(0))];
        assert_eq!(
            validate(&cycle, at(0), 1),
            Err(DecisionError::BadChild { node: 0 })
        );
        // Evaluation on an unvalidated cycle still terminates.
        assert_eq!(evaluate(&cycle, at(0), ConnectionSet::EMPTY), None);
        let same_var = [
            node(0, at(1), NodeRef::NOBODY),
            node(0, NodeRef::NOBODY, deliver(0)),
        ];
        assert_eq!(
            validate(&same_var, at(0), 1),
            Err(DecisionError::BadChild { node: 0 })
        );
        let missing = [node(0, at(7), NodeRef::NOBODY)];
        assert_eq!(
            validate(&missing, at(0), 1),
            Err(DecisionError::BadChild { node: 0 })
        );
        let bad_var = [node(3, NodeRef::NOBODY, NodeRef::NOBODY)];
        assert_eq!(
            validate(&bad_var, at(0), 2),
            Err(DecisionError::VariableOutOfRange { node: 0 })
        );
        let bad_terminal = [node(0, NodeRef(0xFF05), NodeRef::NOBODY)];
        assert_eq!(
            validate(&bad_terminal, at(0), 2),
            Err(DecisionError::BadChild { node: 0 })
        );
    }

    #[test]
    fn steps_decide_as_the_diagram() {
        // A priority chain (one step), a chain with a non-priority node in the middle and a
        // shared tail, and the diagram above; every mask.
        let chain: Vec<DecisionNode> = (0..6)
            .map(|k| {
                node(
                    k,
                    if k < 5 {
                        at(u16::from(k) + 1)
                    } else {
                        NodeRef::NOBODY
                    },
                    deliver(k),
                )
            })
            .collect();
        let mixed = [
            node(0, at(1), deliver(0)),
            node(1, at(3), at(2)),
            node(2, at(3), deliver(5)),
            node(3, at(4), deliver(3)),
            node(4, deliver(1), deliver(4)),
        ];
        let figure = [
            node(0, at(1), at(2)),
            node(1, NodeRef::NOBODY, deliver(1)),
            node(1, deliver(0), deliver(1)),
        ];
        for nodes in [&chain[..], &mixed[..], &figure[..]] {
            validate(nodes, at(0), 6).unwrap();
            let mut steps = std::vec![Step::NOBODY; nodes.len()];
            compile(nodes, &mut steps);
            for mask in 0..1 << 6 {
                let active = ConnectionSet::from_bits(mask);
                assert_eq!(walk(&steps, at(0), active), evaluate(nodes, at(0), active));
            }
        }
        // The chain is one step.
        let mut steps = std::vec![Step::NOBODY; chain.len()];
        compile(&chain, &mut steps);
        assert_eq!(
            (steps[0].mask, steps[0].low, steps[0].high),
            (0x3F, NOBODY, LOWEST)
        );
    }

    #[test]
    fn connection_sets() {
        let set = ConnectionSet::EMPTY.with(0).with(31).with(32);
        assert_eq!(set.bits(), 0x8000_0001);
        assert!(set.contains(31) && !set.contains(32) && !set.contains(200));
        assert_eq!(
            set.iter().collect::<heapless::Vec<u8, 4>>().as_slice(),
            &[0, 31]
        );
    }
}
