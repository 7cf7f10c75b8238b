//! Your own board: the pab node on your firmware, with your CAN driver, your flash and your
//! watchdog. `cargo run -p pab-app --example your_own_board` runs it here, on the host, with
//! stand-ins for the three; docs/your-own-board.md walks through it.
//!
//! The node is `pab_app::run_watched` over four seams, each a small trait:
//!
//! - [`CanBus`]: receive a frame, transmit a frame (two async methods). Here a pair of channels;
//!   on your board, your CAN driver (the NUCLEO-G474RE wraps embassy-stm32's FDCAN, the Linux
//!   node a SocketCAN socket).
//! - [`TableStore`]: where the node keeps its table across resets. `pab_storage::FlashStore`
//!   gives it to any `embedded-storage` NOR flash, power-cut safe; here an in-memory flash.
//! - [`Recipient`]: what your application does with the frames a port delivers (drive the arm,
//!   close the gripper). Here it counts and prints them.
//! - [`Watchdog`]: your hardware watchdog, fed by the node loop at every turn. Here it counts.
//!
//! What it runs: node 1 with the arm's table of Take and Return (committed as
//! `firmware/boards/mps2-an386/tables/take-and-return/arm.pab`, what `pabctl compile
//! examples/take-and-return.toml` writes), planted in its store as a push would have left it.
//! Ten frames of `object_pos` (0x110) come in, 10 ms apart. Its connection C1 (σ = 0.2, τ = 3 s)
//! becomes active at the sixth: with q = e^(-0.01/3), the level after n frames is
//! 0.2 (1 + q + ... + q^(n-1)), 0.993 after five and 1.19 after six (and still above 1 with
//! frames up to 200 ms apart on a slow machine). From then on the arm's port delivers each frame
//! to the recipient and re-publishes it on 0x200, as the table says: five of the ten. The example
//! checks that and exits 1 if not.

use embassy_futures::select::{Either, select};
use futures::StreamExt;
use futures::channel::mpsc::{UnboundedReceiver, UnboundedSender, unbounded};
use pab_app::{BusError, CanBus, Config, Recipient, TableStore, Watchdog};
use pab_core::{Frame, Instant};
use pab_storage::FlashStore;
use pab_storage::testing::MemFlash;

/// Your CAN driver goes here. `receive` must be cancel-safe: the node loop drops a pending
/// receive when a timer fires first, and no frame may be lost by that.
struct MyBus {
    incoming: UnboundedReceiver<Frame>,
    outgoing: UnboundedSender<Frame>,
}

impl CanBus for MyBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        // A driver reports what went wrong instead of a frame: lost frames (`Overrun`,
        // `Dropped(n)`), `ErrorPassive`, `BusOff`, `Recovered`; the node counts and reports them.
        self.incoming.next().await.ok_or(BusError::Other(0))
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        self.outgoing
            .unbounded_send(*frame)
            .map_err(|_| BusError::Other(1))
    }
}

/// Your application: the frames the node's ports deliver.
#[derive(Default)]
struct MyApplication {
    delivered: u32,
}

impl Recipient for MyApplication {
    fn deliver(&mut self, port: u8, frame: &Frame, now: Instant) {
        self.delivered += 1;
        println!(
            "  t = {:>7} µs: port {port} delivers {:03X} {:02X?}",
            now.as_micros(),
            frame.raw_id().0,
            frame.payload()
        );
    }
}

/// Your hardware watchdog: `feed` restarts its countdown (one register write on the boards).
#[derive(Default)]
struct MyWatchdog {
    feeds: u32,
}

impl Watchdog for MyWatchdog {
    /// The node loop turns at least this often to feed it; set your watchdog's timeout well
    /// above it (the G474: 100 ms here, 500 ms there).
    const FEED_INTERVAL_US: u64 = 100_000;

    fn feed(&mut self) {
        self.feeds += 1;
    }
}

/// Your flash goes here: any `embedded_storage::nor_flash::NorFlash`. 12 pages of 4 KiB with
/// 8-byte writes (the G474's geometry), four slots of 12 KiB: each holds an 8 KiB table.
type MyFlash = MemFlash<12, 4096, 8>;

const ARM_TABLE: &[u8] = include_bytes!("../../boards/mps2-an386/tables/take-and-return/arm.pab");

fn main() {
    // The store: a ring of slots over the flash; a table saved there survives a reset.
    let flash = MyFlash::default();
    let mut store = FlashStore::new(flash, 0..12 * 4096, 12 * 1024).expect("the store's layout");
    // As a `pabctl push` would have left it (the node saves a pushed table itself).
    store.save(ARM_TABLE).expect("the table saved");

    // Node 1: the arm's table is compiled for it. The node is large (tens of KiB with its
    // transfer buffer): a board keeps it in a `static` (a StaticCell), here on the heap.
    let config = Config::new(1).expect("a node id in 1..=127");
    let mut node = Box::new(pab_app::BoardNode::new(config, pab_app::now()));

    let (to_node, incoming) = unbounded();
    let (outgoing, mut from_node) = unbounded();
    let mut bus = MyBus { incoming, outgoing };
    let mut application = MyApplication::default();
    let mut watchdog = MyWatchdog::default();

    // The node runs forever; this example runs it beside a behaviour that publishes ten
    // frames, and stops when the behaviour is done.
    let behaviour = async {
        for x in 0u8..10 {
            embassy_time::Timer::after_millis(10).await;
            let frame = Frame::with_raw_id(0x110, false, &[x, 0, 0, 0]).expect("a valid frame");
            to_node.unbounded_send(frame).expect("the node listens");
        }
        embassy_time::Timer::after_millis(100).await;
    };
    println!("node 1 with the arm's table; object_pos (0x110) ten times, 10 ms apart:");
    let ran = futures::executor::block_on(select(
        pab_app::run_watched(
            &mut *node,
            &mut bus,
            &mut store,
            &mut application,
            &mut watchdog,
        ),
        behaviour,
    ));
    assert!(
        matches!(ran, Either::Second(())),
        "the node loop never returns"
    );

    let mut republished = 0;
    let mut ours = 0;
    while let Ok(frame) = from_node.try_recv() {
        match frame.raw_id() {
            (0x200, false) => republished += 1,
            _ => ours += 1,
        }
    }
    println!(
        "delivered {}, re-published on 0x200: {republished}, the node's own frames (heartbeat, \
         status): {ours}, watchdog fed {} times",
        application.delivered, watchdog.feeds
    );
    // What the table says: the frames from the sixth on reach the arm's port, and the port
    // re-publishes what it delivers.
    if application.delivered != 5 || republished != 5 || watchdog.feeds == 0 {
        eprintln!(
            "your_own_board: expected 5 deliveries, 5 re-published frames and a fed watchdog"
        );
        std::process::exit(1);
    }
}
