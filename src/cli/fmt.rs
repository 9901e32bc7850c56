//! `hybsim fmt`: rewrite `.hyb` files in the canonical layout
//! (`syntax::format_source`), or with `--check` only report those that
//! would change.

use std::path::PathBuf;

use clap::Args;
use hybsim::atomic_file;
use hybsim::diagnostics::render;
use hybsim::syntax::format_source;

use super::{EXIT_FAILED, EXIT_MODEL_ERROR, EXIT_OK};

/// Arguments of `hybsim fmt`.
#[derive(Debug, Args)]
pub struct FmtArgs {
    /// The model files (`.hyb`); `-` reads standard input and writes the
    /// formatted text to standard output.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Change nothing; list the files that would change and exit 1 if any.
    #[arg(long)]
    pub check: bool,
}

/// `hybsim fmt`. A file that does not parse is reported (exit 2) and left
/// as it is; the others are still formatted.
pub fn execute(args: FmtArgs) -> anyhow::Result<u8> {
    let mut code = EXIT_OK;
    for path in &args.files {
        let src = match super::read_model(path) {
            Ok(src) => src,
            Err(e) => {
                eprintln!("error: cannot read model file `{}`: {e}", path.display());
                code = EXIT_MODEL_ERROR;
                continue;
            }
        };
        let formatted = match format_source(src.text()) {
            Ok(text) => text,
            Err(e) => {
                eprint!("{}", render(&[e.to_diagnostic()], &src, super::color()));
                code = EXIT_MODEL_ERROR;
                continue;
            }
        };
        if path == std::path::Path::new("-") {
            // A filter, like rustfmt: standard input in, the layout out.
            if args.check {
                if formatted != src.text() {
                    println!("would reformat <stdin>");
                    code = code.max(EXIT_FAILED);
                }
            } else {
                print!("{formatted}");
            }
            continue;
        }
        if formatted == src.text() {
            continue;
        }
        if args.check {
            println!("would reformat {}", path.display());
            if code == EXIT_OK {
                code = EXIT_FAILED;
            }
        } else {
            // Through a temporary file: a failure never leaves half a model.
            atomic_file::write(path, formatted.as_bytes())?;
            eprintln!("formatted {}", path.display());
        }
    }
    Ok(code)
}
