//! The prepared shot: a config read and checked (`config`), then everything that needs more
//! than the config's own keys, done once: the files it names read and checked (the heat maps of
//! image sources, `control.target`'s mesh or VDB voxelised on the controller's grid), the limits
//! of the stages that will run it (the splat's and the preview's parameters), the SHA-256 pins
//! of its files set, and the values derived from it (h0, m0 and the level table built on them;
//! the formulas the config's own checks need too, h0 and the lattice, are methods of the config
//! types, and `ground::levels` holds the level limit and the per-level radius and mass). `nimbus validate`, `run` and `resume` all
//! build one, so what validate accepts, run accepts; the simulation and the writers take theirs
//! from it instead of reading the files again.
//!
//! An issue found here is placed as the config's own are (`FILE:LINE:COL: KEY: ...`,
//! `config::Checked::error`).
pub mod handoff;
pub mod heat_maps;
pub mod target;
pub mod target_volume;

use crate::config::{self, Checked, Issue, ShotConfig};
use crate::error::Result;
use crate::ground::levels::{self, poly6};
use crate::ground::{HeatMap, TargetVoxels};
use glam::DVec3;
use std::path::Path;

/// A shot config with its files read and its derived values, checked once.
#[derive(Debug, Clone)]
pub struct Shot {
    config: ShotConfig,
    /// Per `physics.sources` entry: its heat map (`shape: image`), else `None`.
    heat_maps: Vec<Option<HeatMap>>,
    /// `control.target` voxelised on the controller's grid.
    target: Option<TargetVoxels>,
    /// Level-0 kernel radius h0 = spacing * kernel_ratio (m).
    h0: f64,
    /// The two level-0 masses, each with one job, and distinct on purpose. `m0`, the solver's
    /// ([`pbf_mass`]: rho0 over the lattice's poly6 sum), normalises the discrete kernel sum so
    /// that the lattice sits at rest density: the PBF and wall densities and the particle caches
    /// (which carry the solver's densities) use it. `cell_mass` (`ShotConfig::cell_mass`,
    /// rho0 d^3) is the air a particle stands for: the reported masses and the splat's volumes
    /// use it. At h0 = 2d, m0 = 0.990 cell_mass, the kernel's discretisation error.
    m0: f64,
    cell_mass: f64,
    /// Particles of the initial lattice.
    particles: u64,
}

/// Reads the config at `path` with `overrides` (`config::read`) and prepares its shot.
pub fn load(path: &Path, overrides: &[String]) -> Result<Shot> {
    Shot::from_checked(config::read(path, overrides)?)
}

/// [`load`] for config text in memory; `origin` names it in errors (`config::read_str`).
pub fn load_str(text: &str, origin: &str, overrides: &[String]) -> Result<Shot> {
    Shot::from_checked(config::read_str(text, origin, overrides)?)
}

impl Shot {
    /// The shot of a config read and checked; its issues placed in the config's file.
    pub fn from_checked(checked: Checked) -> Result<Self> {
        Self::build(checked.config.clone()).map_err(|issue| checked.error(&issue))
    }

    /// The shot of a config as `config::read` gives it, checked here (a config built or changed
    /// in code); an issue names its key without a file position.
    pub fn prepare(cfg: ShotConfig) -> Result<Self> {
        if let Some(issue) = config::first_issue(&cfg) {
            return Err(issue.error());
        }
        Self::build(cfg).map_err(|issue| issue.error())
    }

    fn build(mut cfg: ShotConfig) -> std::result::Result<Self, Issue> {
        let heat_maps = heat_maps::read(&cfg)?;
        let target = target::prepare(&cfg)?;
        check_stage_limits(&cfg)?;
        handoff::check(&cfg.export)?;
        pin_files(&mut cfg, &heat_maps);
        Ok(Self {
            h0: cfg.domain.kernel_radius(),
            m0: pbf_mass(&cfg),
            cell_mass: cfg.cell_mass(),
            particles: config::lattice_count(&cfg.domain) as u64,
            config: cfg,
            heat_maps,
            target,
        })
    }

    /// The config, with its files' SHA-256 pins set.
    pub fn config(&self) -> &ShotConfig {
        &self.config
    }

    pub fn into_config(self) -> ShotConfig {
        self.config
    }

    /// Per `physics.sources` entry: its heat map, `None` for a source without one.
    pub fn heat_maps(&self) -> &[Option<HeatMap>] {
        &self.heat_maps
    }

    /// `control.target` voxelised on the controller's grid, if the shot has one.
    pub fn target(&self) -> Option<&TargetVoxels> {
        self.target.as_ref()
    }

    /// Level-0 kernel radius h0 (m).
    pub fn h0(&self) -> f64 {
        self.h0
    }

    /// Level-0 particle mass m0 of the solver (kg; [`pbf_mass`]).
    pub fn m0(&self) -> f64 {
        self.m0
    }

    /// The air a level-0 particle stands for, rho0 d^3 (kg; not [`Self::m0`], see the field).
    pub fn cell_mass(&self) -> f64 {
        self.cell_mass
    }

    /// Kernel radius of a level-`level` particle, h0 2^(-level/3) (m).
    pub fn level_radius(&self, level: u32) -> f64 {
        levels::radius(self.h0, level)
    }

    /// Mass of a level-`level` particle, m0 2^(-level) (kg).
    pub fn level_mass(&self, level: u32) -> f64 {
        levels::mass(self.m0, level)
    }

    /// Particles of the initial lattice (size / spacing per axis).
    pub fn particles(&self) -> u64 {
        self.particles
    }
}

/// Level-0 mass m0 of the solver: rho0 divided by the poly6 sum over the initial lattice, so
/// that the lattice (and a fluid particle next to the wall particles, which continue the
/// lattice) is exactly at rest density. With h0 = 2d this differs from rho0 d^3 by the
/// kernel's discretisation error (docs/ARCHITECTURE.md "Units and choices").
fn pbf_mass(cfg: &ShotConfig) -> f64 {
    let (_, d) = cfg.domain.lattice();
    let h = cfg.domain.kernel_radius();
    let r = [0, 1, 2].map(|a| (h / d[a]).ceil() as i64);
    let mut sum = 0.0;
    for k in -r[2]..=r[2] {
        for j in -r[1]..=r[1] {
            for i in -r[0]..=r[0] {
                let x = DVec3::new(i as f64, j as f64, k as f64) * DVec3::from(d);
                sum += poly6(x.length_squared(), h);
            }
        }
    }
    cfg.solver.rest_density / sum
}

/// The checks `run` makes when it builds the splat and preview parameters, made here first
/// (the same functions, so validate and run can never disagree).
fn check_stage_limits(c: &ShotConfig) -> std::result::Result<(), Issue> {
    let issue = |key: &str, msg: String, prefix: &str| Issue {
        keys: vec![key.to_string()],
        msg: msg.strip_prefix(prefix).unwrap_or(&msg).to_string(),
    };
    if let Err(e) = crate::splat::SplatParams::from_config(c) {
        return Err(issue("export.voxel_size", e.to_string(), "splat: "));
    }
    if let Err(e) = crate::preview::PreviewParams::for_shot(c) {
        let msg = e.to_string();
        let key = if msg.contains("camera") {
            "output.preview.camera.look_at"
        } else if msg.contains("sun_direction") {
            "output.preview.sun_direction"
        } else {
            "output.preview"
        };
        return Err(issue(key, msg, "preview: "));
    }
    Ok(())
}

/// Pins each file's content, so the manifest and the checkpoints name exactly the file the run
/// used and a resume refuses a changed one (a pinned file is compared as it is read).
fn pin_files(cfg: &mut ShotConfig, maps: &[Option<HeatMap>]) {
    for (src, map) in cfg.physics.sources.iter_mut().zip(maps) {
        if let (Some(map), None) = (map, &src.image_sha256) {
            src.image_sha256 = Some(map.sha256.clone());
        }
    }
    if let Some(t) = &mut cfg.control.target {
        for (path, sha) in [(&t.mesh, &mut t.mesh_sha256), (&t.vdb, &mut t.vdb_sha256)] {
            if let (Some(path), true) = (path, sha.is_none()) {
                *sha = crate::io::heat_map::file_sha256(Path::new(path)).ok();
            }
        }
    }
}

#[cfg(test)]
mod tests;
