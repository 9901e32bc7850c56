//! The rules a JSON Schema must obey for Foxglove (and its fork Lichtblick)
//! to decode the messages of a `jsonschema`/`json` channel, and a checker
//! that reports every violation.
//!
//! Foxglove's JSON Schema parser (`parseJsonSchema` in the Foxglove and
//! Lichtblick code bases) turns a schema into message definitions; it
//! rejects a channel as a whole when any field falls outside what it
//! understands. The rules, as documented by its error messages and
//! behaviour:
//!
//! 1. The root, and every nested record, is `"type": "object"`; a record's
//!    fields are its `properties`.
//! 2. Every field has exactly one `type`, a string among `boolean`,
//!    `string`, `number`, `integer`, `object`, `array` (a list of types
//!    such as `["number", "null"]` is a union and is rejected; so is a
//!    field without `type`, e.g. a bare `$ref`).
//! 3. `$ref`, `anyOf`, `allOf` and `not` are not resolved; `oneOf` is only
//!    understood as an enumeration whose alternatives all carry a numeric
//!    `const`.
//! 4. An `array` has an `items` schema (one schema, not a list) whose type
//!    is a primitive or `object`: **no arrays of arrays** (`Unsupported array
//!    item type: "array"`).
//! 5. A `string` has no `contentEncoding` other than `base64`.
//!
//! One rule comes from message paths rather than the parser: a field name
//! that is not an identifier (`[A-Za-z_][A-Za-z0-9_]*`) can only be reached
//! with a quoted path segment, which older Foxglove versions and many
//! panels do not support; the checker reports such names too.

use serde_json::Value;

/// One violation: where in the schema (`properties.agent.items`) and what.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaIssue {
    /// JSON path of the offending schema node, from the root.
    pub path: String,
    /// What is wrong.
    pub problem: String,
}

impl std::fmt::Display for SchemaIssue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path, self.problem)
    }
}

/// Checks a schema against the rules above; `Ok` if Foxglove decodes its
/// messages and reaches every field with an unquoted message path.
pub fn check_schema(schema: &Value) -> Result<(), Vec<SchemaIssue>> {
    let mut issues = Vec::new();
    let root = "$".to_string();
    match schema.get("type") {
        Some(Value::String(t)) if t == "object" => check_object(schema, &root, &mut issues),
        _ => issues.push(SchemaIssue {
            path: root,
            problem: "the root schema must be `\"type\": \"object\"`".into(),
        }),
    }
    if issues.is_empty() {
        Ok(())
    } else {
        Err(issues)
    }
}

/// Whether a field name is reachable by an unquoted message path segment.
pub fn is_path_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

fn push(issues: &mut Vec<SchemaIssue>, path: &str, problem: impl Into<String>) {
    issues.push(SchemaIssue {
        path: path.to_string(),
        problem: problem.into(),
    });
}

/// Keywords the parser does not resolve, anywhere in a node.
fn check_unsupported_keywords(node: &Value, path: &str, issues: &mut Vec<SchemaIssue>) {
    for key in ["$ref", "anyOf", "allOf", "not", "if", "patternProperties"] {
        if node.get(key).is_some() {
            push(issues, path, format!("`{key}` is not supported"));
        }
    }
}

fn check_object(node: &Value, path: &str, issues: &mut Vec<SchemaIssue>) {
    check_unsupported_keywords(node, path, issues);
    let Some(props) = node.get("properties") else {
        return;
    };
    let Some(props) = props.as_object() else {
        push(issues, path, "`properties` must be an object");
        return;
    };
    for (name, field) in props {
        let field_path = format!("{path}.properties.{name}");
        if !is_path_identifier(name) {
            push(
                issues,
                &field_path,
                format!("field name `{name}` is not an identifier; message paths must quote it"),
            );
        }
        check_field(field, &field_path, issues);
    }
}

fn check_field(field: &Value, path: &str, issues: &mut Vec<SchemaIssue>) {
    check_unsupported_keywords(field, path, issues);
    if let Some(alternatives) = field.get("oneOf") {
        let numeric_enum = alternatives.as_array().is_some_and(|a| {
            a.iter()
                .all(|alt| alt.get("const").is_some_and(Value::is_number))
        });
        if !numeric_enum {
            push(
                issues,
                path,
                "`oneOf` is only supported with numeric `const` alternatives (an enumeration)",
            );
        }
        return;
    }
    let t = match field.get("type") {
        Some(Value::String(t)) => t.as_str(),
        Some(Value::Array(_)) => {
            push(
                issues,
                path,
                "a list of types is a union, which is not supported",
            );
            return;
        }
        Some(other) => {
            push(
                issues,
                path,
                format!("`type` must be a string, got {other}"),
            );
            return;
        }
        None => {
            push(issues, path, "field without `type`");
            return;
        }
    };
    match t {
        "boolean" | "number" | "integer" => {}
        "string" => match field.get("contentEncoding") {
            None => {}
            Some(Value::String(e)) if e == "base64" => {}
            Some(e) => push(issues, path, format!("unsupported `contentEncoding` {e}")),
        },
        "object" => check_object(field, path, issues),
        "array" => {
            let items_path = format!("{path}.items");
            let Some(items) = field.get("items") else {
                push(issues, path, "array without `items`");
                return;
            };
            if !items.is_object() {
                push(issues, &items_path, "`items` must be one schema");
                return;
            }
            check_unsupported_keywords(items, &items_path, issues);
            match items.get("type") {
                Some(Value::String(it)) => match it.as_str() {
                    "boolean" | "string" | "number" | "integer" => {}
                    "object" => check_object(items, &items_path, issues),
                    "array" => push(
                        issues,
                        &items_path,
                        "arrays of arrays are not supported (Unsupported array item type: \"array\")",
                    ),
                    other => push(
                        issues,
                        &items_path,
                        format!("unsupported item type `{other}`"),
                    ),
                },
                Some(Value::Array(_)) => push(
                    issues,
                    &items_path,
                    "a list of item types is a union, which is not supported",
                ),
                _ => push(issues, &items_path, "array items without a `type`"),
            }
        }
        other => push(issues, path, format!("unsupported type `{other}`")),
    }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn problems(schema: Value) -> Vec<String> {
        check_schema(&schema)
            .err()
            .unwrap_or_default()
            .into_iter()
            .map(|i| i.to_string())
            .collect()
    }

    #[test]
    fn accepts_what_foxglove_decodes() {
        let ok = json!({
            "type": "object",
            "properties": {
                "t": {"type": "number"},
                "name": {"type": "string"},
                "blob": {"type": "string", "contentEncoding": "base64"},
                "mode": {"oneOf": [{"const": 0}, {"const": 1}]},
                "x": {"type": "array", "items": {"type": "number"}},
                "agent": {"type": "array", "items": {"type": "object", "properties": {
                    "xhat": {"type": "array", "items": {"type": "number"}}}}},
                "P": {"type": "object", "properties": {"data": {"type": "array", "items": {"type": "number"}}}}
            }
        });
        assert!(problems(ok).is_empty());
    }

    #[test]
    fn rejects_each_rule_with_its_place() {
        let bad = json!({
            "type": "object",
            "properties": {
                "xhat": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
                "e[1]": {"type": "number"},
                "u": {"type": ["number", "null"]},
                "r": {"$ref": "#/$defs/R"},
                "o": {"oneOf": [{"type": "number"}, {"type": "string"}]},
                "n": {"type": "object", "properties": {"deep": {"type": "array"}}},
                "s": {"type": "string", "contentEncoding": "hex"}
            }
        });
        let p = problems(bad);
        let has = |needle: &str| p.iter().any(|s| s.contains(needle));
        assert!(has("$.properties.xhat.items: arrays of arrays"), "{p:?}");
        assert!(has("`e[1]` is not an identifier"), "{p:?}");
        assert!(has("properties.u: a list of types"), "{p:?}");
        assert!(has("properties.r: `$ref` is not supported"), "{p:?}");
        assert!(has("properties.o: `oneOf`"), "{p:?}");
        assert!(
            has("properties.n.properties.deep: array without `items`"),
            "{p:?}"
        );
        assert!(has("contentEncoding"), "{p:?}");
        assert!(!problems(json!({"type": "array"})).is_empty());
    }

    #[test]
    fn identifiers() {
        assert!(is_path_identifier("xhat") && is_path_identifier("_k2"));
        assert!(!is_path_identifier("e[1]") && !is_path_identifier("step.timer"));
        assert!(!is_path_identifier("") && !is_path_identifier("1x"));
    }
}
