//! The table image loader fed corrupted bytes: every single-bit flip, every truncation, bodies
//! rewritten under a recomputed CRC (so that the postcard decoder and `Table::validate` see them),
//! random bytes. Whatever the bytes, `load` answers with a typed error or a table that passes
//! validation and that an `Arbiter` runs.

use crate::common;

use common::{at, deliver, node, priority_chain};

use std::cell::Cell;

use embedded_can::{ExtendedId, StandardId};
use pab_core::crc32::{Crc32, crc32};
use pab_core::image::{
    self, FORMAT_VERSION, HEADER_LEN, Header, LoadError, Loaded, MAGIC, MAX_IMAGE_LEN, TableSize,
};
use pab_core::integrator::MAX_TIME_US;
use pab_core::table::TableError;
use pab_core::{
    Arbiter, BoardTable, Connection, Consumer, DecisionNode, Filter, Gain, Id, Instant,
    MAX_CONNECTIONS, MAX_CONNECTIONS_PER_PORT, MAX_DECISION_NODES, MAX_PORTS, NodeRef, OutputId,
    OutputIdError, Reception, Stimulation, Table, ValueSpec,
};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use serde::Serialize;

/// `image::load` into a table of the default capacities.
fn load_default(bytes: &[u8]) -> Result<Loaded, LoadError> {
    image::load(bytes)
}

// ---------------------------------------------------------------------------------------------
// Tables built through the public API.

fn stimulation(sigma: f64, tau: f64, rest: f64) -> Stimulation {
    Stimulation::from_seconds(sigma, tau, rest).expect("valid parameters")
}

fn standard(id: u32, stimulation: Stimulation) -> Connection {
    Connection {
        filter: Filter::exact(id, false).expect("valid filter"),
        stimulation,
    }
}

/// The port of the paper's Figure 1: C0 (face, 0x110) delivers iff x0 ∧ ¬x1, C1 (object, 0x111)
/// iff x1. σ = 0.2, τ = 3 s.
fn figure1_port() -> ([Connection; 2], [DecisionNode; 3], NodeRef) {
    let s = stimulation(0.2, 3.0, 0.0);
    let connections = [standard(0x110, s), standard(0x111, s)];
    let nodes = [
        node(0, at(1), at(2)),
        node(1, NodeRef::NOBODY, deliver(1)),
        node(1, deliver(0), deliver(1)),
    ];
    (connections, nodes, at(0))
}

fn figure1_table() -> Table {
    let (connections, nodes, root) = figure1_port();
    let mut table = Table::new();
    table
        .push_port(&connections, &nodes, root)
        .expect("valid port");
    table
}

/// Several ports: Figure 1, a 32-connection priority chain with every kind of filter and a spread
/// of parameters, a fan-out port on the face topic, an empty port, and a port with a virtual
/// connection (C2 coordinates, never delivers).
fn big_table() -> Table {
    let mut table = Table::new();
    let (connections, nodes, root) = figure1_port();
    table
        .push_port(&connections, &nodes, root)
        .expect("figure 1");

    let chain: Vec<Connection> = (0..32u32)
        .map(|k| {
            let filter = match k % 4 {
                0 => Filter::exact(0x200 + k, false),
                1 => Filter::exact(0x1ABC_0000 + k, true),
                2 => Filter::new(0x300 + (k << 4), 0x7F0, false),
                _ => Filter::new(0x1000_0000 | (k << 8), 0x1FFF_FF00, true),
            }
            .expect("valid filter");
            let sigma = [1.0, 0.2, 1e-3, 2f64.powi(-16)][(k % 4) as usize];
            let tau = [1e-6, 0.05, 3.0, 3600.0][(k / 4 % 4) as usize];
            let rest = [0.0, 0.5, 3600.0][(k % 3) as usize];
            Connection {
                filter,
                stimulation: stimulation(sigma, tau, rest),
            }
        })
        .collect();
    table
        .push_port(&chain, &priority_chain(32), at(0))
        .expect("chain");

    table
        .push_port(
            &[standard(0x110, stimulation(1.0, 1.0, 0.5))],
            &[],
            deliver(0),
        )
        .expect("fan-out");
    table.push_port(&[], &[], NodeRef::NOBODY).expect("empty");

    let s = stimulation(0.5, 0.2, 0.0);
    let connections = [standard(0x400, s), standard(0x401, s), standard(0x402, s)];
    let nodes = [
        node(0, at(1), at(2)),
        node(1, NodeRef::NOBODY, at(3)),
        node(2, deliver(0), NodeRef::NOBODY),
        node(2, NodeRef::NOBODY, deliver(1)),
    ];
    table
        .push_port(&connections, &nodes, at(0))
        .expect("virtual");
    // Two gateways: the fan-out port re-publishes on a standard id, the virtual one on an
    // extended id.
    let standard_out = OutputId::new(0x300, false).expect("11-bit id");
    let extended_out = OutputId::new(0x1ABC_DEF0, true).expect("29-bit id");
    table
        .set_consumer(2, Consumer::Republish(standard_out))
        .expect("port 2");
    table
        .set_consumer(4, Consumer::Republish(extended_out))
        .expect("port 4");
    table.validate().expect("valid table");
    table
}

/// Every capacity used to the full, with the widest encodings: the largest image there is.
fn full_table() -> Table {
    let mut table = Table::new();
    let nodes_per_port = MAX_DECISION_NODES / MAX_PORTS;
    for port in 0..MAX_PORTS as u32 {
        let connections: Vec<Connection> = (0..MAX_CONNECTIONS_PER_PORT as u32)
            .map(|k| Connection {
                filter: Filter::new(0x1F00_0000 | (port << 8) | k, 0x1FFF_FFFF, true)
                    .expect("valid filter"),
                stimulation: Stimulation::new(Gain::ONE, MAX_TIME_US, MAX_TIME_US)
                    .expect("valid parameters"),
            })
            .collect();
        let mut nodes = priority_chain(MAX_CONNECTIONS_PER_PORT as u8);
        // Unreachable filler nodes (valid: terminal children only) up to the node capacity.
        while nodes.len() < nodes_per_port {
            nodes.push(node(31, deliver(31), deliver(30)));
        }
        table
            .push_port(&connections, &nodes, at(0))
            .expect("full port");
    }
    table
}

fn encode(table: &Table, node_id: u8, version: u32) -> Vec<u8> {
    let mut out = vec![0; MAX_IMAGE_LEN];
    let len = image::encode(table, node_id, version, &mut out).expect("encodes");
    out.truncate(len);
    out
}

/// The images every exhaustive test sweeps.
fn images() -> Vec<(&'static str, Table, Vec<u8>)> {
    let tables = [
        ("empty", Table::new(), 0, 0),
        ("figure 1", figure1_table(), 7, 1),
        ("big", big_table(), 0xFE, 0xDEAD_BEEF),
    ];
    tables
        .into_iter()
        .map(|(name, table, node_id, version)| {
            let bytes = encode(&table, node_id, version);
            (name, table, bytes)
        })
        .collect()
}

/// `image` with its body replaced by `body`, the length field and the CRC made right for it.
fn with_body(image: &[u8], body: &[u8]) -> Vec<u8> {
    let mut out = image[..HEADER_LEN].to_vec();
    out[12..16].copy_from_slice(&(body.len() as u32).to_le_bytes());
    let crc = Crc32::new().update(&out[..16]).update(body).finish();
    out[16..20].copy_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(body);
    out
}

fn frame_id(filter: &Filter) -> Id {
    if filter.is_extended() {
        Id::Extended(ExtendedId::new(filter.id()).expect("29-bit id"))
    } else {
        Id::Standard(StandardId::new(filter.id() as u16).expect("11-bit id"))
    }
}

/// Runs an accepted table: the arbiter takes it and every verdict is coherent, over `rounds`
/// rounds of frames on the table's first 48 topics and two others. Returns how many frames were
/// delivered somewhere.
fn exercise(table: &Table, rounds: u64) -> usize {
    table.validate().expect("a loaded table validates");
    let mut arbiter = Arbiter::new(table.clone()).expect("the arbiter takes a loaded table");
    let mut ids: Vec<Id> = table
        .connections()
        .iter()
        .take(48)
        .map(|c| frame_id(&c.filter))
        .collect();
    ids.push(Id::Standard(StandardId::ZERO));
    ids.push(Id::Extended(ExtendedId::MAX));
    let mut delivered = 0;
    for round in 0..rounds {
        for (k, id) in ids.iter().enumerate() {
            let now = Instant::from_micros(round * 700_000 + k as u64);
            let (reception, verdicts) = common::receive(&mut arbiter, *id, now);
            for verdict in &verdicts {
                assert!(!verdict.fed.is_empty());
                assert_eq!(verdict.resting.bits() & !verdict.fed.bits(), 0);
            }
            delivered += usize::from(!reception.delivered.is_empty());
        }
    }
    delivered
}

// ---------------------------------------------------------------------------------------------
// Valid images.

#[test]
fn valid_images_round_trip() {
    for (name, table, bytes) in images() {
        let loaded = load_default(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        let body_len = (bytes.len() - HEADER_LEN) as u32;
        assert_eq!(loaded.table, table, "{name}");
        assert_eq!(&bytes[..4], &MAGIC);
        assert_eq!(image::read_header(&bytes), Ok(loaded.header), "{name}");
        assert_eq!(loaded.header.body_len, body_len, "{name}");
        assert_eq!(
            loaded.header.crc,
            crc32(&[&bytes[..16], &bytes[HEADER_LEN..]].concat()),
            "{name}"
        );
        // Encoding is deterministic: the loaded table gives the same bytes again.
        let header = loaded.header;
        assert_eq!(
            encode(&loaded.table, header.node_id, header.table_version),
            bytes
        );
    }
    let bytes = encode(&big_table(), 0xFE, 0xDEAD_BEEF);
    assert_eq!(
        load_default(&bytes).map(|l| l.header),
        Ok(Header {
            node_id: 0xFE,
            table_version: 0xDEAD_BEEF,
            body_len: (bytes.len() - HEADER_LEN) as u32,
            crc: u32::from_le_bytes(bytes[16..20].try_into().unwrap()),
        })
    );
    assert!(exercise(&big_table(), 4) > 0);
}

#[test]
fn a_table_at_full_capacity_fits_the_image_limit() {
    let table = full_table();
    assert_eq!(table.port_count(), MAX_PORTS);
    assert_eq!(table.node_count(), MAX_DECISION_NODES);
    let bytes = encode(&table, 1, 1);
    eprintln!(
        "full-capacity image: {} of {MAX_IMAGE_LEN} bytes",
        bytes.len()
    );
    assert!(bytes.len() <= MAX_IMAGE_LEN);
    assert_eq!(load_default(&bytes).map(|l| l.table), Ok(table));
    // A sample of flips in the big image is still caught (the CRC covers it all).
    for bit in (0..bytes.len() * 8).step_by(997) {
        let mut flipped = bytes.clone();
        flipped[bit / 8] ^= 1 << (bit % 8);
        assert!(load_default(&flipped).is_err(), "bit {bit}");
    }
}

#[test]
fn encoding_refuses_small_buffers_and_invalid_tables() {
    let table = big_table();
    let len = encode(&table, 0, 0).len();
    for size in [0, HEADER_LEN - 1, HEADER_LEN, len - 1] {
        let mut out = vec![0; size];
        assert_eq!(
            image::encode(&table, 0, 0, &mut out),
            Err(image::EncodeError::BufferTooSmall),
            "{size}"
        );
    }
    let mut out = vec![0; len];
    assert_eq!(image::encode(&table, 0, 0, &mut out), Ok(len));
}

// ---------------------------------------------------------------------------------------------
// Corruption the CRC and the header catch.

/// What `load` must say about `image` with bit `bit` flipped, derived from the layout alone.
fn expected_for_flip(image: &[u8], bit: usize) -> LoadError {
    let mut flipped = image.to_vec();
    flipped[bit / 8] ^= 1 << (bit % 8);
    let byte = bit / 8;
    let original_crc = u32::from_le_bytes(image[16..20].try_into().unwrap());
    let crc_of = |bytes: &[u8]| crc32(&[&bytes[..16], &bytes[HEADER_LEN..]].concat());
    match byte {
        0..4 => LoadError::BadMagic,
        4 | 5 => LoadError::UnsupportedFormat {
            found: u16::from_le_bytes([flipped[4], flipped[5]]),
            expected: FORMAT_VERSION,
        },
        7 => LoadError::ReservedByte,
        12..16 => {
            let declared = u32::from_le_bytes(flipped[12..16].try_into().unwrap());
            let total = HEADER_LEN + declared as usize;
            if declared as usize > MAX_IMAGE_LEN - HEADER_LEN {
                LoadError::TooLarge { body_len: declared }
            } else if total > image.len() {
                LoadError::Truncated {
                    needed: total,
                    got: image.len(),
                }
            } else {
                LoadError::TrailingBytes {
                    extra: image.len() - total,
                }
            }
        }
        16..20 => LoadError::Crc {
            stored: u32::from_le_bytes(flipped[16..20].try_into().unwrap()),
            computed: original_crc,
        },
        // Node id, table version, body: covered by the CRC, nothing before it notices.
        _ => LoadError::Crc {
            stored: original_crc,
            computed: crc_of(&flipped),
        },
    }
}

#[test]
fn every_single_bit_flip_is_refused_by_the_right_check() {
    let mut flips = 0;
    for (name, _, bytes) in images() {
        assert_eq!(bytes[4..6], FORMAT_VERSION.to_le_bytes());
        for bit in 0..bytes.len() * 8 {
            let mut flipped = bytes.clone();
            flipped[bit / 8] ^= 1 << (bit % 8);
            let expected = expected_for_flip(&bytes, bit);
            assert_eq!(
                load_default(&flipped),
                Err(expected.clone()),
                "{name}, bit {bit}"
            );
            // The header alone already tells for the fields before the length.
            if bit / 8 < 8 && bit / 8 != 6 {
                assert_eq!(
                    image::read_header(&flipped),
                    Err(expected),
                    "{name}, bit {bit}"
                );
            }
            flips += 1;
        }
    }
    eprintln!("single-bit flips refused: {flips}");
    assert!(flips > 5_000);
}

#[test]
fn every_truncation_is_refused() {
    let mut count = 0;
    for (name, _, bytes) in images() {
        for len in 0..bytes.len() {
            let needed = if len < HEADER_LEN {
                HEADER_LEN
            } else {
                bytes.len()
            };
            assert_eq!(
                load_default(&bytes[..len]),
                Err(LoadError::Truncated { needed, got: len }),
                "{name}, {len} bytes"
            );
            count += 1;
        }
    }
    assert!(count > 500);
}

#[test]
fn trailing_bytes_are_refused() {
    for (name, _, bytes) in images() {
        for extra in [1, 2, 7, 100] {
            for fill in [0x00, 0xFF] {
                let mut longer = bytes.clone();
                longer.resize(bytes.len() + extra, fill);
                assert_eq!(
                    load_default(&longer),
                    Err(LoadError::TrailingBytes { extra }),
                    "{name}"
                );
            }
        }
    }
}

#[test]
fn declared_lengths_beyond_the_limit_are_refused() {
    let bytes = encode(&figure1_table(), 1, 1);
    let limit = (MAX_IMAGE_LEN - HEADER_LEN) as u32;
    for declared in [limit + 1, limit + 2, 1 << 20, u32::MAX] {
        let mut header = bytes.clone();
        header[12..16].copy_from_slice(&declared.to_le_bytes());
        let expected = LoadError::TooLarge { body_len: declared };
        assert_eq!(image::read_header(&header), Err(expected.clone()));
        assert_eq!(load_default(&header), Err(expected.clone()));
        // Refused from the header alone: the receiver need not wait for the body.
        assert_eq!(image::read_header(&header[..HEADER_LEN]), Err(expected));
    }
    // Exactly at the limit is a length the loader accepts, and then waits for.
    let mut header = bytes.clone();
    header[12..16].copy_from_slice(&limit.to_le_bytes());
    assert!(image::read_header(&header).is_ok());
    assert_eq!(
        load_default(&header),
        Err(LoadError::Truncated {
            needed: MAX_IMAGE_LEN,
            got: bytes.len()
        })
    );
}

// ---------------------------------------------------------------------------------------------
// Corruption under a recomputed CRC: the decoder and the validator are on their own.

/// Outcomes of loading corrupted bodies.
#[derive(Debug, Default)]
struct Tally {
    loads: usize,
    accepted: usize,
    /// Accepted, and re-encoding the table does not give the corrupted body back (postcard takes
    /// overlong varints).
    accepted_non_canonical: usize,
    body: usize,
    body_trailing: usize,
    table: usize,
    /// Decodes, but into more than the default capacities (e.g. a port count raised past 16).
    exceeds_capacity: usize,
    other: usize,
}

impl Tally {
    fn load(&mut self, image: &[u8], original: &Table) {
        self.loads += 1;
        match load_default(image) {
            Ok(loaded) => {
                self.accepted += 1;
                assert_ne!(
                    &loaded.table, original,
                    "a changed body decoded to the same table"
                );
                exercise(&loaded.table, 2);
                let again = encode(
                    &loaded.table,
                    loaded.header.node_id,
                    loaded.header.table_version,
                );
                if again != image {
                    self.accepted_non_canonical += 1;
                }
            }
            Err(LoadError::Body(_)) => self.body += 1,
            Err(LoadError::BodyTrailingBytes) => self.body_trailing += 1,
            Err(LoadError::Table(_)) => self.table += 1,
            Err(LoadError::ExceedsCapacity { needed, capacity }) => {
                assert!(
                    needed.ports > capacity.ports
                        || needed.connections > capacity.connections
                        || needed.nodes > capacity.nodes
                );
                self.exceeds_capacity += 1;
            }
            Err(_) => self.other += 1,
        }
    }
}

#[test]
fn corrupted_bodies_with_a_recomputed_crc_never_panic() {
    let mut tally = Tally::default();
    for (_, table, bytes) in images() {
        let body = &bytes[HEADER_LEN..];
        // Sanity: with the body unchanged, the rebuilt image is the image.
        assert_eq!(with_body(&bytes, body), bytes);
        for bit in 0..body.len() * 8 {
            let mut corrupted = body.to_vec();
            corrupted[bit / 8] ^= 1 << (bit % 8);
            tally.load(&with_body(&bytes, &corrupted), &table);
        }
        for position in 0..body.len() {
            for value in [0x00, 0xFF, 0x7F, 0x80] {
                if body[position] == value {
                    continue;
                }
                let mut corrupted = body.to_vec();
                corrupted[position] = value;
                tally.load(&with_body(&bytes, &corrupted), &table);
            }
            // A byte lost or doubled, with the length and CRC fixed up.
            let mut shorter = body.to_vec();
            shorter.remove(position);
            tally.load(&with_body(&bytes, &shorter), &table);
            let mut longer = body.to_vec();
            longer.insert(position, body[position]);
            tally.load(&with_body(&bytes, &longer), &table);
        }
    }
    eprintln!("bodies corrupted under a recomputed CRC: {tally:?}");
    // Every layer was reached: the decoder refused some, the validator others, and some
    // corruptions give another valid table (a changed σ, τ or id), which then ran.
    assert_eq!(tally.other, 0, "{tally:?}");
    assert!(tally.loads > 10_000);
    assert!(
        tally.accepted > 100 && tally.body > 100 && tally.table > 100,
        "{tally:?}"
    );
    assert!(tally.body_trailing > 0, "{tally:?}");
}

/// A random body under a valid header and CRC, or a valid body with random bytes overwritten, or
/// random bytes (with and without a plausible start).
#[derive(Clone, Debug)]
enum Input {
    RandomBody(Vec<u8>),
    Overwritten(Vec<(prop::sample::Index, u8)>),
    Raw(Vec<u8>),
    RawWithMagic(Vec<u8>),
}

fn input_strategy() -> impl Strategy<Value = Input> {
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..400).prop_map(Input::RandomBody),
        prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)
            .prop_map(Input::Overwritten),
        prop::collection::vec(any::<u8>(), 0..64).prop_map(Input::Raw),
        prop::collection::vec(any::<u8>(), 0..64).prop_map(Input::RawWithMagic),
    ]
}

#[test]
fn random_bytes_never_panic() {
    let base = encode(&big_table(), 3, 3);
    let original = big_table();
    let loads = Cell::new(0usize);
    let accepted = Cell::new(0usize);
    let mut runner = TestRunner::new(Config {
        cases: 3000,
        failure_persistence: None,
        ..Config::default()
    });
    let result = runner.run(&input_strategy(), |input| {
        let bytes = match input {
            Input::RandomBody(body) => with_body(&base, &body),
            Input::Overwritten(writes) => {
                let mut body = base[HEADER_LEN..].to_vec();
                for (index, value) in writes {
                    *index.get_mut(&mut body) = value;
                }
                with_body(&base, &body)
            }
            Input::Raw(bytes) => bytes,
            Input::RawWithMagic(mut bytes) => {
                let start = [MAGIC.as_slice(), &FORMAT_VERSION.to_le_bytes(), &[0, 0]].concat();
                bytes.splice(0..0, start);
                bytes
            }
        };
        loads.set(loads.get() + 1);
        if let Ok(loaded) = load_default(&bytes) {
            accepted.set(accepted.get() + 1);
            prop_assert!(loaded.table.validate().is_ok());
            if loaded.table != original {
                exercise(&loaded.table, 4);
            }
        }
        Ok(())
    });
    if let Err(failure) = result {
        panic!("{failure}");
    }
    eprintln!(
        "random inputs: {} loads, {} accepted",
        loads.get(),
        accepted.get()
    );
    assert!(loads.get() >= 3000);
}

// ---------------------------------------------------------------------------------------------
// Tables that bypass the loader.

/// The serde shape of `Table` (its port record has private fields): written here to produce
/// bodies that no `Table` method would, and checked against the real encoding below.
#[derive(Serialize)]
struct RawTable {
    ports: Vec<RawPort>,
    connections: Vec<RawConnection>,
    nodes: Vec<DecisionNode>,
    roots: Vec<NodeRef>,
    groups: Vec<pab_core::ble::Group>,
    dynamics: Vec<pab_core::dynamics::GroupSpec>,
    gate_sources: Vec<pab_core::dynamics::GateSource>,
    gate_links: Vec<pab_core::dynamics::GateLink>,
    filters: pab_core::hbba::filters::MessageFilters,
    /// Formats 7 and 8: the schema server (none here).
    schema: Option<pab_core::schema::Setup>,
}

#[derive(Serialize)]
struct RawPort {
    connections: u8,
    nodes: u16,
    root: NodeRef,
    consumer: RawConsumer,
    value: Option<ValueSpec>,
}

/// The serde shape of `Consumer`.
#[derive(Clone, Copy, Serialize)]
enum RawConsumer {
    Local,
    #[allow(dead_code)]
    Republish {
        raw: u32,
        extended: bool,
    },
}

#[derive(Clone, Copy, Serialize)]
struct RawConnection {
    id: u32,
    mask: u32,
    extended: bool,
    gain: u32,
    decay_us: u32,
    rest_us: u32,
}

const GOOD: RawConnection = RawConnection {
    id: 0x110,
    mask: 0x7FF,
    extended: false,
    gain: 1 << 31,
    decay_us: 1_000_000,
    rest_us: 0,
};

fn postcard_bytes(value: &impl Serialize) -> Vec<u8> {
    let mut buffer = vec![0; MAX_IMAGE_LEN];
    let len = postcard::to_slice(value, &mut buffer).expect("fits").len();
    buffer.truncate(len);
    buffer
}

fn with_consumer(mut table: RawTable, consumer: RawConsumer) -> RawTable {
    table.ports[0].consumer = consumer;
    table
}

fn one_port(connections: Vec<RawConnection>, nodes: Vec<DecisionNode>, root: NodeRef) -> RawTable {
    RawTable {
        ports: vec![RawPort {
            connections: connections.len() as u8,
            nodes: nodes.len() as u16,
            root,
            consumer: RawConsumer::Local,
            value: None,
        }],
        connections,
        nodes,
        roots: vec![],
        groups: vec![],
        dynamics: vec![],
        gate_sources: vec![],
        gate_links: vec![],
        filters: Default::default(),
        schema: None,
    }
}

#[test]
fn deserialized_tables_are_validated_by_the_arbiter() {
    // The mirror matches the real layout.
    let mut real = Table::new();
    real.push_port(
        &[Connection {
            filter: Filter::exact(0x110, false).unwrap(),
            stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).unwrap(),
        }],
        &[node(0, NodeRef::NOBODY, deliver(0))],
        at(0),
    )
    .unwrap();
    let mirror = one_port(
        vec![GOOD],
        vec![node(0, NodeRef::NOBODY, deliver(0))],
        at(0),
    );
    let mirror_bytes = postcard_bytes(&mirror);
    assert_eq!(mirror_bytes, postcard_bytes(&real));
    assert_eq!(
        postcard::from_bytes::<Table>(&mirror_bytes),
        Ok(real.clone())
    );
    assert!(Arbiter::new(real.clone()).is_ok());
    // ... and so does a re-publishing consumer.
    let mut gateway = real.clone();
    let out = OutputId::new(0x1ABC_DEF0, true).unwrap();
    gateway.set_consumer(0, Consumer::Republish(out)).unwrap();
    let gateway_mirror = with_consumer(
        one_port(
            vec![GOOD],
            vec![node(0, NodeRef::NOBODY, deliver(0))],
            at(0),
        ),
        RawConsumer::Republish {
            raw: 0x1ABC_DEF0,
            extended: true,
        },
    );
    assert_eq!(postcard_bytes(&gateway_mirror), postcard_bytes(&gateway));
    assert_ne!(postcard_bytes(&gateway), mirror_bytes);

    use pab_core::decision::DecisionError::*;
    let decision = |error| TableError::Decision { port: 0, error };
    let bad = [
        // Decisions.
        (one_port(vec![GOOD], vec![], deliver(1)), decision(BadRoot)),
        (one_port(vec![GOOD], vec![], at(0)), decision(BadRoot)),
        (
            one_port(vec![GOOD], vec![node(0, at(0), deliver(0))], at(0)),
            decision(BadChild { node: 0 }),
        ),
        (
            one_port(
                vec![GOOD, GOOD],
                vec![
                    node(1, at(1), NodeRef::NOBODY),
                    node(0, deliver(0), NodeRef::NOBODY),
                ],
                at(0),
            ),
            decision(BadChild { node: 0 }),
        ),
        (
            one_port(
                vec![GOOD],
                vec![node(1, NodeRef::NOBODY, deliver(0))],
                at(0),
            ),
            decision(VariableOutOfRange { node: 0 }),
        ),
        (
            one_port(
                vec![GOOD],
                vec![node(0, NodeRef::NOBODY, deliver(5))],
                at(0),
            ),
            decision(BadChild { node: 0 }),
        ),
        // Counts that do not add up, and a port wider than 32.
        (
            RawTable {
                ports: vec![RawPort {
                    connections: 2,
                    nodes: 0,
                    root: NodeRef::NOBODY,
                    consumer: RawConsumer::Local,
                    value: None,
                }],
                connections: vec![GOOD],
                nodes: vec![],
                roots: vec![],
                groups: vec![],
                dynamics: vec![],
                gate_sources: vec![],
                gate_links: vec![],
                filters: Default::default(),
                schema: None,
            },
            TableError::ConnectionCountMismatch,
        ),
        (
            RawTable {
                ports: vec![RawPort {
                    connections: 0,
                    nodes: 0,
                    root: NodeRef::NOBODY,
                    consumer: RawConsumer::Local,
                    value: None,
                }],
                connections: vec![GOOD],
                nodes: vec![],
                roots: vec![],
                groups: vec![],
                dynamics: vec![],
                gate_sources: vec![],
                gate_links: vec![],
                filters: Default::default(),
                schema: None,
            },
            TableError::ConnectionCountMismatch,
        ),
        (
            RawTable {
                ports: vec![RawPort {
                    connections: 0,
                    nodes: 0,
                    root: NodeRef::NOBODY,
                    consumer: RawConsumer::Local,
                    value: None,
                }],
                connections: vec![],
                nodes: vec![node(0, NodeRef::NOBODY, NodeRef::NOBODY)],
                roots: vec![],
                groups: vec![],
                dynamics: vec![],
                gate_sources: vec![],
                gate_links: vec![],
                filters: Default::default(),
                schema: None,
            },
            TableError::NodeCountMismatch,
        ),
        (
            RawTable {
                ports: vec![RawPort {
                    connections: 33,
                    nodes: 0,
                    root: NodeRef::NOBODY,
                    consumer: RawConsumer::Local,
                    value: None,
                }],
                connections: vec![GOOD; 33],
                nodes: vec![],
                roots: vec![],
                groups: vec![],
                dynamics: vec![],
                gate_sources: vec![],
                gate_links: vec![],
                filters: Default::default(),
                schema: None,
            },
            TableError::PortTooWide { port: 0 },
        ),
        // Consumers that re-publish on an identifier too wide for its format.
        (
            with_consumer(
                one_port(vec![GOOD], vec![], deliver(0)),
                RawConsumer::Republish {
                    raw: 0x800,
                    extended: false,
                },
            ),
            TableError::Consumer {
                port: 0,
                error: OutputIdError::StandardTooWide,
            },
        ),
        (
            with_consumer(
                one_port(vec![GOOD], vec![], deliver(0)),
                RawConsumer::Republish {
                    raw: 0x2000_0000,
                    extended: true,
                },
            ),
            TableError::Consumer {
                port: 0,
                error: OutputIdError::ExtendedTooWide,
            },
        ),
        // Parameters and filters.
        (
            one_port(vec![RawConnection { gain: 0, ..GOOD }], vec![], deliver(0)),
            TableError::Parameter {
                port: 0,
                connection: 0,
                error: pab_core::ParamError::Gain(pab_core::level::GainError::BelowResolution),
            },
        ),
        (
            one_port(
                vec![
                    GOOD,
                    RawConnection {
                        decay_us: 0,
                        ..GOOD
                    },
                ],
                vec![],
                deliver(0),
            ),
            TableError::Parameter {
                port: 0,
                connection: 1,
                error: pab_core::ParamError::DecayTime,
            },
        ),
        (
            one_port(
                vec![RawConnection {
                    rest_us: MAX_TIME_US + 1,
                    ..GOOD
                }],
                vec![],
                deliver(0),
            ),
            TableError::Parameter {
                port: 0,
                connection: 0,
                error: pab_core::ParamError::RestTime,
            },
        ),
        (
            one_port(
                vec![RawConnection {
                    id: 0x111,
                    mask: 0x7F0,
                    ..GOOD
                }],
                vec![],
                deliver(0),
            ),
            TableError::Filter {
                port: 0,
                connection: 0,
                error: pab_core::filter::FilterError::IdOutsideMask,
            },
        ),
    ];
    let bad = bad.into_iter().chain(bad_value_ports());
    for (raw, expected) in bad {
        let bytes = postcard_bytes(&raw);
        let table: Table = postcard::from_bytes(&bytes).expect("decodes without validation");
        assert_eq!(
            Arbiter::new(table.clone()).err(),
            Some(expected),
            "{table:?}"
        );
        assert_eq!(table.validate(), Err(expected));
        // Behind a header with a right CRC, the loader refuses it the same way.
        let wrapped = with_body(&encode(&Table::new(), 0, 0), &bytes);
        assert_eq!(load_default(&wrapped), Err(LoadError::Table(expected)));
        let mut out = vec![0; MAX_IMAGE_LEN];
        assert_eq!(
            image::encode(&table, 0, 0, &mut out),
            Err(image::EncodeError::Table(expected))
        );
    }
}

#[test]
fn a_frame_on_a_table_without_ports_is_not_fed_anywhere() {
    let mut arbiter: Arbiter = Arbiter::new(Table::new()).unwrap();
    let reception = arbiter.receive(
        &Id::Standard(StandardId::ZERO),
        Instant::from_micros(0),
        |_| panic!("no port, no verdict"),
    );
    assert_eq!(reception, Reception::default());
}

// ---------------------------------------------------------------------------------------------
// Capacities and formats.

#[test]
fn an_image_loads_into_any_table_with_room_for_it() {
    // Figure 1 (1 port, 2 connections, 3 nodes) fits the board profile and a tiny table, and
    // decodes to the same ports there.
    let bytes = encode(&figure1_table(), 7, 1);
    let board = image::load::<4, 64, 256>(&bytes).expect("fits the board profile");
    let board_again: Loaded<4, 64, 256> = image::load(&bytes).expect("same with inference");
    assert_eq!(board, board_again);
    let tiny = image::load::<1, 2, 3>(&bytes).expect("fits exactly");
    let default = load_default(&bytes).expect("default capacities");
    assert_eq!(board.header, default.header);
    for table_ports in [
        board.table.ports().collect::<Vec<_>>(),
        tiny.table.ports().collect::<Vec<_>>(),
    ] {
        let expected: Vec<_> = default.table.ports().collect();
        assert_eq!(table_ports.len(), expected.len());
        for (got, want) in table_ports.iter().zip(&expected) {
            assert_eq!(
                (got.connections, got.nodes, got.root, got.consumer),
                (want.connections, want.nodes, want.root, want.consumer)
            );
        }
    }
    // Re-encoding from a smaller table gives the same bytes: the body ignores capacities.
    let board_table: BoardTable = board.table;
    let mut out = vec![0; MAX_IMAGE_LEN];
    let len = image::encode(&board_table, 7, 1, &mut out).expect("encodes");
    assert_eq!(&out[..len], &bytes[..]);
}

#[test]
fn an_image_larger_than_the_table_is_refused_with_what_it_needs() {
    // The big table: 5 ports, 2 + 32 + 1 + 0 + 3 connections, 3 + 32 + 0 + 0 + 4 nodes.
    let table = big_table();
    let needed = TableSize {
        ports: 5,
        connections: 38,
        nodes: 39,
    };
    assert_eq!(
        (
            table.port_count(),
            table.connection_count(),
            table.node_count()
        ),
        (needed.ports, needed.connections, needed.nodes)
    );
    let bytes = encode(&table, 3, 9);
    assert_eq!(
        image::load::<4, 8, 16>(&bytes),
        Err(LoadError::ExceedsCapacity {
            needed,
            capacity: TableSize {
                ports: 4,
                connections: 8,
                nodes: 16,
            },
        })
    );
    // Any one capacity too small is enough; all three just large enough load.
    assert!(matches!(
        image::load::<5, 38, 38>(&bytes),
        Err(LoadError::ExceedsCapacity { .. })
    ));
    assert!(matches!(
        image::load::<5, 37, 39>(&bytes),
        Err(LoadError::ExceedsCapacity { .. })
    ));
    assert!(matches!(
        image::load::<4, 38, 39>(&bytes),
        Err(LoadError::ExceedsCapacity { .. })
    ));
    let exact = image::load::<5, 38, 39>(&bytes).expect("exactly enough room");
    assert_eq!(exact.table.connections(), table.connections());
    // The full-capacity table does not fit a board.
    let full = encode(&full_table(), 1, 1);
    let refused = image::load::<4, 64, 256>(&full).unwrap_err();
    assert_eq!(
        refused,
        LoadError::ExceedsCapacity {
            needed: TableSize {
                ports: MAX_PORTS,
                connections: MAX_CONNECTIONS,
                nodes: MAX_DECISION_NODES,
            },
            capacity: TableSize {
                ports: 4,
                connections: 64,
                nodes: 256,
            },
        }
    );
    assert!(refused.to_string().contains("needs 16 ports"), "{refused}");
    // A body that does not decode at all is still a body error, whatever the capacities.
    let garbage = with_body(&bytes, &[0x05, 0xFF, 0xFF]);
    assert!(matches!(
        image::load::<4, 8, 16>(&garbage),
        Err(LoadError::Body(_))
    ));
    assert!(matches!(load_default(&garbage), Err(LoadError::Body(_))));
}

#[test]
fn images_of_older_formats_are_refused_naming_both_formats() {
    assert_eq!(FORMAT_VERSION, 10);
    for found in [1u16, 2, 3, 4, 5, 6, 7, 8, 9] {
        let mut old = encode(&figure1_table(), 7, 1);
        old[4..6].copy_from_slice(&found.to_le_bytes());
        let crc = crc32(&[&old[..16], &old[HEADER_LEN..]].concat());
        old[16..20].copy_from_slice(&crc.to_le_bytes());
        let expected = LoadError::UnsupportedFormat {
            found,
            expected: 10,
        };
        assert_eq!(image::read_header(&old), Err(expected.clone()));
        assert_eq!(load_default(&old), Err(expected.clone()));
        assert_eq!(image::load::<4, 64, 256>(&old), Err(expected.clone()));
        assert_eq!(
            expected.to_string(),
            format!("image format {found} is not supported (this node reads format 10)")
        );
    }
}

/// A value port of `connections` with `spec`, root `root` and connection roots `roots`.
fn value_port(
    connections: Vec<RawConnection>,
    nodes: Vec<DecisionNode>,
    spec: ValueSpec,
    root: NodeRef,
    roots: Vec<NodeRef>,
) -> RawTable {
    let mut table = one_port(connections, nodes, root);
    table.ports[0].value = Some(spec);
    table.roots = roots;
    table
}

/// Decoded value-port tables that break a rule, with the error the loader must give.
fn bad_value_ports() -> Vec<(RawTable, TableError)> {
    use pab_core::value_port::{FieldError, ValueError};
    use pab_core::{Combine, Endian, Field};
    let field = |offset, size| Field {
        offset,
        size,
        signed: false,
        endian: Endian::Little,
    };
    let spec = |combine, value, priority| ValueSpec {
        combine,
        value,
        priority,
    };
    let max = spec(Combine::Max, field(0, 2), None);
    let value = |error| TableError::Value { port: 0, error };
    let mut cases = vec![
        (
            value_port(
                vec![GOOD],
                vec![],
                spec(Combine::Max, field(0, 3), None),
                NodeRef::NOBODY,
                vec![deliver(0)],
            ),
            value(ValueError::Value(FieldError::BadSize { size: 3 })),
        ),
        (
            value_port(
                vec![GOOD],
                vec![],
                spec(
                    Combine::Min,
                    field(pab_core::frame::MAX_DATA_LEN as u8 - 3, 4),
                    None,
                ),
                NodeRef::NOBODY,
                vec![deliver(0)],
            ),
            value(ValueError::Value(FieldError::OutOfFrame {
                offset: pab_core::frame::MAX_DATA_LEN as u8 - 3,
                size: 4,
            })),
        ),
        (
            value_port(
                vec![GOOD],
                vec![],
                spec(Combine::Priority, field(0, 2), None),
                NodeRef::NOBODY,
                vec![deliver(0)],
            ),
            value(ValueError::PriorityMissing),
        ),
        (
            value_port(
                vec![GOOD],
                vec![],
                spec(Combine::Sum, field(0, 2), Some(field(2, 1))),
                NodeRef::NOBODY,
                vec![deliver(0)],
            ),
            value(ValueError::PriorityNotAllowed),
        ),
        (
            value_port(
                vec![GOOD],
                vec![],
                spec(Combine::Priority, field(0, 2), Some(field(255, 1))),
                NodeRef::NOBODY,
                vec![deliver(0)],
            ),
            value(ValueError::Priority(FieldError::OutOfFrame {
                offset: 255,
                size: 1,
            })),
        ),
        // The port's own root must be nobody on a value port.
        (
            value_port(vec![GOOD], vec![], max, deliver(0), vec![deliver(0)]),
            value(ValueError::PortRoot),
        ),
        // Roots that refer to nothing valid.
        (
            value_port(
                vec![GOOD, GOOD],
                vec![],
                max,
                NodeRef::NOBODY,
                vec![deliver(0), deliver(2)],
            ),
            value(ValueError::BadRoot { connection: 1 }),
        ),
        (
            value_port(
                vec![GOOD],
                vec![node(0, NodeRef::NOBODY, deliver(0))],
                max,
                NodeRef::NOBODY,
                vec![at(1)],
            ),
            value(ValueError::BadRoot { connection: 0 }),
        ),
        // Root counts that do not add up.
        (
            value_port(
                vec![GOOD, GOOD],
                vec![],
                max,
                NodeRef::NOBODY,
                vec![deliver(0)],
            ),
            TableError::RootCountMismatch,
        ),
        (
            value_port(
                vec![GOOD],
                vec![],
                max,
                NodeRef::NOBODY,
                vec![deliver(0), deliver(0)],
            ),
            TableError::RootCountMismatch,
        ),
        // Roots on an ordinary port.
        (
            RawTable {
                roots: vec![deliver(0)],
                ..one_port(vec![GOOD], vec![], deliver(0))
            },
            TableError::RootCountMismatch,
        ),
    ];
    // Capacities: one value port too many, one value connection too many.
    let ports = pab_core::MAX_VALUE_PORTS + 1;
    cases.push((
        RawTable {
            ports: (0..ports)
                .map(|_| RawPort {
                    connections: 1,
                    nodes: 0,
                    root: NodeRef::NOBODY,
                    consumer: RawConsumer::Local,
                    value: Some(max),
                })
                .collect(),
            connections: vec![GOOD; ports],
            nodes: vec![],
            roots: vec![deliver(0); ports],
            groups: vec![],
            dynamics: vec![],
            gate_sources: vec![],
            gate_links: vec![],
            filters: Default::default(),
            schema: None,
        },
        TableError::TooManyValuePorts,
    ));
    let wide = pab_core::MAX_VALUE_CONNECTIONS + 1;
    cases.push((
        value_port(
            vec![GOOD; wide],
            vec![],
            max,
            NodeRef::NOBODY,
            (0..wide as u8).map(deliver).collect(),
        ),
        TableError::TooManyValueConnections,
    ));
    cases
}

/// Decoded tables whose BLE groups break a rule, with the error the loader must give: each is
/// valid but for the one thing its comment names.
fn bad_groups() -> Vec<(RawTable, TableError)> {
    use pab_core::ble::{CLAIM_SLOT_FILTER, EligibilityField, Group, GroupError, GroupPort};
    let claim = RawConnection {
        id: CLAIM_SLOT_FILTER.id(),
        mask: CLAIM_SLOT_FILTER.mask(),
        extended: true,
        ..GOOD
    };
    let base = || one_port(vec![GOOD, claim], vec![], NodeRef::NOBODY);
    let group = |number, claim, gated| Group {
        number,
        node: 3,
        period_us: 100_000,
        local: Filter::exact(0x190, false).unwrap(),
        field: EligibilityField {
            offset: 0,
            size: 2,
            big_endian: false,
        },
        peers: 2,
        ports: [GroupPort {
            port: 0,
            claim,
            gated,
        }]
        .into_iter()
        .collect(),
    };
    let with = |groups: Vec<Group>| RawTable { groups, ..base() };
    let error = |group, error| TableError::Group { group, error };
    vec![
        // The claim connection is fed by a topic.
        (
            with(vec![group(0, 0, 0b10)]),
            TableError::ClaimFilter {
                port: 0,
                connection: 0,
            },
        ),
        // The claim connection does not exist.
        (
            with(vec![group(0, 2, 0b01)]),
            error(0, GroupError::Connection { port: 0 }),
        ),
        // The claim is among the gated.
        (
            with(vec![group(0, 1, 0b11)]),
            error(0, GroupError::Connection { port: 0 }),
        ),
        // A gated connection beyond the port's two.
        (
            with(vec![group(0, 1, 0b101)]),
            error(0, GroupError::Connection { port: 0 }),
        ),
        // No such port.
        (
            with(vec![Group {
                ports: [GroupPort {
                    port: 1,
                    claim: 1,
                    gated: 1,
                }]
                .into_iter()
                .collect(),
                ..group(0, 1, 1)
            }]),
            error(0, GroupError::NoSuchPort { port: 1 }),
        ),
        // A period of 0, a node id of 0, a 4-byte field, too many peers.
        (
            with(vec![Group {
                period_us: 0,
                ..group(0, 1, 1)
            }]),
            error(0, GroupError::Period),
        ),
        (
            with(vec![Group {
                node: 0,
                ..group(0, 1, 1)
            }]),
            error(0, GroupError::Node),
        ),
        (
            with(vec![Group {
                field: EligibilityField {
                    offset: 0,
                    size: 4,
                    big_endian: false,
                },
                ..group(0, 1, 1)
            }]),
            error(0, GroupError::Field),
        ),
        (
            with(vec![Group {
                peers: 8,
                ..group(0, 1, 1)
            }]),
            error(0, GroupError::TooManyPeers),
        ),
        // Two groups with one number, and two groups sharing a claim.
        (
            RawTable {
                groups: vec![group(4, 1, 1), group(4, 2, 1)],
                ..one_port(vec![GOOD, claim, claim], vec![], NodeRef::NOBODY)
            },
            error(1, GroupError::DuplicateGroup { number: 4 }),
        ),
        (
            RawTable {
                groups: vec![group(4, 1, 1), group(5, 1, 1)],
                ..one_port(vec![GOOD, claim, claim], vec![], NodeRef::NOBODY)
            },
            error(1, GroupError::SharedClaim { port: 0 }),
        ),
    ]
}

#[test]
fn the_loader_refuses_every_broken_ble_group_with_its_reason() {
    for (raw, expected) in bad_groups() {
        let body = postcard_bytes(&raw);
        let table = postcard::from_bytes::<Table>(&body).expect("decodes");
        assert_eq!(table.validate(), Err(expected), "{:?}", table.groups());
        assert_eq!(Arbiter::new(table).err(), Some(expected));
    }
    // And the same group, valid, loads.
    let mut good = bad_groups().remove(1).0;
    good.groups[0].ports[0].claim = 1;
    let table = postcard::from_bytes::<Table>(&postcard_bytes(&good)).expect("decodes");
    assert_eq!(table.validate(), Ok(()));
}

#[test]
fn an_image_whose_group_names_another_node_is_refused() {
    use pab_core::ble::GroupError;
    // The valid group of `bad_groups`, for node 3: its claims carry id 3.
    let mut good = bad_groups().remove(1).0;
    good.groups[0].ports[0].claim = 1;
    let table = postcard::from_bytes::<Table>(&postcard_bytes(&good)).expect("decodes");
    let mut buffer = vec![0u8; image::MAX_IMAGE_LEN];
    for (node_id, expected) in [
        (3, Ok(())),
        (
            4,
            Err(LoadError::Table(TableError::Group {
                group: 0,
                error: GroupError::Node,
            })),
        ),
    ] {
        let len = image::encode(&table, node_id, 1, &mut buffer).expect("encodes");
        let loaded: Result<image::Loaded, LoadError> = image::load(&buffer[..len]);
        assert_eq!(loaded.map(|_| ()), expected, "image for node {node_id}");
    }
}
