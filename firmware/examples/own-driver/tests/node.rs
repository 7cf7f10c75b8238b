//! The example's node code on the host: the same `OwnDriverNode`, `Micros32` and `Application`
//! that the STM32F405 firmware runs, with pab-app's test bus in place of bxCAN and a counter the
//! test sets in place of TIM2. Two nodes, a behaviour and a monitor on one bus; the counter wraps
//! during the run.

use std::cell::Cell;
use std::rc::Rc;

use pab_app::testing::{Endpoint, TestBus};
use pab_app::{BoardNode, Clock, Config, EmbeddedCan, TableStore, Watchdog};
use pab_core::protocol::{Message, NodeState};
use pab_core::{Frame, Instant};
use pab_own_driver::{Micros32, OwnDriverNode};
use pab_storage::FlashStore;
use pab_storage::testing::MemFlash;

/// The firmware's store: two 12 KiB slots in RAM.
type RamFlash = MemFlash<6, 4096, 8>;
type Store = FlashStore<RamFlash>;
type Bus = TestBus<4, 512>;
const ARM: usize = 0;
const OTHER: usize = 1;
const BEHAVIOUR: usize = 2;
const MONITOR: usize = 3;

/// The arm's table of Take and Return, compiled for node 1 (`pabctl compile
/// examples/take-and-return.toml`): its port delivers `object_pos` (0x110) once connection C1
/// is active, from the sixth frame 10 ms apart (σ = 0.2, τ = 3 s), and re-publishes it on 0x200.
const ARM_TABLE: &[u8] =
    include_bytes!("../../../boards/mps2-an386/tables/take-and-return/arm.pab");

/// TIM2's count, which the test moves: it starts half a second before it wraps.
#[derive(Clone)]
struct Tim2(Rc<Cell<u32>>);

impl Tim2 {
    fn read(&self) -> impl FnMut() -> u32 + use<> {
        let count = self.0.clone();
        move || count.get()
    }
    fn advance(&self, micros: u32) {
        self.0.set(self.0.get().wrapping_add(micros));
    }
}

#[derive(Default)]
struct Feeds(Rc<Cell<u32>>);

impl Watchdog for Feeds {
    const FEED_INTERVAL_US: u64 = 100_000;
    fn feed(&mut self) {
        self.0.set(self.0.get() + 1);
    }
}

type Firmware<'a> =
    OwnDriverNode<'a, Endpoint<'a, 4, 512>, Micros32<Box<dyn FnMut() -> u32>>, Store, Feeds>;

/// What the firmware's `main` does once its peripherals are up: the bus adapter over the driver
/// and the clock, the node booted from its store.
fn firmware<'a>(
    bus: &'a Bus,
    endpoint: usize,
    tim2: &Tim2,
    node: &'a mut BoardNode,
    store: &'a mut Store,
    feeds: &Rc<Cell<u32>>,
) -> Firmware<'a> {
    let read: Box<dyn FnMut() -> u32> = Box::new(tim2.read());
    let can = EmbeddedCan::new(bus.endpoint(endpoint).unwrap(), Micros32::new(read));
    OwnDriverNode::boot(node, can, store, Feeds(feeds.clone()))
}

/// Node `id`, made at the clock's 0.
fn node(id: u8) -> Box<BoardNode> {
    Box::new(BoardNode::new(
        Config::new(id).unwrap(),
        Instant::from_micros(0),
    ))
}

fn store(image: Option<&[u8]>) -> Box<Store> {
    let mut store = Box::new(FlashStore::new(RamFlash::new(), 0..6 * 4096, 12 * 1024).unwrap());
    if let Some(image) = image {
        store.save(image).unwrap();
    }
    store
}

#[test]
fn the_arm_node_arbitrates_object_pos_lights_its_led_and_re_publishes_to_the_other_node() {
    let bus = Box::new(Bus::new());
    let behaviour = bus.endpoint(BEHAVIOUR).unwrap();
    let monitor = bus.endpoint(MONITOR).unwrap();
    let tim2 = Tim2(Rc::new(Cell::new(u32::MAX - 500_000)));
    let feeds = Rc::new(Cell::new(0));
    let (mut arm_node, mut other_node) = (node(1), node(2));
    let (mut arm_store, mut other_store) = (store(Some(ARM_TABLE)), store(None));
    let mut arm = firmware(&bus, ARM, &tim2, &mut arm_node, &mut arm_store, &feeds);
    let mut other = firmware(
        &bus,
        OTHER,
        &tim2,
        &mut other_node,
        &mut other_store,
        &feeds,
    );
    // Booted: the arm with its stored table, the other without one.
    let version = pab_core::image::read_header(ARM_TABLE)
        .unwrap()
        .table_version;
    assert_eq!(
        arm.node().running().map(|r| r.header.table_version),
        Some(version)
    );
    assert!(other.node().running().is_none());

    // The behaviour publishes object_pos ten times, 10 ms apart; the firmware turns its loops
    // every millisecond of TIM2's count (which wraps at 0.5 s).
    let mut published = 0u8;
    for ms in 0..=1_200u32 {
        if ms % 10 == 0 && published < 10 {
            behaviour.send(&Frame::with_raw_id(0x110, false, &[published, 0, 0, 0]).unwrap());
            published += 1;
        }
        arm.turn();
        other.turn();
        tim2.advance(1_000);
    }

    // From the sixth frame on, the arm's port delivers (to the application: the LED is on for a
    // position away from 0) and re-publishes on 0x200.
    assert_eq!(arm.application().delivered(), 5);
    let (port, last) = arm.application().last().unwrap();
    assert_eq!((port, last.payload()), (0, &[9, 0, 0, 0][..]));
    assert!(arm.application().led());
    let on_the_bus: Vec<Frame> = std::iter::from_fn(|| monitor.try_recv()).collect();
    let republished: Vec<u8> = on_the_bus
        .iter()
        .filter(|frame| frame.raw_id() == (0x200, false))
        .map(|frame| frame.payload()[0])
        .collect();
    assert_eq!(republished, [5, 6, 7, 8, 9]);
    // The other node (no table) read them all: the ten object_pos, the five re-published, the
    // arm's own frames.
    assert!(other.node().counters().received >= 15);
    assert_eq!(other.application().delivered(), 0);

    // Both nodes' heartbeats are on the bus, the first at boot and the next a second later on
    // a clock that went through TIM2's wrap.
    let heartbeats = |source: u8| -> Vec<(NodeState, u32)> {
        on_the_bus
            .iter()
            .filter_map(|frame| match Message::decode(frame) {
                Ok((id, Message::Heartbeat(hb))) if id.source == source => {
                    Some((hb.state, hb.uptime_s))
                }
                _ => None,
            })
            .collect()
    };
    let arm_heartbeats = heartbeats(1);
    assert!(
        arm_heartbeats
            .iter()
            .all(|(state, _)| *state == NodeState::Operational)
            && arm_heartbeats.iter().map(|(_, up)| *up).collect::<Vec<_>>() == [0, 1],
        "{arm_heartbeats:?}"
    );
    let other_heartbeats = heartbeats(2);
    assert!(
        other_heartbeats
            .iter()
            .all(|(state, _)| *state == NodeState::NoTable)
            && other_heartbeats.len() == 2,
        "{other_heartbeats:?}"
    );
    // The loops fed the watchdog at every turn.
    assert!(feeds.get() >= 2 * 1_200);
}

#[test]
fn the_clock_counts_through_the_wrap_of_a_32_bit_counter() {
    let count = Rc::new(Cell::new(u32::MAX - 10));
    let read = {
        let count = count.clone();
        move || count.get()
    };
    let mut clock = Micros32::new(read);
    assert_eq!(clock.now(), Instant::from_micros(0));
    count.set(u32::MAX);
    assert_eq!(clock.now(), Instant::from_micros(10));
    count.set(4);
    assert_eq!(clock.now(), Instant::from_micros(15));
    // Many wraps, read often enough: the total keeps growing past 32 bits.
    for _ in 0..3 {
        count.set(count.get().wrapping_add(1 << 31));
        clock.now();
        count.set(count.get().wrapping_add(1 << 31));
        clock.now();
    }
    assert_eq!(clock.now(), Instant::from_micros(15 + 3 * (1 << 32)));
}
