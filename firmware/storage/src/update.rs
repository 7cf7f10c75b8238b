//! [`UpdateSlot`]: where a node writes a firmware update for its bootloader, chunk by chunk, and
//! asks for it (`pab_core::update::stored`: the image at the slot's start, the manifest in its
//! last 96 bytes, the request page's records); [`WithUpdate`]: a table store with one.
//!
//! **Erases as the image goes**: a write erases first every erase page whose first byte it
//! covers. The node's chunks come in order from offset 0 (`pab_core::update::session`), so every
//! page the image reaches is erased before its first byte is written, and the pages it does not
//! reach are left as they were (their bytes are no part of the image: the hash covers the image's
//! length only). After a swap or a revert the partition holds the other firmware: nothing needs
//! erasing ahead, and an update costs the erases of its own pages.
//!
//! **Power-fail safe by order**: the request record is written last, after the manifest, and the
//! bootloader acts only on a request: a cut anywhere before leaves no request, and the node runs
//! on as it was.

use embedded_storage::nor_flash::NorFlash;
use pab_core::update::stored::{self, Request, Verdict};
use pab_core::update::{MANIFEST_LEN, TRAILER_LEN, Trailer};

use crate::{FlashErrorKind, LayoutError, SaveProgress, StoreError, TableStore};

/// The update (DFU) partition's slot and the request page of a board.
pub struct UpdateSlot<D: NorFlash, R: NorFlash> {
    dfu: D,
    request: R,
    slot_len: u32,
}

fn flash<E: embedded_storage::nor_flash::NorFlashError>(error: E) -> StoreError {
    StoreError::Flash(FlashErrorKind::of(&error))
}

impl<D: NorFlash, R: NorFlash> UpdateSlot<D, R> {
    /// The slot: the first `slot_len` bytes of `dfu` (the active partition's length, a whole
    /// number of erase pages), and the request page `request` (its first erase page). Touches
    /// no flash.
    pub fn new(dfu: D, request: R, slot_len: u32) -> Result<Self, LayoutError> {
        let page = u32::try_from(D::ERASE_SIZE).map_err(|_| LayoutError::UnsupportedGeometry)?;
        if page == 0 || slot_len == 0 || !slot_len.is_multiple_of(page) {
            return Err(LayoutError::SlotSizeNotPageMultiple);
        }
        if usize::try_from(slot_len).map_or(true, |len| len > dfu.capacity())
            || request.capacity() < R::ERASE_SIZE
            || stored::manifest_offset(slot_len).is_none()
        {
            return Err(LayoutError::RangeOutOfBounds);
        }
        // The manifest and the records are whole double words, which every flash here writes.
        if D::WRITE_SIZE == 0
            || R::WRITE_SIZE == 0
            || !MANIFEST_LEN.is_multiple_of(D::WRITE_SIZE)
            || !8usize.is_multiple_of(R::WRITE_SIZE)
            || !8usize.is_multiple_of(D::WRITE_SIZE)
        {
            return Err(LayoutError::UnsupportedGeometry);
        }
        Ok(UpdateSlot {
            dfu,
            request,
            slot_len,
        })
    }

    /// The slot's length in bytes (the largest image is 96 less: `stored::capacity`).
    pub fn slot_len(&self) -> u32 {
        self.slot_len
    }

    /// Writes `data` at `offset` of the slot, having erased every erase page whose first byte
    /// the write covers. A last chunk whose length is not a whole number of write units is
    /// padded with 0xFF (erased bytes). Blocking: on the G474 a page's erase (22 ms typical) and
    /// a chunk's double words (82 µs each).
    pub fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), StoreError> {
        let len = u32::try_from(data.len())
            .map_err(|_| StoreError::Flash(FlashErrorKind::OutOfBounds))?;
        let end = offset
            .checked_add(len)
            .filter(|&end| end <= stored::capacity(self.slot_len))
            .ok_or(StoreError::Flash(FlashErrorKind::OutOfBounds))?;
        let page = D::ERASE_SIZE as u32;
        // The first page start at or after `offset`, then each one before `end`.
        let mut start = offset.div_ceil(page).saturating_mul(page);
        while start < end {
            let next = start.saturating_add(page);
            self.dfu.erase(start, next).map_err(flash)?;
            start = next;
        }
        // Not 0 and at most 8: `new` checked.
        let unit = D::WRITE_SIZE.max(1);
        let whole = data.len() - data.len() % unit;
        let (body, tail) = data.split_at(whole);
        if !body.is_empty() {
            self.dfu.write(offset, body).map_err(flash)?;
        }
        if !tail.is_empty() {
            let mut padded = [0xFFu8; 8];
            let last = padded
                .get_mut(..unit)
                .ok_or(StoreError::Flash(FlashErrorKind::NotAligned))?;
            last.get_mut(..tail.len())
                .ok_or(StoreError::Flash(FlashErrorKind::NotAligned))?
                .copy_from_slice(tail);
            let at = offset.saturating_add(whole as u32);
            self.dfu.write(at, last).map_err(flash)?;
        }
        Ok(())
    }

    /// Stores `manifest` in the slot's last 96 bytes and then the request record: the
    /// bootloader checks and swaps the image at the next reset. The manifest's page is erased
    /// first when it holds anything (an earlier update's manifest, another firmware: only when
    /// the image did not reach that page, whose erase would otherwise have cleared it).
    pub fn request(&mut self, manifest: &[u8; MANIFEST_LEN]) -> Result<(), StoreError> {
        let at = stored::manifest_offset(self.slot_len)
            .ok_or(StoreError::Flash(FlashErrorKind::OutOfBounds))?;
        let mut current = [0u8; MANIFEST_LEN];
        self.dfu.read(at, &mut current).map_err(flash)?;
        if current.iter().any(|&byte| byte != 0xFF) {
            let page = D::ERASE_SIZE as u32;
            let start = at - at % page;
            self.dfu
                .erase(start, start.saturating_add(page))
                .map_err(flash)?;
        }
        self.dfu.write(at, manifest).map_err(flash)?;
        self.request.erase(0, R::ERASE_SIZE as u32).map_err(flash)?;
        let trailer = manifest
            .get(..TRAILER_LEN)
            .ok_or(StoreError::Flash(FlashErrorKind::OutOfBounds))?;
        self.request
            .write(stored::TRAILER_OFFSET, trailer)
            .map_err(flash)?;
        self.request.write(0, &stored::REQUEST).map_err(flash)
    }

    /// The bootloader's verdict on the last request, once, with the trailer of what was asked
    /// for; the request page is then erased. `None`: no request decided. An accepted image need
    /// not be what runs (a reset between the verdict and the swap's mark, or a revert before the
    /// verdict was taken, leave the old firmware): compare the requested trailer with the
    /// running firmware.
    pub fn take_verdict(&mut self) -> Result<Option<Verdict>, StoreError> {
        let mut head = [0u8; 16];
        self.request.read(0, &mut head).map_err(flash)?;
        match Request::read(&head) {
            Request::Decided(outcome) => {
                let mut trailer = [0u8; TRAILER_LEN];
                self.request
                    .read(stored::TRAILER_OFFSET, &mut trailer)
                    .map_err(flash)?;
                self.request.erase(0, R::ERASE_SIZE as u32).map_err(flash)?;
                Ok(Some(Verdict {
                    outcome,
                    requested: Trailer::decode(&trailer).ok(),
                }))
            }
            Request::None | Request::Pending => Ok(None),
        }
    }
}

/// A table store `S` with an update slot: the store's own methods as they are, the update's
/// through the slot, and the firmware's confirmation through `confirm` (the board's
/// bootloader: embassy-boot's `mark_booted`).
pub struct WithUpdate<S, D: NorFlash, R: NorFlash> {
    /// The table store.
    pub store: S,
    slot: UpdateSlot<D, R>,
    confirm: fn() -> bool,
}

impl<S: TableStore, D: NorFlash, R: NorFlash> WithUpdate<S, D, R> {
    /// `store` with the update slot `slot`; `confirm` marks the running firmware booted for the
    /// bootloader, and says whether it could.
    pub fn new(store: S, slot: UpdateSlot<D, R>, confirm: fn() -> bool) -> Self {
        WithUpdate {
            store,
            slot,
            confirm,
        }
    }
}

impl<S: TableStore, D: NorFlash, R: NorFlash> TableStore for WithUpdate<S, D, R> {
    fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        self.store.load(buf)
    }

    fn start_save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        self.store.start_save(image)
    }

    fn continue_save(&mut self, image: &[u8]) -> Result<SaveProgress, StoreError> {
        self.store.continue_save(image)
    }

    fn load_settings(&mut self) -> Result<Option<u16>, StoreError> {
        self.store.load_settings()
    }

    fn save_settings(&mut self, record: u16) -> Result<bool, StoreError> {
        self.store.save_settings(record)
    }

    fn update_slot_len(&self) -> u32 {
        self.slot.slot_len()
    }

    fn write_update(&mut self, offset: u32, data: &[u8]) -> Result<(), StoreError> {
        self.slot.write(offset, data)
    }

    fn request_update(&mut self, manifest: &[u8; MANIFEST_LEN]) -> Result<(), StoreError> {
        self.slot.request(manifest)
    }

    fn take_update_verdict(&mut self) -> Result<Option<Verdict>, StoreError> {
        self.slot.take_verdict()
    }

    fn confirm_firmware(&mut self) -> bool {
        (self.confirm)()
    }
}
