//! `hybsim plot`: HyEQ's plots of a run read back from its MCAP file, drawn
//! by the same sink as `hybsim run --plot` (fed from the file instead of
//! the engine).

use std::path::{Path, PathBuf};

use clap::Args;
use hybsim::atomic_file;
use hybsim::sinks::mcap_read::RunLog;
use hybsim::sinks::plot::{ImageFormat, PlotSink};

use super::run::{PlotKindArg, split_names, unknown_plot_var};
use super::{EXIT_MODEL_ERROR, EXIT_OK};

/// Arguments of `hybsim plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// The MCAP file of a run (`-` reads it from standard input).
    pub file: PathBuf,
    /// What to draw (HyEQ's kinds): components against t (`flows`) or
    /// against j (`jumps`), over (t, j) in 3-D (`hybrid`), the second
    /// selected component against the first (`phase`), or the hybrid time
    /// domain (`domain`).
    #[arg(long, value_enum, default_value_t = PlotKindArg::Flows)]
    pub kind: PlotKindArg,
    /// States or outputs to draw, comma-separated, by the model's names: an
    /// entry (`h`, `err`), a whole family (`xhat`) or one member (`xhat[2]`).
    /// Default: the logged states (its outputs if it logged no state).
    #[arg(long, value_name = "NAMES")]
    pub vars: Option<String>,
    /// The image: `.svg` or `.png` by its extension (`-`: SVG on standard
    /// output). Default: the file's name with `.svg`, in the current
    /// directory.
    #[arg(short = 'o', long = "output", value_name = "OUT.svg|OUT.png")]
    pub output: Option<PathBuf>,
}

/// Default image path: the MCAP file's name with `.svg`, in the current directory.
fn default_output(file: &Path) -> PathBuf {
    let stem = file
        .file_stem()
        .filter(|_| file != Path::new("-"))
        .map(|s| s.to_os_string())
        .unwrap_or_else(|| "stdin".into());
    PathBuf::from(stem).with_extension("svg")
}

/// `hybsim plot`. A file that cannot be read back (truncated, empty,
/// foreign, damaged), an unknown name or kind that cannot draw the
/// selection, and an unknown image extension exit 2.
pub fn execute(args: PlotArgs) -> anyhow::Result<u8> {
    let usage = |message: String| {
        eprintln!("error: {message}");
        Ok(EXIT_MODEL_ERROR)
    };
    let output = args
        .output
        .clone()
        .unwrap_or_else(|| default_output(&args.file));
    if let Err(e) = ImageFormat::of(&output) {
        return usage(e.to_string());
    }
    let input: &[(&str, &Path)] = if args.file == Path::new("-") {
        &[]
    } else {
        &[("the MCAP file", args.file.as_path())]
    };
    if let Some(message) = atomic_file::clash(input, &[("-o", output.as_path())]) {
        return usage(message);
    }
    let bytes = match super::read_mcap_input(&args.file) {
        Ok(b) => b,
        Err(e) => return usage(format!("cannot read `{}`: {e}", args.file.display())),
    };
    let log = match RunLog::read(&bytes) {
        Ok(log) => log,
        Err(e) => return usage(format!("`{}`: {e}", args.file.display())),
    };
    let vars = args.vars.as_deref().map(split_names).unwrap_or_default();
    for name in &vars {
        if let Some(message) = unknown_plot_var("--vars", name, &log.info) {
            return usage(format!(
                "{message}; `{}` logged these (a `log` block or `--log-vars` may have left others out)",
                args.file.display()
            ));
        }
    }
    let kind = args.kind.into();
    if let Err(e) = PlotSink::check_selection(&log.info, &vars, kind) {
        let info = &log.info;
        let empty = info.state_layout.entries.is_empty() && info.output_layout.entries.is_empty();
        return usage(match empty {
            false => e.to_string(),
            true => format!(
                "{e}; `{}` logged no state or output (a `log` block or `--log-vars` left them out): only `--kind domain` can be drawn from it",
                args.file.display()
            ),
        });
    }
    let mut plot = PlotSink::for_log(&output, &log.info, &vars)?.kind(kind)?;
    if let Err(e) = log.replay(&bytes, |at, kind, x, y| plot.push_logged(at, kind, x, y)) {
        return usage(format!("`{}`: {e}", args.file.display()));
    }
    let written = plot.finish()?;
    if written != Path::new("-") {
        eprintln!("wrote {}", written.display());
    }
    Ok(EXIT_OK)
}
