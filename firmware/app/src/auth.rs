//! The node's side of authenticated configuration: its key (or none, or a locked state), the
//! challenge it has out, and its budget of tag checks.
//!
//! Rules (docs/can-protocol.md, "Authenticated configuration"): a challenge lives
//! [`CHALLENGE_LIFETIME_US`] and belongs to the request that made it (its tags are over the
//! exchange of that request's tool nonce); the next request replaces it (a challenge kept for a
//! nonce nobody else can use would let a rogue hold the node with one request a second); the
//! challenge is consumed by the first message whose tag verifies, and only by such a message (a
//! wrong tag leaves it to the tool). At most
//! [`TAG_CHECKS_PER_SECOND`] tags are checked and new challenges made per second (each costs
//! CMACs); beyond, requests and messages are refused unchecked.

use pab_core::auth::{self, Authenticator, Key};
use pab_core::protocol::{AuthFailure, Seal, TransferOpen};
use pab_core::seal::{Refusal, Sealer, Verdict, Verifier};
use pab_core::{Frame, Instant};

/// How long a challenge stays valid.
pub const CHALLENGE_LIFETIME_US: u64 = 1_000_000;
/// Tag checks per second, at most. Bounds the CPU spent on forged tags (a check is one CMAC:
/// two AES blocks) and the rate of guesses at a 32-bit tag: one chance in 2^32 per check, each
/// check consuming nothing but a try, so at this rate a guess needs about 250 days on average.
pub const TAG_CHECKS_PER_SECOND: u16 = 200;

/// Whether the node has a key.
// The keyed variant holds the key schedule inline: no allocator here, and the node is one static
// object, so the unkeyed node's unused bytes are the price of not boxing.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Keying {
    /// No key: configuration from anyone (today's behaviour), and the heartbeat says so.
    Unkeyed,
    /// A key: only authenticated configuration.
    Keyed(Authenticator),
    /// The key page did not verify: no configuration at all. The page error's code.
    Locked(u8),
}

#[derive(Clone, Copy, Debug)]
struct Challenge {
    /// The exchange nonce: what the exchange's tags are over.
    nonce: u64,
    expires: Instant,
}

/// A node's authentication state. Memory: the AES key schedule and CMAC state (a few hundred
/// bytes) and a few words.
#[derive(Clone, Debug)]
pub(crate) struct Guard {
    keying: Keying,
    boot_salt: u32,
    /// Challenges issued since boot; exhausted at 2^32 - 1 (then none is issued until reboot).
    counter: u32,
    challenge: Option<Challenge>,
    window_start: Instant,
    checks_in_window: u16,
    /// Sealed coordination ([`pab_core::seal`]), on a keyed node: its own seals' counter (its
    /// epoch is the boot salt) and what it knows of the senders it hears.
    sealer: Sealer,
    verifier: Verifier,
}

impl Guard {
    pub(crate) fn unkeyed(now: Instant) -> Guard {
        Guard {
            keying: Keying::Unkeyed,
            boot_salt: 0,
            counter: 0,
            challenge: None,
            window_start: now,
            checks_in_window: 0,
            sealer: Sealer::new(0),
            verifier: Verifier::new(),
        }
    }

    pub(crate) fn set_key(&mut self, key: &Key, boot_salt: u32) {
        self.keying = Keying::Keyed(Authenticator::new(key));
        self.boot_salt = boot_salt;
        self.counter = 0;
        self.challenge = None;
        self.sealer = Sealer::new(boot_salt);
        self.verifier = Verifier::new();
    }

    pub(crate) fn lock(&mut self, reason: u8) {
        self.keying = Keying::Locked(reason);
        self.challenge = None;
    }

    /// The outstanding challenge (its exchange nonce and expiry) and the budget's window: what
    /// [`crate::AuthProbe`] shows. Inline: compiled only where a test or fuzz target calls it.
    #[inline]
    pub(crate) fn probe(&self) -> (Option<(u64, Instant)>, Instant, u16) {
        (
            self.challenge
                .map(|challenge| (challenge.nonce, challenge.expires)),
            self.window_start,
            self.checks_in_window,
        )
    }

    /// Whether configuration needs a key (keyed or locked): the heartbeat's flag.
    pub(crate) fn is_keyed(&self) -> bool {
        !matches!(self.keying, Keying::Unkeyed)
    }

    /// The key page error, if the node is locked.
    pub(crate) fn locked(&self) -> Option<u8> {
        match self.keying {
            Keying::Locked(reason) => Some(reason),
            _ => None,
        }
    }

    /// Whether a plain (untagged) configuration message may be taken.
    pub(crate) fn plain_allowed(&self) -> Result<(), AuthFailure> {
        match self.keying {
            Keying::Unkeyed => Ok(()),
            Keying::Keyed(_) => Err(AuthFailure::Missing),
            Keying::Locked(_) => Err(AuthFailure::Locked),
        }
    }

    fn authenticator(&self) -> Result<&Authenticator, AuthFailure> {
        match &self.keying {
            Keying::Keyed(authenticator) => Ok(authenticator),
            Keying::Unkeyed => Err(AuthFailure::NoKey),
            Keying::Locked(_) => Err(AuthFailure::Locked),
        }
    }

    /// The Challenge (node nonce, binding) node `node` answers a request with `tool_nonce` with
    /// at `now`: a new one, which replaces the outstanding one (one check of the budget: two
    /// CMACs).
    pub(crate) fn challenge(
        &mut self,
        node: u8,
        tool_nonce: u64,
        now: Instant,
    ) -> Result<(u64, [u8; auth::BINDING_LEN]), AuthFailure> {
        self.authenticator()?;
        self.spend(now)?;
        let counter = self.counter.checked_add(1).ok_or(AuthFailure::Stale)?;
        let authenticator = self.authenticator()?;
        let node_nonce = authenticator.node_nonce(node, self.boot_salt, counter);
        let exchange = authenticator.exchange(node, tool_nonce, node_nonce);
        self.counter = counter;
        self.challenge = Some(Challenge {
            nonce: exchange.nonce,
            expires: now.wrapping_add_micros(CHALLENGE_LIFETIME_US),
        });
        Ok((node_nonce, exchange.binding))
    }

    fn fresh(&self, now: Instant) -> Option<Challenge> {
        self.challenge.filter(|challenge| {
            challenge
                .expires
                .micros_since(now)
                .is_some_and(|left| left > 0)
        })
    }

    /// Takes one tag check from the budget of the current second.
    fn spend(&mut self, now: Instant) -> Result<(), AuthFailure> {
        let elapsed = now.micros_since(self.window_start);
        if elapsed.is_none_or(|elapsed| elapsed >= 1_000_000) {
            self.window_start = now;
            self.checks_in_window = 0;
        }
        if self.checks_in_window >= TAG_CHECKS_PER_SECOND {
            return Err(AuthFailure::RateLimited);
        }
        self.checks_in_window = self.checks_in_window.saturating_add(1);
        Ok(())
    }

    /// The nonce of the outstanding challenge, checked and consumed if `verify` accepts a tag
    /// over it.
    fn check(
        &mut self,
        now: Instant,
        verify: impl FnOnce(&Authenticator, u64) -> bool,
    ) -> Result<u64, AuthFailure> {
        let (authenticator, nonce) = self.admit(now)?;
        if !verify(authenticator, nonce) {
            return Err(AuthFailure::BadTag);
        }
        self.challenge = None;
        Ok(nonce)
    }

    /// [`Guard::check`] up to the tag: the key, the outstanding challenge's nonce and one check
    /// of the budget. Out of line: one copy for the command and the TransferOpen checks instead
    /// of one inlined into each.
    #[inline(never)]
    fn admit(&mut self, now: Instant) -> Result<(&Authenticator, u64), AuthFailure> {
        self.authenticator()?;
        let challenge = self.fresh(now).ok_or(AuthFailure::Stale)?;
        self.spend(now)?;
        Ok((self.authenticator()?, challenge.nonce))
    }

    /// Checks a tagged command to `node` of `service` with plain payload `payload`.
    pub(crate) fn command(
        &mut self,
        node: u8,
        service: u8,
        payload: &[u8],
        tag: &[u8],
        now: Instant,
    ) -> Result<(), AuthFailure> {
        self.check(now, |authenticator, nonce| {
            authenticator.verify_command(node, service, nonce, payload, tag)
        })
        .map(|_| ())
    }

    /// Checks a TransferOpen to `node`: the nonce the transfer's image MAC is over.
    pub(crate) fn open(
        &mut self,
        node: u8,
        open: &TransferOpen,
        now: Instant,
    ) -> Result<u64, AuthFailure> {
        self.check(now, |authenticator, nonce| {
            authenticator.verify_open(node, nonce, open.length, open.flags, &open.tag)
        })
    }

    /// Whether `mac` is the image MAC of `image` for this transfer.
    pub(crate) fn image(&self, node: u8, nonce: u64, flags: u8, image: &[u8], mac: &[u8]) -> bool {
        match &self.keying {
            Keying::Keyed(authenticator) => {
                authenticator.verify_image(node, nonce, flags, image, mac)
            }
            _ => false,
        }
    }

    /// The Receipt tag for a TransferStatus payload (zeros when the node has no key: never
    /// called then).
    pub(crate) fn receipt(
        &self,
        node: u8,
        nonce: u64,
        status: &[u8; 8],
        running_crc: u32,
        stored: bool,
    ) -> [u8; auth::RECEIPT_TAG_LEN] {
        match &self.keying {
            Keying::Keyed(authenticator) => {
                authenticator.receipt_tag(node, nonce, status, running_crc, stored)
            }
            _ => [0; auth::RECEIPT_TAG_LEN],
        }
    }

    /// The seal to send after `frame` (a Gates frame, a claim: `kind`, to all) on a keyed node;
    /// `None` on another, or once its counter is exhausted. One CMAC.
    pub(crate) fn seal(&mut self, node: u8, frame: &Frame, kind: u8) -> Option<Frame> {
        match &self.keying {
            Keying::Keyed(authenticator) => self.sealer.seal_as(
                authenticator,
                node,
                frame,
                kind,
                pab_core::protocol::BROADCAST,
            ),
            _ => None,
        }
    }

    /// The answer to a freshness request with `nonce` from `requester`: the Freshness frame
    /// and its seal. One check of the budget (a CMAC).
    pub(crate) fn answer_freshness(
        &mut self,
        node: u8,
        requester: u8,
        nonce: u64,
        now: Instant,
    ) -> Result<[Frame; 2], AuthFailure> {
        self.authenticator()?;
        self.spend(now)?;
        self.sealer
            .answer(self.authenticator()?, node, requester, nonce)
            .ok_or(AuthFailure::Stale)
    }

    /// Holds a coordination frame from `source` for its seal: how many frames left the hold
    /// unsealed, and the last of them.
    pub(crate) fn hold(
        &mut self,
        source: u8,
        kind: u8,
        frame: &Frame,
        now: Instant,
    ) -> (usize, Option<Refusal>) {
        self.verifier.hold(source, kind, frame, now)
    }

    /// A seal from `source`: what it does, and a freshness request to send, if any. A locked
    /// node refuses every seal it could match.
    pub(crate) fn on_seal(
        &mut self,
        node: u8,
        source: u8,
        seal: &Seal,
        now: Instant,
    ) -> (Verdict, Option<Frame>) {
        match &self.keying {
            Keying::Keyed(authenticator) => {
                self.verifier
                    .on_seal(authenticator, &mut self.sealer, node, source, seal, now)
            }
            _ => (
                Verdict::Refused(Refusal {
                    reason: AuthFailure::Locked,
                    kind: seal.kind,
                    source,
                }),
                None,
            ),
        }
    }
}
