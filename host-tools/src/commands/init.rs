//! `pabctl init`: a starter network file, the tutorial's or one of the examples.

use std::path::Path;

use pab_lang::diagnostic::Diagnostic;

use crate::failure::Failure;

pub fn run(file: &Path, example: Option<&str>) -> Result<(), Failure> {
    let name = example.unwrap_or(pabctl::starter::DEFAULT);
    let text = pabctl::starter::find(name).map_err(|message| {
        Failure::Input(Diagnostic::file(Path::new("--example"), message).into())
    })?;
    // create_new: a file that is there, whoever wrote it, is never replaced.
    let mut out = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(file)
        .map_err(|error| match error.kind() {
            std::io::ErrorKind::AlreadyExists => format!(
                "{}: already exists; pabctl init never overwrites a file (give another name)",
                file.display()
            ),
            _ => format!("{}: cannot create: {error}", file.display()),
        })
        .map_err(Failure::Output)?;
    use std::io::Write as _;
    out.write_all(text.as_bytes())
        .map_err(|error| Failure::Output(format!("{}: {error}", file.display())))?;
    let what = if example.is_some() {
        format!("the example `{name}`")
    } else {
        "the tutorial's network (docs/tutorial.md)".to_string()
    };
    println!("{}: {what} written; next: pabctl check {0}", file.display());
    Ok(())
}
