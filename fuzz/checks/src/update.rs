//! The signed firmware image (`pab_core::update`): what a node checks before it lets its
//! bootloader swap an image in. Two kinds of input, by the first byte:
//!
//! - **Raw** (even): the rest is a candidate signed image, checked as a node running `fw-g474`
//!   1.4.2 with a 64 KiB update partition and a fixed public key would. Properties: never a
//!   panic; a parsed image's parts add up (image, 32-byte trailer, 64-byte signature, the
//!   trailer's length the image's); the trailer reads back to the same bytes; an admitted image
//!   verifies under the same key with ed25519-dalek's own strict check of the digest.
//! - **Edited** (odd): an image the check signs with the fixed key (image bytes, board kind,
//!   version, downgrade flag from the input), then edits from the input (bytes flipped, cut,
//!   appended, the trailer's fields rewritten). Properties: the unedited image is admitted
//!   exactly when the check's own model of the rules admits its metadata (its board kind, a
//!   version not lower unless signed as a downgrade); an edit that changes any byte is never
//!   admitted.

use arbitrary::{Result, Unstructured};
use ed25519_dalek::{Signer, SigningKey};
use pab_core::identity::Firmware;
use pab_core::update::{self, SIGNATURE_LEN, SignedImage, TRAILER_LEN, Trailer};

const CAPACITY: u32 = 64 * 1024;

fn key() -> SigningKey {
    SigningKey::from_bytes(&[0x5E; 32])
}

fn running() -> Firmware {
    Firmware::new("fw-g474", "1.4.2", "00112233aabbccdd")
}

pub fn check(data: &[u8]) {
    let Some((&kind, rest)) = data.split_first() else {
        return;
    };
    if kind % 2 == 0 {
        raw(rest);
    } else {
        let _ = edited(&mut Unstructured::new(rest));
    }
}

fn raw(bytes: &[u8]) {
    let public = key().verifying_key().to_bytes();
    let Ok(parsed) = SignedImage::parse(bytes) else {
        return;
    };
    assert_eq!(parsed.signed.len() + SIGNATURE_LEN, bytes.len());
    assert_eq!(parsed.image().len() + TRAILER_LEN, parsed.signed.len());
    assert_eq!(parsed.trailer.image_len as usize, parsed.image().len());
    let trailer_bytes = &parsed.signed[parsed.image().len()..];
    assert_eq!(parsed.trailer.encode().as_slice(), trailer_bytes);
    if parsed.check(&running(), CAPACITY, &public).is_ok() {
        assert!(parsed.trailer.admits(&running(), CAPACITY).is_ok());
        let verifying = ed25519_dalek::VerifyingKey::from_bytes(&public).unwrap();
        let signature = ed25519_dalek::Signature::from_bytes(parsed.signature);
        assert!(
            verifying
                .verify_strict(&update::digest(parsed.signed), &signature)
                .is_ok()
        );
    }
}

fn edited(u: &mut Unstructured<'_>) -> Result<()> {
    let len = u.int_in_range(0..=600usize)?;
    let image = u.bytes(len)?.to_vec();
    let name = *u.choose(&["fw-g474", "fw-f446", "fw-an386"])?;
    let version = [
        u.int_in_range(0..=3)?,
        u.int_in_range(0..=6)?,
        u.arbitrary()?,
    ];
    let downgrade: bool = u.arbitrary()?;
    let mut firmware = Firmware::new(name, "0.0.0", "0123456789abcdef");
    firmware.version = version;
    let trailer = Trailer {
        firmware,
        downgrade,
        image_len: image.len() as u32,
    };
    let mut signed = image.clone();
    signed.extend_from_slice(&trailer.encode());
    let signature = key().sign(&update::digest(&signed));
    signed.extend_from_slice(&signature.to_bytes());
    let original = signed.clone();
    let public = key().verifying_key().to_bytes();
    // The rules, modelled apart from `Trailer::admits`: its board kind, a version not lower
    // (compared part by part) unless signed as a downgrade, an image that fits and holds a
    // vector table's first two words.
    let now = running();
    let not_lower =
        (version[0], version[1], version[2]) >= (now.version[0], now.version[1], now.version[2]);
    let admissible = firmware.name == now.name
        && (not_lower || downgrade)
        && image.len() as u32 <= CAPACITY
        && image.len() >= 8;
    let outcome = |bytes: &[u8]| {
        SignedImage::parse(bytes).and_then(|parsed| parsed.check(&running(), CAPACITY, &public))
    };
    assert_eq!(outcome(&signed).is_ok(), admissible, "{trailer:?}");
    for _ in 0..u.int_in_range(0..=4)? {
        match u.int_in_range(0..=3u8)? {
            0 => {
                if !signed.is_empty() {
                    let at = u.choose_index(signed.len())?;
                    let flip: u8 = u.arbitrary()?;
                    signed[at] ^= flip;
                }
            }
            1 => {
                let keep = u.int_in_range(0..=signed.len())?;
                signed.truncate(keep);
            }
            2 => signed.push(u.arbitrary()?),
            _ => {
                // The trailer rewritten as another, well formed (the length kept or not).
                if signed.len() >= update::OVERHEAD {
                    let at = signed.len() - update::OVERHEAD;
                    let mut other = trailer;
                    other.firmware.version = [u.arbitrary()?, u.arbitrary()?, u.arbitrary()?];
                    other.downgrade = u.arbitrary()?;
                    if u.arbitrary()? {
                        other.image_len = u.arbitrary()?;
                    }
                    signed[at..at + TRAILER_LEN].copy_from_slice(&other.encode());
                }
            }
        }
    }
    if signed != original {
        assert!(
            outcome(&signed).is_err(),
            "an edited image was admitted: {} bytes, {} originally",
            signed.len(),
            original.len()
        );
    }
    Ok(())
}

/// Seeds: signed images of each board kind (raw), and edit scripts.
pub fn seeds() -> Vec<(String, Vec<u8>)> {
    let mut seeds = Vec::new();
    for (i, (name, version, downgrade)) in [
        ("fw-g474", "1.5.0", false),
        ("fw-g474", "1.0.0", true),
        ("fw-g474", "1.0.0", false),
        ("fw-f446", "1.5.0", false),
    ]
    .into_iter()
    .enumerate()
    {
        let image: Vec<u8> = (0..100 + 37 * i as u32).map(|b| (b * 13) as u8).collect();
        let trailer = Trailer {
            firmware: Firmware::new(name, version, "0123456789abcdef"),
            downgrade,
            image_len: image.len() as u32,
        };
        let mut bytes = vec![0u8];
        bytes.extend_from_slice(&image);
        bytes.extend_from_slice(&trailer.encode());
        let digest = update::digest(&bytes[1..]);
        bytes.extend_from_slice(&key().sign(&digest).to_bytes());
        let flag = if downgrade { "-downgrade" } else { "" };
        seeds.push((format!("signed-{name}-{version}{flag}"), bytes));
    }
    seeds
}
