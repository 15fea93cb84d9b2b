//! The NanoVDB writer: a grid's buffer built directly from a `SparseGrid` (no OpenVDB tree in
//! between), the statistics of `util/GridStats.h` ("all" mode), the checksum of
//! `util/GridChecksum.h` ("full" mode) and the file of `util/IO.h` (codec NONE).
//!
//! The layout, values, quantisation and statistics are those `nanovdb_convert` writes for the
//! same grid read from nimbus's VDB file: leaves in OpenVDB's order, inactive voxels at the
//! background, the same per-leaf quantiser (no dithering), the same floating-point operations in
//! the same order. Leaves are encoded in parallel; the upper levels merge their children's
//! statistics in child order, so the bytes depend on the grid alone.
use super::layout::{self as l, Value};
use super::{GridClass, GridType, Quantise, MAGIC, MAX_NAME_BYTES, VERSION};
use crate::error::{Error, Result};
use crate::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use crate::io::atomic::write_atomic_buffered;
use crate::io::vdb::write::{tree_key, tree_order};
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// One grid of a NanoVDB file.
#[derive(Debug, Clone)]
pub struct NanoGrid<'a> {
    pub name: String,
    pub class: GridClass,
    pub values: NanoValues<'a>,
}

#[derive(Debug, Clone, Copy)]
pub enum NanoValues<'a> {
    /// A float grid, stored as float or quantised.
    Float(&'a SparseGrid<f32>, Quantise),
    /// A vector grid (NanoVDB has no quantised vector type).
    Vec3(&'a SparseGrid<[f32; 3]>),
}

impl NanoGrid<'_> {
    pub fn grid_type(&self) -> GridType {
        match self.values {
            NanoValues::Float(_, q) => match q {
                Quantise::Float => GridType::Float,
                Quantise::Fp4 => GridType::Fp4,
                Quantise::Fp8 => GridType::Fp8,
                Quantise::Fp16 => GridType::Fp16,
                Quantise::FpN { .. } => GridType::FpN,
            },
            NanoValues::Vec3(_) => GridType::Vec3f,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Little-endian stores into the buffer.

fn put_u16(b: &mut [u8], at: usize, v: u16) {
    b[at..at + 2].copy_from_slice(&v.to_le_bytes());
}
fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
fn put_i64(b: &mut [u8], at: usize, v: i64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
fn put_f32(b: &mut [u8], at: usize, v: f32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
fn put_f64(b: &mut [u8], at: usize, v: f64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
fn put_coord(b: &mut [u8], at: usize, c: [i32; 3]) {
    for (i, x) in c.iter().enumerate() {
        b[at + 4 * i..at + 4 * i + 4].copy_from_slice(&x.to_le_bytes());
    }
}
fn put_mask(b: &mut [u8], at: usize, words: &[u64]) {
    for (i, w) in words.iter().enumerate() {
        put_u64(b, at + 8 * i, *w);
    }
}

/// C's float-to-integer conversion as x86-64 compilers emit it (`cvttss2si`/`cvttsd2si` into a
/// 32-bit register, then the low bits): truncation toward zero, and `i32::MIN` for NaN and
/// values out of range. The quantiser's codes go through it, as in `nanovdb_convert`.
fn c_trunc(x: f64) -> i32 {
    if !(-2_147_483_648.0..2_147_483_648.0).contains(&x) {
        i32::MIN
    } else {
        x as i32
    }
}

// ---------------------------------------------------------------------------------------------
// Values and statistics (`GridStats.h`'s `Stats`: extrema and Welford's running mean and
// variance in double precision).

/// A voxel value of a NanoVDB tree: float or Vec3f.
trait NanoValue: Copy + Send + Sync + PartialEq + 'static {
    const KIND: Value;
    /// What the statistics order and average: the value (float) or its squared length (Vec3f,
    /// `Vec3f::lengthSqr` in float, left to right).
    fn scalar(&self) -> f32;
    fn put(&self, b: &mut [u8], at: usize);
    /// All bytes zero (what the buffer starts as).
    fn zero_bits(&self) -> bool;
    /// `Extrema`'s initial minimum and maximum.
    fn init_min() -> Self;
    fn init_max() -> Self;
}

impl NanoValue for f32 {
    const KIND: Value = Value::Float;
    fn scalar(&self) -> f32 {
        *self
    }
    fn put(&self, b: &mut [u8], at: usize) {
        put_f32(b, at, *self);
    }
    fn zero_bits(&self) -> bool {
        self.to_bits() == 0
    }
    fn init_min() -> Self {
        f32::MAX
    }
    fn init_max() -> Self {
        f32::MIN
    }
}

impl NanoValue for [f32; 3] {
    const KIND: Value = Value::Vec3f;
    fn scalar(&self) -> f32 {
        self[0] * self[0] + self[1] * self[1] + self[2] * self[2]
    }
    fn put(&self, b: &mut [u8], at: usize) {
        for (i, x) in self.iter().enumerate() {
            put_f32(b, at + 4 * i, *x);
        }
    }
    fn zero_bits(&self) -> bool {
        self.iter().all(|x| x.to_bits() == 0)
    }
    fn init_min() -> Self {
        [f32::MAX; 3]
    }
    fn init_max() -> Self {
        [f32::MIN; 3]
    }
}

/// Statistics of active values and their index bounding box (`GridStats::NodeStats`).
#[derive(Debug, Clone, Copy)]
struct NodeStats<T> {
    min: (f32, T),
    max: (f32, T),
    /// The count, as a float (exact below 2^53; NanoVDB converts its integer count each time).
    size: f64,
    avg: f64,
    aux: f64,
    bbox: ([i32; 3], [i32; 3]),
}

const EMPTY_BBOX: ([i32; 3], [i32; 3]) = ([i32::MAX; 3], [i32::MIN; 3]);

impl<T: NanoValue> NodeStats<T> {
    fn new() -> Self {
        let (lo, hi) = (T::init_min(), T::init_max());
        NodeStats {
            // `Extrema`'s initial pairs: the scalar is the limit itself (not a squared length).
            min: (f32::MAX, lo),
            max: (f32::MIN, hi),
            size: 0.0,
            avg: 0.0,
            aux: 0.0,
            bbox: EMPTY_BBOX,
        }
    }

    fn add(&mut self, v: T) {
        let s = v.scalar();
        if s < self.min.0 {
            self.min = (s, v);
        }
        if self.max.0 < s {
            self.max = (s, v);
        }
        self.size += 1.0;
        let delta = s as f64 - self.avg;
        self.avg += delta / self.size;
        self.aux += delta * (s as f64 - self.avg);
    }

    fn merge(&mut self, o: &Self) {
        if o.size > 0.0 {
            let denom = 1.0 / (self.size + o.size);
            let delta = o.avg - self.avg;
            self.avg += denom * delta * o.size;
            self.aux += o.aux + denom * delta * delta * self.size * o.size;
            if o.min.0 < self.min.0 {
                self.min = o.min;
            }
            if self.max.0 < o.max.0 {
                self.max = o.max;
            }
            self.size += o.size;
        }
        for a in 0..3 {
            self.bbox.0[a] = self.bbox.0[a].min(o.bbox.0[a]);
            self.bbox.1[a] = self.bbox.1[a].max(o.bbox.1[a]);
        }
    }

    fn std(&self) -> f64 {
        if self.size < 2.0 {
            0.0
        } else {
            (self.aux / self.size).sqrt()
        }
    }

    fn empty_bbox(&self) -> bool {
        (0..3).any(|a| self.bbox.0[a] > self.bbox.1[a])
    }

    /// Writes min, max (values), average and standard deviation (float) at the given offsets.
    fn put(&self, b: &mut [u8], at: [usize; 4]) {
        self.min.1.put(b, at[0]);
        self.max.1.put(b, at[1]);
        put_f32(b, at[2], self.avg as f32);
        put_f32(b, at[3], self.std() as f32);
    }
}

// ---------------------------------------------------------------------------------------------
// Leaves.

/// The 512 values of a leaf as OpenVDB holds them after reading nimbus's VDB file: active
/// values, and the background elsewhere.
fn leaf_values<T: Copy>(leaf: &Leaf<T>, background: T) -> [T; LEAF_VOXELS] {
    let mut v = [background; LEAF_VOXELS];
    for (w, &word) in leaf.mask.iter().enumerate() {
        let mut m = word;
        while m != 0 {
            let n = w * 64 + m.trailing_zeros() as usize;
            v[n] = leaf.values[n];
            m &= m - 1;
        }
    }
    v
}

fn active(mask: &[u64; 8]) -> impl Iterator<Item = usize> + '_ {
    mask.iter().enumerate().flat_map(|(w, &word)| {
        let mut m = word;
        std::iter::from_fn(move || {
            (m != 0).then(|| {
                let n = w * 64 + m.trailing_zeros() as usize;
                m &= m - 1;
                n
            })
        })
    })
}

/// `LeafNode::updateBBox`: the active voxels' bbox (minimum, and extent - 1 per axis) from the
/// mask's words (x), their union's bits (y) and bytes (z); flag bit 1. Returns the bbox, empty
/// when no voxel is active.
fn put_leaf_head(
    b: &mut [u8],
    leaf_origin: [i32; 3],
    mask: &[u64; 8],
    flags: u8,
) -> ([i32; 3], [i32; 3]) {
    put_mask(b, l::LEAF_MASK, mask);
    let union = mask.iter().fold(0u64, |a, w| a | w);
    if union == 0 {
        put_coord(b, l::LEAF_BBOX_MIN, leaf_origin);
        b[l::LEAF_FLAGS] = flags;
        return EMPTY_BBOX;
    }
    let x0 = mask.iter().position(|&w| w != 0).unwrap_or(0) as i32;
    let x1 = mask.iter().rposition(|&w| w != 0).unwrap_or(0) as i32;
    let y0 = (union.trailing_zeros() >> 3) as i32;
    let y1 = ((63 - union.leading_zeros()) >> 3) as i32;
    let bytes = union.to_le_bytes().iter().fold(0u8, |a, &x| a | x);
    let z0 = bytes.trailing_zeros() as i32;
    let z1 = 7 - bytes.leading_zeros() as i32;
    let (lo, hi) = ([x0, y0, z0], [x1, y1, z1]);
    let min = [0, 1, 2].map(|a| leaf_origin[a] + lo[a]);
    put_coord(b, l::LEAF_BBOX_MIN, min);
    for a in 0..3 {
        b[l::LEAF_BBOX_DIF + a] = (hi[a] - lo[a]) as u8;
    }
    b[l::LEAF_FLAGS] = flags | 2;
    (min, [0, 1, 2].map(|a| leaf_origin[a] + hi[a]))
}

/// A leaf's active values in voxel order, as its statistics read them (the values, or the
/// quantised leaves' decoded values).
struct Active<T> {
    vals: [T; LEAF_VOXELS],
    len: usize,
}

impl<T: NanoValue> Active<T> {
    fn new() -> Self {
        Active {
            vals: [T::init_min(); LEAF_VOXELS],
            len: 0,
        }
    }
}

/// The statistics of several leaves' active values, each leaf's in its own order (so each
/// result is what one leaf alone gives, bit for bit), interleaved so that the divisions of
/// Welford's updates of different leaves overlap instead of waiting on each other.
fn leaf_stats<T: NanoValue>(act: &[Active<T>], out: &mut [NodeStats<T>]) {
    let longest = act.iter().map(|a| a.len).max().unwrap_or(0);
    for i in 0..longest {
        for (a, s) in act.iter().zip(out.iter_mut()) {
            if i < a.len {
                s.add(a.vals[i]);
            }
        }
    }
}

/// A float or Vec3f leaf: head and the 512 values (the background where inactive: the buffer
/// starts zeroed, so only a non-zero background is written); the active values go to `act`.
/// Returns the active bbox.
fn fill_plain_leaf<T: NanoValue>(
    b: &mut [u8],
    leaf: &Leaf<T>,
    background: T,
    act: &mut Active<T>,
) -> ([i32; 3], [i32; 3]) {
    let lay = l::leaf(T::KIND);
    let bbox = put_leaf_head(b, leaf.origin, &leaf.mask, 0);
    let w = T::KIND.bytes();
    let vals = &mut b[lay.values..lay.values + LEAF_VOXELS * w];
    if !background.zero_bits() {
        for slot in vals.chunks_exact_mut(w) {
            background.put(slot, 0);
        }
    }
    let mut len = 0;
    for (i, &word) in leaf.mask.iter().enumerate() {
        let mut m = word;
        while m != 0 {
            let n = i * 64 + m.trailing_zeros() as usize;
            let v = leaf.values[n];
            v.put(&mut vals[n * w..n * w + w], 0);
            act.vals[len] = v;
            len += 1;
            m &= m - 1;
        }
    }
    act.len = len;
    bbox
}

/// A plain leaf's statistics: min, max, average, standard deviation.
fn put_plain_stats<T: NanoValue>(b: &mut [u8], s: &NodeStats<T>) {
    let lay = l::leaf(T::KIND);
    s.put(b, [lay.min, lay.max, lay.avg, lay.dev]);
}

/// Minimum and maximum of all 512 values (`nanovdb_convert`'s quantisation range).
fn range(values: &[f32; LEAF_VOXELS]) -> (f32, f32) {
    let (mut min, mut max) = (f32::MAX, -f32::MAX);
    for &v in values {
        if v < min {
            min = v;
        }
        if v > max {
            max = v;
        }
    }
    (min, max)
}

/// FpN's bit width for a leaf, as log2 (0..=4 for 1..16 bits): the fewest bits whose codes
/// decode every one of the 512 values within `tolerance` (the `AbsDiff` oracle).
fn fpn_log2(values: &[f32; LEAF_VOXELS], tolerance: f32) -> u32 {
    let (min, max) = range(values);
    let range = max - min;
    let mut log2 = 0;
    while range > 0.0 && log2 < 4 {
        let mask = (1u32 << (1u32 << log2)) - 1;
        let encode = mask as f32 / range;
        let decode = range / mask as f32;
        let ok = values.iter().all(|&exact| {
            let code = c_trunc((encode * (exact - min) + 0.5) as f64) as u32;
            let approx = code as f32 * decode + min;
            (exact - approx).abs() <= tolerance
        });
        if ok {
            break;
        }
        log2 += 1;
    }
    log2
}

/// The codes of 512 values at `bits` bits each, packed as NanoVDB reads them (value i at bit
/// `(i % (8 / bits)) * bits` of byte `i * bits / 8`; 16 bits as u16).
fn put_codes(b: &mut [u8], at: usize, values: &[f32; LEAF_VOXELS], min: f32, max: f32, bits: u32) {
    if bits == 16 {
        // 16-bit codes need double precision (as in NanoVDB).
        let encode = 65535.0 / (max - min) as f64;
        for (i, &v) in values.iter().enumerate() {
            let c = c_trunc(encode * (v - min) as f64 + 0.5) as u16;
            put_u16(b, at + 2 * i, c);
        }
        return;
    }
    let encode = ((1u32 << bits) - 1) as f32 / (max - min);
    let code = |v: f32| c_trunc((encode * (v - min) + 0.5) as f64) as u32;
    let per_byte = 8 / bits as usize;
    for (j, chunk) in values.chunks(per_byte).enumerate() {
        let mut byte = 0u32;
        for (k, &v) in chunk.iter().enumerate() {
            byte |= code(v) << (k as u32 * bits);
        }
        b[at + j] = byte as u8;
    }
}

/// A quantised leaf (Fp4, Fp8, Fp16 or FpN of `bits` bits): head, minimum and quantum, and the
/// codes between the minimum and maximum of all 512 values; the active values decoded go to
/// `act`. Returns the active bbox.
fn fill_fn_leaf(
    b: &mut [u8],
    leaf: &Leaf<f32>,
    background: f32,
    bits: u32,
    fpn_log2: Option<u32>,
    act: &mut Active<f32>,
) -> ([i32; 3], [i32; 3]) {
    let values = leaf_values(leaf, background);
    let (min, max) = range(&values);
    let quantum = (max - min) / ((1u32 << bits) - 1) as f32;
    let flags = fpn_log2.map_or(0, |lg| (lg as u8) << 5);
    let bbox = put_leaf_head(b, leaf.origin, &leaf.mask, flags);
    put_f32(b, l::FN_MINIMUM, min);
    put_f32(b, l::FN_QUANTUM, quantum);
    put_codes(b, l::FN_CODES, &values, min, max, bits);
    let mut len = 0;
    for n in active(&leaf.mask) {
        act.vals[len] = code_at(b, n, bits) as f32 * quantum + min;
        len += 1;
    }
    act.len = len;
    bbox
}

/// A quantised leaf's statistics of its decoded values, as u16 codes of its quantum.
fn put_fn_stats(b: &mut [u8], s: &NodeStats<f32>) {
    let f = |at: usize| f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
    let (min, quantum) = (f(l::FN_MINIMUM), f(l::FN_QUANTUM));
    let q = |x: f32| c_trunc(((x - min) / quantum + 0.5) as f64) as u16;
    put_u16(b, l::FN_MIN, q(s.min.1));
    put_u16(b, l::FN_MAX, q(s.max.1));
    put_u16(b, l::FN_AVG, q(s.avg as f32));
    let dev = s.std() as f32;
    put_u16(b, l::FN_DEV, c_trunc((dev / quantum + 0.5) as f64) as u16);
}

/// The code of value `n` of a quantised leaf (codes from `FN_CODES`).
pub(super) fn code_at(b: &[u8], n: usize, bits: u32) -> u32 {
    let at = l::FN_CODES;
    if bits == 16 {
        return u16::from_le_bytes([b[at + 2 * n], b[at + 2 * n + 1]]) as u32;
    }
    let per_byte = 8 / bits as usize;
    let byte = b[at + n / per_byte] as u32;
    (byte >> ((n % per_byte) as u32 * bits)) & ((1 << bits) - 1)
}

// ---------------------------------------------------------------------------------------------
// Tree.

/// How a grid's leaves are stored.
#[derive(Debug, Clone, Copy)]
enum LeafKind {
    Plain,
    /// Fixed bits per value (Fp4, Fp8, Fp16).
    Fixed(u32),
    FpN(f32),
}

/// Internal nodes in breadth-first order (each upper node is one root tile).
struct Topology {
    /// Upper nodes: origin (also the root key), range of their lower nodes.
    uppers: Vec<([i32; 3], std::ops::Range<usize>)>,
    /// Lower nodes: origin, range of their leaves (in tree order).
    lowers: Vec<([i32; 3], std::ops::Range<usize>)>,
}

/// The internal nodes above leaves sorted in tree order (`vdb::write::tree_key`).
fn topology(origins: &[[i32; 3]]) -> Topology {
    let mut t = Topology {
        uppers: Vec::new(),
        lowers: Vec::new(),
    };
    let keys: Vec<_> = origins.iter().map(|&o| tree_key(o)).collect();
    for (i, &o) in origins.iter().enumerate() {
        let new_upper = i == 0 || keys[i - 1].0 != keys[i].0;
        let new_lower = new_upper || keys[i - 1].1 != keys[i].1;
        if new_upper {
            t.uppers.push((keys[i].0, t.lowers.len()..t.lowers.len()));
        }
        if new_lower {
            t.lowers.push((o.map(|c| c & !127), i..i));
            if let Some(u) = t.uppers.last_mut() {
                u.1.end += 1;
            }
        }
        if let Some(lw) = t.lowers.last_mut() {
            lw.1.end += 1;
        }
    }
    t
}

/// Child index of `child_origin` in an internal node of `log2dim` whose children have
/// `child_total` index bits (lower: 4 and 3, upper: 5 and 7).
fn child_index(child_origin: [i32; 3], log2dim: u32, child_total: u32) -> usize {
    let m = (1i32 << (log2dim + child_total)) - 1;
    let c = child_origin.map(|x| ((x & m) >> child_total) as usize);
    (c[0] << (2 * log2dim)) | (c[1] << log2dim) | c[2]
}

/// Splits `buf` into consecutive slices of `sizes`.
fn split_sizes(mut buf: &mut [u8], sizes: impl Iterator<Item = usize>) -> Vec<&mut [u8]> {
    let mut out = Vec::new();
    for s in sizes {
        let (a, rest) = std::mem::take(&mut buf).split_at_mut(s);
        out.push(a);
        buf = rest;
    }
    out
}

/// An internal node: masks, child offsets (from the node), tile values (the background), its
/// children's merged statistics and bbox; flags bit 1 when it holds active values, bit 0 when not.
fn put_internal<T: NanoValue>(
    b: &mut [u8],
    lay: &l::Internal,
    child_total: u32,
    children: &[([i32; 3], usize)],
    child_stats: &[NodeStats<T>],
    background: T,
) -> NodeStats<T> {
    let entries = 1usize << (3 * lay.log2dim);
    let mut child_mask = vec![0u64; entries / 64];
    let mut is_child = vec![false; entries];
    for &(origin, offset) in children {
        let n = child_index(origin, lay.log2dim, child_total);
        child_mask[n / 64] |= 1 << (n % 64);
        is_child[n] = true;
        put_i64(b, lay.table + n * lay.entry, offset as i64);
    }
    for (n, c) in is_child.iter().enumerate() {
        if !c {
            background.put(b, lay.table + n * lay.entry);
        }
    }
    put_mask(b, lay.child_mask, &child_mask);
    let mut s = NodeStats::new();
    for c in child_stats {
        s.merge(c);
    }
    if s.empty_bbox() {
        put_u64(b, l::NODE_FLAGS, 1);
        put_coord(b, l::NODE_BBOX, s.bbox.0);
        put_coord(b, l::NODE_BBOX + 12, s.bbox.1);
    } else {
        put_u64(b, l::NODE_FLAGS, 2);
        put_coord(b, l::NODE_BBOX, s.bbox.0);
        put_coord(b, l::NODE_BBOX + 12, s.bbox.1);
        s.put(b, [lay.min, lay.max, lay.avg, lay.dev]);
    }
    s
}

/// One level of internal nodes (`lay`, children of `child_total` index bits), in parallel, into
/// `region` (which starts at byte `at` of the grid): node i's children are `nodes[i].1` of the
/// level below, child k at `child(k)` = (origin, byte offset in the grid) with `child_stats[k]`.
fn put_level<T: NanoValue>(
    (region, at): (&mut [u8], usize),
    (lay, child_total): (&l::Internal, u32),
    nodes: &[([i32; 3], std::ops::Range<usize>)],
    child: impl Fn(usize) -> ([i32; 3], usize) + Sync,
    child_stats: &[NodeStats<T>],
    background: T,
) -> Vec<NodeStats<T>> {
    split_sizes(region, nodes.iter().map(|_| lay.size))
        .into_par_iter()
        .enumerate()
        .map(|(i, b)| {
            let r = nodes[i].1.clone();
            let node_at = at + i * lay.size;
            let children: Vec<([i32; 3], usize)> = r
                .clone()
                .map(|k| {
                    let (origin, offset) = child(k);
                    (origin, offset - node_at)
                })
                .collect();
            put_internal(b, lay, child_total, &children, &child_stats[r], background)
        })
        .collect()
}

/// `RootData::CoordToKey` with single 64-bit keys: 21 bits per axis of `ijk >> 12`.
fn root_key(o: [i32; 3]) -> u64 {
    ((o[2] as u32 >> 12) as u64)
        | (((o[1] as u32 >> 12) as u64) << 21)
        | (((o[0] as u32 >> 12) as u64) << 42)
}

/// One grid's buffer.
fn encode_tree<T: NanoValue + crate::io::vdb::write::VdbValue>(
    g: &SparseGrid<T>,
    (name, class, gtype): (&str, GridClass, GridType),
    kind: LeafKind,
    fpn_log2s: Option<&[u32]>,
    fill: impl Fn(&Leaf<T>, &mut [u8], Option<u32>, &mut Active<T>) -> ([i32; 3], [i32; 3]) + Sync,
    put_stats: impl Fn(&mut [u8], &NodeStats<T>) + Sync,
) -> Result<Vec<u8>> {
    check_grid(name, &g.transform)?;
    let order = tree_order(g)?;
    let leaves: Vec<&Leaf<T>> = order.iter().map(|&i| &g.leaves[i]).collect();
    let origins: Vec<[i32; 3]> = leaves.iter().map(|lf| lf.origin).collect();
    let topo = topology(&origins);
    let v = T::KIND;
    let (root_l, up_l, low_l, leaf_l) = (l::root(v), l::upper(v), l::lower(v), l::leaf(v));

    // FpN: each leaf's bit width (computed by the caller, per leaf of `g`), in tree order.
    let log2s: Vec<Option<u32>> = match fpn_log2s {
        Some(v) => order.iter().map(|&i| Some(v[i])).collect(),
        None => vec![None; leaves.len()],
    };
    let leaf_size = |i: usize| match kind {
        LeafKind::Plain => leaf_l.size,
        LeafKind::Fixed(bits) => l::fn_leaf_size(bits as usize),
        LeafKind::FpN(_) => l::fn_leaf_size(1 << log2s[i].unwrap_or(4)),
    };
    // The bytes each node's checksum covers: `sizeof` of its type (an FpN leaf's 96-byte head).
    let leaf_crc_len = |i: usize| match kind {
        LeafKind::FpN(_) => l::FN_CODES,
        _ => leaf_size(i),
    };

    let tree_at = l::grid::SIZE;
    let root_at = tree_at + l::tree::SIZE;
    let root_len = root_l.size + topo.uppers.len() * l::TILE_SIZE;
    let upper_at = root_at + root_len;
    let lower_at = upper_at + topo.uppers.len() * up_l.size;
    let leaf_at = lower_at + topo.lowers.len() * low_l.size;
    let mut leaf_offsets = Vec::with_capacity(leaves.len());
    let mut end = leaf_at;
    for i in 0..leaves.len() {
        leaf_offsets.push(end);
        end += leaf_size(i);
    }
    let total = end;
    let mut buf = vec![0u8; total];

    // Leaves, in parallel, in groups whose statistics run interleaved: values or codes, then
    // the statistics of the active ones.
    const GROUP: usize = 8;
    let (head, leaf_region) = buf.split_at_mut(leaf_at);
    let mut leaf_slices = split_sizes(leaf_region, (0..leaves.len()).map(leaf_size));
    let leaf_stats: Vec<NodeStats<T>> = leaf_slices
        .par_chunks_mut(GROUP)
        .enumerate()
        .flat_map_iter(|(c, group)| {
            let mut act: Vec<Active<T>> = group.iter().map(|_| Active::new()).collect();
            let mut stats: Vec<NodeStats<T>> = group.iter().map(|_| NodeStats::new()).collect();
            for (k, b) in group.iter_mut().enumerate() {
                let i = c * GROUP + k;
                stats[k].bbox = fill(leaves[i], b, log2s[i], &mut act[k]);
            }
            leaf_stats(&act, &mut stats);
            for (b, s) in group.iter_mut().zip(&stats) {
                if !s.empty_bbox() {
                    put_stats(b, s);
                }
            }
            stats
        })
        .collect();

    // Lower nodes, then upper nodes, in parallel per level.
    let (head, lower_region) = head.split_at_mut(lower_at);
    let lower_stats = put_level(
        (lower_region, lower_at),
        (&low_l, 3),
        &topo.lowers,
        |k| (origins[k], leaf_offsets[k]),
        &leaf_stats,
        g.background,
    );
    let (head, upper_region) = head.split_at_mut(upper_at);
    let upper_stats = put_level(
        (upper_region, upper_at),
        (&up_l, 7),
        &topo.uppers,
        |k| (topo.lowers[k].0, lower_at + k * low_l.size),
        &lower_stats,
        g.background,
    );

    // Root: one tile per upper node, keyed by its origin.
    let root = &mut head[root_at..];
    put_u32(root, l::ROOT_TABLE_SIZE, topo.uppers.len() as u32);
    g.background.put(root, root_l.background);
    let mut total_stats = NodeStats::new();
    if topo.uppers.is_empty() {
        g.background.put(root, root_l.min);
        g.background.put(root, root_l.max);
    } else {
        for (i, (origin, _)) in topo.uppers.iter().enumerate() {
            let tile = root_l.size + i * l::TILE_SIZE;
            put_u64(root, tile + l::TILE_KEY, root_key(*origin));
            put_i64(
                root,
                tile + l::TILE_CHILD,
                (upper_at + i * up_l.size - root_at) as i64,
            );
            total_stats.merge(&upper_stats[i]);
        }
        total_stats.put(root, [root_l.min, root_l.max, root_l.avg, root_l.dev]);
    }
    let bbox = total_stats.bbox;
    put_coord(root, l::ROOT_BBOX, bbox.0);
    put_coord(root, l::ROOT_BBOX + 12, bbox.1);

    // Tree.
    let voxels: u64 = leaves.iter().map(|lf| lf.active_count()).sum();
    let tree = &mut head[tree_at..root_at];
    let first = |count: usize, at: usize| if count > 0 { (at - tree_at) as u64 } else { 0 };
    put_u64(tree, l::tree::NODE_OFFSET, first(leaves.len(), leaf_at));
    put_u64(
        tree,
        l::tree::NODE_OFFSET + 8,
        first(topo.lowers.len(), lower_at),
    );
    put_u64(
        tree,
        l::tree::NODE_OFFSET + 16,
        first(topo.uppers.len(), upper_at),
    );
    put_u64(tree, l::tree::NODE_OFFSET + 24, (root_at - tree_at) as u64);
    put_u32(tree, l::tree::NODE_COUNT, leaves.len() as u32);
    put_u32(tree, l::tree::NODE_COUNT + 4, topo.lowers.len() as u32);
    put_u32(tree, l::tree::NODE_COUNT + 8, topo.uppers.len() as u32);
    put_u64(tree, l::tree::VOXEL_COUNT, voxels);

    // Grid.
    let empty = total_stats.empty_bbox();
    put_grid(
        &mut head[..tree_at],
        name,
        class,
        gtype,
        &g.transform,
        total as u64,
        bbox,
        empty,
    );

    // Checksum: the grid, tree and root (without magic and checksum), then every node's CRC32
    // (upper, lower, leaves; each as the 8-byte `uint_fast32_t` it is on x86-64 Linux).
    let crc0 = crc32fast::hash(&buf[16..upper_at]);
    let mut nodes: Vec<(usize, usize)> = Vec::new();
    nodes.extend((0..topo.uppers.len()).map(|i| (upper_at + i * up_l.size, up_l.size)));
    nodes.extend((0..topo.lowers.len()).map(|i| (lower_at + i * low_l.size, low_l.size)));
    nodes.extend((0..leaves.len()).map(|i| (leaf_offsets[i], leaf_crc_len(i))));
    let crc1 = if nodes.is_empty() {
        0xffff_ffff
    } else {
        let crcs: Vec<u8> = nodes
            .par_iter()
            .flat_map_iter(|&(at, len)| (crc32fast::hash(&buf[at..at + len]) as u64).to_le_bytes())
            .collect();
        crc32fast::hash(&crcs)
    };
    put_u64(
        &mut buf,
        l::grid::CHECKSUM,
        crc0 as u64 | ((crc1 as u64) << 32),
    );
    Ok(buf)
}

fn check_grid(name: &str, t: &GridTransform) -> Result<()> {
    if name.is_empty() || name.len() > MAX_NAME_BYTES || name.contains('\0') {
        return Err(Error::InvalidInput(format!(
            "NanoVDB grid name {name:?}: 1 to {MAX_NAME_BYTES} bytes without NUL"
        )));
    }
    if !(t.voxel_size.is_finite() && t.voxel_size > 0.0) || t.origin.iter().any(|c| !c.is_finite())
    {
        return Err(Error::InvalidInput(format!(
            "grid '{name}': voxel size must be finite and positive and the origin finite"
        )));
    }
    Ok(())
}

/// `GridData`: magic, version, flags, size, name, map, world bbox, voxel size, class, type.
#[allow(clippy::too_many_arguments)]
fn put_grid(
    b: &mut [u8],
    name: &str,
    class: GridClass,
    gtype: GridType,
    t: &GridTransform,
    size: u64,
    bbox: ([i32; 3], [i32; 3]),
    empty: bool,
) {
    use l::flags as f;
    use l::grid as g;
    put_u64(b, g::MAGIC, MAGIC);
    put_u32(b, g::VERSION, VERSION);
    let mut flags = f::IS_BREADTH_FIRST | f::HAS_MIN_MAX | f::HAS_AVERAGE | f::HAS_STD_DEVIATION;
    if !empty {
        flags |= f::HAS_BBOX;
    }
    put_u32(b, g::FLAGS, flags);
    put_u32(b, g::GRID_INDEX, 0);
    put_u32(b, g::GRID_COUNT, 1);
    put_u64(b, g::GRID_SIZE, size);
    b[g::NAME..g::NAME + name.len()].copy_from_slice(name.as_bytes());
    // Map: a uniform scale and a translation; the matrices are stored transposed (diagonal
    // here), float copies first.
    let s = t.voxel_size;
    let inv = 1.0 / s;
    let diag = |x: f64| [x, 0.0, 0.0, 0.0, x, 0.0, 0.0, 0.0, x];
    let m = g::MAP;
    for (i, (a, c)) in diag(s).iter().zip(diag(inv)).enumerate() {
        put_f32(b, m + 4 * i, *a as f32);
        put_f32(b, m + 36 + 4 * i, c as f32);
        put_f64(b, m + 88 + 8 * i, *a);
        put_f64(b, m + 160 + 8 * i, c);
    }
    for i in 0..3 {
        put_f32(b, m + 72 + 4 * i, t.origin[i] as f32);
        put_f64(b, m + 232 + 8 * i, t.origin[i]);
    }
    put_f32(b, m + 84, 1.0);
    put_f64(b, m + 256, 1.0);
    // World bbox: the index bbox's corners (max + 1: exclusive) through the map, with the
    // map's fused multiply-adds.
    let (lo, hi) = if empty {
        ([1e308; 3], [-1e308; 3])
    } else {
        let mx = bbox.1.map(|c| c + 1);
        let apply = |p: [i32; 3]| -> [f64; 3] {
            let md = diag(s);
            [0, 1, 2].map(|r| {
                (p[0] as f64).mul_add(
                    md[3 * r],
                    (p[1] as f64).mul_add(
                        md[3 * r + 1],
                        (p[2] as f64).mul_add(md[3 * r + 2], t.origin[r]),
                    ),
                )
            })
        };
        let mut lo = apply(bbox.0);
        let mut hi = lo;
        for c in [
            [bbox.0[0], bbox.0[1], mx[2]],
            [bbox.0[0], mx[1], bbox.0[2]],
            [mx[0], bbox.0[1], bbox.0[2]],
            [mx[0], mx[1], bbox.0[2]],
            [mx[0], bbox.0[1], mx[2]],
            [bbox.0[0], mx[1], mx[2]],
            mx,
        ] {
            let w = apply(c);
            for a in 0..3 {
                lo[a] = lo[a].min(w[a]);
                hi[a] = hi[a].max(w[a]);
            }
        }
        (lo, hi)
    };
    for a in 0..3 {
        put_f64(b, g::WORLD_BBOX + 8 * a, lo[a]);
        put_f64(b, g::WORLD_BBOX + 24 + 8 * a, hi[a]);
        put_f64(b, g::VOXEL_SIZE + 8 * a, s);
    }
    put_u32(b, g::CLASS, class as u32);
    put_u32(b, g::TYPE, gtype as u32);
    put_i64(b, g::BLIND_OFFSET, 0);
    put_u32(b, g::BLIND_COUNT, 0);
}

/// One grid's buffer (`GridData` ... leaves), checksummed.
pub fn encode_grid(g: &NanoGrid) -> Result<Vec<u8>> {
    let gtype = g.grid_type();
    match g.values {
        NanoValues::Vec3(grid) => encode_tree(
            grid,
            (&g.name, g.class, gtype),
            LeafKind::Plain,
            None,
            |lf, b, _, act| fill_plain_leaf(b, lf, grid.background, act),
            put_plain_stats,
        ),
        NanoValues::Float(grid, q) => {
            let kind = match q {
                Quantise::Float => LeafKind::Plain,
                Quantise::Fp4 => LeafKind::Fixed(4),
                Quantise::Fp8 => LeafKind::Fixed(8),
                Quantise::Fp16 => LeafKind::Fixed(16),
                Quantise::FpN { tolerance } => LeafKind::FpN(tolerance),
            };
            let bg = grid.background;
            let log2s: Option<Vec<u32>> = match kind {
                LeafKind::FpN(tol) => Some(
                    grid.leaves
                        .par_iter()
                        .map(|lf| fpn_log2(&leaf_values(lf, bg), tol))
                        .collect(),
                ),
                _ => None,
            };
            encode_tree(
                grid,
                (&g.name, g.class, gtype),
                kind,
                log2s.as_deref(),
                move |lf, b, log2, act| match kind {
                    LeafKind::Plain => fill_plain_leaf(b, lf, bg, act),
                    LeafKind::Fixed(bits) => fill_fn_leaf(b, lf, bg, bits, None, act),
                    LeafKind::FpN(_) => {
                        let lg = log2.unwrap_or(4);
                        fill_fn_leaf(b, lf, bg, 1 << lg, Some(lg), act)
                    }
                },
                move |b, s| match kind {
                    LeafKind::Plain => put_plain_stats(b, s),
                    _ => put_fn_stats(b, s),
                },
            )
        }
    }
}

/// A whole file, ready to write: per grid, a segment header, the grid's record and its buffer.
pub struct EncodedNanoFile {
    /// (segment header + record, buffer) per grid.
    pub segments: Vec<(Vec<u8>, Vec<u8>)>,
    pub len: u64,
}

impl EncodedNanoFile {
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(self.len as usize);
        for (head, grid) in &self.segments {
            v.extend_from_slice(head);
            v.extend_from_slice(grid);
        }
        v
    }
    pub fn write_to(&self, w: &mut dyn Write) -> std::io::Result<()> {
        for (head, grid) in &self.segments {
            w.write_all(head)?;
            w.write_all(grid)?;
        }
        Ok(())
    }
}

/// Encodes the grids (in parallel), one segment each, as `nanovdb_convert` writes them. Names
/// must be unique.
pub fn encode(grids: &[NanoGrid]) -> Result<EncodedNanoFile> {
    if grids.is_empty() {
        return Err(Error::InvalidInput(
            "a NanoVDB file needs at least one grid".into(),
        ));
    }
    let mut names = std::collections::BTreeSet::new();
    for g in grids {
        if !names.insert(g.name.as_str()) {
            return Err(Error::InvalidInput(format!(
                "NanoVDB grid name '{}' is used twice",
                g.name
            )));
        }
    }
    let buffers: Vec<Vec<u8>> = grids.par_iter().map(encode_grid).collect::<Result<_>>()?;
    let segments: Vec<(Vec<u8>, Vec<u8>)> = grids
        .iter()
        .zip(buffers)
        .map(|(g, buf)| {
            let mut head = vec![0u8; l::FILE_HEADER];
            put_u64(&mut head, 0, MAGIC);
            put_u32(&mut head, 8, VERSION);
            put_u16(&mut head, 12, 1); // grids in the segment
            put_u16(&mut head, 14, 0); // codec NONE
            head.extend_from_slice(&meta_record(g, &buf));
            (head, buf)
        })
        .collect();
    let len = segments
        .iter()
        .map(|(h, b)| (h.len() + b.len()) as u64)
        .sum();
    Ok(EncodedNanoFile { segments, len })
}

/// A grid's record in the segment (`io::GridMetaData`), copied from its buffer.
fn meta_record(g: &NanoGrid, buf: &[u8]) -> Vec<u8> {
    use l::meta as m;
    let mut r = vec![0u8; m::SIZE];
    let tree = l::grid::SIZE;
    let root = tree + l::tree::SIZE;
    put_u64(&mut r, m::GRID_SIZE, buf.len() as u64);
    put_u64(&mut r, m::FILE_SIZE, buf.len() as u64);
    put_u64(&mut r, m::NAME_KEY, super::string_hash(&g.name));
    r[m::VOXEL_COUNT..m::VOXEL_COUNT + 8]
        .copy_from_slice(&buf[tree + l::tree::VOXEL_COUNT..tree + l::tree::VOXEL_COUNT + 8]);
    put_u32(&mut r, m::TYPE, g.grid_type() as u32);
    put_u32(&mut r, m::CLASS, g.class as u32);
    r[m::WORLD_BBOX..m::WORLD_BBOX + 48]
        .copy_from_slice(&buf[l::grid::WORLD_BBOX..l::grid::WORLD_BBOX + 48]);
    r[m::INDEX_BBOX..m::INDEX_BBOX + 24]
        .copy_from_slice(&buf[root + l::ROOT_BBOX..root + l::ROOT_BBOX + 24]);
    r[m::VOXEL_SIZE..m::VOXEL_SIZE + 24]
        .copy_from_slice(&buf[l::grid::VOXEL_SIZE..l::grid::VOXEL_SIZE + 24]);
    put_u32(&mut r, m::NAME_SIZE, g.name.len() as u32 + 1);
    // Node counts (leaf, lower, upper, root) and tile counts, from the tree.
    r[m::NODE_COUNT..m::NODE_COUNT + 12]
        .copy_from_slice(&buf[tree + l::tree::NODE_COUNT..tree + l::tree::NODE_COUNT + 12]);
    put_u32(&mut r, m::NODE_COUNT + 12, 1);
    r[m::TILE_COUNT..m::TILE_COUNT + 12]
        .copy_from_slice(&buf[tree + l::tree::TILE_COUNT..tree + l::tree::TILE_COUNT + 12]);
    put_u16(&mut r, m::CODEC, 0);
    put_u32(&mut r, m::VERSION, VERSION);
    r.extend_from_slice(g.name.as_bytes());
    r.push(0);
    r
}

/// Writes a NanoVDB file atomically; returns its size in bytes.
pub fn write_file(path: &Path, grids: &[NanoGrid]) -> Result<u64> {
    let enc = encode(grids)?;
    write_atomic_buffered(path, |w| enc.write_to(w))?;
    Ok(enc.len)
}
