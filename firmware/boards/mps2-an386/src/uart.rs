//! UART0 with a receive and a transmit ring, interrupt-driven.
//!
//! **Receiving.** The RX interrupt moves each byte from the UART's one-byte buffer into
//! [`RX_RING`]. When the ring is full it stops taking bytes (and stops the RX interrupt), so
//! they wait in the UART, and the sender is held back: in QEMU the byte stays in the
//! pseudo-terminal, where the host's writes wait; on silicon the next byte sets the UART's overrun
//! flag, which is counted ([`overruns`]) and reported as an overrun. [`take`] resumes reception
//! when it makes room.
//!
//! **Transmitting.** [`try_send`] queues whole lines into [`TX_RING`] (all or nothing, so lines
//! never interleave) and feeds the UART while its buffer is empty; the TX interrupt, enabled only
//! while bytes wait, feeds the rest.
//!
//! **QEMU's serial back end.** QEMU's model of this UART does not tell its character back end
//! when the guest has read a byte, so the next byte would wait in the pseudo-terminal until
//! QEMU's main loop wakes for another reason (a timer). Re-arming a timer wakes it: each byte
//! read here re-arms the dual timer (one-shot, no interrupt), so bytes arrive as fast as the
//! main loop can hand them over. On silicon this costs one register write per byte and nothing
//! else.

use core::cell::RefCell;
use core::future::poll_fn;
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Poll;

use critical_section::{CriticalSection, Mutex};
use embassy_sync::waitqueue::AtomicWaker;
use heapless::Deque;

use crate::cmsdk::{DualTimer1, PCLK_HZ, UART0, Uart};
use crate::interrupts::{self, Interrupt};

/// Bytes the receive ring holds: about 38 of the longest SLCAN lines.
pub const RX_RING: usize = 1024;
/// Bytes the transmit ring holds: about 18 of the longest SLCAN lines.
pub const TX_RING: usize = 512;
/// The line rate the UART is set to. A pseudo-terminal ignores it; a real serial line runs at it.
pub const BAUD: u32 = 115_200;

struct State {
    rx: Deque<u8, RX_RING>,
    tx: Deque<u8, TX_RING>,
    /// Reception is paused (the ring was full).
    rx_paused: bool,
}

static STATE: Mutex<RefCell<State>> = Mutex::new(RefCell::new(State {
    rx: Deque::new(),
    tx: Deque::new(),
    rx_paused: false,
}));
static RX_WAKER: AtomicWaker = AtomicWaker::new();
static TX_WAKER: AtomicWaker = AtomicWaker::new();
static OVERRUNS: AtomicU32 = AtomicU32::new(0);

const CTRL_ON: u32 = Uart::TX_ENABLE | Uart::RX_ENABLE;

/// Sets UART0 to [`BAUD`], 8N1, receiving into the ring, and enables its interrupts.
pub fn init() {
    critical_section::with(|_| {
        UART0.set_control(0);
        UART0.set_baud_divisor(PCLK_HZ / BAUD);
        UART0.clear_state(Uart::RX_OVERRUN);
        UART0.clear_interrupts(Uart::INT_RX | Uart::INT_TX);
        // A one-shot, 32-bit dual timer without interrupt: see "QEMU's serial back end".
        DualTimer1.set_control(
            DualTimer1::ONE_SHOT | DualTimer1::SIZE_32 | DualTimer1::PERIODIC | DualTimer1::ENABLE,
        );
        UART0.set_control(CTRL_ON | Uart::RX_IRQ);
    });
    interrupts::enable(Interrupt::UART0RX);
    interrupts::enable(Interrupt::UART0TX);
}

/// Bytes lost before they were read (the UART's overrun flag), since boot; wrapping.
pub fn overruns() -> u32 {
    OVERRUNS.load(Ordering::Relaxed)
}

fn wake_back_end() {
    DualTimer1.set_load(1);
}

fn note_overrun() {
    if UART0.state() & Uart::RX_OVERRUN != 0 {
        UART0.clear_state(Uart::RX_OVERRUN);
        OVERRUNS.fetch_add(1, Ordering::Relaxed);
    }
}

/// Moves bytes from the UART into the ring until either is empty or full.
fn drain_rx(state: &mut State) {
    note_overrun();
    let mut moved = false;
    while UART0.state() & Uart::RX_FULL != 0 {
        if state.rx.is_full() {
            if !state.rx_paused {
                state.rx_paused = true;
                UART0.set_control(UART0.control() & !Uart::RX_IRQ);
            }
            break;
        }
        let _ = state.rx.push_back(UART0.read_data());
        moved = true;
    }
    if moved {
        wake_back_end();
    }
}

/// Frames the G474's FDCAN holds in its receive FIFO (RX FIFO 0) while the CPU cannot read
/// them.
#[cfg(feature = "single-bank")]
pub const STALL_FIFO_FRAMES: u32 = 3;
/// Frames lost while the CPU stalled ([`stalled_receive`]), since boot; wrapping.
#[cfg(feature = "single-bank")]
static STALL_LOST: AtomicU32 = AtomicU32::new(0);

/// Frames lost while the CPU stalled, since boot; wrapping (0 without the `single-bank` model).
pub fn stall_lost() -> u32 {
    #[cfg(feature = "single-bank")]
    return STALL_LOST.load(Ordering::Relaxed);
    #[cfg(not(feature = "single-bank"))]
    0
}

/// Lines of frames kept during one stall ([`stalled_receive`]).
#[cfg(feature = "single-bank")]
#[derive(Default)]
pub struct StallFifo {
    kept: u32,
}

/// The G474's FDCAN while a flash operation on a single bank stalls the CPU, interrupts included:
/// the bus does not wait, frames keep arriving and are acknowledged; the first
/// [`STALL_FIFO_FRAMES`] wait in the controller's FIFO, the others are lost (its message-lost
/// flag). Called over and over by the stalled flash, with interrupts masked (`cs`): the UART's
/// bytes are taken as they come, the lines of the first frames kept in the ring, the others
/// dropped and counted ([`stall_lost`]). Without it, QEMU would hold the bytes back until the
/// stall ends and nothing would be lost: the serial line waits, a CAN bus does not.
#[cfg(feature = "single-bank")]
pub fn stalled_receive(cs: CriticalSection<'_>, fifo: &mut StallFifo) {
    let mut state = crate::borrow_mut(STATE.borrow(cs));
    let mut moved = false;
    while UART0.state() & Uart::RX_FULL != 0 {
        let byte = UART0.read_data();
        moved = true;
        if fifo.kept < STALL_FIFO_FRAMES && state.rx.push_back(byte).is_ok() {
            if byte == b'\r' {
                fifo.kept += 1;
            }
        } else if byte == b'\r' {
            STALL_LOST.fetch_add(1, Ordering::Relaxed);
        }
    }
    if moved {
        wake_back_end();
    }
}

/// UART0's RX interrupt.
pub fn on_rx_interrupt() {
    critical_section::with(|cs| {
        UART0.clear_interrupts(Uart::INT_RX);
        drain_rx(&mut crate::borrow_mut(STATE.borrow(cs)));
    });
    RX_WAKER.wake();
}

/// The next received byte, if any. Resumes paused reception once there is room.
pub fn take() -> Option<u8> {
    critical_section::with(|cs| {
        let mut state = crate::borrow_mut(STATE.borrow(cs));
        let byte = state.rx.pop_front();
        if state.rx_paused {
            // Interrupt first, then drain: a byte arriving after this write raises it, one that
            // arrived before is drained here.
            state.rx_paused = false;
            UART0.set_control(UART0.control() | Uart::RX_IRQ);
            drain_rx(&mut state);
        }
        byte
    })
}

/// Registers the task to wake when bytes arrive.
pub fn register_rx_waker(waker: &core::task::Waker) {
    RX_WAKER.register(waker);
}

/// Feeds the UART from the ring while its buffer is empty; leaves the TX interrupt on only while
/// bytes wait.
fn feed_tx(state: &mut State) {
    loop {
        while UART0.state() & Uart::TX_FULL == 0 {
            match state.tx.pop_front() {
                Some(byte) => UART0.write_data(byte),
                None => break,
            }
        }
        let control = UART0.control();
        if state.tx.is_empty() {
            if control & Uart::TX_IRQ != 0 {
                UART0.set_control(control & !Uart::TX_IRQ);
            }
            return;
        }
        if control & Uart::TX_IRQ == 0 {
            UART0.set_control(control | Uart::TX_IRQ);
        }
        // The interrupt comes when the buffer empties; if it emptied before the interrupt was
        // on, feed again now.
        if UART0.state() & Uart::TX_FULL != 0 {
            return;
        }
    }
}

/// UART0's TX interrupt.
pub fn on_tx_interrupt() {
    critical_section::with(|cs| {
        UART0.clear_interrupts(Uart::INT_TX);
        feed_tx(&mut crate::borrow_mut(STATE.borrow(cs)));
    });
    TX_WAKER.wake();
}

fn try_send_in(cs: CriticalSection<'_>, bytes: &[u8]) -> bool {
    let mut state = crate::borrow_mut(STATE.borrow(cs));
    if TX_RING - state.tx.len() < bytes.len() {
        return false;
    }
    for &byte in bytes {
        let _ = state.tx.push_back(byte);
    }
    feed_tx(&mut state);
    true
}

/// Queues `bytes` whole for transmission; false (and nothing queued) if the ring has no room.
pub fn try_send(bytes: &[u8]) -> bool {
    critical_section::with(|cs| try_send_in(cs, bytes))
}

/// Queues `bytes` whole, waiting for room. Cancel-safe: dropped before it completes, it has
/// queued nothing.
pub async fn send(bytes: &[u8]) {
    poll_fn(|cx| {
        if try_send(bytes) {
            return Poll::Ready(());
        }
        TX_WAKER.register(cx.waker());
        if try_send(bytes) {
            Poll::Ready(())
        } else {
            Poll::Pending
        }
    })
    .await
}
