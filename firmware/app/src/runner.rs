//! The async loop that runs a [`Node`] on a bus with a store, under embassy (on a board, or on
//! embassy's std executor on Linux).

use embassy_futures::select::{Either, select};
use embassy_time::Timer;
use pab_core::Instant;

use crate::Consumer;
use crate::bus::{BusError, CanBus};
use crate::node::{Node, Step};
use crate::store::TableStore;

/// Now, on embassy's clock, as a core [`Instant`].
///
/// Out of line: the loop reads the clock at nine places, and their inlined copies of the board's
/// time driver (a critical section around the timer's count and period) took 196 bytes more of
/// the NUCLEO-G474RE's flash than one out-of-line copy. A read costs a call more (the node's
/// methods take `now` from their caller, so the measured frame path does not change).
#[inline(never)]
pub fn now() -> Instant {
    Instant::from_micros(embassy_time::Instant::now().as_micros())
}

/// A hardware watchdog that the node loop feeds: once per turn of [`run_watched`]'s loop, and the
/// loop turns at least every [`Watchdog::FEED_INTERVAL_US`], so the watchdog fires only when the
/// loop itself stops (a hang in the node, the driver or the store), not when the bus is quiet.
pub trait Watchdog {
    /// The longest the loop waits between two feeds, µs. The watchdog's timeout must be well
    /// above it plus the longest single step of the loop (a table save: tens of milliseconds).
    const FEED_INTERVAL_US: u64;
    /// Restarts the watchdog's countdown. Costs one register write on the boards.
    fn feed(&mut self);
}

/// No watchdog (the Linux node, tests): never feeds, never wakes the loop for it.
impl Watchdog for () {
    const FEED_INTERVAL_US: u64 = u64::MAX;
    fn feed(&mut self) {}
}

/// Boots `node` from `store`, then runs it forever: reads frames, arbitrates, answers, stores new
/// tables, sends what the node has to send, and wakes at the node's deadlines.
///
/// While a new table is being stored (a flash write: milliseconds) no frame is read; the
/// driver's receive queue holds what arrives meanwhile. The node rate-limits saves
/// ([`crate::Config::store_interval_us`]): a save that waits for its turn comes out of
/// [`Node::poll`] at its deadline.
pub async fn run<B, S, K, const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    bus: &mut B,
    store: &mut S,
    consumer: &mut K,
) -> !
where
    B: CanBus,
    S: TableStore,
    K: Consumer,
{
    run_watched(node, bus, store, consumer, &mut ()).await
}

/// [`run`], feeding `watchdog` at every turn of the loop and waking at least every
/// [`Watchdog::FEED_INTERVAL_US`] to do so: a loop that hangs stops feeding it.
pub async fn run_watched<
    B,
    S,
    K,
    W,
    const P: usize,
    const C: usize,
    const N: usize,
    const IMG: usize,
>(
    node: &mut Node<P, C, N, IMG>,
    bus: &mut B,
    store: &mut S,
    consumer: &mut K,
    watchdog: &mut W,
) -> !
where
    B: CanBus,
    S: TableStore,
    K: Consumer,
    W: Watchdog,
{
    watchdog.feed();
    // An unreadable store is not an empty one: the node says so on the bus.
    match store
        .load(node.boot_buffer())
        .map(|found| found.map(<[u8]>::len))
    {
        Ok(stored) => node.boot(stored, now()),
        Err(error) => node.boot_unreadable(error, now()),
    }
    loop {
        watchdog.feed();
        while let Some(frame) = node.next_outgoing() {
            if bus.transmit(&frame).await.is_err() {
                node.on_transmit_error(now());
            }
        }
        // One reading of the clock for both: the node's deadline and the next feed.
        let now_at = now();
        let deadline = node.deadline(now_at).as_micros();
        let wake = embassy_time::Instant::from_micros(
            deadline.min(now_at.as_micros().saturating_add(W::FEED_INTERVAL_US)),
        );
        let step = match select(bus.receive(), Timer::at(wake)).await {
            Either::First(Ok(frame)) => node.on_frame(&frame, now(), consumer),
            Either::First(Err(error)) => {
                node.on_bus_error(error, now());
                // A driver that fails at once, again and again (a closed socket, a controller
                // stuck bus-off), must not turn this loop into a busy loop. A count of dropped
                // frames comes with a frame that the next read returns: pausing then would only
                // drop more.
                // 1 ms from the clock read out of line (`now`): `Timer::after_millis` inlined
                // another copy of the time driver's read and an overflow check (32 bytes).
                if !matches!(error, BusError::Dropped(_)) {
                    let pause_end = now().as_micros().saturating_add(1_000);
                    Timer::at(embassy_time::Instant::from_micros(pause_end)).await;
                }
                Step::Continue
            }
            Either::Second(()) => node.poll(now(), consumer),
        };
        // A new table to store: at once, or when the store interval let its turn come.
        if step == Step::Store {
            let ok = store.save(node.image_to_store()).is_ok();
            node.stored(ok, now());
        }
    }
}
