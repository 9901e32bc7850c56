//! The pest binding and the conversion of pest pairs into the AST.

use std::iter::Peekable;

use pest::Parser;
use pest::iterators::{Pair, Pairs};

use super::ast::*;
use super::error::SyntaxError;
use crate::source::Span;

/// The pest parser generated from `grammar/hyb.pest`.
#[derive(pest_derive::Parser)]
#[grammar = "../grammar/hyb.pest"]
pub(crate) struct HybParser;

/// Deepest nesting of brackets, `if`s and powers accepted in one
/// expression; deeper input is a [`SyntaxError::TooDeep`], so that no input
/// can exhaust the stack.
pub const MAX_NESTING: usize = 48;

/// Deepest expression tree accepted: operations applied to the result of
/// operations, counted along the longest path (`1 + 1 + … + 1` with N terms
/// is N − 1 deep, as are N − 1 prefix `-`/`!`, postfix `'` or `[i]`).
/// Deeper input is a [`SyntaxError::TooLong`], caught while the tree is
/// built, so that neither building, checking nor dropping it can exhaust
/// the stack. Long sums are written with `sum(k in 1..N: …)`.
pub const MAX_EXPR_DEPTH: usize = 1000;

pub(super) type Res<T> = Result<T, SyntaxError>;

/// Parses a whole model.
pub fn parse_model(text: &str) -> Result<Model, SyntaxError> {
    check_depth(text)?;
    let mut pairs = HybParser::parse(Rule::model, text)
        .map_err(|e| SyntaxError::from_pest(e, text, Rule::model))?;
    let model = first(&mut pairs, Span::new(0, text.len()))?;
    let span = model.as_span().into();
    let mut inner = model.into_inner();
    let header = first(&mut inner, span)?;
    let name = ident(first(&mut header.into_inner(), span)?);
    let mut items = Vec::new();
    for p in inner {
        if p.as_rule() != Rule::EOI {
            push_items(p, &mut items)?;
        }
    }
    Ok(Model { name, items })
}

/// Parses a file brought in by `import`: subsystem declarations and its own
/// imports (returned as [`Item::Subsystem`] and [`Item::Import`] items).
pub fn parse_library(text: &str) -> Result<Vec<Item>, SyntaxError> {
    check_depth(text)?;
    let mut pairs = HybParser::parse(Rule::library, text)
        .map_err(|e| SyntaxError::from_pest(e, text, Rule::library))?;
    let lib = first(&mut pairs, Span::new(0, text.len()))?;
    lib.into_inner()
        .filter(|p| p.as_rule() != Rule::EOI)
        .map(item)
        .collect()
}

/// Parses one expression (an override value `--set name=EXPR`).
pub fn parse_expr(text: &str) -> Result<Expr, SyntaxError> {
    check_depth(text)?;
    let mut pairs = HybParser::parse(Rule::override_value, text)
        .map_err(|e| SyntaxError::from_pest(e, text, Rule::override_value))?;
    let span = Span::new(0, text.len());
    let top = first(&mut pairs, span)?;
    expr(first(&mut top.into_inner(), span)?)
}

/// Rejects input nested deeper than [`MAX_NESTING`] before pest sees it.
fn check_depth(text: &str) -> Res<()> {
    // Per open bracket: how many levels it and the `^`/`if` inside it add.
    let mut stack: Vec<(usize, usize)> = Vec::new();
    let mut depth = 0usize;
    let bytes = text.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i];
        let level = match c {
            b'#' => {
                while i < bytes.len() && bytes[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            b'(' | b'[' | b'{' => {
                stack.push((i, 1));
                1
            }
            b')' | b']' | b'}' => {
                if let Some((_, n)) = stack.pop() {
                    depth = depth.saturating_sub(n);
                }
                0
            }
            b'^' => 1,
            b'i' if text[i..].starts_with("if")
                && (i == 0 || !is_ident_byte(bytes[i - 1]))
                && !bytes.get(i + 2).is_some_and(|b| is_ident_byte(*b)) =>
            {
                1
            }
            _ => 0,
        };
        if level > 0 {
            if c == b'^' || c == b'i' {
                if let Some(top) = stack.last_mut() {
                    top.1 += 1;
                } else {
                    stack.push((i, 1));
                    stack.push((i, 0));
                }
            }
            depth += 1;
            if depth > MAX_NESTING {
                return Err(SyntaxError::TooDeep {
                    span: Span::new(i, i + 1),
                    limit: MAX_NESTING,
                });
            }
        }
        i += 1;
    }
    Ok(())
}

fn is_ident_byte(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b == b'_'
}

pub(super) fn first<'a>(
    pairs: &mut impl Iterator<Item = Pair<'a, Rule>>,
    parent: Span,
) -> Res<Pair<'a, Rule>> {
    pairs.next().ok_or_else(|| SyntaxError::Unexpected {
        span: parent,
        found: "an incomplete construct".into(),
        expected: "more input".into(),
    })
}

pub(super) fn ident(p: Pair<'_, Rule>) -> Ident {
    Ident {
        name: p.as_str().to_string(),
        span: p.as_span().into(),
    }
}

/// The span of `p` up to its last token: pest's implicit trivia leave the blanks and comments
/// before an optional `;` that is not there inside a rule's span (into the next line).
pub(super) fn significant_span(p: &Pair<'_, Rule>) -> Span {
    let start = p.as_span().start();
    let text = p.as_str();
    let mut end = text.len();
    loop {
        let body = text[..end].trim_end();
        let line_start = body.rfind('\n').map_or(0, |i| i + 1);
        // A comment starts with `#` (lexing tells one in a string apart).
        if !body[line_start..].contains('#') {
            return Span::new(start, start + body.len());
        }
        match super::lex::tokens(&body[line_start..]).last() {
            Some(t) if t.kind == super::lex::TokenKind::Comment => end = line_start + t.offset,
            _ => return Span::new(start, start + body.len()),
        }
    }
}

/// Pushes the items of `p`: one, or for a `param` list that mixes
/// definitions and draws (`param g = 9.81, lam ~ uniform(0.5, 0.9)`) one per
/// run of definitions and one per draw, in the list's order.
fn push_items(p: Pair<'_, Rule>, items: &mut Vec<Item>) -> Res<()> {
    if p.as_rule() != Rule::param_decl
        || !p
            .clone()
            .into_inner()
            .any(|d| d.as_rule() == Rule::param_rand)
    {
        items.push(item(p)?);
        return Ok(());
    }
    let mut defs: Vec<Definition> = Vec::new();
    for d in p.into_inner() {
        if d.as_rule() == Rule::param_rand {
            if !defs.is_empty() {
                items.push(Item::Param(std::mem::take(&mut defs)));
            }
            items.push(Item::RandomParam(random_param(d)?));
        } else {
            defs.push(definition(d)?);
        }
    }
    if !defs.is_empty() {
        items.push(Item::Param(defs));
    }
    Ok(())
}

/// `lam ~ uniform(0.5, 0.9)` in a `param` list.
fn random_param(p: Pair<'_, Rule>) -> Res<Definition> {
    let span = significant_span(&p);
    let mut inner = p.into_inner();
    let target = target(first(&mut inner, span)?)?;
    let value = expr(first(&mut inner, span)?)?;
    Ok(Definition { target, value })
}

/// Collects the items of the pairs `ps` (see [`push_items`]).
fn items_of<'a>(ps: impl Iterator<Item = Pair<'a, Rule>>) -> Res<Vec<Item>> {
    let mut items = Vec::new();
    for p in ps {
        push_items(p, &mut items)?;
    }
    Ok(items)
}

fn item(p: Pair<'_, Rule>) -> Res<Item> {
    let span = significant_span(&p);
    let rule = p.as_rule();
    let p_design = p.clone();
    let mut inner = p.into_inner();
    Ok(match rule {
        Rule::param_decl => Item::Param(inner.map(definition).collect::<Res<_>>()?),
        Rule::output_decl => Item::Output(inner.map(definition).collect::<Res<_>>()?),
        Rule::param_tuple => {
            let mut parts: Vec<Pair<'_, Rule>> = inner.collect();
            let Some(value) = parts.pop() else {
                return Err(SyntaxError::Unexpected {
                    span,
                    found: "this".into(),
                    expected: "a value".into(),
                });
            };
            let targets = parts.into_iter().map(target).collect::<Res<_>>()?;
            Item::ParamTuple(targets, expr(value)?)
        }
        Rule::graph_decl => Item::Graph(definition(first(&mut inner, span)?)?),
        Rule::state_decl => Item::State(
            inner
                .map(|sd| {
                    let sspan = sd.as_span().into();
                    let mut it = sd.into_inner();
                    let target = target(first(&mut it, sspan)?)?;
                    let init = match it.next() {
                        Some(i) => {
                            let ispan = i.as_span().into();
                            Some(expr(first(&mut i.into_inner(), ispan)?)?)
                        }
                        None => None,
                    };
                    Ok(StateDef { target, init })
                })
                .collect::<Res<_>>()?,
        ),
        Rule::noise_decl => {
            let target = target(first(&mut inner, span)?)?;
            let dist = expr(first(&mut inner, span)?)?;
            let every = inner.next().map(expr).transpose()?;
            Item::Noise(NoiseDecl {
                target,
                dist,
                every,
                span,
            })
        }
        Rule::flow_block => {
            let mut stmts = Vec::new();
            let mut set = None;
            for q in inner {
                match q.as_rule() {
                    Rule::flow_eq | Rule::flow_for => stmts.push(flow_stmt(q)?),
                    _ => set = Some(expr(q)?),
                }
            }
            Item::Flow(FlowBlock {
                stmts,
                set,
                span: Span::new(span.start, span.start + 4),
            })
        }
        Rule::jump_decl => {
            let mut next = first(&mut inner, span)?;
            let name = if next.as_rule() == Rule::target {
                let name = target(next)?;
                next = first(&mut inner, span)?;
                Some(name)
            } else {
                None
            };
            let trigger = trigger(next)?;
            let head = head_span(span, &trigger);
            let resets = reset_block(first(&mut inner, span)?)?;
            Item::Jump(JumpDecl {
                name,
                trigger,
                resets,
                span: head,
            })
        }
        Rule::every_decl => {
            let trigger = trigger(first(&mut inner, span)?)?;
            let head = head_span(span, &trigger);
            let resets = reset_block(first(&mut inner, span)?)?;
            Item::Jump(JumpDecl {
                name: None,
                trigger,
                resets,
                span: head,
            })
        }
        Rule::sim_block => Item::Sim(
            inner
                .map(|s| {
                    let sspan = s.as_span().into();
                    let mut it = s.into_inner();
                    let key = ident(first(&mut it, sspan)?);
                    let v = first(&mut it, sspan)?;
                    let integer = integer_literal(v.as_str());
                    let value = expr(v)?;
                    Ok(Setting {
                        key,
                        value,
                        integer,
                    })
                })
                .collect::<Res<_>>()?,
        ),
        Rule::property_decl => Item::Property(super::property::property_decl(inner, span)?),
        Rule::metric_decl => Item::Metric(
            inner
                .filter(|p| p.as_rule() == Rule::definition)
                .map(definition)
                .collect::<Res<_>>()?,
        ),
        Rule::sweep_block => {
            let word = first(&mut inner, span)?.as_span().into();
            let mut axes = Vec::new();
            let mut settings = Vec::new();
            for s in inner {
                let sspan = s.as_span().into();
                let rule = s.as_rule();
                let mut it = s.into_inner();
                let name = ident(first(&mut it, sspan)?);
                let v = first(&mut it, sspan)?;
                if rule == Rule::sim_setting {
                    settings.push(Setting {
                        key: name,
                        integer: integer_literal(v.as_str()),
                        value: expr(v)?,
                    });
                } else if v.as_rule() == Rule::sweep_range {
                    let vspan = v.as_span().into();
                    let mut r = v.into_inner();
                    let a = expr(first(&mut r, vspan)?)?;
                    let step = expr(first(&mut r, vspan)?)?;
                    let b = expr(first(&mut r, vspan)?)?;
                    axes.push(SweepAxis {
                        name,
                        values: AxisValues::Range(a, step, b),
                    });
                } else {
                    axes.push(SweepAxis {
                        name,
                        values: AxisValues::List(expr(v)?),
                    });
                }
            }
            Item::Sweep(SweepBlock {
                axes,
                settings,
                span: word,
            })
        }
        Rule::param_table => {
            let name = ident(first(&mut inner, span)?);
            let call = first(&mut inner, span)?;
            let call_span: Span = call.as_span().into();
            let mut parts = call.into_inner();
            let _word = first(&mut parts, call_span)?;
            let lit = first(&mut parts, call_span)?;
            let text = lit.as_str();
            Item::Table(TableParam {
                name,
                path: text[1..text.len() - 1].to_string(),
                path_span: lit.as_span().into(),
                span: call_span,
                file: None,
            })
        }
        Rule::import_decl => {
            let _word = first(&mut inner, span)?;
            let lit = first(&mut inner, span)?;
            let text = lit.as_str();
            Item::Import(Import {
                path: text[1..text.len() - 1].to_string(),
                span: lit.as_span().into(),
            })
        }
        Rule::subsystem_decl => {
            let _word = first(&mut inner, span)?;
            let name = ident(first(&mut inner, span)?);
            let mut params = Vec::new();
            let mut items = Vec::new();
            for p in inner {
                if p.as_rule() == Rule::sub_params {
                    for sp in p.into_inner() {
                        let pspan = sp.as_span().into();
                        let mut it = sp.into_inner();
                        let n = ident(first(&mut it, pspan)?);
                        params.push((n, it.next().map(expr).transpose()?));
                    }
                } else {
                    push_items(p, &mut items)?;
                }
            }
            Item::Subsystem(SubsystemDecl {
                name,
                params,
                items,
            })
        }
        Rule::input_decl => {
            let _word = first(&mut inner, span)?;
            Item::Input(
                inner
                    .map(|d| {
                        let dspan = d.as_span().into();
                        let mut it = d.into_inner();
                        let target = target(first(&mut it, dspan)?)?;
                        let default = it.next().map(expr).transpose()?;
                        Ok(InputDef { target, default })
                    })
                    .collect::<Res<_>>()?,
            )
        }
        Rule::instance_decl => {
            let target = target(first(&mut inner, span)?)?;
            let subsystem = ident(first(&mut inner, span)?);
            let args = inner
                .map(|a| {
                    let aspan = a.as_span().into();
                    let mut it = a.into_inner();
                    let n = ident(first(&mut it, aspan)?);
                    Ok((n, expr(first(&mut it, aspan)?)?))
                })
                .collect::<Res<_>>()?;
            Item::Instance(InstanceDecl {
                target,
                subsystem,
                args,
                span,
            })
        }
        Rule::log_block => {
            let word = first(&mut inner, span)?.as_span().into();
            let mut lists = Vec::new();
            let mut settings = Vec::new();
            for s in inner {
                let sspan = s.as_span().into();
                let rule = s.as_rule();
                let mut it = s.into_inner();
                let key = ident(first(&mut it, sspan)?);
                if rule == Rule::log_setting {
                    let v = first(&mut it, sspan)?;
                    settings.push(Setting {
                        key,
                        integer: integer_literal(v.as_str()),
                        value: expr(v)?,
                    });
                    continue;
                }
                let names = it
                    .map(|n| {
                        let nspan = significant_span(&n);
                        let mut parts = n.into_inner();
                        let target = target(first(&mut parts, nspan)?)?;
                        let suffix = parts.next().map(ident);
                        Ok(LogName {
                            target,
                            suffix,
                            span: nspan,
                        })
                    })
                    .collect::<Res<_>>()?;
                lists.push((key, names));
            }
            Item::Log(LogBlock {
                lists,
                settings,
                span: word,
            })
        }
        Rule::for_item | Rule::together_for | Rule::sub_for => {
            let b = binder(first(&mut inner, span)?)?;
            let items = items_of(inner)?;
            Item::For(b, items)
        }
        Rule::together_block => {
            let word = first(&mut inner, span)?.as_span().into();
            let items = items_of(inner)?;
            Item::Together(items, word)
        }
        Rule::design_block => {
            let _ = inner;
            Item::Design(super::design::design_block(p_design)?)
        }
        _ => {
            return Err(SyntaxError::Unexpected {
                span,
                found: "this".into(),
                expected: "a declaration".into(),
            });
        }
    })
}

pub(super) fn definition(p: Pair<'_, Rule>) -> Res<Definition> {
    let span = p.as_span().into();
    let mut it = p.into_inner();
    let target = target(first(&mut it, span)?)?;
    let value = expr(first(&mut it, span)?)?;
    Ok(Definition { target, value })
}

pub(super) fn target(p: Pair<'_, Rule>) -> Res<Target> {
    // Without the blanks pest's implicit trivia leave after `x[i]` when no
    // index follows: a caret under `x[i]`, not `x[i]   `.
    let span = significant_span(&p);
    let mut it = p.into_inner();
    let name = ident(first(&mut it, span)?);
    let indices = it.map(index_list).collect::<Res<_>>()?;
    Ok(Target {
        name,
        indices,
        span,
    })
}

pub(super) fn index_list(p: Pair<'_, Rule>) -> Res<Vec<IndexArg>> {
    p.into_inner()
        .map(|a| {
            let aspan: Span = a.as_span().into();
            let mut it = a.into_inner();
            let q = first(&mut it, aspan)?;
            Ok(match (q.as_rule(), it.next()) {
                (Rule::colon_all, _) => IndexArg::All(aspan),
                (_, Some(hi)) => {
                    let hi = expr(first(&mut hi.into_inner(), aspan)?)?;
                    IndexArg::Slice(expr(q)?, hi)
                }
                (_, None) => IndexArg::One(expr(q)?),
            })
        })
        .collect()
}

fn flow_stmt(p: Pair<'_, Rule>) -> Res<FlowStmt> {
    let span = p.as_span().into();
    match p.as_rule() {
        Rule::flow_eq => {
            let mut it = p.into_inner();
            let target = target(first(&mut it, span)?)?;
            // `flow_prime`, then the value.
            let _prime = first(&mut it, span)?;
            let value = expr(first(&mut it, span)?)?;
            Ok(FlowStmt::Eq(Definition { target, value }))
        }
        _ => {
            let mut it = p.into_inner();
            let b = binder(first(&mut it, span)?)?;
            Ok(FlowStmt::For(b, it.map(flow_stmt).collect::<Res<_>>()?))
        }
    }
}

/// A rule's head: from `jump`/`every` to the end of its condition or period (the trigger's pair
/// also holds the whitespace before `{`).
fn head_span(decl: Span, trigger: &Trigger) -> Span {
    let (Trigger::When(e) | Trigger::Every(e)) = trigger;
    Span::new(decl.start, e.span.end)
}

fn trigger(p: Pair<'_, Rule>) -> Res<Trigger> {
    let span = p.as_span().into();
    let rule = p.as_rule();
    let e = expr(first(&mut p.into_inner(), span)?)?;
    Ok(match rule {
        Rule::every_clause => Trigger::Every(e),
        _ => Trigger::When(e),
    })
}

fn reset_block(p: Pair<'_, Rule>) -> Res<Vec<ResetStmt>> {
    p.into_inner().map(reset_stmt).collect()
}

fn reset_stmt(p: Pair<'_, Rule>) -> Res<ResetStmt> {
    let span = p.as_span().into();
    match p.as_rule() {
        Rule::reset_eq => {
            let mut it = p.into_inner();
            let t = first(&mut it, span)?;
            let text = t.as_str().trim_end().to_string();
            let target = target(t)?;
            let post = first(&mut it, span)?;
            if post.as_rule() != Rule::reset_post {
                let start = target.span.start;
                return Err(SyntaxError::ResetWithoutPlus {
                    span: Span::new(start, start + text.len()),
                    target: text,
                });
            }
            let value = expr(first(&mut it, span)?)?;
            Ok(ResetStmt::Eq(Definition { target, value }))
        }
        _ => {
            let mut it = p.into_inner();
            let b = binder(first(&mut it, span)?)?;
            Ok(ResetStmt::For(b, it.map(reset_stmt).collect::<Res<_>>()?))
        }
    }
}

pub(super) fn binder(p: Pair<'_, Rule>) -> Res<Binder> {
    let span: Span = p.as_span().into();
    let mut it = p.into_inner();
    let vars = first(&mut it, span)?.into_inner().map(ident).collect();
    let set = index_set(first(&mut it, span)?)?;
    let filter = it.next().map(expr).transpose()?;
    Ok(Binder {
        vars,
        set,
        filter,
        span,
    })
}

/// Converts a `set` pair.
fn index_set(set_pair: Pair<'_, Rule>) -> Res<IndexSet> {
    let sspan: Span = set_pair.as_span().into();
    let s = first(&mut set_pair.into_inner(), sspan)?;
    let rule = s.as_rule();
    let mut parts = s.into_inner();
    Ok(match rule {
        Rule::set_range => {
            let a = expr(first(&mut parts, sspan)?)?;
            IndexSet::Range(a, expr(first(&mut parts, sspan)?)?)
        }
        Rule::set_in => {
            let a = expr(first(&mut parts, sspan)?)?;
            IndexSet::In(a, expr(first(&mut parts, sspan)?)?)
        }
        Rule::set_out => {
            let a = expr(first(&mut parts, sspan)?)?;
            IndexSet::Out(a, expr(first(&mut parts, sspan)?)?)
        }
        Rule::set_edges => IndexSet::Edges(expr(first(&mut parts, sspan)?)?),
        Rule::set_subsets => IndexSet::Subsets(Box::new(index_set(first(&mut parts, sspan)?)?)),
        _ => IndexSet::Named(ident(first(&mut parts, sspan)?)),
    })
}

/// `e.name`: a member of an instance, `ball.h` → the name `ball.h`, and
/// `node[k].y` → `node.y[k]` (a family of instances gives families of
/// members, indexed first by the instance's index).
fn member(e: Expr, name: &str, span: Span) -> Res<Expr> {
    match e.kind {
        ExprKind::Name(n) => Ok(mk(ExprKind::Name(format!("{n}.{name}")), span)),
        ExprKind::Index(inner, args) => match inner.kind {
            ExprKind::Name(n) => Ok(mk(
                ExprKind::Index(
                    Box::new(mk(ExprKind::Name(format!("{n}.{name}")), inner.span)),
                    args,
                ),
                span,
            )),
            _ => Err(SyntaxError::Unexpected {
                span,
                found: format!("`.{name}`"),
                expected: "an operator (`.name` follows an instance: `ball.h`, `node[k].y`)".into(),
            }),
        },
        _ => Err(SyntaxError::Unexpected {
            span,
            found: format!("`.{name}`"),
            expected: "an operator (`.name` follows an instance: `ball.h`, `node[k].y`)".into(),
        }),
    }
}

fn mk(kind: ExprKind, span: Span) -> Expr {
    Expr { kind, span }
}

/// Converts any expression-level pair.
pub(super) fn expr(p: Pair<'_, Rule>) -> Res<Expr> {
    expr_d(p).map(|(e, _)| e)
}

/// The depth of a tree already bounded by [`MAX_EXPR_DEPTH`] (for the few
/// sub-expressions built outside [`expr_d`]: indices, binders).
fn depth(e: &Expr) -> usize {
    let max = |es: &mut dyn Iterator<Item = &Expr>| es.map(depth).max().unwrap_or(0);
    1 + match &e.kind {
        ExprKind::Num(_) | ExprKind::Bool(_) | ExprKind::Name(_) => 0,
        ExprKind::Unary(_, a) => depth(a),
        ExprKind::Binary(_, a, b) => depth(a).max(depth(b)),
        ExprKind::If(a, b, c) => depth(a).max(depth(b)).max(depth(c)),
        ExprKind::Call(_, args) => max(&mut args.iter()),
        ExprKind::Matrix(rows) => max(&mut rows.iter().flatten()),
        ExprKind::Index(a, args) => depth(a).max(max(&mut args.iter().flat_map(index_exprs))),
        ExprKind::Fold(_, b, body) => depth(body).max(binder_depth(b)),
    }
}

fn index_exprs(a: &IndexArg) -> Vec<&Expr> {
    match a {
        IndexArg::One(e) => vec![e],
        IndexArg::Slice(a, b) => vec![a, b],
        IndexArg::All(_) => vec![],
    }
}

fn binder_depth(b: &Binder) -> usize {
    fn set_depth(s: &IndexSet) -> usize {
        match s {
            IndexSet::Range(a, b) | IndexSet::In(a, b) | IndexSet::Out(a, b) => {
                depth(a).max(depth(b))
            }
            IndexSet::Edges(a) => depth(a),
            IndexSet::Subsets(s) => set_depth(s),
            IndexSet::Named(_) => 0,
        }
    }
    set_depth(&b.set).max(b.filter.as_ref().map_or(0, depth))
}

/// `child_depth + 1`, or the error at `span` if that exceeds [`MAX_EXPR_DEPTH`].
fn deeper(child_depth: usize, span: Span) -> Res<usize> {
    if child_depth >= MAX_EXPR_DEPTH {
        return Err(SyntaxError::TooLong {
            span,
            limit: MAX_EXPR_DEPTH,
        });
    }
    Ok(child_depth + 1)
}

/// [`expr`] and the depth of the tree it built.
fn expr_d(p: Pair<'_, Rule>) -> Res<(Expr, usize)> {
    let span: Span = p.as_span().into();
    let rule = p.as_rule();
    let text = p.as_str();
    let mut it = p.into_inner();
    match rule {
        Rule::expr | Rule::paren => expr_d(first(&mut it, span)?),
        Rule::if_expr => {
            let (c, dc) = expr_d(first(&mut it, span)?)?;
            let (a, da) = expr_d(first(&mut it, span)?)?;
            let (b, db) = expr_d(first(&mut it, span)?)?;
            let d = deeper(dc.max(da).max(db), span)?;
            // From `if` to the end of the else branch: the pair's span also holds the
            // whitespace pest skipped after it (before an optional operator that did not follow).
            let span = Span::new(span.start, b.span.end);
            Ok((
                mk(ExprKind::If(Box::new(c), Box::new(a), Box::new(b)), span),
                d,
            ))
        }
        Rule::or_expr => climb(&mut it.peekable(), 0, span),
        Rule::add_expr => climb(&mut it.peekable(), ARITHMETIC, span),
        Rule::postfix => {
            let (mut e, mut d) = expr_d(first(&mut it, span)?)?;
            for post in it {
                let post_span: Span = post.as_span().into();
                let s = Span::new(e.span.start, post_span.end);
                e = match post.as_rule() {
                    Rule::member => member(e, &post.as_str()[1..], s)?,
                    Rule::transpose => {
                        d = deeper(d, post_span)?;
                        mk(ExprKind::Unary(UnOp::Transpose, Box::new(e)), s)
                    }
                    _ => {
                        let args = index_list(post)?;
                        let da = args
                            .iter()
                            .flat_map(index_exprs)
                            .map(depth)
                            .max()
                            .unwrap_or(0);
                        d = deeper(d.max(da), post_span)?;
                        mk(ExprKind::Index(Box::new(e), args), s)
                    }
                };
            }
            Ok((e, d))
        }
        Rule::number => match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok((mk(ExprKind::Num(v), span), 1)),
            _ => Err(SyntaxError::BadNumber {
                span,
                text: text.to_string(),
            }),
        },
        Rule::boolean => Ok((mk(ExprKind::Bool(text == "true"), span), 1)),
        Rule::ident => Ok((mk(ExprKind::Name(text.to_string()), span), 1)),
        Rule::call => {
            let name = ident(first(&mut it, span)?);
            let mut d = 0;
            let mut args = Vec::new();
            for a in it {
                let (a, da) = expr_d(a)?;
                d = d.max(da);
                args.push(a);
            }
            Ok((mk(ExprKind::Call(name, args), span), deeper(d, span)?))
        }
        Rule::matrix => {
            let mut d = 0;
            let mut rows = Vec::new();
            for r in it {
                let mut row = Vec::new();
                for e in r.into_inner() {
                    ambiguous_sign(&e)?;
                    let (e, de) = expr_d(e)?;
                    d = d.max(de);
                    row.push(e);
                }
                rows.push(row);
            }
            Ok((mk(ExprKind::Matrix(rows), span), deeper(d, span)?))
        }
        Rule::sum_expr | Rule::extreme_expr => {
            let fold = match rule {
                Rule::sum_expr => Fold::Sum,
                _ if first(&mut it, span)?.as_str().starts_with("max") => Fold::Max,
                _ => Fold::Min,
            };
            let b = binder(first(&mut it, span)?)?;
            let (body, db) = expr_d(first(&mut it, span)?)?;
            let d = deeper(db.max(binder_depth(&b)), span)?;
            Ok((
                mk(ExprKind::Fold(fold, Box::new(b), Box::new(body)), span),
                d,
            ))
        }
        _ => Err(SyntaxError::Unexpected {
            span,
            found: "this".into(),
            expected: "an expression".into(),
        }),
    }
}

/// The binary operators by precedence, lowest first. `or_expr` holds the
/// first [`ARITHMETIC`] (its operands are `add_expr`s), `add_expr` the others
/// (its operands `unary`s); the last, `^`, is right-associative and binds
/// tighter than a prefix `-` or `!`.
const BINARY: [Rule; 6] = [
    Rule::op_or,
    Rule::op_and,
    Rule::cmp_op,
    Rule::add_op,
    Rule::mul_op,
    Rule::op_pow,
];
/// The level of `+` and `-` in [`BINARY`].
const ARITHMETIC: usize = 3;
/// The level of `^` in [`BINARY`].
const POWER: usize = BINARY.len() - 1;

/// The expression of the operands and binary operators `it` starts with
/// whose operators are at `level` of [`BINARY`] or above (precedence
/// climbing over the flat children of `or_expr` or `add_expr`).
fn climb(it: &mut Peekable<Pairs<'_, Rule>>, level: usize, span: Span) -> Res<(Expr, usize)> {
    if level == POWER {
        return power(it, span);
    }
    let (mut lhs, mut d) = climb(it, level + 1, span)?;
    while let Some(op) = it.next_if(|p| p.as_rule() == BINARY[level]) {
        let (rhs, dr) = climb(it, level + 1, span)?;
        (lhs, d) = binary(&op, lhs, d, rhs, dr)?;
    }
    Ok((lhs, d))
}

/// The operand `it` starts with and the `^` chain after it, under the
/// operand's prefix operators (`-a^b` is `-(a^b)`); an operand of `or_expr`
/// (an `add_expr`) is built alone. `span` is the whole flat rule's.
fn power(it: &mut Peekable<Pairs<'_, Rule>>, span: Span) -> Res<(Expr, usize)> {
    let p = first(it, span)?;
    if p.as_rule() != Rule::unary {
        return expr_d(p);
    }
    // The prefix operators, then the operand.
    let mut parts = p.into_inner();
    let Some(operand) = parts.next_back() else {
        return Err(SyntaxError::Unexpected {
            span,
            found: "this".into(),
            expected: "an expression".into(),
        });
    };
    let (mut e, mut d) = expr_d(operand)?;
    if let Some(op) = it.next_if(|p| p.as_rule() == Rule::op_pow) {
        let (rhs, dr) = power(it, span)?;
        (e, d) = binary(&op, e, d, rhs, dr)?;
    }
    for op in parts.rev() {
        d = deeper(d, op.as_span().into())?;
        let uop = if op.as_str() == "-" {
            UnOp::Neg
        } else {
            UnOp::Not
        };
        let s = Span::new(op.as_span().start(), e.span.end);
        e = mk(ExprKind::Unary(uop, Box::new(e)), s);
    }
    Ok((e, d))
}

/// `lhs op rhs` (of depths `dl` and `dr`) and its depth.
fn binary(op: &Pair<'_, Rule>, lhs: Expr, dl: usize, rhs: Expr, dr: usize) -> Res<(Expr, usize)> {
    let d = deeper(dl.max(dr), op.as_span().into())?;
    let op = match op.as_str() {
        "||" => BinOp::Or,
        "&&" => BinOp::And,
        "<" => BinOp::Lt,
        "<=" => BinOp::Le,
        ">" => BinOp::Gt,
        ">=" => BinOp::Ge,
        "==" => BinOp::Eq,
        "!=" => BinOp::Ne,
        "+" => BinOp::Add,
        "-" => BinOp::Sub,
        "*" => BinOp::Mul,
        "/" => BinOp::Div,
        ".*" => BinOp::ElemMul,
        "./" => BinOp::ElemDiv,
        _ => BinOp::Pow,
    };
    let s = lhs.span.to(rhs.span);
    Ok((mk(ExprKind::Binary(op, Box::new(lhs), Box::new(rhs)), s), d))
}

/// Rejects a binary `-` or `+` written `a -b` (space before, none after) at
/// the top level of the matrix entry `entry`: MATLAB reads `[0 -1]` as two
/// entries, hybsim's grammar as `0 - 1`, so either reading may be meant.
/// Parentheses, calls, index lists and nested matrices are not the entry's
/// top level (`[f(a -b)]` is one entry in MATLAB too).
pub(super) fn ambiguous_sign(entry: &Pair<'_, Rule>) -> Res<()> {
    fn walk(entry: &Pair<'_, Rule>, p: &Pair<'_, Rule>) -> Res<()> {
        let mut children = p.clone().into_inner();
        while let Some(q) = children.next() {
            match q.as_rule() {
                Rule::paren
                | Rule::call
                | Rule::index_list
                | Rule::matrix
                | Rule::sum_expr
                | Rule::extreme_expr => {}
                Rule::add_op => {
                    let span = q.as_span();
                    let input = span.get_input();
                    let spaced_before = input[..span.start()].ends_with(char::is_whitespace);
                    let glued_after =
                        input[span.end()..].starts_with(|c: char| !c.is_whitespace() && c != '#');
                    // The term after the operator: the operands and operators of this
                    // `add_expr` up to its next `+` or `-`.
                    let mut term = children.clone().take_while(|r| r.as_rule() != Rule::add_op);
                    if spaced_before
                        && glued_after
                        && let Some(first) = term.next()
                    {
                        let end = term.last().unwrap_or_else(|| first.clone()).as_span().end();
                        let rhs = &input[first.as_span().start()..end];
                        let op = q.as_str();
                        let lhs = input[entry.as_span().start()..span.start()].trim_end();
                        let (entry2, what) = if op == "-" {
                            (format!("-{rhs}"), "difference")
                        } else {
                            (rhs.to_string(), "sum")
                        };
                        // In brackets when the entry is the whole matrix (`[0 -1]`).
                        let (es, ee) = (entry.as_span().start(), entry.as_span().end());
                        let whole = input[..es].trim_end().ends_with('[')
                            && input[ee..].trim_start().starts_with(']');
                        let (open, close) = if whole { ("[", "]") } else { ("", "") };
                        return Err(SyntaxError::Foreign {
                            span: span.into(),
                            message: format!(
                                "ambiguous `{op}` inside `[ ]`: MATLAB reads `{lhs} {op}{rhs}` \
                                 as two entries, hybsim as a {what}"
                            ),
                            label: format!("a space before `{op}` and none after it"),
                            help: format!(
                                "write `{open}{lhs}, {entry2}{close}` for two entries or \
                                 `{open}{lhs} {op} {rhs}{close}` for the {what}"
                            ),
                        });
                    }
                }
                _ => walk(entry, &q)?,
            }
        }
        Ok(())
    }
    walk(entry, entry)
}
