//! Errors found by the checker: names, shapes, arities, indices and the
//! structure of flows and jumps. Each converts into a [`Diagnostic`].

use crate::diagnostics::Diagnostic;
use crate::source::Span;

/// Shape of a value, for messages: rows × cols.
pub type Dims = (usize, usize);

fn shape(d: Dims) -> String {
    match d {
        (1, 1) => "scalar".to_string(),
        (r, 1) => format!("{r}×1 vector"),
        (r, c) => format!("{r}×{c} matrix"),
    }
}

fn cycle_words(cycle: &[(String, Span)]) -> String {
    let mut names: Vec<String> = cycle.iter().map(|(n, _)| format!("`{n}`")).collect();
    if let Some(first) = names.first().cloned() {
        names.push(first);
    }
    names.join(" → ")
}

/// An estimated count: exact up to 10^15, then in scientific form with 3 digits.
fn estimate_words(x: f64) -> String {
    if x < 1e15 {
        format!("{}", x.round())
    } else {
        format!("{x:.2e}")
    }
}

/// Bytes in words: `32.0 GB`, `512 MB`.
fn bytes_words(b: f64) -> String {
    if b >= 1e9 {
        format!("{:.1} GB", b / 1e9)
    } else {
        format!("{:.0} MB", (b / 1e6).ceil())
    }
}

fn did_you_mean(s: &Option<String>) -> Option<String> {
    s.as_ref().map(|s| format!("did you mean `{s}`?"))
}

/// A family whose only member has one index n ≥ 2 (`state x[2] = [1; 0]`):
/// most likely meant as a vector of n entries, which is declared without an
/// index (`state x = [1; 0]`).
#[derive(Debug, Clone, PartialEq)]
pub struct LoneMember {
    /// The declaration's keyword (`state`, `param`, `output`).
    pub keyword: &'static str,
    /// The member's index.
    pub index: i64,
}

impl LoneMember {
    /// The help for family `name`.
    fn help(&self, name: &str) -> String {
        let (k, n) = (self.keyword, self.index);
        format!(
            "`{k} {name}[{n}] = …` declares one member, `{name}[{n}]`, of a family `{name}` \
             (families are declared member by member, as in `for i in 1..N {{ {k} {name}[i] = 0 }}`); \
             a vector of {n} entries is declared without an index, `{k} {name} = [a; b; …]` \
             (or `zeros({n}, 1)`), and read as `{name}[1]` … `{name}[{n}]`"
        )
    }
}

/// A checker error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CheckError {
    /// A name that is not declared (before this point).
    #[error("unknown name `{name}`")]
    UnknownName {
        /// The name.
        name: String,
        /// Where.
        span: Span,
        /// The closest declared name.
        suggestion: Option<String>,
    },
    /// An assignment (`y' =`, `y+ =`) to a name that is not declared.
    #[error("unknown name `{name}`")]
    UnknownTarget {
        /// The name.
        name: String,
        /// Where.
        span: Span,
        /// The closest declared name.
        suggestion: Option<String>,
    },
    /// A name declared twice.
    #[error("`{name}` is declared twice")]
    Duplicate {
        /// The name.
        name: String,
        /// The second declaration.
        span: Span,
        /// The first declaration.
        first: Span,
    },
    /// A setting given twice: a key of a `sim`, `log` or `sweep` block (in one
    /// block or two), or an axis of the `sweep` block.
    #[error("`{name}` is set twice")]
    SetTwice {
        /// The key or axis as written the second time.
        name: String,
        /// The second one.
        span: Span,
        /// The first one.
        first: Span,
    },
    /// A second `log` or `sweep` block (each is written once).
    #[error("a second `{block}` block")]
    SecondBlock {
        /// `log` or `sweep`.
        block: &'static str,
        /// The second block.
        span: Span,
        /// The first block.
        first: Span,
    },
    /// A call of a function that does not exist.
    #[error("unknown function `{name}`")]
    UnknownFunction {
        /// The name.
        name: String,
        /// Where.
        span: Span,
        /// The closest built-in function.
        suggestion: Option<String>,
        /// How hybsim writes another language's function of this name
        /// (`log10`, MATLAB's `rand`), in place of the closest spelling, which
        /// would name a different function (`log`, `round`).
        foreign: Option<&'static str>,
    },
    /// `x(1)`: a declared name (state, parameter, output, index) called
    /// like a function, MATLAB's indexing.
    #[error("`{name}` is not a function; hybsim indexes with brackets: `{name}[...]`")]
    NotAFunction {
        /// The name.
        name: String,
        /// The call.
        span: Span,
    },
    /// A `sim` key or override that does not exist.
    #[error("unknown setting `{name}`")]
    UnknownSetting {
        /// The key.
        name: String,
        /// Where (empty for overrides).
        span: Span,
        /// The closest known key.
        suggestion: Option<String>,
    },
    /// A `--set name=value` whose name is no parameter, state or `sim`
    /// key of the model (located in the override, or in the flag it stands for).
    #[error("unknown setting `{name}` in {}", match .flag {
        Some(flag) => format!("`{flag}`"),
        None => format!("override `{name}={value}`"),
    })]
    UnknownOverride {
        /// The name.
        name: String,
        /// The value as given.
        value: String,
        /// The command-line flag it stands for, as typed (see [`super::Override::flag`]).
        flag: Option<String>,
        /// The closest name `--set` accepts.
        suggestion: Option<String>,
        /// The family the name designates (whole or a member), which `--set`
        /// does not reach.
        family: Option<String>,
    },
    /// Operands of incompatible shapes.
    #[error("shape mismatch in `{op}`: {} and {}", shape(*left), shape(*right))]
    ShapeMismatch {
        /// The operation.
        op: String,
        /// Left operand's shape.
        left: Dims,
        /// Right operand's shape.
        right: Dims,
        /// Where.
        span: Span,
    },
    /// A left-hand side and right-hand side of different shapes.
    #[error("`{target}` is a {} but the right-hand side is a {}", shape(*expected), shape(*found))]
    AssignShape {
        /// The assigned thing as written (`x'`, `v+`, `h`).
        target: String,
        /// Its shape.
        expected: Dims,
        /// The value's shape.
        found: Dims,
        /// The right-hand side.
        span: Span,
    },
    /// Wrong number of arguments.
    #[error("`{func}` takes {expected} but got {found}")]
    Arity {
        /// Function name.
        func: String,
        /// Expected count in words ("2 arguments").
        expected: String,
        /// Given count.
        found: usize,
        /// The call.
        span: Span,
    },
    /// A value of the wrong kind (e.g. not a square matrix, not a condition).
    #[error("expected {expected}, found {found}")]
    Expected {
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
        /// Where.
        span: Span,
    },
    /// A comparison of a vector or matrix where a condition (one true/false
    /// value) was expected: `x >= 0` with `x` a vector.
    #[error("expected a condition such as `h >= 0`, found {found}")]
    VectorCondition {
        /// The comparison's shape, in words.
        found: String,
        /// hybsim's spellings of "every component" and "some component".
        help: String,
        /// Where.
        span: Span,
    },
    /// Something that must be known before the run depends on states,
    /// time or random draws.
    #[error("{what} must be a constant")]
    NotConstant {
        /// What must be constant.
        what: String,
        /// Where.
        span: Span,
    },
    /// An index outside a vector or matrix.
    #[error("index {index} is out of range 1..{len}")]
    IndexOutOfRange {
        /// The index (1-based).
        index: i64,
        /// The dimension's length.
        len: usize,
        /// Where.
        span: Span,
    },
    /// A family indexed outside its members.
    #[error("`{name}` has no member [{index}]")]
    FamilyOutOfRange {
        /// The family.
        name: String,
        /// The index as written out.
        index: String,
        /// The members, in words.
        members: String,
        /// Set by the checker when the family has one member.
        lone: Option<LoneMember>,
        /// Where.
        span: Span,
    },
    /// A family used without its index, or a plain name indexed as a family.
    #[error("`{name}` is a family; index it as `{name}[i]`")]
    FamilyIndex {
        /// The family.
        name: String,
        /// Set by the checker when the family has one member.
        lone: Option<LoneMember>,
        /// Where.
        span: Span,
    },
    /// Assignment (`x' =`, `x+ =`) to something that is not a state.
    #[error("`{name}` is {kind}, not a state; only states can be assigned")]
    AssignToNonState {
        /// The name.
        name: String,
        /// What it is ("a parameter").
        kind: String,
        /// Where.
        span: Span,
    },
    /// A state component reset twice in one rule.
    #[error("`{name}` is reset twice in rule `{rule}`")]
    ResetTwice {
        /// The state (component).
        name: String,
        /// The rule.
        rule: String,
        /// The second reset.
        span: Span,
        /// The first reset.
        first: Span,
    },
    /// Two rules of one `together` group reset the same state component.
    #[error("`{name}` is reset by rules `{first_rule}` and `{rule}` of one `together` group")]
    GroupResetTwice {
        /// The state (component).
        name: String,
        /// The second rule.
        rule: String,
        /// The first rule.
        first_rule: String,
        /// The second rule's reset.
        span: Span,
        /// The first rule's reset.
        first: Span,
    },
    /// A state component with two flow equations.
    #[error("`{name}` has two flow equations")]
    FlowTwice {
        /// The state (component).
        name: String,
        /// The second equation.
        span: Span,
        /// The first equation.
        first: Span,
    },
    /// A state declared without an initial value.
    #[error("state `{name}` has no initial value")]
    MissingInit {
        /// The state.
        name: String,
        /// Its declaration.
        span: Span,
    },
    /// A random draw where the value must be deterministic.
    #[error("random draws are not allowed in {place}")]
    RandomNotAllowed {
        /// Where ("a flow equation", ...).
        place: String,
        /// The draw.
        span: Span,
    },
    /// A bad value of a `sim` setting.
    #[error("invalid `{key}`: {reason}")]
    BadSetting {
        /// The key.
        key: String,
        /// Why.
        reason: String,
        /// Where.
        span: Span,
    },
    /// A language feature reserved for later.
    #[error("{what} is not supported yet")]
    Unsupported {
        /// The feature.
        what: String,
        /// Where.
        span: Span,
    },
    /// Outputs and instance inputs that depend on each other at one instant
    /// (an algebraic loop): each name in order, with its definition.
    #[error("algebraic loop: {}", cycle_words(.cycle))]
    AlgebraicLoop {
        /// The names of the loop in dependency order (each uses the next;
        /// the last uses the first), with their definitions.
        cycle: Vec<(String, Span)>,
    },
    /// An instance argument that is neither a parameter nor an input of
    /// its subsystem, or a parameter without default left without value,
    /// or an input left unconnected.
    #[error("{message}")]
    Instance {
        /// What is wrong, in words.
        message: String,
        /// Where.
        span: Span,
        /// The subsystem's declaration (or the declaration concerned).
        decl: Option<Span>,
        /// What to change.
        help: String,
    },
    /// A subsystem that contains an instance of itself (directly or through
    /// others): the chain of subsystems.
    #[error("subsystem `{}` contains itself: {}", chain[0], chain.join(" → "))]
    RecursiveSubsystem {
        /// The subsystems from the first back to it.
        chain: Vec<String>,
        /// The instance that closes the chain.
        span: Span,
    },
    /// A failure while computing a parameter (singular matrix, Riccati
    /// equation without a solution, ...).
    #[error("cannot compute `{func}`: {reason}")]
    Compute {
        /// The function.
        func: String,
        /// Why.
        reason: String,
        /// Where.
        span: Span,
    },
    /// An error in a `design` block (E07xx).
    #[error(transparent)]
    Design(super::design::DesignError),
    /// A `table("…")` that could not be read (E0801, E0802, E0804, E0307).
    #[error(transparent)]
    Table(crate::tables::TableError),
    /// A model whose compilation would exceed the work budget (huge
    /// matrices or loops).
    #[error("the model is too large to compile (more than {limit} scalar operations)")]
    TooLarge {
        /// The budget.
        limit: u64,
        /// Where the budget ran out.
        span: Span,
    },
    /// A size that grows with the parameters over its limit, found before allocating it
    /// (see [`super::limits`]).
    #[error("{} {quantity}: over the limit of {limit}", estimate_words(*estimate))]
    Limit {
        /// What is counted.
        quantity: super::limits::Quantity,
        /// The estimated size (a float: `T / dt_out` may be astronomical).
        estimate: f64,
        /// The limit in force.
        limit: u64,
        /// The construct that asks for it.
        span: Span,
    },
    /// A size within its (raised) limit that needs more memory than the machine (or the
    /// process's `ulimit -v`) has, found before allocating it.
    #[error(
        "{} {quantity} need about {}, more memory than there is ({})",
        estimate_words(*estimate),
        bytes_words(*bytes),
        bytes_words(*available as f64)
    )]
    Memory {
        /// What is counted.
        quantity: super::limits::Quantity,
        /// The estimated size.
        estimate: f64,
        /// The bytes it needs at least.
        bytes: f64,
        /// The memory there is.
        available: u64,
        /// The limit that lets the size through: its own, or `ops` for the result of an
        /// operation (a product's entries).
        lifted: super::limits::Quantity,
        /// The construct that asks for it.
        span: Span,
    },
    /// A set condition that reads a NaN value (it would never hold).
    #[error("{set} compares with NaN, so it never holds")]
    NanCondition {
        /// The set (`the flow set`, ``the jump set of `r` ``).
        set: String,
        /// The flow block or the rule's head.
        span: Span,
    },
    /// A flow equation affine in the state with an infinite or NaN coefficient.
    #[error("the flow equation of `{target}` has a coefficient that is not finite (inf or NaN)")]
    NonFiniteFlow {
        /// The equation's left-hand side (`x'`).
        target: String,
        /// The equation.
        span: Span,
    },
    /// A state's constant initial value that is inf or NaN: no run can
    /// start from it (the engine refuses a non-finite initial state).
    #[error("the initial value of `{name}` is not finite ({value})")]
    NonFiniteInit {
        /// The state (`x`, `x[2]` for a component of a vector).
        name: String,
        /// The value (±inf or NaN).
        value: f64,
        /// The initial value's expression.
        span: Span,
    },
    /// A flow equation in which white noise does not enter linearly
    /// (`x' = w^2`): the engine needs `x' = f(x) + G(x) w`.
    #[error("white noise must enter `{target}` linearly")]
    NoiseNotAffine {
        /// The equation's left-hand side (`x'`).
        target: String,
        /// The equation.
        span: Span,
    },
    /// An index error (E0401, E0402) in one iteration of a `for` loop: the
    /// loop and its variables' values there, and the `--set` values its
    /// range reads (a range grown past a table by `--set N=…`); or a size
    /// over its limit (E0307) in a loop whose range reads `--set` values.
    #[error("{inner}")]
    InLoop {
        /// The error.
        inner: Box<CheckError>,
        /// The loop's binder (`i in 1..N`).
        binder: Span,
        /// The variables' values (`i = 4`; empty for a size over its limit,
        /// which counts every iteration).
        values: String,
        /// The overrides its range reads, as typed (`--set N=5`).
        set_by: Vec<String>,
    },
    /// An error inside a `--set name=value` override (or a flag that is one, `--T 0`).
    #[error("in {}: {message}", match .flag {
        Some(flag) => format!("`{flag}`"),
        None => format!("override `{name}={value}`"),
    })]
    Override {
        /// The overridden name.
        name: String,
        /// The value text.
        value: String,
        /// The command-line flag it stands for, as typed (see [`super::Override::flag`]).
        flag: Option<String>,
        /// The underlying message.
        message: String,
        /// Where in the value (a byte range of `value`), when known.
        at: Option<Span>,
        /// The underlying error's advice, if any.
        advice: Option<String>,
        /// The underlying error's code when it is kept (a bad `sim` value stays E0506);
        /// `None`: E0508.
        inner_code: Option<&'static str>,
        /// The underlying error was a size over its limit (see
        /// [`CheckError::is_size_limit`]).
        size_limit: bool,
    },
}

impl CheckError {
    /// A size over its limit (E0307), also inside an override: the checker
    /// stopped short, so later errors are its echoes and are dropped.
    pub fn is_size_limit(&self) -> bool {
        match self {
            CheckError::Limit { .. } | CheckError::TooLarge { .. } | CheckError::Memory { .. } => {
                true
            }
            CheckError::Override { size_limit, .. } => *size_limit,
            CheckError::InLoop { inner, .. } => inner.is_size_limit(),
            _ => false,
        }
    }

    /// The primary span.
    pub fn span(&self) -> Span {
        use CheckError::*;
        match self {
            UnknownName { span, .. }
            | UnknownTarget { span, .. }
            | Duplicate { span, .. }
            | SetTwice { span, .. }
            | SecondBlock { span, .. }
            | UnknownFunction { span, .. }
            | NotAFunction { span, .. }
            | UnknownSetting { span, .. }
            | ShapeMismatch { span, .. }
            | AssignShape { span, .. }
            | Arity { span, .. }
            | Expected { span, .. }
            | VectorCondition { span, .. }
            | NotConstant { span, .. }
            | IndexOutOfRange { span, .. }
            | FamilyOutOfRange { span, .. }
            | FamilyIndex { span, .. }
            | AssignToNonState { span, .. }
            | ResetTwice { span, .. }
            | GroupResetTwice { span, .. }
            | FlowTwice { span, .. }
            | MissingInit { span, .. }
            | RandomNotAllowed { span, .. }
            | BadSetting { span, .. }
            | Unsupported { span, .. }
            | Instance { span, .. }
            | RecursiveSubsystem { span, .. }
            | Compute { span, .. }
            | TooLarge { span, .. }
            | Limit { span, .. }
            | Memory { span, .. }
            | NonFiniteFlow { span, .. }
            | NonFiniteInit { span, .. }
            | NanCondition { span, .. }
            | NoiseNotAffine { span, .. } => *span,
            Design(e) => e.span(),
            Table(e) => e.span(),
            AlgebraicLoop { cycle } => cycle.first().map(|c| c.1).unwrap_or_default(),
            Override { .. } | UnknownOverride { .. } => Span::default(),
            InLoop { inner, .. } => inner.span(),
        }
    }

    /// The stable code (E02xx names, E03xx shapes and kinds, E04xx indices,
    /// E05xx structure).
    pub fn code(&self) -> &'static str {
        use CheckError::*;
        match self {
            UnknownName { .. } | UnknownTarget { .. } => "E0201",
            Duplicate { .. } | SetTwice { .. } | SecondBlock { .. } => "E0202",
            UnknownFunction { .. } => "E0203",
            UnknownSetting { .. } | UnknownOverride { .. } => "E0204",
            NotAFunction { .. } => "E0205",
            ShapeMismatch { .. } => "E0301",
            AssignShape { .. } => "E0302",
            Arity { .. } => "E0303",
            Expected { .. } | VectorCondition { .. } => "E0304",
            NotConstant { .. } => "E0305",
            Compute { .. } => "E0306",
            TooLarge { .. } | Limit { .. } | Memory { .. } => "E0307",
            IndexOutOfRange { .. } => "E0401",
            FamilyOutOfRange { .. } => "E0402",
            FamilyIndex { .. } => "E0403",
            AssignToNonState { .. } => "E0501",
            ResetTwice { .. } => "E0502",
            GroupResetTwice { .. } => "E0510",
            FlowTwice { .. } => "E0503",
            MissingInit { .. } => "E0504",
            RandomNotAllowed { .. } => "E0505",
            BadSetting { .. } => "E0506",
            Unsupported { .. } => "E0507",
            Override { inner_code, .. } => inner_code.unwrap_or("E0508"),
            InLoop { inner, .. } => inner.code(),
            NoiseNotAffine { .. } => "E0509",
            AlgebraicLoop { .. } => "E0511",
            Instance { .. } => "E0512",
            RecursiveSubsystem { .. } => "E0513",
            NonFiniteFlow { .. } => "E0514",
            NanCondition { .. } => "E0515",
            NonFiniteInit { .. } => "E0516",
            Design(e) => e.code(),
            Table(e) => e.code(),
        }
    }

    /// The error as a diagnostic, with labels and help.
    pub fn to_diagnostic(&self) -> Diagnostic {
        use CheckError::*;
        if let InLoop {
            inner,
            binder,
            values,
            set_by,
        } = self
        {
            // No iteration for a size over its limit: the loop's range gave it.
            let d = if values.is_empty() {
                inner
                    .to_diagnostic()
                    .secondary(*binder, "the range of this loop")
            } else {
                inner
                    .to_diagnostic()
                    .secondary(*binder, format!("in the iteration with {values}"))
            };
            return match set_by.as_slice() {
                [] => d,
                sets => d.note(format!("the loop's range reads {}", sets.join(", "))),
            };
        }
        let d = Diagnostic::error(self.code(), self.to_string());
        match self {
            UnknownTarget {
                name,
                span,
                suggestion,
            } => d.primary(*span, "not declared").help(
                did_you_mean(suggestion).unwrap_or_else(|| {
                    format!("only states are assigned: declare it first, e.g. `state {name} = 0`")
                }),
            ),
            // `nan` (as `--set g=nan` or in a model) is no constant: say how to write NaN.
            UnknownName { name, span, .. } if name.eq_ignore_ascii_case("nan") => d
                .primary(*span, "not found")
                .help("there is no `nan` constant: write `0/0` for NaN (`inf` is a constant)"),
            // MATLAB's `x(end)`, written with brackets.
            UnknownName { name, span, .. } if name == "end" => d
                .primary(*span, "not found")
                .help("there is no `end` index: write the last index, `x[length(x)]` (`P[rows(P), :]`, `P[:, cols(P)]` for a matrix)"),
            // `pre(x)` (Modelica's, or the dual of a property's `post(x)`).
            UnknownFunction { name, span, .. } if name == "pre" => d
                .primary(*span, "not found")
                .help("there is no `pre`: a bare name is the value before the jump (`x`); `post(x)`, in a property `at jumps`, is the value after it"),
            UnknownFunction {
                span,
                foreign: Some(help),
                ..
            } => d.primary(*span, "not found").help(*help),
            UnknownName {
                span, suggestion, ..
            }
            | UnknownFunction {
                span, suggestion, ..
            }
            | UnknownSetting {
                span, suggestion, ..
            } => {
                let d = if matches!(self, UnknownSetting { .. }) && *span == Span::default() {
                    d
                } else {
                    d.primary(*span, "not found")
                };
                match did_you_mean(suggestion) {
                    Some(h) => d.help(h),
                    None => d,
                }
            }
            UnknownOverride {
                name,
                value,
                flag,
                suggestion,
                family,
            } => {
                // The flag's word (`--grid` for a sweep axis) and where the name starts in it.
                let (word, start) = match flag {
                    Some(f) => (f.split(' ').next().unwrap_or(f), f.find(' ').map_or(0, |i| i + 1)),
                    None => ("--set", 0),
                };
                let d = d.primary(Span::new(start, start + name.len()), "not in the model");
                let d = match (family, did_you_mean(suggestion)) {
                    (Some(f), _) => d.help(format!(
                        "`{f}` is a family: {word} gives single parameters and initial values, \
                         not families or their members; set what the family is computed from"
                    )),
                    (None, Some(h)) => d.help(h),
                    (None, None) => d.help(format!(
                        "{word} names a parameter, a state (its initial value) or a `sim` key"
                    )),
                };
                match flag {
                    Some(f) => d.in_flag(word, f),
                    None => d.in_set_argument(name, &format!("{name}={value}"), 0),
                }
            }
            NotAFunction { span, name } => d
                .primary(*span, "indexed with parentheses")
                .help(format!(
                    "write `{name}[i]` (or `{name}[i, k]` for a matrix); indices start at 1"
                )),
            Duplicate { span, first, .. } => d
                .primary(*span, "declared again here")
                .secondary(*first, "first declared here")
                .help("rename one of them"),
            // Renaming a setting is no fix (it was "rename one of them"): one must go.
            SetTwice { name, span, first } => d
                .primary(*span, "set again here")
                .secondary(*first, "first set here")
                .help(format!("remove one of them: `{name}` takes one value")),
            SecondBlock { block, span, first } => d
                .primary(*span, "second block")
                .secondary(*first, "first block")
                .help(format!("write all the entries in one `{block}` block")),
            ShapeMismatch {
                span,
                left,
                right,
                op,
            } => d
                .primary(*span, format!("{} and {}", shape(*left), shape(*right)))
                .help(if op.starts_with('^') {
                    // MATLAB's `x.^2` written `x^2`: no transpose helps.
                    "`^` is not elementwise: write `x .* x` for the squares of a vector's entries"
                } else {
                    "check the dimensions; use `'` to transpose"
                }),
            AssignShape { span, found, .. } => d
                .primary(*span, format!("this is a {}", shape(*found)))
                .help("make both sides the same shape"),
            Arity { span, .. } => d.primary(*span, "wrong number of arguments"),
            Expected { span, expected, .. } => d.primary(*span, format!("expected {expected}")),
            VectorCondition { span, help, .. } => d
                .primary(*span, "one true/false value per component")
                .help(help.clone()),
            NotConstant { span, .. } => d
                .primary(*span, "depends on states, time or random draws")
                .help("use only numbers, parameters and index variables here"),
            Compute { span, .. } => d.primary(*span, "while computing this"),
            TooLarge { span, .. } => d
                .primary(*span, "the budget ran out here")
                .help("use smaller dimensions, fewer family members or shorter loops, or raise the limit: `max_ops = N` in `sim` or `--set max_ops=N`"),
            Limit { span, quantity, .. } => d
                .primary(*span, "asked for here")
                .help(format!(
                    "use {}, or raise the limit: `max_{key} = N` in `sim` or `--set max_{key}=N`",
                    quantity.remedy(),
                    key = quantity.key()
                )),
            Memory {
                span,
                quantity,
                lifted,
                ..
            } => d.primary(*span, "asked for here").help(format!(
                "use {}: the limit `max_{}` lets it through, the memory does not",
                quantity.remedy(),
                lifted.key()
            )),
            IndexOutOfRange { span, .. } => d.primary(*span, "out of range"),
            FamilyOutOfRange {
                span,
                members,
                name,
                lone,
                ..
            } => {
                let d = d
                    .primary(*span, "no such member")
                    .note(format!("its members are {members}"));
                match lone {
                    Some(l) => d.help(l.help(name)),
                    None => d,
                }
            }
            FamilyIndex { span, name, lone } => {
                let d = d.primary(*span, "needs a member index");
                match lone {
                    Some(l) => d.help(l.help(name)),
                    None => d,
                }
            }
            AssignToNonState { span, .. } => d
                .primary(*span, "not a state")
                .help("declare it with `state`, or assign another name"),
            ResetTwice { span, first, .. } => d
                .primary(*span, "reset again here")
                .secondary(*first, "first reset here")
                .help("keep one reset per state in each rule"),
            GroupResetTwice {
                span,
                first,
                rule,
                first_rule,
                ..
            } => d
                .primary(*span, format!("reset by `{rule}` here"))
                .secondary(*first, format!("reset by `{first_rule}` here"))
                .note("the rules of a `together` group that are enabled at one instant fire as one jump, each reset computed from the pre-jump state; a component can come from one rule only")
                .help("reset each state in one rule of the group, or move one of the rules out of `together`"),
            FlowTwice { span, first, .. } => d
                .primary(*span, "second equation")
                .secondary(*first, "first equation")
                .help("keep one equation per state"),
            MissingInit { span, name } => d.primary(*span, "no initial value").help(format!(
                "write `{name} = value` or `{name} ~ uniform(lo, hi)`"
            )),
            RandomNotAllowed { span, .. } => d
                .primary(*span, "random draw")
                .help("draw in a jump reset or an initial value, or declare `noise`"),
            BadSetting { span, .. } => d.primary(*span, "invalid value"),
            Unsupported { span, .. } => d.primary(*span, "not supported yet"),
            AlgebraicLoop { cycle } => {
                let mut d = d;
                for (k, (name, span)) in cycle.iter().enumerate() {
                    let next = &cycle[(k + 1) % cycle.len()].0;
                    let msg = format!("`{name}` uses `{next}`");
                    d = if k == 0 {
                        d.primary(*span, msg)
                    } else {
                        d.secondary(*span, msg)
                    };
                }
                d.note("outputs and inputs are evaluated at one instant, each from the ones it uses: a loop among them has no order")
                    .help("break the loop with a state (e.g. a zero-order hold or a first-order filter) on one of its connections")
            }
            Instance {
                span, decl, help, ..
            } => {
                let d = d.primary(*span, "here").help(help.clone());
                match decl {
                    Some(s) => d.secondary(*s, "declared here"),
                    None => d,
                }
            }
            RecursiveSubsystem { span, .. } => d
                .primary(*span, "this instance closes the chain")
                .help("a subsystem cannot contain an instance of itself"),
            Override {
                flag: Some(flag),
                advice,
                ..
            } => {
                // The value as typed: the flag's words after its name (`0` of `--T 0`).
                let (word, typed) = flag.split_once(' ').unwrap_or((flag.as_str(), ""));
                let start = flag.len() - typed.len();
                d.primary(Span::new(start, flag.len()), "here")
                    .help(advice.as_deref().map_or_else(
                        || format!("fix the value given with {word}"),
                        str::to_string,
                    ))
                    .in_flag(word, flag)
            }
            Override {
                name,
                value,
                at,
                advice,
                ..
            } => {
                let d = match at {
                    Some(at) => d.primary(*at, "here"),
                    None => d.primary(Span::new(0, value.len()), ""),
                };
                d.help(advice.as_deref().unwrap_or("fix the value given with --set"))
                    .in_override(name, value)
            }
            NonFiniteFlow { span, .. } => d
                .primary(*span, "inf or NaN in this equation")
                .help("check the parameters it uses (a division by zero, an overflow, `inf`)"),
            NonFiniteInit { span, .. } => d
                .primary(*span, "not a finite number")
                .help("check the parameters it uses (a division by zero, an overflow, `inf`)"),
            NanCondition { span, .. } => d
                .primary(*span, "its condition reads a NaN value")
                .help("check the parameters it uses (`0/0`, `inf - inf`, `0*inf`); write `inf` for a threshold that is never reached"),
            NoiseNotAffine { span, .. } => d
                .primary(*span, "a nonlinear function of white noise")
                .note("flows with noise are read as x' = f(x) + G(x) w, w white noise")
                .help("write the noise term as a coefficient times the noise, e.g. `sigma * x * w`; the coefficient may depend on the state"),
            Design(e) => e.to_diagnostic(),
            Table(e) => e.to_diagnostic(),
            InLoop { inner, .. } => inner.to_diagnostic(),
        }
    }
}
