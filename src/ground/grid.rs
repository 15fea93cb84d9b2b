//! Sparse voxel grids made of 8^3 leaves: what the splat produces and the writers consume.
//!
//! Index space: as in OpenVDB, voxel *centres* sit on integer index points, so the centre of
//! voxel (i, j, k) is at
//! `origin + (i, j, k) * voxel_size` in world space.

/// Edge of a leaf in voxels, and voxels per leaf.
pub const LEAF_DIM: i32 = 8;
pub const LEAF_VOXELS: usize = 512;

/// World transform shared by every frame of a shot (uniform scale + translation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridTransform {
    pub voxel_size: f64,
    /// World position of the centre of voxel (0, 0, 0).
    pub origin: [f64; 3],
}

impl GridTransform {
    pub fn index_to_world(&self, ijk: [f64; 3]) -> [f64; 3] {
        [
            self.origin[0] + ijk[0] * self.voxel_size,
            self.origin[1] + ijk[1] * self.voxel_size,
            self.origin[2] + ijk[2] * self.voxel_size,
        ]
    }
    pub fn world_to_index(&self, p: [f64; 3]) -> [f64; 3] {
        [
            (p[0] - self.origin[0]) / self.voxel_size,
            (p[1] - self.origin[1]) / self.voxel_size,
            (p[2] - self.origin[2]) / self.voxel_size,
        ]
    }
}

/// One 8^3 block. `origin` is a multiple of 8 (index space). Value of voxel (x, y, z) inside the
/// leaf sits at `((x & 7) << 6) | ((y & 7) << 3) | (z & 7)` (OpenVDB's order).
/// Bit n of `mask` (word n / 64, bit n % 64) marks voxel n active; inactive values equal the
/// grid's background.
#[derive(Debug, Clone, PartialEq)]
pub struct Leaf<T> {
    pub origin: [i32; 3],
    pub values: Box<[T; LEAF_VOXELS]>,
    pub mask: [u64; 8],
}

impl<T: Copy> Leaf<T> {
    pub fn offset(x: i32, y: i32, z: i32) -> usize {
        (((x & 7) << 6) | ((y & 7) << 3) | (z & 7)) as usize
    }
    pub fn is_active(&self, n: usize) -> bool {
        self.mask[n / 64] >> (n % 64) & 1 == 1
    }
    pub fn active_count(&self) -> u64 {
        self.mask.iter().map(|w| w.count_ones() as u64).sum()
    }
}

/// A sparse grid: leaves sorted by origin (x, then y, then z: lexicographic), no duplicates.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseGrid<T> {
    pub name: String,
    pub background: T,
    pub transform: GridTransform,
    pub leaves: Vec<Leaf<T>>,
}

impl<T: Copy> SparseGrid<T> {
    pub fn active_voxel_count(&self) -> u64 {
        self.leaves.iter().map(|l| l.active_count()).sum()
    }
    /// Index coordinates of the active voxels, leaf by leaf in storage order.
    pub fn active_voxels(&self) -> impl Iterator<Item = [i32; 3]> + '_ {
        self.leaves.iter().flat_map(|leaf| {
            (0..LEAF_VOXELS).filter(|&n| leaf.is_active(n)).map(|n| {
                [
                    leaf.origin[0] + (n >> 6) as i32,
                    leaf.origin[1] + ((n >> 3) & 7) as i32,
                    leaf.origin[2] + (n & 7) as i32,
                ]
            })
        })
    }
    /// Inclusive index bounding box of the active voxels, `None` when empty.
    pub fn active_bbox(&self) -> Option<([i32; 3], [i32; 3])> {
        let mut lo = [i32::MAX; 3];
        let mut hi = [i32::MIN; 3];
        let mut any = false;
        for leaf in &self.leaves {
            for n in 0..LEAF_VOXELS {
                if leaf.is_active(n) {
                    any = true;
                    let v = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
                    for a in 0..3 {
                        lo[a] = lo[a].min(leaf.origin[a] + v[a]);
                        hi[a] = hi[a].max(leaf.origin[a] + v[a]);
                    }
                }
            }
        }
        any.then_some((lo, hi))
    }
    /// Value at an index point (background where no leaf or inactive).
    pub fn get(&self, ijk: [i32; 3]) -> T {
        let o = ijk.map(|v| v & !7);
        match self.leaves.binary_search_by(|l| l.origin.cmp(&o)) {
            Ok(i) => {
                let n = Leaf::<T>::offset(ijk[0], ijk[1], ijk[2]);
                let leaf = &self.leaves[i];
                if leaf.is_active(n) {
                    leaf.values[n]
                } else {
                    self.background
                }
            }
            Err(_) => self.background,
        }
    }
}
