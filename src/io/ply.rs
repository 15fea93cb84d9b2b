//! Particle caches: one binary little-endian PLY per frame (`particles/<shot>.<frame>.ply`),
//! readable by Blender's and Houdini's PLY importers (a vertex-only point cloud), and by
//! `nimbus export`, which re-makes a run's grids from them.
//!
//! Positions and velocities are in the export frame (`export::ExportSpace`: scene units, up axis,
//! velocity basis) and stored as doubles: the f32 simulation values come back exactly through
//! the inverse map (two f64 roundings are far below half an f32 ulp), so a re-export splats the
//! very particles the run did, in the same order.
//!
//! When the run tracks rest positions (`export.detail` or a rest grid, `sim::rest`), six more
//! floats follow: `rest_x rest_y rest_z rest2_x rest2_y rest2_z`, the two rest fields in the
//! export frame (scene units, up axis). They hold the quantised rest positions exactly
//! (`RestCodec::encode` of the value read back gives the run's u16 again).
use crate::error::{Error, Result};
use crate::export::ExportSpace;
use crate::ground::rest::{RestCodec, RestFrame};
use crate::ground::{levels, ParticleState};
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
/// The rest properties that follow when the run tracks rest positions.
pub const REST_PROPERTIES: [(&str, &str); 6] = [
    ("float", "rest_x"),
    ("float", "rest_y"),
    ("float", "rest_z"),
    ("float", "rest2_x"),
    ("float", "rest2_y"),
    ("float", "rest2_z"),
];
/// Bytes per vertex of the rest properties.
pub const REST_BYTES: usize = 6 * 4;

/// What the cache needs of the shot besides the particles.
#[derive(Debug, Clone)]
pub struct CacheInfo<'a> {
    pub space: &'a ExportSpace,
    /// Level-0 kernel radius (m) and mass (kg).
    pub h0: f64,
    pub m0: f64,
    /// The frame's rest positions (same order as the particles) and their quantisation.
    pub rest: Option<(&'a RestFrame, RestCodec)>,
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
    if info.rest.is_some_and(|(r, _)| r.len() != n) {
        return Err(Error::InvalidInput(
            "particle cache: rest positions and particles differ in length".into(),
        ));
    }
    let mut out = header(n, &info.comments, info.rest.is_some()).into_bytes();
    out.reserve(n * (VERTEX_BYTES + REST_BYTES));
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
        let h = levels::radius(info.h0, level) / s.scale;
        let m = levels::mass(info.m0, level);
        out.extend_from_slice(&(h as f32).to_le_bytes());
        out.extend_from_slice(&(m as f32).to_le_bytes());
        out.extend_from_slice(&id.to_le_bytes());
        if let Some((rest, codec)) = &info.rest {
            let q = rest[j];
            for k in [0, 3] {
                let r = s.point(codec.decode([q[k], q[k + 1], q[k + 2]]));
                for x in r {
                    out.extend_from_slice(&(x as f32).to_le_bytes());
                }
            }
        }
    }
    Ok(out)
}

fn header(n: usize, comments: &[String], rest: bool) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    for c in comments {
        // a comment is one line
        h.push_str(&format!("comment {}\n", c.replace(['\n', '\r'], " ")));
    }
    h.push_str(&format!("element vertex {n}\n"));
    let extra: &[(&str, &str)] = if rest { &REST_PROPERTIES } else { &[] };
    for (t, name) in PROPERTIES.iter().chain(extra) {
        h.push_str(&format!("property {t} {name}\n"));
    }
    h.push_str("end_header\n");
    h
}

/// Reads a cache written by `encode` back into the simulation's frame and units (density set to
/// `rest_density`, as the splat of a run uses it).
pub fn decode(bytes: &[u8], space: &ExportSpace, rest_density: f32) -> Result<ParticleState> {
    decode_with_rest(bytes, space, rest_density, None).map(|(s, _)| s)
}

/// `decode`, and the rest positions when the cache holds them (quantised by `codec`).
pub fn decode_with_rest(
    bytes: &[u8],
    space: &ExportSpace,
    rest_density: f32,
    codec: Option<RestCodec>,
) -> Result<(ParticleState, Option<RestFrame>)> {
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
    let rest_lines: Vec<&str> = lines.collect();
    let has_rest = match rest_lines.len() {
        0 => false,
        6 if rest_lines
            .iter()
            .zip(REST_PROPERTIES)
            .all(|(l, (t, name))| *l == format!("property {t} {name}")) =>
        {
            true
        }
        _ => return Err(bad("unexpected header lines")),
    };
    let stride = VERTEX_BYTES + if has_rest { REST_BYTES } else { 0 };
    let body = &bytes[at + end.len()..];
    if Some(body.len()) != n.checked_mul(stride) {
        return Err(bad(&format!(
            "{} bytes of vertex data, {n} vertices need {}",
            body.len(),
            n.saturating_mul(stride)
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
    let mut rest: Option<RestFrame> = match (has_rest, codec) {
        (true, Some(_)) => Some(Vec::with_capacity(n)),
        _ => None,
    };
    for v in body.chunks_exact(stride) {
        let p = space.point_to_sim([f64_at(v, 0), f64_at(v, 8), f64_at(v, 16)]);
        let u = space.velocity_to_sim([f64_at(v, 24), f64_at(v, 32), f64_at(v, 40)]);
        s.pos.push([p[0] as f32, p[1] as f32, p[2] as f32, 0.0]);
        s.vel.push([u[0] as f32, u[1] as f32, u[2] as f32, 0.0]);
        s.thermo
            .push([f32_at(v, 48), f32_at(v, 52), f32_at(v, 56), 0.0]);
        let level = v[60] as u32;
        let id = u32::from_le_bytes(v[69..73].try_into().unwrap());
        s.info.push([id, level]);
        if let (Some(out), Some(codec)) = (rest.as_mut(), codec) {
            let r = |i: usize| {
                let f = |k: usize| f32_at(v, VERTEX_BYTES + 4 * (i + k)) as f64;
                codec.encode(space.point_to_sim([f(0), f(1), f(2)]))
            };
            let (a, b) = (r(0), r(3));
            out.push([a[0], a[1], a[2], b[0], b[1], b[2]]);
        }
    }
    Ok((s, rest))
}

pub fn read(path: &Path, space: &ExportSpace, rest_density: f32) -> Result<ParticleState> {
    read_with_rest(path, space, rest_density, None).map(|(s, _)| s)
}

/// `read`, and the rest positions when the cache holds them.
pub fn read_with_rest(
    path: &Path,
    space: &ExportSpace,
    rest_density: f32,
    codec: Option<RestCodec>,
) -> Result<(ParticleState, Option<RestFrame>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_with_rest(&bytes, space, rest_density, codec)
        .map_err(|e| Error::InvalidInput(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn space(sets: &[&str]) -> ExportSpace {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        let cfg = crate::shot::load_str(
            "shot: t\noutput: {frames: {start: 1, end: 10}}\ndomain: {size: [100, 50, 100], spacing: 5}\n",
            "t.yaml",
            &sets,
        )
        .unwrap().into_config();
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
                rest: None,
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
    fn rest_positions_round_trip_exactly() {
        let st = state();
        let codec = RestCodec::new([2000.0, 1400.0, 1600.0], [true, true]);
        let rest: RestFrame = (0..st.len())
            .map(|j| {
                let a = codec.encode([j as f64 * 7.3, j as f64 * 3.1, 1599.0 - j as f64]);
                let b = codec.encode([j as f64 * 1.9, 1400.0 - j as f64, j as f64 * 5.5]);
                [a[0], a[1], a[2], b[0], b[1], b[2]]
            })
            .collect();
        for sets in [vec![], vec!["export.scale=0.37", "export.up_axis=z"]] {
            let sp = space(&sets);
            let info = CacheInfo {
                space: &sp,
                h0: 10.0,
                m0: 150.0,
                rest: Some((&rest, codec)),
                comments: vec![],
            };
            let bytes = encode(&st, &info).unwrap();
            let (back, r) = decode_with_rest(&bytes, &sp, 1.0, Some(codec)).unwrap();
            assert_eq!(r.as_ref(), Some(&rest), "{sets:?}");
            assert_eq!(back.info, st.info);
            // a reader that does not ask for them still reads the particles
            assert_eq!(decode(&bytes, &sp, 1.0).unwrap().info, st.info);
            assert!(decode(&bytes[..bytes.len() - 4], &sp, 1.0).is_err());
        }
    }

    #[test]
    fn damaged_caches_are_refused() {
        let sp = space(&[]);
        let info = CacheInfo {
            space: &sp,
            h0: 10.0,
            m0: 150.0,
            rest: None,
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
