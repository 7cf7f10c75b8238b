//! Shared by the storage tests: real table images, the flash geometries, and a store that can be
//! rebuilt over the same memory ("reboot").

#![allow(dead_code)]

use pab_core::image;
use pab_core::{Connection, DecisionNode, Filter, NodeRef, Stimulation, Table};
use pab_storage::testing::MemFlash;
use pab_storage::{FlashStore, StoreError, TableStore};

/// The STM32G474 in single-bank mode: 4 KiB pages, 8-byte words; the recommended 40 KiB, 5 slots
/// of 8 KiB.
pub type BoardFlash = MemFlash<10, 4096, 8>;
pub const BOARD_RANGE: core::ops::Range<u32> = 0..10 * 4096;
pub const BOARD_SLOT: u32 = 8 * 1024;
pub const BOARD_SLOTS: u32 = 5;
/// Bytes of a slot header on the board (24 bytes, three double words).
pub const BOARD_HEADER: u32 = 24;

/// Small pages and 4-byte words: 4 slots of 2 pages, images span pages.
pub type SmallFlash = MemFlash<8, 256, 4>;
pub const SMALL_RANGE: core::ops::Range<u32> = 0..8 * 256;
pub const SMALL_SLOT: u32 = 512;
pub const SMALL_SLOTS: u32 = 4;

/// 64 KiB in 4 slots of 16 KiB, for a 15 KB image.
pub type LargeFlash = MemFlash<16, 4096, 8>;
pub const LARGE_RANGE: core::ops::Range<u32> = 0..16 * 4096;
pub const LARGE_SLOT: u32 = 16 * 1024;

fn node(var: u8, low: NodeRef, high: NodeRef) -> DecisionNode {
    DecisionNode { var, low, high }
}

fn at(index: u16) -> NodeRef {
    NodeRef::node(index).expect("node index")
}

fn deliver(index: u8) -> NodeRef {
    NodeRef::deliver(index).expect("connection index")
}

fn connection(id: u32, sigma: f64, tau: f64) -> Connection {
    Connection {
        filter: Filter::exact(id, false).expect("filter"),
        stimulation: Stimulation::from_seconds(sigma, tau, 0.0).expect("stimulation"),
    }
}

/// A connection whose fields take postcard's longest encodings (29-bit id, odd σ, long times).
fn wide_connection(id: u32, tau: f64) -> Connection {
    Connection {
        filter: Filter::exact(id, true).expect("filter"),
        stimulation: Stimulation::from_seconds(0.123_456_789, tau, 1_234.567_891)
            .expect("stimulation"),
    }
}

/// Node 3's table of the paper's Figure 1, as version 1.
pub fn image_v1() -> Vec<u8> {
    let mut table = Table::new();
    let connections = [connection(0x110, 0.2, 3.0), connection(0x111, 0.2, 3.0)];
    let nodes = [
        node(0, at(1), at(2)),
        node(1, NodeRef::NOBODY, deliver(1)),
        node(1, deliver(0), deliver(1)),
    ];
    table.push_port(&connections, &nodes, at(0)).expect("port");
    encode(&table, 3, 1)
}

/// Node 3's next table, version 2: a third connection with priority over the others.
pub fn image_v2() -> Vec<u8> {
    let mut table = Table::new();
    let connections = [
        connection(0x100, 0.5, 1.0),
        connection(0x110, 0.2, 3.0),
        connection(0x111, 0.25, 2.0),
    ];
    table
        .push_port(&connections, &priority_chain(3), at(0))
        .expect("port");
    encode(&table, 3, 2)
}

/// A node with every connection it can have (16 ports of 32, priority chains, wide fields): about
/// 15 KB, four 4 KiB pages.
pub fn image_large(version: u32) -> Vec<u8> {
    image_ports(16, version)
}

/// `ports` ports of 32 wide connections each (priority chains): about 950 bytes a port.
pub fn image_ports(ports: u32, version: u32) -> Vec<u8> {
    let mut table = Table::new();
    for port in 0..ports {
        push_wide_port(&mut table, port, 32, version);
    }
    encode(&table, 3, version)
}

/// One port of `connections` (1..=32) wide connections: about 30 bytes a connection.
pub fn image_connections(connections: u8, version: u32) -> Vec<u8> {
    let mut table = Table::new();
    push_wide_port(&mut table, 0, connections, version);
    encode(&table, 3, version)
}

fn push_wide_port(table: &mut Table, port: u32, connections: u8, version: u32) {
    let list: Vec<Connection> = (0..u32::from(connections))
        .map(|k| {
            wide_connection(
                0x1800_0000 + port * 0x1_0000 + k * 8,
                3000.0 + f64::from(version),
            )
        })
        .collect();
    table
        .push_port(&list, &priority_chain(connections), at(0))
        .expect("port");
}

fn priority_chain(n: u8) -> Vec<DecisionNode> {
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

fn encode(table: &Table, node_id: u8, version: u32) -> Vec<u8> {
    let mut out = vec![0u8; image::MAX_IMAGE_LEN];
    let len = image::encode(table, node_id, version, &mut out).expect("encode");
    out.truncate(len);
    out
}

/// A store over `flash`, as a board builds it at boot.
pub fn store<const P: usize, const E: usize, const W: usize>(
    flash: MemFlash<P, E, W>,
    range: core::ops::Range<u32>,
    slot: u32,
) -> FlashStore<MemFlash<P, E, W>> {
    FlashStore::new(flash, range, slot).expect("valid layout")
}

/// What `load` returns, as an owned copy; every image returned must pass `image::load`.
pub fn load<F: pab_storage::BackgroundErase>(
    store: &mut FlashStore<F>,
) -> Result<Option<Vec<u8>>, StoreError> {
    let mut buf = vec![0u8; image::MAX_IMAGE_LEN];
    let loaded = store.load(&mut buf)?.map(<[u8]>::to_vec);
    if let Some(bytes) = &loaded {
        image::load::<
            { pab_core::MAX_PORTS },
            { pab_core::MAX_CONNECTIONS },
            { pab_core::MAX_DECISION_NODES },
        >(bytes)
        .expect("the store returns valid images only");
    }
    Ok(loaded)
}

pub fn save<F: pab_storage::BackgroundErase>(
    store: &mut FlashStore<F>,
    image: &[u8],
) -> Result<(), StoreError> {
    store.save(image)
}

/// The table version of an image, for messages.
pub fn version(bytes: &[u8]) -> u32 {
    image::read_header(bytes).expect("header").table_version
}
