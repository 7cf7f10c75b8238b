//! The node loop's watchdog on the emulated board: the CMSDK APB watchdog ([`cmsdk::Watchdog`]).
//!
//! Started with a countdown of [`HALF_TIMEOUT_MS`]: when the node loop has not fed it for that
//! long it raises its interrupt (the NMI: the board says so on QEMU's stderr), and after as long
//! again it resets the machine. The node loop ([`pab_app::run_watched`]) feeds it at every turn
//! and turns at least every [`FEED_INTERVAL_US`], so only a loop that is stuck lets it fire.
//! QEMU's reset reloads the program and keeps the table store (see [`crate::ram_flash`]).

use core::sync::atomic::{AtomicBool, Ordering};

use pab_core::decimal::Decimal;

use crate::cmsdk::{self, PCLK_HZ};
use crate::semihosting;

/// Milliseconds without a feed until the NMI; as long again until the reset.
pub const HALF_TIMEOUT_MS: u32 = 250;
/// How often the node loop feeds at the latest, µs (well below [`HALF_TIMEOUT_MS`]).
pub const FEED_INTERVAL_US: u64 = 100_000;
const _: () = assert!(FEED_INTERVAL_US * 2 <= HALF_TIMEOUT_MS as u64 * 1000);

/// The started watchdog; feeding it is what the node loop does.
pub struct BoardWatchdog(());

impl BoardWatchdog {
    /// Starts the watchdog: from now on the machine resets unless fed every
    /// 2 × [`HALF_TIMEOUT_MS`]. Call once.
    pub fn start() -> Self {
        let dog = cmsdk::Watchdog;
        dog.unlock(true);
        dog.set_load(PCLK_HZ / 1000 * HALF_TIMEOUT_MS);
        dog.set_control(cmsdk::Watchdog::INTEN | cmsdk::Watchdog::RESEN);
        dog.unlock(false);
        BoardWatchdog(())
    }
}

impl pab_app::Watchdog for BoardWatchdog {
    const FEED_INTERVAL_US: u64 = FEED_INTERVAL_US;

    /// Out of line: the node loop's two feeds inlined it (40 bytes of the emulated board's
    /// flash).
    #[inline(never)]
    fn feed(&mut self) {
        let dog = cmsdk::Watchdog;
        dog.unlock(true);
        dog.clear();
        dog.unlock(false);
    }

    /// A system reset (SYSRESETREQ; QEMU's `system_reset`): the RAM-backed flash is kept.
    fn restart(&mut self) {
        cortex_m::peripheral::SCB::sys_reset()
    }
}

/// The watchdog's first expiry (its interrupt is the NMI): say it once on QEMU's stderr. The
/// interrupt stays raised, so the next expiry resets the machine.
pub fn on_nmi() {
    static SAID: AtomicBool = AtomicBool::new(false);
    if !SAID.swap(true, Ordering::Relaxed) {
        // Through `Decimal`: the board has no `core::fmt` integer formatter (logger.rs).
        let half = Decimal::new(HALF_TIMEOUT_MS);
        semihosting::eprint(format_args!(
            "pab-fw-an386: watchdog: the node loop has not fed it for {half} ms; reset in {half} ms\n"
        ));
    }
}
