//! Replays: a recorded capture through a network's tables, in virtual time.
//!
//! A capture's frames ([`crate::candump`]) become the frames of a bus whose time 0 is the
//! capture's earliest frame, in time order ([`Feed::from_capture`]), and go to one of three
//! runners, which all arbitrate with `pab-core` and write the same record
//! ([`pab_app::replay::records`]):
//!
//! - the simulator's bus ([`crate::sim::run`]), whose nodes are `pab_app::FullNode`s polled at
//!   their deadlines: what `pabctl replay` shows;
//! - the node application, one `pab_app::FullNode` per node (the Linux node's capacities),
//!   booted from its compiled image and fed through `Node::on_frame` ([`node_records`]);
//! - a board: [`job()`] writes the file that a board's replay binary reads
//!   (`pab-an386-replay` on the emulated Cortex-M4), which runs `pab_app::BoardNode`s through the
//!   same `pab_app::replay` code.
//!
//! **The project's own frames are not fed** (heartbeats, status, faults, the diagnostic stream,
//! table transfers: every id with the protocol's marker, `pab_core::protocol::classify`). A node
//! never arbitrates them (they are its protocol, not traffic), and a table transfer in the capture,
//! a push during the recorded run, would switch a node's table in the middle of the replay: a
//! replay evaluates the tables it is given on the application traffic. They are counted
//! ([`Feed::protocol_frames`]). **BLE claims, Gates and HBBA's filter commands (FilterSet,
//! FilterProfile) are the exception**: traffic that coordinates the nodes (who holds a task,
//! which gates are open, which connections the intention filters), they are fed like
//! application frames, and every runner hands them to the node's state; a claim to its
//! group state (a node's own claims, coming back from the capture, are refused by
//! it and change nothing). **So are the schema server's commands** (EmergencyStop, SchemaAbort,
//! SchemaTransfer): what a client or a stop button told a board's server, whose decisions the
//! replay records (a node's own flow control, coming back addressed to the tool, is not for it). Re-published frames of gateway ports are ordinary traffic in a
//! capture and are fed like any other; what the replayed nodes re-publish is dropped (the bus of
//! a replay is the capture).

use pab_app::FullNode;
use pab_app::replay::{self, Recorder, job};
use pab_core::Instant;
use pab_core::protocol;

use crate::candump::Capture;
use crate::compile::CompiledNode;
use crate::network::Network;
use crate::sim::BusFrame;

/// The frames a replay feeds, taken from a capture.
#[derive(Clone, Debug, Default)]
pub struct Feed {
    /// The application frames, µs since the capture's earliest frame, in time order.
    pub frames: Vec<BusFrame>,
    /// The project's protocol frames of the capture, not fed.
    pub protocol_frames: usize,
    /// The capture's earliest time (of any frame, protocol ones included), µs.
    pub first_us: u64,
    /// From the capture's earliest frame to its latest, µs.
    pub span_us: u64,
}

impl Feed {
    /// The frames of `capture` to feed, in time order: time 0 is its earliest frame (protocol
    /// frames included); protocol frames are left out.
    ///
    /// Time order, not file order: a capture made on a Linux host holds frames stamped by the
    /// kernel when their senders sent them, but written in the order the recorder's socket got
    /// them, which differs by milliseconds when several processes send (the project's own HIL
    /// logs do). The stamps are when the frames were on the bus. Frames with the same stamp keep
    /// the file's order.
    pub fn from_capture(capture: &Capture) -> Feed {
        let mut ordered: Vec<&crate::candump::Captured> = capture.frames.iter().collect();
        ordered.sort_by_key(|frame| frame.t_us);
        let first_us = ordered.first().map_or(0, |frame| frame.t_us);
        let last_us = ordered.last().map_or(0, |frame| frame.t_us);
        let mut feed = Feed {
            frames: Vec::with_capacity(capture.frames.len()),
            protocol_frames: 0,
            first_us,
            span_us: last_us.saturating_sub(first_us),
        };
        for captured in ordered {
            // BLE claims, Gates and HBBA's filter commands are fed: they are how the nodes
            // coordinate (who holds a task, which behaviours' gates are open, which connections
            // the intention filters).
            let kind = protocol::classify(&captured.frame);
            if kind.is_ours() && !is_coordination(kind) {
                feed.protocol_frames += 1;
                continue;
            }
            feed.frames.push(BusFrame {
                t_us: captured.t_us.saturating_sub(first_us),
                frame: captured.frame,
            });
        }
        feed
    }

    /// The fed frames whose id no topic of `network` matches, per id (raw, extended), with their
    /// counts, in id order: traffic the tables ignore.
    pub fn unmatched(&self, network: &Network) -> Vec<((u32, bool), usize)> {
        let mut counts = std::collections::BTreeMap::new();
        for frame in &self.frames {
            let id = frame.frame.id();
            if !network.topics.iter().any(|topic| topic.filter.matches(&id)) {
                *counts.entry(frame.frame.raw_id()).or_insert(0) += 1;
            }
        }
        counts.into_iter().collect()
    }
}

/// Why a replay could not run.
#[derive(Debug)]
pub struct ReplayError(pub String);

impl std::fmt::Display for ReplayError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ReplayError {}

/// The image compiled for each node of `network`, in the network's node order.
fn images<'a>(
    network: &Network,
    compiled: &'a [CompiledNode],
) -> Result<Vec<(u8, &'a [u8])>, ReplayError> {
    network
        .nodes
        .iter()
        .map(|node| {
            compiled
                .iter()
                .find(|c| c.id == node.id)
                .map(|c| (node.id, c.image.as_slice()))
                .ok_or_else(|| ReplayError(format!("no compiled table for node `{}`", node.name)))
        })
        .collect()
}

/// Runs `frames` through the node application: one [`FullNode`] per node of `network`, booted at
/// time 0 from its image in `compiled` the way a node boots from its store, each frame fed to
/// every node in network order through `Node::on_frame` at the frame's time. Returns the record.
///
/// Memory: one `FullNode` (about 82 KiB) per node, and the record.
pub fn node_records(
    network: &Network,
    compiled: &[CompiledNode],
    frames: &[BusFrame],
) -> Result<String, ReplayError> {
    let mut out = String::new();
    let _ = replay::records::write_preamble(&mut out);
    let mut nodes = Vec::new();
    for (network_node, (id, image)) in network.nodes.iter().zip(images(network, compiled)?) {
        let config = network_node.config();
        config
            .validate()
            .map_err(|error| ReplayError(format!("node {id}: {error}")))?;
        let mut node = Box::new(FullNode::new(config, Instant::from_micros(0)));
        let buffer = node.boot_buffer();
        let Some(room) = buffer.get_mut(..image.len()) else {
            return Err(ReplayError(format!(
                "node {id}: its image ({} bytes) exceeds the node's buffer ({} bytes)",
                image.len(),
                buffer.len()
            )));
        };
        room.copy_from_slice(image);
        let _ = replay::boot(&mut node, image.len(), Instant::from_micros(0), &mut out);
        nodes.push(node);
    }
    let _ = replay::records::write_columns(&mut out);
    let mut recorder = Recorder::new(out);
    for frame in frames {
        let timed = job::TimedFrame {
            t_us: frame.t_us,
            frame: frame.frame,
        };
        for node in nodes.iter_mut() {
            if replay::feed(node, &timed, &mut recorder) {
                return Err(ReplayError(format!(
                    "a node asked to store a table at {} µs: the replay fed it a table transfer",
                    frame.t_us
                )));
            }
        }
    }
    recorder
        .finish(frames.len() as u64)
        .map_err(|_| ReplayError("the record could not be written".into()))
}

/// The job file for a board's replay binary: the image of each node of `network` (in network
/// order) and `frames` (format: [`pab_app::replay::job`]).
pub fn job(
    network: &Network,
    compiled: &[CompiledNode],
    frames: &[BusFrame],
) -> Result<Vec<u8>, ReplayError> {
    // A job's frame records hold 8 data bytes: the board that reads them (the emulated board,
    // behind SLCAN) is a classic CAN node.
    if let Some(fd) = frames.iter().find(|frame| frame.frame.is_fd()) {
        return Err(ReplayError(format!(
            "the capture's frame at {} µs (after its first) is a CAN FD frame: a board job holds \
             classic frames only (the emulated board is a classic CAN node); replay CAN FD \
             captures without --board-job",
            fd.t_us
        )));
    }
    let images = images(network, compiled)?;
    let header = job::JobHeader {
        nodes: u8::try_from(images.len())
            .map_err(|_| ReplayError(format!("{} nodes: a job holds 255", images.len())))?,
        frames: u32::try_from(frames.len())
            .map_err(|_| ReplayError(format!("{} frames: a job holds 2^32", frames.len())))?,
    };
    let mut out = Vec::with_capacity(
        job::HEADER_LEN
            + images
                .iter()
                .map(|(_, image)| job::NODE_LEN + image.len())
                .sum::<usize>()
            + frames.len() * job::FRAME_LEN,
    );
    out.extend_from_slice(&header.encode());
    for (node_id, image) in images {
        let entry = job::NodeEntry {
            node_id,
            image_len: u32::try_from(image.len())
                .map_err(|_| ReplayError(format!("node {node_id}: image too large")))?,
        };
        out.extend_from_slice(&entry.encode());
        out.extend_from_slice(image);
    }
    for frame in frames {
        let timed = job::TimedFrame {
            t_us: frame.t_us,
            frame: frame.frame,
        };
        out.extend_from_slice(&timed.encode());
    }
    Ok(out)
}

/// Whether a frame of this kind is a BLE claim (`pab_core::ble`), a Gates frame
/// (`pab_core::dynamics`), an HBBA filter command or a schema server's command: of our protocol,
/// but traffic that a replay feeds.
fn is_coordination(kind: protocol::FrameKind) -> bool {
    match kind {
        protocol::FrameKind::Claim => true,
        protocol::FrameKind::Service(id) => matches!(
            id.service,
            protocol::Service::Gates
                | protocol::Service::FilterSet
                | protocol::Service::FilterProfile
                | protocol::Service::EmergencyStop
                | protocol::Service::SchemaAbort
                | protocol::Service::SchemaTransfer
        ),
        protocol::FrameKind::Topic | protocol::FrameKind::UnknownService => false,
    }
}
