//! The boards' AES-128-CMAC (`core/src/auth/aes_cmac.rs`, reached through pab-core's feature
//! `board-cmac`) against RustCrypto's `aes` and `cmac` (what hosts use), differentially.
//!
//! The input gives a 16-byte key and a message of up to a few hundred bytes cut into up to 8
//! parts at arbitrary places (empty parts included): the boards' implementation takes the parts
//! as they are (it holds a block back across parts), RustCrypto's gets them through `update`
//! one by one, and again as one slice. Properties:
//!
//! - **Byte-identical MACs**: the boards' 16 bytes equal RustCrypto's for every key, message and
//!   way of cutting it; cut differently (one part), the boards' MAC does not change.
//! - **Never a panic**, whatever the lengths (0, a multiple of 16, one more or less).

use arbitrary::{Result, Unstructured};
use cmac::Mac;
use cmac::digest::KeyInit;
use pab_core::auth::board_cmac;

/// Runs one key and one message.
pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data));
}

fn rustcrypto(key: &[u8; 16], parts: &[&[u8]]) -> [u8; 16] {
    let mut mac = <cmac::Cmac<aes::Aes128> as KeyInit>::new(&(*key).into());
    for part in parts {
        mac.update(part);
    }
    mac.finalize().into_bytes().into()
}

fn run(u: &mut Unstructured<'_>) -> Result<()> {
    let key: [u8; 16] = u.arbitrary()?;
    // Lengths near block boundaries are where CMAC's padding and subkeys differ: now and then a
    // length of exactly k·16 + {-1, 0, 1}.
    let cuts = usize::from(u.int_in_range(0u8..=7)?);
    let len = if u.ratio(1u8, 2)? {
        let blocks = usize::from(u.int_in_range(0u8..=16)?);
        (blocks * 16 + usize::from(u.int_in_range(0u8..=2)?)).saturating_sub(1)
    } else {
        u.int_in_range(0usize..=300)?
    };
    let message: Vec<u8> = if u.ratio(1u8, 4)? {
        // A repeated byte: cheap for the fuzzer, and long.
        vec![u.arbitrary()?; len]
    } else {
        let take = len.min(u.len());
        let mut bytes = u.bytes(take)?.to_vec();
        bytes.resize(len, 0);
        bytes
    };
    let mut at: Vec<usize> = (0..cuts)
        .map(|_| u.int_in_range(0..=message.len()))
        .collect::<Result<_>>()?;
    at.sort_unstable();
    let mut parts: Vec<&[u8]> = Vec::new();
    let mut start = 0;
    for &end in &at {
        parts.push(&message[start..end]);
        start = end;
    }
    parts.push(&message[start..]);

    let theirs = rustcrypto(&key, &[&message]);
    assert_eq!(
        rustcrypto(&key, &parts),
        theirs,
        "RustCrypto's CMAC depends on the cuts"
    );
    let ours = board_cmac(&key, &parts);
    assert_eq!(
        ours,
        theirs,
        "the boards' CMAC differs: key {key:02x?}, {} bytes in parts of {:?}",
        message.len(),
        parts.iter().map(|p| p.len()).collect::<Vec<_>>()
    );
    assert_eq!(
        board_cmac(&key, &[&message]),
        ours,
        "the cuts change the boards' CMAC"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RFC 4493's example 3 (40 bytes): the check's reference and the boards' agree with it, so
    /// the property compares two right answers rather than two equal wrong ones.
    #[test]
    fn both_give_rfc_4493_example_3() {
        let key = [
            0x2b, 0x7e, 0x15, 0x16, 0x28, 0xae, 0xd2, 0xa6, 0xab, 0xf7, 0x15, 0x88, 0x09, 0xcf,
            0x4f, 0x3c,
        ];
        let message = [
            0x6b, 0xc1, 0xbe, 0xe2, 0x2e, 0x40, 0x9f, 0x96, 0xe9, 0x3d, 0x7e, 0x11, 0x73, 0x93,
            0x17, 0x2a, 0xae, 0x2d, 0x8a, 0x57, 0x1e, 0x03, 0xac, 0x9c, 0x9e, 0xb7, 0x6f, 0xac,
            0x45, 0xaf, 0x8e, 0x51, 0x30, 0xc8, 0x1c, 0x46, 0xa3, 0x5c, 0xe4, 0x11,
        ];
        let expected = [
            0xdf, 0xa6, 0x67, 0x47, 0xde, 0x9a, 0xe6, 0x30, 0x30, 0xca, 0x32, 0x61, 0x14, 0x97,
            0xc8, 0x27,
        ];
        assert_eq!(rustcrypto(&key, &[&message[..7], &message[7..]]), expected);
        assert_eq!(
            board_cmac(&key, &[&message[..33], &[], &message[33..]]),
            expected
        );
    }
}
