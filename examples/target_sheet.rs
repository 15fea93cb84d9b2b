//! The side-by-side image of docs/ART_DIRECTION.md "Shot 3": for each run directory given, its
//! last preview frame and the controller's voxels at its newest checkpoint, seen from the front
//! (x right, y up) and from above (x right, z down): white = cloud inside the target, blue =
//! target without cloud, orange = cloud outside the target (a voxel column is coloured by the
//! most frequent of these along the view direction). Prints each run's voxel counts and IoU.
//!
//!     cargo run --release --example target_sheet -- OUT.png RUN_DIR [RUN_DIR ...]
use image::{imageops, Rgb, RgbImage};
use nimbus::io::checkpoint::format::{config_of, read_checkpoint};
use nimbus::sim::control::Target;
use std::path::Path;

const PX: u32 = 10;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        eprintln!("usage: target_sheet OUT.png RUN_DIR [RUN_DIR ...]");
        std::process::exit(2);
    }
    let mut rows = Vec::new();
    for dir in &args[1..] {
        let dir = Path::new(dir);
        let ck = nimbus::io::checkpoint::store::list_checkpoints(&dir.join("checkpoints"))
            .expect("a run directory")
            .into_iter()
            .max_by_key(|c| c.0)
            .expect("a checkpoint");
        let ck = read_checkpoint(&ck.1).expect("a readable checkpoint");
        let cfg = config_of(&ck).expect("the run's config");
        let shot = nimbus::shot::Shot::prepare(cfg.clone()).expect("its target");
        let target = Target::of_shot(&shot).expect("control.target");
        let cloud = target.cloud_voxels(&ck.state);
        let g = target.grid;
        let kind = |v: usize| match (target.inside[v], cloud[v]) {
            (true, true) => 0,
            (true, false) => 1,
            (false, true) => 2,
            _ => 3,
        };
        let counts = (0..g.len()).fold([0usize; 4], |mut c, v| {
            c[kind(v)] += 1;
            c
        });
        println!(
            "{}: frame {}: {} voxels cloud and target, {} target only, {} cloud only; IoU {:.3}",
            dir.display(),
            ck.header.frame,
            counts[0],
            counts[1],
            counts[2],
            counts[0] as f64 / (counts[0] + counts[1] + counts[2]).max(1) as f64
        );
        let colour = [
            Rgb([245, 245, 245]),
            Rgb([60, 90, 200]),
            Rgb([240, 140, 30]),
            Rgb([25, 25, 35]),
        ];
        // a view: (width axis, height axis, depth axis, flip height)
        let view = |a: usize, b: usize, c: usize, up: bool| {
            let mut img = RgbImage::new(g.n[a] as u32 * PX, g.n[b] as u32 * PX);
            for u in 0..g.n[a] {
                for w in 0..g.n[b] {
                    let mut n = [0usize; 4];
                    for d in 0..g.n[c] {
                        let mut ijk = [0; 3];
                        ijk[a] = u;
                        ijk[b] = w;
                        ijk[c] = d;
                        n[kind(g.index(ijk[0], ijk[1], ijk[2]))] += 1;
                    }
                    let k = (0..3)
                        .max_by_key(|k| (n[*k], 3 - *k))
                        .filter(|k| n[*k] > 0)
                        .unwrap_or(3);
                    let row = if up { g.n[b] - 1 - w } else { w };
                    for y in 0..PX {
                        for x in 0..PX {
                            let edge = x == 0 || y == 0;
                            let c = if edge { Rgb([0, 0, 0]) } else { colour[k] };
                            img.put_pixel(u as u32 * PX + x, row as u32 * PX + y, c);
                        }
                    }
                }
            }
            img
        };
        let front = view(0, 1, 2, true);
        let top = view(0, 2, 1, false);
        let last = cfg.output.frames.end.min(ck.header.frame);
        let name = format!(
            "{}.{:0w$}.png",
            cfg.shot,
            last,
            w = cfg.output.frame_padding as usize
        );
        let preview = image::open(dir.join("preview").join(name))
            .map(|i| i.to_rgb8())
            .unwrap_or_else(|_| RgbImage::new(320, 180));
        let h = front.height().max(top.height());
        let preview = imageops::resize(&preview, h * 16 / 9, h, imageops::FilterType::Triangle);
        let mut row = RgbImage::from_pixel(
            preview.width() + front.width() + top.width() + 2 * PX,
            h,
            Rgb([255, 255, 255]),
        );
        imageops::overlay(&mut row, &preview, 0, 0);
        imageops::overlay(&mut row, &front, (preview.width() + PX) as i64, 0);
        imageops::overlay(
            &mut row,
            &top,
            (preview.width() + front.width() + 2 * PX) as i64,
            0,
        );
        rows.push(row);
    }
    let w = rows.iter().map(|r| r.width()).max().unwrap_or(1);
    let h: u32 = rows.iter().map(|r| r.height() + PX).sum();
    let mut sheet = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let mut y = 0;
    for r in &rows {
        imageops::overlay(&mut sheet, r, 0, y as i64);
        y += r.height() + PX;
    }
    sheet.save(&args[0]).expect("the sheet written");
}
