//! The checkpoint byte format: header, sections and checksums, encoded and decoded in memory.
//!
//! # Layout (format version 1; all integers little-endian)
//! ```text
//! offset      size  field
//! 0           8     magic "NIMBUSCK"
//! 8           4     format version (u32) = 1
//! 12          4     H: length of the header body (u32, at most 64 KiB)
//! 16          H     header body:
//!                     u64  file length in bytes, trailer included (detects truncation)
//!                     str  tool version (nimbus CARGO_PKG_VERSION that wrote it)
//!                     str  sim config hash (hex, `config` module's hash of the
//!                          simulation-affecting keys)
//!                     u32  frame (last completed frame)
//!                     u64  step (substeps done since frame 0; with the seed this is the RNG
//!                          state: particle init and heating noise are stateless hashes)
//!                     f64  simulation time in seconds (IEEE bits)
//!                     u64  seed
//!                     u64  particle count (live particles, = length of every array section)
//!                     u64  capacity (GPU buffer length the run allocated)
//!                     str  adapter name (as `gpu::Context::adapter_name`)
//!                     u32  next id (next particle id the split stage hands out)
//!                     u32  number of sections
//!                   (str = u16 byte length + UTF-8 bytes)
//! 16+H        4     crc32 of bytes [0, 16+H)
//! then, per section:
//!             2     name length n (u16, 1..=255)
//!             n     name (UTF-8)
//!             8     data length L (u64)
//!             L     data
//!             4     crc32 of the section's name length, name, data length and data
//! end-32      32    SHA-256 of every byte before it
//! ```
//! Sections, in this order: `pos`, `vel`, `thermo` (`count` x `[f32;4]`, 16 B each), `info`
//! (`count` x `[u32;2]`, 8 B), `density` (`count` x `f32`, 4 B), then the named extra sections in
//! name order (opaque bytes owned by the stage that wrote them). Particle arrays are the raw
//! little-endian words of `sim::ParticleState`, so every float, NaN payloads included, comes back
//! bit for bit. A checkpoint holds 60 bytes per particle plus a few hundred bytes.
//!
//! # Reading
//! [`read_checkpoint`] checks, in this order, and stops at the first problem with one reason:
//! empty file, magic, format version, header length and header crc, file length against the
//! header (truncation / trailing bytes), the whole-file SHA-256 (a mismatch names the corrupt
//! section when its crc32 also fails), then the section table (names, lengths, the required
//! sections and their sizes). No length read from the file is trusted before it is bounded by the
//! file size, so a corrupt file can neither panic the reader nor make it allocate more than the
//! file holds.
use crate::error::{Error, Result};
use crate::ground::ParticleState;
use sha2::{Digest, Sha256};
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::fs;
use std::io::{BufWriter, Read, Write};
use std::path::Path;

/// First 8 bytes of every checkpoint.
pub const MAGIC: &[u8; 8] = b"NIMBUSCK";
/// Layout version this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
/// Extra section holding the run's resolved config as JSON (written by the frame loop).
pub const CONFIG_SECTION: &str = "config";

/// The resolved config a checkpoint records, if it has one that still loads.
pub fn config_of(ck: &Checkpoint) -> Option<crate::config::ShotConfig> {
    let bytes = ck.extra.get(CONFIG_SECTION)?;
    serde_json::from_slice(bytes).ok()
}

/// Names of the particle-array sections, in file order; extra sections may not use them.
pub const STATE_SECTIONS: [&str; 5] = ["pos", "vel", "thermo", "info", "density"];
/// Bytes per particle of each particle-array section, in [`STATE_SECTIONS`] order.
pub const STATE_STRIDES: [usize; 5] = [16, 16, 16, 8, 4];
/// Length of the trailer: the SHA-256 of every byte before it.
pub const TRAILER: usize = 32;

const PRELUDE: usize = 16;
const MAX_HEADER_LEN: usize = 64 * 1024;
const MAX_NAME_LEN: usize = 255;

/// Everything but the particle arrays and the extra sections.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointHeader {
    /// Version of nimbus that wrote the file (`crate::VERSION`).
    pub tool_version: String,
    /// Hex hash of the simulation-affecting config keys.
    pub sim_hash: String,
    /// Last completed frame.
    pub frame: u32,
    /// Substeps done since frame 0.
    pub step: u64,
    /// Simulation time in seconds.
    pub time: f64,
    pub seed: u64,
    /// Live particles; must equal the length of every array of the state.
    pub particle_count: u64,
    /// Particle buffer capacity of the run.
    pub capacity: u64,
    /// GPU adapter the state was computed on (bit-exact resume needs the same one).
    pub adapter: String,
    /// Next particle id to hand out.
    pub next_id: u32,
}

/// One checkpoint: header, particle state, and extra named sections (name -> bytes).
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    pub header: CheckpointHeader,
    pub state: ParticleState,
    pub extra: BTreeMap<String, Vec<u8>>,
}

/// Whether a file starting with these bytes is a checkpoint (for `nimbus inspect` dispatch).
pub fn is_checkpoint(bytes_prefix: &[u8]) -> bool {
    bytes_prefix.starts_with(MAGIC)
}

// ---------------------------------------------------------------------------------------------
// Writing

/// A checkpoint checked and laid out for writing: its header bytes and its sections.
pub struct Encoded<'a> {
    header: Vec<u8>,
    sections: Vec<Section<'a>>,
}

impl<'a> Encoded<'a> {
    /// Checks `ck` and lays it out. An inconsistent `ck` (array lengths, reserved or invalid
    /// extra section names) is `Error::Runtime`: it is a bug of the caller, not of the disk.
    pub fn new(ck: &'a Checkpoint) -> Result<Self> {
        let sections = sections_of(ck)?;
        let header = encode_header(&ck.header, &sections)?;
        Ok(Encoded { header, sections })
    }

    /// Writes the whole file to `out`. With `fail_after`, the write fails like a full disk once
    /// that many bytes have gone out (the fault test hook).
    pub fn write_to(&self, out: impl Write, fail_after: Option<u64>) -> std::io::Result<()> {
        let buf = BufWriter::with_capacity(1 << 20, out);
        let mut w = HashingWriter {
            inner: FaultWriter {
                inner: buf,
                left: fail_after,
            },
            sha: Sha256::new(),
        };
        w.write_all(&self.header)?;
        for (name, data) in &self.sections {
            let name_len = (name.len() as u16).to_le_bytes();
            let data_len = (data.len() as u64).to_le_bytes();
            let mut crc = crc32fast::Hasher::new();
            crc.update(&name_len);
            crc.update(name.as_bytes());
            crc.update(&data_len);
            crc.update(data);
            w.write_all(&name_len)?;
            w.write_all(name.as_bytes())?;
            w.write_all(&data_len)?;
            w.write_all(data)?;
            w.write_all(&crc.finalize().to_le_bytes())?;
        }
        let digest = w.sha.finalize();
        w.inner.write_all(digest.as_slice())?;
        w.inner.inner.flush()
    }
}

/// A section to write: name and little-endian bytes.
type Section<'a> = (&'a str, Cow<'a, [u8]>);

/// The sections of `ck` in file order, after checking that they are consistent.
fn sections_of(ck: &Checkpoint) -> Result<Vec<Section<'_>>> {
    let s = &ck.state;
    let n = s.pos.len();
    let lens = [
        s.pos.len(),
        s.vel.len(),
        s.thermo.len(),
        s.info.len(),
        s.density.len(),
    ];
    if lens.iter().any(|&l| l != n) || ck.header.particle_count != n as u64 {
        return Err(Error::Runtime(format!(
            "checkpoint: inconsistent particle state: header count {}, array lengths \
             pos/vel/thermo/info/density {lens:?}",
            ck.header.particle_count
        )));
    }
    if ck.header.particle_count > ck.header.capacity {
        return Err(Error::Runtime(format!(
            "checkpoint: particle count {} exceeds capacity {}",
            ck.header.particle_count, ck.header.capacity
        )));
    }
    let mut out: Vec<Section> = vec![
        ("pos", le_bytes(&s.pos)),
        ("vel", le_bytes(&s.vel)),
        ("thermo", le_bytes(&s.thermo)),
        ("info", le_bytes(&s.info)),
        ("density", le_bytes(&s.density)),
    ];
    for (name, data) in &ck.extra {
        if name.is_empty() || name.len() > MAX_NAME_LEN || STATE_SECTIONS.contains(&name.as_str()) {
            return Err(Error::Runtime(format!(
                "checkpoint: invalid extra section name {name:?} (1 to {MAX_NAME_LEN} bytes, \
                 not one of {STATE_SECTIONS:?})"
            )));
        }
        out.push((name.as_str(), Cow::Borrowed(data.as_slice())));
    }
    Ok(out)
}

fn encode_header(h: &CheckpointHeader, sections: &[Section]) -> Result<Vec<u8>> {
    let mut body = Vec::with_capacity(256);
    body.extend_from_slice(&0u64.to_le_bytes()); // file length, patched below
    put_str(&mut body, "tool version", &h.tool_version)?;
    put_str(&mut body, "sim hash", &h.sim_hash)?;
    body.extend_from_slice(&h.frame.to_le_bytes());
    body.extend_from_slice(&h.step.to_le_bytes());
    body.extend_from_slice(&h.time.to_bits().to_le_bytes());
    body.extend_from_slice(&h.seed.to_le_bytes());
    body.extend_from_slice(&h.particle_count.to_le_bytes());
    body.extend_from_slice(&h.capacity.to_le_bytes());
    put_str(&mut body, "adapter", &h.adapter)?;
    body.extend_from_slice(&h.next_id.to_le_bytes());
    body.extend_from_slice(&(sections.len() as u32).to_le_bytes());
    if body.len() > MAX_HEADER_LEN {
        return Err(Error::Runtime("checkpoint: header too long".into()));
    }
    let header_total = PRELUDE + body.len() + 4;
    let file_len = header_total as u64
        + sections
            .iter()
            .map(|(n, d)| 2 + n.len() as u64 + 8 + d.len() as u64 + 4)
            .sum::<u64>()
        + TRAILER as u64;
    body[..8].copy_from_slice(&file_len.to_le_bytes());

    let mut out = Vec::with_capacity(header_total);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(body.len() as u32).to_le_bytes());
    out.extend_from_slice(&body);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    Ok(out)
}

fn put_str(out: &mut Vec<u8>, what: &str, s: &str) -> Result<()> {
    if s.len() > u16::MAX as usize {
        return Err(Error::Runtime(format!("checkpoint: {what} too long")));
    }
    out.extend_from_slice(&(s.len() as u16).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
    Ok(())
}

/// Little-endian bytes of an array made of 4-byte words (f32 / u32 and arrays of them).
fn le_bytes<T: bytemuck::Pod>(v: &[T]) -> Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        Cow::Borrowed(bytemuck::cast_slice(v))
    } else {
        let words: &[u32] = bytemuck::cast_slice(v);
        Cow::Owned(words.iter().flat_map(|w| w.to_le_bytes()).collect())
    }
}

/// Inverse of `le_bytes`; `bytes.len()` must be a multiple of `size_of::<T>()`.
fn from_le_bytes<T: bytemuck::Pod>(bytes: &[u8]) -> Vec<T> {
    let mut v = vec![T::zeroed(); bytes.len() / std::mem::size_of::<T>()];
    bytemuck::cast_slice_mut::<T, u8>(&mut v).copy_from_slice(bytes);
    for w in bytemuck::cast_slice_mut::<T, u32>(&mut v) {
        *w = u32::from_le(*w);
    }
    v
}

struct HashingWriter<W> {
    inner: W,
    sha: Sha256,
}

impl<W: Write> Write for HashingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.sha.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Passes writes through until `left` bytes are used up, then fails like a full disk.
struct FaultWriter<W> {
    inner: W,
    left: Option<u64>,
}

impl<W: Write> Write for FaultWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let Some(left) = self.left else {
            return self.inner.write(buf);
        };
        if left == 0 && !buf.is_empty() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::StorageFull,
                "No space left on device (injected fault)",
            ));
        }
        let take = buf.len().min(left.min(usize::MAX as u64) as usize);
        let n = self.inner.write(&buf[..take])?;
        self.left = Some(left - n as u64);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

// ---------------------------------------------------------------------------------------------
// Reading

/// Reads and fully validates a checkpoint. Any defect is `Error::InvalidInput` with
/// `"<path>: <one reason>"`; an unreadable file is `Error::Io`.
pub fn read_checkpoint(path: &Path) -> Result<Checkpoint> {
    read_with_bytes(path).map(|(_, ck)| ck)
}

/// [`read_checkpoint`], also returning the file's bytes (for describing it).
pub fn read_with_bytes(path: &Path) -> Result<(Vec<u8>, Checkpoint)> {
    let bytes = fs::read(path).map_err(|e| Error::io(path, e))?;
    let ck = decode(&bytes).map_err(|reason| invalid(path, &reason))?;
    Ok((bytes, ck))
}

/// Reads and checks only the header (magic, version, header crc), not the sections.
pub fn read_header(path: &Path) -> Result<CheckpointHeader> {
    let f = fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut prefix = Vec::new();
    f.take((PRELUDE + MAX_HEADER_LEN + 4) as u64)
        .read_to_end(&mut prefix)
        .map_err(|e| Error::io(path, e))?;
    decode_header(&prefix)
        .map(|(h, _)| h.header)
        .map_err(|reason| invalid(path, &reason))
}

/// Validates a whole checkpoint held in memory; `Err` is the one-line reason.
pub fn decode(bytes: &[u8]) -> std::result::Result<Checkpoint, String> {
    let (h, header_end) = decode_header(bytes)?;
    let file_len = h.file_len;
    if (bytes.len() as u64) < file_len {
        return Err(format!(
            "truncated: {} of {} bytes present",
            bytes.len(),
            file_len
        ));
    }
    if bytes.len() as u64 > file_len {
        return Err(format!(
            "{} unexpected bytes after the end of the checkpoint ({file_len} bytes)",
            bytes.len() as u64 - file_len
        ));
    }
    let min_len = (header_end + TRAILER) as u64;
    if file_len < min_len {
        return Err(format!(
            "corrupt header: file length {file_len} is shorter than its header"
        ));
    }
    let body_end = bytes.len() - TRAILER;
    let sha = Sha256::digest(&bytes[..body_end]);
    let sha_ok = sha.as_slice() == &bytes[body_end..];

    // Walk the section table (bounded by the file); the first crc failure names the culprit.
    let mut sections: Vec<(String, &[u8])> = Vec::with_capacity(h.section_count as usize);
    let mut cur = Cursor {
        bytes: &bytes[..body_end],
        pos: header_end,
    };
    let walked = (|| -> std::result::Result<(), String> {
        for i in 0..h.section_count {
            let start = cur.pos;
            let name_len = cur.u16().ok_or_else(|| table_end(i, h.section_count))? as usize;
            let name = cur
                .take(name_len)
                .ok_or_else(|| table_end(i, h.section_count))?;
            let data_len = cur.u64().ok_or_else(|| table_end(i, h.section_count))?;
            let data = usize::try_from(data_len)
                .ok()
                .and_then(|l| cur.take(l))
                .ok_or_else(|| {
                    format!(
                        "section {} claims {data_len} bytes, more than the file holds",
                        i + 1
                    )
                })?;
            let stored_crc = cur.u32().ok_or_else(|| table_end(i, h.section_count))?;
            let crc = crc32fast::hash(&cur.bytes[start..cur.pos - 4]);
            let name = String::from_utf8_lossy(name).into_owned();
            if crc != stored_crc {
                return Err(format!(
                    "section '{name}' checksum mismatch (corrupt data in bytes {start}..{})",
                    cur.pos
                ));
            }
            sections.push((name, data));
        }
        if cur.pos != body_end {
            return Err(format!(
                "{} bytes between the last section and the file checksum",
                body_end - cur.pos
            ));
        }
        Ok(())
    })();
    match (walked, sha_ok) {
        (Err(reason), _) => return Err(reason),
        (Ok(()), false) => {
            return Err("file checksum (SHA-256) mismatch: corrupt data".to_string());
        }
        (Ok(()), true) => {}
    }

    let n = usize::try_from(h.header.particle_count)
        .map_err(|_| "corrupt header: particle count too large".to_string())?;
    let mut state_data: [Option<&[u8]>; 5] = [None; 5];
    let mut extra = BTreeMap::new();
    for (name, data) in sections {
        if name.is_empty() || name.len() > MAX_NAME_LEN {
            return Err(format!("invalid section name {name:?}"));
        }
        if let Some(k) = STATE_SECTIONS.iter().position(|s| *s == name) {
            if state_data[k].replace(data).is_some() {
                return Err(format!("duplicate section '{name}'"));
            }
        } else if extra.insert(name.clone(), data.to_vec()).is_some() {
            return Err(format!("duplicate section '{name}'"));
        }
    }
    let strides = STATE_STRIDES;
    let mut arrays: [&[u8]; 5] = [&[]; 5];
    for k in 0..5 {
        let data =
            state_data[k].ok_or_else(|| format!("missing section '{}'", STATE_SECTIONS[k]))?;
        if n.checked_mul(strides[k]) != Some(data.len()) {
            return Err(format!(
                "section '{}' has {} bytes, expected {} x {} for {n} particles",
                STATE_SECTIONS[k],
                data.len(),
                n,
                strides[k]
            ));
        }
        arrays[k] = data;
    }
    let state = ParticleState {
        pos: from_le_bytes(arrays[0]),
        vel: from_le_bytes(arrays[1]),
        thermo: from_le_bytes(arrays[2]),
        info: from_le_bytes(arrays[3]),
        density: from_le_bytes(arrays[4]),
    };
    Ok(Checkpoint {
        header: h.header,
        state,
        extra,
    })
}

fn table_end(i: u32, count: u32) -> String {
    format!(
        "section table ends early: section {} of {count} runs past the file checksum",
        i + 1
    )
}

fn invalid(path: &Path, reason: &str) -> Error {
    Error::InvalidInput(format!("{}: {reason}", path.display()))
}

struct DecodedHeader {
    header: CheckpointHeader,
    file_len: u64,
    section_count: u32,
}

/// Checks magic, version, header length and crc; returns the header and where sections start.
fn decode_header(bytes: &[u8]) -> std::result::Result<(DecodedHeader, usize), String> {
    if bytes.is_empty() {
        return Err("empty file (0 bytes)".into());
    }
    let m = bytes.len().min(MAGIC.len());
    if bytes[..m] != MAGIC[..m] {
        return Err(format!(
            "not a nimbus checkpoint: starts with \"{}\", not \"NIMBUSCK\"",
            bytes[..m].escape_ascii()
        ));
    }
    if bytes.len() < PRELUDE {
        return Err(format!(
            "truncated: {} bytes, shorter than the {PRELUDE}-byte prelude",
            bytes.len()
        ));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default());
    if version != FORMAT_VERSION {
        return Err(format!(
            "unsupported checkpoint format version {version} (this build reads version \
             {FORMAT_VERSION})"
        ));
    }
    let hlen = u32::from_le_bytes(bytes[12..16].try_into().unwrap_or_default()) as usize;
    if hlen > MAX_HEADER_LEN {
        return Err(format!(
            "corrupt header: header length {hlen} is implausible"
        ));
    }
    let header_end = PRELUDE + hlen + 4;
    if bytes.len() < header_end {
        return Err(format!(
            "truncated inside the header: {} bytes, the header needs {header_end}",
            bytes.len()
        ));
    }
    let stored = u32::from_le_bytes(
        bytes[header_end - 4..header_end]
            .try_into()
            .unwrap_or_default(),
    );
    if crc32fast::hash(&bytes[..header_end - 4]) != stored {
        return Err("header checksum mismatch: corrupt header".into());
    }
    let mut c = Cursor {
        bytes: &bytes[..header_end - 4],
        pos: PRELUDE,
    };
    let bad = || "corrupt header: fields do not fit its length".to_string();
    let file_len = c.u64().ok_or_else(bad)?;
    let tool_version = c.str().ok_or_else(bad)??;
    let sim_hash = c.str().ok_or_else(bad)??;
    let frame = c.u32().ok_or_else(bad)?;
    let step = c.u64().ok_or_else(bad)?;
    let time = f64::from_bits(c.u64().ok_or_else(bad)?);
    let seed = c.u64().ok_or_else(bad)?;
    let particle_count = c.u64().ok_or_else(bad)?;
    let capacity = c.u64().ok_or_else(bad)?;
    let adapter = c.str().ok_or_else(bad)??;
    let next_id = c.u32().ok_or_else(bad)?;
    let section_count = c.u32().ok_or_else(bad)?;
    if c.pos != c.bytes.len() {
        return Err("corrupt header: unexpected bytes at its end".into());
    }
    if particle_count > capacity {
        return Err(format!(
            "corrupt header: particle count {particle_count} exceeds capacity {capacity}"
        ));
    }
    Ok((
        DecodedHeader {
            header: CheckpointHeader {
                tool_version,
                sim_hash,
                frame,
                step,
                time,
                seed,
                particle_count,
                capacity,
                adapter,
                next_id,
            },
            file_len,
            section_count,
        },
        header_end,
    ))
}

/// Bounds-checked little-endian reader: every read returns `None` past the end.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }
    fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes(self.take(2)?.try_into().ok()?))
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    /// `None` past the end, `Some(Err)` for invalid UTF-8.
    fn str(&mut self) -> Option<std::result::Result<String, String>> {
        let n = self.u16()? as usize;
        let b = self.take(n)?;
        Some(
            String::from_utf8(b.to_vec())
                .map_err(|_| "corrupt header: a text field is not UTF-8".to_string()),
        )
    }
}
