//! Compute kernels with an explicit bind-group layout shared by every entry point of a shader file
//! (so one bind group serves them all), and 2-D dispatch for arrays beyond 65535 workgroups.
use crate::error::Result;

/// Kind of a binding: a uniform buffer, a read-write or a read-only storage buffer (WGSL
/// `var<storage, read>`: must match the shader's declaration exactly).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bind {
    Uniform,
    Storage,
    StorageRead,
}

/// The compute pipelines of one shader file, all with the same layout.
pub struct Kernel {
    pub layout: wgpu::BindGroupLayout,
    pipelines: Vec<(String, wgpu::ComputePipeline)>,
}

impl Kernel {
    pub fn new(
        device: &wgpu::Device,
        shader: &str,
        binds: &[Bind],
        entries: &[&str],
    ) -> Result<Self> {
        let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = binds
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupLayoutEntry {
                binding: i as u32,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: match b {
                        Bind::Uniform => wgpu::BufferBindingType::Uniform,
                        Bind::Storage => wgpu::BufferBindingType::Storage { read_only: false },
                        Bind::StorageRead => wgpu::BufferBindingType::Storage { read_only: true },
                    },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(shader),
            entries: &layout_entries,
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(shader),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = crate::gpu::shaders::module(device, shader)?;
        let pipelines = entries
            .iter()
            .map(|e| {
                let p = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(&format!("{shader}:{e}")),
                    layout: Some(&pl),
                    module: &module,
                    entry_point: Some(e),
                    compilation_options: Default::default(),
                    cache: None,
                });
                (e.to_string(), p)
            })
            .collect();
        Ok(Self { layout, pipelines })
    }

    pub fn pipeline(&self, entry: &str) -> &wgpu::ComputePipeline {
        &self
            .pipelines
            .iter()
            .find(|(n, _)| n == entry)
            .unwrap_or_else(|| panic!("kernel entry {entry} was not built"))
            .1
    }

    /// A bind group over whole buffers, or ranges where given.
    pub fn bind(&self, device: &wgpu::Device, res: &[wgpu::BindingResource]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = res
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: r.clone(),
            })
            .collect();
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.layout,
            entries: &entries,
        })
    }

    /// Dispatches `entry` over `threads` invocations in workgroups of `wg` (2-D when large; the
    /// shaders rebuild the linear index from `num_workgroups`).
    pub fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass,
        entry: &str,
        bg: &wgpu::BindGroup,
        threads: u32,
        wg: u32,
    ) {
        let groups = threads.div_ceil(wg);
        if groups == 0 {
            return;
        }
        let (x, y) = grid_2d(groups);
        pass.set_pipeline(self.pipeline(entry));
        pass.set_bind_group(0, bg, &[]);
        pass.dispatch_workgroups(x, y, 1);
    }
}

/// Splits a workgroup count into x * y <= 65535 per dimension (x * y >= groups).
pub fn grid_2d(groups: u32) -> (u32, u32) {
    let x = groups.min(65535);
    (x, groups.div_ceil(x))
}

/// A binding over `size` bytes of `buffer` from `offset`.
pub fn range(buffer: &wgpu::Buffer, offset: u64, size: u64) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset,
        size: std::num::NonZeroU64::new(size),
    })
}
