//! # pab-boot-common: what the boards' bootloaders share
//!
//! The emulated board's bootloader (`firmware/boot/mps2-an386`, the model, which
//! `scripts/boot-test.sh` runs in QEMU) and the NUCLEO-G474RE's and NUCLEO-F446RE's
//! (`firmware/boot/nucleo-g474re`, `firmware/boot/nucleo-f446re`) run the same steps, each over
//! its own flash and memory map:
//!
//! 1. [`decide`]: a pending request in the request page (`pab_core::update::stored::Request`)
//!    is checked (`stored::check`: manifest, capacity, board name, the Ed25519 signature under
//!    the key page's update key record; no valid record, no update: `BadSignature`), the verdict
//!    written, and only then, if it passed, the swap marked in embassy-boot's state partition
//!    (`mark_updated`). A request while the state says Swap (the running firmware was swapped
//!    in and never confirmed itself) is dropped and the page erased: the revert comes first.
//!    What it did comes back as a [`Decision`], for a bootloader with a console to say.
//! 2. embassy-boot's `prepare_boot` (each bootloader's own call: the emulated board's reports
//!    whether it swapped or reverted).
//! 3. [`is_application`] (or the board's own check) on the active partition's first two words,
//!    then [`jump`].
//!
//! [`boot`] runs the three steps in a row, as the NUCLEO boards' bootloaders do; the emulated
//! board's runs them one by one, with its factory install and its messages between them. What
//! stays in each bootloader: its partitions' flash, the layout.

#![no_std]
#![warn(missing_docs)]

use core::ops::Range;

use embassy_boot::{
    AlignedBuffer, BlockingFirmwareState, BootLoader, BootLoaderConfig, State as BootState,
};
use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
use pab_core::update::UpdateRefusal;
use pab_core::update::stored::{self, Request};

/// A board's flash map, as [`boot`] reads it.
#[derive(Clone, Debug)]
pub struct Map {
    /// The key page's address: the update key's record lies at `stored::KEY_RECORD_OFFSET` in it.
    pub key_page: u32,
    /// The active partition's address: the application's vector table.
    pub active: u32,
    /// The active partition's length, and the DFU slot's.
    pub active_len: u32,
    /// The request page's length (erased whole when a request is dropped).
    pub request_len: u32,
    /// Data RAM: an application's initial stack pointer lies in it (its end included).
    pub ram: Range<u32>,
    /// The firmware name of the board's application: an update's trailer must name it.
    pub board: &'static [u8; 8],
}

/// Steps 1 to 3 (the crate's documentation) at a reset, over the board's partitions: a pending
/// request decided ([`decide`]), embassy-boot's `prepare_boot` (swap, revert, or nothing), the
/// jump to the active partition if it starts with a vector table ([`is_application`]); else,
/// nothing to run, it waits for a reset or a debugger. A flash error in the second step leaves
/// embassy-boot's progress records as they are, for the next reset to resume; meanwhile it boots
/// what is there.
///
/// `BUFFER`: the swap's buffer on the stack (embassy-boot copies a page through it in chunks of
/// this size: a divisor of the page). `WORD`: the state partition's write unit (its flash's
/// `WRITE_SIZE`).
///
/// # Safety
///
/// The key page and the active partition are the chip's memory-mapped flash at the map's
/// addresses, which nothing else writes while this runs; `map.active` is aligned as VTOR needs
/// (the application's linker script puts its vector table there).
#[inline(always)]
pub unsafe fn boot<A, D, S, R, const BUFFER: usize, const WORD: usize>(
    map: &Map,
    active: A,
    mut dfu: D,
    mut state: S,
    mut request: R,
) -> !
where
    A: NorFlash,
    D: NorFlash,
    S: NorFlash,
    R: NorFlash,
{
    let mut word = [0u8; WORD];
    let swapping = state_of(&mut state, &mut word) == BootState::Swap;
    // SAFETY: the caller's contract (the key page is readable flash nothing writes).
    let key_record = unsafe {
        mapped(
            map.key_page + stored::KEY_RECORD_OFFSET as u32,
            stored::KEY_RECORD_LEN,
        )
    };
    let slot = Slot {
        len: map.active_len,
        board: map.board,
        key_record,
    };
    let _ = decide(
        &mut dfu,
        &mut state,
        &mut request,
        map.request_len,
        slot,
        swapping,
        &mut word,
    );

    let mut buffer = AlignedBuffer([0u8; BUFFER]);
    let _ = BootLoader::new(BootLoaderConfig { active, dfu, state }).prepare_boot(buffer.as_mut());

    // SAFETY: the caller's contract (the active partition is readable flash, word aligned).
    let table = unsafe { vector_table(map.active) };
    if is_application(
        table,
        map.ram.clone(),
        map.active..map.active.saturating_add(map.active_len),
    ) {
        // SAFETY: a vector table at the active partition (checked), aligned (the caller's
        // contract); nothing of this program is used afterwards.
        unsafe { jump(map.active) }
    }
    halt()
}

/// Nothing to run (an erased active partition), or a panic: wait for a debugger or a reset.
pub fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// What [`decide`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decision {
    /// No request, or one already decided (a verdict follows it): nothing to do.
    Nothing,
    /// A request while the state says Swap: dropped, the request page erased (or not, if the
    /// erase failed: the next boot drops it again).
    Dropped,
    /// The request page could not be read: nothing done.
    Unreadable,
    /// The slot was checked and the verdict (its last byte: 0 accepted, else the refusal's
    /// code) written; `marked`: the swap was marked in the state partition (only for an
    /// accepted image, and only after the verdict).
    Decided {
        /// The verdict record's code.
        code: u8,
        /// Whether embassy-boot's `mark_updated` succeeded (false for every refusal).
        marked: bool,
    },
    /// The verdict could not be written (its word was not erased: the application broke the
    /// page's protocol, or a flash error): no swap without a verdict.
    VerdictUnwritable {
        /// The verdict that was not written.
        code: u8,
    },
}

/// Where the update goes and what it must be.
#[derive(Clone, Copy, Debug)]
pub struct Slot<'a> {
    /// The active partition's length, and the DFU slot's (the manifest in its last 96 bytes).
    pub len: u32,
    /// The firmware name the application states in its identity (`pab_app::firmware!`): an
    /// update's trailer must name it.
    pub board: &'a [u8; 8],
    /// The key page's update key record (`stored::KEY_RECORD_LEN` bytes at
    /// `stored::KEY_RECORD_OFFSET`).
    pub key_record: &'a [u8],
}

/// Step 1 (the crate's documentation): decides on a pending request, writes the verdict, then
/// marks the swap of an image that passed. `swapping`: the state says Swap ([`state_of`]).
/// `request_len`: the request page's length (erased whole when a request is dropped). `word`:
/// the state partition's write unit, as embassy-boot's `BlockingFirmwareState` takes it (its
/// length must be `S::WRITE_SIZE`).
pub fn decide<D: ReadNorFlash, S: NorFlash, R: NorFlash>(
    dfu: &mut D,
    state: &mut S,
    request: &mut R,
    request_len: u32,
    slot: Slot<'_>,
    swapping: bool,
    word: &mut [u8],
) -> Decision {
    let mut head = [0u8; 16];
    if request.read(0, &mut head).is_err() {
        return Decision::Unreadable;
    }
    if Request::read(&head) != Request::Pending {
        return Decision::Nothing;
    }
    if swapping {
        let _ = request.erase(0, request_len);
        return Decision::Dropped;
    }
    let outcome = check(dfu, slot);
    let verdict = stored::verdict(outcome.map(|_| ()));
    let code = verdict[7];
    if request.write(stored::VERDICT_OFFSET, &verdict).is_err() {
        return Decision::VerdictUnwritable { code };
    }
    let marked = outcome.is_ok()
        && BlockingFirmwareState::new(&mut *state, word)
            .mark_updated()
            .is_ok();
    Decision::Decided { code, marked }
}

/// The DFU slot's check (`update::stored::check`) under the update key in `slot.key_record`.
pub fn check<D: ReadNorFlash>(
    dfu: &mut D,
    slot: Slot<'_>,
) -> Result<pab_core::update::Trailer, UpdateRefusal> {
    let key = stored::decode_key(slot.key_record).ok_or(UpdateRefusal::BadSignature)?;
    stored::check(slot.len, slot.board, &key, |offset, bytes| {
        dfu.read(offset, bytes)
    })
}

/// embassy-boot's state as `prepare_boot` reads it, from the state partition's first word
/// (`word`: its length is the partition's write unit). An unreadable partition reads as Boot.
pub fn state_of<S: ReadNorFlash>(state: &mut S, word: &mut [u8]) -> BootState {
    match state.read(0, word) {
        Ok(()) => BootState::from(&*word),
        Err(_) => BootState::Boot,
    }
}

/// The `len` bytes at `address` of memory-mapped flash (the key page's update key record).
///
/// # Safety
///
/// `address..address + len` is readable memory (the chip's flash) that nothing writes while
/// the slice lives.
pub unsafe fn mapped(address: u32, len: usize) -> &'static [u8] {
    // SAFETY: the caller's contract.
    unsafe { core::slice::from_raw_parts(address as *const u8, len) }
}

/// The first two words at `address`: an initial stack pointer and a reset vector, if a vector
/// table lies there.
///
/// # Safety
///
/// `address` is word aligned and its 8 bytes are readable memory.
pub unsafe fn vector_table(address: u32) -> [u32; 2] {
    let table = address as *const u32;
    // SAFETY: the caller's contract.
    unsafe {
        [
            core::ptr::read_volatile(table),
            core::ptr::read_volatile(table.wrapping_add(1)),
        ]
    }
}

/// Whether `vector_table` (its first two words) starts an application: an initial stack pointer
/// in `ram` (its end included: a full descending stack may start there) and a reset vector
/// inside `active`. Erased flash (0xFFFF_FFFF) is neither.
pub fn is_application(vector_table: [u32; 2], ram: Range<u32>, active: Range<u32>) -> bool {
    let [sp, reset] = vector_table;
    let reset = reset & !1;
    (ram.start..=ram.end).contains(&sp) && active.contains(&reset)
}

/// Step 3: into the application whose vector table is at `address`: every NVIC line disabled
/// and unpended (a bootloader enables none, but a debugger or a warm start might have), VTOR,
/// then the MSP and the reset vector from the table.
///
/// # Safety
///
/// `address` starts an application's vector table ([`is_application`]), aligned as VTOR needs
/// (128 bytes and more: the application's linker script), and nothing of this program is used
/// afterwards.
pub unsafe fn jump(address: u32) -> ! {
    // SAFETY: this program owns the core's peripherals; nothing else runs.
    let peripherals = unsafe { cortex_m::Peripherals::steal() };
    for index in 0..8 {
        // SAFETY: writes of ones to the clear registers only disable and unpend.
        unsafe {
            peripherals.NVIC.icer[index].write(u32::MAX);
            peripherals.NVIC.icpr[index].write(u32::MAX);
        }
    }
    // SAFETY: the caller's contract.
    unsafe {
        peripherals.SCB.vtor.write(address);
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
        cortex_m::asm::bootload(address as *const u32)
    }
}
