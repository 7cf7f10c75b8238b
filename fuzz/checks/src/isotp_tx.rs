//! The ISO-TP sender (`pab_core::isotp::Sender`) against a model of what ISO 15765-2 (as
//! `docs/can-protocol.md` describes it) requires of it: the exact bytes of every frame (PCI,
//! payload, padding), in order, none while a Flow Control is awaited or before STmin has passed,
//! N_Bs, WAIT counting, Overflow and reserved statuses, and `Done`/`Failed` being final. Time only
//! goes forward here (STmin is a duration between two sends), across the counter's wrap.

use arbitrary::{Result, Unstructured};
use pab_core::Instant;
use pab_core::isotp::{FlowControlEffect, Sender, TxConfig, TxError, TxEvent, TxSetupError};

/// Runs the fuzzer's script against the sender and the model.
pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data));
}

enum Phase {
    Start,
    Await {
        since: u64,
        waits: u8,
    },
    Sending {
        block_left: Option<u8>,
        st_min: u64,
        last: Option<u64>,
    },
    Done,
    Failed(TxError),
}

/// STmin's duration as the standard defines the byte: 0..=127 ms, 0xF1..=0xF9 100..=900 µs, and
/// reserved values as the longest, 127 ms.
fn st_min_micros(byte: u8) -> u64 {
    match byte {
        0x00..=0x7F => u64::from(byte) * 1000,
        0xF1..=0xF9 => u64::from(byte - 0xF0) * 100,
        _ => 127_000,
    }
}

fn elapsed(now: u64, since: u64) -> u64 {
    now.wrapping_sub(since)
}

fn run(u: &mut Unstructured<'_>) -> Result<()> {
    let len: usize = match u.int_in_range(0u8..=7)? {
        0 => u.int_in_range(0..=7)?,
        1 => u.int_in_range(4090..=4200)?,
        _ => u.int_in_range(0..=300)?,
    };
    let seed: u8 = u.arbitrary()?;
    let payload: Vec<u8> = (0..len)
        .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
        .collect();
    let config = TxConfig {
        padding: u.arbitrary()?,
        n_bs_micros: u.int_in_range(0..=10_000)?,
        max_wait_frames: u.int_in_range(0..=3)?,
    };
    let mut sender = match Sender::new(&payload, config) {
        Ok(sender) => {
            assert!(!payload.is_empty());
            sender
        }
        Err(error) => {
            assert!(payload.is_empty() && error == TxSetupError::Empty);
            return Ok(());
        }
    };
    let pad = config.padding;
    let mut phase = Phase::Start;
    let mut sent = 0usize;
    let mut sn = 1u8;
    let mut now: u64 = u.arbitrary()?;
    for _ in 0..10_000 {
        if u.is_empty() {
            break;
        }
        now = now.wrapping_add(match u.int_in_range(0u8..=7)? {
            0..=4 => 0,
            5 => u.int_in_range(0..=2_000)?,
            _ => u.int_in_range(0..=200_000)?,
        });
        let at = Instant::from_micros(now);
        if u.int_in_range(0u8..=3)? > 0 {
            let event = sender.poll(at);
            let expected = match phase {
                Phase::Start if payload.len() <= 7 => {
                    let mut frame = [pad; 8];
                    frame[0] = payload.len() as u8;
                    frame[1..=payload.len()].copy_from_slice(&payload);
                    sent = payload.len();
                    phase = Phase::Done;
                    TxEvent::Send(frame)
                }
                Phase::Start => {
                    let mut frame = [0; 8];
                    if payload.len() <= 4095 {
                        frame[0] = 0x10 | (payload.len() >> 8) as u8;
                        frame[1] = payload.len() as u8;
                        frame[2..].copy_from_slice(&payload[..6]);
                        sent = 6;
                    } else {
                        frame[0] = 0x10;
                        frame[2..6].copy_from_slice(&(payload.len() as u32).to_be_bytes());
                        frame[6..].copy_from_slice(&payload[..2]);
                        sent = 2;
                    }
                    phase = Phase::Await {
                        since: now,
                        waits: 0,
                    };
                    TxEvent::Send(frame)
                }
                Phase::Await { since, .. } => {
                    if elapsed(now, since) >= config.n_bs_micros {
                        phase = Phase::Failed(TxError::Timeout);
                        TxEvent::Failed(TxError::Timeout)
                    } else {
                        TxEvent::WaitUntil(Instant::from_micros(
                            since.wrapping_add(config.n_bs_micros),
                        ))
                    }
                }
                Phase::Sending {
                    last: Some(last),
                    st_min,
                    ..
                } if elapsed(now, last) < st_min => {
                    TxEvent::WaitUntil(Instant::from_micros(last.wrapping_add(st_min)))
                }
                Phase::Sending {
                    block_left, st_min, ..
                } => {
                    let n = (payload.len() - sent).min(7);
                    let mut frame = [pad; 8];
                    frame[0] = 0x20 | sn;
                    frame[1..=n].copy_from_slice(&payload[sent..sent + n]);
                    sent += n;
                    sn = (sn + 1) % 16;
                    phase = if sent == payload.len() {
                        Phase::Done
                    } else if block_left == Some(1) {
                        Phase::Await {
                            since: now,
                            waits: 0,
                        }
                    } else {
                        Phase::Sending {
                            block_left: block_left.map(|left| left - 1),
                            st_min,
                            last: Some(now),
                        }
                    };
                    TxEvent::Send(frame)
                }
                Phase::Done => TxEvent::Done,
                Phase::Failed(error) => TxEvent::Failed(error),
            };
            assert_eq!(
                event,
                expected,
                "poll at {now}, {sent} of {} sent",
                payload.len()
            );
            if let TxEvent::WaitUntil(until) = event {
                assert!(at.micros_since(until).is_none(), "waits for a past instant");
            }
        } else {
            let frame = flow_control(u)?;
            let effect = sender.on_flow_control(&frame, at);
            let expected = match phase {
                Phase::Await { waits, .. }
                    if (1..=8).contains(&frame.len()) && frame[0] >> 4 == 3 =>
                {
                    match frame[0] & 0x0F {
                        0..=2 if frame.len() < 3 => FlowControlEffect::Ignored,
                        0 => {
                            phase = Phase::Sending {
                                block_left: (frame[1] > 0).then_some(frame[1]),
                                st_min: st_min_micros(frame[2]),
                                last: None,
                            };
                            FlowControlEffect::Resumed
                        }
                        1 if waits >= config.max_wait_frames => {
                            phase = Phase::Failed(TxError::TooManyWaits);
                            FlowControlEffect::Failed(TxError::TooManyWaits)
                        }
                        1 => {
                            phase = Phase::Await {
                                since: now,
                                waits: waits + 1,
                            };
                            FlowControlEffect::Waiting
                        }
                        2 => {
                            phase = Phase::Failed(TxError::Overflow);
                            FlowControlEffect::Failed(TxError::Overflow)
                        }
                        status => {
                            let error = TxError::InvalidFlowStatus { status };
                            phase = Phase::Failed(error);
                            FlowControlEffect::Failed(error)
                        }
                    }
                }
                _ => FlowControlEffect::Ignored,
            };
            assert_eq!(effect, expected, "flow control {frame:02x?} at {now}");
        }
        assert_eq!(sender.progress(), (sent, payload.len()));
    }
    Ok(())
}

/// A Flow Control, mostly well formed, or any bytes.
fn flow_control(u: &mut Unstructured<'_>) -> Result<Vec<u8>> {
    if u.ratio(1u8, 8)? {
        let n = u.int_in_range(0..=9)?;
        return (0..n).map(|_| u.arbitrary()).collect();
    }
    let status = match u.int_in_range(0u8..=15)? {
        0..=8 => 0,
        9..=12 => 1,
        13 => 2,
        _ => u.int_in_range(0..=15)?,
    };
    let block_size = match u.int_in_range(0u8..=3)? {
        0 => 0,
        1 => u.arbitrary()?,
        _ => u.int_in_range(1..=4)?,
    };
    let st_min = match u.int_in_range(0u8..=3)? {
        0 => u.arbitrary()?,
        1 => u.int_in_range(0xF1..=0xF9)?,
        _ => u.int_in_range(0..=2)?,
    };
    Ok(vec![
        0x30 | status,
        block_size,
        st_min,
        0xCC,
        0xCC,
        0xCC,
        0xCC,
        0xCC,
    ])
}
