//! `pab-node`: a pab node as a Linux process on a SocketCAN interface.
//!
//! The same application as the boards (`pab-app`), with the full table capacities, on embassy's
//! std executor. Use it to stand in for a board on `vcan0` during development, or as an
//! arbitrating gateway on a Linux computer in front of actuators that are never changed.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use embassy_executor::Executor;

mod file_store;

use file_store::FileStore;
use pab_app::store::TableStore as _;
use pab_node::receive_queue;
use pab_node::socket_bus::SocketBus;

/// A pab node on a SocketCAN interface.
///
/// The node arbitrates every frame it reads with its table, re-publishes the winners of gateway
/// ports, sends its heartbeat (1 Hz), faults and, when `pabctl monitor` asks, the diagnostic
/// stream. It accepts new tables from `pabctl push` over ISO-TP and stores them in --store so it
/// boots with the latest one.
///
/// Its socket takes CAN FD frames as well as classic ones: on an interface with MTU 72 (a vcan:
/// `sudo ip link set vcan0 down; sudo ip link set vcan0 mtu 72; sudo ip link set vcan0 up`) it
/// takes tables pushed in CAN FD frames (`pabctl push --fd`), answering in CAN FD, and arbitrates
/// CAN FD topics; on a classic interface (MTU 16) it runs classic as before.
///
/// Example, three nodes on a virtual bus:
///
///   sudo modprobe vcan; sudo ip link add dev vcan0 type vcan; sudo ip link set up vcan0
///
///   pab-node --iface vcan0 --node-id 1 --store /var/lib/pab/arm &
///
///   pabctl push examples/take-and-return.toml --iface vcan0
///
/// Logging: RUST_LOG=debug for more detail (default: info).
#[derive(Parser, Debug)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// The SocketCAN interface (vcan0, can0...).
    #[arg(long)]
    iface: String,
    /// This node's id, 1..=127; pushed tables must be compiled for it. An id given over the bus
    /// (`pabctl assign`) and kept in --store wins over it. Without either, the node starts
    /// unassigned: it answers only `pabctl nodes` (with its uid) and `pabctl assign`.
    #[arg(long, allow_hyphen_values = true, value_parser = node_id)]
    node_id: Option<u8>,
    /// Boot with this table image (from `pabctl compile`) instead of the stored one. It must be
    /// a regular file of at most 32768 bytes (anything else stops the start, exit status 2). An
    /// image for another node id is refused at boot, as a push of it would be: the node starts
    /// without a table and raises a BadStoredTable fault.
    #[arg(long, value_name = "FILE.pab")]
    table: Option<PathBuf>,
    /// Directory where pushed tables are stored (created if missing), as DIR/table.pab; the node
    /// boots with it. If DIR/table.pab is not a regular file of at most 32768 bytes (a FIFO, a
    /// directory, a device), cannot be read, or is refused like a push, the node starts without
    /// a table and raises a BadStoredTable fault that says why. Without --store, a pushed table
    /// runs until the process ends and the node answers "applied, but storing failed".
    #[arg(long, value_name = "DIR")]
    store: Option<PathBuf>,
    /// Heartbeat period in milliseconds, 10..=3600000.
    #[arg(long, default_value = "1000", allow_hyphen_values = true, value_parser = heartbeat_ms)]
    heartbeat_ms: u64,
    /// This node's key file (`pabctl keygen -o FILE`: 32 hexadecimal characters). With a key,
    /// the node takes only authenticated configuration (`pabctl push --key FILE`) and says so in
    /// its heartbeat; without one, it accepts configuration from anyone on the bus. A file that
    /// cannot be read or is not a key stops the start.
    #[arg(long, value_name = "FILE")]
    key: Option<PathBuf>,
    /// The CAN socket's receive buffer, in bytes as the kernel counts them, 8192..=1073741824.
    /// The default holds 100 ms of a saturated 1 Mbit/s bus: 2128 frames of 47 bits (the
    /// shortest), at 768 bytes each (what Linux charges per queued CAN frame, measured). Beyond
    /// net.core.rmem_max it needs root (SO_RCVBUFFORCE); otherwise the node starts with what
    /// rmem_max allows and logs a warning saying how to raise it. Frames the kernel drops all the
    /// same are counted (Errors, and the RxOverrun fault with the total lost).
    #[arg(long, value_name = "BYTES", default_value_t = receive_queue::DEFAULT_BYTES,
          allow_hyphen_values = true, value_parser = rcvbuf)]
    rcvbuf: u64,
    /// The table capacities to run with: `full` (16 ports, 512 connections, 2048 decision
    /// nodes, 32 KiB images) or `board` (the boards' firmware: 4 ports, 64 connections, 256
    /// decision nodes, 8 KiB images), to try on vcan0 whether a network fits a board before
    /// flashing one. The node's identity says which (`pabctl nodes --json`, `capacity`).
    #[arg(long, value_enum, default_value = "full")]
    capacity: Capacity,
}

/// [`Args::capacity`].
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Capacity {
    Full,
    Board,
}

/// A whole number in `min..=max`, or what is wrong with `text` (a negative number is "not
/// positive", not clap's "unexpected argument").
fn whole(text: &str, min: u64, max: u64) -> Result<u64, String> {
    let text = text.trim();
    if text.starts_with('-') {
        return Err(format!("must be positive ({min}..={max})"));
    }
    match text.parse::<u64>() {
        Ok(value) if (min..=max).contains(&value) => Ok(value),
        Ok(_) => Err(format!("must be in {min}..={max}")),
        Err(_) if !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit()) => {
            Err(format!("must be in {min}..={max}"))
        }
        Err(_) => Err(format!("`{text}` is not a whole number ({min}..={max})")),
    }
}

fn node_id(text: &str) -> Result<u8, String> {
    whole(text, 1, 127).and_then(|id| u8::try_from(id).map_err(|error| error.to_string()))
}

fn heartbeat_ms(text: &str) -> Result<u64, String> {
    whole(text, 10, 3_600_000)
}

fn rcvbuf(text: &str) -> Result<u64, String> {
    whole(text, receive_queue::MIN_BYTES, receive_queue::MAX_BYTES)
}

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let args = Args::parse();
    match start(args) {
        Ok(never) => match never {},
        Err(error) => {
            eprintln!("pab-node: {error:#}");
            ExitCode::from(2)
        }
    }
}

/// Everything that can fail before the node runs; then runs it forever.
fn start(args: Args) -> anyhow::Result<std::convert::Infallible> {
    use anyhow::Context as _;
    let mut store = FileStore::new(args.store.clone(), args.table.clone())
        .with_context(|| "preparing the table store")?;
    let uid = file_store::node_uid(args.store.as_deref()).with_context(|| "the node's uid")?;
    let loaded = store.load_settings();
    let settings = pab_app::Settings::from_loaded(&loaded);
    let node_id = settings.node_id.or(args.node_id);
    if let (Some(kept), Some(given)) = (settings.node_id, args.node_id)
        && kept != given
    {
        log::warn!(
            "node id {kept}, given over the bus and kept in --store, wins over --node-id {given}"
        );
    }
    let mut config = pab_app::Config::for_node(node_id)?;
    let key = args
        .key
        .as_deref()
        .map(pab_node::key_file::read_key)
        .transpose()?;
    config.heartbeat_period_us = args.heartbeat_ms * 1000;
    let (bus, sizing) = SocketBus::open(&args.iface, args.rcvbuf).with_context(|| {
        format!(
            "opening CAN interface {:?} (does it exist and is it up? `ip link show {}`)",
            args.iface, args.iface
        )
    })?;
    match &sizing.shortfall {
        None => log::info!(
            "receive buffer {} bytes: {} frames, {} ms of a saturated 1 Mbit/s bus",
            sizing.got,
            sizing.frames(),
            sizing.window_ms()
        ),
        Some(why) => log::warn!("{why}"),
    }
    let uid_text: String = uid.iter().take(8).map(|b| format!("{b:02x}")).collect();
    log::info!(
        "node {} (uid {uid_text}) on {} ({}; heartbeat every {} ms, store {})",
        node_id.map_or("unassigned".to_string(), |id| id.to_string()),
        args.iface,
        if bus.carries_fd() {
            "classic and CAN FD frames"
        } else {
            "classic CAN only: MTU 16"
        },
        args.heartbeat_ms,
        args.store
            .as_ref()
            .map_or("none".to_string(), |dir| dir.display().to_string())
    );
    let boot_salt = key
        .as_ref()
        .map(|_| pab_node::key_file::boot_salt())
        .transpose()?;
    match &key {
        Some(_) => log::info!("keyed: only authenticated configuration is accepted"),
        None => log::warn!(
            "no --key: this node accepts configuration from anyone on the bus (pabctl keygen)"
        ),
    }
    let parts = Box::leak(Box::new((bus, store)));
    let executor = Box::leak(Box::new(Executor::new()));
    // The node holds the arbiter and its transfer buffer (32 KiB at full capacity): on the heap,
    // not in the task.
    match args.capacity {
        Capacity::Full => {
            let node = Box::leak(Box::new(pab_app::FullNode::new(config, pab_app::now())));
            prepare(node, uid, loaded, key.as_ref().zip(boot_salt));
            executor.run(move |spawner| {
                spawner.spawn(full_task(node, &mut parts.0, &mut parts.1).expect("one task"));
            })
        }
        Capacity::Board => {
            let node = Box::leak(Box::new(pab_app::BoardNode::new(config, pab_app::now())));
            prepare(node, uid, loaded, key.as_ref().zip(boot_salt));
            executor.run(move |spawner| {
                spawner.spawn(board_task(node, &mut parts.0, &mut parts.1).expect("one task"));
            })
        }
    }
}

/// What the node must know before it runs: who it is, its settings, its key.
fn prepare<const P: usize, const C: usize, const N: usize, const IMG: usize>(
    node: &mut pab_app::Node<P, C, N, IMG>,
    uid: [u8; pab_core::identity::UID_LEN],
    loaded: Result<Option<u16>, pab_app::StoreError>,
    key: Option<(&pab_core::auth::Key, u32)>,
) {
    const FIRMWARE: pab_app::Firmware = pab_app::firmware!("pab-node");
    node.set_identity(FIRMWARE, uid);
    // The interface's bit rate is the operating system's (`ip link`), not the node's: 0.
    node.set_settings(loaded, 0, pab_app::now());
    if let Some((key, boot_salt)) = key {
        node.set_key(key, boot_salt);
    }
}

#[embassy_executor::task]
async fn full_task(
    node: &'static mut pab_app::FullNode,
    bus: &'static mut SocketBus,
    store: &'static mut FileStore,
) {
    pab_app::run(node, bus, store, &mut ()).await
}

#[embassy_executor::task]
async fn board_task(
    node: &'static mut pab_app::BoardNode,
    bus: &'static mut SocketBus,
    store: &'static mut FileStore,
) {
    pab_app::run(node, bus, store, &mut ()).await
}
