//! What every command shares in writing its results: output files (refused before a run when
//! they cannot be written, written atomically), the line printers that leave standard output to
//! the JSON, diagnostics' colour, progress bars and plurals.

use std::fs;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use pab_lang::diagnostic::{Diagnostic, Diagnostics};
use pabctl::plot;

use crate::failure::Failure;

/// Whether diagnostics get colour: on a terminal only, and never with `NO_COLOR` set
/// (no-color.org), so that logs and pipes get plain text.
pub fn colour() -> bool {
    use std::io::IsTerminal;
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none()
}

pub fn println_line(line: String) {
    println!("{line}");
}

pub fn eprintln_line(line: String) {
    eprintln!("{line}");
}

/// Refuses, before a run rather than after it, the output files that could not be written as
/// asked: a plot that is neither a `.png` nor a `.svg`, the formats drawn (exit 2, with every such mistake),
/// or a file in a directory that does not exist (exit 3, as any output that cannot be written).
/// Each `(flag, path, is_plot)`.
pub fn refuse_unwritable(outputs: &[(&str, Option<&Path>, bool)]) -> Result<(), Failure> {
    let mut invalid = Vec::new();
    let mut unwritable = Vec::new();
    for &(flag, output, is_plot) in outputs {
        let Some(output) = output else { continue };
        if is_plot && plot::Format::of(output).is_none() {
            invalid.push(Diagnostic::file(
                output,
                format!(
                    "{flag}: plots are drawn as PNG or SVG: give a file name ending in {}",
                    plot::EXTENSIONS
                ),
            ));
        }
        let parent = output.parent().filter(|p| !p.as_os_str().is_empty());
        if let Some(parent) = parent.filter(|p| !p.is_dir()) {
            unwritable.push(format!(
                "cannot write {} ({flag}): the directory {} does not exist (create it first)",
                output.display(),
                parent.display()
            ));
        }
    }
    if !invalid.is_empty() {
        return Err(Failure::Input(Diagnostics(invalid)));
    }
    if !unwritable.is_empty() {
        return Err(Failure::Output(unwritable.join("\n")));
    }
    Ok(())
}

/// Writes `bytes` to a temporary file beside `path`, then renames it: a failure never leaves a
/// half-written file where a good one was.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), Failure> {
    let fail =
        |error: io::Error| Failure::Output(format!("cannot write {}: {error}", path.display()));
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        fs::create_dir_all(parent).map_err(fail)?;
    }
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".part");
    let temporary = PathBuf::from(temporary);
    let mut file = BufWriter::new(fs::File::create(&temporary).map_err(fail)?);
    file.write_all(bytes).map_err(fail)?;
    file.into_inner()
        .map_err(|error| fail(error.into_error()))?
        .sync_all()
        .map_err(fail)?;
    fs::rename(&temporary, path).map_err(fail)
}

/// A progress bar on standard error, drawn only when it is a terminal (indicatif's rule), for
/// long captures.
pub fn progress_bar(total: u64, template: &str) -> ProgressBar {
    ProgressBar::new(total).with_style(
        ProgressStyle::with_template(&format!("{{bar:30}} {template}"))
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    )
}

pub fn plural(count: usize) -> &'static str {
    if count == 1 { "" } else { "s" }
}
