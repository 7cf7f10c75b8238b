//! `pabctl keygen` and `pabctl keypage`: a node's key file, and a board's key page from it;
//! `pabctl keygen --signing`: a firmware signing key.

use std::path::Path;

use pab_lang::diagnostic::Diagnostic;

use crate::failure::Failure;
use crate::output::write_atomically;

pub fn keygen(output: &Path) -> Result<(), Failure> {
    let key = pabctl::keys::generate().map_err(Failure::Output)?;
    pabctl::keys::write_new(output, &key).map_err(Failure::Output)?;
    println!("{}: new key written (mode 0600)", output.display());
    Ok(())
}

pub fn keygen_signing(output: &Path) -> Result<(), Failure> {
    let key = pabctl::signing::generate().map_err(Failure::Output)?;
    pabctl::signing::write_new(output, &key).map_err(Failure::Output)?;
    println!("{}: new signing key written (mode 0600)", output.display());
    println!(
        "public key: {}",
        pabctl::signing::hex(&key.verifying_key().to_bytes())
    );
    Ok(())
}

pub fn keypage(key: &Path, output: &Path) -> Result<(), Failure> {
    let parsed = pabctl::keys::read(key)
        .map_err(|message| Failure::Input(Diagnostic::file(key, message).into()))?;
    write_atomically(output, &pabctl::keys::page_image(&parsed))?;
    println!("{}: key page record written (32 bytes)", output.display());
    Ok(())
}
