//! Protobuf messages of samples and jumps, and the descriptor set that
//! describes them, generated from a model's [`Layout`]: the binary encoding
//! of the MCAP log, which Foxglove decodes natively.
//!
//! The messages have the shapes of the JSON records ([`super::json`]), so a
//! number has the same message path in both encodings
//! (`/hybsim/state.xhat[1].data[0]`), and a message decoded to JSON with the
//! proto field names gives the JSON record:
//!
//! | layout | protobuf |
//! |---|---|
//! | scalar `h` | `double h` |
//! | vector `x` | `repeated double x` (packed) |
//! | matrix `P` | `Matrix P`, `Matrix = {uint32 rows = 1; uint32 cols = 2; repeated double data = 3}` (row-major) |
//! | family of scalars `z[i]` | `repeated double z` |
//! | family of vectors `xhat[i]` | `repeated Vector xhat`, `Vector = {repeated double data = 1}` |
//! | family of matrices or of mixed shapes | `repeated Matrix P` |
//! | family of records `agent` | `repeated T<k>_agent agent`, one message type with the members' fields |
//! | members of a subsystem instance `ball.h` | `T<k>_ball ball` |
//!
//! `State` and `Outputs` are `{double t = 1; uint64 j = 2; <entries from 3>}`;
//! `Jump` is `{double t = 1; uint64 j = 2; string rule = 3; uint32 rule_id = 4;
//! repeated int64 index = 5}`, and with the jump states (`jump_states` of
//! [`ProtoWriter::new`]) also `Values pre = 6; Values post = 7`, `Values`
//! the state's entries under the same field numbers as in `State`.
//!
//! The file is proto2 (proto3 refuses field names that differ only in case,
//! `P` and `p`, which a model may have), every repeated number packed.
//! Every field is written, zeros included, in field order, so a layout's
//! message body is a fixed sequence of bytes with holes for the numbers:
//! [`ProtoWriter`] compiles it once and then writes a record by copying
//! literal bytes and the values' little-endian bytes. (Hand-encoded rather
//! than through prost's generated types, which need the message types at
//! compile time; the descriptors are built with `prost-types`.)

use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{
    DescriptorProto, FieldDescriptorProto, FieldOptions, FileDescriptorProto, FileDescriptorSet,
};

use super::json::rule_indices;
use super::record_shape::{FamilyForm, Node, family_form, nest};
use crate::arc::HybridTime;
use crate::layout::{Entry, Field, Layout, Shape};

/// Wire types of the protobuf encoding.
const VARINT: u8 = 0;
const FIXED64: u8 = 1;
const LEN: u8 = 2;

/// First field number of a record's entries (1 and 2 are `t` and `j`).
const FIRST_ENTRY: u32 = 3;

fn put_varint(out: &mut Vec<u8>, v: u64) {
    prost::encoding::encode_varint(v, out);
}

fn put_key(out: &mut Vec<u8>, field: u32, wire: u8) {
    put_varint(out, (u64::from(field) << 3) | u64::from(wire));
}

/// Part of a message body: literal bytes, or `n` values from component `k`.
#[derive(Debug, Clone, PartialEq)]
enum Piece {
    Bytes(Vec<u8>),
    Values { k: usize, n: usize },
}

/// A message body under construction.
#[derive(Debug, Clone, Default, PartialEq)]
struct Body(Vec<Piece>);

impl Body {
    fn len(&self) -> usize {
        self.0
            .iter()
            .map(|p| match p {
                Piece::Bytes(b) => b.len(),
                Piece::Values { n, .. } => 8 * n,
            })
            .sum()
    }

    fn bytes(&mut self, b: &[u8]) {
        if let Some(Piece::Bytes(last)) = self.0.last_mut() {
            last.extend_from_slice(b);
        } else {
            self.0.push(Piece::Bytes(b.to_vec()));
        }
    }

    fn key(&mut self, field: u32, wire: u8) {
        let mut b = Vec::new();
        put_key(&mut b, field, wire);
        self.bytes(&b);
    }

    fn varint(&mut self, v: u64) {
        let mut b = Vec::new();
        put_varint(&mut b, v);
        self.bytes(&b);
    }

    /// `n` doubles from component `k`, merged with the previous values when
    /// the components continue them.
    fn values(&mut self, k: usize, n: usize) {
        if n == 0 {
            return;
        }
        if let Some(Piece::Values { k: k0, n: n0 }) = self.0.last_mut()
            && *k0 + *n0 == k
        {
            *n0 += n;
            return;
        }
        self.0.push(Piece::Values { k, n });
    }

    /// A length-delimited field holding `inner`.
    fn nested(&mut self, field: u32, inner: Body) {
        self.key(field, LEN);
        self.varint(inner.len() as u64);
        for p in inner.0 {
            match p {
                Piece::Bytes(b) => self.bytes(&b),
                Piece::Values { k, n } => self.values(k, n),
            }
        }
    }

    /// A packed `repeated double` of the given runs of components (omitted
    /// when empty, as protobuf writes an empty repeated field).
    fn packed(&mut self, field: u32, runs: &[(usize, usize)]) {
        let n: usize = runs.iter().map(|r| r.1).sum();
        if n == 0 {
            return;
        }
        self.key(field, LEN);
        self.varint(8 * n as u64);
        for &(k, n) in runs {
            self.values(k, n);
        }
    }
}

/// A compiled message body: literal bytes with holes for runs of values.
#[derive(Debug, Clone, Default, PartialEq)]
struct Template {
    /// A written body with zeros in the holes.
    image: Vec<u8>,
    /// Per run of values: its place in the body, the first component and
    /// the number of components.
    holes: Vec<(usize, usize, usize)>,
}

impl Template {
    fn new(body: &Body) -> Self {
        let mut t = Template::default();
        for p in &body.0 {
            match p {
                Piece::Bytes(b) => t.image.extend_from_slice(b),
                Piece::Values { k, n } => {
                    t.holes.push((t.image.len(), *k, *n));
                    t.image.resize(t.image.len() + 8 * n, 0);
                }
            }
        }
        t
    }

    /// Appends the body with the values of `x`: the image in one copy,
    /// then the values over its holes (rather than literal runs of a byte
    /// or two and numbers appended one by one: this runs per message).
    #[inline]
    fn write(&self, out: &mut Vec<u8>, x: &[f64]) {
        let start = out.len();
        out.extend_from_slice(&self.image);
        let body = &mut out[start..];
        for &(at, k, n) in &self.holes {
            let dst = &mut body[at..at + 8 * n];
            // Protobuf's doubles are little-endian, as in memory here: a
            // run of values is one copy.
            #[cfg(target_endian = "little")]
            dst.copy_from_slice(bytemuck::cast_slice(&x[k..k + n]));
            #[cfg(not(target_endian = "little"))]
            for (dst, v) in dst.chunks_exact_mut(8).zip(&x[k..k + n]) {
                dst.copy_from_slice(&v.to_le_bytes());
            }
        }
    }
}

fn scalar_field(name: &str, number: u32, label: Label, ty: Type) -> FieldDescriptorProto {
    let packed = label == Label::Repeated && ty != Type::Message && ty != Type::String;
    FieldDescriptorProto {
        name: Some(name.to_string()),
        number: Some(number as i32),
        label: Some(label as i32),
        r#type: Some(ty as i32),
        // The proto name, not its lowerCamelCase form, in JSON too.
        json_name: Some(name.to_string()),
        options: packed.then(|| FieldOptions {
            packed: Some(true),
            ..FieldOptions::default()
        }),
        ..FieldDescriptorProto::default()
    }
}

fn message_field(name: &str, number: u32, label: Label, type_name: &str) -> FieldDescriptorProto {
    FieldDescriptorProto {
        type_name: Some(type_name.to_string()),
        ..scalar_field(name, number, label, Type::Message)
    }
}

/// Builds the message types of one file (package `package`) and the bodies
/// of their records together, so the two cannot disagree.
struct Builder {
    package: String,
    /// Message types of the file.
    types: Vec<DescriptorProto>,
}

impl Builder {
    fn full(&self, name: &str) -> String {
        format!(".{}.{name}", self.package)
    }

    /// Registers a message type with a name unique in the file.
    fn add_type(&mut self, hint: &str, fields: Vec<FieldDescriptorProto>) -> String {
        let name = format!("T{}_{hint}", self.types.len() + 1);
        self.types.push(DescriptorProto {
            name: Some(name.clone()),
            field: fields,
            ..DescriptorProto::default()
        });
        self.full(&name)
    }

    /// The body of a matrix message and its type name.
    fn matrix(&mut self, rows: usize, cols: usize, k: usize) -> (Body, String) {
        let mut b = Body::default();
        b.key(1, VARINT);
        b.varint(rows as u64);
        b.key(2, VARINT);
        b.varint(cols as u64);
        b.packed(3, &[(k, rows * cols)]);
        (b, self.full("Matrix"))
    }

    /// One field of a record: its descriptor, appended to `fields`, and its bytes.
    fn field(
        &mut self,
        body: &mut Body,
        fields: &mut Vec<FieldDescriptorProto>,
        number: u32,
        name: &str,
        f: &Field,
    ) {
        match f.shape {
            Shape::Scalar => {
                fields.push(scalar_field(name, number, Label::Optional, Type::Double));
                body.key(number, FIXED64);
                body.values(f.offset, 1);
            }
            Shape::Vector(n) => {
                fields.push(scalar_field(name, number, Label::Repeated, Type::Double));
                body.packed(number, &[(f.offset, n)]);
            }
            Shape::Matrix { rows, cols } => {
                let (inner, ty) = self.matrix(rows, cols, f.offset);
                fields.push(message_field(name, number, Label::Optional, &ty));
                body.nested(number, inner);
            }
        }
    }

    /// The entries of `nodes` as fields numbered from `first`.
    fn nodes(&mut self, nodes: &[Node<'_>], first: u32) -> (Body, Vec<FieldDescriptorProto>) {
        let mut body = Body::default();
        let mut fields = Vec::new();
        for (number, node) in (first..).zip(nodes) {
            match node {
                Node::Leaf(Entry::Field(f), shown) => {
                    self.field(&mut body, &mut fields, number, shown, f);
                }
                Node::Leaf(Entry::Family { members, .. }, shown) => {
                    self.family(&mut body, &mut fields, number, shown, members);
                }
                Node::Group(name, inner) => {
                    let (inner_body, inner_fields) = self.nodes(inner, 1);
                    let ty = self.add_type(name, inner_fields);
                    fields.push(message_field(name, number, Label::Optional, &ty));
                    body.nested(number, inner_body);
                }
            }
        }
        (body, fields)
    }

    fn family(
        &mut self,
        body: &mut Body,
        fields: &mut Vec<FieldDescriptorProto>,
        number: u32,
        name: &str,
        members: &[Vec<Field>],
    ) {
        match family_form(members) {
            FamilyForm::Numbers => {
                fields.push(scalar_field(name, number, Label::Repeated, Type::Double));
                let runs: Vec<(usize, usize)> = members.iter().map(|m| (m[0].offset, 1)).collect();
                body.packed(number, &runs);
            }
            FamilyForm::Vectors(_) => {
                fields.push(message_field(
                    name,
                    number,
                    Label::Repeated,
                    &self.full("Vector"),
                ));
                for m in members {
                    let mut inner = Body::default();
                    inner.packed(1, &[(m[0].offset, m[0].shape.len())]);
                    body.nested(number, inner);
                }
            }
            FamilyForm::Matrices => {
                let mut ty = String::new();
                for m in members {
                    let f = &m[0];
                    let (rows, cols) = match f.shape {
                        Shape::Scalar => (1, 1),
                        Shape::Vector(n) => (n, 1),
                        Shape::Matrix { rows, cols } => (rows, cols),
                    };
                    let (inner, t) = self.matrix(rows, cols, f.offset);
                    ty = t;
                    body.nested(number, inner);
                }
                fields.push(message_field(name, number, Label::Repeated, &ty));
            }
            FamilyForm::Records => {
                // All members have the same fields: one message type.
                let mut member_fields = Vec::new();
                for (k, m) in members.iter().enumerate() {
                    let mut inner = Body::default();
                    let mut descs = Vec::new();
                    for (number, f) in (1..).zip(m) {
                        let shown = if f.name.is_empty() {
                            "value"
                        } else {
                            f.name.as_str()
                        };
                        self.field(&mut inner, &mut descs, number, shown, f);
                    }
                    if k == 0 {
                        member_fields = descs;
                    }
                    body.nested(number, inner);
                }
                let ty = self.add_type(name, member_fields);
                fields.push(message_field(name, number, Label::Repeated, &ty));
            }
        }
    }
}

/// A protobuf package name for a model: its name's identifier characters.
fn package_name(model: &str) -> String {
    let mut name: String = model
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if !name.starts_with(|c: char| c.is_ascii_alphabetic() || c == '_') {
        name.insert(0, '_');
    }
    format!("hybsim.{name}")
}

/// The schemas of a run's protobuf messages: one descriptor set holding the
/// file of its message types, and their full names.
#[derive(Debug, Clone, PartialEq)]
pub struct ProtoSchemas {
    /// A serialized `google.protobuf.FileDescriptorSet` (the schema data
    /// of every protobuf channel).
    pub descriptor_set: Vec<u8>,
    /// Full name of the state sample message (`hybsim.<model>.State`).
    pub state: String,
    /// Full name of the output sample message.
    pub outputs: String,
    /// Full name of the jump message.
    pub jump: String,
}

/// Writes the protobuf records of one run, as [`super::json::RecordWriter`]
/// writes the JSON ones.
///
/// ```
/// use hybsim::arc::HybridTime;
/// use hybsim::layout::Layout;
/// use hybsim::sinks::protobuf::ProtoWriter;
/// let layout = Layout::scalars(&["h", "v"]);
/// let (writer, schemas) = ProtoWriter::new("ball", &layout, &Layout::default(), &["bounce".into()], false);
/// let mut out = Vec::new();
/// writer.sample(&mut out, HybridTime::new(0.5, 2), &[3.0, -1.5]);
/// let json = hybsim::sinks::protobuf::to_json(&schemas.descriptor_set, &schemas.state, &out).unwrap();
/// assert_eq!(json, serde_json::json!({"t": 0.5, "j": 2, "h": 3.0, "v": -1.5}));
/// ```
#[derive(Debug, Clone)]
pub struct ProtoWriter {
    state: Template,
    outputs: Template,
    /// Per rule: `rule`, `rule_id` and `index` fields.
    rule_heads: Vec<Vec<u8>>,
    /// Whether jump records carry `pre` and `post`.
    jump_states: bool,
}

impl ProtoWriter {
    /// The writer and the schemas of the records of a model named `model`
    /// with the given state and output layouts and jump rules; jump records
    /// carry the pre- and post-jump states when `jump_states`.
    pub fn new(
        model: &str,
        state: &Layout,
        outputs: &Layout,
        rule_names: &[String],
        jump_states: bool,
    ) -> (Self, ProtoSchemas) {
        let package = package_name(model);
        let mut b = Builder {
            package: package.clone(),
            types: Vec::new(),
        };
        let (state_body, state_fields) = b.nodes(&nest(&state.entries), FIRST_ENTRY);
        let (outputs_body, outputs_fields) = b.nodes(&nest(&outputs.entries), FIRST_ENTRY);
        let time = || {
            vec![
                scalar_field("t", 1, Label::Optional, Type::Double),
                scalar_field("j", 2, Label::Optional, Type::Uint64),
            ]
        };
        let record = |name: &str, fields: Vec<FieldDescriptorProto>| DescriptorProto {
            name: Some(name.to_string()),
            field: fields,
            ..DescriptorProto::default()
        };
        let mut jump = [
            time(),
            vec![
                scalar_field("rule", 3, Label::Optional, Type::String),
                scalar_field("rule_id", 4, Label::Optional, Type::Uint32),
                scalar_field("index", 5, Label::Repeated, Type::Int64),
            ],
        ]
        .concat();
        let mut types = vec![
            record("State", [time(), state_fields.clone()].concat()),
            record("Outputs", [time(), outputs_fields].concat()),
        ];
        if jump_states {
            let values = format!(".{package}.Values");
            jump.push(message_field("pre", 6, Label::Optional, &values));
            jump.push(message_field("post", 7, Label::Optional, &values));
            types.push(record("Values", state_fields));
        }
        types.insert(2, record("Jump", jump));
        // Declared whether used or not: every model's file has them.
        types.push(record(
            "Matrix",
            vec![
                scalar_field("rows", 1, Label::Optional, Type::Uint32),
                scalar_field("cols", 2, Label::Optional, Type::Uint32),
                scalar_field("data", 3, Label::Repeated, Type::Double),
            ],
        ));
        types.push(record(
            "Vector",
            vec![scalar_field("data", 1, Label::Repeated, Type::Double)],
        ));
        types.extend(b.types);
        let file = FileDescriptorProto {
            name: Some(format!("{}.proto", package.replace('.', "/"))),
            package: Some(package.clone()),
            message_type: types,
            // proto2: proto3 refuses fields whose names differ only in case
            // (`P` and `p`), which models may have.
            syntax: Some("proto2".into()),
            ..FileDescriptorProto::default()
        };
        let set = FileDescriptorSet { file: vec![file] };
        let schemas = ProtoSchemas {
            descriptor_set: set.encode_to_vec(),
            state: format!("{package}.State"),
            outputs: format!("{package}.Outputs"),
            jump: format!("{package}.Jump"),
        };
        let writer = Self {
            state: Template::new(&state_body),
            outputs: Template::new(&outputs_body),
            rule_heads: (0..rule_names.len())
                .map(|k| rule_head(&super::rule_name(rule_names, k), k))
                .collect(),
            jump_states,
        };
        (writer, schemas)
    }

    /// Appends the `t` and `j` fields, at once (this runs per message).
    fn time(out: &mut Vec<u8>, at: HybridTime) {
        // Keys of one byte (fields 1 and 2), a double, a varint of at most
        // 10 bytes.
        let mut b = [0u8; 20];
        b[0] = (1 << 3) | FIXED64;
        b[1..9].copy_from_slice(&at.t.to_le_bytes());
        b[9] = (2 << 3) | VARINT;
        let mut n = 10;
        let mut j = at.j;
        while j >= 0x80 {
            b[n] = (j as u8) | 0x80;
            j >>= 7;
            n += 1;
        }
        b[n] = j as u8;
        out.extend_from_slice(&b[..=n]);
    }

    /// Appends the `State` record of `x` at `at`.
    pub fn sample(&self, out: &mut Vec<u8>, at: HybridTime, x: &[f64]) {
        Self::time(out, at);
        self.state.write(out, x);
    }

    /// Appends the `Outputs` record of `y` at `at`.
    pub fn outputs(&self, out: &mut Vec<u8>, at: HybridTime, y: &[f64]) {
        Self::time(out, at);
        self.outputs.write(out, y);
    }

    /// Appends the `Jump` record of rule `rule` (named `name` if the writer
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
            for (field, x) in [(6, pre), (7, post)] {
                put_key(out, field, LEN);
                put_varint(out, self.state.image.len() as u64);
                self.state.write(out, x);
            }
        }
    }
}

/// The `rule`, `rule_id` and `index` fields of a jump record.
fn rule_head(name: &str, rule: usize) -> Vec<u8> {
    let mut head = Vec::new();
    put_key(&mut head, 3, LEN);
    put_varint(&mut head, name.len() as u64);
    head.extend_from_slice(name.as_bytes());
    put_key(&mut head, 4, VARINT);
    put_varint(&mut head, rule as u64);
    if let Some(index) = rule_indices(name).filter(|i| !i.is_empty()) {
        let mut packed = Vec::new();
        for i in index {
            // int64: two's complement as a 64-bit varint.
            put_varint(&mut packed, i as u64);
        }
        put_key(&mut head, 5, LEN);
        put_varint(&mut head, packed.len() as u64);
        head.extend_from_slice(&packed);
    }
    head
}

/// Decodes a protobuf message of the type `message` described by the
/// descriptor set `schema` into JSON, with the proto field names, every
/// field written (zeros and empty lists included) and 64-bit integers as
/// numbers: for hybsim's messages, the JSON record of the same sample.
pub fn to_json(schema: &[u8], message: &str, data: &[u8]) -> Result<serde_json::Value, String> {
    Decoder::new(schema, message)?.to_json(data)
}

/// Decodes the messages of one protobuf schema to JSON (see [`to_json`]).
#[derive(Debug, Clone)]
pub struct Decoder {
    desc: prost_reflect::MessageDescriptor,
}

impl Decoder {
    /// The decoder of messages of type `message` in the descriptor set `schema`.
    pub fn new(schema: &[u8], message: &str) -> Result<Self, String> {
        let pool = prost_reflect::DescriptorPool::decode(schema)
            .map_err(|e| format!("the protobuf schema does not decode: {e}"))?;
        let desc = pool
            .get_message_by_name(message)
            .ok_or_else(|| format!("the protobuf schema has no message `{message}`"))?;
        Ok(Self { desc })
    }

    /// One message as JSON.
    pub fn to_json(&self, data: &[u8]) -> Result<serde_json::Value, String> {
        let message = prost_reflect::DynamicMessage::decode(self.desc.clone(), data)
            .map_err(|e| format!("a `{}` message does not decode: {e}", self.desc.full_name()))?;
        let options = prost_reflect::SerializeOptions::new()
            .use_proto_field_name(true)
            .skip_default_fields(false)
            .stringify_64_bit_integers(false);
        message
            .serialize_with_options(serde_json::value::Serializer, &options)
            .map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sinks::json::RecordWriter;

    /// A layout with every shape: scalar, vector, matrix, families of each
    /// form, a subsystem instance, and an empty vector.
    fn every_shape() -> (Layout, usize) {
        let f = |name: &str, shape, offset| Field {
            name: name.into(),
            shape,
            offset,
        };
        let entries = vec![
            Entry::Field(f("h", Shape::Scalar, 0)),
            Entry::Field(f("x", Shape::Vector(2), 1)),
            Entry::Field(f("P", Shape::Matrix { rows: 2, cols: 2 }, 3)),
            Entry::Family {
                name: "z".into(),
                labels: vec!["1".into(), "2".into()],
                members: vec![vec![f("", Shape::Scalar, 7)], vec![f("", Shape::Scalar, 8)]],
            },
            Entry::Family {
                name: "xhat".into(),
                labels: vec!["1".into(), "2".into()],
                members: vec![
                    vec![f("", Shape::Vector(2), 9)],
                    vec![f("", Shape::Vector(2), 11)],
                ],
            },
            Entry::Family {
                name: "mixed".into(),
                labels: vec!["1".into(), "2".into()],
                members: vec![
                    vec![f("", Shape::Scalar, 13)],
                    vec![f("", Shape::Matrix { rows: 1, cols: 2 }, 14)],
                ],
            },
            Entry::Family {
                name: "agent".into(),
                labels: vec!["a".into(), "b".into()],
                members: vec![
                    vec![f("p", Shape::Scalar, 16), f("q", Shape::Vector(2), 17)],
                    vec![f("p", Shape::Scalar, 19), f("q", Shape::Vector(2), 20)],
                ],
            },
            Entry::Field(f("ball.h", Shape::Scalar, 22)),
            Entry::Field(f("ball.v", Shape::Scalar, 23)),
            Entry::Field(f("empty", Shape::Vector(0), 24)),
        ];
        (Layout { entries }, 24)
    }

    /// Every shape decodes (through the descriptors, by prost-reflect) to
    /// exactly the JSON record of the same values.
    #[test]
    fn messages_decode_to_the_json_records() {
        let (layout, dim) = every_shape();
        let rules = vec!["hit".to_string(), "transmit[2,3]".to_string()];
        let (w, schemas) = ProtoWriter::new("every-shape", &layout, &layout, &rules, false);
        let json = RecordWriter::new(&layout, &rules);
        let x: Vec<f64> = (0..dim).map(|k| (k as f64 - 3.5) * 0.37).collect();
        let post: Vec<f64> = x.iter().map(|v| -v).collect();
        let at = HybridTime::new(0.25, 300);

        let mut out = Vec::new();
        w.sample(&mut out, at, &x);
        let decoded = to_json(&schemas.descriptor_set, &schemas.state, &out).unwrap();
        let mut text = Vec::new();
        json.sample(&mut text, at, &x);
        let expected: serde_json::Value = serde_json::from_slice(&text).unwrap();
        assert_eq!(decoded, expected);

        out.clear();
        w.outputs(&mut out, at, &x);
        assert_eq!(
            to_json(&schemas.descriptor_set, &schemas.outputs, &out).unwrap(),
            decoded
        );

        // The pre-jump state is the sample's record without its time.
        let mut values = decoded.clone();
        let fields = values.as_object_mut().unwrap();
        fields.remove("t");
        fields.remove("j");
        for jump_states in [false, true] {
            let (w, schemas) =
                ProtoWriter::new("every-shape", &layout, &layout, &rules, jump_states);
            let json = RecordWriter::new(&layout, &rules).with_jump_states(jump_states);
            for (rule, index) in [(0, serde_json::json!([])), (1, serde_json::json!([2, 3]))] {
                out.clear();
                w.jump(&mut out, at, rule, "", &x, &post);
                let decoded = to_json(&schemas.descriptor_set, &schemas.jump, &out).unwrap();
                text.clear();
                json.jump(&mut text, at, rule, "", &x, &post);
                let mut expected: serde_json::Value = serde_json::from_slice(&text).unwrap();
                // JSON leaves out the index of a plain rule; protobuf writes every field.
                expected["index"] = index;
                assert_eq!(decoded, expected, "rule {rule}");
                assert_eq!(decoded.get("pre").is_some(), jump_states);
                if jump_states {
                    assert_eq!(decoded["pre"], values);
                }
            }
        }
        assert_eq!(schemas.state, "hybsim.every_shape.State");
    }
}
