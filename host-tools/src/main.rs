//! `pabctl`: check, compile and simulate port-arbitration networks.

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use pabctl::check;
use pabctl::compile::{self, CompiledNode};
use pabctl::dbc;
use pabctl::diagnostic::{Diagnostic, Diagnostics};
use pabctl::network::Network;
use pabctl::plot;
use pabctl::sim::{self, Options};

const ABOUT: &str = "Check, compile and simulate port-arbitration networks for CAN controller boards, \
     and describe their traffic as DBC";

const LONG_ABOUT: &str = "\
Check, compile and simulate port-arbitration networks for CAN controller boards.

Behaviours publish CAN frames (topics). A node (an arm, hand or head controller board) receives \
competing streams on one input (a port) and decides, frame by frame, which connection gets \
through. Each connection has a stimulation level S in [0, 1]: every frame adds st (σ), and S \
decays to 0 within tc (τ) seconds without frames. A connection is active from S reaching 1 until \
it has decayed to 0. Its rule says when an active connection may deliver, as a Boolean formula \
over the activity of the port's connections, e.g. \"C1 & !C2\" (C1 gets through unless C2 is \
active). A rule of false makes a virtual connection: it never delivers but inhibits others.

A network file (TOML) declares [nodes.NAME] (id), [topics.NAME] (can_id, extended, mask), \
[ports.\"NODE.PORT\"], [connections.NAME] (topic, port, st, tc, tr, rule) and, for simulation, \
[[events]] (topic with rate_hz/from/to or at = [...]) and [[phases]] (name, from, to). See the \
README for the full reference.

Exit status: 0 success; 1 the rules are inconsistent; 2 the input cannot be read or is invalid; \
3 an output cannot be written.";

const AFTER_HELP: &str = "\
Examples:
  pabctl check examples/figure-1.toml
  pabctl compile examples/take-and-return.toml -o out/tables
  pabctl sim examples/take-and-return.toml --plot out/take-and-return.png --trace out/trace.csv
  pabctl dbc examples/take-and-return.toml -o out/take-and-return.dbc";

#[derive(Parser)]
#[command(name = "pabctl", version, about = ABOUT, long_about = LONG_ABOUT, after_help = AFTER_HELP)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Prove that on every port at most one connection can deliver, whatever is active.
    #[command(long_about = "\
Prove, port by port and with binary decision diagrams, that in every activity mask at most one \
connection delivers (connection i delivers when it is active and its rule holds).

Reports every pair of connections that can deliver together, with the smallest set of active \
connections that shows it; every rule that can never deliver (unless it is written \"false\", a \
virtual connection); and, as information, how many masks let nothing through.

Exit status: 0 consistent, 1 inconsistent, 2 unreadable or invalid file.")]
    Check {
        /// The network file (TOML).
        network: PathBuf,
    },
    /// Compile one table image per node into a directory (DIR/<node>.pab).
    #[command(long_about = "\
Check the network, then write one table image per node to DIR/<node>.pab and print each image's \
size. An image holds the node's ports, their connections' CAN filters and parameters, and each \
port's precompiled decision (activity mask -> the connection that delivers); it carries the node \
id, the table version and a CRC-32. Nothing is written if the network is inconsistent.")]
    Compile {
        /// The network file (TOML).
        network: PathBuf,
        /// The directory to write the images to (created if missing).
        #[arg(short, long, value_name = "DIR")]
        output: PathBuf,
        /// The table version written into the images (default: `[network] version`, else 1).
        #[arg(long, value_name = "N")]
        table_version: Option<u32>,
    },
    /// Run every node of the network on a simulated bus, with the events of the file.
    #[command(long_about = "\
Run every node of the network on a simulated bus in virtual time: each node loads its compiled \
table with the same code the boards run, the frames come from the file's [[events]], and the run \
is deterministic. Prints, per port, a timeline of which connection gets through whenever that \
changes, and per connection how many frames it received and delivered.

--trace writes one CSV row per frame per connection it fed, after the update:
  t,port,connection,stimulation,active,delivered
--plot draws each connection's stimulation over time, green while it is the one that gets \
through at its port and orange otherwise (like Fig. 5 of the port-arbitration paper).")]
    Sim {
        /// The network file (TOML).
        network: PathBuf,
        /// Stop at this time in seconds (default: once the last frame's effect has decayed).
        #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
        until: Option<f64>,
        /// Write the trace as CSV.
        #[arg(long, value_name = "FILE.csv")]
        trace: Option<PathBuf>,
        /// Draw the stimulation plot as PNG.
        #[arg(long, value_name = "FILE.png")]
        plot: Option<PathBuf>,
    },
    /// Write a DBC file describing the network's traffic (pab protocol frames and topics).
    #[command(long_about = "\
Write a DBC file (for cantools, SavvyCAN, Wireshark, CANdb++) that decodes a capture of the \
network's bus:

- the pab protocol's own frames (docs/can-protocol.md), one message per service and node: \
PAB_<Service>_<node> for Heartbeat, TableStatus, Traffic, Errors, Fault, Diagnostic (node to all) \
and TransferStatus (node to tool), and PAB_DiagnosticControl_<node> and PAB_DiagnosticControl_all \
(tool to node, tool to all). Value tables name the node states, fault codes and transfer \
statuses; the diagnostic level is scaled to 0..1. Table transfers (ISO-TP, service 0x11) are not \
signals: their ids are in the node comments.
- each topic of the network, named after it, on its can_id (a masked topic: its base id only), \
with 8 one-byte signals data0..data7: the payload is the publisher's.

DBC node PABCTL is the workstation tool; node names are the network's (made C identifiers: other \
characters become _, a leading digit gets node_). Extended ids are written with bit 31 set, as DBC \
does. -o - writes to standard output.

Exit status: 0 written; 2 unreadable or invalid file (a topic inside the protocol's id space, \
extended with bits 25..24 = 0b10, is an error); 3 the output cannot be written.")]
    Dbc {
        /// The network file (TOML).
        network: PathBuf,
        /// The DBC file to write, or - for standard output.
        #[arg(short, long, value_name = "FILE.dbc")]
        output: PathBuf,
    },
}

/// How a command failed, and the exit status that says so.
enum Failure {
    Inconsistent(Vec<Diagnostic>),
    Input(Diagnostics),
    Output(String),
}

impl From<Diagnostics> for Failure {
    fn from(diagnostics: Diagnostics) -> Self {
        Failure::Input(diagnostics)
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check { network } => run_check(&network),
        Command::Compile {
            network,
            output,
            table_version,
        } => run_compile(&network, &output, table_version),
        Command::Sim {
            network,
            until,
            trace,
            plot,
        } => run_sim(&network, until, trace.as_deref(), plot.as_deref()),
        Command::Dbc { network, output } => run_dbc(&network, &output),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Inconsistent(errors)) => {
            for error in &errors {
                eprintln!("{error}");
            }
            eprintln!(
                "the rules are inconsistent: {} error{}",
                errors.len(),
                if errors.len() == 1 { "" } else { "s" }
            );
            ExitCode::from(1)
        }
        Err(Failure::Input(diagnostics)) => {
            eprintln!("{diagnostics}");
            ExitCode::from(2)
        }
        Err(Failure::Output(message)) => {
            eprintln!("error: {message}");
            ExitCode::from(3)
        }
    }
}

fn run_check(path: &Path) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let report = check::check(&network);
    print!("{}", report.summary(&network));
    if report.is_consistent() {
        println!(
            "{}: consistent ({} port{}, {} connection{})",
            path.display(),
            network.ports.len(),
            plural(network.ports.len()),
            network.connections.len(),
            plural(network.connections.len())
        );
        Ok(())
    } else {
        Err(Failure::Inconsistent(report.errors(&network)))
    }
}

fn compiled(network: &Network, table_version: Option<u32>) -> Result<Vec<CompiledNode>, Failure> {
    let mut network = network.clone();
    if let Some(version) = table_version {
        network.version = version;
    }
    compile::compile(&network).map_err(Failure::Inconsistent)
}

fn run_compile(path: &Path, output: &Path, table_version: Option<u32>) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let nodes = compiled(&network, table_version)?;
    fs::create_dir_all(output)
        .map_err(|error| Failure::Output(format!("cannot create {}: {error}", output.display())))?;
    for node in &nodes {
        let file = output.join(format!("{}.pab", node.name));
        write_atomically(&file, &node.image)?;
        println!(
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
        );
    }
    Ok(())
}

fn run_sim(
    path: &Path,
    until: Option<f64>,
    trace: Option<&Path>,
    plot_path: Option<&Path>,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let nodes = compiled(&network, None)?;
    let options = Options {
        until,
        samples: plot_path.is_some(),
    };
    let outcome = sim::simulate(&network, &nodes, &options)
        .map_err(|error| Failure::Input(Diagnostic::file(path, error.to_string()).into()))?;
    println!(
        "{}: {} frames on {} node{}, until t = {} s",
        path.display(),
        outcome.frames,
        network.nodes.len(),
        plural(network.nodes.len()),
        sim::seconds_text(outcome.until_us)
    );
    print!("{}", outcome.report(&network));
    if let Some(trace) = trace {
        let mut csv = Vec::new();
        outcome
            .write_csv(&network, &mut csv)
            .map_err(|error| Failure::Output(format!("cannot write the trace: {error}")))?;
        write_atomically(trace, &csv)?;
        println!("trace: {} ({} rows)", trace.display(), outcome.rows.len());
    }
    if let Some(plot_path) = plot_path {
        let title = path
            .file_name()
            .map_or("network".into(), |n| n.to_string_lossy().into_owned());
        plot::render_png(&outcome.plot_data(&network, &title), plot_path).map_err(|error| {
            Failure::Output(format!("cannot draw {}: {error:#}", plot_path.display()))
        })?;
        println!("plot: {}", plot_path.display());
    }
    Ok(())
}

fn run_dbc(path: &Path, output: &Path) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let database = dbc::build(&network)?;
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

/// Writes `bytes` to a temporary file beside `path`, then renames it: a failure never leaves a
/// half-written file where a good one was.
fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), Failure> {
    let fail =
        |error: io::Error| Failure::Output(format!("cannot write {}: {error}", path.display()));
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        fs::create_dir_all(parent).map_err(fail)?;
    }
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".part");
    let temporary = PathBuf::from(temporary);
    let mut file = BufWriter::new(fs::File::create(&temporary).map_err(fail)?);
    file.write_all(bytes).map_err(fail)?;
    file.into_inner()
        .map_err(|error| fail(error.into_error()))?
        .sync_all()
        .map_err(fail)?;
    fs::rename(&temporary, path).map_err(fail)
}

fn plural(count: usize) -> &'static str {
    if count == 1 { "" } else { "s" }
}
