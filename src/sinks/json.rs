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

use serde::Serialize;
use serde_json::{Value, json};

use super::record_shape::{FamilyForm, Node, family_form, nest};
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

/// Schema of a jump record `{t, j, rule, rule_id, index?}`, with
/// `pre{..}, post{..}` (the states of `layout` just before and after) when
/// `jump_states`; `t, j` are the pre-jump hybrid time.
pub fn jump_schema(title: &str, layout: &Layout, jump_states: bool) -> Value {
    let mut props = serde_json::Map::new();
    let mut required = vec!["rule".to_string(), "rule_id".into()];
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
    if jump_states {
        let (state_props, state_required) = layout_properties(layout);
        let state =
            json!({"type": "object", "properties": state_props, "required": state_required});
        let mut pre = state.clone();
        pre["description"] = json!("state just before the jump, at (t, j)");
        let mut post = state;
        post["description"] = json!("state just after the jump, at (t, j + 1)");
        props.insert("pre".into(), pre);
        props.insert("post".into(), post);
        required.extend(["pre".into(), "post".into()]);
    }
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

/// Appends the shortest text that reads back as exactly `v` (JSON's number
/// syntax for finite values: `0.1`, `1e-7`, `2.220446049250313e-16`).
/// Callers check finiteness first; this is what `serde_json` writes.
#[inline]
pub fn push_f64(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(zmij::Buffer::new().format_finite(v).as_bytes());
}

/// Appends an unsigned integer in decimal.
#[inline]
pub fn push_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(itoa::Buffer::new().format(v).as_bytes());
}

/// The JSON text of the values of a flat vector structured by a [`Layout`],
/// compiled once per layout: literal text with holes for the numbers. Writing
/// a record is then copying the literals and formatting the numbers, with no
/// intermediate value and no per-record allocation (a run writes one record
/// per sample; the layouts never change during a run).
///
/// The text is an object body without braces, `"h":1.5,"x":[1,2]`, in the
/// shapes of the module documentation.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Template {
    /// All literal text, concatenated.
    lits: Vec<u8>,
    /// Per hole: the end of the literal text before it, and the component.
    holes: Vec<(usize, usize)>,
}

impl Template {
    /// The body of the values of `layout` (no braces, no leading comma);
    /// dotted names (`ball.h`) nest as objects, as in the schemas.
    pub fn new(layout: &Layout) -> Self {
        let mut t = Self::default();
        t.nodes(&nest(&layout.entries));
        t
    }

    fn nodes(&mut self, nodes: &[Node<'_>]) {
        for (k, node) in nodes.iter().enumerate() {
            if k > 0 {
                self.lit(",");
            }
            match node {
                Node::Leaf(Entry::Field(f), shown) => {
                    self.key(shown);
                    self.field(f);
                }
                Node::Leaf(Entry::Family { members, .. }, shown) => {
                    self.key(shown);
                    self.family(members);
                }
                Node::Group(name, inner) => {
                    self.key(name);
                    self.lit("{");
                    self.nodes(inner);
                    self.lit("}");
                }
            }
        }
    }

    /// True if the layout has no entries (the body is empty).
    pub fn is_empty(&self) -> bool {
        self.lits.is_empty() && self.holes.is_empty()
    }

    /// Appends the body with the values of `x` (finite, checked by the caller).
    #[inline]
    pub fn write(&self, out: &mut Vec<u8>, x: &[f64]) {
        let mut start = 0;
        for &(end, k) in &self.holes {
            out.extend_from_slice(&self.lits[start..end]);
            push_f64(out, x[k]);
            start = end;
        }
        out.extend_from_slice(&self.lits[start..]);
    }

    fn lit(&mut self, s: &str) {
        self.lits.extend_from_slice(s.as_bytes());
    }

    fn key(&mut self, name: &str) {
        let quoted = serde_json::to_string(name).expect("a string serializes");
        self.lit(&quoted);
        self.lit(":");
    }

    fn hole(&mut self, k: usize) {
        self.holes.push((self.lits.len(), k));
    }

    fn numbers(&mut self, offset: usize, n: usize) {
        self.lit("[");
        for k in 0..n {
            if k > 0 {
                self.lit(",");
            }
            self.hole(offset + k);
        }
        self.lit("]");
    }

    fn matrix(&mut self, rows: usize, cols: usize, offset: usize) {
        self.lit(&format!("{{\"rows\":{rows},\"cols\":{cols},\"data\":"));
        self.numbers(offset, rows * cols);
        self.lit("}");
    }

    /// A number, an array or a matrix object.
    fn field(&mut self, f: &Field) {
        match f.shape {
            Shape::Scalar => self.hole(f.offset),
            Shape::Vector(n) => self.numbers(f.offset, n),
            Shape::Matrix { rows, cols } => self.matrix(rows, cols, f.offset),
        }
    }

    fn family(&mut self, members: &[Vec<Field>]) {
        let form = family_form(members);
        self.lit("[");
        for (k, fields) in members.iter().enumerate() {
            if k > 0 {
                self.lit(",");
            }
            match (form, fields.as_slice()) {
                (FamilyForm::Numbers, [f]) => self.field(f),
                (FamilyForm::Vectors(_), [f]) => {
                    self.lit("{\"data\":");
                    self.numbers(f.offset, f.shape.len());
                    self.lit("}");
                }
                (FamilyForm::Matrices, [f]) => {
                    let (rows, cols) = match f.shape {
                        Shape::Scalar => (1, 1),
                        Shape::Vector(n) => (n, 1),
                        Shape::Matrix { rows, cols } => (rows, cols),
                    };
                    self.matrix(rows, cols, f.offset);
                }
                _ => {
                    self.lit("{");
                    for (i, f) in fields.iter().enumerate() {
                        if i > 0 {
                            self.lit(",");
                        }
                        self.key(&f.name);
                        self.field(f);
                    }
                    self.lit("}");
                }
            }
        }
        self.lit("]");
    }
}

/// Reads the values of sample records of one layout back into a flat
/// vector: the inverse of [`Template::write`] (and of
/// [`RecordWriter::sample`]), for JSON of any spacing and key order.
///
/// Where each component sits is learnt from the template itself: its
/// record written with component k replaced by −(k + 1) (the template's
/// own literal numbers, the `rows` and `cols` of matrices, are never
/// negative), so the reader follows the writer's shapes without a second
/// description of them.
///
/// ```
/// use hybsim::layout::Layout;
/// use hybsim::sinks::json::RecordReader;
/// let layout = Layout::scalars(&["h", "v"]);
/// let record = serde_json::json!({"t": 0.5, "j": 2, "v": -1.5, "h": 3.0});
/// let mut x = [0.0; 2];
/// RecordReader::new(&layout, 2).read(&record, &mut x).unwrap();
/// assert_eq!(x, [3.0, -1.5]);
/// ```
#[derive(Debug, Clone)]
pub struct RecordReader {
    probe: Value,
}

impl RecordReader {
    /// A reader of records of `layout` over vectors of dimension `dim`.
    pub fn new(layout: &Layout, dim: usize) -> Self {
        let marks: Vec<f64> = (0..dim).map(|k| -((k + 1) as f64)).collect();
        let mut text = b"{".to_vec();
        Template::new(layout).write(&mut text, &marks);
        text.push(b'}');
        let probe = serde_json::from_slice(&text).expect("a template writes valid JSON");
        Self { probe }
    }

    /// Writes the values of `record` (an object with the layout's entries;
    /// other keys such as `t` and `j` are ignored) into `x`; components the
    /// layout does not cover are left as they are. The error names the
    /// first entry that is missing, of another shape or not a number.
    pub fn read(&self, record: &Value, x: &mut [f64]) -> Result<(), String> {
        fill(&self.probe, record, x, &mut String::new())
    }
}

fn fill(probe: &Value, value: &Value, x: &mut [f64], path: &mut String) -> Result<(), String> {
    let shown = |path: &str| {
        if path.is_empty() {
            "the record".to_string()
        } else {
            format!("`{path}`")
        }
    };
    match probe {
        Value::Number(n) => {
            let mark = n.as_f64().expect("probe numbers are finite");
            let v = value
                .as_f64()
                .ok_or_else(|| format!("{} is not a number", shown(path)))?;
            if mark < 0.0 {
                let k = (-mark) as usize - 1;
                if let Some(slot) = x.get_mut(k) {
                    *slot = v;
                }
            } else if v != mark {
                return Err(format!("{} is {v}, expected {mark}", shown(path)));
            }
            Ok(())
        }
        Value::Array(items) => {
            let values = value
                .as_array()
                .filter(|a| a.len() == items.len())
                .ok_or_else(|| format!("{} is not an array of {}", shown(path), items.len()))?;
            let len = path.len();
            for (k, (p, v)) in items.iter().zip(values).enumerate() {
                path.push_str(&format!("[{k}]"));
                fill(p, v, x, path)?;
                path.truncate(len);
            }
            Ok(())
        }
        Value::Object(fields) => {
            let object = value
                .as_object()
                .ok_or_else(|| format!("{} is not an object", shown(path)))?;
            let len = path.len();
            for (key, p) in fields {
                if len > 0 {
                    path.push('.');
                }
                path.push_str(key);
                let v = object
                    .get(key)
                    .ok_or_else(|| format!("{} is missing", shown(path)))?;
                fill(p, v, x, path)?;
                path.truncate(len);
            }
            Ok(())
        }
        // A template writes only numbers, arrays and objects.
        _ => Ok(()),
    }
}

/// Writes the records of one run: sample records `{t, j, <values>}` and jump
/// records `{t, j, rule, rule_id, index?}` (with `pre{..}, post{..}` when
/// [`with_jump_states`](Self::with_jump_states)), as compact JSON into a
/// caller's buffer.
#[derive(Debug, Clone)]
pub struct RecordWriter {
    body: Template,
    /// Per rule: `,"rule":"NAME","rule_id":K[,"index":[..]]`.
    rule_heads: Vec<Vec<u8>>,
    jump_states: bool,
}

impl RecordWriter {
    /// Records of vectors structured by `layout`, jumps of the rules named
    /// `rule_names` (in the system's order), without their states.
    pub fn new(layout: &Layout, rule_names: &[String]) -> Self {
        Self {
            body: Template::new(layout),
            rule_heads: (0..rule_names.len())
                .map(|k| rule_head(&super::rule_name(rule_names, k), k))
                .collect(),
            jump_states: false,
        }
    }

    /// Whether jump records carry the pre- and post-jump states (as
    /// [`jump_schema`] with the same flag describes them).
    pub fn with_jump_states(self, jump_states: bool) -> Self {
        Self {
            jump_states,
            ..self
        }
    }

    fn time(out: &mut Vec<u8>, at: HybridTime) {
        out.extend_from_slice(b"{\"t\":");
        push_f64(out, at.t);
        out.extend_from_slice(b",\"j\":");
        push_u64(out, at.j);
    }

    /// Appends the sample record of `x` at `at`.
    pub fn sample(&self, out: &mut Vec<u8>, at: HybridTime, x: &[f64]) {
        Self::time(out, at);
        if !self.body.is_empty() {
            out.push(b',');
        }
        self.body.write(out, x);
        out.push(b'}');
    }

    /// Appends the jump record of rule `rule` (named `name` if the writer
    /// does not know it) at the pre-jump time `at`.
    pub fn jump(
        &self,
        out: &mut Vec<u8>,
        at: HybridTime,
        rule: usize,
        name: &str,
        pre: &[f64],
        post: &[f64],
    ) {
        Self::time(out, at);
        match self.rule_heads.get(rule) {
            Some(head) => out.extend_from_slice(head),
            None => out.extend_from_slice(&rule_head(name, rule)),
        }
        if self.jump_states {
            out.extend_from_slice(b",\"pre\":{");
            self.body.write(out, pre);
            out.extend_from_slice(b"},\"post\":{");
            self.body.write(out, post);
            out.push(b'}');
        }
        out.push(b'}');
    }
}

fn rule_head(name: &str, rule: usize) -> Vec<u8> {
    let mut head = b",\"rule\":".to_vec();
    serde_json::to_writer(&mut head, name).expect("a string serializes");
    head.extend_from_slice(b",\"rule_id\":");
    push_u64(&mut head, rule as u64);
    if let Some(index) = rule_indices(name) {
        head.extend_from_slice(b",\"index\":");
        serde_json::to_writer(&mut head, &index).expect("integers serialize");
    }
    head
}
