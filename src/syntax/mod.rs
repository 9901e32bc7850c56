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

/// The keywords of `grammar/hyb.pest` (its `keyword` rule): never names.
pub(crate) const KEYWORDS: &[&str] = &[
    "model", "param", "graph", "state", "noise", "flow", "jump", "when", "every", "output", "sim",
    "design", "for", "in", "if", "then", "else", "sum", "true", "false", "out", "edges",
];
