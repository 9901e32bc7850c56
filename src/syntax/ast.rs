//! The abstract syntax tree of a `.hyb` model. Every node carries the
//! [`Span`] of its source text.

use crate::source::Span;

/// A name with its location.
#[derive(Debug, Clone, PartialEq)]
pub struct Ident {
    /// The name.
    pub name: String,
    /// Where it is written.
    pub span: Span,
}

/// A whole model: `model NAME` followed by items.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// The model's name.
    pub name: Ident,
    /// Items in source order.
    pub items: Vec<Item>,
}

/// One top-level declaration.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// `param a = 1, b = [1; 2]`.
    Param(Vec<Definition>),
    /// `param g ~ uniform(a, b)`: a random parameter (the value is the
    /// draw), sampled per run and per `hybsim test` case.
    RandomParam(Definition),
    /// `param (Ad, Bd) = c2d(A, B, Ts)`: several results of a control function.
    ParamTuple(Vec<Target>, Expr),
    /// `graph G = adjacency`: a square constant matrix used for neighbour sets.
    Graph(Definition),
    /// `state x = 0, P = eye(2), h ~ uniform(0, 1)`.
    State(Vec<StateDef>),
    /// `noise v ~ normal(0, s) every h` (held) or `noise w ~ wiener(2)` (white).
    Noise(NoiseDecl),
    /// `flow { x' = ... } in predicate`.
    Flow(FlowBlock),
    /// `jump name when predicate { x+ = ... }` or `jump name every Ts { ... }`.
    Jump(JumpDecl),
    /// `output e = x - xhat`.
    Output(Vec<Definition>),
    /// `sim { T = 10; J = 100; ... }`.
    Sim(Vec<Setting>),
    /// `for i in 1..N { items }`.
    For(Binder, Vec<Item>),
    /// `together { rules }`: jump rules (`Jump` items, possibly inside `For`
    /// items) whose enabled members fire as one jump. The span is the
    /// `together` word.
    Together(Vec<Item>, Span),
    /// `design name { ... }`: an LMI problem whose results become parameters.
    Design(DesignBlock),
    /// `property NAME: BODY`.
    Property(PropertyDecl),
    /// `metric rate = count(fire) / t`: scalar reductions of a run.
    Metric(Vec<Definition>),
    /// `sweep { delta in 0:5:80; runs = 20 }`: the grid and settings of
    /// `hybsim sweep`.
    Sweep(SweepBlock),
    /// `import "lib/zoh.hyb"`: the subsystems of another file.
    Import(Import),
    /// `param tk = table("timers.csv")`: a constant matrix from a CSV file.
    Table(TableParam),
    /// `subsystem Name(params) { items }`: a reusable hybrid system.
    Subsystem(SubsystemDecl),
    /// `input u, w = 0` (in a subsystem): values the instance receives.
    Input(Vec<InputDef>),
    /// `ball = Ball(lambda = 0.8, u = plat.y)`: an instance of a subsystem.
    Instance(InstanceDecl),
    /// Produced by elaboration, never parsed: an instance's input as a
    /// named value (an output that is not logged).
    Signal(Definition),
    /// Produced by elaboration, never parsed: the items of one subsystem
    /// instance (the target names it, `node[i]`), whose jump rules are
    /// one part of the composite jump (see `check::compose`).
    Part(Target, Vec<Item>),
    /// `log { vars = [..]; rules = [..]; every = N; dt = DT }`: what
    /// `hybsim run` logs.
    Log(LogBlock),
}

/// `param NAME = table("path")`.
#[derive(Debug, Clone, PartialEq)]
pub struct TableParam {
    /// The parameter.
    pub name: Ident,
    /// The path as written (between the quotes).
    pub path: String,
    /// The string literal.
    pub path_span: Span,
    /// The call `table("path")`.
    pub span: Span,
    /// The file the path names, once [`crate::tables::resolve`] has checked
    /// it against the path rules of `import` (`None` before).
    pub file: Option<std::path::PathBuf>,
}

/// `import "path"`.
#[derive(Debug, Clone, PartialEq)]
pub struct Import {
    /// The path as written (between the quotes).
    pub path: String,
    /// The string literal.
    pub span: Span,
}

/// `subsystem Name(p = default, q) { items }`.
#[derive(Debug, Clone, PartialEq)]
pub struct SubsystemDecl {
    /// Its name.
    pub name: Ident,
    /// Parameters in order, each with its default value if any.
    pub params: Vec<(Ident, Option<Expr>)>,
    /// The body: parameters, inputs, states, noise, flows, jumps, outputs,
    /// loops and nested instances.
    pub items: Vec<Item>,
}

/// One input of a subsystem, with its value when left unconnected.
#[derive(Debug, Clone, PartialEq)]
pub struct InputDef {
    /// The input's name.
    pub target: Target,
    /// `= value` when not connected.
    pub default: Option<Expr>,
}

/// `name = Subsystem(arg = value, ...)`.
#[derive(Debug, Clone, PartialEq)]
pub struct InstanceDecl {
    /// The instance's name (`ball`, `node[i]`).
    pub target: Target,
    /// The subsystem instantiated.
    pub subsystem: Ident,
    /// Parameter values and input connections, by name.
    pub args: Vec<(Ident, Expr)>,
    /// The whole declaration.
    pub span: Span,
}

/// `log { vars = [xh, err]; rules = [event, v.redraw]; every = 10 }`.
#[derive(Debug, Clone, PartialEq)]
pub struct LogBlock {
    /// `KEY = [names]` lists (`vars`, `rules`), in order.
    pub lists: Vec<(Ident, Vec<LogName>)>,
    /// `KEY = value` settings (`every`, `dt`).
    pub settings: Vec<Setting>,
    /// The `log` word.
    pub span: Span,
}

/// A name in a `log` list: `xh`, `xh[2]`, `e[1, 3]`, `v.redraw`.
#[derive(Debug, Clone, PartialEq)]
pub struct LogName {
    /// The name and its family index, if any.
    pub target: Target,
    /// The part after a dot (`redraw` in `v.redraw`).
    pub suffix: Option<Ident>,
    /// The whole name.
    pub span: Span,
}

/// `sweep { NAME in VALUES; …; runs = N; seed = S }`.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepBlock {
    /// The axes in order (the first varies slowest).
    pub axes: Vec<SweepAxis>,
    /// `key = value` settings (`runs`, `seed`).
    pub settings: Vec<Setting>,
    /// The `sweep` word.
    pub span: Span,
}

/// `NAME in a:step:b` or `NAME in VALUES` in a `sweep` block.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepAxis {
    /// The parameter, initial value or `sim` key swept.
    pub name: Ident,
    /// Its values.
    pub values: AxisValues,
}

/// The values of a sweep axis.
#[derive(Debug, Clone, PartialEq)]
pub enum AxisValues {
    /// `start:step:stop` (inclusive).
    Range(Expr, Expr, Expr),
    /// A constant scalar (one value) or vector (its elements).
    List(Expr),
}

/// A declared or assigned name with optional index lists: `x`, `x[i]`,
/// `m[i, k]`, `x[i][2]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    /// The name.
    pub name: Ident,
    /// Index lists in order.
    pub indices: Vec<Vec<IndexArg>>,
    /// The whole target.
    pub span: Span,
}

/// `target = expr`.
#[derive(Debug, Clone, PartialEq)]
pub struct Definition {
    /// Left-hand side.
    pub target: Target,
    /// Right-hand side.
    pub value: Expr,
}

/// One state declaration.
#[derive(Debug, Clone, PartialEq)]
pub struct StateDef {
    /// The state (indexed for families).
    pub target: Target,
    /// Its initial value; `None` is an error reported by the checker.
    pub init: Option<Expr>,
}

/// A noise signal declaration.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseDecl {
    /// Its name.
    pub target: Target,
    /// The distribution (`normal(..)`, `uniform(..)`, `wiener(m)`).
    pub dist: Expr,
    /// The hold period for held noise.
    pub every: Option<Expr>,
    /// The whole declaration.
    pub span: Span,
}

/// Statements of a flow block.
#[derive(Debug, Clone, PartialEq)]
pub enum FlowStmt {
    /// `x' = expr`.
    Eq(Definition),
    /// `for i in S { ... }`.
    For(Binder, Vec<FlowStmt>),
}

/// A flow block.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowBlock {
    /// Derivative equations.
    pub stmts: Vec<FlowStmt>,
    /// The flow set predicate (`in ...`); the whole space if absent.
    pub set: Option<Expr>,
    /// The `flow` keyword.
    pub span: Span,
}

/// When a jump rule fires.
#[derive(Debug, Clone, PartialEq)]
pub enum Trigger {
    /// `when predicate`.
    When(Expr),
    /// `every period`: a timer.
    Every(Expr),
}

/// Statements of a reset block.
#[derive(Debug, Clone, PartialEq)]
pub enum ResetStmt {
    /// `x+ = expr`.
    Eq(Definition),
    /// `for i in S { ... }`.
    For(Binder, Vec<ResetStmt>),
}

/// A jump rule.
#[derive(Debug, Clone, PartialEq)]
pub struct JumpDecl {
    /// Rule name (`None` for a bare `every Ts { }` or a `jump` without one).
    pub name: Option<Target>,
    /// Guard.
    pub trigger: Trigger,
    /// Resets.
    pub resets: Vec<ResetStmt>,
    /// The `jump`/`every` keyword up to the guard.
    pub span: Span,
}

/// `key = value` in a `sim` block.
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    /// The key.
    pub key: Ident,
    /// The value.
    pub value: Expr,
    /// The value exactly, when it is written as a whole number that fits 64
    /// bits: a `seed` above 2^53 has no exact `f64`.
    pub integer: Option<u64>,
}

/// `text` as a whole number written in digits alone, exactly (`None` for
/// anything else: `1e3`, `2^60`, a number above 2^64 − 1).
pub fn integer_literal(text: &str) -> Option<u64> {
    let text = text.trim();
    (!text.is_empty() && text.bytes().all(|b| b.is_ascii_digit()))
        .then(|| text.parse().ok())
        .flatten()
}

/// The index variables, set and filter of `for`/`sum`.
#[derive(Debug, Clone, PartialEq)]
pub struct Binder {
    /// One variable, or two for `edges(G)`.
    pub vars: Vec<Ident>,
    /// The index set.
    pub set: IndexSet,
    /// `if predicate`: keep only members satisfying it.
    pub filter: Option<Expr>,
    /// The whole binder.
    pub span: Span,
}

/// An index set.
#[derive(Debug, Clone, PartialEq)]
pub enum IndexSet {
    /// `a..b` (inclusive).
    Range(Expr, Expr),
    /// `in(G, i)`: the in-neighbours k of i (`G[i, k] != 0`).
    In(Expr, Expr),
    /// `out(G, i)`: the out-neighbours k of i (`G[k, i] != 0`).
    Out(Expr, Expr),
    /// `edges(G)`: pairs (i, k) with `G[i, k] != 0`.
    Edges(Expr),
    /// `subsets(S)`: every subset of S, including ∅ and S (design loops only).
    Subsets(Box<IndexSet>),
    /// A set bound by `for S in subsets(..)`.
    Named(Ident),
}

/// An index argument: `e`, `a:b` or `:`.
#[derive(Debug, Clone, PartialEq)]
pub enum IndexArg {
    /// One index.
    One(Expr),
    /// An inclusive range.
    Slice(Expr, Expr),
    /// All.
    All(Span),
}

pub use super::design::{
    Constraint, DesignBlock, DesignStmt, LmiSide, Rel, Sense, VarDecl, VarShape,
};

/// An expression.
#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    /// What it is.
    pub kind: ExprKind,
    /// Where.
    pub span: Span,
}

/// Unary operators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UnOp {
    /// `-a`.
    Neg,
    /// `!a`.
    Not,
    /// `a'`.
    Transpose,
}

/// Binary operators.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinOp {
    /// `+`
    Add,
    /// `-`
    Sub,
    /// `*` (matrix product, or scaling)
    Mul,
    /// `/` (by a scalar)
    Div,
    /// `.*`
    ElemMul,
    /// `./`
    ElemDiv,
    /// `^` (scalars)
    Pow,
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
    /// `==`
    Eq,
    /// `!=`
    Ne,
    /// `&&`
    And,
    /// `||`
    Or,
}

impl BinOp {
    /// The operator as written.
    pub fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
            BinOp::ElemMul => ".*",
            BinOp::ElemDiv => "./",
            BinOp::Pow => "^",
            BinOp::Lt => "<",
            BinOp::Le => "<=",
            BinOp::Gt => ">",
            BinOp::Ge => ">=",
            BinOp::Eq => "==",
            BinOp::Ne => "!=",
            BinOp::And => "&&",
            BinOp::Or => "||",
        }
    }
}

/// Expression forms.
#[derive(Debug, Clone, PartialEq)]
pub enum ExprKind {
    /// A number literal.
    Num(f64),
    /// `true` / `false`.
    Bool(bool),
    /// A name.
    Name(String),
    /// `[a, b; c, d]`: rows of blocks.
    Matrix(Vec<Vec<Expr>>),
    /// A unary operation.
    Unary(UnOp, Box<Expr>),
    /// A binary operation.
    Binary(BinOp, Box<Expr>, Box<Expr>),
    /// `f(args)`.
    Call(Ident, Vec<Expr>),
    /// `e[args]`.
    Index(Box<Expr>, Vec<IndexArg>),
    /// `if c then a else b`.
    If(Box<Expr>, Box<Expr>, Box<Expr>),
    /// `sum(k in S: body)`, `max(k in S: body)`, `min(k in S: body)`.
    Fold(Fold, Box<Binder>, Box<Expr>),
}

/// How a fold over an index set combines its bodies' values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fold {
    /// Their sum (0 over an empty set).
    Sum,
    /// Their elementwise maximum (−∞ over an empty set).
    Max,
    /// Their elementwise minimum (+∞ over an empty set).
    Min,
}

/// `property NAME: BODY`: what must hold on every solution.
#[derive(Debug, Clone, PartialEq)]
pub struct PropertyDecl {
    /// The property's name.
    pub name: Ident,
    /// What must hold.
    pub body: PropertyBody,
    /// The body's text span (shown in reports).
    pub body_span: Span,
    /// The whole declaration.
    pub span: Span,
}

/// The body of a property declaration.
#[derive(Debug, Clone, PartialEq)]
pub enum PropertyBody {
    /// `always P`.
    Always(Expr),
    /// `during flows P`.
    DuringFlows(Expr),
    /// `after E always P`: P from the first sample where E holds on.
    AlwaysAfter {
        /// E.
        enter: Expr,
        /// P.
        pred: Expr,
    },
    /// `at jumps [RULE] P`, with `post(expr)` for post-jump values.
    AtJumps {
        /// Only jumps of this rule.
        rule: Option<Target>,
        /// The predicate.
        pred: Expr,
    },
    /// `eventually within T P`.
    EventuallyWithin {
        /// The deadline T.
        within: Expr,
        /// The predicate.
        pred: Expr,
    },
    /// `decreasing V during flows [tol ε]`, `nonincreasing V at jumps [tol ε]`, ...
    Monotone {
        /// `decreasing` (else `nonincreasing`).
        decreasing: bool,
        /// `at jumps` (else `during flows`).
        jumps: bool,
        /// V.
        v: Expr,
        /// ε.
        tol: Option<Expr>,
    },
    /// `exponential V kappa κ alpha α [tol ε]`.
    Exponential {
        /// `|x|_A`.
        v: Expr,
        /// κ.
        kappa: Expr,
        /// α.
        alpha: Expr,
        /// ε.
        tol: Option<Expr>,
    },
}
