//! Machine code for register programs, generated with Cranelift.
//!
//! `Jit` turns `Program`s (`ir::program`) into native functions
//! `fn(regs: *mut f64, x: *const f64, rng: *mut SimRng, out: *mut f64)` with the
//! interpreter's contract: the fixed registers (`x`, `t`, `w`) are read from the register
//! file and every output register is written back to it (with `out` null), so a compiled
//! program is a drop-in replacement for `Program::run`'s interpreter, which stays the
//! reference and the fallback. A program given positions (`Program::scatter_to`) stores its
//! outputs into the caller's buffer `out` instead, each at its position
//! (`Program::run_into`), which saves the caller a gather.
//!
//! **Tiers.** A program starts interpreted and is compiled by the thread
//! that runs it for the [`TIER_UP_CALLS`]-th time, each program into its
//! own code memory (`Tier`: a call counter and the code, set once), so a
//! run pays Cranelift only for the programs it evaluates often. Results do
//! not depend on when a program changes tier: both compute the same bits.
//!
//! **Bit-identical results.** Each instruction becomes the IEEE operation
//! the interpreter performs, in the same order: `+ − · /`, `√`, `|a|`,
//! `⌊a⌋` and comparisons inline (Cranelift neither fuses multiply–adds nor
//! reassociates), `Op::Lin` sums left to right as the
//! interpreter does (a term `x · 1` as `x`, `s + x · (−1)` as `s − x`:
//! exact), and every other function (`exp`, `sin`, `pow`, `min`,
//! …) is a call into Rust code that runs the interpreter's own
//! [`eval_un`](crate::check::dag::eval_un) / [`eval_bin`](crate::check::dag::eval_bin),
//! so both call the same libm functions (the unary ones through a small per-thread memo of
//! their last results: the same argument's bits give the same value). Random draws and matrix blocks
//! call the interpreter's own helpers too. Two instructions computed
//! together in the lanes of a vector (`pairs.rs`: neighbouring entries of a
//! matrix product) each get their own lane's IEEE operation, in the same
//! order, so vectors change no bit either (a NaN's payload aside, as in
//! the sums).
//!
//! **Safety.** Generated code addresses only the register file, at offsets
//! below the program's register count fixed at compile time; `Native::run`
//! checks that the file it is given is that long. Code memory lives as long
//! as any program compiled with it ([`Arc`]). A program with more than
//! [`MAX_OPS`] instructions is not compiled (it stays interpreted), which
//! bounds the compiler's time and memory; a machine Cranelift does not
//! support gets [`JitError::Unsupported`] and the interpreter.

mod codegen;
mod helpers;
mod pairs;

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use cranelift_codegen::isa::OwnedTargetIsa;
use cranelift_codegen::settings::{self, Configurable};
use cranelift_jit::{JITBuilder, JITModule};

use super::program::Program;
use crate::engine::SimRng;

/// The largest program (instructions) compiled to machine code; larger ones
/// are interpreted. Cranelift's time and memory grow with the size of one
/// function; at this size a function compiles in well under a second.
pub const MAX_OPS: usize = 200_000;

/// The most code compiled for one model, in instructions plus
/// [`FUNCTION_COST`] per program: programs are compiled as they become hot
/// while they fit, the rest are interpreted. This bounds the compile time
/// of huge models (thousands of jump maps).
pub const MAX_TOTAL_OPS: usize = 40_000;

/// What one program counts against [`MAX_TOTAL_OPS`] besides its
/// instructions (Cranelift's fixed cost per function).
pub const FUNCTION_COST: usize = 50;

/// Why machine code could not be generated.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JitError {
    /// Cranelift has no backend for this machine.
    #[error("Cranelift does not support this machine ({0})")]
    Unsupported(String),
    /// Cranelift rejected the generated function (a bug of the generator).
    #[error("machine-code generation failed: {0}")]
    Codegen(String),
}

/// The code memory of one compilation; freed when the last program compiled
/// with it is dropped.
struct Code {
    module: Option<JITModule>,
    /// Descriptors of the block operations, addressed by the code.
    _blocks: Vec<Box<[helpers::BlockDesc]>>,
    /// The term tables of the loop nests, addressed by the code.
    // Boxed: the code holds their addresses, which must not move.
    #[allow(clippy::vec_box)]
    _loops: Vec<Box<helpers::Nest>>,
    /// The tables the code addresses (also held by the programs; kept
    /// here so that the code never outlives them).
    _tables: Vec<Arc<crate::check::dag::Table>>,
}

// SAFETY: after `finalize_definitions` the module's memory is read-only
// executable code and immutable descriptors; nothing mutates it until drop.
unsafe impl Send for Code {}
// SAFETY: see `Send`: shared references only read immutable memory.
unsafe impl Sync for Code {}

impl Drop for Code {
    fn drop(&mut self) {
        if let Some(module) = self.module.take() {
            // SAFETY: every `Native` holding a pointer into this memory holds
            // an `Arc<Code>`, so none is left when `Code` drops.
            unsafe { module.free_memory() };
        }
    }
}

/// `fn(regs, x, rng, out, t, j)`: state register `k < state_regs` is read
/// from `x[k]`, the time and jump-count registers are `t` and `j`, every
/// other register is read from `regs`; output `k` is written to its
/// register, or to `out[dest[k]]` for a program with positions (`out`
/// unused otherwise).
type Entry = unsafe extern "C" fn(*mut f64, *const f64, *mut SimRng, *mut f64, f64, f64);

/// A program's machine code.
#[derive(Clone)]
pub(crate) struct Native {
    _code: Arc<Code>,
    entry: Entry,
    nregs: usize,
    state_regs: usize,
    /// For a program with positions (`Program::scatter_to`), the length
    /// its output buffer needs; `None`: it writes into the registers.
    dest_len: Option<usize>,
    /// Whether the code touches the register file: code that reads no
    /// fixed register, calls no block or loop and writes its outputs to a
    /// buffer keeps every value in machine registers or its own stack, and
    /// runs without one ([`run_into_without_regs`](Self::run_into_without_regs)).
    needs_regs: bool,
}

impl std::fmt::Debug for Native {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Native")
            .field("nregs", &self.nregs)
            .finish_non_exhaustive()
    }
}

impl Native {
    /// Runs the code on `regs` (fixed registers already filled); same
    /// contract as [`Program::run`].
    #[inline]
    pub fn run(&self, regs: &mut [f64], rng: Option<&mut SimRng>) {
        if regs.len() < self.nregs || self.dest_len.is_some() {
            self.bad_call(regs.len(), regs.len(), None);
        }
        let [t, j] = self.clock_in(regs);
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        let regs = regs.as_mut_ptr();
        // SAFETY: the code reads and writes `regs[..nregs]` only (offsets
        // fixed at compile time; a state register is only written with the
        // value read from it), `rng` is null or a live exclusive reference,
        // and `_code` keeps the code memory alive.
        unsafe { (self.entry)(regs, regs, rng, std::ptr::null_mut(), t, j) }
    }

    /// Runs the code with the state registers read from `x` and the time
    /// and jump count `clock` instead of `regs`; same contract as
    /// [`Program::run_at`].
    #[inline]
    pub fn run_at(&self, regs: &mut [f64], x: &[f64], rng: Option<&mut SimRng>, clock: [f64; 2]) {
        if regs.len() < self.nregs || x.len() < self.state_regs || self.dest_len.is_some() {
            self.bad_call(regs.len(), x.len(), None);
        }
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        let [t, j] = clock;
        // SAFETY: as `run`; the code reads `x[..state_regs]` only (and
        // may copy it into `regs[..state_regs]`, as the interpreter does).
        unsafe {
            (self.entry)(
                regs.as_mut_ptr(),
                x.as_ptr(),
                rng,
                std::ptr::null_mut(),
                t,
                j,
            )
        }
    }

    /// The code of a program with positions: as [`run_at`](Self::run_at),
    /// with the outputs stored into `out` at their positions; same
    /// contract as [`Program::run_into`].
    #[inline]
    pub fn run_into(
        &self,
        regs: &mut [f64],
        x: &[f64],
        rng: Option<&mut SimRng>,
        out: &mut [f64],
        clock: [f64; 2],
    ) {
        // `usize::MAX` without positions: no buffer is long enough.
        let need = self.dest_len.unwrap_or(usize::MAX);
        if regs.len() < self.nregs || x.len() < self.state_regs || out.len() < need {
            self.bad_call(regs.len(), x.len(), Some(out.len()));
        }
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        let [t, j] = clock;
        // SAFETY: as `run_at`; the code writes `out[..dest_len]` only
        // (positions fixed at compile time) and does not read it.
        unsafe { (self.entry)(regs.as_mut_ptr(), x.as_ptr(), rng, out.as_mut_ptr(), t, j) }
    }

    /// Whether the code runs without a register file
    /// ([`run_into_without_regs`](Self::run_into_without_regs)).
    #[inline]
    pub fn runs_without_regs(&self) -> bool {
        !self.needs_regs && self.dest_len.is_some()
    }

    /// [`run_into`](Self::run_into) for code that touches no register file
    /// ([`runs_without_regs`](Self::runs_without_regs)): no thread-local
    /// buffer to borrow.
    ///
    /// # Panics
    /// If the code needs a register file, or a buffer is too short.
    #[inline]
    pub fn run_into_without_regs(
        &self,
        x: &[f64],
        rng: Option<&mut SimRng>,
        out: &mut [f64],
        clock: [f64; 2],
    ) {
        let need = self.dest_len.unwrap_or(usize::MAX);
        if self.needs_regs || x.len() < self.state_regs || out.len() < need {
            self.bad_call(0, x.len(), Some(out.len()));
        }
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        let regs = std::ptr::NonNull::<f64>::dangling().as_ptr();
        let [t, j] = clock;
        // SAFETY: as `run_into`; the code was generated without any access
        // to the register file (`needs_regs` false), so the dangling
        // pointer is never dereferenced.
        unsafe { (self.entry)(regs, x.as_ptr(), rng, out.as_mut_ptr(), t, j) }
    }

    /// The code of a program with positions: as [`run`](Self::run), with
    /// the outputs stored into `out` as by [`run_into`](Self::run_into).
    #[inline]
    pub fn run_regs_into(&self, regs: &mut [f64], rng: Option<&mut SimRng>, out: &mut [f64]) {
        let need = self.dest_len.unwrap_or(usize::MAX);
        if regs.len() < self.nregs || out.len() < need {
            self.bad_call(regs.len(), regs.len(), Some(out.len()));
        }
        let [t, j] = self.clock_in(regs);
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        let regs = regs.as_mut_ptr();
        // SAFETY: as `run` and `run_into`.
        unsafe { (self.entry)(regs, regs, rng, out.as_mut_ptr(), t, j) }
    }

    /// The time and jump count in a register file the caller filled (a
    /// program's registers include its fixed ones: `nregs ≥ state_regs + 2`,
    /// checked by the callers).
    #[inline]
    fn clock_in(&self, regs: &[f64]) -> [f64; 2] {
        [regs[self.state_regs], regs[self.state_regs + 1]]
    }

    /// The panic of a call with buffers too short for the code, or of the
    /// wrong kind of call for it (a bug of the caller): out of line, so
    /// that each call's checks are a few compares.
    #[cold]
    #[inline(never)]
    fn bad_call(&self, regs: usize, x: usize, out: Option<usize>) -> ! {
        panic!(
            "machine code of {} registers, {} state components and outputs to a buffer of \
             {:?} called with a register file of {regs}, a state of {x} and an output buffer \
             of {out:?}",
            self.nregs, self.state_regs, self.dest_len
        )
    }
}

/// Whether this machine has a Cranelift backend.
pub fn supported() -> bool {
    cranelift_native::builder().is_ok()
}

/// Calls a program is interpreted before it gets machine code. Cranelift
/// takes as long to compile a program as the interpreter takes to run it
/// a few thousand times, so code for a program run only a few times (the
/// initial values, the sets' predicates checked at rare events, outputs
/// no sink asks for, rules that never fire) is never worth generating;
/// the programs evaluated at every step pass this count in the first
/// steps of a run.
pub const TIER_UP_CALLS: u32 = 64;

/// The machine-code generator of one model, shared by its programs (and
/// the copies of the model that sweep threads use): when a program has
/// been interpreted [`TIER_UP_CALLS`] times (see [`Jit::attach`]), the
/// thread running it compiles it into its own code memory and attaches
/// the code, which every later call (in any thread) runs. Programs larger
/// than [`MAX_OPS`] instructions, and those that no longer fit into
/// [`MAX_TOTAL_OPS`] when they become hot, stay interpreted.
#[derive(Debug)]
pub(crate) struct Jit {
    /// Calls before a newly attached program is compiled (0: at once).
    after: AtomicU32,
    /// What is left of [`MAX_TOTAL_OPS`].
    budget: AtomicUsize,
    /// Programs attached.
    attached: AtomicUsize,
    /// Programs that need no interpreter: compiled, or computing nothing.
    native: AtomicUsize,
    /// Time spent generating code.
    nanos: AtomicU64,
    /// The first code-generation failure (a bug of the generator).
    error: OnceLock<JitError>,
}

/// How a program is compiled once it is hot.
#[derive(Debug, Clone)]
struct Plan {
    jit: Arc<Jit>,
    /// Calls before it is compiled.
    after: u32,
    /// Evaluated at every integrator stage or choice between flowing and
    /// jumping (`CompiledModel::programs`): Cranelift's backtracking
    /// register allocator, else its single-pass one, which compiles about
    /// 2.5 times faster for code 10–40 % slower (more on large programs).
    hot: bool,
}

/// A program's machine code, compiled when the program becomes hot
/// (one field of [`Program`]).
#[derive(Debug, Default)]
pub(crate) struct Tier {
    code: OnceLock<Native>,
    plan: OnceLock<Plan>,
    /// Interpreted calls so far (counted up to the plan's `after`).
    calls: AtomicU32,
    /// Whether a thread has taken on compiling it.
    claimed: AtomicBool,
}

impl Clone for Tier {
    fn clone(&self) -> Self {
        Self {
            code: self.code.clone(),
            plan: self.plan.clone(),
            calls: AtomicU32::new(self.calls.load(Ordering::Relaxed)),
            claimed: AtomicBool::new(self.claimed.load(Ordering::Relaxed)),
        }
    }
}

impl Tier {
    /// The machine code of `p` (whose tier this is), compiling it first
    /// if this call makes it hot; `None`: interpret.
    #[inline]
    pub fn code(&self, p: &Program) -> Option<&Native> {
        if let Some(code) = self.code.get() {
            return Some(code);
        }
        let plan = self.plan.get()?;
        // Counting stops at the threshold: a program left to the
        // interpreter costs one load per call, and threads share no
        // counter they keep writing.
        if self.calls.load(Ordering::Relaxed) >= plan.after
            || self.calls.fetch_add(1, Ordering::Relaxed) + 1 < plan.after
        {
            return None;
        }
        plan.jit.tier_up(p, plan.hot);
        self.code.get()
    }

    /// The machine code attached, without counting the call or compiling
    /// (the callers' inlined fast path; [`code`](Self::code) does the rest).
    #[inline]
    pub fn attached(&self) -> Option<&Native> {
        self.code.get()
    }

    /// Whether no machine code is attached yet.
    pub fn code_is_unset(&self) -> bool {
        self.code.get().is_none()
    }

    /// Whether machine code is attached.
    #[cfg(test)]
    pub fn is_native(&self) -> bool {
        self.code.get().is_some()
    }
}

impl Jit {
    /// A generator for one model that compiles each program after `after`
    /// interpreted calls (0: when it is attached);
    /// [`JitError::Unsupported`] on a machine Cranelift does not support.
    pub fn new(after: u32) -> Result<Arc<Self>, JitError> {
        isas()?;
        Ok(Arc::new(Self {
            after: AtomicU32::new(after),
            budget: AtomicUsize::new(MAX_TOTAL_OPS),
            attached: AtomicUsize::new(0),
            native: AtomicUsize::new(0),
            nanos: AtomicU64::new(0),
            error: OnceLock::new(),
        }))
    }

    /// Gives `p` to this generator (`hot`: see [`Plan::hot`]); it is
    /// compiled once it has been interpreted the generator's number of
    /// calls (at once if that is 0). A program that computes nothing (no
    /// instruction, no output: the diffusion of a model without noise)
    /// needs no code. A program attached before is left as it is.
    pub fn attach(self: &Arc<Self>, p: &Program, hot: bool) {
        if p.is_nothing() {
            self.attached.fetch_add(1, Ordering::Relaxed);
            self.native.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let after = self.after.load(Ordering::Relaxed);
        let plan = Plan {
            jit: self.clone(),
            after,
            hot,
        };
        if p.tier.plan.set(plan).is_err() {
            return;
        }
        self.attached.fetch_add(1, Ordering::Relaxed);
        if after == 0 {
            self.tier_up(p, hot);
        }
    }

    /// Compiles every program attached so far (if not compiled yet and
    /// within the budget, in the order given) and from now on every
    /// program when it is attached: for callers that want every program
    /// as machine code before the first run (tests, compile-time
    /// measurements).
    pub fn compile_all<'a>(&self, programs: impl IntoIterator<Item = &'a Program>) {
        self.after.store(0, Ordering::Relaxed);
        // Into one code memory per register allocator: a Cranelift module
        // costs tens of microseconds, which a model of hundreds of
        // programs would pay for each.
        let (mut hot, mut cold) = (Vec::new(), Vec::new());
        for p in programs {
            if let Some(plan) = p.tier.plan.get()
                && self.claim(p)
            {
                if plan.hot { &mut hot } else { &mut cold }.push(p);
            }
        }
        self.compile(&hot, true);
        self.compile(&cold, false);
    }

    /// Programs that need no interpreter (compiled or computing nothing)
    /// and programs attached, so far.
    pub fn counts(&self) -> (usize, usize) {
        (
            self.native.load(Ordering::Relaxed),
            self.attached.load(Ordering::Relaxed),
        )
    }

    /// Time spent generating code so far.
    pub fn time(&self) -> Duration {
        Duration::from_nanos(self.nanos.load(Ordering::Relaxed))
    }

    /// The first code-generation failure, if any.
    pub fn error(&self) -> Option<&JitError> {
        self.error.get()
    }

    /// Compiles `p` and attaches its code, unless another thread has taken
    /// it on, it is too large, or the budget is spent (then it stays
    /// interpreted).
    #[cold]
    #[inline(never)]
    fn tier_up(&self, p: &Program, hot: bool) {
        if self.claim(p) {
            self.compile(&[p], hot);
        }
    }

    /// Whether `p` is this caller's to compile: no other thread has taken
    /// it on, it is not too large, and it fits into the budget (charged).
    fn claim(&self, p: &Program) -> bool {
        if p.tier.claimed.swap(true, Ordering::AcqRel) {
            return false;
        }
        let len = p.len();
        let cost = len + FUNCTION_COST;
        // Offsets into the register file and the output buffer are 32-bit.
        let addressable = p.nregs.max(p.dest_len) <= i32::MAX as usize / 8;
        len <= MAX_OPS
            && addressable
            && self
                .budget
                .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |b| {
                    b.checked_sub(cost)
                })
                .is_ok()
    }

    /// Compiles `programs` (claimed) into one code memory and attaches
    /// each its code.
    fn compile(&self, programs: &[&Program], hot: bool) {
        if programs.is_empty() {
            return;
        }
        let start = Instant::now();
        let built = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| build(programs, hot)))
            .unwrap_or_else(|_| Err(JitError::Codegen("the code generator panicked".into())));
        match built {
            Ok((code, entries)) => {
                let code = Arc::new(code);
                for (p, (entry, needs_regs)) in programs.iter().zip(entries) {
                    let native = Native {
                        _code: code.clone(),
                        entry,
                        nregs: p.nregs,
                        state_regs: p.state_regs,
                        dest_len: p.dest.as_ref().map(|_| p.dest_len),
                        needs_regs,
                    };
                    if p.tier.code.set(native).is_ok() {
                        self.native.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            Err(e) => {
                let _ = self.error.set(e);
            }
        }
        let spent = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.nanos.fetch_add(spent, Ordering::Relaxed);
    }
}

/// The host's ISA with each register allocator (backtracking, single
/// pass), built once per process.
fn isas() -> Result<&'static [OwnedTargetIsa; 2], JitError> {
    static ISAS: OnceLock<Result<[OwnedTargetIsa; 2], JitError>> = OnceLock::new();
    ISAS.get_or_init(|| Ok([isa("backtracking")?, isa("single_pass")?]))
        .as_ref()
        .map_err(Clone::clone)
}

/// The host's ISA with the given register allocator.
fn isa(allocator: &str) -> Result<OwnedTargetIsa, JitError> {
    let mut flags = settings::builder();
    let set = |f: &mut settings::Builder, k: &str, v: &str| {
        f.set(k, v)
            .map_err(|e| JitError::Codegen(format!("flag {k}: {e}")))
    };
    // The generator's code comes folded, shared and paired: Cranelift's
    // e-graph pass found nothing to gain on the shipped models and cost
    // ~30 % of the compile time.
    set(&mut flags, "opt_level", "none")?;
    set(&mut flags, "regalloc_algorithm", allocator)?;
    // The generator's output is checked by the tests; verifying every
    // function again costs a fifth of the compile time.
    set(&mut flags, "enable_verifier", "false")?;
    // cranelift-jit needs absolute, non-PIC relocations.
    set(&mut flags, "use_colocated_libcalls", "false")?;
    set(&mut flags, "is_pic", "false")?;
    let builder = cranelift_native::builder().map_err(|e| JitError::Unsupported(e.into()))?;
    builder
        .finish(settings::Flags::new(flags))
        .map_err(|e| JitError::Unsupported(e.to_string()))
}

/// Compiles `programs` into one code memory (`hot`: see [`Plan::hot`]):
/// each one's entry, and whether its code touches the register file.
fn build(programs: &[&Program], hot: bool) -> Result<(Code, Vec<(Entry, bool)>), JitError> {
    let isa = isas()?[usize::from(!hot)].clone();
    let jb = JITBuilder::with_isa(isa, cranelift_module::default_libcall_names());
    let mut module = JITModule::new(jb);
    let mut generator = codegen::Generator::new(&module);
    let mut ids = Vec::with_capacity(programs.len());
    let mut blocks = Vec::new();
    let mut tables = Vec::new();
    for p in programs {
        tables.extend(p.tables.iter().cloned());
        let descs = helpers::block_descs(p);
        let (id, needs_regs) = generator.define(&mut module, p, &descs)?;
        blocks.push(descs);
        ids.push((id, needs_regs));
    }
    module
        .finalize_definitions()
        .map_err(|e| JitError::Codegen(e.to_string()))?;
    let entries = ids
        .into_iter()
        .map(|(id, needs_regs)| {
            let ptr = module.get_finalized_function(id);
            // SAFETY: the function was defined with the signature
            // `(ptr, ptr, ptr, ptr) -> ()` in the platform's C convention.
            let entry = unsafe { std::mem::transmute::<*const u8, Entry>(ptr) };
            (entry, needs_regs)
        })
        .collect();
    Ok((
        Code {
            module: Some(module),
            _blocks: blocks,
            _loops: std::mem::take(&mut generator.tables),
            _tables: tables,
        },
        entries,
    ))
}

/// The number of Cranelift instructions generated for `p` (the work-count
/// tests': code size, not time).
#[cfg(test)]
fn instructions(p: &Program) -> usize {
    let jb = JITBuilder::with_isa(
        isas().expect("a supported machine")[1].clone(),
        cranelift_module::default_libcall_names(),
    );
    let mut module = JITModule::new(jb);
    let mut generator = codegen::Generator::new(&module);
    let descs = helpers::block_descs(p);
    generator
        .define(&mut module, p, &descs)
        .expect("the program compiles");
    generator.instructions
}

#[cfg(test)]
mod tests;
