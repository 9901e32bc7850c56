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
    cli::run(std::env::args_os())
}
