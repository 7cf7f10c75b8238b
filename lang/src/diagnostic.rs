//! Errors that point into a file: `path:line:column: error: cause`, the form editors jump to.

use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::shown;

/// A text file with its name, to turn byte offsets into lines and columns.
#[derive(Clone, Debug)]
pub struct Source {
    path: PathBuf,
    text: String,
}

impl Source {
    /// A source named `path` holding `text`.
    pub fn new(path: impl Into<PathBuf>, text: impl Into<String>) -> Self {
        Source {
            path: path.into(),
            text: text.into(),
        }
    }

    /// Reads a file.
    pub fn read(path: &Path) -> Result<Self, Diagnostic> {
        std::fs::read_to_string(path)
            .map(|text| Source::new(path, text))
            .map_err(|error| Diagnostic::file(path, format!("cannot read: {error}")))
    }

    /// The file's path as given.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file's text.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// 1-based line and column (in characters) of byte `offset`.
    pub fn line_column(&self, offset: usize) -> (usize, usize) {
        let offset = offset.min(self.text.len());
        let before = self.text.get(..offset).unwrap_or("");
        let line = before.matches('\n').count() + 1;
        let line_start = before.rfind('\n').map_or(0, |newline| newline + 1);
        let column = before.get(line_start..).map_or(0, |s| s.chars().count()) + 1;
        (line, column)
    }

    /// A diagnostic at byte range `span` of this file.
    pub fn error(&self, span: Range<usize>, message: impl Into<String>) -> Diagnostic {
        let (line, column) = self.line_column(span.start);
        Diagnostic {
            path: self.path.clone(),
            position: Some((line, column)),
            message: message.into(),
        }
    }
}

/// One error, located in a file (and, when known, at a line and column).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostic {
    /// The file.
    pub path: PathBuf,
    /// 1-based line and column.
    pub position: Option<(usize, usize)>,
    /// What is wrong, in a sentence.
    pub message: String,
}

impl Diagnostic {
    /// An error about a whole file (it cannot be read, say).
    pub fn file(path: &Path, message: impl Into<String>) -> Self {
        Diagnostic {
            path: path.to_path_buf(),
            position: None,
            message: message.into(),
        }
    }

    /// The line, if known.
    pub fn line(&self) -> Option<usize> {
        self.position.map(|(line, _)| line)
    }
}

/// Written on one line, with the control characters of the path and the message escaped
/// ([`crate::shown`]): a message quotes what the file says, and a file may say anything.
impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let path = shown::escaped(&self.path.display().to_string());
        let message = shown::escaped(&self.message);
        match self.position {
            Some((line, column)) => write!(f, "{path}:{line}:{column}: error: {message}"),
            None => write!(f, "{path}: error: {message}"),
        }
    }
}

impl std::error::Error for Diagnostic {}

/// Several diagnostics, reported together so that one run shows every mistake in a file.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Diagnostics(pub Vec<Diagnostic>);

impl fmt::Display for Diagnostics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (index, diagnostic) in self.0.iter().enumerate() {
            if index > 0 {
                writeln!(f)?;
            }
            write!(f, "{diagnostic}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Diagnostics {}

impl From<Diagnostic> for Diagnostics {
    fn from(diagnostic: Diagnostic) -> Self {
        Diagnostics(vec![diagnostic])
    }
}

/// A warning: located like a [`Diagnostic`] and written `path:line:column: warning: cause`. It
/// says that something will not behave as the file probably means; it fails nothing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Warning(pub Diagnostic);

impl Warning {
    /// The line, if known.
    pub fn line(&self) -> Option<usize> {
        self.0.line()
    }
}

/// As a [`Diagnostic`], with `warning` for `error`.
impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let path = shown::escaped(&self.0.path.display().to_string());
        let message = shown::escaped(&self.0.message);
        match self.0.position {
            Some((line, column)) => write!(f, "{path}:{line}:{column}: warning: {message}"),
            None => write!(f, "{path}: warning: {message}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_become_lines_and_columns() {
        let source = Source::new("net.toml", "a = 1\nbé = 2\n");
        assert_eq!(source.line_column(0), (1, 1));
        assert_eq!(source.line_column(6), (2, 1));
        // Columns count characters, not bytes: "bé" is three bytes.
        assert_eq!(source.line_column(10), (2, 4));
        let error = source.error(6..8, "bad");
        assert_eq!(error.to_string(), "net.toml:2:1: error: bad");
        let error = source.error(6..8, "name `a\u{1b}[2J\nb`");
        assert_eq!(
            error.to_string(),
            "net.toml:2:1: error: name `a\\u{1b}[2J\\nb`"
        );
    }

    #[test]
    fn warnings_read_like_errors() {
        let source = Source::new("net.toml", "a = 1\nb = 2\n");
        let warning = Warning(source.error(6..7, "odd\u{7}"));
        assert_eq!(warning.line(), Some(2));
        assert_eq!(warning.to_string(), "net.toml:2:1: warning: odd\\u{7}");
    }
}
