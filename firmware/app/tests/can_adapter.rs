//! `EmbeddedCan`, the adapter from an `embedded_can::nb::Can` driver: frames and errors
//! converted, a frame the driver hands back for a higher-priority one sent later and in order,
//! the async `transmit` bounded in time, `testing::TestBus` as a driver and as a `CanBus`.

use std::cell::Cell;
use std::collections::VecDeque;
use std::rc::Rc;

use embedded_can::ErrorKind;
use pab_app::can::{FRAME_REFUSED, TRANSMIT_TIMED_OUT, TRANSMIT_TIMEOUT_US};
use pab_app::testing::TestBus;
use pab_app::{BusError, CanBus, EmbeddedCan};
use pab_core::{Frame, Instant};

fn frame(id: u32, extended: bool, data: &[u8]) -> Frame {
    Frame::with_raw_id(id, extended, data).unwrap()
}

/// A fixed clock at 0 (the sync adapter reads no time).
fn zero() -> Instant {
    Instant::from_micros(0)
}

#[test]
fn embedded_can_error_kinds_become_the_nodes_bus_errors() {
    let cases = [
        (ErrorKind::Overrun, BusError::Overrun),
        (ErrorKind::Stuff, BusError::Other(1)),
        (ErrorKind::Form, BusError::Other(2)),
        (ErrorKind::Acknowledge, BusError::Other(3)),
        (ErrorKind::Bit, BusError::Other(4)),
        (ErrorKind::Crc, BusError::Other(6)),
        (ErrorKind::Other, BusError::Other(0x0F)),
    ];
    for (kind, expected) in cases {
        assert_eq!(BusError::from(kind), expected, "{kind:?}");
    }
}

/// A driver with a bxCAN's transmit side: three mailboxes; when all are full, a frame of higher
/// priority than the lowest pending one takes its mailbox and that frame is handed back. `wire`
/// sends the pending frame of highest priority (what the controller does). Its receive side is a
/// queue of scripted results.
#[derive(Default)]
struct Mailboxes {
    pending: Vec<DriverFrame>,
    wire: Vec<DriverFrame>,
    incoming: VecDeque<nb::Result<DriverFrame, DriverError>>,
}

/// The driver's own frame type (not pab's): what the adapter converts to and from.
#[derive(Clone, Debug, PartialEq)]
struct DriverFrame {
    id: embedded_can::Id,
    remote: bool,
    dlc: usize,
    data: Vec<u8>,
}

impl embedded_can::Frame for DriverFrame {
    fn new(id: impl Into<embedded_can::Id>, data: &[u8]) -> Option<Self> {
        // A driver for a controller that carries at most 6 data bytes: the adapter must report
        // what it cannot send, not truncate it.
        (data.len() <= 6).then(|| DriverFrame {
            id: id.into(),
            remote: false,
            dlc: data.len(),
            data: data.to_vec(),
        })
    }
    fn new_remote(id: impl Into<embedded_can::Id>, dlc: usize) -> Option<Self> {
        (dlc <= 8).then(|| DriverFrame {
            id: id.into(),
            remote: true,
            dlc,
            data: Vec::new(),
        })
    }
    fn is_extended(&self) -> bool {
        matches!(self.id, embedded_can::Id::Extended(_))
    }
    fn is_remote_frame(&self) -> bool {
        self.remote
    }
    fn id(&self) -> embedded_can::Id {
        self.id
    }
    fn dlc(&self) -> usize {
        self.dlc
    }
    fn data(&self) -> &[u8] {
        &self.data
    }
}

#[derive(Debug)]
struct DriverError(ErrorKind);

impl embedded_can::Error for DriverError {
    fn kind(&self) -> ErrorKind {
        self.0
    }
}

impl Mailboxes {
    /// The controller wins arbitration with its highest-priority pending frame.
    fn wire_one(&mut self) {
        if let Some(best) = (0..self.pending.len()).min_by_key(|&i| self.pending[i].id) {
            let frame = self.pending.remove(best);
            self.wire.push(frame);
        }
    }
}

impl embedded_can::nb::Can for Mailboxes {
    type Frame = DriverFrame;
    type Error = DriverError;

    fn transmit(&mut self, frame: &DriverFrame) -> nb::Result<Option<DriverFrame>, DriverError> {
        if self.pending.len() < 3 {
            self.pending.push(frame.clone());
            return Ok(None);
        }
        // embedded-can orders identifiers by priority: the greatest is the lowest priority.
        let lowest = (0..3).max_by_key(|&i| self.pending[i].id).unwrap();
        if frame.id < self.pending[lowest].id {
            let handed_back = std::mem::replace(&mut self.pending[lowest], frame.clone());
            return Ok(Some(handed_back));
        }
        Err(nb::Error::WouldBlock)
    }

    fn receive(&mut self) -> nb::Result<DriverFrame, DriverError> {
        self.incoming
            .pop_front()
            .unwrap_or(Err(nb::Error::WouldBlock))
    }
}

fn raw(frame: &DriverFrame) -> (u32, Vec<u8>) {
    let id = match frame.id {
        embedded_can::Id::Standard(id) => u32::from(id.as_raw()),
        embedded_can::Id::Extended(id) => id.as_raw(),
    };
    (id, frame.data.clone())
}

#[test]
fn a_frame_the_driver_hands_back_is_sent_later_and_frames_of_one_id_keep_their_order() {
    let mut can = EmbeddedCan::new(Mailboxes::default(), zero);
    // Three frames of a low-priority stream fill the mailboxes...
    for seq in 0..3u8 {
        can.try_transmit(&frame(0x700, false, &[seq])).unwrap();
    }
    // ...a high-priority frame takes the mailbox of the last one, which the adapter keeps.
    can.try_transmit(&frame(0x100, false, &[0xAA])).unwrap();
    assert_eq!(can.driver().pending.len(), 3);
    // The stream's next frame must not overtake the one handed back: it waits while that one
    // finds no room.
    assert_eq!(
        can.try_transmit(&frame(0x700, false, &[3])),
        Err(nb::Error::WouldBlock)
    );
    // As the bus takes frames, the adapter hands the driver the kept frame, then the next.
    let mut offered = vec![frame(0x700, false, &[3]), frame(0x700, false, &[4])];
    offered.reverse();
    let mut retries = 0;
    while let Some(next) = offered.last().copied() {
        can.driver().wire_one();
        match can.try_transmit(&next) {
            Ok(()) => {
                offered.pop();
            }
            Err(nb::Error::WouldBlock) => retries += 1,
            Err(other) => panic!("{other:?}"),
        }
        assert!(retries < 10);
    }
    while !can.driver().pending.is_empty() {
        can.driver().wire_one();
        let _ = can.try_flush();
    }
    let wire: Vec<(u32, Vec<u8>)> = can.driver().wire.iter().map(raw).collect();
    assert_eq!(wire[0], (0x100, vec![0xAA]));
    let stream: Vec<u8> = wire
        .iter()
        .filter(|(id, _)| *id == 0x700)
        .map(|(_, data)| data[0])
        .collect();
    assert_eq!(stream, [0, 1, 2, 3, 4], "{wire:?}");
    assert_eq!(wire.len(), 6);
}

#[test]
fn a_frame_handed_back_goes_out_on_a_flush_when_nothing_else_is_sent() {
    let mut can = EmbeddedCan::new(Mailboxes::default(), zero);
    for seq in 0..3u8 {
        can.try_transmit(&frame(0x700, false, &[seq])).unwrap();
    }
    can.try_transmit(&frame(0x100, false, &[])).unwrap();
    assert_eq!(can.try_flush(), Err(nb::Error::WouldBlock));
    can.driver().wire_one();
    assert_eq!(can.try_flush(), Ok(()));
    assert_eq!(can.try_flush(), Ok(()));
    assert_eq!(can.driver().pending.len(), 3);
    assert!(can.driver().pending.iter().any(|f| f.data == [2]));
}

#[test]
fn frames_convert_both_ways_and_what_the_driver_cannot_hold_is_refused() {
    let mut driver = Mailboxes::default();
    let extended = DriverFrame {
        id: embedded_can::Id::Extended(embedded_can::ExtendedId::new(0x1234_5678).unwrap()),
        remote: false,
        dlc: 2,
        data: vec![1, 2],
    };
    let remote = DriverFrame {
        id: embedded_can::Id::Standard(embedded_can::StandardId::new(0x123).unwrap()),
        remote: true,
        dlc: 4,
        data: Vec::new(),
    };
    driver.incoming.push_back(Ok(extended));
    driver.incoming.push_back(Ok(remote));
    driver
        .incoming
        .push_back(Err(nb::Error::Other(DriverError(ErrorKind::Acknowledge))));
    let mut can = EmbeddedCan::new(driver, zero);
    assert_eq!(can.try_receive(), Ok(frame(0x1234_5678, true, &[1, 2])));
    let received = can.try_receive().unwrap();
    assert!(received.is_remote());
    assert_eq!(embedded_can::Frame::dlc(&received), 4);
    assert_eq!(received.raw_id(), (0x123, false));
    assert_eq!(can.try_receive(), Err(nb::Error::Other(BusError::Other(3))));
    assert_eq!(can.try_receive(), Err(nb::Error::WouldBlock));

    // Out again: the remote frame keeps its DLC; 8 data bytes do not fit this driver.
    can.try_transmit(&received).unwrap();
    assert_eq!(
        can.try_transmit(&frame(0x10, false, &[0; 8])),
        Err(nb::Error::Other(BusError::Other(FRAME_REFUSED)))
    );
    let pending = &can.driver().pending;
    assert_eq!(pending.len(), 1);
    assert!(pending[0].remote && pending[0].dlc == 4);
}

#[test]
fn the_async_transmit_gives_a_frame_up_after_the_timeout_on_the_adapters_clock() {
    // Full mailboxes that nothing drains; a clock that advances 1 ms at every reading.
    let mut driver = Mailboxes::default();
    for seq in 0..3u8 {
        driver.pending.push(DriverFrame {
            id: embedded_can::Id::Standard(embedded_can::StandardId::new(0x050).unwrap()),
            remote: false,
            dlc: 1,
            data: vec![seq],
        });
    }
    let micros = Rc::new(Cell::new(0u64));
    let reading = micros.clone();
    let clock = move || {
        reading.set(reading.get() + 1_000);
        Instant::from_micros(reading.get())
    };
    let mut can = EmbeddedCan::new(driver, clock);
    let sent = futures::executor::block_on(can.transmit(&frame(0x700, false, &[1])));
    assert_eq!(sent, Err(BusError::Other(TRANSMIT_TIMED_OUT)));
    // Given up once the clock had passed the timeout, not before, not much after.
    let waited = micros.get();
    assert!(
        (TRANSMIT_TIMEOUT_US..=TRANSMIT_TIMEOUT_US + 2_000).contains(&waited),
        "{waited} µs"
    );
    assert_eq!(can.driver().pending.len(), 3);
}

#[test]
fn the_async_receive_returns_the_driver_s_frame_once_there_is_one() {
    // The driver has nothing for three polls, then a frame: the polled future finds it.
    struct Late(u32);
    impl embedded_can::nb::Can for Late {
        type Frame = Frame;
        type Error = DriverError;
        fn transmit(&mut self, _frame: &Frame) -> nb::Result<Option<Frame>, DriverError> {
            Ok(None)
        }
        fn receive(&mut self) -> nb::Result<Frame, DriverError> {
            self.0 += 1;
            if self.0 > 3 {
                Ok(Frame::with_raw_id(0x42, false, &[4, 2]).unwrap())
            } else {
                Err(nb::Error::WouldBlock)
            }
        }
    }
    let mut can = EmbeddedCan::new(Late(0), zero);
    let received = futures::executor::block_on(can.receive());
    assert_eq!(received, Ok(frame(0x42, false, &[4, 2])));
    assert_eq!(can.driver().0, 4);
}

#[test]
fn every_frame_on_the_test_bus_reaches_every_other_endpoint_and_not_its_sender() {
    let bus = TestBus::<3, 4>::new();
    let a = bus.endpoint(0).unwrap();
    let b = bus.endpoint(1).unwrap();
    let c = bus.endpoint(2).unwrap();
    assert!(bus.endpoint(3).is_none());
    a.send(&frame(0x10, false, &[1]));
    b.send(&frame(0x20, false, &[2]));
    assert_eq!(a.try_recv(), Some(frame(0x20, false, &[2])));
    assert_eq!(a.try_recv(), None);
    assert_eq!(b.try_recv(), Some(frame(0x10, false, &[1])));
    assert_eq!(c.try_recv(), Some(frame(0x10, false, &[1])));
    assert_eq!(c.try_recv(), Some(frame(0x20, false, &[2])));
    assert_eq!(bus.sent(), 2);
}

#[test]
fn a_full_test_bus_queue_reports_its_loss_before_its_frames() {
    let bus = TestBus::<2, 2>::new();
    let sender = bus.endpoint(0).unwrap();
    for seq in 0..5u8 {
        sender.send(&frame(0x10, false, &[seq]));
    }
    // Through the embedded-can adapter: an overrun, then the two frames the queue held.
    let mut can = EmbeddedCan::new(bus.endpoint(1).unwrap(), zero);
    assert_eq!(can.try_receive(), Err(nb::Error::Other(BusError::Overrun)));
    assert_eq!(can.try_receive(), Ok(frame(0x10, false, &[0])));
    assert_eq!(can.try_receive(), Ok(frame(0x10, false, &[1])));
    assert_eq!(can.try_receive(), Err(nb::Error::WouldBlock));
    // As an async bus: the count.
    for seq in 0..4u8 {
        sender.send(&frame(0x10, false, &[seq]));
    }
    let mut receiver = bus.endpoint(1).unwrap();
    assert_eq!(
        futures::executor::block_on(CanBus::receive(&mut receiver)),
        Err(BusError::Dropped(2))
    );
    assert_eq!(
        futures::executor::block_on(CanBus::receive(&mut receiver)),
        Ok(frame(0x10, false, &[0]))
    );
}

#[test]
fn an_async_receive_on_the_test_bus_sleeps_until_a_frame_wakes_it() {
    use futures::task::noop_waker;
    use std::future::Future;
    use std::task::{Context, Poll};

    let bus = TestBus::<2, 4>::new();
    let sender = bus.endpoint(0).unwrap();
    let mut receiver = bus.endpoint(1).unwrap();
    // Woken: a waker that counts its wakes.
    let woken = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    struct Count(std::sync::Arc<std::sync::atomic::AtomicUsize>);
    impl std::task::Wake for Count {
        fn wake(self: std::sync::Arc<Self>) {
            self.0.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        }
    }
    let waker = std::task::Waker::from(std::sync::Arc::new(Count(woken.clone())));
    let mut context = Context::from_waker(&waker);
    let mut receive = Box::pin(CanBus::receive(&mut receiver));
    assert!(receive.as_mut().poll(&mut context).is_pending());
    assert!(receive.as_mut().poll(&mut context).is_pending());
    assert_eq!(woken.load(std::sync::atomic::Ordering::SeqCst), 0);
    sender.send(&frame(0x33, false, &[3]));
    assert_eq!(woken.load(std::sync::atomic::Ordering::SeqCst), 1);
    assert_eq!(
        receive.as_mut().poll(&mut context),
        Poll::Ready(Ok(frame(0x33, false, &[3])))
    );
    // A noop waker elsewhere changes nothing: a second receive, nothing queued, is pending.
    drop(receive);
    let noop = noop_waker();
    let mut receive = Box::pin(CanBus::receive(&mut receiver));
    assert!(
        receive
            .as_mut()
            .poll(&mut Context::from_waker(&noop))
            .is_pending()
    );
}
