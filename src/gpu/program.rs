//! The one way to declare and run a compute program: one WGSL file and the entry points the Rust
//! side dispatches. (A *stage* is a part of the substep, `sim::stage`; it runs one or more
//! programs.)
//!
//! A program is one WGSL file (`shaders/<name>.wgsl`) and the entry points the Rust side uses,
//! an enum per file declared with [`entry_points!`]: the one place an entry's WGSL name is
//! written, so a dispatch names a variant (`PbfEntry::Predict`), never a string. Its
//! bindings are not written down twice: naga reflects them from the WGSL when the program is built
//! (name, group, uniform / read-only storage / read-write storage), the bind-group layouts come
//! from that, and bind groups are made by binding *name* from [`Resources`] (the particle
//! buffers, a program's own buffers), so a binding no source provides fails when the bind group is
//! made (in every test that builds the program), never at dispatch. Workgroup sizes are reflected too (the WGSL writes them with the prelude's
//! constants, `gpu::shaders::Prelude`), so a dispatch is sized in threads.
//!
//! Conventions:
//! - group 0 holds the program's buffers; one bind group per buffer set, made once;
//! - groups 1.. hold per-dispatch parameters: one uniform each, bound with a dynamic offset into
//!   a [`crate::gpu::buffers::ParamSlots`] buffer (a merge colour, a scan level);
//! - every entry point of a file shares the file's layouts, so one bind group serves them all.
//!
//! Declaring a program: `entry_points! { pub enum ThermoEntry in "thermo.wgsl" { Step =
//! "thermo_step" } }` and `Program::<ThermoEntry>::new(ctx)?`; binding:
//! `program.bind(ctx, &[&[("P", params.slot(0))], &particle_buffers])?`; dispatching:
//! `program.dispatch(pass, ThermoEntry::Step, &[(&group, 0)], Dispatch::Live(&live))`.
use crate::error::{Error, Result};
use crate::gpu::Context;

/// The entry points of one program's WGSL file that the Rust side dispatches (an enum made by
/// [`entry_points!`]).
pub trait Entry: Copy + PartialEq + std::fmt::Debug + 'static {
    /// The WGSL file, `shaders/<SHADER>`.
    const SHADER: &'static str;
    /// Every entry point the program builds a pipeline for.
    const ALL: &'static [Self];
    /// The entry point's name in the WGSL.
    fn name(self) -> &'static str;
}

/// Declares the entry points of WGSL files, an enum per file implementing [`Entry`]: each
/// variant with the name the WGSL gives it, written here once.
macro_rules! entry_points {
    ($($(#[$meta:meta])* $vis:vis enum $name:ident in $shader:literal {
        $($(#[$vmeta:meta])* $variant:ident = $wgsl:literal),+ $(,)?
    })+) => {
        $(
            $(#[$meta])*
            #[derive(Debug, Clone, Copy, PartialEq, Eq)]
            $vis enum $name {
                $($(#[$vmeta])* $variant),+
            }

            impl $crate::gpu::program::Entry for $name {
                const SHADER: &'static str = $shader;
                const ALL: &'static [Self] = &[$(Self::$variant),+];
                fn name(self) -> &'static str {
                    match self {
                        $(Self::$variant => $wgsl),+
                    }
                }
            }
        )+
    };
}
pub(crate) use entry_points;

/// Buffers a bind group can be made from, by the WGSL variable name they bind to.
pub trait Resources {
    fn resource(&self, name: &str) -> Option<wgpu::BindingResource<'_>>;
}

/// A program's own buffers, by name.
impl Resources for [(&str, wgpu::BindingResource<'_>)] {
    fn resource(&self, name: &str) -> Option<wgpu::BindingResource<'_>> {
        self.iter()
            .find(|(n, _)| *n == name)
            .map(|(_, r)| r.clone())
    }
}

impl<const N: usize> Resources for [(&str, wgpu::BindingResource<'_>); N] {
    fn resource(&self, name: &str) -> Option<wgpu::BindingResource<'_>> {
        self.as_slice().resource(name)
    }
}

/// What a binding holds, as the WGSL declares it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BindingKind {
    Uniform,
    /// `var<storage, read>`
    StorageRead,
    /// `var<storage, read_write>`
    Storage,
}

/// One reflected binding of a program.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Binding {
    pub name: String,
    pub group: u32,
    pub binding: u32,
    pub kind: BindingKind,
}

/// How many workgroups a dispatch runs.
#[derive(Clone, Copy)]
pub enum Dispatch<'a> {
    /// One thread per item, `n` items (0 dispatches nothing).
    Threads(u32),
    /// Exactly these workgroups.
    Groups(u32),
    /// Indirect: `(x, y, z)` u32 arguments the GPU wrote at this offset of the buffer.
    Indirect(&'a wgpu::Buffer, u64),
    /// One thread per live particle: the indirect arguments the GPU keeps next to the count
    /// (`gpu::live`), for this entry point's workgroup size.
    Live(&'a crate::gpu::live::LiveBuffer),
}

/// One entry point's pipeline.
struct Pipeline {
    workgroup: [u32; 3],
    pipeline: wgpu::ComputePipeline,
}

/// A compute program: pipelines of its entry points (`E::ALL`, in that order) and the layouts
/// reflected from its WGSL.
pub struct Program<E: Entry> {
    bindings: Vec<Binding>,
    layouts: Vec<wgpu::BindGroupLayout>,
    pipelines: Vec<Pipeline>,
    max_groups_x: u32,
    entry: std::marker::PhantomData<E>,
}

/// The bindings of a program and the workgroup size of each entry point, read from its WGSL.
pub fn reflect(
    shader: &str,
    module: &naga::Module,
    entries: &[&str],
) -> Result<(Vec<Binding>, Vec<[u32; 3]>)> {
    let mut bindings = Vec::new();
    for (_, var) in module.global_variables.iter() {
        let Some(rb) = &var.binding else { continue };
        let kind = match var.space {
            naga::AddressSpace::Uniform => BindingKind::Uniform,
            naga::AddressSpace::Storage { access } => {
                if access.contains(naga::StorageAccess::STORE) {
                    BindingKind::Storage
                } else {
                    BindingKind::StorageRead
                }
            }
            other => {
                return Err(Error::Runtime(format!(
                    "{shader}: binding @group({}) @binding({}) is in address space {other:?}; \
                     programs bind buffers only",
                    rb.group, rb.binding
                )))
            }
        };
        if rb.group > 0 && kind != BindingKind::Uniform {
            return Err(Error::Runtime(format!(
                "{shader}: group {} holds per-dispatch parameters (a uniform with a dynamic \
                 offset), not storage",
                rb.group
            )));
        }
        bindings.push(Binding {
            name: var.name.clone().unwrap_or_default(),
            group: rb.group,
            binding: rb.binding,
            kind,
        });
    }
    bindings.sort_by_key(|b| (b.group, b.binding));
    let groups = bindings.last().map_or(0, |b| b.group + 1);
    for g in 0..groups {
        if !bindings.iter().any(|b| b.group == g) {
            return Err(Error::Runtime(format!("{shader}: bind group {g} is empty")));
        }
    }
    let sizes = entries
        .iter()
        .map(|name| {
            module
                .entry_points
                .iter()
                .find(|e| e.name == *name && e.stage == naga::ShaderStage::Compute)
                .map(|e| e.workgroup_size)
                .ok_or_else(|| Error::Runtime(format!("{shader}: no compute entry point '{name}'")))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((bindings, sizes))
}

impl<E: Entry> Program<E> {
    /// Builds the pipelines of every entry point of `E` with layouts reflected from its WGSL.
    pub fn new(ctx: &Context) -> Result<Self> {
        Self::with_constants(ctx, &[])
    }

    /// [`Self::new`] with values for the shader's pipeline-overridable constants (WGSL
    /// `override`), by name: a value fixed for the program's life that the compiler can fold.
    pub fn with_constants(ctx: &Context, constants: &[(&str, f64)]) -> Result<Self> {
        let shader = E::SHADER;
        let entries: Vec<&'static str> = E::ALL.iter().map(|e| e.name()).collect();
        let entries = entries.as_slice();
        let prelude = ctx.prelude;
        let module = crate::gpu::shaders::validate_with(shader, &prelude)?;
        let (bindings, sizes) = reflect(shader, &module, entries)?;
        let device = &ctx.device;
        let groups = bindings.last().map_or(0, |b| b.group + 1);
        let layouts: Vec<wgpu::BindGroupLayout> = (0..groups)
            .map(|g| {
                let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
                    .iter()
                    .filter(|b| b.group == g)
                    .map(|b| wgpu::BindGroupLayoutEntry {
                        binding: b.binding,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: match b.kind {
                                BindingKind::Uniform => wgpu::BufferBindingType::Uniform,
                                BindingKind::StorageRead => {
                                    wgpu::BufferBindingType::Storage { read_only: true }
                                }
                                BindingKind::Storage => {
                                    wgpu::BufferBindingType::Storage { read_only: false }
                                }
                            },
                            has_dynamic_offset: g > 0,
                            min_binding_size: None,
                        },
                        count: None,
                    })
                    .collect();
                device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some(shader),
                    entries: &layout_entries,
                })
            })
            .collect();
        let layout_refs: Vec<Option<&wgpu::BindGroupLayout>> = layouts.iter().map(Some).collect();
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(shader),
            bind_group_layouts: &layout_refs,
            immediate_size: 0,
        });
        let shader_module = crate::gpu::shaders::module(ctx, shader)?;
        let pipelines = entries
            .iter()
            .zip(sizes)
            .map(|(name, workgroup)| Pipeline {
                workgroup,
                pipeline: device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(&format!("{shader}:{name}")),
                    layout: Some(&pipeline_layout),
                    module: &shader_module,
                    entry_point: Some(name),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants,
                        ..Default::default()
                    },
                    cache: None,
                }),
            })
            .collect();
        Ok(Self {
            bindings,
            layouts,
            pipelines,
            max_groups_x: prelude.max_groups_x,
            entry: std::marker::PhantomData,
        })
    }

    /// The reflected bindings (group, binding, name, kind), in order.
    pub fn bindings(&self) -> &[Binding] {
        &self.bindings
    }

    /// A group-0 bind group: every binding the WGSL declares in group 0, looked up by name in
    /// `sources`, first source first (so a program's own buffers can stand in for a particle
    /// array of the same name).
    pub fn bind(&self, ctx: &Context, sources: &[&dyn Resources]) -> Result<wgpu::BindGroup> {
        self.bind_group(ctx, 0, sources)
    }

    /// A bind group of `group` (group 0: the buffers; 1..: a per-dispatch uniform, bound with
    /// its slot size so dynamic offsets select the slot).
    pub fn bind_group(
        &self,
        ctx: &Context,
        group: u32,
        sources: &[&dyn Resources],
    ) -> Result<wgpu::BindGroup> {
        let layout = self
            .layouts
            .get(group as usize)
            .ok_or_else(|| Error::Runtime(format!("{}: no bind group {group}", E::SHADER)))?;
        let entries = self
            .bindings
            .iter()
            .filter(|b| b.group == group)
            .map(|b| {
                let resource = sources
                    .iter()
                    .find_map(|s| s.resource(&b.name))
                    .ok_or_else(|| {
                        Error::Runtime(format!(
                            "{}: no buffer for binding '{}' (group {group})",
                            E::SHADER,
                            b.name
                        ))
                    })?;
                Ok(wgpu::BindGroupEntry {
                    binding: b.binding,
                    resource,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(E::SHADER),
            layout,
            entries: &entries,
        }))
    }

    fn pipeline(&self, entry: E) -> &Pipeline {
        // every variant has a pipeline (built in `E::ALL`'s order in `new`)
        let k = E::ALL
            .iter()
            .position(|e| *e == entry)
            .expect("E::ALL lists every variant");
        &self.pipelines[k]
    }

    /// Threads per workgroup of an entry point (x; the programs use 1-D workgroups).
    pub fn workgroup_size(&self, entry: E) -> u32 {
        self.pipeline(entry).workgroup[0]
    }

    /// Records `entry` with `groups` (group 0 first; groups 1.. with their dynamic offset).
    pub fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass,
        entry: E,
        groups: &[(&wgpu::BindGroup, u32)],
        size: Dispatch,
    ) {
        let e = self.pipeline(entry);
        assert_eq!(
            groups.len(),
            self.layouts.len(),
            "{}:{} takes {} bind groups",
            E::SHADER,
            entry.name(),
            self.layouts.len()
        );
        let set = |pass: &mut wgpu::ComputePass| {
            pass.set_pipeline(&e.pipeline);
            for (i, (g, offset)) in groups.iter().enumerate() {
                let offsets: &[u32] = if i == 0 {
                    &[]
                } else {
                    std::slice::from_ref(offset)
                };
                pass.set_bind_group(i as u32, Some(*g), offsets);
            }
        };
        match size {
            Dispatch::Threads(n) => {
                let [x, y, z] = groups_for(n, e.workgroup[0], self.max_groups_x);
                if x > 0 {
                    set(pass);
                    pass.dispatch_workgroups(x, y, z);
                }
            }
            Dispatch::Groups(n) => {
                let [x, y, z] = groups_for(n, 1, self.max_groups_x);
                if x > 0 {
                    set(pass);
                    pass.dispatch_workgroups(x, y, z);
                }
            }
            Dispatch::Indirect(buffer, offset) => {
                set(pass);
                pass.dispatch_workgroups_indirect(buffer, offset);
            }
            Dispatch::Live(live) => {
                set(pass);
                pass.dispatch_workgroups_indirect(live.buffer(), live.args_offset(e.workgroup[0]));
            }
        }
    }
}

/// Workgroups for `threads` threads in groups of `wg`: up to `max_x` along x, then rows along y
/// (the shaders rebuild the linear index from `num_workgroups`). The GPU computes its indirect
/// arguments with the same rule (`groups_for` in shaders/shared/live.wgsl).
pub fn groups_for(threads: u32, wg: u32, max_x: u32) -> [u32; 3] {
    let groups = threads.div_ceil(wg);
    if groups == 0 {
        return [0, 1, 1];
    }
    let x = groups.min(max_x);
    [x, groups.div_ceil(x), 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_cover_every_thread_within_the_limit() {
        for wg in [1u32, 64, 256] {
            for n in [0u32, 1, 63, 64, 65, 65535 * 64, 65535 * 64 + 1, 10_000_000] {
                let [x, y, z] = groups_for(n, wg, 65535);
                assert!(x <= 65535 && y <= 65535 && z == 1, "{n}");
                assert!(x as u64 * y as u64 * wg as u64 >= n as u64, "{n}");
                if n > 0 {
                    // no whole row of groups is wasted
                    assert!((x as u64 * (y as u64 - 1)) * (wg as u64) < n as u64, "{n}");
                }
            }
        }
    }

    /// Every program file reflects: buffers only, groups 1.. uniforms, no empty group.
    #[test]
    fn every_program_reflects() {
        let prelude = crate::gpu::shaders::Prelude::default();
        for name in crate::gpu::shaders::program_names() {
            let module = crate::gpu::shaders::validate_with(name, &prelude).unwrap();
            let (bindings, _) = reflect(name, &module, &[]).unwrap_or_else(|e| panic!("{e}"));
            assert!(!bindings.is_empty(), "{name} binds nothing");
            for b in &bindings {
                assert!(!b.name.is_empty(), "{name}: an unnamed binding");
            }
        }
    }

    #[test]
    fn reflection_reads_kinds_groups_and_workgroup_sizes() {
        let src = "@group(0) @binding(0) var<uniform> u: vec4<f32>;\n\
                   @group(0) @binding(2) var<storage, read> r: array<u32>;\n\
                   @group(0) @binding(1) var<storage, read_write> w: array<u32>;\n\
                   @group(1) @binding(0) var<uniform> d: vec4<u32>;\n\
                   @compute @workgroup_size(32) fn a() { w[0] = r[0] + u32(u.x) + d.x; }\n";
        let module = naga::front::wgsl::parse_str(src).unwrap();
        let (b, sizes) = reflect("t.wgsl", &module, &["a"]).unwrap();
        let got: Vec<(&str, u32, u32, BindingKind)> = b
            .iter()
            .map(|b| (b.name.as_str(), b.group, b.binding, b.kind))
            .collect();
        assert_eq!(
            got,
            vec![
                ("u", 0, 0, BindingKind::Uniform),
                ("w", 0, 1, BindingKind::Storage),
                ("r", 0, 2, BindingKind::StorageRead),
                ("d", 1, 0, BindingKind::Uniform),
            ]
        );
        assert_eq!(sizes, vec![[32, 1, 1]]);
        assert!(reflect("t.wgsl", &module, &["missing"]).is_err());
        let storage_in_group_1 = "@group(1) @binding(0) var<storage, read> s: array<u32>;\n\
                   @compute @workgroup_size(1) fn a() { _ = s[0]; }\n";
        let module = naga::front::wgsl::parse_str(storage_in_group_1).unwrap();
        assert!(reflect("t.wgsl", &module, &["a"]).is_err());
    }
}
