//! `pabctl`: check, compile and simulate port-arbitration networks; push tables to the nodes on a
//! CAN bus, list them, monitor them.
//!
//! The command line is [`cli`]; how a command fails and the exit status that says so,
//! [`failure`]; what every command shares in writing its results, [`output`].

mod cli;
mod failure;
mod output;

use std::fs;
use std::io::{self, Write};
use std::path::Path;
use std::process::ExitCode;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use pab_lang::candump;
use pab_lang::check;
use pab_lang::compile::{self, CompiledNode};
use pab_lang::dbc;
use pab_lang::diagnostic::{Diagnostic, Diagnostics};
use pab_lang::network::Network;
use pab_lang::replay::{self, Feed};
use pab_lang::sim::{self, Options};
use pabctl::bus::{self, Bus};
use pabctl::plot;
use pabctl::{monitor, observe, push};

use cli::{Cli, Command};
use failure::Failure;
use output::{
    colour, eprintln_line, plural, println_line, progress_bar, refuse_unwritable, write_atomically,
};

/// A reader that goes away (`pabctl sim NET.toml | head`) ends pabctl quietly, as it ends any
/// Unix tool. Rust's runtime ignores SIGPIPE, which turns the next write to the closed pipe into
/// an error that `println!` reports as a panic.
fn restore_sigpipe() {
    // SAFETY: called first thing in `main`, before any other thread exists; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> ExitCode {
    restore_sigpipe();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check { network, json } => run_check(&network, json),
        Command::Compile {
            network,
            output,
            table_version,
            json,
        } => run_compile(&network, &output, table_version, json),
        Command::Sim {
            network,
            until,
            trace,
            plot,
            candump,
            dynamics_trace,
            schema_trace,
            schema_plot,
            schema_program,
            from,
            json,
        } => run_sim(
            &network,
            until,
            trace.as_deref(),
            plot.as_deref(),
            candump.as_deref(),
            dynamics_trace.as_deref(),
            json,
        )
        .and_then(|schema_only| {
            // A file with a schema server and no port: its plot is the schema server's.
            let schema_plot = schema_plot.or(if schema_only { plot } else { None });
            run_schema_sim(
                &network,
                from,
                until,
                schema_trace.as_deref(),
                schema_plot.as_deref(),
                schema_program.as_deref(),
                if json { eprintln_line } else { println_line },
            )
        }),
        Command::Replay {
            network,
            capture,
            trace,
            plot,
            records,
            board_job,
            json,
        } => run_replay(
            &network,
            &capture,
            trace.as_deref(),
            plot.as_deref(),
            records.as_deref(),
            board_job.as_deref(),
            json,
        ),
        Command::Push {
            network,
            iface,
            node,
            table_version,
            key,
            replace,
        } => run_push(
            &network,
            &iface,
            node.as_deref(),
            table_version,
            key.as_deref(),
            replace,
        ),
        Command::Plant {
            network,
            iface,
            duration,
            period_ms,
            log,
        } => run_plant(&network, &iface, duration, period_ms, log.as_deref()),
        Command::Run {
            network,
            iface,
            timeout,
            trace,
            key,
        } => run_client_program(&network, &iface, timeout, trace.as_deref(), key.as_deref()),
        Command::Limits {
            network,
            iface,
            key,
            overrides,
            dry_run,
        } => {
            let iface = if dry_run { None } else { iface };
            run_limits(&network, iface.as_deref(), key.as_deref(), &overrides)
        }
        Command::Init { file, example } => run_init(&file, example.as_deref()),
        Command::Keygen { output } => run_keygen(&output),
        Command::Keypage { key, output } => run_keypage(&key, &output),
        Command::Nodes {
            iface,
            network,
            listen,
            json,
        } => run_nodes(&iface, network.as_deref(), listen, json),
        Command::Monitor {
            network,
            iface,
            rate,
            duration,
            plain,
            key,
        } => run_monitor(&network, &iface, rate, duration, plain, key.as_deref()),
        Command::Dbc {
            network,
            output,
            claims_from,
        } => run_dbc(&network, &output, claims_from.as_deref()),
        Command::Schema => io::stdout()
            .write_all(pab_lang::network::json_schema().as_bytes())
            .map_err(|error| Failure::Output(format!("standard output: {error}"))),
        Command::Solve {
            network,
            desires,
            json,
        } => run_solve(&network, &desires, json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => failure.report(),
    }
}

fn open_bus(iface: &str) -> Result<Box<dyn Bus>, Failure> {
    bus::open(iface).map_err(|error| Failure::Bus(error.to_string()))
}

fn bus_failure(iface: &str) -> impl Fn(io::Error) -> Failure + '_ {
    move |error| Failure::Bus(format!("on {iface}: {error}"))
}

fn read_key(path: &Path) -> Result<pab_core::auth::Authenticator, Failure> {
    let key = pabctl::keys::read(path)
        .map_err(|message| Failure::Input(Diagnostic::file(path, message).into()))?;
    Ok(pab_core::auth::Authenticator::new(&key))
}

fn run_init(file: &Path, example: Option<&str>) -> Result<(), Failure> {
    let name = example.unwrap_or(pabctl::starter::DEFAULT);
    let text = pabctl::starter::find(name).map_err(|message| {
        Failure::Input(Diagnostic::file(Path::new("--example"), message).into())
    })?;
    // create_new: a file that is there, whoever wrote it, is never replaced.
    let mut out = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(file)
        .map_err(|error| match error.kind() {
            std::io::ErrorKind::AlreadyExists => format!(
                "{}: already exists; pabctl init never overwrites a file (give another name)",
                file.display()
            ),
            _ => format!("{}: cannot create: {error}", file.display()),
        })
        .map_err(Failure::Output)?;
    use std::io::Write as _;
    out.write_all(text.as_bytes())
        .map_err(|error| Failure::Output(format!("{}: {error}", file.display())))?;
    let what = if example.is_some() {
        format!("the example `{name}`")
    } else {
        "the tutorial's network (docs/tutorial.md)".to_string()
    };
    println!("{}: {what} written; next: pabctl check {0}", file.display());
    Ok(())
}

fn run_keygen(output: &Path) -> Result<(), Failure> {
    let key = pabctl::keys::generate().map_err(Failure::Output)?;
    pabctl::keys::write_new(output, &key).map_err(Failure::Output)?;
    println!("{}: new key written (mode 0600)", output.display());
    Ok(())
}

fn run_keypage(key: &Path, output: &Path) -> Result<(), Failure> {
    let parsed = pabctl::keys::read(key)
        .map_err(|message| Failure::Input(Diagnostic::file(key, message).into()))?;
    write_atomically(output, &pabctl::keys::page_image(&parsed))?;
    println!("{}: key page record written (32 bytes)", output.display());
    Ok(())
}

fn run_push(
    path: &Path,
    iface: &str,
    only: Option<&str>,
    table_version: Option<u32>,
    key: Option<&Path>,
    replace: bool,
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
    let mut bus = open_bus(iface)?;
    let mut failures = 0;
    for node in selected {
        let header = pab_core::image::read_header(&node.image)
            .map_err(|error| Failure::Output(format!("compiled image is invalid: {error}")))?;
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
        // counts: 1 s + 10 ms per consecutive frame), not the wait for its answer.
        let mut first_frame: Option<Instant> = None;
        let mut transferred: Option<Duration> = None;
        let mut progress = |sent: usize, total: usize| {
            let now = Instant::now();
            let started = *first_frame.get_or_insert(now);
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
        let took = transferred.map_or(String::new(), |d| format!(" in {} ms", d.as_millis()));
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

fn run_nodes(iface: &str, network: Option<&Path>, listen: f64, json: bool) -> Result<(), Failure> {
    let names = match network {
        Some(path) => Network::load(path)?
            .nodes
            .iter()
            .map(|node| (node.id, node.name.clone()))
            .collect(),
        None => BTreeMap::new(),
    };
    // In (0, 3600] since parsing (args::listen_seconds): the conversion cannot fail.
    let listen_for = Duration::try_from_secs_f64(listen).unwrap_or(Duration::ZERO);
    let mut bus = open_bus(iface)?;
    let mut observer = observe::Observer::new();
    observe::listen(bus.as_mut(), &mut observer, listen_for).map_err(bus_failure(iface))?;
    if observer.nodes().is_empty() {
        return Err(Failure::Bus(format!(
            "no node heard on {iface} within {listen} s"
        )));
    }
    let now = std::time::Instant::now();
    if json {
        println!("{}", pabctl::json::nodes(&observer, &names, now));
    } else {
        print!("{}", observe::nodes_table(&observer, &names, now));
    }
    Ok(())
}

fn run_monitor(
    path: &Path,
    iface: &str,
    rate: u16,
    duration: Option<f64>,
    plain: bool,
    key: Option<&Path>,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let key = key.map(read_key).transpose()?;
    // In (0, 10^6] since parsing (args::seconds): the conversion cannot fail.
    let duration = duration.and_then(|seconds| Duration::try_from_secs_f64(seconds).ok());
    let mut bus = open_bus(iface)?;
    let stop = Arc::new(AtomicBool::new(false));
    let handler = stop.clone();
    // Without a handler, Ctrl-C would leave the nodes streaming.
    let _ = ctrlc::set_handler(move || handler.store(true, Ordering::SeqCst));
    let stop_requested = || stop.load(Ordering::SeqCst);
    monitor::run(
        bus.as_mut(),
        &network,
        rate,
        Duration::from_millis(200),
        duration,
        &stop_requested,
        &mut |screen| {
            if plain {
                println!("{screen}");
            } else {
                print!("\x1b[H\x1b[2J{screen}");
                let _ = io::stdout().flush();
            }
        },
        key.as_ref(),
    )
    .map_err(bus_failure(iface))?;
    Ok(())
}

fn run_check(path: &Path, json: bool) -> Result<(), Failure> {
    let network = match Network::load(path) {
        Ok(network) => network,
        Err(errors) => {
            if json {
                println!("{}", pabctl::json::invalid(path, &errors.0));
            }
            return Err(errors.into());
        }
    };
    let report = check::check(&network);
    // Warnings (competitive dynamics that cannot behave as written) fail nothing.
    let mut warnings = check::connections::warnings(&network);
    warnings.extend(check::dynamics::warnings(&network));
    warnings.sort_by_key(|warning| warning.0.position);
    for warning in &warnings {
        eprintln!("{}\n", warning.render(colour()));
    }
    if !warnings.is_empty() {
        eprintln!("{} warning{}", warnings.len(), plural(warnings.len()));
    }
    // Found once, for the JSON and for the verdict.
    let errors = report.errors(&network);
    if json {
        let shown: Vec<&Diagnostic> = warnings.iter().map(|w| &w.0).collect();
        println!(
            "{}",
            pabctl::json::check(path, &network, &report, &errors, &shown)
        );
        // The text for a person, on standard error.
        eprint!("{}", report.summary(&network));
    } else {
        print!("{}", report.summary(&network));
    }
    if report.is_consistent() {
        let say = if json { eprintln_line } else { println_line };
        say(format!(
            "{}: consistent ({} port{}, {} connection{})",
            path.display(),
            network.ports.len(),
            plural(network.ports.len()),
            network.connections.len(),
            plural(network.connections.len())
        ));
        Ok(())
    } else {
        Err(Failure::Inconsistent(errors))
    }
}

fn compiled(network: &Network, table_version: Option<u32>) -> Result<Vec<CompiledNode>, Failure> {
    let mut network = network.clone();
    if let Some(version) = table_version {
        network.version = version;
    }
    compile::compile(&network).map_err(Failure::Inconsistent)
}

fn run_compile(
    path: &Path,
    output: &Path,
    table_version: Option<u32>,
    json: bool,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let nodes = compiled(&network, table_version)?;
    fs::create_dir_all(output)
        .map_err(|error| Failure::Output(format!("cannot create {}: {error}", output.display())))?;
    let say = if json { eprintln_line } else { println_line };
    for node in &nodes {
        let file = output.join(format!("{}.pab", node.name));
        write_atomically(&file, &node.image)?;
        say(format!(
            "{}  {} bytes  (node id {}, table version {}, {} port{}, {} connection{}, {} decision node{})",
            file.display(),
            node.image.len(),
            node.id,
            table_version.unwrap_or(network.version),
            node.ports,
            plural(node.ports),
            node.connections,
            plural(node.connections),
            node.decision_nodes,
            plural(node.decision_nodes),
        ));
    }
    if json {
        let version = table_version.unwrap_or(network.version);
        println!("{}", pabctl::json::compiled(output, &nodes, version));
    }
    Ok(())
}

fn run_sim(
    path: &Path,
    until: Option<f64>,
    trace: Option<&Path>,
    plot_path: Option<&Path>,
    candump_path: Option<&Path>,
    dynamics_path: Option<&Path>,
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
    let schema_only = network.ports.is_empty() && network.client.is_some();
    let nodes = compiled(&network, None)?;
    let options = Options {
        until,
        samples: plot_path.is_some(),
        records: false,
        // The plot draws the dynamics groups' lanes.
        dynamics: dynamics_path.is_some() || plot_path.is_some(),
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
    let report = outcome.report(&network);
    if !report.is_empty() {
        say(report.trim_end().to_string());
    }
    if let Some(trace) = trace {
        let mut csv = Vec::new();
        outcome
            .write_csv(&network, &mut csv)
            .map_err(|error| Failure::Output(format!("cannot write the trace: {error}")))?;
        write_atomically(trace, &csv)?;
        say(format!(
            "trace: {} ({} rows)",
            trace.display(),
            outcome.rows.len()
        ));
    }
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
        let frames = sim::event_frames(&network)
            .map_err(|error| Failure::Input(Diagnostic::file(path, error.to_string()).into()))?;
        let mut log = String::new();
        let mut written = 0usize;
        for frame in outcome.bus_frames(&frames) {
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
        println!("{}", pabctl::json::sim(path, &network, &outcome));
    }
    Ok(schema_only)
}

/// The schema server's part of `pabctl sim`: runs when the file has a [client]; asked for
/// without one, an error.
fn run_schema_sim(
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

/// The schema server's board, client and plant of a file, for the live verbs.
fn schema_parts<'n>(
    path: &Path,
    network: &'n Network,
) -> Result<
    (
        &'n pab_lang::network::SchemaBoard,
        &'n pab_lang::network::Client,
    ),
    Failure,
> {
    let missing = |what: &str| {
        Failure::Input(Diagnostic::file(path, format!("the file has no {what}")).into())
    };
    let client = network.client.as_ref().ok_or_else(|| missing("[client]"))?;
    let board = network
        .schema_boards
        .iter()
        .find(|b| b.node == client.node)
        .ok_or_else(|| missing("[schema.NODE] for its client"))?;
    Ok((board, client))
}

fn run_plant(
    path: &Path,
    iface: &str,
    duration: Option<f64>,
    period_ms: Option<f64>,
    log_path: Option<&Path>,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let (board, _) = schema_parts(path, &network)?;
    let period_us = period_ms.map_or(board.config.period_us, |ms| {
        (ms * 1000.0).round().max(1.0) as u32
    });
    let mut bus = bus::open(iface).map_err(|e| Failure::Bus(e.to_string()))?;
    let stop = Arc::new(AtomicBool::new(false));
    let handler = stop.clone();
    // Ctrl-C or a SIGTERM ends the run as --duration does: the summary and the log are written.
    let _ = ctrlc::set_handler(move || handler.store(true, Ordering::SeqCst));
    let mut csv = String::from("t,x,y,z,attractor_x,attractor_y,attractor_z,force_n,inserted\n");
    let mut last_report = 0.0;
    let plant = pabctl::plant::run(
        bus.as_mut(),
        board,
        network.plant.clone().unwrap_or_default(),
        period_us,
        duration.map(std::time::Duration::from_secs_f64),
        &stop,
        &mut |s| {
            if log_path.is_some() {
                csv.push_str(&format!(
                    "{:.6},{},{},{},{},{},{},{:.3},{}\n",
                    s.t,
                    s.pose[0],
                    s.pose[1],
                    s.pose[2],
                    s.attractor[0],
                    s.attractor[1],
                    s.attractor[2],
                    s.force_n,
                    s.inserted
                ));
            }
            if s.t - last_report >= 5.0 {
                last_report = s.t;
                eprintln!(
                    "t = {:.0} s: z {:.3} mm, force {:.1} N, {} inserted, {} set-point frames",
                    s.t,
                    f64::from(s.pose[2]) / 1000.0,
                    s.force_n,
                    s.inserted,
                    s.setpoints
                );
            }
        },
    )
    .map_err(|e| Failure::Bus(e.to_string()))?;
    println!(
        "parts inserted: {} of {}",
        plant.inserted(),
        plant.parts().len()
    );
    if let Some(log_path) = log_path {
        write_atomically(log_path, csv.as_bytes())?;
        println!("log: {}", log_path.display());
    }
    Ok(())
}

fn run_client_program(
    path: &Path,
    iface: &str,
    timeout: f64,
    trace_path: Option<&Path>,
    key: Option<&Path>,
) -> Result<(), Failure> {
    let key = key.map(read_key).transpose()?;
    let network = Network::load(path)?;
    let (board, client) = schema_parts(path, &network)?;
    let node = network
        .nodes
        .get(board.node)
        .ok_or_else(|| Failure::Input(Diagnostic::file(path, "no such node").into()))?;
    let mut bus = bus::open(iface).map_err(|e| Failure::Bus(e.to_string()))?;
    let mut arm = match key {
        Some(key) => pabctl::client::Client::with_key(bus.as_mut(), node.id, key),
        None => pabctl::client::Client::new(bus.as_mut(), node.id),
    };
    let outcome = pabctl::client::run_program(
        &mut arm,
        &client.program,
        std::time::Duration::from_secs_f64(timeout),
        &mut |row| {
            println!(
                "{:>10.3} s  {:<28} {:<14} {}",
                row.t, row.schema, row.source, row.event
            );
        },
    );
    let outcome = match outcome {
        Ok(outcome) => outcome,
        Err(error) => return Err(Failure::Bus(format!("{}: {error}", node.name))),
    };
    if let Some(trace_path) = trace_path {
        let mut csv = String::from("t,node,schema,source,event\n");
        for row in &outcome.rows {
            csv.push_str(&format!(
                "{:.6},{},{},{},{}\n",
                row.t,
                node.name,
                csv_field(&row.schema),
                row.source,
                row.event
            ));
        }
        write_atomically(trace_path, csv.as_bytes())?;
        println!(
            "trace: {} ({} rows)",
            trace_path.display(),
            outcome.rows.len()
        );
    }
    match outcome.safety {
        Some(cause) => Err(Failure::Stopped(format!(
            "{}: stopped by a safety event ({}) after {} of {} calls",
            node.name,
            cause.description(),
            outcome.sent,
            client.program.len()
        ))),
        None => {
            println!("{}: {} calls run, no safety event", node.name, outcome.sent);
            Ok(())
        }
    }
}

fn run_limits(
    path: &Path,
    iface: Option<&str>,
    key: Option<&Path>,
    overrides: &pabctl::limits::Overrides,
) -> Result<(), Failure> {
    let key = key.map(read_key).transpose()?;
    let network = Network::load(path)?;
    let board = network.schema_boards.first().ok_or_else(|| {
        Failure::Input(Diagnostic::file(path, "the file has no [schema.NODE]").into())
    })?;
    let node = network
        .nodes
        .get(board.node)
        .ok_or_else(|| Failure::Input(Diagnostic::file(path, "no such node").into()))?;
    let limits = pabctl::limits::apply(board, overrides).map_err(|errors| {
        Failure::Input(Diagnostics(
            errors
                .into_iter()
                .map(|e| Diagnostic::file(path, format!("{}: {e}", node.name)))
                .collect(),
        ))
    })?;
    for line in pabctl::limits::describe(board, &limits) {
        println!("{}: {line}", node.name);
    }
    let Some(iface) = iface else {
        println!(
            "{}: within the table's limits (dry run: nothing sent)",
            node.name
        );
        return Ok(());
    };
    let mut bus = bus::open(iface).map_err(|e| Failure::Bus(e.to_string()))?;
    let mut client = match key {
        Some(key) => pabctl::client::Client::with_key(bus.as_mut(), node.id, key),
        None => pabctl::client::Client::new(bus.as_mut(), node.id),
    };
    match client.set_limits(&limits) {
        Ok(_) => {
            println!("{}: limits in force from its next tick", node.name);
            Ok(())
        }
        Err(error) => Err(Failure::Bus(format!("{}: {error}", node.name))),
    }
}

/// A CSV field, quoted when it holds a comma or a quote.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn run_replay(
    path: &Path,
    capture_path: &Path,
    trace: Option<&Path>,
    plot_path: Option<&Path>,
    records_path: Option<&Path>,
    job_path: Option<&Path>,
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
    let nodes = compiled(&network, None)?;
    let size = fs::metadata(capture_path).map_or(0, |m| m.len());
    let bar = progress_bar(size, "reading {bytes}/{total_bytes}");
    let capture = candump::read(capture_path, &mut |read| bar.set_position(read));
    bar.finish_and_clear();
    let mut capture = capture?;
    let feed = Feed::from_capture(&capture);
    // The feed holds what is replayed; the frames as read are no longer needed.
    let captured = capture.frames.len();
    capture.frames = Vec::new();
    let until_us = sim::settled_until(&network, &feed.frames);
    let options = Options {
        until: None,
        samples: plot_path.is_some(),
        records: records_path.is_some(),
        dynamics: false,
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
    let report = outcome.report(&network);
    if !report.is_empty() {
        say(report.trim_end().to_string());
    }
    if let Some(trace) = trace {
        let mut csv = Vec::new();
        outcome
            .write_csv(&network, &mut csv)
            .map_err(|error| Failure::Output(format!("cannot write the trace: {error}")))?;
        write_atomically(trace, &csv)?;
        say(format!(
            "trace: {} ({} rows)",
            trace.display(),
            outcome.rows.len()
        ));
    }
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
        println!("{found}");
    }
    Ok(())
}

fn run_dbc(path: &Path, output: &Path, claims_from: Option<&Path>) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let claims = match claims_from {
        None => Vec::new(),
        Some(capture_path) => {
            let size = fs::metadata(capture_path).map_or(0, |m| m.len());
            let bar = progress_bar(size, "reading {bytes}/{total_bytes}");
            let capture = candump::read(capture_path, &mut |read| bar.set_position(read));
            bar.finish_and_clear();
            dbc::claims_in(&network, &capture?, capture_path)?
        }
    };
    let database = dbc::build(&network, &claims)?;
    let text = database.render();
    if output.as_os_str() == "-" {
        let mut stdout = io::stdout().lock();
        return stdout
            .write_all(text.as_bytes())
            .and_then(|()| stdout.flush())
            .map_err(|error| Failure::Output(format!("cannot write to standard output: {error}")));
    }
    write_atomically(output, text.as_bytes())?;
    println!(
        "{}  {} messages  ({} node{} and the tool, {} topic{})",
        output.display(),
        database.messages.len(),
        network.nodes.len(),
        plural(network.nodes.len()),
        network.topics.len(),
        plural(network.topics.len()),
    );
    Ok(())
}

fn run_solve(path: &Path, desires: &str, json: bool) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let input = |message: String| Failure::Input(Diagnostic::file(path, message).into());
    let Some(hbba) = &network.hbba else {
        return Err(input(
            "no [hbba] section: `solve` needs resources and strategies (docs/network-file.md)"
                .into(),
        ));
    };
    let intensities = hbba
        .intensities(desires)
        .map_err(|message| input(format!("--desires: {message}")))?;
    let solved = hbba
        .solve(&intensities, pab_core::hbba::DEFAULT_BUDGET)
        .map_err(|error| input(error.to_string()))?;
    if json {
        println!("{}", pabctl::solve::json(hbba, &solved));
    } else {
        print!("{}", pabctl::solve::report(hbba, &intensities, &solved));
    }
    Ok(())
}
