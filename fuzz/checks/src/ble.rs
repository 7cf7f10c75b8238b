//! Broadcast of Local Eligibility on the board (`pab_core::ble` in a `pab_core::Arbiter` of board
//! capacities) under a script of operations: frames on the groups' local topics and their
//! behaviours' topics (arbitrated, then shown to `ble_frame`, as the node does), peers' claims
//! (well formed, mutated, or any frame of ours, through `Claim::decode`), `ble_poll`, resets, and
//! time that moves forwards in steps of a microsecond to years, from any start (across the
//! counter's wrap).
//!
//! The table has 1 to 4 groups, each on its own port: connection 0 (the behaviour, "OBS") delivers
//! iff OBS & the group's claim (connection 1); OBS is the gated connection. Numbers, node ids,
//! periods (1 µs to an hour), local topics (sometimes shared by two groups, sometimes OBS's own),
//! eligibility fields and OBS's parameters come from the input.
//!
//! The expectations come from a reference kept here in plain `u64` microseconds since the start
//! (no `Instant`, no wrap): per group the node's last reading, the last claim of every peer, the
//! next broadcast on the period grid, and what was decided at the last event. Properties, after
//! every operation:
//!
//! - **Decoding**: any frame decodes as the frame layout of `pab_core::ble` says (a decoder written
//!   here from it: kind, marker and claim bit, priority, length, node, eligibility twice, reserved
//!   byte, in that order of errors), and a decoded claim encodes back to the same frame.
//! - **Holding**: `holds` is what the reference decides at the last local reading, claim or poll:
//!   own reading fresh (younger than two periods), offered > 0 (the reading, while OBS is
//!   active), and no fresh peer ranking better (higher eligibility, or equal and a lower id). The
//!   claim connection is active, and OBS selected, exactly as that says. A claim from its own id
//!   is refused with `OwnIdClash`, others are kept.
//! - **More peers than room** (more than `MAX_PEERS` distinct ones heard): `TooManyPeers` only when
//!   `MAX_PEERS` fresh peers rank above the newcomer; a node never holds right after hearing a
//!   fresh claim better than its offer; holding still needs a fresh reading and a positive offer.
//! - **Broadcasts**: a poll sends at most one claim per group, carrying the group's number and the
//!   node's id and the eligibility offered (0 once the reading is stale), exactly when due on the
//!   grid of the first (restarted after a gap of a period or more); two claims of a group two
//!   sends apart are more than a period apart.
//! - **Deadline**: `ble_deadline` is never before now, a poll before it sends nothing, and it is
//!   the earliest of the next broadcast and the next expiry of a reading or kept claim (with more
//!   peers than room: no later than the broadcast and the reading's expiry).

use std::collections::{BTreeMap, BTreeSet};

use arbitrary::{Result, Unstructured};
use embedded_can::{ExtendedId, Id, StandardId};
use pab_core::ble::{
    BleError, CLAIM_SLOT_FILTER, Claim, ClaimError, EligibilityField, Group, GroupPort, MAX_GROUPS,
    MAX_PEERS, MAX_PERIOD_US,
};
use pab_core::integrator::MAX_TIME_US;
use pab_core::{
    Arbiter, BOARD_CONNECTIONS, BOARD_DECISION_NODES, BOARD_PORTS, Connection, DecisionNode,
    Filter, Frame, Gain, Instant, NodeRef, Stimulation, Table,
};

type BoardTable = Table<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;
type BoardArbiter = Arbiter<BOARD_PORTS, BOARD_CONNECTIONS, BOARD_DECISION_NODES>;

/// Time never runs further than this from the start: `Instant` compares instants less than
/// 2^63 µs apart (a claim older than that would look recent again, after 292 000 years).
const HORIZON: u64 = 1 << 62;
/// OBS's topic for the group at port `g`: 0x180 + g (standard).
const OBS_BASE: u32 = 0x180;
/// Local topics are 0x190..=0x193 (standard): groups may share one.
const LOCAL_BASE: u32 = 0x190;

/// Runs the fuzzer's script against one arbiter.
pub fn check(data: &[u8]) {
    let _ = features(data);
}

/// Runs the check and names what the script reached (a reading, a claim held, a grid restart, a
/// refused claim, ...): the seed generator (`examples/seeds.rs`) keeps scripts that reach
/// something new.
pub fn features(data: &[u8]) -> BTreeSet<&'static str> {
    let mut seen = BTreeSet::new();
    let _ = run(&mut Unstructured::new(data), &mut seen);
    seen
}

/// The claim fields the frame layout documents (`core/src/ble.rs`, "The frame ranks itself"),
/// read from a frame without `pab_core::ble`'s decoder.
fn reference_decode(frame: &Frame) -> std::result::Result<Claim, ClaimError> {
    let Id::Extended(id) = frame.id() else {
        return Err(ClaimError::NotAClaim);
    };
    let raw = id.as_raw();
    // Bits 25..24 the marker 0b10, bit 23 the claim bit; remote frames are not claims.
    if (raw >> 23) & 0b111 != 0b101 || frame.is_remote() {
        return Err(ClaimError::NotAClaim);
    }
    // Priority 4 (NOMINAL), bits 28..26.
    if raw >> 26 != 4 {
        return Err(ClaimError::WrongPriority);
    }
    let payload = frame.payload();
    if payload.len() != 4 {
        return Err(ClaimError::WrongLength);
    }
    let node = (raw % 128) as u8;
    if node == 0 {
        return Err(ClaimError::BadNode);
    }
    let inverted = (raw >> 7) % 65_536;
    let eligibility = (65_535 - inverted) as u16;
    if u16::from(payload[1]) + 256 * u16::from(payload[2]) != eligibility {
        return Err(ClaimError::Mismatch);
    }
    if payload[3] != 0 {
        return Err(ClaimError::Reserved);
    }
    Ok(Claim {
        group: payload[0],
        node,
        eligibility,
    })
}

/// Whether `a` ranks strictly above `b`, from the module's documentation.
fn better(a: (u16, u8), b: (u16, u8)) -> bool {
    a.0 > b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// The reference's view of one group. Times are µs since the run's start.
#[derive(Default)]
struct Model {
    /// The node's last reading and when.
    own: Option<(u16, u64)>,
    /// Every peer's last claim (eligibility, when heard), by node id.
    peers: BTreeMap<u8, (u16, u64)>,
    /// The next broadcast's due time; `None` before the first.
    due: Option<u64>,
    /// When the claims were sent.
    sent: Vec<u64>,
    /// More distinct peers were heard than the arbiter keeps (since the last reset).
    overflow: bool,
    /// Whether the node holds the task, as decided at the last event.
    holds: bool,
    /// What the node offered at the last event.
    offer: u16,
}

struct World {
    arbiter: BoardArbiter,
    groups: Vec<Group>,
    models: Vec<Model>,
    /// Each group's pool of peer ids (its own id sometimes among them).
    pools: Vec<Vec<u8>>,
    start: u64,
    /// µs since the start.
    now: u64,
    /// The deadline the arbiter gave after the last operation, in µs since the start.
    deadline: u64,
    /// What the script reached ([`features`]).
    seen: BTreeSet<&'static str>,
}

impl World {
    fn at(&self, elapsed: u64) -> Instant {
        Instant::from_micros(self.start.wrapping_add(elapsed))
    }

    fn period(&self, g: usize) -> u64 {
        u64::from(self.groups[g].period_us)
    }

    fn fresh(&self, g: usize, heard: u64) -> bool {
        self.now - heard < 2 * self.period(g)
    }

    /// OBS of group `g`'s port is active now (the integrator's business: read from the arbiter).
    fn obs_active(&self, g: usize) -> bool {
        self.arbiter
            .activity(g as u8, self.at(self.now))
            .contains(0)
    }

    /// The reading, if fresh.
    fn own(&self, g: usize) -> Option<u16> {
        self.models[g]
            .own
            .filter(|&(_, at)| self.fresh(g, at))
            .map(|(value, _)| value)
    }

    /// What the node offers now: its fresh reading while OBS (the gated connection) is active.
    fn offered(&self, g: usize) -> u16 {
        match self.own(g) {
            Some(value) if self.obs_active(g) => value,
            _ => 0,
        }
    }

    /// The fresh peers ranking above `offered` from this node.
    fn better_peers(&self, g: usize, offered: u16) -> usize {
        let mine = (offered, self.groups[g].node);
        self.models[g]
            .peers
            .iter()
            .filter(|&(&node, &(eligibility, at))| {
                self.fresh(g, at) && better((eligibility, node), mine)
            })
            .count()
    }

    /// Every group's holding decided now, as the reference sees it.
    fn decide(&mut self) {
        for g in 0..self.groups.len() {
            let offered = self.offered(g);
            self.models[g].holds = offered > 0 && self.better_peers(g, offered) == 0;
            self.models[g].offer = offered;
        }
    }

    /// The properties that hold between operations.
    fn verify(&mut self) {
        let now = self.at(self.now);
        for g in 0..self.groups.len() {
            let holds = self.arbiter.holds(g);
            let model = &self.models[g];
            if model.overflow {
                // The arbiter may have dropped a claim that is still fresh; the reading and the
                // offer are still the node's own.
                assert!(
                    !holds || model.offer > 0,
                    "group {g} holds offering 0 (own {:?}, at {} µs)",
                    model.own,
                    self.now
                );
            } else {
                assert_eq!(
                    holds, model.holds,
                    "group {g} holds (at {} µs; own {:?}, peers {:?})",
                    self.now, model.own, model.peers
                );
            }
            if holds {
                self.seen.insert("holds");
            }
            if self.models[g].overflow {
                self.seen.insert("overflow");
            }
            let activity = self.arbiter.activity(g as u8, now);
            assert_eq!(activity.contains(1), holds, "group {g}'s claim connection");
            let selected = activity.contains(0) && holds;
            assert_eq!(
                self.arbiter.selected(g as u8, now),
                selected.then_some(0),
                "port {g}: OBS delivers iff OBS & the claim"
            );
        }
        assert!(!self.arbiter.holds(self.groups.len()), "no such group");
        assert!(!self.arbiter.holds(usize::MAX), "no such group");
        // The deadline.
        let deadline = self
            .arbiter
            .ble_deadline(now)
            .expect("a table with groups has a deadline");
        let ahead = deadline
            .micros_since(now)
            .unwrap_or_else(|| panic!("deadline {deadline:?} before now {now:?}"));
        // Exact without overflow; with it, the kept claims are some of the reference's (each
        // peer's latest), so the deadline is no earlier than the reference's and no later than
        // the broadcasts, the readings and the claims of groups without overflow.
        let mut expected = u64::MAX;
        let mut bound = u64::MAX;
        let mut exact = true;
        for (g, model) in self.models.iter().enumerate() {
            let fresh = 2 * self.period(g);
            let due = model.due.map_or(0, |due| due.saturating_sub(self.now));
            let own = model
                .own
                .map(|(_, at)| at + fresh)
                .filter(|&expiry| expiry > self.now)
                .map_or(u64::MAX, |expiry| expiry - self.now);
            let peers = model
                .peers
                .values()
                .map(|&(_, at)| at + fresh)
                .filter(|&expiry| expiry > self.now)
                .map(|expiry| expiry - self.now)
                .min()
                .unwrap_or(u64::MAX);
            bound = bound.min(due).min(own);
            if !model.overflow {
                bound = bound.min(peers);
            }
            expected = expected.min(due).min(own).min(peers);
            exact &= !model.overflow;
        }
        if exact {
            assert_eq!(ahead, expected, "ble_deadline at {} µs", self.now);
        } else {
            assert!(
                expected <= ahead && ahead <= bound,
                "ble_deadline {ahead} µs ahead, not in [{expected}, {bound}]"
            );
        }
        if ahead == 0 {
            self.seen.insert("deadline now");
        }
        self.deadline = self.now + ahead;
    }

    /// A frame that is not ours, arbitrated then shown to the groups, as the node does.
    fn frame(&mut self, frame: &Frame) {
        let now = self.at(self.now);
        let _ = self.arbiter.receive(&frame.id(), now, |_| {});
        self.arbiter.ble_frame(frame, now);
        let mut read = false;
        for g in 0..self.groups.len() {
            let group = &self.groups[g];
            if frame.id() != Id::Standard(StandardId::new(group_local(group)).expect("11 bits")) {
                continue;
            }
            let field = group.field;
            let start = usize::from(field.offset);
            let value = match field.size {
                1 => frame.payload().get(start).map(|&b| u16::from(b)),
                _ => frame.payload().get(start..start + 2).map(|b| {
                    let (high, low) = if field.big_endian {
                        (b[0], b[1])
                    } else {
                        (b[1], b[0])
                    };
                    u16::from(high) * 256 + u16::from(low)
                }),
            };
            if let Some(value) = value {
                self.seen
                    .insert(if read { "shared topic" } else { "reading" });
                self.models[g].own = Some((value, self.now));
                read = true;
            } else {
                self.seen.insert("short reading");
            }
        }
        if read {
            self.decide();
        }
    }

    /// A frame of ours from the bus: a claim goes to `on_claim`, anything else is dropped.
    fn ours(&mut self, frame: &Frame) {
        let decoded = Claim::decode(frame);
        assert_eq!(decoded, reference_decode(frame), "decoding {frame:?}");
        let claim = match decoded {
            Ok(claim) => claim,
            Err(error) => {
                self.seen.insert(match error {
                    ClaimError::NotAClaim => "not a claim",
                    ClaimError::WrongPriority => "wrong priority",
                    ClaimError::WrongLength => "wrong length",
                    ClaimError::BadNode => "bad node",
                    ClaimError::Mismatch => "mismatch",
                    ClaimError::Reserved => "reserved",
                });
                return;
            }
        };
        assert_eq!(claim.frame(), Some(*frame), "{claim:?} encodes back");
        let now = self.at(self.now);
        let outcome = self.arbiter.on_claim(claim, now);
        let Some(g) = self.groups.iter().position(|g| g.number == claim.group) else {
            assert_eq!(outcome, Ok(()), "a claim of another group");
            self.seen.insert("claim of another group");
            self.decide();
            return;
        };
        if claim.node == self.groups[g].node {
            assert_eq!(
                outcome,
                Err(BleError::OwnIdClash),
                "{claim:?} carries our id"
            );
            self.seen.insert("own id clash");
            self.decide();
            return;
        }
        // Before this claim is counted: the fresh peers above it, its sender's older claim
        // excluded.
        let above = self.models[g]
            .peers
            .iter()
            .filter(|&(&node, &(eligibility, at))| {
                node != claim.node
                    && self.fresh(g, at)
                    && better((eligibility, node), (claim.eligibility, claim.node))
            })
            .count();
        let model = &mut self.models[g];
        model
            .peers
            .insert(claim.node, (claim.eligibility, self.now));
        if model.peers.len() > MAX_PEERS {
            model.overflow = true;
        }
        match outcome {
            Ok(()) => {
                self.seen.insert("claim kept");
            }
            Err(BleError::TooManyPeers) => {
                self.seen.insert("too many peers");
                assert!(
                    self.models[g].overflow,
                    "{claim:?} refused with room for {MAX_PEERS} peers"
                );
                assert!(
                    above >= MAX_PEERS,
                    "{claim:?} refused with only {above} fresh peers above it"
                );
            }
            Err(error) => panic!("{claim:?}: {error:?}"),
        }
        self.decide();
        // Whatever the room: right after hearing a fresh claim better than its offer, the node
        // does not hold.
        let offered = self.offered(g);
        if better(
            (claim.eligibility, claim.node),
            (offered, self.groups[g].node),
        ) {
            assert!(
                !self.arbiter.holds(g),
                "group {g} holds right after {claim:?} (offering {offered})"
            );
            if offered > 0 {
                self.seen.insert("outranked");
            }
        }
    }

    fn poll(&mut self) {
        let now = self.at(self.now);
        let mut sent = Vec::new();
        // Offers are read before the poll changes anything.
        let offered: Vec<u16> = (0..self.groups.len()).map(|g| self.offered(g)).collect();
        self.arbiter.ble_poll(now, |claim| sent.push(claim));
        if self.now < self.deadline {
            self.seen.insert("early poll");
            assert!(
                sent.is_empty(),
                "a poll at {} µs, before the deadline {} µs, sent {sent:?}",
                self.now,
                self.deadline
            );
        }
        let mut expected = Vec::new();
        for (g, group) in self.groups.iter().enumerate() {
            let period = u64::from(group.period_us);
            let model = &mut self.models[g];
            let due = match model.due {
                None => Some(self.now),
                Some(due) if self.now >= due => Some(if self.now - due < period {
                    due
                } else {
                    self.seen.insert("grid restart");
                    self.now
                }),
                Some(_) => None,
            };
            if let Some(base) = due {
                model.due = Some(base + period);
                self.seen.insert(if offered[g] > 0 {
                    "sent positive"
                } else {
                    "sent zero"
                });
                model.sent.push(self.now);
                expected.push(Claim {
                    group: group.number,
                    node: group.node,
                    eligibility: offered[g],
                });
                if let &[.., two_before, _, last] = model.sent.as_slice() {
                    assert!(
                        last - two_before > period,
                        "group {g}: claims at {two_before} and {last} µs, period {period}"
                    );
                }
            }
        }
        for claim in &sent {
            let group = self
                .groups
                .iter()
                .find(|group| group.number == claim.group)
                .unwrap_or_else(|| panic!("{claim:?} of no group of ours"));
            assert_eq!(claim.node, group.node, "{claim:?} carries our id");
            let frame = claim
                .frame()
                .unwrap_or_else(|| panic!("{claim:?} has no frame"));
            assert_eq!(Claim::decode(&frame), Ok(*claim));
            assert_eq!(reference_decode(&frame), Ok(*claim));
        }
        assert_eq!(sent, expected, "claims sent at {} µs", self.now);
        self.decide();
    }

    fn reset(&mut self) {
        self.seen.insert("reset");
        self.arbiter.reset();
        for model in &mut self.models {
            *model = Model::default();
        }
    }

    /// Time moves on by `step`; with `polled`, the arbiter is polled at each deadline on the way
    /// (a node's loop), a bounded number of times.
    fn advance(&mut self, step: u64, polled: bool) {
        let target = self.now + step.min(HORIZON - self.now);
        if polled {
            for _ in 0..64 {
                if self.deadline > target || self.deadline <= self.now {
                    break;
                }
                self.now = self.deadline;
                self.poll();
                self.verify();
            }
        }
        if self.start.checked_add(target).is_none() && self.start.checked_add(self.now).is_some() {
            self.seen.insert("counter wraps");
        }
        if step > 1 << 32 {
            self.seen.insert("long jump");
        }
        self.now = target;
    }
}

fn group_local(group: &Group) -> u16 {
    // The local filter is exact on a standard id; read it back from the table's group.
    group.local.id() as u16
}

fn group(u: &mut Unstructured<'_>, index: u8, used: &[u8]) -> Result<Group> {
    let mut number: u8 = u.arbitrary()?;
    while used.contains(&number) {
        number = number.wrapping_add(1);
    }
    let period_us = match u.int_in_range(0u8..=7)? {
        0..=2 => u.int_in_range(1..=2_000)?,
        3..=5 => 100_000,
        6 => u.int_in_range(1..=MAX_PERIOD_US)?,
        _ => MAX_PERIOD_US,
    };
    let local = if u.ratio(1u8, 4)? {
        OBS_BASE + u32::from(index)
    } else {
        LOCAL_BASE + u32::from(u.int_in_range(0u8..=3)?)
    };
    let size = u.int_in_range(1u8..=2)?;
    Ok(Group {
        number,
        node: u.int_in_range(1..=127)?,
        period_us,
        local: Filter::exact(local, false).expect("a standard id"),
        field: EligibilityField {
            offset: u.int_in_range(0..=8 - size)?,
            size,
            big_endian: u.arbitrary()?,
        },
        peers: u.int_in_range(0..=MAX_PEERS as u8)?,
        ports: [GroupPort {
            port: index,
            claim: 1,
            gated: 0b01,
        }]
        .into_iter()
        .collect(),
    })
}

fn obs(u: &mut Unstructured<'_>, index: u8) -> Result<Connection> {
    let gain = if u.ratio(3u8, 4)? {
        Gain::ONE
    } else {
        Gain::from_raw(u.int_in_range(1 << 15..=1 << 31)?).unwrap_or(Gain::ONE)
    };
    let decay = match u.int_in_range(0u8..=3)? {
        0..=1 => 500_000,
        2 => u.int_in_range(1..=5_000)?,
        _ => u.int_in_range(1..=MAX_TIME_US)?,
    };
    let rest = if u.ratio(1u8, 4)? {
        u.int_in_range(0..=200_000)?
    } else {
        0
    };
    Ok(Connection {
        filter: Filter::exact(OBS_BASE + u32::from(index), false).expect("a standard id"),
        stimulation: Stimulation::new(gain, decay, rest).expect("valid parameters"),
    })
}

fn payload(u: &mut Unstructured<'_>) -> Result<Vec<u8>> {
    let len = u.int_in_range(0..=8)?;
    (0..len).map(|_| u.arbitrary()).collect()
}

/// A frame of ours: mostly a well-formed claim of a group (or another), from the group's pool of
/// peers, sometimes changed a little; or any identifier with our marker.
fn claim_frame(u: &mut Unstructured<'_>, world: &World) -> Result<Frame> {
    let g = u.choose_index(world.groups.len())?;
    let group = if u.ratio(7u8, 8)? {
        world.groups[g].number
    } else {
        u.arbitrary()?
    };
    let node = *u.choose(&world.pools[g])?;
    let eligibility = match u.int_in_range(0u8..=5)? {
        0 => 0,
        1 => u16::MAX,
        2..=3 => u.int_in_range(0..=8)?,
        _ => u.arbitrary()?,
    };
    let claim = Claim {
        group,
        node,
        eligibility,
    };
    let mut frame = claim.frame().expect("pool ids are 1..=127");
    match u.int_in_range(0u8..=15)? {
        0 => {
            // One bit of the identifier flipped (the marker bit 25 kept, so it stays ours).
            let (raw, _) = frame.raw_id();
            let bit = u.int_in_range(0u32..=28)?;
            let raw = if bit == 25 { raw } else { raw ^ 1 << bit };
            frame = Frame::with_raw_id(raw, true, frame.payload()).expect("29 bits");
        }
        1 => {
            let (raw, _) = frame.raw_id();
            let mut data = frame.payload().to_vec();
            let at = u.choose_index(data.len())?;
            data[at] = u.arbitrary()?;
            frame = Frame::with_raw_id(raw, true, &data).expect("4 bytes");
        }
        2 => {
            let (raw, _) = frame.raw_id();
            frame = Frame::with_raw_id(raw, true, &payload(u)?).expect("8 bytes");
        }
        3 => {
            use embedded_can::Frame as _;
            let id = ExtendedId::new(frame.raw_id().0).expect("29 bits");
            frame = Frame::new_remote(id, u.int_in_range(0..=8)?).expect("dlc of 8 at most");
        }
        4 => {
            let raw = u.int_in_range(0u32..=0x1FFF_FFFF)? | 0b10 << 24;
            frame = Frame::with_raw_id(raw, true, &payload(u)?).expect("29 bits");
        }
        _ => {}
    }
    Ok(frame)
}

fn time_step(u: &mut Unstructured<'_>, period: u64) -> Result<u64> {
    Ok(match u.int_in_range(0u8..=15)? {
        0..=5 => u.int_in_range(0..=period.min(1 << 20))?,
        6..=9 => u.int_in_range(0..=3 * period)?,
        10..=11 => u.int_in_range(0..=1_200)?,
        12..=13 => u.int_in_range(0..=10_000_000_000)?,
        14 => u.int_in_range(0..=1 << 40)?,
        _ => u.int_in_range(0..=HORIZON)?,
    })
}

fn run(u: &mut Unstructured<'_>, seen: &mut BTreeSet<&'static str>) -> Result<()> {
    let start = match u.int_in_range(0u8..=3)? {
        0 => 0,
        1 => u64::MAX - u.int_in_range(0..=1_000_000)?,
        _ => u.arbitrary()?,
    };
    let count = u.int_in_range(1..=MAX_GROUPS.min(BOARD_PORTS))?;
    let mut table = BoardTable::new();
    let claim = Connection {
        filter: CLAIM_SLOT_FILTER,
        stimulation: Stimulation::new(Gain::ONE, 1_000_000, 0).expect("valid parameters"),
    };
    // OBS (var 0) & claim (var 1) delivers OBS.
    let nodes = [
        DecisionNode {
            var: 0,
            low: NodeRef::NOBODY,
            high: NodeRef::node(1).expect("node 1"),
        },
        DecisionNode {
            var: 1,
            low: NodeRef::NOBODY,
            high: NodeRef::deliver(0).expect("connection 0"),
        },
    ];
    let mut groups = Vec::new();
    let mut pools = Vec::new();
    for index in 0..count as u8 {
        let obs = obs(u, index)?;
        table
            .push_port(&[obs, claim], &nodes, NodeRef::node(0).expect("node 0"))
            .expect("a port of two connections fits the board");
        let used: Vec<u8> = groups.iter().map(|g: &Group| g.number).collect();
        let group = group(u, index, &used)?;
        // Peers: up to two more than the arbiter keeps; the node's own id now and then.
        let size = u.int_in_range(1..=MAX_PEERS + 2)?;
        let mut pool: Vec<u8> = Vec::new();
        for _ in 0..size {
            let mut id = u.int_in_range(1u8..=127)?;
            if id == group.node && u.ratio(3u8, 4)? {
                id = id % 127 + 1;
            }
            if !pool.contains(&id) {
                pool.push(id);
            }
        }
        pools.push(pool);
        groups.push(group);
    }
    for group in &groups {
        table
            .push_group(group.clone())
            .unwrap_or_else(|error| panic!("{group:?} refused: {error}"));
    }
    let arbiter = BoardArbiter::new(table).expect("a valid table builds an arbiter");
    assert!(arbiter.has_groups());
    let mut world = World {
        arbiter,
        models: groups.iter().map(|_| Model::default()).collect(),
        groups,
        pools,
        start,
        now: 0,
        deadline: 0,
        seen: BTreeSet::new(),
    };
    world
        .seen
        .insert(["one group", "two groups", "three groups", "four groups"][count - 1]);
    world.verify();
    let outcome = script(u, &mut world);
    seen.append(&mut world.seen);
    outcome
}

fn script(u: &mut Unstructured<'_>, world: &mut World) -> Result<()> {
    for _ in 0..400 {
        if u.is_empty() {
            break;
        }
        match u.int_in_range(0u8..=15)? {
            0..=2 => {
                // A reading on a group's local topic (maybe too short to carry the field).
                let g = u.choose_index(world.groups.len())?;
                let id = StandardId::new(group_local(&world.groups[g])).expect("11 bits");
                let frame = Frame::data(id, &payload(u)?).expect("8 bytes");
                world.frame(&frame);
            }
            3..=4 => {
                // The behaviour's output: OBS of some port.
                let g = u.choose_index(world.groups.len())?;
                let id = StandardId::new(OBS_BASE as u16 + g as u16).expect("11 bits");
                let frame = Frame::data(id, &payload(u)?).expect("8 bytes");
                world.frame(&frame);
            }
            5 => {
                // Any frame: ours goes to the claims, anything else to the arbiter.
                let id = if u.arbitrary()? {
                    Id::Standard(StandardId::new(u.int_in_range(0..=0x7FF)?).expect("11 bits"))
                } else {
                    Id::Extended(ExtendedId::new(u.int_in_range(0..=0x1FFF_FFFF)?).expect("29"))
                };
                let frame = Frame::data(id, &payload(u)?).expect("8 bytes");
                if pab_core::protocol::classify(&frame).is_ours() {
                    world.ours(&frame);
                } else {
                    world.frame(&frame);
                }
            }
            6..=9 => {
                let frame = claim_frame(u, world)?;
                world.ours(&frame);
            }
            10..=11 => world.poll(),
            12..=14 => {
                let g = u.choose_index(world.groups.len())?;
                let step = time_step(u, world.period(g))?;
                let polled = u.arbitrary()?;
                world.advance(step, polled);
            }
            _ => world.reset(),
        }
        world.verify();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_decoder_reads_the_documented_identifiers() {
        // docs/can-protocol.md, "Broadcast of Local Eligibility": node 2, eligibility 1000.
        let frame = Frame::with_raw_id(0x12FE_0B82, true, &[7, 0xE8, 0x03, 0]).expect("frame");
        assert_eq!(
            reference_decode(&frame),
            Ok(Claim {
                group: 7,
                node: 2,
                eligibility: 1000
            })
        );
        let wrong = Frame::with_raw_id(0x12FE_0B82, true, &[7, 0xE9, 0x03, 0]).expect("frame");
        assert_eq!(reference_decode(&wrong), Err(ClaimError::Mismatch));
    }
}
