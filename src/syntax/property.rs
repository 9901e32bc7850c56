//! Parsing of `property NAME: BODY` declarations (grammar section
//! `// --- property ---`).

use pest::iterators::{Pair, Pairs};

use super::ast::{Expr, IndexArg, PropertyBody, PropertyDecl, Target};
use super::parse::{Res, Rule, expr, first, ident, index_list, significant_span};
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
    let body_span = significant_span(&body);
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
                    Some(rule_path(first(&mut p.into_inner(), pspan)?)?)
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

fn incomplete(span: Span) -> super::SyntaxError {
    super::SyntaxError::Unexpected {
        span,
        found: "an incomplete property".into(),
        expected: "a complete property body".into(),
    }
}

/// A rule named in `at jumps RULE P`: `impact`, `fire[2]`, `ball.impact`,
/// `f.fire[2]` or `f[2].fire` (a family of instances is indexed first by the
/// instance, as the model names its rules: `f[i].fire[k]` is `f.fire[i, k]`).
fn rule_path(p: Pair<'_, Rule>) -> Res<Target> {
    // Up to its last token: the blanks before the predicate are not the name's.
    let span = significant_span(&p);
    let mut it = p.into_inner();
    let mut name = ident(first(&mut it, span)?);
    let mut index: Vec<IndexArg> = Vec::new();
    let mut indexed = false;
    for q in it {
        if q.as_rule() == Rule::member {
            name.name.push_str(q.as_str());
            name.span = Span::new(name.span.start, q.as_span().end());
        } else {
            index.extend(index_list(q)?);
            indexed = true;
        }
    }
    Ok(Target {
        name,
        indices: if indexed { vec![index] } else { Vec::new() },
        span,
    })
}
