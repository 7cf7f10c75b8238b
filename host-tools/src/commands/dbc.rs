//! `pabctl dbc`: the DBC file that decodes the network's traffic.

use std::fs;
use std::io::{self, Write};
use std::path::Path;

use pab_lang::candump;
use pab_lang::dbc;
use pab_lang::network::Network;

use crate::failure::Failure;
use crate::output::{plural, progress_bar, write_atomically};

pub fn run(path: &Path, output: &Path, claims_from: Option<&Path>) -> Result<(), Failure> {
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
