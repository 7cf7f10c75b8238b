//! # pab-slcan: CAN over a serial line, the Lawicel way (SLCAN)
//!
//! A board without a CAN controller (the emulated Cortex-M4 of `pab-fw-an386`) reaches the bus
//! over a UART speaking the Lawicel CANUSB ASCII protocol, "SLCAN": on a Linux host the kernel's
//! `slcan` line discipline (attached with `slcand`) turns the serial line into a SocketCAN
//! interface, so the board's frames and the bus's meet on a real `can0`/`vcan0` through `cangw`.
//! The board plays the adapter's part: it answers the commands `slcand` and the kernel send, takes
//! the frames the host transmits as the frames it receives from the bus, and sends its own frames
//! as the lines an adapter sends for frames it received.
//!
//! Lines end with CR (`\r`); LF ends a line too, and empty lines are ignored. Identifiers and data
//! are hexadecimal, upper or lower case on input, upper case on output (as the kernel writes them):
//!
//! | line | meaning |
//! | --- | --- |
//! | `tIIILDD..` | data frame, 11-bit id `III` (≤ 7FF), `L` data bytes (0-8), `DD` each |
//! | `TIIIIIIIILDD..` | data frame, 29-bit id (≤ 1FFFFFFF) |
//! | `rIIIL`, `RIIIIIIIIL` | remote frame of DLC `L` |
//! | `O` / `C` | open / close the channel (frames pass only while open) |
//! | `S0`..`S8` | bit rate 10k, 20k, 50k, 100k, 125k, 250k, 500k, 800k, 1M (channel closed) |
//! | `sXXYY` | SJA1000 bit timing registers BTR0/BTR1 (channel closed) |
//! | `V`, `v`, `N` | hardware/software version, firmware version, serial number |
//! | `F` | status flags (bit 3: data overrun since the last `F`); channel open |
//! | `Z0`, `Z1` | timestamps off / on (only off is supported) |
//!
//! The answers are an adapter's: CR for "done", BEL (`\a`, 0x07) for "refused", `z\r` / `Z\r`
//! after a standard / extended frame was taken, and the requested value for `V`, `v`, `N`, `F`.
//!
//! Structure: [`parse`] and [`format_frame`] are the codec (one line ↔ one [`Command`] or
//! [`Frame`]); [`LineReader`] cuts a byte stream into lines; [`Device`] is the adapter's state
//! (open or closed) and decides each answer. All of it is sans-I/O, so the host tests it byte by
//! byte and the board only moves bytes between its UART and these types.
//!
//! Why a crate of its own: SLCAN is a board's transport, not part of the arbitration engine
//! (`pab-core`) nor of the board-independent application (`pab-app`); and the board crate itself
//! only builds for the target, while this code must be tested on the host, exhaustively and with
//! random bytes (`tests/`).
//!
//! Guarantees: `no_std`, no allocation, no `unsafe`, no panics (clippy lints forbid indexing,
//! unwrapping and panicking macros outside tests): whatever bytes arrive, the answer is a command,
//! a frame or a typed error, and the next CR starts afresh.

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::panic,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo,
        clippy::unimplemented
    )
)]

mod codec;
mod device;
mod line;

pub use codec::{Bitrate, Command, Line, ParseError, format_frame, parse};
pub use device::{Device, Outcome, STATUS_DATA_OVERRUN, VERSION};
pub use line::{LineError, LineReader};
pub use pab_core::Frame;

/// Bytes of the longest line, CR included: `T`, 8 identifier digits, the DLC, 16 data digits, CR.
pub const MAX_LINE: usize = 27;

/// BEL: the adapter's "refused".
pub const BEL: u8 = 0x07;
/// CR: ends every line; alone, the adapter's "done".
pub const CR: u8 = b'\r';
