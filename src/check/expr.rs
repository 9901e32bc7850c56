//! Elaboration of expressions: names, shapes, arities and constant
//! indices, lowering into the scalar graph.

use super::dag::{BinFn, BlockKind, Dist, NodeId, UnFn};
use super::error::{CheckError, Dims, LoneMember};
use super::limits::{Limits, Quantity};
use super::{Checker, Sym};
use crate::source::Span;
use crate::syntax::ast::{BinOp, Binder, Expr, ExprKind, Fold, IndexArg, IndexSet, UnOp};
use std::collections::BTreeMap;
use std::rc::Rc;

/// The elements of a [`Val`]: small values (scalars, short vectors, the
/// common case by far) are stored inline, without an allocation.
pub type Elems = smallvec::SmallVec<[NodeId; 4]>;

/// A checked value: a rows × cols matrix of scalar nodes (row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct Val {
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Elements, row-major.
    pub e: Elems,
    /// True for conditions (comparisons, logic, `bernoulli`).
    pub boolean: bool,
}

impl Val {
    /// A scalar.
    pub fn scalar(n: NodeId) -> Self {
        Self {
            rows: 1,
            cols: 1,
            e: smallvec::smallvec![n],
            boolean: false,
        }
    }
    /// The shape.
    pub fn dims(&self) -> Dims {
        (self.rows, self.cols)
    }
    fn is_scalar(&self) -> bool {
        self.rows == 1 && self.cols == 1
    }
    fn at(&self, r: usize, c: usize) -> NodeId {
        self.e[r * self.cols + c]
    }
}

/// Where an expression appears: what it may refer to.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ctx {
    /// Random draws allowed (initial values, resets).
    pub random: bool,
    /// White noise allowed (flow equations).
    pub wiener: bool,
    /// Words for messages: "a flow equation".
    pub place: &'static str,
}

/// How hybsim writes a function that other languages (MATLAB first, then C and
/// Python) call `name` and hybsim does not have: the help of its E0203. The nearest
/// built-in's spelling would often name another function (`log10` → `log`, `rand` →
/// `round`, `exprnd` → `exp`), a wrong value rather than an error if followed.
fn foreign_function(name: &str) -> Option<&'static str> {
    Some(match name {
        "log10" => "`log` is the natural logarithm: the base-10 logarithm is `log(x)/log(10)`",
        "log2" => "`log` is the natural logarithm: the base-2 logarithm is `log(x)/log(2)`",
        "ln" => "the natural logarithm is `log(x)`",
        "rand" => {
            "MATLAB's `rand` is the draw `uniform(0, 1)` (in initial values and resets; \
             `noise` for flows)"
        }
        "randn" => {
            "MATLAB's `randn` is the draw `normal(0, 1)` (in initial values and resets; \
             `noise` for flows)"
        }
        "unifrnd" => "MATLAB's `unifrnd(a, b)` is the draw `uniform(a, b)`",
        "normrnd" => "MATLAB's `normrnd(mu, sigma)` is the draw `normal(mu, sigma)`",
        "binornd" => "MATLAB's `binornd(1, p)` is the draw `bernoulli(p)`",
        "exprnd" | "exponential" | "expon" | "exprand" => {
            "a draw from the exponential distribution of mean m (rate 1/m) is \
             `-m*log(uniform(0, 1))`; `exp(x)` is the exponential function"
        }
        "numel" => "the entries of a vector are `length(x)`, of a matrix `rows(A)*cols(A)`",
        "size" => "a matrix's dimensions are `rows(A)` and `cols(A)` (`length(x)` of a vector)",
        "pow" | "power" => "a power is written `a^b`",
        "sgn" | "signum" => "the sign function is `sign(x)`",
        "arcsin" => "the inverse sine is `asin(x)`",
        "arccos" => "the inverse cosine is `acos(x)`",
        "arctan" => "the inverse tangent is `atan(x)` (`atan2(y, x)` by quadrant)",
        "fix" | "trunc" => "rounding towards zero is `sign(x)*floor(abs(x))`",
        "transpose" => "the transpose is written `A'`",
        "dot" => "the dot product of column vectors is `a'*b`",
        "heaviside" => "the step function is `if x >= 0 then 1 else 0`",
        _ => return None,
    })
}

/// Names of built-in functions, for suggestions.
pub(crate) const BUILTINS: &[&str] = &[
    "eye",
    "zeros",
    "ones",
    "diag",
    "blkdiag",
    "kron",
    "inv",
    "solve",
    "trace",
    "norm",
    "expm",
    "min",
    "max",
    "abs",
    "sqrt",
    "exp",
    "log",
    "sin",
    "cos",
    "tan",
    "atan",
    "atan2",
    "tanh",
    "asin",
    "acos",
    "sinh",
    "cosh",
    "sign",
    "floor",
    "ceil",
    "round",
    "frac",
    "mod",
    "rem",
    "hypot",
    "clamp",
    "interp",
    "rows",
    "cols",
    "length",
    "uniform",
    "normal",
    "bernoulli",
    "dare",
    "care",
    "are",
    "dlqr",
    "lqr",
    "c2d",
    "wiener",
];

impl Checker {
    /// False (and one error recorded) once the work done plus `cost`
    /// exceeds the `ops` limit ([`super::limits`]).
    pub(crate) fn within_budget(&mut self, cost: u64, span: Span) -> bool {
        let limit = self.limits.get(Quantity::Ops);
        if self.dag.ops().saturating_add(cost) <= limit {
            return true;
        }
        if !self.errors.iter().any(CheckError::is_size_limit) {
            self.err(CheckError::TooLarge { limit, span });
        }
        // Stay over the budget so that every later check fails fast.
        self.dag.charge(limit);
        false
    }

    /// False (and an error at `span`) when `estimate` of `q` is over its limit. Called before
    /// anything of that size is allocated.
    pub(crate) fn within_limit(&mut self, q: Quantity, estimate: f64, span: Span) -> bool {
        self.within(q, estimate, true, span)
    }

    /// False (and E0307 at `span`) when `estimate` of `q` needs more memory than there is,
    /// whatever its limit: for sizes that an operation computes from its operands (a matrix
    /// product, `kron`, `diag`, `blkdiag`), whose work the `ops` budget bounds but whose result
    /// a lifted budget would otherwise let through to an allocation that aborts the process.
    pub(crate) fn within_memory(&mut self, q: Quantity, estimate: f64, span: Span) -> bool {
        self.within(q, estimate, false, span)
    }

    /// The checks of `within_limit` (`limited`: `q` has its own limit) and `within_memory`
    /// (only the memory: the `ops` budget gates the size).
    fn within(&mut self, q: Quantity, estimate: f64, limited: bool, span: Span) -> bool {
        let limit = if limited {
            self.limits.get(q)
        } else {
            u64::MAX
        };
        // A limit raised past the memory there is does not let a size through that would abort
        // the process when allocated (the defaults need a few GB at most).
        let over_memory = (estimate > Limits::TABLE[q as usize].3 as f64)
            .then(|| Some((q.bytes(estimate)?, super::limits::memory_ceiling()?)))
            .flatten()
            .filter(|&(bytes, available)| bytes > available as f64);
        if estimate <= limit as f64 && over_memory.is_none() {
            return true;
        }
        // One error per quantity (a family over the limit would repeat it per member).
        if self.errors.iter().any(|e| {
            matches!(e, CheckError::Limit { quantity, .. } | CheckError::Memory { quantity, .. }
                if *quantity == q)
        }) {
            return false;
        }
        self.err(match over_memory {
            Some((bytes, available)) if estimate <= limit as f64 => CheckError::Memory {
                quantity: q,
                estimate,
                bytes,
                available,
                lifted: if limited { q } else { Quantity::Ops },
                span,
            },
            _ => CheckError::Limit {
                quantity: q,
                estimate,
                limit,
                span,
            },
        });
        // Stop here: every later loop and expression fails fast on the spent budget (a family
        // cut short would otherwise give one error per missing member), and `check_model`
        // drops what follows this error.
        self.dag.charge(self.limits.get(Quantity::Ops));
        false
    }

    pub(crate) fn err(&mut self, mut e: CheckError) {
        if let CheckError::FamilyIndex { name, lone, .. }
        | CheckError::FamilyOutOfRange { name, lone, .. } = &mut e
        {
            // The help once per family, at its first error.
            let hinted = |e: &CheckError| {
                matches!(e, CheckError::FamilyIndex { name: n, lone: Some(_), .. }
                    | CheckError::FamilyOutOfRange { name: n, lone: Some(_), .. } if n == name)
            };
            *lone = self
                .lone_member(name)
                .filter(|_| !self.errors.iter().any(hinted));
        }
        self.errors.push(e);
    }

    /// The one member of family `name` if it has one index n ≥ 2 (see
    /// [`LoneMember`]).
    fn lone_member(&self, name: &str) -> Option<LoneMember> {
        fn lone<V>(members: &BTreeMap<Vec<i64>, V>) -> Option<i64> {
            let key = members.keys().next().filter(|_| members.len() == 1)?;
            Some(key[0]).filter(|&n| key.len() == 1 && n >= 2)
        }
        let (keyword, index) = match self.syms.get(name)? {
            Sym::ParamFamily { members, .. } => ("param", lone(members)?),
            Sym::StateFamily { members, .. } => ("state", lone(members)?),
            Sym::OutputFamily { members, .. } => ("output", lone(members)?),
            _ => return None,
        };
        Some(LoneMember { keyword, index })
    }

    /// E0506: the value of setting `key` at `span` is invalid, because `reason`.
    pub(crate) fn bad_setting(&mut self, key: &str, reason: impl Into<String>, span: Span) {
        self.err(CheckError::BadSetting {
            key: key.to_string(),
            reason: reason.into(),
            span,
        });
    }

    fn konst_val(&mut self, rows: usize, cols: usize, f: impl Fn(usize, usize) -> f64) -> Val {
        let mut e = Elems::with_capacity(rows * cols);
        for r in 0..rows {
            for c in 0..cols {
                e.push(self.dag.konst(f(r, c)));
            }
        }
        Val {
            rows,
            cols,
            e,
            boolean: false,
        }
    }

    /// The constant value of a scalar expression.
    pub(crate) fn const_scalar(&mut self, e: &Expr, what: &str) -> Option<f64> {
        let v = self.expr(e, &CONST_CTX)?;
        if !v.is_scalar() {
            self.err(CheckError::Expected {
                expected: format!("a scalar for {what}"),
                found: dims_words(v.dims()),
                span: e.span,
            });
            return None;
        }
        match self.dag.as_const(v.e[0]) {
            Some(x) => Some(x),
            None => {
                self.err(CheckError::NotConstant {
                    what: what.to_string(),
                    span: e.span,
                });
                None
            }
        }
    }

    /// The constant integer value of an expression.
    pub(crate) fn const_int(&mut self, e: &Expr, what: &str) -> Option<i64> {
        let x = self.const_scalar(e, what)?;
        self.int_of(x, e, what)
    }

    /// `x`, the constant value of `e`, as an integer (else an error at `e`).
    fn int_of(&mut self, x: f64, e: &Expr, what: &str) -> Option<i64> {
        if x.fract() != 0.0 || x.abs() > 1e15 {
            // A whole number too large to be a count or an index (`2^62`)
            // is said to be one.
            let expected = if x.fract() == 0.0 {
                format!("an integer of magnitude at most 1e15 for {what}")
            } else {
                format!("an integer for {what}")
            };
            self.err(CheckError::Expected {
                expected,
                found: crate::num::fmt_num(x),
                span: e.span,
            });
            return None;
        }
        Some(x as i64)
    }

    /// The constant matrix value of an expression.
    pub(crate) fn const_matrix(&mut self, e: &Expr, what: &str) -> Option<(Val, Vec<f64>)> {
        let v = self.expr(e, &CONST_CTX)?;
        let vals: Option<Vec<f64>> = v.e.iter().map(|&n| self.dag.as_const(n)).collect();
        match vals {
            Some(x) => Some((v, x)),
            None => {
                self.err(CheckError::NotConstant {
                    what: what.to_string(),
                    span: e.span,
                });
                None
            }
        }
    }

    /// The graph `g` when it is the name of a square matrix parameter: its
    /// size and value, borrowed. `in(G, i)` / `out(G, i)` then read one row
    /// or column where evaluating `G` would copy all N² entries (`for k in
    /// out(G, i)` inside `for i in 1..N` was O(N³)). `None` for anything
    /// else (the general path evaluates and reports).
    fn named_adjacency(&self, g: &Expr) -> Option<(usize, &Val)> {
        let ExprKind::Name(name) = &g.kind else {
            return None;
        };
        if self.scope_lookup(name).is_some() || self.poisoned.contains_key(name) {
            return None;
        }
        let Some(Sym::Param { val, .. }) = self.syms.get(name) else {
            return None;
        };
        (val.rows == val.cols).then_some((val.rows, val))
    }

    /// The members of a binder's index set (tuples of 1-based indices),
    /// before filtering.
    pub(crate) fn index_set(&mut self, b: &Binder) -> Option<Vec<Vec<i64>>> {
        let want = match b.set {
            IndexSet::Edges(_) => 2,
            _ => 1,
        };
        if b.vars.len() != want {
            self.err(CheckError::Expected {
                expected: format!("{want} index variable(s) for this set"),
                found: format!("{}", b.vars.len()),
                span: b.span,
            });
            return None;
        }
        let adjacency = |this: &mut Self, g: &Expr| -> Option<(usize, Vec<f64>)> {
            let (v, x) = this.const_matrix(g, "a graph's adjacency matrix")?;
            if v.rows != v.cols {
                this.err(CheckError::Expected {
                    expected: "a square adjacency matrix".into(),
                    found: dims_words(v.dims()),
                    span: g.span,
                });
                return None;
            }
            Some((v.rows, x))
        };
        Some(match &b.set {
            IndexSet::Range(lo, hi) => {
                let lo = self.const_int(lo, "a range bound")?;
                let hi = self.const_int(hi, "a range bound")?;
                let members = (i128::from(hi) - i128::from(lo) + 1).max(0);
                if !self.within_limit(Quantity::Iterations, members as f64, b.span) {
                    return None;
                }
                (lo..=hi).map(|i| vec![i]).collect()
            }
            IndexSet::In(g, i) | IndexSet::Out(g, i) => {
                let inward = matches!(b.set, IndexSet::In(..));
                if let Some(n) = self.named_adjacency(g).map(|(n, _)| n) {
                    let iv = self.const_int(i, "an agent index")?;
                    if iv < 1 || iv as usize > n {
                        self.err(CheckError::IndexOutOfRange {
                            index: iv,
                            len: n,
                            span: i.span,
                        });
                        return None;
                    }
                    let (_, a) = self.named_adjacency(g)?;
                    let iv = iv as usize - 1;
                    let weights: Option<Vec<f64>> = (0..n)
                        .map(|k| {
                            let w = if inward {
                                a.e[iv * n + k]
                            } else {
                                a.e[k * n + iv]
                            };
                            self.dag.as_const(w)
                        })
                        .collect();
                    // A matrix that is not constant: the general path says so.
                    if let Some(weights) = weights {
                        return Some(
                            (0..n)
                                .filter(|&k| weights[k] != 0.0)
                                .map(|k| vec![k as i64 + 1])
                                .collect(),
                        );
                    }
                }
                let (n, a) = adjacency(self, g)?;
                let iv = self.const_int(i, "an agent index")?;
                if iv < 1 || iv as usize > n {
                    self.err(CheckError::IndexOutOfRange {
                        index: iv,
                        len: n,
                        span: i.span,
                    });
                    return None;
                }
                let iv = iv as usize - 1;
                (0..n)
                    .filter(|&k| {
                        let w = if inward { a[iv * n + k] } else { a[k * n + iv] };
                        w != 0.0
                    })
                    .map(|k| vec![k as i64 + 1])
                    .collect()
            }
            IndexSet::Named(id) => {
                match self.set_scopes.iter().rev().find(|(n, _)| *n == id.name) {
                    Some((_, members)) => members.iter().map(|&i| vec![i]).collect(),
                    None => {
                        self.unknown(&id.name, id.span);
                        return None;
                    }
                }
            }
            IndexSet::Subsets(_) => {
                self.err(CheckError::Expected {
                    expected: "`subsets(..)` only in `for S in subsets(..)` of a design block"
                        .into(),
                    found: "`subsets` here".into(),
                    span: b.span,
                });
                return None;
            }
            IndexSet::Edges(g) => {
                let (n, a) = adjacency(self, g)?;
                let mut out = Vec::new();
                for i in 0..n {
                    for k in 0..n {
                        if a[i * n + k] != 0.0 {
                            out.push(vec![i as i64 + 1, k as i64 + 1]);
                        }
                    }
                }
                out
            }
        })
    }

    /// Runs `body` once per member of the binder's set that passes its
    /// filter, with the index variables bound.
    pub(crate) fn for_each(&mut self, b: &Binder, body: &mut dyn FnMut(&mut Self)) {
        let Some(members) = self.index_set(b) else {
            return;
        };
        let names: Vec<Rc<str>> = b.vars.iter().map(|v| Rc::from(v.name.as_str())).collect();
        for m in members {
            self.dag.charge(1);
            if !self.within_budget(0, b.span) {
                return;
            }
            let depth = self.scopes.len();
            for (v, &i) in names.iter().zip(&m) {
                self.scopes.push((Rc::clone(v), i));
            }
            let keep = match &b.filter {
                None => true,
                Some(f) => match self.expr(f, &CONST_CTX) {
                    Some(v) if v.is_scalar() => match self.dag.as_const(v.e[0]) {
                        Some(x) => x != 0.0,
                        None => {
                            self.err(CheckError::NotConstant {
                                what: "a filter".into(),
                                span: f.span,
                            });
                            self.scopes.truncate(depth);
                            return;
                        }
                    },
                    _ => {
                        self.scopes.truncate(depth);
                        return;
                    }
                },
            };
            if keep {
                body(self);
            }
            self.scopes.truncate(depth);
        }
    }

    pub(crate) fn scope_lookup(&self, name: &str) -> Option<i64> {
        self.scopes
            .iter()
            .rev()
            .find(|(n, _)| &**n == name)
            .map(|&(_, i)| i)
    }

    /// All names visible now, for suggestions.
    pub(crate) fn visible_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self.syms.keys().cloned().collect();
        v.extend(self.signal_names().cloned());
        v.extend(self.scopes.iter().map(|(n, _)| n.to_string()));
        v.push("t".into());
        v.push("j".into());
        v.push("pi".into());
        v
    }

    /// The visible name closest to `name`, within the hint budget.
    pub(crate) fn suggest_visible(&mut self, name: &str) -> Option<String> {
        let n = self.syms.len() + self.signal_count() + self.scopes.len() + 3;
        if !self.hints.charge(n) {
            return None;
        }
        suggest(name, self.visible_names())
    }

    fn unknown(&mut self, name: &str, span: Span) {
        let suggestion = self.suggest_visible(name);
        self.err(CheckError::UnknownName {
            name: name.to_string(),
            span,
            suggestion,
        });
    }

    /// Resolves a family member key `[i, k]` of `name`.
    pub(crate) fn family_key(&mut self, args: &[IndexArg]) -> Option<Vec<i64>> {
        let mut key = Vec::new();
        for a in args {
            match a {
                IndexArg::One(e) => {
                    // A loop variable (the common `x[i]`) is read directly:
                    // the general path allocates a value and interns a
                    // constant per member reference. Same checks, same work
                    // charged.
                    if let ExprKind::Name(n) = &e.kind
                        && let Some(i) = self.scope_lookup(n)
                        && i.abs() <= 1_000_000_000_000_000
                    {
                        if !self.within_budget(0, e.span) {
                            return None;
                        }
                        self.dag.charge(1);
                        key.push(i);
                        continue;
                    }
                    key.push(self.const_int(e, "a family index")?)
                }
                IndexArg::Slice(lo, _) => {
                    self.err(CheckError::Expected {
                        expected: "one index per family dimension".into(),
                        found: "a slice".into(),
                        span: lo.span,
                    });
                    return None;
                }
                IndexArg::All(s) => {
                    self.err(CheckError::Expected {
                        expected: "one index per family dimension".into(),
                        found: "`:`".into(),
                        span: *s,
                    });
                    return None;
                }
            }
        }
        Some(key)
    }

    fn name_val(&mut self, name: &str, span: Span, ctx: &Ctx) -> Option<Val> {
        if let Some(i) = self.scope_lookup(name) {
            return Some(Val::scalar(self.dag.konst(i as f64)));
        }
        if self.is_poisoned(name) {
            return None;
        }
        if !self.syms.contains_key(name) {
            if self.is_signal_family(name) {
                self.err(CheckError::FamilyIndex {
                    lone: None,
                    name: name.to_string(),
                    span,
                });
                return None;
            }
            if !self.demand_signal(name, &[]) {
                return None;
            }
        }
        match self.syms.get(name) {
            Some(Sym::Param { val, .. }) | Some(Sym::Output { val, .. }) => Some(Val::clone(val)),
            Some(Sym::State { field, .. }) => Some(self.field_val(*field)),
            Some(Sym::Wiener { val, .. }) => {
                let val = val.clone();
                if !ctx.wiener {
                    self.err(CheckError::RandomNotAllowed {
                        place: ctx.place.to_string(),
                        span,
                    });
                    return None;
                }
                Some(val)
            }
            Some(Sym::ParamFamily { .. })
            | Some(Sym::StateFamily { .. })
            | Some(Sym::OutputFamily { .. }) => {
                self.err(CheckError::FamilyIndex {
                    lone: None,
                    name: name.to_string(),
                    span,
                });
                None
            }
            None => match name {
                "t" => Some(Val::scalar(self.dag.time())),
                "j" => Some(Val::scalar(self.dag.jumps())),
                "pi" => Some(Val::scalar(self.dag.konst(std::f64::consts::PI))),
                "inf" => Some(Val::scalar(self.dag.konst(f64::INFINITY))),
                _ => {
                    self.unknown(name, span);
                    None
                }
            },
        }
    }

    /// True if `name`'s value is unavailable ([`Checker::poisoned`]);
    /// records why in [`Checker::poison_hit`] (the caller reports nothing).
    pub(crate) fn is_poisoned(&mut self, name: &str) -> bool {
        match self.poisoned.get(name) {
            Some(cause) => {
                self.poison_hit = Some(cause.clone());
                true
            }
            None => false,
        }
    }

    /// The value of state field `field`.
    pub(crate) fn field_val(&mut self, field: usize) -> Val {
        let f = &self.fields[field];
        let (rows, cols, off) = (f.rows, f.cols, f.offset);
        let e = (0..rows * cols).map(|k| self.dag.state(off + k)).collect();
        Val {
            rows,
            cols,
            e,
            boolean: false,
        }
    }

    /// Elaborates `name[args]` where `name` is a family.
    fn family_member(&mut self, name: &str, span: Span, args: &[IndexArg]) -> Option<Val> {
        if self.is_poisoned(name) {
            return None;
        }
        let key = self.family_key(args)?;
        if !self.demand_signal(name, &key) {
            return None;
        }
        let found = match self.syms.get(name) {
            Some(Sym::ParamFamily { members, .. }) | Some(Sym::OutputFamily { members, .. }) => {
                members.get(&key).cloned().map(Ok)
            }
            Some(Sym::StateFamily { members, .. }) => members.get(&key).copied().map(Err),
            _ => None,
        };
        match found {
            Some(Ok(v)) => Some(v),
            Some(Err(field)) => Some(self.field_val(field)),
            None => {
                let members = self.family_members_words(name);
                self.err(CheckError::FamilyOutOfRange {
                    lone: None,
                    name: name.to_string(),
                    index: key_label(&key),
                    members,
                    span,
                });
                None
            }
        }
    }

    pub(crate) fn family_members_words(&self, name: &str) -> String {
        let keys: Vec<Vec<i64>> = match self.syms.get(name) {
            Some(Sym::ParamFamily { members, .. }) | Some(Sym::OutputFamily { members, .. }) => {
                members.keys().cloned().collect()
            }
            Some(Sym::StateFamily { members, .. }) => members.keys().cloned().collect(),
            _ => Vec::new(),
        };
        let labels: Vec<String> = keys.iter().map(|k| key_label(k)).collect();
        members_words(&labels)
    }

    pub(crate) fn is_family(&self, name: &str) -> bool {
        self.is_signal_family(name)
            || matches!(
                self.syms.get(name),
                Some(Sym::ParamFamily { .. })
                    | Some(Sym::StateFamily { .. })
                    | Some(Sym::OutputFamily { .. })
            )
    }

    /// Elaborates an expression. `None` means an error was recorded.
    pub(crate) fn expr(&mut self, e: &Expr, ctx: &Ctx) -> Option<Val> {
        if !self.within_budget(0, e.span) {
            return None;
        }
        match &e.kind {
            ExprKind::Num(x) => Some(Val::scalar(self.dag.konst(*x))),
            ExprKind::Bool(b) => {
                let mut v = Val::scalar(self.dag.konst(if *b { 1.0 } else { 0.0 }));
                v.boolean = true;
                Some(v)
            }
            ExprKind::Name(n) => self.name_val(n, e.span, ctx),
            ExprKind::Matrix(rows) => self.matrix_lit(rows, e.span, ctx),
            ExprKind::Unary(op, a) => {
                let v = self.expr(a, ctx)?;
                Some(match op {
                    UnOp::Neg => self.map(&v, UnFn::Neg),
                    UnOp::Not => {
                        self.logical_operand(&v, "`!`", a.span)?;
                        let mut r = self.map(&v, UnFn::Not);
                        r.boolean = true;
                        r
                    }
                    UnOp::Transpose => transpose(&v),
                })
            }
            ExprKind::Binary(op, a, b) => {
                let l = self.expr(a, ctx);
                // `a && b` needs b only where a holds, `a || b` only where
                // it does not (for run-time indices).
                let cond = match (op, &l) {
                    (BinOp::And, Some(v)) if v.is_scalar() => Some(v.e[0]),
                    (BinOp::Or, Some(v)) if v.is_scalar() => Some(self.dag.un(UnFn::Not, v.e[0])),
                    _ => None,
                };
                let r = self.under(cond, |this| this.expr(b, ctx));
                let (l, r) = (l?, r?);
                if let BinOp::And | BinOp::Or = op {
                    let sym = format!("`{}`", op.symbol());
                    let left = self.logical_operand(&l, &sym, a.span);
                    self.logical_operand(&r, &sym, b.span)?;
                    left?;
                }
                self.binary(*op, l, r, e.span)
            }
            ExprKind::If(c, a, b) => {
                let cv = self.expr(c, ctx);
                let (yes, no) = match &cv {
                    Some(v) if v.is_scalar() => {
                        let not = self.dag.un(UnFn::Not, v.e[0]);
                        (Some(v.e[0]), Some(not))
                    }
                    _ => (None, None),
                };
                let av = self.under(yes, |this| this.expr(a, ctx));
                let bv = self.under(no, |this| this.expr(b, ctx));
                let (cv, av, bv) = (cv?, av?, bv?);
                if !cv.is_scalar() {
                    self.err(CheckError::Expected {
                        expected: "a scalar condition".into(),
                        found: dims_words(cv.dims()),
                        span: c.span,
                    });
                    return None;
                }
                let (av, bv) = self.broadcast(av, bv, "if", e.span)?;
                let boolean = av.boolean && bv.boolean;
                let el =
                    av.e.iter()
                        .zip(&bv.e)
                        .map(|(&x, &y)| self.dag.select(cv.e[0], x, y))
                        .collect();
                Some(Val {
                    rows: av.rows,
                    cols: av.cols,
                    e: el,
                    boolean,
                })
            }
            ExprKind::Fold(fold, b, body) => {
                let mut acc: Option<Val> = None;
                let mut failed = false;
                self.for_each(b, &mut |this| {
                    if failed {
                        return;
                    }
                    match this.expr(body, ctx) {
                        Some(v) => {
                            acc = match acc.take() {
                                None => Some(v),
                                Some(a) => {
                                    let r = this.fold_step(*fold, a, v, body.span);
                                    failed |= r.is_none();
                                    r
                                }
                            }
                        }
                        None => failed = true,
                    }
                });
                if failed {
                    return None;
                }
                // Over an empty set: the fold's identity.
                let empty = match fold {
                    Fold::Sum => 0.0,
                    Fold::Max => f64::NEG_INFINITY,
                    Fold::Min => f64::INFINITY,
                };
                Some(acc.unwrap_or_else(|| Val::scalar(self.dag.konst(empty))))
            }
            ExprKind::Index(base, args) => {
                if let ExprKind::Name(n) = &base.kind
                    && self.scope_lookup(n).is_none()
                    && self.is_family(n)
                {
                    return self.family_member(n, e.span, args);
                }
                // A named matrix is indexed where it is stored: copying it
                // for each `E[:, i]` made loops over its columns quadratic.
                if let ExprKind::Name(n) = &base.kind
                    && self.scope_lookup(n).is_none()
                    && !self.is_poisoned(n)
                    && let Some(Sym::Param { val, .. } | Sym::Output { val, .. }) =
                        self.syms.get(n.as_str())
                {
                    let v = Rc::clone(val);
                    return self.index_in(&v, args, e.span, ctx);
                }
                let v = self.expr(base, ctx)?;
                self.index_in(&v, args, e.span, ctx)
            }
            ExprKind::Call(f, args) => self.call(&f.name, f.span, args, e.span, ctx),
        }
    }

    /// `Some(())` if `v`, an operand of the logical operator `op` (`&&`, `||`, `!`), is a
    /// condition (`x >= 0`, `true`, a parameter set to one, …); otherwise the error at `span`:
    /// a number is not read as true where non-zero.
    fn logical_operand(&mut self, v: &Val, op: &str, span: Span) -> Option<()> {
        if v.boolean {
            return Some(());
        }
        self.err(CheckError::Expected {
            expected: format!("a condition such as `h >= 0` as operand of {op}"),
            found: if v.is_scalar() {
                "a number".into()
            } else {
                format!("{} of numbers", dims_words(v.dims()))
            },
            span,
        });
        None
    }

    /// `[a, b; c, d]`: the blocks of each row side by side, the rows stacked. Built once from all
    /// blocks (not by joining pairs, which copied the growing matrix per element: quadratic in the
    /// literal's length).
    fn matrix_lit(&mut self, rows: &[Vec<Expr>], span: Span, ctx: &Ctx) -> Option<Val> {
        let mut joined: Vec<Val> = Vec::with_capacity(rows.len());
        let mut total_rows = 0;
        let mut ok = true;
        for row in rows {
            let mut blocks: Vec<Val> = Vec::with_capacity(row.len());
            let mut cols = 0;
            for b in row {
                let Some(v) = self.expr(b, ctx) else {
                    ok = false;
                    continue;
                };
                match blocks.first() {
                    Some(a) if a.rows != v.rows => {
                        self.err(CheckError::ShapeMismatch {
                            op: "[a, b] (side by side)".into(),
                            left: (a.rows, cols),
                            right: v.dims(),
                            span: b.span,
                        });
                        ok = false;
                    }
                    _ => {
                        cols += v.cols;
                        blocks.push(v);
                    }
                }
            }
            let Some(r) = side_by_side(blocks, cols) else {
                continue;
            };
            match joined.first() {
                Some(a) if a.cols != r.cols => {
                    let rspan = row[0].span.to(row[row.len() - 1].span);
                    self.err(CheckError::ShapeMismatch {
                        op: "[a; b] (stacked)".into(),
                        left: (total_rows, a.cols),
                        right: r.dims(),
                        span: rspan,
                    });
                    ok = false;
                }
                _ => {
                    total_rows += r.rows;
                    joined.push(r);
                }
            }
        }
        if !ok {
            return None;
        }
        let _ = span;
        let cols = joined.first().map_or(0, |r| r.cols);
        let mut e = Elems::with_capacity(total_rows * cols);
        for r in &joined {
            e.extend_from_slice(&r.e);
        }
        Some(Val {
            rows: total_rows,
            cols,
            e,
            // A matrix of conditions (`[x > 0; y > 0]`, `[true, false]`) is one.
            boolean: !joined.is_empty() && joined.iter().all(|r| r.boolean),
        })
    }

    fn map(&mut self, v: &Val, f: UnFn) -> Val {
        Val {
            rows: v.rows,
            cols: v.cols,
            e: v.e.iter().map(|&n| self.dag.un(f, n)).collect(),
            boolean: false,
        }
    }

    fn broadcast(&mut self, a: Val, b: Val, op: &str, span: Span) -> Option<(Val, Val)> {
        if a.dims() == b.dims() {
            return Some((a, b));
        }
        if a.is_scalar() {
            let e = Elems::from_elem(a.e[0], b.e.len());
            return Some((
                Val {
                    rows: b.rows,
                    cols: b.cols,
                    e,
                    boolean: a.boolean,
                },
                b,
            ));
        }
        if b.is_scalar() {
            let e = Elems::from_elem(b.e[0], a.e.len());
            let bb = Val {
                rows: a.rows,
                cols: a.cols,
                e,
                boolean: b.boolean,
            };
            return Some((a, bb));
        }
        self.err(CheckError::ShapeMismatch {
            op: op.to_string(),
            left: a.dims(),
            right: b.dims(),
            span,
        });
        None
    }

    fn zip(&mut self, a: &Val, b: &Val, f: BinFn) -> Val {
        Val {
            rows: a.rows,
            cols: a.cols,
            e: a.e
                .iter()
                .zip(&b.e)
                .map(|(&x, &y)| self.dag.bin(f, x, y))
                .collect(),
            boolean: false,
        }
    }

    fn matmul(&mut self, a: &Val, b: &Val) -> Val {
        let mut e = Elems::with_capacity(a.rows * b.cols);
        for i in 0..a.rows {
            for j in 0..b.cols {
                let mut acc = self.dag.konst(0.0);
                for k in 0..a.cols {
                    let p = self.dag.bin(BinFn::Mul, a.at(i, k), b.at(k, j));
                    acc = self.dag.bin(BinFn::Add, acc, p);
                }
                e.push(acc);
            }
        }
        Val {
            rows: a.rows,
            cols: b.cols,
            e,
            boolean: false,
        }
    }

    /// One step of a fold: `a + v`, or the elementwise max/min of `a` and
    /// `v` (shapes as `max(a, b)` takes them: equal, or one a scalar).
    fn fold_step(&mut self, fold: Fold, a: Val, v: Val, span: Span) -> Option<Val> {
        let (f, name) = match fold {
            Fold::Sum => return self.binary(BinOp::Add, a, v, span),
            Fold::Max => (BinFn::Max, "max"),
            Fold::Min => (BinFn::Min, "min"),
        };
        let (a, v) = self.broadcast(a, v, name, span)?;
        Some(self.zip(&a, &v, f))
    }

    pub(crate) fn binary(&mut self, op: BinOp, a: Val, b: Val, span: Span) -> Option<Val> {
        let sym = op.symbol();
        let elem = |this: &mut Self, a: Val, b: Val, f: BinFn, boolean: bool| {
            let (a, b) = this.broadcast(a, b, sym, span)?;
            let mut r = this.zip(&a, &b, f);
            r.boolean = boolean;
            Some(r)
        };
        match op {
            BinOp::Add => elem(self, a, b, BinFn::Add, false),
            BinOp::Sub => elem(self, a, b, BinFn::Sub, false),
            BinOp::ElemMul => elem(self, a, b, BinFn::Mul, false),
            BinOp::ElemDiv => elem(self, a, b, BinFn::Div, false),
            BinOp::Lt => elem(self, a, b, BinFn::Lt, true),
            BinOp::Le => elem(self, a, b, BinFn::Le, true),
            BinOp::Gt => elem(self, a, b, BinFn::Gt, true),
            BinOp::Ge => elem(self, a, b, BinFn::Ge, true),
            BinOp::Eq => elem(self, a, b, BinFn::Eq, true),
            BinOp::Ne => elem(self, a, b, BinFn::Ne, true),
            BinOp::And => elem(self, a, b, BinFn::And, true),
            BinOp::Or => elem(self, a, b, BinFn::Or, true),
            BinOp::Mul => {
                if a.is_scalar() || b.is_scalar() {
                    elem(self, a, b, BinFn::Mul, false)
                } else if a.cols == b.rows {
                    let cost = (a.rows * a.cols) as u64 * b.cols as u64;
                    let entries = a.rows as f64 * b.cols as f64;
                    (self.within_budget(2 * cost, span)
                        && self.within_memory(Quantity::Elements, entries, span))
                    .then(|| self.matmul(&a, &b))
                } else {
                    self.err(CheckError::ShapeMismatch {
                        op: "*".into(),
                        left: a.dims(),
                        right: b.dims(),
                        span,
                    });
                    None
                }
            }
            BinOp::Div => {
                if b.is_scalar() {
                    elem(self, a, b, BinFn::Div, false)
                } else {
                    self.err(CheckError::ShapeMismatch {
                        op: "/ (divide by a scalar; use solve or inv for matrices)".into(),
                        left: a.dims(),
                        right: b.dims(),
                        span,
                    });
                    None
                }
            }
            BinOp::Pow => {
                if a.is_scalar() && b.is_scalar() {
                    return elem(self, a, b, BinFn::Pow, false);
                }
                let k = if b.is_scalar() {
                    self.dag.as_const(b.e[0])
                } else {
                    None
                };
                match k {
                    Some(k) if a.rows == a.cols && k >= 0.0 && k.fract() == 0.0 && k <= 64.0 => {
                        let n = a.rows as u64;
                        if !self.within_budget(2 * k as u64 * n * n * n, span) {
                            return None;
                        }
                        let mut r = identity(self, a.rows);
                        for _ in 0..k as usize {
                            r = self.matmul(&r, &a);
                        }
                        Some(r)
                    }
                    // The exponent is fine but the base is not square.
                    Some(k) if k >= 0.0 && k.fract() == 0.0 && k <= 64.0 => {
                        self.err(CheckError::ShapeMismatch {
                            op: "^ (scalars, or a square matrix to a constant integer power)"
                                .into(),
                            left: a.dims(),
                            right: b.dims(),
                            span,
                        });
                        None
                    }
                    // A square matrix with an exponent it cannot take: say which.
                    k if a.rows == a.cols && b.is_scalar() => {
                        let found = match k {
                            None => "an exponent that is not a constant".to_string(),
                            Some(k) if k < 0.0 && k.fract() == 0.0 => {
                                if k == -1.0 {
                                    "the power -1 of a matrix; write `inv(A)` for the inverse"
                                        .into()
                                } else {
                                    format!(
                                        "the power {} of a matrix; write `inv(A)^{}` for a power of the inverse",
                                        crate::num::Num(k),
                                        crate::num::Num(-k)
                                    )
                                }
                            }
                            Some(k) if k < 0.0 => {
                                format!("the power {} of a matrix", crate::num::Num(k))
                            }
                            Some(k) if k.fract() != 0.0 => {
                                format!("the non-integer power {} of a matrix", crate::num::Num(k))
                            }
                            Some(k) => format!(
                                "the power {} of a matrix, above the largest supported power 64 (use `expm`, or a product of powers)",
                                crate::num::Num(k)
                            ),
                        };
                        self.err(CheckError::Expected {
                            expected: "a constant integer power from 0 to 64 of a square matrix"
                                .into(),
                            found,
                            span,
                        });
                        None
                    }
                    _ => {
                        self.err(CheckError::ShapeMismatch {
                            op: "^ (scalars, or a square matrix to a constant integer power)"
                                .into(),
                            left: a.dims(),
                            right: b.dims(),
                            span,
                        });
                        None
                    }
                }
            }
        }
    }

    /// Resolves one index argument against a dimension of length `len`:
    /// the 0-based positions it selects.
    pub(crate) fn selection(&mut self, a: &IndexArg, len: usize) -> Option<Vec<usize>> {
        self.selection_known(a, len, None)
    }

    /// [`selection`](Self::selection) of an argument whose single index
    /// already has the constant value `known` (evaluated by the caller; an
    /// index is evaluated once, or nested indices `a[a[a[i]]]` cost
    /// 2^depth evaluations).
    fn selection_known(
        &mut self,
        a: &IndexArg,
        len: usize,
        known: Option<f64>,
    ) -> Option<Vec<usize>> {
        let check = |this: &mut Self, e: &Expr| -> Option<usize> {
            let i = match known {
                Some(x) => this.int_of(x, e, "an index")?,
                None => this.const_int(e, "an index")?,
            };
            if i < 1 || i as usize > len {
                this.err(CheckError::IndexOutOfRange {
                    index: i,
                    len,
                    span: e.span,
                });
                return None;
            }
            Some(i as usize - 1)
        };
        match a {
            IndexArg::All(_) => Some((0..len).collect()),
            IndexArg::One(e) => Some(vec![check(self, e)?]),
            IndexArg::Slice(lo, hi) => {
                let l = check(self, lo);
                let h = check(self, hi);
                let (l, h) = (l?, h?);
                Some((l..=h).collect())
            }
        }
    }

    /// Runs `f` with the path condition narrowed by `cond` (see
    /// [`Checker::path`]).
    fn under<T>(&mut self, cond: Option<NodeId>, f: impl FnOnce(&mut Self) -> T) -> T {
        let Some(c) = cond else { return f(self) };
        let outer = self.path;
        let c = match outer {
            Some(p) => self.dag.bin(BinFn::And, p, c),
            None => c,
        };
        self.path = Some(c);
        let r = f(self);
        self.path = outer;
        r
    }

    /// `v[args]` where an index may be a run-time expression of the
    /// context `ctx` (`tk[k]` with a state `k`): its entries are then
    /// looked up when evaluated, from `v`'s constant values (a parameter
    /// or table), checked to be an integer in range at run time (E0604).
    /// Constant indices take the constant path ([`index`](Self::index)).
    fn index_in(&mut self, v: &Val, args: &[IndexArg], span: Span, ctx: &Ctx) -> Option<Val> {
        let mut dynamic: Vec<Option<NodeId>> = Vec::with_capacity(args.len());
        // The value of each single index that is a constant scalar.
        let mut known: Vec<Option<f64>> = Vec::with_capacity(args.len());
        for a in args {
            let (mut node, mut value) = (None, None);
            if let IndexArg::One(e) = a {
                let i = self.expr(e, ctx)?;
                if i.is_scalar() {
                    value = self.dag.as_const(i.e[0]);
                    node = value.is_none().then_some(i.e[0]);
                }
            }
            dynamic.push(node);
            known.push(value);
        }
        if dynamic.iter().all(Option::is_none) {
            return self.index_known(v, args, span, &known);
        }
        let vector = v.cols == 1 || v.rows == 1;
        let (rows, cols) = match args.len() {
            1 if vector => (v.e.len(), 1),
            2 => (v.rows, v.cols),
            _ => return self.index_known(v, args, span, &known),
        };
        let Some(table) = self.dag.table(&v.e, rows, cols) else {
            let at = args
                .iter()
                .zip(&dynamic)
                .find_map(|(a, d)| match (a, d) {
                    (IndexArg::One(e), Some(_)) => Some(e.span),
                    _ => None,
                })
                .unwrap_or(span);
            self.err(CheckError::NotConstant {
                what: "an index into a vector or matrix that is not a parameter \
                       (run-time indices read parameters and tables)"
                    .into(),
                span: at,
            });
            return None;
        };
        // Each dimension: the run-time index node, or the constant selection.
        let mut sel: Vec<Result<NodeId, Vec<usize>>> = Vec::with_capacity(2);
        for (k, (a, d)) in args.iter().zip(&dynamic).enumerate() {
            let len = if k == 0 { rows } else { cols };
            sel.push(match d {
                Some(n) => Ok(*n),
                None => Err(self.selection_known(a, len, known[k])?),
            });
        }
        if sel.len() == 1 {
            sel.push(Err(vec![0]));
        }
        let origin = self.block_spans.len() as u32;
        self.block_spans.push(span);
        let picks = |s: &Result<NodeId, Vec<usize>>| match s {
            Ok(n) => vec![Ok(*n)],
            Err(ks) => ks.iter().map(|&k| Err(k)).collect(),
        };
        let (rsel, csel) = (picks(&sel[0]), picks(&sel[1]));
        let mut e = Vec::with_capacity(rsel.len() * csel.len());
        for r in &rsel {
            for c in &csel {
                let mut node = |x: &Result<NodeId, usize>| match *x {
                    Ok(n) => n,
                    Err(k) => self.dag.konst((k + 1) as f64),
                };
                let (r, c) = (node(r), node(c));
                let when = match self.path {
                    Some(p) => p,
                    None => self.dag.konst(1.0),
                };
                // At least one index is not a constant: nothing to fold.
                let n = self
                    .dag
                    .lookup(table, r, c, origin, when)
                    .unwrap_or_else(|_| unreachable!("a run-time index is not folded"));
                e.push(n);
            }
        }
        // One index: a scalar; two: rows × columns selected.
        let (out_rows, out_cols) = (rsel.len(), csel.len());
        Some(Val {
            rows: out_rows,
            cols: out_cols,
            e: e.into(),
            boolean: v.boolean,
        })
    }

    /// `interp(xs, ys, x)`: piecewise-linear interpolation through the
    /// points (xs[k], ys[k]) (constant vectors of one length, xs strictly
    /// increasing), clamped to the end values outside [xs[1], xs[n]];
    /// elementwise in x.
    fn interp_call(&mut self, args: &[Expr], ctx: &Ctx) -> Option<Val> {
        let xs = self.expr(&args[0], ctx);
        let ys = self.expr(&args[1], ctx);
        let x = self.expr(&args[2], ctx);
        let (xs, ys, x) = (xs?, ys?, x?);
        let mut ok = true;
        let mut points = Vec::with_capacity(2);
        for (v, e, what) in [(&xs, &args[0], "xs"), (&ys, &args[1], "ys")] {
            if (v.cols != 1 && v.rows != 1) || v.e.is_empty() {
                self.err(CheckError::Expected {
                    expected: format!("a vector for `interp`'s {what}"),
                    found: dims_words(v.dims()),
                    span: e.span,
                });
                ok = false;
                continue;
            }
            match v
                .e
                .iter()
                .map(|&n| self.dag.as_const(n))
                .collect::<Option<Vec<f64>>>()
            {
                Some(vals) => points.push(vals),
                None => {
                    self.err(CheckError::NotConstant {
                        what: format!("`interp`'s {what}"),
                        span: e.span,
                    });
                    ok = false;
                }
            }
        }
        if !ok {
            return None;
        }
        let (px, py) = (&points[0], &points[1]);
        if px.len() != py.len() {
            self.err(CheckError::ShapeMismatch {
                op: "interp(xs, ys, x) (xs and ys of one length)".into(),
                left: xs.dims(),
                right: ys.dims(),
                span: args[1].span,
            });
            return None;
        }
        if let Some(k) = px.iter().position(|v| !v.is_finite()) {
            self.err(CheckError::Expected {
                expected: "finite abscissae for `interp`".into(),
                found: format!("xs[{}] = {}", k + 1, px[k]),
                span: args[0].span,
            });
            return None;
        }
        if let Some(k) = px.windows(2).position(|w| w[1] <= w[0]) {
            self.err(CheckError::Expected {
                expected: "strictly increasing abscissae for `interp`".into(),
                found: format!(
                    "xs[{}] = {} after xs[{}] = {}",
                    k + 2,
                    px[k + 1],
                    k + 1,
                    px[k]
                ),
                span: args[0].span,
            });
            return None;
        }
        // Row 0 the abscissae, row 1 the ordinates.
        let mut entries: Vec<NodeId> = xs.e.to_vec();
        entries.extend_from_slice(&ys.e);
        let table = self
            .dag
            .table(&entries, 2, px.len())
            .expect("constant entries");
        let e =
            x.e.iter()
                .map(|&n| self.dag.interp(table, n, false))
                .collect();
        Some(Val {
            rows: x.rows,
            cols: x.cols,
            e,
            boolean: false,
        })
    }

    pub(crate) fn index(&mut self, v: &Val, args: &[IndexArg], span: Span) -> Option<Val> {
        self.index_known(v, args, span, &[])
    }

    /// [`index`](Self::index) with the constant values of the indices the
    /// caller has evaluated already (`known[k]` for `args[k]`; missing or
    /// `None`: evaluated here).
    fn index_known(
        &mut self,
        v: &Val,
        args: &[IndexArg],
        span: Span,
        known: &[Option<f64>],
    ) -> Option<Val> {
        let known = |k: usize| known.get(k).copied().flatten();
        match args.len() {
            1 if v.cols == 1 || v.rows == 1 => {
                let len = v.e.len();
                let sel = self.selection_known(&args[0], len, known(0))?;
                let e: Vec<NodeId> = sel.iter().map(|&k| v.e[k]).collect();
                let n = e.len();
                let (rows, cols) = if v.cols == 1 { (n, 1) } else { (1, n) };
                Some(Val {
                    rows,
                    cols,
                    e: e.into(),
                    boolean: v.boolean,
                })
            }
            2 => {
                let rs = self.selection_known(&args[0], v.rows, known(0));
                let cs = self.selection_known(&args[1], v.cols, known(1));
                let (rs, cs) = (rs?, cs?);
                let mut e = Vec::with_capacity(rs.len() * cs.len());
                for &r in &rs {
                    for &c in &cs {
                        e.push(v.at(r, c));
                    }
                }
                Some(Val {
                    rows: rs.len(),
                    cols: cs.len(),
                    e: e.into(),
                    boolean: v.boolean,
                })
            }
            n => {
                self.err(CheckError::Expected {
                    expected: if v.cols == 1 || v.rows == 1 {
                        "one index for a vector (or two)".into()
                    } else {
                        "two indices `[row, col]` for a matrix".into()
                    },
                    found: format!("{n} indices"),
                    span,
                });
                None
            }
        }
    }

    fn call(
        &mut self,
        name: &str,
        name_span: Span,
        args: &[Expr],
        span: Span,
        ctx: &Ctx,
    ) -> Option<Val> {
        let arity = |this: &mut Self, ok: bool, expected: &str| -> Option<()> {
            if ok {
                Some(())
            } else {
                this.err(CheckError::Arity {
                    func: name.to_string(),
                    expected: expected.to_string(),
                    found: args.len(),
                    span,
                });
                None
            }
        };
        if self.is_reduction_call(name) {
            return self.reduction_call(name, args, span);
        }
        let n = args.len();
        let elementwise = |f: UnFn| Some(f);
        let un = match name {
            "abs" => elementwise(UnFn::Abs),
            "sqrt" => elementwise(UnFn::Sqrt),
            "exp" => elementwise(UnFn::Exp),
            "log" => elementwise(UnFn::Log),
            "sin" => elementwise(UnFn::Sin),
            "cos" => elementwise(UnFn::Cos),
            "tan" => elementwise(UnFn::Tan),
            "atan" => elementwise(UnFn::Atan),
            "tanh" => elementwise(UnFn::Tanh),
            "asin" => elementwise(UnFn::Asin),
            "acos" => elementwise(UnFn::Acos),
            "sinh" => elementwise(UnFn::Sinh),
            "cosh" => elementwise(UnFn::Cosh),
            "sign" => elementwise(UnFn::Sign),
            "floor" => elementwise(UnFn::Floor),
            "ceil" => elementwise(UnFn::Ceil),
            "round" => elementwise(UnFn::Round),
            _ => None,
        };
        if let Some(f) = un {
            arity(self, n == 1, "1 argument")?;
            let v = self.expr(&args[0], ctx)?;
            return Some(self.map(&v, f));
        }
        match name {
            "eye" | "zeros" | "ones" => {
                arity(self, n == 1 || n == 2, "1 or 2 arguments")?;
                let r = self.const_int(&args[0], "a dimension");
                let c = match args.get(1) {
                    Some(a) => self.const_int(a, "a dimension"),
                    None if name == "eye" => r,
                    None => Some(1),
                };
                let (r, c) = (r?, c?);
                if r < 0 || c < 0 {
                    self.err(CheckError::Expected {
                        expected: "dimensions of at least 0".into(),
                        found: format!("{r}×{c}"),
                        span,
                    });
                    return None;
                }
                if !self.within_limit(Quantity::Elements, r as f64 * c as f64, span) {
                    return None;
                }
                let (r, c) = (r as usize, c as usize);
                Some(match name {
                    "eye" => self.konst_val(r, c, |i, j| if i == j { 1.0 } else { 0.0 }),
                    "zeros" => self.konst_val(r, c, |_, _| 0.0),
                    _ => self.konst_val(r, c, |_, _| 1.0),
                })
            }
            "rows" | "cols" | "length" => {
                arity(self, n == 1, "1 argument")?;
                let v = self.expr(&args[0], ctx)?;
                let x = match name {
                    "rows" => v.rows,
                    "cols" => v.cols,
                    _ => v.rows.max(v.cols),
                };
                Some(Val::scalar(self.dag.konst(x as f64)))
            }
            "diag" => {
                arity(self, n == 1, "1 argument")?;
                let v = self.expr(&args[0], ctx)?;
                if v.rows == 1 || v.cols == 1 {
                    let k = v.e.len();
                    if !self.within_budget(k as u64 * k as u64, span)
                        || !self.within_memory(Quantity::Elements, k as f64 * k as f64, span)
                    {
                        return None;
                    }
                    let zero = self.dag.konst(0.0);
                    let mut e = vec![zero; k * k];
                    for i in 0..k {
                        e[i * k + i] = v.e[i];
                    }
                    Some(Val {
                        rows: k,
                        cols: k,
                        e: e.into(),
                        boolean: false,
                    })
                } else if v.rows == v.cols {
                    let e = (0..v.rows).map(|i| v.at(i, i)).collect();
                    Some(Val {
                        rows: v.rows,
                        cols: 1,
                        e,
                        boolean: false,
                    })
                } else {
                    self.expected(&args[0], "a vector or a square matrix", &v)
                }
            }
            "blkdiag" => {
                arity(self, n >= 1, "at least 1 argument")?;
                let vs: Option<Vec<Val>> = args.iter().map(|a| self.expr(a, ctx)).collect();
                let vs = vs?;
                let rows: usize = vs.iter().map(|v| v.rows).sum();
                let cols: usize = vs.iter().map(|v| v.cols).sum();
                if !self.within_budget(rows as u64 * cols as u64, span)
                    || !self.within_memory(Quantity::Elements, rows as f64 * cols as f64, span)
                {
                    return None;
                }
                let zero = self.dag.konst(0.0);
                let mut e = vec![zero; rows * cols];
                let (mut r0, mut c0) = (0, 0);
                for v in &vs {
                    for i in 0..v.rows {
                        for j in 0..v.cols {
                            e[(r0 + i) * cols + c0 + j] = v.at(i, j);
                        }
                    }
                    r0 += v.rows;
                    c0 += v.cols;
                }
                Some(Val {
                    rows,
                    cols,
                    e: e.into(),
                    boolean: false,
                })
            }
            "kron" => {
                arity(self, n == 2, "2 arguments")?;
                let a = self.expr(&args[0], ctx);
                let b = self.expr(&args[1], ctx);
                let (a, b) = (a?, b?);
                let (rows, cols) = (a.rows * b.rows, a.cols * b.cols);
                if !self.within_budget(rows as u64 * cols as u64, span)
                    || !self.within_memory(Quantity::Elements, rows as f64 * cols as f64, span)
                {
                    return None;
                }
                let mut e = Vec::with_capacity(rows * cols);
                for i in 0..rows {
                    for j in 0..cols {
                        let x = a.at(i / b.rows, j / b.cols);
                        let y = b.at(i % b.rows, j % b.cols);
                        e.push(self.dag.bin(BinFn::Mul, x, y));
                    }
                }
                Some(Val {
                    rows,
                    cols,
                    e: e.into(),
                    boolean: false,
                })
            }
            "trace" => {
                arity(self, n == 1, "1 argument")?;
                let v = self.expr(&args[0], ctx)?;
                if v.rows != v.cols {
                    return self.expected(&args[0], "a square matrix", &v);
                }
                let mut acc = self.dag.konst(0.0);
                for i in 0..v.rows {
                    acc = self.dag.bin(BinFn::Add, acc, v.at(i, i));
                }
                Some(Val::scalar(acc))
            }
            "norm" => {
                arity(self, n == 1, "1 argument")?;
                let v = self.expr(&args[0], ctx)?;
                if v.rows == 1 || v.cols == 1 {
                    let mut acc = self.dag.konst(0.0);
                    for &x in &v.e {
                        let sq = self.dag.bin(BinFn::Mul, x, x);
                        acc = self.dag.bin(BinFn::Add, acc, sq);
                    }
                    Some(Val::scalar(self.dag.un(UnFn::Sqrt, acc)))
                } else {
                    let kind = BlockKind::Norm2 {
                        r: v.rows as u32,
                        c: v.cols as u32,
                    };
                    self.block(kind, v.e.to_vec(), name, span, 1, 1)
                }
            }
            "inv" | "expm" => {
                arity(self, n == 1, "1 argument")?;
                let v = self.expr(&args[0], ctx)?;
                if v.rows != v.cols {
                    return self.expected(&args[0], "a square matrix", &v);
                }
                let k = v.rows as u32;
                let kind = if name == "inv" {
                    BlockKind::Inv { n: k }
                } else {
                    BlockKind::Expm { n: k }
                };
                if name == "inv" && v.rows == 1 {
                    let one = self.dag.konst(1.0);
                    return Some(Val::scalar(self.dag.bin(BinFn::Div, one, v.e[0])));
                }
                self.block(kind, v.e.to_vec(), name, span, v.rows, v.cols)
            }
            "solve" => {
                arity(self, n == 2, "2 arguments")?;
                let a = self.expr(&args[0], ctx);
                let b = self.expr(&args[1], ctx);
                let (a, b) = (a?, b?);
                if a.rows != a.cols {
                    return self.expected(&args[0], "a square matrix", &a);
                }
                if b.rows != a.rows {
                    self.err(CheckError::ShapeMismatch {
                        op: "solve".into(),
                        left: a.dims(),
                        right: b.dims(),
                        span,
                    });
                    return None;
                }
                let kind = BlockKind::Solve {
                    n: a.rows as u32,
                    m: b.cols as u32,
                };
                let mut inputs = a.e.to_vec();
                inputs.extend_from_slice(&b.e);
                self.block(kind, inputs, name, span, b.rows, b.cols)
            }
            "min" | "max" => {
                let f = if name == "min" {
                    BinFn::Min
                } else {
                    BinFn::Max
                };
                arity(self, n == 1 || n == 2, "1 or 2 arguments")?;
                if n == 1 {
                    let v = self.expr(&args[0], ctx)?;
                    let Some((&first, rest)) = v.e.split_first() else {
                        return self.expected(&args[0], "a non-empty matrix", &v);
                    };
                    let mut acc = first;
                    for &x in rest {
                        acc = self.dag.bin(f, acc, x);
                    }
                    return Some(Val::scalar(acc));
                }
                let a = self.expr(&args[0], ctx);
                let b = self.expr(&args[1], ctx);
                let (a, b) = self.broadcast(a?, b?, name, span)?;
                Some(self.zip(&a, &b, f))
            }
            "frac" => {
                // frac(x) = x − ⌊x⌋ ∈ [0, 1): the floored `mod(x, 1)`.
                arity(self, n == 1, "1 argument")?;
                let v = self.expr(&args[0], ctx)?;
                let one = self.dag.konst(1.0);
                let e =
                    v.e.iter()
                        .map(|&x| self.dag.bin(BinFn::Mod, x, one))
                        .collect();
                Some(Val {
                    e,
                    boolean: false,
                    ..v
                })
            }
            "interp" => {
                arity(self, n == 3, "3 arguments")?;
                self.interp_call(args, ctx)
            }
            "clamp" => {
                // clamp(x, lo, hi) = min(max(x, lo), hi), elementwise with
                // broadcasting; never fails, even for lo > hi (then hi).
                arity(self, n == 3, "3 arguments")?;
                let x = self.expr(&args[0], ctx);
                let lo = self.expr(&args[1], ctx);
                let hi = self.expr(&args[2], ctx);
                let (x, lo) = self.broadcast(x?, lo?, name, span)?;
                let low = self.zip(&x, &lo, BinFn::Max);
                let (low, hi) = self.broadcast(low, hi?, name, span)?;
                Some(self.zip(&low, &hi, BinFn::Min))
            }
            "atan2" | "mod" | "rem" | "hypot" => {
                arity(self, n == 2, "2 arguments")?;
                let f = match name {
                    "mod" => BinFn::Mod,
                    "rem" => BinFn::Rem,
                    "hypot" => BinFn::Hypot,
                    _ => BinFn::Atan2,
                };
                let a = self.expr(&args[0], ctx);
                let b = self.expr(&args[1], ctx);
                let (a, b) = self.broadcast(a?, b?, name, span)?;
                Some(self.zip(&a, &b, f))
            }
            "uniform" | "normal" | "bernoulli" => {
                if !ctx.random {
                    self.err(CheckError::RandomNotAllowed {
                        place: ctx.place.to_string(),
                        span,
                    });
                    return None;
                }
                let (dist, want) = match name {
                    "uniform" => (Dist::Uniform, 2),
                    "normal" => (Dist::Normal, 2),
                    _ => (Dist::Bernoulli, 1),
                };
                arity(
                    self,
                    n == want,
                    if want == 2 {
                        "2 arguments"
                    } else {
                        "1 argument"
                    },
                )?;
                let a = self.expr(&args[0], ctx);
                let b = match args.get(1) {
                    Some(x) => self.expr(x, ctx),
                    None => Some(Val::scalar(self.dag.konst(0.0))),
                };
                let (a, b) = self.broadcast(a?, b?, name, span)?;
                // Parameters known now must make a distribution (those that
                // vary are the model's to keep in range).
                for (&x, &y) in a.e.iter().zip(&b.e) {
                    let (Some(x), Some(y)) = (self.dag.as_const(x), self.dag.as_const(y)) else {
                        continue;
                    };
                    let wrong = match dist {
                        Dist::Uniform => (!(x.is_finite() && y.is_finite() && x <= y))
                            .then(|| ("finite bounds lo ≤ hi in uniform(lo, hi)", format!("uniform({x}, {y})"))),
                        Dist::Normal => (!(x.is_finite() && y.is_finite() && y >= 0.0))
                            .then(|| ("a finite mean and a standard deviation ≥ 0 in normal(mean, std)", format!("normal({x}, {y})"))),
                        Dist::Bernoulli => (!(0.0..=1.0).contains(&x))
                            .then(|| ("a probability in [0, 1] in bernoulli(p)", format!("bernoulli({x})"))),
                    };
                    if let Some((expected, found)) = wrong {
                        self.err(CheckError::Expected {
                            expected: expected.into(),
                            found,
                            span,
                        });
                        return None;
                    }
                }
                let e =
                    a.e.iter()
                        .zip(&b.e)
                        .map(|(&x, &y)| self.dag.rand(dist, x, y))
                        .collect();
                Some(Val {
                    rows: a.rows,
                    cols: a.cols,
                    e,
                    boolean: dist == Dist::Bernoulli,
                })
            }
            "dare" | "care" | "are" | "dlqr" | "lqr" | "c2d" => self.control(name, args, span),
            "post" => self.post_call(args, span, ctx),
            "wiener" => {
                self.err(CheckError::Expected {
                    expected: "`wiener(m)` only in `noise w ~ wiener(m)`".into(),
                    found: "a call".into(),
                    span,
                });
                None
            }
            _ if self.syms.contains_key(name)
                || self.scope_lookup(name).is_some()
                || matches!(name, "t" | "j" | "pi") =>
            {
                self.err(CheckError::NotAFunction {
                    name: name.to_string(),
                    span,
                });
                None
            }
            _ => {
                // In a metric, a misnamed reduction is likelier than a misnamed function.
                let suggestion = self
                    .metric_frame
                    .as_ref()
                    .and_then(|_| super::metric::ReductionKind::meant(name))
                    .or_else(|| suggest(name, BUILTINS.iter().copied()));
                self.err(CheckError::UnknownFunction {
                    name: name.to_string(),
                    span: name_span,
                    suggestion,
                    foreign: foreign_function(name),
                });
                None
            }
        }
    }

    fn expected(&mut self, e: &Expr, what: &str, v: &Val) -> Option<Val> {
        self.err(CheckError::Expected {
            expected: what.to_string(),
            found: dims_words(v.dims()),
            span: e.span,
        });
        None
    }

    fn block(
        &mut self,
        kind: BlockKind,
        inputs: Vec<NodeId>,
        func: &str,
        span: Span,
        rows: usize,
        cols: usize,
    ) -> Option<Val> {
        let origin = self.block_spans.len() as u32;
        self.block_spans.push(span);
        // A constant NaN or infinity makes the operation undefined too; say so, not "singular".
        let non_finite = inputs
            .iter()
            .any(|&i| self.dag.as_const(i).is_some_and(|v| !v.is_finite()));
        // Only `inv` and `solve` fail on a singular matrix; `expm` and `norm`
        // of finite entries fail where the result overflows.
        let singular = matches!(kind, BlockKind::Inv { .. } | BlockKind::Solve { .. });
        match self.dag.add_block(kind, inputs, origin) {
            Ok(e) => Some(Val {
                rows,
                cols,
                e: e.into(),
                boolean: false,
            }),
            Err(_) => {
                self.err(CheckError::Compute {
                    func: func.to_string(),
                    reason: if non_finite {
                        "the matrix has a non-finite entry (NaN or infinity)".into()
                    } else if singular {
                        "the matrix is singular".into()
                    } else {
                        "the result overflows (an entry beyond the range of a 64-bit float)".into()
                    },
                    span,
                });
                None
            }
        }
    }
}

impl Checker {
    /// Control-design functions on constant matrices (`design::control`),
    /// all results: `dare`/`care` → (P), `are` → (X), `dlqr`/`lqr` → (K, P),
    /// `c2d` → (Ad, Bd).
    pub(crate) fn control_multi(
        &mut self,
        name: &str,
        args: &[Expr],
        span: Span,
    ) -> Option<Vec<Val>> {
        use crate::design::control;
        let want = if matches!(name, "c2d" | "are") { 3 } else { 4 };
        if args.len() != want {
            self.err(CheckError::Arity {
                func: name.to_string(),
                expected: format!("{want} arguments"),
                found: args.len(),
                span,
            });
            return None;
        }
        let mut mats = Vec::new();
        let mut ok = true;
        for a in args {
            match self.const_matrix(a, &format!("an argument of `{name}`")) {
                Some((v, x)) => mats.push(nalgebra::DMatrix::from_row_slice(v.rows, v.cols, &x)),
                None => ok = false,
            }
        }
        if !ok {
            return None;
        }
        let result = match name {
            "dare" => control::dare(&mats[0], &mats[1], &mats[2], &mats[3]).map(|p| vec![p]),
            "care" => control::care(&mats[0], &mats[1], &mats[2], &mats[3]).map(|p| vec![p]),
            "are" => control::are(&mats[0], &mats[1], &mats[2]).map(|x| vec![x]),
            "dlqr" => control::dlqr(&mats[0], &mats[1], &mats[2], &mats[3]).map(|l| vec![l.k, l.p]),
            "lqr" => control::lqr(&mats[0], &mats[1], &mats[2], &mats[3]).map(|l| vec![l.k, l.p]),
            _ => {
                if mats[2].len() != 1 {
                    self.err(CheckError::Expected {
                        expected: "a scalar sampling time".into(),
                        found: dims_words((mats[2].nrows(), mats[2].ncols())),
                        span: args[2].span,
                    });
                    return None;
                }
                control::c2d(&mats[0], &mats[1], mats[2][(0, 0)]).map(|(a, b)| vec![a, b])
            }
        };
        match result {
            Ok(ms) => Some(
                ms.iter()
                    .map(|m| self.konst_val(m.nrows(), m.ncols(), |i, j| m[(i, j)]))
                    .collect(),
            ),
            Err(e) => {
                self.err(CheckError::Compute {
                    func: name.to_string(),
                    reason: e.to_string(),
                    span,
                });
                None
            }
        }
    }

    /// A control function in an expression: its first result, except
    /// `c2d`, whose two results must be named.
    fn control(&mut self, name: &str, args: &[Expr], span: Span) -> Option<Val> {
        if name == "c2d" {
            self.err(CheckError::Expected {
                expected: "`param (Ad, Bd) = c2d(A, B, Ts)`".into(),
                found: "`c2d` inside an expression".into(),
                span,
            });
            return None;
        }
        self.control_multi(name, args, span)?.into_iter().next()
    }
}

/// Context for constants (parameters, indices, settings).
pub(crate) const CONST_CTX: Ctx = Ctx {
    random: false,
    wiener: false,
    place: "a parameter",
};

/// A family member's key as written in its name: `2`, `1,3`.
/// A family's members in words, from their index labels (`2`, `1,3`): each
/// up to six, else the first, the last and their number.
pub(crate) fn members_words(labels: &[String]) -> String {
    let show = |l: &String| format!("[{l}]");
    match labels.len() {
        0 => "none".into(),
        n if n <= 6 => labels.iter().map(show).collect::<Vec<_>>().join(", "),
        n => format!(
            "{} … {} ({n} members)",
            show(&labels[0]),
            show(&labels[n - 1])
        ),
    }
}

pub(crate) fn key_label(key: &[i64]) -> String {
    key.iter()
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

pub(crate) fn dims_words(d: Dims) -> String {
    match d {
        (1, 1) => "a scalar".into(),
        (r, 1) => format!("a {r}×1 vector"),
        (r, c) => format!("a {r}×{c} matrix"),
    }
}

fn transpose(v: &Val) -> Val {
    let mut e = Vec::with_capacity(v.e.len());
    for c in 0..v.cols {
        for r in 0..v.rows {
            e.push(v.at(r, c));
        }
    }
    Val {
        rows: v.cols,
        cols: v.rows,
        e: e.into(),
        boolean: v.boolean,
    }
}

/// Blocks of equal height side by side (`cols` their total width); `None` for no block. One block is
/// returned as it is (a lone condition stays a condition).
fn side_by_side(mut blocks: Vec<Val>, cols: usize) -> Option<Val> {
    if blocks.len() <= 1 {
        return blocks.pop();
    }
    let rows = blocks[0].rows;
    let mut e = Elems::with_capacity(rows * cols);
    for r in 0..rows {
        for b in &blocks {
            e.extend_from_slice(&b.e[r * b.cols..(r + 1) * b.cols]);
        }
    }
    let boolean = blocks.iter().all(|b| b.boolean);
    Some(Val {
        rows,
        cols,
        e,
        boolean,
    })
}

fn identity(c: &mut Checker, n: usize) -> Val {
    c.konst_val(n, n, |i, j| if i == j { 1.0 } else { 0.0 })
}

/// The closest candidate to `name` (Jaro–Winkler ≥ 0.8; the last of equally close ones), if any.
pub(crate) fn suggest<S: AsRef<str>>(
    name: &str,
    candidates: impl IntoIterator<Item = S>,
) -> Option<String> {
    let mut best: Option<(f64, S)> = None;
    for c in candidates {
        let s = c.as_ref();
        if s == name {
            continue;
        }
        let score = strsim::jaro_winkler(name, s);
        if score >= 0.8 && best.as_ref().is_none_or(|(b, _)| score >= *b) {
            best = Some((score, c));
        }
    }
    best.map(|(_, c)| c.as_ref().to_string())
}

/// The name comparisons the "did you mean" hints of one check may still make. A hint is a
/// convenience: 50 000 unknown names among 50 000 declared ones took 6 minutes of comparisons
/// (and of copying the names compared). Past the budget, errors come without a hint; each hint is
/// charged whole before its candidates are gathered, so which hints are given does not depend on
/// the order of a hash map.
#[derive(Debug, Clone)]
pub(crate) struct Hints {
    left: usize,
}

impl Hints {
    /// About 0.1 s of comparisons: thousands of hints in a model of thousands of names.
    pub(crate) const BUDGET: usize = 2_000_000;

    /// Charges a hint among `n` candidates; false (nothing charged) if it no longer fits.
    pub(crate) fn charge(&mut self, n: usize) -> bool {
        let fits = n <= self.left;
        if fits {
            self.left -= n;
        }
        fits
    }
}

impl Default for Hints {
    fn default() -> Self {
        Hints { left: Self::BUDGET }
    }
}
