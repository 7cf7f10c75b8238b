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

pub fn bus_failure(iface: &str) -> impl Fn(io::Error) -> Failure + '_ {
    move |error| Failure::Bus(format!("on {iface}: {error}"))
}

pub fn read_key(path: &Path) -> Result<pab_core::auth::Authenticator, Failure> {
    let key = pabctl::keys::read(path)
        .map_err(|message| Failure::Input(Diagnostic::file(path, message).into()))?;
    Ok(pab_core::auth::Authenticator::new(&key))
}
