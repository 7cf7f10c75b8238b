//! HBBA's message filters of one node's table: which of its connections the intention node may
//! throttle, and the filter profiles the table carries for it to switch to in one frame.
//!
//! **Filtered connections.** Every connection of the node that some strategy's `filters` names
//! (the first connection of that name, as [`Network::filter_targets`] addresses it for FilterSet).
//! They start closed on the board (DESIGN.md, "HBBA: decisions"); every other connection has no
//! filter.
//!
//! **Profiles.** Profile 0 (all closed) is implicit. The others are the filter settings of the
//! solver's selections that the node can meet: the selection for each set of classes desired
//! (every intensity 1, sets in increasing order of their bit mask, the classes in their order of
//! first appearance), each selection's φ per filtered connection (the φ of the selected strategy
//! that sets the connection, 0 where none does), distinct vectors in order of first
//! appearance, up to 15. With more than [`ENUMERATED_CLASSES`] classes only the sets of up to two
//! classes are tried. A selection whose vector is not among them is applied one filter at a time
//! (FilterSet): profiles save frames and make a switch atomic, they are not needed for it.

use pab_core::hbba::filters::{MAX_FILTERED, MessageFilters, STORED_PROFILES};
use pab_core::hbba::{DEFAULT_BUDGET, Intensities, MAX_CLASSES};

use crate::network::{Network, Node};

/// Up to this many classes, every set of desired classes is tried for profiles (2^8 solves).
pub const ENUMERATED_CLASSES: usize = 8;

/// The message filters of `node`'s table, whose connections are `connections` (indices into
/// [`Network::connections`], in the table's order). Errors name the node.
pub fn filters_of(
    network: &Network,
    node: &Node,
    connections: &[usize],
) -> Result<MessageFilters, String> {
    let mut filters = MessageFilters::default();
    let Some(hbba) = &network.hbba else {
        return Ok(filters);
    };
    // The connections a strategy filters (as `Network::filter_targets` addresses them).
    let filtered = |position: usize| {
        hbba.strategies
            .iter()
            .any(|s| s.filters.iter().any(|f| f.connection == position))
    };
    let mut positions: Vec<usize> = Vec::new();
    for (index, &position) in connections.iter().enumerate() {
        if !filtered(position) {
            continue;
        }
        let index = u16::try_from(index).map_err(|_| "too many connections".to_string())?;
        filters.connections.push(index).map_err(|_| {
            format!(
                "node `{}`: strategies filter more than {MAX_FILTERED} of its connections (the boards' capacity)",
                node.name
            )
        })?;
        positions.push(position);
    }
    if filters.connections.is_empty() {
        return Ok(filters);
    }
    let classes = hbba.classes.len().min(MAX_CLASSES);
    let sets: Vec<u32> = if classes <= ENUMERATED_CLASSES {
        (1..1u32 << classes).collect()
    } else {
        let mut sets: Vec<u32> = (0..classes).map(|c| 1 << c).collect();
        for a in 0..classes {
            for b in a + 1..classes {
                sets.push(1 << a | 1 << b);
            }
        }
        sets.sort_unstable();
        sets
    };
    let mut seen: Vec<Vec<u8>> = vec![vec![0; positions.len()]];
    for set in sets {
        let mut intensities: Intensities = [0; MAX_CLASSES];
        for (class, slot) in intensities.iter_mut().enumerate().take(classes) {
            if set & 1 << class != 0 {
                *slot = 1;
            }
        }
        // A set the solver cannot answer within its budget has no profile.
        let Ok(solved) = hbba.solve(&intensities, DEFAULT_BUDGET) else {
            continue;
        };
        let vector: Vec<u8> = positions
            .iter()
            .map(|&position| {
                solved
                    .strategies
                    .iter()
                    .filter_map(|&s| hbba.strategies.get(s))
                    .flat_map(|s| s.filters.iter())
                    .find(|f| f.connection == position)
                    .map_or(0, |f| u8::try_from(f.phi).unwrap_or(u8::MAX))
            })
            .collect();
        if seen.contains(&vector) {
            continue;
        }
        if filters.profiles.len() == STORED_PROFILES {
            break;
        }
        // One φ per filtered connection, and room (checked above).
        filters
            .push_profile(&vector)
            .map_err(|error| format!("node `{}`: {error}", node.name))?;
        seen.push(vector);
    }
    Ok(filters)
}
