//! The wedge contact sheet: one row per wedge (a few of its preview frames side by side) with
//! the wedge's name and values printed above the row, so a reviewer can tell the variants apart.
use crate::error::{Error, Result};
use image::{Rgb, RgbImage};
use std::path::Path;

/// 3x5 glyphs, five rows of three bits (bit 2 = left column); lower case is drawn upper case.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 3, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 2, 2, 2],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        '.' => [0, 0, 0, 0, 2],
        ',' => [0, 0, 0, 2, 4],
        ':' => [0, 2, 0, 2, 0],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '_' => [0, 0, 0, 0, 7],
        '=' => [0, 7, 0, 7, 0],
        '[' | '(' => [3, 2, 2, 2, 3],
        ']' | ')' => [6, 2, 2, 2, 6],
        '/' => [1, 1, 2, 4, 4],
        ' ' => [0; 5],
        _ => [7, 7, 7, 7, 7],
    }
}

/// Draws `text` with `scale`-pixel dots at (x, y), white, clipped to the image.
pub fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, scale: u32) {
    for (i, c) in text.chars().enumerate() {
        let gx = x + i as u32 * 4 * scale;
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..3u32 {
                if bits >> (2 - col) & 1 == 0 {
                    continue;
                }
                for sy in 0..scale {
                    for sx in 0..scale {
                        let (px, py) = (gx + col * scale + sx, y + row as u32 * scale + sy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, Rgb([255, 255, 255]));
                        }
                    }
                }
            }
        }
    }
}

/// Pixel width of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: u32) -> u32 {
    text.chars().count() as u32 * 4 * scale
}

/// One row of the sheet: its label and (frame, image) thumbnails.
pub struct SheetRow {
    pub label: String,
    pub frames: Vec<(u32, RgbImage)>,
}

/// Rows of `tile_width`-wide thumbnails under their labels; a row without frames is a grey bar
/// (its wedge wrote no previews), so every wedge has its row.
pub fn wedge_sheet(rows: &[SheetRow], tile_width: u32) -> Result<RgbImage> {
    let first = rows
        .iter()
        .flat_map(|r| r.frames.first())
        .next()
        .map(|(_, img)| img);
    let Some(first) = first else {
        return Err(Error::InvalidInput(
            "wedge contact sheet: no wedge has preview frames".into(),
        ));
    };
    let tw = tile_width.max(16);
    let th = ((tw as u64 * first.height() as u64) / first.width().max(1) as u64).max(1) as u32;
    let cols = rows
        .iter()
        .map(|r| r.frames.len())
        .max()
        .unwrap_or(1)
        .max(1) as u32;
    let (gap, scale) = (4u32, 2u32);
    let label_h = 5 * scale + 2 * gap;
    let label_w = rows
        .iter()
        .map(|r| text_width(&r.label, scale))
        .max()
        .unwrap_or(0);
    let width = (cols * tw + (cols + 1) * gap).max(label_w + 2 * gap);
    let height = rows.len() as u32 * (label_h + th + gap) + gap;
    let mut sheet = RgbImage::from_pixel(width, height, Rgb([40, 40, 40]));
    for (r, row) in rows.iter().enumerate() {
        let y0 = gap + r as u32 * (label_h + th + gap);
        draw_text(&mut sheet, gap, y0 + gap, &row.label, scale);
        let y = y0 + label_h;
        if row.frames.is_empty() {
            let bar = RgbImage::from_pixel(cols * tw + (cols - 1) * gap, th, Rgb([90, 90, 90]));
            image::imageops::replace(&mut sheet, &bar, gap as i64, y as i64);
            draw_text(&mut sheet, gap * 2, y + gap, "NO PREVIEW FRAMES", scale);
        }
        for (c, (frame, img)) in row.frames.iter().enumerate() {
            let thumb = image::imageops::resize(img, tw, th, image::imageops::FilterType::Triangle);
            let x = gap + c as u32 * (tw + gap);
            image::imageops::replace(&mut sheet, &thumb, x as i64, y as i64);
            crate::preview::sheet::draw_number(&mut sheet, x + 2, y + 2, *frame, scale);
        }
    }
    Ok(sheet)
}

/// At most `n` frames of `all`, evenly spaced, first and last included.
pub fn pick_frames(all: &[u32], n: usize) -> Vec<u32> {
    if all.len() <= n || n < 2 {
        return all.iter().copied().take(n).collect();
    }
    (0..n).map(|i| all[i * (all.len() - 1) / (n - 1)]).collect()
}

/// Writes the sheet as PNG (atomically) at `path`.
pub fn write_wedge_sheet(path: &Path, rows: &[SheetRow]) -> Result<()> {
    let sheet = wedge_sheet(rows, 160)?;
    crate::io::atomic::write_atomic(path, &crate::preview::png_bytes(&sheet)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_spread() {
        let all: Vec<u32> = (1..=8).collect();
        assert_eq!(pick_frames(&all, 4), [1, 3, 5, 8]);
        assert_eq!(pick_frames(&all[..3], 4), [1, 2, 3]);
    }

    #[test]
    fn every_wedge_has_a_labelled_row() {
        let img = RgbImage::from_pixel(32, 18, Rgb([0, 0, 200]));
        let rows = [
            SheetRow {
                label: "tiny_w0: seed=1".into(),
                frames: vec![(1, img.clone()), (8, img)],
            },
            SheetRow {
                label: "tiny_w1: seed=2".into(),
                frames: vec![],
            },
        ];
        let sheet = wedge_sheet(&rows, 64).unwrap();
        let th = 36;
        assert_eq!(sheet.height(), 2 * (10 + 8 + th + 4) + 4);
        // the label is drawn: some white pixels in the first label band
        let white = (0..sheet.width())
            .flat_map(|x| (0..18).map(move |y| (x, y)))
            .filter(|&(x, y)| sheet.get_pixel(x, y).0 == [255, 255, 255])
            .count();
        assert!(white > 20, "{white}");
    }
}
