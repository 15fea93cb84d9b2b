//! The order of one substep, as the paper gives it (sections 3-5). Each line records one phase
//! of a stage into the substep's command encoder; nothing here waits for the GPU.
use crate::error::Result;
use crate::sim::phase::Recorder;
use crate::sim::Simulation;

impl Simulation {
    /// Records one substep of `dt`.
    pub(super) fn record_substep(&self, rec: &mut Recorder, dt: f64) -> Result<()> {
        let (s, live) = (&self.s, &self.b.live);
        // the stages take the substep as the PBF parameters hold it (f32), as they always have
        let dt_f32 = self.params.dt as f64;
        debug_assert!((dt_f32 - dt).abs() <= dt * 1e-6);

        // 3. Position Based Fluids: predict, find neighbours, enforce the density, update v.
        s.pbf.predict(rec, live)?;
        s.grid.build(rec, live)?;
        s.pbf.solve(rec, live, self.iterations)?;
        s.pbf
            .update_velocity(rec, live, self.params.vorticity > 0.0)?;

        // 4.1 Temperature smoothing (eqs. 12-17), on the neighbourhoods just built.
        s.smoothing.smooth(rec, live, dt_f32)?;
        // 4. Heating, buoyancy, adiabatic cooling, phase transition, latent heat (eqs. 5-11).
        s.thermo.step(rec, live, dt_f32, self.clock.time)?;

        // 5.2 Adaptive particles: shape energy, split and merge.
        if let Some(adaptive) = &s.adaptive {
            adaptive.split_and_merge(rec, live)?;
        }
        Ok(())
    }
}
