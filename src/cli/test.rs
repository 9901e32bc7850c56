//! `hybsim test`: sample cases of a model's random initial values, check
//! its `property` declarations on each (in parallel), shrink the first
//! failure of each failing property and print it with the `hybsim run`
//! command that replays it.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use hybsim::diagnostics::render;
use hybsim::props::{
    ModelRunError, ModelSubject, Outcome, Property, Subject, TestConfig, replay_args,
    run_tests_each,
};

use super::{EXIT_FAILED, EXIT_MODEL_ERROR, EXIT_OK, GuardArgs, SdpKind, shell_word};

/// Arguments of `hybsim test`.
#[derive(Debug, Args)]
pub struct TestArgs {
    /// The model file (`.hyb`) with `property` declarations.
    pub model: PathBuf,
    /// Number of sampled cases (≥ 1). Default: 100, or 1 for a model that
    /// draws no random number (every case would be the same run).
    #[arg(long, value_name = "N", value_parser = at_least_one)]
    pub cases: Option<usize>,
    /// Master seed from which each case's seed is derived (default: the
    /// model's `sim { seed }`).
    #[arg(long, value_name = "S", value_parser = super::parse_seed)]
    pub seed: Option<u64>,
    /// Check only this property (repeatable). Default: all.
    #[arg(long = "property", value_name = "NAME")]
    pub property: Vec<String>,
    /// Override a parameter, initial value or `sim` key, as for `hybsim run`
    /// (a pinned initial value is no longer sampled).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
    /// Interior-point method of the model's design blocks (solved per case).
    #[arg(long, value_enum, default_value_t = SdpKind::Auto)]
    pub sdp: SdpKind,
    /// Machine code for the model (`on`, default where supported) or the
    /// interpreter (`off`); overrides the model's `sim { jit = … }`.
    #[arg(long, value_enum)]
    pub jit: Option<super::JitMode>,
    /// Most runs spent shrinking a counterexample (0: no shrinking).
    #[arg(long, value_name = "N", default_value_t = 400, value_parser = count)]
    pub max_shrink: usize,
    #[command(flatten)]
    pub guard: GuardArgs,
}

/// A count of at least 1: `--cases 0` would pass vacuously.
fn at_least_one(s: &str) -> Result<usize, String> {
    match super::parse_count(s, 0) {
        Ok(0) => Err("0 cases would test nothing; give at least 1".into()),
        _ => usize::try_from(super::parse_count(s, 1)?).map_err(|e| e.to_string()),
    }
}

/// `--max-shrink`: a count, 0 included (no shrinking).
fn count(s: &str) -> Result<usize, String> {
    usize::try_from(super::parse_count(s, 0)?).map_err(|e| e.to_string())
}

/// `hybsim test`.
pub fn execute(args: TestArgs) -> anyhow::Result<u8> {
    let Some((src, mut overrides)) =
        super::load(&args.model, &args.guard.with_overrides(&args.set))?
    else {
        return Ok(EXIT_MODEL_ERROR);
    };
    super::JitMode::apply(args.jit, &mut overrides);
    let color = super::color();
    let subject = match ModelSubject::with_options(src.clone(), overrides, args.sdp.options()) {
        Ok(s) => s,
        Err(diags) => {
            eprint!("{}", render(&diags, &src, color));
            return Ok(EXIT_MODEL_ERROR);
        }
    };
    let model = subject.model();
    let all = model.properties();
    if all.is_empty() {
        eprintln!(
            "error: `{}` declares no property; add e.g. `property ground: always h >= -1e-9`",
            args.model.display()
        );
        return Ok(EXIT_MODEL_ERROR);
    }
    let mut props: Vec<Property> = Vec::new();
    for name in &args.property {
        match all.iter().find(|p| p.name() == name) {
            // `--property a --property a`: tested (and listed) once.
            Some(_) if props.iter().any(|q| q.name() == name) => {}
            Some(p) => props.push(p.clone()),
            None => {
                let names: Vec<&str> = all.iter().map(|p| p.name()).collect();
                eprintln!(
                    "error: no property `{name}` in `{}`; it declares: {}",
                    args.model.display(),
                    names.join(", ")
                );
                return Ok(EXIT_MODEL_ERROR);
            }
        }
    }
    if props.is_empty() {
        props = all;
    }
    let deterministic = args.cases.is_none() && !model.is_random();
    let cases = args.cases.unwrap_or(subject.default_cases());
    let config = TestConfig::default()
        .cases(cases)
        .seed(args.seed.unwrap_or(model.seed()))
        .max_shrink_runs(args.max_shrink);
    let inputs = subject.inputs();
    let described: Vec<String> = inputs
        .iter()
        .map(|i| format!("{} ~ {}", i.name, i.dist))
        .collect();
    println!(
        "testing {} propert{} of {} on {} (master seed {}); sampled: {}",
        props.len(),
        if props.len() == 1 { "y" } else { "ies" },
        model.name(),
        if deterministic {
            "1 case (deterministic model: no random draw, so every case is the same run)"
                .to_string()
        } else {
            format!(
                "{} case{}",
                config.cases,
                if config.cases == 1 { "" } else { "s" }
            )
        },
        config.seed,
        if described.is_empty() {
            "no named input (other random draws come from each case's seed)".to_string()
        } else {
            described.join(", ")
        }
    );
    let start = Instant::now();
    // Every failure is reported, not only the first (one pass per failing property).
    let mut remaining = props.clone();
    let (mut failed, mut errored, mut cases_run, mut inconclusive) = (0usize, false, 0, 0);
    for report in run_tests_each(&subject, &props, &config) {
        cases_run = cases_run.max(report.cases_run);
        inconclusive = inconclusive.max(report.inconclusive);
        match &report.outcome {
            Outcome::Passed => {
                for p in &remaining {
                    println!("  ok  {p}");
                }
                break;
            }
            Outcome::Failed(cx) => {
                failed += 1;
                let name = cx.violation.property.clone();
                if let Some(p) = remaining.iter().find(|p| p.name() == name) {
                    println!("FAILED  {p}");
                }
                print!(
                    "{}",
                    cx.describe_with_rules(
                        inputs,
                        &subject.report_names(),
                        &subject.model().rule_names()
                    )
                );
                let mut cmd = vec![
                    "hybsim".to_string(),
                    "run".to_string(),
                    args.model.display().to_string(),
                ];
                for o in subject.overrides() {
                    if !inputs.iter().any(|i| i.name == o.name) {
                        cmd.push("--set".into());
                        cmd.push(format!("{}={}", o.name, o.value));
                    }
                }
                cmd.extend(replay_args(&cx.case, inputs));
                if args.sdp != SdpKind::Auto {
                    let sdp = clap::ValueEnum::to_possible_value(&args.sdp).expect("not skipped");
                    cmd.extend(["--sdp".to_string(), sdp.get_name().to_string()]);
                }
                cmd.extend(["-o".to_string(), "replay.mcap".to_string()]);
                let cmd: Vec<String> = cmd.iter().map(|a| shell_word(a)).collect();
                println!("replay: {}", cmd.join(" "));
                remaining.retain(|p| p.name() != name);
                if remaining.is_empty() {
                    break;
                }
            }
            Outcome::Error { index, case, error } => {
                match error {
                    ModelRunError::Compile(diags) => eprint!("{}", render(diags, &src, color)),
                    ModelRunError::Sim(e) => {
                        eprint!("{}", render(&[model.runtime_diagnostic(e)], &src, color))
                    }
                }
                eprintln!(
                    "error: case {index} (seed {}) could not run; replay flags: {}",
                    case.seed,
                    replay_args(case, inputs).join(" ")
                );
                errored = true;
                break;
            }
        }
    }
    let verdict = match failed {
        _ if errored => "error".to_string(),
        0 => "passed".to_string(),
        1 => "counterexample".to_string(),
        n => format!("{n} counterexamples"),
    };
    println!(
        "{verdict}: {} case{}{}, {} inconclusive, {:.2} s",
        cases_run,
        if cases_run == 1 { "" } else { "s" },
        if deterministic {
            " (deterministic model)"
        } else {
            ""
        },
        inconclusive,
        start.elapsed().as_secs_f64()
    );
    Ok(match failed {
        _ if errored => EXIT_MODEL_ERROR,
        0 => EXIT_OK,
        _ => EXIT_FAILED,
    })
}

#[cfg(test)]
mod tests {
    use super::shell_word;

    #[test]
    fn shell_words_quote_only_what_needs_it() {
        assert_eq!(shell_word("h=1.5000000000000002"), "h=1.5000000000000002");
        assert_eq!(shell_word("v=-0.25"), "v=-0.25");
        assert_eq!(shell_word("K=[1, 2]"), "'K=[1, 2]'");
        assert_eq!(shell_word("a'b"), r"'a'\''b'");
    }
}
