//! The particle set on the device: the SoA arrays every stage binds, the cell tables, the static
//! wall particles, the grid uniform and the live count (docs/ARCHITECTURE.md "Contracts").
//!
//! Every array is `capacity` long and the first `live.count` entries are live. Between
//! `predict` and `update_velocity` the velocity array is dead (PBF recomputes v from the
//! positions), so the neighbour grid's permutation gathers into it and then, with `pred.w` and
//! the upper bits of `pos.w`, it holds the substep's neighbour mask (from the first
//! compute_lambda to viscosity_confine, shaders/pbf.wgsl; with more than one level `pred.w`'s top
//! 3 bits hold the particle's level then); the grid build's sort arrays
//! and the PBF solve's vec4 scratch share `pairs`. The later stages take their
//! scratch from arrays dead while they run: smoothing the whole of `pairs` (and its vapor limiter
//! a quarter of `pred`), split and merge their flags and holes from `pred` and their ranks from
//! `pairs` (`quarter`). That keeps the particle set at 92 bytes per particle plus the cell
//! tables ([`crate::sim::Simulation::device_bytes`] adds every stage's buffers up).
use crate::error::{Error, Result};
use crate::gpu::buffers::{storage_init, storage_zeroed, ParamSlots, Span};
use crate::gpu::live::{Live, LiveBuffer};
use crate::gpu::Context;
use crate::ground::ParticleState;
use crate::sim::grid_params::GridParams;

pub struct ParticleBuffers {
    /// Particles the arrays hold at most (what split and merge may fill).
    pub capacity: u32,
    /// Elements allocated per array: the capacity rounded up to 64, so that a quarter of a
    /// 16-byte array starts on a 256-byte binding boundary (`quarter`).
    pub slots: u32,
    /// `vec4<f32>`: xyz position (w: 0; during the PBF solve the neighbour mask's anchor and bits)
    pub pos: wgpu::Buffer,
    /// `vec4<f32>`: xyz velocity (w: the height gained in the substep, for eq. 7)
    pub vel: wgpu::Buffer,
    /// `vec4<f32>`: (temperature K, vapor, cloud, shape energy)
    pub thermo: wgpu::Buffer,
    /// `vec2<u32>`: (id, level)
    pub info: wgpu::Buffer,
    /// `vec4<f32>`: the predicted position p* (w: during the PBF solve, part of the neighbour
    /// mask and, with more than one level, the level)
    pub pred: wgpu::Buffer,
    /// Four u32 arrays of `slots` for the grid build's sort, or one `vec4<f32>` array of scratch.
    pub pairs: wgpu::Buffer,
    /// `f32`: SPH density of the last solve
    pub density: wgpu::Buffer,
    /// `u32`: the cell table of the last grid build (`GridParams::table_len` entries)
    pub cell_start: wgpu::Buffer,
    /// Wall particles (`vec4`: xyz, w = temperature), sorted by cell, and their cell table.
    pub bpos: wgpu::Buffer,
    pub bcell_start: wgpu::Buffer,
    pub grid: ParamSlots<GridParams>,
    pub live: LiveBuffer,
}

impl ParticleBuffers {
    /// Uploads `state` into arrays of `capacity` (at least the state's length; the simulation
    /// rounds it up to a multiple of 64, which the sort's array offsets need).
    pub fn new(
        ctx: &Context,
        state: &ParticleState,
        capacity: u32,
        grid: &GridParams,
        boundary: &(Vec<[f32; 4]>, Vec<u32>),
        next_id: u32,
    ) -> Result<Self> {
        let n = state.len();
        if n > capacity as usize {
            return Err(Error::Runtime(format!(
                "{n} particles do not fit a capacity of {capacity}"
            )));
        }
        let dev = &ctx.device;
        let slots = capacity.next_multiple_of(64);
        let cap = slots as usize;
        let upload = |label: &str, bytes: &[u8], elem: usize| {
            let buf = storage_zeroed::<u8>(dev, label, cap * elem);
            ctx.queue.write_buffer(&buf, 0, bytes);
            buf
        };
        let single_level = state.info.iter().all(|i| i[1] == 0);
        Ok(Self {
            capacity,
            slots,
            pos: upload("pos", bytemuck::cast_slice(&state.pos), 16),
            vel: upload("vel", bytemuck::cast_slice(&state.vel), 16),
            thermo: upload("thermo", bytemuck::cast_slice(&state.thermo), 16),
            info: upload("info", bytemuck::cast_slice(&state.info), 8),
            pred: storage_zeroed::<[f32; 4]>(dev, "pred", cap),
            pairs: storage_zeroed::<[u32; 4]>(dev, "sort pairs / scratch", cap),
            density: upload("density", bytemuck::cast_slice(&state.density), 4),
            cell_start: storage_zeroed::<u32>(dev, "cell_start", grid.table_len()),
            bpos: storage_init(dev, "boundary pos", &boundary.0),
            bcell_start: storage_init(dev, "boundary cell_start", &boundary.1),
            grid: ParamSlots::single(ctx, "grid", grid),
            live: LiveBuffer::new(ctx, &Live::new(ctx, n as u32, next_id, single_level)),
        })
    }

    /// Quarter `k` (0..4) of a 16-byte-per-particle array as a u32 array of `slots`: scratch for
    /// a stage that runs while that array is dead (`pred` after the PBF substep, `pairs`
    /// outside the grid build and the density solve).
    pub fn quarter(&self, buffer: &wgpu::Buffer, k: u64) -> Span {
        let len = self.slots as u64 * 4;
        Span::new(buffer, k * len, len)
    }

    /// Bytes of the particle set's buffers (the stages' own scratch not included).
    pub fn device_bytes(&self) -> u64 {
        [
            &self.pos,
            &self.vel,
            &self.thermo,
            &self.info,
            &self.pred,
            &self.pairs,
            &self.density,
            &self.cell_start,
            &self.bpos,
            &self.bcell_start,
        ]
        .iter()
        .map(|b| b.size())
        .sum::<u64>()
            + self.grid.size()
            + self.live.size()
    }
}

/// The particle set's buffers under the names every stage's WGSL binds them by.
impl crate::gpu::program::Resources for ParticleBuffers {
    fn resource(&self, name: &str) -> Option<wgpu::BindingResource<'_>> {
        let buffer = match name {
            "grid" => return Some(self.grid.slot(0)),
            "live" => return Some(self.live.binding()),
            "pos" => &self.pos,
            "vel" => &self.vel,
            "thermo" => &self.thermo,
            "info" => &self.info,
            "pred" => &self.pred,
            "density" => &self.density,
            "cell_start" => &self.cell_start,
            "bpos" => &self.bpos,
            "bcell_start" => &self.bcell_start,
            _ => return None,
        };
        Some(buffer.as_entire_binding())
    }
}
