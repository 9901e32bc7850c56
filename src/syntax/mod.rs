//! Parsing: the pest binding of `grammar/hyb.pest`, the AST with spans, and
//! [`SyntaxError`] in the user's words.

pub mod ast;
mod design;
mod error;
mod format;
pub mod lex;
mod parse;
mod property;
#[cfg(test)]
mod tests;

pub use error::SyntaxError;
pub use format::format_source;
pub use parse::{MAX_EXPR_DEPTH, MAX_NESTING, parse_expr, parse_library, parse_model};

/// The `sim` settings whose value is a word, with their words (the checker
/// decides them; the parser names them where a keyword was written
/// instead, `priority = flow`).
pub(crate) const SETTING_WORDS: &[(&str, &[&str])] = &[
    (
        "solver",
        &[
            "dopri5",
            "dop853",
            "radau5",
            "bdf",
            "auto",
            "rk4",
            "euler_maruyama",
        ],
    ),
    ("priority", &["jumps", "flows", "random"]),
    ("jump_choice", &["first", "random"]),
    ("exact_affine", &["auto", "on", "off"]),
    ("linear_solver", &["auto", "dense", "sparse"]),
    ("jit", &["on", "off"]),
];

/// The words of `sim` setting `key` (see [`SETTING_WORDS`]).
pub(crate) fn setting_words(key: &str) -> Option<&'static [&'static str]> {
    SETTING_WORDS
        .iter()
        .find(|(k, _)| *k == key)
        .map(|(_, words)| *words)
}

/// What to write for `word`, refused as the value of `sim` setting `key`
/// (`None`: `key` does not take words): the closest word, and all of them.
pub(crate) fn setting_word_help(key: &str, word: &str) -> Option<String> {
    let words = setting_words(key)?;
    let one_of = format!("`{key}` is one of {}", words.join(", "));
    Some(match closest_word(word, words) {
        Some(w) => format!("did you mean `{w}`? {one_of}"),
        None => one_of,
    })
}

/// The word of `words` closest to `word` (Jaro–Winkler ≥ 0.7), if it is
/// not one of them.
pub(crate) fn closest_word(word: &str, words: &[&'static str]) -> Option<&'static str> {
    if words.contains(&word) {
        return None;
    }
    words
        .iter()
        .map(|w| (strsim::jaro_winkler(word, w), *w))
        .filter(|(score, _)| *score >= 0.7)
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, w)| w)
}

/// The keywords of `grammar/hyb.pest` (its `keyword` rule): never names.
pub(crate) const KEYWORDS: &[&str] = &[
    "model", "param", "graph", "state", "noise", "flow", "jump", "when", "every", "output", "sim",
    "design", "for", "in", "if", "then", "else", "sum", "true", "false", "out", "edges",
];
