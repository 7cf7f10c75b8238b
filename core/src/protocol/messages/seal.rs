//! The frames that authenticate coordination on a keyed network ([`crate::seal`]): the seal that
//! follows each coordination frame, and the freshness exchange that tells a receiver where a
//! sender's counter stands.

use crate::protocol::Service;
use crate::protocol::layout::{Field, Layout, Values};

/// The seal of the coordination frame its sender sent just before it (service 0x1E), on a keyed
/// network: to the sealed frame's destination.
///
/// ```text
/// byte 0     kind: the sealed frame's service code (0x07 Gates, 0x17 FilterProfile,
///            0x18 FilterSet, 0x20 Freshness), or 0x80 for a BLE claim
/// byte 1     digest: the sealed frame's payload bytes summed mod 256, which tells apart the
///            frames of one sender and kind held for their seals (not a check: the tag is)
/// bytes 2-3  the sender's freshness counter, bits 0-15, u16 LE (0 for a Freshness)
/// bytes 4-7  tag: CMAC (domain 7, sender, the sealed frame's identifier u32 LE, its length, its
///            payload, freshness u64 LE), bytes 0-3
/// ```
///
/// Priority 5, so that it always ranks after the frame it seals (claims rank at 4, Gates and
/// filter commands at 3): a sender's queue and its controller send in identifier order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Seal {
    /// What it seals: a service code, or [`Seal::CLAIM`].
    pub kind: u8,
    /// The sealed frame's payload bytes summed mod 256 ([`Seal::digest`]).
    pub digest: u8,
    /// The sender's freshness counter, its low 16 bits.
    pub counter: u16,
    /// The truncated CMAC.
    pub tag: [u8; crate::auth::SEAL_TAG_LEN],
}

impl Seal {
    /// [`Seal::kind`] of a BLE claim (claims have no service code: bit 23 of their identifier).
    pub const CLAIM: u8 = 0x80;

    /// [`Seal::digest`] of a payload: its bytes summed mod 256.
    pub fn digest_of(payload: &[u8]) -> u8 {
        payload
            .iter()
            .fold(0u8, |sum, byte| sum.wrapping_add(*byte))
    }

    /// Whether `kind` names something a seal may follow ([`Values::SealKind`]).
    pub const fn is_sealable(kind: u8) -> bool {
        matches!(kind, 0x07 | 0x17 | 0x18 | 0x20 | Seal::CLAIM)
    }

    /// The payload's layout.
    pub const LAYOUT: Layout = Layout::fixed(
        Service::Seal,
        &[
            Field::new(
                "kind",
                0,
                8,
                "the sealed frame's service (0x07 Gates, 0x17 FilterProfile, 0x18 FilterSet, \
                 0x20 Freshness) or 0x80 for a BLE claim",
            )
            .values(Values::SealKind),
            Field::new(
                "digest",
                8,
                8,
                "the sealed frame's payload bytes summed mod 256",
            ),
            Field::new(
                "counter",
                16,
                16,
                "the sender's freshness counter, bits 0-15 (0 for a Freshness)",
            ),
            Field::new(
                "tag",
                32,
                32,
                "CMAC (domain 7, sender, sealed identifier, length, payload, freshness): bytes 0-3",
            ),
        ],
        "follows each coordination frame (Gates, BLE claim, filter command, Freshness) of a \
         keyed node: a keyed receiver applies the frame only once its seal verifies with a \
         freshness above the last it accepted from that sender.",
    );
}

/// The layout of a freshness request (service 0x1F): the receiver's nonce, u64 LE.
pub const FRESHNESS_REQUEST_LAYOUT: Layout = Layout::fixed(
    Service::FreshnessRequest,
    &[
        Field::new("nonce_low", 0, 32, "the receiver's nonce: bits 0-31"),
        Field::new("nonce_high", 32, 32, "the receiver's nonce: bits 32-63"),
    ],
    "a keyed receiver asks a sender where its freshness stands (at its first seal, and when \
     one fails), with a nonce unpredictable without the key; at most once a second per sender.",
);

/// The layout of a freshness answer (service 0x20): the sender's epoch and its counter.
pub const FRESHNESS_LAYOUT: Layout = Layout::fixed(
    Service::Freshness,
    &[
        Field::new(
            "epoch",
            0,
            32,
            "the sender's epoch: its boot salt, never repeated for one key",
        ),
        Field::new(
            "counter",
            32,
            32,
            "the last freshness counter the sender used in this epoch",
        ),
    ],
    "answers a freshness request, to its sender; its seal's freshness is the request's nonce, \
     so that a recorded answer is worthless.",
);
