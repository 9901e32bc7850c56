//! Outputs and instance inputs: named values lowered on first use.
//!
//! Every `output` (and every input of a subsystem instance, an unlogged
//! output after elaboration) is registered with the loop indices in scope
//! where it is declared, then lowered when an expression first uses it or
//! when the checker reaches its declaration, so a value may use values
//! declared after it (and errors still come in source order). A value that uses itself through others is an algebraic loop
//! ([`CheckError::AlgebraicLoop`], naming the loop): outputs and inputs are
//! evaluated at one instant and such a loop has no order. Dependencies are
//! followed member by member, so a family of instances connected along an
//! acyclic graph is not a loop.

use rustc_hash::FxHashMap as HashMap;
use std::collections::BTreeMap;
use std::rc::Rc;

use super::error::CheckError;
use super::expr::key_label;
use super::model::{OUTPUT_CTX, OutputField};
use super::{Checker, Sym};
use crate::source::Span;
use crate::syntax::ast::{Definition, Target};

/// Where a registered value is in its lowering.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Waiting,
    Lowering,
    Done,
    Failed,
}

/// A registered output or input.
#[derive(Debug, Clone)]
struct Signal {
    def: Definition,
    /// Loop indices in scope at the declaration.
    scopes: Vec<(std::rc::Rc<str>, i64)>,
    /// `e[2]` for a family member, `e` otherwise.
    display: String,
    /// Logged (an output) or not (an instance's input).
    logged: bool,
    state: State,
}

/// The registered values of a model.
#[derive(Debug, Default)]
pub(crate) struct Signals {
    list: Vec<Signal>,
    /// name → (declared as a family, member key → signal).
    by_name: HashMap<String, (bool, HashMap<Vec<i64>, usize>)>,
    /// The values being lowered, outermost first.
    stack: Vec<usize>,
    /// The logged values lowered so far, with their declaration number.
    lowered: Vec<(usize, OutputField)>,
    /// The next value in source order ([`Checker::lower_next_signal`]).
    next: usize,
}

impl Checker {
    /// Registers `def` (an output if `logged`, else an instance's input)
    /// with the loop indices now in scope.
    /// Every call adds one entry (a failed one if the declaration is
    /// wrong), so that the n-th declaration met in source order is value n
    /// ([`Self::lower_signal_at`]).
    pub(crate) fn register_signal(&mut self, def: &Definition, logged: bool) {
        let t = &def.target;
        let failed = Signal {
            def: def.clone(),
            scopes: Vec::new(),
            display: t.name.name.clone(),
            logged,
            state: State::Failed,
        };
        let key = match t.indices.as_slice() {
            [] => Vec::new(),
            [args] => match self.family_key(args) {
                Some(k) => k,
                None => return self.signals.list.push(failed),
            },
            _ => {
                self.err(CheckError::Expected {
                    expected: "a name or `name[i]`".into(),
                    found: "several index lists".into(),
                    span: t.span,
                });
                return self.signals.list.push(failed);
            }
        };
        let display = if t.indices.is_empty() {
            t.name.name.clone()
        } else {
            format!("{}[{}]", t.name.name, key_label(&key))
        };
        let id = self.signals.list.len();
        let entry = self
            .signals
            .by_name
            .entry(t.name.name.clone())
            .or_insert_with(|| (!t.indices.is_empty(), HashMap::default()));
        if let Some(&first) = entry.1.get(&key) {
            let first = self.signals.list[first].def.target.span;
            self.err(CheckError::Duplicate {
                name: display,
                span: t.span,
                first,
            });
            return self.signals.list.push(failed);
        }
        entry.0 |= !t.indices.is_empty();
        entry.1.insert(key, id);
        self.signals.list.push(Signal {
            def: def.clone(),
            scopes: self.scopes.clone(),
            display,
            logged,
            state: State::Waiting,
        });
    }

    /// Lowers every registered value not yet lowered, in declaration order.
    pub(crate) fn lower_signals(&mut self) {
        for id in 0..self.signals.list.len() {
            self.lower_signal(id);
        }
    }

    /// Lowers the next value in source order (the checker meets the
    /// declarations in the order they were registered), so that errors come
    /// in source order; values used earlier are already lowered.
    pub(crate) fn lower_next_signal(&mut self) {
        let id = self.signals.next;
        self.signals.next += 1;
        if id < self.signals.list.len() {
            self.lower_signal(id);
        }
    }

    /// The logged values (outputs) in declaration order.
    pub(crate) fn take_outputs(&mut self) -> Vec<OutputField> {
        let mut v = std::mem::take(&mut self.signals.lowered);
        v.sort_by_key(|(order, _)| *order);
        v.into_iter().map(|(_, f)| f).collect()
    }

    /// True if `name` is a family of registered values.
    pub(crate) fn is_signal_family(&self, name: &str) -> bool {
        self.signals.by_name.get(name).is_some_and(|(f, _)| *f)
    }

    /// True if `name` is a registered output or instance input (lowered
    /// on first use).
    pub(crate) fn is_signal(&self, name: &str) -> bool {
        self.signals.by_name.contains_key(name)
    }

    /// The registered names (for suggestions).
    pub(crate) fn signal_names(&self) -> impl Iterator<Item = &String> {
        self.signals.by_name.keys()
    }

    pub(crate) fn signal_count(&self) -> usize {
        self.signals.by_name.len()
    }

    /// Lowers member `key` of `name` if it is a registered value not yet
    /// lowered (called before a name is looked up). False if it is a value
    /// that could not be lowered (its error is already reported: the caller
    /// reports nothing more).
    pub(crate) fn demand_signal(&mut self, name: &str, key: &[i64]) -> bool {
        let Some(&id) = self
            .signals
            .by_name
            .get(name)
            .and_then(|(_, members)| members.get(key))
        else {
            return true;
        };
        self.lower_signal(id);
        !matches!(self.signals.list[id].state, State::Failed | State::Lowering)
    }

    fn lower_signal(&mut self, id: usize) {
        match self.signals.list[id].state {
            State::Done | State::Failed => return,
            State::Lowering => {
                let pos = self
                    .signals
                    .stack
                    .iter()
                    .position(|&s| s == id)
                    .unwrap_or(0);
                // Shown from its first input (a connection the user wrote),
                // if it has one.
                let mut ids = self.signals.stack[pos..].to_vec();
                if let Some(k) = ids.iter().position(|&s| !self.signals.list[s].logged) {
                    ids.rotate_left(k);
                }
                let cycle = ids
                    .iter()
                    .map(|&s| {
                        let sig = &self.signals.list[s];
                        // An input is shown at its connection, an output
                        // at its name.
                        let span = if sig.logged {
                            sig.def.target.span
                        } else {
                            sig.def.value.span
                        };
                        (sig.display.clone(), span)
                    })
                    .collect();
                self.err(CheckError::AlgebraicLoop { cycle });
                return;
            }
            State::Waiting => {}
        }
        self.signals.list[id].state = State::Lowering;
        self.signals.stack.push(id);
        let sig = self.signals.list[id].clone();
        let outer = std::mem::replace(&mut self.scopes, sig.scopes.clone());
        let ok = self.declare_signal(&sig, id);
        self.scopes = outer;
        self.signals.stack.pop();
        self.signals.list[id].state = if ok { State::Done } else { State::Failed };
    }

    /// Lowers one value and declares it as an output (in the scopes of its
    /// declaration); false on error.
    fn declare_signal(&mut self, sig: &Signal, order: usize) -> bool {
        let d = &sig.def;
        let Some(v) = self.expr(&d.value, &OUTPUT_CTX) else {
            return false;
        };
        let span = d.target.name.span;
        let val = v.clone();
        let Some(name) = self.declare(&d.target, |_| Sym::Output {
            val: Rc::new(val),
            span,
        }) else {
            return false;
        };
        if sig.logged {
            // `declare` names a member `e[label]`.
            let family = (!d.target.indices.is_empty()).then(|| {
                let base = &d.target.name.name;
                let label = name[base.len() + 1..name.len() - 1].to_string();
                (base.clone(), label)
            });
            self.signals.lowered.push((
                order,
                OutputField {
                    family,
                    name,
                    rows: v.rows,
                    cols: v.cols,
                    nodes: v.e.into_vec(),
                    span: d.target.span,
                },
            ));
        }
        true
    }

    /// Declares `target` as a name (or family member); returns the display
    /// name and the family key, if any.
    pub(crate) fn declare(
        &mut self,
        target: &Target,
        sym: impl FnOnce(Option<&[i64]>) -> Sym,
    ) -> Option<String> {
        let name = &target.name.name;
        let span = target.span;
        match target.indices.len() {
            0 => {
                if let Some(prev) = self.syms.get(name) {
                    self.err(CheckError::Duplicate {
                        name: name.clone(),
                        span: target.name.span,
                        first: prev.span(),
                    });
                    return None;
                }
                let s = sym(None);
                self.syms.insert(name.clone(), s);
                Some(name.clone())
            }
            1 => {
                let key = self.family_key(&target.indices[0])?;
                let s = sym(Some(&key));
                let display = format!("{name}[{}]", key_label(&key));
                let dup = |prev: Span| CheckError::Duplicate {
                    name: display.clone(),
                    span,
                    first: prev,
                };
                let added = match (self.syms.get_mut(name), s) {
                    (None, Sym::Param { val, span: sp }) => {
                        let members = BTreeMap::from([(key, Rc::unwrap_or_clone(val))]);
                        self.syms
                            .insert(name.clone(), Sym::ParamFamily { members, span: sp });
                        Ok(())
                    }
                    (None, Sym::Output { val, span: sp }) => {
                        let members = BTreeMap::from([(key, Rc::unwrap_or_clone(val))]);
                        self.syms
                            .insert(name.clone(), Sym::OutputFamily { members, span: sp });
                        Ok(())
                    }
                    (None, Sym::State { field, span: sp }) => {
                        let members = BTreeMap::from([(key, field)]);
                        self.syms
                            .insert(name.clone(), Sym::StateFamily { members, span: sp });
                        Ok(())
                    }
                    (Some(Sym::ParamFamily { members, span }), Sym::Param { val, .. }) => {
                        add_member(members, key, Rc::unwrap_or_clone(val), *span)
                    }
                    (Some(Sym::OutputFamily { members, span }), Sym::Output { val, .. }) => {
                        add_member(members, key, Rc::unwrap_or_clone(val), *span)
                    }
                    (Some(Sym::StateFamily { members, span }), Sym::State { field, .. }) => {
                        add_member(members, key, field, *span)
                    }
                    (Some(prev), _) => {
                        let first = prev.span();
                        self.err(CheckError::Duplicate {
                            name: name.clone(),
                            span: target.name.span,
                            first,
                        });
                        return None;
                    }
                    (None, _) => {
                        self.err(CheckError::Unsupported {
                            what: "families of this kind".into(),
                            span,
                        });
                        return None;
                    }
                };
                if let Err(first) = added {
                    self.err(dup(first));
                    return None;
                }
                Some(display)
            }
            _ => {
                self.err(CheckError::Expected {
                    expected: "a name or `name[i]`".into(),
                    found: "several index lists".into(),
                    span,
                });
                None
            }
        }
    }
}

/// Adds member `key` to a family whose declaration is at `first`; `Err(first)` if it exists.
fn add_member<V>(
    members: &mut BTreeMap<Vec<i64>, V>,
    key: Vec<i64>,
    value: V,
    first: Span,
) -> Result<(), Span> {
    if members.contains_key(&key) {
        return Err(first);
    }
    members.insert(key, value);
    Ok(())
}
