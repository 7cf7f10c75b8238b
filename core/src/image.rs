//! The table image: the bytes `pabctl compile` writes and a node loads.
//!
//! ```text
//! offset size  field
//!      0    4  magic "PABT"
//!      4    2  format version, little endian (this is format 10)
//!      6    1  node id the table is for
//!      7    1  reserved, must be 0
//!      8    4  table version, little endian (newer tables have larger versions)
//!     12    4  body length in bytes, little endian
//!     16    4  CRC-32/ISO-HDLC of bytes 0..16 followed by the body, little endian
//!     20    n  body: the postcard encoding of a [`Table`]
//! ```
//!
//! Why a fixed header before a postcard body: a receiver learns the length, the target node and
//! the version from fixed offsets (to refuse a transfer early), and checks the CRC over the whole
//! image before it parses a single field of the body. The CRC covers the header too, so no single
//! flipped bit anywhere goes unnoticed.
//!
//! The loader checks, in this order: length, magic, format, reserved byte, declared length, CRC,
//! body syntax and the receiving table's capacities, and every count, index and parameter of the
//! table. It returns a [`LoadError`] for the first problem; it never panics and never reads out of
//! bounds, whatever the bytes.
//!
//! Format history: format 1 had no port consumers; format 2 adds one [`crate::Consumer`] per port
//! (after its decision root); format 3 adds value ports: an optional [`crate::ValueSpec`] per port
//! (after its consumer) and, after the decision nodes, the list of the value ports' connection
//! roots; format 4 adds, after those roots, the list of the node's BLE groups ([`crate::ble::Group`]:
//! number, node id, period, local topic, eligibility field, peers, and per port the claim
//! connection and the gated set); format 5 adds, after the groups, the competitive-dynamics part
//! ([`crate::dynamics`]): the groups the node runs (number, parameters, contexts), the groups whose
//! gates it reads (owner, number, count) and the gate connections; format 6 adds, after those,
//! HBBA's message filters ([`crate::hbba::filters::MessageFilters`]: the filtered connections and
//! the profiles); format 7 adds, last, the schema server the node runs, an option
//! (`crate::schema::Setup`: the loop's set-up, its innate schemas and its drive's identifiers);
//! format 8 adds, last in that set-up, the topics of its extra sensors (identifier and field);
//! format 9 adds to the loop's set-up, after its watchdog margin, the drive's top speed and rate
//! and the pose sensor's noise (a pose that jumps farther is implausible); format 10 gathers the
//! safety bounds of that set-up ([`crate::schema::Limits`]: the workspace, force and torque
//! limits where they were) and adds after the torque limit the contact, speed and rate limits and
//! the joints' ranges and speeds.
//! This crate reads format 10 only: an image of another format is refused with
//! [`LoadError::UnsupportedFormat`], which names the format found and the one expected.
//!
//! The body does not depend on the capacities of the [`Table`] that was encoded (postcard prefixes
//! each list with its length), so one image loads into any table with room for it: a node with
//! the default capacities and a board with [`crate::BoardTable`] read the same bytes. A node decodes it
//! with a reader of its own (`wire`), not serde: the format is postcard's, the code a fraction.

use crate::crc32::Crc32;
use crate::table::{Table, TableError, Verdict};
use crate::{MAX_CONNECTIONS, MAX_DECISION_NODES, MAX_PORTS};

/// The first four bytes of every image.
pub const MAGIC: [u8; 4] = *b"PABT";
/// The format this crate writes and reads.
pub const FORMAT_VERSION: u16 = 10;
/// Bytes before the body.
pub const HEADER_LEN: usize = 20;
/// The largest image accepted, header included. A table at full capacity encodes in less.
pub const MAX_IMAGE_LEN: usize = 32 * 1024;

/// The header of an image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Header {
    /// The node the table is for.
    pub node_id: u8,
    /// The table's version; a node refuses versions older than its own.
    pub table_version: u32,
    /// Length of the body in bytes.
    pub body_len: u32,
    /// CRC-32 of header bytes 0..16 and the body.
    pub crc: u32,
}

/// A decoded, validated image, in a table of capacities `PORTS`, `CONNECTIONS`, `NODES` (the
/// defaults are those of [`Table`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Loaded<
    const PORTS: usize = MAX_PORTS,
    const CONNECTIONS: usize = MAX_CONNECTIONS,
    const NODES: usize = MAX_DECISION_NODES,
> {
    /// Its header.
    pub header: Header,
    /// Its table.
    pub table: Table<PORTS, CONNECTIONS, NODES>,
}

/// How many ports, connections and decision nodes a table has, or has room for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TableSize {
    /// Ports.
    pub ports: usize,
    /// Connections over all ports.
    pub connections: usize,
    /// Decision nodes over all ports.
    pub nodes: usize,
}

// Not `#[non_exhaustive]`: a node maps each variant to its own TransferStatus detail (pab-app's
// `status_of`).
/// Why an image was refused; a table that breaks a rule is told by the verdict `T` (see
/// [`Verdict`]).
#[derive(Clone, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LoadError<T = TableError> {
    /// Fewer bytes than the header, or than the header says the image has.
    Truncated {
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        got: usize,
    },
    /// More bytes than the header says the image has.
    TrailingBytes {
        /// Bytes beyond the image.
        extra: usize,
    },
    /// Not an image: the first bytes are not "PABT".
    BadMagic,
    /// An image of a format this node does not read (an image written by an older or newer
    /// `pabctl`): compile it again with a `pabctl` of the node's format.
    UnsupportedFormat {
        /// The format found.
        found: u16,
        /// The format this node reads, [`FORMAT_VERSION`].
        expected: u16,
    },
    /// The reserved header byte is not zero.
    ReservedByte,
    /// The header declares a body larger than [`MAX_IMAGE_LEN`] allows.
    TooLarge {
        /// The declared body length.
        body_len: u32,
    },
    /// The CRC does not match: the image was corrupted.
    Crc {
        /// The CRC in the header.
        stored: u32,
        /// The CRC of the bytes.
        computed: u32,
    },
    /// The body is not a valid postcard encoding of a table (with the CRC right, this means a bug
    /// or an incompatible writer, not corruption).
    Body(postcard::Error),
    /// The body decodes, but holds more ports, connections or decision nodes than the receiving
    /// table has room for: the image is for a node with larger capacities. (Whether the table
    /// would otherwise be valid is not known: it was not stored.)
    ExceedsCapacity {
        /// What the body holds.
        needed: TableSize,
        /// What the receiving table holds at most.
        capacity: TableSize,
    },
    /// The body decodes but leaves bytes unread.
    BodyTrailingBytes,
    /// The body decodes to a table that breaks a rule.
    Table(T),
}

impl<T: core::fmt::Display> core::fmt::Display for LoadError<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LoadError::Truncated { needed, got } => {
                write!(f, "image truncated: {got} bytes where {needed} are needed")
            }
            LoadError::TrailingBytes { extra } => {
                write!(f, "{extra} bytes after the end of the image")
            }
            LoadError::BadMagic => f.write_str("not a table image (bad magic)"),
            LoadError::UnsupportedFormat { found, expected } => write!(
                f,
                "image format {found} is not supported (this node reads format {expected})"
            ),
            LoadError::ReservedByte => f.write_str("reserved header byte is not zero"),
            LoadError::TooLarge { body_len } => {
                write!(
                    f,
                    "body of {body_len} bytes exceeds the {MAX_IMAGE_LEN}-byte image limit"
                )
            }
            LoadError::Crc { stored, computed } => write!(
                f,
                "CRC mismatch: header says {stored:#010x}, bytes give {computed:#010x}"
            ),
            LoadError::Body(error) => write!(f, "body does not decode: {error}"),
            LoadError::ExceedsCapacity { needed, capacity } => write!(
                f,
                "the table needs {} ports, {} connections and {} decision nodes; this node holds at most {}, {} and {}",
                needed.ports,
                needed.connections,
                needed.nodes,
                capacity.ports,
                capacity.connections,
                capacity.nodes
            ),
            LoadError::BodyTrailingBytes => f.write_str("body has bytes after the table"),
            LoadError::Table(error) => write!(f, "invalid table: {error}"),
        }
    }
}

impl<T: core::fmt::Debug + core::fmt::Display> core::error::Error for LoadError<T> {}

/// Why an image could not be written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum EncodeError {
    /// The output buffer is too small.
    BufferTooSmall,
    /// The image would exceed [`MAX_IMAGE_LEN`].
    TooLarge,
    /// The table breaks a rule (it was not built through [`Table::push_port`]).
    Table(TableError),
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EncodeError::BufferTooSmall => f.write_str("output buffer too small for the image"),
            EncodeError::TooLarge => write!(f, "image would exceed {MAX_IMAGE_LEN} bytes"),
            EncodeError::Table(error) => write!(f, "invalid table: {error}"),
        }
    }
}

impl core::error::Error for EncodeError {}

/// Header bytes 0..16, the part before the CRC.
fn covered_header(node_id: u8, table_version: u32, body_len: u32) -> [u8; 16] {
    let [f0, f1] = FORMAT_VERSION.to_le_bytes();
    let [v0, v1, v2, v3] = table_version.to_le_bytes();
    let [l0, l1, l2, l3] = body_len.to_le_bytes();
    let [m0, m1, m2, m3] = MAGIC;
    [
        m0, m1, m2, m3, f0, f1, node_id, 0, v0, v1, v2, v3, l0, l1, l2, l3,
    ]
}

/// Reads and checks the header alone: magic, format, reserved byte and the declared length
/// against [`MAX_IMAGE_LEN`]. A receiver calls it on the first bytes of a transfer to refuse it
/// early; it does not check the CRC.
pub fn read_header(bytes: &[u8]) -> Result<Header, LoadError> {
    read_header_as(bytes)
}

/// [`read_header`] with the loader's error for [`load_as`]: one copy of the code where the
/// verdict is [`Refused`](crate::Refused) (it never fails with [`LoadError::Table`]).
pub fn read_header_as<T>(bytes: &[u8]) -> Result<Header, LoadError<T>> {
    let header: [u8; HEADER_LEN] = bytes
        .get(..HEADER_LEN)
        .and_then(|header| header.try_into().ok())
        .ok_or(LoadError::Truncated {
            needed: HEADER_LEN,
            got: bytes.len(),
        })?;
    let [
        m0,
        m1,
        m2,
        m3,
        f0,
        f1,
        node_id,
        reserved,
        v0,
        v1,
        v2,
        v3,
        l0,
        l1,
        l2,
        l3,
        c0,
        c1,
        c2,
        c3,
    ] = header;
    if [m0, m1, m2, m3] != MAGIC {
        return Err(LoadError::BadMagic);
    }
    let format = u16::from_le_bytes([f0, f1]);
    if format != FORMAT_VERSION {
        return Err(LoadError::UnsupportedFormat {
            found: format,
            expected: FORMAT_VERSION,
        });
    }
    if reserved != 0 {
        return Err(LoadError::ReservedByte);
    }
    let body_len = u32::from_le_bytes([l0, l1, l2, l3]);
    if usize::try_from(body_len).map_or(true, |len| len > MAX_IMAGE_LEN - HEADER_LEN) {
        return Err(LoadError::TooLarge { body_len });
    }
    Ok(Header {
        node_id,
        table_version: u32::from_le_bytes([v0, v1, v2, v3]),
        body_len,
        crc: u32::from_le_bytes([c0, c1, c2, c3]),
    })
}

/// Decodes and validates an image into a table of capacities `PORTS`, `CONNECTIONS`, `NODES`:
/// `image::load::<4, 64, 256>(bytes)`, or `let loaded: Loaded = image::load(bytes)?` for the
/// default capacities.
///
/// Costs one CRC pass over the image, one postcard decode and one validation pass; uses no heap
/// and about `size_of::<Table<PORTS, CONNECTIONS, NODES>>()` of stack for the result. A list
/// longer than this table's room does not stop the decode: the rest of the body is read (and
/// checked) without being stored, which tells [`LoadError::ExceedsCapacity`] (the table is too
/// large for this node) from [`LoadError::Body`] (the bytes are not a table).
pub fn load<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>(
    bytes: &[u8],
) -> Result<Loaded<PORTS, CONNECTIONS, NODES>, LoadError> {
    load_as(bytes)
}

/// [`load`], refusing an invalid table with the verdict `R`: [`TableError`] says what is wrong,
/// [`Refused`](crate::Refused) only that something is. The same checks, in the same order.
pub fn load_as<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize, R: Verdict>(
    bytes: &[u8],
) -> Result<Loaded<PORTS, CONNECTIONS, NODES>, LoadError<R>> {
    let mut table = Table::new();
    let header = load_into_as(bytes, &mut table)?;
    Ok(Loaded { header, table })
}

/// [`load`] into `table`, a place of the caller's (whatever it held is replaced): the image's
/// header, its table left in `table`. On an error, `table` holds what was decoded of it.
///
/// For a caller with a place for the table, as the arbiter a node builds in place has
/// ([`crate::Arbiter::new_in`]): returned in a [`Loaded`], the table was in the loader's frame
/// and copied from there, twice, on its way to the arbiter.
pub fn load_into<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>(
    bytes: &[u8],
    table: &mut Table<PORTS, CONNECTIONS, NODES>,
) -> Result<Header, LoadError> {
    load_into_as(bytes, table)
}

/// [`load_into`], refusing an invalid table with the verdict `R` (as [`load_as`]).
pub fn load_into_as<
    const PORTS: usize,
    const CONNECTIONS: usize,
    const NODES: usize,
    R: Verdict,
>(
    bytes: &[u8],
    table: &mut Table<PORTS, CONNECTIONS, NODES>,
) -> Result<Header, LoadError<R>> {
    *table = Table::new();
    let header = read_header_as(bytes)?;
    // read_header bounded body_len by MAX_IMAGE_LEN, so this cannot overflow.
    let total = HEADER_LEN.wrapping_add(header.body_len as usize);
    if bytes.len() < total {
        return Err(LoadError::Truncated {
            needed: total,
            got: bytes.len(),
        });
    }
    if bytes.len() > total {
        return Err(LoadError::TrailingBytes {
            // More bytes than `total`: no underflow.
            extra: bytes.len().wrapping_sub(total),
        });
    }
    let (Some(covered), Some(body)) = (bytes.get(..16), bytes.get(HEADER_LEN..)) else {
        return Err(LoadError::Truncated {
            needed: total,
            got: bytes.len(),
        });
    };
    let computed = Crc32::new().update(covered).update(body).finish();
    if computed != header.crc {
        return Err(LoadError::Crc {
            stored: header.crc,
            computed,
        });
    }
    let mut r = crate::wire::Reader::new(body);
    let (needed, roots) = table.decode_sized(&mut r);
    if let Some(error) = r.error() {
        let capacity = TableSize {
            ports: PORTS,
            connections: CONNECTIONS,
            nodes: NODES,
        };
        // Only a body that is a table and nothing else, whose only faults are lists longer than
        // their room here, is told apart: the first fault then names what it needs.
        return Err(if !r.is_whole() {
            LoadError::Body(error)
        } else if needed.ports > capacity.ports
            || needed.connections > capacity.connections
            || needed.nodes > capacity.nodes
        {
            LoadError::ExceedsCapacity { needed, capacity }
        } else if roots > needed.connections {
            // Within the capacities but more value-port roots than connections: the root list
            // (sized by the connections) overflowed. The verdict every loader gives such a
            // body, before validation ([`too_many_roots`]).
            LoadError::Table(R::refuse(|| TableError::RootCountMismatch))
        } else {
            LoadError::Body(error)
        });
    }
    if !r.rest().is_empty() {
        return Err(LoadError::BodyTrailingBytes);
    }
    too_many_roots(table)?;
    table.check().map_err(LoadError::Table)?;
    // A group's claims carry the node id its table names: it must be the image's own, or the
    // node would claim under another node's id.
    if let Some(position) = table.groups().iter().position(|g| g.node != header.node_id) {
        return Err(LoadError::Table(R::refuse(|| TableError::Group {
            group: u8::try_from(position).unwrap_or(u8::MAX),
            error: crate::ble::GroupError::Node,
        })));
    }
    // Likewise a group read from "another" node under the image's own id: the node would wait
    // for gates only it could send.
    if let Some(position) = table
        .gate_sources()
        .iter()
        .position(|s| s.owner == header.node_id)
    {
        return Err(LoadError::Table(R::refuse(|| {
            TableError::Dynamics(crate::dynamics::DynamicsError::Source {
                source: u8::try_from(position).unwrap_or(u8::MAX),
            })
        })));
    }
    Ok(header)
}

/// Decodes a table body (an image without its header) as the loader does, without validating
/// the table: `(table, bytes after it)`. Exactly postcard's decoding of [`Table`] with serde, by a
/// reader a node can afford (see `wire`); public so that tests and fuzzers can hold the two
/// against each other. Costs one pass over `body`, no heap.
pub fn decode_body<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>(
    body: &[u8],
) -> Result<(Table<PORTS, CONNECTIONS, NODES>, &[u8]), postcard::Error> {
    crate::wire::take(body)
}

/// More value-port roots than connections: refused before validation, so that a node whose root
/// list overflowed while decoding (it has room for one root per connection of its capacity) and
/// a node that decoded the list give the same verdict, whatever else is wrong with the table.
fn too_many_roots<const P: usize, const C: usize, const N: usize, R: Verdict>(
    table: &Table<P, C, N>,
) -> Result<(), LoadError<R>> {
    if table.roots().len() > table.connections().len() {
        return Err(LoadError::Table(R::refuse(|| {
            TableError::RootCountMismatch
        })));
    }
    Ok(())
}

/// Writes the image of `table` (of any capacities) for node `node_id`, version `table_version`,
/// into `out`, and returns its length. Fails if `out` is too small, if the image would exceed
/// [`MAX_IMAGE_LEN`] or if the table is invalid. Costs one validation pass, one postcard encode
/// and one CRC pass.
pub fn encode<const PORTS: usize, const CONNECTIONS: usize, const NODES: usize>(
    table: &Table<PORTS, CONNECTIONS, NODES>,
    node_id: u8,
    table_version: u32,
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    table.validate().map_err(EncodeError::Table)?;
    let (header, body_area) = out
        .split_at_mut_checked(HEADER_LEN)
        .ok_or(EncodeError::BufferTooSmall)?;
    #[cfg_attr(feature = "schema", allow(unused_mut))]
    let mut body_len = postcard::to_slice(table, body_area)
        .map_err(|_| EncodeError::BufferTooSmall)?
        .len();
    // The format's last field, the schema server: `Table` has it only with the feature, so a
    // build without it writes the field's absence itself (postcard's `None`, one 0 byte), or its
    // images would end one byte early for every loader, its own included.
    #[cfg(not(feature = "schema"))]
    {
        *body_area
            .get_mut(body_len)
            .ok_or(EncodeError::BufferTooSmall)? = 0;
        body_len += 1;
    }
    let total = HEADER_LEN.saturating_add(body_len);
    if total > MAX_IMAGE_LEN {
        return Err(EncodeError::TooLarge);
    }
    let body_len_field = u32::try_from(body_len).map_err(|_| EncodeError::TooLarge)?;
    let covered = covered_header(node_id, table_version, body_len_field);
    let body = body_area
        .get(..body_len)
        .ok_or(EncodeError::BufferTooSmall)?;
    let crc = Crc32::new().update(&covered).update(body).finish();
    let (fields, crc_field) = header.split_at_mut(16);
    fields.copy_from_slice(&covered);
    crc_field.copy_from_slice(&crc.to_le_bytes());
    Ok(total)
}

#[cfg(test)]
mod one_pass {
    use super::*;
    use crate::decision::{DecisionNode, NodeRef};
    use crate::level::Gain;
    use crate::table::Connection;
    use crate::{Filter, Stimulation};

    /// The loader's verdict on a body that did not decode, as it was made before
    /// [`crate::wire::Reader::fill_within`]: a second decode that counts every list.
    fn size_of_body(body: &[u8]) -> Option<(TableSize, usize)> {
        let mut r = crate::wire::Reader::new(body);
        let ports = r.count::<crate::table::Port>();
        let connections = r.count::<Connection>();
        let nodes = r.count::<DecisionNode>();
        let roots = r.count::<NodeRef>();
        #[cfg(feature = "ble")]
        r.count::<crate::ble::Group>();
        #[cfg(not(feature = "ble"))]
        r.empty::<u8, 0>();
        #[cfg(feature = "dynamics")]
        {
            r.count::<crate::dynamics::GroupSpec>();
            r.count::<crate::dynamics::GateSource>();
            r.count::<crate::dynamics::GateLink>();
        }
        #[cfg(not(feature = "dynamics"))]
        for _ in 0..3 {
            r.empty::<u8, 0>();
        }
        #[cfg(feature = "filters")]
        r.decode::<crate::hbba::filters::MessageFilters>();
        #[cfg(not(feature = "filters"))]
        for _ in 0..2 {
            r.empty::<u8, 0>();
        }
        #[cfg(feature = "schema")]
        r.option::<crate::schema::Setup>();
        #[cfg(not(feature = "schema"))]
        r.none();
        if r.error().is_some() {
            return None;
        }
        r.rest().is_empty().then_some((
            TableSize {
                ports,
                connections,
                nodes,
            },
            roots,
        ))
    }

    /// [`load`]'s verdict on the body alone (its checks after the CRC), made the former way.
    fn former<const P: usize, const C: usize, const N: usize>(
        body: &[u8],
    ) -> Result<Table<P, C, N>, LoadError> {
        let (table, rest) = match decode_body::<P, C, N>(body) {
            Ok(decoded) => decoded,
            Err(error) => {
                let capacity = TableSize {
                    ports: P,
                    connections: C,
                    nodes: N,
                };
                return Err(match size_of_body(body) {
                    Some((needed, _))
                        if needed.ports > capacity.ports
                            || needed.connections > capacity.connections
                            || needed.nodes > capacity.nodes =>
                    {
                        LoadError::ExceedsCapacity { needed, capacity }
                    }
                    Some((needed, roots)) if roots > needed.connections => {
                        LoadError::Table(TableError::RootCountMismatch)
                    }
                    _ => LoadError::Body(error),
                });
            }
        };
        if !rest.is_empty() {
            return Err(LoadError::BodyTrailingBytes);
        }
        too_many_roots(&table)?;
        table.validate().map_err(LoadError::Table)?;
        Ok(table)
    }

    fn image_of(body: &[u8]) -> std::vec::Vec<u8> {
        let len = u32::try_from(body.len()).unwrap();
        let covered = covered_header(1, 1, len);
        let crc = Crc32::new().update(&covered).update(body).finish();
        let mut image = covered.to_vec();
        image.extend_from_slice(&crc.to_le_bytes());
        image.extend_from_slice(body);
        image
    }

    fn same<const P: usize, const C: usize, const N: usize>(body: &[u8]) {
        let now = load::<P, C, N>(&image_of(body)).map(|loaded| loaded.table);
        assert_eq!(now, former::<P, C, N>(body), "body {body:02x?}");
    }

    fn same_everywhere(body: &[u8]) {
        same::<4, 64, 256>(body);
        same::<2, 3, 2>(body);
        same::<1, 1, 0>(body);
        same::<16, 512, 1024>(body);
    }

    /// The one-pass loader gives every body the verdict of the former two-pass one, at
    /// capacities the body fits and capacities it exceeds: on every one-byte change (to 0, 1,
    /// 0x7F, 0x80, 0xFF and each single bit flipped), every truncation and every appended byte
    /// of a few tables' bodies.
    #[test]
    fn the_one_pass_loader_gives_the_former_verdicts() {
        let connection = |id: u32| Connection {
            filter: Filter::exact(id, false).unwrap(),
            stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).unwrap(),
        };
        let deliver = |k: u8| NodeRef::deliver(k).unwrap();
        let node = DecisionNode {
            var: 0,
            low: deliver(1),
            high: deliver(0),
        };
        let mut tables: std::vec::Vec<Table> = std::vec::Vec::new();
        tables.push(Table::new());
        let mut one = Table::new();
        one.push_port(
            &[connection(1), connection(2)],
            &[node],
            NodeRef::node(0).unwrap(),
        )
        .unwrap();
        one.push_port(&[connection(3)], &[], deliver(0)).unwrap();
        tables.push(one.clone());
        let spec = crate::ValueSpec {
            combine: crate::Combine::Min,
            value: crate::Field {
                offset: 0,
                size: 2,
                signed: false,
                endian: crate::Endian::Little,
            },
            priority: None,
        };
        one.push_value_port(
            &[connection(4), connection(5)],
            &[],
            spec,
            &[deliver(0), deliver(1)],
        )
        .unwrap();
        tables.push(one);
        for table in &tables {
            let mut body = [0u8; 4096];
            let len = postcard::to_slice(table, &mut body).unwrap().len();
            let body = &body[..len];
            same_everywhere(body);
            for at in 0..body.len() {
                let mut changed = body.to_vec();
                for value in [0u8, 1, 2, 3, 0x7F, 0x80, 0xFF]
                    .into_iter()
                    .chain((0..8).map(|bit| body[at] ^ (1 << bit)))
                {
                    changed[at] = value;
                    same_everywhere(&changed);
                }
                same_everywhere(&body[..at]);
            }
            for extra in [0u8, 1, 0x80] {
                let mut longer = body.to_vec();
                longer.push(extra);
                same_everywhere(&longer);
            }
        }
    }

    /// The same on the image fuzz targets' corpora (bodies with BLE groups, dynamics and
    /// filters among them) and the emulated board's Take and Return images: each body, each
    /// truncation of it, and each byte of it set to 0 and to 0xFF.
    #[test]
    fn the_one_pass_loader_gives_the_former_verdicts_on_the_corpora() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut files = std::vec::Vec::new();
        for dir in [
            "fuzz/corpus/image_fixed_crc",
            "fuzz/corpus/image_raw",
            "firmware/boards/mps2-an386/tables/take-and-return",
        ] {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                files.push(entry.unwrap().path());
            }
        }
        assert!(files.len() > 50, "the corpora were not found");
        for file in files {
            let bytes = std::fs::read(&file).unwrap();
            let Some(body) = bytes.get(HEADER_LEN..) else {
                continue;
            };
            same_everywhere(body);
            for at in 0..body.len() {
                same_everywhere(&body[..at]);
                let mut changed = body.to_vec();
                for value in [0u8, 0xFF] {
                    changed[at] = value;
                    same_everywhere(&changed);
                }
            }
        }
    }
}

#[cfg(all(
    test,
    not(feature = "ble"),
    not(feature = "dynamics"),
    not(feature = "filters"),
    not(feature = "schema")
))]
mod without_mechanisms {
    use super::*;

    /// A build without the features writes images it (and every loader) reads back: the schema
    /// server's absence included.
    #[test]
    fn an_image_encoded_without_the_features_loads() {
        let table: Table<4, 8, 16> = Table::new();
        let mut out = [0u8; 64];
        let len = encode(&table, 3, 1, &mut out).unwrap();
        assert_eq!(
            len,
            HEADER_LEN + 11,
            "the empty body of the format: 11 bytes"
        );
        let loaded = load::<4, 8, 16>(&out[..len]).unwrap();
        assert_eq!(loaded.header.node_id, 3);
        assert_eq!(loaded.table.port_count(), 0);
    }

    /// A board built without the mechanisms (the minimal node) reads their lists only when
    /// empty (the schema server's option only when absent): a table that has a BLE group, a
    /// dynamics group, a message filter or profile, or a schema server is refused as a body it
    /// cannot read (InvalidTable on the bus), never half-loaded.
    #[test]
    fn a_table_with_a_mechanism_is_refused_by_a_node_without_it() {
        // An empty table: no port, connection, node, root or BLE group, the three dynamics
        // lists, no message filter and no profile, no schema server.
        let empty = [0u8; 11];
        let (table, rest) = decode_body::<4, 8, 16>(&empty).unwrap();
        assert!(rest.is_empty() && table.port_count() == 0);
        // The BLE groups (4), the dynamics lists (5 to 7), the filters and profiles (8, 9), the
        // schema server (10).
        for part in 4..=10 {
            let mut body = empty;
            body[part] = 1;
            assert_eq!(
                decode_body::<4, 8, 16>(&body).err(),
                Some(postcard::Error::SerdeDeCustom),
                "byte {part}"
            );
        }
    }
}
