//! Preview: sky alone, Beer-Lambert, sun side vs shadow side, determinism, files, contact sheet.
use glam::DVec3;
use nimbus::ground::ParticleState;
use nimbus::ground::{GridTransform, Leaf, SparseGrid, LEAF_VOXELS};
use nimbus::preview::particles::{render_particles, ParticleColor};
use nimbus::preview::{
    auto_camera, contact_sheet, png_bytes, render, write_contact_sheet, write_frame_preview,
    Camera, LinearImage, PreviewParams,
};

/// A grid of `dim`^3 voxels (voxel 1 m, centres at i + 0.5) with `f` as density where positive.
fn grid_from(dim: i32, f: impl Fn([f64; 3]) -> f32) -> SparseGrid<f32> {
    let mut leaves = Vec::new();
    for x in (0..dim).step_by(8) {
        for y in (0..dim).step_by(8) {
            for z in (0..dim).step_by(8) {
                let mut values = Box::new([0.0f32; LEAF_VOXELS]);
                let mut mask = [0u64; 8];
                for m in 0..LEAF_VOXELS {
                    let v = [
                        x + (m as i32 >> 6),
                        y + ((m as i32 >> 3) & 7),
                        z + (m as i32 & 7),
                    ];
                    let d = f(v.map(|c| c as f64 + 0.5));
                    if d > 0.0 {
                        values[m] = d;
                        mask[m / 64] |= 1 << (m % 64);
                    }
                }
                if mask.iter().any(|&w| w != 0) {
                    leaves.push(Leaf {
                        origin: [x, y, z],
                        values,
                        mask,
                    });
                }
            }
        }
    }
    SparseGrid {
        name: "density".into(),
        background: 0.0,
        transform: GridTransform {
            voxel_size: 1.0,
            origin: [0.5; 3],
        },
        leaves,
    }
}

fn side_params(w: u32, h: u32) -> PreviewParams {
    let cam = Camera {
        position: DVec3::new(32.0, 32.0, 160.0),
        look_at: DVec3::new(32.0, 32.0, 32.0),
        fov_deg: 40.0,
    };
    let mut p = PreviewParams::defaults(cam, w, h);
    // The test clouds hold density ~1: an optically thick extinction, whatever the default.
    p.density_scale = 1.0;
    p
}

fn sphere(c: [f64; 3], r: f64, rho: f32) -> impl Fn([f64; 3]) -> f32 {
    move |p| {
        let d2: f64 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum();
        if d2 < r * r {
            rho
        } else {
            0.0
        }
    }
}

#[test]
fn empty_grid_renders_the_sky_alone() {
    let g = grid_from(16, |_| 0.0);
    assert!(g.leaves.is_empty());
    let p = PreviewParams::defaults(auto_camera([100.0, 50.0, 100.0], 16.0 / 9.0, 45.0), 64, 36);
    let img = render(&g, &p).unwrap();
    let sky = p.sky();
    let mut ground = 0;
    for y in 0..36 {
        for x in 0..64 {
            let s = sky.radiance(p.ray(x, y));
            let v = img.pixel(x, y);
            assert_eq!(
                [v[0], v[1], v[2], v[3]],
                [s[0] as f32, s[1] as f32, s[2] as f32, 0.0]
            );
            if p.ray(x, y)[1] < 0.0 {
                ground += 1;
            }
        }
    }
    // Side view: the ground is in the lower part of the frame, the sky above.
    assert!(ground > 0 && ground < 64 * 36);
    assert!(p.ray(32, 35)[1] < 0.0 && p.ray(32, 0)[1] > 0.0);
}

#[test]
fn a_denser_cloud_transmits_less_light() {
    let p = side_params(32, 32);
    let thin = render(&grid_from(64, sphere([32.0; 3], 12.0, 0.05)), &p).unwrap();
    let dense = render(&grid_from(64, sphere([32.0; 3], 12.0, 0.10)), &p).unwrap();
    let (tt, td) = (
        1.0 - thin.pixel(16, 16)[3] as f64,
        1.0 - dense.pixel(16, 16)[3] as f64,
    );
    assert!(tt < 0.9 && td < tt, "thin {tt}, dense {td}");
    // Beer-Lambert: twice the density squares the transmittance along the same ray.
    assert!((td - tt * tt).abs() < 1e-4, "{td} vs {}", tt * tt);
    // Behind the cloud less of the sky comes through; the cloud itself is lit.
    assert!(dense.pixel(16, 16)[0] > 0.0);
}

#[test]
fn the_sun_side_is_brighter_than_the_shadow_side() {
    let mut p = side_params(64, 64);
    p.sun_direction = DVec3::new(1.0, 0.2, 0.0).normalize();
    let img = render(&grid_from(64, sphere([32.0; 3], 14.0, 0.3)), &p).unwrap();
    let lum = |v: [f32; 4]| 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2];
    // Columns about 0.6 radius left and right of the centre, centre rows.
    let (mut sun, mut shade) = (0.0, 0.0);
    for y in 28..36 {
        sun += lum(img.pixel(37, y));
        shade += lum(img.pixel(26, y));
        assert!(img.pixel(37, y)[3] > 0.9 && img.pixel(26, y)[3] > 0.9);
    }
    assert!(sun > 1.5 * shade, "sun side {sun}, shadow side {shade}");
}

#[test]
fn previews_are_deterministic_and_decode() {
    let g = grid_from(64, |p| {
        let a = sphere([28.0, 30.0, 32.0], 12.0, 0.2)(p);
        let b = sphere([40.0, 36.0, 30.0], 9.0, 0.4)(p);
        a + b
    });
    let p = side_params(80, 45);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render(&g, &p).unwrap())
    };
    let a = run(1);
    let b = run(2);
    assert_eq!(a, b);
    let pa = png_bytes(&a.to_srgb8(p.exposure)).unwrap();
    let pb = png_bytes(&run(2).to_srgb8(p.exposure)).unwrap();
    assert_eq!(pa, pb);
    let img = image::load_from_memory(&pa).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (80, 45));
    // The files: PNG and linear EXR under <out>/preview, readable back.
    let dir = tempfile::tempdir().unwrap();
    let run = nimbus::pipeline::run_dir::RunDir::new(dir.path());
    let at = run.frame_file(
        nimbus::pipeline::run_dir::FrameFile::PreviewPng,
        "shot",
        7,
        4,
    );
    let png = write_frame_preview(&g, &p, &at, true).unwrap();
    assert_eq!(png, dir.path().join("preview/shot.0007.png"));
    assert_eq!(std::fs::read(&png).unwrap(), pa);
    let exr = exr::prelude::read_first_rgba_layer_from_file(
        dir.path().join("preview/shot.0007.exr"),
        |res, _| (res.width(), vec![[0.0f32; 4]; res.width() * res.height()]),
        |(w, px), pos, (r, g, b, al): (f32, f32, f32, f32)| {
            px[pos.y() * *w + pos.x()] = [r, g, b, al]
        },
    )
    .unwrap();
    let (w, px) = exr.layer_data.channel_data.pixels;
    assert_eq!(w, 80);
    assert_eq!(px, a.data);
}

fn solid(w: u32, h: u32, c: [u8; 3]) -> image::RgbImage {
    image::RgbImage::from_pixel(w, h, image::Rgb(c))
}

#[test]
fn contact_sheet_tiles_and_labels_frames() {
    let frames: Vec<(u32, image::RgbImage)> = (0..5)
        .map(|i| (10 + i, solid(64, 36, [50 * i as u8, 100, 150])))
        .collect();
    let sheet = contact_sheet(&frames, 64).unwrap();
    // 5 frames -> 3 columns x 2 rows of 64x36 tiles with 2-pixel gaps.
    assert_eq!(sheet.dimensions(), (3 * 64 + 4 * 2, 2 * 36 + 3 * 2));
    // Tile 4 (row 1, col 1) keeps its colour away from the label ...
    let (x4, y4) = (2 + 66, 2 + 38);
    assert_eq!(sheet.get_pixel(x4 + 50, y4 + 30).0, [200, 100, 150]);
    // ... and carries a white label in its top-left corner.
    let white = (0..20)
        .flat_map(|dy| (0..30).map(move |dx| (dx, dy)))
        .filter(|&(dx, dy)| sheet.get_pixel(x4 + dx, y4 + dy).0 == [255, 255, 255])
        .count();
    assert!(white > 10);
    // Different frame numbers give different labels.
    let a = contact_sheet(&[(1, solid(64, 36, [0; 3]))], 64).unwrap();
    let b = contact_sheet(&[(7, solid(64, 36, [0; 3]))], 64).unwrap();
    assert_ne!(a, b);
    assert!(contact_sheet(&[], 64).is_err());
    // From files, sorted by frame, into <out>/preview/contact_sheet.png.
    let dir = tempfile::tempdir().unwrap();
    let mut list = Vec::new();
    for (f, img) in frames.iter().rev() {
        let path = dir.path().join(format!("f{f}.png"));
        std::fs::write(&path, png_bytes(img).unwrap()).unwrap();
        list.push((*f, path));
    }
    let run = nimbus::pipeline::run_dir::RunDir::new(dir.path());
    let out = write_contact_sheet(&run.contact_sheet(), &list).unwrap();
    assert_eq!(out, dir.path().join("preview/contact_sheet.png"));
    let back = image::open(&out).unwrap().to_rgb8();
    assert_eq!(back.dimensions(), (320 * 3 + 8, 180 * 2 + 6));
    let bad = write_contact_sheet(&run.contact_sheet(), &[(1, dir.path().join("missing.png"))]);
    assert_eq!(bad.unwrap_err().exit_code(), 2);
}

#[test]
fn particle_debug_view_colours_by_level() {
    let mut st = ParticleState::default();
    for (i, x) in [12.0f32, 52.0].iter().enumerate() {
        st.pos.push([*x, 32.0, 32.0, 0.0]);
        st.vel.push([0.0; 4]);
        st.thermo.push([290.0, 0.0, 0.0, 0.0]);
        st.info.push([i as u32, i as u32 * 3]);
        st.density.push(1.0);
    }
    let p = side_params(64, 64);
    let img = render_particles(&st, &p, 16.0, ParticleColor::Level { max_level: 3 }, 1.0).unwrap();
    let left = img.pixel(18, 32);
    let right = img.pixel(45, 32);
    assert_eq!(left[3], 1.0);
    assert_eq!(right[3], 1.0);
    // Level 0 blue, level 3 red.
    assert!(left[2] > left[0] && right[0] > right[2]);
    let again =
        render_particles(&st, &p, 16.0, ParticleColor::Level { max_level: 3 }, 1.0).unwrap();
    assert_eq!(img, again);
}

#[test]
fn bad_preview_parameters_are_errors() {
    let g = grid_from(8, |_| 0.1);
    let mut p = side_params(16, 16);
    p.camera.look_at = p.camera.position;
    assert_eq!(render(&g, &p).unwrap_err().exit_code(), 2);
    let mut p = side_params(0, 16);
    assert!(render(&g, &p).is_err());
    p.width = 16;
    p.density_scale = f64::NAN;
    assert!(render(&g, &p).is_err());
    let cfg = nimbus::config::PreviewConfig {
        sun_direction: [0.0; 3],
        ..Default::default()
    };
    assert!(PreviewParams::from_config(&cfg, [10.0; 3], 0.165).is_err());
    let ok =
        PreviewParams::from_config(&Default::default(), [3000.0, 1500.0, 3000.0], 0.165).unwrap();
    let img: LinearImage = render(&g, &ok).unwrap();
    assert_eq!((img.width, img.height), (640, 360));
}
