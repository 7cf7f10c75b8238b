//! A keyed node (`pab_app::Node`, board capacities, `set_key`) under arbitrary bus input, where
//! the fuzzer is now and then the key's holder: it asks for challenges (with tool nonces of its
//! own or arbitrary ones, from the tool or any source), reads the node's Challenges, and sends
//! DiagnosticControl tagged over the current exchange, keyed pushes of the examples' images
//! (ChallengeRequest, TransferOpen, ISO-TP with the image MAC, some frames tampered with or
//! dropped), wrong tags (a bit flipped, an old exchange's nonce, a made-up nonce), replays of
//! any genuine frame it sent before, arbitrary frames (`node`'s generators), stores that succeed
//! or fail, and time moving forward by microseconds or seconds.
//!
//! The harness tracks the exchange itself, from the bus: the tool nonce of each request it sent,
//! the node nonce of the Challenge that answered it, `Authenticator::exchange` of the two under
//! the key. `Node::auth_probe` (hidden, for this target) shows the node's outstanding challenge,
//! its budget window and its diagnostic setting, which the harness holds to what it saw.
//!
//! Properties, checked after every call into the node (`on_frame`, `poll`, `stored`):
//!
//! - **Never a panic; everything the node sends decodes and comes from its id.**
//! - **Challenges answer requests**: a Challenge only during a ChallengeRequest to this node, one,
//!   to its sender, its binding that of the exchange of the request's tool nonce and its node
//!   nonce (which never repeats, and fits 48 bits); the node's outstanding challenge is then that
//!   exchange's nonce, expiring 1 s later. A challenge whose frame the outbox dropped must be
//!   counted as an error.
//! - **Only a verified tag consumes a challenge**: the node's outstanding challenge disappears only
//!   during a tagged DiagnosticControl (to this node) or a TransferOpen (from the tool) whose tag
//!   verifies, by the harness's own computation, over the exchange of the challenge the node last
//!   issued, unconsumed and less than 1 s old. The same genuine frame never does so twice (a
//!   replay never applies). And the converse: a genuine message over the fresh challenge, when
//!   the budget has room, is taken.
//! - **Configuration changes only through it**: the diagnostic setting changes only during a
//!   message that consumed the challenge, and is then that message's (off for rate or ports 0).
//!   The running table changes only during a table-transfer frame from the tool, to an image the
//!   harness MACed under the nonce of an open that consumed a challenge, once per open; never
//!   during a poll or a store.
//! - **Receipts verify**: every Receipt is the tag, under the key, of a TransferStatus the node
//!   sent (in the same call or just before) over the nonce of an opened transfer, with the
//!   running table's CRC and stored flag before or after the call.
//! - **The budget holds**: the node's window holds at most `TAG_CHECKS_PER_SECOND` checks, moves
//!   only to a call at least 1 s after its start, and every challenge made and every challenge
//!   consumed in a call is paid for by a check of that call; no check without a message. Counted
//!   from the bus alone, challenges and consumed challenges are at most twice the budget in any
//!   second (the node's windows are fixed, so a sliding second may straddle two).

use std::collections::{HashSet, VecDeque};

use arbitrary::{Result, Unstructured};
use pab_app::{AuthProbe, Config, Node, Recipient, Step, TAG_CHECKS_PER_SECOND};
use pab_core::auth::{Authenticator, Key, NODE_NONCE_MAX};
use pab_core::isotp::{Sender, TxConfig, TxEvent};
use pab_core::protocol::{self, DiagnosticControl, Message, OPEN_REPLACE, TransferOpen};
use pab_core::{BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, Frame, Instant};

use crate::node::{NODE_ID, any_id, mutated_image, payload, protocol_frame, reached, sent_by_node};

const IMG: usize = 8192;
type TestNode = Node<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES, IMG>;

const SECOND: u64 = 1_000_000;
/// DiagnosticControl's service code (what its command tag covers).
const DIAGNOSTIC_CONTROL: u8 = 0x10;

/// Runs the fuzzer's script against one keyed node.
pub fn check(data: &[u8]) {
    let _ = run(&mut Unstructured::new(data));
}

/// What a run reached (for the test that the script reaches the key holder's paths).
#[derive(Clone, Copy, Debug, Default)]
struct Stats {
    challenges: usize,
    commands_taken: usize,
    opens_taken: usize,
    swaps: usize,
    receipts: usize,
    /// Calls after which the budget's window was full.
    budget_full: usize,
}

/// What the script of `data` reached: a challenge issued, a command taken, an open taken, a
/// table swapped in, a receipt, the budget used up (for choosing seeds: `examples/seeds.rs`).
pub fn features(data: &[u8]) -> std::collections::BTreeSet<&'static str> {
    let stats = run(&mut Unstructured::new(data)).unwrap_or_default();
    reached([
        ("challenge", stats.challenges),
        ("command taken", stats.commands_taken),
        ("open taken", stats.opens_taken),
        ("table swapped", stats.swaps),
        ("receipt", stats.receipts),
        ("budget full", stats.budget_full),
    ])
}

fn run(u: &mut Unstructured<'_>) -> Result<Stats> {
    let mut world = setup(u)?;
    let _ = script(u, &mut world);
    Ok(world.stats)
}

struct Sink;

impl Recipient for Sink {
    fn deliver(&mut self, _port: u8, _frame: &Frame, _now: Instant) {}
}

/// The challenge the node last issued, as the harness computed it from the bus.
#[derive(Clone, Copy, Debug)]
struct Current {
    /// The exchange nonce.
    nonce: u64,
    /// When it expires (µs).
    expires: u64,
    consumed: bool,
}

/// What a call into the node was.
enum Input<'a> {
    Frame(&'a Frame),
    Poll,
    Stored,
}

struct World {
    node: TestNode,
    auth: Authenticator,
    now: u64,
    /// The node's last challenge; `None` before the first, or when its frame was lost.
    current: Option<Current>,
    /// Every exchange nonce the node issued (old ones, for wrong tags).
    old_nonces: Vec<u64>,
    node_nonces: HashSet<u64>,
    /// Exchange nonces of opens that consumed a challenge.
    opens: Vec<u64>,
    /// Opens whose transfer swapped a table in.
    applied_opens: HashSet<u64>,
    /// Images the harness MACed, with the exchange nonce.
    macs: Vec<(u64, Vec<u8>)>,
    /// Genuine frames sent (for replays), and the frames that consumed a challenge.
    genuine: Vec<Frame>,
    consumed_by: HashSet<((u32, bool), Vec<u8>)>,
    /// Recent TransferStatus payloads the node sent.
    statuses: VecDeque<[u8; 8]>,
    /// Times of challenges issued and consumed (the last second's).
    checks_seen: VecDeque<u64>,
    /// `Step::Store` came and `stored` has not been called yet.
    store_owed: bool,
    /// What the next `stored` call reports.
    stored_ok: Option<bool>,
    next_tool_nonce: u64,
    /// The node's flow controls to the tool, in order, for the push in progress.
    flow_controls: Vec<[u8; 8]>,
    stats: Stats,
}

fn running_key(node: &TestNode) -> Option<(u32, u32, bool)> {
    node.running().map(|running| {
        (
            running.header.table_version,
            running.header.crc,
            running.stored,
        )
    })
}

fn frame_key(frame: &Frame) -> ((u32, bool), Vec<u8>) {
    (frame.raw_id(), frame.payload().to_vec())
}

impl World {
    fn at(&self) -> Instant {
        Instant::from_micros(self.now)
    }

    /// Whether the budget lets one more check through at `now`, by the node's window.
    fn budget_room(&self, probe: &AuthProbe) -> bool {
        let elapsed = self.at().micros_since(probe.window_start);
        elapsed.is_none_or(|elapsed| elapsed >= SECOND)
            || probe.checks_in_window < TAG_CHECKS_PER_SECOND
    }

    /// The harness's current challenge, if it is fresh and unconsumed: its nonce.
    fn fresh(&self) -> Option<u64> {
        self.current
            .filter(|current| !current.consumed && self.now < current.expires)
            .map(|current| current.nonce)
    }

    fn feed(&mut self, frame: &Frame) {
        let step = self.call(Input::Frame(frame));
        self.on_step(step);
    }

    fn poll(&mut self) {
        let step = self.call(Input::Poll);
        self.on_step(step);
    }

    fn on_step(&mut self, step: Step) {
        if step == Step::Store {
            assert!(
                !self.store_owed,
                "a second Store before the first was stored"
            );
            self.store_owed = true;
        }
    }

    fn finish_store(&mut self, ok: bool) {
        if self.store_owed {
            self.store_owed = false;
            let step = self.call_stored(ok);
            self.on_step(step);
        }
    }

    fn call_stored(&mut self, ok: bool) -> Step {
        self.stored_ok = Some(ok);
        self.call(Input::Stored)
    }

    /// One call into the node, and every property checked on what it did.
    fn call(&mut self, input: Input<'_>) -> Step {
        let pre = self.node.auth_probe();
        let pre_running = running_key(&self.node);
        let pre_errors = self.node.counters().errors;
        let at = self.at();
        let step = match input {
            Input::Frame(frame) => self.node.on_frame(frame, at, &mut Sink),
            Input::Poll => self.node.poll(at, &mut Sink),
            Input::Stored => {
                let ok = self.stored_ok.take().unwrap_or(true);
                self.node.stored(ok, at);
                Step::Continue
            }
        };
        let post = self.node.auth_probe();
        let post_running = running_key(&self.node);

        // What the node sent: decodes, from its id.
        let mut challenges = Vec::new();
        let mut receipts = Vec::new();
        let mut statuses = Vec::new();
        while let Some(frame) = self.node.next_outgoing() {
            let kind = protocol::classify(&frame);
            if !kind.is_ours() {
                continue; // a gateway port's re-publication
            }
            let Some((id, message)) = sent_by_node(&frame, kind) else {
                continue;
            };
            match message {
                Message::Challenge {
                    node_nonce,
                    binding,
                } => challenges.push((id.destination, node_nonce, binding)),
                Message::Receipt { tag } => receipts.push((id.destination, tag)),
                Message::TransferStatus(_) => {
                    let mut bytes = [0u8; 8];
                    bytes.copy_from_slice(frame.payload());
                    statuses.push(bytes);
                }
                Message::TableTransfer { data, .. } if id.destination == protocol::TOOL => {
                    self.flow_controls.push(data);
                }
                _ => {}
            }
        }
        let frame = match input {
            Input::Frame(frame) => Some(frame),
            _ => None,
        };
        let decoded = frame.and_then(|frame| Message::decode(frame).ok());

        // Challenges answer requests.
        assert!(
            challenges.len() <= 1,
            "{} challenges in one call",
            challenges.len()
        );
        let mut issued = false;
        if let Some(&(destination, node_nonce, binding)) = challenges.first() {
            let Some((id, Message::ChallengeRequest { tool_nonce })) = decoded else {
                panic!("a Challenge during {frame:?}, not a ChallengeRequest");
            };
            assert_eq!(
                id.destination, NODE_ID,
                "a Challenge to a request for {id:?}"
            );
            assert_eq!(
                destination, id.source,
                "a Challenge to another than the requester"
            );
            assert!(node_nonce <= NODE_NONCE_MAX, "a node nonce beyond 48 bits");
            assert!(
                self.node_nonces.insert(node_nonce),
                "the node nonce {node_nonce:#x} came twice"
            );
            let exchange = self.auth.exchange(NODE_ID, tool_nonce, node_nonce);
            assert_eq!(
                binding, exchange.binding,
                "a Challenge's binding does not verify"
            );
            let expires = self.now.wrapping_add(SECOND);
            assert_eq!(
                post.challenge,
                Some((exchange.nonce, Instant::from_micros(expires))),
                "the node's outstanding challenge is not the one it sent"
            );
            self.current = Some(Current {
                nonce: exchange.nonce,
                expires,
                consumed: false,
            });
            self.old_nonces.push(exchange.nonce);
            self.stats.challenges += 1;
            self.checks_seen.push_back(self.now);
            issued = true;
        } else if post.challenge.is_some() && post.challenge != pre.challenge {
            // A challenge was made and its frame lost (outbox full): counted as an error.
            assert!(
                self.node.counters().errors > pre_errors,
                "a new challenge, neither sent nor counted as dropped"
            );
            assert!(
                matches!(decoded, Some((_, Message::ChallengeRequest { .. }))),
                "a new challenge during {frame:?}"
            );
            self.current = None;
            issued = true;
        }

        // Only a verified tag consumes a challenge.
        let consumed = !issued && pre.challenge.is_some() && post.challenge.is_none();
        if consumed {
            let frame = frame.unwrap_or_else(|| panic!("a challenge consumed without a message"));
            let current = self
                .current
                .unwrap_or_else(|| panic!("{frame:?} consumed a challenge the harness never saw"));
            assert_eq!(
                pre.challenge.map(|(nonce, _)| nonce),
                Some(current.nonce),
                "the node's challenge is not the last one it sent"
            );
            assert!(!current.consumed, "{frame:?} consumed a consumed challenge");
            assert!(
                self.now < current.expires,
                "{frame:?} consumed an expired challenge"
            );
            let verified = match decoded {
                Some((id, Message::AuthenticatedDiagnosticControl { control, tag })) => {
                    self.stats.commands_taken += 1;
                    id.destination == NODE_ID
                        && self.auth.verify_command(
                            NODE_ID,
                            DIAGNOSTIC_CONTROL,
                            current.nonce,
                            &control_payload(control),
                            &tag,
                        )
                }
                Some((id, Message::TransferOpen(open))) => {
                    let ok = id.source == protocol::TOOL
                        && id.destination == NODE_ID
                        && self.auth.verify_open(
                            NODE_ID,
                            current.nonce,
                            open.length,
                            open.flags,
                            &open.tag,
                        );
                    if ok {
                        self.opens.push(current.nonce);
                        self.stats.opens_taken += 1;
                    }
                    ok
                }
                _ => false,
            };
            assert!(
                verified,
                "{frame:?} consumed the challenge without a tag over its exchange"
            );
            assert!(
                self.consumed_by.insert(frame_key(frame)),
                "{frame:?} consumed a challenge a second time (a replay applied)"
            );
            if let Some(current) = self.current.as_mut() {
                current.consumed = true;
            }
            self.checks_seen.push_back(self.now);
        }

        // The diagnostic setting changes only through a consuming DiagnosticControl.
        match decoded {
            Some((_, Message::AuthenticatedDiagnosticControl { control, .. })) if consumed => {
                let expected = (control.rate_hz != 0 && control.ports != 0)
                    .then(|| (SECOND / u64::from(control.rate_hz), control.ports));
                assert_eq!(post.diagnostic, expected, "the setting after {control:?}");
            }
            _ => assert_eq!(
                post.diagnostic, pre.diagnostic,
                "the diagnostic setting changed during {frame:?}"
            ),
        }

        // The running table changes only through an opened, MACed transfer, once per open.
        let table = |key: Option<(u32, u32, bool)>| key.map(|(version, crc, _)| (version, crc));
        if table(post_running) != table(pre_running) {
            assert!(
                matches!(decoded, Some((id, Message::TableTransfer { .. }))
                    if id.source == protocol::TOOL && id.destination == NODE_ID),
                "the table changed during {frame:?}"
            );
            let image = self.node.image_to_store();
            let open = self
                .macs
                .iter()
                .filter(|(nonce, bytes)| {
                    bytes.as_slice() == image
                        && self.opens.contains(nonce)
                        && !self.applied_opens.contains(nonce)
                })
                .map(|(nonce, _)| *nonce)
                .next();
            let open = open.unwrap_or_else(|| {
                panic!(
                    "a table of {} bytes swapped in that no open carried",
                    image.len()
                )
            });
            self.applied_opens.insert(open);
            self.stats.swaps += 1;
        }

        // Receipts verify over an opened transfer's exchange.
        self.statuses.extend(statuses.iter().copied());
        while self.statuses.len() > 8 {
            self.statuses.pop_front();
        }
        for (destination, tag) in receipts {
            assert_eq!(destination, protocol::TOOL, "a Receipt to {destination}");
            let states: Vec<(u32, bool)> = [pre_running, post_running]
                .iter()
                .map(|key| key.map_or((0, false), |(_, crc, stored)| (crc, stored)))
                .collect();
            let verifies = self.opens.iter().any(|&nonce| {
                self.statuses.iter().any(|status| {
                    states.iter().any(|&(crc, stored)| {
                        self.auth
                            .verify_receipt(NODE_ID, nonce, status, crc, stored, &tag)
                    })
                })
            });
            assert!(verifies, "a Receipt that verifies over no opened transfer");
            self.stats.receipts += 1;
        }

        // The budget.
        assert!(
            post.checks_in_window <= TAG_CHECKS_PER_SECOND,
            "{} checks in one window",
            post.checks_in_window
        );
        let spent = if post.window_start == pre.window_start {
            assert!(post.checks_in_window >= pre.checks_in_window);
            post.checks_in_window - pre.checks_in_window
        } else {
            assert_eq!(post.window_start, at, "the window moved to another time");
            assert!(
                at.micros_since(pre.window_start)
                    .is_some_and(|elapsed| elapsed >= SECOND),
                "a new window less than a second after the last"
            );
            post.checks_in_window
        };
        if post.checks_in_window == TAG_CHECKS_PER_SECOND {
            self.stats.budget_full += 1;
        }
        let paid = u16::from(issued) + u16::from(consumed);
        assert!(spent >= paid, "{paid} checks made, {spent} paid for");
        if frame.is_none() {
            assert_eq!(spent, 0, "checks without a message");
        }
        while self
            .checks_seen
            .front()
            .is_some_and(|&t| t + SECOND <= self.now)
        {
            self.checks_seen.pop_front();
        }
        assert!(
            self.checks_seen.len() <= 2 * usize::from(TAG_CHECKS_PER_SECOND),
            "{} challenges made or consumed within a second",
            self.checks_seen.len()
        );
        if matches!(input, Input::Poll | Input::Stored) {
            assert_eq!(
                table(post_running),
                table(pre_running),
                "the table changed without a frame"
            );
        }
        step
    }

    /// Time passes up to `t` (later): the node is polled at each deadline on the way.
    fn advance(&mut self, t: u64) {
        for _ in 0..2_000 {
            let deadline = self.node.deadline(self.at()).as_micros();
            if deadline > t || deadline < self.now {
                break;
            }
            self.now = deadline;
            self.poll();
        }
        self.now = t;
        self.poll();
    }

    /// Asks for a challenge from the tool with a nonce of the harness's own: the exchange nonce,
    /// if the node answered.
    fn request(&mut self) -> Option<u64> {
        self.next_tool_nonce = self.next_tool_nonce.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let frame = Message::ChallengeRequest {
            tool_nonce: self.next_tool_nonce,
        }
        .to_frame(protocol::TOOL, NODE_ID);
        let before = self.current.map(|current| current.nonce);
        self.feed(&frame);
        self.current
            .map(|current| current.nonce)
            .filter(|&nonce| Some(nonce) != before)
    }

    /// Feeds a frame the harness built as the key holder over the exchange nonce `nonce`; checks
    /// it was taken when that is the fresh challenge and the budget had room (the converse of
    /// the consumption property).
    fn feed_genuine(&mut self, frame: &Frame, nonce: u64) {
        let room = self.budget_room(&self.node.auth_probe());
        let fresh = self.fresh() == Some(nonce);
        let before = self.node.auth_probe().challenge;
        self.genuine.push(*frame);
        self.feed(frame);
        if fresh && room && before.is_some() {
            assert!(
                self.current.is_some_and(|current| current.consumed),
                "a genuine {frame:?} over the fresh challenge was refused"
            );
        }
    }

    /// A keyed push of `image` as `pabctl push --key` does it, with `tamper` (frame index,
    /// replacement or none to drop) and `reask` (ask for a challenge again after the open).
    fn push(
        &mut self,
        image: &[u8],
        flags: u8,
        nonce: Option<u64>,
        tamper: Option<(usize, Option<[u8; 8]>)>,
        reask: bool,
    ) {
        let nonce = match nonce.or_else(|| self.request()) {
            Some(nonce) => nonce,
            None => return,
        };
        let mut message = image.to_vec();
        message.extend_from_slice(&self.auth.image_mac(NODE_ID, nonce, flags, image));
        self.macs.push((nonce, image.to_vec()));
        let Ok(length) = u16::try_from(message.len()) else {
            return;
        };
        let open = TransferOpen {
            length,
            flags,
            tag: self.auth.open_tag(NODE_ID, nonce, length, flags),
        };
        self.feed_genuine(
            &Message::TransferOpen(open).to_frame(protocol::TOOL, NODE_ID),
            nonce,
        );
        if reask {
            // A rogue (or the tool itself) asks again: the opened transfer goes on.
            self.request();
        }
        let Ok(mut sender) = Sender::new(&message, TxConfig::default()) else {
            return;
        };
        self.flow_controls.clear();
        let mut seen = 0;
        let mut index = 0;
        for _ in 0..10_000 {
            match sender.poll(self.at()) {
                TxEvent::Send(data) => {
                    let data = match tamper {
                        Some((at, replacement)) if at == index => replacement,
                        _ => Some(data),
                    };
                    index += 1;
                    if let Some(data) = data {
                        let frame = Message::TableTransfer { data, len: 8 }
                            .to_frame(protocol::TOOL, NODE_ID);
                        self.genuine.push(frame);
                        self.feed(&frame);
                    }
                    self.advance(self.now + 100);
                }
                TxEvent::WaitUntil(until) => {
                    if let Some(fc) = self.flow_controls.get(seen).copied() {
                        seen += 1;
                        sender.on_flow_control(&fc, self.at());
                    } else {
                        let wait = until
                            .as_micros()
                            .saturating_sub(self.now)
                            .clamp(1, 2 * SECOND);
                        self.advance(self.now + wait);
                    }
                }
                TxEvent::Done | TxEvent::Failed(_) => break,
            }
            if self.store_owed {
                self.finish_store(true);
            }
        }
    }
}

fn control_payload(control: DiagnosticControl) -> [u8; 4] {
    let [r0, r1] = control.rate_hz.to_le_bytes();
    let [p0, p1] = control.ports.to_le_bytes();
    [r0, r1, p0, p1]
}

fn setup(u: &mut Unstructured<'_>) -> Result<World> {
    let key = Key::from_bytes(u.arbitrary()?);
    let salt: u32 = u.arbitrary()?;
    let start: u64 = if u.ratio(1u8, 4)? {
        u.int_in_range(0..=1 << 40)?
    } else {
        0
    };
    let config = Config::new(NODE_ID).expect("node 5 is valid");
    let mut node = TestNode::new(config, Instant::from_micros(start));
    node.set_key(&key, salt);
    // Boot with one of the examples' images, or none.
    if u.ratio(1u8, 2)? {
        let bytes = crate::image::fix_up(&mutated_image(u, 0)?);
        if bytes.len() <= IMG {
            node.boot_buffer()[..bytes.len()].copy_from_slice(&bytes);
            node.boot(Some(bytes.len()), Instant::from_micros(start));
        } else {
            node.boot(None, Instant::from_micros(start));
        }
    } else {
        node.boot(None, Instant::from_micros(start));
    }
    let mut world = World {
        node,
        auth: Authenticator::new(&key),
        now: start,
        current: None,
        old_nonces: Vec::new(),
        node_nonces: HashSet::new(),
        opens: Vec::new(),
        applied_opens: HashSet::new(),
        macs: Vec::new(),
        genuine: Vec::new(),
        consumed_by: HashSet::new(),
        statuses: VecDeque::new(),
        checks_seen: VecDeque::new(),
        store_owed: false,
        stored_ok: None,
        next_tool_nonce: u.arbitrary()?,
        flow_controls: Vec::new(),
        stats: Stats::default(),
    };
    world.poll();
    Ok(world)
}

fn script(u: &mut Unstructured<'_>, world: &mut World) -> Result<()> {
    for _ in 0..200 {
        if u.is_empty() {
            break;
        }
        match u.int_in_range(0u8..=15)? {
            // Arbitrary frames.
            0 => {
                let id = any_id(u)?;
                let data = payload(u)?;
                let frame = Frame::data(id, &data).unwrap_or_else(|| unreachable!("8 bytes"));
                world.feed(&frame);
            }
            1 => {
                let frame = protocol_frame(u)?;
                world.feed(&frame);
            }
            // Challenge requests: the harness's own, or anyone's with any nonce.
            2..=3 => {
                if u.ratio(1u8, 2)? {
                    world.request();
                } else {
                    let source = if u.ratio(1u8, 2)? {
                        protocol::TOOL
                    } else {
                        u.arbitrary()?
                    };
                    let destination = if u.ratio(3u8, 4)? {
                        NODE_ID
                    } else {
                        u.arbitrary()?
                    };
                    let frame = Message::ChallengeRequest {
                        tool_nonce: u.arbitrary()?,
                    }
                    .to_frame(source, destination);
                    world.feed(&frame);
                }
            }
            // A tagged DiagnosticControl: genuine, or a wrong tag.
            4..=6 => {
                let control = DiagnosticControl {
                    rate_hz: u.int_in_range(0..=200)?,
                    ports: if u.ratio(1u8, 4)? { 0 } else { u.arbitrary()? },
                };
                let payload = control_payload(control);
                let (nonce, genuine) = match u.int_in_range(0u8..=7)? {
                    0..=4 => match world.fresh() {
                        Some(nonce) => (nonce, true),
                        None => match world.request() {
                            Some(nonce) => (nonce, true),
                            None => (u.arbitrary()?, false),
                        },
                    },
                    5 if !world.old_nonces.is_empty() => (*u.choose(&world.old_nonces)?, false),
                    _ => (u.arbitrary()?, false),
                };
                let mut tag = world
                    .auth
                    .command_tag(NODE_ID, DIAGNOSTIC_CONTROL, nonce, &payload);
                let flip = u.ratio(1u8, 8)?;
                if flip {
                    let bit: u8 = u.int_in_range(0..=31)?;
                    tag[usize::from(bit / 8)] ^= 1 << (bit % 8);
                }
                let destination = if u.ratio(7u8, 8)? {
                    NODE_ID
                } else {
                    protocol::BROADCAST
                };
                let frame = Message::AuthenticatedDiagnosticControl { control, tag }
                    .to_frame(protocol::TOOL, destination);
                if genuine && !flip && destination == NODE_ID {
                    world.feed_genuine(&frame, nonce);
                } else {
                    world.feed(&frame);
                }
            }
            // A keyed push of an example's image.
            7..=8 => {
                let version = world.node.running().map_or(0, |r| r.header.table_version);
                let image = mutated_image(u, version)?;
                let flags = if u.ratio(1u8, 8)? { OPEN_REPLACE } else { 0 };
                let nonce = match u.int_in_range(0u8..=7)? {
                    0 if !world.old_nonces.is_empty() => Some(*u.choose(&world.old_nonces)?),
                    1 => Some(u.arbitrary()?),
                    _ => None,
                };
                let tamper = if u.ratio(1u8, 6)? {
                    let at = u.int_in_range(0..=image.len() / 7 + 2)?;
                    let replacement = if u.arbitrary()? {
                        Some(u.arbitrary()?)
                    } else {
                        None
                    };
                    Some((at, replacement))
                } else {
                    None
                };
                let reask = u.ratio(1u8, 8)?;
                world.push(&image, flags, nonce, tamper, reask);
            }
            // A TransferOpen with a wrong or made-up tag.
            9 => {
                let open = TransferOpen {
                    length: u.arbitrary()?,
                    flags: u.int_in_range(0..=3)?,
                    tag: u.arbitrary()?,
                };
                let source = if u.ratio(3u8, 4)? {
                    protocol::TOOL
                } else {
                    u.arbitrary()?
                };
                world.feed(&Message::TransferOpen(open).to_frame(source, NODE_ID));
            }
            // Replays of genuine frames.
            10..=11 => {
                if !world.genuine.is_empty() {
                    let frame = *u.choose(&world.genuine)?;
                    world.feed(&frame);
                }
            }
            // Time.
            12..=13 => {
                let forward = match u.int_in_range(0u8..=3)? {
                    0..=1 => u.int_in_range(0..=2_000)?,
                    2 => u.int_in_range(0..=1_100_000)?,
                    _ => u.int_in_range(0..=5_000_000)?,
                };
                world.advance(world.now + forward);
            }
            // A burst of requests (the budget).
            14 => {
                let n = u.int_in_range(1..=250)?;
                let tool_nonce: u64 = u.arbitrary()?;
                for k in 0..n {
                    let frame = Message::ChallengeRequest {
                        tool_nonce: tool_nonce.wrapping_add(k),
                    }
                    .to_frame(protocol::TOOL, NODE_ID);
                    world.feed(&frame);
                    world.now += u64::from(u.int_in_range(0u8..=50)?);
                }
            }
            _ => {
                let ok = u.int_in_range(0u8..=7)? > 0;
                world.finish_store(ok);
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The script is not blind: over pseudo-random inputs the harness, as the key holder, gets
    /// challenges, commands and opens taken, tables swapped in and receipts (so the properties
    /// above are exercised, not vacuously true).
    #[test]
    fn random_scripts_reach_the_key_holders_paths() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut total = Stats::default();
        for _ in 0..200 {
            let bytes: Vec<u8> = (0..4_000)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    (x >> 24) as u8
                })
                .collect();
            let stats = run(&mut Unstructured::new(&bytes)).expect("a set-up from 4000 bytes");
            total.challenges += stats.challenges;
            total.commands_taken += stats.commands_taken;
            total.opens_taken += stats.opens_taken;
            total.swaps += stats.swaps;
            total.receipts += stats.receipts;
            total.budget_full += stats.budget_full;
        }
        eprintln!("{total:?}");
        assert!(total.challenges > 0, "{total:?}");
        assert!(total.commands_taken > 0, "{total:?}");
        assert!(total.opens_taken > 0, "{total:?}");
        assert!(total.swaps > 0, "{total:?}");
        assert!(total.receipts > 0, "{total:?}");
        assert!(total.budget_full > 0, "{total:?}");
    }
}
