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

use pab_core::Frame;
use pab_core::auth::Authenticator;
use pab_core::image::Header;
use pab_core::isotp::{FlowControlEffect, TxError, TxEvent};
use pab_core::protocol::{
    self, AuthFailure, FaultCode, Message, OPEN_REPLACE, Service, TransferOpen, TransferStatusCode,
};

use crate::bus::Bus;
use crate::transfer::TransferSender;

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

/// The key to push with, and whether to replace whatever version runs (the keyed version reset).
#[derive(Clone, Debug)]
pub struct Credentials {
    /// The node's key.
    pub authenticator: Authenticator,
    /// Set [`OPEN_REPLACE`]: the node takes the image even if its version is not newer.
    pub replace: bool,
}

/// Pushes `image` (whose header is `header`) to node `node`, reporting progress as
/// `(bytes sent, total)` after each frame sent (so the calls count the frames), in the frames of
/// the bus's [`Framing`](crate::bus::Framing).
pub fn push(
    bus: &mut dyn Bus,
    node: u8,
    image: &[u8],
    header: &Header,
    timeouts: Timeouts,
    progress: &mut dyn FnMut(usize, usize),
) -> std::io::Result<Outcome> {
    push_inner(bus, node, image, header, timeouts, progress, None)
}

/// Pushes `image` to a node with a key: a challenge, a TransferOpen, the image and its MAC, and
/// a success counts only with a Receipt that verifies under the key (then the heartbeat, as
/// [`push`]). Without a challenge from the node (a node without a key sends none) the push fails
/// with [`Outcome::NoAnswer`] saying so.
pub fn push_authenticated(
    bus: &mut dyn Bus,
    node: u8,
    image: &[u8],
    header: &Header,
    credentials: &Credentials,
    timeouts: Timeouts,
    progress: &mut dyn FnMut(usize, usize),
) -> std::io::Result<Outcome> {
    push_inner(
        bus,
        node,
        image,
        header,
        timeouts,
        progress,
        Some(credentials),
    )
}

/// Frames read and dropped before a challenge request, at most: what was queued before the
/// request answers nothing of this exchange. Bounded so that a flooded bus cannot hold the tool
/// here; the binding check below is what refuses an old or forged challenge anyway.
const DRAIN_LIMIT: usize = 4096;

/// What came of a challenge request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Challenged {
    /// The node's challenge, bound to this request: the exchange nonce its tags are over
    /// ([`pab_core::auth::Exchange::nonce`]).
    Bound(u64),
    /// No challenge answering this request within the time; `unbound` challenges from the node
    /// did not answer it (made up by someone else, or answering another request).
    Nothing {
        /// Challenges whose binding did not verify for this request's nonce.
        unbound: u32,
    },
}

/// Asks `node` for a challenge with a new random tool nonce, and takes only a Challenge whose
/// binding verifies for it (docs/can-protocol.md, "Authenticated configuration"): frames queued
/// before the request are drained first, and a Challenge that does not answer this request,
/// whoever sent it, is counted and ignored. Fails only on the bus, or when the operating system
/// has no random number for the nonce.
pub fn challenge(
    bus: &mut dyn Bus,
    auth: &Authenticator,
    node: u8,
    timeout: Duration,
) -> std::io::Result<Challenged> {
    for _ in 0..DRAIN_LIMIT {
        if bus.receive(Duration::ZERO)?.is_none() {
            break;
        }
    }
    let tool = getrandom::u64().map_err(|error| {
        std::io::Error::other(format!("no random number for the tool's nonce: {error}"))
    })?;
    bus.send(&Message::ChallengeRequest { tool_nonce: tool }.to_frame(protocol::TOOL, node))?;
    let mut unbound = 0u32;
    let end = Instant::now() + timeout;
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Some(frame) = bus.receive(left)? else {
            break;
        };
        if let Ok((
            id,
            Message::Challenge {
                node_nonce,
                binding,
            },
        )) = Message::decode(&frame)
            && id.source == node
            && id.destination == protocol::TOOL
        {
            let exchange = auth.exchange(node, tool, node_nonce);
            if exchange.binding == binding {
                return Ok(Challenged::Bound(exchange.nonce));
            }
            unbound = unbound.saturating_add(1);
        }
    }
    Ok(Challenged::Nothing { unbound })
}

/// Why a keyed exchange with `node` got no challenge (`unbound`: challenges that did not answer
/// the request).
pub fn no_challenge_reason(node: u8, unbound: u32) -> String {
    if unbound > 0 {
        format!(
            "node {node} sent no challenge answering this request within 1 s, and {unbound} \
             challenge(s) in its name that did not verify for it: the key is not the node's, \
             another tool is configuring it, or a participant is making challenges up \
             (docs/can-protocol.md, \"Threat model\")"
        )
    } else {
        format!(
            "node {node} sent no challenge within 1 s: is it on the bus, and does it have a key? \
             (`pabctl nodes` shows which nodes have one; push without --key to a node without a \
             key)"
        )
    }
}

/// The bus during a keyed push, counting on the way the node's refusals of tagged messages (its
/// Unauthenticated faults: wrong tags, and tags beyond what it checks in a second), so that a
/// push the node does not answer says why instead of blaming the bus. A participant that floods
/// a keyed node with bad tags uses up its checks (`pab_app`'s 200 a second) and the tool's open
/// is refused unchecked; the node says so in its faults, which this reads.
pub(crate) struct Refusals<'b> {
    bus: &'b mut dyn Bus,
    node: u8,
    /// Tagged messages the node refused meanwhile (the faults' occurrence counts).
    refused: u32,
    /// Some of them were refused because the node's checks for the second were used up.
    rate_limited: bool,
}

impl Bus for Refusals<'_> {
    fn send(&mut self, frame: &Frame) -> std::io::Result<()> {
        self.bus.send(frame)
    }

    fn framing(&self) -> crate::bus::Framing {
        self.bus.framing()
    }

    fn receive(&mut self, timeout: Duration) -> std::io::Result<Option<Frame>> {
        let frame = self.bus.receive(timeout)?;
        if let Some(Ok((id, Message::Fault(fault)))) = frame.as_ref().map(Message::decode)
            && id.source == self.node
            && fault.code == FaultCode::Unauthenticated
        {
            self.refused = self.refused.saturating_add(u32::from(fault.count));
            self.rate_limited |= fault.detail[0] == AuthFailure::RateLimited.code();
        }
        Ok(frame)
    }
}

impl<'b> Refusals<'b> {
    /// Watches `node`'s refusals on `bus`.
    pub(crate) fn new(bus: &'b mut dyn Bus, node: u8) -> Refusals<'b> {
        Refusals {
            bus,
            node,
            refused: 0,
            rate_limited: false,
        }
    }

    /// Why the node refused tagged messages meanwhile, if it did.
    pub(crate) fn reason(&self) -> Option<String> {
        let n = self.refused;
        if n == 0 {
            None
        } else if self.rate_limited {
            Some(format!(
                "the node refused {n} tags, more than it checks in a second: someone is flooding \
                 it with bad tags (`candump` shows the source of the tagged frames)"
            ))
        } else {
            Some(format!(
                "the node refused {n} tags as wrong: a key that is not the node's, or someone \
                 sending it bad tags"
            ))
        }
    }

    /// `outcome`, with the node's refusals as the reason when it got no answer.
    fn explain(&self, outcome: Outcome) -> Outcome {
        let Some(why) = self.reason() else {
            return outcome;
        };
        match outcome {
            Outcome::NoAnswer(detail) => Outcome::NoAnswer(format!("{why}; {detail}")),
            Outcome::NotConfirmed(detail) => Outcome::NotConfirmed(format!("{why}; {detail}")),
            other => other,
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn push_inner(
    bus: &mut dyn Bus,
    node: u8,
    image: &[u8],
    header: &Header,
    timeouts: Timeouts,
    progress: &mut dyn FnMut(usize, usize),
    credentials: Option<&Credentials>,
) -> std::io::Result<Outcome> {
    if credentials.is_none() {
        return push_steps(bus, node, image, header, timeouts, progress, None);
    }
    let mut watched = Refusals::new(bus, node);
    let outcome = push_steps(
        &mut watched,
        node,
        image,
        header,
        timeouts,
        progress,
        credentials,
    )?;
    Ok(watched.explain(outcome))
}

#[allow(clippy::too_many_arguments)]
fn push_steps(
    bus: &mut dyn Bus,
    node: u8,
    image: &[u8],
    header: &Header,
    timeouts: Timeouts,
    progress: &mut dyn FnMut(usize, usize),
    credentials: Option<&Credentials>,
) -> std::io::Result<Outcome> {
    // With a key: the challenge, the open, and the MAC after the image.
    let mut message = image.to_vec();
    let mut receipt_nonce = None;
    if let Some(credentials) = credentials {
        let auth = &credentials.authenticator;
        let nonce = match challenge(bus, auth, node, Duration::from_secs(1))? {
            Challenged::Bound(nonce) => nonce,
            Challenged::Nothing { unbound } => {
                return Ok(Outcome::NoAnswer(no_challenge_reason(node, unbound)));
            }
        };
        let flags = if credentials.replace { OPEN_REPLACE } else { 0 };
        message.extend_from_slice(&auth.image_mac(node, nonce, flags, image));
        let Ok(length) = u16::try_from(message.len()) else {
            return Ok(Outcome::NoAnswer(format!(
                "the image ({} bytes) is too large for an authenticated transfer",
                image.len()
            )));
        };
        let open = TransferOpen {
            length,
            flags,
            tag: auth.open_tag(node, nonce, length, flags),
        };
        bus.send(&Message::TransferOpen(open).to_frame(protocol::TOOL, node))?;
        receipt_nonce = Some((auth, nonce));
    }
    let image = &message[..];
    let clock = Clock::new();
    let framing = bus.framing();
    let mut sender = match TransferSender::new(image, Service::TableTransfer, node, framing) {
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
            TxEvent::Send(frame) => {
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
    // 2. The node's answer: a refusal, or a success that names the pushed version (with a key:
    // one whose Receipt verifies).
    let version = header.table_version;
    let answer = match receipt_nonce {
        Some((auth, nonce)) => wait_for_receipt(bus, node, auth, nonce, header, timeouts.answer)?,
        None => wait_for_status(bus, node, timeouts.answer, |status| {
            !status.status.is_success() || status.running_version == version
        })?,
    };
    let outcome = match answer {
        None if receipt_nonce.is_some() => {
            return Ok(Outcome::NotConfirmed(format!(
                "no transfer status for version {version} with a receipt that verifies under the \
                 key within {:.1} s after the last frame (a wrong key, or an answer that did not \
                 come from the node)",
                timeouts.answer.as_secs_f64()
            )));
        }
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
        TxError::Timeout if bus.framing() == crate::bus::Framing::Fd => format!(
            "no flow control from node {node} within 1 s to the image's CAN FD frames (is it on \
             the bus? `pabctl nodes`; a node built without CAN FD, a board, ignores them: push \
             without --fd)"
        ),
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

/// With a key: the first TransferStatus from `node` that a Receipt verifies, within `timeout`.
/// A success counts only so; a refusal is taken as it comes (a refusal is no confirmation: a
/// forged one can make a push fail, never make a failed push look done). The Receipt covers the
/// running image's CRC and stored flag: for a success, the pushed image's CRC and either flag
/// (AlreadyCurrent keeps the old flag).
fn wait_for_receipt(
    bus: &mut dyn Bus,
    node: u8,
    auth: &Authenticator,
    nonce: u64,
    header: &Header,
    timeout: Duration,
) -> std::io::Result<Option<protocol::TransferStatus>> {
    let end = Instant::now() + timeout;
    let mut statuses: Vec<protocol::TransferStatus> = Vec::new();
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Some(frame) = bus.receive(left)? else {
            break;
        };
        match Message::decode(&frame) {
            Ok((id, Message::TransferStatus(status)))
                if id.source == node && id.destination == protocol::TOOL =>
            {
                if !status.status.is_success() {
                    return Ok(Some(status));
                }
                statuses.push(status);
            }
            Ok((id, Message::Receipt { tag }))
                if id.source == node && id.destination == protocol::TOOL =>
            {
                for status in &statuses {
                    let frame = Message::TransferStatus(*status).to_frame(node, protocol::TOOL);
                    let mut payload = [0u8; 8];
                    payload.copy_from_slice(frame.payload());
                    let verified = [true, false].into_iter().any(|stored| {
                        auth.verify_receipt(node, nonce, &payload, header.crc, stored, &tag)
                    });
                    if verified && status.running_version == header.table_version {
                        return Ok(Some(*status));
                    }
                }
            }
            _ => {}
        }
    }
    Ok(None)
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
