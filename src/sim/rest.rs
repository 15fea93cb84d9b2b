//! Rest positions: where each particle was when its rest field was last reset, the coordinate
//! in which `export.detail` evaluates its noise so that the noise moves with the air.
//!
//! Host-side and keyed by particle id (the run loop reads the whole state back once per frame);
//! no GPU buffer, no device memory. Ids are unique and survive the sort; across split and merge
//! (`sim::adaptive`):
//! - a particle whose id the last frame knew keeps its rest positions (a split's first child
//!   keeps its parent's id, a merge product the smaller of the two ids);
//! - a new id (a split's second child) takes the rest frame of its nearest known neighbour, in
//!   practice its sibling: rest = rest_k + min_image(x - x_k), so the two children of a split sit
//!   where their parent's rest frame puts them, not both on the parent's rest point;
//! - a merge product keeps the rest of the id it keeps; the other one's is dropped (the two were
//!   within a kernel radius of each other, so their rests differ by about that much).
//!
//! Dual rest fields (`export.detail.rest_period` P > 0): field A is reset to the current
//! positions on frames `start + k P`, field B on frames `start + P/2 + k P`; each field's weight
//! is a triangle over its age, w = 1 - |2 age / P - 1|, zero at its reset, so the blend never
//! jumps and no field is used past an age of P frames. With P = 0 there is one field, set on the
//! first frame and never reset.
//!
//! Storage: 16 bytes per particle: the id (u32) and the two rest positions quantised to u16 over
//! the domain box (`RestCodec`: 1/65535 of each extent, 2.4 cm in a 1.6 km domain). The particle
//! caches store the dequantised positions; `RestCodec::encode` of them gives the same u16 back,
//! so a re-export splats the very rest coordinates the run did.
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::ground::rest::{RestClock, RestCodec, RestFrame};
use crate::ground::ParticleState;

/// The reset schedule of a shot's rest fields (`export.detail.rest_period` from its first frame).
pub fn rest_clock(cfg: &ShotConfig) -> RestClock {
    RestClock {
        start: cfg.output.frames.start,
        period: cfg.export.detail.rest_period,
    }
}

/// The tracker the run loop keeps: (id, rest A, rest B), sorted by id.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RestTracker {
    entries: Vec<(u32, [u16; 6])>,
}

/// Extra checkpoint section holding the tracker (`RestTracker::to_bytes`).
pub const CHECKPOINT_SECTION: &str = "rest";

impl RestTracker {
    pub fn len(&self) -> usize {
        self.entries.len()
    }
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The rest positions of `state` (the frame `frame` just simulated), updating the tracker.
    pub fn update(
        &mut self,
        state: &ParticleState,
        frame: u32,
        clock: &RestClock,
        codec: &RestCodec,
        h0: f64,
    ) -> RestFrame {
        let n = state.len();
        let pos = |j: usize| {
            let p = state.pos[j];
            [p[0] as f64, p[1] as f64, p[2] as f64]
        };
        let mut out: Vec<Option<[u16; 6]>> = (0..n)
            .map(|j| {
                let id = state.info[j][0];
                self.entries
                    .binary_search_by_key(&id, |e| e.0)
                    .ok()
                    .map(|i| self.entries[i].1)
            })
            .collect();
        let known: Vec<usize> = (0..n).filter(|&j| out[j].is_some()).collect();
        if known.len() < n {
            // New ids: the rest frame of the nearest known particle (a split's sibling).
            let grid = CellHash::new(&known, &pos, h0, codec);
            let inherited: Vec<(usize, [u16; 6])> = (0..n)
                .filter(|&j| out[j].is_none())
                .map(|j| {
                    let x = pos(j);
                    let rest = match grid.nearest(x, &pos, codec) {
                        Some(k) => {
                            let r = out[k].expect("known");
                            let d = codec.diff(x, pos(k));
                            let shift = |q: [u16; 3]| {
                                let r = codec.decode(q);
                                codec.encode([r[0] + d[0], r[1] + d[1], r[2] + d[2]])
                            };
                            let a = shift([r[0], r[1], r[2]]);
                            let b = shift([r[3], r[4], r[5]]);
                            [a[0], a[1], a[2], b[0], b[1], b[2]]
                        }
                        None => {
                            let q = codec.encode(x);
                            [q[0], q[1], q[2], q[0], q[1], q[2]]
                        }
                    };
                    (j, rest)
                })
                .collect();
            for (j, r) in inherited {
                out[j] = Some(r);
            }
        }
        let [reset_a, reset_b] = clock.resets(frame);
        let mut rest: RestFrame = out.into_iter().map(|r| r.expect("set")).collect();
        if reset_a || reset_b {
            for (j, r) in rest.iter_mut().enumerate() {
                let q = codec.encode(pos(j));
                if reset_a {
                    r[..3].copy_from_slice(&q);
                }
                if reset_b {
                    r[3..].copy_from_slice(&q);
                }
            }
        }
        self.entries = (0..n).map(|j| (state.info[j][0], rest[j])).collect();
        self.entries.sort_unstable_by_key(|e| e.0);
        rest
    }

    /// Little-endian (id u32, 6 x u16) per particle, in id order.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(self.entries.len() * 16);
        for (id, r) in &self.entries {
            b.extend_from_slice(&id.to_le_bytes());
            for q in r {
                b.extend_from_slice(&q.to_le_bytes());
            }
        }
        b
    }

    pub fn from_bytes(b: &[u8]) -> Result<Self> {
        if !b.len().is_multiple_of(16) {
            return Err(Error::InvalidInput(format!(
                "checkpoint: rest section of {} bytes is not a whole number of 16-byte entries",
                b.len()
            )));
        }
        let entries: Vec<(u32, [u16; 6])> = b
            .chunks_exact(16)
            .map(|c| {
                let id = u32::from_le_bytes(c[..4].try_into().unwrap());
                let r = [0, 1, 2, 3, 4, 5]
                    .map(|i| u16::from_le_bytes(c[4 + 2 * i..6 + 2 * i].try_into().unwrap()));
                (id, r)
            })
            .collect();
        if !entries.windows(2).all(|w| w[0].0 < w[1].0) {
            return Err(Error::InvalidInput(
                "checkpoint: rest section is not sorted by particle id".into(),
            ));
        }
        Ok(Self { entries })
    }
}

/// Cells of edge h0 over the known particles, for the nearest-known-neighbour search.
struct CellHash {
    cell: f64,
    dims: [i64; 3],
    map: std::collections::HashMap<[i64; 3], Vec<usize>>,
}

impl CellHash {
    fn new(known: &[usize], pos: &dyn Fn(usize) -> [f64; 3], h0: f64, codec: &RestCodec) -> Self {
        let cell = h0.max(1e-6);
        let dims = codec.size.map(|s| ((s / cell).floor() as i64).max(1));
        let mut map: std::collections::HashMap<[i64; 3], Vec<usize>> = Default::default();
        let mut hash = Self {
            cell,
            dims,
            map: Default::default(),
        };
        for &k in known {
            map.entry(hash.key(pos(k), codec)).or_default().push(k);
        }
        hash.map = map;
        hash
    }
    fn key(&self, p: [f64; 3], codec: &RestCodec) -> [i64; 3] {
        [0, 1, 2].map(|a| {
            let c = (p[a] / self.cell).floor() as i64;
            if codec.periodic[a] {
                c.rem_euclid(self.dims[a])
            } else {
                c
            }
        })
    }
    /// Nearest known particle within two cells (ties: the lower index).
    fn nearest(
        &self,
        x: [f64; 3],
        pos: &dyn Fn(usize) -> [f64; 3],
        codec: &RestCodec,
    ) -> Option<usize> {
        let c = self.key(x, codec);
        let mut best: Option<(f64, usize)> = None;
        for dx in -2..=2i64 {
            for dy in -2..=2i64 {
                for dz in -2..=2i64 {
                    let mut k = [c[0] + dx, c[1] + dy, c[2] + dz];
                    for a in [0, 2] {
                        if codec.periodic[a] {
                            k[a] = k[a].rem_euclid(self.dims[a]);
                        }
                    }
                    let Some(list) = self.map.get(&k) else {
                        continue;
                    };
                    for &j in list {
                        let d = codec.diff(x, pos(j));
                        let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                        if best.is_none_or(|(b, i)| r2 < b || (r2 == b && j < i)) {
                            best = Some((r2, j));
                        }
                    }
                }
            }
        }
        best.map(|(_, j)| j)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(pts: &[([f32; 3], u32)]) -> ParticleState {
        ParticleState {
            pos: pts.iter().map(|(p, _)| [p[0], p[1], p[2], 0.0]).collect(),
            vel: vec![[0.0; 4]; pts.len()],
            thermo: vec![[290.0, 0.0, 0.0, 0.0]; pts.len()],
            info: pts.iter().map(|(_, id)| [*id, 0]).collect(),
            density: vec![1.0; pts.len()],
        }
    }

    const CODEC: RestCodec = RestCodec {
        size: [1000.0, 500.0, 1000.0],
        periodic: [true, false, true],
    };

    #[test]
    fn codec_round_trips_its_own_values() {
        for p in [
            [0.0, 0.0, 0.0],
            [999.9, 250.3, 17.77],
            [-3.0, 500.0, 1003.0],
        ] {
            let q = CODEC.encode(p);
            let back = CODEC.decode(q);
            assert_eq!(CODEC.encode(back), q);
            // f32 in the export frame and back lands on the same step too
            let f = back.map(|x| x as f32 as f64);
            assert_eq!(CODEC.encode(f), q);
            let d = CODEC.diff(back, p);
            assert!(d.iter().all(|x| x.abs() <= 1000.0 / 65535.0), "{p:?} {d:?}");
        }
    }

    #[test]
    fn clock_alternates_and_weights_are_triangles() {
        let c = RestClock {
            start: 1,
            period: 8,
        };
        assert_eq!(c.resets(1), [true, true]);
        let resets: Vec<u32> = (2..30).filter(|&f| c.resets(f)[0]).collect();
        assert_eq!(resets, vec![9, 17, 25]);
        let resets_b: Vec<u32> = (2..30).filter(|&f| c.resets(f)[1]).collect();
        assert_eq!(resets_b, vec![5, 13, 21, 29]);
        for f in 1..40 {
            let w = c.weights(f);
            assert!((w[0] + w[1] - 1.0).abs() < 1e-12);
            // a field is out of the blend on the frame it resets
            if f > 1 && c.resets(f)[0] {
                assert_eq!(w[0], 0.0, "frame {f}");
            }
            if f > 1 && c.resets(f)[1] {
                assert_eq!(w[1], 0.0, "frame {f}");
            }
        }
        let one = RestClock {
            start: 1,
            period: 0,
        };
        assert_eq!(one.weights(20), [1.0, 0.0]);
        assert_eq!(one.resets(20), [false, false]);
    }

    #[test]
    fn rest_follows_ids_through_sort_split_merge_and_checkpoints() {
        let clock = RestClock {
            start: 1,
            period: 0,
        };
        let mut t = RestTracker::default();
        let s1 = state(&[([100.0, 100.0, 100.0], 0), ([300.0, 100.0, 100.0], 1)]);
        let r1 = t.update(&s1, 1, &clock, &CODEC, 50.0);
        assert_eq!(r1[0][..3], CODEC.encode([100.0, 100.0, 100.0]));
        // Frame 2: moved by (+10, +20, 0), sorted the other way round; particle 0 split into
        // itself and id 7, 6 m apart; particle 1 merged with... nothing new.
        let s2 = state(&[
            ([310.0, 120.0, 100.0], 1),
            ([107.0, 120.0, 100.0], 0),
            ([113.0, 120.0, 100.0], 7),
        ]);
        let r2 = t.update(&s2, 2, &clock, &CODEC, 50.0);
        assert_eq!(r2[0], r1[1]);
        assert_eq!(r2[1], r1[0]);
        // the child sits 6 m from its sibling in the sibling's rest frame
        let child = CODEC.decode([r2[2][0], r2[2][1], r2[2][2]]);
        let sib = CODEC.decode([r2[1][0], r2[1][1], r2[1][2]]);
        assert!((child[0] - sib[0] - 6.0).abs() < 0.05, "{child:?} {sib:?}");
        // a merge of 0 and 7 keeps id 0 and its rest
        let s3 = state(&[([110.0, 125.0, 100.0], 0), ([311.0, 121.0, 100.0], 1)]);
        let r3 = t.update(&s3, 3, &clock, &CODEC, 50.0);
        assert_eq!(r3[0], r1[0]);
        assert_eq!(t.len(), 2);
        // checkpoint round trip
        let back = RestTracker::from_bytes(&t.to_bytes()).unwrap();
        assert_eq!(back, t);
        assert!(RestTracker::from_bytes(&[0u8; 15]).is_err());
        // across the periodic face the inherited rest wraps too
        let mut t = RestTracker::default();
        t.update(&state(&[([998.0, 50.0, 10.0], 3)]), 1, &clock, &CODEC, 50.0);
        let r = t.update(
            &state(&[([998.0, 50.0, 10.0], 3), ([2.0, 50.0, 10.0], 9)]),
            2,
            &clock,
            &CODEC,
            50.0,
        );
        let child = CODEC.decode([r[1][0], r[1][1], r[1][2]]);
        assert!((child[0] - 2.0).abs() < 0.05, "{child:?}");
    }

    #[test]
    fn resets_set_rest_to_the_current_positions() {
        let clock = RestClock {
            start: 1,
            period: 4,
        };
        let mut t = RestTracker::default();
        let mut r = Vec::new();
        for f in 1..=5u32 {
            let x = 100.0 + 10.0 * f as f32;
            r = t.update(&state(&[([x, 100.0, 100.0], 0)]), f, &clock, &CODEC, 50.0);
            let a = CODEC.decode([r[0][0], r[0][1], r[0][2]]);
            let b = CODEC.decode([r[0][3], r[0][4], r[0][5]]);
            // A reset on 1 and 5, B on 1 and 3
            let want_a = if f < 5 { 110.0 } else { 150.0 };
            let want_b = if f < 3 { 110.0 } else { 130.0 };
            assert!((a[0] - want_a).abs() < 0.05, "frame {f}: {a:?}");
            assert!((b[0] - want_b).abs() < 0.05, "frame {f}: {b:?}");
        }
        assert_eq!(r.len(), 1);
    }
}
