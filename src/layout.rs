//! How a flat vector of numbers (a state or an output vector) is structured
//! into named scalars, vectors, matrices and families of agents.
//!
//! The engine works on flat `&[f64]`; sinks use a [`Layout`] to write
//! structured records (e.g. `/hybsim/state.agent[2].xhat` in Foxglove) and
//! readable column names (`agent[2].xhat[1]`) in CSV.

use serde::Serialize;

/// Shape of one named field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
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
            Shape::Matrix { rows, cols } => rows * cols,
        }
    }

    /// True for an empty vector or matrix.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A named field occupying `shape.len()` components from `offset`.
#[derive(Debug, Clone, PartialEq, Serialize)]
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
#[derive(Debug, Clone, PartialEq, Serialize)]
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
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
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
    /// models).
    pub fn flat_names(&self, dim: usize) -> Vec<String> {
        let mut names = vec![String::new(); dim];
        let mut put = |prefix: &str, f: &Field| match f.shape {
            Shape::Scalar => names[f.offset] = format!("{prefix}{}", f.name),
            Shape::Vector(n) => {
                for i in 0..n {
                    names[f.offset + i] = format!("{prefix}{}[{}]", f.name, i + 1);
                }
            }
            Shape::Matrix { rows, cols } => {
                for r in 0..rows {
                    for c in 0..cols {
                        names[f.offset + r * cols + c] =
                            format!("{prefix}{}[{},{}]", f.name, r + 1, c + 1);
                    }
                }
            }
        };
        for e in &self.entries {
            match e {
                Entry::Field(f) => put("", f),
                Entry::Family {
                    name,
                    labels,
                    members,
                } => {
                    for (label, fields) in labels.iter().zip(members) {
                        for f in fields {
                            put(&member_prefix(name, label, f), f);
                        }
                    }
                }
            }
        }
        names
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
}
