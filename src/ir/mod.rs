//! The compiled model: a checked model turned into register programs that
//! implement [`HybridSystem`].
//!
//! | piece of the model | program |
//! |---|---|
//! | flow equations (f, with noise set to 0) | `flow` |
//! | diffusion g (coefficients of the white noise) | `diffusion` |
//! | flow set C and its guard | `flow_set`, `flow_guard` |
//! | rule i: D_i, its guard, G_i | `rules[i].set`, `.guard`, `.map` |
//! | initial values, outputs | `init`, `outputs` |
//!
//! Each program runs on a thread-local register file sized once, so the hot
//! path (flow map, guards) neither allocates nor looks anything up by name.

mod analysis;
mod inputs;
mod program;
mod property;
#[cfg(test)]
mod tests;

use std::cell::RefCell;
use std::collections::HashMap;

use crate::arc::HybridTime;
use crate::check::dag::Node;
use crate::check::{CheckedModel, StateField};
use crate::diagnostics::Diagnostic;
use crate::engine::{
    FlowStructure, GuardKind, HybridSystem, JumpRule, SimError, SimRng, SimSettings,
};
use crate::layout::{Declared, Layout, Shape};
use crate::source::{SourceFile, Span};
use program::{Frame, Program};

thread_local! {
    static REGS: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
}

/// Runs `f` with a register file of at least `need` registers.
#[inline]
fn with_regs<R>(need: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    REGS.with(|cell| match cell.try_borrow_mut() {
        Ok(mut regs) => {
            if regs.len() < need {
                regs.resize(need, 0.0);
            }
            f(&mut regs)
        }
        // Re-entrant use (not expected): a private register file.
        Err(_) => f(&mut vec![0.0; need]),
    })
}

#[derive(Debug, Clone)]
struct RuleCode {
    set: Program,
    guard: Program,
    map: Program,
    /// State component of each output of `map`.
    targets: Vec<usize>,
    span: Span,
}

/// A `.hyb` model compiled for the engine. Build with
/// [`crate::lang::compile`].
#[derive(Debug, Clone)]
pub struct CompiledModel {
    name: String,
    source: SourceFile,
    frame: Frame,
    nregs: usize,
    names: Vec<String>,
    state_layout: Layout,
    output_layout: Layout,
    output_dim: usize,
    fields: Vec<StateField>,
    flow: Program,
    diffusion: Program,
    flow_set: Option<(Program, Program, Span)>,
    rules: Vec<JumpRule>,
    rule_code: Vec<RuleCode>,
    init: Program,
    outputs: Program,
    structure: FlowStructure,
    flow_spans: Vec<Option<Span>>,
    block_spans: Vec<Span>,
    settings: SimSettings,
    seed: u64,
    params: Vec<(String, (usize, usize), Vec<f64>)>,
    inputs: Vec<crate::props::Input>,
    /// How many of `inputs` (the first ones) are random parameters.
    param_inputs: usize,
    /// Draws of the initial-value stream that belong to random parameters
    /// (skipped by `start`, see [`lang::compile_run`](crate::lang::compile_run)).
    param_draws: Vec<crate::props::Dist>,
    designs: Vec<crate::check::DesignReport>,
    properties: Vec<(crate::props::Property, Span)>,
}

fn shape(rows: usize, cols: usize) -> Shape {
    match (rows, cols) {
        (1, 1) => Shape::Scalar,
        (r, 1) => Shape::Vector(r),
        (rows, cols) => Shape::Matrix { rows, cols },
    }
}

impl CompiledModel {
    /// Compiles a checked model (`source` is kept for diagnostics and logs).
    pub fn new(mut m: CheckedModel, source: SourceFile) -> Self {
        let frame = Frame {
            n: m.dim,
            m: m.wiener_dim,
        };
        // Flow: drift (noise = 0) and diffusion columns.
        let mut memo = HashMap::new();
        let drift: Vec<_> = m
            .flow
            .iter()
            .map(|&f| analysis::substitute_wiener(&mut m.dag, f, &|_| 0.0, &mut memo))
            .collect();
        let mut diff = Vec::with_capacity(m.dim * m.wiener_dim);
        for (i, &f) in m.flow.iter().enumerate() {
            for k in 0..m.wiener_dim as u32 {
                let mut memo = HashMap::new();
                let unit = move |j: u32| if j == k { 1.0 } else { 0.0 };
                let with = analysis::substitute_wiener(&mut m.dag, f, &unit, &mut memo);
                diff.push(m.dag.bin(crate::check::dag::BinFn::Sub, with, drift[i]));
            }
        }
        let structure = if m.wiener_dim == 0 {
            match analysis::affine_forms(&m.dag, &drift) {
                Some(forms) => {
                    let n = m.dim;
                    let mut a = vec![0.0; n * n];
                    let mut b = vec![0.0; n];
                    for (i, l) in forms.iter().enumerate() {
                        b[i] = l.c;
                        for &(k, v) in &l.terms {
                            a[i * n + k as usize] += v;
                        }
                    }
                    FlowStructure::Affine { a, b }
                }
                None => FlowStructure::General,
            }
        } else {
            FlowStructure::General
        };
        let flow_set = m.flow_set.map(|(cond, span)| {
            let g = analysis::guard_of(&mut m.dag, cond);
            (
                Program::compile(&m.dag, frame, &[cond]),
                Program::compile(&m.dag, frame, &[g]),
                span,
            )
        });
        let mut rules = Vec::new();
        let mut rule_code = Vec::new();
        for r in &m.rules {
            let g = analysis::guard_of(&mut m.dag, r.guard);
            let kind = match r.timer {
                Some((index, threshold)) => GuardKind::Timer { index, threshold },
                None => detect_timer(&m, r.guard).unwrap_or(GuardKind::General),
            };
            rules.push(JumpRule {
                name: r.name.clone(),
                guard: kind,
                group: r.group,
                writes: r.resets.iter().map(|&(k, _)| k).collect(),
            });
            let values: Vec<_> = r.resets.iter().map(|&(_, n)| n).collect();
            rule_code.push(RuleCode {
                set: Program::compile(&m.dag, frame, &[r.guard]),
                guard: Program::compile(&m.dag, frame, &[g]),
                map: Program::compile(&m.dag, frame, &values),
                targets: r.resets.iter().map(|&(k, _)| k).collect(),
                span: r.span,
            });
        }
        let out_nodes: Vec<_> = m.outputs.iter().flat_map(|o| o.nodes.clone()).collect();
        let flow = Program::compile(&m.dag, frame, &drift);
        let diffusion = Program::compile(&m.dag, frame, &diff);
        let init = Program::compile(&m.dag, frame, &m.init);
        let outputs = Program::compile(&m.dag, frame, &out_nodes);
        let mut nregs = [&flow, &diffusion, &init, &outputs]
            .iter()
            .map(|p| p.nregs)
            .max()
            .unwrap_or(0);
        for rc in &rule_code {
            nregs = nregs
                .max(rc.set.nregs)
                .max(rc.guard.nregs)
                .max(rc.map.nregs);
        }
        if let Some((a, b, _)) = &flow_set {
            nregs = nregs.max(a.nregs).max(b.nregs);
        }
        nregs = nregs.max(frame.fixed());
        let state_layout = state_layout(&m.fields, false);
        let (output_layout, output_dim) = output_layout(&m.outputs);
        let names = self::state_layout(&m.fields, true).flat_names(m.dim);
        let inputs = inputs::random_inputs(&m);
        let param_inputs = m.random_params.len();
        let param_draws = m.random_params.iter().map(|i| i.dist).collect();
        let properties = property::compile(&m.dag, &m.properties, m.dim, &source);
        CompiledModel {
            name: m.name,
            source,
            frame,
            nregs,
            names,
            state_layout,
            output_layout,
            output_dim,
            fields: m.fields,
            flow,
            diffusion,
            flow_set,
            rules,
            rule_code,
            init,
            outputs,
            structure,
            flow_spans: m.flow_spans,
            block_spans: m.block_spans,
            settings: m.settings,
            seed: m.seed,
            params: m.params,
            inputs,
            param_inputs,
            param_draws,
            designs: m.designs,
            properties,
        }
    }

    /// The model's name (`model NAME`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The source it was compiled from.
    pub fn source(&self) -> &SourceFile {
        &self.source
    }

    /// Simulation settings from the `sim` block after overrides.
    pub fn settings(&self) -> SimSettings {
        self.settings.clone()
    }

    /// The run's seed (`sim { seed = N }`, default 0).
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Structure of the state vector.
    pub fn state_layout(&self) -> &Layout {
        &self.state_layout
    }

    /// Structure of the output vector.
    pub fn output_layout(&self) -> &Layout {
        &self.output_layout
    }

    /// Number of output components.
    pub fn output_dim(&self) -> usize {
        self.output_dim
    }

    /// One name per output component (`e`, `err[2]`).
    pub fn output_names(&self) -> Vec<String> {
        self.output_layout.flat_names(self.output_dim)
    }

    /// Names of the jump rules, in order.
    pub fn rule_names(&self) -> Vec<String> {
        self.rules.iter().map(|r| r.name.clone()).collect()
    }

    /// Span of rule `rule`'s declaration.
    pub fn rule_span(&self, rule: usize) -> Option<Span> {
        self.rule_code.get(rule).map(|r| r.span)
    }

    /// The flow equation of state component `k`, if it has one.
    pub fn flow_span(&self, k: usize) -> Option<Span> {
        self.flow_spans.get(k).copied().flatten()
    }

    /// Number of instructions of the flow map (for benchmarks and tests).
    pub fn flow_instructions(&self) -> usize {
        self.flow.len()
    }

    /// The inputs `hybsim test` samples and `--set name=value` pins: the
    /// random parameters ([`random_params`](Self::random_params)), then the
    /// scalar states whose initial value is a draw `uniform(lo, hi)` or
    /// `normal(mean, std)` (constant arguments), each in declaration order.
    pub fn random_inputs(&self) -> &[crate::props::Input] {
        &self.inputs
    }

    /// The random parameters (`param g ~ uniform(a, b)` or `--set
    /// g=uniform(a, b)`, not pinned), in declaration order. This model
    /// gives each its distribution's centre;
    /// [`lang::compile_run`](crate::lang::compile_run) draws them.
    pub fn random_params(&self) -> &[crate::props::Input] {
        &self.inputs[..self.param_inputs]
    }

    /// Marks the random parameters of the model this one was compiled from
    /// as drawn: [`start`](Self::start) skips their draws.
    pub(crate) fn set_param_draws(&mut self, draws: Vec<crate::props::Dist>) {
        self.param_draws = draws;
    }

    /// The model's `property` declarations, in order, ready for
    /// [`props::run_tests`](crate::props::run_tests) or a
    /// [`PropertySink`](crate::props::PropertySink).
    pub fn properties(&self) -> Vec<crate::props::Property> {
        self.properties.iter().map(|(p, _)| p.clone()).collect()
    }

    /// Span of the declaration of property `name`.
    pub fn property_span(&self, name: &str) -> Option<Span> {
        self.properties
            .iter()
            .find(|(p, _)| p.name() == name)
            .map(|&(_, s)| s)
    }

    /// How every run of the model starts (`hybsim run`, `hybsim test`):
    /// the initial state, its random values drawn from
    /// [`props::input_stream(seed)`](crate::props::input_stream) (after
    /// one draw per random parameter: parameters come first, as in a
    /// `hybsim test` case), and the
    /// run's own generator `SimRng::seed_from(seed)` for everything drawn
    /// later (resets, noise, random priority). The two streams are separate,
    /// so pinning an initial value with `--set` changes no later draw.
    pub fn start(&self, seed: u64) -> (Vec<f64>, SimRng) {
        let mut inputs = crate::props::input_stream(seed);
        for d in &self.param_draws {
            d.sample(&mut inputs);
        }
        let x0 = self.initial_state(&mut inputs);
        (x0, SimRng::seed_from(seed))
    }

    /// Draws an initial state (random initial values use `rng`); runs use
    /// [`start`](Self::start).
    pub fn initial_state(&self, rng: &mut SimRng) -> Vec<f64> {
        let mut x0 = vec![0.0; self.frame.n];
        let zero = vec![0.0; self.frame.n];
        with_regs(self.nregs, |regs| {
            self.load(regs, HybridTime::new(0.0, 0), &zero);
            self.init.run(regs, Some(rng));
            for (o, &r) in x0.iter_mut().zip(&self.init.outs) {
                *o = regs[r as usize];
            }
        });
        x0
    }

    /// Evaluates the outputs at hybrid time `at` and state `x` into `out`
    /// (length [`output_dim`](Self::output_dim)).
    pub fn outputs(&self, at: HybridTime, x: &[f64], out: &mut [f64]) {
        with_regs(self.nregs, |regs| {
            self.load(regs, at, x);
            self.outputs.run(regs, None);
            for (o, &r) in out.iter_mut().zip(&self.outputs.outs) {
                *o = regs[r as usize];
            }
        });
    }

    /// The `design` blocks' reports in source order (solver figures, results).
    pub fn design_reports(&self) -> &[crate::check::DesignReport] {
        &self.designs
    }

    /// The design reports as JSON, `{block name: report}` (the MCAP metadata
    /// `hybsim.design`); `None` without `design` blocks.
    pub fn design_json(&self) -> Option<serde_json::Value> {
        if self.designs.is_empty() {
            return None;
        }
        let blocks: serde_json::Map<String, serde_json::Value> = self
            .designs
            .iter()
            .map(|d| (d.name.clone(), d.to_json()))
            .collect();
        Some(serde_json::Value::Object(blocks))
    }

    /// The resolved value of parameter `name` (after overrides and `design`
    /// blocks) as a matrix (a scalar is 1×1, a vector a column), or `None`
    /// if the model has no such parameter.
    ///
    /// ```
    /// use hybsim::{lang, source::SourceFile};
    /// let src = SourceFile::new("m.hyb", "model m\nparam K = [1, 2; 3, 4]\nstate x = 0\n");
    /// let model = lang::compile(&src, &[]).unwrap();
    /// let k = model.parameter("K").unwrap();
    /// assert_eq!((k.nrows(), k.ncols(), k[(1, 0)]), (2, 2, 3.0));
    /// assert!(model.parameter("L").is_none());
    /// ```
    pub fn parameter(&self, name: &str) -> Option<nalgebra::DMatrix<f64>> {
        self.params
            .iter()
            .find(|(n, _, _)| n == name)
            .map(|(_, (rows, cols), vals)| nalgebra::DMatrix::from_row_slice(*rows, *cols, vals))
    }

    /// Resolved parameters as JSON: `{name: number | [..] | [[..], ..]}`.
    pub fn parameters_json(&self) -> serde_json::Value {
        let mut map = serde_json::Map::new();
        for (name, (rows, cols), vals) in &self.params {
            let v = crate::num::matrix_json(*rows, *cols, vals);
            map.insert(name.clone(), v);
        }
        serde_json::Value::Object(map)
    }

    /// A diagnostic for a simulation error that points into the model: the
    /// flow equation of a component that became non-finite (or the jump
    /// whose map made it so), the flow equation of the fastest-changing
    /// component when the integrator gave up (step-size collapse,
    /// stiffness), or the matrix operation that failed, with the hybrid
    /// time.
    pub fn runtime_diagnostic(&self, err: &SimError) -> Diagnostic {
        let mut d = Diagnostic::error("E0601", err.to_string()).help(err.help());
        if let Some(origin) = program::take_fault()
            && let Some(&span) = self.block_spans.get(origin as usize)
        {
            d = d.primary(span, "this matrix was singular during the run");
        }
        if let SimError::NonFinite {
            component,
            at,
            rule: Some(rule),
            ..
        } = err
            && let Some(span) = self.rule_span(*rule)
        {
            // The jump map made it non-finite: point at the rule.
            d.code = "E0602";
            let name = self
                .state_names()
                .get(*component)
                .cloned()
                .unwrap_or_default();
            let label = format!(
                "this jump made `{name}` non-finite at (t, j) = ({}, {})",
                at.t, at.j
            );
            return if d.labels.is_empty() {
                d.primary(span, label)
            } else {
                d.secondary(span, label)
            };
        }
        if let SimError::StepSizeCollapse {
            component,
            at,
            name,
            ..
        }
        | SimError::Stiff {
            component,
            at,
            name,
            ..
        } = err
        {
            let label = format!(
                "`{name}` changes fastest here at (t, j) = ({}, {})",
                at.t, at.j
            );
            let span = self
                .flow_span(*component)
                .or_else(|| self.field_of(*component).map(|f| f.span));
            if let Some(span) = span {
                return if d.labels.is_empty() {
                    d.primary(span, label)
                } else {
                    d.secondary(span, label)
                };
            }
        }
        if let SimError::NonFinite { component, at, .. } = err {
            d.code = "E0602";
            if let Some(span) = self.flow_span(*component) {
                let label = format!("became non-finite at (t, j) = ({}, {})", at.t, at.j);
                d = if d.labels.is_empty() {
                    d.primary(span, label)
                } else {
                    d.secondary(span, label)
                };
            } else if let Some(f) = self.field_of(*component) {
                d = d.primary(f.span, "this state became non-finite");
            }
        }
        d
    }

    /// The state field holding component `k`.
    fn field_of(&self, k: usize) -> Option<&StateField> {
        self.fields
            .iter()
            .find(|f| k >= f.offset && k < f.offset + f.rows * f.cols)
    }

    #[inline]
    fn load(&self, regs: &mut [f64], at: HybridTime, x: &[f64]) {
        regs[..self.frame.n].copy_from_slice(x);
        regs[self.frame.time_reg()] = at.t;
        regs[self.frame.jumps_reg()] = at.j as f64;
    }

    #[inline]
    fn scalar(&self, p: &Program, at: HybridTime, x: &[f64]) -> f64 {
        with_regs(self.nregs, |regs| {
            self.load(regs, at, x);
            p.run(regs, None);
            regs[p.outs[0] as usize]
        })
    }
}

/// The layout of the state fields (`generated: false` leaves out the
/// timers the language adds for `every` and `noise`, which the logs do not
/// show): plain fields, and one `Family` entry per state family.
fn state_layout(fields: &[StateField], generated: bool) -> Layout {
    Layout::from_declared(
        fields
            .iter()
            .filter(|f| generated || !f.generated)
            .map(|f| Declared {
                name: &f.name,
                shape: shape(f.rows, f.cols),
                offset: f.offset,
                family: f.family.as_ref().map(|(n, l)| (n.as_str(), l.as_str())),
            }),
    )
}

/// The layout of the outputs (families grouped like state families) and
/// their total dimension.
fn output_layout(outputs: &[crate::check::OutputField]) -> (Layout, usize) {
    let mut off = 0;
    let declared: Vec<Declared> = outputs
        .iter()
        .map(|o| {
            let d = Declared {
                name: &o.name,
                shape: shape(o.rows, o.cols),
                offset: off,
                family: o.family.as_ref().map(|(n, l)| (n.as_str(), l.as_str())),
            };
            off += o.rows * o.cols;
            d
        })
        .collect();
    (Layout::from_declared(declared), off)
}

/// Errors of a checked model that need the IR's analyses: flow equations
/// in which white noise does not enter affinely (the diffusion is computed
/// as f(x, e_k) − f(x, 0), which is only right for `f(x) + G(x) w`).
pub fn structural_errors(m: &CheckedModel) -> Vec<crate::check::CheckError> {
    if m.wiener_dim == 0 {
        return Vec::new();
    }
    let forms = analysis::affine_in(&m.dag, &m.flow, analysis::Vars::Wiener);
    let mut seen = Vec::new();
    let mut errors = Vec::new();
    for (k, form) in forms.iter().enumerate() {
        if form.is_some() {
            continue;
        }
        let Some(span) = m.flow_spans[k] else {
            continue;
        };
        // One error per equation (a vector equation covers many components).
        if seen.contains(&span) {
            continue;
        }
        seen.push(span);
        let field = m
            .fields
            .iter()
            .find(|f| k >= f.offset && k < f.offset + f.rows * f.cols);
        errors.push(crate::check::CheckError::NoiseNotAffine {
            target: format!("{}'", field.map_or("x", |f| f.name.as_str())),
            span,
        });
    }
    errors
}

/// A `when` rule whose condition is `x[k] >= c` (or `<=`) for a state with
/// constant rate in the right direction is a timer.
fn detect_timer(m: &CheckedModel, cond: crate::check::dag::NodeId) -> Option<GuardKind> {
    use crate::check::dag::BinFn;
    let Node::Bin(f, a, b) = m.dag.node(cond) else {
        return None;
    };
    let Node::State(k) = m.dag.node(a) else {
        return None;
    };
    let threshold = m.dag.as_const(b)?;
    let rate = m.dag.as_const(*m.flow.get(k as usize)?)?;
    let ok = match f {
        BinFn::Ge | BinFn::Gt => rate > 0.0,
        BinFn::Le | BinFn::Lt => rate < 0.0,
        _ => false,
    };
    (ok && m.wiener_dim == 0).then_some(GuardKind::Timer {
        index: k as usize,
        threshold,
    })
}

impl HybridSystem for CompiledModel {
    fn state_dim(&self) -> usize {
        self.frame.n
    }

    fn state_names(&self) -> Vec<String> {
        self.names.clone()
    }

    fn flow_map(&self, at: HybridTime, x: &[f64], dx: &mut [f64]) {
        with_regs(self.nregs, |regs| {
            self.load(regs, at, x);
            self.flow.run(regs, None);
            for (d, &r) in dx.iter_mut().zip(&self.flow.outs) {
                *d = regs[r as usize];
            }
        });
    }

    fn flow_set(&self, at: HybridTime, x: &[f64]) -> bool {
        match &self.flow_set {
            Some((set, _, _)) => self.scalar(set, at, x) != 0.0,
            None => true,
        }
    }

    fn flow_guard(&self, at: HybridTime, x: &[f64]) -> Option<f64> {
        self.flow_set
            .as_ref()
            .map(|(_, guard, _)| self.scalar(guard, at, x))
    }

    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }

    fn jump_set(&self, rule: usize, at: HybridTime, x: &[f64]) -> bool {
        self.scalar(&self.rule_code[rule].set, at, x) != 0.0
    }

    fn jump_guard(&self, rule: usize, at: HybridTime, x: &[f64]) -> f64 {
        self.scalar(&self.rule_code[rule].guard, at, x)
    }

    fn jump_map(
        &self,
        rule: usize,
        at: HybridTime,
        x: &[f64],
        rng: &mut SimRng,
        x_plus: &mut [f64],
    ) {
        let code = &self.rule_code[rule];
        with_regs(self.nregs, |regs| {
            self.load(regs, at, x);
            code.map.run(regs, Some(rng));
            x_plus.copy_from_slice(x);
            for (&k, &r) in code.targets.iter().zip(&code.map.outs) {
                x_plus[k] = regs[r as usize];
            }
        });
    }

    fn flow_structure(&self) -> FlowStructure {
        self.structure.clone()
    }

    fn noise_dim(&self) -> usize {
        self.frame.m
    }

    fn diffusion(&self, at: HybridTime, x: &[f64], g: &mut [f64]) {
        with_regs(self.nregs, |regs| {
            self.load(regs, at, x);
            self.diffusion.run(regs, None);
            for (o, &r) in g.iter_mut().zip(&self.diffusion.outs) {
                *o = regs[r as usize];
            }
        });
    }
}
