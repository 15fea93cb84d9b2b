//! The physical meaning of the density grid (`export.optics`): its unit, the liquid water content
//! one unit of it stands for, and the extinction coefficient that follows, per scene unit.
//!
//! A water cloud of liquid water content LWC (kg/m^3) made of droplets of effective radius r_e
//! (m) has, in the geometric-optics limit (extinction efficiency Q_ext ~ 2, droplets far larger
//! than visible wavelengths), the extinction coefficient
//!
//!   beta = 3 LWC / (2 rho_w r_e)   (1/m), rho_w = 1000 kg/m^3
//!
//! (Stephens 1978, J. Atmos. Sci. 35, 2123; Hansen & Travis 1974). The density grid holds cloud
//! water q (kg/kg) times `export.density_scale`, and LWC = q rho_air, so one unit of the grid is
//! rho_air / density_scale kg/m^3 of liquid water, and the extinction per unit of the grid per
//! metre is 3 rho_air / (2 rho_w r_e density_scale); per scene unit it is that times
//! `export.scale` (metres per unit). With the defaults (r_e = 10 um, rho_air = 1.1 kg/m^3,
//! density_scale 1000) a grid value of 1 (1 g/kg) is 1.1 g/m^3 and 0.165 per metre.
use crate::config::ShotConfig;
use crate::io::vdb::MetaValue;
use serde::{Deserialize, Serialize};

/// Density of liquid water (kg/m^3).
pub const WATER_DENSITY: f64 = 1000.0;

/// The optics of a shot's density grid, as written into the VDB metadata and the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Optics {
    /// Droplet effective radius (micrometres).
    pub effective_radius_um: f64,
    /// Air density (kg/m^3) and liquid water density (kg/m^3).
    pub air_density: f64,
    pub water_density: f64,
    /// What one unit of the density grid is, in words.
    pub density_unit: String,
    /// Liquid water content of one unit of the density grid (kg/m^3).
    pub lwc_per_unit: f64,
    /// Extinction coefficient of one unit of the density grid per metre (1/m) and per scene
    /// unit (1/scene unit): the renderer's density multiplier for physical extinction.
    pub extinction_per_metre: f64,
    pub extinction_per_unit: f64,
}

impl Optics {
    pub fn from_config(cfg: &ShotConfig) -> Self {
        let e = &cfg.export;
        let o = &e.optics;
        let lwc_per_unit = o.air_density / e.density_scale;
        let extinction_per_metre =
            1.5 * lwc_per_unit / (WATER_DENSITY * o.effective_radius * 1.0e-6);
        Self {
            effective_radius_um: o.effective_radius,
            air_density: o.air_density,
            water_density: WATER_DENSITY,
            density_unit: density_unit(e.density_scale),
            lwc_per_unit,
            extinction_per_metre,
            extinction_per_unit: extinction_per_metre * e.scale,
        }
    }

    /// Metadata of the density grid (and its aliases).
    pub fn metadata(&self) -> Vec<(String, MetaValue)> {
        vec![
            (
                "nimbus_density_unit".into(),
                MetaValue::String(self.density_unit.clone()),
            ),
            (
                "nimbus_lwc_per_unit".into(),
                MetaValue::Double(self.lwc_per_unit),
            ),
            (
                "nimbus_extinction_per_unit".into(),
                MetaValue::Double(self.extinction_per_unit),
            ),
            (
                "nimbus_effective_radius_um".into(),
                MetaValue::Double(self.effective_radius_um),
            ),
            (
                "nimbus_air_density".into(),
                MetaValue::Double(self.air_density),
            ),
        ]
    }
}

/// The density grid's unit for a given `export.density_scale`.
fn density_unit(density_scale: f64) -> String {
    if density_scale == 1000.0 {
        "g of cloud water per kg of air".into()
    } else if density_scale == 1.0 {
        "kg of cloud water per kg of air".into()
    } else {
        format!("kg of cloud water per kg of air x {density_scale}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(set: &[&str]) -> ShotConfig {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny.yaml");
        let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        crate::shot::load(&path, &set).unwrap().into_config()
    }

    #[test]
    fn extinction_is_three_lwc_over_two_rho_w_re() {
        let o = Optics::from_config(&cfg(&[]));
        // 1 g/kg at 1.1 kg/m^3 is 1.1 g/m^3; 3 * 1.1e-3 / (2 * 1000 * 10e-6) = 0.165 /m
        assert!((o.lwc_per_unit - 1.1e-3).abs() < 1e-15);
        assert!((o.extinction_per_metre - 0.165).abs() < 1e-12);
        assert_eq!(o.extinction_per_unit, o.extinction_per_metre);
        assert_eq!(o.density_unit, "g of cloud water per kg of air");
        // 0.15 /m per g/m^3 at r_e = 10 um (docs/RENDERING.md)
        assert!((o.extinction_per_metre / (o.lwc_per_unit * 1e3) - 0.15).abs() < 1e-12);
        // scene units of 100 m: 100x the extinction per unit; twice the radius, half of it;
        // the density in kg/kg: 1000x per unit
        let o2 = Optics::from_config(&cfg(&[
            "export.scale=100",
            "export.optics.effective_radius=20",
            "export.density_scale=1",
        ]));
        assert!((o2.extinction_per_unit - 0.165 * 100.0 / 2.0 * 1000.0).abs() < 1e-9);
        assert_eq!(o2.density_unit, "kg of cloud water per kg of air");
    }
}
