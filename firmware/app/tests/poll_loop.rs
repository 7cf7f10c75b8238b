//! `PollLoop`, the loop of a firmware without embassy: a node turned by the test over the
//! `embedded-can` adapter, on `testing::TestBus` endpoints, in virtual time. A tool pushes a
//! table over ISO-TP, the node stores it in a flash store and arbitrates with it, a monitor sees
//! what goes on the bus; drivers that refuse to send and a save under traffic.

use std::cell::Cell;
use std::rc::Rc;

use crate::common;

use common::*;
use pab_app::testing::{Endpoint, TestBus};
use pab_app::{Config, EmbeddedCan, PollLoop, TableStore, Watchdog};
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, Message, NodeState, TransferStatusCode};
use pab_core::{Frame, Instant};
use pab_storage::FlashStore;
use pab_storage::testing::MemFlash;

/// The G474's geometry: 4 KiB pages, 8-byte writes; 64 KiB.
type Flash = MemFlash<16, 4096, 8>;
/// Node, tool, monitor: room for a whole pushed image in each queue.
type Bus = TestBus<3, 2048>;
const NODE: usize = 0;
const TOOL: usize = 1;
const MONITOR: usize = 2;

/// A virtual clock, µs, that the test moves.
#[derive(Clone, Default)]
struct VirtualTime(Rc<Cell<u64>>);

impl VirtualTime {
    fn clock(&self) -> impl FnMut() -> Instant + use<> {
        let time = self.0.clone();
        move || Instant::from_micros(time.get())
    }
    fn now(&self) -> u64 {
        self.0.get()
    }
    fn set(&self, micros: u64) {
        self.0.set(micros);
    }
}

/// A watchdog that counts its feeds.
#[derive(Default)]
struct Feeds(u32);

impl Watchdog for Feeds {
    const FEED_INTERVAL_US: u64 = 100_000;
    fn feed(&mut self) {
        self.0 += 1;
    }
}

/// The node's driver: its endpoint, whose reads the test can make fail (a controller gone
/// bus-off, say).
struct Flaky<'a> {
    endpoint: Endpoint<'a, 3, 2048>,
    failing: bool,
}

#[derive(Debug)]
struct Failed;

impl embedded_can::Error for Failed {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Bit
    }
}

impl embedded_can::nb::Can for Flaky<'_> {
    type Frame = Frame;
    type Error = Failed;
    fn transmit(&mut self, frame: &Frame) -> nb::Result<Option<Frame>, Failed> {
        self.endpoint.send(frame);
        Ok(None)
    }
    fn receive(&mut self) -> nb::Result<Frame, Failed> {
        if self.failing {
            return Err(nb::Error::Other(Failed));
        }
        embedded_can::nb::Can::receive(&mut self.endpoint).map_err(|error| error.map(|_| Failed))
    }
}

type NodeBus<'a> = EmbeddedCan<Flaky<'a>, Box<dyn FnMut() -> Instant>>;

/// A node on endpoint NODE, turned by the test.
struct Rig<'a> {
    time: VirtualTime,
    node: Box<TestNode>,
    can: NodeBus<'a>,
    store: FlashStore<Flash>,
    node_loop: PollLoop,
    deliveries: Deliveries,
    watchdog: Feeds,
}

impl<'a> Rig<'a> {
    fn boot(bus: &'a Bus, flash: Flash) -> Rig<'a> {
        let time = VirtualTime::default();
        let clock: Box<dyn FnMut() -> Instant> = Box::new(time.clock());
        let mut rig = Rig {
            node: Box::new(TestNode::new(
                Config::new(Harness::NODE_ID).unwrap(),
                Instant::from_micros(0),
            )),
            can: EmbeddedCan::new(
                Flaky {
                    endpoint: bus.endpoint(NODE).unwrap(),
                    failing: false,
                },
                clock,
            ),
            store: FlashStore::new(flash, 0..16 * 4096, 8192).unwrap(),
            node_loop: PollLoop::new(),
            deliveries: Deliveries::default(),
            watchdog: Feeds::default(),
            time,
        };
        rig.node_loop
            .boot(&mut rig.node, &mut rig.store, Instant::from_micros(0));
        rig
    }

    /// One turn at the current time; the instant the loop asks to be turned again by.
    fn turn(&mut self) -> u64 {
        self.node_loop
            .turn(
                &mut self.node,
                &mut self.can,
                &mut self.store,
                &mut self.deliveries,
                &mut self.watchdog,
            )
            .as_micros()
    }

    /// Turns the loop as a firmware that sleeps between turns would: at each instant it asks
    /// for, or every `step` µs (a frame's interrupt), up to `until`.
    fn run_until(&mut self, until: u64, step: u64) {
        while self.time.now() < until {
            let wake = self.turn();
            let next = wake.min(self.time.now() + step).max(self.time.now() + 1);
            self.time.set(next.min(until));
        }
        self.turn();
    }
}

/// Our protocol's messages in `endpoint`'s queue, in order.
fn messages(endpoint: &Endpoint<'_, 3, 2048>) -> Vec<(protocol::FrameId, Message)> {
    std::iter::from_fn(|| endpoint.try_recv())
        .filter_map(|frame| Message::decode(&frame).ok())
        .collect()
}

/// Pushes `image` from the tool endpoint with pab-core's ISO-TP sender, turning the node every
/// 100 µs; returns the TransferStatus the node answered.
fn push(rig: &mut Rig<'_>, tool: &Endpoint<'_, 3, 2048>, image: &[u8]) -> protocol::TransferStatus {
    push_with(rig, tool, image, |_, _, _| {})
}

/// [`push`], with `before_turn(rig, tool, sent)` called before each turn of the node (`sent`:
/// the image's last frame is on the bus).
fn push_with(
    rig: &mut Rig<'_>,
    tool: &Endpoint<'_, 3, 2048>,
    image: &[u8],
    mut before_turn: impl FnMut(&mut Rig<'_>, &Endpoint<'_, 3, 2048>, bool),
) -> protocol::TransferStatus {
    let mut sender = Sender::new(image, TxConfig::default()).unwrap();
    let give_up = rig.time.now() + 5_000_000;
    let mut done = false;
    while rig.time.now() < give_up {
        if !done {
            match sender.poll(Instant::from_micros(rig.time.now())) {
                TxEvent::Send(data) => tool.send(
                    &Message::TableTransfer { data, len: 8 }
                        .to_frame(protocol::TOOL, Harness::NODE_ID),
                ),
                TxEvent::Done => done = true,
                TxEvent::WaitUntil(_) => {}
                TxEvent::Failed(error) => panic!("the transfer failed: {error:?}"),
            }
        }
        before_turn(rig, tool, done);
        rig.turn();
        for (id, message) in messages(tool) {
            match message {
                Message::TableTransfer { data, len } if id.destination == protocol::TOOL => {
                    sender.on_flow_control(
                        &data[..len as usize],
                        Instant::from_micros(rig.time.now()),
                    );
                }
                Message::TransferStatus(status) if id.destination == protocol::TOOL => {
                    return status;
                }
                _ => {}
            }
        }
        rig.time.set(rig.time.now() + 100);
    }
    panic!("no TransferStatus within 5 s");
}

#[test]
fn a_node_on_the_poll_loop_takes_a_pushed_table_stores_it_and_arbitrates_with_it() {
    let bus = Box::new(Bus::new());
    let tool = bus.endpoint(TOOL).unwrap();
    let monitor = bus.endpoint(MONITOR).unwrap();
    let mut rig = Rig::boot(&bus, Flash::new());

    // Booted without a table: its first heartbeat says so, at once.
    rig.turn();
    let first = messages(&monitor);
    assert!(
        first.iter().any(|(id, m)| id.source == Harness::NODE_ID
            && matches!(m, Message::Heartbeat(hb) if hb.state == NodeState::NoTable)),
        "{first:?}"
    );

    let v1 = image(
        &priority_table(&[TOPIC_A], Some(GATEWAY_OUT)),
        Harness::NODE_ID,
        1,
    );
    let status = push(&mut rig, &tool, &v1);
    assert_eq!(status.status, TransferStatusCode::Applied, "{status:?}");
    assert_eq!(status.running_version, 1);
    assert_eq!(rig.node.running().map(|r| r.stored), Some(true));
    // In the flash, where a restart finds it.
    let mut buf = vec![0u8; 8192];
    assert_eq!(rig.store.load(&mut buf).unwrap(), Some(&v1[..]));

    // A frame on topic A: delivered to the application and re-published on the gateway's id,
    // which the monitor sees with the same payload.
    let _ = messages(&monitor);
    let at = rig.time.now();
    tool.send(&frame(TOPIC_A, &[7, 8, 9]));
    rig.turn();
    assert_eq!(rig.deliveries.0.len(), 1);
    assert_eq!(rig.deliveries.0[0].0, 0);
    assert_eq!(rig.deliveries.0[0].1.payload(), &[7, 8, 9]);
    assert_eq!(rig.deliveries.0[0].2, at);
    let seen: Vec<Frame> = std::iter::from_fn(|| monitor.try_recv()).collect();
    assert!(
        seen.iter()
            .any(|f| f.raw_id() == (GATEWAY_OUT, false) && f.payload() == [7, 8, 9]),
        "{seen:?}"
    );

    // Heartbeats keep coming in virtual time, once a second, with the new table's version.
    let from = rig.time.now();
    rig.run_until(from + 3_000_000, 50_000);
    let heartbeats: Vec<u32> = messages(&monitor)
        .into_iter()
        .filter_map(|(id, m)| match m {
            Message::Heartbeat(hb) if id.source == Harness::NODE_ID => Some(hb.table_version),
            _ => None,
        })
        .collect();
    assert!(
        (3..=4).contains(&heartbeats.len()) && heartbeats.iter().all(|&v| v == 1),
        "{heartbeats:?}"
    );
    assert!(rig.watchdog.0 > 0);
}

#[test]
fn the_instant_a_turn_returns_is_the_next_heartbeat_or_feed_on_a_quiet_bus() {
    let bus = Box::new(Bus::new());
    let mut rig = Rig::boot(&bus, Flash::new());
    let wake = rig.turn();
    // Nothing due before the next feed (100 ms here) or the next heartbeat (1 s), whichever
    // is first: the feed.
    assert_eq!(wake, Feeds::FEED_INTERVAL_US);
    // Turned at that instant, it asks for the next feed.
    rig.time.set(wake);
    assert_eq!(rig.turn(), wake + Feeds::FEED_INTERVAL_US);
}

/// Pushes a table to a node whose flash erases in the background for 30 checks a page, with
/// `interference` before each turn (as [`push_with`]'s `before_turn`); checks that the save ended
/// (the transfer answered `Applied`, the image in the flash). The node's counters at the end.
fn assert_the_save_ends(
    interference: impl FnMut(&mut Rig<'_>, &Endpoint<'_, 3, 2048>, bool),
) -> pab_app::Counters {
    let bus = Box::new(Bus::new());
    let tool = bus.endpoint(TOOL).unwrap();
    let mut flash = Flash::new();
    flash.set_erase_polls(30);
    let mut rig = Rig::boot(&bus, flash);
    rig.turn();
    let v1 = image(&priority_table(&[TOPIC_A], None), Harness::NODE_ID, 1);
    let status = push_with(&mut rig, &tool, &v1, interference);
    assert_eq!(status.status, TransferStatusCode::Applied, "{status:?}");
    let mut buf = vec![0u8; 8192];
    assert_eq!(rig.store.load(&mut buf).unwrap(), Some(&v1[..]));
    rig.node.counters()
}

#[test]
fn a_save_under_a_stream_of_frames_still_ends() {
    // As many frames of another topic before every turn as a turn reads: no read finds the bus
    // quiet, so the save must step after frames once it has waited SAVE_STARVED_US.
    assert_the_save_ends(|_, tool, _| {
        for _ in 0..pab_app::RECEIVES_PER_TURN {
            tool.send(&frame(TOPIC_B, &[1]));
        }
    });
}

#[test]
fn a_driver_that_fails_every_read_does_not_starve_a_save() {
    // Once the whole image is in, every read of the driver fails. The save must still step:
    // a loop that stepped only when a read found no frame would never store it.
    let mut errors_before = None;
    let counters = assert_the_save_ends(|rig, _, sent| {
        if sent && errors_before.is_none() {
            // The last frame is on the bus: the node reads it, then its driver fails.
            rig.turn();
            rig.can.driver().failing = true;
            errors_before = Some(rig.node.counters().errors);
        }
    });
    // The reads did fail meanwhile, and the node counted them.
    assert!(counters.errors > errors_before.expect("the image was sent") + 10);
}

/// A driver whose transmit buffer is always full (a bus where nobody acknowledges) and that
/// never receives anything.
struct Unacknowledged;

#[derive(Debug)]
struct Never;

impl embedded_can::Error for Never {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Other
    }
}

impl embedded_can::nb::Can for Unacknowledged {
    type Frame = Frame;
    type Error = Never;
    fn transmit(&mut self, _frame: &Frame) -> nb::Result<Option<Frame>, Never> {
        Err(nb::Error::WouldBlock)
    }
    fn receive(&mut self) -> nb::Result<Frame, Never> {
        Err(nb::Error::WouldBlock)
    }
}

#[test]
fn a_bus_where_nobody_acknowledges_costs_frames_not_the_loop() {
    let time = VirtualTime::default();
    let mut can = EmbeddedCan::new(Unacknowledged, time.clock());
    let mut node = Box::new(TestNode::new(
        Config::new(Harness::NODE_ID).unwrap(),
        Instant::from_micros(0),
    ));
    let mut store = FlashStore::new(Flash::new(), 0..16 * 4096, 8192).unwrap();
    let mut node_loop = PollLoop::new();
    let mut watchdog = Feeds::default();
    node_loop.boot(&mut node, &mut store, Instant::from_micros(0));
    // A frame that finds no room is offered again at once: the turn asks to be called now.
    assert_eq!(
        node_loop
            .turn(&mut node, &mut can, &mut store, &mut (), &mut watchdog)
            .as_micros(),
        0
    );
    let errors_at_start = node.counters().errors;
    // 9 ms of turns, one every millisecond: the frame still waits, nothing given up.
    for ms in 1..=9 {
        time.set(ms * 1_000);
        node_loop.turn(&mut node, &mut can, &mut store, &mut (), &mut watchdog);
    }
    assert_eq!(node.counters().errors, errors_at_start);
    // From 10 ms on, a frame is given up every 10 ms and counted (the node's boot frames, then
    // the TxOverrun faults it raises for them, rate-limited), and every turn feeds.
    let mut given_up_at = Vec::new();
    for ms in 10..=200 {
        time.set(ms * 1_000);
        let before = node.counters().errors;
        node_loop.turn(&mut node, &mut can, &mut store, &mut (), &mut watchdog);
        if node.counters().errors > before {
            given_up_at.push(ms);
        }
    }
    // Each frame waited its 10 ms: one given up per 10 ms of turns, the first at 10 ms; the
    // boot queued five frames or more (its heartbeat group among them).
    assert_eq!(given_up_at.first(), Some(&10), "{given_up_at:?}");
    assert!(given_up_at.len() >= 5, "{given_up_at:?}");
    assert!(given_up_at.iter().all(|ms| ms % 10 == 0), "{given_up_at:?}");
    assert_eq!(watchdog.0, 201);
}
