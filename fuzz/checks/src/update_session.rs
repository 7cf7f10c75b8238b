//! A node's side of a firmware update (`pab_core::update::session`): the messages of an
//! update, from the fuzzer, through an [`Updater`] that writes into a slot. The input picks the
//! image (length and bytes), the Begin's manifest (the node's board kind or another, a version
//! lower, equal or higher, a length that fits or not) and then a sequence of steps: the next
//! chunk as a tool sends it, the same with a byte changed, a chunk anywhere with any bytes, a
//! commit with the image's CRC or another, an abort, a Begin again, any bytes as a message, a
//! write that fails, time passing.
//!
//! Properties: never a panic; a write lands only inside the slot's image area and at the offset
//! the session had acknowledged; every Ack's CRC is that of the slot's bytes before its offset;
//! a Begin is admitted exactly when the check's own model of the rules admits its trailer; a
//! commit happens only for a slot that holds exactly the image, and names its length and CRC.

use arbitrary::{Result, Unstructured};
use pab_core::Instant;
use pab_core::crc32::crc32;
use pab_core::identity::Firmware;
use pab_core::update::session::{self, CHUNK, Outcome, SESSION_TIMEOUT_US, Updater};
use pab_core::update::stored::{self, Manifest};
use pab_core::update::{MIN_IMAGE_LEN, Trailer};

const SLOT: u32 = 8 * 1024;

fn running() -> Firmware {
    Firmware::new("fw-an386", "2.3.4", "00112233aabbccdd")
}

pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data));
}

fn run(u: &mut Unstructured<'_>) -> Result<()> {
    let len = usize::from(u.int_in_range(0u16..=(SLOT as u16))?);
    let seed: u8 = u.arbitrary()?;
    let image: Vec<u8> = (0..len)
        .map(|i| (i as u8).wrapping_mul(seed) ^ 0x3C)
        .collect();
    let other_board: bool = u.arbitrary()?;
    let version: [u8; 3] = [2, 3, u.int_in_range(3..=5)?];
    let downgrade: bool = u.arbitrary()?;
    let trailer = Trailer {
        firmware: Firmware {
            name: if other_board {
                *b"fw-g474\0"
            } else {
                running().name
            },
            version,
            build: [7; 8],
        },
        downgrade,
        image_len: len as u32,
    };
    let manifest = Manifest {
        trailer,
        signature: [0xA5; 64],
    }
    .encode();
    let admitted = !other_board
        && (version >= running().version || downgrade)
        && len as u32 >= MIN_IMAGE_LEN
        && len as u32 <= stored::capacity(SLOT);

    let mut updater = Updater::new();
    let mut slot = vec![0xFFu8; SLOT as usize];
    let mut now = Instant::from_micros(0);
    // Where the session stands as the model sees it: `None` without a session.
    let mut next: Option<usize> = None;
    let mut fail = false;
    // The CRC the last Commit carried: the image's, or any (the fuzzer's CMP-guided search finds
    // the CRC of a slot that a flipped chunk changed).
    let mut commit_crc = None;
    while !u.is_empty() {
        let message: Vec<u8> = match u.int_in_range(0u8..=8)? {
            0 => session::begin(&manifest).to_vec(),
            1 | 2 => {
                let at = next.unwrap_or(0);
                let n = usize::from(u.int_in_range(1u16..=(CHUNK as u16))?) / 8 * 8;
                let end = (at + n.max(8)).min(len);
                let mut message = session::chunk_head(at as u32).to_vec();
                message.extend_from_slice(image.get(at..end).unwrap_or(&[]));
                if u.arbitrary::<bool>()? && message.len() > 5 {
                    let i = 5 + usize::from(u.arbitrary::<u16>()?) % (message.len() - 5);
                    message[i] ^= 1 << u.int_in_range(0..=7)?;
                }
                message
            }
            3 => {
                let mut message = session::chunk_head(u.arbitrary()?).to_vec();
                let n = usize::from(u.int_in_range(0u16..=1100)?);
                message.extend(std::iter::repeat_n(u.arbitrary::<u8>()?, n));
                message
            }
            4 => {
                let crc = if u.arbitrary()? {
                    crc32(&image)
                } else {
                    u.arbitrary()?
                };
                commit_crc = Some(crc);
                session::commit(crc).to_vec()
            }
            5 => session::abort().to_vec(),
            6 => {
                let n = usize::from(u.int_in_range(0u8..=16)?);
                u.bytes(n)?.to_vec()
            }
            7 => {
                fail = !fail;
                continue;
            }
            _ => {
                now = now.wrapping_add_micros(u.int_in_range(0..=2 * SESSION_TIMEOUT_US)?);
                if updater.expire(now) {
                    next = None;
                }
                continue;
            }
        };
        let outcome = updater.on_message(&message, &running(), SLOT, now);
        let outcome = match outcome {
            Outcome::Write { offset, data } => {
                let at = offset as usize;
                assert_eq!(Some(at), next, "a write not where the session stood");
                assert!(at + data.len() <= stored::capacity(SLOT) as usize);
                assert!(data.len() <= CHUNK && (data.len() % 8 == 0 || at + data.len() == len));
                if fail {
                    updater.written(false)
                } else {
                    slot[at..at + data.len()].copy_from_slice(data);
                    updater.written(true)
                }
            }
            Outcome::Request {
                manifest: stored_manifest,
            } => {
                assert_eq!(stored_manifest, manifest);
                updater.requested(!fail)
            }
            other => other.detached().expect("only a Write borrows the message"),
        };
        match outcome {
            Outcome::Ready { chunk } => {
                assert!(admitted, "a Begin admitted that the rules refuse");
                assert_eq!(chunk as usize, CHUNK);
                next = Some(0);
            }
            Outcome::Refused(_) => {
                assert!(
                    !admitted || message.first() != Some(&1),
                    "a Begin refused that the rules admit"
                );
                next = None;
            }
            Outcome::Ack { offset, crc } => {
                assert!(next.is_some());
                assert_eq!(crc, crc32(&slot[..offset as usize]));
                next = Some(offset as usize);
            }
            Outcome::Committed { offset, crc } => {
                // The session commits exactly what the tool's CRC names: the slot's bytes, of the
                // Begin's length; a commit naming the image's CRC, exactly the image.
                assert_eq!(offset as usize, len);
                assert_eq!(
                    Some(crc),
                    commit_crc,
                    "a commit with another CRC than the tool's"
                );
                assert_eq!(
                    crc,
                    crc32(&slot[..len]),
                    "a commit of bytes the CRC does not name"
                );
                if crc == crc32(&image) {
                    assert_eq!(&slot[..len], &image[..], "a commit of another image");
                }
                next = None;
            }
            Outcome::FlashError { .. } | Outcome::Aborted => next = None,
            Outcome::NoSession => assert!(next.is_none() || updater.is_open()),
            _ => {}
        }
        assert_eq!(updater.is_open(), next.is_some());
    }
    Ok(())
}
