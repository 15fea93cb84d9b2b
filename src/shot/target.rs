//! `control.target` prepared once: its mesh (a closed OBJ) or VDB read and pinned, placed in the
//! domain (scale, then rotation about y, then translation) and voxelised on the controller's
//! coarse grid (cells of about `voxel_size`, default the kernel radius): a voxel is inside when
//! its centre is. For a mesh by the parity of the crossings of a vertical ray through its
//! column; for a VDB fog volume or level set ([`super::target_volume`]) by the grid's value
//! there. From the voxels on both are the same (`sim::control` steers towards them).
use super::target_volume;
use crate::config::{Issue, ShotConfig, TargetConfig};
use crate::ground::{TargetVoxels, VoxelGrid, MAX_VOXELS};
use crate::io::obj::Mesh;

/// Most triangle-column tests of a target's voxelisation (a few seconds).
pub const MAX_TARGET_WORK: u64 = 1 << 31;

fn num(x: f64) -> String {
    crate::config::fmt_float(x)
}

fn issue(keys: &[&str], msg: String) -> Issue {
    Issue {
        keys: keys.iter().map(|k| k.to_string()).collect(),
        msg,
    }
}

/// Edge of the controller's voxels (m).
pub fn voxel_size(cfg: &ShotConfig, t: &TargetConfig) -> f64 {
    t.voxel_size.unwrap_or(cfg.domain.kernel_radius())
}

/// The controller's grid of a target: cells of about [`voxel_size`] over the domain.
pub fn grid_for(cfg: &ShotConfig, t: &TargetConfig) -> VoxelGrid {
    VoxelGrid::new(cfg.domain.size, voxel_size(cfg, t))
}

/// The shot's target voxelised, or `None` without `control.target`; the first problem with its
/// shape (the grid's size, the file, where it lands) as an issue naming its keys. The target's
/// keys themselves (one shape, the scale's form) were checked with the config.
pub fn prepare(c: &ShotConfig) -> Result<Option<TargetVoxels>, Issue> {
    let Some(t) = &c.control.target else {
        return Ok(None);
    };
    let grid = grid_for(c, t);
    if grid.len() > MAX_VOXELS {
        return Err(issue(
            &["control.target.voxel_size", "control.target"],
            format!(
                "voxels of {} m make {} x {} x {} voxels over the domain; at most {} (use larger voxels)",
                num(voxel_size(c, t)),
                grid.n[0],
                grid.n[1],
                grid.n[2],
                MAX_VOXELS
            ),
        ));
    }
    let (shape_key, bounds, inside) = match target_volume::load(t) {
        Some(Err(e)) => return Err(issue(e.keys, e.msg)),
        Some(Ok(vdb)) => (
            "control.target.vdb",
            vdb.placed_bounds(t),
            vdb.voxelize(t, &grid),
        ),
        None => {
            let mesh = load_mesh(t).map_err(|why| issue(&["control.target.mesh"], why))?;
            // the voxelisation tests every triangle against every column
            let work = (grid.columns() as u64).saturating_mul(mesh.triangles.len() as u64);
            if work > MAX_TARGET_WORK {
                return Err(issue(
                    &["control.target.voxel_size", "control.target.mesh"],
                    format!(
                        "{} triangles over {} x {} columns of voxels is too much to voxelise ({} tests; at most {}): use larger voxels or a coarser mesh",
                        mesh.triangles.len(),
                        grid.n[0],
                        grid.n[2],
                        work,
                        MAX_TARGET_WORK
                    ),
                ));
            }
            let placed = place(&mesh, t);
            let inside = voxelize(&placed, &grid);
            ("control.target.mesh", placed.bounds(), inside)
        }
    };
    let (lo, hi) = bounds;
    let size = c.domain.size;
    for (a, axis) in ["x", "y", "z"].iter().enumerate() {
        if lo[a] < 0.0 || hi[a] > size[a] {
            return Err(issue(
                &[
                    "control.target.translate",
                    "control.target.scale",
                    shape_key,
                ],
                format!(
                    "the placed target spans {axis} [{}, {}] m, outside the domain [0, {}] (check translate, scale and rotate_y)",
                    num(lo[a]),
                    num(hi[a]),
                    num(size[a])
                ),
            ));
        }
    }
    if !inside.iter().any(|x| *x) {
        return Err(issue(
            &["control.target.scale", shape_key],
            format!(
                "the placed target holds no voxel centre of the controller's {} m voxels (scale it up or set a smaller voxel_size)",
                num(voxel_size(c, t))
            ),
        ));
    }
    Ok(Some(TargetVoxels { grid, inside }))
}

/// The voxels of `mesh` (in its own coordinates) placed by `t` on the grid of `cfg`'s target.
pub fn mesh_voxels(cfg: &ShotConfig, t: &TargetConfig, mesh: &Mesh) -> TargetVoxels {
    let grid = grid_for(cfg, t);
    let inside = voxelize(&place(mesh, t), &grid);
    TargetVoxels { grid, inside }
}

/// Reads a target's mesh and checks that it is closed (the error is one line, without the key).
/// (A target without `mesh` is a VDB: [`target_volume::load`].)
pub fn load_mesh(t: &TargetConfig) -> Result<Mesh, String> {
    let Some(name) = t.mesh.as_deref() else {
        return Err("control.target has no mesh".into());
    };
    let path = std::path::Path::new(name);
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    if ext.as_deref() == Some("vdb") {
        return Err(format!(
            "{name}: a VDB volume is given as control.target.vdb, not as a mesh"
        ));
    }
    if ext.as_deref() != Some("obj") {
        return Err(format!(
            "{name}: only Wavefront OBJ meshes (.obj) are read as target meshes (VDB volumes: control.target.vdb)"
        ));
    }
    let mesh = crate::io::obj::read(path).map_err(|why| format!("{name}: {why}"))?;
    mesh.check_closed()
        .map_err(|why| format!("{name}: {why}"))?;
    if let Some(sha) = &t.mesh_sha256 {
        let now = crate::io::heat_map::file_sha256(path)?;
        if *sha != now {
            return Err(format!(
                "{name} has changed since this config was resolved (SHA-256 {now}, recorded {sha}); restore the mesh or start a new run"
            ));
        }
    }
    Ok(mesh)
}

/// The placement of a target: scale, then turn about y (from +x towards +z), then translate.
pub fn place_point(v: [f64; 3], t: &TargetConfig) -> [f64; 3] {
    let s = t.scale3();
    let (sin, cos) = t.rotate_y.to_radians().sin_cos();
    let (x, y, z) = (v[0] * s[0], v[1] * s[1], v[2] * s[2]);
    [
        cos * x - sin * z + t.translate[0],
        y + t.translate[1],
        sin * x + cos * z + t.translate[2],
    ]
}

/// The mesh's vertices placed in the domain: scaled, turned about y (from +x towards +z),
/// translated.
pub fn place(mesh: &Mesh, t: &TargetConfig) -> Mesh {
    let vertices = mesh.vertices.iter().map(|v| place_point(*v, t)).collect();
    Mesh {
        vertices,
        triangles: mesh.triangles.clone(),
    }
}

/// Inside flags of every voxel of `grid` (by its centre), by ray parity: a vertical ray through
/// each column (nudged by a tiny irrational offset, so it misses edges and vertices of meshes
/// on round coordinates) crosses the surface at sorted heights; a centre with an odd number of
/// crossings below it is inside.
pub fn voxelize(mesh: &Mesh, grid: &VoxelGrid) -> Vec<bool> {
    let mut inside = vec![false; grid.len()];
    let tris: Vec<[[f64; 3]; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| mesh.vertices[i as usize]))
        .collect();
    let mut ys = Vec::new();
    for k in 0..grid.n[2] {
        for i in 0..grid.n[0] {
            let x = (i as f64 + 0.5) * grid.cell[0]
                + 1.0e-7 * grid.cell[0] * std::f64::consts::FRAC_1_PI;
            let z =
                (k as f64 + 0.5) * grid.cell[2] + 1.0e-7 * grid.cell[2] * std::f64::consts::LN_2;
            ys.clear();
            for t in &tris {
                if let Some(y) = vertical_hit(t, x, z) {
                    ys.push(y);
                }
            }
            if ys.is_empty() {
                continue;
            }
            ys.sort_by(f64::total_cmp);
            for j in 0..grid.n[1] {
                let y = (j as f64 + 0.5) * grid.cell[1];
                let below = ys.partition_point(|h| *h < y);
                inside[grid.index(i, j, k)] = below % 2 == 1;
            }
        }
    }
    inside
}

/// Height where the vertical line through (x, z) crosses triangle t, if it does.
fn vertical_hit(t: &[[f64; 3]; 3], x: f64, z: f64) -> Option<f64> {
    let [a, b, c] = t;
    let d = (b[0] - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (b[2] - a[2]);
    if d == 0.0 {
        return None; // a vertical triangle: the ray grazes it
    }
    let u = ((x - a[0]) * (c[2] - a[2]) - (c[0] - a[0]) * (z - a[2])) / d;
    let v = ((b[0] - a[0]) * (z - a[2]) - (x - a[0]) * (b[2] - a[2])) / d;
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(a[1] + u * (b[1] - a[1]) + v * (c[1] - a[1]))
}
