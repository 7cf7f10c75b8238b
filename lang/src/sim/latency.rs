//! The timed bus's measured latencies against the worst-case response times of `pabctl check`
//! (`pabctl sim --timed-bus`).
//!
//! Each frame the timed bus carried ([`super::timed`]) is given to the analysed stream it
//! belongs to ([`crate::check::bus::streams`]): a topic's or a gateway's by its identifier, a
//! protocol frame by its identifier (service and source), a BLE claim by its node and group
//! whatever its eligibility. Per stream, the worst latency (queued to the end of its EOF) is
//! compared with R, the bound from the start of its period to its end on the bus (the
//! intermission included): with a queue time no earlier than the period's start and an end no
//! later than R's, a latency above R means the analysis or the simulator is wrong.
//!
//! The bound holds only under the analysis's assumptions, so a latency is compared only where
//! they held:
//!
//! - **the stream's own frames** come no faster than its period and jitter allow: any two of
//!   them, k apart in the stream, are queued at least k·T − J apart (T rounded down and J up as
//!   the analysis has them). The frames that break this with the ones before them (a scenario
//!   that sends a topic faster than its `period`, a node's FilterStatus answering a filter
//!   command besides its heartbeat group's) are **beyond its period**: outside the analysis,
//!   not compared, and counted as frames the analysis does not know; the stream's other frames,
//!   which make up the sporadic stream it assumes, are compared. Each stream says how many of
//!   its frames that leaves out, and the first;
//! - **what it waited for**: the frames the analysis does not count (frames of no analysed
//!   stream, such as the nodes' identity announced at start-up, and frames beyond their
//!   stream's period) may delay it beyond R. A frame is not compared when such a frame went on
//!   the bus before it in the same busy stretch (the bus busy without a gap until its own start)
//!   and ranks above it (or has its identifier), or is longer than the longest lower frame the
//!   analysis lets block it. Its stream says how many of its frames that leaves out, and behind
//!   what;
//! - a stream whose identifier another analysed stream shares (a value port's per contributor)
//!   is not compared: which of them sent a frame is not known.
//!
//! The frames of no analysed stream are listed by identifier, never dropped silently.

use std::collections::HashMap;

use pab_core::Frame;
use pab_core::protocol::{FrameKind, classify};

use super::timed::{Clock, TimedRun, Transmission};
use crate::check::bus::{Timing, duration, id_text, milliseconds};
use crate::diagnostic::Diagnostic;
use crate::network::Network;

/// How an analysed stream's latencies compare with its bound.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Every compared latency is at most R.
    Within,
    /// A compared latency exceeds R: the analysis or the simulator is wrong.
    Above,
    /// The bus carried none of its frames.
    NoFrames,
    /// The analysis has no bound for it (it fails `pabctl check`).
    Unbounded,
    /// Its latencies are not compared: why.
    Outside(String),
}

/// The frames of a stream left out of the comparison because they waited behind frames the
/// analysis does not count.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Behind {
    /// How many.
    pub frames: usize,
    /// When the first of them was queued, µs.
    pub first_us: u64,
    /// Their largest latency, in [`Clock`] units: what the frames ahead cost them (it may
    /// exceed R, which does not count those).
    pub worst_latency: u128,
    /// What they waited behind (names, in order of first appearance).
    pub ahead: Vec<String>,
}

/// One analysed stream on the timed bus.
#[derive(Clone, Debug)]
pub struct StreamLatency {
    /// The stream, by index into the timing's streams.
    pub stream: usize,
    /// Its frames the bus carried.
    pub frames: usize,
    /// Of them, the frames whose latency is compared with R.
    pub compared: usize,
    /// The compared frame of the largest latency (the first of equal ones).
    pub worst: Option<Transmission>,
    /// Its latency, in [`Clock`] units.
    pub worst_latency: u128,
    /// The longest wait for the bus (queued to SOF) of the compared frames, in [`Clock`] units.
    pub worst_wait: u128,
    /// R in [`Clock`] units, if the analysis has a bound.
    pub bound: Option<u128>,
    /// The comparison.
    pub verdict: Verdict,
    /// Its frames beyond its period, not compared (and not counted for the others).
    pub faster: Option<Faster>,
    /// Frames not compared for what they waited behind.
    pub behind: Option<Behind>,
}

/// The frames of a stream that came closer to its earlier frames than its period and jitter
/// allow: outside the analysis, whose sporadic stream the others (its kept frames) make up.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Faster {
    /// How many.
    pub frames: usize,
    /// When the first of them was queued, µs.
    pub first_us: u64,
    /// How close it came, to which frame, against which period and jitter.
    pub detail: String,
}

/// The frames of one identifier that belong to no analysed stream.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Unmatched {
    /// The identifier.
    pub id: u32,
    /// Extended.
    pub extended: bool,
    /// What they are, as far as the network and the protocol say.
    pub name: String,
    /// How many the bus carried.
    pub frames: usize,
    /// When the first was queued, µs.
    pub first_us: u64,
    /// Their largest latency, in [`Clock`] units.
    pub worst_latency: u128,
}

/// The timed bus's latencies, stream by stream, against the analysis at the same rates.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// The bus's clock.
    pub clock: Clock,
    /// The rates, as `pabctl check` says them.
    pub rates: String,
    /// Frames carried.
    pub carried: usize,
    /// Frames still waiting, or on the bus, when the run ended.
    pub unsent: usize,
    /// One per analysed stream, in the timing's order (rank).
    pub streams: Vec<StreamLatency>,
    /// The frames of no analysed stream, by identifier in order of rank.
    pub unmatched: Vec<Unmatched>,
}

/// Whom a carried frame belongs to.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Owner {
    Stream(usize),
    /// Several analysed streams share its identifier (a value port's streams per contributor,
    /// two dynamics groups' Gates of one node): which one sent it is not known.
    Shared,
    Nobody,
}

/// The analysed stream `frame` belongs to.
fn owner(
    network: &Network,
    timing: &Timing,
    by_id: &HashMap<(u32, bool), Vec<usize>>,
    frame: &Frame,
) -> Owner {
    if classify(frame) == FrameKind::Claim {
        let Ok(claim) = pab_core::ble::Claim::decode(frame) else {
            return Owner::Nobody;
        };
        let Some(node) = network.nodes.iter().position(|n| n.id == claim.node) else {
            return Owner::Nobody;
        };
        // The claim's group is its position among the node's groups, in network order.
        let Some(group) = network
            .groups
            .iter()
            .enumerate()
            .filter(|(_, g)| g.member(node).is_some())
            .nth(usize::from(claim.group))
            .map(|(index, _)| index)
        else {
            return Owner::Nobody;
        };
        return timing
            .streams
            .streams
            .iter()
            .position(|s| s.claim.is_some_and(|c| c.node == node && c.group == group))
            .map_or(Owner::Nobody, Owner::Stream);
    }
    match by_id.get(&frame.raw_id()).map(Vec::as_slice) {
        Some([one]) => Owner::Stream(*one),
        Some([_, _, ..]) => Owner::Shared,
        _ => Owner::Nobody,
    }
}

/// What a frame of no analysed stream is, as far as the network and the protocol say.
fn describe(network: &Network, frame: &Frame) -> String {
    let id = frame.id();
    match classify(frame) {
        FrameKind::Service(service) => {
            let source = network
                .nodes
                .iter()
                .find(|n| n.id == service.source)
                .map_or_else(
                    || match service.source {
                        pab_core::protocol::TOOL => "the tool".to_string(),
                        pab_core::protocol::INTENTION => "the intention node".to_string(),
                        other => format!("node {other}"),
                    },
                    |n| n.name.clone(),
                );
            format!("{source}: {:?}", service.service)
        }
        FrameKind::Claim => "a BLE claim of no analysed group".into(),
        FrameKind::UnknownService => "a service this version does not know".into(),
        FrameKind::Topic => {
            if let Some(topic) = network.topics.iter().find(|t| t.filter.matches(&id)) {
                return format!("topic {} (no `period`)", topic.name);
            }
            let (raw, extended) = frame.raw_id();
            if let Some(port) = network.ports.iter().find(|p| match p.consumer {
                pab_core::consumer::Consumer::Republish(output) => {
                    output.raw() == raw && output.is_extended() == extended
                }
                _ => false,
            }) {
                return format!("{} (republished)", port.name);
            }
            "no topic of the network".into()
        }
    }
}

/// The frames of one stream beyond its period: of `queued` (µs, in queueing order), those that
/// break a period of `period` and a jitter of `jitter` ([`Clock`] units) with the frames kept
/// before them. A frame is kept when, with every frame kept before it, any two kept frames k
/// apart are queued at least k·period − jitter apart (the sporadic stream with jitter the
/// analysis assumes); the others are extra. Returns the extra frames' positions and, for the
/// first of them, the kept frame it came too close to and how many kept frames apart they are.
fn beyond_period(
    clock: &Clock,
    queued: &[u64],
    period: u128,
    jitter: u128,
) -> (Vec<usize>, Option<(u64, u64, usize)>) {
    let period = i128::try_from(period).unwrap_or(i128::MAX);
    let jitter = i128::try_from(jitter).unwrap_or(i128::MAX);
    // a_j − a_i ≥ (j − i)·T − J for every kept i < j  ⇔  a_j − j·T ≥ max_i(a_i − i·T) − J,
    // j counting kept frames: the running maximum and the kept frame that reached it.
    let mut best: Option<(i128, u64, i128)> = None;
    let mut kept: i128 = 0;
    let mut extra = Vec::new();
    let mut first = None;
    for (position, &t) in queued.iter().enumerate() {
        let a = i128::try_from(clock.at_us(t)).unwrap_or(i128::MAX);
        let value = a.saturating_sub(period.saturating_mul(kept));
        if let Some((max, at, index)) = best
            && value < max.saturating_sub(jitter)
        {
            extra.push(position);
            first.get_or_insert((at, t, usize::try_from(kept - index).unwrap_or(0)));
            continue;
        }
        // The latest of equal values: a violation is reported with the closest kept frame.
        if best.is_none_or(|(max, _, _)| value >= max) {
            best = Some((value, t, kept));
        }
        kept += 1;
    }
    (extra, first)
}

/// Compares the timed bus's run with `timing`, the analysis of the network at the same rates
/// (`crate::check::bus::timing`). Refused when the timing has no analysis or another bus.
pub fn compare(network: &Network, timing: &Timing, run: &TimedRun) -> Result<Comparison, String> {
    let clock = run.clock;
    let Some(analysis) = &timing.analysis else {
        return Err("the network has no bus to analyse".into());
    };
    if analysis.base != clock.base {
        return Err(format!(
            "the analysis is at {}, not at the timed bus's rates",
            analysis.rates()
        ));
    }
    let streams = &timing.streams.streams;
    let scale = clock.per_base_unit();
    let mut by_id: HashMap<(u32, bool), Vec<usize>> = HashMap::new();
    for (index, stream) in streams.iter().enumerate() {
        if stream.claim.is_none() {
            by_id
                .entry((stream.id, stream.extended))
                .or_default()
                .push(index);
        }
    }
    let owners: Vec<Owner> = run
        .transmissions
        .iter()
        .map(|t| owner(network, timing, &by_id, &t.frame))
        .collect();
    // Each stream's frames (by transmission), in the order they were queued.
    let mut queued: Vec<Vec<usize>> = vec![Vec::new(); streams.len()];
    for (k, owner) in owners.iter().enumerate() {
        if let Owner::Stream(s) = owner {
            queued[*s].push(k);
        }
    }
    for frames in &mut queued {
        frames.sort_by_key(|&k| (run.transmissions[k].queued_us, k));
    }
    // The streams whose identifier other streams share: not compared at all.
    let shared: Vec<bool> = streams
        .iter()
        .enumerate()
        .map(|(index, stream)| {
            by_id
                .get(&(stream.id, stream.extended))
                .is_some_and(|s| s.len() > 1 && s.contains(&index))
        })
        .collect();
    // The frames beyond their stream's period, and per stream what to say of them.
    let mut extra = vec![false; run.transmissions.len()];
    let mut faster: Vec<Option<Faster>> = vec![None; streams.len()];
    for (index, (row, frames)) in analysis.rows.iter().zip(&queued).enumerate() {
        let times: Vec<u64> = frames
            .iter()
            .map(|&k| run.transmissions[k].queued_us)
            .collect();
        let period = u128::from(row.period) * scale;
        let jitter = u128::from(row.jitter) * scale;
        let (beyond, first) = beyond_period(&clock, &times, period, jitter);
        for &position in &beyond {
            extra[frames[position]] = true;
        }
        if let Some((before, at, apart)) = first {
            faster[index] = Some(Faster {
                frames: beyond.len(),
                first_us: at,
                detail: format!(
                    "queued at {} s, {} after its frame of {} s ({apart} frame{} before it), less than {apart} × {} − {} (its period and jitter as analysed)",
                    super::seconds_text(at),
                    milliseconds(clock.ns(clock.at_us(at) - clock.at_us(before))),
                    super::seconds_text(before),
                    if apart == 1 { "" } else { "s" },
                    duration(clock.ns(period)),
                    duration(clock.ns(jitter)),
                ),
            });
        }
    }
    // What the analysis does not count: frames of no stream, of a shared identifier, or beyond
    // their stream's period.
    let uncounted = |k: usize| match owners[k] {
        Owner::Stream(s) => shared[s] || extra[k],
        Owner::Shared | Owner::Nobody => true,
    };
    // The longest frame the analysis lets block each stream: its lower streams' and the
    // background's longest, in clock units.
    let base = &analysis.base;
    let blocking: Vec<u128> = streams
        .iter()
        .map(|m| {
            let lower = streams
                .iter()
                .filter(|k| k.key > m.key || (k.key == m.key && !std::ptr::eq(*k, m)))
                .map(|k| k.frame_time(base));
            let background = timing
                .streams
                .background
                .iter()
                .filter(|b| b.key > m.key)
                .map(|b| base.frame(b.fd, b.length, true));
            u128::from(lower.chain(background).max().unwrap_or(0)) * scale
        })
        .collect();
    let name_of = |index: usize| -> String {
        match &owners[index] {
            Owner::Stream(s) if extra[index] => {
                format!("{} (beyond its period)", streams[*s].name)
            }
            Owner::Stream(s) => streams[*s].name.clone(),
            _ => describe(network, &run.transmissions[index].frame),
        }
    };
    let mut rows: Vec<StreamLatency> = streams
        .iter()
        .zip(&analysis.rows)
        .zip(faster)
        .enumerate()
        .map(|(index, ((_, row), faster))| StreamLatency {
            stream: index,
            frames: 0,
            compared: 0,
            worst: None,
            worst_latency: 0,
            worst_wait: 0,
            bound: row.response.bound().map(|r| u128::from(r) * scale),
            verdict: Verdict::NoFrames,
            faster,
            behind: None,
        })
        .collect();
    // The uncounted frames of the current busy stretch (the bus busy without a gap), by index.
    let mut stretch: Vec<usize> = Vec::new();
    for (k, t) in run.transmissions.iter().enumerate() {
        let contiguous = k > 0 && run.transmissions[k - 1].end == t.start;
        if !contiguous {
            stretch.clear();
        }
        if let Owner::Stream(s) = owners[k] {
            let row = &mut rows[s];
            row.frames += 1;
            let rank = t.frame.arbitration_rank();
            // Ahead of it and not counted: ranked above it (or the same identifier: a frame of
            // its own stream beyond its period, first in first out), or longer than what the
            // analysis lets block it.
            let ahead: Vec<usize> = stretch
                .iter()
                .copied()
                .filter(|&l| {
                    let other = &run.transmissions[l];
                    other.frame.arbitration_rank() <= rank
                        || u128::from(other.bits.time(base)) * scale > blocking[s]
                })
                .collect();
            if shared[s] || extra[k] {
                // Not compared: said by the verdict, or by `faster`.
            } else if !ahead.is_empty() {
                let behind = row.behind.get_or_insert(Behind {
                    frames: 0,
                    first_us: t.queued_us,
                    worst_latency: 0,
                    ahead: Vec::new(),
                });
                behind.frames += 1;
                behind.worst_latency = behind.worst_latency.max(t.latency(&clock));
                for l in ahead {
                    let name = name_of(l);
                    if !behind.ahead.contains(&name) {
                        behind.ahead.push(name);
                    }
                }
            } else {
                row.compared += 1;
                let latency = t.latency(&clock);
                if row.worst.is_none() || latency > row.worst_latency {
                    row.worst = Some(*t);
                    row.worst_latency = latency;
                }
                row.worst_wait = row.worst_wait.max(t.wait(&clock));
            }
        }
        if uncounted(k) {
            stretch.push(k);
        }
    }
    for (row, &shared) in rows.iter_mut().zip(&shared) {
        row.verdict = if shared {
            let stream = &streams[row.stream];
            Verdict::Outside(format!(
                "other analysed streams have its identifier {}: which of them sent a frame is not known",
                id_text(stream.id, stream.extended)
            ))
        } else if row.frames == 0 {
            Verdict::NoFrames
        } else if row.compared == 0 {
            Verdict::Outside(
                "every frame of it was beyond its period or waited behind frames the analysis does not count"
                    .into(),
            )
        } else {
            match row.bound {
                None => Verdict::Unbounded,
                Some(bound) if row.worst_latency > bound => Verdict::Above,
                Some(_) => Verdict::Within,
            }
        };
    }
    let mut unmatched: Vec<(u32, Unmatched)> = Vec::new();
    for (t, owner) in run.transmissions.iter().zip(&owners) {
        if *owner != Owner::Nobody {
            continue;
        }
        let (id, extended) = t.frame.raw_id();
        let latency = t.latency(&clock);
        match unmatched
            .iter_mut()
            .find(|(_, u)| u.id == id && u.extended == extended)
        {
            Some((_, entry)) => {
                entry.frames += 1;
                entry.worst_latency = entry.worst_latency.max(latency);
            }
            None => unmatched.push((
                t.frame.arbitration_rank(),
                Unmatched {
                    id,
                    extended,
                    name: describe(network, &t.frame),
                    frames: 1,
                    first_us: t.queued_us,
                    worst_latency: latency,
                },
            )),
        }
    }
    unmatched.sort_by_key(|(rank, _)| *rank);
    Ok(Comparison {
        clock,
        rates: analysis.rates(),
        carried: run.transmissions.len(),
        unsent: run.unsent.len(),
        streams: rows,
        unmatched: unmatched.into_iter().map(|(_, u)| u).collect(),
    })
}

/// The first three of `names`, and how many more.
fn first_few(names: &[String]) -> String {
    match names {
        [a, b, c, rest @ ..] if !rest.is_empty() => {
            format!("{a}, {b}, {c} and {} more", rest.len())
        }
        _ => names.join(", "),
    }
}

/// `units` of `clock` as milliseconds with three decimals, rounded up to the microsecond: a
/// latency is never shown shorter than it was.
fn ms_up(clock: &Clock, units: u128) -> String {
    let us = units.div_ceil(clock.per_us());
    format!("{}.{:03} ms", us / 1000, us % 1000)
}

impl Comparison {
    /// Every compared latency within its bound.
    pub fn holds(&self) -> bool {
        self.streams.iter().all(|s| s.verdict != Verdict::Above)
    }

    /// The streams whose latencies were compared (at least one frame each).
    pub fn compared(&self) -> impl Iterator<Item = &StreamLatency> {
        self.streams
            .iter()
            .filter(|s| matches!(s.verdict, Verdict::Within | Verdict::Above))
    }

    /// Why `pabctl sim --timed-bus` fails: each stream a latency of which exceeds its bound, at
    /// the line that declares it.
    pub fn errors(&self, network: &Network, timing: &Timing) -> Vec<Diagnostic> {
        self.streams
            .iter()
            .filter(|s| s.verdict == Verdict::Above)
            .filter_map(|s| {
                let stream = timing.streams.streams.get(s.stream)?;
                let worst = s.worst?;
                Some(network.error(
                    stream.span.clone(),
                    format!(
                        "`{}` ({}): a frame queued at {} s took {} on the timed bus at {}, above its worst-case response time R = {}: the analysis or the simulator is wrong",
                        stream.name,
                        id_text(stream.id, stream.extended),
                        super::seconds_text(worst.queued_us),
                        ms_up(&self.clock, s.worst_latency),
                        self.rates,
                        s.bound.map_or("?".into(), |b| ms_up(&self.clock, b)),
                    ),
                ))
            })
            .collect()
    }

    /// The table `pabctl sim --timed-bus` prints: per analysed stream its frames, how many are
    /// compared, the worst wait and latency among them, R and the verdict; then why some are not
    /// compared, the frames of no analysed stream, and the conclusion.
    pub fn table(&self, timing: &Timing) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        let streams = &timing.streams.streams;
        let _ = writeln!(
            out,
            "timed bus at {}: {} frames carried, {} still waiting at the end (latency: queued to the end of its EOF; R: `pabctl check`'s bound)",
            self.rates, self.carried, self.unsent
        );
        let width = streams
            .iter()
            .map(|s| s.name.chars().count())
            .max()
            .unwrap_or(6)
            .max(6);
        let _ = writeln!(
            out,
            "  {:width$}  {:10}  {:>6}  {:>8}  {:>11}  {:>13}  {:>11}  verdict",
            "stream", "id", "frames", "compared", "worst wait", "worst latency", "R"
        );
        for row in &self.streams {
            let Some(stream) = streams.get(row.stream) else {
                continue;
            };
            let (wait, latency) = if row.compared > 0 {
                (
                    ms_up(&self.clock, row.worst_wait),
                    ms_up(&self.clock, row.worst_latency),
                )
            } else {
                ("-".into(), "-".into())
            };
            let verdict = match &row.verdict {
                Verdict::Within => "within",
                Verdict::Above => "ABOVE R",
                Verdict::NoFrames => "no frames",
                Verdict::Unbounded => "no bound",
                Verdict::Outside(_) => "not compared",
            };
            let _ = writeln!(
                out,
                "  {:width$}  {:10}  {:>6}  {:>8}  {:>11}  {:>13}  {:>11}  {verdict}",
                stream.name,
                id_text(stream.id, stream.extended),
                row.frames,
                row.compared,
                wait,
                latency,
                row.bound
                    .map_or("unbounded".into(), |b| ms_up(&self.clock, b)),
            );
        }
        for row in &self.streams {
            let Some(stream) = streams.get(row.stream) else {
                continue;
            };
            if let Verdict::Outside(why) = &row.verdict {
                let _ = writeln!(out, "  {}: not compared: {why}", stream.name);
            }
            if let Some(faster) = &row.faster {
                let _ = writeln!(
                    out,
                    "  {}: {} frame{} beyond its period, not compared (frames the analysis does not count, for the others): the first {}",
                    stream.name,
                    faster.frames,
                    if faster.frames == 1 { "" } else { "s" },
                    faster.detail
                );
            }
            if let Some(behind) = &row.behind {
                let _ = writeln!(
                    out,
                    "  {}: {} frame{} not compared (the first queued at {} s, the longest latency {}): {} waited behind frames the analysis does not count: {}",
                    stream.name,
                    behind.frames,
                    if behind.frames == 1 { "" } else { "s" },
                    super::seconds_text(behind.first_us),
                    ms_up(&self.clock, behind.worst_latency),
                    if behind.frames == 1 { "it" } else { "they" },
                    first_few(&behind.ahead)
                );
            }
        }
        for unmatched in &self.unmatched {
            let _ = writeln!(
                out,
                "  no analysed stream: {} ({}): {} frame{}, the first queued at {} s, worst latency {}",
                unmatched.name,
                id_text(unmatched.id, unmatched.extended),
                unmatched.frames,
                if unmatched.frames == 1 { "" } else { "s" },
                super::seconds_text(unmatched.first_us),
                ms_up(&self.clock, unmatched.worst_latency),
            );
        }
        let compared = self.compared().count();
        let frames: usize = self.compared().map(|s| s.compared).sum();
        let above = self
            .streams
            .iter()
            .filter(|s| s.verdict == Verdict::Above)
            .count();
        if above == 0 {
            let _ = writeln!(
                out,
                "every compared latency within its bound: {compared} stream{}, {frames} frame{}",
                if compared == 1 { "" } else { "s" },
                if frames == 1 { "" } else { "s" },
            );
        } else {
            let _ = writeln!(
                out,
                "latencies above their bound in {above} stream{} of {compared} compared",
                if above == 1 { "" } else { "s" },
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::bus::timing;
    use crate::check::response::Response;
    use crate::diagnostic::Source;
    use crate::sim::{Options, simulate};

    const TAKE_AND_RETURN: &str = include_str!("../../../examples/take-and-return.toml");

    fn timed(text: &str) -> (Network, Timing, TimedRun) {
        let network = Network::parse(Source::new("net.toml", text)).unwrap();
        let compiled = crate::compile::compile(&network).unwrap();
        let options = Options {
            timed_bus: true,
            ..Options::default()
        };
        let outcome = simulate(&network, &compiled, &options).unwrap();
        let timing = timing(&network);
        (network, timing, outcome.timed.unwrap())
    }

    fn row<'a>(comparison: &'a Comparison, timing: &Timing, name: &str) -> &'a StreamLatency {
        comparison
            .streams
            .iter()
            .find(|r| timing.streams.streams[r.stream].name == name)
            .unwrap_or_else(|| panic!("no stream {name}"))
    }

    #[test]
    fn the_frames_beyond_a_period_are_found_one_by_one() {
        let clock = Clock::new(1_000_000, None);
        // Period 100 µs, no jitter: 0, 100, 200 keep it; in 0, 100, 199, 300 the third is
        // beyond it (99 after the second), and the fourth is kept (200 after the second).
        assert_eq!(
            beyond_period(&clock, &[0, 100, 200], 100, 0),
            (Vec::new(), None)
        );
        assert_eq!(
            beyond_period(&clock, &[0, 100, 199, 300], 100, 0),
            (vec![2], Some((100, 199, 1)))
        );
        // With 10 µs of jitter any two frames k apart may be 10 µs closer than k periods, no
        // more: 0, 95, 200, 290 and 0, 110, 200 keep it; 10, 100, 190 does not (its first and
        // third frames 180 apart, two periods less 10 is 190), though each neighbour is 90 apart.
        assert_eq!(
            beyond_period(&clock, &[0, 95, 200, 290], 100, 10).0,
            Vec::<usize>::new()
        );
        assert_eq!(
            beyond_period(&clock, &[0, 110, 200], 100, 10).0,
            Vec::<usize>::new()
        );
        assert_eq!(
            beyond_period(&clock, &[10, 100, 190], 100, 10),
            (vec![2], Some((10, 190, 2)))
        );
        // Drift never accumulates past the jitter: 0, 99, 198 with 1 µs of jitter.
        assert_eq!(
            beyond_period(&clock, &[0, 99, 198], 100, 1),
            (vec![2], Some((0, 198, 2)))
        );
        // Twice as fast: every other frame is beyond the period.
        let doubled: Vec<u64> = (0..10).map(|k| 50 * k).collect();
        assert_eq!(
            beyond_period(&clock, &doubled, 100, 0).0,
            vec![1, 3, 5, 7, 9]
        );
    }

    /// Take and Return's streams all keep their periods on the timed bus, so every one of them is
    /// compared, and its frames come within their bounds; only the traffic frames queued at 0 s
    /// behind the nodes' identity announcements (no analysed stream) are left out.
    #[test]
    fn take_and_return_is_within_its_bounds() {
        let (network, timing, run) = timed(TAKE_AND_RETURN);
        let comparison = compare(&network, &timing, &run).unwrap();
        assert!(comparison.holds());
        assert!(comparison.errors(&network, &timing).is_empty());
        assert_eq!(comparison.compared().count(), timing.streams.streams.len());
        let traffic = row(&comparison, &timing, "gaze: Traffic");
        let behind = traffic.behind.as_ref().unwrap();
        assert_eq!((behind.frames, behind.first_us), (1, 0));
        assert_eq!(behind.ahead.len(), 18);
        assert!(behind.ahead[0].ends_with(": Identity"), "{behind:?}");
        assert!(
            comparison
                .unmatched
                .iter()
                .all(|u| u.name.contains(": Identity") && u.first_us == 0)
        );
        let table = comparison.table(&timing);
        assert!(
            table.contains(
                "  object_pos                  0x110          160       160     0.000 ms       0.248 ms     0.590 ms  within"
            ),
            "{table}"
        );
        assert!(table.contains("gaze: Errors: 1 frame not compared (the first queued at 0.000000 s, the longest latency 9.478 ms): it waited behind frames the analysis does not count: arm: Identity, hand: Identity, gaze: Identity and 15 more"), "{table}");
    }

    /// A bound made smaller than a measured latency is reported, at the stream's line: the
    /// comparison is one that can fail.
    #[test]
    fn a_latency_above_its_bound_fails_at_the_streams_line() {
        let (network, mut timing, run) = timed(TAKE_AND_RETURN);
        let index = timing
            .streams
            .streams
            .iter()
            .position(|s| s.name == "grasped")
            .unwrap();
        let honest = compare(&network, &timing, &run).unwrap();
        let worst = honest.streams[index].worst_latency;
        let analysis = timing.analysis.as_mut().unwrap();
        // One unit of the analysis (a bit time) under the worst latency, in bit times.
        let scale = run.clock.per_base_unit();
        let r = u64::try_from(worst.div_ceil(scale)).unwrap() - 1;
        analysis.rows[index].response = Response::Bounded {
            r,
            blocking: 0,
            instances: 1,
        };
        let comparison = compare(&network, &timing, &run).unwrap();
        assert!(!comparison.holds());
        assert_eq!(comparison.streams[index].verdict, Verdict::Above);
        let errors: Vec<String> = comparison
            .errors(&network, &timing)
            .iter()
            .map(ToString::to_string)
            .collect();
        let line = TAKE_AND_RETURN
            .lines()
            .position(|l| l.starts_with("can_id = 0x130"))
            .unwrap()
            + 2;
        assert_eq!(errors.len(), 1, "{errors:#?}");
        assert!(
            errors[0].starts_with(&format!(
                "net.toml:{line}:10: error: `grasped` (0x130): a frame queued at "
            )),
            "{errors:#?}"
        );
        assert!(
            errors[0].contains("above its worst-case response time R = 0.994 ms: the analysis or the simulator is wrong"),
            "{errors:#?}"
        );
        assert!(
            comparison
                .table(&timing)
                .contains("latencies above their bound in 1 stream of 23 compared")
        );
    }

    /// A scenario that sends a topic twice as fast as its `period`: every other frame of it is
    /// beyond its period, not compared, and the frames that waited behind those are not either;
    /// the rest are compared.
    #[test]
    fn a_topic_faster_than_its_period_is_compared_on_its_periodic_frames() {
        let text = TAKE_AND_RETURN.replacen(
            "topic = \"object_pos\"\nrate_hz = 10.0\n",
            "topic = \"object_pos\"\nrate_hz = 20.0\n",
            1,
        );
        let (network, timing, run) = timed(&text);
        let comparison = compare(&network, &timing, &run).unwrap();
        let object = row(&comparison, &timing, "object_pos");
        let faster = object.faster.as_ref().unwrap();
        // Its first cycle (10 s to 18 s) at 20 Hz: 80 frames beyond its period of 0.1 s.
        assert_eq!((faster.frames, faster.first_us), (80, 10_050_000));
        assert_eq!(
            faster.detail,
            "queued at 10.050000 s, 50.000 ms after its frame of 10.000000 s (1 frame before it), less than 1 × 100 ms − 0 ms (its period and jitter as analysed)"
        );
        assert_eq!((object.frames, object.compared), (240, 160));
        assert_eq!(object.verdict, Verdict::Within);
        // The gateways that re-publish the extra frames have theirs beyond their period too,
        // and the frames that waited behind those are not compared: the others are, within.
        let gaze = row(&comparison, &timing, "gaze.target (republished)");
        assert!(gaze.faster.is_some() && gaze.behind.is_some());
        assert!(gaze.compared > 0);
        assert!(comparison.holds());
        let table = comparison.table(&timing);
        assert!(
            table.contains("  object_pos: 80 frames beyond its period, not compared (frames the analysis does not count, for the others): the first queued at 10.050000 s"),
            "{table}"
        );
    }
}
