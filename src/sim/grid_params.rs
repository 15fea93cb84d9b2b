//! The uniform neighbour grid shared by every particle stage (mirror of `GridParams` in
//! shaders/shared/common.wgsl; the layout must match it byte for byte).
use crate::config::{Axis, ShotConfig};
use glam::DVec3;

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GridParams {
    pub domain_min: [f32; 3],
    pub n_particles: u32,
    pub domain_size: [f32; 3],
    pub n_boundary: u32,
    pub cell_size: [f32; 3],
    pub num_cells: u32,
    pub dims: [u32; 3],
    /// bit 0: x periodic, bit 2: z periodic.
    pub periodic: u32,
    /// Each cell is cut into this many slices along x; particles are sorted by (cell, slice) and
    /// the cell table has an entry per slice, so a neighbour search can clip each row of cells
    /// to the x extent of its search sphere (`row_entries`). Cell `c` spans table entries
    /// `c * x_slices .. (c + 1) * x_slices`.
    pub x_slices: u32,
    /// Radius around a particle's current position that a neighbour search covers, measured to
    /// the other particles' cells and slices as sorted (the cell edge's lower bound).
    pub search_radius: f32,
    pub _pad: [u32; 2],
}

/// Slices per cell along x (see `GridParams::x_slices`); measured in docs/PERFORMANCE.md "PBF".
pub const X_SLICES: u32 = 2;

impl GridParams {
    /// Cells of edge >= `max_radius` (the search radius); along a periodic axis the cell count
    /// divides the extent exactly, so wrapping cell indices matches minimum-image distances.
    pub fn new(size: [f64; 3], max_radius: f64, periodic_x: bool, periodic_z: bool) -> Self {
        let dims = size.map(|s| ((s / max_radius).floor() as u32).max(1));
        let cell_size = [0, 1, 2].map(|a| (size[a] / dims[a] as f64) as f32);
        Self {
            domain_min: [0.0; 3],
            n_particles: 0,
            domain_size: size.map(|s| s as f32),
            n_boundary: 0,
            cell_size,
            num_cells: dims[0] * dims[1] * dims[2],
            dims,
            periodic: (periodic_x as u32) | ((periodic_z as u32) << 2),
            x_slices: X_SLICES,
            search_radius: max_radius as f32,
            _pad: [0; 2],
        }
    }

    /// The grid of a shot: cells sized by the largest kernel radius (level 0). Searches read the
    /// cells as sorted while the PBF iterations move particles by a few percent of h0; a skin
    /// (cells and search radius 1.1 h0) changed neither the momentum drift nor the at-rest
    /// behaviour measurably and cost 15% of the PBF time (docs/PERFORMANCE.md "PBF").
    pub fn for_shot(cfg: &ShotConfig) -> Self {
        let h0 = cfg.domain.kernel_radius();
        Self::new(
            cfg.domain.size,
            h0,
            cfg.domain.periodic.contains(&Axis::X),
            cfg.domain.periodic.contains(&Axis::Z),
        )
    }

    pub fn periodic_x(&self) -> bool {
        self.periodic & 1 != 0
    }
    pub fn periodic_z(&self) -> bool {
        self.periodic & 4 != 0
    }

    /// Integer cell of a position, clamped into the grid (mirror of `cell_coord`).
    pub fn cell_coord(&self, p: DVec3) -> [i32; 3] {
        [0, 1, 2].map(|a| {
            let c = ((p[a] - self.domain_min[a] as f64) / self.cell_size[a] as f64).floor() as i64;
            c.clamp(0, self.dims[a] as i64 - 1) as i32
        })
    }

    /// Linear cell index of `c + offset`, wrapping periodic axes; None outside a wall
    /// (mirror of `neighbor_cell`).
    pub fn neighbor_cell(&self, c: [i32; 3], offset: [i32; 3]) -> Option<u32> {
        let d = self.dims.map(|v| v as i32);
        let mut n = [c[0] + offset[0], c[1] + offset[1], c[2] + offset[2]];
        let wrap = [self.periodic_x(), false, self.periodic_z()];
        for a in 0..3 {
            if wrap[a] {
                n[a] = n[a].rem_euclid(d[a]);
            } else if n[a] < 0 || n[a] >= d[a] {
                return None;
            }
        }
        Some(((n[2] * d[1] + n[1]) * d[0] + n[0]) as u32)
    }

    /// Entries of a cell table: one per slice, plus the end.
    pub fn table_len(&self) -> usize {
        (self.num_cells * self.x_slices) as usize + 1
    }

    /// Rows of the wall table: wall particles lie below the floor and above the ceiling, so they
    /// are binned only into the first and the last y row of cells (one row when the grid has
    /// one). The wall table holds those rows alone: a table over every row would cost one entry
    /// per slice of the whole grid, mostly empty (docs/PERFORMANCE.md "Memory").
    pub fn wall_rows(&self) -> u32 {
        self.dims[1].min(2)
    }

    /// Entries of a wall table: one per slice of the wall rows, plus the end.
    pub fn wall_table_len(&self) -> usize {
        (self.dims[0] * self.wall_rows() * self.dims[2] * self.x_slices) as usize + 1
    }

    /// Wall-table entry of the first slice of cell `cell`, or None when its y row holds no wall
    /// particles (mirror of `wall_shift` in common.wgsl).
    pub fn wall_entry(&self, cell: u32) -> Option<usize> {
        let [dx, dy, _] = self.dims;
        let (cx, cy, cz) = (cell % dx, (cell / dx) % dy, cell / (dx * dy));
        let w = if cy == 0 {
            0
        } else if cy == dy - 1 {
            self.wall_rows() - 1
        } else {
            return None;
        };
        Some((((cz * self.wall_rows() + w) * dx + cx) * self.x_slices) as usize)
    }

    /// Slots of cell `cell` in a wall table (`wall_entry`); empty in the rows between.
    pub fn wall_cell_slots(&self, wall_start: &[u32], cell: u32) -> std::ops::Range<u32> {
        match self.wall_entry(cell) {
            Some(e) => wall_start[e]..wall_start[e + self.x_slices as usize],
            None => 0..0,
        }
    }

    /// Slots (indices into the cell-ordered arrays) of cell `cell` in a cell table.
    pub fn cell_slots(&self, cell_start: &[u32], cell: u32) -> std::ops::Range<u32> {
        let s = self.x_slices as usize;
        cell_start[cell as usize * s]..cell_start[(cell as usize + 1) * s]
    }

    /// Sort key of a position: its cell's first table entry plus its x slice within the cell
    /// (mirror of `slice_key` in common.wgsl, computed in f32 like the shader).
    pub fn slice_key(&self, p: DVec3) -> u32 {
        let c = self.cell_coord(p);
        let cell = self
            .neighbor_cell(c, [0, 0, 0])
            .expect("clamped cell is inside");
        cell * self.x_slices + self.slice_in_cell(p.x as f32, c[0])
    }

    fn slice_in_cell(&self, x: f32, cx: i32) -> u32 {
        let w = self.cell_size[0] / self.x_slices as f32;
        let s = ((x - self.domain_min[0] - cx as f32 * self.cell_size[0]) / w).floor();
        s.clamp(0.0, (self.x_slices - 1) as f32) as u32
    }
}
