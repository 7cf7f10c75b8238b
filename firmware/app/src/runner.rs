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
pub fn now() -> Instant {
    Instant::from_micros(embassy_time::Instant::now().as_micros())
}

/// Boots `node` from `store`, then runs it forever: reads frames, arbitrates, answers, stores new
/// tables, sends what the node has to send, and wakes at the node's deadlines.
///
/// While a new table is being stored (a flash write: milliseconds) no frame is read; the
/// driver's receive queue holds what arrives meanwhile.
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
    // An unreadable store is not an empty one: the node says so on the bus.
    match store
        .load(node.boot_buffer())
        .await
        .map(|found| found.map(<[u8]>::len))
    {
        Ok(stored) => node.boot(stored, now()),
        Err(error) => node.boot_unreadable(error, now()),
    }
    loop {
        while let Some(frame) = node.next_outgoing() {
            if bus.transmit(&frame).await.is_err() {
                node.on_transmit_error(now());
            }
        }
        let deadline = node.deadline(now());
        let wake = embassy_time::Instant::from_micros(deadline.as_micros());
        match select(bus.receive(), Timer::at(wake)).await {
            Either::First(Ok(frame)) => {
                if node.on_frame(&frame, now(), consumer) == Step::Store {
                    let ok = store.save(node.image_to_store()).await.is_ok();
                    node.stored(ok, now());
                }
            }
            Either::First(Err(error)) => {
                node.on_bus_error(error, now());
                // A driver that fails at once, again and again (a closed socket, a controller
                // stuck bus-off), must not turn this loop into a busy loop. A count of dropped
                // frames comes with a frame that the next read returns: pausing then would only
                // drop more.
                if !matches!(error, BusError::Dropped(_)) {
                    Timer::after_millis(1).await;
                }
            }
            Either::Second(()) => node.poll(now()),
        }
    }
}
