//! Text from a user's file inside our messages: control characters and the Unicode controls that
//! reorder or break lines are shown escaped (`\n`, `\u{1b}`), never written raw to a terminal,
//! and long text is shortened. A name holding `\u{1b}[2J` must not clear the screen of whoever
//! reads the error about it.

/// Whether `c` is written escaped: C0 and C1 control characters (ESC, CSI, newline, tab...) and
/// DEL, the bidirectional controls (U+200E, U+200F, U+202A..U+202E, U+2066..U+2069) and the line
/// and paragraph separators.
pub fn needs_escape(c: char) -> bool {
    c.is_control()
        || matches!(
            c,
            '\u{200E}' | '\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}'
                | '\u{2028}' | '\u{2029}'
        )
}

/// Whether `text` holds a character [`needs_escape`] escapes.
pub fn has_control(text: &str) -> bool {
    text.chars().any(needs_escape)
}

/// `text`, safe to print: `\n`, `\r`, `\t` and `\u{..}` in place of the characters
/// [`needs_escape`] names; everything else as is.
pub fn escaped(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        push_escaped(&mut out, c);
    }
    out
}

/// [`escaped`], shortened to its first `max` characters followed by `…` when longer (a rule of
/// 100 000 operands is not repeated whole in each message about it).
pub fn excerpt(text: &str, max: usize) -> String {
    let mut out = String::new();
    for (count, c) in text.chars().enumerate() {
        if count == max {
            out.push('…');
            break;
        }
        push_escaped(&mut out, c);
    }
    out
}

fn push_escaped(out: &mut String, c: char) {
    match c {
        '\n' => out.push_str("\\n"),
        '\r' => out.push_str("\\r"),
        '\t' => out.push_str("\\t"),
        c if needs_escape(c) => out.push_str(&format!("\\u{{{:x}}}", u32::from(c))),
        c => out.push(c),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn controls_are_escaped_and_the_rest_kept() {
        assert_eq!(escaped("arm\u{1b}[31m\n"), "arm\\u{1b}[31m\\n");
        assert_eq!(escaped("a\u{9b}2J\u{202e}é σ"), "a\\u{9b}2J\\u{202e}é σ");
        assert_eq!(escaped("C1 & !C2"), "C1 & !C2");
        assert!(has_control("x\u{7f}") && !has_control("gaze.target"));
    }

    #[test]
    fn excerpts_are_cut_on_characters() {
        assert_eq!(excerpt("σσσσ", 2), "σσ…");
        assert_eq!(excerpt("abc", 3), "abc");
        assert_eq!(excerpt("a\nb", 5), "a\\nb");
    }
}
