//! Parsing of `property NAME: BODY` declarations (grammar section
//! `// --- property ---`).

use pest::iterators::{Pair, Pairs};

use super::ast::{Expr, PropertyBody, PropertyDecl};
use super::parse::{Res, Rule, expr, first, ident, target};
use crate::source::Span;

/// The children of a `property_decl` pair (span `span`) as a declaration.
pub(super) fn property_decl(inner: Pairs<'_, Rule>, span: Span) -> Res<PropertyDecl> {
    // Contextual words (`always`, `during`, ...) carry no information
    // beyond the rule that holds them.
    let mut parts = inner.filter(|p| !is_word(p.as_rule()));
    let name = ident(parts.next().ok_or_else(|| incomplete(span))?);
    let body = parts.next().ok_or_else(|| incomplete(span))?;
    // pest's implicit trivia can leave comments after the last token inside
    // the span: cut them off, so that reports show exactly the body.
    let body_start = body.as_span().start();
    let body_span = Span::new(body_start, body_start + significant_len(body.as_str()));
    let span = Span::new(span.start, body_span.end);
    let rule = body.as_rule();
    let kids: Vec<Pair<'_, Rule>> = body.into_inner().collect();
    let decreasing = kids.iter().any(|p| p.as_rule() == Rule::w_decreasing);
    let mut it = kids.into_iter().filter(|p| !is_word(p.as_rule()));
    let next_expr = |it: &mut dyn Iterator<Item = Pair<'_, Rule>>| -> Res<Expr> {
        expr(it.next().ok_or_else(|| incomplete(body_span))?)
    };
    let body = match rule {
        Rule::prop_always => PropertyBody::Always(next_expr(&mut it)?),
        Rule::prop_flows => PropertyBody::DuringFlows(next_expr(&mut it)?),
        Rule::prop_after => {
            let enter = next_expr(&mut it)?;
            let pred = next_expr(&mut it)?;
            PropertyBody::AlwaysAfter { enter, pred }
        }
        Rule::prop_jumps => {
            let mut rest: Vec<Pair<'_, Rule>> = it.collect();
            let rule = match rest.first() {
                Some(p) if p.as_rule() == Rule::prop_rule => {
                    let p = rest.remove(0);
                    let pspan = p.as_span().into();
                    Some(target(first(&mut p.into_inner(), pspan)?)?)
                }
                _ => None,
            };
            let pred = next_expr(&mut rest.into_iter())?;
            PropertyBody::AtJumps { rule, pred }
        }
        Rule::prop_eventually => {
            let within = next_expr(&mut it)?;
            let pred = next_expr(&mut it)?;
            PropertyBody::EventuallyWithin { within, pred }
        }
        Rule::prop_monotone => {
            let v = next_expr(&mut it)?;
            let scope = it.next().ok_or_else(|| incomplete(body_span))?;
            let jumps = scope.as_rule() == Rule::scope_jumps;
            let tol = it.next().map(tol).transpose()?;
            PropertyBody::Monotone {
                decreasing,
                jumps,
                v,
                tol,
            }
        }
        Rule::prop_exponential => {
            let v = next_expr(&mut it)?;
            let kappa = next_expr(&mut it)?;
            let alpha = next_expr(&mut it)?;
            let tol = it.next().map(tol).transpose()?;
            PropertyBody::Exponential {
                v,
                kappa,
                alpha,
                tol,
            }
        }
        _ => return Err(incomplete(body_span)),
    };
    Ok(PropertyDecl {
        name,
        body,
        body_span,
        span,
    })
}

/// Length of `text` up to its last character that is neither whitespace
/// nor part of a `#` comment.
fn significant_len(text: &str) -> usize {
    let mut end = 0;
    let mut line_start = 0;
    for line in text.split_inclusive('\n') {
        let code = line.split('#').next().unwrap_or_default().trim_end();
        if !code.is_empty() {
            end = line_start + code.len();
        }
        line_start += line.len();
    }
    end
}

fn is_word(r: Rule) -> bool {
    matches!(
        r,
        Rule::w_property
            | Rule::w_always
            | Rule::w_after
            | Rule::w_during
            | Rule::w_flows
            | Rule::w_at
            | Rule::w_jumps
            | Rule::w_eventually
            | Rule::w_within
            | Rule::w_decreasing
            | Rule::w_nonincreasing
            | Rule::w_exponential
            | Rule::w_kappa
            | Rule::w_alpha
            | Rule::w_tol
    )
}

/// `tol ε`: the expression ε.
fn tol(p: Pair<'_, Rule>) -> Res<Expr> {
    let span: Span = p.as_span().into();
    let mut it = p.into_inner().filter(|q| !is_word(q.as_rule()));
    expr(it.next().ok_or_else(|| incomplete(span))?)
}

#[cfg(test)]
#[test]
fn trailing_comments_are_not_significant() {
    assert_eq!(significant_len("always h >= 0 # ok\n  # more\n"), 13);
    assert_eq!(significant_len("always h >= 0\n  && v <= 1  # c\n"), 25);
    assert_eq!(significant_len("always x"), 8);
}

fn incomplete(span: Span) -> super::SyntaxError {
    super::SyntaxError::Unexpected {
        span,
        found: "an incomplete property".into(),
        expected: "a complete property body".into(),
    }
}
