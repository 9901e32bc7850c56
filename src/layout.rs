//! How a flat vector of numbers (a state or an output vector) is structured
//! into named scalars, vectors, matrices and families of agents.
//!
//! The engine works on flat `&[f64]`; sinks use a [`Layout`] to write
//! structured records (e.g. `/hybsim/state.agent[2].xhat` in Foxglove) and
//! readable column names (`agent[2].xhat[1]`) in CSV.

use serde::{Deserialize, Serialize};

/// Shape of one named field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Shape {
    /// One number.
    Scalar,
    /// A column vector of the given length.
    Vector(usize),
    /// A matrix, stored row-major in the flat vector.
    Matrix {
        /// Number of rows.
        rows: usize,
        /// Number of columns.
        cols: usize,
    },
}

impl Shape {
    /// Number of flat components.
    pub fn len(&self) -> usize {
        match *self {
            Shape::Scalar => 1,
            Shape::Vector(n) => n,
            // Saturating: a layout read back from a file may be damaged.
            Shape::Matrix { rows, cols } => rows.saturating_mul(cols),
        }
    }

    /// True for an empty vector or matrix.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A named field occupying `shape.len()` components from `offset`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Field {
    /// Name as written in the model.
    pub name: String,
    /// Its shape.
    pub shape: Shape,
    /// Index of its first component in the flat vector.
    pub offset: usize,
}

/// One top-level entry: a field, or a family (an array of records, one per
/// agent or edge, e.g. `agent[i].xhat`). A family whose members have one
/// field with an empty name is an array of values (`x[1]`, `x[2]`, … for the
/// `.hyb` family `state x[i]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Entry {
    /// A plain field.
    Field(Field),
    /// A family named `name` whose members each have the given fields;
    /// `labels[k]` names member k (e.g. `"2"` for agent 2, `"1,3"` for edge (1,3)).
    Family {
        /// Family name.
        name: String,
        /// One label per member.
        labels: Vec<String>,
        /// The fields of each member, in the same order for every member.
        members: Vec<Vec<Field>>,
    },
}

/// The structure of a flat vector.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Layout {
    /// Top-level entries, in declaration order.
    pub entries: Vec<Entry>,
}

impl Layout {
    /// A layout of scalars named `names`, one per component.
    pub fn scalars<S: AsRef<str>>(names: &[S]) -> Self {
        let entries = names
            .iter()
            .enumerate()
            .map(|(offset, n)| {
                Entry::Field(Field {
                    name: n.as_ref().to_string(),
                    shape: Shape::Scalar,
                    offset,
                })
            })
            .collect();
        Self { entries }
    }

    /// One flat name per component, in component order: `h`, `x[2]`,
    /// `P[1,2]`, `agent[3].xhat[1]`, `tau[3]` (1-based indices, as in the
    /// models); components the layout does not cover (hidden ones) have
    /// empty names.
    pub fn flat_names(&self, dim: usize) -> Vec<String> {
        let mut names = vec![String::new(); dim];
        for (k, name) in self.components() {
            if let Some(slot) = names.get_mut(k) {
                *slot = name;
            }
        }
        names
    }
}

/// One named block of a flat vector as a model declares it: a plain field,
/// or a member of a family (`x[2]`: family `x`, label `"2"`).
#[derive(Debug, Clone, Copy)]
pub struct Declared<'a> {
    /// Name as shown (`h`, `x[2]`).
    pub name: &'a str,
    /// Its shape.
    pub shape: Shape,
    /// Index of its first component.
    pub offset: usize,
    /// Family name and member label, for a family member.
    pub family: Option<(&'a str, &'a str)>,
}

impl Layout {
    /// The layout of declared blocks: plain fields in order, and one
    /// [`Entry::Family`] per family (at its first member's place) whose
    /// members are unnamed values of their own shapes, so that sinks write
    /// `x: [..]` and name the components `x[1]`, `x[2][1]`, ….
    pub fn from_declared<'a>(items: impl IntoIterator<Item = Declared<'a>>) -> Self {
        let mut entries: Vec<Entry> = Vec::new();
        let mut families: std::collections::HashMap<&str, usize> = Default::default();
        for d in items {
            let Some((family, label)) = d.family else {
                entries.push(Entry::Field(Field {
                    name: d.name.to_string(),
                    shape: d.shape,
                    offset: d.offset,
                }));
                continue;
            };
            let member = vec![Field {
                name: String::new(),
                shape: d.shape,
                offset: d.offset,
            }];
            match families.get(family) {
                Some(&e) => {
                    if let Entry::Family {
                        labels, members, ..
                    } = &mut entries[e]
                    {
                        labels.push(label.to_string());
                        members.push(member);
                    }
                }
                None => {
                    families.insert(family, entries.len());
                    entries.push(Entry::Family {
                        name: family.to_string(),
                        labels: vec![label.to_string()],
                        members: vec![member],
                    });
                }
            }
        }
        Self { entries }
    }

    /// The entry a model name refers to: a field or a family by its name
    /// (`h`, `xhat`), or one member of a family (`xhat[2]`, `e[1,3]`, a
    /// family restricted to that member). `None` if nothing has that name.
    pub fn find(&self, name: &str) -> Option<Entry> {
        let name = instance_index_last(name.trim());
        let name = name.as_str();
        let (base, label) = match name.strip_suffix(']').and_then(|n| n.split_once('[')) {
            Some((base, label)) => (base.trim(), Some(label.replace(' ', ""))),
            None => (name, None),
        };
        self.entries.iter().find_map(|e| match (e, &label) {
            (Entry::Field(f), None) if f.name == base => Some(e.clone()),
            (Entry::Family { name: n, .. }, None) if n == base => Some(e.clone()),
            (
                Entry::Family {
                    name: n,
                    labels,
                    members,
                },
                Some(label),
            ) if n == base => {
                let k = labels.iter().position(|l| l == label)?;
                Some(Entry::Family {
                    name: n.clone(),
                    labels: vec![labels[k].clone()],
                    members: vec![members[k].clone()],
                })
            }
            _ => None,
        })
    }

    /// The entries a model name selects: the entry [`find`](Self::find)
    /// gives, else those of a subsystem instance: `b1` (or a nested
    /// `plant.adc`) every state or output of the instance, `f[2]` those of
    /// member 2 of a family of instances, `f[2].c` (`f.c[2]`) member 2's
    /// whole family `c`. Empty if the name selects nothing.
    pub fn find_all(&self, name: &str) -> Vec<Entry> {
        if let Some(e) = self.find(name) {
            return vec![e];
        }
        let name = instance_index_last(name.trim());
        let (base, label) = match name.strip_suffix(']').and_then(|n| n.split_once('[')) {
            Some((base, label)) => (base.trim(), Some(label.replace(' ', ""))),
            None => (name.as_str(), None),
        };
        if base.is_empty() || base.contains(['[', ']']) {
            return Vec::new();
        }
        let under = |n: &str| {
            n.strip_prefix(base)
                .is_some_and(|rest| rest.starts_with('.'))
        };
        // An index selects a member of a family of instances, whose every
        // entry is a family: a single instance has no members.
        let single = |e: &Entry| matches!(e, Entry::Field(f) if under(&f.name));
        if label.is_some() && self.entries.iter().any(single) {
            return Vec::new();
        }
        self.entries
            .iter()
            .filter_map(|e| match (e, &label) {
                (_, None) => under(entry_name(e)).then(|| e.clone()),
                (Entry::Field(_), Some(_)) => None,
                (
                    Entry::Family {
                        name: n,
                        labels,
                        members,
                    },
                    Some(label),
                ) => {
                    // Only a family of instances (a dotted name) is indexed
                    // first by the instance: `e[1]` of a family `e[i, k]`
                    // stays an error.
                    if !(under(n) || (n == base && n.contains('.'))) {
                        return None;
                    }
                    let lead = format!("{label},");
                    let (labels, members): (Vec<_>, Vec<_>) = labels
                        .iter()
                        .zip(members)
                        .filter(|(l, _)| *l == label || l.starts_with(&lead))
                        .map(|(l, m)| (l.clone(), m.clone()))
                        .unzip();
                    (!labels.is_empty()).then(|| Entry::Family {
                        name: n.clone(),
                        labels,
                        members,
                    })
                }
            })
            .collect()
    }

    /// The layout of the entries named in `names` (see
    /// [`find_all`](Self::find_all)), in declaration order, members of one
    /// family merged into one entry; and the names that refer to nothing.
    pub fn select<S: AsRef<str>>(&self, names: &[S]) -> (Layout, Vec<String>) {
        let mut unknown = Vec::new();
        // Per entry of self: None (not selected), or the selected member labels
        // (all of them for a whole entry).
        let mut chosen: Vec<Option<Vec<String>>> = vec![None; self.entries.len()];
        for name in names {
            let name = name.as_ref();
            let found = self.find_all(name);
            if found.is_empty() {
                unknown.push(name.to_string());
                continue;
            }
            for found in found {
                let k = self
                    .entries
                    .iter()
                    .position(|e| entry_name(e) == entry_name(&found))
                    .expect("found in self");
                let labels = match &found {
                    Entry::Field(_) => Vec::new(),
                    Entry::Family { labels, .. } => labels.clone(),
                };
                let slot = chosen[k].get_or_insert_with(Vec::new);
                for l in labels {
                    if !slot.contains(&l) {
                        slot.push(l);
                    }
                }
            }
        }
        let entries = self
            .entries
            .iter()
            .zip(chosen)
            .filter_map(|(e, c)| {
                let c = c?;
                Some(match e {
                    Entry::Field(_) => e.clone(),
                    Entry::Family {
                        name,
                        labels,
                        members,
                    } => {
                        let (labels, members) = labels
                            .iter()
                            .zip(members)
                            .filter(|(l, _)| c.contains(l))
                            .map(|(l, m)| (l.clone(), m.clone()))
                            .unzip();
                        Entry::Family {
                            name: name.clone(),
                            labels,
                            members,
                        }
                    }
                })
            })
            .collect();
        (Layout { entries }, unknown)
    }

    /// The covered components in layout order, with their flat names.
    pub fn components(&self) -> Vec<(usize, String)> {
        let mut out = Vec::new();
        self.for_each_field(|prefix, f| {
            let names = field_names(prefix, f);
            out.extend((f.offset..).zip(names));
        });
        out
    }

    /// Calls `visit(prefix, field)` for every field, families' members in order.
    fn for_each_field(&self, mut visit: impl FnMut(&str, &Field)) {
        for e in &self.entries {
            match e {
                Entry::Field(f) => visit("", f),
                Entry::Family {
                    name,
                    labels,
                    members,
                } => {
                    for (label, fields) in labels.iter().zip(members) {
                        for f in fields {
                            visit(&member_prefix(name, label, f), f);
                        }
                    }
                }
            }
        }
    }
}

/// A member of a family of subsystem instances as the language reads it,
/// `f[2].x`, written as the model names it, `f.x[2]` (instance families index
/// their states and outputs first by the instance); other names unchanged.
pub fn instance_index_last(name: &str) -> String {
    if let Some((head, field)) = name.rsplit_once("].")
        && let Some((base, label)) = head.split_once('[')
        && !label.contains(['[', ']'])
        && !field.contains(['[', ']'])
    {
        return format!("{base}.{field}[{label}]");
    }
    name.to_string()
}

/// The name of a top-level entry.
pub fn entry_name(e: &Entry) -> &str {
    match e {
        Entry::Field(f) => &f.name,
        Entry::Family { name, .. } => name,
    }
}

/// Flat names of the components of `f` (`x[1]`, `P[1,2]`), prefixed.
fn field_names(prefix: &str, f: &Field) -> Vec<String> {
    match f.shape {
        Shape::Scalar => vec![format!("{prefix}{}", f.name)],
        Shape::Vector(n) => (1..=n)
            .map(|i| format!("{prefix}{}[{i}]", f.name))
            .collect(),
        Shape::Matrix { rows, cols } => (1..=rows)
            .flat_map(|r| (1..=cols).map(move |c| (r, c)))
            .map(|(r, c)| format!("{prefix}{}[{r},{c}]", f.name))
            .collect(),
    }
}

/// The prefix of field `f` of member `label` of family `family` in flat
/// names: `agent[2].` (then the field's name), or `x[2]` for an unnamed field.
pub fn member_prefix(family: &str, label: &str, f: &Field) -> String {
    if f.name.is_empty() {
        format!("{family}[{label}]")
    } else {
        format!("{family}[{label}].")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selections_by_entry_and_member_names() {
        let field = |name: &str, shape, offset| Field {
            name: name.into(),
            shape,
            offset,
        };
        let layout = Layout::from_declared([
            Declared {
                name: "h",
                shape: Shape::Scalar,
                offset: 0,
                family: None,
            },
            Declared {
                name: "x[1]",
                shape: Shape::Vector(2),
                offset: 1,
                family: Some(("x", "1")),
            },
            Declared {
                name: "x[2]",
                shape: Shape::Vector(2),
                offset: 3,
                family: Some(("x", "2")),
            },
        ]);
        let (sel, unknown) = layout.select(&["x[2]", "nope", "h", "x[ 2 ]"]);
        assert_eq!(unknown, ["nope"]);
        assert_eq!(entry_name(&sel.entries[0]), "h", "declaration order");
        assert_eq!(
            sel.entries[1],
            Entry::Family {
                name: "x".into(),
                labels: vec!["2".into()],
                members: vec![vec![field("", Shape::Vector(2), 3)]],
            }
        );
        assert_eq!(
            sel.components(),
            [
                (0, "h".to_string()),
                (3, "x[2][1]".into()),
                (4, "x[2][2]".into())
            ]
        );
        assert!(layout.find("x[3]").is_none() && layout.find("h[1]").is_none());
        assert_eq!(
            layout.select(&["x"]).0,
            Layout {
                entries: layout.entries[1..].to_vec()
            }
        );
    }

    #[test]
    fn families_of_values_are_named_like_the_model() {
        let field = |name: &str, shape, offset| Field {
            name: name.into(),
            shape,
            offset,
        };
        let layout = Layout {
            entries: vec![
                Entry::Field(field("h", Shape::Scalar, 0)),
                Entry::Family {
                    name: "x".into(),
                    labels: vec!["1".into(), "2".into()],
                    members: vec![
                        vec![field("", Shape::Vector(2), 1)],
                        vec![field("", Shape::Vector(2), 3)],
                    ],
                },
                Entry::Family {
                    name: "agent".into(),
                    labels: vec!["1,2".into()],
                    members: vec![vec![field("xhat", Shape::Scalar, 5)]],
                },
            ],
        };
        assert_eq!(
            layout.flat_names(6),
            [
                "h",
                "x[1][1]",
                "x[1][2]",
                "x[2][1]",
                "x[2][2]",
                "agent[1,2].xhat"
            ]
        );
    }

    #[test]
    fn an_instance_name_selects_all_of_the_instance() {
        // `b1 = Ball()`, `b10 = Ball()`, a family `f[i] = Osc()` with a
        // family `c[m]` inside, and a family `e[i, k]` of the model.
        let mut offset = 0;
        let mut item = |name: &'static str, family: Option<(&'static str, &'static str)>| {
            offset += 1;
            Declared {
                name,
                shape: Shape::Scalar,
                offset: offset - 1,
                family,
            }
        };
        let layout = Layout::from_declared([
            item("b1.h", None),
            item("b1.v", None),
            item("b10.h", None),
            item("f.x[1]", Some(("f.x", "1"))),
            item("f.x[2]", Some(("f.x", "2"))),
            item("f.c[1,1]", Some(("f.c", "1,1"))),
            item("f.c[1,2]", Some(("f.c", "1,2"))),
            item("f.c[2,1]", Some(("f.c", "2,1"))),
            item("f.c[2,2]", Some(("f.c", "2,2"))),
            item("e[1,1]", Some(("e", "1,1"))),
            item("e[1,2]", Some(("e", "1,2"))),
        ]);
        let names = |sel: &[&str]| -> Vec<String> {
            let (layout, unknown) = layout.select(sel);
            assert!(unknown.is_empty(), "{unknown:?}");
            layout.components().into_iter().map(|(_, n)| n).collect()
        };
        assert_eq!(names(&["b1"]), ["b1.h", "b1.v"]);
        assert_eq!(
            names(&["f"]),
            [
                "f.x[1]", "f.x[2]", "f.c[1,1]", "f.c[1,2]", "f.c[2,1]", "f.c[2,2]"
            ]
        );
        assert_eq!(names(&["f[2]"]), ["f.x[2]", "f.c[2,1]", "f.c[2,2]"]);
        assert_eq!(names(&["f[2].c"]), ["f.c[2,1]", "f.c[2,2]"]);
        assert_eq!(names(&["f.c[1]", "b1.v"]), ["b1.v", "f.c[1,1]", "f.c[1,2]"]);
        // Exact names are found as before; nothing else is taken for an instance.
        assert_eq!(names(&["f.c[2,1]"]), ["f.c[2,1]"]);
        for nope in ["b", "f[3]", "e[1]", "b1[1]", "h", "f.", ""] {
            assert!(layout.find_all(nope).is_empty(), "{nope}");
        }
    }
}
