//! `nimbus inspect FILE`: a human-readable description of a file nimbus writes, chosen by its
//! magic bytes (checkpoint, VDB, NanoVDB, EXR; other formats register here as they are added).
use crate::error::{Error, Result};
use crate::ground::SparseGrid;
use crate::io::checkpoint::{self, format};
use crate::io::vdb::{self, GridData};
use std::fmt::Write as _;
use std::io::Read;
use std::path::Path;

const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

/// Statistics of the active values of a grid (f64 sums, in leaf order: deterministic).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stats {
    pub active: u64,
    pub min: f64,
    pub max: f64,
    pub sum: f64,
}

/// Active-value statistics; for vectors, of the vector length.
pub fn stats<T: Copy>(g: &SparseGrid<T>, scalar: impl Fn(&T) -> f64) -> Stats {
    let mut s = Stats {
        active: 0,
        min: f64::INFINITY,
        max: f64::NEG_INFINITY,
        sum: 0.0,
    };
    for leaf in &g.leaves {
        for n in (0..crate::ground::LEAF_VOXELS).filter(|&n| leaf.is_active(n)) {
            let v = scalar(&leaf.values[n]);
            s.active += 1;
            s.min = s.min.min(v);
            s.max = s.max.max(v);
            s.sum += v;
        }
    }
    s
}

fn describe_grid<T: Copy>(out: &mut String, g: &SparseGrid<T>, f: impl Fn(&T) -> f64, what: &str) {
    let s = stats(g, f);
    let t = g.transform;
    let _ = writeln!(
        out,
        "  voxel size: {}  origin: {:?}",
        t.voxel_size, t.origin
    );
    let _ = writeln!(
        out,
        "  leaves: {}  active voxels: {}",
        g.leaves.len(),
        s.active
    );
    match g.active_bbox() {
        Some((lo, hi)) => {
            let _ = writeln!(out, "  bbox: {lo:?} .. {hi:?}");
            let _ = writeln!(
                out,
                "  {what}: min {:.6e}  max {:.6e}  sum {:.9e}",
                s.min, s.max, s.sum
            );
        }
        None => {
            let _ = writeln!(out, "  bbox: empty");
        }
    }
}

fn describe_vdb(path: &Path) -> Result<String> {
    let f = vdb::read_file(path)?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: OpenVDB file format {} (library {}.{}), uuid {}",
        path.display(),
        f.version,
        f.library.0,
        f.library.1,
        f.uuid
    );
    for (k, v) in &f.metadata {
        let _ = writeln!(out, "  {k}: {v}");
    }
    for g in &f.grids {
        let class = g
            .meta("class")
            .map(|v| v.to_string())
            .unwrap_or_else(|| "unknown".into());
        let _ = write!(out, "grid '{}': {} class '{class}'", g.name, g.type_name);
        if let Some(p) = &g.instance_parent {
            let _ = write!(out, " (instance of '{p}')");
        }
        let _ = writeln!(
            out,
            " compression '{}'",
            vdb::write::compression_name(g.compression)
        );
        match &g.data {
            GridData::Float(s) => describe_grid(&mut out, s, |v| *v as f64, "value"),
            GridData::Vec3(s) => describe_grid(&mut out, s, length, "|value|"),
        }
        if !g.tiles.is_empty() {
            let active: Vec<_> = g.tiles.iter().filter(|t| t.active).collect();
            let _ = writeln!(
                out,
                "  tiles: {} ({} active, {} active voxels in them)",
                g.tiles.len(),
                active.len(),
                active.iter().map(|t| t.voxels()).sum::<u64>()
            );
        }
    }
    for (name, ty) in &f.skipped {
        let _ = writeln!(
            out,
            "grid '{name}': {ty} (not read: nimbus reads float and vec3s grids)"
        );
    }
    Ok(out)
}

fn describe_exr(path: &Path) -> Result<String> {
    let meta = exr::meta::MetaData::read_from_file(path, false)
        .map_err(|e| Error::InvalidInput(format!("{}: not a readable EXR: {e}", path.display())))?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: OpenEXR, {} part(s)",
        path.display(),
        meta.headers.len()
    );
    for h in meta.headers.iter() {
        let _ = writeln!(
            out,
            "  size {}x{}  compression {:?}  line order {:?}",
            h.layer_size.width(),
            h.layer_size.height(),
            h.compression,
            h.line_order
        );
        let names: Vec<String> = h
            .channels
            .list
            .iter()
            .map(|c| format!("{} ({:?})", c.name, c.sample_type))
            .collect();
        let _ = writeln!(out, "  channels: {}", names.join(", "));
        let mut attrs: Vec<_> = h
            .own_attributes
            .other
            .iter()
            .chain(h.shared_attributes.other.iter())
            .collect();
        attrs.sort_by_key(|a| a.0.to_string());
        for (k, v) in attrs {
            let _ = writeln!(out, "  {k}: {v:?}");
        }
    }
    Ok(out)
}

/// Describes a checkpoint, VDB or EXR file, the describer chosen by the file's first bytes (for
/// `nimbus inspect FILE`). A directory, FIFO or device is invalid input, and is never read.
pub fn describe(path: &Path) -> Result<String> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_file() => {}
        Ok(m) => {
            return Err(Error::InvalidInput(format!(
                "{}: {}, not a .vdb, .nvdb, .exr or checkpoint file",
                path.display(),
                if m.is_dir() {
                    "is a directory"
                } else {
                    "is not a regular file"
                }
            )))
        }
        Err(e) => return Err(Error::InvalidInput(format!("{}: {e}", path.display()))),
    }
    let f = std::fs::File::open(path)
        .map_err(|e| Error::InvalidInput(format!("{}: {e}", path.display())))?;
    let mut head = Vec::with_capacity(8);
    f.take(8)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, e))?;
    if checkpoint::is_checkpoint(&head) {
        describe_checkpoint(path)
    } else if head == vdb::MAGIC.to_le_bytes() {
        describe_vdb(path)
    } else if head.starts_with(&EXR_MAGIC) {
        describe_exr(path)
    } else if head == crate::io::nanovdb::MAGIC.to_le_bytes() {
        describe_nanovdb(path)
    } else {
        Err(Error::InvalidInput(format!(
            "{}: not a file nimbus knows (neither OpenVDB, NanoVDB nor OpenEXR)",
            path.display()
        )))
    }
}

/// A vector's length (what `inspect` reports of vector grids).
fn length(v: &[f32; 3]) -> f64 {
    v.iter()
        .map(|&c| (c as f64) * (c as f64))
        .sum::<f64>()
        .sqrt()
}

/// A NanoVDB file nimbus wrote: each grid's type, class, transform, active voxels, bbox, size,
/// checksum and value statistics (decoded values for the quantised types).
fn describe_nanovdb(path: &Path) -> Result<String> {
    use crate::io::nanovdb::{read_file, Leaves};
    let grids = read_file(path)?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: NanoVDB 32.4 file, {} grid(s)",
        path.display(),
        grids.len()
    );
    for g in &grids {
        let class = match g.class {
            2 => "fog volume",
            1 => "level set",
            _ => "unknown",
        };
        let _ = writeln!(
            out,
            "grid '{}': {} class '{class}', {} bytes, checksum {}",
            g.name,
            g.grid_type.name(),
            g.bytes,
            if g.checksum_ok { "ok" } else { "MISMATCH" }
        );
        let t = crate::ground::GridTransform {
            voxel_size: g.voxel_size,
            origin: g.origin,
        };
        match &g.leaves {
            Leaves::Float(l) => {
                describe_grid(&mut out, &as_grid(l, t, 0.0), |v| *v as f64, "value")
            }
            Leaves::Vec3(l) => describe_grid(&mut out, &as_grid(l, t, [0.0; 3]), length, "|value|"),
        }
    }
    Ok(out)
}

fn as_grid<T: Copy>(
    leaves: &[crate::ground::Leaf<T>],
    transform: crate::ground::GridTransform,
    background: T,
) -> SparseGrid<T> {
    SparseGrid {
        name: String::new(),
        background,
        transform,
        leaves: leaves.to_vec(),
    }
}

/// Validates the checkpoint at `path` and describes it.
fn describe_checkpoint(path: &Path) -> Result<String> {
    let (bytes, ck) = format::read_with_bytes(path)?;
    let h = &ck.header;
    let mut s = String::new();
    let _ = writeln!(s, "nimbus checkpoint {}", path.display());
    let _ = writeln!(s, "  format version   {}", format::FORMAT_VERSION);
    let _ = writeln!(s, "  tool version     {}", h.tool_version);
    let _ = writeln!(s, "  sim config hash  {}", h.sim_hash);
    let _ = writeln!(s, "  frame            {}", h.frame);
    let _ = writeln!(s, "  step             {}", h.step);
    let _ = writeln!(s, "  sim time         {} s", h.time);
    let _ = writeln!(s, "  seed             {}", h.seed);
    let _ = writeln!(s, "  particles        {}", h.particle_count);
    let _ = writeln!(s, "  capacity         {}", h.capacity);
    let _ = writeln!(s, "  adapter          {}", h.adapter);
    let _ = writeln!(s, "  next id          {}", h.next_id);
    let _ = writeln!(
        s,
        "  size             {} bytes ({:.1} bytes/particle)",
        bytes.len(),
        bytes.len() as f64 / (h.particle_count.max(1)) as f64
    );
    let array_bytes = |k: usize| h.particle_count * format::STATE_STRIDES[k] as u64;
    let mut names: Vec<String> = format::STATE_SECTIONS
        .iter()
        .enumerate()
        .map(|(k, n)| format!("{n} ({} B)", array_bytes(k)))
        .collect();
    names.extend(ck.extra.iter().map(|(n, d)| format!("{n} ({} B)", d.len())));
    let _ = writeln!(s, "  sections         {}", names.join(", "));
    let digest = &bytes[bytes.len() - format::TRAILER..];
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    let _ = write!(s, "  checksums        ok (sha256 {hex})");
    Ok(s)
}
