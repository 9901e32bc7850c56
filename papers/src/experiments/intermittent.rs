//! Fig. 2 of Phillips–Erwin–Sanfelice: |e| over t for the three scenarios
//! of Example 3.8, simulated from `models/intermittent_estimation.hyb`
//! (used by `examples/intermittent_fig2.rs` and its test).

use super::{ExperimentError, compile, simulate_seeded};
use hybsim::sinks::plot::{Figure, Panel, Series};
use hybsim::source::SourceFile;

/// The scenarios of Fig. 2: letter, `--set` override, title.
pub const SCENARIOS: [(char, &str, &str); 3] = [
    ('a', "", "(a) all-to-all"),
    ('b', "cut=1", "(b) edges (2,1), (3,2) removed"),
    ('c', "blind2=1", "(c) all-to-all, H_2 = 0"),
];

/// One scenario's run.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig2Trace {
    /// `a`, `b` or `c`.
    pub letter: char,
    /// The panel title.
    pub title: &'static str,
    /// Number of jumps (transmissions) in the run.
    pub jumps: usize,
    /// `(t, |e|)` at every sample (output `enorm`).
    pub enorm: Vec<(f64, f64)>,
}

/// Runs the three scenarios of the model `src` with run seed `seed` up to
/// `t = horizon`, logging every `dt_out`.
///
/// # Errors
/// If the model does not compile or a run fails.
pub fn fig2(
    src: &SourceFile,
    seed: u64,
    horizon: f64,
    dt_out: f64,
) -> Result<Vec<Fig2Trace>, ExperimentError> {
    SCENARIOS
        .iter()
        .map(|&(letter, set, title)| {
            let t = format!("T={horizon}");
            let dt = format!("dt_out={dt_out}");
            let sets: Vec<&str> = [set, &t, &dt]
                .into_iter()
                .filter(|s| !s.is_empty())
                .collect();
            let model = compile(src, &sets)?;
            let arc = simulate_seeded(&model, seed)?;
            let k = model
                .output_names()
                .iter()
                .position(|n| n == "enorm")
                .ok_or_else(|| ExperimentError::MissingName {
                    model: model.name().to_string(),
                    name: "enorm".into(),
                })?;
            let mut y = vec![0.0; model.output_dim()];
            let enorm = arc
                .samples()
                .map(|s| {
                    model.outputs(s.at, s.x, &mut y);
                    (s.at.t, y[k])
                })
                .collect();
            Ok(Fig2Trace {
                letter,
                title,
                jumps: arc.jumps().len(),
                enorm,
            })
        })
        .collect()
}

/// The figures of Fig. 2 with their file names: `fig2a.svg`, `fig2b.svg`,
/// `fig2c.svg` (|e| on a linear axis, one scenario each, as in the paper)
/// and `fig2_log.svg` (the three on a logarithmic axis).
pub fn fig2_figures(traces: &[Fig2Trace], seed: u64) -> Vec<(String, Figure)> {
    let mut out = Vec::new();
    let mut log_panel = Panel::new(format!("|e| over t, seed {seed}"))
        .x_label("t")
        .y_label("|e|")
        .log_y(true);
    for tr in traces {
        out.push((
            format!("fig2{}.svg", tr.letter),
            Figure::new().panel(
                Panel::new(tr.title)
                    .x_label("t")
                    .y_label("|e|")
                    .series(Series::line("|e|", tr.enorm.clone())),
            ),
        ));
        log_panel = log_panel.series(Series::line(tr.title, tr.enorm.clone()));
    }
    out.push(("fig2_log.svg".into(), Figure::new().panel(log_panel)));
    out
}
