//! The Linux node's table store: one file, `DIR/table.pab`, replaced atomically (write a
//! temporary file, fsync it, rename it over the old one, fsync the directory), so that a crash or
//! a power cut leaves the old image or the new one, never a mix.
//!
//! Reading is as careful as writing: the node must send its first heartbeat whatever sits at the
//! image's path. Anything but a regular file of at most the image limit (a FIFO that would block
//! the open or the read, a symlink to `/dev/zero` that never ends, a directory, a 200 MB file) is
//! refused before a byte is read, naming the path; the node then starts without a table and says
//! why on the bus (a `BadStoredTable` fault, see `pab_app::Node::boot_unreadable`).

use std::fmt;
use std::fs;
use std::io::{self, Read, Write};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use pab_app::store::{SaveProgress, StoreError, TableStore};
use pab_core::image::MAX_IMAGE_LEN;
use pab_storage::FlashErrorKind;

/// The file name inside the store directory.
pub const FILE_NAME: &str = "table.pab";
/// The node's configuration record (`pab_app::Settings`: node id, set over the bus), 2 bytes
/// little endian, replaced atomically like the table.
pub const SETTINGS_FILE: &str = "settings.bin";
/// The node's unique id: 16 hexadecimal digits and a newline, made once from the OS's random
/// source (what `pabctl nodes` lists and `pabctl assign --uid` names).
pub const UID_FILE: &str = "uid";

/// Reads the boot table from `--table` (if given) or the store directory; writes pushed tables to
/// the store directory (if given).
pub struct FileStore {
    dir: Option<PathBuf>,
    /// The `--table` image, read whole at start so that a bad one stops the process there.
    boot_image: Option<Vec<u8>>,
    /// A save written by `start_save` whose `continue_save` has not reported it yet.
    written: bool,
}

/// The node's unique id: read from `DIR/uid`, or made from the OS's random source (and written
/// there, once) when the file does not exist; without a directory, new at every start. 64 random
/// bits in the first 8 bytes of the 12 an identity carries.
pub fn node_uid(dir: Option<&Path>) -> io::Result<[u8; pab_core::identity::UID_LEN]> {
    let mut uid = [0u8; pab_core::identity::UID_LEN];
    let path = dir.map(|dir| dir.join(UID_FILE));
    if let Some(path) = &path {
        match fs::read_to_string(path) {
            Ok(text) => {
                let text = text.trim();
                let parsed = (text.len() == 16)
                    .then(|| u64::from_str_radix(text, 16).ok())
                    .flatten();
                return match parsed {
                    Some(value) => {
                        uid[..8].copy_from_slice(&value.to_be_bytes());
                        Ok(uid)
                    }
                    None => Err(io::Error::other(format!(
                        "{}: not a uid (16 hexadecimal digits); remove it to make a new one",
                        path.display()
                    ))),
                };
            }
            Err(error) if error.kind() == io::ErrorKind::NotFound => {}
            Err(error) => {
                return Err(io::Error::new(
                    error.kind(),
                    format!("{}: {error}", path.display()),
                ));
            }
        }
    }
    let mut random = [0u8; 8];
    fs::File::open("/dev/urandom").and_then(|mut source| source.read_exact(&mut random))?;
    uid[..8].copy_from_slice(&random);
    if let Some(path) = &path {
        let text = format!("{:016x}\n", u64::from_be_bytes(random));
        write_atomically(path, text.as_bytes()).map_err(|error| {
            io::Error::new(error.kind(), format!("{}: {error}", path.display()))
        })?;
        log::info!(
            "new uid {:016x} in {}",
            u64::from_be_bytes(random),
            path.display()
        );
    }
    Ok(uid)
}

/// Why an image file was not read.
#[derive(Debug)]
#[non_exhaustive]
pub enum ReadError {
    /// Nothing at the path.
    NotFound(PathBuf),
    /// Something other than a regular file (after following symlinks): what it is.
    NotRegular(PathBuf, &'static str),
    /// A regular file larger than the image limit.
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its size in bytes (at least `limit + 1` if it grew while being read).
        len: u64,
        /// The largest image taken.
        limit: usize,
    },
    /// The path could not be inspected, opened or read (permissions, I/O).
    Io(PathBuf, io::Error),
}

impl fmt::Display for ReadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReadError::NotFound(path) => write!(f, "{}: no such file", path.display()),
            ReadError::NotRegular(path, kind) => write!(
                f,
                "{}: {kind}, not a regular file; a table image must be a regular file",
                path.display()
            ),
            ReadError::TooLarge { path, len, limit } => write!(
                f,
                "{}: {len} bytes, more than the {limit}-byte image limit",
                path.display()
            ),
            ReadError::Io(path, error) => write!(f, "{}: cannot read: {error}", path.display()),
        }
    }
}

impl std::error::Error for ReadError {}

impl ReadError {
    /// The store error the node reports for it (`None`: nothing stored).
    fn to_store_error(&self) -> Option<StoreError> {
        match self {
            ReadError::NotFound(_) => None,
            ReadError::TooLarge { len, limit, .. } => Some(StoreError::BufferTooSmall {
                needed: usize::try_from(*len).unwrap_or(usize::MAX),
                got: *limit,
            }),
            ReadError::NotRegular(..) | ReadError::Io(..) => {
                Some(StoreError::Flash(FlashErrorKind::Other))
            }
        }
    }
}

/// What a non-regular file is, in words.
fn kind_of(file_type: fs::FileType) -> &'static str {
    if file_type.is_dir() {
        "a directory"
    } else if file_type.is_fifo() {
        "a FIFO (named pipe)"
    } else if file_type.is_char_device() {
        "a character device"
    } else if file_type.is_block_device() {
        "a block device"
    } else if file_type.is_socket() {
        "a socket"
    } else {
        "not a file"
    }
}

/// Reads the image file at `path` into `buf` and returns the bytes read, if `path` is (or links
/// to) a regular file of at most `buf.len()` bytes. Never blocks on a FIFO and never reads more
/// than `buf.len() + 1` bytes: the type and size are checked before opening, again on the opened
/// descriptor (the path may have changed in between), and the read stops one byte past the
/// limit.
pub fn read_image<'b>(path: &Path, buf: &'b mut [u8]) -> Result<&'b [u8], ReadError> {
    let limit = buf.len();
    let io_error = |error: io::Error| match error.kind() {
        io::ErrorKind::NotFound => ReadError::NotFound(path.to_path_buf()),
        _ => ReadError::Io(path.to_path_buf(), error),
    };
    let check = |metadata: &fs::Metadata| {
        if !metadata.file_type().is_file() {
            return Err(ReadError::NotRegular(
                path.to_path_buf(),
                kind_of(metadata.file_type()),
            ));
        }
        if metadata.len() > limit as u64 {
            return Err(ReadError::TooLarge {
                path: path.to_path_buf(),
                len: metadata.len(),
                limit,
            });
        }
        Ok(())
    };
    // Before opening: opening a device can have effects of its own.
    check(&fs::metadata(path).map_err(io_error)?)?;
    // O_NONBLOCK: should the path have become a FIFO meanwhile, the open returns at once.
    let mut file = fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
        .map_err(io_error)?;
    check(&file.metadata().map_err(io_error)?)?;
    let mut len = 0;
    while let Some(rest) = buf.get_mut(len..).filter(|rest| !rest.is_empty()) {
        match file.read(rest) {
            Ok(0) => break,
            Ok(read) => len += read,
            Err(error) if error.kind() == io::ErrorKind::Interrupted => {}
            Err(error) => return Err(io_error(error)),
        }
    }
    // A file that grew past the limit since it was checked.
    let mut one = [0u8; 1];
    if len == limit && matches!(file.read(&mut one), Ok(1)) {
        return Err(ReadError::TooLarge {
            path: path.to_path_buf(),
            len: limit as u64 + 1,
            limit,
        });
    }
    Ok(buf.get(..len).unwrap_or(&[]))
}

impl FileStore {
    /// A store in `dir` (created if missing), booting from `boot_table` instead if given. The
    /// boot table is read here, whole: a missing file, one that is not a regular file or one
    /// larger than an image can be is an error now, not a node without a table later.
    pub fn new(dir: Option<PathBuf>, boot_table: Option<PathBuf>) -> io::Result<FileStore> {
        if let Some(dir) = &dir {
            fs::create_dir_all(dir).map_err(|error| {
                io::Error::new(
                    error.kind(),
                    format!("cannot create {}: {error}", dir.display()),
                )
            })?;
        }
        let boot_image = match &boot_table {
            Some(table) => {
                let mut buf = vec![0u8; MAX_IMAGE_LEN];
                let len = read_image(table, &mut buf)
                    .map_err(|error| io::Error::other(format!("--table {error}")))?
                    .len();
                buf.truncate(len);
                Some(buf)
            }
            None => None,
        };
        Ok(FileStore {
            dir,
            boot_image,
            written: false,
        })
    }

    fn stored_path(&self) -> Option<PathBuf> {
        self.dir.as_ref().map(|dir| dir.join(FILE_NAME))
    }

    fn settings_path(&self) -> Option<PathBuf> {
        self.dir.as_ref().map(|dir| dir.join(SETTINGS_FILE))
    }
}

fn io_failure(what: &str, path: &Path, error: &io::Error) -> StoreError {
    log::error!("{what} {}: {error}", path.display());
    StoreError::Flash(FlashErrorKind::Other)
}

impl TableStore for FileStore {
    fn load_settings(&mut self) -> Result<Option<u16>, StoreError> {
        let Some(path) = self.settings_path() else {
            return Ok(None);
        };
        match fs::read(&path) {
            Ok(bytes) => match <[u8; 2]>::try_from(bytes.as_slice()) {
                Ok(record) => Ok(Some(u16::from_le_bytes(record))),
                Err(_) => {
                    log::error!("{}: not a settings record (2 bytes)", path.display());
                    Err(StoreError::Corrupt)
                }
            },
            Err(error) if error.kind() == io::ErrorKind::NotFound => Ok(None),
            Err(error) => Err(io_failure("cannot read", &path, &error)),
        }
    }

    fn save_settings(&mut self, record: u16) -> Result<bool, StoreError> {
        let Some(path) = self.settings_path() else {
            log::warn!("no --store directory: the new setting is lost when the node stops");
            return Ok(false);
        };
        write_atomically(&path, &record.to_le_bytes())
            .map_err(|error| io_failure("cannot write", &path, &error))?;
        Ok(true)
    }

    fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        // --table wins once, at boot; later loads (none today) would read the store.
        if let Some(image) = self.boot_image.take() {
            let capacity = buf.len();
            let Some(target) = buf.get_mut(..image.len()) else {
                log::error!(
                    "the --table image has {} bytes, more than this node accepts ({capacity})",
                    image.len()
                );
                return Err(StoreError::BufferTooSmall {
                    needed: image.len(),
                    got: capacity,
                });
            };
            target.copy_from_slice(&image);
            log::info!("booting with the --table image ({} bytes)", image.len());
            return Ok(Some(target));
        }
        let Some(path) = self.stored_path() else {
            return Ok(None);
        };
        match read_image(&path, buf) {
            Ok(bytes) => {
                log::info!("read {} ({} bytes)", path.display(), bytes.len());
                Ok(Some(bytes))
            }
            Err(error) => match error.to_store_error() {
                None => Ok(None),
                Some(store_error) => {
                    log::error!("cannot use the stored table: {error}");
                    Err(store_error)
                }
            },
        }
    }

    /// Writes the file at once (a file's write and rename take a fraction of a millisecond, not a
    /// flash erase's tens): the one step of `continue_save` only reports it.
    fn start_save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        self.written = false;
        let Some(path) = self.stored_path() else {
            log::warn!("no --store directory: the new table will be lost when the node stops");
            return Err(StoreError::Flash(FlashErrorKind::Other));
        };
        write_atomically(&path, image)
            .map_err(|error| io_failure("cannot write", &path, &error))?;
        self.written = true;
        Ok(())
    }

    fn continue_save(&mut self, _image: &[u8]) -> Result<SaveProgress, StoreError> {
        if core::mem::take(&mut self.written) {
            Ok(SaveProgress::Done)
        } else {
            Err(StoreError::NoSave)
        }
    }
}

/// Replaces `path` with `bytes` so that readers see the old or the new content, also across a
/// crash.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let temporary = path.with_extension("pab.part");
    {
        // A fresh file: whatever a crash (or someone) left at the temporary path, a FIFO
        // included, is removed rather than opened.
        match fs::remove_file(&temporary) {
            Err(error) if error.kind() != io::ErrorKind::NotFound => return Err(error),
            _ => {}
        }
        let mut file = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()?;
    }
    fs::rename(&temporary, path)?;
    if let Some(dir) = path.parent() {
        // The rename is durable once the directory entry is.
        fs::File::open(dir)?.sync_all()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;
    use std::os::unix::process::CommandExt;
    use std::sync::mpsc;
    use std::time::Duration;

    /// Runs `f` on a thread and fails if it takes more than 10 s: a regression that blocks on a
    /// FIFO or reads `/dev/zero` fails the test instead of hanging it.
    fn within_10_s<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        let (done, result) = mpsc::channel();
        std::thread::spawn(move || {
            let _ = done.send(f());
        });
        result
            .recv_timeout(Duration::from_secs(10))
            .expect("the store did not answer within 10 s")
    }

    /// Loads from a store directory whose `table.pab` `make` creates; returns the result and
    /// whether the node would start without a table.
    fn load_with(make: impl FnOnce(&Path)) -> Result<Option<Vec<u8>>, StoreError> {
        let dir = tempfile::tempdir().unwrap();
        make(&dir.path().join(FILE_NAME));
        let path = dir.path().to_path_buf();
        within_10_s(move || {
            let mut store = FileStore::new(Some(path), None).unwrap();
            let mut buf = vec![0u8; MAX_IMAGE_LEN];
            store.load(&mut buf).map(|found| found.map(<[u8]>::to_vec))
        })
    }

    #[test]
    fn saves_then_loads_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileStore::new(Some(dir.path().join("node")), None).unwrap();
        let mut buf = [0u8; 64];
        assert_eq!(store.load(&mut buf).unwrap(), None);
        store.save(b"PABT image bytes").unwrap();
        store.save(b"PABT newer image").unwrap();
        let mut store = FileStore::new(Some(dir.path().join("node")), None).unwrap();
        assert_eq!(
            store.load(&mut buf).unwrap(),
            Some(&b"PABT newer image"[..])
        );
        assert!(!dir.path().join("node").join("table.pab.part").exists());
    }

    #[test]
    fn boot_table_wins_and_missing_files_are_reported_at_start() {
        let dir = tempfile::tempdir().unwrap();
        let boot = dir.path().join("boot.pab");
        fs::write(&boot, b"boot").unwrap();
        let mut store = FileStore::new(Some(dir.path().join("s")), Some(boot)).unwrap();
        store.save(b"stored").unwrap();
        let mut buf = [0u8; 16];
        assert_eq!(store.load(&mut buf).unwrap(), Some(&b"boot"[..]));
        let missing = FileStore::new(None, Some(dir.path().join("missing.pab")))
            .err()
            .unwrap();
        assert!(missing.to_string().contains("missing.pab"), "{missing}");
    }

    #[test]
    fn too_small_a_buffer_and_no_store_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileStore::new(Some(dir.path().to_path_buf()), None).unwrap();
        store.save(&[7; 32]).unwrap();
        let mut small = [0u8; 8];
        assert_eq!(
            store.load(&mut small),
            Err(StoreError::BufferTooSmall { needed: 32, got: 8 })
        );
        let mut none = FileStore::new(None, None).unwrap();
        assert!(none.save(b"x").is_err());
    }

    fn mkfifo(path: &Path) {
        let status = std::process::Command::new("mkfifo")
            .arg(path)
            .status()
            .expect("mkfifo runs");
        assert!(status.success());
    }

    #[test]
    fn a_fifo_is_refused_without_blocking() {
        let result = load_with(mkfifo);
        assert_eq!(result, Err(StoreError::Flash(FlashErrorKind::Other)));
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo.pab");
        mkfifo(&fifo);
        let error = within_10_s(move || read_image(&fifo, &mut [0u8; 64]).unwrap_err());
        let text = error.to_string();
        assert!(text.contains("fifo.pab: a FIFO"), "{text}");
    }

    #[test]
    fn a_symlink_to_dev_zero_is_refused_without_reading() {
        let result = load_with(|path| std::os::unix::fs::symlink("/dev/zero", path).unwrap());
        assert_eq!(result, Err(StoreError::Flash(FlashErrorKind::Other)));
        let error = read_image(Path::new("/dev/zero"), &mut [0u8; 64]).unwrap_err();
        assert_eq!(
            error.to_string(),
            "/dev/zero: a character device, not a regular file; a table image must be a regular file"
        );
    }

    #[test]
    fn a_file_over_the_limit_is_refused_before_it_is_read() {
        // 64 GiB, sparse: reading it whole would not end within the test's 10 s (nor fit in
        // memory).
        let huge = 64 << 30;
        let result = load_with(move |path| fs::File::create(path).unwrap().set_len(huge).unwrap());
        assert_eq!(
            result,
            Err(StoreError::BufferTooSmall {
                needed: huge as usize,
                got: MAX_IMAGE_LEN
            })
        );
        // One byte over is over.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.pab");
        fs::write(&path, vec![1u8; MAX_IMAGE_LEN + 1]).unwrap();
        let error = read_image(&path, &mut vec![0u8; MAX_IMAGE_LEN]).unwrap_err();
        assert!(
            error
                .to_string()
                .ends_with("big.pab: 32769 bytes, more than the 32768-byte image limit"),
            "{error}"
        );
        // Exactly the limit is fine.
        fs::write(&path, vec![1u8; MAX_IMAGE_LEN]).unwrap();
        let mut buf = vec![0u8; MAX_IMAGE_LEN];
        assert_eq!(read_image(&path, &mut buf).unwrap().len(), MAX_IMAGE_LEN);
    }

    #[test]
    fn a_directory_is_refused() {
        let result = load_with(|path| fs::create_dir(path).unwrap());
        assert_eq!(result, Err(StoreError::Flash(FlashErrorKind::Other)));
        let dir = tempfile::tempdir().unwrap();
        let error = read_image(dir.path(), &mut [0u8; 64]).unwrap_err();
        assert!(error.to_string().contains("a directory"), "{error}");
    }

    #[test]
    fn bad_boot_tables_stop_the_start() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo.pab");
        mkfifo(&fifo);
        let big = dir.path().join("big.pab");
        fs::File::create(&big).unwrap().set_len(200 << 20).unwrap();
        for (path, expected) in [
            (fifo, "a FIFO (named pipe), not a regular file"),
            (big, "209715200 bytes, more than the 32768-byte image limit"),
            (dir.path().to_path_buf(), "a directory, not a regular file"),
        ] {
            let shown = path.display().to_string();
            let error =
                within_10_s(move || FileStore::new(None, Some(path)).err().unwrap().to_string());
            assert!(
                error.starts_with(&format!("--table {shown}: {expected}")),
                "{error}"
            );
        }
    }

    /// Set by the parent test to the store directory the child (another user) must fail to read.
    const CHILD_STORE: &str = "PAB_TEST_UNREADABLE_STORE";

    #[test]
    fn an_unreadable_file_is_an_error_not_an_empty_store() {
        if let Some(dir) = std::env::var_os(CHILD_STORE) {
            // The child, running as a user who may not read the file.
            let mut store = FileStore::new(Some(PathBuf::from(dir)), None).unwrap();
            let mut buf = vec![0u8; MAX_IMAGE_LEN];
            let result = store.load(&mut buf).map(|found| found.is_some());
            assert_eq!(result, Err(StoreError::Flash(FlashErrorKind::Other)));
            println!("refused as uid {}", effective_uid());
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("store");
        fs::create_dir(&store).unwrap();
        fs::write(store.join(FILE_NAME), b"PABT secret").unwrap();
        fs::set_permissions(store.join(FILE_NAME), fs::Permissions::from_mode(0o000)).unwrap();
        if effective_uid() != 0 {
            let mut store = FileStore::new(Some(store), None).unwrap();
            let mut buf = vec![0u8; MAX_IMAGE_LEN];
            assert_eq!(
                store.load(&mut buf),
                Err(StoreError::Flash(FlashErrorKind::Other))
            );
            return;
        }
        // Root reads every file whatever its mode: run this test again as `nobody` (65534) in
        // a child process, on a path it may traverse but a file it may not read.
        for path in [dir.path(), store.as_path()] {
            fs::set_permissions(path, fs::Permissions::from_mode(0o755)).unwrap();
        }
        let output = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "file_store::tests::an_unreadable_file_is_an_error_not_an_empty_store",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(CHILD_STORE, &store)
            .uid(65534)
            .gid(65534)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&output.stdout);
        assert!(
            output.status.success() && stdout.contains("refused as uid 65534"),
            "child: {}\n{stdout}\n{}",
            output.status,
            String::from_utf8_lossy(&output.stderr)
        );
    }

    /// The effective user id, from /proc (no `unsafe` for `geteuid`).
    fn effective_uid() -> u32 {
        let status = fs::read_to_string("/proc/self/status").unwrap();
        status
            .lines()
            .find_map(|line| line.strip_prefix("Uid:"))
            .and_then(|ids| ids.split_whitespace().nth(1))
            .and_then(|euid| euid.parse().ok())
            .unwrap()
    }
}
