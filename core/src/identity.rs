//! Who a node is: what it runs, what it can load, and the unique id that addresses it before it
//! has a node id (`docs/can-protocol.md`, "Identity and configuration").
//!
//! A node answers an [`IdentityRequest`](crate::protocol::Service::IdentityRequest) (addressed or
//! broadcast) and announces itself once at start-up with six frames, one per
//! [`IdentityPart`], 8 bytes each, in part order:
//!
//! ```text
//! Identity          uid bytes 0-7
//! IdentityVersion   uid bytes 8-11, firmware major, minor, patch, protocol version
//! IdentityBuild     build id (8 bytes: the first 16 hex digits of the git commit)
//! IdentityCapacity  ports u8, connections u16, decision nodes u16, largest image u16 (bytes), 0
//! IdentityFeatures  table formats min u8, max u8, features u16, flags u8, 0, bit rate u16 (kbit/s)
//! IdentityName      firmware name: 8 ASCII bytes, NUL-padded
//! ```
//!
//! Six frames rather than one ISO-TP message: an answer to a broadcast comes from every node at
//! once, and ISO-TP's flow control is point to point; fixed single frames need none, and each
//! has one layout for the DBC (as the heartbeat group's four).
//!
//! ## Unassigned nodes
//!
//! A node without a node id (none in its configuration page, none compiled in) sends from its
//! *provisional address* `0x80 + (crc32(uid) >> 24) % 127` (0x80..=0xFE: never a node id, the
//! tool or broadcast). Two unassigned nodes must not send one identifier with different data (a
//! bit error every time they start together): the uid bits in the address make that a 1-in-127
//! chance per pair, as Cyphal's anonymous frames do with their pseudo-ids; the tool tells two
//! nodes behind one address apart by their uids, and an [`Assign`](crate::protocol::Assign)
//! carries a 24-bit check of the uid ([`uid_check`]), so only the node it names takes it.

use crate::crc32::crc32;

/// The protocol version a node states in its identity: the frames of `docs/can-protocol.md` as
/// this crate encodes them. Raised when a frame a node sends or reads changes.
pub const PROTOCOL_VERSION: u8 = 1;

/// Bytes of a unique id: the STM32's 96-bit factory UID; `pab-node`'s random 64-bit id takes the
/// first 8 (the last 4 zero).
pub const UID_LEN: usize = 12;

/// The first provisional address of an unassigned node.
pub const PROVISIONAL_BASE: u8 = 0x80;

/// The feature bits of [`Identity::features`], and their names (what `pabctl nodes` prints).
pub const FEATURES: [(u16, &str); 5] = [
    (Identity::FEATURE_BLE, "ble"),
    (Identity::FEATURE_DYNAMICS, "dynamics"),
    (Identity::FEATURE_FILTERS, "filters"),
    (Identity::FEATURE_SCHEMA, "schema"),
    (Identity::FEATURE_FD, "fd"),
];

/// The six frames of an identity, in the order a node sends them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum IdentityPart {
    /// uid bytes 0-7 (service 0x22).
    Uid = 0,
    /// uid bytes 8-11, firmware version, protocol version (service 0x23).
    Version = 1,
    /// Build id (service 0x24).
    Build = 2,
    /// Capacities (service 0x25).
    Capacity = 3,
    /// Table formats, features, flags, bit rate (service 0x26).
    Features = 4,
    /// Firmware name (service 0x27).
    Name = 5,
}

impl IdentityPart {
    /// Every part, in the order a node sends them.
    pub const ALL: [IdentityPart; 6] = [
        IdentityPart::Uid,
        IdentityPart::Version,
        IdentityPart::Build,
        IdentityPart::Capacity,
        IdentityPart::Features,
        IdentityPart::Name,
    ];

    /// The part at `index` (0..6).
    pub const fn from_index(index: u8) -> Option<IdentityPart> {
        Some(match index {
            0 => IdentityPart::Uid,
            1 => IdentityPart::Version,
            2 => IdentityPart::Build,
            3 => IdentityPart::Capacity,
            4 => IdentityPart::Features,
            5 => IdentityPart::Name,
            _ => return None,
        })
    }

    /// Its position, 0..6.
    pub const fn index(self) -> u8 {
        self as u8
    }
}

/// A firmware's name, version and build: what it is, as compiled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Firmware {
    /// ASCII, NUL-padded (`pab-node`, `fw-g474`, ...).
    pub name: [u8; 8],
    /// Semantic version: major, minor, patch.
    pub version: [u8; 3],
    /// The first 8 bytes of the git commit it was built from (zeros: unknown).
    pub build: [u8; 8],
}

impl Firmware {
    /// A firmware description from text, at compile time: `name` (at most 8 ASCII bytes, longer
    /// is cut), `version` as Cargo writes it (`"0.1.0"`; a pre-release or build suffix is
    /// ignored, a part above 255 reads 255) and `build` as hex digits (the first 16 are read; a
    /// non-hex digit ends it, the rest zero).
    // Indexing, in a `const fn` (where `get` is not available): every index is bounded by its
    // loop's condition, and the boards call it in `const` items (`pab_app::firmware!`), where a
    // panic would be a compile error, never a run-time one.
    #[allow(clippy::indexing_slicing)]
    pub const fn new(name: &str, version: &str, build: &str) -> Firmware {
        let mut out = Firmware {
            name: [0; 8],
            version: [0; 3],
            build: [0; 8],
        };
        let name = name.as_bytes();
        let mut i = 0;
        while i < name.len() && i < 8 {
            out.name[i] = name[i];
            i += 1;
        }
        let version = version.as_bytes();
        let (mut part, mut value, mut i) = (0, 0u32, 0);
        while i < version.len() && part < 3 {
            let c = version[i];
            if c == b'.' {
                out.version[part] = if value > 255 { 255 } else { value as u8 };
                part += 1;
                value = 0;
            } else if c.is_ascii_digit() {
                value = value * 10 + (c - b'0') as u32;
                if value > 255 {
                    value = 256;
                }
            } else {
                break;
            }
            i += 1;
        }
        if part < 3 {
            out.version[part] = if value > 255 { 255 } else { value as u8 };
        }
        let build = build.as_bytes();
        let mut i = 0;
        while i < build.len() && i < 16 {
            let digit = match build[i] {
                c @ b'0'..=b'9' => c - b'0',
                c @ b'a'..=b'f' => c - b'a' + 10,
                c @ b'A'..=b'F' => c - b'A' + 10,
                _ => break,
            };
            out.build[i / 2] |= if i % 2 == 0 { digit << 4 } else { digit };
            i += 1;
        }
        out
    }

    /// The name without its padding (up to the first NUL), if it is ASCII.
    pub fn name_str(&self) -> Option<&str> {
        let end = self.name.iter().position(|&b| b == 0).unwrap_or(8);
        let name = self.name.get(..end)?;
        if name.is_ascii() {
            core::str::from_utf8(name).ok()
        } else {
            None
        }
    }
}

/// The largest tables a node loads and the largest image it takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Capacity {
    /// Ports.
    pub ports: u8,
    /// Connections, all ports together.
    pub connections: u16,
    /// Decision nodes.
    pub decision_nodes: u16,
    /// The largest table image, bytes (its transfer buffer).
    pub image_len: u16,
}

/// What a node says of itself ([module documentation](self)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Identity {
    /// Its unique id.
    pub uid: [u8; UID_LEN],
    /// Its firmware.
    pub firmware: Firmware,
    /// [`PROTOCOL_VERSION`] of its firmware.
    pub protocol: u8,
    /// The table image formats it loads ([`crate::image::FORMAT_VERSION`]), lowest and highest.
    pub formats: [u8; 2],
    /// Its capacities.
    pub capacity: Capacity,
    /// The mechanisms compiled in: `FEATURE_*` bits.
    pub features: u16,
    /// `FLAG_*` bits.
    pub flags: u8,
    /// The bit rate it runs at, kbit/s (0: not its to set, as on a Linux socket).
    pub bitrate_kbps: u16,
}

impl Identity {
    /// Feature: BLE's distributed selection ([`crate::ble`]).
    pub const FEATURE_BLE: u16 = 1 << 0;
    /// Feature: competitive dynamics ([`crate::dynamics`]).
    pub const FEATURE_DYNAMICS: u16 = 1 << 1;
    /// Feature: HBBA's message filters ([`crate::filter`]).
    pub const FEATURE_FILTERS: u16 = 1 << 2;
    /// Feature: the schema server.
    pub const FEATURE_SCHEMA: u16 = 1 << 3;
    /// Feature: CAN FD. It takes CAN FD frames, and its transfers (tables, schemas, updates) in
    /// CAN FD frames as well as classic ones. Without it, a CAN FD transfer to it is lost.
    pub const FEATURE_FD: u16 = 1 << 4;

    /// Flag: the node takes only authenticated configuration.
    pub const FLAG_KEYED: u8 = 1 << 0;
    /// Flag: its key page or boot counter is invalid; it takes no configuration at all.
    pub const FLAG_LOCKED: u8 = 1 << 1;
    /// Flag: it has no node id and sends from its provisional address.
    pub const FLAG_UNASSIGNED: u8 = 1 << 2;
    /// Flag: it runs a bit rate set over the bus that has not heard the bus yet (it goes back to
    /// the previous one if it does not within 5 s).
    pub const FLAG_BITRATE_TRIAL: u8 = 1 << 3;
    /// Flag: a bit rate set over the bus did not hear the bus, and the node went back to the
    /// previous one.
    pub const FLAG_BITRATE_FELL_BACK: u8 = 1 << 4;
    /// Every flag bit defined.
    const FLAGS: u8 = 0x1F;
    /// Every feature bit defined.
    const FEATURES: u16 = 0x1F;

    /// Whether the node has a key (or is locked).
    pub const fn keyed(&self) -> bool {
        self.flags & (Identity::FLAG_KEYED | Identity::FLAG_LOCKED) != 0
    }

    /// The payload of `part`.
    pub fn payload(&self, part: IdentityPart) -> [u8; 8] {
        let uid = &self.uid;
        let at = |i: usize| uid.get(i).copied().unwrap_or(0);
        match part {
            IdentityPart::Uid => [at(0), at(1), at(2), at(3), at(4), at(5), at(6), at(7)],
            IdentityPart::Version => {
                let [major, minor, patch] = self.firmware.version;
                [
                    at(8),
                    at(9),
                    at(10),
                    at(11),
                    major,
                    minor,
                    patch,
                    self.protocol,
                ]
            }
            IdentityPart::Build => self.firmware.build,
            IdentityPart::Capacity => {
                let c = &self.capacity;
                let [c0, c1] = c.connections.to_le_bytes();
                let [n0, n1] = c.decision_nodes.to_le_bytes();
                let [i0, i1] = c.image_len.to_le_bytes();
                [c.ports, c0, c1, n0, n1, i0, i1, 0]
            }
            IdentityPart::Features => {
                let [f0, f1] = self.features.to_le_bytes();
                let [b0, b1] = self.bitrate_kbps.to_le_bytes();
                let [low, high] = self.formats;
                [low, high, f0, f1, self.flags, 0, b0, b1]
            }
            IdentityPart::Name => self.firmware.name,
        }
    }

    /// Whether `payload` is a valid `part`: reserved bytes zero, known flags, a name of
    /// printable ASCII. What a decoder refuses ([`crate::protocol::DecodeError::Value`]).
    pub fn part_is_valid(part: IdentityPart, payload: &[u8; 8]) -> bool {
        let [b0, b1, b2, b3, b4, b5, _, b7] = *payload;
        match part {
            IdentityPart::Uid | IdentityPart::Version | IdentityPart::Build => true,
            IdentityPart::Capacity => b7 == 0,
            IdentityPart::Features => {
                let features = u16::from_le_bytes([b2, b3]);
                features & !Identity::FEATURES == 0
                    && b4 & !Identity::FLAGS == 0
                    && b5 == 0
                    && b0 <= b1
            }
            IdentityPart::Name => {
                let end = payload.iter().position(|&b| b == 0).unwrap_or(8);
                payload.iter().take(end).all(|b| b.is_ascii_graphic())
                    && payload.iter().skip(end).all(|&b| b == 0)
            }
        }
    }

    /// The identity made of its six payloads, in [`IdentityPart::ALL`]'s order (each checked by
    /// [`Identity::part_is_valid`] as it was decoded).
    pub fn from_payloads(parts: &[[u8; 8]; 6]) -> Identity {
        let [uid, version, build, capacity, features, name] = parts;
        let mut id = [0u8; UID_LEN];
        for (slot, byte) in id.iter_mut().zip(uid.iter().chain(version.iter().take(4))) {
            *slot = *byte;
        }
        let [_, _, _, _, major, minor, patch, protocol] = *version;
        let [ports, c0, c1, n0, n1, i0, i1, _] = *capacity;
        let [low, high, f0, f1, flags, _, b0, b1] = *features;
        Identity {
            uid: id,
            firmware: Firmware {
                name: *name,
                version: [major, minor, patch],
                build: *build,
            },
            protocol,
            formats: [low, high],
            capacity: Capacity {
                ports,
                connections: u16::from_le_bytes([c0, c1]),
                decision_nodes: u16::from_le_bytes([n0, n1]),
                image_len: u16::from_le_bytes([i0, i1]),
            },
            features: u16::from_le_bytes([f0, f1]),
            flags,
            bitrate_kbps: u16::from_le_bytes([b0, b1]),
        }
    }

    /// The names of the features set, in [`FEATURES`]' order.
    pub fn feature_names(&self) -> impl Iterator<Item = &'static str> + '_ {
        FEATURES
            .iter()
            .filter(|(bit, _)| self.features & bit != 0)
            .map(|(_, name)| *name)
    }
}

/// The provisional address of an unassigned node with this uid: 0x80..=0xFE.
pub fn provisional_address(uid: &[u8; UID_LEN]) -> u8 {
    let [_, _, _, high] = crc32(uid).to_le_bytes();
    // high % 127 < 127: the sum stays within 0x80..=0xFE.
    PROVISIONAL_BASE.wrapping_add(high % 127)
}

/// Whether `address` is a provisional address (an unassigned node's).
pub const fn is_provisional(address: u8) -> bool {
    address >= PROVISIONAL_BASE && address != crate::protocol::BROADCAST
}

/// The 24-bit check of a uid that an [`Assign`](crate::protocol::Assign) carries: the low 24 bits
/// of its CRC-32 (the address takes the high byte).
pub fn uid_check(uid: &[u8; UID_LEN]) -> u32 {
    crc32(uid) & 0x00FF_FFFF
}

/// Collects one node's identity frames as they arrive (the tool's side): complete once all six
/// parts came from one source.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IdentityParts {
    parts: [[u8; 8]; 6],
    seen: u8,
}

impl IdentityParts {
    /// Nothing yet.
    pub const fn new() -> IdentityParts {
        IdentityParts {
            parts: [[0; 8]; 6],
            seen: 0,
        }
    }

    /// Adds a part (a repeated part replaces the one before).
    pub fn add(&mut self, part: IdentityPart, payload: [u8; 8]) {
        if let Some(slot) = self.parts.get_mut(usize::from(part.index())) {
            *slot = payload;
            self.seen |= 1 << part.index();
        }
    }

    /// The identity, once all six parts are in.
    pub fn complete(&self) -> Option<Identity> {
        (self.seen == 0x3F).then(|| Identity::from_payloads(&self.parts))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Identity {
        Identity {
            uid: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12],
            firmware: Firmware::new("fw-g474", "0.1.2", "0123456789abcdefff"),
            protocol: PROTOCOL_VERSION,
            formats: [10, 10],
            capacity: Capacity {
                ports: 4,
                connections: 64,
                decision_nodes: 256,
                image_len: 8192,
            },
            features: Identity::FEATURE_BLE | Identity::FEATURE_SCHEMA,
            flags: Identity::FLAG_KEYED,
            bitrate_kbps: 500,
        }
    }

    #[test]
    fn every_part_round_trips() {
        let identity = sample();
        let mut parts = IdentityParts::new();
        for part in IdentityPart::ALL {
            assert_eq!(parts.complete(), None);
            let payload = identity.payload(part);
            assert!(Identity::part_is_valid(part, &payload), "{part:?}");
            parts.add(part, payload);
        }
        assert_eq!(parts.complete(), Some(identity));
        assert_eq!(
            identity.feature_names().collect::<Vec<_>>(),
            ["ble", "schema"]
        );
        assert_eq!(identity.firmware.name_str(), Some("fw-g474"));
    }

    #[test]
    fn firmware_text_is_read_as_documented() {
        let firmware = Firmware::new("a-very-long-name", "1.20.300-rc.1", "0a1B2c3D4e5F6a7b8");
        assert_eq!(&firmware.name, b"a-very-l");
        assert_eq!(firmware.version, [1, 20, 255]);
        assert_eq!(
            firmware.build,
            [0x0a, 0x1b, 0x2c, 0x3d, 0x4e, 0x5f, 0x6a, 0x7b]
        );
        let unknown = Firmware::new("pab-node", "0.1.0", "");
        assert_eq!(unknown.build, [0; 8]);
        assert_eq!(unknown.version, [0, 1, 0]);
        assert_eq!(Firmware::new("x", "2", "zz").version, [2, 0, 0]);
    }

    #[test]
    fn reserved_bytes_and_bad_names_are_refused() {
        let identity = sample();
        let mut capacity = identity.payload(IdentityPart::Capacity);
        capacity[7] = 1;
        assert!(!Identity::part_is_valid(IdentityPart::Capacity, &capacity));
        let mut features = identity.payload(IdentityPart::Features);
        features[4] = 0x80;
        assert!(!Identity::part_is_valid(IdentityPart::Features, &features));
        // Feature bits 0-4 are defined (4: CAN FD), 5-15 reserved.
        let mut features = identity.payload(IdentityPart::Features);
        features[2] = 0x1F;
        assert!(Identity::part_is_valid(IdentityPart::Features, &features));
        features[2] = 0x20;
        assert!(!Identity::part_is_valid(IdentityPart::Features, &features));
        features[2] = 0;
        features[3] = 0x01;
        assert!(!Identity::part_is_valid(IdentityPart::Features, &features));
        assert!(!Identity::part_is_valid(
            IdentityPart::Name,
            b"ab\0c\0\0\0\0"
        ));
        assert!(!Identity::part_is_valid(
            IdentityPart::Name,
            b"a b\0\0\0\0\0"
        ));
        assert!(Identity::part_is_valid(
            IdentityPart::Name,
            b"\0\0\0\0\0\0\0\0"
        ));
    }

    #[test]
    #[cfg(feature = "identity")]
    fn the_documented_assignment_example_holds() {
        // docs/can-protocol.md, "Assign (0x28)".
        let uid = [0xAB, 1, 2, 3, 4, 5, 6, 0xCD, 0, 0, 0, 0];
        assert_eq!(crc32(&uid), 0x9FE9_0B6B);
        assert_eq!(provisional_address(&uid), 0xA0);
        assert_eq!(uid_check(&uid), 0x00E9_0B6B);
        let frame = crate::protocol::Message::Assign(crate::protocol::Assign {
            uid_check: uid_check(&uid),
            node_id: 4,
            tag: None,
        })
        .to_frame(crate::protocol::TOOL, 0xA0);
        assert_eq!(
            frame.id(),
            crate::protocol::FrameId::from_raw(0x0E28_A000)
                .unwrap()
                .id()
        );
        assert_eq!(frame.payload(), [0x6B, 0x0B, 0xE9, 4]);
    }

    #[test]
    fn provisional_addresses_are_never_a_node_tool_or_broadcast() {
        for seed in 0u32..20_000 {
            let mut uid = [0u8; UID_LEN];
            uid[..4].copy_from_slice(&seed.to_le_bytes());
            let address = provisional_address(&uid);
            assert!((0x80..=0xFE).contains(&address), "{address:#x}");
            assert!(is_provisional(address));
            assert!(uid_check(&uid) <= 0x00FF_FFFF);
        }
        assert!(!is_provisional(crate::protocol::BROADCAST));
        assert!(!is_provisional(127));
    }
}
