//! The adapter's side of the protocol: which commands it takes and what it answers.

use pab_core::Frame;

use crate::codec::{Bitrate, Command, Line};
use crate::line::LineError;

/// What `V` answers (after the `V`): hardware 01, software 00.
pub const VERSION: &[u8; 4] = b"0100";
/// The status flag (`F`) for "data overrun": bytes or frames were lost since the last `F`.
pub const STATUS_DATA_OVERRUN: u8 = 1 << 3;

/// An SLCAN adapter's state, as a node on a serial line plays it.
///
/// Differences from a CANUSB, chosen for a node rather than a PC adapter, all answered with BEL
/// when asked for: the channel is **open from the start** (a node's controller is on from boot,
/// and a board reset must not leave it deaf until the host sends `O` again); listen-only (`L`),
/// timestamps (`Z1`), acceptance filters (`M`, `m`) and auto-poll are not implemented. The bit
/// rate (`S`, `s`) is recorded and answered, but a serial line has no bit timing: it changes
/// nothing.
#[derive(Clone, Debug)]
pub struct Device {
    open: bool,
    bitrate: Option<Bitrate>,
    bit_timing: Option<(u8, u8)>,
    status: u8,
    serial: [u8; 4],
}

/// What to do with one line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outcome {
    /// A frame the host put on the bus: the node receives it.
    pub frame: Option<Frame>,
    /// The bytes to answer with (possibly none).
    pub reply: Line,
    /// The line was not a command: count it as an error.
    pub error: Option<LineError>,
}

impl Outcome {
    /// Out of line: six callers inlined it (28 bytes of the emulated board's flash).
    #[inline(never)]
    fn reply(reply: Line) -> Outcome {
        Outcome {
            frame: None,
            reply,
            error: None,
        }
    }
}

impl Device {
    /// An open channel; `serial` is what `N` answers (four characters, e.g. the node id).
    pub const fn new(serial: [u8; 4]) -> Self {
        Device {
            open: true,
            bitrate: None,
            bit_timing: None,
            status: 0,
            serial,
        }
    }

    /// Whether frames pass (between `O` and `C`).
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The bit rate the host last set with `S`, if any.
    pub fn bitrate(&self) -> Option<Bitrate> {
        self.bitrate
    }

    /// The bit timing the host last set with `s` (BTR0, BTR1), if any.
    pub fn bit_timing(&self) -> Option<(u8, u8)> {
        self.bit_timing
    }

    /// Records that input was lost (an overrun): the next `F` reports it.
    pub fn note_overrun(&mut self) {
        self.status |= STATUS_DATA_OVERRUN;
    }

    /// Handles one line (what [`crate::LineReader::push`] returned).
    pub fn handle(&mut self, line: Result<Command, LineError>) -> Outcome {
        let command = match line {
            Ok(command) => command,
            Err(error) => {
                return Outcome {
                    frame: None,
                    reply: Line::refused(),
                    error: Some(error),
                };
            }
        };
        let done_if = |ok: bool| Outcome::reply(if ok { Line::ok() } else { Line::refused() });
        match command {
            Command::Frame(frame) => {
                if !self.open {
                    return Outcome::reply(Line::refused());
                }
                let extended = matches!(frame.id(), pab_core::Id::Extended(_));
                Outcome {
                    frame: Some(frame),
                    reply: Line::text(if extended { b"Z" } else { b"z" }),
                    error: None,
                }
            }
            Command::Open => {
                let was_open = self.open;
                self.open = true;
                done_if(!was_open)
            }
            Command::Close => {
                self.open = false;
                Outcome::reply(Line::ok())
            }
            Command::Bitrate(bitrate) => {
                if !self.open {
                    self.bitrate = Some(bitrate);
                }
                done_if(!self.open)
            }
            Command::BitTiming { btr0, btr1 } => {
                if !self.open {
                    self.bit_timing = Some((btr0, btr1));
                }
                done_if(!self.open)
            }
            Command::Version => {
                let [a, b, c, d] = *VERSION;
                Outcome::reply(Line::text(&[b'V', a, b, c, d]))
            }
            Command::FirmwareVersion => {
                let [a, b, c, d] = *VERSION;
                Outcome::reply(Line::text(&[b'v', a, b, c, d]))
            }
            Command::SerialNumber => {
                let [a, b, c, d] = self.serial;
                Outcome::reply(Line::text(&[b'N', a, b, c, d]))
            }
            Command::Status => {
                if !self.open {
                    return Outcome::reply(Line::refused());
                }
                let hex = b"0123456789ABCDEF";
                let high = hex
                    .get(usize::from(self.status >> 4))
                    .copied()
                    .unwrap_or(b'0');
                let low = hex
                    .get(usize::from(self.status & 0xF))
                    .copied()
                    .unwrap_or(b'0');
                self.status = 0;
                Outcome::reply(Line::text(&[b'F', high, low]))
            }
            Command::Timestamps(on) => done_if(!on && !self.open),
            Command::ListenOnly | Command::Unsupported(_) => Outcome::reply(Line::refused()),
        }
    }
}
