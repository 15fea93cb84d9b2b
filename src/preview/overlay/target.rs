//! The target volume of `control.target` drawn into a preview as a ghost: the controller's
//! voxelised target (what the controller steers towards, not the mesh itself), each pixel's ray
//! marched through its voxel grid. The ghost's opacity grows with the length of the ray inside
//! the target, its shade tells the face the ray entered through (top, x or z side), and its
//! silhouette and creases (neighbouring pixels entering through other faces or missing it) are
//! drawn as lines.
use super::{blend, line_width};
use crate::ground::{TargetVoxels, VoxelGrid};
use crate::preview::{LinearImage, PreviewParams};
use glam::DVec3;
use rayon::prelude::*;

/// The ghost's colour (linear RGB).
const COLOR: DVec3 = DVec3::new(1.0, 0.25, 0.6);
/// Opacity where a ray grazes the target, the most a long chord adds to it, and the lines'.
const GHOST_MIN: f64 = 0.08;
const GHOST_ADD: f64 = 0.17;
const LINE_ALPHA: f64 = 0.9;

/// A target's voxels, ready to draw.
pub struct TargetGhost {
    grid: VoxelGrid,
    inside: Vec<bool>,
}

/// What a pixel's ray meets: the axis of the face it enters the target through (0 x, 1 y,
/// 2 z) and the length (m) it runs inside.
#[derive(Clone, Copy, PartialEq)]
struct Hit {
    face: usize,
    length: f64,
}

impl TargetGhost {
    pub fn new(target: &TargetVoxels) -> Self {
        Self {
            grid: target.grid,
            inside: target.inside.clone(),
        }
    }

    pub fn draw(&self, img: &mut LinearImage, params: &PreviewParams) {
        let (w, h) = (img.width, img.height);
        let hits: Vec<Option<Hit>> = (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                (0..w).map(move |x| self.march(params.camera.position, params.ray(x, y)))
            })
            .collect();
        let cell = self.grid.cell.iter().copied().fold(f64::INFINITY, f64::min);
        for (i, hit) in hits.iter().enumerate() {
            if let Some(hit) = hit {
                let shade = [0.75, 1.0, 0.55][hit.face];
                let a = GHOST_MIN + GHOST_ADD * (1.0 - (-hit.length / (4.0 * cell)).exp());
                blend(img, params, i, COLOR * shade, a);
            }
        }
        let reach = (0.5 * line_width(h)).ceil() as i64;
        let face = |x: i64, y: i64| {
            if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                return None;
            }
            hits[(y * w as i64 + x) as usize].map(|h| h.face)
        };
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let Some(f) = face(x, y) else { continue };
                let edge = (-reach..=reach)
                    .any(|dy| (-reach..=reach).any(|dx| face(x + dx, y + dy) != Some(f)));
                if edge {
                    blend(img, params, (y * w as i64 + x) as usize, COLOR, LINE_ALPHA);
                }
            }
        }
    }

    /// Amanatides-Woo traversal of the voxel grid (the domain `[0, n cell]`) along the ray.
    fn march(&self, o: DVec3, d: DVec3) -> Option<Hit> {
        let g = &self.grid;
        let hi = DVec3::from_array([0, 1, 2].map(|a| g.n[a] as f64 * g.cell[a]));
        // clip to the grid's box; `entry_axis` is the face the ray comes in through
        let (mut t0, mut t1, mut entry_axis) = (0.0f64, f64::INFINITY, 1usize);
        for a in 0..3 {
            if d[a].abs() < 1e-12 {
                if o[a] < 0.0 || o[a] > hi[a] {
                    return None;
                }
                continue;
            }
            let (mut ta, mut tb) = (-o[a] / d[a], (hi[a] - o[a]) / d[a]);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            if ta > t0 {
                t0 = ta;
                entry_axis = a;
            }
            t1 = t1.min(tb);
        }
        if t0 >= t1 {
            return None;
        }
        let p = o + d * (t0 + 1e-9 * (1.0 + t0));
        let mut v =
            [0, 1, 2].map(|a| ((p[a] / g.cell[a]).floor().max(0.0) as i64).min(g.n[a] as i64 - 1));
        let step = [0, 1, 2].map(|a| if d[a] > 0.0 { 1i64 } else { -1 });
        let mut t_max = [0, 1, 2].map(|a| {
            if d[a].abs() < 1e-12 {
                f64::INFINITY
            } else {
                let edge = (v[a] + (step[a] > 0) as i64) as f64 * g.cell[a];
                (edge - o[a]) / d[a]
            }
        });
        let t_delta = [0, 1, 2].map(|a| {
            if d[a].abs() < 1e-12 {
                f64::INFINITY
            } else {
                g.cell[a] / d[a].abs()
            }
        });
        let (mut t, mut axis) = (t0, entry_axis);
        let mut hit: Option<Hit> = None;
        loop {
            let a = (0..3)
                .min_by(|&i, &j| t_max[i].total_cmp(&t_max[j]))
                .unwrap_or(0);
            let t_next = t_max[a].min(t1);
            let idx = g.index(v[0] as usize, v[1] as usize, v[2] as usize);
            if self.inside[idx] {
                let h = hit.get_or_insert(Hit {
                    face: axis,
                    length: 0.0,
                });
                h.length += t_next - t;
            }
            if t_max[a] >= t1 {
                break;
            }
            t = t_max[a];
            axis = a;
            v[a] += step[a];
            if v[a] < 0 || v[a] >= g.n[a] as i64 {
                break;
            }
            t_max[a] += t_delta[a];
        }
        hit
    }
}
