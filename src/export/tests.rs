use super::*;
use crate::config::{Profile, ShotConfig};

fn base() -> ShotConfig {
    crate::shot::load_str(
        "shot: t\noutput: {frames: {start: 1, end: 10}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
        "t.yaml",
        &[],
    )
    .unwrap().into_config()
}

fn grid() -> SparseGrid<f32> {
    // Two leaves, a few active voxels with distinct values, some at negative indices.
    let mut leaves = Vec::new();
    for (origin, set) in [
        ([-8, 0, 8], vec![([-8, 0, 8], 1.0), ([-1, 7, 15], 2.0)]),
        ([0, 8, -16], vec![([3, 9, -12], 3.0), ([0, 15, -9], 4.0)]),
    ] {
        let mut l = Leaf {
            origin,
            values: Box::new([0.0f32; LEAF_VOXELS]),
            mask: [0; 8],
        };
        for (ijk, v) in set {
            let n = Leaf::<f32>::offset(ijk[0], ijk[1], ijk[2]);
            l.values[n] = v;
            l.mask[n / 64] |= 1 << (n % 64);
        }
        leaves.push(l);
    }
    leaves.sort_by_key(|l| l.origin);
    SparseGrid {
        name: "density".into(),
        background: 0.0,
        transform: GridTransform {
            voxel_size: 25.0,
            origin: [12.5, 12.5, 12.5],
        },
        leaves,
    }
}

fn space(up: UpAxis, scale: f64) -> ExportSpace {
    let mut cfg = base();
    cfg.export.up_axis = Some(up);
    cfg.export.scale = scale;
    ExportSpace::from_config(&cfg)
}

/// (world position, value) of every active voxel.
fn voxels(g: &SparseGrid<f32>) -> Vec<([f64; 3], f32)> {
    let mut out = Vec::new();
    for l in &g.leaves {
        for n in 0..LEAF_VOXELS {
            if l.is_active(n) {
                let local = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
                let ijk = [0, 1, 2].map(|k| (l.origin[k] + local[k]) as f64);
                out.push((g.transform.index_to_world(ijk), l.values[n]));
            }
        }
    }
    out
}

#[test]
fn every_voxel_lands_at_its_rotated_scaled_position() {
    for up in [UpAxis::Y, UpAxis::Z] {
        for scale in [1.0, 100.0, 0.3] {
            let s = space(up, scale);
            let g = grid();
            let want: Vec<_> = voxels(&g)
                .into_iter()
                .map(|(p, v)| (s.point(p), v))
                .collect();
            let out = s.float_grid(g.clone());
            assert!(out.leaves.windows(2).all(|w| w[0].origin < w[1].origin));
            assert!(out
                .leaves
                .iter()
                .all(|l| l.origin.iter().all(|o| o % 8 == 0)));
            let got = voxels(&out);
            assert_eq!(got.len(), want.len());
            for (p, v) in &want {
                let hit = got.iter().find(|(q, w)| {
                    w == v && (0..3).all(|k| (p[k] - q[k]).abs() < 1e-9 * (1.0 + p[k].abs()))
                });
                assert!(hit.is_some(), "{up:?} {scale}: {v} at {p:?} not in {got:?}");
            }
            let back = s.float_grid_to_sim(out);
            assert_eq!(back.leaves, g.leaves, "{up:?} {scale}");
            for k in 0..3 {
                assert!((back.transform.origin[k] - g.transform.origin[k]).abs() < 1e-9);
            }
            assert!((back.transform.voxel_size - 25.0).abs() < 1e-9);
        }
    }
}

#[test]
fn velocity_basis_and_axis() {
    let mut cfg = base();
    cfg.output.frame_seconds = 8.0;
    cfg.output.fps = 24.0;
    cfg.export.scale = 2.0;
    let v = [1.0, 2.0, 3.0];
    for (t, k) in [
        (VelocityTime::Playback, 8.0 * 24.0 / 2.0),
        (VelocityTime::Simulated, 1.0 / 2.0),
        (VelocityTime::PerFrame, 8.0 / 2.0),
    ] {
        cfg.export.velocity_time = Some(t);
        let s = ExportSpace::from_config(&cfg);
        assert_eq!(s.velocity(v), [k, 2.0 * k, 3.0 * k], "{t:?}");
    }
    cfg.export.velocity_time = None;
    cfg.export.profile = Some(Profile::Blender);
    let s = ExportSpace::from_config(&cfg);
    assert_eq!(s.up_axis, UpAxis::Z);
    assert_eq!(s.velocity_time, VelocityTime::PerFrame);
    assert_eq!(s.velocity(v), [4.0, -12.0, 8.0]);
    // an explicit key wins over the profile
    cfg.export.up_axis = Some(UpAxis::Y);
    assert_eq!(ExportSpace::from_config(&cfg).up_axis, UpAxis::Y);
}

#[test]
fn velocity_grid_values_follow_the_voxels() {
    let s = space(UpAxis::Z, 10.0);
    let g = grid();
    let vg = SparseGrid {
        name: "vel".into(),
        background: [0.0f32; 3],
        transform: g.transform,
        leaves: g
            .leaves
            .iter()
            .map(|l| Leaf {
                origin: l.origin,
                values: Box::new(l.values.map(|x| [x, 2.0 * x, 3.0 * x])),
                mask: l.mask,
            })
            .collect(),
    };
    let f = s.float_grid(g);
    let v = s.velocity_grid(vg);
    assert_eq!(f.transform, v.transform);
    let k = s.time_factor() / 10.0;
    let scaled = |x: f32| (x as f64 * k) as f32;
    for (lf, lv) in f.leaves.iter().zip(&v.leaves) {
        assert_eq!(lf.mask, lv.mask);
        for n in 0..LEAF_VOXELS {
            if lf.is_active(n) {
                let x = lf.values[n];
                assert_eq!(lv.values[n], [scaled(x), -scaled(3.0 * x), scaled(2.0 * x)]);
            }
        }
    }
}

#[test]
fn profiles_set_their_conventions() {
    let mut cfg = base();
    let s = ExportSpace::from_config(&cfg);
    assert_eq!(
        (s.up_axis, s.velocity_time, s.velocity_class),
        (UpAxis::Y, VelocityTime::Playback, VectorClass::Unknown)
    );
    cfg.export.profile = Some(Profile::Renderman);
    let s = ExportSpace::from_config(&cfg);
    assert_eq!(s.velocity_time, VelocityTime::PerFrame);
    assert_eq!(s.velocity_class_name(), "fog volume");
    cfg.export.profile = Some(Profile::Blender);
    let a = ExportSpace::aliases(&cfg);
    assert_eq!(a.get("heat").map(String::as_str), Some("temperature"));
    // a configured alias of that name wins; no alias to a grid left out
    cfg.export
        .grids
        .aliases
        .insert("heat".into(), "vapor".into());
    assert_eq!(ExportSpace::aliases(&cfg)["heat"], "vapor");
    cfg.export.grids.aliases.clear();
    cfg.export.grids.temperature.clear();
    assert!(ExportSpace::aliases(&cfg).is_empty());
}
