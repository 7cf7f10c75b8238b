//! The frame streams of a network's bus and their worst-case response times at its bit rate
//! (`pabctl check`; the analysis is [`crate::check::response`]'s, docs/response-times.md the model).
//!
//! On a CAN FD bus (`[bus] data_bitrate`) the analysis counts time in the units of
//! [`TimeBase`](crate::can_frame::TimeBase), in which both the nominal and the data-phase bit are whole: each frame's C is
//! exact, classic frames' bits at the nominal rate and CAN FD frames' data phase at the data rate
//! ([`crate::can_frame`]). On a classic bus the unit is the bit time, as it always was.
//!
//! The streams:
//!
//! - every **topic** with a `period` (or a `rate_hz`, its inverse): its identifier, `length`,
//!   `fd`, `jitter` and `deadline` (default the period); a topic with neither is listed, not
//!   analysed;
//! - every **gateway** (a port with `republish`): the frames it re-publishes, at most as often as
//!   the fastest topic feeding the port delivers (T = the shortest period among them), as long as
//!   the longest of them (CAN FD frames when a feeding topic's are: a port fed by both kinds
//!   re-publishes both, and its C is the longer of its longest frame of each kind); queued when the winning frame has arrived, so its jitter is the
//!   feeding topics' R − C, found by [`analyse`](crate::check::bus::analyse), and its deadline one period after that. A value
//!   port's output changes on every contributor's frame and when one ages out: one stream per
//!   feeding topic, at half its period. A topic declared on the gateway's own identifier with a
//!   period describes it instead;
//! - the **protocol's own frames** whose rate the network and docs/can-protocol.md determine, at
//!   the most their nodes send: each node's heartbeat group (Heartbeat, TableStatus, Traffic,
//!   Errors, and FilterStatus on a node with HBBA filters) at the nodes' default heartbeat
//!   period; each dynamics group's Gates, one per step
//!   at most (a change at every step), at least every 100 ms; each BLE group member's claim once
//!   per group period; a schema server's SchemaState every 100 ms, and its drive's attractor,
//!   attractor rotation and impedance frames every loop period (the impedance, "on change and
//!   every 100 ms", at most once a tick);
//! - **one table transfer at a time**, a background stream: the node's flow control (block size
//!   8, STmin 0) lets the tool send its consecutive frames back to back, so while a table is
//!   pushed every frame ranked below the transfer waits for its end. On a CAN FD bus the
//!   transfer is ISO-TP on CAN FD (ISO 15765-2:2016) with 64-byte frames (TX_DL 64, with
//!   bit-rate switching when the data rate is above the nominal one); the protocol's other
//!   frames stay classic 8-byte frames.
//!
//! Everything else the protocol sends on events whose rate the network does not say (faults,
//! schema transfers and answers, HBBA's traffic, the diagnostic stream, identity, configuration,
//! firmware updates, seals) is listed as not analysed, with the reason; so is the identity each
//! node announces once at start-up, which is not periodic. The simulator's timed bus
//! (`pabctl sim --timed-bus`) shows what those frames do to the others.

use std::ops::Range;

use pab_core::consumer::Consumer;
use pab_core::protocol::{BROADCAST, FrameId, Service, TOOL};

use super::response::{self, Background, Response, Stream, Unbounded};
use crate::can_frame::{FD_DATA_LEN, TimeBase};
use crate::diagnostic::Diagnostic;
use crate::network::{NO_TOPIC, Network};

/// The standard bit rates `pabctl check` tries for the lowest at which every deadline holds:
/// CiA 301's (CANopen's) classic CAN rates, which bus hardware and tools offer. On a CAN FD bus
/// they are the nominal rates tried, the data rate kept as analysed (those above it skipped).
pub const STANDARD_BITRATES: [u32; 8] = [
    10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// SchemaState's period and the Gates' repeat, ns (docs/can-protocol.md).
const HUNDRED_MS: u64 = 100_000_000;

/// What a stream is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A topic of the file, by index.
    Topic(usize),
    /// A gateway's re-published frames, by port index.
    Gateway(usize),
    /// A frame of the protocol's own.
    Protocol,
}

/// A frame stream of the bus, in nanoseconds.
#[derive(Clone, Debug)]
pub struct BusStream {
    /// What it is called in the table: a topic's name, `PORT (republished)`, `NODE: Service`.
    pub name: String,
    /// What it is.
    pub kind: Kind,
    /// Its identifier (a BLE claim's at eligibility 0, the lowest it sends).
    pub id: u32,
    /// A 29-bit identifier.
    pub extended: bool,
    /// Its rank on the bus ([`response::arbitration_key`]); the BLE claims share one.
    pub key: u32,
    /// Data bytes (a gateway's: its longest frame's).
    pub length: u8,
    /// CAN FD frames (a gateway's: when a topic feeding it sends them).
    pub fd: bool,
    /// A gateway fed by both classic and CAN FD topics re-publishes both kinds: the longest of
    /// its classic frames, whose C counts when it is the longer.
    pub also_classic: Option<u8>,
    /// T.
    pub period_ns: u64,
    /// J.
    pub jitter_ns: u64,
    /// D.
    pub deadline_ns: u64,
    /// Where the file says it (a topic's deadline or period, a port, a node, a group).
    pub span: Range<usize>,
    /// A gateway's feeding topics (indices into the network's topics): its jitter is theirs
    /// to arrive, found by the analysis.
    pub feeders: Vec<usize>,
    /// A BLE claim's stream: the claims of this node in this group, whatever the eligibility
    /// their identifiers carry (every other stream's frames are those on [`BusStream::id`]).
    pub claim: Option<ClaimOf>,
}

/// Whose claims a BLE claim stream is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClaimOf {
    /// The node, by index into the network's nodes.
    pub node: usize,
    /// The group, by index into the network's groups.
    pub group: usize,
}

impl BusStream {
    /// A periodic frame of the protocol's own (or a schema server's drive): its deadline its
    /// period, no jitter, ranked by `id` (`rank_id` instead for the BLE claims, which share the
    /// rank of their base identifier).
    fn protocol(
        name: String,
        (id, extended): (u32, bool),
        rank_id: u32,
        length: usize,
        period_ns: u64,
        span: Range<usize>,
    ) -> BusStream {
        BusStream {
            name,
            kind: Kind::Protocol,
            id,
            extended,
            key: response::arbitration_key(rank_id, extended),
            length: u8::try_from(length).unwrap_or(u8::MAX),
            fd: false,
            also_classic: None,
            period_ns,
            jitter_ns: 0,
            deadline_ns: period_ns,
            span,
            feeders: Vec::new(),
            claim: None,
        }
    }
}

/// A stream with no period: it takes the bus whenever nothing above it wants it.
#[derive(Clone, Debug)]
pub struct BackgroundStream {
    /// What it is called.
    pub name: String,
    /// Its identifier (the one of highest rank among its frames).
    pub id: u32,
    /// Its rank.
    pub key: u32,
    /// Data bytes of its frames.
    pub length: u8,
    /// CAN FD frames (ISO-TP on CAN FD, on a CAN FD bus).
    pub fd: bool,
}

/// A stream that is not analysed, and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Unanalysed {
    /// What it is called.
    pub name: String,
    /// Why it is not in the analysis.
    pub reason: String,
}

/// The streams of a network's bus.
#[derive(Clone, Debug, Default)]
pub struct Streams {
    /// The periodic streams, in order of rank (highest first).
    pub streams: Vec<BusStream>,
    /// The background streams.
    pub background: Vec<BackgroundStream>,
    /// What is not analysed.
    pub unanalysed: Vec<Unanalysed>,
}

/// The key every BLE claim shares: a claim ranks above every priority-4 frame of a service
/// (bit 23 set) and below every priority-5 frame, and among claims by an eligibility known only
/// at run time.
const CLAIM_BASE: u32 = 4 << 26 | 0b10 << 24 | 1 << 23;

fn protocol_id(service: Service, source: u8, destination: u8) -> u32 {
    FrameId::new(service, source, destination).raw()
}

/// The streams of `network`'s bus.
pub fn streams(network: &Network) -> Streams {
    let mut out = Streams::default();
    let push = |out: &mut Streams, stream: BusStream| out.streams.push(stream);
    for (index, topic) in network.topics.iter().enumerate() {
        let Some(timing) = &topic.timing else {
            out.unanalysed.push(Unanalysed {
                name: topic.name.clone(),
                reason: "topic without `period` (or `rate_hz`)".into(),
            });
            continue;
        };
        let (id, extended) = (topic.filter.id(), topic.filter.is_extended());
        push(
            &mut out,
            BusStream {
                name: topic.name.clone(),
                kind: Kind::Topic(index),
                id,
                extended,
                key: response::arbitration_key(id, extended),
                length: topic.length,
                fd: topic.fd,
                also_classic: None,
                period_ns: timing.period_ns,
                jitter_ns: timing.jitter_ns,
                deadline_ns: timing.deadline_ns,
                span: timing.span.clone(),
                feeders: Vec::new(),
                claim: None,
            },
        );
    }
    for (index, port) in network.ports.iter().enumerate() {
        let Consumer::Republish(output) = port.consumer else {
            continue;
        };
        let (id, extended) = (output.raw(), output.is_extended());
        let exact = pab_core::Filter::exact(id, extended).ok();
        let described = network
            .topics
            .iter()
            .any(|t| t.timing.is_some() && Some(t.filter) == exact);
        if described {
            continue;
        }
        let name = format!("{} (republished)", port.name);
        let feeding: Vec<&crate::network::Topic> = network
            .port_connections(index)
            .filter(|c| c.topic != NO_TOPIC)
            .filter_map(|c| network.topics.get(c.topic))
            .collect();
        let timed: Vec<_> = feeding
            .iter()
            .filter_map(|t| t.timing.as_ref().map(|timing| (t, timing)))
            .collect();
        if timed.is_empty() || timed.len() < feeding.len() {
            out.unanalysed.push(Unanalysed {
                name,
                reason: "a topic feeding the port has no `period`".into(),
            });
            continue;
        }
        let mut feeders: Vec<usize> = network
            .port_connections(index)
            .filter(|c| c.topic != NO_TOPIC)
            .map(|c| c.topic)
            .collect();
        feeders.sort_unstable();
        feeders.dedup();
        let length = timed.iter().map(|(t, _)| t.length).max().unwrap_or(8);
        let fd = timed.iter().any(|(t, _)| t.fd);
        let also_classic = timed
            .iter()
            .filter(|(t, _)| !t.fd)
            .map(|(t, _)| t.length)
            .max()
            .filter(|_| fd);
        let gateway = |name: String, period_ns: u64, feeders: Vec<usize>| BusStream {
            name,
            kind: Kind::Gateway(index),
            id,
            extended,
            key: response::arbitration_key(id, extended),
            length,
            fd,
            also_classic,
            period_ns,
            jitter_ns: 0,
            deadline_ns: period_ns,
            span: port.span.clone(),
            feeders,
            claim: None,
        };
        if port.value.is_some() {
            // A value port's output changes on every frame of a contributor and when one ages
            // out: per feeding topic, at most twice a period.
            for &topic in &feeders {
                let Some(timing) = network.topics.get(topic).and_then(|t| t.timing.as_ref()) else {
                    continue;
                };
                let from = network.topics.get(topic).map_or("?", |t| t.name.as_str());
                push(
                    &mut out,
                    gateway(
                        format!("{} (republished, {from})", port.name),
                        (timing.period_ns / 2).max(1),
                        vec![topic],
                    ),
                );
            }
        } else {
            let period_ns = timed.iter().map(|(_, t)| t.period_ns).min().unwrap_or(1);
            push(&mut out, gateway(name, period_ns, feeders));
        }
    }
    for (node_index, node) in network.nodes.iter().enumerate() {
        let period_ns = node.config().heartbeat_period_us * 1000;
        // A node whose table has HBBA filters (a strategy filters one of its connections) ends
        // its heartbeat group with FilterStatus.
        let filters = network.hbba.as_ref().is_some_and(|hbba| {
            hbba.strategies.iter().flat_map(|s| &s.filters).any(|f| {
                network
                    .connections
                    .get(f.connection)
                    .and_then(|c| network.ports.get(c.port))
                    .is_some_and(|p| p.node == node_index)
            })
        });
        let group = [
            Service::Heartbeat,
            Service::TableStatus,
            Service::Traffic,
            Service::Errors,
        ]
        .into_iter()
        .chain(filters.then_some(Service::FilterStatus));
        for service in group {
            let id = protocol_id(service, node.id, BROADCAST);
            push(
                &mut out,
                BusStream::protocol(
                    format!("{}: {service:?}", node.name),
                    (id, true),
                    id,
                    service.payload_len(),
                    period_ns,
                    node.span.clone(),
                ),
            );
        }
    }
    for group in &network.dynamics {
        let Some(node) = network.nodes.get(group.node) else {
            continue;
        };
        let id = protocol_id(Service::Gates, node.id, BROADCAST);
        let period_ns = (u64::from(group.params.step_us) * 1000).clamp(1, HUNDRED_MS);
        push(
            &mut out,
            BusStream::protocol(
                format!("{}: Gates of {}", node.name, group.name),
                (id, true),
                id,
                Service::Gates.payload_len(),
                period_ns,
                group.span.clone(),
            ),
        );
    }
    for (group_index, group) in network.groups.iter().enumerate() {
        for member in &group.members {
            let Some(node) = network.nodes.get(member.node) else {
                continue;
            };
            let id = CLAIM_BASE | 0xFFFF << 7 | u32::from(node.id);
            let period_ns = u64::from(group.period_us) * 1000;
            let mut stream = BusStream::protocol(
                format!("{}: claim of {}", node.name, group.name),
                (id, true),
                CLAIM_BASE,
                pab_core::ble::PAYLOAD_LEN,
                period_ns,
                group.span.clone(),
            );
            stream.claim = Some(ClaimOf {
                node: member.node,
                group: group_index,
            });
            push(&mut out, stream);
        }
    }
    for board in &network.schema_boards {
        let Some(node) = network.nodes.get(board.node) else {
            continue;
        };
        let id = protocol_id(Service::SchemaState, node.id, BROADCAST);
        push(
            &mut out,
            BusStream::protocol(
                format!("{}: SchemaState", node.name),
                (id, true),
                id,
                Service::SchemaState.payload_len(),
                HUNDRED_MS,
                board.span.clone(),
            ),
        );
        let tick_ns = u64::from(board.config.period_us).max(1) * 1000;
        let setpoint = board.drive.setpoint;
        for (offset, what) in ["attractor", "attractor rotation", "impedance"]
            .iter()
            .enumerate()
        {
            let id = setpoint.raw() + offset as u32;
            let extended = setpoint.is_extended();
            push(
                &mut out,
                BusStream::protocol(
                    format!("{}: drive {what}", node.name),
                    (id, extended),
                    id,
                    8,
                    tick_ns,
                    board.span.clone(),
                ),
            );
        }
        out.unanalysed.push(Unanalysed {
            name: format!(
                "{}: SchemaTransition, SchemaAck, the drive's pose and wrench",
                node.name
            ),
            reason: "sent on schema changes, per message, or at the drive's own rate".into(),
        });
    }
    if let Some(first) = network.nodes.iter().map(|n| n.id).min() {
        let id = protocol_id(Service::TableTransfer, TOOL, first);
        let fd = network.bus.as_ref().is_some_and(crate::network::Bus::is_fd);
        out.background.push(BackgroundStream {
            name: if fd {
                "table transfer (one at a time, ISO-TP on CAN FD: 64-byte frames)".into()
            } else {
                "table transfer (one at a time)".into()
            },
            id,
            key: response::arbitration_key(id, true),
            length: if fd { FD_DATA_LEN as u8 } else { 8 },
            fd,
        });
        out.unanalysed.push(Unanalysed {
            name: "Fault".into(),
            reason: "on events: at most one per code per 100 ms and node, but how many codes at once is not determinable".into(),
        });
        out.unanalysed.push(Unanalysed {
            name: "Identity".into(),
            reason: "announced once at start-up (6 frames a node at priority 4), not periodic"
                .into(),
        });
        out.unanalysed.push(Unanalysed {
            name: "Diagnostic stream, identity on request, configuration, firmware update".into(),
            reason: "switched on or sent at an operator's request".into(),
        });
    }
    if !network.schema_boards.is_empty() || network.client.is_some() {
        out.unanalysed.push(Unanalysed {
            name: "EmergencyStop, SchemaAbort, SchemaTransfer".into(),
            reason: "sent by the client or an operator when they choose (a schema message is up to 40 frames at priority 2, back to back)".into(),
        });
    }
    if network.hbba.is_some() {
        out.unanalysed.push(Unanalysed {
            name: "Desire, Intention, FilterProfile, FilterSet, FilterStatus answering them, Exploitation".into(),
            reason:
                "HBBA's traffic follows desires and solves, whose rate the network does not say"
                    .into(),
        });
    }
    out.streams.sort_by_key(|s| s.key);
    out
}

/// One stream's result at a bit rate.
#[derive(Clone, Debug)]
pub struct Row {
    /// T as analysed, in the analysis's time units (rounded down).
    pub period: u64,
    /// J as analysed, in the analysis's time units (rounded up; a gateway's: found by the
    /// analysis).
    pub jitter: u64,
    /// C, ns (rounded up).
    pub c_ns: u64,
    /// C in the analysis's time units.
    pub c: u64,
    /// J as analysed, ns (a gateway's: found by the analysis).
    pub jitter_ns: u64,
    /// D as analysed, ns (a gateway's: its period after its jitter).
    pub deadline_ns: u64,
    /// The analysis's answer, in the analysis's time units ([`Analysis::base`]).
    pub response: Response,
    /// R, ns (rounded up), if bounded.
    pub r_ns: Option<u64>,
    /// Whether R ≤ D (in time units).
    pub meets: bool,
    /// A gateway one of whose feeding topics has no bound: neither has it.
    pub fed_unbounded: bool,
}

/// The analysis at one bit rate.
#[derive(Clone, Debug)]
pub struct Analysis {
    /// Bit/s: the nominal rate.
    pub bitrate: u32,
    /// A CAN FD bus's data rate, bit/s (at least `bitrate`); `None` on a classic bus.
    pub data_bitrate: Option<u32>,
    /// The unit of time of the analysis: a bit time on a classic bus.
    pub base: TimeBase,
    /// One row per stream of [`Streams::streams`], in order.
    pub rows: Vec<Row>,
    /// The periodic streams' load, parts per billion of the bus's time (C/T rounded up).
    pub load_ppb: u128,
}

impl Analysis {
    /// Every deadline met and the load at most 100 %.
    pub fn holds(&self) -> bool {
        self.load_ppb <= 1_000_000_000 && self.rows.iter().all(|row| row.meets)
    }

    /// The rates as the messages say them: `500 kbit/s`, on a CAN FD bus `500 kbit/s (data
    /// phase 2 Mbit/s)`.
    pub fn rates(&self) -> String {
        match self.data_bitrate {
            Some(data) => format!("{} (data phase {})", rate(self.bitrate), rate(data)),
            None => rate(self.bitrate),
        }
    }

    /// The rates as the table's first line says them: `500 kbit/s`, on a CAN FD bus `500
    /// kbit/s, data phase 2 Mbit/s (CAN FD with bit-rate switching)`.
    fn rates_long(&self) -> String {
        match self.data_bitrate {
            Some(data) if data > self.bitrate => format!(
                "{}, data phase {} (CAN FD with bit-rate switching)",
                rate(self.bitrate),
                rate(data)
            ),
            Some(_) => format!("{} (CAN FD without bit-rate switching)", rate(self.bitrate)),
            None => rate(self.bitrate),
        }
    }
}

/// `ns` in time units of `per_second` a second, rounded down or up.
fn bits(ns: u64, per_second: u64, up: bool) -> u64 {
    let product = u128::from(ns) * u128::from(per_second);
    let bits = if up {
        product.div_ceil(1_000_000_000)
    } else {
        product / 1_000_000_000
    };
    u64::try_from(bits).unwrap_or(u64::MAX)
}

/// `bits` time units of `per_second` a second in ns, rounded up.
fn nanoseconds(bits: u64, per_second: u64) -> u64 {
    let ns = (u128::from(bits) * 1_000_000_000).div_ceil(u128::from(per_second.max(1)));
    u64::try_from(ns).unwrap_or(u64::MAX)
}

impl BusStream {
    /// C, in the units of `base`: its frame's transmission time, or for a gateway that
    /// re-publishes both kinds, the longer of its longest CAN FD and its longest classic frame.
    pub fn frame_time(&self, base: &TimeBase) -> u64 {
        let own = base.frame(self.fd, self.length, self.extended);
        self.also_classic.map_or(own, |classic| {
            own.max(base.frame(false, classic, self.extended))
        })
    }
}

/// The response times of `streams` on a classic bus at `bitrate` ([`analyse_at`] with no data
/// rate: CAN FD frames, if any, at the nominal rate throughout).
pub fn analyse(streams: &Streams, bitrate: u32) -> Analysis {
    analyse_at(streams, bitrate, None)
}

/// The response times of `streams` at `bitrate` and, on a CAN FD bus, `data_bitrate` (raised to
/// `bitrate` if below: the data phase is never slower than the arbitration): periods and
/// deadlines rounded down to whole time units ([`TimeBase`]: bit times on a classic bus), jitter
/// up.
///
/// A gateway's frame is queued when the frame it re-publishes has arrived: its period starts
/// with that frame's, so its jitter is how late that frame can arrive after its earliest,
/// R − C of the feeding topic (the worst among them), and its deadline is one period after its
/// jitter. The feeding topics' responses depend on the gateways' jitter in turn (a gateway
/// above a topic interferes with it): the analysis is repeated until the jitters settle (the
/// holistic iteration; they only grow), at most 32 times, and a gateway whose feeding topic has
/// no bound has none either.
pub fn analyse_at(streams: &Streams, bitrate: u32, data_bitrate: Option<u32>) -> Analysis {
    let data_bitrate = data_bitrate.map(|rate| rate.max(bitrate));
    let base = TimeBase::new(bitrate, data_bitrate);
    let per_second = base.per_second;
    let mut model: Vec<Stream> = streams
        .streams
        .iter()
        .map(|s| Stream {
            key: s.key,
            bits: s.frame_time(&base),
            period: bits(s.period_ns, per_second, false).max(1),
            jitter: bits(s.jitter_ns, per_second, true),
            deadline: bits(s.deadline_ns, per_second, false),
        })
        .collect();
    let background: Vec<Background> = streams
        .background
        .iter()
        .map(|b| Background {
            key: b.key,
            bits: base.frame(b.fd, b.length, true),
        })
        .collect();
    // Each gateway's feeding streams, by position in `model`.
    let feeders: Vec<Vec<usize>> = streams
        .streams
        .iter()
        .map(|s| {
            s.feeders
                .iter()
                .filter_map(|&topic| {
                    streams
                        .streams
                        .iter()
                        .position(|other| other.kind == Kind::Topic(topic))
                })
                .collect()
        })
        .collect();
    let mut responses = response::responses_at(&model, &background, base.nominal);
    let mut starved = vec![false; model.len()];
    for _ in 0..32 {
        let mut changed = false;
        for (g, sources) in feeders.iter().enumerate() {
            if sources.is_empty() {
                continue;
            }
            let mut jitter = 0;
            for &f in sources {
                match responses[f].bound() {
                    Some(r) => jitter = jitter.max(r.saturating_sub(model[f].bits)),
                    None => starved[g] = true,
                }
            }
            if jitter > model[g].jitter {
                model[g].jitter = jitter;
                model[g].deadline = bits(streams.streams[g].period_ns, per_second, false) + jitter;
                changed = true;
            }
        }
        if !changed {
            break;
        }
        responses = response::responses_at(&model, &background, base.nominal);
    }
    let rows = responses
        .into_iter()
        .zip(&model)
        .zip(&starved)
        .zip(&streams.streams)
        .map(|(((response, stream), &starved), written)| {
            let response = if starved {
                Response::Unbounded(Unbounded::Overload)
            } else {
                response
            };
            Row {
                period: stream.period,
                jitter: stream.jitter,
                c_ns: nanoseconds(stream.bits, per_second),
                c: stream.bits,
                // As written, but a gateway's, which the analysis found.
                jitter_ns: if written.feeders.is_empty() {
                    written.jitter_ns
                } else {
                    nanoseconds(stream.jitter, per_second)
                },
                deadline_ns: if written.feeders.is_empty() {
                    written.deadline_ns
                } else {
                    nanoseconds(stream.deadline, per_second)
                },
                r_ns: response.bound().map(|r| nanoseconds(r, per_second)),
                meets: response.meets(stream.deadline),
                response,
                fed_unbounded: starved,
            }
        })
        .collect();
    Analysis {
        bitrate,
        data_bitrate,
        base,
        rows,
        load_ppb: response::load_ppb(&model),
    }
}

/// The bus's timing: its streams, the analysis at the network's bit rate, and the lowest
/// standard bit rate at which every deadline holds.
#[derive(Clone, Debug)]
pub struct Timing {
    /// The streams.
    pub streams: Streams,
    /// At the network's bit rate (`[bus] bitrate`), if it has one.
    pub analysis: Option<Analysis>,
    /// The lowest of [`STANDARD_BITRATES`] at which everything holds, if any; on a CAN FD bus
    /// the lowest nominal rate with the data phase at [`Timing::lowest_data_bitrate`].
    pub lowest: Option<u32>,
    /// On a CAN FD bus, the data rate the lowest nominal rate was searched at (the analysis's).
    pub lowest_data_bitrate: Option<u32>,
}

/// The timing of `network`'s bus, at its bit rate (`[bus] bitrate`).
pub fn timing(network: &Network) -> Timing {
    timing_at(network, None)
}

/// The timing of `network`'s bus at `bitrate` (bit/s) if given, else at the network's
/// (`pabctl check --bitrate`: what another bus would miss, without editing the file).
pub fn timing_at(network: &Network, bitrate: Option<u32>) -> Timing {
    timing_with(network, bitrate, None)
}

/// The timing of `network`'s bus at `bitrate` and, on a CAN FD bus, `data_bitrate` (bit/s) if
/// given, else at the network's (`pabctl check --bitrate --data-bitrate`). The data rate is
/// never below the nominal one: a nominal rate above the file's data rate analyses CAN FD
/// without bit-rate switching. On a classic bus `data_bitrate` is not used (the caller refuses
/// it: whether the bus is CAN FD is the file's to say, with what it makes valid).
///
/// The lowest standard bit rate is searched among [`STANDARD_BITRATES`] at the data rate
/// analysed on a CAN FD bus, the nominal rates above it skipped: how slow the arbitration phase
/// may be (a longer bus) with the data phase as it is.
pub fn timing_with(network: &Network, bitrate: Option<u32>, data_bitrate: Option<u32>) -> Timing {
    let streams = streams(network);
    let bus = network.bus.as_ref();
    let data = bus
        .and_then(|bus| bus.data_bitrate)
        .map(|written| data_bitrate.unwrap_or(written));
    let analysis = bitrate
        .or(bus.map(|bus| bus.bitrate))
        .map(|bitrate| analyse_at(&streams, bitrate, data));
    let lowest_data_bitrate = analysis.as_ref().and_then(|a| a.data_bitrate).or(data);
    let lowest = STANDARD_BITRATES
        .into_iter()
        .filter(|&rate| lowest_data_bitrate.is_none_or(|data| rate <= data))
        .find(|&rate| analyse_at(&streams, rate, lowest_data_bitrate).holds());
    Timing {
        streams,
        analysis,
        lowest,
        lowest_data_bitrate,
    }
}

/// Seconds as a person reads them: `1 s`, `100 ms`, `0.270 ms`.
pub fn duration(ns: u64) -> String {
    if ns >= 1_000_000_000 && ns.is_multiple_of(1_000_000) {
        let ms = ns / 1_000_000;
        return if ms.is_multiple_of(1000) {
            format!("{} s", ms / 1000)
        } else {
            format!("{:.3} s", ns as f64 / 1e9)
        };
    }
    if ns.is_multiple_of(1_000_000) {
        return format!("{} ms", ns / 1_000_000);
    }
    format!("{:.3} ms", ns as f64 / 1e6)
}

/// A response time, a transmission time or a slack: ms with three decimals (`0.270 ms`).
pub fn milliseconds(ns: u64) -> String {
    format!("{:.3} ms", ns as f64 / 1e6)
}

/// A bit rate as `500 kbit/s` or `1 Mbit/s`.
pub fn rate(bitrate: u32) -> String {
    if bitrate.is_multiple_of(1_000_000) {
        format!("{} Mbit/s", bitrate / 1_000_000)
    } else if bitrate.is_multiple_of(1000) {
        format!("{} kbit/s", bitrate / 1000)
    } else {
        format!("{bitrate} bit/s")
    }
}

/// An identifier as the table prints it.
pub fn id_text(id: u32, extended: bool) -> String {
    if extended {
        format!("0x{id:08X}")
    } else {
        format!("0x{id:03X}")
    }
}

impl Timing {
    /// Why `pabctl check` fails on the bus: each stream that can miss its deadline, at its
    /// line, and the load above 100 %, at the file's bit rate (analysed at another one, given
    /// on the command line, the streams that cannot keep up say it).
    pub fn errors(&self, network: &Network) -> Vec<Diagnostic> {
        let Some(analysis) = &self.analysis else {
            return Vec::new();
        };
        let mut errors = Vec::new();
        let at = analysis.rates();
        let overloaded = analysis.load_ppb > 1_000_000_000;
        if let Some(bus) = (network.bus.as_ref()).filter(|bus| {
            overloaded
                && bus.bitrate == analysis.bitrate
                && bus.data_bitrate == analysis.data_bitrate
        }) {
            errors.push(network.error(
                bus.span.clone(),
                format!(
                    "the bus is loaded {:.1} % at {at}: its periodic streams need more bits a second than it carries{}",
                    analysis.load_ppb as f64 / 1e7,
                    self.lowest_hint()
                ),
            ));
        }
        for (stream, row) in self.streams.streams.iter().zip(&analysis.rows) {
            if row.meets {
                continue;
            }
            let id = id_text(stream.id, stream.extended);
            let deadline = duration(row.deadline_ns);
            let message = match (row.response, row.r_ns) {
                _ if row.fed_unbounded => format!(
                    "`{}` ({id}) can miss its deadline at {at}: a topic it re-publishes has no bound on its response time, so neither has it (deadline {deadline})",
                    stream.name
                ),
                (Response::Bounded { .. }, Some(r)) => format!(
                    "`{}` ({id}) can miss its deadline at {at}: worst-case response time {} > deadline {deadline}{}",
                    stream.name,
                    milliseconds(r),
                    self.lowest_hint()
                ),
                (Response::Unbounded(Unbounded::Background(index)), _) => format!(
                    "`{}` ({id}) can miss its deadline at {at}: while a table is pushed it waits for the whole transfer ({} ranks above it), so its response time has no bound (deadline {deadline}); give it an identifier that ranks above {}",
                    stream.name,
                    self.streams.background.get(index).map_or(
                        "the transfer".to_string(),
                        |b| format!("{} {}", b.name, id_text(b.id, true))
                    ),
                    self.streams
                        .background
                        .get(index)
                        .map_or(String::new(), |b| id_text(b.id, true)),
                ),
                _ => format!(
                    "`{}` ({id}) can miss its deadline at {at}: the streams at and above its priority load the bus to 100 % or more, so its response time has no bound (deadline {deadline}){}",
                    stream.name,
                    self.lowest_hint()
                ),
            };
            errors.push(network.error(stream.span.clone(), message));
        }
        errors
    }

    fn lowest_hint(&self) -> String {
        let data = self.lowest_data_bitrate.map_or(String::new(), |data| {
            format!(" with the data phase at {}", self::rate(data))
        });
        match self.lowest {
            Some(rate) => format!(" (every deadline holds from {}{data})", self::rate(rate)),
            None => format!(" (no standard bit rate up to 1 Mbit/s meets every deadline{data})"),
        }
    }

    /// The table `pabctl check` prints: one line per stream, in order of rank, then the
    /// background, what is not analysed, the load and the lowest standard bit rate. Empty for
    /// a network without a bit rate and without streams.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        let Some(analysis) = &self.analysis else {
            return out;
        };
        let _ = writeln!(
            out,
            "bus at {}: {} stream{} analysed (Davis et al. 2007, worst-case stuffing)",
            analysis.rates_long(),
            self.streams.streams.len(),
            if self.streams.streams.len() == 1 {
                ""
            } else {
                "s"
            }
        );
        let name_width = self
            .streams
            .streams
            .iter()
            .map(|s| s.name.chars().count())
            .max()
            .unwrap_or(6)
            .max(6);
        // On a CAN FD bus, a column says each stream's frames: classic, FD (with BRS when
        // the data phase is faster), or both (a gateway fed by both kinds).
        let fd_bus = analysis.data_bitrate.is_some();
        let brs = analysis
            .data_bitrate
            .is_some_and(|data| data > analysis.bitrate);
        let format_of = |stream: &BusStream| match (stream.fd, stream.also_classic, brs) {
            (false, _, _) => "classic",
            (true, Some(_), _) => "both",
            (true, None, true) => "FD BRS",
            (true, None, false) => "FD",
        };
        let column = |text: &str| {
            if fd_bus {
                format!("  {text:7}")
            } else {
                String::new()
            }
        };
        let _ = writeln!(
            out,
            "  {:name_width$}  {:10}  {:>5}{}  {:>11}  {:>11}  {:>9}  {:>11}  {:>11}",
            "stream",
            "id",
            "bytes",
            column("frame"),
            "period",
            "deadline",
            "C",
            "R",
            "slack"
        );
        for (stream, row) in self.streams.streams.iter().zip(&analysis.rows) {
            let (r, slack) = match row.r_ns {
                Some(r) if row.meets => (
                    milliseconds(r),
                    milliseconds(row.deadline_ns - r.min(row.deadline_ns)),
                ),
                Some(r) => (milliseconds(r), "MISSED".to_string()),
                None => ("unbounded".to_string(), "MISSED".to_string()),
            };
            let _ = writeln!(
                out,
                "  {:name_width$}  {:10}  {:>5}{}  {:>11}  {:>11}  {:>9}  {:>11}  {:>11}",
                stream.name,
                id_text(stream.id, stream.extended),
                stream.length,
                column(format_of(stream)),
                duration(stream.period_ns),
                duration(row.deadline_ns),
                milliseconds(row.c_ns),
                r,
                slack
            );
        }
        for background in &self.streams.background {
            let _ = writeln!(
                out,
                "  background: {} ({}): takes the bus whenever nothing above it wants it",
                background.name,
                id_text(background.id, true)
            );
        }
        for unanalysed in &self.streams.unanalysed {
            let _ = writeln!(
                out,
                "  not analysed: {}: {}",
                unanalysed.name, unanalysed.reason
            );
        }
        let _ = writeln!(
            out,
            "bus load: {:.1} % of {} (the periodic streams)",
            analysis.load_ppb as f64 / 1e7,
            match analysis.data_bitrate {
                Some(data) => format!(
                    "the time at {}, data phase {}",
                    rate(analysis.bitrate),
                    rate(data)
                ),
                None => rate(analysis.bitrate),
            }
        );
        let data = self.lowest_data_bitrate.map_or(String::new(), |data| {
            format!(" (data phase at {})", rate(data))
        });
        match self.lowest {
            Some(lowest) => {
                let _ = writeln!(
                    out,
                    "lowest standard bit rate at which every deadline holds: {}{data}",
                    rate(lowest)
                );
            }
            None => {
                let _ = writeln!(
                    out,
                    "no standard bit rate up to 1 Mbit/s meets every deadline{data}"
                );
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;

    const TAKE_AND_RETURN: &str = include_str!("../../../examples/take-and-return.toml");

    fn parse(text: &str) -> Network {
        Network::parse(Source::new("net.toml", text)).unwrap()
    }

    fn row<'a>(timing: &'a Timing, name: &str) -> (&'a BusStream, &'a Row) {
        let analysis = timing.analysis.as_ref().unwrap();
        timing
            .streams
            .streams
            .iter()
            .zip(&analysis.rows)
            .find(|(s, _)| s.name == name)
            .unwrap_or_else(|| panic!("no stream {name}"))
    }

    /// A node's `heartbeat` is the period its heartbeat group is analysed at (and only its
    /// own); a period its configuration refuses is refused at the key.
    #[test]
    fn a_node_s_heartbeat_sets_its_heartbeat_group_s_period() {
        let text = TAKE_AND_RETURN.replace("id = 2\n", "id = 2\nheartbeat = 0.25\n");
        let network = parse(&text);
        assert_eq!(network.nodes[1].heartbeat_us, 250_000);
        assert_eq!(network.nodes[1].config().heartbeat_period_us, 250_000);
        assert_eq!(network.nodes[0].config().heartbeat_period_us, 1_000_000);
        let timing = timing(&network);
        for service in ["Heartbeat", "TableStatus", "Traffic", "Errors"] {
            let (hand, _) = row(&timing, &format!("hand: {service}"));
            assert_eq!(hand.period_ns, 250_000_000, "{service}");
            let (arm, _) = row(&timing, &format!("arm: {service}"));
            assert_eq!(arm.period_ns, 1_000_000_000, "{service}");
        }
        for bad in ["0.001", "3601", "-1", "nan"] {
            let text = TAKE_AND_RETURN.replace("id = 2\n", &format!("id = 2\nheartbeat = {bad}\n"));
            let found = Network::parse(Source::new("net.toml", &text))
                .unwrap_err()
                .to_string();
            assert!(
                found.contains(&format!(
                    "error: heartbeat = {}: seconds between the node's heartbeats, 0.01 to 3600",
                    bad.parse::<f64>().unwrap()
                )),
                "{bad}: {found}"
            );
        }
    }

    #[test]
    fn take_and_return_holds_from_20_kbit_s() {
        let network = parse(TAKE_AND_RETURN);
        let timing = timing(&network);
        let analysis = timing.analysis.as_ref().unwrap();
        assert_eq!(analysis.bitrate, 500_000);
        assert!(analysis.holds());
        assert!(timing.errors(&network).is_empty());
        assert_eq!(timing.lowest, Some(20_000));
        // 8 topics, 3 gateways, 3 nodes × 4 heartbeat frames.
        assert_eq!(timing.streams.streams.len(), 8 + 3 + 12);
        // The highest: blocked by one 8-byte extended frame (160 bits), then its own 135:
        // 295 bits at 500 kbit/s = 590 µs.
        let (stream, object) = row(&timing, "object_pos");
        assert_eq!((stream.id, stream.extended), (0x110, false));
        assert_eq!((object.c_ns, object.r_ns), (270_000, Some(590_000)));
        // A heartbeat: extended, 160 bits = 320 µs.
        let (stream, heartbeat) = row(&timing, "gaze: Heartbeat");
        assert_eq!(stream.id, 0x1202_FF03);
        assert_eq!(heartbeat.c_ns, 320_000);
        // A gateway: its period its fastest topic's, its jitter the feeding topic's R − C.
        let (stream, gateway) = row(&timing, "hand.command (republished)");
        assert_eq!((stream.id, stream.period_ns), (0x202, 100_000_000));
        let worst_feeder = ["grasp_cmd", "release_cmd", "rest_open", "grasped"]
            .iter()
            .map(|name| {
                let (_, r) = row(&timing, name);
                r.r_ns.unwrap() - r.c_ns
            })
            .max()
            .unwrap();
        assert!(gateway.jitter_ns >= worst_feeder, "{gateway:?}");
        assert_eq!(gateway.deadline_ns, 100_000_000 + gateway.jitter_ns);
        // The load: 8 + 3 frames of 135 bits at their rates, 12 of 160 bits a second.
        let bits_per_second = 135.0 * (10.0 * 5.0 + 1.0 + 2.0 * 5.0 + 3.0 * 10.0) + 12.0 * 160.0;
        let load = analysis.load_ppb as f64 / 1e9;
        assert!((load - bits_per_second / 500_000.0).abs() < 1e-6, "{load}");
        // At 20 kbit/s it still holds (the load 71 %), at 10 kbit/s not (142 %); the table says so.
        assert!(analyse(&timing.streams, 20_000).holds());
        assert!(!analyse(&timing.streams, 10_000).holds());
        let table = timing.table();
        assert!(
            table.contains("lowest standard bit rate at which every deadline holds: 20 kbit/s")
        );
        assert!(table.contains("  object_pos "), "{table}");
    }

    #[test]
    fn an_overloaded_bus_fails_at_the_lines_that_say_it() {
        // object_pos every 0.2 ms: 135 bits per 100 bit times at 500 kbit/s.
        let text = TAKE_AND_RETURN.replace(
            "can_id = 0x110\nperiod = 0.1\n",
            "can_id = 0x110\nperiod = 0.0002\n",
        );
        let network = parse(&text);
        let timing = timing(&network);
        assert!(!timing.analysis.as_ref().unwrap().holds());
        assert_eq!(timing.lowest, None);
        let errors: Vec<String> = timing
            .errors(&network)
            .iter()
            .map(ToString::to_string)
            .collect();
        let line = |needle: &str| {
            text.lines()
                .position(|line| line.starts_with(needle))
                .map(|n| n + 1)
                .unwrap()
        };
        // object_pos feeds two gateways, which re-publish it as often: 3 × 135 %, and more.
        assert!(
            errors[0].starts_with(&format!(
                "net.toml:{}:11: error: the bus is loaded 407.0 % at 500 kbit/s",
                line("bitrate = 500000")
            )),
            "{errors:#?}"
        );
        assert!(
            errors[1].starts_with(&format!(
                "net.toml:{}:10: error: `object_pos` (0x110) can miss its deadline at 500 kbit/s: the streams at and above its priority load the bus to 100 % or more",
                line("period = 0.0002")
            )),
            "{errors:#?}"
        );
        // Every stream below it starves with it.
        assert_eq!(errors.len(), 1 + 23, "{errors:#?}");
    }

    #[test]
    fn a_tight_deadline_is_missed_with_its_response_time() {
        let text = TAKE_AND_RETURN.replace(
            "can_id = 0x130\nperiod = 0.1\n",
            "can_id = 0x130\nperiod = 0.1\ndeadline = 0.002\n",
        );
        let network = parse(&text);
        let timing = timing(&network);
        let errors: Vec<String> = timing
            .errors(&network)
            .iter()
            .map(ToString::to_string)
            .collect();
        // grasped: R = 160 + 8 × 135 = 1240 bits = 2.48 ms > 2 ms at 500 kbit/s; at 1 Mbit/s
        // 1.24 ms.
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(
            errors[0].contains(
                "error: `grasped` (0x130) can miss its deadline at 500 kbit/s: worst-case response time 2.480 ms > deadline 2 ms (every deadline holds from 800 kbit/s)"
            ),
            "{errors:#?}"
        );
        assert_eq!(timing.lowest, Some(800_000));
    }

    #[test]
    fn a_stream_below_the_table_transfer_has_no_bound() {
        let text =
            TAKE_AND_RETURN.replace("can_id = 0x130\n", "can_id = 0x1A110200\nextended = true\n");
        let network = parse(&text);
        let timing = timing(&network);
        let errors: Vec<String> = timing
            .errors(&network)
            .iter()
            .map(ToString::to_string)
            .collect();
        // grasped, and the three gateways it feeds.
        assert_eq!(errors.len(), 4, "{errors:#?}");
        assert!(
            errors[3].contains("`grasped` (0x1A110200) can miss its deadline at 500 kbit/s: while a table is pushed it waits for the whole transfer"),
            "{errors:#?}"
        );
        assert!(
            errors[0].contains("`arm.target (republished)` (0x200) can miss its deadline at 500 kbit/s: a topic it re-publishes has no bound"),
            "{errors:#?}"
        );
    }

    #[test]
    fn claims_rank_between_nominal_and_low_frames_and_topics_without_period_are_listed() {
        let network = parse(include_str!(
            "../../../examples/multi-target-observation.toml"
        ));
        let streams = streams(&network);
        let claims: Vec<&BusStream> = streams
            .streams
            .iter()
            .filter(|s| s.name.contains(": claim of "))
            .collect();
        assert!(!claims.is_empty());
        let key = response::arbitration_key(CLAIM_BASE, true);
        for claim in &claims {
            assert_eq!(claim.key, key);
            assert_eq!(claim.length, 4);
            assert_eq!(claim.id & !0x7F, CLAIM_BASE | 0xFFFF << 7);
            assert_eq!(claim.period_ns, 100_000_000);
        }
        let heartbeat = response::arbitration_key(0x1202_FF01, true);
        let traffic = response::arbitration_key(0x1604_FF01, true);
        assert!(heartbeat < key && key < traffic);
        assert!(
            streams
                .unanalysed
                .iter()
                .any(|u| u.reason.starts_with("topic without `period`"))
        );
        // Without [bus], no analysis and nothing fails.
        let timing = timing(&network);
        assert!(timing.analysis.is_none() && timing.errors(&network).is_empty());
        assert!(timing.table().is_empty());
    }

    #[test]
    fn a_value_port_republishes_at_most_twice_a_period_per_contributor() {
        let text = include_str!("../../../examples/value-ports.toml")
            .replace("can_id = 0x1A0\n", "can_id = 0x1A0\nperiod = 0.05\n")
            .replace("can_id = 0x1A1\n", "can_id = 0x1A1\nperiod = 0.1\n")
            .replace("can_id = 0x1A2\n", "can_id = 0x1A2\nperiod = 0.1\n");
        let network = parse(&format!("[bus]\nbitrate = 500000\n{text}"));
        let timing = timing(&network);
        let gateways: Vec<(&str, u64)> = timing
            .streams
            .streams
            .iter()
            .filter(|s| matches!(s.kind, Kind::Gateway(_)))
            .map(|s| (s.name.as_str(), s.period_ns))
            .collect();
        assert_eq!(
            gateways,
            [
                ("base.nearest (republished, range_left)", 25_000_000),
                ("base.nearest (republished, range_front)", 50_000_000),
                ("base.nearest (republished, range_right)", 50_000_000),
            ]
        );
        assert!(timing.analysis.as_ref().unwrap().holds());
    }

    const TAKE_AND_RETURN_FD: &str = include_str!("../../../examples/take-and-return-fd.toml");

    #[test]
    fn take_and_return_on_can_fd_counts_each_phase_at_its_rate() {
        let network = parse(TAKE_AND_RETURN_FD);
        let timing = timing(&network);
        let analysis = timing.analysis.as_ref().unwrap();
        assert_eq!(
            (analysis.bitrate, analysis.data_bitrate),
            (500_000, Some(2_000_000))
        );
        // Units of 0.5 µs: a nominal bit 4 units, a data bit 1.
        assert_eq!(
            (analysis.base.per_second, analysis.base.nominal),
            (2_000_000, 4)
        );
        assert!(analysis.holds() && timing.errors(&network).is_empty());
        // Take and Return's 23 streams and the two CAN FD topics.
        assert_eq!(timing.streams.streams.len(), 25);
        // hand_skin, 48 bytes with BRS: 32 nominal bits (64 µs) and 520 data bits (260 µs).
        let (stream, skin) = row(&timing, "hand_skin");
        assert!(stream.fd && stream.length == 48);
        assert_eq!((skin.c, skin.c_ns), (32 * 4 + 520, 324_000));
        let (_, state) = row(&timing, "arm_state");
        assert_eq!(state.c_ns, 64_000 + 180_000);
        // The classic frames: their bits at the nominal rate, as on a classic bus.
        let (stream, object) = row(&timing, "object_pos");
        assert!(!stream.fd);
        assert_eq!(object.c_ns, 270_000);
        // The highest stream is blocked by one frame of the table transfer, now ISO-TP on CAN
        // FD: 64 bytes, extended, 56 nominal and 680 data bits (452 µs), then its own 270 µs.
        let transfer = &timing.streams.background[0];
        assert!(transfer.fd && transfer.length == 64);
        assert_eq!(object.r_ns, Some(452_000 + 270_000));
        // hand_skin's deadline (5 ms) holds from 500 kbit/s with the data phase at 2 Mbit/s,
        // not at 250 kbit/s.
        assert_eq!(
            (timing.lowest, timing.lowest_data_bitrate),
            (Some(500_000), Some(2_000_000))
        );
        assert!(!analyse_at(&timing.streams, 250_000, Some(2_000_000)).holds());
        let table = timing.table();
        for line in [
            "bus at 500 kbit/s, data phase 2 Mbit/s (CAN FD with bit-rate switching): 25 streams analysed",
            "  stream                      id          bytes  frame         period     deadline          C            R        slack",
            "  hand_skin                   0x141          48  FD BRS         20 ms         5 ms   0.324 ms",
            "  object_pos                  0x110           8  classic       100 ms       100 ms   0.270 ms     0.722 ms",
            "  background: table transfer (one at a time, ISO-TP on CAN FD: 64-byte frames) (0x1A110100)",
            "bus load: 6.9 % of the time at 500 kbit/s, data phase 2 Mbit/s (the periodic streams)",
            "lowest standard bit rate at which every deadline holds: 500 kbit/s (data phase at 2 Mbit/s)",
        ] {
            assert!(table.contains(line), "{line}\n{table}");
        }
        // Another data rate, as `--data-bitrate` gives it: only the FD frames change.
        let fast = timing_with(&network, None, Some(5_000_000));
        let (_, skin) = row(&fast, "hand_skin");
        assert_eq!(skin.c_ns, 64_000 + 104_000);
        assert_eq!(row(&fast, "object_pos").1.c_ns, 270_000);
        // A nominal rate above the data rate: the data phase is never slower, so CAN FD without
        // switching: 48 bytes, base format, 10 × 48 + 72 = 552 bits at 1 µs.
        let slow_data = timing_with(&network, Some(1_000_000), Some(500_000));
        let analysis = slow_data.analysis.as_ref().unwrap();
        assert_eq!(analysis.data_bitrate, Some(1_000_000));
        assert_eq!(row(&slow_data, "hand_skin").1.c_ns, 552_000);
    }

    #[test]
    fn can_fd_without_bit_rate_switching_counts_every_bit_at_the_nominal_rate() {
        let text = TAKE_AND_RETURN_FD.replace("data_bitrate = 2000000", "data_bitrate = 500000");
        let network = parse(&text);
        let timing = timing(&network);
        let analysis = timing.analysis.as_ref().unwrap();
        assert_eq!(
            (analysis.base.per_second, analysis.base.nominal),
            (500_000, 1)
        );
        // 48 bytes, base format: 10 × 48 + 72 = 552 bits at 2 µs.
        assert_eq!(row(&timing, "hand_skin").1.c_ns, 552 * 2000);
        assert!(
            timing
                .table()
                .contains("  hand_skin                   0x141          48  FD      ")
        );
        assert!(
            timing
                .table()
                .contains("(CAN FD without bit-rate switching)")
        );
    }

    #[test]
    fn a_missed_deadline_on_can_fd_says_both_rates() {
        let text = TAKE_AND_RETURN_FD.replace("deadline = 0.005", "deadline = 0.002");
        let network = parse(&text);
        let timing = timing(&network);
        let errors: Vec<String> = timing
            .errors(&network)
            .iter()
            .map(ToString::to_string)
            .collect();
        assert_eq!(errors.len(), 1, "{errors:#?}");
        let line = text
            .lines()
            .position(|l| l.starts_with("deadline = 0.002"))
            .unwrap()
            + 1;
        assert!(
            errors[0].starts_with(&format!(
                "net.toml:{line}:12: error: `hand_skin` (0x141) can miss its deadline at 500 kbit/s (data phase 2 Mbit/s): worst-case response time 3.180 ms > deadline 2 ms (every deadline holds from 1 Mbit/s with the data phase at 2 Mbit/s)"
            )),
            "{errors:#?}"
        );
    }

    #[test]
    fn a_gateway_fed_by_classic_and_fd_topics_is_as_long_as_its_longest_frame() {
        let text = TAKE_AND_RETURN_FD.replace(
            "[topics.grasped]            # Grasped: status, 10 Hz while the hand holds the object\ncan_id = 0x130\n",
            "[topics.grasped]\ncan_id = 0x130\nfd = true\nlength = 12\n",
        );
        let network = parse(&text);
        let timing = timing(&network);
        let (stream, hand) = row(&timing, "hand.command (republished)");
        assert!(stream.fd);
        assert_eq!((stream.length, stream.also_classic), (12, Some(8)));
        // A classic 8-byte frame (135 bits at 2 µs) is longer than a 12-byte FD frame with BRS
        // (32 nominal bits, 155 data bits: 141.5 µs).
        assert_eq!(row(&timing, "grasped").1.c_ns, 141_500);
        assert_eq!(hand.c_ns, 270_000);
        assert!(
            timing
                .table()
                .contains("  hand.command (republished)  0x202          12  both")
        );
    }
}
