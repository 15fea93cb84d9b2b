//! The CPU side of a frame: splat the particles, write VDB, EXR and preview files atomically,
//! and return their records for the manifest.
use super::records::{file_record, FrameRecord, Manifest, WriterTimes};
use super::run_dir::{FrameFile, RunDir};
use crate::config::ShotConfig;
use crate::error::Result;
use crate::export::ExportSpace;
use crate::ground::rest::{RestClock, RestCodec, RestFrame};
use crate::ground::ParticleState;
use crate::ground::{GridTransform, SparseGrid};
use crate::io::vdb::{VdbFile, VdbGrid, VdbOptions};
use crate::shot::Shot;
use crate::splat::SplatGrids;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

pub struct FrameJob {
    pub frame: u32,
    pub state: Arc<ParticleState>,
    /// The frame is already on disk with matching checksums (a resume): do not rewrite it.
    pub skip_write: bool,
    pub started: Instant,
    /// Rest positions of the particles, same order (`sim::rest`), when the run tracks them
    /// (`ExportConfig::tracks_rest`).
    pub rest: Option<Arc<RestFrame>>,
}

pub struct WrittenFrame {
    pub frame: u32,
    pub particles: u64,
    pub record: Option<FrameRecord>,
    pub phase_ms: WriterTimes,
    pub wall_ms: f64,
}

pub struct FrameWriter {
    cfg: ShotConfig,
    run_dir: RunDir,
    transform: GridTransform,
    /// The VDB files' frame (scale, axis, velocity basis) and grid aliases.
    space: ExportSpace,
    aliases: BTreeMap<String, String>,
    /// The shot's level-0 kernel radius (m) and mass (kg), for the particle cache.
    h0: f64,
    m0: f64,
    splat: crate::splat::SplatParams,
    preview: Option<crate::preview::PreviewParams>,
    /// `output.preview.source_overlay`: the sources drawn into the previews.
    overlay: Option<crate::preview::overlay::sources::SourceOverlay>,
    rest_clock: RestClock,
    rest_codec: RestCodec,
}

impl FrameWriter {
    /// The writer of `cfg`'s frames into `run_dir`: `cfg` is `shot`'s config, or it with other
    /// export or preview keys (a re-export, a bench); the particle caches' h0 and m0 and the
    /// heat maps the source overlay draws are the shot's.
    pub fn new(shot: &Shot, cfg: &ShotConfig, run_dir: &RunDir) -> Result<Self> {
        let heat_maps = shot.heat_maps();
        if cfg.output.preview.enabled && cfg.output.preview.movie {
            crate::preview::movie::require_ffmpeg()?;
        }
        let splat = crate::splat::SplatParams::from_config(cfg)?;
        let preview = if cfg.output.preview.enabled {
            Some(crate::preview::PreviewParams::for_shot(cfg)?)
        } else {
            None
        };
        let overlay = if preview.is_some() && cfg.output.preview.source_overlay {
            Some(crate::preview::overlay::sources::SourceOverlay::new(
                cfg, heat_maps,
            )?)
        } else {
            None
        };
        Ok(Self {
            cfg: cfg.clone(),
            run_dir: run_dir.clone(),
            transform: splat.transform,
            space: ExportSpace::from_config(cfg),
            aliases: ExportSpace::aliases(cfg),
            h0: shot.h0(),
            m0: shot.m0(),
            rest_codec: RestCodec::new(cfg.domain.size, splat.periodic),
            splat,
            preview,
            overlay,
            rest_clock: crate::sim::rest::rest_clock(cfg),
        })
    }

    pub fn new_manifest(
        &self,
        cfg: &ShotConfig,
        adapter: &str,
        sim_hash: &str,
    ) -> Result<Manifest> {
        Ok(Manifest {
            tool: "nimbus".into(),
            version: crate::VERSION.into(),
            shot: cfg.shot.clone(),
            config: serde_json::to_value(cfg).map_err(|e| crate::Error::Runtime(e.to_string()))?,
            config_hash: crate::config::full_hash(cfg),
            sim_hash: sim_hash.to_string(),
            adapter: adapter.to_string(),
            frame_start: cfg.output.frames.start,
            frame_end: cfg.output.frames.end,
            fps: cfg.output.fps,
            voxel_size: self.space.transform(&self.transform).voxel_size,
            grid_origin: self.space.transform(&self.transform).origin,
            export: Some(self.space.clone()),
            sources: crate::sim::sources::records(cfg),
            preroll: super::records::PrerollRecord::of(cfg),
            resume_command: super::naming::resume_command(self.run_dir.root()),
            usd: None,
            frames: Vec::new(),
            complete: false,
        })
    }

    pub fn write(&self, job: FrameJob) -> Result<WrittenFrame> {
        let mut phase_ms = WriterTimes::default();
        let particles = job.state.len() as u64;
        if job.skip_write {
            return Ok(WrittenFrame {
                frame: job.frame,
                particles,
                record: None,
                phase_ms,
                wall_ms: ms(job.started),
            });
        }
        let t = Instant::now();
        // Split and merge move particles without their SPH densities, and PBF holds every
        // density at rho0 within a few percent: the splat uses m / rho0 as particle volume.
        let mut state = (*job.state).clone();
        state.density.fill(self.cfg.solver.rest_density as f32);
        let rest = job.rest.as_deref().map(|r| crate::splat::RestInput {
            rest: r,
            codec: self.rest_codec,
            weights: self.rest_clock.weights(job.frame),
            dual: self.rest_clock.dual(),
        });
        let grids = crate::splat::splat_with_rest(&state, &self.splat, rest)?;
        phase_ms.splat = Some(ms(t));
        let mut files = Vec::new();
        let c = &self.cfg;
        if c.export.exr.enabled {
            let t = Instant::now();
            let path = self.file(FrameFile::Exr, job.frame);
            let empty;
            let density = match &grids.density {
                Some(g) => g,
                None => {
                    empty = SparseGrid {
                        name: "density".into(),
                        background: 0.0,
                        transform: self.transform,
                        leaves: vec![],
                    };
                    &empty
                }
            };
            crate::io::exr::write_density_atlas(&path, density, c.export.exr.half)?;
            files.push(file_record(self.run_dir.root(), &path)?);
            phase_ms.write_exr = Some(ms(t));
        }
        if let (Some(params), Some(density)) = (&self.preview, &grids.density) {
            let t = Instant::now();
            let mut img = crate::preview::render(density, params)?;
            if let Some(overlay) = &self.overlay {
                overlay.draw(&mut img, params, job.frame);
            }
            let png = crate::preview::write_image(
                &img,
                params.exposure,
                &self.file(FrameFile::PreviewPng, job.frame),
                c.output.preview.exr,
            )?;
            files.push(file_record(self.run_dir.root(), &png)?);
            if c.output.preview.exr {
                files.push(file_record(
                    self.run_dir.root(),
                    &png.with_extension("exr"),
                )?);
            }
            phase_ms.preview = Some(ms(t));
        }
        if c.export.particles {
            let t = Instant::now();
            let path = self.file(FrameFile::Particles, job.frame);
            self.write_particles(&path, &job.state, job.rest.as_deref(), job.frame)?;
            files.push(file_record(self.run_dir.root(), &path)?);
            phase_ms.write_particles = Some(ms(t));
        }
        // Last, so the grids move into the file instead of being copied; listed first, then
        // the NanoVDB file made from the same grids.
        if c.export.vdb.enabled || c.export.nanovdb.enabled {
            let file = self.vdb_file(grids, job.frame);
            let mut head = Vec::new();
            if c.export.vdb.enabled {
                let t = Instant::now();
                let path = self.file(FrameFile::Vdb, job.frame);
                crate::io::vdb::write_file(&path, &file, &self.vdb_options())?;
                head.push(file_record(self.run_dir.root(), &path)?);
                phase_ms.write_vdb = Some(ms(t));
            }
            if c.export.nanovdb.enabled {
                let t = Instant::now();
                let path = self.file(FrameFile::NanoVdb, job.frame);
                self.write_nanovdb(&path, &file)?;
                head.push(file_record(self.run_dir.root(), &path)?);
                phase_ms.write_nanovdb = Some(ms(t));
            }
            files.splice(0..0, head);
        }
        Ok(WrittenFrame {
            frame: job.frame,
            particles,
            record: Some(FrameRecord {
                frame: job.frame,
                files,
            }),
            phase_ms,
            wall_ms: ms(job.started),
        })
    }

    /// A frame record holds exactly the files this config writes (a resume with other export
    /// settings writes its frames again).
    pub fn has_all_files(&self, rec: &FrameRecord) -> bool {
        let want = self.frame_files(rec.frame);
        want.len() == rec.files.len()
            && want.iter().zip(&rec.files).all(|(p, f)| {
                p.strip_prefix(self.run_dir.root())
                    .is_ok_and(|r| r == Path::new(&f.path))
            })
    }

    /// The file of `kind` of `frame` of this shot.
    fn file(&self, kind: FrameFile, frame: u32) -> PathBuf {
        self.run_dir
            .frame_file(kind, &self.cfg.shot, frame, self.cfg.output.frame_padding)
    }

    /// The files a frame of this config has, in the order of its manifest record.
    pub fn frame_files(&self, frame: u32) -> Vec<PathBuf> {
        let c = &self.cfg;
        let f = |kind| self.file(kind, frame);
        let mut v = Vec::new();
        if c.export.vdb.enabled {
            v.push(f(FrameFile::Vdb));
        }
        if c.export.nanovdb.enabled {
            v.push(f(FrameFile::NanoVdb));
        }
        if c.export.exr.enabled {
            v.push(f(FrameFile::Exr));
        }
        if self.preview.is_some() && !c.export.grids.density.is_empty() {
            v.push(f(FrameFile::PreviewPng));
            if c.output.preview.exr {
                v.push(f(FrameFile::PreviewExr));
            }
        }
        if c.export.particles {
            v.push(f(FrameFile::Particles));
        }
        v
    }

    /// The frame's particle cache (`io::ply`), in the export frame.
    fn write_particles(
        &self,
        path: &Path,
        state: &ParticleState,
        rest: Option<&RestFrame>,
        frame: u32,
    ) -> Result<()> {
        let s = &self.space;
        let info = crate::io::ply::CacheInfo {
            space: s,
            rest: rest.map(|r| (r, self.rest_codec)),
            h0: self.h0,
            m0: self.m0,
            comments: vec![
                format!("nimbus {} shot {} frame {frame}", crate::VERSION, self.cfg.shot),
                format!(
                    "units: position and radius in scene units of {} m, up axis {}, velocity in {}, temperature K, vapor and cloud_water kg/kg, mass kg",
                    s.scale,
                    if s.up_axis == crate::config::UpAxis::Z { "z" } else { "y" },
                    s.velocity_unit
                ),
            ],
        };
        let bytes = crate::io::ply::encode(state, &info)?;
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
        }
        crate::io::atomic::write_atomic(path, &bytes)
    }

    /// Records of the frames `start..before` whose files are all on disk, with the sizes and
    /// checksums read from disk (a manifest rebuilt after it was lost).
    pub fn records_on_disk(&self, start: u32, before: u32) -> Result<Vec<FrameRecord>> {
        let mut out = Vec::new();
        for frame in start..before {
            let files = self.frame_files(frame);
            if files.is_empty() || !files.iter().all(|p| p.is_file()) {
                continue;
            }
            let files = files
                .iter()
                .map(|p| file_record(self.run_dir.root(), p))
                .collect::<Result<Vec<_>>>()?;
            out.push(FrameRecord { frame, files });
        }
        Ok(out)
    }

    /// The grids of a frame under their configured names, with their aliases, in the export
    /// frame (`export::ExportSpace`).
    fn vdb_file(&self, grids: SplatGrids, frame: u32) -> VdbFile {
        let names = &self.cfg.export.grids;
        let space = &self.space;
        let with_aliases = |mut g: VdbGrid| {
            for (alias, target) in &self.aliases {
                if *target == g.name {
                    g = g.with_alias(alias.clone());
                }
            }
            g
        };
        let mut out = Vec::new();
        for (name, grid) in [
            (&names.density, grids.density),
            (&names.temperature, grids.temperature),
            (&names.vapor, grids.vapor),
        ] {
            if let (false, Some(g)) = (name.is_empty(), grid) {
                let mut fg = VdbGrid::float(name.clone(), space.float_grid(g));
                if std::ptr::eq(name, &names.density) {
                    if let Some(o) = &space.optics {
                        fg.metadata = o.metadata();
                    }
                }
                out.push(with_aliases(fg));
            }
        }
        if let (false, Some(g)) = (names.velocity.is_empty(), grids.velocity) {
            let mut vg = VdbGrid::vec3(names.velocity.clone(), space.velocity_grid(g))
                .with_class(space.velocity_class_name());
            vg.metadata = space.velocity_metadata();
            out.push(with_aliases(vg));
        }
        let w = self.rest_clock.weights(frame);
        let second = format!("{}2", names.rest);
        for (name, grid, weight) in [
            (&names.rest, grids.rest, w[0]),
            (&second, grids.rest2, w[1]),
        ] {
            if let (false, Some(g)) = (names.rest.is_empty(), grid) {
                let mut rg = VdbGrid::vec3(name.clone(), space.point_grid(g));
                rg.metadata = self.rest_metadata(weight);
                out.push(with_aliases(rg));
            }
        }
        let mut metadata = VdbFile::standard_metadata(frame as i64);
        metadata.extend(space.file_metadata(self.transform.voxel_size));
        VdbFile {
            grids: out,
            metadata,
        }
    }

    /// Metadata of a rest grid: its blend weight this frame (the two sum to 1; shaders
    /// cross-fade noise(rest) and noise(rest2) by them) and the reset period.
    fn rest_metadata(&self, weight: f64) -> Vec<(String, crate::io::vdb::MetaValue)> {
        use crate::io::vdb::MetaValue;
        vec![
            ("nimbus_rest_weight".into(), MetaValue::Double(weight)),
            (
                "nimbus_rest_period_frames".into(),
                MetaValue::Int64(self.rest_clock.period as i64),
            ),
        ]
    }

    /// The frame's NanoVDB file (`export.nanovdb`): the selected grids of the VDB file, in its
    /// order and frame, float or quantised (`io::nanovdb`).
    fn write_nanovdb(&self, path: &Path, file: &VdbFile) -> Result<()> {
        use crate::io::nanovdb::{GridClass, NanoGrid, NanoValues};
        use crate::io::vdb::GridData;
        let n = &self.cfg.export.nanovdb;
        let mut grids = Vec::new();
        for (g, precision) in crate::export::nanovdb_grids(&self.cfg.export) {
            let source = g.alias_of.as_deref().unwrap_or(&g.name);
            let Some(vg) = file.grids.iter().find(|v| v.name == source) else {
                return Err(crate::Error::Runtime(format!(
                    "internal: NanoVDB grid '{source}' is not in the frame's grids"
                )));
            };
            let values = match &vg.data {
                GridData::Float(s) => NanoValues::Float(s, quantise(precision, s, n.tolerance)),
                GridData::Vec3(s) => NanoValues::Vec3(s),
            };
            grids.push(NanoGrid {
                name: g.name.clone(),
                class: GridClass::from_openvdb(vg.class),
                values,
            });
        }
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
        }
        crate::io::nanovdb::write_file(path, &grids)?;
        Ok(())
    }

    fn vdb_options(&self) -> VdbOptions {
        VdbOptions {
            compression: self.cfg.export.vdb.compression,
            half: self.cfg.export.vdb.half,
        }
    }

    /// After the last frame: the contact sheet of the previews.
    pub fn finish_run(&self, manifest: &Manifest) -> Result<()> {
        if !self.cfg.output.preview.enabled {
            return Ok(());
        }
        let frames: Vec<(u32, PathBuf)> = manifest
            .frames
            .iter()
            .map(|f| (f.frame, self.file(FrameFile::PreviewPng, f.frame)))
            .filter(|(_, p)| p.exists())
            .collect();
        if frames.is_empty() {
            return Ok(());
        }
        crate::preview::sheet::write_contact_sheet(&self.run_dir.contact_sheet(), &frames)?;
        // The movie once the whole range is there (an export directory fills up in parts).
        if self.cfg.output.preview.movie
            && manifest.complete
            && frames.len() == manifest.frames.len()
        {
            crate::preview::movie::write_movie(
                &self.run_dir.movie(&self.cfg.shot),
                &self.run_dir.frame_pattern(
                    FrameFile::PreviewPng,
                    &self.cfg.shot,
                    self.cfg.output.frame_padding,
                ),
                &frames,
                self.cfg.output.fps,
            )?;
        }
        Ok(())
    }
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// NanoVDB's storage for a float grid; FpN's tolerance is `tolerance` x the range (max - min)
/// of the grid's active values in this frame.
fn quantise(
    p: crate::config::NanoPrecision,
    g: &SparseGrid<f32>,
    tolerance: f64,
) -> crate::io::nanovdb::Quantise {
    use crate::config::NanoPrecision as P;
    use crate::io::nanovdb::Quantise as Q;
    match p {
        P::Float => Q::Float,
        P::Fp4 => Q::Fp4,
        P::Fp8 => Q::Fp8,
        P::Fp16 => Q::Fp16,
        P::Fpn => Q::FpN {
            tolerance: fpn_tolerance(g, tolerance),
        },
    }
}

/// `tolerance` x (max - min) of the active values, in f32 (0 for an empty grid).
pub fn fpn_tolerance(g: &SparseGrid<f32>, tolerance: f64) -> f32 {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for leaf in &g.leaves {
        for n in (0..crate::ground::LEAF_VOXELS).filter(|&n| leaf.is_active(n)) {
            lo = lo.min(leaf.values[n]);
            hi = hi.max(leaf.values[n]);
        }
    }
    if hi < lo {
        0.0
    } else {
        (tolerance * (hi - lo) as f64) as f32
    }
}
