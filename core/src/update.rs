//! Firmware update: the signed image, and the checks a node makes before it lets its bootloader
//! swap one in (docs/firmware-update.md).
//!
//! A signed image is the application's binary as linked, a 32-byte trailer that says what it
//! is, and an Ed25519 signature:
//!
//! ```text
//! offset  bytes  field
//! 0       N      the image: the application's binary, its vector table first
//! N       4      magic "PABU"
//! N+4     1      trailer format: 1
//! N+5     1      flags: bit 0 = a downgrade is allowed; the other bits 0
//! N+6     2      0
//! N+8     8      board kind: the firmware's name as its identity states it (ASCII, 0-padded)
//! N+16    3      version: major, minor, patch
//! N+19    1      0
//! N+20    8      build id (the identity's: the first 16 hex digits of the commit)
//! N+28    4      N, little endian
//! N+32    64     Ed25519 signature of SHA-512(image ‖ trailer)
//! ```
//!
//! **A trailer, not a header**: the image is written to the update (DFU) partition as it is and
//! the bootloader swaps it into the active partition, where its vector table must come first.
//!
//! **What is signed**: the SHA-512 digest of the image and its trailer, so that the metadata
//! cannot be moved onto another image, nor the image put under other metadata. A digest rather
//! than the bytes, because that is what embassy-boot's `verify_and_mark_updated` checks (it
//! hashes the first `update_len` bytes of the DFU partition with SHA-512 and verifies the
//! signature over the digest), with `update_len` = N + 32: a node can check an image in flash in
//! chunks, and the bootloader's own check, where it makes one, is over the same bytes.
//!
//! **What a node admits** ([`Trailer::admits`]): an image for its own board kind, of a version
//! not lower than the one it runs unless the signed downgrade flag says so, that fits its update
//! partition, signed by the key it holds ([`verify`], with the feature `signature`). Anything
//! else is refused whole with an [`UpdateRefusal`]. The checks cost nothing at run time until an
//! update is offered; the signature's (the `signature` feature: RustCrypto's `sha2` and
//! `ed25519-dalek`) is the only one that needs a dependency.

use core::fmt;

use crate::identity::Firmware;

/// The trailer's magic: "PABU".
pub const MAGIC: [u8; 4] = *b"PABU";
/// The trailer's format.
pub const FORMAT: u8 = 1;
/// The trailer's length in bytes.
pub const TRAILER_LEN: usize = 32;
/// The signature's length in bytes (Ed25519).
pub const SIGNATURE_LEN: usize = 64;
/// An Ed25519 public key's length in bytes.
pub const PUBLIC_KEY_LEN: usize = 32;
/// What a signed image adds to its image: the trailer and the signature.
pub const OVERHEAD: usize = TRAILER_LEN + SIGNATURE_LEN;
/// A manifest's length: the trailer and the signature, as a node stores them for its bootloader
/// ([`stored`]).
pub const MANIFEST_LEN: usize = OVERHEAD;

pub mod session;
pub mod stored;

/// The shortest image a node takes: a vector table's first two words (the initial stack pointer
/// and the reset handler), without which a bootloader would jump into nothing.
pub const MIN_IMAGE_LEN: u32 = 8;

/// Flag bit 0: the image may replace a firmware of a higher version.
const DOWNGRADE: u8 = 1;

/// Why an image is refused. Each has a code (1 to 6), for the answer a node sends and the fault
/// it raises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum UpdateRefusal {
    /// Shorter than a trailer and a signature, not as long as its trailer says, or an image too
    /// short to hold a vector table ([`MIN_IMAGE_LEN`]).
    Truncated,
    /// The trailer is not one: its magic, its format or a reserved field.
    BadTrailer,
    /// The image does not fit the update partition.
    TooLarge {
        /// The image's length, bytes.
        len: u32,
        /// The largest image the node takes, bytes.
        capacity: u32,
    },
    /// Built for another board kind.
    OtherBoard,
    /// A version lower than the running one, without the signed downgrade flag.
    Downgrade,
    /// The signature does not verify under the node's public key (another key, or bytes changed).
    BadSignature,
    /// The bootloader could not read the update partition.
    Unreadable,
}

impl UpdateRefusal {
    /// A number for this refusal, for the wire: 1 truncated, 2 bad trailer, 3 too large, 4 other
    /// board, 5 downgrade, 6 bad signature, 7 unreadable.
    pub const fn code(self) -> u8 {
        match self {
            UpdateRefusal::Truncated => 1,
            UpdateRefusal::BadTrailer => 2,
            UpdateRefusal::TooLarge { .. } => 3,
            UpdateRefusal::OtherBoard => 4,
            UpdateRefusal::Downgrade => 5,
            UpdateRefusal::BadSignature => 6,
            UpdateRefusal::Unreadable => 7,
        }
    }
}

impl fmt::Display for UpdateRefusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UpdateRefusal::Truncated => f.write_str("truncated: not the length its trailer says"),
            UpdateRefusal::BadTrailer => f.write_str("no signed-image trailer at its end"),
            UpdateRefusal::TooLarge { len, capacity } => write!(
                f,
                "the image is {len} bytes, more than the {capacity} the node's update partition holds"
            ),
            UpdateRefusal::OtherBoard => f.write_str("built for another board kind"),
            UpdateRefusal::Downgrade => {
                f.write_str("a lower version than the node runs, and not signed as a downgrade")
            }
            UpdateRefusal::BadSignature => {
                f.write_str("the signature does not verify under the node's public key")
            }
            UpdateRefusal::Unreadable => f.write_str("the update partition could not be read"),
        }
    }
}

impl core::error::Error for UpdateRefusal {}

/// What a signed image says it is: its trailer's fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Trailer {
    /// The board kind, version and build it was signed as (the name is the board kind).
    pub firmware: Firmware,
    /// Whether it may replace a higher version.
    pub downgrade: bool,
    /// The image's length in bytes (what precedes the trailer).
    pub image_len: u32,
}

impl Trailer {
    /// The trailer's 32 bytes.
    pub fn encode(&self) -> [u8; TRAILER_LEN] {
        let mut out = [0u8; TRAILER_LEN];
        let (magic, rest) = out.split_at_mut(4);
        magic.copy_from_slice(&MAGIC);
        let (head, rest) = rest.split_at_mut(4);
        head.copy_from_slice(&[FORMAT, if self.downgrade { DOWNGRADE } else { 0 }, 0, 0]);
        let (name, rest) = rest.split_at_mut(8);
        name.copy_from_slice(&self.firmware.name);
        let (version, rest) = rest.split_at_mut(4);
        let [major, minor, patch] = self.firmware.version;
        version.copy_from_slice(&[major, minor, patch, 0]);
        let (build, len) = rest.split_at_mut(8);
        build.copy_from_slice(&self.firmware.build);
        len.copy_from_slice(&self.image_len.to_le_bytes());
        out
    }

    /// Reads a trailer: its magic, its format and its reserved bits must be as written; nothing
    /// else is judged here ([`Trailer::admits`] does).
    pub fn decode(bytes: &[u8; TRAILER_LEN]) -> Result<Trailer, UpdateRefusal> {
        let mut rest: &[u8] = bytes;
        let magic = take::<4>(&mut rest);
        let [format, flags, r0, r1] = take::<4>(&mut rest);
        let name = take::<8>(&mut rest);
        let [major, minor, patch, r2] = take::<4>(&mut rest);
        let build = take::<8>(&mut rest);
        let len = take::<4>(&mut rest);
        if magic != MAGIC || format != FORMAT || flags & !DOWNGRADE != 0 || [r0, r1, r2] != [0; 3] {
            return Err(UpdateRefusal::BadTrailer);
        }
        Ok(Trailer {
            firmware: Firmware {
                name,
                version: [major, minor, patch],
                build,
            },
            downgrade: flags & DOWNGRADE != 0,
            image_len: u32::from_le_bytes(len),
        })
    }

    /// Whether a node running `running`, whose update partition takes images of up to
    /// `capacity` bytes, may take this image (its signature aside: [`verify`]). An image shorter
    /// than [`MIN_IMAGE_LEN`] is [`UpdateRefusal::Truncated`]. The board kind
    /// is the firmware's name; a version equal to the running one is admitted (the same
    /// release built again, or re-flashed).
    pub fn admits(&self, running: &Firmware, capacity: u32) -> Result<(), UpdateRefusal> {
        if self.image_len < MIN_IMAGE_LEN {
            return Err(UpdateRefusal::Truncated);
        }
        if self.image_len > capacity {
            return Err(UpdateRefusal::TooLarge {
                len: self.image_len,
                capacity,
            });
        }
        if self.firmware.name != running.name {
            return Err(UpdateRefusal::OtherBoard);
        }
        if self.firmware.version < running.version && !self.downgrade {
            return Err(UpdateRefusal::Downgrade);
        }
        Ok(())
    }
}

/// The next `N` bytes of `rest`, which then starts after them (zeros past its end: the
/// trailer's fields add up to its 32 bytes, so none is read there).
fn take<const N: usize>(rest: &mut &[u8]) -> [u8; N] {
    match rest.split_first_chunk::<N>() {
        Some((head, tail)) => {
            *rest = tail;
            *head
        }
        None => [0; N],
    }
}

/// A signed image in memory, split into its parts ([`SignedImage::parse`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SignedImage<'a> {
    /// The image and its trailer: the bytes the signature is over (through their digest).
    pub signed: &'a [u8],
    /// The trailer, read.
    pub trailer: Trailer,
    /// The signature.
    pub signature: &'a [u8; SIGNATURE_LEN],
}

impl<'a> SignedImage<'a> {
    /// Splits `bytes` into image, trailer and signature: at least a trailer and a signature,
    /// the trailer well formed, and its image length the bytes before it.
    pub fn parse(bytes: &'a [u8]) -> Result<SignedImage<'a>, UpdateRefusal> {
        let signed_len = bytes
            .len()
            .checked_sub(SIGNATURE_LEN)
            .ok_or(UpdateRefusal::Truncated)?;
        let (signed, signature) = bytes.split_at(signed_len);
        let image_len = signed_len
            .checked_sub(TRAILER_LEN)
            .ok_or(UpdateRefusal::Truncated)?;
        let trailer = signed
            .get(image_len..)
            .and_then(|trailer| <&[u8; TRAILER_LEN]>::try_from(trailer).ok())
            .ok_or(UpdateRefusal::Truncated)?;
        let signature =
            <&[u8; SIGNATURE_LEN]>::try_from(signature).map_err(|_| UpdateRefusal::Truncated)?;
        let trailer = Trailer::decode(trailer)?;
        if usize::try_from(trailer.image_len).ok() != Some(image_len) {
            return Err(UpdateRefusal::Truncated);
        }
        Ok(SignedImage {
            signed,
            trailer,
            signature,
        })
    }

    /// The image alone (what goes to the update partition before its trailer).
    pub fn image(&self) -> &'a [u8] {
        self.signed
            .get(..self.signed.len().saturating_sub(TRAILER_LEN))
            .unwrap_or(&[])
    }

    /// The image's trailer and signature checked for a node running `running` with an update
    /// partition of `capacity` bytes and the public key `public_key`: [`Trailer::admits`], then
    /// [`verify`] over the image's digest.
    #[cfg(feature = "signature")]
    pub fn check(
        &self,
        running: &Firmware,
        capacity: u32,
        public_key: &[u8; PUBLIC_KEY_LEN],
    ) -> Result<Trailer, UpdateRefusal> {
        self.trailer.admits(running, capacity)?;
        verify(&digest(self.signed), self.signature, public_key)?;
        Ok(self.trailer)
    }
}

/// SHA-512 of `bytes`: what the signature is over. A node that holds the image in flash hashes
/// it in chunks with [`Digest`] instead.
#[cfg(feature = "signature")]
pub fn digest(bytes: &[u8]) -> [u8; 64] {
    use sha2::Digest as _;
    sha2::Sha512::digest(bytes).into()
}

/// The hash a node feeds an image in flash to, chunk by chunk (`update`, then `finalize`).
#[cfg(feature = "signature")]
pub type Digest = sha2::Sha512;

/// Verifies `signature` over `digest` (the SHA-512 of image and trailer) under `public_key`.
/// A public key that is not a point of the curve, a signature not in canonical form, or one made
/// by another key are all [`UpdateRefusal::BadSignature`]. Strict verification
/// (`verify_strict`): no small-order key, no malleable signature.
#[cfg(feature = "signature")]
pub fn verify(
    digest: &[u8; 64],
    signature: &[u8; SIGNATURE_LEN],
    public_key: &[u8; PUBLIC_KEY_LEN],
) -> Result<(), UpdateRefusal> {
    let key = ed25519_dalek::VerifyingKey::from_bytes(public_key)
        .map_err(|_| UpdateRefusal::BadSignature)?;
    let signature = ed25519_dalek::Signature::from_bytes(signature);
    key.verify_strict(digest, &signature)
        .map_err(|_| UpdateRefusal::BadSignature)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn firmware(name: &str, version: &str) -> Firmware {
        Firmware::new(name, version, "0123456789abcdef")
    }

    fn trailer(name: &str, version: &str, downgrade: bool, image_len: u32) -> Trailer {
        Trailer {
            firmware: firmware(name, version),
            downgrade,
            image_len,
        }
    }

    #[test]
    fn the_trailer_reads_back_as_written_and_its_layout_is_the_documented_one() {
        let t = trailer("fw-g474", "1.2.3", true, 0x0001_2345);
        let bytes = t.encode();
        assert_eq!(
            bytes,
            [
                b'P', b'A', b'B', b'U', 1, 1, 0, 0, // magic, format, flags, reserved
                b'f', b'w', b'-', b'g', b'4', b'7', b'4', 0, // board kind
                1, 2, 3, 0, // version, reserved
                0x01, 0x23, 0x45, 0x67, 0x89, 0xab, 0xcd, 0xef, // build
                0x45, 0x23, 0x01, 0x00, // image length
            ]
        );
        assert_eq!(Trailer::decode(&bytes), Ok(t));
    }

    #[test]
    fn a_trailer_with_another_magic_format_or_reserved_bits_is_refused() {
        let good = trailer("fw-an386", "0.1.0", false, 10).encode();
        for (at, value) in [
            (0, b'X'),
            (4, 2),
            (5, 2),
            (5, 0x80),
            (6, 1),
            (7, 1),
            (19, 1),
        ] {
            let mut bad = good;
            bad[at] = value;
            assert_eq!(
                Trailer::decode(&bad),
                Err(UpdateRefusal::BadTrailer),
                "byte {at}"
            );
        }
    }

    #[test]
    fn admits_its_own_board_kind_at_a_version_not_lower_unless_signed_as_a_downgrade() {
        let running = firmware("fw-g474", "1.2.3");
        let ok = |t: Trailer| t.admits(&running, 1000);
        assert_eq!(ok(trailer("fw-g474", "1.2.3", false, 1000)), Ok(()));
        assert_eq!(ok(trailer("fw-g474", "1.3.0", false, 10)), Ok(()));
        assert_eq!(ok(trailer("fw-g474", "2.0.0", false, 10)), Ok(()));
        assert_eq!(
            ok(trailer("fw-g474", "1.2.2", false, 10)),
            Err(UpdateRefusal::Downgrade)
        );
        assert_eq!(
            ok(trailer("fw-g474", "0.9.9", false, 10)),
            Err(UpdateRefusal::Downgrade)
        );
        assert_eq!(ok(trailer("fw-g474", "0.9.9", true, 10)), Ok(()));
        assert_eq!(
            ok(trailer("fw-f446", "1.2.3", false, 10)),
            Err(UpdateRefusal::OtherBoard)
        );
        assert_eq!(
            ok(trailer("fw-g474", "1.2.3", false, 1001)),
            Err(UpdateRefusal::TooLarge {
                len: 1001,
                capacity: 1000
            })
        );
    }

    #[test]
    fn parse_splits_image_trailer_and_signature_and_refuses_a_length_that_disagrees() {
        let image = [7u8; 40];
        let mut bytes = image.to_vec();
        bytes.extend_from_slice(&trailer("fw-an386", "0.1.0", false, 40).encode());
        bytes.extend_from_slice(&[9u8; SIGNATURE_LEN]);
        let parsed = SignedImage::parse(&bytes).unwrap();
        assert_eq!(parsed.image(), &image);
        assert_eq!(parsed.signed.len(), 40 + TRAILER_LEN);
        assert_eq!(parsed.signature, &[9u8; SIGNATURE_LEN]);
        assert_eq!(parsed.trailer.image_len, 40);
        // A byte less or more anywhere before the trailer: the length disagrees.
        let mut shorter = bytes.clone();
        shorter.remove(0);
        assert_eq!(SignedImage::parse(&shorter), Err(UpdateRefusal::Truncated));
        let mut longer = bytes.clone();
        longer.insert(0, 0);
        assert_eq!(SignedImage::parse(&longer), Err(UpdateRefusal::Truncated));
        for len in 0..OVERHEAD {
            assert!(SignedImage::parse(&bytes[..len]).is_err(), "{len} bytes");
        }
    }

    #[test]
    fn every_refusal_has_its_own_code() {
        let all = [
            UpdateRefusal::Truncated,
            UpdateRefusal::BadTrailer,
            UpdateRefusal::TooLarge {
                len: 0,
                capacity: 0,
            },
            UpdateRefusal::OtherBoard,
            UpdateRefusal::Downgrade,
            UpdateRefusal::BadSignature,
        ];
        let codes: std::vec::Vec<u8> = all.iter().map(|r| r.code()).collect();
        assert_eq!(codes, [1, 2, 3, 4, 5, 6]);
    }
}
