//! A board's key at boot: what its key page and its boot counter make of the node.
//!
//! A board keeps its key in a dedicated flash page (written with `pabctl keypage` and a flasher;
//! docs/keys.md) and counts its boots in flash pages of its own ([`pab_storage::BootCounter`]).
//! At boot, before the node runs, [`key_from_page`] decides, the same way on every board:
//!
//! - **erased page** (the record is all 0xFF): no key; the node takes configuration from anyone
//!   and says so in its heartbeat. The boot counter is not touched (no wear, no salt needed).
//! - **a record that verifies**: the node gets the key ([`Node::set_key`]) with the boot count as
//!   its boot salt, counted for this boot. If counting fails (a flash error, a record that does
//!   not read back, the count exhausted), the node **fails closed**: no salt that is sure never
//!   to repeat means no challenge that is sure to be fresh, so it takes no configuration at all
//!   ([`Node::lock_configuration`], reason [`BOOT_COUNTER_FAILED`] + [`CounterError::code`]).
//! - **anything else** (garbage, a cut write, another format): the node fails closed with the
//!   page's reason ([`pab_core::auth::page::PageError::code`]).
//!
//! A locked node raises `KeyPageInvalid` (detail byte 0: the reason) after every heartbeat group
//! until the page or the counter is fixed and the board restarts.

use pab_core::auth::page;
use pab_storage::CounterError;

use crate::Node;
use crate::fmt::int;

/// The `KeyPageInvalid` reason of a boot counter failure, plus [`CounterError::code`]: 0x11
/// flash error, 0x12 layout, 0x13 count exhausted, 0x14 record does not read back. (Reasons
/// 1..=5 are the key page's own, [`pab_core::auth::page::PageError::code`].)
pub const BOOT_COUNTER_FAILED: u8 = 0x10;

/// What a board's boot made of its key page.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Keying {
    /// The page is erased: no key.
    Unkeyed,
    /// The node has the page's key; this boot's salt (the boot count).
    Keyed {
        /// The boot count, the high half of every challenge of this boot.
        boot_salt: u32,
    },
    /// The node takes no configuration; `reason` is the `KeyPageInvalid` fault's detail byte 0.
    Locked {
        /// A [`pab_core::auth::page::PageError::code`], or [`BOOT_COUNTER_FAILED`] plus a
        /// [`CounterError::code`].
        reason: u8,
    },
}

/// Keys `node` from its key page record `page` (the page's first
/// [`pab_core::auth::page::LEN`] bytes; a page that could not be read: pass an empty slice,
/// which fails closed as truncated). `boot_count` counts this boot
/// ([`pab_storage::BootCounter::increment`]); it is called only when the page holds a key.
///
/// Costs the record's CRC, and with a key one boot count and the AES key expansion. Logs the
/// outcome.
pub fn key_from_page<const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    page: &[u8],
    boot_count: impl FnOnce() -> Result<u32, CounterError>,
) -> Keying {
    let keying = match page::decode(page) {
        Ok(None) => Keying::Unkeyed,
        Ok(Some(key)) => match boot_count() {
            Ok(boot_salt) => {
                node.set_key(&key, boot_salt);
                Keying::Keyed { boot_salt }
            }
            Err(error) => Keying::Locked {
                reason: BOOT_COUNTER_FAILED | error.code(),
            },
        },
        Err(error) => Keying::Locked {
            reason: error.code(),
        },
    };
    match keying {
        Keying::Unkeyed => {
            warn!("key page erased: no key, this node accepts configuration from anyone on the bus")
        }
        Keying::Keyed { boot_salt } => {
            info!(
                "keyed: only authenticated configuration is accepted (boot {})",
                int(boot_salt)
            )
        }
        Keying::Locked { reason } => {
            node.lock_configuration(reason);
            warn!(
                "key page or boot counter invalid (reason {}): configuration locked",
                int(u32::from(reason))
            )
        }
    }
    keying
}
