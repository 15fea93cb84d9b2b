//! f64 mirror of the adaptive stage (shaders/adaptive_*.wgsl), one function per entry point
//! with the same name, run in the same order by [`run`]. Arrays have the GPU's length
//! (`capacity`) so slot assignment (compaction, appended children) mirrors the GPU exactly.
use super::kernels::min_image;
use crate::sim::adaptive::{
    colour_passes, mass_units, AdaptiveParams, AdaptiveReport, ColourPass, FLAG_DEAD, FLAG_MERGE,
    FLAG_MERGED, FLAG_SPLIT, MAX_LEVELS,
};
use crate::sim::grid_params::GridParams;

/// Particle arrays of length `capacity` (xyzw as on the GPU; pos.w is carried, unused).
#[derive(Debug, Clone, PartialEq)]
pub struct RefParticles {
    pub pos: Vec<[f64; 4]>,
    pub vel: Vec<[f64; 4]>,
    pub thermo: Vec<[f64; 4]>,
    pub info: Vec<[u32; 2]>,
}

impl RefParticles {
    /// The first `pos.len()` particles live, padded with zeros to `capacity`.
    pub fn from_f32(
        pos: &[[f32; 4]],
        vel: &[[f32; 4]],
        thermo: &[[f32; 4]],
        info: &[[u32; 2]],
        capacity: usize,
    ) -> Self {
        let widen = |v: &[[f32; 4]]| {
            let mut out: Vec<[f64; 4]> = v.iter().map(|a| a.map(|x| x as f64)).collect();
            out.resize(capacity, [0.0; 4]);
            out
        };
        let mut info = info.to_vec();
        info.resize(capacity, [0, 0]);
        Self {
            pos: widen(pos),
            vel: widen(vel),
            thermo: widen(thermo),
            info,
        }
    }
}

/// Mirror of the counters buffer.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Counters {
    pub merges: u32,
    pub newcount: u32,
    pub split_wanted: u32,
    pub splits: u32,
    pub skipped: u32,
    pub final_count: u32,
    pub next_id: u32,
    pub levels: Vec<u32>,
}

pub fn level_radius(h0: f64, level: u32) -> f64 {
    h0 * (-(level as f64) / 3.0).exp2()
}

/// The shaders' `pcg_hash` (shared/common.wgsl); one mirror for noise and split directions.
pub use crate::sim::noise::pcg_hash;

/// Unit direction of a split from the particle id (uniform on the sphere).
pub fn split_dir(id: u32) -> [f64; 3] {
    let a = pcg_hash(id);
    let b = pcg_hash(a);
    let u = (a >> 8) as f64 / 16777216.0;
    let v = (b >> 8) as f64 / 16777216.0;
    let z = 1.0 - 2.0 * u;
    let s = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f64::consts::TAU * v;
    [s * phi.cos(), s * phi.sin(), z]
}

fn size(g: &GridParams) -> [f64; 3] {
    g.domain_size.map(|v| v as f64)
}

fn mi(d: [f64; 3], g: &GridParams) -> [f64; 3] {
    min_image(d, size(g), [g.periodic_x(), g.periodic_z()])
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn xyz(p: [f64; 4]) -> [f64; 3] {
    [p[0], p[1], p[2]]
}

pub fn wrap_pos(p: [f64; 3], g: &GridParams) -> [f64; 3] {
    let mut r = p;
    let (lo, sz) = (g.domain_min.map(|v| v as f64), size(g));
    if g.periodic_x() {
        r[0] -= sz[0] * ((r[0] - lo[0]) / sz[0]).floor();
    }
    if g.periodic_z() {
        r[2] -= sz[2] * ((r[2] - lo[2]) / sz[2]).floor();
    }
    r
}

pub fn inside_walls(p: [f64; 3], g: &GridParams) -> bool {
    let lo = g.domain_min.map(|v| v as f64);
    let sz = size(g);
    let within = |a: usize| p[a] >= lo[a] && p[a] <= lo[a] + sz[a];
    within(1) && (g.periodic_x() || within(0)) && (g.periodic_z() || within(2))
}

/// Calls `f(k)` for every slot of the 27 cells around cell `c`, in the shaders' order.
fn for_slots(g: &GridParams, cell_start: &[u32], c: [i32; 3], mut f: impl FnMut(usize) -> bool) {
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let Some(n) = g.neighbor_cell(c, [dx, dy, dz]) else {
                    continue;
                };
                for k in g.cell_slots(cell_start, n) {
                    if !f(k as usize) {
                        return;
                    }
                }
            }
        }
    }
}

fn children(
    g: &GridParams,
    prm: &AdaptiveParams,
    x: [f64; 3],
    id: u32,
    level: u32,
) -> [[f64; 3]; 2] {
    let hc = level_radius(prm.h0 as f64, level + 1);
    let d = split_dir(id);
    let r = prm.split_offset as f64 * hc;
    let off = d.map(|v| r * v);
    [
        wrap_pos([x[0] + off[0], x[1] + off[1], x[2] + off[2]], g),
        wrap_pos([x[0] - off[0], x[1] - off[1], x[2] - off[2]], g),
    ]
}

fn split_fits(
    g: &GridParams,
    prm: &AdaptiveParams,
    cell_start: &[u32],
    p: &RefParticles,
    i: usize,
) -> bool {
    let x = xyz(p.pos[i]);
    let [id, level] = p.info[i];
    let [a, b] = children(g, prm, x, id, level);
    if !inside_walls(a, g) || !inside_walls(b, g) {
        return false;
    }
    let r = prm.min_distance as f64 * level_radius(prm.h0 as f64, level + 1);
    let mut ok = true;
    for_slots(g, cell_start, g.cell_coord(x), |k| {
        if k != i {
            let q = xyz(p.pos[k]);
            let (da, db) = (mi(sub(a, q), g), mi(sub(b, q), g));
            if dot(da, da) < r * r || dot(db, db) < r * r {
                ok = false;
            }
        }
        ok
    });
    ok
}

/// Shape energy and marks (adaptive_mark.wgsl).
#[allow(clippy::needless_range_loop)] // indexed like the shader: split_fits reads all of `p`
pub fn adaptive_mark(
    g: &GridParams,
    prm: &AdaptiveParams,
    cell_start: &[u32],
    p: &mut RefParticles,
    flags: &mut [u32],
) {
    for i in 0..prm.count as usize {
        let e = prm.kp as f64 * (1.0 - (-(prm.kc as f64) * p.thermo[i][2]).exp());
        p.thermo[i][3] = e;
        let level = p.info[i][1];
        flags[i] = if e < prm.merge_threshold as f64 && level > 0 {
            FLAG_MERGE
        } else if e > prm.split_threshold as f64
            && level < prm.max_level
            && split_fits(g, prm, cell_start, p, i)
        {
            FLAG_SPLIT
        } else {
            0
        };
    }
}

/// One colour pass of the merge (adaptive_merge.wgsl); its cells are independent, so running
/// them one after another gives what the parallel threads give.
pub fn adaptive_merge(
    g: &GridParams,
    prm: &AdaptiveParams,
    colour: &ColourPass,
    cell_start: &[u32],
    p: &mut RefParticles,
    flags: &mut [u32],
) {
    let h0 = prm.h0 as f64;
    for t in 0..colour.cells() {
        let c = colour.cell(t);
        let cell = g
            .neighbor_cell(c, [0, 0, 0])
            .expect("colour cells are inside") as usize;
        for i in g.cell_slots(cell_start, cell as u32) {
            let i = i as usize;
            if flags[i] != FLAG_MERGE {
                continue;
            }
            let level = p.info[i][1];
            let xi = xyz(p.pos[i]);
            let h = level_radius(h0, level);
            let (mut best, mut best_d2) = (None, h * h);
            for_slots(g, cell_start, c, |k| {
                if k != i && flags[k] == FLAG_MERGE && p.info[k][1] == level {
                    let d = mi(sub(xyz(p.pos[k]), xi), g);
                    if dot(d, d) < best_d2 {
                        best_d2 = dot(d, d);
                        best = Some(k);
                    }
                }
                true
            });
            let Some(j) = best else { continue };
            let dj = mi(sub(xyz(p.pos[j]), xi), g);
            let m = wrap_pos(
                [
                    xi[0] + 0.5 * dj[0],
                    xi[1] + 0.5 * dj[1],
                    xi[2] + 0.5 * dj[2],
                ],
                g,
            );
            let r = prm.min_distance as f64 * level_radius(h0, level - 1);
            let mut clear = true;
            for_slots(g, cell_start, c, |k| {
                if k != i && k != j && flags[k] & FLAG_DEAD == 0 {
                    let d = mi(sub(m, xyz(p.pos[k])), g);
                    if dot(d, d) < r * r {
                        clear = false;
                    }
                }
                clear
            });
            if !clear {
                continue;
            }
            p.pos[i] = [m[0], m[1], m[2], p.pos[i][3]];
            p.vel[i] = std::array::from_fn(|a| 0.5 * (p.vel[i][a] + p.vel[j][a]));
            p.thermo[i] = std::array::from_fn(|a| 0.5 * (p.thermo[i][a] + p.thermo[j][a]));
            p.info[i] = [p.info[i][0].min(p.info[j][0]), level - 1];
            flags[i] = FLAG_MERGED;
            flags[j] = FLAG_DEAD;
        }
    }
}

/// Exclusive scan of `(flags & mask) != 0` over the first n (scan_blocks + add_block_offsets).
pub fn exclusive_scan(flags: &[u32], n: usize, mask: u32) -> Vec<u32> {
    let mut acc = 0;
    flags[..n]
        .iter()
        .map(|&f| {
            let v = acc;
            acc += (f & mask != 0) as u32;
            v
        })
        .collect()
}

fn scan_total(scan: &[u32], flags: &[u32], n: usize, bit: u32) -> u32 {
    if n == 0 {
        0
    } else {
        scan[n - 1] + (flags[n - 1] & bit != 0) as u32
    }
}

pub fn totals_merge(prm: &AdaptiveParams, scan: &[u32], flags: &[u32], c: &mut Counters) {
    let dead = scan_total(scan, flags, prm.count as usize, FLAG_DEAD);
    c.merges = dead;
    c.newcount = prm.count - dead;
}

pub fn compact_holes(
    prm: &AdaptiveParams,
    c: &Counters,
    scan: &[u32],
    flags: &[u32],
    holes: &mut [u32],
) {
    for i in 0..prm.count as usize {
        if i < c.newcount as usize && flags[i] & FLAG_DEAD != 0 {
            holes[scan[i] as usize] = i as u32;
        }
    }
}

pub fn compact_move(
    prm: &AdaptiveParams,
    c: &Counters,
    scan: &[u32],
    flags: &mut [u32],
    holes: &[u32],
    p: &mut RefParticles,
) {
    let nc = c.newcount as usize;
    for j in nc..prm.count as usize {
        let f = flags[j];
        if f & FLAG_DEAD == 0 {
            let rank = (j - nc) - (scan[j] - scan[nc]) as usize;
            let dst = holes[rank] as usize;
            p.pos[dst] = p.pos[j];
            p.vel[dst] = p.vel[j];
            p.thermo[dst] = p.thermo[j];
            p.info[dst] = p.info[j];
            flags[dst] = f;
        }
        flags[j] = 0;
    }
}

pub fn totals_split(prm: &AdaptiveParams, scan: &[u32], flags: &[u32], c: &mut Counters) {
    let wanted = scan_total(scan, flags, prm.count as usize, FLAG_SPLIT);
    let done = wanted.min(prm.capacity - c.newcount);
    c.split_wanted = wanted;
    c.splits = done;
    c.skipped = wanted - done;
    c.final_count = c.newcount + done;
    c.next_id = prm.next_id + done;
    c.levels = vec![0; MAX_LEVELS as usize];
}

pub fn adaptive_split(
    g: &GridParams,
    prm: &AdaptiveParams,
    c: &Counters,
    scan: &[u32],
    flags: &[u32],
    p: &mut RefParticles,
) {
    for i in 0..c.newcount as usize {
        if flags[i] & FLAG_SPLIT == 0 || scan[i] >= c.splits {
            continue;
        }
        let k = scan[i];
        let slot = (c.newcount + k) as usize;
        let [id, level] = p.info[i];
        let [a, b] = children(g, prm, xyz(p.pos[i]), id, level);
        let w = p.pos[i][3];
        p.pos[i] = [a[0], a[1], a[2], w];
        p.pos[slot] = [b[0], b[1], b[2], w];
        p.vel[slot] = p.vel[i];
        p.thermo[slot] = p.thermo[i];
        p.info[i] = [id, level + 1];
        p.info[slot] = [prm.next_id + k, level + 1];
    }
}

pub fn count_levels(c: &mut Counters, p: &RefParticles) {
    for i in 0..c.final_count as usize {
        c.levels[(p.info[i][1]).min(MAX_LEVELS - 1) as usize] += 1;
    }
}

/// The whole stage, in the GPU's order; `prm.count` and `prm.next_id` describe the input.
pub fn run(
    g: &GridParams,
    prm: &AdaptiveParams,
    cell_start: &[u32],
    p: &mut RefParticles,
) -> AdaptiveReport {
    let cap = prm.capacity as usize;
    let n = prm.count as usize;
    let mut flags = vec![0u32; cap];
    let mut holes = vec![0u32; cap];
    let mut c = Counters::default();
    adaptive_mark(g, prm, cell_start, p, &mut flags);
    for colour in colour_passes(g) {
        adaptive_merge(g, prm, &colour, cell_start, p, &mut flags);
    }
    let scan = exclusive_scan(&flags, n, FLAG_DEAD);
    totals_merge(prm, &scan, &flags, &mut c);
    compact_holes(prm, &c, &scan, &flags, &mut holes);
    compact_move(prm, &c, &scan, &mut flags, &holes, p);
    let scan = exclusive_scan(&flags, n, FLAG_SPLIT);
    totals_split(prm, &scan, &flags, &mut c);
    adaptive_split(g, prm, &c, &scan, &flags, p);
    count_levels(&mut c, p);
    let per_level = c.levels[..prm.max_level as usize + 1].to_vec();
    AdaptiveReport {
        mass_units: mass_units(&per_level, prm.max_level),
        per_level,
        splits: c.splits,
        merges: c.merges,
        skipped_splits: c.skipped,
        count: c.final_count,
        next_id: c.next_id,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::AdaptiveConfig;
    use crate::sim::reference::grid::build_cell_table;
    use rand::{Rng, SeedableRng};

    #[test]
    fn split_dir_is_unit_and_spread() {
        let mut mean = [0.0; 3];
        for id in 0..4000 {
            let d = split_dir(id);
            assert!((dot(d, d) - 1.0).abs() < 1e-12);
            for a in 0..3 {
                mean[a] += d[a] / 4000.0;
            }
        }
        assert!(dot(mean, mean).sqrt() < 0.05, "biased directions {mean:?}");
    }

    /// Random particles; merges and splits happen and mass units are conserved by the mirror.
    #[test]
    fn mirror_conserves_mass_units_and_ids() {
        let g = GridParams::new([1.0, 0.65, 1.1], 0.1, true, true);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 1500;
        let pos: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                [
                    rng.random::<f64>(),
                    0.05 + 0.55 * rng.random::<f64>(),
                    1.1 * rng.random::<f64>(),
                ]
            })
            .collect();
        let (order, cell_start) = build_cell_table(&g, &pos);
        let mut p = RefParticles::from_f32(&[], &[], &[], &[], 2 * n);
        for (k, &o) in order.iter().enumerate() {
            let x = pos[o as usize];
            p.pos[k] = [x[0], x[1], x[2], 0.0];
            p.thermo[k] = [
                280.0,
                0.01,
                if rng.random::<bool>() { 0.0 } else { 0.01 },
                0.0,
            ];
            p.info[k] = [o, rng.random_range(0..=3)];
        }
        let cfg = AdaptiveConfig::default();
        let mut prm = AdaptiveParams::new(&cfg, 0.1, 2 * n as u32).unwrap();
        prm.count = n as u32;
        prm.next_id = n as u32;
        let before: u64 = p.info[..n]
            .iter()
            .map(|i| crate::sim::adaptive::level_mass_units(i[1], 3))
            .sum();
        let rep = run(&g, &prm, &cell_start, &mut p);
        assert!(rep.merges > 10 && rep.splits > 10, "{rep:?}");
        assert_eq!(rep.mass_units, before);
        let mut ids: Vec<u32> = p.info[..rep.count as usize].iter().map(|i| i[0]).collect();
        ids.sort();
        ids.dedup();
        assert_eq!(ids.len(), rep.count as usize);
    }
}
