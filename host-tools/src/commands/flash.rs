//! `pabctl flash`: a signed firmware image to each node over CAN, one node after the other, with
//! a progress bar (pabctl's `flash` module does the exchange).

use std::path::Path;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;
use pabctl::flash;

use super::{bus_failure, open_bus_with, read_key};
use crate::failure::Failure;
use crate::output::plural;

/// The largest signed file read: 16 MiB, more than any board's flash.
const MAX_IMAGE: u64 = 16 << 20;

pub fn run(
    firmware: &Path,
    iface: &str,
    nodes: &[String],
    network: Option<&Path>,
    key: Option<&Path>,
    restart_timeout: f64,
    framing: pabctl::bus::Framing,
) -> Result<(), Failure> {
    // Everything is read and checked before the bus is opened.
    pab_lang::input::regular_file(firmware, "signed firmware image", MAX_IMAGE)
        .map_err(|diagnostic| Failure::Input(diagnostic.into()))?;
    let bytes = std::fs::read(firmware).map_err(|error| {
        Failure::Input(Diagnostic::file(firmware, format!("cannot read it: {error}")).into())
    })?;
    let signed = flash::parse(&bytes)
        .map_err(|message| Failure::Input(Diagnostic::file(firmware, message).into()))?;
    let targets = resolve(nodes, network)?;
    let key = key.map(read_key).transpose()?;
    let timeouts = flash::Timeouts {
        // In (0, MAX_TIME_S] since parsing (args::seconds): the conversion cannot fail.
        restart: Duration::try_from_secs_f64(restart_timeout).unwrap_or(Duration::from_secs(30)),
        ..flash::Timeouts::default()
    };
    let total = signed.image().len();
    let target = flash::firmware_text(&signed.trailer.firmware);
    let mut bus = open_bus_with(iface, framing)?;
    let mut failures = 0;
    let mut stopped = None;
    for (index, (id, name)) in targets.iter().enumerate() {
        let bar = ProgressBar::new(total as u64).with_style(
            ProgressStyle::with_template(
                "{prefix:>10} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec} {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
        bar.set_prefix(name.clone());
        bar.set_message(format!("node {id} <- {target}"));
        // The transfer's time, Begin to the last chunk's Ack (not the restart's).
        let started = Instant::now();
        let mut transferred: Option<Duration> = None;
        let mut progress = |sent: usize, total: usize| {
            if sent >= total {
                transferred.get_or_insert(started.elapsed());
            }
            bar.set_position(sent as u64);
        };
        let outcome = flash::flash(
            bus.as_mut(),
            *id,
            &signed,
            key.as_ref(),
            timeouts,
            &mut progress,
        )
        .map_err(bus_failure(iface))?;
        bar.finish_and_clear();
        let mark = if outcome.is_success() { "ok" } else { "FAILED" };
        let took = transferred.map_or(String::new(), |d| {
            let seconds = d.as_secs_f64().max(1e-6);
            format!(
                " in {} ms ({:.0} B/s)",
                d.as_millis(),
                total as f64 / seconds
            )
        });
        println!("{name:>10}  node {id:>3}  {total} bytes{took}  {mark}: {outcome}");
        if !outcome.is_success() {
            failures += 1;
            if outcome.after_commit() {
                stopped = Some(targets.len() - index - 1);
                break;
            }
        }
    }
    if let Some(left) = stopped.filter(|&left| left > 0) {
        eprintln!(
            "stopped: {left} node{} not updated, as the image did not run on the last one",
            plural(left)
        );
    }
    if failures > 0 {
        return Err(Failure::Bus(format!(
            "{failures} node{} did not take the update",
            plural(failures)
        )));
    }
    Ok(())
}

/// The nodes of `--node`: ids as they are, names through the network file, each with the name
/// it is printed with.
fn resolve(nodes: &[String], network: Option<&Path>) -> Result<Vec<(u8, String)>, Failure> {
    let network_path = network;
    let network = network.map(Network::load).transpose()?;
    let mut targets = Vec::new();
    for text in nodes {
        let text = text.trim();
        let named = network
            .as_ref()
            .and_then(|network| network.nodes.iter().find(|node| node.name == text));
        let target = match named {
            Some(node) => (node.id, node.name.clone()),
            None if text.bytes().all(|b| b.is_ascii_digit()) && !text.is_empty() => {
                let id = pabctl::args::node_id(text).map_err(|why| {
                    Failure::Input(
                        Diagnostic::file(Path::new("--node"), format!("{text}: {why}")).into(),
                    )
                })?;
                let name = network
                    .as_ref()
                    .and_then(|network| network.nodes.iter().find(|node| node.id == id))
                    .map_or(format!("node {id}"), |node| node.name.clone());
                (id, name)
            }
            None => {
                let why = match &network {
                    Some(network) => format!(
                        "no node named {text:?} in the network file (nodes: {})",
                        network
                            .nodes
                            .iter()
                            .map(|node| node.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                    None => format!(
                        "`{text}` is not a node id (1 to 127); give --network FILE to name nodes"
                    ),
                };
                return Err(Failure::Input(
                    Diagnostic::file(network_path.unwrap_or(Path::new("--node")), why).into(),
                ));
            }
        };
        if !targets.contains(&target) {
            targets.push(target);
        }
    }
    Ok(targets)
}
