//! Particle caches: one binary little-endian PLY per frame (`particles/<shot>.<frame>.ply`),
//! readable by Blender's and Houdini's PLY importers (a vertex-only point cloud), and by
//! `nimbus export`, which re-makes a run's grids from them.
//!
//! Positions and velocities are in the export frame (`export::ExportSpace`: scene units, up axis,
//! velocity basis) and stored as doubles: the f32 simulation values come back exactly through
//! the inverse map (two f64 roundings are far below half an f32 ulp), so a re-export splats the
//! very particles the run did, in the same order.
use crate::error::{Error, Result};
use crate::export::ExportSpace;
use crate::sim::ParticleState;
use std::path::Path;

/// Per-vertex properties, in file order: (PLY type, name).
pub const PROPERTIES: [(&str, &str); 13] = [
    ("double", "x"),
    ("double", "y"),
    ("double", "z"),
    ("double", "vx"),
    ("double", "vy"),
    ("double", "vz"),
    ("float", "temperature"),
    ("float", "vapor"),
    ("float", "cloud_water"),
    ("uchar", "level"),
    ("float", "radius"),
    ("float", "mass"),
    ("uint", "id"),
];
/// Bytes per vertex.
pub const VERTEX_BYTES: usize = 6 * 8 + 3 * 4 + 1 + 2 * 4 + 4;

/// What the cache needs of the shot besides the particles.
#[derive(Debug, Clone)]
pub struct CacheInfo<'a> {
    pub space: &'a ExportSpace,
    /// Level-0 kernel radius (m) and mass (kg).
    pub h0: f64,
    pub m0: f64,
    /// Comment lines (shot, frame, units) for people reading the header.
    pub comments: Vec<String>,
}

/// The whole file in memory.
pub fn encode(state: &ParticleState, info: &CacheInfo) -> Result<Vec<u8>> {
    let n = state.len();
    if state.vel.len() != n || state.thermo.len() != n || state.info.len() != n {
        return Err(Error::InvalidInput(
            "particle cache: particle arrays differ in length".into(),
        ));
    }
    let mut out = header(n, &info.comments).into_bytes();
    out.reserve(n * VERTEX_BYTES);
    let s = info.space;
    for j in 0..n {
        let p = s.point(state.pos[j].map(|x| x as f64)[..3].try_into().unwrap());
        let v = s.velocity(state.vel[j].map(|x| x as f64)[..3].try_into().unwrap());
        for x in p.iter().chain(&v) {
            out.extend_from_slice(&x.to_le_bytes());
        }
        let th = state.thermo[j];
        for x in &th[..3] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        let [id, level] = state.info[j];
        let lv = u8::try_from(level).map_err(|_| {
            Error::InvalidInput(format!("particle cache: level {level} does not fit a byte"))
        })?;
        out.push(lv);
        let h = info.h0 * (-(level as f64) / 3.0).exp2() / s.scale;
        let m = info.m0 * (-(level as f64)).exp2();
        out.extend_from_slice(&(h as f32).to_le_bytes());
        out.extend_from_slice(&(m as f32).to_le_bytes());
        out.extend_from_slice(&id.to_le_bytes());
    }
    Ok(out)
}

fn header(n: usize, comments: &[String]) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    for c in comments {
        // a comment is one line
        h.push_str(&format!("comment {}\n", c.replace(['\n', '\r'], " ")));
    }
    h.push_str(&format!("element vertex {n}\n"));
    for (t, name) in PROPERTIES {
        h.push_str(&format!("property {t} {name}\n"));
    }
    h.push_str("end_header\n");
    h
}

/// Reads a cache written by `encode` back into the simulation's frame and units (density set to
/// `rest_density`, as the splat of a run uses it).
pub fn decode(bytes: &[u8], space: &ExportSpace, rest_density: f32) -> Result<ParticleState> {
    let bad = |m: &str| Error::InvalidInput(format!("particle cache: {m}"));
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| bad("no end_header"))?;
    let head = std::str::from_utf8(&bytes[..at]).map_err(|_| bad("header is not text"))?;
    let mut lines = head.lines().filter(|l| !l.starts_with("comment "));
    if lines.next() != Some("ply") || lines.next() != Some("format binary_little_endian 1.0") {
        return Err(bad("not a binary little-endian PLY"));
    }
    let n: usize = lines
        .next()
        .and_then(|l| l.strip_prefix("element vertex "))
        .and_then(|c| c.parse().ok())
        .ok_or_else(|| bad("no vertex element"))?;
    for (t, name) in PROPERTIES {
        if lines.next() != Some(format!("property {t} {name}").as_str()) {
            return Err(bad(&format!("expected property {t} {name}")));
        }
    }
    if lines.next().is_some() {
        return Err(bad("unexpected header lines"));
    }
    let body = &bytes[at + end.len()..];
    if Some(body.len()) != n.checked_mul(VERTEX_BYTES) {
        return Err(bad(&format!(
            "{} bytes of vertex data, {n} vertices need {}",
            body.len(),
            n.saturating_mul(VERTEX_BYTES)
        )));
    }
    let mut s = ParticleState {
        pos: Vec::with_capacity(n),
        vel: Vec::with_capacity(n),
        thermo: Vec::with_capacity(n),
        info: Vec::with_capacity(n),
        density: vec![rest_density; n],
    };
    let f64_at = |b: &[u8], i: usize| f64::from_le_bytes(b[i..i + 8].try_into().unwrap());
    let f32_at = |b: &[u8], i: usize| f32::from_le_bytes(b[i..i + 4].try_into().unwrap());
    for v in body.chunks_exact(VERTEX_BYTES) {
        let p = space.point_to_sim([f64_at(v, 0), f64_at(v, 8), f64_at(v, 16)]);
        let u = space.velocity_to_sim([f64_at(v, 24), f64_at(v, 32), f64_at(v, 40)]);
        s.pos.push([p[0] as f32, p[1] as f32, p[2] as f32, 0.0]);
        s.vel.push([u[0] as f32, u[1] as f32, u[2] as f32, 0.0]);
        s.thermo
            .push([f32_at(v, 48), f32_at(v, 52), f32_at(v, 56), 0.0]);
        let level = v[60] as u32;
        let id = u32::from_le_bytes(v[69..73].try_into().unwrap());
        s.info.push([id, level]);
    }
    Ok(s)
}

pub fn read(path: &Path, space: &ExportSpace, rest_density: f32) -> Result<ParticleState> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode(&bytes, space, rest_density)
        .map_err(|e| Error::InvalidInput(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn space(sets: &[&str]) -> ExportSpace {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let cfg = crate::config::load_str(
            "shot: t\noutput: {frames: {start: 1, end: 10}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
            "t.yaml",
            &sets,
        )
        .unwrap();
        ExportSpace::from_config(&cfg)
    }

    fn header_len(b: &[u8]) -> usize {
        b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11
    }

    fn state() -> ParticleState {
        let n = 257;
        let mut s = ParticleState {
            pos: vec![],
            vel: vec![],
            thermo: vec![],
            info: vec![],
            density: vec![1.2; n],
        };
        let mut x = 0x1234_5678_u32;
        let mut r = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x as f32 / u32::MAX as f32) * 2.0 - 1.0
        };
        for i in 0..n {
            s.pos
                .push([1000.0 * r(), 1400.0 * r().abs(), 1600.0 * r(), 0.0]);
            s.vel.push([3.0 * r(), 1e-7 * r(), 30.0 * r(), 0.0]);
            s.thermo
                .push([290.0 + r(), 0.01 * r().abs(), 1e-4 * r().abs(), 0.0]);
            s.info.push([i as u32 * 7, (i % 4) as u32]);
        }
        s
    }

    #[test]
    fn round_trip_is_exact_in_every_frame() {
        let st = state();
        for sets in [
            vec![],
            vec!["export.scale=0.37", "export.up_axis=z"],
            vec!["export.scale=100", "export.velocity_time=per_frame"],
            vec!["export.profile=blender", "export.scale=3"],
        ] {
            let sp = space(&sets);
            let info = CacheInfo {
                space: &sp,
                h0: 10.0,
                m0: 150.0,
                comments: vec!["nimbus test\nframe 3".into()],
            };
            let bytes = encode(&st, &info).unwrap();
            let back = decode(&bytes, &sp, 1.0).unwrap();
            assert_eq!(back.pos.len(), st.pos.len());
            for j in 0..st.len() {
                assert_eq!(back.pos[j][..3], st.pos[j][..3], "{sets:?} pos {j}");
                assert_eq!(back.vel[j][..3], st.vel[j][..3], "{sets:?} vel {j}");
                assert_eq!(back.thermo[j][..3], st.thermo[j][..3]);
                assert_eq!(back.info[j], st.info[j]);
            }
            assert!(back.density.iter().all(|&d| d == 1.0));
            // the header is one line per comment and names every property
            let head = std::str::from_utf8(&bytes[..header_len(&bytes)]).unwrap();
            assert!(head.contains("comment nimbus test frame 3\n"));
        }
    }

    #[test]
    fn damaged_caches_are_refused() {
        let sp = space(&[]);
        let info = CacheInfo {
            space: &sp,
            h0: 10.0,
            m0: 150.0,
            comments: vec![],
        };
        let bytes = encode(&state(), &info).unwrap();
        assert!(decode(&bytes[..bytes.len() - 1], &sp, 1.0).is_err());
        assert!(decode(b"ply\nformat ascii 1.0\nend_header\n", &sp, 1.0).is_err());
        assert!(decode(b"not a ply", &sp, 1.0).is_err());
        let h = header_len(&bytes);
        let renamed = std::str::from_utf8(&bytes[..h])
            .unwrap()
            .replace("property uint id", "property uint ix");
        let mut b2 = renamed.into_bytes();
        b2.extend_from_slice(&bytes[h..]);
        assert!(decode(&b2, &sp, 1.0).is_err());
    }
}
