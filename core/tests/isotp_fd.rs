//! ISO-TP on CAN FD against python can-isotp: every frame `isotp::fd`'s encoders write for a
//! message, at each of the eight TX_DL values, is the frame can-isotp 2.0.7 sends for it
//! (fixtures/isotp_fd_can_isotp.txt, written by scripts/isotp_fd_golden.py; ./test.sh checks
//! that the script still writes it), and every one of can-isotp's frames decodes back into
//! the message. The FD sender sends those frames; with the feature `fd`, the receiver takes
//! them, and property tests send any message at any TX_DL through both, and any mix of classic
//! and CAN FD frames into the receiver.

use pab_core::Instant;
use pab_core::isotp::fd::{self, FdFrame, TxDl};
use pab_core::isotp::pci::Pci;
use pab_core::isotp::{FdSender, FlowControlEffect, Sender, TxConfig, TxEvent};

/// The message the script sends for `len`: byte i is (i * 7 + len) & 0xFF.
fn message(len: usize) -> Vec<u8> {
    (0..len).map(|i| ((i * 7 + len) & 0xFF) as u8).collect()
}

/// Every frame of `message` at `tx_dl`, as a sender that is never held up writes them: a Single
/// Frame, or a First Frame and the Consecutive Frames (sequence numbers from 1).
fn segment(message: &[u8], tx_dl: TxDl) -> Vec<FdFrame> {
    if message.len() <= tx_dl.max_single() {
        return vec![fd::encode_single(message, tx_dl, 0xCC).unwrap()];
    }
    let (first, mut at) = fd::encode_first(message.len() as u32, message, tx_dl).unwrap();
    let mut frames = vec![first];
    let mut sn = 1u8;
    while at < message.len() {
        let end = (at + tx_dl.consecutive_data_len()).min(message.len());
        frames.push(fd::encode_consecutive(sn, &message[at..end], tx_dl, 0xCC).unwrap());
        at = end;
        sn = (sn + 1) & 0x0F;
    }
    frames
}

/// The message the frames carry, through `fd::decode`, with the receiver's checks: the
/// Consecutive Frames in sequence, each as long as the First Frame (RX_DL) but the last.
fn reassemble(frames: &[Vec<u8>]) -> Vec<u8> {
    let (pci, payload) = fd::decode(&frames[0]).unwrap();
    let total = match pci {
        Pci::Single { len } => {
            assert_eq!(frames.len(), 1);
            return payload[..usize::from(len)].to_vec();
        }
        Pci::First { len } => len as usize,
        other => panic!("a message starting with {other:?}"),
    };
    let rx_dl = frames[0].len();
    let mut message = payload.to_vec();
    for (index, frame) in frames.iter().enumerate().skip(1) {
        let (pci, payload) = fd::decode(frame).unwrap();
        assert_eq!(
            pci,
            Pci::Consecutive {
                sn: (index & 0x0F) as u8
            }
        );
        if index + 1 < frames.len() {
            assert_eq!(frame.len(), rx_dl, "a Consecutive Frame shorter than RX_DL");
        } else {
            assert!(frame.len() <= rx_dl);
        }
        message.extend_from_slice(payload);
    }
    assert!(message.len() >= total);
    message.truncate(total);
    message
}

#[test]
fn the_frames_are_can_isotps() {
    let golden = include_str!("fixtures/isotp_fd_can_isotp.txt");
    let mut messages = 0;
    for line in golden.lines().filter(|line| !line.starts_with('#')) {
        let mut fields = line.split(' ');
        let tx: usize = fields.next().unwrap().parse().unwrap();
        let len: usize = fields.next().unwrap().parse().unwrap();
        let count: usize = fields.next().unwrap().parse().unwrap();
        let shown: Vec<&str> = fields.collect();
        let tx_dl = TxDl::new(tx).unwrap();
        let expected = message(len);

        let ours: Vec<Vec<u8>> = segment(&expected, tx_dl)
            .iter()
            .map(|frame| frame.as_bytes().to_vec())
            .collect();
        assert_eq!(ours.len(), count, "TX_DL {tx}, {len} bytes: frame count");
        let hex = |frame: &[u8]| frame.iter().map(|b| format!("{b:02x}")).collect::<String>();
        if let Some(gap) = shown.iter().position(|&field| field == "...") {
            // A long message: its first frames and its last.
            for (index, theirs) in shown[..gap].iter().enumerate() {
                assert_eq!(
                    &hex(&ours[index]),
                    theirs,
                    "TX_DL {tx}, {len} bytes, frame {index}"
                );
            }
            assert_eq!(
                &hex(ours.last().unwrap()),
                shown[gap + 1],
                "TX_DL {tx}, {len} bytes: last frame"
            );
        } else {
            assert_eq!(shown.len(), count);
            for (index, theirs) in shown.iter().enumerate() {
                assert_eq!(
                    &hex(&ours[index]),
                    theirs,
                    "TX_DL {tx}, {len} bytes, frame {index}"
                );
            }
            // can-isotp's frames, decoded by ours.
            let theirs: Vec<Vec<u8>> = shown
                .iter()
                .map(|field| {
                    (0..field.len())
                        .step_by(2)
                        .map(|i| u8::from_str_radix(&field[i..i + 2], 16).unwrap())
                        .collect()
                })
                .collect();
            assert_eq!(reassemble(&theirs), expected, "TX_DL {tx}, {len} bytes");
        }
        assert_eq!(reassemble(&ours), expected, "TX_DL {tx}, {len} bytes: ours");
        messages += 1;
    }
    // Eight TX_DL values, 133 lengths each.
    assert_eq!(messages, 8 * 133);
}

/// Every frame [`FdSender`] hands out for a message, its receiver answering each First Frame and
/// block at once (`block_size`; 0: one Flow Control after the First Frame).
fn send_all(message: &[u8], tx_dl: TxDl, block_size: u8) -> Vec<Vec<u8>> {
    let mut sender = FdSender::new(message, TxConfig::default(), tx_dl).unwrap();
    let now = Instant::from_micros(0);
    let cts = [0x30, block_size, 0, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC];
    let mut frames = Vec::new();
    loop {
        match sender.poll(now) {
            TxEvent::Send(frame) => frames.push(frame.as_bytes().to_vec()),
            TxEvent::WaitUntil(_) => {
                assert_eq!(
                    sender.on_flow_control(&cts, now),
                    FlowControlEffect::Resumed
                );
            }
            TxEvent::Done => return frames,
            TxEvent::Failed(error) => panic!("{error:?}"),
        }
    }
}

/// The sender's frames are the codec's, so can-isotp's: every golden message at every TX_DL.
#[test]
fn the_fd_sender_sends_can_isotps_frames() {
    let golden = include_str!("fixtures/isotp_fd_can_isotp.txt");
    for line in golden.lines().filter(|line| !line.starts_with('#')) {
        let mut fields = line.split(' ');
        let tx: usize = fields.next().unwrap().parse().unwrap();
        let len: usize = fields.next().unwrap().parse().unwrap();
        let tx_dl = TxDl::new(tx).unwrap();
        let expected: Vec<Vec<u8>> = segment(&message(len), tx_dl)
            .iter()
            .map(|frame| frame.as_bytes().to_vec())
            .collect();
        for block_size in [0, 3] {
            assert_eq!(
                send_all(&message(len), tx_dl, block_size),
                expected,
                "TX_DL {tx}, {len} bytes, BS {block_size}"
            );
        }
    }
}

/// At TX_DL 8 the FD sender and the classic one send the same bytes.
#[test]
fn at_eight_bytes_the_fd_sender_is_the_classic_sender() {
    for len in [1, 7, 8, 100, 4095, 4096, 9000] {
        let payload = message(len);
        let mut classic = Sender::new(&payload, TxConfig::default()).unwrap();
        let now = Instant::from_micros(0);
        let cts = [0x30, 0, 0];
        let mut frames = Vec::new();
        loop {
            match classic.poll(now) {
                TxEvent::Send(frame) => frames.push(frame.to_vec()),
                TxEvent::WaitUntil(_) => {
                    classic.on_flow_control(&cts, now);
                }
                TxEvent::Done => break,
                TxEvent::Failed(error) => panic!("{error:?}"),
            }
        }
        assert_eq!(send_all(&payload, TxDl::CLASSIC, 0), frames, "{len} bytes");
    }
}

#[cfg(feature = "fd")]
mod receiver {
    use super::*;
    use pab_core::isotp::{Ignored, Receiver, RxConfig, RxError, RxEvent};
    use proptest::prelude::*;

    fn t(micros: u64) -> Instant {
        Instant::from_micros(micros)
    }

    /// can-isotp's frames of every golden message shown whole, into the receiver: the message,
    /// a Flow Control after each First Frame and block.
    #[test]
    fn the_receiver_takes_can_isotps_frames() {
        let golden = include_str!("fixtures/isotp_fd_can_isotp.txt");
        let mut checked = 0;
        for line in golden.lines().filter(|line| !line.starts_with('#')) {
            let fields: Vec<&str> = line.split(' ').collect();
            if fields.contains(&"...") {
                continue;
            }
            let len: usize = fields[1].parse().unwrap();
            let frames: Vec<Vec<u8>> = fields[3..]
                .iter()
                .map(|field| {
                    (0..field.len())
                        .step_by(2)
                        .map(|i| u8::from_str_radix(&field[i..i + 2], 16).unwrap())
                        .collect()
                })
                .collect();
            let mut rx = Receiver::<5000>::new(RxConfig::default());
            let mut completed = None;
            for (index, frame) in frames.iter().enumerate() {
                let outcome = rx.on_fd_frame(frame, t(index as u64));
                assert_eq!(outcome.aborted, None);
                match outcome.event {
                    RxEvent::Complete(m) => completed = Some(m.to_vec()),
                    RxEvent::SendFlowControl(fc) => {
                        assert_eq!(index, 0);
                        assert_eq!(fc[0], 0x30);
                        assert_eq!(rx.is_fd(), Some(true));
                    }
                    RxEvent::Nothing => {}
                    other => panic!("{line}: frame {index}: {other:?}"),
                }
            }
            assert_eq!(completed, Some(message(len)), "{line}");
            checked += 1;
        }
        assert!(checked > 8 * 100, "{checked}");
    }

    /// Delivers `frames` (data, is it FD) in order; returns each frame's event, as text.
    fn feed(rx: &mut Receiver<512>, frames: &[(Vec<u8>, bool)]) -> Vec<String> {
        frames
            .iter()
            .enumerate()
            .map(|(index, (data, fd))| {
                let now = t(index as u64 * 1000);
                let outcome = if *fd {
                    rx.on_fd_frame(data, now)
                } else {
                    rx.on_frame(data, now)
                };
                format!("{:?} {:?}", outcome.aborted, outcome.event)
            })
            .collect()
    }

    #[test]
    fn a_consecutive_frame_of_the_other_kind_is_ignored() {
        let payload = message(200);
        let fd_frames: Vec<(Vec<u8>, bool)> = send_all(&payload, TxDl::MAX, 0)
            .into_iter()
            .map(|f| (f, true))
            .collect();
        // An FD First Frame, then a classic Consecutive Frame with the next sequence number:
        // ignored; the FD one after it goes on.
        let mut rx = Receiver::<512>::new(RxConfig::default());
        let mut frames = vec![fd_frames[0].clone()];
        frames.push((vec![0x21, 1, 2, 3, 4, 5, 6, 7], false));
        frames.extend(fd_frames[1..].iter().cloned());
        let events = feed(&mut rx, &frames);
        assert!(events[1].contains("OtherFormat"), "{events:?}");
        assert!(events.last().unwrap().contains("Complete"), "{events:?}");

        // A classic First Frame, then an FD Consecutive Frame: ignored.
        let mut rx = Receiver::<512>::new(RxConfig::default());
        let classic = pab_core::isotp::pci::encode_first(200, &payload).unwrap().0;
        let events = feed(
            &mut rx,
            &[(classic.to_vec(), false), (fd_frames[1].0.clone(), true)],
        );
        assert!(events[1].contains("OtherFormat"), "{events:?}");
        assert_eq!(rx.is_fd(), Some(false));
        // An FD First Frame during the classic reception interrupts it and starts its own.
        let outcome = rx.on_fd_frame(&fd_frames[0].0, t(5000));
        assert_eq!(outcome.aborted, Some(RxError::Interrupted));
        assert!(matches!(outcome.event, RxEvent::SendFlowControl(_)));
        assert_eq!(rx.is_fd(), Some(true));
    }

    #[test]
    fn consecutive_frames_must_be_rx_dl_long_but_the_last() {
        let payload = message(300);
        let frames = send_all(&payload, TxDl::new(32).unwrap(), 0);
        let mut rx = Receiver::<512>::new(RxConfig::default());
        assert!(matches!(
            rx.on_fd_frame(&frames[0], t(0)).event,
            RxEvent::SendFlowControl(_)
        ));
        // The second frame cut to 24 bytes (a valid CAN FD length, not the last): ignored.
        let short = rx.on_fd_frame(&frames[1][..24], t(1));
        assert_eq!(
            short.event,
            RxEvent::Ignored(Ignored::FdLength { rx_dl: 32, got: 24 })
        );
        // Longer than RX_DL: ignored.
        let mut long = frames[1].clone();
        long.resize(48, 0xCC);
        let long = rx.on_fd_frame(&long, t(2));
        assert_eq!(
            long.event,
            RxEvent::Ignored(Ignored::FdLength { rx_dl: 32, got: 48 })
        );
        let mut last = None;
        for (index, frame) in frames.iter().enumerate().skip(1) {
            last = Some(format!(
                "{:?}",
                rx.on_fd_frame(frame, t(3 + index as u64)).event
            ));
        }
        assert!(last.unwrap().starts_with("Complete"));
    }

    fn tx_dls() -> impl Strategy<Value = TxDl> {
        prop::sample::select(vec![8usize, 12, 16, 20, 24, 32, 48, 64])
            .prop_map(|l| TxDl::new(l).unwrap())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Any message at any TX_DL and block size: the receiver takes exactly the message,
        /// answering each First Frame and block with a Flow Control.
        #[test]
        fn round_trip(len in 1usize..=5000, tx_dl in tx_dls(), block_size in prop_oneof![Just(0u8), 1u8..=16]) {
            let payload = message(len);
            let mut sender = FdSender::new(&payload, TxConfig::default(), tx_dl).unwrap();
            let mut rx = Receiver::<5000>::new(RxConfig { block_size, ..RxConfig::default() });
            let mut now = 0u64;
            let mut completed = None;
            let mut frames = 0;
            loop {
                now += 10;
                match sender.poll(t(now)) {
                    TxEvent::Send(frame) => {
                        frames += 1;
                        prop_assert!(frame.as_bytes().len() <= tx_dl.len());
                        let outcome = rx.on_fd_frame(frame.as_bytes(), t(now));
                        prop_assert_eq!(outcome.aborted, None);
                        match outcome.event {
                            RxEvent::SendFlowControl(fc) => {
                                sender.on_flow_control(&fc, t(now));
                            }
                            RxEvent::Complete(m) => completed = Some(m.to_vec()),
                            RxEvent::Nothing => {}
                            other => prop_assert!(false, "{:?}", other),
                        }
                    }
                    TxEvent::WaitUntil(_) => prop_assert!(false, "waiting with nothing to wait for"),
                    TxEvent::Done => break,
                    TxEvent::Failed(error) => prop_assert!(false, "{:?}", error),
                }
            }
            prop_assert_eq!(completed, Some(payload));
            // The fewest frames: a Single Frame, or the First Frame and full Consecutive Frames.
            let expected = if len <= tx_dl.max_single() {
                1
            } else {
                1 + (len - tx_dl.first_data_len(len as u32)).div_ceil(tx_dl.consecutive_data_len())
            };
            prop_assert_eq!(frames, expected);
        }

        /// Frames of either kind, of any bytes and lengths, in any order: never a panic, a message
        /// only from a complete reception, and a state that stays sane.
        #[test]
        fn any_mix_of_frames(
            frames in prop::collection::vec((prop::collection::vec(any::<u8>(), 0..=64), any::<bool>(), 0u64..2_000_000), 0..200),
            block_size in any::<u8>(),
        ) {
            let mut rx = Receiver::<300>::new(RxConfig { block_size, ..RxConfig::default() });
            let mut now = u64::MAX - 10_000_000;
            for (data, fd, step) in &frames {
                now = now.wrapping_add(*step);
                let outcome = if *fd { rx.on_fd_frame(data, t(now)) } else { rx.on_frame(data, t(now)) };
                if let RxEvent::Complete(message) = outcome.event {
                    prop_assert!(!message.is_empty() && message.len() <= 300);
                }
                if let Some((received, total)) = rx.in_progress() {
                    prop_assert!(received < total && total <= 300);
                }
            }
        }
    }
}
