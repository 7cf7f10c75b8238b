//! A node's firmware update through the node itself (`pab_app::Node` with the `update` feature,
//! board capacities): UpdateTransfer frames from the bus, whole update messages through pab-core's
//! ISO-TP sender (obeying the node's flow control) from the tool or from another node, arbitrary
//! frames of any service, times that jump and go backwards, writes of the update slot that fail.
//! The runner's side is the check's: it writes the chunks the node asks for into a slot and
//! stores the manifest it asks for, as `pab_app::run` does.
//!
//! Properties, checked after every step:
//!
//! - **A write lands where the session stands**: every chunk the node asks to write is inside
//!   the slot's image area, at the offset the node last acknowledged to the tool (0 after a
//!   Ready), and no longer than a chunk.
//! - **A commit only for a whole image**: the node asks to store a manifest and restart only
//!   when the bytes it wrote since the last Ready, in order from 0, are as long as that Begin's
//!   trailer says and are what the slot holds, and the manifest is that Begin's; a session the
//!   tool ran honestly commits exactly the image it sent.
//! - **Only the tool updates**: messages from another source never make the node write.
//! - **Everything the node sends decodes**, comes from its id, and its update answers go to
//!   the tool.

use arbitrary::{Result, Unstructured};
use pab_app::{Config, Firmware, Node, Recipient, Step};
use pab_core::crc32::crc32;
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, Message, UpdateStatusCode};
use pab_core::update::session::{self, CHUNK};
use pab_core::update::stored::{self, Manifest};
use pab_core::update::{MANIFEST_LEN, Trailer};
use pab_core::{BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, Frame, Instant};

use crate::isotp_rx::next_time;

type TestNode = Node<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES, 8192>;

const NODE_ID: u8 = 5;
const SLOT: u32 = 8 * 1024;

fn running() -> Firmware {
    Firmware::new("fw-an386", "1.2.0", "0011223344556677")
}

struct Nobody;

impl Recipient for Nobody {
    fn deliver(&mut self, _port: u8, _frame: &Frame, _now: Instant) {}
}

struct World {
    node: TestNode,
    now: u64,
    slot: Vec<u8>,
    write_ok: bool,
    /// The manifest of the last Begin the node answered Ready, and the bytes it wrote since,
    /// in order from 0.
    session: Option<([u8; MANIFEST_LEN], Vec<u8>)>,
    /// Whether the session is the tool's honest one for `image` (no chunk changed).
    honest: bool,
    image: Vec<u8>,
    /// The offset the node last acknowledged to the tool (`None` without a session).
    acked: Option<u32>,
    /// Frames the node sent and the check has read.
    seen: usize,
    sent: Vec<Frame>,
    /// Whether the message being pushed comes from the tool.
    from_tool: bool,
    /// The message being pushed (a Begin's manifest is read from it when the Ready comes).
    pushing: Vec<u8>,
    /// Whether that message is the tool's honest Begin or chunk for `image`.
    pushing_honest: bool,
}

impl World {
    fn at(&self) -> Instant {
        Instant::from_micros(self.now)
    }

    /// A step's Step, as the runner handles it, with the properties of the writes.
    fn runner(&mut self, step: Step) {
        match step {
            Step::WriteUpdate => {
                assert!(
                    self.from_tool,
                    "a write asked by a message not from the tool"
                );
                let (offset, data) = self.node.update_chunk().expect("a chunk owed");
                assert_eq!(
                    Some(offset),
                    self.acked,
                    "a write not where the session stands"
                );
                assert!(data.len() <= CHUNK);
                let end = offset as usize + data.len();
                assert!(
                    end <= stored::capacity(SLOT) as usize,
                    "a write into the manifest"
                );
                let (_, written) = self.session.as_mut().expect("a write without a session");
                assert_eq!(written.len(), offset as usize);
                if self.write_ok {
                    self.slot[offset as usize..end].copy_from_slice(data);
                    written.extend_from_slice(data);
                }
                if !self.pushing_honest {
                    self.honest = false;
                }
                let ok = self.write_ok;
                self.node.update_written(ok);
            }
            Step::RequestUpdate => {
                assert!(
                    self.from_tool,
                    "a commit asked by a message not from the tool"
                );
                let manifest = *self.node.update_manifest().expect("a manifest owed");
                let (admitted, written) = self.session.clone().expect("a commit without a Ready");
                assert_eq!(manifest, admitted, "a commit of another manifest");
                let trailer = Manifest::decode(&manifest)
                    .expect("an admitted manifest")
                    .trailer;
                assert_eq!(
                    written.len(),
                    trailer.image_len as usize,
                    "a commit of a part"
                );
                assert_eq!(&self.slot[..written.len()], &written[..]);
                if self.honest {
                    assert_eq!(
                        written, self.image,
                        "an honest session committed another image"
                    );
                }
                let ok = self.write_ok;
                let _ = self.node.update_requested(ok);
            }
            _ => {}
        }
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(frame) = self.node.next_outgoing() {
            self.sent.push(frame);
        }
        while self.seen < self.sent.len() {
            let frame = self.sent[self.seen];
            self.seen += 1;
            let (id, message) = Message::decode(&frame).expect("everything the node sends decodes");
            assert_eq!(id.source, NODE_ID);
            if let Message::UpdateStatus(status) = message {
                assert_eq!(
                    id.destination,
                    protocol::TOOL,
                    "an update answer not to the tool"
                );
                match status.status {
                    UpdateStatusCode::Ready => {
                        let manifest = self
                            .pushing
                            .get(1..)
                            .and_then(|bytes| <[u8; MANIFEST_LEN]>::try_from(bytes).ok())
                            .filter(|_| self.pushing.first() == Some(&1) && self.from_tool)
                            .expect("a Ready for the tool's Begin");
                        self.session = Some((manifest, Vec::new()));
                        self.honest = self.pushing_honest;
                        self.acked = Some(0);
                    }
                    UpdateStatusCode::Ack => {
                        let (_, written) = self.session.as_ref().expect("an Ack without a session");
                        assert_eq!(status.offset as usize, written.len());
                        assert_eq!(status.value, crc32(written));
                        self.acked = Some(status.offset);
                    }
                    UpdateStatusCode::Refused
                    | UpdateStatusCode::FlashError
                    | UpdateStatusCode::Committed
                    | UpdateStatusCode::NoSession => {
                        self.acked = None;
                        self.session = None;
                    }
                    _ => {}
                }
            }
        }
    }

    fn feed(&mut self, frame: &Frame) {
        let step = self.node.on_frame(frame, self.at(), &mut Nobody);
        self.runner(step);
    }

    fn poll(&mut self) {
        let step = self.node.poll(self.at(), &mut Nobody);
        self.runner(step);
    }

    /// Pushes `message` from `source` with pab-core's ISO-TP sender, following the node's flow
    /// control, one frame per 100 µs.
    fn push(&mut self, message: &[u8], source: u8, honest: bool) {
        self.from_tool = source == protocol::TOOL;
        self.pushing = message.to_vec();
        self.pushing_honest = honest;
        let Ok(mut sender) = Sender::new(message, TxConfig::default()) else {
            return;
        };
        let mut read = self.sent.len();
        for _ in 0..2000 {
            match sender.poll(self.at()) {
                TxEvent::Send(data) => {
                    let frame = Message::UpdateTransfer { data, len: 8 }.to_frame(source, NODE_ID);
                    self.feed(&frame);
                    self.now = self.now.wrapping_add(100);
                }
                TxEvent::WaitUntil(until) => {
                    let mut delivered = false;
                    while read < self.sent.len() {
                        let frame = self.sent[read];
                        read += 1;
                        if let Ok((id, Message::UpdateTransfer { data, len })) =
                            Message::decode(&frame)
                            && id.destination == source
                        {
                            sender.on_flow_control(&data[..len as usize], self.at());
                            delivered = true;
                        }
                    }
                    if !delivered {
                        self.now = until.as_micros().max(self.now.wrapping_add(1));
                        self.poll();
                    }
                }
                TxEvent::Done | TxEvent::Failed(_) => break,
            }
        }
        self.from_tool = true;
        self.pushing.clear();
        self.pushing_honest = false;
    }
}

pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data));
}

fn run(u: &mut Unstructured<'_>) -> Result<()> {
    let len = usize::from(u.int_in_range(0u16..=(SLOT as u16))?);
    let seed: u8 = u.arbitrary()?;
    let image: Vec<u8> = (0..len)
        .map(|i| (i as u8).wrapping_mul(seed) ^ 0x5A)
        .collect();
    let manifest = |u: &mut Unstructured<'_>, len: usize| -> Result<[u8; MANIFEST_LEN]> {
        Ok(Manifest {
            trailer: Trailer {
                firmware: Firmware {
                    name: if u.arbitrary()? {
                        running().name
                    } else {
                        *b"fw-g474\0"
                    },
                    version: [1, u.int_in_range(1..=3)?, 0],
                    build: [3; 8],
                },
                downgrade: u.arbitrary()?,
                image_len: len as u32,
            },
            signature: [0x11; 64],
        }
        .encode())
    };
    let mut node = TestNode::new(
        Config::new(NODE_ID).expect("a valid id"),
        Instant::from_micros(0),
    );
    node.set_identity(running(), [7; 12]);
    node.set_update_slot(SLOT);
    node.boot(None, Instant::from_micros(0));
    let mut world = World {
        node,
        now: 0,
        slot: vec![0xFF; SLOT as usize],
        write_ok: true,
        session: None,
        honest: false,
        image: image.clone(),
        acked: None,
        seen: 0,
        sent: Vec::new(),
        from_tool: true,
        pushing: Vec::new(),
        pushing_honest: false,
    };
    world.drain();
    while !u.is_empty() {
        match u.int_in_range(0u8..=9)? {
            0 => {
                let manifest = manifest(u, len)?;
                world.push(&session::begin(&manifest), protocol::TOOL, true);
            }
            1 | 2 => {
                // The next chunk as the tool sends it, or with a byte changed.
                let at = world.acked.unwrap_or(0) as usize;
                let n = usize::from(u.int_in_range(1u16..=(CHUNK as u16))?) / 8 * 8;
                let end = (at + n.max(8)).min(len);
                let mut message = session::chunk_head(at as u32).to_vec();
                message.extend_from_slice(image.get(at..end).unwrap_or(&[]));
                let corrupt = u.arbitrary::<bool>()? && message.len() > 5;
                if corrupt {
                    let i = 5 + usize::from(u.arbitrary::<u16>()?) % (message.len() - 5);
                    message[i] ^= 0x80;
                }
                world.push(&message, protocol::TOOL, !corrupt);
            }
            3 => {
                let claimed = if u.arbitrary()? {
                    crc32(&image)
                } else {
                    u.arbitrary()?
                };
                world.push(&session::commit(claimed), protocol::TOOL, false);
            }
            4 => world.push(&session::abort(), protocol::TOOL, false),
            5 => {
                // A message of any bytes, from the tool or another node.
                let n = usize::from(u.int_in_range(0u16..=1100)?);
                let message = u.bytes(n.min(u.len()))?.to_vec();
                let source = if u.arbitrary()? {
                    protocol::TOOL
                } else {
                    u.int_in_range(1..=127)?
                };
                world.push(&message, source, false);
            }
            6 => {
                // A Begin, a chunk or a commit from another node: refused, never written.
                let source = u.int_in_range(1..=127)?;
                let message = match u.int_in_range(0..=2)? {
                    0 => session::begin(&manifest(u, len)?).to_vec(),
                    1 => {
                        let mut chunk = session::chunk_head(0).to_vec();
                        chunk.extend_from_slice(image.get(..len.min(64)).unwrap_or(&[]));
                        chunk
                    }
                    _ => session::commit(crc32(&image)).to_vec(),
                };
                world.push(&message, source, false);
            }
            7 => {
                // A single frame of any service or bytes, from anyone.
                let id: u32 = u.arbitrary()?;
                let n = u.int_in_range(0..=8)?;
                let data = u.bytes(n)?;
                world.from_tool = false;
                if let Some(frame) = embedded_can::ExtendedId::new(id & 0x1FFF_FFFF)
                    .and_then(|id| Frame::data(embedded_can::Id::Extended(id), data))
                {
                    // Not the tool's UpdateTransfer frames: a message the tool sends is pushed
                    // whole (above), so that the check knows what it was.
                    let tools_update = protocol::FrameId::decode(&frame.id()).is_some_and(|id| {
                        id.source == protocol::TOOL
                            && id.service == protocol::Service::UpdateTransfer
                    });
                    if !tools_update {
                        world.feed(&frame);
                    }
                }
                world.from_tool = true;
            }
            8 => world.write_ok = !world.write_ok,
            _ => {
                world.now = next_time(u, world.now)?;
                world.poll();
            }
        }
    }
    Ok(())
}
