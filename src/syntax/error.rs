//! Syntax errors, translated from pest's into plain words.

use pest::error::{ErrorVariant, InputLocation};

use super::KEYWORDS;
use super::parse::{HybParser, Rule};
use crate::diagnostics::Diagnostic;
use crate::source::Span;

/// A syntax error: where, what was found and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SyntaxError {
    /// The parser could not continue at `span`.
    #[error("unexpected {found}; expected {expected}")]
    Unexpected {
        /// Where.
        span: Span,
        /// What was found, in words (e.g. "`}`", "end of file").
        found: String,
        /// What would have been accepted, in words.
        expected: String,
    },
    /// Brackets nested deeper than [`super::MAX_NESTING`].
    #[error("nesting deeper than {limit} levels")]
    TooDeep {
        /// The opening bracket that exceeds the limit.
        span: Span,
        /// The limit.
        limit: usize,
    },
    /// An expression tree deeper than [`super::MAX_EXPR_DEPTH`] operations
    /// (a very long flat sum, product or chain of unary operators).
    #[error("expression deeper than {limit} operations")]
    TooLong {
        /// The operator that exceeds the limit.
        span: Span,
        /// The limit.
        limit: usize,
    },
    /// `x = v` in a jump's reset block: a reset names the state after the
    /// jump, `x+ = v`.
    #[error("a reset assigns the state after the jump: write `{target}+ = ...`")]
    ResetWithoutPlus {
        /// The assigned state (`x`, `x[1]`).
        span: Span,
        /// Its text.
        target: String,
    },
    /// A MATLAB spelling hybsim does not use (`&`, `|`, `~=`, `~x`), or a
    /// Python one (`and`, `or`, `not`).
    #[error("`{found}` is {lang}'s spelling; hybsim writes `{write}`")]
    MatlabOperator {
        /// The operator.
        span: Span,
        /// What was written.
        found: &'static str,
        /// The hybsim spelling.
        write: &'static str,
        /// Whose spelling it is (`MATLAB`, `Python`).
        lang: &'static str,
    },
    /// `dx = v` in a flow block: an equation gives a state's derivative,
    /// `x' = v` (HyEQ's and Simulink's scripts name it `dx`).
    #[error("a flow equation gives a state's derivative, written with a prime: `x' = ...`")]
    FlowWithoutPrime {
        /// The name before `=`.
        span: Span,
        /// Its text.
        name: String,
    },
    /// Another language's way of writing something hybsim writes
    /// differently, where the parser stopped: a MATLAB `%` or C `//`
    /// comment, `.^`, `**`, `.5`, matrix entries separated by spaces,
    /// `x(1)` indexing, `x''`, `=` in a condition, a flow set without `in`,
    /// `end`.
    #[error("{message}")]
    Foreign {
        /// What was written.
        span: Span,
        /// The error, naming the spelling and hybsim's.
        message: String,
        /// The label at the span.
        label: String,
        /// What to write instead.
        help: String,
    },
    /// A block whose `{` is not closed where a new declaration (or the end
    /// of the file) begins, or a `(` or `[` not closed where a closing
    /// delimiter of another kind, a new declaration or the end of the file
    /// comes.
    #[error("`{delim}` not closed: expected `{}` before {found}", closing(*.delim))]
    Unclosed {
        /// What was found where the closing delimiter was expected.
        span: Span,
        /// The unclosed delimiter.
        open: Span,
        /// Which: `{`, `(` or `[`.
        delim: char,
        /// What was found, in words.
        found: String,
    },
    /// A word close to a keyword where the parser stopped: the first word of
    /// a statement (`stat x = 1`, `flwo { … }`) or a word where a keyword was
    /// expected (`jump r wen x <= 0`).
    #[error("{message}")]
    Misspelt {
        /// The word.
        span: Span,
        /// The error.
        message: String,
        /// The label at the span.
        label: String,
        /// The keyword it is closest to.
        keyword: &'static str,
    },
    /// A statement whose first word is no declaration's keyword nor close
    /// to one (`const g = 1`, `initial x = 1`), or a flow equation outside
    /// `flow { }`: the parser read the word as an instance's name and
    /// stopped after it.
    #[error("{message}")]
    NotADeclaration {
        /// The word.
        span: Span,
        /// The error.
        message: String,
        /// The label at the span.
        label: &'static str,
        /// What to write instead.
        help: String,
    },
    /// A `param` or `output` declared without its value (`param k` alone
    /// on its line): the parser read on into the next statement.
    #[error("`{keyword} {name}` has no value")]
    MissingValue {
        /// The declared name.
        span: Span,
        /// `param` or `output`.
        keyword: &'static str,
        /// The name.
        name: String,
    },
    /// A keyword where a name was expected (`jump out when …`).
    #[error("`{word}` is a keyword, not a name")]
    KeywordAsName {
        /// The keyword.
        span: Span,
        /// Its text.
        word: &'static str,
    },
    /// A keyword as the value of a `sim` setting whose values are words
    /// (`priority = flow`, `priority = jump`).
    #[error("`{word}` is a keyword, not a value of `{setting}`")]
    SettingKeyword {
        /// The keyword.
        span: Span,
        /// Its text.
        word: &'static str,
        /// The setting.
        setting: &'static str,
    },
    /// A number literal that does not fit in an f64.
    #[error("number `{text}` is out of range")]
    BadNumber {
        /// Where.
        span: Span,
        /// The literal.
        text: String,
    },
}

impl SyntaxError {
    /// Where the error is.
    pub fn span(&self) -> Span {
        match self {
            SyntaxError::Unexpected { span, .. }
            | SyntaxError::TooDeep { span, .. }
            | SyntaxError::TooLong { span, .. }
            | SyntaxError::ResetWithoutPlus { span, .. }
            | SyntaxError::MatlabOperator { span, .. }
            | SyntaxError::FlowWithoutPrime { span, .. }
            | SyntaxError::Foreign { span, .. }
            | SyntaxError::Unclosed { span, .. }
            | SyntaxError::Misspelt { span, .. }
            | SyntaxError::NotADeclaration { span, .. }
            | SyntaxError::MissingValue { span, .. }
            | SyntaxError::KeywordAsName { span, .. }
            | SyntaxError::SettingKeyword { span, .. }
            | SyntaxError::BadNumber { span, .. } => *span,
        }
    }

    /// The error as a diagnostic (codes E01xx).
    pub fn to_diagnostic(&self) -> Diagnostic {
        match self {
            SyntaxError::Unexpected {
                span,
                found,
                expected,
            } => {
                let d = Diagnostic::error("E0101", format!("unexpected {found}; expected {expected}"))
                    .primary(*span, format!("expected {expected} here"));
                // After a flow equation's state name.
                if expected.contains(FLOW_PRIME) {
                    d.help("a flow equation gives a state's derivative: `x' = f(x)` (with `x[i]' = …` for a family member)")
                } else if found == "`if`" && expected.contains("an expression") {
                    // `tau >= if q == 1 then a else b`: `if` is an
                    // expression, but one that reaches to the end, not an
                    // operand.
                    d.help("`if c then a else b` extends as far as it can, so it starts an expression, not an operand: write the operand in parentheses, `x >= (if c then a else b)`")
                } else {
                    d
                }
            }
            SyntaxError::TooDeep { span, limit } => Diagnostic::error(
                "E0102",
                format!("brackets nested deeper than {limit} levels"),
            )
            .primary(*span, "too deep")
            .help("split the expression into named parameters or outputs"),
            SyntaxError::TooLong { span, limit } => Diagnostic::error(
                "E0106",
                format!("expression deeper than {limit} operations"),
            )
            .primary(*span, "the limit is reached here")
            .note("a chain `a + b + c + …` (or of `*`, `&&`, prefix `-`/`!`, postfix `'`/`[i]`) nests one operation per operator")
            .help("write long sums and products with `sum(k in 1..N: …)` or matrix products, or split the expression into named parameters or outputs"),
            SyntaxError::ResetWithoutPlus { span, target } => {
                Diagnostic::error("E0104", self.to_string())
                    .primary(*span, format!("`{target}+` expected"))
                    .note("in `jump` and `every` blocks, `x+` is the state after the jump and `x` the state before it")
                    .help(format!("write `{target}+ = ...`"))
            }
            SyntaxError::MatlabOperator {
                span, found, write, ..
            } => {
                Diagnostic::error("E0105", self.to_string())
                    .primary(*span, format!("write `{write}` here"))
                    .help(format!(
                        "hybsim's operators are C-like: `&&` and, `||` or, `!=` not equal, \
                         `!x` not; replace `{found}` by `{write}`"
                    ))
            }
            SyntaxError::FlowWithoutPrime { span, name } => {
                let mut d = Diagnostic::error("E0107", self.to_string())
                    .primary(*span, format!("the derivative of `{name}` is `{name}'`"))
                    .note("a `flow` block holds equations `x' = f(x)`, one per state that changes");
                // HyEQ's `dx1`, MATLAB's `xdot` or `x_dot`: the derivative of `x`.
                let base = ["_dot", "dot", "Dot"]
                    .iter()
                    .find_map(|s| name.strip_suffix(s))
                    .or_else(|| name.strip_prefix('d'))
                    .filter(|x| !x.is_empty());
                if let Some(x) = base {
                    d = d.help(format!(
                        "if `{name}` is the derivative of `{x}`, write `{x}' = ...`"
                    ));
                }
                d
            }
            SyntaxError::Foreign {
                span,
                message,
                label,
                help,
            } => Diagnostic::error("E0109", message.clone())
                .primary(*span, label.clone())
                .help(help.clone()),
            SyntaxError::Unclosed {
                span, open, delim, ..
            } => {
                let close = closing(*delim);
                Diagnostic::error("E0108", self.to_string())
                    .primary(*span, format!("`{close}` expected before this"))
                    .secondary(*open, format!("this `{delim}` is not closed"))
                    .help(if *delim == '{' {
                        "close the block with `}`".to_string()
                    } else {
                        format!("close it with `{close}` where its contents end")
                    })
            }
            SyntaxError::Misspelt {
                span,
                message,
                label,
                keyword,
            } => Diagnostic::error("E0101", message.clone())
                .primary(*span, label.clone())
                .help(format!("did you mean `{keyword}`?")),
            SyntaxError::NotADeclaration {
                span,
                message,
                label,
                help,
            } => {
                Diagnostic::error("E0101", message.clone())
                    .primary(*span, *label)
                    .help(help.clone())
            }
            SyntaxError::MissingValue {
                span,
                keyword,
                name,
            } => Diagnostic::error("E0101", self.to_string())
                .primary(*span, "no `= …` after this name")
                .help(format!("write `{keyword} {name} = …`")),
            SyntaxError::SettingKeyword {
                span,
                word,
                setting,
            } => Diagnostic::error("E0101", self.to_string())
                .primary(*span, format!("a value of `{setting}` expected here"))
                .help(super::setting_word_help(setting, word).unwrap_or_default()),
            SyntaxError::KeywordAsName { span, word } => {
                Diagnostic::error("E0101", self.to_string())
                    .primary(*span, "a name expected here")
                    .note(format!(
                        "keywords cannot be names: {}",
                        KEYWORDS
                            .iter()
                            .map(|k| format!("`{k}`"))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ))
                    .help(format!("choose another name than `{word}`"))
            }
            SyntaxError::BadNumber { span, text } => {
                Diagnostic::error("E0103", format!("number `{text}` is out of range"))
                    .primary(*span, "too large for a 64-bit float")
            }
        }
    }

    /// Translates a pest error on `text`.
    /// `rule` is the rule `text` was parsed as (re-parsed with a missing
    /// operator supplied, for [`missing_operator`]).
    pub(crate) fn from_pest(err: pest::error::Error<Rule>, text: &str, rule: Rule) -> Self {
        let pos = match err.location {
            InputLocation::Pos(p) => p,
            InputLocation::Span((s, _)) => s,
        };
        let mut expected: Vec<&'static str> = match &err.variant {
            ErrorVariant::ParsingError { positives, .. } => {
                positives.iter().filter_map(|r| describe(*r)).collect()
            }
            ErrorVariant::CustomError { .. } => Vec::new(),
        };
        expected.sort_unstable();
        expected.dedup();
        // The keywords among the expectations (`when` of "`when`").
        let mut keywords: Vec<&'static str> = expected
            .iter()
            .filter_map(|e| e.strip_prefix('`')?.strip_suffix('`'))
            .filter(|k| KEYWORDS.contains(k))
            .collect();
        // A property body's first word is contextual, not a keyword, and
        // listed as the body's description: `allways` gets `always` too.
        if expected.iter().any(|e| e.starts_with("a property body")) {
            keywords.extend(PROPERTY_WORDS);
        }
        // Only a name, or after `jump` a name or the trigger that may replace
        // it (`jump out when`): where a declaration may start too, a keyword
        // there is a misplaced keyword (`flow { … } when x >= 0`).
        let wants_name = expected.contains(&"a name")
            && expected
                .iter()
                .all(|e| matches!(*e, "a name" | "`when`" | "`every`"));
        let expected = match expected.len() {
            0 => "something else".to_string(),
            1 => expected[0].to_string(),
            n => format!("{} or {}", expected[..n - 1].join(", "), expected[n - 1]),
        };
        if let Some(err) = walrus(text, pos) {
            return err;
        }
        if let Some((found, write)) = matlab_operator(text, pos) {
            return SyntaxError::MatlabOperator {
                span: Span::new(pos, pos + found.len()),
                found,
                write,
                lang: "MATLAB",
            };
        }
        if let Some((at, found, write)) = word_operator(text, pos) {
            return SyntaxError::MatlabOperator {
                span: Span::new(at, at + found.len()),
                found,
                write,
                lang: "Python",
            };
        }
        // Before a flow equation's: `for i = 1:N` in a flow block is a loop.
        if let Some(err) = matlab_range(text, pos) {
            return err;
        }
        if let Some((at, name)) = flow_without_prime(text, pos) {
            return SyntaxError::FlowWithoutPrime {
                span: Span::new(at, at + name.len()),
                name,
            };
        }
        if let Some(foreign) = foreign_spelling(text, pos) {
            return foreign;
        }
        if let Some(missing) = missing_operator(text, pos, rule) {
            return missing;
        }
        let (found, len) = found_at(text, pos);
        // A group left open after a complete operand (where an expression
        // is still wanted, as after `[1,`, that is the better message).
        let operand_done = !expected.contains("an expression");
        if let Some((open, delim)) = unclosed_group(text, pos)
            .filter(|_| operand_done)
            .or_else(|| unclosed_before_declaration(text, pos).map(|open| (open, '{')))
        {
            return SyntaxError::Unclosed {
                span: Span::new(pos, pos + len),
                open: Span::new(open, open + 1),
                delim,
                found,
            };
        }
        if let Some(err) = missing_value(text, pos, &expected) {
            return err;
        }
        if let Some(err) = setting_keyword(text, pos) {
            return err;
        }
        if let Some(err) = bare_assignment(text, pos, &expected) {
            return err;
        }
        if let Some(err) = keyword_mistake(text, pos, &keywords, wants_name, &expected) {
            return err;
        }
        // The file ended too early: point just past its last token, on that
        // token's line (`jump r when x <= 0` without its block), not at the
        // empty line after it.
        let pos = if pos == text.len() {
            text.trim_end().len()
        } else {
            pos
        };
        SyntaxError::Unexpected {
            span: Span::new(pos, pos + len),
            found,
            expected,
        }
    }
}

/// What a flow equation's state name is followed by.
const FLOW_PRIME: &str = "`'` (`x' = …`)";

/// The words that start a declaration (keywords and contextual words), which
/// a misspelt first word of a statement is compared with.
const DECLARATION_WORDS: [&str; 20] = [
    "param",
    "graph",
    "state",
    "noise",
    "flow",
    "jump",
    "every",
    "output",
    "sim",
    "design",
    "check",
    "for",
    "together",
    "property",
    "metric",
    "sweep",
    "log",
    "import",
    "subsystem",
    "input",
];

/// A `param NAME` or `output NAME` statement that ends without `= …`, the
/// parser stopped after it at `pos` expecting only an index's `[`.
fn missing_value(text: &str, pos: usize, expected: &str) -> Option<SyntaxError> {
    if expected != "`[`" {
        return None;
    }
    let before = text.get(..pos)?.trim_end();
    let line_start = before.rfind(['\n', ';', '{', '}']).map_or(0, |i| i + 1);
    let line = &before[line_start..];
    let mut words = line.split_whitespace();
    let keyword = match words.next()? {
        "param" => "param",
        "output" => "output",
        _ => return None,
    };
    let name = words.next()?;
    let is_name = name.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if words.next().is_some() || !is_name {
        return None;
    }
    let end = line_start + line.len();
    Some(SyntaxError::MissingValue {
        span: Span::new(end - name.len(), end),
        keyword,
        name: name.to_string(),
    })
}

/// The words a property's body starts with (`property p: always …`).
const PROPERTY_WORDS: [&str; 8] = [
    "always",
    "after",
    "during",
    "at",
    "eventually",
    "decreasing",
    "nonincreasing",
    "exponential",
];

/// The keyword closest to `word` (Jaro–Winkler ≥ 0.8), unless `word` is one.
fn closest_keyword(word: &str, keywords: &[&'static str]) -> Option<&'static str> {
    if word.len() < 2 || keywords.contains(&word) {
        return None;
    }
    keywords
        .iter()
        .map(|k| (strsim::jaro_winkler(word, k), *k))
        .filter(|(score, _)| *score >= 0.8)
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, k)| k)
}

/// Where the parser stopped at `pos`: a keyword as the value of a `sim`
/// setting whose values are words (`priority = flow`).
fn setting_keyword(text: &str, pos: usize) -> Option<SyntaxError> {
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let (before, rest) = (text.get(..pos)?, text.get(pos..)?);
    let here = &rest[..rest.find(|c: char| !is_word(c)).unwrap_or(rest.len())];
    let word = *KEYWORDS.iter().find(|k| **k == here)?;
    let before = before.trim_end_matches([' ', '\t']).strip_suffix('=')?;
    if before.ends_with(['=', '<', '>', '!']) {
        return None;
    }
    let before = before.trim_end_matches([' ', '\t']);
    let key = &before[before.trim_end_matches(is_word).len()..];
    let (setting, _) = *super::SETTING_WORDS.iter().find(|(k, _)| *k == key)?;
    Some(SyntaxError::SettingKeyword {
        span: Span::new(pos, pos + here.len()),
        word,
        setting,
    })
}

/// Where the parser stopped at `pos`: a keyword used as a name (`jump out
/// when`), a word close to an expected keyword (`jump r wen`), or a
/// statement's first word close to a declaration's keyword (`stat x = 1`
/// stops at `x`, `stat` having been read as an instance's name).
fn keyword_mistake(
    text: &str,
    pos: usize,
    keywords: &[&'static str],
    wants_name: bool,
    expected: &str,
) -> Option<SyntaxError> {
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let (before, rest) = (text.get(..pos)?, text.get(pos..)?);
    let here = &rest[..rest.find(|c: char| !is_word(c)).unwrap_or(rest.len())];
    if wants_name && let Some(&word) = KEYWORDS.iter().find(|k| **k == here) {
        return Some(SyntaxError::KeywordAsName {
            span: Span::new(pos, pos + here.len()),
            word,
        });
    }
    if let Some(keyword) = closest_keyword(here, keywords) {
        return Some(SyntaxError::Misspelt {
            span: Span::new(pos, pos + here.len()),
            message: format!("unexpected `{here}`; expected {expected}"),
            label: format!("expected {expected} here"),
            keyword,
        });
    }
    // At the end of the file after a name read as an instance's (only `[`
    // expected), that name (`stat` alone on the last line).
    let end = if rest.trim().is_empty() && expected == "`[`" {
        before.trim_end().len()
    } else {
        before.trim_end_matches([' ', '\t']).len()
    };
    let start = before[..end].trim_end_matches(is_word).len();
    let word = &before[start..end];
    let statement_start = before[..start]
        .trim_end_matches([' ', '\t'])
        .chars()
        .next_back()
        .is_none_or(|c| matches!(c, '\n' | '\r' | ';' | '{' | '}'));
    if !statement_start || !word.starts_with(|c: char| c.is_ascii_alphabetic()) {
        return None;
    }
    let span = Span::new(start, end);
    if let Some(keyword) = closest_keyword(word, &DECLARATION_WORDS) {
        return Some(SyntaxError::Misspelt {
            span,
            message: format!("`{word}` does not start a declaration"),
            label: "not a declaration's keyword".into(),
            keyword,
        });
    }
    // Only `[` expected: the word was read as an instance's name (`name =
    // Sub(…)`, whose `=` pest does not list), which it is not.
    if expected != "`[`" || rest.trim_start_matches([' ', '\t']).starts_with('=') {
        return None;
    }
    let (message, label, help) = if rest.starts_with('\'') {
        (
            format!("a flow equation `{word}' = …` outside a flow block"),
            "a state's derivative outside `flow { }`",
            format!("write flow equations in a flow block: `flow {{ {word}' = … }}`"),
        )
    } else {
        let declares = match word {
            "const" | "constant" | "let" | "var" | "val" | "def" | "define" => {
                "; constants are declared with `param` (`param g = 9.81`), states with `state`"
            }
            _ => "",
        };
        (
            format!("`{word}` does not start a declaration"),
            "not a declaration's keyword",
            format!(
                "a statement starts with one of {}, or is an instance `name = Subsystem(…)`{declares}",
                DECLARATION_WORDS
                    .iter()
                    .map(|k| format!("`{k}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
    };
    Some(SyntaxError::NotADeclaration {
        span,
        message,
        label,
        help,
    })
}

/// A statement `name = value` (or `name[i] = value`) that is not an
/// instance `name = Subsystem(…)`: MATLAB's and HyEQ's way of defining a
/// constant (`g = 9.81`) or a set (`C = x >= 0`). The parser read the name
/// as an instance's and stopped at the `=` (expecting only `[`) or at the
/// value (expecting a subsystem's name), and said only that.
fn bare_assignment(text: &str, pos: usize, expected: &str) -> Option<SyntaxError> {
    if expected != "`[`" && expected != "a name" {
        return None;
    }
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let before = text.get(..pos)?;
    let start = before
        .rfind(['\n', '\r', ';', '{', '}'])
        .map_or(0, |i| i + 1);
    let name_start =
        start + text[start..].len() - text[start..].trim_start_matches([' ', '\t']).len();
    let rest = &text[name_start..];
    let name = &rest[..rest.find(|c: char| !is_word(c)).unwrap_or(rest.len())];
    if !name.starts_with(|c: char| c.is_ascii_alphabetic())
        || KEYWORDS.contains(&name)
        || DECLARATION_WORDS.contains(&name)
    {
        return None;
    }
    let mut end = name_start + name.len();
    // A family member's index, `x[1] = …`.
    if text[end..].starts_with('[') {
        end += text[end..].find([']', '\n'])?;
        if !text[end..].starts_with(']') {
            return None;
        }
        end += 1;
    }
    let eq = end + text[end..].len() - text[end..].trim_start_matches([' ', '\t']).len();
    if !text[eq..].starts_with('=') || text[eq..].starts_with("==") {
        return None;
    }
    let value_start =
        eq + 1 + text[eq + 1..].len() - text[eq + 1..].trim_start_matches([' ', '\t']).len();
    if pos != eq && pos != value_start {
        return None;
    }
    // `name = Sub(…)` is an instance: its errors are elsewhere.
    let value = &text[value_start..];
    let head = value.trim_start_matches(is_word);
    if head.len() < value.len() && head.trim_start_matches([' ', '\t']).starts_with('(') {
        return None;
    }
    let target = &text[name_start..end];
    // A keyword glued to its name, `paramx = 1`.
    let glued = DECLARATION_WORDS
        .iter()
        .find_map(|w| Some((w, name.strip_prefix(w).filter(|r| !r.is_empty())?)))
        .map(|(w, r)| format!("if `{name}` is `{w} {r}`, separate the words: `{w} {r} = …`; else "))
        .unwrap_or_default();
    let sets = match name {
        "C" => "; HyEQ's flow set C is written after the flow block, `flow { … } in x >= 0`",
        "D" => "; HyEQ's jump set D is a jump rule's guard, `jump NAME when x <= 0 { … }`",
        _ => "",
    };
    Some(SyntaxError::NotADeclaration {
        span: Span::new(name_start, end),
        message: format!(
            "`{target} = …` is not a declaration: hybsim declares a name with a keyword"
        ),
        label: "a keyword expected before this name",
        help: format!(
            "{glued}write `param {target} = …` for a constant, `state {target} = …` for a state and its \
             initial value, or `output {target} = …` for a logged expression (a statement \
             without a keyword is an instance of a subsystem, `{target} = Subsystem(…)`){sets}"
        ),
    })
}

/// A MATLAB operator at `pos` where the parser stopped, with its hybsim
/// spelling: `~=` → `!=`, `~` → `!`, `&` → `&&`, `|` → `||`. (`&&`, `||`
/// and `!=` are never where a parse fails, so a single `&`, `|` or `~` is.)
fn matlab_operator(text: &str, pos: usize) -> Option<(&'static str, &'static str)> {
    let rest = text.get(pos..)?;
    if rest.starts_with("~=") {
        Some(("~=", "!="))
    } else if rest.starts_with('~') {
        Some(("~", "!"))
    } else if rest.starts_with('&') && !rest.starts_with("&&") {
        Some(("&", "&&"))
    } else if rest.starts_with('|') && !rest.starts_with("||") {
        Some(("|", "||"))
    } else {
        None
    }
}

/// A Python operator word (`and`, `or`, `not`) where the parser stopped or
/// just before it (`x >= 0 and x <= 5` stops at the second `x`, `and`
/// having been read as a name), with its position and hybsim spelling.
fn word_operator(text: &str, pos: usize) -> Option<(usize, &'static str, &'static str)> {
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let spelling = |w: &str| match w {
        "and" => Some(("and", "&&")),
        "or" => Some(("or", "||")),
        "not" => Some(("not", "!")),
        _ => None,
    };
    let (before, rest) = (text.get(..pos)?, text.get(pos..)?);
    let here = &rest[..rest.find(|c: char| !is_word(c)).unwrap_or(rest.len())];
    if let Some((found, write)) = spelling(here) {
        return Some((pos, found, write));
    }
    let end = before.trim_end_matches([' ', '\t']).len();
    let start = before[..end].trim_end_matches(is_word).len();
    let (found, write) = spelling(&before[start..end])?;
    Some((start, found, write))
}

/// The closing delimiter of `open` (`{`, `(` or `[`).
fn closing(open: char) -> char {
    match open {
        '{' => '}',
        '(' => ')',
        _ => ']',
    }
}

/// The delimiters among `kinds` (openers) open before `pos`, innermost
/// last, with their positions: each closer pops the innermost of its own
/// kind (comments and quoted strings skipped).
fn open_delims(text: &str, pos: usize, kinds: &[char]) -> Option<Vec<(usize, char)>> {
    let mut open: Vec<(usize, char)> = Vec::new();
    let (mut comment, mut string) = (false, false);
    for (i, c) in text.get(..pos)?.char_indices() {
        match c {
            '\n' => comment = false,
            _ if comment => {}
            '"' => string = !string,
            _ if string => {}
            '#' => comment = true,
            c if kinds.contains(&c) => open.push((i, c)),
            '}' | ')' | ']' => {
                if let Some(k) = open.iter().rposition(|&(_, o)| closing(o) == c) {
                    open.truncate(k);
                }
            }
            _ => {}
        }
    }
    Some(open)
}

/// The last `{` before `pos` that is not closed before it.
fn unclosed_brace(text: &str, pos: usize) -> Option<usize> {
    open_delims(text, pos, &['{'])?.pop().map(|(i, _)| i)
}

/// The innermost `(` or `[` open at `pos` when the parser stopped there at
/// a closing delimiter of another kind (`-(x + 1` then the block's `}`), at
/// the end of the file or at a line that starts a declaration: that group
/// was not closed. `None` elsewhere (inside a group the parser stops at
/// many tokens that are no closing mistake).
fn unclosed_group(text: &str, pos: usize) -> Option<(usize, char)> {
    let open = open_delims(text, pos, &['{', '(', '['])?;
    let &(at, delim) = open.last()?;
    if delim == '{' {
        return None;
    }
    let rest = text[pos..].trim_start();
    let closer = rest.starts_with(['}', ')', ']']) && !rest.starts_with(closing(delim));
    let ends = at_declaration_or_end(text, pos);
    (closer || ends).then_some((at, delim))
}

/// Another language's spelling where the parser stopped at `pos` (see
/// [`SyntaxError::Foreign`]), with hybsim's.
/// A `:=` (Pascal's, Modelica's and Python's assignment) on the line where
/// the parser stopped, at or after where it stopped: pest stops before it,
/// at the statement it could not complete (`flow { x' := 1 }` stopped at
/// `x'` and read as a flow equation outside its block).
fn walrus(text: &str, pos: usize) -> Option<SyntaxError> {
    let line_start = text.get(..pos)?.rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[pos..].find('\n').map_or(text.len(), |i| pos + i);
    let at = pos + text[pos..line_end].find(":=")?;
    if text[line_start..at].contains('#') {
        return None;
    }
    Some(SyntaxError::Foreign {
        span: Span::new(at, at + 2),
        message: "`:=` is the assignment of Pascal, Modelica and Python; hybsim writes `=`".into(),
        label: "write `=` here".into(),
        help: "equations, resets and declarations take one `=`: `x' = …`, `x+ = …`, `param k = …`"
            .into(),
    })
}

fn foreign_spelling(text: &str, pos: usize) -> Option<SyntaxError> {
    let rest = text.get(pos..)?;
    let before = text.get(..pos)?;
    let prev = before.chars().next_back();
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    // The operand before `pos` ends here (a name, a number, a closing
    // bracket or a transpose).
    let after_operand = |b: &str| {
        b.trim_end_matches([' ', '\t'])
            .chars()
            .next_back()
            .is_some_and(|c| is_word(c) || matches!(c, ')' | ']' | '\''))
    };
    let foreign = |start: usize, end: usize, message: &str, label: &str, help: &str| {
        Some(SyntaxError::Foreign {
            span: Span::new(start, end),
            message: message.into(),
            label: label.into(),
            help: help.into(),
        })
    };
    // A typographic character, as equations copied from a PDF or a word
    // processor bring them (`x′ = −x`, `x ≥ 0`): hybsim's text is ASCII
    // outside comments.
    if let Some(c) = rest.chars().next()
        && let Some(write) = typographic(c)
    {
        let shown = if c.is_whitespace() {
            format!("the space character U+{:04X}", c as u32)
        } else {
            format!("`{c}` (U+{:04X})", c as u32)
        };
        let write = if write == " " {
            "an ordinary space".to_string()
        } else {
            format!("`{write}`")
        };
        return foreign(
            pos,
            pos + c.len_utf8(),
            &format!("{shown} is a typographic character; hybsim writes {write}"),
            &format!("write {write} here"),
            "hybsim's operators and names are ASCII (an equation copied from a PDF often brings \
             `−`, `′`, `≤`, `≥`, `×`): retype them as `-`, `'`, `<=`, `>=`, `*`",
        );
    }
    // `x+` read in an expression (`x+ = x+ + 1`, `when x+ >= 1`): the
    // parser took `x +` for a sum and stopped where its right operand was
    // due. `x+` names the state after a jump, which is only assigned.
    if let Some(plus) = before.trim_end_matches([' ', '\t']).strip_suffix('+')
        && !plus.ends_with([' ', '\t', '+'])
        && let Some(name) = plus
            .rsplit(|c: char| !(is_word(c) || matches!(c, '[' | ']' | '.')))
            .next()
            .filter(|n| n.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_'))
    {
        let at = plus.len() - name.len();
        return foreign(
            at,
            plus.len() + 1,
            &format!("`{name}+` read in an expression; `{name}+` is only assigned"),
            &format!("`{name}+` is the state after the jump"),
            &format!(
                "a reset's right side and a condition read the state before the jump: write \
                 `{name}` (`{name}+ = {name} + 1` increments it)"
            ),
        );
    }
    // `==` where an equation's `=` is expected (`x' == -x`, `x+ == 0`,
    // `param k == 2`): the parse stopped at the second `=`.
    if rest.starts_with('=')
        && let Some(head) = before.strip_suffix('=')
        && !head.ends_with(['<', '>', '!', '='])
        && head
            .trim_end()
            .ends_with(|c: char| is_word(c) || matches!(c, '\'' | '+' | ']'))
    {
        return foreign(
            pos - 1,
            pos + 1,
            "`==` is a comparison; an equation is written with one `=`",
            "write `=` here",
            "`==` compares in conditions (`when q == 1`); a flow equation `x' = …`, a reset \
             `x+ = …` and a declaration `param k = …` take one `=`",
        );
    }
    // A name written with Greek letters or subscript digits, as in the
    // equations of a paper (`θ' = ω`, `x₁`): names are ASCII.
    if let Some(c) = rest.chars().next()
        && ascii_name(c).is_some()
    {
        let word: &str = &rest[..rest
            .find(|c: char| !(c.is_alphanumeric() || c == '_'))
            .unwrap_or(rest.len())];
        let ascii: Option<String> = word
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '_' {
                    Some(c.to_string())
                } else {
                    ascii_name(c).map(str::to_string)
                }
            })
            .collect();
        if let Some(ascii) = ascii {
            return foreign(
                pos,
                pos + word.len(),
                &format!("`{word}` is not an ASCII name; hybsim writes `{ascii}`"),
                &format!("write `{ascii}` here"),
                "names are ASCII letters, digits and `_`: write a Greek letter out (`theta`, \
                 `omega`) and a subscript as a digit (`x1`), in every use of the name",
            );
        }
    }
    // Any other letter outside ASCII (`été`, `x_日本`): the parse stopped at
    // it, maybe inside a name begun in ASCII.
    if rest.starts_with(|c: char| c.is_alphanumeric() && !c.is_ascii()) {
        let start = before.trim_end_matches(is_word).len();
        let len = rest
            .find(|c: char| !(c.is_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        let word = &text[start..pos + len];
        return foreign(
            start,
            pos + len,
            &format!("`{word}` is not an ASCII name"),
            "names are ASCII",
            "names are ASCII letters, digits and `_` (other characters may stand in comments): \
             rename it, in every use of the name",
        );
    }
    // A keyword glued to what follows it (keywords are whole words): other
    // languages' `elseif`, or `else0` for `else 0`.
    let word = &rest[..rest.find(|c: char| !is_word(c)).unwrap_or(rest.len())];
    if let Some(lang) = match word {
        "elseif" => Some("MATLAB's (and Julia's)"),
        "elif" => Some("Python's"),
        "elsif" => Some("Perl's (and Ruby's)"),
        _ => None,
    } {
        return foreign(
            pos,
            pos + word.len(),
            &format!("`{word}` is {lang} spelling; hybsim writes `else if`"),
            "write `else if` here",
            "chain conditions as `if a then x else if b then y else z`",
        );
    }
    if let Some(kw) = ["then", "else", "when", "every", "in", "if"]
        .into_iter()
        .find(|kw| {
            word.strip_prefix(kw)
                .is_some_and(|r| r.starts_with(|c: char| c.is_ascii_digit()))
        })
    {
        let rest = &word[kw.len()..];
        return foreign(
            pos,
            pos + word.len(),
            &format!("`{word}` is one name: `{kw}` is a keyword, a whole word"),
            &format!("write `{kw} {rest}`"),
            &format!("separate the keyword from what follows: `{kw} {rest}`"),
        );
    }
    if rest.starts_with('%') {
        return foreign(
            pos,
            pos + 1,
            "`%` starts a comment in MATLAB; hybsim's comments start with `#`",
            "write `#` here",
            "replace `%` by `#`: everything after `#` on the line is a comment",
        );
    }
    // Two-character spellings, where the parse stops at either character.
    let pair = |c: char| {
        if rest.starts_with(c) && rest[1..].starts_with(c) {
            Some(pos)
        } else if rest.starts_with(c) && prev == Some(c) {
            Some(pos - 1)
        } else {
            None
        }
    };
    if let Some(at) = pair('/') {
        return foreign(
            at,
            at + 2,
            "`//` starts a comment in C; hybsim's comments start with `#`",
            "write `#` here",
            "replace `//` by `#`: everything after `#` on the line is a comment",
        );
    }
    if rest.starts_with(".^") {
        return foreign(
            pos,
            pos + 2,
            "`.^` is MATLAB's elementwise power; hybsim writes `^`",
            "write `^` here",
            "`x^2` for a scalar; elementwise on a vector or matrix, `x .* x` (or `exp(p * log(x))` for x > 0)",
        );
    }
    if rest.starts_with(".'") {
        return foreign(
            pos,
            pos + 2,
            "`.'` is MATLAB's transpose; hybsim writes `'`",
            "write `'` here",
            "hybsim's matrices are real: `A'` is the transpose",
        );
    }
    if let Some(at) = pair('*') {
        return foreign(
            at,
            at + 2,
            "`**` is Python's power; hybsim writes `^`",
            "write `^` here",
            "`x^2` for a scalar (or a square matrix to a constant integer power); elementwise, `x .* x`",
        );
    }
    if rest.starts_with('.')
        && rest[1..].starts_with(|c: char| c.is_ascii_digit())
        && !after_operand(before)
    {
        let digits = rest[1..]
            .find(|c: char| !c.is_ascii_digit())
            .map_or(rest.len(), |i| i + 1);
        return foreign(
            pos,
            pos + digits,
            &format!("a number starts with a digit: write `0{}`", &rest[..digits]),
            &format!("write `0{}`", &rest[..digits]),
            "write a leading zero before the decimal point",
        );
    }
    if let Some(at) = pair('\'') {
        return foreign(
            at,
            at + 2,
            "a flow equation gives a first derivative: `x''` is not written",
            "a second derivative",
            "write a second-order equation as two first-order ones: `x' = v; v' = ...` (with `state v`)",
        );
    }
    if rest.starts_with('(') && prev.is_some_and(is_word) {
        let start = before.trim_end_matches(is_word).len();
        let name = &before[start..];
        // A derivative written as a call on the left of an equation, `dot(x) = …`
        // (MATLAB's and the books' ẋ) or Modelica's `der(x) = …`.
        let inner = rest[1..].trim_start_matches([' ', '\t']);
        let arg = &inner[..inner.find(|c: char| !is_word(c)).unwrap_or(inner.len())];
        let after = inner[arg.len()..].trim_start_matches([' ', '\t']);
        let statement_start = before[..start]
            .trim_end_matches([' ', '\t'])
            .ends_with(['{', ';', '\n']);
        if matches!(name, "dot" | "der" | "diff" | "d" | "D")
            && statement_start
            && arg.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
            && after.starts_with(')')
            && after[1..].trim_start_matches([' ', '\t']).starts_with('=')
            && !after[1..].trim_start_matches([' ', '\t']).starts_with("==")
        {
            return foreign(
                start,
                // Through the `)`.
                text.len() - after.len() + 1,
                &format!("`{name}({arg})` is not how hybsim writes a derivative: write `{arg}'`"),
                &format!("write `{arg}'` here"),
                &format!(
                    "a `flow` block holds equations `{arg}' = f(x)`, the state's name with a prime"
                ),
            );
        }
        if name.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') {
            return foreign(
                start,
                pos + 1,
                &format!(
                    "`{name}(...)` indexes in MATLAB; hybsim indexes with brackets: `{name}[...]`"
                ),
                "indexed with parentheses",
                &format!(
                    "write `{name}[i]` (or `{name}[i, k]` for a matrix), indices starting at 1; \
                     an initial value is written `state {name} = value`"
                ),
            );
        }
    }
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = &before[line_start..];
    // A MATLAB function header, `function xdot = f(x)`: the parse stops
    // after `function`, read as a name.
    if let Some(after) = line.trim_start().strip_prefix("function")
        && after.starts_with([' ', '\t', '['])
    {
        let at = line_start + (line.len() - line.trim_start().len());
        return foreign(
            at,
            at + "function".len(),
            "hybsim has no `function`: a model declares its states and writes its flow, jumps and \
             outputs directly",
            "a MATLAB function header",
            "write the function's body as the model: `state x = ...`, `flow { x' = ... }` for \
             `xdot = f(x)`, `jump when C { x+ = ... }` for a jump map, `output y = ...` for a \
             value computed from the state",
        );
    }
    // MATLAB's `if c ... end` block where a statement starts.
    let statement_start = |b: &str| b.is_empty() || b.ends_with(['\n', '{', '}', ';']);
    if word == "if" && statement_start(before.trim_end_matches([' ', '\t'])) {
        return foreign(
            pos,
            pos + 2,
            "hybsim has no `if` statement: its `if` is an expression, `if c then a else b`",
            "an `if` block",
            "choose a value with `if c then a else b` (`x' = if x > 0 then -1 else 1`); \
             change the state when a condition holds with a jump guarded by it, `jump when c { x+ = ... }`",
        );
    }
    // Resets or flow equations separated by `,` (a newline or `;` separates them).
    if rest.starts_with(',')
        && unclosed_bracket(text, pos).is_none()
        && let Some(open) = unclosed_brace(text, pos)
        && let Some(block) = ["jump", "every", "flow", "for"].into_iter().find(|kw| {
            let ls = text[..open].rfind('\n').map_or(0, |i| i + 1);
            text[ls..open]
                .trim_start()
                .strip_prefix(kw)
                .is_some_and(|r| !r.starts_with(is_word))
        })
    {
        let (what, example) = if block == "flow" {
            ("equations", "x' = v; v' = -1")
        } else {
            ("resets", "x+ = 0; v+ = -v")
        };
        return foreign(
            pos,
            pos + 1,
            &format!("`,` does not separate {what}: a newline or `;` does"),
            "write `;` here",
            &format!(
                "put each of the block's {what} on its own line, or end each with `;`: \
                 `{{ {example} }}`"
            ),
        );
    }
    // A unit glued to a number, `T = 10s`: hybsim's numbers are plain. The
    // parser stops at the unit, or after it when the unit reads as the
    // start of what follows (`x' = -x/10s }`: `s` as the next equation).
    let word_before = before.trim_end();
    let before_start = word_before
        .trim_end_matches(|c: char| c.is_ascii_alphabetic())
        .len();
    if let Some(e) = glued_unit(text, pos).or_else(|| {
        (before_start < word_before.len())
            .then(|| glued_unit(text, before_start))
            .flatten()
    }) {
        return Some(e);
    }
    if rest.starts_with('=') && !rest.starts_with("==") && !before.ends_with(['<', '>', '!', '=']) {
        // `=` inside a condition: after `when`, `in`, `if`, ... on this line
        // and not inside a block opened after it.
        let words = ["when", "in", "if", "always", "within"];
        let cond = line
            .match_indices(|c: char| !is_word(c))
            .map(|(i, m)| i + m.len())
            .chain(std::iter::once(0))
            .filter(|&i| {
                let w = &line[i..];
                let w = &w[..w.find(|c: char| !is_word(c)).unwrap_or(w.len())];
                words.contains(&w)
            })
            .max();
        if let Some(i) = cond
            && !line[i..].contains(['{', '}'])
        {
            return foreign(
                pos,
                pos + 1,
                "`=` in a condition: hybsim compares with `==`",
                "write `==` here",
                "`x == 0` holds where x equals 0 (`=` only assigns, in `param`, `state`, equations and resets)",
            );
        }
    }
    // A flow set without `in`: the parser read its first name as a new
    // declaration, right after a flow block's `}` on the same line.
    let trimmed = before.trim_end_matches([' ', '\t']);
    let word_start = trimmed.trim_end_matches(is_word);
    if word_start.len() < trimmed.len()
        && let Some(close) = word_start.trim_end_matches([' ', '\t']).strip_suffix('}')
        && close.len() >= line_start
        && let Some(open) = unclosed_brace(text, close.len())
        && text[..open].trim_end().ends_with("flow")
    {
        let at = close.len();
        return foreign(
            at,
            at + 1,
            "a flow set is written after `in`: `flow { ... } in CONDITION`",
            "`in` expected after this `}`",
            "write `in` between the flow block and its flow set C",
        );
    }
    // A flow set written after a jump's block (`jump r when g { ... } in C`,
    // as if C were the jump's): C belongs to the flow block.
    if rest.starts_with("in")
        && !rest[2..].starts_with(is_word)
        && let Some(close) = before.trim_end().strip_suffix('}')
        && let Some(open) = unclosed_brace(text, close.len())
        && text[..open][text[..open].rfind('\n').map_or(0, |i| i + 1)..]
            .trim_start()
            .starts_with("jump")
    {
        return foreign(
            pos,
            pos + 2,
            "a flow set belongs to the flow block, not to a jump",
            "`in` after a jump's block",
            "C is written after the flow block, `flow { x' = 1 } in x <= 1`; a jump's set is its `when` condition",
        );
    }
    // MATLAB's `end`, alone on its line: read as the start of a declaration.
    let is_end = |at: usize| {
        let ls = text[..at].rfind('\n').map_or(0, |i| i + 1);
        let le = text[at..].find('\n').map_or(text.len(), |i| at + i);
        text[ls..le].trim() == "end"
    };
    let last = before.trim_end();
    if rest.starts_with("end") && is_end(pos) {
        return end_keyword(pos);
    }
    if last.ends_with("end") && is_end(last.len() - 3) {
        return end_keyword(last.len() - 3);
    }
    // Matrix entries separated by spaces, as MATLAB allows: the parser
    // stopped at the second entry, inside `[`.
    if rest.starts_with(|c: char| is_word(c) || c == '(')
        && before.ends_with([' ', '\t'])
        && after_operand(before)
        && unclosed_bracket(text, pos).is_some()
    {
        return foreign(
            pos,
            pos + rest
                .find(|c: char| !is_word(c))
                .unwrap_or(rest.len())
                .max(1),
            "matrix entries are separated by `,` (rows by `;`), not by spaces",
            "`,` expected before this entry",
            "write `[0, 1; -1, 0]` for MATLAB's `[0 1; -1 0]`",
        );
    }
    // MATLAB's `sum(x)` of a vector: hybsim's `sum` is a comprehension, so
    // the parser stopped where it wanted `in`, inside `sum(`.
    if let Some(open) = before.rfind('(')
        && before[..open]
            .trim_end_matches([' ', '\t'])
            .ends_with("sum")
        && !before[..open]
            .trim_end_matches([' ', '\t'])
            .trim_end_matches("sum")
            .ends_with(is_word)
        && !before[open..].contains([')', ':', '\n'])
        && (rest.starts_with([')', ',']) || before[open + 1..].trim().is_empty())
    {
        let arg = before[open + 1..].trim();
        let arg = if !arg.is_empty() && arg.chars().all(is_word) {
            arg
        } else {
            "v"
        };
        return foreign(
            pos,
            pos + 1,
            &format!(
                "`sum({arg})` sums a vector in MATLAB; hybsim's `sum` runs over indices: \
                 `sum(k in 1..n: {arg}[k])`"
            ),
            "a sum over indices expected: `sum(k in a..b: expression)`",
            &format!(
                "write `sum(k in 1..length({arg}): {arg}[k])` for the entries of a vector, \
                 or `ones(1, length({arg}))*{arg}`"
            ),
        );
    }
    // Several declarations on one line joined by `;` (`state h = 1; v = 0`):
    // the second reads as an instance `v = Sub(…)`, and the parse stops at its value.
    let line_words = line.trim_start();
    if let Some(kw) = ["state", "param"].into_iter().find(|kw| {
        line_words
            .strip_prefix(kw)
            .is_some_and(|r| r.starts_with([' ', '\t']))
    }) && let Some(semi) = line.rfind(';')
        && let Some(name) = line[semi + 1..].trim().strip_suffix('=')
        && let name = name.trim_end()
        && !name.is_empty()
        && name.chars().all(is_word)
    {
        let at = line_start + semi;
        return foreign(
            at,
            at + 1,
            &format!("`;` ends the `{kw}` declaration, so `{name} = ...` is not declared"),
            "the declaration ends here",
            &format!(
                "declare several on one line with `,`: `{}, {name} = ...` \
                 (or repeat the keyword: `; {kw} {name} = ...`)",
                line[..semi].trim()
            ),
        );
    }
    // Two declarations on one line with nothing between them (`state x = 1 y = 2`): the
    // second reads as an instance `y = Sub(…)` as well, and the parse stopped at its value
    // with "expected a name".
    if let Some(kw) = ["state", "param"].into_iter().find(|kw| {
        line_words
            .strip_prefix(kw)
            .is_some_and(|r| r.starts_with([' ', '\t']))
    }) && let Some(head) = line.trim_end().strip_suffix('=')
        && let head = head.trim_end()
        && let name_start = head.rfind(|c: char| !is_word(c)).map_or(0, |i| i + 1)
        && let name = &head[name_start..]
        && name.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
        && let first = &head[..name_start]
        && first.ends_with([' ', '\t'])
        && after_operand(first)
        && first.contains('=')
    {
        let at = line_start + name_start;
        return foreign(
            at,
            at + name.len(),
            &format!("`{name} = ...` follows the `{kw}` declaration with no `,` before it"),
            "a `,` expected before this",
            &format!(
                "declare several on one line with `,`: `{}, {name} = ...` \
                 (or put `{kw} {name} = ...` on a line of its own)",
                first.trim()
            ),
        );
    }
    None
}

/// Other languages' ranges where the parse stopped at `pos`: MATLAB's `for i =
/// 1:N` (stopped at `=`, where `in` belongs) and `1:N` after a loop's or a
/// comprehension's `in` (`for i in 1:N`, `sum(k in 1:N: …)`, stopped at the
/// `:`), Python's `for i in range(N)`, where hybsim writes `a..b`; and `..` in
/// brackets, a slice `x[1..3]` (hybsim's is `x[1:3]`) or a family declared at
/// once, `state x[1..N] = 0`.
fn matlab_range(text: &str, pos: usize) -> Option<SyntaxError> {
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let before = text.get(..pos)?;
    let line = &before[before.rfind('\n').map_or(0, |i| i + 1)..];
    let rest = text.get(pos..)?;
    // `head` ends with `for NAME` (`Some(true)`) or `(NAME`, a comprehension's
    // binder (`Some(false)`).
    fn binder(head: &str) -> Option<(&str, bool)> {
        let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
        let head = head.trim_end_matches([' ', '\t']);
        let name_start = head.trim_end_matches(is_word).len();
        let name = &head[name_start..];
        let before = head[..name_start].trim_end_matches([' ', '\t']);
        let by_for = name_start > before.len()
            && before
                .strip_suffix("for")
                .is_some_and(|b| !b.ends_with(is_word));
        (name.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
            && (by_for || before.ends_with('(')))
        .then_some((name, by_for))
    }
    let help = "a range is `a..b`, both ends included (`for i in 1..N`, `sum(k in 1..N: x[k])`), \
                in steps of 1: for another step filter it, `for i in 1..N if mod(i, 2) == 0`";
    if rest.starts_with('=')
        && !rest.starts_with("==")
        && let Some((name, true)) = binder(line)
    {
        return Some(SyntaxError::Foreign {
            span: Span::new(pos, pos + 1),
            message: format!(
                "`for {name} = …` is MATLAB's loop; hybsim writes `for {name} in a..b`"
            ),
            label: "write `in` here".into(),
            help: help.into(),
        });
    }
    // `..` in brackets: a slice (`x[1..3]`, written `x[1:3]`) or a family
    // declared at once (`state x[1..N] = 0`), where the parse stopped at `..`.
    if rest.starts_with("..")
        && let Some(open) = unclosed_bracket(text, pos)
        && open >= pos - line.len()
    {
        let head = &text[pos - line.len()..open];
        let name = &head[head.trim_end_matches(is_word).len()..];
        let words: Vec<&str> = head.split_whitespace().collect();
        if let [kw @ ("state" | "param" | "output"), declared] = words[..]
            && declared == name
            && !name.is_empty()
        {
            let hi = &rest[2..];
            let hi = hi[..hi.find([']', '\n']).unwrap_or(hi.len())].trim();
            let range = format!("{}..{hi}", text[open + 1..pos].trim());
            return Some(SyntaxError::Foreign {
                span: Span::new(pos, pos + 2),
                message: format!(
                    "`{kw} {name}[{range}]` declares no family: its members are declared in a loop"
                ),
                label: "a range in a declaration".into(),
                help: format!(
                    "write `for i in {range} {{ {kw} {name}[i] = … }}` for a family (read as `{name}[i]`), \
                     or one vector, `{kw} {name} = zeros({hi}, 1)` (read as `{name}[1]`, …)"
                ),
            });
        }
        if !name.is_empty() {
            return Some(SyntaxError::Foreign {
                span: Span::new(pos, pos + 2),
                message: "`..` in an index: a slice is written `a:b`".into(),
                label: "write `:` here".into(),
                help: format!(
                    "`{name}[2:3]` is the entries 2 to 3, `{name}[:, 1]` a column; `a..b` is the range of a loop or a sum"
                ),
            });
        }
    }
    // The last `in` of the line, as a whole word, bound by `for NAME` or `(NAME`,
    // and only an operand (no range yet) between it and where the parse stopped.
    let at = line
        .rmatch_indices("in")
        .find(|(i, _)| !line[..*i].ends_with(is_word) && !line[i + 2..].starts_with(is_word))?
        .0;
    let after_in = &line[at + 2..];
    let operand = after_in.trim();
    let binder = binder(&line[..at]);
    if binder.is_none()
        || operand.is_empty()
        || operand.contains("..")
        || operand.contains([':', '{', '}', '<', '>', '=', '!', '&', '|'])
    {
        return None;
    }
    if rest.starts_with(':') && !rest.starts_with("::") {
        return Some(SyntaxError::Foreign {
            span: Span::new(pos, pos + 1),
            message: "`a:b` is MATLAB's range; hybsim writes `a..b`".into(),
            label: "write `..` here".into(),
            help: help.into(),
        });
    }
    // Python's `for i in range(N)`: the parse stopped after it, wanting `..`.
    if let Some(arg) = operand
        .strip_prefix("range")
        .map(|r| r.trim_start())
        .and_then(|r| r.strip_prefix('('))
        .and_then(|r| r.strip_suffix(')'))
    {
        let from = pos - after_in.trim_start().len();
        return Some(SyntaxError::Foreign {
            span: Span::new(from, from + operand.len()),
            message: format!(
                "`range({arg})` is Python's range; hybsim writes `1..{arg}` (indices start at 1)"
            ),
            label: format!("write `1..{arg}` here"),
            help: help.into(),
        });
    }
    None
}

/// The error for a unit glued to a number (`10s`, `1e-3s`) if the word at
/// `start` is one, and no name of the model has its spelling.
fn glued_unit(text: &str, start: usize) -> Option<SyntaxError> {
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let (before, rest) = (text.get(..start)?, text.get(start..)?);
    let word = &rest[..rest.find(|c: char| !is_word(c)).unwrap_or(rest.len())];
    // The number's start, through an exponent's sign (`1e-3s`).
    fn digits(b: &str) -> &str {
        b.trim_end_matches(|c: char| c.is_ascii_alphanumeric() || c == '.')
    }
    let glued = before
        .chars()
        .next_back()
        .is_some_and(|c| c.is_ascii_digit())
        && digits(before)
            .chars()
            .next_back()
            .is_none_or(|c| !is_word(c))
        && UNITS.contains(&word)
        && !declares(text, word);
    if !glued {
        return None;
    }
    let mut head = digits(before);
    if head.ends_with(['-', '+']) && head[..head.len() - 1].ends_with(['e', 'E']) {
        head = digits(&head[..head.len() - 1]);
    }
    let number = &before[head.len()..];
    Some(SyntaxError::Foreign {
        span: Span::new(head.len(), start + word.len()),
        message: format!("`{number}{word}`: a number has no unit in hybsim"),
        label: format!("write `{number}` here"),
        help: format!(
            "write the number alone, in the model's units: `{number}` (a comment can name the \
             unit: `# {word}`)"
        ),
    })
}

/// Unit symbols a number may be written with (`10s`, `5ms`, `2kg`), where no
/// name of the model has that spelling.
const UNITS: &[&str] = &[
    "s", "sec", "secs", "ms", "us", "ns", "min", "h", "hr", "Hz", "hz", "kHz", "m", "cm", "mm",
    "km", "kg", "g", "N", "Nm", "rad", "deg", "V", "mV", "A", "mA", "W", "kW",
];

/// Whether `name` occurs in `text` as a declared name would: a whole word
/// somewhere (a rough test that keeps `2g` a product where `g` is declared).
fn declares(text: &str, name: &str) -> bool {
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    text.match_indices(name)
        .any(|(i, _)| !text[..i].ends_with(is_word) && !text[i + name.len()..].starts_with(is_word))
}

/// hybsim's spelling of a typographic character that stands for one of its
/// operators, constants or a space.
fn typographic(c: char) -> Option<&'static str> {
    Some(match c {
        '−' | '–' | '—' | '‐' | '‑' => "-",
        '′' | '’' | '‘' | '´' => "'",
        '≤' | '⩽' => "<=",
        '≥' | '⩾' => ">=",
        '≠' => "!=",
        '×' | '·' | '⋅' | '∗' => "*",
        '÷' | '∕' => "/",
        '∧' => "&&",
        '∨' => "||",
        '¬' => "!",
        'π' => "pi",
        '∞' => "inf",
        '\u{a0}' | '\u{2009}' | '\u{202f}' => " ",
        _ => return None,
    })
}

/// The ASCII spelling of a Greek letter (but `π`, the constant
/// [`typographic`] reads as `pi`) or a subscript digit in a name.
fn ascii_name(c: char) -> Option<&'static str> {
    const LOWER: [&str; 25] = [
        "alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta", "iota", "kappa",
        "lambda", "mu", "nu", "xi", "omicron", "pi", "rho", "sigma", "sigma", "tau", "upsilon",
        "phi", "chi", "psi", "omega",
    ];
    const SUBSCRIPTS: [&str; 10] = ["0", "1", "2", "3", "4", "5", "6", "7", "8", "9"];
    Some(match c {
        // U+03C2 is the final sigma, between rho and sigma.
        'α'..='ω' if c != 'π' => LOWER[c as usize - 'α' as usize],
        'Α'..='Ω' if c != 'Π' && c != '\u{3a2}' => {
            let lower = LOWER[c as usize - 'Α' as usize];
            // Capital Γ, Δ, … as `Gamma`, `Delta`.
            match lower {
                "gamma" => "Gamma",
                "delta" => "Delta",
                "theta" => "Theta",
                "lambda" => "Lambda",
                "xi" => "Xi",
                "sigma" => "Sigma",
                "phi" => "Phi",
                "psi" => "Psi",
                "omega" => "Omega",
                _ => return None,
            }
        }
        'ϕ' => "phi",
        'ϑ' => "theta",
        'ϵ' => "epsilon",
        '₀'..='₉' => SUBSCRIPTS[c as usize - '₀' as usize],
        _ => return None,
    })
}

/// Two operands side by side with no operator between them (`-k x`, `2 pi`,
/// a product written as in mathematics) on the line where the parse stopped
/// at `pos` (or the line before, when it stopped at the next one): the pair
/// nearest `pos` whose `*` lets `text` parse as `rule` past that line, else
/// the nearest of several that do so together (`sin(2 pi t)`); a `*` that
/// leaves an error on the line is no fix (`state x = 1 y = 2`, a missing
/// `,`, is not taken for a product). The parse
/// may stop well after the pair (`x' = -k x }` reads `x` as the next
/// equation and stops at `}`), so each candidate is checked by re-parsing.
fn missing_operator(text: &str, pos: usize, rule: Rule) -> Option<SyntaxError> {
    use pest::Parser;
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == '.';
    let before = text.get(..pos)?;
    // From the start of the line holding the last token before `pos`.
    let last = before.trim_end().len();
    let line_start = before[..last].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[pos..].find('\n').map_or(text.len(), |i| pos + i);
    let line = &text[line_start..line_end];
    let line = &line[..line.find('#').unwrap_or(line.len())];
    // Gaps of spaces between an operand's end and an operand's start that
    // are not keywords (`0 then`), on the whole line, nearest `pos` first (a
    // handful: each costs a parse).
    let bytes = line.as_bytes();
    let token = |s: &str, from_end: bool| -> String {
        if from_end {
            // The operand's last name or number with its transposes (`A'`).
            let t = s.trim_end();
            let w = t.trim_end_matches('\'');
            let start = w.trim_end_matches(is_word).len();
            if start == t.len() {
                t[t.len() - 1..].to_string()
            } else {
                t[start..].to_string()
            }
        } else {
            let end = s.find(|c: char| !is_word(c)).unwrap_or(s.len());
            s[..end.max(1)].to_string()
        }
    };
    let mut at: Vec<usize> = (1..line.len())
        .filter(|&i| {
            let (prev, next) = (bytes[i - 1] as char, bytes[i] as char);
            matches!(prev, ' ' | '\t')
                && (is_word(next) || next == '(')
                && line[..i]
                    .trim_end()
                    .chars()
                    .next_back()
                    .is_some_and(|c| is_word(c) || matches!(c, ')' | ']' | '\''))
        })
        .collect();
    at.sort_by_key(|&i| (line_start + i).abs_diff(pos));
    let gaps: Vec<(usize, String, String)> = at
        .into_iter()
        .map(|i| (i, token(&line[..i], true), token(&line[i..], false)))
        .filter(|(_, a, b)| !KEYWORDS.contains(&a.as_str()) && !KEYWORDS.contains(&b.as_str()))
        .take(4)
        .collect();
    // Whether `text` with a `*` after the first operand of each gap in
    // `with` parses past the line.
    let parses = |with: &[&(usize, String, String)]| {
        let mut ends: Vec<usize> = with
            .iter()
            .map(|(i, ..)| line_start + line[..*i].trim_end().len())
            .collect();
        ends.sort_unstable();
        let mut fixed = String::with_capacity(text.len() + ends.len());
        let mut from = 0;
        for e in ends {
            fixed.push_str(&text[from..e]);
            fixed.push('*');
            from = e;
        }
        fixed.push_str(&text[from..]);
        match HybParser::parse(rule, &fixed) {
            Ok(_) => true,
            Err(e) => match e.location {
                InputLocation::Pos(p) | InputLocation::Span((p, _)) => p > line_end + with.len(),
            },
        }
    };
    // One product (`-k x`), else all of them (`sin(2 pi t)`), named at the
    // gap nearest where the parse stopped.
    let found = gaps
        .iter()
        .find(|g| parses(&[g]))
        .or_else(|| (gaps.len() > 1 && parses(&gaps.iter().collect::<Vec<_>>())).then(|| &gaps[0]));
    let (i, a, b) = found?;
    let at = line_start + i;
    Some(SyntaxError::Foreign {
        span: Span::new(at, at + b.len()),
        message: format!(
            "an operator is missing between `{a}` and `{b}`: hybsim does not multiply by juxtaposition"
        ),
        label: "an operator expected before this".into(),
        help: format!(
            "write `{a}*{b}` for the product (or separate two entries with `,`, two statements with `;` or a new line)"
        ),
    })
}

/// MATLAB's `end` at `at`.
fn end_keyword(at: usize) -> Option<SyntaxError> {
    Some(SyntaxError::Foreign {
        span: Span::new(at, at + 3),
        message: "hybsim has no `end`: blocks are written in braces `{ ... }`".into(),
        label: "MATLAB's `end`".into(),
        help: "delete `end`; a block ends with its `}`".into(),
    })
}

/// The last `[` before `pos` that is not closed before it.
fn unclosed_bracket(text: &str, pos: usize) -> Option<usize> {
    open_delims(text, pos, &['['])?.pop().map(|(i, _)| i)
}

/// `NAME =` where the parser stopped at `=` inside a `flow` block: the
/// start of `NAME` and its text.
fn flow_without_prime(text: &str, pos: usize) -> Option<(usize, String)> {
    let rest = text.get(pos..)?;
    if !rest.starts_with('=') || rest.starts_with("==") {
        return None;
    }
    let is_word = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let before = text.get(..pos)?.trim_end_matches([' ', '\t']);
    let start = before.trim_end_matches(is_word).len();
    let name = &before[start..];
    if name.is_empty() || !name.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') {
        return None;
    }
    let brace = unclosed_brace(text, start)?;
    let opener = text[..brace].trim_end();
    opener.ends_with("flow").then(|| (start, name.to_string()))
}

/// The unclosed `{` of a block when the parser stopped at the end of the
/// file or at the first word of a line that begins a declaration (or
/// `in`, the flow set after a flow block): the block was not closed.
fn unclosed_before_declaration(text: &str, pos: usize) -> Option<usize> {
    if !at_declaration_or_end(text, pos) {
        return None;
    }
    unclosed_brace(text, pos)
}

/// Whether `pos` is the end of the file (but for blanks) or the first word
/// of a line that begins a declaration (or `in`, the flow set after a flow
/// block).
fn at_declaration_or_end(text: &str, pos: usize) -> bool {
    const STARTS: [&str; 13] = [
        "in",
        "flow",
        "jump",
        "every",
        "state",
        "param",
        "sim",
        "output",
        "noise",
        "design",
        "import",
        "subsystem",
        "log",
    ];
    let Some(rest) = text.get(pos..) else {
        return false;
    };
    let line_start = text[..pos].rfind('\n').map_or(0, |i| i + 1);
    let at_line_start = text[line_start..pos].trim().is_empty();
    let word = &rest[..rest
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(rest.len())];
    rest.trim().is_empty() || (at_line_start && STARTS.contains(&word))
}

/// The token at `pos`, in words, and its length in bytes.
fn found_at(text: &str, pos: usize) -> (String, usize) {
    let rest = text.get(pos..).unwrap_or("");
    let Some(c) = rest.chars().next() else {
        return ("end of file".into(), 0);
    };
    if c == '\n' || c == '\r' {
        return ("end of line".into(), c.len_utf8());
    }
    // Named, not echoed: a NUL or an escape sequence is invisible (or acts on
    // the terminal) inside backticks.
    if c.is_control() {
        return (
            format!("control character U+{:04X}", c as u32),
            c.len_utf8(),
        );
    }
    let word: String = if c.is_ascii_alphanumeric() || c == '_' {
        rest.chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_' || *c == '.')
            .take(24)
            .collect()
    } else {
        c.to_string()
    };
    let len = word.len();
    (format!("`{word}`"), len)
}

/// What a grammar rule means to a user; `None` for rules that never appear
/// alone in an expectation.
fn describe(rule: Rule) -> Option<&'static str> {
    Some(match rule {
        Rule::EOI => "end of file",
        Rule::header | Rule::b_model => "`model NAME` at the start of the file",
        Rule::ident | Rule::target | Rule::rule_path => "a name",
        Rule::number => "a number",
        Rule::expr
        | Rule::if_expr
        | Rule::or_expr
        | Rule::add_expr
        | Rule::unary
        | Rule::postfix
        | Rule::paren
        | Rule::call
        | Rule::matrix
        | Rule::sum_expr
        | Rule::extreme_expr
        | Rule::extreme_op
        | Rule::boolean
        | Rule::prefix_op => "an expression",
        Rule::param_decl
        | Rule::b_param
        | Rule::b_graph
        | Rule::b_state
        | Rule::b_noise
        | Rule::b_flow
        | Rule::b_jump
        | Rule::b_output
        | Rule::b_sim
        | Rule::b_design
        | Rule::param_tuple
        | Rule::param_table
        | Rule::table_call
        | Rule::w_table
        | Rule::graph_decl
        | Rule::state_decl
        | Rule::noise_decl
        | Rule::flow_block
        | Rule::jump_decl
        | Rule::every_decl
        | Rule::output_decl
        | Rule::sim_block
        | Rule::for_item
        | Rule::param_rand
        | Rule::w_check
        | Rule::together_block
        | Rule::w_together
        | Rule::design_block
        | Rule::import_decl
        | Rule::w_import
        | Rule::subsystem_decl
        | Rule::w_subsystem
        | Rule::instance_decl => {
            "a declaration (param, state, flow, jump, every, output, sim, ...)"
        }
        Rule::input_decl | Rule::w_input | Rule::sub_for => {
            "a subsystem item (param, input, state, flow, jump, every, output, for, an instance)"
        }
        Rule::sub_params | Rule::sub_param => "parameters `(name = default, ...)`",
        Rule::inst_arg => "an argument `name = value`",
        Rule::string => "a quoted path",
        Rule::together_for => "a rule (`jump`, `every`, `for`)",
        Rule::flow_eq | Rule::flow_for => "an equation `x' = ...`",
        Rule::reset_eq | Rule::reset_for => "a reset `x+ = ...`",
        // Apart: an `every` rule is also a declaration, where `when` cannot
        // start anything (after `jump NAME` both are expected).
        Rule::when_clause | Rule::b_when => "`when`",
        Rule::every_clause | Rule::b_every => "`every`",
        // A keyword's look-ahead stands for the rule it starts when it is the
        // only thing tried there.
        Rule::b_for => "`for`",
        Rule::b_in => "`in`",
        Rule::b_if => "`if`",
        Rule::b_then => "`then`",
        Rule::b_else => "`else`",
        Rule::b_sum => "`sum`",
        Rule::b_out => "`out`",
        Rule::b_edges => "`edges`",
        Rule::reset_block => "`{`",
        Rule::reset_post => "`+`",
        Rule::sim_setting | Rule::log_setting | Rule::log_key => "a setting `key = value`",
        Rule::index_list => "`[`",
        Rule::index_arg | Rule::slice_hi | Rule::colon_all => "an index",
        Rule::transpose => "`'`",
        // A flow equation's prime (its help says more).
        Rule::flow_prime => FLOW_PRIME,
        Rule::op_or | Rule::op_and | Rule::cmp_op | Rule::add_op | Rule::mul_op | Rule::op_pow => {
            "an operator"
        }
        Rule::binder | Rule::binder_vars => "an index variable",
        Rule::set | Rule::set_range | Rule::set_in | Rule::set_out | Rule::set_edges => {
            "an index set (`1..N`, `in(G, i)`, `out(G, i)`, `edges(G)`)"
        }
        // --- design ---
        Rule::set_subsets | Rule::set_named => "an index set (`1..N`, `subsets(1..N)`, `S`)",
        Rule::design_var | Rule::var_kind => {
            "a decision variable (`sym P[n]`, `full U[n, m]`, `diag D[n]`, `scalar g`)"
        }
        Rule::var_decl => "a variable name",
        Rule::var_member | Rule::member_close => "a family index and a size (`sym P[k][n]`)",
        Rule::design_obj | Rule::obj_sense => "`minimize` or `maximize`",
        Rule::design_for | Rule::design_if => "`for` or `if`",
        Rule::design_cons | Rule::lmi_side | Rule::lmi_blocks | Rule::lmi_row | Rule::lmi_elem => {
            "a constraint such as `[P, A'*P; *, P] > 0`"
        }
        Rule::lmi_star => "`*`",
        Rule::lmi_rel => "a relation (`>`, `>=`, `<`, `<=`, `==`)",
        Rule::cons_label => "a constraint label",
        Rule::init_eq | Rule::init_draw => "`=` or `~` and an initial value",
        Rule::definition => "a definition `name = value`",
        Rule::state_def => "a state name",
        Rule::log_list => "a list `vars = [names]` or `rules = [names]`",
        Rule::log_name => "a state, output or rule name (`xh`, `xh[2]`, `v.redraw`)",
        Rule::prop_always
        | Rule::prop_after
        | Rule::prop_flows
        | Rule::prop_jumps
        | Rule::prop_eventually
        | Rule::prop_monotone
        | Rule::prop_exponential
        | Rule::w_always
        | Rule::w_after
        | Rule::w_during
        | Rule::w_at
        | Rule::w_eventually
        | Rule::w_decreasing
        | Rule::w_nonincreasing
        | Rule::w_exponential => {
            "a property body (`always P`, `during flows P`, `at jumps P`, `after E always P`, \
             `eventually within T P`, `decreasing V during flows`, `nonincreasing V at jumps`, \
             `exponential V kappa K alpha A`)"
        }
        Rule::w_flows => "`flows`",
        Rule::w_jumps => "`jumps`",
        Rule::w_within => "`within`",
        Rule::w_kappa => "`kappa`",
        Rule::w_alpha => "`alpha`",
        Rule::scope_flows | Rule::scope_jumps => "`during flows` or `at jumps`",
        _ => return None,
    })
}
