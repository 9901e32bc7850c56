//! The `hybsim` command line: clap arguments, one file per subcommand, and
//! the mapping of outcomes to exit codes (the binary edge: errors here are
//! `anyhow`, everything below is typed).

mod check;
mod design;
mod fmt;
mod info;
mod plot;
mod progress;
mod run;
mod sweep;
mod test;

use std::ffi::OsString;
use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};
use hybsim::diagnostics::render;
use hybsim::lang::{Backend, CheckOptions, Override};
use hybsim::source::SourceFile;

/// Exit code: the command did what was asked (a run reached its end, a
/// check found no error).
pub const EXIT_OK: u8 = 0;
/// Exit code: the run failed (engine error, non-finite value, output not
/// written) or a property test found a counterexample.
pub const EXIT_FAILED: u8 = 1;
/// Exit code: the model has errors (syntax, names, shapes, a bad `--set`),
/// or the command line is malformed.
pub const EXIT_MODEL_ERROR: u8 = 2;
/// Exit code: interrupted with Ctrl-C, SIGTERM or SIGHUP (the output files are still completed).
pub const EXIT_INTERRUPTED: u8 = 130;

const EXAMPLES: &str = "\
Examples:
  hybsim run models/bouncing_ball.hyb                 simulate, write bouncing_ball.mcap
  hybsim run models/bouncing_ball.hyb -o ball.mcap --T 5 --J 30 --seed 1
  hybsim run models/bouncing_ball.hyb --set lambda=0.5 --csv ball.csv --plot ball.svg
  hybsim run models/bouncing_ball.hyb --no-mcap --plot ball.svg --plot-vars h,v
  hybsim plot ball.mcap --kind hybrid --vars h -o ball.png   plot a logged run
  hybsim check models/bouncing_ball.hyb               check the model only
  hybsim design models/platoon.hyb                    solve the design blocks, print the results
  hybsim test models/bouncing_ball.hyb --cases 500    check its `property` declarations
  hybsim sweep models/bouncing_ball.hyb --grid lambda=0.5:0.1:0.9 --runs 10 -o ball_sweep

Exit codes:
  0    success (a run ended: horizon reached, or an outcome such as Zeno suspected)
  1    the run failed (engine error, non-finite value, output file not written),
       or `hybsim test` found a counterexample
  2    the model has errors, or the command line is malformed
  130  interrupted (Ctrl-C, SIGTERM, SIGHUP); output files are completed up to that point";

/// Simulate, design and test hybrid dynamical systems written in `.hyb`.
#[derive(Debug, Parser)]
#[command(name = "hybsim", version, about, after_help = EXAMPLES)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
    /// Colour in diagnostics: `auto` (when stderr is a terminal and
    /// `NO_COLOR` is not set), `always` or `never`.
    #[arg(long, global = true, value_enum, default_value_t = ColorChoice::Auto)]
    pub color: ColorChoice,
}

/// `--color`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ColorChoice {
    /// Colour when stderr is a terminal and `NO_COLOR` is unset or empty.
    #[default]
    Auto,
    /// Always colour.
    Always,
    /// Never colour.
    Never,
}

/// The process's `--color` choice, set once by [`run`].
static COLOR: std::sync::OnceLock<ColorChoice> = std::sync::OnceLock::new();

/// Whether diagnostics on stderr are coloured (see [`ColorChoice`]).
pub fn color() -> bool {
    match COLOR.get().copied().unwrap_or_default() {
        ColorChoice::Always => true,
        ColorChoice::Never => false,
        ColorChoice::Auto => {
            std::io::IsTerminal::is_terminal(&std::io::stderr())
                && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty())
        }
    }
}

/// The subcommands.
#[derive(Debug, Subcommand)]
#[allow(clippy::large_enum_variant)] // built once per process
pub enum Command {
    /// Simulate a model and log the solution (MCAP by default; CSV and SVG on request).
    // Negative numbers are values (`--T -1` is refused by the checker as
    // a bad `T`, not by clap as an unknown flag `-1`).
    #[command(after_help = EXAMPLES, allow_negative_numbers = true)]
    Run(run::RunArgs),
    /// Parse and check a model without simulating it.
    Check(check::CheckArgs),
    /// Solve the model's `design` blocks and print their reports and results.
    Design(design::DesignArgs),
    /// Check the model's `property` declarations on sampled cases; shrink and
    /// print the first counterexample with a command that replays it.
    #[command(allow_negative_numbers = true)]
    Test(test::TestArgs),
    /// Run a grid of parameter values × seeded runs and collect the model's
    /// metrics (per run and per grid point; CSV and SVG); `--shard k/n` runs a
    /// part, `--merge` joins the parts.
    // Negative numbers are values (`--seed -1` is refused as a seed, not
    // as an unknown flag `-1` with the advice to write `-- -1`).
    #[command(allow_negative_numbers = true)]
    Sweep(sweep::SweepArgs),
    /// Rewrite `.hyb` files in the canonical layout (`--check`: only list
    /// those that would change, exit 1 if any).
    Fmt(fmt::FmtArgs),
    /// Draw a run's MCAP file: HyEQ's plots (flows, jumps, hybrid, phase,
    /// domain) of the logged states and outputs, as SVG or PNG.
    Plot(plot::PlotArgs),
    /// Describe a run's MCAP file: model, parameters, seed, solver,
    /// channels and message counts, how the run ended, the command that
    /// reproduces it.
    Info(info::InfoArgs),
    /// Print a shell completion script (`hybsim completions bash > /etc/bash_completion.d/hybsim`).
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
}

/// A `--seed` value: a whole number from 0 to 2⁶⁴ − 1, as the model's
/// `sim { seed }` takes it (clap's own message was "invalid digit found in
/// string" for `-1`, `1.5` or `1e3`).
pub(crate) fn parse_seed(s: &str) -> Result<u64, String> {
    s.trim().parse::<u64>().map_err(|_| {
        format!("`{s}`: a seed is a whole number from 0 to 2^64 - 1 (18446744073709551615)")
    })
}

/// A count flag's value (`--runs`, `--threads`, `--cases`, `--log-every`,
/// `--max-shrink`): a whole number of at least `min`, in digits or, as the
/// counts among the `sim` keys take it, `1e3` (clap's own message was
/// "invalid digit found in string" for `-1`, `1.5` or `1e3`).
pub(crate) fn parse_count(s: &str, min: u64) -> Result<u64, String> {
    let t = s.trim();
    // Floats are whole and exact below 2^53.
    let n = t.parse::<u64>().ok().or_else(|| {
        let x = t.parse::<f64>().ok()?;
        (x.fract() == 0.0 && (0.0..9_007_199_254_740_992.0).contains(&x)).then_some(x as u64)
    });
    match n {
        Some(n) if n >= min => Ok(n),
        _ => Err(format!("`{s}`: a whole number ≥ {min} (such as 20 or 1e3)")),
    }
}

/// [`parse_count`] of at least 1.
pub(crate) fn parse_positive_count(s: &str) -> Result<u64, String> {
    parse_count(s, 1)
}

/// clap's error for `--set Ts 2` (a space for the `=`), "unexpected
/// argument '2'", replaced by one that names the fix. (A lone `--set Ts`
/// reaches the override parser, which locates its error.)
fn set_without_value(e: clap::Error, args: &[OsString]) -> clap::Error {
    if e.kind() != clap::error::ErrorKind::UnknownArgument {
        return e;
    }
    let no_value = args
        .windows(2)
        .filter(|w| w[0] == "--set")
        .map(|w| w[1].to_string_lossy())
        .find(|value| !value.contains('='));
    let Some(name) = no_value else {
        return e;
    };
    let message = format!(
        "`--set {name}` has no value: write `--set {name}=VALUE` as one argument (e.g. \
         `--set {name}=2`; quote values with spaces: `--set \"{name}=[1, 2]\"`)"
    );
    let kind = clap::error::ErrorKind::ValueValidation;
    // The usage shown is the subcommand's, as in clap's own error.
    let mut cli = Cli::command();
    cli.build();
    let sub = args
        .iter()
        .skip(1)
        .filter_map(|a| a.to_str())
        .find(|a| cli.find_subcommand(a).is_some());
    match sub.and_then(|sub| cli.find_subcommand_mut(sub)) {
        Some(cmd) => cmd.error(kind, message),
        None => cli.error(kind, message),
    }
}

/// Replaces the default panic message by a short report: what went wrong
/// where, the command that led there (with the model file), and what to do.
/// A panic during a run still completes the output files (see
/// `run::simulate_to_files`).
pub fn install_panic_hook() {
    std::panic::set_hook(Box::new(|info| {
        let message = run::panic_message(info.payload());
        let location = info
            .location()
            .map(|l| format!(" ({}:{})", l.file(), l.line()))
            .unwrap_or_default();
        let command: Vec<String> = std::iter::once("hybsim".to_string())
            .chain(
                std::env::args_os()
                    .skip(1)
                    .map(|a| a.to_string_lossy().into_owned()),
            )
            .collect();
        eprintln!(
            "error: internal error in hybsim (a bug): {message}{location}\n  command: {}\n  \
             please report it with this command and the model file",
            command.join(" ")
        );
    }));
}

/// Parses `args` (including the program name), runs the subcommand, and
/// returns the process exit code. Errors are printed to stderr.
pub fn run<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let args: Vec<OsString> = args.into_iter().map(Into::into).collect();
    let cli = match Cli::try_parse_from(&args).map_err(|e| set_without_value(e, &args)) {
        Ok(cli) => cli,
        Err(e) => {
            // --help and --version print and succeed; usage errors exit 2.
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() {
                EXIT_MODEL_ERROR
            } else {
                EXIT_OK
            });
        }
    };
    let _ = COLOR.set(cli.color);
    let result = match cli.command {
        Command::Run(args) => run::execute(args),
        Command::Check(args) => check::execute(args),
        Command::Design(args) => design::execute(args),
        Command::Test(args) => test::execute(args),
        Command::Sweep(args) => sweep::execute(args),
        Command::Fmt(args) => fmt::execute(args),
        Command::Info(args) => info::execute(args),
        Command::Plot(args) => plot::execute(args),
        Command::Completions { shell } => {
            clap_complete::generate(shell, &mut Cli::command(), "hybsim", &mut std::io::stdout());
            Ok(EXIT_OK)
        }
    };
    match result {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            eprintln!("error: {}", chain_text(&e));
            ExitCode::from(EXIT_FAILED)
        }
    }
}

/// An error and its causes, `: `-separated, leaving out a cause whose text the message already
/// holds (many errors, hybsim's sink errors and `tempfile`'s among them, both show their cause
/// and return it as `source`: "No space left on device (os error 28)" came twice).
fn chain_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}

/// `--jit on|off`: machine code for the model's programs, or the
/// interpreter (the model's `sim { jit = … }` otherwise decides; default on).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum JitMode {
    /// Compile the programs to machine code (Cranelift).
    On,
    /// Interpret the programs.
    Off,
}

impl JitMode {
    /// Adds the `jit` override this flag stands for (it wins over a
    /// `--set jit=…`).
    fn apply(mode: Option<Self>, overrides: &mut Vec<Override>) {
        if let Some(mode) = mode {
            let word = if mode == JitMode::On { "on" } else { "off" };
            let o: Override = format!("sim.jit={word}").parse().expect("a valid override");
            overrides.push(o.from_flag(format!("--jit {word}")));
        }
    }
}

/// A number given to a flag that is a `sim` key (`--T 0`): its value, and its text as typed,
/// which diagnostics show.
#[derive(Debug, Clone, PartialEq)]
pub struct NumberArg {
    /// The number.
    pub value: f64,
    /// As typed.
    pub text: String,
}

impl std::str::FromStr for NumberArg {
    type Err = std::num::ParseFloatError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(Self {
            value: s.trim().parse()?,
            text: s.to_string(),
        })
    }
}

/// An override of the command line: a `--set name=value` as typed, or a flag that is a `sim`
/// key as the override it stands for (`sim.T=0e0`) with the flag as typed (`--T 0`), which
/// diagnostics show.
#[derive(Debug, Clone, PartialEq)]
pub struct ArgOverride {
    /// `name=value`.
    pub text: String,
    /// The flag as typed, for a flag.
    pub flag: Option<String>,
}

impl ArgOverride {
    /// The `--set` arguments `set`.
    pub fn set(set: &[String]) -> Vec<Self> {
        set.iter()
            .map(|s| Self {
                text: s.clone(),
                flag: None,
            })
            .collect()
    }

    /// The flag `--FLAG` (`flag`) that sets the `sim` key `key`, if given: its value `value` in the
    /// override (all its digits), `typed` as the user wrote it.
    fn flag(flag: &str, key: &str, value: Option<(String, String)>) -> Option<Self> {
        value.map(|(value, typed)| Self {
            text: format!("{key}={value}"),
            flag: Some(format!("{flag} {typed}")),
        })
    }

    /// A number flag (`--T 0`).
    fn number(flag: &str, key: &str, value: Option<&NumberArg>) -> Option<Self> {
        Self::flag(
            flag,
            key,
            value.map(|n| (float_override(n.value), n.text.clone())),
        )
    }
}

/// The event and Zeno guard flags of `run` and `test`. Each is the `sim` key
/// of the same name, passed as an override after the user's `--set`s (so a
/// flag wins), and therefore checked and located like one.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct GuardArgs {
    /// Tolerance on the flow set's atoms when deciding whether a state may
    /// flow (the `sim` key `set_tol`; default 1e-9).
    #[arg(long, value_name = "TOL", allow_hyphen_values = true)]
    pub set_tol: Option<NumberArg>,
    /// Zeno guard: most jumps per unit of t over the window (`inf`
    /// disables it); applies only when J is unbounded (`sim` key `zeno_rate`).
    #[arg(long, value_name = "RATE", allow_hyphen_values = true)]
    pub zeno_rate: Option<NumberArg>,
    /// Zeno guard: number of jumps over which the rate is measured (a whole
    /// number ≥ 2, `1e3` too).
    #[arg(long, value_name = "N", allow_hyphen_values = true)]
    pub zeno_window: Option<NumberArg>,
    /// Zeno guard: jump budget of a run with unbounded J (a whole number
    /// ≥ 1, `1e7` too).
    #[arg(long, value_name = "N", allow_hyphen_values = true)]
    pub max_total_jumps: Option<NumberArg>,
}

impl GuardArgs {
    /// `set` followed by the flags as `sim`-key overrides.
    pub fn with_overrides(&self, set: &[String]) -> Vec<ArgOverride> {
        let mut all = ArgOverride::set(set);
        all.extend(ArgOverride::number(
            "--set-tol",
            "sim.set_tol",
            self.set_tol.as_ref(),
        ));
        all.extend(ArgOverride::number(
            "--zeno-rate",
            "sim.zeno_rate",
            self.zeno_rate.as_ref(),
        ));
        all.extend(ArgOverride::number(
            "--zeno-window",
            "sim.zeno_window",
            self.zeno_window.as_ref(),
        ));
        all.extend(ArgOverride::number(
            "--max-total-jumps",
            "sim.max_total_jumps",
            self.max_total_jumps.as_ref(),
        ));
        all
    }
}

/// A flag's float as the value of an override: `{:e}` keeps every digit, `inf` is the
/// language's spelling of +∞.
fn float_override(x: f64) -> String {
    if x.is_infinite() && x > 0.0 {
        "inf".to_string()
    } else if x.is_nan() {
        // The language's NaN, so that `--T nan` is refused as the value it is (not as an
        // unknown name `NaN`, which the user did not type).
        "0/0".to_string()
    } else {
        format!("{x:e}")
    }
}

/// Interior-point methods for `design` blocks on the command line
/// (`--sdp`; `--solver` of `hybsim run` is the flow integrator).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum SdpKind {
    /// clarabel for small problems, the Schur-complement method above 1000
    /// svec rows of matrix blocks.
    #[default]
    Auto,
    /// clarabel's direct (KKT) method.
    Clarabel,
    /// hybsim's Schur-complement method (large problems).
    Schur,
}

impl SdpKind {
    /// The checker options that solve the design blocks with this method.
    fn options(self) -> CheckOptions {
        let backend = match self {
            SdpKind::Auto => Backend::Auto,
            SdpKind::Clarabel => Backend::Clarabel,
            SdpKind::Schur => Backend::Schur,
        };
        CheckOptions {
            backend,
            ..CheckOptions::default()
        }
    }
}

/// `arg` as one shell word (single-quoted unless plainly safe), for the
/// replay commands that `test` and `info` print.
pub(crate) fn shell_word(arg: &str) -> String {
    let safe = !arg.is_empty()
        && arg
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-+=.,/:@%".contains(c));
    if safe {
        arg.to_string()
    } else {
        format!("'{}'", arg.replace('\'', r"'\''"))
    }
}

/// The bytes of the MCAP file at `path` (standard input for `-`), as far as they can be one: an
/// input that does not start with MCAP's magic bytes is returned after those 8 bytes, for the
/// reader to refuse, so `/dev/zero` or a model given by mistake is not read to its end (or
/// forever).
pub(crate) fn read_mcap_input(path: &std::path::Path) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    const MAGIC: &[u8] = b"\x89MCAP0\r\n";
    let mut reader: Box<dyn Read> = if path == std::path::Path::new("-") {
        Box::new(std::io::stdin())
    } else {
        Box::new(std::fs::File::open(path)?)
    };
    let mut bytes = Vec::new();
    (&mut reader)
        .take(MAGIC.len() as u64)
        .read_to_end(&mut bytes)?;
    if bytes == MAGIC {
        reader.read_to_end(&mut bytes)?;
    }
    Ok(bytes)
}

/// The model file at `path`, or standard input for `-` (named `<stdin>` in
/// diagnostics).
pub(crate) fn read_model(path: &std::path::Path) -> std::io::Result<SourceFile> {
    if path == std::path::Path::new("-") {
        let text = hybsim::source::read_text(std::io::stdin())?;
        Ok(SourceFile::new("<stdin>", text))
    } else {
        SourceFile::read(path)
    }
}

/// Why a model and its `--set` overrides could not be loaded.
enum LoadError {
    /// The model file cannot be read (the message says why).
    Unreadable(String),
    /// Some overrides do not parse: their diagnostics, against the model.
    Overrides(SourceFile, Vec<hybsim::diagnostics::Diagnostic>),
}

/// Reads the model file and parses the `--set` overrides.
fn read_inputs(
    path: &std::path::Path,
    set: &[ArgOverride],
) -> Result<(SourceFile, Vec<Override>), LoadError> {
    let src = read_model(path).map_err(|e| {
        LoadError::Unreadable(format!("cannot read model file `{}`: {e}", path.display()))
    })?;
    let mut overrides = Vec::new();
    let mut problems = Vec::new();
    for s in set {
        match s.text.parse::<Override>() {
            Ok(o) => overrides.push(match &s.flag {
                Some(flag) => o.from_flag(flag),
                None => o,
            }),
            Err(d) => problems.push(d),
        }
    }
    if problems.is_empty() {
        Ok((src, overrides))
    } else {
        Err(LoadError::Overrides(src, problems))
    }
}

/// Reads the model file and parses the `--set` overrides. Prints the
/// problem and returns `None` if either fails (exit code 2).
fn load(
    path: &std::path::Path,
    set: &[ArgOverride],
) -> anyhow::Result<Option<(SourceFile, Vec<Override>)>> {
    match read_inputs(path, set) {
        Ok(loaded) => Ok(Some(loaded)),
        Err(LoadError::Unreadable(message)) => {
            eprintln!("error: {message}");
            Ok(None)
        }
        Err(LoadError::Overrides(src, problems)) => {
            eprint!("{}", render(&problems, &src, color()));
            Ok(None)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn run_arguments_parse() {
        let cli = Cli::try_parse_from([
            "hybsim",
            "run",
            "m.hyb",
            "-o",
            "x.mcap",
            "--T",
            "5",
            "--J",
            "30",
            "--seed",
            "3",
            "--set",
            "g=9.8",
            "--set",
            "K=[1, 2]",
            "--csv",
            "x.csv",
            "--plot",
            "x.svg",
            "--plot-vars",
            "h,v",
            "--log-every",
            "10",
        ])
        .unwrap();
        let Command::Run(a) = cli.command else {
            panic!("not run")
        };
        assert_eq!(a.horizon_t.map(|n| n.value), Some(5.0));
        assert_eq!(a.horizon_j.map(|n| n.value), Some(30.0));
        assert_eq!(a.seed, Some(3));
        assert_eq!(a.set, ["g=9.8", "K=[1, 2]"]);
        assert_eq!(
            run::split_names(a.plot_vars.as_deref().unwrap()),
            ["h", "v"]
        );
        assert_eq!(a.log_every, Some(10));
        assert!(Cli::try_parse_from(["hybsim", "run", "m.hyb", "--log-every", "0"]).is_err());
    }
}
