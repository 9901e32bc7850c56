//! Checking a model's `log { … }` block: which states and outputs (`vars`),
//! which jump rules in full (`rules`) or as records only (`marks`) and
//! which flow samples (`every`, `dt`)
//! `hybsim run` logs, and how the MCAP file encodes and compresses it
//! (`encoding`, `compression`, `jump_states`). Without a block every state and output is
//! logged, and every rule but the noise redraws.

use std::collections::HashMap;

use super::error::CheckError;
use super::expr::suggest;
use super::model::CheckedRule;
use super::{Checker, Sym};
use crate::sinks::mcap::{Compression, Encoding};
use crate::source::Span;
use crate::syntax::ast::{Expr, ExprKind, Item, LogBlock, LogName};

/// A model's logging choices after checking (the defaults without a `log`
/// block).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LogDecl {
    /// `vars`: the states and outputs logged, as the model names them
    /// (`xh`, `xh[2]`, `e[1,3]`); `None`: all of them.
    pub vars: Option<Vec<String>>,
    /// Per rule (the model's order): whether its jumps are logged in full
    /// (pre-jump sample, record, post-jump sample). Default: every rule but
    /// the redraws of held `noise`.
    pub rules: Vec<bool>,
    /// `marks`: per rule, whether its jumps are logged as records only
    /// (never a rule of `rules`). Default: none.
    pub marks: Vec<bool>,
    /// `every = N`: every N-th flow sample.
    pub every: Option<u64>,
    /// `dt = DT`: flow samples at least DT apart.
    pub dt: Option<f64>,
    /// `encoding = protobuf | json`: the MCAP messages' encoding.
    pub encoding: Option<Encoding>,
    /// `compression = lz4 | zstd | none`: the MCAP chunks' compression.
    pub compression: Option<Compression>,
    /// `jump_states = true | false`: whether MCAP jump records carry the
    /// pre- and post-jump states.
    pub jump_states: Option<bool>,
}

/// The keys a `log` block knows.
const KEYS: &[&str] = &[
    "vars",
    "rules",
    "marks",
    "every",
    "dt",
    "encoding",
    "compression",
    "jump_states",
];

/// Checks the `log` block among the top-level `items` (at most one; none
/// inside `for`) against the model's rules.
pub(crate) fn check_logs(c: &mut Checker, items: &[Item], rules: &[CheckedRule]) -> LogDecl {
    let mut decl = LogDecl {
        rules: rules.iter().map(|r| !r.redraw).collect(),
        marks: vec![false; rules.len()],
        ..LogDecl::default()
    };
    let mut first: Option<Span> = None;
    for it in items {
        match it {
            Item::Log(b) => match first {
                Some(first) => c.err(CheckError::SecondBlock {
                    block: "log",
                    span: b.span,
                    first,
                }),
                None => {
                    first = Some(b.span);
                    check_block(c, b, rules, &mut decl);
                }
            },
            Item::For(_, inner) => nested(c, inner),
            _ => {}
        }
    }
    decl
}

/// Reports `log` blocks inside `for` loops.
fn nested(c: &mut Checker, items: &[Item]) {
    for it in items {
        match it {
            Item::Log(b) => c.err(CheckError::Unsupported {
                what: "a `log` block inside `for` (write it once, at the top level)".into(),
                span: b.span,
            }),
            Item::For(_, inner) => nested(c, inner),
            _ => {}
        }
    }
}

fn check_block(c: &mut Checker, b: &LogBlock, rules: &[CheckedRule], decl: &mut LogDecl) {
    let mut seen: HashMap<&str, Span> = HashMap::new();
    let keys = b
        .lists
        .iter()
        .map(|(k, _)| k)
        .chain(b.settings.iter().map(|s| &s.key));
    for key in keys {
        if let Some(&first) = seen.get(key.name.as_str()) {
            c.err(CheckError::SetTwice {
                name: key.name.clone(),
                span: key.span,
                first,
            });
        }
        seen.insert(&key.name, key.span);
    }
    // Where `marks` names each rule it marks.
    let mut marked_at: Vec<Option<Span>> = vec![None; rules.len()];
    for (key, names) in &b.lists {
        match key.name.as_str() {
            "vars" => {
                let vars: Vec<String> = names.iter().filter_map(|n| var_name(c, n)).collect();
                decl.vars = Some(vars);
            }
            "rules" => {
                let mut chosen = vec![false; rules.len()];
                for n in names {
                    for k in rule_indices(c, n, rules) {
                        chosen[k] = true;
                    }
                }
                decl.rules = chosen;
            }
            "marks" => {
                for n in names {
                    for k in rule_indices(c, n, rules) {
                        decl.marks[k] = true;
                        marked_at[k].get_or_insert(n.span);
                    }
                }
            }
            other => c.err(CheckError::UnknownSetting {
                name: other.to_string(),
                span: key.span,
                suggestion: suggest(other, KEYS.iter().copied()),
            }),
        }
    }
    // A marked rule is not logged in full: left out of the default `rules`,
    // an error where `rules` names it too.
    let explicit_rules = b.lists.iter().any(|(k, _)| k.name == "rules");
    for (k, span) in marked_at.iter().enumerate() {
        let Some(span) = *span else { continue };
        if !explicit_rules {
            decl.rules[k] = false;
        } else if decl.rules[k] {
            c.bad_setting(
                "marks",
                format!(
                    "`{}` is in `rules` too: a rule is logged in full or marked, not both",
                    rules[k].name
                ),
                span,
            );
        }
    }
    for s in &b.settings {
        let key = s.key.name.as_str();
        let bad = |c: &mut Checker, reason: &str| c.bad_setting(key, reason, s.value.span);
        match key {
            "every" => match c.const_int(&s.value, "`every`") {
                Some(n) if n >= 1 => decl.every = Some(n as u64),
                Some(_) => bad(c, "at least 1 (1 keeps every flow sample)"),
                None => {}
            },
            "dt" => match c.const_scalar(&s.value, "`dt`") {
                Some(dt) if dt.is_finite() && dt >= 0.0 => decl.dt = Some(dt),
                Some(_) => bad(c, "a number of time units ≥ 0"),
                None => {}
            },
            "encoding" => match word(&s.value).and_then(Encoding::parse) {
                Some(e) => decl.encoding = Some(e),
                None => bad(c, "write protobuf or json"),
            },
            "compression" => match word(&s.value).and_then(Compression::parse) {
                Some(k) => decl.compression = Some(k),
                None => bad(c, "write lz4, zstd or none"),
            },
            "jump_states" => match s.value.kind {
                ExprKind::Bool(b) => decl.jump_states = Some(b),
                _ => bad(c, "write true or false"),
            },
            "vars" | "rules" | "marks" => c.err(CheckError::Expected {
                expected: format!("a list of names `{key} = [a, b[2]]`"),
                found: "an expression".into(),
                span: s.value.span,
            }),
            other => c.err(CheckError::UnknownSetting {
                name: other.to_string(),
                span: s.key.span,
                suggestion: suggest(other, KEYS.iter().copied()),
            }),
        }
    }
}

/// The family label of `n`'s index (`2`, `1,3`), if it has one.
fn label_of(c: &mut Checker, n: &LogName) -> Option<Option<String>> {
    match n.target.indices.as_slice() {
        [] => Some(None),
        [args] => {
            let key = c.family_key(args)?;
            let words: Vec<String> = key.iter().map(|i| i.to_string()).collect();
            Some(Some(words.join(",")))
        }
        _ => {
            c.err(CheckError::Expected {
                expected: "one index list (`xh[2]`, `e[1, 3]`)".into(),
                found: "several index lists".into(),
                span: n.span,
            });
            None
        }
    }
}

/// The name of a state or output to log (`xh`, `xh[2]`), or an error.
fn var_name(c: &mut Checker, n: &LogName) -> Option<String> {
    let mut name = n.target.name.name.clone();
    if let Some(suffix) = &n.suffix {
        // A state or output of a subsystem instance: `ball.h`; of a member of a family of
        // instances, `f[2].x` (the family `f.x`, indexed first by the instance).
        let dotted = format!("{name}.{}", suffix.name);
        if !c.syms.contains_key(&dotted) && instance_keys(c, &dotted).is_empty() {
            c.err(CheckError::Expected {
                expected: "a state or an output (`x`, `xh[2]`, `ball.h`)".into(),
                found: format!("`{}`", dotted),
                span: n.span,
            });
            return None;
        }
        name = dotted;
    }
    let name = name.as_str();
    if !c.syms.contains_key(name) {
        let keys = instance_keys(c, name);
        if !keys.is_empty() {
            return instance_var(c, n, name, &keys);
        }
    }
    let family = match c.syms.get(name) {
        Some(Sym::State { .. } | Sym::Output { .. }) => false,
        Some(Sym::StateFamily { .. } | Sym::OutputFamily { .. }) => true,
        Some(other) => {
            let found = other.kind_words().to_string();
            c.err(CheckError::Expected {
                expected: "a state or an output".into(),
                found,
                span: n.target.name.span,
            });
            return None;
        }
        None => {
            let fits = c.hints.charge(c.syms.len());
            let candidates = c
                .syms
                .iter()
                .filter(|(_, s)| {
                    matches!(
                        s,
                        Sym::State { .. }
                            | Sym::StateFamily { .. }
                            | Sym::Output { .. }
                            | Sym::OutputFamily { .. }
                    )
                })
                .map(|(k, _)| k.as_str());
            let suggestion = fits.then(|| suggest(name, candidates)).flatten();
            c.err(CheckError::UnknownName {
                name: name.to_string(),
                span: n.target.name.span,
                suggestion,
            });
            return None;
        }
    };
    let label = label_of(c, n)?;
    match (family, label) {
        (_, None) => Some(name.to_string()),
        (false, Some(_)) => {
            c.err(CheckError::Expected {
                expected: format!(
                    "`{name}` whole (only members of families are chosen one by one)"
                ),
                found: "an index".into(),
                span: n.span,
            });
            None
        }
        (true, Some(label)) => {
            let key: Vec<i64> = label.split(',').filter_map(|s| s.parse().ok()).collect();
            // A family of instances' family (`f[2].c`, the model's
            // `f.c[i, m]`) is indexed first by the instance: `[2]` selects
            // member 2's whole family.
            let nested = name.contains('.');
            let has = |k: &Vec<i64>| *k == key || (nested && k.starts_with(&key));
            let present = match c.syms.get(name) {
                Some(Sym::StateFamily { members, .. }) => members.keys().any(has),
                Some(Sym::OutputFamily { members, .. }) => members.keys().any(has),
                _ => false,
            };
            if !present {
                let members = c.family_members_words(name);
                c.err(CheckError::FamilyOutOfRange {
                    lone: None,
                    name: name.to_string(),
                    index: label,
                    members,
                    span: n.span,
                });
                return None;
            }
            Some(format!("{name}[{label}]"))
        }
    }
}

/// The keys of the states and outputs of the subsystem instance `name`
/// (`ball`, `f`, a nested `plant.adc`), empty if it is none: `[]` for a
/// plain state or output, the family keys of a family (of instances, the
/// instance's index first).
fn instance_keys(c: &Checker, name: &str) -> Vec<Vec<i64>> {
    let mut keys = Vec::new();
    for (sym_name, sym) in &c.syms {
        let under = sym_name
            .strip_prefix(name)
            .is_some_and(|rest| rest.starts_with('.'));
        if !under {
            continue;
        }
        match sym {
            Sym::State { .. } | Sym::Output { .. } => keys.push(Vec::new()),
            Sym::StateFamily { members, .. } => keys.extend(members.keys().cloned()),
            Sym::OutputFamily { members, .. } => keys.extend(members.keys().cloned()),
            _ => {}
        }
    }
    keys
}

/// `vars` naming a whole subsystem instance (`ball`: its states and
/// outputs) or a member of a family of instances (`f[2]`), whose states
/// and outputs have the `keys`.
fn instance_var(c: &mut Checker, n: &LogName, name: &str, keys: &[Vec<i64>]) -> Option<String> {
    match label_of(c, n)? {
        None => Some(name.to_string()),
        Some(label) => {
            let key: Vec<i64> = label.split(',').filter_map(|s| s.parse().ok()).collect();
            if keys.iter().any(|k| k.is_empty()) {
                c.err(CheckError::Expected {
                    expected: format!("`{name}` whole (an instance, not a family of instances)"),
                    found: "an index".into(),
                    span: n.span,
                });
                return None;
            }
            if keys.iter().any(|k| k.starts_with(&key)) {
                return Some(format!("{name}[{label}]"));
            }
            let mut firsts: Vec<i64> = keys.iter().filter_map(|k| k.first().copied()).collect();
            firsts.sort_unstable();
            firsts.dedup();
            let labels: Vec<String> = firsts.iter().map(|i| i.to_string()).collect();
            c.err(CheckError::FamilyOutOfRange {
                lone: None,
                name: name.to_string(),
                index: label,
                members: super::expr::members_words(&labels),
                span: n.span,
            });
            None
        }
    }
}

/// The rules a name in `rules = [..]` selects, or an error (and none).
fn rule_indices(c: &mut Checker, n: &LogName, rules: &[CheckedRule]) -> Vec<usize> {
    let Some(label) = label_of(c, n) else {
        return Vec::new();
    };
    let base = n.target.name.name.as_str();
    let suffix = n.suffix.as_ref().map(|s| s.name.as_str());
    let selection = RuleSelection {
        base,
        label: label.as_deref(),
        suffix,
    };
    let found: Vec<usize> = rules
        .iter()
        .enumerate()
        .filter(|(_, r)| selection.matches(&r.name))
        .map(|(k, _)| k)
        .collect();
    if found.is_empty() {
        // A family's member it does not have: as for a family of states.
        if let Some(index) = selection.label {
            let labels: Vec<String> = rules
                .iter()
                .map(|r| RuleSelection::parse(&r.name))
                .filter(|p| p.base == base && p.suffix == suffix)
                .filter_map(|p| p.label.map(str::to_string))
                .collect();
            if !labels.is_empty() {
                c.err(CheckError::FamilyOutOfRange {
                    lone: None,
                    name: RuleSelection {
                        label: None,
                        ..selection
                    }
                    .to_string(),
                    index: index.to_string(),
                    members: super::expr::members_words(&labels),
                    span: n.span,
                });
                return found;
            }
        }
        let name = selection.to_string();
        // Families and noises by their own names too (`fire` for `fire[2]`).
        let suggestion = c
            .hints
            .charge(2 * rules.len())
            .then(|| {
                let mut candidates: Vec<String> = Vec::new();
                let mut seen = std::collections::HashSet::new();
                for r in rules {
                    let p = RuleSelection::parse(&r.name);
                    let whole = RuleSelection { label: None, ..p }.to_string();
                    for c in [r.name.clone(), whole] {
                        if seen.insert(c.clone()) {
                            candidates.push(c);
                        }
                    }
                }
                suggest(&name, candidates)
            })
            .flatten();
        c.err(CheckError::UnknownName {
            name,
            span: n.span,
            suggestion,
        });
    }
    found
}

/// A name that selects jump rules: `fire` (a rule, or every member of the
/// family `fire`), `fire[2]`, `v.redraw` (the redraws of the noise `v`, or of
/// every member of the noise family `v`), `v[2].redraw`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RuleSelection<'a> {
    /// The name before any index.
    pub base: &'a str,
    /// The family label (`2`, `1,3`), if given.
    pub label: Option<&'a str>,
    /// The part after the dot (`redraw`), if any.
    pub suffix: Option<&'a str>,
}

impl<'a> RuleSelection<'a> {
    /// Splits a rule name or selection as written (`fire[1, 3]`,
    /// `v[2].redraw`); spaces inside the index are ignored by
    /// [`matches`](Self::matches).
    pub fn parse(name: &'a str) -> Self {
        let name = name.trim();
        // A suffix follows the last `.` that is not inside brackets.
        let (head, suffix) = match name.rsplit_once('.') {
            Some((h, s)) if !s.contains(']') && !s.is_empty() => (h, Some(s.trim())),
            _ => (name, None),
        };
        let (base, label) = match head.strip_suffix(']').and_then(|h| h.split_once('[')) {
            Some((b, l)) => (b.trim(), Some(l)),
            None => (head.trim(), None),
        };
        Self {
            base,
            label,
            suffix,
        }
    }

    /// Whether the rule named `rule` (as the model names its rules) is
    /// selected. Names are compared with their index taken out, wherever it
    /// stands: the model names a member of an instance family's rule
    /// `f.fire[2]`, the language reads it `f[2].fire`, and the family is
    /// `f.fire` (as a noise family's member is `v[2].redraw`).
    ///
    /// A selection also names a subsystem instance: `b1`
    /// selects `b1.bounce`, `f` every rule of the instance family `f`, and
    /// `f[2]` those of its member (`f.fire[2]`, `f.g.fire[2][1]`).
    pub fn matches(&self, rule: &str) -> bool {
        let (name, label) = without_index(&self.to_string());
        let (rule_name, rule_label) = without_index(rule);
        let exact = name == rule_name
            && match (&label, &rule_label) {
                (None, _) => true,
                (Some(a), Some(b)) => a == b,
                (Some(_), None) => false,
            };
        // (`v` alone is a noise, whose redraws are named `v.redraw`.)
        let instance = rule_name
            .strip_prefix(name.as_str())
            .is_some_and(|rest| rest.starts_with('.') && rest != ".redraw")
            && match (&label, &rule_label) {
                (None, _) => true,
                (Some(a), Some(b)) => b.starts_with(a),
                (Some(_), None) => false,
            };
        exact || instance
    }
}

/// `name` without its index brackets (`f[2].fire` → `f.fire`), and the
/// index's entries (`["2"]`; several brackets, of nested families, in
/// order), spaces ignored.
fn without_index(name: &str) -> (String, Option<Vec<String>>) {
    let mut bare = String::with_capacity(name.len());
    let mut label: Option<Vec<String>> = None;
    let mut depth = 0usize;
    let mut entry = String::new();
    for ch in name.chars().filter(|c| !c.is_whitespace()) {
        match ch {
            '[' => {
                depth += 1;
                label.get_or_insert_with(Vec::new);
            }
            ']' if depth > 0 => {
                depth -= 1;
                if let Some(l) = label.as_mut() {
                    l.push(std::mem::take(&mut entry));
                }
            }
            ',' if depth > 0 => {
                if let Some(l) = label.as_mut() {
                    l.push(std::mem::take(&mut entry));
                }
            }
            _ if depth > 0 => entry.push(ch),
            _ => bare.push(ch),
        }
    }
    (bare, label)
}

impl std::fmt::Display for RuleSelection<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.base)?;
        if let Some(l) = self.label {
            write!(f, "[{l}]")?;
        }
        if let Some(s) = self.suffix {
            write!(f, ".{s}")?;
        }
        Ok(())
    }
}

/// The name a setting's value is, if it is a bare name (`json`).
fn word(e: &Expr) -> Option<&str> {
    match &e.kind {
        ExprKind::Name(n) => Some(n.as_str()),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::RuleSelection;

    #[test]
    fn rule_selections_match_rules_families_and_redraws() {
        let sel = |s| RuleSelection::parse(s);
        assert!(sel("event").matches("event"));
        assert!(sel("event").matches("event[3]"));
        assert!(sel("event[3]").matches("event[3]"));
        assert!(!sel("event[3]").matches("event[2]"));
        assert!(!sel("event").matches("event.redraw"));
        assert!(sel("edge[1, 3]").matches("edge[1,3]"));
        assert!(!sel("edge[1]").matches("edge[1,3]"));
        assert!(sel("v.redraw").matches("v.redraw"));
        assert!(sel("v.redraw").matches("v[2].redraw"));
        assert!(sel("v[2].redraw").matches("v[2].redraw"));
        assert!(!sel("v").matches("v.redraw"));
        assert!(!sel("eve").matches("event"));
        assert_eq!(sel("v[2].redraw").to_string(), "v[2].redraw");
        // Rules of a family of subsystem instances: the model's `f.fire[2]`.
        assert!(sel("f.fire").matches("f.fire[2]"));
        assert!(sel("f[2].fire").matches("f.fire[2]"));
        assert!(sel("f.fire[2]").matches("f.fire[2]"));
        assert!(!sel("f[1].fire").matches("f.fire[2]"));
        // An instance's rules by its name, not another's it begins.
        assert!(sel("f").matches("f.fire[2]"));
        assert!(sel("f[2]").matches("f.fire[2]"));
        assert!(!sel("f[1]").matches("f.fire[2]"));
        assert!(sel("b1").matches("b1.tick"));
        assert!(sel("b1").matches("b1.v.redraw"));
        assert!(!sel("b1").matches("b10.tick"));
        assert!(sel("f[2]").matches("f.g.fire[2][1]"));
        assert!(sel("ball.impact").matches("ball.impact"));
        let block = RuleSelection {
            base: "f",
            label: Some("2"),
            suffix: Some("fire"),
        };
        assert!(block.matches("f.fire[2]"));
    }
}
