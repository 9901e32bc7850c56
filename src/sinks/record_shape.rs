//! The shapes of sample records that every message encoding shares (JSON
//! in [`super::json`], protobuf in [`super::protobuf`]): how dotted entry
//! names nest as objects and how the members of a family are written, so
//! that both encodings give every number the same message path.

use crate::layout::{Entry, Field, Shape};

/// How the members of a family are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum FamilyForm {
    /// Unnamed scalars: an array of numbers.
    Numbers,
    /// Unnamed vectors: an array of `{data}` objects (`Some(n)` if all have
    /// length n).
    Vectors(Option<usize>),
    /// Unnamed matrices, or unnamed values of mixed shapes: an array of
    /// `{rows, cols, data}` objects.
    Matrices,
    /// Members with named fields: an array of objects.
    Records,
}

pub(super) fn family_form(members: &[Vec<Field>]) -> FamilyForm {
    let mut shapes = Vec::with_capacity(members.len());
    for m in members {
        match m.as_slice() {
            [f] if f.name.is_empty() => shapes.push(f.shape),
            _ => return FamilyForm::Records,
        }
    }
    if shapes.iter().all(|s| *s == Shape::Scalar) {
        return FamilyForm::Numbers;
    }
    let lengths: Vec<usize> = shapes
        .iter()
        .filter_map(|s| match s {
            Shape::Vector(n) => Some(*n),
            _ => None,
        })
        .collect();
    if lengths.len() == shapes.len() {
        let same = lengths.windows(2).all(|w| w[0] == w[1]);
        return FamilyForm::Vectors(if same { lengths.first().copied() } else { None });
    }
    FamilyForm::Matrices
}

/// Entries of a layout nested by the dots of their names: `ball.h` and
/// `ball.v` (members of a subsystem instance `ball`) become the object
/// `ball: {h, v}`, so that every JSON name is an identifier that Foxglove's
/// message paths reach (`/hybsim/state.ball.h`).
pub(super) enum Node<'a> {
    /// An entry, shown under the last part of its name.
    Leaf(&'a Entry, &'a str),
    /// The entries whose names start with `name.`.
    Group(&'a str, Vec<Node<'a>>),
}

pub(super) fn nest(entries: &[Entry]) -> Vec<Node<'_>> {
    let mut out = Vec::new();
    for e in entries {
        let name = match e {
            Entry::Field(f) => f.name.as_str(),
            Entry::Family { name, .. } => name.as_str(),
        };
        insert(&mut out, e, name);
    }
    out
}

fn insert<'a>(level: &mut Vec<Node<'a>>, e: &'a Entry, name: &'a str) {
    let Some((head, tail)) = name.split_once('.') else {
        level.push(Node::Leaf(e, name));
        return;
    };
    let at = level
        .iter()
        .position(|n| matches!(n, Node::Group(g, _) if *g == head));
    let at = at.unwrap_or_else(|| {
        level.push(Node::Group(head, Vec::new()));
        level.len() - 1
    });
    if let Node::Group(_, inner) = &mut level[at] {
        insert(inner, e, tail);
    }
}
