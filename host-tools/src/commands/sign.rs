//! `pabctl sign`: a firmware image signed for the boards of one kind (pabctl's `signing`).

use std::path::Path;

use pab_core::update::{OVERHEAD, SignedImage};
use pab_lang::diagnostic::Diagnostic;
use pabctl::signing::{self, Signed};

use crate::failure::Failure;
use crate::output::write_atomically;

/// The largest firmware image read: 16 MiB, more than any board's flash.
const MAX_IMAGE: u64 = 16 << 20;

pub fn run(key: &Path, firmware: &Path, output: &Path, signed: Signed) -> Result<(), Failure> {
    if same_file(firmware, output) {
        return Err(Failure::Output(format!(
            "--output {}: the input itself; the signed image goes to a file of its own",
            output.display()
        )));
    }
    let signing_key = signing::read_key(key)
        .map_err(|message| Failure::Input(Diagnostic::file(key, message).into()))?;
    pab_lang::input::regular_file(firmware, "firmware image", MAX_IMAGE)
        .map_err(|diagnostic| Failure::Input(diagnostic.into()))?;
    let image = std::fs::read(firmware).map_err(|error| {
        Failure::Input(Diagnostic::file(firmware, format!("cannot read it: {error}")).into())
    })?;
    if image.is_empty() {
        return Err(Failure::Input(
            Diagnostic::file(firmware, "empty: nothing to sign").into(),
        ));
    }
    let bytes = signing::sign(&signing_key, &image, signed).map_err(Failure::Output)?;
    // What is written reads back as what was meant (the layout is pab-core's).
    let parsed =
        SignedImage::parse(&bytes).map_err(|refusal| Failure::Output(refusal.to_string()))?;
    write_atomically(output, &bytes)?;
    let trailer = parsed.trailer;
    let [major, minor, patch] = trailer.firmware.version;
    let board = String::from_utf8_lossy(&trailer.firmware.name);
    println!(
        "{}: {} bytes of {} signed as {} {major}.{minor}.{patch}, build {}{}; {} bytes with \
         trailer and signature; public key {}",
        output.display(),
        parsed.image().len(),
        firmware.display(),
        board.trim_end_matches('\0'),
        signing::hex(&trailer.firmware.build),
        if trailer.downgrade {
            ", downgrade allowed"
        } else {
            ""
        },
        parsed.image().len() + OVERHEAD,
        signing::hex(&signing_key.verifying_key().to_bytes()),
    );
    Ok(())
}

/// Whether `a` and `b` name the same existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}
