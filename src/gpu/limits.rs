//! What an adapter holds, as far as a shot's size is concerned: the limits nimbus opens the
//! device with, the device memory where the backend reports it, and `NIMBUS_GPU_LIMITS`, which
//! lowers them to rehearse a smaller adapter (tests; a farm that wants to know whether a shot
//! fits its smallest GPU).
//!
//! The caps are real: the device is created with the lowered limits, so wgpu refuses a binding
//! or a dispatch over them exactly as a smaller adapter's driver would.
use crate::error::{Error, Result};

/// The environment variable that lowers the limits: `key=value` pairs separated by commas, a
/// value in bytes (suffixes `KiB`, `MiB`, `GiB`) or a count, e.g.
/// `NIMBUS_GPU_LIMITS=max_storage_buffer_binding_size=1MiB,max_compute_workgroups_per_dimension=16`.
pub const CAP_ENV: &str = "NIMBUS_GPU_LIMITS";

/// The keys `NIMBUS_GPU_LIMITS` takes.
pub const CAP_KEYS: [&str; 4] = [
    "max_buffer_size",
    "max_storage_buffer_binding_size",
    "max_compute_workgroups_per_dimension",
    "device_memory",
];

/// The limits that bound how many particles a shot may have on a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct DeviceLimits {
    /// Largest buffer (bytes): the frame's read-back staging buffer is the largest one.
    pub max_buffer_size: u64,
    /// Largest storage binding (bytes): a particle array is bound whole.
    pub max_storage_buffer_binding_size: u64,
    /// Most workgroups per dispatch dimension (dispatches fold into x * y, see
    /// `gpu::program::groups_for`).
    pub max_compute_workgroups_per_dimension: u32,
    /// Bytes of the largest device-local memory heap; `None` where the backend does not say
    /// (OpenGL).
    pub device_memory: Option<u64>,
}

impl DeviceLimits {
    /// The limits of a device opened with `limits`, on an adapter with `device_memory`.
    pub fn new(limits: &wgpu::Limits, device_memory: Option<u64>) -> Self {
        Self {
            max_buffer_size: limits.max_buffer_size,
            max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
            max_compute_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
            device_memory,
        }
    }
}

/// Caps on the limits, from [`CAP_ENV`]; each only ever lowers what the adapter offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Caps {
    pub max_buffer_size: Option<u64>,
    pub max_storage_buffer_binding_size: Option<u64>,
    pub max_compute_workgroups_per_dimension: Option<u32>,
    pub device_memory: Option<u64>,
}

impl Caps {
    /// The caps the environment sets (none when [`CAP_ENV`] is unset or empty).
    pub fn from_env() -> Result<Self> {
        match std::env::var(CAP_ENV) {
            Ok(s) => Self::parse(&s),
            Err(std::env::VarError::NotPresent) => Ok(Self::default()),
            Err(e) => Err(Error::InvalidInput(format!("{CAP_ENV}: {e}"))),
        }
    }

    /// Parses `key=value,key=value` (see [`CAP_ENV`]).
    pub fn parse(s: &str) -> Result<Self> {
        let mut caps = Self::default();
        for pair in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let bad = |why: &str| {
                Error::InvalidInput(format!(
                    "{CAP_ENV}: '{pair}': {why} (keys: {}; values in bytes, with an optional \
                     KiB, MiB or GiB suffix, or a count)",
                    CAP_KEYS.join(", ")
                ))
            };
            let (key, value) = pair.split_once('=').ok_or_else(|| bad("not key=value"))?;
            let value = parse_amount(value.trim()).ok_or_else(|| bad("not a positive number"))?;
            match key.trim() {
                "max_buffer_size" => caps.max_buffer_size = Some(value),
                "max_storage_buffer_binding_size" => {
                    caps.max_storage_buffer_binding_size = Some(value)
                }
                "max_compute_workgroups_per_dimension" => {
                    let n = u32::try_from(value).map_err(|_| bad("too large"))?;
                    caps.max_compute_workgroups_per_dimension = Some(n)
                }
                "device_memory" => caps.device_memory = Some(value),
                _ => return Err(bad("unknown key")),
            }
        }
        Ok(caps)
    }

    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// Lowers the limits a device is asked for (and the device memory) to the caps.
    pub fn apply(&self, limits: &mut wgpu::Limits, device_memory: &mut Option<u64>) {
        if let Some(v) = self.max_buffer_size {
            limits.max_buffer_size = limits.max_buffer_size.min(v);
        }
        if let Some(v) = self.max_storage_buffer_binding_size {
            limits.max_storage_buffer_binding_size = limits.max_storage_buffer_binding_size.min(v);
        }
        if let Some(v) = self.max_compute_workgroups_per_dimension {
            limits.max_compute_workgroups_per_dimension =
                limits.max_compute_workgroups_per_dimension.min(v);
        }
        if let Some(v) = self.device_memory {
            *device_memory = Some(device_memory.map_or(v, |m| m.min(v)));
        }
    }
}

/// `123`, `64KiB`, `128MiB`, `4GiB` (binary units), positive.
fn parse_amount(s: &str) -> Option<u64> {
    let (digits, unit) = match s.find(|c: char| !c.is_ascii_digit()) {
        Some(i) => s.split_at(i),
        None => (s, ""),
    };
    let scale: u64 = match unit.trim() {
        "" => 1,
        "KiB" => 1 << 10,
        "MiB" => 1 << 20,
        "GiB" => 1 << 30,
        _ => return None,
    };
    digits
        .parse::<u64>()
        .ok()
        .and_then(|v| v.checked_mul(scale))
        .filter(|&v| v > 0)
}

/// Bytes of the adapter's largest device-local memory heap, where the backend reports it
/// (Vulkan's memory heaps; OpenGL has no portable query).
pub fn device_memory(adapter: &wgpu::Adapter) -> Option<u64> {
    // SAFETY: the raw handles are only read (a property query), while `adapter` lives.
    unsafe {
        let hal = adapter.as_hal::<wgpu::hal::api::Vulkan>()?;
        let instance = hal.shared_instance().raw_instance();
        let props = instance.get_physical_device_memory_properties(hal.raw_physical_device());
        props.memory_heaps[..props.memory_heap_count as usize]
            .iter()
            .filter(|h| h.flags.contains(ash::vk::MemoryHeapFlags::DEVICE_LOCAL))
            .map(|h| h.size)
            .max()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caps_parse_units_and_refuse_nonsense() {
        let c = Caps::parse(
            "max_storage_buffer_binding_size=1MiB, max_compute_workgroups_per_dimension=16,\
             device_memory=2GiB,max_buffer_size=4096",
        )
        .unwrap();
        assert_eq!(c.max_storage_buffer_binding_size, Some(1 << 20));
        assert_eq!(c.max_compute_workgroups_per_dimension, Some(16));
        assert_eq!(c.device_memory, Some(2 << 30));
        assert_eq!(c.max_buffer_size, Some(4096));
        assert!(Caps::parse("").unwrap().is_empty());
        for bad in [
            "max_buffer_size",
            "max_buffer_size=0",
            "max_buffer_size=-1",
            "max_buffer_size=1TB",
            "max_texture_dimension_2d=16",
            "max_compute_workgroups_per_dimension=8GiB",
        ] {
            let e = Caps::parse(bad).unwrap_err().to_string();
            assert!(e.starts_with(CAP_ENV), "{bad}: {e}");
        }
    }

    #[test]
    fn caps_only_lower() {
        let mut l = wgpu::Limits {
            max_storage_buffer_binding_size: 128 << 20,
            max_compute_workgroups_per_dimension: 65535,
            ..wgpu::Limits::default()
        };
        let mut memory = Some(1 << 30);
        Caps::parse("max_storage_buffer_binding_size=4GiB,max_compute_workgroups_per_dimension=8,device_memory=64MiB")
            .unwrap()
            .apply(&mut l, &mut memory);
        assert_eq!(l.max_storage_buffer_binding_size, 128 << 20);
        assert_eq!(l.max_compute_workgroups_per_dimension, 8);
        assert_eq!(memory, Some(64 << 20));
        let mut none = None;
        Caps::parse("device_memory=1GiB")
            .unwrap()
            .apply(&mut l, &mut none);
        assert_eq!(none, Some(1 << 30));
    }
}
