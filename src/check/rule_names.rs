//! The jump rules' names as properties and metrics look them up: by name
//! (`fire[2]`) and by family (`fire`, every member), each in constant time,
//! so that checking is linear in the number of references.

use std::collections::{HashMap, HashSet};

use super::error::CheckError;
use super::expr::members_words;
use crate::source::Span;
use crate::syntax::ast::{Item, Trigger};

/// The names of rules declared without one, in declaration order: `every Ts { … }` is `step`,
/// `step2`, …; `jump when … { … }` is `jump1`, `jump2`, … (`jump` is a keyword). Subsystem
/// instances count their own.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Anonymous {
    every: usize,
    jumps: usize,
}

impl Anonymous {
    /// The name of the next rule without one, triggered by `trigger`.
    pub(crate) fn name(&mut self, trigger: &Trigger) -> String {
        match trigger {
            Trigger::When(_) => {
                self.jumps += 1;
                format!("jump{}", self.jumps)
            }
            Trigger::Every(_) => {
                self.every += 1;
                if self.every == 1 {
                    "step".to_string()
                } else {
                    format!("step{}", self.every)
                }
            }
        }
    }
}

/// The rules' names in declaration order, indexed by name and by family.
#[derive(Debug, Clone, Default)]
pub(crate) struct RuleNames {
    names: Vec<String>,
    index: HashMap<String, usize>,
    /// Family name (`fire` of `fire[2]`) → its members, in declaration order; a family declared
    /// over an empty range has none.
    families: HashMap<String, Vec<usize>>,
    /// Rules declared but refused (their own errors are reported): known names without a
    /// rule, so that naming one reports nothing more.
    failed: HashSet<String>,
}

impl RuleNames {
    /// The rules `names`, the families the model declares ([`declared_families`]), which
    /// may have no member, and the names of rules refused by the checker.
    pub(crate) fn new(names: Vec<String>, declared: Vec<String>, failed: HashSet<String>) -> Self {
        let mut index = HashMap::with_capacity(names.len());
        let mut families: HashMap<String, Vec<usize>> =
            declared.into_iter().map(|f| (f, Vec::new())).collect();
        for (k, name) in names.iter().enumerate() {
            // A name declared twice is an error reported elsewhere; the first counts.
            index.entry(name.clone()).or_insert(k);
            if let Some((base, _)) = name.split_once('[') {
                families.entry(base.to_string()).or_default().push(k);
            }
        }
        Self {
            names,
            index,
            families,
            failed,
        }
    }

    /// Whether `name` is a rule that was declared but refused (an error already reported).
    pub(crate) fn is_failed(&self, name: &str) -> bool {
        self.failed.contains(name)
    }

    /// All names, in declaration order (for "did you mean" hints).
    pub(crate) fn names(&self) -> &[String] {
        &self.names
    }

    /// The rule named exactly `name`.
    pub(crate) fn get(&self, name: &str) -> Option<usize> {
        self.index.get(name).copied()
    }

    /// Whether `name` is a declared family of rules (possibly empty).
    pub(crate) fn is_family(&self, name: &str) -> bool {
        self.families.contains_key(name)
    }

    /// The index labels (`2`, `1,3`) of the members of family `name`, in
    /// declaration order; `None` if it is not a family.
    pub(crate) fn member_labels(&self, name: &str) -> Option<Vec<String>> {
        let members = self.families.get(name)?;
        Some(
            members
                .iter()
                .map(|&k| {
                    let full = &self.names[k];
                    full[name.len() + 1..full.len() - 1].to_string()
                })
                .collect(),
        )
    }

    /// The error of a reference to no rule: `base[index]` (or `base`) where
    /// `base` is a family without that member is a family's missing member
    /// (E0402, as for states); otherwise an unknown name, with the hint
    /// `suggest` gives for the full name.
    pub(crate) fn not_found(
        &self,
        base: &str,
        index: Option<String>,
        span: Span,
        suggest: impl FnOnce(&str) -> Option<String>,
    ) -> CheckError {
        if let Some(index) = &index
            && let Some(labels) = self.member_labels(base).filter(|l| !l.is_empty())
        {
            return CheckError::FamilyOutOfRange {
                lone: None,
                name: base.to_string(),
                index: index.clone(),
                members: members_words(&labels),
                span,
            };
        }
        let name = match &index {
            Some(i) => format!("{base}[{i}]"),
            None => base.to_string(),
        };
        let suggestion = suggest(&name);
        CheckError::UnknownName {
            name,
            span,
            suggestion,
        }
    }

    /// The rules `name` stands for: the rule of that name and, for a family
    /// name, every member, in declaration order.
    pub(crate) fn matching(&self, name: &str) -> Vec<usize> {
        let mut found: Vec<usize> = self.get(name).into_iter().collect();
        if !name.contains('[')
            && let Some(members) = self.families.get(name)
        {
            found.extend(members);
            found.sort_unstable();
            found.dedup();
        }
        found
    }
}

/// The families of jump rules `items` (a flat model: instances elaborated) declare, members or
/// not: `fire` of `for i in 1..N { jump fire[i] … }` and `f.fire` of a family of instances
/// `f[i]` are families even when N = 0 (so `count(fire)` is 0 rather than an unknown name).
pub(crate) fn declared_families(items: &[Item]) -> Vec<String> {
    let mut out = Vec::new();
    for it in items {
        match it {
            Item::Jump(j) => {
                if let Some(t) = j.name.as_ref().filter(|t| !t.indices.is_empty()) {
                    out.push(t.name.name.clone());
                }
            }
            Item::For(_, body) | Item::Together(body, _) | Item::Part(_, body) => {
                out.extend(declared_families(body));
            }
            _ => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_families_are_found_in_declaration_order() {
        let r = RuleNames::new(
            ["fire[1]", "reset", "fire[2]", "fire", "fire[1,2]"]
                .map(String::from)
                .to_vec(),
            vec!["fire".into(), "none".into()],
            HashSet::from(["broken".to_string()]),
        );
        assert_eq!(r.get("fire[2]"), Some(2));
        assert_eq!(r.get("fire[3]"), None);
        assert_eq!(r.matching("fire"), [0, 2, 3, 4]);
        assert_eq!(r.matching("fire[1]"), [0]);
        assert_eq!(r.matching("reset"), [1]);
        assert!(r.matching("fir").is_empty());
        assert_eq!(r.names().len(), 5);
        // A family declared over an empty range: known, no member.
        assert!(r.is_family("none") && r.matching("none").is_empty());
        assert_eq!(r.member_labels("fire").unwrap(), ["1", "2", "1,2"]);
        assert_eq!(r.member_labels("reset"), None);
        assert!(!r.is_family("reset"));
        assert!(r.is_failed("broken") && r.get("broken").is_none());
    }
}
