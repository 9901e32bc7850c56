//! `hybsim check`: parse and check a model, report every error at once.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::Args;
use hybsim::diagnostics::{Severity, render};
use hybsim::lang;

use super::{EXIT_MODEL_ERROR, EXIT_OK};

/// Arguments of `hybsim check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// The model file (`.hyb`).
    pub model: PathBuf,
    /// Check with parameter overrides applied (`--set name=value`, repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
}

/// `hybsim check`.
pub fn execute(args: CheckArgs) -> anyhow::Result<u8> {
    let Some((src, overrides)) = super::load(&args.model, &args.set)? else {
        return Ok(EXIT_MODEL_ERROR);
    };
    let diags = lang::check_only(&src, &overrides);
    if !diags.is_empty() {
        eprint!("{}", render(&diags, &src, std::io::stderr().is_terminal()));
    }
    let errors = diags
        .iter()
        .filter(|d| d.severity == Severity::Error)
        .count();
    if errors == 0 {
        println!("{}: no errors", args.model.display());
        Ok(EXIT_OK)
    } else {
        eprintln!(
            "{}: {errors} error{}",
            args.model.display(),
            if errors == 1 { "" } else { "s" }
        );
        Ok(EXIT_MODEL_ERROR)
    }
}
