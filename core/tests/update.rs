//! The signed firmware image (`pab_core::update`) against real Ed25519 signatures: an image
//! signed for the node is admitted, and every change to it, every other key and every
//! inadmissible trailer is refused with its reason.

use ed25519_dalek::{Signer, SigningKey};
use pab_core::identity::Firmware;
use pab_core::update::{
    self, SIGNATURE_LEN, SignedImage, TRAILER_LEN, Trailer, UpdateRefusal, stored,
};
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
    // Shorter than a vector table's first two words: nothing a bootloader could jump to.
    assert_eq!(
        check(&sign(&key(1), &[0; 7], running(), false), &key(1)),
        Err(UpdateRefusal::Truncated)
    );
    assert!(check(&sign(&key(1), &[0; 8], running(), false), &key(1)).is_ok());
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
    /// (Images of a vector table's two words at least: shorter ones are refused anyway.)
    #[test]
    fn any_changed_byte_is_refused(
        image in proptest::collection::vec(any::<u8>(), 8..512),
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

/// A slot of `slot_len` bytes as a node leaves it: `signed`'s image at offset 0, its trailer and
/// signature at the slot's end, erased (0xFF) between.
fn stored(signed: &[u8], slot_len: u32) -> Vec<u8> {
    let parsed = SignedImage::parse(signed).unwrap();
    let mut slot = vec![0xFFu8; slot_len as usize];
    slot[..parsed.image().len()].copy_from_slice(parsed.image());
    let manifest = stored::Manifest {
        trailer: parsed.trailer,
        signature: *parsed.signature,
    };
    let at = stored::manifest_offset(slot_len).unwrap() as usize;
    slot[at..].copy_from_slice(&manifest.encode());
    slot
}

fn check_slot(slot: &[u8], board: &str, public: &SigningKey) -> Result<Trailer, UpdateRefusal> {
    let board = Firmware::new(board, "0.0.0", "0").name;
    stored::check(
        slot.len() as u32,
        &board,
        &public.verifying_key().to_bytes(),
        |offset, buf: &mut [u8]| {
            let offset = offset as usize;
            buf.copy_from_slice(slot.get(offset..offset + buf.len()).ok_or(())?);
            Ok::<(), ()>(())
        },
    )
}

#[test]
fn the_bootloader_admits_a_stored_image_signed_for_its_board_and_nothing_else() {
    let image: Vec<u8> = (0..3000u32).map(|i| (i * 13 + 5) as u8).collect();
    let firmware = Firmware::new("fw-g474", "2.0.0", "1122334455667788");
    let slot = stored(&sign(&key(1), &image, firmware, false), 4096);
    assert_eq!(
        check_slot(&slot, "fw-g474", &key(1)).unwrap().firmware,
        firmware
    );
    assert_eq!(
        check_slot(&slot, "fw-g474", &key(2)),
        Err(UpdateRefusal::BadSignature)
    );
    assert_eq!(
        check_slot(&slot, "fw-f446", &key(1)),
        Err(UpdateRefusal::OtherBoard)
    );
    // A byte of the image, of the padding the hash does not cover, of the manifest.
    let mut changed = slot.clone();
    changed[2999] ^= 1;
    assert_eq!(
        check_slot(&changed, "fw-g474", &key(1)),
        Err(UpdateRefusal::BadSignature)
    );
    let mut padding = slot.clone();
    padding[3500] = 0;
    assert!(check_slot(&padding, "fw-g474", &key(1)).is_ok());
    let mut build = slot.clone();
    build[4096 - 96 + 20] ^= 1;
    assert_eq!(
        check_slot(&build, "fw-g474", &key(1)),
        Err(UpdateRefusal::BadSignature)
    );
    // An erased slot has no manifest; a manifest whose image overruns it is refused unread.
    assert_eq!(
        check_slot(&[0xFF; 4096], "fw-g474", &key(1)),
        Err(UpdateRefusal::BadTrailer)
    );
    let mut long = slot.clone();
    long[4096 - 96 + 28..4096 - 96 + 32].copy_from_slice(&4001u32.to_le_bytes());
    assert_eq!(
        check_slot(&long, "fw-g474", &key(1)),
        Err(UpdateRefusal::TooLarge {
            len: 4001,
            capacity: 4000
        })
    );
    // A slot that cannot be read is refused, not admitted.
    let board = Firmware::new("fw-g474", "0.0.0", "0").name;
    let unreadable = stored::check(4096, &board, &key(1).verifying_key().to_bytes(), |_, _| {
        Err::<(), ()>(())
    });
    assert_eq!(unreadable, Err(UpdateRefusal::Unreadable));
}

#[test]
fn the_request_page_reads_as_each_step_leaves_it() {
    let mut page = [0xFFu8; 16];
    assert_eq!(stored::Request::read(&page), stored::Request::None);
    page[..8].copy_from_slice(&stored::REQUEST);
    assert_eq!(stored::Request::read(&page), stored::Request::Pending);
    page[8..].copy_from_slice(&stored::verdict(Ok(())));
    assert_eq!(
        stored::Request::read(&page),
        stored::Request::Decided(Ok(()))
    );
    page[8..].copy_from_slice(&stored::verdict(Err(UpdateRefusal::BadSignature)));
    assert_eq!(
        stored::Request::read(&page),
        stored::Request::Decided(Err(6))
    );
    // A verdict half written, or with a code no refusal has, is decided again.
    page[15] = 0xFF;
    assert_eq!(stored::Request::read(&page), stored::Request::Pending);
    page[12] = 0;
    page[15] = 0;
    assert_eq!(stored::Request::read(&page), stored::Request::Pending);
    // A page of zeros (the emulated board's flash before its first erase) holds no request.
    assert_eq!(stored::Request::read(&[0; 16]), stored::Request::None);
}

#[test]
fn the_update_key_record_reads_back_and_nothing_else_reads_as_a_key() {
    let public = key(3).verifying_key().to_bytes();
    let record = stored::encode_key(&public);
    assert_eq!(&record[..8], b"PABS\x01\0\0\0");
    assert_eq!(stored::decode_key(&record), Some(public));
    for at in 0..stored::KEY_RECORD_LEN {
        let mut changed = record;
        changed[at] ^= 0x10;
        assert_eq!(stored::decode_key(&changed), None, "byte {at} changed");
    }
    assert_eq!(stored::decode_key(&[0xFF; stored::KEY_RECORD_LEN]), None);
    assert_eq!(stored::decode_key(&record[..47]), None);
}
