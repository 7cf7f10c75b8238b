//! Warnings about what a file allows but almost certainly does not mean (`pabctl check` prints
//! them; they fail nothing): a network with nothing to arbitrate, a decay time that reads like
//! milliseconds written as seconds, and a connection that its topic's own rate can never make
//! active.
//!
//! The last is decided with the boards' own integrator ([`pab_core::Integrator`]), fed the
//! topic's frames at its declared rate (`rate_hz`) from rest: if the level has not reached 1
//! after [`FRAMES`](crate::check::connections::FRAMES) of them, it never will, since a steady
//! stream's level only approaches its fixed point from below.

use std::ops::Range;

use pab_core::integrator::Runtime;
use pab_core::{Instant, Integrator};

use crate::diagnostic::Warning;
use crate::network::Network;

/// Frames of a steady stream after which a connection that is not active never will be: the
/// level's approach to its fixed point is geometric, and 10 000 frames take it within far less
/// than one level step of it.
pub const FRAMES: u32 = 10_000;

/// A decay time above this many seconds gets the "milliseconds?" warning: a minute without a
/// frame is already long for a behaviour's stream.
pub const LONG_TAU_S: f64 = 60.0;

/// Every warning about the network's connections, in file order.
pub fn warnings(network: &Network) -> Vec<Warning> {
    let mut out = Vec::new();
    // Nothing for a node to run: no connection, no dynamics group, no schema server.
    if network.connections.is_empty()
        && network.dynamics.is_empty()
        && network.schema_boards.is_empty()
        && network.hbba.is_none()
    {
        let span: Range<usize> = 0..0;
        out.push(Warning(network.error(
            span,
            "the network has nothing for its nodes to run: no connection (a [connections.NAME] \
             joins a topic to a port), no [dynamics.NAME] group and no [schema.NODE] server"
                .to_string(),
        )));
    }
    for connection in &network.connections {
        if connection.tau > LONG_TAU_S {
            out.push(Warning(network.error(
                connection.span.clone(),
                format!(
                    "connection `{}`: tc = {} keeps it active {} s after its last frame; if \
                     milliseconds were meant, write tc = {}",
                    connection.name,
                    connection.tau,
                    connection.tau,
                    connection.tau / 1000.0
                ),
            )));
        }
        let Some(rate_uhz) = network
            .topics
            .get(connection.topic)
            .and_then(|t| t.rate_uhz)
        else {
            continue;
        };
        if rate_uhz == 0 {
            continue;
        }
        if !becomes_active(connection.stimulation, rate_uhz) {
            let rate = network
                .topics
                .get(connection.topic)
                .and_then(|t| t.rate_hz)
                .unwrap_or(0.0);
            out.push(Warning(network.error(
                connection.span.clone(),
                format!(
                    "connection `{}` never becomes active on its topic's {rate} frames a second: \
                     each frame adds st = {} and the level decays within tc = {} s, so it never \
                     reaches 1; raise st or tc",
                    connection.name, connection.sigma, connection.tau
                ),
            )));
        }
    }
    out.sort_by_key(|warning| warning.0.position);
    out
}

/// Whether frames every 10^6 / `rate_uhz` seconds make a connection with `stimulation` active,
/// from rest, within [`FRAMES`] frames, with the boards' integrator.
fn becomes_active(stimulation: pab_core::Stimulation, rate_uhz: u64) -> bool {
    let Ok(runtime) = Runtime::new(stimulation) else {
        return true;
    };
    // µs between frames: 10^12 / µHz.
    let Some(period_us) = 1_000_000_000_000u64.checked_div(rate_uhz) else {
        return true;
    };
    let mut integrator = Integrator::new();
    let mut now = 0u64;
    for _ in 0..FRAMES {
        integrator.stimulate(&runtime, Instant::from_micros(now));
        if integrator.is_active(&runtime, Instant::from_micros(now)) {
            return true;
        }
        now = now.saturating_add(period_us.max(1));
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnostic::Source;

    fn network(connections: &str) -> Network {
        let text = format!(
            "[nodes.hand]\nid = 2\n[topics.grasp]\ncan_id = 0x120\nrate_hz = 10.0\n\
             [ports.\"hand.command\"]\n{connections}"
        );
        Network::parse(Source::new("net.toml", text)).expect("valid")
    }

    fn messages(network: &Network) -> Vec<String> {
        warnings(network).iter().map(ToString::to_string).collect()
    }

    #[test]
    fn a_stream_that_can_activate_its_connection_gets_no_warning() {
        let n = network(
            "[connections.G]\ntopic = \"grasp\"\nport = \"hand.command\"\nst = 0.2\ntc = 1.0\n",
        );
        assert_eq!(messages(&n), Vec::<String>::new());
    }

    #[test]
    fn a_connection_its_topic_can_never_activate_is_named() {
        // 10 frames a second, each adding 0.05, decaying within 0.15 s: at most two frames count.
        let n = network(
            "[connections.G]\ntopic = \"grasp\"\nport = \"hand.command\"\nst = 0.05\ntc = 0.15\n",
        );
        let found = messages(&n);
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(found[0].starts_with("net.toml:7:"), "{found:?}");
        assert!(
            found[0].contains("warning: connection `G` never becomes active"),
            "{found:?}"
        );
    }

    #[test]
    fn a_decay_time_that_reads_like_milliseconds_is_questioned() {
        let n = network(
            "[connections.G]\ntopic = \"grasp\"\nport = \"hand.command\"\nst = 0.5\ntc = 500\n",
        );
        let found = messages(&n);
        assert!(
            found
                .iter()
                .any(|w| w.contains("tc = 500 keeps it active 500 s")
                    && w.contains("write tc = 0.5")),
            "{found:?}"
        );
    }

    #[test]
    fn an_empty_network_is_questioned() {
        let n = Network::parse(Source::new("net.toml", "[nodes.hand]\nid = 2\n")).expect("valid");
        let found = messages(&n);
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].contains("nothing for its nodes to run"),
            "{found:?}"
        );
    }
}
