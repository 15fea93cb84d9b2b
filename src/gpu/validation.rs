//! Validation of every GPU call, for tests and CI: with `NIMBUS_GPU_VALIDATION=1` the device is
//! opened with the Khronos validation layer (Vulkan; Debian `vulkan-validationlayers`) or the
//! driver's debug output (OpenGL), and the first error either reports ends the process with the
//! message, so a violation fails the test or the run that made it.
//!
//! wgpu hands the layer's and the GL debug output's messages to the `log` crate (wgpu-hal's
//! debug callbacks: target `wgpu_hal::...`, level Error for errors). [`Logger`] forwards every
//! record to the logger beneath it (the CLI's env_logger) and, once [`arm`]ed, aborts on such an
//! error: abort, not panic, because the callbacks catch panics, and the driver call that
//! reports a violation may be on any thread. Without the variable validation stays off, also in
//! debug builds, so the tests' speed does not depend on whether the layer is installed.
use std::sync::atomic::{AtomicBool, Ordering};

/// The environment variable that turns validation on (any value but empty or `0`).
pub const ENV: &str = "NIMBUS_GPU_VALIDATION";

/// The Khronos validation layer's name.
pub const VULKAN_LAYER: &str = "VK_LAYER_KHRONOS_validation";

static ARMED: AtomicBool = AtomicBool::new(false);

/// Whether the environment asks for validation.
pub fn requested() -> bool {
    std::env::var(ENV).is_ok_and(|v| !v.is_empty() && v != "0")
}

/// A `log` logger that forwards to `inner` and, once armed, ends the process on a GPU
/// validation error.
pub struct Logger {
    inner: Option<Box<dyn log::Log>>,
}

impl Logger {
    /// Installs the logger over `inner` (the CLI's), with `inner`'s level filter.
    pub fn install(inner: Box<dyn log::Log>, filter: log::LevelFilter) {
        if log::set_boxed_logger(Box::new(Self { inner: Some(inner) })).is_ok() {
            log::set_max_level(filter);
        }
    }
}

/// A record that may be a validation error: an error of wgpu-hal.
fn is_gpu_error(meta: &log::Metadata) -> bool {
    meta.level() == log::Level::Error && meta.target().starts_with("wgpu_hal")
}

/// An error the validation layer (wgpu-hal's Vulkan debug messenger) or the GL debug output
/// (messages `GLES: [...]`) reported. EGL's own errors are not: probing the platforms at
/// instance creation logs some (a missing DRI driver) whatever nimbus does.
fn is_validation_error(record: &log::Record) -> bool {
    let target = record.target();
    if !is_gpu_error(record.metadata()) {
        return false;
    }
    let message = record.args().to_string();
    if target.starts_with("wgpu_hal::vulkan") {
        // wgpu logs a message's queue, command buffer and object labels as lines of their own
        // after it, starting with a tab: the message itself decides
        !message.starts_with('\t') && !is_known_false_positive(&message)
    } else {
        target.starts_with("wgpu_hal::gles") && message.starts_with("GLES:")
    }
}

/// Layer messages that are the layer's mistake, not ours: Debian 12's layer (1.3.239) predates
/// WGSL as a SPIR-V source language (`OpSource` 10, which naga writes with the debug info that
/// the layer's messenger needs, `InstanceFlags::DEBUG`), and its SPIR-V check stops there. The
/// SPIR-V itself is checked by spirv-val in tests/gpu_spirv.rs, without debug info.
fn is_known_false_positive(message: &str) -> bool {
    message.contains("UNASSIGNED-CoreValidation-Shader-InconsistentSpirv")
        && message.contains("Invalid source language operand: 10")
}

impl log::Log for Logger {
    fn enabled(&self, meta: &log::Metadata) -> bool {
        (ARMED.load(Ordering::Relaxed) && is_gpu_error(meta))
            || self.inner.as_ref().is_some_and(|l| l.enabled(meta))
    }

    fn log(&self, record: &log::Record) {
        if let Some(inner) = &self.inner {
            if inner.enabled(record.metadata()) {
                inner.log(record);
            }
        }
        if ARMED.load(Ordering::Relaxed) && is_validation_error(record) {
            fail(&format!("{} ({})", record.args(), record.target()));
        }
    }

    fn flush(&self) {
        if let Some(inner) = &self.inner {
            inner.flush();
        }
    }
}

/// Ends the process with a validation failure: the message, the thread (a test's name under
/// `cargo test`), then abort.
pub fn fail(message: &str) -> ! {
    use std::io::Write;
    let thread = std::thread::current();
    let mut err = std::io::stderr().lock();
    let _ = writeln!(
        err,
        "error: GPU validation error ({ENV}) on thread '{}': {message}",
        thread.name().unwrap_or("unnamed")
    );
    let _ = err.flush();
    std::process::abort()
}

/// Turns the failure on: called when a device is opened with validation. Installs [`Logger`]
/// where no logger is (the tests), and lets error records through the level filter, which
/// must happen before the instance is made (wgpu asks the layer only for the severities the
/// filter lets through).
pub fn arm() {
    ARMED.store(true, Ordering::Relaxed);
    let _ = log::set_boxed_logger(Box::new(Logger { inner: None }));
    if log::max_level() < log::LevelFilter::Error {
        log::set_max_level(log::LevelFilter::Error);
    }
}

/// Whether the Vulkan loader of `adapter`'s instance finds the Khronos validation layer
/// (`None`: not a Vulkan adapter).
pub fn vulkan_layer_present(adapter: &wgpu::Adapter) -> Option<bool> {
    // SAFETY: a read-only query of the loader through the adapter's live instance.
    unsafe {
        let hal = adapter.as_hal::<wgpu::hal::api::Vulkan>()?;
        let layers = hal
            .shared_instance()
            .entry()
            .enumerate_instance_layer_properties()
            .ok()?;
        Some(layers.iter().any(|l| {
            l.layer_name_as_c_str()
                .is_ok_and(|n| n.to_bytes() == VULKAN_LAYER.as_bytes())
        }))
    }
}
