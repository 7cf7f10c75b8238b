//! `pabctl nodes`: the nodes heard on the bus, from their heartbeats.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use pab_lang::network::Network;
use pabctl::observe;

use super::{bus_failure, open_bus};
use crate::failure::Failure;

pub fn run(iface: &str, network: Option<&Path>, listen: f64, json: bool) -> Result<(), Failure> {
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
