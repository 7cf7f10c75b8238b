//! Key files: `pabctl keygen` writes them, `--key FILE` reads them, `pabctl keypage` turns one
//! into a board's key page image.
//!
//! A key file holds 32 hexadecimal characters (128 bits) and an optional trailing newline.
//! Whoever can read it can configure the node: `keygen` creates it readable by its owner only
//! (mode 0600) and never overwrites one, and a key file that its group or other users may read
//! is refused, as ssh refuses such a private key: a key that leaked is no key. So is a key of
//! zeros, the value a forgotten placeholder has.

use std::fs::OpenOptions;
use std::io::{Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

use pab_core::auth::{KEY_LEN, Key, page};

/// The largest key file read: 32 characters and a line end, with room for a comment-less
/// editor's habits; a larger file is not a key file.
const MAX_KEY_FILE: u64 = 256;

/// Reads a key file: a regular file of at most 256 bytes, readable by its owner only, holding a
/// key that is not all zeros. The error says the cause and what to do, without the path (the
/// caller's diagnostic names the file).
pub fn read(path: &Path) -> Result<Key, String> {
    let text = read_private(path, "key", "make a new key if someone may have read it")?;
    let key = Key::from_hex(&text).map_err(|error| format!("line 1: {error}"))?;
    if key == Key::from_bytes([0; KEY_LEN]) {
        return Err(
            "the key is all zeros, a placeholder rather than a secret: make one with `pabctl \
             keygen -o FILE`"
                .to_string(),
        );
    }
    Ok(key)
}

/// The text of a private file holding a `what` (a node key, a signing key): a regular file of
/// at most 256 bytes that only its owner may read, else an error that says so and then
/// `advice`. Shared by node keys and signing keys ([`crate::signing`]).
pub fn read_private(path: &Path, what: &str, advice: &str) -> Result<String, String> {
    use std::os::unix::fs::PermissionsExt;
    let file = format!("{what} file");
    pab_lang::input::regular_file(path, &file, MAX_KEY_FILE)
        .map_err(|diagnostic| diagnostic.message)?;
    let mode = std::fs::metadata(path)
        .map_err(|error| format!("cannot read the {file}: {error}"))?
        .permissions()
        .mode();
    if mode & 0o077 != 0 {
        return Err(format!(
            "mode {:04o} lets other users read the {what}: `chmod 600 {}` ({advice})",
            mode & 0o7777,
            path.display()
        ));
    }
    pab_lang::input::read_text(path, &file, MAX_KEY_FILE).map_err(|diagnostic| diagnostic.message)
}

/// `N` random bytes from the operating system's random source.
pub fn random<const N: usize>() -> Result<[u8; N], String> {
    let mut bytes = [0u8; N];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut random| random.read_exact(&mut bytes))
        .map_err(|error| format!("/dev/urandom: {error}"))?;
    Ok(bytes)
}

/// A new random key, from the operating system's random source.
pub fn generate() -> Result<Key, String> {
    random().map(Key::from_bytes)
}

/// Writes `key` to a new file at `path`, mode 0600; refuses to overwrite anything.
pub fn write_new(path: &Path, key: &Key) -> Result<(), String> {
    let mut text = key.to_hex().to_vec();
    text.push(b'\n');
    write_private(
        path,
        &text,
        "the nodes keyed with it would be locked out of configuration",
    )
}

/// Writes `text` to a new file at `path`, mode 0600, synced; refuses to overwrite anything, and
/// says why with `why` (what a new key in its place would break).
pub fn write_private(path: &Path, text: &[u8], why: &str) -> Result<(), String> {
    let mut file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)
        .map_err(|error| match error.kind() {
            std::io::ErrorKind::AlreadyExists => format!(
                "{}: exists; keygen never overwrites a key ({why}): choose another name or \
                 remove it first",
                path.display()
            ),
            _ => format!("{}: {error}", path.display()),
        })?;
    file.write_all(text)
        .and_then(|()| file.sync_all())
        .map_err(|error| format!("{}: {error}", path.display()))
}

/// The key page record of `key` (32 bytes: magic, format, key, CRC): what a board reads at its
/// key page's address (docs/keys.md).
pub fn page_image(key: &Key) -> [u8; page::LEN] {
    page::encode(key)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key_file(path: &Path, text: &[u8], mode: u32) {
        use std::os::unix::fs::PermissionsExt;
        std::fs::write(path, text).unwrap();
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
    }

    #[test]
    fn keygen_writes_a_private_file_once_and_it_reads_back() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("pab-keys-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("node.key");
        let _ = std::fs::remove_file(&path);
        let key = generate().unwrap();
        write_new(&path, &key).unwrap();
        assert_eq!(read(&path).unwrap(), key);
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        let again = write_new(&path, &generate().unwrap()).unwrap_err();
        assert!(again.contains("never overwrites"), "{again}");
        assert_eq!(read(&path).unwrap(), key, "the first key is kept");
        std::fs::write(&path, "xyz\n").unwrap();
        let error = read(&path).unwrap_err();
        assert!(error.contains("line 1: a key is 32 hexadecimal"), "{error}");
        // Readable by the group: refused, whatever the key.
        key_file(&path, &key.to_hex(), 0o640);
        let error = read(&path).unwrap_err();
        assert!(
            error.starts_with("mode 0640 lets other users read the key: `chmod 600"),
            "{error}"
        );
        key_file(&path, &[b'0'; 32], 0o600);
        let error = read(&path).unwrap_err();
        assert!(error.starts_with("the key is all zeros"), "{error}");
        // Not a file: refused before it is opened.
        let error = read(Path::new("/dev/zero")).unwrap_err();
        assert!(
            error.starts_with("a character device is not a regular file"),
            "{error}"
        );
        assert_ne!(generate().unwrap(), generate().unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
