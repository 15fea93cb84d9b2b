//! `nimbus preview --view sources|target|particles` and `output.preview.source_overlay`
//! (issue 18's debug view) on real runs: each view writes its own folder in the volume
//! preview's camera, drawn where the sources, the target and the particles are; the volume view
//! and the run's previews stay byte for byte; a view with nothing to draw is one line, exit 2,
//! nothing written.
mod common;
use common::*;
use glam::DVec3;
use nimbus::preview::overlay::project;
use nimbus::preview::PreviewParams;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const CUBE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
    f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

/// A ground disc in the middle, a sphere in the air, a box in the air that switches on long
/// after the run (drawn dimmed), and a cube target 300 m wide from 350 m up.
const SHOT: &str = "shot: views\nseed: 3\noutput:\n  frames: {start: 1, end: 3}\n  frame_seconds: 5.0\n  substeps: 2\n  preview: {enabled: true, resolution: [160, 90]}\n\
domain:\n  size: [800, 800, 800]\n  spacing: 50\n\
physics:\n  initial_vapor: 0.95\n  sources: [\
{shape: disc, center: [400, 400], radius: 250, strength: 0.2}, \
{shape: sphere, center: [200, 500, 600], radius: 120, strength: 0.05}, \
{shape: box, center: [600, 300, 200], size: [150, 100, 150], strength: 0.05, start: 1000}]\n\
control:\n  target: {mesh: cube.obj, scale: [300], translate: [250, 350, 250]}\n\
adaptive:\n  enabled: true\nexport:\n  voxel_size: 25\n  particles: true\ncheckpoint:\n  every: 2\n  keep: 5\n";

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

fn png(p: &Path) -> image::RgbImage {
    image::open(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .to_rgb8()
}

fn preview(out: &Path, args: &[&str]) -> std::process::Output {
    nimbus()
        .arg("preview")
        .arg(out)
        .args(args)
        .output()
        .unwrap()
}

/// The pixel a world point projects to with the run's preview camera.
fn pixel(params: &PreviewParams, p: DVec3) -> (u32, u32) {
    let (x, y, _) = project(params, p).expect("in front of the camera");
    assert!(x >= 0.0 && y >= 0.0 && x < params.width as f64 && y < params.height as f64);
    (x as u32, y as u32)
}

fn rgb(img: &image::RgbImage, (x, y): (u32, u32)) -> [i32; 3] {
    img.get_pixel(x, y).0.map(i32::from)
}

#[test]
fn each_view_draws_its_own_folder_and_leaves_the_previews_alone() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cube.obj"), CUBE).unwrap();
    let cfg_path = d.join("views.yaml");
    std::fs::write(&cfg_path, SHOT).unwrap();
    let out = d.join("run");
    let o = nimbus()
        .arg("run")
        .arg(&cfg_path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let cfg = nimbus::shot::load(&cfg_path, &[]).unwrap().into_config();
    let params = PreviewParams::for_shot(&cfg).unwrap();
    let names: Vec<String> = (1..=3).map(|f| format!("views.{f:04}.png")).collect();
    let run_previews = snapshot(&out.join("preview"));

    // volume: the run's own previews, byte for byte
    let o = preview(&out, &["--view", "volume"]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(snapshot(&out.join("preview")), run_previews);

    // sources: the disc tints the ground under it; the sphere's wires change its pixels
    let o = preview(&out, &["--view", "sources"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("3 previews written to"),
        "{}",
        text(&o)
    );
    let vol = png(&out.join("preview").join(&names[2]));
    let src = png(&out.join("preview/sources").join(&names[2]));
    assert!(out.join("preview/sources/contact_sheet.png").is_file());
    let under = pixel(&params, DVec3::new(400.0, 0.0, 400.0));
    let (a, b) = (rgb(&vol, under), rgb(&src, under));
    assert!(
        b[0] > a[0] + 30 && b[2] < a[2] - 30,
        "disc centre {a:?} -> {b:?}"
    );
    // beside the disc, far from every source: not tinted. From the preview's camera on the
    // ground the ground is one pixel row, where the domain box's bottom edges are drawn as
    // faint white wires: they lighten it evenly, the disc's fill tints it orange
    let beside = pixel(&params, DVec3::new(100.0, 0.0, 400.0));
    let (a, b) = (rgb(&vol, beside), rgb(&src, beside));
    assert!(
        ((b[0] - a[0]) - (b[2] - a[2])).abs() <= 8,
        "beside {a:?} -> {b:?}"
    );
    // the sky away from the box and the sources: untouched
    assert_eq!(rgb(&vol, (2, 2)), rgb(&src, (2, 2)));
    let (sx, sy) = pixel(&params, DVec3::new(200.0, 500.0, 600.0));
    let changed = (sx.saturating_sub(12)..(sx + 12).min(160))
        .flat_map(|x| (sy.saturating_sub(12)..(sy + 12).min(90)).map(move |y| (x, y)))
        .filter(|&p| rgb(&vol, p) != rgb(&src, p))
        .count();
    assert!(changed > 20, "{changed} pixels of the sphere's wires");

    // target: the ghost over the cube's middle
    let o = preview(&out, &["--view", "target"]);
    assert!(o.status.success(), "{}", text(&o));
    let tgt = png(&out.join("preview/target").join(&names[2]));
    let inside = pixel(&params, DVec3::new(400.0, 500.0, 400.0));
    let (a, b) = (rgb(&vol, inside), rgb(&tgt, inside));
    assert!(
        b[0] > a[0] + 10 && b[0] - b[1] > a[0] - a[1] + 10,
        "{a:?} -> {b:?}"
    );
    // the sky outside the domain's box is untouched
    assert_eq!(rgb(&vol, (2, 2)), rgb(&tgt, (2, 2)));

    // particles: discs in the level colours over a dark grey
    let o = preview(&out, &["--view", "particles"]);
    assert!(o.status.success(), "{}", text(&o));
    let pdir = out.join("preview/particles");
    let first = png(&pdir.join(&names[1]));
    assert_eq!(rgb(&first, (0, 45)), [39, 39, 39], "background");
    let centre = rgb(&first, pixel(&params, DVec3::new(400.0, 400.0, 800.0)));
    assert!(centre[2] > centre[0] + 60, "level 0 is blue: {centre:?}");
    let frame2 = std::fs::read(pdir.join(&names[1])).unwrap();
    for n in &names {
        assert!(out.join("preview/sources").join(n).is_file(), "{n}");
        assert!(out.join("preview/target").join(n).is_file(), "{n}");
        assert!(pdir.join(n).is_file(), "{n}");
    }
    // no view touched the run's previews
    let now: BTreeMap<_, _> = snapshot(&out.join("preview"))
        .into_iter()
        .filter(|(p, _)| p.parent() == Some(&out.join("preview")))
        .collect();
    assert_eq!(now, run_previews);

    // Without caches: frame 2 from its checkpoint (the same particles), frame 1 (none) skipped
    // with a note.
    for f in [1, 2] {
        std::fs::remove_file(out.join(format!("particles/views.{f:04}.ply"))).unwrap();
    }
    let o = preview(&out, &["--view", "particles"]);
    assert!(o.status.success(), "{}", text(&o));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        err.lines().collect::<Vec<_>>(),
        ["note: no particle cache or checkpoint for frame 1; skipped"],
        "{}",
        text(&o)
    );
    assert!(!pdir.join(&names[0]).exists());
    assert_eq!(std::fs::read(pdir.join(&names[1])).unwrap(), frame2);
    assert!(pdir.join(&names[2]).is_file());
}

#[test]
fn views_with_nothing_to_draw_are_refused_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = run_tiny(&out, &["--set", "output.frames.end=1"]);
    assert!(o.status.success(), "{}", text(&o));
    for (view, words) in [
        ("sources", "--view sources: the run has no physics.sources"),
        ("target", "--view target: the run has no control.target"),
        (
            "particles",
            "--view particles: the run has no particle caches",
        ),
    ] {
        if view == "particles" {
            std::fs::remove_dir_all(out.join("checkpoints")).unwrap();
        }
        let before = snapshot(&out);
        let o = preview(&out, &["--view", view]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{}", text(&o));
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.contains(words), "{err}");
        assert_eq!(snapshot(&out), before, "--view {view} wrote");
    }
    let o = preview(&out, &["--view", "sideways"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}

#[test]
fn source_overlay_draws_into_the_run_previews() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cube.obj"), CUBE).unwrap();
    let cfg_path = d.join("views.yaml");
    std::fs::write(&cfg_path, SHOT).unwrap();
    let run = |name: &str, overlay: bool| {
        let out = d.join(name);
        let o = nimbus()
            .arg("run")
            .arg(&cfg_path)
            .arg("--out")
            .arg(&out)
            .args([
                "--set",
                "output.frames.end=1",
                "--set",
                "export.particles=false",
            ])
            .args(["--set", &format!("output.preview.source_overlay={overlay}")])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o));
        out
    };
    let (plain, drawn) = (run("plain", false), run("drawn", true));
    let cfg = nimbus::shot::load(&cfg_path, &[]).unwrap().into_config();
    let params = PreviewParams::for_shot(&cfg).unwrap();
    let name = "preview/views.0001.png";
    let (a, b) = (png(&plain.join(name)), png(&drawn.join(name)));
    let under = pixel(&params, DVec3::new(400.0, 0.0, 400.0));
    assert!(
        rgb(&b, under)[0] > rgb(&a, under)[0] + 30,
        "{:?} -> {:?}",
        rgb(&a, under),
        rgb(&b, under)
    );
    // off: the key is not in the manifest, so earlier runs' config hashes are unchanged
    assert!(manifest(&plain)["config"]["output"]["preview"]
        .get("source_overlay")
        .is_none());
    assert_eq!(
        manifest(&drawn)["config"]["output"]["preview"]["source_overlay"],
        true
    );
    // `nimbus preview` re-makes the overlaid previews byte for byte
    let before = std::fs::read(drawn.join(name)).unwrap();
    let o = preview(&drawn, &[]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(std::fs::read(drawn.join(name)).unwrap(), before);

    // a shot without sources is refused
    let bad = d.join("bad.yaml");
    std::fs::write(
        &bad,
        "shot: bad\noutput:\n  frames: {start: 1, end: 1}\n  preview: {enabled: true, source_overlay: true}\ndomain: {size: [800, 800, 800], spacing: 50}\n",
    )
    .unwrap();
    assert_refused(
        &bad,
        &[],
        "4:28",
        "output.preview.source_overlay",
        "the shot has none",
        &d.join("bad_run"),
    );
}
