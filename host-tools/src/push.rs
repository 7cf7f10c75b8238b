//! `pabctl push`: send a table image to a node over ISO-TP and wait until the node runs it.
//!
//! The sequence, per node (docs/can-protocol.md, "Table transfer"):
//! 1. ISO-TP transfer of the image to the node (service TableTransfer, tool → node), paced by the
//!    node's flow control;
//! 2. the node's TransferStatus: applied (and stored), already current, or why it refused;
//! 3. confirmation from the node's own heartbeat: a Heartbeat with the new table version followed
//!    by a TableStatus with the image's CRC. Only then is the push reported as done.
//!
//! Why so suspicious: a TransferStatus carries no transfer number. One that arrives before the
//! last frame was sent, or that names another running version, answers something else (an
//! earlier push that was cut short, another tool, a confused participant), so it never counts
//! as a success; and even the right answer counts only once the heartbeat shows the table.

use std::time::{Duration, Instant};

use pab_core::image::Header;
use pab_core::isotp::{FlowControlEffect, Sender, TxConfig, TxError, TxEvent};
use pab_core::protocol::{self, Message, TransferStatusCode};

use crate::bus::Bus;

/// How long to wait at each stage.
#[derive(Clone, Copy, Debug)]
pub struct Timeouts {
    /// For the TransferStatus after the last frame (the node may be writing flash).
    pub answer: Duration,
    /// For the heartbeat that confirms the new version (heartbeats come every second).
    pub confirm: Duration,
}

impl Default for Timeouts {
    fn default() -> Self {
        Timeouts {
            answer: Duration::from_secs(3),
            confirm: Duration::from_secs(4),
        }
    }
}

/// How a push to one node ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The node runs the new table; `stored` says whether it will boot with it.
    Confirmed {
        /// The version now running.
        version: u32,
        /// Whether the node stored it.
        stored: bool,
    },
    /// The node already ran this exact table.
    AlreadyCurrent {
        /// Its version.
        version: u32,
    },
    /// The node refused the table; its old table keeps running.
    Refused {
        /// Why.
        status: TransferStatusCode,
        /// The status's detail byte.
        detail: u8,
        /// The version the node still runs.
        running_version: u32,
    },
    /// The node did not answer (a timeout at some stage, said which).
    NoAnswer(String),
    /// The node answered, but its heartbeat does not show the new table.
    NotConfirmed(String),
}

impl Outcome {
    /// Whether the node runs the pushed table.
    pub fn is_success(&self) -> bool {
        matches!(
            self,
            Outcome::Confirmed { .. } | Outcome::AlreadyCurrent { .. }
        )
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Outcome::Confirmed {
                version,
                stored: true,
            } => write!(f, "runs version {version} (stored)"),
            Outcome::Confirmed {
                version,
                stored: false,
            } => write!(
                f,
                "runs version {version}, but NOT stored: it will boot with its old table"
            ),
            Outcome::AlreadyCurrent { version } => {
                write!(f, "already runs version {version} (unchanged)")
            }
            Outcome::Refused {
                status,
                detail,
                running_version,
            } => {
                write!(f, "refused: {status}")?;
                if *detail != 0 {
                    write!(f, " (detail {detail})")?;
                }
                write!(f, "; still runs version {running_version}")
            }
            Outcome::NoAnswer(why) => write!(f, "no answer: {why}"),
            Outcome::NotConfirmed(why) => write!(f, "not confirmed: {why}"),
        }
    }
}

/// Pushes `image` (whose header is `header`) to node `node`, reporting progress as
/// `(bytes sent, total)`.
pub fn push(
    bus: &mut dyn Bus,
    node: u8,
    image: &[u8],
    header: &Header,
    timeouts: Timeouts,
    progress: &mut dyn FnMut(usize, usize),
) -> std::io::Result<Outcome> {
    let clock = Clock::new();
    let mut sender = match Sender::new(image, TxConfig::default()) {
        Ok(sender) => sender,
        Err(error) => {
            return Ok(Outcome::NoAnswer(format!(
                "cannot send the image: {error:?}"
            )));
        }
    };
    // 1. The transfer.
    let mut cut_short = None;
    loop {
        let event = sender.poll(clock.now());
        match event {
            TxEvent::Send(data) => {
                let frame = Message::TableTransfer { data, len: 8 }.to_frame(protocol::TOOL, node);
                bus.send(&frame)?;
                let (sent, total) = sender.progress();
                progress(sent, total);
            }
            TxEvent::WaitUntil(until) => {
                let wait = clock.until(until);
                if let Some(frame) = bus.receive(wait)? {
                    match Message::decode(&frame) {
                        Ok((id, Message::TableTransfer { data, len }))
                            if id.source == node && id.destination == protocol::TOOL =>
                        {
                            let data = data.get(..usize::from(len)).unwrap_or(&data);
                            if let FlowControlEffect::Failed(error) =
                                sender.on_flow_control(data, clock.now())
                            {
                                return transfer_failed(bus, node, error, cut_short);
                            }
                        }
                        Ok((id, Message::TransferStatus(status)))
                            if id.source == node && id.destination == protocol::TOOL =>
                        {
                            match status.status {
                                // A transfer cut short ends with these; the one cut may be an
                                // earlier push (killed, then run again at once): kept, and
                                // reported only if this transfer fails too.
                                TransferStatusCode::Interrupted | TransferStatusCode::Timeout => {
                                    cut_short = Some(status);
                                }
                                // A success before the end cannot be about this image, which has
                                // not arrived whole: ignored.
                                code if code.is_success() => {}
                                // The node refused this transfer early (busy, too large).
                                _ => return Ok(refused(status)),
                            }
                        }
                        _ => {}
                    }
                }
            }
            TxEvent::Done => break,
            TxEvent::Failed(error) => return transfer_failed(bus, node, error, cut_short),
        }
    }
    // 2. The node's answer: a refusal, or a success that names the pushed version.
    let version = header.table_version;
    let answer = wait_for_status(bus, node, timeouts.answer, |status| {
        !status.status.is_success() || status.running_version == version
    })?;
    let outcome = match answer {
        None => {
            return Ok(Outcome::NoAnswer(format!(
                "no transfer status for version {version} within {:.1} s after the last frame",
                timeouts.answer.as_secs_f64()
            )));
        }
        Some(status) => match status.status {
            TransferStatusCode::Applied => Outcome::Confirmed {
                version,
                stored: true,
            },
            TransferStatusCode::AppliedNotStored => Outcome::Confirmed {
                version,
                stored: false,
            },
            TransferStatusCode::AlreadyCurrent => Outcome::AlreadyCurrent { version },
            _ => return Ok(refused(status)),
        },
    };
    // 3. The heartbeat must show it, whatever the answer said.
    confirm(bus, node, header, timeouts.confirm, outcome)
}

fn refused(status: protocol::TransferStatus) -> Outcome {
    Outcome::Refused {
        status: status.status,
        detail: status.detail,
        running_version: status.running_version,
    }
}

/// The transfer failed on our side; the node may still have said why (e.g. an overflow flow
/// control comes with a TooLarge status), or have said it during the transfer (`cut_short`: a
/// consecutive frame lost, our pace too slow).
fn transfer_failed(
    bus: &mut dyn Bus,
    node: u8,
    error: TxError,
    cut_short: Option<protocol::TransferStatus>,
) -> std::io::Result<Outcome> {
    if let Some(status) = wait_for_status(bus, node, Duration::from_millis(300), |status| {
        !status.status.is_success()
    })?
    .or(cut_short)
    {
        return Ok(refused(status));
    }
    let why = match error {
        TxError::Timeout => format!(
            "no flow control from node {node} within 1 s (is it on the bus? `pabctl nodes`)"
        ),
        TxError::Overflow => "the node refused the image as too large".to_string(),
        TxError::TooManyWaits => "the node kept asking to wait".to_string(),
        TxError::InvalidFlowStatus { status } => {
            format!("the node sent an invalid flow control (status {status})")
        }
    };
    Ok(Outcome::NoAnswer(why))
}

/// The first TransferStatus from `node` to the tool that `relevant` accepts, within `timeout`;
/// the others are stale or stray and are skipped.
fn wait_for_status(
    bus: &mut dyn Bus,
    node: u8,
    timeout: Duration,
    relevant: impl Fn(&protocol::TransferStatus) -> bool,
) -> std::io::Result<Option<protocol::TransferStatus>> {
    let end = Instant::now() + timeout;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Some(frame) = bus.receive(left)? else {
            break;
        };
        if let Ok((id, Message::TransferStatus(status))) = Message::decode(&frame)
            && id.source == node
            && id.destination == protocol::TOOL
            && relevant(&status)
        {
            return Ok(Some(status));
        }
    }
    Ok(None)
}

/// Waits for a Heartbeat with the new version, then the TableStatus of the same group with the
/// image's CRC.
fn confirm(
    bus: &mut dyn Bus,
    node: u8,
    header: &Header,
    timeout: Duration,
    outcome: Outcome,
) -> std::io::Result<Outcome> {
    let end = Instant::now() + timeout;
    let mut heard_version = None;
    let mut version_seen = false;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Some(frame) = bus.receive(left)? else {
            break;
        };
        match Message::decode(&frame) {
            Ok((id, Message::Heartbeat(heartbeat))) if id.source == node => {
                heard_version = Some(heartbeat.table_version);
                version_seen = heartbeat.table_version == header.table_version;
            }
            Ok((id, Message::TableStatus(status))) if id.source == node && version_seen => {
                if status.crc == header.crc {
                    return Ok(match outcome {
                        Outcome::Confirmed { version, .. } => Outcome::Confirmed {
                            version,
                            stored: status.stored,
                        },
                        other => other,
                    });
                }
                return Ok(Outcome::NotConfirmed(format!(
                    "the node reports version {} but CRC {:08x}, not {:08x}",
                    header.table_version, status.crc, header.crc
                )));
            }
            _ => {}
        }
    }
    Ok(Outcome::NotConfirmed(match heard_version {
        Some(version) => format!(
            "its heartbeat still shows version {version} after {:.1} s",
            timeout.as_secs_f64()
        ),
        None => format!("no heartbeat within {:.1} s", timeout.as_secs_f64()),
    }))
}

/// The sender's clock: microseconds since the push started.
struct Clock(Instant);

impl Clock {
    fn new() -> Clock {
        Clock(Instant::now())
    }

    fn now(&self) -> pab_core::Instant {
        pab_core::Instant::from_micros(
            u64::try_from(self.0.elapsed().as_micros()).unwrap_or(u64::MAX),
        )
    }

    fn until(&self, until: pab_core::Instant) -> Duration {
        Duration::from_micros(until.micros_since(self.now()).unwrap_or(0))
    }
}
