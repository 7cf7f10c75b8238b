//! An in-process CAN bus for tests (feature `test-bus`): [`TestBus`], any number of endpoints,
//! every frame one sends received by all the others, no socket and no kernel module. Nodes, a
//! tool and a monitor can share one in a host test, through the `embedded-can` driver trait
//! (the path of a firmware without embassy: [`crate::EmbeddedCan`], [`crate::PollLoop`]) or as
//! a [`CanBus`] (an async loop).

use core::cell::RefCell;
use core::future::poll_fn;
use core::task::{Poll, Waker};

use heapless::Deque;
use pab_core::Frame;

use crate::bus::{BusError, CanBus};

/// An ideal CAN bus between `ENDPOINTS` endpoints, each with a receive queue of `DEPTH` frames.
///
/// What it models: a frame sent by one endpoint is in every other endpoint's queue when `send`
/// returns, in the order sent (the sender does not receive its own frames, as a CAN controller
/// does not). A queue that is full loses the frame, and its endpoint's next read reports the loss
/// (an overrun). What it does not model: bit timing, arbitration between frames sent "at the same
/// time" (they go in the order of the calls), error frames, a bus where nobody acknowledges, or
/// time at all (tests bring their own clock).
///
/// Single-threaded (`RefCell`; not `Sync`): endpoints borrow the bus, and one thread runs them
/// all (a test's loop, or one executor). No allocation: the bus holds `ENDPOINTS × DEPTH` frames
/// of 16 bytes (keep a large one in a `Box` or a `static`).
pub struct TestBus<const ENDPOINTS: usize, const DEPTH: usize> {
    state: RefCell<State<ENDPOINTS, DEPTH>>,
}

struct State<const ENDPOINTS: usize, const DEPTH: usize> {
    queues: [Deque<Frame, DEPTH>; ENDPOINTS],
    /// Frames each endpoint's full queue could not take since its last report of them.
    lost: [u32; ENDPOINTS],
    /// The task waiting for each endpoint's next frame (an async `receive`).
    wakers: [Option<Waker>; ENDPOINTS],
    /// Frames sent on the bus since it was made.
    sent: u64,
}

impl<const ENDPOINTS: usize, const DEPTH: usize> Default for TestBus<ENDPOINTS, DEPTH> {
    fn default() -> Self {
        TestBus::new()
    }
}

impl<const ENDPOINTS: usize, const DEPTH: usize> TestBus<ENDPOINTS, DEPTH> {
    /// A bus with every queue empty.
    pub const fn new() -> TestBus<ENDPOINTS, DEPTH> {
        TestBus {
            state: RefCell::new(State {
                queues: [const { Deque::new() }; ENDPOINTS],
                lost: [0; ENDPOINTS],
                wakers: [const { None }; ENDPOINTS],
                sent: 0,
            }),
        }
    }

    /// Endpoint `index` (0 to `ENDPOINTS - 1`), or `None` past the last. Endpoints are handles:
    /// two of one index share its queue (each frame goes to whichever reads it first).
    pub fn endpoint(&self, index: usize) -> Option<Endpoint<'_, ENDPOINTS, DEPTH>> {
        (index < ENDPOINTS).then_some(Endpoint { bus: self, index })
    }

    /// Frames sent on the bus so far, by all endpoints.
    pub fn sent(&self) -> u64 {
        self.state.try_borrow().map_or(0, |state| state.sent)
    }

    /// `frame` from endpoint `from` into every other endpoint's queue; wakes their waiting tasks.
    fn send(&self, from: usize, frame: &Frame) {
        let mut woken: [Option<Waker>; ENDPOINTS] = [const { None }; ENDPOINTS];
        // The bus is borrowed only inside its own methods, which never call each other while
        // they hold it: the borrow cannot fail.
        if let Ok(mut state) = self.state.try_borrow_mut() {
            let state = &mut *state;
            state.sent = state.sent.wrapping_add(1);
            let endpoints = state
                .queues
                .iter_mut()
                .zip(state.lost.iter_mut())
                .zip(state.wakers.iter_mut())
                .zip(woken.iter_mut())
                .enumerate();
            for (index, (((queue, lost), waker), woken)) in endpoints {
                if index == from {
                    continue;
                }
                if queue.push_back(*frame).is_err() {
                    *lost = lost.saturating_add(1);
                }
                *woken = waker.take();
            }
        }
        // Woken after the borrow ends, so that an executor that polls at once finds the bus free.
        for waker in woken.into_iter().flatten() {
            waker.wake();
        }
    }

    /// What endpoint `index` reads next: a loss first (then the frames that were in the queue),
    /// or a frame, or nothing (`None`). With `waker`, a read that finds nothing leaves it to be
    /// woken by the next frame.
    fn read(&self, index: usize, waker: Option<&Waker>) -> Option<Result<Frame, u32>> {
        let mut state = self.state.try_borrow_mut().ok()?;
        let state = &mut *state;
        if let Some(lost) = state.lost.get_mut(index)
            && *lost > 0
        {
            return Some(Err(core::mem::take(lost)));
        }
        let frame = state.queues.get_mut(index)?.pop_front();
        if frame.is_none()
            && let (Some(waker), Some(slot)) = (waker, state.wakers.get_mut(index))
        {
            match slot {
                Some(waiting) if waiting.will_wake(waker) => {}
                _ => *slot = Some(waker.clone()),
            }
        }
        frame.map(Ok)
    }
}

/// One node's (or tool's, or monitor's) connection to a [`TestBus`]: an
/// [`embedded_can::nb::Can`] driver and a [`CanBus`].
pub struct Endpoint<'bus, const ENDPOINTS: usize, const DEPTH: usize> {
    bus: &'bus TestBus<ENDPOINTS, DEPTH>,
    index: usize,
}

impl<const ENDPOINTS: usize, const DEPTH: usize> Endpoint<'_, ENDPOINTS, DEPTH> {
    /// Which endpoint of its bus this is.
    pub fn index(&self) -> usize {
        self.index
    }

    /// Sends `frame` to every other endpoint at once (a test script's send: never fails).
    pub fn send(&self, frame: &Frame) {
        self.bus.send(self.index, frame);
    }

    /// The next frame waiting for this endpoint, if any; frames lost to a full queue are skipped
    /// silently (a script that wants to see them reads through [`embedded_can::nb::Can`]).
    pub fn try_recv(&self) -> Option<Frame> {
        loop {
            match self.bus.read(self.index, None)? {
                Ok(frame) => return Some(frame),
                Err(_lost) => {}
            }
        }
    }
}

/// A frame lost to a full queue, as the endpoint's driver reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Overrun {
    /// Frames lost since the last report.
    pub lost: u32,
}

impl embedded_can::Error for Overrun {
    fn kind(&self) -> embedded_can::ErrorKind {
        embedded_can::ErrorKind::Overrun
    }
}

/// As a driver: `transmit` always has room (and never hands a frame back), `receive` reports an
/// overrun before the frames that were queued when the loss happened.
impl<const ENDPOINTS: usize, const DEPTH: usize> embedded_can::nb::Can
    for Endpoint<'_, ENDPOINTS, DEPTH>
{
    type Frame = Frame;
    type Error = Overrun;

    fn transmit(&mut self, frame: &Frame) -> nb::Result<Option<Frame>, Overrun> {
        self.send(frame);
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<Frame, Overrun> {
        match self.bus.read(self.index, None) {
            Some(Ok(frame)) => Ok(frame),
            Some(Err(lost)) => Err(nb::Error::Other(Overrun { lost })),
            None => Err(nb::Error::WouldBlock),
        }
    }
}

/// As an async bus: `receive` waits (woken by the next frame sent to it, no polling) and reports
/// a loss as [`BusError::Dropped`] with the count; `transmit` never waits. Cancel-safe.
impl<const ENDPOINTS: usize, const DEPTH: usize> CanBus for Endpoint<'_, ENDPOINTS, DEPTH> {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        poll_fn(
            |context| match self.bus.read(self.index, Some(context.waker())) {
                Some(Ok(frame)) => Poll::Ready(Ok(frame)),
                Some(Err(lost)) => Poll::Ready(Err(BusError::Dropped(lost))),
                None => Poll::Pending,
            },
        )
        .await
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        self.send(frame);
        Ok(())
    }
}
