//! The application's side of the bootloader (feature `update`; the bootloader is
//! firmware/boot/nucleo-g474re, its flash map `pab_boot_g474::layout`, which this module reads
//! rather than repeating it).
//!
//! An update's course, as the node runs it (pab-app's `update`, through
//! `pab_storage::WithUpdate` over [`Partition`]s):
//!
//! 1. The update receiver writes the image at the start of the DFU partition and, once it is
//!    complete, the manifest (trailer and signature) in the slot's last 96 bytes and the request
//!    in the request page (`pab_core::update::stored`). A page is erased as the image reaches
//!    it (`pab_storage::UpdateSlot`).
//! 2. The runner restarts the board (`NodeWatchdog::restart`: `SCB::sys_reset`) once the
//!    Commit's answer is sent.
//! 3. The bootloader checks the signature, writes its verdict and swaps only an image that
//!    passed; the firmware that runs next reports the verdict (pab-app, at start).
//! 4. The firmware confirms itself ([`mark_booted`], embassy-boot's, on the state partition)
//!    once it has sent a frame and heard one with its table loaded; until then a reset (its own
//!    watchdog's, when it hangs) makes the bootloader revert to the firmware before it.
//!
//! Every partition is in bank 2, with the table store: their erases and programs never stall
//! the program's fetches from bank 1. They go through the store's driver
//! ([`BankFlash`]: embassy's reads and programs, the page erase of its own, waited for here).
//!
//! **A table's save in the background**: the node takes a table while an update runs, so an
//! update's chunk may come while the store's page erase runs in the background. Each operation
//! here waits for it first (`BSY`: the erase's start here, embassy's program in its unlock) and
//! leaves the end of it, the control register's erase bit, the data cache's return and the
//! lock, to the store's own check of it; what is lost is that erase's error flags, which an
//! operation here clears before its own, and a page that was not erased is then found by the
//! store's next program of it (a programming error) and its CRC.
//!
//! Not run on a board (docs/nucleo-g474re.md, "Bootloader").

use embassy_boot::BlockingFirmwareState;
use embassy_stm32::flash::{Error, Flash};
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use pab_boot_g474::layout;

use crate::bank_flash::BankFlash;
use crate::{BANK2, PAGE};

/// The bootloader's partitions that the application reads, as offsets within bank 2 (what
/// FLASH_ECCR says of a double-ECC error: the NMI handler in src/main.rs): DFU, STATE and
/// REQUEST, which follow each other. A power loss that cuts a program of any of them (the
/// application's chunk, manifest, request or confirmation; the bootloader's verdict, swap or
/// progress record) can leave a double word that reads with one.
pub const ECC_TOLERATED: core::ops::Range<u32> =
    layout::DFU - layout::BANK2..layout::REQUEST + layout::REQUEST_LEN - layout::BANK2;

// The bootloader's map agrees with the board's own (src/main.rs), and with the identity's name.
const _: () = assert!(
    layout::BANK2 == layout::FLASH_BASE + BANK2
        && layout::PAGE == PAGE
        && layout::WORD == <Flash<'static, embassy_stm32::flash::Blocking> as NorFlash>::WRITE_SIZE
        && layout::DFU >= layout::BANK2
        && layout::STATE == layout::DFU + layout::DFU_LEN
        && layout::REQUEST == layout::STATE + layout::STATE_LEN
        && same_name(&crate::FIRMWARE.name, &layout::BOARD_NAME),
    "the bootloader's partitions are in bank 2, in this order; the firmware's name is the board's"
);

/// Whether two firmware names are the same (a `const fn`: arrays' `==` is not one).
const fn same_name(a: &[u8; 8], b: &[u8; 8]) -> bool {
    let mut i = 0;
    while i < 8 {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// One of the bootloader's partitions in bank 2, as a NOR flash: offsets count from its start,
/// and nothing outside it is reached. 2 KiB erase pages, double-word programs (the chip's).
pub struct Partition {
    flash: BankFlash,
    /// The partition's first byte, as an offset from the flash base (embassy's offsets).
    start: u32,
    len: u32,
}

/// The DFU partition: the update's slot (the first `layout::ACTIVE_LEN` bytes), then the page
/// embassy-boot's swap needs.
pub type Dfu = Partition;
/// The request page: `update::stored`'s request and the bootloader's verdict.
pub type RequestPage = Partition;

impl Partition {
    /// The partition at `address` (the layout's), `len` bytes.
    ///
    /// # Safety
    ///
    /// Its own driver over the flash controller (embassy's, a handle without state): the caller
    /// does not use two at once, nor interrupts a flash operation with another (the node loop
    /// makes them all, one after the other).
    unsafe fn take(address: u32, len: u32) -> Self {
        // SAFETY: the caller's contract; embassy's driver keeps no state of its own.
        let peripheral = unsafe { embassy_stm32::peripherals::FLASH::steal() };
        Partition {
            flash: BankFlash::new(Flash::new_blocking(peripheral)),
            start: address - layout::FLASH_BASE,
            len,
        }
    }

    /// The DFU partition.
    ///
    /// # Safety
    ///
    /// As [`Partition::take`]'s: the node's store holds it and the request page for the
    /// firmware's life, and the node loop alone uses them.
    pub unsafe fn dfu() -> Dfu {
        // SAFETY: the caller's contract.
        unsafe { Partition::take(layout::DFU, layout::DFU_LEN) }
    }

    /// The request page.
    ///
    /// # Safety
    ///
    /// As [`Partition::dfu`]'s.
    pub unsafe fn request_page() -> RequestPage {
        // SAFETY: the caller's contract.
        unsafe { Partition::take(layout::REQUEST, layout::REQUEST_LEN) }
    }

    /// The flash offset of `offset..offset + len` of the partition, checked against it.
    fn at(&self, offset: u32, len: usize) -> Result<u32, Error> {
        let end = u32::try_from(len)
            .ok()
            .and_then(|len| offset.checked_add(len))
            .ok_or(Error::Size)?;
        if end > self.len {
            return Err(Error::Size);
        }
        Ok(self.start + offset)
    }
}

impl ErrorType for Partition {
    type Error = Error;
}

impl ReadNorFlash for Partition {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        let at = self.at(offset, bytes.len())?;
        self.flash.read(at, bytes)
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

impl NorFlash for Partition {
    const WRITE_SIZE: usize = layout::WORD;
    const ERASE_SIZE: usize = PAGE as usize;

    /// The pages in `from..to`, each waited for (a page's erase: 22 ms typical); bank 2 only,
    /// whole pages only (the driver's erase refuses the rest).
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        let len = to.checked_sub(from).ok_or(Error::Size)?;
        let at = self.at(from, len as usize)?;
        self.flash.erase(at, at + len)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        let at = self.at(offset, bytes.len())?;
        self.flash.write(at, bytes)
    }
}

/// Confirms the running firmware (embassy-boot's `mark_booted` on the state partition): the
/// bootloader will not revert it; whether it could. Harmless when there is nothing to confirm:
/// it rewrites the state page only when it does not say Boot already (a new board's erased page
/// once: an erase and two programs).
pub fn mark_booted() -> bool {
    let mut word = [0u8; layout::WORD];
    // SAFETY: one handle to the state partition, dropped before returning; the node loop calls
    // this between its other flash operations.
    let mut state = unsafe { Partition::take(layout::STATE, layout::STATE_LEN) };
    BlockingFirmwareState::new(&mut state, &mut word)
        .mark_booted()
        .is_ok()
}
