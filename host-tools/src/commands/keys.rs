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

/// The key page image: the node key's record (erased without `key`) and, with `update_key`,
/// the update key's record at its offset (pab_core::update::stored).
pub fn keypage(
    key: Option<&Path>,
    update_key: Option<[u8; 32]>,
    output: &Path,
) -> Result<(), Failure> {
    use pab_core::update::stored::{KEY_RECORD_LEN, KEY_RECORD_OFFSET, encode_key};
    let node = match key {
        Some(key) => {
            let parsed = pabctl::keys::read(key)
                .map_err(|message| Failure::Input(Diagnostic::file(key, message).into()))?;
            Some(pabctl::keys::page_image(&parsed))
        }
        None => None,
    };
    let update = update_key;
    let record = pab_core::auth::page::LEN;
    let mut page = match (&node, &update) {
        (_, Some(_)) => vec![0xFF; KEY_RECORD_OFFSET + KEY_RECORD_LEN],
        (Some(_), None) => vec![0xFF; record],
        // clap requires one of them.
        (None, None) => vec![0xFF; record],
    };
    if let Some(node) = node {
        page[..record].copy_from_slice(&node);
    }
    if let Some(public) = update {
        page[KEY_RECORD_OFFSET..].copy_from_slice(&encode_key(&public));
    }
    write_atomically(output, &page)?;
    let parts = match (key.is_some(), update_key.is_some()) {
        (true, true) => "the node key's record and the update key's",
        (true, false) => "the node key's record",
        _ => "the update key's record (no node key: the node stays unkeyed)",
    };
    println!(
        "{}: key page written ({} bytes: {parts})",
        output.display(),
        page.len()
    );
    Ok(())
}
