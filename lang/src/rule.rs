//! Arbitration rules: Boolean formulas over the activity of a port's connections.
//!
//! Grammar, loosest binding first (the usual precedence: `!` over `&` over `|`):
//!
//! ```text
//! rule    = or
//! or      = and ( "|" and )*
//! and     = not ( "&" not )*
//! not     = "!" not | primary
//! primary = NAME | "true" | "false" | "(" or ")"
//! NAME    = [A-Za-z_][A-Za-z0-9_]*      a connection of the same port
//! ```
//!
//! Why a hand-written parser: errors must point at the character that is wrong, inside a string
//! inside a TOML file, and say what was expected there.
//!
//! Why the depth limit and the n-ary `&` and `|`: every walk of a rule (the parser itself,
//! evaluation, the BDD, display, and dropping the tree) recurses once per level of the tree. A
//! chain `a & b & c ...` is one level however long; only parentheses and `!` nest, and the
//! parser refuses more than [`MAX_DEPTH`] of them with an ordinary error, so no rule from a file
//! can overflow the stack, whatever its length.

use std::fmt;

/// The deepest nesting of parentheses and `!` a rule may have. Rules over at most 32
/// connections need a handful; the limit keeps every recursive walk of a rule far within a
/// thread's stack.
pub const MAX_DEPTH: usize = 128;

/// A parsed rule. Variables are indices of connections within their port.
///
/// Trees from [`parse`] are at most about 3 × [`MAX_DEPTH`] levels deep (each level of nesting
/// may hold an `|`, an `&` and a `!`); walks recurse once per level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Rule {
    /// `true` or `false`.
    Constant(bool),
    /// The activity x_i of the port's connection i.
    Active(usize),
    /// `!a`.
    Not(Box<Rule>),
    /// `a & b & ...`: two or more operands, all of which hold.
    And(Vec<Rule>),
    /// `a | b | ...`: two or more operands, one of which holds.
    Or(Vec<Rule>),
}

impl Rule {
    /// Evaluates the rule under an activity mask (bit i is connection i). Used by tests as the
    /// direct meaning of a rule, against which compiled decisions are checked.
    pub fn eval(&self, mask: u64) -> bool {
        match self {
            Rule::Constant(value) => *value,
            Rule::Active(index) => u32::try_from(*index)
                .ok()
                .and_then(|index| mask.checked_shr(index))
                .is_some_and(|bits| bits & 1 == 1),
            Rule::Not(rule) => !rule.eval(mask),
            Rule::And(operands) => operands.iter().all(|rule| rule.eval(mask)),
            Rule::Or(operands) => operands.iter().any(|rule| rule.eval(mask)),
        }
    }

    /// Whether the rule reads the activity of connection `index`.
    pub fn mentions(&self, index: usize) -> bool {
        match self {
            Rule::Constant(_) => false,
            Rule::Active(i) => *i == index,
            Rule::Not(rule) => rule.mentions(index),
            Rule::And(operands) | Rule::Or(operands) => operands.iter().any(|r| r.mentions(index)),
        }
    }

    /// Writes the rule with connection names, parenthesised only where precedence requires.
    pub fn display<'a>(&'a self, names: &'a [String]) -> impl fmt::Display + 'a {
        Shown { rule: self, names }
    }
}

struct Shown<'a> {
    rule: &'a Rule,
    names: &'a [String],
}

impl Shown<'_> {
    fn write(&self, f: &mut fmt::Formatter<'_>, rule: &Rule, context: u8) -> fmt::Result {
        // Binding strength: or 1, and 2, not/primary 3.
        let (strength, open) = match rule {
            Rule::Or(..) => (1, context > 1),
            Rule::And(..) => (2, context > 2),
            _ => (3, false),
        };
        if open {
            f.write_str("(")?;
        }
        match rule {
            Rule::Constant(value) => write!(f, "{value}")?,
            Rule::Active(index) => match self.names.get(*index) {
                Some(name) => f.write_str(name)?,
                None => write!(f, "#{index}")?,
            },
            Rule::Not(inner) => {
                f.write_str("!")?;
                self.write(f, inner, 3)?;
            }
            Rule::And(operands) | Rule::Or(operands) => {
                let operator = if strength == 1 { " | " } else { " & " };
                for (index, operand) in operands.iter().enumerate() {
                    if index > 0 {
                        f.write_str(operator)?;
                    }
                    // `(a | b) | c` reads as `a | b | c`; `a | (b | c)` keeps its parentheses.
                    let context = if index == 0 { strength } else { strength + 1 };
                    self.write(f, operand, context)?;
                }
            }
        }
        if open {
            f.write_str(")")?;
        }
        Ok(())
    }
}

impl fmt::Display for Shown<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write(f, self.rule, 0)
    }
}

/// A syntax or name error in a rule, at a byte offset of the rule's text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RuleError {
    /// Byte offset in the rule text.
    pub offset: usize,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for RuleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "at byte {}: {}", self.offset, self.message)
    }
}

impl std::error::Error for RuleError {}

#[derive(Clone, Debug, PartialEq, Eq)]
enum Token<'a> {
    Name(&'a str),
    Not,
    And,
    Or,
    Open,
    Close,
    End,
}

impl fmt::Display for Token<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Token::Name(name) => write!(f, "`{name}`"),
            Token::Not => f.write_str("`!`"),
            Token::And => f.write_str("`&`"),
            Token::Or => f.write_str("`|`"),
            Token::Open => f.write_str("`(`"),
            Token::Close => f.write_str("`)`"),
            Token::End => f.write_str("the end of the rule"),
        }
    }
}

fn is_name_start(c: char) -> bool {
    c.is_ascii_alphabetic() || c == '_'
}

fn is_name_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Whether `name` can be written in a rule.
pub fn is_valid_name(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(is_name_start)
        && chars.all(is_name_char)
        && name != "true"
        && name != "false"
}

fn tokenize(text: &str) -> Result<Vec<(usize, Token<'_>)>, RuleError> {
    let mut tokens = Vec::new();
    let mut chars = text.char_indices().peekable();
    while let Some((offset, c)) = chars.next() {
        let token = match c {
            c if c.is_whitespace() => continue,
            '!' => Token::Not,
            '&' | '|' if chars.peek().map(|&(_, next)| next) == Some(c) => {
                return Err(RuleError {
                    offset,
                    message: format!("write `{c}`, not `{c}{c}`"),
                });
            }
            '&' => Token::And,
            '|' => Token::Or,
            '(' => Token::Open,
            ')' => Token::Close,
            c if is_name_start(c) => {
                let mut end = offset + c.len_utf8();
                // A name, or `group.behaviour` (a competitive-dynamics gate): one dot between
                // two names, nothing else (connection names have no dot).
                let mut dotted = false;
                while let Some(&(next_offset, next)) = chars.peek() {
                    if next == '.' && !dotted {
                        let after = text[next_offset + 1..].chars().next();
                        if !after.is_some_and(is_name_start) {
                            return Err(RuleError {
                                offset: next_offset,
                                message: "a `.` in a rule joins a dynamics group and one of its behaviours (`door.search`)".to_string(),
                            });
                        }
                        dotted = true;
                    } else if !is_name_char(next) {
                        break;
                    }
                    end = next_offset + next.len_utf8();
                    chars.next();
                }
                Token::Name(&text[offset..end])
            }
            other => {
                return Err(RuleError {
                    offset,
                    message: format!(
                        "unexpected character `{}`; rules use connection names, gates (`group.behaviour`), `!`, `&`, `|`, parentheses, `true` and `false`",
                        crate::shown::escaped(other.encode_utf8(&mut [0; 4]))
                    ),
                });
            }
        };
        tokens.push((offset, token));
    }
    tokens.push((text.len(), Token::End));
    Ok(tokens)
}

struct Parser<'a, 'r> {
    tokens: Vec<(usize, Token<'a>)>,
    position: usize,
    /// Parentheses and `!` open at the current token.
    depth: usize,
    resolve: &'r dyn Fn(&str) -> Result<usize, String>,
}

impl<'a> Parser<'a, '_> {
    fn peek(&self) -> (usize, &Token<'a>) {
        self.tokens
            .get(self.position)
            .or(self.tokens.last())
            .map_or((0, &Token::End), |(offset, token)| (*offset, token))
    }

    fn advance(&mut self) {
        self.position += 1;
    }

    /// Enters one level of nesting at the current token (a `(` or a `!`).
    fn enter(&mut self) -> Result<(), RuleError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(RuleError {
                offset: self.peek().0,
                message: format!(
                    "the rule is nested more than {MAX_DEPTH} levels deep (parentheses and `!`); write it flatter"
                ),
            });
        }
        Ok(())
    }

    fn or(&mut self) -> Result<Rule, RuleError> {
        let first = self.and()?;
        if *self.peek().1 != Token::Or {
            return Ok(first);
        }
        let mut operands = vec![first];
        while *self.peek().1 == Token::Or {
            self.advance();
            operands.push(self.and()?);
        }
        Ok(Rule::Or(operands))
    }

    fn and(&mut self) -> Result<Rule, RuleError> {
        let first = self.not()?;
        if *self.peek().1 != Token::And {
            return Ok(first);
        }
        let mut operands = vec![first];
        while *self.peek().1 == Token::And {
            self.advance();
            operands.push(self.not()?);
        }
        Ok(Rule::And(operands))
    }

    fn not(&mut self) -> Result<Rule, RuleError> {
        if *self.peek().1 == Token::Not {
            self.enter()?;
            self.advance();
            let inner = self.not()?;
            self.depth -= 1;
            return Ok(Rule::Not(Box::new(inner)));
        }
        self.primary()
    }

    fn primary(&mut self) -> Result<Rule, RuleError> {
        let (offset, token) = self.peek();
        let token = token.clone();
        match token {
            Token::Name("true") => {
                self.advance();
                Ok(Rule::Constant(true))
            }
            Token::Name("false") => {
                self.advance();
                Ok(Rule::Constant(false))
            }
            Token::Name(name) => {
                let index =
                    (self.resolve)(name).map_err(|message| RuleError { offset, message })?;
                self.advance();
                Ok(Rule::Active(index))
            }
            Token::Open => {
                self.enter()?;
                self.advance();
                let rule = self.or()?;
                self.depth -= 1;
                let (close_offset, close) = self.peek();
                if *close != Token::Close {
                    return Err(RuleError {
                        offset: close_offset,
                        message: format!(
                            "expected `)` to close the `(` at column {}, found {close}",
                            offset + 1
                        ),
                    });
                }
                self.advance();
                Ok(rule)
            }
            other => Err(RuleError {
                offset,
                message: format!(
                    "expected a connection name, `true`, `false`, `!` or `(`, found {other}"
                ),
            }),
        }
    }
}

/// Parses `text`. `resolve` maps a connection name to its index in the port, or explains why the
/// name is not allowed.
pub fn parse(
    text: &str,
    resolve: &dyn Fn(&str) -> Result<usize, String>,
) -> Result<Rule, RuleError> {
    let tokens = tokenize(text)?;
    let mut parser = Parser {
        tokens,
        position: 0,
        depth: 0,
        resolve,
    };
    let rule = parser.or()?;
    let (offset, token) = parser.peek();
    if *token != Token::End {
        let hint = match token {
            Token::Close => "this `)` has no matching `(`".to_string(),
            other => format!("expected `&`, `|` or the end of the rule, found {other}"),
        };
        return Err(RuleError {
            offset,
            message: hint,
        });
    }
    Ok(rule)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names() -> Vec<String> {
        ["C1", "C2", "C3"].iter().map(|s| s.to_string()).collect()
    }

    fn parse_here(text: &str) -> Result<Rule, RuleError> {
        let names = names();
        parse(text, &|name| {
            names
                .iter()
                .position(|n| n == name)
                .ok_or_else(|| format!("unknown connection `{name}`"))
        })
    }

    #[test]
    fn precedence_is_not_over_and_over_or() {
        let rule = parse_here("C1 | C2 & !C3").unwrap();
        assert_eq!(
            rule,
            Rule::Or(vec![
                Rule::Active(0),
                Rule::And(vec![Rule::Active(1), Rule::Not(Box::new(Rule::Active(2)))])
            ])
        );
        assert_eq!(rule.display(&names()).to_string(), "C1 | C2 & !C3");
        let grouped = parse_here("(C1 | C2) & !(C3)").unwrap();
        assert_eq!(grouped.display(&names()).to_string(), "(C1 | C2) & !C3");
        // x1 | x2 & !x3 is true for mask {C1} and false for {C3}.
        assert!(rule.eval(0b001));
        assert!(!rule.eval(0b100));
        assert!(!grouped.eval(0b101));
    }

    #[test]
    fn constants_and_nesting() {
        assert_eq!(parse_here("false").unwrap(), Rule::Constant(false));
        assert_eq!(parse_here(" true ").unwrap(), Rule::Constant(true));
        let rule = parse_here("!!((C1))").unwrap();
        assert!(rule.eval(1) && !rule.eval(0));
        assert_eq!(rule.display(&names()).to_string(), "!!C1");
    }

    #[test]
    fn errors_point_at_the_culprit() {
        let cases = [
            ("", 0, "found the end of the rule"),
            ("C1 &", 4, "found the end of the rule"),
            ("C1 && C2", 3, "write `&`, not `&&`"),
            ("C1 C2", 3, "expected `&`, `|` or the end"),
            ("(C1 | C2", 8, "expected `)` to close the `(` at column 1"),
            ("C1)", 2, "no matching `(`"),
            ("C1 & C9", 5, "unknown connection `C9`"),
            ("C1 ^ C2", 3, "unexpected character `^`"),
            ("& C1", 0, "expected a connection name"),
        ];
        for (text, offset, message) in cases {
            let error = parse_here(text).unwrap_err();
            assert_eq!(error.offset, offset, "{text}: {error:?}");
            assert!(error.message.contains(message), "{text}: {error:?}");
        }
    }

    #[test]
    fn valid_names() {
        assert!(is_valid_name("C1") && is_valid_name("_x") && is_valid_name("grasp_2"));
        assert!(!is_valid_name("1C") && !is_valid_name("a-b") && !is_valid_name("true"));
        assert!(!is_valid_name(""));
    }

    #[test]
    fn chains_are_flat_and_grouping_is_kept() {
        let rule = parse_here("C1 & C2 & C3 | C1 | (C2 | C3) | C1 & (C2 & C3)").unwrap();
        let Rule::Or(operands) = &rule else {
            panic!("{rule:?}")
        };
        assert_eq!(operands.len(), 4);
        assert_eq!(
            rule.display(&names()).to_string(),
            "C1 & C2 & C3 | C1 | (C2 | C3) | C1 & (C2 & C3)"
        );
        assert_eq!(
            parse_here("(C1 | C2) | C3")
                .unwrap()
                .display(&names())
                .to_string(),
            "C1 | C2 | C3"
        );
        for mask in 0..8 {
            let (c1, c2, c3) = (mask & 1 != 0, mask & 2 != 0, mask & 4 != 0);
            let terms = [c1 && c2 && c3, c1, c2 || c3, c1 && (c2 && c3)];
            assert_eq!(rule.eval(mask), terms.contains(&true));
        }
    }

    #[test]
    fn nesting_is_limited_and_length_is_not() {
        let deepest = format!("{}C1{}", "(".repeat(MAX_DEPTH), ")".repeat(MAX_DEPTH));
        assert_eq!(parse_here(&deepest).unwrap(), Rule::Active(0));
        let too_deep = format!(
            "{}C1{}",
            "(".repeat(MAX_DEPTH + 1),
            ")".repeat(MAX_DEPTH + 1)
        );
        let error = parse_here(&too_deep).unwrap_err();
        assert_eq!(error.offset, MAX_DEPTH);
        assert!(
            error.message.contains("nested more than 128 levels"),
            "{error:?}"
        );
        let nots = format!("{}C1", "!".repeat(MAX_DEPTH));
        assert!(parse_here(&nots).unwrap().eval(1));
        let error = parse_here(&format!("!{nots}")).unwrap_err();
        assert_eq!(error.offset, MAX_DEPTH);
        // Siblings do not add up: 1000 groups side by side are one level each.
        let wide = vec!["(C1 & !(C2))"; 1000].join(" | ");
        assert!(parse_here(&wide).unwrap().eval(0b001));
        // 100 000 operands: one level.
        let long = vec!["C1"; 100_000].join(" & ");
        let rule = parse_here(&long).unwrap();
        assert!(rule.eval(1) && !rule.eval(0));
        assert_eq!(rule.display(&names()).to_string().len(), long.len());
    }
}
