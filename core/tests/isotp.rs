//! ISO-TP: byte-exact frame vectors, the receiver's and the sender's state machines on every edge
//! the standard names, and sender → receiver round trips with random lengths, block sizes, STmin
//! and lost frames.

use pab_core::Instant;
use pab_core::isotp::pci::{
    self, EncodeError, FlowStatus, FrameError, Pci, StMin, encode_consecutive, encode_first,
    encode_flow_control, encode_single,
};
use pab_core::isotp::{
    FlowControlEffect, Ignored, Receiver, Refusal, RxConfig, RxError, RxEvent, RxOutcome, Sender,
    TxConfig, TxError, TxEvent, TxSetupError,
};
use proptest::prelude::*;

const CC: u8 = 0xCC;

fn t(micros: u64) -> Instant {
    Instant::from_micros(micros)
}

/// A message whose bytes encode their own position, so that any misplaced byte shows.
fn message(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i ^ (i >> 8) ^ (i >> 16)) as u8).collect()
}

fn outcome(aborted: Option<RxError>, event: RxEvent<'_>) -> RxOutcome<'_> {
    RxOutcome { aborted, event }
}

fn cts(block_size: u8, st_min: u8) -> [u8; 8] {
    [0x30, block_size, st_min, CC, CC, CC, CC, CC]
}

// ---------------------------------------------------------------------------------------------
// Codec vectors

#[test]
fn single_frame_vectors() {
    assert_eq!(
        encode_single(&[0xAB], CC),
        Ok([0x01, 0xAB, CC, CC, CC, CC, CC, CC])
    );
    assert_eq!(
        encode_single(&[1, 2, 3, 4, 5, 6, 7], 0x00),
        Ok([0x07, 1, 2, 3, 4, 5, 6, 7])
    );
    assert_eq!(
        encode_single(&[], CC),
        Err(EncodeError::PayloadLength { len: 0 })
    );
    assert_eq!(
        encode_single(&[0; 8], CC),
        Err(EncodeError::PayloadLength { len: 8 })
    );
    assert_eq!(
        pci::decode(&[0x01, 0xAB, CC, CC, CC, CC, CC, CC]),
        Ok((Pci::Single { len: 1 }, &[0xAB][..]))
    );
    assert_eq!(
        pci::decode(&[0x07, 1, 2, 3, 4, 5, 6, 7]),
        Ok((Pci::Single { len: 7 }, &[1, 2, 3, 4, 5, 6, 7][..]))
    );
    // Unpadded: exactly the announced bytes.
    assert_eq!(
        pci::decode(&[0x03, 9, 8, 7]),
        Ok((Pci::Single { len: 3 }, &[9, 8, 7][..]))
    );
    // Malformed: L = 0 (CAN FD escape), L > 7, L beyond the frame.
    assert_eq!(
        pci::decode(&[0x00, 1, 2]),
        Err(FrameError::SingleLength { len: 0 })
    );
    for l in 8..=15u8 {
        assert_eq!(
            pci::decode(&[l, 0, 0, 0, 0, 0, 0, 0]),
            Err(FrameError::SingleLength { len: l })
        );
    }
    assert_eq!(
        pci::decode(&[0x05, 1, 2, 3]),
        Err(FrameError::Truncated { needed: 6, got: 4 })
    );
}

#[test]
fn first_frame_vectors() {
    let data = message(40_000);
    assert_eq!(
        encode_first(8, &data),
        Ok((
            [
                0x10, 0x08, data[0], data[1], data[2], data[3], data[4], data[5]
            ],
            6
        ))
    );
    assert_eq!(
        encode_first(4095, &data),
        Ok((
            [
                0x1F, 0xFF, data[0], data[1], data[2], data[3], data[4], data[5]
            ],
            6
        ))
    );
    // 4096 and above: the 2016 escape, 32-bit big-endian length, 2 data bytes.
    assert_eq!(
        encode_first(4096, &data),
        Ok(([0x10, 0x00, 0x00, 0x00, 0x10, 0x00, data[0], data[1]], 2))
    );
    assert_eq!(
        encode_first(32_768, &data),
        Ok(([0x10, 0x00, 0x00, 0x00, 0x80, 0x00, data[0], data[1]], 2))
    );
    assert_eq!(
        encode_first(u32::MAX, &data),
        Ok(([0x10, 0x00, 0xFF, 0xFF, 0xFF, 0xFF, data[0], data[1]], 2))
    );
    assert_eq!(
        encode_first(7, &data),
        Err(EncodeError::MessageTooShort { len: 7 })
    );
    assert_eq!(
        encode_first(100, &data[..5]),
        Err(EncodeError::NotEnoughData { needed: 6, got: 5 })
    );

    for len in [8u32, 9, 0x123, 4095, 4096, 32_768, u32::MAX] {
        let (frame, carried) = encode_first(len, &data).unwrap();
        assert_eq!(
            pci::decode(&frame),
            Ok((Pci::First { len }, &data[..carried])),
            "{len}"
        );
    }
    // A 12-bit length that fits a Single Frame is malformed.
    for len in 1..=7u8 {
        assert_eq!(
            pci::decode(&[0x10, len, 0, 0, 0, 0, 0, 0]),
            Err(FrameError::FirstLength {
                len: u32::from(len)
            })
        );
    }
    // An escaped length that fits 12 bits is malformed.
    for len in [0u32, 7, 8, 4095] {
        let [a, b, c, d] = len.to_be_bytes();
        assert_eq!(
            pci::decode(&[0x10, 0x00, a, b, c, d, 0, 0]),
            Err(FrameError::FirstLength { len })
        );
    }
    // First Frames are always full: any shorter frame is truncated.
    let (full, _) = encode_first(100, &data).unwrap();
    let (escaped, _) = encode_first(5000, &data).unwrap();
    for cut in 1..8 {
        assert_eq!(
            pci::decode(&full[..cut]),
            Err(FrameError::Truncated {
                needed: 8,
                got: cut
            })
        );
        assert_eq!(
            pci::decode(&escaped[..cut]),
            Err(FrameError::Truncated {
                needed: 8,
                got: cut
            })
        );
    }
}

#[test]
fn consecutive_frame_vectors() {
    assert_eq!(
        encode_consecutive(1, &[1, 2, 3, 4, 5, 6, 7], CC),
        Ok([0x21, 1, 2, 3, 4, 5, 6, 7])
    );
    assert_eq!(
        encode_consecutive(0, &[9], CC),
        Ok([0x20, 9, CC, CC, CC, CC, CC, CC])
    );
    assert_eq!(
        encode_consecutive(15, &[9, 8], 0x55),
        Ok([0x2F, 9, 8, 0x55, 0x55, 0x55, 0x55, 0x55])
    );
    assert_eq!(
        encode_consecutive(16, &[9], CC),
        Err(EncodeError::SequenceNumber { sn: 16 })
    );
    assert_eq!(
        encode_consecutive(1, &[], CC),
        Err(EncodeError::PayloadLength { len: 0 })
    );
    assert_eq!(
        encode_consecutive(1, &[0; 8], CC),
        Err(EncodeError::PayloadLength { len: 8 })
    );
    assert_eq!(
        pci::decode(&[0x2A, 1, 2]),
        Ok((Pci::Consecutive { sn: 10 }, &[1, 2][..]))
    );
    assert_eq!(
        pci::decode(&[0x21]),
        Err(FrameError::Truncated { needed: 2, got: 1 })
    );
}

#[test]
fn flow_control_vectors() {
    assert_eq!(
        encode_flow_control(
            FlowStatus::ContinueToSend,
            8,
            StMin::from_millis(20).unwrap(),
            CC
        ),
        [0x30, 0x08, 0x14, CC, CC, CC, CC, CC]
    );
    assert_eq!(
        encode_flow_control(FlowStatus::Wait, 0, StMin::ZERO, 0x00),
        [0x31, 0, 0, 0, 0, 0, 0, 0]
    );
    assert_eq!(
        encode_flow_control(
            FlowStatus::Overflow,
            0,
            StMin::from_hundred_micros(5).unwrap(),
            CC
        ),
        [0x32, 0x00, 0xF5, CC, CC, CC, CC, CC]
    );
    for (nibble, status) in [
        (0, FlowStatus::ContinueToSend),
        (1, FlowStatus::Wait),
        (2, FlowStatus::Overflow),
    ] {
        // Unpadded (3 bytes) and padded decode alike.
        let expected = Pci::FlowControl {
            status,
            block_size: 3,
            st_min: StMin::from_byte(0xF9),
        };
        assert_eq!(
            pci::decode(&[0x30 | nibble, 3, 0xF9]),
            Ok((expected, &[][..]))
        );
        assert_eq!(
            pci::decode(&[0x30 | nibble, 3, 0xF9, CC, CC, CC, CC, CC]),
            Ok((expected, &[][..]))
        );
        assert_eq!(
            pci::decode(&[0x30 | nibble, 3]),
            Err(FrameError::Truncated { needed: 3, got: 2 })
        );
    }
    for status in 3..=15u8 {
        assert_eq!(
            pci::decode(&[0x30 | status, 0, 0]),
            Err(FrameError::InvalidFlowStatus { status })
        );
    }
}

#[test]
fn st_min_encodings() {
    let cases = [
        (0x00u8, 0u32, false),
        (0x7F, 127_000, false),
        (0xF1, 100, false),
        (0xF9, 900, false),
        // Reserved: the sender must use the longest valid value, 127 ms.
        (0x80, 127_000, true),
        (0xF0, 127_000, true),
        (0xFA, 127_000, true),
        (0xFF, 127_000, true),
    ];
    for (byte, micros, reserved) in cases {
        let st_min = StMin::from_byte(byte);
        assert_eq!(st_min.as_micros(), micros, "{byte:#04x}");
        assert_eq!(st_min.is_reserved(), reserved, "{byte:#04x}");
        assert_eq!(st_min.byte(), byte);
    }
    assert_eq!(StMin::from_millis(127), Some(StMin::MAX));
    assert_eq!(StMin::from_millis(128), None);
    assert_eq!(StMin::from_hundred_micros(0), None);
    assert_eq!(StMin::from_hundred_micros(10), None);
    assert_eq!(StMin::from_hundred_micros(1).map(StMin::byte), Some(0xF1));
    assert_eq!(StMin::at_least_micros(0).byte(), 0x00);
    assert_eq!(StMin::at_least_micros(1).byte(), 0xF1);
    assert_eq!(StMin::at_least_micros(101).byte(), 0xF2);
    assert_eq!(StMin::at_least_micros(900).byte(), 0xF9);
    assert_eq!(StMin::at_least_micros(901).byte(), 0x01);
    assert_eq!(StMin::at_least_micros(1001).byte(), 0x02);
    assert_eq!(StMin::at_least_micros(127_000).byte(), 0x7F);
    assert_eq!(StMin::at_least_micros(u32::MAX).byte(), 0x7F);
}

#[test]
fn unknown_pci_types_and_lengths() {
    assert_eq!(pci::decode(&[]), Err(FrameError::Empty));
    assert_eq!(
        pci::decode(&[0x01, 1, 2, 3, 4, 5, 6, 7, 8]),
        Err(FrameError::TooLong { len: 9 })
    );
    for pci_type in 4..=15u8 {
        assert_eq!(
            pci::decode(&[pci_type << 4, 0, 0, 0, 0, 0, 0, 0]),
            Err(FrameError::UnknownType { pci_type })
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Receiver

/// The frames of a whole message as a sender emits them, with BS = 0 and STmin = 0.
fn frames_of(payload: &[u8]) -> Vec<[u8; 8]> {
    let mut sender = Sender::new(payload, TxConfig::default()).unwrap();
    let mut frames = Vec::new();
    loop {
        match sender.poll(t(0)) {
            TxEvent::Send(frame) => frames.push(frame),
            TxEvent::WaitUntil(_) => {
                assert_eq!(
                    sender.on_flow_control(&cts(0, 0), t(0)),
                    FlowControlEffect::Resumed
                )
            }
            TxEvent::Done => return frames,
            TxEvent::Failed(error) => panic!("{error:?}"),
        }
    }
}

#[test]
fn receiver_single_frames() {
    let mut rx = Receiver::<64>::new(RxConfig::default());
    assert_eq!(
        rx.on_frame(&[0x01, 0xAB, CC, CC, CC, CC, CC, CC], t(0)),
        outcome(None, RxEvent::Complete(&[0xAB]))
    );
    assert_eq!(
        rx.on_frame(&[0x07, 1, 2, 3, 4, 5, 6, 7], t(0)),
        outcome(None, RxEvent::Complete(&[1, 2, 3, 4, 5, 6, 7]))
    );
    // Unpadded.
    assert_eq!(
        rx.on_frame(&[0x02, 5, 6], t(0)),
        outcome(None, RxEvent::Complete(&[5, 6]))
    );
    assert_eq!(rx.in_progress(), None);
    // Malformed ones are ignored and counted.
    assert_eq!(
        rx.on_frame(&[0x00, 5, 6], t(0)),
        outcome(
            None,
            RxEvent::Ignored(Ignored::Malformed(FrameError::SingleLength { len: 0 }))
        )
    );
    assert_eq!(
        rx.on_frame(&[0x04, 5, 6], t(0)),
        outcome(
            None,
            RxEvent::Ignored(Ignored::Malformed(FrameError::Truncated {
                needed: 5,
                got: 3
            }))
        )
    );
    // A receiver smaller than the Single Frame refuses it; Single Frames get no Flow Control.
    let mut small = Receiver::<4>::new(RxConfig::default());
    assert_eq!(
        small.on_frame(&[0x05, 1, 2, 3, 4, 5], t(0)),
        outcome(
            None,
            RxEvent::Refused {
                reason: Refusal::TooLarge { len: 5 },
                flow_control: None
            }
        )
    );
    assert_eq!(
        small.on_frame(&[0x04, 1, 2, 3, 4], t(0)),
        outcome(None, RxEvent::Complete(&[1, 2, 3, 4]))
    );
}

#[test]
fn receiver_answers_a_first_frame_with_its_configuration() {
    let config = RxConfig {
        block_size: 8,
        st_min: StMin::from_hundred_micros(3).unwrap(),
        n_cr_micros: 1_000_000,
        padding: 0xAA,
    };
    let mut rx = Receiver::<4096>::new(config);
    let data = message(100);
    let (ff, _) = encode_first(100, &data).unwrap();
    assert_eq!(
        rx.on_frame(&ff, t(5)),
        outcome(
            None,
            RxEvent::SendFlowControl([0x30, 0x08, 0xF3, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA])
        )
    );
    assert_eq!(rx.in_progress(), Some((6, 100)));
    assert_eq!(rx.message_len(), Some(100));
    assert_eq!(rx.received(), &data[..6]);
    assert_eq!(rx.deadline(), Some(t(1_000_005)));
}

#[test]
fn receiver_refuses_a_too_large_first_frame_with_overflow() {
    let mut rx = Receiver::<4096>::new(RxConfig {
        block_size: 4,
        ..RxConfig::default()
    });
    let data = message(5000);
    let (ff, _) = encode_first(4097, &data).unwrap();
    assert_eq!(
        rx.on_frame(&ff, t(0)),
        outcome(
            None,
            RxEvent::Refused {
                reason: Refusal::TooLarge { len: 4097 },
                flow_control: Some([0x32, 0x04, 0x00, CC, CC, CC, CC, CC]),
            }
        )
    );
    assert_eq!(rx.in_progress(), None);
    assert_eq!(rx.deadline(), None);
    // Exactly N is taken.
    let (ff, _) = encode_first(4096, &data).unwrap();
    assert!(matches!(
        rx.on_frame(&ff, t(0)).event,
        RxEvent::SendFlowControl(_)
    ));
}

/// Feeds every frame of `payload`, checking the receiver's answer to each.
fn receive_whole(rx: &mut Receiver<40_000>, payload: &[u8]) {
    let frames = frames_of(payload);
    let bs = usize::from(rx.config().block_size);
    let last = frames.len() - 1;
    for (index, frame) in frames.iter().enumerate() {
        let result = rx.on_frame(frame, t(index as u64));
        assert_eq!(result.aborted, None);
        match result.event {
            RxEvent::SendFlowControl(fc) => {
                // After the First Frame, then after every BS-th Consecutive Frame (never after
                // the last one).
                assert!(index == 0 || (bs > 0 && index % bs == 0 && index != last));
                assert_eq!(fc, cts(bs as u8, 0));
            }
            RxEvent::Nothing => {
                assert!(index != 0 && index != last && (bs == 0 || index % bs != 0))
            }
            RxEvent::Complete(message) => {
                assert_eq!(index, last);
                assert_eq!(message, payload);
            }
            other => panic!("frame {index}: {other:?}"),
        }
    }
}

#[test]
fn receiver_sends_flow_control_after_exactly_block_size_frames() {
    // 6 + 20 × 7 bytes: 20 Consecutive Frames, SN 1..15, 0..4.
    let payload = message(146);
    for block_size in [0u8, 1, 3, 8, 20, 255] {
        let mut rx = Receiver::<40_000>::new(RxConfig {
            block_size,
            ..RxConfig::default()
        });
        receive_whole(&mut rx, &payload);
        assert_eq!(rx.in_progress(), None);
    }
}

#[test]
fn receiver_takes_the_large_and_edge_lengths() {
    let mut rx = Receiver::<40_000>::new(RxConfig::default());
    for len in [8, 13, 14, 15, 4095, 4096, 4097, 32_768, 40_000] {
        receive_whole(&mut rx, &message(len));
    }
}

#[test]
fn last_consecutive_frame_may_be_unpadded_but_not_short() {
    let payload = message(10);
    let mut rx = Receiver::<64>::new(RxConfig::default());
    let (ff, _) = encode_first(10, &payload).unwrap();
    assert!(matches!(
        rx.on_frame(&ff, t(0)).event,
        RxEvent::SendFlowControl(_)
    ));
    // 4 bytes remain: a 3-byte Consecutive Frame is short, and ignored.
    assert_eq!(
        rx.on_frame(&[0x21, payload[6], payload[7], payload[8]], t(1)),
        outcome(
            None,
            RxEvent::Ignored(Ignored::ShortConsecutive { needed: 4, got: 3 })
        )
    );
    assert_eq!(rx.in_progress(), Some((6, 10)));
    assert_eq!(
        rx.on_frame(
            &[0x21, payload[6], payload[7], payload[8], payload[9]],
            t(2)
        ),
        outcome(None, RxEvent::Complete(&payload))
    );

    // A middle Consecutive Frame must carry 7 bytes.
    let payload = message(30);
    let (ff, _) = encode_first(30, &payload).unwrap();
    let _ = rx.on_frame(&ff, t(0));
    assert_eq!(
        rx.on_frame(&[0x21, 1, 2, 3, 4, 5, 6], t(1)).event,
        RxEvent::Ignored(Ignored::ShortConsecutive { needed: 7, got: 6 })
    );
    assert_eq!(rx.received(), &payload[..6]);
}

#[test]
fn consecutive_frames_while_idle_and_flow_controls_are_ignored() {
    let mut rx = Receiver::<64>::new(RxConfig::default());
    assert_eq!(
        rx.on_frame(&[0x21, 1, 2, 3, 4, 5, 6, 7], t(0)),
        outcome(None, RxEvent::Ignored(Ignored::UnexpectedConsecutive))
    );
    let payload = message(20);
    let (ff, _) = encode_first(20, &payload).unwrap();
    let _ = rx.on_frame(&ff, t(0));
    assert_eq!(
        rx.on_frame(&cts(0, 0), t(1)),
        outcome(None, RxEvent::Ignored(Ignored::FlowControl))
    );
    assert_eq!(
        rx.on_frame(&[0x40, 0, 0], t(1)),
        outcome(
            None,
            RxEvent::Ignored(Ignored::Malformed(FrameError::UnknownType { pci_type: 4 }))
        )
    );
    // The reception went on untouched.
    assert_eq!(rx.in_progress(), Some((6, 20)));
    let frames = frames_of(&payload);
    assert_eq!(rx.on_frame(&frames[1], t(2)).event, RxEvent::Nothing);
    assert_eq!(
        rx.on_frame(&frames[2], t(3)).event,
        RxEvent::Complete(&payload)
    );
}

#[test]
fn wrong_sequence_number_aborts() {
    let payload = message(30);
    let frames = frames_of(&payload);
    let mut rx = Receiver::<64>::new(RxConfig::default());
    let _ = rx.on_frame(&frames[0], t(0));
    // Frame 1 (SN 1) lost: frame 2 carries SN 2.
    assert_eq!(
        rx.on_frame(&frames[2], t(1)),
        outcome(
            Some(RxError::WrongSequenceNumber {
                expected: 1,
                got: 2
            }),
            RxEvent::Nothing
        )
    );
    assert_eq!(rx.in_progress(), None);
    assert_eq!(
        rx.on_frame(&frames[3], t(2)).event,
        RxEvent::Ignored(Ignored::UnexpectedConsecutive)
    );
    // A repeated frame is also a wrong sequence number.
    let _ = rx.on_frame(&frames[0], t(3));
    let _ = rx.on_frame(&frames[1], t(4));
    assert_eq!(
        rx.on_frame(&frames[1], t(5)).aborted,
        Some(RxError::WrongSequenceNumber {
            expected: 2,
            got: 1
        })
    );
}

#[test]
fn sequence_numbers_wrap_from_15_to_0() {
    let payload = message(6 + 7 * 40);
    let frames = frames_of(&payload);
    let sns: Vec<u8> = frames[1..].iter().map(|frame| frame[0]).collect();
    let expected: Vec<u8> = (1..=40).map(|k| 0x20 | (k % 16) as u8).collect();
    assert_eq!(sns, expected);
    assert_eq!(&sns[13..18], &[0x2E, 0x2F, 0x20, 0x21, 0x22]);
    let mut rx = Receiver::<40_000>::new(RxConfig::default());
    receive_whole(&mut rx, &payload);
}

#[test]
fn new_message_interrupts_a_reception() {
    let payload = message(100);
    let frames = frames_of(&payload);
    let mut rx = Receiver::<64>::new(RxConfig::default());
    let other = message(50);
    let (ff50, _) = encode_first(50, &other).unwrap();
    let _ = rx.on_frame(&ff50, t(0));
    let _ = rx.on_frame(&frames_of(&other)[1], t(1));
    assert_eq!(rx.in_progress(), Some((13, 50)));

    // A Single Frame: the abort and the new message, both reported.
    assert_eq!(
        rx.on_frame(&[0x02, 7, 8], t(2)),
        outcome(Some(RxError::Interrupted), RxEvent::Complete(&[7, 8]))
    );
    assert_eq!(rx.in_progress(), None);

    // A First Frame: the abort, and the new reception started.
    let _ = rx.on_frame(&ff50, t(3));
    let (ff20, _) = encode_first(20, &payload).unwrap();
    assert_eq!(
        rx.on_frame(&ff20, t(4)),
        outcome(
            Some(RxError::Interrupted),
            RxEvent::SendFlowControl(cts(0, 0))
        )
    );
    assert_eq!(rx.in_progress(), Some((6, 20)));
    assert_eq!(rx.received(), &payload[..6]);

    // A First Frame too large for the receiver: the abort, and the refusal.
    assert_eq!(
        rx.on_frame(&frames[0], t(5)),
        outcome(
            Some(RxError::Interrupted),
            RxEvent::Refused {
                reason: Refusal::TooLarge { len: 100 },
                flow_control: Some([0x32, 0, 0, CC, CC, CC, CC, CC]),
            }
        )
    );
    assert_eq!(rx.in_progress(), None);
}

#[test]
fn n_cr_timeout_across_the_counter_wrap() {
    let start = u64::MAX - 400_000;
    let payload = message(30);
    let frames = frames_of(&payload);
    let mut rx = Receiver::<64>::new(RxConfig {
        n_cr_micros: 1_000_000,
        ..RxConfig::default()
    });
    let _ = rx.on_frame(&frames[0], t(start));
    let deadline = t(start).wrapping_add_micros(1_000_000);
    assert_eq!(deadline.as_micros(), 599_999);
    assert_eq!(rx.deadline(), Some(deadline));
    assert_eq!(rx.poll(t(start)), None);
    assert_eq!(rx.poll(t(599_998)), None);
    // A Consecutive Frame restarts N_Cr.
    assert_eq!(rx.on_frame(&frames[1], t(599_998)).event, RxEvent::Nothing);
    assert_eq!(rx.deadline(), Some(t(1_599_998)));
    assert_eq!(rx.poll(t(1_599_997)), None);
    assert_eq!(rx.poll(t(1_599_998)), Some(RxError::Timeout));
    assert_eq!(rx.in_progress(), None);
    assert_eq!(rx.deadline(), None);
    assert_eq!(rx.poll(t(1_599_999)), None);

    // Without a poll, a late Consecutive Frame reports the timeout, then is ignored.
    let _ = rx.on_frame(&frames[0], t(start));
    assert_eq!(
        rx.on_frame(&frames[1], t(599_999)),
        outcome(
            Some(RxError::Timeout),
            RxEvent::Ignored(Ignored::UnexpectedConsecutive)
        )
    );
}

#[test]
fn abort_and_early_inspection() {
    let payload = message(100);
    let frames = frames_of(&payload);
    let mut rx = Receiver::<128>::new(RxConfig::default());
    assert!(!rx.abort());
    assert_eq!(rx.received(), &[] as &[u8]);
    let _ = rx.on_frame(&frames[0], t(0));
    let _ = rx.on_frame(&frames[1], t(0));
    let _ = rx.on_frame(&frames[2], t(0));
    // A 20-byte header is there after the First Frame and two Consecutive Frames.
    assert_eq!(rx.received(), &payload[..20]);
    assert_eq!(rx.message_len(), Some(100));
    assert!(rx.abort());
    assert_eq!(rx.in_progress(), None);
    assert_eq!(rx.message_len(), None);
    assert_eq!(
        rx.on_frame(&frames[3], t(0)).event,
        RxEvent::Ignored(Ignored::UnexpectedConsecutive)
    );
}

// ---------------------------------------------------------------------------------------------
// Sender

#[test]
fn sender_single_frame() {
    assert_eq!(
        Sender::new(&[], TxConfig::default()).err(),
        Some(TxSetupError::Empty)
    );
    let mut tx = Sender::new(&[1, 2, 3], TxConfig::default()).unwrap();
    assert_eq!(tx.progress(), (0, 3));
    assert_eq!(
        tx.poll(t(0)),
        TxEvent::Send([0x03, 1, 2, 3, CC, CC, CC, CC])
    );
    assert_eq!(tx.progress(), (3, 3));
    assert_eq!(tx.poll(t(0)), TxEvent::Done);
    assert_eq!(tx.poll(t(1)), TxEvent::Done);
    // A Flow Control is not expected after a Single Frame.
    assert_eq!(
        tx.on_flow_control(&cts(0, 0), t(1)),
        FlowControlEffect::Ignored
    );
    let seven = [1, 2, 3, 4, 5, 6, 7];
    let mut tx = Sender::new(
        &seven,
        TxConfig {
            padding: 0,
            ..TxConfig::default()
        },
    )
    .unwrap();
    assert_eq!(tx.poll(t(0)), TxEvent::Send([0x07, 1, 2, 3, 4, 5, 6, 7]));
}

#[test]
fn sender_eight_bytes() {
    let payload = message(8);
    let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
    assert_eq!(
        tx.poll(t(0)),
        TxEvent::Send([
            0x10, 0x08, payload[0], payload[1], payload[2], payload[3], payload[4], payload[5]
        ])
    );
    assert_eq!(tx.progress(), (6, 8));
    assert_eq!(tx.poll(t(10)), TxEvent::WaitUntil(t(1_000_000)));
    assert_eq!(
        tx.on_flow_control(&cts(0, 0), t(20)),
        FlowControlEffect::Resumed
    );
    // The last Consecutive Frame carries the remainder, padded.
    assert_eq!(
        tx.poll(t(20)),
        TxEvent::Send([0x21, payload[6], payload[7], CC, CC, CC, CC, CC])
    );
    assert_eq!(tx.progress(), (8, 8));
    assert_eq!(tx.poll(t(20)), TxEvent::Done);
}

#[test]
fn sender_first_frames_of_long_messages() {
    let payload = message(32_768);
    for (len, expected) in [
        (
            4095usize,
            [
                0x1F, 0xFF, payload[0], payload[1], payload[2], payload[3], payload[4], payload[5],
            ],
        ),
        (
            4096,
            [0x10, 0x00, 0x00, 0x00, 0x10, 0x00, payload[0], payload[1]],
        ),
        (
            32_768,
            [0x10, 0x00, 0x00, 0x00, 0x80, 0x00, payload[0], payload[1]],
        ),
    ] {
        let mut tx = Sender::new(&payload[..len], TxConfig::default()).unwrap();
        assert_eq!(tx.poll(t(0)), TxEvent::Send(expected), "{len}");
        let frames = frames_of(&payload[..len]);
        // The first Consecutive Frame continues right after the First Frame's data.
        let carried = if len > 4095 { 2 } else { 6 };
        assert_eq!(frames[1][0], 0x21);
        assert_eq!(&frames[1][1..], &payload[carried..carried + 7]);
        // Count and remainder of the last Consecutive Frame.
        let rest = len - carried;
        assert_eq!(frames.len(), 1 + rest.div_ceil(7));
        let tail = rest - 7 * (rest.div_ceil(7) - 1);
        let last = frames.last().unwrap();
        assert_eq!(&last[1..1 + tail], &payload[len - tail..len]);
        assert!(last[1 + tail..].iter().all(|&byte| byte == CC));
    }
}

/// Drives a sender with a Flow Control (BS, STmin byte) and returns, per Consecutive Frame, the
/// instant it was handed out. The driver polls at the instants the sender asks for.
fn paced(payload: &[u8], block_size: u8, st_min: u8) -> Vec<u64> {
    let mut tx = Sender::new(payload, TxConfig::default()).unwrap();
    let mut now = 1_000u64;
    let mut sent = Vec::new();
    let mut since_fc = 0usize;
    assert!(matches!(tx.poll(t(now)), TxEvent::Send(_)));
    let mut awaiting_fc = true;
    loop {
        match tx.poll(t(now)) {
            TxEvent::Send(frame) => {
                assert!(!awaiting_fc);
                assert_eq!(frame[0] >> 4, 2);
                sent.push(now);
                since_fc += 1;
                assert!(block_size == 0 || since_fc <= usize::from(block_size));
            }
            TxEvent::WaitUntil(at) => {
                if awaiting_fc || (block_size > 0 && since_fc == usize::from(block_size)) {
                    // Waiting for a Flow Control: its deadline is N_Bs from the last frame.
                    assert_eq!(at.as_micros(), now + 1_000_000);
                    assert!(
                        block_size == 0 || since_fc == 0 || since_fc == usize::from(block_size)
                    );
                    now += 50;
                    assert_eq!(
                        tx.on_flow_control(&cts(block_size, st_min), t(now)),
                        FlowControlEffect::Resumed
                    );
                    awaiting_fc = false;
                    since_fc = 0;
                } else {
                    assert!(at.as_micros() > now);
                    now = at.as_micros();
                }
            }
            TxEvent::Done => return sent,
            TxEvent::Failed(error) => panic!("{error:?}"),
        }
    }
}

#[test]
fn sender_honours_st_min() {
    let payload = message(6 + 7 * 10);
    for (st_min, gap) in [
        (0x00u8, 0u64),
        (0x01, 1_000),
        (0x0A, 10_000),
        (0x7F, 127_000),
        (0xF1, 100),
        (0xF9, 900),
        (0x80, 127_000),
        (0xFA, 127_000),
    ] {
        let sent = paced(&payload, 0, st_min);
        assert_eq!(sent.len(), 10);
        for pair in sent.windows(2) {
            // Exactly STmin apart: the driver polls at the instant asked for.
            assert_eq!(pair[1] - pair[0], gap, "STmin {st_min:#04x}");
        }
    }
    // Polling early does not release a frame.
    let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
    let _ = tx.poll(t(0));
    let _ = tx.on_flow_control(&cts(0, 0x0A), t(0));
    assert!(matches!(tx.poll(t(0)), TxEvent::Send(_)));
    assert_eq!(tx.poll(t(9_999)), TxEvent::WaitUntil(t(10_000)));
    assert!(matches!(tx.poll(t(10_000)), TxEvent::Send(_)));
    // Late polls send at once, and STmin counts from the late frame.
    assert!(matches!(tx.poll(t(50_000)), TxEvent::Send(_)));
    assert_eq!(tx.poll(t(50_001)), TxEvent::WaitUntil(t(60_000)));
}

#[test]
fn sender_stops_after_each_block() {
    let payload = message(6 + 7 * 20);
    for block_size in [0u8, 1, 3, 8] {
        let sent = paced(&payload, block_size, 0);
        assert_eq!(sent.len(), 20, "BS {block_size}");
        // The driver advances 50 µs per Flow Control: count the pauses.
        let pauses = sent.windows(2).filter(|pair| pair[1] != pair[0]).count();
        let expected = if block_size == 0 {
            0
        } else {
            (20 - 1) / usize::from(block_size)
        };
        assert_eq!(pauses, expected, "BS {block_size}");
    }
    // Exactly BS frames, then WaitUntil until the next Flow Control, however often it is polled.
    let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
    let _ = tx.poll(t(0));
    let _ = tx.on_flow_control(&cts(3, 0), t(0));
    for _ in 0..3 {
        assert!(matches!(tx.poll(t(7)), TxEvent::Send(_)));
    }
    for now in [7, 8, 999_999, 1_000_006] {
        assert_eq!(tx.poll(t(now)), TxEvent::WaitUntil(t(1_000_007)));
    }
    assert_eq!(tx.progress(), (27, 146));
    assert_eq!(
        tx.on_flow_control(&cts(3, 0), t(1_000_006)),
        FlowControlEffect::Resumed
    );
    assert_eq!(
        tx.poll(t(1_000_006)),
        TxEvent::Send([
            0x24,
            payload[27],
            payload[28],
            payload[29],
            payload[30],
            payload[31],
            payload[32],
            payload[33]
        ])
    );
}

#[test]
fn n_bs_timeout_across_the_counter_wrap() {
    let payload = message(20);
    let start = u64::MAX - 100;
    let mut tx = Sender::new(
        &payload,
        TxConfig {
            n_bs_micros: 1_000,
            ..TxConfig::default()
        },
    )
    .unwrap();
    assert!(matches!(tx.poll(t(start)), TxEvent::Send(_)));
    assert_eq!(tx.poll(t(start)), TxEvent::WaitUntil(t(899)));
    assert_eq!(tx.poll(t(898)), TxEvent::WaitUntil(t(899)));
    assert_eq!(tx.poll(t(899)), TxEvent::Failed(TxError::Timeout));
    assert_eq!(tx.poll(t(900)), TxEvent::Failed(TxError::Timeout));
    // A Flow Control after the failure changes nothing.
    assert_eq!(
        tx.on_flow_control(&cts(0, 0), t(900)),
        FlowControlEffect::Ignored
    );
    assert_eq!(tx.poll(t(901)), TxEvent::Failed(TxError::Timeout));
}

#[test]
fn wait_restarts_n_bs_up_to_the_limit() {
    let payload = message(20);
    let wait = [0x31, 0, 0, CC, CC, CC, CC, CC];
    let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
    let _ = tx.poll(t(0));
    let mut now = 0;
    for _ in 0..10 {
        now += 900_000;
        assert_eq!(
            tx.on_flow_control(&wait, t(now)),
            FlowControlEffect::Waiting
        );
        assert_eq!(tx.poll(t(now)), TxEvent::WaitUntil(t(now + 1_000_000)));
    }
    // The eleventh WAIT in a row is one too many.
    assert_eq!(
        tx.on_flow_control(&wait, t(now)),
        FlowControlEffect::Failed(TxError::TooManyWaits)
    );
    assert_eq!(tx.poll(t(now)), TxEvent::Failed(TxError::TooManyWaits));

    // A ContinueToSend resets the count.
    let mut tx = Sender::new(
        &payload,
        TxConfig {
            max_wait_frames: 1,
            ..TxConfig::default()
        },
    )
    .unwrap();
    let _ = tx.poll(t(0));
    assert_eq!(tx.on_flow_control(&wait, t(0)), FlowControlEffect::Waiting);
    assert_eq!(
        tx.on_flow_control(&cts(1, 0), t(0)),
        FlowControlEffect::Resumed
    );
    assert!(matches!(tx.poll(t(0)), TxEvent::Send(_)));
    assert_eq!(tx.on_flow_control(&wait, t(0)), FlowControlEffect::Waiting);
    assert_eq!(
        tx.on_flow_control(&wait, t(0)),
        FlowControlEffect::Failed(TxError::TooManyWaits)
    );

    // N_WFTmax = 0: no WAIT accepted.
    let mut tx = Sender::new(
        &payload,
        TxConfig {
            max_wait_frames: 0,
            ..TxConfig::default()
        },
    )
    .unwrap();
    let _ = tx.poll(t(0));
    assert_eq!(
        tx.on_flow_control(&wait, t(0)),
        FlowControlEffect::Failed(TxError::TooManyWaits)
    );
}

#[test]
fn overflow_and_invalid_status_fail_the_transfer() {
    let payload = message(5000);
    let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
    let _ = tx.poll(t(0));
    assert_eq!(
        tx.on_flow_control(&[0x32, 0, 0, CC, CC, CC, CC, CC], t(1)),
        FlowControlEffect::Failed(TxError::Overflow)
    );
    assert_eq!(tx.poll(t(1)), TxEvent::Failed(TxError::Overflow));

    for status in 3..=15u8 {
        let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
        let _ = tx.poll(t(0));
        let error = TxError::InvalidFlowStatus { status };
        assert_eq!(
            tx.on_flow_control(&[0x30 | status, 0, 0], t(1)),
            FlowControlEffect::Failed(error)
        );
        assert_eq!(tx.poll(t(1)), TxEvent::Failed(error));
    }
}

#[test]
fn unexpected_and_malformed_flow_controls_are_ignored() {
    let payload = message(100);
    let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
    // Before the First Frame.
    assert_eq!(
        tx.on_flow_control(&cts(0, 0), t(0)),
        FlowControlEffect::Ignored
    );
    let _ = tx.poll(t(0));
    // Waiting: truncated, or not a Flow Control.
    for frame in [
        &[0x30, 0][..],
        &[0x30],
        &[],
        &[0x21, 1, 2],
        &[0x02, 1, 2],
        &[0x50, 0, 0],
    ] {
        assert_eq!(tx.on_flow_control(frame, t(0)), FlowControlEffect::Ignored);
    }
    assert_eq!(tx.poll(t(0)), TxEvent::WaitUntil(t(1_000_000)));
    // Unpadded is fine.
    assert_eq!(
        tx.on_flow_control(&[0x30, 0, 0], t(0)),
        FlowControlEffect::Resumed
    );
    assert!(matches!(tx.poll(t(0)), TxEvent::Send(_)));
    // While sending with BS = 0, even an Overflow is ignored.
    assert_eq!(
        tx.on_flow_control(&[0x32, 0, 0], t(0)),
        FlowControlEffect::Ignored
    );
    assert!(matches!(tx.poll(t(0)), TxEvent::Send(_)));
    assert_eq!(tx.progress(), (20, 100));
}

// ---------------------------------------------------------------------------------------------
// Round trips

/// What happened to a transfer between one sender and one receiver on an ideal bus that may lose
/// frames.
#[derive(Debug, Default)]
struct Transfer {
    /// The messages the receiver completed.
    completed: Vec<Vec<u8>>,
    sender_error: Option<TxError>,
    receiver_errors: Vec<RxError>,
    frames: usize,
}

/// Runs a transfer; `drop(k)` says whether the k-th frame on the bus (both directions, from 0) is
/// lost. Checks STmin pacing and block sizes on the way.
fn transfer(
    payload: &[u8],
    block_size: u8,
    st_min: StMin,
    drop: impl Fn(usize) -> bool,
) -> Transfer {
    let mut rx = Box::new(Receiver::<32_768>::new(RxConfig {
        block_size,
        st_min,
        ..RxConfig::default()
    }));
    let mut tx = Sender::new(payload, TxConfig::default()).unwrap();
    let mut result = Transfer::default();
    let mut now = t(u64::MAX - 5_000_000); // across the counter's wrap
    let mut last_cf: Option<Instant> = None;
    let mut in_block = 0usize;
    let mut sender_finished = false;
    for _ in 0..1_000_000 {
        if !sender_finished {
            match tx.poll(now) {
                TxEvent::Send(frame) => {
                    if frame[0] >> 4 == 2 {
                        if let Some(previous) = last_cf
                            && in_block > 0
                        {
                            let gap = now.micros_since(previous).unwrap();
                            assert!(gap >= u64::from(st_min.as_micros()));
                        }
                        last_cf = Some(now);
                        in_block += 1;
                        assert!(block_size == 0 || in_block <= usize::from(block_size));
                    }
                    let lost = drop(result.frames);
                    result.frames += 1;
                    if !lost {
                        let answer = rx.on_frame(&frame, now);
                        result.receiver_errors.extend(answer.aborted);
                        match answer.event {
                            RxEvent::Complete(message) => result.completed.push(message.to_vec()),
                            RxEvent::SendFlowControl(fc) => {
                                let lost = drop(result.frames);
                                result.frames += 1;
                                if !lost {
                                    let _ = tx.on_flow_control(&fc, now);
                                    in_block = 0;
                                }
                            }
                            RxEvent::Nothing | RxEvent::Ignored(_) => {}
                            RxEvent::Refused { .. } => panic!("refused"),
                        }
                    }
                    continue;
                }
                TxEvent::WaitUntil(at) => {
                    let at = match rx.deadline() {
                        Some(deadline) if deadline.micros_since(at).is_none() => deadline,
                        _ => at,
                    };
                    now = at;
                }
                TxEvent::Done => sender_finished = true,
                TxEvent::Failed(error) => {
                    result.sender_error = Some(error);
                    sender_finished = true;
                }
            }
        } else {
            match rx.deadline() {
                Some(deadline) => now = deadline,
                None => return result,
            }
        }
        result.receiver_errors.extend(rx.poll(now));
    }
    panic!("the transfer did not end");
}

fn lengths() -> impl Strategy<Value = usize> {
    prop_oneof![1usize..=20, 1usize..=300, 4090usize..=4100, 1usize..=32_768]
}

fn st_mins() -> impl Strategy<Value = StMin> {
    prop_oneof![
        Just(StMin::ZERO),
        (0u8..=3).prop_map(|ms| StMin::from_millis(ms).unwrap()),
        (1u8..=9).prop_map(|h| StMin::from_hundred_micros(h).unwrap()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn round_trip(len in lengths(), block_size in prop_oneof![Just(0u8), 1u8..=16, Just(255u8)], st_min in st_mins()) {
        let payload = message(len);
        let result = transfer(&payload, block_size, st_min, |_| false);
        prop_assert_eq!(result.sender_error, None);
        prop_assert!(result.receiver_errors.is_empty());
        prop_assert_eq!(result.completed, vec![payload]);
    }

    /// Losing up to three frames anywhere (data or Flow Control) always shows as an error on one
    /// side or the other, and never as a wrong message.
    #[test]
    fn lost_frames_are_errors_never_wrong_messages(
        len in lengths(),
        block_size in prop_oneof![Just(0u8), 1u8..=16],
        st_min in st_mins(),
        picks in prop::collection::vec(any::<prop::sample::Index>(), 1..=3),
    ) {
        let payload = message(len);
        let total = transfer(&payload, block_size, st_min, |_| false).frames;
        let lost: Vec<usize> = picks.iter().map(|pick| pick.index(total)).collect();
        let result = transfer(&payload, block_size, st_min, |k| lost.contains(&k));
        prop_assert!(result.completed.is_empty(), "a message completed after losing {:?}", lost);
        // A lost Single Frame or a lost last frame with BS = 0 leaves only the receiver to notice
        // (or nobody, for a Single Frame: nothing was ever started).
        let single = len <= 7;
        prop_assert!(single || result.sender_error.is_some() || !result.receiver_errors.is_empty());
    }

    /// Random bytes, at random times, into a receiver: never a panic, and its state stays sane.
    #[test]
    fn receiver_survives_any_frames(
        frames in prop::collection::vec((prop::collection::vec(any::<u8>(), 0..=10), 0u64..2_000_000), 0..200),
        block_size in any::<u8>(),
    ) {
        let mut rx = Receiver::<64>::new(RxConfig { block_size, ..RxConfig::default() });
        let mut now = t(u64::MAX - 10_000_000);
        for (frame, step) in &frames {
            now = now.wrapping_add_micros(*step);
            let result = rx.on_frame(frame, now);
            if let RxEvent::Complete(message) = result.event {
                prop_assert!(!message.is_empty() && message.len() <= 64);
            }
            if let Some((received, total)) = rx.in_progress() {
                prop_assert!(received < total && total <= 64);
                prop_assert_eq!(rx.received().len(), received);
            }
            let _ = rx.poll(now);
        }
    }

    /// Random bytes as Flow Controls, at random times, into a sender: never a panic, never more
    /// than the payload.
    #[test]
    fn sender_survives_any_flow_controls(
        frames in prop::collection::vec((prop::collection::vec(any::<u8>(), 0..=10), 0u64..200_000), 0..100),
        len in 1usize..200,
    ) {
        let payload = message(len);
        let mut tx = Sender::new(&payload, TxConfig::default()).unwrap();
        let mut now = t(u64::MAX - 1_000_000);
        for (frame, step) in &frames {
            now = now.wrapping_add_micros(*step);
            let _ = tx.poll(now);
            let _ = tx.on_flow_control(frame, now);
            let (sent, total) = tx.progress();
            prop_assert!(sent <= total && total == len);
        }
    }
}
