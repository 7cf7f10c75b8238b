//! `pabctl sim`: the network on a simulated bus, its report and the files it writes (trace, plot,
//! candump log, dynamics trace), with `--timed-bus` the latencies against the bounds; then the
//! schema server's part of the run.

use std::path::Path;

use pab_lang::candump;
use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;
use pab_lang::sim::{self, Options};
use pabctl::plot;

use super::compile::compiled;
use crate::failure::Failure;
use crate::output::{eprintln_line, plural, println_line, refuse_unwritable, write_atomically};

/// The ports' part of `pabctl sim`. It returns whether the file has a schema server and no port,
/// for then `--plot` is the schema server's to draw.
// One argument per option of the command line, as `main` hands them over.
#[allow(clippy::too_many_arguments)]
pub fn run(
    path: &Path,
    until: Option<f64>,
    trace: Option<&Path>,
    plot_path: Option<&Path>,
    candump_path: Option<&Path>,
    dynamics_path: Option<&Path>,
    timed_bus: bool,
    json: bool,
) -> Result<bool, Failure> {
    // With --json, standard output is the JSON's alone.
    let say = if json { eprintln_line } else { println_line };
    refuse_unwritable(&[
        ("--trace", trace, false),
        ("--plot", plot_path, true),
        ("--candump", candump_path, false),
        ("--dynamics-trace", dynamics_path, false),
    ])?;
    let network = Network::load(path)?;
    if dynamics_path.is_some() && network.dynamics.is_empty() {
        return Err(Failure::Input(
            Diagnostic::file(
                path,
                "--dynamics-trace: the network has no [dynamics.*] group, so nothing to trace",
            )
            .into(),
        ));
    }
    if timed_bus && network.bus.is_none() {
        return Err(Failure::Input(
            Diagnostic::file(
                path,
                "--timed-bus: the network has no [bus], so no bit rate to time its frames at (add `[bus]` with `bitrate = 500000`, and `data_bitrate` for CAN FD)",
            )
            .into(),
        ));
    }
    let schema_only = network.ports.is_empty() && network.client.is_some();
    let nodes = compiled(&network, None)?;
    let options = Options {
        until,
        samples: plot_path.is_some(),
        records: false,
        // The plot draws the dynamics groups' lanes.
        dynamics: dynamics_path.is_some() || plot_path.is_some(),
        timed_bus,
    };
    let outcome = sim::simulate(&network, &nodes, &options)
        .map_err(|error| Failure::Input(Diagnostic::file(path, error.to_string()).into()))?;
    say(format!(
        "{}: {} frames on {} node{}, until t = {} s",
        path.display(),
        outcome.frames,
        network.nodes.len(),
        plural(network.nodes.len()),
        sim::seconds_text(outcome.until_us)
    ));
    report_and_trace(&network, &outcome, trace, say)?;
    // The latencies against the bounds, at the file's rates; their failure waits for the files
    // and the JSON, as a verdict does.
    let mut late = Vec::new();
    let comparison = match &outcome.timed {
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
    if let Some(plot_path) = plot_path.filter(|_| !schema_only) {
        let title = path
            .file_name()
            .map_or("network".into(), |n| n.to_string_lossy().into_owned());
        plot::render(&outcome.plot_data(&network, &title), plot_path).map_err(|error| {
            Failure::Output(format!("cannot draw {}: {error:#}", plot_path.display()))
        })?;
        say(format!("plot: {}", plot_path.display()));
    }
    if let Some(candump_path) = candump_path {
        let mut log = String::new();
        let mut written = 0usize;
        for frame in &outcome.bus {
            log.push_str(&candump::line(frame.t_us, "vcan0", &frame.frame));
            log.push('\n');
            written += 1;
        }
        write_atomically(candump_path, log.as_bytes())?;
        say(format!(
            "candump: {} ({written} frames)",
            candump_path.display()
        ));
    }
    if let Some(dynamics_path) = dynamics_path {
        let mut csv = Vec::new();
        sim::write_dynamics_csv(&outcome.dynamics, &network, &mut csv).map_err(|error| {
            Failure::Output(format!("cannot write the dynamics trace: {error}"))
        })?;
        write_atomically(dynamics_path, &csv)?;
        say(format!(
            "dynamics trace: {} ({} rows)",
            dynamics_path.display(),
            outcome.dynamics.len()
        ));
    }
    if json {
        let mut value = pabctl::json::sim(path, &network, &outcome);
        if let Some((comparison, timing)) = &comparison {
            value["timed_bus"] = pabctl::json::timed_bus(comparison, timing);
        }
        println!("{value}");
    }
    if !late.is_empty() {
        return Err(Failure::Latencies(late));
    }
    Ok(schema_only)
}

/// The schema server's part of `pabctl sim`: runs when the file has a `[client]`; asked for
/// without one, an error.
pub fn run_schema(
    path: &Path,
    from: Option<f64>,
    until: Option<f64>,
    trace: Option<&Path>,
    plot_path: Option<&Path>,
    program_path: Option<&Path>,
    say: fn(String),
) -> Result<(), Failure> {
    refuse_unwritable(&[
        ("--schema-trace", trace, false),
        ("--schema-plot", plot_path, true),
        ("--schema-program", program_path, false),
    ])?;
    let network = Network::load(path)?;
    if network.client.is_none() {
        if trace.is_some() || plot_path.is_some() || program_path.is_some() {
            return Err(Failure::Input(
                Diagnostic::file(
                    path,
                    "--schema-trace, --schema-plot and --schema-program need a schema server with a [client] in the file",
                )
                .into(),
            ));
        }
        return Ok(());
    }
    if let (Some(program_path), Some(client)) = (program_path, network.client.as_ref()) {
        let calls: Vec<serde_json::Value> = client
            .program
            .iter()
            .map(|call| serde_json::json!({ "name": call.name, "schema": call.schema }))
            .collect();
        let text = serde_json::to_string_pretty(&calls)
            .map_err(|e| Failure::Output(format!("cannot write the program: {e}")))?;
        write_atomically(program_path, text.as_bytes())?;
        say(format!(
            "schema program: {} ({} calls)",
            program_path.display(),
            calls.len()
        ));
    }
    let limits = sim::schema::Limits {
        until_us: until.map_or(100_000 * 1_000_000, sim::micros),
        settle_us: 100_000,
    };
    let run = sim::schema::simulate(&network, limits)
        .map_err(|error| Failure::Input(Diagnostic::file(path, error.to_string()).into()))?;
    let report = sim::schema::report(&run, &network);
    if !report.is_empty() {
        say(report.trim_end().to_string());
    }
    if let Some(trace) = trace {
        let mut csv = Vec::new();
        sim::schema::write_trace(&run, &network, &mut csv)
            .map_err(|error| Failure::Output(format!("cannot write the schema trace: {error}")))?;
        write_atomically(trace, &csv)?;
        say(format!(
            "schema trace: {} ({} rows)",
            trace.display(),
            run.installed.len()
        ));
    }
    if let Some(plot_path) = plot_path {
        let title = path
            .file_name()
            .map_or("network".into(), |n| n.to_string_lossy().into_owned());
        let end = run.end_us as f64 * 1e-6;
        let from = from.unwrap_or(0.0);
        plot::schema::render(&run, from, until.unwrap_or(end).min(end), &title, plot_path)
            .map_err(|error| {
                Failure::Output(format!("cannot draw {}: {error:#}", plot_path.display()))
            })?;
        say(format!("schema plot: {}", plot_path.display()));
    }
    Ok(())
}

/// The run's report, then its trace written to `trace` if asked: what sim and replay both print
/// after a run, through `say` (standard error under `--json`).
pub(super) fn report_and_trace(
    network: &Network,
    outcome: &sim::Outcome,
    trace: Option<&Path>,
    say: fn(String),
) -> Result<(), Failure> {
    let report = outcome.report(network);
    if !report.is_empty() {
        say(report.trim_end().to_string());
    }
    if let Some(trace) = trace {
        let mut csv = Vec::new();
        outcome
            .write_csv(network, &mut csv)
            .map_err(|error| Failure::Output(format!("cannot write the trace: {error}")))?;
        write_atomically(trace, &csv)?;
        say(format!(
            "trace: {} ({} rows)",
            trace.display(),
            outcome.rows.len()
        ));
    }
    Ok(())
}
