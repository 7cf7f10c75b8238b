//! # pab-fw-an386: the pab node on the emulated Cortex-M4 (QEMU `mps2-an386`)
//!
//! The node application of `pab-app` (arbitration, heartbeat, faults, diagnostic stream, table
//! transfers), as on the NUCLEO-G474RE, under embassy's Cortex-M executor (the interrupt
//! executor: see [`EXECUTOR`]), with:
//!
//! - **CAN**: SLCAN on UART0 ([`pab_fw_an386::slcan_bus`]); on the host, `slcand` attaches the
//!   kernel's `slcan` driver to QEMU's pseudo-terminal and `cangw` routes `slcan0` to the bus.
//! - **Time**: embassy-time at 1 MHz from the CMSDK timers ([`pab_fw_an386::time_driver`]).
//! - **Table store**: `pab-storage` over 48 KiB of code RAM with NOR flash semantics, four
//!   12 KiB slots as on the G474 ([`pab_fw_an386::ram_flash`]): kept across QEMU's
//!   `system_reset`, lost when QEMU exits.
//! - **Key**: the key page at 0x0004_E000 in the same RAM
//!   ([`pab_fw_an386::ram_flash::KEY_PAGE`]), planted by QEMU's loader (`PAB_KEY_PAGE=page.bin`
//!   with the cargo runner, scripts/run-thumbv7em.sh), and the boot counter in the two pages
//!   below it ([`pab_fw_an386::ram_flash::BOOT_COUNTER_RANGE`]), as on the G474
//!   ([`pab_app::key_from_page`]). One difference: a page of all zeros, what QEMU's fresh RAM
//!   holds when nothing was planted, counts as erased (no key), where the G474 would lock. The
//!   boot counter lives as long as the QEMU process: a new QEMU counts from 1 again, so its boot
//!   salts repeat across QEMU processes with one key. The emulated board is for tests: never
//!   give it a key that a real node uses.
//! - **Node id and bit rate**: from the configuration page ([`pab_fw_an386::ram_flash::SETTINGS_RANGE`],
//!   set over the bus: `pabctl assign`, `pabctl config`); an erased page gives [`NODE_ID`], from
//!   `PAB_NODE_ID` at build time (default 1; `unassigned` for none), and [`BITRATE_KBPS`]. The
//!   emulated link has no bit timing (SLCAN's rate is the host's `slcand -s6`): the board keeps
//!   and reports the rate, and its trial passes once it hears a frame.
//! - **Unique id**: the 12 bytes at [`pab_fw_an386::ram_flash::UID_PAGE`], planted by a test
//!   (QEMU's loader, `PAB_UID_PAGE=uid.bin`); zeros when nothing was planted.
//! - **Log**: `log` on QEMU's standard error through semihosting (run QEMU with
//!   `-semihosting-config enable=on,target=native`).
//! - **Watchdog**: the CMSDK APB watchdog, started first at boot and fed by the node loop; a boot
//!   or a loop stuck for 500 ms resets the machine ([`pab_fw_an386::watchdog`]).
//! - **Stack**: below the static data (flip-link, the linker in `.cargo/config.toml`): an
//!   overflow runs off the RAM's start instead of writing over the node (scripts/watchdog-test.sh
//!   shows it, and what QEMU makes of it: docs/no-panic-and-watchdog.md).
//! - **Feature `hang-test`** (tests only: scripts/watchdog-test.sh): the node loop spins forever
//!   on receiving the frame [`hang::TRIGGER_ID`], and recurses until its stack overflows on
//!   [`hang::OVERFLOW_ID`], to show the watchdog's reset and the stack's guard. The production
//!   build has no such frame.
//!
//! Run: `cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf -- -serial pty`
//! (docs/mps2-an386.md has the whole bridge).

#![no_std]
#![no_main]

use embassy_executor::InterruptExecutor;
use embedded_storage::nor_flash::ReadNorFlash;
use pab_core::decimal::Decimal;
use pab_fw_an386::interrupts::{self, Interrupt};
use pab_fw_an386::ram_flash::{BOOT_COUNTER_RANGE, KEY_PAGE, RamFlash, STORE_RANGE};
#[cfg(feature = "identity")]
use pab_fw_an386::ram_flash::{SETTINGS_RANGE, UID_PAGE};
use pab_fw_an386::slcan_bus::SlcanBus;
use pab_fw_an386::time_driver::TimeDriver;
use pab_fw_an386::watchdog::{self, BoardWatchdog};
use pab_fw_an386::{logger, semihosting, uart};
#[cfg(feature = "identity")]
use pab_storage::TableStore;
use pab_storage::{BootCounter, FlashStore};

/// This node's id (1..=127): `PAB_NODE_ID` at build time, 1 without it. Tables pushed to the
/// node must be compiled for this id.
pub const NODE_ID: u8 = pab_app::parse_node_id(option_env!("PAB_NODE_ID"));

/// The bit rate of an erased configuration page, kbit/s: the G474's.
pub const BITRATE_KBPS: u16 = 500;

/// What this firmware says it is in its identity.
#[cfg(feature = "identity")]
const FIRMWARE: pab_app::Firmware = pab_app::firmware!("fw-an386");

/// A ring of four slots of 12 KiB (three pages) each, the G474's layout: every slot holds its
/// 24-byte header and any image the node's 8 KiB transfer buffer can receive.
pub const STORE_SLOT_SIZE: u32 = 12 * 1024;
const _: () = assert!(
    STORE_SLOT_SIZE as usize >= 8192 + pab_storage::SLOT_HEADER_LEN
        && (STORE_RANGE.end - STORE_RANGE.start).is_multiple_of(STORE_SLOT_SIZE),
    "a slot must hold the largest image plus its header, and the region whole slots"
);

/// The store over the RAM-backed flash.
type Store = FlashStore<RamFlash>;

/// The node's store: with the feature `update`, the table store and the bootloader's update
/// slot (the DFU partition and the request page: pab_boot_an386's layout).
#[cfg(not(feature = "update"))]
type NodeStore = Store;
#[cfg(feature = "update")]
type NodeStore = pab_storage::WithUpdate<Store, pab_boot_an386::Dfu, pab_boot_an386::RequestPage>;

embassy_time_driver::time_driver_impl!(static TIME: TimeDriver = TimeDriver::new());

/// The executor: embassy's interrupt executor on [`Interrupt::SOFTWARE`], below the devices'
/// interrupts (priority 0), which preempt the tasks. Why not the thread executor: it idles in
/// WFE, which QEMU 7.2 (Debian 12's) treats as a yield, not a sleep, so an idle board would keep a
/// host core busy; thread mode here sleeps in WFI, which QEMU does honour, and the executor runs
/// in its interrupt when there is work.
static EXECUTOR: InterruptExecutor = InterruptExecutor::new();
/// Priority of the executor's interrupt: the lowest (the devices keep 0, the highest).
const EXECUTOR_PRIORITY: u8 = 0xE0;

#[cortex_m_rt::entry]
fn main() -> ! {
    // The watchdog first: a boot that hangs ends in a reset, as a stuck loop does. From here on
    // only the node loop feeds it (it feeds once before the node's boot).
    let watchdog = BoardWatchdog::start();
    logger::init(log::LevelFilter::Info);
    TIME.start();
    uart::init();
    // Through pab-app's out-of-line `log`, as its own messages: `log::info!` would inline
    // `log`'s record building here for this one line.
    pab_app::log(
        log::Level::Info,
        module_path!(),
        format_args!(
            "pab node {} on the emulated Cortex-M4 (mps2-an386), SLCAN on UART0",
            Decimal::new(u32::from(NODE_ID))
        ),
    );

    // SAFETY: called once; memory.x keeps the program below the RAM-backed flash.
    let flash = unsafe { RamFlash::take() };
    interrupts::set_priority(Interrupt::SOFTWARE, EXECUTOR_PRIORITY);
    let spawner = EXECUTOR.start(Interrupt::SOFTWARE);
    match node_task(flash, watchdog) {
        Ok(task) => spawner.spawn(task),
        Err(_) => fail(format_args!("cannot spawn the node task")),
    }
    loop {
        cortex_m::asm::wfi();
    }
}

/// Builds the node and runs it forever, feeding the watchdog. The node is built here, in place
/// in the task's future (a `static`), as on the NUCLEO boards: built in `main` and moved into a
/// `static`, it sat in `main`'s frame first, 42 KB of stack under everything after.
#[embassy_executor::task]
#[cfg_attr(
    feature = "hang-at-start",
    allow(unreachable_code, unused_variables, unused_mut)
)]
async fn node_task(flash: RamFlash, mut watchdog: BoardWatchdog) {
    // Tests only: a firmware that never comes up (the HIL update test's v2 that hangs at start):
    // the watchdog resets the board, and the bootloader reverts the update it never confirmed.
    #[cfg(feature = "hang-at-start")]
    loop {
        cortex_m::asm::nop();
    }
    #[cfg(feature = "identity")]
    #[cfg_attr(feature = "update", allow(unused_mut))]
    let (config, loaded, bitrate, mut store) = configured(flash);
    #[cfg(not(feature = "identity"))]
    let (config, mut store) = configured(flash);
    #[cfg(feature = "update")]
    let mut store = with_update(store);
    let mut node = pab_app::BoardNode::new(config, pab_app::now());
    #[cfg(feature = "identity")]
    {
        let mut uid = [0u8; pab_core::identity::UID_LEN];
        let _ = flash_of(&mut store).read(UID_PAGE, &mut uid);
        node.set_identity(FIRMWARE, uid);
        node.set_settings(loaded, bitrate, pab_app::now());
    }
    // The SLCAN device's serial number: the node's address (an unassigned node's comes from its
    // uid).
    let mut bus = bus(SlcanBus::new(hex4(node.config().node_id)));
    key(&mut node, flash_of(&mut store));
    pab_app::run_watched(&mut node, &mut bus, &mut store, &mut (), &mut watchdog).await
}

/// The RAM-backed flash under the node's store.
fn flash_of(store: &mut NodeStore) -> &mut RamFlash {
    #[cfg(feature = "update")]
    let store = &mut store.store;
    store.flash_mut()
}

/// The table store with the bootloader's update slot: the DFU partition's first
/// `ACTIVE_LEN` bytes and the request page.
#[cfg(feature = "update")]
fn with_update(store: Store) -> NodeStore {
    use pab_boot_an386::{Dfu, RequestPage, layout};
    // SAFETY: one handle each for the firmware's life: the bootloader does not run while the
    // application does, and nothing else here takes them.
    let (dfu, request) = unsafe { (Dfu::take(), RequestPage::take()) };
    match pab_storage::UpdateSlot::new(dfu, request, layout::ACTIVE_LEN as u32) {
        Ok(slot) => pab_storage::WithUpdate::new(store, slot, confirm),
        Err(_) => fail(format_args!(
            "update slot: the bootloader's layout does not fit"
        )),
    }
}

/// Confirms the running firmware to the bootloader (embassy-boot's `mark_booted`).
#[cfg(feature = "update")]
fn confirm() -> bool {
    pab_fw_an386::boot::mark_booted().is_ok()
}

/// The node's configuration and its store, from the compiled node id (without the feature
/// `identity`).
#[cfg(not(feature = "identity"))]
fn configured(flash: RamFlash) -> (pab_app::Config, Store) {
    let config = match pab_app::Config::new(NODE_ID) {
        Ok(config) => config,
        Err(error) => fail(format_args!("configuration: {error}")),
    };
    match FlashStore::new(flash, STORE_RANGE, STORE_SLOT_SIZE) {
        Ok(store) => (config, store),
        Err(error) => store_failed(error),
    }
}

/// What the configuration page held: the settings record, if any (`TableStore::load_settings`).
#[cfg(feature = "identity")]
type Loaded = Result<Option<u16>, pab_storage::StoreError>;

/// The node's configuration, its stored settings, the bit rate to start at and its store, with
/// identity and configuration over the bus: the node id and bit rate from the configuration
/// page (else the compiled ones).
#[cfg(feature = "identity")]
fn configured(flash: RamFlash) -> (pab_app::Config, Loaded, u16, Store) {
    let mut store = match FlashStore::new(flash, STORE_RANGE, STORE_SLOT_SIZE)
        .and_then(|store| store.with_settings(SETTINGS_RANGE))
    {
        Ok(store) => store,
        Err(error) => store_failed(error),
    };
    let loaded = store.load_settings();
    let settings = pab_app::Settings::from_loaded(&loaded);
    let node_id = settings.node_id.or((NODE_ID != 0).then_some(NODE_ID));
    // Cannot fail: the record's id is 1..=127 and NODE_ID is checked at compile time. Not
    // displayed: the error's formatting took 590 bytes of flash (core::fmt's integers).
    let config =
        pab_app::Config::for_node(node_id).unwrap_or_else(|_| pab_app::Config::unassigned());
    let bitrate = settings.start_bitrate(BITRATE_KBPS);
    (config, loaded, bitrate, store)
}

/// Stops on a store that cannot be opened: its layout's constants do not fit the RAM-backed
/// flash (a build's mistake; opening reads nothing but the configuration page). Not displayed:
/// `StoreError`'s words took 550 bytes of flash once the node was built in its task.
fn store_failed(_: pab_storage::StoreError) -> ! {
    fail(format_args!(
        "table store: STORE_RANGE, STORE_SLOT_SIZE or SETTINGS_RANGE do not fit the flash"
    ))
}

/// Keys the node from its key page, counting the boot (`pab_app::key_from_page`).
fn key(node: &mut pab_app::BoardNode, flash: &mut RamFlash) {
    let mut page = [0u8; pab_core::auth::page::LEN];
    let page: &[u8] = match flash.read(KEY_PAGE, &mut page) {
        // QEMU's fresh RAM, nothing planted: the emulation's erased page.
        Ok(()) if page.iter().all(|&byte| byte == 0) => &[0xFF; pab_core::auth::page::LEN],
        Ok(()) => &page,
        Err(_) => &[],
    };
    pab_app::key_from_page(node, page, || {
        BootCounter::new(&mut *flash, BOOT_COUNTER_RANGE)?.increment()
    });
}

/// The node's bus: SLCAN on UART0.
#[cfg(not(feature = "hang-test"))]
type Bus = SlcanBus;

#[cfg(not(feature = "hang-test"))]
fn bus(slcan: SlcanBus) -> Bus {
    slcan
}

#[cfg(feature = "hang-test")]
fn bus(slcan: SlcanBus) -> Bus {
    hang::HangOnTrigger::new(slcan)
}

#[cfg(feature = "hang-test")]
type Bus = hang::HangOnTrigger;

/// The test build's bus: hangs the node loop on a trigger frame.
#[cfg(feature = "hang-test")]
mod hang {
    use pab_app::{BusError, CanBus};
    use pab_core::Frame;
    use pab_core::decimal::Decimal;
    use pab_fw_an386::semihosting;
    use pab_fw_an386::slcan_bus::SlcanBus;

    /// The frame that hangs the loop: extended id 0x1FFF_FFFF (no pab service uses it).
    pub const TRIGGER_ID: u32 = 0x1FFF_FFFF;
    /// The frame that overflows the stack: extended id 0x1FFF_FFFE.
    pub const OVERFLOW_ID: u32 = 0x1FFF_FFFE;

    /// SLCAN, but a received [`TRIGGER_ID`] frame never returns: the node loop spins in its
    /// receive, interrupts still run, and nothing feeds the watchdog; a received [`OVERFLOW_ID`]
    /// frame recurses until the stack overflows ([`overflow`]).
    pub struct HangOnTrigger(SlcanBus);

    impl HangOnTrigger {
        pub fn new(bus: SlcanBus) -> Self {
            HangOnTrigger(bus)
        }
    }

    impl CanBus for HangOnTrigger {
        async fn receive(&mut self) -> Result<Frame, BusError> {
            let frame = self.0.receive().await?;
            if frame.raw_id() == (TRIGGER_ID, true) {
                semihosting::eprint(format_args!(
                    "pab-fw-an386: hang-test: the node loop spins\n"
                ));
                loop {
                    core::hint::spin_loop();
                }
            }
            if frame.raw_id() == (OVERFLOW_ID, true) {
                semihosting::eprint(format_args!(
                    "pab-fw-an386: hang-test: the stack overflows\n"
                ));
                overflow(0);
            }
            Ok(frame)
        }

        async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
            self.0.transmit(frame).await
        }
    }

    unsafe extern "C" {
        // cortex-m-rt's link.x: where the static data (.data, .bss, .uninit) begin and end.
        static __sdata: u8;
        static __euninit: u8;
    }

    /// Recurses with 64 bytes of its own a call, checking at each where its frame lies: with
    /// the stack below the statics, the recursion runs off the RAM's start and faults; without,
    /// its frames come into the static data, which it says before it fails the emulation.
    #[inline(never)]
    #[allow(unconditional_recursion)]
    fn overflow(depth: u32) -> u32 {
        let frame = core::hint::black_box([depth; 16]);
        let at = core::ptr::addr_of!(frame) as usize;
        // Only the symbols' addresses, never their contents.
        let statics =
            core::ptr::addr_of!(__sdata) as usize..core::ptr::addr_of!(__euninit) as usize;
        if statics.contains(&at) {
            semihosting::eprint(format_args!(
                "pab-fw-an386: hang-test: the stack ran into the static data at depth {}\n",
                Decimal::new(depth)
            ));
            semihosting::exit(false)
        }
        overflow(depth.wrapping_add(1)).wrapping_add(frame[3])
    }
}

/// The node id as four hex digits, for SLCAN's `N` (serial number).
fn hex4(id: u8) -> [u8; 4] {
    let hex = b"0123456789ABCDEF";
    let digit = |nibble: u8| hex.get(usize::from(nibble)).copied().unwrap_or(b'0');
    [b'0', b'0', digit(id >> 4), digit(id & 0xF)]
}

/// Says why on QEMU's stderr and ends the emulation with a failure status.
fn fail(why: core::fmt::Arguments<'_>) -> ! {
    semihosting::eprint(format_args!("pab-fw-an386: {why}\n"));
    semihosting::exit(false)
}

#[unsafe(no_mangle)]
extern "C" fn TIMER0() {
    TIME.on_period();
}

#[unsafe(no_mangle)]
extern "C" fn TIMER1() {
    TIME.on_alarm();
}

#[unsafe(no_mangle)]
extern "C" fn UART0RX() {
    uart::on_rx_interrupt();
}

#[unsafe(no_mangle)]
extern "C" fn UART0TX() {
    uart::on_tx_interrupt();
}

#[unsafe(no_mangle)]
extern "C" fn SOFTWARE() {
    // SAFETY: this is the interrupt `EXECUTOR` was started on.
    unsafe { EXECUTOR.on_interrupt() }
}

/// The watchdog's interrupt (QEMU wires it to the NMI).
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    watchdog::on_nmi();
}

/// Says so on QEMU's stderr, and fails the emulation. With `PAB_PANIC_LOCATION=1` at build time
/// (build.rs), where and why: the text of `{info}` (`panicked at FILE:LINE:COLUMN:` and the
/// message on the next line), written out here so that the file's name goes through
/// `write_str`, not through `&str`'s `Display` (which pads), and the line and column through
/// `Decimal`, not through `u32`'s `Display` (see [`pab_core::decimal`]). Without it, every panic
/// site's location and message leave the flash (1 296 bytes, which sealed coordination needed):
/// a panic seen in a test run is found again in a build with the variable.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    #[cfg(panic_location)]
    match info.location() {
        Some(at) => fail(format_args!(
            "panic: panicked at {}:{}:{}:\n{}",
            Verbatim(at.file()),
            Decimal::new(at.line()),
            Decimal::new(at.column()),
            info.message()
        )),
        None => fail(format_args!("panic: panicked:\n{}", info.message())),
    }
    #[cfg(not(panic_location))]
    {
        let _ = info;
        fail(format_args!(
            "panic: panicked (PAB_PANIC_LOCATION=1 builds say where)"
        ))
    }
}

/// A string written as it is (`write_str`): no width, no padding to look for.
#[cfg(panic_location)]
struct Verbatim<'a>(&'a str);

#[cfg(panic_location)]
impl core::fmt::Display for Verbatim<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.0)
    }
}
