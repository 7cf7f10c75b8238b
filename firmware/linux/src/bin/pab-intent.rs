//! `pab-intent`: HBBA's intention node as a Linux process on a SocketCAN interface.

// The doc comment of `Args` is clap's --help, verbatim: its [hbba] is the network file's section,
// not a link.
#![allow(rustdoc::broken_intra_doc_links)]

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use pab_intent::{Clock as _, IntentNode, Report, Setup, SystemClock};
use pab_node::receive_queue;
use pab_node::socket_bus::SocketBus;

/// HBBA's intention node on a SocketCAN interface.
///
/// Listens to the Desire frames on the bus (class, intensity, lease: a desire not sent again
/// within its lease is dropped), keeps per class the most intense, and on every change solves
/// which strategies of the network's [hbba] section run. It then sets the message filters of the
/// boards with FilterSet commands (per filtered connection the φ of its selected strategy, 0 when
/// none names it): every reduction first, every increase once the reductions are acknowledged
/// (FilterStatus) or refused (FilterRefused), a command without an answer sent again after
/// 250 ms and given up after 3 sends. It publishes the selected strategies (Intention, from
/// address 126) on every change and every second, and re-applies a node's filters when its
/// heartbeat shows a restart. It logs every desire, selection, command, refusal and restart.
///
/// A node answers each command it applied with FilterStatus; one it cannot apply it refuses
/// (FilterRefused: no such profile, not a filtered connection, or a table without filters),
/// which pab-intent logs as a warning; the intention is published all the same.
///
/// Example, on a virtual bus with the tour guide's nodes:
///
///   pab-node --iface vcan0 --node-id 1 &
///
///   pabctl compile examples/tour-guide.toml -o tables
///
///   pab-intent --interface vcan0 --setup tables/intention.json
///
///   cansend vcan0 1208FF09#0200030010270100   # node 9: class 2 (voice), intensity 3, 10 s
///
/// On a keyed network (nodes started with a key), give pab-intent the nodes' key with --key:
/// every FilterSet is then followed by its seal, and a keyed node applies only sealed commands
/// (a participant without the key cannot steer its filters).
///
/// Logging: RUST_LOG=debug for more detail (default: info).
#[derive(Parser, Debug)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// The SocketCAN interface (vcan0, can0...).
    #[arg(long, visible_alias = "iface")]
    interface: String,
    /// The intention setup `pabctl compile` wrote for the network (DIR/intention.json).
    #[arg(long, value_name = "intention.json")]
    setup: PathBuf,
    /// The network's key file (`pabctl keygen -o FILE`), the one its keyed nodes have: seals
    /// every filter command and answers the nodes' freshness requests. Without it, keyed nodes
    /// refuse every command (and pab-intent logs their refusals).
    #[arg(long, value_name = "FILE")]
    key: Option<PathBuf>,
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let args = Args::parse();
    match start(args) {
        Ok(never) => match never {},
        Err(error) => {
            eprintln!("pab-intent: {error:#}");
            ExitCode::from(2)
        }
    }
}

/// Everything that can fail before the loop runs; then runs it forever.
fn start(args: Args) -> anyhow::Result<std::convert::Infallible> {
    use anyhow::Context as _;
    let path = args.setup.display();
    let text = std::fs::read_to_string(&args.setup).with_context(|| {
        format!("reading the intention setup {path} (`pabctl compile NET.toml -o DIR` writes DIR/intention.json for a network with an [hbba] section)")
    })?;
    let setup = Setup::from_json(&text).map_err(|error| anyhow::anyhow!("{path}: {error}"))?;
    let key = args
        .key
        .as_deref()
        .map(pab_node::key_file::read_key)
        .transpose()?;
    let mut node = IntentNode::new(&setup, pab_core::protocol::INTENTION)
        .map_err(|error| anyhow::anyhow!("{path}: [hbba]: {error}"))?;
    let mut clock = SystemClock::new();
    if let Some(key) = &key {
        node.set_key(key, pab_node::key_file::boot_salt()?, clock.now());
    }
    let (mut bus, sizing) = SocketBus::open(&args.interface, receive_queue::DEFAULT_BYTES)
        .with_context(|| {
            format!(
                "opening CAN interface {:?} (does it exist and is it up? `ip link show {}`)",
                args.interface, args.interface
            )
        })?;
    if let Some(why) = &sizing.shortfall {
        log::warn!("{why}");
    }
    log::info!(
        "intention node {} on {}: {} strategies, {} filtered connections, from {}{}",
        pab_core::protocol::INTENTION,
        args.interface,
        setup.instance.strategies.len(),
        setup.targets.len(),
        path,
        if key.is_some() {
            ", sealing its commands"
        } else {
            ""
        }
    );
    let mut log = |report: Report| {
        if report.warning {
            log::warn!("{report}");
        } else {
            log::info!("{report}");
        }
    };
    async_io::block_on(pab_intent::run(&mut node, &mut bus, &mut clock, &mut log))
}
