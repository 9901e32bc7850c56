//! The `hybsim` binary: arguments → [`cli::run`] → exit code.

mod cli;

fn main() -> std::process::ExitCode {
    // Writing to a closed pipe (`hybsim … | head`) ends the process quietly
    // with SIGPIPE (exit status 141 in a shell), as Unix tools do, instead
    // of a panic in `println!`.
    // SAFETY: called first thing, before any other thread exists; SIG_DFL is
    // a valid disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    cli::install_panic_hook();
    // One OpenBLAS thread before any BLAS call (the design layer pins it too; here it also
    // holds for anything else in the process).
    hybsim::design::blas::pin();
    // The front end's recursion is bounded (`syntax::MAX_NESTING`,
    // `syntax::MAX_EXPR_DEPTH`); a large stack is only a second line of
    // defence (reserved, not committed, memory).
    let worker = std::thread::Builder::new()
        .name("hybsim".into())
        .stack_size(STACK_BYTES)
        .spawn(|| cli::run(std::env::args_os()));
    match worker {
        // A panic has been reported by the hook; 101 as Rust's own.
        Ok(worker) => worker.join().unwrap_or(std::process::ExitCode::from(101)),
        Err(_) => cli::run(std::env::args_os()),
    }
}

/// Stack of the thread that runs the command.
const STACK_BYTES: usize = 256 << 20;
