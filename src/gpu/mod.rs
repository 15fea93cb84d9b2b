//! wgpu context (headless adapter choice, features, limits, the one host wait), the compute
//! [`program::Program`] every compute program is declared with, buffer helpers, shader loading, and the
//! generic passes (prefix scan, timestamps).
pub mod buffers;
pub mod choice;
pub mod limits;
pub mod live;
pub mod program;
pub mod scan;
pub mod shaders;
pub mod timing;
pub mod validation;

use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};
use choice::{Backend, GpuConfig};

/// What a machine without a usable adapter should do about it.
pub const NO_ADAPTER_REMEDY: &str = "install the Vulkan driver of your GPU (NVIDIA/AMD/Intel); \
on a machine without a GPU, `apt-get install mesa-vulkan-drivers libvulkan1` gives a CPU Vulkan \
device (lavapipe), or try `gpu.backend: gl`";

/// An open device and queue with what the adapter can do.
pub struct Context {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter_info: wgpu::AdapterInfo,
    /// Timestamp queries are available: per-phase GPU timings come from them.
    pub timestamps: bool,
    /// The constants every program's WGSL is compiled with (workgroup sizes, dispatch limit).
    pub prelude: shaders::Prelude,
    /// What bounds a shot's size on this device (`NIMBUS_GPU_LIMITS` applied).
    pub limits: limits::DeviceLimits,
    /// Opened with validation (`NIMBUS_GPU_VALIDATION`): a validation error ends the process.
    pub validation: bool,
    /// Times the host has waited for the GPU ([`Context::wait`]); stats.jsonl records the
    /// waits per frame.
    waits: AtomicU64,
}

impl Context {
    /// Opens the adapter the config asks for: `auto` prefers a discrete GPU, then any other;
    /// a name substring picks the first adapter whose name contains it (case-insensitive).
    pub fn new(cfg: &GpuConfig) -> Result<Self> {
        let caps = limits::Caps::from_env()?;
        let validation = validation::requested();
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        // Validation only when asked for (debug builds would otherwise load the layer wherever
        // it is installed, and the tests' speed would depend on it); WGPU_VALIDATION still works
        // for logging alone.
        if validation {
            validation::arm();
            // DEBUG too: wgpu registers its debug messenger (through which the layer's
            // messages reach `log`) only with it
            desc.flags
                .insert(wgpu::InstanceFlags::VALIDATION | wgpu::InstanceFlags::DEBUG);
        } else if std::env::var_os("WGPU_VALIDATION").is_none() {
            desc.flags.remove(wgpu::InstanceFlags::VALIDATION);
        }
        let backends = match cfg.backend {
            Backend::Auto => {
                wgpu::Backends::from_env().unwrap_or(wgpu::Backends::VULKAN | wgpu::Backends::GL)
            }
            Backend::Vulkan => wgpu::Backends::VULKAN,
            Backend::Gl => wgpu::Backends::GL,
        };
        desc.backends = backends;
        let instance = wgpu::Instance::new(desc);
        // Vulkan first: probing GL on a headless machine logs driver errors for nothing.
        let mut adapters = Vec::new();
        for b in [wgpu::Backends::VULKAN, wgpu::Backends::GL] {
            if backends.contains(b) && adapters.is_empty() {
                adapters = pollster::block_on(instance.enumerate_adapters(b));
            }
        }
        let adapter = pick_adapter(adapters, &cfg.adapter)?;
        let info = adapter.get_info();
        log::info!(
            "GPU adapter: {} ({:?}, {:?})",
            info.name,
            info.device_type,
            info.backend
        );
        // GL is only tried when Vulkan, asked for as well, found nothing: a node without a
        // Vulkan driver then runs, but slower, and its operator should know why.
        if info.backend == wgpu::Backend::Gl && backends.contains(wgpu::Backends::VULKAN) {
            log::warn!("{}", gl_fallback_warning(&info.name));
        }
        // A validation run without the layer would validate nothing and pass.
        if validation && validation::vulkan_layer_present(&adapter) == Some(false) {
            return Err(Error::NoGpu(format!(
                "{}=1 but the Vulkan loader finds no {} (Debian: apt-get install \
                 vulkan-validationlayers, as tools/setup.sh does)",
                validation::ENV,
                validation::VULKAN_LAYER
            )));
        }
        let wanted = wgpu::Features::TIMESTAMP_QUERY;
        let features = adapter.features() & wanted;
        let limits = adapter.limits();
        let mut required_limits = wgpu::Limits::downlevel_defaults();
        // Particle arrays are large storage buffers; ask for what the adapter has.
        required_limits.max_storage_buffer_binding_size = limits.max_storage_buffer_binding_size;
        required_limits.max_buffer_size = limits.max_buffer_size;
        required_limits.max_storage_buffers_per_shader_stage =
            limits.max_storage_buffers_per_shader_stage.min(16);
        required_limits.max_compute_workgroups_per_dimension =
            limits.max_compute_workgroups_per_dimension;
        required_limits.max_compute_invocations_per_workgroup =
            limits.max_compute_invocations_per_workgroup.min(256);
        required_limits.max_compute_workgroup_size_x = limits.max_compute_workgroup_size_x.min(256);
        required_limits.max_compute_workgroup_storage_size =
            limits.max_compute_workgroup_storage_size.min(32768);
        let mut memory = limits::device_memory(&adapter);
        if !caps.is_empty() {
            log::warn!(
                "{}: the device's limits are lowered on purpose ({caps:?})",
                limits::CAP_ENV
            );
        }
        caps.apply(&mut required_limits, &mut memory);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("nimbus"),
            required_features: features,
            required_limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| Error::NoGpu(format!("adapter {} refused a device: {e}", info.name)))?;
        let prelude = shaders::Prelude::for_device(&device.limits(), info.device_type)?;
        Ok(Self {
            limits: limits::DeviceLimits::new(&device.limits(), memory),
            device,
            queue,
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
            adapter_info: info,
            prelude,
            validation,
            waits: AtomicU64::new(0),
        })
    }

    /// Blocks until the GPU has finished everything submitted: the one place the host waits.
    pub fn wait(&self) -> Result<()> {
        self.waits.fetch_add(1, Ordering::Relaxed);
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::Runtime(format!("GPU poll failed: {e}")))
    }

    /// Host waits so far (see [`Context::wait`]).
    pub fn waits(&self) -> u64 {
        self.waits.load(Ordering::Relaxed)
    }

    /// Everything recorded about the adapter and the device nimbus opened on it, for benches
    /// and the GPU machine's record: name, backend, type, vendor and device ids, driver,
    /// subgroup sizes, the limits that bound a shot, timestamps, validation, the prelude.
    pub fn describe(&self) -> serde_json::Value {
        let i = &self.adapter_info;
        let p = &self.prelude;
        serde_json::json!({
            "name": i.name,
            "backend": format!("{:?}", i.backend),
            "device_type": format!("{:?}", i.device_type),
            "vendor": format!("{:#06x}", i.vendor),
            "device": format!("{:#06x}", i.device),
            "driver": i.driver,
            "driver_info": i.driver_info,
            "subgroup_size": [i.subgroup_min_size, i.subgroup_max_size],
            "limits": self.limits,
            "timestamps": self.timestamps,
            "validation": self.validation,
            "prelude": {
                "wg_particles": p.wg_particles,
                "wg_block": p.wg_block,
                "wg_scan": p.wg_scan,
                "max_groups_x": p.max_groups_x,
                "loop_budget": p.loop_budget,
            },
        })
    }

    /// Adapter name as written into manifests and checkpoints.
    pub fn adapter_name(&self) -> String {
        format!(
            "{} ({:?})",
            self.adapter_info.name, self.adapter_info.backend
        )
    }
}

/// The warning for a run that fell back to OpenGL because no Vulkan adapter was found. On a
/// CPU, llvmpipe's OpenGL ran the 100k-particle PBF step 3.8x slower than Vulkan's lavapipe on
/// the same machine (docs/PERFORMANCE.md "PBF / Session 19").
fn gl_fallback_warning(adapter: &str) -> String {
    format!(
        "no Vulkan adapter found: running on {adapter} through OpenGL, which is slower (on a CPU \
         about 4x); install a Vulkan driver (Debian: mesa-vulkan-drivers, as tools/setup.sh \
         does), or set gpu.backend: gl to choose OpenGL"
    )
}

fn pick_adapter(adapters: Vec<wgpu::Adapter>, wanted: &str) -> Result<wgpu::Adapter> {
    let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
    let usable = |a: &wgpu::Adapter| {
        a.get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
    };
    let mut candidates: Vec<wgpu::Adapter> = adapters.into_iter().filter(usable).collect();
    if wanted != "auto" {
        let w = wanted.to_lowercase();
        candidates.retain(|a| a.get_info().name.to_lowercase().contains(&w));
        if candidates.is_empty() {
            return Err(Error::NoGpu(format!(
                "no GPU adapter matches gpu.adapter '{wanted}' (found: {}); {NO_ADAPTER_REMEDY}",
                if names.is_empty() {
                    "none".to_string()
                } else {
                    names.join(", ")
                }
            )));
        }
    }
    // Prefer real GPUs over CPU/virtual ones; ties keep enumeration order (deterministic).
    let rank = |a: &wgpu::Adapter| match a.get_info().device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    candidates.sort_by_key(rank);
    candidates.into_iter().next().ok_or_else(|| {
        Error::NoGpu(format!(
            "no GPU adapter with compute shaders found; {NO_ADAPTER_REMEDY}"
        ))
    })
}
