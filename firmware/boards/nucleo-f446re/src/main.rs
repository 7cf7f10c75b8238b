//! # pab-fw-f446: the pab node on a NUCLEO-F446RE
//!
//! The node application of `pab-app` (arbitration, heartbeat, faults, diagnostic stream, table
//! transfers, competitive dynamics, the schema server) on an STM32F446RE, the second MCU family
//! after the NUCLEO-G474RE's STM32G4, with:
//!
//! - **CAN**: the bxCAN CAN1 on PA11 (RX) / PA12 (TX), the same Morpho pins as the
//!   NUCLEO-G474RE's FDCAN1, classic CAN at [`BITRATE`] (500 kbit/s), every standard and
//!   extended frame (data and remote) accepted into FIFO 0 by filter bank 0, through
//!   [`bxcan_bus::BxcanBus`]. The bxCAN runs on APB1, [`PCLK1_HZ`] = 40 MHz, a whole multiple of
//!   the bit rate's 16 time quanta; APB1 comes from the PLL on the 8 MHz clock that the board's
//!   ST-LINK gives the MCU (its MCO, the HSE in bypass mode), so the bit timing has the ST-LINK's
//!   crystal's accuracy.
//! - **Flash**: one bank of eight sectors, in which an erase stalls the CPU; the program lives
//!   in sector 5 (its vector table in sector 0), and what the firmware writes in sectors of its
//!   own (`memory.x`, [`sector_flash`]).
//! - **Table store**: sectors 1 to 3 ([`STORE_RANGE`]), a ring of three 16 KiB slots
//!   (`pab-storage`), saved in steps between frames; each step's sector erase stalls the node
//!   for 250 ms typical ([`sector_flash`]).
//! - **Key**: sector 4 at [`KEY_PAGE`] (0x0801_0000), written with `pabctl keypage` and probe-rs
//!   (docs/keys.md): erased = no key, a valid record = keyed, anything else = no configuration
//!   accepted; boots counted in sectors 6 and 7 ([`BOOT_COUNTER_RANGE`]) for the challenges'
//!   boot salt ([`pab_app::key_from_page`]).
//! - **Node id**: [`NODE_ID`], compiled in from the `PAB_NODE_ID` environment variable
//!   (default 1): `PAB_NODE_ID=2 cargo fw-f446`. An invalid value is a compile error.
//! - **LED**: LD2 (PA5) blinks at about 1 Hz while the node loop turns (set as it feeds the
//!   watchdog: [`NodeWatchdog`]).
//! - **Log**: defmt over RTT (`probe-rs run` prints it); `DEFMT_LOG=debug` at build time shows
//!   every delivered frame.
//! - **Clock**: embassy-time on TIM2's 32 bits ([`time_driver`]), which a sector erase's stall
//!   cannot set back, in place of embassy-stm32's 16-bit timer driver.
//! - **Watchdog**: the IWDG (its own LSI clock, 32 kHz nominal), timeout
//!   [`WATCHDOG_TIMEOUT_US`], fed by the node loop itself ([`pab_app::run_watched`]) at least
//!   every [`FEED_INTERVAL_US`], and given [`ERASE_WATCHDOG_TIMEOUT_US`] for each sector erase,
//!   during which the CPU cannot feed it ([`watchdog_for_erase`]); once started, nothing but a
//!   reset stops it.
//! - **Flash accelerator**: prefetch buffer and instruction/data caches on
//!   ([`enable_flash_prefetch_and_caches`]).
//!
//! Built with the workspace's `firmware` profile (fat LTO, one codegen unit, opt-level "s": the
//! root `Cargo.toml` says why). Build and flash: `cargo run --profile firmware -p pab-fw-f446
//! --target thumbv7em-none-eabihf` (the root `.cargo/config.toml` sets probe-rs as the runner).
//! Built, sized and panic-checked; not run on hardware yet.
//!
//! **Behind the bootloader** (feature `boot`; firmware/boot/nucleo-f446re): the program is
//! linked at the bootloader's ACTIVE partition, sector 5 (`memory-boot.x`), and the bootloader
//! takes sectors 0 to 3 and 6 to 7 (its own code, embassy-boot's state, the request sector, the
//! DFU partition). The key page stays in sector 4; the table store and the boot counter have no
//! sector left, so that build runs without either ([`NoStore`]: nothing loaded, every save
//! refused; a keyed node locked, refusing configuration, since it cannot count its boots):
//! docs/nucleo-f446re.md, "Bootloader". Not a firmware to deploy yet.

#![no_std]
#![no_main]

mod bxcan_bus;
mod recipient;
// Behind the bootloader (`boot`) nothing erases: no store, no boot counter.
#[cfg(not(feature = "boot"))]
mod sector_flash;
mod time_driver;

use core::num::{NonZeroU8, NonZeroU16};
use core::ops::Range;

use defmt::{info, unwrap};
use defmt_rtt as _;
use embassy_executor::Spawner;
use embassy_stm32::Peri;
use embassy_stm32::can::filter::Mask32;
use embassy_stm32::can::util::NominalBitTiming;
use embassy_stm32::can::{self, Can, Fifo};
use embassy_stm32::flash::Flash;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::pac::iwdg::vals::{Key, Pr};
use embassy_stm32::peripherals::{CAN1, IWDG};
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, rcc};
use embedded_storage::nor_flash::ReadNorFlash;
#[cfg(not(feature = "boot"))]
use pab_storage::{Blocking, BootCounter, FlashStore};
#[cfg(feature = "boot")]
use pab_storage::{CounterError, FlashErrorKind, SaveProgress, StoreError, TableStore};

// The boards' memcpy, memset, memcmp and 64-bit division (firmware/builtins).
use pab_builtins as _;

use bxcan_bus::BxcanBus;
use recipient::BoardRecipient;
#[cfg(not(feature = "boot"))]
use sector_flash::SectorFlash;

/// This node's id (1..=127): `PAB_NODE_ID` at build time, 1 without it. Tables pushed to the
/// node must be compiled for this id.
pub const NODE_ID: u8 = pab_app::parse_node_id(option_env!("PAB_NODE_ID"));

/// The nominal bit rate of the bus, bit/s.
pub const BITRATE: u32 = 500_000;

/// What this firmware says it is in its identity.
#[cfg(feature = "identity")]
const FIRMWARE: pab_app::Firmware = pab_app::firmware!("fw-f446");

/// The HSE: the 8 MHz clock the NUCLEO's ST-LINK puts out on its MCO pin, wired to the MCU's
/// OSC_IN (the board's factory configuration; no crystal is fitted at X3), so the HSE runs in
/// bypass mode.
const HSE_HZ: u32 = 8_000_000;
/// The PLL: 8 MHz / M = 2 MHz into the VCO (the reference manual's recommended input),
/// × N = 320 MHz, / P = 160 MHz.
const PLL_M: u32 = 4;
const PLL_N: u32 = 160;
const PLL_P: u32 = 2;
/// SYSCLK and HCLK: 160 MHz, within the 168 MHz that needs no over-drive (embassy turns it on
/// all the same), with 5 flash wait states at 3.3 V (embassy sets them).
pub const SYSCLK_HZ: u32 = HSE_HZ / PLL_M * PLL_N / PLL_P;
/// APB1 divides HCLK by 4: 40 MHz (at most 45 MHz), the bxCAN's clock.
const APB1_DIV: u32 = 4;
pub const PCLK1_HZ: u32 = SYSCLK_HZ / APB1_DIV;
/// TIM2's kernel clock: twice PCLK1, as for every APB timer whose bus is divided (RM0390,
/// clock tree), 80 MHz.
pub const TIM2_HZ: u32 = 2 * PCLK1_HZ;
const _: () = assert!(
    SYSCLK_HZ == 160_000_000 && PCLK1_HZ == 40_000_000 && HSE_HZ / PLL_M == 2_000_000,
    "the clock tree of `clocks()`"
);

/// Time quanta per bit: 1 (sync) + [`SEG1`] + [`SEG2`] = 16, sample point at 14/16 = 87.5 %
/// (CiA 301's recommendation for 500 kbit/s), as on the NUCLEO-G474RE.
const TQ_PER_BIT: u32 = 16;
const SEG1: u8 = 13;
const SEG2: u8 = 2;
/// Resynchronization jump width, in time quanta (at most [`SEG2`]; the bxCAN allows 4).
const SJW: u8 = 2;
const _: () =
    assert!(1 + SEG1 as u32 + SEG2 as u32 == TQ_PER_BIT && SJW <= SEG2 && SEG1 <= 16 && SEG2 <= 8);
/// APB1 cycles per time quantum: 40 MHz / (500 kbit/s * 16) = 5.
const PRESCALER: u32 = PCLK1_HZ / (BITRATE * TQ_PER_BIT);
const _: () = assert!(
    PRESCALER >= 1 && PRESCALER <= 1024 && PRESCALER * BITRATE * TQ_PER_BIT == PCLK1_HZ,
    "BITRATE must divide 40 MHz / 16 (e.g. 125, 250 or 500 kbit/s)"
);

/// The flash's small sectors (0 to 3) and large ones (5 to 7); sector 4 has 64 KiB.
pub const SMALL_SECTOR: u32 = 16 * 1024;
pub const LARGE_SECTOR: u32 = 128 * 1024;

/// The table store: sectors 1 to 3, 0x0800_4000..0x0801_0000 (offsets from the flash base, as
/// the flash driver counts them). The smallest sectors: a save erases one, and the CPU stalls
/// for as long as that takes (250 ms typical, 500 ms at most for 16 KiB; 1 s typical for a 128
/// KiB sector). Sector 0 would do too but holds the vector table, from which the chip boots.
pub const STORE_RANGE: Range<u32> = 0x4000..0x1_0000;
/// A ring of three slots, one sector each: every slot holds its 24-byte header and any image
/// the node's 8 KiB transfer buffer can receive; each sector is erased once per three saves.
pub const STORE_SLOT_SIZE: u32 = SMALL_SECTOR;
const _: () = assert!(
    STORE_SLOT_SIZE as usize >= 8192 + pab_storage::SLOT_HEADER_LEN
        && (STORE_RANGE.end - STORE_RANGE.start).is_multiple_of(STORE_SLOT_SIZE)
        && STORE_SLOT_SIZE.is_multiple_of(SMALL_SECTOR)
        && STORE_RANGE.start == SMALL_SECTOR
        && STORE_RANGE.end == 4 * SMALL_SECTOR,
    "the store: whole small sectors after sector 0, each slot the largest image plus its header"
);

/// The key page: sector 4 (64 KiB at 0x0801_0000), which holds nothing but the key record
/// (`pabctl keypage`), so that writing it (probe-rs erases the whole sector) touches nothing else.
/// The firmware never erases or writes it.
pub const KEY_PAGE: u32 = 0x1_0000;
/// The program: sector 5 (`memory.x`: `_stext`), between the key page and the boot counter.
pub const PROGRAM: Range<u32> = 0x2_0000..0x4_0000;
/// The boot counter: sectors 6 and 7 (0x0804_0000..0x0808_0000), the only two equal sectors
/// left. One 16-byte record per keyed boot, each sector erased once per 8 192 boots, at boot (a
/// stall of 1 s typical, 2 s at most).
pub const BOOT_COUNTER_RANGE: Range<u32> = 0x4_0000..0x8_0000;
const _: () = assert!(
    STORE_RANGE.end == KEY_PAGE
        && KEY_PAGE + 4 * SMALL_SECTOR == PROGRAM.start
        && PROGRAM.end - PROGRAM.start == LARGE_SECTOR
        && PROGRAM.end == BOOT_COUNTER_RANGE.start
        && BOOT_COUNTER_RANGE.end - BOOT_COUNTER_RANGE.start == 2 * LARGE_SECTOR
        && BOOT_COUNTER_RANGE.end == 512 * 1024,
    "store (sectors 1-3), key page (4), program (5) and boot counter (6-7) follow each other"
);

/// The longest sector erases, µs (the datasheet's maxima at x32 parallelism, which
/// [`sector_flash`] uses): a small sector (the store's), a large one (the boot counter's).
pub const SMALL_ERASE_MAX_US: u32 = 500_000;
pub const LARGE_ERASE_MAX_US: u32 = 2_000_000;

/// The IWDG's timeout, µs: a node loop that has not turned for this long resets the chip. Well
/// above the loop's longest step apart from an erase (a step of a table save programs 16 bytes:
/// four words, 400 µs at most) and the LSI's tolerance (below).
pub const WATCHDOG_TIMEOUT_US: u32 = 500_000;
/// How often the node loop feeds the IWDG at the latest, µs.
pub const FEED_INTERVAL_US: u64 = 100_000;
/// The IWDG's timeout while a sector erase stalls the CPU, µs ([`watchdog_for_erase`]).
pub const ERASE_WATCHDOG_TIMEOUT_US: u32 = 4_000_000;

/// The LSI's range (the datasheet: 17 to 47 kHz, 32 kHz typical): the IWDG's timeouts are
/// computed at 32 kHz, and a fast LSI makes them shorter by up to 32/47.
const LSI_MAX_HZ: u32 = 47_000;
const fn shortest_us(timeout_us: u32) -> u64 {
    timeout_us as u64 * embassy_stm32::rcc::LSI_FREQ.0 as u64 / LSI_MAX_HZ as u64
}
const _: () = assert!(
    shortest_us(WATCHDOG_TIMEOUT_US) >= 3 * FEED_INTERVAL_US
        && shortest_us(ERASE_WATCHDOG_TIMEOUT_US) > LARGE_ERASE_MAX_US as u64
        && LARGE_ERASE_MAX_US >= SMALL_ERASE_MAX_US,
    "the watchdog must outlast three feed intervals, and the longest erase, even on a fast LSI"
);

/// The IWDG's count, µs: its LSI (32 kHz) divided by 32, one count a millisecond, so that one
/// prescaler serves both timeouts (its 12-bit reload reaches 4.096 s).
const IWDG_TICK_US: u32 = 1_000_000 * 32 / embassy_stm32::rcc::LSI_FREQ.0;
const IWDG_PRESCALER: Pr = Pr::DIVIDE_BY32;
/// The counter runs from the reload value down to 0: reload + 1 counts make the timeout.
const IWDG_RELOAD: u16 = reload(WATCHDOG_TIMEOUT_US);
#[cfg(not(feature = "boot"))]
const IWDG_ERASE_RELOAD: u16 = reload(ERASE_WATCHDOG_TIMEOUT_US);
const fn reload(timeout_us: u32) -> u16 {
    let counts = timeout_us / IWDG_TICK_US;
    assert!(
        counts * IWDG_TICK_US == timeout_us && counts >= 1 && counts <= 0x1000,
        "a timeout must be a whole number of counts, at most 4096"
    );
    (counts - 1) as u16
}

/// The IWDG, driven through its registers with the prescaler and reload fixed at compile time,
/// as on the NUCLEO-G474RE (embassy's driver computes them at run time). Holds the peripheral,
/// so nothing else can drive it.
struct Iwdg {
    _peripheral: Peri<'static, IWDG>,
}

impl Iwdg {
    /// Starts the IWDG with a timeout of [`WATCHDOG_TIMEOUT_US`]; once started, nothing but a
    /// reset stops it. Called first thing at boot, before embassy's init takes the peripheral
    /// (handed over by [`Iwdg::claim`]): the IWDG runs on its own LSI, which it starts itself,
    /// so it needs no clock set up, and a boot that hangs (embassy waits for the HSE without a
    /// limit) ends in a reset.
    fn start() -> Started {
        // Frozen while a debugger halts the core (DBGMCU_APB1_FZ.DBG_IWDG_STOP): a breakpoint
        // would otherwise reset the board within the timeout. Without a debugger the bit
        // changes nothing.
        embassy_stm32::pac::DBGMCU
            .apb1fzr()
            .modify(|w| w.set_iwdg(true));
        let regs = embassy_stm32::pac::IWDG;
        // The ENABLE key unlocks the prescaler and reload registers.
        regs.kr().write(|w| w.set_key(Key::ENABLE));
        regs.pr().write(|w| w.set_pr(IWDG_PRESCALER));
        regs.rlr().write(|w| w.set_rl(IWDG_RELOAD));
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

/// Sets the IWDG's reload value and reloads the counter with it: a feed with another timeout.
/// The new value reaches the IWDG's own clock domain within five LSI cycles (SR.RVU clears);
/// a reload before then would still use the old one, and a write while RVU is set is lost.
#[cfg(not(feature = "boot"))]
fn reload_watchdog(reload: u16) {
    let regs = embassy_stm32::pac::IWDG;
    while regs.sr().read().rvu() {}
    regs.kr().write(|w| w.set_key(Key::ENABLE));
    regs.rlr().write(|w| w.set_rl(reload));
    while regs.sr().read().rvu() {}
    regs.kr().write(|w| w.set_key(Key::RESET));
}

/// Gives the IWDG [`ERASE_WATCHDOG_TIMEOUT_US`] from now: called by [`sector_flash`] just before
/// it starts a sector erase, during which the stalled CPU cannot feed it (the longest erase, a
/// 128 KiB sector of the boot counter, takes up to 2 s). A hang in the erase still resets the
/// chip, 4 s later.
#[cfg(not(feature = "boot"))]
pub(crate) fn watchdog_for_erase() {
    reload_watchdog(IWDG_ERASE_RELOAD);
}

/// Back to [`WATCHDOG_TIMEOUT_US`], from now: called by [`sector_flash`] once the erase is over.
#[cfg(not(feature = "boot"))]
pub(crate) fn watchdog_after_erase() {
    reload_watchdog(IWDG_RELOAD);
}

/// Says whether a watchdog reset the chip last (RCC_CSR.WDGRSTF, the IWDG's), then clears the
/// reset flags, so that the next boot reads only its own cause. A boot that hangs before the
/// node loop (no clock on OSC_IN) says so at every restart, every [`WATCHDOG_TIMEOUT_US`]; the
/// bus sees no heartbeat from it.
fn report_watchdog_reset() {
    let rcc = embassy_stm32::pac::RCC;
    if rcc.csr().read().wdgrstf() {
        defmt::error!("reset by the watchdog: the last boot or node loop hung");
    }
    rcc.csr().modify(|w| w.set_rmvf(true));
}

/// The IWDG, as the node loop feeds it, and LD2, which follows bit 19 of the microsecond clock
/// at each feed: it blinks at 0.95 Hz (a 2^20 µs period) while the node loop itself turns, and
/// stops with it (the NUCLEO-G474RE's, unchanged).
struct NodeWatchdog {
    watchdog: Iwdg,
    led: Output<'static>,
}

impl pab_app::Watchdog for NodeWatchdog {
    const FEED_INTERVAL_US: u64 = FEED_INTERVAL_US;

    #[inline(never)]
    fn feed(&mut self) {
        self.watchdog.feed();
        let level = pab_app::now().as_micros() & (1 << 19) != 0;
        self.led.set_level(level.into());
    }
}

// One handler for the four CAN1 lines (`bxcan_bus::Interrupt` serves whatever is pending), and
// the time driver's.
bind_interrupts!(struct Irqs {
    CAN1_TX => bxcan_bus::Interrupt;
    CAN1_RX0 => bxcan_bus::Interrupt;
    CAN1_RX1 => bxcan_bus::Interrupt;
    CAN1_SCE => bxcan_bus::Interrupt;
    TIM2 => time_driver::Interrupt;
});

// SAFETY: `Can::new` asks for the driver's four handlers bound to CAN1's lines, so that its
// flags are acknowledged. `bxcan_bus::Interrupt`, bound there instead, acknowledges each flag
// those handlers do (its doc lists them, against embassy-stm32 0.6's `can/bxcan/mod.rs`); what
// it leaves out (the wakers of the driver's `read` and `write`, a sleep acknowledgement) serves
// driver calls this firmware never makes.
unsafe impl
    embassy_stm32::interrupt::typelevel::Binding<
        embassy_stm32::interrupt::typelevel::CAN1_TX,
        can::TxInterruptHandler<CAN1>,
    > for Irqs
{
}
// SAFETY: as above.
unsafe impl
    embassy_stm32::interrupt::typelevel::Binding<
        embassy_stm32::interrupt::typelevel::CAN1_RX0,
        can::Rx0InterruptHandler<CAN1>,
    > for Irqs
{
}
// SAFETY: as above.
unsafe impl
    embassy_stm32::interrupt::typelevel::Binding<
        embassy_stm32::interrupt::typelevel::CAN1_RX1,
        can::Rx1InterruptHandler<CAN1>,
    > for Irqs
{
}
// SAFETY: as above.
unsafe impl
    embassy_stm32::interrupt::typelevel::Binding<
        embassy_stm32::interrupt::typelevel::CAN1_SCE,
        can::SceInterruptHandler<CAN1>,
    > for Irqs
{
}

/// Turns on the flash's prefetch buffer and its instruction and data caches (the ART
/// accelerator, FLASH_ACR PRFTEN, ICEN, DCEN).
///
/// Why: at 160 MHz the flash needs 5 wait states, and embassy-stm32 0.6's clock set-up writes
/// FLASH_ACR whole with only the latency (`rcc/f247.rs`), which leaves prefetch and both caches
/// off: every fetch would wait for them. The caches held nothing while they were off, so they
/// are turned on without a reset. Flash writes stay coherent: [`sector_flash`] resets the data
/// cache after every erase and program.
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
    time_driver::start(p.TIM2);
    info!(
        "pab node {} on NUCLEO-F446RE, CAN {} kbit/s",
        NODE_ID,
        BITRATE / 1000
    );

    let led = Output::new(p.PA5, Level::Low, Speed::Low);

    let mut can = Can::new(p.CAN1, p.PA11, p.PA12, Irqs);
    can.modify_config().set_bit_timing(NominalBitTiming {
        prescaler: unwrap!(NonZeroU16::new(PRESCALER as u16)),
        seg1: unwrap!(NonZeroU8::new(SEG1)),
        seg2: unwrap!(NonZeroU8::new(SEG2)),
        sync_jump_width: unwrap!(NonZeroU8::new(SJW)),
    });
    // Filter bank 0: a 32-bit mask of zeros, every frame (standard or extended, data or remote)
    // into FIFO 0. FIFO 1 stays unused, so frames are read in the order they arrived.
    can.modify_filters()
        .enable_bank(0, Fifo::Fifo0, Mask32::accept_all());
    let mut bus = BxcanBus::new(can);

    let mut flash = p.FLASH;
    let config = unwrap!(pab_app::Config::new(NODE_ID));
    // Built in place in the task's future, as on the NUCLEO-G474RE (the node loop runs in this
    // frame).
    let mut node = pab_app::BoardNode::new(config, pab_app::now());
    // Who it is: the chip's 96-bit factory UID. No configuration page yet (its flash has no
    // free pair of sectors of one size: docs/nucleo-f446re.md): the compiled node id, and a bit
    // rate the node does not set over the bus (0: Configure is answered Unsupported).
    #[cfg(feature = "identity")]
    {
        node.set_identity(FIRMWARE, embassy_stm32::uid::uid());
        node.set_settings(Ok(None), 0, pab_app::now());
    }
    // The key before anything else: a page that cannot be read counts as truncated (locked).
    let mut page = [0u8; pab_core::auth::page::LEN];
    let page: &[u8] = match Flash::new_blocking(flash.reborrow()).read(KEY_PAGE, &mut page) {
        Ok(()) => &page,
        Err(_) => &[],
    };
    #[cfg(not(feature = "boot"))]
    pab_app::key_from_page(&mut node, page, || {
        let counter = SectorFlash::<LARGE_SECTOR>::new(
            Flash::new_blocking(flash.reborrow()),
            BOOT_COUNTER_RANGE,
        );
        BootCounter::new(counter, BOOT_COUNTER_RANGE)?.increment()
    });
    #[cfg(not(feature = "boot"))]
    let store_flash = SectorFlash::<SMALL_SECTOR>::new(Flash::new_blocking(flash), STORE_RANGE);
    #[cfg(not(feature = "boot"))]
    let mut store = unwrap!(FlashStore::new(
        Blocking(store_flash),
        STORE_RANGE,
        STORE_SLOT_SIZE
    ));
    // Behind the bootloader: no boot counter (a keyed node locks) and no table store.
    #[cfg(feature = "boot")]
    pab_app::key_from_page(&mut node, page, || {
        Err(CounterError::Flash(FlashErrorKind::OutOfBounds))
    });
    #[cfg(feature = "boot")]
    let mut store = NoStore;
    // Only the node loop feeds it from here on (once before the node's boot, then every turn).
    let watchdog = Iwdg::claim(started, p.IWDG);
    let mut recipient = BoardRecipient::new();
    let mut watchdog = NodeWatchdog { watchdog, led };
    pab_app::run_watched(
        &mut node,
        &mut bus,
        &mut store,
        &mut recipient,
        &mut watchdog,
    )
    .await
}

/// The table store behind the bootloader: none. embassy-boot's swap takes the 128 KiB sectors
/// 5 to 7 and the bootloader sectors 0 to 3 (its code, its state, the request), so the ring of
/// 16 KiB slots has no sector left (docs/nucleo-f446re.md, "Bootloader"). Nothing is ever loaded
/// and every save is refused (out of bounds), which the node reports as a failed store; a table
/// pushed still runs until the next reset.
#[cfg(feature = "boot")]
struct NoStore;

#[cfg(feature = "boot")]
impl TableStore for NoStore {
    fn load<'b>(&mut self, _: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        Ok(None)
    }

    fn start_save(&mut self, _: &[u8]) -> Result<(), StoreError> {
        Err(StoreError::Flash(FlashErrorKind::OutOfBounds))
    }

    fn continue_save(&mut self, _: &[u8]) -> Result<SaveProgress, StoreError> {
        Err(StoreError::NoSave)
    }
}

/// HSE 8 MHz in bypass (the ST-LINK's MCO); SYSCLK 160 MHz from the PLL (8 / 4 * 160 / 2); APB1
/// 40 MHz (the bxCAN; TIM2 at 80 MHz), APB2 80 MHz; HSI off once the PLL runs; LSI on (the
/// IWDG's), RTC off.
fn clocks() -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(rcc::Hse {
        freq: Hertz(HSE_HZ),
        mode: rcc::HseMode::Bypass,
    });
    config.rcc.pll_src = rcc::PllSource::HSE;
    config.rcc.pll = Some(rcc::Pll {
        prediv: rcc::PllPreDiv::DIV4,
        mul: rcc::PllMul::MUL160,
        divp: Some(rcc::PllPDiv::DIV2),
        divq: None,
        divr: None,
    });
    config.rcc.sys = rcc::Sysclk::PLL1_P;
    config.rcc.hsi = false;
    config.rcc.ahb_pre = rcc::AHBPrescaler::DIV1;
    config.rcc.apb1_pre = rcc::APBPrescaler::DIV4;
    config.rcc.apb2_pre = rcc::APBPrescaler::DIV2;
    // The RTC unclocked: nothing here uses it (as on the NUCLEO-G474RE). The LSI stays on: the
    // IWDG runs from it.
    config.rcc.ls = rcc::LsConfig {
        rtc: rcc::RtcClockSource::DISABLE,
        lsi: true,
        lse: None,
    };
    config
}

/// A panic says so over defmt and stops on a permanently undefined instruction, as on the
/// NUCLEO-G474RE (whose `main.rs` says why this handler, and why `inline(always)`): only
/// embassy's own checks can get here (`scripts/panic-check.sh` finds no panic site in the
/// project's crates), and where it happened only in a build with `PAB_PANIC_LOCATION=1`.
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
/// stop as [`panic()`] does.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    cortex_m::asm::udf()
}
