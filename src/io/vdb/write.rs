//! OpenVDB writer, format 224 as OpenVDB 10 writes it (`io/Archive.cc`, `tree/RootNode.h`,
//! `InternalNode.h`, `LeafNode.h`, `io/Compression.h`), for `Tree_*_5_4_3` trees made of
//! leaves only (no active tiles).
//!
//! Per grid: descriptor (name, type, instance parent, three i64 offsets), compression flags,
//! metadata sorted by name, transform, topology (root -> 32^3 nodes -> 16^3 nodes -> leaf masks)
//! and buffers (per leaf: mask, then the active values as one compressed block, metadata byte 0
//! since every inactive value is the background). Leaf blocks are compressed in parallel, once.
use super::{
    blosc, Compression, GridData, MetaValue, VdbFile, VdbGrid, VdbOptions, COMPRESS_ACTIVE_MASK,
    COMPRESS_BLOSC, COMPRESS_ZIP, FILE_VERSION, LIBRARY_VERSION, MAGIC,
};
use crate::error::{Error, Result};
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use crate::io::atomic::write_atomic_buffered;
use rayon::prelude::*;
use sha2::{Digest, Sha256};
use std::io::Write;
use std::path::Path;

/// A voxel value type OpenVDB knows, stored as `COMPS` f32 (or half) components.
pub trait VdbValue: Copy + Send + Sync + PartialEq + std::fmt::Debug + 'static {
    /// Tree type name without `_HalfFloat`.
    const TREE_TYPE: &'static str;
    const COMPS: usize;
    fn comps(&self) -> [f32; 3];
    fn from_comps(c: [f32; 3]) -> Self;
    fn zero() -> Self;
}

impl VdbValue for f32 {
    const TREE_TYPE: &'static str = "Tree_float_5_4_3";
    const COMPS: usize = 1;
    fn comps(&self) -> [f32; 3] {
        [*self, 0.0, 0.0]
    }
    fn from_comps(c: [f32; 3]) -> Self {
        c[0]
    }
    fn zero() -> Self {
        0.0
    }
}

impl VdbValue for [f32; 3] {
    const TREE_TYPE: &'static str = "Tree_vec3s_5_4_3";
    const COMPS: usize = 3;
    fn comps(&self) -> [f32; 3] {
        *self
    }
    fn from_comps(c: [f32; 3]) -> Self {
        c
    }
    fn zero() -> Self {
        [0.0; 3]
    }
}

/// Appends a value as f32 components, or as half components.
#[inline]
fn put_value<T: VdbValue>(v: &T, half: bool, out: &mut Vec<u8>) {
    let c = v.comps();
    for x in &c[..T::COMPS] {
        if half {
            out.extend_from_slice(&half::f16::from_f32(*x).to_le_bytes());
        } else {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
}

/// A value rounded through half precision, kept as f32 (how OpenVDB writes the background of
/// half grids).
fn truncate_half<T: VdbValue>(v: &T) -> T {
    T::from_comps(v.comps().map(|x| half::f16::from_f32(x).to_f32()))
}

fn flags_for(opts: &VdbOptions) -> u32 {
    COMPRESS_ACTIVE_MASK
        | match opts.compression {
            Compression::None => 0,
            Compression::Zip => COMPRESS_ZIP,
            Compression::Blosc => COMPRESS_BLOSC,
        }
}

/// OpenVDB's `compressionToString`.
pub fn compression_name(flags: u32) -> String {
    if flags == 0 {
        return "none".into();
    }
    let mut w = Vec::new();
    if flags & COMPRESS_ZIP != 0 {
        w.push("zip");
    }
    if flags & COMPRESS_BLOSC != 0 {
        w.push("blosc");
    }
    if flags & COMPRESS_ACTIVE_MASK != 0 {
        w.push("active values");
    }
    w.join(" + ")
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_i64(out: &mut Vec<u8>, v: i64) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_str(out: &mut Vec<u8>, s: &str) {
    put_u32(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}
fn put_mask(out: &mut Vec<u8>, words: &[u64]) {
    for w in words {
        out.extend_from_slice(&w.to_le_bytes());
    }
}

fn meta_bytes(v: &MetaValue) -> Vec<u8> {
    let mut b = Vec::new();
    match v {
        MetaValue::String(s) => b.extend_from_slice(s.as_bytes()),
        MetaValue::Int32(x) => b.extend_from_slice(&x.to_le_bytes()),
        MetaValue::Int64(x) => b.extend_from_slice(&x.to_le_bytes()),
        MetaValue::Float(x) => b.extend_from_slice(&x.to_le_bytes()),
        MetaValue::Double(x) => b.extend_from_slice(&x.to_le_bytes()),
        MetaValue::Bool(x) => b.push(*x as u8),
        MetaValue::Vec3i(x) => x.iter().for_each(|c| b.extend_from_slice(&c.to_le_bytes())),
        MetaValue::Vec3d(x) => x.iter().for_each(|c| b.extend_from_slice(&c.to_le_bytes())),
    }
    b
}

/// OpenVDB `MetaMap::writeMeta`: count, then (name, type name, u32 size, bytes) sorted by name.
fn put_metadata(out: &mut Vec<u8>, entries: &[(String, MetaValue)]) {
    let mut map = std::collections::BTreeMap::new();
    for (k, v) in entries {
        map.insert(k.as_str(), v);
    }
    put_u32(out, map.len() as u32);
    for (k, v) in map {
        put_str(out, k);
        put_str(out, v.type_name());
        let b = meta_bytes(v);
        put_u32(out, b.len() as u32);
        out.extend_from_slice(&b);
    }
}

/// `Transform::write`: map type name, then the map. Voxel centres sit on integer index points,
/// so index (0,0,0) maps to `origin`: a uniform scale, plus a translation when `origin != 0`.
fn put_transform(out: &mut Vec<u8>, t: &GridTransform) {
    let s = t.voxel_size;
    let v = |out: &mut Vec<u8>, x: f64| {
        for _ in 0..3 {
            out.extend_from_slice(&x.to_le_bytes());
        }
    };
    if t.origin == [0.0; 3] {
        put_str(out, "UniformScaleMap");
    } else {
        put_str(out, "UniformScaleTranslateMap");
        t.origin
            .iter()
            .for_each(|c| out.extend_from_slice(&c.to_le_bytes()));
    }
    // ScaleMap: scale, voxel size, 1/scale, 1/scale^2, 1/(2 scale).
    v(out, s);
    v(out, s);
    v(out, 1.0 / s);
    v(out, 1.0 / (s * s));
    v(out, 0.5 / s);
}

/// Position of a leaf in OpenVDB's tree order: root key (origin & !4095, ordered as `Coord`),
/// child index in the 32^3 node, child index in the 16^3 node.
pub(crate) fn tree_key(o: [i32; 3]) -> ([i32; 3], u32, u32) {
    let root = o.map(|c| c & !4095);
    let n5 = (((o[0] & 4095) >> 7) << 10) | (((o[1] & 4095) >> 7) << 5) | ((o[2] & 4095) >> 7);
    let n4 = (((o[0] & 127) >> 3) << 8) | (((o[1] & 127) >> 3) << 4) | ((o[2] & 127) >> 3);
    (root, n5 as u32, n4 as u32)
}

/// Leaf indices in tree order; rejects origins off the 8-grid and duplicate leaves.
pub(crate) fn tree_order<T: VdbValue>(g: &SparseGrid<T>) -> Result<Vec<usize>> {
    if let Some(l) = g
        .leaves
        .iter()
        .find(|l| l.origin.iter().any(|c| c & 7 != 0))
    {
        return Err(Error::InvalidInput(format!(
            "grid '{}': leaf origin {:?} is not a multiple of 8",
            g.name, l.origin
        )));
    }
    let mut order: Vec<usize> = (0..g.leaves.len()).collect();
    order.sort_by_key(|&i| tree_key(g.leaves[i].origin));
    for w in order.windows(2) {
        if g.leaves[w[0]].origin == g.leaves[w[1]].origin {
            return Err(Error::InvalidInput(format!(
                "grid '{}': two leaves at {:?}",
                g.name, g.leaves[w[0]].origin
            )));
        }
    }
    Ok(order)
}

/// `io::writeData` for the stream's codec: a block of `bytes` (`typesize` for blosc shuffling).
fn put_data(out: &mut Vec<u8>, bytes: &[u8], typesize: usize, comp: Compression) {
    match comp {
        Compression::None => out.extend_from_slice(bytes),
        Compression::Zip => {
            // zipToStream: i64 size + zlib stream, or -size + raw bytes when it does not shrink.
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            let zipped = z
                .write_all(bytes)
                .and_then(|_| z.finish())
                .unwrap_or_default();
            if !zipped.is_empty() && zipped.len() < bytes.len() {
                put_i64(out, zipped.len() as i64);
                out.extend_from_slice(&zipped);
            } else {
                put_i64(out, -(bytes.len() as i64));
                out.extend_from_slice(bytes);
            }
        }
        Compression::Blosc => {
            let at = out.len();
            put_i64(out, 0);
            let n = blosc::compress(bytes, typesize, out);
            out[at..at + 8].copy_from_slice(&(n as i64).to_le_bytes());
        }
    }
}

/// A tile-value block of an internal node with no active tiles: metadata 0, zero values.
fn put_empty_values(out: &mut Vec<u8>, opts: &VdbOptions) {
    out.push(0);
    put_data(out, &[], if opts.half { 2 } else { 4 }, opts.compression);
}

/// `LeafNode::writeBuffers`: value mask, metadata byte 0, the active values compressed.
fn leaf_block<T: VdbValue>(leaf: &Leaf<T>, opts: &VdbOptions) -> Vec<u8> {
    let elem = if opts.half { 2 } else { 4 } * T::COMPS;
    let active = leaf.active_count() as usize;
    let mut vals = Vec::with_capacity(active * elem);
    for (w, &word) in leaf.mask.iter().enumerate() {
        let mut m = word;
        while m != 0 {
            let n = w * 64 + m.trailing_zeros() as usize;
            put_value(&leaf.values[n], opts.half, &mut vals);
            m &= m - 1;
        }
    }
    let mut out = Vec::with_capacity(64 + 1 + 8 + 16 + 4 * 4 + vals.len() + vals.len() / 8);
    put_mask(&mut out, &leaf.mask);
    out.push(0);
    put_data(
        &mut out,
        &vals,
        if opts.half { 2 } else { 4 },
        opts.compression,
    );
    out
}

/// Approximate in-memory size of the tree (OpenVDB's `file_mem_bytes` is informational).
fn mem_bytes<T: VdbValue>(leaves: usize, n4: usize, n5: usize) -> i64 {
    let v = std::mem::size_of::<T>();
    let leaf = LEAF_VOXELS * v + 64 + 12 + 16;
    let node4 = 4096 * v.max(8) + 2 * 512 + 12;
    let node5 = 32768 * v.max(8) + 2 * 4096 + 12;
    (leaves * leaf + n4 * node4 + n5 * node5 + 256) as i64
}

/// One encoded grid: its topology part (flags, metadata, transform, topology) and its buffer
/// blocks in tree order.
struct Encoded {
    name: String,
    type_name: String,
    head: Vec<u8>,
    blocks: Vec<Vec<u8>>,
    aliases: Vec<(String, Vec<u8>)>,
}

fn grid_metadata(
    name: &str,
    class: &str,
    vector_type: Option<&str>,
    stats: &[(String, MetaValue)],
    extra: &[(String, MetaValue)],
    half: bool,
) -> Vec<(String, MetaValue)> {
    let mut m: Vec<(String, MetaValue)> = stats.to_vec();
    m.extend_from_slice(extra);
    m.push(("class".into(), MetaValue::String(class.into())));
    m.push(("name".into(), MetaValue::String(name.into())));
    m.push(("is_saved_as_half_float".into(), MetaValue::Bool(half)));
    if let Some(vt) = vector_type {
        m.push(("vector_type".into(), MetaValue::String(vt.into())));
    }
    m
}

fn encode_grid<T: VdbValue>(
    g: &SparseGrid<T>,
    name: &str,
    aliases: &[String],
    class: &str,
    vector_type: Option<&str>,
    extra: &[(String, MetaValue)],
    opts: &VdbOptions,
) -> Result<Encoded> {
    if !(g.transform.voxel_size.is_finite() && g.transform.voxel_size > 0.0)
        || g.transform.origin.iter().any(|c| !c.is_finite())
    {
        return Err(Error::InvalidInput(format!(
            "grid '{name}': voxel size must be finite and positive and the origin finite"
        )));
    }
    let order = tree_order(g)?;
    let flags = flags_for(opts);

    // Topology.
    let mut topo = Vec::new();
    put_u32(&mut topo, 1); // buffer count
    let bg = if opts.half {
        truncate_half(&g.background)
    } else {
        g.background
    };
    put_value(&bg, false, &mut topo);
    let keys: Vec<_> = order
        .iter()
        .map(|&i| tree_key(g.leaves[i].origin))
        .collect();
    let mut roots: Vec<usize> = Vec::new(); // start index (in `order`) of each root child
    let mut n5_count = 0;
    let mut n4_count = 0;
    for (i, k) in keys.iter().enumerate() {
        if i == 0 || keys[i - 1].0 != k.0 {
            roots.push(i);
        }
    }
    put_u32(&mut topo, 0); // tiles
    put_u32(&mut topo, roots.len() as u32);
    for (r, &start) in roots.iter().enumerate() {
        let end = roots.get(r + 1).copied().unwrap_or(keys.len());
        let root = keys[start].0;
        root.iter()
            .for_each(|c| topo.extend_from_slice(&c.to_le_bytes()));
        n5_count += 1;
        let mut child5 = vec![0u64; 512];
        for k in &keys[start..end] {
            child5[(k.1 / 64) as usize] |= 1 << (k.1 % 64);
        }
        put_mask(&mut topo, &child5);
        put_mask(&mut topo, &[0u64; 512]);
        put_empty_values(&mut topo, opts);
        let mut i = start;
        while i < end {
            let n5 = keys[i].1;
            let mut j = i;
            let mut child4 = [0u64; 64];
            while j < end && keys[j].1 == n5 {
                child4[(keys[j].2 / 64) as usize] |= 1 << (keys[j].2 % 64);
                j += 1;
            }
            n4_count += 1;
            put_mask(&mut topo, &child4);
            put_mask(&mut topo, &[0u64; 64]);
            put_empty_values(&mut topo, opts);
            for &li in &order[i..j] {
                put_mask(&mut topo, &g.leaves[li].mask);
            }
            i = j;
        }
    }

    let blocks: Vec<Vec<u8>> = order
        .par_iter()
        .map(|&i| leaf_block(&g.leaves[i], opts))
        .collect();

    let (stats, count) = {
        let count = g.active_voxel_count() as i64;
        let (lo, hi) = g.active_bbox().unwrap_or(([i32::MAX; 3], [i32::MIN; 3]));
        (
            vec![
                ("file_bbox_min".to_string(), MetaValue::Vec3i(lo)),
                ("file_bbox_max".to_string(), MetaValue::Vec3i(hi)),
                (
                    "file_compression".to_string(),
                    MetaValue::String(compression_name(flags)),
                ),
                (
                    "file_mem_bytes".to_string(),
                    MetaValue::Int64(mem_bytes::<T>(g.leaves.len(), n4_count, n5_count)),
                ),
                ("file_voxel_count".to_string(), MetaValue::Int64(0)),
            ],
            count,
        )
    };
    let mut stats = stats;
    stats[4].1 = MetaValue::Int64(count);

    let head_for = |n: &str, with_topology: bool| {
        let mut h = Vec::new();
        put_u32(&mut h, flags);
        // Instances carry the grid's own metadata only, as `Archive::writeGridInstance`.
        let st: &[(String, MetaValue)] = if with_topology { &stats } else { &[] };
        put_metadata(
            &mut h,
            &grid_metadata(n, class, vector_type, st, extra, opts.half),
        );
        put_transform(&mut h, &g.transform);
        if with_topology {
            h.extend_from_slice(&topo);
        }
        h
    };
    let type_name = if opts.half {
        format!("{}_HalfFloat", T::TREE_TYPE)
    } else {
        T::TREE_TYPE.to_string()
    };
    Ok(Encoded {
        name: name.to_string(),
        type_name,
        head: head_for(name, true),
        blocks,
        aliases: aliases
            .iter()
            .map(|a| (a.clone(), head_for(a, false)))
            .collect(),
    })
}

/// A file ready to be written: byte chunks in order (the leaf blocks are not copied again).
pub struct EncodedFile {
    chunks: Vec<Vec<u8>>,
    blocks: Vec<Vec<Vec<u8>>>,
    /// Where each grid's blocks go: after chunk `i` of `chunks`.
    block_after: Vec<usize>,
    pub len: u64,
}

impl EncodedFile {
    fn write_to(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let mut g = 0;
        for (i, c) in self.chunks.iter().enumerate() {
            w.write_all(c)?;
            while g < self.block_after.len() && self.block_after[g] == i {
                for b in &self.blocks[g] {
                    w.write_all(b)?;
                }
                g += 1;
            }
        }
        Ok(())
    }
    /// The whole file as one buffer.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.len as usize);
        self.write_to(&mut v).expect("writing to a Vec cannot fail");
        v
    }
}

/// Encodes a file (leaves compressed in parallel). Grid names must be unique, including aliases.
pub fn encode(file: &VdbFile, opts: &VdbOptions) -> Result<EncodedFile> {
    let mut names = std::collections::BTreeSet::new();
    for g in &file.grids {
        for n in std::iter::once(&g.name).chain(&g.aliases) {
            if n.is_empty() || !names.insert(n.as_str()) {
                return Err(Error::InvalidInput(format!(
                    "VDB grid name '{n}' is empty or used twice"
                )));
            }
        }
    }
    let grids: Vec<Encoded> = file
        .grids
        .iter()
        .map(|g: &VdbGrid| match &g.data {
            GridData::Float(s) => {
                encode_grid(s, &g.name, &g.aliases, g.class, None, &g.metadata, opts)
            }
            GridData::Vec3(s) => encode_grid(
                s,
                &g.name,
                &g.aliases,
                g.class,
                Some("contravariant relative"),
                &g.metadata,
                opts,
            ),
        })
        .collect::<Result<_>>()?;

    // The UUID is derived from the content (no randomness): a hash of the metadata, topology
    // and a CRC of each leaf block.
    let mut hasher = Sha256::new();
    let mut fmeta = Vec::new();
    put_metadata(&mut fmeta, &file.metadata);
    hasher.update(&fmeta);
    for e in &grids {
        hasher.update(e.name.as_bytes());
        hasher.update(&e.head);
        let crcs: Vec<u8> = e
            .blocks
            .par_iter()
            .flat_map_iter(|b| crc32fast::hash(b).to_le_bytes())
            .collect();
        hasher.update(&crcs);
        for (a, h) in &e.aliases {
            hasher.update(a.as_bytes());
            hasher.update(h);
        }
    }
    let d = hasher.finalize();
    let hex: String = d[..16].iter().map(|b| format!("{b:02x}")).collect();
    let uuid = format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    );

    let mut head = Vec::new();
    put_i64(&mut head, MAGIC);
    put_u32(&mut head, FILE_VERSION);
    put_u32(&mut head, LIBRARY_VERSION.0);
    put_u32(&mut head, LIBRARY_VERSION.1);
    head.push(1); // grid offsets follow each descriptor
    head.extend_from_slice(uuid.as_bytes());
    head.extend_from_slice(&fmeta);
    let count: usize = grids.iter().map(|e| 1 + e.aliases.len()).sum();
    put_u32(&mut head, count as u32);

    let mut chunks = vec![head];
    let mut pos = chunks[0].len() as u64;
    let mut blocks = Vec::new();
    let mut block_after = Vec::new();
    for e in grids {
        // Descriptor: unique name, type, instance parent, then grid/block/end positions.
        let mut d = Vec::new();
        put_str(&mut d, &e.name);
        put_str(&mut d, &e.type_name);
        put_str(&mut d, "");
        let grid_pos = pos + d.len() as u64 + 24;
        let block_pos = grid_pos + e.head.len() as u64;
        let blocks_len: u64 = e.blocks.iter().map(|b| b.len() as u64).sum();
        let end_pos = block_pos + blocks_len;
        put_i64(&mut d, grid_pos as i64);
        put_i64(&mut d, block_pos as i64);
        put_i64(&mut d, end_pos as i64);
        d.extend_from_slice(&e.head);
        pos = end_pos;
        chunks.push(d);
        block_after.push(chunks.len() - 1);
        blocks.push(e.blocks);
        for (alias, h) in e.aliases {
            let mut d = Vec::new();
            put_str(&mut d, &alias);
            put_str(&mut d, &e.type_name);
            put_str(&mut d, &e.name);
            let grid_pos = pos + d.len() as u64 + 24;
            let end_pos = grid_pos + h.len() as u64;
            put_i64(&mut d, grid_pos as i64);
            put_i64(&mut d, 0); // OpenVDB leaves an instance's block position unset
            put_i64(&mut d, end_pos as i64);
            d.extend_from_slice(&h);
            pos = end_pos;
            chunks.push(d);
        }
    }
    Ok(EncodedFile {
        chunks,
        blocks,
        block_after,
        len: pos,
    })
}

/// Writes a VDB file atomically; returns its size in bytes.
pub fn write_file(path: &Path, file: &VdbFile, opts: &VdbOptions) -> Result<u64> {
    let enc = encode(file, opts)?;
    write_atomic_buffered(path, |w| enc.write_to(w))?;
    Ok(enc.len)
}
