//! # pab-storage: table images in a board's flash, safe against power loss
//!
//! A node receives table images (bytes, at most [`pab_core::image::MAX_IMAGE_LEN`]) over CAN and
//! must boot with the latest one it accepted. [`TableStore`] is what the firmware needs;
//! [`FlashStore`] implements it over any `embedded_storage` [`NorFlash`], for instance a board's
//! internal flash.
//!
//! A save runs in steps ([`TableStore::start_save`], then [`TableStore::continue_save`]), each
//! bounded: the start or the check of one page erase, or the programming and read-back of one
//! [`SAVE_CHUNK`]. A node reads its frames between the steps. On a flash that erases in the
//! background ([`BackgroundErase`]: the G474 in dual-bank mode erasing the bank the code does not
//! run from), no step waits for an erase; [`Blocking`] makes any [`NorFlash`] a store's flash
//! whose erases complete within their step. The steps are plain functions, not `async fn`: every
//! `async fn` that can return carries a "resumed after completion" state that panics, which the
//! compiler cannot prove unreachable, and the boards' firmware would link a panic call site per
//! async fn of this crate (`scripts/panic-check.sh` fails on them).
//!
//! ## The guarantee
//!
//! - After [`TableStore::save`] returned `Ok`, every later [`TableStore::load`] (after any number
//!   of power losses) returns exactly the saved bytes, until the next successful `save`.
//! - If power is lost at any point during a `save` (or the save fails), the next `load` returns
//!   exactly the previous image or exactly the new one; never a mixture, never a truncation,
//!   never nothing.
//! - `load` never returns bytes whose CRC-32 differs from the one recorded at commit time: if
//!   the newest committed copy was damaged afterwards (a flipped bit), it returns the newest
//!   older copy that still verifies; if no committed copy verifies, [`StoreError::Corrupt`].
//! - Whatever the flash holds (erased, garbage, another program's data), `load` and `save` answer
//!   with a value or a typed [`StoreError`]; nothing panics (no `unsafe`, no indexing, no
//!   unwrapping: enforced by lints).
//!
//! The crate also holds a keyed board's [`BootCounter`] ([`boot_counter`]): a count of boots in
//! its own flash pages that never returns a value twice across power cuts, the source of the
//! boot salt of a keyed node's challenges.
//!
//! The image format is not this crate's business: it stores bytes. The firmware checks what
//! `load` returns with [`pab_core::image::load`] before using it.
//!
//! ## Layout: a ring of self-describing slots
//!
//! The range given to [`FlashStore::new`] is divided into K = `range.len() / slot_size` ≥ 2
//! equal slots, each a whole number of erase pages. A slot starts with a header, then holds the
//! image:
//!
//! ```text
//! | slot 0                      | slot 1                      | ... | slot K-1 |
//! | header | image | (unused)   | header | image | (unused)   |
//! ```
//!
//! The header (24 bytes, little endian; it occupies the first 24 bytes rounded up to the flash's
//! write size, so on the STM32G4 exactly three double words) holds: magic `PABS`, format (u16,
//! 1), reserved (u16, 0), **sequence number** (u32), **image length** (u32), **CRC-32 of the
//! image** (u32), and the CRC-32 of the 20 bytes before it (all CRCs are
//! [`pab_core::crc32`]). A slot is *committed* when its header verifies and its length fits the
//! slot; it is *valid* when, moreover, its image matches the image CRC.
//!
//! `save(image)` (step 1 and 2 are `start_save`; each erase, each chunk and the commit a step of
//! `continue_save`):
//!
//! 1. Read every header. The new sequence number is the highest committed one plus one. The
//!    *current* slot is the valid slot with the highest sequence number (what `load` returns).
//! 2. The target is the slot after the current one in ring order (after the newest committed
//!    one if nothing is valid, slot 0 on an empty range). With K ≥ 2 it is never the current
//!    slot, so the image `load` returns now is never touched.
//! 3. Erase only the target's pages that header and image occupy (`ceil((24 + len) / page)`),
//!    one page at a time, first page first, which invalidates the target's old header.
//! 4. Program the image after the header area, in [`SAVE_CHUNK`]-byte chunks (the last word
//!    padded with 0xFF), reading each back ([`StoreError::VerifyFailed`] if it differs).
//! 5. Program the header, read it back. **This write is the commit**: before it completes, the
//!    target has no header that verifies (erased, or cut mid-write: the header CRC, stored in
//!    its last word, fails) and `load` returns the current image; after it, the target is the
//!    newest valid slot and `load` returns the new image.
//!
//! `load(buf)`: read every header; try the committed slots from the highest sequence number
//! down; return the first whose image matches its CRC. No committed slot at all (an erased
//! range, garbage, a first save cut before its commit) gives `Ok(None)`; committed slots none of
//! which verifies give [`StoreError::Corrupt`] (the flash was altered behind the store's back:
//! power loss alone never does that, since a save never touches the current slot). Ties of
//! sequence numbers (only possible in planted data) are broken by the higher slot index.
//!
//! Sequence numbers are plain `u32`, compared as numbers (no wrap-around): after 4 294 967 295
//! saves a store answers [`StoreError::SequenceExhausted`] until it is formatted. The flash wears
//! out five orders of magnitude earlier, so in practice only a planted header reaches it.
//!
//! ### Why the header is at the start of the slot
//!
//! The header is written last in program order whatever its place; its place decides the erases.
//! At the start, a save erases only the pages `24 + len` bytes need: a small image costs one
//! page erase, and the page that holds the old header is erased first, so a slot never carries a
//! header over image bytes that are being rewritten. At the end of the slot, every save would
//! also erase the slot's last page, doubling the erases of small images. `load` reads K small
//! headers at fixed places, and a slot describes itself: no other area of flash (no log, no
//! index) has to be consistent with it.
//!
//! ### NOR flash rules, and the STM32G4
//!
//! The G4 programs double words (8 bytes), refuses to program a double word that is not erased
//! (unless with all zeros), and keeps an ECC per double word. The store programs every double
//! word of a slot at most once between two erases (image, padding and header never share a
//! word: the header area is a whole number of words and the image starts after it), so it never
//! asks for a refused program. A cut program leaves a *partially programmed* word, a cut erase
//! a *partially erased* page; either way the bytes are garbage to the store: a cut image write
//! comes before the header exists, and a cut header write leaves a header whose CRC fails, so
//! the slot is skipped (a pseudo-random pattern passing a CRC-32 has a chance of 2^-32, and the
//! image CRC must also pass).
//!
//! **Board-level concern, not handled here.** On the G4, *reading* a double word whose
//! programming or erase was cut can hit a double ECC error: the flash sets `ECCD` in
//! `FLASH_ECCR` and raises an NMI (RM0440, "Error code correction"). `load` and `save` read
//! every slot's header, so after a cut header write or a cut erase the next boot reads such a
//! word (image words are read only behind a header that verifies, that is, after a complete
//! image write). The store cannot catch
//! this: it happens below `NorFlash::read`. The board crate must make that read survive: check
//! whether its HAL's flash driver handles flash ECC errors; if not, install an NMI handler that,
//! when `ECCD` is set and the failing address (`FLASH_ECCR.ADDR_ECC`) lies inside the store's
//! range, clears `ECCD` and returns, so the read completes with unreliable bytes that the
//! header or image CRC then rejects (any other NMI: halt as before). Without it a board can hang
//! at boot after a power cut during a save. `MemFlash` reads cut words without fault, so the
//! tests here cover the store's logic, not this handler; it must be tested on the board (cut
//! power during saves, or program a word twice to provoke ECCD).
//!
//! ## Wear
//!
//! Each save erases `ceil((24 + len) / page)` pages of one slot, and the slots take turns, so
//! each page is erased at most once every K saves. On the G474 layout below (K = 5, 4 KiB
//! pages), an image up to 4 072 bytes costs one page erase per save and an image up to 8 168
//! bytes two; either way each page is erased once per 5 saves: with the G4's 10 000 guaranteed
//! cycles, at least 50 000 saves. Measured (`tests/wear.rs`): 1 000 saves of small images erase
//! the first page of each of the 5 slots 200 times and nothing else.
//!
//! ## Recommended layout on the STM32G474 (512 KiB, single bank: 4 KiB pages, 8-byte words)
//!
//! The firmware must leave the range out of the linker's `FLASH` region (a `memory.x` whose
//! `FLASH` length stops at the range's start) so that no code lands there.
//!
//! - **40 KiB, 5 slots of 8 KiB** (`0x7_6000..0x8_0000`, offsets from the flash base
//!   `0x0800_0000`): `FlashStore::new(flash, 0x7_6000..0x8_0000, 8 * 1024)`. Holds images up to
//!   8 168 bytes ([`FlashStore::capacity`]): the board's images (a few KiB at most; the largest
//!   example node image is 177 bytes); 50 000 saves at least.
//! - If a board must store images of a full 8 KiB receive buffer (8 192 bytes, 24 more than an
//!   8 KiB slot holds): **48 KiB, 4 slots of 12 KiB** (`0x7_4000..0x8_0000`), 12 264 bytes per
//!   image, 40 000 saves at least.
//! - Any image the format allows ([`pab_core::image::MAX_IMAGE_LEN`], 32 KiB): slots of 36 KiB,
//!   at least two (72 KiB); three (108 KiB) if the flash can spare it.
//!
//! More slots only add endurance (and a few header reads at boot); two slots are enough for the
//! guarantee.
//!
//! embassy-stm32's blocking flash driver for the G4 (`Flash::new_blocking`) is a [`NorFlash`]
//! as it is: `FlashStore::new(Blocking(Flash::new_blocking(p.FLASH)), range, slot_size)` saves
//! with erases that stop the caller; the NUCLEO-G474RE's firmware erases in the background
//! instead (its `flash` module).
//!
//! ## Testing
//!
//! The `mem-flash` feature adds `testing::MemFlash`, an in-memory NOR flash that enforces the
//! G4's rules, counts erases per page and simulates a power loss in the middle of any program or
//! erase call (partially programmed words, partially erased pages). The crate's tests cut the
//! power at every program and erase call of a save, after every save of histories of hundreds
//! of saves (the ring wraps many times), reboot, and check that `load` returns exactly the old
//! or the new image and that the store goes on working.

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

mod background;
pub mod boot_counter;
mod error;
pub mod settings;
#[cfg(feature = "mem-flash")]
pub mod testing;
pub mod update;

pub use background::{BackgroundErase, Blocking};
pub use boot_counter::BootCounter;
pub use error::{CounterError, FlashErrorKind, LayoutError, StoreError};
pub use settings::SettingsPage;
pub use update::{UpdateSlot, WithUpdate};

use core::ops::Range;

use embedded_storage::nor_flash::NorFlash;
use pab_core::crc32::{Crc32, crc32};

/// Where a node keeps its latest accepted table image.
///
/// A save runs in steps ([`start_save`](Self::start_save), then
/// [`continue_save`](Self::continue_save) until [`SaveProgress::Done`]), so that a node reads
/// its frames between them: on a board each step takes at most a chunk's programming (about a
/// millisecond) or the start or check of a page erase (microseconds; the erase itself runs in
/// the background on a [`BackgroundErase`] flash). [`save`](Self::save) runs all the steps at
/// once, for callers that can wait. The power-loss guarantee holds at every step.
pub trait TableStore {
    /// Reads the latest committed image into `buf`; `Ok(None)` if none was ever committed.
    fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError>;
    /// Begins storing `image`: checks that it fits and chooses where it goes. Nothing is written
    /// yet; a save already in progress is abandoned (it never committed, so `load` still returns
    /// what it returned before it). The caller keeps `image` unchanged until the save is done.
    fn start_save(&mut self, image: &[u8]) -> Result<(), StoreError>;
    /// Does the next step of the save [`start_save`](Self::start_save) began, with the same
    /// `image`. [`SaveProgress::Done`] once the image is committed (the next `load` returns it,
    /// also after a power loss); an error ends the save (`load` returns the previous image).
    /// Without a save in progress: `Err(`[`StoreError::NoSave`]`)`.
    fn continue_save(&mut self, image: &[u8]) -> Result<SaveProgress, StoreError>;
    /// Stores `image` so the next `load` (also after a power loss at any point of this call once it
    /// returned `Ok`) returns it: every step at once, waiting for the page erases.
    fn save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        self.start_save(image)?;
        while self.continue_save(image)? != SaveProgress::Done {}
        Ok(())
    }

    /// The node's configuration record (`pab_app::Settings`) from its configuration page;
    /// `Ok(None)` when none was written (the compiled defaults apply). The default: a store
    /// without a configuration page, always `Ok(None)`.
    fn load_settings(&mut self) -> Result<Option<u16>, StoreError> {
        Ok(None)
    }

    /// Stores a configuration record, power-fail safe: `Ok(true)` once it is in force after any
    /// restart, `Ok(false)` when the store has no configuration page (the default: the caller
    /// keeps the setting until it exits). Blocking: a record's program, and once in a while a
    /// page erase (up to 40 ms on the G474); configuration is rare.
    fn save_settings(&mut self, record: u16) -> Result<bool, StoreError> {
        let _ = record;
        Ok(false)
    }

    /// The firmware update's slot length in bytes (the active partition's:
    /// `pab_core::update::stored`); 0, the default, for a store without an update partition,
    /// which takes no update. [`WithUpdate`] gives a store one.
    fn update_slot_len(&self) -> u32 {
        0
    }

    /// Writes an update's chunk at `offset` of the slot, erasing the pages it starts
    /// ([`UpdateSlot::write`]). Blocking. The default: out of bounds (there is no slot).
    fn write_update(&mut self, offset: u32, data: &[u8]) -> Result<(), StoreError> {
        let _ = (offset, data);
        Err(StoreError::Flash(FlashErrorKind::OutOfBounds))
    }

    /// Stores the update's manifest and asks the bootloader to check and swap it in at the next
    /// reset ([`UpdateSlot::request`]). The default: out of bounds.
    fn request_update(
        &mut self,
        manifest: &[u8; pab_core::update::MANIFEST_LEN],
    ) -> Result<(), StoreError> {
        let _ = manifest;
        Err(StoreError::Flash(FlashErrorKind::OutOfBounds))
    }

    /// The bootloader's verdict on the last request, taken once ([`UpdateSlot::take_verdict`]).
    /// The default: none.
    fn take_update_verdict(
        &mut self,
    ) -> Result<Option<pab_core::update::stored::Verdict>, StoreError> {
        Ok(None)
    }

    /// Confirms the running firmware to the bootloader, which then never reverts it; whether it
    /// could. The default (no bootloader): nothing to confirm, `true`.
    fn confirm_firmware(&mut self) -> bool {
        true
    }
}

/// Where a step-wise save stands after a step ([`TableStore::continue_save`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SaveProgress {
    /// More work is ready: call again as soon as the caller has nothing more urgent.
    Ready,
    /// A page erase runs in the background: call again later (a millisecond is about a twentieth
    /// of an erase on the G474); calling sooner only checks the flash's busy flag.
    Erasing,
    /// The image is committed.
    Done,
}

/// Bytes programmed per step of a save (or one write unit of a flash whose unit is larger): two
/// of the G474's double words, 164 µs of programming (82 µs each, datasheet typical; 182 µs at
/// its maximum of 91 µs). That is less than one classic frame's time at 500 kbit/s (at least 222 µs for eight data bytes): a step delays a frame, or a
/// schema server's tick, by less than a frame delays the next one, so a node that takes a step
/// after every frame of a saturated bus keeps pace with it. A chunk of 128 bytes (1.3 ms) would
/// make a 1 kHz server's tick later than its overrun bound (one period late) whenever a step came
/// just before it.
pub const SAVE_CHUNK: usize = 16;

// The promise above, in the datasheet's worst case: two double words (91 µs each) within the
// shortest 8-byte classic frame at 500 kbit/s (111 bits, 2 µs each).
const _: () = assert!(SAVE_CHUNK / 8 * 91 < 111 * 2);

/// Bytes moved per flash read or write: the stack buffer of `load` and `save`.
const CHUNK: usize = 256;
/// The slot header's magic bytes ("PAB slot").
const SLOT_MAGIC: [u8; 4] = *b"PABS";
/// The slot header format this crate writes and reads.
const SLOT_FORMAT: u16 = 1;
/// Bytes of a slot header, before rounding up to the flash's write size (a multiple of 8 already):
/// a slot of `s` bytes holds images of up to `s - SLOT_HEADER_LEN` bytes.
pub const SLOT_HEADER_LEN: usize = 24;
const HEADER_LEN: usize = SLOT_HEADER_LEN;

/// A slot header: the slot holds `len` image bytes whose CRC-32 is `crc`, committed as number
/// `sequence`.
///
/// On flash (little endian): magic `PABS` (4), format (u16), reserved (u16, 0), sequence (u32),
/// length (u32), CRC-32 of the image (u32), CRC-32 of the 20 bytes before it (u32).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Header {
    sequence: u32,
    len: u32,
    crc: u32,
}

impl Header {
    fn encode(&self) -> [u8; HEADER_LEN] {
        let mut out = [0u8; HEADER_LEN];
        let fields = [
            u32::from_le_bytes(SLOT_MAGIC),
            u32::from(SLOT_FORMAT),
            self.sequence,
            self.len,
            self.crc,
        ];
        for (bytes, field) in out.chunks_exact_mut(4).zip(fields) {
            bytes.copy_from_slice(&field.to_le_bytes());
        }
        let (body, tail) = out.split_at_mut(HEADER_LEN - 4);
        tail.copy_from_slice(&crc32(body).to_le_bytes());
        out
    }

    /// The header in `bytes`, if its magic, format and CRC check.
    fn decode(bytes: &[u8; HEADER_LEN]) -> Option<Header> {
        let mut words = [0u32; HEADER_LEN / 4];
        for (word, bytes) in words.iter_mut().zip(bytes.chunks_exact(4)) {
            *word = u32::from_le_bytes(bytes.try_into().ok()?);
        }
        let [magic, format, sequence, len, crc, header_crc] = words;
        let body = bytes.get(..HEADER_LEN - 4)?;
        let ok = magic == u32::from_le_bytes(SLOT_MAGIC)
            && format == u32::from(SLOT_FORMAT)
            && header_crc == crc32(body);
        ok.then_some(Header { sequence, len, crc })
    }
}

/// A [`TableStore`] in a range of NOR flash: a ring of self-describing slots (see the crate
/// documentation for the layout, the algorithm and the guarantees).
pub struct FlashStore<F: NorFlash> {
    flash: F,
    start: u32,
    slots: u32,
    slot_size: u32,
    /// Bytes reserved for the header at the start of each slot: `HEADER_LEN` rounded up to the
    /// flash's write and read sizes.
    header_area: u32,
    /// The save in progress, if any.
    saving: Option<Saving>,
    /// The configuration page's range, if the store has one ([`FlashStore::with_settings`]).
    settings: Option<Range<u32>>,
}

/// A save in progress: the slot it writes, the header it will commit, and how far it got.
#[derive(Clone, Copy, Debug)]
struct Saving {
    /// The target slot's first byte.
    start: u32,
    header: Header,
    phase: Phase,
}

/// The steps of a save, in the order that makes it power-loss safe (crate documentation,
/// `save`): the pages erased first to last, the image programmed and read back chunk by chunk,
/// the header last.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Erasing the page at this offset: `started` once `start_erase` returned.
    Erase { page: u32, started: bool },
    /// Programming the image from this many bytes in.
    Program { done: u32 },
    /// Programming the header: the commit.
    Commit,
}

impl<F: NorFlash> FlashStore<F> {
    /// A store in `range` of `flash` (offsets as the driver counts them), divided into
    /// `range.len() / slot_size` slots (at least two).
    ///
    /// `range` must start and end on erase-page boundaries, lie inside the flash and be a whole
    /// number of slots; `slot_size` must be a positive whole number of erase pages. Touches no
    /// flash: a new store over an erased range simply has nothing committed yet.
    pub fn new(flash: F, range: Range<u32>, slot_size: u32) -> Result<Self, StoreError> {
        let geometry = StoreError::Layout(LayoutError::UnsupportedGeometry);
        let page = u32::try_from(F::ERASE_SIZE).map_err(|_| geometry)?;
        let geometry_ok = F::ERASE_SIZE > 0
            && F::WRITE_SIZE > 0
            && F::READ_SIZE > 0
            && CHUNK.is_multiple_of(F::WRITE_SIZE)
            && CHUNK.is_multiple_of(F::READ_SIZE)
            && F::ERASE_SIZE.is_multiple_of(F::WRITE_SIZE)
            && F::ERASE_SIZE.is_multiple_of(F::READ_SIZE);
        if !geometry_ok {
            return Err(geometry);
        }
        // Both sizes divide 256, so they are powers of two and the larger is a multiple of both.
        let header_area = HEADER_LEN.next_multiple_of(F::WRITE_SIZE.max(F::READ_SIZE));
        let header_area = u32::try_from(header_area).map_err(|_| geometry)?;
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
        let len = range.end - range.start;
        let slots = len / slot_size;
        if slots < 2 {
            return Err(StoreError::Layout(LayoutError::RangeTooSmall));
        }
        if !len.is_multiple_of(slot_size) {
            return Err(StoreError::Layout(LayoutError::RangeNotSlotMultiple));
        }
        Ok(FlashStore {
            flash,
            start: range.start,
            slots,
            slot_size,
            header_area,
            saving: None,
            settings: None,
        })
    }

    /// The store with a configuration page in `range` of the same flash (outside the store's
    /// range; at least two erase pages: [`SettingsPage`]'s rules, checked here), which
    /// [`TableStore::load_settings`] and [`TableStore::save_settings`] then use.
    pub fn with_settings(mut self, range: Range<u32>) -> Result<Self, StoreError> {
        let end = self
            .start
            .saturating_add(self.slots.saturating_mul(self.slot_size));
        if range.start < end && self.start < range.end {
            return Err(StoreError::Layout(LayoutError::RangeOutOfBounds));
        }
        SettingsPage::new(&mut self.flash, range.clone())?;
        self.settings = Some(range);
        Ok(self)
    }

    /// The size of a slot, in bytes (as given to [`Self::new`]).
    pub fn slot_size(&self) -> u32 {
        self.slot_size
    }

    /// The number of slots in the ring (at least two).
    pub fn slot_count(&self) -> u32 {
        self.slots
    }

    /// The largest image a slot holds, in bytes: the slot size less its header (24 bytes, or the
    /// flash's write size if larger).
    pub fn capacity(&self) -> u32 {
        self.slot_size.saturating_sub(self.header_area)
    }

    /// The flash, for inspection (tests, diagnostics). Writing to the store's range through it
    /// voids the guarantees.
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Erases the whole range: the store then holds nothing and the next `load` returns
    /// `Ok(None)`. To forget the table, or to clear a range that another program used (a `load`
    /// answering [`StoreError::Corrupt`] or [`StoreError::SequenceExhausted`]).
    pub fn format(&mut self) -> Result<(), StoreError> {
        // `new` checked that the range (slots * slot_size bytes from start) lies in the flash.
        self.saving = None;
        let end = self
            .start
            .saturating_add(self.slots.saturating_mul(self.slot_size));
        self.flash
            .erase(self.start, end)
            .map_err(|e| StoreError::Flash(FlashErrorKind::of(&e)))
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    // Out of line: four callers inlined it (24 bytes of the NUCLEO-G474RE's flash).
    #[inline(never)]
    fn slot_start(&self, slot: u32) -> u32 {
        // slot < slots, and slots * slot_size bytes from start lie in the flash.
        self.start
            .saturating_add(slot.saturating_mul(self.slot_size))
    }

    /// The slot's header, if it verifies and describes an image that fits the slot.
    fn header(&mut self, slot: u32) -> Result<Option<Header>, StoreError> {
        let mut bytes = [0u8; CHUNK];
        let area = bytes
            .get_mut(..self.header_area as usize)
            .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
        self.flash
            .read(self.slot_start(slot), area)
            .map_err(|e| StoreError::Flash(FlashErrorKind::of(&e)))?;
        let header = area
            .get(..HEADER_LEN)
            .and_then(|bytes| bytes.try_into().ok())
            .and_then(Header::decode);
        Ok(header.filter(|header| header.len <= self.capacity()))
    }

    /// Among the slots whose header verifies, the one with the greatest `(sequence, slot)` below
    /// `bound` (all of them if `None`): the newest commits first, one per call.
    fn newest_below(
        &mut self,
        bound: Option<(u32, u32)>,
    ) -> Result<Option<(u32, Header)>, StoreError> {
        let mut best: Option<(u32, Header)> = None;
        // `(sequence, slot)` compared as one number, sequence in the high half: the same order
        // as the pair's, in one comparison instead of two (32 bytes of the boards' flash).
        let key = |sequence: u32, slot: u32| u64::from(sequence) << 32 | u64::from(slot);
        let bound = bound.map(|(sequence, slot)| key(sequence, slot));
        for slot in 0..self.slots {
            let Some(header) = self.header(slot)? else {
                continue;
            };
            let this = key(header.sequence, slot);
            if bound.is_some_and(|bound| this >= bound) {
                continue;
            }
            if best.is_none_or(|(best_slot, best)| this > key(best.sequence, best_slot)) {
                best = Some((slot, header));
            }
        }
        Ok(best)
    }

    /// Reads `out.len()` bytes from `address` (inside a slot; `out` no longer than the slot).
    fn read_at(&mut self, address: u32, out: &mut [u8]) -> Result<(), StoreError> {
        let flash_error = |e: F::Error| StoreError::Flash(FlashErrorKind::of(&e));
        // The whole READ_SIZE units straight into `out`; a last partial one (none where reads are
        // byte-granular, as on the G4) through a buffer of one unit, read whole: slots are
        // multiples of the unit, so this stays inside.
        let partial = out.len().checked_rem(F::READ_SIZE).unwrap_or(0);
        let whole = out.len().saturating_sub(partial);
        let (head, tail) = out
            .split_at_mut_checked(whole)
            .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
        self.flash.read(address, head).map_err(flash_error)?;
        if !tail.is_empty() {
            let mut unit = [0u8; CHUNK];
            let unit = unit
                .get_mut(..F::READ_SIZE)
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            self.flash
                .read(address.saturating_add(whole as u32), unit)
                .map_err(flash_error)?;
            let bytes = unit
                .get(..tail.len())
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            tail.copy_from_slice(bytes);
        }
        Ok(())
    }

    /// True if the slot's image area holds `header.len` bytes with CRC `header.crc`. Streams
    /// the slot through a chunk buffer (no caller buffer needed).
    fn image_verifies(&mut self, slot: u32, header: Header) -> Result<bool, StoreError> {
        let start = self.slot_start(slot).saturating_add(self.header_area);
        let mut chunk = [0u8; CHUNK];
        let mut crc = Crc32::new();
        let mut done = 0u32;
        while done < header.len {
            let len = (header.len - done).min(CHUNK as u32) as usize;
            let piece = chunk
                .get_mut(..len)
                .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
            self.read_at(start.saturating_add(done), piece)?;
            crc = crc.update(piece);
            done = done.saturating_add(CHUNK as u32);
        }
        Ok(crc.finish() == header.crc)
    }

    /// Programs `piece` (at most [`CHUNK`] bytes) at `address` (write-size aligned), the last
    /// word padded with 0xFF, then reads it back ([`StoreError::VerifyFailed`] if it differs).
    fn program(&mut self, address: u32, piece: &[u8]) -> Result<(), StoreError> {
        let mut chunk = [0xFFu8; CHUNK];
        let padded = piece.len().next_multiple_of(F::WRITE_SIZE);
        let area = chunk
            .get_mut(..padded)
            .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
        area.get_mut(..piece.len())
            .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?
            .copy_from_slice(piece);
        self.flash
            .write(address, area)
            .map_err(|e| StoreError::Flash(FlashErrorKind::of(&e)))?;
        let back = chunk
            .get_mut(..piece.len())
            .ok_or(StoreError::Layout(LayoutError::UnsupportedGeometry))?;
        self.read_at(address, back)?;
        if back != piece {
            return Err(StoreError::VerifyFailed);
        }
        Ok(())
    }
}

impl<F: BackgroundErase> TableStore for FlashStore<F> {
    fn load_settings(&mut self) -> Result<Option<u16>, StoreError> {
        match self.settings.clone() {
            Some(range) => Ok(SettingsPage::new(&mut self.flash, range)?.read()?),
            None => Ok(None),
        }
    }

    fn save_settings(&mut self, record: u16) -> Result<bool, StoreError> {
        match self.settings.clone() {
            Some(range) => {
                SettingsPage::new(&mut self.flash, range)?.write(record)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    fn load<'b>(&mut self, buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        let mut bound = None;
        let mut committed = false;
        while let Some((slot, header)) = self.newest_below(bound)? {
            committed = true;
            bound = Some((header.sequence, slot));
            let len = header.len as usize;
            let got = buf.len();
            let image = self.slot_start(slot).saturating_add(self.header_area);
            match buf.get_mut(..len) {
                Some(area) => {
                    self.read_at(image, area)?;
                    if crc32(area) == header.crc {
                        return Ok(buf.get(..len));
                    }
                }
                None => {
                    if self.image_verifies(slot, header)? {
                        return Err(StoreError::BufferTooSmall { needed: len, got });
                    }
                }
            }
        }
        if committed {
            Err(StoreError::Corrupt)
        } else {
            Ok(None)
        }
    }

    fn start_save(&mut self, image: &[u8]) -> Result<(), StoreError> {
        self.saving = None;
        let too_large = StoreError::ImageTooLarge {
            len: image.len(),
            capacity: self.capacity(),
        };
        let len = u32::try_from(image.len()).map_err(|_| too_large)?;
        if len > self.capacity() {
            return Err(too_large);
        }
        // The highest committed sequence number (image intact or not), so the new one is above
        // every header in the range; then the slot of the image `load` returns now.
        let newest = self.newest_below(None)?;
        let mut current = None;
        let mut candidate = newest;
        while let Some((slot, header)) = candidate {
            if self.image_verifies(slot, header)? {
                current = Some(slot);
                break;
            }
            candidate = self.newest_below(Some((header.sequence, slot)))?;
        }
        // The slot after the current image in ring order: never the current image's slot (there
        // are at least two). With nothing loadable, the slot after the newest header.
        let after = current.or(newest.map(|(slot, _)| slot));
        // Wrapping by comparison, not `%`: no division, and nothing for a zero divisor to panic
        // on (`slots` is at least two, but the compiler cannot know it).
        let target = after.map_or(0, |slot| match slot.saturating_add(1) {
            next if next < self.slots => next,
            _ => 0,
        });
        let sequence = match newest {
            Some((_, header)) => header
                .sequence
                .checked_add(1)
                .ok_or(StoreError::SequenceExhausted)?,
            None => 1,
        };
        let start = self.slot_start(target);
        self.saving = Some(Saving {
            start,
            header: Header {
                sequence,
                len,
                crc: crc32(image),
            },
            phase: Phase::Erase {
                page: start,
                started: false,
            },
        });
        Ok(())
    }

    fn continue_save(&mut self, image: &[u8]) -> Result<SaveProgress, StoreError> {
        let mut saving = self.saving.take().ok_or(StoreError::NoSave)?;
        // The image must be the one `start_save` was given: its length decides the pages erased
        // and its CRC the header (a different image of the same length is caught by the commit's
        // check below, before anything is committed).
        if u32::try_from(image.len()).ok() != Some(saving.header.len) {
            return Err(StoreError::NoSave);
        }
        let flash_error = |e: F::Error| StoreError::Flash(FlashErrorKind::of(&e));
        let image_start = saving.start.saturating_add(self.header_area);
        let (progress, next) = match saving.phase {
            Phase::Erase {
                page,
                started: false,
            } => {
                self.flash.start_erase(page).map_err(flash_error)?;
                (
                    SaveProgress::Erasing,
                    Phase::Erase {
                        page,
                        started: true,
                    },
                )
            }
            Phase::Erase {
                page,
                started: true,
            } => {
                if !self.flash.erase_done().map_err(flash_error)? {
                    (SaveProgress::Erasing, saving.phase)
                } else {
                    // The pages header and image occupy (len <= capacity: inside the slot), the
                    // old header's first.
                    let end = image_start.saturating_add(saving.header.len);
                    let next = page.saturating_add(F::ERASE_SIZE as u32);
                    if next < end {
                        (
                            SaveProgress::Ready,
                            Phase::Erase {
                                page: next,
                                started: false,
                            },
                        )
                    } else {
                        (SaveProgress::Ready, Phase::Program { done: 0 })
                    }
                }
            }
            Phase::Program { done } => {
                let rest = image.get(done as usize..).unwrap_or(&[]);
                // A chunk is whole write units: a flash that writes more than SAVE_CHUNK bytes
                // at once gets one unit a step.
                let chunk = SAVE_CHUNK.next_multiple_of(F::WRITE_SIZE);
                let piece = rest.get(..chunk).unwrap_or(rest);
                if piece.is_empty() {
                    (SaveProgress::Ready, Phase::Commit)
                } else {
                    self.program(image_start.saturating_add(done), piece)?;
                    let done = done.saturating_add(chunk as u32);
                    (SaveProgress::Ready, Phase::Program { done })
                }
            }
            Phase::Commit => {
                if crc32(image) != saving.header.crc {
                    return Err(StoreError::NoSave);
                }
                // The commit: the header, programmed last.
                self.program(saving.start, &saving.header.encode())?;
                return Ok(SaveProgress::Done);
            }
        };
        saving.phase = next;
        self.saving = Some(saving);
        Ok(progress)
    }
}
