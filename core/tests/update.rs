//! The signed firmware image (`pab_core::update`) against real Ed25519 signatures: an image
//! signed for the node is admitted, and every change to it, every other key and every
//! inadmissible trailer is refused with its reason.

use ed25519_dalek::{Signer, SigningKey};
use pab_core::identity::Firmware;
use pab_core::update::{self, SIGNATURE_LEN, SignedImage, TRAILER_LEN, Trailer, UpdateRefusal};
use proptest::prelude::*;

const CAPACITY: u32 = 4096;

fn key(seed: u8) -> SigningKey {
    SigningKey::from_bytes(&[seed; 32])
}

fn running() -> Firmware {
    Firmware::new("fw-g474", "1.4.2", "00112233aabbccdd")
}

/// `image` signed by `key` as `firmware` (as `pabctl sign` does).
fn sign(key: &SigningKey, image: &[u8], firmware: Firmware, downgrade: bool) -> Vec<u8> {
    let trailer = Trailer {
        firmware,
        downgrade,
        image_len: image.len() as u32,
    };
    let mut bytes = image.to_vec();
    bytes.extend_from_slice(&trailer.encode());
    let signature = key.sign(&update::digest(&bytes));
    bytes.extend_from_slice(&signature.to_bytes());
    bytes
}

fn check(bytes: &[u8], public: &SigningKey) -> Result<Trailer, UpdateRefusal> {
    SignedImage::parse(bytes)?.check(&running(), CAPACITY, &public.verifying_key().to_bytes())
}

#[test]
fn an_image_signed_for_the_node_is_admitted_and_its_digest_can_be_taken_in_chunks() {
    let image: Vec<u8> = (0..1000u32).map(|i| (i * 7) as u8).collect();
    let firmware = Firmware::new("fw-g474", "1.5.0", "ffeeddccbbaa9988");
    let signed = sign(&key(1), &image, firmware, false);
    assert_eq!(signed.len(), image.len() + TRAILER_LEN + SIGNATURE_LEN);
    let trailer = check(&signed, &key(1)).unwrap();
    assert_eq!(trailer.firmware, firmware);
    // A node hashes the image where it lies, chunk by chunk: the same digest.
    use sha2::Digest as _;
    let mut digest = update::Digest::new();
    for chunk in signed[..image.len() + TRAILER_LEN].chunks(96) {
        digest.update(chunk);
    }
    let digest: [u8; 64] = digest.finalize().into();
    let signature: &[u8; SIGNATURE_LEN] = signed[image.len() + TRAILER_LEN..].try_into().unwrap();
    assert_eq!(
        update::verify(&digest, signature, &key(1).verifying_key().to_bytes()),
        Ok(())
    );
}

#[test]
fn another_key_and_inadmissible_trailers_are_refused_with_their_reasons() {
    let image = [0x5Au8; 300];
    let ours = Firmware::new("fw-g474", "1.4.2", "0");
    assert_eq!(
        check(&sign(&key(2), &image, ours, false), &key(1)),
        Err(UpdateRefusal::BadSignature)
    );
    let other_board = Firmware::new("fw-f446", "1.4.2", "0");
    assert_eq!(
        check(&sign(&key(1), &image, other_board, false), &key(1)),
        Err(UpdateRefusal::OtherBoard)
    );
    let older = Firmware::new("fw-g474", "1.4.1", "0");
    assert_eq!(
        check(&sign(&key(1), &image, older, false), &key(1)),
        Err(UpdateRefusal::Downgrade)
    );
    assert!(check(&sign(&key(1), &image, older, true), &key(1)).is_ok());
    let large = vec![0u8; CAPACITY as usize + 1];
    assert_eq!(
        check(&sign(&key(1), &large, ours, false), &key(1)),
        Err(UpdateRefusal::TooLarge {
            len: CAPACITY + 1,
            capacity: CAPACITY
        })
    );
}

#[test]
fn a_signed_downgrade_flag_cannot_be_set_after_signing() {
    // The flag is in the signed bytes: set on an image signed without it, the signature fails.
    let image = [1u8; 64];
    let older = Firmware::new("fw-g474", "1.0.0", "0");
    let mut signed = sign(&key(1), &image, older, false);
    signed[image.len() + 5] |= 1;
    assert_eq!(check(&signed, &key(1)), Err(UpdateRefusal::BadSignature));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Any one byte changed anywhere in a signed image (image, trailer or signature) is refused.
    #[test]
    fn any_changed_byte_is_refused(
        image in proptest::collection::vec(any::<u8>(), 0..512),
        at in any::<prop::sample::Index>(),
        flip in 1..=255u8,
    ) {
        let signed = sign(&key(3), &image, running(), false);
        prop_assert!(check(&signed, &key(3)).is_ok());
        let mut changed = signed.clone();
        let at = at.index(changed.len());
        changed[at] ^= flip;
        prop_assert!(check(&changed, &key(3)).is_err(), "byte {} ^ {:#04x} admitted", at, flip);
    }

    /// Cut anywhere, a signed image is refused; nothing panics.
    #[test]
    fn a_truncated_image_is_refused(
        image in proptest::collection::vec(any::<u8>(), 0..256),
        cut in any::<prop::sample::Index>(),
    ) {
        let signed = sign(&key(4), &image, running(), false);
        let cut = cut.index(signed.len());
        prop_assert!(check(&signed[..cut], &key(4)).is_err());
    }
}
