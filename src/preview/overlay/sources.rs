//! The heat sources (`physics.sources`) drawn into a preview: a ground shape (disc, ellipse,
//! ground box) as its footprint on the ground, filled with its strength profile (full inside
//! 0.7 of its size, fading to its edge, as the thermo stage heats) and outlined at its edge; an
//! image source as its heat map tinting the ground; a sphere or a box in the air as a
//! wireframe. Each source has its own colour ([`super::PALETTE`], by index).
//!
//! Schedules: a source is drawn at full strength in a frame in which it acts (its
//! `start`..`end` overlaps the frame's simulated time), its fill following its ramp's envelope
//! over the frame from a dim floor up to full; in a frame in which it does not act it is drawn
//! dimmed (the floor of the fill, faint outline or wires), so its place is still visible.
//! Footprints wrap across periodic faces as the heating does; wireframes are drawn where the
//! centre is, unwrapped.
use super::{blend, display_color, draw_segment, edge, ground_hit, line_width, PALETTE};
use crate::config::{Axis, HeatSource, ShotConfig, SourceShape};
use crate::error::{Error, Result};
use crate::ground::HeatMap;
use crate::preview::{LinearImage, PreviewParams};
use glam::DVec3;

/// Opacity of a footprint's fill at full strength, of its outline, and the fraction of either
/// drawn for a source in a frame in which it does not act.
const FILL_ALPHA: f64 = 0.55;
const LINE_ALPHA: f64 = 0.95;
const DIM: f64 = 0.35;

/// The sources of a shot, ready to draw (heat maps read once).
pub struct SourceOverlay {
    sources: Vec<HeatSource>,
    maps: Vec<Option<HeatMap>>,
    size: [f64; 3],
    periodic: [bool; 2],
    /// Simulated seconds per frame and the first frame: a frame's time span.
    frame_seconds: f64,
    first_frame: u32,
}

impl SourceOverlay {
    /// The overlay of `cfg`'s sources with their heat maps as the prepared shot read them
    /// (`maps[i]` for source i); an input error when it has none.
    pub fn new(cfg: &ShotConfig, maps: &[Option<HeatMap>]) -> Result<Self> {
        if cfg.physics.sources.is_empty() {
            return Err(Error::InvalidInput(
                "the shot has no physics.sources to draw".into(),
            ));
        }
        Ok(Self {
            sources: cfg.physics.sources.clone(),
            maps: maps.to_vec(),
            size: cfg.domain.size,
            periodic: [
                cfg.domain.periodic.contains(&Axis::X),
                cfg.domain.periodic.contains(&Axis::Z),
            ],
            frame_seconds: cfg.output.frame_seconds,
            first_frame: cfg.output.frames.start,
        })
    }

    /// Simulated time span (s) of `frame`: the frame's state is the one at its end.
    pub fn frame_span(&self, frame: u32) -> (f64, f64) {
        let t0 = frame.saturating_sub(self.first_frame) as f64 * self.frame_seconds;
        (t0, t0 + self.frame_seconds)
    }

    /// Per source: (acts during the span, highest envelope over it).
    fn schedule(&self, frame: u32) -> Vec<(bool, f64)> {
        let (t0, t1) = self.frame_span(frame);
        self.sources
            .iter()
            .map(|s| {
                let acts = s.start < t1 && s.end.is_none_or(|e| e > t0);
                let env = (0..=8)
                    .map(|k| s.envelope(t0 + (t1 - t0) * k as f64 / 8.0))
                    .fold(0.0, f64::max);
                (acts, if acts { env } else { 0.0 })
            })
            .collect()
    }

    /// Draws every source into `img` as it stands in `frame`.
    pub fn draw(&self, img: &mut LinearImage, params: &PreviewParams, frame: u32) {
        let sched = self.schedule(frame);
        self.draw_ground(img, params, &sched);
        let width = line_width(img.height);
        for (k, s) in self.sources.iter().enumerate() {
            if s.on_ground() {
                continue;
            }
            let alpha = LINE_ALPHA * if sched[k].0 { 1.0 } else { DIM };
            for (a, b) in wireframe(s) {
                draw_segment(img, params, a, b, PALETTE[k % PALETTE.len()], alpha, width);
            }
        }
    }

    /// The ground shapes: per pixel that sees the ground, each shape's falloff there; the fill
    /// tints what the cloud lets through, the outline is drawn where a pixel is inside the
    /// shape and a neighbour is not.
    fn draw_ground(&self, img: &mut LinearImage, params: &PreviewParams, sched: &[(bool, f64)]) {
        let ground: Vec<usize> = (0..self.sources.len())
            .filter(|&k| self.sources[k].on_ground())
            .collect();
        if ground.is_empty() {
            return;
        }
        let (w, h) = (img.width, img.height);
        let n = (w * h) as usize;
        // per ground source and pixel: (q, fill factor); q < 1 inside, NaN off the ground
        let mut q = vec![f64::NAN; n * ground.len()];
        let mut fill = vec![0.0; n * ground.len()];
        for y in 0..h {
            for x in 0..w {
                let Some(p) = ground_hit(params, self.size, x, y) else {
                    continue;
                };
                let i = (y * w + x) as usize;
                for (g, &k) in ground.iter().enumerate() {
                    let (qq, f) = self.footprint(k, p.x, p.z);
                    q[g * n + i] = qq;
                    fill[g * n + i] = f;
                }
            }
        }
        // The ground is behind the cloud: each fill mixes into the background, which shows
        // where the cloud lets it through.
        let sky = params.sky();
        let clear: Vec<DVec3> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| sky.radiance(params.ray(x, y)))
            .collect();
        let mut bg = clear.clone();
        for (g, &k) in ground.iter().enumerate() {
            let color = display_color(PALETTE[k % PALETTE.len()], params);
            for (i, b) in bg.iter_mut().enumerate() {
                let a = FILL_ALPHA * fill[g * n + i] * (DIM + (1.0 - DIM) * sched[k].1);
                if a > 0.0 {
                    *b = b.lerp(color, a);
                }
            }
        }
        for ((px, b), c0) in img.data.iter_mut().zip(&bg).zip(&clear) {
            let through = 1.0 - px[3] as f64;
            for (c, d) in px.iter_mut().zip((*b - *c0).to_array()) {
                *c += (through * d) as f32;
            }
        }
        let width = line_width(h);
        let reach = (0.5 * width).ceil() as i64;
        for (g, &k) in ground.iter().enumerate() {
            let color = PALETTE[k % PALETTE.len()];
            let acts = sched[k].0;
            // inside the shape (NaN off the ground is outside)
            let ins: Vec<bool> = q[g * n..(g + 1) * n].iter().map(|q| *q < 1.0).collect();
            if self.sources[k].shape == SourceShape::Image {
                continue;
            }
            let alpha = LINE_ALPHA * if acts { 1.0 } else { DIM };
            for y in 0..h as i64 {
                for x in 0..w as i64 {
                    let i = (y * w as i64 + x) as usize;
                    if !ins[i] {
                        continue;
                    }
                    let outside = |dx: i64, dy: i64| {
                        let (nx, ny) = (x + dx, y + dy);
                        nx >= 0
                            && ny >= 0
                            && nx < w as i64
                            && ny < h as i64
                            && !ins[(ny * w as i64 + nx) as usize]
                    };
                    // An inside pixel with an outside one within the line's reach.
                    let on_edge = (-reach..=reach).any(|dy| {
                        (-reach..=reach).any(|dx| (dx != 0 || dy != 0) && outside(dx, dy))
                    });
                    if on_edge {
                        blend(img, params, i, color, alpha);
                    }
                }
            }
        }
    }

    /// Source k at ground point (x, z): (q, strength fraction), q the normalised distance
    /// from its centre (1 at its edge), for an image the fraction alone (q 0 where it heats).
    fn footprint(&self, k: usize, x: f64, z: f64) -> (f64, f64) {
        let s = &self.sources[k];
        let wrap = |d: f64, size: f64, periodic: bool| {
            if periodic {
                d - size * (d / size).round()
            } else {
                d
            }
        };
        if let Some(map) = &self.maps[k] {
            let f = sample_map(map, x / self.size[0], z / self.size[2], self.periodic);
            return (if f > 0.0 { 0.0 } else { 2.0 }, f);
        }
        let c = |i: usize| s.center.get(i).copied().unwrap_or(0.0);
        let dx = wrap(x - c(0), self.size[0], self.periodic[0]);
        let dz = wrap(z - c(1), self.size[2], self.periodic[1]);
        let (sn, cs) = s.angle.unwrap_or(0.0).to_radians().sin_cos();
        let (lx, lz) = (cs * dx + sn * dz, cs * dz - sn * dx);
        match s.shape {
            SourceShape::Disc => {
                let q = (dx * dx + dz * dz).sqrt() / s.radius.unwrap_or(1.0);
                (q, edge(q))
            }
            SourceShape::Ellipse => {
                let r = s.radii.unwrap_or([1.0; 2]);
                let q = ((lx / r[0]).powi(2) + (lz / r[1]).powi(2)).sqrt();
                (q, edge(q))
            }
            SourceShape::Box => {
                let half = |i: usize| 0.5 * s.size.as_ref().and_then(|v| v.get(i)).unwrap_or(&1.0);
                let (qx, qz) = (lx.abs() / half(0), lz.abs() / half(1));
                (qx.max(qz), edge(qx) * edge(qz))
            }
            // in the air: not on the ground
            SourceShape::Sphere | SourceShape::Image => (f64::NAN, 0.0),
        }
    }
}

/// A heat map at ground point (u, v) in [0, 1] of the domain's x and z: bilinear between pixel
/// centres, wrapped on periodic axes and clamped on walled ones (as the thermo stage samples).
fn sample_map(map: &HeatMap, u: f64, v: f64, periodic: [bool; 2]) -> f64 {
    let (w, h) = (map.width as i64, map.height as i64);
    let pick = |i: i64, n: i64, p: bool| {
        if p {
            i.rem_euclid(n)
        } else {
            i.clamp(0, n - 1)
        }
    };
    let (fu, fv) = (u * w as f64 - 0.5, v * h as f64 - 0.5);
    let (iu, iv) = (fu.floor(), fv.floor());
    let (tu, tv) = (fu - iu, fv - iv);
    let at = |i: i64, j: i64| {
        map.values[(pick(j, h, periodic[1]) * w + pick(i, w, periodic[0])) as usize] as f64
    };
    let (i, j) = (iu as i64, iv as i64);
    let a = at(i, j) + (at(i + 1, j) - at(i, j)) * tu;
    let b = at(i, j + 1) + (at(i + 1, j + 1) - at(i, j + 1)) * tu;
    a + (b - a) * tv
}

/// The edges of a source in the air: a sphere's three great circles, a box's twelve edges.
fn wireframe(s: &HeatSource) -> Vec<(DVec3, DVec3)> {
    let c = DVec3::new(
        s.center.first().copied().unwrap_or(0.0),
        s.center.get(1).copied().unwrap_or(0.0),
        s.center.get(2).copied().unwrap_or(0.0),
    );
    match s.shape {
        SourceShape::Sphere => {
            let r = s.radius.unwrap_or(0.0);
            let n = 48;
            let mut out = Vec::with_capacity(3 * n);
            for plane in 0..3 {
                let pt = |k: usize| {
                    let (sn, cs) = (k as f64 / n as f64 * std::f64::consts::TAU).sin_cos();
                    let (a, b) = (r * cs, r * sn);
                    c + match plane {
                        0 => DVec3::new(a, b, 0.0),
                        1 => DVec3::new(0.0, a, b),
                        _ => DVec3::new(a, 0.0, b),
                    }
                };
                out.extend((0..n).map(|k| (pt(k), pt(k + 1))));
            }
            out
        }
        SourceShape::Box => {
            let half = |i: usize| 0.5 * s.size.as_ref().and_then(|v| v.get(i)).unwrap_or(&0.0);
            let (hx, hy, hz) = (half(0), half(1), half(2));
            let (sn, cs) = s.angle.unwrap_or(0.0).to_radians().sin_cos();
            // the inverse of the thermo stage's turn into the box's frame
            let corner = |i: usize| {
                let (lx, ly, lz) = (
                    if i & 1 == 1 { hx } else { -hx },
                    if i & 2 == 2 { hy } else { -hy },
                    if i & 4 == 4 { hz } else { -hz },
                );
                c + DVec3::new(cs * lx - sn * lz, ly, sn * lx + cs * lz)
            };
            let mut out = Vec::with_capacity(12);
            for i in 0..8usize {
                for bit in [1, 2, 4] {
                    if i & bit == 0 {
                        out.push((corner(i), corner(i | bit)));
                    }
                }
            }
            out
        }
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn overlay(sources: &str) -> SourceOverlay {
        let shot = crate::shot::load_str(
            &format!(
                "shot: t\noutput: {{frames: {{start: 1, end: 9}}, frame_seconds: 5}}\n\
                 domain: {{size: [800, 800, 800], spacing: 50}}\nphysics: {{sources: {sources}}}\n"
            ),
            "t.yaml",
            &[],
        )
        .unwrap();
        SourceOverlay::new(shot.config(), shot.heat_maps()).unwrap()
    }

    #[test]
    fn a_source_acts_in_the_frames_its_schedule_overlaps() {
        let o = overlay(
            "[{shape: disc, center: [400, 400], radius: 100, strength: 0.1, start: 10, end: 30, ramp: 5}]",
        );
        // frame 1 is the state after 0..5 s
        assert_eq!(o.frame_span(1), (0.0, 5.0));
        let at = |f: u32| o.schedule(f)[0];
        assert_eq!(at(2), (false, 0.0), "5..10 s: not yet");
        // 10..15 s: ramping in, full at its end
        assert_eq!(at(3), (true, 1.0));
        assert_eq!(at(6), (true, 1.0), "25..30 s: ramping out from full");
        assert_eq!(at(7), (false, 0.0), "30..35 s: off");
    }

    #[test]
    fn footprints_wrap_across_periodic_faces_and_turn_with_their_angle() {
        let o = overlay(
            "[{shape: disc, center: [20, 400], radius: 100, strength: 0.1},\
              {shape: box, center: [400, 400], size: [200, 40], angle: 90, strength: 0.1}]",
        );
        // 40 m from the centre across the x faces (periodic by default)
        let (q, f) = o.footprint(0, 780.0, 400.0);
        assert!((q - 0.4).abs() < 1e-9 && f == 1.0, "{q} {f}");
        assert!(o.footprint(0, 400.0, 400.0).0 > 1.0);
        // the box turned by 90 degrees is long along z
        assert!(o.footprint(1, 400.0, 480.0).0 < 1.0);
        assert!(o.footprint(1, 480.0, 400.0).0 > 1.0);
    }
}
