//! `pabctl schema`: the network file's JSON Schema, on standard output.

use std::io::{self, Write};

use crate::failure::Failure;

pub fn run() -> Result<(), Failure> {
    io::stdout()
        .write_all(pab_lang::network::json_schema().as_bytes())
        .map_err(|error| Failure::Output(format!("standard output: {error}")))
}
