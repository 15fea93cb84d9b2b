//! The one harness that runs a GPU stage against its f64 mirror (`nimbus::sim::reference`) on
//! fresh random inputs: a [`Scene`] of particles in the stages' input contract (cell order,
//! cell tables, walls) is uploaded as the device's particle buffers, one stage is recorded over
//! it, and the particles come back for the comparison with the mirror run on the same scene.
//! Every test prints its seed; `NIMBUS_TEST_SEED=N` repeats a failure.
#![allow(dead_code)]
use nimbus::config::GpuConfig;
use nimbus::error::Result;
use nimbus::gpu::live::{Live, LiveBuffer};
use nimbus::gpu::Context;
use nimbus::ground::ParticleState;
use nimbus::sim::buffers::ParticleBuffers;
use nimbus::sim::grid_params::GridParams;
use nimbus::sim::phase::Recorder;
use nimbus::sim::reference::grid::{build_cell_table, build_wall_table};
use std::sync::Arc;

/// The adapter the tests run on (lavapipe is enough).
pub fn context() -> Arc<Context> {
    let dir = std::env::temp_dir().join("nimbus-test-xdg");
    std::fs::create_dir_all(&dir).unwrap();
    std::env::set_var("XDG_RUNTIME_DIR", &dir);
    Arc::new(
        Context::new(&GpuConfig::default())
            .expect("these tests need a wgpu adapter (lavapipe is enough)"),
    )
}

/// A fresh seed from the clock, or `NIMBUS_TEST_SEED`; printed so a failure can be repeated.
pub fn fresh_seed() -> u64 {
    let seed = std::env::var("NIMBUS_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos() as u64
        });
    eprintln!("seed {seed} (repeat with NIMBUS_TEST_SEED={seed})");
    seed
}

/// Particles in the stages' input contract: sorted into cell order of `grid`, with the cell
/// table, and the walls (xyz, temperature) sorted likewise with theirs.
#[derive(Debug, Clone)]
pub struct Scene {
    pub grid: GridParams,
    pub state: ParticleState,
    pub cell_start: Vec<u32>,
    pub boundary: (Vec<[f32; 4]>, Vec<u32>),
    pub capacity: u32,
    pub next_id: u32,
}

impl Scene {
    /// Sorts `state` and `walls` into cell order; arrays get `capacity` slots on the device.
    pub fn new(
        mut grid: GridParams,
        state: ParticleState,
        walls: Vec<[f32; 4]>,
        capacity: usize,
    ) -> Self {
        let p64 = |v: &[[f32; 4]]| -> Vec<[f64; 3]> {
            v.iter().map(|p| [0, 1, 2].map(|a| p[a] as f64)).collect()
        };
        let (order, cell_start) = build_cell_table(&grid, &p64(&state.pos));
        let pick4 = |v: &[[f32; 4]]| order.iter().map(|&o| v[o as usize]).collect::<Vec<_>>();
        let n = state.len();
        let density = if state.density.len() == n {
            order.iter().map(|&o| state.density[o as usize]).collect()
        } else {
            vec![0.0; n]
        };
        let sorted = ParticleState {
            pos: pick4(&state.pos),
            vel: pick4(&state.vel),
            thermo: pick4(&state.thermo),
            info: order.iter().map(|&o| state.info[o as usize]).collect(),
            density,
        };
        let (border, bcell) = build_wall_table(&grid, &p64(&walls));
        let walls = border
            .iter()
            .map(|&o| walls[o as usize])
            .collect::<Vec<_>>();
        grid.n_boundary = walls.len() as u32;
        let next_id = sorted.info.iter().map(|i| i[0] + 1).max().unwrap_or(0);
        Self {
            grid,
            state: sorted,
            cell_start,
            boundary: (walls, bcell),
            capacity: capacity.max(n).next_multiple_of(64) as u32,
            next_id,
        }
    }

    /// Particles kept in the given order, without cell tables (for stages that read no
    /// neighbours, so that the comparison can go index by index).
    pub fn as_given(grid: GridParams, state: ParticleState, capacity: usize) -> Self {
        let n = state.len();
        let mut state = state;
        if state.density.len() != n {
            state.density = vec![0.0; n];
        }
        let next_id = state.info.iter().map(|i| i[0] + 1).max().unwrap_or(0);
        Self {
            cell_start: vec![0; grid.table_len()],
            grid,
            state,
            boundary: (Vec::new(), vec![0; grid.table_len()]),
            capacity: capacity.max(n).next_multiple_of(64) as u32,
            next_id,
        }
    }

    /// The scene as the device's particle buffers (cell tables included).
    pub fn upload(&self, ctx: &Context) -> ParticleBuffers {
        let b = ParticleBuffers::new(
            ctx,
            &self.state,
            self.capacity,
            &self.grid,
            &self.boundary,
            self.next_id,
        )
        .unwrap();
        ctx.queue
            .write_buffer(&b.cell_start, 0, bytemuck::cast_slice(&self.cell_start));
        b
    }

    pub fn len(&self) -> usize {
        self.state.len()
    }

    /// Writes the scene into buffers made for a scene of the same grid and capacity (tests that
    /// run one stage many times keep its bind groups).
    pub fn write_into(&self, ctx: &Context, b: &ParticleBuffers) {
        assert!(self.len() <= b.capacity as usize);
        let q = &ctx.queue;
        q.write_buffer(&b.pos, 0, bytemuck::cast_slice(&self.state.pos));
        q.write_buffer(&b.vel, 0, bytemuck::cast_slice(&self.state.vel));
        q.write_buffer(&b.thermo, 0, bytemuck::cast_slice(&self.state.thermo));
        q.write_buffer(&b.info, 0, bytemuck::cast_slice(&self.state.info));
        q.write_buffer(&b.density, 0, bytemuck::cast_slice(&self.state.density));
        q.write_buffer(&b.cell_start, 0, bytemuck::cast_slice(&self.cell_start));
        let single = self.state.info.iter().all(|i| i[1] == 0);
        b.live.write(
            ctx,
            &Live::new(ctx, self.len() as u32, self.next_id, single),
        );
    }
}

/// Records `stage` and submits it, without reading anything back (a stage's parameters are
/// written before the submit that carries it, so every substep is its own submit).
pub fn submit(
    ctx: &Context,
    b: &ParticleBuffers,
    stage: impl FnOnce(&mut Recorder, &LiveBuffer) -> Result<()>,
) {
    let mut rec = Recorder::new(ctx, None, None);
    stage(&mut rec, &b.live).unwrap();
    rec.submit();
}

/// Records `stage` over the uploaded scene, submits it, and reads the live particles back
/// (their count from the GPU's live state) with the live state itself.
pub fn run_gpu(
    ctx: &Context,
    b: &ParticleBuffers,
    stage: impl FnOnce(&mut Recorder, &LiveBuffer) -> Result<()>,
) -> (ParticleState, Live) {
    let mut rec = Recorder::new(ctx, None, None);
    stage(&mut rec, &b.live).unwrap();
    rec.submit();
    read_particles(ctx, b)
}

/// The live particles of the buffers and the live state.
pub fn read_particles(ctx: &Context, b: &ParticleBuffers) -> (ParticleState, Live) {
    use nimbus::gpu::buffers::read_back;
    let live: Live = read_back::<Live>(ctx, b.live.buffer(), 1).unwrap()[0];
    let n = live.count as usize;
    let state = ParticleState {
        pos: read_back(ctx, &b.pos, n).unwrap(),
        vel: read_back(ctx, &b.vel, n).unwrap(),
        thermo: read_back(ctx, &b.thermo, n).unwrap(),
        info: read_back(ctx, &b.info, n).unwrap(),
        density: read_back(ctx, &b.density, n).unwrap(),
    };
    (state, live)
}

/// xyz of a vec4 in f64.
pub fn v3(a: &[f32; 4]) -> [f64; 3] {
    [a[0] as f64, a[1] as f64, a[2] as f64]
}

/// Largest |gpu - mirror| over all components, relative to the largest |mirror| component
/// (floored at `floor`).
pub fn max_rel_err<const N: usize>(gpu: &[[f64; N]], cpu: &[[f64; N]], floor: f64) -> f64 {
    assert_eq!(gpu.len(), cpu.len(), "lengths differ");
    let scale = cpu
        .iter()
        .flat_map(|v| v.iter())
        .fold(floor, |m, x| m.max(x.abs()));
    gpu.iter()
        .zip(cpu)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f64::max)
        / scale
}

/// Moves every position lying within 1e-4 of a slice width of a cell or x-slice boundary of
/// `grid` 2e-4 slice widths away from it. The sort key is the floor of a quotient, and Vulkan
/// lets a division be 2.5 ulp off (and a driver may fuse a multiply and an add), so a position
/// within a few ulp of a boundary may get either key on another adapter; everywhere else the
/// key, and with it the grid build, is exact on any adapter. Returns how many were moved.
#[allow(clippy::needless_range_loop)] // three axes of three arrays
pub fn off_cell_boundaries(grid: &GridParams, pos: &mut [[f32; 4]]) -> usize {
    let mut moved = 0;
    for p in pos.iter_mut() {
        for a in 0..3 {
            let width = grid.cell_size[a] as f64 / if a == 0 { grid.x_slices as f64 } else { 1.0 };
            let u = (p[a] as f64 - grid.domain_min[a] as f64) / width;
            let off = u - u.round();
            if off.abs() < 1e-4 {
                let away = if off < 0.0 { -2e-4 } else { 2e-4 };
                p[a] = (grid.domain_min[a] as f64 + (u.round() + away) * width) as f32;
                moved += 1;
            }
        }
    }
    moved
}

/// A particle stage of `cfg` (a force such as `sim::forces::coriolis`) bound to `state`,
/// uploaded as given: the context, the buffers it is bound to and the stage, for one
/// `apply_with` against its mirror.
pub fn stage_over<S: nimbus::sim::stage::Stage>(
    cfg: &nimbus::config::ShotConfig,
    state: &ParticleState,
) -> (Arc<Context>, ParticleBuffers, S) {
    let ctx = context();
    let grid = GridParams::for_shot(cfg);
    let b = Scene::as_given(grid, state.clone(), state.len()).upload(&ctx);
    let shot = nimbus::shot::Shot::prepare(cfg.clone()).unwrap();
    let maps = nimbus::sim::sources::HeatMaps::new(&[]);
    let stage = S::from_setup(&nimbus::sim::stage::Setup {
        ctx: &ctx,
        shot: &shot,
        buffers: &b,
        grid: &grid,
        maps: &maps,
    })
    .unwrap();
    (ctx, b, stage)
}
