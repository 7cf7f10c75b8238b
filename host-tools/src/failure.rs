//! How a command fails: [`Failure`], what each kind of failure prints on standard error, and the
//! exit status it ends pabctl with (the statuses `pabctl --help` lists).

use std::process::ExitCode;

use pab_lang::diagnostic::{Diagnostic, Diagnostics};

use crate::output::colour;

/// How a command failed, and the exit status that says so.
pub enum Failure {
    Inconsistent(Vec<Diagnostic>),
    /// A frame stream can miss its deadline on the bus, or the bus is overloaded (exit status 1,
    /// like a verdict).
    Deadlines(Vec<Diagnostic>),
    Input(Diagnostics),
    Output(String),
    Bus(String),
    /// A live schema server stopped on a safety event (exit status 1, like a verdict).
    Stopped(String),
    /// A latency measured on the simulator's timed bus exceeds its stream's worst-case response
    /// time (exit status 1, like a verdict: the analysis or the simulator is wrong).
    Latencies(Vec<Diagnostic>),
}

impl From<Diagnostics> for Failure {
    fn from(diagnostics: Diagnostics) -> Self {
        Failure::Input(diagnostics)
    }
}

impl Failure {
    /// Prints the failure on standard error and returns its exit status.
    pub fn report(self) -> ExitCode {
        match self {
            Failure::Inconsistent(errors) => {
                // Capped like any list of errors: an inconsistent network of many nodes repeats
                // one counterexample per port and connection.
                let count = errors.len();
                eprintln!("{}\n", Diagnostics(errors).render(colour()));
                eprintln!(
                    "the rules are inconsistent: {count} error{}",
                    if count == 1 { "" } else { "s" }
                );
                ExitCode::from(1)
            }
            Failure::Deadlines(errors) => {
                let count = errors.len();
                eprintln!("{}\n", Diagnostics(errors).render(colour()));
                eprintln!(
                    "frames can miss their deadlines on the bus: {count} error{}",
                    if count == 1 { "" } else { "s" }
                );
                ExitCode::from(1)
            }
            Failure::Input(diagnostics) => {
                eprintln!("{}", diagnostics.render(colour()));
                if diagnostics.0.len() > 1 {
                    eprintln!("\n{} errors", diagnostics.0.len());
                }
                ExitCode::from(2)
            }
            Failure::Output(message) => {
                eprintln!("error: {message}");
                ExitCode::from(3)
            }
            Failure::Bus(message) => {
                eprintln!("error: {message}");
                ExitCode::from(4)
            }
            Failure::Stopped(message) => {
                eprintln!("{message}");
                ExitCode::from(1)
            }
            Failure::Latencies(errors) => {
                let count = errors.len();
                eprintln!("{}\n", Diagnostics(errors).render(colour()));
                eprintln!(
                    "latencies on the timed bus above their bounds: {count} error{}",
                    if count == 1 { "" } else { "s" }
                );
                ExitCode::from(1)
            }
        }
    }
}
