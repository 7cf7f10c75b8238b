//! `pabctl solve`: HBBA's intention solver on a set of desires.

use std::path::Path;

use pab_lang::diagnostic::Diagnostic;
use pab_lang::network::Network;

use crate::failure::Failure;

pub fn run(path: &Path, desires: &str, json: bool) -> Result<(), Failure> {
    let network = Network::load(path)?;
    let input = |message: String| Failure::Input(Diagnostic::file(path, message).into());
    let Some(hbba) = &network.hbba else {
        return Err(input(
            "no [hbba] section: `solve` needs resources and strategies (docs/network-file.md)"
                .into(),
        ));
    };
    let intensities = hbba
        .intensities(desires)
        .map_err(|message| input(format!("--desires: {message}")))?;
    let solved = hbba
        .solve(&intensities, pab_core::hbba::DEFAULT_BUDGET)
        .map_err(|error| input(error.to_string()))?;
    if json {
        println!("{}", pabctl::solve::json(hbba, &solved));
    } else {
        print!("{}", pabctl::solve::report(hbba, &intensities, &solved));
    }
    Ok(())
}
