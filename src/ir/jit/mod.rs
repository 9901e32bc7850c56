//! Machine code for register programs, generated with Cranelift.
//!
//! `compile` turns `Program`s (`ir::program`) into native functions
//! `fn(regs: *mut f64, rng: *mut SimRng)` with the interpreter's contract:
//! the fixed registers (`x`, `t`, `w`) are read from the register file and
//! every output register is written back to it, so a compiled program is a
//! drop-in replacement for `Program::run`'s interpreter, which stays the
//! reference and the fallback.
//!
//! **Bit-identical results.** Each instruction becomes the IEEE operation
//! the interpreter performs, in the same order: `+ − · /`, `√`, `|a|`,
//! `⌊a⌋` and comparisons inline (Cranelift neither fuses multiply–adds nor
//! reassociates), `Op::Lin` sums left to right as the
//! interpreter does, and every other function (`exp`, `sin`, `pow`, `min`,
//! …) is a call into Rust code that runs the interpreter's own
//! [`eval_un`](crate::check::dag::eval_un) / [`eval_bin`](crate::check::dag::eval_bin),
//! so both call the same libm functions. Random draws and matrix blocks
//! call the interpreter's own helpers too.
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

use std::sync::Arc;

use cranelift_codegen::settings::{self, Configurable};
use cranelift_jit::{JITBuilder, JITModule};

use super::program::Program;
use crate::engine::SimRng;

/// The largest program (instructions) compiled to machine code; larger ones
/// are interpreted. Cranelift's time and memory grow with the size of one
/// function; at this size a function compiles in well under a second.
pub const MAX_OPS: usize = 200_000;

/// The most code compiled for one model, in instructions plus
/// [`FUNCTION_COST`] per program: programs are compiled in the order given
/// (hottest first) while they fit, the rest are interpreted. This bounds
/// the compile time of huge models (thousands of jump maps).
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

/// `fn(regs, x, rng)`: state register `k < state_regs` is read from `x[k]`,
/// every other register from `regs`.
type Entry = unsafe extern "C" fn(*mut f64, *const f64, *mut SimRng);

/// A program's machine code.
#[derive(Clone)]
pub(crate) struct Native {
    _code: Arc<Code>,
    entry: Entry,
    nregs: usize,
    state_regs: usize,
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
        assert!(
            regs.len() >= self.nregs,
            "register file of {} < {} registers",
            regs.len(),
            self.nregs
        );
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        let regs = regs.as_mut_ptr();
        // SAFETY: the code reads and writes `regs[..nregs]` only (offsets
        // fixed at compile time; a state register is only written with the
        // value read from it), `rng` is null or a live exclusive reference,
        // and `_code` keeps the code memory alive.
        unsafe { (self.entry)(regs, regs, rng) }
    }

    /// Runs the code with the state registers read from `x` instead of
    /// `regs`; same contract as [`Program::run_at`].
    #[inline]
    pub fn run_at(&self, regs: &mut [f64], x: &[f64], rng: Option<&mut SimRng>) {
        assert!(
            regs.len() >= self.nregs && x.len() >= self.state_regs,
            "register file of {} < {} registers or state of {} < {} components",
            regs.len(),
            self.nregs,
            x.len(),
            self.state_regs
        );
        let rng = rng.map_or(std::ptr::null_mut(), |r| r as *mut SimRng);
        // SAFETY: as `run`; the code reads `x[..state_regs]` only (and
        // may copy it into `regs[..state_regs]`, as the interpreter does).
        unsafe { (self.entry)(regs.as_mut_ptr(), x.as_ptr(), rng) }
    }
}

/// Whether this machine has a Cranelift backend.
pub fn supported() -> bool {
    cranelift_native::builder().is_ok()
}

/// Compiles `programs` and attaches the machine code to each
/// ([`Program::run`] then uses it). Programs larger than [`MAX_OPS`]
/// instructions, and those that no longer fit into [`MAX_TOTAL_OPS`] when
/// their turn comes, are left to the interpreter. The first `hot` programs
/// (those evaluated at every integrator stage) get Cranelift's backtracking
/// register allocator, the others its single-pass one, which compiles about
/// 2.5 times faster for code about 10 % slower. Programs that compute
/// nothing (no instruction, no output: the diffusion of a model without
/// noise) need no code. Returns the number of programs that need no
/// interpreter: those compiled and those that compute nothing.
pub(crate) fn compile(programs: &mut [&mut Program], hot: usize) -> Result<usize, JitError> {
    let mut budget = MAX_TOTAL_OPS;
    let nothing = programs.iter().filter(|p| p.is_nothing()).count();
    let chosen: Vec<usize> = (0..programs.len())
        .filter(|&i| {
            if programs[i].is_nothing() {
                return false;
            }
            let len = programs[i].len();
            let fits = len <= MAX_OPS && len + FUNCTION_COST <= budget;
            if fits {
                budget -= len + FUNCTION_COST;
            }
            fits
        })
        .collect();
    if chosen.is_empty() {
        return Ok(nothing);
    }
    let split = chosen.partition_point(|&i| i < hot);
    let mut compiled = Vec::with_capacity(chosen.len());
    for (group, allocator) in [
        (&chosen[..split], "backtracking"),
        (&chosen[split..], "single_pass"),
    ] {
        if group.is_empty() {
            continue;
        }
        let refs: Vec<&Program> = group.iter().map(|&i| &*programs[i]).collect();
        let (code, entries) =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| build(&refs, allocator)))
                .unwrap_or_else(|_| Err(JitError::Codegen("the code generator panicked".into())))?;
        let code = Arc::new(code);
        compiled.extend(
            group
                .iter()
                .zip(entries)
                .map(|(&i, e)| (i, e, code.clone())),
        );
    }
    for (i, entry, code) in compiled {
        let (nregs, state_regs) = (programs[i].nregs, programs[i].state_regs);
        programs[i].set_native(Native {
            _code: code,
            entry,
            nregs,
            state_regs,
        });
    }
    Ok(chosen.len() + nothing)
}

/// The host's ISA with the given register allocator.
fn isa(allocator: &str) -> Result<cranelift_codegen::isa::OwnedTargetIsa, JitError> {
    let mut flags = settings::builder();
    let set = |f: &mut settings::Builder, k: &str, v: &str| {
        f.set(k, v)
            .map_err(|e| JitError::Codegen(format!("flag {k}: {e}")))
    };
    set(&mut flags, "opt_level", "speed")?;
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

fn build(programs: &[&Program], allocator: &str) -> Result<(Code, Vec<Entry>), JitError> {
    let jb = JITBuilder::with_isa(isa(allocator)?, cranelift_module::default_libcall_names());
    let mut module = JITModule::new(jb);
    let mut generator = codegen::Generator::new(&module);
    let mut ids = Vec::with_capacity(programs.len());
    let mut blocks = Vec::new();
    let mut tables = Vec::new();
    for p in programs {
        tables.extend(p.tables.iter().cloned());
        let descs = helpers::block_descs(p);
        let id = generator.define(&mut module, p, &descs)?;
        blocks.push(descs);
        ids.push(id);
    }
    module
        .finalize_definitions()
        .map_err(|e| JitError::Codegen(e.to_string()))?;
    let entries = ids
        .into_iter()
        .map(|id| {
            let ptr = module.get_finalized_function(id);
            // SAFETY: the function was defined with the signature
            // `(ptr, ptr, ptr) -> ()` in the platform's C convention.
            unsafe { std::mem::transmute::<*const u8, Entry>(ptr) }
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
        isa("single_pass").expect("a supported machine"),
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
