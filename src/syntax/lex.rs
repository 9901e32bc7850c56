//! The tokens of `.hyb` text, with their positions: what the formatter
//! rearranges and what the mutation tests edit. Lexing does not validate
//! (the pest grammar does): any text splits into tokens, whitespace and
//! comments, so that token-level tools also work on text that does not
//! parse.

/// What kind of token.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TokenKind {
    /// A name or keyword.
    Word,
    /// A number literal.
    Number,
    /// A string literal (`"…"`).
    Str,
    /// An operator or punctuation character sequence.
    Op,
    /// `#` to the end of the line.
    Comment,
}

/// One token of the source.
#[derive(Debug, Clone)]
pub struct Token<'a> {
    /// What it is.
    pub kind: TokenKind,
    /// Its text.
    pub text: &'a str,
    /// Byte offset of its first character in the source.
    pub offset: usize,
    /// Line of the source (from 0).
    pub line: usize,
    /// Column in characters (from 0).
    pub col: usize,
    /// Whitespace separates it from the previous token on its line.
    pub spaced: bool,
}

/// Operators, longest first so that `<=` wins over `<`.
const OPS: &[&str] = &[
    "||", "&&", "<=", ">=", "==", "!=", ".*", "./", "..", "'", "+", "-", "*", "/", "^", "<", ">",
    "!", "=", "~", "(", ")", "[", "]", "{", "}", ",", ";", ":",
];

/// Splits `text` into tokens (comments included; whitespace, CR and a
/// byte-order mark skipped).
///
/// ```
/// use hybsim::syntax::lex::{TokenKind, tokens};
/// let t = tokens("x' = -2.5e-1 * x  # decay");
/// let texts: Vec<&str> = t.iter().map(|t| t.text).collect();
/// assert_eq!(texts, ["x", "'", "=", "-", "2.5e-1", "*", "x", "# decay"]);
/// assert_eq!(t[4].kind, TokenKind::Number);
/// assert_eq!((t[7].offset, t[7].col), (18, 18));
/// ```
pub fn tokens(text: &str) -> Vec<Token<'_>> {
    let mut tokens = Vec::new();
    let mut line_start = 0;
    for (line, src) in text.split('\n').enumerate() {
        let offset0 = line_start;
        line_start += src.len() + 1;
        let src = src.strip_suffix('\r').unwrap_or(src);
        let mut rest = src;
        let mut spaced = false;
        // The column in characters, counted as the line is consumed (counting
        // from the line's start at each token made long lines quadratic).
        let mut col = 0;
        while let Some(c) = rest.chars().next() {
            let at = src.len() - rest.len();
            if c.is_whitespace() || c == '\u{feff}' {
                rest = &rest[c.len_utf8()..];
                col += 1;
                spaced = true;
                continue;
            }
            let (kind, len) = if c == '#' {
                (TokenKind::Comment, rest.len())
            } else if c == '"' {
                let end = rest[1..].find('"').map_or(rest.len(), |i| i + 2);
                (TokenKind::Str, end)
            } else if c.is_ascii_alphabetic() || c == '_' {
                let end = rest
                    .find(|ch: char| !(ch.is_ascii_alphanumeric() || ch == '_'))
                    .unwrap_or(rest.len());
                (TokenKind::Word, end)
            } else if c.is_ascii_digit() {
                (TokenKind::Number, number_len(rest))
            } else if let Some(op) = OPS.iter().find(|op| rest.starts_with(**op)) {
                (TokenKind::Op, op.len())
            } else {
                (TokenKind::Op, c.len_utf8())
            };
            tokens.push(Token {
                kind,
                text: &rest[..len],
                offset: offset0 + at,
                line,
                col,
                spaced,
            });
            col += rest[..len].chars().count();
            rest = &rest[len..];
            spaced = false;
        }
    }
    tokens
}

/// Length of the number literal at the start of `s` (the grammar's
/// `digits ("." digits)? (e ("+"|"-")? digits)?`; `1..N` is `1`, `..`, `N`).
fn number_len(s: &str) -> usize {
    let b = s.as_bytes();
    let digits = |mut i: usize| {
        while i < b.len() && b[i].is_ascii_digit() {
            i += 1;
        }
        i
    };
    let mut i = digits(0);
    if i + 1 < b.len() && b[i] == b'.' && b[i + 1].is_ascii_digit() {
        i = digits(i + 1);
    }
    if i < b.len() && (b[i] == b'e' || b[i] == b'E') {
        let mut k = i + 1;
        if k < b.len() && (b[k] == b'+' || b[k] == b'-') {
            k += 1;
        }
        if k < b.len() && b[k].is_ascii_digit() {
            i = digits(k);
        }
    }
    i
}
