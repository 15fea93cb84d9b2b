//! A serde Deserializer over the positioned tree: every error carries the dotted key path and
//! the position of the offending key or value, and says "expected X, got Y" in plain words.
use super::node::{fmt_float, Node, Pos, Val};
use serde::de::{self, DeserializeSeed, IntoDeserializer, Visitor};
use std::fmt;

#[derive(Debug)]
pub(crate) struct DeError {
    pub msg: String,
    /// Key path and position, filled in by the innermost node that saw the error.
    pub at: Option<(String, Pos)>,
    /// A missing key is reported at its parent's key, not at the parent's first child.
    missing: bool,
}

impl DeError {
    fn new(msg: String) -> Self {
        DeError {
            msg,
            at: None,
            missing: false,
        }
    }
    fn locate(mut self, path: &str, pos: Pos, key_pos: Pos) -> Self {
        if self.at.is_none() {
            let p = if self.missing { key_pos } else { pos };
            self.at = Some((path.to_string(), p));
        }
        self
    }
}

impl fmt::Display for DeError {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(&self.msg)
    }
}
impl std::error::Error for DeError {}

/// Rewrites serde's type names ("u32", "struct OutputConfig") into words an artist can act on.
fn expected_words(exp: &dyn de::Expected) -> String {
    let s = exp.to_string();
    match s.as_str() {
        "u8" | "u16" | "u32" | "u64" | "usize" => "an unsigned integer (0, 1, 2, ...)".into(),
        "i8" | "i16" | "i32" | "i64" | "isize" => "an integer".into(),
        "f32" | "f64" => "a number".into(),
        "a boolean" => "true or false".into(),
        "a string" => "a string".into(),
        _ if s.starts_with("struct ") => "a mapping of keys".into(),
        _ if s.starts_with("an array of length ") => {
            format!("a list of {} values", &s["an array of length ".len()..])
        }
        "a map" => "a mapping of names".into(),
        "option" => "a value".into(),
        _ => s,
    }
}

fn unexpected_words(u: de::Unexpected) -> String {
    use de::Unexpected as U;
    match u {
        U::Bool(b) => b.to_string(),
        U::Unsigned(n) => n.to_string(),
        U::Signed(n) => n.to_string(),
        // "4.0", not "4": the user must see why an integer key refused it.
        U::Float(f) if f.is_finite() && f.fract() == 0.0 && f.abs() < 1e15 => format!("{f:.1}"),
        U::Float(f) => fmt_float(f),
        U::Char(c) => format!("{c:?}"),
        U::Str(s) => format!("{:?}", super::node::clip(s)),
        U::Unit | U::Option => "an empty value".into(),
        U::Seq => "a list".into(),
        U::Map => "a mapping".into(),
        other => other.to_string(),
    }
}

fn one_of(names: &[&str]) -> String {
    names.join(", ")
}

impl de::Error for DeError {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        DeError::new(msg.to_string())
    }
    fn invalid_type(unexp: de::Unexpected, exp: &dyn de::Expected) -> Self {
        let mut m = format!(
            "expected {}, got {}",
            expected_words(exp),
            unexpected_words(unexp)
        );
        if exp.to_string() == "a string"
            && matches!(
                unexp,
                de::Unexpected::Unsigned(_)
                    | de::Unexpected::Signed(_)
                    | de::Unexpected::Float(_)
                    | de::Unexpected::Bool(_)
            )
        {
            m.push_str(" (put it in quotes to make it text)");
        }
        DeError::new(m)
    }
    fn invalid_value(unexp: de::Unexpected, exp: &dyn de::Expected) -> Self {
        let words = expected_words(exp);
        let extra = match exp.to_string().as_str() {
            _ if matches!(unexp, de::Unexpected::Signed(_)) => "",
            "u8" => " up to 255",
            "u16" => " up to 65535",
            "u32" => " up to 4294967295",
            _ => "",
        };
        DeError::new(format!(
            "expected {words}{extra}, got {}",
            unexpected_words(unexp)
        ))
    }
    fn invalid_length(len: usize, exp: &dyn de::Expected) -> Self {
        DeError::new(format!(
            "expected {}, got {len} value{}",
            expected_words(exp),
            if len == 1 { "" } else { "s" }
        ))
    }
    fn unknown_variant(variant: &str, expected: &'static [&'static str]) -> Self {
        DeError::new(format!(
            "expected one of {}, got {:?}",
            one_of(expected),
            super::node::clip(variant)
        ))
    }
    fn unknown_field(field: &str, expected: &'static [&'static str]) -> Self {
        DeError::new(format!(
            "unknown key {:?} (valid keys here: {})",
            super::node::clip(field),
            one_of(expected)
        ))
    }
    fn missing_field(field: &'static str) -> Self {
        DeError {
            msg: format!("missing required key '{field}'"),
            at: None,
            missing: true,
        }
    }
    fn duplicate_field(field: &'static str) -> Self {
        DeError::new(format!("key '{field}' is given twice"))
    }
}

/// Deserializes `node` (found at `path`) into `T`.
pub(crate) fn from_node<'de, T: de::Deserialize<'de>>(node: &Node) -> Result<T, DeError> {
    T::deserialize(NodeDe {
        node,
        path: String::new(),
        key_pos: node.pos,
    })
}

struct NodeDe<'a> {
    node: &'a Node,
    path: String,
    /// Position of the key that holds this node (the node's own position at the top level).
    key_pos: Pos,
}

fn join(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_string()
    } else {
        format!("{path}.{key}")
    }
}

impl<'a> NodeDe<'a> {
    fn loc<T>(&self, r: Result<T, DeError>) -> Result<T, DeError> {
        r.map_err(|e| e.locate(&self.path, self.node.pos, self.key_pos))
    }

    fn err(&self, msg: String) -> DeError {
        DeError::new(msg).locate(&self.path, self.node.pos, self.key_pos)
    }

    /// Rejects a mapping that names a key twice (YAML forbids it; serde would keep one silently).
    fn check_duplicates(&self, entries: &[(super::node::Key, Node)]) -> Result<(), DeError> {
        for (i, (k, _)) in entries.iter().enumerate() {
            if let Some((first, _)) = entries[..i].iter().find(|(f, _)| f.name == k.name) {
                let first_at = match first.pos {
                    Pos::At { line, col } => format!(" (first given at line {line}:{col})"),
                    _ => String::new(),
                };
                return Err(DeError::new(format!("duplicate key{first_at}")).locate(
                    &join(&self.path, &k.name),
                    k.pos,
                    k.pos,
                ));
            }
        }
        Ok(())
    }
}

impl<'de, 'a> de::Deserializer<'de> for NodeDe<'a> {
    type Error = DeError;

    fn deserialize_any<V: Visitor<'de>>(self, v: V) -> Result<V::Value, DeError> {
        let r = match &self.node.val {
            Val::Null => v.visit_unit(),
            Val::Bool(b) => v.visit_bool(*b),
            Val::UInt(u) => v.visit_u64(*u),
            Val::Int(i) => v.visit_i64(*i),
            Val::Float(f) => {
                if !f.is_finite() {
                    return Err(
                        self.err(format!("expected a finite number, got {}", fmt_float(*f)))
                    );
                }
                v.visit_f64(*f)
            }
            Val::Str(s) => v.visit_str(s),
            Val::Seq(items) => {
                let mut acc = SeqAcc {
                    items: items.iter(),
                    index: 0,
                    path: &self.path,
                };
                let out = v.visit_seq(&mut acc);
                let out = self.loc(out)?;
                let rest = acc.items.len();
                if rest > 0 {
                    return Err(self.err(format!(
                        "too many values: expected {}, got {}",
                        items.len() - rest,
                        items.len()
                    )));
                }
                return Ok(out);
            }
            Val::Map(entries) => {
                self.check_duplicates(entries)?;
                let acc = MapAcc {
                    entries: entries.iter(),
                    value: None,
                    path: &self.path,
                };
                v.visit_map(acc)
            }
        };
        self.loc(r)
    }

    fn deserialize_option<V: Visitor<'de>>(self, v: V) -> Result<V::Value, DeError> {
        match self.node.val {
            Val::Null => {
                let r = v.visit_none();
                self.loc(r)
            }
            _ => v.visit_some(self),
        }
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _name: &'static str,
        variants: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, DeError> {
        match &self.node.val {
            Val::Str(s) if variants.contains(&s.as_str()) => {
                let r = v.visit_enum(s.as_str().into_deserializer());
                self.loc(r)
            }
            other => Err(self.err(format!(
                "expected one of {}, got {}",
                one_of(variants),
                other.describe()
            ))),
        }
    }

    /// `solver:` with nothing after it means "all defaults", not an error.
    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        _fields: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, DeError> {
        if self.node.val == Val::Null {
            let acc = MapAcc {
                entries: [].iter(),
                value: None,
                path: &self.path,
            };
            let r = v.visit_map(acc);
            return self.loc(r);
        }
        self.deserialize_any(v)
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _name: &'static str,
        v: V,
    ) -> Result<V::Value, DeError> {
        v.visit_newtype_struct(self)
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string
        bytes byte_buf unit unit_struct seq tuple
        tuple_struct map identifier ignored_any
    }
}

struct SeqAcc<'a, 'p> {
    items: std::slice::Iter<'a, Node>,
    index: usize,
    path: &'p str,
}

impl<'de, 'a, 'p> de::SeqAccess<'de> for &mut SeqAcc<'a, 'p> {
    type Error = DeError;
    fn next_element_seed<T: DeserializeSeed<'de>>(
        &mut self,
        seed: T,
    ) -> Result<Option<T::Value>, DeError> {
        let Some(node) = self.items.next() else {
            return Ok(None);
        };
        let path = format!("{}[{}]", self.path, self.index);
        self.index += 1;
        seed.deserialize(NodeDe {
            node,
            path,
            key_pos: node.pos,
        })
        .map(Some)
    }
    fn size_hint(&self) -> Option<usize> {
        Some(self.items.len())
    }
}

struct MapAcc<'a, 'p> {
    entries: std::slice::Iter<'a, (super::node::Key, Node)>,
    value: Option<(&'a Node, String, Pos)>,
    path: &'p str,
}

impl<'de, 'a, 'p> de::MapAccess<'de> for MapAcc<'a, 'p> {
    type Error = DeError;
    fn next_key_seed<K: DeserializeSeed<'de>>(
        &mut self,
        seed: K,
    ) -> Result<Option<K::Value>, DeError> {
        let Some((key, node)) = self.entries.next() else {
            return Ok(None);
        };
        let path = join(self.path, &key.name);
        let k: Result<K::Value, DeError> = seed.deserialize(key.name.as_str().into_deserializer());
        let k = k.map_err(|e| e.locate(&path, key.pos, key.pos))?;
        self.value = Some((node, path, key.pos));
        Ok(Some(k))
    }
    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, DeError> {
        let (node, path, key_pos) = self
            .value
            .take()
            .ok_or_else(|| DeError::new("internal: value requested before key".into()))?;
        seed.deserialize(NodeDe {
            node,
            path,
            key_pos,
        })
    }
    fn size_hint(&self) -> Option<usize> {
        Some(self.entries.len())
    }
}
