//! Sealed coordination (`pab_core::seal`) between one genuine sender and one receiver, with the
//! fuzzer as everyone else on the bus: it makes the sender seal Gates frames, claims and filter
//! commands (the seals then wait in the sender's queue, as seals rank after the frames they
//! seal), delivers, drops or reorders the waiting seals, forges coordination frames and seals
//! under any sender's id (the genuine one's included), replays anything that went on the bus
//! (frames, seals, freshness answers) in any order, sends arbitrary frames, restarts the sender
//! (a new epoch) or the receiver (a new `Verifier`), and moves time by 0 µs to 2^40 µs, now and
//! then backwards. The genuine sender answers every freshness request the receiver sends it.
//!
//! Properties, checked at every step:
//!
//! - **Never a panic**, and the hold never holds more than `seal::HELD` frames.
//! - **Only the genuine sender's frames are accepted, fresh**: every frame the receiver accepts
//!   is one the genuine sender sealed, with the freshness (epoch, counter) the receiver then
//!   knows; within one receiver's life, no freshness is accepted twice, the counters of an epoch
//!   only grow, and an epoch left is never accepted again.
//! - **Synchronisation only by a genuine answer**: `Synchronised` only with the genuine sender,
//!   and what the receiver then knows is what the sender answered to the receiver's last request
//!   (its seal delivered at once, or replayed later: still the sender's seal over that nonce).
//! - **Requests are the receiver's and spaced**: every request decodes as a FreshnessRequest from
//!   the receiver to the seal's source, at most one per `seal::REQUEST_US` per source (on a clock
//!   that only moves forward between them).

use std::collections::{HashMap, HashSet};

use arbitrary::{Result, Unstructured};
use pab_core::auth::{Authenticator, Key};
use pab_core::ble::Claim;
use pab_core::protocol::{BROADCAST, FilterProfile, FilterSet, Gates, Message, Seal};
use pab_core::seal::{HELD, REQUEST_US, Sealer, Verdict, Verifier, sealed_kind};
use pab_core::{Frame, Instant};

const SENDER: u8 = 1;
const RECEIVER: u8 = 5;

/// A coordination frame from `source`, of a kind a seal may follow.
fn coordination(u: &mut Unstructured<'_>, source: u8) -> Result<Frame> {
    Ok(match u.int_in_range(0u8..=3)? {
        0 => {
            let behaviours = u.int_in_range(1..=32u8)?;
            Message::Gates(Gates {
                group: u.int_in_range(0..=2)?,
                behaviours,
                mask: u.arbitrary::<u32>()?
                    & 1u32
                        .checked_shl(behaviours.into())
                        .map_or(u32::MAX, |b| b - 1),
                changes: u.arbitrary()?,
            })
            .to_frame(source, BROADCAST)
        }
        1 => Message::FilterSet(FilterSet {
            port: u.int_in_range(0..=3)?,
            connection: u.arbitrary()?,
            phi: u.arbitrary()?,
            sequence: u.arbitrary()?,
        })
        .to_frame(source, RECEIVER),
        2 => Message::FilterProfile(FilterProfile {
            profile: u.int_in_range(0..=15)?,
            sequence: u.arbitrary()?,
        })
        .to_frame(source, RECEIVER),
        _ => Claim {
            group: u.int_in_range(0..=3)?,
            node: source.clamp(1, 127),
            eligibility: u.arbitrary()?,
        }
        .frame()
        .unwrap_or_else(|| unreachable!("node 1..=127")),
    })
}

struct Bus {
    authenticator: Authenticator,
    sender: Sealer,
    epoch: u32,
    receiver: Verifier,
    receiver_sealer: Sealer,
    now: u64,
    /// Seals waiting in the sender's queue, oldest first.
    waiting: Vec<Frame>,
    /// Everything that went on the bus: what a rogue replays.
    recorded: Vec<Frame>,
    /// What the sender sealed: (epoch, counter) → frame.
    sealed: HashMap<(u32, u32), Frame>,
    /// Freshness answers the sender gave: the nonce → (epoch, counter).
    answers: HashMap<u64, (u32, u32)>,
    /// What this receiver accepted, in order.
    accepted: Vec<(u32, u32)>,
    /// Per source, when the receiver last asked it.
    asked: HashMap<u8, u64>,
    /// The clock went backwards since the last request to a source: the spacing is not checked
    /// for it until it asks again.
    rewound: HashSet<u8>,
    /// The nonce of the receiver's last request to the genuine sender.
    last_request: Option<u64>,
}

impl Bus {
    fn new(key: &Key, epoch: u32) -> Bus {
        Bus {
            authenticator: Authenticator::new(key),
            sender: Sealer::new(epoch),
            epoch,
            receiver: Verifier::new(),
            receiver_sealer: Sealer::new(epoch ^ 0x5A5A_5A5A),
            now: 1_000,
            waiting: Vec::new(),
            recorded: Vec::new(),
            sealed: HashMap::new(),
            answers: HashMap::new(),
            accepted: Vec::new(),
            asked: HashMap::new(),
            rewound: HashSet::new(),
            last_request: None,
        }
    }

    fn at(&self) -> Instant {
        Instant::from_micros(self.now)
    }

    /// A frame reaches the receiver (and the bus's record): held if a seal may follow it, read
    /// as a seal if it is one.
    fn deliver(&mut self, frame: &Frame) {
        self.recorded.push(*frame);
        if let Some((kind, _)) = sealed_kind(frame) {
            let source = match Message::decode(frame) {
                Ok((id, _)) => id.source,
                // A claim: its node id is the identifier's low 7 bits.
                Err(_) => (frame.raw_id().0 & 0x7F) as u8,
            };
            let (count, refusal) = self.receiver.hold(source, kind, frame, self.at());
            assert!(count <= HELD && (count == 0) == refusal.is_none());
            assert!(self.receiver.held() <= HELD);
            return;
        }
        if let Ok((id, Message::Seal(seal))) = Message::decode(frame) {
            self.seal(id.source, &seal);
        }
    }

    fn seal(&mut self, source: u8, seal: &Seal) {
        let now = self.at();
        let (verdict, request) = self.receiver.on_seal(
            &self.authenticator,
            &mut self.receiver_sealer,
            RECEIVER,
            source,
            seal,
            now,
        );
        match verdict {
            Verdict::Accepted(frame) => {
                assert_eq!(
                    source, SENDER,
                    "a frame accepted from a sender without the key"
                );
                let known = self
                    .receiver
                    .known(SENDER)
                    .expect("a sender it accepted from");
                assert_eq!(
                    self.sealed.get(&known),
                    Some(&frame),
                    "accepted a frame the sender did not seal with that freshness"
                );
                assert!(!self.accepted.contains(&known), "{known:?} accepted twice");
                if let Some(&(epoch, counter)) = self.accepted.last() {
                    if epoch == known.0 {
                        assert!(known.1 > counter, "counter {} after {counter}", known.1);
                    } else {
                        assert!(
                            !self.accepted.iter().any(|&(e, _)| e == known.0),
                            "back to an epoch left"
                        );
                    }
                }
                self.accepted.push(known);
            }
            // The genuine answer to the receiver's last request (its seal delivered then, or
            // replayed later while the request is fresh: still the sender's over that nonce).
            Verdict::Synchronised => {
                assert_eq!(source, SENDER, "synchronised with a sender without the key");
                let known = self.receiver.known(SENDER).expect("synchronised");
                let answered = self.last_request.and_then(|nonce| self.answers.get(&nonce));
                assert_eq!(
                    answered,
                    Some(&known),
                    "synchronised to what no answer to its last request said"
                );
            }
            Verdict::Refused(refusal) => assert_eq!(refusal.source, source),
            Verdict::Nothing => {}
        }
        if let Some(request) = request {
            let Ok((id, Message::FreshnessRequest { nonce })) = Message::decode(&request) else {
                panic!("a request that is not a FreshnessRequest: {request:?}");
            };
            assert_eq!((id.source, id.destination), (RECEIVER, source));
            if let Some(&last) = self.asked.get(&source)
                && !self.rewound.contains(&source)
            {
                assert!(
                    self.now >= last + REQUEST_US,
                    "asked {source} again too soon"
                );
            }
            self.asked.insert(source, self.now);
            self.rewound.remove(&source);
            if source == SENDER {
                self.last_request = Some(nonce);
                // The genuine sender answers at once: its answer, then the answer's seal.
                let [answer, answer_seal] = self
                    .sender
                    .answer(&self.authenticator, SENDER, RECEIVER, nonce)
                    .expect("an answer");
                self.answers
                    .insert(nonce, (self.sender.epoch(), self.sender.counter()));
                self.deliver(&answer);
                self.deliver(&answer_seal);
            }
        }
    }

    fn step(&mut self, u: &mut Unstructured<'_>) -> Result<()> {
        match u.int_in_range(0u8..=10)? {
            // The sender seals a frame: it goes out now, its seal waits.
            0..=2 => {
                let frame = coordination(u, SENDER)?;
                if let Some(seal) = self.sender.seal(&self.authenticator, SENDER, &frame) {
                    self.sealed
                        .insert((self.epoch, self.sender.counter()), frame);
                    self.waiting.push(seal);
                }
                self.deliver(&frame);
            }
            // The oldest waiting seal goes out (now and then another one: a reordering).
            3 | 4 => {
                if !self.waiting.is_empty() {
                    let at = if u.ratio(1u8, 8)? {
                        u.choose_index(self.waiting.len())?
                    } else {
                        0
                    };
                    let seal = self.waiting.remove(at);
                    self.deliver(&seal);
                }
            }
            // A waiting seal is lost.
            5 => {
                if !self.waiting.is_empty() {
                    let at = u.choose_index(self.waiting.len())?;
                    self.waiting.remove(at);
                }
            }
            // A rogue's frame under any id (the sender's often), with a made-up seal or none.
            6 => {
                let source = if u.arbitrary()? {
                    SENDER
                } else {
                    u.int_in_range(1..=127)?
                };
                let frame = coordination(u, source)?;
                self.deliver(&frame);
                if u.arbitrary()? {
                    let (kind, destination) = sealed_kind(&frame).expect("sealable");
                    let seal = Message::Seal(Seal {
                        kind,
                        digest: if u.arbitrary()? {
                            Seal::digest_of(frame.payload())
                        } else {
                            u.arbitrary()?
                        },
                        counter: u.arbitrary()?,
                        tag: u.arbitrary()?,
                    })
                    .to_frame(source, destination);
                    self.deliver(&seal);
                }
            }
            // A replay of anything that went on the bus.
            7 => {
                if !self.recorded.is_empty() {
                    let at = u.choose_index(self.recorded.len())?;
                    let frame = self.recorded[at];
                    self.deliver(&frame);
                }
            }
            // Any frame at all: a seal of any kind from anyone, a Freshness, garbage.
            8 => {
                let raw: u32 = u.arbitrary()?;
                let len = u.int_in_range(0..=8usize)?;
                let mut bytes = [0u8; 8];
                u.fill_buffer(&mut bytes[..len])?;
                if let Some(frame) = Frame::with_raw_id(raw & 0x1FFF_FFFF, true, &bytes[..len]) {
                    self.deliver(&frame);
                }
            }
            // Time.
            9 => {
                let step: u64 = if u.ratio(1u8, 16)? {
                    u.int_in_range(0..=1u64 << 40)?
                } else {
                    u.int_in_range(0..=2_000_000)?
                };
                if u.ratio(1u8, 16)? {
                    self.now = self.now.saturating_sub(step);
                    self.rewound.extend(self.asked.keys().copied());
                } else {
                    self.now = self.now.saturating_add(step);
                }
            }
            // A restart: of the sender (a new epoch; its waiting seals are lost) or of the
            // receiver (it knows nothing again).
            _ => {
                if u.arbitrary()? {
                    self.epoch = self.epoch.wrapping_add(u.int_in_range(1..=u32::MAX)?);
                    self.sender = Sealer::new(self.epoch);
                    self.waiting.clear();
                } else {
                    self.receiver = Verifier::new();
                    self.last_request = None;
                    self.accepted.clear();
                    self.asked.clear();
                    self.rewound.clear();
                }
            }
        }
        Ok(())
    }
}

/// Runs one script.
pub fn check(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let Ok(key) = u.arbitrary::<[u8; 16]>() else {
        return;
    };
    let Ok(epoch) = u.arbitrary::<u32>() else {
        return;
    };
    let mut bus = Bus::new(&Key::from_bytes(key), epoch);
    for _ in 0..600 {
        if u.is_empty() || bus.step(&mut u).is_err() {
            break;
        }
    }
}
