//! The validation run's tripwire (`NIMBUS_GPU_VALIDATION=1`, which .ci/run sets for a second
//! pass of the GPU suites): a call that breaks the Vulkan spec, or makes an OpenGL error, ends
//! the process with the validation layer's or the driver's message. Without this test a
//! validation run whose layer was never loaded, or whose messages went nowhere, would pass.
//!
//! Each violation is made in a child process (this test binary, running the ignored test
//! `violate_through_the_driver`), since the failure it proves is the end of the process.
//! Without the Khronos layer the Vulkan case is skipped with a note; under CI=true (.ci/run
//! installs `vulkan-validationlayers`) it fails.
use nimbus::config::{Backend, GpuConfig};
use nimbus::gpu::validation;
use nimbus::gpu::Context;
use std::process::Command;

const VIOLATE_ENV: &str = "NIMBUS_TEST_VIOLATE";

/// Runs `violate_through_the_driver` in a child with validation on; its stderr and whether it
/// exited successfully.
fn violate(backend: &str) -> (bool, String) {
    let out = Command::new(std::env::current_exe().unwrap())
        .args(["violate_through_the_driver", "--exact", "--ignored"])
        .args(["--nocapture", "--test-threads=1"])
        .env(validation::ENV, "1")
        .env(VIOLATE_ENV, backend)
        .env(
            "XDG_RUNTIME_DIR",
            std::env::temp_dir().join("nimbus-test-xdg"),
        )
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_vulkan_validation_error_ends_the_process_with_its_message() {
    let (ok, err) = violate("vulkan");
    if err.contains(&format!("finds no {}", validation::VULKAN_LAYER)) {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but the Khronos validation layer is missing: tools/setup.sh installs \
             vulkan-validationlayers\n{err}"
        );
        eprintln!(
            "skipped: no Khronos validation layer here (apt-get install vulkan-validationlayers)"
        );
        return;
    }
    assert!(!ok, "the violation went unreported:\n{err}");
    assert!(err.contains("error: GPU validation error"), "{err}");
    // the layer's own words: a buffer of size 0
    assert!(err.contains("VUID-VkBufferCreateInfo-size-00912"), "{err}");
    assert!(err.contains("violate_through_the_driver"), "{err}");
}

#[test]
fn an_opengl_error_ends_the_process_with_its_message() {
    let (ok, err) = violate("gl");
    assert!(!ok, "the GL error went unreported:\n{err}");
    assert!(err.contains("error: GPU validation error"), "{err}");
    assert!(err.contains("GLES: [API/Error]"), "{err}");
    assert!(err.contains("violate_through_the_driver"), "{err}");
}

/// The child: opens the device with validation and breaks a rule through the raw API, which
/// wgpu's own checks never see. Does nothing unless the parent set NIMBUS_TEST_VIOLATE.
#[test]
#[ignore = "a child process of the two tests above"]
fn violate_through_the_driver() {
    let Ok(backend) = std::env::var(VIOLATE_ENV) else {
        return;
    };
    let cfg = GpuConfig {
        backend: if backend == "gl" {
            Backend::Gl
        } else {
            Backend::Vulkan
        },
        ..GpuConfig::default()
    };
    let ctx = Context::new(&cfg).unwrap_or_else(|e| panic!("{e}"));
    assert!(ctx.validation);
    // SAFETY: deliberately invalid calls on live handles, for the layer to catch; the process
    // ends in the layer's callback.
    unsafe {
        if backend == "gl" {
            use glow::HasContext;
            let hal = ctx.device.as_hal::<wgpu::hal::api::Gles>().unwrap();
            let gl = hal.context().lock();
            gl.bind_buffer(0xDEAD, None); // GL_INVALID_ENUM
            gl.finish();
        } else {
            let hal = ctx.device.as_hal::<wgpu::hal::api::Vulkan>().unwrap();
            let info = ash::vk::BufferCreateInfo::default()
                .size(0) // VUID-VkBufferCreateInfo-size-00912
                .usage(ash::vk::BufferUsageFlags::STORAGE_BUFFER);
            if let Ok(b) = hal.raw_device().create_buffer(&info, None) {
                hal.raw_device().destroy_buffer(b, None);
            }
        }
    }
    panic!("no validation error ended the process");
}
