//! `pabctl`: check, compile and simulate port-arbitration networks; push tables to the nodes on a
//! CAN bus, list them, monitor them.

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use pab_lang::candump;
use pab_lang::check;
use pab_lang::compile::{self, CompiledNode};
use pab_lang::dbc;
use pab_lang::diagnostic::{Diagnostic, Diagnostics};
use pab_lang::network::Network;
use pab_lang::replay::{self, Feed};
use pab_lang::sim::{self, Options};
use pabctl::args;
use pabctl::bus::{self, Bus};
use pabctl::plot;
use pabctl::{monitor, observe, push};

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

A network file (TOML) declares [nodes.NAME] (id), [topics.NAME] (can_id, extended, mask, rate_hz), \
[ports.\"NODE.PORT\"], [connections.NAME] (topic, port, st, tc, tr, rule) and, for simulation, \
[[events]] (topic with rate_hz/from/to or at = [...]) and [[phases]] (name, from, to), and for \
HBBA's intention solver [hbba] (resources, bitrate), [hbba.strategies.NAME] (class, utility, \
costs, filters, requires) and, for simulation, [[desires]] (class, intensity, from, to). See \
docs/network-file.md for the full reference.

Exit status: 0 success; 1 the rules are inconsistent; 2 the input cannot be read or is invalid; \
3 an output cannot be written; 4 the bus cannot be used or a node refused or did not answer.";

const AFTER_HELP: &str = "\
Examples:
  pabctl check examples/figure-1.toml
  pabctl compile examples/take-and-return.toml -o out/tables
  pabctl sim examples/take-and-return.toml --plot out/take-and-return.png --trace out/trace.csv
  pabctl replay examples/take-and-return.toml yesterday.log --trace out/replay.csv
  pabctl push examples/take-and-return.toml --iface vcan0
  pabctl nodes --iface vcan0
  pabctl monitor examples/take-and-return.toml --iface vcan0
  pabctl dbc examples/take-and-return.toml -o out/take-and-return.dbc
  pabctl solve examples/tour-guide.toml --desires \"face=2,nav=2,voice=3\"
  pabctl schema > docs/network-file.schema.json";

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
        /// Also print the verdict as one JSON object on standard output (docs/pabctl.md, "JSON
        /// output"); the text goes to standard error.
        #[arg(long)]
        json: bool,
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
        /// The table version written into the images, 1 to 4294967295 (default: `[network]
        /// version`, else 1; 0 is reserved: heartbeats report it for "no table").
        #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = args::table_version)]
        table_version: Option<u32>,
        /// Also print the images written as a JSON array on standard output (docs/pabctl.md,
        /// "JSON output"); the text goes to standard error.
        #[arg(long)]
        json: bool,
    },
    /// Run every node of the network on a simulated bus, with the events of the file.
    #[command(long_about = "\
Run every node of the network on a simulated bus in virtual time: each node loads its compiled \
table with the same code the boards run, the frames come from the file's [[events]] (with their \
data bytes), a node of the file's [[faults]] stops at its time (it receives nothing from then on \
and its ports deliver nothing), and the run is deterministic. A node that runs a [dynamics.*] \
group steps it at its `step` and puts its Gates on the bus; every node whose rules name a gate \
(`door.search`) reads them. Prints, per port, a timeline of which connection gets through \
whenever that changes, and per connection how many frames it received and delivered.

--trace writes one CSV row per frame per connection it fed, after the update:
  t,port,connection,stimulation,active,delivered
--plot draws each connection's stimulation over time, green while it is the one that gets \
through at its port and orange otherwise (like Fig. 5 of the port-arbitration paper); a \
suppress, inhibit, write-inhibit or override connection as its windows (a band from each \
activation to its expiry, named after its kind), a gate a rule names (`door.search`) as a band \
while it is open; and under the ports a lane per [dynamics.*] behaviour: n, ρ and m, on green \
where its gate is open. FILE.png draws a PNG, FILE.svg an SVG (its texts as text).
With [hbba], the intention node's logic runs on the file's [[desires]] (the filter commands \
answered at once by the simulated nodes): the report lists each change of the selected \
strategies and the filter commands sent, reductions before increases, and --plot adds a lane \
per strategy (filled while selected) and per filtered connection (its commanded pass rate 1/φ, \
0 closed); the simulated nodes apply the commands, so the arbitration sees the filters.
With a schema server ([schema.NODE], [plant], [client]), its board runs the client's program \
in virtual time against the simulated robot, at the board's period: the report names the \
schemas installed, the parts inserted and any safety event; --schema-trace writes one CSV row \
per installed schema (t,node,schema,source,event; the event `safety:<name>` for the built-in \
ones) and --schema-plot draws the height, lateral position, contact force and installed schema \
over time, from --from to --until (--plot draws it too when the file has no port).
--candump writes the simulated bus as a candump -L log (each frame with its event's data, by \
default its topic's `length` of zeros; the intention's filter commands, the nodes' BLE claims and \
Gates too; times from 0 s on interface vcan0): `pabctl replay` reads it back, `canplayer -I` puts it on a real bus.")]
    Sim {
        /// The network file (TOML).
        network: PathBuf,
        /// Stop at this time in seconds, up to 1000000 (default: once the last frame's effect has
        /// decayed).
        #[arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = args::seconds)]
        until: Option<f64>,
        /// Write the trace as CSV.
        #[arg(long, value_name = "FILE.csv")]
        trace: Option<PathBuf>,
        /// Draw the stimulation plot: PNG or SVG, by the file name's extension (.png, .svg).
        #[arg(long, value_name = "FILE.png|FILE.svg")]
        plot: Option<PathBuf>,
        /// Write the simulated bus's frames as a candump -L log.
        #[arg(long, value_name = "FILE.log")]
        candump: Option<PathBuf>,
        /// Write the [dynamics.*] groups' states as CSV
        /// (t,group,behaviour,context,n,rho,m,gate; one row per behaviour per step).
        #[arg(long, value_name = "FILE.csv")]
        dynamics_trace: Option<PathBuf>,
        /// Write the schema server's installed schemas as CSV
        /// (t,node,schema,source,event; one row per installed schema).
        #[arg(long, value_name = "FILE.csv")]
        schema_trace: Option<PathBuf>,
        /// Draw the schema server's run: height, lateral position, contact force and the
        /// installed schema over time (from --from to --until); PNG or SVG, by the file name's
        /// extension (.png, .svg).
        #[arg(long, value_name = "FILE.png|FILE.svg")]
        schema_plot: Option<PathBuf>,
        /// Write the schema server's client program as JSON: per call its name and its schema
        /// (serde's form, the one `pab_client.Schema.from_json` reads), so that another client
        /// sends exactly the file's schemas.
        #[arg(long, value_name = "FILE.json")]
        schema_program: Option<PathBuf>,
        /// Start the schema plot's time axis here, seconds (default 0), to show one insertion.
        #[arg(long, value_name = "SECONDS", value_parser = args::seconds)]
        from: Option<f64>,
        /// Also print the run's summary as one JSON object on standard output (docs/pabctl.md,
        /// "JSON output"); the text goes to standard error.
        #[arg(long)]
        json: bool,
    },
    /// Choose the HBBA strategies for a set of desires: which run, the objective, each resource's
    /// use.
    #[command(long_about = "\
Run HBBA's intention solver on the network's [hbba] section for the desires of --desires, and \
print the strategies it selects, the objective and each resource's use.

Motivations issue desires: a class (\"face\", \"voice\") and an intensity. A strategy \
([hbba.strategies.NAME]) fulfils one class with a utility, costs some of each resource (cpu, \
...), sets filters on connections (φ: 0 closes, 1 passes every frame, N one frame in N) and may \
require other classes (requires = { nav = 1 }: the strategy chosen for nav must have a utility of \
at least 1). The solver chooses at most one strategy per class and maximises the sum of \
intensity × utility over the classes with a desire, so that:
  - every resource's capacity covers the chosen strategies' costs;
  - two chosen strategies that set the same connection set the same φ;
  - every requirement of a chosen strategy is met;
  - a class without a desire gets a strategy only when a chosen strategy requires it \
(directly or through others); it adds nothing to the objective.
The bus is a resource like the others, in percent of [hbba] bitrate: a strategy's bus cost is \
computed from the rates its filters let through (each filtered connection's topic's rate_hz / φ \
frames a second of the longest stuffed frame, 135 bits with an 11-bit id, 160 with a 29-bit id), \
rounded up.

Ties between equally good selections are broken the same way every time: classes are compared \
in order of first appearance among the strategies; at the first class where two selections \
differ, the one that chose a strategy wins over none, then the strategy that comes first in the \
file. The search is exact (branch and bound) and visits at most 100000 nodes; beyond that it \
gives no answer rather than a possibly wrong one (exit status 2).

--desires takes CLASS=INTENSITY pairs separated by commas, intensities 1 to 65535 (a class left \
out has no desire; \"\" is no desire at all). --json prints one object instead:
  {\"strategies\":[\"face_throttled\",\"nav_follow\"],\"objective\":17,\"use\":{\"cpu\":95,\"bus\":12}}
with the strategies' names sorted and the resources in file order.

Exit status: 0 solved; 2 the network cannot be read or is invalid, has no [hbba] section, the \
desires are invalid, or the search exceeded its work bound.")]
    #[command(after_help = "\
Examples:
  pabctl solve examples/tour-guide.toml --desires \"face=2,qr=1,nav=2\"
  pabctl solve examples/tour-guide.toml --desires \"face=2,qr=1,nav=2,voice=3\"     # a loud noise
  pabctl solve examples/tour-guide.toml --desires \"voice=3\" --json")]
    Solve {
        /// The network file (TOML), with an [hbba] section.
        network: PathBuf,
        /// The desires: CLASS=INTENSITY,... (intensity 1 to 65535; \"\" for none).
        #[arg(long, value_name = "CLASS=INTENSITY,...", allow_hyphen_values = true)]
        desires: String,
        /// Print one JSON object: {"strategies": [names, sorted], "objective": N, "use":
        /// {resource: N}}.
        #[arg(long)]
        json: bool,
    },
    /// Run a recorded candump capture through the network's tables: what would they have let
    /// through?
    #[command(long_about = "\
Run a recorded CAN capture through the network's tables, in virtual time: every node of the \
network arbitrates the capture's frames with the same code the boards run, at the capture's own \
timestamps (time 0 = the capture's earliest frame). What would this table have let through on \
yesterday's traffic? Prints, per port, who gets through whenever that changes, and per \
connection how many frames it received and delivered, like `pabctl sim`.

The capture is a candump log: `candump -L can0 > yesterday.log`, `candump -l` (the same lines in \
a file), or python-can's .log writer. One frame per line:
  (1700000000.123456) can0 123#DEADBEEF
  (1700000000.125000) can0 1ABCDEF0#0102 R
  (1700000000.130000) can0 123#R
Standard ids have 3 hex digits, extended ids 8. Error frames are counted and skipped; CAN FD \
frames (ID##...) are refused. Every malformed line is reported as FILE:LINE:COLUMN: error: \
cause, all in one run, and nothing is replayed then (exit status 2). Frames are replayed in the \
order of their timestamps (a Linux recorder may write them a few milliseconds out of order; \
the summary says how many were).

The project's own frames (heartbeats, diagnostic stream, table transfers: 29-bit ids of the pab \
protocol) are counted and not fed: the replay runs the tables of NET, and a push recorded in the \
capture must not replace them halfway. Frames that no topic of NET matches are listed by id.

--trace writes exactly the CSV of `pabctl sim --trace`:
  t,port,connection,stimulation,active,delivered
--plot draws the stimulation plot of `pabctl sim --plot` (without phases: those belong to the \
simulation's scenario).
--records writes every verdict exactly, one line per frame and port it fed (masks in hex, levels \
as raw Q1.31 integers): the record that the cross-runner test compares between the simulator, \
the Linux node and the board firmware (see docs/pabctl.md, \"Replay records\").
--board-job writes the tables and the frames replayed for pab-an386-replay, the same replay on \
the emulated Cortex-M4 (QEMU mps2-an386), which writes the same records:
  pabctl replay NET.toml CAPTURE.log --records sim.txt --board-job job.bin
  cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \\
      --bin pab-an386-replay -- -append \"job.bin board.txt\"
  cmp sim.txt board.txt

Exit status: 0 replayed; 1 the rules are inconsistent; 2 the network or the capture cannot be \
read or is invalid; 3 an output cannot be written.")]
    #[command(after_help = "\
Examples:
  candump -L can0 > yesterday.log                  # record a day of traffic
  pabctl replay arm-v2.toml yesterday.log          # what would version 2 have let through?
  pabctl replay arm-v2.toml yesterday.log --trace v2.csv --plot v2.png
  pabctl sim examples/figure-1.toml --candump fig1.log     # a simulated bus, as a capture
  pabctl replay examples/figure-1.toml fig1.log")]
    Replay {
        /// The network file (TOML).
        network: PathBuf,
        /// The capture: a candump -L log.
        capture: PathBuf,
        /// Write the trace as CSV (the format of `pabctl sim --trace`).
        #[arg(long, value_name = "FILE.csv")]
        trace: Option<PathBuf>,
        /// Draw the stimulation plot: PNG or SVG, by the file name's extension (.png, .svg).
        #[arg(long, value_name = "FILE.png|FILE.svg")]
        plot: Option<PathBuf>,
        /// Write every verdict in the replay record format.
        #[arg(long, value_name = "FILE")]
        records: Option<PathBuf>,
        /// Write the tables and frames for the emulated board's replay binary
        /// (pab-an386-replay), which writes the same records.
        #[arg(long, value_name = "FILE")]
        board_job: Option<PathBuf>,
        /// Also print the replay's summary as one JSON object on standard output
        /// (docs/pabctl.md, "JSON output"); the text goes to standard error.
        #[arg(long)]
        json: bool,
    },
    /// Compile the network and push each node's table over CAN; wait until each node runs it.
    #[command(long_about = "\
Check and compile the network, then send each node its table image over ISO-TP (ISO 15765-2) on \
--iface, one node after the other, with a progress bar. A node keeps running its old table until \
the new one has arrived whole and passed its checks (node id, version, CRC, loader); then it \
swaps atomically, stores the table and answers. The push of a node is done when its heartbeat \
shows the new version and CRC.

A node that refuses (older version, wrong node, corrupted image, too large...) or does not answer \
is reported with the reason, and the command fails (exit status 4) after trying every node.")]
    Push {
        /// The network file (TOML).
        network: PathBuf,
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// Push only to this node (by its name in the network file).
        #[arg(long, value_name = "NAME")]
        node: Option<String>,
        /// The table version, 1 to 4294967295 (default: `[network] version`, else 1; 0 is
        /// reserved). Nodes refuse versions older than the one they run.
        #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = args::table_version)]
        table_version: Option<u32>,
        /// The nodes' key file (`pabctl keygen`): authenticated push (challenge, TransferOpen,
        /// image MAC); a node counts as done only with a receipt that verifies. Required by nodes
        /// with a key, refused by nodes without one.
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
        /// With --key: replace whatever version the node runs, even a newer one (the keyed
        /// version reset; version 0 stays refused).
        #[arg(long, requires = "key")]
        replace: bool,
    },
    /// Run the simulated robot of a schema server's board on a live bus.
    #[command(long_about = "\
Run the file's [plant] (the simulator's robot: an impedance-controlled end-effector over a plate \
with holes, parts, a wrist force sensor) on --iface in real time, in front of the board of its \
[client]: every period it reads the board's set-point frames (the drive's frames of \
[schema.NODE] `drive`: attractor, rotation, impedance, gripper), integrates the model for one \
period and publishes the measured pose and wrench, and its range finder on the sensor that \
[plant] `range_finder` names, if any (the frame `pabctl sim` feeds the board). Until \
--duration, Ctrl-C or SIGTERM; then prints the parts inserted. --log writes one CSV row per \
step: t,x,y,z,attractor_x,attractor_y,attractor_z,force_n,inserted (µm, N).")]
    Plant {
        /// The network file (TOML).
        network: PathBuf,
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// Stop after this many seconds (default: until interrupted).
        #[arg(long, value_name = "SECONDS", value_parser = args::seconds)]
        duration: Option<f64>,
        /// The step, ms (default: the board's period).
        #[arg(long, value_name = "MS", value_parser = args::seconds)]
        period_ms: Option<f64>,
        /// Write every step as CSV.
        #[arg(long, value_name = "FILE.csv")]
        log: Option<PathBuf>,
    },
    /// Send the file's client program to a live schema server and follow it.
    #[command(long_about = "\
Send the calls of the file's [client] program to its board on --iface, over ISO-TP, each as the \
queue takes it (8 deep), and follow the board's SchemaTransition frames until the last call has \
ended or a safety event stops the board. Prints one line per installed schema; --trace writes \
them as `pabctl sim --schema-trace` does (t,node,schema,source,event), so a live run and a \
simulated one compare line by line. Exits 1 when a safety event stopped the board, 4 when the \
board refused a call or did not answer. The timed [[client.commands]] are the simulator's: \
not sent here.")]
    Run {
        /// The network file (TOML).
        network: PathBuf,
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// Give up after this many seconds.
        #[arg(long, value_name = "SECONDS", default_value = "600", value_parser = args::seconds)]
        timeout: f64,
        /// Write the installed schemas as CSV.
        #[arg(long, value_name = "FILE.csv")]
        trace: Option<PathBuf>,
        /// The board's key file (`pabctl keygen`): every schema goes as the key holder's
        /// (challenge, TransferOpen, the message and its MAC) and its answer counts only with a
        /// Receipt that verifies. Needed by a board with a key, refused by one without.
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
    },
    /// Tighten a live schema server's safety limits, or set them back to its table's.
    #[command(long_about = "\
Set the safety bounds a schema server's board runs with, at run time: the table's (from the \
network file's [schema.NODE]) with the options given applied, each tighter than the table's or \
back up to it, never looser. The board takes them from its next tick (a robot outside a \
tightened workspace or joint range stops at once; a schema that brings it back is not stopped) \
and keeps them until it restarts or gets a new table; `pabctl limits NET --iface can0` with no \
option sets the table's back. Units are the network file's: N, N·m, mm, mm/s, rad/s, and a \
joint's sensor's unit (--joint elbow=-45:90:30 is elbow's range -45..90 and 30 a second). \
Every bound that would be looser is named before anything is sent. On a board with a key, \
--key is needed (the limits are authenticated like a schema). Exits 2 for limits that cannot \
be set, 4 when the board refused them or did not answer.\n\n\
Examples:\n  pabctl limits arm.toml --iface can0 --force-limit-n 10 --speed-limit-mm-s 100\n  \
pabctl limits arm.toml --iface can0 --workspace-max-mm 100,100,50 --key arm.key\n  \
pabctl limits arm.toml --dry-run --joint elbow=-45:90")]
    Limits {
        /// The network file (TOML): its [schema.NODE] is the board's table.
        network: PathBuf,
        /// The CAN interface (vcan0, can0...); not needed with --dry-run.
        #[arg(long, required_unless_present = "dry_run")]
        iface: Option<String>,
        /// The board's key file (`pabctl keygen`), for a board with a key.
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
        #[command(flatten)]
        overrides: pabctl::limits::Overrides,
        /// Print the limits and check them; send nothing.
        #[arg(long)]
        dry_run: bool,
    },
    /// Create a node key file (32 hexadecimal characters, mode 0600).
    #[command(long_about = "\
Write a new random 128-bit key (from /dev/urandom) to FILE as 32 hexadecimal characters and a \
newline, readable by its owner only (mode 0600). Refuses to overwrite an existing file. Give the \
file to the node (`pab-node --key FILE`, or a board's key page: `pabctl keypage`) and to the \
configuring verbs (`pabctl push --key FILE`, `pabctl monitor --key FILE`). Whoever can read the \
file can configure the node.")]
    Keygen {
        /// The key file to create.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
    },
    /// Write a starter network file: the tutorial's, or one of the examples.
    #[command(long_about = "\
Write a network file to start from, one that `pabctl check` accepts: the tutorial's (a grasp and \
a release competing for a gripper, commented key by key), or with --example NAME one of the \
project's examples, built into pabctl (an unknown NAME lists them). Refuses to overwrite an \
existing file. Then: `pabctl check FILE`, `pabctl sim FILE --plot FILE.png`.")]
    Init {
        /// The file to create.
        #[arg(default_value = "network.toml")]
        file: PathBuf,
        /// Start from this example instead of the tutorial's network (assembly, tour-guide,
        /// take-and-return, ...).
        #[arg(long, value_name = "NAME")]
        example: Option<String>,
    },
    /// Write a board's key page image from a key file.
    #[command(long_about = "\
Write the 32-byte key page record of KEYFILE (magic PABK, format 1, the key, CRC-32) to \
FILE.bin, to be written at the board's key page address (docs/keys.md: probe-rs download \
--binary-format bin --base-address ...).")]
    Keypage {
        /// The key file (`pabctl keygen`).
        key: PathBuf,
        /// The page image to write.
        #[arg(short, long, value_name = "FILE.bin")]
        output: PathBuf,
    },
    /// List the nodes on the bus from their heartbeats.
    #[command(long_about = "\
Listen to --iface for --listen seconds and print one line per node heard: state (no table, \
operational, fault), uptime, table version and CRC, whether the table is stored, the frame \
counters (received, delivered, discarded, errors) and the last fault. With a network file, \
nodes are named.")]
    Nodes {
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// Name the nodes from this network file.
        network: Option<PathBuf>,
        /// How long to listen, in seconds, up to 3600 (heartbeats come every second).
        #[arg(
            long,
            default_value = "2.5",
            value_name = "SECONDS",
            allow_hyphen_values = true,
            value_parser = args::listen_seconds
        )]
        listen: f64,
        /// Print the nodes as a JSON array on standard output instead of the table
        /// (docs/pabctl.md, "JSON output").
        #[arg(long)]
        json: bool,
    },
    /// Live view of every port: connections' stimulation, activity and who delivers.
    #[command(long_about = "\
Switch on the diagnostic stream of every node of the network file and draw, several times per \
second, one bar per connection: its stimulation S, ACTIVE when it is active, resting during its \
rest time, and \"◀ delivering\" for the connection the port lets through. A node that runs a \
competitive-dynamics group also shows its gates (OPEN or -) from its Gates frames, or that it fell \
silent (its readers then take every gate as closed). Ctrl-C ends it and switches the stream off.")]
    Monitor {
        /// The network file (TOML): names of nodes, ports and connections.
        network: PathBuf,
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// Diagnostic rounds per second asked of each node (1..=200).
        #[arg(
            long,
            default_value = "10",
            value_name = "HZ",
            allow_hyphen_values = true,
            value_parser = args::rate_hz
        )]
        rate: u16,
        /// Stop after this many seconds, up to 1000000 (default: until Ctrl-C).
        #[arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = args::seconds)]
        duration: Option<f64>,
        /// Print each screen one after the other instead of redrawing in place.
        #[arg(long)]
        plain: bool,
        /// The nodes' key file: switch the stream with authenticated commands (nodes with a key
        /// take no other).
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
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
its DLC the topic's `length` (default 8): the fields the network reads from its frames (value \
ports, BLE eligibilities, dynamics contexts) as signals with their size, sign and byte order, the \
other bytes as one-byte signals dataN.
- each BLE group member's claim. A claim's identifier carries its eligibility, and tools such as \
cantools match whole identifiers: the database lists each member's claim at eligibility 0, and \
with --claims-from CAPTURE.log every claim of that capture too (each must decode as a claim of a \
member; the others are errors at their line).

With the frames of the topics' lengths, `python -m cantools decode NET.dbc < CAPTURE.log` decodes \
every frame of the capture strictly (without --no-strict):

    pabctl sim NET.toml --candump bus.log
    pabctl dbc NET.toml --claims-from bus.log -o NET.dbc
    python -m cantools decode NET.dbc < bus.log

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
        /// List the BLE claims of this candump -L capture too (each eligibility a claim
        /// identifier of its own)
        #[arg(long, value_name = "CAPTURE.log")]
        claims_from: Option<PathBuf>,
    },
    /// Print the network file's JSON Schema, for editors (docs/network-file.schema.json).
    #[command(long_about = "\
Print the network file's JSON Schema (draft 7) on standard output: every table and key the \
parser takes, with its type and a description, unknown keys refused. Editors that complete and \
check TOML with a JSON Schema (taplo, VS Code's Even Better TOML) use it; the repository's copy \
is docs/network-file.schema.json, which this regenerates:

  pabctl schema > docs/network-file.schema.json

The schema is derived from the parser's own tables, so it takes exactly what `pabctl check` \
takes in shape; names, ranges and rules are still for `pabctl check` to judge.")]
    Schema,
}

/// How a command failed, and the exit status that says so.
enum Failure {
    Inconsistent(Vec<Diagnostic>),
    Input(Diagnostics),
    Output(String),
    Bus(String),
    /// A live schema server stopped on a safety event (exit status 1, like a verdict).
    Stopped(String),
}

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

impl From<Diagnostics> for Failure {
    fn from(diagnostics: Diagnostics) -> Self {
        Failure::Input(diagnostics)
    }
}

/// Whether diagnostics get colour: on a terminal only, and never with `NO_COLOR` set
/// (no-color.org), so that logs and pipes get plain text.
fn colour() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none()
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
        Err(Failure::Inconsistent(errors)) => {
            for error in &errors {
                eprintln!("{}\n", error.render(colour()));
            }
            eprintln!(
                "the rules are inconsistent: {} error{}",
                errors.len(),
                if errors.len() == 1 { "" } else { "s" }
            );
            ExitCode::from(1)
        }
        Err(Failure::Input(diagnostics)) => {
            eprintln!("{}", diagnostics.render(colour()));
            if diagnostics.0.len() > 1 {
                eprintln!("\n{} errors", diagnostics.0.len());
            }
            ExitCode::from(2)
        }
        Err(Failure::Output(message)) => {
            eprintln!("error: {message}");
            ExitCode::from(3)
        }
        Err(Failure::Bus(message)) => {
            eprintln!("error: {message}");
            ExitCode::from(4)
        }
        Err(Failure::Stopped(message)) => {
            eprintln!("{message}");
            ExitCode::from(1)
        }
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

fn println_line(line: String) {
    println!("{line}");
}

fn eprintln_line(line: String) {
    eprintln!("{line}");
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

/// Refuses, before a run rather than after it, the output files that could not be written as
/// asked: a plot that is neither a `.png` nor a `.svg`, the formats drawn (exit 2, with every such mistake),
/// or a file in a directory that does not exist (exit 3, as any output that cannot be written).
/// Each `(flag, path, is_plot)`.
fn refuse_unwritable(outputs: &[(&str, Option<&Path>, bool)]) -> Result<(), Failure> {
    let mut invalid = Vec::new();
    let mut unwritable = Vec::new();
    for &(flag, output, is_plot) in outputs {
        let Some(output) = output else { continue };
        if is_plot && plot::Format::of(output).is_none() {
            invalid.push(Diagnostic::file(
                output,
                format!(
                    "{flag}: plots are drawn as PNG or SVG: give a file name ending in {}",
                    plot::EXTENSIONS
                ),
            ));
        }
        let parent = output.parent().filter(|p| !p.as_os_str().is_empty());
        if let Some(parent) = parent.filter(|p| !p.is_dir()) {
            unwritable.push(format!(
                "cannot write {} ({flag}): the directory {} does not exist (create it first)",
                output.display(),
                parent.display()
            ));
        }
    }
    if !invalid.is_empty() {
        return Err(Failure::Input(Diagnostics(invalid)));
    }
    if !unwritable.is_empty() {
        return Err(Failure::Output(unwritable.join("\n")));
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

/// A progress bar on standard error, drawn only when it is a terminal (indicatif's rule), for
/// long captures.
fn progress_bar(total: u64, template: &str) -> ProgressBar {
    ProgressBar::new(total).with_style(
        ProgressStyle::with_template(&format!("{{bar:30}} {template}"))
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    )
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
