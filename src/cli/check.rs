//! `hybsim check`: parse and check a model, report every error at once.

use std::path::PathBuf;

use clap::Args;
use hybsim::diagnostics::{Diagnostic, Severity, render, to_json};
use hybsim::lang;
use hybsim::source::SourceFile;

use super::{EXIT_MODEL_ERROR, EXIT_OK, LoadError};

/// Arguments of `hybsim check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// The model file (`.hyb`; `-` reads it from standard input).
    pub model: PathBuf,
    /// Check with parameter overrides applied (`--set name=value`, repeatable).
    #[arg(long = "set", value_name = "NAME=VALUE")]
    pub set: Vec<String>,
    /// `human` (rendered with the source line and carets, on stderr) or
    /// `json` (one JSON object per diagnostic and line on stdout, for
    /// editors' problem matchers; nothing else is printed).
    #[arg(long, value_enum, default_value_t = MessageFormat::Human)]
    pub message_format: MessageFormat,
}

/// `--message-format`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MessageFormat {
    /// Rendered for people.
    Human,
    /// One JSON object per line (see `diagnostics::to_json`).
    Json,
}

/// Prints `diags` in `format`.
fn report(diags: &[Diagnostic], src: &SourceFile, format: MessageFormat) {
    match format {
        MessageFormat::Human => {
            if !diags.is_empty() {
                eprint!("{}", render(diags, src, super::color()));
            }
        }
        MessageFormat::Json => {
            for d in diags {
                println!("{}", to_json(d, src));
            }
        }
    }
}

/// `hybsim check`.
pub fn execute(args: CheckArgs) -> anyhow::Result<u8> {
    let (src, overrides) =
        match super::read_inputs(&args.model, &super::ArgOverride::set(&args.set)) {
            Ok(loaded) => loaded,
            Err(LoadError::Unreadable(message)) => {
                match args.message_format {
                    MessageFormat::Human => eprintln!("error: {message}"),
                    MessageFormat::Json => println!(
                        "{}",
                        serde_json::json!({
                            "code": null, "severity": "error", "message": message,
                            "file": args.model.display().to_string(), "line": null,
                            "column": null, "end_line": null, "end_column": null,
                            "labels": [], "notes": [], "help": null,
                        })
                    ),
                }
                return Ok(EXIT_MODEL_ERROR);
            }
            Err(LoadError::Overrides(src, problems)) => {
                report(&problems, &src, args.message_format);
                return Ok(EXIT_MODEL_ERROR);
            }
        };
    let diags = lang::check_only(&src, &overrides);
    report(&diags, &src, args.message_format);
    let errors = diags
        .iter()
        .filter(|d| d.severity == Severity::Error)
        .count();
    let human = args.message_format == MessageFormat::Human;
    if errors == 0 {
        if human {
            // `<stdin>` for `-`, as the diagnostics name it.
            println!("{}: no errors", src.name());
        }
        Ok(EXIT_OK)
    } else {
        if human {
            eprintln!(
                "{}: {errors} error{}",
                src.name(),
                if errors == 1 { "" } else { "s" }
            );
        }
        Ok(EXIT_MODEL_ERROR)
    }
}
