//! Replays: timestamped frames fed to a node in virtual time, and the record of every verdict it
//! makes, so that runners (the simulator, the Linux node, the firmware on a Cortex-M4) can be
//! compared byte for byte.
//!
//! - [`records`]: the record format, one text line per verdict (raw Q1.31 levels, masks in hex),
//!   written with `core::fmt` (no allocation), and [`Recorder`], a [`crate::Recipient`] that
//!   writes them.
//! - [`job`]: the binary file that brings a board runner its tables and frames (a replay on a
//!   board reads it through semihosting).
//!
//! Both sides of each format live here, in the `no_std` application, so a host tool and a board
//! write and read them with the same code.

pub mod job;
pub mod records;

pub use records::Recorder;

use core::fmt::Write;

use pab_core::image::{self, Header};
use pab_core::protocol::TransferStatusCode;
use pab_core::{Frame, Instant, Refused};

use crate::node::{Node, status_of};

/// Boots `node` at `now` with the image in the first `len` bytes of its
/// [`Node::boot_buffer`], as a board boots from its store, and writes its `# node` record line.
/// Returns the running table's header, or the transfer status and detail byte the image was
/// refused with (then the node runs no table, and its verdicts are missing from the record: a
/// comparison with a runner that took the image fails at that line).
pub fn boot<const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut Node<P, C, N, IMG>,
    len: usize,
    now: Instant,
    out: &mut impl Write,
) -> Result<Header, (TransferStatusCode, u8)> {
    // The reason, if the image is refused: the loader's verdict at this node's capacities. Read
    // before booting because the boot buffer is the node's transfer buffer.
    let refusal = match node.boot_buffer().get(..len) {
        Some(bytes) => image::load_as::<P, C, N, Refused>(bytes)
            .err()
            .map(|error| status_of(&error)),
        None => Some((TransferStatusCode::TooLarge, 0)),
    };
    node.boot(Some(len), now);
    let outcome = match (node.running(), refusal) {
        (Some(running), _) => Ok(running.header),
        (None, Some(refusal)) => Err(refusal),
        // The loader took it but the arbiter did not (a table it cannot run).
        (None, None) => Err((TransferStatusCode::InvalidTable, 0)),
    };
    let _ = records::write_boot(out, node.config().node_id, outcome.as_ref().map_err(|e| *e));
    outcome
}

/// Feeds `frame` to `node` at its time, recording its verdicts with `recorder` under the node's
/// id. What the node sends is recorded only if it runs a schema server ([`records`] says why),
/// and otherwise dropped (heartbeats, re-published frames: a replay's bus is the capture).
/// Returns whether the node asked to store a table, which a replay never causes (its frames
/// hold no table transfer).
pub fn feed<const P: usize, const C: usize, const N: usize, const IMG: usize, W: Write>(
    node: &mut Node<P, C, N, IMG>,
    frame: &job::TimedFrame,
    recorder: &mut Recorder<W>,
) -> bool {
    recorder.node_id = node.config().node_id;
    if runs_schema_server(node) {
        feed_with(node, frame, recorder, &mut |recorder, sent, at| {
            recorder.sent(&sent, at)
        })
    } else {
        feed_with(node, frame, recorder, &mut |_, _, _| {})
    }
}

/// [`feed`], handing every frame the node sends, with the time it sent it, to `sent` (with the
/// recorder, which the node holds meanwhile). A closed-loop rig that reacts to what the node
/// sends drives it through this, so that a replay of the rig's bus wakes the node at the very
/// same instants.
pub fn feed_with<const P: usize, const C: usize, const N: usize, const IMG: usize, W: Write>(
    node: &mut Node<P, C, N, IMG>,
    frame: &job::TimedFrame,
    recorder: &mut Recorder<W>,
    sent: &mut impl FnMut(&mut Recorder<W>, Frame, Instant),
) -> bool {
    let now = frame.instant();
    // The node's own work between frames, at the instants it asks for, as its runner wakes it
    // (the steps of the dynamics it runs, which sample their contexts at those instants; its
    // heartbeats and claims; its schema server's ticks): what a live node would have done before
    // this frame arrived. A deadline that polling does not move is not polled again (the node
    // has nothing more due).
    let mut polled: Option<Instant> = None;
    loop {
        let due = node.deadline(now);
        let before = now.micros_since(due).is_some_and(|ahead| ahead > 0);
        if !before || polled == Some(due) {
            break;
        }
        let _ = node.poll(due, recorder);
        while let Some(out) = node.next_outgoing() {
            sent(recorder, out, due);
        }
        polled = Some(due);
    }
    let step = node.on_frame(&frame.frame, now, recorder);
    while let Some(out) = node.next_outgoing() {
        sent(recorder, out, now);
    }
    step == crate::Step::Store
}

/// Whether `node` runs a schema server (never, without the feature).
fn runs_schema_server<const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &Node<P, C, N, IMG>,
) -> bool {
    #[cfg(feature = "schema")]
    return node.schema().is_some();
    #[cfg(not(feature = "schema"))]
    {
        let _ = node;
        false
    }
}
