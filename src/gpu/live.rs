//! The particle set's GPU-resident scalars: how many particles are live, the next particle id,
//! whether every particle is on level 0, and the indirect dispatch arguments over the live count.
//!
//! Split and merge change the count on the GPU in the middle of a frame. Rather than reading it
//! back after every substep (a host round trip each time), the adaptive stage writes the new
//! values here, every particle kernel reads `live.count` (shaders/shared/live.wgsl), and every
//! dispatch over the particles is indirect with the arguments stored here. The host writes the
//! buffer only between frames (after its one read-back) and reads it with the frame's state.
use crate::gpu::program::groups_for;
use crate::gpu::Context;

/// Mirror of `Live` in shaders/shared/live.wgsl (byte layout must match).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Live {
    /// Live particles: the first `count` slots of every particle array.
    pub count: u32,
    /// The id the next new particle (split child) gets.
    pub next_id: u32,
    /// 1 while every particle is on level 0 (PBF's fast path); a split clears it at once.
    pub single_level: u32,
    /// Particles of the substep's density solve, before split and merge changed the count
    /// (the length of the `density` array the frame's density error is measured on).
    pub solved_count: u32,
    /// Indirect dispatch arguments (x, y, z, unused) over `count` for workgroups of
    /// `WG_PARTICLES` threads.
    pub groups_particles: [u32; 4],
    /// The same for workgroups of `WG_BLOCK` threads.
    pub groups_block: [u32; 4],
}

impl Live {
    /// The live state of `count` particles, dispatch arguments included.
    pub fn new(ctx: &Context, count: u32, next_id: u32, single_level: bool) -> Self {
        let p = ctx.prelude;
        let args = |wg| {
            let [x, y, z] = groups_for(count, wg, p.max_groups_x);
            [x, y, z, 0]
        };
        Self {
            count,
            next_id,
            single_level: single_level as u32,
            solved_count: count,
            groups_particles: args(p.wg_particles),
            groups_block: args(p.wg_block),
        }
    }
}

/// The device buffer holding [`Live`] (storage for the kernels, indirect for the dispatches).
pub struct LiveBuffer {
    buffer: wgpu::Buffer,
    wg_particles: u32,
    wg_block: u32,
}

impl LiveBuffer {
    pub fn new(ctx: &Context, live: &Live) -> Self {
        let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("live"),
            size: std::mem::size_of::<Live>() as u64,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::INDIRECT
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue.write_buffer(&buffer, 0, bytemuck::bytes_of(live));
        Self {
            buffer,
            wg_particles: ctx.prelude.wg_particles,
            wg_block: ctx.prelude.wg_block,
        }
    }

    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        self.buffer.as_entire_binding()
    }

    /// Overwrites the live state (between frames, when the host knows it).
    pub fn write(&self, ctx: &Context, live: &Live) {
        ctx.queue
            .write_buffer(&self.buffer, 0, bytemuck::bytes_of(live));
    }

    /// Byte offset of the indirect arguments for workgroups of `wg` threads.
    pub fn args_offset(&self, wg: u32) -> u64 {
        if wg == self.wg_particles {
            std::mem::offset_of!(Live, groups_particles) as u64
        } else if wg == self.wg_block {
            std::mem::offset_of!(Live, groups_block) as u64
        } else {
            // Fixed in the WGSL with the prelude's constants; any other size is a programming
            // error every test of that stage hits.
            panic!("no live dispatch arguments for workgroups of {wg} threads")
        }
    }

    pub fn size(&self) -> u64 {
        self.buffer.size()
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn layout_matches_wgsl() {
        assert_eq!(std::mem::size_of::<super::Live>(), 48);
        assert_eq!(std::mem::offset_of!(super::Live, groups_particles), 16);
        assert_eq!(std::mem::offset_of!(super::Live, groups_block), 32);
    }
}
