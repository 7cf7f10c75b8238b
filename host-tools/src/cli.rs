//! The command line: every command, its options and their help texts (clap's derive), as
//! `pabctl --help` and `pabctl COMMAND --help` print them.

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use pabctl::args;

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

A network file (TOML) declares [bus] (bitrate), [nodes.NAME] (id), [topics.NAME] (can_id, \
extended, mask, rate_hz or period, length, jitter, deadline), \
[ports.\"NODE.PORT\"], [connections.NAME] (topic, port, st, tc, tr, rule) and, for simulation, \
[[events]] (topic with rate_hz/from/to or at = [...]) and [[phases]] (name, from, to), and for \
HBBA's intention solver [hbba] (resources, bitrate), [hbba.strategies.NAME] (class, utility, \
costs, filters, requires) and, for simulation, [[desires]] (class, intensity, from, to). See \
docs/network-file.md for the full reference.

Exit status: 0 success; 1 the rules are inconsistent (or, for check, a frame can miss its \
deadline on the bus; for sim --timed-bus, a measured latency exceeds its bound); 2 the input \
cannot be read or is invalid; \
3 an output cannot be written; 4 the bus cannot be used or a node refused or did not answer.";

const AFTER_HELP: &str = "\
Examples:
  pabctl check examples/figure-1.toml
  pabctl compile examples/take-and-return.toml -o out/tables
  pabctl sim examples/take-and-return.toml --plot out/take-and-return.png --trace out/trace.csv
  pabctl replay examples/take-and-return.toml yesterday.log --trace out/replay.csv
  pabctl push examples/take-and-return.toml --iface vcan0
  pabctl flash --iface vcan0 --node 3 fw-1.2.0.signed
  pabctl nodes --iface vcan0
  pabctl assign --iface vcan0 --uid 3f2a9c0d11e04b77 --node-id 4
  pabctl monitor examples/take-and-return.toml --iface vcan0
  pabctl dbc examples/take-and-return.toml -o out/take-and-return.dbc
  pabctl solve examples/tour-guide.toml --desires \"face=2,nav=2,voice=3\"
  pabctl schema > docs/network-file.schema.json";

#[derive(Parser)]
#[command(name = "pabctl", version, about = ABOUT, long_about = LONG_ABOUT, after_help = AFTER_HELP)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Prove that on every port at most one connection can deliver, whatever is active.
    #[command(long_about = "\
Prove, port by port and with binary decision diagrams, that in every activity mask at most one \
connection delivers (connection i delivers when it is active and its rule holds).

Reports every pair of connections that can deliver together, with the smallest set of active \
connections that shows it; every rule that can never deliver (unless it is written \"false\", a \
virtual connection); and, as information, how many masks let nothing through.

With a bus bit rate ([bus] bitrate), also the worst-case response time of every frame stream on \
the bus (Davis, Burns, Bril and Lukkien 2007; worst-case bit stuffing): the topics with a period \
(or rate_hz), the gateways' re-published frames and the protocol's own periodic frames, one \
table transfer at a time in the background. Prints the table (stream, id, bytes, period, \
deadline, C, R, slack), the bus load and the lowest standard bit rate (CiA 301's: 10k, 20k, \
50k, 125k, 250k, 500k, 800k, 1M) at which every deadline holds; fails when a deadline can be missed or the load exceeds \
100 %, at the line of the stream (docs/response-times.md). On a CAN FD bus ([bus] \
data_bitrate), CAN FD frames (topics with fd = true, the table transfers) send their data \
phase at the data rate; the table says each stream's frame format, and the lowest bit rate is \
the lowest nominal one with the data phase as analysed.

Exit status: 0 consistent (and every deadline holds), 1 inconsistent or a deadline can be \
missed, 2 unreadable or invalid file.")]
    Check {
        /// The network file (TOML).
        network: PathBuf,
        /// Also print the verdict as one JSON object on standard output (docs/pabctl.md, "JSON
        /// output"); the text goes to standard error.
        #[arg(long)]
        json: bool,
        /// Analyse the bus at this bit rate (bit/s, 1 to 1000000) instead of the file's `[bus]
        /// bitrate`, also for a file without one: e.g. `--bitrate 125000` shows what a slower
        /// bus would miss, without editing the file.
        #[arg(long, value_name = "BIT/S", value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
        bitrate: Option<u32>,
        /// Analyse a CAN FD bus's data phase at this bit rate (bit/s, 1 to 8000000, at least
        /// the nominal rate) instead of the file's `[bus] data_bitrate`. The file must say the bus
        /// is CAN FD: a classic network is refused (exit status 2), since `data_bitrate` changes
        /// what the file may hold (CAN FD topics, classic-only nodes).
        #[arg(long, value_name = "BIT/S", value_parser = clap::value_parser!(u32).range(1..=8_000_000))]
        data_bitrate: Option<u32>,
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
Run every node of the network on a simulated bus in virtual time: each node is the node \
application the boards run, booted from its compiled table, the frames come from the file's \
[[events]] (with their data bytes), what the nodes send (heartbeats, BLE claims, Gates, \
re-published frames) goes on the bus too, a node of the file's [[faults]] stops at its time (it \
receives and sends nothing from then on and its ports deliver nothing), and the run is \
deterministic. A node that runs a [dynamics.*] \
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
With [hbba], the intention node itself runs on the file's [[desires]] (its filter commands \
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
default its topic's `length` of zeros; the intention's filter commands and everything the nodes \
sent too; times from 0 s on interface vcan0): `pabctl replay` reads it back, `canplayer -I` puts it on a real bus.
--timed-bus carries the frames on a bus that takes time, at the file's [bus] bitrate (and \
data_bitrate for CAN FD frames), instead of the ideal bus (no transmission time): each frame \
takes the bus for its actual bits (their stuff bits counted from the frame's own bits) and the \
3-bit intermission, one frame at a time; when the bus is free the waiting frame with the lowest \
identifier goes next; the other nodes receive a frame when its EOF ends (at that microsecond, \
rounded up) and answer from then. Then it prints, per stream of `pabctl check`'s table, its \
frames, the worst wait for the bus and the worst latency (queued to the end of its EOF) beside \
the bound R: a latency above R fails the command (exit status 1). A stream whose own frames \
come faster than its period (and jitter) allow is outside the analysis: shown, not compared; \
so is a frame that waited behind frames the analysis does not count, which are listed. The \
nodes still answer in zero time. Refused without [bus] (exit status 2). For example:
  pabctl sim examples/take-and-return.toml --timed-bus")]
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
        /// Carry the frames on a bus that takes time at the file's [bus] rates, and compare each
        /// stream's worst latency with its bound from `pabctl check` (exit status 1 above it).
        #[arg(long)]
        timed_bus: bool,
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
  (1700000000.131000) can0 124##1000102030405060708090A0B
Standard ids have 3 hex digits, extended ids 8. Error frames are counted and skipped. CAN FD \
frames are ID##F DATA, F one hex digit of flags (1: bit-rate switching), up to 64 data bytes; \
they are replayed like classic ones (a length between CAN FD lengths is padded with zeros to \
the next, as a controller sends it). Every malformed line is reported as FILE:LINE:COLUMN: error: \
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
the emulated Cortex-M4 (QEMU mps2-an386), which writes the same records (classic frames only: \
that board is a classic CAN node, so a capture with CAN FD frames is refused there):
  pabctl replay NET.toml CAPTURE.log --records sim.txt --board-job job.bin
  cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \\
      --bin pab-an386-replay -- -append \"job.bin board.txt\"
  cmp sim.txt board.txt

--timed-bus carries every frame of the capture (the pab protocol's too) again, on the bus of \
`pabctl sim --timed-bus` at the file's [bus] rates: each frame is queued at its timestamp and \
takes the bus for its actual bits, one frame at a time, lowest identifier first. Then it prints, \
per stream of `pabctl check`'s table, the worst latency beside the bound R, as `sim --timed-bus` \
does; a latency above R fails the command (exit status 1). It checks the analysis against the \
release times of real nodes (their periods, their jitter, their bursts): a capture from Linux's \
vcan, where a frame takes no time, stamps each frame when its sender wrote it, so its times are \
the release times; frames that came faster than their stream's period and jitter allow are \
outside the analysis and shown, not compared. Refused without [bus] (exit status 2). For example:
  pabctl replay examples/take-and-return.toml host-tools/tests/fixtures/take-and-return-hil.log --timed-bus

Exit status: 0 replayed; 1 the rules are inconsistent, or with --timed-bus a latency exceeds its \
bound; 2 the network or the capture cannot be \
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
        /// Carry the capture's frames, each queued at its timestamp, on a bus that takes time at
        /// the file's [bus] rates, and compare each stream's worst latency with its bound from
        /// `pabctl check` (exit status 1 above it).
        #[arg(long)]
        timed_bus: bool,
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
        /// Send the transfer in CAN FD frames (ISO-TP on CAN FD: 64-byte frames with the
        /// bit-rate switch, 63 bytes of the message a frame) instead of classic ones: for nodes
        /// built with CAN FD (pab-node) on an interface that carries CAN FD frames (MTU 72).
        /// Without it, the transfer is CAN FD when the file's bus is ([bus] data_bitrate).
        #[arg(long)]
        fd: bool,
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
        /// Send the transfer in CAN FD frames (ISO-TP on CAN FD: 64-byte frames with the
        /// bit-rate switch, 63 bytes of the message a frame) instead of classic ones: for nodes
        /// built with CAN FD (pab-node) on an interface that carries CAN FD frames (MTU 72).
        /// Without it, the transfer is CAN FD when the file's bus is ([bus] data_bitrate).
        #[arg(long)]
        fd: bool,
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
        /// Send the transfer in CAN FD frames (ISO-TP on CAN FD: 64-byte frames with the
        /// bit-rate switch, 63 bytes of the message a frame) instead of classic ones: for nodes
        /// built with CAN FD (pab-node) on an interface that carries CAN FD frames (MTU 72).
        /// Without it, the transfer is CAN FD when the file's bus is ([bus] data_bitrate).
        #[arg(long)]
        fd: bool,
    },
    /// Create a node key file (32 hexadecimal characters, mode 0600), or with --signing a
    /// firmware signing key.
    #[command(long_about = "\
Write a new random 128-bit key (from /dev/urandom) to FILE as 32 hexadecimal characters and a \
newline, readable by its owner only (mode 0600). Refuses to overwrite an existing file. Give the \
file to the node (`pab-node --key FILE`, or a board's key page: `pabctl keypage`) and to the \
configuring verbs (`pabctl push --key FILE`, `pabctl monitor --key FILE`). Whoever can read the \
file can configure the node.

With --signing: a new Ed25519 signing key for firmware images (its 32-byte secret as 64 \
hexadecimal characters, mode 0600, never overwritten), and its public key printed, the one the \
boards check images against (docs/firmware-update.md). Sign with `pabctl sign --key FILE`. \
Whoever can read the file can sign firmware that the boards will run: keep it off the robot.")]
    Keygen {
        /// The key file to create.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
        /// A firmware signing key (Ed25519) instead of a node key.
        #[arg(long)]
        signing: bool,
    },
    /// Sign a firmware image for the boards of one kind (Ed25519, docs/firmware-update.md).
    #[command(long_about = "\
Append to FIRMWARE.bin (the application's binary, as `objcopy -O binary` writes it) a trailer \
that says what it is (board kind, version, build id, length, whether it may replace a higher \
version) and the Ed25519 signature of the SHA-512 digest of both, and write the result to \
--output. A board takes an image only if it is signed by the key whose public key it holds, \
for its own board kind (the firmware's name in its identity: fw-g474, fw-f446, fw-an386), of a \
version not lower than the one it runs unless signed with --downgrade. Prints the signed \
image's trailer and size. Refuses to overwrite the input, and writes --output whole or not at \
all.

Example: pabctl sign --key release.sign --board fw-g474 --version 1.2.0 --build $(git \
rev-parse HEAD) target/fw.bin -o fw-1.2.0.signed")]
    Sign {
        /// The signing key file (`pabctl keygen --signing`).
        #[arg(long, value_name = "FILE")]
        key: PathBuf,
        /// The firmware binary to sign.
        firmware: PathBuf,
        /// The signed image to write.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
        /// The board kind: the firmware's name as its identity states it (at most 8 ASCII
        /// characters: fw-g474, fw-f446, fw-an386).
        #[arg(long, value_name = "NAME", value_parser = pabctl::signing::board_kind)]
        board: [u8; 8],
        /// The firmware's semantic version (MAJOR.MINOR.PATCH, each 0 to 255).
        #[arg(long, value_name = "X.Y.Z", value_parser = pabctl::signing::version)]
        version: [u8; 3],
        /// The build id: hexadecimal digits of the commit (the first 16 are kept).
        #[arg(long, value_name = "HEX", value_parser = pabctl::signing::build_id)]
        build: [u8; 8],
        /// Allow the image to replace a higher version (signed with it).
        #[arg(long)]
        downgrade: bool,
    },
    /// Update nodes' firmware over the bus with a signed image; check that each runs it.
    #[command(long_about = "\
Send FIRMWARE.signed (an image `pabctl sign` made) to each node of --node over --iface, one node \
after the other, and check that the node runs it. Per node: the Begin (the image's trailer and \
signature), which the node checks (board kind, version not lower than the one it runs unless \
signed as a downgrade, size) and answers Ready or Refused; the image in chunks of 1 024 bytes, \
each acknowledged with the next offset and the CRC-32 so far, checked against the tool's (a lost \
answer sends the chunk again, a node that expects another offset is resumed from it); the \
Commit with the image's CRC-32, after which the node stores the request and restarts into its \
bootloader. The bootloader checks the Ed25519 signature against the public key in the node's key \
page, swaps the image in or refuses it, and the node says which when it is back (within \
--restart-timeout). The update of a node is done only when its identity then states the signed \
board kind, version and build. A progress bar per node shows bytes sent and throughput (on a \
terminal); one line per node says how it ended.

What the node needs: a firmware built with the `update` feature, an update partition and a \
bootloader (today the emulated board's `update` build, behind its bootloader; not yet the NUCLEO \
boards' flashed firmware, and not pab-node, which has no update partition and answers \
Unsupported), and the update key (Ed25519 public key) in its key page: only images signed with the \
matching key run, whatever the bus carries. A keyed node takes the update only with --key (a \
challenge and a TransferOpen authorise the Begin).

Nodes are taken one after the other. A node that refuses the image, does not answer or fails \
before its restart is reported and the next node is tried; a node that restarted with the image \
and does not come back running it (the bootloader refused or reverted it) stops the command \
there: the image or the bootloader is suspect, and the other nodes keep their firmware. Exit \
status 2 for a file that is not a signed image (nothing is sent), 4 when a node did not take the \
update.

Examples:
  pabctl flash --iface can0 --node 3 fw-1.2.0.signed
  pabctl flash --iface can0 --node arm,hand --network robot.toml --key robot.key fw-1.2.0.signed")]
    Flash {
        /// The signed firmware image (`pabctl sign`).
        #[arg(value_name = "FIRMWARE.signed")]
        firmware: PathBuf,
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// The nodes to update, in order: node ids (1..=127), or names from --network,
        /// separated by commas.
        #[arg(
            long,
            value_name = "NAME_OR_ID,...",
            value_delimiter = ',',
            required = true
        )]
        node: Vec<String>,
        /// The network file (TOML) whose [nodes] name the nodes of --node.
        #[arg(long, value_name = "FILE")]
        network: Option<PathBuf>,
        /// The nodes' key file (`pabctl keygen`): needed by nodes with a key (challenge and
        /// TransferOpen before the Begin), refused by nodes without one.
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
        /// How long to wait for a node to come back after its restart into the bootloader.
        #[arg(long, value_name = "SECONDS", default_value = "30", value_parser = args::seconds)]
        restart_timeout: f64,
        /// Send the update's messages in CAN FD frames (ISO-TP on CAN FD: 64-byte frames with the
        /// bit-rate switch, 63 bytes of the message a frame) instead of classic ones: for nodes
        /// built with CAN FD (pab-node) on an interface that carries CAN FD frames (MTU 72).
        #[arg(long)]
        fd: bool,
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
    /// Write a board's key page image from a key file and an update key.
    #[command(long_about = "\
Write the key page image to FILE.bin, to be written at the board's key page address \
(docs/keys.md: probe-rs download --binary-format bin --base-address ...): the 32-byte record of \
KEYFILE (magic PABK, format 1, the key, CRC-32), which keys the node, and with --update-key the \
48-byte record of the public key the board's bootloader checks firmware images against, at \
offset 64 (magic PABS: docs/firmware-update.md). Without KEYFILE the node key's record is left \
erased (0xFF): the node stays unkeyed. Neither can be changed over the bus. The update public \
key is the one `pabctl keygen` printed when it made the signing key.

Example: pabctl keypage node3.key --update-key 3b6a...e1 -o node3.keypage.bin")]
    Keypage {
        /// The node's key file (`pabctl keygen`); without it the node stays unkeyed.
        #[arg(required_unless_present = "update_key")]
        key: Option<PathBuf>,
        /// The update public key: its 64 hexadecimal digits (as `pabctl keygen` printed them
        /// for the signing key) or a file that holds them.
        #[arg(long, value_name = "HEX|FILE", value_parser = pabctl::signing::public_key)]
        update_key: Option<[u8; 32]>,
        /// The page image to write.
        #[arg(short, long, value_name = "FILE.bin")]
        output: PathBuf,
    },
    /// List the nodes on the bus: who they are and how they are doing.
    #[command(long_about = "\
Ask every node on --iface who it is (an identity request, broadcast), listen for --listen \
seconds and print one line per node heard: its node id (\"-\" for an unassigned node, which \
answers from its provisional address 128-254), state (no table, operational, fault), uptime, \
table version and CRC, whether the table is stored, the frame counters (received, delivered, \
discarded, errors), the last fault, its firmware (name, version) and its uid (what `pabctl \
assign --uid` takes). With a network file, nodes are named. --json prints every field of the \
identity too: build, protocol, table formats, capacities, features, keyed, bit rate.")]
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
    /// Give a node (named by its uid) its node id, stored in its configuration page.
    #[command(long_about = "\
Find the node whose uid is --uid (`pabctl nodes` lists uids; an unassigned node answers from its \
provisional address) and give it node id --node-id, which it stores power-fail safe and takes at \
once: it then announces itself, sends heartbeats and takes tables compiled for that id. Refused \
before anything is sent when another node answers to --node-id, or when the node is keyed and \
--key is missing. A table that ran on the node under its old id stops (tables are compiled for \
one node id): push the network again.

Example: pabctl assign --iface can0 --uid 0123456789abcdef01234567 --node-id 3")]
    Assign {
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// The node's uid, as `pabctl nodes` prints it (24 hexadecimal digits, 16 for a
        /// pab-node).
        #[arg(long, value_parser = pabctl::identity::parse_uid)]
        uid: [u8; 12],
        /// The node id to give it, 1..=127.
        #[arg(long, allow_hyphen_values = true, value_parser = args::node_id)]
        node_id: u8,
        /// The node's key file (`pabctl keygen`): needed when the node is keyed.
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
    },
    /// Set a node's bit rate, from its next start.
    #[command(long_about = "\
Set the bit rate node --node runs at from its next start (125, 250, 500 or 1000 kbit/s), stored \
in its configuration page. At that start the node must hear a frame within 5 s, or it stores its \
previous rate again, restarts on it and raises a BitrateFallback fault: a wrong rate never \
strands a board. Change every node of a bus, then restart them together. A Linux node \
(pab-node) answers that its bit rate is its interface's (`ip link set can0 type can bitrate R`).

Example: pabctl config --iface can0 --node 3 --bitrate 1000")]
    Config {
        /// The CAN interface (vcan0, can0...).
        #[arg(long)]
        iface: String,
        /// The node's id.
        #[arg(long, allow_hyphen_values = true, value_parser = args::node_id)]
        node: u8,
        /// The bit rate from the next start, kbit/s: 125, 250, 500 or 1000.
        #[arg(long, value_parser = args::bitrate_kbps)]
        bitrate: u16,
        /// The node's key file (`pabctl keygen`): needed when the node is keyed.
        #[arg(long, value_name = "FILE")]
        key: Option<PathBuf>,
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
