//! Firmware signing: `pabctl keygen --signing` writes an Ed25519 signing key, `pabctl sign`
//! signs an image with it (pab-core's `update` module says the signed image's layout, and
//! checks it).
//!
//! A signing key file holds the key's 32-byte secret as 64 hexadecimal characters and an
//! optional newline, readable by its owner only (mode 0600), never overwritten, refused if its
//! group or other users may read it and if it is all zeros: as a node key file
//! ([`crate::keys`]), for the same reasons, and more so: whoever holds it can make every board
//! of a kind run their code.

use std::path::Path;

use ed25519_dalek::{Signer, SigningKey};
use pab_core::identity::Firmware;
use pab_core::update::{self, Trailer};

/// What `sign` writes into the trailer besides the length: the board kind (the firmware's
/// name), the version, the build id and the downgrade flag, checked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Signed {
    pub firmware: Firmware,
    pub downgrade: bool,
}

/// A board kind: 1 to 8 printable ASCII characters, as a firmware's identity states its name.
pub fn board_kind(text: &str) -> Result<[u8; 8], String> {
    if text.is_empty() || text.len() > 8 || !text.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(format!(
            "`{text}`: a board kind is the firmware's name, 1 to 8 printable ASCII characters \
             (fw-g474, fw-f446, fw-an386)"
        ));
    }
    let mut name = [0u8; 8];
    name.iter_mut()
        .zip(text.bytes())
        .for_each(|(slot, byte)| *slot = byte);
    Ok(name)
}

/// A semantic version MAJOR.MINOR.PATCH, each 0 to 255 (the identity's bytes).
pub fn version(text: &str) -> Result<[u8; 3], String> {
    let parts: Vec<&str> = text.split('.').collect();
    let [major, minor, patch] = parts.as_slice() else {
        return Err(format!(
            "`{text}`: a version is MAJOR.MINOR.PATCH (e.g. 1.2.0)"
        ));
    };
    let part = |p: &str| {
        p.parse::<u8>()
            .map_err(|_| format!("`{text}`: each part of a version is a number from 0 to 255"))
    };
    Ok([part(major)?, part(minor)?, part(patch)?])
}

/// A build id: 1 to 40 hexadecimal digits (a commit's hash or its start); the first 16 are
/// kept, as in the identity.
pub fn build_id(text: &str) -> Result<[u8; 8], String> {
    if text.is_empty() || text.len() > 40 || !text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!(
            "`{text}`: a build id is 1 to 40 hexadecimal digits (`git rev-parse HEAD`)"
        ));
    }
    Ok(Firmware::new("", "0.0.0", text).build)
}

/// Reads a signing key file (see the module).
pub fn read_key(path: &Path) -> Result<SigningKey, String> {
    let text = crate::keys::read_private(
        path,
        "signing key",
        "and make a new key, and give the boards its public key, if someone may have read it",
    )?;
    let hex = text.strip_suffix('\n').unwrap_or(&text);
    if hex.len() != 64 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!(
            "line 1: a signing key is 64 hexadecimal characters, found {} characters{}",
            hex.len(),
            if hex.len() == 32 {
                " (a node key? `pabctl keygen --signing` makes a signing key)"
            } else {
                ""
            }
        ));
    }
    let mut secret = [0u8; 32];
    for (byte, pair) in secret.iter_mut().zip(hex.as_bytes().chunks(2)) {
        let text = std::str::from_utf8(pair).map_err(|_| "line 1: not hexadecimal".to_string())?;
        *byte = u8::from_str_radix(text, 16).map_err(|_| "line 1: not hexadecimal".to_string())?;
    }
    if secret == [0; 32] {
        return Err(
            "the signing key is all zeros, a placeholder rather than a secret: make one with \
             `pabctl keygen --signing -o FILE`"
                .to_string(),
        );
    }
    Ok(SigningKey::from_bytes(&secret))
}

/// A new signing key from the operating system's random source.
pub fn generate() -> Result<SigningKey, String> {
    crate::keys::random().map(|secret| SigningKey::from_bytes(&secret))
}

/// Writes `key` to a new file at `path`, mode 0600; refuses to overwrite anything.
pub fn write_new(path: &Path, key: &SigningKey) -> Result<(), String> {
    let mut text = hex(&key.to_bytes());
    text.push('\n');
    crate::keys::write_private(
        path,
        text.as_bytes(),
        "the boards that hold its public key would take no image signed by a new one",
    )
}

/// An update public key (what `pabctl keygen --signing` prints): 64 hexadecimal digits, given
/// as they are or in a file whose first line they are. Refuses a key that is not a point of the
/// curve (no board could check an image with it).
pub fn public_key(text_or_file: &str) -> Result<[u8; update::PUBLIC_KEY_LEN], String> {
    let text = if text_or_file.len() == 2 * update::PUBLIC_KEY_LEN
        && text_or_file.bytes().all(|b| b.is_ascii_hexdigit())
    {
        text_or_file.to_string()
    } else {
        let read = std::fs::read_to_string(text_or_file).map_err(|error| {
            format!(
                "{text_or_file}: neither 64 hexadecimal digits (the public key `pabctl keygen \
                 --signing` prints) nor a file that holds them: {error}"
            )
        })?;
        read.lines().next().unwrap_or("").trim().to_string()
    };
    let mut key = [0u8; update::PUBLIC_KEY_LEN];
    if text.len() != 2 * key.len() {
        return Err(format!(
            "{text_or_file}: a public key is 64 hexadecimal digits, not {} characters",
            text.len()
        ));
    }
    for (byte, pair) in key.iter_mut().zip(text.as_bytes().chunks(2)) {
        let pair = std::str::from_utf8(pair).map_err(|_| "not ASCII".to_string())?;
        *byte = u8::from_str_radix(pair, 16)
            .map_err(|_| format!("{text_or_file}: {pair:?} is not hexadecimal"))?;
    }
    ed25519_dalek::VerifyingKey::from_bytes(&key)
        .map_err(|_| format!("{text_or_file}: not an Ed25519 public key"))?;
    Ok(key)
}

/// Lower-case hexadecimal.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|byte| format!("{byte:02x}")).collect()
}

/// `image` signed by `key` as `signed` says: the image, its trailer, the signature of the
/// SHA-512 digest of both (pab-core's `update` module). Fails for an image longer than 4 GiB, or
/// shorter than a vector table's first two words (no board would take it).
pub fn sign(key: &SigningKey, image: &[u8], signed: Signed) -> Result<Vec<u8>, String> {
    let image_len = u32::try_from(image.len())
        .map_err(|_| format!("the image is {} bytes: at most 4 GiB", image.len()))?;
    if image_len < update::MIN_IMAGE_LEN {
        return Err(format!(
            "the image is {image_len} bytes: a firmware starts with its vector table, at least {} bytes",
            update::MIN_IMAGE_LEN
        ));
    }
    let trailer = Trailer {
        firmware: signed.firmware,
        downgrade: signed.downgrade,
        image_len,
    };
    let mut bytes = Vec::with_capacity(image.len() + update::OVERHEAD);
    bytes.extend_from_slice(image);
    bytes.extend_from_slice(&trailer.encode());
    let signature = key.sign(&update::digest(&bytes));
    bytes.extend_from_slice(&signature.to_bytes());
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pab_core::update::{SignedImage, UpdateRefusal};

    #[test]
    fn a_signed_image_verifies_under_its_public_key_only() {
        let key = SigningKey::from_bytes(&[5; 32]);
        let firmware = Firmware::new("fw-an386", "0.2.0", "abcdef");
        let bytes = sign(
            &key,
            &[1, 2, 3, 4, 5, 6, 7, 8],
            Signed {
                firmware,
                downgrade: false,
            },
        )
        .unwrap();
        let parsed = SignedImage::parse(&bytes).unwrap();
        assert_eq!(parsed.image(), &[1, 2, 3, 4, 5, 6, 7, 8]);
        assert!(
            sign(
                &key,
                &[0; 7],
                Signed {
                    firmware,
                    downgrade: false
                }
            )
            .is_err()
        );
        let running = Firmware::new("fw-an386", "0.1.0", "0");
        let public = key.verifying_key().to_bytes();
        assert_eq!(
            parsed.check(&running, 1000, &public).unwrap().firmware,
            firmware
        );
        let other = SigningKey::from_bytes(&[6; 32]).verifying_key().to_bytes();
        assert_eq!(
            parsed.check(&running, 1000, &other),
            Err(UpdateRefusal::BadSignature)
        );
    }

    #[test]
    fn the_arguments_are_read_and_bad_ones_say_what_they_must_be() {
        assert_eq!(board_kind("fw-g474").unwrap(), *b"fw-g474\0");
        assert!(board_kind("").is_err() && board_kind("nucleo-g474re").is_err());
        assert_eq!(version("1.2.255").unwrap(), [1, 2, 255]);
        for bad in ["1.2", "1.2.3.4", "1.2.256", "a.b.c", "", "1..2"] {
            assert!(version(bad).is_err(), "{bad}");
        }
        assert_eq!(
            build_id("0123456789abcdef0123").unwrap(),
            [0x01, 0x23, 0x45, 0x67, 0x89, 0xab, 0xcd, 0xef]
        );
        assert!(build_id("xyz").is_err() && build_id("").is_err());
    }

    #[test]
    fn keygen_writes_a_private_file_once_and_it_reads_back() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("release.sign");
        let key = generate().unwrap();
        write_new(&path, &key).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        assert_eq!(read_key(&path).unwrap().to_bytes(), key.to_bytes());
        assert!(
            write_new(&path, &key)
                .unwrap_err()
                .contains("never overwrites")
        );
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        assert!(read_key(&path).unwrap_err().contains("chmod 600"));
        let node_key = dir.path().join("node.key");
        std::fs::write(&node_key, "00112233445566778899aabbccddeeff\n").unwrap();
        std::fs::set_permissions(&node_key, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert!(read_key(&node_key).unwrap_err().contains("a node key?"));
        let zeros = dir.path().join("zeros.sign");
        std::fs::write(&zeros, "0".repeat(64)).unwrap();
        std::fs::set_permissions(&zeros, std::fs::Permissions::from_mode(0o600)).unwrap();
        assert!(read_key(&zeros).unwrap_err().contains("all zeros"));
    }
}
