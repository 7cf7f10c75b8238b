//! The async loop that runs a [`Node`] on a bus with a store, under embassy (on a board, or on
//! embassy's std executor on Linux); the loop itself and the clock need the `embassy` feature,
//! the watchdog seam, the loop's bounds and the save's step serve [`crate::PollLoop`] too.

#[cfg(feature = "embassy")]
use embassy_futures::select::{Either, select};
#[cfg(feature = "embassy")]
use embassy_time::Timer;
use pab_core::Instant;

#[cfg(feature = "embassy")]
use crate::Recipient;
#[cfg(feature = "embassy")]
use crate::bus::{BusError, CanBus};
use crate::node::Node;
#[cfg(feature = "embassy")]
use crate::node::Step;
use crate::store::{SaveProgress, TableStore};

/// Now, on embassy's clock, as a core [`Instant`].
///
/// Out of line: the loop reads the clock at nine places, and their inlined copies of the board's
/// time driver (a critical section around the timer's count and period) took 196 bytes more of
/// the NUCLEO-G474RE's flash than one out-of-line copy. A read costs a call more (the node's
/// methods take `now` from their caller, so the measured frame path does not change).
#[cfg(feature = "embassy")]
#[inline(never)]
pub fn now() -> Instant {
    Instant::from_micros(embassy_time::Instant::now().as_micros())
}

/// A hardware watchdog that the node loop feeds: once per turn of `run_watched`'s loop (or of a
/// [`crate::PollLoop`]), and the loop turns at least every [`Watchdog::FEED_INTERVAL_US`], so the watchdog fires only when the
/// loop itself stops (a hang in the node, the driver or the store), not when the bus is quiet.
pub trait Watchdog {
    /// The longest the loop waits between two feeds, µs. The watchdog's timeout must be well
    /// above it plus the longest single step of the loop (a step of a table save: a page erase on a
    /// flash that cannot erase in the background, up to 40 ms on the G474, else about a millisecond).
    const FEED_INTERVAL_US: u64;
    /// Restarts the watchdog's countdown. Costs one register write on the boards.
    fn feed(&mut self);

    /// Restarts the node now (a board: a system reset), for a setting that takes effect at
    /// start, such as a bit rate that went back to the previous one. The default does nothing:
    /// a host process keeps running, the setting applies at its next start.
    fn restart(&mut self) {}
}

/// No watchdog (the Linux node, tests): never feeds, never wakes the loop for it.
impl Watchdog for () {
    const FEED_INTERVAL_US: u64 = u64::MAX;
    fn feed(&mut self) {}
}

/// How long the loop waits for frames between two checks of a page erase running in the
/// background, µs: a twentieth of the G474's typical erase (22 ms), and long enough that the checks
/// cost nothing measurable.
pub const SAVE_POLL_US: u64 = 1_000;
/// The longest a save waits for its next step while frames keep the loop busy, µs: from then on a
/// step is taken after every frame until the bus falls quiet, so that a saturated bus delays a
/// save but never starves it.
pub const SAVE_STARVED_US: u64 = 20_000;

/// The most frames the loop hands the bus per turn. On a bus where nobody acknowledges, a send
/// takes the driver's whole timeout (10 ms on the G474) and fails, and each failure is a duty
/// point at which the node may queue more (a fault, the diagnostic stream's samples): a loop that
/// sent until the outbox was empty could send forever and never feed the watchdog again. 16
/// failed sends are 160 ms, well within the G474's 500 ms timeout; frames left over go out next
/// turn.
pub const SENDS_PER_TURN: usize = 16;

/// Boots `node` from `store`, then runs it forever: reads frames, arbitrates, answers, stores new
/// tables, sends what the node has to send, and wakes at the node's deadlines.
///
/// A new table is stored in steps ([`TableStore::continue_save`]), taken when no frame is waiting
/// (or, once a save has waited [`SAVE_STARVED_US`], after every frame): a step programs one small
/// chunk (less than a frame's time on the bus) or starts or checks a page erase that runs in the
/// background, so the node goes on
/// reading, arbitrating and sending while the table is written; the driver's receive queue holds
/// what arrives during a step. The node refuses transfers until the save is done (its image
/// stays in the transfer buffer) and rate-limits saves ([`crate::Config::store_interval_us`]): a
/// save that waits for its turn comes out of [`Node::poll`] at its deadline.
#[cfg(feature = "embassy")]
pub async fn run<B, S, K, const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    bus: &mut B,
    store: &mut S,
    recipient: &mut K,
) -> !
where
    B: CanBus,
    S: TableStore,
    K: Recipient,
{
    run_watched(node, bus, store, recipient, &mut ()).await
}

/// [`run`], feeding `watchdog` at every turn of the loop and waking at least every
/// [`Watchdog::FEED_INTERVAL_US`] to do so: a loop that hangs stops feeding it.
#[cfg(feature = "embassy")]
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
    recipient: &mut K,
    watchdog: &mut W,
) -> !
where
    B: CanBus,
    S: TableStore,
    K: Recipient,
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
    #[cfg(feature = "update")]
    start_update(node, store);
    // The firmware confirms itself to its bootloader once it has sent a frame and heard one,
    // with its table loaded (above): until then a reset reverts an update.
    #[cfg(feature = "update")]
    let (mut sent, mut heard, mut confirmed) = (false, false, false);
    // The save in progress, if any: when its next step is due (µs on the node's clock).
    let mut save_due: Option<u64> = None;
    loop {
        watchdog.feed();
        for _ in 0..SENDS_PER_TURN {
            let Some(frame) = node.next_outgoing() else {
                break;
            };
            if bus.transmit(&frame).await.is_err() {
                node.on_transmit_error(now());
            } else {
                #[cfg(feature = "update")]
                {
                    sent = true;
                }
            }
        }
        #[cfg(feature = "update")]
        if sent && heard && !confirmed {
            confirmed = true;
            confirm_firmware(store);
        }
        // One reading of the clock for all: the node's deadline, the next feed, the save's step.
        let now_at = now();
        // Frames left after a full turn of sends (a failing bus only: a working one takes the
        // outbox's 16 in one turn) go at the node's next duty point or frame.
        let deadline = node.deadline(now_at).as_micros();
        let feed = now_at.as_micros().saturating_add(W::FEED_INTERVAL_US);
        let wake = deadline.min(feed).min(save_due.unwrap_or(u64::MAX));
        let wake = embassy_time::Instant::from_micros(wake);
        // `select` polls the bus first: a waiting frame always goes before a save's step.
        let step = match select(bus.receive(), Timer::at(wake)).await {
            Either::First(Ok(frame)) => {
                #[cfg(feature = "update")]
                {
                    heard = true;
                }
                let step = node.on_frame(&frame, now(), recipient);
                // A save that has waited SAVE_STARVED_US for the bus to fall quiet steps anyway,
                // then after every frame until it ends (`save_step` keeps its due time): a step
                // is shorter than a frame, so a saturated bus neither starves the save nor
                // outruns the node.
                if let Some(due) = save_due
                    && now().as_micros() >= due.saturating_add(SAVE_STARVED_US)
                {
                    save_due = save_step(node, store, now(), due);
                }
                step
            }
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
            Either::Second(()) => {
                let at = now();
                if let Some(due) = save_due
                    && at.as_micros() >= due
                {
                    save_due = save_step(node, store, at, due);
                }
                node.poll(now(), recipient)
            }
        };
        // A configuration record to store: blocking (a record's program, once in a while an
        // erase); configuration is rare, and the node refuses it while a table's save runs.
        #[cfg(feature = "identity")]
        if step == Step::SaveSettings {
            save_settings(node, store, watchdog, now());
        }
        // A new table to store: at once, or when the store interval let its turn come.
        if step == Step::Store {
            // A save that cannot start (the image does not fit, the flash fails) is reported by
            // its first step, which then finds no save in progress: one place tells the node.
            let _ = store.start_save(node.image_to_store());
            save_due = Some(now().as_micros());
        }
        // An update's chunk: written at once (blocking: a page's erase and a chunk's program,
        // some 30 ms on the G474), then answered.
        #[cfg(feature = "update")]
        if step == Step::WriteUpdate {
            write_update(node, store);
        }
        // The update complete: the manifest and the request stored, the answer sent, then the
        // bootloader.
        #[cfg(feature = "update")]
        if step == Step::RequestUpdate && request_update(node, store) {
            while let Some(frame) = node.next_outgoing() {
                if bus.transmit(&frame).await.is_err() {
                    break;
                }
            }
            watchdog.restart();
        }
    }
}

/// At start, before the loop: the store's update slot to the node, and the bootloader's
/// verdict on the last request, if it made one since.
#[cfg(feature = "update")]
// The async loop's (`run_watched`, feature `embassy`); a build without it has no caller.
#[cfg_attr(not(feature = "embassy"), allow(dead_code))]
#[inline(never)]
pub(crate) fn start_update<S, const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    store: &mut S,
) where
    S: TableStore,
{
    node.set_update_slot(store.update_slot_len());
    match store.take_update_verdict() {
        Ok(Some(verdict)) => node.update_verdict(verdict),
        Ok(None) => {}
        Err(_) => warn!("firmware update: the request page could not be read"),
    }
}

/// Confirms the running firmware to the bootloader (which then never reverts it).
#[cfg(feature = "update")]
// The async loop's (`run_watched`, feature `embassy`); a build without it has no caller.
#[cfg_attr(not(feature = "embassy"), allow(dead_code))]
#[inline(never)]
pub(crate) fn confirm_firmware<S: TableStore>(store: &mut S) {
    if store.confirm_firmware() {
        info!("firmware confirmed to the bootloader");
    } else {
        warn!("firmware update: the firmware could not be confirmed; a reset reverts it");
    }
}

/// Writes the update chunk the node owes and tells it how that went.
#[cfg(feature = "update")]
// The async loop's (`run_watched`, feature `embassy`); a build without it has no caller.
#[cfg_attr(not(feature = "embassy"), allow(dead_code))]
#[inline(never)]
pub(crate) fn write_update<S, const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    store: &mut S,
) where
    S: TableStore,
{
    let ok = match node.update_chunk() {
        Some((offset, data)) => store.write_update(offset, data).is_ok(),
        None => false,
    };
    node.update_written(ok);
}

/// Stores the update's manifest and request and tells the node; whether to restart now.
#[cfg(feature = "update")]
// The async loop's (`run_watched`, feature `embassy`); a build without it has no caller.
#[cfg_attr(not(feature = "embassy"), allow(dead_code))]
#[inline(never)]
pub(crate) fn request_update<S, const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    store: &mut S,
) -> bool
where
    S: TableStore,
{
    let ok = match node.update_manifest() {
        Some(manifest) => {
            let manifest = *manifest;
            store.request_update(&manifest).is_ok()
        }
        None => false,
    };
    node.update_requested(ok)
}

/// Stores the node's configuration record and tells it how that went; restarts the node when it
/// asks (a bit rate's trial that heard nothing). Out of line: configuration is rare, and the
/// loop's future need not hold its code.
#[cfg(feature = "identity")]
#[inline(never)]
pub(crate) fn save_settings<
    S,
    W,
    const P: usize,
    const C: usize,
    const N: usize,
    const IMG: usize,
>(
    node: &mut Node<P, C, N, IMG>,
    store: &mut S,
    watchdog: &mut W,
    now: Instant,
) where
    S: TableStore,
    W: Watchdog,
{
    let result = store.save_settings(node.settings_to_store());
    if node.settings_stored(result, now) {
        watchdog.restart();
    }
}

/// One step of the save in progress, which was due at `due`; when the next is due (`None` once
/// the save has ended, and the node told how). A step that leaves more ready keeps `due`: the
/// next is due at once, and a save that has waited [`SAVE_STARVED_US`] for the bus to fall quiet
/// stays that late, so that it steps after every frame until it ends.
// Out of line: two callers, and one call site in the loop's future (the step's flag computed in
// both branches, the call after them) took 36 bytes more of the emulated board's flash.
#[inline(never)]
pub(crate) fn save_step<
    S: TableStore,
    const P: usize,
    const C: usize,
    const N: usize,
    const IMG: usize,
>(
    node: &mut Node<P, C, N, IMG>,
    store: &mut S,
    now: Instant,
    due: u64,
) -> Option<u64> {
    let at = now.as_micros();
    // One call of `stored` for both ends: two took 64 bytes more of the NUCLEO-G474RE's flash.
    let ok = match store.continue_save(node.image_to_store()) {
        Ok(SaveProgress::Ready) => return Some(due),
        Ok(SaveProgress::Erasing) => return Some(at.saturating_add(SAVE_POLL_US)),
        Ok(SaveProgress::Done) => true,
        Err(_) => false,
    };
    node.stored(ok, now);
    None
}
