//! Shader sources, embedded at build time. A program file may pull shared code in with a line
//! `//!include shared/NAME.wgsl` (WGSL has no includes; this is plain text substitution,
//! each file included at most once), and generate a neighbour walk with a line `//!walk NAME`
//! ([`WALKS`]: one template, shared/walk.wgsl, for every pair function). Every program is preceded by the [`Prelude`]: constants the
//! Rust side owns (workgroup sizes, the dispatch limit), so that WGSL and Rust cannot disagree.
use crate::error::{Error, Result};

/// Threads per workgroup of the per-particle kernels (`WG_PARTICLES` in WGSL).
pub const WG_PARTICLES: u32 = 64;
/// Threads per workgroup of the block kernels: the adaptive stage's per-particle kernels, and a
/// prefix-scan block on GPUs (`WG_BLOCK` in WGSL).
pub const WG_BLOCK: u32 = 256;
/// Values in one prefix-scan block, whatever the device (the mirror `sim::reference::scan` scans
/// the same blocks): `WG_SCAN` threads scan `SCAN_ITEMS` = `SCAN_BLOCK / WG_SCAN` consecutive
/// values each (both in WGSL).
pub const SCAN_BLOCK: u32 = 2048;
/// Threads per prefix-scan block on GPUs: a full workgroup, 8 values each.
pub const WG_SCAN_GPU: u32 = WG_BLOCK;
/// Threads per prefix-scan block on CPU devices: one SIMD batch, 256 values each. llvmpipe runs a
/// workgroup as batches of 8 invocations that take turns at every barrier; with a single batch
/// the scan's barriers cost next to nothing (a scan of 137k values: 3.2 -> 1.4-1.9 ms,
/// docs/PERFORMANCE.md "Table 1 / Session 10").
pub const WG_SCAN_CPU: u32 = 8;

/// The finest adaptive particle level (`ground::levels`, its one definition), `MAX_LEVEL` in
/// the prelude.
use crate::ground::levels::MAX_LEVEL;
/// The thermo uniform's table sizes (`ground::limits`), in the prelude as well.
use crate::ground::limits::{
    MAX_ENVIRONMENT_LEVELS, MAX_FORCING_LAYERS, MAX_LAYERS, MAX_SOURCES, MAX_WIND_LEVELS,
};

/// Loop iterations an invocation may run on llvmpipe, with a margin below its 65535.
pub const CPU_LOOP_BUDGET: u32 = 60_000;

/// The environment variable that forces every workgroup size (`WG_PARTICLES`, `WG_BLOCK` and
/// `WG_SCAN`) to one value, 32, 64, 128 or 256: the test suites run with each, so that no kernel
/// depends on the sizes nimbus picks (docs/ARCHITECTURE.md "Across adapters").
pub const WORKGROUP_ENV: &str = "NIMBUS_GPU_WORKGROUP";

/// The workgroup sizes [`WORKGROUP_ENV`] may force (the merge kernel needs 27 threads, one per
/// neighbour cell; a scan block of 2048 values must split into whole quads per thread).
pub const FORCEABLE_WORKGROUPS: [u32; 4] = [32, 64, 128, 256];

/// Constants prepended to every program's WGSL.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Prelude {
    pub wg_particles: u32,
    pub wg_block: u32,
    /// Threads per prefix-scan block (`WG_SCAN`; `WG_SCAN_GPU` or `WG_SCAN_CPU`).
    pub wg_scan: u32,
    /// Most workgroups per dispatch dimension (the adapter's limit; a larger dispatch is folded
    /// into rows along y).
    pub max_groups_x: u32,
    /// Loop iterations one invocation may run (`LOOP_BUDGET`): llvmpipe (lavapipe, the CPU
    /// device) silently ends all loops of an invocation after 65535 iterations in total, so
    /// 60000 there; unbounded on GPUs.
    pub loop_budget: u32,
}

impl Default for Prelude {
    fn default() -> Self {
        Self {
            wg_particles: WG_PARTICLES,
            wg_block: WG_BLOCK,
            wg_scan: WG_SCAN_GPU,
            max_groups_x: 65535,
            loop_budget: CPU_LOOP_BUDGET,
        }
    }
}

impl Prelude {
    /// The prelude for a device of this type with these limits (and the workgroup size
    /// [`WORKGROUP_ENV`] forces, if set).
    pub fn for_device(limits: &wgpu::Limits, device_type: wgpu::DeviceType) -> Result<Self> {
        let cpu = device_type == wgpu::DeviceType::Cpu;
        let mut p = Self {
            max_groups_x: limits.max_compute_workgroups_per_dimension,
            loop_budget: if cpu { CPU_LOOP_BUDGET } else { u32::MAX },
            wg_scan: if cpu { WG_SCAN_CPU } else { WG_SCAN_GPU },
            ..Self::default()
        };
        if let Some(wg) = forced_workgroup()? {
            log::warn!("{WORKGROUP_ENV}={wg}: every workgroup has {wg} threads (a test setting)");
            p = p.with_workgroup(wg);
        }
        if limits.max_compute_invocations_per_workgroup < p.wg_block
            || limits.max_compute_workgroup_size_x < p.wg_block
        {
            return Err(Error::NoGpu(format!(
                "the adapter runs at most {} threads per workgroup; nimbus needs {}",
                limits.max_compute_invocations_per_workgroup, p.wg_block
            )));
        }
        Ok(p)
    }

    /// This prelude with every workgroup size `wg` (one of [`FORCEABLE_WORKGROUPS`]).
    pub fn with_workgroup(self, wg: u32) -> Self {
        assert!(FORCEABLE_WORKGROUPS.contains(&wg), "workgroup size {wg}");
        Self {
            wg_particles: wg,
            wg_block: wg,
            wg_scan: wg,
            ..self
        }
    }

    fn wgsl(&self) -> String {
        format!(
            "// prelude (src/gpu/shaders.rs)\nconst WG_PARTICLES: u32 = {}u;\nconst WG_BLOCK: u32 = {}u;\nconst WG_SCAN: u32 = {}u;\nconst SCAN_ITEMS: u32 = {}u;\nconst MAX_GROUPS_X: u32 = {}u;\nconst LOOP_BUDGET: u32 = {}u;\nconst MAX_LEVEL: u32 = {}u;\nconst MAX_SOURCES: u32 = {}u;\nconst MAX_WIND_LEVELS: u32 = {}u;\nconst MAX_LAYERS: u32 = {}u;\nconst MAX_ENVIRONMENT_LEVELS: u32 = {}u;\nconst MAX_FORCING_LAYERS: u32 = {}u;\n",
            self.wg_particles,
            self.wg_block,
            self.wg_scan,
            SCAN_BLOCK / self.wg_scan,
            self.max_groups_x,
            self.loop_budget,
            MAX_LEVEL,
            MAX_SOURCES,
            MAX_WIND_LEVELS,
            MAX_LAYERS,
            MAX_ENVIRONMENT_LEVELS,
            MAX_FORCING_LAYERS
        )
    }
}

/// The workgroup size [`WORKGROUP_ENV`] forces, if any.
fn forced_workgroup() -> Result<Option<u32>> {
    let Ok(v) = std::env::var(WORKGROUP_ENV) else {
        return Ok(None);
    };
    match v.trim().parse::<u32>() {
        Ok(wg) if FORCEABLE_WORKGROUPS.contains(&wg) => Ok(Some(wg)),
        _ => Err(Error::InvalidInput(format!(
            "{WORKGROUP_ENV}={v}: one of {FORCEABLE_WORKGROUPS:?} (threads per workgroup)"
        ))),
    }
}

include!(concat!(env!("OUT_DIR"), "/shader_files.rs"));

/// (word, replacement) pairs applied to a template's text.
type Words = &'static [(&'static str, &'static str)];

/// Programs built from a template in `shared/` by replacing words: (program, template, words).
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

/// The neighbour-walk template: sections `//!template KIND` (`scan`, `build`, `masked`, `cells`,
/// `cells_shared`).
const WALK_TEMPLATE: &str = "shared/walk.wgsl";

/// One neighbour walk made from [`WALK_TEMPLATE`] (its words are explained there).
struct Walk {
    /// The function's name; `//!walk NAME` in a program puts it there.
    name: &'static str,
    /// The template's section: `scan` (around the position), `build` (around the anchor, writing
    /// the neighbour mask), `masked` (reading it), `cells` (the whole 27 cells around a cell) or
    /// `cells_shared` (adaptive_merge.wgsl's tabulated cells, a thread's share).
    template: &'static str,
    /// The function's leading parameters, the ones its pair and wall calls pass on: mostly an
    /// accumulator and `me`, the particle (the templates read `me.p`, and `build` `me.k`).
    params: &'static str,
    /// The call for a fluid candidate, `$` its index: a statement in `scan` and `masked`, in
    /// `build` whether the candidate is a neighbour, in `cells` and `cells_shared` whether the
    /// walk stops there.
    pair: &'static str,
    /// The call for a wall particle, `$` its index; `None`: the walk leaves the walls out.
    wall: Option<&'static str>,
    /// Whether the walls' row at cell row `$` is out of the particle's reach (skipped).
    skip_walls: &'static str,
}

/// The PBF passes reach the walls within max(h_i, h0) (the wall particles are level 0).
const PBF_SKIP_WALLS: &str = "!wall_reach($, me.p.y, max(me.hi, me.k.h0), grid)";
const VISC_SKIP_WALLS: &str = "!wall_reach($, me.p.y, max(me.lv.x, me.k.h0), grid)";

/// Every walk the programs generate. The build, masked and scan walks of one pass share its pair
/// function, so the mask changes which candidates are visited, never what a pair adds; the
/// adaptive stage's walks (`cells`, `cells_shared`) visit whole cells and stop where a pair says.
const WALKS: &[Walk] = &[
    Walk {
        name: "lam_scan",
        template: "scan",
        params: "a: ptr<function, LamAcc>, me: Me, packed: bool",
        pair: "_ = lam_fluid(a, me, $, packed)",
        wall: Some("lam_wall(a, me, $)"),
        skip_walls: PBF_SKIP_WALLS,
    },
    Walk {
        name: "lam_build",
        template: "build",
        params: "a: ptr<function, LamAcc>, me: Me",
        pair: "lam_fluid(a, me, $, false)",
        wall: Some("lam_wall(a, me, $)"),
        skip_walls: PBF_SKIP_WALLS,
    },
    Walk {
        name: "lam_masked",
        template: "masked",
        params: "a: ptr<function, LamAcc>, me: Me",
        pair: "_ = lam_fluid(a, me, $, true)",
        wall: Some("lam_wall(a, me, $)"),
        skip_walls: PBF_SKIP_WALLS,
    },
    Walk {
        name: "delta_scan",
        template: "scan",
        params: "dp: ptr<function, vec3<f32>>, me: Me",
        pair: "delta_fluid(dp, me, $)",
        wall: Some("delta_wall(dp, me, $)"),
        skip_walls: PBF_SKIP_WALLS,
    },
    Walk {
        name: "delta_masked",
        template: "masked",
        params: "dp: ptr<function, vec3<f32>>, me: Me",
        pair: "delta_fluid(dp, me, $)",
        wall: Some("delta_wall(dp, me, $)"),
        skip_walls: PBF_SKIP_WALLS,
    },
    Walk {
        name: "visc_scan",
        template: "scan",
        params: "a: ptr<function, Visc>, me: Vi",
        pair: "visc_pair(a, me, $)",
        wall: Some("visc_wall(a, me, $)"),
        skip_walls: VISC_SKIP_WALLS,
    },
    Walk {
        name: "visc_masked",
        template: "masked",
        params: "a: ptr<function, Visc>, me: Vi",
        pair: "visc_pair(a, me, $)",
        wall: Some("visc_wall(a, me, $)"),
        skip_walls: VISC_SKIP_WALLS,
    },
    Walk {
        name: "vort_scan",
        template: "scan",
        params: "w: ptr<function, vec3<f32>>, me: Vo",
        pair: "vort_pair(w, me, $)",
        wall: None,
        skip_walls: "",
    },
    Walk {
        name: "demand_scan",
        template: "scan",
        params: "sum: ptr<function, f32>, me: Dm",
        pair: "demand_pair(sum, me, $)",
        wall: None,
        skip_walls: "",
    },
    Walk {
        name: "smooth_scan",
        template: "scan",
        params: "a: ptr<function, SmAcc>, me: Sm",
        pair: "smooth_pair(a, me, $)",
        wall: Some("smooth_wall(a, me, $)"),
        skip_walls: "S.fixed_walls == 0u || !wall_reach($, me.p.y, S.h0, grid)",
    },
    Walk {
        name: "fit_walk",
        template: "cells",
        params: "me: Fit",
        pair: "fit_blocked(me, $)",
        wall: None,
        skip_walls: "",
    },
    Walk {
        name: "partner_walk",
        template: "cells",
        params: "tested: ptr<function, u32>, me: Slots",
        pair: "partner_found(tested, me, $)",
        wall: None,
        skip_walls: "",
    },
    Walk {
        name: "nearest_walk",
        template: "cells_shared",
        params: "a: ptr<function, Nearest>, me: Merging",
        pair: "nearest_pair(a, me, kc, $)",
        wall: None,
        skip_walls: "",
    },
    Walk {
        name: "room_walk",
        template: "cells_shared",
        params: "me: Product",
        pair: "room_blocked(me, $)",
        wall: None,
        skip_walls: "",
    },
];

/// The WGSL of the walk `name` ([`WALKS`]).
fn walk_source(name: &str) -> Result<String> {
    let w = WALKS
        .iter()
        .find(|w| w.name == name)
        .ok_or_else(|| Error::Runtime(format!("no neighbour walk '{name}' in WALKS")))?;
    let template = raw(WALK_TEMPLATE)?;
    let marker = format!("//!template {}\n", w.template);
    let start = template
        .find(&marker)
        .ok_or_else(|| Error::Runtime(format!("{WALK_TEMPLATE}: no section '{}'", w.template)))?
        + marker.len();
    let section = &template[start..];
    let section = &section[..section.find("//!template ").unwrap_or(section.len())];
    let mut out = String::new();
    let mut in_walls = false;
    for line in section.lines() {
        match line.trim() {
            "//!walls" => in_walls = true,
            "//!end walls" => in_walls = false,
            _ if in_walls && w.wall.is_none() => {}
            _ => {
                out.push_str(line);
                out.push('\n');
            }
        }
    }
    let out = out
        .replace("WALK_NAME", w.name)
        .replace("WALK_PARAMS", w.params);
    let out = calls(&out, "PAIR", w.pair)?;
    let out = calls(&out, "SKIP_WALLS", w.skip_walls)?;
    calls(&out, "WALL", w.wall.unwrap_or(""))
}

/// Replaces every `WORD[[arg]]` in `text` by `call` with `$` = arg.
fn calls(text: &str, word: &str, call: &str) -> Result<String> {
    let open = format!("{word}[[");
    let mut out = String::new();
    let mut rest = text;
    while let Some(i) = rest.find(&open) {
        out.push_str(&rest[..i]);
        rest = &rest[i + open.len()..];
        let end = rest
            .find("]]")
            .ok_or_else(|| Error::Runtime(format!("{WALK_TEMPLATE}: {open} without ]]")))?;
        out.push_str(&call.replace('$', &rest[..end]));
        rest = &rest[end + 2..];
    }
    out.push_str(rest);
    Ok(out)
}

/// Names of the compute programs (every `.wgsl` outside `shared/`, and the template variants).
pub fn program_names() -> impl Iterator<Item = &'static str> {
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

/// The full WGSL text of a program with its includes expanded, after the default prelude.
pub fn source(name: &str) -> Result<String> {
    source_with(name, &Prelude::default())
}

/// The full WGSL text of a program with its includes expanded, after `prelude`.
pub fn source_with(name: &str, prelude: &Prelude) -> Result<String> {
    let (file, words): (&str, Words) = VARIANTS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map_or((name, &[]), |(_, t, w)| (*t, *w));
    let mut seen = Vec::new();
    let mut out = prelude.wgsl();
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
        } else if let Some(walk) = line.trim().strip_prefix("//!walk ") {
            out.push_str(&walk_source(walk.trim())?);
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    Ok(())
}

/// Parses and validates a program with naga (what wgpu does at pipeline creation).
pub fn validate(name: &str) -> Result<naga::Module> {
    validate_with(name, &Prelude::default())
}

/// [`validate`] with a device's prelude.
pub fn validate_with(name: &str, prelude: &Prelude) -> Result<naga::Module> {
    let src = source_with(name, prelude)?;
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

/// Compiles a program into a shader module on the context's device, with its prelude.
///
/// Every check wgpu adds stays on except the forced loop bound: naga would give every loop a
/// 64-bit trip counter and an extra exit test, which cost 5-12% of a PBF substep on llvmpipe
/// (docs/PERFORMANCE.md "PBF / Session 11"). Our loops need no such bound: each runs over a
/// range fixed before it starts (candidate entries, cells, scan items) or pops a bit of a mask
/// per trip, so every loop ends.
pub fn module(ctx: &crate::gpu::Context, name: &str) -> Result<wgpu::ShaderModule> {
    let src = source_with(name, &ctx.prelude)?;
    let checks = wgpu::ShaderRuntimeChecks {
        force_loop_bounding: false,
        ..wgpu::ShaderRuntimeChecks::checked()
    };
    let desc = wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(src.into()),
    };
    // SAFETY: the only check left out is the loop bound, and every loop of shaders/ ends (above).
    Ok(unsafe { ctx.device.create_shader_module_trusted(desc, checks) })
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_shader_compiles_through_naga() {
        // Shared files are valid modules on their own (templates only as their variants);
        // programs are checked with their includes.
        let mut templates: Vec<&str> = super::VARIANTS.iter().map(|(_, t, _)| *t).collect();
        templates.push(super::WALK_TEMPLATE);
        let files = super::SHADER_FILES.iter().map(|(n, _)| *n);
        for name in files.chain(super::program_names()) {
            if !templates.contains(&name) {
                super::validate(name).unwrap_or_else(|e| panic!("{e}"));
            }
        }
        assert!(!super::SHADER_FILES.is_empty(), "no shaders found");
    }

    #[test]
    fn every_walk_is_used_once_and_fully_expanded() {
        let mut used = Vec::new();
        for (name, text) in super::SHADER_FILES {
            for line in text.lines() {
                if let Some(w) = line.trim().strip_prefix("//!walk ") {
                    used.push(w.trim().to_string());
                    let src =
                        super::walk_source(w.trim()).unwrap_or_else(|e| panic!("{name}: {e}"));
                    for word in ["WALK_", "PAIR[[", "WALL[[", "SKIP_WALLS", "//!"] {
                        assert!(!src.contains(word), "{name}: {w} keeps {word}:\n{src}");
                    }
                    assert!(src.contains(&format!("fn {}(", w.trim())), "{w}");
                }
            }
        }
        used.sort();
        let mut all: Vec<String> = super::WALKS.iter().map(|w| w.name.to_string()).collect();
        all.sort();
        assert_eq!(used, all, "each walk of WALKS generated once");
    }

    #[test]
    fn only_the_walk_template_walks_neighbours() {
        // The pieces a neighbour walk is made of: rows around a position or an anchor, the
        // neighbour cells by offset, the merge's strided share, the loop over the rows. Outside
        // the template only common.wgsl (which defines them) and their own definitions name them;
        // `cell_entries` is free (the merge tabulates cells with it, merge_cells sums their
        // sizes: neither visits a pair).
        let pieces = [
            "row_entries(",
            "anchor_row(",
            "neighbor_cell(",
            "first_candidate(",
            "for (var dz",
        ];
        for (name, text) in super::SHADER_FILES {
            if [super::WALK_TEMPLATE, "shared/common.wgsl"].contains(name) {
                continue;
            }
            for (n, line) in text.lines().enumerate() {
                let code = line.split("//").next().unwrap_or("").trim();
                if code.starts_with("fn ") {
                    continue;
                }
                for piece in pieces {
                    assert!(
                        !code.contains(piece),
                        "{name}:{}: a neighbour walk outside {}: {line}",
                        n + 1,
                        super::WALK_TEMPLATE
                    );
                }
            }
        }
    }

    #[test]
    fn the_level_tables_select_chains_cover_max_level() {
        // lv_of (pbf.wgsl) and level_row (smoothing.wgsl) pick rows 1..MAX_LEVEL by one select
        // each, the last for every level at or above MAX_LEVEL
        for (file, fun) in [
            ("pbf.wgsl", "fn lv_of("),
            ("smoothing.wgsl", "fn level_row("),
        ] {
            let src = super::raw(file).unwrap();
            let body = &src[src.find(fun).unwrap()..];
            let body = &body[..body.find("\n}").unwrap()];
            assert_eq!(
                body.matches("select(").count() as u32,
                super::MAX_LEVEL,
                "{file} {fun}"
            );
            assert!(body.contains("l >= MAX_LEVEL"), "{file} {fun}");
        }
    }
}
