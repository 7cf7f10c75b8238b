//! The Linux node's table store: one file, `DIR/table.pab`, replaced atomically (write a
//! temporary file, fsync it, rename it over the old one, fsync the directory), so that a crash or
//! a power cut leaves the old image or the new one, never a mix.

use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use pab_app::store::{StoreError, TableStore};
use pab_storage::FlashErrorKind;

/// The file name inside the store directory.
pub const FILE_NAME: &str = "table.pab";

/// Reads the boot table from `--table` (if given) or the store directory; writes pushed tables to
/// the store directory (if given).
pub struct FileStore {
    dir: Option<PathBuf>,
    boot_table: Option<PathBuf>,
}

impl FileStore {
    /// A store in `dir` (created if missing), booting from `boot_table` instead if given.
    pub fn new(dir: Option<PathBuf>, boot_table: Option<PathBuf>) -> io::Result<FileStore> {
        if let Some(dir) = &dir {
            fs::create_dir_all(dir).map_err(|error| {
                io::Error::new(
                    error.kind(),
                    format!("cannot create {}: {error}", dir.display()),
                )
            })?;
        }
        if let Some(table) = &boot_table {
            // Fail at start, not silently at boot, if the file is not there.
            fs::metadata(table).map_err(|error| {
                io::Error::new(
                    error.kind(),
                    format!("cannot read {}: {error}", table.display()),
                )
            })?;
        }
        Ok(FileStore { dir, boot_table })
    }

    fn stored_path(&self) -> Option<PathBuf> {
        self.dir.as_ref().map(|dir| dir.join(FILE_NAME))
    }
}

fn io_failure(what: &str, path: &Path, error: &io::Error) -> StoreError {
    log::error!("{what} {}: {error}", path.display());
    StoreError::Flash(FlashErrorKind::Other)
}

impl TableStore for FileStore {
    async fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        // --table wins once, at boot; later loads (none today) would read the store.
        let path = match self.boot_table.take() {
            Some(path) => path,
            None => match self.stored_path() {
                Some(path) => path,
                None => return Ok(None),
            },
        };
        let bytes = match fs::read(&path) {
            Ok(bytes) => bytes,
            Err(error) if error.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(error) => return Err(io_failure("cannot read", &path, &error)),
        };
        let capacity = buf.len();
        let Some(target) = buf.get_mut(..bytes.len()) else {
            log::error!(
                "{} has {} bytes, more than this node accepts ({})",
                path.display(),
                bytes.len(),
                capacity
            );
            return Err(StoreError::BufferTooSmall {
                needed: bytes.len(),
                got: capacity,
            });
        };
        target.copy_from_slice(&bytes);
        log::info!("read {} ({} bytes)", path.display(), bytes.len());
        Ok(Some(target))
    }

    async fn save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        let Some(path) = self.stored_path() else {
            log::warn!("no --store directory: the new table will be lost when the node stops");
            return Err(StoreError::Flash(FlashErrorKind::Other));
        };
        write_atomically(&path, image).map_err(|error| io_failure("cannot write", &path, &error))
    }
}

/// Replaces `path` with `bytes` so that readers see the old or the new content, also across a
/// crash.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let temporary = path.with_extension("pab.part");
    {
        let mut file = fs::File::create(&temporary)?;
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

    fn block_on<F: std::future::Future>(future: F) -> F::Output {
        futures::executor::block_on(future)
    }

    #[test]
    fn saves_then_loads_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileStore::new(Some(dir.path().join("node")), None).unwrap();
        let mut buf = [0u8; 64];
        assert_eq!(block_on(store.load(&mut buf)).unwrap(), None);
        block_on(store.save(b"PABT image bytes")).unwrap();
        block_on(store.save(b"PABT newer image")).unwrap();
        let mut store = FileStore::new(Some(dir.path().join("node")), None).unwrap();
        assert_eq!(
            block_on(store.load(&mut buf)).unwrap(),
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
        block_on(store.save(b"stored")).unwrap();
        let mut buf = [0u8; 16];
        assert_eq!(block_on(store.load(&mut buf)).unwrap(), Some(&b"boot"[..]));
        assert!(FileStore::new(None, Some(dir.path().join("missing.pab"))).is_err());
    }

    #[test]
    fn too_small_a_buffer_and_no_store_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = FileStore::new(Some(dir.path().to_path_buf()), None).unwrap();
        block_on(store.save(&[7; 32])).unwrap();
        let mut small = [0u8; 8];
        assert_eq!(
            block_on(store.load(&mut small)),
            Err(StoreError::BufferTooSmall { needed: 32, got: 8 })
        );
        let mut none = FileStore::new(None, None).unwrap();
        assert!(block_on(none.save(b"x")).is_err());
    }
}
