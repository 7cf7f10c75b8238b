//! # A pab node on your own CAN driver, without embassy
//!
//! The firmware (`src/main.rs`, feature `board`) runs a node on an STM32F405 with
//! stm32f4xx-hal's bxCAN driver (the `bxcan` crate) in a superloop: no executor, no embassy.
//! Everything here is generic over the four things a board brings, so that the host's tests run
//! this very code over pab-app's test bus (`tests/`):
//!
//! - the CAN driver: any [`embedded_can::nb::Can`] (bxCAN on the board, a
//!   `pab_app::testing::TestBus` endpoint in the tests), wrapped in [`pab_app::EmbeddedCan`];
//! - the clock: [`Micros32`] extends a free-running 32-bit microsecond counter (TIM2 on the
//!   board, a number the test sets) to the node's 64-bit [`Instant`];
//! - the store: any [`TableStore`];
//! - the watchdog: any [`Watchdog`].
//!
//! [`OwnDriverNode`] holds them with the node and turns [`PollLoop`]; [`Application`] is what
//! the board does with what the node's ports deliver (here: an LED).

#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

use embedded_can::nb::Can;
use pab_app::{BoardNode, Clock, EmbeddedCan, PollLoop, Recipient, TableStore, Watchdog};
use pab_core::{Frame, Instant};

/// The application: what the node's ports deliver lights the board's LED. The LED is on while
/// the last frame delivered has a first data byte other than 0.
#[derive(Debug, Default)]
pub struct Application {
    delivered: u32,
    last: Option<(u8, Frame)>,
}

impl Application {
    /// Frames delivered so far, at every port.
    pub fn delivered(&self) -> u32 {
        self.delivered
    }

    /// The last frame delivered, and at which port.
    pub fn last(&self) -> Option<(u8, Frame)> {
        self.last
    }

    /// Whether the LED is on.
    pub fn led(&self) -> bool {
        self.last
            .is_some_and(|(_, frame)| frame.payload().first().is_some_and(|&byte| byte != 0))
    }
}

impl Recipient for Application {
    fn deliver(&mut self, port: u8, frame: &Frame, _now: Instant) {
        self.delivered = self.delivered.wrapping_add(1);
        self.last = Some((port, *frame));
    }
}

/// A free-running 32-bit microsecond counter (`read` returns it) as the node's clock.
///
/// The counter wraps after 71 minutes; the clock adds what it advanced since the last reading
/// (a wrapping subtraction), so it stays right as long as it is read at least once per wrap:
/// the loop reads it at every turn, and turns at least every `Watchdog::FEED_INTERVAL_US`. A
/// counter whose top value is below `u32::MAX` (a timer's auto-reload one less) makes its wrap
/// count a microsecond or two more: the clock stays monotonic.
pub struct Micros32<R> {
    read: R,
    last: u32,
    micros: u64,
}

impl<R: FnMut() -> u32> Micros32<R> {
    /// A clock at 0 now, over `read`.
    pub fn new(mut read: R) -> Micros32<R> {
        let last = read();
        Micros32 {
            read,
            last,
            micros: 0,
        }
    }
}

impl<R: FnMut() -> u32> Clock for Micros32<R> {
    fn now(&mut self) -> Instant {
        let count = (self.read)();
        self.micros = self
            .micros
            .saturating_add(u64::from(count.wrapping_sub(self.last)));
        self.last = count;
        Instant::from_micros(self.micros)
    }
}

/// The node and what it runs on: driver `D` with clock `T`, store `S`, watchdog `W`. The node
/// and the store are borrowed: on the board they live in `static`s (the node is tens of KiB,
/// too large for a stack frame), in a test on the heap.
pub struct OwnDriverNode<'a, D: Can, T, S, W> {
    node: &'a mut BoardNode,
    can: EmbeddedCan<D, T>,
    store: &'a mut S,
    watchdog: W,
    node_loop: PollLoop,
    application: Application,
}

impl<'a, D, T, S, W> OwnDriverNode<'a, D, T, S, W>
where
    D: Can,
    T: Clock,
    S: TableStore,
    W: Watchdog,
{
    /// Boots `node` from `store` (its stored table, if any) on `can`'s clock. Start the watchdog
    /// before: a store that hangs is a hang like any other.
    pub fn boot(
        node: &'a mut BoardNode,
        mut can: EmbeddedCan<D, T>,
        store: &'a mut S,
        mut watchdog: W,
    ) -> Self {
        watchdog.feed();
        let mut node_loop = PollLoop::new();
        node_loop.boot(node, store, can.now());
        OwnDriverNode {
            node,
            can,
            store,
            watchdog,
            node_loop,
            application: Application::default(),
        }
    }

    /// One turn of the node's loop; the instant the next is due by. The firmware turns it again
    /// at once (a superloop); a board that sleeps sleeps until then or the CAN interrupt.
    pub fn turn(&mut self) -> Instant {
        self.node_loop.turn(
            self.node,
            &mut self.can,
            self.store,
            &mut self.application,
            &mut self.watchdog,
        )
    }

    /// What the ports delivered.
    pub fn application(&self) -> &Application {
        &self.application
    }

    /// The node, to read (its state, its counters, its running table).
    pub fn node(&self) -> &BoardNode {
        self.node
    }

    /// The bus adapter (and through it the driver and the clock).
    pub fn can(&mut self) -> &mut EmbeddedCan<D, T> {
        &mut self.can
    }
}
