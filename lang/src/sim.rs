//! The simulator: every node of a network on one simulated bus, in virtual time.
//!
//! Each node is the node application itself, a `pab_app::FullNode` booted at time 0 from its
//! compiled table image: the same bytes and the same code as a board, so a simulation shows what
//! the robot will do. The node arbitrates, re-publishes, claims its BLE tasks, steps its
//! dynamics and sends their Gates, applies HBBA's filter commands, sends its heartbeats and
//! faults; the simulator only carries the frames, keeps the time and watches. Nothing here
//! decides who delivers.
//!
//! The bus is ideal (no transmission time, no loss) and deterministic: frames due at the same
//! microsecond go out in CAN arbitration order (lower identifier first; a standard frame before
//! an extended one with the same 11 base bits), then in the order of the `[[events]]`; what the
//! nodes send follows the events of its instant, heard by every other node at once.
//!
//! The nodes boot at 0, before the frames of time 0: their first heartbeats and BLE claims (which
//! offer 0: nothing heard yet) and the dynamics' t_0 (contexts sampled then) come first. A node
//! handles the frames of one instant one after the other and does its own work after each, as a
//! board does with a burst it reads at one timestamp: a dynamics step due at that instant is
//! taken after the first of them, and the others count from the next step.
//!
//! A node of the file's `[[faults]]` stops at its time: from that microsecond on (a frame sent at
//! the same microsecond included) it receives nothing, sends nothing and its ports deliver
//! nothing; its timelines show nobody from then on and its plotted levels drop to 0. Its peers
//! take its BLE task over once its last claim is two periods old.
//!
//! The timelines also follow the ports between frames: each port is read when an activity may
//! lapse (a microsecond after τ has passed since a connection's last accepted frame) and after
//! every instant's work, so they show the moment a port changes hands even when no frame arrives
//! then. A value port (`combine = ...`) delivers the combined output when it changes
//! ([`pab_core::value_port`]): its trace rows mark `delivered` on the connection whose frame was
//! handed over, and its timeline follows the output's connection.
//!
//! With [`Options::timed_bus`] the bus takes time instead ([`timed`]): each frame occupies it for
//! its transmission time at the network's `[bus]` rates, the bus starts the waiting frame that
//! wins arbitration whenever it is free, and every node receives a frame when it has ended;
//! [`Outcome::timed`] holds each frame's queueing, start and end, so its latency, which
//! [`latency`] compares with the bounds of `pabctl check`. The ideal bus stays the default: with
//! the option off, nothing of the timed bus runs.
//!
//! [`run`] is the same bus fed with any timed frames: a capture's, for `pabctl replay`
//! (see [`crate::replay`]); what the nodes send is dropped there (the capture is the bus). With
//! [`Options::records`] it also writes every verdict in the record format of
//! [`pab_app::replay::records`], the one the other runners write.

use std::collections::BinaryHeap;

use embedded_can::{ExtendedId, Id, StandardId};
use pab_app::replay::{Recorder, records};

use crate::compile::CompiledNode;
use crate::network::{MAX_TIME_S, Network};
use crate::series::Sample;
use run::Run;
use station::Station;

mod dynamics;
pub mod intention;
pub mod latency;
pub mod plant;
mod report;
mod run;
pub mod schema;
mod station;
pub mod timed;

pub use dynamics::{DynamicsRow, write_csv as write_dynamics_csv};
pub use intention::IntentionRun;
// The conversions live with the model, which reads times too; kept here for the tools' paths.
pub use crate::time::{micros, seconds_text};

/// How to run a simulation.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// Stop at this time, seconds. Default: when the last frame's effects have decayed (the last
    /// frame plus the longest τ, or the end of the last phase or the last fault, whichever is
    /// later).
    pub until: Option<f64>,
    /// Record stimulation samples for a plot.
    pub samples: bool,
    /// Write every verdict as a record line ([`Outcome::records`]).
    pub records: bool,
    /// Step the `[dynamics.*]` groups and record their states ([`Outcome::dynamics`]).
    pub dynamics: bool,
    /// Carry the frames on a timed bus at the network's `[bus]` rates ([`timed`]) instead of the
    /// ideal one, and record each frame's latency ([`Outcome::timed`]). Refused without a
    /// `[bus]`, and in a replay (its frames are the capture's, timed by its own bus).
    pub timed_bus: bool,
}

/// A frame on the simulated bus and when it is sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BusFrame {
    /// When, µs.
    pub t_us: u64,
    /// The frame (an event's frames carry its `data`, by default its topic's `length` of zeros).
    pub frame: pab_core::Frame,
}

/// One row of the trace: a frame's effect on one connection it fed, after the update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceRow {
    /// When, µs.
    pub t_us: u64,
    /// The connection, as an index into the network's connections.
    pub connection: usize,
    /// Its stimulation after the frame.
    pub level: f64,
    /// Whether it is active after the frame.
    pub active: bool,
    /// Whether the frame was delivered through it.
    pub delivered: bool,
}

/// A change of the connection selected at a port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Change {
    /// When, µs.
    pub t_us: u64,
    /// The connection whose frames get through from then on (network index), or nobody.
    pub selected: Option<usize>,
}

/// What a simulation produced.
#[derive(Clone, Debug)]
pub struct Outcome {
    /// The end of the simulated time, µs.
    pub until_us: u64,
    /// Frames put on the bus.
    pub frames: usize,
    /// Trace rows in time order, ties in the order of the connections in the file.
    pub rows: Vec<TraceRow>,
    /// Per port (network order), the changes of its selected connection, starting with nobody at 0.
    pub timelines: Vec<Vec<Change>>,
    /// Per connection (network order), stimulation samples for plots (empty unless requested).
    pub samples: Vec<Vec<Sample>>,
    /// Every verdict in the record format (empty unless [`Options::records`]).
    pub records: String,
    /// The BLE claims the nodes sent, in bus order (none when the frames were given: [`run`]).
    pub claims: Vec<BusFrame>,
    /// Per BLE group (network order), the changes of who holds its task, starting with nobody at
    /// 0: node indices, in network order (more than one during a transient).
    pub holdings: Vec<Vec<Holding>>,
    /// The `[dynamics.*]` groups' states, one row per behaviour per step, in time order, then
    /// group and behaviour order (empty unless [`Options::dynamics`]).
    pub dynamics: Vec<DynamicsRow>,
    /// The Gates frames the nodes sent, in bus order.
    pub gates: Vec<BusFrame>,
    /// Every frame the nodes sent (heartbeats, BLE claims, Gates, filter status, faults,
    /// re-published frames), in bus order (none in a replay, [`run`]: its bus is the capture).
    pub sent: Vec<BusFrame>,
    /// HBBA's intention node on the `[[desires]]` ([`intention`]), with `[hbba]` in
    /// [`simulate`] only (a replay has no script); its frames are in [`Outcome::sent`].
    pub intention: Option<IntentionRun>,
    /// Every frame on the simulated bus in the order it carried them: the events' (with the
    /// scripted desires to the intention node) and what the nodes sent (none in a replay,
    /// [`run`]: its bus is the capture). `--candump` writes it. On the timed bus, each at the
    /// microsecond the nodes received it.
    pub bus: Vec<BusFrame>,
    /// What the timed bus did: every frame's queueing, start and end (with
    /// [`Options::timed_bus`] only).
    pub timed: Option<timed::TimedRun>,
}

/// A change of the nodes that hold a BLE group's task.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Holding {
    /// When, µs.
    pub t_us: u64,
    /// The nodes that hold it from then on (network indices, in order).
    pub holders: Vec<usize>,
}

/// Why a simulation could not run.
#[derive(Debug)]
pub struct SimError(pub String);

impl std::fmt::Display for SimError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SimError {}

/// Runs `network` with the tables `compiled` (one per node, from [`crate::compile::compile`]) on
/// the frames of its `[[events]]`.
pub fn simulate(
    network: &Network,
    compiled: &[CompiledNode],
    options: &Options,
) -> Result<Outcome, SimError> {
    let frames = event_frames(network)?;
    let until_us = match options.until {
        Some(until) if (0.0..=MAX_TIME_S).contains(&until) => micros(until),
        Some(until) => {
            return Err(SimError(format!(
                "--until {until} is not a time in [0, {MAX_TIME_S}] seconds"
            )));
        }
        None => default_until(network, &frames),
    };
    let stops: Vec<(u64, usize)> = network
        .faults
        .iter()
        .map(|fault| (micros(fault.at), fault.node))
        .collect();
    // HBBA's intention node on the same bus: the scripted desires are Desire frames to it,
    // before the topics' frames of their instant.
    let setup = match &network.hbba {
        Some(_) => Some(crate::compile::intention_setup(network).map_err(SimError)?),
        None => None,
    };
    let desires = if setup.is_some() {
        intention::desire_frames(network, until_us)
    } else {
        Vec::new()
    };
    let mut all: Vec<(u64, u8, BusFrame)> = desires
        .iter()
        .map(|f| (f.t_us, 0, *f))
        .chain(frames.iter().map(|f| (f.t_us, 1, *f)))
        .collect();
    all.sort_by_key(|(t, kind, _)| (*t, *kind));
    let frames: Vec<BusFrame> = all.into_iter().map(|(_, _, f)| f).collect();
    run_stopping(
        network,
        compiled,
        &frames,
        until_us,
        options,
        &stops,
        Some(&setup),
        &mut |_| {},
    )
}

/// Runs `network` with the tables `compiled` on `frames` (in the order given, which must be time
/// order) until `until_us`: frames after it are not sent. `progress` is called with the number
/// of frames sent so far, every 65 536 frames and at the end. Nothing here reads
/// [`Options::until`].
pub fn run(
    network: &Network,
    compiled: &[CompiledNode],
    frames: &[BusFrame],
    until_us: u64,
    options: &Options,
    progress: &mut dyn FnMut(usize),
) -> Result<Outcome, SimError> {
    run_stopping(
        network,
        compiled,
        frames,
        until_us,
        options,
        &[],
        None,
        progress,
    )
}

/// [`run`], with nodes that stop: `(t_us, node)`, the node as an index into the network's nodes.
/// With `intention` (a simulation), what the nodes send goes on the bus, and the intention node
/// runs on that setup if there is one; without (a replay: the bus is the frames given, claims
/// and Gates included), what the nodes send is dropped, as on a replayed node.
#[allow(clippy::too_many_arguments)]
fn run_stopping(
    network: &Network,
    compiled: &[CompiledNode],
    frames: &[BusFrame],
    until_us: u64,
    options: &Options,
    stops: &[(u64, usize)],
    intention: Option<&Option<pab_intent::Setup>>,
    progress: &mut dyn FnMut(usize),
) -> Result<Outcome, SimError> {
    let broadcast = intention.is_some();
    let timed = if options.timed_bus {
        if !broadcast {
            return Err(SimError(
                "the timed bus carries a simulation's frames; a replay's are the capture's, already timed by the bus they were captured on".into(),
            ));
        }
        let Some(bus) = &network.bus else {
            return Err(SimError(
                "the timed bus needs the bus's bit rate: the network has no [bus] (add `[bus]` with `bitrate = 500000`, and `data_bitrate` for CAN FD)".into(),
            ));
        };
        Some(timed::TimedBus::new(timed::Clock::new(
            bus.bitrate,
            bus.data_bitrate,
        )))
    } else {
        None
    };
    let intent = match intention.and_then(Option::as_ref) {
        Some(setup) => Some(station::IntentStation::new(setup)?),
        None => None,
    };
    if frames
        .windows(2)
        .any(|pair| matches!(pair, [a, b] if b.t_us < a.t_us))
    {
        return Err(SimError("the frames are not in time order".into()));
    }
    let mut records = String::new();
    let _ = records::write_preamble(&mut records);
    let mut stations = Vec::new();
    for (node_index, node) in network.nodes.iter().enumerate() {
        let Some(table) = compiled.iter().find(|c| c.id == node.id) else {
            return Err(SimError(format!(
                "no compiled table for node `{}`",
                node.name
            )));
        };
        let stop_us = stops
            .iter()
            .filter(|(_, node)| *node == node_index)
            .map(|(t, _)| *t)
            .min();
        stations.push(Station::boot(
            node_index,
            node,
            &table.image,
            stop_us,
            &mut records,
        )?);
    }
    let _ = records::write_columns(&mut records);
    let mut run = Run {
        network,
        stations,
        options,
        broadcast,
        recorder: options.records.then(|| Recorder::new(records)),
        rows: Vec::new(),
        timelines: network
            .ports
            .iter()
            .map(|_| {
                vec![Change {
                    t_us: 0,
                    selected: None,
                }]
            })
            .collect(),
        samples: vec![Vec::new(); network.connections.len()],
        holdings: network
            .groups
            .iter()
            .map(|_| {
                vec![Holding {
                    t_us: 0,
                    holders: Vec::new(),
                }]
            })
            .collect(),
        dynamics_rows: Vec::new(),
        wakes: BinaryHeap::new(),
        outgoing: Vec::new(),
        sent: Vec::new(),
        bus: Vec::new(),
        intent,
        timed,
    };
    let fed = run.go(frames, until_us, progress)?;
    let records = run.finish_records(fed);
    let mut rows = run.rows;
    rows.sort_by_key(|row| (row.t_us, row.connection));
    let mut dynamics = run.dynamics_rows;
    dynamics.sort_by_key(|row| (row.t_us, row.group, row.behaviour));
    let claims = run
        .sent
        .iter()
        .filter(|f| pab_core::protocol::classify(&f.frame) == pab_core::protocol::FrameKind::Claim)
        .copied()
        .collect();
    let gates = run
        .sent
        .iter()
        .filter(|f| run::is_gates(&f.frame))
        .copied()
        .collect();
    Ok(Outcome {
        until_us,
        frames: fed,
        rows,
        timelines: run.timelines,
        samples: run.samples,
        records,
        claims,
        holdings: run.holdings,
        dynamics,
        gates,
        sent: run.sent,
        intention: run.intent.map(|intent| intent.run),
        bus: run.bus,
        timed: run.timed.map(timed::TimedBus::finish),
    })
}

/// The frames of the network's events, in bus order: by time, then CAN arbitration order, then
/// the order of the events in the file. Each carries its event's `data`.
pub fn event_frames(network: &Network) -> Result<Vec<BusFrame>, SimError> {
    let mut frames = Vec::new();
    for (sequence, event) in network.events.iter().enumerate() {
        let Some(topic) = network.topics.get(event.topic) else {
            continue;
        };
        let filter = topic.filter;
        let id = if filter.is_extended() {
            ExtendedId::new(filter.id()).map(Id::Extended)
        } else {
            u16::try_from(filter.id())
                .ok()
                .and_then(StandardId::new)
                .map(Id::Standard)
        }
        .ok_or_else(|| SimError(format!("topic `{}` has an invalid CAN id", topic.name)))?;
        // CAN arbitration compares the 11 base bits first; on a tie a standard frame wins.
        let base = if filter.is_extended() {
            filter.id() >> 18
        } else {
            filter.id()
        };
        // A CAN FD topic's events are CAN FD frames, switching their bit rate when the bus's
        // data phase is faster (the simulator's bus has no timing: the flag is carried as sent).
        let brs = network
            .bus
            .as_ref()
            .and_then(|bus| bus.data_bitrate.map(|data| data > bus.bitrate))
            .unwrap_or(false);
        let frame = if topic.fd {
            pab_core::Frame::fd(id, &event.data, brs)
        } else {
            pab_core::Frame::data(id, &event.data)
        }
        .ok_or_else(|| {
            SimError(format!(
                "an event of topic `{}` has {} bytes of data, more than its frames carry",
                topic.name,
                event.data.len()
            ))
        })?;
        for t in event.schedule.times() {
            frames.push((
                (micros(t), base, filter.is_extended(), filter.id(), sequence),
                BusFrame {
                    t_us: micros(t),
                    frame,
                },
            ));
        }
    }
    frames.sort_by_key(|(order, _)| *order);
    Ok(frames.into_iter().map(|(_, frame)| frame).collect())
}

/// The default end of a simulation: once the last frame's effects have decayed, or at the end of
/// the last phase, the last fault or the last scripted desire, whichever is later, rounded up to
/// a tenth of a second.
fn default_until(network: &Network, frames: &[BusFrame]) -> u64 {
    let after_phases = network
        .phases
        .iter()
        .map(|p| micros(p.to))
        .chain(network.faults.iter().map(|f| micros(f.at)))
        .chain(network.desires.iter().map(|d| micros(d.to)))
        .max()
        .unwrap_or(0);
    // Round up to a tenth of a second.
    settled_until(network, frames)
        .max(after_phases)
        .div_ceil(100_000)
        .saturating_mul(100_000)
}

/// The time by which the effects of `frames` on `network` have decayed: the last frame plus the
/// longest τ plus 1 µs (so the last lapse shows in the timelines), rounded up to a tenth of a
/// second.
pub fn settled_until(network: &Network, frames: &[BusFrame]) -> u64 {
    let longest_decay = network
        .connections
        .iter()
        .map(|c| u64::from(c.stimulation.decay_us()))
        .max()
        .unwrap_or(0);
    let after_frames = frames.last().map_or(0, |frame| {
        frame.t_us.saturating_add(longest_decay).saturating_add(1)
    });
    after_frames.div_ceil(100_000).saturating_mul(100_000)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;
    use embedded_can::Frame as _;

    /// A CAN FD topic's events are CAN FD frames (with BRS on a bus whose data phase is faster),
    /// and a value port reads its field past byte 8 and re-publishes the value as a CAN FD frame.
    #[test]
    fn an_fd_topic_is_simulated_with_can_fd_frames() {
        let text = "[bus]\nbitrate = 500000\ndata_bitrate = 2000000\n[nodes.base]\nid = 4\n\
                    [topics.range]\ncan_id = 0x1A0\nfd = true\nlength = 12\n\
                    [ports.\"base.nearest\"]\ncombine = \"max\"\nvalue = { offset = 10, size = 2 }\n\
                    republish = { can_id = 0x300 }\n\
                    [connections.R]\ntopic = \"range\"\nport = \"base.nearest\"\nst = 1.0\ntc = 0.3\n\
                    [[events]]\ntopic = \"range\"\nat = [0.1]\n\
                    data = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x34, 0x12]\n";
        let network = Network::parse(Source::new("net.toml", text)).unwrap();
        let frames = event_frames(&network).unwrap();
        assert_eq!(frames.len(), 1);
        let frame = frames[0].frame;
        assert!(frame.is_fd() && frame.is_brs());
        assert_eq!(frame.data().len(), 12);
        let compiled = crate::compile::compile(&network).unwrap();
        let outcome = simulate(&network, &compiled, &Options::default()).unwrap();
        let republished: Vec<&pab_core::Frame> = outcome
            .sent
            .iter()
            .map(|f| &f.frame)
            .filter(|f| {
                f.id() == embedded_can::Id::Standard(embedded_can::StandardId::new(0x300).unwrap())
            })
            .collect();
        assert!(!republished.is_empty(), "{:?}", outcome.sent);
        let first = republished[0];
        assert!(first.is_fd(), "{first:?}");
        assert_eq!(
            first.data().get(10..12),
            Some(&[0x34, 0x12][..]),
            "{first:?}"
        );
    }

    /// On the timed bus two frames queued at once go out lower identifier first, back to back;
    /// every node receives each at the microsecond its EOF ends (rounded up), and a gateway's
    /// re-published frame is queued then, behind nothing: the second event frame is already on
    /// the bus, so it waits for it.
    #[test]
    fn the_timed_bus_delivers_each_frame_when_it_ends() {
        let text = "[bus]\nbitrate = 500000\n[nodes.hand]\nid = 2\n\
                    [topics.grasp]\ncan_id = 0x120\n[topics.release]\ncan_id = 0x110\n\
                    [ports.\"hand.command\"]\nrepublish = { can_id = 0x300 }\n\
                    [connections.G]\ntopic = \"grasp\"\nport = \"hand.command\"\nst = 1.0\ntc = 1.0\n\
                    [connections.R]\ntopic = \"release\"\nport = \"hand.command\"\nst = 1.0\ntc = 1.0\n\
                    rule = \"false\"\n\
                    [[events]]\ntopic = \"grasp\"\nat = [0.5]\n\
                    [[events]]\ntopic = \"release\"\nat = [0.5]\n";
        let network = Network::parse(Source::new("net.toml", text)).unwrap();
        let compiled = crate::compile::compile(&network).unwrap();
        let options = Options {
            timed_bus: true,
            ..Options::default()
        };
        let outcome = simulate(&network, &compiled, &options).unwrap();
        let run = outcome.timed.as_ref().unwrap();
        let clock = run.clock;
        let at = |id: u16| {
            run.transmissions
                .iter()
                .find(|t| {
                    t.frame.id()
                        == embedded_can::Id::Standard(embedded_can::StandardId::new(id).unwrap())
                })
                .unwrap_or_else(|| panic!("no frame {id:#x}: {:?}", run.transmissions))
        };
        let (release, grasp, republished) = (at(0x110), at(0x120), at(0x300));
        assert_eq!(release.start, clock.at_us(500_000));
        assert_eq!(grasp.start, release.end);
        assert_eq!(release.sender, timed::Sender::Scenario);
        // Its bits as sent: 500 kbit/s, 2 µs a bit, 1 µs units; delivered at its EOF's end.
        let bits = crate::can_frame::transmitted(&release.frame);
        assert_eq!(release.end - release.start, u128::from(bits.nominal) * 2);
        assert_eq!(release.end_of_frame, release.end - 6);
        assert_eq!(release.delivered_us, clock.ceil_us(release.end_of_frame));
        // The gateway re-publishes grasp's frame when it has it, and that waits for nothing.
        assert_eq!(republished.queued_us, grasp.delivered_us);
        assert_eq!(republished.sender, timed::Sender::Node(0));
        assert_eq!(
            republished.start,
            grasp.end.max(clock.at_us(grasp.delivered_us))
        );
        assert!(release.wait(&clock) == 0 && grasp.wait(&clock) == release.end - release.start);
        // The trace and the candump log see the frames when the nodes received them.
        let row = outcome.rows.iter().find(|r| r.delivered).unwrap();
        assert_eq!(row.t_us, grasp.delivered_us);
        assert!(
            outcome
                .bus
                .iter()
                .any(|f| f.t_us == republished.delivered_us && f.frame == republished.frame)
        );
        // The ideal bus, for comparison: everything at 0.5 s.
        let ideal = simulate(&network, &compiled, &Options::default()).unwrap();
        assert!(ideal.timed.is_none());
        assert_eq!(
            ideal.rows.iter().find(|r| r.delivered).unwrap().t_us,
            500_000
        );
    }

    #[test]
    fn the_timed_bus_needs_a_bus_and_a_simulation() {
        let text = include_str!("../../examples/first-network.toml");
        let network = Network::parse(Source::new("net.toml", text)).unwrap();
        let compiled = crate::compile::compile(&network).unwrap();
        let options = Options {
            timed_bus: true,
            ..Options::default()
        };
        let error = simulate(&network, &compiled, &options).unwrap_err();
        assert!(
            error
                .0
                .starts_with("the timed bus needs the bus's bit rate: the network has no [bus]"),
            "{error}"
        );
        let network = Network::parse(Source::new(
            "net.toml",
            format!("[bus]\nbitrate = 500000\n{text}"),
        ))
        .unwrap();
        let error = run(&network, &compiled, &[], 1_000_000, &options, &mut |_| {}).unwrap_err();
        assert!(error.0.contains("a replay's are the capture's"), "{error}");
    }
}
