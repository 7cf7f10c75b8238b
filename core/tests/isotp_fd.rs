//! ISO-TP on CAN FD against python can-isotp: every frame `isotp::fd`'s encoders write for a
//! message, at each of the eight TX_DL values, is the frame can-isotp 2.0.7 sends for it
//! (fixtures/isotp_fd_can_isotp.txt, written by scripts/isotp_fd_golden.py; ./test.sh checks
//! that the script still writes it), and every one of can-isotp's frames decodes back into
//! the message.

use pab_core::isotp::fd::{self, FdFrame, TxDl};
use pab_core::isotp::pci::Pci;

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
