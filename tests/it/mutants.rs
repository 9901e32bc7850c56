//! Grammar-aware mutation test (issue 24): up to `CASES` token-level
//! mutants of the shipped models (`models/`, `models/lib/`,
//! `benches/models/`), each through `hybsim::fuzz::run`: check, compile
//! and, for what compiles, a run cut to T ≤ 2 and J ≤ 200. Asserted: no
//! panic, every error located inside its file, `check` accepts only what
//! compiles, and no case takes longer than `CASE_LIMIT` (each case runs on a
//! worker thread watched by the test thread).
//!
//! Case k is the same on every run (fixed seed, a function of k alone); a
//! run checks the first cases of that list: all `CASES` if they fit in
//! `BUDGET` of wall time, else those started within it, never fewer than
//! `MIN_CASES` (`Plan`).
//!
//! A mutant applies 1–3 edits to the model's tokens: delete, duplicate or
//! swap tokens, replace a number by an edge value (0, -0, 1e308, 1e-320,
//! 1e309, huge integers, 0/0, …), a name by another word of the model, an
//! operator by another operator, empty a bracket's contents or insert
//! empty brackets. Mutants of `models/lib/` files are compiled through a
//! model that imports them, so their errors must point into the library
//! file.
//!
//! `HYBSIM_MUTANTS=N` runs exactly the first N cases, without a time budget
//! (e.g. 100000 for a long local run); a failure prints the case number k,
//! the file and the mutant (`HYBSIM_MUTANTS=k+1` runs it again).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use hybsim::fuzz::{self, Budget, Input, Outcome};
use hybsim::source::SourceFile;
use hybsim::syntax::lex::{self, TokenKind as Kind};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::util::thread_cpu;

/// Cases per run of the test, at most (README, "Hostile input").
const CASES: usize = 5000;
/// Cases per run, at least, however long they take.
const MIN_CASES: usize = 1000;
/// Wall time after which no new case starts (once `MIN_CASES` have):
/// 5 000 cases took 66 s on 2 loaded cores, which CI cannot spend.
const BUDGET: Duration = Duration::from_secs(30);
/// The seed of the mutants.
const SEED: u64 = 24;
/// A case slower than this is a hang (typical cases take milliseconds).
const CASE_LIMIT: Duration = Duration::from_secs(30);

/// Numbers that have broken numeric code before: zeros of both signs,
/// the largest and smallest doubles and beyond, integers past u32/u64/f64
/// exactness, non-finite values spelled as expressions.
const EDGE_NUMBERS: &[&str] = &[
    "0",
    "-0",
    "0.0",
    "1",
    "-1",
    "2",
    "65",
    "1e308",
    "-1e308",
    "1e309",
    "-1e-308",
    "1e-320",
    "4294967297",
    "18446744073709551617",
    "9007199254740993",
    "99999999999999999999999999999999999999",
    "0/0",
    "1/0",
    "-1/0",
    "(0/0)",
    "inf",
    "NaN",
];

/// Operators a mutant may put in place of another.
const OPERATORS: &[&str] = &[
    "+", "-", "*", "/", "^", ".*", "./", "'", "<", ">", "<=", ">=", "==", "!=", "&&", "||", "!",
    "=", "~", ",", ";", ":", "..",
];

/// A token and the whitespace or comments before it.
#[derive(Debug, Clone)]
struct Token {
    before: String,
    text: String,
    kind: Kind,
}

/// Splits `text` into the language's tokens (`hybsim::syntax::lex`), with
/// whitespace and comments attached to the next token; the rest after the
/// last token is returned too.
fn lex(text: &str) -> (Vec<Token>, String) {
    let mut tokens = Vec::new();
    let mut end = 0;
    for t in lex::tokens(text) {
        if t.kind == Kind::Comment {
            continue;
        }
        tokens.push(Token {
            before: text[end..t.offset].to_string(),
            text: t.text.to_string(),
            kind: t.kind,
        });
        end = t.offset + t.text.len();
    }
    (tokens, text[end..].to_string())
}

/// One shipped file and how to compile its mutants: `host` is the model
/// that imports it (library files), else the file itself.
struct Subject {
    path: PathBuf,
    tokens: Vec<Token>,
    tail: String,
    words: Vec<String>,
    host: Option<String>,
}

fn subjects() -> Vec<Subject> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut paths = Vec::new();
    for dir in ["models", "models/lib", "benches/models"] {
        let mut found: Vec<PathBuf> = std::fs::read_dir(root.join(dir))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "hyb"))
            .collect();
        found.sort();
        paths.extend(found);
    }
    assert!(paths.len() >= 15, "shipped models not found: {paths:?}");
    paths
        .into_iter()
        .map(|path| {
            let text = std::fs::read_to_string(&path).unwrap();
            let (tokens, tail) = lex(&text);
            let mut words: Vec<String> = tokens
                .iter()
                .filter(|t| t.kind == Kind::Word)
                .map(|t| t.text.clone())
                .collect();
            words.sort();
            words.dedup();
            let host = path
                .parent()
                .is_some_and(|d| d.ends_with("models/lib"))
                .then(|| library_host(root, &path));
            Subject {
                path,
                tokens,
                tail,
                words,
                host,
            }
        })
        .collect()
}

/// A model importing the library file `lib`: a shipped model that imports
/// it, else one that only imports it (the subsystems are still parsed and
/// checked).
fn library_host(root: &Path, lib: &Path) -> String {
    let import = format!(
        "import \"lib/{}\"",
        lib.file_name().unwrap().to_string_lossy()
    );
    for entry in std::fs::read_dir(root.join("models")).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "hyb") {
            let text = std::fs::read_to_string(&p).unwrap();
            if text.contains(&import) {
                return text;
            }
        }
    }
    format!("model host\n{import}\nstate x = 1\nflow {{ x' = -x }}\nsim {{ T = 1 }}\n")
}

fn pick<'a, T>(rng: &mut ChaCha8Rng, items: &'a [T]) -> &'a T {
    &items[(rng.next_u64() % items.len() as u64) as usize]
}

fn below(rng: &mut ChaCha8Rng, n: usize) -> usize {
    (rng.next_u64() % n.max(1) as u64) as usize
}

/// Applies one random edit to `tokens`; returns what it did.
fn mutate(rng: &mut ChaCha8Rng, tokens: &mut Vec<Token>, words: &[String]) -> String {
    if tokens.len() < 2 {
        return "none".into();
    }
    let i = below(rng, tokens.len());
    let token = |text: &str, kind: Kind| Token {
        before: " ".into(),
        text: text.into(),
        kind,
    };
    // Weighted towards edits that keep the text parsing (numbers, names), so that most mutants
    // reach the checker and many the run.
    match below(rng, 12) {
        0 => {
            let t = tokens.remove(i);
            format!("delete `{}`", t.text)
        }
        1 => {
            let t = tokens[i].clone();
            tokens.insert(
                i + 1,
                Token {
                    before: " ".into(),
                    ..t.clone()
                },
            );
            format!("duplicate `{}`", t.text)
        }
        2 => {
            let j = if below(rng, 2) == 0 {
                (i + 1).min(tokens.len() - 1)
            } else {
                below(rng, tokens.len())
            };
            let (a, b) = (tokens[i].text.clone(), tokens[j].text.clone());
            tokens[i].text = b.clone();
            tokens[i].kind = tokens[j].kind;
            let kind = tokens[i].kind;
            tokens[j].text = a.clone();
            tokens[j].kind = if kind == tokens[j].kind {
                kind
            } else {
                Kind::Op
            };
            format!("swap `{a}` and `{b}`")
        }
        3..=6 => {
            // Numbers are the most productive target: aim at one if any.
            let numbers: Vec<usize> = (0..tokens.len())
                .filter(|&k| tokens[k].kind == Kind::Number)
                .collect();
            let k = if numbers.is_empty() {
                i
            } else {
                *pick(rng, &numbers)
            };
            let edge = *pick(rng, EDGE_NUMBERS);
            let old = std::mem::replace(&mut tokens[k].text, edge.to_string());
            format!("number `{old}` -> `{edge}`")
        }
        7 | 8 => {
            let names: Vec<usize> = (0..tokens.len())
                .filter(|&k| tokens[k].kind == Kind::Word)
                .collect();
            let k = if names.is_empty() {
                i
            } else {
                *pick(rng, &names)
            };
            let new = pick(rng, words).clone();
            let old = std::mem::replace(&mut tokens[k].text, new.clone());
            tokens[k].kind = Kind::Word;
            format!("name `{old}` -> `{new}`")
        }
        9 => {
            let ops: Vec<usize> = (0..tokens.len())
                .filter(|&k| tokens[k].kind == Kind::Op && !"()[]{}".contains(&tokens[k].text))
                .collect();
            let k = if ops.is_empty() { i } else { *pick(rng, &ops) };
            let new = *pick(rng, OPERATORS);
            let old = std::mem::replace(&mut tokens[k].text, new.to_string());
            tokens[k].kind = Kind::Op;
            format!("operator `{old}` -> `{new}`")
        }
        10 => {
            // Empty the contents of a bracket pair.
            let opens: Vec<usize> = (0..tokens.len())
                .filter(|&k| matches!(tokens[k].text.as_str(), "(" | "[" | "{"))
                .collect();
            if opens.is_empty() {
                return "none".into();
            }
            let k = *pick(rng, &opens);
            let mut depth = 0usize;
            let mut end = None;
            for (m, t) in tokens.iter().enumerate().skip(k) {
                match t.text.as_str() {
                    "(" | "[" | "{" => depth += 1,
                    ")" | "]" | "}" => {
                        depth -= 1;
                        if depth == 0 {
                            end = Some(m);
                            break;
                        }
                    }
                    _ => {}
                }
            }
            let Some(end) = end else {
                return "none".into();
            };
            tokens.drain(k + 1..end);
            format!("empty the brackets at token {k}")
        }
        _ => {
            let (open, close) = *pick(rng, &[("[", "]"), ("(", ")"), ("{", "}")]);
            tokens.insert(i, token(close, Kind::Op));
            tokens.insert(i, token(open, Kind::Op));
            format!("insert `{open}{close}`")
        }
    }
}

fn render(tokens: &[Token], tail: &str) -> String {
    let mut s = String::new();
    for t in tokens {
        s.push_str(&t.before);
        s.push_str(&t.text);
    }
    s.push_str(tail);
    s
}

/// Case `case`: the subject (round robin over the files) and its mutant.
struct Case {
    subject: usize,
    edits: Vec<String>,
    text: String,
}

fn case(subjects: &[Subject], case: usize) -> Case {
    let subject = case % subjects.len();
    let s = &subjects[subject];
    let mut rng =
        ChaCha8Rng::seed_from_u64(SEED ^ (case as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let mut tokens = s.tokens.clone();
    let edits = (0..1 + below(&mut rng, 3))
        .map(|_| mutate(&mut rng, &mut tokens, &s.words))
        .collect();
    Case {
        subject,
        edits,
        text: render(&tokens, &s.tail),
    }
}

/// Runs one case; library mutants are written beside a copy of their host
/// in a temporary `lib/`, so that imports read the mutant.
fn run_case(s: &Subject, text: &str) -> Result<Outcome, String> {
    let budget = Budget::default();
    match &s.host {
        None => fuzz::run(&SourceFile::new(s.path.to_string_lossy(), text), &budget)
            .map_err(|v| v.to_string()),
        Some(host) => {
            let dir = tempfile::tempdir().unwrap();
            let lib = dir.path().join("lib");
            std::fs::create_dir(&lib).unwrap();
            let root = s.path.parent().unwrap();
            for entry in std::fs::read_dir(root).unwrap() {
                let p = entry.unwrap().path();
                std::fs::copy(&p, lib.join(p.file_name().unwrap())).unwrap();
            }
            let mutant = lib.join(s.path.file_name().unwrap());
            std::fs::write(&mutant, text).unwrap();
            let src = SourceFile::new(dir.path().join("host.hyb").to_string_lossy(), host.as_str());
            let outcome = fuzz::run(&src, &budget).map_err(|v| v.to_string())?;
            if let Outcome::Rejected { .. } = outcome {
                // The host is valid: a syntax error (E01xx) can only be the library file's, and
                // must be shown in it, not at the same offsets of the host.
                for d in hybsim::lang::check_only(&src, &[]) {
                    let file = d.primary_file(&src);
                    if d.code.starts_with("E01")
                        && !mutant.ends_with(file)
                        && file != mutant.to_string_lossy()
                    {
                        return Err(format!(
                            "{} located in {file}, not in the library file: {d:?}",
                            d.code
                        ));
                    }
                }
            }
            Ok(outcome)
        }
    }
}

/// How many cases of a test's fixed list run: the first ones, up to `max`;
/// a new case starts only while `budget` lasts or fewer than `min` have
/// started, so the test's time is bounded on a slow or busy machine and
/// never checks fewer than `min` cases. Case `k` is the same on every run
/// (a function of `k` alone), so a run checks a prefix of the same list.
#[derive(Debug, Clone, Copy)]
struct Plan {
    max: usize,
    min: usize,
    budget: Option<Duration>,
}

impl Plan {
    /// `max` cases in `budget`, at least `min`; the environment variable
    /// `var` set to N asks for exactly the first N cases, however long
    /// they take (a long local run, or a failure's case again).
    fn from_env(var: &str, max: usize, min: usize, budget: Duration) -> Plan {
        match std::env::var(var).ok().and_then(|v| v.parse().ok()) {
            Some(n) => Plan {
                max: n,
                min: n,
                budget: None,
            },
            None => Plan {
                max,
                min,
                budget: Some(budget),
            },
        }
    }

    /// Whether case `k` may start `elapsed` after the first.
    fn starts(&self, k: usize, elapsed: Duration) -> bool {
        k < self.max && (k < self.min || self.budget.is_none_or(|b| elapsed < b))
    }
}

/// What the cases of a [`run_cases`] gave.
#[derive(Debug, Default)]
struct Tally {
    done: usize,
    rejected: usize,
    ran: usize,
    failed: usize,
    /// (case, why) of the cases that broke a promise or hung.
    failures: Vec<(usize, String)>,
    elapsed: Duration,
}

impl Tally {
    /// Asserted of every run: no broken promise (`report` renders a failing case), at least the
    /// plan's minimum done, and the cases reach every stage (not all refused by the parser).
    fn assert_ok(&self, what: &str, plan: &Plan, report: impl Fn(usize, &str) -> String) {
        eprintln!(
            "{} {what} (the first of the list; at most {}) in {:.1} s: {} rejected, {} ran, {} failed at run time, {} broke a promise",
            self.done,
            plan.max,
            self.elapsed.as_secs_f64(),
            self.rejected,
            self.ran,
            self.failed,
            self.failures.len()
        );
        let shown: Vec<String> = self
            .failures
            .iter()
            .take(20)
            .map(|(k, why)| report(*k, why))
            .collect();
        assert!(self.failures.is_empty(), "{}", shown.join("\n"));
        assert!(
            self.done >= plan.min,
            "{} {what} done, fewer than the minimum {}",
            self.done,
            plan.min
        );
        assert!(
            self.ran > self.done / 20 && self.rejected > self.done / 4,
            "ran {}, rejected {}",
            self.ran,
            self.rejected
        );
    }
}

/// What a worker is doing: (case, since when).
type Running = Option<(usize, Instant)>;

/// Runs cases 0, 1, … of `plan` (`job(k)` is case `k`) on two worker
/// threads; a case without a result after `CASE_LIMIT` is recorded as a
/// hang and ends the run (a worker cannot be stopped).
fn run_cases<F>(plan: Plan, job: F) -> Tally
where
    F: Fn(usize) -> Result<Outcome, String> + Send + Sync + 'static,
{
    let job = Arc::new(job);
    let started = Instant::now();
    let next = Arc::new(AtomicUsize::new(0));
    let busy: Arc<Mutex<Vec<Running>>> = Arc::new(Mutex::new(vec![None; 2]));
    let (tx, rx) = mpsc::channel();
    for w in 0..2 {
        let (job, next, busy, tx) = (job.clone(), next.clone(), busy.clone(), tx.clone());
        std::thread::spawn(move || {
            loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                if !plan.starts(k, started.elapsed()) {
                    break;
                }
                busy.lock().unwrap()[w] = Some((k, Instant::now()));
                let r = job(k);
                busy.lock().unwrap()[w] = None;
                if tx.send((k, r)).is_err() {
                    break;
                }
            }
        });
    }
    drop(tx);
    let mut tally = Tally::default();
    loop {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok((k, r)) => {
                tally.done += 1;
                match r {
                    Ok(Outcome::Rejected { .. }) => tally.rejected += 1,
                    Ok(Outcome::Ran { .. }) => tally.ran += 1,
                    Ok(Outcome::Failed { .. }) => tally.failed += 1,
                    Ok(Outcome::Accepted) => {}
                    Err(why) => tally.failures.push((k, why)),
                }
            }
            // Every worker has stopped: the plan is done.
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        let hung = busy
            .lock()
            .unwrap()
            .iter()
            .flatten()
            .find(|(_, since)| since.elapsed() > CASE_LIMIT)
            .copied();
        if let Some((k, _)) = hung {
            tally
                .failures
                .push((k, format!("no result after {CASE_LIMIT:?}")));
            break;
        }
    }
    tally.elapsed = started.elapsed();
    tally
}

#[test]
fn mutants_of_the_shipped_models_never_panic_hang_or_lose_a_location() {
    let plan = Plan::from_env("HYBSIM_MUTANTS", CASES, MIN_CASES, BUDGET);
    let subjects = Arc::new(subjects());
    // Library hosts compile unmutated (so every error of a mutant is the mutant's).
    for s in subjects.iter() {
        if s.host.is_some() {
            let r = run_case(s, &render(&s.tokens, &s.tail));
            assert!(
                matches!(r, Ok(Outcome::Ran { .. })),
                "{}: {r:?}",
                s.path.display()
            );
        }
    }
    let tally = run_cases(plan, {
        let subjects = subjects.clone();
        move |k| {
            let c = case(&subjects, k);
            run_case(&subjects[c.subject], &c.text)
        }
    });
    tally.assert_ok("mutants", &plan, |k, why| {
        let c = case(&subjects, k);
        format!(
            "case {k}: {} after {:?}\n{why}\n--- mutant ---\n{}\n",
            subjects[c.subject].path.display(),
            c.edits,
            c.text
        )
    });
}

/// The defects the mutation test found, each as its smallest model (see
/// `hybsim::linalg`, `ir::detect_timer`): they hung or failed unlocated.
#[test]
fn defects_found_by_mutation_end_quickly_with_located_results() {
    let t0 = thread_cpu();
    let run = |text: &str| fuzz::run(&SourceFile::new("m.hyb", text), &Budget::default());
    // appendix_f with an LMI coefficient whose square overflows (nalgebra's SVD iterated forever
    // in the LMI's factor compression): a located E0705, design not solved.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/appendix_f.hyb");
    let text = std::fs::read_to_string(path).unwrap();
    let lmi = text.replace("param B = [0, 1; 1, 0]", "param B = [0, 1; 1, -1e300]");
    assert_ne!(lmi, text);
    let diags = hybsim::lang::check_only(&SourceFile::new("m.hyb", lmi.as_str()), &[]);
    assert!(
        diags
            .iter()
            .any(|d| d.code == "E0705" && d.primary_span().is_some()),
        "{diags:?}"
    );
    // Norms of huge, tiny and non-finite matrices, folded at check time and evaluated in a run.
    let norms = "model m\nparam a = norm([0, 1e-320; 0, -1e-308]) + norm([1e300, 1; 0, 1])\n\
                 state x = 1\nflow { x' = -x }\noutput n = norm([x * 1e300, 1; 0, 0/0])\nsim { T = 1 }\n";
    assert!(
        matches!(run(norms), Ok(Outcome::Ran { .. })),
        "{:?}",
        run(norms)
    );
    // A timer guard against NaN (it was an unlocated "invalid system" at run time, then a rule
    // that silently never fired): a located E0515.
    let nan_timer = "model m\nstate tau = 0\nflow { tau' = 1 }\njump j when tau >= 0/0 { tau+ = 0 }\nsim { T = 1 }\n";
    assert!(
        matches!(run(nan_timer), Ok(Outcome::Rejected { errors: 1 })),
        "{:?}",
        run(nan_timer)
    );
    let diags = hybsim::lang::check_only(&SourceFile::new("m.hyb", nan_timer), &[]);
    assert!(
        diags
            .iter()
            .any(|d| d.code == "E0515" && d.primary_span().is_some()),
        "{diags:?}"
    );
    let cpu = thread_cpu() - t0;
    assert!(cpu < Duration::from_secs(2), "{cpu:?} CPU");
}

/// Cases per run of the override and table test, at most (README, "Hostile input").
const INPUT_CASES: usize = 1000;
/// Override and table cases per run, at least.
const MIN_INPUT_CASES: usize = 300;
/// Wall time after which no new override or table case starts.
const INPUT_BUDGET: Duration = Duration::from_secs(15);

/// `sim` keys an override may name (besides the model's own words and
/// unknown names).
const SIM_KEYS: &[&str] = &[
    "T",
    "J",
    "dt_out",
    "max_step",
    "rtol",
    "atol",
    "event_tol",
    "zeno_rate",
    "zeno_max_rate",
    "max_total_jumps",
    "max_matrix_elements",
    "seed",
    "solver",
    "jit",
    "nosuch",
];

/// Override values beyond the edge numbers: huge matrices, non-finite and
/// overflowing entries, ragged and empty matrices, syntax errors, byte-order
/// marks and control characters.
const HOSTILE_VALUES: &[&str] = &[
    "eye(100000)",
    "zeros(100000, 100000)",
    "ones(1e9, 1)",
    "zeros(0, 0)",
    "[]",
    "[1, 2; 3]",
    "[0/0, 1; 1, 0/0]",
    "[1e308, 1e308; 1e308, 1e308] * 1e308",
    "1e308 * 10",
    "-(0/0)",
    "1 +",
    "(",
    "[1, 2",
    "1 1",
    "",
    "=",
    "@",
    "x'",
    "1e",
    "\u{feff}1",
    "1\u{0}",
    "\"s\"",
    "rk4",
    "dopri5",
    "off",
    "true",
];

/// One override argument: `name=value`, or a malformed argument.
fn override_arg(rng: &mut ChaCha8Rng, words: &[String]) -> String {
    let name = match below(rng, 3) {
        0 => pick(rng, SIM_KEYS).to_string(),
        _ => pick(rng, words).clone(),
    };
    let value = match below(rng, 10) {
        0..=3 => pick(rng, EDGE_NUMBERS).to_string(),
        4..=6 => pick(rng, HOSTILE_VALUES).to_string(),
        7 => pick(rng, words).clone(),
        8 => match below(rng, 3) {
            // Long flat chains (the parser's depth limits), inside the CLI's argument size.
            0 => format!("1{}", "+1".repeat(20_000)),
            1 => format!("{}1", "-".repeat(10_000)),
            _ => format!("{}1{}", "(".repeat(300), ")".repeat(300)),
        },
        _ => format!("[{}]", vec!["1e308"; 1 + below(rng, 50)].join(", ")),
    };
    match below(rng, 20) {
        0 => name,
        1 => format!("={value}"),
        2 => format!("{name} {name}={value}"),
        3 => format!("{name}=={value}"),
        _ => format!("{name}={value}"),
    }
}

/// Data models whose table files the table cases mutate: (model, table
/// name, table), the model reading it with constant and run-time indices,
/// slices, `rows`/`cols`/`length` and `interp`.
fn table_hosts() -> Vec<(String, &'static str, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let bench = |f: &str| std::fs::read_to_string(root.join("benches/models").join(f)).unwrap();
    let timers = bench("limit_agents_timers.csv");
    // The benchmark's table cut to 60 rows, so a case stays cheap.
    let timers: String = timers.split_inclusive('\n').take(60).collect();
    vec![
        (
            "model tab\nparam tk = table(\"t.csv\")\nstate x = tk[1], n = 1\n\
             flow { x' = -1; n' = 0 }\njump next when x <= 0 { x+ = tk[n + 1]; n+ = n + 1 }\n\
             output r = rows(tk), c = cols(tk), v = tk[n], s = length(tk)\nsim { T = 2 }\n"
                .to_string(),
            "t.csv",
            "# delays\n0.3\n0.25\n0.2\n0.4\n0.1\n0.3\n0.5\n0.2\n0.1\n0.2\n".to_string(),
        ),
        (
            "model gain\nparam M = table(\"m.csv\")\nstate y = M[1, 2]\n\
             flow { y' = -interp(M[:, 1], M[:, 2], t) * y }\noutput a = M[2, 1], g = interp(M[:, 1], M[:, 2], y)\n\
             sim { T = 2 }\n"
                .to_string(),
            "m.csv",
            "time, gain\r\n0, 2\r\n0.5, 4\r\n1.5, 1e-3\r\n3, 0\r\n".to_string(),
        ),
        (bench("limit_agents.hyb"), "limit_agents_timers.csv", timers),
    ]
}

/// Fields that have broken CSV readers: non-finite and overflowing
/// numbers, other syntaxes, empty, quoted, full-width and control text.
const HOSTILE_FIELDS: &[&str] = &[
    "nan", "NaN", "inf", "-inf", "1e309", "-1e-320", "0x10", "abc", "", " ", "\"1\"", "1e", "--1",
    "+", ".", "1_000", "１", "1;2", "\u{0}", "1e308", "-0", "\t",
];

/// Applies one edit to a CSV file's bytes; returns what it did.
fn mutate_csv(rng: &mut ChaCha8Rng, bytes: &mut Vec<u8>) -> String {
    let text = String::from_utf8_lossy(bytes).into_owned();
    let mut lines: Vec<String> = text.split_inclusive('\n').map(str::to_string).collect();
    if lines.is_empty() {
        lines.push("1\n".into());
    }
    let i = below(rng, lines.len());
    let what = match below(rng, 14) {
        0..=3 => {
            // A field replaced by a hostile one.
            let eol = lines[i].len() - lines[i].trim_end_matches(['\r', '\n']).len();
            let (body, end) = lines[i].split_at(lines[i].len() - eol);
            let mut fields: Vec<String> = body.split(',').map(str::to_string).collect();
            let k = below(rng, fields.len());
            let new = *pick(rng, HOSTILE_FIELDS);
            fields[k] = new.to_string();
            lines[i] = format!("{}{end}", fields.join(","));
            format!("field {k} of line {i} -> {new:?}")
        }
        4 => {
            // Ragged: a field dropped or added.
            let body = lines[i].trim_end_matches(['\r', '\n']).to_string();
            lines[i] = if below(rng, 2) == 0 {
                match body.rsplit_once(',') {
                    Some((a, _)) => format!("{a}\n"),
                    None => "\n".into(),
                }
            } else {
                format!("{body},1\n")
            };
            format!("line {i} made ragged")
        }
        5 => {
            lines.remove(i);
            format!("delete line {i}")
        }
        6 => {
            let new = pick(rng, &["a,b\n", "# c\n", "\n", "\r\n", ",\n", "x\n"]).to_string();
            lines.insert(i, new.clone());
            format!("insert {new:?} at line {i}")
        }
        7 => {
            let k = if below(rng, 2) == 0 { 0 } else { i };
            lines.insert(k, "\u{feff}".into());
            format!("byte-order mark at line {k}")
        }
        8 => {
            let n = [1000, 20_000][below(rng, 2)];
            // A short line (not one an earlier edit made huge).
            let line = if lines[i].len() <= 64 {
                lines[i].clone()
            } else {
                "1\n".into()
            };
            lines.insert(i, line.repeat(n));
            format!("line {i} repeated {n} times")
        }
        9 => {
            let n = [1000, 20_000][below(rng, 2)];
            lines.insert(i, format!("{}\n", vec!["1"; n].join(",")));
            format!("a row of {n} fields at line {i}")
        }
        10 => {
            lines.clear();
            "empty the file".into()
        }
        11 => {
            for l in &mut lines {
                *l = l.replace('\n', "\r\n").replace("\r\r", "\r");
            }
            "CRLF".into()
        }
        12 => {
            let mut b = lines.concat().into_bytes();
            let k = below(rng, b.len() + 1);
            b.insert(k, [0xFF, 0x80, 0xC3][below(rng, 3)]);
            *bytes = b;
            return format!("a byte that is not UTF-8 at {k}");
        }
        _ => {
            let b = lines.concat().into_bytes();
            let k = below(rng, b.len() + 1);
            *bytes = b[..k].to_vec();
            return format!("truncated at byte {k}");
        }
    };
    *bytes = lines.concat().into_bytes();
    what
}

/// Input case `case`: even cases a shipped model with mutated overrides,
/// odd cases a data model with a mutated table (and at times an override).
fn input_case(
    subjects: &[Subject],
    hosts: &[(String, &str, String)],
    case: usize,
) -> (Input, Vec<String>) {
    let mut rng =
        ChaCha8Rng::seed_from_u64(!SEED ^ (case as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let overrides_case = case.is_multiple_of(2);
    let mut edits = Vec::new();
    let mut input;
    let words;
    if overrides_case {
        let models: Vec<&Subject> = subjects.iter().filter(|s| s.host.is_none()).collect();
        let s = models[(case / 2) % models.len()];
        input = Input::model(render(&s.tokens, &s.tail));
        edits.push(s.path.display().to_string());
        words = s.words.clone();
    } else {
        let (model, name, table) = &hosts[(case / 2) % hosts.len()];
        let mut bytes = table.clone().into_bytes();
        for _ in 0..1 + below(&mut rng, 3) {
            edits.push(mutate_csv(&mut rng, &mut bytes));
        }
        input = Input::model(model.as_str());
        input.tables.push((name.to_string(), bytes));
        let (tokens, _) = lex(model);
        words = tokens
            .into_iter()
            .filter(|t| t.kind == Kind::Word)
            .map(|t| t.text)
            .collect();
    }
    let n = if overrides_case {
        1 + below(&mut rng, 3)
    } else {
        below(&mut rng, 4) / 3
    };
    if !overrides_case && below(&mut rng, 8) == 0 {
        // A table over the size limit, without writing megabytes.
        input.overrides.push("max_matrix_elements=100".into());
        edits.push("max_matrix_elements=100".into());
    }
    for _ in 0..n {
        input.overrides.push(override_arg(&mut rng, &words));
    }
    (input, edits)
}

#[test]
fn overrides_and_tables_never_panic_hang_or_lose_a_location() {
    let plan = Plan::from_env(
        "HYBSIM_INPUT_MUTANTS",
        INPUT_CASES,
        MIN_INPUT_CASES,
        INPUT_BUDGET,
    );
    let subjects = Arc::new(subjects());
    let hosts = Arc::new(table_hosts());
    // The data models run unmutated (so every error of a case is its mutation's).
    for (model, name, table) in hosts.iter() {
        let mut input = Input::model(model.as_str());
        input
            .tables
            .push((name.to_string(), table.clone().into_bytes()));
        let r = input.run(&Budget::default());
        assert!(matches!(r, Ok(Outcome::Ran { .. })), "{model}: {r:?}");
    }
    let tally = run_cases(plan, {
        let (subjects, hosts) = (subjects.clone(), hosts.clone());
        move |k| {
            let (input, _) = input_case(&subjects, &hosts, k);
            input.run(&Budget::default()).map_err(|v| v.to_string())
        }
    });
    tally.assert_ok("override and table cases", &plan, |k, why| {
        let (input, edits) = input_case(&subjects, &hosts, k);
        let shown: Vec<String> = input
            .overrides
            .iter()
            .map(|o| o.chars().take(120).collect())
            .collect();
        let tables: Vec<String> = input
            .tables
            .iter()
            .map(|(n, b)| format!("{n}: {:?}", String::from_utf8_lossy(&b[..b.len().min(300)])))
            .collect();
        format!("case {k}: {edits:?}\n{why}\n--set {shown:?}\ntables {tables:?}\n")
    });
}
