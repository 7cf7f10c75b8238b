//! Identity and configuration over the bus ([`crate::identity`]): the request a node answers
//! with its six identity frames, the assignment of a node id by uid, the bit rate, and the
//! status that answers both.

use crate::identity::IdentityPart;
use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Values};

/// Gives a node its id (service 0x28), tool → the node's current address (its node id, or its
/// provisional address when unassigned). Point to point: a broadcast is ignored.
///
/// ```text
/// bytes 0-2  uid check: the low 24 bits of CRC-32 of the node's 12-byte uid (identity::uid_check);
///            a node whose check differs ignores the frame (two unassigned nodes may share an
///            address)
/// byte 3     the new node id, 1..=127
/// bytes 4-7  on a keyed node: tag, CMAC (domain 1, address, service, both nonces, bytes 0-3),
///            first 4 bytes (the frame is 4 bytes long without a key)
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Assign {
    /// [`crate::identity::uid_check`] of the node meant.
    pub uid_check: u32,
    /// Its new node id.
    pub node_id: u8,
    /// The tag over the node's challenge (a keyed node's form).
    pub tag: Option<[u8; crate::auth::COMMAND_TAG_LEN]>,
}

impl Assign {
    /// The 4 bytes the tag covers.
    pub fn payload(&self) -> [u8; 4] {
        let [c0, c1, c2, _] = self.uid_check.to_le_bytes();
        [c0, c1, c2, self.node_id]
    }

    /// The payload's layout (to a node with a key, 4 more bytes: the tag).
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Assign,
        &[
            Field::new(
                "uid_check",
                0,
                24,
                "low 24 bits of CRC-32 of the node's uid: only that node takes the frame",
            ),
            Field::new("node_id", 24, 8, "the node's new id").max(127),
        ],
        "gives the node at this address its node id, stored power-fail safe and in force at \
         once; answered by ConfigStatus from the new id. To a node with a key, the frame is 8 \
         bytes: these 4 and a 4-byte tag over the node's challenge.",
    );
}

/// Sets a node's bit rate from its next start (service 0x29), tool → node. Point to point.
///
/// ```text
/// bytes 0-1  bit rate, kbit/s, u16 LE: 125, 250, 500 or 1000
/// bytes 2-3  reserved, 0
/// bytes 4-7  on a keyed node: tag, as Assign's
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Configure {
    /// The bit rate, kbit/s.
    pub bitrate_kbps: u16,
    /// The tag over the node's challenge (a keyed node's form).
    pub tag: Option<[u8; crate::auth::COMMAND_TAG_LEN]>,
}

impl Configure {
    /// The bit rates a node may be set to, kbit/s (classic CAN's usual ones that every board
    /// here derives exactly from its clock).
    pub const BITRATES_KBPS: [u16; 4] = [125, 250, 500, 1000];

    /// The 4 bytes the tag covers.
    pub fn payload(&self) -> [u8; 4] {
        let [b0, b1] = self.bitrate_kbps.to_le_bytes();
        [b0, b1, 0, 0]
    }

    /// The payload's layout (to a node with a key, 4 more bytes: the tag).
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Configure,
        &[
            Field::new(
                "bitrate",
                0,
                16,
                "the bit rate from the next start: 125, 250, 500 or 1000",
            )
            .unit("kbit/s"),
            Field::reserved("reserved", 16, 16),
        ],
        "sets the node's bit rate from its next start; a node that then hears nothing within \
         5 s goes back to its previous rate and raises BitrateFallback. Answered by \
         ConfigStatus. To a node with a key, the frame is 8 bytes: these 4 and a 4-byte tag.",
    );
}

/// The answer to an [`Assign`] or a [`Configure`] (service 0x2A), node → tool.
///
/// ```text
/// byte 0     the command answered: its service code (0x28 Assign, 0x29 Configure)
/// byte 1     status (ConfigStatusCode)
/// byte 2     the node id the node has now (0: none)
/// byte 3     reserved, 0
/// bytes 4-5  the bit rate from the next start, kbit/s, u16 LE
/// bytes 6-7  reserved, 0
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConfigStatus {
    /// [`Service::Assign`] or [`Service::Configure`]'s code.
    pub command: u8,
    /// What happened.
    pub status: crate::protocol::ConfigStatusCode,
    /// The node's id now (0: unassigned).
    pub node_id: u8,
    /// The bit rate it will run at from its next start, kbit/s.
    pub bitrate_kbps: u16,
}

impl ConfigStatus {
    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::ConfigStatus,
        &[
            Field::new(
                "command",
                0,
                8,
                "the command answered: 0x28 Assign, 0x29 Configure",
            )
            .values(Values::ConfigCommand),
            Field::new("status", 8, 8, "what happened").values(Values::ConfigStatusCode),
            Field::new("node_id", 16, 8, "the node id the node has now (0: none)").max(127),
            Field::reserved("reserved", 24, 8),
            Field::new("bitrate", 32, 16, "the bit rate from the next start").unit("kbit/s"),
            Field::reserved("reserved_2", 48, 16),
        ],
        "answers Assign and Configure, to the tool; from the node's new id after an Assign.",
    );
}

/// The layout of an identity request (service 0x21): no payload.
pub const IDENTITY_REQUEST_LAYOUT: Layout = Layout::fixed(
    Service::IdentityRequest,
    &[],
    "asks a node (or every node, broadcast) for its identity: answered by its six identity \
     frames, which it also sends once at start-up, to all.",
);

/// The service of each identity part.
pub const fn identity_service(part: IdentityPart) -> Service {
    match part {
        IdentityPart::Uid => Service::Identity,
        IdentityPart::Version => Service::IdentityVersion,
        IdentityPart::Build => Service::IdentityBuild,
        IdentityPart::Capacity => Service::IdentityCapacity,
        IdentityPart::Features => Service::IdentityFeatures,
        IdentityPart::Name => Service::IdentityName,
    }
}

/// The identity part a service carries, if it is one.
pub const fn identity_part(service: Service) -> Option<IdentityPart> {
    Some(match service {
        Service::Identity => IdentityPart::Uid,
        Service::IdentityVersion => IdentityPart::Version,
        Service::IdentityBuild => IdentityPart::Build,
        Service::IdentityCapacity => IdentityPart::Capacity,
        Service::IdentityFeatures => IdentityPart::Features,
        Service::IdentityName => IdentityPart::Name,
        _ => return None,
    })
}

const IDENTITY_SUMMARY: &str = "one of the six identity frames a node sends, in service order, \
    when asked (IdentityRequest) and once at start-up; an unassigned node sends them from its \
    provisional address (0x80 + a hash of its uid).";

/// The layout of identity part 0 (service 0x22): uid bytes 0-7.
pub const IDENTITY_LAYOUT: Layout = Layout::fixed(
    Service::Identity,
    &[
        Field::new("uid_low", 0, 32, "unique id: bytes 0-3"),
        Field::new("uid_mid", 32, 32, "unique id: bytes 4-7"),
    ],
    IDENTITY_SUMMARY,
);

/// The layout of identity part 1 (service 0x23).
pub const IDENTITY_VERSION_LAYOUT: Layout = Layout::fixed(
    Service::IdentityVersion,
    &[
        Field::new("uid_high", 0, 32, "unique id: bytes 8-11"),
        Field::new("major", 32, 8, "firmware version: major"),
        Field::new("minor", 40, 8, "firmware version: minor"),
        Field::new("patch", 48, 8, "firmware version: patch"),
        Field::new("protocol", 56, 8, "protocol version of the firmware"),
    ],
    IDENTITY_SUMMARY,
);

/// The layout of identity part 2 (service 0x24).
pub const IDENTITY_BUILD_LAYOUT: Layout = Layout::fixed(
    Service::IdentityBuild,
    &[
        Field::new(
            "build_high",
            0,
            32,
            "build id bytes 0-3 (byte 0: the git commit's first two hex digits; 0: unknown)",
        ),
        Field::new("build_low", 32, 32, "build id bytes 4-7"),
    ],
    IDENTITY_SUMMARY,
);

/// The layout of identity part 3 (service 0x25).
pub const IDENTITY_CAPACITY_LAYOUT: Layout = Layout::fixed(
    Service::IdentityCapacity,
    &[
        Field::new("ports", 0, 8, "ports a table may have"),
        Field::new("connections", 8, 16, "connections a table may have"),
        Field::new("decision_nodes", 24, 16, "decision nodes a table may have"),
        Field::new("image", 40, 16, "the largest table image it takes").unit("B"),
        Field::reserved("reserved", 56, 8),
    ],
    IDENTITY_SUMMARY,
);

/// The layout of identity part 4 (service 0x26).
pub const IDENTITY_FEATURES_LAYOUT: Layout = Layout::fixed(
    Service::IdentityFeatures,
    &[
        Field::new("format_min", 0, 8, "lowest table image format it loads"),
        Field::new("format_max", 8, 8, "highest table image format it loads"),
        Field::new("ble", 16, 1, "1: BLE compiled in"),
        Field::new("dynamics", 17, 1, "1: competitive dynamics compiled in"),
        Field::new("filters", 18, 1, "1: HBBA's message filters compiled in"),
        Field::new("schema", 19, 1, "1: the schema server compiled in"),
        Field::new(
            "fd",
            20,
            1,
            "1: CAN FD compiled in (takes CAN FD frames and transfers)",
        ),
        Field::reserved("reserved_features", 21, 11),
        Field::new("keyed", 32, 1, "1: takes only authenticated configuration"),
        Field::new(
            "locked",
            33,
            1,
            "1: key page invalid, takes no configuration",
        ),
        Field::new("unassigned", 34, 1, "1: no node id yet"),
        Field::new(
            "bitrate_trial",
            35,
            1,
            "1: runs a bit rate set over the bus that has not heard the bus yet",
        ),
        Field::new(
            "bitrate_fell_back",
            36,
            1,
            "1: a bit rate set over the bus heard nothing; back on the previous one",
        ),
        Field::reserved("reserved_flags", 37, 3),
        Field::reserved("reserved", 40, 8),
        Field::new(
            "bitrate",
            48,
            16,
            "the bit rate it runs at (0: set by its host)",
        )
        .unit("kbit/s"),
    ],
    IDENTITY_SUMMARY,
);

/// The layout of identity part 5 (service 0x27).
pub const IDENTITY_NAME_LAYOUT: Layout = Layout::fixed(
    Service::IdentityName,
    &[
        Field::new("name_low", 0, 32, "firmware name: ASCII bytes 0-3"),
        Field::new(
            "name_high",
            32,
            32,
            "firmware name: ASCII bytes 4-7, NUL-padded",
        ),
    ],
    IDENTITY_SUMMARY,
);
