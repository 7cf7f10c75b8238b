//! The ISO-TP receiver (`pab_core::isotp::Receiver`) against a reference model written here from
//! ISO 15765-2 as `docs/can-protocol.md` describes it: every frame, poll and abort goes to both,
//! and every outcome, flow control, message, deadline and partial reception must be the same.
//!
//! The model is deliberately naive (a `Vec` that grows, the frame's fields read by index, no
//! shared code with pab-core), so that agreeing with it means agreeing with the standard.
//! Where the standard leaves a choice, the model makes the one the documentation states: normal
//! addressing, frames of at most 8 bytes, unpadded frames accepted if they carry what their PCI
//! announces, First Frames of exactly 8 bytes, the shortest length encoding required, a Consecutive
//! Frame shorter than needed ignored (not stored, timer not restarted), a wrong sequence number
//! aborting, a new Single or First Frame interrupting, N_Cr restarted by each stored Consecutive
//! Frame, and wrap-safe time (an instant is "not yet" when it lies less than 2^63 µs ahead).

use arbitrary::{Result, Unstructured};
use pab_core::Instant;
use pab_core::isotp::{
    FlowStatus, FrameError, Ignored, Receiver, Refusal, RxConfig, RxError, RxEvent, StMin,
};

/// Runs the fuzzer's script against both receivers.
pub fn check(data: &[u8]) {
    let mut u = Unstructured::new(data);
    // Two buffer sizes: 64 bytes (most First Frames are too large) and 4200 (the escaped 32-bit
    // length of messages over 4095 bytes can be taken).
    let _ = match u.arbitrary::<bool>() {
        Ok(false) | Err(_) => run::<64>(&mut u),
        Ok(true) => run::<4200>(&mut u),
    };
}

/// What the model says a frame decodes to, from the layout table of the documentation.
enum Decoded<'a> {
    Single(&'a [u8]),
    First { len: u32, payload: &'a [u8] },
    Consecutive { sn: u8, payload: &'a [u8] },
    FlowControl,
    Malformed(FrameError),
}

fn decode(data: &[u8]) -> Decoded<'_> {
    use Decoded::*;
    if data.len() > 8 {
        return Malformed(FrameError::TooLong { len: data.len() });
    }
    if data.is_empty() {
        return Malformed(FrameError::Empty);
    }
    let kind = data[0] >> 4;
    let low = data[0] & 0x0F;
    match kind {
        0 => {
            let len = usize::from(low);
            if !(1..=7).contains(&len) {
                Malformed(FrameError::SingleLength { len: low })
            } else if data.len() < 1 + len {
                Malformed(FrameError::Truncated {
                    needed: 1 + len,
                    got: data.len(),
                })
            } else {
                Single(&data[1..1 + len])
            }
        }
        1 => {
            // Lengths that a shorter encoding could carry are refused; a First Frame is 8 bytes.
            let short = data.get(1).map(|&b| u32::from(low) << 8 | u32::from(b));
            let escaped =
                (data.len() >= 6).then(|| u32::from_be_bytes([data[2], data[3], data[4], data[5]]));
            match (short, escaped) {
                (Some(len @ 1..=7), _) => Malformed(FrameError::FirstLength { len }),
                (Some(0), Some(len @ 0..=4095)) if data.len() == 8 => {
                    Malformed(FrameError::FirstLength { len })
                }
                _ if data.len() < 8 => Malformed(FrameError::Truncated {
                    needed: 8,
                    got: data.len(),
                }),
                (Some(0), Some(len)) => First {
                    len,
                    payload: &data[6..8],
                },
                (Some(len), _) => First {
                    len,
                    payload: &data[2..8],
                },
                (None, _) => unreachable!("an 8-byte frame has a second byte"),
            }
        }
        2 => {
            if data.len() < 2 {
                Malformed(FrameError::Truncated { needed: 2, got: 1 })
            } else {
                Consecutive {
                    sn: low,
                    payload: &data[1..],
                }
            }
        }
        3 => {
            if low > 2 {
                Malformed(FrameError::InvalidFlowStatus { status: low })
            } else if data.len() < 3 {
                Malformed(FrameError::Truncated {
                    needed: 3,
                    got: data.len(),
                })
            } else {
                FlowControl
            }
        }
        pci_type => Malformed(FrameError::UnknownType { pci_type }),
    }
}

/// Whether `deadline` has come at `now`, wrap-safe.
fn reached(now: u64, deadline: u64) -> bool {
    now.wrapping_sub(deadline) < 1 << 63
}

/// A reception in progress, in the model.
struct Reception {
    total: usize,
    data: Vec<u8>,
    next_sn: u8,
    /// Consecutive Frames since the last Flow Control.
    in_block: u32,
    deadline: u64,
}

/// The model's outcome of one frame, owned.
#[derive(Debug, PartialEq, Eq)]
enum Event {
    Nothing,
    FlowControl([u8; 8]),
    Complete(Vec<u8>),
    Refused(Refusal, Option<[u8; 8]>),
    Ignored(Ignored),
}

struct Model {
    config: RxConfig,
    capacity: usize,
    reception: Option<Reception>,
}

impl Model {
    fn flow_control(&self, status: FlowStatus) -> [u8; 8] {
        let fs = match status {
            FlowStatus::ContinueToSend => 0,
            FlowStatus::Wait => 1,
            FlowStatus::Overflow => 2,
        };
        let p = self.config.padding;
        [
            0x30 | fs,
            self.config.block_size,
            self.config.st_min.byte(),
            p,
            p,
            p,
            p,
            p,
        ]
    }

    fn poll(&mut self, now: u64) -> Option<RxError> {
        match &self.reception {
            Some(r) if reached(now, r.deadline) => {
                self.reception = None;
                Some(RxError::Timeout)
            }
            _ => None,
        }
    }

    fn on_frame(&mut self, data: &[u8], now: u64) -> (Option<RxError>, Event) {
        let mut aborted = self.poll(now);
        let event = match decode(data) {
            Decoded::Malformed(error) => Event::Ignored(Ignored::Malformed(error)),
            Decoded::FlowControl => Event::Ignored(Ignored::FlowControl),
            Decoded::Single(payload) => {
                if self.reception.take().is_some() {
                    aborted = aborted.or(Some(RxError::Interrupted));
                }
                if payload.len() <= self.capacity {
                    Event::Complete(payload.to_vec())
                } else {
                    Event::Refused(
                        Refusal::TooLarge {
                            len: payload.len() as u32,
                        },
                        None,
                    )
                }
            }
            Decoded::First { len, payload } => {
                if self.reception.take().is_some() {
                    aborted = aborted.or(Some(RxError::Interrupted));
                }
                if len as usize > self.capacity {
                    Event::Refused(
                        Refusal::TooLarge { len },
                        Some(self.flow_control(FlowStatus::Overflow)),
                    )
                } else {
                    self.reception = Some(Reception {
                        total: len as usize,
                        data: payload.to_vec(),
                        next_sn: 1,
                        in_block: 0,
                        deadline: now.wrapping_add(self.config.n_cr_micros),
                    });
                    Event::FlowControl(self.flow_control(FlowStatus::ContinueToSend))
                }
            }
            Decoded::Consecutive { sn, payload } => match self.reception.as_mut() {
                None => Event::Ignored(Ignored::UnexpectedConsecutive),
                Some(r) if r.next_sn != sn => {
                    aborted = aborted.or(Some(RxError::WrongSequenceNumber {
                        expected: r.next_sn,
                        got: sn,
                    }));
                    self.reception = None;
                    Event::Nothing
                }
                Some(r) => {
                    let needed = (r.total - r.data.len()).min(7);
                    if payload.len() < needed {
                        Event::Ignored(Ignored::ShortConsecutive {
                            needed,
                            got: payload.len(),
                        })
                    } else {
                        r.data.extend_from_slice(&payload[..needed]);
                        if r.data.len() == r.total {
                            let message = std::mem::take(&mut r.data);
                            self.reception = None;
                            Event::Complete(message)
                        } else {
                            r.next_sn = (r.next_sn + 1) % 16;
                            r.deadline = now.wrapping_add(self.config.n_cr_micros);
                            r.in_block += 1;
                            let bs = u32::from(self.config.block_size);
                            if bs > 0 && r.in_block == bs {
                                r.in_block = 0;
                                Event::FlowControl(self.flow_control(FlowStatus::ContinueToSend))
                            } else {
                                Event::Nothing
                            }
                        }
                    }
                }
            },
        };
        (aborted, event)
    }
}

/// The receiver's event, owned, in the model's terms.
fn owned(event: RxEvent<'_>) -> Event {
    match event {
        RxEvent::Nothing => Event::Nothing,
        RxEvent::SendFlowControl(frame) => Event::FlowControl(frame),
        RxEvent::Complete(message) => Event::Complete(message.to_vec()),
        RxEvent::Refused {
            reason,
            flow_control,
        } => Event::Refused(reason, flow_control),
        RxEvent::Ignored(why) => Event::Ignored(why),
    }
}

/// The next instant: mostly a little later, sometimes much later, sometimes earlier (a clock set
/// back, controllers out of order), sometimes across the counter's wrap.
pub(crate) fn next_time(u: &mut Unstructured<'_>, now: u64) -> Result<u64> {
    Ok(match u.int_in_range(0u8..=15)? {
        0..=9 => now.wrapping_add(u.int_in_range(0u64..=1_200)?),
        10..=11 => now.wrapping_add(u.int_in_range(0u64..=3_000_000)?),
        12..=13 => now.wrapping_sub(u.int_in_range(0u64..=3_000_000)?),
        _ => u.arbitrary()?,
    })
}

fn run<const N: usize>(u: &mut Unstructured<'_>) -> Result<()> {
    let config = RxConfig {
        block_size: match u.int_in_range(0u8..=3)? {
            0 => 0,
            1 => u.arbitrary()?,
            _ => u.int_in_range(1..=4)?,
        },
        st_min: StMin::from_byte(u.arbitrary()?),
        n_cr_micros: match u.int_in_range(0u8..=3)? {
            0 => u.arbitrary()?,
            _ => u.int_in_range(0..=5_000)?,
        },
        padding: u.arbitrary()?,
    };
    let mut rx = Receiver::<N>::new(config);
    let mut model = Model {
        config,
        capacity: N,
        reception: None,
    };
    let mut now: u64 = u.arbitrary()?;
    // The last message: it stays at the start of the buffer until a Single or First Frame.
    let mut last: Option<Vec<u8>> = None;
    for _ in 0..4_000 {
        if u.is_empty() {
            break;
        }
        now = next_time(u, now)?;
        let at = Instant::from_micros(now);
        match u.int_in_range(0u8..=15)? {
            0 => assert_eq!(rx.poll(at), model.poll(now), "poll at {now}"),
            1 => {
                let was = model.reception.take().is_some();
                assert_eq!(rx.abort(), was, "abort");
            }
            op => {
                let frame = frame(u, op, &model)?;
                let outcome = rx.on_frame(&frame, at);
                let (aborted, event) = (outcome.aborted, owned(outcome.event));
                let expected = model.on_frame(&frame, now);
                assert_eq!(
                    (aborted, &event),
                    (expected.0, &expected.1),
                    "frame {frame:02x?} at {now}"
                );
                if frame.first().is_some_and(|b| b >> 4 <= 1) && frame.len() <= 8 {
                    last = None;
                }
                if let Event::Complete(message) = event {
                    last = Some(message);
                }
            }
        }
        // Between calls, the receiver shows what the model holds.
        let expected = model.reception.as_ref().map(|r| (r.data.len(), r.total));
        assert_eq!(rx.in_progress(), expected);
        assert_eq!(rx.message_len(), expected.map(|(_, total)| total));
        assert_eq!(
            rx.deadline().map(Instant::as_micros),
            model.reception.as_ref().map(|r| r.deadline)
        );
        let received: &[u8] = model.reception.as_ref().map_or(&[], |r| &r.data);
        assert_eq!(rx.received(), received);
        assert_eq!(rx.buffer_mut().is_some(), model.reception.is_none());
        if let (Some(message), None) = (&last, &model.reception) {
            assert_eq!(
                &rx.buffer()[..message.len()],
                &message[..],
                "the last message moved"
            );
        }
    }
    Ok(())
}

/// A frame: random bytes, or one built to be valid for the reception in progress.
fn frame(u: &mut Unstructured<'_>, op: u8, model: &Model) -> Result<Vec<u8>> {
    let frame_len = |u: &mut Unstructured<'_>| -> Result<usize> {
        Ok(match u.int_in_range(0u8..=7)? {
            0 => u.int_in_range(0..=9)?,
            _ => 8,
        })
    };
    Ok(match op {
        // The next Consecutive Frame, mostly right.
        2..=9 => {
            let sn = match (&model.reception, u.int_in_range(0u8..=15)?) {
                (Some(r), 0..=13) => r.next_sn,
                _ => u.int_in_range(0..=15)?,
            };
            let n = frame_len(u)?.max(1);
            let mut bytes = vec![0x20 | sn];
            for _ in 1..n {
                bytes.push(u.arbitrary()?);
            }
            bytes
        }
        // A First Frame of a length around the buffer's.
        10..=11 => {
            let len: u32 = match u.int_in_range(0u8..=3)? {
                0 => u.arbitrary()?,
                1 => u.int_in_range(0..=4095)?,
                _ => u.int_in_range(8..=(model.capacity as u32 + 8))?,
            };
            let mut bytes = if len > 4095 || u.ratio(1u8, 16)? {
                let [a, b, c, d] = len.to_be_bytes();
                vec![0x10, 0, a, b, c, d]
            } else {
                vec![0x10 | (len >> 8) as u8 & 0x0F, len as u8]
            };
            let n = frame_len(u)?;
            while bytes.len() < n {
                bytes.push(u.arbitrary()?);
            }
            bytes.truncate(n);
            bytes
        }
        // Anything.
        _ => {
            let n = frame_len(u)?;
            let mut bytes = Vec::with_capacity(n);
            for _ in 0..n {
                bytes.push(u.arbitrary()?);
            }
            bytes
        }
    })
}
