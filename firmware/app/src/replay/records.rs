//! The record of a replay: every verdict of every node, as text, exact.
//!
//! ```text
//! # pab replay records 2
//! # node 1: table version 1, crc 0x3c5a9e01
//! # node 3: image refused: table refused by the loader (status 0x17, detail 4)
//! t_us,id,ext,node,port,fed,resting,active,selected,delivered,levels
//! 500000,113,0,1,0,00002000,00000000,00002000,13,13,13:2147483648
//! > 501000,300,0,10,3075000000e6ff03
//! # end: 1234 frames, 567 verdicts, 1 sent
//! ```
//!
//! One line per frame and port it fed, in frame order, then node order (the order the runner
//! lists its nodes in), then port order:
//!
//! | column | meaning |
//! | --- | --- |
//! | `t_us` | the frame's time, µs since the replay's time 0, decimal |
//! | `id` | its CAN id in hex, 3 digits (standard) or 8 (extended), as candump writes it |
//! | `ext` | 1 for an extended id, else 0 |
//! | `node` | the node id |
//! | `port` | the port's index in the node's table |
//! | `fed`, `resting`, `active` | [`PortVerdict`]'s sets of the port's connections, 8 hex digits, bit i = connection i |
//! | `selected`, `delivered` | a connection index, or `-` for none |
//! | `levels` | for each fed connection, `index:level` with the level after the frame as its raw Q1.31 integer (2147483648 = 1.0), space-separated |
//!
//! A node that runs a schema server also has its **sent frames** recorded, one `>` line each, in
//! the order it sent them among the verdicts: `> t_us,id,ext,node,data` (the time it sent the
//! frame, the id as above, the payload in hex). What such a node decides is what it sends (the
//! drive's set-points, the schema transitions, the acknowledgements, its heartbeats too); other
//! nodes' sends (heartbeats, re-published frames) follow from their verdicts and are not
//! recorded.
//!
//! The `# node` lines say which table each node runs (or why its image was refused); the `# end`
//! line counts the frames fed and the lines written, so a runner that stopped early cannot match
//! one that did not.
//!
//! Format 2 added the `>` lines and the `# end` line's `sent`.

use core::fmt::{self, Write};

use pab_core::image::Header;
use pab_core::protocol::TransferStatusCode;
use pab_core::{Arbiter, Frame, Instant, Level, PortVerdict};

use crate::Recipient;

/// The format's first line.
pub const PREAMBLE: &str = "# pab replay records 2\n";
/// The column header, written after the `# node` lines.
pub const COLUMNS: &str = "t_us,id,ext,node,port,fed,resting,active,selected,delivered,levels\n";

/// Writes [`PREAMBLE`].
pub fn write_preamble(out: &mut impl Write) -> fmt::Result {
    out.write_str(PREAMBLE)
}

/// Writes the `# node` line of node `node_id`: the table it booted with, or the transfer status
/// and detail byte its image was refused with ([`crate::node::status_of`]).
pub fn write_boot(
    out: &mut impl Write,
    node_id: u8,
    outcome: Result<&Header, (TransferStatusCode, u8)>,
) -> fmt::Result {
    match outcome {
        Ok(header) => writeln!(
            out,
            "# node {node_id}: table version {}, crc 0x{:08x}",
            header.table_version, header.crc
        ),
        Err((status, detail)) => writeln!(
            out,
            "# node {node_id}: image refused: {status} (status 0x{:02x}, detail {detail})",
            status.code()
        ),
    }
}

/// Writes [`COLUMNS`].
pub fn write_columns(out: &mut impl Write) -> fmt::Result {
    out.write_str(COLUMNS)
}

/// Writes the line of `verdict`, the verdict of node `node_id` on `frame` at `t_us`. `level`
/// gives a connection's level after the frame (`None` prints as `-`, which no runner with the
/// table's arbiter produces).
pub fn write_verdict(
    out: &mut impl Write,
    t_us: u64,
    frame: &Frame,
    node_id: u8,
    verdict: &PortVerdict,
    level: impl Fn(u8) -> Option<Level>,
) -> fmt::Result {
    let (id, extended) = frame.raw_id();
    write!(out, "{t_us},")?;
    if extended {
        write!(out, "{id:08X},1,")?;
    } else {
        write!(out, "{id:03X},0,")?;
    }
    write!(
        out,
        "{node_id},{},{:08x},{:08x},{:08x},",
        verdict.port,
        verdict.fed.bits(),
        verdict.resting.bits(),
        verdict.active.bits()
    )?;
    write_index(out, verdict.selected)?;
    out.write_char(',')?;
    write_index(out, verdict.delivered)?;
    out.write_char(',')?;
    for (position, connection) in verdict.fed.iter().enumerate() {
        if position > 0 {
            out.write_char(' ')?;
        }
        match level(connection) {
            Some(level) => write!(out, "{connection}:{}", level.raw())?,
            None => write!(out, "{connection}:-")?,
        }
    }
    out.write_char('\n')
}

/// Writes the `>` line of `frame`, sent by node `node_id` at `t_us`.
pub fn write_sent(out: &mut impl Write, t_us: u64, frame: &Frame, node_id: u8) -> fmt::Result {
    let (id, extended) = frame.raw_id();
    write!(out, "> {t_us},")?;
    if extended {
        write!(out, "{id:08X},1,{node_id},")?;
    } else {
        write!(out, "{id:03X},0,{node_id},")?;
    }
    for byte in frame.payload() {
        write!(out, "{byte:02x}")?;
    }
    out.write_char('\n')
}

/// Writes the `# end` line.
pub fn write_end(out: &mut impl Write, frames: u64, verdicts: u64, sent: u64) -> fmt::Result {
    writeln!(
        out,
        "# end: {frames} frames, {verdicts} verdicts, {sent} sent"
    )
}

fn write_index(out: &mut impl Write, index: Option<u8>) -> fmt::Result {
    match index {
        Some(index) => write!(out, "{index}"),
        None => out.write_char('-'),
    }
}

/// A [`Recipient`] that writes every verdict of the node it is handed to as a record line.
///
/// One recorder serves all the nodes of a replay: set [`Recorder::node_id`] before each node's
/// [`crate::Node::on_frame`]. Deliveries are not recorded (the `delivered` column says it). The
/// first write error is kept ([`Recorder::failed`]) and later lines are not written, so a full
/// disk cannot produce a record that looks complete.
pub struct Recorder<W> {
    out: W,
    /// The node whose verdicts come next.
    pub node_id: u8,
    verdicts: u64,
    sent: u64,
    failed: bool,
}

impl<W: Write> Recorder<W> {
    /// A recorder writing to `out`, which should already hold the preamble, the `# node` lines
    /// and the columns.
    pub fn new(out: W) -> Self {
        Recorder {
            out,
            node_id: 0,
            verdicts: 0,
            sent: 0,
            failed: false,
        }
    }

    /// Lines written so far.
    pub fn verdicts(&self) -> u64 {
        self.verdicts
    }

    /// Sent frames recorded so far.
    pub fn sent_frames(&self) -> u64 {
        self.sent
    }

    /// Records `frame`, sent by [`Recorder::node_id`] at `now` (a `>` line). Identity frames are
    /// not recorded: they say what the build is (its name, its features), not what the node
    /// decided, and a replay compares runners built differently.
    pub fn sent(&mut self, frame: &Frame, now: Instant) {
        let identity = pab_core::protocol::FrameId::decode(&frame.id())
            .is_some_and(|id| pab_core::protocol::identity_part(id.service).is_some());
        if self.failed || identity {
            return;
        }
        match write_sent(&mut self.out, now.as_micros(), frame, self.node_id) {
            Ok(()) => self.sent = self.sent.wrapping_add(1),
            Err(_) => self.failed = true,
        }
    }

    /// Whether a write failed (nothing was written after it).
    pub fn failed(&self) -> bool {
        self.failed
    }

    /// The writer.
    pub fn writer(&mut self) -> &mut W {
        &mut self.out
    }

    /// Writes the `# end` line after `frames` frames and returns the writer, or `Err` if any
    /// write failed.
    pub fn finish(mut self, frames: u64) -> Result<W, fmt::Error> {
        if self.failed || write_end(&mut self.out, frames, self.verdicts, self.sent).is_err() {
            return Err(fmt::Error);
        }
        Ok(self.out)
    }
}

impl<W: Write> Recipient for Recorder<W> {
    const OBSERVES_VERDICTS: bool = true;

    fn deliver(&mut self, _port: u8, _frame: &Frame, _now: Instant) {}

    fn verdict<const P: usize, const C: usize, const N: usize>(
        &mut self,
        frame: &Frame,
        now: Instant,
        verdict: &PortVerdict,
        arbiter: &Arbiter<P, C, N>,
    ) {
        if self.failed {
            return;
        }
        let written = write_verdict(
            &mut self.out,
            now.as_micros(),
            frame,
            self.node_id,
            verdict,
            |connection| arbiter.level(verdict.port, connection, now),
        );
        match written {
            Ok(()) => self.verdicts = self.verdicts.wrapping_add(1),
            Err(_) => self.failed = true,
        }
    }
}
