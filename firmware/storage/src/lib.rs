//! # pab-storage: table images in a board's flash, safe against power loss
//!
//! A node receives table images (bytes, at most [`pab_core::image::MAX_IMAGE_LEN`]) over CAN and
//! must boot with the latest one it accepted. [`TableStore`] is what the firmware needs;
//! [`FlashStore`] implements it over any `embedded_storage_async` [`NorFlash`], for instance a
//! board's internal flash.
//!
//! ## The guarantee
//!
//! - After [`TableStore::save`] returned `Ok`, every later [`TableStore::load`] (after any number
//!   of power losses) returns exactly the saved bytes, until the next successful `save`.
//! - If power is lost at any point during a `save` (or the save fails), the next `load` returns
//!   exactly the previous image or exactly the new one; never a mixture, never a truncation.
//! - `load` never returns bytes whose CRC-32 differs from the one recorded at commit time: if
//!   the newest committed copy was damaged afterwards (a flipped bit), it returns the previous
//!   committed image, which the store keeps intact; if both are damaged, [`StoreError::Corrupt`].
//! - Whatever the flash holds (erased, garbage, another program's data), `load` and `save` answer
//!   with a value or a typed [`StoreError`]; nothing panics (no `unsafe`, no indexing, no
//!   unwrapping: enforced by lints).
//!
//! The image format is not this crate's business: it stores bytes. The firmware checks what
//! `load` returns with [`pab_core::image::load`] before using it.
//!
//! ## Layout and algorithm
//!
//! The range given to [`FlashStore::new`] is split into:
//!
//! ```text
//! | slot 0 (slot_size) | slot 1 (slot_size) | commit log (the rest, >= 2 erase pages) |
//! ```
//!
//! The **commit log** is a `sequential-storage` map with one key per slot; the value is a commit
//! record `{format, sequence number, length, CRC-32 of the image}` (13 bytes). The map keeps, for
//! each slot, the newest record written for it, and `sequential-storage` makes each record write
//! atomic across power loss (CRC-protected items, repaired on the next access) and spreads its
//! page erases over the log's pages (it appends, and erases a page only when it wraps around).
//!
//! `save(image)`:
//!
//! 1. Find the *current* image: the record with the highest sequence number whose slot matches
//!    its length and CRC, else the other record if it matches (exactly what `load` returns).
//! 2. Write into the **other** slot: erase only the pages the image needs, program it in 256-byte
//!    chunks aligned to the flash's write size (the last word padded with 0xFF), read it back and
//!    compare ([`StoreError::VerifyFailed`] otherwise).
//! 3. Append the record `{sequence = highest + 1, length, CRC}` for that slot to the log. This
//!    single small write is the commit point: before it, `load` still finds the current image
//!    (the target slot's old record no longer matches its half-written contents, so it is
//!    skipped); after it, `load` finds the new one.
//!
//! `load(buf)`: read both records; try them newest first; for each, read the slot into `buf`,
//! compute the CRC of exactly those bytes and return them if it matches. So `load` **falls back to
//! the previous commit** when the newest one does not verify.
//!
//! Choices that differ from a plain A/B scheme, and why:
//!
//! - The target of a save is the slot *not holding the image `load` returns* (step 1), rather
//!   than the slot not referenced by the newest record. When the newest copy has been damaged and
//!   `load` falls back to the older one, overwriting that older one (the only good copy) would
//!   leave nothing to boot if power were lost during the save.
//! - A save erases only the pages its image occupies (`ceil(len / page)`), not the whole slot: a
//!   typical image (a few hundred bytes) costs one page erase per save, and the slots can be sized
//!   for the largest image without making small saves slower or wear the flash more.
//! - The commit record lives in the log, not in the slot: the slot is plain image bytes, and the
//!   atomic, wear-levelled append of `sequential-storage` is used exactly where it helps (small,
//!   frequent records).
//!
//! Wear: every save erases the first `ceil(len / page)` pages of one slot, alternating between the
//! slots, so each slot page is erased once every two saves of images that reach it; the log adds
//! about one erase per `(page - 16) / 24` saves (170 records per 4 KiB page with 8-byte words),
//! spread evenly over its pages. With the STM32G4's 10 000 guaranteed erase cycles per page, that
//! is at least 20 000 saves, far more than a robot's table pushes.
//!
//! ## Recommended layout on the STM32G474 (512 KiB, single bank: 4 KiB pages, 8-byte words)
//!
//! The firmware must leave the range out of the linker's `FLASH` region (a `memory.x` whose
//! `FLASH` length stops at the range's start) so that no code lands there.
//!
//! - **40 KiB** (`0x7_6000..0x8_0000`, offsets from the flash base `0x0800_0000`): slots of
//!   16 KiB (4 pages) at `0x7_6000` and `0x7_A000`, log of 8 KiB (2 pages) at `0x7_E000`:
//!   `FlashStore::new(flash, 0x7_6000..0x8_0000, 16 * 1024)`. Holds images up to 16 KiB: every
//!   example network (the largest node image is 177 bytes) and about half a node's capacity.
//! - **64 KiB** (`0x7_0000..0x8_0000`): slots of 28 KiB (7 pages), log of 8 KiB. Holds a node at
//!   full capacity (26 745 bytes).
//! - **72 KiB** (`0x6_E000..0x8_0000`): slots of 32 KiB, log of 8 KiB. Holds any image the format
//!   allows ([`pab_core::image::MAX_IMAGE_LEN`]).
//!
//! embassy-stm32's flash driver for the G4 is blocking; wrap it in
//! `embassy_embedded_hal::adapter::BlockingAsync` to get the async [`NorFlash`] this store takes.
//! One hardware caveat that no test here can model: the G4's flash has ECC, and reading a double
//! word whose programming was cut by a power loss can raise a double-ECC error (an NMI). The
//! board's NMI handler must clear `ECCD` for addresses inside the store's range and let the read
//! fail (the CRC then rejects the slot) instead of halting.
//!
//! ## Testing
//!
//! The `mem-flash` feature adds [`testing::MemFlash`], an in-memory NOR flash that enforces NOR
//! semantics, counts erases per page and simulates a power loss in the middle of any program or
//! erase call. The crate's tests cut the power at every operation of a save, from many log states,
//! reboot, and check that `load` returns exactly the old or the new image.

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::panic,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo,
        clippy::unimplemented
    )
)]

mod error;
#[cfg(feature = "mem-flash")]
pub mod testing;

pub use error::{FlashErrorKind, LayoutError, LogErrorKind, StoreError};

use core::ops::Range;

use embedded_storage_async::nor_flash::NorFlash;
use pab_core::crc32::Crc32;
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage, SerializationError, Value};

/// Where a node keeps its latest accepted table image.
///
/// Async functions in a public trait: callers use it through static dispatch (a generic or a
/// concrete type), as embassy tasks do; no `Send` bound is needed on a single-core executor.
#[allow(async_fn_in_trait)]
pub trait TableStore {
    /// Reads the latest committed image into `buf`; `Ok(None)` if none was ever committed.
    async fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError>;
    /// Stores `image` so the next `load` (also after a power loss at any point of this call once it
    /// returned `Ok`) returns it.
    async fn save(&mut self, image: &[u8]) -> Result<(), StoreError>;
}

/// Bytes moved per flash read or write: the stack buffer of `load` and `save`.
const CHUNK: usize = 256;
/// Bytes of a serialized commit record.
const RECORD_LEN: usize = 13;
/// The commit record format this crate writes.
const RECORD_FORMAT: u8 = 1;
/// The log's work buffer: key and record, rounded up to the largest word `sequential-storage`
/// supports (32 bytes).
const LOG_BUFFER: usize = 64;

/// A commit: slot `key` holds `len` bytes whose CRC-32 is `crc`, committed as number `sequence`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Record {
    sequence: u32,
    len: u32,
    crc: u32,
}

impl<'a> Value<'a> for Record {
    fn serialize_into(&self, buffer: &mut [u8]) -> Result<usize, SerializationError> {
        let out = buffer
            .get_mut(..RECORD_LEN)
            .ok_or(SerializationError::BufferTooSmall)?;
        let [s0, s1, s2, s3] = self.sequence.to_le_bytes();
        let [l0, l1, l2, l3] = self.len.to_le_bytes();
        let [c0, c1, c2, c3] = self.crc.to_le_bytes();
        out.copy_from_slice(&[
            RECORD_FORMAT,
            s0,
            s1,
            s2,
            s3,
            l0,
            l1,
            l2,
            l3,
            c0,
            c1,
            c2,
            c3,
        ]);
        Ok(RECORD_LEN)
    }

    fn deserialize_from(buffer: &'a [u8]) -> Result<(Self, usize), SerializationError> {
        let bytes: [u8; RECORD_LEN] = buffer
            .get(..RECORD_LEN)
            .and_then(|bytes| bytes.try_into().ok())
            .ok_or(SerializationError::BufferTooSmall)?;
        let [format, s0, s1, s2, s3, l0, l1, l2, l3, c0, c1, c2, c3] = bytes;
        if format != RECORD_FORMAT {
            return Err(SerializationError::InvalidFormat);
        }
        Ok((
            Record {
                sequence: u32::from_le_bytes([s0, s1, s2, s3]),
                len: u32::from_le_bytes([l0, l1, l2, l3]),
                crc: u32::from_le_bytes([c0, c1, c2, c3]),
            },
            RECORD_LEN,
        ))
    }
}

/// The two slots' records, newest first.
#[derive(Clone, Copy, Debug, Default)]
struct Commits {
    /// `(slot, record)` pairs, newest first.
    ordered: [Option<(u8, Record)>; 2],
}

impl Commits {
    fn new(slot0: Option<Record>, slot1: Option<Record>) -> Self {
        let ordered = match (slot0, slot1) {
            (Some(a), Some(b)) if b.sequence > a.sequence => [Some((1, b)), Some((0, a))],
            (Some(a), Some(b)) => [Some((0, a)), Some((1, b))],
            (Some(a), None) => [Some((0, a)), None],
            (None, Some(b)) => [Some((1, b)), None],
            (None, None) => [None, None],
        };
        Commits { ordered }
    }

    fn iter(&self) -> impl Iterator<Item = (u8, Record)> + '_ {
        self.ordered.iter().flatten().copied()
    }

    fn highest_sequence(&self) -> Option<u32> {
        self.iter().map(|(_, record)| record.sequence).max()
    }
}

/// A [`TableStore`] in a range of NOR flash: two image slots and a commit log (see the crate
/// documentation for the layout, the algorithm and the guarantees).
pub struct FlashStore<F: NorFlash> {
    log: MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>,
    slots: [u32; 2],
    slot_size: u32,
}

impl<F: NorFlash> FlashStore<F> {
    /// A store in `range` of `flash` (offsets as the driver counts them), with two slots of
    /// `slot_size` bytes at its start and the commit log in the rest.
    ///
    /// `range` must start and end on erase-page boundaries and lie inside the flash; `slot_size`
    /// must be a positive whole number of erase pages; at least two pages must remain for the log.
    /// Touches no flash: a new store over an erased range simply has nothing committed yet.
    pub fn new(flash: F, range: Range<u32>, slot_size: u32) -> Result<Self, StoreError> {
        let page = u32::try_from(F::ERASE_SIZE)
            .map_err(|_| StoreError::Layout(LayoutError::UnsupportedGeometry))?;
        let geometry_ok = F::ERASE_SIZE > 0
            && F::WRITE_SIZE > 0
            && F::READ_SIZE > 0
            && CHUNK.is_multiple_of(F::WRITE_SIZE)
            && CHUNK.is_multiple_of(F::READ_SIZE)
            && F::ERASE_SIZE.is_multiple_of(F::WRITE_SIZE)
            && F::ERASE_SIZE.is_multiple_of(F::READ_SIZE);
        if !geometry_ok {
            return Err(StoreError::Layout(LayoutError::UnsupportedGeometry));
        }
        let capacity = u32::try_from(flash.capacity()).unwrap_or(u32::MAX);
        if range.start >= range.end || range.end > capacity {
            return Err(StoreError::Layout(LayoutError::RangeOutOfBounds));
        }
        if !range.start.is_multiple_of(page) || !range.end.is_multiple_of(page) {
            return Err(StoreError::Layout(LayoutError::RangeNotPageAligned));
        }
        if slot_size == 0 || !slot_size.is_multiple_of(page) {
            return Err(StoreError::Layout(LayoutError::SlotSizeNotPageMultiple));
        }
        let log_start = slot_size
            .checked_mul(2)
            .and_then(|slots| range.start.checked_add(slots))
            .ok_or(StoreError::Layout(LayoutError::RangeTooSmall))?;
        let log_pages = range.end.saturating_sub(log_start) / page;
        if log_start >= range.end || log_pages < 2 {
            return Err(StoreError::Layout(LayoutError::RangeTooSmall));
        }
        let config = MapConfig::<F>::try_new(log_start..range.end)
            .map_err(|_| StoreError::Layout(LayoutError::LogRefused))?;
        Ok(FlashStore {
            log: MapStorage::new(flash, config, Cache::new_uncached()),
            // log_start did not overflow, so neither does this.
            slots: [range.start, range.start.saturating_add(slot_size)],
            slot_size,
        })
    }

    /// The largest image a slot holds, in bytes.
    pub fn slot_size(&self) -> u32 {
        self.slot_size
    }

    /// The flash, for inspection (tests, diagnostics). Writing to the store's range through it
    /// voids the guarantees.
    pub fn flash_mut(&mut self) -> &mut F {
        self.log.flash()
    }

    /// Erases the whole range (both slots and the log): the store then holds nothing and the next
    /// `load` returns `Ok(None)`. For a range that held something else before (a `load` that
    /// answers [`StoreError::Log`]`(`[`LogErrorKind::Corrupted`]`)`), or to forget the table.
    pub async fn format(&mut self) -> Result<(), StoreError> {
        self.log.erase_all().await?;
        let end = self.slots[1].saturating_add(self.slot_size);
        self.log
            .flash()
            .erase(self.slots[0], end)
            .await
            .map_err(|e| StoreError::Flash(FlashErrorKind::of(&e)))
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.log.destroy().0
    }

    fn slot_start(&self, slot: u8) -> u32 {
        if slot == 0 {
            self.slots[0]
        } else {
            self.slots[1]
        }
    }

    async fn commits(&mut self) -> Result<Commits, StoreError> {
        let mut buffer = [0u8; LOG_BUFFER];
        let slot0 = self.log.fetch_item::<Record>(&mut buffer, &0).await?;
        let slot1 = self.log.fetch_item::<Record>(&mut buffer, &1).await?;
        Ok(Commits::new(slot0, slot1))
    }

    /// Reads `out.len()` bytes of the slot starting at `start` (`out` no longer than the slot).
    async fn read_slot(&mut self, start: u32, out: &mut [u8]) -> Result<(), StoreError> {
        let mut chunk = [0u8; CHUNK];
        let mut address = start;
        for piece in out.chunks_mut(CHUNK) {
            // Reads whole READ_SIZE units; the slot is a multiple of them, so this stays inside.
            let aligned = piece.len().next_multiple_of(F::READ_SIZE);
            let area = chunk
                .get_mut(..aligned)
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            self.log
                .flash()
                .read(address, area)
                .await
                .map_err(|e| StoreError::Flash(FlashErrorKind::of(&e)))?;
            let bytes = area
                .get(..piece.len())
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            piece.copy_from_slice(bytes);
            address = address.saturating_add(CHUNK as u32);
        }
        Ok(())
    }

    /// True if the slot holds `record.len` bytes with CRC `record.crc`. Streams the slot through
    /// a chunk buffer (no caller buffer needed).
    async fn verifies(&mut self, slot: u8, record: Record) -> Result<bool, StoreError> {
        if record.len > self.slot_size {
            return Ok(false);
        }
        let start = self.slot_start(slot);
        let mut chunk = [0u8; CHUNK];
        let mut crc = Crc32::new();
        let mut done = 0u32;
        while done < record.len {
            let len = (record.len - done).min(CHUNK as u32) as usize;
            let piece = chunk
                .get_mut(..len)
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            self.read_slot(start.saturating_add(done), piece).await?;
            crc = crc.update(piece);
            done = done.saturating_add(CHUNK as u32);
        }
        Ok(crc.finish() == record.crc)
    }

    /// Erases the pages `len` bytes of the slot need, programs `image` and reads it back.
    async fn write_slot(&mut self, slot: u8, image: &[u8]) -> Result<(), StoreError> {
        let start = self.slot_start(slot);
        let flash_error = |e: F::Error| StoreError::Flash(FlashErrorKind::of(&e));
        // `image.len() <= slot_size`, checked by the caller, so these fit in u32.
        let len = u32::try_from(image.len()).map_err(|_| StoreError::ImageTooLarge {
            len: image.len(),
            slot_size: self.slot_size,
        })?;
        let erase_len = len.next_multiple_of(F::ERASE_SIZE as u32);
        if erase_len > 0 {
            self.log
                .flash()
                .erase(start, start.saturating_add(erase_len))
                .await
                .map_err(flash_error)?;
        }
        let mut chunk = [0xFFu8; CHUNK];
        let mut address = start;
        for piece in image.chunks(CHUNK) {
            let padded = piece.len().next_multiple_of(F::WRITE_SIZE);
            let area = chunk
                .get_mut(..padded)
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            area.fill(0xFF);
            let (data, _) = area.split_at_mut(piece.len());
            data.copy_from_slice(piece);
            self.log
                .flash()
                .write(address, area)
                .await
                .map_err(flash_error)?;
            address = address.saturating_add(CHUNK as u32);
        }
        let mut address = start;
        for piece in image.chunks(CHUNK) {
            let area = chunk
                .get_mut(..piece.len())
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            self.read_slot(address, area).await?;
            if area != piece {
                return Err(StoreError::VerifyFailed);
            }
            address = address.saturating_add(CHUNK as u32);
        }
        Ok(())
    }
}

impl<F: NorFlash> TableStore for FlashStore<F> {
    async fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        let commits = self.commits().await?;
        let mut any = false;
        for (slot, record) in commits.iter() {
            any = true;
            if record.len > self.slot_size {
                continue;
            }
            let len = record.len as usize;
            let got = buf.len();
            let Some(area) = buf.get_mut(..len) else {
                return Err(StoreError::BufferTooSmall { needed: len, got });
            };
            self.read_slot(self.slot_start(slot), area).await?;
            if Crc32::new().update(area).finish() == record.crc {
                return Ok(buf.get(..len));
            }
        }
        if any {
            Err(StoreError::Corrupt)
        } else {
            Ok(None)
        }
    }

    async fn save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        let too_large = StoreError::ImageTooLarge {
            len: image.len(),
            slot_size: self.slot_size,
        };
        let len = u32::try_from(image.len()).map_err(|_| too_large)?;
        if len > self.slot_size {
            return Err(too_large);
        }
        let commits = self.commits().await?;
        let mut current = None;
        for (slot, record) in commits.iter() {
            if self.verifies(slot, record).await? {
                current = Some(slot);
                break;
            }
        }
        // The slot not holding what `load` returns now; with nothing loadable, the slot the newest
        // record does not reference (or slot 0).
        let target = match current {
            Some(slot) => slot ^ 1,
            None => commits
                .ordered
                .first()
                .copied()
                .flatten()
                .map_or(0, |(slot, _)| slot ^ 1),
        };
        let sequence = commits
            .highest_sequence()
            .map_or(1, |highest| highest.saturating_add(1));
        self.write_slot(target, image).await?;
        let record = Record {
            sequence,
            len,
            crc: Crc32::new().update(image).finish(),
        };
        let mut buffer = [0u8; LOG_BUFFER];
        self.log.store_item(&mut buffer, &target, &record).await?;
        Ok(())
    }
}
