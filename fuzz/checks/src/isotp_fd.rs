//! ISO-TP on CAN FD (`pab_core::isotp::fd`): any bytes as one frame's data field (up to 65
//! bytes). The decoder never panics, refuses every length that is not a CAN FD one, agrees with
//! the classic decoder on frames of 8 bytes or fewer, and what it accepts longer is what the
//! encoders write again: the PCI bytes and the payload at TX_DL = the frame's length.

use pab_core::isotp::fd::{self, TxDl};
use pab_core::isotp::pci::{self, FrameError, Pci};

pub fn check(data: &[u8]) {
    let frame = data
        .get(..data.len().min(fd::MAX_FD_FRAME_LEN + 1))
        .unwrap_or(data);
    let len = frame.len();
    let result = fd::decode(frame);
    if !fd::is_fd_length(len) {
        assert_eq!(result, Err(FrameError::FdLength { len }));
        return;
    }
    if len <= pci::FRAME_LEN {
        assert_eq!(result, pci::decode(frame));
        return;
    }
    let Ok((pci, payload)) = result else {
        return;
    };
    let tx_dl = TxDl::new(len).expect("a CAN FD length above 8 is a TX_DL");
    match pci {
        Pci::Single { len: single } => {
            let single = usize::from(single);
            assert!(single > 7 && single <= len - 2 && payload.len() == single);
            let again = fd::encode_single(payload, tx_dl, 0).expect("an accepted Single Frame");
            assert_eq!(&again.as_bytes()[..2 + single], &frame[..2 + single]);
        }
        Pci::First { len: total } => {
            assert!(total as usize > len - 2);
            let (again, carried) =
                fd::encode_first(total, payload, tx_dl).expect("an accepted First Frame");
            assert_eq!(again.as_bytes(), frame);
            assert_eq!(carried, payload.len());
        }
        Pci::Consecutive { sn } => {
            assert_eq!(payload.len(), len - 1);
            let again = fd::encode_consecutive(sn, payload, tx_dl, 0).expect("a full one");
            assert_eq!(again.as_bytes(), frame);
        }
        Pci::FlowControl { .. } => {
            assert!(payload.is_empty());
            assert_eq!(frame[0] >> 4, 3);
        }
    }
}

/// Seeds (`examples/seeds.rs`): at each TX_DL, the longest Single Frame, a First Frame with the
/// 12-bit length and one with the escape, a full Consecutive Frame, and a Flow Control padded to
/// the TX_DL.
pub fn seeds() -> Vec<(String, Vec<u8>)> {
    let message: Vec<u8> = (0..64u8).map(|i| i.wrapping_mul(37)).collect();
    let mut seeds = Vec::new();
    for len in [8, 12, 16, 20, 24, 32, 48, 64] {
        let Some(tx_dl) = TxDl::new(len) else {
            continue;
        };
        let mut add =
            |kind: &str, bytes: &[u8]| seeds.push((format!("{kind}-{len}"), bytes.to_vec()));
        if let Ok(frame) = fd::encode_single(&message[..tx_dl.max_single()], tx_dl, 0xCC) {
            add("single", frame.as_bytes());
        }
        for (kind, total) in [("first", 4000u32), ("first-escaped", 70_000)] {
            if let Ok((frame, _)) = fd::encode_first(total, &message, tx_dl) {
                add(kind, frame.as_bytes());
            }
        }
        let full = tx_dl.consecutive_data_len();
        if let Ok(frame) = fd::encode_consecutive(1, &message[..full], tx_dl, 0xCC) {
            add("consecutive", frame.as_bytes());
        }
        let mut flow = vec![0xCC; len];
        flow[..3].copy_from_slice(&[0x30, 0, 0]);
        add("flow-control", &flow);
    }
    seeds
}
