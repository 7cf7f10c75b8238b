//! The application's [`CanBus`] over the F446's bxCAN (CAN1), with queues of its own.
//!
//! embassy-stm32's bxCAN driver sets the controller up (`can::Can::new`: pins, clock, reset,
//! interrupt lines; the bit timing and the filter bank: `main.rs`); from then on [`Interrupt`],
//! bound to all four of CAN1's interrupt lines, moves the frames between the controller and two
//! queues, as the NUCLEO-G474RE's FDCAN interrupt does: it hands the controller one frame of the
//! [`TX_QUEUE`]-frame transmit queue when its three mailboxes are empty, and drains the receive
//! FIFO (three frames deep) into the [`RX_QUEUE`]-frame receive queue, so that frames arriving
//! while the node task is busy wait there instead of overflowing the FIFO. The mailboxes and
//! the FIFO are read and written here, through the register block: the driver's `read` and
//! `write` go through its shared state and its priority-replacement logic (a frame can displace
//! a queued one of lower priority), and build an embassy frame that the node converts again.
//!
//! **Cancel safety.** The runner drops a pending [`CanBus::receive`] when its timer fires first.
//! `receive` takes an entry out of the queue only in the poll that returns it, so dropping the
//! future before it completed leaves every frame in the queue for the next call. The periodic
//! check of the controller state keeps its memory in `self.mode`, updated only in the poll that
//! returns the change, so no transition is lost either.
//!
//! Transmitting, **by priority**: frames go into the transmit queue, and the interrupt hands the
//! controller the queued frame that would win arbitration (the lowest identifier, as the bus
//! compares them: `pab_core::Frame::arbitration_rank`; among equal identifiers the oldest, so
//! ISO-TP's frames and a diagnostic round keep their order), one at a time, into mailbox 0 when
//! all three are empty: a high-priority frame waits behind at most the one frame of ours already
//! on its way. The bxCAN's own choice among its mailboxes (by identifier, equal identifiers by
//! mailbox number) is never asked for, since it would reorder equal identifiers. When the queue
//! stays full for [`TX_TIMEOUT`] (nobody acknowledges, bus-off) the frame is dropped and
//! reported, so the node keeps reading instead of blocking behind a dead bus.
//!
//! Errors: the controller's last error code (stuff, form, acknowledge, bit, CRC) is reported
//! after the frames read in a pass, once (the code is then set to 7, "set by software", which the
//! controller overwrites at its next error or successful frame). Error-passive and bus-off are
//! latched by the status-change interrupt when the controller enters them (ESR.EPVF, ESR.BOFF
//! with IER.EPVIE, IER.BOFIE), so a bus-off that recovers within milliseconds (the recovery takes
//! 128 × 11 recessive bits, 2.8 ms at 500 kbit/s) is still reported; `receive` reports each
//! latched entry, then looks at the controller state (also every [`STATE_POLL`]) for the way
//! back (`ErrorPassive`, `BusOff`, `Recovered`). Bus-off recovery is automatic (MCR.ABOM). A
//! bus-off that begins and ends while a sector erase stalls the CPU is not seen (the interrupt
//! runs after the recovery, when ESR no longer says bus-off). RM0390 says MSR.ERRI is set "when
//! a bit of the CAN_ESR has been set on error detection": read as once per entry, which is how
//! ST's HAL treats it too; if the controller sets it again at every error while it stays
//! error-passive, the interrupt runs once per erroneous frame (a few microseconds each, at
//! most one per frame time). Which one it is has not been seen on a board.
//!
//! Lost frames are counted ([`BusError::Dropped`]): a frame that finds the receive queue full,
//! and a frame the controller lost into a full FIFO (RF0R.FOVR0: the FIFO says that it lost, not
//! how many, so each such flag counts one, the least it lost). A sector erase stalls the CPU
//! for 250 ms or more (`crate::sector_flash`): the FIFO keeps three frames and the rest of that
//! time's traffic is lost, counted so.
//!
//! Not run on hardware yet (docs/nucleo-f446re.md says so).

use core::cell::RefCell;
use core::future::{Future, poll_fn};
use core::sync::atomic::{AtomicU8, AtomicU32, Ordering};
use core::task::Poll;

use critical_section::Mutex;
use embassy_futures::select::{Either, select};
use embassy_stm32::can::Can;
use embassy_stm32::interrupt::typelevel::{CAN1_RX0, CAN1_RX1, CAN1_SCE, CAN1_TX, Handler};
use embassy_stm32::interrupt::{self, InterruptExt};
use embassy_stm32::pac::CAN1;
use embassy_stm32::pac::can::regs::{Tdhr, Tdlr, Tir};
use embassy_stm32::pac::can::vals::Lec;
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

/// Identifier register bits (CAN_TIxR, CAN_RIxR): extended identifier, remote frame, transmit
/// request; the standard identifier starts at bit 21, the extended one at bit 3.
const IDE: u32 = 1 << 2;
const RTR: u32 = 1 << 1;
const TXRQ: u32 = 1;
const STANDARD_SHIFT: u32 = 21;
const EXTENDED_SHIFT: u32 = 3;

/// What the interrupt and the node task share: the two queues.
struct Queues {
    /// Received frames, or the last error code read after them, oldest first.
    rx: Deque<Result<Frame, u8>, RX_QUEUE>,
    /// Frames to transmit, oldest first, each with its `Frame::arbitration_rank`.
    tx: heapless::Vec<(u32, Frame), TX_QUEUE>,
}

/// Empty queues are all zeros: in .bss, not in flash.
static QUEUES: Mutex<RefCell<Queues>> = Mutex::new(RefCell::new(Queues {
    rx: Deque::new(),
    tx: heapless::Vec::new(),
}));
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

/// CAN1's four interrupt handlers in one, in place of the driver's (whose bindings `main.rs`
/// claims for it): the transmit interrupt (a mailbox's request completed, TSR.RQCPx), FIFO 0's
/// (a frame pending), FIFO 1's (never enabled: the filter routes every frame to FIFO 0) and the
/// status-change interrupt (error-passive or bus-off entered). Each serves whatever is pending;
/// they run at one priority, so never inside one another.
///
/// Why not the driver's handlers: they serve its buffered and unbuffered modes, chosen at run
/// time from its shared state, and in the unbuffered mode they only wake the driver's own
/// `read` and `write`, which are not used here. What they do that matters is done here: the
/// transmit handler acknowledges RQCP0..2 (write 1 to clear); the status-change handler
/// acknowledges MSR.ERRI (it also turns the error interrupt off until the driver's `read` has
/// reported the error, which this firmware does not need: only EPVIE and BOFIE raise it, once
/// per entry).
pub struct Interrupt;

impl Handler<CAN1_TX> for Interrupt {
    unsafe fn on_interrupt() {
        on_interrupt();
    }
}

impl Handler<CAN1_RX0> for Interrupt {
    unsafe fn on_interrupt() {
        on_interrupt();
    }
}

impl Handler<CAN1_RX1> for Interrupt {
    unsafe fn on_interrupt() {
        on_interrupt();
    }
}

impl Handler<CAN1_SCE> for Interrupt {
    unsafe fn on_interrupt() {
        on_interrupt();
    }
}

/// Acknowledges what the controller flagged, latches the error states entered and counts the
/// frames FIFO 0 lost, then serves the queues ([`serve`]).
#[inline(never)]
fn on_interrupt() {
    // Completed transmit requests (RQCPx; writing 1 also clears TXOKx, ALSTx, TERRx).
    let tsr = CAN1.tsr().read();
    CAN1.tsr().write(|w| {
        w.set_rqcp(0, tsr.rqcp(0));
        w.set_rqcp(1, tsr.rqcp(1));
        w.set_rqcp(2, tsr.rqcp(2));
    });
    if CAN1.rfr(0).read().fovr() {
        // Write 1 to clear; RFOM0 written 0 releases nothing.
        CAN1.rfr(0).write(|w| w.set_fovr(true));
        LOST.fetch_add(1, Ordering::Relaxed);
    }
    if CAN1.msr().read().erri() {
        let esr = CAN1.esr().read();
        let entered = (u8::from(esr.boff()) * BUS_OFF) | (u8::from(esr.epvf()) * PASSIVE);
        if entered != 0 {
            ENTERED.fetch_or(entered, Ordering::Relaxed);
        }
        // Write 1 to clear; WKUI and SLAKI written 0 stay as they are.
        CAN1.msr().write(|w| w.set_erri(true));
    }
    critical_section::with(|cs| serve(&mut QUEUES.borrow_ref_mut(cs)));
}

/// Moves one frame from the transmit queue into mailbox 0 if all three mailboxes are empty;
/// then reads FIFO 0 until it is empty into the receive queue, and the last error code after
/// the frames, if the controller holds one.
fn serve(queues: &mut Queues) {
    let Queues { rx, tx } = queues;
    // The frame that wins arbitration among ours: the first of the lowest key (`min_by_key`
    // returns the first of equal minima).
    let tsr = CAN1.tsr().read();
    if tsr.tme(0)
        && tsr.tme(1)
        && tsr.tme(2)
        && let Some((index, (_, frame))) = tx.iter().enumerate().min_by_key(|(_, (key, _))| *key)
    {
        write_mailbox(frame);
        tx.remove(index);
        TX_WAKER.wake();
    }
    let mut arrived = false;
    while CAN1.rfr(0).read().fmp() != 0 {
        let frame = read_fifo();
        // Releases the output mailbox; the next frame (if any) moves into it once RFOM0 reads 0.
        CAN1.rfr(0).write(|w| w.set_rfom(true));
        while CAN1.rfr(0).read().rfom() {}
        // A full queue drops the frame, counted.
        if rx.push_back(Ok(frame)).is_err() {
            LOST.fetch_add(1, Ordering::Relaxed);
        }
        arrived = true;
    }
    if arrived {
        // The last error code, reported once: 7 ("set by software") marks it read, until the
        // controller's next error or successful frame overwrites it.
        let code = CAN1.esr().read().lec().to_bits();
        if (1..=6).contains(&code) {
            CAN1.esr().write(|w| w.set_lec(Lec::CUSTOM));
            // No room: the frames come first, and the next error will be reported.
            let _ = rx.push_back(Err(code));
        }
        RX_WAKER.wake();
    }
}

/// The frame in FIFO 0's output mailbox. An identifier the register cannot hold is impossible
/// (11 and 29 bits); it would read as a frame on standard identifier 0.
fn read_fifo() -> Frame {
    let mailbox = CAN1.rx(0);
    let rir = mailbox.rir().read().0;
    let extended = rir & IDE != 0;
    let raw = if extended {
        rir >> EXTENDED_SHIFT
    } else {
        rir >> STANDARD_SHIFT
    };
    let id = pab_core::frame::raw_id(raw, extended)
        .unwrap_or(embedded_can::Id::Standard(embedded_can::StandardId::ZERO));
    // DLC 9 to 15 mean 8 bytes on classic CAN.
    let len = usize::from(mailbox.rdtr().read().dlc()).min(8);
    if rir & RTR != 0 {
        return <Frame as embedded_can::Frame>::new_remote(id, len).unwrap_or(Frame::empty());
    }
    let low = mailbox.rdlr().read().0.to_le_bytes();
    let high = mailbox.rdhr().read().0.to_le_bytes();
    let mut data = [0u8; 8];
    let (first, second) = data.split_at_mut(4);
    first.copy_from_slice(&low);
    second.copy_from_slice(&high);
    // The bytes after the DLC are the mailbox's leftovers: zeros instead, as every other
    // driver's frames have them.
    Frame::data(id, data.get(..len).unwrap_or(&[])).unwrap_or(Frame::empty())
}

/// Writes `frame` into mailbox 0 (empty: [`serve`] checks) and requests its transmission.
fn write_mailbox(frame: &Frame) {
    let (raw, extended) = frame.raw_id();
    let mut identifier = if extended {
        raw << EXTENDED_SHIFT | IDE
    } else {
        raw << STANDARD_SHIFT
    };
    if frame.is_remote() {
        identifier |= RTR;
    }
    // A remote frame's payload is empty and its DLC the requested length.
    let payload = frame.payload();
    let mut data = [0u8; 8];
    if let Some(bytes) = data.get_mut(..payload.len()) {
        bytes.copy_from_slice(payload);
    }
    let [d0, d1, d2, d3, d4, d5, d6, d7] = data;
    let mailbox = CAN1.tx(0);
    mailbox
        .tdtr()
        .write(|w| w.set_dlc(embedded_can::Frame::dlc(frame) as u8));
    mailbox
        .tdlr()
        .write_value(Tdlr(u32::from_le_bytes([d0, d1, d2, d3])));
    mailbox
        .tdhr()
        .write_value(Tdhr(u32::from_le_bytes([d4, d5, d6, d7])));
    mailbox.tir().write_value(Tir(identifier | TXRQ));
}

/// The controller state as last reported to the node.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Active,
    Passive,
    Off,
}

/// CAN1 as the node's bus.
pub struct BxcanBus {
    mode: Mode,
    /// [`LOST`] as last reported.
    lost_reported: u32,
}

impl BxcanBus {
    /// Takes the configured controller (bit timing and filters set, in sleep mode, as the
    /// driver's set-up leaves it), enables the interrupts this module serves and asks the
    /// controller to join the bus: it does so by itself once it has seen 11 recessive bits,
    /// without the node waiting for it (a bus held dominant would otherwise hold the boot).
    pub fn new(can: Can<'static>) -> Self {
        // Forgotten: dropping the driver resets the controller (its `Drop`), and nothing of it
        // is used from here on.
        core::mem::forget(can);
        // Only what `serve` and `on_interrupt` handle: a mailbox emptied, a frame in FIFO 0,
        // error-passive and bus-off entered (not the warning level, and not every error code,
        // which would interrupt at every erroneous frame).
        CAN1.ier().write(|w| {
            w.set_tmeie(true);
            w.set_fmpie(0, true);
            w.set_errie(true);
            w.set_epvie(true);
            w.set_bofie(true);
        });
        // Out of sleep into normal mode, with automatic bus-off recovery. Automatic
        // retransmission stays on (MCR.NART = 0, the reset value).
        CAN1.mcr().modify(|w| {
            w.set_abom(true);
            w.set_sleep(false);
            w.set_inrq(false);
        });
        BxcanBus {
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
            let esr = CAN1.esr().read();
            if esr.boff() {
                Mode::Off
            } else if esr.epvf() {
                Mode::Passive
            } else {
                Mode::Active
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
            Some(Ok(frame)) => Poll::Ready(Ok(frame)),
            // The bxCAN's last error code as the detail byte (1 stuff, 2 form, 3 acknowledge,
            // 4 bit recessive, 5 bit dominant, 6 CRC): the G474's numbers.
            Some(Err(code)) => Poll::Ready(Err(BusError::Other(code))),
            None => Poll::Pending,
        }
    })
}

impl CanBus for BxcanBus {
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
        // Queued once there is room (cancel-safe: a frame is queued in the poll that returns),
        // then the interrupt raised to hand it to the controller.
        let key = frame.arbitration_rank();
        let outgoing = *frame;
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
        interrupt::CAN1_TX.pend();
        Ok(())
    }
}

/// `delay` from now, on the clock the node loop reads out of line ([`pab_app::now`]), as the
/// G474's driver does.
fn after(delay: Duration) -> Instant {
    Instant::from_micros(pab_app::now().as_micros().saturating_add(delay.as_micros()))
}
