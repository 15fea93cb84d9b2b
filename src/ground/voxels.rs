//! Coarse voxel grids over the domain and the voxels of `control.target` on one: what the
//! prepared shot voxelises once and the controller and the target preview read.

/// Most voxels of the controller's grid (validation refuses more).
pub const MAX_VOXELS: usize = 1 << 24;

/// A voxel grid: `n` cells along x, y, z tiling the domain exactly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelGrid {
    pub n: [usize; 3],
    pub cell: [f64; 3],
}

impl VoxelGrid {
    /// Cells of about `voxel` m over a domain of `size` m (at least one per axis).
    pub fn new(size: [f64; 3], voxel: f64) -> Self {
        // at most MAX_VOXELS per axis, so the products below cannot overflow (validation
        // refuses grids of more than MAX_VOXELS voxels in all)
        let n = size.map(|s| ((s / voxel).round() as usize).clamp(1, MAX_VOXELS));
        Self {
            n,
            cell: [0, 1, 2].map(|a| size[a] / n[a] as f64),
        }
    }

    pub fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn columns(&self) -> usize {
        self.n[0] * self.n[2]
    }

    /// Index of voxel (i, j, k): x fastest, then z, then y (so a column's voxels are `columns`
    /// apart and a layer is one heat map, row = z).
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (j * self.n[2] + k) * self.n[0] + i
    }

    /// Voxel holding point p (clamped into the grid).
    pub fn voxel_of(&self, p: [f64; 3]) -> [usize; 3] {
        [0, 1, 2].map(|a| ((p[a] / self.cell[a]).floor().max(0.0) as usize).min(self.n[a] - 1))
    }
}

/// A placed target's voxels: which voxels of `grid` (index [`VoxelGrid::index`]) have their
/// centre inside it.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetVoxels {
    pub grid: VoxelGrid,
    pub inside: Vec<bool>,
}
