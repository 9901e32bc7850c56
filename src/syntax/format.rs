//! `hybsim fmt`: the canonical layout of a `.hyb` file.
//!
//! The formatter works on tokens, not on the AST, so that comments and the
//! user's line breaks survive: it changes only the whitespace *between*
//! tokens, never the tokens themselves (a test checks the token sequences
//! are equal, and that the compiled model gives the same arc). The layout:
//!
//! - the user's line breaks are kept; runs of blank lines become one, and
//!   the file starts with its first token and ends with one newline;
//! - each line is indented by four spaces per block (`{ … }`) and per
//!   bracket (`( … )`, `[ … ]`) opened on an earlier line (brackets opened on
//!   one line count once), one more if it continues an expression (starts
//!   with `then`, `else` or a binary operator); a line starting with closing delimiters is
//!   indented as the line that opened them;
//! - one space around binary operators, `=` and `~`, after `,` and `;` and
//!   inside `{ … }`; none inside `( … )` and `[ … ]`, after unary `-`/`!`,
//!   before `'`, around `^` and `..`, in a reset `x+ = …`, nor around `:`
//!   inside brackets (slices); a `:` elsewhere (properties, labels, `sum`,
//!   sweep ranges) has no space before it and keeps the user's choice after;
//! - a name directly followed by `(` stays a call (`f(x)`); whether a space
//!   separates a keyword from `(` is kept, since `in (…)` (a flow set) and
//!   `in(G, i)` (a neighbour set) read differently; the same holds for the
//!   contextual words of properties (`always (…)`);
//! - a trailing comment keeps its column when the code leaves room for it,
//!   else it follows the code after two spaces; a comment line is indented
//!   like the code around it.
//!
//! Only a file that parses is formatted.

use crate::syntax::lex::{Token, TokenKind as Kind, tokens as lex};
use crate::syntax::{KEYWORDS, SyntaxError, parse_model};

/// The contextual words of `property` declarations (`always (…)`, `eventually
/// within 3 (…)`): never called, so a `(` after one keeps the user's spacing as
/// after a keyword. Not in [`KEYWORDS`]: `alpha`, `tol`, … may also be names,
/// after which `-` is binary.
const PROPERTY_WORDS: &[&str] = &[
    "always",
    "after",
    "during",
    "flows",
    "at",
    "jumps",
    "eventually",
    "within",
    "decreasing",
    "nonincreasing",
    "exponential",
    "kappa",
    "alpha",
    "tol",
];

fn is_keyword(t: &Token<'_>) -> bool {
    t.kind == Kind::Word && KEYWORDS.contains(&t.text)
}

/// The token ends an operand: a following `-` is binary, a following `[`
/// indexes it, a following `'` transposes it.
fn ends_operand(t: &Token<'_>) -> bool {
    match t.kind {
        Kind::Word => !is_keyword(t) || matches!(t.text, "true" | "false"),
        Kind::Number | Kind::Str => true,
        Kind::Op => matches!(t.text, ")" | "]" | "'"),
        Kind::Comment => false,
    }
}

/// Binary operators spaced on both sides.
fn is_spaced_binary(op: &str) -> bool {
    matches!(
        op,
        "||" | "&&"
            | "<="
            | ">="
            | "=="
            | "!="
            | ".*"
            | "./"
            | "+"
            | "-"
            | "*"
            | "/"
            | "<"
            | ">"
            | "="
            | "~"
    )
}

/// The role of each token that the spacing rules need: unary `-`/`!`,
/// the `+` of a reset, an LMI `*` block, a `:` inside brackets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Plain,
    Unary,
    ResetPlus,
    /// An operand-like operator token (`*` standing for a block of an LMI).
    Operand,
    SliceColon,
}

fn roles(tokens: &[Token<'_>]) -> Vec<Role> {
    let mut roles = Vec::with_capacity(tokens.len());
    let mut open: Vec<&str> = Vec::new();
    let code: Vec<usize> = (0..tokens.len())
        .filter(|&i| tokens[i].kind != Kind::Comment)
        .collect();
    let mut prev: Option<&Token<'_>> = None;
    let mut k = 0;
    for (i, t) in tokens.iter().enumerate() {
        if t.kind == Kind::Comment {
            roles.push(Role::Plain);
            continue;
        }
        let next = code.get(k + 1).map(|&n| &tokens[n]);
        k += 1;
        let after_operand = prev.is_some_and(ends_operand);
        let role = match (t.kind, t.text) {
            (Kind::Op, "-" | "!") if !after_operand || t.text == "!" => Role::Unary,
            (Kind::Op, "+") if after_operand && next.is_some_and(|n| n.text == "=") => {
                Role::ResetPlus
            }
            (Kind::Op, "*") if !after_operand => Role::Operand,
            (Kind::Op, ":") if open.last() == Some(&"[") => Role::SliceColon,
            _ => Role::Plain,
        };
        match t.text {
            "(" | "[" | "{" if t.kind == Kind::Op => open.push(t.text),
            ")" | "]" | "}" if t.kind == Kind::Op => {
                open.pop();
            }
            _ => {}
        }
        debug_assert_eq!(roles.len(), i);
        roles.push(role);
        prev = Some(t);
    }
    roles
}

/// Whether one space separates `p` (role `rp`) from the following `c` (role `rc`).
fn space_between(p: &Token<'_>, rp: Role, c: &Token<'_>, rc: Role) -> bool {
    let (pt, ct) = (p.text, c.text);
    let p_op = p.kind == Kind::Op && rp != Role::Operand;
    let c_op = c.kind == Kind::Op && rc != Role::Operand;
    if c_op {
        match ct {
            "," | ";" | "'" | ")" | "]" => return false,
            "}" => return pt != "{",
            "{" => return true,
            // A slice's `:` after a comma (`P[1:2, :]`) is spaced like any element.
            ":" => return p_op && matches!(pt, "," | ";"),
            // `ball.h`: a member of an instance.
            "." | ".." | "^" => return false,
            "(" => {
                return match p.kind {
                    Kind::Word if !is_keyword(p) && !PROPERTY_WORDS.contains(&p.text) => false, // a call
                    Kind::Word => c.spaced, // a keyword: `in (…)` is not `in(…)`
                    _ => !(p_op && (matches!(pt, "(" | "[") || rp == Role::Unary)),
                };
            }
            "[" => {
                return if ends_operand(p) {
                    false // indexing
                } else {
                    !(p_op && (matches!(pt, "(" | "[") || rp == Role::Unary))
                };
            }
            _ => {}
        }
        if rc == Role::ResetPlus {
            return false;
        }
    }
    if p_op {
        match pt {
            "(" | "[" | "." | ".." | "^" => return false,
            "{" | "," | ";" => return true,
            ":" => return rp != Role::SliceColon && c.spaced,
            _ => {}
        }
        if rp == Role::Unary {
            return false;
        }
    }
    if c_op && rc == Role::SliceColon || p_op && rp == Role::SliceColon {
        return false;
    }
    if (c_op && (is_spaced_binary(ct) || rc == Role::Unary)) || (p_op && is_spaced_binary(pt)) {
        return true;
    }
    true
}

/// Formats `text` in the canonical layout (see the module docs).
///
/// ```
/// let text = "model m\nstate x=1\nflow{x'=-x}\njump r when x<=0.5{x+=1}\n";
/// let formatted = hybsim::syntax::format_source(text).unwrap();
/// assert_eq!(
///     formatted,
///     "model m\nstate x = 1\nflow { x' = -x }\njump r when x <= 0.5 { x+ = 1 }\n"
/// );
/// ```
pub fn format_source(text: &str) -> Result<String, SyntaxError> {
    // A model, or a file of subsystems brought in by `import`.
    if let Err(e) = parse_model(text) {
        crate::syntax::parse_library(text).map_err(|_| e)?;
    }
    let tokens = lex(text);
    let roles = roles(&tokens);
    let mut out = String::with_capacity(text.len() + text.len() / 8);
    if text.starts_with('\u{feff}') {
        out.push('\u{feff}');
    }
    // Open delimiters: (text, line of the source where opened).
    let mut open: Vec<(&str, usize)> = Vec::new();
    let mut prev_code: Option<usize> = None;
    let mut i = 0;
    let mut last_line: Option<usize> = None;
    while i < tokens.len() {
        let line = tokens[i].line;
        let end = tokens[i..]
            .iter()
            .position(|t| t.line != line)
            .map_or(tokens.len(), |n| i + n);
        if let Some(last) = last_line {
            out.push('\n');
            if line > last + 1 {
                out.push('\n');
            }
        }
        last_line = Some(line);
        // Indentation: closing delimiters at the start of the line close first.
        let mut probe = open.clone();
        for t in &tokens[i..end] {
            if t.kind == Kind::Op && matches!(t.text, ")" | "]" | "}") {
                probe.pop();
            } else {
                break;
            }
        }
        let mut depth = 0;
        let mut seen_line = None;
        for &(_, l) in &probe {
            if seen_line != Some(l) && l < line {
                depth += 1;
            }
            seen_line = Some(l);
        }
        let first = &tokens[i];
        // `then`/`else` on a line of their own continue an `if` expression too.
        let continues = (first.kind == Kind::Op
            && roles[i] == Role::Plain
            && is_spaced_binary(first.text)
            && first.text != "=")
            && prev_code.is_some_and(|p| ends_operand(&tokens[p]))
            || first.kind == Kind::Word && matches!(first.text, "then" | "else");
        if continues {
            depth += 1;
        }
        let mut line_out = " ".repeat(4 * depth);
        let mut prev_in_line: Option<usize> = None;
        for k in i..end {
            let t = &tokens[k];
            if t.kind == Kind::Comment {
                if prev_in_line.is_some() {
                    let width = line_out.chars().count();
                    let pad = if t.col >= width + 2 { t.col - width } else { 2 };
                    line_out.push_str(&" ".repeat(pad));
                }
                line_out.push_str(t.text.trim_end());
                continue;
            }
            if let Some(p) = prev_in_line
                && space_between(&tokens[p], roles[p], t, roles[k])
            {
                line_out.push(' ');
            }
            line_out.push_str(t.text);
            if t.kind == Kind::Op {
                match t.text {
                    "(" | "[" | "{" => open.push((t.text, line)),
                    ")" | "]" | "}" => {
                        open.pop();
                    }
                    _ => {}
                }
            }
            prev_in_line = Some(k);
            prev_code = Some(k);
        }
        out.push_str(line_out.trim_end());
        i = end;
    }
    out.push('\n');
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Token texts without comments: what the formatter must never change.
    fn code_tokens(text: &str) -> Vec<String> {
        lex(text)
            .into_iter()
            .filter(|t| t.kind != Kind::Comment)
            .map(|t| t.text.to_string())
            .collect()
    }

    fn fmt(text: &str) -> String {
        format_source(text).unwrap_or_else(|e| panic!("{e:?}"))
    }

    #[test]
    fn spacing_of_operators_calls_indexing_and_resets() {
        let text = "model m\nparam A=[1,2;3,4]\nparam B=A'*A+ -A^2\nstate x=zeros(2,1)\n\
                    flow{x'=A*x-[1;0]}\njump r when x[1]>=1&&!(x[2]<0){x[1]+=-x[1]}\n";
        assert_eq!(
            fmt(text),
            "model m\nparam A = [1, 2; 3, 4]\nparam B = A' * A + -A^2\nstate x = zeros(2, 1)\n\
             flow { x' = A * x - [1; 0] }\njump r when x[1] >= 1 && !(x[2] < 0) { x[1]+ = -x[1] }\n"
        );
    }

    #[test]
    fn blocks_indent_and_comments_stay() {
        let text = "model m   # the header\n\n\n\nstate x = 1\nflow {\nx' = -x   # decay\n  }\n\
                    design d {\nsym P[2]\n# a comment line\nfor S in subsets(1..2) {\n\
                    c: [P, *; *, P] >= 0\n}\nparam K = P[1:2, :]\n}\n";
        assert_eq!(
            fmt(text),
            "model m   # the header\n\nstate x = 1\nflow {\n    x' = -x  # decay\n}\n\
             design d {\n    sym P[2]\n    # a comment line\n    for S in subsets(1..2) {\n\
             \x20       c: [P, *; *, P] >= 0\n    }\n    param K = P[1:2, :]\n}\n"
        );
    }

    #[test]
    fn continuation_lines_and_brackets_over_lines() {
        let text = "model m\nstate x = 1\nparam M = [1, 2;\n3, 4]\nflow {\nx' = -x\n} in x >= 0\n\
                    || x <= -1\n";
        assert_eq!(
            fmt(text),
            "model m\nstate x = 1\nparam M = [1, 2;\n    3, 4]\nflow {\n    x' = -x\n} in x >= 0\n\
             \x20   || x <= -1\n"
        );
    }

    #[test]
    fn keeps_the_meaning_of_contextual_spacing() {
        // `in (…)` is a flow set, `in(G, i)` a neighbour set; `sym P[k][n]`
        // needs its brackets together; sweep ranges keep their colons.
        let text = "model m\ngraph G = [0, 1; 1, 0]\nfor i in 1..2 { state x[i] = 0 }\n\
                    flow { for i in 1..2 { x[i]' = sum(k in in(G, i): x[k] - x[i]) } } in (x[1] >= -9)\n\
                    design d { sym P[2][2]\n minimize trace(P[1]) }\nsweep { g in 0:1:4 }\n";
        let f = fmt(text);
        assert!(f.contains("sum(k in in(G, i): x[k] - x[i])"), "{f}");
        assert!(f.contains("} in (x[1] >= -9)"), "{f}");
        assert!(f.contains("sym P[2][2]"), "{f}");
        assert!(f.contains("g in 0:1:4"), "{f}");
    }

    #[test]
    fn members_of_instances_and_files_of_subsystems() {
        let text = "subsystem S(a=1){input u\nstate x=a\nflow{x'=-x+u}\noutput y=x}\n";
        assert_eq!(
            fmt(text),
            "subsystem S(a = 1) { input u\n    state x = a\n    flow { x' = -x + u }\n    output y = x }\n"
        );
        let text = "model m\nimport \"lib/s.hyb\"\ns=S(u=t)\noutput z=s.y+f[1].y*2\n";
        assert_eq!(
            fmt(text),
            "model m\nimport \"lib/s.hyb\"\ns = S(u = t)\noutput z = s.y + f[1].y * 2\n"
        );
    }

    #[test]
    fn is_idempotent_and_changes_only_whitespace_on_the_shipped_models() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
        let mut n = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "hyb") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let once = fmt(&text);
            assert_eq!(code_tokens(&once), code_tokens(&text), "{}", path.display());
            assert_eq!(fmt(&once), once, "not idempotent on {}", path.display());
            let comments = |s: &str| {
                lex(s)
                    .into_iter()
                    .filter(|t| t.kind == Kind::Comment)
                    .map(|t| t.text.trim_end().to_string())
                    .collect::<Vec<_>>()
            };
            assert_eq!(comments(&once), comments(&text), "{}", path.display());
            n += 1;
        }
        assert!(n >= 8);
    }

    #[test]
    fn refuses_a_file_that_does_not_parse() {
        assert!(format_source("model m\nstate x = \n").is_err());
    }
}
