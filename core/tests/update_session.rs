//! A node's side of a firmware update (`pab_core::update::session`): a whole session written
//! to a slot, and every way a tool (or a participant posing as one) can get the order, the
//! lengths or the CRC wrong.

use pab_core::Instant;
use pab_core::crc32::crc32;
use pab_core::identity::Firmware;
use pab_core::update::session::{self, CHUNK, Outcome, SESSION_TIMEOUT_US, Updater};
use pab_core::update::stored::{self, Manifest};
use pab_core::update::{MANIFEST_LEN, Trailer, UpdateRefusal};
use proptest::prelude::*;

const SLOT: u32 = 16 * 1024;

fn running() -> Firmware {
    Firmware::new("fw-an386", "1.0.0", "00112233aabbccdd")
}

fn manifest(name: &str, version: &str, image_len: u32) -> [u8; MANIFEST_LEN] {
    Manifest {
        trailer: Trailer {
            firmware: Firmware::new(name, version, "99887766554433"),
            downgrade: false,
            image_len,
        },
        signature: [0x5A; 64],
    }
    .encode()
}

fn image(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 31 + 7) as u8).collect()
}

fn chunk(offset: u32, data: &[u8]) -> Vec<u8> {
    let mut out = session::chunk_head(offset).to_vec();
    out.extend_from_slice(data);
    out
}

/// A node: its updater and its slot, writing what it is asked to at once.
struct Node {
    updater: Updater,
    slot: Vec<u8>,
    writes: usize,
    fail_writes: bool,
    now: Instant,
}

impl Node {
    fn new() -> Node {
        Node {
            updater: Updater::new(),
            slot: vec![0xFF; SLOT as usize],
            writes: 0,
            fail_writes: false,
            now: Instant::from_micros(1_000),
        }
    }

    /// The answer the node sends for `message` (after any write it was asked for).
    fn send(&mut self, message: &[u8]) -> Outcome<'static> {
        let outcome = self.updater.on_message(message, &running(), SLOT, self.now);
        match outcome {
            Outcome::Write { offset, data } => {
                let at = offset as usize;
                assert!(
                    at + data.len() <= SLOT as usize - MANIFEST_LEN,
                    "a write into the manifest"
                );
                if self.fail_writes {
                    return self.updater.written(false);
                }
                self.slot[at..at + data.len()].copy_from_slice(data);
                self.writes += 1;
                self.updater.written(true)
            }
            Outcome::Request { manifest } => {
                let at = stored::manifest_offset(SLOT).unwrap() as usize;
                self.slot[at..].copy_from_slice(&manifest);
                self.updater.requested(!self.fail_writes)
            }
            other => other.detached().expect("only a Write borrows the message"),
        }
    }
}

#[test]
fn an_image_sent_in_chunks_lands_in_the_slot_with_its_manifest_and_is_committed() {
    let image = image(5000);
    let mut node = Node::new();
    let manifest = manifest("fw-an386", "1.1.0", image.len() as u32);
    assert_eq!(
        node.send(&session::begin(&manifest)),
        Outcome::Ready {
            chunk: CHUNK as u32
        }
    );
    let mut offset = 0;
    for data in image.chunks(CHUNK) {
        let next = offset + data.len();
        assert_eq!(
            node.send(&chunk(offset as u32, data)),
            Outcome::Ack {
                offset: next as u32,
                crc: crc32(&image[..next])
            }
        );
        offset = next;
    }
    assert_eq!(
        node.send(&session::commit(crc32(&image))),
        Outcome::Committed {
            offset: 5000,
            crc: crc32(&image)
        }
    );
    assert_eq!(&node.slot[..5000], &image[..]);
    assert!(
        node.slot[5000..SLOT as usize - MANIFEST_LEN]
            .iter()
            .all(|&b| b == 0xFF)
    );
    assert_eq!(&node.slot[SLOT as usize - MANIFEST_LEN..], &manifest[..]);
    assert!(!node.updater.is_open(), "the session ends with the commit");
}

#[test]
fn a_begin_whose_trailer_the_node_refuses_opens_no_session() {
    let mut node = Node::new();
    let refused = [
        (
            manifest("fw-g474", "1.1.0", 1000),
            UpdateRefusal::OtherBoard,
        ),
        (
            manifest("fw-an386", "0.9.0", 1000),
            UpdateRefusal::Downgrade,
        ),
        (
            manifest("fw-an386", "1.1.0", SLOT - 95),
            UpdateRefusal::TooLarge {
                len: SLOT - 95,
                capacity: SLOT - 96,
            },
        ),
        (manifest("fw-an386", "1.1.0", 4), UpdateRefusal::Truncated),
        ([0xFF; MANIFEST_LEN], UpdateRefusal::BadTrailer),
    ];
    for (manifest, refusal) in refused {
        assert_eq!(
            node.send(&session::begin(&manifest)),
            Outcome::Refused(refusal)
        );
        assert_eq!(node.send(&chunk(0, &[1; 8])), Outcome::NoSession);
        assert_eq!(node.send(&session::commit(0)), Outcome::NoSession);
    }
    // The largest image the slot takes is admitted.
    let largest = manifest("fw-an386", "1.0.0", SLOT - 96);
    assert_eq!(
        node.send(&session::begin(&largest)),
        Outcome::Ready {
            chunk: CHUNK as u32
        }
    );
    assert_eq!(node.writes, 0);
}

#[test]
fn chunks_out_of_order_are_answered_with_the_offset_expected_and_a_repeated_one_is_not_written_twice()
 {
    let image = image(3000);
    let mut node = Node::new();
    node.send(&session::begin(&manifest("fw-an386", "1.0.0", 3000)));
    let first = Outcome::Ack {
        offset: 1024,
        crc: crc32(&image[..1024]),
    };
    assert_eq!(node.send(&chunk(0, &image[..1024])), first);
    // Its answer was lost: the same chunk again is acknowledged again, not written.
    assert_eq!(node.send(&chunk(0, &image[..1024])), first);
    assert_eq!(node.writes, 1);
    let expected = Outcome::OutOfOrder {
        offset: 1024,
        crc: crc32(&image[..1024]),
    };
    // Ahead, behind, not a multiple of 8 before the end, past the end.
    assert_eq!(node.send(&chunk(2048, &image[2048..2056])), expected);
    assert_eq!(node.send(&chunk(8, &image[8..16])), expected);
    assert_eq!(node.send(&chunk(1024, &image[1024..1027])), expected);
    assert_eq!(node.send(&chunk(2048, &vec![0; 1000])), expected);
    // Too long for a chunk, empty, cut short: not a chunk at all.
    assert_eq!(
        node.send(&chunk(1024, &vec![0; CHUNK + 8])),
        Outcome::Malformed
    );
    assert_eq!(node.send(&chunk(1024, &[])), Outcome::Malformed);
    assert_eq!(node.send(&[2, 0, 4]), Outcome::Malformed);
    assert_eq!(node.writes, 1);
    // The last chunk may end anywhere.
    node.send(&chunk(1024, &image[1024..2048]));
    let last = node.send(&chunk(2048, &image[2048..]));
    assert_eq!(
        last,
        Outcome::Ack {
            offset: 3000,
            crc: crc32(&image)
        }
    );
}

#[test]
fn a_commit_early_or_with_another_crc_is_a_mismatch_and_the_session_goes_on() {
    let image = image(2048);
    let mut node = Node::new();
    node.send(&session::begin(&manifest("fw-an386", "1.0.0", 2048)));
    node.send(&chunk(0, &image[..1024]));
    let early = Outcome::Mismatch {
        offset: 1024,
        crc: crc32(&image[..1024]),
    };
    assert_eq!(node.send(&session::commit(crc32(&image))), early);
    node.send(&chunk(1024, &image[1024..]));
    let wrong = Outcome::Mismatch {
        offset: 2048,
        crc: crc32(&image),
    };
    assert_eq!(node.send(&session::commit(crc32(&image) ^ 1)), wrong);
    assert_eq!(
        node.send(&session::commit(crc32(&image))),
        Outcome::Committed {
            offset: 2048,
            crc: crc32(&image)
        }
    );
}

#[test]
fn a_failed_write_an_abort_and_silence_each_end_the_session() {
    let image = image(2048);
    let mut node = Node::new();
    let begin = session::begin(&manifest("fw-an386", "1.0.0", 2048));
    node.send(&begin);
    node.fail_writes = true;
    assert_eq!(
        node.send(&chunk(0, &image[..1024])),
        Outcome::FlashError { offset: 0 }
    );
    assert_eq!(node.send(&chunk(0, &image[..1024])), Outcome::NoSession);
    node.fail_writes = false;

    node.send(&begin);
    assert_eq!(node.send(&session::abort()), Outcome::Aborted);
    assert_eq!(node.send(&chunk(0, &image[..1024])), Outcome::NoSession);

    node.send(&begin);
    node.send(&chunk(0, &image[..1024]));
    let deadline = node.updater.deadline().unwrap();
    assert_eq!(deadline, node.now.wrapping_add_micros(SESSION_TIMEOUT_US));
    assert!(
        !node
            .updater
            .expire(Instant::from_micros(deadline.as_micros() - 1))
    );
    assert!(node.updater.expire(deadline));
    assert_eq!(node.send(&chunk(1024, &image[1024..])), Outcome::NoSession);

    // A storing of the request that fails: no commit.
    node.send(&begin);
    node.send(&chunk(0, &image[..1024]));
    node.send(&chunk(1024, &image[1024..]));
    node.fail_writes = true;
    assert_eq!(
        node.send(&session::commit(crc32(&image))),
        Outcome::FlashError { offset: 2048 }
    );
    assert!(!node.updater.is_open());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Whatever a tool sends (messages of every kind, offsets and lengths anywhere, Begins
    /// between), a commit happens only for a slot that holds, at every offset the session wrote,
    /// the bytes of one image whose CRC the commit named, written in order from 0.
    #[test]
    fn only_a_complete_image_written_in_order_is_ever_committed(
        len in 8usize..4000,
        steps in proptest::collection::vec((0u8..6, any::<u16>(), 0usize..1100, any::<bool>()), 1..120),
    ) {
        let image = image(len);
        let mut node = Node::new();
        let begin = session::begin(&manifest("fw-an386", "1.0.0", len as u32));
        let mut written_from_zero = 0usize;
        for (kind, offset, n, honest) in steps {
            let outcome = match kind {
                0 => { written_from_zero = 0; node.send(&begin) }
                1 | 2 => {
                    // The next chunk as a tool would send it; the same with a byte changed (a
                    // participant posing as the tool); or one anywhere with any bytes.
                    let end = (written_from_zero + CHUNK.min(n.max(8) / 8 * 8)).min(len);
                    let (at, data) = match (kind, honest) {
                        (1, true) => (written_from_zero, image[written_from_zero..end].to_vec()),
                        (1, false) => {
                            let mut data = image[written_from_zero..end].to_vec();
                            if let Some(byte) = data.get_mut(n % 8) {
                                *byte ^= 0x40;
                            }
                            (written_from_zero, data)
                        }
                        _ => (usize::from(offset), vec![offset as u8; n]),
                    };
                    node.send(&chunk(at as u32, &data))
                }
                3 => node.send(&session::commit(if honest { crc32(&image) } else { u32::from(offset) })),
                4 => node.send(&session::abort()),
                _ => node.send(&vec![offset as u8; n % 8]),
            };
            match outcome {
                Outcome::Ack { offset, crc } => {
                    written_from_zero = offset as usize;
                    prop_assert_eq!(crc, crc32(&node.slot[..offset as usize]));
                }
                Outcome::Committed { offset, crc } => {
                    prop_assert_eq!(offset as usize, len);
                    prop_assert_eq!(&node.slot[..len], &image[..]);
                    prop_assert_eq!(crc, crc32(&image));
                }
                _ => {}
            }
        }
    }
}
