//! A float grid read back as a function of index space, as OpenVDB's accessors and its box
//! sampler read it: a leaf's voxel value (active or not: a level set's inactive voxels carry the
//! sign), else the value of the tile holding the point (8^3 and 128^3 tiles of the internal
//! nodes, 4096^3 root tiles), else the background.
use super::read::ReadGrid;
use super::GridData;
use crate::ground::{GridTransform, Leaf, LEAF_VOXELS};
use std::collections::HashMap;

/// Tile edges from the smallest (internal node of 16^3 leaves) to the root's.
const TILE_EDGES: [i64; 3] = [8, 128, 4096];

#[derive(Debug, Clone)]
pub struct Volume {
    pub background: f32,
    pub transform: GridTransform,
    leaves: HashMap<[i32; 3], Box<[f32; LEAF_VOXELS]>>,
    /// Per entry of `TILE_EDGES`: tile origin -> value.
    tiles: [HashMap<[i32; 3], f32>; 3],
}

impl Volume {
    /// The volume of a float grid; `None` for a vector grid.
    pub fn new(g: &ReadGrid) -> Option<Self> {
        let GridData::Float(s) = &g.data else {
            return None;
        };
        let mut leaves: HashMap<[i32; 3], Box<[f32; LEAF_VOXELS]>> = s
            .leaves
            .iter()
            .map(|l| (l.origin, l.values.clone()))
            .collect();
        // leaves whose inactive voxels are not the background replace their active-only copy
        for l in &g.inactive_leaves {
            leaves.insert(l.origin, l.values.clone());
        }
        let mut tiles: [HashMap<[i32; 3], f32>; 3] = Default::default();
        for t in &g.tiles {
            if let Some(level) = TILE_EDGES.iter().position(|e| *e == t.edge as i64) {
                tiles[level].insert(t.origin, t.value);
            }
        }
        Some(Self {
            background: s.background,
            transform: s.transform,
            leaves,
            tiles,
        })
    }

    /// The value at voxel `ijk`.
    pub fn value(&self, ijk: [i32; 3]) -> f32 {
        if let Some(v) = self.leaves.get(&ijk.map(|c| c & !7)) {
            return v[Leaf::<f32>::offset(ijk[0], ijk[1], ijk[2])];
        }
        for (level, edge) in TILE_EDGES.iter().enumerate() {
            let key = ijk.map(|c| c & !(*edge as i32 - 1));
            if let Some(v) = self.tiles[level].get(&key) {
                return *v;
            }
        }
        self.background
    }

    /// Trilinear interpolation of the voxel values at index-space point `p` (OpenVDB's
    /// `BoxSampler`); far outside the index range, the background.
    pub fn sample(&self, p: [f64; 3]) -> f64 {
        let lo = p.map(f64::floor);
        if lo
            .iter()
            .any(|c| !c.is_finite() || c.abs() >= i32::MAX as f64 - 1.0)
        {
            return self.background as f64;
        }
        let f = [p[0] - lo[0], p[1] - lo[1], p[2] - lo[2]];
        let i = lo.map(|c| c as i32);
        let mut sum = 0.0;
        for corner in 0..8 {
            let d = [corner >> 2 & 1, corner >> 1 & 1, corner & 1];
            let mut w = 1.0;
            for a in 0..3 {
                w *= if d[a] == 1 { f[a] } else { 1.0 - f[a] };
            }
            if w > 0.0 {
                let ijk = [i[0] + d[0], i[1] + d[1], i[2] + d[2]];
                sum += w * self.value(ijk) as f64;
            }
        }
        sum
    }

    /// The index-space box (first and last voxel, inclusive) of every voxel whose value passes
    /// `inside`, over the leaves and tiles (the background is not looked at); `None` when none
    /// does.
    pub fn bounds(&self, inside: impl Fn(f32) -> bool) -> Option<([i64; 3], [i64; 3])> {
        let mut lo = [i64::MAX; 3];
        let mut hi = [i64::MIN; 3];
        let mut grow = |a: [i64; 3], b: [i64; 3]| {
            for k in 0..3 {
                lo[k] = lo[k].min(a[k]);
                hi[k] = hi[k].max(b[k]);
            }
        };
        for (origin, values) in &self.leaves {
            for (n, v) in values.iter().enumerate() {
                if inside(*v) {
                    let p = [
                        origin[0] as i64 + (n >> 6) as i64,
                        origin[1] as i64 + ((n >> 3) & 7) as i64,
                        origin[2] as i64 + (n & 7) as i64,
                    ];
                    grow(p, p);
                }
            }
        }
        for (level, edge) in TILE_EDGES.iter().enumerate() {
            for (origin, v) in &self.tiles[level] {
                if inside(*v) {
                    let o = origin.map(|c| c as i64);
                    grow(o, o.map(|c| c + edge - 1));
                }
            }
        }
        (lo[0] <= hi[0]).then_some((lo, hi))
    }
}
