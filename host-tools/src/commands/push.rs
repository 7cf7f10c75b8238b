//! `pabctl push`: each node's table over CAN, one node after the other, with a progress bar.

use std::path::Path;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use pab_lang::compile::CompiledNode;
use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;
use pabctl::push;

use super::compile::compiled;
use super::{bus_failure, open_bus_with, read_key};
use crate::failure::Failure;
use crate::output::plural;

pub fn run(
    path: &Path,
    iface: &str,
    only: Option<&str>,
    table_version: Option<u32>,
    key: Option<&Path>,
    replace: bool,
    framing: pabctl::bus::Framing,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let credentials = match key {
        Some(key) => Some(push::Credentials {
            authenticator: read_key(key)?,
            replace,
        }),
        None => None,
    };
    let nodes = compiled(&network, table_version)?;
    let selected: Vec<&CompiledNode> = match only {
        Some(name) => {
            let node = nodes.iter().find(|node| node.name == name).ok_or_else(|| {
                let known: Vec<&str> = nodes.iter().map(|node| node.name.as_str()).collect();
                Failure::Input(
                    Diagnostic::file(
                        path,
                        format!("no node named {name:?} (nodes: {})", known.join(", ")),
                    )
                    .into(),
                )
            })?;
            vec![node]
        }
        None => nodes.iter().collect(),
    };
    let framing = super::framing_on(&network, framing);
    let mut bus = open_bus_with(iface, framing)?;
    let mut failures = 0;
    for node in selected {
        let header = pab_core::image::read_header(&node.image)
            .map_err(|error| Failure::Output(format!("compiled image is invalid: {error}")))?;
        // Who the node is, before anything is sent: a table it cannot load is refused here,
        // in one line, rather than by the node after the whole transfer.
        if let Some(why) = loadable(bus.as_mut(), node, framing).map_err(bus_failure(iface))? {
            println!(
                "{:>10}  node {:>3}  {} bytes  FAILED: not sent: {why}",
                node.name,
                node.id,
                node.image.len()
            );
            failures += 1;
            continue;
        }
        let bar = ProgressBar::new(node.image.len() as u64).with_style(
            ProgressStyle::with_template("{prefix:>10} [{bar:30}] {bytes}/{total_bytes} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        bar.set_prefix(node.name.clone());
        bar.set_message(format!(
            "node {} <- version {}",
            node.id, header.table_version
        ));
        // The transfer's time, first frame to last (what the node's time budget for a transfer
        // counts: 1 s + 10 ms per consecutive frame), not the wait for its answer; and its
        // frames (the push reports progress once a frame).
        let mut first_frame: Option<Instant> = None;
        let mut transferred: Option<Duration> = None;
        let mut frames = 0usize;
        let mut progress = |sent: usize, total: usize| {
            let now = Instant::now();
            let started = *first_frame.get_or_insert(now);
            frames += 1;
            if sent >= total {
                transferred = Some(now - started);
            }
            bar.set_position(sent as u64);
        };
        let outcome = match &credentials {
            Some(credentials) => push::push_authenticated(
                bus.as_mut(),
                node.id,
                &node.image,
                &header,
                credentials,
                push::Timeouts::default(),
                &mut progress,
            ),
            None => push::push(
                bus.as_mut(),
                node.id,
                &node.image,
                &header,
                push::Timeouts::default(),
                &mut progress,
            ),
        }
        .map_err(bus_failure(iface))?;
        bar.finish_and_clear();
        let mark = if outcome.is_success() { "ok" } else { "FAILED" };
        let took = transferred.map_or(String::new(), |d| {
            format!(
                " in {} ms ({frames} {} frame{})",
                d.as_millis(),
                framing.name(),
                plural(frames)
            )
        });
        println!(
            "{:>10}  node {:>3}  {} bytes{took}  {mark}: {outcome}",
            node.name,
            node.id,
            node.image.len()
        );
        if !outcome.is_success() {
            failures += 1;
        }
    }
    if failures > 0 {
        return Err(Failure::Bus(format!(
            "{failures} node{} did not take the new table",
            plural(failures)
        )));
    }
    Ok(())
}

/// Why `node`'s table cannot go to the node that answers to its id (`None`: it can, or it did
/// not say who it is): a table beyond what its identity says it loads.
fn loadable(
    bus: &mut dyn pabctl::bus::Bus,
    node: &CompiledNode,
    framing: pabctl::bus::Framing,
) -> std::io::Result<Option<String>> {
    let Some(identity) =
        pabctl::identity::request(bus, node.id, pabctl::identity::ANSWER_TIMEOUT)?.remove(&node.id)
    else {
        // A firmware built without identity (the boards' flashed firmware today) answers
        // nothing: the push goes on, and the node's own checks refuse what it cannot load.
        eprintln!(
            "{:>10}  node {:>3}  said nothing of itself within 500 ms (a firmware without \
             identity, or off the bus): pushing without the capacity check",
            node.name, node.id
        );
        return Ok(None);
    };
    // A firmware built without CAN FD loses every CAN FD frame of the transfer: the push
    // would only time out.
    if framing == pabctl::bus::Framing::Fd
        && identity.features & pab_core::identity::Identity::FEATURE_FD == 0
    {
        return Ok(Some(format!(
            "its firmware takes classic CAN frames only (built without CAN FD), and the transfer \
             is in CAN FD frames (--fd, or the network's data_bitrate) (node {}: {} {})",
            node.id,
            identity.firmware.name_str().unwrap_or("?"),
            pabctl::observe::version_text(&identity)
        )));
    }
    Ok(match pabctl::identity::Needs::of_image(&node.image) {
        Ok(needs) => needs.refusal(&identity).map(|why| {
            format!(
                "{why} (node {}: {} {})",
                node.id,
                identity.firmware.name_str().unwrap_or("?"),
                pabctl::observe::version_text(&identity)
            )
        }),
        Err(why) => Some(why),
    })
}
