//! `pabctl monitor`: a live view of every port's connections from the nodes' diagnostic stream.
//!
//! The tool switches the stream on at each node of the network (DiagnosticControl), redraws the
//! terminal a few times per second from the latest samples, and switches the stream off when it
//! ends. Names come from the network file; values only from the nodes. A node that runs a
//! competitive-dynamics group shows its gates from its Gates frames, which it sends anyway.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::{Duration, Instant};

use pab_core::protocol::{self, DiagnosticControl, Gates, Message};

use crate::bus::Bus;
use crate::observe::Observer;
use pab_lang::network::Network;

/// Samples older than this are shown as stale: the node stopped streaming or left the bus.
pub const STALE_AFTER: Duration = Duration::from_secs(2);

/// Width of a stimulation bar in characters.
const BAR: usize = 30;

/// Asks every node of `network` for `rate_hz` diagnostic rounds per second (0 stops them).
pub fn request_stream(bus: &mut dyn Bus, network: &Network, rate_hz: u16) -> std::io::Result<()> {
    for node in &network.nodes {
        let control = Message::DiagnosticControl(DiagnosticControl {
            rate_hz,
            ports: u16::MAX,
        });
        bus.send(&control.to_frame(protocol::TOOL, node.id))?;
    }
    Ok(())
}

/// As [`request_stream`], authenticated for nodes with a key: per node a challenge, then the
/// tagged command. Returns, for each node that was not asked, why: it sent no challenge (a node
/// without a key, or off the bus), only challenges that did not verify, or it refused tags
/// meanwhile (its Unauthenticated faults: someone flooding it with bad tags, as `pabctl push`
/// says it). Each node's challenge waits up to a second.
pub fn request_stream_keyed(
    bus: &mut dyn Bus,
    network: &Network,
    rate_hz: u16,
    authenticator: &pab_core::auth::Authenticator,
) -> std::io::Result<BTreeMap<u8, String>> {
    use crate::push::{Challenged, Refusals};
    let mut unasked = BTreeMap::new();
    for node in &network.nodes {
        let control = DiagnosticControl {
            rate_hz,
            ports: u16::MAX,
        };
        // The node's refusals are read on the way: a flood of bad tags is said as such.
        let mut watched = Refusals::new(&mut *bus, node.id);
        let answer =
            crate::push::challenge(&mut watched, authenticator, node.id, Duration::from_secs(1))?;
        let nonce = match (answer, watched.reason()) {
            (Challenged::Bound(nonce), _) => nonce,
            (Challenged::Nothing { .. }, Some(why)) => {
                unasked.insert(node.id, why);
                continue;
            }
            (Challenged::Nothing { unbound: 0 }, None) => {
                unasked.insert(
                    node.id,
                    "no challenge: a node without a key, or off the bus".to_string(),
                );
                continue;
            }
            (Challenged::Nothing { unbound }, None) => {
                unasked.insert(
                    node.id,
                    format!(
                        "{unbound} challenge(s) in its name that did not verify: a key that is \
                         not the node's, another tool, or a participant making them up"
                    ),
                );
                continue;
            }
        };
        let mut payload = [0u8; 4];
        payload[..2].copy_from_slice(&control.rate_hz.to_le_bytes());
        payload[2..].copy_from_slice(&control.ports.to_le_bytes());
        let tag = authenticator.command_tag(
            node.id,
            protocol::Service::DiagnosticControl.code(),
            nonce,
            &payload,
        );
        let message = Message::AuthenticatedDiagnosticControl { control, tag };
        bus.send(&message.to_frame(protocol::TOOL, node.id))?;
    }
    Ok(unasked)
}

/// When each sample arrived, to tell live samples from stale ones.
#[derive(Default)]
pub struct Freshness {
    seen: BTreeMap<(u8, u8, u8), Instant>,
}

impl Freshness {
    /// Notes the arrival of a sample.
    pub fn note(&mut self, node: u8, port: u8, connection: u8, at: Instant) {
        self.seen.insert((node, port, connection), at);
    }

    fn is_fresh(&self, key: (u8, u8, u8), now: Instant) -> bool {
        self.seen
            .get(&key)
            .is_some_and(|at| now.saturating_duration_since(*at) < STALE_AFTER)
    }
}

/// The screen: per node, per port, one line per connection with its stimulation bar.
///
/// ```text
/// arm (id 1)  version 1  operational
///   gates tr  take OPEN  hold -  bring -  release -  (3 changes)
///   arm.target
///     C1  object_pos  [##########--------------------] 0.33
///     C3  rest_pose   [##############################] 1.00  ACTIVE  ◀ delivering
/// ```
pub fn render(
    network: &Network,
    observer: &Observer,
    freshness: &Freshness,
    unasked: &BTreeMap<u8, String>,
    now: Instant,
) -> String {
    let mut out = String::new();
    for node in &network.nodes {
        let view = observer.node(node.id);
        let header = match view.and_then(|v| v.heartbeat) {
            Some((heartbeat, _)) => format!(
                "version {}  {}",
                heartbeat.table_version,
                heartbeat.state.description()
            ),
            None => "not heard from".to_string(),
        };
        let _ = writeln!(out, "{} (id {})  {}", node.name, node.id, header);
        if let Some(why) = unasked.get(&node.id) {
            let _ = writeln!(out, "  ! stream not asked for: {why}");
        }
        for (number, group) in network.dynamics.iter().enumerate() {
            if network.nodes.get(group.node).map(|n| n.id) != Some(node.id) {
                continue;
            }
            let heard = u8::try_from(number)
                .ok()
                .and_then(|number| view.and_then(|v| v.gates.get(&number)));
            let _ = writeln!(
                out,
                "  gates {}  {}",
                group.name,
                gates_line(group, heard, now)
            );
        }
        for (port_index, &port) in node.ports.iter().enumerate() {
            let _ = writeln!(out, "  {}", network.ports[port].name);
            for connection in network.port_connections(port) {
                let key = (
                    node.id,
                    u8::try_from(port_index).unwrap_or(u8::MAX),
                    u8::try_from(connection.index).unwrap_or(u8::MAX),
                );
                let sample = view.and_then(|v| v.samples.get(&(key.1, key.2)));
                // A gate has no topic: it shows as fed by its group.
                let topic = network
                    .topics
                    .get(connection.topic)
                    .map_or("gate", |t| t.name.as_str());
                let line = match sample {
                    Some(sample) if freshness.is_fresh(key, now) => {
                        let level = sample.level_f32().clamp(0.0, 1.0);
                        let filled = (level * BAR as f32).round() as usize;
                        format!(
                            "[{}{}] {:.2}{}{}{}",
                            "#".repeat(filled),
                            "-".repeat(BAR - filled.min(BAR)),
                            level,
                            if sample.flags.active { "  ACTIVE" } else { "" },
                            if sample.flags.resting {
                                "  resting"
                            } else {
                                ""
                            },
                            if sample.flags.delivering {
                                "  ◀ delivering"
                            } else {
                                ""
                            },
                        )
                    }
                    Some(_) => "(stale)".to_string(),
                    None => "(no sample)".to_string(),
                };
                let _ = writeln!(out, "    {:<6} {:<14} {line}", connection.name, topic);
            }
        }
    }
    out
}

/// A group's gates as its owner last sent them: each behaviour OPEN or `-`, and the count of
/// changes; after [`Gates::SILENCE_US`] without a frame the readers have closed every gate, and
/// so does the line.
fn gates_line(
    group: &pab_lang::network::DynamicsGroup,
    heard: Option<&(Gates, Instant)>,
    now: Instant,
) -> String {
    let Some((gates, at)) = heard else {
        return "(not heard)".to_string();
    };
    if now.saturating_duration_since(*at) >= Duration::from_micros(Gates::SILENCE_US) {
        return "(silent: read as all closed)".to_string();
    }
    let mut line = String::new();
    for (bit, behaviour) in group.behaviours.iter().enumerate() {
        let open = bit < 32 && gates.mask >> bit & 1 == 1;
        let _ = write!(
            line,
            "{} {}  ",
            behaviour.name,
            if open { "OPEN" } else { "-" }
        );
    }
    let _ = write!(line, "({} changes)", gates.changes);
    line
}

/// Runs the monitor: streams at `rate_hz`, redraws every `redraw`, for `duration` (forever if
/// `None`) or until `stop` returns true. `draw` receives each screen.
#[allow(clippy::too_many_arguments)]
pub fn run(
    bus: &mut dyn Bus,
    network: &Network,
    rate_hz: u16,
    redraw: Duration,
    duration: Option<Duration>,
    stop: &dyn Fn() -> bool,
    draw: &mut dyn FnMut(&str),
    key: Option<&pab_core::auth::Authenticator>,
) -> std::io::Result<Observer> {
    // Nodes with a key take only the authenticated command (one challenge per node); the screen
    // says why a node was not asked.
    let request = |bus: &mut dyn Bus, rate_hz: u16| match key {
        Some(key) => request_stream_keyed(bus, network, rate_hz, key),
        None => request_stream(bus, network, rate_hz).map(|()| BTreeMap::new()),
    };
    let started = Instant::now();
    let mut observer = Observer::new();
    let mut freshness = Freshness::default();
    let mut unasked = request(bus, rate_hz)?;
    let mut last_request = Instant::now();
    let mut next_draw = Instant::now() + redraw;
    loop {
        let now = Instant::now();
        if stop() || duration.is_some_and(|d| now.duration_since(started) >= d) {
            break;
        }
        // Nodes that restart come back with the stream off: ask again now and then.
        if now.duration_since(last_request) >= Duration::from_secs(3) {
            unasked = request(bus, rate_hz)?;
            last_request = now;
        }
        let wait = next_draw.saturating_duration_since(now);
        if let Some(frame) = bus.receive(wait)? {
            let at = Instant::now();
            if let Some((id, Message::Diagnostic(sample))) = observer.observe(&frame, at) {
                freshness.note(id.source, sample.port, sample.connection, at);
            }
        }
        if Instant::now() >= next_draw {
            draw(&render(
                network,
                &observer,
                &freshness,
                &unasked,
                Instant::now(),
            ));
            next_draw += redraw;
        }
    }
    request(bus, 0)?;
    Ok(observer)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pab_core::Frame;
    use pab_lang::diagnostic::Source;

    fn door() -> Network {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/door-dynamics.toml"
        );
        let text = std::fs::read_to_string(path).unwrap();
        Network::parse(Source::new("door-dynamics.toml", &text)).unwrap()
    }

    fn gates_frame(source: u8, mask: u32, changes: u8) -> Frame {
        let gates = Gates {
            group: 0,
            behaviours: 3,
            mask,
            changes,
        };
        Message::Gates(gates).to_frame(source, protocol::BROADCAST)
    }

    #[test]
    fn a_node_not_asked_for_its_stream_says_why_under_its_name() {
        let network = door();
        let node = &network.nodes[0];
        let why =
            "the node refused 37 tags, more than it checks in a second: someone is flooding it";
        let unasked = BTreeMap::from([(node.id, why.to_string())]);
        let screen = render(
            &network,
            &Observer::new(),
            &Freshness::default(),
            &unasked,
            Instant::now(),
        );
        let header = format!("{} (id {})  not heard from\n", node.name, node.id);
        assert!(
            screen.contains(&format!("{header}  ! stream not asked for: {why}\n")),
            "{screen}"
        );
        assert_eq!(screen.matches("not asked").count(), 1, "{screen}");
    }

    #[test]
    fn the_owner_of_a_group_shows_its_gates_until_it_falls_silent() {
        let network = door();
        let base = &network.nodes[network.dynamics[0].node];
        let mut observer = Observer::new();
        let freshness = Freshness::default();
        let start = Instant::now();
        let screen = render(&network, &observer, &freshness, &BTreeMap::new(), start);
        assert!(screen.contains("  gates door  (not heard)\n"), "{screen}");

        observer.observe(&gates_frame(base.id, 0b010, 2), start);
        let screen = render(&network, &observer, &freshness, &BTreeMap::new(), start);
        assert!(
            screen.contains("  gates door  search -  recognise OPEN  approach -  (2 changes)\n"),
            "{screen}"
        );
        // Only the owner's section has the line.
        assert_eq!(screen.matches("gates door").count(), 1, "{screen}");

        let later = start + Duration::from_micros(Gates::SILENCE_US);
        let screen = render(&network, &observer, &freshness, &BTreeMap::new(), later);
        assert!(
            screen.contains("  gates door  (silent: read as all closed)\n"),
            "{screen}"
        );
    }
}
