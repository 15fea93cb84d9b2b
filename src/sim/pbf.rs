//! Parameters of the PBF step (shaders/pbf.wgsl `PbfParams`, byte-identical).
use crate::config::ShotConfig;

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PbfParams {
    pub dt: f32,
    pub inv_dt: f32,
    pub rest_density: f32,
    pub m0: f32,
    pub h0: f32,
    /// Relaxation epsilon of eq. 4 in 1/m^2: `solver.relaxation / h0^2`.
    pub eps: f32,
    pub scorr_k: f32,
    pub scorr_n: f32,
    pub scorr_dq: f32,
    pub xsph: f32,
    pub vorticity: f32,
    pub gravity: f32,
    pub max_speed: f32,
    /// 1 when every particle is on level 0: the shader skips the per-pair level look-up.
    pub single_level: u32,
    /// Under-density up to this fraction of rho0 is not corrected (`solver.expansion_tolerance`).
    pub expansion_tolerance: f32,
    /// The share of that correction split particles get (`solver.split_expansion_weight`).
    pub split_expansion_weight: f32,
    /// Per level l (0..8): (h_l, 315 / (64 pi h_l^9), -45 / (pi h_l^6), m_l).
    pub levels: [[f32; 4]; 8],
}

impl PbfParams {
    /// The parameters at the shot's fewest substeps (`output.substeps`); [`Self::set_dt`]
    /// changes the substep.
    pub fn for_shot(cfg: &ShotConfig) -> Self {
        let s = &cfg.solver;
        let h0 = crate::sim::init::kernel_radius(cfg);
        let dt = cfg.output.frame_seconds / cfg.output.substeps as f64;
        let mut p = Self {
            dt: dt as f32,
            inv_dt: (1.0 / dt) as f32,
            rest_density: s.rest_density as f32,
            m0: crate::sim::init::particle_mass(cfg) as f32,
            h0: h0 as f32,
            eps: (s.relaxation / (h0 * h0)) as f32,
            scorr_k: s.scorr_k as f32,
            scorr_n: s.scorr_n as f32,
            scorr_dq: s.scorr_dq as f32,
            xsph: s.xsph as f32,
            vorticity: s.vorticity as f32,
            gravity: s.gravity as f32,
            max_speed: s.max_speed as f32,
            single_level: 0,
            expansion_tolerance: s.expansion_tolerance as f32,
            split_expansion_weight: s.split_expansion_weight as f32,
            levels: std::array::from_fn(|l| {
                let h = h0 * (-(l as f64) / 3.0).exp2();
                let pi = std::f64::consts::PI;
                [
                    h as f32,
                    (315.0 / (64.0 * pi * h.powi(9))) as f32,
                    (-45.0 / (pi * h.powi(6))) as f32,
                    (crate::sim::init::particle_mass(cfg) * (-(l as f64)).exp2()) as f32,
                ]
            }),
        };
        p.set_dt(cfg, dt);
        p
    }

    /// A substep of `dt` seconds: dt, 1/dt and the XSPH fraction of this substep,
    /// `1 - (1 - solver.xsph)^(dt / solver.reference_step)`, and the s_corr strength
    /// `solver.scorr_k min(dt / solver.reference_step, 1)`.
    pub fn set_dt(&mut self, cfg: &ShotConfig, dt: f64) {
        self.dt = dt as f32;
        self.inv_dt = (1.0 / dt) as f32;
        let share = dt / cfg.solver.reference_step;
        self.xsph = crate::sim::smoothing::rate_share(cfg.solver.xsph, share) as f32;
        // s_corr acts in every iteration of every substep, and its pushes add up like a
        // stiffness: at 4x the substeps the same k held a heated layer in place (docs/PHYSICS.md
        // "Substeps"); so k is per reference_step too
        // (never above k itself: a substep longer than reference_step does not push harder)
        self.scorr_k = (cfg.solver.scorr_k * share.min(1.0)) as f32;
    }
}
