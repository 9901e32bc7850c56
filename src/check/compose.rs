//! Subsystems: instances elaborated into the flat model.
//!
//! `ball = Ball(lambda = 0.8, u = plat.y)` becomes the subsystem's items
//! with every name it declares prefixed by the instance (`ball.h`,
//! `ball.impact`, `ball.lambda`); a family of instances `node[i] =
//! Node(...)` (inside `for`) gives families `node.x[i]` indexed first by the
//! instance's index. Parameters become `param`s (the argument, else the
//! default), inputs become [`Item::Signal`]s (the connection, evaluated in
//! the parent's names, else the default), and each instance's items are
//! wrapped in one [`Item::Part`] so that the checker puts its jump rules in
//! one part of the composite jump. Spans are kept, so errors point into the
//! subsystem's source. The checker and the engine never see a subsystem:
//! the language's semantics stay those of the flat model.

use std::collections::{HashMap, HashSet};

use super::error::CheckError;
use super::expr::{Hints, suggest};
use crate::source::Span;
use crate::syntax::ast::*;

/// The flat model of `model` if it declares instances (`None`: nothing to
/// elaborate), with the flat names whose definition failed (an
/// unconnected input: its uses report nothing more); errors are appended
/// to `errors`.
pub(crate) fn elaborate(
    model: &Model,
    errors: &mut Vec<CheckError>,
) -> Option<(Model, Vec<String>)> {
    let mut subs: HashMap<String, &SubsystemDecl> = HashMap::new();
    let mut instances = HashMap::new();
    let mut duplicates = HashSet::new();
    scan(
        &model.items,
        true,
        &mut subs,
        &mut instances,
        &mut duplicates,
        errors,
    );
    if instances.is_empty() {
        return None;
    }
    // An instance's name is the prefix of its members: no other declaration
    // of the model may take it (outputs write `ball` as an object).
    let mut declared = HashMap::new();
    collect(&model.items, &subs, 0, &mut declared);
    for (name, (_, _, span)) in &instances {
        if declared.contains_key(name) {
            errors.push(CheckError::Instance {
                message: format!("`{name}` names both an instance and a declaration of the model"),
                span: *span,
                decl: None,
                help: "rename the instance or the declaration".into(),
            });
        }
    }
    let mut e = Elab {
        subs,
        errors,
        stack: Vec::new(),
        hints: Default::default(),
        duplicates,
        unavailable: Vec::new(),
    };
    let items = e.items(&model.items, None);
    let model = Model {
        name: model.name.clone(),
        items,
    };
    Some((model, e.unavailable))
}

/// Collects the subsystem declarations, notes whether there are instances,
/// and reports declarations out of place.
/// Instances by name: (a family, its subsystem, the first declaration).
type Instances = HashMap<String, (bool, String, Span)>;

fn scan<'m>(
    items: &'m [Item],
    top: bool,
    subs: &mut HashMap<String, &'m SubsystemDecl>,
    instances: &mut Instances,
    duplicates: &mut HashSet<Span>,
    errors: &mut Vec<CheckError>,
) {
    for it in items {
        match it {
            Item::Subsystem(s) if top => {
                if let Some(prev) = subs.get(&s.name.name) {
                    errors.push(CheckError::Duplicate {
                        name: s.name.name.clone(),
                        span: s.name.span,
                        first: prev.name.span,
                    });
                } else {
                    subs.insert(s.name.name.clone(), s);
                }
            }
            Item::Subsystem(s) => errors.push(CheckError::Unsupported {
                what: "a subsystem declared inside `for` (declare it at the top level)".into(),
                span: s.name.span,
            }),
            Item::Import(i) if !top => errors.push(CheckError::Unsupported {
                what: "an import inside `for` (import at the top level)".into(),
                span: i.span,
            }),
            Item::Instance(inst) => {
                let family = !inst.target.indices.is_empty();
                let t = &inst.target.name;
                match instances.get(&t.name) {
                    // Members of one family may be declared in several loops.
                    Some((true, sub, _)) if family && *sub == inst.subsystem.name => {}
                    Some((_, _, first)) => {
                        errors.push(CheckError::Duplicate {
                            name: t.name.clone(),
                            span: t.span,
                            first: *first,
                        });
                        // Not expanded: each of its members would be
                        // declared twice too.
                        duplicates.insert(t.span);
                    }
                    None => {
                        instances.insert(
                            t.name.clone(),
                            (family, inst.subsystem.name.clone(), t.span),
                        );
                    }
                }
            }
            Item::Input(defs) => {
                for d in defs {
                    errors.push(CheckError::Unsupported {
                        what: "an input outside a subsystem (a model's inputs are its parameters)"
                            .into(),
                        span: d.target.span,
                    });
                }
            }
            Item::For(_, inner) | Item::Together(inner, _) => {
                scan(inner, false, subs, instances, duplicates, errors)
            }
            _ => {}
        }
    }
}

struct Elab<'m, 'e> {
    subs: HashMap<String, &'m SubsystemDecl>,
    errors: &'e mut Vec<CheckError>,
    /// The subsystems being expanded, outermost first (a subsystem that
    /// contains itself is an error, not an endless expansion).
    stack: Vec<String>,
    /// What is left of the budget for "did you mean" hints.
    hints: Hints,
    /// The instance declarations that repeat another's name (reported by
    /// [`scan`]), left out.
    duplicates: HashSet<Span>,
    /// Flat names whose definition failed (see [`elaborate`]).
    unavailable: Vec<String>,
}

/// How the names of one instance's subsystem are rewritten.
struct Scope {
    /// The instance's flat name (`ball`, `plant.adc`).
    prefix: String,
    /// Its index in a family of instances (empty for a single instance),
    /// as expressions over the enclosing loops.
    index: Vec<Expr>,
    /// The names the subsystem declares, and whether each is a family.
    locals: HashMap<String, bool>,
    /// Loop variables in scope: written name → fresh name (so that an
    /// instance index `i` is never captured by a loop of the subsystem).
    bound: Vec<(String, String)>,
    /// Input connections (already in the parent's names).
    inputs: HashMap<String, Expr>,
    /// The instance (for errors about it).
    instance: Span,
    /// The subsystem's name.
    subsystem: String,
    /// Names of the rules declared without one (as in a model).
    anonymous: super::rule_names::Anonymous,
}

impl Scope {
    fn flat(&self, name: &str) -> String {
        format!("{}.{name}", self.prefix)
    }

    fn index_args(&self) -> Vec<IndexArg> {
        self.index.iter().cloned().map(IndexArg::One).collect()
    }

    fn rename(&self, e: &Expr) -> Expr {
        let kind = match &e.kind {
            ExprKind::Num(_) | ExprKind::Bool(_) => e.kind.clone(),
            ExprKind::Name(n) => return self.name(n, e.span),
            ExprKind::Index(base, args) => {
                if let ExprKind::Name(n) = &base.kind
                    && self.locals.get(n) == Some(&true)
                    && !self.is_bound(n)
                {
                    let mut all = self.index_args();
                    all.extend(args.iter().map(|a| self.index_arg(a)));
                    let flat = Expr {
                        kind: ExprKind::Name(self.flat(n)),
                        span: base.span,
                    };
                    ExprKind::Index(Box::new(flat), all)
                } else {
                    ExprKind::Index(
                        Box::new(self.rename(base)),
                        args.iter().map(|a| self.index_arg(a)).collect(),
                    )
                }
            }
            ExprKind::Matrix(rows) => ExprKind::Matrix(
                rows.iter()
                    .map(|r| r.iter().map(|x| self.rename(x)).collect())
                    .collect(),
            ),
            ExprKind::Unary(op, a) => ExprKind::Unary(*op, Box::new(self.rename(a))),
            ExprKind::Binary(op, a, b) => {
                ExprKind::Binary(*op, Box::new(self.rename(a)), Box::new(self.rename(b)))
            }
            ExprKind::Call(f, args) => {
                ExprKind::Call(f.clone(), args.iter().map(|a| self.rename(a)).collect())
            }
            ExprKind::If(c, a, b) => ExprKind::If(
                Box::new(self.rename(c)),
                Box::new(self.rename(a)),
                Box::new(self.rename(b)),
            ),
            ExprKind::Fold(f, b, body) => {
                let (b, scope) = self.binder(b);
                ExprKind::Fold(*f, Box::new(b), Box::new(scope.rename(body)))
            }
        };
        Expr { kind, span: e.span }
    }

    fn is_bound(&self, n: &str) -> bool {
        self.bound.iter().any(|(w, _)| w == n)
    }

    /// A name used in the subsystem: a loop variable, a declared name (of
    /// this instance), or a built-in (`t`, `j`, `pi`, `inf`). Any other
    /// name is prefixed too, so that it is reported unknown rather than
    /// found among the parent's names: a subsystem sees only its own.
    fn name(&self, n: &str, span: Span) -> Expr {
        if let Some((_, fresh)) = self.bound.iter().rev().find(|(w, _)| w == n) {
            return Expr {
                kind: ExprKind::Name(fresh.clone()),
                span,
            };
        }
        let local = self.locals.contains_key(n);
        if !local && matches!(n, "t" | "j" | "pi" | "inf") {
            return Expr {
                kind: ExprKind::Name(n.to_string()),
                span,
            };
        }
        let flat = Expr {
            kind: ExprKind::Name(self.flat(n)),
            span,
        };
        if self.index.is_empty() || self.locals.get(n) == Some(&true) {
            flat
        } else {
            Expr {
                kind: ExprKind::Index(Box::new(flat), self.index_args()),
                span,
            }
        }
    }

    fn index_arg(&self, a: &IndexArg) -> IndexArg {
        match a {
            IndexArg::One(e) => IndexArg::One(self.rename(e)),
            IndexArg::Slice(a, b) => IndexArg::Slice(self.rename(a), self.rename(b)),
            IndexArg::All(s) => IndexArg::All(*s),
        }
    }

    /// A binder with its expressions renamed, and the scope inside it (its
    /// variables bound to fresh names).
    fn binder(&self, b: &Binder) -> (Binder, Scope) {
        let set = match &b.set {
            IndexSet::Range(a, c) => IndexSet::Range(self.rename(a), self.rename(c)),
            IndexSet::In(a, c) => IndexSet::In(self.rename(a), self.rename(c)),
            IndexSet::Out(a, c) => IndexSet::Out(self.rename(a), self.rename(c)),
            IndexSet::Edges(a) => IndexSet::Edges(self.rename(a)),
            other => other.clone(),
        };
        let mut inner = self.child();
        let vars: Vec<Ident> = b
            .vars
            .iter()
            .map(|v| {
                // `#` cannot be written in a model: the fresh name is unique.
                let fresh = format!("{}#{}", v.name, inner.bound.len());
                inner.bound.push((v.name.clone(), fresh.clone()));
                Ident {
                    name: fresh,
                    span: v.span,
                }
            })
            .collect();
        let filter = b.filter.as_ref().map(|f| inner.rename(f));
        (
            Binder {
                vars,
                set,
                filter,
                span: b.span,
            },
            inner,
        )
    }

    fn child(&self) -> Scope {
        Scope {
            prefix: self.prefix.clone(),
            index: self.index.clone(),
            locals: self.locals.clone(),
            bound: self.bound.clone(),
            inputs: self.inputs.clone(),
            instance: self.instance,
            subsystem: self.subsystem.clone(),
            anonymous: self.anonymous,
        }
    }

    /// A declared or assigned name: the instance's index goes first (into
    /// the family key of a family, as a first index list otherwise).
    fn target(&self, t: &Target) -> Target {
        let family = self.locals.get(&t.name.name) == Some(&true) || !t.indices.is_empty();
        self.target_as(t, family)
    }

    fn target_as(&self, t: &Target, family: bool) -> Target {
        let mut indices: Vec<Vec<IndexArg>> = t
            .indices
            .iter()
            .map(|l| l.iter().map(|a| self.index_arg(a)).collect())
            .collect();
        if !self.index.is_empty() {
            if family && !indices.is_empty() {
                let mut first = self.index_args();
                first.append(&mut indices[0]);
                indices[0] = first;
            } else {
                indices.insert(0, self.index_args());
            }
        }
        Target {
            name: Ident {
                name: self.flat(&t.name.name),
                span: t.name.span,
            },
            indices,
            span: t.span,
        }
    }

    fn definition(&self, d: &Definition) -> Definition {
        Definition {
            target: self.target(&d.target),
            value: self.rename(&d.value),
        }
    }

    fn flow_stmt(&self, s: &FlowStmt) -> FlowStmt {
        match s {
            FlowStmt::Eq(d) => FlowStmt::Eq(self.definition(d)),
            FlowStmt::For(b, body) => {
                let (b, inner) = self.binder(b);
                FlowStmt::For(b, body.iter().map(|s| inner.flow_stmt(s)).collect())
            }
        }
    }

    fn reset_stmt(&self, s: &ResetStmt) -> ResetStmt {
        match s {
            ResetStmt::Eq(d) => ResetStmt::Eq(self.definition(d)),
            ResetStmt::For(b, body) => {
                let (b, inner) = self.binder(b);
                ResetStmt::For(b, body.iter().map(|s| inner.reset_stmt(s)).collect())
            }
        }
    }
}

/// The names a subsystem declares (flat within it: `x`, and `sub.y` for
/// the members of a nested instance `sub`), each with whether it is a
/// family.
fn locals(
    sub: &SubsystemDecl,
    subs: &HashMap<String, &SubsystemDecl>,
    depth: usize,
) -> HashMap<String, bool> {
    let mut out = HashMap::new();
    for (p, _) in &sub.params {
        out.insert(p.name.clone(), false);
    }
    collect(&sub.items, subs, depth, &mut out);
    out
}

fn collect(
    items: &[Item],
    subs: &HashMap<String, &SubsystemDecl>,
    depth: usize,
    out: &mut HashMap<String, bool>,
) {
    let add = |t: &Target, out: &mut HashMap<String, bool>| {
        let fam = !t.indices.is_empty();
        let e = out.entry(t.name.name.clone()).or_insert(fam);
        *e |= fam;
    };
    for it in items {
        match it {
            Item::Param(defs) | Item::Output(defs) => defs.iter().for_each(|d| add(&d.target, out)),
            Item::Graph(d) | Item::RandomParam(d) => add(&d.target, out),
            Item::ParamTuple(ts, _) => ts.iter().for_each(|t| add(t, out)),
            Item::Table(t) => {
                out.entry(t.name.name.clone()).or_insert(false);
            }
            Item::State(defs) => defs.iter().for_each(|d| add(&d.target, out)),
            Item::Input(defs) => defs.iter().for_each(|d| add(&d.target, out)),
            Item::Noise(n) => add(&n.target, out),
            Item::For(_, inner) => collect(inner, subs, depth, out),
            Item::Instance(inst) => {
                // Depth-limited: a subsystem containing itself is reported
                // when it is expanded.
                if depth < 64
                    && let Some(s) = subs.get(&inst.subsystem.name)
                {
                    let fam = !inst.target.indices.is_empty();
                    for (m, f) in locals(s, subs, depth + 1) {
                        out.insert(format!("{}.{m}", inst.target.name.name), f || fam);
                    }
                }
            }
            _ => {}
        }
    }
}

/// The top-level inputs of a subsystem (name → declaration).
fn inputs(sub: &SubsystemDecl) -> Vec<&InputDef> {
    sub.items
        .iter()
        .filter_map(|it| match it {
            Item::Input(defs) => Some(defs.iter()),
            _ => None,
        })
        .flatten()
        .collect()
}

impl Elab<'_, '_> {
    fn items(&mut self, items: &[Item], scope: Option<&mut Scope>) -> Vec<Item> {
        let mut scope = scope;
        let mut out = Vec::new();
        for it in items {
            match (it, scope.as_deref_mut()) {
                (Item::Subsystem(_) | Item::Import(_), None) => {}
                (Item::Instance(inst), None)
                    if self.duplicates.contains(&inst.target.name.span) => {}
                (Item::Instance(inst), s) => out.extend(self.instance(inst, s.map(|s| &*s))),
                (Item::For(b, inner), None) => {
                    let body = self.items(inner, None);
                    out.push(Item::For(b.clone(), body));
                }
                (Item::For(b, inner), Some(s)) => {
                    let (b, mut child) = s.binder(b);
                    let body = self.items(inner, Some(&mut child));
                    s.anonymous = child.anonymous;
                    out.push(Item::For(b, body));
                }
                (Item::Together(_, span), None) => self.errors.push(CheckError::Unsupported {
                    what: "`together` in a model with subsystem instances (the instances \
                           already jump together: each subsystem in its jump set jumps in \
                           the same jump)"
                        .into(),
                    span: *span,
                }),
                (other, None) => out.push(other.clone()),
                (other, Some(s)) => out.extend(self.rename_item(other, s)),
            }
        }
        out
    }

    /// An item of a subsystem's body, in the instance's names.
    fn rename_item(&mut self, it: &Item, s: &mut Scope) -> Vec<Item> {
        let item = match it {
            Item::Param(defs) => Item::Param(defs.iter().map(|d| s.definition(d)).collect()),
            Item::Output(defs) => Item::Output(defs.iter().map(|d| s.definition(d)).collect()),
            Item::Graph(d) => Item::Graph(s.definition(d)),
            Item::RandomParam(d) => Item::RandomParam(s.definition(d)),
            Item::ParamTuple(ts, v) => {
                Item::ParamTuple(ts.iter().map(|t| s.target(t)).collect(), s.rename(v))
            }
            Item::State(defs) => Item::State(
                defs.iter()
                    .map(|d| StateDef {
                        target: s.target(&d.target),
                        init: d.init.as_ref().map(|e| s.rename(e)),
                    })
                    .collect(),
            ),
            Item::Noise(n) => Item::Noise(NoiseDecl {
                target: s.target(&n.target),
                dist: s.rename(&n.dist),
                every: n.every.as_ref().map(|e| s.rename(e)),
                span: n.span,
            }),
            Item::Flow(f) => Item::Flow(FlowBlock {
                stmts: f.stmts.iter().map(|x| s.flow_stmt(x)).collect(),
                set: f.set.as_ref().map(|e| s.rename(e)),
                span: f.span,
            }),
            Item::Jump(j) => {
                let name = match &j.name {
                    Some(t) => s.target_as(t, !t.indices.is_empty()),
                    None => {
                        let n = s.anonymous.name(&j.trigger);
                        s.target_as(
                            &Target {
                                name: Ident {
                                    name: n,
                                    span: j.span,
                                },
                                indices: Vec::new(),
                                span: j.span,
                            },
                            false,
                        )
                    }
                };
                let trigger = match &j.trigger {
                    Trigger::When(e) => Trigger::When(s.rename(e)),
                    Trigger::Every(e) => Trigger::Every(s.rename(e)),
                };
                Item::Jump(JumpDecl {
                    name: Some(name),
                    trigger,
                    resets: j.resets.iter().map(|r| s.reset_stmt(r)).collect(),
                    span: j.span,
                })
            }
            Item::Input(defs) => {
                return defs.iter().filter_map(|d| self.input(d, s)).collect();
            }
            other => {
                // The grammar admits nothing else in a subsystem.
                self.errors.push(CheckError::Unsupported {
                    what: "this declaration inside a subsystem".into(),
                    span: item_span(other),
                });
                return Vec::new();
            }
        };
        vec![item]
    }

    /// An input: its connection, else its default.
    fn input(&mut self, d: &InputDef, s: &Scope) -> Option<Item> {
        let name = &d.target.name.name;
        if !d.target.indices.is_empty() || !s.bound.is_empty() {
            self.errors.push(CheckError::Unsupported {
                what: "an indexed input or an input inside `for` (declare one input and \
                       connect a vector to it)"
                    .into(),
                span: d.target.span,
            });
            return None;
        }
        let value = match (s.inputs.get(name), &d.default) {
            (Some(v), _) => v.clone(),
            (None, Some(def)) => s.rename(def),
            (None, None) => {
                self.errors.push(CheckError::Instance {
                    message: format!(
                        "input `{name}` of `{}` ({}) is not connected",
                        s.prefix, s.subsystem
                    ),
                    span: s.instance,
                    decl: Some(d.target.span),
                    help: format!(
                        "connect it in the instance, `{}(…, {name} = EXPR)`, or give the input \
                         a value for when it is not connected: `input {name} = 0`",
                        s.subsystem
                    ),
                });
                // Its uses report nothing more (an unknown `p.u` suggesting
                // another member).
                self.unavailable.push(s.flat(name));
                return None;
            }
        };
        Some(Item::Signal(Definition {
            target: s.target_as(&d.target, false),
            value,
        }))
    }

    /// Expands one instance (inside `outer`'s subsystem, if any).
    fn instance(&mut self, inst: &InstanceDecl, outer: Option<&Scope>) -> Vec<Item> {
        let sname = &inst.subsystem.name;
        let Some(sub) = self.subs.get(sname).copied() else {
            let suggestion = self
                .hints
                .charge(self.subs.len())
                .then(|| suggest(sname, self.subs.keys()))
                .flatten();
            self.errors.push(CheckError::UnknownName {
                name: sname.clone(),
                span: inst.subsystem.span,
                suggestion,
            });
            return Vec::new();
        };
        if let Some(pos) = self.stack.iter().position(|s| s == sname) {
            let mut chain = self.stack[pos..].to_vec();
            chain.push(sname.clone());
            self.errors.push(CheckError::RecursiveSubsystem {
                chain,
                span: inst.span,
            });
            return Vec::new();
        }
        // The instance's flat name and index.
        let t = &inst.target;
        let mut own: Vec<Expr> = Vec::new();
        match t.indices.as_slice() {
            [] => {}
            [args] => {
                for a in args {
                    match a {
                        IndexArg::One(e) => {
                            own.push(outer.map_or_else(|| e.clone(), |o| o.rename(e)))
                        }
                        IndexArg::Slice(e, _) => self.errors.push(CheckError::Expected {
                            expected: "one index per family dimension".into(),
                            found: "a slice".into(),
                            span: e.span,
                        }),
                        IndexArg::All(sp) => self.errors.push(CheckError::Expected {
                            expected: "one index per family dimension".into(),
                            found: "`:`".into(),
                            span: *sp,
                        }),
                    }
                }
            }
            _ => self.errors.push(CheckError::Expected {
                expected: "an instance name or `name[i]`".into(),
                found: "several index lists".into(),
                span: t.span,
            }),
        }
        let (prefix, index) = match outer {
            None => (t.name.name.clone(), own),
            Some(o) => {
                let mut index = o.index.clone();
                index.extend(own);
                (o.flat(&t.name.name), index)
            }
        };
        // Arguments: parameters and input connections, in the parent's names.
        let ins = inputs(sub);
        let mut params: HashMap<String, Expr> = HashMap::new();
        let mut connections: HashMap<String, Expr> = HashMap::new();
        let mut seen: HashMap<&str, Span> = HashMap::new();
        for (name, value) in &inst.args {
            if let Some(first) = seen.insert(&name.name, name.span) {
                self.errors.push(CheckError::Duplicate {
                    name: name.name.clone(),
                    span: name.span,
                    first,
                });
                continue;
            }
            let value = outer.map_or_else(|| value.clone(), |o| o.rename(value));
            if sub.params.iter().any(|(p, _)| p.name == name.name) {
                params.insert(name.name.clone(), value);
            } else if ins.iter().any(|d| d.target.name.name == name.name) {
                connections.insert(name.name.clone(), value);
            } else {
                let cands = sub
                    .params
                    .iter()
                    .map(|(p, _)| p.name.as_str())
                    .chain(ins.iter().map(|d| d.target.name.name.as_str()));
                let hint = self
                    .hints
                    .charge(sub.params.len() + ins.len())
                    .then(|| suggest(&name.name, cands))
                    .flatten()
                    .map(|s| format!("did you mean `{s}`? "))
                    .unwrap_or_default();
                self.errors.push(CheckError::Instance {
                    message: format!(
                        "`{}` is neither a parameter nor an input of subsystem `{sname}`",
                        name.name
                    ),
                    span: name.span,
                    decl: Some(sub.name.span),
                    help: format!(
                        "{hint}the arguments of an instance set the subsystem's parameters \
                         and connect its inputs by name"
                    ),
                });
            }
        }
        let mut scope = Scope {
            prefix,
            index,
            locals: locals(sub, &self.subs, 0),
            bound: Vec::new(),
            inputs: connections,
            instance: inst.span,
            subsystem: sname.clone(),
            anonymous: Default::default(),
        };
        let mut out = Vec::new();
        for (p, default) in &sub.params {
            let value = match (params.remove(&p.name), default) {
                (Some(v), _) => v,
                (None, Some(d)) => scope.rename(d),
                (None, None) => {
                    self.errors.push(CheckError::Instance {
                        message: format!(
                            "parameter `{}` of `{}` ({sname}) has no value",
                            p.name, scope.prefix
                        ),
                        span: inst.span,
                        decl: Some(p.span),
                        help: format!(
                            "give it in the instance, `{sname}(…, {} = VALUE)`, or a default \
                             in the declaration, `subsystem {sname}(…, {} = VALUE)`",
                            p.name, p.name
                        ),
                    });
                    // Declared anyway (as 0, like a parameter whose value failed), so
                    // that the body's uses of it do not cascade into unknown names.
                    Expr {
                        kind: ExprKind::Num(0.0),
                        span: p.span,
                    }
                }
            };
            let target = Target {
                name: p.clone(),
                indices: Vec::new(),
                span: p.span,
            };
            out.push(Item::Param(vec![Definition {
                target: scope.target_as(&target, false),
                value,
            }]));
        }
        self.stack.push(sname.clone());
        out.extend(self.items(&sub.items, Some(&mut scope)));
        self.stack.pop();
        let part = Target {
            name: Ident {
                name: scope.prefix.clone(),
                span: t.name.span,
            },
            indices: if scope.index.is_empty() {
                Vec::new()
            } else {
                vec![scope.index_args()]
            },
            span: t.span,
        };
        vec![Item::Part(part, out)]
    }
}

/// A span for an item (for errors about the item as a whole).
fn item_span(it: &Item) -> Span {
    match it {
        Item::Param(d) | Item::Output(d) | Item::Metric(d) => {
            d.first().map(|d| d.target.span).unwrap_or_default()
        }
        Item::RandomParam(d) | Item::Graph(d) | Item::Signal(d) => d.target.span,
        Item::ParamTuple(t, _) => t.first().map(|t| t.span).unwrap_or_default(),
        Item::State(d) => d.first().map(|d| d.target.span).unwrap_or_default(),
        Item::Input(d) => d.first().map(|d| d.target.span).unwrap_or_default(),
        Item::Noise(n) => n.span,
        Item::Flow(f) => f.span,
        Item::Jump(j) => j.span,
        Item::Sim(s) => s.first().map(|s| s.key.span).unwrap_or_default(),
        Item::For(b, _) => b.span,
        Item::Together(_, s) => *s,
        Item::Design(d) => d.name.span,
        Item::Property(p) => p.span,
        Item::Sweep(s) => s.span,
        Item::Log(l) => l.span,
        Item::Import(i) => i.span,
        Item::Table(t) => t.name.span,
        Item::Subsystem(s) => s.name.span,
        Item::Instance(i) => i.span,
        Item::Part(t, _) => t.span,
    }
}
