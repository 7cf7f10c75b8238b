//! # pab-fw-g474: the pab node on a NUCLEO-G474RE
//!
//! The node application of `pab-app` (arbitration, heartbeat, faults, diagnostic stream, table
//! transfers) on an STM32G474RE, with:
//!
//! - **CAN**: FDCAN1 on PA11 (RX) / PA12 (TX), classic CAN at [`BITRATE`] (500 kbit/s), every
//!   standard and extended frame (data and remote) accepted into RX FIFO 0, through
//!   [`fdcan_bus::FdcanBus`]. The FDCAN kernel clock is the 24 MHz crystal (HSE), so the bit
//!   timing is exact and independent of the system clock (170 MHz from the PLL). With the
//!   feature `fd`, CAN FD with bit-rate switching, the data phase at 2 Mbit/s ([`can_fd`]).
//! - **Flash**: in dual-bank mode, the chip's factory setting (no option byte to change): the
//!   program in bank 1, everything the firmware writes in bank 2, whose page erases run in the
//!   background while the node reads frames ([`bank_flash`]).
//! - **Table store**: the top 40 KiB of bank 2 ([`STORE_RANGE`]), a ring of four 10 KiB slots
//!   (`pab-storage`), saved in steps between frames.
//! - **Key**: the 2 KiB page at [`KEY_PAGE`] (0x0807_4800), written with `pabctl keypage` and
//!   probe-rs (docs/keys.md): erased = no key, a valid record = keyed, anything else = no
//!   configuration accepted; boots counted in the two pages of [`BOOT_COUNTER_RANGE`] for the
//!   challenges' boot salt ([`pab_app::key_from_page`]).
//! - **Node id**: [`NODE_ID`], compiled in from the `PAB_NODE_ID` environment variable
//!   (default 1): `PAB_NODE_ID=2 cargo fw-g474`. An invalid value is a compile error.
//! - **LED**: LD2 (PA5) blinks at about 1 Hz while the node loop turns (set as it feeds the
//!   watchdog: [`NodeWatchdog`]).
//! - **Log**: defmt over RTT (`probe-rs run` prints it); `DEFMT_LOG=debug` at build time shows
//!   every delivered frame.
//! - **Watchdog**: the IWDG (its own 32 kHz LSI clock, independent of the system clock), timeout
//!   [`WATCHDOG_TIMEOUT_US`], fed by the node loop itself ([`pab_app::run_watched`]) at least
//!   every [`FEED_INTERVAL_US`]: a node loop that hangs resets the chip; once started, nothing
//!   but a reset stops it.
//! - **Flash accelerator**: prefetch buffer and instruction/data caches on
//!   ([`enable_flash_prefetch_and_caches`]).
//! - **Firmware update** (feature `update`, behind the bootloader: `boot`): the store with the
//!   bootloader's update slot, the DFU partition and the request page in bank 2
//!   (`pab_storage::WithUpdate`, src/boot.rs); the firmware confirmed to the bootloader once it has
//!   joined the bus (embassy-boot's `mark_booted`), the board restarted into the bootloader
//!   once an update is committed ([`NodeWatchdog`]'s `restart`). Built without the schema
//!   server (`--no-default-features --features ble,dynamics,filters,update`: the three do not
//!   fit 64 KiB together).
//!
//! Built with the workspace's `firmware` profile (fat LTO, one codegen unit, opt-level "s": the
//! root `Cargo.toml` says why). Build and flash: `cargo run --profile firmware -p pab-fw-g474
//! --target thumbv7em-none-eabihf` (the root `.cargo/config.toml` sets probe-rs as the runner).
//! Not run on hardware yet.

#![no_std]
#![no_main]

mod bank_flash;
#[cfg(feature = "update")]
mod boot;
#[cfg(feature = "fd")]
mod can_fd;
mod fdcan_bus;
mod recipient;

use core::num::{NonZeroU8, NonZeroU16};
use core::ops::Range;

use defmt::{info, unwrap};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::Peri;
use embassy_stm32::can::config::{
    FrameTransmissionConfig, GlobalFilter, NominalBitTiming, NonMatchingFilter, TxBufferMode,
};
#[cfg(not(feature = "fd"))]
/// Classic CAN only: the controller neither sends nor takes CAN FD frames.
const FRAME_TRANSMIT: FrameTransmissionConfig = FrameTransmissionConfig::ClassicCanOnly;
#[cfg(feature = "fd")]
/// CAN FD with bit-rate switching: classic and FD frames received, FD frames sent with BRS at
/// [`can_fd::DATA_BITRATE`] when the node's frame asks for it (`can_fd`).
const FRAME_TRANSMIT: FrameTransmissionConfig = FrameTransmissionConfig::AllowFdCanAndBRS;
use embassy_stm32::can::{self, CanConfigurator, OperatingMode};
use embassy_stm32::flash::Flash;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::pac::iwdg::vals::{Key, Pr};
use embassy_stm32::peripherals::FDCAN1;
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, rcc};
use embedded_storage::nor_flash::ReadNorFlash;
#[cfg(feature = "identity")]
use pab_storage::TableStore;
use pab_storage::{BootCounter, FlashStore};

// The boards' memcpy, memset, memcmp and 64-bit division (firmware/builtins): 2.5 KB less flash
// than compiler_builtins'.
use pab_builtins as _;

use bank_flash::BankFlash;
use fdcan_bus::FdcanBus;
use recipient::BoardRecipient;

/// This node's id of an erased configuration page (1..=127): `PAB_NODE_ID` at build time, 1
/// without it, `unassigned` for none (then `pabctl assign` gives it one). An id set over the bus
/// wins. Tables pushed to the node must be compiled for its id.
pub const NODE_ID: u8 = pab_app::parse_node_id(option_env!("PAB_NODE_ID"));

/// The nominal bit rate of an erased configuration page, bit/s (`pabctl config --bitrate` sets
/// another from the next start: 125, 250, 500 or 1000 kbit/s, [`bit_timing`]).
pub const BITRATE: u32 = 500_000;

/// What this firmware says it is in its identity.
#[cfg(feature = "identity")]
const FIRMWARE: pab_app::Firmware = pab_app::firmware!("fw-g474");

/// The NUCLEO-G474RE's crystal (X3, 24 MHz): the HSE, and the FDCAN kernel clock.
const HSE_HZ: u32 = 24_000_000;

/// Time quanta per bit: 1 (sync) + [`SEG1`] + [`SEG2`] = 16, sample point at 14/16 = 87.5 %
/// (CiA 301's recommendation for 500 kbit/s).
const TQ_PER_BIT: u32 = 16;
const SEG1: u8 = 13;
const SEG2: u8 = 2;
/// Resynchronization jump width, in time quanta (at most [`SEG2`]).
const SJW: u8 = 2;
const _: () = assert!(1 + SEG1 as u32 + SEG2 as u32 == TQ_PER_BIT && SJW <= SEG2);
/// Clock cycles per time quantum: 24 MHz / (500 kbit/s * 16) = 3.
const PRESCALER: u32 = HSE_HZ / (BITRATE * TQ_PER_BIT);
const _: () = assert!(
    PRESCALER >= 1 && PRESCALER <= 512 && PRESCALER * BITRATE * TQ_PER_BIT == HSE_HZ,
    "BITRATE must divide 24 MHz / 16 (e.g. 125, 250 or 500 kbit/s); 1 Mbit/s needs 12 or 24 quanta"
);

/// Bank 2's first byte, as an offset from the flash base (0x0800_0000) as the flash driver counts
/// them: the chip in dual-bank mode (its factory setting), two banks of 256 KiB. The program runs
/// from bank 1 (`memory.x` gives it 256 KiB); everything the firmware writes lives in bank 2, so
/// that no erase or program stalls the CPU ([`bank_flash`]).
pub const BANK2: u32 = 0x4_0000;
/// Erase page of the G474's flash in dual-bank mode.
pub const PAGE: u32 = 2048;

/// The table store: 0x0807_6000..0x0808_0000, the top 40 KiB of bank 2.
pub const STORE_RANGE: Range<u32> = 0x7_6000..0x8_0000;
/// A ring of four slots of 10 KiB (5 pages) each: every slot holds its 24-byte header and any
/// image the node's 8 KiB transfer buffer can receive; each page is erased once per four saves.
pub const STORE_SLOT_SIZE: u32 = 10 * 1024;
const _: () = assert!(
    STORE_SLOT_SIZE as usize >= 8192 + pab_storage::SLOT_HEADER_LEN
        && (STORE_RANGE.end - STORE_RANGE.start).is_multiple_of(STORE_SLOT_SIZE)
        && STORE_SLOT_SIZE.is_multiple_of(PAGE),
    "a slot must hold the largest image plus its header, and the range whole slots"
);

/// The configuration page: two 2 KiB pages (0x0807_3800..0x0807_4800) below the key page: the node
/// id and bit rate set over the bus (`pab_storage::SettingsPage`), one 16-byte record per change.
pub const SETTINGS_RANGE: Range<u32> = 0x7_3800..0x7_4800;

/// The key page: one 2 KiB page (0x0807_4800..0x0807_5000) that holds nothing but the key record
/// (`pabctl keypage`), so that writing it (probe-rs erases the whole page) touches nothing else.
pub const KEY_PAGE: u32 = 0x7_4800;
/// The boot counter: two 2 KiB pages (0x0807_5000..0x0807_6000), between the key page and the
/// table store. One 16-byte record per keyed boot, each page erased once per 256 boots.
pub const BOOT_COUNTER_RANGE: Range<u32> = 0x7_5000..0x7_6000;
const _: () = assert!(
    SETTINGS_RANGE.start >= BANK2
        && SETTINGS_RANGE.end == KEY_PAGE
        && SETTINGS_RANGE.end - SETTINGS_RANGE.start == 2 * PAGE
        && KEY_PAGE.is_multiple_of(PAGE)
        && KEY_PAGE + PAGE == BOOT_COUNTER_RANGE.start
        && BOOT_COUNTER_RANGE.end - BOOT_COUNTER_RANGE.start == 2 * PAGE
        && BOOT_COUNTER_RANGE.end == STORE_RANGE.start
        && STORE_RANGE.end == 2 * BANK2,
    "configuration page, key page, boot counter and table store follow each other, \
     page-aligned, at the top of bank 2"
);

/// Behind the bootloader (feature `boot`): its flash map (`pab_boot_g474::layout`) keeps clear of
/// what the board keeps at the top of bank 2, and memory-boot.x links the program at its active
/// partition, in all of it but the manifest's last 96 bytes (a linker script cannot read the
/// layout: its two numbers are checked here).
#[cfg(feature = "boot")]
const _: () = {
    use pab_boot_g474::layout;
    assert!(
        layout::APPLICATION_DATA == layout::FLASH_BASE + SETTINGS_RANGE.start
            && layout::KEY_PAGE == layout::FLASH_BASE + KEY_PAGE
            && layout::ACTIVE == 0x0800_8000
            && layout::ACTIVE_LEN - pab_core::update::MANIFEST_LEN as u32 == 0x107A0,
        "the bootloader's layout, this board's pages and memory-boot.x disagree"
    );
};

/// The FDCAN's nominal bit timing for `kbps`: 16 time quanta at 24 MHz / (rate * 16) for 125,
/// 250 and 500 kbit/s (87.5 % sample point); 1 Mbit/s has 12 quanta of 2 cycles (1 + 9 + 2,
/// 83.3 %: 24 MHz has no whole prescaler for 16). Derived here, not run on hardware
/// (docs/nucleo-g474re.md).
fn bit_timing(kbps: u16) -> NominalBitTiming {
    let (prescaler, seg1) = match kbps {
        1000 => (2, 9),
        kbps => (HSE_HZ / (u32::from(kbps) * 1000 * TQ_PER_BIT), SEG1),
    };
    NominalBitTiming {
        prescaler: NonZeroU16::new(prescaler as u16).unwrap_or(NonZeroU16::MIN),
        seg1: NonZeroU8::new(seg1).unwrap_or(NonZeroU8::MIN),
        seg2: NonZeroU8::new(SEG2).unwrap_or(NonZeroU8::MIN),
        sync_jump_width: NonZeroU8::new(SJW).unwrap_or(NonZeroU8::MIN),
    }
}

/// The IWDG's timeout, µs: a node loop that has not turned for this long resets the chip. Well
/// above the loop's longest step (a step of a table save: a 128-byte program, about a
/// millisecond; the page erases run in the background) and the boot's (the boot counter's page
/// erase, up to 40 ms by the datasheet), and the LSI's tolerance (the timeout can be shorter by
/// some 10 % on a fast LSI).
pub const WATCHDOG_TIMEOUT_US: u32 = 500_000;
/// How often the node loop feeds the IWDG at the latest, µs.
pub const FEED_INTERVAL_US: u64 = 100_000;
const _: () = assert!(FEED_INTERVAL_US * 3 <= WATCHDOG_TIMEOUT_US as u64);

/// The IWDG's count, µs: its LSI (32 kHz) divided by 4, the finest prescaler whose 12-bit reload
/// still reaches [`WATCHDOG_TIMEOUT_US`] (the one embassy's driver would pick).
const IWDG_TICK_US: u32 = 1_000_000 * 4 / embassy_stm32::rcc::LSI_FREQ.0;
const IWDG_PRESCALER: Pr = Pr::DIVIDE_BY4;
/// The counter runs from the reload value down to 0: reload + 1 counts make the timeout.
const IWDG_RELOAD: u32 = WATCHDOG_TIMEOUT_US / IWDG_TICK_US - 1;
const _: () = assert!(
    (IWDG_RELOAD + 1) * IWDG_TICK_US == WATCHDOG_TIMEOUT_US && IWDG_RELOAD <= 0xFFF,
    "the timeout must be a whole number of counts, at most 4096"
);

/// The IWDG, driven through its registers with the prescaler and reload fixed at compile time:
/// embassy's driver (`wdg::IndependentWatchdog`) works them out at run time from the timeout,
/// 376 bytes of flash for what the constants above say (its range check a panic site of its
/// own). Holds the peripheral, so nothing else can drive it.
struct Iwdg {
    _peripheral: Peri<'static, IWDG>,
}

impl Iwdg {
    /// Starts the IWDG with a timeout of [`WATCHDOG_TIMEOUT_US`]; once started, nothing but a
    /// reset stops it. Called first thing at boot, before embassy's init takes the peripheral
    /// (handed over by [`Iwdg::claim`]): the IWDG runs on its own LSI, which it starts itself,
    /// so it needs no clock set up, and a boot that hangs (embassy waits for the crystal without
    /// a limit) ends in a reset.
    fn start() -> Started {
        // Frozen while a debugger halts the core (DBGMCU_APB1FZR1.DBG_IWDG_STOP, reset only by a
        // power-on): a breakpoint would otherwise reset the board within the timeout. Without a
        // debugger the bit changes nothing.
        embassy_stm32::pac::DBGMCU
            .apb1lfzr()
            .modify(|w| w.set_iwdg(true));
        let regs = embassy_stm32::pac::IWDG;
        // The ENABLE key unlocks the prescaler and reload registers.
        regs.kr().write(|w| w.set_key(Key::ENABLE));
        regs.pr().write(|w| w.set_pr(IWDG_PRESCALER));
        regs.rlr().write(|w| w.set_rl(IWDG_RELOAD as u16));
        regs.kr().write(|w| w.set_key(Key::START));
        Started(())
    }

    /// The started IWDG with its peripheral, once embassy's init has handed it out.
    fn claim(_started: Started, iwdg: Peri<'static, IWDG>) -> Self {
        Iwdg { _peripheral: iwdg }
    }

    /// Reloads the counter.
    fn feed(&mut self) {
        embassy_stm32::pac::IWDG
            .kr()
            .write(|w| w.set_key(Key::RESET));
    }
}

/// The IWDG started ([`Iwdg::start`]), before its peripheral exists.
struct Started(());

/// Says whether the IWDG reset the chip last (RCC_CSR.IWDGRSTF), then clears the reset flags,
/// so that the next boot reads only its own cause. A boot that hangs before the node loop (a
/// crystal that never starts) says so at every restart, every [`WATCHDOG_TIMEOUT_US`]; the bus
/// sees no heartbeat from it.
fn report_watchdog_reset() {
    let rcc = embassy_stm32::pac::RCC;
    if rcc.csr().read().iwdgrstf() {
        defmt::error!("reset by the watchdog: the last boot or node loop hung");
    }
    rcc.csr().modify(|w| w.set_rmvf(true));
}

/// The IWDG, as the node loop feeds it, and LD2, which follows bit 19 of the microsecond clock
/// at each feed: it blinks at 0.95 Hz (a 2^20 µs period) while the node loop itself turns (it
/// feeds at least every [`FEED_INTERVAL_US`], so each edge comes within 100 ms), and stops with
/// it. Why here rather than in a task of its own: a hung node loop with a blinking LED would say
/// the wrong thing, and the task took 284 bytes of flash.
struct NodeWatchdog {
    watchdog: Iwdg,
    led: Output<'static>,
}

impl pab_app::Watchdog for NodeWatchdog {
    const FEED_INTERVAL_US: u64 = FEED_INTERVAL_US;

    /// Out of line: the node loop feeds before the boot and at every turn, and the two inlined
    /// copies (the LED's pin is resolved at run time) took 72 bytes more flash than a call.
    #[inline(never)]
    fn feed(&mut self) {
        self.watchdog.feed();
        let level = pab_app::now().as_micros() & (1 << 19) != 0;
        self.led.set_level(level.into());
    }

    /// A system reset: a bit rate's trial heard nothing, the previous rate is stored.
    fn restart(&mut self) {
        cortex_m::peripheral::SCB::sys_reset()
    }
}

// IT0 carries every FDCAN interrupt: `fdcan_bus::Interrupt` does what the driver's handler does
// in its unbuffered mode, then serves the queues.
bind_interrupts!(struct Irqs {
    FDCAN1_IT0 => fdcan_bus::Interrupt;
    FDCAN1_IT1 => can::IT1InterruptHandler<FDCAN1>;
});

// SAFETY: `CanConfigurator::new` asks for the driver's IT0 handler bound to FDCAN1_IT0, so that
// the driver's flags are cleared and its bus-off recovered. `fdcan_bus::Interrupt`, bound there
// instead, does each of the things that handler does with the driver unbuffered, the only mode
// this firmware starts it in (its doc lists them, against embassy-stm32 0.6's `fdcan.rs`);
// linking the handler itself took its buffered modes' code along (1.9 KiB of flash).
unsafe impl
    embassy_stm32::interrupt::typelevel::Binding<
        embassy_stm32::interrupt::typelevel::FDCAN1_IT0,
        can::IT0InterruptHandler<FDCAN1>,
    > for Irqs
{
}

/// Turns on the flash's prefetch buffer and its instruction and data caches (the ART
/// accelerator, FLASH_ACR PRFTEN, ICEN, DCEN).
///
/// Why: at 170 MHz the flash needs 4 wait states, which embassy's RCC set; every instruction
/// fetch that misses the 1 KiB instruction cache then stalls for them unless the prefetch buffer
/// has read ahead, and the reset value leaves prefetch off. embassy-stm32 0.6 sets only the
/// latency on the G4 (`rcc/g4.rs`), so the register is set here. The caches are on after reset;
/// they are set anyway so that this does not depend on what ran before (a bootloader). Flash
/// writes stay coherent: embassy's flash driver turns the data cache off and resets it around
/// each erase and write (`flash/g.rs`), which is what pab-storage's saves go through.
fn enable_flash_prefetch_and_caches() {
    embassy_stm32::pac::FLASH.acr().modify(|w| {
        w.set_prften(true);
        w.set_icen(true);
        w.set_dcen(true);
    });
}

#[embassy_executor::main]
async fn main(_spawner: Spawner) {
    // The watchdog first: from here on a boot that hangs ends in a reset.
    let started = Iwdg::start();
    report_watchdog_reset();
    let p = embassy_stm32::init(clocks());
    enable_flash_prefetch_and_caches();

    let led = Output::new(p.PA5, Level::Low, Speed::Low);
    // Before the CAN controller joins the bus: embassy stops here if the chip's banks are not
    // what the build expects (DBANK cleared by someone), and a board that stops must not be
    // acknowledging others' frames meanwhile.
    let flash = BankFlash::new(Flash::new_blocking(p.FLASH));
    let store = unwrap!(FlashStore::new(flash, STORE_RANGE, STORE_SLOT_SIZE));
    // The node id and bit rate set over the bus, else the compiled ones (feature `identity`).
    #[cfg(feature = "identity")]
    let mut store = unwrap!(store.with_settings(SETTINGS_RANGE));
    #[cfg(not(feature = "identity"))]
    let mut store = store;
    #[cfg(feature = "identity")]
    let loaded = store.load_settings();
    #[cfg(feature = "identity")]
    let settings = pab_app::Settings::from_loaded(&loaded);
    #[cfg(feature = "identity")]
    let (kbps, node_id) = (
        settings.start_bitrate((BITRATE / 1000) as u16),
        settings.node_id.or((NODE_ID != 0).then_some(NODE_ID)),
    );
    #[cfg(not(feature = "identity"))]
    let kbps = (BITRATE / 1000) as u16;
    info!("pab node on NUCLEO-G474RE, CAN {} kbit/s", kbps);

    let mut can = CanConfigurator::new(p.FDCAN1, p.PA11, p.PA12, Irqs);
    let config = can
        .config()
        .set_nominal_bit_timing(bit_timing(kbps))
        .set_frame_transmit(FRAME_TRANSMIT)
        // FIFO mode, fed one frame at a time from a queue ordered by priority (`fdcan_bus`):
        // frames of equal identifier leave in the order they were queued (ISO-TP), none is ever
        // aborted.
        .set_tx_buffer_mode(TxBufferMode::Fifo)
        .set_global_filter(
            GlobalFilter::default()
                .set_handle_standard_frames(NonMatchingFilter::IntoRxFifo0)
                .set_handle_extended_frames(NonMatchingFilter::IntoRxFifo0)
                .set_reject_remote_standard_frames(false)
                .set_reject_remote_extended_frames(false),
        )
        .set_automatic_retransmit(true)
        .set_automatic_bus_off_recovery(true);
    #[cfg(feature = "fd")]
    let config = config.set_data_bit_timing(can_fd::data_bit_timing());
    can.set_config(config);
    #[cfg(not(feature = "fd"))]
    let mut bus = FdcanBus::new(can.start(OperatingMode::NormalOperationMode));
    #[cfg(feature = "fd")]
    let mut bus = {
        let can = can.start(OperatingMode::NormalOperationMode);
        can_fd::compensate_transceiver_delay();
        FdcanBus::new(can)
    };

    // Cannot fail: the record's id is 1..=127 and NODE_ID is checked at compile time.
    #[cfg(feature = "identity")]
    let config =
        pab_app::Config::for_node(node_id).unwrap_or_else(|_| pab_app::Config::unassigned());
    #[cfg(not(feature = "identity"))]
    let config = unwrap!(pab_app::Config::new(NODE_ID));
    // Built in place in the task's future (40 KiB with the schema server; this task's stack
    // frame is some 400 bytes). It must stay so: the node loop runs in this frame, so a node
    // built in a temporary on the stack would keep that room under the loop's deepest calls.
    let mut node = pab_app::BoardNode::new(config, pab_app::now());
    // Who it is: the chip's 96-bit factory UID.
    #[cfg(feature = "identity")]
    {
        node.set_identity(FIRMWARE, embassy_stm32::uid::uid());
        node.set_settings(loaded, kbps, pab_app::now());
    }
    // The key before anything else: a page that cannot be read counts as truncated (locked).
    let flash = store.flash_mut();
    let mut page = [0u8; pab_core::auth::page::LEN];
    let page: &[u8] = match flash.read(KEY_PAGE, &mut page) {
        Ok(()) => &page,
        Err(_) => &[],
    };
    pab_app::key_from_page(&mut node, page, || {
        BootCounter::new(&mut *flash, BOOT_COUNTER_RANGE)?.increment()
    });
    // Only the node loop feeds it from here on (once before the node's boot, then every turn).
    let watchdog = Iwdg::claim(started, p.IWDG);
    // The node loop runs in this task rather than in one of its own: spawning one (its pool, the
    // move of the loop's state into it, the check that the pool was free) took some 110 bytes of
    // flash, and this task would only have returned.
    let mut recipient = BoardRecipient::new();
    let mut watchdog = NodeWatchdog { watchdog, led };
    // With the bootloader's update slot (feature `update`): the DFU partition and the request
    // page; the firmware confirmed once it has joined the bus, and the board restarted into the
    // bootloader (`NodeWatchdog::restart`) once an update is committed.
    #[cfg(feature = "update")]
    let mut store = with_update(store);
    pab_app::run_watched(
        &mut node,
        &mut bus,
        &mut store,
        &mut recipient,
        &mut watchdog,
    )
    .await
}

/// The table store with the bootloader's update slot: the DFU partition's first `ACTIVE_LEN`
/// bytes and the request page (`pab_boot_g474::layout`), and embassy-boot's `mark_booted` as
/// the firmware's confirmation.
#[cfg(feature = "update")]
fn with_update<S: pab_storage::TableStore>(
    store: S,
) -> pab_storage::WithUpdate<S, boot::Dfu, boot::RequestPage> {
    // SAFETY: one handle each for the firmware's life, used by the node loop alone, which makes
    // one flash operation at a time (src/boot.rs).
    let (dfu, request) = unsafe { (boot::Partition::dfu(), boot::Partition::request_page()) };
    let slot = unwrap!(pab_storage::UpdateSlot::new(
        dfu,
        request,
        pab_boot_g474::layout::ACTIVE_LEN
    ));
    pab_storage::WithUpdate::new(store, slot, boot::mark_booted)
}

/// HSE 24 MHz; SYSCLK 170 MHz from the PLL (24 / 6 * 85 / 2), boost mode; FDCAN on the HSE; LSI
/// on, RTC off.
fn clocks() -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(rcc::Hse {
        freq: Hertz(HSE_HZ),
        mode: rcc::HseMode::Oscillator,
    });
    config.rcc.pll = Some(rcc::Pll {
        source: rcc::PllSource::HSE,
        prediv: rcc::PllPreDiv::DIV6,
        mul: rcc::PllMul::MUL85,
        divp: None,
        divq: None,
        divr: Some(rcc::PllRDiv::DIV2),
    });
    config.rcc.sys = rcc::Sysclk::PLL1_R;
    config.rcc.boost = true;
    // The RTC unclocked: nothing here uses it. embassy's default clocks it from the LSI, at the
    // price of a backup-domain reset and the clock's selection at every power-on (and 48 bytes
    // of flash). The LSI itself stays on, started here as before: the IWDG runs from it.
    config.rcc.ls = rcc::LsConfig {
        rtc: rcc::RtcClockSource::DISABLE,
        lsi: true,
        lse: None,
    };
    config.rcc.mux.fdcansel = rcc::mux::Fdcansel::HSE;
    config
}

/// The lowest of the board's pages in bank 2 whose double-ECC errors the NMI handler clears:
/// the key page; with identity, the configuration page below it, which the firmware then reads
/// and writes (a record's program cut by a power loss).
#[cfg(not(feature = "identity"))]
const ECC_TOLERATED_START: u32 = KEY_PAGE;
#[cfg(feature = "identity")]
const ECC_TOLERATED_START: u32 = SETTINGS_RANGE.start;

/// Whether a double-ECC error at `at` (an offset within bank 2) is one the NMI handler clears.
#[inline(always)]
fn ecc_tolerated(at: u32) -> bool {
    #[cfg(feature = "update")]
    if boot::ECC_TOLERATED.contains(&at) {
        return true;
    }
    (ECC_TOLERATED_START - BANK2..STORE_RANGE.end - BANK2).contains(&at)
}

/// The flash's double-ECC error (a double word whose programming a power loss cut) raises an NMI.
/// Inside the table store, the boot counter and the key page (bank 2) that is expected after a power loss
/// during a save, a boot count or the page's writing: clear the flag and return, so the read
/// completes with bad bytes that the store's CRC, the counter's record check or the key page's
/// CRC rejects (the store falls back to the other slot, the counter skips the record, the key
/// page locks the node). Anywhere else (the program) it is a real fault: halt.
///
/// With identity, the configuration page too (its records are checked as the boot counter's).
/// With `update`, the application also reads the bootloader's DFU, STATE and REQUEST partitions
/// (`boot::ECC_TOLERATED`, bank 2): the manifest's page before it writes a manifest, embassy-boot's
/// state when it confirms itself, the verdict at start; an update's program, the bootloader's
/// verdict or a swap's progress record cut by a power loss can leave a double word there that
/// reads with an ECC error. Cleared as well: the bad bytes fail the check that reads them (a
/// manifest's page that is not erased is erased before the manifest is written, a state that
/// is no magic reads as Boot and is written again by the confirmation, a request or verdict
/// that is no record is not taken: `update::stored::Request::read`). The bootloader, which
/// reads the same partitions, clears them too (pab-boot-g474's src/main.rs).
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    let flash = embassy_stm32::pac::FLASH;
    let eccr = flash.eccr().read();
    // Dual-bank mode: ADDR_ECC is the byte offset of the failing double word within its bank,
    // BK_ECC the bank (set: bank 2). (ECCD2, a second word of a 128-bit line, exists only in
    // single-bank mode.)
    if eccr.eccd() && eccr.bk_ecc() && ecc_tolerated(eccr.addr_ecc()) {
        // ECCD is write-1-to-clear; writing 0 to the other bits leaves ECCC alone and keeps the
        // ECC-correction interrupt disabled (its reset state, which embassy does not change).
        flash.eccr().write(|w| w.set_eccd(true));
        return;
    }
    defmt::panic!(
        "NMI (flash ECCR {=u32:#x}): double ECC error in the program, or a clock failure",
        eccr.0
    );
}

/// A panic says so over defmt and stops on a permanently undefined instruction (a debugger
/// shows the backtrace there; without one, the HardFault spins until the watchdog resets the
/// board). Only embassy's own checks can get here: `scripts/panic-check.sh` finds no panic site
/// in the project's crates. Not panic-probe: its message goes through `core::fmt`, about 2 KiB
/// of flash that the mechanisms need more.
///
/// Where it happened (file and line) only in a build with `PAB_PANIC_LOCATION=1` (build.rs),
/// such as the bring-up build (docs/bring-up-g474.md): each of embassy's panic sites passes a
/// `Location`, and their locations and file names took 1 732 bytes of flash, which sealed
/// coordination needed (`scripts/firmware-size.sh`). A debugger shows the place anyway.
///
/// `inline(always)`: rustc warns that the attribute is ignored on an exported function, but under
/// the firmware profile's fat LTO LLVM honours it and inlines the handler into core's
/// `panic_fmt`. Only then can it see that the message (and, without `panic_location`, the
/// location) is never read and drop what every panic site prepares (`usize`'s `Display`,
/// `Formatter::pad`): 1 932 bytes of flash on the BLE build, measured with
/// `scripts/firmware-size.sh`, which fails if they come back and push the firmware past 64 KiB.
/// They leave the flash only because LLVM's dead-argument elimination runs again after the
/// inlining (`.cargo/config.toml`).
#[panic_handler]
#[allow(unused_attributes)]
#[inline(always)]
fn panic(info: &core::panic::PanicInfo) -> ! {
    #[cfg(panic_location)]
    match info.location() {
        Some(at) => defmt::error!("panic at {=str}:{=u32}", at.file(), at.line()),
        None => defmt::error!("panic"),
    }
    #[cfg(not(panic_location))]
    {
        let _ = info;
        defmt::error!("panic (PAB_PANIC_LOCATION=1 builds say where)");
    }
    cortex_m::asm::udf()
}

/// What follows a `defmt::panic!` (embassy's checks, `unwrap!`) once it has logged its message:
/// stop as [`panic`] does. defmt's default handler went through core's `panic!` instead, whose
/// handler logged a second line that says nothing (a location inside defmt): 64 bytes of flash.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::asm::udf()
}
