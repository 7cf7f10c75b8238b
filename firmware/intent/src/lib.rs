//! # pab-intent: HBBA's intention node
//!
//! Listens to Desire frames, keeps their leases, solves which strategies run, sets the boards'
//! message filters with FilterSet commands (every disable before any enable, each acknowledged
//! by FilterStatus), publishes the selection (Intention) on every change and every second, and
//! re-applies a node's filters when it restarts. The decisions are
//! `pab_core::hbba::intention::Workspace`'s, the code `pabctl sim` runs too; this crate puts it on
//! a bus and says what happens, in words.
//!
//! Structure, as the nodes': [`IntentNode`] is the whole behaviour without I/O (frames and time
//! in, frames and [`Report`]s out); [`run`] drives it on any [`pab_app::CanBus`] with a
//! [`Clock`]; [`Setup`] is what it knows of the network, the file `pabctl compile` writes. The
//! Linux process `pab-intent` (a binary of `pab-node`, firmware/linux) gives it that crate's
//! SocketCAN bus and the system clock; the simulator (`pabctl sim`) and the tests, their buses in
//! virtual time.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

use std::collections::VecDeque;
use std::fmt;

use embassy_futures::select::{Either, select};
use pab_app::CanBus;
use pab_core::auth::{Authenticator, Key};
use pab_core::hbba::Instance;
use pab_core::hbba::intention::{Command, Event, IntentionError, MAX_SENDS, Target, Workspace};
use pab_core::protocol::{self, AuthFailure, BROADCAST, FaultCode, Intention, Message, Service};
use pab_core::seal::Sealer;
use pab_core::{Frame, Instant};

/// How often the intention is published when nothing changes, µs: 1 s.
pub const PUBLISH_PERIOD_US: u64 = 1_000_000;
/// Reports held until read; older ones are dropped (and counted in a report).
const MAX_REPORTS: usize = 256;
/// Freshness requests answered per second, at most (each answer is a CMAC and two frames): as
/// the nodes' budget of tag checks, so that a participant cannot make the intention node
/// amplify a flood.
pub const ANSWERS_PER_SECOND: u16 = 200;

/// What the intention node needs from a network file: the solver's instance, where each filtered
/// connection is, and names to speak of it.
///
/// `pabctl compile` writes it for a network with an `[hbba]` section, as `DIR/intention.json`
/// beside the nodes' table images ([`Setup::to_json`]); the node reads it back with
/// [`Setup::from_json`], as a board loads its table image: the intention node needs neither the
/// network file nor the language that parses it.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Setup {
    /// The format, [`SETUP_FORMAT`]: a file of another format is refused by name.
    format: String,
    /// The solver's instance (`[hbba]`).
    pub instance: Instance,
    /// Per filtered connection, its node, port and index.
    pub targets: Vec<Target>,
    /// Node names by id.
    nodes: Vec<(u8, String)>,
    /// Per target (same order), "CONNECTION (PORT)".
    filters: Vec<String>,
    /// Strategy names, file order.
    strategies: Vec<String>,
    /// Class names, in the solver's numbering.
    classes: Vec<String>,
}

/// The format of [`Setup`]'s file: its `format` field. A change of the fields changes it.
pub const SETUP_FORMAT: &str = "pab intention setup 1";

/// Why a setup file was refused.
#[derive(Debug)]
#[non_exhaustive]
pub enum SetupError {
    /// Not JSON, or not a setup's fields: serde_json's message, with its line and column.
    Json(serde_json::Error),
    /// A setup of another format (the file's `format`).
    Format(String),
    /// The names do not match the instance: what differs.
    Inconsistent(String),
}

impl fmt::Display for SetupError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SetupError::Json(error) => write!(f, "not an intention setup: {error}"),
            SetupError::Format(format) => write!(
                f,
                "an intention setup of format {format:?}, where this pab-intent reads \
                 {SETUP_FORMAT:?}: compile the network again with this version's pabctl"
            ),
            SetupError::Inconsistent(why) => write!(f, "an inconsistent intention setup: {why}"),
        }
    }
}

impl std::error::Error for SetupError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SetupError::Json(error) => Some(error),
            _ => None,
        }
    }
}

impl Setup {
    /// A setup: `instance`, its filtered connections `targets` with a name each (`filters`, same
    /// order: "CONNECTION (PORT)"), the nodes' names by id, the strategies' names (the
    /// instance's order) and the classes' (the solver's numbering). `Err` says which list does
    /// not match the instance.
    pub fn new(
        instance: Instance,
        targets: Vec<Target>,
        nodes: Vec<(u8, String)>,
        filters: Vec<String>,
        strategies: Vec<String>,
        classes: Vec<String>,
    ) -> Result<Setup, SetupError> {
        let setup = Setup {
            format: SETUP_FORMAT.to_string(),
            instance,
            targets,
            nodes,
            filters,
            strategies,
            classes,
        };
        setup.check()?;
        Ok(setup)
    }

    /// The setup in a file's text (what [`Setup::to_json`] wrote), checked: its format, and
    /// names for every filtered connection, strategy and class. The instance itself is judged
    /// by [`IntentNode::new`], as the solver takes it.
    pub fn from_json(text: &str) -> Result<Setup, SetupError> {
        #[derive(serde::Deserialize)]
        struct Format {
            format: String,
        }
        // The format first, so that a file of another version is named as such rather than
        // refused for a field it lacks.
        let format: Format = serde_json::from_str(text).map_err(SetupError::Json)?;
        if format.format != SETUP_FORMAT {
            return Err(SetupError::Format(format.format));
        }
        let setup: Setup = serde_json::from_str(text).map_err(SetupError::Json)?;
        setup.check()?;
        Ok(setup)
    }

    /// The file's text: pretty-printed JSON, a final newline.
    pub fn to_json(&self) -> String {
        // A tree of plain numbers, strings and lists: serialising it cannot fail.
        let mut text = serde_json::to_string_pretty(self).unwrap_or_default();
        text.push('\n');
        text
    }

    fn check(&self) -> Result<(), SetupError> {
        let counts = [
            (
                "filtered connections",
                self.targets.len(),
                "filter names",
                self.filters.len(),
            ),
            (
                "strategies",
                self.instance.strategies.len(),
                "strategy names",
                self.strategies.len(),
            ),
            (
                "classes",
                usize::from(self.instance.classes),
                "class names",
                self.classes.len(),
            ),
        ];
        for (what, count, names, named) in counts {
            if count != named {
                return Err(SetupError::Inconsistent(format!(
                    "{count} {what} and {named} {names}"
                )));
            }
        }
        Ok(())
    }

    fn node(&self, id: u8) -> String {
        match self.nodes.iter().find(|(n, _)| *n == id) {
            Some((_, name)) => format!("{name} (node {id})"),
            None => format!("node {id}"),
        }
    }

    fn filter(&self, target: &Target) -> String {
        self.targets
            .iter()
            .position(|t| t == target)
            .and_then(|i| self.filters.get(i))
            .cloned()
            .unwrap_or_else(|| format!("connection {}", target.connection))
    }

    fn class(&self, class: u8) -> String {
        self.classes
            .get(usize::from(class))
            .map_or_else(|| format!("class {class}"), |name| format!("`{name}`"))
    }

    /// The names of the strategies of `mask`, or "none".
    pub fn strategy_names(&self, mask: u64) -> String {
        let names: Vec<&str> = self
            .strategies
            .iter()
            .enumerate()
            .filter(|(i, _)| mask.checked_shr(*i as u32).is_some_and(|m| m & 1 == 1))
            .map(|(_, name)| name.as_str())
            .collect();
        if names.is_empty() {
            "none".to_string()
        } else {
            names.join(", ")
        }
    }
}

/// Something the intention node did or saw, in words: what its log says.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Report {
    /// Whether it needs attention (a refusal, a lost command, a refused desire).
    pub warning: bool,
    /// What happened.
    pub text: String,
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

/// What the node did, as data where a [`Report`] says it in words: for an observer that draws
/// or checks it (the simulator). Kept only after [`IntentNode::observe`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Observed {
    /// One of the workspace's events, in the order it had them.
    Event(Event),
    /// A FilterSet the node sent (a resend included: its `send` counts).
    Command(Command),
}

/// The intention node as a state machine: frames and time in, frames and reports out.
#[derive(Debug)]
pub struct IntentNode<'a> {
    setup: &'a Setup,
    workspace: Workspace<'a>,
    address: u8,
    outbox: VecDeque<Frame>,
    reports: VecDeque<Report>,
    lost_reports: u64,
    next_publish: Option<Instant>,
    /// What it did, once [`IntentNode::observe`] asked; drained by [`IntentNode::next_observed`].
    observed: Option<VecDeque<Observed>>,
    /// On a keyed network: the key, the seals' counter, and the answers' budget (the start of
    /// the current second, answers in it).
    keyed: Option<Keyed>,
}

/// The intention node's side of sealed coordination ([`pab_core::seal`]).
#[derive(Clone, Debug)]
struct Keyed {
    authenticator: Authenticator,
    sealer: Sealer,
    window: (Instant, u16),
}

impl<'a> IntentNode<'a> {
    /// An intention node for `setup`, sending from `address` ([`protocol::INTENTION`] unless
    /// the network says otherwise). Fails when the workspace cannot hold the instance.
    pub fn new(setup: &'a Setup, address: u8) -> Result<IntentNode<'a>, IntentionError> {
        Ok(IntentNode {
            setup,
            workspace: Workspace::new(&setup.instance, &setup.targets)?,
            address,
            outbox: VecDeque::new(),
            reports: VecDeque::new(),
            lost_reports: 0,
            next_publish: None,
            observed: None,
            keyed: None,
        })
    }

    /// Gives the node the network's key: from now on every filter command it sends is followed
    /// by its seal, and it answers the nodes' freshness requests, so that keyed nodes apply its
    /// commands ([`pab_core::seal`]). `epoch` must never repeat for one key (random bits from the
    /// operating system at each start).
    pub fn set_key(&mut self, key: &Key, epoch: u32, now: Instant) {
        self.keyed = Some(Keyed {
            authenticator: Authenticator::new(key),
            sealer: Sealer::new(epoch),
            window: (now, 0),
        });
    }

    /// Queues `frame`, followed by its seal on a keyed network.
    fn send_sealed(&mut self, frame: Frame) {
        self.outbox.push_back(frame);
        if let Some(keyed) = self.keyed.as_mut() {
            match keyed.sealer.seal(&keyed.authenticator, self.address, &frame) {
                Some(seal) => self.outbox.push_back(seal),
                None => self.report(
                    true,
                    "the seals' counter is exhausted: restart pab-intent (keyed nodes refuse its commands)"
                        .to_string(),
                ),
            }
        }
    }

    /// A freshness request from `requester`: the answer and its seal, within the budget.
    fn answer_freshness(&mut self, requester: u8, nonce: u64, now: Instant) {
        let Some(keyed) = self.keyed.as_mut() else {
            return;
        };
        let (start, count) = &mut keyed.window;
        if now
            .micros_since(*start)
            .is_none_or(|elapsed| elapsed >= 1_000_000)
        {
            *start = now;
            *count = 0;
        }
        if *count >= ANSWERS_PER_SECOND {
            return;
        }
        *count += 1;
        if let Some(frames) =
            keyed
                .sealer
                .answer(&keyed.authenticator, self.address, requester, nonce)
        {
            self.outbox.extend(frames);
        }
    }

    /// From now on, keeps what the node does as data ([`Observed`]) until
    /// [`IntentNode::next_observed`] takes it. The process never asks (its log is the
    /// reports); an observer that does must drain it, or it grows with every event.
    pub fn observe(&mut self) {
        self.observed.get_or_insert_with(VecDeque::new);
    }

    /// The oldest thing done not taken yet (none without [`IntentNode::observe`]).
    pub fn next_observed(&mut self) -> Option<Observed> {
        self.observed.as_mut()?.pop_front()
    }

    /// The workspace (desires, selection, filters), read-only.
    pub fn workspace(&self) -> &Workspace<'a> {
        &self.workspace
    }

    /// A frame from the bus at `now`: desires, filter statuses, faults and heartbeats are taken;
    /// anything else, a frame of ours (sent from this node's address), or one with another
    /// priority than its service's, is ignored.
    pub fn on_frame(&mut self, frame: &Frame, now: Instant) {
        let Ok((id, message)) = Message::decode(frame) else {
            return;
        };
        if id.source == self.address || !id.has_service_priority() {
            return;
        }
        match message {
            Message::Desire(desire) if id.is_for(self.address) => {
                match self.workspace.on_desire(id.source, &desire, now) {
                    Ok(true) if desire.intensity == 0 => self.report(
                        false,
                        format!("desire {} of node {} withdrawn", desire.id, id.source),
                    ),
                    Ok(true) => self.report(
                        false,
                        format!(
                            "desire {} of node {}: {} at {} for {} ms",
                            desire.id,
                            id.source,
                            self.setup.class(desire.class),
                            desire.intensity,
                            desire.lease_ms
                        ),
                    ),
                    Ok(false) => {}
                    Err(error) => self.report(
                        true,
                        format!(
                            "desire {} of node {} refused: {}",
                            desire.id,
                            id.source,
                            match error {
                                pab_core::hbba::DesireError::Full =>
                                    "the workspace already holds 32 desires".to_string(),
                                pab_core::hbba::DesireError::UnknownClass { class } => format!(
                                    "class {class} is not one of the network's {} classes",
                                    self.setup.classes.len()
                                ),
                                pab_core::hbba::DesireError::ZeroLease =>
                                    "a lease of 0 ms".to_string(),
                            }
                        ),
                    ),
                }
            }
            Message::FilterStatus(status) => {
                self.workspace.on_filter_status(id.source, &status);
            }
            Message::Fault(fault) if fault.code == FaultCode::FilterRefused => {
                self.workspace.on_fault(id.source, &fault);
            }
            Message::Heartbeat(heartbeat) => {
                self.workspace.on_heartbeat(id.source, &heartbeat);
            }
            Message::FreshnessRequest { nonce } if id.destination == self.address => {
                self.answer_freshness(id.source, nonce, now);
            }
            // A node that refused one of our filter commands (or our freshness answer) as not
            // sealed: said once per fault frame, with what to check.
            Message::Fault(fault)
                if fault.code == FaultCode::Unauthenticated && fault.detail[2] == self.address =>
            {
                let node = self.setup.node(id.source);
                let failure = AuthFailure::from_code(fault.detail[0]);
                if failure == Some(AuthFailure::Unsynced) {
                    self.report(
                        false,
                        format!(
                            "{node} asked where our seals stand (its first from us): the command goes again"
                        ),
                    );
                } else {
                    let why = failure
                        .map_or_else(|| format!("reason {}", fault.detail[0]), |f| f.to_string());
                    let hint = if self.keyed.is_some() {
                        "is pab-intent's key the node's?"
                    } else {
                        "the node has a key: start pab-intent with --key"
                    };
                    self.report(
                        true,
                        format!("{node} refused a frame of ours: {why} ({hint})"),
                    );
                }
            }
            _ => {}
        }
        self.collect(now);
    }

    /// Brings everything up to `now`: leases, solving, retries, the next phase, the periodic
    /// intention. The frames to send come from [`IntentNode::next_outgoing`].
    pub fn poll(&mut self, now: Instant) {
        self.workspace.poll(now);
        self.collect(now);
        if self
            .next_publish
            .is_none_or(|at| now.micros_since(at).is_some())
        {
            self.publish(now);
        }
    }

    /// The next frame to send.
    pub fn next_outgoing(&mut self) -> Option<Frame> {
        self.outbox.pop_front()
    }

    /// The next report, oldest first.
    pub fn next_report(&mut self) -> Option<Report> {
        self.reports.pop_front()
    }

    /// When [`IntentNode::poll`] next has work, at the latest.
    pub fn deadline(&self, now: Instant) -> Instant {
        let publish = self.next_publish.unwrap_or(now);
        match self.workspace.deadline(now) {
            Some(at) if publish.micros_since(at).is_some() => at,
            _ => publish,
        }
    }

    fn publish(&mut self, now: Instant) {
        let intention = Message::Intention(Intention {
            strategies: self.workspace.strategies(),
        });
        self.outbox
            .push_back(intention.to_frame(self.address, BROADCAST));
        self.next_publish = Some(now.wrapping_add_micros(PUBLISH_PERIOD_US));
    }

    /// The workspace's events and commands, as reports and frames (events first: a selection
    /// is said before the commands it causes).
    fn collect(&mut self, now: Instant) {
        while let Some(event) = self.workspace.next_event() {
            if let Some(observed) = self.observed.as_mut() {
                observed.push_back(Observed::Event(event));
            }
            match event {
                Event::Selected {
                    strategies,
                    objective,
                } => {
                    let names = self.setup.strategy_names(strategies);
                    self.report(false, format!("selected: {names} (objective {objective})"));
                    self.publish(now);
                }
                Event::SolveFailed(error) => self.report(
                    true,
                    format!("solving failed, the previous selection stays: {error}"),
                ),
                Event::Expired => {
                    self.report(false, "a desire's lease ran out: recomputing".to_string());
                }
                Event::Acknowledged { target, phi } => {
                    let filter = self.setup.filter(&target);
                    let node = self.setup.node(target.node);
                    self.report(false, format!("{node} applied {filter} φ {phi}"));
                }
                Event::Refused { target, phi, why } => {
                    let filter = self.setup.filter(&target);
                    let node = self.setup.node(target.node);
                    let reason = match why {
                        1 => "no such profile",
                        2 => "not a filtered connection of its table",
                        3 => "its table has no message filters",
                        _ => "an unknown reason",
                    };
                    self.report(
                        true,
                        format!(
                            "{node} refused {filter} φ {phi}: {reason} (FilterRefused, detail {why}); the intention is not in force there"
                        ),
                    );
                }
                Event::GaveUp { target, phi } => {
                    let filter = self.setup.filter(&target);
                    let node = self.setup.node(target.node);
                    self.report(
                        true,
                        format!(
                            "{node} did not answer {filter} φ {phi} after {MAX_SENDS} sends: its filter's state is unknown"
                        ),
                    );
                }
                Event::Restarted { node } => {
                    let node = self.setup.node(node);
                    self.report(
                        false,
                        format!("{node} restarted or was heard first: re-applying its filters"),
                    );
                }
                Event::Settled { refused, gave_up } => {
                    let warning = refused > 0 || gave_up > 0;
                    self.report(
                        warning,
                        format!("filters settled: {refused} refused, {gave_up} unanswered"),
                    );
                }
            }
        }
        while let Some(command) = self.workspace.next_command(now) {
            if let Some(observed) = self.observed.as_mut() {
                observed.push_back(Observed::Command(command));
            }
            let set = command.set;
            let node = self.setup.node(command.node);
            let filter = self
                .setup
                .targets
                .iter()
                .find(|t| t.node == command.node && t.port == set.port && t.index == set.connection)
                .map_or_else(|| "?".to_string(), |t| self.setup.filter(t));
            let again = if command.send > 1 {
                format!(
                    ", again (send {} of {MAX_SENDS}: no answer yet)",
                    command.send
                )
            } else {
                String::new()
            };
            let phase = if command.reduction {
                "reduction"
            } else {
                "increase"
            };
            self.report(
                command.send > 1,
                format!(
                    "FilterSet to {node}: {filter} φ {} (port {}, connection {}, seq {}; {phase}){again}",
                    set.phi, set.port, set.connection, set.sequence
                ),
            );
            self.send_sealed(Message::FilterSet(set).to_frame(self.address, command.node));
        }
        let lost = self.workspace.lost_events();
        if u64::from(lost) > self.lost_reports {
            self.lost_reports = u64::from(lost);
            self.report(
                true,
                format!("{lost} events were dropped before they could be reported"),
            );
        }
    }

    fn report(&mut self, warning: bool, text: String) {
        if self.reports.len() == MAX_REPORTS {
            self.reports.pop_front();
        }
        self.reports.push_back(Report { warning, text });
    }
}

/// What the loop needs of time.
#[allow(async_fn_in_trait)]
pub trait Clock {
    /// Now.
    fn now(&self) -> Instant;
    /// Returns at `at` (at once if it is past).
    async fn sleep_until(&mut self, at: Instant);
}

/// The system's monotonic clock, from the moment it is made; sleeps with `async-io`'s timers.
#[derive(Clone, Copy, Debug)]
pub struct SystemClock {
    start: std::time::Instant,
}

impl SystemClock {
    /// A clock at 0 now.
    pub fn new() -> SystemClock {
        SystemClock {
            start: std::time::Instant::now(),
        }
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        SystemClock::new()
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Instant {
        let micros = self.start.elapsed().as_micros();
        Instant::from_micros(u64::try_from(micros).unwrap_or(u64::MAX))
    }

    async fn sleep_until(&mut self, at: Instant) {
        let left = at.micros_since(self.now()).unwrap_or(0);
        async_io::Timer::after(std::time::Duration::from_micros(left)).await;
    }
}

/// Runs `node` on `bus` forever: reads frames, polls at the node's deadlines, sends what it has
/// to send, and hands every report to `report` (the binary logs them). A transmit error is
/// reported and the frame dropped (the workspace sends a command again when it is not
/// acknowledged, and the intention goes out again within a second); a receive error is reported
/// and the loop pauses 1 ms (but after a count of dropped frames), so that a failing driver does
/// not make it spin.
pub async fn run<B, C>(
    node: &mut IntentNode<'_>,
    bus: &mut B,
    clock: &mut C,
    report: &mut dyn FnMut(Report),
) -> !
where
    B: CanBus,
    C: Clock,
{
    loop {
        node.poll(clock.now());
        while let Some(frame) = node.next_outgoing() {
            if let Err(error) = bus.transmit(&frame).await {
                let what = protocol::FrameId::decode(&frame.id())
                    .map_or(Service::Intention, |id| id.service);
                report(Report {
                    warning: true,
                    text: format!("sending a {what:?} frame failed: {error:?}"),
                });
            }
        }
        while let Some(line) = node.next_report() {
            report(line);
        }
        let wake = node.deadline(clock.now());
        match select(bus.receive(), clock.sleep_until(wake)).await {
            Either::First(Ok(frame)) => node.on_frame(&frame, clock.now()),
            Either::First(Err(error)) => {
                report(Report {
                    warning: true,
                    text: format!("the bus reported {error:?}"),
                });
                // As the nodes' loop: a count of dropped frames comes with a frame the next read
                // returns, so no pause then.
                if !matches!(error, pab_app::BusError::Dropped(_)) {
                    let pause = clock.now().wrapping_add_micros(1000);
                    clock.sleep_until(pause).await;
                }
            }
            Either::Second(()) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pab_core::hbba::{FilterSetting, Strategy};

    fn setup() -> Setup {
        let mut strategy = Strategy::new(0, 3);
        strategy
            .filters
            .push(FilterSetting {
                connection: 4,
                phi: 2,
            })
            .unwrap();
        let mut instance = Instance {
            classes: 1,
            ..Instance::default()
        };
        instance.capacities.push(100).unwrap();
        instance.strategies.push(strategy).unwrap();
        let target = Target {
            connection: 4,
            node: 2,
            port: 0,
            index: 1,
        };
        Setup::new(
            instance,
            vec![target],
            vec![(2, "base".into())],
            vec!["C4 (base.drive)".into()],
            vec!["follow".into()],
            vec!["goto".into()],
        )
        .unwrap()
    }

    #[test]
    fn a_setup_reads_back_what_it_wrote() {
        let setup = setup();
        let text = setup.to_json();
        assert!(text.contains(SETUP_FORMAT) && text.ends_with('\n'));
        assert_eq!(Setup::from_json(&text).unwrap(), setup);
        assert_eq!(setup.strategy_names(1), "follow");
    }

    #[test]
    fn a_setup_of_another_format_or_with_names_missing_is_refused() {
        let text = setup().to_json();
        let other = text.replace(SETUP_FORMAT, "pab intention setup 0");
        assert!(matches!(
            Setup::from_json(&other),
            Err(SetupError::Format(format)) if format == "pab intention setup 0"
        ));
        let unnamed = text.replace("\"follow\"", "");
        let error = Setup::from_json(&unnamed).unwrap_err();
        assert!(
            error
                .to_string()
                .contains("1 strategies and 0 strategy names"),
            "{error}"
        );
        let extra = text.replacen('{', "{\n  \"surplus\": 1,", 1);
        assert!(matches!(Setup::from_json(&extra), Err(SetupError::Json(_))));
        assert!(matches!(
            Setup::from_json("not json"),
            Err(SetupError::Json(_))
        ));
    }
}
