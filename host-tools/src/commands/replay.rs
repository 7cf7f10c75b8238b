//! `pabctl replay`: a recorded candump capture through the network's tables, with the files
//! `sim` writes and the records and board job the cross-runner test compares.

use std::fs;
use std::path::Path;

use pab_lang::candump;
use pab_lang::diagnostic::{Diagnostic, Diagnostics};
use pab_lang::network::Network;
use pab_lang::replay::{self, Feed};
use pab_lang::sim::timed::{self, Clock};
use pab_lang::sim::{self, Options};
use pabctl::plot;

use super::compile::compiled;
use super::sim::report_and_trace;
use crate::failure::Failure;
use crate::output::{
    eprintln_line, plural, println_line, progress_bar, refuse_unwritable, write_atomically,
};

// One argument per option of the command line, as `main` hands them over (as `sim::run`).
#[allow(clippy::too_many_arguments)]
pub fn run(
    path: &Path,
    capture_path: &Path,
    trace: Option<&Path>,
    plot_path: Option<&Path>,
    records_path: Option<&Path>,
    job_path: Option<&Path>,
    timed_bus: bool,
    json: bool,
) -> Result<(), Failure> {
    // With --json, standard output is the JSON's alone.
    let say = if json { eprintln_line } else { println_line };
    // An output that is an input would destroy it (`--trace yesterday.log`): refuse before
    // reading anything.
    let inputs = [path, capture_path];
    let outputs = [
        ("--trace", trace),
        ("--plot", plot_path),
        ("--records", records_path),
        ("--board-job", job_path),
    ];
    let mut errors = Vec::new();
    for (index, (flag, output)) in outputs.iter().enumerate() {
        let Some(output) = output else { continue };
        let same_as = |other: &Path| {
            other == *output
                || matches!((fs::canonicalize(other), fs::canonicalize(output)),
                            (Ok(a), Ok(b)) if a == b)
        };
        if inputs.iter().any(|input| same_as(input)) {
            errors.push(Diagnostic::file(
                output,
                format!("{flag} would overwrite an input file"),
            ));
        }
        if outputs[..index]
            .iter()
            .any(|(_, earlier)| earlier.is_some_and(&same_as))
        {
            errors.push(Diagnostic::file(
                output,
                format!("{flag} names a file another option writes too"),
            ));
        }
    }
    if !errors.is_empty() {
        return Err(Failure::Input(Diagnostics(errors)));
    }
    refuse_unwritable(&[
        ("--trace", trace, false),
        ("--plot", plot_path, true),
        ("--records", records_path, false),
        ("--board-job", job_path, false),
    ])?;
    let network = Network::load(path)?;
    let clock = match (&network.bus, timed_bus) {
        (Some(bus), true) => Some(Clock::new(bus.bitrate, bus.data_bitrate)),
        (None, true) => {
            return Err(Failure::Input(
                Diagnostic::file(
                    path,
                    "--timed-bus: the network has no [bus], so no bit rate to time the capture's frames at (add `[bus]` with `bitrate = 500000`, and `data_bitrate` for CAN FD)",
                )
                .into(),
            ));
        }
        (_, false) => None,
    };
    let nodes = compiled(&network, None)?;
    let size = fs::metadata(capture_path).map_or(0, |m| m.len());
    let bar = progress_bar(size, "reading {bytes}/{total_bytes}");
    let capture = candump::read(capture_path, &mut |read| bar.set_position(read));
    bar.finish_and_clear();
    let mut capture = capture?;
    let feed = Feed::from_capture(&capture);
    // Every frame, the protocol's too: they all take the bus.
    let timed = clock.map(|clock| {
        let mut frames: Vec<(u64, pab_core::Frame)> = capture
            .frames
            .iter()
            .map(|c| (c.t_us.saturating_sub(feed.first_us), c.frame))
            .collect();
        frames.sort_by_key(|(t_us, _)| *t_us);
        timed::carry(clock, &frames)
    });
    // The feed holds what is replayed; the frames as read are no longer needed.
    let captured = capture.frames.len();
    capture.frames = Vec::new();
    let until_us = sim::settled_until(&network, &feed.frames);
    let options = Options {
        until: None,
        samples: plot_path.is_some(),
        records: records_path.is_some(),
        dynamics: false,
        timed_bus: false,
    };
    let bar = progress_bar(feed.frames.len() as u64, "replaying {pos}/{len} frames");
    let outcome = sim::run(
        &network,
        &nodes,
        &feed.frames,
        until_us,
        &options,
        &mut |sent| bar.set_position(sent as u64),
    );
    bar.finish_and_clear();
    let outcome = outcome
        .map_err(|error| Failure::Input(Diagnostic::file(path, error.to_string()).into()))?;
    let interfaces: Vec<&str> = capture
        .interfaces
        .iter()
        .map(|(name, _)| name.as_str())
        .collect();
    say(format!(
        "{}: {} frames over {} s on {} (time 0 = {}); {} replayed on {} node{}, {} of the pab \
         protocol not fed{}",
        capture_path.display(),
        captured,
        sim::seconds_text(feed.span_us),
        interfaces.join(", "),
        sim::seconds_text(feed.first_us),
        feed.frames.len(),
        network.nodes.len(),
        plural(network.nodes.len()),
        feed.protocol_frames,
        match capture.error_frames {
            0 => String::new(),
            n => format!(", {n} error frame{} skipped", plural(n)),
        }
    ));
    if let (count @ 1.., step) = capture.out_of_order {
        say(format!(
            "{count} frame{} out of time order in the file (at most {} s early): replayed in \
             time order",
            plural(count),
            sim::seconds_text(step)
        ));
    }
    let unmatched = feed.unmatched(&network);
    if !unmatched.is_empty() {
        let total: usize = unmatched.iter().map(|(_, count)| count).sum();
        let listed: Vec<String> = unmatched
            .iter()
            .take(12)
            .map(|((id, extended), count)| {
                if *extended {
                    format!("0x{id:08X} ×{count}")
                } else {
                    format!("0x{id:03X} ×{count}")
                }
            })
            .collect();
        say(format!(
            "{total} frame{} match no topic: {}{}",
            plural(total),
            listed.join(", "),
            if unmatched.len() > listed.len() {
                format!(" and {} more ids", unmatched.len() - listed.len())
            } else {
                String::new()
            }
        ));
    }
    report_and_trace(&network, &outcome, trace, say)?;
    // The latencies against the bounds; their failure waits for the files and the JSON, as a
    // verdict does.
    let mut late = Vec::new();
    let comparison = match &timed {
        Some(run) => {
            let timing = pab_lang::check::bus::timing(&network);
            let comparison = sim::latency::compare(&network, &timing, run)
                .map_err(|error| Failure::Input(Diagnostic::file(path, error).into()))?;
            say(comparison.table(&timing).trim_end().to_string());
            late = comparison.errors(&network, &timing);
            Some((comparison, timing))
        }
        None => None,
    };
    if let Some(records_path) = records_path {
        write_atomically(records_path, outcome.records.as_bytes())?;
        say(format!("records: {}", records_path.display()));
    }
    if let Some(job_path) = job_path {
        let job = replay::job(&network, &nodes, &feed.frames)
            .map_err(|error| Failure::Input(Diagnostic::file(path, error.to_string()).into()))?;
        write_atomically(job_path, &job)?;
        say(format!(
            "board job: {} ({} bytes)",
            job_path.display(),
            job.len()
        ));
    }
    if let Some(plot_path) = plot_path {
        let title = capture_path
            .file_name()
            .map_or("capture".into(), |n| n.to_string_lossy().into_owned());
        let mut data = outcome.plot_data(&network, &title);
        data.phases.clear();
        plot::render(&data, plot_path).map_err(|error| {
            Failure::Output(format!("cannot draw {}: {error:#}", plot_path.display()))
        })?;
        say(format!("plot: {}", plot_path.display()));
    }
    if json {
        let mut found = pabctl::json::sim(path, &network, &outcome);
        found["capture"] = capture_path.display().to_string().into();
        found["captured"] = captured.into();
        found["replayed"] = feed.frames.len().into();
        found["protocol_frames"] = feed.protocol_frames.into();
        found["error_frames"] = capture.error_frames.into();
        found["unmatched"] = unmatched
            .iter()
            .map(|((id, extended), count)| {
                serde_json::json!({"id": id, "extended": extended, "count": count})
            })
            .collect::<Vec<_>>()
            .into();
        if let Some((comparison, timing)) = &comparison {
            found["timed_bus"] = pabctl::json::timed_bus(comparison, timing);
        }
        println!("{found}");
    }
    if !late.is_empty() {
        return Err(Failure::Latencies(late));
    }
    Ok(())
}
