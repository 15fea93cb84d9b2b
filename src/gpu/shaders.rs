//! Shader sources, embedded at build time. A stage file may pull shared code in with a line
//! `//!include shared/NAME.wgsl` (WGSL has no includes; this is plain text substitution,
//! each file included at most once).
use crate::error::{Error, Result};

include!(concat!(env!("OUT_DIR"), "/shader_files.rs"));

/// (word, replacement) pairs applied to a template's text.
type Words = &'static [(&'static str, &'static str)];

/// Stages built from a template in `shared/` by replacing words: (stage, template, words).
/// WGSL has no generics; one gather kernel serves two element types.
const VARIANTS: &[(&str, &str, Words)] = &[
    (
        "permute4.wgsl",
        "shared/permute.wgsl",
        &[("ELEM", "vec4<f32>"), ("WIDTH", "4")],
    ),
    (
        "permute2.wgsl",
        "shared/permute.wgsl",
        &[("ELEM", "vec2<u32>"), ("WIDTH", "2")],
    ),
];

/// Names of the compute stages (every `.wgsl` outside `shared/`, and the template variants).
pub fn stage_names() -> impl Iterator<Item = &'static str> {
    SHADER_FILES
        .iter()
        .map(|(n, _)| *n)
        .filter(|n| !n.starts_with("shared/"))
        .chain(VARIANTS.iter().map(|(n, _, _)| *n))
}

fn raw(name: &str) -> Result<&'static str> {
    SHADER_FILES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, s)| *s)
        .ok_or_else(|| Error::Runtime(format!("shader '{name}' is not built into this binary")))
}

/// The full WGSL text of a stage with its includes expanded.
pub fn source(name: &str) -> Result<String> {
    let (file, words): (&str, Words) = VARIANTS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map_or((name, &[]), |(_, t, w)| (*t, *w));
    let mut seen = Vec::new();
    let mut out = String::new();
    expand(file, &mut seen, &mut out)?;
    for (word, replacement) in words {
        out = out.replace(word, replacement);
    }
    Ok(out)
}

fn expand(name: &str, seen: &mut Vec<String>, out: &mut String) -> Result<()> {
    if seen.iter().any(|s| s == name) {
        return Ok(());
    }
    seen.push(name.to_string());
    for line in raw(name)?.lines() {
        if let Some(inc) = line.trim().strip_prefix("//!include ") {
            expand(inc.trim(), seen, out)?;
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    Ok(())
}

/// Parses and validates a stage with naga (what wgpu does at pipeline creation).
pub fn validate(name: &str) -> Result<naga::Module> {
    let src = source(name)?;
    let module = naga::front::wgsl::parse_str(&src)
        .map_err(|e| Error::Runtime(format!("{name}: {}", e.emit_to_string(&src))))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .map_err(|e| Error::Runtime(format!("{name}: {e:?}")))?;
    Ok(module)
}

/// Compiles a stage into a shader module on `device`.
pub fn module(device: &wgpu::Device, name: &str) -> Result<wgpu::ShaderModule> {
    let src = source(name)?;
    Ok(device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(src.into()),
    }))
}

/// A compute pipeline for entry point `entry` of stage `name`, with an automatic layout.
pub fn compute_pipeline(
    device: &wgpu::Device,
    name: &str,
    entry: &str,
) -> Result<wgpu::ComputePipeline> {
    let module = module(device, name)?;
    Ok(
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(&format!("{name}:{entry}")),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        }),
    )
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_shader_compiles_through_naga() {
        // Shared files are valid modules on their own (templates only as their variants);
        // stages are checked with their includes.
        let templates: Vec<&str> = super::VARIANTS.iter().map(|(_, t, _)| *t).collect();
        let files = super::SHADER_FILES.iter().map(|(n, _)| *n);
        for name in files.chain(super::stage_names()) {
            if !templates.contains(&name) {
                super::validate(name).unwrap_or_else(|e| panic!("{e}"));
            }
        }
        assert!(!super::SHADER_FILES.is_empty(), "no shaders found");
    }
}
