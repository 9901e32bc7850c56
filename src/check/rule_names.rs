//! The jump rules' names as properties and metrics look them up: by name
//! (`fire[2]`) and by family (`fire`, every member), each in constant time,
//! so that checking is linear in the number of references.

use std::collections::HashMap;

/// The rules' names in declaration order, indexed by name and by family.
#[derive(Debug, Clone, Default)]
pub(crate) struct RuleNames {
    names: Vec<String>,
    index: HashMap<String, usize>,
    /// Family name (`fire` of `fire[2]`) → its members, in declaration order.
    families: HashMap<String, Vec<usize>>,
}

impl RuleNames {
    pub(crate) fn new(names: Vec<String>) -> Self {
        let mut index = HashMap::with_capacity(names.len());
        let mut families: HashMap<String, Vec<usize>> = HashMap::new();
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
        }
    }

    /// All names, in declaration order (for "did you mean" hints).
    pub(crate) fn names(&self) -> &[String] {
        &self.names
    }

    /// The rule named exactly `name`.
    pub(crate) fn get(&self, name: &str) -> Option<usize> {
        self.index.get(name).copied()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_families_are_found_in_declaration_order() {
        let r = RuleNames::new(
            ["fire[1]", "reset", "fire[2]", "fire", "fire[1,2]"]
                .map(String::from)
                .to_vec(),
        );
        assert_eq!(r.get("fire[2]"), Some(2));
        assert_eq!(r.get("fire[3]"), None);
        assert_eq!(r.matching("fire"), [0, 2, 3, 4]);
        assert_eq!(r.matching("fire[1]"), [0]);
        assert_eq!(r.matching("reset"), [1]);
        assert!(r.matching("fir").is_empty());
        assert_eq!(r.names().len(), 5);
    }
}
