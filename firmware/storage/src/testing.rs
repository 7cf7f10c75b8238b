//! [`MemFlash`]: an in-memory NOR flash for tests, with wear counters and power-loss injection.
//!
//! Behind the `mem-flash` feature; this crate's tests enable it, and other crates' tests may
//! (`pab-storage = { workspace = true, features = ["mem-flash"] }` in their dev-dependencies).
//!
//! NOR semantics, as strict as the STM32G4's flash controller:
//!
//! - erasing sets every byte of whole pages to 0xFF;
//! - a write covers whole words (`WRITE_SIZE` bytes, aligned) and **every word it touches must be
//!   erased** (all 0xFF) **or be written with zeros**; otherwise the write fails with
//!   [`MemFlashError::NotErased`] and changes nothing. This is the STM32G4's rule (RM0440: PROGERR
//!   when the double word is not erased, except when all zeros are written). An AND semantics
//!   would hide double writes that the board refuses, so this flash refuses them. (`FlashStore`
//!   never needs the zero exception: it programs each word once between erases.)
//! - misaligned or out-of-range accesses fail with [`MemFlashError::NotAligned`] or
//!   [`MemFlashError::OutOfBounds`] (reads are byte-granular: `READ_SIZE` is 1, as on the G4).
//!
//! Power loss: [`MemFlash::fail_after`]`(n)` arms a failure at the n-th program or erase call from
//! now (0 = the next one). That call stops part-way and returns [`MemFlashError::PowerLost`]:
//!
//! - a write programs a pseudo-random number of its words (possibly none, possibly all), then
//!   leaves the next word *half programmed* (only some of the bits that should clear do);
//! - an erase erases a pseudo-random number of its pages, then leaves the next page *half
//!   erased* (random bits of its old contents set to 1).
//!
//! How many bits of a cut word or page went wrong varies from cut to cut: about half of them,
//! one in eight, seven in eight, or none, so that garbage, nearly finished and nearly untouched
//! contents are all exercised.
//!
//! Every later call (reads too) fails with `PowerLost` until [`MemFlash::reboot`], which keeps
//! the memory as it is, like a board that comes back up. The pseudo-random choices come from a
//! seed ([`MemFlash::set_seed`]), so every run is repeatable.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

use crate::BackgroundErase;

/// Why a [`MemFlash`] operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum MemFlashError {
    /// Not aligned to the write or erase size.
    NotAligned,
    /// Outside the memory.
    OutOfBounds,
    /// A write touched a word that is not erased.
    NotErased {
        /// Address of the first such word.
        offset: u32,
    },
    /// The simulated power loss happened (during this call or before it).
    PowerLost,
}

impl NorFlashError for MemFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            MemFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            MemFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            MemFlashError::NotErased { .. } | MemFlashError::PowerLost => NorFlashErrorKind::Other,
        }
    }
}

impl core::fmt::Display for MemFlashError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MemFlashError::NotAligned => f.write_str("not aligned"),
            MemFlashError::OutOfBounds => f.write_str("out of bounds"),
            MemFlashError::NotErased { offset } => write!(f, "word at {offset:#x} not erased"),
            MemFlashError::PowerLost => f.write_str("power lost"),
        }
    }
}

impl core::error::Error for MemFlashError {}

/// An in-memory NOR flash of `PAGES` erase pages of `ERASE_SIZE` bytes, written in words of
/// `WRITE_SIZE` bytes. Its capacity is `PAGES * ERASE_SIZE` bytes (the page count is the generic
/// parameter, rather than the byte size, so that the per-page erase counters need no allocation).
///
/// `Clone` copies the memory, the counters and the armed failure: a test can save a state and
/// replay operations from it.
#[derive(Clone, Debug)]
pub struct MemFlash<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize> {
    pages: [[u8; ERASE_SIZE]; PAGES],
    erases: [u32; PAGES],
    operations: u32,
    fail_at: Option<u32>,
    power_lost: bool,
    rng: u64,
    /// How many `erase_done` calls answer "still erasing" after each `start_erase`.
    erase_polls: u32,
    /// Of those, how many are left for the erase started last.
    erase_pending: u32,
}

impl<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize> Default
    for MemFlash<PAGES, ERASE_SIZE, WRITE_SIZE>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize>
    MemFlash<PAGES, ERASE_SIZE, WRITE_SIZE>
{
    const GEOMETRY_OK: () = assert!(
        WRITE_SIZE > 0 && ERASE_SIZE > 0 && ERASE_SIZE.is_multiple_of(WRITE_SIZE),
        "ERASE_SIZE must be a positive multiple of WRITE_SIZE"
    );

    /// An erased flash (all 0xFF), no erase counted, no failure armed.
    pub const fn new() -> Self {
        let () = Self::GEOMETRY_OK;
        MemFlash {
            pages: [[0xFF; ERASE_SIZE]; PAGES],
            erases: [0; PAGES],
            operations: 0,
            fail_at: None,
            power_lost: false,
            rng: 0x9E37_79B9_7F4A_7C15,
            erase_polls: 1,
            erase_pending: 0,
        }
    }

    /// How many [`BackgroundErase::erase_done`] calls answer `Ok(false)` after each
    /// [`BackgroundErase::start_erase`] (default 1): a background erase that takes its time.
    /// The erase itself happens at `start_erase` (a power loss armed for it cuts it there).
    pub fn set_erase_polls(&mut self, polls: u32) {
        self.erase_polls = polls;
    }

    /// A flash full of pseudo-random bytes from `seed` (as if another program had used it).
    pub fn garbage(seed: u64) -> Self {
        let mut flash = Self::new();
        flash.set_seed(seed);
        for page in flash.pages.iter_mut() {
            for byte in page.iter_mut() {
                *byte = (next_random(&mut flash.rng) >> 24) as u8;
            }
        }
        flash
    }

    /// Seeds the pseudo-random choices of the simulated power loss.
    pub fn set_seed(&mut self, seed: u64) {
        // xorshift must not start at 0.
        self.rng = seed ^ 0x9E37_79B9_7F4A_7C15;
        if self.rng == 0 {
            self.rng = 1;
        }
    }

    /// Arms a power loss: the `n`-th program or erase call from now (0 = the next) stops part-way
    /// and every later call fails, until [`Self::reboot`].
    pub fn fail_after(&mut self, n: u32) {
        self.fail_at = Some(self.operations.saturating_add(n));
    }

    /// True once the armed power loss has happened.
    pub fn power_lost(&self) -> bool {
        self.power_lost
    }

    /// Power comes back: disarms any failure and accepts operations again; memory and counters
    /// stay as they are.
    pub fn reboot(&mut self) {
        self.fail_at = None;
        self.power_lost = false;
    }

    /// Program and erase calls so far (including one interrupted by a power loss).
    pub fn operations(&self) -> u32 {
        self.operations
    }

    /// How many times each page was erased (an interrupted erase counts for the pages it
    /// touched).
    pub fn erase_counts(&self) -> &[u32; PAGES] {
        &self.erases
    }

    /// The memory, page by page.
    pub fn pages(&self) -> &[[u8; ERASE_SIZE]; PAGES] {
        &self.pages
    }

    /// Inverts bit `bit` (0..8) of the byte at `offset`, behind everyone's back (a cosmic ray, a
    /// worn cell). Returns false if `offset` is out of range.
    pub fn flip_bit(&mut self, offset: u32, bit: u8) -> bool {
        match self.byte_mut(offset) {
            Some(byte) => {
                *byte ^= 1u8.wrapping_shl(u32::from(bit));
                true
            }
            None => false,
        }
    }

    fn byte_mut(&mut self, offset: u32) -> Option<&mut u8> {
        let offset = usize::try_from(offset).ok()?;
        let page = offset.checked_div(ERASE_SIZE)?;
        let within = offset.checked_rem(ERASE_SIZE)?;
        self.pages.get_mut(page)?.get_mut(within)
    }

    fn byte(&self, offset: usize) -> Option<u8> {
        let page = offset.checked_div(ERASE_SIZE)?;
        let within = offset.checked_rem(ERASE_SIZE)?;
        self.pages.get(page)?.get(within).copied()
    }

    const fn capacity_bytes() -> usize {
        PAGES.saturating_mul(ERASE_SIZE)
    }

    /// Counts a program or erase call; true if it is the one that loses power.
    fn begin_operation(&mut self) -> Result<bool, MemFlashError> {
        if self.power_lost {
            return Err(MemFlashError::PowerLost);
        }
        let this = self.operations;
        self.operations = self.operations.saturating_add(1);
        if self.fail_at == Some(this) {
            self.power_lost = true;
            return Ok(true);
        }
        Ok(false)
    }

    fn random_below(&mut self, bound: usize) -> usize {
        let value = next_random(&mut self.rng);
        usize::try_from(value % u64::try_from(bound.max(1)).unwrap_or(1)).unwrap_or(0)
    }

    fn check_range(offset: u32, len: usize, align: usize) -> Result<usize, MemFlashError> {
        let start = usize::try_from(offset).map_err(|_| MemFlashError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(MemFlashError::OutOfBounds)?;
        if end > Self::capacity_bytes() {
            return Err(MemFlashError::OutOfBounds);
        }
        if !start.is_multiple_of(align) || !len.is_multiple_of(align) {
            return Err(MemFlashError::NotAligned);
        }
        Ok(start)
    }
}

/// A pseudo-random byte with about half of its bits set (`density` 0), one in eight (1), none (2)
/// or seven in eight (3).
fn noise(state: &mut u64, density: usize) -> u8 {
    let sparse = |state: &mut u64| {
        let (a, b, c) = (next_random(state), next_random(state), next_random(state));
        ((a & b & c) >> 32) as u8
    };
    match density {
        0 => (next_random(state) >> 32) as u8,
        1 => sparse(state),
        2 => 0,
        _ => !sparse(state),
    }
}

/// xorshift64: enough to scatter failure points; not for anything else.
fn next_random(state: &mut u64) -> u64 {
    let mut x = *state;
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    *state = x;
    x
}

impl<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize> ErrorType
    for MemFlash<PAGES, ERASE_SIZE, WRITE_SIZE>
{
    type Error = MemFlashError;
}

impl<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize> ReadNorFlash
    for MemFlash<PAGES, ERASE_SIZE, WRITE_SIZE>
{
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        if self.power_lost {
            return Err(MemFlashError::PowerLost);
        }
        let start = Self::check_range(offset, bytes.len(), 1)?;
        for (k, out) in bytes.iter_mut().enumerate() {
            *out = self
                .byte(start.saturating_add(k))
                .ok_or(MemFlashError::OutOfBounds)?;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        Self::capacity_bytes()
    }
}

impl<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize> NorFlash
    for MemFlash<PAGES, ERASE_SIZE, WRITE_SIZE>
{
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        if self.power_lost {
            return Err(MemFlashError::PowerLost);
        }
        let len = to
            .checked_sub(from)
            .and_then(|len| usize::try_from(len).ok())
            .ok_or(MemFlashError::OutOfBounds)?;
        let start = Self::check_range(from, len, ERASE_SIZE)?;
        let first = start / ERASE_SIZE;
        let count = len / ERASE_SIZE;
        let interrupted = self.begin_operation()?;
        let complete = if interrupted {
            self.random_below(count)
        } else {
            count
        };
        for page in first..first.saturating_add(complete) {
            if let (Some(memory), Some(erases)) =
                (self.pages.get_mut(page), self.erases.get_mut(page))
            {
                memory.fill(0xFF);
                *erases = erases.saturating_add(1);
            }
        }
        if !interrupted {
            return Ok(());
        }
        // Half erased: random bits of the old contents went to 1 (a few pages untouched after).
        let half = first.saturating_add(complete);
        if half < first.saturating_add(count) {
            let density = self.random_below(4);
            let mut rng = self.rng;
            if let (Some(memory), Some(erases)) =
                (self.pages.get_mut(half), self.erases.get_mut(half))
            {
                for byte in memory.iter_mut() {
                    *byte |= noise(&mut rng, density);
                }
                *erases = erases.saturating_add(1);
            }
            self.rng = rng;
        }
        Err(MemFlashError::PowerLost)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        if self.power_lost {
            return Err(MemFlashError::PowerLost);
        }
        let start = Self::check_range(offset, bytes.len(), WRITE_SIZE)?;
        // Every word must be erased, or be written with zeros; nothing changes otherwise.
        for (index, word) in bytes.chunks(WRITE_SIZE).enumerate() {
            let address = start.saturating_add(index.saturating_mul(WRITE_SIZE));
            let erased =
                (0..WRITE_SIZE).all(|k| self.byte(address.saturating_add(k)) == Some(0xFF));
            if !erased && word.iter().any(|&byte| byte != 0) {
                return Err(MemFlashError::NotErased {
                    offset: u32::try_from(address).unwrap_or(u32::MAX),
                });
            }
        }
        let interrupted = self.begin_operation()?;
        let words = bytes.len() / WRITE_SIZE;
        let complete = if interrupted {
            self.random_below(words.saturating_add(1))
        } else {
            words
        };
        let programmed = complete.saturating_mul(WRITE_SIZE);
        for (k, &value) in bytes.iter().enumerate().take(programmed) {
            if let Some(byte) = self.byte_mut(u32::try_from(start.saturating_add(k)).unwrap_or(0)) {
                *byte &= value;
            }
        }
        if !interrupted {
            return Ok(());
        }
        // The next word half programmed: only some of the bits that should clear did.
        let density = self.random_below(4);
        let mut rng = self.rng;
        for (k, &value) in bytes.iter().enumerate().skip(programmed).take(WRITE_SIZE) {
            // The bits of `value` that stay 1 although they should have cleared.
            let missed = noise(&mut rng, density);
            if let Some(byte) = self.byte_mut(u32::try_from(start.saturating_add(k)).unwrap_or(0)) {
                *byte &= value | missed;
            }
        }
        self.rng = rng;
        Err(MemFlashError::PowerLost)
    }
}

impl<const PAGES: usize, const ERASE_SIZE: usize, const WRITE_SIZE: usize> BackgroundErase
    for MemFlash<PAGES, ERASE_SIZE, WRITE_SIZE>
{
    fn start_erase(&mut self, offset: u32) -> Result<(), Self::Error> {
        let end = offset.saturating_add(ERASE_SIZE as u32);
        self.erase(offset, end)?;
        self.erase_pending = self.erase_polls;
        Ok(())
    }

    fn erase_done(&mut self) -> Result<bool, Self::Error> {
        if self.power_lost {
            return Err(MemFlashError::PowerLost);
        }
        match self.erase_pending.checked_sub(1) {
            Some(left) => {
                self.erase_pending = left;
                Ok(false)
            }
            None => Ok(true),
        }
    }
}
