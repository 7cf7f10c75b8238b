//! The application's side of the bootloader (feature `boot`; the bootloader is
//! firmware/boot/mps2-an386, its memory map `pab_boot_an386::layout`).
//!
//! An update's course, as the node will run it:
//!
//! 1. The update receiver erases the DFU partition ([`dfu`]) and writes the image at its start
//!    and the manifest (trailer and signature) in the slot's last 96 bytes
//!    (`pab_core::update::stored`), after the cheap checks of the trailer
//!    (`Trailer::admits`). The partition must be erased first: after a swap or a revert it
//!    holds the other firmware, shifted by a page.
//! 2. [`request_update`], then a reset (`cortex_m::peripheral::SCB::sys_reset`).
//! 3. The bootloader checks the signature, writes its verdict and swaps only an image that
//!    passed; the firmware that runs next reads the verdict with [`take_verdict`] (and reports
//!    it).
//! 4. A swapped-in firmware calls [`mark_booted`] once it has shown that it works (heartbeat
//!    sent, bus heard, table loaded: the design's "Firmware update: decisions"); until then
//!    [`state`] says `Swap`, and a reset (its own, or its watchdog's when it hangs) makes the
//!    bootloader revert to the firmware before it.
//!
//! The partitions are code RAM with the flash rules of [`crate::ram_flash`], but no time is
//! spent on their erases and programs (the bootloader's model, `pab_boot_an386::Nor`).

use embassy_boot::{BlockingFirmwareState, FirmwareUpdaterError, State};
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use pab_boot_an386::{NorError, RequestPage, layout};
use pab_core::update::stored::{self, Request};

pub use pab_boot_an386::Dfu;

/// Why a bootloader operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum BootError {
    /// A partition's flash refused (a layout mistake, or a page in a state it should not be).
    Flash,
    /// The running firmware was swapped in and has not marked itself booted: it may not ask
    /// for another update (the bootloader would revert it first, over the DFU partition).
    NotConfirmed,
}

impl From<NorError> for BootError {
    fn from(_: NorError) -> Self {
        BootError::Flash
    }
}

impl From<FirmwareUpdaterError> for BootError {
    fn from(_: FirmwareUpdaterError) -> Self {
        BootError::Flash
    }
}

/// embassy-boot's state: `Swap` while a swapped-in firmware has not confirmed itself (the
/// next reset reverts it), `Revert` after a revert, `Boot` otherwise (a fresh board's zeroed
/// state page reads so too).
pub fn state() -> Result<State, BootError> {
    let mut word = [0u8; layout::WORD];
    // SAFETY: one handle to the state partition, dropped before returning; the bootloader does
    // not run meanwhile.
    let mut partition = unsafe { pab_boot_an386::State::take() };
    Ok(BlockingFirmwareState::new(&mut partition, &mut word).get_state()?)
}

/// Confirms the running firmware (embassy-boot's `mark_booted` on the state partition): the
/// bootloader will not revert it. Harmless when there is nothing to confirm (it rewrites the
/// state page only when it does not say Boot already).
pub fn mark_booted() -> Result<(), BootError> {
    let mut word = [0u8; layout::WORD];
    // SAFETY: as in `state`.
    let mut partition = unsafe { pab_boot_an386::State::take() };
    Ok(BlockingFirmwareState::new(&mut partition, &mut word).mark_booted()?)
}

/// Asks the bootloader to check and swap in the DFU slot's image at the next reset: erases the
/// request page and writes `stored::REQUEST`. Refused while the running firmware is not
/// confirmed ([`BootError::NotConfirmed`]).
pub fn request_update() -> Result<(), BootError> {
    if state()? == State::Swap {
        return Err(BootError::NotConfirmed);
    }
    // SAFETY: one handle to the request page, dropped before returning.
    let mut page = unsafe { RequestPage::take() };
    page.erase(0, layout::REQUEST_LEN as u32)?;
    page.write(0, &stored::REQUEST)?;
    Ok(())
}

/// The bootloader's verdict on the last request, once: `Some(Ok(()))` swapped in (the running
/// firmware is the update, unless it was since reverted or a reset came between the verdict and
/// the swap's mark: compare its version with the one asked for), `Some(Err(code))`
/// refused (`UpdateRefusal::code`: 4 another board, 6 a bad signature or no update key, ...),
/// and the request page erased; `None` when there is no decided request (none, or one the
/// bootloader has not seen yet).
pub fn take_verdict() -> Result<Option<Result<(), u8>>, BootError> {
    // SAFETY: as in `request_update`.
    let mut page = unsafe { RequestPage::take() };
    let mut head = [0u8; 16];
    page.read(0, &mut head)?;
    match Request::read(&head) {
        Request::Decided(verdict) => {
            page.erase(0, layout::REQUEST_LEN as u32)?;
            Ok(Some(verdict))
        }
        Request::None | Request::Pending => Ok(None),
    }
}

/// The DFU partition as a NOR flash (`embedded_storage`'s; 4 KiB erase pages, 8-byte writes),
/// for the update receiver: the slot is its first `layout::ACTIVE_LEN` bytes, the manifest at
/// `stored::manifest_offset(ACTIVE_LEN)`.
///
/// # Safety
///
/// One handle at a time (the bootloader does not run while the application does).
pub unsafe fn dfu() -> Dfu {
    // SAFETY: the caller's contract.
    unsafe { Dfu::take() }
}

/// Copies `slot` (an image and its manifest as [`dfu`]'s slot holds them, at most
/// `layout::ACTIVE_LEN` bytes) into the erased DFU partition: a whole update at once, what a
/// test plants. The receiver writes chunk by chunk through [`dfu`] instead.
pub fn store_update(slot: &[u8]) -> Result<(), BootError> {
    if slot.len() > layout::ACTIVE_LEN {
        return Err(BootError::Flash);
    }
    // SAFETY: one handle, dropped before returning.
    let mut partition = unsafe { Dfu::take() };
    partition.erase(0, partition.capacity() as u32)?;
    partition.write(0, slot)?;
    Ok(())
}
