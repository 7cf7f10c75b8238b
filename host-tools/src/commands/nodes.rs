//! `pabctl nodes`: the nodes on the bus, from their identities and heartbeats; `pabctl assign`
//! and `pabctl config`: their node ids and bit rates, over the bus.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use pab_lang::network::Network;
use pabctl::observe;

use pab_core::protocol::Message;
use pabctl::identity;

use super::{bus_failure, open_bus, read_key};
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
    // Every node says who it is, the unassigned ones too (they send no heartbeat).
    bus.send(
        &Message::IdentityRequest.to_frame(pab_core::protocol::TOOL, pab_core::protocol::BROADCAST),
    )
    .map_err(bus_failure(iface))?;
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

/// `pabctl assign`.
pub fn assign(iface: &str, uid: &[u8; 12], node_id: u8, key: Option<&Path>) -> Result<(), Failure> {
    let key = key.map(read_key).transpose()?;
    let mut bus = open_bus(iface)?;
    let status = identity::assign(bus.as_mut(), uid, node_id, key.as_ref())
        .map_err(|e| config_failure(iface, e))?;
    report(&format!("uid {}", identity::uid_text(uid)), &status)
}

/// `pabctl config`.
pub fn configure(iface: &str, node: u8, bitrate: u16, key: Option<&Path>) -> Result<(), Failure> {
    let key = key.map(read_key).transpose()?;
    let mut bus = open_bus(iface)?;
    let status = identity::configure(bus.as_mut(), node, bitrate, key.as_ref())
        .map_err(|e| config_failure(iface, e))?;
    report(&format!("node {node}"), &status)
}

fn config_failure(iface: &str, error: identity::ConfigError) -> Failure {
    match error {
        identity::ConfigError::Io(error) => bus_failure(iface)(error),
        identity::ConfigError::Refused(why) => Failure::Bus(why),
    }
}

fn report(who: &str, status: &pab_core::protocol::ConfigStatus) -> Result<(), Failure> {
    use pab_core::protocol::ConfigStatusCode;
    let words = identity::describe_status(status);
    match status.status {
        ConfigStatusCode::Stored => {
            println!("{who}: {words}");
            Ok(())
        }
        ConfigStatusCode::NotStored => {
            println!("{who}: {words}");
            Ok(())
        }
        _ => Err(Failure::Bus(format!("{who}: refused: {words}"))),
    }
}
