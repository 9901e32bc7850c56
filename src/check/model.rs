//! Checking of declarations: parameters, states, noise, flows, jumps,
//! outputs and simulation settings.

use rustc_hash::FxHashMap as HashMap;
use std::rc::Rc;

use super::dag::{BinFn, Dag, Node, NodeId};
use super::design::Solved;
use super::error::{CheckError, Dims};
use super::expr::{CONST_CTX, Ctx, Val, dims_words, key_label, suggest};
use super::limits::{Limits, Quantity};
use super::rule_names::RuleNames;
use super::{Checker, DesignReport, Sym, Unavailable};
use crate::engine::{
    ExactAffine, JumpChoice, LinearSolver, Priority, SimError, SimSettings, Solver,
};
use crate::num::Num;
use crate::source::Span;
use crate::syntax::ast::*;

/// A `--set name=value` override: `value` is an expression.
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    /// A parameter, a state (its initial value) or a `sim` key.
    pub name: String,
    /// The value's source text.
    pub value: String,
    /// The parsed value.
    pub expr: Expr,
    /// The command-line flag it stands for, as typed (`--T 0` for `sim.T=0e0`), which
    /// diagnostics show instead of `name=value`; `None` for a `--set`.
    pub flag: Option<String>,
}

impl Override {
    /// The override as the user typed it: its flag (`--T 0`), or `--set name=value`.
    pub fn typed(&self) -> String {
        self.flag
            .clone()
            .unwrap_or_else(|| format!("--set {}={}", self.name, self.value))
    }

    /// This override as the command-line flag `flag` the user typed (`--T 0`).
    #[must_use]
    pub fn from_flag(self, flag: impl Into<String>) -> Self {
        Self {
            flag: Some(flag.into()),
            ..self
        }
    }
}

/// A state field: a named scalar, vector or matrix in the flat state.
#[derive(Debug, Clone, PartialEq)]
pub struct StateField {
    /// Name as shown (`h`, `x[2]` for family member 2, `step.timer`).
    pub name: String,
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// First component.
    pub offset: usize,
    /// The declaration.
    pub span: Span,
    /// True for states the language adds (timers of `every` and `noise`).
    pub generated: bool,
    /// For a member of a state family (`x[2]`): the family's name and the
    /// member's label (`"2"`, `"1,3"`).
    pub family: Option<(String, String)>,
}

/// A checked jump rule.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedRule {
    /// Name (`impact`, `flash[3]`).
    pub name: String,
    /// Its jump set as a condition node.
    pub guard: NodeId,
    /// For `every` rules: the timer component and the period.
    pub timer: Option<(usize, f64)>,
    /// Reset components and their new values (over pre-jump values).
    pub resets: Vec<(usize, NodeId)>,
    /// The assignment (`x+ = …`) of each of `resets` (an `every` timer's: the rule's head), for
    /// run-time errors of the value it computes.
    pub reset_spans: Vec<Span>,
    /// The `together` block the rule belongs to (numbered in source
    /// order, one per block instance), if any.
    pub group: Option<usize>,
    /// In a model with subsystem instances: the part of the composite jump
    /// (0 the model's own rules, then one per instance); at most one rule
    /// of a part fires in a jump (see `engine::JumpRule::part`).
    pub part: Option<usize>,
    /// The rule's head.
    pub span: Span,
    /// True for the redraw rule of a held `noise` (`v.redraw`).
    pub redraw: bool,
}

/// A named output.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputField {
    /// Name.
    pub name: String,
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Element nodes, row-major.
    pub nodes: Vec<NodeId>,
    /// The definition.
    pub span: Span,
    /// For a member of an output family (`e[2]`): the family's name and the
    /// member's label (`"2"`, `"1,3"`).
    pub family: Option<(String, String)>,
}

/// A model after checking: every expression lowered into one scalar graph.
#[derive(Debug, Clone)]
pub struct CheckedModel {
    /// The model's name.
    pub name: String,
    /// Where the name is (the `model` header).
    pub name_span: Span,
    /// The scalar graph.
    pub dag: Dag,
    /// State fields in order.
    pub fields: Vec<StateField>,
    /// Dimension of the state.
    pub dim: usize,
    /// Initial value node per component.
    pub init: Vec<NodeId>,
    /// Derivative node per component.
    pub flow: Vec<NodeId>,
    /// The flow equation of each component, if any.
    pub flow_spans: Vec<Option<Span>>,
    /// Flow set condition (`None`: everywhere).
    pub flow_set: Option<(NodeId, Span)>,
    /// Jump rules in order.
    pub rules: Vec<CheckedRule>,
    /// Outputs in order.
    pub outputs: Vec<OutputField>,
    /// Number of white-noise components.
    pub wiener_dim: usize,
    /// Simulation settings after overrides.
    pub settings: SimSettings,
    /// The `sim` block's `rtol`, `atol` and `h` as given (after overrides),
    /// also those its solver does not use.
    pub solver_keys: SolverKeys,
    /// Seed of the run.
    pub seed: u64,
    /// `jit = on | off` (`None`: not given; machine code where supported).
    pub jit: Option<bool>,
    /// Resolved parameters: name, shape, row-major values.
    pub params: Vec<(String, Dims, Vec<f64>)>,
    /// Span of each block operation, by its origin index.
    pub block_spans: Vec<Span>,
    /// The `design` blocks in order: solver figures and results.
    pub designs: Vec<DesignReport>,
    /// The `property` declarations (nodes in the property frame, see
    /// [`super::property`]).
    pub properties: Vec<super::property::CheckedProperty>,
    /// The `metric` declarations and their reductions (see
    /// [`super::metric`]).
    pub metrics: super::metric::CheckedMetrics,
    /// The random parameters (`param g ~ uniform(a, b)`, or `--set
    /// g=uniform(a, b)`) not pinned by an override, in declaration order;
    /// each is declared with its distribution's centre.
    pub random_params: Vec<crate::props::Input>,
    /// The `sweep { … }` block, if the model has one.
    pub sweep: Option<super::sweep::SweepDecl>,
    /// What `hybsim run` logs (the `log { … }` block, or the defaults).
    pub log: super::log::LogDecl,
    /// The files read by `table("…")` (path and SHA-256).
    pub tables: Vec<crate::tables::TableFile>,
    /// The resource limits in force (after the `sim` block and `--set`).
    pub limits: super::limits::Limits,
}

/// The solver keys of a `sim` block (after overrides) as given, whichever
/// solver it names: `sim { h = 0.01 }` on Dopri5 is the step `--solver rk4`
/// takes, `rtol` on RK4 the tolerance `--solver dopri5` takes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolverKeys {
    /// `rtol`, if given.
    pub rtol: Option<f64>,
    /// `atol`, if given.
    pub atol: Option<f64>,
    /// `h`, if given.
    pub h: Option<f64>,
}

const FLOW_CTX: Ctx = Ctx {
    random: false,
    wiener: true,
    place: "a flow equation",
};
const GUARD_CTX: Ctx = Ctx {
    random: false,
    wiener: false,
    place: "a condition",
};
const INIT_CTX: Ctx = Ctx {
    random: true,
    wiener: false,
    place: "an initial value",
};
const RESET_CTX: Ctx = Ctx {
    random: true,
    wiener: false,
    place: "a reset",
};
pub(crate) const OUTPUT_CTX: Ctx = Ctx {
    random: false,
    wiener: false,
    place: "an output",
};

/// The `solver` names, for the errors that list them.
/// Why the value `e` of word-valued `sim` setting `key` is refused: its
/// words, with the closest one to a misspelt word (`jmps`: `jumps`), MATLAB's
/// solvers by their hybsim names (`ode45`: `dopri5`) and, for `priority`, the
/// numbers of HyEQ's `rule` (1 jumps, 2 flows, 3 random).
fn word_reason(key: &str, e: &Expr) -> String {
    let words = crate::syntax::setting_words(key).unwrap_or_default();
    let list = format!("write one of {}", words.join(", "));
    let matlab = |w: &str| match w {
        "ode45" | "ode23" => Some("dopri5"),
        "ode113" | "ode78" | "ode89" => Some("dop853"),
        "ode15s" | "ode15i" => Some("bdf"),
        "ode23s" | "ode23t" | "ode23tb" => Some("radau5"),
        _ => None,
    };
    match &e.kind {
        ExprKind::Name(w) => {
            let hint = matlab(w)
                .filter(|_| key == "solver")
                .map(|m| format!("MATLAB's `{w}` is `{m}` here"))
                .or_else(|| {
                    crate::syntax::closest_word(w, words).map(|c| format!("did you mean `{c}`?"))
                });
            match hint {
                Some(h) => format!("{list} ({h})"),
                None => list,
            }
        }
        ExprKind::Num(_) if key == "priority" => {
            format!("{list} (HyEQ's `rule = 1` is `jumps`, 2 is `flows`, 3 is `random`)")
        }
        _ => list,
    }
}

/// The values a numeric `sim` key takes, for its out-of-range message.
fn sim_range(key: &str) -> &'static str {
    match key {
        "T" => "the horizon T is a positive finite time",
        "J" => "the horizon J is a whole number of jumps ≥ 0, or inf (no bound)",
        "seed" => "a seed is a whole number from 0 to 2^64 - 1",
        "event_tol" => "event_tol is a tolerance ≥ 0",
        "set_tol" => "set_tol is a finite tolerance ≥ 0",
        "max_step" | "rtol" | "atol" | "zeno_rate" => "it is a number > 0",
        _ => "it is a positive finite number",
    }
}

/// Known `sim` keys.
const SIM_KEYS: &[&str] = &[
    "T",
    "J",
    "solver",
    "rtol",
    "atol",
    "h",
    "priority",
    "jump_choice",
    "dt_out",
    "seed",
    "max_step",
    "event_tol",
    "set_tol",
    "zeno_rate",
    "zeno_max_rate",
    "zeno_window",
    "max_total_jumps",
    "horizon_t",
    "horizon_j",
    "exact_affine",
    "linear_solver",
    "jit",
];

/// The canonical name of a `sim` key (`horizon_t` is `T`).
fn canonical_sim_key(key: &str) -> &str {
    match key {
        "horizon_t" => "T",
        "horizon_j" => "J",
        "zeno_max_rate" => "zeno_rate",
        k => k,
    }
}

/// The `sim` key a user of MATLAB's ODE solvers or of the HyEQ Toolbox means by
/// one of their names (`TSPAN`, `RelTol`, HyEQ's `rule`), compared without case.
fn foreign_sim_key(key: &str) -> Option<&'static str> {
    Some(match key.to_ascii_lowercase().as_str() {
        "tspan" | "tf" | "tfinal" | "t_final" | "tend" | "t_end" | "tmax" | "t_max" => "T",
        "jspan" | "jf" | "jmax" | "j_max" | "jend" | "j_end" => "J",
        "reltol" => "rtol",
        "abstol" => "atol",
        "maxstep" => "max_step",
        "rule" => "priority",
        "choice" | "rule_choice" => "jump_choice",
        _ => return None,
    })
}

/// The closest `sim` key to an unknown one: the key another tool's name means,
/// else the nearest spelling.
fn suggest_sim_key(key: &str) -> Option<String> {
    foreign_sim_key(key)
        .map(str::to_string)
        .or_else(|| suggest(key, SIM_KEYS.iter().copied()))
}

/// The canonical `sim` key an override names, and whether it names it explicitly
/// (`sim.T`: `sim` is a keyword, so no declaration of the model has that name).
fn sim_key(name: &str) -> Option<(&'static str, bool)> {
    let (key, explicit) = match name.strip_prefix("sim.") {
        Some(key) => (key, true),
        None => (name, false),
    };
    let key = SIM_KEYS.iter().find(|k| **k == key)?;
    Some((canonical_sim_key(key), explicit))
}

/// A component reset in a `together` group: by which rule, where, and the
/// rule's part of the composite jump.
type GroupReset = (String, Span, Option<usize>);

struct ModelChecker<'o> {
    c: Checker,
    overrides: HashMap<&'o str, &'o Override>,
    used: Vec<String>,
    /// The names `--set` accepts (the `sim` keys, parameters, random
    /// parameters, initial values): sweep axes must be among them.
    settable: Vec<String>,
    init: Vec<Option<NodeId>>,
    flow: Vec<Option<(NodeId, Span)>>,
    flow_set: Option<(NodeId, Span)>,
    rules: Vec<CheckedRule>,
    rule_names: HashMap<String, Span>,
    outputs: Vec<OutputField>,
    wiener_dim: usize,
    /// The `sim` block's settings: key, value, where, the value as written when a whole number.
    sim: Vec<(String, Expr, Span, Option<u64>)>,
    params: Vec<(String, Dims, Vec<f64>)>,
    /// Names of the rules declared without one.
    anonymous: super::rule_names::Anonymous,
    /// The `together` block being checked, and the number of blocks seen.
    group: Option<usize>,
    groups: usize,
    /// Per group: each reset component with its rule and reset, to report
    /// two rules of one group that reset one component.
    group_resets: Vec<HashMap<usize, GroupReset>>,
    /// The part of the composite jump being checked (models with
    /// instances), and the parts by instance name.
    part: Option<usize>,
    parts: HashMap<String, usize>,
    designs: Vec<DesignReport>,
    random_params: Vec<crate::props::Input>,
    solve_checks: bool,
    /// What was not evaluated because a design block failed: (that block,
    /// what), reported as a note on the block's error.
    unavailable: Vec<(String, String)>,
    /// The files read by `table("…")`.
    tables: Vec<crate::tables::TableFile>,
    /// The `for` loops being run, outermost first: (member, members).
    loops: Vec<(usize, usize)>,
}

pub(crate) fn check_model(
    model: &Model,
    overrides: &[Override],
    options: &super::CheckOptions,
) -> Result<CheckedModel, Vec<CheckError>> {
    let mut m = ModelChecker {
        c: Checker {
            dag: Dag::new(),
            errors: Vec::new(),
            syms: HashMap::default(),
            scopes: Vec::new(),
            set_scopes: Vec::new(),
            fields: Vec::new(),
            block_spans: Vec::new(),
            post_frame: None,
            poisoned: HashMap::default(),
            poison_hit: None,
            backend: options.backend,
            metric_frame: None,
            signals: Default::default(),
            limits: options.limits,
            path: None,
            reuse: None,
            hints: Default::default(),
        },
        overrides: overrides.iter().map(|o| (o.name.as_str(), o)).collect(),
        used: Vec::new(),
        settable: SIM_KEYS.iter().map(|k| k.to_string()).collect(),
        init: Vec::new(),
        flow: Vec::new(),
        flow_set: None,
        rules: Vec::new(),
        rule_names: HashMap::default(),
        outputs: Vec::new(),
        wiener_dim: 0,
        sim: Vec::new(),
        params: Vec::new(),
        anonymous: Default::default(),
        group: None,
        groups: 0,
        group_resets: Vec::new(),
        part: None,
        parts: HashMap::default(),
        designs: Vec::new(),
        random_params: Vec::new(),
        solve_checks: options.solve_checks,
        unavailable: Vec::new(),
        tables: Vec::new(),
        loops: Vec::new(),
    };
    // Subsystem instances are expanded into the flat model first.
    let flat = super::compose::elaborate(model, &mut m.c.errors).map(|(flat, unavailable)| {
        for name in unavailable {
            m.c.poisoned.insert(name, Unavailable::Failed);
        }
        flat
    });
    let composite = flat.is_some();
    let model = flat.as_ref().unwrap_or(model);
    m.limit_keys(model);
    for it in &model.items {
        m.pass1(it);
    }
    for it in &model.items {
        m.signals(it);
    }
    if composite {
        // HyEQ's composite system: one jump group; the model's own rules
        // are part 0, each instance a part of its own.
        m.group = Some(m.groups);
        m.groups += 1;
        m.group_resets.push(HashMap::default());
        m.part = Some(0);
        m.parts.insert(String::new(), 0);
    }
    for it in &model.items {
        m.pass2(it);
    }
    m.c.lower_signals();
    m.outputs = m.c.take_outputs();
    let names: Vec<String> = m.rules.iter().map(|r| r.name.clone()).collect();
    // Declared rules that failed their checks stay known names: a property or metric naming
    // one adds no error to theirs.
    let checked: std::collections::HashSet<&String> = names.iter().collect();
    let failed = m
        .rule_names
        .keys()
        .filter(|n| !checked.contains(n))
        .cloned()
        .collect();
    let rule_names = RuleNames::new(
        names,
        super::rule_names::declared_families(&model.items),
        failed,
    );
    let properties =
        super::property::check_properties(&mut m.c, &model.items, &rule_names, m.init.len());
    let mut collector =
        super::metric::MetricCollector::new(&mut m.c, rule_names.clone(), m.init.len());
    for it in &model.items {
        m.metrics(it, &mut collector);
    }
    let metrics = collector.finish(&mut m.c);
    let sweep = super::sweep::check_sweeps(&mut m.c, &model.items, &m.settable);
    let log = super::log::check_logs(&mut m.c, &model.items, &m.rules);
    let (settings, solver_keys, seed, jit) = m.settings(overrides);
    for o in overrides {
        if !m.used.iter().any(|u| u == &o.name) && sim_key(&o.name).is_none() {
            // A family (`z`, `z[2]`, an instance family's `f[2].x0`) is declared but not
            // settable; any other hint names what `--set` accepts, never a name it refuses.
            let family = family_named(&o.name, &m.c.syms);
            let fits = family.is_none() && m.c.hints.charge(m.settable.len());
            let suggestion = foreign_sim_key(&o.name)
                .map(str::to_string)
                .or_else(|| fits.then(|| suggest(&o.name, &m.settable)).flatten());
            m.c.err(CheckError::UnknownOverride {
                name: o.name.clone(),
                value: o.value.clone(),
                flag: o.flag.clone(),
                suggestion,
                family,
            });
        }
    }
    let simulates = m.designs.is_empty()
        || model
            .items
            .iter()
            .any(|it| matches!(it, Item::State(_) | Item::Flow(_) | Item::Jump(_)));
    if m.c.errors.is_empty() && m.init.is_empty() && simulates {
        // The engine needs at least one state component (`run` would
        // reject the model); families sized 0 by a parameter end here too.
        // A model of `design` blocks alone is for `hybsim design`.
        // Sized 0 by an override (`--set N=0`): say so.
        let mut given: Vec<String> = m.overrides.values().map(|o| o.typed()).collect();
        given.sort();
        let found = match given.as_slice() {
            [] => "a model without states".to_string(),
            _ => format!("a model without states with `{}`", given.join("`, `")),
        };
        m.c.err(CheckError::Expected {
            expected: "at least one state component (`state x = ...`, or a family of size ≥ 1)"
                .into(),
            found,
            span: model.name.span,
        });
    }
    // After a size over its limit the checker stopped short: what follows are its echoes
    // (names never declared, members never made).
    if let Some(k) = m.c.errors.iter().position(CheckError::is_size_limit) {
        m.c.errors.truncate(k + 1);
    }
    if !m.c.errors.is_empty() {
        // Loop headers and filters are evaluated in each pass over the model: an error there
        // (`for i in 1..N` with N = 2.5) is found once per pass, and reported once.
        let mut seen = std::collections::HashSet::new();
        m.c.errors
            .retain(|e| seen.insert((e.span(), e.to_string())));
        for e in &mut m.c.errors {
            if let CheckError::Design(d) = e
                && let Some((block, list)) = d.unavailable_mut()
            {
                let block = block.to_string();
                list.extend(
                    m.unavailable
                        .iter()
                        .filter(|(b, _)| *b == block)
                        .map(|(_, what)| what.clone()),
                );
            }
        }
        return Err(m.c.errors);
    }
    let dim = m.c.fields.iter().map(|f| f.rows * f.cols).sum();
    let zero = m.c.dag.konst(0.0);
    let init = m.init.iter().map(|i| i.unwrap_or(zero)).collect();
    let flow = m.flow.iter().map(|f| f.map_or(zero, |(n, _)| n)).collect();
    let flow_spans = m.flow.iter().map(|f| f.map(|(_, s)| s)).collect();
    Ok(CheckedModel {
        name: model.name.name.clone(),
        name_span: model.name.span,
        dag: m.c.dag,
        fields: m.c.fields,
        dim,
        init,
        flow,
        flow_spans,
        flow_set: m.flow_set,
        rules: m.rules,
        outputs: m.outputs,
        wiener_dim: m.wiener_dim,
        settings,
        solver_keys,
        seed,
        jit,
        params: m.params,
        block_spans: m.c.block_spans,
        designs: m.designs,
        properties,
        metrics,
        random_params: m.random_params,
        sweep,
        log,
        tables: m.tables,
        limits: m.c.limits,
    })
}

/// `uniform(a, b)` or `normal(m, s)` (two arguments): a random
/// parameter's draw.
/// An assigned target (`x`, `x[2]`, `x[2][1:3]`) resolved to state
/// components.
struct Assigned {
    comps: Vec<usize>,
    dims: Dims,
    /// The family member's key, for a member of a state family.
    key: Option<Vec<i64>>,
    /// True if the target selects part of the field (`x[1:3]`).
    indexed: bool,
}

impl Assigned {
    /// The target as messages show it (`x`, `x[2]`, `x[…]`); built only
    /// when needed, since a family reset resolves one target per member.
    fn display(&self, t: &Target) -> String {
        let name = &t.name.name;
        let base = match &self.key {
            Some(key) => format!("{name}[{}]", key_label(key)),
            None => name.clone(),
        };
        if self.indexed {
            format!("{base}[…]")
        } else {
            base
        }
    }
}

/// The family that the override name `name` designates, whole or one member
/// (`z`, `z[2]`, `f[2].x0` and `f.x0[2]` for `f.x0`), if the model declares one.
fn family_named(name: &str, syms: &HashMap<String, Sym>) -> Option<String> {
    let mut bare = String::with_capacity(name.len());
    let mut depth = 0usize;
    for ch in name.chars() {
        match ch {
            '[' => depth += 1,
            ']' => depth = depth.saturating_sub(1),
            _ if depth == 0 => bare.push(ch),
            _ => {}
        }
    }
    matches!(
        syms.get(&bare),
        Some(Sym::ParamFamily { .. } | Sym::StateFamily { .. } | Sym::OutputFamily { .. })
    )
    .then_some(bare)
}

fn is_draw(e: &Expr) -> bool {
    matches!(&e.kind, ExprKind::Call(f, args)
        if (f.name == "uniform" || f.name == "normal") && args.len() == 2)
}

impl ModelChecker<'_> {
    /// Elaborates `e`, or the override for `name` if there is one (errors in
    /// the override are reported as such).
    fn value_with_override(&mut self, name: &str, e: &Expr, ctx: &Ctx) -> Option<Val> {
        self.settable.push(name.to_string());
        let Some(o) = self.overrides.get(name).copied() else {
            return self.c.expr(e, ctx);
        };
        self.used.push(name.to_string());
        let before = self.c.errors.len();
        let v = self.c.expr(&o.expr, ctx);
        self.locate_in_override(before, o, false);
        v
    }

    /// Rewrites the errors recorded since `before` (found while elaborating the override `o`,
    /// whose spans are byte ranges of its value) as errors located in that override.
    /// With `keep_code` the errors keep their own codes (a `sim` value: E0506 as in the
    /// model's `sim` block), otherwise they become E0508.
    fn locate_in_override(&mut self, before: usize, o: &Override, keep_code: bool) {
        let new: Vec<CheckError> = self.c.errors.drain(before..).collect();
        for err in new {
            let at = err.span();
            let inner_code = keep_code.then(|| err.code());
            self.c.err(CheckError::Override {
                name: o.name.clone(),
                value: o.value.clone(),
                flag: o.flag.clone(),
                message: err.to_string(),
                at: (at.end <= o.value.len() && at != Span::default()).then_some(at),
                advice: err.to_diagnostic().help,
                inner_code,
                size_limit: err.is_size_limit(),
            });
        }
    }

    /// Declares `target` as a name (or family member); see
    /// [`Checker::declare`].
    fn declare(
        &mut self,
        target: &Target,
        sym: impl FnOnce(Option<&[i64]>) -> Sym,
    ) -> Option<String> {
        self.c.declare(target, sym)
    }

    fn add_field(
        &mut self,
        name: String,
        rows: usize,
        cols: usize,
        span: Span,
        generated: bool,
    ) -> usize {
        let offset = self.init.len();
        self.c.fields.push(StateField {
            name,
            rows,
            cols,
            offset,
            span,
            generated,
            family: None,
        });
        self.init.extend(std::iter::repeat_n(None, rows * cols));
        self.flow.extend(std::iter::repeat_n(None, rows * cols));
        self.c.fields.len() - 1
    }

    fn pass1(&mut self, item: &Item) {
        match item {
            Item::Param(defs) => {
                for d in defs {
                    self.param(d, false);
                }
            }
            Item::Graph(d) => self.param(d, true),
            Item::RandomParam(d) => self.random_param(d),
            Item::ParamTuple(targets, value) => self.param_tuple(targets, value),
            Item::Table(t) => self.table(t),
            Item::State(defs) => {
                for sd in defs {
                    self.state(sd);
                }
            }
            Item::Noise(n) => self.noise_decl(n),
            Item::For(b, items) => {
                self.c.poison_hit = None;
                let errors = self.c.errors.len();
                let ran = self.c_for(b, &mut |this| {
                    for it in items {
                        this.pass1(it);
                    }
                });
                // Its range failed (with an error, or from an unavailable
                // value): what the body declares is unavailable too.
                let cause = match self.c.poison_hit.take() {
                    Some(cause) => Some(cause),
                    None => (self.c.errors.len() > errors).then_some(Unavailable::Failed),
                };
                if let (false, Some(cause)) = (ran, cause) {
                    let mut names = Vec::new();
                    declared_names(items, &mut names);
                    for name in names {
                        self.c.poisoned.insert(name, cause.clone());
                    }
                }
            }
            Item::Design(d) => self.design(d),
            Item::Part(_, items) => {
                for it in items {
                    self.pass1(it);
                }
            }
            Item::Flow(_)
            | Item::Jump(_)
            | Item::Output(_)
            | Item::Signal(_)
            | Item::Import(_)
            | Item::Subsystem(_)
            | Item::Input(_)
            | Item::Instance(_)
            | Item::Sim(_)
            | Item::Property(_)
            | Item::Together(..)
            | Item::Metric(_)
            | Item::Sweep(_)
            | Item::Log(_) => {}
        }
    }

    fn pass2(&mut self, item: &Item) {
        match item {
            Item::Flow(f) => self.flow_block(f),
            Item::Jump(j) => self.jump(j),
            Item::Noise(n) => self.noise_rule(n),
            Item::Part(t, items) => {
                let Some(label) = self.part_label(t) else {
                    return;
                };
                let n = self.parts.len();
                let p = *self.parts.entry(label).or_insert(n);
                let outer = self.part.replace(p);
                for it in items {
                    self.pass2(it);
                }
                self.part = outer;
            }
            Item::Sim(settings) => {
                for s in settings {
                    self.sim
                        .push((s.key.name.clone(), s.value.clone(), s.key.span, s.integer));
                }
            }
            Item::For(b, items) => {
                self.c_for(b, &mut |this| {
                    for it in items {
                        this.pass2(it);
                    }
                });
            }
            Item::Together(items, _) => {
                let outer = self.group.replace(self.groups);
                self.groups += 1;
                self.group_resets.push(HashMap::default());
                for it in items {
                    self.pass2(it);
                }
                self.group = outer;
            }
            Item::Param(_)
            | Item::RandomParam(_)
            | Item::ParamTuple(..)
            | Item::Graph(_)
            | Item::State(_)
            | Item::Design(_)
            | Item::Property(_)
            | Item::Metric(_)
            | Item::Sweep(_)
            | Item::Import(_)
            | Item::Table(_)
            | Item::Subsystem(_)
            | Item::Input(_)
            | Item::Instance(_)
            | Item::Log(_) => {}
            Item::Output(defs) => {
                for _ in defs {
                    self.c.lower_next_signal();
                }
            }
            Item::Signal(_) => self.c.lower_next_signal(),
        }
    }

    /// Refuses a state or output named `t` or `j`: every logged record (MCAP
    /// message, CSV and Parquet row) carries the hybrid time under those
    /// names, so the value would be lost or ambiguous there.
    fn not_a_time_name(&mut self, name: &str, span: Span) {
        if name == "t" || name == "j" {
            self.c.err(CheckError::Expected {
                expected: "a name other than `t` and `j`, which name the hybrid time in every logged record".into(),
                found: format!("a state or output named `{name}`"),
                span,
            });
        }
    }

    /// Registers the outputs and instance inputs (lowered on first use, see
    /// `check::signal`).
    fn signals(&mut self, item: &Item) {
        match item {
            Item::Output(defs) => {
                for d in defs {
                    self.not_a_time_name(&d.target.name.name, d.target.span);
                    self.c.register_signal(d, true);
                }
            }
            Item::Signal(d) => self.c.register_signal(d, false),
            Item::For(b, items) => {
                self.c_for(b, &mut |this| {
                    for it in items {
                        this.signals(it);
                    }
                });
            }
            Item::Part(_, items) | Item::Together(items, _) => {
                for it in items {
                    self.signals(it);
                }
            }
            _ => {}
        }
    }

    /// The instance a part stands for, `node[3]`.
    fn part_label(&mut self, t: &Target) -> Option<String> {
        match t.indices.as_slice() {
            [] => Some(t.name.name.clone()),
            [args] => {
                let key = self.c.family_key(args)?;
                Some(format!("{}[{}]", t.name.name, key_label(&key)))
            }
            _ => None,
        }
    }

    /// The `metric` declarations (after every rule and output is known).
    fn metrics(&mut self, item: &Item, m: &mut super::metric::MetricCollector) {
        match item {
            Item::Metric(defs) => {
                for d in defs {
                    m.metric(&mut self.c, d);
                }
            }
            Item::For(b, items) => {
                self.c_for(b, &mut |this| {
                    for it in items {
                        this.metrics(it, m);
                    }
                });
            }
            _ => {}
        }
    }

    /// `for` over a binder with `self` (not just the inner checker).
    /// Runs `body` for each member of `b`'s index set; false if the set
    /// could not be formed.
    fn c_for(&mut self, b: &Binder, body: &mut dyn FnMut(&mut Self)) -> bool {
        // The outermost loop keeps the statement values its body lowers
        // for reuse (`super::reuse`), until it ends.
        let outermost = self.c.reuse.is_none();
        if outermost {
            self.c.reuse = super::reuse::Reuse::start();
        }
        let ran = self.c_for_members(b, body);
        if outermost {
            self.c.reuse = None;
        }
        ran
    }

    fn c_for_members(&mut self, b: &Binder, body: &mut dyn FnMut(&mut Self)) -> bool {
        let Some(members) = self.c.index_set(b) else {
            return false;
        };
        let names: Vec<Rc<str>> = b.vars.iter().map(|v| Rc::from(v.name.as_str())).collect();
        self.loops.push((0, members.len()));
        for (k, m) in members.into_iter().enumerate() {
            self.c.dag.charge(1);
            if !self.c.within_budget(0, b.span) {
                break;
            }
            if let Some(at) = self.loops.last_mut() {
                at.0 = k;
            }
            let depth = self.c.scopes.len();
            for (v, &i) in names.iter().zip(&m) {
                self.c.scopes.push((Rc::clone(v), i));
            }
            let keep = match &b.filter {
                None => true,
                Some(f) => match self.c.expr(f, &CONST_CTX) {
                    Some(v) if v.rows * v.cols == 1 => match self.c.dag.as_const(v.e[0]) {
                        Some(x) => x != 0.0,
                        None => {
                            self.c.err(CheckError::NotConstant {
                                what: "a filter".into(),
                                span: f.span,
                            });
                            false
                        }
                    },
                    _ => false,
                },
            };
            if keep {
                let errors = self.c.errors.len();
                body(self);
                self.in_loop(b, errors, depth);
            }
            self.c.scopes.truncate(depth);
        }
        self.loops.pop();
        true
    }

    /// Index errors of the loop `b`'s iteration since `errors` say which
    /// iteration (its variables from scope `depth` on) and what `--set`
    /// values its range reads.
    fn in_loop(&mut self, b: &Binder, errors: usize, depth: usize) {
        let wrapped = |e: &CheckError| matches!(e.code(), "E0401" | "E0402");
        // A size over its limit (`for i in 1..N { state x[i] = 0 }` with `--set N=1e5`) gets
        // the loop and the `--set` values its range reads, not an iteration: it counts them all.
        let sized = |e: &CheckError| e.code() == "E0307" && !matches!(e, CheckError::InLoop { .. });
        if !self.c.errors[errors..]
            .iter()
            .any(|e| wrapped(e) || sized(e))
        {
            return;
        }
        let values = self.c.scopes[depth..]
            .iter()
            .map(|(v, i)| format!("`{v}` = {i}"))
            .collect::<Vec<_>>()
            .join(", ");
        let mut set_by = Vec::new();
        let mut reads = |e: &Expr| overrides_read(e, &self.overrides, &mut set_by);
        // The binder up to its last expression (its span runs on over blanks).
        let mut end = b.span.end;
        match &b.set {
            IndexSet::Range(lo, hi) | IndexSet::In(lo, hi) | IndexSet::Out(lo, hi) => {
                reads(lo);
                reads(hi);
                end = hi.span.end;
            }
            IndexSet::Edges(g) => {
                reads(g);
                end = g.span.end;
            }
            _ => {}
        }
        if let Some(f) = &b.filter {
            end = f.span.end;
        }
        let binder = Span::new(b.span.start, end.min(b.span.end));
        for e in &mut self.c.errors[errors..] {
            if sized(e) && !set_by.is_empty() {
                let inner = Box::new(std::mem::replace(
                    e,
                    CheckError::AlgebraicLoop { cycle: Vec::new() },
                ));
                *e = CheckError::InLoop {
                    inner,
                    binder,
                    values: String::new(),
                    set_by: set_by.clone(),
                };
            } else if wrapped(e) {
                let inner = Box::new(std::mem::replace(
                    e,
                    CheckError::AlgebraicLoop { cycle: Vec::new() },
                ));
                *e = CheckError::InLoop {
                    inner,
                    binder,
                    values: values.clone(),
                    set_by: set_by.clone(),
                };
            }
        }
    }

    /// How many more times the statement being checked runs, this time
    /// included, if every `for` loop around it runs all its members (before
    /// their filters): exact for loops whose ranges do not depend on each
    /// other's variables.
    fn runs_left(&self) -> f64 {
        self.loops
            .iter()
            .rev()
            .fold((1.0, 1.0), |(left, inner), &(k, n)| {
                (left + (n - k - 1) as f64 * inner, inner * n as f64)
            })
            .0
    }

    fn param(&mut self, d: &Definition, graph: bool) {
        let name = d.target.name.name.clone();
        if !graph
            && d.target.indices.is_empty()
            && let Some(o) = self.overrides.get(name.as_str()).copied()
            && is_draw(&o.expr)
        {
            // `--set g=uniform(a, b)`: a random parameter.
            self.settable.push(name.clone());
            self.used.push(name);
            self.declare_random(&d.target, &o.expr);
            return;
        }
        self.c.poison_hit = None;
        let errors = self.c.errors.len();
        let v = if d.target.indices.is_empty() {
            self.value_with_override(&name, &d.value, &CONST_CTX)
        } else {
            self.c.expr(&d.value, &CONST_CTX)
        };
        if let Some(cause) = self.c.poison_hit.take() {
            // Computed from an unavailable value: unavailable too.
            self.poison(&d.target, cause);
            return;
        }
        let Some(v) = v else {
            self.failed(&d.target, errors);
            return;
        };
        let vals: Option<Vec<f64>> = v.e.iter().map(|&n| self.c.dag.as_const(n)).collect();
        let Some(vals) = vals else {
            self.c.err(CheckError::NotConstant {
                what: format!("parameter `{name}`"),
                span: d.value.span,
            });
            return;
        };
        if graph && v.rows != v.cols {
            self.c.err(CheckError::Expected {
                expected: "a square adjacency matrix".into(),
                found: dims_words(v.dims()),
                span: d.value.span,
            });
            return;
        }
        let dims = v.dims();
        let span = d.target.name.span;
        if let Some(display) = self.declare(&d.target, |_| Sym::Param {
            val: Rc::new(v),
            span,
        }) {
            self.params.push((display, dims, vals));
        }
    }

    /// `param tk = table("file.csv")`: the file read (once, here, with the
    /// size limit in force) into a constant matrix; `--set tk=[…]` replaces
    /// it without reading the file.
    fn table(&mut self, t: &TableParam) {
        if !self.c.scopes.is_empty() {
            // Once, not per iteration.
            let seen = self
                .c
                .errors
                .iter()
                .any(|e| matches!(e, CheckError::Unsupported { span, .. } if *span == t.span));
            if !seen {
                self.c.err(CheckError::Unsupported {
                    what: "`table(…)` inside `for` (declare the table once, at the top level)"
                        .into(),
                    span: t.span,
                });
            }
            return;
        }
        let target = Target {
            name: t.name.clone(),
            indices: Vec::new(),
            span: t.name.span,
        };
        if self.overrides.contains_key(t.name.name.as_str()) {
            let value = Expr {
                kind: ExprKind::Num(0.0),
                span: t.span,
            };
            self.param(&Definition { target, value }, false);
            return;
        }
        let span = t.name.span;
        let read = match &t.file {
            Some(file) => {
                crate::tables::read(file, &t.path, t.span, self.c.limits.get(Quantity::Elements))
            }
            // Checked without `lang` (no model folder): nothing to read from.
            None => Err(crate::tables::TableError::Path(
                crate::imports::ImportError::Unreadable {
                    path: t.path.clone(),
                    resolved: t.path.clone(),
                    reason: "tables are read by `lang::compile` (the model's folder is unknown)"
                        .into(),
                    span: t.path_span,
                },
            )),
        };
        let val = match read {
            Ok(data) => {
                let e = data.data.iter().map(|&v| self.c.dag.konst(v)).collect();
                self.tables.push(data.file);
                Val {
                    rows: data.rows,
                    cols: data.cols,
                    e,
                    boolean: false,
                }
            }
            Err(e) => {
                self.c.err(CheckError::Table(e));
                // Its shape is unknown: later uses report nothing.
                self.poison(&target, Unavailable::Failed);
                return;
            }
        };
        self.declare(&target, |_| Sym::Param {
            val: Rc::new(val),
            span,
        });
    }

    /// `param g ~ DRAW`: random unless `--set` pins it (or replaces the
    /// draw by another one).
    fn random_param(&mut self, d: &Definition) {
        if !d.target.indices.is_empty() {
            self.c.err(CheckError::Unsupported {
                what: "families of random parameters (declare them one by one)".into(),
                span: d.target.span,
            });
            return;
        }
        if self.overrides.contains_key(d.target.name.name.as_str()) {
            // A pinned value (or another draw): as any overridden parameter.
            self.param(d, false);
        } else {
            self.settable.push(d.target.name.name.clone());
            self.declare_random(&d.target, &d.value);
        }
    }

    /// Declares the random parameter `target ~ draw` with the draw's
    /// centre as its value, and records it in `random_params`.
    fn declare_random(&mut self, target: &Target, draw: &Expr) {
        let name = target.name.name.clone();
        let span = target.name.span;
        let dist = self.draw(draw);
        let nominal = dist.map_or(0.0, |d| d.centre());
        let val = Val::scalar(self.c.dag.konst(nominal));
        if self
            .declare(target, |_| Sym::Param {
                val: Rc::new(val),
                span,
            })
            .is_some()
        {
            self.params.push((name.clone(), (1, 1), vec![nominal]));
            if let Some(dist) = dist {
                self.random_params
                    .push(crate::props::Input::new(name, dist));
            }
        }
    }

    /// The distribution of a random parameter: `uniform(a, b)` or
    /// `normal(m, s)` with constant scalar arguments.
    fn draw(&mut self, e: &Expr) -> Option<crate::props::Dist> {
        use crate::props::Dist;
        let ExprKind::Call(f, args) = &e.kind else {
            self.c.err(CheckError::Expected {
                expected: "a draw `uniform(lo, hi)` or `normal(mean, std)`".into(),
                found: "another expression".into(),
                span: e.span,
            });
            return None;
        };
        let (a, b) = match args.as_slice() {
            [a, b] if is_draw(e) => (
                self.c.const_scalar(a, "a random parameter's distribution"),
                self.c.const_scalar(b, "a random parameter's distribution"),
            ),
            _ => {
                self.c.err(CheckError::Expected {
                    expected: "a draw `uniform(lo, hi)` or `normal(mean, std)`".into(),
                    found: format!("`{}` with {} argument(s)", f.name, args.len()),
                    span: e.span,
                });
                return None;
            }
        };
        let (a, b) = (a?, b?);
        let dist = if f.name == "uniform" {
            Dist::Uniform { lo: a, hi: b }
        } else {
            Dist::Normal { mean: a, std: b }
        };
        if let Err(reason) = dist.validate() {
            self.c.err(CheckError::Expected {
                expected: "a valid distribution".into(),
                found: reason,
                span: e.span,
            });
            return None;
        }
        Some(dist)
    }

    /// A `design` block: solved (unless `--set` gives every result: then it
    /// is not even assembled), then its results declared as parameters with
    /// the variables bound to their values.
    fn design(&mut self, d: &DesignBlock) {
        let mut targets: Vec<&Target> = Vec::new();
        for s in &d.stmts {
            match s {
                DesignStmt::Param(defs) => targets.extend(defs.iter().map(|d| &d.target)),
                DesignStmt::ParamTuple(t, _) => targets.extend(t.iter()),
                _ => {}
            }
        }
        // Results inside loops (families) cannot all be given with --set.
        let nested_results = has_results(&d.stmts, false);
        let all_set = !nested_results
            && !targets.is_empty()
            && targets
                .iter()
                .all(|t| self.overrides.contains_key(t.name.name.as_str()));
        // A `check` block is solved only when asked for (`hybsim design`):
        // nothing in the model depends on it.
        if d.check && !targets.is_empty() {
            self.c.err(CheckError::Unsupported {
                what: "results (`param`) in a `check` block (use `design`)".into(),
                span: targets[0].span,
            });
        }
        let solved = if !d.check && all_set {
            // Nothing depends on the block: it is neither assembled nor
            // solved (its LMIs can take seconds and hundreds of MB to build;
            // `hybsim design` checks it).
            Some(Solved {
                values: Vec::new(),
                summary: None,
                unsolved: None,
            })
        } else {
            self.c.design_block(d, !d.check || self.solve_checks)
        };
        let Some(solved) = solved else {
            // The results are unavailable: uses of them report nothing
            // (one failed design, one error). A block that failed because
            // it uses another failed block's results passes that block on.
            let failed = match self.c.poison_hit.take() {
                Some(Unavailable::Design(block)) => {
                    let kind = if d.check { "check" } else { "design" };
                    let what = format!("{kind} `{}`", d.name.name);
                    self.unavailable.push((block.clone(), what));
                    Unavailable::Design(block)
                }
                Some(Unavailable::Failed) => Unavailable::Failed,
                None => Unavailable::Design(d.name.name.clone()),
            };
            self.design_results(&d.stmts, Some(&failed));
            return;
        };
        self.c.bind_design_values(&solved.values);
        let first = self.params.len();
        self.design_results(&d.stmts, None);
        for v in &solved.values {
            self.c.syms.remove(&v.name);
        }
        self.designs.push(DesignReport {
            name: d.name.name.clone(),
            span: d.name.span,
            solve: solved.summary,
            results: self.params[first..].to_vec(),
            unsolved: solved.unsolved,
            check: d.check,
        });
    }

    /// Declares the results (`param` lines) of a design block, also those in
    /// its `for` loops and `if`s: evaluated, or (`failed`: the failed block)
    /// as unavailable, so that later uses do not cascade.
    fn design_results(&mut self, stmts: &[DesignStmt], failed: Option<&Unavailable>) {
        let solved = failed.is_none();
        for s in stmts {
            match s {
                DesignStmt::Param(defs) if solved => defs.iter().for_each(|p| self.param(p, false)),
                DesignStmt::ParamTuple(t, v) if solved => self.param_tuple(t, v),
                DesignStmt::Param(defs) => {
                    for d in defs {
                        self.poison(&d.target, failed.cloned().unwrap_or(Unavailable::Failed));
                    }
                }
                DesignStmt::ParamTuple(t, _) => {
                    for t in t {
                        self.poison(t, failed.cloned().unwrap_or(Unavailable::Failed));
                    }
                }
                DesignStmt::For(b, body)
                    if !matches!(b.set, crate::syntax::ast::IndexSet::Subsets(_))
                        && has_results(body, true) =>
                {
                    let _ = self.c_for(b, &mut |this| this.design_results(body, failed));
                }
                DesignStmt::If(c, body) if has_results(body, true) => {
                    if let Some(x) = self.c.const_scalar(c, "the condition of `if` in a design")
                        && x != 0.0
                    {
                        self.design_results(body, failed);
                    }
                }
                _ => {}
            }
        }
    }

    /// Declares `t` as a parameter whose value is unavailable (`cause`):
    /// uses of it report nothing (see [`Checker::poisoned`]); after a
    /// failed design it is listed in the block's error.
    fn poison(&mut self, t: &Target, cause: Unavailable) {
        let z = self.c.dag.konst(0.0);
        let span = t.name.span;
        let shown = self.declare(t, |_| Sym::Param {
            val: Rc::new(Val::scalar(z)),
            span,
        });
        self.c.poisoned.insert(t.name.name.clone(), cause.clone());
        if let Unavailable::Design(block) = cause {
            let what = format!("`{}`", shown.unwrap_or_else(|| t.name.name.clone()));
            if !self.unavailable.iter().any(|(_, w)| *w == what) {
                self.unavailable.push((block, what));
            }
        }
    }

    /// After parameter `t`'s definition gave no value: unavailable if that
    /// recorded an error (more than `errors_before`), so that uses of it
    /// (whose shape is unknown) report nothing more; otherwise declared as
    /// 0, as before.
    fn failed(&mut self, t: &Target, errors_before: usize) {
        if self.c.errors.len() > errors_before {
            self.poison(t, Unavailable::Failed);
        } else {
            let z = self.c.dag.konst(0.0);
            let span = t.name.span;
            self.declare(t, |_| Sym::Param {
                val: Rc::new(Val::scalar(z)),
                span,
            });
        }
    }

    fn param_tuple(&mut self, targets: &[Target], value: &Expr) {
        self.c.poison_hit = None;
        let errors = self.c.errors.len();
        let vals = match &value.kind {
            ExprKind::Call(f, args)
                if matches!(f.name.as_str(), "c2d" | "dlqr" | "lqr" | "dare" | "care") =>
            {
                self.c.control_multi(&f.name, args, value.span)
            }
            _ => {
                self.c.err(CheckError::Expected {
                    expected: "a call of c2d, dlqr, lqr, dare or care".into(),
                    found: "another expression".into(),
                    span: value.span,
                });
                None
            }
        };
        if let Some(cause) = self.c.poison_hit.take() {
            for t in targets {
                self.poison(t, cause.clone());
            }
            return;
        }
        let vals = vals.filter(|vals| {
            let fits = vals.len() == targets.len();
            if !fits {
                self.c.err(CheckError::Arity {
                    func: "this destructuring".into(),
                    expected: format!("{} names", vals.len()),
                    found: targets.len(),
                    span: value.span,
                });
            }
            fits
        });
        let Some(vals) = vals else {
            for t in targets {
                self.failed(t, errors);
            }
            return;
        };
        for (t, v) in targets.iter().zip(vals) {
            let vals: Vec<f64> = v.e.iter().filter_map(|&n| self.c.dag.as_const(n)).collect();
            let dims = v.dims();
            let span = t.name.span;
            if let Some(display) = self.declare(t, |_| Sym::Param {
                val: Rc::new(v),
                span,
            }) {
                self.params.push((display, dims, vals));
            }
        }
    }

    fn state(&mut self, sd: &StateDef) {
        let name = sd.target.name.name.clone();
        self.not_a_time_name(&name, sd.target.span);
        let Some(init_expr) = &sd.init else {
            self.c.err(CheckError::MissingInit {
                name: name.clone(),
                span: sd.target.span,
            });
            // A state all the same: its equations and uses report nothing
            // more (they were unknown names).
            self.c.poisoned.insert(name, Unavailable::Failed);
            return;
        };
        self.c.poison_hit = None;
        let errors = self.c.errors.len();
        let v = if sd.target.indices.is_empty() {
            self.value_with_override(&name, init_expr, &INIT_CTX)
        } else {
            self.c.expr(init_expr, &INIT_CTX)
        };
        if let Some(cause) = self.c.poison_hit.take() {
            // Its shape is unknown: uses and equations of it report nothing.
            if let Unavailable::Design(block) = &cause {
                self.unavailable
                    .push((block.clone(), format!("state `{name}`")));
            }
            self.c.poisoned.insert(name, cause);
            return;
        }
        let v = v.filter(|v| {
            let empty = v.rows * v.cols == 0;
            if empty {
                self.c.err(CheckError::Expected {
                    expected: "a non-empty initial value".into(),
                    found: dims_words(v.dims()),
                    span: init_expr.span,
                });
            }
            !empty
        });
        let Some(v) = v else {
            // Its own error is reported: uses and equations of it report
            // nothing more.
            if self.c.errors.len() > errors {
                self.c.poisoned.insert(name, Unavailable::Failed);
            }
            return;
        };
        // The engine's work and memory (the implicit solver's Jacobian is n × n) grow with the
        // number of scalar states.
        let size = (v.rows * v.cols) as f64;
        let mut states = self.init.len() as f64 + size;
        if states > self.c.limits.get(Quantity::States) as f64 {
            // Over the limit: the error names the total the loops around
            // this declaration would reach, not the first member past it.
            states += size * (self.runs_left() - 1.0);
        }
        if !self
            .c
            .within_limit(Quantity::States, states, sd.target.span)
        {
            return;
        }
        if self.c.dag.any_reachable(&v.e, |n| {
            matches!(n, Node::State(_) | Node::Time | Node::Jumps)
        }) {
            self.c.err(CheckError::NotConstant {
                what: format!("the initial value of `{name}`"),
                span: init_expr.span,
            });
            // Its uses report nothing more (they were unknown names, "did you mean …").
            self.c.poisoned.insert(name, Unavailable::Failed);
            return;
        }
        // A constant the engine would refuse at (0, 0): said here, at the
        // value, not as a run-time failure of the state's flow.
        let bad = v.e.iter().enumerate().find_map(|(k, &n)| {
            let c = self.c.dag.as_const(n)?;
            (!c.is_finite()).then_some((k, c))
        });
        if let Some((k, value)) = bad {
            // Uses and equations of the state report nothing more.
            self.c.poisoned.insert(name.clone(), Unavailable::Failed);
            let name = if size > 1.0 {
                format!("{name}[{}]", k + 1)
            } else {
                name
            };
            // From `--set x=…`: located in the override.
            let o = (sd.target.indices.is_empty())
                .then(|| self.overrides.get(sd.target.name.name.as_str()).copied())
                .flatten();
            let before = self.c.errors.len();
            self.c.err(CheckError::NonFiniteInit {
                name,
                value,
                span: o.map_or(init_expr.span, |o| o.expr.span),
            });
            if let Some(o) = o {
                self.locate_in_override(before, o, false);
            }
            return;
        }
        let field_idx = self.c.fields.len();
        let span = sd.target.name.span;
        if let Some(display) = self.declare(&sd.target, |_| Sym::State {
            field: field_idx,
            span,
        }) {
            let f = self.add_field(display.clone(), v.rows, v.cols, sd.target.span, false);
            if !sd.target.indices.is_empty() {
                // `name[label]`, as built by `declare`.
                let label = display[name.len() + 1..display.len() - 1].to_string();
                self.c.fields[f].family = Some((name.clone(), label));
            }
            let off = self.c.fields[f].offset;
            for (k, &n) in v.e.iter().enumerate() {
                self.init[off + k] = Some(n);
            }
        }
    }

    fn noise_decl(&mut self, n: &NoiseDecl) {
        if let ExprKind::Call(f, args) = &n.dist.kind
            && f.name == "wiener"
        {
            if n.every.is_some() {
                self.c.err(CheckError::Expected {
                    expected: "no `every` for white noise".into(),
                    found: "`every`".into(),
                    span: n.span,
                });
                return;
            }
            if args.len() > 1 {
                self.c.err(CheckError::Arity {
                    func: "wiener".into(),
                    expected: "0 or 1 argument".into(),
                    found: args.len(),
                    span: n.dist.span,
                });
                return;
            }
            let m = match args.first() {
                Some(a) => match self.c.const_int(a, "the number of noise channels") {
                    Some(m) if (1..=10_000).contains(&m) => m as usize,
                    Some(m) => {
                        self.c.err(CheckError::Expected {
                            expected: "between 1 and 10000 channels".into(),
                            found: m.to_string(),
                            span: a.span,
                        });
                        return;
                    }
                    None => return,
                },
                None => 1,
            };
            let base = self.wiener_dim;
            self.wiener_dim += m;
            let e = (0..m).map(|k| self.c.dag.wiener(base + k)).collect();
            let val = Val {
                rows: m,
                cols: 1,
                e,
                boolean: false,
            };
            let span = n.target.name.span;
            self.declare(&n.target, |_| Sym::Wiener { val, span });
            return;
        }
        // Held noise: a state drawn initially and at every period.
        if n.every.is_none() {
            self.c.err(CheckError::Expected {
                expected: "`every PERIOD` after a held noise (or `~ wiener(m)`)".into(),
                found: "no period".into(),
                span: n.span,
            });
            return;
        }
        let sd = StateDef {
            target: n.target.clone(),
            init: Some(n.dist.clone()),
        };
        self.state(&sd);
    }

    fn noise_rule(&mut self, n: &NoiseDecl) {
        let Some(every) = &n.every else { return };
        let Some(target) = self.resolve_state(&n.target, true) else {
            return;
        };
        let resets: Vec<ResetStmt> = vec![ResetStmt::Eq(Definition {
            target: n.target.clone(),
            value: n.dist.clone(),
        })];
        self.rule(
            format!("{}.redraw", target.display(&n.target)),
            &Trigger::Every(every.clone()),
            &resets,
            n.span,
            true,
        );
    }

    /// Resolves an assigned target to state components.
    fn resolve_state(&mut self, t: &Target, quiet: bool) -> Option<Assigned> {
        let name = &t.name.name;
        // What the name is, without cloning a family's member table (a
        // reset of a family member would otherwise cost O(family size)).
        enum Kind {
            State(usize),
            Family,
            Other(&'static str),
        }
        let kind = self.c.syms.get(name).map(|sym| match sym {
            Sym::State { field, .. } => Kind::State(*field),
            Sym::StateFamily { .. } => Kind::Family,
            other => Kind::Other(other.kind_words()),
        });
        let (val, rest, key) = match kind {
            Some(Kind::State(field)) => (self.c.field_val(field), &t.indices[..], None),
            Some(Kind::Family) => {
                let Some(first) = t.indices.first() else {
                    self.c.err(CheckError::FamilyIndex {
                        lone: None,
                        name: name.clone(),
                        span: t.span,
                    });
                    return None;
                };
                let key = self.c.family_key(first)?;
                let member = match self.c.syms.get(name) {
                    Some(Sym::StateFamily { members, .. }) => members.get(&key).copied(),
                    _ => None,
                };
                let Some(field) = member else {
                    // A member whose declaration failed: reported there.
                    if self.c.is_poisoned(name) {
                        return None;
                    }
                    let members = self.c.family_members_words(name);
                    self.c.err(CheckError::FamilyOutOfRange {
                        lone: None,
                        name: name.clone(),
                        index: key_label(&key),
                        members,
                        span: t.span,
                    });
                    return None;
                };
                (self.c.field_val(field), &t.indices[1..], Some(key))
            }
            Some(Kind::Other(kind)) => {
                if !quiet {
                    self.c.err(CheckError::AssignToNonState {
                        name: name.clone(),
                        kind: kind.into(),
                        span: t.name.span,
                    });
                }
                return None;
            }
            None if self.c.is_poisoned(name) => return None,
            None => {
                if !quiet {
                    let suggestion = self.c.suggest_visible(name);
                    self.c.err(CheckError::UnknownTarget {
                        name: name.clone(),
                        span: t.name.span,
                        suggestion,
                    });
                }
                return None;
            }
        };
        let val = match rest {
            [] => val,
            [args] => self.c.index(&val, args, t.span)?,
            _ => {
                self.c.err(CheckError::Expected {
                    expected: "at most one index list after the state".into(),
                    found: "more".into(),
                    span: t.span,
                });
                return None;
            }
        };
        let comps = val
            .e
            .iter()
            .map(|&n| match self.c.dag.node(n) {
                Node::State(k) => k as usize,
                _ => usize::MAX,
            })
            .collect();
        Some(Assigned {
            comps,
            dims: val.dims(),
            key,
            indexed: !rest.is_empty(),
        })
    }

    fn flow_block(&mut self, f: &FlowBlock) {
        for s in &f.stmts {
            self.flow_stmt(s);
        }
        if let Some(set) = &f.set
            && let Some(node) = self.condition(set)
        {
            // Several `in` clauses (e.g. one per family member): C is
            // their intersection.
            self.flow_set = Some(match self.flow_set {
                Some((prev, span)) => (self.c.dag.bin(BinFn::And, prev, node), span),
                None => (node, set.span),
            });
        }
    }

    fn flow_stmt(&mut self, s: &FlowStmt) {
        match s {
            FlowStmt::For(b, body) => {
                self.c_for(b, &mut |this| {
                    for s in body {
                        this.flow_stmt(s);
                    }
                });
            }
            FlowStmt::Eq(d) => {
                let target = self.resolve_state(&d.target, false);
                let v = self.c.expr_reused(&d.value, &FLOW_CTX);
                let (Some(target), Some(v)) = (target, v) else {
                    return;
                };
                let (comps, dims) = (&target.comps, target.dims);
                if v.dims() != dims {
                    self.c.err(CheckError::AssignShape {
                        target: format!("{}'", target.display(&d.target)),
                        expected: dims,
                        found: v.dims(),
                        span: d.value.span,
                    });
                    return;
                }
                let span = d.target.span.to(d.value.span);
                for (&k, &n) in comps.iter().zip(&v.e) {
                    if let Some((_, first)) = self.flow[k] {
                        let name = self.component_name(k);
                        self.c.err(CheckError::FlowTwice {
                            name,
                            span: d.target.span,
                            first,
                        });
                        return;
                    }
                    self.flow[k] = Some((n, span));
                }
            }
        }
    }

    /// The part of a condition that is not one true/false value, to point at:
    /// the operand of `&&`, `||` or `!` that is (`x <= 0` with `x` a vector in
    /// `h <= 0 && x <= 0`), else the whole condition `e` of value `v`.
    fn culprit<'e>(&mut self, e: &'e Expr, v: Val) -> (&'e Expr, Val) {
        let parts: Vec<&Expr> = match &e.kind {
            ExprKind::Binary(BinOp::And | BinOp::Or, a, b) => vec![&**a, &**b],
            ExprKind::Unary(UnOp::Not, a) => vec![&**a],
            _ => Vec::new(),
        };
        for part in parts {
            // The whole was evaluated without error: its parts are too (same values).
            if let Some(pv) = self.c.expr(part, &GUARD_CTX)
                && (pv.rows * pv.cols != 1 || !pv.boolean)
            {
                return self.culprit(part, pv);
            }
        }
        (e, v)
    }

    fn component_name(&self, k: usize) -> String {
        for f in &self.c.fields {
            let len = f.rows * f.cols;
            if k >= f.offset && k < f.offset + len {
                let i = k - f.offset;
                return match (f.rows, f.cols) {
                    (1, 1) => f.name.clone(),
                    (_, 1) => format!("{}[{}]", f.name, i + 1),
                    (_, c) => format!("{}[{},{}]", f.name, i / c + 1, i % c + 1),
                };
            }
        }
        format!("x[{}]", k + 1)
    }

    /// For `a >= b` (`>`, `<=`, `<`) with a vector or matrix side, hybsim's
    /// spellings of "every component" (`min(x) >= 0`) and "some component"
    /// (`max(x) >= 0`), and of the conjunction.
    fn vector_comparison_help(&mut self, e: &Expr) -> Option<String> {
        if let ExprKind::Binary(op @ (BinOp::Eq | BinOp::Ne), a, b) = &e.kind {
            return self.vector_equality_help(*op, a, b);
        }
        let ExprKind::Binary(op @ (BinOp::Lt | BinOp::Le | BinOp::Gt | BinOp::Ge), a, b) = &e.kind
        else {
            return None;
        };
        let (av, bv) = (self.c.expr(a, &GUARD_CTX)?, self.c.expr(b, &GUARD_CTX)?);
        let text = |e: &Expr, v: &Val, fallback: &str| match &e.kind {
            ExprKind::Name(n) => n.clone(),
            ExprKind::Num(x) if v.rows * v.cols == 1 => crate::num::Num(*x).to_string(),
            _ => fallback.to_string(),
        };
        let op_text = op.symbol();
        // The vector side, compared with the other; `x >= 0` holds for every
        // component where the smallest one does.
        let greater = matches!(op, BinOp::Gt | BinOp::Ge);
        let first = |v: &Val| {
            if v.rows == 1 || v.cols == 1 {
                "[1]"
            } else {
                "[1, 1]"
            }
        };
        let (all, some, component) = if bv.rows * bv.cols == 1 {
            let (x, c) = (text(a, &av, "v"), text(b, &bv, "c"));
            let (lo, hi) = if greater {
                ("min", "max")
            } else {
                ("max", "min")
            };
            (
                format!("{lo}({x}) {op_text} {c}"),
                format!("{hi}({x}) {op_text} {c}"),
                format!("{x}{} {op_text} {c}", first(&av)),
            )
        } else if av.rows * av.cols == 1 {
            let (c, x) = (text(a, &av, "c"), text(b, &bv, "v"));
            let (lo, hi) = if greater {
                ("max", "min")
            } else {
                ("min", "max")
            };
            (
                format!("{c} {op_text} {lo}({x})"),
                format!("{c} {op_text} {hi}({x})"),
                format!("{c} {op_text} {x}{}", first(&bv)),
            )
        } else {
            return None;
        };
        Some(format!(
            "a condition is one true/false value: write `{all}` for every component, `{some}` \
             for some component, or join the components' conditions with `&&`: `{component} && ...`"
        ))
    }

    /// For `x == c` (`!=`) with a vector or matrix side: the components'
    /// equalities joined with `&&` (`||` for `!=`), written out for the
    /// first two components. `norm(x - c) == 0` would be the same set, but
    /// its zero is a touch, not a crossing, and would never be found along
    /// a flow.
    fn vector_equality_help(&mut self, op: BinOp, a: &Expr, b: &Expr) -> Option<String> {
        let (av, bv) = (self.c.expr(a, &GUARD_CTX)?, self.c.expr(b, &GUARD_CTX)?);
        let (v, other, vv, ov) = if av.rows * av.cols > 1 {
            (a, b, &av, &bv)
        } else {
            (b, a, &bv, &av)
        };
        let ExprKind::Name(x) = &v.kind else {
            return None;
        };
        let component = |k: usize| {
            if vv.rows == 1 || vv.cols == 1 {
                format!("{x}[{k}]")
            } else {
                format!("{x}[1, {k}]")
            }
        };
        let rhs = |k: usize| match &other.kind {
            ExprKind::Num(c) if ov.rows * ov.cols == 1 => crate::num::Num(*c).to_string(),
            ExprKind::Name(c) if ov.rows * ov.cols == 1 => c.clone(),
            ExprKind::Name(c) => format!("{c}[{k}]"),
            _ => "c".to_string(),
        };
        let (sym, join, every) = match op {
            BinOp::Eq => ("==", "&&", "every component equal"),
            _ => ("!=", "||", "some component different"),
        };
        let (x1, x2) = (component(1), component(2));
        let (c1, c2) = (rhs(1), rhs(2));
        Some(format!(
            "a condition is one true/false value: for {every}, join the components' conditions \
             with `{join}`: `{x1} {sym} {c1} {join} {x2} {sym} {c2} {join} ...`"
        ))
    }

    fn condition(&mut self, e: &Expr) -> Option<NodeId> {
        let v = self.c.expr(e, &GUARD_CTX)?;
        if v.rows * v.cols != 1 || !v.boolean {
            let (e, v) = self.culprit(e, v);
            if v.boolean
                && let Some(help) = self.vector_comparison_help(e)
            {
                self.c.err(CheckError::VectorCondition {
                    found: dims_words(v.dims()),
                    help,
                    span: e.span,
                });
                return None;
            }
            self.c.err(CheckError::Expected {
                expected: "a condition such as `h >= 0`".into(),
                found: if v.rows * v.cols == 1 {
                    "a number".into()
                } else {
                    dims_words(v.dims())
                },
                span: e.span,
            });
            return None;
        }
        Some(v.e[0])
    }

    fn jump(&mut self, j: &JumpDecl) {
        let name = match &j.name {
            Some(t) => match t.indices.as_slice() {
                [] => t.name.name.clone(),
                [args] => match self.c.family_key(args) {
                    Some(k) => format!("{}[{}]", t.name.name, key_label(&k)),
                    None => return,
                },
                _ => {
                    self.c.err(CheckError::Expected {
                        expected: "a rule name or `name[i]`".into(),
                        found: "several index lists".into(),
                        span: t.span,
                    });
                    return;
                }
            },
            None => self.anonymous.name(&j.trigger),
        };
        self.rule(name, &j.trigger, &j.resets, j.span, false);
    }

    fn rule(
        &mut self,
        name: String,
        trigger: &Trigger,
        resets: &[ResetStmt],
        span: Span,
        redraw: bool,
    ) {
        if let Some(&first) = self.rule_names.get(&name) {
            self.c.err(CheckError::Duplicate { name, span, first });
            return;
        }
        self.rule_names.insert(name.clone(), span);
        let mut assigned: HashMap<usize, Span> = HashMap::default();
        let mut out: Vec<(usize, NodeId)> = Vec::new();
        let mut spans: Vec<Span> = Vec::new();
        let (guard, timer) = match trigger {
            Trigger::When(e) => match self.condition(e) {
                Some(g) => (g, None),
                None => (self.c.dag.konst(0.0), None),
            },
            Trigger::Every(p) => {
                let Some(period) = self.c.const_scalar(p, "the period of `every`") else {
                    return;
                };
                if !(period > 0.0 && period.is_finite()) {
                    self.c.err(CheckError::Expected {
                        expected: "a finite, positive period".into(),
                        found: format!("{period}"),
                        span: p.span,
                    });
                    return;
                }
                let f = self.add_field(format!("{name}.timer"), 1, 1, span, true);
                let k = self.c.fields[f].offset;
                let zero = self.c.dag.konst(0.0);
                let one = self.c.dag.konst(1.0);
                self.init[k] = Some(zero);
                self.flow[k] = Some((one, span));
                let x = self.c.dag.state(k);
                let th = self.c.dag.konst(period);
                let g = self.c.dag.bin(BinFn::Ge, x, th);
                out.push((k, zero));
                spans.push(span);
                assigned.insert(k, span);
                (g, Some((k, period)))
            }
        };
        for r in resets {
            self.reset(&name, r, &mut assigned, &mut out, &mut spans);
        }
        if let Some(g) = self.group {
            self.check_group_resets(g, &name, &out, &assigned);
        }
        self.rules.push(CheckedRule {
            name,
            guard,
            timer,
            resets: out,
            reset_spans: spans,
            group: self.group,
            part: self.part,
            span,
            redraw,
        });
    }

    /// Two rules of one `together` group must reset disjoint components:
    /// each component of the simultaneous jump comes from one rule.
    fn check_group_resets(
        &mut self,
        g: usize,
        rule: &str,
        resets: &[(usize, NodeId)],
        spans: &HashMap<usize, Span>,
    ) {
        for &(k, _) in resets {
            let span = spans.get(&k).copied().unwrap_or_default();
            match self.group_resets[g].get(&k) {
                // Rules of one part (one instance) are alternatives: at
                // most one of them fires in a jump.
                Some((_, _, part)) if part.is_some() && *part == self.part => {}
                Some((first_rule, first, _)) => {
                    let (first_rule, first) = (first_rule.clone(), *first);
                    let name = self.component_name(k);
                    self.c.err(CheckError::GroupResetTwice {
                        name,
                        rule: rule.to_string(),
                        first_rule,
                        span,
                        first,
                    });
                    return;
                }
                None => {
                    self.group_resets[g].insert(k, (rule.to_string(), span, self.part));
                }
            }
        }
    }

    fn reset(
        &mut self,
        rule: &str,
        r: &ResetStmt,
        assigned: &mut HashMap<usize, Span>,
        out: &mut Vec<(usize, NodeId)>,
        spans: &mut Vec<Span>,
    ) {
        match r {
            ResetStmt::For(b, body) => {
                self.c_for(b, &mut |this| {
                    for r in body {
                        this.reset(rule, r, assigned, out, spans);
                    }
                });
            }
            ResetStmt::Eq(d) => {
                let target = self.resolve_state(&d.target, false);
                let v = self.c.expr_reused(&d.value, &RESET_CTX);
                let (Some(target), Some(v)) = (target, v) else {
                    return;
                };
                let (comps, dims) = (&target.comps, target.dims);
                let v = if v.dims() != dims && v.rows * v.cols == 1 {
                    Val {
                        rows: dims.0,
                        cols: dims.1,
                        e: super::expr::Elems::from_elem(v.e[0], dims.0 * dims.1),
                        boolean: v.boolean,
                    }
                } else {
                    v
                };
                if v.dims() != dims {
                    self.c.err(CheckError::AssignShape {
                        target: format!("{}+", target.display(&d.target)),
                        expected: dims,
                        found: v.dims(),
                        span: d.value.span,
                    });
                    return;
                }
                for (&k, &n) in comps.iter().zip(&v.e) {
                    if let Some(&first) = assigned.get(&k) {
                        let name = self.component_name(k);
                        self.c.err(CheckError::ResetTwice {
                            name,
                            rule: rule.to_string(),
                            span: d.target.span,
                            first,
                        });
                        return;
                    }
                    assigned.insert(k, d.target.span);
                    out.push((k, n));
                    spans.push(Span::new(d.target.span.start, d.value.span.end));
                }
            }
        }
    }

    /// The limits the model sets itself (`sim { max_states = 1e5 }`, or `--set max_states=…`),
    /// applied before anything is checked since they bound what the checker may build. Their
    /// values must be numbers (nothing else is known yet).
    fn limit_keys(&mut self, model: &Model) {
        let mut keys: Vec<(&str, &Expr, bool)> = Vec::new();
        for it in &model.items {
            if let Item::Sim(settings) = it {
                keys.extend(
                    settings
                        .iter()
                        .map(|s| (s.key.name.as_str(), &s.value, false)),
                );
            }
        }
        let overrides: Vec<&Override> = self.overrides.values().copied().collect();
        keys.extend(overrides.iter().map(|o| (o.name.as_str(), &o.expr, true)));
        for (key, e, is_override) in keys {
            let Some(q) = key
                .starts_with("max_")
                .then(|| Limits::quantity(key))
                .flatten()
            else {
                continue;
            };
            if is_override {
                self.used.push(key.to_string());
            }
            let value = match &e.kind {
                ExprKind::Num(x) if *x >= 1.0 && x.fract() == 0.0 && *x < 2f64.powi(64) => {
                    Some(*x as u64)
                }
                _ => None,
            };
            let before = self.c.errors.len();
            match value {
                Some(v) => self.c.limits.set(q, v),
                None => self.c.bad_setting(
                    key,
                    "a limit is a positive integer written as a number (e.g. 100000 or 1e5)",
                    e.span,
                ),
            }
            if is_override && let Some(o) = self.overrides.get(key).copied() {
                self.locate_in_override(before, o, true);
            }
        }
    }

    fn settings<'s>(
        &mut self,
        overrides: &'s [Override],
    ) -> (SimSettings, SolverKeys, u64, Option<bool>) {
        let mut s = SimSettings::default();
        let mut seed = 0u64;
        let mut jit = None;
        let mut solver_name: Option<(String, Span)> = None;
        let (mut rtol, mut atol, mut h) = (None, None, None);
        let mut items = std::mem::take(&mut self.sim);
        // The overrides of settings by canonical key. A name the model declares (`param T`,
        // `state h`) is that declaration's, not the setting's, which `sim.T` (or `horizon_t`)
        // still names; of several overrides of one setting (`T`, `horizon_t`) the last wins.
        let mut by_key: HashMap<&str, &'s Override> = HashMap::default();
        for o in overrides {
            if let Some((key, explicit)) = sim_key(&o.name)
                && (explicit || !self.used.contains(&o.name))
            {
                by_key.insert(key, o);
            }
        }
        // Settings given only as overrides.
        for key in SIM_KEYS {
            if let Some(o) = by_key.get(key)
                && !items.iter().any(|(k, ..)| canonical_sim_key(k) == *key)
            {
                items.push((key.to_string(), o.expr.clone(), Span::default(), None));
            }
        }
        let mut seen: HashMap<String, Span> = HashMap::default();
        // Per canonical key: where its value is, for the checks of the settings as a whole.
        let mut values: HashMap<String, (Span, Option<&Override>)> = HashMap::default();
        for (key, e, span, integer) in &items {
            if key.starts_with("max_") && Limits::quantity(key).is_some() {
                continue; // applied by `limit_keys`
            }
            let canon = canonical_sim_key(key);
            if let Some(&first) = seen.get(canon) {
                self.c.err(CheckError::SetTwice {
                    name: key.clone(),
                    span: *span,
                    first,
                });
                continue;
            }
            seen.insert(canon.to_string(), *span);
            // An override's value replaces the block's; its spans are in the override's text,
            // so the errors about it are located there.
            let ov = by_key.get(canon).copied();
            if let Some(o) = ov {
                self.used.push(o.name.clone());
            }
            let e = ov.map_or(e, |o| &o.expr);
            let integer = ov.map_or(*integer, |o| crate::syntax::ast::integer_literal(&o.value));
            values.insert(canon.to_string(), (e.span, ov));
            let before = self.c.errors.len();
            'key: {
                let bad = |this: &mut Self, reason: String| {
                    this.c.err(CheckError::BadSetting {
                        key: key.clone(),
                        reason,
                        span: e.span,
                    })
                };
                let word = match &e.kind {
                    ExprKind::Name(n) => Some(n.as_str()),
                    _ => None,
                };
                match canon {
                    "solver" => match word {
                        Some(w) => solver_name = Some((w.to_string(), e.span)),
                        None => bad(self, word_reason(canon, e)),
                    },
                    "priority" => match word {
                        Some("jumps") => s.priority = Priority::Jumps,
                        Some("flows") => s.priority = Priority::Flows,
                        Some("random") => s.priority = Priority::Random,
                        _ => bad(self, word_reason(canon, e)),
                    },
                    "jump_choice" => match word.and_then(JumpChoice::from_name) {
                        Some(c) => s.jump_choice = c,
                        None => bad(self, word_reason(canon, e)),
                    },
                    "exact_affine" => match word {
                        Some("auto") => s.exact_affine = ExactAffine::Auto,
                        Some("on") => s.exact_affine = ExactAffine::On,
                        Some("off") => s.exact_affine = ExactAffine::Off,
                        _ => bad(self, word_reason(canon, e)),
                    },
                    "linear_solver" => match word.and_then(LinearSolver::from_name) {
                        Some(l) => s.linear_solver = l,
                        None => bad(self, word_reason(canon, e)),
                    },
                    "jit" => match word {
                        Some("on") => jit = Some(true),
                        Some("off") => jit = Some(false),
                        _ => bad(self, word_reason(canon, e)),
                    },
                    // Unknown before its value is read: `tspan = [0, 10]` is not a shape error.
                    _ if !SIM_KEYS.contains(&canon) => self.c.err(CheckError::UnknownSetting {
                        name: key.clone(),
                        span: *span,
                        suggestion: suggest_sim_key(key),
                    }),
                    // HyEQ's spans [0, T] and [0, J]: the horizon is their end.
                    "T" | "J"
                        if matches!(&e.kind, ExprKind::Matrix(rows)
                            if rows.len() == 1 && rows[0].len() == 2) =>
                    {
                        bad(
                            self,
                            format!(
                                "the horizon is one number, the end of HyEQ's span [0, {canon}]: \
                                 write `{key} = ...` with that end alone"
                            ),
                        )
                    }
                    _ => {
                        // Exactly as written: an `f64` rounds seeds above 2^53.
                        if let ("seed", Some(n)) = (canon, integer) {
                            seed = n;
                            break 'key;
                        }
                        let Some(x) = self.c.const_scalar(e, &format!("`{key}`")) else {
                            break 'key;
                        };
                        match canon {
                            "T" if x > 0.0 && x.is_finite() => s.horizon_t = x,
                            // `inf`: no bound (the largest count).
                            "J" if x >= 0.0 && (x.fract() == 0.0 || x == f64::INFINITY) => {
                                s.horizon_j = x.min(u64::MAX as f64) as u64
                            }
                            "rtol" if x > 0.0 => rtol = Some(x),
                            "atol" if x > 0.0 => atol = Some(x),
                            "h" if x > 0.0 && x.is_finite() => h = Some(x),
                            "dt_out" if x > 0.0 && x.is_finite() => s.dt_out = Some(x),
                            "seed" if x >= 0.0 && x.fract() == 0.0 && x < 2f64.powi(64) => {
                                seed = x as u64
                            }
                            "max_step" if x > 0.0 => s.max_step = x,
                            "event_tol" if x >= 0.0 => s.event_tol = x,
                            "set_tol" if x >= 0.0 && x.is_finite() => s.set_tol = x,
                            "zeno_rate" if x > 0.0 => s.zeno_max_rate = x,
                            "zeno_window"
                                if x >= 2.0 && x.fract() == 0.0 && x <= u32::MAX as f64 =>
                            {
                                s.zeno_window = x as u32
                            }
                            "max_total_jumps" if x >= 1.0 && x.fract() == 0.0 => {
                                s.max_total_jumps = x.min(u64::MAX as f64) as u64
                            }
                            "zeno_window" => bad(
                                self,
                                format!("{} is not a whole number in 2..={}", Num(x), u32::MAX),
                            ),
                            "max_total_jumps" => {
                                bad(self, format!("{} is not an integer ≥ 1", Num(x)))
                            }
                            "T" | "J" | "rtol" | "atol" | "h" | "dt_out" | "seed" | "max_step"
                            | "event_tol" | "set_tol" | "zeno_rate" => bad(
                                self,
                                format!("{} is out of range: {}", Num(x), sim_range(canon)),
                            ),
                            // The keys above are every numeric one.
                            _ => self.c.err(CheckError::UnknownSetting {
                                name: key.clone(),
                                span: *span,
                                suggestion: suggest_sim_key(key),
                            }),
                        }
                    }
                }
            }
            if let Some(o) = ov {
                self.locate_in_override(before, o, true);
            }
        }
        let before_solver = self.c.errors.len();
        let noisy = self.wiener_dim > 0;
        let default_name = if noisy { "euler_maruyama" } else { "dopri5" };
        let (name, span) = solver_name.unwrap_or((default_name.into(), Span::default()));
        let (r0, a0) = match Solver::default() {
            Solver::Dopri5 { rtol, atol } | Solver::Dop853 { rtol, atol } => (rtol, atol),
            _ => (1e-6, 1e-9),
        };
        let keys = SolverKeys { rtol, atol, h };
        let (rtol, atol) = (rtol.unwrap_or(r0), atol.unwrap_or(a0));
        s.solver = match name.as_str() {
            "dopri5" => Solver::Dopri5 { rtol, atol },
            "dop853" => Solver::Dop853 { rtol, atol },
            "radau5" => Solver::Radau5 { rtol, atol },
            "bdf" => Solver::Bdf { rtol, atol },
            "auto" => Solver::Auto { rtol, atol },
            "rk4" => Solver::Rk4 {
                h: h.unwrap_or(crate::engine::DEFAULT_FIXED_STEP),
            },
            "euler_maruyama" => Solver::EulerMaruyama {
                h: h.unwrap_or(crate::engine::DEFAULT_FIXED_STEP),
            },
            other => {
                self.c.err(CheckError::BadSetting {
                    key: "solver".into(),
                    reason: format!(
                        "`{other}` is not a solver; {}",
                        word_reason(
                            "solver",
                            &Expr {
                                kind: ExprKind::Name(other.to_string()),
                                span,
                            }
                        )
                    ),
                    span,
                });
                s.solver
            }
        };
        if noisy && !matches!(s.solver, Solver::EulerMaruyama { .. }) {
            self.c.err(CheckError::BadSetting {
                key: "solver".into(),
                reason: "white noise needs `solver = euler_maruyama`".into(),
                span,
            });
        }
        if let Some(&(_, Some(o))) = values.get("solver") {
            self.locate_in_override(before_solver, o, true);
        }
        self.whole_settings(&s, &values);
        (s, keys, seed, jit)
    }

    /// The checks of the settings as a whole, located at the value of the key involved: the
    /// engine's own validation (so `check` rejects what `run` would), the smallest output and
    /// step intervals relative to the horizon, and the jump budget of a run without a Zeno guard.
    fn whole_settings(
        &mut self,
        s: &SimSettings,
        values: &HashMap<String, (Span, Option<&Override>)>,
    ) {
        let bad = |this: &mut Self, key: &str, reason: String| {
            let (span, ov) = values.get(key).copied().unwrap_or_default();
            let before = this.c.errors.len();
            this.c.err(CheckError::BadSetting {
                key: key.into(),
                reason,
                span,
            });
            if let Some(o) = ov {
                this.locate_in_override(before, o, true);
            }
        };
        if let Err(SimError::InvalidSettings { field, reason }) = s.validate() {
            let key = match field {
                "horizon_t" => "T",
                "solver.rtol" => "rtol",
                "solver.atol" => "atol",
                "solver.h" => "h",
                "zeno_max_rate" => "zeno_rate",
                f => f,
            };
            bad(self, key, reason);
            return;
        }
        // The output grid and the steps `max_step` or a fixed-step solver's `h` force, relative
        // to the horizon (`h = 1e-300` ran for ever).
        for (key, q, estimate) in super::limits::forced_sizes(s) {
            // A default `h` is located at the horizon or the solver that makes it too small.
            let (span, ov) = [key, "T", "solver"]
                .iter()
                .find_map(|k| values.get(*k))
                .copied()
                .unwrap_or_default();
            let before = self.c.errors.len();
            if !self.c.within_limit(q, estimate, span)
                && let Some(o) = ov
            {
                self.locate_in_override(before, o, true);
            }
        }
        if s.zeno_max_rate == f64::INFINITY
            && s.horizon_j == u64::MAX
            && !values.contains_key("max_total_jumps")
        {
            bad(
                self,
                "zeno_rate",
                "`zeno_rate = inf` turns the Zeno guard off: give the run an explicit jump budget (`J = ...` or `max_total_jumps = ...` in `sim`)".into(),
            );
        }
    }
}

/// Whether design statements declare results (`param` lines), at this level
/// (`deep`: also inside `for` and `if`).
fn has_results(stmts: &[DesignStmt], deep: bool) -> bool {
    stmts.iter().any(|s| match s {
        DesignStmt::Param(_) | DesignStmt::ParamTuple(..) => deep,
        DesignStmt::For(_, body) | DesignStmt::If(_, body) => has_results(body, true),
        _ => false,
    })
}

/// The names that `items` declare (parameters, graphs, tables, states,
/// noises, outputs, a design block's results), in loops and instances too:
/// made unavailable when a loop around them cannot run.
fn declared_names(items: &[Item], out: &mut Vec<String>) {
    fn design(stmts: &[DesignStmt], out: &mut Vec<String>) {
        for s in stmts {
            match s {
                DesignStmt::Param(defs) => {
                    out.extend(defs.iter().map(|d| d.target.name.name.clone()))
                }
                DesignStmt::ParamTuple(ts, _) => out.extend(ts.iter().map(|t| t.name.name.clone())),
                DesignStmt::For(_, body) | DesignStmt::If(_, body) => design(body, out),
                DesignStmt::Var(..) | DesignStmt::Objective(..) | DesignStmt::Constraint(_) => {}
            }
        }
    }
    for item in items {
        match item {
            Item::Param(defs) | Item::Output(defs) => {
                out.extend(defs.iter().map(|d| d.target.name.name.clone()));
            }
            Item::RandomParam(d) | Item::Graph(d) | Item::Signal(d) => {
                out.push(d.target.name.name.clone());
            }
            Item::ParamTuple(ts, _) => out.extend(ts.iter().map(|t| t.name.name.clone())),
            Item::Table(t) => out.push(t.name.name.clone()),
            Item::State(defs) => out.extend(defs.iter().map(|d| d.target.name.name.clone())),
            Item::Noise(n) => out.push(n.target.name.name.clone()),
            Item::Design(d) => design(&d.stmts, out),
            Item::For(_, items) | Item::Part(_, items) | Item::Together(items, _) => {
                declared_names(items, out);
            }
            Item::Flow(_)
            | Item::Jump(_)
            | Item::Sim(_)
            | Item::Property(_)
            | Item::Metric(_)
            | Item::Sweep(_)
            | Item::Import(_)
            | Item::Subsystem(_)
            | Item::Input(_)
            | Item::Instance(_)
            | Item::Log(_) => {}
        }
    }
}

/// The overrides expression `e` reads by name, as the user typed them
/// (`--set N=5`), each once, into `out`.
fn overrides_read(e: &Expr, overrides: &HashMap<&str, &Override>, out: &mut Vec<String>) {
    let mut go = |e: &Expr| overrides_read(e, overrides, out);
    match &e.kind {
        ExprKind::Name(n) => {
            if let Some(o) = overrides.get(n.as_str()) {
                let typed = format!("`{}`, set by `{}`", o.name, o.typed());
                if !out.contains(&typed) {
                    out.push(typed);
                }
            }
        }
        ExprKind::Num(_) | ExprKind::Bool(_) => {}
        ExprKind::Matrix(rows) => rows.iter().flatten().for_each(go),
        ExprKind::Unary(_, a) => go(a),
        ExprKind::Binary(_, a, b) => {
            go(a);
            go(b);
        }
        ExprKind::Call(_, args) => args.iter().for_each(go),
        ExprKind::Index(a, args) => {
            go(a);
            for arg in args {
                match arg {
                    IndexArg::One(x) => go(x),
                    IndexArg::Slice(x, y) => {
                        go(x);
                        go(y);
                    }
                    IndexArg::All(_) => {}
                }
            }
        }
        ExprKind::If(c, a, b) => {
            go(c);
            go(a);
            go(b);
        }
        ExprKind::Fold(_, _, body) => go(body),
    }
}
