//! The heat maps of `physics.sources` (`shape: image`), read once: each file decoded, its
//! SHA-256 pin compared, its aspect that of the ground.
use crate::config::{Issue, ShotConfig};
use crate::ground::HeatMap;

/// How far a heat map's pixel aspect may be from square (fraction).
pub const MAP_ASPECT_TOLERANCE: f64 = 0.01;

fn num(x: f64) -> String {
    crate::config::fmt_float(x)
}

/// Per source of `c`: its heat map, `None` for a source without one; the first problem as an
/// issue naming its keys.
pub fn read(c: &ShotConfig) -> Result<Vec<Option<HeatMap>>, Issue> {
    let mut maps = Vec::with_capacity(c.physics.sources.len());
    for (i, src) in c.physics.sources.iter().enumerate() {
        maps.push(match &src.image {
            Some(path) => Some(read_one(i, path, src.image_sha256.as_deref(), c)?),
            None => None,
        });
    }
    Ok(maps)
}

fn read_one(i: usize, path: &str, sha: Option<&str>, c: &ShotConfig) -> Result<HeatMap, Issue> {
    let key = |f: &str| format!("physics.sources[{i}].{f}");
    let fail = |keys: &[String], msg: String| Issue {
        keys: keys.to_vec(),
        msg,
    };
    let map = crate::io::heat_map::read(std::path::Path::new(path))
        .map_err(|why| fail(&[key("image")], format!("{path}: {why}")))?;
    if let Some(sha) = sha {
        if sha != map.sha256 {
            return Err(fail(
                &[key("image_sha256"), key("image")],
                format!(
                    "{path} has changed since this config was resolved (SHA-256 {}, recorded {sha}); restore the image or start a new run",
                    map.sha256
                ),
            ));
        }
    }
    let (sx, sz) = (c.domain.size[0], c.domain.size[2]);
    let px = (sx / map.width as f64) / (sz / map.height as f64);
    if (px - 1.0).abs() > MAP_ASPECT_TOLERANCE {
        return Err(fail(
            &[key("image")],
            format!(
                "{path}: {} x {} pixels over a {} x {} m ground makes pixels of {} x {} m; the map must have the ground's aspect (square pixels within 1%)",
                map.width,
                map.height,
                num(sx),
                num(sz),
                num(sx / map.width as f64),
                num(sz / map.height as f64)
            ),
        ));
    }
    Ok(map)
}
