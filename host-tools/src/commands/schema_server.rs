//! The schema server's live commands: `pabctl plant` (the simulated robot on a live bus), `pabctl
//! run` (the client program sent to the board) and `pabctl limits` (its safety limits).

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use pab_lang::diagnostic::{Diagnostic, Diagnostics};
use pab_lang::network::Network;
use pabctl::bus;

use super::read_key;
use crate::failure::Failure;
use crate::output::write_atomically;

/// The schema server's board, client and plant of a file, for the live verbs.
fn schema_parts<'n>(
    path: &Path,
    network: &'n Network,
) -> Result<
    (
        &'n pab_lang::network::SchemaBoard,
        &'n pab_lang::network::Client,
    ),
    Failure,
> {
    let missing = |what: &str| {
        Failure::Input(Diagnostic::file(path, format!("the file has no {what}")).into())
    };
    let client = network.client.as_ref().ok_or_else(|| missing("[client]"))?;
    let board = network
        .schema_boards
        .iter()
        .find(|b| b.node == client.node)
        .ok_or_else(|| missing("[schema.NODE] for its client"))?;
    Ok((board, client))
}

pub fn plant(
    path: &Path,
    iface: &str,
    duration: Option<f64>,
    period_ms: Option<f64>,
    log_path: Option<&Path>,
) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let (board, _) = schema_parts(path, &network)?;
    let period_us = period_ms.map_or(board.config.period_us, |ms| {
        (ms * 1000.0).round().max(1.0) as u32
    });
    let mut bus = bus::open(iface).map_err(|e| Failure::Bus(e.to_string()))?;
    let stop = Arc::new(AtomicBool::new(false));
    let handler = stop.clone();
    // Ctrl-C or a SIGTERM ends the run as --duration does: the summary and the log are written.
    let _ = ctrlc::set_handler(move || handler.store(true, Ordering::SeqCst));
    let mut csv = String::from("t,x,y,z,attractor_x,attractor_y,attractor_z,force_n,inserted\n");
    let mut last_report = 0.0;
    let plant = pabctl::plant::run(
        bus.as_mut(),
        board,
        network.plant.clone().unwrap_or_default(),
        period_us,
        duration.map(std::time::Duration::from_secs_f64),
        &stop,
        &mut |s| {
            if log_path.is_some() {
                csv.push_str(&format!(
                    "{:.6},{},{},{},{},{},{},{:.3},{}\n",
                    s.t,
                    s.pose[0],
                    s.pose[1],
                    s.pose[2],
                    s.attractor[0],
                    s.attractor[1],
                    s.attractor[2],
                    s.force_n,
                    s.inserted
                ));
            }
            if s.t - last_report >= 5.0 {
                last_report = s.t;
                eprintln!(
                    "t = {:.0} s: z {:.3} mm, force {:.1} N, {} inserted, {} set-point frames",
                    s.t,
                    f64::from(s.pose[2]) / 1000.0,
                    s.force_n,
                    s.inserted,
                    s.setpoints
                );
            }
        },
    )
    .map_err(|e| Failure::Bus(e.to_string()))?;
    println!(
        "parts inserted: {} of {}",
        plant.inserted(),
        plant.parts().len()
    );
    if let Some(log_path) = log_path {
        write_atomically(log_path, csv.as_bytes())?;
        println!("log: {}", log_path.display());
    }
    Ok(())
}

pub fn run(
    path: &Path,
    iface: &str,
    timeout: f64,
    trace_path: Option<&Path>,
    key: Option<&Path>,
    framing: bus::Framing,
) -> Result<(), Failure> {
    let key = key.map(read_key).transpose()?;
    let network = Network::load(path)?;
    let (board, client) = schema_parts(path, &network)?;
    let node = network
        .nodes
        .get(board.node)
        .ok_or_else(|| Failure::Input(Diagnostic::file(path, "no such node").into()))?;
    let framing = super::framing_on(&network, framing);
    let mut bus = bus::open_with(iface, framing).map_err(|e| Failure::Bus(e.to_string()))?;
    let mut arm = match key {
        Some(key) => pabctl::client::Client::with_key(bus.as_mut(), node.id, key),
        None => pabctl::client::Client::new(bus.as_mut(), node.id),
    };
    let outcome = pabctl::client::run_program(
        &mut arm,
        &client.program,
        board,
        std::time::Duration::from_secs_f64(timeout),
        &mut |row| {
            println!(
                "{:>10.3} s  {:<28} {:<14} {}",
                row.t, row.schema, row.source, row.event
            );
        },
    );
    let outcome = match outcome {
        Ok(outcome) => outcome,
        Err(error) => return Err(Failure::Bus(format!("{}: {error}", node.name))),
    };
    if let Some(trace_path) = trace_path {
        let mut csv = String::from("t,node,schema,source,event\n");
        for row in &outcome.rows {
            csv.push_str(&format!(
                "{:.6},{},{},{},{}\n",
                row.t,
                node.name,
                csv_field(&row.schema),
                row.source,
                row.event
            ));
        }
        write_atomically(trace_path, csv.as_bytes())?;
        println!(
            "trace: {} ({} rows)",
            trace_path.display(),
            outcome.rows.len()
        );
    }
    match outcome.safety {
        Some(cause) => Err(Failure::Stopped(format!(
            "{}: stopped by a safety event ({}) after {} of {} calls",
            node.name,
            cause.description(),
            outcome.sent,
            client.program.len()
        ))),
        None => {
            println!("{}: {} calls run, no safety event", node.name, outcome.sent);
            Ok(())
        }
    }
}

pub fn limits(
    path: &Path,
    iface: Option<&str>,
    key: Option<&Path>,
    overrides: &pabctl::limits::Overrides,
    framing: bus::Framing,
) -> Result<(), Failure> {
    let key = key.map(read_key).transpose()?;
    let network = Network::load(path)?;
    let board = network.schema_boards.first().ok_or_else(|| {
        Failure::Input(Diagnostic::file(path, "the file has no [schema.NODE]").into())
    })?;
    let node = network
        .nodes
        .get(board.node)
        .ok_or_else(|| Failure::Input(Diagnostic::file(path, "no such node").into()))?;
    let limits = pabctl::limits::apply(board, overrides).map_err(|errors| {
        Failure::Input(Diagnostics(
            errors
                .into_iter()
                .map(|e| Diagnostic::file(path, format!("{}: {e}", node.name)))
                .collect(),
        ))
    })?;
    for line in pabctl::limits::describe(board, &limits) {
        println!("{}: {line}", node.name);
    }
    let Some(iface) = iface else {
        println!(
            "{}: within the table's limits (dry run: nothing sent)",
            node.name
        );
        return Ok(());
    };
    let framing = super::framing_on(&network, framing);
    let mut bus = bus::open_with(iface, framing).map_err(|e| Failure::Bus(e.to_string()))?;
    let mut client = match key {
        Some(key) => pabctl::client::Client::with_key(bus.as_mut(), node.id, key),
        None => pabctl::client::Client::new(bus.as_mut(), node.id),
    };
    match client.set_limits(&limits) {
        Ok(_) => {
            println!("{}: limits in force from its next tick", node.name);
            Ok(())
        }
        Err(error) => Err(Failure::Bus(format!("{}: {error}", node.name))),
    }
}

/// A CSV field, quoted when it holds a comma or a quote.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
