//! The firmware: a pab node on an STM32F405 with an 8 MHz crystal, CAN1 on PB8 (RX) and PB9 (TX)
//! through a transceiver at 500 kbit/s, an LED on PC13. stm32f4xx-hal and its bxCAN driver, a
//! superloop; no embassy anywhere (`cargo tree -p pab-own-driver --features board -e normal`
//! shows none, and `./test.sh` checks it). Change the pins, the crystal and the node id for your
//! board.
//!
//! Build: `cargo build -p pab-own-driver --features board --target thumbv7em-none-eabihf
//! --profile firmware`; flash the ELF with your probe (`probe-rs run --chip STM32F405RGTx`).
//!
//! The table lives in RAM (pab-storage's `MemFlash`): a reset loses it, and the node boots
//! without one until a tool pushes it again. The F405's own flash would keep it
//! (`pab_storage::FlashStore` over stm32f4xx-hal's `UnlockedFlash` in `pab_storage::Blocking`),
//! but the chip cannot run code while it erases one of its 128 KiB sectors, which takes seconds
//! by its datasheet: the loop would stop for that long at each save, and the watchdog's timeout
//! would have to cover it. An external flash, or a part that erases in the background (the
//! NUCLEO-G474RE's second bank), keeps the loop going.

#![no_std]
#![no_main]

use bxcan::Fifo;
use bxcan::filter::Mask32;
use cortex_m_rt::entry;
use pab_app::{BoardNode, Config, EmbeddedCan, Watchdog};
use pab_own_driver::{Micros32, OwnDriverNode};
use pab_storage::FlashStore;
use pab_storage::testing::MemFlash;
use static_cell::StaticCell;
use stm32f4xx_hal::gpio::PinState;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config as Clocks;
use stm32f4xx_hal::watchdog::IndependentWatchdog;

/// This board's node id (1 to 127).
const NODE_ID: u8 = 1;

/// bxCAN's bit timing register for 500 kbit/s from the 42 MHz APB1 clock: prescaler 6 (7 MHz,
/// 14 time quanta a bit), BS1 11, BS2 2 (sample point at 85.7 %), SJW 1.
const BTR_500K_AT_42MHZ: u32 = 0x001A_0005;

/// The table store: two 12 KiB slots in RAM (pages of 4 KiB, 8-byte writes), each room for the
/// largest table a `BoardNode` takes (8 KiB) and the slot's header.
type RamFlash = MemFlash<6, 4096, 8>;

/// The independent watchdog, fed by the node loop at every turn.
struct Iwdg(IndependentWatchdog);

impl Watchdog for Iwdg {
    /// The loop turns continuously (a superloop); this is what it promises at least.
    const FEED_INTERVAL_US: u64 = 100_000;

    fn feed(&mut self) {
        self.0.feed();
    }
}

static NODE: StaticCell<BoardNode> = StaticCell::new();
static STORE: StaticCell<FlashStore<RamFlash>> = StaticCell::new();

#[entry]
fn main() -> ! {
    let Some(dp) = pac::Peripherals::take() else {
        halt()
    };
    // The watchdog first, before the clocks and the bus: a hang anywhere from here resets.
    let mut watchdog = IndependentWatchdog::new(dp.IWDG);
    watchdog.start(500.millis());

    let mut rcc = dp
        .RCC
        .freeze(Clocks::hse(8.MHz()).sysclk(168.MHz()).pclk1(42.MHz()));

    // The node's clock: TIM2 (32 bits) counting microseconds, free-running.
    let mut tim2 = dp.TIM2.counter_us(&mut rcc);
    if tim2.start(u32::MAX.micros()).is_err() {
        halt()
    }
    let clock = Micros32::new(move || tim2.now().ticks());

    // bxCAN through stm32f4xx-hal: 500 kbit/s, every frame into FIFO 0 (the node filters).
    let gpiob = dp.GPIOB.split(&mut rcc);
    let can1 = dp.CAN1.can((gpiob.pb9, gpiob.pb8), &mut rcc);
    let mut can = bxcan::Can::builder(can1)
        .set_bit_timing(BTR_500K_AT_42MHZ)
        .enable();
    can.modify_filters()
        .enable_bank(0, Fifo::Fifo0, Mask32::accept_all());

    let gpioc = dp.GPIOC.split(&mut rcc);
    let mut led = gpioc.pc13.into_push_pull_output();

    let Ok(config) = Config::new(NODE_ID) else {
        halt()
    };
    let Ok(store) = FlashStore::new(RamFlash::new(), 0..6 * 4096, 12 * 1024) else {
        halt()
    };
    let store = STORE.init(store);
    let mut bus = EmbeddedCan::new(can, clock);
    let now = bus.now();
    let node = NODE.init_with(|| BoardNode::new(config, now));
    let mut firmware = OwnDriverNode::boot(node, bus, store, Iwdg(watchdog));
    loop {
        // A superloop: turn, show, turn again. A board that should sleep waits for the CAN
        // interrupt or the instant `turn` returns (TIM2's compare), whichever comes first.
        let _next_due = firmware.turn();
        led.set_state(PinState::from(firmware.application().led()));
    }
}

/// Nothing to run on: wait for the watchdog's reset.
fn halt() -> ! {
    loop {
        cortex_m::asm::nop();
    }
}

/// A panic waits for the watchdog's reset.
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    halt()
}
