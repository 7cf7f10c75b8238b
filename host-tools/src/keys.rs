//! Key files: `pabctl keygen` writes them, `--key FILE` reads them, `pabctl keypage` turns one
//! into a board's key page image.
//!
//! A key file holds 32 hexadecimal characters (128 bits) and an optional trailing newline.
//! Whoever can read it can configure the node: `keygen` creates it readable by its owner only
//! (mode 0600) and never overwrites one.

use std::fs::OpenOptions;
use std::io::{Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

use pab_core::auth::{KEY_LEN, Key, page};

/// Reads a key file. The error names the file and the cause.
pub fn read(path: &Path) -> Result<Key, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|error| format!("{}: cannot read the key file: {error}", path.display()))?;
    Key::from_hex(&text).map_err(|error| format!("{}:1: {error}", path.display()))
}

/// A new random key, from the operating system's random source.
pub fn generate() -> Result<Key, String> {
    let mut bytes = [0u8; KEY_LEN];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut random| random.read_exact(&mut bytes))
        .map_err(|error| format!("/dev/urandom: {error}"))?;
    Ok(Key::from_bytes(bytes))
}

/// Writes `key` to a new file at `path`, mode 0600; refuses to overwrite anything.
pub fn write_new(path: &Path, key: &Key) -> Result<(), String> {
    let mut file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)
        .map_err(|error| match error.kind() {
            std::io::ErrorKind::AlreadyExists => format!(
                "{}: exists; keygen never overwrites a key (the nodes keyed with it would be \
                 locked out of configuration): choose another name or remove it first",
                path.display()
            ),
            _ => format!("{}: {error}", path.display()),
        })?;
    let mut text = key.to_hex().to_vec();
    text.push(b'\n');
    file.write_all(&text)
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
        assert!(
            error.contains("node.key:1: a key is 32 hexadecimal"),
            "{error}"
        );
        assert_ne!(generate().unwrap(), generate().unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
