//! Greyscale heat maps (`physics.sources` with `shape: image`): a PNG or OpenEXR file read into
//! one value in [0, 1] per pixel. Pixel (column i, row j) covers the ground square whose x
//! runs over [i, i + 1) size_x / width and z over [j, j + 1) size_z / height: row 0 at z = 0,
//! so the picture is the ground seen from above with x to the right and z down (Houdini's top
//! view). The value is the stored grey level (no sRGB decoding: mid grey 128 is half strength),
//! times the alpha where there is one (transparent = no heat).
use sha2::{Digest, Sha256};
use std::path::Path;

/// Largest width and height accepted (pixels).
pub const MAX_SIDE: usize = 4096;
/// Largest file accepted (bytes).
pub const MAX_BYTES: u64 = 256 << 20;

pub use crate::ground::HeatMap;

/// Hex SHA-256 of a file, or why it cannot be read.
pub fn file_sha256(path: &Path) -> Result<String, String> {
    Ok(hex(&read_bytes(path)?))
}

fn hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, String> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => "no such file".to_string(),
        _ => e.to_string(),
    })?;
    if !meta.is_file() {
        return Err("not a regular file".into());
    }
    if meta.len() > MAX_BYTES {
        return Err(format!(
            "{} bytes is larger than the {MAX_BYTES}-byte limit of a heat map",
            meta.len()
        ));
    }
    std::fs::read(path).map_err(|e| e.to_string())
}

/// Reads a PNG or OpenEXR heat map; the error says what is wrong with the file in words.
pub fn read(path: &Path) -> Result<HeatMap, String> {
    let bytes = read_bytes(path)?;
    let (width, height, values) = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(&bytes)?
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        decode_exr(path)?
    } else {
        return Err("not a PNG or OpenEXR image".into());
    };
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(format!(
            "{width} x {height} pixels; a heat map has 1 to {MAX_SIDE} pixels per side"
        ));
    }
    Ok(HeatMap {
        width,
        height,
        values,
        sha256: hex(&bytes),
    })
}

/// Any PNG colour type; colour pixels (R, G, B not equal within one 8-bit step) are refused.
fn decode_png(bytes: &[u8]) -> Result<(usize, usize, Vec<f32>), String> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| format!("unreadable PNG: {e}"))?;
    let rgba = img.to_rgba32f();
    let (w, h) = (rgba.width() as usize, rgba.height() as usize);
    let mut values = Vec::with_capacity(w * h);
    for (i, px) in rgba.pixels().enumerate() {
        let [r, g, b, a] = px.0;
        grey(r, g, b, 1.0 / 255.0, i % w.max(1), i / w.max(1))?;
        values.push(r * a);
    }
    Ok((w, h, values))
}

fn grey(r: f32, g: f32, b: f32, tol: f32, x: usize, y: usize) -> Result<(), String> {
    if (r - g).abs() > tol || (g - b).abs() > tol {
        return Err(format!(
            "a colour image (pixel {x}, {y} is R {r:.3} G {g:.3} B {b:.3}); a heat map is greyscale (R = G = B)"
        ));
    }
    Ok(())
}

/// The first layer of an OpenEXR file: a `Y` channel, or equal `R` `G` `B`, or a single
/// channel; `A` multiplies. Values must be finite and within [0, 1].
fn decode_exr(path: &Path) -> Result<(usize, usize, Vec<f32>), String> {
    let img = exr::prelude::read_first_flat_layer_from_file(path)
        .map_err(|e| format!("unreadable OpenEXR: {e}"))?;
    let layer = &img.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let chans = &layer.channel_data.list;
    let find = |name: &str| {
        chans
            .iter()
            .find(|c| c.name.to_string() == name)
            .map(|c| c.sample_data.values_as_f32().collect::<Vec<f32>>())
    };
    let names: Vec<String> = chans.iter().map(|c| c.name.to_string()).collect();
    let alpha = find("A");
    let mut values = if let Some(y) = find("Y") {
        y
    } else if let (Some(r), Some(g), Some(b)) = (find("R"), find("G"), find("B")) {
        for (i, ((r, g), b)) in r.iter().zip(&g).zip(&b).enumerate() {
            grey(*r, *g, *b, 1e-3, i % w.max(1), i / w.max(1))?;
        }
        r
    } else {
        let colour: Vec<&String> = names.iter().filter(|n| n.as_str() != "A").collect();
        match colour.as_slice() {
            [one] => find(one).unwrap_or_default(),
            _ => {
                return Err(format!(
                "OpenEXR channels {names:?}: a heat map has a Y channel, or R G B, or one channel"
            ))
            }
        }
    };
    if let Some(a) = alpha {
        values.iter_mut().zip(&a).for_each(|(v, a)| *v *= a);
    }
    if let Some(i) = values
        .iter()
        .position(|v| !v.is_finite() || !(0.0..=1.0).contains(v))
    {
        return Err(format!(
            "pixel {}, {} is {}; heat map values must be within [0, 1] (1 = full strength)",
            i % w.max(1),
            i / w.max(1),
            values[i]
        ));
    }
    Ok((w, h, values))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(dir: &Path, name: &str, img: image::DynamicImage) -> std::path::PathBuf {
        let p = dir.join(name);
        img.save_with_format(&p, image::ImageFormat::Png).unwrap();
        p
    }

    #[test]
    fn greyscale_png_values_and_orientation() {
        let dir = tempfile::tempdir().unwrap();
        // 3 x 2: row 0 (z = 0) dark to light along x, row 1 white; alpha halves one pixel.
        let mut im = image::RgbaImage::new(3, 2);
        for (x, y, px) in im.enumerate_pixels_mut() {
            let v = if y == 0 { (x * 100) as u8 } else { 255 };
            *px = image::Rgba([v, v, v, if (x, y) == (2, 1) { 0 } else { 255 }]);
        }
        let p = png(dir.path(), "a.png", image::DynamicImage::ImageRgba8(im));
        let m = read(&p).unwrap();
        assert_eq!((m.width, m.height), (3, 2));
        let want = [0.0, 100.0 / 255.0, 200.0 / 255.0, 1.0, 1.0, 0.0];
        for (v, w) in m.values.iter().zip(want) {
            assert!((v - w).abs() < 1e-6, "{:?}", m.values);
        }
        assert_eq!(m.sha256, file_sha256(&p).unwrap());
        // 16-bit grey
        let g16 = image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(4, 4, image::Luma([32768]));
        let p = png(dir.path(), "b.png", image::DynamicImage::ImageLuma16(g16));
        let m = read(&p).unwrap();
        assert!((m.values[5] - 0.5).abs() < 1e-4);
    }

    #[test]
    fn wrong_kinds_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let colour = image::RgbImage::from_pixel(2, 2, image::Rgb([200, 10, 10]));
        let p = png(dir.path(), "c.png", image::DynamicImage::ImageRgb8(colour));
        assert!(read(&p).unwrap_err().contains("colour image"));
        let t = dir.path().join("t.png");
        std::fs::write(&t, "not an image").unwrap();
        assert_eq!(read(&t).unwrap_err(), "not a PNG or OpenEXR image");
        let mut bad = b"\x89PNG\r\n\x1a\n".to_vec();
        bad.extend_from_slice(&[0; 20]);
        std::fs::write(&t, &bad).unwrap();
        assert!(read(&t).unwrap_err().starts_with("unreadable PNG"));
        assert_eq!(
            read(&dir.path().join("gone.png")).unwrap_err(),
            "no such file"
        );
        assert_eq!(read(dir.path()).unwrap_err(), "not a regular file");
    }

    #[test]
    fn exr_channels_and_range() {
        use exr::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("y.exr");
        let y = AnyChannel::new("Y", FlatSamples::F32(vec![0.0, 0.25, 0.5, 1.0]));
        Image::from_channels((2, 2), AnyChannels::sort(SmallVec::from_vec(vec![y])))
            .write()
            .to_file(&p)
            .unwrap();
        let m = super::read(&p).unwrap();
        assert_eq!(m.values, vec![0.0, 0.25, 0.5, 1.0]);
        let q = dir.path().join("rgb.exr");
        Image::from_channels(
            (2, 1),
            SpecificChannels::rgb(|_: Vec2<usize>| (0.7f32, 0.2f32, 0.2f32)),
        )
        .write()
        .to_file(&q)
        .unwrap();
        assert!(super::read(&q).unwrap_err().contains("colour image"));
        let hot = dir.path().join("hot.exr");
        let y = AnyChannel::new("Y", FlatSamples::F32(vec![0.0, 2.0]));
        Image::from_channels((2, 1), AnyChannels::sort(SmallVec::from_vec(vec![y])))
            .write()
            .to_file(&hot)
            .unwrap();
        assert!(super::read(&hot).unwrap_err().contains("within [0, 1]"));
    }
}
