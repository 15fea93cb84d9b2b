//! Contact sheet: the frames of a shot tiled in a grid, each labelled with its frame number.
use crate::error::{Error, Result};
use image::{Rgb, RgbImage};
use std::path::{Path, PathBuf};

/// 3x5 bitmap digits, one row per byte (bit 2 = left column).
const DIGITS: [[u8; 5]; 10] = [
    [0b111, 0b101, 0b101, 0b101, 0b111],
    [0b010, 0b110, 0b010, 0b010, 0b111],
    [0b111, 0b001, 0b111, 0b100, 0b111],
    [0b111, 0b001, 0b011, 0b001, 0b111],
    [0b101, 0b101, 0b111, 0b001, 0b001],
    [0b111, 0b100, 0b111, 0b001, 0b111],
    [0b111, 0b100, 0b111, 0b101, 0b111],
    [0b111, 0b001, 0b010, 0b010, 0b010],
    [0b111, 0b101, 0b111, 0b101, 0b111],
    [0b111, 0b101, 0b111, 0b001, 0b111],
];

/// Draws `n` at (x, y) with `scale`-pixel dots, white on a dark box; clipped to the image.
pub fn draw_number(img: &mut RgbImage, x: u32, y: u32, n: u32, scale: u32) {
    let text = n.to_string();
    let (cw, ch) = (3 * scale, 5 * scale);
    let pad = scale;
    let box_w = text.len() as u32 * (cw + scale) + pad;
    let box_h = ch + 2 * pad;
    let mut put = |px: u32, py: u32, c: Rgb<u8>| {
        if px < img.width() && py < img.height() {
            img.put_pixel(px, py, c);
        }
    };
    for py in y..y + box_h {
        for px in x..x + box_w {
            put(px, py, Rgb([16, 16, 16]));
        }
    }
    for (i, c) in text.bytes().enumerate() {
        let glyph = DIGITS[(c - b'0') as usize];
        let gx = x + pad + i as u32 * (cw + scale);
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..3 {
                if bits >> (2 - col) & 1 == 1 {
                    for sy in 0..scale {
                        for sx in 0..scale {
                            put(
                                gx + col * scale + sx,
                                y + pad + row as u32 * scale + sy,
                                Rgb([255, 255, 255]),
                            );
                        }
                    }
                }
            }
        }
    }
}

/// Tiles `frames` (frame number, image) in a near-square grid of `tile_width`-wide thumbnails
/// (height from the first frame's aspect), each labelled at its top-left corner.
pub fn contact_sheet(frames: &[(u32, RgbImage)], tile_width: u32) -> Result<RgbImage> {
    let Some((_, first)) = frames.first() else {
        return Err(Error::InvalidInput("contact sheet: no frames".into()));
    };
    if first.width() == 0 || first.height() == 0 || tile_width == 0 {
        return Err(Error::InvalidInput("contact sheet: empty image".into()));
    }
    let tw = tile_width;
    let th = ((tw as u64 * first.height() as u64) / first.width() as u64).max(1) as u32;
    let cols = (frames.len() as f64).sqrt().ceil() as u32;
    let rows = (frames.len() as u32).div_ceil(cols);
    let gap = 2;
    let mut sheet = RgbImage::from_pixel(
        cols * tw + (cols + 1) * gap,
        rows * th + (rows + 1) * gap,
        Rgb([40, 40, 40]),
    );
    let scale = (tw / 160).max(1) * 2;
    for (i, (frame, img)) in frames.iter().enumerate() {
        let thumb = if img.width() == tw && img.height() == th {
            img.clone()
        } else {
            image::imageops::resize(img, tw, th, image::imageops::FilterType::Triangle)
        };
        let x = gap + (i as u32 % cols) * (tw + gap);
        let y = gap + (i as u32 / cols) * (th + gap);
        image::imageops::replace(&mut sheet, &thumb, x as i64, y as i64);
        draw_number(&mut sheet, x + 2, y + 2, *frame, scale);
    }
    Ok(sheet)
}

/// Reads the frames' PNGs and writes their contact sheet to `path` (`preview/contact_sheet.png`
/// of a run), sorted by frame.
pub fn write_contact_sheet(path: &Path, frames: &[(u32, PathBuf)]) -> Result<PathBuf> {
    let mut sorted = frames.to_vec();
    sorted.sort();
    let mut images = Vec::with_capacity(sorted.len());
    for (f, p) in &sorted {
        let img = image::open(p)
            .map_err(|e| Error::InvalidInput(format!("{}: {e}", p.display())))?
            .to_rgb8();
        images.push((*f, img));
    }
    let sheet = contact_sheet(&images, 320)?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    crate::io::atomic::write_atomic(path, &super::png_bytes(&sheet)?)?;
    Ok(path.to_path_buf())
}
