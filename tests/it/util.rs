//! Helpers shared by the integration tests.

use std::ffi::OsStr;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use hybsim::arc::{ArcSink, HybridTime, SampleKind, Termination};
use hybsim::engine::models::BouncingBall;
use serde_json::Value;

/// Gravity and restitution of the test ball.
pub const G: f64 = 9.81;
/// Restitution coefficient.
pub const LAMBDA: f64 = 0.8;

/// The switch times before `horizon` of a mode cycle dwelling `dwells[0]`, `dwells[1]`, … in
/// turn from t = 0 (the closed form of a dwell timer indexed by the mode).
pub fn cyclic_switch_times(dwells: &[f64], horizon: f64) -> Vec<f64> {
    let (mut t, mut times) = (0.0, vec![]);
    for k in 0.. {
        t += dwells[k % dwells.len()];
        if t >= horizon {
            break;
        }
        times.push(t);
    }
    times
}

/// Closed-form impact times of the test ball dropped from `h0` at rest.
pub fn ball_impacts(h0: f64, n: usize) -> Vec<f64> {
    BouncingBall::new(G, LAMBDA)
        .impacts(h0, n)
        .into_iter()
        .map(|(t, _)| t)
        .collect()
}

/// Pushes the exact bouncing-ball arc (state h, v) with `n` impacts into
/// `sink`, flow samples every `dt`, stopping early if the sink asks to.
/// Returns the number of samples pushed.
pub fn push_ball(sink: &mut dyn ArcSink, h0: f64, n: usize, dt: f64) -> usize {
    let impacts = ball_impacts(h0, n);
    let (mut t0, mut h, mut v) = (0.0, h0, 0.0);
    let mut pushed = 0;
    let mut push = |sink: &mut dyn ArcSink, at, x: &[f64], kind| {
        pushed += 1;
        sink.sample(at, x, kind)
    };
    if push(sink, HybridTime::new(0.0, 0), &[h, v], SampleKind::Initial).is_break() {
        return pushed;
    }
    for (j, &ti) in impacts.iter().enumerate() {
        let j = j as u64;
        let mut k = 1;
        while t0 + k as f64 * dt < ti {
            let s = k as f64 * dt;
            let x = [h + v * s - 0.5 * G * s * s, v - G * s];
            if push(sink, HybridTime::new(t0 + s, j), &x, SampleKind::Flow).is_break() {
                return pushed;
            }
            k += 1;
        }
        let s = ti - t0;
        let pre = [0.0, v - G * s];
        let post = [0.0, -LAMBDA * pre[1]];
        let at = HybridTime::new(ti, j);
        if push(sink, at, &pre, SampleKind::PreJump).is_break()
            || sink.jump(at, 0, &pre, &post).is_break()
            || push(
                sink,
                HybridTime::new(ti, j + 1),
                &post,
                SampleKind::PostJump,
            )
            .is_break()
        {
            return pushed;
        }
        (t0, h, v) = (ti, post[0], post[1]);
    }
    let _ = push(
        sink,
        HybridTime::new(t0, n as u64),
        &[h, v],
        SampleKind::Final,
    );
    pushed
}

/// A sink that records nothing but the termination, and stops after `left`
/// samples.
pub struct StopAfter {
    /// Samples still to accept.
    pub left: usize,
    /// The termination the engine reported, once it has.
    pub termination: Option<Termination>,
}

impl StopAfter {
    /// Stops after `n` samples.
    pub fn new(n: usize) -> Self {
        Self {
            left: n,
            termination: None,
        }
    }
}

impl ArcSink for StopAfter {
    fn sample(&mut self, _: HybridTime, _: &[f64], _: SampleKind) -> ControlFlow<()> {
        self.left = self.left.saturating_sub(1);
        if self.left == 0 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }
    fn jump(&mut self, _: HybridTime, _: usize, _: &[f64], _: &[f64]) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }
    fn finish(&mut self, t: &Termination) {
        self.termination = Some(t.clone());
    }
}

/// Asserts that `v` conforms to `s`, for the subset of JSON Schema the sinks
/// generate: type, properties, required, items, min/maxItems, const, minimum.
pub fn assert_conforms(v: &Value, s: &Value, path: &str) {
    let ty = s["type"].as_str().unwrap();
    let ok = match ty {
        "object" => v.is_object(),
        "array" => v.is_array(),
        "number" => v.is_number(),
        "integer" => v.is_u64() || v.is_i64(),
        "string" => v.is_string(),
        other => panic!("unexpected schema type {other}"),
    };
    assert!(ok, "{path}: {v} is not {ty}");
    if let Some(c) = s.get("const") {
        assert_eq!(v, c, "{path}");
    }
    if let Some(min) = s.get("minimum") {
        assert!(v.as_f64().unwrap() >= min.as_f64().unwrap(), "{path}");
    }
    if let Some(obj) = v.as_object() {
        for r in s["required"].as_array().unwrap() {
            assert!(obj.contains_key(r.as_str().unwrap()), "{path}: missing {r}");
        }
        let props = s["properties"].as_object().unwrap();
        for (k, x) in obj {
            let p = props
                .get(k)
                .unwrap_or_else(|| panic!("{path}: `{k}` not in schema"));
            assert_conforms(x, p, &format!("{path}.{k}"));
        }
    }
    if let Some(arr) = v.as_array() {
        if let Some(n) = s.get("minItems") {
            assert!(arr.len() as u64 >= n.as_u64().unwrap(), "{path}");
        }
        if let Some(n) = s.get("maxItems") {
            assert!(arr.len() as u64 <= n.as_u64().unwrap(), "{path}");
        }
        for (k, x) in arr.iter().enumerate() {
            assert_conforms(x, &s["items"], &format!("{path}[{k}]"));
        }
    }
}

/// Files in `dir` whose names end in `.tmp`: what an unfinished or failed
/// write would leave behind (the sinks' temporary files are `.NAME.XXXXXX.tmp`).
pub fn temp_files(dir: &std::path::Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .expect("a readable directory")
        .map(|e| {
            e.expect("a directory entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

/// The `hybsim` binary built for these tests.
pub const BIN: &str = env!("CARGO_BIN_EXE_hybsim");

/// Runs the `hybsim` binary with `args` in `dir` and waits for it.
pub fn hybsim<S: AsRef<OsStr>>(dir: &Path, args: &[S]) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .output()
        .expect("the binary runs")
}

/// Runs `hybsim ARGS` in `dir` as [`hybsim`] does; also returns the child's
/// own CPU time.
pub fn hybsim_cpu<S: AsRef<OsStr>>(dir: &Path, args: &[S]) -> (Output, Duration) {
    output_with_cpu(Command::new(BIN).args(args).current_dir(dir))
}

/// Runs `cmd` to its end as `Command::output` does (standard input
/// closed, standard output and error captured) and returns the child's own
/// CPU time, user and system, from `wait4`. A time bound that guards
/// against super-linear blow-ups holds on this however loaded the machine
/// is, where one on wall-clock time fails when other work takes the cores.
// The child is reaped by `wait4`, which `Child::wait` cannot replace (it
// gives no resource usage).
#[allow(clippy::zombie_processes)]
pub fn output_with_cpu(cmd: &mut Command) -> (Output, Duration) {
    use std::io::Read;
    use std::os::unix::process::ExitStatusExt;
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the binary runs");
    let mut err_pipe = child.stderr.take().expect("piped");
    let err_reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        err_pipe.read_to_end(&mut buf).map(|_| buf)
    });
    let mut stdout = Vec::new();
    child
        .stdout
        .take()
        .expect("piped")
        .read_to_end(&mut stdout)
        .expect("the child's standard output");
    let stderr = err_reader
        .join()
        .expect("the reader thread")
        .expect("the child's standard error");
    let pid = libc::pid_t::try_from(child.id()).expect("a pid");
    let (mut status, mut usage) = (0, unsafe { std::mem::zeroed::<libc::rusage>() });
    loop {
        // SAFETY: `status` and `usage` are valid for writes; `pid` is this
        // process's child, not waited for yet (`child` is dropped unwaited).
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        if r == pid {
            break;
        }
        let e = std::io::Error::last_os_error();
        assert_eq!(e.kind(), std::io::ErrorKind::Interrupted, "wait4: {e}");
    }
    let time = |t: libc::timeval| {
        Duration::from_secs(t.tv_sec as u64) + Duration::from_micros(t.tv_usec as u64)
    };
    let cpu = time(usage.ru_utime) + time(usage.ru_stime);
    let output = Output {
        status: std::process::ExitStatus::from_raw(status),
        stdout,
        stderr,
    };
    (output, cpu)
}

/// This thread's CPU time so far: bounds on work done in process hold on it
/// however loaded the machine is.
pub fn thread_cpu() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is valid for writes.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(r, 0, "clock_gettime");
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// A run's standard output as text.
pub fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A run's standard error as text.
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A run's exit code (the run must have exited, not been killed).
pub fn code(out: &Output) -> i32 {
    out.status.code().expect("exited normally")
}

/// `hybsim test MODEL --cases CASES --property PROPERTY` in `dir`.
pub fn test_property(dir: &Path, model: &Path, cases: &str, property: &str) -> Output {
    let model = model.to_str().expect("a UTF-8 path");
    hybsim(
        dir,
        &["test", model, "--cases", cases, "--property", property],
    )
}

/// A model file under `tests/models`.
pub fn test_model(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/models")
        .join(name)
}

/// `hybsim::engine::simulate_arc`, and every arc it returns checked with
/// `engine::check_arc` (each jump starts from a point of D, each flow in C
/// within `set_tol`): the integration tests simulate through this.
pub fn simulate_arc<S: hybsim::engine::HybridSystem + ?Sized>(
    sys: &S,
    x0: &[f64],
    settings: &hybsim::engine::SimSettings,
    rng: &mut hybsim::engine::SimRng,
) -> Result<hybsim::arc::HybridArc, hybsim::engine::SimError> {
    let arc = hybsim::engine::simulate_arc(sys, x0, settings, rng)?;
    if let Err(violation) = hybsim::engine::check_arc(sys, &arc, settings) {
        panic!("the arc breaks the engine's invariants: {violation}");
    }
    Ok(arc)
}

/// The metadata record `name` of an MCAP file's bytes (its key-value map).
pub fn mcap_metadata(bytes: &[u8], name: &str) -> std::collections::BTreeMap<String, String> {
    let summary = mcap::read::Summary::read(bytes)
        .unwrap()
        .expect("an indexed MCAP file");
    summary
        .metadata_indexes
        .iter()
        .map(|i| mcap::read::metadata(bytes, i).unwrap())
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("no metadata record {name}"))
        .metadata
}

/// Hex SHA-256 of `bytes`, as the MCAP metadata writes it.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// (target folder, profile) of the running test binary (`target/PROFILE/deps/it-…`), for tests that
/// run cargo themselves and should reuse what the test build compiled.
pub fn target_and_profile() -> (PathBuf, String) {
    let exe = std::env::current_exe().unwrap();
    let profile_dir = exe.parent().and_then(|d| d.parent()).unwrap();
    let name = profile_dir
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let profile = if name == "debug" { "dev".into() } else { name };
    (profile_dir.parent().unwrap().to_path_buf(), profile)
}

/// A command that runs cargo (a nested build in the test binary's target folder, possibly through
/// a script), without the variables cargo sets for the running test (`CARGO_MANIFEST_DIR`,
/// `CARGO_PKG_*`, …): the nested cargo records some of them in the fingerprints of build scripts
/// (ring's read `CARGO_MANIFEST_DIR`), and the next ordinary build would compile those crates and
/// every crate above them again (clarabel, hybsim, …).
pub fn nested_cargo(program: impl AsRef<OsStr>) -> Command {
    let mut cmd = Command::new(program);
    for (name, _) in std::env::vars_os() {
        let name = name.to_string_lossy();
        let per_crate = ["CARGO_PKG_", "CARGO_MANIFEST_", "CARGO_BIN_"]
            .iter()
            .any(|p| name.starts_with(p))
            || matches!(
                &*name,
                "CARGO_CRATE_NAME"
                    | "CARGO_PRIMARY_PACKAGE"
                    | "CARGO_TARGET_TMPDIR"
                    | "CARGO_RUSTC_CURRENT_DIR"
                    | "OUT_DIR"
            );
        if per_crate {
            cmd.env_remove(&*name);
        }
    }
    cmd
}

/// Compiles the `.hyb` source `src` (panics with the rendered diagnostic if
/// it does not).
pub fn compile(src: &str) -> hybsim::ir::CompiledModel {
    let file = hybsim::source::SourceFile::new("t.hyb", src);
    match hybsim::lang::compile(&file, &[]) {
        Ok(m) => m,
        Err(d) => panic!("{}", hybsim::diagnostics::render(&d, &file, false)),
    }
}
