//! Checkpoint size per particle and write / read+validate time (figures for docs/PERFORMANCE.md).
use crate::error::{Error, Result};
use crate::ground::ParticleState;
use crate::io::checkpoint::{self, Checkpoint, CheckpointHeader};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

const REPS: usize = 5;

/// Measures a checkpoint of `particles` particles in a fresh directory under the system
/// temporary directory (removed afterwards).
pub fn bench_checkpoint(particles: usize) -> Result<serde_json::Value> {
    let dir = std::env::temp_dir().join(format!(
        "nimbus-bench-checkpoint-{}-{particles}",
        std::process::id()
    ));
    let result = bench_checkpoint_in(&dir, particles);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Measures a checkpoint of `particles` particles written into `dir`: file size, bytes per
/// particle, and the median / min of `REPS` writes (fsync'd, atomic) and of `REPS` full reads
/// with validation.
pub fn bench_checkpoint_in(dir: &Path, particles: usize) -> Result<serde_json::Value> {
    let ck = synthetic(particles);
    let mut write_s = Vec::with_capacity(REPS);
    let mut path = dir.to_path_buf();
    for _ in 0..REPS {
        let t = Instant::now();
        path = checkpoint::write_checkpoint(dir, &ck)?;
        write_s.push(t.elapsed().as_secs_f64());
    }
    let bytes = std::fs::metadata(&path)
        .map_err(|e| Error::io(&path, e))?
        .len();
    let mut read_s = Vec::with_capacity(REPS);
    for _ in 0..REPS {
        let t = Instant::now();
        let back = checkpoint::read_checkpoint(&path)?;
        read_s.push(t.elapsed().as_secs_f64());
        if !same_bits(&back, &ck) {
            return Err(Error::Runtime(
                "checkpoint benchmark: read back differs from what was written".into(),
            ));
        }
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[0])
    };
    let (w_med, w_min) = med(&mut write_s);
    let (r_med, r_min) = med(&mut read_s);
    let mb = bytes as f64 / 1e6;
    Ok(serde_json::json!({
        "particles": particles,
        "file_bytes": bytes,
        "bytes_per_particle": bytes as f64 / particles.max(1) as f64,
        "reps": REPS,
        "write_ms_median": w_med * 1e3,
        "write_ms_min": w_min * 1e3,
        "write_mb_per_s": mb / w_med,
        "read_validate_ms_median": r_med * 1e3,
        "read_validate_ms_min": r_min * 1e3,
        "read_mb_per_s": mb / r_med,
        "dir": dir.display().to_string(),
    }))
}

/// Bitwise equality: the synthetic floats include NaNs, for which `==` is false.
fn same_bits(a: &Checkpoint, b: &Checkpoint) -> bool {
    fn words<T: bytemuck::Pod>(v: &[T]) -> &[u32] {
        bytemuck::cast_slice(v)
    }
    let (x, y) = (&a.state, &b.state);
    a.header.time.to_bits() == b.header.time.to_bits()
        && a.header.frame == b.header.frame
        && a.header.particle_count == b.header.particle_count
        && words(&x.pos) == words(&y.pos)
        && words(&x.vel) == words(&y.vel)
        && words(&x.thermo) == words(&y.thermo)
        && words(&x.info) == words(&y.info)
        && words(&x.density) == words(&y.density)
        && a.extra == b.extra
}

/// A checkpoint filled with deterministic pseudo-random bits (incompressible like real state).
fn synthetic(n: usize) -> Checkpoint {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        // splitmix64
        x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = x;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        (z ^ (z >> 31)) as u32
    };
    let mut f4 = |_| [0; 4].map(|_: u8| f32::from_bits(next()));
    let state = ParticleState {
        pos: (0..n).map(&mut f4).collect(),
        vel: (0..n).map(&mut f4).collect(),
        thermo: (0..n).map(&mut f4).collect(),
        info: (0..n as u32).map(|i| [i, i % 3]).collect(),
        density: (0..n).map(|i| 1.0 + i as f32 * 1e-6).collect(),
    };
    Checkpoint {
        header: CheckpointHeader {
            tool_version: crate::VERSION.to_string(),
            sim_hash: "0123456789abcdef".into(),
            frame: 1,
            step: 4,
            time: 1.0 / 24.0,
            seed: 1,
            particle_count: n as u64,
            capacity: 2 * n as u64,
            adapter: "bench".into(),
            next_id: n as u32,
        },
        state,
        extra: BTreeMap::new(),
    }
}
