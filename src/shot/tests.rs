//! The prepared shot: its issues placed like the config's own, and the keys the stages below
//! trust refused here.
use super::*;
use crate::error::Error;

const BASE: &str = "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
                    domain: {size: [1000, 800, 1000], spacing: 50}\n";

#[test]
fn a_missing_heat_map_is_placed_at_its_key() {
    let text = format!(
        "{BASE}physics:\n  sources:\n    - shape: image\n      image: /nonexistent/heat.png\n"
    );
    let e = load_str(&text, "t.yaml", &[]).unwrap_err();
    assert!(matches!(e, Error::Config(_)), "{e:?}");
    assert_eq!(
        e.to_string(),
        "t.yaml:7:7: physics.sources[0].image: /nonexistent/heat.png: no such file"
    );
    // the config reads no file; prepared from code, the issue names its key alone
    let cfg = crate::config::read_str(&text, "t.yaml", &[])
        .unwrap()
        .config;
    let e = Shot::prepare(cfg).unwrap_err();
    assert_eq!(
        e.to_string(),
        "physics.sources[0].image: /nonexistent/heat.png: no such file"
    );
}

/// `AdaptiveParams::new`, `AdaptiveStage::new`, `Simulation::from_state`, the smoothing's
/// parameters, the capacity and the checkpoint pruning no longer check or clamp these: a shot
/// that breaks them is never prepared.
#[test]
fn the_keys_the_stages_trust_are_refused_here() {
    let ok = load_str(BASE, "t.yaml", &[]).unwrap().into_config();
    assert!(Shot::prepare(ok.clone()).is_ok());
    type Edit = fn(&mut ShotConfig);
    let breakers: [(Edit, &str); 9] = [
        (
            |c| c.adaptive.merge_threshold = c.adaptive.split_threshold,
            "adaptive.merge_threshold",
        ),
        (|c| c.adaptive.min_distance = 0.9, "adaptive.min_distance"),
        (|c| c.adaptive.split_offset = 0.0, "adaptive.split_offset"),
        (|c| c.adaptive.kc = f64::NAN, "adaptive.kc"),
        (|c| c.output.substeps = 0, "output.substeps"),
        (
            |c| c.physics.smoothing.iterations = 0,
            "physics.smoothing.iterations",
        ),
        (
            |c| {
                c.adaptive.enabled = true;
                c.adaptive.capacity_factor = 0.5;
            },
            "adaptive.capacity_factor",
        ),
        (|c| c.checkpoint.keep = 0, "checkpoint.keep"),
        (
            |c| {
                c.domain.size[0] = 250.0;
                c.domain.periodic = vec![crate::config::Axis::X];
            },
            "domain.periodic",
        ),
    ];
    for (edit, key) in breakers {
        let mut c = ok.clone();
        edit(&mut c);
        let e = Shot::prepare(c).unwrap_err();
        assert!(matches!(e, Error::Config(_)), "{e:?}");
        assert!(e.to_string().starts_with(&format!("{key}: ")), "{key}: {e}");
    }
}

/// The two level-0 masses: the solver's m0 puts the lattice at rest density by its own poly6
/// sum, the cell mass is rho0 d^3; at h0 = 2d they differ by the kernel's discretisation error
/// (the lattice sum is 1.0098 / d^3), and the level table halves both per level.
#[test]
fn the_solver_mass_normalises_the_lattice_sum_and_the_cell_mass_is_rho0_d3() {
    let shot = load_str(BASE, "t.yaml", &["solver.rest_density=1.2".into()]).unwrap();
    assert_eq!(shot.cell_mass(), 1.2 * 50.0 * 50.0 * 50.0);
    let (h, d) = (shot.h0(), 50.0);
    let mut sum = 0.0;
    for k in -2i32..=2 {
        for j in -2i32..=2 {
            for i in -2i32..=2 {
                let r2 = ((i * i + j * j + k * k) as f64) * d * d;
                sum += crate::ground::levels::poly6(r2, h);
            }
        }
    }
    assert!((shot.m0() * sum / 1.2 - 1.0).abs() < 1e-12, "{}", shot.m0());
    let ratio = shot.m0() / shot.cell_mass();
    assert!((ratio - 1.0 / 1.00978).abs() < 1e-5, "{ratio}");
    assert_eq!(shot.level_mass(3), shot.m0() / 8.0);
    assert!((shot.level_radius(3) - shot.h0() / 2.0).abs() < 1e-12);
}
