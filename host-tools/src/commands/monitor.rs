//! `pabctl monitor`: the live view of every port, from the nodes' diagnostic stream.

use std::io::{self, Write};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use pab_lang::network::Network;
use pabctl::monitor;

use super::{bus_failure, open_bus, read_key};
use crate::failure::Failure;

pub fn run(
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
