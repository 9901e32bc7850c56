//! Source-like text of scalar graph nodes, for messages about compiled
//! sets (which atom of the flow set failed). Constants are printed folded
//! (parameters appear as their values); long expressions are cut with `…`.

use crate::check::dag::{BinFn, Dag, Node, NodeId, UnFn};
use crate::engine::Cmp;

/// Longest text produced, in characters (before the final `…`).
const BUDGET: usize = 120;

/// The atom `g ⋈ 0` as text: `a ⋈ b` when `g` is `a − b`.
pub(crate) fn atom_text(dag: &Dag, cmp: Cmp, g: NodeId, names: &[String]) -> String {
    let op = match cmp {
        Cmp::Lt => "<",
        Cmp::Le => "<=",
        Cmp::Gt => ">",
        Cmp::Ge => ">=",
        Cmp::Eq => "==",
        Cmp::Ne => "!=",
    };
    let mut w = Writer {
        dag,
        names,
        out: String::new(),
    };
    match dag.node(g) {
        Node::Bin(BinFn::Sub, a, b) => {
            w.expr(a, CMP);
            w.push(&format!(" {op} "));
            w.expr(b, CMP);
        }
        _ => {
            w.expr(g, CMP);
            w.push(&format!(" {op} 0"));
        }
    }
    w.finish()
}

// Binding strengths, loosest first.
const SELECT: u8 = 0;
const OR: u8 = 1;
const AND: u8 = 2;
const CMP: u8 = 3;
const ADD: u8 = 4;
const MUL: u8 = 5;
const NEG: u8 = 6;
const POW: u8 = 7;

struct Writer<'a> {
    dag: &'a Dag,
    names: &'a [String],
    out: String,
}

impl Writer<'_> {
    fn full(&self) -> bool {
        self.out.chars().count() > BUDGET
    }

    fn push(&mut self, s: &str) {
        if !self.full() {
            self.out.push_str(s);
        }
    }

    fn finish(mut self) -> String {
        if self.full() {
            let cut: String = self.out.chars().take(BUDGET).collect();
            self.out = cut + "…";
        }
        self.out
    }

    /// Writes node `n` in a context binding at least as tight as `ctx`.
    fn expr(&mut self, n: NodeId, ctx: u8) {
        if self.full() {
            return;
        }
        let paren = self.strength(n) < ctx;
        if paren {
            self.push("(");
        }
        self.body(n);
        if paren {
            self.push(")");
        }
    }

    fn strength(&self, n: NodeId) -> u8 {
        match self.dag.node(n) {
            Node::Select(..) => SELECT,
            Node::Bin(BinFn::Or, ..) => OR,
            Node::Bin(BinFn::And, ..) => AND,
            Node::Bin(
                BinFn::Lt | BinFn::Le | BinFn::Gt | BinFn::Ge | BinFn::Eq | BinFn::Ne,
                ..,
            ) => CMP,
            Node::Bin(BinFn::Add | BinFn::Sub, ..) => ADD,
            Node::Bin(BinFn::Mul | BinFn::Div, ..) => MUL,
            Node::Un(UnFn::Neg | UnFn::Not, _) => NEG,
            Node::Bin(BinFn::Pow, ..) => POW,
            Node::Const(b) if f64::from_bits(b) < 0.0 => NEG,
            _ => u8::MAX,
        }
    }

    fn body(&mut self, n: NodeId) {
        match self.dag.node(n) {
            Node::Const(b) => self.push(&number(f64::from_bits(b))),
            Node::State(k) => {
                let name = self.names.get(k as usize).cloned();
                self.push(&name.unwrap_or_else(|| format!("x{k}")));
            }
            Node::Time => self.push("t"),
            Node::Jumps => self.push("j"),
            Node::Wiener(k) => self.push(&format!("w{k}")),
            Node::Rand(..) => self.push("<random draw>"),
            Node::BlockOut(..) => self.push("<matrix result>"),
            Node::Lookup { .. } => self.push("<table entry>"),
            Node::Interp { .. } => self.push("<interpolation>"),
            Node::Un(f, a) => match f {
                UnFn::Neg => {
                    self.push("-");
                    self.expr(a, NEG + 1);
                }
                UnFn::Not => {
                    self.push("!");
                    self.expr(a, NEG + 1);
                }
                _ => {
                    self.push(un_name(f));
                    self.push("(");
                    self.expr(a, SELECT);
                    self.push(")");
                }
            },
            Node::Bin(f, a, b) => match infix(f) {
                // The graph orders commutative operands its own way; a
                // coefficient reads best first.
                Some((op, s))
                    if f == BinFn::Mul
                        && matches!(self.dag.node(b), Node::Const(_))
                        && !matches!(self.dag.node(a), Node::Const(_)) =>
                {
                    self.expr(b, s);
                    self.push(op);
                    self.expr(a, s + 1);
                }
                Some((op, s)) => {
                    // Left-associative: the right operand of a same-strength
                    // operator needs brackets (a - (b - c)); `^` is the
                    // other way round.
                    let (l, r) = if f == BinFn::Pow {
                        (s + 1, s)
                    } else {
                        (s, s + 1)
                    };
                    self.expr(a, l);
                    self.push(op);
                    self.expr(b, r);
                }
                None => {
                    self.push(bin_name(f));
                    self.push("(");
                    self.expr(a, SELECT);
                    self.push(", ");
                    self.expr(b, SELECT);
                    self.push(")");
                }
            },
            Node::Select(c, a, b) => {
                self.push("if ");
                self.expr(c, OR);
                self.push(" then ");
                self.expr(a, OR);
                self.push(" else ");
                self.expr(b, SELECT);
            }
        }
    }
}

fn infix(f: BinFn) -> Option<(&'static str, u8)> {
    Some(match f {
        BinFn::Add => (" + ", ADD),
        BinFn::Sub => (" - ", ADD),
        BinFn::Mul => ("*", MUL),
        BinFn::Div => ("/", MUL),
        BinFn::Pow => ("^", POW),
        BinFn::Lt => (" < ", CMP),
        BinFn::Le => (" <= ", CMP),
        BinFn::Gt => (" > ", CMP),
        BinFn::Ge => (" >= ", CMP),
        BinFn::Eq => (" == ", CMP),
        BinFn::Ne => (" != ", CMP),
        BinFn::And => (" && ", AND),
        BinFn::Or => (" || ", OR),
        _ => return None,
    })
}

fn bin_name(f: BinFn) -> &'static str {
    match f {
        BinFn::Min => "min",
        BinFn::Max => "max",
        BinFn::Atan2 => "atan2",
        BinFn::Mod => "mod",
        BinFn::Rem => "rem",
        BinFn::Hypot => "hypot",
        _ => "?",
    }
}

fn un_name(f: UnFn) -> &'static str {
    match f {
        UnFn::Abs => "abs",
        UnFn::Sqrt => "sqrt",
        UnFn::Exp => "exp",
        UnFn::Log => "log",
        UnFn::Sin => "sin",
        UnFn::Cos => "cos",
        UnFn::Tan => "tan",
        UnFn::Atan => "atan",
        UnFn::Tanh => "tanh",
        UnFn::Asin => "asin",
        UnFn::Acos => "acos",
        UnFn::Sinh => "sinh",
        UnFn::Cosh => "cosh",
        UnFn::Sign => "sign",
        UnFn::Floor => "floor",
        UnFn::Ceil => "ceil",
        UnFn::Round => "round",
        UnFn::Neg | UnFn::Not => "?",
    }
}

/// A number as the shortest text that reads back to it (exponent form
/// outside [1e-4, 1e15)).
pub(crate) fn number(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-4..1e15).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names() -> Vec<String> {
        vec!["h".into(), "v".into()]
    }

    #[test]
    fn atoms_read_like_the_source() {
        let mut dag = Dag::default();
        let h = dag.state(0);
        let v = dag.state(1);
        let one = dag.konst(1.0);
        let g = dag.bin(BinFn::Sub, h, one);
        assert_eq!(atom_text(&dag, Cmp::Ge, g, &names()), "h >= 1");
        // a - (b - c) keeps its brackets; products bind tighter than sums.
        let d = dag.bin(BinFn::Sub, v, h);
        let two = dag.konst(2.0);
        let m = dag.bin(BinFn::Mul, two, d);
        let s = dag.bin(BinFn::Sub, h, d);
        let e = dag.bin(BinFn::Add, m, s);
        assert_eq!(
            atom_text(&dag, Cmp::Lt, e, &names()),
            "2*(v - h) + (h - (v - h)) < 0"
        );
        let mx = dag.bin(BinFn::Max, h, v);
        let sq = dag.un(UnFn::Sqrt, mx);
        assert_eq!(
            atom_text(&dag, Cmp::Ne, sq, &names()),
            "sqrt(max(h, v)) != 0"
        );
    }

    #[test]
    fn long_expressions_are_cut() {
        let mut dag = Dag::default();
        let mut e = dag.state(0);
        for k in 0..200 {
            let c = dag.konst(k as f64 + 0.5);
            let p = dag.bin(BinFn::Mul, c, e);
            e = dag.bin(BinFn::Add, p, e);
        }
        let text = atom_text(&dag, Cmp::Ge, e, &names());
        assert!(
            text.ends_with('…') && text.chars().count() == BUDGET + 1,
            "{text}"
        );
    }
}
