//! Key files and boot salts of the Linux processes (`pab-node --key`, `pab-intent --key`).

/// The key of `--key FILE`; the error names the file and the cause. As pabctl's key files
/// (host-tools/src/keys.rs): a regular file of at most 256 bytes, readable by its owner only
/// (a key others could read is no key), holding a key that is not all zeros (a placeholder).
pub fn read_key(path: &std::path::Path) -> anyhow::Result<pab_core::auth::Key> {
    use std::io::Read as _;
    use std::os::unix::fs::PermissionsExt as _;
    let fail = |cause: String| anyhow::anyhow!("{}: {cause}", path.display());
    let metadata = std::fs::metadata(path)
        .map_err(|error| fail(format!("cannot read the key file: {error}")))?;
    if !metadata.is_file() || metadata.len() > 256 {
        return Err(fail(
            "not a key file (a regular file of 32 hexadecimal characters)".to_string(),
        ));
    }
    let mode = metadata.permissions().mode();
    if mode & 0o077 != 0 {
        return Err(fail(format!(
            "mode {:04o} lets other users read the key: `chmod 600 {}`",
            mode & 0o7777,
            path.display()
        )));
    }
    let mut text = String::new();
    std::fs::File::open(path)
        .and_then(|file| file.take(256).read_to_string(&mut text))
        .map_err(|error| fail(format!("cannot read the key file: {error}")))?;
    let key =
        pab_core::auth::Key::from_hex(&text).map_err(|error| fail(format!("line 1: {error}")))?;
    if key == pab_core::auth::Key::from_bytes([0; pab_core::auth::KEY_LEN]) {
        return Err(fail(
            "the key is all zeros, a placeholder rather than a secret: make one with `pabctl keygen -o FILE`"
                .to_string(),
        ));
    }
    Ok(key)
}

/// 32 bits from the operating system's random source: the boot salt of the node's challenges
/// (and the epoch of its seals, and of `pab-intent`'s),
/// which must not repeat for one key. Random salts repeat by the birthday bound: some pair of
/// boots shares one with probability about n^2 / 2^33 after n restarts (1 % after 9 300), so a
/// node restarted that often should get a new key; boards count boots in flash instead.
pub fn boot_salt() -> anyhow::Result<u32> {
    use std::io::Read as _;
    let mut bytes = [0u8; 4];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut random| random.read_exact(&mut bytes))
        .map_err(|error| anyhow::anyhow!("/dev/urandom: {error}"))?;
    Ok(u32::from_le_bytes(bytes))
}
