//! A node's side of a firmware update: the messages the tool sends over ISO-TP (service
//! UpdateTransfer, docs/can-protocol.md), judged one at a time, sans I/O. The node writes what
//! [`Outcome::Write`] asks into its update partition and says how it went ([`Updater::written`]);
//! it stores the manifest and the request when [`Outcome::Request`] asks, and says how that went
//! ([`Updater::requested`]); it sends each outcome's answer (UpdateStatus).
//!
//! ```text
//! Begin   1, the manifest (trailer ‖ signature, 96 bytes)         97 bytes
//! Chunk   2, offset (u32 LE), 1 to CHUNK bytes of the image        6 to 1029 bytes
//! Commit  3, CRC-32 of the whole image (u32 LE)                    5 bytes
//! Abort   4                                                        1 byte
//! ```
//!
//! **Why chunks with offsets**, each answered with the next offset and the running CRC: a
//! classic ISO-TP message holds at most 4 095 bytes, an image up to 64 KiB; a chunk lost or
//! refused is sent again from the offset the node names, not the whole image. A chunk of
//! [`CHUNK`] bytes divides every board's erase page (2 KiB on the G474, 4 KiB on the emulated
//! board), so that a page is erased when a chunk starts it, and fits the node's transfer buffer.
//!
//! **Order**: chunks come in order, each a multiple of 8 bytes but the last (the G474 programs
//! double words), and the chunk just acknowledged may come again (its answer was lost): it is
//! acknowledged again and not written twice. Anything else is answered with the offset
//! expected.
//!
//! **What is checked here**: the trailer, before a byte of the image is taken ([`Trailer::admits`]:
//! board kind, version, length); the image's CRC at the commit. The signature is the bootloader's
//! ([`super::stored`]).

use super::stored::{self, Manifest};
use super::{MANIFEST_LEN, Trailer, UpdateRefusal};
use crate::crc32::Crc32;
use crate::identity::Firmware;
use crate::time::Instant;

/// The most image bytes a Chunk carries.
pub const CHUNK: usize = 1024;
/// The longest message: a Chunk's kind, offset and [`CHUNK`] bytes (a node's receive buffer).
pub const MESSAGE_MAX: usize = 1 + 4 + CHUNK;
/// A Begin's length: what a TransferOpen for an update announces on a keyed node.
pub const BEGIN_LEN: usize = 1 + MANIFEST_LEN;
/// A session ends when no message came for this long, µs (the tool's chunks come every few
/// milliseconds; a tool that went away must not hold the node's update partition).
pub const SESSION_TIMEOUT_US: u64 = 5_000_000;

const BEGIN: u8 = 1;
const CHUNK_KIND: u8 = 2;
const COMMIT: u8 = 3;
const ABORT: u8 = 4;

/// What a message, or the outcome of a write the node made, comes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome<'a> {
    /// A Begin was admitted: chunks may come from offset 0, of up to `chunk` bytes.
    Ready {
        /// The most image bytes a chunk may carry.
        chunk: u32,
    },
    /// Write `data` at `offset` of the update partition, then call [`Updater::written`].
    Write {
        /// Where in the image.
        offset: u32,
        /// The bytes (within the message that was passed).
        data: &'a [u8],
    },
    /// A chunk is in the partition: the next one at `offset`; `crc` is the CRC-32 of the image
    /// bytes before it.
    Ack {
        /// The next image byte expected.
        offset: u32,
        /// CRC-32 of the bytes before it.
        crc: u32,
    },
    /// The image is complete and its CRC matches: store `manifest` at the slot's end and the
    /// request record ([`stored`]), then call [`Updater::requested`].
    Request {
        /// The trailer and signature, as the bootloader reads them.
        manifest: [u8; MANIFEST_LEN],
    },
    /// The manifest and the request are stored: the node restarts into its bootloader.
    Committed {
        /// The image's length.
        offset: u32,
        /// Its CRC-32.
        crc: u32,
    },
    /// The image is refused: the session is over.
    Refused(UpdateRefusal),
    /// A chunk not at `offset`, the one expected (`crc`: the running CRC).
    OutOfOrder {
        /// The next image byte expected.
        offset: u32,
        /// CRC-32 of the bytes before it.
        crc: u32,
    },
    /// A Commit before the image is complete, or with another CRC (`offset`, `crc`: what the
    /// node has). The session goes on: the tool may send what is missing, or begin again.
    Mismatch {
        /// The next image byte expected.
        offset: u32,
        /// CRC-32 of the bytes before it.
        crc: u32,
    },
    /// The update partition could not be written at `offset`: the session is over.
    FlashError {
        /// Where the write failed.
        offset: u32,
    },
    /// A Chunk or Commit without a session (none began, or it ended).
    NoSession,
    /// None of the four messages, or one of the wrong length: ignored, and the session goes on.
    Malformed,
    /// The tool ended the session (Abort).
    Aborted,
}

impl Outcome<'_> {
    /// The outcome without the message it borrowed from, to answer after the message's buffer
    /// is in use again: `None` for a [`Outcome::Write`], whose bytes are the message's; every
    /// other outcome owns what it carries and comes back as it is. A copy of at most 97 bytes.
    pub fn detached(self) -> Option<Outcome<'static>> {
        Some(match self {
            Outcome::Write { .. } => return None,
            Outcome::Ready { chunk } => Outcome::Ready { chunk },
            Outcome::Ack { offset, crc } => Outcome::Ack { offset, crc },
            Outcome::Request { manifest } => Outcome::Request { manifest },
            Outcome::Committed { offset, crc } => Outcome::Committed { offset, crc },
            Outcome::Refused(refusal) => Outcome::Refused(refusal),
            Outcome::OutOfOrder { offset, crc } => Outcome::OutOfOrder { offset, crc },
            Outcome::Mismatch { offset, crc } => Outcome::Mismatch { offset, crc },
            Outcome::FlashError { offset } => Outcome::FlashError { offset },
            Outcome::NoSession => Outcome::NoSession,
            Outcome::Malformed => Outcome::Malformed,
            Outcome::Aborted => Outcome::Aborted,
        })
    }
}

/// A write the node was asked for and has not reported yet.
#[derive(Clone, Copy, Debug)]
enum Pending {
    Nothing,
    /// A chunk: its offset, its length, the CRC once it is in.
    Chunk {
        offset: u32,
        len: u32,
        crc: Crc32,
    },
    /// The manifest and the request.
    Request,
}

#[derive(Clone, Copy, Debug)]
struct Session {
    manifest: Manifest,
    /// The next image byte expected, and the CRC of those before it.
    next: u32,
    crc: Crc32,
    /// The last chunk acknowledged: its offset and length (0, 0 before the first).
    last: (u32, u32),
    pending: Pending,
    expires: Instant,
}

/// The update session of a node: at most one at a time. It holds the manifest and where the
/// image stands, never the image: about 150 bytes.
#[derive(Debug, Default)]
pub struct Updater {
    session: Option<Session>,
}

impl Updater {
    /// No session.
    pub const fn new() -> Self {
        Updater { session: None }
    }

    /// Whether a session is open.
    pub fn is_open(&self) -> bool {
        self.session.is_some()
    }

    /// When the open session ends unless a message comes ([`Updater::expire`]).
    pub fn deadline(&self) -> Option<Instant> {
        self.session.map(|session| session.expires)
    }

    /// Ends the session if it has had no message by `now`; whether it did.
    pub fn expire(&mut self, now: Instant) -> bool {
        let expired = self
            .session
            .is_some_and(|session| now.micros_since(session.expires).is_some());
        if expired {
            self.session = None;
        }
        expired
    }

    /// Ends the session, whatever it was doing.
    pub fn abort(&mut self) {
        self.session = None;
    }

    /// Judges one message for a node running `running` whose update slot is `slot_len` bytes
    /// (the image and its manifest: [`stored::capacity`]). A message while a write is pending
    /// (the node has not called back) is answered [`Outcome::Malformed`]; a node that writes
    /// synchronously never sees it.
    pub fn on_message<'a>(
        &mut self,
        message: &'a [u8],
        running: &Firmware,
        slot_len: u32,
        now: Instant,
    ) -> Outcome<'a> {
        let Some((&kind, body)) = message.split_first() else {
            return Outcome::Malformed;
        };
        if let Some(session) = &self.session
            && !matches!(session.pending, Pending::Nothing)
        {
            return Outcome::Malformed;
        }
        match kind {
            BEGIN => self.begin(body, running, slot_len, now),
            CHUNK_KIND => self.chunk(body, now),
            COMMIT => self.commit(body, now),
            ABORT if body.is_empty() => {
                self.session = None;
                Outcome::Aborted
            }
            _ => Outcome::Malformed,
        }
    }

    fn begin(
        &mut self,
        body: &[u8],
        running: &Firmware,
        slot_len: u32,
        now: Instant,
    ) -> Outcome<'static> {
        let Ok(bytes) = <&[u8; MANIFEST_LEN]>::try_from(body) else {
            return Outcome::Malformed;
        };
        // A Begin replaces a session in progress: the tool started again.
        self.session = None;
        let manifest = match Manifest::decode(bytes) {
            Ok(manifest) => manifest,
            Err(refusal) => return Outcome::Refused(refusal),
        };
        if let Err(refusal) = manifest.trailer.admits(running, stored::capacity(slot_len)) {
            return Outcome::Refused(refusal);
        }
        self.session = Some(Session {
            manifest,
            next: 0,
            crc: Crc32::new(),
            last: (0, 0),
            pending: Pending::Nothing,
            expires: now.wrapping_add_micros(SESSION_TIMEOUT_US),
        });
        Outcome::Ready {
            chunk: CHUNK as u32,
        }
    }

    fn chunk<'a>(&mut self, body: &'a [u8], now: Instant) -> Outcome<'a> {
        let Some((offset, data)) = body.split_first_chunk::<4>() else {
            return Outcome::Malformed;
        };
        let offset = u32::from_le_bytes(*offset);
        let Some(session) = self.session.as_mut() else {
            return Outcome::NoSession;
        };
        session.expires = now.wrapping_add_micros(SESSION_TIMEOUT_US);
        // Within CHUNK, so that it fits u32 and every board's erase page.
        let Some(len) = u32::try_from(data.len())
            .ok()
            .filter(|_| data.len() <= CHUNK)
        else {
            return Outcome::Malformed;
        };
        if data.is_empty() {
            return Outcome::Malformed;
        }
        let (next, crc) = (session.next, session.crc.finish());
        // The chunk just acknowledged, again: its answer was lost.
        if (offset, len) == session.last && len > 0 {
            return Outcome::Ack { offset: next, crc };
        }
        let image_len = session.manifest.trailer.image_len;
        let end = offset.checked_add(len);
        let ends_image = end == Some(image_len);
        let in_order = offset == next
            && end.is_some_and(|end| end <= image_len)
            && (len % 8 == 0 || ends_image);
        if !in_order {
            return Outcome::OutOfOrder { offset: next, crc };
        }
        session.pending = Pending::Chunk {
            offset,
            len,
            crc: session.crc.update(data),
        };
        Outcome::Write { offset, data }
    }

    fn commit(&mut self, body: &[u8], now: Instant) -> Outcome<'static> {
        let Ok(claimed) = <[u8; 4]>::try_from(body) else {
            return Outcome::Malformed;
        };
        let Some(session) = self.session.as_mut() else {
            return Outcome::NoSession;
        };
        session.expires = now.wrapping_add_micros(SESSION_TIMEOUT_US);
        let (offset, crc) = (session.next, session.crc.finish());
        if offset != session.manifest.trailer.image_len || crc != u32::from_le_bytes(claimed) {
            return Outcome::Mismatch { offset, crc };
        }
        session.pending = Pending::Request;
        Outcome::Request {
            manifest: session.manifest.encode(),
        }
    }

    /// How the write of the last [`Outcome::Write`] went: [`Outcome::Ack`], or
    /// [`Outcome::FlashError`] (the session is over). Without a write pending,
    /// [`Outcome::NoSession`].
    pub fn written(&mut self, ok: bool) -> Outcome<'static> {
        let Some(session) = self.session.as_mut() else {
            return Outcome::NoSession;
        };
        let Pending::Chunk { offset, len, crc } = session.pending else {
            return Outcome::NoSession;
        };
        session.pending = Pending::Nothing;
        if !ok {
            self.session = None;
            return Outcome::FlashError { offset };
        }
        // offset + len ≤ image_len was checked when the chunk came.
        session.next = offset.saturating_add(len);
        session.crc = crc;
        session.last = (offset, len);
        Outcome::Ack {
            offset: session.next,
            crc: crc.finish(),
        }
    }

    /// How storing the manifest and the request went: [`Outcome::Committed`] (the node
    /// restarts into its bootloader once the answer is out), or [`Outcome::FlashError`]. The
    /// session is over either way.
    pub fn requested(&mut self, ok: bool) -> Outcome<'static> {
        let Some(session) = self.session.take() else {
            return Outcome::NoSession;
        };
        if !matches!(session.pending, Pending::Request) {
            self.session = Some(session);
            return Outcome::NoSession;
        }
        let trailer: Trailer = session.manifest.trailer;
        if ok {
            Outcome::Committed {
                offset: trailer.image_len,
                crc: session.crc.finish(),
            }
        } else {
            Outcome::FlashError {
                offset: trailer.image_len,
            }
        }
    }
}

/// The messages as the tool builds them (`pabctl flash`; tests and the fuzz target): Begin.
pub fn begin(manifest: &[u8; MANIFEST_LEN]) -> [u8; 1 + MANIFEST_LEN] {
    let mut out = [BEGIN; 1 + MANIFEST_LEN];
    if let Some(rest) = out.get_mut(1..) {
        rest.copy_from_slice(manifest);
    }
    out
}

/// A Chunk's first five bytes (kind and offset); the image's bytes follow.
pub fn chunk_head(offset: u32) -> [u8; 5] {
    let [a, b, c, d] = offset.to_le_bytes();
    [CHUNK_KIND, a, b, c, d]
}

/// A Commit.
pub fn commit(crc: u32) -> [u8; 5] {
    let [a, b, c, d] = crc.to_le_bytes();
    [COMMIT, a, b, c, d]
}

/// An Abort.
pub const fn abort() -> [u8; 1] {
    [ABORT]
}
