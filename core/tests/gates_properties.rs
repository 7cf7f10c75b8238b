//! Properties of the dynamics part of a table, over random specs: a valid one (groups run, gate
//! sources, gate links on gate connections) goes through an image and back unchanged (serde's
//! encoder against the hand-written wire decoder), and one broken field at a time (a behaviour
//! beyond the source, a link to a connection that is not a gate's, a group number twice, a count
//! of 0 or 33, a context connection the table does not have, a scale or a timeout of 0) is refused
//! by `Table::push_dynamics` with the error that names it, leaving the table as it was.

use pab_core::dynamics::{
    Behaviour, Context, DynamicsError, Exclusion, GATE_SLOT_FILTER, GateLink, GateSource,
    GroupSpec, MAX_BEHAVIOURS, MAX_TIMEOUT_US, ONE, OWN, Params,
};
use pab_core::image;
use pab_core::table::TableError;
use pab_core::{
    Connection, DecisionNode, Endian, Field, Filter, Gain, NodeRef, Stimulation, Table,
};
use proptest::prelude::*;

/// A context before it is fitted to the table: a kind and numbers.
type RawContext = (u8, u32, u32, u32, u32, u8);
/// A group's raw parameters: step, τ offsets, behaviours (memory offset, requirements, context),
/// exclusions (i, j, γ), noise, seed, c, unit.
type RawGroup = (
    u32,
    [u32; 4],
    Vec<(u32, u32, RawContext)>,
    Vec<(u8, u8, u16)>,
    (u32, u32, u32, u32),
);

/// A valid dynamics part and the ports it sits on.
#[derive(Clone, Debug)]
struct Spec {
    /// Gate connections per port (connection 0 is the port's command topic).
    ports: Vec<u8>,
    groups: Vec<GroupSpec>,
    sources: Vec<GateSource>,
    links: Vec<GateLink>,
    /// The image's node id (no remote source is its own).
    node: u8,
}

fn connection(filter: Filter) -> Connection {
    Connection {
        filter,
        stimulation: Stimulation::new(Gain::ONE, 50_000, 0).unwrap(),
    }
}

/// The ports alone: connection 0 delivers iff it and the first gate connection are active.
fn base_table(ports: &[u8]) -> Table {
    let mut table = Table::new();
    for (p, &gates) in ports.iter().enumerate() {
        let mut connections = vec![connection(Filter::exact(0x100 + p as u32, false).unwrap())];
        connections.extend((0..gates).map(|_| connection(GATE_SLOT_FILTER)));
        let (nodes, root) = if gates == 0 {
            (Vec::new(), NodeRef::deliver(0).unwrap())
        } else {
            (
                vec![
                    DecisionNode {
                        var: 0,
                        low: NodeRef::NOBODY,
                        high: NodeRef::node(1).unwrap(),
                    },
                    DecisionNode {
                        var: 1,
                        low: NodeRef::NOBODY,
                        high: NodeRef::deliver(0).unwrap(),
                    },
                ],
                NodeRef::node(0).unwrap(),
            )
        };
        table.push_port(&connections, &nodes, root).unwrap();
    }
    table
}

fn topic(a: u32, b: u32, c: u32, d: u32, e: u8) -> Context {
    let size = [1u8, 2, 4][b as usize % 3];
    Context::Topic {
        filter: Filter::exact(0x150 + a % 4, false).unwrap(),
        field: Field {
            offset: (c % u32::from(9 - size)) as u8,
            size,
            signed: e & 1 != 0,
            endian: if e & 2 != 0 {
                Endian::Big
            } else {
                Endian::Little
            },
        },
        scale: d.max(1),
        timeout_us: 1 + c % MAX_TIMEOUT_US,
    }
}

fn context(raw: RawContext, ports: &[u8]) -> Context {
    let (kind, a, b, c, d, e) = raw;
    match kind % 3 {
        0 => Context::Constant(a % (ONE as u32 + 1)),
        1 => {
            let port = a as usize % ports.len();
            Context::Connection {
                port: port as u8,
                connection: (b % (u32::from(ports[port]) + 1)) as u8,
            }
        }
        _ => topic(a, b, c, d, e),
    }
}

/// Valid parameters: every τ at least 4 steps, Σγ within dt (2 + Σγ) / τ ≤ 1.
fn group(raw: RawGroup, number: u8, ports: &[u8]) -> GroupSpec {
    let (step, taus, behaviours, exclusions, (noise, seed, c, unit)) = raw;
    let mut params = Params::new();
    params.step_us = step;
    let tau = |offset: u32| 4 * step + offset;
    (
        params.tau_us,
        params.tau_rho_fast_us,
        params.tau_rho_slow_us,
        params.tau_n_us,
    ) = (tau(taus[0]), tau(taus[1]), tau(taus[2]), tau(taus[3]));
    (params.noise, params.seed, params.c, params.unit_us) = (noise, seed, c, unit);
    let count = behaviours.len();
    let members = u32::MAX >> (32 - count);
    let mut contexts = heapless::Vec::new();
    for &(memory, requires, raw) in &behaviours {
        params
            .behaviours
            .push(Behaviour {
                memory_us: tau(memory),
                requires: requires & members,
            })
            .unwrap();
        contexts.push(context(raw, ports)).unwrap();
    }
    let budget = (256 * u64::from(params.tau_us) / u64::from(step)).saturating_sub(512);
    let mut sums = [0u64; MAX_BEHAVIOURS];
    for (i, j, gamma) in exclusions {
        let (i, j) = (i % count as u8, j % count as u8);
        let room = (budget - sums[usize::from(i)]).min(u64::from(u16::MAX));
        let declared = params
            .exclusions
            .iter()
            .any(|e| e.behaviour == i && e.by == j);
        if i == j || declared || room == 0 {
            continue;
        }
        let gamma = 1 + gamma % room as u16;
        sums[usize::from(i)] += u64::from(gamma);
        params
            .exclusions
            .push(Exclusion {
                behaviour: i,
                by: j,
                gamma,
            })
            .unwrap();
    }
    assert_eq!(params.validate(), Ok(()));
    GroupSpec {
        number,
        params,
        contexts,
    }
}

fn raw_context() -> impl Strategy<Value = RawContext> {
    (
        any::<u8>(),
        any::<u32>(),
        any::<u32>(),
        any::<u32>(),
        any::<u32>(),
        any::<u8>(),
    )
}

fn raw_group() -> impl Strategy<Value = RawGroup> {
    (
        prop_oneof![Just(1_000u32), 1u32..=20_000],
        [0u32..=100_000, 0..=100_000, 0..=1_000_000, 0..=100_000],
        prop::collection::vec(
            (0u32..=1_000_000, any::<u32>(), raw_context()),
            1..=MAX_BEHAVIOURS,
        ),
        prop::collection::vec((any::<u8>(), any::<u8>(), any::<u16>()), 0..40),
        (1u32.., 1u32.., any::<u32>(), 1u32..=1_000_000),
    )
}

/// Valid specs: 1 to 3 ports of 0 to 8 gate connections, 0 to 2 groups run, the own sources of
/// some, remote sources up to 4 in all, most gate connections linked.
fn spec() -> impl Strategy<Value = Spec> {
    (
        prop::collection::vec(0u8..=8, 1..=3),
        prop::collection::vec(raw_group(), 0..=2),
        prop::collection::vec(any::<bool>(), 2),
        prop::collection::vec((1u8..=127, 1u8..=32), 0..=4),
        prop::collection::vec((any::<bool>(), any::<u8>(), any::<u8>()), 24),
        prop::collection::vec(any::<u8>(), 6),
        1u8..=127,
        any::<u8>(),
    )
        .prop_map(
            |(ports, raw_groups, own, remote, link_raw, numbers, node, rotate)| {
                // Numbers: one per group and source, all different.
                let mut used: Vec<u8> = Vec::new();
                let mut unique = |wanted: u8| {
                    let mut number = wanted;
                    while used.contains(&number) {
                        number = number.wrapping_add(1);
                    }
                    used.push(number);
                    number
                };
                let groups: Vec<GroupSpec> = raw_groups
                    .into_iter()
                    .enumerate()
                    .map(|(g, raw)| group(raw, unique(numbers[g]), &ports))
                    .collect();
                let mut sources: Vec<GateSource> = groups
                    .iter()
                    .zip(&own)
                    .filter(|(_, own)| **own)
                    .map(|(g, _)| GateSource {
                        owner: OWN,
                        group: g.number,
                        behaviours: g.params.behaviours.len() as u8,
                    })
                    .collect();
                for (k, &(owner, behaviours)) in remote.iter().enumerate() {
                    if sources.len() == 4 {
                        break;
                    }
                    let owner = if owner == node {
                        owner % 127 + 1
                    } else {
                        owner
                    };
                    sources.push(GateSource {
                        owner,
                        group: unique(numbers[2 + k]),
                        behaviours,
                    });
                }
                if !sources.is_empty() {
                    let len = sources.len();
                    sources.rotate_left(usize::from(rotate) % len);
                }
                let mut links = Vec::new();
                let mut raw = link_raw.into_iter();
                for (p, &gates) in ports.iter().enumerate() {
                    for connection in 1..=gates {
                        let (linked, source, behaviour) = raw.next().unwrap_or((false, 0, 0));
                        if sources.is_empty() || !linked {
                            continue;
                        }
                        let source = usize::from(source) % sources.len();
                        links.push(GateLink {
                            source: source as u8,
                            behaviour: behaviour % sources[source].behaviours,
                            port: p as u8,
                            connection,
                        });
                    }
                }
                Spec {
                    ports,
                    groups,
                    sources,
                    links,
                    node,
                }
            },
        )
}

/// A topic context with another scale or timeout.
fn with_topic(context: Context, scale: Option<u32>, timeout: Option<u32>) -> Context {
    let Context::Topic {
        filter,
        field,
        scale: s,
        timeout_us,
    } = context
    else {
        return context;
    };
    Context::Topic {
        filter,
        field,
        scale: scale.unwrap_or(s),
        timeout_us: timeout.unwrap_or(timeout_us),
    }
}

/// One field of a valid spec broken, and the error that names it; `None` when the spec has
/// nothing to break that way (no link, one group, ...).
fn broken(spec: &Spec, kind: u8, pick: usize) -> Option<(Spec, DynamicsError)> {
    let mut bad = spec.clone();
    let error = match kind % 9 {
        // A behaviour at or beyond the source's count.
        0 if !spec.links.is_empty() => {
            let k = pick % spec.links.len();
            let source = spec.sources[usize::from(spec.links[k].source)];
            bad.links[k].behaviour = source.behaviours + (pick % 3) as u8;
            DynamicsError::Link { link: k as u8 }
        }
        // A link to the port's command, not a gate connection.
        1 if !spec.links.is_empty() => {
            let k = pick % spec.links.len();
            bad.links[k].connection = 0;
            DynamicsError::Link { link: k as u8 }
        }
        // Two groups run under one number.
        2 if spec.groups.len() == 2 => {
            bad.groups[1].number = spec.groups[0].number;
            DynamicsError::DuplicateGroup {
                number: spec.groups[0].number,
            }
        }
        // A group read from another node under the number of one run here.
        3 if !spec.groups.is_empty() && spec.sources.iter().any(|s| s.owner != OWN) => {
            let remote: Vec<usize> = (0..spec.sources.len())
                .filter(|&s| spec.sources[s].owner != OWN)
                .collect();
            let s = remote[pick % remote.len()];
            let number = spec.groups[pick % spec.groups.len()].number;
            bad.sources[s].group = number;
            // Reported at the first source that then clashes (an own source of that number
            // coming first clashes at `s` too).
            DynamicsError::DuplicateGroup { number }
        }
        // A count of 0 or 33.
        4 | 5 if !spec.sources.is_empty() => {
            let s = pick % spec.sources.len();
            bad.sources[s].behaviours = if kind % 9 == 4 { 0 } else { 33 };
            DynamicsError::Source { source: s as u8 }
        }
        // A context connection beyond the port, or a port beyond the table.
        6..=8 if !spec.groups.is_empty() => {
            let g = pick % spec.groups.len();
            let b = (pick / 2) % spec.groups[g].contexts.len();
            let p = pick % spec.ports.len();
            bad.groups[g].contexts[b] = match (kind % 9, pick % 2) {
                (6, 0) => Context::Connection {
                    port: p as u8,
                    connection: spec.ports[p] + 1,
                },
                (6, _) => Context::Connection {
                    port: spec.ports.len() as u8,
                    connection: 0,
                },
                (7, _) => with_topic(topic(pick as u32, 0, 7, 1, 0), Some(0), None),
                _ => with_topic(topic(pick as u32, 1, 7, 255 * 256, 0), None, Some(0)),
            };
            DynamicsError::Context {
                group: g as u8,
                behaviour: b as u8,
            }
        }
        _ => return None,
    };
    Some((bad, error))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, failure_persistence: None, ..ProptestConfig::default() })]

    /// A valid spec is accepted, and its image (serde's encoder) loads (the hand-written decoder)
    /// to the same table, for its node.
    #[test]
    fn valid_specs_round_trip_through_an_image(spec in spec(), version in 1u32..) {
        let mut table = base_table(&spec.ports);
        table.push_dynamics(&spec.groups, &spec.sources, &spec.links).unwrap();
        prop_assert_eq!(table.dynamics(), &spec.groups[..]);
        prop_assert_eq!(table.gate_sources(), &spec.sources[..]);
        prop_assert_eq!(table.gate_links(), &spec.links[..]);
        let mut out = vec![0; image::MAX_IMAGE_LEN];
        let len = image::encode(&table, spec.node, version, &mut out).unwrap();
        let loaded = image::load::<16, 512, 2048>(&out[..len]).unwrap();
        prop_assert_eq!(loaded.header.node_id, spec.node);
        prop_assert_eq!(loaded.header.table_version, version);
        prop_assert_eq!(loaded.table, table);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    /// One field broken at a time: refused with the error naming it, the table unchanged.
    #[test]
    fn a_broken_field_is_refused_and_changes_nothing(
        spec in spec(),
        kind in any::<u8>(),
        pick in any::<usize>(),
    ) {
        // The first kind that applies, from `kind` on.
        let Some((bad, expected)) = (0..9).find_map(|k| broken(&spec, kind.wrapping_add(k), pick))
        else {
            return Ok(());
        };
        let mut table = base_table(&spec.ports);
        let before = table.clone();
        let error = table.push_dynamics(&bad.groups, &bad.sources, &bad.links).unwrap_err();
        prop_assert_eq!(error, TableError::Dynamics(expected), "{:?}", bad);
        prop_assert_eq!(&table, &before);
        // The valid spec still goes in after the refusal.
        table.push_dynamics(&spec.groups, &spec.sources, &spec.links).unwrap();
    }
}
