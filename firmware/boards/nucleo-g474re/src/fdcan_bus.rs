//! The application's [`CanBus`] over embassy-stm32's FDCAN driver, with queues of its own.
//!
//! The driver runs in its unbuffered mode, and [`Interrupt`], FDCAN1_IT0's handler, does what the
//! driver's own handler does in that mode (it clears the flags and recovers from bus-off; its
//! wakers wake nobody who matters), then what the driver's buffered mode did, in the same order
//! and under the same conditions: it moves one frame from the [`TX_QUEUE`]-frame transmit queue
//! into the controller's TX FIFO if the FIFO has room, then, if a frame arrived, drains the
//! hardware RX FIFOs (3 frames each on the G4) into the [`RX_QUEUE`]-frame receive queue, so
//! frames that arrive while the node task is busy (arbitrating, waiting to transmit) wait there
//! instead of overflowing the hardware FIFO. Both go through the driver's own reads and writes of the
//! message RAM (`CanRx::read`, `CanTx::write`, polled once each). Why not the buffered mode: its
//! queues are `embassy_sync` channels behind `dyn` references, whose every method, and the FD
//! frames' copies of the driver's reads and writes, the firmware carried: some 2 KB of flash.
//!
//! **Cancel safety.** The runner drops a pending [`CanBus::receive`] when its timer fires first.
//! `receive` takes an entry out of the queue only in the poll that returns it, so dropping the
//! future before it completed leaves every frame in the queue for the next call. The periodic
//! check of the controller state in between keeps its memory in `self.mode`, updated only in the
//! poll that returns the change, so no transition is lost either.
//!
//! Transmitting, **by priority**: frames go into the transmit queue, and the interrupt hands the
//! controller the queued frame that would win arbitration (the lowest identifier, as the bus
//! compares them: `pab_core::Frame::arbitration_rank`; among equal identifiers the oldest, so ISO-TP's frames and
//! a diagnostic round keep their order), one at a time: only when the controller's TX FIFO is
//! empty, so a high-priority frame waits behind at most the one frame of ours already on its way,
//! never behind a FIFO of losers. The FDCAN's own priority mode (`TxBufferMode::Priority`) is not
//! used: it sends equal identifiers by buffer number, not in queue order, which would reorder
//! ISO-TP's frames. When the queue stays full for [`TX_TIMEOUT`] (nobody acknowledges, bus-off)
//! the frame is dropped and reported, so the node keeps reading instead of blocking behind a
//! dead bus.
//!
//! Errors: the driver reports protocol errors (the controller's last error code: stuff, form,
//! acknowledge, bit, CRC) when it finds no more frame to read. Error-passive and bus-off are
//! latched by the interrupt when the controller enters them (IR.EP, IR.BO), so a bus-off that
//! recovers within milliseconds (the recovery sequence takes some 2.8 ms at 500 kbit/s) is still
//! reported; `receive` reports each latched entry, then looks at the controller state (also every
//! [`STATE_POLL`]) for the way back (`ErrorPassive`, `BusOff`, `Recovered`). Bus-off recovery is
//! automatic (the driver restarts the controller after the bus-off sequence).
//!
//! Lost frames are counted ([`BusError::Dropped`]): a frame that finds the receive queue full,
//! and a frame the controller itself lost into a full RX FIFO (IR.RF0L, IR.RF1L: the FIFO says
//! that it lost, not how many, so each such flag counts one, the least it lost).

use core::cell::RefCell;
use core::future::{Future, poll_fn};
use core::pin::pin;
use core::sync::atomic::{AtomicU8, AtomicU32, Ordering};
use core::task::{Context, Poll, Waker};

use critical_section::Mutex;
use embassy_futures::select::{Either, select};
use embassy_stm32::can::enums::BusErrorMode;
use embassy_stm32::can::frame::Header;
use embassy_stm32::can::{self, Can, CanRx, CanTx, Properties};
use embassy_stm32::interrupt::typelevel::{FDCAN1_IT0, Handler};
use embassy_stm32::interrupt::{self, InterruptExt};
use embassy_stm32::pac::FDCAN1;
use embassy_sync::waitqueue::AtomicWaker;
use embassy_time::{Duration, Instant, Timer, with_deadline};
use heapless::Deque;
use pab_app::{BusError, CanBus};
use pab_core::Frame;

/// Frames the RX queue holds (about 8 ms of a fully loaded bus at 500 kbit/s).
pub const RX_QUEUE: usize = 32;
/// Frames the TX queue holds (a heartbeat group and an ISO-TP flow control with room to spare).
pub const TX_QUEUE: usize = 16;
/// How long `transmit` waits for room in the TX queue before it drops the frame.
pub const TX_TIMEOUT: Duration = Duration::from_millis(10);
/// How often `receive` looks at the controller state (error-active, error-passive, bus-off).
pub const STATE_POLL: Duration = Duration::from_millis(50);

/// The driver's frame in the queues: its classic frame, or with CAN FD (feature `fd`) its FD
/// frame, which carries classic frames too (its header says which).
#[cfg(not(feature = "fd"))]
type DriverFrame = can::frame::Frame;
#[cfg(feature = "fd")]
type DriverFrame = can::frame::FdFrame;

/// What the interrupt and the node task share: the two queues.
struct Queues {
    /// Received frames, or the protocol error read after them, oldest first.
    rx: Deque<Result<DriverFrame, can::enums::BusError>, RX_QUEUE>,
    /// Frames to transmit, oldest first, each with its `Frame::arbitration_rank`.
    tx: heapless::Vec<(u32, DriverFrame), TX_QUEUE>,
}

/// Empty queues are all zeros: in .bss, not in flash.
static QUEUES: Mutex<RefCell<Queues>> = Mutex::new(RefCell::new(Queues {
    rx: Deque::new(),
    tx: heapless::Vec::new(),
}));
/// The driver's two halves, the interrupt's alone once [`FdcanBus::new`] put them here (apart
/// from the queues: `None` is not all zeros).
static HALVES: Mutex<RefCell<Option<(CanTx<'static>, CanRx<'static>)>>> =
    Mutex::new(RefCell::new(None));
/// The node task waiting for a received frame.
static RX_WAKER: AtomicWaker = AtomicWaker::new();
/// Frames lost before the node read them, since boot; wrapping.
static LOST: AtomicU32 = AtomicU32::new(0);
/// The controller states entered since `receive` last looked ([`BUS_OFF`], [`PASSIVE`]).
static ENTERED: AtomicU8 = AtomicU8::new(0);
const BUS_OFF: u8 = 1;
const PASSIVE: u8 = 2;
/// The node task waiting for room in the transmit queue.
static TX_WAKER: AtomicWaker = AtomicWaker::new();
/// FDCAN1_IT0's handler, in place of the driver's `can::IT0InterruptHandler` (whose binding
/// `main.rs` claims for it): what the driver's handler does with the driver in its unbuffered
/// mode, then the queues served as the driver's buffered mode served them ([`serve`]).
///
/// Why not the driver's own handler: it serves the driver's three modes, chosen at run time from
/// a `static`, so its buffered paths (the FD frames' read and write, the RX FIFOs' drain into its
/// channels: `RxMode::on_interrupt`) came along, some 2.5 KB of flash, though the driver never
/// runs buffered here. What it does unbuffered (embassy-stm32 0.6, `can/fdcan.rs`), done here:
/// - it acknowledges TC, TEFN, each RX FIFO's new-message flag and the bus-off status change
///   that it read set (write 1 to clear; here in one write);
/// - it wakes the tasks waiting in `CanTx::write` and `CanRx::read`: the only ones are
///   [`serve`]'s polls, with a no-op waker, so not waking them changes nothing;
/// - on a bus-off status change, with automatic recovery on (`main.rs` configures it, and the
///   driver reads it only once `CanConfigurator::start` ran, which [`FdcanBus::new`], which puts
///   the halves here, follows) and the controller in bus-off, it clears CCCR.INIT, which starts
///   the recovery sequence.
pub struct Interrupt;

impl Handler<FDCAN1_IT0> for Interrupt {
    unsafe fn on_interrupt() {
        let ir = FDCAN1.ir().read();
        let arrived = ir.rfn(0) || ir.rfn(1);
        FDCAN1.ir().write(|w| {
            w.set_tc(ir.tc());
            w.set_tefn(ir.tefn());
            w.set_rfn(0, ir.rfn(0));
            w.set_rfn(1, ir.rfn(1));
            w.set_rfl(0, ir.rfl(0));
            w.set_rfl(1, ir.rfl(1));
            w.set_ep(ir.ep());
            w.set_bo(ir.bo());
        });
        let fifo_lost = u32::from(ir.rfl(0)) + u32::from(ir.rfl(1));
        if fifo_lost != 0 {
            LOST.fetch_add(fifo_lost, Ordering::Relaxed);
        }
        let psr = FDCAN1.psr().read();
        let entered =
            (u8::from(ir.bo() && psr.bo()) * BUS_OFF) | (u8::from(ir.ep() && psr.ep()) * PASSIVE);
        if entered != 0 {
            ENTERED.fetch_or(entered, Ordering::Relaxed);
        }
        critical_section::with(|cs| {
            if let Some((tx_can, rx_can)) = &mut *HALVES.borrow_ref_mut(cs) {
                // Halves here: started, automatic recovery on (see above).
                if ir.bo() && FDCAN1.psr().read().bo() {
                    FDCAN1.cccr().modify(|w| w.set_init(false));
                }
                serve(tx_can, rx_can, &mut QUEUES.borrow_ref_mut(cs), arrived);
            }
        });
    }
}

/// Moves one frame from the transmit queue into the TX FIFO if it has room; then, if a frame
/// arrived (`flagged`, or waiting in a FIFO: one that came after [`Interrupt`] read the flags,
/// which it has cleared), reads the RX FIFOs until they are empty, and the protocol error
/// the controller holds, if any, after them, into the receive queue.
fn serve(
    tx_can: &mut CanTx<'static>,
    rx_can: &mut CanRx<'static>,
    queues: &mut Queues,
    flagged: bool,
) {
    let Queues { rx, tx } = queues;
    let mut cx = Context::from_waker(Waker::noop());
    // The frame that wins arbitration among ours: the first of the lowest key (`min_by_key`
    // returns the first of equal minima), into an empty TX FIFO only (3 free elements).
    let next = tx.iter().enumerate().min_by_key(|(_, (key, _))| *key);
    if let Some((index, (_, frame))) = next
        && FDCAN1.txfqs().read().tffl() == 3
        && write(tx_can, frame, &mut cx)
    {
        tx.remove(index);
        TX_WAKER.wake();
    }
    let arrived = flagged || FDCAN1.rxfs(0).read().ffl() > 0 || FDCAN1.rxfs(1).read().ffl() > 0;
    if arrived {
        loop {
            let received = match read(rx_can, &mut cx) {
                Poll::Ready(Ok(envelope)) => Ok(envelope.frame),
                Poll::Ready(Err(error)) => Err(error),
                Poll::Pending => break,
            };
            let error = received.is_err();
            // A full queue drops the frame, counted.
            if rx.push_back(received).is_err() {
                LOST.fetch_add(1, Ordering::Relaxed);
            }
            if error {
                // Bus error states can persist: one report a pass (the driver's rule).
                break;
            }
        }
        RX_WAKER.wake();
    }
}

/// Hands `frame` to the TX FIFO; whether it took it.
#[cfg(not(feature = "fd"))]
fn write(tx_can: &mut CanTx<'static>, frame: &DriverFrame, cx: &mut Context<'_>) -> bool {
    pin!(tx_can.write(frame)).poll(cx).is_ready()
}
/// Hands `frame` to the TX FIFO; whether it took it.
#[cfg(feature = "fd")]
fn write(tx_can: &mut CanTx<'static>, frame: &DriverFrame, cx: &mut Context<'_>) -> bool {
    pin!(tx_can.write_fd(frame)).poll(cx).is_ready()
}

/// The next frame of the RX FIFOs, if any.
#[cfg(not(feature = "fd"))]
fn read(
    rx_can: &mut CanRx<'static>,
    cx: &mut Context<'_>,
) -> Poll<Result<can::frame::Envelope, can::enums::BusError>> {
    pin!(rx_can.read()).poll(cx)
}
/// The next frame of the RX FIFOs, if any.
#[cfg(feature = "fd")]
fn read(
    rx_can: &mut CanRx<'static>,
    cx: &mut Context<'_>,
) -> Poll<Result<can::frame::FdEnvelope, can::enums::BusError>> {
    pin!(rx_can.read_fd()).poll(cx)
}

/// The node's frame for a received one.
#[cfg(not(feature = "fd"))]
fn to_frame(frame: &DriverFrame) -> Frame {
    pab_core::frame::from_frame(frame)
}
/// The node's frame for a received one: an FD frame with its bit-rate switch, else classic.
#[cfg(feature = "fd")]
fn to_frame(frame: &DriverFrame) -> Frame {
    let header = frame.header();
    if header.fdcan()
        && let Some(fd) = Frame::fd(*header.id(), frame.data(), header.bit_rate_switching())
    {
        return fd;
    }
    pab_core::frame::from_frame(frame)
}

/// The driver's header for the node's frame `frame` with `len` data bytes.
#[cfg(not(feature = "fd"))]
fn header(frame: &Frame, len: u8) -> Header {
    Header::new(frame.id(), len, frame.is_remote())
}
/// The driver's header for the node's frame `frame` with `len` data bytes: an FD frame with its
/// bit-rate switch, or a classic one.
#[cfg(feature = "fd")]
fn header(frame: &Frame, len: u8) -> Header {
    if frame.is_fd() {
        Header::new_fd(frame.id(), len, false, frame.is_brs())
    } else {
        Header::new(frame.id(), len, frame.is_remote())
    }
}

/// The controller state as last reported to the node.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Active,
    Passive,
    Off,
}

/// FDCAN1 as the node's bus.
pub struct FdcanBus {
    properties: Properties,
    mode: Mode,
    /// [`LOST`] as last reported.
    lost_reported: u32,
}

impl FdcanBus {
    /// Takes a started FDCAN instance: its two halves go to the interrupt.
    pub fn new(can: Can<'static>) -> Self {
        let (tx_can, rx_can, properties) = can.split();
        // The interrupts the driver leaves off: a frame lost into a full RX FIFO, error-passive
        // entered (bus-off's it enables itself). All on interrupt line 0 (ILS at reset).
        FDCAN1.ie().modify(|w| {
            w.set_rfle(0, true);
            w.set_rfle(1, true);
            w.set_epe(true);
        });
        // Nothing to drop: there were no halves before (forgotten rather than dropped, whose
        // code, the driver's reference counts, took 92 bytes of flash).
        critical_section::with(|cs| {
            core::mem::forget(HALVES.borrow_ref_mut(cs).replace((tx_can, rx_can)));
        });
        FdcanBus {
            properties,
            mode: Mode::Active,
            lost_reported: 0,
        }
    }

    /// What to report before the next frame: frames lost since the last report, else the
    /// controller state's change (a state entered since, first); `None` if nothing changed.
    fn state_change(&mut self) -> Option<BusError> {
        let lost = LOST.load(Ordering::Relaxed);
        if lost != self.lost_reported {
            let count = lost.wrapping_sub(self.lost_reported);
            self.lost_reported = lost;
            return Some(BusError::Dropped(count));
        }
        // A state entered since the last look goes first, even if the controller has left it.
        let entered = ENTERED.swap(0, Ordering::Relaxed);
        let mode = if entered & BUS_OFF != 0 {
            Mode::Off
        } else if entered & PASSIVE != 0 && self.mode == Mode::Active {
            Mode::Passive
        } else {
            match self.properties.bus_error_mode() {
                BusErrorMode::ErrorActive => Mode::Active,
                BusErrorMode::ErrorPassive => Mode::Passive,
                BusErrorMode::BusOff => Mode::Off,
            }
        };
        if mode == self.mode {
            return None;
        }
        self.mode = mode;
        Some(match mode {
            Mode::Active => BusError::Recovered,
            Mode::Passive => BusError::ErrorPassive,
            Mode::Off => BusError::BusOff,
        })
    }
}

/// The oldest entry of the receive queue, waiting for one. Cancel-safe: the entry leaves the
/// queue in the poll that returns it.
fn received() -> impl Future<Output = Result<Frame, BusError>> {
    poll_fn(|cx| {
        RX_WAKER.register(cx.waker());
        match critical_section::with(|cs| QUEUES.borrow_ref_mut(cs).rx.pop_front()) {
            Some(Ok(frame)) => Poll::Ready(Ok(to_frame(&frame))),
            Some(Err(error)) => Poll::Ready(Err(protocol_error(&error))),
            None => Poll::Pending,
        }
    })
}

impl CanBus for FdcanBus {
    async fn receive(&mut self) -> Result<Frame, BusError> {
        loop {
            if let Some(change) = self.state_change() {
                return Err(change);
            }
            match select(received(), Timer::at(after(STATE_POLL))).await {
                Either::First(entry) => return entry,
                Either::Second(()) => {}
            }
        }
    }

    async fn transmit(&mut self, frame: &Frame) -> Result<(), BusError> {
        // One constructor for data and remote frames (the driver's `new_data` and `new_remote`
        // were two inlined copies, 112 bytes of flash). A remote frame's payload is empty, so its
        // DLC is 0, as `new_remote(id, frame.payload().len())` made it; a payload has at most 64
        // bytes, so its length fits the header's `u8`.
        let payload = frame.payload();
        // The header first, then the frame: in one expression it cost 8 bytes of flash.
        let header = header(frame, payload.len() as u8);
        let Ok(outgoing) = DriverFrame::new(header, payload) else {
            // Unreachable for a pab_core::Frame (at most 8 bytes, or a CAN FD length, and a
            // valid id); reported all the same.
            return Err(BusError::Other(0xFF));
        };
        // Queued once there is room (cancel-safe: a frame is queued in the poll that returns),
        // then the interrupt raised to feed it to the controller.
        let key = frame.arbitration_rank();
        let queued = poll_fn(|cx| {
            TX_WAKER.register(cx.waker());
            match critical_section::with(|cs| QUEUES.borrow_ref_mut(cs).tx.push((key, outgoing))) {
                Ok(()) => Poll::Ready(()),
                Err(_) => Poll::Pending,
            }
        });
        with_deadline(after(TX_TIMEOUT), queued)
            .await
            .map_err(|_| BusError::Overrun)?;
        interrupt::FDCAN1_IT0.pend();
        Ok(())
    }
}

/// `delay` from now, on the clock the node loop reads out of line ([`pab_app::now`]):
/// `Timer::after` and `with_timeout` inlined a copy of the time driver's read each, and an
/// overflow check (132 bytes of flash).
fn after(delay: Duration) -> Instant {
    Instant::from_micros(pab_app::now().as_micros().saturating_add(delay.as_micros()))
}

/// The driver's protocol errors as [`BusError::Other`], with the FDCAN's last-error-code number
/// as the detail byte (1 stuff, 2 form, 3 acknowledge, 4 bit recessive, 5 bit dominant, 6 CRC).
fn protocol_error(error: &can::enums::BusError) -> BusError {
    use can::enums::BusError as Driver;
    BusError::Other(match error {
        Driver::Stuff => 1,
        Driver::Form => 2,
        Driver::Acknowledge => 3,
        Driver::BitRecessive => 4,
        Driver::BitDominant => 5,
        Driver::Crc => 6,
        Driver::Software => 7,
    })
}
