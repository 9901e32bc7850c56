//! Translation of one register program into a Cranelift function.
//!
//! Programs are straight-line code (a selection is a `select`, not a
//! branch), so each becomes basic blocks in SSA form: a register's value
//! is the Cranelift value that defined it; the state registers are loaded
//! from the state pointer, the time and jump count are arguments, the
//! noise registers and the block outputs are loaded from the register
//! file, on first use; each output is stored as soon
//! as its register is defined, into the register file or, for a program
//! given positions in its caller's buffer, there (stores at the end kept
//! every output live through the whole function, which made Cranelift's
//! register allocation half as slow again on a large flow).
//!
//! **Sums as loops.** The checker scalarizes matrix work: the entries of
//! `A * X` are [`Op::Lin`] sums of `cₖ·xₖ` over a row, `n³` terms for
//! `n × n` matrices. Straight-line code for them (two instructions per
//! term) makes Cranelift's time grow with the number of terms. Instead,
//! sums of at least [`LOOP_LEN`] register terms are deferred until an
//! instruction reads one (or the program ends), and a group of at least
//! [`LOOP_TERMS`] terms becomes a table of terms (register, coefficient)
//! and one call of [`helpers::sums`], a loop over the table: the same
//! products added in the same order, so the result is the same to the
//! bit, and the code grows with the number of instructions, not of
//! terms. The loop reads its operands from the register file, so each
//! operand that so far lives only in a machine register (or in the state)
//! is stored there first, once per program; its results are written to
//! the register file.
//!
//! **Pairs.** Two isomorphic instructions that [`pairs::plan`] pairs are
//! emitted together, at the first one's place, as one `F64X2` instruction
//! on packed operands (see [`Emit::pack`]); a register computed in a lane
//! stays in its vector until a scalar instruction or a store needs it.

use cranelift_codegen::Context;
use cranelift_codegen::ir::condcodes::FloatCC;
use cranelift_codegen::ir::{
    AbiParam, ConstantData, InstBuilder, MemFlagsData, SigRef, Signature, Type, UserFuncName,
    Value, types,
};
use cranelift_frontend::{FunctionBuilder, FunctionBuilderContext};
use cranelift_jit::JITModule;
use cranelift_module::{FuncId, Linkage, Module};
use rustc_hash::FxHashMap as HashMap;

use super::JitError;
use super::helpers::{self, BlockDesc};
use super::pairs::{self, Slot};
use crate::check::dag::{BinFn, UnFn};
use crate::ir::program::{CONST_TERM, Op, Program};

/// The fewest terms a group of sums needs to become a loop. Below it the
/// sums are straight-line code (immediates, no table to load); 64 terms
/// are ~130 instructions inline, a call and the stores of its operands
/// as a loop.
pub(crate) const LOOP_TERMS: usize = 64;

/// The fewest terms a sum needs to go into a loop: a shorter one
/// (`a + b`, a 4 × 4 product's row) is no matrix work, runs faster inline
/// and costs few instructions there.
pub(crate) const LOOP_LEN: usize = 8;

/// How many sums of equal length advance together (their terms
/// interleaved in the table): independent additions the processor
/// overlaps, as it overlaps the sums of straight-line code.
const WIDTH: usize = 4;

/// The sums of `p` that may go into a loop nest: at least [`LOOP_LEN`]
/// terms, none of them a constant.
fn loopable(p: &Program, op: &Op) -> bool {
    match *op {
        Op::Lin { t0, len, .. } => {
            len as usize >= LOOP_LEN
                && p.lin[t0 as usize..(t0 + len) as usize]
                    .iter()
                    .all(|&(r, _)| r != CONST_TERM)
        }
        _ => false,
    }
}

/// Translates programs one after the other, reusing Cranelift's buffers.
pub(super) struct Generator {
    ctx: Context,
    fctx: FunctionBuilderContext,
    count: u32,
    /// The tables of the loop nests generated so far.
    // Boxed: the code holds their addresses, which must not move.
    #[allow(clippy::vec_box)]
    pub tables: Vec<Box<helpers::Nest>>,
    /// Cranelift instructions generated so far (the work-count tests').
    pub instructions: usize,
}

/// The imported signatures of the helpers, per function.
struct Sigs {
    un: SigRef,
    bin: SigRef,
    rand: SigRef,
    block: SigRef,
    lookup: SigRef,
    interp: SigRef,
}

/// State of the translation of one program.
struct Emit<'a, 'b> {
    b: &'b mut FunctionBuilder<'a>,
    ptr: Type,
    regs: Value,
    /// Whether the code reads or writes the register file (`regs` asked
    /// for through [`Emit::regs`]).
    uses_regs: bool,
    /// The time and the jump count, passed as arguments: an instruction
    /// that reads their registers reads these.
    clock: [Value; 2],
    /// Where the state registers are read from.
    x: Value,
    state_regs: u32,
    rng: Value,
    vals: Vec<Option<Value>>,
    /// The vector and lane of each register a pair of instructions
    /// computed (see [`pairs`]); its scalar is extracted into `vals` when
    /// an instruction of one lane reads it.
    lanes: Vec<Option<(Value, u8)>>,
    /// Splats and gathers of two registers, made once.
    packed: HashMap<(u32, u32), Value>,
    /// Scalar and vector constants by their bits, each made once: the code
    /// is one block, so a value made anywhere dominates every later use.
    consts: HashMap<u64, Value>,
    vconsts: HashMap<(u64, u64), Value>,
    /// Registers whose value so far lives only in `vals` (not yet stored
    /// into the register file).
    dirty: Vec<bool>,
    /// State registers copied into the register file (for the loops).
    copied: Vec<bool>,
    /// The outputs as (register, position) sorted by register: each is
    /// stored as soon as its register is defined, so that no value stays
    /// live to the end of the program (Cranelift's register allocation
    /// time and spills grow with the values live at once).
    outputs: Vec<(u32, u32)>,
    /// Where outputs go: the caller's buffer (a program with positions)
    /// or, if `None`, the register file.
    out: Option<Value>,
    /// Registers whose outputs are stored already.
    stored: Vec<bool>,
    sigs: Sigs,
    // Boxed: the code holds their addresses, which must not move.
    #[allow(clippy::vec_box)]
    tables: &'b mut Vec<Box<helpers::Nest>>,
}

fn sig(module: &JITModule, params: &[Type], ret: Option<Type>) -> Signature {
    let mut s = module.make_signature();
    s.params.extend(params.iter().map(|&t| AbiParam::new(t)));
    s.returns.extend(ret.map(AbiParam::new));
    s
}

impl Generator {
    pub fn new(module: &JITModule) -> Self {
        Self {
            ctx: module.make_context(),
            fctx: FunctionBuilderContext::new(),
            count: 0,
            tables: Vec::new(),
            instructions: 0,
        }
    }

    /// Defines `p` in `module`; `blocks` are its block descriptors (kept
    /// alive by the caller as long as the code). With the function: whether
    /// its code touches the register file at all.
    pub fn define(
        &mut self,
        module: &mut JITModule,
        p: &Program,
        blocks: &[BlockDesc],
    ) -> Result<(FuncId, bool), JitError> {
        let ptr = module.target_config().pointer_type();
        let f64t = types::F64;
        let entry_sig = sig(module, &[ptr, ptr, ptr, ptr, f64t, f64t], None);
        let name = format!("program{}", self.count);
        self.count += 1;
        let id = module
            .declare_function(&name, Linkage::Local, &entry_sig)
            .map_err(|e| JitError::Codegen(e.to_string()))?;
        module.clear_context(&mut self.ctx);
        self.ctx.func.signature = entry_sig;
        let uses_regs;
        self.ctx.func.name = UserFuncName::user(0, id.as_u32());
        {
            let mut b = FunctionBuilder::new(&mut self.ctx.func, &mut self.fctx);
            let block = b.create_block();
            b.append_block_params_for_function_params(block);
            b.switch_to_block(block);
            let params = b.block_params(block);
            let (regs, x, rng, out) = (params[0], params[1], params[2], params[3]);
            let clock = [params[4], params[5]];
            let sigs = Sigs {
                un: b.import_signature(sig(module, &[f64t], Some(f64t))),
                bin: b.import_signature(sig(module, &[f64t, f64t], Some(f64t))),
                rand: b.import_signature(sig(module, &[ptr, f64t, f64t], Some(f64t))),
                block: b.import_signature(sig(module, &[ptr, ptr], None)),
                lookup: b.import_signature(sig(
                    module,
                    &[ptr, f64t, f64t, types::I32, f64t, f64t, f64t],
                    Some(f64t),
                )),
                interp: b.import_signature(sig(module, &[ptr, f64t, types::I32], Some(f64t))),
            };
            let mut e = Emit {
                b: &mut b,
                ptr,
                regs,
                uses_regs: false,
                clock,
                x,
                state_regs: p.state_regs as u32,
                rng,
                vals: vec![None; p.nregs],
                lanes: vec![None; p.nregs],
                packed: HashMap::default(),
                consts: HashMap::default(),
                vconsts: HashMap::default(),
                dirty: vec![false; p.nregs],
                copied: vec![false; p.state_regs],
                outputs: outputs(p),
                out: p.dest.as_ref().map(|_| out),
                stored: vec![false; p.nregs],
                sigs,
                tables: &mut self.tables,
            };
            e.program(p, blocks, out);
            uses_regs = e.uses_regs;
            b.seal_all_blocks();
            b.finalize(module.target_config());
        }
        self.instructions += self.ctx.func.dfg.num_insts();
        module
            .define_function(id, &mut self.ctx)
            .map_err(|e| JitError::Codegen(format!("{e:?}")))?;
        Ok((id, uses_regs))
    }
}

/// `p`'s outputs as (register, position in the output buffer or, without
/// positions, the register itself), sorted, each once.
fn outputs(p: &Program) -> Vec<(u32, u32)> {
    let mut outputs: Vec<(u32, u32)> = match &p.dest {
        Some(dest) => p.outs.iter().copied().zip(dest.iter().copied()).collect(),
        None => p.outs.iter().map(|&o| (o, o)).collect(),
    };
    outputs.sort_unstable();
    outputs.dedup();
    outputs
}

/// Vector accesses: two `f64` are 8-byte aligned, not 16.
const UNALIGNED: MemFlagsData = MemFlagsData::new().with_notrap();

fn offset(r: u32) -> i32 {
    // Register files are far below 2³¹ / 8 registers (`Program` indexes
    // them with u32 and the JIT's size limit bounds them further).
    (r as usize * 8) as i32
}

impl Emit<'_, '_> {
    fn get(&mut self, r: u32) -> Value {
        if self.vals[r as usize].is_none()
            && let Some((v, lane)) = self.lanes[r as usize]
        {
            let v = self.b.ins().extractlane(v, lane);
            self.vals[r as usize] = Some(v);
        }
        match self.vals[r as usize] {
            Some(v) => v,
            None if r == self.state_regs || r == self.state_regs + 1 => {
                self.clock[(r - self.state_regs) as usize]
            }
            None => {
                let base = if r < self.state_regs {
                    self.x
                } else {
                    self.regs()
                };
                let v = self
                    .b
                    .ins()
                    .load(types::F64, MemFlagsData::trusted(), base, offset(r));
                self.vals[r as usize] = Some(v);
                v
            }
        }
    }

    fn set(&mut self, r: u32, v: Value) {
        self.vals[r as usize] = Some(v);
        self.dirty[r as usize] = true;
        self.defined(r, false);
    }

    /// Stores register `r`'s outputs now that its value is defined
    /// (`in_regs`: a loop or block wrote it into the register file).
    fn defined(&mut self, r: u32, in_regs: bool) {
        let first = self.outputs.partition_point(|&(o, _)| o < r);
        if self.outputs.get(first).is_none_or(|&(o, _)| o != r) {
            return;
        }
        self.stored[r as usize] = true;
        match self.out {
            Some(out) => {
                let v = self.get(r);
                // A register written to many places (a constant: the zero
                // rates of modes and held values) fills neighbouring
                // positions two at a time.
                let mut both = None;
                let mut k = first;
                while let Some(&(o, d)) = self.outputs.get(k)
                    && o == r
                {
                    let pair = self.outputs.get(k + 1) == Some(&(r, d + 1));
                    let (w, flags) = if pair {
                        let w = *both.get_or_insert_with(|| self.b.ins().splat(types::F64X2, v));
                        (w, UNALIGNED)
                    } else {
                        (v, MemFlagsData::trusted())
                    };
                    self.b.ins().store(flags, w, out, offset(d));
                    k += if pair { 2 } else { 1 };
                }
            }
            None if !in_regs => {
                let v = self.get(r);
                self.store(r, v);
                self.dirty[r as usize] = false;
            }
            None => {}
        }
    }

    fn store(&mut self, r: u32, v: Value) {
        let regs = self.regs();
        self.b
            .ins()
            .store(MemFlagsData::trusted(), v, regs, offset(r));
    }

    /// The register file's address, noting that the code uses it.
    fn regs(&mut self) -> Value {
        self.uses_regs = true;
        self.regs
    }

    /// `ops` (all [`Op::Lin`] without constant terms) as loop nests over
    /// tables of their terms: for each sum, `acc = term₀`, then
    /// `acc = acc + termₖ` in order, stored to its register, as the
    /// interpreter computes it. Runs of [`WIDTH`] consecutive sums of one
    /// length, none reading another, go through one loop together; the
    /// others one by one.
    fn lin_loop(&mut self, p: &Program, ops: &[Op]) {
        let sums: Vec<(u32, &[(u32, f64)])> = ops
            .iter()
            .map(|op| match *op {
                Op::Lin { d, t0, len } => (d, &p.lin[t0 as usize..(t0 + len) as usize]),
                _ => unreachable!("a loop nest of sums only"),
            })
            .collect();
        // The loops read their operands from the register file: a value
        // defined before in this program, or a state component, goes there
        // first (the interpreter's `run_at` copies the state there too).
        for &(_, terms) in &sums {
            for &(r, _) in terms {
                debug_assert_ne!(r, CONST_TERM, "constant terms stay inline");
                let r = r as usize;
                if self.dirty[r] || (r < self.state_regs as usize && !self.copied[r]) {
                    let v = self.get(r as u32);
                    self.store(r as u32, v);
                    self.dirty[r] = false;
                    if r < self.state_regs as usize {
                        self.copied[r] = true;
                    }
                }
            }
        }
        // Batches, in order, then runs of batches of one width.
        let mut i = 0;
        let mut batches: Vec<(usize, usize)> = Vec::new(); // (first sum, width)
        while i < sums.len() {
            let group = &sums[i..(i + WIDTH).min(sums.len())];
            let together = group.len() == WIDTH
                && group.iter().all(|s| s.1.len() == group[0].1.len())
                && group
                    .iter()
                    .all(|s| s.1.iter().all(|&(r, _)| group.iter().all(|g| g.0 != r)));
            let w = if together { WIDTH } else { 1 };
            batches.push((i, w));
            i += w;
        }
        let mut start = 0;
        while start < batches.len() {
            let w = batches[start].1;
            let end = start + batches[start..].iter().take_while(|b| b.1 == w).count();
            let mut table = Vec::new();
            let mut terms = Vec::new();
            for &(first, w) in &batches[start..end] {
                let group = &sums[first..first + w];
                table.push(group[0].1.len() as u32);
                table.extend(group.iter().map(|s| s.0));
                for k in 0..group[0].1.len() {
                    terms.extend(group.iter().map(|s| helpers::LoopTerm {
                        reg: s.1[k].0 as usize,
                        c: s.1[k].1,
                    }));
                }
            }
            let nest = Box::new(helpers::Nest {
                width: w,
                batches: table.into_boxed_slice(),
                terms: terms.into_boxed_slice(),
            });
            let desc = self.address((&*nest as *const helpers::Nest).cast());
            let (sig, regs) = (self.sigs.block, self.regs());
            let h = helpers::sums as helpers::Sums as *const u8;
            self.call(sig, h, &[desc, regs]);
            self.tables.push(nest);
            start = end;
        }
        // The results are in the register file now.
        for &(d, _) in &sums {
            self.vals[d as usize] = None;
            self.dirty[d as usize] = false;
            self.defined(d, true);
        }
    }

    /// Two operands in one vector, lane 0 `s` and lane 1 `t`: an earlier
    /// pair's vector, a splat, one load of two adjacent state components,
    /// a constant or, failing those, the two scalars gathered.
    fn pack(&mut self, s: Slot, t: Slot) -> Value {
        let (a, b) = match (s, t) {
            (Slot::Imm(a), Slot::Imm(b)) => return self.vconst(a, b),
            (Slot::Reg(a), Slot::Reg(b)) => (a, b),
            _ => unreachable!("pairs pack registers with registers"),
        };
        if let (Some((v, 0)), Some((w, 1))) = (self.lanes[a as usize], self.lanes[b as usize])
            && v == w
        {
            return v;
        }
        if b == a + 1 && b < self.state_regs {
            return self
                .b
                .ins()
                .load(types::F64X2, UNALIGNED, self.x, offset(a));
        }
        if let Some(&v) = self.packed.get(&(a, b)) {
            return v;
        }
        // A splat, or `b` inserted into lane 1 of `a`'s vector or splat.
        let v = match self.lanes[a as usize] {
            Some((v, 0)) if a != b => v,
            _ => {
                let x = self.get(a);
                self.b.ins().splat(types::F64X2, x)
            }
        };
        let v = if a == b {
            v
        } else {
            let y = self.get(b);
            self.b.ins().insertlane(v, y, 1)
        };
        self.packed.insert((a, b), v);
        v
    }

    fn vconst(&mut self, a: f64, b: f64) -> Value {
        let key = (a.to_bits(), b.to_bits());
        if let Some(&v) = self.vconsts.get(&key) {
            return v;
        }
        let bytes: Vec<u8> = a.to_le_bytes().into_iter().chain(b.to_le_bytes()).collect();
        let c = self.b.func.dfg.constants.insert(ConstantData::from(bytes));
        let v = self.b.ins().vconst(types::F64X2, c);
        self.vconsts.insert(key, v);
        v
    }

    /// Emits the pair of instructions `x` (lane 0) and `y` (lane 1; its
    /// operands swapped if `swap`) as vector instructions.
    fn pair(&mut self, p: &Program, x: &Op, y: &Op, swap: bool) {
        let ops = |e: &mut Self, k: usize| {
            let t = if swap { 1 - k } else { k };
            e.pack(pairs::slot(p, x, k), pairs::slot(p, y, t))
        };
        let v = match (*x, *y) {
            (Op::Lin { t0, len, .. }, Op::Lin { t0: u0, .. }) => {
                let (tx, ty) = (t0 as usize, u0 as usize);
                // As the scalar code (`Op::Lin` in `op`), lane by lane: a
                // coefficient pair other than (1, 1) or (−1, −1) multiplies,
                // and `x · 1 = x`, `s + x · (−1) = s − x` exactly.
                let mut acc: Option<Value> = None;
                for k in 0..len as usize {
                    let ((rx, cx), (_, cy)) = (p.lin[tx + k], p.lin[ty + k]);
                    let v = ops(self, k);
                    let unit = (rx != CONST_TERM && cx == cy && (cx == 1.0 || cx == -1.0))
                        .then_some(cx == 1.0);
                    let term = if unit.is_some() || rx == CONST_TERM {
                        v
                    } else {
                        let c = self.vconst(cx, cy);
                        self.b.ins().fmul(v, c)
                    };
                    acc = Some(self.accumulate(acc, term, unit));
                }
                acc.expect("a sum has terms")
            }
            (Op::Neg { .. }, _) => {
                let a = ops(self, 0);
                self.b.ins().fneg(a)
            }
            _ => {
                let (a, b) = (ops(self, 0), ops(self, 1));
                match *x {
                    Op::Add { .. } | Op::AddC { .. } => self.b.ins().fadd(a, b),
                    Op::Sub { .. } => self.b.ins().fsub(a, b),
                    Op::Mul { .. } | Op::MulC { .. } => self.b.ins().fmul(a, b),
                    Op::Div { .. } => self.b.ins().fdiv(a, b),
                    _ => unreachable!("{x:?} does not pair"),
                }
            }
        };
        let (d0, d1) = (pairs::dest(x), pairs::dest(y));
        self.lanes[d0 as usize] = Some((v, 0));
        self.lanes[d1 as usize] = Some((v, 1));
        self.dirty[d0 as usize] = true;
        self.dirty[d1 as usize] = true;
        // Two outputs at adjacent positions: one store.
        let at = |e: &Self, r: u32| {
            let first = e.outputs.partition_point(|&(o, _)| o < r);
            let mut at = e.outputs[first..].iter().take_while(|&&(o, _)| o == r);
            match (at.next(), at.next()) {
                (Some(&(_, d)), None) => Some(d),
                _ => None,
            }
        };
        if let (Some(p0), Some(p1)) = (at(self, d0), at(self, d1))
            && p1 == p0 + 1
        {
            let base = match self.out {
                Some(out) => out,
                None => {
                    self.dirty[d0 as usize] = false;
                    self.dirty[d1 as usize] = false;
                    self.regs()
                }
            };
            self.b.ins().store(UNALIGNED, v, base, offset(p0));
            self.stored[d0 as usize] = true;
            self.stored[d1 as usize] = true;
            return;
        }
        self.defined(d0, false);
        self.defined(d1, false);
    }

    /// `acc` plus a sum's next term, for scalars and vectors alike: `unit`
    /// (`Some(plus)`) for a coefficient ±1, added or subtracted without a
    /// multiplication (`x · 1 = x`, `s + x · (−1) = s − x` exactly), else
    /// `term` is the product already.
    fn accumulate(&mut self, acc: Option<Value>, term: Value, unit: Option<bool>) -> Value {
        match (acc, unit) {
            (None, Some(false)) => self.b.ins().fneg(term),
            (None, _) => term,
            (Some(s), Some(false)) => self.b.ins().fsub(s, term),
            (Some(s), _) => self.b.ins().fadd(s, term),
        }
    }

    fn konst(&mut self, c: f64) -> Value {
        let key = c.to_bits();
        if let Some(&v) = self.consts.get(&key) {
            return v;
        }
        let v = self.b.ins().f64const(c);
        self.consts.insert(key, v);
        v
    }

    fn b2f(&mut self, cond: Value) -> Value {
        let (one, zero) = (self.konst(1.0), self.konst(0.0));
        self.b.ins().select(cond, one, zero)
    }

    fn nonzero(&mut self, a: Value) -> Value {
        let zero = self.konst(0.0);
        self.b.ins().fcmp(FloatCC::NotEqual, a, zero)
    }

    fn address(&mut self, p: *const u8) -> Value {
        self.b.ins().iconst(self.ptr, p as i64)
    }

    fn call(&mut self, sig: SigRef, f: *const u8, args: &[Value]) -> Option<Value> {
        let callee = self.address(f);
        let call = self.b.ins().call_indirect(sig, callee, args);
        self.b.inst_results(call).first().copied()
    }

    fn un(&mut self, f: UnFn, a: Value) -> Value {
        if let Some(h) = helpers::un_helper(f) {
            let sig = self.sigs.un;
            return self.call(sig, h as *const u8, &[a]).expect("one result");
        }
        match f {
            UnFn::Neg => self.b.ins().fneg(a),
            UnFn::Abs => self.b.ins().fabs(a),
            UnFn::Sqrt => self.b.ins().sqrt(a),
            UnFn::Floor => self.b.ins().floor(a),
            UnFn::Ceil => self.b.ins().ceil(a),
            UnFn::Sign => {
                let zero = self.konst(0.0);
                let gt = self.b.ins().fcmp(FloatCC::GreaterThan, a, zero);
                let lt = self.b.ins().fcmp(FloatCC::LessThan, a, zero);
                let (one, minus) = (self.konst(1.0), self.konst(-1.0));
                let neg = self.b.ins().select(lt, minus, zero);
                self.b.ins().select(gt, one, neg)
            }
            UnFn::Not => {
                let zero = self.konst(0.0);
                let eq = self.b.ins().fcmp(FloatCC::Equal, a, zero);
                self.b2f(eq)
            }
            _ => unreachable!("{f:?} is a helper call"),
        }
    }

    /// `f(a, b)`; `b_const` is `b`'s value when it is an immediate.
    fn bin(&mut self, f: BinFn, a: Value, b: Value, b_const: Option<f64>) -> Value {
        if f == BinFn::Pow && b_const == Some(2.0) {
            return self.b.ins().fmul(a, a);
        }
        if let Some(h) = helpers::bin_helper(f) {
            let sig = self.sigs.bin;
            return self.call(sig, h as *const u8, &[a, b]).expect("one result");
        }
        let cmp = |e: &mut Self, cc: FloatCC| {
            let c = e.b.ins().fcmp(cc, a, b);
            e.b2f(c)
        };
        match f {
            BinFn::Add => self.b.ins().fadd(a, b),
            BinFn::Sub => self.b.ins().fsub(a, b),
            BinFn::Mul => self.b.ins().fmul(a, b),
            BinFn::Div => self.b.ins().fdiv(a, b),
            BinFn::Mod => {
                // a − b·⌊a / b⌋, as `eval_bin` computes it.
                let q = self.b.ins().fdiv(a, b);
                let fl = self.b.ins().floor(q);
                let m = self.b.ins().fmul(b, fl);
                self.b.ins().fsub(a, m)
            }
            BinFn::Rem => {
                // a − b·trunc(a / b), as `eval_bin` computes it.
                let q = self.b.ins().fdiv(a, b);
                let tr = self.b.ins().trunc(q);
                let m = self.b.ins().fmul(b, tr);
                self.b.ins().fsub(a, m)
            }
            BinFn::Lt => cmp(self, FloatCC::LessThan),
            BinFn::Le => cmp(self, FloatCC::LessThanOrEqual),
            BinFn::Gt => cmp(self, FloatCC::GreaterThan),
            BinFn::Ge => cmp(self, FloatCC::GreaterThanOrEqual),
            BinFn::Eq => cmp(self, FloatCC::Equal),
            // Unordered or unequal: true for NaN, as Rust's `!=`.
            BinFn::Ne => cmp(self, FloatCC::NotEqual),
            BinFn::And | BinFn::Or => {
                let (x, y) = (self.nonzero(a), self.nonzero(b));
                let c = if f == BinFn::And {
                    self.b.ins().band(x, y)
                } else {
                    self.b.ins().bor(x, y)
                };
                self.b2f(c)
            }
            _ => unreachable!("{f:?} is a helper call"),
        }
    }

    /// Emits `p`, each output stored when it is defined and, at the end,
    /// those that are fixed registers: into the register file, or for a
    /// program with positions (`Program::dest`) into `out` (the entry's
    /// pointer) at those.
    fn program(&mut self, p: &Program, blocks: &[BlockDesc], out: Value) {
        let mut next_block = 0;
        // Sums are deferred, and gathered into one loop nest, until an
        // instruction reads one (or the program ends): nothing but a sum
        // reads the interleaved products a shared coefficient makes
        // (`c * x` used by many rows), so a matrix product's sums stay
        // together. Each instruction's value only depends on its
        // operands, so the order does not change any result.
        let mut sums: Vec<Op> = Vec::new();
        let mut pending = vec![false; p.nregs];
        let plan = pairs::plan(p, |op| loopable(p, op));
        for (i, op) in p.ops.iter().enumerate() {
            if plan.follows(i) {
                continue;
            }
            if let Op::Lin { d, .. } = *op
                && loopable(p, op)
            {
                sums.push(*op);
                pending[d as usize] = true;
                continue;
            }
            let partner = plan.partner(i).map(|(j, swap)| (&p.ops[j as usize], swap));
            if !sums.is_empty()
                && (p.reads(op, |r| pending[r as usize])
                    || partner.is_some_and(|(y, _)| p.reads(y, |r| pending[r as usize])))
            {
                self.sums(p, &mut sums, &mut pending);
            }
            match partner {
                Some((y, swap)) => self.pair(p, op, y, swap),
                None => self.op(p, op, blocks, &mut next_block),
            }
        }
        self.sums(p, &mut sums, &mut pending);
        match &p.dest {
            // Every output lands in the register file, also one that is a
            // state register read from `x`.
            None => {
                for &o in &p.outs {
                    if o >= self.state_regs && !self.dirty[o as usize] {
                        // Already there (read from there, or a loop's or a
                        // block's result).
                        continue;
                    }
                    let v = self.get(o);
                    self.store(o, v);
                }
            }
            // Each output at its position in the caller's buffer.
            Some(dest) => {
                for (&o, &d) in p.outs.iter().zip(dest) {
                    if self.stored[o as usize] {
                        continue;
                    }
                    let v = self.get(o);
                    self.b
                        .ins()
                        .store(MemFlagsData::trusted(), v, out, offset(d));
                }
            }
        }
        self.b.ins().return_(&[]);
    }

    /// Emits the deferred `sums`: one loop nest if they have at least
    /// [`LOOP_TERMS`] terms, else inline; then clears them.
    fn sums(&mut self, p: &Program, sums: &mut Vec<Op>, pending: &mut [bool]) {
        let terms: usize = sums
            .iter()
            .map(|o| match o {
                Op::Lin { len, .. } => *len as usize,
                _ => 0,
            })
            .sum();
        if terms >= LOOP_TERMS {
            self.lin_loop(p, sums);
        } else {
            for op in sums.iter() {
                self.op(p, op, &[], &mut 0);
            }
        }
        for op in sums.drain(..) {
            if let Op::Lin { d, .. } = op {
                pending[d as usize] = false;
            }
        }
    }

    /// Emits one instruction; `blocks[next_block]` is the next block
    /// operation's descriptor.
    fn op(&mut self, p: &Program, op: &Op, blocks: &[BlockDesc], next_block: &mut usize) {
        match *op {
            Op::Const { d, c } => {
                let v = self.konst(c);
                self.set(d, v);
            }
            Op::Add { d, a, b }
            | Op::Sub { d, a, b }
            | Op::Mul { d, a, b }
            | Op::Div { d, a, b } => {
                let f = match op {
                    Op::Add { .. } => BinFn::Add,
                    Op::Sub { .. } => BinFn::Sub,
                    Op::Mul { .. } => BinFn::Mul,
                    _ => BinFn::Div,
                };
                let (a, b) = (self.get(a), self.get(b));
                let v = self.bin(f, a, b, None);
                self.set(d, v);
            }
            Op::AddC { d, a, c } => {
                let (a, c) = (self.get(a), self.konst(c));
                let v = self.b.ins().fadd(a, c);
                self.set(d, v);
            }
            Op::MulC { d, a, c } => {
                let (a, c) = (self.get(a), self.konst(c));
                let v = self.b.ins().fmul(a, c);
                self.set(d, v);
            }
            Op::BinRC { d, f, a, c } => {
                let (a, k) = (self.get(a), self.konst(c));
                let v = self.bin(f, a, k, Some(c));
                self.set(d, v);
            }
            Op::BinCR { d, f, c, b } => {
                let (k, b) = (self.konst(c), self.get(b));
                let v = self.bin(f, k, b, None);
                self.set(d, v);
            }
            Op::Bin { d, f, a, b } => {
                let (a, b) = (self.get(a), self.get(b));
                let v = self.bin(f, a, b, None);
                self.set(d, v);
            }
            Op::Neg { d, a } => {
                let a = self.get(a);
                let v = self.b.ins().fneg(a);
                self.set(d, v);
            }
            Op::Un { d, f, a } => {
                let a = self.get(a);
                let v = self.un(f, a);
                self.set(d, v);
            }
            Op::Select { d, c, a, b } => {
                let c = self.get(c);
                let cond = self.nonzero(c);
                let (a, b) = (self.get(a), self.get(b));
                let v = self.b.ins().select(cond, a, b);
                self.set(d, v);
            }
            Op::Rand { d, dist, a, b } => {
                let (a, b) = (self.get(a), self.get(b));
                let (sig, rng) = (self.sigs.rand, self.rng);
                let r = helpers::rand_helper(dist) as *const u8;
                let v = self.call(sig, r, &[rng, a, b]).expect("one result");
                self.set(d, v);
            }
            Op::Lookup {
                d,
                table,
                row,
                col,
                origin,
                when,
            } => {
                let (row, col, when) = (self.get(row), self.get(col), self.get(when));
                // The time and jump registers follow the state ones.
                let (t, j) = (self.get(self.state_regs), self.get(self.state_regs + 1));
                let table = self.address(std::sync::Arc::as_ptr(&p.tables[table as usize]).cast());
                let origin = self.b.ins().iconst(types::I32, i64::from(origin));
                let h = helpers::table_lookup as helpers::Lookup as *const u8;
                let v = self
                    .call(self.sigs.lookup, h, &[table, row, col, origin, when, t, j])
                    .expect("one result");
                self.set(d, v);
            }
            Op::Interp { d, table, x, slope } => {
                let x = self.get(x);
                let table = self.address(std::sync::Arc::as_ptr(&p.tables[table as usize]).cast());
                let slope = self.b.ins().iconst(types::I32, i64::from(slope));
                let h = helpers::table_interp as helpers::Interp as *const u8;
                let v = self
                    .call(self.sigs.interp, h, &[table, x, slope])
                    .expect("one result");
                self.set(d, v);
            }
            Op::Lin { d, t0, len } => {
                let terms = &p.lin[t0 as usize..(t0 + len) as usize];
                // A coefficient ±1 (most terms: the products of a matrix
                // product of states, `a − b`) needs no multiplication:
                // `x · 1 = x` and `s + x · (−1) = s − x` exactly (NaN aside,
                // whose sign bit is not kept anyway).
                let mut acc: Option<Value> = None;
                for &(r, c) in terms {
                    let unit = (r != CONST_TERM && (c == 1.0 || c == -1.0)).then_some(c == 1.0);
                    let term = if unit.is_some() {
                        self.get(r)
                    } else {
                        let k = self.konst(c);
                        if r == CONST_TERM {
                            k
                        } else {
                            let x = self.get(r);
                            self.b.ins().fmul(x, k)
                        }
                    };
                    acc = Some(self.accumulate(acc, term, unit));
                }
                let v = acc.expect("a sum has terms");
                self.set(d, v);
            }
            Op::Block {
                kind,
                g0,
                len,
                inp,
                out,
                ..
            } => {
                for k in 0..len {
                    let v = self.get(p.gather[(g0 + k) as usize]);
                    let regs = self.regs();
                    self.b
                        .ins()
                        .store(MemFlagsData::trusted(), v, regs, offset(inp + k));
                }
                let desc = &blocks[*next_block] as *const BlockDesc as *const u8;
                *next_block += 1;
                let desc = self.address(desc);
                let (sig, regs) = (self.sigs.block, self.regs());
                let h = helpers::block as helpers::Block as *const u8;
                self.call(sig, h, &[desc, regs]);
                // The outputs are in the register file now.
                for r in out..out + kind.outputs() as u32 {
                    self.vals[r as usize] = None;
                    self.dirty[r as usize] = false;
                    self.defined(r, true);
                }
            }
        }
    }
}
