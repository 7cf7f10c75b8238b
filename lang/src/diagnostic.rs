//! Errors that point into a file: `path:line:column: error: cause`, the form editors jump to,
//! and, rendered for a person ([`Diagnostic::render`]), the line it points at with a caret under
//! the cause, as rustc and cargo show theirs.

use std::fmt;
use std::fmt::Write as _;
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::shown;

/// A text file with its name, to turn byte offsets into lines and columns.
#[derive(Clone, Debug)]
pub struct Source {
    path: PathBuf,
    text: String,
    /// The byte offset of each line's start: a position is a binary search, not a scan from the
    /// file's start (10 000 errors in a 500 KB file took seconds that way).
    line_starts: Vec<usize>,
}

impl Source {
    /// A source named `path` holding `text`. Costs one pass over the text.
    pub fn new(path: impl Into<PathBuf>, text: impl Into<String>) -> Self {
        let text = text.into();
        let line_starts = std::iter::once(0)
            .chain(text.match_indices('\n').map(|(at, _)| at + 1))
            .collect();
        Source {
            path: path.into(),
            text,
            line_starts,
        }
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
        // The lines that start at or before `offset`; the first always does.
        let line = self
            .line_starts
            .partition_point(|&start| start <= offset)
            .max(1);
        let line_start = self.line_starts.get(line - 1).copied().unwrap_or(0);
        let column = self
            .text
            .get(line_start..offset)
            .map_or(0, |s| s.chars().count())
            + 1;
        (line, column)
    }

    /// A diagnostic at byte range `span` of this file, with the line it starts on.
    pub fn error(&self, span: Range<usize>, message: impl Into<String>) -> Diagnostic {
        let (line, column) = self.line_column(span.start);
        let start = span.start.min(self.text.len());
        let line_start = self
            .text
            .get(..start)
            .and_then(|t| t.rfind('\n'))
            .map_or(0, |n| n + 1);
        let line_end = self
            .text
            .get(start..)
            .and_then(|t| t.find('\n'))
            .map_or(self.text.len(), |n| start + n);
        let text = self.text.get(line_start..line_end).unwrap_or("");
        let text = text.trim_end_matches('\r');
        // The caret runs under the span, or to the line's end when the span goes further.
        let end = span.end.clamp(start, line_end);
        let width = self
            .text
            .get(start..end)
            .map_or(1, |t| t.chars().count())
            .max(1);
        // A long line (a generated file, a value nested 100 000 deep) is shown around the
        // caret only: SNIPPET_BEFORE characters before it, SNIPPET_CHARS in all.
        let caret = column - 1;
        let first = caret.saturating_sub(SNIPPET_BEFORE);
        let total = text.chars().count();
        let mut shown: String = text.chars().skip(first).take(SNIPPET_CHARS).collect();
        let mut at = caret - first;
        if first > 0 {
            shown.insert(0, '…');
            at += 1;
        }
        if first + SNIPPET_CHARS < total {
            shown.push('…');
        }
        let width = width
            .min(SNIPPET_CHARS.saturating_sub(caret - first))
            .max(1);
        Diagnostic {
            path: self.path.clone(),
            position: Some((line, column)),
            message: message.into(),
            snippet: Some(Snippet {
                text: shown,
                caret: at,
                width,
            }),
        }
    }
}

/// Characters of a long line shown before the caret.
const SNIPPET_BEFORE: usize = 40;
/// Characters of a long line shown in all.
const SNIPPET_CHARS: usize = 100;

/// The line a [`Diagnostic`] points at, for [`Diagnostic::render`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Snippet {
    /// The line, without its end (around the caret only, with `…`, when it is long).
    pub text: String,
    /// How many characters of `text` come before the caret.
    pub caret: usize,
    /// How many characters the caret underlines (at least 1).
    pub width: usize,
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
    /// The line it points at, when the diagnostic came from a [`Source`].
    pub snippet: Option<Snippet>,
}

impl Diagnostic {
    /// An error about a whole file (it cannot be read, say).
    pub fn file(path: &Path, message: impl Into<String>) -> Self {
        Diagnostic {
            path: path.to_path_buf(),
            position: None,
            message: message.into(),
            snippet: None,
        }
    }

    /// An error at a line and column of `path`, without its line's text (a capture's line,
    /// say, whose text is the message's business).
    pub fn at(path: &Path, line: usize, column: usize, message: impl Into<String>) -> Self {
        Diagnostic {
            path: path.to_path_buf(),
            position: Some((line, column)),
            message: message.into(),
            snippet: None,
        }
    }

    /// For a person: the one-line form ([`fmt::Display`]), then the line it points at with a
    /// caret under the cause, as rustc shows its errors; `error` in bold red when `color` (a
    /// terminal). Control characters of the file's line are escaped like the message's.
    pub fn render(&self, color: bool) -> String {
        render(
            &self.to_string(),
            "error",
            self.position,
            self.snippet.as_ref(),
            color,
        )
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

/// The most diagnostics [`Diagnostics::render`] shows: a person reads the first ones, fixes
/// their cause, and runs again.
pub const SHOWN: usize = 50;
/// The most diagnostics of one same message it shows (a cause repeated 10 000 times by a
/// generated file is one cause).
pub const SHOWN_ALIKE: usize = 3;

impl Diagnostics {
    /// The diagnostics [rendered](Diagnostic::render), a blank line after one that shows its
    /// line (a list of one-line diagnostics, a capture's say, stays a list): at most
    /// [`SHOWN_ALIKE`] with one same message and [`SHOWN`] in all, in order, then one line that
    /// counts the others by message, the most frequent first.
    pub fn render(&self, color: bool) -> String {
        let mut out = String::new();
        let mut alike: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
        // The messages not shown, in order of first appearance, with their counts.
        let mut hidden: Vec<(&str, usize)> = Vec::new();
        let mut shown = 0usize;
        let mut previous_snippet = false;
        for diagnostic in &self.0 {
            let seen = alike.entry(diagnostic.message.as_str()).or_insert(0);
            *seen += 1;
            if *seen > SHOWN_ALIKE || shown >= SHOWN {
                match hidden.iter_mut().find(|(m, _)| *m == diagnostic.message) {
                    Some((_, count)) => *count += 1,
                    None => hidden.push((&diagnostic.message, 1)),
                }
                continue;
            }
            if shown > 0 {
                out.push('\n');
                if previous_snippet {
                    out.push('\n');
                }
            }
            out.push_str(&diagnostic.render(color));
            previous_snippet = diagnostic.snippet.is_some();
            shown += 1;
        }
        if !hidden.is_empty() {
            let total: usize = hidden.iter().map(|(_, count)| count).sum();
            hidden.sort_by_key(|&(_, count)| std::cmp::Reverse(count));
            let most: Vec<String> = hidden
                .iter()
                .take(3)
                .map(|(message, count)| format!("{count} × {}", shown::escaped(message)))
                .collect();
            let others = hidden.len().saturating_sub(3);
            let _ = write!(
                out,
                "{}… {total} more error{} not shown: {}{}",
                if previous_snippet { "\n\n" } else { "\n" },
                if total == 1 { "" } else { "s" },
                most.join("; "),
                match others {
                    0 => String::new(),
                    1 => "; 1 other message".to_string(),
                    n => format!("; {n} other messages"),
                }
            );
        }
        out
    }
}

/// `first` (a diagnostic's one-line form), its `level` word coloured on a terminal, then the
/// snippet: a gutter as wide as the line number, the line, and the caret.
fn render(
    first: &str,
    level: &str,
    position: Option<(usize, usize)>,
    snippet: Option<&Snippet>,
    color: bool,
) -> String {
    let marker = format!(": {level}: ");
    let mut out = match (color, first.find(&marker)) {
        (true, Some(at)) => {
            let colour = if level == "error" { "31" } else { "33" };
            format!(
                "{}: \x1b[1;{colour}m{level}\x1b[0m: \x1b[1m{}\x1b[0m",
                first.get(..at).unwrap_or(""),
                first.get(at + marker.len()..).unwrap_or("")
            )
        }
        _ => first.to_string(),
    };
    let (Some((line, _)), Some(snippet)) = (position, snippet) else {
        return out;
    };
    let number = line.to_string();
    let gutter = " ".repeat(number.len());
    let text = shown::escaped(&snippet.text);
    // The caret's column counts the escaped line's characters before it.
    let before: String = snippet.text.chars().take(snippet.caret).collect();
    let indent = shown::escaped(&before).chars().count();
    let (on, off) = if color {
        ("\x1b[1;34m", "\x1b[0m")
    } else {
        ("", "")
    };
    let caret = if color && level == "error" {
        format!("\x1b[1;31m{}\x1b[0m", "^".repeat(snippet.width))
    } else {
        "^".repeat(snippet.width)
    };
    out.push_str(&format!(
        "\n{on}{gutter} |{off}\n{on}{number} |{off} {text}\n{on}{gutter} |{off} {}{caret}",
        " ".repeat(indent)
    ));
    out
}

/// The candidate nearest to `name` by edit distance, if near enough to be a slip of the hand
/// (at most one edit in four characters, and at least one): for "did you mean `tc`?".
pub fn did_you_mean<'a>(
    name: &str,
    candidates: impl IntoIterator<Item = &'a str>,
) -> Option<&'a str> {
    let most = (name.chars().count() / 4).max(1);
    candidates
        .into_iter()
        .filter(|candidate| *candidate != name)
        .map(|candidate| (distance(name, candidate), candidate))
        .filter(|(d, _)| *d <= most)
        .min_by_key(|(d, _)| *d)
        .map(|(_, candidate)| candidate)
}

/// Levenshtein distance, case-insensitive (a key typed `TC` is `tc` mistyped).
fn distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.to_lowercase().chars().collect();
    let b: Vec<char> = b.to_lowercase().chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.iter().enumerate() {
        let mut previous = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let substitution = previous + usize::from(ca != cb);
            previous = row[j + 1];
            row[j + 1] = substitution.min(previous + 1).min(row[j] + 1);
        }
    }
    row[b.len()]
}

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

impl Warning {
    /// For a person, as [`Diagnostic::render`] with `warning`.
    pub fn render(&self, color: bool) -> String {
        render(
            &self.to_string(),
            "warning",
            self.0.position,
            self.0.snippet.as_ref(),
            color,
        )
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
    fn a_cause_repeated_is_shown_three_times_and_at_most_fifty_in_all() {
        let source = Source::new("net.toml", "a = 1\n".repeat(200));
        let alike: Vec<Diagnostic> = (0..100)
            .map(|line| source.error(6 * line..6 * line + 1, "the same cause"))
            .collect();
        let text = Diagnostics(alike).render(false);
        assert_eq!(text.matches("error: the same cause").count(), 3, "{text}");
        assert!(
            text.ends_with("\n\n… 97 more errors not shown: 97 × the same cause"),
            "{text}"
        );
        let distinct: Vec<Diagnostic> = (0..60)
            .map(|line| source.error(6 * line..6 * line + 1, format!("cause {line}")))
            .collect();
        let text = Diagnostics(distinct).render(false);
        assert_eq!(text.matches(": error: cause").count(), SHOWN, "{text}");
        assert!(text.contains("net.toml:50:1: error: cause 49"), "{text}");
        assert!(
            text.ends_with("… 10 more errors not shown: 1 × cause 50; 1 × cause 51; 1 × cause 52; 7 other messages"),
            "{text}"
        );
        // Fewer than the limits: every one, nothing counted.
        let few = Diagnostics(vec![source.error(0..1, "one"), source.error(6..7, "two")]);
        assert!(!few.render(false).contains("not shown"));
    }

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
    fn a_rendered_error_shows_its_line_and_a_caret_under_the_cause() {
        let source = Source::new("net.toml", "[connections.A]\ntcc = 3.0\n");
        let error = source.error(16..19, "unknown key `tcc`");
        assert_eq!(
            error.render(false),
            "net.toml:2:1: error: unknown key `tcc`\n  |\n2 | tcc = 3.0\n  | ^^^"
        );
        // In colour, the same text with escapes around `error`, the message and the caret.
        let coloured = error.render(true);
        assert!(coloured.contains("\x1b[1;31merror\x1b[0m"), "{coloured:?}");
        assert!(coloured.contains("\x1b[1;31m^^^\x1b[0m"), "{coloured:?}");
        // A caret after a control character of the line lands under the cause still.
        let source = Source::new("net.toml", "a\u{7} = x\n");
        let error = source.error(5..6, "bad");
        assert_eq!(
            error.render(false),
            "net.toml:1:6: error: bad\n  |\n1 | a\\u{7} = x\n  |          ^"
        );
        // A long line is shown around the caret.
        let long = format!("x = [{}]\n", "1, ".repeat(1000));
        let source = Source::new("net.toml", long.as_str());
        let error = source.error(2000..2001, "here");
        let rendered = error.render(false);
        assert!(rendered.len() < 400, "{rendered}");
        assert!(rendered.contains("1 | …"), "{rendered}");
        // A file error has no line to show.
        let error = Diagnostic::file(Path::new("net.toml"), "cannot read");
        assert_eq!(error.render(false), "net.toml: error: cannot read");
    }

    #[test]
    fn did_you_mean_offers_the_nearest_name_within_a_slip() {
        let keys = ["topic", "port", "st", "tc", "tr", "rule"];
        assert_eq!(did_you_mean("tcc", keys), Some("tc"));
        assert_eq!(did_you_mean("TC", keys), Some("tc"));
        assert_eq!(did_you_mean("rulez", keys), Some("rule"));
        assert_eq!(did_you_mean("topc", keys), Some("topic"));
        assert_eq!(did_you_mean("velocity", keys), None);
        assert_eq!(
            did_you_mean("tc", ["tc"]),
            None,
            "a name is not its own suggestion"
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
