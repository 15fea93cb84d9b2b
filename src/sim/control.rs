//! Target-shape control (`control.target`), a feedback controller after Dobashi et al. 2008.
//!
//! The prepared shot has placed the target in the domain and voxelised it once on a coarse grid
//! tiling the domain (`shot::target`). From the voxels this gives, per ground column, the
//! target's top, and the footprint gives a mask that keeps the other heating (noise, sources) at
//! full strength within `margin` of the footprint and fades it to 0 over the next `margin`
//! (condensation supply suppressed far outside the target).
//!
//! Per frame, from the state the frame's one read-back already brought home (no host wait of
//! its own): the particles are binned into the voxels; a voxel is cloud when the mass-weighted
//! mean cloud water of its particles is above `cloud_threshold`; the cloud top of a column is
//! the top of its highest cloud voxel. A footprint column gets the supply factor
//! `min(1, gain * (target top - cloud top))` (0 once the cloud reaches the top), which the thermo
//! stage turns into `heat` K/s and `vapor` kg/kg/s below `supply_height`, bilinear between
//! column centres (a map in the heat-map buffer, [`crate::sim::sources::HeatMaps`]). The factor is
//! a function of the read-back state alone, so a resumed run (state from the checkpoint)
//! continues byte for byte. The same binning gives `target_iou`, the intersection over union of
//! the cloud voxels and the target voxels.
use crate::config::{ShotConfig, TargetConfig};
use crate::ground::{levels, ParticleState, TargetVoxels, VoxelGrid};

/// Intersection over union of two voxel sets (0 when both are empty).
pub fn iou(a: &[bool], b: &[bool]) -> f64 {
    let (mut both, mut either) = (0usize, 0usize);
    for (x, y) in a.iter().zip(b) {
        both += (*x && *y) as usize;
        either += (*x || *y) as usize;
    }
    if either == 0 {
        0.0
    } else {
        both as f64 / either as f64
    }
}

/// A placed, voxelised target and its controller's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    pub grid: VoxelGrid,
    pub inside: Vec<bool>,
    /// Per column (row = z): the top of the target's highest voxel there (m), 0 outside the
    /// footprint.
    pub top: Vec<f64>,
    /// Per column: the factor on the other heating, 1 within `margin` of the footprint, a
    /// smoothstep to 0 over the next `margin`.
    pub mask: Vec<f32>,
    /// Per voxel (index [`VoxelGrid::index`]): the offset (m) from its centre to the centre of
    /// the nearest target voxel (nearest along 6-connected steps, ties to the first reached)
    /// and its length; (0, 0, 0, 0) inside the target.
    pub field: Vec<[f32; 4]>,
    pub enabled: bool,
    pub threshold: f64,
    pub gain: f64,
    /// The pull towards the target (m/s^2) and its reach (m).
    pub pull: f64,
    pub reach: f64,
}

impl Target {
    /// The controller of the shot's target, or `None` without `control.target`.
    pub fn of_shot(shot: &crate::shot::Shot) -> Option<Self> {
        let cfg = shot.config();
        let t = cfg.control.target.as_ref()?;
        Some(Self::new(cfg, t, shot.target()?))
    }

    /// The controller of the target `t` of `cfg`, voxelised as `voxels`.
    pub fn new(cfg: &ShotConfig, t: &TargetConfig, voxels: &TargetVoxels) -> Self {
        let grid = voxels.grid;
        let inside = voxels.inside.clone();
        let cols = grid.columns();
        let mut top = vec![0.0; cols];
        for (v, _) in inside.iter().enumerate().filter(|(_, x)| **x) {
            let j = v / cols;
            top[v % cols] = f64::max(top[v % cols], (j + 1) as f64 * grid.cell[1]);
        }
        let mask = footprint_mask(&grid, &top, t.margin, cfg);
        let field = nearest_field(&grid, &inside);
        Self {
            grid,
            inside,
            top,
            mask,
            field,
            enabled: t.enabled,
            threshold: t.cloud_threshold,
            gain: t.gain,
            pull: t.pull,
            reach: t.reach,
        }
    }

    /// Voxels holding cloud: the mass-weighted mean cloud water of their particles is above
    /// the threshold.
    pub fn cloud_voxels(&self, state: &ParticleState) -> Vec<bool> {
        let mut water = vec![0.0f64; self.grid.len()];
        let mut mass = vec![0.0f64; self.grid.len()];
        for i in 0..state.len() {
            let p = state.pos[i];
            let [a, b, c] = self.grid.voxel_of([p[0] as f64, p[1] as f64, p[2] as f64]);
            let v = self.grid.index(a, b, c);
            let m = levels::mass(1.0, state.info[i][1].min(levels::MAX_LEVEL));
            water[v] += m * state.thermo[i][2] as f64;
            mass[v] += m;
        }
        water
            .iter()
            .zip(&mass)
            .map(|(w, m)| *m > 0.0 && *w > self.threshold * *m)
            .collect()
    }

    /// The supply factor per column (row = z) for a state's cloud voxels: min(1, gain * gap)
    /// in the footprint, 0 elsewhere and where the cloud has reached the target's top.
    pub fn supply(&self, cloud: &[bool]) -> Vec<f32> {
        let cols = self.grid.columns();
        let mut cloud_top = vec![0.0f64; cols];
        for (v, _) in cloud.iter().enumerate().filter(|(_, x)| **x) {
            let j = v / cols;
            cloud_top[v % cols] = f64::max(cloud_top[v % cols], (j + 1) as f64 * self.grid.cell[1]);
        }
        self.top
            .iter()
            .zip(&cloud_top)
            .map(|(t, c)| {
                if *t > 0.0 {
                    (self.gain * (t - c)).clamp(0.0, 1.0) as f32
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// The supply map and the IoU of a state.
    pub fn update(&self, state: &ParticleState) -> (Vec<f32>, f64) {
        let cloud = self.cloud_voxels(state);
        (self.supply(&cloud), iou(&cloud, &self.inside))
    }
}

/// The offset from each voxel's centre to the nearest target voxel's centre, by a breadth-first
/// search from every target voxel at once (6-connected steps, no wrap): exact along the axes,
/// within a step of the nearest elsewhere, in time linear in the voxels.
fn nearest_field(grid: &VoxelGrid, inside: &[bool]) -> Vec<[f32; 4]> {
    let [nx, ny, nz] = grid.n;
    let mut source = vec![usize::MAX; inside.len()];
    let mut queue = std::collections::VecDeque::new();
    for (v, _) in inside.iter().enumerate().filter(|(_, x)| **x) {
        source[v] = v;
        queue.push_back(v);
    }
    let coords = |v: usize| (v % nx, v / (nx * nz), (v / nx) % nz);
    while let Some(v) = queue.pop_front() {
        let (i, j, k) = coords(v);
        let steps = [
            (i > 0).then(|| grid.index(i - 1, j, k)),
            (i + 1 < nx).then(|| grid.index(i + 1, j, k)),
            (j > 0).then(|| grid.index(i, j - 1, k)),
            (j + 1 < ny).then(|| grid.index(i, j + 1, k)),
            (k > 0).then(|| grid.index(i, j, k - 1)),
            (k + 1 < nz).then(|| grid.index(i, j, k + 1)),
        ];
        for w in steps.into_iter().flatten() {
            if source[w] == usize::MAX {
                source[w] = source[v];
                queue.push_back(w);
            }
        }
    }
    source
        .iter()
        .enumerate()
        .map(|(v, s)| {
            if *s == usize::MAX || *s == v {
                return [0.0; 4];
            }
            let (a, b) = (coords(v), coords(*s));
            let d = [
                (b.0 as f64 - a.0 as f64) * grid.cell[0],
                (b.1 as f64 - a.1 as f64) * grid.cell[1],
                (b.2 as f64 - a.2 as f64) * grid.cell[2],
            ];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            [d[0] as f32, d[1] as f32, d[2] as f32, len as f32]
        })
        .collect()
}

/// 1 within `margin` of a footprint column, a smoothstep to 0 at twice `margin`; all 1 when
/// there is no footprint. The distance is centre to centre from each column to the footprint
/// column a breadth-first search over the columns reaches first (4-connected steps, wrapping on
/// periodic axes): exact along the axes, within a column of the nearest elsewhere, in time
/// linear in the columns.
fn footprint_mask(grid: &VoxelGrid, top: &[f64], margin: f64, cfg: &ShotConfig) -> Vec<f32> {
    let [nx, _, nz] = grid.n;
    let periodic = [
        cfg.domain.periodic.contains(&crate::config::Axis::X),
        cfg.domain.periodic.contains(&crate::config::Axis::Z),
    ];
    let mut source = vec![usize::MAX; nx * nz];
    let mut queue = std::collections::VecDeque::new();
    for (c, t) in top.iter().enumerate() {
        if *t > 0.0 {
            source[c] = c;
            queue.push_back(c);
        }
    }
    if queue.is_empty() {
        return vec![1.0; nx * nz];
    }
    let step = |i: usize, d: isize, n: usize, per: bool| -> Option<usize> {
        let j = i as isize + d;
        if (0..n as isize).contains(&j) {
            Some(j as usize)
        } else if per && n > 1 {
            Some(j.rem_euclid(n as isize) as usize)
        } else {
            None
        }
    };
    while let Some(c) = queue.pop_front() {
        let (i, k) = (c % nx, c / nx);
        let next = [
            step(i, -1, nx, periodic[0]).map(|i| k * nx + i),
            step(i, 1, nx, periodic[0]).map(|i| k * nx + i),
            step(k, -1, nz, periodic[1]).map(|k| k * nx + i),
            step(k, 1, nz, periodic[1]).map(|k| k * nx + i),
        ];
        for w in next.into_iter().flatten() {
            if source[w] == usize::MAX {
                source[w] = source[c];
                queue.push_back(w);
            }
        }
    }
    let delta = |a: usize, b: usize, n: usize, per: bool, cell: f64| {
        let d = a.abs_diff(b);
        let d = if per { d.min(n - d) } else { d };
        d as f64 * cell
    };
    source
        .iter()
        .enumerate()
        .map(|(c, s)| {
            let dx = delta(c % nx, s % nx, nx, periodic[0], grid.cell[0]);
            let dz = delta(c / nx, s / nx, nz, periodic[1], grid.cell[2]);
            let d = (dx * dx + dz * dz).sqrt();
            let t = if margin > 0.0 {
                (2.0 - d / margin).clamp(0.0, 1.0)
            } else {
                (d == 0.0) as u8 as f64
            };
            (t * t * (3.0 - 2.0 * t)) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const CUBE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
        f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

    fn cube_target(cfg: &ShotConfig, t: &TargetConfig) -> Target {
        let mesh = crate::io::obj::parse(CUBE).unwrap();
        Target::new(cfg, t, &crate::shot::target::mesh_voxels(cfg, t, &mesh))
    }

    fn shot(target: &str) -> ShotConfig {
        let mut cfg: ShotConfig = serde_saphyr::from_str(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [1000, 800, 1000], spacing: 50}\n",
        )
        .unwrap();
        cfg.control.target = Some(serde_saphyr::from_str(target).unwrap());
        cfg
    }

    #[test]
    fn a_placed_cube_fills_exactly_its_voxels() {
        // a unit cube scaled to 400 x 300 x 200 m, its corner at (300, 200, 400): voxels of
        // 100 m, centres 350..650 along x, 250..450 along y, 450..550 along z
        let cfg = shot("{mesh: c.obj, scale: [400, 300, 200], translate: [300, 200, 400]}");
        let t = cfg.control.target.clone().unwrap();
        let target = cube_target(&cfg, &t);
        assert_eq!(target.grid.n, [10, 8, 10]);
        let count = target.inside.iter().filter(|x| **x).count();
        assert_eq!(count, 4 * 3 * 2);
        assert!(target.inside[target.grid.index(3, 2, 4)]);
        assert!(target.inside[target.grid.index(6, 4, 5)]);
        assert!(!target.inside[target.grid.index(7, 4, 5)]);
        assert!(!target.inside[target.grid.index(3, 5, 4)]);
        // the top of a footprint column is the cube's top, 500 m
        assert_eq!(target.top[4 * 10 + 3], 500.0);
        assert_eq!(target.top[0], 0.0);
        // mask: 1 in and next to the footprint (margin 100 m), 0 far away
        assert_eq!(target.mask[4 * 10 + 3], 1.0);
        assert_eq!(target.mask[4 * 10 + 2], 1.0);
        assert_eq!(target.mask[0], 0.0);
    }

    #[test]
    fn rotation_about_y_turns_the_footprint() {
        // a 600 x 100 m bar along x turned by 90 degrees lies along z
        let cfg =
            shot("{mesh: c.obj, scale: [600, 200, 100], rotate_y: 90, translate: [560, 100, 200]}");
        let t = cfg.control.target.clone().unwrap();
        let target = cube_target(&cfg, &t);
        // x' = -z, z' = x: the bar covers x in [460, 560], z in [200, 800]
        let cols: Vec<usize> = (0..100).filter(|c| target.top[*c] > 0.0).collect();
        assert_eq!(cols.len(), 6, "{cols:?}");
        assert!(cols.iter().all(|c| c % 10 == 5));
        assert_eq!(cols[0] / 10, 2);
        assert_eq!(cols[5] / 10, 7);
    }

    #[test]
    fn the_pull_field_points_at_the_nearest_target_voxel() {
        let cfg = shot("{mesh: c.obj, scale: [400, 300, 200], translate: [300, 200, 400]}");
        let t = cfg.control.target.clone().unwrap();
        let target = cube_target(&cfg, &t);
        let g = target.grid;
        assert_eq!(target.field[g.index(3, 2, 4)], [0.0; 4]);
        // two voxels above the top layer (j = 4): 200 m down
        assert_eq!(target.field[g.index(4, 6, 5)], [0.0, -200.0, 0.0, 200.0]);
        // one voxel left of x = 3
        assert_eq!(target.field[g.index(2, 3, 4)], [100.0, 0.0, 0.0, 100.0]);
        // a corner voxel's offset reaches the cube's nearest corner voxel (3, 2, 4)
        let f = target.field[g.index(0, 0, 0)];
        assert_eq!(&f[..3], &[300.0, 200.0, 400.0]);
    }

    #[test]
    fn iou_of_sets() {
        let a = [true, true, false, false];
        let b = [true, false, true, false];
        assert!((iou(&a, &b) - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(iou(&a, &a), 1.0);
        assert_eq!(iou(&[false; 3], &[false; 3]), 0.0);
        assert_eq!(iou(&a, &[false; 4]), 0.0);
    }

    #[test]
    fn supply_follows_the_gap_and_stops_at_the_top() {
        let cfg =
            shot("{mesh: c.obj, scale: [400, 300, 200], translate: [300, 200, 400], gain: 0.005}");
        let t = cfg.control.target.clone().unwrap();
        let target = cube_target(&cfg, &t);
        let mut s = ParticleState::default();
        let mut put = |x: f32, y: f32, z: f32, w: f32| {
            s.pos.push([x, y, z, 0.0]);
            s.vel.push([0.0; 4]);
            s.thermo.push([280.0, 0.0, w, 0.0]);
            s.info.push([s.info.len() as u32, 0]);
            s.density.push(1.0);
        };
        // column (3, 4): cloud up to 300 m (gap 200 m -> 1.0 at gain 0.005); column (4, 4):
        // cloud up to 500 m (gap 0); column (5, 4): cloud up to 400 m (gap 100 m -> 0.5);
        // a dry particle in column (6, 4) and cloud outside the footprint
        put(350.0, 250.0, 450.0, 1e-4);
        put(450.0, 450.0, 450.0, 1e-4);
        put(550.0, 350.0, 450.0, 1e-4);
        put(650.0, 450.0, 450.0, 0.0);
        put(50.0, 450.0, 50.0, 1e-3);
        let (supply, iou) = target.update(&s);
        assert_eq!(supply[43], 1.0);
        assert_eq!(supply[44], 0.0);
        assert!((supply[45] - 0.5).abs() < 1e-6);
        assert_eq!(supply[46], 1.0);
        assert_eq!(supply[0], 0.0);
        // 3 of the 4 cloud voxels are inside the 24 target voxels
        assert!((iou - 3.0 / 25.0).abs() < 1e-12, "{iou}");
    }
}
