//! The engine's own Dormand–Prince 8(5,3) stepper (DOP853), built for
//! hybrid runs as [`Dopri5`](super::dopri5::Dopri5) is: steps one at a
//! time, reuses f at the step end as the next step's first stage (FSAL)
//! and the caller's f at a segment start, keeps the controller's step
//! proposal across segments and jumps, gives the order-7 dense output of
//! each step (three more stages, evaluated when the step's interior is
//! first read: a run that reads only step ends saves a fifth of its
//! evaluations of f), and allocates nothing after construction. Events are
//! located on that interpolant, so their times are as accurate as the
//! steps. The step loop, controller and stiffness test are
//! [`Explicit`]'s.
//!
//! Coefficients, the error estimate (the order-5 and order-3 estimates
//! combined), the controller and the stiffness test follow Hairer,
//! Nørsett & Wanner, *Solving ODEs I* (2nd ed.: DOP853 and its dense
//! output CONTD8), with the digits of Hairer's `dop853.f`. (ode_solvers'
//! `Dop853`, used before, gave `solout` only the step ends, and evaluated
//! stage 12 at the step's start instead of its end.)

// The coefficients keep the published digits, checkable against the source.
#![allow(clippy::excessive_precision)]

use super::dopri5::{NonFiniteRate, Rhs};
use super::events::{MAX_CONTROL, StepPath, bernstein_points};
use super::explicit::{Deferred, Explicit, Gains, Tableau};
use std::cell::RefCell;

// Nodes.
const C2: f64 = 0.526001519587677318785587544488e-01;
const C3: f64 = 0.789002279381515978178381316732e-01;
const C4: f64 = 0.118350341907227396726757197510e+00;
const C5: f64 = 0.281649658092772603273242802490e+00;
const C6: f64 = 0.333333333333333333333333333333e+00;
const C7: f64 = 0.25;
const C8: f64 = 0.307692307692307692307692307692e+00;
const C9: f64 = 0.651282051282051282051282051282e+00;
const C10: f64 = 0.6;
const C11: f64 = 0.857142857142857142857142857142e+00;
const C14: f64 = 0.1;
const C15: f64 = 0.2;
const C16: f64 = 0.777777777777777777777777777778e+00;
// Stages 2–12 (a_ij; the zero ones left out).
const A2_1: f64 = 5.26001519587677318785587544488e-2;
const A3_1: f64 = 1.97250569845378994544595329183e-2;
const A3_2: f64 = 5.91751709536136983633785987549e-2;
const A4_1: f64 = 2.95875854768068491816892993775e-2;
const A4_3: f64 = 8.87627564304205475450678981324e-2;
const A5_1: f64 = 2.41365134159266685502369798665e-1;
const A5_3: f64 = -8.84549479328286085344864962717e-1;
const A5_4: f64 = 9.24834003261792003115737966543e-1;
const A6_1: f64 = 3.7037037037037037037037037037e-2;
const A6_4: f64 = 1.70828608729473871279604482173e-1;
const A6_5: f64 = 1.25467687566822425016691814123e-1;
const A7_1: f64 = 3.7109375e-2;
const A7_4: f64 = 1.70252211019544039314978060272e-1;
const A7_5: f64 = 6.02165389804559606850219397283e-2;
const A7_6: f64 = -1.7578125e-2;
const A8_1: f64 = 3.70920001185047927108779319836e-2;
const A8_4: f64 = 1.70383925712239993810214054705e-1;
const A8_5: f64 = 1.07262030446373284651809199168e-1;
const A8_6: f64 = -1.53194377486244017527936158236e-2;
const A8_7: f64 = 8.27378916381402288758473766002e-3;
const A9_1: f64 = 6.24110958716075717114429577812e-1;
const A9_4: f64 = -3.36089262944694129406857109825e0;
const A9_5: f64 = -8.68219346841726006818189891453e-1;
const A9_6: f64 = 2.75920996994467083049415600797e1;
const A9_7: f64 = 2.01540675504778934086186788979e1;
const A9_8: f64 = -4.34898841810699588477366255144e1;
const A10_1: f64 = 4.77662536438264365890433908527e-1;
const A10_4: f64 = -2.48811461997166764192642586468e0;
const A10_5: f64 = -5.90290826836842996371446475743e-1;
const A10_6: f64 = 2.12300514481811942347288949897e1;
const A10_7: f64 = 1.52792336328824235832596922938e1;
const A10_8: f64 = -3.32882109689848629194453265587e1;
const A10_9: f64 = -2.03312017085086261358222928593e-2;
const A11_1: f64 = -9.3714243008598732571704021658e-1;
const A11_4: f64 = 5.18637242884406370830023853209e0;
const A11_5: f64 = 1.09143734899672957818500254654e0;
const A11_6: f64 = -8.14978701074692612513997267357e0;
const A11_7: f64 = -1.85200656599969598641566180701e1;
const A11_8: f64 = 2.27394870993505042818970056734e1;
const A11_9: f64 = 2.49360555267965238987089396762e0;
const A11_10: f64 = -3.0467644718982195003823669022e0;
const A12_1: f64 = 2.27331014751653820792359768449e0;
const A12_4: f64 = -1.05344954667372501984066689879e1;
const A12_5: f64 = -2.00087205822486249909675718444e0;
const A12_6: f64 = -1.79589318631187989172765950534e1;
const A12_7: f64 = 2.79488845294199600508499808837e1;
const A12_8: f64 = -2.85899827713502369474065508674e0;
const A12_9: f64 = -8.87285693353062954433549289258e0;
const A12_10: f64 = 1.23605671757943030647266201528e1;
const A12_11: f64 = 6.43392746015763530355970484046e-1;
// The order-8 weights of stages 1 and 6–12.
const B1: f64 = 5.42937341165687622380535766363e-2;
const B6: f64 = 4.45031289275240888144113950566e0;
const B7: f64 = 1.89151789931450038304281599044e0;
const B8: f64 = -5.8012039600105847814672114227e0;
const B9: f64 = 3.1116436695781989440891606237e-1;
const B10: f64 = -1.52160949662516078556178806805e-1;
const B11: f64 = 2.01365400804030348374776537501e-1;
const B12: f64 = 4.47106157277725905176885569043e-2;
// The order-3 embedded solution's weights of stages 1, 9 and 12 (on the
// order-8 increment).
const BHH1: f64 = 0.244094488188976377952755905512e+00;
const BHH2: f64 = 0.733846688281611857341361741547e+00;
const BHH3: f64 = 0.220588235294117647058823529412e-01;
// The order-5 error estimate's weights of stages 1 and 6–12.
const ER1: f64 = 0.1312004499419488073250102996e-01;
const ER6: f64 = -0.1225156446376204440720569753e+01;
const ER7: f64 = -0.4957589496572501915214079952e+00;
const ER8: f64 = 0.1664377182454986536961530415e+01;
const ER9: f64 = -0.3503288487499736816886487290e+00;
const ER10: f64 = 0.3341791187130174790297318841e+00;
const ER11: f64 = 0.8192320648511571246570742613e-01;
const ER12: f64 = -0.2235530786388629525884427845e-01;
// The dense output's three extra stages 14–16 (stage 13 is f at the step end).
const A14_1: f64 = 5.61675022830479523392909219681e-2;
const A14_7: f64 = 2.53500210216624811088794765333e-1;
const A14_8: f64 = -2.46239037470802489917441475441e-1;
const A14_9: f64 = -1.24191423263816360469010140626e-1;
const A14_10: f64 = 1.5329179827876569731206322685e-1;
const A14_11: f64 = 8.20105229563468988491666602057e-3;
const A14_12: f64 = 7.56789766054569976138603589584e-3;
const A14_13: f64 = -8.298e-3;
const A15_1: f64 = 3.18346481635021405060768473261e-2;
const A15_6: f64 = 2.83009096723667755288322961402e-2;
const A15_7: f64 = 5.35419883074385676223797384372e-2;
const A15_8: f64 = -5.49237485713909884646569340306e-2;
const A15_11: f64 = -1.08347328697249322858509316994e-4;
const A15_12: f64 = 3.82571090835658412954920192323e-4;
const A15_13: f64 = -3.40465008687404560802977114492e-4;
const A15_14: f64 = 1.41312443674632500278074618366e-1;
const A16_1: f64 = -4.28896301583791923408573538692e-1;
const A16_6: f64 = -4.69762141536116384314449447206e0;
const A16_7: f64 = 7.68342119606259904184240953878e0;
const A16_8: f64 = 4.06898981839711007970213554331e0;
const A16_9: f64 = 3.56727187455281109270669543021e-1;
const A16_13: f64 = -1.39902416515901462129418009734e-3;
const A16_14: f64 = 2.9475147891527723389556272149e0;
const A16_15: f64 = -9.15095847217987001081870187138e0;
/// The dense output's coefficients d_4j … d_7j of stages j = 1, 6–16.
const D: [[f64; 12]; 4] = [
    [
        -0.84289382761090128651353491142e+01,
        0.56671495351937776962531783590e+00,
        -0.30689499459498916912797304727e+01,
        0.23846676565120698287728149680e+01,
        0.21170345824450282767155149946e+01,
        -0.87139158377797299206789907490e+00,
        0.22404374302607882758541771650e+01,
        0.63157877876946881815570249290e+00,
        -0.88990336451333310820698117400e-01,
        0.18148505520854727256656404962e+02,
        -0.91946323924783554000451984436e+01,
        -0.44360363875948939664310572000e+01,
    ],
    [
        0.10427508642579134603413151009e+02,
        0.24228349177525818288430175319e+03,
        0.16520045171727028198505394887e+03,
        -0.37454675472269020279518312152e+03,
        -0.22113666853125306036270938578e+02,
        0.77334326684722638389603898808e+01,
        -0.30674084731089398182061213626e+02,
        -0.93321305264302278729567221706e+01,
        0.15697238121770843886131091075e+02,
        -0.31139403219565177677282850411e+02,
        -0.93529243588444783865713862664e+01,
        0.35816841486394083752465898540e+02,
    ],
    [
        0.19985053242002433820987653617e+02,
        -0.38703730874935176555105901742e+03,
        -0.18917813819516756882830838328e+03,
        0.52780815920542364900561016686e+03,
        -0.11573902539959630126141871134e+02,
        0.68812326946963000169666922661e+01,
        -0.10006050966910838403183860980e+01,
        0.77771377980534432092869265740e+00,
        -0.27782057523535084065932004339e+01,
        -0.60196695231264120758267380846e+02,
        0.84320405506677161018159903784e+02,
        0.11992291136182789328035130030e+02,
    ],
    [
        -0.25693933462703749003312586129e+02,
        -0.15418974869023643374053993627e+03,
        -0.23152937917604549567536039109e+03,
        0.35763911791061412378285349910e+03,
        0.93405324183624310003907691704e+02,
        -0.37458323136451633156875139351e+02,
        0.10409964950896230045147246184e+03,
        0.29840293426660503123344363579e+02,
        -0.43533456590011143754432175058e+02,
        0.96324553959188282948394950600e+02,
        -0.39177261675615439165231486172e+02,
        -0.14972683625798562581422125276e+03,
    ],
];

// Step-size controller: Hairer's DOP853 defaults (β = 0: no PI term), and
// the stiffness test's threshold.
const GAINS: Gains = Gains {
    safe: 0.9,
    beta: 0.0,
    fac_min: 0.333,
    fac_max: 6.0,
    expo: 0.125,
    stiff_hlamb: 6.1,
};

/// The engine's Dop853 stepper.
pub(crate) type Dop853 = Explicit<Dop853Tableau>;

/// Dop853's own part: the stages and the interpolant of the last accepted
/// step.
pub(crate) struct Dop853Tableau {
    /// Stages k1 (f at the step start; FSAL) … k12, k13 (f at the step
    /// end) and the dense output's k14 … k16.
    k: [Vec<f64>; 16],
    /// The dense-output polynomial of the last step: its first vector
    /// (the state at the step's start), and the other seven, the last four
    /// once the step's deferred stages are evaluated.
    y0: Vec<f64>,
    rcont: [Vec<f64>; 7],
    /// Whether the last accepted step's deferred stages are still to
    /// evaluate (on the first read of its interior).
    pending: bool,
}

impl Tableau for Dop853Tableau {
    const ORDER: i32 = 8;
    const GAINS: Gains = GAINS;
    const ATTEMPT_EVALS: u64 = 11;
    type Path<'a> = Dop853Path<'a>;

    fn new(n: usize) -> Self {
        Self {
            k: std::array::from_fn(|_| vec![0.0; n]),
            y0: vec![0.0; n],
            rcont: std::array::from_fn(|_| vec![0.0; n]),
            pending: false,
        }
    }

    fn first_stages(&mut self) -> (&mut [f64], &mut [f64]) {
        let [k1, k2, ..] = &mut self.k;
        (k1, k2)
    }

    /// The eleven stages up to the step end, the order-8 solution and
    /// Hairer's error estimate.
    fn attempt(
        &mut self,
        s: f64,
        y: &[f64],
        h: f64,
        (rtol, atol): (f64, f64),
        ys: &mut [f64],
        yn: &mut [f64],
        f: &mut Rhs<'_>,
    ) -> f64 {
        // Every vector cut to n: the loops index without bounds checks.
        let n = y.len();
        let [k1, k2, k3, k4, k5, k6, k7, k8, k9, k10, k11, k12, ..] = &mut self.k;
        let (k1, k2, k3, k4) = (&mut k1[..n], &mut k2[..n], &mut k3[..n], &mut k4[..n]);
        let (k5, k6, k7, k8) = (&mut k5[..n], &mut k6[..n], &mut k7[..n], &mut k8[..n]);
        let (k9, k10, k11, k12) = (&mut k9[..n], &mut k10[..n], &mut k11[..n], &mut k12[..n]);
        let (ys, yn) = (&mut ys[..n], &mut yn[..n]);
        for i in 0..n {
            ys[i] = y[i] + h * A2_1 * k1[i];
        }
        f(s + C2 * h, ys, k2);
        for i in 0..n {
            ys[i] = y[i] + h * (A3_1 * k1[i] + A3_2 * k2[i]);
        }
        f(s + C3 * h, ys, k3);
        for i in 0..n {
            ys[i] = y[i] + h * (A4_1 * k1[i] + A4_3 * k3[i]);
        }
        f(s + C4 * h, ys, k4);
        for i in 0..n {
            ys[i] = y[i] + h * (A5_1 * k1[i] + A5_3 * k3[i] + A5_4 * k4[i]);
        }
        f(s + C5 * h, ys, k5);
        for i in 0..n {
            ys[i] = y[i] + h * (A6_1 * k1[i] + A6_4 * k4[i] + A6_5 * k5[i]);
        }
        f(s + C6 * h, ys, k6);
        for i in 0..n {
            ys[i] = y[i] + h * (A7_1 * k1[i] + A7_4 * k4[i] + A7_5 * k5[i] + A7_6 * k6[i]);
        }
        f(s + C7 * h, ys, k7);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A8_1 * k1[i] + A8_4 * k4[i] + A8_5 * k5[i] + A8_6 * k6[i] + A8_7 * k7[i]);
        }
        f(s + C8 * h, ys, k8);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A9_1 * k1[i]
                    + A9_4 * k4[i]
                    + A9_5 * k5[i]
                    + A9_6 * k6[i]
                    + A9_7 * k7[i]
                    + A9_8 * k8[i]);
        }
        f(s + C9 * h, ys, k9);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A10_1 * k1[i]
                    + A10_4 * k4[i]
                    + A10_5 * k5[i]
                    + A10_6 * k6[i]
                    + A10_7 * k7[i]
                    + A10_8 * k8[i]
                    + A10_9 * k9[i]);
        }
        f(s + C10 * h, ys, k10);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A11_1 * k1[i]
                    + A11_4 * k4[i]
                    + A11_5 * k5[i]
                    + A11_6 * k6[i]
                    + A11_7 * k7[i]
                    + A11_8 * k8[i]
                    + A11_9 * k9[i]
                    + A11_10 * k10[i]);
        }
        f(s + C11 * h, ys, k11);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A12_1 * k1[i]
                    + A12_4 * k4[i]
                    + A12_5 * k5[i]
                    + A12_6 * k6[i]
                    + A12_7 * k7[i]
                    + A12_8 * k8[i]
                    + A12_9 * k9[i]
                    + A12_10 * k10[i]
                    + A12_11 * k11[i]);
        }
        let s_new = s + h;
        f(s_new, ys, k12);
        // The order-8 solution, and the two error estimates scaled by
        // the tolerances (Hairer's combination below).
        let incr = |i: usize| {
            B1 * k1[i]
                + B6 * k6[i]
                + B7 * k7[i]
                + B8 * k8[i]
                + B9 * k9[i]
                + B10 * k10[i]
                + B11 * k11[i]
                + B12 * k12[i]
        };
        // Component i's two error estimates over its tolerance (order 3, order 5).
        let ratios = |i: usize, incr: f64, yn: f64| {
            let sk = atol + rtol * y[i].abs().max(yn.abs());
            let e3 = incr - BHH1 * k1[i] - BHH2 * k9[i] - BHH3 * k12[i];
            let e5 = ER1 * k1[i]
                + ER6 * k6[i]
                + ER7 * k7[i]
                + ER8 * k8[i]
                + ER9 * k9[i]
                + ER10 * k10[i]
                + ER11 * k11[i]
                + ER12 * k12[i];
            (e3 / sk, e5 / sk)
        };
        let (mut err5, mut err3) = (0.0, 0.0);
        for i in 0..n {
            let incr = incr(i);
            yn[i] = y[i] + h * incr;
            let (r3, r5) = ratios(i, incr, yn[i]);
            err3 += r3 * r3;
            err5 += r5 * r5;
        }
        // err5·h·√(err5 / (err5 + 0.01·err3)) per component: the
        // order-5 estimate, kept from overestimating where the order-3
        // one is small.
        if !(err5.is_finite() && err3.is_finite()) {
            // A tolerance far below the stages' rounding (`atol = 1e-300` on a state at 0)
            // overflows the sums of squares (the norm came out NaN and every step was
            // rejected): the same norm with the largest ratio m factored out,
            // h·m·A/√((A + 0.01·B)·n) with the sums A, B of the squared ratios over m.
            let m = (0..n).fold(0.0f64, |m, i| {
                let (r3, r5) = ratios(i, incr(i), yn[i]);
                m.max(r3.abs()).max(r5.abs())
            });
            let (mut a, mut b) = (0.0, 0.0);
            for (i, &yn_i) in yn.iter().enumerate() {
                let (r3, r5) = ratios(i, incr(i), yn_i);
                a += (r5 / m) * (r5 / m);
                b += (r3 / m) * (r3 / m);
            }
            return h * m * a / ((a + 0.01 * b) * n as f64).sqrt();
        }
        let deno = err5 + 0.01 * err3;
        let deno = if deno > 0.0 { deno } else { 1.0 };
        h * err5 * (1.0 / (deno * n as f64)).sqrt()
    }

    fn non_finite(&self, s: f64, h: f64) -> Option<NonFiniteRate> {
        let c = [C2, C3, C4, C5, C6, C7, C8, C9, C10, C11, 1.0];
        c.iter()
            .zip(&self.k[1..12])
            .find_map(|(&c, k)| NonFiniteRate::find(s + c * h, k))
    }

    fn end_rate(&mut self, s_new: f64, yn: &[f64], f: &mut Rhs<'_>) -> u64 {
        f(s_new, yn, &mut self.k[12]);
        1
    }

    fn end_rates(&self) -> (&[f64], &[f64]) {
        (&self.k[12], &self.k[11])
    }

    /// Hairer's CONTD8: three more stages, then the eight vectors of the
    /// degree-7 interpolant.
    /// Hairer's CONTD8, the part from the step's ends: the first four
    /// vectors of the degree-7 interpolant. The three more stages of the
    /// other four wait for the first read of the step's interior
    /// ([`Dense::rcont`]): a run that reads only step ends (no watched
    /// guards, no dense output) does not evaluate them.
    fn dense_output(&mut self, y: &[f64], h: f64, yn: &[f64]) {
        let n = y.len();
        let (k1, k13, yn) = (&self.k[0][..n], &self.k[12][..n], &yn[..n]);
        let r1 = &mut self.y0[..n];
        let [r2, r3, r4, ..] = &mut self.rcont;
        let (r2, r3, r4) = (&mut r2[..n], &mut r3[..n], &mut r4[..n]);
        for i in 0..n {
            let ydiff = yn[i] - y[i];
            let bspl = h * k1[i] - ydiff;
            r1[i] = y[i];
            r2[i] = ydiff;
            r3[i] = bspl;
            r4[i] = ydiff - h * k13[i] - bspl;
        }
        self.pending = true;
    }

    fn start_rate(&self) -> &[f64] {
        &self.k[0]
    }

    fn fsal(&mut self) {
        self.k.swap(0, 12);
    }

    fn path<'a>(
        &'a mut self,
        (s0, h): (f64, f64),
        s1: f64,
        y1: &'a [f64],
        rest: Deferred<'a>,
    ) -> Dop853Path<'a> {
        let Self {
            k,
            y0,
            rcont,
            pending,
        } = self;
        let y0: &[f64] = y0;
        let dense = Dense {
            k,
            y0,
            rcont,
            pending,
            rest,
            s0,
            h,
        };
        Dop853Path {
            dense: RefCell::new(dense),
            y0,
            s0,
            h,
            s1,
            y1,
        }
    }
}

/// The stages and interpolant of the last accepted step, with what
/// evaluates the stages it defers.
struct Dense<'a> {
    k: &'a mut [Vec<f64>; 16],
    y0: &'a [f64],
    rcont: &'a mut [Vec<f64>; 7],
    pending: &'a mut bool,
    rest: Deferred<'a>,
    s0: f64,
    h: f64,
}

impl Dense<'_> {
    /// The interpolant's vectors after the first, the last four computed
    /// on the first call (Hairer's CONTD8: three more stages, the same as
    /// when evaluated with the step).
    #[inline]
    fn rcont(&mut self) -> &[Vec<f64>; 7] {
        if *self.pending {
            self.deferred_stages();
            *self.pending = false;
        }
        self.rcont
    }

    // Out of line: `rcont` stays a test and a load in `eval`.
    #[inline(never)]
    fn deferred_stages(&mut self) {
        let (s, h, y) = (self.s0, self.h, self.y0);
        let n = y.len();
        // After the step's FSAL swap: k1 is in k13's place and k13 in k1's.
        let [
            k13,
            _,
            _,
            _,
            _,
            k6,
            k7,
            k8,
            k9,
            k10,
            k11,
            k12,
            k1,
            k14,
            k15,
            k16,
        ] = &mut *self.k;
        let (k1, k6, k7, k8) = (&k1[..n], &k6[..n], &k7[..n], &k8[..n]);
        let (k9, k10, k11, k12, k13) = (&k9[..n], &k10[..n], &k11[..n], &k12[..n], &k13[..n]);
        let (k14, k15, k16) = (&mut k14[..n], &mut k15[..n], &mut k16[..n]);
        let (ys, f) = (&mut self.rest.ys[..n], &mut *self.rest.f);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A14_1 * k1[i]
                    + A14_7 * k7[i]
                    + A14_8 * k8[i]
                    + A14_9 * k9[i]
                    + A14_10 * k10[i]
                    + A14_11 * k11[i]
                    + A14_12 * k12[i]
                    + A14_13 * k13[i]);
        }
        f(s + C14 * h, ys, k14);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A15_1 * k1[i]
                    + A15_6 * k6[i]
                    + A15_7 * k7[i]
                    + A15_8 * k8[i]
                    + A15_11 * k11[i]
                    + A15_12 * k12[i]
                    + A15_13 * k13[i]
                    + A15_14 * k14[i]);
        }
        f(s + C15 * h, ys, k15);
        for i in 0..n {
            ys[i] = y[i]
                + h * (A16_1 * k1[i]
                    + A16_6 * k6[i]
                    + A16_7 * k7[i]
                    + A16_8 * k8[i]
                    + A16_9 * k9[i]
                    + A16_13 * k13[i]
                    + A16_14 * k14[i]
                    + A16_15 * k15[i]);
        }
        f(s + C16 * h, ys, k16);
        *self.rest.fevals += 3;
        let [_, _, _, r5, r6, r7, r8] = &mut *self.rcont;
        let (r5, r6, r7, r8) = (&mut r5[..n], &mut r6[..n], &mut r7[..n], &mut r8[..n]);
        for i in 0..n {
            let stages = [
                k1[i], k6[i], k7[i], k8[i], k9[i], k10[i], k11[i], k12[i], k13[i], k14[i], k15[i],
                k16[i],
            ];
            for (r, d) in [&mut *r5, &mut *r6, &mut *r7, &mut *r8].into_iter().zip(&D) {
                r[i] = h * d.iter().zip(&stages).map(|(d, k)| d * k).sum::<f64>();
            }
        }
    }
}

/// The order-7 dense output of one Dop853 step.
pub(crate) struct Dop853Path<'a> {
    /// In a cell: control points (through `&self`) may be the first read
    /// that evaluates the deferred stages.
    dense: RefCell<Dense<'a>>,
    /// The interpolant's first vector: the state at the step's start.
    y0: &'a [f64],
    s0: f64,
    h: f64,
    s1: f64,
    y1: &'a [f64],
}

impl Dop853Path<'_> {
    /// The state at the step's start (the interpolant's constant term).
    pub fn start(&self) -> &[f64] {
        self.y0
    }
}

impl StepPath for Dop853Path<'_> {
    fn eval(&mut self, s: f64, out: &mut [f64]) {
        if s == self.s1 {
            out.copy_from_slice(self.y1);
            return;
        }
        let th = (s - self.s0) / self.h;
        let th1 = 1.0 - th;
        let r1 = self.y0;
        let [r2, r3, r4, r5, r6, r7, r8] = self.dense.get_mut().rcont();
        for (i, o) in out.iter_mut().enumerate() {
            let inner = r5[i] + th * (r6[i] + th1 * (r7[i] + th * r8[i]));
            *o = r1[i] + th * (r2[i] + th1 * (r3[i] + th * (r4[i] + th1 * inner)));
        }
    }

    /// The degree-7 polynomial of `eval` in powers of τ = (s − s0)/(s1 − s0),
    /// then in Bernstein form.
    fn control_points(&self, i: usize, out: &mut [f64; MAX_CONTROL]) -> Option<(usize, f64)> {
        let mut dense = self.dense.borrow_mut();
        let rest = dense.rcont();
        let r: [f64; 8] = std::array::from_fn(|k| if k == 0 { self.y0[i] } else { rest[k - 1][i] });
        // `eval` nests r1 + θ(r2 + (1 − θ)(r3 + θ(… + θ·r8))): expanded from
        // the inside, in powers of θ = (s − s0)/h, into `a`; `size` the same
        // expansion of the terms' magnitudes, which bounds the rounding.
        let (mut a, mut size) = ([0.0; 8], [0.0; 8]);
        a[0] = r[7];
        size[0] = a[0].abs();
        for (deg, r_k) in r[..7].iter().rev().enumerate() {
            // r + θ·p for even r, r + (1 − θ)·p for odd r.
            let theta = (6 - deg) % 2 == 0;
            for d in (0..=deg).rev() {
                if theta {
                    (a[d + 1], a[d]) = (a[d], 0.0);
                    (size[d + 1], size[d]) = (size[d], 0.0);
                } else {
                    a[d + 1] -= a[d];
                    size[d + 1] += size[d];
                }
            }
            a[0] += r_k;
            size[0] += r_k.abs();
        }
        // θ = w·τ (w = 1 unless the step end was rounded).
        let w = (self.s1 - self.s0) / self.h;
        let (mut wk, mut bound) = (1.0, 0.0);
        for (c, m) in a.iter_mut().zip(&size) {
            *c *= wk;
            bound += m * wk.abs();
            wk *= w;
        }
        let (count, err) = bernstein_points(&a, out);
        Some((count, err.max(32.0 * f64::EPSILON * bound)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::stepper::OwnStepper;

    /// x' = x² from x(0) = 1: x(s) = 1/(1 − s).
    fn square(_: f64, y: &[f64], dy: &mut [f64]) {
        dy[0] = y[0] * y[0];
    }

    /// The tableau's consistency: each stage's weights sum to its node,
    /// the order-8 and order-3 weights to 1, the error weights to 0 (a
    /// wrong digit in a coefficient breaks one of these).
    #[test]
    fn coefficients_are_consistent() {
        let rows: [(f64, &[f64]); 14] = [
            (C2, &[A2_1]),
            (C3, &[A3_1, A3_2]),
            (C4, &[A4_1, A4_3]),
            (C5, &[A5_1, A5_3, A5_4]),
            (C6, &[A6_1, A6_4, A6_5]),
            (C7, &[A7_1, A7_4, A7_5, A7_6]),
            (C8, &[A8_1, A8_4, A8_5, A8_6, A8_7]),
            (C9, &[A9_1, A9_4, A9_5, A9_6, A9_7, A9_8]),
            (C10, &[A10_1, A10_4, A10_5, A10_6, A10_7, A10_8, A10_9]),
            (
                C11,
                &[A11_1, A11_4, A11_5, A11_6, A11_7, A11_8, A11_9, A11_10],
            ),
            (
                1.0,
                &[
                    A12_1, A12_4, A12_5, A12_6, A12_7, A12_8, A12_9, A12_10, A12_11,
                ],
            ),
            (
                C14,
                &[A14_1, A14_7, A14_8, A14_9, A14_10, A14_11, A14_12, A14_13],
            ),
            (
                C15,
                &[A15_1, A15_6, A15_7, A15_8, A15_11, A15_12, A15_13, A15_14],
            ),
            (
                C16,
                &[A16_1, A16_6, A16_7, A16_8, A16_9, A16_13, A16_14, A16_15],
            ),
        ];
        for (k, (c, a)) in rows.iter().enumerate() {
            let sum: f64 = a.iter().sum();
            assert!((sum - c).abs() < 1e-14, "row {k}: {sum} vs {c}");
        }
        let b = [B1, B6, B7, B8, B9, B10, B11, B12];
        assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-14);
        assert!((BHH1 + BHH2 + BHH3 - 1.0).abs() < 1e-14);
        let er = [ER1, ER6, ER7, ER8, ER9, ER10, ER11, ER12];
        assert!(er.iter().sum::<f64>().abs() < 1e-14);
        // The dense output is exact on a straight line (all stages equal):
        // each row of D sums to 0.
        for (r, row) in D.iter().enumerate() {
            let sum: f64 = row.iter().sum();
            assert!(sum.abs() < 1e-11, "row {r} of D: {sum}");
        }
    }

    /// Fixed steps (a tolerance that accepts any) of the oscillator
    /// y'' = −y to s = 4: halving the step divides the error at the end by
    /// about 2⁸ (order 8), and the dense output's error at the steps'
    /// midpoints by about 2⁸ too (local error O(h⁸): order 7).
    #[test]
    fn steps_are_order_8_and_the_dense_output_order_7() {
        let mut f = |_: f64, y: &[f64], dy: &mut [f64]| {
            dy[0] = y[1];
            dy[1] = -y[0];
        };
        let mut errors = |steps: u32| {
            let h = 4.0 / f64::from(steps);
            let mut st = Dop853::new(2, 1e12, 1e12);
            let mut y = vec![0.0, 1.0];
            st.set_proposal(1.0);
            st.start(&y, &[1.0, 0.0], &mut f);
            let (mut s, mut dense) = (0.0, 0.0f64);
            for k in 0..steps {
                assert_eq!(st.step(s, &y, h, &mut f), Ok(h));
                let s1 = if k + 1 == steps { 4.0 } else { s + h };
                let mut out = [0.0; 2];
                let mid = s + 0.5 * h;
                st.path(s1, &mut f).0.eval(mid, &mut out);
                dense = dense.max((out[0] - mid.sin()).abs());
                y.copy_from_slice(&st.y_new);
                s = s1;
            }
            ((y[0] - 4f64.sin()).abs(), dense)
        };
        let (e1, d1) = errors(8);
        let (e2, d2) = errors(16);
        let (step_order, dense_order) = ((e1 / e2).log2(), (d1 / d2).log2());
        assert!(e2 > 0.0 && e2 < 1e-9, "error {e2:e}");
        assert!(step_order > 7.5, "order {step_order} ({e1:e}, {e2:e})");
        assert!(
            dense_order > 7.5,
            "dense order {dense_order} ({d1:e}, {d2:e})"
        );
    }

    /// y' = -y + sin(s): steps and interpolant against the closed form,
    /// within the tolerance (the interpolant, an order below the steps,
    /// within a few times it: 2.1e-10 at most at rtol 1e-10); f at the
    /// step end reused as the next step's first stage.
    #[test]
    fn dop853_steps_and_dense_output_follow_the_solution() {
        let exact = |s: f64| 1.5 * (-s).exp() + 0.5 * (s.sin() - s.cos());
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| dy[0] = -y[0] + s.sin();
        let mut st = Dop853::new(1, 1e-10, 1e-12);
        let mut y = vec![1.0];
        let mut f0 = vec![0.0];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f);
        assert_eq!(st.fevals, 1, "the initial step's estimate");
        let mut s = 0.0;
        let mut steps = 0;
        while s < 10.0 {
            let h = st.step(s, &y, 10.0 - s, &mut f).unwrap();
            let s1 = if s + h >= 10.0 { 10.0 } else { s + h };
            let (mut p, _) = st.path(s1, &mut f);
            assert_eq!(p.start(), &y[..], "start of the step at {s}");
            let mut out = [0.0];
            p.eval(s, &mut out);
            assert_eq!(out, y[..], "the interpolant at {s}");
            for k in 1..8 {
                let sm = s + (s1 - s) * k as f64 / 8.0;
                p.eval(sm, &mut out);
                assert!((out[0] - exact(sm)).abs() < 1e-9, "at {sm}");
            }
            y.copy_from_slice(&st.y_new);
            s = s1;
            steps += 1;
        }
        assert!((y[0] - exact(10.0)).abs() < 1e-10);
        assert!(steps < 100, "{steps} steps");
        // FSAL: 15 evaluations per accepted step whose interior is read (11
        // stages, f at the end, 3 for the dense output), 11 per rejected
        // attempt, plus the initial estimate's one.
        let rejected = (st.fevals - 1 - 15 * steps as u64) / 11;
        assert_eq!(st.fevals, 1 + 15 * steps as u64 + 11 * rejected);
        assert!(rejected <= 3, "{rejected} rejected attempts");
    }

    /// The dense output's three extra stages wait for the first read of
    /// the step's interior: 12 evaluations of f per accepted step (11 per
    /// rejected attempt) while only its end is read, 3 more at the first
    /// interior read, none at later ones; the interpolant is the same at
    /// every read.
    #[test]
    fn the_dense_stages_are_evaluated_at_the_first_interior_read() {
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| dy[0] = -y[0] + s.sin();
        let mut st = Dop853::new(1, 1e-10, 1e-12);
        let mut y = vec![1.0];
        st.start(&y, &[-1.0], &mut f);
        let (mut s, mut fevals) = (0.0, st.fevals);
        for _ in 0..5 {
            let h = st.step(s, &y, 10.0, &mut f).unwrap();
            let attempts = st.fevals - fevals - 1;
            assert_eq!(attempts % 11, 0, "{attempts} evaluations in attempts");
            fevals = st.fevals;
            let (mut p, y1) = st.path(s + h, &mut f);
            let mut end = [0.0];
            p.eval(s + h, &mut end);
            assert_eq!(end, y1);
            assert_eq!(st.fevals, fevals, "the step's end");
            let mid = s + 0.5 * h;
            let (mut first, mut again) = ([0.0], [0.0]);
            st.path(s + h, &mut f).0.eval(mid, &mut first);
            assert_eq!(st.fevals, fevals + 3, "the first interior read");
            let mut p = st.path(s + h, &mut f).0;
            p.eval(mid, &mut again);
            let mut points = [0.0; MAX_CONTROL];
            assert!(p.control_points(0, &mut points).is_some());
            assert_eq!((st.fevals, first), (fevals + 3, again), "later reads");
            fevals = st.fevals;
            y.copy_from_slice(&st.y_new);
            s += h;
        }
    }

    /// The step proposal is carried: a new segment (after a jump) starts
    /// from it without a new estimate, and lowered by `limit_proposal`.
    #[test]
    fn the_step_proposal_is_carried_across_segments() {
        let mut st = Dop853::new(1, 1e-8, 1e-10);
        let (y, f0) = ([1.0], [1.0]);
        st.start(&y, &f0, &mut square);
        let h = st.step(0.0, &y, 0.5, &mut square).unwrap();
        let (proposal, fevals) = (st.proposal(), st.fevals);
        assert!(proposal > 0.0 && h > 0.0);
        st.start(&y, &f0, &mut square);
        assert_eq!((st.proposal(), st.fevals), (proposal, fevals));
        st.limit_proposal(0.5 * proposal);
        assert_eq!(st.proposal(), 0.5 * proposal);
        // A step cut short by h_max keeps the controller's proposal.
        let h_max = 0.1 * st.proposal();
        assert_eq!(st.step(0.0, &y, h_max, &mut square), Ok(h_max));
        assert!(st.proposal() >= 0.5 * proposal);
    }

    /// The control points of a step's degree-7 polynomial give back its
    /// values within their error bound, also when the step end is not
    /// s0 + h (rounded to a segment end).
    #[test]
    fn control_points_give_the_dense_output() {
        let mut f = |s: f64, y: &[f64], dy: &mut [f64]| {
            dy[0] = y[1];
            dy[1] = -y[0].sin() + 0.3 * s.cos();
        };
        let mut st = Dop853::new(2, 1e-6, 1e-8);
        let y = vec![1.0, -0.5];
        let mut f0 = vec![0.0; 2];
        f(0.0, &y, &mut f0);
        st.start(&y, &f0, &mut f);
        let h = st.step(0.0, &y, 10.0, &mut f).unwrap();
        for s1 in [h, 0.9 * h] {
            let mut p = st.path(s1, &mut f).0;
            crate::engine::events::tests::assert_control_points(&mut p, 2, (0.0, s1), 8);
        }
    }
}
