//! The async runner, as the boards and the Linux node run it: `pab_app::run` on a bus (an
//! endpoint of `testing::TestBus`, the tool on another), with the real flash store
//! (`pab-storage`'s `FlashStore`) over an in-memory NOR flash, in real time on embassy's std time
//! driver. A table pushed while it runs is stored, and a node started again on the same flash
//! boots with it.

use crate::common;

use common::*;
use embassy_futures::select::{Either, select};
use pab_app::testing::{Endpoint, TestBus};
use pab_app::{BusError, CanBus, Config, SaveProgress, StoreError, TableStore};
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, Message, TransferStatusCode};
use pab_core::{Frame, Instant};
use pab_storage::testing::MemFlash;
use pab_storage::{FlashErrorKind, FlashStore};

/// The G474's geometry: 4 KiB pages, 8-byte writes; 64 KiB.
type Flash = MemFlash<16, 4096, 8>;

/// The node and the tool, each with room for a whole pushed image.
type Bus = TestBus<2, 4096>;
/// The tool's end of the bus (a script's).
type Tool = Endpoint<'static, 2, 4096>;

/// A bus for one test (leaked: a test's lifetime, and the scripts' futures borrow it).
fn bus() -> &'static Bus {
    Box::leak(Box::new(Bus::new()))
}

fn store(flash: Flash) -> FlashStore<Flash> {
    FlashStore::new(flash, 0..16 * 4096, 8192).unwrap()
}

fn now() -> Instant {
    pab_app::now()
}

/// The next of our messages from the node, skipping others, within 3 s.
async fn next_message(tool: &mut Tool) -> (protocol::FrameId, Message) {
    let deadline = embassy_time::Instant::now() + embassy_time::Duration::from_secs(3);
    loop {
        let frame = match select(tool.receive(), embassy_time::Timer::at(deadline)).await {
            Either::First(Ok(frame)) => frame,
            Either::First(Err(error)) => panic!("the tool's end of the bus: {error:?}"),
            Either::Second(()) => panic!("the node said nothing for 3 s"),
        };
        match Message::decode(&frame) {
            // The identity the node announces at start: not what these tests follow.
            Ok((_, Message::Identity { .. })) => {}
            Ok(decoded) => return decoded,
            Err(_) => {}
        }
    }
}

/// Pushes `image` over ISO-TP from the tool; returns the node's transfer status.
async fn push(image: &[u8], tool: &mut Tool) -> protocol::TransferStatus {
    push_then(image, tool, None).await
}

/// [`push`], sending `then` right after the image's last frame (before the node's answer).
async fn push_then(image: &[u8], tool: &mut Tool, then: Option<Frame>) -> protocol::TransferStatus {
    let mut sender = Sender::new(image, TxConfig::default()).unwrap();
    loop {
        match sender.poll(now()) {
            TxEvent::Send(data) => {
                let frame = Message::TableTransfer { data, len: 8 }
                    .to_frame(protocol::TOOL, Harness::NODE_ID);
                tool.send(&frame);
            }
            TxEvent::WaitUntil(_) => {
                // Wait for the flow control (or an early answer).
                match next_message(tool).await {
                    (id, Message::TableTransfer { data, len })
                        if id.destination == protocol::TOOL =>
                    {
                        sender.on_flow_control(&data[..len as usize], now());
                    }
                    (_, Message::TransferStatus(status)) => return status,
                    _ => {}
                }
            }
            TxEvent::Done => {
                if let Some(frame) = then {
                    tool.send(&frame);
                }
                break;
            }
            TxEvent::Failed(error) => panic!("transfer failed: {error:?}"),
        }
    }
    loop {
        if let (id, Message::TransferStatus(status)) = next_message(tool).await {
            assert_eq!(id.destination, protocol::TOOL);
            return status;
        }
    }
}

/// Runs a node on `flash` while `script` talks to it; returns the flash.
fn with_running_node<F, Fut>(flash: Flash, script: F) -> Flash
where
    F: FnOnce(Tool) -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    let bus = bus();
    let mut node_end = bus.endpoint(0).unwrap();
    let tool = bus.endpoint(1).unwrap();
    let mut store = store(flash);
    let mut node = Box::new(TestNode::new(Config::new(Harness::NODE_ID).unwrap(), now()));
    futures::executor::block_on(async {
        match select(
            pab_app::run(&mut node, &mut node_end, &mut store, &mut ()),
            script(tool),
        )
        .await
        {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    });
    store.into_flash()
}

#[test]
fn a_pushed_table_is_stored_in_flash_and_the_node_boots_with_it() {
    let v1 = image(&priority_table(&[TOPIC_A], None), Harness::NODE_ID, 1);
    let v2 = image(
        &priority_table(&[TOPIC_B, TOPIC_A], None),
        Harness::NODE_ID,
        2,
    );
    let mut flash_store = store(Flash::new());
    flash_store.save(&v1).unwrap();
    let flash = flash_store.into_flash();

    // First life: boots with v1, takes v2.
    let (v1_crc, v2_bytes) = (pab_core::image::read_header(&v1).unwrap().crc, v2.clone());
    let flash = with_running_node(flash, |mut tool| async move {
        let (id, first) = next_message(&mut tool).await;
        assert_eq!(id.source, Harness::NODE_ID);
        assert!(
            matches!(first, Message::Heartbeat(hb) if hb.table_version == 1),
            "{first:?}"
        );
        assert!(matches!(next_message(&mut tool).await.1,
            Message::TableStatus(s) if s.crc == v1_crc && s.stored));
        let status = push(&v2_bytes, &mut tool).await;
        assert_eq!(status.status, TransferStatusCode::Applied);
        assert_eq!(status.running_version, 2);
        // The new table arbitrates at once: B is delivered... and re-published nowhere (local).
        tool.send(&frame(TOPIC_B, &[1]));
        embassy_time::Timer::after(embassy_time::Duration::from_millis(20)).await;
    });

    // The flash holds v2 now.
    let mut reopened = store(flash);
    let mut buf = vec![0u8; 8192];
    let loaded = reopened.load(&mut buf).unwrap();
    assert_eq!(loaded, Some(&v2[..]));
    let flash = reopened.into_flash();

    // Second life: boots with v2.
    let v2_crc = pab_core::image::read_header(&v2).unwrap().crc;
    with_running_node(flash, |mut tool| async move {
        let (_, first) = next_message(&mut tool).await;
        assert!(
            matches!(first, Message::Heartbeat(hb) if hb.table_version == 2),
            "{first:?}"
        );
        assert!(matches!(next_message(&mut tool).await.1,
            Message::TableStatus(s) if s.crc == v2_crc && s.stored));
    });
}

/// The same through the async runner on the test bus, the table in CAN FD frames (TX_DL 64,
/// bit-rate switch, feature `fd`): stored in flash, and every flow control the node sent a CAN
/// FD frame with the bit-rate switch.
#[cfg(feature = "fd")]
#[test]
fn a_table_pushed_in_can_fd_frames_is_stored_and_answered_in_can_fd() {
    use pab_core::isotp::FdSender;
    use pab_core::isotp::fd::TxDl;
    let ids: Vec<u32> = (0..30).map(|k| 0x120 + k).collect();
    let v1 = image(&priority_table(&ids, None), Harness::NODE_ID, 1);
    let pushed = v1.clone();
    let flash = with_running_node(Flash::new(), |mut tool| async move {
        let transfer_id = Message::TableTransfer {
            data: [0; 8],
            len: 8,
        }
        .to_frame(protocol::TOOL, Harness::NODE_ID)
        .id();
        let mut sender = FdSender::new(&pushed, TxConfig::default(), TxDl::MAX).unwrap();
        let mut flow_controls = Vec::new();
        let status = loop {
            match sender.poll(now()) {
                TxEvent::Send(data) => {
                    tool.send(&Frame::fd(transfer_id, data.as_bytes(), true).unwrap());
                }
                TxEvent::WaitUntil(_) => {
                    // The flow control's frame itself, to see its kind.
                    let frame = tool.receive().await.unwrap();
                    if let Ok((id, Message::TableTransfer { .. })) = Message::decode(&frame)
                        && id.destination == protocol::TOOL
                    {
                        flow_controls.push(frame);
                        sender.on_flow_control(frame.payload(), now());
                    }
                }
                TxEvent::Done => {
                    break loop {
                        if let (_, Message::TransferStatus(status)) = next_message(&mut tool).await
                        {
                            break status;
                        }
                    };
                }
                TxEvent::Failed(error) => panic!("transfer failed: {error:?}"),
            }
        };
        assert_eq!(status.status, TransferStatusCode::Applied, "{status:?}");
        // 608 bytes: a First Frame of 62, then 9 of 63: two blocks, two flow controls.
        assert_eq!(flow_controls.len(), 2, "{flow_controls:?}");
        assert!(flow_controls.iter().all(|f| f.is_fd() && f.is_brs()));
    });
    let mut reopened = store(flash);
    let mut buf = vec![0u8; 8192];
    assert_eq!(reopened.load(&mut buf).unwrap(), Some(&v1[..]));
}

#[test]
fn the_node_reads_and_answers_frames_while_a_table_is_saved() {
    // Each page erase runs in the background for 30 checks of the flash: some 30 ms at the
    // runner's SAVE_POLL_US.
    let mut flash = Flash::new();
    flash.set_erase_polls(30);
    let v1 = image(&priority_table(&[TOPIC_A], None), Harness::NODE_ID, 1);
    // The first frame of another transfer, sent right after v1's last frame: the node refuses it
    // `Busy` while it stores v1. A runner that stored v1 before reading the next frame would
    // answer v1's transfer first.
    let mut other = Sender::new(&v1, TxConfig::default()).unwrap();
    let TxEvent::Send(data) = other.poll(now()) else {
        panic!("a first frame")
    };
    let second = Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, Harness::NODE_ID);
    let pushed = v1.clone();
    let flash = with_running_node(flash, |mut tool| async move {
        let (_, first) = next_message(&mut tool).await;
        assert!(matches!(first, Message::Heartbeat(_)), "{first:?}");
        let during = push_then(&pushed, &mut tool, Some(second)).await;
        assert_eq!(during.status, TransferStatusCode::Busy, "{during:?}");
        let stored = loop {
            if let (_, Message::TransferStatus(status)) = next_message(&mut tool).await {
                break status;
            }
        };
        assert_eq!(stored.status, TransferStatusCode::Applied, "{stored:?}");
        assert_eq!(stored.running_version, 1);
    });
    let mut reopened = store(flash);
    let mut buf = vec![0u8; 8192];
    assert_eq!(reopened.load(&mut buf).unwrap(), Some(&v1[..]));
}

#[test]
fn an_empty_flash_boots_without_a_table() {
    with_running_node(Flash::new(), |mut tool| async move {
        let (_, first) = next_message(&mut tool).await;
        assert!(matches!(first,
            Message::Heartbeat(hb) if hb.state == protocol::NodeState::NoTable && hb.table_version == 0));
    });
}

/// A driver that fails at once, forever.
struct BrokenBus {
    receives: u32,
}

impl CanBus for BrokenBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        self.receives += 1;
        Err(BusError::BusOff)
    }

    async fn transmit(&mut self, _frame: &Frame) -> Result<(), BusError> {
        Err(BusError::BusOff)
    }
}

#[test]
fn a_bus_that_keeps_failing_does_not_make_the_node_spin() {
    let mut bus = BrokenBus { receives: 0 };
    let mut store = store(Flash::new());
    let mut node = Box::new(TestNode::new(Config::new(Harness::NODE_ID).unwrap(), now()));
    futures::executor::block_on(async {
        let window = embassy_time::Timer::after(embassy_time::Duration::from_millis(100));
        match select(
            pab_app::run(&mut node, &mut bus, &mut store, &mut ()),
            window,
        )
        .await
        {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    });
    // One attempt per millisecond at most (and at least a few: it keeps trying).
    assert!(
        (5..=110).contains(&bus.receives),
        "{} receives in 100 ms",
        bus.receives
    );
    assert_eq!(node.state(), protocol::NodeState::NoTable);
    assert!(node.counters().errors >= 5);
}

/// A store whose medium cannot be read (a flash driver error, a file that is not one).
struct UnreadableStore;

impl TableStore for UnreadableStore {
    fn load<'b>(&mut self, _buf: &'b mut [u8]) -> Result<Option<&'b [u8]>, StoreError> {
        Err(StoreError::Flash(FlashErrorKind::Other))
    }

    fn start_save(&mut self, _image: &[u8]) -> Result<(), StoreError> {
        Err(StoreError::Flash(FlashErrorKind::Other))
    }

    fn continue_save(&mut self, _image: &[u8]) -> Result<SaveProgress, StoreError> {
        Err(StoreError::NoSave)
    }
}

#[test]
fn a_store_that_cannot_be_read_raises_the_stored_table_fault() {
    let bus = bus();
    let mut node_end = bus.endpoint(0).unwrap();
    let mut tool = bus.endpoint(1).unwrap();
    let mut node = Box::new(TestNode::new(Config::new(Harness::NODE_ID).unwrap(), now()));
    futures::executor::block_on(async {
        let script = async {
            // The fault that says why, first (it outranks the heartbeat group queued with it),
            // then the heartbeat that says "no table".
            let mut fault_seen = false;
            loop {
                match next_message(&mut tool).await {
                    (_, Message::Heartbeat(hb)) if fault_seen => {
                        assert_eq!(hb.state, protocol::NodeState::NoTable);
                        break;
                    }
                    (_, Message::Fault(fault)) => {
                        assert_eq!(fault.code, protocol::FaultCode::BadStoredTable);
                        assert_eq!(
                            fault.detail,
                            [
                                protocol::STORE_UNREADABLE,
                                protocol::StoreFailure::Read.code(),
                                0,
                                0,
                                0
                            ]
                        );
                        fault_seen = true;
                    }
                    (_, Message::Heartbeat(hb)) => panic!("a heartbeat before the fault: {hb:?}"),
                    _ => {}
                }
            }
        };
        match select(
            pab_app::run(&mut node, &mut node_end, &mut UnreadableStore, &mut ()),
            script,
        )
        .await
        {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    });
    assert_eq!(node.state(), protocol::NodeState::NoTable);
}

/// A bus where nobody acknowledges: each send takes the G474 driver's 10 ms timeout and fails;
/// the only frame it ever brings is `first` (the tool's request for the diagnostic stream), then
/// nothing. It counts the sends.
struct DeadBus {
    first: Option<Frame>,
    sends: std::rc::Rc<std::cell::Cell<usize>>,
}

impl CanBus for DeadBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        match self.first.take() {
            Some(frame) => Ok(frame),
            None => std::future::pending().await,
        }
    }

    async fn transmit(&mut self, _frame: &Frame) -> Result<(), BusError> {
        embassy_time::Timer::after(embassy_time::Duration::from_millis(10)).await;
        self.sends.set(self.sends.get() + 1);
        Err(BusError::Overrun)
    }
}

/// A watchdog that notes how many sends the bus had seen at each feed.
struct CountingWatchdog {
    sends: std::rc::Rc<std::cell::Cell<usize>>,
    at_feeds: Vec<usize>,
}

impl pab_app::Watchdog for CountingWatchdog {
    const FEED_INTERVAL_US: u64 = 100_000;
    fn feed(&mut self) {
        self.at_feeds.push(self.sends.get());
    }
}

#[test]
fn a_dead_bus_with_the_diagnostic_stream_on_does_not_starve_the_watchdog() {
    // A port of 32 connections sampled 200 times a second: 6 400 samples a second queued as the
    // outbox has room, far more than a dead bus drains (one send per 10 ms). Each failed send is
    // a point where the node queues more: the loop must still come back to the watchdog.
    let ids: Vec<u32> = (0..32).map(|k| 0x100 + k).collect();
    let table = priority_table(&ids, None);
    let mut store = store(Flash::new());
    store.save(&image(&table, Harness::NODE_ID, 1)).unwrap();
    let control = Message::DiagnosticControl(protocol::DiagnosticControl {
        rate_hz: 200,
        ports: 1,
    })
    .to_frame(protocol::TOOL, Harness::NODE_ID);
    let sends = std::rc::Rc::new(std::cell::Cell::new(0));
    let mut bus = DeadBus {
        first: Some(control),
        sends: sends.clone(),
    };
    let mut watchdog = CountingWatchdog {
        sends: sends.clone(),
        at_feeds: Vec::new(),
    };
    let mut node = Box::new(TestNode::new(Config::new(Harness::NODE_ID).unwrap(), now()));
    futures::executor::block_on(async {
        let window = embassy_time::Timer::after(embassy_time::Duration::from_millis(1_000));
        match select(
            pab_app::run_watched(&mut node, &mut bus, &mut store, &mut (), &mut watchdog),
            window,
        )
        .await
        {
            Either::First(never) => match never {},
            Either::Second(()) => {}
        }
    });
    let feeds = &watchdog.at_feeds;
    // It kept sending (the bus is dead, not the node)...
    assert!(sends.get() >= 20, "{} sends in 1 s", sends.get());
    // ...and fed the watchdog all along: counted in sends, not in time, so that a slow machine
    // cannot make it fail. The G474's watchdog fires after 500 ms, 50 failed sends of 10 ms;
    // at most half of that between two feeds, and since the last one.
    const MOST: usize = 25;
    let most = feeds
        .windows(2)
        .map(|pair| pair[1] - pair[0])
        .max()
        .unwrap_or(0);
    assert!(most <= MOST, "{most} sends between two feeds ({feeds:?})");
    assert!(
        sends.get() - feeds.last().copied().unwrap_or(0) <= MOST,
        "{} sends in all, the last feed after {feeds:?}",
        sends.get()
    );
}
