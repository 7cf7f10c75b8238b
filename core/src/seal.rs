//! Sealed coordination: on a keyed network, the frames nodes coordinate with (Gates, BLE claims,
//! HBBA's filter commands) are applied only when the sender's **seal** verifies, in the manner of
//! AUTOSAR SecOC (payload + freshness + truncated MAC). `docs/can-protocol.md` ("Sealed
//! coordination") is the reference; this is its one implementation, run by the nodes
//! (`pab-app`) and the intention node (`pab-intent`).
//!
//! # Decisions
//!
//! - **A companion frame.** A classic frame has no room for a MAC and a freshness value (Gates
//!   fill all 8 bytes), so each coordination frame is followed by a [`Seal`] from the same
//!   sender: the low 16 bits of its freshness counter and the first 4 bytes of a CMAC over the
//!   sealed frame's identifier, length and payload and the full freshness. The seal's priority
//!   (5) ranks it after every frame it seals, so a sender's queue and controller, which send in
//!   identifier order, never put it first.
//! - **Freshness per sender**: (epoch << 32 | counter), the epoch the sender's boot salt (which
//!   never repeats for one key), the counter counting its seals since boot. A receiver accepts a
//!   seal only above the last it accepted from that sender: a replayed frame's seal was computed
//!   over an older counter and does not verify for any counter above it.
//! - **Synchronised by a challenge.** A receiver that does not know a sender's epoch (at its
//!   first seal, after either restarts) asks it with a [`Message::FreshnessRequest`] carrying a
//!   nonce nobody can predict without the key; the sender answers with [`Message::Freshness`]
//!   (its epoch and last counter) sealed over that nonce, so a recorded answer is worthless. The
//!   frames before the answer are refused (`Unsynced`): a receiver never guesses.
//! - **Deny, never steer.** A participant without the key can keep frames from being applied
//!   (forged frames that push the sender's out of the hold, seals that fail, a flood), never get
//!   a frame of its own applied but for a 4-byte tag guessed at one chance in 2^32 per try.
//!
//! # Cost
//!
//! One CMAC of two AES blocks (a 23-byte input) per seal made and per seal checked: about
//! 12 000 Cortex-M4 instructions on the boards (`scripts/cortex-m4-cost.sh`, case `auth`,
//! classes `seal-make` and `seal-check`). A held frame or a seal matches by a walk of at most
//! [`HELD`] entries, a sender by one of [`PEERS`]. Memory: a [`Verifier`] is about 500 bytes.

use crate::Instant;
use crate::auth::Authenticator;
use crate::frame::Frame;
use crate::protocol::{self, AuthFailure, FrameKind, Message, Seal, Service};

/// Senders a receiver keeps the freshness of: a node reads the Gates of a few groups, the
/// claims of its BLE peers and the intention node's commands. Beyond, the first kept is
/// forgotten (and asked again at its next seal), unless it was asked within [`REQUEST_US`]: then
/// a new sender's seal is refused without a request, until that request ages out. Forgetting
/// a sender asked a moment ago would let it be asked again at once: a participant that filled the
/// list with forged senders could make a genuine one answer at will (found by the fuzz target
/// `seal`).
pub const PEERS: usize = 8;
/// Coordination frames held for their seal at once (every sender together); beyond, the oldest
/// is refused `Unsealed`.
pub const HELD: usize = 8;
/// How long a coordination frame waits for its seal. A seal follows its frame within a few
/// frame times on a working bus; a frame older than this leaves the hold at the next frame held
/// (refused `Unsealed` if no seal was tried on it).
pub const HOLD_US: u64 = 500_000;
/// Held frames a seal is tried on, at most: a sender's in-flight frames of one kind and digest
/// (two frames sent before the first's seal left), or a participant's frame of the same digest
/// held before the sender's. Bounds the CMACs a seal can cost.
pub const TRIES: usize = 2;
/// How long a freshness request waits for its answer, and the least time between two requests
/// to one sender (a participant that makes seals fail costs each sender at most one answer a
/// second per receiver).
pub const REQUEST_US: u64 = 1_000_000;

/// What a seal follows: the sealed frame's kind (its service code, or [`Seal::CLAIM`]) and the
/// seal's destination (the frame's; a claim's is every node). `None` for a frame nothing seals.
pub fn sealed_kind(frame: &Frame) -> Option<(u8, u8)> {
    match protocol::classify(frame) {
        FrameKind::Claim => Some((Seal::CLAIM, protocol::BROADCAST)),
        FrameKind::Service(id) if Seal::is_sealable(id.service.code()) => {
            Some((id.service.code(), id.destination))
        }
        _ => None,
    }
}

/// The freshness value of `counter` in `epoch`.
const fn freshness(epoch: u32, counter: u32) -> u64 {
    (epoch as u64) << 32 | counter as u64
}

/// The seal of `frame` from `sender` over `freshness`, as a frame to `destination`.
fn seal_frame(
    authenticator: &Authenticator,
    sender: u8,
    frame: &Frame,
    (kind, destination): (u8, u8),
    counter: u16,
    freshness: u64,
) -> Option<Frame> {
    let (raw, _) = frame.raw_id();
    let payload = frame.payload();
    let seal = Seal {
        kind,
        digest: Seal::digest_of(payload),
        counter,
        tag: authenticator.seal_tag(sender, raw, payload, freshness),
    };
    Message::Seal(seal).report_frame(sender, destination)
}

/// A sender's side: its epoch and the counter of what it sealed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sealer {
    epoch: u32,
    counter: u32,
}

impl Sealer {
    /// A sender in `epoch`: its boot salt, which must never repeat for one key (boards: their
    /// boot count; hosts: random bits from the operating system).
    pub const fn new(epoch: u32) -> Sealer {
        Sealer { epoch, counter: 0 }
    }

    /// The epoch.
    pub const fn epoch(&self) -> u32 {
        self.epoch
    }

    /// The last counter used (0 before the first seal).
    pub const fn counter(&self) -> u32 {
        self.counter
    }

    /// Takes the next counter; `None` once all 2^32 - 1 are used (then nothing is sealed until
    /// the sender restarts in a new epoch: its frames are refused, never accepted twice).
    fn next(&mut self) -> Option<u32> {
        self.counter = self.counter.checked_add(1)?;
        Some(self.counter)
    }

    /// The seal to send right after `frame` from `sender`: `None` for a frame nothing seals, and
    /// once the counter is exhausted. One CMAC. (A node, which knows what it sends, calls
    /// [`Sealer::seal_as`] and skips the frame's classification.)
    pub fn seal(
        &mut self,
        authenticator: &Authenticator,
        sender: u8,
        frame: &Frame,
    ) -> Option<Frame> {
        let (kind, destination) = sealed_kind(frame)?;
        self.seal_as(authenticator, sender, frame, kind, destination)
    }

    /// [`Sealer::seal`] of a frame of `kind` (its service code, or [`Seal::CLAIM`]) to
    /// `destination`: `None` once the counter is exhausted.
    pub fn seal_as(
        &mut self,
        authenticator: &Authenticator,
        sender: u8,
        frame: &Frame,
        kind: u8,
        destination: u8,
    ) -> Option<Frame> {
        let counter = self.next()?;
        seal_frame(
            authenticator,
            sender,
            frame,
            (kind, destination),
            counter as u16,
            freshness(self.epoch, counter),
        )
    }

    /// The answer of `sender` to a freshness request with `nonce` from `requester`: the
    /// Freshness frame and its seal over the nonce, to be sent in this order. One CMAC.
    pub fn answer(
        &self,
        authenticator: &Authenticator,
        sender: u8,
        requester: u8,
        nonce: u64,
    ) -> Option<[Frame; 2]> {
        let answer = Message::Freshness {
            epoch: self.epoch,
            counter: self.counter,
        }
        .report_frame(sender, requester)?;
        let seal = seal_frame(
            authenticator,
            sender,
            &answer,
            (Service::Freshness.code(), requester),
            0,
            nonce,
        )?;
        Some([answer, seal])
    }

    /// A freshness request from `node` to `peer`: its nonce and frame. Takes a counter (one
    /// CMAC); `None` once the counter is exhausted.
    fn request(
        &mut self,
        authenticator: &Authenticator,
        node: u8,
        peer: u8,
    ) -> Option<(u64, Frame)> {
        let counter = self.next()?;
        // The node nonce of the challenges (a CMAC of epoch and counter under the key): as
        // unpredictable, and no code of its own on the boards.
        let nonce = authenticator.node_nonce(node, self.epoch, counter);
        let frame = Message::FreshnessRequest { nonce }.report_frame(node, peer)?;
        Some((nonce, frame))
    }
}

/// A coordination frame or freshness answer refused by a keyed receiver: why, what (the sealed
/// kind: a service code, or [`Seal::CLAIM`]) and from whom. What the `Unauthenticated` fault
/// reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Refusal {
    /// Why.
    pub reason: AuthFailure,
    /// The sealed kind.
    pub kind: u8,
    /// The sender.
    pub source: u8,
}

/// What a seal did at a receiver ([`Verifier::on_seal`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// No held frame it could seal (a stray or late seal): nothing happens.
    Nothing,
    /// The frame it seals verified and is fresh: apply it.
    Accepted(Frame),
    /// A freshness answer verified: the sender's freshness is known from now on.
    Synchronised,
    /// Refused: count it and say so.
    Refused(Refusal),
}

#[derive(Clone, Copy, Debug)]
struct Peer {
    node: u8,
    /// Whether the request out to it was answered: its nonce is spent, but its time still
    /// spaces the next request.
    answered: bool,
    /// The sender's epoch and the last counter accepted from it.
    known: Option<(u32, u32)>,
    /// The nonce of the last request to it, and when it left.
    asked: Option<(u64, Instant)>,
}

#[derive(Clone, Copy, Debug)]
struct Held {
    source: u8,
    kind: u8,
    /// A seal failed on it (and was counted then): not counted again when it leaves the hold.
    refused: bool,
    /// [`Seal::digest_of`] its payload.
    digest: u8,
    frame: Frame,
    at: Instant,
}

/// A receiver's side: the frames held for their seals and what it knows of each sender's
/// freshness. Fixed capacity ([`PEERS`], [`HELD`]), no allocation.
#[derive(Clone, Debug, Default)]
pub struct Verifier {
    peers: heapless::Vec<Peer, PEERS>,
    /// Oldest first.
    held: heapless::Vec<Held, HELD>,
}

/// Whether `then` is less than `span` µs before `now` (a clock that went backwards: not).
fn within(now: Instant, then: Instant, span: u64) -> bool {
    now.micros_since(then).is_some_and(|age| age < span)
}

/// Removes and returns the entry at `at`, keeping the others in order (`None` past the end).
/// The bound is checked here, so heapless's own assertion in `remove` is known to hold and no
/// panic path is left on the boards.
fn take<T: Copy, const N: usize>(entries: &mut heapless::Vec<T, N>, at: usize) -> Option<T> {
    (at < entries.len()).then(|| entries.remove(at))
}

/// The counter above `last` whose low 16 bits are `low`: `None` past 2^32 - 1.
fn counter_after(last: u32, low: u16) -> Option<u32> {
    let candidate = last & !0xFFFF | u32::from(low);
    if candidate > last {
        Some(candidate)
    } else {
        candidate.checked_add(0x1_0000)
    }
}

impl Verifier {
    /// An empty receiver: no frame held, no sender known.
    pub const fn new() -> Verifier {
        Verifier {
            peers: heapless::Vec::new(),
            held: heapless::Vec::new(),
        }
    }

    /// Holds a coordination frame (or a freshness answer) of `kind` (a service code, or
    /// [`Seal::CLAIM`]: [`sealed_kind`]) from `source` until its seal comes. Frames that waited
    /// longer than [`HOLD_US`] leave the hold, and the oldest leaves when it is full: returned
    /// are how many of them no seal had been tried on (refused `Unsealed`), and the last of
    /// those.
    pub fn hold(
        &mut self,
        source: u8,
        kind: u8,
        frame: &Frame,
        now: Instant,
    ) -> (usize, Option<Refusal>) {
        let mut unsealed = (0, None);
        // Oldest first: the frames that waited too long are at the front.
        while let Some(oldest) = self.held.first()
            && (self.held.is_full() || !within(now, oldest.at, HOLD_US))
        {
            if !oldest.refused {
                unsealed.0 += 1;
                unsealed.1 = Some(Refusal {
                    reason: AuthFailure::Unsealed,
                    kind: oldest.kind,
                    source: oldest.source,
                });
            }
            self.held.remove(0);
        }
        // Room was made above if the hold was full.
        let _ = self.held.push(Held {
            source,
            kind,
            refused: false,
            digest: Seal::digest_of(frame.payload()),
            frame: *frame,
            at: now,
        });
        unsealed
    }

    /// A seal from `source` reached `node` at `now`: the frame it seals, checked, or why not.
    ///
    /// It is tried on the frames held from that sender with its kind and digest, oldest first
    /// (a sender's seals follow its frames in order), at most [`TRIES`] of them: one CMAC each, none when no frame matches (then
    /// nothing happens). A frame whose seal fails stays held (a forged seal must not take the
    /// sender's frame away before its own seal comes, and a participant's frame of the same
    /// digest must not hide it), counted once. A seal from a sender whose freshness is unknown,
    /// or one that fails, makes the node ask the sender (at most once per [`REQUEST_US`]): the
    /// request is in the second field, to be sent.
    pub fn on_seal(
        &mut self,
        authenticator: &Authenticator,
        sealer: &mut Sealer,
        node: u8,
        source: u8,
        seal: &Seal,
        now: Instant,
    ) -> (Verdict, Option<Frame>) {
        let peer = self.peers.iter().find(|peer| peer.node == source).copied();
        // The freshness to check the tag with: the request's nonce for an answer (only while
        // the request is fresh and unanswered), else the counter above the last accepted.
        let answer = seal.kind == Service::Freshness.code();
        let freshness = match (answer, peer) {
            (true, Some(peer)) => match peer.asked {
                Some((nonce, at)) if !peer.answered && within(now, at, REQUEST_US) => Ok(nonce),
                _ => Err(AuthFailure::Stale),
            },
            (true, None) => Err(AuthFailure::Stale),
            (
                false,
                Some(Peer {
                    known: Some((epoch, last)),
                    ..
                }),
            ) => counter_after(last, seal.counter)
                .map(|counter| freshness(epoch, counter))
                .ok_or(AuthFailure::BadSeal),
            (false, _) => Err(AuthFailure::Unsynced),
        };
        let mut tries = 0;
        // A frame held longer than HOLD_US is still tried (it leaves at the next `hold`): a
        // late seal of the sender's applies it, nobody else's verifies.
        let slot = self.held.iter_mut().position(|held| {
            let candidate =
                held.source == source && held.kind == seal.kind && held.digest == seal.digest;
            if !candidate || tries == TRIES {
                return false;
            }
            tries += 1;
            let (raw, _) = held.frame.raw_id();
            let good = freshness.is_ok_and(|freshness| {
                authenticator.verify_seal(source, raw, held.frame.payload(), freshness, &seal.tag)
            });
            // Counted with the seal's refusal: not again when it leaves the hold.
            held.refused |= !good;
            good
        });
        if tries == 0 {
            return (Verdict::Nothing, None);
        }
        let refusal = |reason| {
            Verdict::Refused(Refusal {
                reason,
                kind: seal.kind,
                source,
            })
        };
        let Some(peer) = self
            .peer_at(source, now)
            .and_then(|at| self.peers.get_mut(at))
        else {
            // No room for a new sender (the first kept was asked within REQUEST_US): its seal
            // could only have failed (no freshness is known for it), and no request goes out.
            return (
                refusal(freshness.err().unwrap_or(AuthFailure::Unsynced)),
                None,
            );
        };
        let verdict = match (slot.and_then(|slot| take(&mut self.held, slot)), freshness) {
            (Some(held), Ok(_)) if answer => {
                // A Freshness: epoch and counter, u32 LE each (its length checked when decoded).
                let mut bytes = [0u8; 8];
                for (byte, of) in bytes.iter_mut().zip(held.frame.payload()) {
                    *byte = *of;
                }
                let [e0, e1, e2, e3, c0, c1, c2, c3] = bytes;
                peer.known = Some((
                    u32::from_le_bytes([e0, e1, e2, e3]),
                    u32::from_le_bytes([c0, c1, c2, c3]),
                ));
                peer.answered = true;
                return (Verdict::Synchronised, None);
            }
            (Some(held), Ok(freshness)) => {
                peer.known = Some(((freshness >> 32) as u32, freshness as u32));
                return (Verdict::Accepted(held.frame), None);
            }
            (_, Err(failure)) => refusal(failure),
            (None, Ok(_)) => refusal(AuthFailure::BadSeal),
        };
        // Forged, replayed, another key, a sender unknown or that restarted in a new epoch:
        // ask where it stands, at most once per REQUEST_US (an answer that fails asks for
        // nothing more).
        let due = peer
            .asked
            .is_none_or(|(_, at)| !within(now, at, REQUEST_US));
        let request = if due && !answer {
            sealer
                .request(authenticator, node, source)
                .map(|(nonce, frame)| {
                    peer.asked = Some((nonce, now));
                    peer.answered = false;
                    frame
                })
        } else {
            None
        };
        (verdict, request)
    }

    /// Where the state kept for `source` is, made if need be: when all [`PEERS`] are taken, in
    /// place of the first kept, unless it was asked within [`REQUEST_US`] of `now` (then `None`:
    /// see [`PEERS`]).
    fn peer_at(&mut self, source: u8, now: Instant) -> Option<usize> {
        if let Some(at) = self.peers.iter().position(|peer| peer.node == source) {
            return Some(at);
        }
        if self.peers.is_full() {
            let first = self.peers.first()?;
            if first
                .asked
                .is_some_and(|(_, at)| within(now, at, REQUEST_US))
            {
                return None;
            }
            take(&mut self.peers, 0);
        }
        // Room was made above if need be.
        self.peers
            .push(Peer {
                node: source,
                answered: false,
                known: None,
                asked: None,
            })
            .ok()?;
        Some(self.peers.len().saturating_sub(1))
    }

    /// What it knows of `source`: its epoch and the last counter accepted. For tests and
    /// diagnostics.
    pub fn known(&self, source: u8) -> Option<(u32, u32)> {
        self.peers
            .iter()
            .find(|peer| peer.node == source)
            .and_then(|peer| peer.known)
    }

    /// How many frames wait for their seal.
    pub fn held(&self) -> usize {
        self.held.len()
    }
}
