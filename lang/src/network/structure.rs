//! The file's structure, every mistake of it in one run.
//!
//! serde stops at a file's first structural mistake (an unknown key, a value of the wrong type, a
//! missing key). To report them all, as a compiler does, the file is read again without what was
//! wrong, up to [`MAX_ERRORS`] times: the mistaken key with its value (or a whole table, for an
//! unknown or incomplete one) is blanked with spaces, newlines kept, so every later span still
//! points into the file as written. serde's derive stays the only authority on what the file may
//! hold; this module only words its answers for a person: "did you mean" among the keys serde
//! expected, and what a value of the wrong type should have been, with its unit.
//!
//! A key that was blanked cannot also be reported missing (its table's "missing field" is its
//! consequence, not a mistake of its own), nor can the known key an unknown one is a slip of; and
//! a file with structural mistakes gets no semantic check: its meaning would be judged on a file
//! the author did not write, and every error that followed from a blanked key would be a cascade.

use std::ops::Range;

use serde::de::DeserializeOwned;

use crate::diagnostic::{Diagnostic, Diagnostics, Source, did_you_mean};

/// The most structural errors reported in one run: enough for every independent slip of a file,
/// few enough that a file of the wrong kind does not scroll the terminal away.
pub(crate) const MAX_ERRORS: usize = 20;

/// `T` read from `source`, or every structural error of it, in the file's order.
pub(crate) fn read<T: DeserializeOwned>(source: &Source) -> Result<T, Diagnostics> {
    let mut text = source.text().to_string();
    let mut errors: Vec<Diagnostic> = Vec::new();
    // Keys blanked so far: (name, where).
    let mut blanked: Vec<(String, usize)> = Vec::new();
    let mut last_span: Option<Range<usize>> = None;
    loop {
        let error = match toml::from_str::<T>(&text) {
            Ok(raw) if errors.is_empty() => return Ok(raw),
            Ok(_) => break,
            Err(error) => error,
        };
        let span = error.span().unwrap_or(0..0);
        let message = error.message().trim_end().to_string();
        // The same place again: blanking did not help (a syntax error the blank made, say).
        if last_span.as_ref() == Some(&span) {
            if errors.is_empty() {
                errors.push(source.error(span, message));
            }
            break;
        }
        last_span = Some(span.clone());
        let missing = quoted_after(&message, "missing field ");
        let cascade = missing.as_ref().is_some_and(|field| {
            blanked
                .iter()
                .any(|(name, at)| name == field && *at >= span.start)
        });
        if !cascade {
            errors.push(source.error(span.clone(), word(&message, source.text(), &span)));
        }
        if errors.len() >= MAX_ERRORS {
            break;
        }
        let blank = if missing.is_some() || is_header(source.text(), span.start) {
            table_extent(source.text(), span.start)
        } else {
            let extent = item_extent(source.text(), span.start);
            if let Some(key) = key_of_line(source.text(), span.start) {
                blanked.push((key, span.start));
            }
            // An unknown key that is a slip of a known one stood for it: that one is not
            // "missing" either.
            if let Some(near) = quoted_after(&message, "unknown field ")
                .and_then(|field| nearest_expected(&field, &message))
            {
                blanked.push((near, span.start));
            }
            extent
        };
        if blank.is_empty() {
            break;
        }
        blank_out(&mut text, blank);
    }
    errors.sort_by_key(|error| error.position);
    Err(Diagnostics(errors))
}

/// serde's message, for a person: the closest expected key or variant, and for a value of the
/// wrong type, what it should be and in which unit.
fn word(message: &str, text: &str, span: &Range<usize>) -> String {
    if let Some(field) = quoted_after(message, "unknown field ") {
        let expected = expected_names(message);
        let what = if is_header(text, span.start) && !text_before_header(text, span.start) {
            "section"
        } else {
            "key"
        };
        let hint = did_you_mean_hint(&field, message);
        return format!(
            "unknown {what} `{field}`{hint} (known here: {})",
            expected.join(", ")
        );
    }
    if let Some(variant) = quoted_after(message, "unknown variant ") {
        let expected = expected_names(message);
        let hint = did_you_mean_hint(&variant, message);
        return format!(
            "unknown value `{variant}`{hint} (one of: {})",
            expected.join(", ")
        );
    }
    if let Some(rest) = message.strip_prefix("invalid type: ") {
        let (found, expected) = rest.split_once(", expected ").unwrap_or((rest, ""));
        let key = key_of_line(text, span.start);
        let want = key
            .as_deref()
            .and_then(unit_of)
            .map(|(what, example)| format!("{what}: {example}"))
            .unwrap_or_else(|| plain(expected).to_string());
        let duration = found
            .strip_prefix("string \"")
            .and_then(|s| s.strip_suffix('"'))
            .and_then(seconds_in);
        let hint = match (key.as_deref().and_then(unit_of), duration) {
            (Some(("seconds, a number", _)), Some(seconds)) => {
                format!(" (durations here are numbers of seconds: {seconds})")
            }
            _ => String::new(),
        };
        return match key {
            Some(key) => format!("`{key}` is {want}, not {}{hint}", plain_found(found)),
            None => format!("expected {want}, found {}{hint}", plain_found(found)),
        };
    }
    if let Some(field) = quoted_after(message, "missing field ") {
        return format!("missing key `{field}`: this table needs it");
    }
    message.to_string()
}

/// The name among those serde's `message` expected that `name` is a slip of.
fn nearest_expected(name: &str, message: &str) -> Option<String> {
    let expected = expected_names(message);
    did_you_mean(name, expected.iter().map(String::as_str)).map(str::to_string)
}

/// "; did you mean `x`?" for [`nearest_expected`], or nothing.
fn did_you_mean_hint(name: &str, message: &str) -> String {
    nearest_expected(name, message)
        .map(|near| format!("; did you mean `{near}`?"))
        .unwrap_or_default()
}

/// What a key holds and an example, from its name: the file's units are in its keys' names
/// (`period_ms`, `rate_hz`) or, for the few in seconds, fixed by the language.
fn unit_of(key: &str) -> Option<(&'static str, &'static str)> {
    Some(match key {
        "tc" => ("seconds, a number", "tc = 0.5"),
        "tr" => ("seconds, a number", "tr = 0.5"),
        "period" => ("seconds, a number", "period = 0.5"),
        "step" => ("seconds, a number", "step = 0.001"),
        "from" => ("seconds, a number", "from = 1.0"),
        "to" => ("seconds, a number", "to = 5.0"),
        "timeout" => ("seconds, a number", "timeout = 0.2"),
        "at" => ("seconds, a number or a list of numbers", "at = [1.0, 1.5]"),
        "st" => ("a stimulation gain, a number in (0, 1]", "st = 0.2"),
        "id" => ("a node id, an integer 1 to 127", "id = 1"),
        "can_id" => ("a CAN identifier, an integer", "can_id = 0x120"),
        "mask" => ("a CAN identifier mask, an integer", "mask = 0x7F0"),
        "rule" => ("a rule, a string", "rule = \"A & !B\""),
        "topic" => ("a topic's name, a string", "topic = \"grasp\""),
        "port" => ("a port's name, a string", "port = \"hand.command\""),
        "node" => ("a node's name, a string", "node = \"arm\""),
        _ if key.ends_with("_ms") => ("milliseconds, a number", "period_ms = 5"),
        _ if key.ends_with("_hz") => ("hertz, a number", "rate_hz = 10.0"),
        _ if key.ends_with("_mm_s") => ("millimetres per second, a number", "speed_mm_s = 50"),
        _ if key.ends_with("_mm") => ("millimetres, a number", "clearance_mm = 0.05"),
        _ if key.ends_with("_rad_s") => ("radians per second, a number", "drive_rate_rad_s = 3"),
        _ if key.ends_with("_n") => ("newtons, a number", "contact_n = 3"),
        _ => return None,
    })
}

/// serde's type names as a person says them.
fn plain(expected: &str) -> &str {
    match expected {
        "f64" | "f32" => "a number",
        "i64" | "u64" | "i32" | "u32" | "u16" | "u8" | "i8" | "i16" => "an integer",
        "a boolean" | "bool" => "true or false",
        "a sequence" => "a list",
        "a map" => "a table",
        "struct" => "a table",
        other => other,
    }
}

fn plain_found(found: &str) -> String {
    if let Some(string) = found.strip_prefix("string ") {
        return format!("the string {string}");
    }
    match found {
        "sequence" => "a list".to_string(),
        "map" => "a table".to_string(),
        other => other
            .replace("floating point", "the number")
            .replace("integer", "the integer"),
    }
}

/// "500ms", "0.5 s", "2min" as seconds, for the hint of a duration written with its unit.
fn seconds_in(text: &str) -> Option<f64> {
    let text = text.trim();
    let split = text
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(text.len());
    let (number, unit) = text.split_at(split);
    let value: f64 = number.parse().ok()?;
    let scale = match unit.trim() {
        "s" | "sec" | "" => 1.0,
        "ms" => 1e-3,
        "us" | "µs" => 1e-6,
        "min" => 60.0,
        _ => return None,
    };
    Some(value * scale)
}

/// The name between backquotes right after `prefix` in `message`.
fn quoted_after(message: &str, prefix: &str) -> Option<String> {
    let rest = message.strip_prefix(prefix)?.strip_prefix('`')?;
    rest.split_once('`').map(|(name, _)| name.to_string())
}

/// The names serde lists after "expected" (`a`, `b` or `c`).
fn expected_names(message: &str) -> Vec<String> {
    let Some((_, list)) = message.split_once(", expected ") else {
        return Vec::new();
    };
    list.split('`')
        .enumerate()
        .filter(|(index, _)| index % 2 == 1)
        .map(|(_, name)| name.to_string())
        .collect()
}

fn line_start(text: &str, at: usize) -> usize {
    text.get(..at.min(text.len()))
        .and_then(|t| t.rfind('\n'))
        .map_or(0, |n| n + 1)
}

fn line_end(text: &str, at: usize) -> usize {
    let at = at.min(text.len());
    text.get(at..)
        .and_then(|t| t.find('\n'))
        .map_or(text.len(), |n| at + n)
}

/// Whether the line holding `at` is a table header (`[name]` or `[[name]]`).
fn is_header(text: &str, at: usize) -> bool {
    let start = line_start(text, at);
    text.get(start..)
        .is_some_and(|t| t.trim_start().starts_with('['))
}

/// Whether a header at `at` names a table inside another (`[nodes.arm]`) rather than a section
/// of the file (`[bogus]`): a dot before `at` on its line.
fn text_before_header(text: &str, at: usize) -> bool {
    let start = line_start(text, at);
    text.get(start..at).is_some_and(|t| t.contains('.'))
}

/// The key of the `key = value` line holding `at`, if it is one.
fn key_of_line(text: &str, at: usize) -> Option<String> {
    let start = line_start(text, at);
    let line = text.get(start..line_end(text, at))?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim().trim_matches('"');
    let key = key.rsplit('.').next().unwrap_or(key).trim();
    (!key.is_empty() && !key.starts_with('[')).then(|| key.to_string())
}

/// The `key = value` item whose line holds `at`: from the line's start to the value's end,
/// across lines for a multi-line list, inline table or string.
fn item_extent(text: &str, at: usize) -> Range<usize> {
    let start = line_start(text, at);
    let Some(equals) = text
        .get(start..)
        .and_then(|t| t.find('='))
        .map(|n| start + n)
    else {
        return start..line_end(text, at);
    };
    if equals > line_end(text, at) {
        return start..line_end(text, at);
    }
    start..value_end(text, equals + 1)
}

/// Where the value that starts after `from` ends: brackets and braces matched, strings skipped,
/// a comment ends the line.
fn value_end(text: &str, from: usize) -> usize {
    let bytes = text.as_bytes();
    let mut depth = 0usize;
    let mut index = from;
    while index < bytes.len() {
        match bytes[index] {
            b'"' | b'\'' => {
                let quote = bytes[index];
                let triple = text
                    .get(index..index + 3)
                    .is_some_and(|t| t.bytes().all(|b| b == quote));
                let close = if triple {
                    &text[index..index + 3]
                } else {
                    &text[index..index + 1]
                };
                let open = close.len();
                match text.get(index + open..).and_then(|t| {
                    if triple || quote == b'\'' {
                        t.find(close)
                    } else {
                        find_unescaped(t, '"')
                    }
                }) {
                    Some(n) => index += open + n + open,
                    None => return text.len(),
                }
                continue;
            }
            b'[' | b'{' => depth += 1,
            b']' | b'}' => depth = depth.saturating_sub(1),
            b'#' => {
                index = line_end(text, index);
                if depth == 0 {
                    return index;
                }
                continue;
            }
            b'\n' if depth == 0 => return index,
            _ => {}
        }
        index += 1;
    }
    text.len()
}

fn find_unescaped(text: &str, quote: char) -> Option<usize> {
    let mut escaped = false;
    for (index, c) in text.char_indices() {
        match c {
            '\\' if !escaped => escaped = true,
            c if c == quote && !escaped => return Some(index),
            _ => escaped = false,
        }
    }
    None
}

/// The table whose header or body holds `at`: from its header line to the next header, or from
/// the file's start for keys before any header.
fn table_extent(text: &str, at: usize) -> Range<usize> {
    let mut start = line_start(text, at);
    // Back to the header of the table holding `at`.
    while start > 0 && !is_header(text, start) {
        start = line_start(text, start - 1);
    }
    let mut end = line_end(text, at);
    while end < text.len() {
        let next = end + 1;
        if is_header(text, next) {
            break;
        }
        end = line_end(text, next);
    }
    start..end
}

/// Spaces over `range` of `text`, newlines kept (so every other span keeps its place).
fn blank_out(text: &mut String, range: Range<usize>) {
    let Some(part) = text.get(range.clone()) else {
        return;
    };
    // Same length in bytes: a multi-byte character becomes as many spaces as it had bytes.
    let blank: String = part
        .chars()
        .flat_map(|c| {
            let fill = if c == '\n' { '\n' } else { ' ' };
            std::iter::repeat_n(fill, c.len_utf8())
        })
        .collect();
    text.replace_range(range, &blank);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_duration_with_its_unit_is_read_as_seconds() {
        assert_eq!(seconds_in("500ms"), Some(0.5));
        assert_eq!(seconds_in("2 s"), Some(2.0));
        assert_eq!(seconds_in("3min"), Some(180.0));
        assert_eq!(seconds_in("fast"), None);
    }

    #[test]
    fn an_item_is_blanked_whole_and_the_file_keeps_its_lines() {
        let text = "[a]\nx = [1,\n  2] # note\ny = \"]\" \nz = 1\n";
        let at = text.find('x').unwrap();
        let extent = item_extent(text, at);
        assert_eq!(&text[extent.clone()], "x = [1,\n  2] # note");
        let mut blanked = text.to_string();
        blank_out(&mut blanked, extent);
        assert_eq!(blanked.len(), text.len());
        assert_eq!(blanked.lines().count(), text.lines().count());
        let at = text.find('y').unwrap();
        assert_eq!(&text[item_extent(text, at)], "y = \"]\" ");
        assert_eq!(&text[table_extent(text, at)], text);
    }

    #[test]
    fn serde_names_become_a_persons() {
        assert_eq!(
            expected_names("unknown field `tcc`, expected one of `topic`, `port`, `tc`"),
            ["topic", "port", "tc"]
        );
        assert_eq!(
            expected_names("unknown field `idd`, expected `id` or `description`"),
            ["id", "description"]
        );
        assert_eq!(
            quoted_after("missing field `id`", "missing field "),
            Some("id".into())
        );
    }
}
