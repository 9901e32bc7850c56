//! JSON records of samples and jumps, and the JSON Schemas that describe
//! them, generated from a model's [`Layout`].
//!
//! Shapes (chosen so that Foxglove can address every number with a message
//! path such as `/hybsim/state.agent[2].xhat[0]`):
//!
//! | layout | JSON | schema |
//! |---|---|---|
//! | scalar `h` | `"h": 1.5` | `number` |
//! | vector `x` | `"x": [1, 2]` | `array` of `number`, fixed length |
//! | matrix `P` | `"P": {"rows": 2, "cols": 2, "data": [..]}` (row-major) | `object` |
//! | family of records `agent` | `"agent": [{"xhat": ..}, ..]` | `array` of `object` |
//! | family of scalars `z[i]` | `"z": [1, 2]` | `array` of `number` |
//! | family of vectors `xhat[i]` | `"xhat": [{"data": [..]}, ..]` | `array` of `object` |
//! | family of matrices or of mixed shapes `P[i]` | `"P": [{"rows": 2, "cols": 2, "data": [..]}, ..]` | `array` of `object` |
//! | members of a subsystem instance `ball.h`, `node.x[i]` | `"ball": {"h": ..}`, `"node": {"x": [..]}` | `object` |
//!
//! State families and output families are written alike. Every record
//! carries `t` (number) and `j` (integer). Schemas obey the rules of
//! Foxglove's JSON Schema parser ([`super::foxglove`]): no arrays of
//! arrays, no `$ref`, no unions, names that message paths reach without
//! quoting (`/hybsim/state.xhat[1].data[0]`).

use serde::ser::{SerializeMap, SerializeStruct};
use serde::{Serialize, Serializer};
use serde_json::{Value, json};

use crate::arc::HybridTime;
use crate::layout::{Entry, Field, Layout, Shape};

/// The JSON Schema dialect named in every generated schema.
pub const DIALECT: &str = "https://json-schema.org/draft/2020-12/schema";

fn field_schema(shape: Shape) -> Value {
    match shape {
        Shape::Scalar => json!({"type": "number"}),
        Shape::Vector(n) => json!({
            "type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n
        }),
        Shape::Matrix { rows, cols } => json!({
            "type": "object",
            "description": "row-major matrix",
            "properties": {
                "rows": {"type": "integer", "const": rows},
                "cols": {"type": "integer", "const": cols},
                "data": {"type": "array", "items": {"type": "number"},
                         "minItems": rows * cols, "maxItems": rows * cols}
            },
            "required": ["rows", "cols", "data"]
        }),
    }
}

/// How the members of a family are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FamilyForm {
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

fn family_form(members: &[Vec<Field>]) -> FamilyForm {
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

fn fields_schema(fields: &[Field]) -> (serde_json::Map<String, Value>, Vec<String>) {
    let props = fields
        .iter()
        .map(|f| (f.name.clone(), field_schema(f.shape)))
        .collect();
    let required = fields.iter().map(|f| f.name.clone()).collect();
    (props, required)
}

/// Properties and required names of the values of `layout` (no `t`, `j`).
fn layout_properties(layout: &Layout) -> (serde_json::Map<String, Value>, Vec<String>) {
    nodes_properties(&nest(&layout.entries))
}

/// Entries of a layout nested by the dots of their names: `ball.h` and
/// `ball.v` (members of a subsystem instance `ball`) become the object
/// `ball: {h, v}`, so that every JSON name is an identifier that Foxglove's
/// message paths reach (`/hybsim/state.ball.h`).
enum Node<'a> {
    /// An entry, shown under the last part of its name.
    Leaf(&'a Entry, &'a str),
    /// The entries whose names start with `name.`.
    Group(&'a str, Vec<Node<'a>>),
}

fn nest(entries: &[Entry]) -> Vec<Node<'_>> {
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

fn nodes_properties(nodes: &[Node<'_>]) -> (serde_json::Map<String, Value>, Vec<String>) {
    let mut props = serde_json::Map::new();
    let mut required = Vec::new();
    for node in nodes {
        let (e, shown) = match node {
            Node::Leaf(e, shown) => (*e, *shown),
            Node::Group(name, inner) => {
                let (p, r) = nodes_properties(inner);
                props.insert(
                    name.to_string(),
                    json!({"type": "object", "properties": p, "required": r}),
                );
                required.push(name.to_string());
                continue;
            }
        };
        match e {
            Entry::Field(f) => {
                props.insert(shown.to_string(), field_schema(f.shape));
                required.push(shown.to_string());
            }
            Entry::Family {
                labels, members, ..
            } => {
                let items = match family_form(members) {
                    FamilyForm::Numbers => json!({"type": "number"}),
                    FamilyForm::Vectors(n) => {
                        let mut data = json!({"type": "array", "items": {"type": "number"}});
                        if let Some(n) = n {
                            data["minItems"] = json!(n);
                            data["maxItems"] = json!(n);
                        }
                        json!({"type": "object", "properties": {"data": data}, "required": ["data"]})
                    }
                    FamilyForm::Matrices => json!({
                        "type": "object",
                        "description": "row-major matrix",
                        "properties": {
                            "rows": {"type": "integer"},
                            "cols": {"type": "integer"},
                            "data": {"type": "array", "items": {"type": "number"}}
                        },
                        "required": ["rows", "cols", "data"]
                    }),
                    FamilyForm::Records => {
                        // All members have the same fields.
                        let first = members.first().map(Vec::as_slice).unwrap_or(&[]);
                        let (item_props, item_required) = fields_schema(first);
                        json!({"type": "object", "properties": item_props, "required": item_required})
                    }
                };
                props.insert(
                    shown.to_string(),
                    json!({
                        "type": "array",
                        "description": format!("members in order: {}", labels.join("; ")),
                        "minItems": labels.len(),
                        "maxItems": labels.len(),
                        "items": items
                    }),
                );
                required.push(shown.to_string());
            }
        }
    }
    (props, required)
}

fn time_properties(props: &mut serde_json::Map<String, Value>, required: &mut Vec<String>) {
    props.insert(
        "t".into(),
        json!({"type": "number", "description": "ordinary time t"}),
    );
    props.insert(
        "j".into(),
        json!({"type": "integer", "minimum": 0, "description": "jump count j"}),
    );
    required.splice(0..0, ["t".to_string(), "j".to_string()]);
}

/// Schema of a sample record `{t, j, <entries of layout>}`.
pub fn sample_schema(title: &str, layout: &Layout) -> Value {
    let (mut props, mut required) = layout_properties(layout);
    time_properties(&mut props, &mut required);
    json!({
        "$schema": DIALECT,
        "title": title,
        "type": "object",
        "properties": props,
        "required": required
    })
}

/// Schema of a jump record `{t, j, rule, rule_id, index?, pre{..}, post{..}}`;
/// `t, j` are the pre-jump hybrid time.
pub fn jump_schema(title: &str, layout: &Layout) -> Value {
    let (state_props, state_required) = layout_properties(layout);
    let state = json!({"type": "object", "properties": state_props, "required": state_required});
    let mut props = serde_json::Map::new();
    let mut required = vec![
        "rule".to_string(),
        "rule_id".into(),
        "pre".into(),
        "post".into(),
    ];
    props.insert(
        "rule".into(),
        json!({"type": "string", "description": "name of the jump rule that fired"}),
    );
    props.insert(
        "rule_id".into(),
        json!({"type": "integer", "minimum": 0, "description": "position of the rule in the model"}),
    );
    props.insert(
        "index".into(),
        json!({"type": "array", "items": {"type": "integer"},
               "description": "indices of an indexed rule, e.g. [2] for transmit[2]"}),
    );
    let mut pre = state.clone();
    pre["description"] = json!("state just before the jump, at (t, j)");
    let mut post = state;
    post["description"] = json!("state just after the jump, at (t, j + 1)");
    props.insert("pre".into(), pre);
    props.insert("post".into(), post);
    time_properties(&mut props, &mut required);
    json!({
        "$schema": DIALECT,
        "title": title,
        "type": "object",
        "properties": props,
        "required": required
    })
}

/// Schema of `foxglove.Log` in JSON (the fields Foxglove's Log panel reads).
pub fn log_schema() -> Value {
    json!({
        "$schema": DIALECT,
        "title": "foxglove.Log",
        "description": "A log message",
        "type": "object",
        "properties": {
            "timestamp": {
                "type": "object",
                "properties": {
                    "sec": {"type": "integer", "minimum": 0},
                    "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}
                },
                "required": ["sec", "nsec"]
            },
            "level": {"type": "integer", "minimum": 0, "maximum": 5,
                      "description": "0 unknown, 1 debug, 2 info, 3 warning, 4 error, 5 fatal"},
            "message": {"type": "string"},
            "name": {"type": "string"},
            "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0}
        },
        "required": ["timestamp", "level", "message", "name", "file", "line"]
    })
}

/// Severity of a `/hybsim/log` message (values of `foxglove.LogLevel`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogLevel {
    /// Informational.
    Info = 2,
    /// Something the user should look at.
    Warning = 3,
    /// The run failed.
    Error = 4,
}

/// A `foxglove.Log` message.
#[derive(Debug, Clone, Serialize)]
pub struct LogRecord<'a> {
    /// `{sec, nsec}` of the log time.
    pub timestamp: LogTimestamp,
    /// [`LogLevel`] as an integer.
    pub level: u8,
    /// The text.
    pub message: &'a str,
    /// Always `hybsim`.
    pub name: &'a str,
    /// The model file.
    pub file: &'a str,
    /// Line in the model file (0 if none).
    pub line: u32,
}

/// A `foxglove` time.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LogTimestamp {
    /// Whole seconds.
    pub sec: u64,
    /// Nanoseconds.
    pub nsec: u32,
}

impl LogTimestamp {
    /// Splits nanoseconds.
    pub fn from_nanos(ns: u64) -> Self {
        Self {
            sec: ns / 1_000_000_000,
            nsec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// The values of a flat vector `x`, structured by `layout` (serializes as a
/// map of the layout's entries).
#[derive(Clone, Copy)]
pub struct Values<'a> {
    /// The structure.
    pub layout: &'a Layout,
    /// The flat vector.
    pub x: &'a [f64],
}

struct Matrix<'a> {
    rows: usize,
    cols: usize,
    data: &'a [f64],
}

impl Serialize for Matrix<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_struct("Matrix", 3)?;
        m.serialize_field("rows", &self.rows)?;
        m.serialize_field("cols", &self.cols)?;
        m.serialize_field("data", self.data)?;
        m.end()
    }
}

fn put_field<M: SerializeMap>(m: &mut M, f: &Field, x: &[f64]) -> Result<(), M::Error> {
    m.serialize_entry(&f.name, &FieldValue { f, x })
}

/// The value of one field: a number, an array or a matrix object.
struct FieldValue<'a> {
    f: &'a Field,
    x: &'a [f64],
}

impl Serialize for FieldValue<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let v = &self.x[self.f.offset..self.f.offset + self.f.shape.len()];
        match self.f.shape {
            Shape::Scalar => v[0].serialize(s),
            Shape::Vector(_) => v.serialize(s),
            Shape::Matrix { rows, cols } => Matrix {
                rows,
                cols,
                data: v,
            }
            .serialize(s),
        }
    }
}

/// One member of a family written in `form`.
struct Member<'a> {
    form: FamilyForm,
    fields: &'a [Field],
    x: &'a [f64],
}

impl Serialize for Member<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match (self.form, self.fields) {
            (FamilyForm::Numbers, [f]) => FieldValue { f, x: self.x }.serialize(s),
            (FamilyForm::Vectors(_), [f]) => {
                let mut m = s.serialize_struct("Vector", 1)?;
                m.serialize_field("data", &self.x[f.offset..f.offset + f.shape.len()])?;
                m.end()
            }
            (FamilyForm::Matrices, [f]) => {
                let (rows, cols) = match f.shape {
                    Shape::Scalar => (1, 1),
                    Shape::Vector(n) => (n, 1),
                    Shape::Matrix { rows, cols } => (rows, cols),
                };
                Matrix {
                    rows,
                    cols,
                    data: &self.x[f.offset..f.offset + f.shape.len()],
                }
                .serialize(s)
            }
            _ => {
                let mut m = s.serialize_map(Some(self.fields.len()))?;
                for f in self.fields {
                    put_field(&mut m, f, self.x)?;
                }
                m.end()
            }
        }
    }
}

struct Family<'a> {
    members: &'a [Vec<Field>],
    x: &'a [f64],
}

impl Serialize for Family<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let form = family_form(self.members);
        s.collect_seq(self.members.iter().map(|fields| Member {
            form,
            fields,
            x: self.x,
        }))
    }
}

impl Values<'_> {
    fn put<M: SerializeMap>(&self, m: &mut M) -> Result<(), M::Error> {
        let dotted = self.layout.entries.iter().any(|e| match e {
            Entry::Field(f) => f.name.contains('.'),
            Entry::Family { name, .. } => name.contains('.'),
        });
        if dotted {
            return put_nodes(m, &nest(&self.layout.entries), self.x);
        }
        for e in &self.layout.entries {
            match e {
                Entry::Field(f) => put_field(m, f, self.x)?,
                Entry::Family { name, members, .. } => {
                    m.serialize_entry(name, &Family { members, x: self.x })?
                }
            }
        }
        Ok(())
    }
}

fn put_nodes<M: SerializeMap>(m: &mut M, nodes: &[Node<'_>], x: &[f64]) -> Result<(), M::Error> {
    for node in nodes {
        match node {
            Node::Leaf(Entry::Field(f), shown) => {
                m.serialize_entry(*shown, &FieldValue { f, x })?
            }
            Node::Leaf(Entry::Family { members, .. }, shown) => {
                m.serialize_entry(*shown, &Family { members, x })?
            }
            Node::Group(name, inner) => m.serialize_entry(*name, &Group { nodes: inner, x })?,
        }
    }
    Ok(())
}

/// The object of a [`Node::Group`].
struct Group<'a> {
    nodes: &'a [Node<'a>],
    x: &'a [f64],
}

impl Serialize for Group<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        put_nodes(&mut m, self.nodes, self.x)?;
        m.end()
    }
}

impl Serialize for Values<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        self.put(&mut m)?;
        m.end()
    }
}

/// A sample record `{t, j, ...values}`.
pub struct SampleRecord<'a> {
    /// Hybrid time.
    pub at: HybridTime,
    /// The values.
    pub values: Values<'a>,
}

impl Serialize for SampleRecord<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("t", &self.at.t)?;
        m.serialize_entry("j", &self.at.j)?;
        self.values.put(&mut m)?;
        m.end()
    }
}

/// A jump record `{t, j, rule, rule_id, index?, pre, post}`.
pub struct JumpRecordJson<'a> {
    /// Pre-jump hybrid time.
    pub at: HybridTime,
    /// Rule name as in the model (`transmit[2]`).
    pub rule: &'a str,
    /// Position of the rule.
    pub rule_id: usize,
    /// State before.
    pub pre: Values<'a>,
    /// State after.
    pub post: Values<'a>,
}

/// The indices of an indexed rule name: `transmit[2]` → `[2]`,
/// `edge[1,3]` → `[1, 3]`; `None` for a plain name or non-integer indices.
pub fn rule_indices(name: &str) -> Option<Vec<i64>> {
    let inner = name.strip_suffix(']')?;
    let open = inner.rfind('[')?;
    inner[open + 1..]
        .split(',')
        .map(|s| s.trim().parse::<i64>().ok())
        .collect()
}

impl Serialize for JumpRecordJson<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(None)?;
        m.serialize_entry("t", &self.at.t)?;
        m.serialize_entry("j", &self.at.j)?;
        m.serialize_entry("rule", self.rule)?;
        m.serialize_entry("rule_id", &self.rule_id)?;
        if let Some(index) = rule_indices(self.rule) {
            m.serialize_entry("index", &index)?;
        }
        m.serialize_entry("pre", &self.pre)?;
        m.serialize_entry("post", &self.post)?;
        m.end()
    }
}
