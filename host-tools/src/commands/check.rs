//! `pabctl check`: the verdict on a network's rules, with its warnings.

use std::path::Path;

use pab_lang::check;
use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;

use crate::failure::Failure;
use crate::output::{colour, eprintln_line, plural, println_line};

pub fn run(
    path: &Path,
    json: bool,
    bitrate: Option<u32>,
    data_bitrate: Option<u32>,
) -> Result<(), Failure> {
    let network = match Network::load(path) {
        Ok(network) => network,
        Err(errors) => {
            if json {
                println!("{}", pabctl::json::invalid(path, &errors.0));
            }
            return Err(errors.into());
        }
    };
    if let Some(data) = data_bitrate {
        let refused = data_bitrate_refused(&network, bitrate, data);
        if let Some(message) = refused {
            let errors = vec![Diagnostic::file(path, message)];
            if json {
                println!("{}", pabctl::json::invalid(path, &errors));
            }
            return Err(Failure::Input(pab_lang::diagnostic::Diagnostics(errors)));
        }
    }
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
    // The bus: every stream's worst-case response time at the network's bit rate, or the
    // command line's.
    let timing = check::bus::timing_with(&network, bitrate, data_bitrate);
    let late = timing.errors(&network);
    if json {
        let shown: Vec<&Diagnostic> = warnings.iter().map(|w| &w.0).collect();
        let mut value = pabctl::json::check(path, &network, &report, &errors, &shown);
        value["bus"] = pabctl::json::bus(&timing, &late);
        println!("{value}");
        // The text for a person, on standard error.
        eprint!("{}", report.summary(&network));
        eprint!("{}", timing.table());
    } else {
        print!("{}", report.summary(&network));
        print!("{}", timing.table());
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
        if late.is_empty() {
            Ok(())
        } else {
            Err(Failure::Deadlines(late))
        }
    } else {
        if !late.is_empty() {
            eprintln!(
                "{}\n",
                pab_lang::diagnostic::Diagnostics(late).render(colour())
            );
        }
        Err(Failure::Inconsistent(errors))
    }
}

/// Why `--data-bitrate DATA` cannot be analysed on `network` (with `--bitrate`, if given): a
/// classic bus (the file says whether the bus is CAN FD, as that changes what it may hold), or a
/// data phase slower than the nominal rate.
fn data_bitrate_refused(network: &Network, bitrate: Option<u32>, data: u32) -> Option<String> {
    let Some(bus) = network.bus.as_ref().filter(|bus| bus.is_fd()) else {
        return Some(format!(
            "--data-bitrate {data}: the network's bus is classic CAN (no `data_bitrate` in [bus]); write `data_bitrate` in its [bus] to make it a CAN FD bus"
        ));
    };
    let nominal = bitrate.unwrap_or(bus.bitrate);
    (data < nominal).then(|| {
        format!(
            "--data-bitrate {data}: below the nominal bit rate {nominal} (the data phase is never slower than the arbitration)"
        )
    })
}
