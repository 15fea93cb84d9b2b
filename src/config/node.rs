//! A YAML document as a tree that remembers where every key and value came from (a line:col
//! in the file, or a `--set` override), so that every later error can point at its source.
//! serde-saphyr does the YAML parsing; `Spanned` gives us the positions.
use serde::de::{self, Deserialize, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_saphyr::{DuplicateKeyPolicy, NonFiniteFloatPolicy, Spanned};
use std::fmt;

/// Where a key or value came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Pos {
    /// 1-based line and column in the config file.
    At { line: u64, col: u64 },
    /// The n-th `--set` override.
    Set(usize),
    /// Nowhere in particular (defaults, or a parser that gave no location).
    Unknown,
}

impl Pos {
    fn from_location(loc: serde_saphyr::Location) -> Pos {
        if loc.line() == 0 {
            Pos::Unknown
        } else {
            Pos::At {
                line: loc.line(),
                col: loc.column(),
            }
        }
    }

    /// Rebases positions parsed from an override value onto that override.
    fn into_set(self, idx: usize) -> Pos {
        match self {
            Pos::Set(i) => Pos::Set(i),
            _ => Pos::Set(idx),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Val {
    Null,
    Bool(bool),
    /// Non-negative integers.
    UInt(u64),
    /// Negative integers.
    Int(i64),
    /// Floats as written (may be non-finite: the deserializer rejects those with the key path).
    Float(f64),
    Str(String),
    Seq(Vec<Node>),
    /// Entries in file order; duplicates are kept so that they can be reported with a path.
    Map(Vec<(Key, Node)>),
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Node {
    pub val: Val,
    pub pos: Pos,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Key {
    pub name: String,
    pub pos: Pos,
}

impl Val {
    /// What a user would call this kind of value, for "got ..." messages.
    pub fn describe(&self) -> String {
        match self {
            Val::Null => "an empty value".into(),
            Val::Bool(b) => b.to_string(),
            Val::UInt(u) => u.to_string(),
            Val::Int(i) => i.to_string(),
            Val::Float(f) => fmt_float(*f),
            Val::Str(s) => format!("{:?}", clip(s)),
            Val::Seq(_) => "a list".into(),
            Val::Map(_) => "a mapping".into(),
        }
    }
}

/// YAML spelling of a float (`.nan`, `.inf`), else Rust's shortest round-trip form.
pub fn fmt_float(f: f64) -> String {
    if f.is_nan() {
        ".nan".into()
    } else if f.is_infinite() {
        if f > 0.0 { ".inf" } else { "-.inf" }.into()
    } else if f != 0.0 && (f.abs() >= 1e15 || f.abs() < 1e-5) {
        format!("{f:e}")
    } else {
        // Display is the shortest round-trip form without a trailing ".0".
        format!("{f}")
    }
}

/// Long user strings are shortened so that the error stays one readable line.
pub(crate) fn clip(s: &str) -> String {
    const MAX: usize = 60;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(MAX).collect();
        t.push('…');
        t
    }
}

impl<'de> Deserialize<'de> for Node {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = Spanned::<Val>::deserialize(d)?;
        Ok(Node {
            val: s.value,
            pos: Pos::from_location(s.referenced),
        })
    }
}

impl<'de> Deserialize<'de> for Val {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(ValVisitor)
    }
}

struct ValVisitor;

impl<'de> Visitor<'de> for ValVisitor {
    type Value = Val;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any YAML value")
    }
    fn visit_bool<E>(self, v: bool) -> Result<Val, E> {
        Ok(Val::Bool(v))
    }
    fn visit_i64<E>(self, v: i64) -> Result<Val, E> {
        Ok(if v >= 0 {
            Val::UInt(v as u64)
        } else {
            Val::Int(v)
        })
    }
    fn visit_u64<E>(self, v: u64) -> Result<Val, E> {
        Ok(Val::UInt(v))
    }
    fn visit_i128<E: de::Error>(self, v: i128) -> Result<Val, E> {
        if let Ok(u) = u64::try_from(v) {
            Ok(Val::UInt(u))
        } else if let Ok(i) = i64::try_from(v) {
            Ok(Val::Int(i))
        } else {
            Err(E::custom(format!("integer {v} is out of range")))
        }
    }
    fn visit_u128<E: de::Error>(self, v: u128) -> Result<Val, E> {
        u64::try_from(v)
            .map(Val::UInt)
            .map_err(|_| E::custom(format!("integer {v} is out of range")))
    }
    fn visit_f64<E>(self, v: f64) -> Result<Val, E> {
        Ok(Val::Float(v))
    }
    fn visit_str<E>(self, v: &str) -> Result<Val, E> {
        Ok(Val::Str(v.to_string()))
    }
    fn visit_string<E>(self, v: String) -> Result<Val, E> {
        Ok(Val::Str(v))
    }
    fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Val, E> {
        String::from_utf8(v.to_vec())
            .map(Val::Str)
            .map_err(|_| E::custom("binary data where text was expected"))
    }
    fn visit_unit<E>(self) -> Result<Val, E> {
        Ok(Val::Null)
    }
    fn visit_none<E>(self) -> Result<Val, E> {
        Ok(Val::Null)
    }
    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Val, D::Error> {
        Val::deserialize(d)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Val, A::Error> {
        let mut items = Vec::new();
        while let Some(n) = seq.next_element::<Node>()? {
            items.push(n);
        }
        Ok(Val::Seq(items))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Val, A::Error> {
        let mut entries = Vec::new();
        while let Some(k) = map.next_key::<Key>()? {
            let v = map.next_value::<Node>()?;
            entries.push((k, v));
        }
        Ok(Val::Map(entries))
    }
}

impl<'de> Deserialize<'de> for Key {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = Spanned::<KeyName>::deserialize(d)?;
        Ok(Key {
            name: s.value.0,
            pos: Pos::from_location(s.referenced),
        })
    }
}

/// A mapping key: any scalar, kept as text (a key `1:` is looked up as "1").
struct KeyName(String);

impl<'de> Deserialize<'de> for KeyName {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = KeyName;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a plain key (a name), not a list or mapping")
            }
            fn visit_str<E>(self, v: &str) -> Result<KeyName, E> {
                Ok(KeyName(v.to_string()))
            }
            fn visit_bool<E>(self, v: bool) -> Result<KeyName, E> {
                Ok(KeyName(v.to_string()))
            }
            fn visit_i64<E>(self, v: i64) -> Result<KeyName, E> {
                Ok(KeyName(v.to_string()))
            }
            fn visit_u64<E>(self, v: u64) -> Result<KeyName, E> {
                Ok(KeyName(v.to_string()))
            }
            fn visit_f64<E>(self, v: f64) -> Result<KeyName, E> {
                Ok(KeyName(fmt_float(v)))
            }
            fn visit_unit<E>(self) -> Result<KeyName, E> {
                Ok(KeyName("null".into()))
            }
        }
        d.deserialize_any(V)
    }
}

/// A YAML-level failure: position (if the parser gave one) and a one-line message.
#[derive(Debug)]
pub(crate) struct ParseError {
    pub pos: Pos,
    pub msg: String,
}

/// Parses YAML text into a positioned tree.
pub(crate) fn parse(text: &str) -> Result<Node, ParseError> {
    let opts = serde_saphyr::options! {
        // Duplicates are forwarded and reported by us, with their key path.
        duplicate_keys: DuplicateKeyPolicy::PassThrough,
        // Non-finite floats are forwarded and rejected by us, with their key path.
        non_finite_float_policy: NonFiniteFloatPolicy::PassThrough,
        // YAML 1.2: only true/false are booleans, so `periodic: [x, y]` keeps its "y".
        strict_booleans: true,
        with_snippet: false,
    };
    serde_saphyr::from_str_with_options::<Node>(text, opts).map_err(|e| {
        let inner = e.without_snippet();
        let pos = inner.location().map_or(Pos::Unknown, Pos::from_location);
        let msg = serde_saphyr::MessageFormatter::format_message(
            &serde_saphyr::UserMessageFormatter,
            inner,
        );
        ParseError {
            pos,
            msg: one_line(&msg),
        }
    })
}

/// Collapses whitespace runs (including newlines) so that a message stays on one line.
pub(crate) fn one_line(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for w in s.split_whitespace() {
        if !out.is_empty() {
            out.push(' ');
        }
        out.extend(w.chars().filter(|c| !c.is_control()));
    }
    out
}

/// Moves every position in a subtree onto the n-th override.
pub(crate) fn rebase_set(node: &mut Node, idx: usize) {
    node.pos = node.pos.into_set(idx);
    match &mut node.val {
        Val::Seq(items) => items.iter_mut().for_each(|n| rebase_set(n, idx)),
        Val::Map(entries) => {
            for (k, v) in entries {
                k.pos = k.pos.into_set(idx);
                rebase_set(v, idx);
            }
        }
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_of_keys_and_values() {
        let n = parse("a: 1\nb:\n  c: [1, 2.5, x]\n").unwrap();
        let Val::Map(e) = &n.val else { panic!() };
        assert_eq!(e[0].0.name, "a");
        assert_eq!(e[0].0.pos, Pos::At { line: 1, col: 1 });
        assert_eq!(e[0].1.val, Val::UInt(1));
        assert_eq!(e[0].1.pos, Pos::At { line: 1, col: 4 });
        let Val::Map(inner) = &e[1].1.val else {
            panic!()
        };
        assert_eq!(inner[0].0.pos, Pos::At { line: 3, col: 3 });
        let Val::Seq(items) = &inner[0].1.val else {
            panic!()
        };
        assert_eq!(items[1].val, Val::Float(2.5));
        assert_eq!(items[2].val, Val::Str("x".into()));
    }

    #[test]
    fn duplicates_and_nan_are_kept_for_later_reporting() {
        let n = parse("a: 1\na: .nan\n").unwrap();
        let Val::Map(e) = &n.val else { panic!() };
        assert_eq!(e.len(), 2);
        assert!(matches!(e[1].1.val, Val::Float(f) if f.is_nan()));
    }

    #[test]
    fn quoted_numbers_stay_strings() {
        let n = parse("a: \"4\"\nb: -3\n").unwrap();
        let Val::Map(e) = &n.val else { panic!() };
        assert_eq!(e[0].1.val, Val::Str("4".into()));
        assert_eq!(e[1].1.val, Val::Int(-3));
    }

    #[test]
    fn syntax_error_has_a_position() {
        let e = parse("a: [1, 2\nb: 3\n").unwrap_err();
        assert!(matches!(e.pos, Pos::At { .. }), "{e:?}");
        assert!(!e.msg.contains('\n'));
    }
}
