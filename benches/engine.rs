//! Engine benchmarks, each beside a hand-written reference that codes the
//! same model directly on `ode_solvers` (same solver, tolerances, flow
//! function and output: the state at every step end, every pre/post-jump
//! point kept in memory). Results and the machine are in BENCHMARKS.md.
//!
//! `cargo bench --bench engine`

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use hybsim::arc::HybridTime;
use hybsim::engine::models::{BouncingBall, SampleAndHold};
use hybsim::engine::{
    GuardKind, HybridSystem, JumpRule, SimRng, SimSettings, Solver, simulate_arc,
};
use nalgebra::{DMatrix, DVector};
use ode_solvers::{Dopri5, OutputType, System};

const RTOL: f64 = 1e-6;
const ATOL: f64 = 1e-9;

fn dopri<F: System<f64, DVector<f64>>>(
    f: F,
    d: f64,
    y: DVector<f64>,
) -> Dopri5<f64, DVector<f64>, F> {
    Dopri5::from_param(
        f,
        0.0,
        d,
        d,
        y,
        RTOL,
        ATOL,
        0.9,
        0.04,
        0.2,
        10.0,
        d,
        0.0,
        100_000,
        1000,
        OutputType::Sparse,
    )
}

/// What the references keep, as `HybridArc` does: (t, j) and the state of
/// every sample, flat, and a record (time, rule, pre, post) per jump.
#[derive(Default)]
struct Log {
    times: Vec<HybridTime>,
    states: Vec<f64>,
    jumps: Vec<(HybridTime, usize, Vec<f64>, Vec<f64>)>,
}

impl Log {
    fn push(&mut self, t: f64, j: u64, x: &[f64]) {
        self.times.push(HybridTime::new(t, j));
        self.states.extend_from_slice(x);
    }

    fn jump(&mut self, t: f64, j: u64, rule: usize, pre: &[f64], post: &[f64]) {
        self.jumps
            .push((HybridTime::new(t, j), rule, pre.to_vec(), post.to_vec()));
    }
}

// ---------------------------------------------------------------- ball --

/// Hand-written bouncing ball: watch the sign of h at step ends, localize
/// the impact on the cubic Hermite interpolant of the step by bracketed
/// Newton to 4 ulp, restart after each impact; Zeno guard as the engine's default.
struct BallFlow<'a> {
    g: f64,
    t0: f64,
    j: u64,
    log: &'a mut Log,
    prev: (f64, [f64; 2], [f64; 2]),
    event: Option<(f64, [f64; 2])>,
}

impl System<f64, DVector<f64>> for &mut BallFlow<'_> {
    fn system(&self, _s: f64, y: &DVector<f64>, dy: &mut DVector<f64>) {
        dy[0] = y[1];
        dy[1] = -self.g;
    }
    fn solout(&mut self, s: f64, y: &DVector<f64>, dy: &DVector<f64>) -> bool {
        let (s0, y0, f0) = self.prev;
        let (y1, f1) = ([y[0], y[1]], [dy[0], dy[1]]);
        if y1[0] < 0.0 && y0[0] >= 0.0 {
            let h = s - s0;
            let herm = |s: f64| {
                let th = (s - s0) / h;
                let (t2, t3) = (th * th, th * th * th);
                let mut out = [0.0; 2];
                for i in 0..2 {
                    out[i] = (2.0 * t3 - 3.0 * t2 + 1.0) * y0[i]
                        + (t3 - 2.0 * t2 + th) * h * f0[i]
                        + (-2.0 * t3 + 3.0 * t2) * y1[i]
                        + (t3 - t2) * h * f1[i];
                }
                out
            };
            // Bracketed Newton from the step end on the interpolant
            // (dh/ds = v on it), bisection when Newton leaves the bracket.
            let (mut a, mut b) = (s0, s);
            let mut m = s;
            let mut width = f64::INFINITY;
            for _ in 0..200 {
                if b - a <= 4.0 * f64::EPSILON * b {
                    break;
                }
                let y = herm(m);
                if y[0] < 0.0 {
                    b = m;
                } else {
                    a = m;
                }
                let newton = m - y[0] / y[1];
                let halved = b - a <= 0.5 * width;
                width = b - a;
                m = if halved && newton > a && newton < b {
                    newton
                } else {
                    0.5 * (a + b)
                };
                if !(m > a && m < b) {
                    break;
                }
            }
            self.event = Some((a, herm(a)));
            return true;
        }
        self.log.push(self.t0 + s, self.j, &y1);
        self.prev = (s, y1, f1);
        false
    }
}

fn reference_ball(horizon: f64) -> (u64, f64) {
    let (g, lambda) = (9.81, 0.8);
    let mut log = Log::default();
    let mut x = [1.0, 0.0];
    let (mut t, mut j) = (0.0, 0u64);
    let mut window = std::collections::VecDeque::new();
    log.push(t, j, &x);
    loop {
        let mut flow = BallFlow {
            g,
            t0: t,
            j,
            log: &mut log,
            prev: (0.0, x, [x[1], -g]),
            event: None,
        };
        let d = horizon - t;
        dopri(&mut flow, d, DVector::from_column_slice(&x))
            .integrate()
            .expect("flow");
        let Some((s, xe)) = flow.event else { break };
        t += s;
        x = xe;
        window.push_back(t);
        if window.len() > 10 {
            window.pop_front();
        }
        if window.len() == 10 && t - window[0] < 10.0 / 1e6 {
            break;
        }
        log.push(t, j, &x);
        let pre = x;
        x[1] *= -lambda;
        log.jump(t, j, 0, &pre, &x);
        j += 1;
        log.push(t, j, &x);
    }
    (j, t)
}

// ---------------------------------------------------- sample and hold --

/// The 39-state plant: 13 damped blocks [[0,1,0],[-w²,-2ζw,1],[0,0,-a]],
/// weakly coupled in a ring, 3 inputs, a small stabilizing gain.
fn plant39() -> SampleAndHold {
    let n = 39;
    let m = 3;
    let mut a = DMatrix::zeros(n, n);
    for blk in 0..13 {
        let i = 3 * blk;
        let w = 1.0 + 0.25 * blk as f64;
        a[(i, i + 1)] = 1.0;
        a[(i + 1, i)] = -w * w;
        a[(i + 1, i + 1)] = -0.4 * w;
        a[(i + 1, i + 2)] = 1.0;
        a[(i + 2, i + 2)] = -0.5 - 0.1 * blk as f64;
        let next = 3 * ((blk + 1) % 13);
        a[(i + 1, next)] = 0.05;
    }
    let mut b = DMatrix::zeros(n, m);
    let mut k = DMatrix::zeros(m, n);
    for blk in 0..13 {
        b[(3 * blk + 1, blk % m)] = 1.0;
        k[(blk % m, 3 * blk + 1)] = 0.1;
        k[(blk % m, 3 * blk)] = 0.05;
    }
    SampleAndHold::new(a, b, k, 0.02)
}

struct HoldFlow<'a> {
    sys: &'a SampleAndHold,
    t0: f64,
    j: u64,
    d: f64,
    log: &'a mut Log,
}

impl System<f64, DVector<f64>> for &mut HoldFlow<'_> {
    fn system(&self, _s: f64, y: &DVector<f64>, dy: &mut DVector<f64>) {
        self.sys.flow(y.as_slice(), dy.as_mut_slice());
    }
    fn solout(&mut self, s: f64, y: &DVector<f64>, _dy: &DVector<f64>) -> bool {
        if s < self.d {
            self.log.push(self.t0 + s, self.j, y.as_slice());
        }
        false
    }
}

/// Hand-written sampled loop on Dopri5: integrate each period, then apply
/// the sampler.
fn reference_hold(sys: &SampleAndHold, horizon: f64) -> Vec<f64> {
    let mut log = Log::default();
    let mut x = sys.initial_state(&vec![0.1; sys.n()]);
    let mut xp = x.clone();
    let mut j = 0;
    log.push(0.0, 0, &x);
    let periods = (horizon / sys.ts).round() as u64;
    for k in 0..periods {
        let t0 = k as f64 * sys.ts;
        let mut flow = HoldFlow {
            sys,
            t0,
            j,
            d: sys.ts,
            log: &mut log,
        };
        let mut st = dopri(&mut flow, sys.ts, DVector::from_column_slice(&x));
        st.integrate().expect("flow");
        x.copy_from_slice(st.y_out().last().expect("a step").as_slice());
        log.push(t0 + sys.ts, j, &x);
        sys.sample(&x, &mut xp);
        log.jump(t0 + sys.ts, j, 0, &x, &xp);
        j += 1;
        std::mem::swap(&mut x, &mut xp);
        log.push(t0 + sys.ts, j, &x);
    }
    x
}

/// Hand-written exact discretization: one matrix exponential, then one
/// matrix-vector product per period.
fn reference_hold_exact(sys: &SampleAndHold, horizon: f64) -> Vec<f64> {
    let p = (augmented_generator(sys) * sys.ts).exp();
    let d = sys.state_dim();
    let mut log = Log::default();
    let mut x = sys.initial_state(&vec![0.1; sys.n()]);
    let mut y = vec![0.0; d];
    let periods = (horizon / sys.ts).round() as u64;
    log.push(0.0, 0, &x);
    for k in 0..periods {
        let phi = p.view((0, 0), (d, d));
        let mut yv = nalgebra::DVectorViewMut::from_slice(&mut y, d);
        yv.copy_from(&p.view((0, d), (d, 1)));
        yv.gemv(1.0, &phi, &nalgebra::DVectorView::from_slice(&x, d), 1.0);
        let t = (k + 1) as f64 * sys.ts;
        log.push(t, k, &y);
        sys.sample(&y, &mut x);
        log.jump(t, k, 0, &y, &x);
        log.push(t, k + 1, &x);
    }
    x
}

/// The augmented generator [[A, b], [0, 0]] of the loop's affine flow.
fn augmented_generator(sys: &SampleAndHold) -> DMatrix<f64> {
    let d = sys.state_dim();
    let mut affine = sys.clone();
    affine.affine = true;
    let hybsim::engine::FlowStructure::Affine { a, b } = affine.flow_structure() else {
        unreachable!("SampleAndHold with affine = true reports an affine flow")
    };
    let mut gen_ = DMatrix::zeros(d + 1, d + 1);
    for r in 0..d {
        for c in 0..d {
            gen_[(r, c)] = a[r * d + c];
        }
        gen_[(r, d)] = b[r];
    }
    gen_
}

// ------------------------------------------------------------- agents --

/// Three agents with 14 states each: plant p (3), estimates of the three
/// plants (9) driven by the last transmitted outputs, held output y (1),
/// countdown timer τ (1). Agent k's rule `transmit[k]` fires when τ_k = 0:
/// y_k⁺ = C p_k, τ_k⁺ ∈ U[0.1, 0.7].
#[derive(Clone)]
struct Agents {
    ap: [[f64; 3]; 3],
    l: [f64; 3],
    rules: Vec<JumpRule>,
}

const AGENT: usize = 14;

impl Agents {
    fn new() -> Self {
        let rules = (0..3)
            .map(|k| JumpRule {
                name: format!("transmit[{k}]"),
                group: None,
                part: None,
                writes: Vec::new(),
                guard: GuardKind::Timer {
                    index: AGENT * k + 13,
                    threshold: 0.0,
                    bounds_flow: false,
                },
            })
            .collect();
        Self {
            ap: [[0.0, 1.0, 0.0], [-1.0, -0.3, 0.5], [0.0, 0.0, -0.2]],
            l: [0.8, 0.5, 0.1],
            rules,
        }
    }

    fn flow(&self, x: &[f64], dx: &mut [f64]) {
        let mv = |v: &[f64], out: &mut [f64]| {
            for (o, row) in out.iter_mut().zip(&self.ap) {
                *o = row[0] * v[0] + row[1] * v[1] + row[2] * v[2];
            }
        };
        for k in 0..3 {
            let o = AGENT * k;
            mv(&x[o..o + 3], &mut dx[o..o + 3]);
            for l in 0..3 {
                let e = o + 3 + 3 * l;
                mv(&x[e..e + 3], &mut dx[e..e + 3]);
                let innov = x[AGENT * l + 12] - x[e];
                for r in 0..3 {
                    dx[e + r] += self.l[r] * innov;
                }
            }
            dx[o + 12] = 0.0;
            dx[o + 13] = -1.0;
        }
    }

    fn transmit(&self, k: usize, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
        xp.copy_from_slice(x);
        xp[AGENT * k + 12] = x[AGENT * k];
        xp[AGENT * k + 13] = rng.uniform(0.1, 0.7);
    }

    fn initial_state() -> Vec<f64> {
        let mut x = vec![0.0; 3 * AGENT];
        for k in 0..3 {
            x[AGENT * k] = 1.0 + k as f64;
            x[AGENT * k + 13] = 0.1 * (k + 1) as f64;
        }
        x
    }
}

impl HybridSystem for Agents {
    fn state_dim(&self) -> usize {
        3 * AGENT
    }
    fn state_names(&self) -> Vec<String> {
        (0..3 * AGENT)
            .map(|i| format!("agent[{}].x[{}]", i / AGENT, i % AGENT))
            .collect()
    }
    fn flow_map(&self, _at: HybridTime, x: &[f64], dx: &mut [f64]) {
        self.flow(x, dx);
    }
    fn jump_rules(&self) -> &[JumpRule] {
        &self.rules
    }
    fn jump_set(&self, rule: usize, _at: HybridTime, x: &[f64]) -> bool {
        x[AGENT * rule + 13] <= 0.0
    }
    fn jump_guard(&self, rule: usize, _at: HybridTime, x: &[f64]) -> f64 {
        -x[AGENT * rule + 13]
    }
    fn jump_map(&self, rule: usize, _at: HybridTime, x: &[f64], rng: &mut SimRng, xp: &mut [f64]) {
        self.transmit(rule, x, rng, xp);
    }
}

struct AgentFlow<'a> {
    sys: &'a Agents,
    t0: f64,
    j: u64,
    d: f64,
    log: &'a mut Log,
}

impl System<f64, DVector<f64>> for &mut AgentFlow<'_> {
    fn system(&self, _s: f64, y: &DVector<f64>, dy: &mut DVector<f64>) {
        self.sys.flow(y.as_slice(), dy.as_mut_slice());
    }
    fn solout(&mut self, s: f64, y: &DVector<f64>, _dy: &DVector<f64>) -> bool {
        if s < self.d {
            self.log.push(self.t0 + s, self.j, y.as_slice());
        }
        false
    }
}

/// Hand-written agents: integrate to the next timer expiry (computed
/// exactly), transmit, repeat.
fn reference_agents(sys: &Agents, horizon: f64, seed: u64) -> u64 {
    let mut rng = SimRng::seed_from(seed);
    let mut log = Log::default();
    let mut x = Agents::initial_state();
    let mut xp = x.clone();
    let (mut t, mut j) = (0.0, 0u64);
    log.push(t, j, &x);
    loop {
        let (k, d) = (0..3)
            .map(|k| (k, x[AGENT * k + 13]))
            .fold((0, f64::INFINITY), |b, c| if c.1 < b.1 { c } else { b });
        let d_end = d.min(horizon - t);
        let mut flow = AgentFlow {
            sys,
            t0: t,
            j,
            d: d_end,
            log: &mut log,
        };
        let mut st = dopri(&mut flow, d_end, DVector::from_column_slice(&x));
        st.integrate().expect("flow");
        x.copy_from_slice(st.y_out().last().expect("a step").as_slice());
        t += d_end;
        if d_end < d {
            break;
        }
        x[AGENT * k + 13] = 0.0;
        log.push(t, j, &x);
        sys.transmit(k, &x, &mut rng, &mut xp);
        log.jump(t, j, k, &x, &xp);
        std::mem::swap(&mut x, &mut xp);
        j += 1;
        log.push(t, j, &x);
    }
    j
}

// ------------------------------------------------------------- benches --

fn benches(c: &mut Criterion) {
    let mut g = c.benchmark_group("engine");
    g.sample_size(10);
    let dopri5 = SimSettings::default().solver(Solver::Dopri5 {
        rtol: RTOL,
        atol: ATOL,
    });

    let ball = BouncingBall::new(9.81, 0.8);
    let s_ball = dopri5.clone().horizon_t(20.0);
    g.bench_function("bouncing_ball/hybsim", |b| {
        b.iter(|| {
            simulate_arc(
                &ball,
                black_box(&[1.0, 0.0]),
                &s_ball,
                &mut SimRng::seed_from(0),
            )
        })
    });
    g.bench_function("bouncing_ball/reference", |b| {
        b.iter(|| reference_ball(black_box(20.0)))
    });

    let hold = plant39();
    let mut hold_affine = hold.clone();
    hold_affine.affine = true;
    let x0 = hold.initial_state(&vec![0.1; hold.n()]);
    let s_hold = dopri5.clone().horizon_t(1000.0 + 0.01);
    g.bench_function("sample_and_hold_39/hybsim_dopri5", |b| {
        b.iter(|| simulate_arc(&hold, black_box(&x0), &s_hold, &mut SimRng::seed_from(0)))
    });
    g.bench_function("sample_and_hold_39/reference_dopri5", |b| {
        b.iter(|| reference_hold(&hold, black_box(1000.0)))
    });
    g.bench_function("sample_and_hold_39/hybsim_exact_affine", |b| {
        b.iter(|| {
            simulate_arc(
                &hold_affine,
                black_box(&x0),
                &s_hold,
                &mut SimRng::seed_from(0),
            )
        })
    });
    g.bench_function("sample_and_hold_39/reference_exact", |b| {
        b.iter(|| reference_hold_exact(&hold, black_box(1000.0)))
    });

    let agents = Agents::new();
    let xa = Agents::initial_state();
    let s_agents = dopri5.clone().horizon_t(1000.0);
    g.bench_function("agents_3x14/hybsim", |b| {
        b.iter(|| {
            simulate_arc(
                &agents,
                black_box(&xa),
                &s_agents,
                &mut SimRng::seed_from(1),
            )
        })
    });
    g.bench_function("agents_3x14/reference", |b| {
        b.iter(|| reference_agents(&agents, black_box(1000.0), 1))
    });
    g.finish();
}

/// Before timing: the framework and the references agree on the models.
fn agree() {
    let ball = BouncingBall::new(9.81, 0.8);
    let arc = simulate_arc(
        &ball,
        &[1.0, 0.0],
        &SimSettings::default().horizon_t(20.0),
        &mut SimRng::seed_from(0),
    )
    .expect("ball");
    let (jumps, t) = reference_ball(20.0);
    let term = arc.termination().expect("terminated");
    assert_eq!(term.at.j, jumps, "ball: jumps");
    assert!(
        (term.at.t - t).abs() < 1e-9,
        "ball: Zeno stop {} vs {t}",
        term.at.t
    );

    let hold = plant39();
    let x0 = hold.initial_state(&vec![0.1; hold.n()]);
    let arc = simulate_arc(
        &hold,
        &x0,
        &SimSettings::default().horizon_t(10.01),
        &mut SimRng::seed_from(0),
    )
    .expect("hold");
    let reference = reference_hold(&hold, 10.0);
    let last = arc.jumps().last().expect("jumps");
    let err = last
        .post
        .iter()
        .zip(&reference)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-9, "hold: {err:e}");
    let exact = reference_hold_exact(&hold, 10.0);
    let err = last
        .post
        .iter()
        .zip(&exact)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-5, "hold vs exact: {err:e}");

    let agents = Agents::new();
    let arc = simulate_arc(
        &agents,
        &Agents::initial_state(),
        &SimSettings::default().horizon_t(100.0),
        &mut SimRng::seed_from(1),
    )
    .expect("agents");
    assert_eq!(
        arc.jumps().len() as u64,
        reference_agents(&agents, 100.0, 1),
        "agents: jumps"
    );
}

fn all(c: &mut Criterion) {
    agree();
    benches(c);
}

criterion_group!(engine, all);
criterion_main!(engine);
