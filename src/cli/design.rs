//! `hybsim design`: solve a model's `design` blocks and print, per block, the
//! solver's report and the resulting parameters. Nothing is simulated.

use std::path::PathBuf;

use clap::Args;
use hybsim::diagnostics::render;
use hybsim::lang::{self, DesignReport};

use super::{EXIT_FAILED, EXIT_MODEL_ERROR, EXIT_OK, SdpKind};

/// Arguments of `hybsim design`.
#[derive(Debug, Args)]
pub struct DesignArgs {
    /// The model file (`.hyb`; `-` reads it from standard input).
    pub model: PathBuf,
    /// Parameter overrides (`--set name=value`, repeatable); a design result
    /// given here replaces the computed one (a block whose results are all
    /// given is not solved).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
    /// Print the results as JSON (the `hybsim.design` metadata of a run).
    #[arg(long)]
    pub json: bool,
    /// Interior-point method of the design blocks.
    #[arg(long, value_enum, default_value_t = SdpKind::Auto)]
    pub sdp: SdpKind,
}

/// The results of a block, one line per parameter (matrices row by row).
pub fn format_results(report: &DesignReport) -> String {
    let mut out = String::new();
    for (name, (rows, cols), vals) in &report.results {
        let show = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:.6e}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        match (rows, cols) {
            (1, 1) => out.push_str(&format!("  {name} = {:.9e}\n", vals[0])),
            (_, 1) => out.push_str(&format!("  {name} = [{}]'\n", show(vals))),
            (_, 0) => out.push_str(&format!("  {name} = []\n")),
            (_, c) => {
                out.push_str(&format!("  {name} = [\n"));
                for row in vals.chunks(*c) {
                    out.push_str(&format!("    {};\n", show(row)));
                }
                out.push_str("  ]\n");
            }
        }
    }
    out
}

/// `hybsim design`.
pub fn execute(args: DesignArgs) -> anyhow::Result<u8> {
    let Some((src, overrides)) = super::load(&args.model, &super::ArgOverride::set(&args.set))?
    else {
        return Ok(EXIT_MODEL_ERROR);
    };
    let reports = match lang::design_only_with(&src, &overrides, &args.sdp.options()) {
        Ok(r) => r,
        Err(diags) => {
            eprint!("{}", render(&diags, &src, super::color()));
            return Ok(EXIT_MODEL_ERROR);
        }
    };
    // `--json` prints JSON whatever the model holds (`{}`: no block); the
    // sentence broke a reader of standard output.
    if reports.is_empty() && !args.json {
        println!("{}: no design blocks", src.name());
        return Ok(EXIT_OK);
    }
    if args.json {
        let blocks: serde_json::Map<String, serde_json::Value> = reports
            .iter()
            .map(|r| (r.name.clone(), r.to_json()))
            .collect();
        println!("{}", serde_json::to_string_pretty(&blocks)?);
        if reports.iter().any(|r| r.check_failed()) {
            return Ok(EXIT_FAILED);
        }
        return Ok(EXIT_OK);
    }
    for r in &reports {
        println!("{}", r.summary_line());
        print!("{}", format_results(r));
    }
    // A `check` without solution is a result (exit 1), not a model error.
    if reports.iter().any(|r| r.check_failed()) {
        return Ok(EXIT_FAILED);
    }
    Ok(EXIT_OK)
}
