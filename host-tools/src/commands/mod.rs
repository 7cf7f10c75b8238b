//! One module per command, or per family of commands, each with the function the dispatch in
//! `main.rs` calls; and what the commands on a live bus share: opening the bus, its errors, the
//! key file.

pub mod check;
pub mod compile;
pub mod dbc;
pub mod flash;
pub mod init;
pub mod keys;
pub mod monitor;
pub mod nodes;
pub mod push;
pub mod replay;
pub mod schema;
pub mod schema_server;
pub mod sign;
pub mod sim;
pub mod solve;

use std::io;
use std::path::Path;

use pab_lang::diagnostic::Diagnostic;
use pabctl::bus::{self, Bus};

use crate::failure::Failure;

pub fn open_bus(iface: &str) -> Result<Box<dyn Bus>, Failure> {
    open_bus_with(iface, bus::Framing::Classic)
}

/// [`open_bus`], its transfers framed as `framing` says (`--fd`).
pub fn open_bus_with(iface: &str, framing: bus::Framing) -> Result<Box<dyn Bus>, Failure> {
    bus::open_with(iface, framing).map_err(|error| Failure::Bus(error.to_string()))
}

/// The transfers' framing `--fd` asks for.
pub fn framing(fd: bool) -> bus::Framing {
    if fd {
        bus::Framing::Fd
    } else {
        bus::Framing::Classic
    }
}

/// The transfers' framing on `network`'s bus: CAN FD on a CAN FD bus (`[bus] data_bitrate`,
/// where every node has a CAN FD controller: a classic one is refused there), else what `--fd`
/// asked (`asked`). Says so when the file decided it.
pub fn framing_on(network: &pab_lang::network::Network, asked: bus::Framing) -> bus::Framing {
    match network.bus.as_ref().and_then(|bus| bus.data_bitrate) {
        Some(rate) if asked != bus::Framing::Fd => {
            eprintln!(
                "transfers in CAN FD frames: the network's bus is CAN FD (data_bitrate = {rate})"
            );
            bus::Framing::Fd
        }
        _ => asked,
    }
}

pub fn bus_failure(iface: &str) -> impl Fn(io::Error) -> Failure + '_ {
    move |error| Failure::Bus(format!("on {iface}: {error}"))
}

pub fn read_key(path: &Path) -> Result<pab_core::auth::Authenticator, Failure> {
    let key = pabctl::keys::read(path)
        .map_err(|message| Failure::Input(Diagnostic::file(path, message).into()))?;
    Ok(pab_core::auth::Authenticator::new(&key))
}

#[cfg(test)]
mod tests {
    use super::*;
    use pab_lang::diagnostic::Source;
    use pab_lang::network::Network;

    fn network(bus: &str) -> Network {
        let text = format!(
            "{bus}[nodes.arm]\nid = 1\n[topics.t]\ncan_id = 0x100\n[ports.\"arm.p\"]\n\
             [connections.C]\ntopic = \"t\"\nport = \"arm.p\"\nst = 1.0\ntc = 0.5\n"
        );
        Network::parse(Source::new("net.toml", &text)).unwrap()
    }

    /// On a CAN FD bus the transfers are CAN FD whatever was asked; elsewhere what was asked.
    #[test]
    fn a_can_fd_bus_makes_the_transfers_can_fd() {
        let fd = network("[bus]\nbitrate = 500000\ndata_bitrate = 2000000\n");
        assert_eq!(framing_on(&fd, bus::Framing::Classic), bus::Framing::Fd);
        assert_eq!(framing_on(&fd, bus::Framing::Fd), bus::Framing::Fd);
        for classic in [network("[bus]\nbitrate = 500000\n"), network("")] {
            assert_eq!(
                framing_on(&classic, bus::Framing::Classic),
                bus::Framing::Classic
            );
            assert_eq!(framing_on(&classic, bus::Framing::Fd), bus::Framing::Fd);
        }
    }
}
