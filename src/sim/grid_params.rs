//! The uniform neighbour grid shared by every particle stage (mirror of `GridParams` in
//! shaders/shared/common.wgsl; the layout must match it byte for byte).
use crate::config::{Axis, ShotConfig};

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
}

impl GridParams {
    /// Cells of edge >= `max_radius`; along a periodic axis the cell count divides the extent
    /// exactly, so wrapping cell indices matches minimum-image distances.
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
        }
    }

    /// The grid of a shot: cells sized by the largest kernel radius (level 0).
    pub fn for_shot(cfg: &ShotConfig) -> Self {
        let h0 = cfg.domain.spacing * cfg.domain.kernel_ratio;
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
    pub fn cell_coord(&self, p: [f64; 3]) -> [i32; 3] {
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

    pub fn cell_index(&self, p: [f64; 3]) -> u32 {
        self.neighbor_cell(self.cell_coord(p), [0, 0, 0])
            .expect("clamped cell is inside")
    }
}
