//! `pabctl`: check, compile and simulate port-arbitration networks; push tables to the nodes on a
//! CAN bus, list them, monitor them.
//!
//! This file parses the command line ([`cli`]), runs the command ([`commands`]: one module per
//! command or family) and turns its [`failure`] into the exit status; [`output`] is what the
//! commands share in writing their results.

mod cli;
mod commands;
mod failure;
mod output;

use std::process::ExitCode;

use clap::Parser;

use cli::{Cli, Command};
use output::{eprintln_line, println_line};

/// A reader that goes away (`pabctl sim NET.toml | head`) ends pabctl quietly, as it ends any
/// Unix tool. Rust's runtime ignores SIGPIPE, which turns the next write to the closed pipe into
/// an error that `println!` reports as a panic.
fn restore_sigpipe() {
    // SAFETY: called first thing in `main`, before any other thread exists; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn main() -> ExitCode {
    restore_sigpipe();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check {
            network,
            json,
            bitrate,
            data_bitrate,
        } => commands::check::run(&network, json, bitrate, data_bitrate),
        Command::Compile {
            network,
            output,
            table_version,
            json,
        } => commands::compile::run(&network, &output, table_version, json),
        Command::Sim {
            network,
            until,
            trace,
            plot,
            candump,
            timed_bus,
            dynamics_trace,
            schema_trace,
            schema_plot,
            schema_program,
            from,
            json,
        } => commands::sim::run(
            &network,
            until,
            trace.as_deref(),
            plot.as_deref(),
            candump.as_deref(),
            dynamics_trace.as_deref(),
            timed_bus,
            json,
        )
        .and_then(|schema_only| {
            // A file with a schema server and no port: its plot is the schema server's.
            let schema_plot = schema_plot.or(if schema_only { plot } else { None });
            commands::sim::run_schema(
                &network,
                from,
                until,
                schema_trace.as_deref(),
                schema_plot.as_deref(),
                schema_program.as_deref(),
                if json { eprintln_line } else { println_line },
            )
        }),
        Command::Replay {
            network,
            capture,
            trace,
            plot,
            records,
            board_job,
            timed_bus,
            json,
        } => commands::replay::run(
            &network,
            &capture,
            trace.as_deref(),
            plot.as_deref(),
            records.as_deref(),
            board_job.as_deref(),
            timed_bus,
            json,
        ),
        Command::Push {
            network,
            iface,
            node,
            table_version,
            key,
            replace,
            fd,
        } => commands::push::run(
            &network,
            &iface,
            node.as_deref(),
            table_version,
            key.as_deref(),
            replace,
            commands::framing(fd),
        ),
        Command::Plant {
            network,
            iface,
            duration,
            period_ms,
            log,
        } => commands::schema_server::plant(&network, &iface, duration, period_ms, log.as_deref()),
        Command::Run {
            network,
            iface,
            timeout,
            trace,
            key,
            fd,
        } => commands::schema_server::run(
            &network,
            &iface,
            timeout,
            trace.as_deref(),
            key.as_deref(),
            commands::framing(fd),
        ),
        Command::Limits {
            network,
            iface,
            key,
            overrides,
            dry_run,
            fd,
        } => {
            let iface = if dry_run { None } else { iface };
            commands::schema_server::limits(
                &network,
                iface.as_deref(),
                key.as_deref(),
                &overrides,
                commands::framing(fd),
            )
        }
        Command::Init { file, example } => commands::init::run(&file, example.as_deref()),
        Command::Keygen { output, signing } => {
            if signing {
                commands::keys::keygen_signing(&output)
            } else {
                commands::keys::keygen(&output)
            }
        }
        Command::Sign {
            key,
            firmware,
            output,
            board,
            version,
            build,
            downgrade,
        } => commands::sign::run(
            &key,
            &firmware,
            &output,
            pabctl::signing::Signed {
                firmware: pab_core::identity::Firmware {
                    name: board,
                    version,
                    build,
                },
                downgrade,
            },
        ),
        Command::Flash {
            firmware,
            iface,
            node,
            network,
            key,
            restart_timeout,
            fd,
        } => commands::flash::run(
            &firmware,
            &iface,
            &node,
            network.as_deref(),
            key.as_deref(),
            restart_timeout,
            commands::framing(fd),
        ),
        Command::Keypage {
            key,
            update_key,
            output,
        } => commands::keys::keypage(key.as_deref(), update_key, &output),
        Command::Nodes {
            iface,
            network,
            listen,
            json,
        } => commands::nodes::run(&iface, network.as_deref(), listen, json),
        Command::Assign {
            iface,
            uid,
            node_id,
            key,
        } => commands::nodes::assign(&iface, &uid, node_id, key.as_deref()),
        Command::Config {
            iface,
            node,
            bitrate,
            key,
        } => commands::nodes::configure(&iface, node, bitrate, key.as_deref()),
        Command::Monitor {
            network,
            iface,
            rate,
            duration,
            plain,
            key,
        } => commands::monitor::run(&network, &iface, rate, duration, plain, key.as_deref()),
        Command::Dbc {
            network,
            output,
            claims_from,
        } => commands::dbc::run(&network, &output, claims_from.as_deref()),
        Command::Schema => commands::schema::run(),
        Command::Solve {
            network,
            desires,
            json,
        } => commands::solve::run(&network, &desires, json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => failure.report(),
    }
}
