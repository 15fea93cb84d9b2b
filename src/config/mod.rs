//! Shot configs: schema, reading with precise errors, `--set` overrides, ranges and the rules
//! between keys, hashing. The files a config names (heat maps, a target) and the limits of the
//! stages that run it are checked by the prepared shot (`shot`), which places its issues with
//! [`Checked::error`].
//!
//! Every failure is one line: `FILE:LINE:COL: KEY.PATH: what was expected (got what)`. Keys set
//! by `--set` read `FILE: --set KEY.PATH: ...`; keys left at their default read `FILE: KEY.PATH: ...`.
mod art;
mod de;
mod hash;
mod node;
mod schema;
mod validate;

pub use art::{MAX_ENVIRONMENT_LEVELS, MAX_WIND_LEVELS};
pub use hash::{full_hash, sim_hash, sim_key_diff, NON_SIM_KEYS};
pub use node::fmt_float;
pub use schema::*;
pub use validate::{
    float_values, lattice_count, FloatRange, Issue, FLOAT_RANGES, MAX_CAPACITY, MAX_FRAME,
    MAX_LEVEL, MAX_MIN_DISTANCE, MAX_NANOVDB_NAME_BYTES, MAX_PARTICLES, MAX_SHOT_BYTES,
    MAX_SOURCES, MAX_VOXELS_PER_AXIS,
};

use crate::error::{Error, Result};
use node::{Key, Node, Pos, Val};
use std::collections::HashMap;
use std::path::Path;

/// Largest config file accepted (bytes): a shot config is a few kilobytes.
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// A config read and checked (schema, ranges, the rules between keys), and where each of its
/// keys was set, to place the issues found later (`shot`) as the config's own are placed.
#[derive(Debug, Clone)]
pub struct Checked {
    pub config: ShotConfig,
    file: String,
    sets: Vec<String>,
    positions: HashMap<String, Pos>,
}

impl Checked {
    /// `issue` as a one-line error at the position of its first key the config sets.
    pub fn error(&self, issue: &Issue) -> Error {
        let ctx = Ctx {
            file: &self.file,
            sets: &self.sets,
        };
        let key = issue
            .keys
            .iter()
            .find(|k| self.positions.contains_key(k.as_str()))
            .unwrap_or(&issue.keys[0]);
        let pos = self
            .positions
            .get(key.as_str())
            .copied()
            .unwrap_or(Pos::Unknown);
        ctx.at(key, pos, &issue.msg)
    }
}

impl Issue {
    /// The issue as a one-line error naming its first key (no file position: see [`read`]).
    pub fn error(&self) -> Error {
        Error::Config(format!("{}: {}", self.keys[0], self.msg))
    }
}

/// Reads, parses, overrides (`--set key.path=value`, in order), deserializes and checks.
/// The file must be a regular file of at most [`MAX_CONFIG_BYTES`] (a directory, FIFO or device
/// is refused at once, without reading it).
pub fn read(path: &Path, overrides: &[String]) -> Result<Checked> {
    let name = path.display().to_string();
    let bytes = read_bounded(path)
        .map_err(|why| Error::Config(format!("{name}: cannot read config: {why}")))?;
    let text = decode(&name, &bytes)?;
    read_text(&text, &name, overrides, path.parent())
}

/// The bytes of a regular file of at most [`MAX_CONFIG_BYTES`], or why not.
fn read_bounded(path: &Path) -> std::result::Result<Vec<u8>, String> {
    use std::io::Read;
    let words = |e: std::io::Error| match e.kind() {
        std::io::ErrorKind::NotFound => "no such file".to_string(),
        std::io::ErrorKind::PermissionDenied => "permission denied".to_string(),
        std::io::ErrorKind::IsADirectory => "is a directory, not a config file".to_string(),
        _ => e.to_string(),
    };
    let kind = |m: &std::fs::Metadata| -> std::result::Result<(), String> {
        let t = m.file_type();
        if t.is_dir() {
            return Err("is a directory, not a config file".into());
        }
        if !t.is_file() {
            return Err(
                "not a regular file (a FIFO, socket or device); configs must be regular files"
                    .into(),
            );
        }
        if m.len() > MAX_CONFIG_BYTES {
            return Err(format!(
                "{} bytes is larger than the {MAX_CONFIG_BYTES}-byte limit of a config file",
                m.len()
            ));
        }
        Ok(())
    };
    // stat before open: opening a FIFO would block until someone writes to it.
    kind(&std::fs::metadata(path).map_err(words)?)?;
    let f = std::fs::File::open(path).map_err(words)?;
    kind(&f.metadata().map_err(words)?)?;
    let mut bytes = Vec::new();
    f.take(MAX_CONFIG_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(words)?;
    if bytes.len() as u64 > MAX_CONFIG_BYTES {
        return Err(format!(
            "larger than the {MAX_CONFIG_BYTES}-byte limit of a config file"
        ));
    }
    Ok(bytes)
}

/// Like [`read`] for text already in memory; `origin` names it in errors. Relative file paths
/// in it (heat maps) are taken from the working directory.
pub fn read_str(text: &str, origin: &str, overrides: &[String]) -> Result<Checked> {
    read_text(text, origin, overrides, None)
}

/// `base`: the directory relative file paths in the config are resolved against.
fn read_text(
    text: &str,
    origin: &str,
    overrides: &[String],
    base: Option<&Path>,
) -> Result<Checked> {
    let ctx = Ctx {
        file: origin,
        sets: overrides,
    };
    if text.contains('\0') {
        return Err(ctx.bare("binary data (NUL bytes), not a YAML text file"));
    }
    let mut root = match node::parse(text) {
        Ok(n) => n,
        Err(e) => {
            let near = match e.pos {
                Pos::At { line, .. } => key_near(text, line),
                _ => None,
            };
            let mut msg = format!("invalid YAML: {}", yaml_words(&e.msg));
            if let Pos::At { line, .. } = e.pos {
                if let Some((open, l, c)) = unclosed_bracket(text, line) {
                    msg.push_str(&format!(" (is the '{open}' at line {l}:{c} closed?)"));
                }
            }
            return Err(match near {
                Some(k) => ctx.at(&k, e.pos, &msg),
                None => ctx.at_no_key(e.pos, &msg),
            });
        }
    };
    match &root.val {
        Val::Map(_) => {}
        Val::Null => {
            return Err(ctx.bare(
                "the file is empty; a shot needs at least the keys shot, output and domain (see docs/CONFIG.md)",
            ))
        }
        other => {
            return Err(ctx.at(
                "",
                root.pos,
                &format!("expected a mapping of keys (shot:, output:, domain:, ...), got {}", other.describe()),
            ))
        }
    }
    for (i, set) in overrides.iter().enumerate() {
        apply_override(&mut root, i, set).map_err(|(key, msg)| ctx.at(&key, Pos::Set(i), &msg))?;
    }
    let mut cfg: ShotConfig = de::from_node(&root).map_err(|e| match e.at {
        Some((path, pos)) => ctx.at(&path, pos, &e.msg),
        None => ctx.bare(&e.msg),
    })?;
    resolve_paths(&mut cfg, base);
    let mut positions = HashMap::new();
    collect_positions(&root, "", &mut positions);
    let mut checked = Checked {
        config: cfg,
        file: origin.to_string(),
        sets: overrides.to_vec(),
        positions,
    };
    if let Some(issue) = first_issue(&checked.config) {
        return Err(checked.error(&issue));
    }
    normalise(&mut checked.config);
    Ok(checked)
}

/// The first problem of the range and consistency checks, if any.
pub fn first_issue(cfg: &ShotConfig) -> Option<Issue> {
    validate::issues(cfg).into_iter().next()
}

/// Range and consistency checks; the error names the key path (no file position: see [`read`]).
pub fn validate(cfg: &ShotConfig) -> Result<()> {
    match first_issue(cfg) {
        None => Ok(()),
        Some(i) => Err(i.error()),
    }
}

/// Values that are stored normalised (documented in docs/CONFIG.md).
fn normalise(cfg: &mut ShotConfig) {
    let d = &mut cfg.output.preview.sun_direction;
    let v = glam::DVec3::from(*d);
    let len = v.length();
    // divided, not times the reciprocal (glam's normalize): the stored config stays the same
    if len > 0.0 && len.is_finite() {
        *d = (v / len).to_array();
    }
    // (the files' SHA-256 pins are set by the prepared shot, which reads the files)
}

/// Heat-map paths become absolute: relative ones are taken from `base` (the config file's
/// directory) or the working directory, so a resume from the manifest finds the same file.
fn resolve_paths(cfg: &mut ShotConfig, base: Option<&Path>) {
    for src in &mut cfg.physics.sources {
        let Some(image) = &src.image else { continue };
        let p = Path::new(image);
        let joined = match base {
            Some(b) if p.is_relative() => b.join(p),
            _ => p.to_path_buf(),
        };
        if let Ok(abs) = std::path::absolute(&joined) {
            src.image = Some(abs.to_string_lossy().into_owned());
        }
    }
    if let Some(t) = &mut cfg.control.target {
        for path in [&mut t.mesh, &mut t.vdb].into_iter().flatten() {
            let p = Path::new(path.as_str());
            let joined = match base {
                Some(b) if p.is_relative() => b.join(p),
                _ => p.to_path_buf(),
            };
            if let Ok(abs) = std::path::absolute(&joined) {
                *path = abs.to_string_lossy().into_owned();
            }
        }
    }
}

struct Ctx<'a> {
    file: &'a str,
    sets: &'a [String],
}

impl Ctx<'_> {
    fn bare(&self, msg: &str) -> Error {
        Error::Config(format!("{}: {}", self.file, msg))
    }

    fn at_no_key(&self, pos: Pos, msg: &str) -> Error {
        match pos {
            Pos::At { line, col } => Error::Config(format!("{}:{line}:{col}: {msg}", self.file)),
            _ => self.bare(msg),
        }
    }

    fn at(&self, key: &str, pos: Pos, msg: &str) -> Error {
        let key = if key.is_empty() { "(top level)" } else { key };
        let f = self.file;
        Error::Config(match pos {
            Pos::At { line, col } => format!("{f}:{line}:{col}: {key}: {msg}"),
            Pos::Set(i) => {
                let set_key = self
                    .sets
                    .get(i)
                    .map(|s| s.split_once('=').map_or(s.as_str(), |(k, _)| k).trim())
                    .unwrap_or("?");
                if set_key == key {
                    format!("{f}: --set {key}: {msg}")
                } else {
                    format!("{f}: --set {set_key}: {key}: {msg}")
                }
            }
            Pos::Unknown => format!("{f}: {key}: {msg}"),
        })
    }
}

/// UTF-8 with an optional BOM; anything else is named with its line:col.
fn decode(name: &str, bytes: &[u8]) -> Result<String> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(Error::Config(format!(
            "{name}: the file is empty; a shot needs at least the keys shot, output and domain (see docs/CONFIG.md)"
        )));
    }
    match std::str::from_utf8(bytes) {
        Ok(s) => {
            if let Some(off) = s.find('\0') {
                let (line, col) = line_col(&bytes[..off]);
                return Err(Error::Config(format!(
                    "{name}:{line}:{col}: binary data (a NUL byte at offset {off}), not a YAML text file"
                )));
            }
            Ok(s.to_string())
        }
        Err(e) => {
            let off = e.valid_up_to();
            let (line, col) = line_col(&bytes[..off]);
            Err(Error::Config(format!(
                "{name}:{line}:{col}: not UTF-8 text (byte 0x{:02x} at offset {off}); binary file, or save it as UTF-8",
                bytes[off]
            )))
        }
    }
}

fn line_col(before: &[u8]) -> (usize, usize) {
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let start = before
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |p| p + 1);
    let col = String::from_utf8_lossy(&before[start..]).chars().count() + 1;
    (line, col)
}

/// Clarifies the parser's wording for the mistakes people actually make.
fn yaml_words(msg: &str) -> String {
    let lower = msg.to_lowercase();
    if lower.contains("tab") {
        format!("{msg} (indent with spaces; YAML forbids tabs)")
    } else {
        msg.to_string()
    }
}

/// Best guess of the key a syntax error sits in: the block-style keys enclosing `line`.
fn key_near(text: &str, line: u64) -> Option<String> {
    let mut stack: Vec<(usize, String)> = Vec::new();
    let mut found = None;
    for (i, raw) in text.lines().enumerate() {
        if i as u64 >= line {
            break;
        }
        let content = raw.trim_start_matches([' ', '\t', '-']);
        let indent = raw.len() - content.len();
        let Some((k, _)) = content.split_once(':') else {
            continue;
        };
        let k = k.trim();
        if k.is_empty()
            || k.starts_with('#')
            || !k
                .chars()
                .all(|c| c.is_alphanumeric() || c == '_' || c == '-')
        {
            continue;
        }
        while stack.last().is_some_and(|(ind, _)| *ind >= indent) {
            stack.pop();
        }
        stack.push((indent, k.to_string()));
        found = Some(
            stack
                .iter()
                .map(|(_, k)| k.as_str())
                .collect::<Vec<_>>()
                .join("."),
        );
    }
    found
}

/// The innermost flow bracket still open before `line` (quotes and comments skipped), if any:
/// a forgotten `]` makes the parser complain lines later about something else.
fn unclosed_bracket(text: &str, line: u64) -> Option<(char, usize, usize)> {
    let mut stack = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        if i as u64 + 1 >= line {
            break;
        }
        let mut quote = None;
        for (j, ch) in raw.chars().enumerate() {
            match (quote, ch) {
                (Some(q), c) if c == q => quote = None,
                (Some(_), _) => {}
                (None, '"' | '\'') => quote = Some(ch),
                (None, '#') => break,
                (None, '[' | '{') => stack.push((ch, i + 1, j + 1)),
                (None, ']' | '}') => {
                    stack.pop();
                }
                _ => {}
            }
        }
    }
    stack.pop()
}

/// Where the dotted `key` is set in config `text` (1-based line, column), or None when the text
/// does not set it (a default) or does not parse. Lets callers that override a key (farm wedges)
/// point at the line they override.
pub fn key_position(text: &str, key: &str) -> Option<(u64, u64)> {
    let root = node::parse(text).ok()?;
    let mut positions = HashMap::new();
    collect_positions(&root, "", &mut positions);
    match positions.get(key)? {
        Pos::At { line, col } => Some((*line, *col)),
        _ => None,
    }
}

/// Dotted path of every key (key position) and list element (value position).
fn collect_positions(n: &Node, path: &str, out: &mut HashMap<String, Pos>) {
    match &n.val {
        Val::Map(entries) => {
            for (k, v) in entries {
                let p = join(path, &k.name);
                out.insert(p.clone(), k.pos);
                collect_positions(v, &p, out);
            }
        }
        Val::Seq(items) => {
            for (i, v) in items.iter().enumerate() {
                let p = format!("{path}[{i}]");
                out.insert(p.clone(), v.pos);
                collect_positions(v, &p, out);
            }
        }
        _ => {}
    }
}

fn join(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_string()
    } else {
        format!("{path}.{key}")
    }
}

#[derive(Debug, PartialEq)]
enum Seg {
    Key(String),
    Index(usize),
}

/// `a.b[2].c` or `a.b.2.c` -> segments. Errors are (key, message).
fn parse_key(key: &str) -> std::result::Result<Vec<Seg>, String> {
    let mut segs = Vec::new();
    for part in key.split('.') {
        let (name, mut rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if name.is_empty() && (rest.is_empty() || segs.is_empty()) {
            return Err(
                "empty key segment; write KEY.PATH=VALUE, e.g. output.frames.end=10".into(),
            );
        }
        if !name.is_empty() {
            if name.chars().all(|c| c.is_ascii_digit()) && !segs.is_empty() {
                segs.push(Seg::Index(
                    name.parse().map_err(|_| format!("bad index {name:?}"))?,
                ));
            } else {
                segs.push(Seg::Key(name.to_string()));
            }
        }
        while !rest.is_empty() {
            let close = rest.find(']').ok_or("unclosed '[' in key path")?;
            let idx = &rest[1..close];
            segs.push(Seg::Index(idx.parse().map_err(|_| {
                format!("expected a list index in [..], got {idx:?}")
            })?));
            rest = &rest[close + 1..];
            if !rest.is_empty() && !rest.starts_with('[') {
                return Err(format!("unexpected {rest:?} after ']' in key path"));
            }
        }
    }
    Ok(segs)
}

fn seg_path(segs: &[Seg]) -> String {
    let mut s = String::new();
    for seg in segs {
        match seg {
            Seg::Key(k) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(k);
            }
            Seg::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

/// Applies the i-th `--set`. Errors are (key path to report, message).
fn apply_override(
    root: &mut Node,
    i: usize,
    set: &str,
) -> std::result::Result<(), (String, String)> {
    let Some((key, value)) = set.split_once('=') else {
        return Err((
            set.to_string(),
            format!("expected KEY.PATH=VALUE (e.g. --set output.frames.end=10), got {set:?}"),
        ));
    };
    let key = key.trim();
    let segs = parse_key(key).map_err(|m| (key.to_string(), m))?;
    let mut value = if value.trim().is_empty() {
        Node {
            val: Val::Null,
            pos: Pos::Set(i),
        }
    } else {
        node::parse(value).map_err(|e| {
            (
                key.to_string(),
                format!(
                    "cannot read the value {:?} as YAML: {}",
                    node::clip(value),
                    e.msg
                ),
            )
        })?
    };
    node::rebase_set(&mut value, i);
    set_at(root, &segs, 0, value, i)
}

/// Keys whose value may be `true`/`false` for `{enabled: true/false}`.
const ENABLED_SHORTHANDS: &[&str] = &["export.nanovdb"];

fn set_at(
    cur: &mut Node,
    segs: &[Seg],
    depth: usize,
    value: Node,
    i: usize,
) -> std::result::Result<(), (String, String)> {
    let last = depth + 1 == segs.len();
    let here = seg_path(&segs[..depth]);
    if cur.val == Val::Null && depth > 0 {
        // `solver:` with no value is an empty mapping we may add to.
        cur.val = match segs[depth] {
            Seg::Key(_) => Val::Map(Vec::new()),
            Seg::Index(_) => Val::Seq(Vec::new()),
        };
    }
    // A key under `export.nanovdb: true` goes into the mapping that shorthand stands for.
    if let (Val::Bool(on), Seg::Key(_)) = (&cur.val, &segs[depth]) {
        if ENABLED_SHORTHANDS.contains(&here.as_str()) {
            let pos = cur.pos;
            cur.val = Val::Map(vec![(
                Key {
                    name: "enabled".into(),
                    pos,
                },
                Node {
                    val: Val::Bool(*on),
                    pos,
                },
            )]);
        }
    }
    match (&segs[depth], &mut cur.val) {
        (Seg::Key(name), Val::Map(entries)) => {
            let slot = match entries.iter().rposition(|(k, _)| &k.name == name) {
                Some(j) => j,
                None => {
                    entries.push((
                        Key {
                            name: name.clone(),
                            pos: Pos::Set(i),
                        },
                        Node {
                            val: Val::Null,
                            pos: Pos::Set(i),
                        },
                    ));
                    entries.len() - 1
                }
            };
            if last {
                // The value now comes from --set, so errors about this key point there.
                entries[slot].0.pos = Pos::Set(i);
                entries[slot].1 = value;
                Ok(())
            } else {
                set_at(&mut entries[slot].1, segs, depth + 1, value, i)
            }
        }
        (Seg::Index(j), Val::Seq(items)) => {
            let len = items.len();
            let Some(item) = items.get_mut(*j) else {
                return Err((
                    seg_path(&segs[..=depth]),
                    format!("index {j} is past the end of {here}, which has {len} values"),
                ));
            };
            if last {
                *item = value;
                Ok(())
            } else {
                set_at(item, segs, depth + 1, value, i)
            }
        }
        (seg, other) => {
            let want = match seg {
                Seg::Key(_) => "a mapping",
                Seg::Index(_) => "a list",
            };
            let what = if here.is_empty() {
                "the top level".to_string()
            } else {
                here.clone()
            };
            Err((
                seg_path(&segs[..=depth]),
                format!("cannot set it: {what} is {}, not {want}", other.describe()),
            ))
        }
    }
}

#[cfg(test)]
mod tests;
