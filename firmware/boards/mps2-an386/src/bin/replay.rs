//! `pab-an386-replay`: the node application on the emulated Cortex-M4, fed recorded frames in
//! virtual time, recording every verdict (and the sent frames of a node that runs a schema
//! server): the board's side of the cross-runner test. Built with the package's `schema` feature
//! (the node application's schema server), which the board's own firmware does not have yet.
//!
//! Reads a replay job file from the host (`pab_app::replay::job`: the nodes' table images and the
//! timestamped frames), boots one `pab_app::BoardNode` per node (the boards' capacities: 4 ports,
//! 64 connections, 256 decision nodes, 8 KiB images) from its image the way a board boots from
//! its store, feeds every frame to every node through `Node::on_frame` at the frame's time
//! (`pab_app::replay::feed`, the code the Linux-node runner uses), and writes the record
//! (`pab_app::replay::records`) to a host file. Both files go through semihosting.
//!
//!     qemu-system-arm -M mps2-an386 -nographic -monitor none \
//!         -semihosting-config enable=on,target=native,arg=replay,arg=JOB,arg=RECORDS \
//!         -kernel target/thumbv7em-none-eabihf/firmware/pab-an386-replay
//!
//! (or `cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf --bin
//! pab-an386-replay -- -append "JOB RECORDS"`; paths without spaces, relative to QEMU's working
//! directory). Exit status 0: every frame replayed and every node booted; 1: anything else, with
//! the reason on standard error. An image a board refuses (too large for its capacities) is
//! written in the record as refused, and the run ends with status 1.
//!
//! No allocation, no panic: fixed buffers (up to [`MAX_NODES`] nodes on the stack, frames read
//! [`FRAMES_PER_READ`] at a time, the record written in 4 KiB pieces).

#![no_std]
#![no_main]
#![deny(
    clippy::panic,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::unreachable,
    clippy::todo,
    clippy::unimplemented
)]

#[path = "replay/host_file.rs"]
mod host_file;

use core::fmt;

use cortex_m_rt::entry;
use pab_app::replay::job::{self, JobError, JobHeader, NodeEntry, TimedFrame};
use pab_app::replay::{self, Recorder, records};
use pab_app::{BoardNode, Config};
use pab_core::Instant;
use pab_fw_an386::semihosting;

use host_file::{Buffered, HostError, HostFile, Mode};

/// The most nodes one job may hold (each a `BoardNode` of about 14 KiB on the stack; the
/// emulated board has 4 MiB of RAM).
const MAX_NODES: usize = 8;
/// Frames read from the job file per semihosting call.
const FRAMES_PER_READ: usize = 128;
/// Bytes of record written per semihosting call.
const WRITE_PIECE: usize = 4096;

/// Why a replay failed.
enum Error {
    Usage,
    Host(&'static str, HostError),
    Job(JobError),
    TooManyNodes(u8),
    NodeId(u8),
    TimeGoesBack { frame: u32 },
    TrailingBytes,
    Store { frame: u32 },
    Record,
    Refused { nodes: usize },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Usage => f.write_str(
                "usage: pab-an386-replay JOB RECORDS (semihosting arguments: \
                 -semihosting-config ...,arg=replay,arg=JOB,arg=RECORDS)",
            ),
            Error::Host(what, error) => write!(f, "{what}: {error}"),
            Error::Job(error) => write!(f, "job file: {error}"),
            Error::TooManyNodes(count) => {
                write!(f, "job file: {count} nodes (this binary runs {MAX_NODES})")
            }
            Error::NodeId(id) => write!(f, "job file: node id {id} is outside 1..=127"),
            Error::TimeGoesBack { frame } => {
                write!(f, "job file: frame {frame} is earlier than the one before")
            }
            Error::TrailingBytes => f.write_str("job file: bytes after the last frame"),
            Error::Store { frame } => {
                write!(
                    f,
                    "frame {frame} made a node store a table (a table transfer)"
                )
            }
            Error::Record => f.write_str("the record could not be written"),
            Error::Refused { nodes } => write!(
                f,
                "{nodes} node(s) refused their image (see the record's `# node` lines)"
            ),
        }
    }
}

impl From<JobError> for Error {
    fn from(error: JobError) -> Self {
        Error::Job(error)
    }
}

#[entry]
fn main() -> ! {
    match run() {
        Ok((frames, verdicts, sent)) => {
            semihosting::eprint(format_args!(
                "pab-an386-replay: {frames} frames, {verdicts} verdicts, {sent} sent\n"
            ));
            semihosting::exit(true)
        }
        Err(error) => {
            semihosting::eprint(format_args!("pab-an386-replay: error: {error}\n"));
            semihosting::exit(false)
        }
    }
}

/// The replay: (frames fed, verdicts recorded, sent frames recorded).
fn run() -> Result<(u64, u64, u64), Error> {
    let mut command_line = [0u8; 1024];
    let arguments = host_file::command_line(&mut command_line)
        .map_err(|error| Error::Host("command line", error))?;
    let mut words = arguments.split_ascii_whitespace();
    let _program = words.next();
    let (Some(job_path), Some(records_path), None) = (words.next(), words.next(), words.next())
    else {
        return Err(Error::Usage);
    };
    let mut input =
        HostFile::open(job_path, Mode::Read).map_err(|error| Error::Host("job file", error))?;
    let mut output = HostFile::open(records_path, Mode::Write)
        .map_err(|error| Error::Host("record file", error))?;
    let mut out: Buffered<'_, WRITE_PIECE> = Buffered::new(&mut output);
    let read_error = |error| Error::Host("job file", error);

    let mut header = [0u8; job::HEADER_LEN];
    input.read_exact(&mut header).map_err(read_error)?;
    let header = JobHeader::decode(&header)?;
    if usize::from(header.nodes) > MAX_NODES {
        return Err(Error::TooManyNodes(header.nodes));
    }
    records::write_preamble(&mut out).map_err(|_| Error::Record)?;
    let mut nodes: [Option<BoardNode>; MAX_NODES] = [const { None }; MAX_NODES];
    let mut refused = 0;
    for slot in nodes.iter_mut().take(usize::from(header.nodes)) {
        let mut entry = [0u8; job::NODE_LEN];
        input.read_exact(&mut entry).map_err(read_error)?;
        let entry = NodeEntry::decode(&entry)?;
        let config = Config::new(entry.node_id).map_err(|_| Error::NodeId(entry.node_id))?;
        let node = slot.insert(BoardNode::new(config, Instant::from_micros(0)));
        let len = usize::try_from(entry.image_len).unwrap_or(usize::MAX);
        match node.boot_buffer().get_mut(..len) {
            Some(room) => input.read_exact(room).map_err(read_error)?,
            // Larger than the board's transfer buffer: skip it; `boot` records the refusal.
            None => skip(&mut input, entry.image_len).map_err(read_error)?,
        }
        if replay::boot(node, len, Instant::from_micros(0), &mut out).is_err() {
            refused += 1;
        }
    }
    records::write_columns(&mut out).map_err(|_| Error::Record)?;

    let mut recorder = Recorder::new(out);
    let mut chunk = [0u8; job::FRAME_LEN * FRAMES_PER_READ];
    let mut remaining = header.frames;
    let mut index = 0u32;
    let mut previous = 0u64;
    while remaining > 0 {
        let count = remaining.min(FRAMES_PER_READ as u32);
        let bytes = chunk
            .get_mut(..count as usize * job::FRAME_LEN)
            .ok_or(Error::Record)?;
        input.read_exact(bytes).map_err(read_error)?;
        for piece in bytes.chunks_exact(job::FRAME_LEN) {
            let piece: &[u8; job::FRAME_LEN] = piece.try_into().map_err(|_| Error::Record)?;
            let frame = TimedFrame::decode(piece)?;
            if frame.t_us < previous {
                return Err(Error::TimeGoesBack { frame: index });
            }
            previous = frame.t_us;
            for node in nodes.iter_mut().flatten() {
                if replay::feed(node, &frame, &mut recorder) {
                    return Err(Error::Store { frame: index });
                }
            }
            index = index.saturating_add(1);
        }
        remaining -= count;
    }
    if input.read(&mut [0u8; 1]).map_err(read_error)? != 0 {
        return Err(Error::TrailingBytes);
    }
    let (verdicts, sent) = (recorder.verdicts(), recorder.sent_frames());
    let mut out = recorder
        .finish(u64::from(header.frames))
        .map_err(|_| Error::Record)?;
    out.flush()
        .map_err(|error| Error::Host("record file", error))?;
    if refused > 0 {
        return Err(Error::Refused { nodes: refused });
    }
    Ok((u64::from(header.frames), verdicts, sent))
}

/// Reads and drops `len` bytes.
fn skip(input: &mut HostFile, len: u32) -> Result<(), HostError> {
    let mut scratch = [0u8; 256];
    let mut left = usize::try_from(len).unwrap_or(usize::MAX);
    while left > 0 {
        let piece = scratch.get_mut(..left.min(256)).ok_or(HostError::Read)?;
        input.read_exact(piece)?;
        left -= piece.len();
    }
    Ok(())
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    semihosting::exit(false)
}
