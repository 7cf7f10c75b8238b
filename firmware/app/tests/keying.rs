//! A board's boot with its key page and boot counter (`pab_app::key_from_page`), on the node's
//! own code and pab-storage's test flash: erased page → no key; a valid record → keyed with the
//! boot count as salt, a new one every boot; an invalid page or a failing counter → locked, with
//! the reason in the `KeyPageInvalid` fault.

use crate::common;

use common::*;
use embedded_storage::nor_flash::NorFlash;
use pab_app::{BOOT_COUNTER_FAILED, Keying, key_from_page};
use pab_core::auth::{Authenticator, Key, page};
use pab_core::protocol::{self, DiagnosticControl, FaultCode, Message};
use pab_storage::testing::MemFlash;
use pab_storage::{BootCounter, CounterError};

/// The counter's two pages, the G474's geometry.
type CounterFlash = MemFlash<2, 4096, 8>;
const COUNTER: core::ops::Range<u32> = 0..2 * 4096;
const KEY: Key = Key::from_bytes([0x3C; 16]);

/// A key page as the flasher leaves it: the record, then erased bytes.
fn key_page(key: &Key) -> Vec<u8> {
    let mut bytes = page::encode(key).to_vec();
    bytes.resize(4096, 0xFF);
    bytes
}

/// Boots a node as a board does: key page first, then the stored table (none here).
fn boot(page: &[u8], flash: &mut CounterFlash) -> (Harness, Keying) {
    let mut keying = None;
    let harness = Harness::boot_with(None, |node| {
        keying = Some(key_from_page(node, page, || {
            BootCounter::new(&mut *flash, COUNTER)?.increment()
        }));
    });
    (harness, keying.expect("keyed at boot"))
}

fn key_page_faults(h: &Harness) -> Vec<u8> {
    h.messages_since(0)
        .into_iter()
        .filter_map(|(_, _, m)| match m {
            Message::Fault(f) if f.code == FaultCode::KeyPageInvalid => Some(f.detail[0]),
            _ => None,
        })
        .collect()
}

#[test]
fn an_erased_page_leaves_the_node_unkeyed_and_the_counter_untouched() {
    let mut flash = CounterFlash::new();
    let (h, keying) = boot(&[0xFF; 4096], &mut flash);
    assert_eq!(keying, Keying::Unkeyed);
    assert!(!h.node.is_keyed());
    assert_eq!(flash.operations(), 0);
}

#[test]
fn a_valid_page_keys_the_node_with_a_new_boot_salt_every_boot() {
    let mut flash = CounterFlash::new();
    let mut salts = Vec::new();
    for boot_number in 1..=3u32 {
        let (mut h, keying) = boot(&key_page(&KEY), &mut flash);
        assert_eq!(
            keying,
            Keying::Keyed {
                boot_salt: boot_number
            }
        );
        assert!(h.node.is_keyed());
        h.advance_to(2_000_000);
        assert!(key_page_faults(&h).is_empty());
        let (node_nonce, _) = h
            .challenge_answer(protocol::TOOL, 7)
            .expect("a keyed node answers a challenge");
        // The boot salt is in the node nonce, through the key: its first challenge's nonce is
        // the CMAC of this boot's salt and counter 1.
        let salt = (1..=3)
            .find(|&salt| {
                Authenticator::new(&KEY).node_nonce(Harness::NODE_ID, salt, 1) == node_nonce
            })
            .expect("the nonce of a salt of the first three boots");
        salts.push(salt);
        // The key holder's command is taken: the node has this key.
        let from = h.now;
        h.keyed_command(
            &KEY,
            DiagnosticControl {
                rate_hz: 10,
                ports: 1,
            },
        );
        h.advance_to(h.now + 1_100_000);
        assert!(h.auth_failures_since(from).is_empty());
        assert!(
            h.messages_since(from)
                .iter()
                .any(|(_, _, m)| matches!(m, Message::TableStatus(s) if s.diagnostic && s.keyed))
        );
    }
    assert_eq!(salts, [1, 2, 3]);
}

#[test]
fn an_invalid_page_locks_the_node_with_its_reason() {
    let mut flipped = key_page(&KEY);
    flipped[10] ^= 1;
    for (page, reason) in [
        (flipped, page::PageError::Crc.code()),
        (vec![0; 4096], page::PageError::BadMagic.code()),
        (Vec::new(), page::PageError::Truncated.code()),
    ] {
        let mut flash = CounterFlash::new();
        let (mut h, keying) = boot(&page, &mut flash);
        assert_eq!(keying, Keying::Locked { reason });
        assert!(h.node.is_keyed());
        assert_eq!(flash.operations(), 0, "the counter is not touched");
        h.advance_to(3_000_000);
        let faults = key_page_faults(&h);
        assert!(
            !faults.is_empty() && faults.iter().all(|&d| d == reason),
            "{faults:?}"
        );
        assert!(
            h.challenge(protocol::TOOL, &KEY).is_none(),
            "a locked node issues no challenge"
        );
    }
}

#[test]
fn a_failing_boot_counter_locks_the_node() {
    // The power goes during the count: locked this boot, keyed with a new salt the next.
    let mut flash = CounterFlash::new();
    flash.fail_after(0);
    let (mut h, keying) = boot(&key_page(&KEY), &mut flash);
    let reason =
        BOOT_COUNTER_FAILED | CounterError::Flash(pab_storage::FlashErrorKind::Other).code();
    assert_eq!(reason, 0x11);
    assert_eq!(keying, Keying::Locked { reason });
    h.advance_to(2_000_000);
    assert!(key_page_faults(&h).contains(&reason));
    assert!(h.challenge(protocol::TOOL, &KEY).is_none());
    flash.reboot();
    let (_, keying) = boot(&key_page(&KEY), &mut flash);
    assert_eq!(keying, Keying::Keyed { boot_salt: 1 });
    // An exhausted count: locked for good (until a new key and a formatted counter).
    let mut flash = CounterFlash::new();
    let mut record = [0xFFu8; 16];
    record[..4].copy_from_slice(b"PABB");
    record[4..8].copy_from_slice(&u32::MAX.to_le_bytes());
    record[8..12].copy_from_slice(&0u32.to_le_bytes());
    let crc = pab_core::crc32::crc32(&record[..12]);
    record[12..].copy_from_slice(&crc.to_le_bytes());
    flash.write(0, &record).expect("plant");
    let (_, keying) = boot(&key_page(&KEY), &mut flash);
    assert_eq!(keying, Keying::Locked { reason: 0x13 });
}
