//! Fast lookups into a sparse density grid for the ray-marcher, built once per frame: a dense
//! table of leaf slots over the leaves' bounding box, a dilated leaf occupancy for empty-space
//! skipping, and a coarse copy of the density with the optical depth towards the sun and towards
//! the zenith precomputed at its cell centres.
use crate::ground::{SparseGrid, LEAF_DIM, LEAF_VOXELS};
use glam::{DVec3, IVec3};
use rayon::prelude::*;

pub(crate) struct Volume {
    pub voxel: f64,
    pub origin: DVec3,
    /// Leaf-space box: leaf coordinates `leaf_lo .. leaf_lo + leaf_dims`.
    leaf_lo: [i32; 3],
    leaf_dims: [i32; 3],
    /// Slot of each leaf in `blocks`, -1 where absent.
    table: Vec<i32>,
    /// Leaf or one of its 26 neighbours present: trilinear samples inside it may be non-zero.
    near: Vec<bool>,
    blocks: Vec<[f32; LEAF_VOXELS]>,
    pub coarse: Coarse,
}

/// Coarse density (mean over `stride`^3 voxels) and optical depths (towards the sun, the zenith
/// and the nadir), per unit `density_scale`.
pub(crate) struct Coarse {
    pub stride: i32,
    /// Index-space position of voxel (0,0,0) of the coarse grid's first cell.
    pub lo: [i32; 3],
    pub dims: [i32; 3],
    pub density: Vec<f32>,
    pub tau_sun: Vec<f32>,
    pub tau_up: Vec<f32>,
    pub tau_down: Vec<f32>,
}

impl Volume {
    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    pub fn new(grid: &SparseGrid<f32>, sun: DVec3) -> Self {
        let t = grid.transform;
        let mut lo = [i32::MAX; 3];
        let mut hi = [i32::MIN; 3];
        for l in &grid.leaves {
            for a in 0..3 {
                lo[a] = lo[a].min(l.origin[a].div_euclid(LEAF_DIM));
                hi[a] = hi[a].max(l.origin[a].div_euclid(LEAF_DIM));
            }
        }
        if grid.leaves.is_empty() {
            lo = [0; 3];
            hi = [-1; 3];
        }
        let dims = [0, 1, 2].map(|a| hi[a] - lo[a] + 1);
        let cells = dims.iter().map(|&d| d.max(0) as usize).product::<usize>();
        let mut table = vec![-1i32; cells];
        let mut blocks = Vec::with_capacity(grid.leaves.len());
        for l in &grid.leaves {
            let mut b = [0.0f32; LEAF_VOXELS];
            for (n, v) in b.iter_mut().enumerate() {
                // Inactive voxels are empty space for the renderer, whatever the background.
                if l.is_active(n) && l.values[n].is_finite() {
                    *v = l.values[n].max(0.0);
                }
            }
            let k = l.origin.map(|o| o.div_euclid(LEAF_DIM));
            let i = Self::cell(lo, dims, k).expect("leaf inside its own bbox");
            table[i] = blocks.len() as i32;
            blocks.push(b);
        }
        let mut near = vec![false; cells];
        for x in 0..dims[0] {
            for y in 0..dims[1] {
                for z in 0..dims[2] {
                    let k = [lo[0] + x, lo[1] + y, lo[2] + z];
                    if table[Self::cell(lo, dims, k).unwrap()] < 0 {
                        continue;
                    }
                    for dx in -1..=1 {
                        for dy in -1..=1 {
                            for dz in -1..=1 {
                                if let Some(c) =
                                    Self::cell(lo, dims, [k[0] + dx, k[1] + dy, k[2] + dz])
                                {
                                    near[c] = true;
                                }
                            }
                        }
                    }
                }
            }
        }
        let mut v = Volume {
            voxel: t.voxel_size,
            origin: t.origin.into(),
            leaf_lo: lo,
            leaf_dims: dims,
            table,
            near,
            blocks,
            coarse: Coarse {
                stride: 1,
                lo: [0; 3],
                dims: [0; 3],
                density: vec![],
                tau_sun: vec![],
                tau_up: vec![],
                tau_down: vec![],
            },
        };
        v.coarse = v.build_coarse(sun);
        v
    }

    fn cell(lo: [i32; 3], dims: [i32; 3], k: [i32; 3]) -> Option<usize> {
        let r = [0, 1, 2].map(|a| k[a] - lo[a]);
        if (0..3).any(|a| r[a] < 0 || r[a] >= dims[a]) {
            return None;
        }
        Some(((r[0] * dims[1] + r[1]) * dims[2] + r[2]) as usize)
    }

    /// Index-space box `[lo, hi]` that contains every non-zero trilinear sample.
    pub fn index_box(&self) -> (DVec3, DVec3) {
        let (lo, dims) = (IVec3::from(self.leaf_lo), IVec3::from(self.leaf_dims));
        (
            (lo * LEAF_DIM).as_dvec3() - 1.0,
            ((lo + dims) * LEAF_DIM).as_dvec3(),
        )
    }

    #[inline]
    fn voxel_value(&self, i: [i32; 3]) -> f32 {
        let k = i.map(|v| v >> 3);
        match Self::cell(self.leaf_lo, self.leaf_dims, k) {
            Some(c) => {
                let s = self.table[c];
                if s < 0 {
                    0.0
                } else {
                    self.blocks[s as usize]
                        [(((i[0] & 7) << 6) | ((i[1] & 7) << 3) | (i[2] & 7)) as usize]
                }
            }
            None => 0.0,
        }
    }

    /// Whether samples in the leaf containing index point `q` may be non-zero.
    #[inline]
    pub fn maybe_dense(&self, q: DVec3) -> bool {
        let k = (q.floor().as_ivec3() >> 3_i32).to_array();
        Self::cell(self.leaf_lo, self.leaf_dims, k).is_some_and(|c| self.near[c])
    }

    /// Trilinear density at index-space point `q`.
    #[inline]
    pub fn sample(&self, q: DVec3) -> f64 {
        let f = q.floor();
        let i = f.as_ivec3();
        let t = q - f;
        let mut acc = 0.0;
        for c in 0..8 {
            let o = [(c >> 2) & 1, (c >> 1) & 1, c & 1];
            let w = (0..3)
                .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
                .product::<f64>();
            if w > 0.0 {
                acc += w * self.voxel_value([i[0] + o[0], i[1] + o[1], i[2] + o[2]]) as f64;
            }
        }
        acc
    }

    /// Exit distance (in index units along unit direction `d`) of the leaf containing `q`.
    pub fn leaf_exit(&self, q: DVec3, d: DVec3) -> f64 {
        let mut t = f64::INFINITY;
        for a in 0..3 {
            let k = ((q[a].floor() as i32) >> 3) as f64 * LEAF_DIM as f64;
            if d[a] > 1e-12 {
                t = t.min((k + LEAF_DIM as f64 - q[a]) / d[a]);
            } else if d[a] < -1e-12 {
                t = t.min((k - q[a]) / d[a]);
            }
        }
        t.max(0.0)
    }

    fn build_coarse(&self, sun: DVec3) -> Coarse {
        let vox = [0, 1, 2].map(|a| self.leaf_dims[a].max(0) * LEAF_DIM);
        let maxdim = *vox.iter().max().unwrap();
        // About 64 cells across: cheap to march, fine enough for soft shadows.
        let stride = ((maxdim + 63) / 64).max(2);
        let lo = [0, 1, 2].map(|a| self.leaf_lo[a] * LEAF_DIM);
        let dims = [0, 1, 2].map(|a| (vox[a] + stride - 1) / stride);
        let n = dims.iter().map(|&d| d.max(0) as usize).product::<usize>();
        let mut density = vec![0.0f64; n];
        for x in 0..self.leaf_dims[0] {
            for y in 0..self.leaf_dims[1] {
                for z in 0..self.leaf_dims[2] {
                    let c = ((x * self.leaf_dims[1] + y) * self.leaf_dims[2] + z) as usize;
                    let s = self.table[c];
                    if s < 0 {
                        continue;
                    }
                    let b = &self.blocks[s as usize];
                    for (m, &val) in b.iter().enumerate() {
                        if val == 0.0 {
                            continue;
                        }
                        let v = [
                            x * 8 + (m as i32 >> 6),
                            y * 8 + ((m as i32 >> 3) & 7),
                            z * 8 + (m as i32 & 7),
                        ];
                        let cc = v.map(|u| u / stride);
                        density[((cc[0] * dims[1] + cc[1]) * dims[2] + cc[2]) as usize] +=
                            val as f64;
                    }
                }
            }
        }
        let norm = 1.0 / (stride as f64).powi(3);
        let density: Vec<f32> = density.iter().map(|&d| (d * norm) as f32).collect();
        let mut c = Coarse {
            stride,
            lo,
            dims,
            density,
            tau_sun: vec![0.0; n],
            tau_up: vec![0.0; n],
            tau_down: vec![0.0; n],
        };
        // Optical depth (per unit density scale, in metres) along columns towards +y and -y.
        let cell_m = stride as f64 * self.voxel;
        for x in 0..dims[0] {
            for z in 0..dims[2] {
                let mut acc = 0.0f64;
                for y in (0..dims[1]).rev() {
                    let i = ((x * dims[1] + y) * dims[2] + z) as usize;
                    let d = c.density[i] as f64 * cell_m;
                    c.tau_up[i] = (acc + 0.5 * d) as f32;
                    acc += d;
                }
                let mut acc = 0.0f64;
                for y in 0..dims[1] {
                    let i = ((x * dims[1] + y) * dims[2] + z) as usize;
                    let d = c.density[i] as f64 * cell_m;
                    c.tau_down[i] = (acc + 0.5 * d) as f32;
                    acc += d;
                }
            }
        }
        let tau: Vec<f32> = (0..n)
            .into_par_iter()
            .map(|i| {
                let i = i as i32;
                let z = i % dims[2];
                let y = (i / dims[2]) % dims[1];
                let x = i / (dims[2] * dims[1]);
                let p = IVec3::new(x, y, z).as_dvec3() + 0.5;
                c.march(p, sun, cell_m) as f32
            })
            .collect();
        c.tau_sun = tau;
        c
    }
}

impl Coarse {
    /// Coarse-cell coordinates (cell centres at +0.5) of an index-space point.
    pub fn to_cell(&self, q: DVec3) -> DVec3 {
        (q + 0.5 - IVec3::from(self.lo).as_dvec3()) / self.stride as f64
    }

    fn lerp(&self, field: &[f32], p: DVec3) -> f64 {
        // Clamp to the cell centres: the edge value extends to the box faces (f64::clamp per
        // axis: glam's clamp treats NaN differently).
        let q = DVec3::from_array(
            [0, 1, 2].map(|a| (p[a] - 0.5).clamp(0.0, (self.dims[a] - 1).max(0) as f64)),
        );
        let f = q.floor();
        let t = q - f;
        let mut acc = 0.0;
        for c in 0..8 {
            let o = [(c >> 2) & 1, (c >> 1) & 1, c & 1];
            let w = (0..3)
                .map(|a| if o[a] == 1 { t[a] } else { 1.0 - t[a] })
                .product::<f64>();
            if w > 0.0 {
                let i = [0, 1, 2].map(|a| (f[a] as i32 + o[a]).min(self.dims[a] - 1));
                acc +=
                    w * field[((i[0] * self.dims[1] + i[1]) * self.dims[2] + i[2]) as usize] as f64;
            }
        }
        acc
    }

    /// Optical depth per unit density scale towards the sun / the zenith at index point `q`.
    pub fn tau_sun_at(&self, q: DVec3) -> f64 {
        self.lerp(&self.tau_sun, self.to_cell(q))
    }
    pub fn tau_up_at(&self, q: DVec3) -> f64 {
        self.lerp(&self.tau_up, self.to_cell(q))
    }
    pub fn tau_down_at(&self, q: DVec3) -> f64 {
        self.lerp(&self.tau_down, self.to_cell(q))
    }

    /// Marches from coarse-cell point `p` along `d` through the coarse density until it leaves the
    /// box; optical depth per unit density scale (metres x density).
    pub fn march(&self, p: DVec3, d: DVec3, cell_m: f64) -> f64 {
        if self.density.is_empty() {
            return 0.0;
        }
        // Clip the ray to the box [0, dims].
        let mut t0 = 0.0f64;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            let hi = self.dims[a] as f64;
            if d[a].abs() < 1e-12 {
                if p[a] < 0.0 || p[a] > hi {
                    return 0.0;
                }
            } else {
                let (mut ta, mut tb) = ((0.0 - p[a]) / d[a], (hi - p[a]) / d[a]);
                if ta > tb {
                    std::mem::swap(&mut ta, &mut tb);
                }
                t0 = t0.max(ta);
                t1 = t1.min(tb);
            }
        }
        if t0 >= t1 {
            return 0.0;
        }
        let step = 0.75;
        let mut tau = 0.0;
        let mut t = t0 + 0.5 * step;
        while t < t1 {
            tau += self.lerp(&self.density, p + d * t);
            t += step;
        }
        tau * step * cell_m
    }
}
