//! The velocity grid is what a renderer's motion blur needs: with `export.velocity_time:
//! playback` (the default) the density-weighted mean `vel` of the cloud, divided by fps, is the
//! displacement of the cloud's density centroid from one frame to the next (scene units per
//! frame). A cloud that condenses in place moves its centroid without moving its air, so the
//! shot gets a uniform wind first: its checkpoint is boosted by a constant velocity (a Galilean
//! boost: PBF, XSPH and the periodic x axis carry it unchanged) and the run resumed from it.
mod common;
use common::*;
use nimbus::io::checkpoint::{read_checkpoint, write_checkpoint};
use nimbus::io::vdb::{read_file, GridData, MetaValue};
use std::path::Path;

const SHOT: &str = "shot: thermal
seed: 5
output:
  frames: { start: 1, end: 22 }
  fps: 24
  frame_seconds: 4.0
  substeps: 2
  preview: { enabled: false }
domain:
  size: [1600, 1600, 1600]
  spacing: 100
physics:
  initial_vapor: 0.97
  heat_noise: false
  sources:
    - { shape: disc, center: [800, 800], radius: 500, strength: 0.3, end: 60 }
export:
  voxel_size: 50
  exr: { enabled: false }
checkpoint: { every: 0 }
";
/// Wind added at the checkpoint (m/s along x) and the frames run after it.
const WIND: f32 = 12.0;
const BOOSTED_END: u32 = 27;

/// Density-weighted centroid (scene units) and mean velocity (grid units) of a frame's cloud.
fn cloud_moments(path: &Path) -> ([f64; 3], [f64; 3], f64) {
    let file = read_file(path).unwrap();
    let Some(GridData::Float(d)) = file.grid("density").map(|g| &g.data) else {
        panic!("{}: no density grid", path.display())
    };
    let Some(GridData::Vec3(v)) = file.grid("vel").map(|g| &g.data) else {
        panic!("{}: no vel grid", path.display())
    };
    let (mut m, mut c, mut u) = (0.0, [0.0; 3], [0.0; 3]);
    for leaf in &d.leaves {
        for n in 0..512 {
            if !leaf.is_active(n) {
                continue;
            }
            let local = [(n >> 6) as i32, ((n >> 3) & 7) as i32, (n & 7) as i32];
            let ijk = [0, 1, 2].map(|k| leaf.origin[k] + local[k]);
            let w = leaf.values[n] as f64;
            let p = d.transform.index_to_world(ijk.map(|x| x as f64));
            let vel = v.get(ijk);
            m += w;
            for k in 0..3 {
                c[k] += w * p[k];
                u[k] += w * vel[k] as f64;
            }
        }
    }
    assert!(m > 0.0, "{}: empty cloud", path.display());
    (c.map(|x| x / m), u.map(|x| x / m), m)
}

fn norm(v: [f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

#[test]
fn mean_velocity_over_fps_is_the_centroid_displacement() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("export_velocity");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("thermal.yaml");
    std::fs::write(&cfg, SHOT).unwrap();
    let out = dir.join("run");
    let o = nimbus()
        .arg("run")
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));

    let ck_path = out.join("checkpoints").join("ckpt_000022.nck");
    let mut ck = read_checkpoint(&ck_path).unwrap();
    for v in &mut ck.state.vel {
        v[0] += WIND;
    }
    write_checkpoint(&out.join("checkpoints"), &ck).unwrap();
    let o = nimbus()
        .arg("run")
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .arg("--resume")
        .args(["--set", &format!("output.frames.end={BOOSTED_END}")])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));

    let fps = 24.0;
    // From frame 23 on, both ends of every interval carry the wind.
    let frames: Vec<_> = (23..=BOOSTED_END)
        .map(|f| cloud_moments(&out.join(format!("vdb/thermal.{f:04}.vdb"))))
        .collect();
    for (f, w) in (24..=BOOSTED_END).zip(frames.windows(2)) {
        let disp = [0, 1, 2].map(|k| w[1].0[k] - w[0].0[k]);
        // the mean of the two frames' velocities: the displacement is over the whole interval
        let pred = [0, 1, 2].map(|k| 0.5 * (w[0].1[k] + w[1].1[k]) / fps);
        let err = norm([0, 1, 2].map(|k| pred[k] - disp[k])) / norm(disp);
        eprintln!(
            "frames {}-{f}: centroid moved {disp:.2?}, mean vel / fps {pred:.2?}, error {:.1}% (cloud {:.1})",
            f - 1,
            100.0 * err,
            w[1].2
        );
        assert!(err < 0.25, "frame {f}: error {:.1}% > 25%", 100.0 * err);
    }
    // the grid records its basis and unit
    let file = read_file(&out.join(format!("vdb/thermal.{BOOSTED_END:04}.vdb"))).unwrap();
    let vel = file.grid("vel").unwrap();
    assert_eq!(
        vel.meta("nimbus_velocity_time"),
        Some(&MetaValue::String("playback".into()))
    );
    assert_eq!(
        vel.meta("nimbus_velocity_unit"),
        Some(&MetaValue::String(
            "scene units per second of playback".into()
        ))
    );
}
