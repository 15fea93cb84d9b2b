//! What a shot asks of a device, known from its config before anything is allocated: the
//! largest storage binding, the largest buffer, the device bytes and the most workgroups of one
//! dispatch, and whether the device holds them ([`Footprint::check`]). `validate --gpu`, the
//! start of `run` (before the run directory is made), `bench pbf` and
//! [`crate::sim::Simulation::from_state`] all refuse a shot over the device's limits with the
//! same message: the limit, and the largest particle count that fits.
//!
//! The figures follow the allocations of `sim::buffers`, the stages and `gpu::scan` (92 bytes
//! per particle slot, the cell tables, the walls, the heat maps, the scans' block sums); the
//! parameter blocks, counters and timestamp buffers are bounded by [`FIXED_BYTES`]. A test
//! holds the estimate to within 1% above what a simulation allocates
//! (`Simulation::device_bytes`).
use crate::config::ShotConfig;
use crate::error::{Error, Result};
use crate::gpu::limits::DeviceLimits;
use crate::gpu::shaders::SCAN_BLOCK;
use crate::sim::grid_params::GridParams;

/// Bytes of device memory per particle slot: pos, vel, thermo, pred, pairs (16 each), info (8),
/// density (4) (`sim::buffers`).
pub const BYTES_PER_SLOT: u64 = 92;
/// The largest per-particle array's element: a `vec4<f32>` (the whole array is one binding).
pub const WIDEST_ELEMENT: u64 = 16;
/// Bytes of one frame's read-back per live particle: pos, vel, thermo, info, density.
pub const READBACK_PER_PARTICLE: u64 = 60;
/// A bound on every buffer whose size does not grow with the shot: parameter blocks (one
/// 256-byte slot each, up to 75 merge colours and the scans' levels), the adaptive counters,
/// the live state and the timestamp queries (4096 x 8 bytes, resolved and read back).
pub const FIXED_BYTES: u64 = 256 << 10;
/// Share of the largest device-local heap a shot may fill: the driver, the read-back and other
/// processes need the rest.
pub const MEMORY_SHARE: f64 = 0.9;

/// The size-determining facts of a shot (all but the particle count come from its config).
#[derive(Debug, Clone)]
pub struct ShotSize {
    pub particles: u64,
    /// Slots per particle (`AdaptiveConfig::slots_per_particle`).
    pub capacity_factor: f64,
    pub adaptive: bool,
    pub grid: GridParams,
    /// Wall particles (floor and ceiling).
    pub boundary: u64,
    /// f32 values of the heat-map buffer (image sources and the target controller's maps).
    pub map_values: u64,
}

impl ShotSize {
    /// A prepared shot with `particles` particles (its heat maps and target size the map
    /// buffer, as the thermodynamics stage will).
    pub fn of(shot: &crate::shot::Shot, particles: u64) -> Self {
        let target = crate::sim::control::Target::of_shot(shot);
        let maps =
            crate::sim::sources::HeatMaps::new(shot.heat_maps()).with_target(target.as_ref());
        Self::with_maps(shot.config(), particles, maps.values.len() as u64)
    }

    /// [`Self::of`] with the heat-map buffer's length known.
    pub fn with_maps(cfg: &ShotConfig, particles: u64, map_values: u64) -> Self {
        let grid = GridParams::for_shot(cfg);
        Self {
            particles,
            capacity_factor: cfg.adaptive.slots_per_particle(),
            adaptive: cfg.adaptive.enabled,
            boundary: crate::sim::init::boundary_count(cfg) as u64,
            grid,
            map_values,
        }
    }

    /// Particle slots on the device: the capacity rounded up to 64 (`Simulation::from_state`).
    pub fn capacity(&self) -> u64 {
        let n = self.particles;
        ((n as f64 * self.capacity_factor).ceil() as u64)
            .max(n)
            .next_multiple_of(64)
    }
}

/// What a shot asks of the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Footprint {
    pub particles: u64,
    /// Particle slots (what split and merge may fill).
    pub capacity: u64,
    /// The largest storage binding, bytes (a particle array of `vec4`, or a cell table or the
    /// heat maps where they are larger).
    pub largest_binding: u64,
    /// The largest buffer, bytes: the largest binding, or the frame's read-back staging buffer.
    pub largest_buffer: u64,
    /// Device bytes of every buffer the simulation allocates, and the read-back staging.
    pub device_bytes: u64,
    /// Most workgroups one dispatch runs (they fold into x * y rows: `gpu::program::groups_for`).
    pub max_groups: u64,
}

/// Bytes a scan of `len` values allocates beyond its level-0 output, which both of nimbus's
/// scans lend (`gpu::scan::PrefixScan::new`).
fn scan_bytes(len: u64) -> u64 {
    let block = SCAN_BLOCK as u64;
    let mut lens = vec![len.max(1)];
    while *lens.last().unwrap() > block {
        lens.push(lens.last().unwrap().div_ceil(block));
    }
    let buf = |bytes: u64| bytes.max(16).next_multiple_of(4);
    lens.iter()
        .enumerate()
        .map(|(k, &n)| {
            let sums = buf(4 * n.div_ceil(block).next_multiple_of(4));
            let output = if k > 0 { buf(4 * n) } else { 0 };
            sums + output
        })
        .sum()
}

impl Footprint {
    /// The footprint of `shot` with per-particle workgroups of `wg` threads (the smallest
    /// workgroup of the device's prelude).
    pub fn of(shot: &ShotSize, wg: u32) -> Self {
        let slots = shot.capacity();
        let grid = &shot.grid;
        let buf = |bytes: u64| bytes.max(16).next_multiple_of(4);
        let table = grid.table_len() as u64;
        let cells = grid.num_cells as u64;
        let table_bytes = buf(4 * table);
        // the grid build's counts live in `pairs` unless the table is larger than a quarter
        let counts_own = if (4 * table).next_multiple_of(16) > 4 * slots {
            (4 * table).next_multiple_of(16)
        } else {
            0
        };
        let walls = buf(16 * shot.boundary) + buf(4 * grid.wall_table_len() as u64);
        let maps = buf(4 * shot.map_values);
        let adaptive = if shot.adaptive {
            buf(4 * cells) + scan_bytes(slots)
        } else {
            0
        };
        let readback = READBACK_PER_PARTICLE * slots;
        let device_bytes = BYTES_PER_SLOT * slots
            + table_bytes
            + counts_own
            + scan_bytes(table)
            + walls
            + maps
            + adaptive
            + FIXED_BYTES
            + readback;
        let largest_binding = (WIDEST_ELEMENT * slots)
            .max(table_bytes)
            .max(counts_own)
            .max(maps)
            .max(buf(16 * shot.boundary))
            .max(if shot.adaptive { buf(4 * cells) } else { 0 });
        let wg = wg.max(1) as u64;
        let mut max_groups = slots.div_ceil(wg).max(table.div_ceil(wg));
        if shot.adaptive {
            // the merge runs a workgroup per listed cell of a colour
            let colour = crate::sim::adaptive::colour_passes(grid)
                .iter()
                .map(|c| c.cells() as u64)
                .max()
                .unwrap_or(0);
            max_groups = max_groups.max(colour);
        }
        Self {
            particles: shot.particles,
            capacity: slots,
            largest_binding,
            largest_buffer: largest_binding.max(readback),
            device_bytes,
            max_groups,
        }
    }

    /// The first limit of `limits` this footprint exceeds: (the limit's name, its value, what
    /// the shot needs), or `None` when the device holds it.
    pub fn exceeds(&self, limits: &DeviceLimits) -> Option<(&'static str, u64, u64)> {
        let groups = limits.max_compute_workgroups_per_dimension as u64;
        let memory = limits
            .device_memory
            .map(|m| (m as f64 * MEMORY_SHARE) as u64);
        if self.largest_binding > limits.max_storage_buffer_binding_size {
            Some((
                "max_storage_buffer_binding_size",
                limits.max_storage_buffer_binding_size,
                self.largest_binding,
            ))
        } else if self.largest_buffer > limits.max_buffer_size {
            Some((
                "max_buffer_size",
                limits.max_buffer_size,
                self.largest_buffer,
            ))
        } else if self.max_groups > groups * groups {
            Some((
                "max_compute_workgroups_per_dimension",
                groups,
                self.max_groups,
            ))
        } else {
            match memory {
                Some(m) if self.device_bytes > m => Some((
                    "device memory",
                    limits.device_memory.unwrap_or(0),
                    self.device_bytes,
                )),
                _ => None,
            }
        }
    }
}

/// The largest particle count of `shot`'s kind (its grid, walls, maps and capacity factor) that
/// `limits` hold (0 when none does).
pub fn largest_count(shot: &ShotSize, wg: u32, limits: &DeviceLimits) -> u64 {
    let fits = |n: u64| {
        let s = ShotSize {
            particles: n,
            ..shot.clone()
        };
        Footprint::of(&s, wg).exceeds(limits).is_none()
    };
    if !fits(1) {
        return 0;
    }
    let (mut lo, mut hi) = (1u64, 1u64 << 40);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if fits(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The reason a shot does not fit, as one line: the limit, what the shot needs, and the
/// largest particle count that fits (`hint`: how to get there, e.g. a larger spacing).
pub fn refusal(
    shot: &ShotSize,
    fp: &Footprint,
    limit: (&'static str, u64, u64),
    adapter: &str,
    largest: u64,
    hint: Option<String>,
) -> String {
    let (name, value, need) = limit;
    let what = match name {
        "max_storage_buffer_binding_size" => format!(
            "their largest storage binding is {need} bytes, over the adapter's {name} of \
             {value} bytes"
        ),
        "max_buffer_size" => {
            format!(
                "their largest buffer is {need} bytes, over the adapter's {name} of {value} bytes"
            )
        }
        "max_compute_workgroups_per_dimension" => format!(
            "one dispatch runs {need} workgroups, over the adapter's {name} of {value} ({} in \
             rows)",
            value * value
        ),
        _ => format!(
            "they need {need} bytes of device memory, over {:.0}% of the adapter's largest \
             memory heap ({value} bytes)",
            MEMORY_SHARE * 100.0
        ),
    };
    let fits = if largest == 0 {
        "no particle count of this shot fits".to_string()
    } else {
        format!("at most {largest} particles of this shot fit")
    };
    format!(
        "{} particles (capacity {}) do not fit adapter {adapter}: {what}; {fits}{}",
        shot.particles,
        fp.capacity,
        hint.map(|h| format!(" ({h})")).unwrap_or_default()
    )
}

/// Checks `shot` with `particles` particles against the device; the refusal is exit 4 with the
/// limit and the largest count that fits, and a domain.spacing that fits.
pub fn check_shot(
    ctx: &crate::gpu::Context,
    shot: &crate::shot::Shot,
    particles: u64,
) -> Result<Footprint> {
    let size = ShotSize::of(shot, particles);
    check(ctx, &size, || spacing_hint(ctx, shot.config(), &size))
}

/// `validate --gpu`: `shot` (its lattice's particles) checked against the device; on success,
/// its footprint and the largest particle count of this shot the device holds.
pub fn check_config(
    ctx: &crate::gpu::Context,
    shot: &crate::shot::Shot,
) -> Result<(Footprint, u64)> {
    let cfg = shot.config();
    let size = ShotSize::of(shot, shot.particles());
    let fp = check(ctx, &size, || spacing_hint(ctx, cfg, &size))?;
    let largest = largest_count(&size, smallest_workgroup(&ctx.prelude), &ctx.limits);
    Ok((fp, largest))
}

/// Checks `shot` against the device (`hint` is asked for only on a refusal).
pub fn check(
    ctx: &crate::gpu::Context,
    shot: &ShotSize,
    hint: impl FnOnce() -> Option<String>,
) -> Result<Footprint> {
    let wg = smallest_workgroup(&ctx.prelude);
    let fp = Footprint::of(shot, wg);
    match fp.exceeds(&ctx.limits) {
        None => Ok(fp),
        Some(limit) => {
            let largest = largest_count(shot, wg, &ctx.limits);
            Err(Error::NoGpu(refusal(
                shot,
                &fp,
                limit,
                &ctx.adapter_name(),
                largest,
                hint(),
            )))
        }
    }
}

/// The smallest workgroup of a prelude's per-particle kernels (the most workgroups).
pub fn smallest_workgroup(p: &crate::gpu::shaders::Prelude) -> u32 {
    p.wg_particles.min(p.wg_block)
}

/// "domain.spacing >= D": the smallest spacing (3 significant digits, rounded up) at which the
/// shot of `cfg` fits, when its particle count comes from the lattice.
fn spacing_hint(ctx: &crate::gpu::Context, cfg: &ShotConfig, shot: &ShotSize) -> Option<String> {
    if shot.particles != crate::config::lattice_count(&cfg.domain) as u64 {
        return None;
    }
    let wg = smallest_workgroup(&ctx.prelude);
    let fits = |d: f64| {
        let mut c = cfg.clone();
        c.domain.spacing = d;
        let s = ShotSize::with_maps(
            &c,
            crate::config::lattice_count(&c.domain) as u64,
            shot.map_values,
        );
        Footprint::of(&s, wg).exceeds(&ctx.limits).is_none()
    };
    let d0 = cfg.domain.spacing;
    let mut hi = d0;
    while !fits(hi) {
        hi *= 2.0;
        if hi > d0 * 1e4 {
            return None;
        }
    }
    let mut lo = d0;
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if fits(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    // three significant digits, rounded up, and still fitting
    let scale = 10f64.powi(2 - hi.log10().floor() as i32);
    let mut d = (hi * scale).ceil() / scale;
    while !fits(d) {
        d += 1.0 / scale;
    }
    Some(format!("domain.spacing >= {d} fits"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shot(yaml: &str) -> ShotConfig {
        serde_saphyr::from_str(yaml).unwrap()
    }

    fn limits(binding: u64) -> DeviceLimits {
        DeviceLimits {
            max_buffer_size: 1 << 31,
            max_storage_buffer_binding_size: binding,
            max_compute_workgroups_per_dimension: 65535,
            device_memory: Some(16 << 30),
        }
    }

    /// The case: 7M particles with adaptivity (capacity 14M) on lavapipe's 128 MiB
    /// bindings; about 4.19M fit.
    #[test]
    fn seven_million_adaptive_particles_exceed_128_mib_bindings() {
        let cfg = shot(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [1600, 1400, 1600], spacing: 8}\nadaptive: {enabled: true}\n",
        );
        let n = crate::config::lattice_count(&cfg.domain) as u64;
        assert_eq!(n, 7_000_000);
        let s = ShotSize::with_maps(&cfg, n, 1);
        let fp = Footprint::of(&s, 64);
        assert_eq!(fp.capacity, 2 * n);
        let lim = limits(128 << 20);
        let (name, value, need) = fp.exceeds(&lim).unwrap();
        assert_eq!(name, "max_storage_buffer_binding_size");
        assert_eq!((value, need), (128 << 20, 16 * 2 * n));
        let largest = largest_count(&s, 64, &lim);
        // 2^23 slots of 16 bytes, two per particle
        assert_eq!(largest, 1 << 22);
        let at = ShotSize {
            particles: largest,
            ..s.clone()
        };
        assert!(Footprint::of(&at, 64).exceeds(&lim).is_none());
        let over = ShotSize {
            particles: largest + 1,
            ..s
        };
        assert!(Footprint::of(&over, 64).exceeds(&lim).is_some());
    }

    #[test]
    fn workgroups_and_memory_are_limits_too() {
        let cfg = shot(
            "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
             domain: {size: [1000, 1000, 1000], spacing: 10}\n",
        );
        let s = ShotSize::with_maps(&cfg, 1_000_000, 1);
        let fp = Footprint::of(&s, 64);
        assert_eq!(fp.max_groups, 1_000_000u64.div_ceil(64));
        let mut lim = limits(1 << 30);
        assert!(fp.exceeds(&lim).is_none());
        lim.max_compute_workgroups_per_dimension = 100;
        assert_eq!(
            fp.exceeds(&lim).unwrap().0,
            "max_compute_workgroups_per_dimension"
        );
        assert_eq!(largest_count(&s, 64, &lim), 100 * 100 * 64);
        lim.max_compute_workgroups_per_dimension = 65535;
        lim.device_memory = Some(100 << 20);
        assert_eq!(fp.exceeds(&lim).unwrap().0, "device memory");
        lim.device_memory = None;
        assert!(fp.exceeds(&lim).is_none());
        lim.max_buffer_size = 50 << 20;
        assert_eq!(fp.exceeds(&lim).unwrap().0, "max_buffer_size");
    }
}
