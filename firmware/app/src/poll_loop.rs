//! The node loop without an executor: [`PollLoop`], one turn per call, over an
//! `embedded-can` driver ([`EmbeddedCan`]), on the integrator's clock. No embassy, no async.

use embedded_can::nb::Can;
use pab_core::{Frame, Instant};

use crate::Recipient;
use crate::can::{Clock, EmbeddedCan, TRANSMIT_TIMEOUT_US};
use crate::node::{Node, Step};
#[cfg(feature = "identity")]
use crate::runner::save_settings;
use crate::runner::{SAVE_STARVED_US, SENDS_PER_TURN, Watchdog, save_step};
use crate::store::TableStore;

/// The most frames a turn of [`PollLoop`] reads: a bus that delivers frames faster than the node
/// handles them must not keep one turn from sending, saving and feeding the watchdog. The
/// controller's receive FIFOs hold what the turn leaves.
pub const RECEIVES_PER_TURN: usize = 16;

/// The node loop of `run_watched` as a state machine that a loop of yours turns: for a firmware
/// without embassy (a superloop, RTIC, an RTOS task), over any [`embedded_can::nb::Can`] driver.
///
/// ```text
/// let mut node_loop = PollLoop::new();
/// node_loop.boot(&mut node, &mut store, bus.now());
/// loop {
///     let wake = node_loop.turn(&mut node, &mut bus, &mut store, &mut recipient, &mut watchdog);
///     // nothing else to do: call `turn` again at once, or sleep until `wake` or until the
///     // CAN controller's interrupt (a frame received, a transmit mailbox free)
/// }
/// ```
///
/// A turn does what one pass of `run_watched` does, without waiting anywhere: feeds the
/// watchdog; hands the driver up to [`SENDS_PER_TURN`] frames of the node's outbox; reads up to
/// [`RECEIVES_PER_TURN`] frames and hands each to the node; polls the node (heartbeats, faults,
/// timeouts, the diagnostic stream); takes a step of a table save when no frame is waiting or the
/// driver failed its read (or, once the save has waited [`SAVE_STARVED_US`], after every frame). It returns the instant by
/// which the next turn is due: the node's deadline, the next feed of the watchdog
/// ([`Watchdog::FEED_INTERVAL_US`]) or the save's next step; now, when a frame waits for room in
/// the driver.
///
/// **Timing.** Time comes from the bus's clock ([`EmbeddedCan::now`]), read as a turn goes (a
/// frame is stamped when it is read). A frame is stamped when the turn reads it, not when it
/// arrived: a loop that turns late delays the node's view of its frames by as much, so turn
/// often (a superloop turns continuously). The controller's receive FIFO must hold what arrives
/// between two turns (a bxCAN FIFO holds three frames, under a millisecond of a busy 500 kbit/s
/// bus); frames it drops are reported by the driver as an overrun, and the node raises
/// `RxOverrun`.
///
/// **Sending.** A frame that finds the driver's transmit buffer full waits in the loop (one frame)
/// and is offered again each turn; after [`TRANSMIT_TIMEOUT_US`] it is dropped and reported
/// ([`Node::on_transmit_error`]), so that a bus where nobody acknowledges costs frames, not the
/// loop.
///
/// **Size.** Three words and a frame; no allocation, no panic.
#[derive(Debug, Default)]
pub struct PollLoop {
    /// The save in progress, if any: when its next step is due (µs on the clock).
    save_due: Option<u64>,
    /// A frame the driver had no room for, and since when it waits.
    waiting: Option<(Frame, Instant)>,
}

impl PollLoop {
    /// A loop with nothing in progress.
    pub const fn new() -> PollLoop {
        PollLoop {
            save_due: None,
            waiting: None,
        }
    }

    /// Boots `node` from `store` at `now`: the stored table if there is one, none if the store is
    /// empty, none and a fault on the bus if it cannot be read. Call it once, before the first
    /// turn, with the watchdog already running.
    pub fn boot<S, const P: usize, const C: usize, const N: usize, const IMG: usize>(
        &mut self,
        node: &mut Node<P, C, N, IMG>,
        store: &mut S,
        now: Instant,
    ) where
        S: TableStore,
    {
        // An unreadable store is not an empty one: the node says so on the bus.
        match store
            .load(node.boot_buffer())
            .map(|found| found.map(<[u8]>::len))
        {
            Ok(stored) => node.boot(stored, now),
            Err(error) => node.boot_unreadable(error, now),
        }
        self.save_due = None;
        self.waiting = None;
    }

    /// One turn of the loop (see [`PollLoop`]); returns when the next is due at the latest.
    pub fn turn<D, T, S, K, W, const P: usize, const C: usize, const N: usize, const IMG: usize>(
        &mut self,
        node: &mut Node<P, C, N, IMG>,
        bus: &mut EmbeddedCan<D, T>,
        store: &mut S,
        recipient: &mut K,
        watchdog: &mut W,
    ) -> Instant
    where
        D: Can,
        T: Clock,
        S: TableStore,
        K: Recipient,
        W: Watchdog,
    {
        watchdog.feed();
        self.send(node, bus);
        for _ in 0..RECEIVES_PER_TURN {
            let frame = match bus.try_receive() {
                Ok(frame) => frame,
                Err(error) => {
                    // The next turn reads again; a driver that fails at once, again and again,
                    // makes a busy loop of a superloop, but the node's fault frames are rate
                    // limited.
                    if let nb::Error::Other(error) = error {
                        node.on_bus_error(error, bus.now());
                    }
                    // No frame to read (the bus is quiet, or the driver failed: a driver that
                    // keeps failing must not starve the save either): the save's step, if due.
                    let now = bus.now();
                    if let Some(due) = self.save_due
                        && now.as_micros() >= due
                    {
                        self.save_due = save_step(node, store, now, due);
                    }
                    break;
                }
            };
            let step = node.on_frame(&frame, bus.now(), recipient);
            self.store_if(step, node, store, watchdog, bus.now());
            // A save that has waited SAVE_STARVED_US for the bus to fall quiet steps after
            // every frame until it ends, as in `run_watched`.
            if let Some(due) = self.save_due {
                let now = bus.now();
                if now.as_micros() >= due.saturating_add(SAVE_STARVED_US) {
                    self.save_due = save_step(node, store, now, due);
                }
            }
        }
        let now = bus.now();
        let step = node.poll(now, recipient);
        self.store_if(step, node, store, watchdog, now);
        // What the node queued meanwhile (answers, faults, heartbeats) goes now, not next turn.
        self.send(node, bus);
        let now = bus.now();
        if self.waiting.is_some() {
            return now;
        }
        let feed = now.as_micros().saturating_add(W::FEED_INTERVAL_US);
        let wake = node
            .deadline(now)
            .as_micros()
            .min(feed)
            .min(self.save_due.unwrap_or(u64::MAX));
        Instant::from_micros(wake)
    }

    /// Up to [`SENDS_PER_TURN`] frames to the driver: the one that waits for room first.
    fn send<D, T, const P: usize, const C: usize, const N: usize, const IMG: usize>(
        &mut self,
        node: &mut Node<P, C, N, IMG>,
        bus: &mut EmbeddedCan<D, T>,
    ) where
        D: Can,
        T: Clock,
    {
        for _ in 0..SENDS_PER_TURN {
            let (frame, since) = match self.waiting.take() {
                Some(waiting) => waiting,
                None => match node.next_outgoing() {
                    Some(frame) => (frame, bus.now()),
                    None => {
                        // Nothing of the node's: a frame the driver handed back goes out now.
                        let _ = bus.try_flush();
                        return;
                    }
                },
            };
            match bus.try_transmit(&frame) {
                Ok(()) => {}
                Err(nb::Error::WouldBlock) => {
                    let now = bus.now();
                    if now.micros_since(since).unwrap_or(0) >= TRANSMIT_TIMEOUT_US {
                        node.on_transmit_error(now);
                    } else {
                        self.waiting = Some((frame, since));
                    }
                    return;
                }
                Err(nb::Error::Other(_)) => node.on_transmit_error(bus.now()),
            }
        }
    }

    /// Starts storing the running image if the node asked for it (`Step::Store`); stores its
    /// configuration record (`Step::SaveSettings`), restarting it through `watchdog` when it
    /// asks.
    fn store_if<S, W, const P: usize, const C: usize, const N: usize, const IMG: usize>(
        &mut self,
        step: Step,
        node: &mut Node<P, C, N, IMG>,
        store: &mut S,
        watchdog: &mut W,
        now: Instant,
    ) where
        S: TableStore,
        W: Watchdog,
    {
        #[cfg(feature = "identity")]
        if step == Step::SaveSettings {
            save_settings(node, store, watchdog, now);
        }
        #[cfg(not(feature = "identity"))]
        let _ = watchdog;
        if step == Step::Store {
            // A save that cannot start (the image does not fit, the flash fails) is reported by
            // its first step, which then finds no save in progress: one place tells the node.
            let _ = store.start_save(node.image_to_store());
            self.save_due = Some(now.as_micros());
        }
    }
}
