//! Human-readable counterexamples and the `hybsim run` flags that replay
//! them.

use std::fmt::Write as _;

use super::monitor::{Violation, ViolationDetail};
use super::runner::{Case, Counterexample, Input};
use crate::num::Num;

/// The `hybsim run` flags that reproduce `case` exactly: `--seed`, one
/// `--set name=value` per input (values printed in Rust's shortest
/// round-trip form, so the replay is bit-exact), and `--T` / `--J` for
/// shrunk horizons.
pub fn replay_args(case: &Case, inputs: &[Input]) -> Vec<String> {
    let mut args = vec!["--seed".to_string(), case.seed.to_string()];
    for (input, value) in inputs.iter().zip(&case.values) {
        args.push("--set".into());
        args.push(format!("{}={}", input.name, fmt_value(*value)));
    }
    if let Some(t) = case.horizon_t {
        args.push("--T".into());
        args.push(fmt_value(t));
    }
    if let Some(j) = case.horizon_j {
        args.push("--J".into());
        args.push(j.to_string());
    }
    args
}

/// A value as `--set` reads it back exactly ([`Num`] is lossless).
pub(crate) fn fmt_value(v: f64) -> String {
    Num(v).to_string()
}

/// `x` with its components named; a component whose name is empty is left
/// out (see [`Subject::report_names`](super::Subject::report_names)).
fn named(names: &[String], x: &[f64]) -> String {
    x.iter()
        .enumerate()
        .filter_map(|(k, v)| match names.get(k) {
            Some(n) if n.is_empty() => None,
            Some(n) => Some(format!("{n} = {}", Num(*v))),
            None => Some(format!("x[{k}] = {}", Num(*v))),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

impl Violation {
    /// The violation over several lines, with state components named by
    /// `state_names` (those with an empty name left out).
    pub fn describe(&self, state_names: &[String]) -> String {
        self.describe_with_rules(state_names, &[])
    }

    /// As [`describe`](Self::describe), the jump rule named by `rule_names` (in rule order)
    /// instead of by its index: "(jump of rule `step`)", not "(jump of rule 0)".
    pub fn describe_with_rules(&self, state_names: &[String], rule_names: &[String]) -> String {
        let mut s = match &self.detail {
            ViolationDetail::Jump { rule, .. } if rule_names.get(*rule).is_some() => format!(
                "`{}` fails at {} (jump of rule `{}`)\n",
                self.property, self.at, rule_names[*rule]
            ),
            _ => format!("{self}\n"),
        };
        if !self.state.is_empty() {
            let side = match self.detail {
                ViolationDetail::Jump { .. } | ViolationDetail::Monotone { .. } => {
                    "state (pre-jump or later point)"
                }
                _ => "state",
            };
            let _ = writeln!(s, "  {side}: {}", named(state_names, &self.state));
        }
        if let ViolationDetail::Jump { post, .. } = &self.detail {
            let _ = writeln!(s, "  post-jump state: {}", named(state_names, post));
        }
        s
    }
}

impl Counterexample {
    /// The counterexample as a report: property, failing hybrid time and
    /// state, seed, inputs (shrunk and as sampled), and the `hybsim run`
    /// flags replaying it ([`replay_args`]).
    pub fn describe(&self, inputs: &[Input], state_names: &[String]) -> String {
        self.describe_with_rules(inputs, state_names, &[])
    }

    /// As [`describe`](Self::describe), jump rules named by `rule_names` (in rule order).
    pub fn describe_with_rules(
        &self,
        inputs: &[Input],
        state_names: &[String],
        rule_names: &[String],
    ) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "counterexample: case {} (seed {}), shrunk in {} runs",
            self.index, self.case.seed, self.shrink_runs
        );
        let _ = write!(
            s,
            "  {}",
            self.violation.describe_with_rules(state_names, rule_names)
        );
        for ((input, v), v0) in inputs
            .iter()
            .zip(&self.case.values)
            .zip(&self.original.values)
        {
            let _ = writeln!(
                s,
                "  input {} = {}  (~ {}; sampled {})",
                input.name,
                Num(*v),
                input.dist,
                Num(*v0)
            );
        }
        if let Some(t) = self.case.horizon_t {
            let _ = writeln!(s, "  horizon T = {}", Num(t));
        }
        if let Some(j) = self.case.horizon_j {
            let _ = writeln!(s, "  horizon J = {j}");
        }
        let _ = writeln!(
            s,
            "  replay flags: {}",
            replay_args(&self.case, inputs).join(" ")
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::props::Dist;

    #[test]
    fn replay_args_round_trip_values() {
        let inputs = [
            Input::new("h", Dist::Uniform { lo: 0.0, hi: 2.0 }),
            Input::new(
                "v",
                Dist::Normal {
                    mean: 0.0,
                    std: 1.0,
                },
            ),
        ];
        let case = Case {
            seed: 42,
            values: vec![1.5000000000000002, -0.1],
            horizon_t: Some(0.3),
            horizon_j: Some(2),
        };
        let args = replay_args(&case, &inputs);
        assert_eq!(
            args,
            [
                "--seed",
                "42",
                "--set",
                "h=1.5000000000000002",
                "--set",
                "v=-0.1",
                "--T",
                "0.3",
                "--J",
                "2"
            ]
        );
        assert_eq!("1.5000000000000002".parse::<f64>(), Ok(case.values[0]));
    }
}
