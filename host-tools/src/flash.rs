//! `pabctl flash`: a signed firmware image to a node over the bus, and the check that the node
//! runs it after its bootloader swapped it in (docs/firmware-update.md).
//!
//! The sequence, per node (`pab_core::update::session` is the node's side):
//! 1. with a key: a challenge, then a TransferOpen with `OPEN_UPDATE` for the Begin's 97 bytes;
//! 2. Begin (the manifest: the signed file's last 96 bytes, trailer and signature) over ISO-TP
//!    on UpdateTransfer; the node checks the trailer (board kind, version, length) and answers
//!    Ready with its largest chunk, or Refused with the reason;
//! 3. the image in chunks, each a multiple of 8 bytes but the last, each answered with an Ack
//!    naming the next offset and the CRC-32 of the image so far, which the tool checks against
//!    its own; a lost answer sends the same chunk again (the node acknowledges it again without
//!    writing it twice), an OutOfOrder resumes from the offset the node names, both bounded;
//! 4. Commit with the image's CRC-32; Committed, and the node restarts into its bootloader;
//! 5. the node back: its UpdateStatus Swapped (NotRunning if it was reverted, Refused with the
//!    bootloader's reason), then its
//!    identity, which must state the signed board kind, version and build. Only then is the
//!    update reported done: the bootloader checks the signature and may refuse or revert, and
//!    only the running firmware's identity says what runs.

use std::time::{Duration, Instant};

use pab_core::auth::Authenticator;
use pab_core::crc32::{Crc32, crc32};
use pab_core::identity::Firmware;
use pab_core::isotp::{FlowControlEffect, TxError, TxEvent};
use pab_core::protocol::{
    self, FaultCode, Message, OPEN_UPDATE, Service, TransferOpen, UpdateStatus, UpdateStatusCode,
};
use pab_core::update::session::{self, BEGIN_LEN, CHUNK};
use pab_core::update::{MANIFEST_LEN, SignedImage, UpdateRefusal};

use crate::bus::Bus;
use crate::push::{Challenged, Refusals, challenge, no_challenge_reason};
use crate::transfer::TransferSender;

/// How long to wait at each stage, and how often to try again.
#[derive(Clone, Copy, Debug)]
pub struct Timeouts {
    /// For each answer (UpdateStatus) after a message's last frame: a chunk's answer comes after
    /// its page's erase and program (some 30 ms on the G474).
    pub answer: Duration,
    /// For the node to come back after the Committed: its bootloader checks the signature and
    /// swaps the image in (seconds on a board).
    pub restart: Duration,
    /// How many times one chunk (or the Commit) is sent again after its answer was lost, and
    /// how many times the transfer resumes from an offset the node names.
    pub retries: u32,
}

impl Default for Timeouts {
    fn default() -> Self {
        Timeouts {
            answer: Duration::from_secs(2),
            restart: Duration::from_secs(30),
            retries: 3,
        }
    }
}

/// Why an image was refused, decoded from the refusal's code (an UpdateStatus Refused's value,
/// `UpdateRefusal::code`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// A refusal with its reason (all but the image's size, whose figures the code leaves out).
    Image(UpdateRefusal),
    /// The image does not fit the node's update partition (code 3).
    TooLarge,
    /// A code this tool does not know.
    Unknown(u8),
}

impl Refusal {
    /// The refusal that `code` says.
    pub fn from_code(code: u32) -> Refusal {
        let Ok(code) = u8::try_from(code) else {
            return Refusal::Unknown(u8::MAX);
        };
        let known = [
            UpdateRefusal::Truncated,
            UpdateRefusal::BadTrailer,
            UpdateRefusal::OtherBoard,
            UpdateRefusal::Downgrade,
            UpdateRefusal::BadSignature,
            UpdateRefusal::Unreadable,
        ];
        if code == 3 {
            return Refusal::TooLarge;
        }
        known
            .into_iter()
            .find(|refusal| refusal.code() == code)
            .map_or(Refusal::Unknown(code), Refusal::Image)
    }
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Image(refusal) => write!(f, "{refusal}"),
            Refusal::TooLarge => f.write_str("the image does not fit the node's update partition"),
            Refusal::Unknown(code) => write!(f, "refusal code {code}"),
        }
    }
}

/// How an update of one node ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The node came back running the signed board kind, version and build.
    Running {
        /// What it runs.
        firmware: Firmware,
    },
    /// The node refused the image at the Begin (its trailer): nothing was written.
    Refused(Refusal),
    /// The bootloader refused the image after the restart (it checks the signature): the old
    /// firmware runs.
    BootloaderRefused(Refusal),
    /// The node came back, but its identity is not the signed one (the bootloader reverted, or
    /// did not swap).
    NotRunning {
        /// What the image was signed as.
        expected: Firmware,
        /// What the node says it runs.
        running: Firmware,
    },
    /// The node cannot take updates (no update partition, or a firmware without the `update`
    /// feature answers nothing at all: [`Outcome::NoAnswer`]).
    Unsupported,
    /// The node had no session for a chunk or the Commit (it timed out, or the node restarted).
    NoSession,
    /// The node could not write its update partition at `offset`.
    FlashError {
        /// Where the write failed.
        offset: u32,
    },
    /// Another transfer held the node.
    Busy,
    /// A keyed node refused the update's messages: the reason from its Unauthenticated faults.
    Unauthenticated(String),
    /// The node did not answer (a timeout at some stage, said which).
    NoAnswer(String),
    /// The node answered something that does not fit the transfer (a CRC or an offset that
    /// differs from the tool's, a commit mismatch, too many retries): said what.
    Failed(String),
}

impl Outcome {
    /// Whether the node runs the image.
    pub fn is_success(&self) -> bool {
        matches!(self, Outcome::Running { .. })
    }

    /// Whether the node restarted into its bootloader with the image and did not come back
    /// running it: the image or the bootloader is suspect, so `pabctl flash` does not send it to
    /// the nodes after this one.
    pub fn after_commit(&self) -> bool {
        matches!(
            self,
            Outcome::BootloaderRefused(_) | Outcome::NotRunning { .. }
        )
    }
}

/// A firmware as `name version (build hex)`.
pub fn firmware_text(firmware: &Firmware) -> String {
    let [major, minor, patch] = firmware.version;
    format!(
        "{} {major}.{minor}.{patch} (build {})",
        firmware.name_str().unwrap_or("?"),
        crate::signing::hex(&firmware.build)
    )
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Outcome::Running { firmware } => write!(f, "runs {}", firmware_text(firmware)),
            Outcome::Refused(refusal) => {
                write!(
                    f,
                    "refused: {refusal}; nothing written, the old firmware runs"
                )
            }
            Outcome::BootloaderRefused(refusal) => write!(
                f,
                "the bootloader refused the image: {refusal}; the old firmware runs"
            ),
            Outcome::NotRunning { expected, running } => write!(
                f,
                "came back running {}, not {} (the bootloader did not swap the image in, or \
                 reverted it)",
                firmware_text(running),
                firmware_text(expected)
            ),
            Outcome::Unsupported => f.write_str(
                "this node takes no updates (no update partition: a board needs a bootloader)",
            ),
            Outcome::NoSession => f.write_str("the node had no update session (it timed out)"),
            Outcome::FlashError { offset } => write!(
                f,
                "the node could not write its update partition at offset {offset}"
            ),
            Outcome::Busy => f.write_str("busy: another transfer holds the node; try again"),
            Outcome::Unauthenticated(why) => write!(f, "not authenticated: {why}"),
            Outcome::NoAnswer(why) => write!(f, "no answer: {why}"),
            Outcome::Failed(why) => write!(f, "failed: {why}"),
        }
    }
}

/// Why a signed file cannot be flashed, before anything is sent: it is not a signed image.
pub fn parse(bytes: &[u8]) -> Result<SignedImage<'_>, String> {
    SignedImage::parse(bytes).map_err(|refusal| {
        format!(
            "not a signed firmware image ({refusal}): `pabctl sign` makes one from the \
             application's binary"
        )
    })
}

/// Flashes the signed image `signed` (a whole signed file, [`parse`]d) to node `node`, with
/// `key` on a keyed node, reporting progress as `(image bytes acknowledged, image length)`.
pub fn flash(
    bus: &mut dyn Bus,
    node: u8,
    signed: &SignedImage<'_>,
    key: Option<&Authenticator>,
    timeouts: Timeouts,
    progress: &mut dyn FnMut(usize, usize),
) -> std::io::Result<Outcome> {
    let mut watched = Refusals::new(bus, node);
    let outcome = Flash {
        bus: &mut watched,
        node,
        timeouts,
        unauthenticated: None,
    }
    .run(signed, key, progress)?;
    // A node that went silent while refusing tags says why.
    Ok(match (outcome, watched.reason()) {
        (Outcome::NoAnswer(detail), Some(why)) => Outcome::NoAnswer(format!("{why}; {detail}")),
        (outcome, _) => outcome,
    })
}

/// What came of waiting for an answer.
enum Answer {
    Status(UpdateStatus),
    /// No UpdateStatus within the time.
    Silence,
    /// The node refused the message as unauthenticated (its fault, described).
    Unauthenticated(String),
}

struct Flash<'b> {
    bus: &'b mut dyn Bus,
    node: u8,
    timeouts: Timeouts,
    /// An Unauthenticated fault the node raised for the update's messages, described.
    unauthenticated: Option<String>,
}

impl Flash<'_> {
    fn run(
        &mut self,
        signed: &SignedImage<'_>,
        key: Option<&Authenticator>,
        progress: &mut dyn FnMut(usize, usize),
    ) -> std::io::Result<Outcome> {
        let image = signed.image();
        let trailer = signed.trailer;
        let mut manifest = [0u8; MANIFEST_LEN];
        manifest[..pab_core::update::TRAILER_LEN].copy_from_slice(&trailer.encode());
        manifest[pab_core::update::TRAILER_LEN..].copy_from_slice(signed.signature);
        drain(self.bus)?;
        // 1. With a key: the challenge and the open for the Begin.
        if let Some(auth) = key {
            let nonce = match challenge(self.bus, auth, self.node, Duration::from_secs(1))? {
                Challenged::Bound(nonce) => nonce,
                Challenged::Nothing { unbound } => {
                    return Ok(Outcome::NoAnswer(no_challenge_reason(self.node, unbound)));
                }
            };
            let length = BEGIN_LEN as u16;
            let open = TransferOpen {
                length,
                flags: OPEN_UPDATE,
                tag: auth.open_tag(self.node, nonce, length, OPEN_UPDATE),
            };
            self.bus
                .send(&Message::TransferOpen(open).to_frame(protocol::TOOL, self.node))?;
        }
        // 2. The Begin.
        let ready = match self.exchange(&session::begin(&manifest), "the Begin")? {
            Err(outcome) => return Ok(outcome),
            Ok(status) => match status.status {
                UpdateStatusCode::Ready => status,
                _ => return Ok(self.ended(status, "the Begin")),
            },
        };
        // The largest chunk both take, a whole number of double words.
        let chunk = usize::try_from(ready.value).unwrap_or(CHUNK).min(CHUNK) / 8 * 8;
        if chunk == 0 {
            return Ok(Outcome::Failed(format!(
                "the node takes chunks of {} bytes: fewer than 8",
                ready.value
            )));
        }
        // 3. The chunks.
        let total = image.len();
        let mut offset = 0usize;
        let mut crc = Crc32::new();
        let mut lost = 0u32;
        let mut resumed = 0u32;
        progress(0, total);
        while offset < total {
            let end = (offset + chunk).min(total);
            let data = &image[offset..end];
            let mut message = session::chunk_head(offset as u32).to_vec();
            message.extend_from_slice(data);
            let what = format!("the chunk at offset {offset}");
            let expected = crc.update(data);
            let status = loop {
                match self.exchange(&message, &what)? {
                    Ok(status)
                        if status.status == UpdateStatusCode::Ack
                            && status.offset as usize == offset
                            && offset > 0 =>
                    {
                        // The answer to the previous chunk sent again: its first answer came
                        // late. This chunk's own answer follows.
                        match self.answer()? {
                            Answer::Status(status) => break status,
                            Answer::Silence => {}
                            Answer::Unauthenticated(why) => {
                                return Ok(Outcome::Unauthenticated(why));
                            }
                        }
                    }
                    Ok(status) => break status,
                    Err(Outcome::NoAnswer(why)) => {
                        lost += 1;
                        if lost > self.timeouts.retries {
                            return Ok(Outcome::NoAnswer(format!(
                                "{why} ({lost} time(s), the chunk sent again each time)"
                            )));
                        }
                    }
                    Err(outcome) => return Ok(outcome),
                }
            };
            match status.status {
                UpdateStatusCode::Ack => {
                    let next = end as u32;
                    if status.offset != next || status.value != expected.finish() {
                        return Ok(Outcome::Failed(format!(
                            "the node acknowledged {what} with offset {} and CRC {:08x}, not \
                             {next} and {:08x}: its bytes differ from the image's",
                            status.offset,
                            status.value,
                            expected.finish()
                        )));
                    }
                    offset = end;
                    crc = expected;
                    progress(offset, total);
                }
                UpdateStatusCode::OutOfOrder => {
                    resumed += 1;
                    let at = status.offset as usize;
                    let ours = image.get(..at).map(crc32);
                    if resumed > self.timeouts.retries
                        || ours != Some(status.value)
                        || (!at.is_multiple_of(8) && at != total)
                    {
                        return Ok(Outcome::Failed(format!(
                            "the node expects offset {at} with CRC {:08x} ({}); {resumed} \
                             resumption(s)",
                            status.value,
                            match ours {
                                Some(ours) if ours == status.value => "the tool's too",
                                Some(_) => "the tool's CRC of those bytes differs",
                                None => "beyond the image",
                            }
                        )));
                    }
                    offset = at;
                    crc = Crc32::new().update(&image[..at]);
                    progress(offset, total);
                }
                _ => return Ok(self.ended(status, &what)),
            }
        }
        // 4. The Commit.
        let image_crc = crc32(image);
        let mut commits = 0u32;
        loop {
            commits += 1;
            match self.exchange(&session::commit(image_crc), "the Commit")? {
                Ok(status) if status.status == UpdateStatusCode::Committed => {
                    if status.offset as usize != total || status.value != image_crc {
                        return Ok(Outcome::Failed(format!(
                            "the node committed {} bytes with CRC {:08x}, not {total} with \
                             {image_crc:08x}",
                            status.offset, status.value
                        )));
                    }
                    break;
                }
                // A Commit sent again after its answer was lost finds the node restarted, with
                // no session: the first one went through. The identity tells.
                Ok(status) if status.status == UpdateStatusCode::NoSession && commits > 1 => break,
                Ok(status) if status.status == UpdateStatusCode::Mismatch => {
                    return Ok(Outcome::Failed(format!(
                        "the node has {} bytes with CRC {:08x}, the image is {total} with \
                         {image_crc:08x}",
                        status.offset, status.value
                    )));
                }
                Ok(status) => return Ok(self.ended(status, "the Commit")),
                Err(Outcome::NoAnswer(why)) if commits <= self.timeouts.retries => {
                    let _ = why;
                }
                Err(outcome) => return Ok(outcome),
            }
        }
        // 5. The node back: the bootloader's verdict, then what it runs.
        self.back(&trailer.firmware)
    }

    /// After the Committed: the node's UpdateStatus at its start (Swapped, or Refused with the
    /// bootloader's reason), then its identity.
    fn back(&mut self, expected: &Firmware) -> std::io::Result<Outcome> {
        let end = Instant::now() + self.timeouts.restart;
        let mut verdict = None;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            let Some(frame) = self.bus.receive(left)? else {
                break;
            };
            if let Ok((id, Message::UpdateStatus(status))) = Message::decode(&frame)
                && id.source == self.node
                && id.destination == protocol::TOOL
            {
                match status.status {
                    // Swapped, or accepted but reverted (NotRunning): the identity says which
                    // firmware runs, and the outcome comes from it.
                    UpdateStatusCode::Swapped | UpdateStatusCode::NotRunning => {
                        verdict = Some(status);
                        break;
                    }
                    UpdateStatusCode::Refused => {
                        return Ok(Outcome::BootloaderRefused(Refusal::from_code(status.value)));
                    }
                    _ => {}
                }
            }
        }
        let identity =
            crate::identity::request(self.bus, self.node, crate::identity::ANSWER_TIMEOUT * 2)?
                .remove(&self.node);
        let restart = self.timeouts.restart.as_secs_f64();
        match (verdict, identity) {
            (_, Some(identity)) if identity.firmware == *expected => Ok(Outcome::Running {
                firmware: identity.firmware,
            }),
            (_, Some(identity)) => Ok(Outcome::NotRunning {
                expected: *expected,
                running: identity.firmware,
            }),
            (Some(_), None) => Ok(Outcome::NoAnswer(
                "the node said its bootloader swapped the image in, but did not say who it is \
                 (a firmware without identity?)"
                    .to_string(),
            )),
            (None, None) => Ok(Outcome::NoAnswer(format!(
                "the node did not come back within {restart:.0} s of its restart (no update \
                 status, no identity)"
            ))),
        }
    }

    /// The outcome of an answer that ends the update.
    fn ended(&self, status: UpdateStatus, what: &str) -> Outcome {
        match status.status {
            UpdateStatusCode::Refused => Outcome::Refused(Refusal::from_code(status.value)),
            UpdateStatusCode::Unsupported => Outcome::Unsupported,
            UpdateStatusCode::NoSession => Outcome::NoSession,
            UpdateStatusCode::FlashError => Outcome::FlashError {
                offset: status.offset,
            },
            UpdateStatusCode::Busy => Outcome::Busy,
            other => Outcome::Failed(format!(
                "the node answered {what} with \"{}\" (offset {}, value {})",
                other.description(),
                status.offset,
                status.value
            )),
        }
    }

    /// Sends `message` over ISO-TP and waits for its UpdateStatus: `Err` with the outcome when
    /// the transfer failed, the node refused it unauthenticated or no answer came.
    fn exchange(
        &mut self,
        message: &[u8],
        what: &str,
    ) -> std::io::Result<Result<UpdateStatus, Outcome>> {
        if let Some(outcome) = self.send(message, what)? {
            return Ok(Err(outcome));
        }
        Ok(match self.answer()? {
            Answer::Status(status) => Ok(status),
            Answer::Unauthenticated(why) => Err(Outcome::Unauthenticated(why)),
            Answer::Silence => Err(Outcome::NoAnswer(format!(
                "no update status for {what} within {:.1} s",
                self.timeouts.answer.as_secs_f64()
            ))),
        })
    }

    /// The next UpdateStatus from the node within the answer's time.
    fn answer(&mut self) -> std::io::Result<Answer> {
        let end = Instant::now() + self.timeouts.answer;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            let Some(frame) = self.bus.receive(left)? else {
                break;
            };
            if let Some(answer) = self.judge(&frame) {
                return Ok(answer);
            }
        }
        Ok(match self.unauthenticated.take() {
            Some(why) => Answer::Unauthenticated(why),
            None => Answer::Silence,
        })
    }

    /// An UpdateStatus from the node to the tool, or its refusal of the update's messages.
    fn judge(&mut self, frame: &pab_core::Frame) -> Option<Answer> {
        match Message::decode(frame) {
            Ok((id, Message::UpdateStatus(status)))
                if id.source == self.node && id.destination == protocol::TOOL =>
            {
                Some(Answer::Status(status))
            }
            Ok((id, Message::Fault(fault)))
                if id.source == self.node
                    && fault.code == FaultCode::Unauthenticated
                    && [Service::UpdateTransfer.code(), Service::TransferOpen.code()]
                        .contains(&fault.detail[1]) =>
            {
                let why = format!(
                    "the node refused the update: {} (a keyed node needs --key with its key)",
                    crate::observe::describe_fault(&fault)
                );
                self.unauthenticated = Some(why.clone());
                Some(Answer::Unauthenticated(why))
            }
            _ => None,
        }
    }

    /// Sends `message` over ISO-TP on UpdateTransfer, paced by the node's flow control; `Some`
    /// outcome when it could not.
    fn send(&mut self, message: &[u8], what: &str) -> std::io::Result<Option<Outcome>> {
        let clock = Instant::now();
        let now = || {
            pab_core::Instant::from_micros(
                u64::try_from(clock.elapsed().as_micros()).unwrap_or(u64::MAX),
            )
        };
        let framing = self.bus.framing();
        let mut sender =
            match TransferSender::new(message, Service::UpdateTransfer, self.node, framing) {
                Ok(sender) => sender,
                Err(error) => {
                    return Ok(Some(Outcome::Failed(format!(
                        "cannot send {what}: {error:?}"
                    ))));
                }
            };
        loop {
            match sender.poll(now()) {
                TxEvent::Send(frame) => self.bus.send(&frame)?,
                TxEvent::WaitUntil(until) => {
                    let wait = Duration::from_micros(until.micros_since(now()).unwrap_or(0));
                    let Some(frame) = self.bus.receive(wait)? else {
                        continue;
                    };
                    match Message::decode(&frame) {
                        Ok((id, Message::UpdateTransfer { data, len }))
                            if id.source == self.node && id.destination == protocol::TOOL =>
                        {
                            let data = data.get(..usize::from(len)).unwrap_or(&data);
                            if let FlowControlEffect::Failed(error) =
                                sender.on_flow_control(data, now())
                            {
                                return Ok(Some(self.transfer_failed(error, what)));
                            }
                        }
                        _ => {
                            // An answer before the last frame (Busy, Unsupported) or a refusal.
                            match self.judge(&frame) {
                                Some(Answer::Status(status)) => {
                                    return Ok(Some(self.ended(status, what)));
                                }
                                Some(Answer::Unauthenticated(why)) => {
                                    return Ok(Some(Outcome::Unauthenticated(why)));
                                }
                                _ => {}
                            }
                        }
                    }
                }
                TxEvent::Done => return Ok(None),
                TxEvent::Failed(error) => return Ok(Some(self.transfer_failed(error, what))),
            }
        }
    }

    fn transfer_failed(&mut self, error: TxError, what: &str) -> Outcome {
        if let Some(why) = self.unauthenticated.take() {
            return Outcome::Unauthenticated(why);
        }
        let node = self.node;
        Outcome::NoAnswer(match error {
            TxError::Timeout if self.bus.framing() == crate::bus::Framing::Fd => format!(
                "no flow control from node {node} for {what} in CAN FD frames within 1 s (is it \
                 on the bus? `pabctl nodes`; a node built without CAN FD, a board, ignores them: \
                 flash without --fd)"
            ),
            TxError::Timeout => format!(
                "no flow control from node {node} for {what} within 1 s (is it on the bus? \
                 `pabctl nodes`)"
            ),
            TxError::Overflow => format!("the node refused {what} as too large"),
            TxError::TooManyWaits => format!("the node kept asking to wait during {what}"),
            TxError::InvalidFlowStatus { status } => {
                format!("the node sent an invalid flow control (status {status}) for {what}")
            }
        })
    }
}

/// Drops what the bus holds before the update, so that old answers are not read as new ones.
fn drain(bus: &mut dyn Bus) -> std::io::Result<()> {
    for _ in 0..4096 {
        if bus.receive(Duration::ZERO)?.is_none() {
            break;
        }
    }
    Ok(())
}
