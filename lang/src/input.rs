//! Files the tools read, checked before they are read: what kind of file, and how large.
//!
//! A path can name anything: `/dev/zero` never ends, a FIFO without a writer blocks whoever
//! opens it, a 5 GB file given by mistake fills the memory. So a file is looked at
//! (`std::fs::metadata`, which opens nothing and so cannot block) before it is opened: only a
//! regular file of at most the kind's size is read, and it is read through a bound, so that a
//! file growing between the look and the read is cut short rather than followed.

use std::io::Read;
use std::path::Path;

use crate::diagnostic::Diagnostic;

/// The largest network file read: 16 MiB, some hundred times the largest example, and far
/// more than a network within the nodes' capacities can need.
pub const MAX_NETWORK_BYTES: u64 = 16 << 20;
/// The largest capture read: 4 GiB, room for [`crate::candump::MAX_FRAMES`] lines of a long
/// interface name.
pub const MAX_CAPTURE_BYTES: u64 = 4 << 30;

/// Checks that `path` is a regular file of at most `max_bytes`, without opening it; `what` names
/// it in the errors ("network file", "capture"). Returns its size.
pub fn regular_file(path: &Path, what: &str, max_bytes: u64) -> Result<u64, Diagnostic> {
    let metadata = std::fs::metadata(path)
        .map_err(|error| Diagnostic::file(path, format!("cannot read: {error}")))?;
    if !metadata.is_file() {
        return Err(Diagnostic::file(
            path,
            format!(
                "{} is not a regular file: a {what} is read from a file ({})",
                kind(&metadata),
                match kind(&metadata) {
                    "a directory" => "give a file in it",
                    _ => "write it to a file first: a pipe or a device may never end",
                }
            ),
        ));
    }
    let size = metadata.len();
    if size > max_bytes {
        return Err(Diagnostic::file(
            path,
            format!(
                "{} is too large for a {what} (at most {})",
                bytes(size),
                bytes(max_bytes)
            ),
        ));
    }
    Ok(size)
}

/// Reads the text of a regular file of at most `max_bytes` ([`regular_file`]).
pub fn read_text(path: &Path, what: &str, max_bytes: u64) -> Result<String, Diagnostic> {
    regular_file(path, what, max_bytes)?;
    let file = std::fs::File::open(path)
        .map_err(|error| Diagnostic::file(path, format!("cannot read: {error}")))?;
    let mut bytes = Vec::new();
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|error| Diagnostic::file(path, format!("cannot read: {error}")))?;
    if bytes.len() as u64 > max_bytes {
        return Err(Diagnostic::file(
            path,
            format!(
                "grew beyond {} while it was read: a {what} must hold still",
                self::bytes(max_bytes)
            ),
        ));
    }
    String::from_utf8(bytes).map_err(|error| {
        Diagnostic::file(
            path,
            format!(
                "is not UTF-8 text (byte {} of the file): a {what} is text",
                error.utf8_error().valid_up_to()
            ),
        )
    })
}

/// "a FIFO", "a directory", ...: what a path that is not a regular file names.
fn kind(metadata: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let kind = metadata.file_type();
    if kind.is_dir() {
        "a directory"
    } else if kind.is_fifo() {
        "a FIFO (named pipe)"
    } else if kind.is_char_device() {
        "a character device"
    } else if kind.is_block_device() {
        "a block device"
    } else if kind.is_socket() {
        "a socket"
    } else {
        "not a file"
    }
}

/// A size for a person: bytes, KiB, MiB or GiB, one decimal above bytes.
fn bytes(size: u64) -> String {
    const UNITS: [&str; 3] = ["KiB", "MiB", "GiB"];
    if size < 1024 {
        return format!("{size} bytes");
    }
    let mut value = size as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", UNITS[unit])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_fifos_and_directories_are_refused_without_being_opened() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        // No writer: opening it would block forever; looking at it does not.
        for (path, kind) in [
            (fifo.as_path(), "a FIFO (named pipe) is not a regular file"),
            (
                Path::new("/dev/zero"),
                "a character device is not a regular file",
            ),
            (dir.path(), "a directory is not a regular file"),
        ] {
            let error = read_text(path, "network file", MAX_NETWORK_BYTES).unwrap_err();
            assert!(error.message.starts_with(kind), "{error}");
            assert!(
                error.message.contains("a network file is read from a file"),
                "{error}"
            );
        }
        let missing = read_text(&dir.path().join("nope"), "network file", 10).unwrap_err();
        assert!(missing.message.starts_with("cannot read:"), "{missing}");
    }

    #[test]
    fn a_file_above_its_kinds_limit_is_refused_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.toml");
        std::fs::write(&path, vec![b'#'; 3000]).unwrap();
        let error = read_text(&path, "network file", 2048).unwrap_err();
        assert_eq!(
            error.message,
            "2.9 KiB is too large for a network file (at most 2.0 KiB)"
        );
        assert_eq!(read_text(&path, "network file", 3000).unwrap().len(), 3000);
        std::fs::write(&path, [b'a', 0xFF, b'b']).unwrap();
        let error = read_text(&path, "network file", 10).unwrap_err();
        assert!(error.message.contains("not UTF-8 text (byte 1"), "{error}");
    }

    #[test]
    fn sizes_read_as_a_person_writes_them() {
        assert_eq!(bytes(0), "0 bytes");
        assert_eq!(bytes(1023), "1023 bytes");
        assert_eq!(bytes(16 << 20), "16.0 MiB");
        assert_eq!(bytes(5 << 30), "5.0 GiB");
    }
}
